//! Search structures cached in the index: `INDEX/searchers/<method>.searcher`, built by the
//! first reader that searches a method after a commit and memory-mapped by every later one, so
//! a query does not rebuild (or even read) the method's descriptors.
//!
//! A cache names the manifest generation and the method id it was built from; a cache of
//! another generation or id is stale, never used, and replaced by the next reader that builds
//! one. It is written atomically (a reader racing another writes the same bytes), in a folder
//! toporec owns: writers leave it alone and `verify` reports each cache and whether it is
//! current. An index folder that cannot be written gets no cache; its readers build the
//! structure in memory each time.
//!
//! ```text
//! "toporec-search\0\0"  u64 LE header length   header (JSON)   rows   pad   body (page aligned)
//! ```
//!
//! The header holds the format version, generation, method, id, parameters, the row count, the
//! sessions and the offsets; the rows are each entry's scan id, session, time and position
//! (what a query prints); the body is the method's structure, as its searcher lays it out.

use super::reader::IndexedScan;
use crate::error::{Error, Result, ResultExt};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

/// A cache file's extension.
pub(crate) const EXTENSION: &str = "searcher";
const MAGIC: &[u8; 16] = b"toporec-search\0\0";
/// The layout of this file (not of the body: [`Header::layout`] says that).
pub const FORMAT_VERSION: u64 = 1;
/// The body starts on a page boundary, so its sections are aligned when mapped.
const PAGE: usize = 4096;

/// The cache file of `method` in `index`.
pub fn path(index: &Path, method: &str) -> PathBuf {
    index.join(super::SEARCHERS_DIR).join(format!("{method}.{EXTENSION}"))
}

/// What a cache was built from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// The layout of this file.
    pub format_version: u64,
    /// The manifest generation of the descriptors.
    pub generation: u64,
    /// The method.
    pub method: String,
    /// The method's id (its descriptors' `codebook_id`).
    pub id: String,
    /// The method's parameters.
    pub params: serde_json::Value,
    /// The layout of the body, as the method's searcher names it (a cache of another layout,
    /// made by another version of toporec, is stale).
    #[serde(default)]
    pub layout: String,
    /// Entries.
    pub rows: usize,
    /// The sessions the rows name (by index).
    pub sessions: Vec<String>,
    /// Byte offset and length of the body.
    pub body: (usize, usize),
}

/// A cache opened for searching: its header, rows, and its mapped bytes.
pub struct Mapped {
    /// What it was built from.
    pub header: Header,
    /// The rows, without descriptors.
    pub rows: Vec<IndexedScan>,
    /// The file, mapped.
    pub map: memmap2::Mmap,
}

/// Writes the cache of `rows` and `body` (the searcher's bytes) for `header`, atomically.
pub fn write(path: &Path, header: &Header, rows: &[IndexedScan], body: &[u8]) -> Result<()> {
    let mut header = header.clone();
    let mut sessions: Vec<String> = rows.iter().map(|r| r.session.clone()).collect();
    sessions.sort();
    sessions.dedup();
    header.sessions = sessions;
    let meta = encode_rows(rows, &header.sessions);
    // The body's offset depends on the header's length, which names it: settle both.
    let mut offset = 0;
    let text = loop {
        header.body = (offset, body.len());
        let text = serde_json::to_vec(&header).expect("JSON of plain values");
        let end = 24 + text.len() + meta.len();
        let wanted = end.next_multiple_of(PAGE);
        if wanted == offset {
            break text;
        }
        offset = wanted;
    };
    let mut f = crate::fsutil::AtomicFile::create(path)?;
    f.write_all(MAGIC).at(path)?;
    f.write_all(&(text.len() as u64).to_le_bytes()).at(path)?;
    f.write_all(&text).at(path)?;
    f.write_all(&meta).at(path)?;
    f.write_all(&vec![0u8; offset - 24 - text.len() - meta.len()]).at(path)?;
    f.write_all(body).at(path)?;
    f.commit().map(drop)
}

/// Opens the cache at `path` when it was built from `generation` and `id` in `layout`; `None`
/// when there is none, or it is stale or unreadable (it is then rebuilt).
pub fn open(path: &Path, generation: u64, id: &str, layout: &str) -> Option<Mapped> {
    let file = std::fs::File::open(path).ok()?;
    // SAFETY: cache files are replaced by rename, never written in place, so the mapped bytes
    // do not change under the map.
    let map = unsafe { memmap2::Mmap::map(&file) }.ok()?;
    let parsed = parse(&map);
    match parsed {
        Ok((header, rows))
            if header.generation == generation && header.id == id && header.layout == layout =>
        {
            Some(Mapped { header, rows, map })
        }
        Ok(_) => None,
        Err(e) => {
            tracing::warn!("{}: {e}; rebuilding it", path.display());
            None
        }
    }
}

/// The header of the cache at `path` (for `verify`).
pub fn header(path: &Path) -> Result<Header> {
    let bytes = std::fs::read(path).at(path)?;
    parse(&bytes).map(|(h, _)| h).map_err(|e| Error::index(path, e))
}

fn parse(bytes: &[u8]) -> std::result::Result<(Header, Vec<IndexedScan>), String> {
    if bytes.len() < 24 || &bytes[..16] != MAGIC {
        return Err("not a toporec search cache".into());
    }
    let len = u64::from_le_bytes(bytes[16..24].try_into().expect("8 bytes")) as usize;
    let text = bytes.get(24..24 + len).ok_or("header cut short")?;
    let header: Header = serde_json::from_slice(text).map_err(|e| format!("header: {e}"))?;
    if header.format_version != FORMAT_VERSION {
        return Err(format!("cache format {}; this toporec reads {FORMAT_VERSION}", header.format_version));
    }
    let (offset, size) = header.body;
    if !offset.is_multiple_of(PAGE) || bytes.len() != offset + size {
        return Err("body cut short".into());
    }
    let rows = decode_rows(&bytes[24 + len..offset], &header)?;
    Ok((header, rows))
}

/// Rows as bytes: per row the session index (u32), time (i64, with a flag), position (3 ×
/// f64, NaN without), then the scan ids (u32 offsets, then their bytes).
fn encode_rows(rows: &[IndexedScan], sessions: &[String]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut ids: Vec<u8> = Vec::new();
    let mut offsets = vec![0u32];
    for r in rows {
        let s = sessions.binary_search(&r.session).expect("listed") as u32;
        out.extend(s.to_le_bytes());
        out.push(r.utime.is_some() as u8);
        out.extend(r.utime.unwrap_or(0).to_le_bytes());
        for c in r.pose.unwrap_or([f64::NAN; 3]) {
            out.extend(c.to_le_bytes());
        }
        ids.extend(r.scan_id.as_bytes());
        offsets.push(ids.len() as u32);
    }
    offsets.iter().for_each(|o| out.extend(o.to_le_bytes()));
    out.extend(ids);
    out
}

const ROW_BYTES: usize = 4 + 1 + 8 + 24;

fn decode_rows(bytes: &[u8], header: &Header) -> std::result::Result<Vec<IndexedScan>, String> {
    let n = header.rows;
    let fixed = n * ROW_BYTES;
    let offsets_end = fixed + 4 * (n + 1);
    if bytes.len() < offsets_end {
        return Err("rows cut short".into());
    }
    let offset = |i: usize| {
        let at = fixed + 4 * i;
        u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes")) as usize
    };
    let ids = &bytes[offsets_end..];
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let r = &bytes[i * ROW_BYTES..(i + 1) * ROW_BYTES];
        let session = header
            .sessions
            .get(u32::from_le_bytes(r[0..4].try_into().expect("4 bytes")) as usize)
            .ok_or("a row names no session")?
            .clone();
        let utime = (r[4] != 0).then(|| i64::from_le_bytes(r[5..13].try_into().expect("8 bytes")));
        let c = |k: usize| f64::from_le_bytes(r[13 + 8 * k..21 + 8 * k].try_into().expect("8 bytes"));
        let pose = [c(0), c(1), c(2)];
        let id = ids.get(offset(i)..offset(i + 1)).ok_or("scan ids cut short")?;
        out.push(IndexedScan {
            scan_id: String::from_utf8(id.to_vec()).map_err(|_| "a scan id is not UTF-8")?,
            session,
            utime,
            pose: pose.iter().all(|v| v.is_finite()).then_some(pose),
            descriptor: Vec::new(),
            codebook_id: header.id.clone(),
        });
    }
    Ok(out)
}
