//! Completing a commit that a kill interrupted, and telling toporec's own files from the rest.
//!
//! A commit writes its manifest first — the commit point, naming every file of the new
//! generation at its place in the table folders — then renames its staged files from
//! `.staging/` into place, then deletes the files it superseded. Killed before the manifest,
//! its staged files are named by no manifest: [`recover`] deletes them (the commit is undone).
//! Killed after it, the manifest names files still staged, and superseded files are still in
//! the table folders: [`recover`] renames the first into place and deletes the second (the
//! commit is rolled forward). Every writer recovers when it opens the index, under its lock;
//! a reader that finds a commit half done ([`pending`]) recovers too when it can take the lock
//! at once (else a writer is at work and will), and reads the staged files meanwhile.
//!
//! Only files with toporec's own names are ever deleted: part files (`part-<n>.parquet`) in
//! the table folders, staged files (`part-<n>.staged`) and the temporary names of
//! [`crate::fsutil::temp_path`]. Anything else in an index folder is foreign: left alone, and
//! listed by `toporec verify`.

use super::manifest::Manifest;
use super::{
    CODEBOOK_FILE, LOCK_FILE, MANIFEST_FILE, PIPELINE_FILE, SHARDS_DIR, STAGING_DIR, is_part_name,
    is_staged_name, staged_path,
};
use crate::error::{Error, Result, ResultExt};
use crate::fsutil::is_temp_name;
use crate::sinks::schema::tables;
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// Renames the staged files among `rels` (paths relative to the index) into place, then syncs
/// the folders they went to. Files already in place are passed over.
pub fn place<'a>(root: &Path, rels: impl IntoIterator<Item = &'a str>) -> Result<usize> {
    let mut folders: HashSet<PathBuf> = HashSet::new();
    let mut placed = 0;
    for rel in rels {
        let staged = staged_path(root, rel);
        if !staged.exists() {
            continue;
        }
        if placed == 1 {
            crate::fault::point("mid-renames");
        }
        let target = root.join(rel);
        let folder = target.parent().expect("a file inside a table folder").to_owned();
        std::fs::create_dir_all(&folder).at(&folder)?;
        std::fs::rename(&staged, &target).at(&target)?;
        folders.insert(folder);
        placed += 1;
    }
    for dir in &folders {
        std::fs::File::open(dir).and_then(|d| d.sync_all()).at(dir)?;
    }
    Ok(placed)
}

/// Whether the index holds a commit not yet complete, in a way a glob of the tables sees: a
/// file its manifest names still staged, or a part file it does not name still in a table
/// folder (superseded, or left by a writer killed before an older protocol's commit point).
pub fn pending(root: &Path, manifest: &Manifest) -> bool {
    if manifest.files.iter().any(|f| !root.join(&f.path).exists() && staged_path(root, &f.path).exists()) {
        return true;
    }
    let named: HashSet<&str> = manifest.files.iter().map(|f| f.path.as_str()).collect();
    super::files_on_disk(root).iter().any(|(path, rel)| {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        is_part_name(&name) && !named.contains(rel.as_str())
    })
}

/// Completes or undoes an interrupted commit (see the module doc), given the manifest read
/// under the writer's lock. Returns how many files it renamed into place and deleted.
pub fn recover(root: &Path, manifest: &Manifest) -> Result<(usize, usize)> {
    let placed = place(root, manifest.files.iter().map(|f| f.path.as_str()))?;
    if placed > 0 {
        tracing::info!("{}: completed the commit of generation {}", root.display(), manifest.generation);
    }
    let mut deleted = 0;
    for rel in orphans(root, manifest) {
        tracing::info!("{}: removing {rel}, which no commit names", root.display());
        if std::fs::remove_file(root.join(&rel)).is_ok() {
            deleted += 1;
        }
    }
    // Older writers' leftovers at the top: staging folders, temporary files.
    for e in std::fs::read_dir(root).at(root)?.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if name.starts_with(".staging-") && e.file_type().is_ok_and(|t| t.is_dir()) {
            let _ = std::fs::remove_dir_all(e.path());
        } else if is_temp_name(&name) {
            let _ = std::fs::remove_file(e.path());
        }
    }
    let _ = std::fs::remove_dir(root.join(STAGING_DIR));
    for table in tables::ALL {
        remove_empty_partitions(&root.join(table));
    }
    Ok((placed, deleted))
}

/// Files with toporec's own names that the manifest does not name (relative paths): part
/// files in the table folders, staged files, temporary files. A commit in progress has some;
/// after a kill, the next writer deletes them.
pub fn orphans(root: &Path, manifest: &Manifest) -> Vec<String> {
    let named: HashSet<&str> = manifest.files.iter().map(|f| f.path.as_str()).collect();
    let staged: HashSet<PathBuf> = manifest.files.iter().map(|f| staged_path(root, &f.path)).collect();
    let mut out = Vec::new();
    for (path, rel) in super::files_on_disk(root) {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if (is_part_name(&name) && !named.contains(rel.as_str())) || is_temp_name(&name) {
            out.push(rel);
        }
    }
    let staging = root.join(STAGING_DIR);
    for e in std::fs::read_dir(&staging).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if (is_staged_name(&name) && !staged.contains(&e.path())) || is_temp_name(&name) {
            out.push(format!("{STAGING_DIR}/{name}"));
        }
    }
    out.sort();
    out
}

/// Everything in the index folder that is not toporec's (relative paths, folders with a
/// trailing `/`): left alone by every writer, listed by `verify`.
pub fn foreign(root: &Path) -> Vec<String> {
    let own_top = [
        MANIFEST_FILE,
        CODEBOOK_FILE,
        PIPELINE_FILE,
        LOCK_FILE,
        STAGING_DIR,
        SHARDS_DIR,
        super::searchers::FOLDER,
    ];
    let mut out = Vec::new();
    for e in std::fs::read_dir(root).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let is_dir = e.file_type().is_ok_and(|t| t.is_dir());
        if tables::ALL.contains(&name.as_str()) && is_dir {
            foreign_in_table(root, &e.path(), &mut out);
        } else if !(own_top.contains(&name.as_str()) || is_temp_name(&name) || name.starts_with(".staging-"))
        {
            out.push(format!("{name}{}", if is_dir { "/" } else { "" }));
        }
    }
    for e in std::fs::read_dir(root.join(STAGING_DIR)).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if !(is_staged_name(&name) || is_temp_name(&name)) {
            out.push(format!("{STAGING_DIR}/{name}"));
        }
    }
    out.sort();
    out
}

/// The foreign entries under one table folder: files that are not part or temporary files,
/// folders that are not `method=` or `session=` partitions (not entered).
fn foreign_in_table(root: &Path, dir: &Path, out: &mut Vec<String>) {
    let mut entries = walkdir::WalkDir::new(dir).min_depth(1).into_iter();
    while let Some(Ok(e)) = entries.next() {
        let name = e.file_name().to_string_lossy().into_owned();
        let rel =
            e.path().strip_prefix(root).map(|r| r.to_string_lossy().replace('\\', "/")).unwrap_or_default();
        if e.file_type().is_dir() {
            if !(name.starts_with("session=") || name.starts_with("method=")) {
                out.push(format!("{rel}/"));
                entries.skip_current_dir();
            }
        } else if !(is_part_name(&name) || is_temp_name(&name)) {
            out.push(rel);
        }
    }
}

/// Refuses to write an index into a folder that holds something and is not an index: a
/// folder that exists, holds no manifest and holds anything but toporec's lock and staging
/// folder (what a first run killed before its first commit leaves) is someone else's.
pub fn check_writable_folder(root: &Path) -> Result<()> {
    if !root.exists() || root.join(MANIFEST_FILE).exists() {
        return Ok(());
    }
    if !root.is_dir() {
        return Err(Error::index(root, "not a folder"));
    }
    let mut held: Vec<String> = Vec::new();
    for e in std::fs::read_dir(root).at(root)?.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if name == LOCK_FILE || name == STAGING_DIR || is_temp_name(&name) {
            continue;
        }
        let is_dir = e.file_type().is_ok_and(|t| t.is_dir());
        held.push(format!("{name}{}", if is_dir { "/" } else { "" }));
    }
    if held.is_empty() {
        return Ok(());
    }
    held.sort();
    let more = held.len().saturating_sub(5);
    held.truncate(5);
    let list = held.join(", ") + &if more > 0 { format!(" and {more} more") } else { String::new() };
    Err(Error::index(
        root,
        format!(
            "not empty and not a toporec index (no {MANIFEST_FILE}; it holds {list}); \
             write the index into a new or empty folder"
        ),
    ))
}

/// Removes the empty partition folders (`session=…`, `method=…`) under `dir`, deepest first.
fn remove_empty_partitions(dir: &Path) {
    for e in walkdir::WalkDir::new(dir).min_depth(1).contents_first(true).into_iter().flatten() {
        let name = e.file_name().to_string_lossy();
        if e.file_type().is_dir() && (name.starts_with("session=") || name.starts_with("method=")) {
            let _ = std::fs::remove_dir(e.path());
        }
    }
}
