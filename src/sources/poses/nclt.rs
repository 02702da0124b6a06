//! Pose CSVs in NCLT's `groundtruth_<date>.csv` layout (NCLT's `read_ground_truth.py`): no
//! header, columns `utime (µs), x, y, z, roll, pitch, heading`, x north, y east, z down (extra
//! columns are ignored). Read with the `csv` crate, so a byte-order mark, Windows line ends and
//! quoted fields are fine. Rows with a NaN or infinite value are kept as non-finite poses (NCLT
//! has some): a scan joined to one gets no pose, with that reason. Unparsable lines are reported
//! with their line number and skipped. Poses are exposed z up like the clouds: `(x, −y, −z)` and
//! yaw = −heading. Scans are joined to the row with the nearest utime within a tolerance.

use super::{Pose, PoseTable};
use crate::sources::SourceError;
use std::path::{Path, PathBuf};

impl PoseTable {
    /// Reads and parses the NCLT ground-truth CSV at `path`.
    pub fn read_nclt(path: &Path) -> Result<Self, SourceError> {
        let bytes =
            std::fs::read(path).map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
        Ok(Self::parse_nclt(&bytes, path))
    }

    /// Parses the bytes of an NCLT ground-truth CSV.
    pub fn parse_nclt(bytes: &[u8], path: &Path) -> Self {
        let mut gt = PoseTable { path: path.to_owned(), ..Default::default() };
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(bytes);
        for (line, record) in crate::sources::csv::numbered_records(&mut reader) {
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
