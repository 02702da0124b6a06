//! The bag source (`kind = "rosbag"`): ROS 1 bags ([`super::ros1bag`]), rosbag2 folders and
//! lone `.db3` files ([`super::rosbag2`]), and MCAP files, each path read by what it is
//! ([`super::logs::LogKind`]), each one session: a bag file by its stem, a rosbag2 folder by its
//! name (its split files continue one another). Topic, ids, times and poses as for every log.

use super::logs::LogSettings;
use super::{ScanStream, SourceError};
use std::path::{Path, PathBuf};

/// `kind = "rosbag"` in a pipeline file.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RosbagSpec {
    /// ROS 1 `.bag` files, rosbag2 folders, rosbag2 `.db3` files or MCAP files; each is one
    /// session (unless `session` is set).
    pub paths: Vec<PathBuf>,
    /// The point-cloud topic; default: the bag's only one.
    #[serde(default)]
    pub topic: Option<String>,
    /// Session name for all paths (default: a file's stem, a folder's name).
    #[serde(default)]
    pub session: Option<String>,
    /// Poses in NCLT's ground-truth CSV layout, joined by nearest utime.
    #[serde(default)]
    pub poses: Option<PathBuf>,
    /// Largest time gap for a pose join, milliseconds.
    #[serde(default = "default_tolerance_ms")]
    pub tolerance_ms: f64,
}

fn default_tolerance_ms() -> f64 {
    100.0
}

impl RosbagSpec {
    /// A spec for one bag with defaults.
    pub fn path(path: &Path) -> Self {
        RosbagSpec {
            paths: vec![path.to_owned()],
            topic: None,
            session: None,
            poses: None,
            tolerance_ms: default_tolerance_ms(),
        }
    }

    /// How the bags are read.
    pub(crate) fn settings(&self) -> LogSettings {
        LogSettings {
            topic: self.topic.clone(),
            session: self.session.clone(),
            poses: self.poses.clone(),
            tolerance_ms: self.tolerance_ms,
        }
    }

    /// Opens the stream over all bags, in order; a bag that cannot be opened is one failure
    /// naming it, and the others are read.
    pub fn open(&self) -> Result<ScanStream, SourceError> {
        self.settings().open(self.paths.clone())
    }

    /// The scans of `path` whose message index lies in `range` (as [`super::mcap::McapSpec::open_range`]).
    pub fn open_range(&self, path: &Path, range: std::ops::Range<u64>) -> Result<ScanStream, SourceError> {
        self.settings().open_range(path, range)
    }
}
