//! Where scans take their poses from: a log's own transforms and odometry (`log`), or a pose
//! file — NCLT's ground-truth CSV (`nclt`), TUM (`tum`) or KITTI's 3 × 4 rows (`kitti`) —
//! read into one [`PoseTable`] and joined by time; and what a run records of them ([`PoseOrigin`]).
//!
//! **From the log.** One pass over the log gathers `/tf` and `/tf_static` (`tf2_msgs/TFMessage`)
//! into a transform tree, and every `nav_msgs/Odometry`, `geometry_msgs/PoseStamped` and
//! `geometry_msgs/PoseWithCovarianceStamped` topic into a track. The pose of a scan is the pose
//! of its cloud's `header.frame_id` at its header stamp:
//!
//! * with a transform chain (`pose_frames = "odom:velodyne"`, or found): the product of the
//!   transforms from the root frame down to the cloud's frame, each dynamic one interpolated;
//! * with a pose topic (`poses_topic = "/odom"`, or the only one): its track interpolated, then
//!   the mounting from `/tf_static` applied when the frame its poses are of is not the cloud's:
//!   Odometry's `child_frame_id`, the second frame of `pose_frames` for the others, else the
//!   cloud's own frame (a PoseStamped names no frame: it is taken as the sensor's unless said).
//!
//! Without a choice: the transform chain when `/tf` and `/tf_static` link the cloud's frame to a
//! root through at least one moving transform; else the only pose topic; else none (several
//! topics and no chain: an error naming them). Interpolation is linear in translation and
//! spherical (slerp) in rotation, between the two samples around the stamp when they lie within
//! twice the tolerance of each other; else the nearest sample within the tolerance; a scan with
//! none keeps no pose, counted by reason.
//!
//! **From a file** (`poses`): NCLT's ground-truth CSV, TUM's `t x y z qx qy qz qw`, or KITTI's
//! 3 × 4 rows (the sensor's pose, z up, as KISS-ICP writes it) with the times of `poses_times`
//! (seconds, one per row; relative times start at the session's first scan), joined by the
//! nearest time within the tolerance.

mod kitti;
mod log;
mod nclt;
mod origin;
mod tum;

pub use kitti::{KittiFrame, kitti_rows, read_times};
pub use log::{Choice, LogPoses, PoseKeys, TfTree, Track, parse_frames};
pub(crate) use nclt::find_for_session;
pub use origin::PoseOrigin;
pub use tum::parse_tum;

use super::rosmsg::{Iso, yaw_of};
use super::{NoPose, Pose, SourceError};
use std::path::{Path, PathBuf};

/// The layout of a pose file.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum PoseFormat {
    /// NCLT's ground-truth CSV (`utime, x, y, z, roll, pitch, heading`).
    #[default]
    Nclt,
    /// TUM's `t x y z qx qy qz qw` (seconds).
    Tum,
    /// KITTI's 3 × 4 rows of the sensor's pose (z up), with their times from `poses_times`.
    Kitti,
}

impl PoseFormat {
    /// The layout of a pose file given without one, the same everywhere (the command line,
    /// pipeline files, Python): KITTI with a times file, NCLT for `.csv`, else TUM.
    pub fn guess(file: &Path, times: Option<&Path>) -> PoseFormat {
        match (file.extension().and_then(|e| e.to_str()), times) {
            (_, Some(_)) => PoseFormat::Kitti,
            (Some(e), _) if e.eq_ignore_ascii_case("csv") => PoseFormat::Nclt,
            _ => PoseFormat::Tum,
        }
    }

    /// Its name, as `poses_format` and `--poses-format` spell it.
    pub fn name(self) -> &'static str {
        match self {
            PoseFormat::Nclt => "nclt",
            PoseFormat::Tum => "tum",
            PoseFormat::Kitti => "kitti",
        }
    }
}

/// A parsed pose file.
#[derive(Clone, Debug, Default)]
pub struct PoseTable {
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

impl PoseTable {
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

/// A transform as toporec keeps a scan's pose: position, and yaw about z.
pub fn pose_of(iso: &Iso) -> Pose {
    let t = iso.translation.vector;
    Pose { x: t.x, y: t.y, z: t.z, yaw: yaw_of(iso) }
}

/// A log's scan poses: from the log (its poses and the choice), or from a file.
#[derive(Clone, Debug)]
pub enum ScanPoses {
    /// From the log.
    Log(std::sync::Arc<LogPoses>, Choice),
    /// From a file.
    File(std::sync::Arc<PoseTable>),
}

impl ScanPoses {
    /// The pose at `stamp_ns` within `tol_ns`, or why there is none.
    pub fn at(&self, stamp_ns: i64, tol_ns: i64) -> Result<Pose, NoPose> {
        match self {
            ScanPoses::Log(poses, choice) => {
                poses.pose_at(choice, stamp_ns, tol_ns).map(|p| pose_of(&p)).ok_or(NoPose::NoRowNear)
            }
            ScanPoses::File(gt) => gt.pose_at(stamp_ns.div_euclid(1000), tol_ns / 1000),
        }
    }
}

/// Reads a pose file of `format` (`times`: KITTI's `times.txt`; `first_us`: the session's first
/// scan time, for relative times) as a time-indexed table. A file that cannot be read is named
/// as the pose file (or its times file).
pub fn read_file(
    path: &Path,
    format: PoseFormat,
    times: Option<&Path>,
    first_us: Option<i64>,
) -> Result<PoseTable, SourceError> {
    read_file_unnamed(path, format, times, first_us).map_err(|e| match e {
        SourceError::Io { path: p, source } => {
            let what = if p == path { "the pose file" } else { "the pose file's times" };
            SourceError::invalid(&p, format!("cannot read {what}: {source}"))
        }
        e => e,
    })
}

fn read_file_unnamed(
    path: &Path,
    format: PoseFormat,
    times: Option<&Path>,
    first_us: Option<i64>,
) -> Result<PoseTable, SourceError> {
    match format {
        PoseFormat::Nclt => PoseTable::read_nclt(path),
        PoseFormat::Tum => {
            let text = std::fs::read_to_string(path)
                .map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
            Ok(parse_tum(&text, path))
        }
        PoseFormat::Kitti => {
            let Some(times) = times else {
                return Err(SourceError::invalid(
                    path,
                    "a KITTI poses file has no times: give `poses_times` (its times.txt, seconds per row)",
                ));
            };
            let secs = read_times(times)?;
            // Relative times (a sequence's times.txt starts at 0) start at the first scan.
            let offset = match (secs.first().copied().flatten(), first_us) {
                (Some(t0), Some(first)) if t0.abs() < 1e6 => first,
                _ => 0,
            };
            let rows = kitti_rows(path, KittiFrame::Sensor)?;
            if rows.len() != secs.len() {
                return Err(SourceError::invalid(
                    path,
                    format!(
                        "{} poses and {} times in {}: one time per pose",
                        rows.len(),
                        secs.len(),
                        times.display()
                    ),
                ));
            }
            let mut gt = PoseTable { path: path.to_owned(), ..Default::default() };
            gt.rows = rows
                .into_iter()
                .zip(&secs)
                .filter_map(|(p, t)| Some(((t.as_ref()? * 1e6).round() as i64 + offset, p)))
                .collect();
            gt.rows.sort_by_key(|r| r.0);
            Ok(gt)
        }
    }
}

/// [`read_file`], refusing a file that holds no pose of its layout (the wrong layout, most
/// likely): the error names the file and `--poses-format`.
pub fn read_nonempty(
    path: &Path,
    format: PoseFormat,
    times: Option<&Path>,
    first_us: Option<i64>,
) -> Result<PoseTable, SourceError> {
    let gt = read_file(path, format, times, first_us)?;
    if gt.rows.is_empty() {
        let layout = match format {
            PoseFormat::Nclt => "NCLT: utime,x,y,z,roll,pitch,heading",
            PoseFormat::Tum => "TUM: t x y z qx qy qz qw",
            PoseFormat::Kitti => "KITTI: 3 x 4 rows",
        };
        return Err(SourceError::invalid(
            path,
            format!("no pose read as {layout}; give its layout with --poses-format (tum, kitti, nclt)"),
        ));
    }
    Ok(gt)
}
