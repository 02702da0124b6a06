//! Reading an index back: the descriptors (`query`, `eval`), the diagrams (`fit`, `vectorize`,
//! `plot`), the scans (`verify`, incremental runs).
//!
//! Every committed part is checked against its commit's checksum before any of its rows is
//! used (`super::damage`): refused when damaged, or skipped and recorded for a command run with
//! `--skip-damaged`. Every table file is then checked as a table: its `toporec.table` and
//! `toporec.schema_version` metadata (when present: a table rewritten by another tool may have
//! lost it), and each needed column's presence and type. Types are accepted by family and cast
//! to toporec's own (a string column written as `LargeUtf8` by Polars reads as `Utf8`, a
//! `List<float64>` descriptor as `FixedSizeList<float32>`); anything else is an error naming the
//! file and the column, never a panic.
//!
//! This module is the index as a whole (`IndexReader`: its committed parts, checked, by table
//! and method); `table` reads one part file as its table, every table through the one checking
//! and casting path.

mod table;

use super::damage::{Checked, Damage, checked_bytes, load};
use super::manifest::{FileEntry, Manifest};
use super::{CODEBOOK_FILE, MANIFEST_FILE, resolve, table_files};
use crate::error::{Error, Result, ResultExt};
use crate::homology::Diagram;
use crate::sinks::parquet::ScanRow;
use crate::sinks::schema::{self, columns as C, tables};
use crate::vectorize::codebook::Codebook;
use arrow::array::{Array, RecordBatch};
use arrow::datatypes::{DataType, Field};
use bytes::Bytes;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use table::{CheckedTable, as_declared};
pub use table::{DiagramStream, diagrams, read_scans, scan_ids};
pub(crate) use table::{
    check_file, declared, declared_batches, diagrams_in, read_descriptors, read_scans_in, scan_ids_in,
};

/// One row of `descriptors`, with its session.
#[derive(Clone, Debug, PartialEq)]
pub struct IndexedScan {
    /// Scan id.
    pub scan_id: String,
    /// Session.
    pub session: String,
    /// Timestamp (µs).
    pub utime: Option<i64>,
    /// Position, when known.
    pub pose: Option<[f64; 3]>,
    /// The descriptor.
    pub descriptor: Vec<f32>,
    /// Codebook id.
    pub codebook_id: String,
}

/// How many times [`IndexReader::read_consistent`] starts a read over before it gives up.
pub(crate) const READ_ATTEMPTS: u32 = 20;

/// One row of `scans`, as stored.
pub type ScanRecord = ScanRow;

/// An index folder, opened for reading. With a manifest (every index toporec writes), it
/// sees exactly the committed files, whatever a running writer is doing; without one (a
/// folder of tables assembled by other tools), every part file in the partitions.
#[derive(Clone, Debug)]
pub struct IndexReader {
    root: PathBuf,
    manifest: Option<Manifest>,
    damage: Damage,
}

/// A part file as a reader takes it: its session, where its bytes are, and its commit's
/// record (none in a folder of tables without a manifest).
#[derive(Clone, Debug)]
pub(crate) struct Part {
    pub session: String,
    pub path: PathBuf,
    pub entry: Option<FileEntry>,
}

impl IndexReader {
    /// Opens `root`; fails when it is not a folder or its manifest cannot be read. A commit a
    /// kill left half done is completed first, when the writer's lock is free (see
    /// `super::recovery`); the files it names are read where they are meanwhile.
    pub fn open(root: &Path) -> Result<Self> {
        Self::open_with(root, &Damage::refuse())
    }

    /// [`IndexReader::open`], doing with damaged parts as `damage` says (refuse them, or skip
    /// and record them).
    pub fn open_with(root: &Path, damage: &Damage) -> Result<Self> {
        if !root.is_dir() {
            return Err(Error::index(root, "no such index folder"));
        }
        let mut manifest = Manifest::load(&root.join(MANIFEST_FILE))?;
        if let Some(m) = &manifest
            && super::recovery::pending(root, m)
            && let Some(recovered) = super::recovery::recover_for_reader(root)
        {
            manifest = Some(recovered);
        }
        Ok(IndexReader { root: root.to_owned(), manifest, damage: damage.clone() })
    }

    /// Runs `read` on the index at `root`, opened afresh. When a file its manifest named is
    /// gone — a commit replaced it since — the index is opened again and `read` starts over on
    /// the newer generation, up to `READ_ATTEMPTS` times: a read never mixes two generations
    /// and never fails because a writer committed meanwhile.
    pub fn read_consistent<T>(root: &Path, read: impl FnMut(&IndexReader) -> Result<T>) -> Result<T> {
        Self::read_consistent_with(root, &Damage::refuse(), read)
    }

    /// [`IndexReader::read_consistent`], doing with damaged parts as `damage` says.
    pub fn read_consistent_with<T>(
        root: &Path,
        damage: &Damage,
        mut read: impl FnMut(&IndexReader) -> Result<T>,
    ) -> Result<T> {
        let mut attempt = 1;
        loop {
            let reader = IndexReader::open_with(root, damage)?;
            match read(&reader) {
                Err(e) if e.is_not_found() && reader.manifest.is_some() && attempt < READ_ATTEMPTS => {
                    tracing::debug!("{}: {e}; reading the newer generation", root.display());
                    std::thread::sleep(std::time::Duration::from_millis(5 * attempt as u64));
                    attempt += 1;
                }
                other => return other,
            }
        }
    }

    /// The folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The manifest, when the index has one.
    pub fn manifest(&self) -> Option<&Manifest> {
        self.manifest.as_ref()
    }

    /// The index's codebook: the committed one, or `codebook.json` in an index without a
    /// manifest.
    pub fn codebook(&self) -> Result<Codebook> {
        match &self.manifest {
            Some(m) => m.codebook(&self.root)?.ok_or_else(|| {
                Error::index(&self.root, "no codebook yet (its first run has not finished): no descriptors")
            }),
            None => Codebook::load(&self.root.join(CODEBOOK_FILE)),
        }
    }

    /// The part files of a table, with their sessions, sorted by (session, part); for
    /// `descriptors`, the TopoRec method's (see [`IndexReader::descriptor_files`]).
    pub fn files(&self, table: &str) -> Result<Vec<(String, PathBuf)>> {
        let method = (table == tables::DESCRIPTORS).then_some(crate::methods::TOPOREC);
        Ok(self.parts(table, method)?.into_iter().map(|p| (p.session, p.path)).collect())
    }

    /// The descriptors files of `method`, with their sessions, sorted by (session, part).
    pub fn descriptor_files(&self, method: &str) -> Result<Vec<(String, PathBuf)>> {
        Ok(self.parts(tables::DESCRIPTORS, Some(method))?.into_iter().map(|p| (p.session, p.path)).collect())
    }

    /// The parts of a table (for `descriptors`, of `method`), sorted by (session, path).
    pub(crate) fn parts(&self, table: &str, method: Option<&str>) -> Result<Vec<Part>> {
        let Some(m) = &self.manifest else {
            let listed = table_files(&self.root, table, method)?;
            return Ok(listed
                .into_iter()
                .map(|(session, path)| Part { session, path, entry: None })
                .collect());
        };
        let entries: Vec<&FileEntry> = match (table, method) {
            (tables::DESCRIPTORS, m_) => {
                m.descriptor_files_of(m_.unwrap_or(crate::methods::TOPOREC)).collect()
            }
            _ => m.files_of(table).collect(),
        };
        let mut parts: Vec<Part> = entries
            .into_iter()
            .map(|f| Part {
                session: f.session.clone(),
                path: resolve(&self.root, &f.path),
                entry: Some(f.clone()),
            })
            .collect();
        parts.sort_by(|a, b| (&a.session, &a.path).cmp(&(&b.session, &b.path)));
        Ok(parts)
    }

    /// The bytes of a part: a committed one's checked against its commit (refused or, when the
    /// reader skips damage, `None` and recorded, when they differ); a part of a folder without
    /// a manifest as it is.
    pub(crate) fn bytes_of(&self, part: &Part) -> Result<Option<Bytes>> {
        let Some(entry) = part.entry.as_ref().filter(|_| self.damage.checks()) else {
            return load(&part.path).map(Some);
        };
        let generation = self.manifest.as_ref().map_or(0, |m| m.generation);
        match checked_bytes(&self.root, entry, generation)? {
            Checked::Intact(bytes) => Ok(Some(bytes)),
            Checked::Damaged(d) if self.damage.skips() => {
                self.damage.record(d);
                Ok(None)
            }
            Checked::Damaged(d) => Err(d.error()),
        }
    }

    /// What this reader does with damaged parts, and those it left out.
    pub fn damage(&self) -> &Damage {
        &self.damage
    }

    /// A whole table — `scans`, `diagrams`, or `descriptors` of `method` (TopoRec by default)
    /// — as record batches in toporec's schema (columns cast to toporec's types, as every
    /// reader here does), with the Hive partition column `session` appended, in (session,
    /// part, row) order. An empty table has the schema and no batch.
    pub fn table(
        &self,
        table: &str,
        method: Option<&str>,
    ) -> Result<(Arc<arrow::datatypes::Schema>, Vec<RecordBatch>)> {
        let held = if table == tables::DESCRIPTORS { self.methods()? } else { Vec::new() };
        let method = match method {
            Some(m) => m,
            // The index's only method, or TopoRec's among several.
            None if held.len() == 1 => held[0].as_str(),
            None if table != tables::DESCRIPTORS || held.iter().any(|m| m == crate::methods::TOPOREC) => {
                crate::methods::TOPOREC
            }
            None => {
                return Err(Error::index(
                    &self.root,
                    format!("holds descriptors of several methods ({}): name one", held.join(", ")),
                ));
            }
        };
        if table == tables::DESCRIPTORS && !held.iter().any(|m| m == method) {
            let known = if held.is_empty() { "none".to_string() } else { held.join(", ") };
            return Err(Error::index(
                &self.root,
                format!("holds no descriptors of method `{method}` (its methods: {known})"),
            ));
        }
        let (parts, length) = match table {
            tables::DESCRIPTORS => {
                let length = match self.manifest.as_ref().and_then(|m| m.methods.get(method)) {
                    Some(entry) => Some(entry.length),
                    None if method == crate::methods::TOPOREC => self.codebook().ok().map(|c| c.len()),
                    None => None,
                };
                (self.parts(table, Some(method))?, length)
            }
            tables::SCANS | tables::DIAGRAMS => (self.parts(table, None)?, None),
            other => return Err(Error::index(&self.root, format!("`{other}` is not a table of an index"))),
        };
        let definition = match table {
            tables::SCANS => schema::scans(),
            tables::DIAGRAMS => schema::diagrams(),
            _ => schema::descriptors_for(method, length.unwrap_or(0)),
        };
        let names: Vec<&'static str> = definition.columns.iter().map(|c| c.name).collect();
        // Field types as the checked columns come (a descriptor's list items may be nullable).
        let schema_of = |types: Vec<DataType>| {
            let mut fields: Vec<Field> = definition
                .columns
                .iter()
                .zip(types)
                .map(|(c, t)| Field::new(c.name, t, c.nullable))
                .collect();
            fields.push(Field::new(C::SESSION, DataType::Utf8, false));
            Arc::new(arrow::datatypes::Schema::new(fields))
        };
        let mut schema = schema_of(definition.columns.iter().map(|c| c.data_type.clone()).collect());
        let mut batches = Vec::new();
        for part in parts {
            let Some(bytes) = self.bytes_of(&part)? else { continue };
            let (session, path) = (part.session, part.path);
            let mut checked = CheckedTable::open(&path, bytes, &definition, &names, length)?;
            while let Some(columns) = checked.next_batch() {
                let mut columns = columns?.into_arrays();
                for (column, def) in columns.iter_mut().zip(&definition.columns) {
                    *column = as_declared(column.clone(), &def.data_type);
                }
                if batches.is_empty() {
                    schema = schema_of(columns.iter().map(|c| c.data_type().clone()).collect());
                }
                let rows = columns.first().map_or(0, |c| c.len());
                columns.push(Arc::new(arrow::array::StringArray::from(vec![session.as_str(); rows])));
                batches.push(RecordBatch::try_new(schema.clone(), columns).at(&path)?);
            }
        }
        Ok((schema, batches))
    }

    /// The descriptor methods the index holds: `toporec` (when it has a codebook, or
    /// TopoRec descriptors files) and those of the manifest, sorted by name.
    pub fn methods(&self) -> Result<Vec<String>> {
        let mut out = Vec::new();
        let toporec = match &self.manifest {
            Some(m) => m.codebook.is_some(),
            None => !self.descriptor_files(crate::methods::TOPOREC)?.is_empty(),
        };
        if toporec {
            out.push(crate::methods::TOPOREC.to_string());
        }
        if let Some(m) = &self.manifest {
            out.extend(m.methods.keys().cloned());
        }
        out.sort();
        Ok(out)
    }

    /// Every TopoRec descriptor (only `sessions`, when not empty), in (session, part, row)
    /// order. `length`: the descriptor length expected (needed to read variable-length lists).
    pub fn descriptors(&self, sessions: &[String], length: Option<usize>) -> Result<Vec<IndexedScan>> {
        self.descriptors_of(crate::methods::TOPOREC, sessions, length)
    }

    /// Every descriptor of `method` (only `sessions`, when not empty), in (session, part, row)
    /// order.
    pub fn descriptors_of(
        &self,
        method: &str,
        sessions: &[String],
        length: Option<usize>,
    ) -> Result<Vec<IndexedScan>> {
        let mut out = Vec::new();
        for part in self.parts(tables::DESCRIPTORS, Some(method))? {
            if sessions.is_empty() || sessions.contains(&part.session) {
                let Some(bytes) = self.bytes_of(&part)? else { continue };
                out.extend(read_descriptors(&part.path, bytes, &part.session, length)?);
            }
        }
        Ok(out)
    }

    /// Every diagram of the index, streamed scan by scan, in (session, part, row) order.
    pub fn diagrams(&self) -> Result<impl Iterator<Item = Result<(String, Diagram)>> + use<>> {
        let parts = self.parts(tables::DIAGRAMS, None)?;
        let reader = self.clone();
        Ok(parts.into_iter().flat_map(move |part| -> Box<dyn Iterator<Item = Result<(String, Diagram)>>> {
            let stream = reader.bytes_of(&part).and_then(|bytes| match bytes {
                Some(bytes) => diagrams_in(&part.path, bytes, None).map(Some),
                None => Ok(None),
            });
            match stream {
                Ok(Some(it)) => Box::new(it),
                Ok(None) => Box::new(std::iter::empty()),
                Err(e) => Box::new(std::iter::once(Err(e))),
            }
        }))
    }

    /// The diagram of one scan (searching every diagrams file).
    pub fn diagram_of(&self, scan_id: &str) -> Result<Option<Diagram>> {
        for d in self.diagrams()? {
            let (id, diagram) = d?;
            if id == scan_id {
                return Ok(Some(diagram));
            }
        }
        Ok(None)
    }

    /// Every row of `scans`, in (session, part, row) order.
    pub fn scans(&self) -> Result<Vec<ScanRecord>> {
        let mut out = Vec::new();
        for part in self.parts(tables::SCANS, None)? {
            let Some(bytes) = self.bytes_of(&part)? else { continue };
            out.extend(read_scans_in(&part.path, bytes, &part.session)?);
        }
        Ok(out)
    }
}
