//! Pose CSVs in NCLT's `groundtruth_<date>.csv` layout (NCLT's `read_ground_truth.py`): no
//! header, columns `utime (µs), x, y, z, roll, pitch, heading`, x north, y east, z down (extra
//! columns are ignored). Read with the `csv` crate, so a byte-order mark, Windows line ends and
//! quoted fields are fine. Rows with a NaN or infinite value are kept as non-finite poses (NCLT
//! has some): a scan joined to one gets no pose, with that reason. Unparsable lines are reported
//! with their line number and skipped. Poses are exposed z up like the clouds: `(x, −y, −z)` and
//! yaw = −heading. Scans are joined to the row with the nearest utime within a tolerance.

use super::{NoPose, Pose, SourceError};
use std::path::{Path, PathBuf};

/// A parsed pose file.
#[derive(Clone, Debug, Default)]
pub struct GroundTruth {
    /// The file.
    pub path: PathBuf,
    /// (utime, pose), sorted by utime; `None` for a row with a non-finite value.
    pub rows: Vec<(i64, Option<Pose>)>,
    /// Rows with a NaN or infinite value.
    pub non_finite_rows: usize,
    /// Lines that could not be parsed (reported once, by the run that reads them: see
    /// [`super::poses::PoseOrigin::bad_lines_warning`]).
    pub bad_lines: Vec<String>,
}

impl GroundTruth {
    /// Reads and parses `path`.
    pub fn read(path: &Path) -> Result<Self, SourceError> {
        let bytes =
            std::fs::read(path).map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
        Ok(Self::parse_bytes(&bytes, path))
    }

    /// Parses the text of a pose file.
    pub fn parse(text: &str, path: &Path) -> Self {
        Self::parse_bytes(text.as_bytes(), path)
    }

    /// Parses the bytes of a pose file.
    pub fn parse_bytes(bytes: &[u8], path: &Path) -> Self {
        let mut gt = GroundTruth { path: path.to_owned(), ..Default::default() };
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(bytes);
        for (line, record) in super::csv::numbered_records(&mut reader) {
            let record = match record {
                Ok(r) => r,
                Err(e) => {
                    gt.bad(line, &format!("not CSV: {e}"));
                    continue;
                }
            };
            let numbers: Option<Vec<f64>> = record.iter().take(7).map(|f| f.parse::<f64>().ok()).collect();
            match numbers.filter(|v| v.len() == 7) {
                Some(v) if v[0].is_finite() && v[0].abs() < 9.2e18 => {
                    let pose = if v.iter().all(|x| x.is_finite()) {
                        Some(Pose { x: v[1], y: -v[2], z: -v[3], yaw: -v[6] })
                    } else {
                        gt.non_finite_rows += 1;
                        None
                    };
                    gt.rows.push((v[0] as i64, pose));
                }
                _ => gt.bad(line, "expected 7 numbers: utime,x,y,z,roll,pitch,heading"),
            }
        }
        gt.rows.sort_by_key(|r| r.0);
        gt
    }

    fn bad(&mut self, line: usize, message: &str) {
        self.bad_lines.push(format!("line {line}: {message}"));
    }

    /// The pose of the row nearest in time to `utime`, if within `tolerance_us` and finite.
    pub fn pose_at(&self, utime: i64, tolerance_us: i64) -> Result<Pose, NoPose> {
        let i = self.rows.partition_point(|r| r.0 < utime);
        let candidates = [i.checked_sub(1), Some(i)];
        let nearest = candidates
            .into_iter()
            .flatten()
            .filter_map(|j| self.rows.get(j))
            .min_by_key(|r| r.0.abs_diff(utime))
            .filter(|r| r.0.abs_diff(utime) <= tolerance_us.unsigned_abs());
        match nearest {
            None => Err(NoPose::NoRowNear),
            Some((_, None)) => Err(NoPose::NonFinite),
            Some((_, Some(p))) => Ok(*p),
        }
    }
}

/// Finds `groundtruth_<session>.csv` for an NCLT session folder: in the folder, beside it, or
/// in a `ground_truth` folder beside it or one level up (the layouts NCLT ships and users make).
pub(crate) fn find_for_session(session_dir: &Path, session: &str) -> Option<PathBuf> {
    let name = format!("groundtruth_{session}.csv");
    let parent = session_dir.parent().unwrap_or(Path::new("."));
    let mut candidates =
        vec![session_dir.join(&name), parent.join(&name), parent.join("ground_truth").join(&name)];
    if let Some(grand) = parent.parent() {
        candidates.push(grand.join("ground_truth").join(&name));
    }
    candidates.into_iter().find(|p| p.is_file())
}
