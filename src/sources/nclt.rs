//! NCLT Velodyne HDL-32E `velodyne_sync/<utime>.bin` scans (NCLT's `read_vel_sync.py`): little-endian
//! 8-byte records `x: u16, y: u16, z: u16, intensity: u8, laser_id: u8`, metric value
//! `raw · 0.005 − 100` m. Stored with z down; exposed as `(x, −y, −z)` (z up, see
//! [`super`]).

use super::poses::PoseTable;
use super::{Scan, ScanFailure, ScanStream, SourceError};
use crate::types::Point;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Bytes per record.
pub(crate) const RECORD: usize = 8;
/// Metres per raw unit.
pub(crate) const SCALE: f64 = 0.005;
/// Offset in metres.
pub(crate) const OFFSET: f64 = -100.0;

/// A decoded NCLT scan.
#[derive(Debug, Default)]
pub struct NcltScan {
    /// Points in metres, z up.
    pub points: Vec<Point>,
    /// Intensity per point.
    pub intensity: Vec<u8>,
    /// Laser id (ring) per point, 0..31.
    pub laser: Vec<u8>,
}

/// Decodes one `velodyne_sync` buffer.
pub fn decode_sync(bytes: &[u8], path: &Path) -> Result<NcltScan, SourceError> {
    if !bytes.len().is_multiple_of(RECORD) {
        return Err(SourceError::Truncated { path: path.to_owned(), len: bytes.len(), record: RECORD });
    }
    let n = bytes.len() / RECORD;
    let mut scan = NcltScan {
        points: Vec::with_capacity(n),
        intensity: Vec::with_capacity(n),
        laser: Vec::with_capacity(n),
    };
    for r in bytes.chunks_exact(RECORD) {
        let c = |o: usize| u16::from_le_bytes([r[o], r[o + 1]]) as f64 * SCALE + OFFSET;
        scan.points.push([c(0), -c(2), -c(4)]);
        scan.intensity.push(r[6]);
        scan.laser.push(r[7]);
    }
    Ok(scan)
}

/// Magic of a `velodyne_hits.bin` packet: four u16 equal to 44444.
pub const HITS_MAGIC: [u8; 8] = [0x9C, 0xAD, 0x9C, 0xAD, 0x9C, 0xAD, 0x9C, 0xAD];
/// Bytes of a packet header: magic, u32 hit count, u64 utime, 4 padding bytes.
pub(crate) const HITS_HEADER: usize = 24;

/// Which NCLT files to read in a session.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NcltReader {
    /// `velodyne_sync/<utime>.bin`, one file per scan.
    #[default]
    Sync,
    /// The raw `velodyne_hits.bin` stream, cut into scans.
    Hits,
}

/// `kind = "nclt"` in a pipeline file.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NcltSpec {
    /// Session folders (named by date, holding `velodyne_sync/` or `velodyne_hits.bin`), or
    /// folders holding such session folders.
    pub sessions: Vec<PathBuf>,
    /// Which files to read.
    #[serde(default)]
    pub reader: NcltReader,
    /// Ground-truth CSV; default: `groundtruth_<session>.csv` found near each session.
    #[serde(default)]
    pub groundtruth: Option<PathBuf>,
    /// Largest time gap for a pose join, milliseconds.
    #[serde(default = "default_tolerance_ms")]
    pub tolerance_ms: f64,
    /// `hits` only: cut scans every this many milliseconds instead of at each full revolution.
    #[serde(default)]
    pub hits_period_ms: Option<f64>,
}

fn default_tolerance_ms() -> f64 {
    100.0
}

/// Whether `dir` looks like one NCLT session.
pub(crate) fn is_session(dir: &Path) -> bool {
    dir.join("velodyne_sync").is_dir() || dir.join("velodyne_hits.bin").is_file()
}

impl super::Kind for NcltSpec {
    const NAME: &'static str = "nclt";
    const READS: &'static str = "NCLT session";

    fn detect(path: &Path) -> Option<super::Detected> {
        let (what, spec) = if path.is_dir() && is_session(path) {
            ("nclt session", NcltSpec::sessions(vec![path.to_owned()]))
        } else if path.is_dir()
            && std::fs::read_dir(path).is_ok_and(|e| e.flatten().any(|c| is_session(&c.path())))
        {
            ("nclt sessions", NcltSpec::sessions(vec![path.to_owned()]))
        } else if path.is_file() && path.file_name().is_some_and(|n| n == "velodyne_hits.bin") {
            let dir = path.parent().unwrap_or(Path::new(".")).to_owned();
            ("nclt velodyne_hits", NcltSpec { reader: NcltReader::Hits, ..NcltSpec::sessions(vec![dir]) })
        } else {
            return None;
        };
        Some(super::Detected { what, source: super::SourceSpec::new(spec) })
    }
}

impl super::Source for NcltSpec {
    fn kind(&self) -> &'static str {
        <Self as super::Kind>::NAME
    }

    fn keys(&self) -> toml::Table {
        toml::Table::try_from(self).expect("plain data")
    }

    fn problems(&self, inputs: bool) -> Vec<(&'static str, String)> {
        let mut out = super::required("sessions", &self.sessions, inputs);
        out.extend(super::missing("groundtruth", self.groundtruth.as_slice(), inputs));
        if let Some(p) = self.hits_period_ms.filter(|p| !(p.is_finite() && *p > 0.0)) {
            out.push(("hits_period_ms", format!("must be in (0, inf) ms; found {p}")));
        }
        out.extend(super::tolerance(self.tolerance_ms));
        out
    }

    fn open(&self) -> Result<ScanStream, SourceError> {
        NcltSpec::open(self)
    }

    fn sessions(&self) -> Result<Vec<(String, PathBuf)>, SourceError> {
        let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        Ok(self.session_dirs()?.into_iter().map(|d| (name(&d), d)).collect())
    }

    fn narrowed(&self, places: Vec<PathBuf>) -> Option<Box<dyn super::Source>> {
        Some(Box::new(NcltSpec { sessions: places, ..self.clone() }))
    }

    fn count_hint(&self) -> Option<u64> {
        if self.reader != NcltReader::Sync {
            return None;
        }
        let dirs = self.session_dirs().ok()?;
        dirs.iter()
            .map(|d| super::list_files(&d.join("velodyne_sync"), "bin").ok().map(|f| f.len() as u64))
            .sum()
    }

    fn session_folder(&self, file: &Path, format: Option<super::CloudFormat>) -> Option<(String, PathBuf)> {
        let in_layout = file.parent()?.file_name()? == "velodyne_sync";
        if self.reader != NcltReader::Sync || !(in_layout || format == Some(super::CloudFormat::Nclt)) {
            return None;
        }
        let dir = file.parent()?.parent()?;
        let canonical = |p: &Path| p.canonicalize().unwrap_or_else(|_| p.to_owned());
        let wanted = canonical(dir);
        let dirs = self.session_dirs().ok()?;
        let dir = dirs.into_iter().find(|d| canonical(d) == wanted)?;
        Some((dir.file_name()?.to_string_lossy().into_owned(), dir))
    }

    fn scan_files(
        &self,
        session: &str,
        dir: &Path,
        points_only: bool,
    ) -> Result<Arc<dyn super::ScanFiles>, SourceError> {
        // A ground truth that cannot be read leaves the scans without a pose, as a missing one does.
        let gt = match points_only {
            true => None,
            false => self
                .groundtruth
                .clone()
                .or_else(|| super::poses::find_for_session(dir, session))
                .and_then(|p| PoseTable::read_nclt(&p).ok()),
        };
        let tolerance = (self.tolerance_ms * 1000.0).round() as i64;
        Ok(Arc::new(SyncFiles { session: session.to_string(), gt, tolerance }))
    }

    fn pose_origins(&self) -> Vec<super::poses::PoseOrigin> {
        let Ok(sessions) = super::Source::sessions(self) else { return Vec::new() };
        let within = format!("NCLT layout, nearest time within {} ms", self.tolerance_ms);
        sessions
            .into_iter()
            .filter_map(|(session, dir)| {
                let file =
                    self.groundtruth.clone().or_else(|| super::poses::find_for_session(&dir, &session))?;
                let table = PoseTable::read_nclt(&file).unwrap_or_default();
                Some(super::poses::PoseOrigin::of_file(vec![session], &file, None, &table, &within))
            })
            .collect()
    }

    fn paths_mut(&mut self) -> Vec<&mut PathBuf> {
        self.sessions.iter_mut().chain(self.groundtruth.iter_mut()).collect()
    }

    fn overview(&self) -> Result<Vec<String>, SourceError> {
        Ok(match self.reader {
            NcltReader::Sync => vec![format!("sessions: {}", self.session_dirs()?.len())],
            NcltReader::Hits => Vec::new(),
        })
    }

    fn boxed(&self) -> Box<dyn super::Source> {
        Box::new(self.clone())
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

impl NcltSpec {
    /// A spec for given session folders with defaults.
    pub fn sessions(sessions: Vec<PathBuf>) -> Self {
        NcltSpec {
            sessions,
            reader: NcltReader::Sync,
            groundtruth: None,
            tolerance_ms: default_tolerance_ms(),
            hits_period_ms: None,
        }
    }

    /// The session folders, with parent folders expanded (sorted).
    pub fn session_dirs(&self) -> Result<Vec<PathBuf>, SourceError> {
        let mut out = Vec::new();
        for s in &self.sessions {
            if is_session(s) {
                out.push(s.clone());
                continue;
            }
            let entries =
                std::fs::read_dir(s).map_err(|source| SourceError::Io { path: s.clone(), source })?;
            let mut found: Vec<PathBuf> =
                entries.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| is_session(p)).collect();
            if found.is_empty() {
                return Err(SourceError::invalid(
                    s,
                    "not an NCLT session (no velodyne_sync/ or velodyne_hits.bin)",
                ));
            }
            found.sort();
            out.extend(found);
        }
        Ok(out)
    }

    /// Opens the stream over all sessions, in order. A session that cannot be opened (its
    /// ground truth unreadable, its scan folder or file missing) is one failure naming it, and
    /// the other sessions are read.
    pub fn open(&self) -> Result<ScanStream, SourceError> {
        let mut streams: Vec<ScanStream> = Vec::new();
        for dir in self.session_dirs()? {
            let session = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            match self.open_session(&dir, &session) {
                Ok(stream) => streams.push(stream),
                Err(e) => {
                    let failure = ScanFailure::of_input(&session, &dir, e.to_string());
                    streams.push(Box::new(std::iter::once(Err(failure))));
                }
            }
        }
        Ok(Box::new(streams.into_iter().flatten()))
    }

    /// The scans of one session folder.
    #[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
    fn open_session(&self, dir: &Path, session: &str) -> Result<ScanStream, SourceError> {
        let tolerance = (self.tolerance_ms * 1000.0).round() as i64;
        let gt_path = self.groundtruth.clone().or_else(|| super::poses::find_for_session(dir, session));
        let gt = match gt_path {
            Some(p) => Some(Arc::new(PoseTable::read_nclt(&p)?)),
            None => {
                tracing::info!("{}: no groundtruth_{session}.csv found; scans have no pose", dir.display());
                None
            }
        };
        let session = session.to_string();
        match self.reader {
            NcltReader::Sync => {
                let files = super::list_files(&dir.join("velodyne_sync"), "bin")?;
                let mut files: Vec<(Option<i64>, PathBuf)> = files
                    .into_iter()
                    .map(|p| (p.file_stem().and_then(|s| s.to_str()?.parse().ok()), p))
                    .collect();
                files.sort();
                Ok(Box::new(
                    files.into_iter().map(move |(utime, path)| {
                        sync_scan(&path, &session, utime, gt.as_deref(), tolerance)
                    }),
                ))
            }
            NcltReader::Hits => {
                let path = dir.join("velodyne_hits.bin");
                let file = std::fs::File::open(&path)
                    .map_err(|source| SourceError::Io { path: path.clone(), source })?;
                let period = self.hits_period_ms.map(|ms| (ms * 1000.0).round() as i64);
                Ok(Box::new(HitsScans::new(
                    std::io::BufReader::new(file),
                    path,
                    session,
                    period,
                    gt,
                    tolerance,
                )))
            }
        }
    }
}

/// A session's `velodyne_sync/` files, with its ground truth read once.
struct SyncFiles {
    session: String,
    gt: Option<PoseTable>,
    /// The join's tolerance, µs.
    tolerance: i64,
}

impl super::ScanFiles for SyncFiles {
    fn scan(&self, path: &Path, bytes: &[u8]) -> Result<Scan, ScanFailure> {
        sync_scan_bytes(path, bytes, &self.session, self.gt.as_ref(), self.tolerance)
    }
}

#[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
fn sync_scan(
    path: &Path,
    session: &str,
    utime: Option<i64>,
    gt: Option<&PoseTable>,
    tolerance: i64,
) -> Result<Scan, ScanFailure> {
    let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let fail = |error: String| ScanFailure::of_file(format!("{session}/{name}"), session, path, utime, error);
    let bytes = std::fs::read(path).map_err(|e| fail(format!("{}: {e}", path.display())))?;
    sync_scan_bytes(path, &bytes, session, gt, tolerance)
}

/// The scan of a `velodyne_sync/<utime>.bin` file's `bytes`, in session `session`, its pose
/// joined from `gt` within `tolerance` µs: as the NCLT source makes it from the file.
#[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
pub(crate) fn sync_scan_bytes(
    path: &Path,
    bytes: &[u8],
    session: &str,
    gt: Option<&PoseTable>,
    tolerance: i64,
) -> Result<Scan, ScanFailure> {
    let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let utime: Option<i64> = name.parse().ok();
    let fail = |error: String| ScanFailure::of_file(format!("{session}/{name}"), session, path, utime, error);
    let Some(utime) = utime else {
        return Err(fail(format!("{}: file name is not a utime (µs)", path.display())));
    };
    let fingerprint = crate::fingerprint::of_bytes(bytes);
    let scan = decode_sync(bytes, path).map_err(|e| fail(e.to_string()).with_fingerprint(fingerprint))?;
    Ok(to_scan(
        scan,
        format!("{session}/{utime}"),
        session,
        path,
        (utime, fingerprint),
        gt.map_or(Err(super::NoPose::NoGroundTruth), |g| g.pose_at(utime, tolerance)),
    ))
}

fn to_scan(
    scan: NcltScan,
    id: String,
    session: &str,
    path: &Path,
    (utime, fingerprint): (i64, u64),
    pose: Result<super::Pose, super::NoPose>,
) -> Scan {
    let (pose, no_pose) = super::split_pose(pose);
    Scan {
        id,
        fingerprint,
        session: session.to_string(),
        path: path.to_owned(),
        message_index: None,
        utime: Some(utime),
        raw_points: scan.points.len(),
        points: scan.points,
        intensity: Some(scan.intensity.iter().map(|&i| i as f32).collect()),
        ring: Some(scan.laser.iter().map(|&l| l as u16).collect()),
        pose,
        no_pose,
    }
}

/// Cuts the `velodyne_hits.bin` packet stream into scans: at each full revolution (the
/// azimuth of packets' first hits, unwrapped, has turned 2π) or every `period` µs. A bad
/// packet (wrong magic) is reported and skipped by searching for the next magic; a truncated
/// tail ends the stream with an error.
pub struct HitsScans<R> {
    input: R,
    path: PathBuf,
    session: String,
    period: Option<i64>,
    gt: Option<Arc<PoseTable>>,
    tolerance: i64,
    offset: u64,
    current: NcltScan,
    /// The fingerprint of the current scan's packets (utime and records).
    hash: crate::fingerprint::Streaming,
    start_utime: Option<i64>,
    turned: f64,
    last_azimuth: Option<f64>,
    pending: std::collections::VecDeque<Result<Scan, ScanFailure>>,
    magic_consumed: bool,
    done: bool,
}

impl<R: std::io::Read> HitsScans<R> {
    /// Reads packets from `input` (the file `path`).
    pub fn new(
        input: R,
        path: PathBuf,
        session: String,
        period: Option<i64>,
        gt: Option<Arc<PoseTable>>,
        tolerance: i64,
    ) -> Self {
        HitsScans {
            input,
            path,
            session,
            period,
            gt,
            tolerance,
            offset: 0,
            current: NcltScan::default(),
            hash: Default::default(),
            start_utime: None,
            turned: 0.0,
            last_azimuth: None,
            pending: Default::default(),
            magic_consumed: false,
            done: false,
        }
    }

    fn failure(&self, error: String) -> ScanFailure {
        ScanFailure {
            id: format!("{}/hits@{}", self.session, self.offset),
            session: self.session.clone(),
            path: self.path.clone(),
            message_index: None,
            utime: None,
            fingerprint: None,
            error: format!("{}: byte {}: {error}", self.path.display(), self.offset),
            // Packets past a bad one may hold scans the stream does not yield.
            input_unread: true,
        }
    }

    /// Ends the stream: the scan in progress, then `error` if any.
    fn stop(&mut self, error: Option<String>) {
        self.flush();
        if let Some(e) = error {
            let f = self.failure(e);
            self.pending.push_back(Err(f));
        }
        self.done = true;
    }

    fn flush(&mut self) {
        if let Some(utime) = self.start_utime.take()
            && !self.current.points.is_empty()
        {
            let scan = std::mem::take(&mut self.current);
            let pose = self
                .gt
                .as_ref()
                .map_or(Err(super::NoPose::NoGroundTruth), |g| g.pose_at(utime, self.tolerance));
            let id = format!("{}/{utime}", self.session);
            let fingerprint = self.hash.take();
            self.pending.push_back(Ok(to_scan(
                scan,
                id,
                &self.session,
                &self.path,
                (utime, fingerprint),
                pose,
            )));
        }
        self.hash.take();
        self.current = NcltScan::default();
        self.turned = 0.0;
    }

    /// Reads exactly `buf.len()` bytes; Ok(false) at a clean end of input.
    fn read_exact_or_eof(&mut self, buf: &mut [u8]) -> Result<bool, String> {
        let mut got = 0;
        while got < buf.len() {
            match self.input.read(&mut buf[got..]) {
                Ok(0) if got == 0 => return Ok(false),
                Ok(0) => {
                    return Err(format!("truncated: file ends {got} bytes into a {}-byte read", buf.len()));
                }
                Ok(k) => got += k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e.to_string()),
            }
        }
        Ok(true)
    }

    /// Reads one packet; Ok(None) at the end.
    fn packet(&mut self) -> Result<Option<(i64, Vec<u8>)>, String> {
        if !self.magic_consumed {
            let mut magic = [0u8; 8];
            if !self.read_exact_or_eof(&mut magic)? {
                return Ok(None);
            }
            if magic != HITS_MAGIC {
                return Err(BAD_MAGIC.into());
            }
        }
        self.magic_consumed = false;
        let mut rest = [0u8; HITS_HEADER - 8];
        if !self.read_exact_or_eof(&mut rest)? {
            return Err("truncated: file ends after a packet magic".into());
        }
        let hits = u32::from_le_bytes(rest[..4].try_into().unwrap()) as usize;
        let utime = u64::from_le_bytes(rest[4..12].try_into().unwrap()) as i64;
        if hits > MAX_HITS {
            return Err(format!("packet claims {hits} hits (corrupt header)"));
        }
        let mut body = vec![0u8; hits * RECORD];
        if hits > 0 && !self.read_exact_or_eof(&mut body)? {
            return Err("truncated: file ends after a packet header".into());
        }
        self.offset += (HITS_HEADER + body.len()) as u64;
        Ok(Some((utime, body)))
    }

    /// Skips forward to just after the next magic; Ok(false) at the end of input.
    fn resync(&mut self) -> Result<bool, String> {
        let mut window = [0u8; 8];
        let mut filled = 0;
        loop {
            let mut b = [0u8; 1];
            if !self.read_exact_or_eof(&mut b)? {
                return Ok(false);
            }
            self.offset += 1;
            window.rotate_left(1);
            window[7] = b[0];
            filled += 1;
            if filled >= 8 && window == HITS_MAGIC {
                self.offset -= 8;
                self.magic_consumed = true;
                return Ok(true);
            }
        }
    }

    fn add_packet(&mut self, utime: i64, body: &[u8]) {
        let packet = decode_sync(body, &self.path).expect("whole records");
        let Some(first) = packet.points.first() else { return };
        let azimuth = first[1].atan2(first[0]);
        let delta = self.last_azimuth.map_or(0.0, |a| {
            let d = azimuth - a;
            // Into (−π, π]: the rotation between two packets is small.
            d - (2.0 * PI) * ((d + PI) / (2.0 * PI)).floor()
        });
        self.last_azimuth = Some(azimuth);
        let cut = match (self.period, self.start_utime) {
            (Some(period), Some(start)) => utime - start >= period,
            (Some(_), None) => false,
            // (A hair under 2π: the sum of the packet steps rounds.)
            (None, _) => (self.turned + delta).abs() >= 2.0 * PI - 1e-9,
        };
        if cut {
            self.flush();
        } else {
            self.turned += delta;
        }
        self.start_utime.get_or_insert(utime);
        self.hash.write(&utime.to_le_bytes());
        self.hash.write(body);
        self.current.points.extend(packet.points);
        self.current.intensity.extend(packet.intensity);
        self.current.laser.extend(packet.laser);
    }
}

const BAD_MAGIC: &str = "bad packet magic (expected 4 × 0xAD9C); skipping to the next packet";
/// More hits than any real packet holds: the header is corrupt.
const MAX_HITS: usize = 1 << 20;

impl<R: std::io::Read> Iterator for HitsScans<R> {
    type Item = Result<Scan, ScanFailure>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(item) = self.pending.pop_front() {
                return Some(item);
            }
            if self.done {
                return None;
            }
            match self.packet() {
                Ok(Some((utime, body))) => self.add_packet(utime, &body),
                Ok(None) => self.stop(None),
                Err(e) if e == BAD_MAGIC => {
                    let f = self.failure(e);
                    self.pending.push_back(Err(f));
                    match self.resync() {
                        Ok(true) => {}
                        Ok(false) => self.stop(None),
                        Err(e) => self.stop(Some(e)),
                    }
                }
                Err(e) => self.stop(Some(e)),
            }
        }
    }
}
