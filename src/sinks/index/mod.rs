//! The index folder: Hive-partitioned Parquet tables plus the codebook, the effective
//! pipeline and the manifest.
//!
//! ```text
//! INDEX/
//!   scans/session=<s>/part-<n>.parquet      diagrams/session=<s>/part-<n>.parquet
//!   descriptors/method=<m>/session=<s>/part-<n>.parquet
//!   manifest.json   codebook.json   pipeline.toml   .lock
//!   .staging/part-<n>.staged                 files of a commit not yet in place
//! ```
//!
//! [`writer`] stages a run's files and commits them; [`damage`] checks a committed part's
//! bytes against its commit before any reader or writer uses them; `recovery` completes a commit a kill
//! interrupted and tells toporec's own files from foreign ones; [`reader`] reads the committed
//! files back, checking every table against the schemas of [`super::schema`] so that a foreign
//! or rewritten table gives an error, never a panic. This module owns the layout they agree on.
//!
//! Staged files live outside the table folders, under names that do not end in `.parquet`, so
//! a glob of the tables (`scans/*/*.parquet`, `**/*.parquet`) never sees an uncommitted row.

pub mod damage;
pub mod holdings;
pub mod manifest;
pub mod reader;
pub(crate) mod recovery;
pub mod searchers;
pub mod writer;

pub use reader::{IndexReader, IndexedScan, ScanRecord};
pub use writer::IndexWriter;

use crate::error::{Error, Result, ResultExt};
use std::path::{Path, PathBuf};

/// The codebook file of an index.
pub(crate) const CODEBOOK_FILE: &str = "codebook.json";
/// The effective pipeline of an index.
pub(crate) const PIPELINE_FILE: &str = "pipeline.toml";
/// The manifest: the committed files and counts.
pub const MANIFEST_FILE: &str = "manifest.json";
/// The writer's lock file.
pub(crate) const LOCK_FILE: &str = ".lock";
/// The staging folder: the files of a commit until they are renamed into place (and those of
/// a `run --full` until it switches the index to them).
pub(crate) const STAGING_DIR: &str = ".staging";
/// The folder of a sharded run's per-shard indexes.
pub(crate) const SHARDS_DIR: &str = "shards";
/// The folder of the search caches ([`searchers`]).
pub(crate) const SEARCHERS_DIR: &str = "searchers";
/// The extension of a staged file.
const STAGED_EXTENSION: &str = "staged";

/// Where the file committed as `rel` (`<table>/…/part-<n>.parquet`) waits until it is put in
/// place: `.staging/part-<n>.staged` (part numbers are unique across an index).
pub(crate) fn staged_path(root: &Path, rel: &str) -> PathBuf {
    let name = Path::new(rel).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    root.join(STAGING_DIR).join(format!("{name}.{STAGED_EXTENSION}"))
}

/// Where the bytes of the committed file `rel` are now: in place, or still staged when a
/// commit is being completed (by its writer, or after a kill by the next process to open the
/// index). The path in place when neither exists.
pub(crate) fn resolve(root: &Path, rel: &str) -> PathBuf {
    let placed = root.join(rel);
    if placed.exists() {
        return placed;
    }
    let staged = staged_path(root, rel);
    if staged.exists() { staged } else { placed }
}

/// Whether `name` is the name of one of toporec's part files, `part-<digits>.parquet`.
pub(crate) fn is_part_name(name: &str) -> bool {
    name.strip_prefix("part-")
        .and_then(|n| n.strip_suffix(".parquet"))
        .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
}

/// Whether `name` is the name of a staged file, `part-<digits>.staged`.
pub(crate) fn is_staged_name(name: &str) -> bool {
    name.strip_prefix("part-")
        .and_then(|n| n.strip_suffix(&format!(".{STAGED_EXTENSION}")))
        .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
}

/// The bytes of a session name kept as they are in its partition folder name: letters, digits,
/// `-`, `_`, `.` (every other byte is percent-encoded, as Hive does).
const SESSION_ESCAPES: &percent_encoding::AsciiSet =
    &percent_encoding::NON_ALPHANUMERIC.remove(b'-').remove(b'_').remove(b'.');

/// The partition folder name of a session: `session=<name>` with characters other than
/// letters, digits, `-`, `_`, `.` percent-encoded (as Hive does).
pub fn partition(session: &str) -> String {
    format!("session={}", percent_encoding::utf8_percent_encode(session, SESSION_ESCAPES))
}

/// The folder of a table's part files, relative to the index: `<table>/session=<s>`, and
/// `descriptors/method=<m>/session=<s>` for descriptors (each method's apart: their lengths
/// differ).
pub(crate) fn partition_dir(table: &str, method: Option<&str>, session: &str) -> PathBuf {
    let mut dir = PathBuf::from(table);
    if table == crate::sinks::schema::tables::DESCRIPTORS {
        dir.push(format!("method={}", method.unwrap_or(crate::methods::TOPOREC)));
    }
    dir.push(partition(session));
    dir
}

/// Every file under the table folders of an index (any depth), toporec's or not, with its
/// path relative to the index (`/` separators), sorted.
pub(crate) fn files_on_disk(root: &Path) -> Vec<(PathBuf, String)> {
    let mut out = Vec::new();
    for table in crate::sinks::schema::tables::ALL {
        for e in walkdir::WalkDir::new(root.join(table)).into_iter().flatten() {
            if e.file_type().is_file()
                && let Ok(rel) = e.path().strip_prefix(root)
            {
                let rel = rel.to_string_lossy().replace('\\', "/");
                out.push((e.path().to_owned(), rel));
            }
        }
    }
    out.sort();
    out
}

/// Decodes a `session=<name>` partition folder name.
pub(crate) fn session_of(partition: &str) -> Option<String> {
    let encoded = partition.strip_prefix("session=")?;
    percent_encoding::percent_decode_str(encoded).decode_utf8().ok().map(|s| s.into_owned())
}

/// The part number of a `part-<n>.parquet` file.
fn part_number(path: &Path) -> Option<u64> {
    path.file_stem()?.to_str()?.strip_prefix("part-")?.parse().ok()
}

/// The part files of `table` in an index without a manifest, with their sessions, sorted by
/// (session, part). For `descriptors`, those of `method` (`descriptors/method=<m>/`; for the
/// TopoRec method also the older `descriptors/session=<s>/`).
pub(crate) fn table_files(root: &Path, table: &str, method: Option<&str>) -> Result<Vec<(String, PathBuf)>> {
    let dir = root.join(table);
    if !dir.is_dir() {
        return Err(Error::index(root, format!("not an index (no {table}/ folder)")));
    }
    let mut partitions = vec![dir.clone()];
    if table == crate::sinks::schema::tables::DESCRIPTORS {
        let method = method.unwrap_or(crate::methods::TOPOREC);
        partitions = vec![dir.join(format!("method={method}"))];
        if method == crate::methods::TOPOREC {
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
