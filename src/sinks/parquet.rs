//! Parquet writers for the index tables (zstd, row groups bounded in rows so memory stays
//! bounded), and the rows they take. Rows are buffered a few thousand at a time and written
//! as Arrow record batches.

use super::rows::{Col, RowBuilder};
use super::schema::{self, Table};
use crate::error::{Error, Result, ResultExt};
use crate::fsutil::{AtomicFile, StagedFile};
use crate::homology::Diagram;
use crate::types::Pose;
use crate::vectorize::codebook::Descriptor;
use arrow::array::RecordBatch;
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

impl ScanRow {
    /// Where the scan was found, to read it again ([`crate::sources::reread`]).
    pub fn place(&self) -> crate::sources::reread::Place {
        crate::sources::reread::Place {
            scan_id: self.scan_id.clone(),
            session: self.session.clone(),
            path: std::path::PathBuf::from(&self.source_path),
            message_index: self.message_index,
        }
    }
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
        let batch = scan_batch(&rows, self.file.schema.clone()).at(&self.file.path)?;
        self.file.write_batch(&batch)
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
    rows: DiagramRows,
    pending: usize,
}

impl DiagramsFile {
    /// Creates the file.
    pub(crate) fn create(path: &Path) -> Result<Self> {
        let file = TableFile::create(path, &schema::diagrams(), &[])?;
        Ok(DiagramsFile { rows: DiagramRows::new(file.schema.clone()), file, pending: 0 })
    }

    /// Adds one scan's pairs in dimensions `dims`.
    pub(crate) fn push(&mut self, scan_id: &str, diagram: &Diagram, dims: &[u8]) -> Result<()> {
        self.pending += self.rows.push(scan_id, diagram, dims);
        if self.pending >= 8 * BATCH_ROWS { self.flush() } else { Ok(()) }
    }

    fn flush(&mut self) -> Result<()> {
        if self.pending == 0 {
            return Ok(());
        }
        self.pending = 0;
        let batch = self.rows.finish().at(&self.file.path)?;
        self.file.write_batch(&batch)
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
    method: String,
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
            method: method.to_string(),
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
        let schema = self.file.schema.clone();
        let batch =
            descriptor_batch(&rows, &self.method, self.b, &self.codebook_id, schema).at(&self.file.path)?;
        self.file.write_batch(&batch)
    }

    /// Flushes and closes (see [`TableFile::finish`]).
    pub(crate) fn finish(mut self) -> Result<(StagedFile, u64)> {
        self.flush()?;
        self.file.finish()
    }
}

/// The `scans` rows as a batch of [`schema::scans`], of `schema` (the table's, with its metadata).
pub(crate) fn scan_batch(
    rows: &[ScanRow],
    schema: Arc<Schema>,
) -> Result<RecordBatch, arrow::error::ArrowError> {
    use schema::columns as C;
    let table = schema::scans();
    let mut b = RowBuilder::new(&table, schema);
    let [id, fp, settings, seq, source, message, utime] =
        [C::SCAN_ID, C::FINGERPRINT, C::SETTINGS_HASH, C::SEQ, C::SOURCE_PATH, C::MESSAGE_INDEX, C::UTIME]
            .map(|n| b.col(n));
    let [x, y, z, yaw] = [C::POSE_X, C::POSE_Y, C::POSE_Z, C::POSE_YAW].map(|n| b.col(n));
    let [raw, kept, status, error] = [C::RAW_POINTS, C::KEPT_POINTS, C::STATUS, C::ERROR].map(|n| b.col(n));
    for r in rows {
        b.text(id, Some(&r.scan_id))
            .text(fp, r.fingerprint.as_deref())
            .text(settings, Some(&r.settings_hash))
            .uint(seq, Some(r.seq))
            .text(source, Some(&r.source_path))
            .uint(message, r.message_index)
            .int(utime, r.utime)
            .float(x, r.pose.map(|p| p.x))
            .float(y, r.pose.map(|p| p.y))
            .float(z, r.pose.map(|p| p.z))
            .float(yaw, r.pose.map(|p| p.yaw))
            .uint(raw, Some(r.raw_points))
            .uint(kept, Some(r.kept_points))
            .text(status, Some(r.status.as_str()))
            .text(error, r.error.as_deref())
            .end_row();
    }
    b.finish()
}

/// The `diagrams` rows, built a scan at a time ([`schema::diagrams`]).
pub(crate) struct DiagramRows {
    builder: RowBuilder,
    cols: [Col; 4],
}

impl DiagramRows {
    /// Rows of batches of `schema` (the table's, with its metadata).
    pub(crate) fn new(schema: Arc<Schema>) -> Self {
        use schema::columns as C;
        let builder = RowBuilder::new(&schema::diagrams(), schema);
        let cols = [C::SCAN_ID, C::DIM, C::BIRTH, C::DEATH].map(|n| builder.col(n));
        DiagramRows { builder, cols }
    }

    /// Adds one scan's pairs in dimensions `dims`; returns how many.
    pub(crate) fn push(&mut self, scan_id: &str, diagram: &Diagram, dims: &[u8]) -> usize {
        let [id, dim, birth, death] = self.cols;
        let mut added = 0;
        for p in diagram.pairs().iter().filter(|p| dims.contains(&p.dim)) {
            self.builder
                .text(id, Some(scan_id))
                .uint(dim, Some(p.dim as u64))
                .float(birth, Some(p.birth))
                .float(death, Some(p.death))
                .end_row();
            added += 1;
        }
        added
    }

    /// Every pair added since the last call, as a batch.
    pub(crate) fn finish(&mut self) -> Result<RecordBatch, arrow::error::ArrowError> {
        self.builder.finish()
    }
}

/// Whether a descriptor value is a byte (an integer in 0..=255).
pub(crate) fn is_byte(v: f32) -> bool {
    (0.0..=255.0).contains(&v) && v.fract() == 0.0
}

/// The `descriptors` rows (length `b`, made by `codebook_id`) as a batch of
/// [`schema::descriptors_for`] `method`, of `schema` (the table's, with its metadata): the values
/// as uint8 for a method whose descriptors are bytes (each a byte, as [`is_byte`] checks), else
/// float32.
pub(crate) fn descriptor_batch(
    rows: &[DescriptorRow],
    method: &str,
    b: usize,
    codebook_id: &str,
    schema: Arc<Schema>,
) -> Result<RecordBatch, arrow::error::ArrowError> {
    use schema::columns as C;
    let table = schema::descriptors_for(method, b);
    let mut builder = RowBuilder::new(&table, schema);
    let [id, utime, x, y, z, dim, vector, codebook] =
        [C::SCAN_ID, C::UTIME, C::POSE_X, C::POSE_Y, C::POSE_Z, C::DIM_USED, C::DESCRIPTOR, C::CODEBOOK_ID]
            .map(|n| builder.col(n));
    for r in rows {
        builder
            .text(id, Some(&r.scan_id))
            .int(utime, r.utime)
            .float(x, r.pose.map(|p| p.x))
            .float(y, r.pose.map(|p| p.y))
            .float(z, r.pose.map(|p| p.z))
            .uint(dim, r.dim_used.map(u64::from))
            .list(vector, &r.values)
            .text(codebook, Some(codebook_id))
            .end_row();
    }
    builder.finish()
}
