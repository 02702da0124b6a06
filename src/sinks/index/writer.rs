//! Writing an index: one writer at a time, rows committed in chunks.
//!
//! [`IndexWriter::open`] takes an OS advisory lock on `INDEX/.lock` (released by the OS when
//! the process ends, however it ends: a killed writer leaves no stale lock), reads the
//! manifest, and deletes every file the manifest does not name — the leftovers of a writer
//! killed mid-chunk.
//!
//! Rows go into the open chunk's part files, written under hidden temporary names.
//! [`IndexWriter::commit`] closes them (fsync), rewrites the committed files that hold rows
//! being replaced or pruned, renames the new files into place, and then replaces the manifest
//! atomically (temporary file, fsync, rename, fsync of the folder): that rename is the commit
//! point. Files the new manifest no longer names are deleted last. Killed at any moment, the
//! index keeps every chunk committed before; the next writer resumes from there.

use super::manifest::{Counts, FileEntry, MANIFEST_VERSION, Manifest, MethodEntry, file_checksum};
use super::reader::{read_scans, scan_ids};
use super::{CODEBOOK_FILE, MANIFEST_FILE, PIPELINE_FILE, partition_dir};
use crate::baselines::TOPOREC;
use crate::error::{Error, Result, ResultExt};
use crate::fsutil::{StagedFile, is_temp_name};
use crate::homology::Diagram;
use crate::sinks::parquet::{
    DescriptorRow, DescriptorsFile, DiagramsFile, ScanRow, ScansFile, Status, TableFile,
};
use crate::sinks::schema::tables;
use crate::vectorize::codebook::Codebook;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The lock file of an index.
pub const LOCK_FILE: &str = ".lock";

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

/// The files of the open chunk, per session.
#[derive(Default)]
struct SessionFiles {
    scans: Option<ScansFile>,
    diagrams: Option<DiagramsFile>,
    /// By method.
    descriptors: BTreeMap<String, DescriptorsFile>,
}

/// A closed file waiting for its commit.
struct Staged {
    table: &'static str,
    /// The method, for descriptors.
    method: Option<String>,
    session: String,
    file: StagedFile,
    rows: u64,
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
    manifest: Manifest,
    committed: HashMap<String, CommittedScan>,
    chunk: BTreeMap<String, SessionFiles>,
    chunk_rows: u64,
    chunk_started: Instant,
    /// Scans of the open chunk (for the counts and the committed-scan map).
    chunk_scans: Vec<(String, CommittedScan)>,
    /// Committed scans to drop at the next commit (replaced or pruned).
    removals: HashSet<String>,
    /// The codebook (and pipeline text) to commit with the next chunk.
    pending_codebook: Option<(Codebook, Option<String>)>,
    /// The effective pipeline to write with the next commit.
    pending_pipeline: Option<String>,
    /// Committed files to drop at the next commit (a new descriptors table, compaction).
    dropped: HashSet<String>,
    /// Merged files to add at the next commit (compaction).
    compacted: Vec<Staged>,
    /// The methods to record with the next commit.
    pending_methods: Option<BTreeMap<String, MethodEntry>>,
    /// A pause between publishing a chunk's files and committing its manifest
    /// (`TOPOREC_COMMIT_PAUSE_MS`: fault injection for crash tests).
    pause: Option<Duration>,
    commits: u64,
}

impl IndexWriter {
    /// Opens (or creates) the index at `root` for writing. `full`: delete what it holds first.
    /// Fails at once when another writer holds the index.
    pub fn open(root: &Path, settings_hash: &str, full: bool) -> Result<Self> {
        Self::open_with(root, settings_hash, full, false)
    }

    /// [`IndexWriter::open`], waiting for another writer to finish instead of failing (the
    /// merge step of a sharded run: shards take turns at the manifest).
    pub fn open_waiting(root: &Path, settings_hash: &str) -> Result<Self> {
        Self::open_with(root, settings_hash, false, true)
    }

    fn open_with(root: &Path, settings_hash: &str, full: bool, wait: bool) -> Result<Self> {
        std::fs::create_dir_all(root).at(root)?;
        let lock = take_lock(root, wait)?;
        if full {
            for table in tables::ALL {
                let dir = root.join(table);
                if dir.exists() {
                    std::fs::remove_dir_all(&dir).at(&dir)?;
                }
            }
            for name in [MANIFEST_FILE, CODEBOOK_FILE, PIPELINE_FILE] {
                let _ = std::fs::remove_file(root.join(name));
            }
        }
        let manifest =
            Manifest::load(&root.join(MANIFEST_FILE))?.unwrap_or_else(|| Manifest::empty(settings_hash));
        remove_uncommitted(root, &manifest)?;
        let committed = committed_scans(root, &manifest)?;
        let pause = std::env::var("TOPOREC_COMMIT_PAUSE_MS")
            .ok()
            .and_then(|v| v.parse().ok())
            .map(Duration::from_millis);
        Ok(IndexWriter {
            root: root.to_owned(),
            _lock: lock,
            manifest,
            committed,
            chunk: BTreeMap::new(),
            chunk_rows: 0,
            chunk_started: Instant::now(),
            chunk_scans: Vec::new(),
            removals: HashSet::new(),
            pending_codebook: None,
            pending_pipeline: None,
            dropped: HashSet::new(),
            compacted: Vec::new(),
            pending_methods: None,
            pause,
            commits: 0,
        })
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

    fn next_part(&mut self, table: &str, method: Option<&str>, session: &str) -> PathBuf {
        let n = self.manifest.next_part;
        self.manifest.next_part += 1;
        self.root.join(partition_dir(table, method, session)).join(format!("part-{n:06}.parquet"))
    }

    fn session_files(&mut self, session: &str) -> &mut SessionFiles {
        if !self.chunk.contains_key(session) {
            self.chunk.insert(session.to_string(), SessionFiles::default());
        }
        self.chunk.get_mut(session).expect("inserted")
    }

    /// Takes in the committed content of another index with the same settings and codebook
    /// (a shard of a sharded run): its files are linked in under this index's part numbers
    /// and its scans replace any this index holds, at the next [`IndexWriter::commit`]. The
    /// other index is left as it is. Returns the number of scans taken in.
    pub fn absorb(&mut self, other: &Path) -> Result<u64> {
        let (files, scans) = match Manifest::load(&other.join(MANIFEST_FILE))? {
            Some(theirs) => {
                if theirs.settings_hash != self.manifest.settings_hash {
                    return Err(Error::index(
                        other,
                        format!(
                            "made with settings {}, the index {} with {}",
                            theirs.settings_hash,
                            self.root.display(),
                            self.manifest.settings_hash
                        ),
                    ));
                }
                if theirs.codebook_id.is_some() && theirs.codebook_id != self.manifest.codebook_id {
                    return Err(Error::index(
                        other,
                        "made with another codebook than the index it merges into",
                    ));
                }
                let scans = committed_scans(other, &theirs)?;
                (theirs.files, scans)
            }
            None => self.written_elsewhere(other)?,
        };
        for f in &files {
            let table = tables::ALL
                .into_iter()
                .find(|t| *t == f.table)
                .ok_or_else(|| Error::index(other, format!("unknown table `{}` in its manifest", f.table)))?;
            let method = (table == tables::DESCRIPTORS).then(|| f.method_name().to_string());
            let target = self.next_part(table, method.as_deref(), &f.session);
            let file = StagedFile::link(&other.join(&f.path), &target)?;
            self.compacted.push(Staged { table, method, session: f.session.clone(), file, rows: f.rows });
        }
        let taken = scans.len() as u64;
        for (id, scan) in scans {
            if self.committed.contains_key(&id) {
                self.removals.insert(id.clone());
            }
            self.chunk_scans.push((id, scan));
        }
        Ok(taken)
    }

    /// The table files another tool wrote in this index's layout (a folder with `scans/`,
    /// `diagrams/`, `descriptors/method=<m>/`, each partitioned by `session=<s>/`, and no
    /// manifest: a Spark job's output), every one checked against toporec's schema (types by
    /// family), its scans made with this index's settings and its TopoRec descriptors with
    /// its codebook.
    fn written_elsewhere(&self, other: &Path) -> Result<(Vec<FileEntry>, HashMap<String, CommittedScan>)> {
        let mut files = Vec::new();
        let mut scans = HashMap::new();
        let entry = |table: &str, method: Option<&str>, session: String, path: &Path, rows: u64| FileEntry {
            table: table.to_string(),
            method: method.map(str::to_string),
            session,
            path: path.strip_prefix(other).unwrap_or(path).to_string_lossy().replace('\\', "/"),
            rows,
            bytes: 0,
            xxh3: String::new(),
        };
        let mut methods: Vec<String> = Vec::new();
        if let Ok(entries) = std::fs::read_dir(other.join(tables::DESCRIPTORS)) {
            for e in entries.flatten() {
                if let Some(m) = e.file_name().to_string_lossy().strip_prefix("method=") {
                    methods.push(m.to_string());
                }
            }
        }
        methods.sort();
        for table in [tables::SCANS, tables::DIAGRAMS] {
            let listed =
                if other.join(table).is_dir() { super::table_files(other, table, None)? } else { Vec::new() };
            for (session, path) in listed {
                let info = super::reader::check_file(&path, table, None)?;
                if table == tables::SCANS {
                    for r in read_scans(&path, &session)? {
                        if r.settings_hash != self.manifest.settings_hash {
                            return Err(Error::table(
                                &path,
                                format!(
                                    "scan {} was made with settings {}, the index {} has {}",
                                    r.scan_id,
                                    r.settings_hash,
                                    self.root.display(),
                                    self.manifest.settings_hash
                                ),
                            ));
                        }
                        let (id, record) = CommittedScan::of_row(r);
                        scans.insert(id, record);
                    }
                }
                files.push(entry(table, None, session, &path, info.rows));
            }
        }
        for method in &methods {
            let length = match self.manifest.methods.get(method) {
                Some(m) => Some(m.length),
                None if method == TOPOREC => self.manifest.descriptor_length,
                None => None,
            };
            let expected = match self.manifest.methods.get(method) {
                Some(m) => Some(m.id.clone()),
                None if method == TOPOREC => self.manifest.codebook_id.clone(),
                None => None,
            };
            let Some(expected) = expected else {
                return Err(Error::index(
                    other,
                    format!(
                        "descriptors of `{method}`, a method the index {} does not have",
                        self.root.display()
                    ),
                ));
            };
            for (session, path) in super::table_files(other, tables::DESCRIPTORS, Some(method))? {
                let info = super::reader::check_file(&path, tables::DESCRIPTORS, length)?;
                if info.codebook_id.as_ref().is_some_and(|id| *id != expected) {
                    return Err(Error::table(
                        &path,
                        format!(
                            "made by {}, the index's `{method}` by {expected}",
                            info.codebook_id.unwrap_or_default()
                        ),
                    ));
                }
                if method == TOPOREC {
                    for id in scan_ids(&path)? {
                        if let Some(c) = scans.get_mut(&id) {
                            c.has_descriptor = true;
                        }
                    }
                }
                files.push(entry(tables::DESCRIPTORS, Some(method), session, &path, info.rows));
            }
        }
        Ok((files, scans))
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
            if self.session_files(&session).diagrams.is_none() {
                let f = DiagramsFile::create(&self.next_part(tables::DIAGRAMS, None, &session))?;
                self.session_files(&session).diagrams = Some(f);
            }
            self.session_files(&session).diagrams.as_mut().expect("opened").push(&row.scan_id, d, dims)?;
        }
        let has_descriptor = descriptors.iter().any(|d| d.method == TOPOREC);
        for d in descriptors {
            self.push_descriptor(&session, &d.method, d.row, || d.id.clone())?;
        }
        if self.session_files(&session).scans.is_none() {
            let f = ScansFile::create(&self.next_part(tables::SCANS, None, &session))?;
            self.session_files(&session).scans = Some(f);
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
        self.session_files(&session).scans.as_mut().expect("opened").push(row)
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
            let path = self.next_part(tables::DESCRIPTORS, Some(method), session);
            let f = DescriptorsFile::create(&path, session, method, row.values.len(), &id())?;
            self.session_files(session).descriptors.insert(method.to_string(), f);
        }
        self.session_files(session).descriptors.get_mut(method).expect("opened").push(row)
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

    /// Merges each partition's part files of each table into one file, in one commit.
    /// Returns how many files were merged into how many.
    pub fn compact(&mut self) -> Result<(usize, usize)> {
        let mut groups: BTreeMap<(String, Option<String>, String), Vec<FileEntry>> = BTreeMap::new();
        for f in &self.manifest.files {
            let method = (f.table == tables::DESCRIPTORS).then(|| f.method_name().to_string());
            groups.entry((f.table.clone(), method, f.session.clone())).or_default().push(f.clone());
        }
        let (mut merged, mut into) = (0, 0);
        for ((table, method, session), files) in groups.into_iter().filter(|(_, files)| files.len() > 1) {
            let table = tables::ALL.into_iter().find(|t| *t == table).expect("a table name");
            let target = self.next_part(table, method.as_deref(), &session);
            let first = self.root.join(&files[0].path);
            let schema = {
                let file = std::fs::File::open(&first).at(&first)?;
                parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file)
                    .at(&first)?
                    .schema()
                    .clone()
            };
            let mut out = TableFile::with_schema(&target, schema)?;
            for f in &files {
                let path = self.root.join(&f.path);
                let file = std::fs::File::open(&path).at(&path)?;
                let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file)
                    .at(&path)?
                    .build()
                    .at(&path)?;
                for batch in reader {
                    out.write_batch(&batch.at(&path)?)?;
                }
                self.dropped.insert(f.path.clone());
            }
            let (file, rows) = out.finish()?;
            self.compacted.push(Staged { table, method, session, file, rows });
            merged += files.len();
            into += 1;
        }
        self.commit()?;
        Ok((merged, into))
    }

    /// Writes the effective pipeline (`pipeline.toml`) with the next commit.
    pub fn set_pipeline(&mut self, text: String) {
        self.pending_pipeline = Some(text);
    }

    /// Commits the open chunk (see the module doc). A no-op when there is nothing to commit.
    pub fn commit(&mut self) -> Result<()> {
        if self.chunk.is_empty()
            && self.compacted.is_empty()
            && self.removals.is_empty()
            && self.pending_codebook.is_none()
            && self.pending_methods.is_none()
            && self.dropped.is_empty()
        {
            return Ok(());
        }
        // 1. The chunk's files, complete under their temporary names.
        let mut staged: Vec<Staged> = std::mem::take(&mut self.compacted);
        for (session, files) in std::mem::take(&mut self.chunk) {
            if let Some(f) = files.scans {
                let (file, rows) = f.finish()?;
                staged.push(Staged {
                    table: tables::SCANS,
                    method: None,
                    session: session.clone(),
                    file,
                    rows,
                });
            }
            if let Some(f) = files.diagrams {
                let (file, rows) = f.finish()?;
                staged.push(Staged {
                    table: tables::DIAGRAMS,
                    method: None,
                    session: session.clone(),
                    file,
                    rows,
                });
            }
            for (method, f) in files.descriptors {
                let (file, rows) = f.finish()?;
                let (table, method, session) = (tables::DESCRIPTORS, Some(method), session.clone());
                staged.push(Staged { table, method, session, file, rows });
            }
        }
        // 2. Committed files holding rows to remove: rewritten without them.
        let removals = std::mem::take(&mut self.removals);
        let mut superseded: Vec<String> = std::mem::take(&mut self.dropped).into_iter().collect();
        if !removals.is_empty() {
            let sessions: HashSet<&str> =
                removals.iter().filter_map(|id| self.committed.get(id)).map(|c| c.session.as_str()).collect();
            let affected: Vec<FileEntry> = self
                .manifest
                .files
                .iter()
                .filter(|f| sessions.contains(f.session.as_str()) && !superseded.contains(&f.path))
                .cloned()
                .collect();
            for entry in affected {
                let path = self.root.join(&entry.path);
                let ids = scan_ids(&path)?;
                if !ids.iter().any(|id| removals.contains(id)) {
                    continue;
                }
                superseded.push(entry.path.clone());
                let table = tables::ALL.into_iter().find(|t| *t == entry.table).expect("a table name");
                let method = (table == tables::DESCRIPTORS).then(|| entry.method_name().to_string());
                let target = self.next_part(table, method.as_deref(), &entry.session);
                if let Some((file, rows)) = rewrite_without(&path, &target, &removals)? {
                    staged.push(Staged { table, method, session: entry.session.clone(), file, rows });
                }
            }
        }
        // 3. The new manifest.
        let mut manifest = self.manifest.clone();
        manifest.files.retain(|f| !superseded.contains(&f.path));
        for s in &staged {
            let (bytes, xxh3) = file_checksum(s.file.temp())?;
            let path = s.file.path().strip_prefix(&self.root).expect("inside the index");
            manifest.files.push(FileEntry {
                table: s.table.to_string(),
                method: s.method.clone(),
                session: s.session.clone(),
                path: path.to_string_lossy().replace('\\', "/"),
                rows: s.rows,
                bytes,
                xxh3,
            });
        }
        let mut counts = manifest.counts;
        for id in &removals {
            if let Some(c) = self.committed.get(id) {
                count(&mut counts, c.status, -1);
            }
        }
        for (_, c) in &self.chunk_scans {
            count(&mut counts, c.status, 1);
        }
        manifest.counts = counts;
        manifest.generation += 1;
        manifest.manifest_version = MANIFEST_VERSION;
        manifest.toporec_version = env!("CARGO_PKG_VERSION").into();
        if let Some(methods) = &self.pending_methods {
            manifest.methods = methods.clone();
        }
        if let Some((codebook, _)) = &self.pending_codebook {
            manifest.codebook_id = Some(codebook.id());
            manifest.descriptor_length = Some(codebook.len());
            manifest.codebook = Some(codebook.to_json());
        }
        // 4. Files in place; the codebook's and the pipeline's convenience copies.
        tracing::info!(generation = manifest.generation, files = staged.len(), "publishing a chunk");
        let mut published: Vec<PathBuf> = Vec::new();
        let outcome = self.publish_and_commit(staged, &manifest, &mut published);
        if let Err(e) = outcome {
            // Not committed: nothing the manifest does not name stays behind.
            for path in published {
                let _ = std::fs::remove_file(path);
            }
            return Err(e);
        }
        // 6. What the manifest no longer names.
        for path in &superseded {
            let _ = std::fs::remove_file(self.root.join(path));
        }
        for id in &removals {
            self.committed.remove(id);
        }
        self.committed.extend(std::mem::take(&mut self.chunk_scans));
        self.manifest = manifest;
        self.pending_codebook = None;
        self.pending_methods = None;
        self.commits += 1;
        self.chunk_rows = 0;
        self.chunk_started = Instant::now();
        Ok(())
    }
}

impl IndexWriter {
    /// Steps 4 and 5 of a commit: the files in place (listed in `published` as they go), the
    /// codebook's and pipeline's copies, then the manifest.
    fn publish_and_commit(
        &mut self,
        staged: Vec<Staged>,
        manifest: &Manifest,
        published: &mut Vec<PathBuf>,
    ) -> Result<()> {
        let mut folders: HashSet<PathBuf> = HashSet::new();
        for s in staged {
            let path = s.file.publish_unsynced()?;
            folders.insert(path.parent().expect("in a partition").to_owned());
            published.push(path);
        }
        for dir in &folders {
            std::fs::File::open(dir).and_then(|d| d.sync_all()).at(dir)?;
        }
        if let Some((codebook, pipeline)) = &self.pending_codebook {
            codebook.save(&self.root.join(CODEBOOK_FILE))?;
            if let Some(text) = pipeline {
                self.pending_pipeline = Some(text.clone());
            }
        }
        if let Some(text) = self.pending_pipeline.take() {
            crate::fsutil::write_atomic(&self.root.join(PIPELINE_FILE), text.as_bytes())?;
        }
        if let Some(pause) = self.pause {
            std::thread::sleep(pause);
        }
        // 5. The commit point.
        crate::fsutil::write_atomic(&self.root.join(MANIFEST_FILE), manifest.to_text().as_bytes())
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

/// Takes the writer's lock, or explains who holds it.
fn take_lock(root: &Path, wait: bool) -> Result<std::fs::File> {
    use std::io::{Read, Seek, Write};
    let path = root.join(LOCK_FILE);
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .at(&path)?;
    let attempt = if wait { file.lock().map_err(std::fs::TryLockError::Error) } else { file.try_lock() };
    match attempt {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            let mut holder = String::new();
            let _ = file.read_to_string(&mut holder);
            let holder = holder.trim();
            let holder = if holder.is_empty() { "another process".to_string() } else { holder.to_string() };
            return Err(Error::Locked { path: root.to_owned(), holder });
        }
        Err(std::fs::TryLockError::Error(e)) => return Err(e).at(&path),
    }
    let host = gethostname::gethostname().to_string_lossy().into_owned();
    let since = chrono::Utc::now().format("%Y-%m-%dT%H:%M:%SZ");
    file.set_len(0).at(&path)?;
    file.rewind().at(&path)?;
    writeln!(file, "pid {} (host {host}) since {since}", std::process::id()).at(&path)?;
    file.flush().at(&path)?;
    Ok(file)
}

/// Deletes what the manifest does not name: parts of uncommitted chunks, temporary files,
/// staging folders of older writers, empty partitions.
fn remove_uncommitted(root: &Path, manifest: &Manifest) -> Result<()> {
    let named: HashSet<&str> = manifest.files.iter().map(|f| f.path.as_str()).collect();
    for e in std::fs::read_dir(root).at(root)?.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if name.starts_with(".staging-") {
            let _ = std::fs::remove_dir_all(e.path());
        } else if is_temp_name(&name) {
            let _ = std::fs::remove_file(e.path());
        }
    }
    for (path, rel) in super::files_on_disk(root) {
        if !named.contains(rel.as_str()) {
            tracing::info!("{}: removing a file no commit names", path.display());
            let _ = std::fs::remove_file(&path);
        }
    }
    // Partition folders left empty (a folder is removed only when empty).
    for table in tables::ALL {
        remove_empty_dirs(&root.join(table));
    }
    Ok(())
}

/// Removes the empty folders under `dir` (not `dir` itself), deepest first.
fn remove_empty_dirs(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        if e.file_type().is_ok_and(|t| t.is_dir()) {
            remove_empty_dirs(&e.path());
            let _ = std::fs::remove_dir(e.path());
        }
    }
}

/// Every committed scan, by id, from the manifest's `scans` and `descriptors` files.
/// What the index at `root` with `manifest` holds for each committed scan.
pub fn committed_scans(root: &Path, manifest: &Manifest) -> Result<HashMap<String, CommittedScan>> {
    let mut out = HashMap::new();
    for f in manifest.files_of(tables::SCANS) {
        out.extend(read_scans(&root.join(&f.path), &f.session)?.into_iter().map(CommittedScan::of_row));
    }
    for f in manifest.descriptor_files_of(TOPOREC) {
        for id in scan_ids(&root.join(&f.path))? {
            if let Some(c) = out.get_mut(&id) {
                c.has_descriptor = true;
            }
        }
    }
    Ok(out)
}

/// Writes `target` as `path` without the rows of `removed` scans; `None` when no row is left.
fn rewrite_without(
    path: &Path,
    target: &Path,
    removed: &HashSet<String>,
) -> Result<Option<(StagedFile, u64)>> {
    use arrow::array::{AsArray, BooleanArray};
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
    let file = std::fs::File::open(path).at(path)?;
    let builder = ParquetRecordBatchReaderBuilder::try_new(file).at(path)?;
    let schema = builder.schema().clone();
    let mut out = TableFile::with_schema(target, schema)?;
    for batch in builder.build().at(path)? {
        let batch = batch.at(path)?;
        let ids = batch
            .column_by_name(crate::sinks::schema::columns::SCAN_ID)
            .ok_or_else(|| Error::table(path, "no column `scan_id`"))?
            .as_string::<i32>()
            .clone();
        let keep: BooleanArray =
            ids.iter().map(|id| Some(!id.is_some_and(|id| removed.contains(id)))).collect();
        let kept = arrow::compute::filter_record_batch(&batch, &keep).at(path)?;
        if kept.num_rows() > 0 {
            out.write_batch(&kept)?;
        }
    }
    let (file, rows) = out.finish()?;
    Ok((rows > 0).then_some((file, rows)))
}
