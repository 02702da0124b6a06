//! Alpha persistence and ATOL on arrays: the engine on `(n, 3)` point arrays (one, a batch, or
//! with each pair's simplices), and ATOL codebooks fitted and applied to diagram arrays.

use super::{toporec_error, value_error};
use numpy::ndarray::{Array1, Array2};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;
use std::path::PathBuf;
use toporec::homology::{Diagram, alpha_persistence as engine_persistence};
use toporec::vectorize::atol::{Atol, Contrast, Weighting};
use toporec::vectorize::codebook::{Codebook, CodebookPart, CodebookSpec, DimSelection};
use toporec::vectorize::kmeans::{Algorithm, KMeansParams};

/// The rows of a float64 `(n, 3)` array (any other shape is an error naming `what`).
pub(crate) fn points_of(points: &PyReadonlyArray2<f64>, what: &str) -> PyResult<Vec<[f64; 3]>> {
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
pub(crate) fn cloud(points: &PyReadonlyArray2<f64>, what: &str) -> PyResult<Vec<[f64; 3]>> {
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
pub(crate) fn diagram_of(points: &[[f64; 3]], squared: bool, what: &str) -> PyResult<Diagram> {
    let d = engine_persistence(points).map_err(|e| value_error(format!("{what}: {e}")))?;
    Ok(if squared { d } else { d.to_radii() })
}

/// `{dim: (k, 2) float64 array}` for each of `dims` (pairs in (birth, death) order).
pub(crate) fn diagram_dict<'py>(py: Python<'py>, d: &Diagram, dims: &[u8]) -> PyResult<Bound<'py, PyDict>> {
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
pub(crate) fn alpha_persistence<'py>(
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
pub(crate) fn alpha_persistence_timed<'py>(
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
pub(crate) fn alpha_persistence_located<'py>(
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
pub(crate) fn alpha_persistence_batch<'py>(
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
pub(crate) fn simplex_counts(py: Python<'_>, points: PyReadonlyArray2<'_, f64>) -> PyResult<[usize; 4]> {
    let pts = cloud(&points, "points")?;
    py.detach(|| {
        toporec::homology::DelaunayComplex::new(&pts).map(|c| c.simplex_counts()).map_err(value_error)
    })
}

pub(crate) fn contrast_of(s: &str) -> PyResult<Contrast> {
    serde_json::from_value(serde_json::json!(s))
        .map_err(|_| value_error(format!("contrast: expected gaussian, laplacian or indicator; got {s:?}")))
}

pub(crate) fn weighting_of(s: &str) -> PyResult<Weighting> {
    serde_json::from_value(serde_json::json!(s))
        .map_err(|_| value_error(format!("weighting: expected cloud or iidproba; got {s:?}")))
}

pub(crate) fn kmeans_of(s: &str) -> PyResult<KMeansParams> {
    let algorithm = match s {
        "minibatch" => Algorithm::MiniBatch,
        "lloyd" | "full" => Algorithm::Lloyd,
        other => return Err(value_error(format!("kmeans: expected minibatch or lloyd; got {other:?}"))),
    };
    Ok(KMeansParams { algorithm, ..KMeansParams::default() })
}

/// The `(k, 2)` points of each diagram, checked.
pub(crate) fn measures(diagrams: &[PyReadonlyArray2<'_, f64>]) -> PyResult<Vec<Vec<[f64; 2]>>> {
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
pub(crate) fn atol_fit<'py>(
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

pub(crate) fn atol_model(
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
pub(crate) fn atol_transform<'py>(
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
pub(crate) fn codebook_save(
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
pub(crate) fn codebook_load(py: Python<'_>, path: PathBuf) -> PyResult<String> {
    let codebook = py.detach(|| Codebook::load(&path)).map_err(toporec_error)?;
    Ok(serde_json::to_string(&codebook.to_json()).expect("JSON of plain values"))
}
