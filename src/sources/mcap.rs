//! The MCAP source (`kind = "mcap"`): `sensor_msgs/PointCloud2` messages (ROS 2 CDR or ROS 1)
//! of one topic per file, read as every message log is ([`super::logs`]: the topic, the scan
//! ids and times), optionally joined to poses from an NCLT-style CSV. The topics come from the
//! file's summary section, or by a first pass over the file when it has none.

use super::logs::LogSettings;
use super::mcap_reader::{ChannelInfo, McapMessages, summary_channels};
use super::{ScanStream, SourceError};
use std::path::{Path, PathBuf};

/// `kind = "mcap"` in a pipeline file.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct McapSpec {
    /// MCAP files; each is one session named by its file stem (unless `session` is set).
    pub files: Vec<PathBuf>,
    /// The point-cloud topic; default: the file's only one.
    #[serde(default)]
    pub topic: Option<String>,
    /// Session name for all files (default: each file's stem).
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

impl McapSpec {
    /// A spec for one file with defaults.
    pub fn file(path: &Path) -> Self {
        McapSpec {
            files: vec![path.to_owned()],
            topic: None,
            session: None,
            poses: None,
            tolerance_ms: default_tolerance_ms(),
        }
    }

    /// How the files are read.
    pub(crate) fn settings(&self) -> LogSettings {
        LogSettings {
            topic: self.topic.clone(),
            session: self.session.clone(),
            poses: self.poses.clone(),
            tolerance_ms: self.tolerance_ms,
        }
    }

    /// Opens the stream over all files, in order. A file that cannot be opened (not an MCAP,
    /// truncated before its first message, no point-cloud topic) is one failure naming it, and
    /// the other files are read.
    pub fn open(&self) -> Result<ScanStream, SourceError> {
        self.settings().open(self.files.clone())
    }

    /// The scans of `path` (one of the spec's files, or any file read with the spec's
    /// settings) whose message index lies in `range`: what [`McapSpec::open`] yields for them,
    /// ids, times and poses included. Messages before the range are passed over undecoded;
    /// reading stops at its end. A corrupt chunk is reported by the range it falls in.
    pub fn open_range(&self, path: &Path, range: std::ops::Range<u64>) -> Result<ScanStream, SourceError> {
        self.settings().open_range(path, range)
    }
}

/// The number of scans (messages of the point-cloud topic, `topic` or the file's only one)
/// in a log (an MCAP file, or any log [`super::logs`] reads), and the topic: a pass over it
/// that decodes no cloud.
pub fn count_scans(path: &Path, topic: Option<&str>) -> Result<(String, u64), SourceError> {
    super::logs::count_scans(path, topic)
}

/// All channels of a file: from the summary, else by a full pass.
pub fn channels(path: &Path) -> Result<Vec<ChannelInfo>, SourceError> {
    if let Some(c) = summary_channels(path) {
        return Ok(c);
    }
    let mut messages =
        McapMessages::open(path).map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
    for m in messages.by_ref() {
        if let Err(fault) = m {
            tracing::warn!("{}: {}: {}", path.display(), fault.location, fault.message);
        }
    }
    let mut c: Vec<ChannelInfo> = messages.channels().map(|c| (**c).clone()).collect();
    c.sort_by_key(|c| c.id);
    Ok(c)
}
