//! KITTI odometry: Velodyne `.bin` scans, little-endian float32 records `x, y, z,
//! reflectance` (x forward, y left, z up, metres), in `sequences/NN/velodyne/`, with
//! `times.txt` (seconds) and `poses.txt` (3x4 poses of camera 0 in the frame of camera 0 at
//! frame 0). Poses are exposed z up: `(t_z, −t_x, −t_y)` (forward, left, up).

use super::{Pose, Scan, ScanFailure, ScanStream, SourceError};
use crate::types::Point;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Bytes per KITTI record.
pub(crate) const RECORD: usize = 16;

/// A decoded KITTI scan.
#[derive(Debug, Default)]
pub struct KittiScan {
    /// Points in metres.
    pub points: Vec<Point>,
    /// Reflectance per point.
    pub reflectance: Vec<f32>,
}

/// Decodes a KITTI `.bin` buffer.
pub fn decode(bytes: &[u8], path: &Path) -> Result<KittiScan, SourceError> {
    if !bytes.len().is_multiple_of(RECORD) {
        return Err(SourceError::Truncated { path: path.to_owned(), len: bytes.len(), record: RECORD });
    }
    let n = bytes.len() / RECORD;
    let mut scan = KittiScan { points: Vec::with_capacity(n), reflectance: Vec::with_capacity(n) };
    for r in bytes.chunks_exact(RECORD) {
        let f = |o: usize| f32::from_le_bytes([r[o], r[o + 1], r[o + 2], r[o + 3]]);
        scan.points.push([f(0) as f64, f(4) as f64, f(8) as f64]);
        scan.reflectance.push(f(12));
    }
    Ok(scan)
}

/// `kind = "kitti"` in a pipeline file.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KittiSpec {
    /// Sequence folders (`sequences/NN`, holding `velodyne/*.bin`, `times.txt`, `poses.txt`).
    pub sequences: Vec<PathBuf>,
}

/// A KITTI sequence's side files: per-frame times (s) and poses. A NaN or infinite value
/// leaves that frame without a time (its frame number stands in) or without a pose.
#[derive(Clone, Debug, Default)]
pub struct Sequence {
    /// `times.txt`, seconds per frame (`None`: not finite).
    pub times: Vec<Option<f64>>,
    /// `poses.txt` translations as poses (z up), per frame (`None`: not finite).
    pub poses: Vec<Option<Pose>>,
}

impl Sequence {
    /// Reads `times.txt` and `poses.txt` of a sequence folder (either may be absent; a bad
    /// line is an error naming the line), as [`super::poses`] reads KITTI's layout.
    pub fn read(dir: &Path) -> Result<Self, SourceError> {
        use super::poses::{KittiFrame, kitti_rows, read_times};
        let (times, poses) = (dir.join("times.txt"), dir.join("poses.txt"));
        Ok(Sequence {
            times: if times.is_file() { read_times(&times)? } else { Vec::new() },
            poses: if poses.is_file() { kitti_rows(&poses, KittiFrame::Camera)? } else { Vec::new() },
        })
    }
}

/// Whether `dir` is a KITTI sequence folder (it holds `velodyne/`).
fn is_sequence(dir: &Path) -> bool {
    dir.join("velodyne").is_dir()
}

impl super::Kind for KittiSpec {
    const NAME: &'static str = "kitti";
    const READS: &'static str = "KITTI sequence";

    fn detect(path: &Path) -> Option<super::Detected> {
        if !path.is_dir() {
            return None;
        }
        let (what, sequences) = if is_sequence(path) {
            ("kitti sequence", vec![path.to_owned()])
        } else {
            let mut children: Vec<PathBuf> = std::fs::read_dir(path)
                .ok()?
                .flatten()
                .map(|e| e.path())
                .filter(|p| is_sequence(p))
                .collect();
            children.sort();
            if children.is_empty() {
                return None;
            }
            ("kitti sequences", children)
        };
        Some(super::Detected { what, source: super::SourceSpec::new(KittiSpec { sequences }) })
    }
}

impl super::Source for KittiSpec {
    fn kind(&self) -> &'static str {
        <Self as super::Kind>::NAME
    }

    fn keys(&self) -> toml::Table {
        toml::Table::try_from(self).expect("plain data")
    }

    fn problems(&self, inputs: bool) -> Vec<(&'static str, String)> {
        super::required("sequences", &self.sequences, inputs)
    }

    fn open(&self) -> Result<ScanStream, SourceError> {
        KittiSpec::open(self)
    }

    fn sessions(&self) -> Result<Vec<(String, PathBuf)>, SourceError> {
        let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        Ok(self.sequences.iter().map(|d| (name(d), d.clone())).collect())
    }

    fn narrowed(&self, places: Vec<PathBuf>) -> Option<Box<dyn super::Source>> {
        Some(Box::new(KittiSpec { sequences: places }))
    }

    fn count_hint(&self) -> Option<u64> {
        let count = |d: &Path| super::list_files(&d.join("velodyne"), "bin").ok().map(|f| f.len() as u64);
        self.sequences.iter().map(|d| count(d)).sum()
    }

    fn session_folder(&self, file: &Path, format: Option<super::CloudFormat>) -> Option<(String, PathBuf)> {
        let in_layout = file.parent()?.file_name()? == "velodyne";
        if !(in_layout || format == Some(super::CloudFormat::Kitti)) {
            return None;
        }
        let dir = file.parent()?.parent()?;
        let canonical = |p: &Path| p.canonicalize().unwrap_or_else(|_| p.to_owned());
        let wanted = canonical(dir);
        let dir = self.sequences.iter().find(|d| canonical(d) == wanted)?;
        Some((dir.file_name()?.to_string_lossy().into_owned(), dir.clone()))
    }

    fn scan_files(
        &self,
        session: &str,
        dir: &Path,
        points_only: bool,
    ) -> Result<Arc<dyn super::ScanFiles>, SourceError> {
        let mut seq = Sequence::read(dir)?;
        if points_only {
            seq.poses.clear();
        }
        Ok(Arc::new(FrameFiles { session: session.to_string(), seq }))
    }

    fn pose_origins(&self) -> Vec<super::poses::PoseOrigin> {
        let Ok(sessions) = super::Source::sessions(self) else { return Vec::new() };
        sessions
            .into_iter()
            .filter_map(|(session, dir)| {
                let file = dir.join("poses.txt");
                let times = dir.join("times.txt");
                let times = times.is_file().then_some(times);
                file.is_file()
                    .then(|| super::poses::PoseOrigin::of_kitti_sequence(session, &file, times.as_deref()))
            })
            .collect()
    }

    fn paths_mut(&mut self) -> Vec<&mut PathBuf> {
        self.sequences.iter_mut().collect()
    }

    fn overview(&self) -> Result<Vec<String>, SourceError> {
        Ok(vec![format!("sequences: {}", self.sequences.len())])
    }

    fn boxed(&self) -> Box<dyn super::Source> {
        Box::new(self.clone())
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

impl KittiSpec {
    /// Opens the stream over all sequences, in order.
    #[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
    pub fn open(&self) -> Result<ScanStream, SourceError> {
        let mut streams: Vec<ScanStream> = Vec::new();
        // A sequence that cannot be opened is one failure naming it; the others are read.
        for dir in &self.sequences {
            let session = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let opened = (|| -> Result<(Arc<Sequence>, Vec<PathBuf>), SourceError> {
                let velodyne = dir.join("velodyne");
                if !velodyne.is_dir() {
                    return Err(SourceError::invalid(dir, "not a KITTI sequence (no velodyne/ folder)"));
                }
                Ok((Arc::new(Sequence::read(dir)?), super::list_files(&velodyne, "bin")?))
            })();
            match opened {
                Ok((seq, files)) => streams
                    .push(Box::new(files.into_iter().map(move |path| frame_scan(&path, &session, &seq)))),
                Err(e) => {
                    let failure = ScanFailure::of_input(&session, dir, e.to_string());
                    streams.push(Box::new(std::iter::once(Err(failure))));
                }
            }
        }
        Ok(Box::new(streams.into_iter().flatten()))
    }
}

/// A sequence's frames, with its times and poses read once.
struct FrameFiles {
    session: String,
    seq: Sequence,
}

impl super::ScanFiles for FrameFiles {
    fn scan(&self, path: &Path, bytes: &[u8]) -> Result<Scan, ScanFailure> {
        frame_scan_bytes(path, bytes, &self.session, &self.seq)
    }
}

#[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
fn frame_scan(path: &Path, session: &str, seq: &Sequence) -> Result<Scan, ScanFailure> {
    let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let frame: Option<usize> = name.parse().ok();
    let utime = frame.and_then(|f| seq.times.get(f).copied().flatten()).map(|t| (t * 1e6).round() as i64);
    let fail = |error: String| ScanFailure::of_file(format!("{session}/{name}"), session, path, utime, error);
    let bytes = std::fs::read(path).map_err(|e| fail(format!("{}: {e}", path.display())))?;
    frame_scan_bytes(path, &bytes, session, seq)
}

/// The scan of a `velodyne/<frame>.bin` file's `bytes` in sequence `session`, with its time
/// and pose from `seq`: as the KITTI source makes it from the file.
#[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
pub(crate) fn frame_scan_bytes(
    path: &Path,
    bytes: &[u8],
    session: &str,
    seq: &Sequence,
) -> Result<Scan, ScanFailure> {
    let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let frame: Option<usize> = name.parse().ok();
    let utime = frame.and_then(|f| seq.times.get(f).copied().flatten()).map(|t| (t * 1e6).round() as i64);
    let fail = |error: String| ScanFailure::of_file(format!("{session}/{name}"), session, path, utime, error);
    let Some(frame) = frame else {
        return Err(fail(format!("{}: file name is not a frame number", path.display())));
    };
    let fingerprint = crate::fingerprint::of_bytes(bytes);
    let mut scan = decode(bytes, path).map_err(|e| fail(e.to_string()).with_fingerprint(fingerprint))?;
    let raw_points = scan.points.len();
    let mut intensity = Some(std::mem::take(&mut scan.reflectance));
    let mut ring = None;
    super::drop_invalid(&mut scan.points, &mut intensity, &mut ring);
    Ok(Scan {
        id: format!("{session}/{frame:06}"),
        fingerprint,
        session: session.to_string(),
        path: path.to_owned(),
        message_index: None,
        // Without times.txt, no time: the frame's place orders it.
        utime,
        points: scan.points,
        intensity,
        ring,
        raw_points,
        pose: seq.poses.get(frame).copied().flatten(),
        no_pose: match seq.poses.get(frame) {
            Some(Some(_)) => None,
            Some(None) => Some(super::NoPose::NonFinite),
            None => Some(super::NoPose::NoGroundTruth),
        },
    })
}
