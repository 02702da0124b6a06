//! `toporec-plus`: a topological scan context — where a scan's persistent homology dies, laid
//! out around the sensor, matched by circular shift.
//!
//! The paper's descriptor summarizes a whole diagram, so it finds the drive but not the spot,
//! and a quarter of the view hidden changes all of it. Here the diagram keeps its geometry:
//!
//! 1. the raw scan (sensor frame, metres) within `max_radius` of the sensor, on a voxel grid
//!    centred on the sensor (`voxel`, one centroid a cell: the density no longer depends on
//!    the sensor or on dropped points);
//! 2. the persistent homology of its alpha complex, each pair located where its class dies —
//!    the midpoint of the edge that merges two components (H0), the centroid of the triangle
//!    that fills a loop (H1) ([`crate::homology::alpha_persistence_located`]);
//! 3. each H0 and H1 pair's persistence (radii, metres) added to a polar grid (`rings` ×
//!    `sectors` out to `max_radius`), shared linearly between the two nearest rings and the
//!    two nearest sectors: per dimension, the total persistence in a cell — a `2 × rings ×
//!    sectors` image of where the scan's components merge and its loops close;
//! 4. the grid made again with the locations turned by `1/rotations`, `2/rotations`, … of a
//!    sector, so that a turn between two visits that is not a whole number of sectors still
//!    lines the cells up.
//!
//! The stored descriptor is the `rotations` grids, one after the other (`[rotation][dim][ring]
//! [sector]`). Two scans compare as ScanContext's do, by columns: for each shift of the
//! sectors and each rotation of the candidate, `1 −` the mean cosine of the columns (the
//! `2 · rings` values of one sector) filled in both — a sector hidden in one scan is left out,
//! not counted as a difference, and a scan cut at a shorter range is compared on the rings
//! both reach, its outermost ring (half filled, shared with the ring beyond) left out — and the
//! smallest wins; the shift and rotation give the yaw.
//! A [`Searcher`] takes candidates from two keys that do not depend on the yaw, in turn, and
//! re-ranks them by that distance.
//!
//! Why these choices (measured on simulated two-session drives; the tables are in
//! `docs/evaluation.md`): the H0 totals carry most of the place and the H1 totals add a little;
//! the H2 totals changed no result, and the largest persistence per cell, or each dimension
//! weighed equally, made every condition worse; three turned grids found the nearest scan far
//! more often than one; the candidates, not the distance, limited the recall, until the two
//! keys took turns.
//!
//! Nothing is trained or fitted: no codebook. A turn by a multiple of 90° maps the voxel grid
//! and the polar grid onto themselves (with `sectors` a multiple of 4), so the distance of a
//! scan to itself turned so is 0 up to rounding.

use crate::homology::alpha_persistence_located;
use crate::types::Point;

/// The name of the method.
pub const NAME: &str = "toporec-plus";

/// Grid channels: the total persistence of the H0 and of the H1 pairs in a cell.
const CHANNELS: usize = 2;

/// Settings (`[toporec-plus]` of a pipeline file).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlusParams {
    /// Voxel-grid cell (m).
    pub voxel: f64,
    /// Farthest return kept, and the outer edge of the grid (m, horizontal).
    pub max_radius: f64,
    /// Rings of the polar grid.
    pub rings: usize,
    /// Sectors of the polar grid.
    pub sectors: usize,
    /// Grids per scan, turned by fractions of a sector.
    pub rotations: usize,
    /// Candidates a search re-ranks (at least the k asked for).
    pub candidates: usize,
    /// Shifts tried on all channels around the best alignment of the H0 columns, as a share
    /// of the sectors (ScanContext's `SEARCH_RATIO`): ±`round(0.5 · ratio · sectors)`; 1
    /// tries every shift.
    pub search_ratio: f64,
}

impl Default for PlusParams {
    fn default() -> Self {
        PlusParams {
            voxel: 0.6,
            max_radius: 80.0,
            rings: 20,
            sectors: 60,
            rotations: 3,
            candidates: 100,
            search_ratio: 0.1,
        }
    }
}

impl PlusParams {
    /// The settings' problems, each with its key.
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if !(self.voxel.is_finite() && self.voxel > 0.0) {
            out.push(format!("{NAME}.voxel: must be in (0, inf) m; found {}", self.voxel));
        }
        if !(self.max_radius.is_finite() && self.max_radius > 0.0) {
            out.push(format!("{NAME}.max_radius: must be in (0, inf) m; found {}", self.max_radius));
        }
        if !(1..=200).contains(&self.rings) || !(4..=720).contains(&self.sectors) {
            out.push(format!(
                "{NAME}: need rings in [1, 200] and sectors in [4, 720] (rings {}, sectors {})",
                self.rings, self.sectors
            ));
        }
        if !(1..=16).contains(&self.rotations) {
            out.push(format!("{NAME}.rotations: must be in [1, 16]; found {}", self.rotations));
        }
        if self.candidates == 0 {
            out.push(format!("{NAME}.candidates: must be in [1, inf)"));
        }
        if !(0.0..=1.0).contains(&self.search_ratio) {
            out.push(format!("{NAME}.search_ratio: must be in [0, 1]; found {}", self.search_ratio));
        }
        out
    }

    /// Values of one grid: 2 channels × rings × sectors.
    pub fn grid_len(&self) -> usize {
        CHANNELS * self.rings * self.sectors
    }

    /// Descriptor length: `rotations` grids.
    pub fn len(&self) -> usize {
        self.rotations * self.grid_len()
    }

    /// Whether the descriptor is empty (never, for valid settings).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The angle of one sector, degrees.
    fn sector_degrees(&self) -> f64 {
        360.0 / self.sectors as f64
    }

    /// The turn of grid `r`, degrees.
    fn rotation_degrees(&self, r: usize) -> f64 {
        self.sector_degrees() * r as f64 / self.rotations as f64
    }
}

/// The points of a raw scan the method describes: finite, within `max_radius` of the sensor
/// (horizontally), on the voxel grid centred on the sensor
/// ([`crate::preprocess::voxel_grid_centred`]: a quarter turn of the scan turns the cells).
pub fn preprocess(points: &[Point], p: &PlusParams) -> Vec<Point> {
    let kept = points.iter().filter(|q| q.iter().all(|c| c.is_finite()) && q[0].hypot(q[1]) <= p.max_radius);
    crate::preprocess::voxel_grid_centred(kept, p.voxel)
}

/// The descriptor of a raw scan (sensor frame, metres, z up); an error when its alpha complex
/// cannot be built (points closer than the engine resolves, a cloud past the engine's limits).
/// A scan with few points left, or all on a plane, has the descriptor of the pairs it has.
pub fn describe(points: &[Point], p: &PlusParams) -> Result<Vec<f32>, crate::homology::ComplexError> {
    let cloud = preprocess(points, p);
    let mut out = vec![0f32; p.len()];
    // A scan whose complex cannot be built has no descriptor (an error row), never a zero
    // vector that would match every other such scan.
    let located = alpha_persistence_located(&cloud)?;
    // (dim, persistence in metres, x, y) of every finite pair.
    let pairs: Vec<(usize, f64, f64, f64)> = located
        .iter()
        .filter_map(|l| {
            let at = l.at?;
            let persistence = l.pair.death.sqrt() - l.pair.birth.sqrt();
            (persistence > 0.0 && (l.pair.dim as usize) < CHANNELS).then_some((
                l.pair.dim as usize,
                persistence,
                at[0],
                at[1],
            ))
        })
        .collect();
    let (rings, sectors) = (p.rings, p.sectors);
    // Accumulated in f64, in the pairs' order: the same on every machine and thread count.
    let mut grid = vec![0f64; p.grid_len()];
    for (r, block) in out.chunks_exact_mut(p.grid_len()).enumerate() {
        grid.iter_mut().for_each(|v| *v = 0.0);
        let (s, c) = p.rotation_degrees(r).to_radians().sin_cos();
        for &(dim, persistence, x, y) in &pairs {
            let (x, y) = if r == 0 { (x, y) } else { (c * x - s * y, s * x + c * y) };
            let range = x.hypot(y);
            if range > p.max_radius {
                continue;
            }
            // Shared between the two nearest ring centres, linearly: a scan seen a little
            // nearer or farther moves its topology smoothly across rings.
            let u = (range / p.max_radius * rings as f64 - 0.5).clamp(0.0, (rings - 1) as f64);
            let inner = (u as usize).min(rings - 1);
            let outer = (inner + 1).min(rings - 1);
            let w = u - inner as f64;
            // Likewise between the two nearest sector centres: a turn by part of a sector
            // moves the topology smoothly from one column to the next.
            let v = y.atan2(x).to_degrees().rem_euclid(360.0) / p.sector_degrees() - 0.5;
            let (first, ws) = (v.floor(), v - v.floor());
            let before = (first as i64).rem_euclid(sectors as i64) as usize;
            let after = (before + 1) % sectors;
            for (ring, weight) in [(inner, 1.0 - w), (outer, w)] {
                let row = &mut grid[(dim * rings + ring) * sectors..(dim * rings + ring + 1) * sectors];
                row[before] += weight * (1.0 - ws) * persistence;
                row[after] += weight * ws * persistence;
            }
        }
        block.iter_mut().zip(&grid).for_each(|(o, &v)| *o = v as f32);
    }
    Ok(out)
}

/// Terms of the shape key: the magnitudes of the first `SHAPE_TERMS` terms of the discrete
/// Fourier transform along the sectors.
const SHAPE_TERMS: usize = 16;

/// The terms per ring of the shape key.
fn shape_terms(p: &PlusParams) -> usize {
    SHAPE_TERMS.min(p.sectors / 2 + 1)
}

/// The shape key of a descriptor, independent of the yaw: for the H0 and the H1 sums of each
/// ring of the unturned grid, which sectors are filled (1 or 0), and of that, the magnitudes
/// of the first [`SHAPE_TERMS`] Fourier terms along the sectors (a circular shift changes
/// their phases only); each half scaled to length `1/√2` (all zeros stay zeros). The first
/// term is ScanContext's ring key (the filled share of the ring); the others tell where along
/// the ring the gaps are. Built from what is filled, not from the values, it does not move
/// when fewer returns make the sums smaller.
fn shape_key(descriptor: &[f32], p: &PlusParams) -> Vec<f32> {
    let (rings, sectors) = (p.rings, p.sectors);
    let terms = shape_terms(p);
    // cos and sin of 2π m / sectors, m = k · j mod sectors.
    let twiddles: Vec<(f64, f64)> = (0..sectors)
        .map(|m| {
            let angle = std::f64::consts::TAU * m as f64 / sectors as f64;
            (angle.cos(), angle.sin())
        })
        .collect();
    let mut out = Vec::with_capacity(CHANNELS * rings * terms);
    for channel in 0..CHANNELS {
        let rows = &descriptor[channel * rings * sectors..(channel + 1) * rings * sectors];
        let mut half = Vec::with_capacity(rings * terms);
        for row in rows.chunks_exact(sectors) {
            for k in 0..terms {
                let (mut re, mut im) = (0.0f64, 0.0f64);
                for (j, _) in row.iter().enumerate().filter(|(_, v)| **v > 0.0) {
                    let (cos, sin) = twiddles[k * j % sectors];
                    re += cos;
                    im -= sin;
                }
                half.push(re.hypot(im));
            }
        }
        let norm = half.iter().map(|v| v * v).sum::<f64>().sqrt() * std::f64::consts::SQRT_2;
        out.extend(half.into_iter().map(|v| if norm > 0.0 { (v / norm) as f32 } else { 0.0 }));
    }
    out
}

/// The profile key of a descriptor, independent of the yaw: the mean and the standard
/// deviation, value by value, of the unturned grid's unit columns over its filled sectors —
/// what a sector of this place looks like, whichever sectors are seen. A quarter of the view
/// hidden leaves it nearly as it was, where it moves every term of the shape key.
fn profile_key(descriptor: &[f32], p: &PlusParams) -> Vec<f32> {
    let (height, sectors) = (CHANNELS * p.rings, p.sectors);
    let mut columns = vec![0f32; sectors * height];
    let mut filled = vec![0u8; sectors];
    unit_columns(&descriptor[..p.grid_len()], height, sectors, &mut columns, &mut filled);
    let n = filled.iter().filter(|&&f| f != 0).count();
    let (mut mean, mut square) = (vec![0f64; height], vec![0f64; height]);
    for column in columns.chunks_exact(height).zip(&filled).filter(|(_, f)| **f != 0).map(|(c, _)| c) {
        for ((m, s), &v) in mean.iter_mut().zip(&mut square).zip(column) {
            *m += v as f64;
            *s += v as f64 * v as f64;
        }
    }
    let n = n.max(1) as f64;
    let spread = mean.iter().zip(&square).map(|(m, s)| (s / n - (m / n).powi(2)).max(0.0).sqrt());
    mean.iter().map(|m| m / n).chain(spread).map(|v| v as f32).collect()
}

/// The yaw-independent key of a descriptor: its shape key, then its profile key.
pub fn key(descriptor: &[f32], p: &PlusParams) -> Vec<f32> {
    let mut out = shape_key(descriptor, p);
    out.extend(profile_key(descriptor, p));
    out
}

/// The key's length.
pub fn key_len(p: &PlusParams) -> usize {
    shape_len(p) + profile_len(p)
}

fn shape_len(p: &PlusParams) -> usize {
    CHANNELS * p.rings * shape_terms(p)
}

fn profile_len(p: &PlusParams) -> usize {
    2 * CHANNELS * p.rings
}

/// A descriptor made ready for matching: for each grid, its unit columns (`sectors`
/// columns of `2 · rings` values) and which are filled; for the unturned grid, its unit H0
/// columns (the `rings` H0 persistence sums of each sector) and which are filled.
struct Ready {
    columns: Vec<f32>,
    filled: Vec<u8>,
    h0: Vec<f32>,
    h0_filled: Vec<u8>,
    /// Per entry: the rings out to the outermost one holding a value (a scan cut at a shorter
    /// range reaches fewer).
    reach: Vec<u8>,
}

/// Borrowed parts of a [`Ready`] (one entry of a [`Searcher`]).
#[derive(Clone, Copy)]
struct ReadyRef<'a> {
    columns: &'a [f32],
    filled: &'a [u8],
    h0: &'a [f32],
    h0_filled: &'a [u8],
    reach: usize,
}

/// The unit columns of `rows` consecutive rows of a grid (column `s` = the rows' values in
/// sector `s`) written to `columns`, and whether each column is filled, to `filled`.
fn unit_columns(grid: &[f32], rows: usize, sectors: usize, columns: &mut [f32], filled: &mut [u8]) {
    for (s, (column, filled)) in columns.chunks_exact_mut(rows).zip(filled).enumerate() {
        let norm = (0..rows).map(|h| (grid[h * sectors + s] as f64).powi(2)).sum::<f64>().sqrt();
        *filled = (norm > 0.0) as u8;
        for (h, c) in column.iter_mut().enumerate() {
            *c = if norm > 0.0 { (grid[h * sectors + s] as f64 / norm) as f32 } else { 0.0 };
        }
    }
}

/// The rings of a descriptor's unturned grid out to the outermost one holding a value.
fn reach(descriptor: &[f32], p: &PlusParams) -> usize {
    let (rings, sectors) = (p.rings, p.sectors);
    (0..rings)
        .rev()
        .find(|&r| {
            (0..CHANNELS).any(|ch| {
                let row = (ch * rings + r) * sectors;
                descriptor[row..row + sectors].iter().any(|v| *v != 0.0)
            })
        })
        .map_or(0, |r| r + 1)
}

/// As [`column_distance`], over the first `reach` of the `rings` rings of each channel of the
/// columns only (`channels` channels), the columns renormalized there: two scans compare where
/// both reach.
#[expect(clippy::too_many_arguments, reason = "the columns, their shape and the cut")]
fn column_distance_within(
    q: &[f32],
    qf: &[u8],
    c: &[f32],
    cf: &[u8],
    channels: usize,
    rings: usize,
    reach: usize,
    shift: usize,
) -> f64 {
    let sectors = qf.len();
    let height = channels * rings;
    let (mut sum, mut count) = (0.0f64, 0usize);
    for b in 0..sectors {
        let a = (b + shift) % sectors;
        if qf[a] & cf[b] == 0 {
            continue;
        }
        let (qa, cb) = (&q[a * height..(a + 1) * height], &c[b * height..(b + 1) * height]);
        let (mut dot, mut nq, mut nc) = (0.0f64, 0.0f64, 0.0f64);
        for ch in 0..channels {
            for r in 0..reach {
                let (x, y) = (qa[ch * rings + r] as f64, cb[ch * rings + r] as f64);
                dot += x * y;
                nq += x * x;
                nc += y * y;
            }
        }
        if nq > 0.0 && nc > 0.0 {
            sum += dot / (nq * nc).sqrt();
            count += 1;
        }
    }
    if count > 0 { 1.0 - sum / count as f64 } else { 1.0 }
}

/// Mutable parts of one entry's [`Ready`] form.
struct ReadyMut<'a> {
    columns: &'a mut [f32],
    filled: &'a mut [u8],
    h0: &'a mut [f32],
    h0_filled: &'a mut [u8],
    reach: &'a mut u8,
}

impl ReadyMut<'_> {
    /// Writes the ready form of `descriptor`.
    fn fill(self, descriptor: &[f32], p: &PlusParams) {
        let (height, sectors) = (CHANNELS * p.rings, p.sectors);
        let grids = descriptor.chunks_exact(p.grid_len());
        let columns = self.columns.chunks_exact_mut(sectors * height);
        for ((grid, columns), filled) in grids.zip(columns).zip(self.filled.chunks_exact_mut(sectors)) {
            unit_columns(grid, height, sectors, columns, filled);
        }
        unit_columns(&descriptor[..p.rings * sectors], p.rings, sectors, self.h0, self.h0_filled);
        *self.reach = reach(descriptor, p) as u8;
    }
}

impl Ready {
    /// Room for `n` entries, all zero.
    fn zeroed(n: usize, p: &PlusParams) -> Self {
        Ready {
            columns: vec![0.0; n * p.len()],
            filled: vec![0; n * p.rotations * p.sectors],
            h0: vec![0.0; n * p.rings * p.sectors],
            h0_filled: vec![0; n * p.sectors],
            reach: vec![0; n],
        }
    }

    fn new(descriptor: &[f32], p: &PlusParams) -> Self {
        let mut out = Ready::zeroed(1, p);
        ReadyMut {
            columns: &mut out.columns,
            filled: &mut out.filled,
            h0: &mut out.h0,
            h0_filled: &mut out.h0_filled,
            reach: &mut out.reach[0],
        }
        .fill(descriptor, p);
        out
    }

    fn as_ref(&self) -> ReadyRef<'_> {
        ReadyRef {
            columns: &self.columns,
            filled: &self.filled,
            h0: &self.h0,
            h0_filled: &self.h0_filled,
            reach: self.reach[0] as usize,
        }
    }
}

/// The distance of `query` to `candidate` (both full descriptors; the query's unturned grid
/// is compared with each of the candidate's grids, at the sector shifts around the best
/// alignment of their H0 columns, see [`PlusParams::search_ratio`]), in [0, 1] (1 when no
/// column is filled in both), and the yaw of the query relative to the candidate (degrees,
/// [0, 360), counter-clockwise seen from above) that attains it.
pub fn distance(query: &[f32], candidate: &[f32], p: &PlusParams) -> (f64, f64) {
    distance_to(Ready::new(query, p).as_ref(), Ready::new(candidate, p).as_ref(), p)
}

/// `1 −` the mean cosine of the columns filled in both, candidate column `b` against query
/// column `(b + shift) mod sectors` (1 when none is filled in both). With AVX2, the dot
/// products run eight lanes wide, without fused multiply-adds: the same sums as without.
fn column_distance(q: &[f32], qf: &[u8], c: &[f32], cf: &[u8], height: usize, shift: usize) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { column_distance_avx2(q, qf, c, cf, height, shift) };
    }
    column_distance_portable(q, qf, c, cf, height, shift)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn column_distance_avx2(q: &[f32], qf: &[u8], c: &[f32], cf: &[u8], height: usize, shift: usize) -> f64 {
    column_distance_portable(q, qf, c, cf, height, shift)
}

#[inline(always)]
fn column_distance_portable(q: &[f32], qf: &[u8], c: &[f32], cf: &[u8], height: usize, shift: usize) -> f64 {
    let sectors = qf.len();
    let (mut sum, mut count) = (0.0f64, 0usize);
    for b in 0..sectors {
        let a = (b + shift) % sectors;
        if qf[a] & cf[b] != 0 {
            sum += dot(&q[a * height..(a + 1) * height], &c[b * height..(b + 1) * height]) as f64;
            count += 1;
        }
    }
    if count > 0 { 1.0 - sum / count as f64 } else { 1.0 }
}

/// The cosine of two unit columns, as `1 − ‖a − b‖² / 2` (equal columns give exactly 1),
/// in eight lanes summed in a fixed order.
#[inline(always)]
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut lanes = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca.remainder().iter().zip(cb.remainder()).map(|(x, y)| (x - y) * (x - y)).sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..8 {
            lanes[i] += (x[i] - y[i]) * (x[i] - y[i]);
        }
    }
    1.0 - 0.5 * (lanes.iter().sum::<f32>() + tail)
}

/// The distance of a ready query to a ready candidate. The shift search is in two steps:
/// every shift of the unturned grids compared on their H0 columns alone (a hidden sector
/// drops out of the comparison, as it does below), then the shifts within the search radius
/// of the best one, for each of the candidate's grids, on all channels.
fn distance_to(q: ReadyRef<'_>, c: ReadyRef<'_>, p: &PlusParams) -> (f64, f64) {
    let (height, sectors) = (CHANNELS * p.rings, p.sectors);
    // Compared where both reach: a scan cut at a shorter range leaves the outer rings out.
    let reach = q.reach.min(c.reach).max(1);
    let cut = reach < p.rings;
    // The outermost ring of a cut scan is half empty (shared with the ring beyond): left out.
    let reach = if cut { (reach - 1).max(1) } else { reach };
    let radius = (0.5 * p.search_ratio * sectors as f64).round() as usize;
    let shifts: Vec<usize> = if 2 * radius + 1 >= sectors {
        (0..sectors).collect()
    } else {
        let mut coarse = (f64::INFINITY, 0usize);
        for shift in 0..sectors {
            let d = if cut {
                column_distance_within(q.h0, q.h0_filled, c.h0, c.h0_filled, 1, p.rings, reach, shift)
            } else {
                column_distance(q.h0, q.h0_filled, c.h0, c.h0_filled, p.rings, shift)
            };
            if d < coarse.0 {
                coarse = (d, shift);
            }
        }
        let mut out: Vec<usize> =
            (0..=2 * radius).map(|i| (coarse.1 + sectors + i - radius) % sectors).collect();
        out.sort_unstable();
        out.dedup();
        out
    };
    let (qc, qf) = (&q.columns[..sectors * height], &q.filled[..sectors]);
    let mut best = (f64::INFINITY, 0.0);
    for r in 0..p.rotations {
        let cc = &c.columns[r * sectors * height..(r + 1) * sectors * height];
        let cf = &c.filled[r * sectors..(r + 1) * sectors];
        for &shift in &shifts {
            let d = if cut {
                column_distance_within(qc, qf, cc, cf, CHANNELS, p.rings, reach, shift)
            } else {
                column_distance(qc, qf, cc, cf, height, shift)
            };
            if d < best.0 {
                let yaw = (shift as f64 * p.sector_degrees() + p.rotation_degrees(r)).rem_euclid(360.0);
                best = (d, yaw);
            }
        }
    }
    (best.0.max(0.0), best.1)
}

/// A hit: database row, distance, yaw of the query relative to it (degrees).
pub type PlusHit = (usize, f64, f64);

/// Seconds a search spent in each step.
#[derive(Clone, Copy, Debug, Default)]
pub struct SearchTimes {
    /// Key nearest neighbours.
    pub candidates: f64,
    /// Distances of the candidates.
    pub rerank: f64,
}

/// Entries the first step of the shape half keeps, per candidate it gives: their filled
/// shares per ring are nearest the query's.
const COARSE_PER_CANDIDATE: usize = 10;

/// Descriptors searched in two steps: candidates by the keys, then those re-ranked by
/// [`distance`]. Half the candidates come from each key: by the shape key among the entries
/// whose filled shares per ring (its first terms: a fast exact k-NN) are nearest the query's,
/// and by the profile key among all entries; the two lists are taken in turn, each entry
/// once. Each key misses what the other finds: the shape key the scans with a hidden sector,
/// the profile key places whose sectors look alike in another order. The entries are kept
/// ready for matching (unit columns), not as descriptors.
pub struct Searcher {
    params: PlusParams,
    /// Entries.
    n: usize,
    /// Every entry's ready form and keys, in one buffer of sections ([`Section`]): owned, or
    /// mapped from a cache file.
    store: Store,
    /// Byte offset of each section in `store`.
    offsets: [usize; SECTIONS],
}

/// The sections of a searcher's buffer, per entry: the ready form's unit columns (f32), filled
/// flags (u8), unit H0 columns (f32), their filled flags (u8), reach (u8); the shape key
/// (f32), its filled shares per ring ([`quantized`]), the profile key ([`quantized`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Section {
    Columns,
    Filled,
    H0,
    H0Filled,
    Reach,
    Shapes,
    Shares,
    Profiles,
}

const SECTIONS: usize = 8;
const ALL_SECTIONS: [Section; SECTIONS] = [
    Section::Columns,
    Section::Filled,
    Section::H0,
    Section::H0Filled,
    Section::Reach,
    Section::Shapes,
    Section::Shares,
    Section::Profiles,
];

impl Section {
    /// Bytes per entry.
    fn entry_bytes(self, p: &PlusParams) -> usize {
        match self {
            Section::Columns => 4 * p.len(),
            Section::Filled => p.rotations * p.sectors,
            Section::H0 => 4 * p.rings * p.sectors,
            Section::H0Filled => p.sectors,
            Section::Reach => 1,
            Section::Shapes => 4 * shape_len(p),
            Section::Shares => CHANNELS * p.rings,
            Section::Profiles => profile_len(p),
        }
    }
}

/// Sections start on 64-byte boundaries.
const SECTION_ALIGN: usize = 64;

/// The byte offsets of the sections for `n` entries, and the buffer's length.
fn layout(n: usize, p: &PlusParams) -> ([usize; SECTIONS], usize) {
    let mut offsets = [0; SECTIONS];
    let mut at = 0;
    for (o, section) in offsets.iter_mut().zip(ALL_SECTIONS) {
        *o = at;
        at = (at + n * section.entry_bytes(p)).next_multiple_of(SECTION_ALIGN);
    }
    (offsets, at)
}

/// A searcher's bytes: built in memory, or mapped from a cache file (read only; the OS pages
/// it in as searches touch it).
enum Store {
    /// 8-byte aligned.
    Owned(Vec<u64>),
    /// The file's bytes from `body` on (page aligned, so the sections are too).
    Mapped { map: memmap2::Mmap, body: usize },
}

impl Store {
    fn bytes(&self) -> &[u8] {
        match self {
            Store::Owned(v) => bytemuck::cast_slice(v),
            Store::Mapped { map, body } => &map[*body..],
        }
    }
}

/// Key values in [0, 1] as bytes (`round(255 v)`): the first narrowing of a search reads a
/// quarter of the memory, and its integer distances are exact and the same on every machine.
fn quantized(values: &[f32]) -> Vec<u8> {
    values.iter().map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect()
}

/// The `m` rows of `rows` (row-major, `query.len()` bytes each) nearest `query` by squared
/// Euclidean distance, ties to the lower row, in that order.
fn nearest_rows(rows: &[u8], query: &[u8], m: usize) -> Vec<usize> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { nearest_rows_avx2(rows, query, m) };
    }
    nearest_rows_portable(rows, query, m)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn nearest_rows_avx2(rows: &[u8], query: &[u8], m: usize) -> Vec<usize> {
    nearest_rows_portable(rows, query, m)
}

#[inline(always)]
fn nearest_rows_portable(rows: &[u8], query: &[u8], m: usize) -> Vec<usize> {
    // The m smallest (distance << 32 | row) so far, largest on top: one integer to compare,
    // ties to the lower row; most rows are refused by one comparison with the top.
    let mut best: std::collections::BinaryHeap<u64> = std::collections::BinaryHeap::with_capacity(m + 1);
    if m == 0 {
        return Vec::new();
    }
    for (i, r) in rows.chunks_exact(query.len()).enumerate() {
        let sum: i32 = r
            .iter()
            .zip(query)
            .map(|(&a, &b)| {
                let d = a as i16 - b as i16;
                d as i32 * d as i32
            })
            .sum();
        let key = ((sum as u64) << 32) | i as u64;
        if best.len() < m {
            best.push(key);
        } else if key < *best.peek().expect("m > 0") {
            best.pop();
            best.push(key);
        }
    }
    best.into_sorted_vec().into_iter().map(|v| (v & 0xffff_ffff) as usize).collect()
}

/// The filled shares per ring of a shape key (its terms of order 0).
fn shares_of(shape: &[f32], p: &PlusParams) -> Vec<f32> {
    shape.iter().step_by(shape_terms(p)).copied().collect()
}

impl Searcher {
    /// A searcher over `descriptors` (`n × len`, row-major), made ready in place of them.
    pub fn new(descriptors: Vec<f32>, params: PlusParams) -> Self {
        use rayon::prelude::*;
        let p = &params;
        let n = descriptors.len() / p.len();
        let (offsets, total) = layout(n, p);
        let mut buffer = vec![0u64; total.div_ceil(8)];
        {
            // The sections, each borrowed mutably on its own.
            let mut rest: &mut [u8] = bytemuck::cast_slice_mut(&mut buffer);
            let mut parts: Vec<&mut [u8]> = Vec::with_capacity(SECTIONS);
            let mut at = 0;
            for (o, section) in offsets.iter().zip(ALL_SECTIONS) {
                let (_, tail) = std::mem::take(&mut rest).split_at_mut(o - at);
                let (part, tail) = tail.split_at_mut(n * section.entry_bytes(p));
                parts.push(part);
                rest = tail;
                at = o + n * section.entry_bytes(p);
            }
            let [columns, filled, h0, h0_filled, reach, shapes, shares, profiles]: [&mut [u8]; SECTIONS] =
                parts.try_into().unwrap_or_else(|_| unreachable!("{SECTIONS} sections"));
            let columns: &mut [f32] = bytemuck::cast_slice_mut(columns);
            let h0: &mut [f32] = bytemuck::cast_slice_mut(h0);
            let shapes: &mut [f32] = bytemuck::cast_slice_mut(shapes);
            descriptors
                .par_chunks_exact(p.len())
                .zip(columns.par_chunks_exact_mut(p.len()))
                .zip(filled.par_chunks_exact_mut(p.rotations * p.sectors))
                .zip(h0.par_chunks_exact_mut(p.rings * p.sectors))
                .zip(h0_filled.par_chunks_exact_mut(p.sectors))
                .zip(shapes.par_chunks_exact_mut(shape_len(p)))
                .zip(shares.par_chunks_exact_mut(CHANNELS * p.rings))
                .zip(profiles.par_chunks_exact_mut(profile_len(p)))
                .zip(reach.par_iter_mut())
                .for_each(
                    |((((((((d, columns), filled), h0), h0_filled), shape), share), profile), reach)| {
                        ReadyMut { columns, filled, h0, h0_filled, reach }.fill(d, p);
                        let key = shape_key(d, p);
                        share.copy_from_slice(&quantized(&shares_of(&key, p)));
                        shape.copy_from_slice(&key);
                        profile.copy_from_slice(&quantized(&profile_key(d, p)));
                    },
                );
        }
        drop(descriptors);
        Searcher { params, n, store: Store::Owned(buffer), offsets }
    }

    /// The searcher's bytes (its sections, as a cache file's body holds them).
    pub fn bytes(&self) -> &[u8] {
        let (_, total) = layout(self.n, &self.params);
        &self.store.bytes()[..total]
    }

    /// A searcher over the `n` entries laid out in `map` from byte `body` on (a cache file
    /// written from [`Searcher::bytes`]).
    pub fn mapped(map: memmap2::Mmap, body: usize, n: usize, params: PlusParams) -> Result<Self, String> {
        let (offsets, total) = layout(n, &params);
        if map.len() < body + total || !body.is_multiple_of(SECTION_ALIGN) {
            return Err(format!(
                "{} bytes for {n} entries, {total} expected",
                map.len().saturating_sub(body)
            ));
        }
        Ok(Searcher { params, n, store: Store::Mapped { map, body }, offsets })
    }

    /// The entries `rows` (in that order) in a searcher of their own, copied.
    pub fn subset(&self, rows: &[usize]) -> Self {
        let p = &self.params;
        let (offsets, total) = layout(rows.len(), p);
        let mut buffer = vec![0u64; total.div_ceil(8)];
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut buffer);
        for (i, section) in ALL_SECTIONS.into_iter().enumerate() {
            let per = section.entry_bytes(p);
            let from = &self.store.bytes()[self.offsets[i]..];
            for (k, &row) in rows.iter().enumerate() {
                let to = offsets[i] + k * per;
                bytes[to..to + per].copy_from_slice(&from[row * per..(row + 1) * per]);
            }
        }
        Searcher { params: self.params.clone(), n: rows.len(), store: Store::Owned(buffer), offsets }
    }

    /// The same entries searched with other search settings (candidates, shift range); the
    /// descriptor settings must be this searcher's.
    pub fn with_search(mut self, candidates: usize, search_ratio: f64) -> Self {
        self.params.candidates = candidates;
        self.params.search_ratio = search_ratio;
        self
    }

    /// One section of every entry.
    fn section<T: bytemuck::Pod>(&self, section: Section) -> &[T] {
        let i = section as usize;
        let start = self.offsets[i];
        bytemuck::cast_slice(&self.store.bytes()[start..start + self.n * section.entry_bytes(&self.params)])
    }

    /// One section of entry `row`.
    fn entry_section<T: bytemuck::Pod>(&self, section: Section, row: usize) -> &[T] {
        let all = self.section::<T>(section);
        let per = all.len() / self.n.max(1);
        &all[row * per..(row + 1) * per]
    }

    /// Rows.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The parameters.
    pub fn params(&self) -> &PlusParams {
        &self.params
    }

    /// Entry `row`, ready for matching.
    fn entry(&self, row: usize) -> ReadyRef<'_> {
        ReadyRef {
            columns: self.entry_section(Section::Columns, row),
            filled: self.entry_section(Section::Filled, row),
            h0: self.entry_section(Section::H0, row),
            h0_filled: self.entry_section(Section::H0Filled, row),
            reach: self.entry_section::<u8>(Section::Reach, row)[0] as usize,
        }
    }

    /// The candidates for `query`: at most `wanted` rows, half by each key, taken in turn.
    fn candidates(&self, query: &[f32], wanted: usize) -> Vec<usize> {
        let p = &self.params;
        let half = wanted.div_ceil(2);
        let shape = shape_key(query, p);
        let width = shape_len(p);
        let mut by_shape: Vec<(f64, usize)> = nearest_rows(
            self.section(Section::Shares),
            &quantized(&shares_of(&shape, p)),
            COARSE_PER_CANDIDATE * half,
        )
        .into_iter()
        .map(|row| {
            let e = &self.section::<f32>(Section::Shapes)[row * width..(row + 1) * width];
            (shape.iter().zip(e).map(|(a, b)| ((a - b) as f64).powi(2)).sum(), row)
        })
        .collect();
        by_shape.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let by_profile =
            nearest_rows(self.section(Section::Profiles), &quantized(&profile_key(query, p)), wanted);
        let lists = [by_shape.into_iter().map(|(_, row)| row).collect::<Vec<_>>(), by_profile];
        // In turn, each row once: half from each list unless they share rows.
        let mut out = Vec::with_capacity(wanted);
        let mut taken = std::collections::HashSet::with_capacity(wanted);
        for i in 0..lists[0].len().max(lists[1].len()) {
            for list in &lists {
                if let Some(&row) = list.get(i)
                    && out.len() < wanted
                    && taken.insert(row)
                {
                    out.push(row);
                }
            }
        }
        out
    }

    /// The `k` best rows for `query`, by (distance, row), with the time of each step.
    pub fn search(&self, query: &[f32], k: usize) -> (Vec<PlusHit>, SearchTimes) {
        let p = &self.params;
        let t = std::time::Instant::now();
        let wanted = p.candidates.max(k).min(self.len());
        let rows = self.candidates(query, wanted);
        let candidates_secs = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let q = Ready::new(query, p);
        let mut hits: Vec<PlusHit> = rows
            .into_iter()
            .map(|row| {
                let (d, yaw) = distance_to(q.as_ref(), self.entry(row), p);
                (row, d, yaw)
            })
            .collect();
        hits.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        hits.truncate(k);
        (hits, SearchTimes { candidates: candidates_secs, rerank: t.elapsed().as_secs_f64() })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Box walls around the sensor, sampled every 20 cm with a few centimetres of noise (in
    /// general position: no point on a voxel boundary, no four on a circle).
    fn scene() -> Vec<Point> {
        let mut rng = crate::rng::SplitMix64(7);
        let mut jitter = move || (rng.next_f64() - 0.5) * 0.04;
        let mut pts = Vec::new();
        let mut add_box = |cx: f64, cy: f64, w: f64, h: f64| {
            let steps = (w / 0.2) as i32;
            for i in 0..=steps {
                for k in 0..=(h / 0.2) as i32 {
                    let t = i as f64 * 0.2 - w / 2.0;
                    let z = k as f64 * 0.2;
                    for q in [
                        [cx + t, cy - w / 2.0, z],
                        [cx + t, cy + w / 2.0, z],
                        [cx - w / 2.0, cy + t, z],
                        [cx + w / 2.0, cy + t, z],
                    ] {
                        pts.push([q[0] + jitter(), q[1] + jitter(), q[2] + jitter()]);
                    }
                }
            }
        };
        add_box(12.0, 5.0, 6.0, 4.0);
        add_box(-9.0, 14.0, 8.0, 6.0);
        add_box(-15.0, -10.0, 5.0, 3.0);
        add_box(4.0, -20.0, 10.0, 5.0);
        add_box(30.0, -3.0, 4.0, 8.0);
        pts
    }

    fn turned(pts: &[Point], quarter_turns: usize) -> Vec<Point> {
        pts.iter()
            .map(|&[x, y, z]| match quarter_turns % 4 {
                0 => [x, y, z],
                1 => [-y, x, z],
                2 => [-x, -y, z],
                _ => [y, -x, z],
            })
            .collect()
    }

    #[test]
    fn a_quarter_turn_is_matched_exactly_and_its_yaw_found() {
        let p = PlusParams::default();
        let a = describe(&scene(), &p).unwrap();
        assert!(a.iter().any(|&v| v > 0.0));
        for q in 1..4 {
            let b = describe(&turned(&scene(), q), &p).unwrap();
            let (d, yaw) = distance(&b, &a, &p);
            assert_eq!(d, 0.0, "{q} quarter turns: distance {d}");
            assert!((yaw - 90.0 * q as f64).abs() < 1e-9, "{q} quarter turns: yaw {yaw}");
        }
    }

    #[test]
    fn keys_do_not_depend_on_quarter_turns_and_distances_are_symmetric_in_range() {
        let p = PlusParams::default();
        let a = describe(&scene(), &p).unwrap();
        let b = describe(&turned(&scene(), 1), &p).unwrap();
        let (ka, kb) = (key(&a, &p), key(&b, &p));
        for (x, y) in ka.iter().zip(&kb) {
            assert!((x - y).abs() < 1e-6);
        }
        let empty = describe(&[], &p).unwrap();
        assert_eq!(distance(&empty, &a, &p).0, 1.0, "an empty scan matches nothing");
    }

    #[test]
    fn a_hidden_sector_is_left_out_not_counted_as_a_difference() {
        let p = PlusParams::default();
        let full = describe(&scene(), &p).unwrap();
        // The boxes at x > 0, y > 0 (the first quadrant) hidden.
        let hidden: Vec<Point> = scene().into_iter().filter(|q| !(q[0] > 0.0 && q[1] > 0.0)).collect();
        let part = describe(&hidden, &p).unwrap();
        let (d, yaw) = distance(&part, &full, &p);
        let other = describe(
            &turned(&scene(), 1).into_iter().map(|q| [q[0] * 1.7, q[1] * 0.6, q[2]]).collect::<Vec<_>>(),
            &p,
        )
        .unwrap();
        assert!(d < distance(&part, &other, &p).0, "the occluded scan is nearer its own place");
        assert!(!(6.0..=354.0).contains(&yaw), "no turn: yaw {yaw}");
    }

    #[test]
    fn a_scan_cut_at_a_shorter_range_is_compared_where_both_reach() {
        // Rings of 2 m: the scene reaches ring 16 (32 m); cut at 20 m, ring 10.
        let p = PlusParams { max_radius: 40.0, ..PlusParams::default() };
        let full = describe(&scene(), &p).unwrap();
        let near: Vec<Point> = scene().into_iter().filter(|q| q[0].hypot(q[1]) <= 20.0).collect();
        let cut = describe(&near, &p).unwrap();
        let (r_full, r_cut) = (reach(&full, &p), reach(&cut, &p));
        assert!(r_cut < r_full && r_cut <= 11, "reach {r_cut} of {r_full} rings");
        // Within the rings both reach (the cut's last, half-empty ring left out), the cut scan
        // is its own place: nearer it than the place turned and stretched, and than it was
        // when the rings beyond the cut counted.
        let other: Vec<Point> =
            turned(&scene(), 1).into_iter().map(|q| [q[0] * 1.7, q[1] * 0.6, q[2]]).collect();
        let other = describe(&other, &p).unwrap();
        let (d, _) = distance(&cut, &full, &p);
        assert!(d < distance(&cut, &other, &p).0, "{d}");
        let ready = |x: &[f32]| Ready::new(x, &p);
        let (q, c) = (ready(&cut), ready(&full));
        let everywhere = (0..p.sectors)
            .map(|s| {
                column_distance(
                    &q.columns[..p.sectors * 2 * p.rings],
                    &q.filled[..p.sectors],
                    &c.columns[..p.sectors * 2 * p.rings],
                    &c.filled[..p.sectors],
                    2 * p.rings,
                    s,
                )
            })
            .fold(f64::INFINITY, f64::min);
        assert!(d < everywhere, "{d} within the reach, {everywhere} over every ring");
    }
}
