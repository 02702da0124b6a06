//! The one path from a scan to its descriptors: preprocess → alpha persistence → (radii) →
//! ATOL for the TopoRec descriptor, and the raw scan (sensor frame) → each computed baseline
//! (toporec-plus and the baselines, [`crate::methods`]) with its own preprocessing. `toporec run`'s workers, `query` and `eval`
//! all go through a [`Describer`], so a scan gets the same diagram and descriptors whichever
//! command computes it. The persistence stage runs only when the TopoRec descriptor is wanted.
//!
//! [`Describer::scan_rows`] is the per-scan step of `run` and [`crate::batch`]: a scan (or the
//! failure to read it) as its `scans` row, diagram and descriptor rows ([`ScanResult`]).
//!
//! A [`Describer`] never panics on a scan: a panic inside a stage is caught and becomes that
//! scan's [`DescribeError::Internal`]. Stage times are the calling thread's CPU time, so they
//! add up to the work done whatever the thread count and machine load.

use crate::homology::{ComplexError, Diagram, alpha_persistence};
use crate::methods::Method;
use crate::preprocess::{Preprocess, Skip, preprocess};
use crate::sinks::index::writer::MethodDescriptor;
use crate::sinks::parquet::{DescriptorRow, ScanRow, Status};
use crate::sources::Scan;
use crate::sources::ScanFailure;
use crate::types::Point;
use crate::vectorize::codebook::{Codebook, Descriptor};
use cpu_time::ThreadTime;

/// CPU seconds spent in each stage on one scan (or summed over scans).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// Preprocessing.
    pub preprocess: f64,
    /// Alpha persistence.
    pub persistence: f64,
    /// ATOL.
    pub vectorize: f64,
    /// The methods computed from the raw scan, all together.
    pub baselines: f64,
}

impl std::ops::AddAssign for StageTimes {
    fn add_assign(&mut self, o: StageTimes) {
        self.preprocess += o.preprocess;
        self.persistence += o.persistence;
        self.vectorize += o.vectorize;
        self.baselines += o.baselines;
    }
}

/// Why a scan has no diagram.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DescribeError {
    /// Left out on purpose: too few points after preprocessing.
    #[error("{0}")]
    Skipped(String),
    /// The alpha complex could not be built.
    #[error("{label}: {source}")]
    Complex {
        /// `<file>: scan <id>`.
        label: String,
        /// The engine's error.
        source: ComplexError,
    },
    /// A method computed from the raw scan could not describe it.
    #[error("{label}: {reason}")]
    Method {
        /// `<file>: scan <id> (<method>)`.
        label: String,
        /// Why.
        reason: String,
    },
    /// The descriptor holds a NaN or infinite value (never stored).
    #[error("{label}: the descriptor has non-finite values")]
    NonFinite {
        /// `<file>: scan <id>`.
        label: String,
    },
    /// A stage panicked (a bug, caught so the run goes on).
    #[error("{label}: internal error: {message}")]
    Internal {
        /// `<file>: scan <id>`.
        label: String,
        /// The panic message.
        message: String,
    },
}

/// A scan's diagram and, with a codebook, its descriptor; and its baseline descriptors.
#[derive(Clone, Debug, PartialEq)]
pub struct Described {
    /// The persistence diagram (squared radii or radii, as configured), when the TopoRec
    /// descriptor is wanted.
    pub diagram: Option<Diagram>,
    /// The ATOL descriptor, when the describer has a codebook.
    pub descriptor: Option<Descriptor>,
    /// One descriptor per computed method of the describer, in its order.
    pub baselines: Vec<Vec<f32>>,
}

/// What became of one scan.
#[derive(Clone, Debug, PartialEq)]
pub struct Description {
    /// Points left after preprocessing (0 when skipped).
    pub kept_points: usize,
    /// CPU time per stage.
    pub times: StageTimes,
    /// The result.
    pub outcome: Result<Described, DescribeError>,
}

/// Preprocess settings, persistence units, (optionally) a codebook and the computed
/// baselines: everything that turns a scan into its descriptors.
#[derive(Clone, Debug)]
pub struct Describer {
    /// The preprocess stage's settings (TopoRec).
    pub preprocess: Preprocess,
    /// Squared radii (GUDHI's default) or radii.
    pub squared: bool,
    /// The codebook; without one, scans get diagrams only.
    pub codebook: Option<Codebook>,
    /// Whether the TopoRec descriptor is wanted (else no preprocess, no persistence).
    pub topological: bool,
    /// The baselines computed from the raw scan.
    pub computed: Vec<Method>,
}

fn cpu_seconds(since: ThreadTime) -> f64 {
    since.elapsed().as_secs_f64()
}

impl Describer {
    /// The preprocessed points of a scan.
    pub fn preprocess(&self, scan: Scan) -> Result<Vec<Point>, Skip> {
        preprocess(scan.points, scan.fingerprint, &self.preprocess)
    }

    /// The diagram of preprocessed points, in the configured units.
    pub fn diagram(&self, points: &[Point]) -> Result<Diagram, ComplexError> {
        alpha_persistence(points).map(|d| if self.squared { d } else { d.to_radii() })
    }

    /// The descriptor of a diagram, when there is a codebook.
    pub fn vectorize(&self, diagram: &Diagram) -> Option<Descriptor> {
        self.codebook.as_ref().map(|cb| cb.vectorize(diagram))
    }

    /// A TopoRec-only describer.
    pub fn toporec(preprocess: Preprocess, squared: bool, codebook: Option<Codebook>) -> Self {
        Describer { preprocess, squared, codebook, topological: true, computed: Vec::new() }
    }

    /// A describer of one method computed from raw scans (none for an imported one).
    pub fn of_computed(method: &Method) -> Self {
        let computed = if method.is_computed() { vec![method.clone()] } else { Vec::new() };
        Describer { topological: false, computed, ..Self::toporec(Preprocess::default(), true, None) }
    }

    /// A describer that describes nothing (a search over stored descriptors).
    pub fn nothing() -> Self {
        Describer { topological: false, ..Self::toporec(Preprocess::default(), true, None) }
    }

    /// The baseline descriptors of a raw scan (sensor frame), one per computed method.
    pub fn describe_raw(&self, points: &[Point], label: &str) -> Result<Vec<Vec<f32>>, DescribeError> {
        if !self.computed.is_empty() && points.len() < crate::methods::MIN_RAW_POINTS {
            return Err(DescribeError::Skipped(format!(
                "{label}: {} points, fewer than the {} a raw-scan method needs",
                points.len(),
                crate::methods::MIN_RAW_POINTS
            )));
        }
        catch(label, || {
            let mut out = Vec::with_capacity(self.computed.len());
            for m in &self.computed {
                let d = match m.describe_raw(points) {
                    Some(Ok(d)) => d,
                    Some(Err(reason)) => {
                        return Err(DescribeError::Method { label: format!("{label} ({})", m.name), reason });
                    }
                    None => Vec::new(),
                };
                if !d.iter().all(|v| v.is_finite()) {
                    return Err(DescribeError::NonFinite { label: format!("{label} ({})", m.name) });
                }
                out.push(d);
            }
            Ok(out)
        })
    }

    /// The diagram and descriptor of preprocessed points; `label` names the scan in errors.
    pub fn describe_points(&self, points: &[Point], label: &str) -> Description {
        let mut times = StageTimes::default();
        let outcome = catch(label, || {
            let t = ThreadTime::now();
            let diagram = self.diagram(points);
            times.persistence = cpu_seconds(t);
            let diagram = diagram.map_err(|source| DescribeError::Complex { label: label.into(), source })?;
            let t = ThreadTime::now();
            let descriptor = self.vectorize(&diagram);
            times.vectorize = cpu_seconds(t);
            if descriptor.as_ref().is_some_and(|d| !d.values.iter().all(|v| v.is_finite())) {
                return Err(DescribeError::NonFinite { label: label.into() });
            }
            Ok(Described { diagram: Some(diagram), descriptor, baselines: Vec::new() })
        });
        Description { kept_points: points.len(), times, outcome }
    }

    /// A scan's diagram and descriptors, through every stage.
    pub fn describe(&self, scan: Scan) -> Description {
        let label = format!("{}: scan {}", scan.path.display(), scan.id);
        let t = ThreadTime::now();
        let baselines = self.describe_raw(&scan.points, &label);
        let baselines_secs = cpu_seconds(t);
        if !self.topological {
            let kept_points = scan.points.len();
            let outcome = baselines.map(|b| Described { diagram: None, descriptor: None, baselines: b });
            let times = StageTimes { baselines: baselines_secs, ..StageTimes::default() };
            return Description { kept_points, times, outcome };
        }
        let t = ThreadTime::now();
        let points =
            catch(&label, || self.preprocess(scan).map_err(|Skip(reason)| DescribeError::Skipped(reason)));
        let preprocess = cpu_seconds(t);
        let mut d = match points {
            Ok(points) => self.describe_points(&points, &label),
            Err(e) => Description { kept_points: 0, times: StageTimes::default(), outcome: Err(e) },
        };
        d.times.preprocess = preprocess;
        d.times.baselines = baselines_secs;
        d.outcome = match (d.outcome, baselines) {
            (Ok(mut x), Ok(b)) => {
                x.baselines = b;
                Ok(x)
            }
            (Err(e), _) | (Ok(_), Err(e)) => Err(e),
        };
        d
    }
}

impl Describer {
    /// Name and id of each computed method, in the describer's order.
    pub fn computed_ids(&self) -> Vec<(String, String)> {
        self.computed.iter().map(|m| (m.name.clone(), m.id())).collect()
    }

    /// One scan (or the failure to read it) as the rows of the index: its `scans` row, at
    /// `position` in the input, made with settings `settings`, and its diagram and descriptors
    /// (what `toporec run`'s workers and [`crate::batch`] store).
    pub fn scan_rows(&self, item: Result<Scan, ScanFailure>, position: u64, settings: &str) -> ScanResult {
        let scan = match item {
            Ok(scan) => scan,
            Err(f) => {
                let row = ScanRow {
                    scan_id: f.id,
                    fingerprint: f.fingerprint.map(crate::fingerprint::hex),
                    settings_hash: settings.to_string(),
                    session: f.session,
                    seq: position,
                    source_path: f.path.display().to_string(),
                    message_index: f.message_index,
                    utime: f.utime,
                    pose: None,
                    raw_points: 0,
                    kept_points: 0,
                    status: Status::Error,
                    error: Some(f.error),
                };
                let times = StageTimes::default();
                return ScanResult { row, diagram: None, descriptor: None, baselines: Vec::new(), times };
            }
        };
        let mut row = ScanRow {
            scan_id: scan.id.clone(),
            fingerprint: Some(crate::fingerprint::hex(scan.fingerprint)),
            settings_hash: settings.to_string(),
            session: scan.session.clone(),
            seq: position,
            source_path: scan.path.display().to_string(),
            message_index: scan.message_index,
            utime: scan.utime,
            pose: scan.pose,
            raw_points: scan.raw_points as u64,
            kept_points: 0,
            status: Status::Ok,
            error: None,
        };
        let d = self.describe(scan);
        row.kept_points = d.kept_points as u64;
        let (diagram, descriptor, baselines) = match d.outcome {
            Ok(x) => (x.diagram, x.descriptor, x.baselines),
            Err(e) => {
                row.status =
                    if matches!(e, DescribeError::Skipped(_)) { Status::Skipped } else { Status::Error };
                row.error = Some(e.to_string());
                (None, None, Vec::new())
            }
        };
        ScanResult { row, diagram, descriptor, baselines, times: d.times }
    }
}

/// What became of one scan: its `scans` row and what it was described by.
#[derive(Clone, Debug)]
pub struct ScanResult {
    /// The `scans` row.
    pub row: ScanRow,
    /// The diagram (ok scans, when the TopoRec descriptor is wanted).
    pub diagram: Option<Diagram>,
    /// The TopoRec descriptor (ok scans, with a codebook).
    pub descriptor: Option<Descriptor>,
    /// One per computed method (ok scans).
    pub baselines: Vec<Vec<f32>>,
    /// CPU time per stage.
    pub times: StageTimes,
}

impl ScanResult {
    /// The scan's `descriptors` rows, one per method: TopoRec's made with the codebook
    /// `codebook_id` (when given), then the computed methods as `(name, id)`, in the
    /// describer's order.
    pub fn method_descriptors(
        &self,
        codebook_id: Option<&str>,
        computed: &[(String, String)],
    ) -> Vec<MethodDescriptor> {
        let row = &self.row;
        let mut out = Vec::new();
        if let (Some(id), Some(d)) = (codebook_id, &self.descriptor) {
            let r = DescriptorRow::new(row.scan_id.clone(), row.utime, row.pose, d);
            out.push(MethodDescriptor { method: crate::methods::TOPOREC.into(), id: id.to_string(), row: r });
        }
        if row.status == Status::Ok {
            for ((method, id), values) in computed.iter().zip(&self.baselines) {
                let r = DescriptorRow {
                    scan_id: row.scan_id.clone(),
                    utime: row.utime,
                    pose: row.pose,
                    dim_used: None,
                    values: values.clone(),
                };
                out.push(MethodDescriptor { method: method.clone(), id: id.clone(), row: r });
            }
        }
        out
    }
}

/// Runs `f`, turning a panic into [`DescribeError::Internal`].
fn catch<T>(label: &str, f: impl FnOnce() -> Result<T, DescribeError>) -> Result<T, DescribeError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or_else(|panic| {
        let message = panic
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default();
        Err(DescribeError::Internal { label: label.to_string(), message })
    })
}
