//! Committed files written again: without the rows of removed scans, and with the time and
//! pose of rejoined ones (a commit's rewrite of the parts it supersedes).

use crate::error::{Error, Result, ResultExt};
use crate::fsutil::StagedFile;
use crate::sinks::parquet::TableFile;
use std::collections::{HashMap, HashSet};
use std::path::Path;

/// A scan's time and pose as its source joins them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Joined {
    /// Timestamp (µs), when the source gives one.
    pub utime: Option<i64>,
    /// The pose, when one was joined.
    pub pose: Option<crate::types::Pose>,
}

/// Writes `target` as `path` without the rows of `removed` scans, and with the time and pose
/// columns (those the file has) of `rejoined` scans replaced; `None` when no row is left.
pub(super) fn rewrite_rows(
    path: &Path,
    bytes: bytes::Bytes,
    target: &Path,
    removed: &HashSet<String>,
    rejoined: &HashMap<String, Joined>,
) -> Result<Option<(StagedFile, u64)>> {
    use arrow::array::{AsArray, BooleanArray};
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
    let builder = ParquetRecordBatchReaderBuilder::try_new(bytes).at(path)?;
    let schema = builder.schema().clone();
    let mut out = TableFile::with_schema(target, schema)?;
    for batch in builder.build().at(path)? {
        let batch = batch.at(path)?;
        let ids = batch
            .column_by_name(crate::sinks::schema::columns::SCAN_ID)
            .ok_or_else(|| Error::table(path, "no column `scan_id`"))?
            .as_string::<i32>()
            .clone();
        let keep: BooleanArray =
            ids.iter().map(|id| Some(!id.is_some_and(|id| removed.contains(id)))).collect();
        let batch = if ids.iter().any(|id| id.is_some_and(|id| rejoined.contains_key(id))) {
            with_joined(&batch, &ids, rejoined).at(path)?
        } else {
            batch
        };
        let kept = arrow::compute::filter_record_batch(&batch, &keep).at(path)?;
        if kept.num_rows() > 0 {
            out.write_batch(&kept)?;
        }
    }
    let (file, rows) = out.finish()?;
    Ok((rows > 0).then_some((file, rows)))
}

/// `batch` with the time and pose columns it has set to `rejoined`'s values on the rows of
/// the scans it names.
fn with_joined(
    batch: &arrow::record_batch::RecordBatch,
    ids: &arrow::array::StringArray,
    rejoined: &HashMap<String, Joined>,
) -> std::result::Result<arrow::record_batch::RecordBatch, arrow::error::ArrowError> {
    use crate::sinks::schema::columns as C;
    use arrow::array::{Array, ArrayRef, AsArray, Float64Array, Int64Array};
    use arrow::datatypes::{Float64Type, Int64Type};
    use std::sync::Arc;
    let joined = |row: usize| ids.is_valid(row).then(|| rejoined.get(ids.value(row))).flatten();
    let schema = batch.schema();
    let mut columns: Vec<ArrayRef> = Vec::with_capacity(batch.num_columns());
    for (field, column) in schema.fields().iter().zip(batch.columns()) {
        let pose_value = |p: &crate::types::Pose| match field.name().as_str() {
            C::POSE_X => Some(p.x),
            C::POSE_Y => Some(p.y),
            C::POSE_Z => Some(p.z),
            C::POSE_YAW => Some(p.yaw),
            _ => None,
        };
        let replaced: ArrayRef = match field.name().as_str() {
            C::UTIME => {
                let old = column.as_primitive::<Int64Type>();
                Arc::new(
                    (0..batch.num_rows())
                        .map(|r| match joined(r) {
                            Some(j) => j.utime,
                            None => old.is_valid(r).then(|| old.value(r)),
                        })
                        .collect::<Int64Array>(),
                )
            }
            C::POSE_X | C::POSE_Y | C::POSE_Z | C::POSE_YAW => {
                let old = column.as_primitive::<Float64Type>();
                Arc::new(
                    (0..batch.num_rows())
                        .map(|r| match joined(r) {
                            Some(j) => j.pose.as_ref().and_then(pose_value),
                            None => old.is_valid(r).then(|| old.value(r)),
                        })
                        .collect::<Float64Array>(),
                )
            }
            _ => column.clone(),
        };
        columns.push(replaced);
    }
    arrow::record_batch::RecordBatch::try_new(schema, columns)
}
