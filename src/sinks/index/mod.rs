//! The index folder: Hive-partitioned Parquet tables plus the codebook, the effective
//! pipeline and the manifest.
//!
//! ```text
//! INDEX/
//!   scans/session=<s>/part-0.parquet      diagrams/session=<s>/part-0.parquet
//!   descriptors/method=<m>/session=<s>/part-0.parquet
//!   codebook.json   pipeline.toml   manifest.json
//! ```
//!
//! [`writer`] stages a run's files and commits them; [`reader`] reads them back, checking
//! every table against the schemas of [`super::schema`] so that a foreign or rewritten table
//! gives an error, never a panic. This module owns the layout both agree on.

pub mod manifest;
pub mod reader;
pub mod writer;

pub use reader::{IndexReader, IndexedScan, ScanRecord};
pub use writer::IndexWriter;

use crate::error::{Error, Result, ResultExt};
use std::path::{Path, PathBuf};

/// The codebook file of an index.
pub const CODEBOOK_FILE: &str = "codebook.json";
/// The effective pipeline of an index.
pub const PIPELINE_FILE: &str = "pipeline.toml";
/// The manifest: the committed files and counts.
pub const MANIFEST_FILE: &str = "manifest.json";

/// The partition folder name of a session: `session=<name>` with characters other than
/// letters, digits, `-`, `_`, `.` percent-encoded (as Hive does).
pub fn partition(session: &str) -> String {
    let mut s = String::from("session=");
    for b in session.bytes() {
        if b.is_ascii_alphanumeric() || b"-_.".contains(&b) {
            s.push(b as char);
        } else {
            s.push_str(&format!("%{b:02X}"));
        }
    }
    s
}

/// The folder of a table's part files, relative to the index: `<table>/session=<s>`, and
/// `descriptors/method=<m>/session=<s>` for descriptors (each method's apart: their lengths
/// differ).
pub fn partition_dir(table: &str, method: Option<&str>, session: &str) -> PathBuf {
    let mut dir = PathBuf::from(table);
    if table == crate::sinks::schema::tables::DESCRIPTORS {
        dir.push(format!("method={}", method.unwrap_or(crate::baselines::TOPOREC)));
    }
    dir.push(partition(session));
    dir
}

/// Every file under the table folders of an index (any depth), with its path relative to
/// the index (`/` separators), sorted.
pub fn files_on_disk(root: &Path) -> Vec<(PathBuf, String)> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<(PathBuf, String)>) {
        let Ok(entries) = std::fs::read_dir(dir) else { return };
        for e in entries.flatten() {
            let path = e.path();
            if e.file_type().is_ok_and(|t| t.is_dir()) {
                walk(root, &path, out);
            } else if let Ok(rel) = path.strip_prefix(root) {
                let rel = rel.to_string_lossy().replace('\\', "/");
                out.push((path, rel));
            }
        }
    }
    let mut out = Vec::new();
    for table in crate::sinks::schema::tables::ALL {
        walk(root, &root.join(table), &mut out);
    }
    out.sort();
    out
}

/// Decodes a `session=<name>` partition folder name.
pub fn session_of(partition: &str) -> Option<String> {
    let enc = partition.strip_prefix("session=")?;
    let bytes = enc.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' && i + 2 < bytes.len() {
            let hex = std::str::from_utf8(&bytes[i + 1..i + 3]).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// The part number of a `part-<n>.parquet` file.
fn part_number(path: &Path) -> Option<u64> {
    path.file_stem()?.to_str()?.strip_prefix("part-")?.parse().ok()
}

/// The part files of `table` in an index without a manifest, with their sessions, sorted by
/// (session, part). For `descriptors`, those of `method` (`descriptors/method=<m>/`; for the
/// TopoRec method also the older `descriptors/session=<s>/`).
pub fn table_files(root: &Path, table: &str, method: Option<&str>) -> Result<Vec<(String, PathBuf)>> {
    let dir = root.join(table);
    if !dir.is_dir() {
        return Err(Error::index(root, format!("not an index (no {table}/ folder)")));
    }
    let mut partitions = vec![dir.clone()];
    if table == crate::sinks::schema::tables::DESCRIPTORS {
        let method = method.unwrap_or(crate::baselines::TOPOREC);
        partitions = vec![dir.join(format!("method={method}"))];
        if method == crate::baselines::TOPOREC {
            partitions.push(dir);
        }
    }
    let mut out = Vec::new();
    for parent in partitions {
        let Ok(entries) = std::fs::read_dir(&parent) else { continue };
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some(session) = session_of(&name) else { continue };
            for f in std::fs::read_dir(e.path()).at(&e.path())?.flatten() {
                let p = f.path();
                let hidden = f.file_name().to_string_lossy().starts_with('.');
                if !hidden && p.extension().is_some_and(|x| x == "parquet") {
                    out.push((session.clone(), p));
                }
            }
        }
    }
    out.sort_by(|a, b| a.0.cmp(&b.0).then(part_number(&a.1).cmp(&part_number(&b.1))).then(a.1.cmp(&b.1)));
    Ok(out)
}
