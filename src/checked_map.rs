//! Bytes of a memory-mapped file under one checksum (xxh3-64) per block, each block checked the
//! first time any of its bytes are read. A searcher mapped from the index's cache reads this
//! way, so opening a cache costs what its header and rows cost, not a read of the whole file,
//! and a query pays only for the blocks it touches (once each).
//!
//! A block that fails its checksum is recorded ([`CheckedMap::damage`]) and its bytes are handed
//! out as they are: the caller asks after a read whether anything it read was damaged, and
//! throws away what it computed if so.

use crate::fingerprint::of_bytes;
use rayon::prelude::*;
use std::ops::Range;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicU64, Ordering};

/// Blocks checked at once on every core, rather than one after another.
const PARALLEL_BLOCKS: usize = 64;

/// A part of a mapped file (`start`, `len` bytes) whose blocks are checked on first read.
pub struct CheckedMap {
    map: memmap2::Mmap,
    start: usize,
    len: usize,
    block: usize,
    /// One per block, in order; empty: nothing is checked ([`CheckedMap::unchecked`]).
    sums: Vec<u64>,
    /// One bit per block, set once it was checked (passed or not).
    checked: Vec<AtomicU64>,
    /// The first block found damaged: what failed.
    damage: OnceLock<String>,
}

impl CheckedMap {
    /// Bytes `start..start + len` of `map`, each `block` bytes under `sums` (one per block, in
    /// order); an error when the checksums do not cover the bytes.
    pub fn new(
        map: memmap2::Mmap,
        start: usize,
        len: usize,
        block: usize,
        sums: Vec<u64>,
    ) -> Result<Self, String> {
        if start.checked_add(len).is_none_or(|end| end > map.len()) {
            return Err(format!("bytes {start}..{} lie past the file's {}", start + len, map.len()));
        }
        if block == 0 || sums.len() != len.div_ceil(block) {
            return Err(format!("{} checksums of {block}-byte blocks for {len} bytes", sums.len()));
        }
        let checked = (0..sums.len().div_ceil(64)).map(|_| AtomicU64::new(0)).collect();
        Ok(CheckedMap { map, start, len, block, sums, checked, damage: OnceLock::new() })
    }

    /// Bytes `start..start + len` of `map`, read without any check.
    pub fn unchecked(map: memmap2::Mmap, start: usize, len: usize) -> Self {
        let len = len.min(map.len().saturating_sub(start));
        CheckedMap {
            map,
            start,
            len,
            block: 1,
            sums: Vec::new(),
            checked: Vec::new(),
            damage: OnceLock::new(),
        }
    }

    /// Bytes.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes `range` (of this part), every block they lie in checked first (once each). A
    /// block that fails is recorded ([`CheckedMap::damage`]); its bytes are returned as they
    /// are.
    ///
    /// # Panics
    /// When `range` lies past the part's end (a caller's bug: the searcher lays out its own
    /// sections).
    #[inline]
    pub fn get(&self, range: Range<usize>) -> &[u8] {
        assert!(range.start <= range.end && range.end <= self.len, "{range:?} past {} bytes", self.len);
        if !self.sums.is_empty() && range.start < range.end {
            self.check(range.start / self.block..(range.end - 1) / self.block + 1);
        }
        &self.map[self.start + range.start..self.start + range.end]
    }

    /// Asks the OS to start reading bytes `range` from the file, in the background (a hint:
    /// nothing is checked, nothing waits).
    pub fn will_need(&self, range: Range<usize>) {
        #[cfg(unix)]
        if range.start < range.end && range.end <= self.len {
            let _ = self.map.advise_range(memmap2::Advice::WillNeed, self.start + range.start, range.len());
        }
        #[cfg(not(unix))]
        let _ = range;
    }

    /// Every byte, every block checked.
    pub fn all(&self) -> &[u8] {
        self.get(0..self.len)
    }

    /// What failed, when a block read so far failed its checksum (the first such block).
    pub fn damage(&self) -> Option<&str> {
        self.damage.get().map(String::as_str)
    }

    fn is_checked(&self, b: usize) -> bool {
        self.checked[b / 64].load(Ordering::Relaxed) & (1 << (b % 64)) != 0
    }

    /// Checks the blocks `blocks` not checked yet; many of them at once on every core.
    fn check(&self, blocks: Range<usize>) {
        if blocks.len() == 1 {
            if !self.is_checked(blocks.start) {
                self.check_one(blocks.start);
            }
            return;
        }
        let todo: Vec<usize> = blocks.filter(|&b| !self.is_checked(b)).collect();
        if todo.len() >= PARALLEL_BLOCKS {
            todo.into_par_iter().for_each(|b| self.check_one(b));
        } else {
            todo.into_iter().for_each(|b| self.check_one(b));
        }
    }

    #[cold]
    fn check_one(&self, b: usize) {
        let from = b * self.block;
        let to = (from + self.block).min(self.len);
        // Two readers may check one block at once: both get the same answer.
        if of_bytes(&self.map[self.start + from..self.start + to]) != self.sums[b] {
            let _ = self.damage.set(format!(
                "body block {} of {} (bytes {}..{}) fails its checksum",
                b + 1,
                self.sums.len(),
                self.start + from,
                self.start + to
            ));
        }
        self.checked[b / 64].fetch_or(1 << (b % 64), Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn mapped(bytes: &[u8]) -> memmap2::Mmap {
        let mut f = tempfile::tempfile().unwrap();
        f.write_all(bytes).unwrap();
        // SAFETY: the file is this test's own, not written while mapped.
        unsafe { memmap2::Mmap::map(&f) }.unwrap()
    }

    fn sums(bytes: &[u8], block: usize) -> Vec<u64> {
        bytes.chunks(block).map(of_bytes).collect()
    }

    #[test]
    fn a_damaged_block_is_found_when_it_is_read_and_not_before() {
        let good: Vec<u8> = (0..1000u32).map(|i| (i * 7 % 251) as u8).collect();
        let mut bad = good.clone();
        bad[10 + 350] ^= 1; // block 3 (bytes 300..400 of the part)
        let part = CheckedMap::new(mapped(&bad), 10, 990, 100, sums(&good[10..], 100)).unwrap();
        assert_eq!(part.get(0..300), &bad[10..310]);
        assert_eq!(part.get(450..450), &[] as &[u8]);
        assert_eq!(part.damage(), None, "block 3 not read yet");
        assert_eq!(part.get(399..401), &bad[409..411]);
        assert_eq!(part.damage(), Some("body block 4 of 10 (bytes 310..410) fails its checksum"));
        let whole = CheckedMap::new(mapped(&good), 10, 990, 100, sums(&good[10..], 100)).unwrap();
        assert_eq!(whole.all(), &good[10..]);
        assert_eq!(whole.damage(), None);
    }

    #[test]
    fn many_blocks_are_checked_at_once_and_checksums_must_cover_the_part() {
        let good: Vec<u8> = (0..100_000u32).map(|i| (i % 253) as u8).collect();
        let mut bad = good.clone();
        bad[77_777] ^= 0x80;
        let part = CheckedMap::new(mapped(&bad), 0, good.len(), 64, sums(&good, 64)).unwrap();
        assert_eq!(part.get(1000..99_000).len(), 98_000);
        assert!(part.damage().unwrap().starts_with("body block 1216 of 1563"), "{:?}", part.damage());
        assert!(CheckedMap::new(mapped(&good), 0, good.len(), 64, sums(&good, 100)).is_err());
        assert!(CheckedMap::new(mapped(&good), 1, good.len(), 64, sums(&good, 64)).is_err());
        let plain = CheckedMap::unchecked(mapped(&bad), 0, bad.len());
        assert_eq!(plain.all(), &bad[..]);
        assert_eq!(plain.damage(), None);
    }
}
