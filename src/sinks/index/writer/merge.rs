//! Taking in what other writers committed: a shard's index (a sharded run) or a folder of
//! tables another tool wrote (the Spark job), each file checked, linked in under this index's
//! part numbers at the next commit.

use super::{CommittedScan, IndexWriter, Staged, committed_scans, verified};
use crate::error::{Error, Result};
use crate::fsutil::StagedFile;
use crate::methods::TOPOREC;
use crate::sinks::index::manifest::{FileEntry, Manifest};
use crate::sinks::index::reader::{read_scans, scan_ids};
use crate::sinks::index::{MANIFEST_FILE, resolve};
use crate::sinks::schema::tables;
use std::collections::{HashMap, HashSet};
use std::path::Path;

impl IndexWriter {
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
                let scans = committed_scans(other, &theirs, &HashSet::new())?;
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
            let source = resolve(other, &f.path);
            if !f.xxh3.is_empty() {
                verified(other, f, 0)?;
            }
            let (rel, staged) = self.next_part(table, method.as_deref(), &f.session);
            let file = StagedFile::link(&source, &staged)?;
            self.compacted.push(Staged::of(table, method, &f.session, rel, file, f.rows)?);
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
            let listed = if other.join(table).is_dir() {
                crate::sinks::index::table_files(other, table, None)?
            } else {
                Vec::new()
            };
            for (session, path) in listed {
                let info = crate::sinks::index::reader::check_file(&path, table, None)?;
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
            for (session, path) in crate::sinks::index::table_files(other, tables::DESCRIPTORS, Some(method))?
            {
                let info = crate::sinks::index::reader::check_file(&path, tables::DESCRIPTORS, length)?;
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
}
