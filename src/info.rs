//! `toporec info`: what an index holds, in one screen or as JSON — its sessions with scans per
//! status, its descriptor methods (length, codebook or method id, settings), the manifest
//! generation, its size on disk and the pipeline it was made with — and the list of its
//! committed files, for readers outside toporec that want exactly one generation.

use crate::error::{Error, Result};
use crate::sinks::index::IndexReader;
use crate::sinks::index::damage::Damage;
use crate::sinks::index::manifest::{Counts, Manifest};
use crate::sinks::parquet::Status;
use crate::sinks::schema::tables;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// What an index holds (see the module doc).
#[derive(Clone, Debug, Serialize)]
pub struct IndexInfo {
    /// The index folder.
    pub index: PathBuf,
    /// The manifest generation (commits so far).
    pub generation: u64,
    /// The toporec version of the last commit.
    pub toporec_version: String,
    /// The fingerprint of the preprocess and persistence settings.
    pub settings_hash: String,
    /// Scans per status, over the whole index.
    pub counts: Counts,
    /// Scans per status, by session.
    pub sessions: BTreeMap<String, Counts>,
    /// The descriptor methods, by name.
    pub methods: BTreeMap<String, MethodInfo>,
    /// Committed part files.
    pub files: usize,
    /// Their bytes on disk.
    pub bytes: u64,
    /// The effective pipeline the index was made with (TOML), when it records one.
    pub pipeline: Option<String>,
    /// Where the scans' poses came from, as the last run joined them, with fingerprints.
    pub poses: Vec<crate::sources::poses::PoseOrigin>,
}

/// One descriptor method of an index.
#[derive(Clone, Debug, Serialize)]
pub struct MethodInfo {
    /// `toporec`, a computed method's name ([`crate::methods::REGISTRY`]), or `imported`.
    pub kind: String,
    /// Descriptor length.
    pub length: usize,
    /// The codebook id (TopoRec) or the method's id (the others).
    pub id: String,
    /// Its settings: the codebook's (TopoRec), the method's parameters (the others).
    pub settings: serde_json::Value,
    /// Descriptor rows.
    pub rows: u64,
    /// The loop threshold `loops` uses when none is given: the one calibrated for these
    /// settings, if any.
    pub loop_threshold: Option<f64>,
}

/// A method's settings as it reads them, with the keys it leaves out when written (an empty
/// `lateral`) taken from `stored`.
fn with_every_key(settings: serde_json::Value, stored: &serde_json::Value) -> serde_json::Value {
    match (settings, stored.as_object()) {
        (serde_json::Value::Object(mut s), Some(stored)) => {
            for (k, v) in stored {
                s.entry(k.clone()).or_insert_with(|| v.clone());
            }
            serde_json::Value::Object(s)
        }
        (settings, _) => settings,
    }
}

/// Reads what the index at `index` holds.
pub fn info(index: &Path) -> Result<IndexInfo> {
    info_with(index, &Damage::refuse())
}

/// [`info`], doing with damaged parts as `damage` says.
pub fn info_with(index: &Path, damage: &Damage) -> Result<IndexInfo> {
    IndexReader::read_consistent_with(index, damage, |reader| {
        let manifest = committed(reader)?;
        let mut sessions: BTreeMap<String, Counts> = BTreeMap::new();
        for scan in reader.scans()? {
            let c = sessions.entry(scan.session.clone()).or_default();
            c.scans += 1;
            match scan.status {
                Status::Ok => c.ok += 1,
                Status::Skipped => c.skipped += 1,
                Status::Error => c.errors += 1,
            }
        }
        let rows = |method: &str| manifest.descriptor_files_of(method).map(|f| f.rows).sum();
        let mut methods = BTreeMap::new();
        if let (Some(id), Some(length), Some(codebook)) =
            (&manifest.codebook_id, manifest.descriptor_length, &manifest.codebook)
        {
            // The codebook's settings, without its fitted centres.
            let mut settings = codebook.clone();
            if let Some(s) = settings.as_object_mut() {
                for key in ["parts", "format", "format_version", "toporec_version"] {
                    s.remove(key);
                }
            }
            let method = crate::methods::TOPOREC;
            let kind = method.to_string();
            methods.insert(
                method.to_string(),
                MethodInfo {
                    kind,
                    length,
                    id: id.clone(),
                    settings,
                    rows: rows(method),
                    loop_threshold: None,
                },
            );
        }
        for (name, e) in &manifest.methods {
            // Every setting as the index holds it, those it stored by leaving them out too.
            let method = e.method(name);
            let settings = match method.as_ref().and_then(|m| m.as_computed()) {
                Some(c) => with_every_key(c.settings(), &crate::methods::stored_settings(&e.kind, &e.params)),
                None => e.params.clone(),
            };
            let m = MethodInfo {
                kind: e.kind.clone(),
                length: e.length,
                id: e.id.clone(),
                settings,
                rows: rows(name),
                loop_threshold: method.as_ref().and_then(crate::loops::default_threshold),
            };
            methods.insert(name.clone(), m);
        }
        Ok(IndexInfo {
            index: index.to_owned(),
            generation: manifest.generation,
            toporec_version: manifest.toporec_version.clone(),
            settings_hash: manifest.settings_hash.clone(),
            counts: manifest.counts,
            sessions,
            methods,
            files: manifest.files.len(),
            bytes: manifest.files.iter().map(|f| f.bytes).sum(),
            pipeline: manifest.pipeline.clone(),
            poses: manifest.poses.clone(),
        })
    })
}

/// The committed files of one generation, absolute paths: every file, or those of `table`
/// (for `descriptors`, of `method` when given), sorted by (table, method, session, part).
pub fn files(index: &Path, table: Option<&str>, method: Option<&str>) -> Result<Vec<PathBuf>> {
    if let Some(t) = table
        && !tables::ALL.contains(&t)
    {
        return Err(Error::invalid(format!("`{t}` is not a table of an index ({})", tables::ALL.join(", "))));
    }
    let reader = IndexReader::open(index)?;
    let manifest = committed(&reader)?;
    let root = std::path::absolute(index).unwrap_or_else(|_| index.to_owned());
    let mut out: Vec<(String, Option<&str>, &str, PathBuf)> = manifest
        .files
        .iter()
        .filter(|f| table.is_none_or(|t| f.table == t))
        .filter(|f| method.is_none_or(|m| f.table == tables::DESCRIPTORS && f.method_name() == m))
        .map(|f| {
            let m = (f.table == tables::DESCRIPTORS).then(|| f.method_name());
            (f.table.clone(), m, f.session.as_str(), crate::sinks::index::resolve(&root, &f.path))
        })
        .collect();
    out.sort();
    Ok(out.into_iter().map(|(_, _, _, p)| p).collect())
}

fn committed(reader: &IndexReader) -> Result<&Manifest> {
    reader.manifest().ok_or_else(|| {
        Error::index(
            reader.root(),
            "no manifest.json: not an index toporec wrote (or its first run has not committed)",
        )
    })
}

/// A byte count in B, kB, MB, GB (powers of 1000).
fn human_bytes(bytes: u64) -> String {
    let units = ["B", "kB", "MB", "GB", "TB"];
    let mut v = bytes as f64;
    let mut u = 0;
    while v >= 1000.0 && u + 1 < units.len() {
        v /= 1000.0;
        u += 1;
    }
    if u == 0 { format!("{bytes} B") } else { format!("{v:.1} {}", units[u]) }
}

impl std::fmt::Display for IndexInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "index: {}", self.index.display())?;
        writeln!(
            f,
            "generation {}, {} files, {} (toporec {}, settings {})",
            self.generation,
            self.files,
            human_bytes(self.bytes),
            self.toporec_version,
            self.settings_hash
        )?;
        let c = self.counts;
        writeln!(f, "scans: {} ({} ok, {} skipped, {} errors)", c.scans, c.ok, c.skipped, c.errors)?;
        let width = self.sessions.keys().map(|s| s.chars().count()).max().unwrap_or(0).max(7);
        writeln!(f, "  {:<width$}  {:>8} {:>8} {:>8} {:>8}", "session", "scans", "ok", "skipped", "errors")?;
        for (s, c) in &self.sessions {
            writeln!(f, "  {s:<width$}  {:>8} {:>8} {:>8} {:>8}", c.scans, c.ok, c.skipped, c.errors)?;
        }
        writeln!(f, "methods:")?;
        for (name, m) in &self.methods {
            let id = if m.kind == crate::methods::TOPOREC { "codebook" } else { "id" };
            let settings = serde_json::to_string(&m.settings).unwrap_or_default();
            let threshold = m.loop_threshold.map(|t| format!(", loop threshold {t}")).unwrap_or_default();
            writeln!(
                f,
                "  {name}: length {}, {id} {}, {} rows{threshold}, {settings}",
                m.length, m.id, m.rows
            )?;
        }
        if !self.poses.is_empty() {
            writeln!(f, "poses:")?;
        }
        for o in &self.poses {
            let file = o.file_xxh3.as_ref().map(|h| format!(", file {h}")).unwrap_or_default();
            // (A log's own poses are evidently so; a pose file's usually share one frame.)
            let own = if o.file.is_some() && o.in_own_frame() { "; a frame of its own" } else { "" };
            writeln!(
                f,
                "  {}: {}: {} of {} scans with a pose (poses {}{file}){own}",
                o.sessions.join(", "),
                o.origin,
                o.with_pose,
                o.scans,
                o.poses_xxh3
            )?;
        }
        match &self.pipeline {
            Some(p) => {
                writeln!(f, "pipeline:")?;
                for line in p.lines() {
                    writeln!(f, "  {line}")?;
                }
                Ok(())
            }
            None => writeln!(f, "pipeline: not recorded (see pipeline.toml)"),
        }
    }
}
