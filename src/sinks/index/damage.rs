//! Committed parts checked before use.
//!
//! The manifest records every committed part's size and xxh3-64. A reader takes a part's bytes
//! whole (`checked_bytes`), compares them with that record, and decodes only those bytes,
//! never the file a second time: what it answers from is exactly what was committed. (The
//! Parquet files carry no page checksums of their own, so this is the only guard.)
//!
//! A part that fails its check is refused with [`Error::Damaged`] — the file, its table, the
//! recorded and the found checksum, and `toporec repair` — or, by a reader that skips damage
//! ([`Damage::skip`]), left out and recorded, so that the command can name it and the scans it
//! held (`super::holdings`) and end partial.

use super::manifest::{FileEntry, Manifest};
use super::{MANIFEST_FILE, resolve};
use crate::error::{Error, Result, ResultExt};
use crate::sinks::schema::tables;
use bytes::Bytes;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// Parts from this size on are mapped rather than read: a compacted session's diagrams can
/// be larger than the memory a reader should take.
const MAP_FROM: u64 = 64 << 20;

/// What the reads of one command do with a damaged part: refuse it (the default), or skip it
/// and record it. Clones share the record.
#[derive(Clone, Debug, Default)]
pub struct Damage {
    skip: bool,
    unchecked: bool,
    found: Arc<Mutex<Vec<DamagedPart>>>,
}

impl Damage {
    /// Refuse: the first damaged part ends the read with [`Error::Damaged`].
    pub fn refuse() -> Self {
        Damage::default()
    }

    /// Skip: a damaged part is left out (its rows are not read) and recorded.
    pub fn skip() -> Self {
        Damage { skip: true, ..Default::default() }
    }

    /// Reads committed parts without checking them: the baseline that `cargo bench --bench
    /// checks` measures the checks' cost against. No command reads this way.
    #[doc(hidden)]
    pub fn unchecked() -> Self {
        Damage { unchecked: true, ..Default::default() }
    }

    /// Whether parts are read without their checks ([`Damage::unchecked`]).
    pub(crate) fn checks(&self) -> bool {
        !self.unchecked
    }

    /// Skip when `skip`, else refuse.
    pub fn skipping(skip: bool) -> Self {
        if skip { Self::skip() } else { Self::refuse() }
    }

    /// Whether damaged parts are skipped.
    pub fn skips(&self) -> bool {
        self.skip
    }

    /// The damaged parts left out so far, each once, in the order met.
    pub fn found(&self) -> Vec<DamagedPart> {
        self.found.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Records a damaged part (once).
    pub(crate) fn record(&self, part: DamagedPart) {
        let mut found = self.found.lock().unwrap_or_else(|e| e.into_inner());
        if !found.iter().any(|p| p.path == part.path) {
            found.push(part);
        }
    }
}

/// A committed part whose bytes are not those its commit recorded.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, schemars::JsonSchema)]
pub struct DamagedPart {
    /// The index it belongs to.
    pub index: PathBuf,
    /// Its path, relative to the index.
    pub path: String,
    /// `scans`, `diagrams` or `descriptors`.
    pub table: String,
    /// For descriptors: the method.
    pub method: Option<String>,
    /// Its session.
    pub session: String,
    /// What its commit recorded: `xxh3 <16 hex digits>, <n> bytes`.
    pub expected: String,
    /// What is there now: the same form, or `missing`.
    pub found: String,
    /// The scans it held, as far as the intact parts of its index tell.
    pub scans: Vec<String>,
    /// Rows its commit recorded.
    pub rows: u64,
}

impl DamagedPart {
    fn of(root: &Path, entry: &FileEntry, found: String) -> Self {
        DamagedPart {
            index: root.to_owned(),
            path: entry.path.clone(),
            table: entry.table.clone(),
            method: (entry.table == tables::DESCRIPTORS).then(|| entry.method_name().to_string()),
            session: entry.session.clone(),
            expected: recorded(&entry.xxh3, entry.bytes),
            found,
            scans: Vec::new(),
            rows: entry.rows,
        }
    }

    /// `scans part`, `descriptors part of toporec-plus`, with the session.
    pub fn what(&self) -> String {
        match &self.method {
            Some(m) => format!("{} part of {m} (session {})", self.table, self.session),
            None => format!("{} part (session {})", self.table, self.session),
        }
    }

    /// The error a refusing read ends with.
    pub(crate) fn error(&self) -> Error {
        Error::Damaged {
            path: resolve(&self.index, &self.path),
            index: self.index.clone(),
            what: self.what(),
            expected: self.expected.clone(),
            found: self.found.clone(),
        }
    }

    /// One line for stderr: the part, its checksums, and the scans it held.
    pub fn describe(&self) -> String {
        let scans = if self.scans.is_empty() {
            "no scan known to the intact parts".to_string()
        } else {
            format!("{} scans: {}", self.scans.len(), self.scans.join(", "))
        };
        format!(
            "{}: damaged {}: {}, its commit recorded {}; left out, with the {scans}",
            resolve(&self.index, &self.path).display(),
            self.what(),
            self.found,
            self.expected
        )
    }
}

fn recorded(xxh3: &str, bytes: u64) -> String {
    format!("xxh3 {xxh3}, {bytes} bytes")
}

/// A file's bytes, whole: read, or mapped when large.
pub(crate) fn load(path: &Path) -> Result<Bytes> {
    let file = std::fs::File::open(path).at(path)?;
    let len = file.metadata().at(path)?.len();
    if len >= MAP_FROM {
        // SAFETY: toporec never writes a committed file in place (a commit renames new files
        // into place and deletes old ones; the map keeps the old file's pages).
        let map = unsafe { memmap2::Mmap::map(&file) }.at(path)?;
        return Ok(Bytes::from_owner(map));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    std::io::Read::read_to_end(&mut &file, &mut bytes).at(path)?;
    Ok(Bytes::from(bytes))
}

/// The xxh3-64 of bytes, as the manifest writes it (16 hex digits).
pub(crate) fn xxh3_hex(bytes: &[u8]) -> String {
    format!("{:016x}", twox_hash::XxHash3_64::oneshot(bytes))
}

/// What checking a committed part found.
pub(crate) enum Checked {
    /// Its bytes, as committed.
    Intact(Bytes),
    /// Not as committed.
    Damaged(DamagedPart),
}

/// The bytes of the committed part `entry` of the index at `root`, checked against the size
/// and checksum its commit recorded. A missing file is an I/O error (not found) when a newer
/// commit than `generation` replaced it (the caller reads the newer generation), damage
/// otherwise.
pub(crate) fn checked_bytes(root: &Path, entry: &FileEntry, generation: u64) -> Result<Checked> {
    let path = resolve(root, &entry.path);
    // A commit renames its staged files into place right after its manifest: a file found
    // staged may be in place by the time it is read, so a miss is looked up once more.
    let bytes = match load(&path)
        .or_else(|e| if e.is_not_found() { load(&resolve(root, &entry.path)) } else { Err(e) })
    {
        Ok(b) => b,
        Err(e) if e.is_not_found() => {
            let now = Manifest::load(&root.join(MANIFEST_FILE)).ok().flatten().map(|m| m.generation);
            if now.is_some_and(|g| g != generation) {
                return Err(e);
            }
            return Ok(Checked::Damaged(DamagedPart::of(root, entry, "missing".into())));
        }
        Err(e) => return Err(e),
    };
    let found = xxh3_hex(&bytes);
    if bytes.len() as u64 == entry.bytes && found == entry.xxh3 {
        Ok(Checked::Intact(bytes))
    } else {
        Ok(Checked::Damaged(DamagedPart::of(root, entry, recorded(&found, bytes.len() as u64))))
    }
}

/// Every committed part of `manifest` checked: the damaged ones.
pub(crate) fn damaged_parts(root: &Path, manifest: &Manifest) -> Result<Vec<DamagedPart>> {
    let mut out = Vec::new();
    for f in &manifest.files {
        if let Checked::Damaged(d) = checked_bytes(root, f, manifest.generation)? {
            out.push(d);
        }
    }
    Ok(out)
}
