//! The MCAP source: `sensor_msgs/PointCloud2` messages (ROS 2 CDR or ROS 1) of one topic per
//! file, decoded by [`super::pointcloud2`], optionally joined to poses from an NCLT-style CSV.
//!
//! Topic: the configured one, or else the only point-cloud topic of the file (found in the
//! summary section, or by a first pass over the file when it has none). Scans are numbered by
//! their index among that topic's messages (`message_index`, and the id `<stem>/<index>`).
//! utime = header stamp (µs), or the log time when the stamp is zero.

use super::groundtruth::GroundTruth;
use super::mcap_reader::{ChannelInfo, McapMessages, is_point_cloud, summary_channels};
use super::pointcloud2::{self, Encoding};
use super::{Scan, ScanFailure, ScanStream, SourceError};
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

    /// Opens the stream over all files, in order. A file that cannot be opened (not an MCAP,
    /// truncated before its first message, no point-cloud topic) is one failure naming it, and
    /// the other files are read.
    pub fn open(&self) -> Result<ScanStream, SourceError> {
        let poses = match &self.poses {
            Some(p) => Some(std::sync::Arc::new(GroundTruth::read(p)?)),
            None => None,
        };
        let spec = self.clone();
        let files = self.files.clone();
        Ok(Box::new(files.into_iter().flat_map(move |path| -> ScanStream {
            let session = spec.session.clone().unwrap_or_else(|| stem(&path));
            match spec.scans_of(&path, poses.clone(), 0..u64::MAX) {
                Ok(scans) => Box::new(scans),
                Err(e) => {
                    Box::new(std::iter::once(Err(ScanFailure::of_input(&session, &path, e.to_string()))))
                }
            }
        })))
    }

    /// The scans of one file whose message index lies in `range`.
    fn scans_of(
        &self,
        path: &Path,
        poses: Option<std::sync::Arc<GroundTruth>>,
        range: std::ops::Range<u64>,
    ) -> Result<McapScans, SourceError> {
        let topic = resolve_topic(path, self.topic.as_deref())?;
        let session = self.session.clone().unwrap_or_else(|| stem(path));
        let messages =
            McapMessages::open(path).map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
        let tolerance = (self.tolerance_ms * 1000.0).round() as i64;
        Ok(McapScans { messages, topic, session, poses, tolerance, index: 0, range })
    }

    /// The scans of `path` (one of the spec's files, or any file read with the spec's
    /// settings) whose message index lies in `range`: what [`McapSpec::open`] yields for them,
    /// ids, times and poses included. Messages before the range are passed over undecoded;
    /// reading stops at its end. A corrupt chunk is reported by the range it falls in.
    pub fn open_range(&self, path: &Path, range: std::ops::Range<u64>) -> Result<ScanStream, SourceError> {
        let poses = match &self.poses {
            Some(p) => Some(std::sync::Arc::new(GroundTruth::read(p)?)),
            None => None,
        };
        Ok(Box::new(self.scans_of(path, poses, range)?))
    }
}

/// The number of scans (messages of the point-cloud topic, `topic` or the file's only one)
/// in an MCAP file, and the topic: a pass over the file that decodes no cloud.
pub fn count_scans(path: &Path, topic: Option<&str>) -> Result<(String, u64), SourceError> {
    let topic = resolve_topic(path, topic)?;
    let messages =
        McapMessages::open(path).map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
    let mut count = 0u64;
    for m in messages.flatten() {
        if m.channel.topic == topic && is_point_cloud(&m.channel) {
            count += 1;
        }
    }
    Ok((topic, count))
}

fn stem(path: &Path) -> String {
    path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
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

fn resolve_topic(path: &Path, wanted: Option<&str>) -> Result<String, SourceError> {
    let channels = channels(path)?;
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

struct McapScans {
    messages: McapMessages,
    topic: String,
    session: String,
    poses: Option<std::sync::Arc<GroundTruth>>,
    tolerance: i64,
    index: u64,
    /// The message indices wanted (all, for a whole file).
    range: std::ops::Range<u64>,
}

impl Iterator for McapScans {
    type Item = Result<Scan, ScanFailure>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if self.index >= self.range.end {
                return None;
            }
            let path = self.messages.path().to_owned();
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
