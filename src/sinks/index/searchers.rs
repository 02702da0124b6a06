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
//! "toporec-search\0\0"  u64 LE header length   header (JSON)   u64 LE xxh3 of the header
//!     rows   pad   body (page aligned)
//! ```
//!
//! The header holds the format version, generation, method, id, parameters, the row count, the
//! sessions, the offsets and the checksums; the rows are each entry's scan id, session, time and
//! position (what a query prints); the body is the method's structure, as its searcher lays it
//! out. Every byte is covered by a checksum (xxh3-64): the header by the one after it, the rows
//! and the padding after them by one in the header, the body by one per [`BLOCK`] bytes in the
//! header. [`open`] checks the header and the rows; each block of the body is checked the first
//! time a search reads it ([`crate::checked_map`]), so opening costs what the rows cost, not a
//! read of the whole file. A cache that fails a check is damaged, and treated as a stale one: a
//! warning naming the file and what failed, then rebuilt (by the search that found it, for a
//! block of the body). [`check`] is `verify`'s: every byte, at once.

use super::reader::IndexedScan;
use crate::checked_map::CheckedMap;
use crate::error::{Result, ResultExt};
use crate::fingerprint::{hex, of_bytes};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

/// A cache file's extension.
pub(crate) const EXTENSION: &str = "searcher";
const MAGIC: &[u8; 16] = b"toporec-search\0\0";
/// The layout of this file (not of the body: [`Header::layout`] says that).
pub const FORMAT_VERSION: u64 = 2;
/// The body starts on a page boundary, so its sections are aligned when mapped.
const PAGE: usize = 4096;
/// Bytes of the body under one checksum: a search checks whole blocks, so a block is small
/// beside what it reads of the entries it touches (a few KB each).
pub const BLOCK: usize = 64 << 10;
/// Magic, header length.
const LEAD: usize = 24;

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
    /// The checksums of the rows and of the body's blocks (set by [`write()`]).
    #[serde(default)]
    pub checksums: Checksums,
}

/// The xxh3-64 checksums of a cache's parts, 16 hex digits each.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Checksums {
    /// The rows and the padding after them (the bytes between the header's checksum and the
    /// body).
    pub rows: String,
    /// Bytes of the body under one checksum.
    pub block: usize,
    /// One per block of the body, in order.
    pub body: Vec<String>,
}

impl Header {
    /// The header of a cache of `rows` entries of `method` (its id, parameters and searcher
    /// layout), built from the manifest's `generation`.
    pub fn new(
        generation: u64,
        method: &str,
        id: &str,
        params: serde_json::Value,
        layout: &str,
        rows: usize,
    ) -> Self {
        Header {
            format_version: FORMAT_VERSION,
            generation,
            method: method.to_string(),
            id: id.to_string(),
            params,
            layout: layout.to_string(),
            rows,
            sessions: Vec::new(),
            body: (0, 0),
            checksums: Checksums::default(),
        }
    }
}

/// A cache opened for searching: its header and rows, checked, and its body, mapped, each block
/// checked when first read.
pub struct Mapped {
    /// What it was built from.
    pub header: Header,
    /// The rows, without descriptors.
    pub rows: Vec<IndexedScan>,
    /// The body.
    pub body: CheckedMap,
}

/// Writes the cache of `rows` and `body` (the searcher's bytes) for `header`, atomically.
pub fn write(path: &Path, header: &Header, rows: &[IndexedScan], body: &[u8]) -> Result<()> {
    let mut header = header.clone();
    let mut sessions: Vec<String> = rows.iter().map(|r| r.session.clone()).collect();
    sessions.sort();
    sessions.dedup();
    header.sessions = sessions;
    let meta = encode_rows(rows, &header.sessions);
    header.checksums.block = BLOCK;
    header.checksums.body = block_checksums(body, BLOCK);
    // The body's offset depends on the header's length, which names it (and the checksum of
    // the rows' padding): settle them together.
    let mut offset = 0;
    let (text, rows_part) = loop {
        header.body = (offset, body.len());
        let text = serde_json::to_vec(&header).expect("JSON of plain values");
        let end = LEAD + text.len() + 8 + meta.len();
        let wanted = end.next_multiple_of(PAGE);
        if wanted == offset {
            let mut rows_part = meta.clone();
            rows_part.resize(offset - LEAD - text.len() - 8, 0);
            let checksum = hex(of_bytes(&rows_part));
            if header.checksums.rows == checksum {
                break (text, rows_part);
            }
            // The checksum changes the header's length only if its digits did not fit: once.
            header.checksums.rows = checksum;
            continue;
        }
        offset = wanted;
    };
    let mut f = crate::fsutil::AtomicFile::create(path)?;
    f.write_all(MAGIC).at(path)?;
    f.write_all(&(text.len() as u64).to_le_bytes()).at(path)?;
    f.write_all(&text).at(path)?;
    f.write_all(&of_bytes(&text).to_le_bytes()).at(path)?;
    f.write_all(&rows_part).at(path)?;
    f.write_all(body).at(path)?;
    f.commit().map(drop)
}

/// The checksums of `body`'s blocks of `block` bytes, computed on every core.
fn block_checksums(body: &[u8], block: usize) -> Vec<String> {
    body.par_chunks(block.max(1)).map(|b| hex(of_bytes(b))).collect()
}

/// What [`open`] found at a cache's path.
pub enum Opened {
    /// A current cache: its header and rows checked, its body's blocks checked as searches
    /// read them.
    Current(Box<Mapped>),
    /// None there.
    Missing,
    /// A cache of another generation or method id: rebuilt as a matter of course.
    Stale,
    /// A cache made by another version of toporec (another file format or body layout): rebuilt,
    /// with a warning.
    OtherVersion(String),
    /// A damaged cache: what failed (rebuilt, with a warning).
    Damaged(String),
}

/// Opens the cache at `path` when it was built from `generation` and `id` in `layout`: its
/// header and rows checked, its body mapped, each block checked when a search first reads it.
pub fn open(path: &Path, generation: u64, id: &str, layout: &str) -> Opened {
    let Ok(file) = std::fs::File::open(path) else { return Opened::Missing };
    // SAFETY: cache files are replaced by rename, never written in place, so the mapped bytes
    // do not change under the map. Pages are read as searches touch them.
    let map = match unsafe { memmap2::Mmap::map(&file) } {
        Ok(map) => map,
        Err(e) => return Opened::Damaged(format!("cannot be mapped ({e})")),
    };
    match parse(&map) {
        Ok((header, _)) if header.layout != layout => Opened::OtherVersion(format!(
            "its body layout is {:?}, this toporec's is {layout:?}",
            header.layout
        )),
        Ok((header, _)) if header.generation != generation || header.id != id => Opened::Stale,
        Ok((header, rows)) => match body(map, &header) {
            Ok(body) => Opened::Current(Box::new(Mapped { header, rows, body })),
            Err(e) => Opened::Damaged(e),
        },
        Err(Fault::OtherFormat(v)) => {
            Opened::OtherVersion(format!("cache format {v}; this toporec reads {FORMAT_VERSION}"))
        }
        Err(Fault::Damaged(e)) => Opened::Damaged(e),
    }
}

/// What `verify` finds of the cache at `path`: its header, every checksum checked; or why it
/// cannot be used.
pub enum Check {
    /// Intact (current or stale: its header says which).
    Intact(Header),
    /// Made by another version of toporec (another file format).
    OtherFormat(u64),
    /// Damaged: what failed.
    Damaged(String),
}

/// Checks the cache at `path` as [`open`] and the searches after it do, every block of the body
/// at once, whatever it was built from.
pub fn check(path: &Path) -> Check {
    // SAFETY: as in `open`: cache files are replaced by rename, never written in place.
    let map = match std::fs::File::open(path).and_then(|f| unsafe { memmap2::Mmap::map(&f) }) {
        Ok(map) => map,
        Err(e) => return Check::Damaged(format!("cannot be read ({e})")),
    };
    let header = match parse(&map) {
        Ok((h, _)) => h,
        Err(Fault::OtherFormat(v)) => return Check::OtherFormat(v),
        Err(Fault::Damaged(e)) => return Check::Damaged(e),
    };
    match body(map, &header) {
        Ok(body) => {
            body.all();
            match body.damage() {
                None => Check::Intact(header),
                Some(e) => Check::Damaged(e.to_string()),
            }
        }
        Err(e) => Check::Damaged(e),
    }
}

/// The body of the cache mapped in `map`, whose `header` [`parse`] read: each block checked
/// against the header's checksum when first read.
fn body(map: memmap2::Mmap, header: &Header) -> std::result::Result<CheckedMap, String> {
    let c = &header.checksums;
    let sums = c
        .body
        .iter()
        .map(|h| u64::from_str_radix(h, 16).map_err(|_| "a body checksum is not hex".to_string()))
        .collect::<std::result::Result<Vec<u64>, String>>()?;
    CheckedMap::new(map, header.body.0, header.body.1, c.block, sums)
}

/// The header of the cache at `path`, every checksum checked; an error saying why it cannot
/// be used.
pub fn header(path: &Path) -> Result<Header> {
    match check(path) {
        Check::Intact(h) => Ok(h),
        Check::OtherFormat(v) => {
            Err(crate::Error::index(path, format!("cache format {v}; this toporec reads {FORMAT_VERSION}")))
        }
        Check::Damaged(why) => Err(crate::Error::index(path, why)),
    }
}

/// Why a cache cannot be read.
enum Fault {
    /// Another file format (another version of toporec).
    OtherFormat(u64),
    /// Damaged: what failed.
    Damaged(String),
}

fn damaged(what: impl Into<String>) -> Fault {
    Fault::Damaged(what.into())
}

/// The header and rows of a cache, checked, and the body's size and checksum count; the body's
/// blocks are checked by [`CheckedMap`] ([`body`]).
fn parse(bytes: &[u8]) -> std::result::Result<(Header, Vec<IndexedScan>), Fault> {
    if bytes.is_empty() {
        return Err(damaged("empty file"));
    }
    if bytes.len() < LEAD || &bytes[..16] != MAGIC {
        return Err(damaged("not a toporec search cache"));
    }
    let len = u64::from_le_bytes(bytes[16..LEAD].try_into().expect("8 bytes")) as usize;
    let text = bytes.get(LEAD..LEAD.saturating_add(len)).ok_or_else(|| damaged("header cut short"))?;
    let header: Header = serde_json::from_slice(text).map_err(|e| damaged(format!("header: {e}")))?;
    if header.format_version != FORMAT_VERSION {
        return Err(Fault::OtherFormat(header.format_version));
    }
    let stored = bytes.get(LEAD + len..LEAD + len + 8).ok_or_else(|| damaged("header cut short"))?;
    if u64::from_le_bytes(stored.try_into().expect("8 bytes")) != of_bytes(text) {
        return Err(damaged("header fails its checksum"));
    }
    let (offset, size) = header.body;
    if !offset.is_multiple_of(PAGE) || offset < LEAD + len + 8 {
        return Err(damaged("header names no valid body"));
    }
    match bytes.len().cmp(&offset.saturating_add(size)) {
        std::cmp::Ordering::Less => return Err(damaged("body cut short")),
        std::cmp::Ordering::Greater => return Err(damaged("longer than its header says")),
        std::cmp::Ordering::Equal => {}
    }
    let rows_part = &bytes[LEAD + len + 8..offset];
    if hex(of_bytes(rows_part)) != header.checksums.rows {
        return Err(damaged("rows fail their checksum"));
    }
    let c = &header.checksums;
    if c.block == 0 || c.body.len() != size.div_ceil(c.block) {
        return Err(damaged("header lists the wrong number of body checksums"));
    }
    let rows = decode_rows(rows_part, &header).map_err(damaged)?;
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
    let fixed = n.checked_mul(ROW_BYTES).ok_or("a row count no file holds")?;
    let offsets_end = n.checked_add(1).and_then(|m| m.checked_mul(4)).and_then(|m| m.checked_add(fixed));
    let offsets_end = offsets_end.filter(|&e| e <= bytes.len()).ok_or("rows cut short")?;
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
