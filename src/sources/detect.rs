//! What a path given on the command line is — an NCLT session (or a folder of them), a
//! `velodyne_hits.bin`, a KITTI sequence (or `sequences/`), an MCAP, a ROS 1 bag, a rosbag2
//! folder or `.db3` file (by their magic or `metadata.yaml`), or one
//! cloud file (by extension and folder) — and the source that reads it. `inspect`, `query`
//! and `diagram` all decide here.

use super::kitti::KittiSpec;
use super::logs::LogKind;
use super::mcap::McapSpec;
use super::nclt::{NcltReader, NcltSpec, is_session};
use super::rosbag::RosbagSpec;
use super::{SourceError, SourceSpec};
use std::path::{Path, PathBuf};

/// A single-cloud file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CloudFormat {
    /// CSV with a header naming columns `x`, `y`, `z`.
    Csv,
    /// KITTI `.bin`: float32 x, y, z, reflectance.
    Kitti,
    /// NCLT `velodyne_sync` `.bin`: 8-byte records.
    Nclt,
    /// PCD (PCL): ascii, binary or binary_compressed.
    Pcd,
    /// PLY: ascii or binary, the vertices' x, y, z.
    Ply,
}

impl CloudFormat {
    /// The format a file name implies: `.csv`, `.pcd`, `.ply`; `.bin` under a `velodyne_sync` folder is NCLT,
    /// any other `.bin` KITTI.
    pub fn of_path(path: &Path) -> Option<Self> {
        match path.extension()?.to_str()?.to_ascii_lowercase().as_str() {
            "csv" => Some(CloudFormat::Csv),
            "pcd" => Some(CloudFormat::Pcd),
            "ply" => Some(CloudFormat::Ply),
            "bin" => {
                let parent = path.parent().and_then(|p| p.file_name()).and_then(|n| n.to_str());
                Some(if parent == Some("velodyne_sync") { CloudFormat::Nclt } else { CloudFormat::Kitti })
            }
            _ => None,
        }
    }
}

/// What a path holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputKind {
    /// One NCLT session folder.
    NcltSession,
    /// A folder of NCLT sessions.
    NcltSessions,
    /// An NCLT `velodyne_hits.bin`.
    NcltHits,
    /// One KITTI sequence folder.
    KittiSequence,
    /// A folder of KITTI sequences.
    KittiSequences,
    /// An MCAP file.
    Mcap,
    /// A ROS 1 bag, a rosbag2 folder or a rosbag2 `.db3` file.
    Bag(LogKind),
    /// A folder of PCD / PLY files (a session).
    CloudFolder,
    /// One cloud file.
    Cloud(CloudFormat),
}

/// Whether the file starts with the MCAP magic.
pub(crate) fn is_mcap(path: &Path) -> bool {
    let mut magic = [0u8; 8];
    std::fs::File::open(path).and_then(|mut f| std::io::Read::read_exact(&mut f, &mut magic)).is_ok()
        && magic == ::mcap::MAGIC
}

fn is_kitti_sequence(dir: &Path) -> bool {
    dir.join("velodyne").is_dir()
}

fn children(path: &Path) -> Result<Vec<PathBuf>, SourceError> {
    let entries =
        std::fs::read_dir(path).map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
    let mut out: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    out.sort();
    Ok(out)
}

impl InputKind {
    /// Decides what `path` is.
    pub fn detect(path: &Path) -> Result<Self, SourceError> {
        if path.is_dir() {
            if let Some(kind) = LogKind::detect(path) {
                return Ok(InputKind::Bag(kind));
            }
            if is_session(path) {
                return Ok(InputKind::NcltSession);
            }
            if is_kitti_sequence(path) {
                return Ok(InputKind::KittiSequence);
            }
            let children = children(path)?;
            if children.iter().any(|c| is_session(c)) {
                return Ok(InputKind::NcltSessions);
            }
            if children.iter().any(|c| is_kitti_sequence(c)) {
                return Ok(InputKind::KittiSequences);
            }
            if super::clouds::is_cloud_folder(path) {
                return Ok(InputKind::CloudFolder);
            }
            return Err(SourceError::invalid(
                path,
                "no NCLT session, KITTI sequence, rosbag2 metadata.yaml or PCD/PLY file here",
            ));
        }
        if !path.exists() {
            let source = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or folder");
            return Err(SourceError::Io { path: path.to_owned(), source });
        }
        match LogKind::detect(path) {
            Some(LogKind::Mcap) => return Ok(InputKind::Mcap),
            Some(kind) => return Ok(InputKind::Bag(kind)),
            None => {}
        }
        if path.file_name().is_some_and(|n| n == "velodyne_hits.bin") {
            return Ok(InputKind::NcltHits);
        }
        CloudFormat::of_path(path)
            .map(InputKind::Cloud)
            .ok_or_else(|| SourceError::UnknownFormat { path: path.to_owned() })
    }

    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            InputKind::NcltSession => "nclt session",
            InputKind::NcltSessions => "nclt sessions",
            InputKind::NcltHits => "nclt velodyne_hits",
            InputKind::KittiSequence => "kitti sequence",
            InputKind::KittiSequences => "kitti sequences",
            InputKind::Mcap => "mcap",
            InputKind::Bag(kind) => kind.name(),
            InputKind::CloudFolder => "folder of clouds",
            InputKind::Cloud(CloudFormat::Csv) => "csv cloud",
            InputKind::Cloud(CloudFormat::Kitti) => "kitti scan",
            InputKind::Cloud(CloudFormat::Nclt) => "nclt velodyne_sync scan",
            InputKind::Cloud(CloudFormat::Pcd) => "pcd cloud",
            InputKind::Cloud(CloudFormat::Ply) => "ply cloud",
        }
    }

    /// The source that reads `path` of this kind (`topic` picks an MCAP topic); None for a
    /// single cloud file.
    pub fn source(self, path: &Path, topic: Option<&str>) -> Result<Option<SourceSpec>, SourceError> {
        Ok(Some(match self {
            InputKind::Mcap => {
                SourceSpec::Mcap(McapSpec { topic: topic.map(String::from), ..McapSpec::file(path) })
            }
            InputKind::CloudFolder => SourceSpec::Clouds(super::clouds::CloudsSpec::folder(path)),
            InputKind::Bag(_) => {
                SourceSpec::Rosbag(RosbagSpec { topic: topic.map(String::from), ..RosbagSpec::path(path) })
            }
            InputKind::NcltSession | InputKind::NcltSessions => {
                SourceSpec::Nclt(NcltSpec::sessions(vec![path.to_owned()]))
            }
            InputKind::NcltHits => {
                let dir = path.parent().unwrap_or(Path::new(".")).to_owned();
                SourceSpec::Nclt(NcltSpec { reader: NcltReader::Hits, ..NcltSpec::sessions(vec![dir]) })
            }
            InputKind::KittiSequence => SourceSpec::Kitti(KittiSpec { sequences: vec![path.to_owned()] }),
            InputKind::KittiSequences => {
                let sequences = children(path)?.into_iter().filter(|p| is_kitti_sequence(p)).collect();
                SourceSpec::Kitti(KittiSpec { sequences })
            }
            InputKind::Cloud(_) => return Ok(None),
        }))
    }
}
