//! Folders of single-cloud files (`kind = "clouds"`): each folder is a session, its `.pcd` and
//! `.ply` files the scans, in name order (PCD and PLY as [`super::pcd`] and [`super::ply`] read
//! them). A scan's id is `<folder name>/<file stem>`, so ids are stable across runs.
//!
//! What a numeric file name means is the `names` setting:
//! - `index` (default): a frame number (`0000000153.pcd`, as KITTI raw's exports); a name that
//!   is not a number takes its place in the folder instead. The scan has no time (loops keep
//!   its neighbours out by position, `--exclude-scans`), unless `frame_period_ms` gives one:
//!   the frame times that period.
//! - `seconds`, `milliseconds`, `microseconds`, `nanoseconds`: a timestamp in that unit (a
//!   decimal point allowed); a name that is not one is a failure naming the file.
//!
//! Poses (optional, `poses`): NCLT's ground-truth CSV layout or TUM's `t x y z qx qy qz qw`
//! (`poses_format = "tum"`; seconds; `#` comments; what KISS-ICP and most SLAM tools write;
//! yaw from the quaternion, z up as written). With timestamp names a scan takes the pose
//! nearest in time within `tolerance_ms`; with frame indices, the pose on the frame's row (the
//! k-th pose in time order for frame k).

use super::poses::PoseTable;
use super::{NoPose, Scan, ScanFailure, ScanStream, SourceError};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// What a numeric file name means.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FileNames {
    /// A frame number.
    #[default]
    Index,
    /// A timestamp in seconds.
    Seconds,
    /// A timestamp in milliseconds.
    Milliseconds,
    /// A timestamp in microseconds.
    Microseconds,
    /// A timestamp in nanoseconds.
    Nanoseconds,
}

pub use super::poses::PoseFormat;

/// `kind = "clouds"` in a pipeline file.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CloudsSpec {
    /// Folders of `.pcd` / `.ply` files; each is one session named by the folder.
    pub folders: Vec<PathBuf>,
    /// What a numeric file name means.
    #[serde(default)]
    pub names: FileNames,
    /// With `names = "index"`: the time between frames (ms), when it is known; without it the
    /// scans have no time.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_period_ms: Option<f64>,
    /// Poses for every folder (one session's, usually).
    #[serde(default)]
    pub poses: Option<PathBuf>,
    /// The layout of `poses` (default: guessed as `--poses` guesses it, [`PoseFormat::guess`]:
    /// `nclt` for `.csv`, else `tum`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poses_format: Option<PoseFormat>,
    /// Largest time gap for a pose join by time, milliseconds.
    #[serde(default = "default_tolerance_ms")]
    pub tolerance_ms: f64,
}

fn default_tolerance_ms() -> f64 {
    100.0
}

/// Whether `path` is a cloud file a folder session holds.
fn is_cloud_file(path: &Path) -> bool {
    path.is_file()
        && path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("pcd") || e.eq_ignore_ascii_case("ply"))
}

/// Whether `dir` is a folder holding `.pcd` or `.ply` files.
pub fn is_cloud_folder(dir: &Path) -> bool {
    std::fs::read_dir(dir).is_ok_and(|entries| entries.flatten().any(|e| is_cloud_file(&e.path())))
}

/// The cloud files of `dir`, in name order.
fn cloud_files(dir: &Path) -> Result<Vec<PathBuf>, SourceError> {
    let entries =
        std::fs::read_dir(dir).map_err(|source| SourceError::Io { path: dir.to_owned(), source })?;
    let mut files: Vec<PathBuf> = entries.flatten().map(|e| e.path()).filter(|p| is_cloud_file(p)).collect();
    files.sort();
    Ok(files)
}

pub use super::poses::parse_tum;

impl super::Kind for CloudsSpec {
    const NAME: &'static str = "clouds";
    const READS: &'static str = "PCD/PLY file";

    fn detect(path: &Path) -> Option<super::Detected> {
        (path.is_dir() && is_cloud_folder(path)).then(|| super::Detected {
            what: "folder of clouds",
            source: super::SourceSpec::new(CloudsSpec::folder(path)),
        })
    }
}

impl super::Source for CloudsSpec {
    fn kind(&self) -> &'static str {
        <Self as super::Kind>::NAME
    }

    fn keys(&self) -> toml::Table {
        toml::Table::try_from(self).expect("plain data")
    }

    fn problems(&self, inputs: bool) -> Vec<(&'static str, String)> {
        let mut out = super::required("folders", &self.folders, inputs);
        out.extend(super::missing("poses", self.poses.as_slice(), inputs));
        if let Some(period) = self.frame_period_ms.filter(|p| !(p.is_finite() && *p > 0.0)) {
            out.push(("frame_period_ms", format!("must be in (0, inf) ms; found {period}")));
        }
        out.extend(super::tolerance(self.tolerance_ms));
        out
    }

    fn open(&self) -> Result<ScanStream, SourceError> {
        CloudsSpec::open(self)
    }

    fn sessions(&self) -> Result<Vec<(String, PathBuf)>, SourceError> {
        let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        Ok(self.folders.iter().map(|d| (name(d), d.clone())).collect())
    }

    fn narrowed(&self, places: Vec<PathBuf>) -> Option<Box<dyn super::Source>> {
        Some(Box::new(CloudsSpec { folders: places, ..self.clone() }))
    }

    fn session_folder(&self, file: &Path, _format: Option<super::CloudFormat>) -> Option<(String, PathBuf)> {
        let canonical = |p: &Path| p.canonicalize().unwrap_or_else(|_| p.to_owned());
        let wanted = canonical(file.parent()?);
        let dir = self.folders.iter().find(|d| canonical(d) == wanted)?;
        (is_cloud_file(file)).then(|| {
            (dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(), dir.clone())
        })
    }

    fn scan_files(
        &self,
        session: &str,
        dir: &Path,
        points_only: bool,
    ) -> Result<Arc<dyn super::ScanFiles>, SourceError> {
        let poses = if points_only { None } else { self.ground_truth()? };
        let files = cloud_files(dir)?;
        Ok(Arc::new(FolderFiles { spec: self.clone(), session: session.to_string(), poses, files }))
    }

    fn pose_origins(&self) -> Vec<super::poses::PoseOrigin> {
        let Some(file) = &self.poses else { return Vec::new() };
        let sessions = super::Source::sessions(self).unwrap_or_default().into_iter().map(|s| s.0).collect();
        let table = self.ground_truth().ok().flatten().map(|t| (*t).clone()).unwrap_or_default();
        let joined = match self.names {
            FileNames::Index => {
                format!("{} layout, row k for frame k", self.poses_layout().unwrap_or_default().name())
            }
            _ => format!(
                "{} layout, nearest time within {} ms",
                self.poses_layout().unwrap_or_default().name(),
                self.tolerance_ms
            ),
        };
        vec![super::poses::PoseOrigin::of_file(sessions, file, None, &table, &joined)]
    }

    fn paths_mut(&mut self) -> Vec<&mut PathBuf> {
        self.folders.iter_mut().chain(self.poses.iter_mut()).collect()
    }

    fn boxed(&self) -> Box<dyn super::Source> {
        Box::new(self.clone())
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

/// A folder's cloud files, with its poses read once.
struct FolderFiles {
    spec: CloudsSpec,
    session: String,
    poses: Option<Arc<PoseTable>>,
    /// The folder's cloud files in name order (a file's place, for names that are no number).
    files: Vec<PathBuf>,
}

impl super::ScanFiles for FolderFiles {
    fn scan(&self, path: &Path, _bytes: &[u8]) -> Result<Scan, ScanFailure> {
        let position = self.files.iter().position(|f| f == path).unwrap_or(self.files.len());
        self.spec.scan(&self.session, path, position, self.poses.as_deref())
    }
}

impl CloudsSpec {
    /// The layout of its pose file: given, or guessed ([`PoseFormat::guess`]).
    fn poses_layout(&self) -> Option<PoseFormat> {
        let file = self.poses.as_deref()?;
        Some(self.poses_format.unwrap_or_else(|| PoseFormat::guess(file, None)))
    }

    /// A spec for one folder with defaults.
    pub fn folder(dir: &Path) -> Self {
        CloudsSpec {
            folders: vec![dir.to_owned()],
            names: FileNames::default(),
            frame_period_ms: None,
            poses: None,
            poses_format: None,
            tolerance_ms: default_tolerance_ms(),
        }
    }

    fn ground_truth(&self) -> Result<Option<Arc<PoseTable>>, SourceError> {
        let Some(path) = &self.poses else { return Ok(None) };
        Ok(Some(Arc::new(match self.poses_layout().unwrap_or_default() {
            // KITTI rows have no times here: row k is frame k.
            PoseFormat::Kitti => {
                let rows = super::poses::kitti_rows(path, super::poses::KittiFrame::Sensor)?;
                let rows = rows.into_iter().enumerate().map(|(k, p)| (k as i64, p)).collect();
                PoseTable { path: path.to_owned(), rows, ..Default::default() }
            }
            format => super::poses::read_file(path, format, None, None)?,
        })))
    }

    /// The time of a scan (µs) from its file name, when it has one, and its frame (`position`:
    /// its place in the folder).
    fn utime_of(&self, path: &Path, position: usize) -> Result<(Option<i64>, Option<usize>), String> {
        let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let scale = match self.names {
            FileNames::Index => {
                let frame = stem.parse::<usize>().unwrap_or(position);
                let utime = self.frame_period_ms.map(|p| (frame as f64 * p * 1000.0).round() as i64);
                return Ok((utime, Some(frame)));
            }
            FileNames::Seconds => 1e6,
            FileNames::Milliseconds => 1e3,
            FileNames::Microseconds => 1.0,
            FileNames::Nanoseconds => 1e-3,
        };
        // Integers exactly (nanoseconds overflow f64's integers), decimals as f64.
        let t = match stem.parse::<i64>() {
            Ok(n) => match self.names {
                FileNames::Nanoseconds => Some(n.div_euclid(1000)),
                _ => n.checked_mul(scale as i64),
            },
            Err(_) => stem
                .parse::<f64>()
                .ok()
                .map(|v| (v * scale).round())
                .filter(|v| v.abs() < 9.2e18)
                .map(|v| v as i64),
        };
        t.map(|t| (Some(t), None))
            .ok_or_else(|| format!("file name `{stem}` is not a timestamp in {:?}", self.names))
    }

    /// Opens the stream: each folder's files in name order. A folder that cannot be listed is
    /// one failure naming it; a file that cannot be read is one failure naming it.
    #[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
    pub fn open(&self) -> Result<ScanStream, SourceError> {
        let poses = self.ground_truth()?;
        let spec = self.clone();
        let folders = self.folders.clone();
        Ok(Box::new(folders.into_iter().flat_map(move |dir| -> ScanStream {
            let session = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let files = match cloud_files(&dir) {
                Ok(f) => f,
                Err(e) => {
                    return Box::new(std::iter::once(Err(ScanFailure::of_input(
                        &session,
                        &dir,
                        e.to_string(),
                    ))));
                }
            };
            let (spec, poses) = (spec.clone(), poses.clone());
            Box::new(
                files
                    .into_iter()
                    .enumerate()
                    .map(move |(position, path)| spec.scan(&session, &path, position, poses.as_deref())),
            )
        })))
    }

    #[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
    fn scan(
        &self,
        session: &str,
        path: &Path,
        position: usize,
        poses: Option<&PoseTable>,
    ) -> Result<Scan, ScanFailure> {
        let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let id = format!("{session}/{stem}");
        let (utime, frame) = self.utime_of(path, position).map_err(|e| {
            ScanFailure::of_file(id.clone(), session, path, None, format!("{}: {e}", path.display()))
        })?;
        let (points, fingerprint) = super::read_cloud_file(path, None)
            .map_err(|e| ScanFailure::of_file(id.clone(), session, path, utime, e.to_string()))?;
        let pose = match (poses, frame) {
            (None, _) => Err(NoPose::NoGroundTruth),
            (Some(gt), Some(frame)) => match gt.rows.get(frame) {
                Some((_, Some(p))) => Ok(*p),
                Some((_, None)) => Err(NoPose::NonFinite),
                None => Err(NoPose::NoRowNear),
            },
            (Some(gt), None) => match utime {
                Some(t) => gt.pose_at(t, (self.tolerance_ms * 1000.0).round() as i64),
                None => Err(NoPose::NoRowNear),
            },
        };
        let (pose, no_pose) = super::split_pose(pose);
        let raw_points = points.len();
        let mut points = points;
        let (mut intensity, mut ring) = (None, None);
        super::drop_invalid(&mut points, &mut intensity, &mut ring);
        Ok(Scan {
            id,
            fingerprint,
            session: session.to_string(),
            path: path.to_owned(),
            message_index: None,
            utime,
            points,
            intensity,
            ring,
            raw_points,
            pose,
            no_pose,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_names_mean_frames_or_timestamps() {
        let mut spec = CloudsSpec::folder(Path::new("d"));
        // Frames have no time unless a period gives one.
        assert_eq!(spec.utime_of(Path::new("d/0000000153.pcd"), 7), Ok((None, Some(153))));
        assert_eq!(spec.utime_of(Path::new("d/scan_a.pcd"), 7), Ok((None, Some(7))));
        spec.frame_period_ms = Some(100.0);
        assert_eq!(spec.utime_of(Path::new("d/0000000153.pcd"), 7), Ok((Some(15_300_000), Some(153))));
        spec.names = FileNames::Nanoseconds;
        assert_eq!(
            spec.utime_of(Path::new("d/1317000009745340952.ply"), 0),
            Ok((Some(1_317_000_009_745_340), None))
        );
        spec.names = FileNames::Seconds;
        assert_eq!(
            spec.utime_of(Path::new("d/1317000009.745341.pcd"), 0),
            Ok((Some(1_317_000_009_745_341), None))
        );
        spec.names = FileNames::Milliseconds;
        assert_eq!(spec.utime_of(Path::new("d/1500.pcd"), 0), Ok((Some(1_500_000), None)));
        assert!(spec.utime_of(Path::new("d/frame.pcd"), 0).unwrap_err().contains("not a timestamp"));
    }

    #[test]
    fn tum_poses_parse_with_their_yaw() {
        let half = std::f64::consts::FRAC_1_SQRT_2;
        let text =
            format!("# t x y z qx qy qz qw\n1.5 1 2 3 0 0 {half} {half}\n0.5 0 0 0 0 0 0 1\nbad line\n");
        let gt = parse_tum(&text, Path::new("p.txt"));
        assert_eq!(gt.rows.len(), 2);
        assert_eq!(gt.rows[0], (500_000, Some(crate::sources::Pose { x: 0.0, y: 0.0, z: 0.0, yaw: 0.0 })));
        let p = gt.rows[1].1.unwrap();
        assert_eq!((gt.rows[1].0, p.x, p.y, p.z), (1_500_000, 1.0, 2.0, 3.0));
        assert!((p.yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert_eq!(gt.bad_lines.len(), 1);
    }
}
