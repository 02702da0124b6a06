//! `toporec._toporec`: the Python bindings of toporec's Rust core. The package `toporec`
//! (python/toporec/) wraps these functions in its public API; nothing here is meant to be
//! called directly.
//!
//! Conventions: the GIL is released around every computation (`Python::detach`), batch calls
//! run on rayon's threads, bad input raises `ValueError` with toporec's message, and Arrow
//! data crosses the boundary through the Arrow C stream interface (PyCapsules named
//! `arrow_array_stream`), without copies.

use arrow::array::{RecordBatch, RecordBatchIterator, RecordBatchReader};
use arrow::datatypes::SchemaRef;
use arrow::ffi_stream::{FFI_ArrowArrayStream, RecordBatchStreamReader};
use numpy::ndarray::{Array1, Array2};
use numpy::{IntoPyArray, PyArray2};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyCapsule, PyCapsuleMethods, PyDict};
use std::path::PathBuf;
use std::sync::Arc;

mod persistence;
mod search;

use persistence::*;
use search::*;

/// The engine allocates and frees large buffers on every call; mimalloc keeps them warm between
/// calls where the system allocator in a Python process returns them to the OS each time.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// mimalloc's `mi_option_purge_delay` (mimalloc.h, v3): how long freed memory stays committed.
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Freed memory stays with the process (mimalloc's default returns it to the OS after 10 ms):
/// the engine's buffers are megabytes a scan, freed and allocated again scan after scan, and
/// each return made a later scan fault its pages in again, zero-filled by the kernel (~7 % of
/// a batch's time, measured). Like the system allocator's heap, the memory is reused, not
/// returned. `MIMALLOC_PURGE_DELAY` in the environment wins.
fn keep_freed_memory_warm() {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_some() {
        return;
    }
    // SAFETY: setting an option is allowed at any time; it takes a plain integer.
    unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1) };
}

const STREAM: &std::ffi::CStr = c"arrow_array_stream";

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// toporec's errors: input/output problems as `OSError`, the rest as `ValueError`.
fn toporec_error(e: toporec::Error) -> PyErr {
    match e {
        toporec::Error::Io { .. } => PyOSError::new_err(e.to_string()),
        other => PyValueError::new_err(other.to_string()),
    }
}

/// Runs a pipeline file; returns the run summary as JSON text.
#[pyfunction]
#[pyo3(signature = (pipeline, threads, index, full))]
fn run(
    py: Python<'_>,
    pipeline: PathBuf,
    threads: usize,
    index: Option<PathBuf>,
    full: bool,
) -> PyResult<String> {
    let p = toporec::Pipeline::load(&pipeline).map_err(value_error)?;
    let mut opts = toporec::RunOptions::new(threads.max(1));
    opts.progress = false;
    opts.index = index;
    opts.full = full;
    let summary = py.detach(|| toporec::pipeline::run(&p, &opts)).map_err(toporec_error)?;
    Ok(summary.to_json().to_string())
}

/// `toporec fit --pipeline`: fits the pipeline's codebook on a hash sample of its scans and
/// freezes it in `index`; returns the codebook id and the number of scans fitted on.
#[pyfunction]
#[pyo3(signature = (pipeline, index, fraction, threads))]
fn fit_sample(
    py: Python<'_>,
    pipeline: PathBuf,
    index: Option<PathBuf>,
    fraction: f64,
    threads: usize,
) -> PyResult<(String, u64)> {
    let p = toporec::Pipeline::load(&pipeline).map_err(value_error)?;
    let index = index.unwrap_or_else(|| p.index.clone());
    let (codebook, scans) = py
        .detach(|| toporec::pipeline::shard::fit_sample(&p, &index, fraction, threads))
        .map_err(toporec_error)?;
    Ok((codebook.id(), scans))
}

/// The number of scans of an MCAP file and its point-cloud topic (`topic`, or the file's
/// only one): a pass that decodes no cloud.
#[pyfunction]
#[pyo3(signature = (path, topic=None))]
fn mcap_scan_count(py: Python<'_>, path: PathBuf, topic: Option<String>) -> PyResult<(String, u64)> {
    py.detach(|| toporec::sources::logs::count_scans(&path, topic.as_deref()))
        .map_err(|e| value_error(e.to_string()))
}

/// `toporec loops <source>…` with these command-line arguments (after `loops`); returns its
/// summary and the maps' corrected poses (the `corrected_poses` table), the written loops
/// table's path left to the caller to read.
#[pyfunction]
fn loops(py: Python<'_>, args: Vec<String>, threads: usize) -> PyResult<(String, ArrowStream)> {
    #[derive(clap::Parser)]
    struct Loops {
        #[command(flatten)]
        args: toporec::loops::LoopsArgs,
    }
    let parsed = <Loops as clap::Parser>::try_parse_from(std::iter::once("loops".to_string()).chain(args))
        .map_err(|e| value_error(e.to_string().trim()))?;
    let done = py.detach(|| toporec::loops::run(&parsed.args, threads.max(1))).map_err(toporec_error)?;
    let poses = toporec::loops::map::corrected_batch(&done.loops.maps);
    Ok((done.to_string(), ArrowStream::new(poses.schema(), vec![poses])))
}

/// `toporec optimize GRAPH.g2o [-o OUT]`: the graph optimized (written to `out` when given);
/// returns the summary as JSON and each vertex's id and optimized values.
#[pyfunction]
#[pyo3(signature = (graph, out, robust, max_iterations, start))]
fn optimize(
    py: Python<'_>,
    graph: PathBuf,
    out: Option<PathBuf>,
    robust: bool,
    max_iterations: usize,
    start: &str,
) -> PyResult<(String, Vec<i64>, Vec<Vec<f64>>)> {
    // The command line's own names (`--start file|chordal`).
    use clap::ValueEnum;
    let start = toporec::map::Start::from_str(start, false).map_err(|_| {
        let names: Vec<String> = toporec::map::Start::value_variants()
            .iter()
            .filter_map(|v| v.to_possible_value().map(|p| p.get_name().to_string()))
            .collect();
        value_error(format!("start: {start:?} is none of {}", names.join(", ")))
    })?;
    let done = py
        .detach(|| toporec::map::optimize_graph(&graph, out.as_deref(), robust, max_iterations.max(1), start))
        .map_err(toporec_error)?;
    let summary = serde_json::json!({
        "kind": done.kind,
        "vertices": done.size.0,
        "edges": done.size.1,
        "held": done.size.2,
        "cost_before": done.costs.0,
        "cost_after": done.costs.1,
        "cost_start": done.start_cost,
        "iterations": done.iterations,
        "rejected": done.rejected,
        "seconds": done.seconds,
    });
    let (ids, values) = done.vertices.into_iter().unzip();
    Ok((summary.to_string(), ids, values))
}

/// Merges table files written by another tool in the index's layout under `folder` (a Spark
/// job's output) into `index`, in one commit under the index's lock; returns the scans taken in.
#[pyfunction]
fn merge_written(py: Python<'_>, index: PathBuf, folder: PathBuf) -> PyResult<u64> {
    py.detach(|| -> toporec::Result<u64> {
        let manifest = toporec::sinks::index::manifest::Manifest::load(
            &index.join(toporec::sinks::index::MANIFEST_FILE),
        )?
        .ok_or_else(|| {
            toporec::Error::index(&index, "no manifest: fit its codebook first (`toporec fit --pipeline`)")
        })?;
        let mut writer = toporec::IndexWriter::open_waiting(&index, &manifest.settings_hash)?;
        let taken = writer.absorb(&folder)?;
        writer.commit()?;
        Ok(taken)
    })
    .map_err(toporec_error)
}

/// Record batches handed to Python through the Arrow C stream interface
/// (`__arrow_c_stream__`): pyarrow, Polars and DuckDB read it without a copy.
#[pyclass(module = "toporec._toporec")]
struct ArrowStream {
    content: Option<(SchemaRef, Vec<RecordBatch>)>,
}

impl ArrowStream {
    fn new(schema: SchemaRef, batches: Vec<RecordBatch>) -> Self {
        ArrowStream { content: Some((schema, batches)) }
    }
}

#[pymethods]
impl ArrowStream {
    /// The stream as a PyCapsule (consumed: a stream is read once).
    #[pyo3(signature = (requested_schema=None))]
    fn __arrow_c_stream__<'py>(
        &mut self,
        py: Python<'py>,
        requested_schema: Option<Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyCapsule>> {
        let _ = requested_schema;
        let (schema, batches) =
            self.content.take().ok_or_else(|| value_error("this Arrow stream was already consumed"))?;
        let reader = RecordBatchIterator::new(batches.into_iter().map(Ok), schema);
        let stream = FFI_ArrowArrayStream::new(Box::new(reader));
        PyCapsule::new_with_value(py, stream, STREAM)
    }
}

/// Reads an Arrow C stream capsule (from `__arrow_c_stream__`) into record batches.
fn import_stream(capsule: &Bound<'_, PyCapsule>) -> PyResult<(SchemaRef, Vec<RecordBatch>)> {
    let ptr = capsule.pointer_checked(Some(STREAM))?;
    // SAFETY: a capsule named `arrow_array_stream` holds an `ArrowArrayStream` (Arrow PyCapsule
    // interface); `from_raw` moves it out and marks the original released.
    let stream = unsafe { FFI_ArrowArrayStream::from_raw(ptr.as_ptr().cast()) };
    let reader = RecordBatchStreamReader::try_new(stream).map_err(value_error)?;
    let schema = reader.schema();
    let batches = reader.collect::<Result<Vec<_>, _>>().map_err(value_error)?;
    Ok((schema, batches))
}

/// A table of an index as an Arrow stream (toporec's schema and `session`).
#[pyfunction]
#[pyo3(signature = (index, table, method))]
fn index_table(py: Python<'_>, index: PathBuf, table: &str, method: Option<String>) -> PyResult<ArrowStream> {
    let (schema, batches) = py
        .detach(|| {
            toporec::IndexReader::read_consistent(&index, |reader| reader.table(table, method.as_deref()))
        })
        .map_err(toporec_error)?;
    Ok(ArrowStream::new(schema, batches))
}

/// The descriptor methods an index holds.
#[pyfunction]
fn index_methods(py: Python<'_>, index: PathBuf) -> PyResult<Vec<String>> {
    py.detach(|| toporec::IndexReader::open(&index)?.methods()).map_err(toporec_error)
}

/// What an index holds (`toporec info --json`), as JSON text.
#[pyfunction]
fn index_info(py: Python<'_>, index: PathBuf) -> PyResult<String> {
    let info = py.detach(|| toporec::info::info(&index)).map_err(toporec_error)?;
    serde_json::to_string(&info).map_err(value_error)
}

/// The committed files of one generation of an index (`toporec info --files`).
#[pyfunction]
#[pyo3(signature = (index, table, method))]
fn index_files(
    py: Python<'_>,
    index: PathBuf,
    table: Option<String>,
    method: Option<String>,
) -> PyResult<Vec<PathBuf>> {
    py.detach(|| toporec::info::files(&index, table.as_deref(), method.as_deref())).map_err(toporec_error)
}

/// The points of one scan file (KITTI `.bin`, NCLT `velodyne_sync` `.bin`, `.csv`), in the
/// sensor frame as toporec's sources read them.
#[pyfunction]
fn read_points<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let points =
        py.detach(|| toporec::sources::read_cloud(&path, None)).map_err(|e| value_error(e.to_string()))?;
    let flat: Vec<f64> = points.iter().flatten().copied().collect();
    Ok(Array2::from_shape_vec((points.len(), 3), flat).expect("n × 3 values").into_pyarray(py))
}

/// The scans of a source path (a bag, a rosbag2 folder, an MCAP, an NCLT session, a KITTI
/// sequence), read one at a time as a run reads them; a scan that cannot be read is a dict with
/// `error`.
#[pyclass(module = "toporec._toporec")]
struct ScanReader {
    stream: std::sync::Mutex<toporec::sources::ScanStream>,
}

#[pymethods]
impl ScanReader {
    #[new]
    #[pyo3(signature = (path, topic=None))]
    fn new(py: Python<'_>, path: PathBuf, topic: Option<String>) -> PyResult<Self> {
        let stream = py
            .detach(|| -> Result<toporec::sources::ScanStream, toporec::sources::SourceError> {
                let input = toporec::sources::Input::detect(&path)?;
                match input.source(topic.as_deref()) {
                    Some(spec) => spec.open(),
                    None => Err(toporec::sources::SourceError::invalid(
                        &path,
                        "a single cloud file: read it with read_points",
                    )),
                }
            })
            .map_err(|e| value_error(e.to_string()))?;
        Ok(ScanReader { stream: std::sync::Mutex::new(stream) })
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let item = py.detach(|| match self.stream.lock() {
            Ok(mut s) => Ok(s.next()),
            Err(_) => Err("the reader failed in another thread"),
        });
        let Some(item) = item.map_err(value_error)? else {
            return Ok(None);
        };
        let out = PyDict::new(py);
        match item {
            Ok(scan) => {
                out.set_item("scan_id", &scan.id)?;
                out.set_item("session", &scan.session)?;
                out.set_item("path", scan.path.to_string_lossy().into_owned())?;
                out.set_item("utime", scan.utime)?;
                out.set_item("message_index", scan.message_index)?;
                let flat: Vec<f64> = scan.points.iter().flatten().copied().collect();
                let points = Array2::from_shape_vec((scan.points.len(), 3), flat).expect("n × 3 values");
                out.set_item("points", points.into_pyarray(py))?;
                out.set_item("intensity", scan.intensity.map(|v| Array1::from_vec(v).into_pyarray(py)))?;
                out.set_item("pose", scan.pose.map(|p| (p.x, p.y, p.z, p.yaw)))?;
            }
            Err(f) => {
                out.set_item("scan_id", &f.id)?;
                out.set_item("session", &f.session)?;
                out.set_item("path", f.path.to_string_lossy().into_owned())?;
                out.set_item("utime", f.utime)?;
                out.set_item("message_index", f.message_index)?;
                out.set_item("error", &f.error)?;
            }
        }
        Ok(Some(out))
    }
}

/// Describes batches of scans for one index (`toporec.describe_batch`).
#[pyclass(module = "toporec._toporec")]
struct BatchDescriber {
    inner: Arc<toporec::BatchDescriber>,
}

#[pymethods]
impl BatchDescriber {
    #[new]
    fn new(py: Python<'_>, index: PathBuf) -> PyResult<Self> {
        let inner = py.detach(|| toporec::BatchDescriber::from_index(&index)).map_err(toporec_error)?;
        Ok(BatchDescriber { inner: Arc::new(inner) })
    }

    /// The methods and descriptor lengths, in output order.
    fn methods(&self) -> Vec<(String, usize)> {
        self.inner.methods()
    }

    /// Describes the scans of an Arrow stream (normalized by the Python side: `path` utf8;
    /// `content` binary or `points` list<float64>, or neither (the file is read from `path`);
    /// optional `format`, `scan_id`, `session` utf8, `seq` uint64, `utime` int64,
    /// `pose_x/y/z/yaw` float64). With `write_to` (a folder, and a file name), the diagrams
    /// and descriptors are written there instead of returned.
    #[allow(clippy::type_complexity)]
    #[pyo3(signature = (stream, write_to=None))]
    fn describe(
        &self,
        py: Python<'_>,
        stream: Bound<'_, PyCapsule>,
        write_to: Option<(PathBuf, String)>,
    ) -> PyResult<(ArrowStream, ArrowStream, Vec<(String, ArrowStream)>)> {
        let (_, batches) = import_stream(&stream)?;
        let inner = self.inner.clone();
        let out = py.detach(move || -> PyResult<toporec::BatchOutput> {
            let mut inputs = Vec::new();
            for b in &batches {
                inputs.extend(toporec::batch::inputs_of(b, inputs.len() as u64).map_err(value_error)?);
            }
            match &write_to {
                Some((folder, name)) => inner.describe_into(inputs, folder, name),
                None => inner.describe(inputs),
            }
            .map_err(toporec_error)
        })?;
        let stream = |b: RecordBatch| ArrowStream::new(b.schema(), vec![b]);
        Ok((
            stream(out.scans),
            stream(out.diagrams),
            out.descriptors.into_iter().map(|(m, b)| (m, stream(b))).collect(),
        ))
    }
}

/// The schema of the batches `describe_batch` takes (the `batch_inputs` table), as an empty
/// Arrow stream.
#[pyfunction]
fn batch_input_schema() -> ArrowStream {
    ArrowStream::new(toporec::sinks::schema::batch_inputs().plain_schema(), Vec::new())
}

/// The names of the methods computed from raw scans, in the registry's order.
#[pyfunction]
fn computed_methods() -> Vec<&'static str> {
    toporec::methods::computed_names()
}

/// The declared schema of a table toporec writes (`scans`, `diagrams`, `descriptors`, `query`,
/// `loops`): the one declaration the Spark job builds its rows from.
#[pyfunction]
fn table_schema(name: &str) -> PyResult<ArrowStream> {
    let table = toporec::sinks::schema::all()
        .into_iter()
        .find(|t| t.name == name)
        .ok_or_else(|| value_error(format!("no table `{name}`")))?;
    Ok(ArrowStream::new(table.plain_schema(), Vec::new()))
}

#[pymodule]
fn _toporec(m: &Bound<'_, PyModule>) -> PyResult<()> {
    keep_freed_memory_warm();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(alpha_persistence, m)?)?;
    m.add_function(wrap_pyfunction!(alpha_persistence_batch, m)?)?;
    m.add_function(wrap_pyfunction!(alpha_persistence_located, m)?)?;
    m.add_function(wrap_pyfunction!(alpha_persistence_timed, m)?)?;
    m.add_function(wrap_pyfunction!(simplex_counts, m)?)?;
    m.add_function(wrap_pyfunction!(atol_fit, m)?)?;
    m.add_function(wrap_pyfunction!(atol_transform, m)?)?;
    m.add_function(wrap_pyfunction!(codebook_save, m)?)?;
    m.add_function(wrap_pyfunction!(codebook_load, m)?)?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(fit_sample, m)?)?;
    m.add_function(wrap_pyfunction!(merge_written, m)?)?;
    m.add_function(wrap_pyfunction!(loops, m)?)?;
    m.add_function(wrap_pyfunction!(optimize, m)?)?;
    m.add_function(wrap_pyfunction!(mcap_scan_count, m)?)?;
    m.add_function(wrap_pyfunction!(index_table, m)?)?;
    m.add_function(wrap_pyfunction!(index_methods, m)?)?;
    m.add_function(wrap_pyfunction!(index_info, m)?)?;
    m.add_function(wrap_pyfunction!(index_files, m)?)?;
    m.add_class::<ArrowStream>()?;
    m.add_class::<QueryEngine>()?;
    m.add_class::<LoopDetector>()?;
    m.add_class::<ScanReader>()?;
    m.add_function(wrap_pyfunction!(read_points, m)?)?;
    m.add_class::<BatchDescriber>()?;
    m.add_function(wrap_pyfunction!(batch_input_schema, m)?)?;
    m.add_function(wrap_pyfunction!(table_schema, m)?)?;
    m.add_function(wrap_pyfunction!(computed_methods, m)?)?;
    Ok(())
}
