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
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyCapsule, PyCapsuleMethods, PyDict};
use rayon::prelude::*;
use std::path::PathBuf;
use std::sync::Arc;
use toporec::homology::{Diagram, alpha_persistence as engine_persistence};
use toporec::vectorize::atol::{Atol, Contrast, Weighting};
use toporec::vectorize::codebook::{Codebook, CodebookPart, CodebookSpec, DimSelection};
use toporec::vectorize::kmeans::{Algorithm, KMeansParams};

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

/// The rows of a float64 `(n, 3)` array (any other shape is an error naming `what`).
fn points_of(points: &PyReadonlyArray2<f64>, what: &str) -> PyResult<Vec<[f64; 3]>> {
    let a = points.as_array();
    if a.ncols() != 3 {
        return Err(value_error(format!(
            "{what}: expected an (n, 3) array of points, got shape {:?}",
            a.shape()
        )));
    }
    Ok(match a.as_slice() {
        // C-contiguous (what the package passes): one pass over the buffer.
        Some(flat) => flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        None => a.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect(),
    })
}

/// The rows of a float64 `(n, 3)` array, checked: finite, at least 4 points.
fn cloud(points: &PyReadonlyArray2<f64>, what: &str) -> PyResult<Vec<[f64; 3]>> {
    let n = points.as_array().nrows();
    let rows = points_of(points, what)?;
    if n < 4 {
        return Err(value_error(format!("{what}: {n} points; the 3D alpha complex needs at least 4")));
    }
    if let Some((i, p)) = rows.iter().enumerate().find(|(_, p)| !p.iter().all(|c| c.is_finite())) {
        return Err(value_error(format!("{what}: point {i} is not finite: {p:?}")));
    }
    Ok(rows)
}

/// The diagram of one checked cloud, in squared radii or radii.
fn diagram_of(points: &[[f64; 3]], squared: bool, what: &str) -> PyResult<Diagram> {
    let d = engine_persistence(points).map_err(|e| value_error(format!("{what}: {e}")))?;
    Ok(if squared { d } else { d.to_radii() })
}

/// `{dim: (k, 2) float64 array}` for each of `dims` (pairs in (birth, death) order).
fn diagram_dict<'py>(py: Python<'py>, d: &Diagram, dims: &[u8]) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    for &dim in dims {
        let pairs = d.dimension(dim);
        let flat: Vec<f64> = pairs.iter().flat_map(|p| [p.birth, p.death]).collect();
        let array = Array2::from_shape_vec((pairs.len(), 2), flat).expect("k × 2 values");
        out.set_item(dim, array.into_pyarray(py))?;
    }
    Ok(out)
}

/// Persistence pairs of the alpha complex of one cloud.
#[pyfunction]
#[pyo3(signature = (points, dims, squared))]
fn alpha_persistence<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    dims: Vec<u8>,
    squared: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let pts = cloud(&points, "points")?;
    let d = py.detach(|| diagram_of(&pts, squared, "points"))?;
    diagram_dict(py, &d, &dims)
}

/// `alpha_persistence` with the seconds spent in the engine alone (the benchmark's measure of
/// what crossing the boundary costs).
#[pyfunction]
#[pyo3(signature = (points, dims, squared))]
fn alpha_persistence_timed<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    dims: Vec<u8>,
    squared: bool,
) -> PyResult<(Bound<'py, PyDict>, f64)> {
    let pts = cloud(&points, "points")?;
    let (d, secs) = py.detach(|| {
        let t = std::time::Instant::now();
        let d = diagram_of(&pts, squared, "points");
        (d, t.elapsed().as_secs_f64())
    });
    Ok((diagram_dict(py, &d?, &dims)?, secs))
}

/// A float64 numpy matrix handed to Python.
type PyMatrix<'py> = Bound<'py, numpy::PyArray2<f64>>;

/// The pairs of a cloud with where each dies (`toporec::homology::alpha_persistence_located`):
/// an (n, 3) array of `dim, birth, death` (squared radii) and an (n, 3) array of locations
/// (NaN for the essential class).
#[pyfunction]
fn alpha_persistence_located<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
) -> PyResult<(PyMatrix<'py>, PyMatrix<'py>)> {
    let pts = cloud(&points, "points")?;
    let located = py
        .detach(|| toporec::homology::alpha_persistence_located(&pts))
        .map_err(|e| value_error(format!("points: {e}")))?;
    let pairs: Vec<Vec<f64>> =
        located.iter().map(|l| vec![l.pair.dim as f64, l.pair.birth, l.pair.death]).collect();
    let at: Vec<Vec<f64>> = located.iter().map(|l| l.at.unwrap_or([f64::NAN; 3]).to_vec()).collect();
    let pairs = numpy::PyArray2::from_vec2(py, &pairs).map_err(value_error)?;
    let at = numpy::PyArray2::from_vec2(py, &at).map_err(value_error)?;
    Ok((pairs, at))
}

/// Persistence of many clouds, in parallel.
#[pyfunction]
#[pyo3(signature = (clouds, dims, squared))]
fn alpha_persistence_batch<'py>(
    py: Python<'py>,
    clouds: Vec<PyReadonlyArray2<'py, f64>>,
    dims: Vec<u8>,
    squared: bool,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    let pts: Vec<Vec<[f64; 3]>> =
        clouds.iter().enumerate().map(|(i, c)| cloud(c, &format!("cloud {i}"))).collect::<PyResult<_>>()?;
    let diagrams: Vec<PyResult<Diagram>> = py.detach(|| {
        pts.par_iter().enumerate().map(|(i, p)| diagram_of(p, squared, &format!("cloud {i}"))).collect()
    });
    diagrams.into_iter().map(|d| diagram_dict(py, &d?, &dims)).collect()
}

/// Vertices, edges, triangles and tetrahedra of the Delaunay complex (duplicates merged).
#[pyfunction]
fn simplex_counts(py: Python<'_>, points: PyReadonlyArray2<'_, f64>) -> PyResult<[usize; 4]> {
    let pts = cloud(&points, "points")?;
    py.detach(|| {
        toporec::homology::DelaunayComplex::new(&pts).map(|c| c.simplex_counts()).map_err(value_error)
    })
}

fn contrast_of(s: &str) -> PyResult<Contrast> {
    serde_json::from_value(serde_json::json!(s))
        .map_err(|_| value_error(format!("contrast: expected gaussian, laplacian or indicator; got {s:?}")))
}

fn weighting_of(s: &str) -> PyResult<Weighting> {
    serde_json::from_value(serde_json::json!(s))
        .map_err(|_| value_error(format!("weighting: expected cloud or iidproba; got {s:?}")))
}

fn kmeans_of(s: &str) -> PyResult<KMeansParams> {
    let algorithm = match s {
        "minibatch" => Algorithm::MiniBatch,
        "lloyd" | "full" => Algorithm::Lloyd,
        other => return Err(value_error(format!("kmeans: expected minibatch or lloyd; got {other:?}"))),
    };
    Ok(KMeansParams { algorithm, ..KMeansParams::default() })
}

/// The `(k, 2)` points of each diagram, checked.
fn measures(diagrams: &[PyReadonlyArray2<'_, f64>]) -> PyResult<Vec<Vec<[f64; 2]>>> {
    diagrams
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let a = d.as_array();
            if a.ncols() != 2 && a.nrows() > 0 {
                return Err(value_error(format!(
                    "diagram {i}: expected a (k, 2) array, got shape {:?}",
                    a.shape()
                )));
            }
            Ok(a.rows().into_iter().map(|r| [r[0], r[1]]).collect())
        })
        .collect()
}

/// Centres `(b, 2)`, inertias `(b,)` and the number of finite points fitted on.
type FittedAtol<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>, u64);

/// Fits ATOL's centres and inertias on all points of `diagrams`.
#[pyfunction]
#[pyo3(signature = (diagrams, b, contrast, weighting, kmeans, seed))]
fn atol_fit<'py>(
    py: Python<'py>,
    diagrams: Vec<PyReadonlyArray2<'py, f64>>,
    b: usize,
    contrast: &str,
    weighting: &str,
    kmeans: &str,
    seed: u64,
) -> PyResult<FittedAtol<'py>> {
    let (contrast, weighting, params) =
        (contrast_of(contrast)?, weighting_of(weighting)?, kmeans_of(kmeans)?);
    let m = measures(&diagrams)?;
    let points_seen = m.iter().flatten().filter(|p| p.iter().all(|v| v.is_finite())).count() as u64;
    let atol = py.detach(|| {
        let refs: Vec<&[[f64; 2]]> = m.iter().map(Vec::as_slice).collect();
        Atol::fit(&refs, b, contrast, weighting, &params, seed)
    });
    let atol = atol.map_err(value_error)?;
    let centers: Vec<f64> = atol.centers.iter().flatten().copied().collect();
    let centers = Array2::from_shape_vec((atol.centers.len(), 2), centers).expect("b × 2 values");
    Ok((centers.into_pyarray(py), Array1::from(atol.inertias).into_pyarray(py), points_seen))
}

fn atol_model(
    centers: &PyReadonlyArray2<'_, f64>,
    inertias: &PyReadonlyArray1<'_, f64>,
    contrast: &str,
    weighting: &str,
) -> PyResult<Atol> {
    let c = centers.as_array();
    let s = inertias.as_slice()?.to_vec();
    if c.ncols() != 2 || c.nrows() != s.len() || s.is_empty() {
        return Err(value_error(format!(
            "centers must be (b, 2) and inertias (b,), b ≥ 1; got {:?} and {}",
            c.shape(),
            s.len()
        )));
    }
    let centers = c.rows().into_iter().map(|r| [r[0], r[1]]).collect();
    Ok(Atol { centers, inertias: s, contrast: contrast_of(contrast)?, weighting: weighting_of(weighting)? })
}

/// ATOL vectors `(n, b)` of `diagrams` under given centres, in parallel.
#[pyfunction]
#[pyo3(signature = (diagrams, centers, inertias, contrast, weighting))]
fn atol_transform<'py>(
    py: Python<'py>,
    diagrams: Vec<PyReadonlyArray2<'py, f64>>,
    centers: PyReadonlyArray2<'py, f64>,
    inertias: PyReadonlyArray1<'py, f64>,
    contrast: &str,
    weighting: &str,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let atol = atol_model(&centers, &inertias, contrast, weighting)?;
    let m = measures(&diagrams)?;
    let b = atol.len();
    let flat: Vec<f64> = py.detach(|| m.par_iter().flat_map_iter(|x| atol.transform(x)).collect());
    Ok(Array2::from_shape_vec((m.len(), b), flat).expect("n × b values").into_pyarray(py))
}

/// Writes a one-part codebook (the paper's layout) in the CLI's JSON format; returns its id.
#[pyfunction]
#[pyo3(signature = (path, centers, inertias, contrast, weighting, kmeans, seed, points_seen, squared))]
#[allow(clippy::too_many_arguments)]
fn codebook_save(
    py: Python<'_>,
    path: PathBuf,
    centers: PyReadonlyArray2<'_, f64>,
    inertias: PyReadonlyArray1<'_, f64>,
    contrast: &str,
    weighting: &str,
    kmeans: &str,
    seed: u64,
    points_seen: u64,
    squared: bool,
) -> PyResult<String> {
    let atol = atol_model(&centers, &inertias, contrast, weighting)?;
    let spec = CodebookSpec {
        dims: DimSelection::Paper,
        b: atol.len(),
        contrast: atol.contrast,
        weighting: atol.weighting,
        kmeans: kmeans_of(kmeans)?,
        seed,
        squared_radii: squared,
        ..CodebookSpec::default()
    };
    let codebook = Codebook {
        spec,
        toporec_version: env!("CARGO_PKG_VERSION").into(),
        parts: vec![CodebookPart { dim: None, points_seen, atol }],
    };
    py.detach(|| codebook.save(&path)).map_err(toporec_error)?;
    Ok(codebook.id())
}

/// A codebook file, checked, as its JSON text (non-finite numbers as strings).
#[pyfunction]
fn codebook_load(py: Python<'_>, path: PathBuf) -> PyResult<String> {
    let codebook = py.detach(|| Codebook::load(&path)).map_err(toporec_error)?;
    Ok(serde_json::to_string(&codebook.to_json()).expect("JSON of plain values"))
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

/// The online loop detector of one method.
#[pyclass(module = "toporec._toporec")]
struct LoopDetector {
    inner: std::sync::Mutex<toporec::Detector>,
}

#[pymethods]
impl LoopDetector {
    #[new]
    #[pyo3(signature = (method, settings, index, exclude_seconds, exclude_scans, threshold))]
    fn new(
        py: Python<'_>,
        method: &str,
        settings: &str,
        index: Option<PathBuf>,
        exclude_seconds: f64,
        exclude_scans: Option<usize>,
        threshold: Option<f64>,
    ) -> PyResult<Self> {
        let m = match index {
            Some(index) => py
                .detach(|| toporec::loops::detector::method_of_index(&index, method))
                .map_err(toporec_error)?,
            None => {
                let settings: serde_json::Value = serde_json::from_str(settings).map_err(value_error)?;
                toporec::Method::from_settings(method, &settings).map_err(value_error)?
            }
        };
        if !(exclude_seconds.is_finite() && exclude_seconds >= 0.0) {
            return Err(value_error(format!("exclude_seconds {exclude_seconds}: must be finite and >= 0")));
        }
        let exclusion = match exclude_scans {
            Some(n) => toporec::Exclusion::Scans(n),
            None => toporec::Exclusion::Seconds(exclude_seconds),
        };
        let threshold = match threshold.or_else(|| toporec::loops::default_threshold(&m)) {
            Some(t) => t,
            None => {
                return Err(value_error(format!(
                    "threshold: `{method}` has no default threshold at its settings; give one (calibrate with \
                     `toporec loops --calibrate`)"
                )));
            }
        };
        let inner = toporec::Detector::new(m, exclusion, threshold).map_err(value_error)?;
        Ok(LoopDetector { inner: std::sync::Mutex::new(inner) })
    }

    /// Describes and adds one scan; its best allowed earlier match as
    /// `(row, distance, yaw, offset, rank2, true_distance, accepted)`, or None for the first
    /// scans.
    #[pyo3(signature = (points, time, session, pose))]
    #[expect(clippy::type_complexity, reason = "a plain tuple the Python layer names")]
    fn add(
        &self,
        py: Python<'_>,
        points: PyReadonlyArray2<'_, f64>,
        time: Option<f64>,
        session: &str,
        pose: Option<[f64; 3]>,
    ) -> PyResult<Option<(usize, f64, Option<f64>, Option<[f64; 2]>, Option<f64>, Option<f64>, bool)>> {
        let pts = points_of(&points, "points")?;
        if let Some(t) = time.filter(|t| !t.is_finite()) {
            return Err(value_error(format!("time {t}: must be finite")));
        }
        let utime = time.map(|t| (t * 1e6).round() as i64);
        let found = py
            .detach(|| self.inner.lock().expect("not poisoned").add(&pts, utime, session, pose))
            .map_err(value_error)?;
        Ok(found.map(|m| {
            (m.row, m.distance, m.yaw_degrees, m.offset, m.rank2_distance, m.true_distance_m, m.accepted)
        }))
    }

    /// Scans added.
    fn __len__(&self) -> usize {
        self.inner.lock().expect("not poisoned").len()
    }

    /// The threshold below which a match is a loop.
    #[getter]
    fn threshold(&self) -> f64 {
        self.inner.lock().expect("not poisoned").threshold()
    }

    /// Seconds the last `add` spent describing, and searching plus inserting.
    fn last_times(&self) -> (f64, f64) {
        let t = self.inner.lock().expect("not poisoned").last_times();
        (t.describe, t.search_insert)
    }
}

/// Answers queries against one method of an index.
#[pyclass(module = "toporec._toporec")]
struct QueryEngine {
    engine: Arc<toporec::Engine>,
}

/// One query: its id and descriptor, or why it has none.
type Described = Result<(String, Vec<f32>), String>;

#[pymethods]
impl QueryEngine {
    #[new]
    #[pyo3(signature = (index, method, sessions))]
    fn new(py: Python<'_>, index: PathBuf, method: &str, sessions: Vec<String>) -> PyResult<Self> {
        let engine = py.detach(|| toporec::Engine::open(&index, &sessions, method)).map_err(toporec_error)?;
        Ok(QueryEngine { engine: Arc::new(engine) })
    }

    /// Scans in the sensor frame, described as the index describes them.
    fn query_points<'py>(
        &self,
        py: Python<'py>,
        clouds: Vec<PyReadonlyArray2<'py, f64>>,
        ids: Vec<String>,
        k: usize,
    ) -> PyResult<(ArrowStream, Vec<String>)> {
        let scans: Vec<(String, Vec<[f64; 3]>)> = clouds
            .iter()
            .zip(ids)
            .map(|(c, id)| {
                let points = points_of(c, &id)?;
                Ok((id, points))
            })
            .collect::<PyResult<_>>()?;
        let engine = self.engine.clone();
        Ok(py.detach(move || {
            let described: Vec<Described> = scans
                .into_par_iter()
                .map(|(id, points)| {
                    let scan =
                        toporec::Scan::of_points(id.clone(), "query".into(), PathBuf::from(&id), points);
                    engine.describe_scan(scan).map(|(v, _)| (id, v)).map_err(|e| e.to_string())
                })
                .collect();
            answer(&engine, described, k)
        }))
    }

    /// Scan files, clouds or logs, read as `toporec query` reads them.
    fn query_paths(
        &self,
        py: Python<'_>,
        paths: Vec<PathBuf>,
        k: usize,
    ) -> PyResult<(ArrowStream, Vec<String>)> {
        let engine = self.engine.clone();
        py.detach(move || {
            let mut items = Vec::new();
            for p in &paths {
                items.extend(toporec::query::open_path(p, None).map_err(toporec_error)?);
            }
            let described: Vec<Described> = items
                .into_par_iter()
                .map(|item| {
                    let scan = item.map_err(|f| f.error)?;
                    let id = scan.id.clone();
                    engine.describe_scan(scan).map(|(v, _)| (id, v)).map_err(|e| e.to_string())
                })
                .collect();
            Ok(answer(&engine, described, k))
        })
    }
}

/// The query table (`toporec query`'s columns, [`toporec::query::hits_batch`]) of described
/// queries, and the failures.
fn answer(engine: &toporec::Engine, described: Vec<Described>, k: usize) -> (ArrowStream, Vec<String>) {
    let flat: Vec<f32> = described.iter().flatten().flat_map(|(_, v)| v.iter().copied()).collect();
    let mut found = engine.find_many(&flat, k).into_iter();
    let mut answered = Vec::new();
    let mut failures = Vec::new();
    for d in &described {
        match d {
            Ok((id, _)) => answered.push((id.as_str(), found.next().expect("one result per query").0)),
            Err(e) => failures.push(e.clone()),
        }
    }
    let answers: Vec<(&str, &[toporec::Hit])> = answered.iter().map(|(id, h)| (*id, h.as_slice())).collect();
    let batch = toporec::query::hits_batch(engine, &answers);
    (ArrowStream::new(batch.schema(), vec![batch]), failures)
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
