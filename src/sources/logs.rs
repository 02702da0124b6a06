//! Message logs: MCAP files, ROS 1 bags, rosbag2 folders and lone rosbag2 `.db3` files, read
//! through one interface. Each kind's reader yields [`RawMessage`]s in file order (a corrupt
//! chunk or message is a fault item, and reading goes on); this module picks the point-cloud
//! topic, decodes `sensor_msgs/PointCloud2` ([`super::pointcloud2`]) and joins poses, the same
//! way for every kind.
//!
//! Topic: the configured one, or else the log's only point-cloud topic. Scans are numbered by
//! their index among that topic's messages (`message_index`, and the id `<session>/<index>`,
//! six digits); in a rosbag2 folder split into several files the numbering runs on across them.
//! utime = the message header's stamp (µs), or the log time when the stamp is zero (MCAP's log
//! time, a ROS 1 bag's record time, rosbag2's `timestamp`: the time it was recorded).

use super::groundtruth::GroundTruth;
use super::mcap_reader::{ChannelInfo, McapFault, McapMessages, RawMessage, is_point_cloud};
use super::pointcloud2::{self, Encoding};
use super::{Scan, ScanFailure, ScanStream, SourceError, ros1bag, rosbag2};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A stream of messages of one log.
pub(crate) type Messages = Box<dyn Iterator<Item = Result<RawMessage, McapFault>> + Send>;

/// What kind of log a path is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogKind {
    /// An MCAP file (by its magic).
    Mcap,
    /// A ROS 1 bag (`#ROSBAG V2.0`).
    Ros1Bag,
    /// A rosbag2 folder (`metadata.yaml` and its storage files).
    Rosbag2,
    /// One rosbag2 sqlite3 file (`.db3`, by SQLite's magic).
    Sqlite3,
}

impl LogKind {
    /// The kind of log at `path`, by its content (magic bytes, `metadata.yaml`).
    pub fn detect(path: &Path) -> Option<LogKind> {
        if rosbag2::is_rosbag2_folder(path) {
            Some(LogKind::Rosbag2)
        } else if !path.is_file() {
            None
        } else if super::detect::is_mcap(path) {
            Some(LogKind::Mcap)
        } else if ros1bag::is_ros1_bag(path) {
            Some(LogKind::Ros1Bag)
        } else if rosbag2::is_sqlite(path) {
            Some(LogKind::Sqlite3)
        } else {
            None
        }
    }

    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            LogKind::Mcap => "mcap",
            LogKind::Ros1Bag => "ros1 bag",
            LogKind::Rosbag2 => "rosbag2 folder",
            LogKind::Sqlite3 => "rosbag2 sqlite3 file",
        }
    }

    /// The log's messages, in order.
    pub(crate) fn messages(self, path: &Path) -> Result<Messages, SourceError> {
        let invalid = |e: String| SourceError::invalid(path, e);
        Ok(match self {
            LogKind::Mcap => Box::new(
                McapMessages::open(path)
                    .map_err(|source| SourceError::Io { path: path.to_owned(), source })?,
            ),
            LogKind::Ros1Bag => Box::new(ros1bag::Ros1Messages::open(path).map_err(invalid)?),
            LogKind::Rosbag2 => rosbag2::folder_messages(path).map_err(invalid)?,
            LogKind::Sqlite3 => Box::new(rosbag2::Sqlite3Messages::open(path).map_err(invalid)?),
        })
    }

    /// The log's channels (topics with their types): from an index or summary where the log has
    /// one, else by a pass over it.
    pub fn channels(self, path: &Path) -> Result<Vec<ChannelInfo>, SourceError> {
        let invalid = |e: String| SourceError::invalid(path, e);
        match self {
            LogKind::Mcap => super::mcap::channels(path),
            LogKind::Ros1Bag => ros1bag::channels(path).map_err(invalid),
            LogKind::Rosbag2 => rosbag2::folder_channels(path).map_err(invalid),
            LogKind::Sqlite3 => rosbag2::sqlite3_file_channels(path).map_err(invalid),
        }
    }
}

/// The kind of `path`, or an error naming it.
pub(crate) fn kind_of(path: &Path) -> Result<LogKind, SourceError> {
    if !path.exists() {
        let source = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or folder");
        return Err(SourceError::Io { path: path.to_owned(), source });
    }
    LogKind::detect(path).ok_or_else(|| {
        SourceError::invalid(path, "not an MCAP file, a ROS 1 bag, a rosbag2 folder or a rosbag2 .db3 file")
    })
}

/// The session a log is, by default: a file's stem, a folder's name.
pub(crate) fn default_session(path: &Path) -> String {
    let name = if path.is_dir() { path.file_name() } else { path.file_stem() };
    name.map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
}

/// How a source reads its logs (the keys `kind = "mcap"` and `kind = "rosbag"` share).
#[derive(Clone, Debug)]
pub(crate) struct LogSettings {
    pub(crate) topic: Option<String>,
    pub(crate) session: Option<String>,
    pub(crate) poses: Option<PathBuf>,
    pub(crate) tolerance_ms: f64,
}

impl LogSettings {
    fn ground_truth(&self) -> Result<Option<Arc<GroundTruth>>, SourceError> {
        Ok(match &self.poses {
            Some(p) => Some(Arc::new(GroundTruth::read(p)?)),
            None => None,
        })
    }

    /// The stream over `paths`, in order. A log that cannot be opened (not a log, truncated
    /// before its first message, no point-cloud topic) is one failure naming it, and the other
    /// logs are read.
    pub(crate) fn open(&self, paths: Vec<PathBuf>) -> Result<ScanStream, SourceError> {
        let poses = self.ground_truth()?;
        let settings = self.clone();
        Ok(Box::new(paths.into_iter().flat_map(move |path| -> ScanStream {
            let session = settings.session.clone().unwrap_or_else(|| default_session(&path));
            match settings.scans_of(&path, poses.clone(), 0..u64::MAX) {
                Ok(scans) => Box::new(scans),
                Err(e) => {
                    Box::new(std::iter::once(Err(ScanFailure::of_input(&session, &path, e.to_string()))))
                }
            }
        })))
    }

    /// The scans of `path` whose message index lies in `range`: what [`LogSettings::open`]
    /// yields for them, ids, times and poses included. Messages before the range are passed
    /// over undecoded; reading stops at its end.
    pub(crate) fn open_range(
        &self,
        path: &Path,
        range: std::ops::Range<u64>,
    ) -> Result<ScanStream, SourceError> {
        Ok(Box::new(self.scans_of(path, self.ground_truth()?, range)?))
    }

    fn scans_of(
        &self,
        path: &Path,
        poses: Option<Arc<GroundTruth>>,
        range: std::ops::Range<u64>,
    ) -> Result<LogScans, SourceError> {
        let kind = kind_of(path)?;
        let topic = resolve_topic(path, &kind.channels(path)?, self.topic.as_deref())?;
        let session = self.session.clone().unwrap_or_else(|| default_session(path));
        let messages = kind.messages(path)?;
        let tolerance = (self.tolerance_ms * 1000.0).round() as i64;
        Ok(LogScans { messages, path: path.to_owned(), topic, session, poses, tolerance, index: 0, range })
    }
}

/// The number of scans (messages of the point-cloud topic, `topic` or the log's only one) in a
/// log, and the topic: a pass that decodes no cloud.
pub fn count_scans(path: &Path, topic: Option<&str>) -> Result<(String, u64), SourceError> {
    let kind = kind_of(path)?;
    let topic = resolve_topic(path, &kind.channels(path)?, topic)?;
    let mut count = 0u64;
    for m in kind.messages(path)?.flatten() {
        if m.channel.topic == topic && is_point_cloud(&m.channel) {
            count += 1;
        }
    }
    Ok((topic, count))
}

fn resolve_topic(path: &Path, channels: &[ChannelInfo], wanted: Option<&str>) -> Result<String, SourceError> {
    let clouds: Vec<&ChannelInfo> = channels.iter().filter(|c| is_point_cloud(c)).collect();
    let mut topics: Vec<&str> = clouds.iter().map(|c| c.topic.as_str()).collect();
    topics.dedup();
    match wanted {
        Some(t) if topics.contains(&t) => Ok(t.to_string()),
        Some(t) => match channels.iter().find(|c| c.topic == t) {
            Some(c) => Err(SourceError::invalid(
                path,
                format!(
                    "topic {t} has schema `{}` ({}), not a PointCloud2 toporec reads",
                    c.schema_name, c.message_encoding
                ),
            )),
            None => Err(SourceError::invalid(path, format!("no topic {t} (point-cloud topics: {topics:?})"))),
        },
        None => match topics.as_slice() {
            [one] => Ok(one.to_string()),
            [] => Err(SourceError::invalid(path, "no sensor_msgs/PointCloud2 topic (cdr or ros1)")),
            many => Err(SourceError::invalid(
                path,
                format!("several point-cloud topics {many:?}; choose one with `topic`"),
            )),
        },
    }
}

struct LogScans {
    messages: Messages,
    path: PathBuf,
    topic: String,
    session: String,
    poses: Option<std::sync::Arc<GroundTruth>>,
    tolerance: i64,
    index: u64,
    /// The message indices wanted (all, for a whole file).
    range: std::ops::Range<u64>,
}

impl Iterator for LogScans {
    type Item = Result<Scan, ScanFailure>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if self.index >= self.range.end {
                return None;
            }
            let path = self.path.clone();
            let failure = |id: String, index: Option<u64>, error: String| ScanFailure {
                id,
                session: self.session.clone(),
                path: path.clone(),
                message_index: index,
                utime: None,
                fingerprint: None,
                error,
                // A corrupt chunk hides the messages it held; a bad message is its own scan.
                input_unread: index.is_none(),
            };
            let message = match self.messages.next()? {
                Ok(m) => m,
                Err(fault) => {
                    if !self.range.contains(&self.index) {
                        continue;
                    }
                    // A corrupt chunk: its messages are lost, the stream goes on.
                    let id = format!("{}/{}", self.session, fault.location.replace(' ', "_"));
                    let e = format!("{}: {}: {}", path.display(), fault.location, fault.message);
                    return Some(Err(failure(id, None, e)));
                }
            };
            if message.channel.topic != self.topic || !is_point_cloud(&message.channel) {
                continue;
            }
            let index = self.index;
            self.index += 1;
            if index < self.range.start {
                continue;
            }
            let id = format!("{}/{index:06}", self.session);
            let fingerprint = crate::fingerprint::of_bytes(&message.data);
            let encoding = Encoding::of_channel(&message.channel.message_encoding);
            let decoded =
                pointcloud2::parse(&message.data, encoding).and_then(|c| Ok((c.stamp_ns, c.decode()?)));
            let (stamp_ns, cloud) = match decoded {
                Ok(x) => x,
                Err(e) => {
                    let e = format!("{}: message {index} on {}: {e}", path.display(), self.topic);
                    return Some(Err(failure(id, Some(index), e).with_fingerprint(fingerprint)));
                }
            };
            let utime =
                if stamp_ns != 0 { stamp_ns.div_euclid(1000) } else { (message.log_time / 1000) as i64 };
            let pose = self
                .poses
                .as_ref()
                .map_or(Err(super::NoPose::NoGroundTruth), |g| g.pose_at(utime, self.tolerance));
            let (pose, no_pose) = super::split_pose(pose);
            return Some(Ok(Scan {
                id,
                fingerprint,
                session: self.session.clone(),
                path,
                message_index: Some(index),
                utime,
                points: cloud.points,
                intensity: cloud.intensity,
                ring: cloud.ring,
                raw_points: cloud.raw_points,
                pose,
                no_pose,
            }));
        }
    }
}
