//! Thresholds: given, read from a calibration file, calibrated on the index's own poses
//! ([`calibrate`]: the largest threshold whose accepted matches reach a target precision), or
//! the method's documented default ([`default_threshold`]).

use super::LoopsArgs;
use crate::error::{Error, Result, ResultExt};
use crate::search::Engine;
use std::path::{Path, PathBuf};

/// A calibrated threshold.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Calibration {
    /// The method.
    pub method: String,
    /// What made its descriptors (codebook or method id): a threshold holds for those only.
    pub id: String,
    /// Matches below it are loops.
    pub threshold: f64,
    /// The precision asked for.
    pub target_precision: f64,
    /// The precision reached on the calibration drive.
    pub precision: f64,
    /// Accepted matches on the calibration drive.
    pub accepted: usize,
    /// Matches with poses on the calibration drive.
    pub matches: usize,
    /// A match was true within this distance (m).
    pub revisit_radius_m: f64,
}

/// The largest threshold whose accepted matches reach `target` precision, from `(distance,
/// true)` pairs: the matches sorted by distance, the longest prefix with that precision, and
/// the threshold halfway between its last distance and the next one (just above it when it is
/// the last); `None` when no prefix reaches it.
pub fn calibrate(matches: &[(f64, bool)], target: f64) -> Option<f64> {
    let mut sorted: Vec<(f64, bool)> = matches.to_vec();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut best = None;
    let mut true_so_far = 0usize;
    for (i, &(d, t)) in sorted.iter().enumerate() {
        true_so_far += usize::from(t);
        // A prefix must end between distinct distances: a threshold cannot split a tie.
        let next = sorted.get(i + 1).map(|n| n.0);
        if next == Some(d) {
            continue;
        }
        if true_so_far as f64 >= target * (i + 1) as f64 {
            best = Some(match next {
                Some(n) => d + (n - d) / 2.0,
                None => d + d.abs().max(f64::MIN_POSITIVE) * 1e-9,
            });
        }
    }
    best
}

/// The default threshold of a method at its default settings: the threshold calibrated on
/// simulated HDL-64E drives (revisits within 5 m; docs/loops.md says which drives and at what
/// precision). `None` for the other methods and settings (their distances differ).
pub fn default_threshold(method: &crate::methods::Method) -> Option<f64> {
    method.as_computed().and_then(|c| c.default_threshold())
}

/// The threshold of one method: given, from a calibration file (which must be the method's and
/// of its descriptors), calibrated (`None` until then), or the method's default.
pub(super) fn given_threshold(a: &LoopsArgs, method: &str, engine: &Engine) -> Result<Option<f64>> {
    let id = &engine.id;
    if let Some(t) = a.threshold {
        return Ok(Some(t));
    }
    let Some(path) = &a.threshold_from else {
        if a.calibrate {
            return Ok(None);
        }
        return default_threshold(&engine.method).map(Some).ok_or_else(|| {
            Error::invalid(format!(
                "`{method}` has no default threshold at its settings: give --threshold D, --threshold-from FILE, \
                 or --calibrate on a drive with poses"
            ))
        });
    };
    let text = std::fs::read_to_string(path).at(path)?;
    let all: Vec<Calibration> = serde_json::from_str(&text)
        .map_err(|e| Error::invalid(format!("{}: not a toporec loops calibration: {e}", path.display())))?;
    let Some(c) = all.iter().find(|c| c.method == method) else {
        return Err(Error::invalid(format!("{}: no threshold for method `{method}`", path.display())));
    };
    if c.id != *id {
        return Err(Error::invalid(format!(
            "{}: the threshold of `{method}` was calibrated on descriptors {}, the index holds {id}",
            path.display(),
            c.id
        )));
    }
    Ok(Some(c.threshold))
}

/// Where `--calibrate` writes its thresholds: beside the output, `<stem>.calibration.json`.
pub(crate) fn calibration_path(out: &Path) -> PathBuf {
    let stem = out.file_stem().map_or_else(|| "loops".into(), |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}.calibration.json"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calibration_by_hand() {
        // Sorted: 0.1 T, 0.2 T, 0.3 F, 0.4 T, 0.5 F. Prefix precisions: 1, 1, 2/3, 3/4, 3/5.
        let m = [(0.4, true), (0.1, true), (0.5, false), (0.3, false), (0.2, true)];
        // 0.75: the longest prefix is the first four; halfway between 0.4 and 0.5.
        assert_eq!(calibrate(&m, 0.75), Some(0.45));
        // 0.99: the first two; halfway between 0.2 and 0.3.
        assert_eq!(calibrate(&m, 0.99), Some(0.25));
        // 0.6: every match; just above the last.
        assert!(calibrate(&m, 0.6).is_some_and(|t| t > 0.5 && t < 0.5 + 1e-6));
        // None reach it when the nearest match is false.
        assert_eq!(calibrate(&[(0.1, false), (0.2, true)], 0.9), None);
        // A tie is not split: 0.1 T and 0.1 F together have precision 1/2.
        assert_eq!(calibrate(&[(0.1, true), (0.1, false), (0.3, true)], 0.9), None);
    }
}
