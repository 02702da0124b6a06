//! Parquet writers for the index tables (zstd, row groups bounded in rows so memory stays
//! bounded), and the rows they take. Rows are buffered a few thousand at a time and written
//! as Arrow record batches.

use super::schema::{self, Table};
use crate::error::{Error, Result, ResultExt};
use crate::fsutil::{AtomicFile, StagedFile};
use crate::homology::Diagram;
use crate::types::Pose;
use crate::vectorize::codebook::Descriptor;
use arrow::array::{
    ArrayRef, FixedSizeListArray, Float32Array, Float64Builder, Int64Builder, RecordBatch, StringBuilder,
    UInt8Array, UInt8Builder, UInt64Builder,
};
use arrow::datatypes::Schema;
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::properties::WriterProperties;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Rows per row group (bounded memory per open file).
const ROW_GROUP_ROWS: usize = 256 * 1024;

/// What happened to a scan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Status {
    /// Indexed.
    Ok,
    /// Left out on purpose (e.g. too few points after preprocessing).
    Skipped,
    /// Could not be read or processed.
    Error,
}

impl Status {
    /// The status a `status` column value names.
    pub fn parse(s: &str) -> Option<Status> {
        [Status::Ok, Status::Skipped, Status::Error].into_iter().find(|x| x.as_str() == s)
    }

    /// The value in the `status` column.
    pub fn as_str(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::Skipped => "skipped",
            Status::Error => "error",
        }
    }
}

/// A row of `scans`.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanRow {
    /// Scan id.
    pub scan_id: String,
    /// xxh3-64 of the scan's raw bytes (16 hex digits), when they could be read.
    pub fingerprint: Option<String>,
    /// Fingerprint of the preprocess and persistence settings the row was made with.
    pub settings_hash: String,
    /// Session (the partition).
    pub session: String,
    /// Position in the run's input.
    pub seq: u64,
    /// Source file.
    pub source_path: String,
    /// MCAP message index.
    pub message_index: Option<u64>,
    /// Timestamp (µs).
    pub utime: Option<i64>,
    /// Ground-truth pose.
    pub pose: Option<Pose>,
    /// Points in the record.
    pub raw_points: u64,
    /// Points after preprocessing.
    pub kept_points: u64,
    /// Outcome.
    pub status: Status,
    /// Reason for skipped/error.
    pub error: Option<String>,
}

/// A row of `descriptors`.
#[derive(Clone, Debug, PartialEq)]
pub struct DescriptorRow {
    /// Scan id.
    pub scan_id: String,
    /// Timestamp (µs).
    pub utime: Option<i64>,
    /// Ground-truth pose.
    pub pose: Option<Pose>,
    /// Paper rule: the dimension used.
    pub dim_used: Option<u8>,
    /// The vector.
    pub values: Vec<f32>,
}

impl DescriptorRow {
    /// The row of one scan's descriptor.
    pub fn new(scan_id: String, utime: Option<i64>, pose: Option<Pose>, d: &Descriptor) -> Self {
        DescriptorRow { scan_id, utime, pose, dim_used: d.dim_used, values: d.to_f32() }
    }
}

fn properties(schema: &Schema) -> WriterProperties {
    let kv = schema
        .metadata()
        .iter()
        .map(|(k, v)| parquet::file::metadata::KeyValue::new(k.clone(), v.clone()))
        .collect();
    let builder = WriterProperties::builder()
        .set_compression(Compression::ZSTD(ZstdLevel::try_new(3).expect("valid level")))
        .set_max_row_group_row_count(Some(ROW_GROUP_ROWS))
        .set_key_value_metadata(Some(kv));
    // Diagrams: small pages, so a reader that needs one dimension (a codebook reading H2)
    // skips the pages of the others through the page index; births and deaths stored plain
    // (zstd saves ~15 % on them, and costs more to decode than everything else).
    let diagrams = schema.metadata().get(schema::meta::TABLE).is_some_and(|t| t == schema::tables::DIAGRAMS);
    let builder = if diagrams {
        let mut b =
            builder.set_data_page_row_count_limit(DIAGRAM_PAGE_ROWS).set_write_batch_size(DIAGRAM_PAGE_ROWS);
        for column in [schema::columns::BIRTH, schema::columns::DEATH] {
            let path = parquet::schema::types::ColumnPath::from(column);
            b = b
                .set_column_compression(path.clone(), Compression::UNCOMPRESSED)
                .set_column_dictionary_enabled(path, false);
        }
        b
    } else {
        builder
    };
    builder.build()
}

/// Rows per data page of a diagrams file (a scan of 4096 points has ~8,000 pairs, ~400 of
/// them in H2).
const DIAGRAM_PAGE_ROWS: usize = 1024;

/// One Parquet file being written (atomically: it appears under its name only once
/// complete, footer included).
pub(crate) struct TableFile {
    path: PathBuf,
    writer: ArrowWriter<AtomicFile>,
    schema: Arc<Schema>,
    rows: u64,
}

impl TableFile {
    /// Creates `path` (its folder too) for `table`.
    pub(crate) fn create(path: &Path, table: &Table, extra_meta: &[(&str, String)]) -> Result<Self> {
        let schema = table.arrow_schema(extra_meta);
        let file = AtomicFile::create(path)?;
        let writer = ArrowWriter::try_new(file, schema.clone(), Some(properties(&schema))).at(path)?;
        Ok(TableFile { path: path.to_owned(), writer, schema, rows: 0 })
    }

    fn write(&mut self, columns: Vec<ArrayRef>) -> Result<()> {
        let batch = RecordBatch::try_new(self.schema.clone(), columns).at(&self.path)?;
        self.rows += batch.num_rows() as u64;
        self.writer.write(&batch).at(&self.path)
    }

    /// Creates `path` with a given schema (a table being rewritten).
    pub(crate) fn with_schema(path: &Path, schema: Arc<Schema>) -> Result<Self> {
        let file = AtomicFile::create(path)?;
        let writer = ArrowWriter::try_new(file, schema.clone(), Some(properties(&schema))).at(path)?;
        Ok(TableFile { path: path.to_owned(), writer, schema, rows: 0 })
    }

    /// The file's schema.
    pub(crate) fn schema(&self) -> &Arc<Schema> {
        &self.schema
    }

    /// Writes a batch of this file's schema.
    pub(crate) fn write_batch(&mut self, batch: &RecordBatch) -> Result<()> {
        self.rows += batch.num_rows() as u64;
        self.writer.write(batch).at(&self.path)
    }

    /// Closes the file (footer written), complete under its temporary name; returns it and its
    /// row count.
    pub(crate) fn finish(self) -> Result<(StagedFile, u64)> {
        let file = self.writer.into_inner().at(&self.path)?;
        Ok((file.finish()?, self.rows))
    }
}

/// Rows buffered before a batch is written.
const BATCH_ROWS: usize = 8192;

/// Writer of one `scans` file.
pub(crate) struct ScansFile {
    file: TableFile,
    rows: Vec<ScanRow>,
}

impl ScansFile {
    /// Creates the file.
    pub(crate) fn create(path: &Path) -> Result<Self> {
        Ok(ScansFile { file: TableFile::create(path, &schema::scans(), &[])?, rows: Vec::new() })
    }

    /// Adds a row.
    pub(crate) fn push(&mut self, row: ScanRow) -> Result<()> {
        self.rows.push(row);
        if self.rows.len() >= BATCH_ROWS { self.flush() } else { Ok(()) }
    }

    fn flush(&mut self) -> Result<()> {
        if self.rows.is_empty() {
            return Ok(());
        }
        let rows = std::mem::take(&mut self.rows);
        let columns = scan_columns(&rows);
        self.file.write(columns)
    }

    /// Flushes and closes (see [`TableFile::finish`]).
    pub(crate) fn finish(mut self) -> Result<(StagedFile, u64)> {
        self.flush()?;
        self.file.finish()
    }
}

/// Writer of one `diagrams` file.
pub(crate) struct DiagramsFile {
    file: TableFile,
    columns: DiagramColumns,
    pending: usize,
}

impl DiagramsFile {
    /// Creates the file.
    pub(crate) fn create(path: &Path) -> Result<Self> {
        Ok(DiagramsFile {
            file: TableFile::create(path, &schema::diagrams(), &[])?,
            columns: DiagramColumns::default(),
            pending: 0,
        })
    }

    /// Adds one scan's pairs in dimensions `dims`.
    pub(crate) fn push(&mut self, scan_id: &str, diagram: &Diagram, dims: &[u8]) -> Result<()> {
        self.pending += self.columns.push(scan_id, diagram, dims);
        if self.pending >= 8 * BATCH_ROWS { self.flush() } else { Ok(()) }
    }

    fn flush(&mut self) -> Result<()> {
        if self.pending == 0 {
            return Ok(());
        }
        self.pending = 0;
        let columns = self.columns.finish();
        self.file.write(columns)
    }

    /// Flushes and closes (see [`TableFile::finish`]).
    pub(crate) fn finish(mut self) -> Result<(StagedFile, u64)> {
        self.flush()?;
        self.file.finish()
    }
}

/// Writer of one `descriptors` file.
pub(crate) struct DescriptorsFile {
    file: TableFile,
    b: usize,
    codebook_id: String,
    /// Whether the values are bytes (stored as uint8).
    bytes: bool,
    rows: Vec<DescriptorRow>,
}

impl DescriptorsFile {
    /// Creates the file for descriptors of `method`, of length `b`, made with codebook (or
    /// method id) `codebook_id`.
    pub(crate) fn create(path: &Path, method: &str, b: usize, codebook_id: &str) -> Result<Self> {
        let meta = [
            (schema::meta::CODEBOOK_ID, codebook_id.to_string()),
            (schema::meta::METHOD, method.to_string()),
        ];
        Ok(DescriptorsFile {
            file: TableFile::create(path, &schema::descriptors_for(method, b), &meta)?,
            b,
            codebook_id: codebook_id.to_string(),
            bytes: crate::methods::stores_bytes(method),
            rows: Vec::new(),
        })
    }

    /// Adds a row.
    pub(crate) fn push(&mut self, row: DescriptorRow) -> Result<()> {
        if row.values.len() != self.b {
            return Err(Error::table(
                &self.file.path,
                format!("descriptor of length {} in a table of length {}", row.values.len(), self.b),
            ));
        }
        if !row.values.iter().all(|v| v.is_finite()) {
            return Err(Error::table(
                &self.file.path,
                format!("scan {}: a descriptor with non-finite values is never stored", row.scan_id),
            ));
        }
        if self.bytes && !row.values.iter().all(|&v| is_byte(v)) {
            return Err(Error::table(
                &self.file.path,
                format!("scan {}: a byte descriptor with a value that is not a byte", row.scan_id),
            ));
        }
        self.rows.push(row);
        if self.rows.len() >= BATCH_ROWS / 4 { self.flush() } else { Ok(()) }
    }

    fn flush(&mut self) -> Result<()> {
        if self.rows.is_empty() {
            return Ok(());
        }
        let rows = std::mem::take(&mut self.rows);
        let columns = descriptor_columns(&rows, self.b, &self.codebook_id, self.bytes);
        self.file.write(columns)
    }

    /// Flushes and closes (see [`TableFile::finish`]).
    pub(crate) fn finish(mut self) -> Result<(StagedFile, u64)> {
        self.flush()?;
        self.file.finish()
    }
}

/// The `scans` columns of `rows`, in the schema's order ([`schema::scans`]).
pub(crate) fn scan_columns(rows: &[ScanRow]) -> Vec<ArrayRef> {
    let s = |f: &dyn Fn(&ScanRow) -> Option<String>| {
        let mut b = StringBuilder::new();
        rows.iter().for_each(|r| b.append_option(f(r)));
        Arc::new(b.finish()) as ArrayRef
    };
    let u = |f: &dyn Fn(&ScanRow) -> Option<u64>| {
        let mut b = UInt64Builder::new();
        rows.iter().for_each(|r| b.append_option(f(r)));
        Arc::new(b.finish()) as ArrayRef
    };
    let p = |f: &dyn Fn(&Pose) -> f64| {
        let mut b = Float64Builder::new();
        rows.iter().for_each(|r| b.append_option(r.pose.as_ref().map(f)));
        Arc::new(b.finish()) as ArrayRef
    };
    let mut utime = Int64Builder::new();
    rows.iter().for_each(|r| utime.append_option(r.utime));
    let columns = vec![
        s(&|r| Some(r.scan_id.clone())),
        s(&|r| r.fingerprint.clone()),
        s(&|r| Some(r.settings_hash.clone())),
        u(&|r| Some(r.seq)),
        s(&|r| Some(r.source_path.clone())),
        u(&|r| r.message_index),
        Arc::new(utime.finish()) as ArrayRef,
        p(&|q| q.x),
        p(&|q| q.y),
        p(&|q| q.z),
        p(&|q| q.yaw),
        u(&|r| Some(r.raw_points)),
        u(&|r| Some(r.kept_points)),
        s(&|r| Some(r.status.as_str().to_string())),
        s(&|r| r.error.clone()),
    ];
    columns
}

/// The `diagrams` columns, built a scan at a time ([`schema::diagrams`]).
#[derive(Default)]
pub(crate) struct DiagramColumns {
    ids: StringBuilder,
    dims: UInt8Builder,
    births: Float64Builder,
    deaths: Float64Builder,
}

impl DiagramColumns {
    /// Adds one scan's pairs in dimensions `dims`; returns how many.
    pub(crate) fn push(&mut self, scan_id: &str, diagram: &Diagram, dims: &[u8]) -> usize {
        let mut added = 0;
        for p in diagram.pairs().iter().filter(|p| dims.contains(&p.dim)) {
            self.ids.append_value(scan_id);
            self.dims.append_value(p.dim);
            self.births.append_value(p.birth);
            self.deaths.append_value(p.death);
            added += 1;
        }
        added
    }

    /// The columns of every pair added since the last call.
    pub(crate) fn finish(&mut self) -> Vec<ArrayRef> {
        vec![
            Arc::new(self.ids.finish()),
            Arc::new(self.dims.finish()),
            Arc::new(self.births.finish()),
            Arc::new(self.deaths.finish()),
        ]
    }
}

/// Whether a descriptor value is a byte (an integer in 0..=255).
pub(crate) fn is_byte(v: f32) -> bool {
    (0.0..=255.0).contains(&v) && v.fract() == 0.0
}

/// The `descriptors` columns of `rows` (length `b`, made by `codebook_id`), in the schema's
/// order ([`schema::descriptors_for`]): the values as uint8 when `bytes` (each a byte, as
/// [`is_byte`] checks), else float32.
pub(crate) fn descriptor_columns(
    rows: &[DescriptorRow],
    b: usize,
    codebook_id: &str,
    bytes: bool,
) -> Vec<ArrayRef> {
    let mut ids = StringBuilder::new();
    let mut utime = Int64Builder::new();
    let mut pose = [Float64Builder::new(), Float64Builder::new(), Float64Builder::new()];
    let mut dim = UInt8Builder::new();
    let mut codebook = StringBuilder::new();
    for r in rows {
        ids.append_value(&r.scan_id);
        utime.append_option(r.utime);
        pose[0].append_option(r.pose.map(|p| p.x));
        pose[1].append_option(r.pose.map(|p| p.y));
        pose[2].append_option(r.pose.map(|p| p.z));
        dim.append_option(r.dim_used);
        codebook.append_value(codebook_id);
    }
    let values = rows.iter().flat_map(|r| r.values.iter().copied());
    let values: ArrayRef = if bytes {
        Arc::new(UInt8Array::from_iter_values(values.map(|v| v as u8)))
    } else {
        Arc::new(Float32Array::from_iter_values(values))
    };
    let item = Arc::new(arrow::datatypes::Field::new("item", values.data_type().clone(), false));
    let vectors = Arc::new(FixedSizeListArray::new(item, b as i32, values, None));
    let [px, py, pz] = pose.map(|mut b| Arc::new(b.finish()) as ArrayRef);
    let columns: Vec<ArrayRef> = vec![
        Arc::new(ids.finish()),
        Arc::new(utime.finish()),
        px,
        py,
        pz,
        Arc::new(dim.finish()),
        vectors,
        Arc::new(codebook.finish()),
    ];
    columns
}
