//! Message logs: MCAP files, ROS 1 bags, rosbag2 folders and lone rosbag2 `.db3` files, read
//! through one interface. Each kind's reader yields [`RawMessage`](super::mcap_reader::RawMessage)s in file order (a corrupt
//! chunk or message is a fault item, and reading goes on); this module picks the point-cloud
//! topic, decodes `sensor_msgs/PointCloud2` ([`super::pointcloud2`]) and joins poses, the same
//! way for every kind.
//!
//! Topic: the configured one, or else the log's only point-cloud topic. Scans are numbered by
//! their index among that topic's messages (`message_index`, and the id `<session>/<index>`,
//! six digits); in a rosbag2 folder split into several files the numbering runs on across them.
//! utime = the message header's stamp (µs), or the log time when the stamp is zero (MCAP's log
//! time, a ROS 1 bag's record time, rosbag2's `timestamp`: the time it was recorded).

use super::mcap_reader::{ChannelInfo, McapMessages, Messages, is_point_cloud};
use super::pointcloud2::{self, Encoding};
use super::poses::PoseTable;
use super::poses::{Choice, LogPoses, PoseFormat, PoseKeys, ScanPoses};
use super::rosmsg::PoseKind;
use super::{Scan, ScanFailure, ScanStream, SourceError, ros1bag, rosbag2};
use std::path::{Path, PathBuf};
use std::sync::Arc;

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
        } else if super::mcap_reader::is_mcap(path) {
            Some(LogKind::Mcap)
        } else if ros1bag::is_ros1_bag(path) {
            Some(LogKind::Ros1Bag)
        } else if rosbag2::is_sqlite(path) && rosbag2::has_rosbag2_tables(path) == Ok(true) {
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
            LogKind::Mcap => super::mcap_reader::channels(path),
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
        let why = not_a_log(path).unwrap_or_else(|| {
            "not an MCAP file, a ROS 1 bag, a rosbag2 folder or a rosbag2 .db3 file".to_string()
        });
        SourceError::invalid(path, why)
    })
}

/// Why a file named as a log (`.bag`, `.db3`, `.mcap`) is not the log its name says, judged by
/// its content: what it is not and what was found. `None` when it is a log of some kind (a
/// valid MCAP named `.bag` is read as an MCAP), or is not named as one.
pub fn not_a_log(path: &Path) -> Option<String> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    if !matches!(ext.as_str(), "bag" | "db3" | "mcap") || !path.is_file() || LogKind::detect(path).is_some() {
        return None;
    }
    let mut head = Vec::new();
    {
        use std::io::Read;
        let file = std::fs::File::open(path).ok()?;
        file.take(64).read_to_end(&mut head).ok()?;
    }
    let found = found_words(&head);
    Some(match ext.as_str() {
        "bag" if head.starts_with(b"#ROSBAG V") => {
            let line = head.split(|&b| b == b'\n').next().unwrap_or_default();
            let version = String::from_utf8_lossy(&line[..line.len().min(13)]).into_owned();
            format!(
                "not a ROS 1 bag toporec reads: a `{version}` header (toporec reads bag format 2.0, `#ROSBAG V2.0`)"
            )
        }
        "bag" => format!("not a ROS 1 bag: no `#ROSBAG V2.0` header (found {found})"),
        "db3" if rosbag2::is_sqlite(path) => match rosbag2::has_rosbag2_tables(path) {
            Err(e) => format!("not a rosbag2 .db3 file: a SQLite header, and no database behind it ({e})"),
            Ok(_) => {
                "not a rosbag2 .db3 file: a SQLite database without rosbag2's tables (`topics`, `messages`)"
                    .into()
            }
        },
        "db3" => format!("not a rosbag2 .db3 file: no SQLite header (found {found})"),
        _ => format!("not an MCAP file: no MCAP magic (found {found})"),
    })
}

/// The first bytes of a file, in words.
fn found_words(head: &[u8]) -> String {
    if head.is_empty() {
        return "an empty file".into();
    }
    let text: String = head.iter().take(24).map(|&b| b as char).collect();
    let printable = |b: u8| b == b'\n' || b == b'\r' || b == b'\t' || (0x20..0x7f).contains(&b);
    if head.iter().take(24).all(|&b| printable(b)) {
        return format!("text: `{}`", text.lines().next().unwrap_or_default());
    }
    let hex: Vec<String> = head.iter().take(8).map(|b| format!("{b:02x}")).collect();
    format!("bytes {}", hex.join(" "))
}

/// The session a log is, by default: a file's stem, a folder's name.
pub(crate) fn default_session(path: &Path) -> String {
    let name = if path.is_dir() { path.file_name() } else { path.file_stem() };
    name.map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
}

/// `kind = "rosbag"` (and its other name `kind = "mcap"`, whose key `files` is `paths`) in a
/// pipeline file: message logs — ROS 1 `.bag` files, rosbag2 folders, rosbag2 `.db3` files and
/// MCAP files, each read by what it is ([`LogKind`]), each one session: a file by its stem, a
/// folder by its name (a rosbag2 folder's split files continue one another).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LogSpec {
    /// The logs; each is one session (unless `session` is set).
    pub paths: Vec<PathBuf>,
    /// The point-cloud topic; default: the log's only one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub topic: Option<String>,
    /// Session name for all logs (default: a file's stem, a folder's name).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub session: Option<String>,
    /// A pose file (its layout `poses_format`), joined by nearest time; without it, the log's own
    /// poses (see [`super::poses`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poses: Option<PathBuf>,
    /// The layout of `poses`: `nclt`, `tum` or `kitti` (default: guessed as the command line
    /// guesses it, [`PoseFormat::guess`]: `kitti` with `poses_times`, `nclt` for `.csv`, else
    /// `tum`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poses_format: Option<PoseFormat>,
    /// With `poses_format = "kitti"`: the times of its rows (seconds, one per line).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poses_times: Option<PathBuf>,
    /// The log's pose topic: an Odometry, PoseStamped or PoseWithCovarianceStamped topic, or
    /// `/tf` for the transform chain (default: the chain when it reaches the cloud's frame, else
    /// the only pose topic).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poses_topic: Option<String>,
    /// `parent:child`: the transform chain from `parent` down to `child` (the cloud's frame), or,
    /// with a pose topic, the frame its poses are of and the cloud's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose_frames: Option<String>,
    /// Largest time gap for a pose join, milliseconds.
    #[serde(default = "default_tolerance_ms")]
    pub tolerance_ms: f64,
    /// How a sharded run hands out its scans: `scans` (by id; `kind = "rosbag"`'s default) or
    /// `sessions` (each log read whole by one shard; `kind = "mcap"`'s default).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shards: Option<super::Shards>,
    /// The name the entry was given (`rosbag`, or `mcap` with `files`): it is written back so.
    #[serde(skip)]
    pub named: LogName,
    /// Read the scans without joining poses (what needs only their points: loops' checks).
    #[serde(skip)]
    pub points_only: bool,
    /// A log's poses as settling its choice gathered them ([`super::Source::settle`]): the run
    /// joins these instead of reading the log for its poses again.
    #[serde(skip)]
    pub gathered: Option<Gathered>,
}

/// A log's poses gathered once, kept with the spec for the run to join (a cache, not a setting:
/// specs compare equal whatever they hold).
#[derive(Clone, Debug)]
pub struct Gathered(Arc<(PathBuf, LogPoses)>);

impl PartialEq for Gathered {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// The `kind` a message-log entry is written as.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LogName {
    /// `kind = "rosbag"`, `paths`.
    #[default]
    Rosbag,
    /// `kind = "mcap"`, `files` (its logs sharded by session unless `shards` says otherwise).
    Mcap,
}

fn default_tolerance_ms() -> f64 {
    100.0
}

impl LogSpec {
    /// A spec for one log with defaults.
    pub fn path(path: &Path) -> Self {
        LogSpec {
            paths: vec![path.to_owned()],
            topic: None,
            session: None,
            poses: None,
            poses_format: None,
            poses_times: None,
            poses_topic: None,
            pose_frames: None,
            tolerance_ms: default_tolerance_ms(),
            shards: None,
            named: LogName::Rosbag,
            points_only: false,
            gathered: None,
        }
    }

    /// Whether `path` is one of its logs (compared as the files they are).
    fn lists(&self, path: &Path) -> bool {
        let canonical = |p: &Path| p.canonicalize().unwrap_or_else(|_| p.to_owned());
        let wanted = canonical(path);
        self.paths.iter().any(|p| canonical(p) == wanted)
    }

    /// The layout of its pose file: given, or guessed ([`PoseFormat::guess`]).
    pub fn poses_layout(&self) -> Option<PoseFormat> {
        let file = self.poses.as_deref()?;
        Some(self.poses_format.unwrap_or_else(|| PoseFormat::guess(file, self.poses_times.as_deref())))
    }

    /// The session of `path`: the spec's `session`, else the file's stem or the folder's name.
    pub fn session_of(&self, path: &Path) -> String {
        self.session.clone().unwrap_or_else(|| default_session(path))
    }
}

impl super::Kind for LogSpec {
    const NAME: &'static str = "rosbag";
    const READS: &'static str = "MCAP file, ROS 1 bag, rosbag2 folder or .db3 file";

    fn detect(path: &Path) -> Option<super::Detected> {
        let kind = LogKind::detect(path)?;
        Some(super::Detected { what: kind.name(), source: super::SourceSpec::new(LogSpec::path(path)) })
    }
}

/// `kind = "mcap"`: the message-log source under its older name, `files` for `paths`.
pub(super) const MCAP_ALIAS: super::SourceKind =
    super::SourceKind { name: "mcap", reads: "", parse: parse_mcap, detect: |_| None };

fn parse_mcap(keys: &toml::Table) -> Result<Box<dyn super::Source>, super::KeyError> {
    let mut keys = keys.clone();
    if let Some(files) = keys.remove("files") {
        keys.insert("paths".into(), files);
    } else if let Some(paths) = keys.remove("paths") {
        // `paths` is not a key of `kind = "mcap"`: named as the reader would.
        keys.insert("mcap_paths".into(), paths);
    }
    let spec: LogSpec = super::parse_keys(&keys).map_err(|e| super::KeyError {
        path: e.path.replace("paths", "files").replace("mcap_files", "paths"),
        message: e.message.replace("`paths`", "`files`").replace("`mcap_files`", "`paths`"),
    })?;
    // Its logs are read whole by one shard each, unless said otherwise.
    let shards = spec.shards.or(Some(super::Shards::Sessions));
    Ok(Box::new(LogSpec { named: LogName::Mcap, shards, ..spec }))
}

impl super::Source for LogSpec {
    fn kind(&self) -> &'static str {
        match self.named {
            LogName::Rosbag => "rosbag",
            LogName::Mcap => "mcap",
        }
    }

    fn keys(&self) -> toml::Table {
        let mut t = toml::Table::try_from(self).expect("plain data");
        if self.named == LogName::Mcap
            && let Some(paths) = t.remove("paths")
        {
            t.insert("files".into(), paths);
            // Written back as read: sessions is its kind's default.
            if self.shards == Some(super::Shards::Sessions) {
                t.remove("shards");
            }
        }
        t
    }

    fn problems(&self, inputs: bool) -> Vec<(&'static str, String)> {
        let key = if self.named == LogName::Mcap { "files" } else { "paths" };
        let mut out = super::required(key, &self.paths, inputs);
        out.extend(super::missing("poses", self.poses.as_slice(), inputs));
        out.extend(super::missing("poses_times", self.poses_times.as_slice(), inputs));
        if let Some(Err(e)) = self.pose_frames.as_deref().map(super::poses::parse_frames) {
            out.push(("pose_frames", e));
        }
        if self.poses.is_some() && (self.poses_topic.is_some() || self.pose_frames.is_some()) {
            out.push((
                "poses",
                "a pose file, or the log's poses (poses_topic, pose_frames): give one".into(),
            ));
        }
        out.extend(super::tolerance(self.tolerance_ms));
        out
    }

    fn open(&self) -> Result<ScanStream, SourceError> {
        self.settings().open(self.paths.clone())
    }

    fn sessions(&self) -> Result<Vec<(String, PathBuf)>, SourceError> {
        Ok(self.paths.iter().map(|p| (self.session_of(p), p.clone())).collect())
    }

    fn narrowed(&self, places: Vec<PathBuf>) -> Option<Box<dyn super::Source>> {
        Some(Box::new(LogSpec { paths: places, ..self.clone() }))
    }

    fn paths_mut(&mut self) -> Vec<&mut PathBuf> {
        self.paths.iter_mut().chain(self.poses.iter_mut()).chain(self.poses_times.iter_mut()).collect()
    }

    fn shards_by_session(&self) -> bool {
        self.shards == Some(super::Shards::Sessions)
    }

    fn reread(
        &self,
        path: &Path,
        messages: &[u64],
        points_only: bool,
    ) -> Option<Result<ScanStream, SourceError>> {
        if !self.lists(path) {
            return None;
        }
        let spec = LogSpec { points_only, paths: vec![path.to_owned()], ..self.clone() };
        let (Some(&first), Some(&last)) = (messages.iter().min(), messages.iter().max()) else {
            return Some(Ok(Box::new(std::iter::empty())));
        };
        let wanted: std::collections::HashSet<u64> = messages.iter().copied().collect();
        Some(spec.settings().open_wanted(path, first..last.saturating_add(1), Some(Arc::new(wanted))))
    }

    fn read_range(
        &self,
        path: &Path,
        range: std::ops::Range<u64>,
    ) -> Option<Result<ScanStream, SourceError>> {
        self.lists(path).then(|| self.open_range(path, range))
    }

    fn settle(
        &self,
        options: &super::SourceOptions,
    ) -> Option<Result<(super::SourceSpec, Option<String>), SourceError>> {
        Some(self.settled(options))
    }

    fn pose_origins(&self) -> Vec<super::poses::PoseOrigin> {
        use super::poses::PoseOrigin;
        let within = format!("nearest time within {} ms", self.tolerance_ms);
        let own = self.own_poses_words();
        self.paths
            .iter()
            .filter_map(|path| {
                let sessions = vec![self.session_of(path)];
                if let Some(file) = &self.poses {
                    let times = self.poses_times.as_deref();
                    let format = self.poses_layout().unwrap_or_default();
                    let table = super::poses::read_file(file, format, times, None).unwrap_or_default();
                    let layout = format!("{} layout, {within}", format.name());
                    return Some(PoseOrigin::of_file(sessions, file, times, &table, &layout));
                }
                let words = match &own {
                    Some(w) => w.clone(),
                    // No keys: the log's own poses as found, when it has any.
                    None => {
                        let channels = kind_of(path).and_then(|k| k.channels(path)).ok()?;
                        channels.iter().any(|c| PoseKind::of_schema(&c.schema_name).is_some()).then(|| {
                            "the log's own poses (the /tf chain to the cloud's frame, or its only pose topic)"
                                .to_string()
                        })?
                    }
                };
                Some(PoseOrigin::of_source(sessions, format!("{words}, {within}")))
            })
            .collect()
    }

    fn boxed(&self) -> Box<dyn super::Source> {
        Box::new(self.clone())
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

impl LogSpec {
    /// The scans of `path` (one of the spec's logs, or any log read with its settings) whose
    /// message index lies in `range`: what [`super::Source::open`] yields for them, ids, times
    /// and poses included. Messages before the range are passed over undecoded; reading stops
    /// at its end. A corrupt chunk is reported by the range it falls in.
    pub fn open_range(&self, path: &Path, range: std::ops::Range<u64>) -> Result<ScanStream, SourceError> {
        self.settings().open_range(path, range)
    }

    /// How the logs are read.
    fn settings(&self) -> LogSettings {
        LogSettings { spec: Arc::new(self.clone()) }
    }

    /// This log's spec with `options` applied and its poses settled: the file given, or the log's
    /// own as the keys choose or as found, written as explicit keys (so the pipeline says what
    /// was chosen), the poses gathered once for the run to join. Returns the spec and, when the
    /// log holds no pose, a note saying so. An error names the file and what to pass.
    fn settled(&self, o: &super::SourceOptions) -> Result<(super::SourceSpec, Option<String>), SourceError> {
        let path = self.paths.first().cloned().unwrap_or_default();
        let mut spec = LogSpec { tolerance_ms: o.tolerance_ms, ..self.clone() };
        if let Some(file) = &o.poses {
            let format = o.poses_layout().expect("a pose file");
            spec.poses = Some(std::path::absolute(file).unwrap_or_else(|_| file.clone()));
            spec.poses_format = Some(format);
            spec.poses_times =
                o.poses_times.as_ref().map(|t| std::path::absolute(t).unwrap_or_else(|_| t.clone()));
            // Read now: a file that holds no pose of its layout is an error, not a run without poses.
            super::poses::read_nonempty(file, format, o.poses_times.as_deref(), Some(0))?;
            return Ok((super::SourceSpec::new(spec), None));
        }
        spec.poses_topic = o.poses_topic.clone();
        spec.pose_frames = o.pose_frames.as_ref().map(|(a, b)| format!("{a}:{b}"));
        let (gathered, choice) = spec.pose_choice(&path)?;
        let said = match &choice {
            None => Some(format!(
                "{}: no poses in the log (give --poses FILE for loop distances)",
                path.display()
            )),
            Some(c) => {
                let tol = (o.tolerance_ms * 1e6).round() as i64;
                gathered.check_overlap(&path, c, tol)?;
                let keys = c.keys();
                spec.poses_topic = keys.topic;
                spec.pose_frames = keys.frames.map(|(a, b)| format!("{a}:{b}"));
                None
            }
        };
        spec.gathered = Some(Gathered(Arc::new((path, gathered))));
        Ok((super::SourceSpec::new(spec), said))
    }

    /// The log's own poses as the keys choose them, in words; `None` without keys.
    fn own_poses_words(&self) -> Option<String> {
        let keys = self.pose_keys();
        let tf = |t: &str| t.trim_start_matches('/') == "tf";
        Some(match (&keys.topic, &keys.frames) {
            (Some(t), Some((a, b))) if tf(t) => format!("/tf chain {a} → {b} in the log"),
            (None, Some((a, b))) => format!("/tf chain {a} → {b} in the log"),
            (Some(t), _) if tf(t) => "/tf chain to the cloud's frame in the log".into(),
            (Some(t), Some((a, b))) => {
                format!("{t} in the log (poses of {a}, mounted {a} → {b} by /tf_static)")
            }
            (Some(t), None) => format!("{t} in the log"),
            (None, None) => return None,
        })
    }

    /// The pose keys, parsed.
    fn pose_keys(&self) -> PoseKeys {
        PoseKeys {
            topic: self.poses_topic.clone(),
            frames: self.pose_frames.as_deref().and_then(|f| super::poses::parse_frames(f).ok()),
        }
    }

    /// What `path` (one of the spec's logs) holds of poses and how its scans take theirs: the
    /// choice of the keys, or the one found (`None`: no pose in the log). An error names the
    /// file and what to pass.
    pub fn pose_choice(&self, path: &Path) -> Result<(LogPoses, Option<Choice>), SourceError> {
        let kind = kind_of(path)?;
        let channels = kind.channels(path)?;
        let topic = resolve_topic(path, &channels, self.topic.as_deref())?;
        let poses = LogPoses::gather(path, &channels, kind.messages(path)?, &topic)?;
        let choice = poses.choose(path, &self.pose_keys())?;
        Ok((poses, choice))
    }
}

/// How a spec reads its logs.
#[derive(Clone, Debug)]
struct LogSettings {
    spec: Arc<LogSpec>,
}

impl LogSettings {
    /// The pose file, read (KITTI rows with relative times wait for the log's first scan).
    fn ground_truth(&self) -> Result<Option<Arc<PoseTable>>, SourceError> {
        let s = &self.spec;
        Ok(match &s.poses {
            Some(p) if !s.points_only && s.poses_layout() != Some(PoseFormat::Kitti) => {
                Some(Arc::new(super::poses::read_nonempty(
                    p,
                    s.poses_layout().unwrap_or_default(),
                    s.poses_times.as_deref(),
                    None,
                )?))
            }
            _ => None,
        })
    }

    /// The poses of the scans of `path`: the file's, else the log's own (gathered in a pass over
    /// the log when it has pose messages or keys ask for them).
    fn scan_poses(
        &self,
        path: &Path,
        kind: LogKind,
        channels: &[ChannelInfo],
        topic: &str,
        file: Option<Arc<PoseTable>>,
    ) -> Result<Option<ScanPoses>, SourceError> {
        let s = &self.spec;
        if s.points_only {
            return Ok(None);
        }
        if let Some(gt) = file {
            return Ok(Some(ScanPoses::File(gt)));
        }
        let keys = s.pose_keys();
        let has_poses = channels.iter().any(|c| PoseKind::of_schema(&c.schema_name).is_some());
        let kitti = s.poses_layout() == Some(PoseFormat::Kitti);
        if !kitti && !has_poses && keys == PoseKeys::default() {
            return Ok(None);
        }
        // Gathered once: by settling the choice, when it did (`loops <log>`), else now.
        let gathered = match s.gathered.as_ref().map(|g| &*g.0) {
            Some((p, poses)) if p == path => poses.clone(),
            _ => LogPoses::gather(path, channels, kind.messages(path)?, topic)?,
        };
        if let Some(p) = &s.poses {
            let first_us = gathered.cloud_stamps.iter().min().map(|t| t.div_euclid(1000));
            let gt = super::poses::read_nonempty(p, PoseFormat::Kitti, s.poses_times.as_deref(), first_us)?;
            return Ok(Some(ScanPoses::File(Arc::new(gt))));
        }
        let tol = (s.tolerance_ms * 1e6).round() as i64;
        match gathered.choose(path, &keys)? {
            None => Ok(None),
            Some(choice) => {
                gathered.check_overlap(path, &choice, tol)?;
                Ok(Some(ScanPoses::Log(Arc::new(gathered), choice)))
            }
        }
    }

    /// The stream over `paths`, in order. A log that cannot be opened (not a log, truncated
    /// before its first message, no point-cloud topic) is one failure naming it, and the other
    /// logs are read.
    fn open(&self, paths: Vec<PathBuf>) -> Result<ScanStream, SourceError> {
        let poses = self.ground_truth()?;
        let settings = self.clone();
        Ok(Box::new(paths.into_iter().flat_map(move |path| -> ScanStream {
            let session = settings.spec.session_of(&path);
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
    fn open_range(&self, path: &Path, range: std::ops::Range<u64>) -> Result<ScanStream, SourceError> {
        self.open_wanted(path, range, None)
    }

    /// [`LogSettings::open_range`], decoding only the messages `wanted` holds (all, without).
    fn open_wanted(
        &self,
        path: &Path,
        range: std::ops::Range<u64>,
        wanted: Option<Arc<std::collections::HashSet<u64>>>,
    ) -> Result<ScanStream, SourceError> {
        let mut scans = self.scans_of(path, self.ground_truth()?, range)?;
        scans.wanted = wanted;
        Ok(Box::new(scans))
    }

    fn scans_of(
        &self,
        path: &Path,
        file: Option<Arc<PoseTable>>,
        range: std::ops::Range<u64>,
    ) -> Result<LogScans, SourceError> {
        let kind = kind_of(path)?;
        let channels = kind.channels(path)?;
        let topic = resolve_topic(path, &channels, self.spec.topic.as_deref())?;
        let session = self.spec.session_of(path);
        let poses = self.scan_poses(path, kind, &channels, &topic, file)?;
        let messages = kind.messages(path)?;
        let tolerance = (self.spec.tolerance_ms * 1e6).round() as i64;
        Ok(LogScans {
            messages,
            path: path.to_owned(),
            topic,
            session,
            poses,
            tolerance,
            index: 0,
            range,
            wanted: None,
        })
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
    poses: Option<ScanPoses>,
    /// The pose join's tolerance, ns.
    tolerance: i64,
    index: u64,
    /// The message indices wanted (all, for a whole file).
    range: std::ops::Range<u64>,
    /// Within the range, the only messages decoded (all, without).
    wanted: Option<Arc<std::collections::HashSet<u64>>>,
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
            if index < self.range.start || self.wanted.as_ref().is_some_and(|w| !w.contains(&index)) {
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
            let stamp_ns = if stamp_ns != 0 { stamp_ns } else { message.log_time as i64 };
            let utime = stamp_ns.div_euclid(1000);
            let pose = self
                .poses
                .as_ref()
                .map_or(Err(super::NoPose::NoGroundTruth), |p| p.at(stamp_ns, self.tolerance));
            let (pose, no_pose) = super::split_pose(pose);
            return Some(Ok(Scan {
                id,
                fingerprint,
                session: self.session.clone(),
                path,
                message_index: Some(index),
                utime: Some(utime),
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
