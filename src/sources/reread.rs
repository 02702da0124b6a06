//! Reading scans again from where they were found: what `loops --verify` aligns, what `repair`
//! rebuilds, what `eval` perturbs or describes under a condition, and what a batch of scan files
//! describes. One way for all of them, so a scan read again is the scan the index was made from.
//!
//! A scan is found again by its [`Place`] (its `scans` row: session, source file, message
//! index), through the source that lists it:
//!
//! * a scan file (an NCLT `velodyne_sync/` file, a KITTI frame, a PCD/PLY file of a folder) is
//!   read alone, with what its session gives it — its times and poses — read once per session
//!   ([`ScanFiles`]);
//! * a message of a log is read by its index: one pass over the log that decodes only the
//!   messages wanted and stops after the last ([`super::Source::reread`]);
//! * a scan no source can read alone (one cut from NCLT's `velodyne_hits.bin` packet stream) is
//!   found by reading its session again.
//!
//! A batch's scan file that no source lists is read by the source its folder is (an NCLT session,
//! a KITTI sequence), found as `inspect` finds it.

use super::{CloudFormat, Input, Scan, ScanFailure, ScanFiles, SourceError, SourceSpec};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// Where a scan was found: what its `scans` row records.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct Place {
    /// The scan's id.
    pub scan_id: String,
    /// Its session.
    pub session: String,
    /// The file it came from.
    pub path: PathBuf,
    /// Its message index, in a log.
    pub message_index: Option<u64>,
}

/// A scan found again (or why not), with its place's id.
pub type Found = (String, Result<Scan, ScanFailure>);

/// Each session folder's scan-file reader (or why there is none), by (source, folder).
type FileReaders = HashMap<(usize, PathBuf), Result<Arc<dyn ScanFiles>, String>>;

/// Reads scans again through a pipeline's sources (see the module doc).
pub struct Rereader {
    sources: Vec<SourceSpec>,
    /// Read the scans' points only: no pose is joined (a log's poses are then not gathered).
    points_only: bool,
    /// Each session folder's scan files, by (source, folder); `usize::MAX` for a source found
    /// from the folder itself.
    files: Mutex<FileReaders>,
}

impl Rereader {
    /// A reader through `sources` (an index's pipeline's).
    pub fn new(sources: &[SourceSpec]) -> Self {
        Rereader { sources: sources.to_vec(), points_only: false, files: Mutex::new(HashMap::new()) }
    }

    /// The same, reading points only: the scans come without poses (what an alignment needs).
    pub fn points_only(mut self) -> Self {
        self.points_only = true;
        self
    }

    /// The scans at `places`, each with its place's id, in the order of `places`: read from
    /// where it was found (see the module doc). A scan that cannot be read is a failure naming
    /// it and why; one no source yields any more, a failure saying so.
    #[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
    pub fn scans(&self, places: &[Place]) -> Vec<Found> {
        let mut found: HashMap<String, Result<Scan, ScanFailure>> = self.stream(places).collect();
        places
            .iter()
            .map(|p| {
                let item = found.remove(&p.scan_id).unwrap_or_else(|| {
                    let why =
                        format!("{}: scan {} is not in its source any more", p.path.display(), p.scan_id);
                    Err(ScanFailure::of_file(p.scan_id.clone(), &p.session, &p.path, None, why))
                });
                (p.scan_id.clone(), item)
            })
            .collect()
    }

    /// The scans of `places` that can be found, each with its place's id, read one at a time as
    /// the stream is consumed (a scan is dropped once the caller is done with it): the scan files
    /// first, then each log's messages, then the scans found by reading their sessions.
    #[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
    pub fn stream<'a>(&'a self, places: &'a [Place]) -> Box<dyn Iterator<Item = Found> + Send + 'a> {
        let mut by_log: BTreeMap<&Path, Vec<&Place>> = BTreeMap::new();
        let mut files: Vec<&Place> = Vec::new();
        let mut by_session: Vec<&Place> = Vec::new();
        for place in places {
            if place.message_index.is_some() {
                by_log.entry(place.path.as_path()).or_default().push(place);
            } else if self.file_reader(&place.path, None).is_some() {
                files.push(place);
            } else {
                by_session.push(place);
            }
        }
        let files = files.into_iter().map(move |place| {
            let scan = match std::fs::read(&place.path) {
                Ok(bytes) => self
                    .file_reader(&place.path, None)
                    .expect("checked above")
                    .and_then(|r| r.scan(&place.path, &bytes)),
                Err(e) => Err(unreadable(&place.path, format!("{}: {e}", place.path.display()))),
            };
            (place.scan_id.clone(), scan)
        });
        let mut logs: Vec<Box<dyn Iterator<Item = Found> + Send + 'a>> = Vec::new();
        for (path, wanted) in by_log {
            let indices: Vec<u64> = wanted.iter().filter_map(|p| p.message_index).collect();
            let Some(stream) = self.sources.iter().find_map(|s| s.reread(path, &indices, self.points_only))
            else {
                by_session.extend(wanted);
                continue;
            };
            match stream {
                Ok(items) => {
                    let ids: HashMap<u64, String> =
                        wanted.iter().filter_map(|p| Some((p.message_index?, p.scan_id.clone()))).collect();
                    logs.push(Box::new(items.filter_map(move |item| {
                        let index = match &item {
                            Ok(s) => s.message_index,
                            Err(f) => f.message_index,
                        };
                        Some((ids.get(&index?)?.clone(), item))
                    })));
                }
                Err(e) => {
                    let failed: Vec<Found> = wanted
                        .iter()
                        .map(|p| {
                            let f = ScanFailure::of_file(
                                p.scan_id.clone(),
                                &p.session,
                                path,
                                None,
                                e.to_string(),
                            );
                            (p.scan_id.clone(), Err(f))
                        })
                        .collect();
                    logs.push(Box::new(failed.into_iter()));
                }
            }
        }
        let sessions: HashSet<String> = by_session.iter().map(|p| p.session.clone()).collect();
        let wanted: HashSet<String> = by_session.iter().map(|p| p.scan_id.clone()).collect();
        let streams = if sessions.is_empty() { Vec::new() } else { self.sessions(&sessions) };
        let by_sessions = streams.into_iter().flatten().filter_map(move |item| {
            let id = match &item {
                Ok(s) => s.id.clone(),
                Err(f) => f.id.clone(),
            };
            wanted.contains(&id).then_some((id, item))
        });
        Box::new(files.chain(logs.into_iter().flatten()).chain(by_sessions))
    }

    /// Every scan of `sessions`, as the sources listing them yield them: one stream per source
    /// that lists any (a source that cannot be opened is a warning naming it).
    pub fn sessions(&self, sessions: &HashSet<String>) -> Vec<super::ScanStream> {
        let mut out: Vec<super::ScanStream> = Vec::new();
        for spec in &self.sources {
            let Some(spec) = spec.only_sessions(sessions) else { continue };
            match spec.open() {
                Ok(s) => out.push(s),
                // Its sessions' scans are then not found: each is named by its reader.
                Err(e) => tracing::warn!("{e}"),
            }
        }
        out
    }

    /// The scan in `bytes`, the content of the scan file `path`, as the source that lists its
    /// session makes it (its time and pose), else as the source its folder is (an NCLT session, a
    /// KITTI sequence); `format` (`nclt` or `kitti`) says which for a file outside its layout's
    /// folder.
    #[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
    pub fn file(&self, path: &Path, bytes: &[u8], format: Option<CloudFormat>) -> Result<Scan, ScanFailure> {
        match self.file_reader(path, format) {
            Some(reader) => reader.and_then(|r| r.scan(path, bytes)),
            None => Err(unreadable(
                path,
                format!(
                    "{}: unknown scan file format (give `format`: nclt or kitti; or the layout's velodyne_sync/ or velodyne/ folder)",
                    path.display()
                ),
            )),
        }
    }

    /// The scans of the log `path` whose message index lies in `range`, as the source that lists
    /// it reads it (its topic, poses, session), else with a log's defaults.
    pub fn log_range(
        &self,
        path: &Path,
        range: std::ops::Range<u64>,
    ) -> Result<super::ScanStream, SourceError> {
        let listed = self.sources.iter().find_map(|s| s.read_range(path, range.clone()));
        listed.unwrap_or_else(|| super::logs::LogSpec::path(path).open_range(path, range))
    }

    /// The scan-file reader of `path`'s session: the listing source's, else the one of the
    /// source its folder is; `None` when no source reads it as a scan file.
    fn file_reader(
        &self,
        path: &Path,
        format: Option<CloudFormat>,
    ) -> Option<Result<Arc<dyn ScanFiles>, ScanFailure>> {
        let found = self
            .sources
            .iter()
            .enumerate()
            .find_map(|(i, s)| Some((i, s.clone(), s.session_folder(path, format)?)));
        let (key, spec, (session, dir)) = match found {
            Some(x) => x,
            None => {
                let folder = path.parent().and_then(Path::parent)?;
                let Ok(Input::Source(detected)) = Input::detect(folder) else {
                    return format.and_then(|f| self.by_format(path, f));
                };
                let at = detected.source.session_folder(path, format)?;
                (usize::MAX, detected.source, at)
            }
        };
        Some(self.cached(key, &spec, &session, &dir, path))
    }

    /// A file of `format` outside its layout's folder: read by a default source of that kind.
    fn by_format(&self, path: &Path, format: CloudFormat) -> Option<Result<Arc<dyn ScanFiles>, ScanFailure>> {
        let dir = path.parent().and_then(Path::parent)?.to_owned();
        let spec = super::of_format(&dir, format)?;
        let session = folder_name(Some(&dir));
        Some(self.cached(usize::MAX, &spec, &session, &dir, path))
    }

    #[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
    fn cached(
        &self,
        key: usize,
        spec: &SourceSpec,
        session: &str,
        dir: &Path,
        path: &Path,
    ) -> Result<Arc<dyn ScanFiles>, ScanFailure> {
        let mut files = self.files.lock().unwrap_or_else(|e| e.into_inner());
        let entry = files
            .entry((key, dir.to_owned()))
            .or_insert_with(|| spec.scan_files(session, dir, self.points_only).map_err(|e| e.to_string()));
        entry.clone().map_err(|e| {
            let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            ScanFailure::of_file(format!("{session}/{name}"), session, path, None, e)
        })
    }
}

/// The failure of a scan file that could not be read: named `<session folder>/<file stem>`, as
/// the layouts of scan files name their scans.
pub fn unreadable(path: &Path, error: String) -> ScanFailure {
    let session = folder_name(path.parent().and_then(Path::parent));
    let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    ScanFailure::of_file(format!("{session}/{name}"), &session, path, None, error)
}

/// A folder's name, as a session is named.
fn folder_name(dir: Option<&Path>) -> String {
    dir.and_then(Path::file_name).map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
}
