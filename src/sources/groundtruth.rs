//! Pose CSVs in NCLT's `groundtruth_<date>.csv` layout (NCLT's `read_ground_truth.py`): no header, columns
//! `utime (µs), x, y, z, roll, pitch, heading`, x north, y east, z down. Rows with NaN are
//! skipped (NCLT has some); unparsable lines are reported with their line number and skipped.
//! Poses are exposed z up like the clouds: `(x, −y, −z)` and yaw = −heading.
//! Scans are joined to the row with the nearest utime within a tolerance.

use super::{Pose, SourceError};
use std::path::{Path, PathBuf};

/// A parsed pose file.
#[derive(Clone, Debug, Default)]
pub struct GroundTruth {
    /// The file.
    pub path: PathBuf,
    /// (utime, pose), sorted by utime.
    pub rows: Vec<(i64, Pose)>,
    /// Rows skipped because a value was NaN.
    pub nan_rows: usize,
    /// Lines that could not be parsed (each also logged as a warning).
    pub bad_lines: Vec<String>,
}

impl GroundTruth {
    /// Reads and parses `path`.
    pub fn read(path: &Path) -> Result<Self, SourceError> {
        let text = std::fs::read(path).map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
        Ok(Self::parse(&String::from_utf8_lossy(&text), path))
    }

    /// Parses the text of a pose file.
    pub fn parse(text: &str, path: &Path) -> Self {
        let mut gt = GroundTruth { path: path.to_owned(), ..Default::default() };
        for (i, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            let parsed = (fields.len() == 7)
                .then(|| {
                    let utime = fields[0].parse::<f64>().ok()?;
                    let v: Option<Vec<f64>> = fields[1..].iter().map(|f| f.parse::<f64>().ok()).collect();
                    Some((utime, v?))
                })
                .flatten();
            match parsed {
                Some((utime, v)) if utime.is_finite() => {
                    if v.iter().any(|x| x.is_nan()) {
                        gt.nan_rows += 1;
                        continue;
                    }
                    let pose = Pose { x: v[0], y: -v[1], z: -v[2], yaw: -v[5] };
                    gt.rows.push((utime as i64, pose));
                }
                _ => {
                    let e = SourceError::Parse {
                        path: path.to_owned(),
                        line: i + 1,
                        message: "expected 7 numbers: utime,x,y,z,roll,pitch,heading".into(),
                    };
                    tracing::warn!("{e}");
                    gt.bad_lines.push(e.to_string());
                }
            }
        }
        gt.rows.sort_by_key(|r| r.0);
        gt
    }

    /// The pose nearest in time to `utime`, if within `tolerance_us`.
    pub fn pose_at(&self, utime: i64, tolerance_us: i64) -> Option<Pose> {
        let i = self.rows.partition_point(|r| r.0 < utime);
        let candidates = [i.checked_sub(1), Some(i)];
        candidates
            .into_iter()
            .flatten()
            .filter_map(|j| self.rows.get(j))
            .min_by_key(|r| (r.0 - utime).abs())
            .filter(|r| (r.0 - utime).abs() <= tolerance_us)
            .map(|r| r.1)
    }
}

/// Finds `groundtruth_<session>.csv` for an NCLT session folder: in the folder, beside it, or
/// in a `ground_truth` folder beside it or one level up (the layouts NCLT ships and users make).
pub fn find_for_session(session_dir: &Path, session: &str) -> Option<PathBuf> {
    let name = format!("groundtruth_{session}.csv");
    let parent = session_dir.parent().unwrap_or(Path::new("."));
    let mut candidates =
        vec![session_dir.join(&name), parent.join(&name), parent.join("ground_truth").join(&name)];
    if let Some(grand) = parent.parent() {
        candidates.push(grand.join("ground_truth").join(&name));
    }
    candidates.into_iter().find(|p| p.is_file())
}
