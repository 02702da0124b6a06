//! Sources: decoding point clouds from the files users already have.
//!
//! Owns byte layouts and file formats; knows nothing of topology. Every error names the file
//! and, where it applies, the record or line.
//!
//! Axis convention: clouds are exposed in metres in the sensor frame, right-handed with z up.
//! KITTI already is (x forward, y left, z up); NCLT stores z down (NED-like), so its records
//! are rotated by 180° about x: `(x, y, z) → (x, -y, -z)` (a rotation, so distances — and
//! hence diagrams — are unchanged).

pub mod clouds;
pub mod csv;
pub mod detect;
pub mod groundtruth;
pub mod kitti;
pub mod logs;
pub mod mcap;
pub mod mcap_reader;
pub mod nclt;
pub mod pcd;
pub mod ply;
pub mod pointcloud2;
pub mod pointnetvlad;
pub mod ros1bag;
pub mod rosbag;
pub mod rosbag2;

pub use crate::error::SourceError;
pub use detect::{CloudFormat, InputKind};

use crate::types::Point;
use std::path::{Path, PathBuf};

pub use crate::types::Pose;

/// One LiDAR scan as a source yields it.
#[derive(Clone, Debug, PartialEq)]
pub struct Scan {
    /// Stable id, `<session>/<utime>` (NCLT), `<session>/<frame>` (KITTI) or
    /// `<session>/<index>` (MCAP, index of the message on its topic).
    pub id: String,
    /// Content fingerprint: xxh3-64 of the scan's raw bytes (the file, the MCAP message, the
    /// packets). Every random choice made for the scan is seeded from it.
    pub fingerprint: u64,
    /// Session (NCLT date folder, KITTI sequence folder, MCAP file stem).
    pub session: String,
    /// The file it came from.
    pub path: PathBuf,
    /// MCAP: 0-based index of the message among the topic's point clouds.
    pub message_index: Option<u64>,
    /// Timestamp in microseconds.
    pub utime: i64,
    /// Points (metres, sensor frame, z up); non-finite and zero points already dropped.
    pub points: Vec<Point>,
    /// Per-point intensity, when the source has it.
    pub intensity: Option<Vec<f32>>,
    /// Per-point ring / laser id, when the source has it.
    pub ring: Option<Vec<u16>>,
    /// Points in the record before dropping non-finite and zero points.
    pub raw_points: usize,
    /// Ground-truth pose, when joined.
    pub pose: Option<Pose>,
    /// Why there is no pose (when `pose` is `None`).
    pub no_pose: Option<NoPose>,
}

impl Scan {
    /// A scan of points handed over in memory rather than read from a file (the Python
    /// package, `describe_batch`): fingerprinted by the points' bytes, so its random choices
    /// are seeded from its content; no time (0) and no pose.
    pub fn of_points(id: String, session: String, path: PathBuf, points: Vec<Point>) -> Scan {
        let bytes: Vec<u8> = points.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
        Scan {
            id,
            fingerprint: crate::fingerprint::of_bytes(&bytes),
            session,
            path,
            message_index: None,
            utime: 0,
            raw_points: points.len(),
            points,
            intensity: None,
            ring: None,
            pose: None,
            no_pose: Some(NoPose::NoGroundTruth),
        }
    }
}

/// Why a scan has no pose.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum NoPose {
    /// No ground-truth file for its session (or none given).
    NoGroundTruth,
    /// No ground-truth row within the join tolerance.
    NoRowNear,
    /// The nearest ground-truth row holds a NaN or infinite value.
    NonFinite,
}

impl std::fmt::Display for NoPose {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            NoPose::NoGroundTruth => "no ground-truth file",
            NoPose::NoRowNear => "no ground-truth row within the tolerance",
            NoPose::NonFinite => "a non-finite ground-truth pose",
        })
    }
}

/// A joined pose as the scan carries it: the pose, or why there is none.
pub(crate) fn split_pose(pose: Result<Pose, NoPose>) -> (Option<Pose>, Option<NoPose>) {
    match pose {
        Ok(p) => (Some(p), None),
        Err(why) => (None, Some(why)),
    }
}

/// A scan that could not be read: where it was, and why. The stream goes on after it.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanFailure {
    /// Best-effort id (as [`Scan::id`], or derived from the location).
    pub id: String,
    /// Session.
    pub session: String,
    /// The file.
    pub path: PathBuf,
    /// MCAP message index, when known.
    pub message_index: Option<u64>,
    /// Timestamp, when known.
    pub utime: Option<i64>,
    /// Content fingerprint of the bytes, when they could be read.
    pub fingerprint: Option<u64>,
    /// The error, naming the file (and message or record).
    pub error: String,
    /// Whether the input (a file, a session) could not be read whole: scans it holds may be
    /// missing from the stream, so none of them is taken as gone (`run --prune` keeps them).
    pub input_unread: bool,
}

impl ScanFailure {
    /// A failure of the scan stored in `path` (no message index).
    pub fn of_file(id: String, session: &str, path: &Path, utime: Option<i64>, error: String) -> Self {
        ScanFailure {
            id,
            session: session.to_string(),
            path: path.to_owned(),
            message_index: None,
            utime,
            fingerprint: None,
            error,
            input_unread: false,
        }
    }

    /// An input of `session` — a file or folder at `path` — that could not be read (whole or
    /// from some point on): one failure, id `<session>/<file name>`, for every scan it holds.
    pub fn of_input(session: &str, path: &Path, error: String) -> Self {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        ScanFailure {
            id: format!("{session}/{name}"),
            session: session.to_string(),
            path: path.to_owned(),
            message_index: None,
            utime: None,
            fingerprint: None,
            error,
            input_unread: true,
        }
    }

    /// The same failure, with the fingerprint of the bytes that were read.
    pub fn with_fingerprint(self, fingerprint: u64) -> Self {
        ScanFailure { fingerprint: Some(fingerprint), ..self }
    }
}

impl std::fmt::Display for ScanFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.error)
    }
}

/// A stream of scans; failures are items too, so one bad scan never stops a run.
pub type ScanStream = Box<dyn Iterator<Item = Result<Scan, ScanFailure>> + Send>;

/// Where scans come from (a `[[sources]]` table of a pipeline file).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum SourceSpec {
    /// NCLT sessions.
    Nclt(nclt::NcltSpec),
    /// MCAP files with PointCloud2 messages.
    Mcap(mcap::McapSpec),
    /// KITTI odometry sequences.
    Kitti(kitti::KittiSpec),
    /// The PointNetVLAD benchmark's test submaps (`benchmark_datasets/`).
    PointNetVlad(pointnetvlad::PointNetVladSpec),
    /// ROS 1 bags, rosbag2 folders (sqlite3 or MCAP storage), `.db3` and MCAP files.
    Rosbag(rosbag::RosbagSpec),
    /// Folders of PCD / PLY files, each a session.
    Clouds(clouds::CloudsSpec),
}

impl SourceSpec {
    /// Opens the stream. Fails only when the source as a whole is unusable (a missing folder,
    /// an MCAP without point clouds); per-scan problems are stream items.
    pub fn open(&self) -> Result<ScanStream, SourceError> {
        match self {
            SourceSpec::Nclt(s) => s.open(),
            SourceSpec::Mcap(s) => s.open(),
            SourceSpec::Kitti(s) => s.open(),
            SourceSpec::PointNetVlad(s) => s.open(),
            SourceSpec::Rosbag(s) => s.open(),
            SourceSpec::Clouds(s) => s.open(),
        }
    }

    /// The number of scans, when a directory listing tells (NCLT `velodyne_sync`, KITTI);
    /// None when only reading would (MCAP, `velodyne_hits`).
    pub fn count_hint(&self) -> Option<u64> {
        let count = |dir: &Path| list_files(dir, "bin").ok().map(|f| f.len() as u64);
        match self {
            SourceSpec::Nclt(s) if s.reader == nclt::NcltReader::Sync => {
                s.session_dirs().ok()?.iter().map(|d| count(&d.join("velodyne_sync"))).sum()
            }
            SourceSpec::Kitti(s) => s.sequences.iter().map(|d| count(&d.join("velodyne"))).sum(),
            _ => None,
        }
    }

    /// The sessions this source yields, with the folder or file each comes from.
    pub fn sessions(&self) -> Result<Vec<(String, PathBuf)>, SourceError> {
        let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        Ok(match self {
            SourceSpec::Nclt(s) => s.session_dirs()?.into_iter().map(|d| (name(&d), d)).collect(),
            SourceSpec::Kitti(s) => s.sequences.iter().map(|d| (name(d), d.clone())).collect(),
            SourceSpec::PointNetVlad(s) => s.runs()?.into_iter().map(|r| (r.name, r.dir)).collect(),
            SourceSpec::Mcap(s) => s
                .files
                .iter()
                .map(|f| {
                    let stem = f.file_stem().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
                    (s.session.clone().unwrap_or(stem), f.clone())
                })
                .collect(),
            SourceSpec::Clouds(s) => s.folders.iter().map(|d| (name(d), d.clone())).collect(),
            SourceSpec::Rosbag(s) => s
                .paths
                .iter()
                .map(|p| (s.session.clone().unwrap_or_else(|| logs::default_session(p)), p.clone()))
                .collect(),
        })
    }

    /// This source restricted to the sessions in `wanted` (the same scans of those sessions,
    /// under the same ids); `None` when it yields none of them. A source whose sessions cannot
    /// be listed is kept whole (its stream is filtered by the caller).
    pub fn only_sessions(&self, wanted: &std::collections::HashSet<String>) -> Option<SourceSpec> {
        let Ok(listed) = self.sessions() else { return Some(self.clone()) };
        let keep: Vec<PathBuf> =
            listed.iter().filter(|(s, _)| wanted.contains(s)).map(|(_, p)| p.clone()).collect();
        if keep.is_empty() {
            return None;
        }
        let mut out = self.clone();
        match &mut out {
            SourceSpec::Nclt(s) => s.sessions = keep,
            SourceSpec::Kitti(s) => s.sequences = keep,
            SourceSpec::Mcap(s) => s.files = keep,
            SourceSpec::Rosbag(s) => s.paths = keep,
            SourceSpec::Clouds(s) => s.folders = keep,
            // Runs are named by their set and folder: the stream is filtered instead.
            SourceSpec::PointNetVlad(_) => {}
        }
        Some(out)
    }

    /// Makes relative paths relative to `base` (the pipeline file's folder).
    pub fn resolve_paths(&mut self, base: &Path) {
        self.clean_paths(|p| if p.is_relative() { base.join(p) } else { p.to_owned() });
    }

    /// Rewrites every path of the spec with `f`.
    pub fn clean_paths(&mut self, f: impl Fn(&Path) -> PathBuf) {
        let fix = |p: &mut PathBuf| *p = f(p);
        match self {
            SourceSpec::Nclt(s) => {
                s.sessions.iter_mut().for_each(fix);
                s.groundtruth.iter_mut().for_each(fix);
            }
            SourceSpec::Mcap(s) => {
                s.files.iter_mut().for_each(fix);
                s.poses.iter_mut().for_each(fix);
            }
            SourceSpec::Kitti(s) => s.sequences.iter_mut().for_each(fix),
            SourceSpec::PointNetVlad(s) => fix(&mut s.root),
            SourceSpec::Rosbag(s) => {
                s.paths.iter_mut().for_each(fix);
                s.poses.iter_mut().for_each(fix);
            }
            SourceSpec::Clouds(s) => {
                s.folders.iter_mut().for_each(fix);
                s.poses.iter_mut().for_each(fix);
            }
        }
    }
}

/// Lists `dir`'s files with extension `ext`, sorted by name.
pub(crate) fn list_files(dir: &Path, ext: &str) -> Result<Vec<PathBuf>, SourceError> {
    let entries =
        std::fs::read_dir(dir).map_err(|source| SourceError::Io { path: dir.to_owned(), source })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().is_some_and(|e| e.eq_ignore_ascii_case(ext)))
        .collect();
    files.sort();
    Ok(files)
}

/// Whether a point is a real return: finite, and not the exact `(0, 0, 0)` that sensors
/// write for no-returns.
pub(crate) fn is_return(p: &Point) -> bool {
    p.iter().all(|v| v.is_finite()) && *p != [0.0; 3]
}

/// Drops points that are not returns ([`is_return`]), keeping channels aligned.
pub(crate) fn drop_invalid(
    points: &mut Vec<Point>,
    intensity: &mut Option<Vec<f32>>,
    ring: &mut Option<Vec<u16>>,
) {
    let keep: Vec<bool> = points.iter().map(is_return).collect();
    if keep.iter().all(|&k| k) {
        return;
    }
    let mut k = keep.iter();
    points.retain(|_| *k.next().unwrap());
    if let Some(v) = intensity {
        let mut k = keep.iter();
        v.retain(|_| *k.next().unwrap());
    }
    if let Some(v) = ring {
        let mut k = keep.iter();
        v.retain(|_| *k.next().unwrap());
    }
}

/// Reads one cloud from `path` in `format` (detected from the path if `None`).
pub fn read_cloud(path: &Path, format: Option<CloudFormat>) -> Result<Vec<Point>, SourceError> {
    read_cloud_file(path, format).map(|(points, _)| points)
}

/// Reads one cloud and the content fingerprint of its file.
pub(crate) fn read_cloud_file(
    path: &Path,
    format: Option<CloudFormat>,
) -> Result<(Vec<Point>, u64), SourceError> {
    let format = match format {
        Some(f) => f,
        None => match InputKind::detect(path)? {
            InputKind::Cloud(f) => f,
            kind => {
                return Err(SourceError::invalid(
                    path,
                    format!("a {}, not a single cloud file", kind.name()),
                ));
            }
        },
    };
    let bytes = std::fs::read(path).map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
    let fingerprint = crate::fingerprint::of_bytes(&bytes);
    let points = match format {
        CloudFormat::Csv => csv::parse_xyz(&bytes, path)?,
        CloudFormat::Kitti => kitti::decode(&bytes, path)?.points,
        CloudFormat::Nclt => nclt::decode_sync(&bytes, path)?.points,
        CloudFormat::Pcd => pcd::decode(&bytes, path)?,
        CloudFormat::Ply => ply::decode(&bytes, path)?,
    };
    if let Some(index) = points.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        return Err(SourceError::NonFinite { path: path.to_owned(), index });
    }
    Ok((points, fingerprint))
}
