//! One part file read as its table: its metadata and every needed column checked, the columns
//! cast to toporec's types by family (see the module above), a nullable column the file lacks
//! read as nulls; scans, diagrams, descriptors and scan ids, and the declared batches compaction
//! writes.

use super::{IndexedScan, ScanRecord};
use crate::error::{Error, FileError, Result, ResultExt};
use crate::homology::{Diagram, Pair};
use crate::sinks::index::damage::load;
use crate::sinks::parquet::{ScanRow, Status};
use crate::sinks::rows::Columns;
use crate::sinks::schema::{self, SCHEMA_VERSION, columns as C, meta, tables};
use crate::types::Pose;
use arrow::array::{Array, ArrayRef, AsArray, RecordBatch};
use arrow::datatypes::{DataType, Field, Float32Type, UInt8Type};
use bytes::Bytes;
use parquet::arrow::ProjectionMask;
use parquet::arrow::arrow_reader::{ParquetRecordBatchReader, ParquetRecordBatchReaderBuilder};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The family a column type belongs to: types of one family are cast to toporec's.
#[derive(PartialEq)]
enum Family {
    Text,
    Integer,
    Float,
    FloatList,
    Other,
}

fn family(t: &DataType) -> Family {
    use DataType::*;
    match t {
        Utf8 | LargeUtf8 | Utf8View => Family::Text,
        Int8 | Int16 | Int32 | Int64 | UInt8 | UInt16 | UInt32 | UInt64 => Family::Integer,
        Float16 | Float32 | Float64 => Family::Float,
        FixedSizeList(f, _) | List(f) | LargeList(f) | ListView(f) | LargeListView(f)
            if family(f.data_type()) == Family::Float =>
        {
            Family::FloatList
        }
        _ => Family::Other,
    }
}

/// A column wanted from a table: its name, toporec's type, whether nulls are allowed, and
/// whether the file has it (a nullable column added to the table after the file was written
/// reads as nulls).
struct Wanted {
    name: &'static str,
    data_type: DataType,
    nullable: bool,
    present: bool,
}

/// A table file opened with its needed columns checked; yields batches whose columns are in
/// the wanted order and of toporec's types.
pub(super) struct CheckedTable {
    path: PathBuf,
    wanted: Vec<Wanted>,
    batches: ParquetRecordBatchReader,
}

impl CheckedTable {
    /// Opens the bytes of `path` as table `table`, reading only `names`.
    pub(super) fn open(
        path: &Path,
        bytes: Bytes,
        table: &schema::Table,
        names: &[&'static str],
        length: Option<usize>,
    ) -> Result<Self> {
        Self::open_any(path, bytes, table, Some(table.name), names, length, false, None)
    }

    /// Opens the bytes of `path`, reading `names` as `table` declares them; `table_name`: the
    /// table it must be (when its metadata names one).
    #[allow(clippy::too_many_arguments)]
    fn open_any(
        path: &Path,
        bytes: Bytes,
        table: &schema::Table,
        table_name: Option<&str>,
        names: &[&'static str],
        length: Option<usize>,
        dictionary_ids: bool,
        only_dims: Option<Vec<u8>>,
    ) -> Result<Self> {
        let builder = ParquetRecordBatchReaderBuilder::try_new(bytes.clone()).at(path)?;
        let kv = builder.metadata().file_metadata().key_value_metadata();
        let get =
            |key: &str| kv.and_then(|kv| kv.iter().find(|e| e.key == key)).and_then(|e| e.value.clone());
        // A newer layout may have changed what older readers rely on; an older one is read by
        // column name (a nullable column it lacks reads as nulls).
        let newer = |v: &String| {
            let number = |v: &str| v.trim().parse::<u64>().ok();
            number(v).is_none_or(|n| number(SCHEMA_VERSION).is_some_and(|ours| n > ours))
        };
        if let Some(v) = get(meta::SCHEMA_VERSION).filter(newer) {
            return Err(Error::table(
                path,
                format!("table layout version {v}; this toporec reads versions up to {SCHEMA_VERSION}"),
            ));
        }
        if let (Some(t), Some(want)) = (get(meta::TABLE), table_name)
            && t != want
        {
            return Err(Error::table(path, format!("a `{t}` table where `{want}` was expected")));
        }
        let arrow_schema = builder.schema().clone();
        let mut wanted = Vec::new();
        let mut roots = Vec::new();
        for &name in names {
            let column = table.columns.iter().find(|c| c.name == name).expect("a column of the table");
            let found = arrow_schema.column_with_name(name);
            if found.is_none() && column.nullable {
                wanted.push(Wanted {
                    name,
                    data_type: column.data_type.clone(),
                    nullable: true,
                    present: false,
                });
                continue;
            }
            let Some((i, field)) = found else {
                let have: Vec<&str> = arrow_schema.fields().iter().map(|f| f.name().as_str()).collect();
                // The table this file stands for: the one asked for, else the one its metadata
                // or its folder names.
                let what = match table_name
                    .map(str::to_string)
                    .or_else(|| get(meta::TABLE))
                    .or_else(|| table_of_path(path))
                {
                    Some(t) => format!("this `{t}` table"),
                    None => "this table".to_string(),
                };
                return Err(Error::table(
                    path,
                    format!("no column `{name}` in {what} (columns: {})", have.join(", ")),
                ));
            };
            let mut data_type = column.data_type.clone();
            if name == C::DESCRIPTOR {
                data_type = descriptor_type(path, field, length, &data_type)?;
            } else if family(field.data_type()) != family(&data_type) || family(&data_type) == Family::Other {
                return Err(Error::table(
                    path,
                    format!("column `{name}` is {}, expected {data_type}", field.data_type()),
                ));
            }
            wanted.push(Wanted { name, data_type, nullable: column.nullable, present: true });
            roots.push(i);
        }
        // Scan ids as a dictionary: decoded once per batch, not once per row (a diagrams file
        // holds thousands of rows per scan).
        let scan_id = arrow_schema.column_with_name(C::SCAN_ID);
        let builder = match scan_id {
            Some((i, f)) if dictionary_ids && f.data_type() == &DataType::Utf8 => {
                let dictionary = DataType::Dictionary(Box::new(DataType::Int32), Box::new(DataType::Utf8));
                let mut fields: Vec<Field> = arrow_schema.fields().iter().map(|f| (**f).clone()).collect();
                fields[i] = fields[i].clone().with_data_type(dictionary.clone());
                let hint = Arc::new(arrow::datatypes::Schema::new_with_metadata(
                    fields,
                    arrow_schema.metadata().clone(),
                ));
                if let Some(w) = wanted.iter_mut().find(|w| w.name == C::SCAN_ID) {
                    w.data_type = dictionary;
                }
                let options = parquet::arrow::arrow_reader::ArrowReaderOptions::new()
                    .with_schema(hint)
                    .with_page_index_policy(parquet::file::metadata::PageIndexPolicy::Optional);
                ParquetRecordBatchReaderBuilder::try_new_with_options(bytes, options).at(path)?
            }
            _ => builder,
        };
        let mask = ProjectionMask::roots(builder.parquet_schema(), roots);
        let mut builder = builder.with_projection(mask).with_batch_size(32 * 1024);
        // Only the rows of some dimensions: the other columns are decoded for those rows only.
        if let (Some(dims), Some((i, _))) = (only_dims, arrow_schema.column_with_name(C::DIM)) {
            let projection = ProjectionMask::roots(builder.parquet_schema(), [i]);
            let predicate =
                parquet::arrow::arrow_reader::ArrowPredicateFn::new(projection, move |batch: RecordBatch| {
                    let dim = arrow::compute::cast(batch.column(0), &DataType::UInt8)?;
                    let dim = dim.as_primitive::<UInt8Type>();
                    // A mask of the wanted dimensions, tested by bit (nulls are caught later).
                    let mask = dims.iter().fold(0u8, |m, &d| m | (1 << d.min(7)));
                    let values = dim.values();
                    let keep = arrow::buffer::BooleanBuffer::collect_bool(values.len(), |i| {
                        let d = values[i];
                        d < 8 && mask & (1 << d) != 0
                    });
                    Ok(arrow::array::BooleanArray::new(keep, None))
                });
            builder = builder
                .with_row_filter(parquet::arrow::arrow_reader::RowFilter::new(vec![Box::new(predicate)]));
        }
        let batches = builder.build().at(path)?;
        Ok(CheckedTable { path: path.to_owned(), wanted, batches })
    }

    /// The next batch's columns, by name, cast to toporec's types.
    pub(super) fn next_batch(&mut self) -> Option<Result<Columns>> {
        let batch = match self.batches.next()? {
            Ok(b) => b,
            Err(e) => return Some(Err(e.at(&self.path))),
        };
        Some(self.columns(&batch).map(|c| Columns::new(self.wanted.iter().map(|w| w.name).collect(), c)))
    }

    fn columns(&self, batch: &RecordBatch) -> Result<Vec<ArrayRef>> {
        let options = arrow::compute::CastOptions { safe: false, ..Default::default() };
        let mut out = Vec::with_capacity(self.wanted.len());
        for w in &self.wanted {
            if !w.present {
                out.push(arrow::array::new_null_array(&w.data_type, batch.num_rows()));
                continue;
            }
            let column = batch.column_by_name(w.name).expect("projected");
            let column = if column.data_type() == &w.data_type {
                column.clone()
            } else {
                arrow::compute::cast_with_options(column, &w.data_type, &options)
                    .map_err(|e| Error::table(&self.path, format!("column `{}`: {e}", w.name)))?
            };
            if !w.nullable && column.null_count() > 0 {
                return Err(Error::table(&self.path, format!("column `{}` has null values", w.name)));
            }
            out.push(column);
        }
        Ok(out)
    }
}

/// The index table a file's folder names (`…/descriptors/method=m/session=s/x.parquet`:
/// `descriptors`), if any.
fn table_of_path(path: &Path) -> Option<String> {
    path.ancestors().skip(1).find_map(|dir| {
        let name = dir.file_name()?.to_str()?;
        tables::ALL.contains(&name).then(|| name.to_string())
    })
}

/// The type a `descriptor` column of `field`'s type is read as: a fixed-size list of the
/// `declared` list's items (float32, or uint8 for byte descriptors), of the stored length (or of
/// `length` for a variable-length list). Lists of floats or of integers are accepted (a byte
/// descriptor's file holds uint8).
fn descriptor_type(
    path: &Path,
    field: &Field,
    length: Option<usize>,
    declared: &DataType,
) -> Result<DataType> {
    let numbers = |t: &DataType| matches!(family(t), Family::Float | Family::Integer);
    let size = match field.data_type() {
        DataType::FixedSizeList(f, n) if numbers(f.data_type()) => *n,
        DataType::List(f) | DataType::LargeList(f) | DataType::ListView(f) | DataType::LargeListView(f)
            if numbers(f.data_type()) =>
        {
            match length {
                Some(n) => n as i32,
                None => return Err(Error::table(path, "column `descriptor` has no fixed length")),
            }
        }
        t => {
            return Err(Error::table(
                path,
                format!("column `descriptor` is {t}, expected a list of numbers"),
            ));
        }
    };
    let item = match declared {
        DataType::FixedSizeList(f, _) => f.data_type().clone(),
        _ => DataType::Float32,
    };
    Ok(DataType::FixedSizeList(Arc::new(Field::new("item", item, true)), size))
}

/// Reads the bytes of one `descriptors` file of `session`.
pub(crate) fn read_descriptors(
    path: &Path,
    bytes: Bytes,
    session: &str,
    length: Option<usize>,
) -> Result<Vec<IndexedScan>> {
    let names = [C::SCAN_ID, C::UTIME, C::POSE_X, C::POSE_Y, C::POSE_Z, C::DESCRIPTOR, C::CODEBOOK_ID];
    let mut table = CheckedTable::open(path, bytes, &schema::descriptors(1), &names, length)?;
    let mut out = Vec::new();
    while let Some(columns) = table.next_batch() {
        let c = columns?;
        let ids = c.text(C::SCAN_ID);
        let utime = c.int64(C::UTIME);
        let [x, y, z] = [C::POSE_X, C::POSE_Y, C::POSE_Z].map(|n| c.float64(n));
        let vectors = c.get(C::DESCRIPTOR).as_fixed_size_list();
        let b = vectors.value_length() as usize;
        let values = vectors.values().as_primitive::<Float32Type>();
        if vectors.null_count() > 0 || values.null_count() > 0 {
            return Err(Error::table(path, "column `descriptor` has null values"));
        }
        let codebook = c.text(C::CODEBOOK_ID);
        for i in 0..ids.len() {
            let start = i * b;
            out.push(IndexedScan {
                scan_id: ids.value(i).to_string(),
                session: session.to_string(),
                utime: utime.is_valid(i).then(|| utime.value(i)),
                // A pose with a null or non-finite coordinate (a foreign table's) is no pose.
                pose: [x, y, z]
                    .iter()
                    .all(|c| c.is_valid(i) && c.value(i).is_finite())
                    .then(|| [x.value(i), y.value(i), z.value(i)]),
                descriptor: values.values()[start..start + b].to_vec(),
                codebook_id: codebook.value(i).to_string(),
            });
        }
    }
    Ok(out)
}

/// What [`check_file`] found in a table file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct FileInfo {
    /// Rows.
    pub rows: u64,
    /// Descriptors: the codebook id of every row (an error when they differ).
    pub codebook_id: Option<String>,
}

/// `column` with `declared`'s list item field when it is a fixed-size list whose items fit it
/// (the reader's lists have nullable items; toporec writes them non-null), else unchanged.
pub(super) fn as_declared(column: ArrayRef, declared: &DataType) -> ArrayRef {
    let (Some(list), DataType::FixedSizeList(item, size)) = (column.as_fixed_size_list_opt(), declared)
    else {
        return column;
    };
    if list.value_length() != *size || column.data_type() == declared {
        return column;
    }
    arrow::array::FixedSizeListArray::try_new(
        item.clone(),
        *size,
        list.values().clone(),
        list.nulls().cloned(),
    )
    .map_or(column, |a| Arc::new(a) as ArrayRef)
}

/// The declaration of an index table (`descriptors` of `method`, of `length`).
pub(crate) fn declared(table: &str, method: Option<&str>, length: Option<usize>) -> Option<schema::Table> {
    match table {
        tables::SCANS => Some(schema::scans()),
        tables::DIAGRAMS => Some(schema::diagrams()),
        tables::DESCRIPTORS => {
            Some(schema::descriptors_for(method.unwrap_or(crate::methods::TOPOREC), length.unwrap_or(1)))
        }
        _ => None,
    }
}

/// The rows of the bytes of `path` as batches of `table`'s declared columns (its plain schema):
/// every column checked and cast as every reader does, a nullable column the file lacks (an
/// older layout's) as nulls. What compaction writes, whatever layout its inputs have.
pub(crate) fn declared_batches(path: &Path, bytes: Bytes, table: &schema::Table) -> Result<Vec<RecordBatch>> {
    let names: Vec<&'static str> = table.columns.iter().map(|c| c.name).collect();
    let length = table.column(C::DESCRIPTOR).and_then(|c| match &c.data_type {
        DataType::FixedSizeList(_, n) => Some(*n as usize),
        _ => None,
    });
    let schema = table.plain_schema();
    let mut checked = CheckedTable::open(path, bytes, table, &names, length)?;
    let mut out = Vec::new();
    while let Some(columns) = checked.next_batch() {
        let columns: Vec<ArrayRef> = columns?
            .into_arrays()
            .into_iter()
            .zip(&table.columns)
            .map(|(column, c)| as_declared(column, &c.data_type))
            .collect();
        out.push(RecordBatch::try_new(schema.clone(), columns).at(path)?);
    }
    Ok(out)
}

/// Reads a whole table file, checking every column of `table`'s schema (types, nulls).
pub(crate) fn check_file(path: &Path, table: &str, descriptor_length: Option<usize>) -> Result<FileInfo> {
    check_bytes(path, load(path)?, table, descriptor_length)
}

/// [`check_file`] on the bytes of `path`.
pub(crate) fn check_bytes(
    path: &Path,
    bytes: Bytes,
    table: &str,
    descriptor_length: Option<usize>,
) -> Result<FileInfo> {
    let schema = match table {
        tables::SCANS => schema::scans(),
        tables::DIAGRAMS => schema::diagrams(),
        tables::DESCRIPTORS => schema::descriptors(descriptor_length.unwrap_or(1)),
        other => return Err(Error::table(path, format!("`{other}` is not a table of an index"))),
    };
    let names: Vec<&'static str> = schema.columns.iter().map(|c| c.name).collect();
    let mut checked = CheckedTable::open(path, bytes, &schema, &names, descriptor_length)?;
    let mut info = FileInfo { rows: 0, codebook_id: None };
    let has_codebook = names.contains(&C::CODEBOOK_ID);
    while let Some(columns) = checked.next_batch() {
        let columns = columns?;
        info.rows += columns.len() as u64;
        if has_codebook {
            for id in columns.text(C::CODEBOOK_ID).iter().flatten() {
                match &info.codebook_id {
                    None => info.codebook_id = Some(id.to_string()),
                    Some(c) if c != id => {
                        return Err(Error::table(path, format!("rows made with codebooks {c} and {id}")));
                    }
                    _ => {}
                }
            }
        }
    }
    Ok(info)
}

/// The `scan_id` column of any table file (one entry per row).
pub fn scan_ids(path: &Path) -> Result<Vec<String>> {
    scan_ids_in(path, load(path)?)
}

/// [`scan_ids`] of the bytes of `path`.
pub(crate) fn scan_ids_in(path: &Path, bytes: Bytes) -> Result<Vec<String>> {
    let mut table =
        CheckedTable::open_any(path, bytes, &schema::diagrams(), None, &[C::SCAN_ID], None, true, None)?;
    let mut out = Vec::new();
    while let Some(columns) = table.next_batch() {
        let columns = columns?;
        let ids = ScanIds::of(columns.get(C::SCAN_ID));
        let mut last_key = -1;
        for i in 0..ids.len() {
            let (key, id) = ids.get(i);
            // A run of equal ids (a dictionary key repeated) is copied from the last one.
            let same = key >= 0 && key == last_key || out.last().is_some_and(|s: &String| s == id);
            last_key = key;
            out.push(if same { out.last().expect("same as the last").clone() } else { id.to_string() });
        }
    }
    Ok(out)
}

/// Reads one `scans` file of `session`.
pub fn read_scans(path: &Path, session: &str) -> Result<Vec<ScanRecord>> {
    read_scans_in(path, load(path)?, session)
}

/// [`read_scans`] of the bytes of `path`.
pub(crate) fn read_scans_in(path: &Path, bytes: Bytes, session: &str) -> Result<Vec<ScanRecord>> {
    let names = [
        C::SCAN_ID,
        C::FINGERPRINT,
        C::SETTINGS_HASH,
        C::SEQ,
        C::SOURCE_PATH,
        C::MESSAGE_INDEX,
        C::UTIME,
        C::POSE_X,
        C::POSE_Y,
        C::POSE_Z,
        C::POSE_YAW,
        C::RAW_POINTS,
        C::KEPT_POINTS,
        C::STATUS,
        C::ERROR,
    ];
    let mut table = CheckedTable::open(path, bytes, &schema::scans(), &names, None)?;
    let mut out = Vec::new();
    while let Some(columns) = table.next_batch() {
        let c = columns?;
        let text = |name: &str| c.text(name);
        let uint = |name: &str| c.uint64(name);
        let float = |name: &str| c.float64(name);
        let (ids, fingerprint, settings) = (text(C::SCAN_ID), text(C::FINGERPRINT), text(C::SETTINGS_HASH));
        let (seq, source, message) = (uint(C::SEQ), text(C::SOURCE_PATH), uint(C::MESSAGE_INDEX));
        let utime = c.int64(C::UTIME);
        let [x, y, z, yaw] = [C::POSE_X, C::POSE_Y, C::POSE_Z, C::POSE_YAW].map(float);
        let (raw, kept) = (uint(C::RAW_POINTS), uint(C::KEPT_POINTS));
        let (status, error) = (text(C::STATUS), text(C::ERROR));
        for i in 0..ids.len() {
            let status = Status::parse(status.value(i)).ok_or_else(|| {
                Error::table(
                    path,
                    format!("row {i}: status `{}` is not ok, skipped or error", status.value(i)),
                )
            })?;
            let pose = [x, y, z, yaw].iter().all(|c| c.is_valid(i)).then(|| Pose {
                x: x.value(i),
                y: y.value(i),
                z: z.value(i),
                yaw: yaw.value(i),
            });
            out.push(ScanRow {
                scan_id: ids.value(i).to_string(),
                fingerprint: fingerprint.is_valid(i).then(|| fingerprint.value(i).to_string()),
                settings_hash: settings.value(i).to_string(),
                session: session.to_string(),
                seq: seq.value(i),
                source_path: source.value(i).to_string(),
                message_index: message.is_valid(i).then(|| message.value(i)),
                utime: utime.is_valid(i).then(|| utime.value(i)),
                pose,
                raw_points: raw.value(i),
                kept_points: kept.value(i),
                status,
                error: error.is_valid(i).then(|| error.value(i).to_string()),
            });
        }
    }
    Ok(out)
}

/// Streams the diagrams of one `diagrams` file, one scan at a time, in file order (a
/// scan's pairs are contiguous).
pub fn diagrams(path: &Path) -> Result<DiagramStream> {
    diagrams_in(path, load(path)?, None)
}

/// As [`diagrams`], of the bytes of `path`, with only the pairs of `dims` (all of them when
/// `None`): a scan with no pair in `dims` is left out.
pub(crate) fn diagrams_in(path: &Path, bytes: Bytes, dims: Option<&[u8]>) -> Result<DiagramStream> {
    let names = [C::SCAN_ID, C::DIM, C::BIRTH, C::DEATH];
    let dims = dims.map(<[u8]>::to_vec);
    let table = CheckedTable::open_any(
        path,
        bytes,
        &schema::diagrams(),
        Some(tables::DIAGRAMS),
        &names,
        None,
        true,
        dims,
    )?;
    Ok(DiagramStream { table, current: None, ready: VecDeque::new(), done: false })
}

/// The diagrams of a file, scan by scan ([`diagrams`]).
pub struct DiagramStream {
    table: CheckedTable,
    current: Option<(String, Vec<Pair>)>,
    ready: VecDeque<(String, Diagram)>,
    done: bool,
}

/// A scan-id column, plain or dictionary-encoded.
enum ScanIds<'a> {
    Plain(&'a arrow::array::StringArray),
    Dictionary(&'a arrow::array::Int32Array, &'a arrow::array::StringArray),
}

impl<'a> ScanIds<'a> {
    fn of(column: &'a ArrayRef) -> Self {
        match column.data_type() {
            DataType::Dictionary(..) => {
                let d = column.as_dictionary::<arrow::datatypes::Int32Type>();
                ScanIds::Dictionary(d.keys(), d.values().as_string::<i32>())
            }
            _ => ScanIds::Plain(column.as_string::<i32>()),
        }
    }

    fn len(&self) -> usize {
        match self {
            ScanIds::Plain(a) => a.len(),
            ScanIds::Dictionary(k, _) => k.len(),
        }
    }

    /// The row's dictionary key (-1 for plain strings) and id.
    fn get(&self, i: usize) -> (i32, &'a str) {
        match self {
            ScanIds::Plain(a) => (-1, a.value(i)),
            ScanIds::Dictionary(k, v) => {
                let key = k.value(i);
                (key, v.value(key as usize))
            }
        }
    }
}

impl DiagramStream {
    fn add(&mut self, c: &Columns) -> Result<()> {
        let ids = ScanIds::of(c.get(C::SCAN_ID));
        let dims = c.uint8(C::DIM);
        let births = c.float64(C::BIRTH);
        let deaths = c.float64(C::DEATH);
        // With dictionary ids, the id is compared only where the key changes.
        let mut last_key = -1;
        for i in 0..ids.len() {
            let (key, id) = ids.get(i);
            if (key < 0 || key != last_key) && self.current.as_ref().is_none_or(|c| c.0 != id) {
                if let Some((id, pairs)) = self.current.take() {
                    self.ready.push_back((id, Diagram::new(pairs)));
                }
                self.current = Some((id.to_string(), Vec::new()));
            }
            last_key = key;
            let dim = dims.value(i);
            if dim > 2 {
                return Err(Error::table(&self.table.path, format!("row {i}: dim {dim} is not 0, 1 or 2")));
            }
            let pair = Pair { dim, birth: births.value(i), death: deaths.value(i) };
            self.current.as_mut().expect("set above").1.push(pair);
        }
        Ok(())
    }
}

impl Iterator for DiagramStream {
    type Item = Result<(String, Diagram)>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(d) = self.ready.pop_front() {
                return Some(Ok(d));
            }
            if self.done {
                return None;
            }
            match self.table.next_batch() {
                None => {
                    self.done = true;
                    if let Some((id, pairs)) = self.current.take() {
                        return Some(Ok((id, Diagram::new(pairs))));
                    }
                }
                Some(Err(e)) => {
                    self.done = true;
                    return Some(Err(e));
                }
                Some(Ok(columns)) => {
                    if let Err(e) = self.add(&columns) {
                        self.done = true;
                        return Some(Err(e));
                    }
                }
            }
        }
    }
}
