//! Writing an index: one writer at a time, rows committed in chunks.
//!
//! [`IndexWriter::open`] refuses a folder that holds something but no index (it deletes
//! nothing that is not its own), takes an OS advisory lock on `INDEX/.lock` (released by the
//! OS when the process ends, however it ends: a killed writer leaves no stale lock), reads the
//! manifest, and completes or undoes a commit a kill interrupted (`super::recovery`).
//!
//! Rows go into the open chunk's part files, written in `.staging/` (outside the table
//! folders, under names no `*.parquet` glob matches). [`IndexWriter::commit`] closes them
//! (fsync), writes the committed files that hold rows being replaced or pruned again without
//! them (checking each file it reads against its checksum), and then:
//!
//! 1. replaces the manifest atomically (temporary file, fsync, rename, fsync of the folder),
//!    naming the new files at their places: **the commit point**;
//! 2. renames the staged files into place;
//! 3. deletes the files the new manifest no longer names.
//!
//! Killed before 1, the commit never happened; after it, the next process to open the index
//! completes it. A plain glob of the tables sees committed files only, and a mix of two
//! generations only for the milliseconds of steps 2 and 3 (no data is written then).
//!
//! The commit protocol (chunks, replacement, pruning, `--full` rebuilds) is one state machine
//! over one manifest, kept in this file to be read as one; taking in other writers' files
//! (`merge`), compaction (`compact`) and repair's rows (`repair`) are its submodules.
//!
//! A rebuild (`run --full`) writes the new generation beside the old one: its chunks stay in
//! `.staging/` and the on-disk manifest keeps naming the old files until
//! [`IndexWriter::finish`] switches to the new ones in one commit.

mod compact;
mod merge;
mod repair;
mod rewrite;

pub use rewrite::Joined;
use rewrite::rewrite_rows;

use super::damage::{Checked, DamagedPart, checked_bytes};
use super::manifest::{Counts, FileEntry, MANIFEST_VERSION, Manifest, MethodEntry, file_checksum};
use super::reader::{read_scans_in, scan_ids_in};
use super::recovery::{self, take_lock};
use super::{CODEBOOK_FILE, MANIFEST_FILE, PIPELINE_FILE, STAGING_DIR, partition_dir, resolve, staged_path};
use crate::error::{Error, Result, ResultExt};
use crate::fsutil::StagedFile;
use crate::homology::Diagram;
use crate::methods::TOPOREC;
use crate::sinks::parquet::{DescriptorRow, DescriptorsFile, DiagramsFile, ScanRow, ScansFile, Status};
use crate::sinks::schema::tables;
use crate::vectorize::codebook::Codebook;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// What the index holds for one committed scan.
#[derive(Clone, Debug, PartialEq)]
pub struct CommittedScan {
    /// Session.
    pub session: String,
    /// Content fingerprint (hex), when the scan could be read.
    pub fingerprint: Option<String>,
    /// Settings fingerprint of its row.
    pub settings_hash: String,
    /// Its status.
    pub status: Status,
    /// Why skipped or failed.
    pub error: Option<String>,
    /// Whether the descriptors table has its TopoRec row.
    pub has_descriptor: bool,
    /// Timestamp (µs).
    pub utime: Option<i64>,
    /// Ground-truth pose.
    pub pose: Option<crate::types::Pose>,
}

impl CommittedScan {
    /// Its time and pose.
    pub fn joined(&self) -> Joined {
        Joined { utime: self.utime, pose: self.pose }
    }

    /// A committed `scans` row as the writer keeps it, with its id (no TopoRec descriptor
    /// known yet).
    fn of_row(r: ScanRow) -> (String, CommittedScan) {
        let record = CommittedScan {
            session: r.session,
            fingerprint: r.fingerprint,
            settings_hash: r.settings_hash,
            status: r.status,
            error: r.error,
            has_descriptor: false,
            utime: r.utime,
            pose: r.pose,
        };
        (r.scan_id, record)
    }
}

/// The files of the open chunk, per session, each with its path once committed.
#[derive(Default)]
struct SessionFiles {
    scans: Option<(String, ScansFile)>,
    diagrams: Option<(String, DiagramsFile)>,
    /// By method.
    descriptors: BTreeMap<String, (String, DescriptorsFile)>,
}

/// A complete file in the staging folder, waiting for its commit.
struct Staged {
    /// Its manifest entry (its path in place, rows, size, checksum).
    entry: FileEntry,
}

impl Staged {
    /// Puts a closed file under its staged name, and takes its size and checksum.
    fn of(
        table: &str,
        method: Option<String>,
        session: &str,
        rel: String,
        file: StagedFile,
        rows: u64,
    ) -> Result<Self> {
        let path = file.publish_unsynced()?;
        let (bytes, xxh3) = file_checksum(&path)?;
        let entry = FileEntry {
            table: table.to_string(),
            method,
            session: session.to_string(),
            path: rel,
            rows,
            bytes,
            xxh3,
        };
        Ok(Staged { entry })
    }
}

/// One descriptor of a scan, for [`IndexWriter::write_scan`].
#[derive(Clone, Debug, PartialEq)]
pub struct MethodDescriptor {
    /// The method (`toporec`, `scancontext`, …).
    pub method: String,
    /// What made it: the codebook id (TopoRec) or the method's id (others).
    pub id: String,
    /// The row.
    pub row: DescriptorRow,
}

/// The index writer (see the module doc).
pub struct IndexWriter {
    root: PathBuf,
    _lock: std::fs::File,
    /// The manifest of the last commit (of a rebuild: of its last chunk, not yet on disk).
    manifest: Manifest,
    /// A rebuild's: the manifest on disk, whose files stay until the switch.
    rebuild_of: Option<Manifest>,
    /// A rebuild's: its committed chunks' files, staged until the switch.
    held: Vec<Staged>,
    committed: HashMap<String, CommittedScan>,
    chunk: BTreeMap<String, SessionFiles>,
    chunk_rows: u64,
    chunk_started: Instant,
    /// Scans of the open chunk (for the counts and the committed-scan map).
    chunk_scans: Vec<(String, CommittedScan)>,
    /// Committed scans to drop at the next commit (replaced or pruned).
    removals: HashSet<String>,
    /// Committed scans whose time and pose are written anew at the next commit (their source's
    /// poses changed; nothing else of them did).
    rejoined: HashMap<String, Joined>,
    /// Sessions of removed scans that have no committed `scans` row (its part was damaged).
    removal_sessions: HashSet<String>,
    /// Whether the next commit counts the scans anew from the rows it keeps (a repair: the
    /// counts of a damaged `scans` part cannot be taken off one by one).
    recount: bool,
    /// The codebook (and pipeline text) to commit with the next chunk.
    pending_codebook: Option<(Codebook, Option<String>)>,
    /// The effective pipeline to write with the next commit.
    pending_pipeline: Option<String>,
    /// The poses' origins to record with the next commit.
    pending_poses: Option<Vec<crate::sources::poses::PoseOrigin>>,
    /// Committed files to drop at the next commit (a new descriptors table, compaction).
    dropped: HashSet<String>,
    /// Merged files to add at the next commit (compaction).
    compacted: Vec<Staged>,
    /// The methods to record with the next commit.
    pending_methods: Option<BTreeMap<String, MethodEntry>>,
    /// Whether `codebook.json` and `pipeline.toml` are to be written after the next commit
    /// that reaches the disk.
    copies_stale: bool,
    commits: u64,
}

impl IndexWriter {
    /// Opens (or creates) the index at `root` for writing. `full`: delete what it holds first.
    /// Fails at once when another writer holds the index.
    pub fn open(root: &Path, settings_hash: &str, full: bool) -> Result<Self> {
        Self::open_with(root, settings_hash, full, false, false).map(|(w, _)| w)
    }

    /// [`IndexWriter::open`], waiting for another writer to finish instead of failing (the
    /// merge step of a sharded run: shards take turns at the manifest).
    pub fn open_waiting(root: &Path, settings_hash: &str) -> Result<Self> {
        Self::open_with(root, settings_hash, false, true, false).map(|(w, _)| w)
    }

    /// Opens an index to repair it: every committed part is checked first, and the writer's
    /// view of the committed scans is taken from the intact ones. Returns the damaged parts
    /// too (`toporec repair` drops them at its commit).
    pub fn open_for_repair(root: &Path) -> Result<(Self, Vec<DamagedPart>)> {
        let Some(manifest) = Manifest::load(&root.join(MANIFEST_FILE))? else {
            return Err(Error::index(root, "no manifest.json: not an index toporec wrote"));
        };
        Self::open_with(root, &manifest.settings_hash, false, false, true)
    }

    fn open_with(
        root: &Path,
        settings_hash: &str,
        full: bool,
        wait: bool,
        repair: bool,
    ) -> Result<(Self, Vec<DamagedPart>)> {
        recovery::check_writable_folder(root)?;
        std::fs::create_dir_all(root).at(root)?;
        let lock = take_lock(root, wait)?;
        let on_disk = Manifest::load(&root.join(MANIFEST_FILE))?;
        if let Some(m) = &on_disk {
            recovery::recover(root, m)?;
        } else {
            recovery::recover(root, &Manifest::empty(settings_hash))?;
        }
        // A rebuild starts from an empty manifest; the old one stays on disk until the switch.
        let (manifest, rebuild_of) = match on_disk {
            Some(old) if full && old.generation > 0 => {
                let mut fresh = Manifest::empty(settings_hash);
                fresh.next_part = old.next_part;
                (fresh, Some(old))
            }
            Some(m) if !full => (m, None),
            _ => (Manifest::empty(settings_hash), None),
        };
        // Checked under the lock: no other writer changes the parts meanwhile.
        let damaged = if repair { super::damage::damaged_parts(root, &manifest)? } else { Vec::new() };
        let skip: HashSet<String> = damaged.iter().map(|d| d.path.clone()).collect();
        let committed = committed_scans(root, &manifest, &skip)?;
        let writer = IndexWriter {
            root: root.to_owned(),
            _lock: lock,
            manifest,
            rebuild_of,
            held: Vec::new(),
            committed,
            chunk: BTreeMap::new(),
            chunk_rows: 0,
            chunk_started: Instant::now(),
            chunk_scans: Vec::new(),
            removals: HashSet::new(),
            rejoined: HashMap::new(),
            removal_sessions: HashSet::new(),
            recount: false,
            pending_codebook: None,
            pending_pipeline: None,
            pending_poses: None,
            dropped: HashSet::new(),
            compacted: Vec::new(),
            pending_methods: None,
            copies_stale: false,
            commits: 0,
        };
        Ok((writer, damaged))
    }

    /// The index folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The committed manifest.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The committed scans, by id.
    pub fn committed(&self) -> &HashMap<String, CommittedScan> {
        &self.committed
    }

    /// Chunks committed by this writer.
    pub fn commits(&self) -> u64 {
        self.commits
    }

    /// Scans in the open chunk.
    pub fn chunk_len(&self) -> u64 {
        self.chunk_rows
    }

    /// Seconds since the open chunk started.
    pub fn chunk_age(&self) -> Duration {
        self.chunk_started.elapsed()
    }

    /// A new part file: its path in place (relative to the index) and where it is written
    /// until its commit.
    fn next_part(&mut self, table: &str, method: Option<&str>, session: &str) -> (String, PathBuf) {
        let n = self.manifest.next_part;
        self.manifest.next_part += 1;
        let rel = partition_dir(table, method, session).join(format!("part-{n:06}.parquet"));
        let rel = rel.to_string_lossy().replace('\\', "/");
        let staged = staged_path(&self.root, &rel);
        (rel, staged)
    }

    /// Where the bytes of a committed file are (in place, or staged: a rebuild's chunks).
    pub fn path_of(&self, entry: &FileEntry) -> PathBuf {
        resolve(&self.root, &entry.path)
    }

    /// [`IndexWriter::path_of`], after checking the file against its size and checksum: every
    /// file a rewrite reads (compaction, replaced rows, a new codebook's descriptors) is
    /// checked first, so damage is refused, never copied into a file with a fresh checksum.
    pub fn verified_path(&self, entry: &FileEntry) -> Result<PathBuf> {
        self.verified_bytes(entry).map(|_| self.path_of(entry))
    }

    /// The bytes of a committed file, checked against its commit (see
    /// [`IndexWriter::verified_path`]): what a rewrite reads.
    pub fn verified_bytes(&self, entry: &FileEntry) -> Result<bytes::Bytes> {
        verified(&self.root, entry, self.manifest.generation)
    }

    fn session_files(&mut self, session: &str) -> &mut SessionFiles {
        if !self.chunk.contains_key(session) {
            self.chunk.insert(session.to_string(), SessionFiles::default());
        }
        self.chunk.get_mut(session).expect("inserted")
    }

    /// Adds one scan to the open chunk: its row, its pairs in `dims` (ok scans), its
    /// descriptors (one per method it has). A committed scan of the same id is replaced at the
    /// commit.
    pub fn write_scan(
        &mut self,
        row: ScanRow,
        diagram: Option<&Diagram>,
        dims: &[u8],
        descriptors: Vec<MethodDescriptor>,
    ) -> Result<()> {
        if self.committed.contains_key(&row.scan_id) {
            self.removals.insert(row.scan_id.clone());
        }
        let session = row.session.clone();
        if let Some(d) = diagram {
            self.push_diagram(&session, &row.scan_id, d, dims)?;
        }
        let has_descriptor = descriptors.iter().any(|d| d.method == TOPOREC);
        for d in descriptors {
            self.push_descriptor(&session, &d.method, d.row, || d.id.clone())?;
        }
        self.push_scan(row, has_descriptor)
    }

    fn push_diagram(&mut self, session: &str, scan_id: &str, diagram: &Diagram, dims: &[u8]) -> Result<()> {
        if self.session_files(session).diagrams.is_none() {
            let (rel, staged) = self.next_part(tables::DIAGRAMS, None, session);
            let f = DiagramsFile::create(&staged)?;
            self.session_files(session).diagrams = Some((rel, f));
        }
        self.session_files(session).diagrams.as_mut().expect("opened").1.push(scan_id, diagram, dims)
    }

    /// Adds a `scans` row to the open chunk, with what the writer keeps of it.
    fn push_scan(&mut self, row: ScanRow, has_descriptor: bool) -> Result<()> {
        let session = row.session.clone();
        if self.session_files(&session).scans.is_none() {
            let (rel, staged) = self.next_part(tables::SCANS, None, &session);
            let f = ScansFile::create(&staged)?;
            self.session_files(&session).scans = Some((rel, f));
        }
        let record = CommittedScan {
            session: session.clone(),
            fingerprint: row.fingerprint.clone(),
            settings_hash: row.settings_hash.clone(),
            status: row.status,
            error: row.error.clone(),
            has_descriptor,
            utime: row.utime,
            pose: row.pose,
        };
        tracing::debug!(scan = %row.scan_id, "row added to the open chunk");
        self.chunk_scans.push((row.scan_id.clone(), record));
        self.chunk_rows += 1;
        self.session_files(&session).scans.as_mut().expect("opened").1.push(row)
    }

    /// Adds the TopoRec descriptor of a committed scan to the open chunk.
    pub fn write_descriptor(&mut self, session: &str, row: DescriptorRow, codebook: &Codebook) -> Result<()> {
        self.chunk_rows += 1;
        if let Some(c) = self.committed.get_mut(&row.scan_id) {
            c.has_descriptor = true;
        }
        self.push_descriptor(session, TOPOREC, row, || codebook.id())
    }

    /// Adds a descriptor of `method` (not TopoRec) of a committed scan to the open chunk
    /// (`toporec import`): `id` is the method's.
    pub fn write_method_descriptor(
        &mut self,
        session: &str,
        method: &str,
        id: &str,
        row: DescriptorRow,
    ) -> Result<()> {
        self.chunk_rows += 1;
        self.push_descriptor(session, method, row, || id.to_string())
    }

    fn push_descriptor(
        &mut self,
        session: &str,
        method: &str,
        row: DescriptorRow,
        id: impl FnOnce() -> String,
    ) -> Result<()> {
        if !self.session_files(session).descriptors.contains_key(method) {
            let (rel, staged) = self.next_part(tables::DESCRIPTORS, Some(method), session);
            let f = DescriptorsFile::create(&staged, method, row.values.len(), &id())?;
            self.session_files(session).descriptors.insert(method.to_string(), (rel, f));
        }
        self.session_files(session).descriptors.get_mut(method).expect("opened").1.push(row)
    }

    /// Records the index's descriptor methods besides TopoRec with the next commit.
    pub fn set_methods(&mut self, methods: BTreeMap<String, MethodEntry>) {
        if methods != self.manifest.methods {
            self.pending_methods = Some(methods);
        }
    }

    /// Drops every committed descriptors file of `method` (not TopoRec) at the next commit.
    pub fn drop_method(&mut self, method: &str) {
        let files: Vec<String> = self.manifest.descriptor_files_of(method).map(|f| f.path.clone()).collect();
        self.dropped.extend(files);
    }

    /// Marks a committed scan for removal at the next commit.
    pub fn remove(&mut self, scan_id: &str) {
        if self.committed.contains_key(scan_id) {
            self.removals.insert(scan_id.to_string());
        }
    }

    /// Writes a committed scan's time and pose anew at the next commit, in every table that
    /// holds them (`scans`, `descriptors`), leaving its other columns as they are: what a run
    /// does when a scan's poses changed and its points did not.
    pub fn rejoin(&mut self, scan_id: &str, joined: Joined) {
        if self.committed.contains_key(scan_id) {
            self.rejoined.insert(scan_id.to_string(), joined);
        }
    }

    /// Commits `codebook` (and the effective pipeline `pipeline_toml`) with the next commit.
    pub fn set_codebook(&mut self, codebook: Codebook, pipeline_toml: Option<String>) {
        self.pending_codebook = Some((codebook, pipeline_toml));
    }

    /// Drops every committed TopoRec descriptors file at the next commit (a new codebook's
    /// descriptors replace them in the same commit).
    pub fn drop_descriptors(&mut self) {
        let files: Vec<String> = self.manifest.descriptor_files_of(TOPOREC).map(|f| f.path.clone()).collect();
        self.dropped.extend(files);
        self.committed.values_mut().for_each(|c| c.has_descriptor = false);
    }

    /// Records the effective pipeline with the next commit (in the manifest, and its copy
    /// `pipeline.toml`), when it is not the one recorded.
    pub fn set_pipeline(&mut self, text: String) {
        if self.manifest.pipeline.as_deref() != Some(text.as_str()) {
            self.pending_pipeline = Some(text);
        }
    }

    /// Records where the scans' poses came from with the next commit, when it is not what the
    /// manifest records.
    pub fn set_pose_origins(&mut self, origins: Vec<crate::sources::poses::PoseOrigin>) {
        let recorded: Vec<_> = origins.iter().map(|o| o.recorded()).collect();
        if self.manifest.poses != recorded {
            self.pending_poses = Some(recorded);
        }
    }

    /// Commits the open chunk (see the module doc). A no-op when there is nothing to commit.
    /// In a rebuild, the chunk is committed to the rebuild only: the index on disk is
    /// unchanged until [`IndexWriter::finish`].
    pub fn commit(&mut self) -> Result<()> {
        if self.chunk.is_empty()
            && self.compacted.is_empty()
            && self.removals.is_empty()
            && self.rejoined.is_empty()
            && self.pending_codebook.is_none()
            && self.pending_methods.is_none()
            && self.pending_pipeline.is_none()
            && self.pending_poses.is_none()
            && self.dropped.is_empty()
        {
            return Ok(());
        }
        let mut staged: Vec<Staged> = Vec::new();
        let outcome = self.stage(&mut staged);
        let (manifest, superseded, removals) = match outcome {
            Ok(x) => x,
            Err(e) => {
                // Not committed: what was staged is nobody's.
                discard(&self.root, &staged);
                return Err(e);
            }
        };
        crate::fault::point("after-staging");
        if self.rebuild_of.is_some() {
            // A superseded file of the rebuild itself is still staged: gone now.
            self.held.retain(|h| {
                let keep = !superseded.contains(&h.entry.path);
                if !keep {
                    let _ = std::fs::remove_file(staged_path(&self.root, &h.entry.path));
                }
                keep
            });
            self.held.extend(staged);
            self.settle(manifest, &removals);
            crate::fault::point("full-mid");
            return Ok(());
        }
        tracing::info!(generation = manifest.generation, files = staged.len(), "publishing a chunk");
        let codebook_changed = self.pending_codebook.is_some() || self.copies_stale;
        self.publish(&manifest, &staged, &superseded, codebook_changed)?;
        self.settle(manifest, &removals);
        Ok(())
    }

    /// Switches the index to what this writer committed: for a rebuild, the commit that
    /// replaces the old generation by the new one (until then, readers and a killed run see the
    /// old index whole); otherwise a plain [`IndexWriter::commit`].
    pub fn finish(&mut self) -> Result<()> {
        self.commit()?;
        let Some(old) = self.rebuild_of.take() else { return Ok(()) };
        let mut manifest = self.manifest.clone();
        manifest.generation = old.generation + 1;
        let superseded: Vec<String> = old.files.iter().map(|f| f.path.clone()).collect();
        let staged = std::mem::take(&mut self.held);
        tracing::info!(
            generation = manifest.generation,
            files = staged.len(),
            "switching to the rebuilt index"
        );
        self.publish(&manifest, &staged, &superseded, true)?;
        self.manifest = manifest;
        self.commits += 1;
        Ok(())
    }

    /// The first half of a commit: the chunk's files closed and staged, the committed files
    /// holding removed rows rewritten (staged too), and the manifest that names them. Returns
    /// that manifest, the files it supersedes and the scans it removes.
    fn stage(&mut self, staged: &mut Vec<Staged>) -> Result<(Manifest, Vec<String>, HashSet<String>)> {
        staged.append(&mut self.compacted);
        for (session, files) in std::mem::take(&mut self.chunk) {
            if let Some((rel, f)) = files.scans {
                let (file, rows) = f.finish()?;
                staged.push(Staged::of(tables::SCANS, None, &session, rel, file, rows)?);
            }
            if let Some((rel, f)) = files.diagrams {
                let (file, rows) = f.finish()?;
                staged.push(Staged::of(tables::DIAGRAMS, None, &session, rel, file, rows)?);
            }
            for (method, (rel, f)) in files.descriptors {
                let (file, rows) = f.finish()?;
                staged.push(Staged::of(tables::DESCRIPTORS, Some(method), &session, rel, file, rows)?);
            }
        }
        // Committed files holding rows to remove or to rejoin: written again without them, or
        // with their new time and pose.
        let removals = std::mem::take(&mut self.removals);
        let mut rejoined = std::mem::take(&mut self.rejoined);
        rejoined.retain(|id, _| !removals.contains(id));
        let mut superseded: Vec<String> = std::mem::take(&mut self.dropped).into_iter().collect();
        if !removals.is_empty() || !rejoined.is_empty() {
            let mut sessions: HashSet<&str> = removals
                .iter()
                .chain(rejoined.keys())
                .filter_map(|id| self.committed.get(id))
                .map(|c| c.session.as_str())
                .collect();
            sessions.extend(self.removal_sessions.iter().map(String::as_str));
            let affected: Vec<FileEntry> = self
                .manifest
                .files
                .iter()
                .filter(|f| sessions.contains(f.session.as_str()) && !superseded.contains(&f.path))
                .cloned()
                .collect();
            for entry in affected {
                let bytes = self.verified_bytes(&entry)?;
                let path = self.path_of(&entry);
                let ids = scan_ids_in(&path, bytes.clone())?;
                if !ids.iter().any(|id| removals.contains(id) || rejoined.contains_key(id)) {
                    continue;
                }
                superseded.push(entry.path.clone());
                let table = tables::ALL.into_iter().find(|t| *t == entry.table).expect("a table name");
                let method = (table == tables::DESCRIPTORS).then(|| entry.method_name().to_string());
                let (rel, target) = self.next_part(table, method.as_deref(), &entry.session);
                if let Some((file, rows)) = rewrite_rows(&path, bytes, &target, &removals, &rejoined)? {
                    staged.push(Staged::of(table, method, &entry.session, rel, file, rows)?);
                }
            }
        }
        let staging = self.root.join(STAGING_DIR);
        if staging.is_dir() {
            std::fs::File::open(&staging).and_then(|d| d.sync_all()).at(&staging)?;
        }
        // The new manifest.
        let mut manifest = self.manifest.clone();
        manifest.files.retain(|f| !superseded.contains(&f.path));
        manifest.files.extend(staged.iter().map(|s| s.entry.clone()));
        let mut counts = manifest.counts;
        for id in &removals {
            if let Some(c) = self.committed.get(id) {
                count(&mut counts, c.status, -1);
            }
        }
        for (_, c) in &self.chunk_scans {
            count(&mut counts, c.status, 1);
        }
        if std::mem::take(&mut self.recount) {
            counts = Counts::default();
            let kept = self.committed.iter().filter(|(id, _)| !removals.contains(*id)).map(|(_, c)| c);
            for c in kept.chain(self.chunk_scans.iter().map(|(_, c)| c)) {
                count(&mut counts, c.status, 1);
            }
        }
        self.removal_sessions.clear();
        manifest.counts = counts;
        manifest.generation += 1;
        manifest.manifest_version = MANIFEST_VERSION;
        manifest.toporec_version = env!("CARGO_PKG_VERSION").into();
        if let Some(methods) = &self.pending_methods {
            manifest.methods = methods.clone();
        }
        if let Some((codebook, pipeline)) = &self.pending_codebook {
            manifest.codebook_id = Some(codebook.id());
            manifest.descriptor_length = Some(codebook.len());
            manifest.codebook = Some(codebook.to_json());
            if let Some(text) = pipeline {
                manifest.pipeline = Some(text.clone());
            }
        }
        if let Some(text) = &self.pending_pipeline {
            manifest.pipeline = Some(text.clone());
        }
        if let Some(poses) = &self.pending_poses {
            manifest.poses = poses.clone();
        }
        for (id, j) in rejoined {
            if let Some(c) = self.committed.get_mut(&id) {
                (c.utime, c.pose) = (j.utime, j.pose);
            }
        }
        Ok((manifest, superseded, removals))
    }

    /// The second half of a commit that reaches the disk: the manifest (the commit point), the
    /// staged files renamed into place, the superseded files deleted, then the convenience
    /// copies of the codebook and the pipeline.
    fn publish(
        &mut self,
        manifest: &Manifest,
        staged: &[Staged],
        superseded: &[String],
        copies: bool,
    ) -> Result<()> {
        crate::fault::commit_pause();
        if let Err(e) =
            crate::fsutil::write_atomic(&self.root.join(MANIFEST_FILE), manifest.to_text().as_bytes())
        {
            discard(&self.root, staged);
            return Err(e);
        }
        crate::fault::point("after-manifest");
        // Committed: a failure from here on leaves the rest to the next writer's recovery.
        recovery::place(&self.root, staged.iter().map(|s| s.entry.path.as_str()))?;
        for rel in superseded {
            let _ = std::fs::remove_file(self.root.join(rel));
        }
        let _ = std::fs::remove_dir(self.root.join(STAGING_DIR));
        self.copies_stale = copies;
        if copies {
            if let Some(cb) = manifest.codebook(&self.root)? {
                cb.save(&self.root.join(CODEBOOK_FILE))?;
            }
            if let Some(text) = &manifest.pipeline {
                crate::fsutil::write_atomic(&self.root.join(PIPELINE_FILE), text.as_bytes())?;
            }
            self.copies_stale = false;
        } else if manifest.pipeline != self.manifest.pipeline
            && let Some(text) = &manifest.pipeline
        {
            crate::fsutil::write_atomic(&self.root.join(PIPELINE_FILE), text.as_bytes())?;
        }
        Ok(())
    }

    /// After a commit (of the index or of a rebuild): the writer's view of what is committed.
    fn settle(&mut self, manifest: Manifest, removals: &HashSet<String>) {
        for id in removals {
            self.committed.remove(id);
        }
        self.committed.extend(std::mem::take(&mut self.chunk_scans));
        self.manifest = manifest;
        self.pending_codebook = None;
        self.pending_methods = None;
        self.pending_pipeline = None;
        self.pending_poses = None;
        self.commits += 1;
        self.chunk_rows = 0;
        self.chunk_started = Instant::now();
    }
}

/// Deletes staged files that no commit will name.
fn discard(root: &Path, staged: &[Staged]) {
    for s in staged {
        let _ = std::fs::remove_file(staged_path(root, &s.entry.path));
    }
}

/// The bytes of `entry` of the index at `root`, after checking them against the size and
/// checksum its commit recorded (see [`IndexWriter::verified_path`]).
pub(crate) fn verified(root: &Path, entry: &FileEntry, generation: u64) -> Result<bytes::Bytes> {
    match checked_bytes(root, entry, generation)? {
        Checked::Intact(bytes) => Ok(bytes),
        Checked::Damaged(d) => Err(d.error()),
    }
}

impl Drop for IndexWriter {
    /// A rebuild that never switched (it failed): its staged files are nobody's.
    fn drop(&mut self) {
        discard(&self.root, &self.held);
    }
}

fn count(c: &mut Counts, status: Status, delta: i64) {
    let add = |x: &mut u64| *x = (*x as i64 + delta).max(0) as u64;
    add(&mut c.scans);
    match status {
        Status::Ok => add(&mut c.ok),
        Status::Skipped => add(&mut c.skipped),
        Status::Error => add(&mut c.errors),
    }
}

/// What the index at `root` with `manifest` holds for each committed scan, read from its
/// parts checked against their commits (a damaged one is refused), leaving out the parts named
/// in `skip`.
pub(crate) fn committed_scans(
    root: &Path,
    manifest: &Manifest,
    skip: &HashSet<String>,
) -> Result<HashMap<String, CommittedScan>> {
    let mut out = HashMap::new();
    let wanted = |f: &&FileEntry| !skip.contains(&f.path);
    for f in manifest.files_of(tables::SCANS).filter(wanted) {
        let bytes = verified(root, f, manifest.generation)?;
        let rows = read_scans_in(&resolve(root, &f.path), bytes, &f.session)?;
        out.extend(rows.into_iter().map(CommittedScan::of_row));
    }
    for f in manifest.descriptor_files_of(TOPOREC).filter(wanted) {
        let bytes = verified(root, f, manifest.generation)?;
        for id in scan_ids_in(&resolve(root, &f.path), bytes)? {
            if let Some(c) = out.get_mut(&id) {
                c.has_descriptor = true;
            }
        }
    }
    Ok(out)
}
