//! Searching an index from Python: the query engine (new scans against an index's
//! descriptors) and the online loop detector.

use super::persistence::*;
use super::{ArrowStream, toporec_error, value_error};
use numpy::PyReadonlyArray2;
use pyo3::prelude::*;
use rayon::prelude::*;
use std::path::PathBuf;
use std::sync::Arc;

/// The online loop detector of one method.
#[pyclass(module = "toporec._toporec")]
pub(crate) struct LoopDetector {
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
pub(crate) struct QueryEngine {
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
        py.detach(move || {
            let described: Vec<Described> = scans
                .into_par_iter()
                .map(|(id, points)| {
                    let scan =
                        toporec::Scan::of_points(id.clone(), "query".into(), PathBuf::from(&id), points);
                    engine.describe_scan(scan).map(|(v, _)| (id, v)).map_err(|e| e.to_string())
                })
                .collect();
            answer(&engine, described, k)
        })
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
            answer(&engine, described, k)
        })
    }
}

/// The query table (`toporec query`'s columns, [`toporec::query::hits_batch`]) of described
/// queries, and the failures.
pub(crate) fn answer(
    engine: &toporec::Engine,
    described: Vec<Described>,
    k: usize,
) -> PyResult<(ArrowStream, Vec<String>)> {
    let flat: Vec<f32> = described.iter().flatten().flat_map(|(_, v)| v.iter().copied()).collect();
    let mut found = engine.find_many(&flat, k).map_err(toporec_error)?.into_iter();
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
    Ok((ArrowStream::new(batch.schema(), vec![batch]), failures))
}
