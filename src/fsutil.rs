//! No output file is ever left half-written: [`AtomicFile`] writes under a temporary name in
//! the destination folder, and only a complete file is renamed into place (after an fsync of
//! the file, and of the folder after the rename). Every writer of toporec goes through it:
//! index tables, the codebook, the manifest, query results, reports.

use crate::error::{Result, ResultExt};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// The temporary name used while `path` is being written: hidden (a leading dot, so Hive
/// readers such as Spark, pyarrow and DuckDB's `*.parquet` globs skip it), in the same folder
/// (so the rename is atomic), and marked with the writer's pid.
pub(crate) fn temp_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.partial-{}", std::process::id()))
}

/// Whether a file name is a temporary name of [`temp_path`] (an interrupted writer's leftover).
pub(crate) fn is_temp_name(name: &str) -> bool {
    name.starts_with('.') && name.contains(".partial-")
}

/// A file being written atomically: [`AtomicFile::commit`] puts it in place; dropping it
/// without a commit removes the temporary file.
pub struct AtomicFile {
    path: PathBuf,
    temp: PathBuf,
    out: Option<BufWriter<File>>,
}

impl AtomicFile {
    /// Starts writing `path` (its folder is created if needed).
    pub fn create(path: &Path) -> Result<Self> {
        create_parent(path)?;
        let temp = temp_path(path);
        let file = File::create(&temp).at(path)?;
        Ok(AtomicFile { path: path.to_owned(), temp, out: Some(BufWriter::new(file)) })
    }

    /// The final path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Flushes and syncs the file, complete but still under its temporary name; its
    /// [`StagedFile::publish`] puts it in place.
    pub fn finish(mut self) -> Result<StagedFile> {
        let out = self.out.take().expect("not yet finished");
        let synced = out.into_inner().map_err(|e| e.into_error()).and_then(|file| file.sync_all());
        if let Err(e) = synced {
            // A failed flush (a full disk, a file-size limit) leaves nothing behind.
            let _ = std::fs::remove_file(&self.temp);
            return Err(e).at(&self.path);
        }
        Ok(StagedFile {
            path: std::mem::take(&mut self.path),
            temp: std::mem::take(&mut self.temp),
            published: false,
        })
    }

    /// Flushes, syncs and renames the file into place, then syncs its folder.
    pub fn commit(self) -> Result<PathBuf> {
        self.finish()?.publish()
    }
}

/// A complete file under its temporary name, waiting to be put in place (several files can be
/// staged, then published together at a commit). Dropped unpublished, it is removed.
#[derive(Debug)]
pub struct StagedFile {
    path: PathBuf,
    temp: PathBuf,
    published: bool,
}

impl StagedFile {
    /// Stages the existing file `source` to be published as `path`: hard-linked under the
    /// temporary name (copied where links are not possible), so `source` stays as it is.
    pub fn link(source: &Path, path: &Path) -> Result<StagedFile> {
        create_parent(path)?;
        let temp = temp_path(path);
        if std::fs::hard_link(source, &temp).is_err() {
            std::fs::copy(source, &temp).at(source)?;
            std::fs::File::open(&temp).and_then(|f| f.sync_all()).at(&temp)?;
        }
        Ok(StagedFile { path: path.to_owned(), temp, published: false })
    }

    /// The final path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Where the bytes are until published.
    pub fn temp(&self) -> &Path {
        &self.temp
    }

    /// Renames the file into place (without syncing the folder: see `sync_parent`).
    pub fn publish_unsynced(mut self) -> Result<PathBuf> {
        std::fs::rename(&self.temp, &self.path).at(&self.path)?;
        self.published = true;
        Ok(std::mem::take(&mut self.path))
    }

    /// Renames the file into place and syncs its folder.
    pub fn publish(self) -> Result<PathBuf> {
        let path = self.publish_unsynced()?;
        sync_parent(&path)?;
        Ok(path)
    }
}

impl Drop for StagedFile {
    fn drop(&mut self) {
        if !self.published {
            let _ = std::fs::remove_file(&self.temp);
        }
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.out.as_mut().expect("not yet finished").write(buf)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.out.as_mut().expect("not yet finished").flush()
    }
}

impl std::io::Seek for AtomicFile {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        self.out.as_mut().expect("not yet finished").seek(pos)
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.out.take().is_some() {
            let _ = std::fs::remove_file(&self.temp);
        }
    }
}

impl std::fmt::Debug for AtomicFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AtomicFile").field("path", &self.path).finish()
    }
}

/// Writes `bytes` to `path` atomically.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut f = AtomicFile::create(path)?;
    f.write_all(bytes).at(path)?;
    f.commit().map(drop)
}

/// Creates the folder of `path` if needed.
pub(crate) fn create_parent(path: &Path) -> Result<()> {
    match path.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(dir) => std::fs::create_dir_all(dir).at(dir),
        None => Ok(()),
    }
}

/// Syncs the folder holding `path`, so a rename into it survives a power loss.
pub(crate) fn sync_parent(path: &Path) -> Result<()> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    File::open(dir).and_then(|d| d.sync_all()).at(dir)
}
