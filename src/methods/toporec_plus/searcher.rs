//! The searcher: every entry's code columns and keys in sections (owned and growing, or mapped
//! from the index's cache), candidates from the keys in one pass (blocked, AVX2), re-ranked by
//! the distance.

use super::PlusParams;
use super::distance::{Entry, Query, columns_of, distance_to, reach};
use super::keys::*;
use super::lateral;
use super::pose::Aligner;
use crate::methods::Computed;
use crate::methods::searcher::{Allowed, Hit, SearchBudget, SearchTimes};
use std::sync::Arc;

/// A hit: database row, distance, yaw of the query relative to it (degrees).
pub(super) type PlusHit = (usize, f64, f64);

/// Entries the first step of the shape list keeps, per row of the list: their filled shares
/// per ring are nearest the query's.
pub(super) const COARSE_PER_CANDIDATE: usize = 10;

/// Rows of each key's list, per candidate wanted.
pub(super) const LIST_PER_CANDIDATE: usize = 4;

/// The constant of the reciprocal-rank fusion: a row's score is `Σ 1 / (FUSION_K + rank)`.
pub(super) const FUSION_K: f64 = 10.0;

/// Descriptors searched in two steps: candidates by the keys, then those re-ranked by
/// [`super::distance()`]. Three keys rank the entries (the shape key among the entries whose filled
/// shares per ring, its first terms, are nearest the query's; the profile key and the ring key
/// among all entries: exact k-NN over bytes), and the candidates are the best of the rankings
/// fused. Each key misses what another finds: the shape and ring keys the scans with a hidden
/// sector, the profile key places whose sectors look alike in another order. The entries are
/// kept as their code columns (a byte a code), not as descriptors.
pub struct Searcher {
    params: PlusParams,
    /// The fine stage's phase correlation, planned once.
    aligner: Arc<Aligner>,
    /// Entries.
    n: usize,
    /// Every entry's columns and keys, by sections ([`Section`]): owned (and growing), or
    /// mapped from a cache file.
    store: Store,
    /// What failed in the mapped bytes an owned store was copied from ([`Searcher::subset`]).
    copied_damage: Option<String>,
}

/// The sections of a searcher's buffer, per entry: the code columns (u8), reach (u8); the first
/// pass's keys ([`firsts`]), the shape key and the profile key (each [`quantized`]); the
/// Cartesian image's codes (u8, [`super::pose`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Section {
    Columns,
    Reach,
    Firsts,
    Shapes,
    Profiles,
    Image,
}

pub(super) const SECTIONS: usize = 6;
pub(super) const ALL_SECTIONS: [Section; SECTIONS] =
    [Section::Columns, Section::Reach, Section::Firsts, Section::Shapes, Section::Profiles, Section::Image];

impl Section {
    /// Bytes per entry.
    fn entry_bytes(self, p: &PlusParams) -> usize {
        match self {
            Section::Columns => p.polar_len(),
            Section::Reach => 1,
            Section::Firsts => FIRSTS * first_width(p),
            Section::Shapes => shape_len(p),
            Section::Profiles => profile_len(p),
            Section::Image => p.image_side * p.image_side,
        }
    }

    /// Bytes for `n` entries: the first pass's keys in whole blocks ([`BLOCK`]).
    fn bytes_for(self, n: usize, p: &PlusParams) -> usize {
        match self {
            Section::Firsts => n.div_ceil(BLOCK) * BLOCK * self.entry_bytes(p),
            _ => n * self.entry_bytes(p),
        }
    }

    /// Puts `bytes` (one entry's) as entry `row` of this section's `to`, which holds the
    /// entries before it.
    fn append(self, to: &mut Vec<u8>, row: usize, bytes: &[u8], p: &PlusParams) {
        match self {
            Section::Firsts => {
                to.resize(self.bytes_for(row + 1, p), 0);
                put_first(to, row, bytes);
            }
            _ => to.extend_from_slice(bytes),
        }
    }

    /// Entry `row`'s bytes in `all` (this section of every entry).
    fn entry_of<'a>(self, all: &'a [u8], row: usize, p: &PlusParams) -> std::borrow::Cow<'a, [u8]> {
        let per = self.entry_bytes(p);
        match self {
            Section::Firsts => std::borrow::Cow::Owned(get_first(all, row, per)),
            _ => std::borrow::Cow::Borrowed(&all[row * per..(row + 1) * per]),
        }
    }
}

/// The layout of a searcher's bytes ([`Searcher::bytes`]), as a cache file names it: a cache of
/// another layout is rebuilt.
pub const SEARCHER_LAYOUT: &str = "toporec-plus/height-field-4";

/// Sections start on 64-byte boundaries.
pub(super) const SECTION_ALIGN: usize = 64;

/// The byte offsets of the sections for `n` entries, and the buffer's length.
pub(super) fn layout(n: usize, p: &PlusParams) -> ([usize; SECTIONS], usize) {
    let mut offsets = [0; SECTIONS];
    let mut at = 0;
    for (o, section) in offsets.iter_mut().zip(ALL_SECTIONS) {
        *o = at;
        at = (at + section.bytes_for(n, p)).next_multiple_of(SECTION_ALIGN);
    }
    (offsets, at)
}

/// The sections of the body of a searcher of `n` entries ([`Searcher::bytes`]), by name, with
/// their byte ranges (each section's own bytes, without the alignment after it).
pub fn body_sections(n: usize, p: &PlusParams) -> Vec<(&'static str, std::ops::Range<usize>)> {
    let (offsets, _) = layout(n, p);
    let names = ["columns", "reach", "firsts", "shapes", "profiles", "image"];
    (0..SECTIONS).map(|i| (names[i], offsets[i]..offsets[i] + ALL_SECTIONS[i].bytes_for(n, p))).collect()
}

/// Bytes a searcher holds per entry (its sections, without their alignment).
pub fn entry_bytes(p: &PlusParams) -> usize {
    ALL_SECTIONS.iter().map(|s| s.entry_bytes(p)).sum()
}

/// A searcher's sections: built in memory (one growing vector each), or mapped from a cache
/// file (read only; the OS pages it in, and its blocks are checked, as searches touch it).
pub(super) enum Store {
    Owned([Vec<u8>; SECTIONS]),
    /// The cache's body, the sections at `offsets` ([`layout`]).
    Mapped {
        body: crate::checked_map::CheckedMap,
        offsets: [usize; SECTIONS],
    },
}

/// Rows of a block of the first pass's keys. A block holds each key's 8-byte groups
/// group by group, the block's rows side by side (`[key][group][row][8 bytes]`), so that one
/// 32-byte load reads one group of four rows and one sum of absolute differences (`psadbw`)
/// gives their four partial distances.
pub(super) const BLOCK: usize = 4;

/// Where byte `t` of a row's keys (`width` bytes a key, a multiple of 8) lies in its block.
#[inline(always)]
pub(super) fn first_offset(t: usize, row_in_block: usize) -> usize {
    (t / 8) * 8 * BLOCK + row_in_block * 8 + t % 8
}

/// Writes `first` (the [`FIRSTS`] keys of one row, in a row) as row `row` of the blocked
/// section `blocks`.
pub(super) fn put_first(blocks: &mut [u8], row: usize, first: &[u8]) {
    let block = &mut blocks[row / BLOCK * BLOCK * first.len()..][..BLOCK * first.len()];
    for (t, &byte) in first.iter().enumerate() {
        block[first_offset(t, row % BLOCK)] = byte;
    }
}

/// Row `row`'s keys (`row_bytes` bytes) from the blocked section `blocks`.
pub(super) fn get_first(blocks: &[u8], row: usize, row_bytes: usize) -> Vec<u8> {
    let block = &blocks[row / BLOCK * BLOCK * row_bytes..][..BLOCK * row_bytes];
    (0..row_bytes).map(|t| block[first_offset(t, row % BLOCK)]).collect()
}

/// The rows a search may answer with.
type Rule<'a> = &'a dyn Fn(usize) -> bool;

/// One list of rows per first-pass key.
pub(super) type Lists = [Vec<usize>; FIRSTS];

/// The first pass of a search: the `n` rows of `blocks` (blocked, [`BLOCK`]; [`FIRSTS`] keys of
/// `width` bytes, a multiple of 8) against the query's keys (`FIRSTS × width` bytes, in a row).
#[derive(Clone, Copy)]
pub(super) struct FirstPass<'a> {
    pub(super) blocks: &'a [u8],
    pub(super) n: usize,
    pub(super) query: &'a [u8],
    pub(super) width: usize,
}

impl FirstPass<'_> {
    /// For each key, the `m[i]` rows (among those `allowed` admits) nearest the query's by the L1
    /// distance (the sum of absolute differences), ties to the lower row, in that order: one pass
    /// over the rows.
    pub(super) fn nearest(self, m: [usize; FIRSTS], allowed: Rule<'_>) -> Lists {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            return unsafe { self.nearest_avx2(m, allowed) };
        }
        self.nearest_portable(m, allowed)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub(super) fn nearest_avx2(self, m: [usize; FIRSTS], allowed: Rule<'_>) -> Lists {
        let FirstPass { blocks, n, query, width } = self;
        use std::arch::x86_64::*;
        let groups = width / 8;
        let row_bytes = FIRSTS * width;
        // Each query group repeated for the four rows of a block.
        let q: Vec<__m256i> = query
            .chunks_exact(8)
            .map(|g| _mm256_set1_epi64x(i64::from_le_bytes(g.try_into().expect("8 bytes"))))
            .collect();
        let mut best = Nearest::new(m, allowed);
        let mut bounds = best.distance_bounds().map(|b| _mm256_set1_epi64x(b as i64));
        for (b, block) in blocks.chunks_exact(BLOCK * row_bytes).take(n.div_ceil(BLOCK)).enumerate() {
            let mut sums = [_mm256_setzero_si256(); FIRSTS];
            let mut near = 0;
            for (k, sum) in sums.iter_mut().enumerate() {
                for g in k * groups..(k + 1) * groups {
                    let bytes = &block[g * 8 * BLOCK..(g + 1) * 8 * BLOCK];
                    // SAFETY: `bytes` is 32 bytes long; an unaligned load.
                    let v = unsafe { _mm256_loadu_si256(bytes.as_ptr() as *const __m256i) };
                    *sum = _mm256_add_epi64(*sum, _mm256_sad_epu8(v, q[g]));
                }
                near |= _mm256_movemask_pd(_mm256_castsi256_pd(_mm256_cmpgt_epi64(bounds[k], *sum)));
            }
            // Most blocks hold no row nearer than a list's farthest.
            if near != 0 {
                let sums = sums.map(|s| {
                    let mut out = [0u64; BLOCK];
                    // SAFETY: `out` holds 32 bytes; an unaligned store.
                    unsafe { _mm256_storeu_si256(out.as_mut_ptr() as *mut __m256i, s) };
                    out
                });
                for (i, row) in (b * BLOCK..n.min((b + 1) * BLOCK)).enumerate() {
                    best.offer(row, std::array::from_fn(|k| sums[k][i] as u32));
                }
                bounds = best.distance_bounds().map(|b| _mm256_set1_epi64x(b as i64));
            }
        }
        best.rows()
    }

    pub(super) fn nearest_portable(self, m: [usize; FIRSTS], allowed: Rule<'_>) -> Lists {
        let FirstPass { blocks, n, query, width } = self;
        let row_bytes = FIRSTS * width;
        let mut best = Nearest::new(m, allowed);
        for (b, block) in blocks.chunks_exact(BLOCK * row_bytes).take(n.div_ceil(BLOCK)).enumerate() {
            for i in 0..BLOCK.min(n - b * BLOCK) {
                let distance = |k: usize| -> u32 {
                    (k * width..(k + 1) * width)
                        .map(|t| block[first_offset(t, i)].abs_diff(query[t]) as u32)
                        .sum()
                };
                best.offer(b * BLOCK + i, std::array::from_fn(distance));
            }
        }
        best.rows()
    }
}

/// The `m[k]` smallest (distance, row) for each of the [`FIRSTS`] keys among the rows
/// `allowed` admits (asked only of a row that would be kept), ties to the lower row. Each list
/// gathers up to `2 m` keys below its bound, then keeps its `m` smallest (a selection, not a
/// heap: a constant cost per key kept).
pub(super) struct Nearest<'a> {
    allowed: &'a dyn Fn(usize) -> bool,
    m: [usize; FIRSTS],
    kept: [Vec<u64>; FIRSTS],
    /// The largest of the `m` smallest keys so far once a list has been cut to `m` (u64::MAX
    /// before, 0 when `m` is 0): most rows are refused by one comparison with it.
    bound: [u64; FIRSTS],
}

impl<'a> Nearest<'a> {
    fn new(m: [usize; FIRSTS], allowed: &'a dyn Fn(usize) -> bool) -> Self {
        Nearest {
            allowed,
            m,
            kept: m.map(|m| Vec::with_capacity(2 * m)),
            bound: m.map(|m| if m == 0 { 0 } else { u64::MAX }),
        }
    }

    #[inline(always)]
    fn offer(&mut self, row: usize, distances: [u32; FIRSTS]) {
        // Whether the row is allowed: asked once, and only of a row some list would keep.
        let mut admitted: Option<bool> = None;
        for (k, &distance) in distances.iter().enumerate() {
            let key = ((distance as u64) << 32) | row as u64;
            if key < self.bound[k] && *admitted.get_or_insert_with(|| (self.allowed)(row)) {
                self.kept[k].push(key);
                if self.kept[k].len() == 2 * self.m[k] {
                    self.shrink(k);
                }
            }
        }
    }

    /// Keeps list `k`'s `m` smallest keys; the largest of them bounds what it takes next.
    #[cold]
    fn shrink(&mut self, k: usize) {
        let (kept, m) = (&mut self.kept[k], self.m[k]);
        kept.select_nth_unstable(m - 1);
        kept.truncate(m);
        self.bound[k] = kept[m - 1];
    }

    /// Per list, the distance a row must be below to be kept: rows come in order, so one at the
    /// farthest kept distance comes after the kept row and loses the tie.
    fn distance_bounds(&self) -> [u32; FIRSTS] {
        self.bound.map(|b| (b >> 32) as u32)
    }

    fn rows(self) -> [Vec<usize>; FIRSTS] {
        let mut kept = self.kept;
        std::array::from_fn(|k| {
            let list = &mut kept[k];
            list.sort_unstable();
            list.iter().take(self.m[k]).map(|&v| (v & 0xffff_ffff) as usize).collect()
        })
    }
}

/// A searcher built entry by entry: each descriptor is made into its entry's bytes as it comes
/// (in parallel within a batch), so the descriptors need never be held all at once.
pub struct Builder {
    params: PlusParams,
    sections: [Vec<u8>; SECTIONS],
    n: usize,
}

impl Builder {
    /// An empty builder, room made for `capacity` entries.
    pub fn new(params: PlusParams, capacity: usize) -> Self {
        let sections = ALL_SECTIONS.map(|section| Vec::with_capacity(section.bytes_for(capacity, &params)));
        Builder { params, sections, n: 0 }
    }

    /// Appends the entries of `descriptors` (`k × len`, row-major).
    ///
    /// # Panics
    /// When `descriptors` is not a whole number of entries: a caller's bug (the index holds
    /// descriptors of the method's length), which would shift every entry after it.
    pub fn extend(&mut self, descriptors: &[f32]) {
        use rayon::prelude::*;
        let p = &self.params;
        let len = p.len();
        assert!(
            descriptors.len().is_multiple_of(len),
            "{} values are not whole toporec-plus entries of {len}",
            descriptors.len()
        );
        // Batches bound the entries' bytes held beside the sections.
        for batch in descriptors.chunks(len * 4096) {
            let parts: Vec<[Vec<u8>; SECTIONS]> = batch.par_chunks_exact(len).map(|d| entry(d, p)).collect();
            for part in &parts {
                for ((to, from), section) in self.sections.iter_mut().zip(part).zip(ALL_SECTIONS) {
                    section.append(to, self.n, from, p);
                }
                self.n += 1;
            }
        }
    }

    /// The searcher over the entries appended.
    pub fn finish(self) -> Searcher {
        Searcher {
            n: self.n,
            aligner: Arc::new(Aligner::new(&self.params)),
            params: self.params,
            store: Store::Owned(self.sections),
            copied_damage: None,
        }
    }
}

impl Searcher {
    /// A searcher over `descriptors` (`n × len`, row-major), made ready in place of them.
    ///
    /// # Panics
    /// When `descriptors` is not a whole number of entries: a caller's bug (the index holds
    /// descriptors of the method's length), which would shift every entry after the first short
    /// one.
    pub fn new(descriptors: Vec<f32>, params: PlusParams) -> Self {
        let n = descriptors.len() / params.len().max(1);
        let mut builder = Builder::new(params, n);
        builder.extend(&descriptors);
        drop(descriptors);
        builder.finish()
    }
    /// The searcher's bytes, its sections laid out as a cache file's body holds them
    /// (`layout`).
    pub fn bytes(&self) -> std::borrow::Cow<'_, [u8]> {
        let (offsets, total) = layout(self.n, &self.params);
        match &self.store {
            Store::Mapped { body, .. } => std::borrow::Cow::Borrowed(&body.all()[..total]),
            Store::Owned(_) => {
                let mut out = vec![0u8; total];
                for (i, section) in ALL_SECTIONS.into_iter().enumerate() {
                    let bytes = self.section(section);
                    out[offsets[i]..offsets[i] + bytes.len()].copy_from_slice(bytes);
                }
                std::borrow::Cow::Owned(out)
            }
        }
    }

    /// A searcher over the `n` entries laid out in `body` (a cache file's, written from
    /// [`Searcher::bytes`]).
    pub fn mapped(
        body: crate::checked_map::CheckedMap,
        n: usize,
        params: PlusParams,
    ) -> Result<Self, String> {
        let (offsets, total) = layout(n, &params);
        if body.len() < total {
            return Err(format!("{} bytes for {n} entries, {total} expected", body.len()));
        }
        // Every search reads these sections whole or at thousands of scattered rows; the others
        // at a few rows each.
        for section in [Section::Firsts, Section::Shapes, Section::Profiles] {
            let i = section as usize;
            body.will_need(offsets[i]..offsets[i] + section.bytes_for(n, &params));
        }
        Ok(Searcher {
            aligner: Arc::new(Aligner::new(&params)),
            params,
            n,
            store: Store::Mapped { body, offsets },
            copied_damage: None,
        })
    }

    /// What failed, when bytes read from the mapped cache (or the one this searcher's entries
    /// were copied from) failed their checksum.
    pub fn damage(&self) -> Option<String> {
        match &self.store {
            Store::Mapped { body, .. } => body.damage().map(str::to_string),
            Store::Owned(_) => self.copied_damage.clone(),
        }
    }

    /// The entries `rows` (in that order) in a searcher of their own, copied.
    pub fn subset(&self, rows: &[usize]) -> Self {
        let p = &self.params;
        let sections = ALL_SECTIONS.map(|section| {
            let from = self.section(section);
            let mut out = Vec::with_capacity(section.bytes_for(rows.len(), p));
            for (to, &row) in rows.iter().enumerate() {
                section.append(&mut out, to, &section.entry_of(from, row, p), p);
            }
            out
        });
        Searcher {
            params: self.params.clone(),
            aligner: self.aligner.clone(),
            n: rows.len(),
            store: Store::Owned(sections),
            copied_damage: self.damage(),
        }
    }

    /// The same entries searched with other search settings (candidates, shift range); the
    /// descriptor settings must be this searcher's.
    pub fn with_search(mut self, candidates: usize, search_ratio: f64) -> Self {
        self.set_search(candidates, search_ratio);
        self
    }

    /// [`Searcher::with_search`] in place.
    pub fn set_search(&mut self, candidates: usize, search_ratio: f64) {
        self.params.candidates = candidates;
        self.params.search_ratio = search_ratio;
    }

    /// One section of every entry.
    fn section(&self, section: Section) -> &[u8] {
        self.section_part(section, 0..section.bytes_for(self.n, &self.params))
    }

    /// Bytes `range` of one section: only they are read (and, mapped, checked).
    fn section_part(&self, section: Section, range: std::ops::Range<usize>) -> &[u8] {
        let i = section as usize;
        match &self.store {
            Store::Owned(sections) => &sections[i][range],
            Store::Mapped { body, offsets } => body.get(offsets[i] + range.start..offsets[i] + range.end),
        }
    }

    /// One section of entry `row` (not of [`Section::Firsts`], whose entries are interleaved).
    fn entry_section(&self, section: Section, row: usize) -> &[u8] {
        let per = section.entry_bytes(&self.params);
        self.section_part(section, row * per..(row + 1) * per)
    }

    /// The parameters.
    pub fn params(&self) -> &PlusParams {
        &self.params
    }

    /// Entry `row`, ready for matching.
    fn entry(&self, row: usize) -> Entry<'_> {
        Entry {
            columns: self.entry_section(Section::Columns, row),
            reach: self.entry_section(Section::Reach, row)[0] as usize,
        }
    }

    /// The candidates for `query`: the `wanted` rows best by the reciprocal-rank fusion of three
    /// lists of `LIST_PER_CANDIDATE × wanted` rows, one by each key (a row's score is the sum
    /// over the lists of `1 / (FUSION_K + rank)`, ties to the lower row): the ring key's, and
    /// the shape key's and the profile key's among the `COARSE_PER_CANDIDATE` times as many
    /// rows nearest the query by their first terms ([`firsts`], all three read in one pass).
    fn candidates(&self, query: &[f32], wanted: usize, allowed: &dyn Fn(usize) -> bool) -> Vec<usize> {
        let p = &self.params;
        let long = LIST_PER_CANDIDATE * wanted;
        let (shape, profile) = (quantized(&shape_key(query, p)), quantized(&profile_key(query, p)));
        let first = firsts(&shape, &profile, &quantized(&ring_key(query, p)), p);
        let pass = FirstPass {
            blocks: self.section(Section::Firsts),
            n: self.n,
            query: &first,
            width: first_width(p),
        };
        let [by_ring, coarse_shape, coarse_profile] =
            pass.nearest([long, COARSE_PER_CANDIDATE * long, COARSE_PER_CANDIDATE * long], allowed);
        let refined = |section: Section, key: &[u8], mut coarse: Vec<usize>| -> Vec<usize> {
            let entry = |row: usize| self.entry_section(section, row);
            // The rows lie anywhere in the section: each one's bytes are asked for a few rows
            // ahead of their use, in the section's order.
            coarse.sort_unstable();
            let mut scored: Vec<(u32, usize)> = Vec::with_capacity(coarse.len());
            for (i, &row) in coarse.iter().enumerate() {
                if let Some(&ahead) = coarse.get(i + PREFETCH_ROWS) {
                    prefetch(entry(ahead));
                }
                let d = key.iter().zip(entry(row)).map(|(&a, &b)| (a as i32 - b as i32).pow(2) as u32).sum();
                scored.push((d, row));
            }
            scored.sort_unstable();
            scored.into_iter().take(long).map(|(_, row)| row).collect()
        };
        let by_shape = refined(Section::Shapes, &shape, coarse_shape);
        let by_profile = refined(Section::Profiles, &profile, coarse_profile);
        let mut score: std::collections::HashMap<usize, f64> =
            std::collections::HashMap::with_capacity(3 * long);
        for list in [&by_ring, &by_shape, &by_profile] {
            for (rank, &row) in list.iter().enumerate() {
                *score.entry(row).or_default() += 1.0 / (FUSION_K + rank as f64);
            }
        }
        let mut fused: Vec<(f64, usize)> = score.into_iter().map(|(row, s)| (s, row)).collect();
        fused.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        fused.into_iter().take(wanted).map(|(_, row)| row).collect()
    }

    /// Sets the query's lateral views ([`PlusParams::lateral`]): a search-time setting, the
    /// entries are the same with any.
    pub fn set_lateral(&mut self, lateral: Vec<f64>) {
        self.params.lateral = lateral;
    }

    /// The `k` best rows for `query`, by (distance, row), with the time of each step.
    pub fn search(&self, query: &[f32], k: usize) -> (Vec<Hit>, SearchTimes) {
        self.search_where(query, k, &|_| true)
    }

    /// The `k` best rows for `query` among those `allowed` admits, by (distance, row), with the
    /// time of each step: the rows and distances a searcher of those rows alone would give.
    pub fn search_where(
        &self,
        query: &[f32],
        k: usize,
        allowed: &dyn Fn(usize) -> bool,
    ) -> (Vec<Hit>, SearchTimes) {
        let p = &self.params;
        let t = std::time::Instant::now();
        let wanted = p.candidates.max(k);
        // With no more allowed rows than wanted, the keys' lists hold them all.
        let rows = if wanted >= self.n {
            (0..self.n).filter(|&row| allowed(row)).collect()
        } else {
            self.candidates(query, wanted, allowed)
        };
        let candidates_secs = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let views: Vec<Query> = std::iter::once(Query::new(query, p))
            .chain(
                p.lateral.iter().flat_map(|&s| [s, -s]).map(|s| Query::new(&lateral::view(query, s, p), p)),
            )
            .collect();
        let mut hits: Vec<PlusHit> = rows
            .into_iter()
            .map(|row| {
                // The smallest over the views; the query as scanned wins a tie.
                let (d, yaw) = views
                    .iter()
                    .map(|q| distance_to(q, self.entry(row), p))
                    .fold((f64::INFINITY, 0.0), |best, d| if d.0 < best.0 { d } else { best });
                (row, d, yaw)
            })
            .collect();
        hits.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        let hits = self.fine(query, hits, k);
        (hits, SearchTimes { candidates: candidates_secs, rerank: t.elapsed().as_secs_f64() })
    }

    /// The fine stage over hits sorted by the polar distance: the pose of the query relative to
    /// each of the best `fine` ([`super::pose`]), which are then ordered by a score, the polar
    /// distance plus [`POSE_WEIGHT`] times the offset along the candidate's heading
    /// ([`forward_offset`] of [`super::pose::Pose::ranked_x`]; posed by a correlation peak
    /// below [`PEAK_FLOOR`], or turned more than a quarter turn from the best hit, counts as
    /// [`OFFSET_CAP`]), ties by row; only those within [`NEAR_TIE`] of the best polar distance
    /// are ordered so, the others follow in polar order. The turn: neighbouring scans of one
    /// street are seen the same way round, while a lookalike turned half round (a symmetric
    /// crossing from its other side) may pose near the query and must not overtake the best.
    /// Every hit reports its polar distance: the score orders the few, and a threshold on the
    /// distance (loop closure) keeps the scale of the polar ranking.
    fn fine(&self, query: &[f32], hits: Vec<PlusHit>, k: usize) -> Vec<Hit> {
        let p = &self.params;
        let image: Vec<u8> = image_codes(query, p);
        let best_yaw = hits.first().map_or(0.0, |h| h.2);
        let mut posed: Vec<(f64, Hit)> = hits
            .iter()
            .take(p.fine)
            .map(|&(row, d, yaw)| {
                let pose = self.aligner.pose(&image, self.entry_section(Section::Image, row), yaw, p);
                let counted = if pose.peak >= PEAK_FLOOR && turned_alike(yaw, best_yaw) {
                    forward_offset(pose.ranked_x)
                } else {
                    OFFSET_CAP
                };
                let hit = Hit { row, distance: d, yaw_degrees: Some(yaw), offset: Some([pose.x, pose.y]) };
                (d + POSE_WEIGHT * counted, hit)
            })
            .collect();
        // The near-ties are ordered by the score; the posed hits behind them keep polar order.
        let best = hits.first().map_or(0.0, |h| h.1);
        let ties = posed.iter().take_while(|(_, hit)| hit.distance <= best + NEAR_TIE).count();
        posed[..ties].sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.row.cmp(&b.1.row)));
        let rest = hits.iter().skip(p.fine).map(|&(row, d, yaw)| Hit {
            row,
            distance: d,
            yaw_degrees: Some(yaw),
            offset: None,
        });
        posed.into_iter().map(|(_, hit)| hit).chain(rest).take(k).collect()
    }
}

/// How much a metre of offset adds to the distance in the fine stage.
pub(super) const POSE_WEIGHT: f64 = 0.2;

/// The fine stage orders only the candidates whose polar distance lies within this of the best
/// one's: neighbouring scans of one street, near-ties the offset can tell apart. A candidate
/// further behind is another place whose pose may look centred by chance, and it keeps its
/// polar rank. Chosen on the city drive's first half and the seed-11 drive, among 0, 0.02,
/// 0.05, 0.1, 0.15 and no limit (docs/evaluation.md): wider limits find the nearest scan no
/// more often on the city drive and less often on the seed-11 drive; 0.02 more often on the
/// seed-11 drive (by 1–3 points) but much less often on the real city drive (by 4–10).
pub(super) const NEAR_TIE: f64 = 0.05;

/// The lowest phase-correlation peak whose offset the fine stage trusts: below it, two images
/// share too little for their offset to say anything (a candidate of another place, or a view
/// mostly hidden), and the hit counts as not posed. Its pose is reported all the same.
pub(super) const PEAK_FLOOR: f64 = 0.15;

/// The largest offset the fine stage counts (m): beyond it a pose says only "elsewhere".
pub(super) const OFFSET_CAP: f64 = 4.0;

/// Whether two candidates' yaws (degrees) lie within a quarter turn of each other.
pub(super) fn turned_alike(a: f64, b: f64) -> bool {
    let d = (a - b).rem_euclid(360.0);
    d.min(360.0 - d) <= 90.0
}

/// The offset of a pose as the fine stage counts it: its forward part `|x|`, at most
/// [`OFFSET_CAP`]. Neighbouring map scans of a drive lie along their headings, so how far the
/// query is ahead of or behind each says which is nearest; a lateral offset (a lane over) is
/// common to them all and says little, and the pose is reported with it, not ranked by it.
pub(super) fn forward_offset(x: f64) -> f64 {
    x.abs().min(OFFSET_CAP)
}

/// The Cartesian image's codes of a descriptor, as bytes.
fn image_codes(d: &[f32], p: &PlusParams) -> Vec<u8> {
    d[p.polar_len()..].iter().map(|&v| v.clamp(0.0, 255.0) as u8).collect()
}

/// The sections' bytes of one entry.
pub(super) fn entry(d: &[f32], p: &PlusParams) -> [Vec<u8>; SECTIONS] {
    let mut columns = vec![0u8; p.polar_len()];
    columns_of(d, p, &mut columns);
    let (shape, profile) = (quantized(&shape_key(d, p)), quantized(&profile_key(d, p)));
    let first = firsts(&shape, &profile, &quantized(&ring_key(d, p)), p);
    [columns, vec![reach(d, p) as u8], first, shape, profile, image_codes(d, p)]
}

/// Rows ahead whose bytes a scan of scattered rows asks for.
pub(super) const PREFETCH_ROWS: usize = 8;

/// Asks for `bytes` to be brought into the cache; a hint, with no effect on results.
#[inline(always)]
pub(super) fn prefetch(bytes: &[u8]) {
    #[cfg(target_arch = "x86_64")]
    for line in bytes.chunks(64) {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: prefetching reads nothing and cannot fault; the address is within `bytes`.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(line.as_ptr() as *const i8) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = bytes;
}

impl crate::methods::Searcher for Searcher {
    /// Rows.
    fn len(&self) -> usize {
        self.n
    }

    /// One more entry, after the others (a mapped searcher is copied into memory first).
    fn push(&mut self, descriptor: &[f32]) {
        if let Store::Mapped { .. } = self.store {
            *self = Searcher::subset(self, &(0..self.n).collect::<Vec<_>>());
        }
        let parts = entry(descriptor, &self.params);
        if let Store::Owned(sections) = &mut self.store {
            for ((to, from), section) in sections.iter_mut().zip(&parts).zip(ALL_SECTIONS) {
                section.append(to, self.n, from, &self.params);
            }
        }
        self.n += 1;
    }

    fn search(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> (Vec<Hit>, SearchTimes) {
        self.search_where(query, k, allowed.unwrap_or(&|_| true))
    }

    fn set_budget(&mut self, budget: SearchBudget, entries: usize) {
        if let Some((candidates, ratio)) = budget.candidates_and_ratio(self.params.sectors, entries) {
            (self.params.candidates, self.params.search_ratio) = (candidates, ratio);
        }
    }

    fn subset(&self, rows: &[usize]) -> Option<Box<dyn crate::methods::Searcher>> {
        Some(Box::new(Searcher::subset(self, rows)))
    }

    fn bytes(&self) -> Option<std::borrow::Cow<'_, [u8]>> {
        Some(Searcher::bytes(self))
    }

    fn damage(&self) -> Option<String> {
        Searcher::damage(self)
    }
}
