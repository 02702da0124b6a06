//! Output files are never left half-written: everything is written to a temporary file in
//! the destination folder and renamed into place once complete.

use anyhow::Context;
use std::path::{Path, PathBuf};

/// The temporary name used while `path` is being written (same folder, so rename is atomic).
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.partial-{}", std::process::id()))
}

/// Writes `bytes` to `path` atomically.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("{}: creating folder", dir.display()))?;
    }
    let tmp = temp_path(path);
    std::fs::write(&tmp, bytes).with_context(|| format!("{}: writing", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("{}: renaming into place", path.display()))
}
