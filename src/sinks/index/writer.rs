//! Writing an index: a run's files are staged in `INDEX/.staging-<pid>/` and moved into place
//! at the commit, partition by partition, with the codebook, the effective pipeline and the
//! manifest written last. Readers never see a half-written file, and a crashed run leaves the
//! previous index intact (the next run removes its staging folder). A run that fits a new
//! codebook replaces the whole index; a run with the index's own codebook replaces only the
//! sessions it wrote.

use super::{CODEBOOK_FILE, MANIFEST_FILE, PIPELINE_FILE, partition};
use crate::error::{Result, ResultExt};
use crate::homology::Diagram;
use crate::sinks::parquet::{DescriptorsFile, DiagramsFile, ScanRow, ScansFile};
use crate::sinks::schema::{self, tables};
use crate::vectorize::codebook::Codebook;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// A finished file in staging.
#[derive(Clone, Debug)]
pub struct WrittenFile {
    /// `scans`, `diagrams` or `descriptors`.
    pub table: &'static str,
    /// Session.
    pub session: String,
    /// Path (in staging until committed).
    pub path: PathBuf,
    /// Rows.
    pub rows: u64,
}

/// Scan counts recorded in the manifest.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ScanCounts {
    /// Scans read.
    pub read: u64,
    /// Scans indexed (status ok).
    pub indexed: u64,
    /// Scans skipped on purpose.
    pub skipped: u64,
    /// Scans that failed.
    pub errors: u64,
}

struct SessionFiles {
    session: String,
    scans: ScansFile,
    diagrams: DiagramsFile,
}

/// Writes a new index into staging, then commits it.
pub struct IndexWriter {
    root: PathBuf,
    staging: PathBuf,
    current: Option<SessionFiles>,
    parts: HashMap<(&'static str, String), usize>,
    written: Vec<WrittenFile>,
    /// The codebook id of the index before this run, if any.
    previous_codebook: Option<String>,
}

impl IndexWriter {
    /// Prepares `root` (created if needed; stale staging folders of crashed runs removed).
    pub fn create(root: &Path) -> Result<Self> {
        std::fs::create_dir_all(root).at(root)?;
        for e in std::fs::read_dir(root).at(root)?.flatten() {
            if e.file_name().to_string_lossy().starts_with(".staging-") {
                tracing::info!("{}: removing a crashed run's staging folder", e.path().display());
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
        let previous_codebook = Codebook::load(&root.join(CODEBOOK_FILE)).ok().map(|c| c.id());
        let staging = root.join(format!(".staging-{}", std::process::id()));
        std::fs::create_dir_all(&staging).at(&staging)?;
        Ok(IndexWriter {
            root: root.to_owned(),
            staging,
            current: None,
            parts: HashMap::new(),
            written: Vec::new(),
            previous_codebook,
        })
    }

    /// The next part path of `table` for `session`, in staging.
    fn part_path(&mut self, table: &'static str, session: &str) -> PathBuf {
        let n = self.parts.entry((table, session.to_string())).or_insert(0);
        let p = self.staging.join(table).join(partition(session)).join(format!("part-{n}.parquet"));
        *n += 1;
        p
    }

    /// Writes one scan's row and, for an ok scan, its pairs in `dims`. Scans of one session
    /// come together.
    pub fn write_scan(&mut self, row: ScanRow, diagram: Option<&Diagram>, dims: &[u8]) -> Result<()> {
        if self.current.as_ref().is_none_or(|c| c.session != row.session) {
            self.close_session()?;
            let scans = ScansFile::create(&self.part_path(tables::SCANS, &row.session))?;
            let diagrams = DiagramsFile::create(&self.part_path(tables::DIAGRAMS, &row.session))?;
            self.current = Some(SessionFiles { session: row.session.clone(), scans, diagrams });
        }
        let files = self.current.as_mut().expect("opened above");
        if let Some(d) = diagram {
            files.diagrams.push(&row.scan_id, d, dims)?;
        }
        files.scans.push(row)
    }

    /// Closes the open session's scans and diagrams files.
    pub fn close_session(&mut self) -> Result<()> {
        if let Some(f) = self.current.take() {
            self.record(tables::SCANS, &f.session, f.scans.finish()?);
            self.record(tables::DIAGRAMS, &f.session, f.diagrams.finish()?);
        }
        Ok(())
    }

    /// Opens a descriptors file for `session` in staging.
    pub fn descriptors_file(&mut self, session: &str, codebook: &Codebook) -> Result<DescriptorsFile> {
        let path = self.part_path(tables::DESCRIPTORS, session);
        DescriptorsFile::create(&path, session, codebook.len(), &codebook.id())
    }

    /// Closes a descriptors file opened by [`IndexWriter::descriptors_file`].
    pub fn finish_descriptors(&mut self, file: DescriptorsFile) -> Result<()> {
        let session = file.session().to_string();
        let finished = file.finish()?;
        self.record(tables::DESCRIPTORS, &session, finished);
        Ok(())
    }

    fn record(&mut self, table: &'static str, session: &str, (path, rows): (PathBuf, u64)) {
        self.written.push(WrittenFile { table, session: session.to_string(), path, rows });
    }

    /// The staged diagrams files, with their sessions, in the order written.
    pub fn staged_diagrams(&self) -> Vec<(String, PathBuf)> {
        self.written
            .iter()
            .filter(|w| w.table == tables::DIAGRAMS)
            .map(|w| (w.session.clone(), w.path.clone()))
            .collect()
    }

    /// The manifest: versions, the codebook, the counts, and every file written.
    fn manifest(&self, codebook: &Codebook, counts: ScanCounts) -> serde_json::Value {
        let files: Vec<serde_json::Value> = self
            .written
            .iter()
            .map(|w| {
                let name = w.path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
                serde_json::json!({
                    "table": w.table,
                    "session": w.session,
                    "path": format!("{}/{}/{name}", w.table, partition(&w.session)),
                    "rows": w.rows,
                })
            })
            .collect();
        serde_json::json!({
            "toporec_version": env!("CARGO_PKG_VERSION"),
            "schema_version": schema::SCHEMA_VERSION,
            "codebook_id": codebook.id(),
            "descriptor_length": codebook.len(),
            "scans": {"read": counts.read, "indexed": counts.indexed, "skipped": counts.skipped, "errors": counts.errors},
            "files": files,
        })
    }

    /// Moves the staged partitions into the index, then writes the codebook, the effective
    /// pipeline and the manifest. A new codebook replaces the whole index; the index's own
    /// codebook replaces only the sessions written.
    pub fn commit(mut self, codebook: &Codebook, pipeline_toml: &str, counts: ScanCounts) -> Result<PathBuf> {
        self.close_session()?;
        let replace_all = self.previous_codebook.as_deref() != Some(codebook.id().as_str());
        for table in tables::ALL {
            let live = self.root.join(table);
            if replace_all && live.exists() {
                std::fs::remove_dir_all(&live).at(&live)?;
            }
            let staged = self.staging.join(table);
            if !staged.exists() {
                continue;
            }
            std::fs::create_dir_all(&live).at(&live)?;
            for part in std::fs::read_dir(&staged).at(&staged)?.flatten() {
                let target = live.join(part.file_name());
                if target.exists() {
                    std::fs::remove_dir_all(&target).at(&target)?;
                }
                std::fs::rename(part.path(), &target).at(&target)?;
            }
        }
        let manifest = self.manifest(codebook, counts);
        let json =
            |v: &serde_json::Value| serde_json::to_string_pretty(v).expect("JSON of plain values") + "\n";
        let files = [
            (CODEBOOK_FILE, json(&codebook.to_json())),
            (PIPELINE_FILE, pipeline_toml.to_string()),
            (MANIFEST_FILE, json(&manifest)),
        ];
        for (name, text) in files {
            crate::fsutil::write_atomic(&self.root.join(name), text.as_bytes())?;
        }
        std::fs::remove_dir_all(&self.staging).ok();
        Ok(self.root.clone())
    }

    /// Deletes the staging folder (a run that fails before committing).
    pub fn abandon(self) {
        std::fs::remove_dir_all(&self.staging).ok();
    }
}
