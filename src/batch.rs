//! Describing a batch of scans handed over in memory — the bytes of scan files, or points —
//! into the rows of an index's tables, exactly as `toporec run` makes them for that index
//! (its settings, its frozen codebook, its methods). The unit that the Python package's
//! `describe_batch` and the distributed engines (Spark `mapInArrow`, Ray `map_batches`)
//! call: batches in, Arrow record batches out, nothing written.
//!
//! A file's scan id, session, time and pose come from its path as the sources make them:
//! `<session>/velodyne_sync/<utime>.bin` (NCLT, pose joined from the session's ground-truth
//! CSV found as the NCLT source finds it) and `<sequence>/velodyne/<frame>.bin` (KITTI, time
//! and pose from the sequence's `times.txt` and `poses`). An MCAP file is handed over as a
//! range of message indices and read from its path. A scan that cannot be read or described
//! becomes an `error` (or `skipped`) row, never a failed batch.

use crate::describe::Describer;
use crate::describe::ScanResult;
use crate::error::{Error, Result, ResultExt};
use crate::pipeline::config::Pipeline;
use crate::sinks::index::partition_dir;
use crate::sinks::index::reader::IndexReader;
use crate::sinks::parquet::{DescriptorsFile, DiagramRows, DiagramsFile, descriptor_batch, scan_batch};
use crate::sinks::schema::{self, columns as C};
use crate::sources::{CloudFormat, Pose, Scan, ScanFailure};
use crate::types::Point;
use arrow::array::{ArrayRef, RecordBatch, StringArray};
use arrow::datatypes::{DataType, Field, Schema};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::collections::btree_map::Entry;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Inputs per rayon thread that [`BatchDescriber::describe_into`] describes before writing
/// their diagrams: enough to keep the threads busy, few enough to keep memory flat.
pub(crate) const STREAM_CHUNK: usize = 16;

/// One scan of a batch.
#[derive(Clone, Debug)]
pub enum ScanInput {
    /// A scan file's bytes, with the path it was read from.
    File {
        /// The file (names the scan and its session).
        path: PathBuf,
        /// Its bytes.
        bytes: Vec<u8>,
        /// Its format (`None`: from the path).
        format: Option<CloudFormat>,
    },
    /// A scan file read by the describer itself (on a file system it mounts).
    Path {
        /// The file (names the scan and its session).
        path: PathBuf,
        /// Its format (`None`: from the path).
        format: Option<CloudFormat>,
    },
    /// The scans of a message log (an MCAP file, a ROS 1 bag, a rosbag2 folder or `.db3` file)
    /// whose message index (among its point-cloud topic's messages) lies in
    /// `first..first + count`, read from it, as the pipeline's `mcap` or `rosbag` source that
    /// lists it reads it (its topic, poses, session), else with the defaults. Its
    /// position is that of the range's first scan; the others follow.
    McapRange {
        /// The log.
        path: PathBuf,
        /// The first message index.
        first: u64,
        /// How many.
        count: u64,
    },
    /// Points in the sensor frame (metres, z up).
    Points {
        /// The scan id.
        scan_id: String,
        /// Its session.
        session: String,
        /// Where it came from (the `source_path` column).
        path: PathBuf,
        /// Timestamp (µs).
        utime: Option<i64>,
        /// Ground-truth pose.
        pose: Option<Pose>,
        /// The points.
        points: Vec<Point>,
    },
}

/// A batch's rows: `scans`, `diagrams` and each method's `descriptors`, in the index's
/// schemas with the `session` partition column appended.
#[derive(Clone, Debug)]
pub struct BatchOutput {
    /// One row per scan.
    pub scans: RecordBatch,
    /// One row per persistence pair of the ok scans.
    pub diagrams: RecordBatch,
    /// Per method (TopoRec first, then the computed ones): one row per ok scan.
    pub descriptors: Vec<(String, RecordBatch)>,
}

/// Describes batches of scans for one index (see the module doc).
pub struct BatchDescriber {
    describer: Describer,
    settings: String,
    dims: Vec<u8>,
    codebook_id: Option<String>,
    computed: Vec<(String, String)>,
    /// The index's sources, reading a batch's scan files and logs as they read them.
    rereader: crate::sources::reread::Rereader,
}

impl BatchDescriber {
    /// A describer with `index`'s settings, frozen codebook and methods. The index must have
    /// its codebook when it holds TopoRec descriptors (`toporec fit` or a first `toporec run`
    /// makes it).
    pub fn from_index(index: &Path) -> Result<Self> {
        let reader = IndexReader::open(index)?;
        let manifest = reader
            .manifest()
            .ok_or_else(|| Error::index(index, "no manifest: not an index `toporec run` wrote"))?;
        let settings = manifest.settings_hash.clone();
        let pipeline = Pipeline::of_index(index).map_err(|e| Error::index(index, e.to_string()))?;
        let codebook = if pipeline.methods.toporec {
            Some(manifest.codebook(index)?.ok_or_else(|| {
                Error::index(index, "no codebook yet: fit one first (`toporec fit` or `toporec run`)")
            })?)
        } else {
            None
        };
        let describer = Describer {
            preprocess: pipeline.preprocess.clone(),
            squared: pipeline.persistence.squared,
            codebook,
            topological: pipeline.methods.toporec,
            computed: pipeline.methods.computed.clone(),
        };
        Ok(BatchDescriber {
            settings,
            dims: pipeline.persistence.dims.clone(),
            codebook_id: describer.codebook.as_ref().map(|c| c.id()),
            computed: describer.computed_ids(),
            describer,
            rereader: crate::sources::reread::Rereader::new(&pipeline.sources),
        })
    }

    /// The descriptor methods and their lengths, in output order.
    pub fn methods(&self) -> Vec<(String, usize)> {
        let mut out = Vec::new();
        if let Some(cb) = &self.describer.codebook {
            out.push((crate::methods::TOPOREC.to_string(), cb.len()));
        }
        out.extend(self.describer.computed.iter().map(|m| (m.name.clone(), m.len())));
        out
    }

    /// Describes `inputs`, each with its position in the job's input (the `seq` column), on
    /// rayon's threads.
    pub fn describe(&self, inputs: Vec<(u64, ScanInput)>) -> Result<BatchOutput> {
        let results = self.results(inputs);
        self.output(&results)
    }

    /// Every scan of `inputs`, read and described on rayon's threads, in input order.
    fn results(&self, inputs: Vec<(u64, ScanInput)>) -> Vec<ScanResult> {
        let scans: Vec<(u64, std::result::Result<Scan, ScanFailure>)> = inputs
            .into_par_iter()
            .flat_map_iter(|(position, input)| match input {
                ScanInput::McapRange { path, first, count } => self.mcap_range(&path, first, count, position),
                other => vec![(position, self.scan(other))],
            })
            .collect();
        scans
            .into_par_iter()
            .map(|(position, scan)| self.describer.scan_rows(scan, position, &self.settings))
            .collect()
    }

    /// The scans of an MCAP message range (see [`ScanInput::McapRange`]) with their positions.
    fn mcap_range(
        &self,
        path: &Path,
        first: u64,
        count: u64,
        position: u64,
    ) -> Vec<(u64, std::result::Result<Scan, ScanFailure>)> {
        let end = first.saturating_add(count);
        match self.rereader.log_range(path, first..end) {
            Ok(stream) => stream
                .map(|item| {
                    let index = match &item {
                        Ok(s) => s.message_index,
                        Err(f) => f.message_index,
                    };
                    (position + index.map_or(0, |i| i.saturating_sub(first)), item)
                })
                .collect(),
            Err(e) => {
                let session = crate::sources::logs::default_session(path);
                let id = format!("{session}/messages_{first}-{end}");
                vec![(position, Err(ScanFailure::of_file(id, &session, path, None, e.to_string())))]
            }
        }
    }

    /// Like [`BatchDescriber::describe`], but the diagrams and the descriptors are written,
    /// not returned: one file per table (each method's descriptors a table) and session of
    /// the batch, `folder/diagrams/session=<s>/<name>.parquet` and
    /// `folder/descriptors/method=<m>/session=<s>/<name>.parquet`, by toporec's own writer (its
    /// layout, page sizes and file metadata), each appearing only once complete. The same
    /// `name` again (a retried task) replaces the files. The returned batches hold the scans
    /// only (`diagrams` and `descriptors` empty). A distributed job's tasks call this: the
    /// rows go straight from the engine to Parquet, and the engine is left with one row a scan.
    ///
    /// The inputs are described a few at a time (`STREAM_CHUNK` per thread) and their rows
    /// written before the next ones are read, so a task's memory does not grow with its size
    /// (a scan's diagram is about a megabyte in memory; growing the heap by hundreds of them
    /// cost a fresh worker process a fifth of a batch's time).
    pub fn describe_into(
        &self,
        inputs: Vec<(u64, ScanInput)>,
        folder: &Path,
        name: &str,
    ) -> Result<BatchOutput> {
        let chunk = STREAM_CHUNK * rayon::current_num_threads().max(1);
        let path = |table: &str, method: Option<&str>, session: &str| {
            folder.join(partition_dir(table, method, session)).join(format!("{name}.parquet"))
        };
        let mut diagram_files: BTreeMap<String, DiagramsFile> = BTreeMap::new();
        let mut descriptor_files: BTreeMap<(String, String), DescriptorsFile> = BTreeMap::new();
        let mut results = Vec::with_capacity(inputs.len());
        let mut inputs = inputs.into_iter().peekable();
        while inputs.peek().is_some() {
            let mut described = self.results(inputs.by_ref().take(chunk).collect());
            for r in &mut described {
                let session = r.row.session.as_str();
                if let Some(diagram) = r.diagram.take() {
                    let file = open_file(&mut diagram_files, session.to_owned(), || {
                        DiagramsFile::create(&path(schema::tables::DIAGRAMS, None, session))
                    })?;
                    file.push(&r.row.scan_id, &diagram, &self.dims)?;
                }
                for d in r.method_descriptors(self.codebook_id.as_deref(), &self.computed) {
                    let key = (d.method.clone(), session.to_owned());
                    let file = open_file(&mut descriptor_files, key, || {
                        let at = path(schema::tables::DESCRIPTORS, Some(&d.method), session);
                        DescriptorsFile::create(&at, &d.method, d.row.values.len(), &d.id)
                    })?;
                    file.push(d.row)?;
                }
                r.descriptor = None;
                r.baselines.clear();
            }
            results.append(&mut described);
        }
        for file in diagram_files.into_values() {
            file.finish()?.0.publish()?;
        }
        for file in descriptor_files.into_values() {
            file.finish()?.0.publish()?;
        }
        self.output(&results)
    }

    /// The scan of one input, as the sources would make it.
    #[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
    fn scan(&self, input: ScanInput) -> std::result::Result<Scan, ScanFailure> {
        let (path, bytes, format) = match input {
            ScanInput::Points { scan_id, session, path, utime, pose, points } => {
                let scan = Scan::of_points(scan_id, session, path, points);
                let no_pose = pose.is_none().then_some(crate::sources::NoPose::NoGroundTruth);
                return Ok(Scan { utime, pose, no_pose, ..scan });
            }
            ScanInput::File { path, bytes, format } => (path, bytes, format),
            ScanInput::Path { path, format } => match std::fs::read(&path) {
                Ok(bytes) => (path, bytes, format),
                Err(e) => {
                    let error = format!("{}: cannot read: {e}", path.display());
                    return Err(crate::sources::reread::unreadable(&path, error));
                }
            },
            ScanInput::McapRange { path, first, .. } => {
                return Err(ScanFailure::of_file(
                    format!("{}/{first}", path.display()),
                    "",
                    &path,
                    None,
                    "an MCAP range is read by BatchDescriber::describe".into(),
                ));
            }
        };
        self.rereader.file(&path, &bytes, format)
    }

    /// The output batches of described scans (the diagrams and descriptors they still hold).
    fn output(&self, results: &[ScanResult]) -> Result<BatchOutput> {
        let here = Path::new("describe_batch");
        let sessions = |ids: Vec<&str>| -> ArrayRef { Arc::new(StringArray::from(ids)) };
        // A table's batch with the Hive partition column `session` appended.
        let with_session = |batch: std::result::Result<RecordBatch, arrow::error::ArrowError>,
                            session: ArrayRef| {
            let batch = batch.at(here)?;
            let mut fields: Vec<Field> = batch.schema().fields().iter().map(|f| (**f).clone()).collect();
            fields.push(Field::new(C::SESSION, DataType::Utf8, false));
            let mut columns = batch.columns().to_vec();
            columns.push(session);
            RecordBatch::try_new(Arc::new(Schema::new(fields)), columns).at(here)
        };
        let rows: Vec<_> = results.iter().map(|r| r.row.clone()).collect();
        let scans = with_session(
            scan_batch(&rows, schema::scans().plain_schema()),
            sessions(rows.iter().map(|r| r.session.as_str()).collect()),
        )?;
        let mut diagram_rows = DiagramRows::new(schema::diagrams().plain_schema());
        let mut diagram_sessions = Vec::new();
        for r in results {
            if let Some(d) = &r.diagram {
                let n = diagram_rows.push(&r.row.scan_id, d, &self.dims);
                diagram_sessions.extend(std::iter::repeat_n(r.row.session.as_str(), n));
            }
        }
        let diagrams = with_session(diagram_rows.finish(), sessions(diagram_sessions))?;
        let mut per_method: Vec<(String, usize, String, Vec<_>, Vec<&str>)> = Vec::new();
        if let Some(cb) = &self.describer.codebook {
            let id = self.codebook_id.clone().unwrap_or_default();
            per_method.push((crate::methods::TOPOREC.into(), cb.len(), id, Vec::new(), Vec::new()));
        }
        for (m, (name, id)) in self.describer.computed.iter().zip(&self.computed) {
            per_method.push((name.clone(), m.len(), id.clone(), Vec::new(), Vec::new()));
        }
        for r in results {
            for d in r.method_descriptors(self.codebook_id.as_deref(), &self.computed) {
                if let Some(entry) = per_method.iter_mut().find(|e| e.0 == d.method) {
                    entry.3.push(d.row);
                    entry.4.push(r.row.session.as_str());
                }
            }
        }
        let mut descriptors = Vec::new();
        for (name, length, id, rows, row_sessions) in per_method {
            let table = schema::descriptors_for(&name, length).plain_schema();
            let batch = descriptor_batch(&rows, &name, length, &id, table);
            descriptors.push((name, with_session(batch, sessions(row_sessions))?));
        }
        Ok(BatchOutput { scans, diagrams, descriptors })
    }
}

/// The scans of one input batch (the `batch_inputs` table, [`schema::batch_inputs`]), each
/// with its position (its `seq`, else `offset` + its row); an error naming the column or the
/// row for a batch that does not follow the table.
pub fn inputs_of(b: &RecordBatch, offset: u64) -> std::result::Result<Vec<(u64, ScanInput)>, String> {
    use arrow::array::{Array, AsArray};
    use arrow::datatypes::{Float64Type, Int64Type, UInt64Type};
    let table = schema::batch_inputs();
    for column in &table.columns {
        // A list's item may be named anything (pyarrow: item, Spark and Polars: element).
        let same = |a: &DataType, b: &DataType| match (a, b) {
            (DataType::List(x), DataType::List(y)) => x.data_type() == y.data_type(),
            _ => a == b,
        };
        if let Some(found) = b.column_by_name(column.name)
            && !same(found.data_type(), &column.data_type)
        {
            return Err(format!(
                "column `{}`: expected {}, found {}",
                column.name,
                column.data_type,
                found.data_type()
            ));
        }
    }
    let column = |name: &str| b.column_by_name(name);
    let strings = |name: &str| column(name).map(|c| c.as_string::<i32>().clone());
    let floats = |name: &str| column(name).map(|c| c.as_primitive::<Float64Type>().clone());
    let counts = |name: &str| column(name).map(|c| c.as_primitive::<UInt64Type>().clone());
    let paths = strings("path").ok_or("the batch has no `path` column")?;
    let (formats, ids, sessions) = (strings("format"), strings(C::SCAN_ID), strings(C::SESSION));
    let seqs = counts(C::SEQ);
    let utimes = column(C::UTIME).map(|c| c.as_primitive::<Int64Type>().clone());
    let pose = [C::POSE_X, C::POSE_Y, C::POSE_Z, C::POSE_YAW].map(floats);
    let content = column("content").map(|c| c.as_binary::<i32>().clone());
    let points = column("points").map(|c| c.as_list::<i32>().clone());
    let ranges = (counts("first_message"), counts("message_count"));
    let get = |a: &Option<arrow::array::StringArray>, i: usize| {
        a.as_ref().filter(|a| a.is_valid(i)).map(|a| a.value(i).to_string())
    };
    let value = |a: &Option<arrow::array::UInt64Array>, i: usize| {
        a.as_ref().filter(|a| a.is_valid(i)).map(|a| a.value(i))
    };
    let file_format = |i: usize| -> std::result::Result<Option<CloudFormat>, String> {
        match get(&formats, i) {
            None => Ok(None),
            Some(f) => CloudFormat::parse(if f == "velodyne_sync" { "nclt" } else { &f })
                .filter(|f| matches!(f, CloudFormat::Nclt | CloudFormat::Kitti))
                .map(Some)
                .ok_or_else(|| format!("row {i}: format {f:?}: expected nclt, kitti or mcap")),
        }
    };
    let mut out = Vec::with_capacity(b.num_rows());
    for i in 0..b.num_rows() {
        let seq = value(&seqs, i).unwrap_or(offset + i as u64);
        let path = PathBuf::from(paths.value(i));
        let input = match (&content, &points) {
            _ if get(&formats, i).as_deref() == Some("mcap") => {
                let (Some(first), Some(count)) = (value(&ranges.0, i), value(&ranges.1, i)) else {
                    return Err(format!("row {i}: an mcap row needs `first_message` and `message_count`"));
                };
                ScanInput::McapRange { path, first, count }
            }
            (Some(c), _) if c.is_valid(i) => {
                ScanInput::File { path, bytes: c.value(i).to_vec(), format: file_format(i)? }
            }
            (_, Some(p)) if p.is_valid(i) => {
                let values = p.value(i);
                let values = values.as_primitive::<Float64Type>();
                if values.len() % 3 != 0 {
                    return Err(format!("row {i}: {} point values, not a multiple of 3", values.len()));
                }
                let pts = values.values().chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
                let scan_id = get(&ids, i).ok_or_else(|| format!("row {i}: points need a `scan_id`"))?;
                let session = get(&sessions, i)
                    .unwrap_or_else(|| scan_id.split('/').next().unwrap_or_default().to_string());
                let at = |k: usize| pose[k].as_ref().filter(|a| a.is_valid(i)).map(|a| a.value(i));
                let pose = match (at(0), at(1), at(2)) {
                    (Some(x), Some(y), Some(z)) => Some(Pose { x, y, z, yaw: at(3).unwrap_or(0.0) }),
                    _ => None,
                };
                let utime = utimes.as_ref().filter(|a| a.is_valid(i)).map(|a| a.value(i));
                ScanInput::Points { scan_id, session, path, utime, pose, points: pts }
            }
            // Neither bytes nor points: the describer reads the file.
            _ => ScanInput::Path { path, format: file_format(i)? },
        };
        out.push((seq, input));
    }
    Ok(out)
}

/// The session folder of a scan file (`<session>/velodyne_sync/<utime>.bin`,
/// The open file under `key`, made by `create` at its first use.
fn open_file<K: Ord, T>(
    files: &mut BTreeMap<K, T>,
    key: K,
    create: impl FnOnce() -> Result<T>,
) -> Result<&mut T> {
    Ok(match files.entry(key) {
        Entry::Occupied(e) => e.into_mut(),
        Entry::Vacant(e) => e.insert(create()?),
    })
}
