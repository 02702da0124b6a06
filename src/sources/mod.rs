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
pub mod kitti;
pub mod logs;
pub mod mcap_reader;
pub mod nclt;
mod options;
pub mod pcd;
pub mod ply;
pub mod pointcloud2;
pub mod pointnetvlad;
pub mod poses;
pub mod reread;
pub mod ros1bag;
pub mod rosbag2;
pub mod rosmsg;
pub mod wire;

pub use crate::error::SourceError;
pub use options::SourceOptions;

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
    /// Timestamp in microseconds; `None` for a source that records no time (a folder of clouds
    /// named by frame number, a KITTI sequence without `times.txt`): such scans are ordered by
    /// their place in the source, and loops exclude neighbours by position, never by a made-up
    /// time.
    pub utime: Option<i64>,
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
            utime: None,
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

/// The scans of one session's scan files, with what the session gives them (its times and
/// poses), read once.
pub trait ScanFiles: Send + Sync {
    /// The scan in `bytes`, the content of `path`, one of the session's scan files.
    #[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
    fn scan(&self, path: &Path, bytes: &[u8]) -> Result<Scan, ScanFailure>;
}

/// The source of the session folder `dir` whose scan files are of `format` (`nclt`: NCLT
/// `velodyne_sync` records, `kitti`: KITTI frames), when a file of that format lies outside its
/// layout's folder (a batch's file given with its format).
pub(crate) fn of_format(dir: &Path, format: CloudFormat) -> Option<SourceSpec> {
    match format {
        CloudFormat::Nclt => Some(SourceSpec::new(nclt::NcltSpec::sessions(vec![dir.to_owned()]))),
        CloudFormat::Kitti => Some(SourceSpec::new(kitti::KittiSpec { sequences: vec![dir.to_owned()] })),
        _ => None,
    }
}

/// How a sharded run (`run --shard I/N`) hands out a source's scans.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Shards {
    /// By scan id: every shard reads the source and describes its own scans.
    Scans,
    /// By session: each session (a log) is read whole by one shard.
    Sessions,
}

/// A stream of scans; failures are items too, so one bad scan never stops a run.
pub type ScanStream = Box<dyn Iterator<Item = Result<Scan, ScanFailure>> + Send>;

/// A source: one `[[sources]]` entry of a pipeline file, read as its kind reads it. Each kind
/// is its module and one line of [`SOURCES`].
pub trait Source: std::fmt::Debug + Send + Sync + 'static {
    /// The `kind` it is written back as (its [`SOURCES`] entry's name).
    fn kind(&self) -> &'static str;

    /// Its keys as its `[[sources]]` table (without `kind`): what the effective pipeline of an
    /// index records.
    fn keys(&self) -> toml::Table;

    /// What parsing does not catch: empty lists, numbers out of range and, with `inputs`, paths
    /// that do not exist; each with its key.
    fn problems(&self, inputs: bool) -> Vec<(&'static str, String)>;

    /// Opens the stream. Fails only when the source as a whole is unusable (a missing folder,
    /// a log without point clouds); per-scan problems are stream items.
    fn open(&self) -> Result<ScanStream, SourceError>;

    /// The sessions it yields, with the folder or file each comes from.
    fn sessions(&self) -> Result<Vec<(String, PathBuf)>, SourceError>;

    /// The same source reading only the sessions that come from `places` (some of
    /// [`Source::sessions`]'); `None` when it cannot be narrowed (its stream is filtered then).
    fn narrowed(&self, places: Vec<PathBuf>) -> Option<Box<dyn Source>>;

    /// The number of scans, when a directory listing tells (NCLT `velodyne_sync`, KITTI);
    /// `None` when only reading would (logs, `velodyne_hits`).
    fn count_hint(&self) -> Option<u64> {
        None
    }

    /// Every path among its keys (relative ones are made relative to the pipeline file).
    fn paths_mut(&mut self) -> Vec<&mut PathBuf>;

    /// Whether a sharded run hands out its sessions whole (each read by one shard) rather than
    /// its scans by id.
    fn shards_by_session(&self) -> bool {
        false
    }

    /// This source with the poses and topic of the command line's `options` settled (`loops
    /// <source>`, `run <source>`): the spec written with explicit keys, and a note when it holds
    /// no pose; `None` for a source whose own poses are read (an error then, when the options
    /// ask for others). An error names the file and what to pass.
    fn settle(&self, _options: &SourceOptions) -> Option<Result<(SourceSpec, Option<String>), SourceError>> {
        None
    }

    /// Where its scans' poses come from: one entry per pose file or log that gives some, read
    /// now for its words and fingerprint (a run records them with its counts); empty when it
    /// has none.
    fn pose_origins(&self) -> Vec<poses::PoseOrigin> {
        Vec::new()
    }

    /// Its log `path`'s scans at message indices `messages`, when `path` is one of its logs: one
    /// pass over the log that decodes only those and stops after the last (`points_only`: no
    /// pose joined, so the log's poses are not gathered). See [`reread`].
    fn reread(
        &self,
        _path: &Path,
        _messages: &[u64],
        _points_only: bool,
    ) -> Option<Result<ScanStream, SourceError>> {
        None
    }

    /// The scans of its log `path` whose message index lies in `range`, when `path` is one of
    /// its logs (a batch's message range).
    fn read_range(
        &self,
        _path: &Path,
        _range: std::ops::Range<u64>,
    ) -> Option<Result<ScanStream, SourceError>> {
        None
    }

    /// The session (its name and folder) whose scan file `file` is, when it lists it: an NCLT
    /// session's `velodyne_sync/` file, a KITTI sequence's frame, a cloud file of a folder;
    /// `format` (`nclt`, `kitti`) takes a file outside its layout's folder as one of the session
    /// above it.
    fn session_folder(&self, _file: &Path, _format: Option<CloudFormat>) -> Option<(String, PathBuf)> {
        None
    }

    /// The reader of the scan files of its session `session` in `dir` (what the session gives
    /// its scans, times and poses, read once; `points_only`: no pose).
    fn scan_files(
        &self,
        _session: &str,
        dir: &Path,
        _points_only: bool,
    ) -> Result<std::sync::Arc<dyn ScanFiles>, SourceError> {
        Err(SourceError::invalid(dir, "not a folder of scan files"))
    }

    /// Lines `inspect` prints about it before its scans (sessions, topics).
    fn overview(&self) -> Result<Vec<String>, SourceError> {
        Ok(Vec::new())
    }

    /// A boxed copy.
    fn boxed(&self) -> Box<dyn Source>;

    /// Itself, for the readers that need one kind's own settings (a batch's message ranges,
    /// the PointNetVLAD protocol's sets).
    fn as_any(&self) -> &dyn std::any::Any;
}

/// A kind of source the registry knows: its pipeline-file `kind`, how its keys are read, and
/// how a path on the command line is recognised as one.
pub struct SourceKind {
    /// The `kind` of a `[[sources]]` entry.
    pub name: &'static str,
    /// What it reads, in a few words (for messages and docs).
    pub reads: &'static str,
    parse: fn(&toml::Table) -> Result<Box<dyn Source>, KeyError>,
    detect: fn(&Path) -> Option<Detected>,
}

/// A key of a `[[sources]]` entry that does not parse: its path (`sessions`, `tolerance_ms`,
/// or empty for the entry as a whole) and why.
#[derive(Clone, Debug, PartialEq)]
pub struct KeyError {
    /// The key's path inside the entry.
    pub path: String,
    /// The deserializer's message.
    pub message: String,
}

/// Reads an entry's keys (without `kind`) as `T`, keeping the path of the key at fault.
pub(crate) fn parse_keys<T: serde::de::DeserializeOwned>(keys: &toml::Table) -> Result<T, KeyError> {
    serde_path_to_error::deserialize(toml::Value::Table(keys.clone())).map_err(|e| {
        let path = e.path().to_string();
        KeyError {
            path: if path == "." { String::new() } else { path },
            message: e.into_inner().message().trim().to_string(),
        }
    })
}

/// The registry entry of a source whose keys are of type `S`.
const fn kind<S: Source + Kind + serde::de::DeserializeOwned>() -> SourceKind {
    fn parse<S: Source + serde::de::DeserializeOwned>(
        keys: &toml::Table,
    ) -> Result<Box<dyn Source>, KeyError> {
        parse_keys::<S>(keys).map(|s| Box::new(s) as Box<dyn Source>)
    }
    SourceKind { name: S::NAME, reads: S::READS, parse: parse::<S>, detect: S::detect }
}

/// What a source kind's keys type names itself, and how it recognises a path.
pub trait Kind {
    /// The `kind`.
    const NAME: &'static str;
    /// What it reads, in a few words.
    const READS: &'static str;
    /// The source reading `path` when it is one of this kind's (a session folder, a log file).
    fn detect(path: &Path) -> Option<Detected>;
}

/// Every kind of source, in the order a path is recognised: logs (by their content) first,
/// then layouts of folders (NCLT, KITTI), then folders of cloud files. Adding a kind is its
/// module and one line here; pipeline files, `inspect`, `query`, `loops` and `repair` find it.
pub const SOURCES: &[SourceKind] = &[
    kind::<logs::LogSpec>(),
    logs::MCAP_ALIAS,
    kind::<nclt::NcltSpec>(),
    kind::<kitti::KittiSpec>(),
    kind::<clouds::CloudsSpec>(),
    kind::<pointnetvlad::PointNetVladSpec>(),
];

impl SourceKind {
    /// The entry of `kind`.
    pub fn of(kind: &str) -> Option<&'static SourceKind> {
        SOURCES.iter().find(|k| k.name == kind)
    }

    /// The kinds' names, for messages: `rosbag, mcap, nclt, kitti, clouds or pointnetvlad`.
    pub fn names() -> String {
        let names: Vec<&str> = SOURCES.iter().map(|k| k.name).collect();
        match names.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
            _ => names.join(""),
        }
    }

    /// A source of this kind from an entry's keys (without `kind`).
    pub fn parse(&self, keys: &toml::Table) -> Result<SourceSpec, KeyError> {
        (self.parse)(keys).map(SourceSpec)
    }
}

/// A source as a pipeline holds it: any kind of [`SOURCES`].
pub struct SourceSpec(Box<dyn Source>);

impl SourceSpec {
    /// Wraps a source.
    pub fn new(source: impl Source) -> Self {
        SourceSpec(Box::new(source))
    }

    /// The source's own type, when it is `S`.
    fn get<S: Source>(&self) -> Option<&S> {
        self.0.as_any().downcast_ref::<S>()
    }

    /// The PointNetVLAD benchmark's source, when it is one (its protocol reads the sets).
    pub fn pointnetvlad(&self) -> Option<&pointnetvlad::PointNetVladSpec> {
        self.get()
    }

    /// This source restricted to the sessions in `wanted` (the same scans of those sessions,
    /// under the same ids); `None` when it yields none of them. A source whose sessions cannot
    /// be listed or narrowed is kept whole (its stream is filtered by the caller).
    pub fn only_sessions(&self, wanted: &std::collections::HashSet<String>) -> Option<SourceSpec> {
        let Ok(listed) = self.sessions() else { return Some(self.clone()) };
        let keep: Vec<PathBuf> =
            listed.iter().filter(|(s, _)| wanted.contains(s)).map(|(_, p)| p.clone()).collect();
        if keep.is_empty() {
            return None;
        }
        Some(self.narrowed(keep).map(SourceSpec).unwrap_or_else(|| self.clone()))
    }

    /// Makes relative paths relative to `base` (the pipeline file's folder).
    pub fn resolve_paths(&mut self, base: &Path) {
        self.clean_paths(|p| if p.is_relative() { base.join(p) } else { p.to_owned() });
    }

    /// Rewrites every path of the spec with `f`.
    pub fn clean_paths(&mut self, f: impl Fn(&Path) -> PathBuf) {
        for p in self.0.paths_mut() {
            *p = f(p);
        }
    }

    /// The entry as its `[[sources]]` table, `kind` included.
    pub fn table(&self) -> toml::Table {
        let mut t = self.0.keys();
        t.insert("kind".into(), toml::Value::String(self.0.kind().into()));
        t
    }
}

impl std::ops::Deref for SourceSpec {
    type Target = dyn Source;

    fn deref(&self) -> &dyn Source {
        &*self.0
    }
}

impl Clone for SourceSpec {
    fn clone(&self) -> Self {
        SourceSpec(self.0.boxed())
    }
}

impl std::fmt::Debug for SourceSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.0.fmt(f)
    }
}

impl PartialEq for SourceSpec {
    fn eq(&self, other: &Self) -> bool {
        self.table() == other.table()
    }
}

impl serde::Serialize for SourceSpec {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.table().serialize(serializer)
    }
}

/// The paths of `key` that do not exist (with `inputs`), as [`Source::problems`] lists them.
pub(crate) fn missing(key: &'static str, paths: &[PathBuf], inputs: bool) -> Vec<(&'static str, String)> {
    let gone = paths.iter().filter(|p| inputs && !p.exists());
    gone.map(|p| (key, format!("{} does not exist", p.display()))).collect()
}

/// As [`missing`], for a key that must name at least one path.
pub(crate) fn required(key: &'static str, paths: &[PathBuf], inputs: bool) -> Vec<(&'static str, String)> {
    let mut out = missing(key, paths, inputs);
    if paths.is_empty() {
        out.push((key, "empty".into()));
    }
    out
}

/// A pose-join tolerance out of its range, as [`Source::problems`] lists it.
pub(crate) fn tolerance(ms: f64) -> Option<(&'static str, String)> {
    (!(ms.is_finite() && ms >= 0.0)).then(|| ("tolerance_ms", format!("must be in [0, inf) ms; found {ms}")))
}

/// What a path given on the command line is: a source (its sessions, as it reads them), or
/// one cloud file.
#[derive(Clone, Debug)]
pub enum Input {
    /// A source, recognised by a kind of [`SOURCES`].
    Source(Detected),
    /// One cloud file.
    Cloud(CloudFormat),
}

/// A path recognised as a source.
#[derive(Clone, Debug)]
pub struct Detected {
    /// What the path is, in reports (`nclt session`, `ros1 bag`, `folder of clouds`).
    pub what: &'static str,
    /// The source reading it, at its kind's defaults.
    pub source: SourceSpec,
}

impl Input {
    /// Decides what `path` is: each kind of [`SOURCES`] in order, then a cloud file by its
    /// extension.
    pub fn detect(path: &Path) -> Result<Self, SourceError> {
        if !path.exists() {
            let source = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or folder");
            return Err(SourceError::Io { path: path.to_owned(), source });
        }
        if let Some(d) = SOURCES.iter().find_map(|k| (k.detect)(path)) {
            return Ok(Input::Source(d));
        }
        if let Some(why) = logs::not_a_log(path) {
            return Err(SourceError::invalid(path, why));
        }
        if path.is_dir() {
            let kinds: Vec<&str> = SOURCES.iter().map(|k| k.reads).filter(|r| !r.is_empty()).collect();
            let (last, rest) = kinds.split_last().expect("kinds");
            return Err(SourceError::invalid(path, format!("no {} or {last} here", rest.join(", "))));
        }
        CloudFormat::of_path(path)
            .map(Input::Cloud)
            .ok_or_else(|| SourceError::UnknownFormat { path: path.to_owned() })
    }

    /// Its name in reports.
    pub fn name(&self) -> &'static str {
        match self {
            Input::Source(d) => d.what,
            Input::Cloud(f) => f.name(),
        }
    }

    /// The source that reads it, with `topic` for a message log; `None` for a cloud file.
    pub fn source(&self, topic: Option<&str>) -> Option<SourceSpec> {
        let Input::Source(d) = self else { return None };
        match (d.source.get::<logs::LogSpec>(), topic) {
            (Some(log), Some(t)) => {
                Some(SourceSpec::new(logs::LogSpec { topic: Some(t.into()), ..log.clone() }))
            }
            _ => Some(d.source.clone()),
        }
    }
}

/// A single-cloud file format (`diagram --format`, a batch's `format`, detection by path).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
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
    /// The format a file name implies: `.csv`, `.pcd`, `.ply`; `.bin` under a `velodyne_sync`
    /// folder is NCLT, any other `.bin` KITTI.
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

    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            CloudFormat::Csv => "csv cloud",
            CloudFormat::Kitti => "kitti scan",
            CloudFormat::Nclt => "nclt velodyne_sync scan",
            CloudFormat::Pcd => "pcd cloud",
            CloudFormat::Ply => "ply cloud",
        }
    }

    /// Parses a format's name (`csv`, `kitti`, `nclt`, `pcd`, `ply`).
    pub fn parse(name: &str) -> Option<Self> {
        <Self as clap::ValueEnum>::from_str(name, true).ok()
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
        None => match Input::detect(path)? {
            Input::Cloud(f) => f,
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Every registered kind: a unique name, and an entry that reads back from the table it
    /// writes (what the effective pipeline of an index records).
    #[test]
    fn every_kind_round_trips_through_its_table() {
        let mut names: Vec<&str> = SOURCES.iter().map(|k| k.name).collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), SOURCES.len(), "kind names are unique");
        let minimal = |kind: &str| -> toml::Table {
            let key = match kind {
                "nclt" => "sessions",
                "kitti" => "sequences",
                "rosbag" => "paths",
                "mcap" => "files",
                "clouds" => "folders",
                "pointnetvlad" => "root",
                other => panic!("kind `{other}` has no minimal entry in this test: add one"),
            };
            let value = if key == "root" {
                toml::Value::String("/data".into())
            } else {
                toml::Value::Array(vec![toml::Value::String("/data/x".into())])
            };
            toml::Table::from_iter([(key.to_string(), value)])
        };
        for k in SOURCES {
            let spec = k.parse(&minimal(k.name)).unwrap_or_else(|e| panic!("{}: {e:?}", k.name));
            assert_eq!(spec.kind(), k.name);
            let mut table = spec.table();
            assert_eq!(table.remove("kind"), Some(toml::Value::String(k.name.into())));
            let again = k.parse(&table).unwrap_or_else(|e| panic!("{}: {e:?}", k.name));
            assert_eq!(again, spec, "{}", k.name);
            let unknown = toml::Table::from_iter([("no_such_key".to_string(), toml::Value::Integer(1))]);
            let mut bad = minimal(k.name);
            bad.extend(unknown);
            assert!(k.parse(&bad).unwrap_err().message.contains("no_such_key"), "{}", k.name);
        }
    }

    #[test]
    fn cloud_formats_parse_by_name() {
        for f in [CloudFormat::Csv, CloudFormat::Kitti, CloudFormat::Nclt, CloudFormat::Pcd, CloudFormat::Ply]
        {
            let name = clap::ValueEnum::to_possible_value(&f).unwrap().get_name().to_string();
            assert_eq!(CloudFormat::parse(&name), Some(f));
        }
    }
}
