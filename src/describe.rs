//! The one path from a scan to its descriptor: preprocess → alpha persistence → (radii) →
//! ATOL. `toporec run`'s workers, `query` and `eval` all go through a [`Describer`], so a scan
//! gets the same diagram and descriptor whichever command computes it.
//!
//! A [`Describer`] never panics on a scan: a panic inside a stage is caught and becomes that
//! scan's [`DescribeError::Internal`]. Stage times are the calling thread's CPU time, so they
//! add up to the work done whatever the thread count and machine load.

use crate::homology::{ComplexError, Diagram, alpha_persistence};
use crate::preprocess::{Preprocess, Skip, preprocess};
use crate::sources::Scan;
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
}

impl std::ops::AddAssign for StageTimes {
    fn add_assign(&mut self, o: StageTimes) {
        self.preprocess += o.preprocess;
        self.persistence += o.persistence;
        self.vectorize += o.vectorize;
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

/// A scan's diagram and, with a codebook, its descriptor.
#[derive(Clone, Debug, PartialEq)]
pub struct Described {
    /// The persistence diagram (squared radii or radii, as configured).
    pub diagram: Diagram,
    /// The ATOL descriptor, when the describer has a codebook.
    pub descriptor: Option<Descriptor>,
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

/// Preprocess settings, persistence units and (optionally) a codebook: everything that turns
/// a scan into a descriptor.
#[derive(Clone, Debug)]
pub struct Describer {
    /// The preprocess stage's settings.
    pub preprocess: Preprocess,
    /// Squared radii (GUDHI's default) or radii.
    pub squared: bool,
    /// The codebook; without one, scans get diagrams only.
    pub codebook: Option<Codebook>,
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
            Ok(Described { diagram, descriptor })
        });
        Description { kept_points: points.len(), times, outcome }
    }

    /// A scan's diagram and descriptor, through every stage.
    pub fn describe(&self, scan: Scan) -> Description {
        let label = format!("{}: scan {}", scan.path.display(), scan.id);
        let t = ThreadTime::now();
        let points =
            catch(&label, || self.preprocess(scan).map_err(|Skip(reason)| DescribeError::Skipped(reason)));
        let preprocess = cpu_seconds(t);
        let mut d = match points {
            Ok(points) => self.describe_points(&points, &label),
            Err(e) => Description { kept_points: 0, times: StageTimes::default(), outcome: Err(e) },
        };
        d.times.preprocess = preprocess;
        d
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
