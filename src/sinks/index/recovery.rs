//! The writer's lock, completing a commit that a kill interrupted, and telling toporec's own
//! files from the rest: what the writer and the readers of an index both use.
//!
//! One writer at a time holds `.lock` (an advisory file lock, [`take_lock`]); the file names
//! the holder (process, host, time) so that another writer can say who is at work.
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
use std::time::{Duration, Instant};

/// Renames the staged files among `rels` (paths relative to the index) into place, then syncs
/// the folders they went to. Files already in place are passed over.
pub(crate) fn place<'a>(root: &Path, rels: impl IntoIterator<Item = &'a str>) -> Result<usize> {
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
pub(crate) fn pending(root: &Path, manifest: &Manifest) -> bool {
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
pub(crate) fn recover(root: &Path, manifest: &Manifest) -> Result<(usize, usize)> {
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
pub(crate) fn orphans(root: &Path, manifest: &Manifest) -> Vec<String> {
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
pub(crate) fn foreign(root: &Path) -> Vec<String> {
    let own_top = [
        MANIFEST_FILE,
        CODEBOOK_FILE,
        PIPELINE_FILE,
        LOCK_FILE,
        STAGING_DIR,
        SHARDS_DIR,
        super::SEARCHERS_DIR,
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
pub(crate) fn check_writable_folder(root: &Path) -> Result<()> {
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

/// What a reader that completes a commit writes into the lock file after its holder line: a
/// writer that finds the lock held so waits for it (milliseconds) instead of failing.
const RECOVERING: &str = "completing a commit";

/// Takes the writer's lock, or explains who holds it. A reader completing a commit holds it
/// for milliseconds: it is waited for; so is a holder whose name is not yet written (between
/// taking the lock and writing it, the lock file is empty).
pub(super) fn take_lock(root: &Path, wait: bool) -> Result<std::fs::File> {
    use std::io::{Read, Seek, Write};
    let path = root.join(LOCK_FILE);
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .at(&path)?;
    let patience = Instant::now();
    loop {
        let attempt = if wait { file.lock().map_err(std::fs::TryLockError::Error) } else { file.try_lock() };
        match attempt {
            Ok(()) => break,
            Err(std::fs::TryLockError::WouldBlock) => {
                let mut holder = String::new();
                let _ = file.rewind();
                let _ = file.read_to_string(&mut holder);
                let holder = holder.trim();
                let transient = holder.is_empty() || holder.ends_with(RECOVERING);
                if transient && patience.elapsed() < Duration::from_secs(10) {
                    std::thread::sleep(Duration::from_millis(10));
                    continue;
                }
                let holder =
                    if holder.is_empty() { "another process".to_string() } else { holder.to_string() };
                return Err(Error::Locked { path: root.to_owned(), holder });
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(e).at(&path),
        }
    }
    write_holder(&mut file, "").at(&path)?;
    let _ = file.flush();
    Ok(file)
}

/// Writes `pid N (host H) since T` and `note` into the held lock file.
fn write_holder(file: &mut std::fs::File, note: &str) -> std::io::Result<()> {
    use std::io::{Seek, Write};
    let host = gethostname::gethostname().to_string_lossy().into_owned();
    let since = chrono::Utc::now().format("%Y-%m-%dT%H:%M:%SZ");
    file.set_len(0)?;
    file.rewind()?;
    writeln!(file, "pid {} (host {host}) since {since}{note}", std::process::id())?;
    file.flush()
}

/// Completes a half-done commit for a reader ([`recovery::pending`]), when the writer's lock
/// can be taken at once (else a writer is at work, and completes it itself). Returns the
/// manifest read under the lock when it did.
pub(crate) fn recover_for_reader(root: &Path) -> Option<Manifest> {
    let path = root.join(LOCK_FILE);
    let mut file = std::fs::OpenOptions::new().read(true).write(true).open(&path).ok()?;
    file.try_lock().ok()?;
    write_holder(&mut file, &format!(", {RECOVERING}")).ok()?;
    let manifest = Manifest::load(&root.join(MANIFEST_FILE)).ok()??;
    match recover(root, &manifest) {
        Ok(_) => Some(manifest),
        Err(e) => {
            tracing::warn!("{}: could not complete its last commit: {e}", root.display());
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_holder_that_has_not_written_its_name_yet_is_waited_for() {
        let dir = std::env::temp_dir().join(format!("toporec-lock-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(crate::sinks::index::LOCK_FILE);
        let held = std::fs::File::create(&path).unwrap();
        held.try_lock().unwrap();
        // The lock is held with an empty file, as in the moment before its holder writes its
        // name, then released.
        let release = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(200));
            drop(held);
        });
        let taken = take_lock(&dir, false);
        release.join().unwrap();
        assert!(taken.is_ok(), "{:?}", taken.err());
        drop(taken);
        // A named holder is refused at once, with its name.
        let mut named = std::fs::OpenOptions::new().read(true).write(true).open(&path).unwrap();
        named.try_lock().unwrap();
        write_holder(&mut named, "").unwrap();
        let refused = take_lock(&dir, false).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(refused.contains(&format!("pid {}", std::process::id())), "{refused}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
