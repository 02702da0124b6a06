//! `toporec-plus`: the persistence of a scan's height field, laid out around the sensor and
//! matched by circular shift.
//!
//! The paper's descriptor summarizes a whole diagram, so it finds the drive but not the spot,
//! and a quarter of the view hidden changes all of it. Here the topology keeps its place:
//!
//! 1. **The height field.** The raw scan (sensor frame, metres, z up) within `max_radius` of
//!    the sensor, on a bird's-eye grid of `cell`-metre squares centred on the sensor: each
//!    square holds the highest return above it.
//! 2. **Its persistence.** The superlevel-set filtration of the field (squares enter from the
//!    highest down, each joined to its eight neighbours): every peak is born as an H0 class,
//!    which dies where it meets the component of a higher peak (the elder rule) — persistence
//!    is a structure's prominence. Each square belongs to the class it joined when it
//!    entered, and its **relief** is its height above the level where that class dies: a
//!    peak's relief is its pair's persistence, and the squares below it carry what is left of
//!    it at their height. The classes that never die (one per connected part of the field)
//!    die at the field's lowest square. Union-find over the squares in height order computes
//!    it exactly.
//! 3. **The polar grid.** `rings` × `sectors` out to `max_radius`, two channels: the total
//!    relief in a cell, each square's shared linearly between the two nearest rings and the
//!    two nearest sectors (a structure seen a little nearer or turned a little moves smoothly
//!    across cells), and the height of the highest square in the cell plus `lidar_height`
//!    (the filtration's own values: ScanContext's bin, whose squares the relief ranks).
//! 4. **Codes.** Each channel is stored as the square root of its share of the scan's
//!    largest value, in 256 levels (`0..=255` as float32): the square root keeps the small
//!    near cells apart from each other, the codes are what the searcher multiplies, in exact
//!    integer arithmetic, and the Parquet dictionary stores a code in about a byte.
//!
//! Two scans compare by columns (the `rings` codes of one channel in one sector): per
//! channel, `1 −` the mean cosine of the columns filled in both — a sector hidden in one scan
//! is left out, not counted as a difference, and a scan cut at a shorter range is compared on
//! the rings both reach, its outermost ring (half filled) left out — the two channels
//! averaged. The query is turned by the sector shifts (around the best alignment of the
//! relief columns, see [`PlusParams::search_ratio`]) and by `1/turns`, `2/turns`, … of a
//! sector between them (its columns interpolated), and the smallest distance wins; the shift
//! and the turn give the yaw. A [`Searcher`] takes candidates from two keys that do not depend
//! on the yaw, in turn, and re-ranks them by that distance.
//!
//! Nothing is trained or fitted: no codebook. A turn by a multiple of 90° maps the square
//! grid and the polar grid onto themselves (with `sectors` a multiple of 4; angles are taken
//! within a quadrant, so a quarter turn gives the same numbers), so the distance of a scan to
//! itself turned so is exactly 0, up to ties in height (two squares at exactly the same height
//! enter in the order of their position, which a turn changes).
//!
//! Why these choices (measured on a simulated drive no reported table uses; the tables are in
//! `docs/evaluation.md`): the relief alone finds the place within 2 m under every condition
//! and the nearest scan more often than ScanContext; the height channel beside it adds the
//! nearest scan under occlusion and a shorter range; finer squares help (0.5 m against 1 m),
//! and so do the query's sub-sector turns (one grid matched at whole sectors loses the nearest
//! scan on reversed revisits).

use crate::types::Point;

/// The name of the method.
pub const NAME: &str = "toporec-plus";

/// Grid channels: the total relief in a cell, the height of its highest square.
const CHANNELS: usize = 2;

/// The relief channel.
const RELIEF: usize = 0;

/// Largest code.
const LEVELS: f64 = 255.0;

/// The height (m, above the ground by `lidar_height`) of the largest height code: taller is
/// stored as this tall.
const HEIGHT_SCALE: f64 = 64.0;

/// Settings (`[toporec-plus]` of a pipeline file).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlusParams {
    /// Side of the height field's squares (m).
    pub cell: f64,
    /// Farthest return kept, and the outer edge of the grid (m, horizontal).
    pub max_radius: f64,
    /// Rings of the polar grid.
    pub rings: usize,
    /// Sectors of the polar grid.
    pub sectors: usize,
    /// Added to every height of the height channel (m): the sensor's height above the ground,
    /// as ScanContext's `lidar_height`.
    pub lidar_height: f64,
    /// Turns of the query tried between two sector shifts: by `0, 1/turns, …` of a sector.
    pub turns: usize,
    /// Candidates a search re-ranks (at least the k asked for).
    pub candidates: usize,
    /// Shifts tried around the best alignment of the relief columns, as a share of the
    /// sectors (ScanContext's `SEARCH_RATIO`): ±`round(0.5 · ratio · sectors)`; 1 tries every
    /// shift.
    pub search_ratio: f64,
}

impl Default for PlusParams {
    fn default() -> Self {
        PlusParams {
            cell: 0.5,
            max_radius: 80.0,
            rings: 20,
            sectors: 60,
            lidar_height: 2.0,
            turns: 3,
            candidates: 50,
            search_ratio: 0.1,
        }
    }
}

impl PlusParams {
    /// The settings' problems, each with its key.
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if !(self.cell.is_finite() && self.cell >= 0.05) {
            out.push(format!("{NAME}.cell: must be in [0.05, inf) m; found {}", self.cell));
        }
        if !(self.max_radius.is_finite() && self.max_radius > 0.0) {
            out.push(format!("{NAME}.max_radius: must be in (0, inf) m; found {}", self.max_radius));
        } else if self.cell.is_finite() && self.cell > 0.0 && self.max_radius / self.cell > 4096.0 {
            out.push(format!(
                "{NAME}: max_radius / cell must be at most 4096 (the height field's side); found {}",
                self.max_radius / self.cell
            ));
        }
        if !(1..=200).contains(&self.rings) || !(4..=720).contains(&self.sectors) {
            out.push(format!(
                "{NAME}: need rings in [1, 200] and sectors in [4, 720] (rings {}, sectors {})",
                self.rings, self.sectors
            ));
        }
        if !self.lidar_height.is_finite() {
            out.push(format!("{NAME}.lidar_height: must be finite; found {}", self.lidar_height));
        }
        if !(1..=16).contains(&self.turns) {
            out.push(format!("{NAME}.turns: must be in [1, 16]; found {}", self.turns));
        }
        if self.candidates == 0 {
            out.push(format!("{NAME}.candidates: must be in [1, inf)"));
        }
        if !(0.0..=1.0).contains(&self.search_ratio) {
            out.push(format!("{NAME}.search_ratio: must be in [0, 1]; found {}", self.search_ratio));
        }
        out
    }

    /// Descriptor length: 2 channels × rings × sectors.
    pub fn len(&self) -> usize {
        CHANNELS * self.rings * self.sectors
    }

    /// Whether the descriptor is empty (never, for valid settings).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The angle of one sector, degrees.
    fn sector_degrees(&self) -> f64 {
        360.0 / self.sectors as f64
    }

    /// Codes of one column (one channel of one sector).
    fn height(&self) -> usize {
        CHANNELS * self.rings
    }
}

/// The squares on a side of the height field: an even number, so that the sensor sits on a
/// corner and a quarter turn maps the squares onto themselves.
fn side(p: &PlusParams) -> usize {
    2 * (p.max_radius / p.cell).ceil() as usize
}

/// Range and azimuth (degrees, [0, 360), counter-clockwise from x) of (x, y). The angle is
/// taken within the quadrant, after turning (x, y) into the first one exactly, so that a point
/// turned by a quarter turn gets the same numbers plus 90°.
fn polar(x: f64, y: f64) -> (f64, f64) {
    let (quadrant, u, v) = if x > 0.0 && y >= 0.0 {
        (0.0, x, y)
    } else if x <= 0.0 && y > 0.0 {
        (90.0, y, -x)
    } else if x < 0.0 && y <= 0.0 {
        (180.0, -x, -y)
    } else {
        (270.0, -y, x)
    };
    (u.hypot(v), quadrant + v.atan2(u).to_degrees())
}

/// The height field of a raw scan: per square (row-major, `side` × `side`), the highest z
/// above it (NaN when none), and the filled squares.
struct HeightField {
    side: usize,
    height: Vec<f32>,
    filled: Vec<u32>,
}

fn height_field(points: &[Point], p: &PlusParams) -> HeightField {
    let side = side(p);
    let half = (side / 2) as f64;
    let mut height = vec![f32::NAN; side * side];
    let mut filled = Vec::new();
    for q in points {
        if !q.iter().all(|c| c.is_finite()) || q[0].hypot(q[1]) > p.max_radius {
            continue;
        }
        let (i, j) = ((q[0] / p.cell + half).floor(), (q[1] / p.cell + half).floor());
        if !(0.0..side as f64).contains(&i) || !(0.0..side as f64).contains(&j) {
            continue;
        }
        let k = i as usize * side + j as usize;
        let z = q[2] as f32;
        let h = &mut height[k];
        if h.is_nan() {
            filled.push(k as u32);
            *h = z;
        } else if z > *h {
            *h = z;
        }
    }
    HeightField { side, height, filled }
}

impl HeightField {
    /// The centre (x, y) of square `k`.
    fn centre(&self, k: usize, cell: f64) -> (f64, f64) {
        let half = (self.side / 2) as f64;
        let (i, j) = ((k / self.side) as f64, (k % self.side) as f64);
        ((i - half + 0.5) * cell, (j - half + 0.5) * cell)
    }

    /// Each filled square's relief (in the order of `filled` sorted by height, highest first,
    /// ties by position), with the squares in that order: the superlevel-set H0 persistence,
    /// by union-find.
    fn relief(&self) -> (Vec<u32>, Vec<f32>) {
        let side = self.side;
        // Highest first; equal heights by position. The key orders f32 totally.
        let key = |k: u32| {
            let bits = self.height[k as usize].to_bits();
            let ordered = if bits >> 31 == 1 { !bits } else { bits | 0x8000_0000 };
            ((!ordered as u64) << 32) | k as u64
        };
        let mut keys: Vec<u64> = self.filled.iter().map(|&k| key(k)).collect();
        keys.sort_unstable();
        let order: Vec<u32> = keys.iter().map(|k| *k as u32).collect();
        let n = order.len();
        // The entry rank of each square (u32::MAX: empty).
        let mut rank = vec![u32::MAX; side * side];
        for (r, &k) in order.iter().enumerate() {
            rank[k as usize] = r as u32;
        }
        // Union-find over ranks. A component's root is its highest square (its lowest rank),
        // which is the peak of the class it stands for: the elder of two is the lower root.
        let mut parent: Vec<u32> = (0..n as u32).collect();
        let find = |parent: &mut Vec<u32>, mut a: u32| {
            while parent[a as usize] != a {
                let up = parent[parent[a as usize] as usize];
                parent[a as usize] = up;
                a = up;
            }
            a
        };
        let mut class = vec![0u32; n];
        let mut death = vec![f32::NAN; n];
        let mut roots: Vec<u32> = Vec::with_capacity(8);
        for r in 0..n {
            let k = order[r] as usize;
            let (i, j) = (k / side, k % side);
            roots.clear();
            for di in [-1i64, 0, 1] {
                for dj in [-1i64, 0, 1] {
                    let (a, b) = (i as i64 + di, j as i64 + dj);
                    if (di == 0 && dj == 0) || a < 0 || b < 0 || a >= side as i64 || b >= side as i64 {
                        continue;
                    }
                    let m = rank[a as usize * side + b as usize];
                    if m < r as u32 {
                        let root = find(&mut parent, m);
                        if !roots.contains(&root) {
                            roots.push(root);
                        }
                    }
                }
            }
            let Some(&elder) = roots.iter().min() else {
                class[r] = r as u32;
                continue;
            };
            class[r] = elder;
            parent[r] = elder;
            for &younger in roots.iter().filter(|&&root| root != elder) {
                death[younger as usize] = self.height[k];
                parent[younger as usize] = elder;
            }
        }
        let lowest = order.last().map_or(0.0, |&k| self.height[k as usize]);
        let relief = (0..n)
            .map(|r| {
                let d = death[class[r] as usize];
                self.height[order[r] as usize] - if d.is_nan() { lowest } else { d }
            })
            .collect();
        (order, relief)
    }
}

/// The descriptor of a raw scan (sensor frame, metres, z up): `2 × rings × sectors` codes in
/// `0..=255` (`[channel][ring][sector]`, channel 0 the relief, 1 the height). An error for a
/// scan with no return within `max_radius`: it has no descriptor (an error row), never a zero
/// vector.
pub fn describe(points: &[Point], p: &PlusParams) -> Result<Vec<f32>, String> {
    let field = height_field(points, p);
    if field.filled.is_empty() {
        return Err(format!("no return within {} m of the sensor", p.max_radius));
    }
    let (order, relief) = field.relief();
    let (rings, sectors) = (p.rings, p.sectors);
    let mut grid = vec![0f64; p.len()];
    let sector = p.sector_degrees();
    for (&k, &r) in order.iter().zip(&relief) {
        let (x, y) = field.centre(k as usize, p.cell);
        let (range, azimuth) = polar(x, y);
        if range > p.max_radius {
            continue;
        }
        // Relief: shared between the two nearest ring centres and the two nearest sector
        // centres, linearly.
        let u = (range / p.max_radius * rings as f64 - 0.5).clamp(0.0, (rings - 1) as f64);
        let inner = (u as usize).min(rings - 1);
        let outer = (inner + 1).min(rings - 1);
        let w = u - inner as f64;
        let v = azimuth / sector - 0.5;
        let (first, ws) = (v.floor(), v - v.floor());
        let before = (first as i64).rem_euclid(sectors as i64) as usize;
        let after = (before + 1) % sectors;
        let value = r as f64;
        for (ring, weight) in [(inner, 1.0 - w), (outer, w)] {
            let row = &mut grid[(RELIEF * rings + ring) * sectors..(RELIEF * rings + ring + 1) * sectors];
            row[before] += weight * (1.0 - ws) * value;
            row[after] += weight * ws * value;
        }
        // Height: the highest square of the cell it falls in.
        let ring = ((range / p.max_radius * rings as f64) as usize).min(rings - 1);
        let s = ((azimuth / sector) as usize).min(sectors - 1);
        let h = (field.height[k as usize] as f64 + p.lidar_height).max(0.0);
        let cell = &mut grid[((1 - RELIEF) * rings + ring) * sectors + s];
        *cell = cell.max(h);
    }
    let mut out = vec![0f32; p.len()];
    for (ch, (codes, values)) in
        out.chunks_exact_mut(rings * sectors).zip(grid.chunks_exact(rings * sectors)).enumerate()
    {
        // The relief relative to the scan's largest, the heights on a fixed scale (metres).
        let largest = if ch == RELIEF { values.iter().copied().fold(0.0, f64::max) } else { HEIGHT_SCALE };
        if largest > 0.0 {
            for (c, &v) in codes.iter_mut().zip(values) {
                *c = ((v / largest).min(1.0).sqrt() * LEVELS).round() as f32;
            }
        }
    }
    Ok(out)
}

/// A descriptor's codes as bytes, column by column: `[sector][channel][ring]`.
fn columns_of(descriptor: &[f32], p: &PlusParams, out: &mut [u8]) {
    let (rings, sectors, height) = (p.rings, p.sectors, p.height());
    for ch in 0..CHANNELS {
        for r in 0..rings {
            let row = &descriptor[(ch * rings + r) * sectors..(ch * rings + r + 1) * sectors];
            for (s, &v) in row.iter().enumerate() {
                out[s * height + ch * rings + r] = v.clamp(0.0, LEVELS as f32) as u8;
            }
        }
    }
}

/// The rings of a descriptor out to the outermost one holding a code.
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

/// A query made ready for matching: its columns turned by `t/turns` of a sector for each t
/// (`[turn][sector][channel][ring]`, interpolated between neighbouring sectors and scaled by
/// `turns`: exact integers), and its reach.
struct Query {
    turned: Vec<i16>,
    reach: usize,
}

impl Query {
    fn new(descriptor: &[f32], p: &PlusParams) -> Self {
        let (sectors, height, turns) = (p.sectors, p.height(), p.turns);
        let mut columns = vec![0u8; sectors * height];
        columns_of(descriptor, p, &mut columns);
        let mut turned = vec![0i16; turns * sectors * height];
        for t in 0..turns {
            let block = &mut turned[t * sectors * height..(t + 1) * sectors * height];
            for s in 0..sectors {
                let (a, b) =
                    (&columns[s * height..(s + 1) * height], &columns[((s + 1) % sectors) * height..]);
                for (h, o) in block[s * height..(s + 1) * height].iter_mut().enumerate() {
                    *o = ((turns - t) * a[h] as usize + t * b[h] as usize) as i16;
                }
            }
        }
        Query { turned, reach: reach(descriptor, p) }
    }
}

/// One database entry's columns (`[sector][channel][ring]` codes) and reach.
#[derive(Clone, Copy)]
struct Entry<'a> {
    columns: &'a [u8],
    reach: usize,
}

/// The dot product of two column parts, exact (codes below 2^12, at most 200 of them).
#[inline(always)]
fn dot(a: &[i16], b: &[i16]) -> i32 {
    a.iter().zip(b).map(|(&x, &y)| x as i32 * y as i32).sum()
}

/// Per column part (`[sector][channel]`), `1/‖part‖` over the first `reach` rings, 0 for an
/// empty part.
fn inverse_norms(columns: &[i16], p: &PlusParams, reach: usize) -> Vec<f64> {
    columns
        .chunks_exact(p.rings)
        .map(|part| {
            let n = dot(&part[..reach], &part[..reach]);
            if n > 0 { 1.0 / (n as f64).sqrt() } else { 0.0 }
        })
        .collect()
}

/// The distance of a ready query to an entry, in [0, 1], and the yaw of the query relative to
/// it (degrees, [0, 360), counter-clockwise seen from above). Every shift of the unturned
/// query is compared on the relief columns; then, for every turn, the shifts within the
/// search radius of the best one, on both channels (every shift and turn when the radius
/// covers the sectors). Per channel, `1 −` the mean cosine of the columns filled in both over
/// the first `reach` rings, candidate column `b` against query column `(b + shift) mod
/// sectors` (1 for a channel with none filled in both); the channels averaged. The dot
/// products are exact integers: the AVX2 build computes the same sums.
fn distance_to(q: &Query, c: Entry<'_>, p: &PlusParams) -> (f64, f64) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { distance_to_avx2(q, c, p) };
    }
    distance_to_portable(q, c, p)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn distance_to_avx2(q: &Query, c: Entry<'_>, p: &PlusParams) -> (f64, f64) {
    distance_to_portable(q, c, p)
}

#[inline(always)]
fn distance_to_portable(q: &Query, c: Entry<'_>, p: &PlusParams) -> (f64, f64) {
    let (rings, sectors, height) = (p.rings, p.sectors, p.height());
    let block = sectors * height;
    // Compared where both reach; the outermost ring of a cut scan is half empty (shared with
    // the ring beyond): left out.
    let reach = q.reach.min(c.reach).max(1);
    let reach = if reach < rings { (reach - 1).max(1) } else { reach };
    let candidate: Vec<i16> = c.columns.iter().map(|&v| v as i16).collect();
    let inverse_c = inverse_norms(&candidate, p, reach);
    let inverse_q: Vec<Vec<f64>> =
        (0..p.turns).map(|t| inverse_norms(&q.turned[t * block..(t + 1) * block], p, reach)).collect();
    // Per channel, the candidate's filled sectors: the only ones a sum can take.
    let filled: [Vec<usize>; CHANNELS] =
        std::array::from_fn(|ch| (0..sectors).filter(|&b| inverse_c[b * CHANNELS + ch] > 0.0).collect());
    // The sums are a function's, not a closure's: a closure is compiled on its own, without
    // `distance_to_avx2`'s features.
    let sides = |t: usize| Sides {
        query: &q.turned[t * block..(t + 1) * block],
        query_inverse: &inverse_q[t],
        candidate: &candidate,
        candidate_inverse: &inverse_c,
        filled: &filled,
    };
    let radius = (0.5 * p.search_ratio * sectors as f64).round() as usize;
    let shifts: Vec<usize> = if 2 * radius + 1 >= sectors {
        (0..sectors).collect()
    } else {
        let mut coarse = (f64::INFINITY, 0usize);
        for shift in 0..sectors {
            let d = mean_cosine_distance(sides(0), p, reach, shift, 1);
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
    let mut best = (f64::INFINITY, 0.0);
    for t in 0..p.turns {
        for &shift in &shifts {
            let d = mean_cosine_distance(sides(t), p, reach, shift, CHANNELS);
            if d < best.0 {
                let yaw = ((shift as f64 + t as f64 / p.turns as f64) * p.sector_degrees()).rem_euclid(360.0);
                best = (d, yaw);
            }
        }
    }
    (best.0.clamp(0.0, 1.0), best.1)
}

/// One query turn's columns and one candidate's, with their inverse norms
/// ([`inverse_norms`]) and the candidate's filled sectors per channel.
struct Sides<'a> {
    query: &'a [i16],
    query_inverse: &'a [f64],
    candidate: &'a [i16],
    candidate_inverse: &'a [f64],
    filled: &'a [Vec<usize>; CHANNELS],
}

/// `1 −` the mean cosine per channel of the query's columns turned by `shift` sectors
/// against the candidate's, over the first `reach` rings, averaged over the first
/// `channels`: candidate column `b` against query column `(b + shift) mod sectors`, in the
/// order of `b`, where both are filled. A function, not a closure, so that it is compiled
/// inside [`distance_to_avx2`] with its features.
#[inline(always)]
fn mean_cosine_distance(
    sides: Sides<'_>,
    p: &PlusParams,
    reach: usize,
    shift: usize,
    channels: usize,
) -> f64 {
    let (rings, sectors, height) = (p.rings, p.sectors, p.height());
    let mut total = 0.0;
    for ch in 0..channels {
        let (mut sum, mut count) = (0.0f64, 0usize);
        for &b in &sides.filled[ch] {
            let a = if b + shift >= sectors { b + shift - sectors } else { b + shift };
            let x = sides.query_inverse[a * CHANNELS + ch];
            if x > 0.0 {
                let y = sides.candidate_inverse[b * CHANNELS + ch];
                let qa = &sides.query[a * height + ch * rings..a * height + ch * rings + reach];
                let cb = &sides.candidate[b * height + ch * rings..b * height + ch * rings + reach];
                sum += dot(qa, cb) as f64 * x * y;
                count += 1;
            }
        }
        total += if count > 0 { 1.0 - sum / count as f64 } else { 1.0 };
    }
    total / channels as f64
}

/// The distance of `query` to `candidate` (both descriptors), in [0, 1] (1 when no column is
/// filled in both), and the yaw of the query relative to the candidate (degrees, [0, 360),
/// counter-clockwise seen from above) that attains it.
pub fn distance(query: &[f32], candidate: &[f32], p: &PlusParams) -> (f64, f64) {
    let mut columns = vec![0u8; p.len()];
    columns_of(candidate, p, &mut columns);
    distance_to(&Query::new(query, p), Entry { columns: &columns, reach: reach(candidate, p) }, p)
}

/// Terms of the shape key: the magnitudes of the first `SHAPE_TERMS` terms of the discrete
/// Fourier transform along the sectors.
const SHAPE_TERMS: usize = 16;

/// The terms per ring of the shape key.
fn shape_terms(p: &PlusParams) -> usize {
    SHAPE_TERMS.min(p.sectors / 2 + 1)
}

fn shape_len(p: &PlusParams) -> usize {
    CHANNELS * p.rings * shape_terms(p)
}

fn profile_len(p: &PlusParams) -> usize {
    2 * CHANNELS * p.rings
}

/// The shape key of a descriptor, independent of the yaw: for each channel and ring, which
/// sectors are filled (1 or 0), and of that, the magnitudes of the first [`SHAPE_TERMS`]
/// Fourier terms along the sectors (a circular shift changes their phases only); each channel
/// scaled to length `1/√2` (all zeros stay zeros). The first term is ScanContext's ring key
/// (the filled share of the ring); the others tell where along the ring the gaps are. Built
/// from what is filled, not from the values, it does not move when fewer returns change them.
fn shape_key(descriptor: &[f32], p: &PlusParams) -> Vec<f32> {
    let (rings, sectors) = (p.rings, p.sectors);
    let terms = shape_terms(p);
    let twiddles: Vec<(f64, f64)> = (0..sectors)
        .map(|m| {
            let angle = std::f64::consts::TAU * m as f64 / sectors as f64;
            (angle.cos(), angle.sin())
        })
        .collect();
    let mut out = Vec::with_capacity(shape_len(p));
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
/// deviation, code by code, of its unit columns (both channels of a sector, each channel's part
/// of unit length scaled by `1/√2`) over the filled sectors — what a sector of this place
/// looks like, whichever sectors are seen. A quarter of the view hidden leaves it nearly as it
/// was, where it moves every term of the shape key.
fn profile_key(descriptor: &[f32], p: &PlusParams) -> Vec<f32> {
    let (rings, sectors, height) = (p.rings, p.sectors, p.height());
    let mut columns = vec![0u8; p.len()];
    columns_of(descriptor, p, &mut columns);
    let (mut mean, mut square) = (vec![0f64; height], vec![0f64; height]);
    let mut n = 0usize;
    let mut unit = vec![0f64; height];
    for column in columns.chunks_exact(height) {
        let mut any = false;
        for ch in 0..CHANNELS {
            let part = &column[ch * rings..(ch + 1) * rings];
            let norm = part.iter().map(|&v| (v as f64).powi(2)).sum::<f64>().sqrt();
            any |= norm > 0.0;
            for (u, &v) in unit[ch * rings..(ch + 1) * rings].iter_mut().zip(part) {
                *u = if norm > 0.0 { v as f64 / norm * std::f64::consts::FRAC_1_SQRT_2 } else { 0.0 };
            }
        }
        if any {
            n += 1;
            for ((m, s), &v) in mean.iter_mut().zip(&mut square).zip(&unit) {
                *m += v;
                *s += v * v;
            }
        }
    }
    let _ = sectors;
    let n = n.max(1) as f64;
    let spread = mean.iter().zip(&square).map(|(m, s)| (s / n - (m / n).powi(2)).max(0.0).sqrt());
    mean.iter().map(|m| m / n).chain(spread).map(|v| v as f32).collect()
}

/// The ring key of a descriptor, independent of the yaw: per ring, the mean height of its
/// cells (empty ones count 0) as a share of [`RING_KEY_SCALE`] (at most 1) — ScanContext's ring
/// key.
fn ring_key(descriptor: &[f32], p: &PlusParams) -> Vec<f32> {
    let (rings, sectors) = (p.rings, p.sectors);
    let heights = &descriptor[(1 - RELIEF) * rings * sectors..(2 - RELIEF) * rings * sectors];
    heights
        .chunks_exact(sectors)
        .map(|row| {
            let sum: f64 = row.iter().map(|&c| (c as f64 / LEVELS).powi(2)).sum();
            (sum / sectors as f64 * HEIGHT_SCALE / RING_KEY_SCALE).min(1.0) as f32
        })
        .collect()
}

/// The mean height (m) of the largest ring key.
const RING_KEY_SCALE: f64 = 16.0;

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

/// Entries the first step of the shape list keeps, per row of the list: their filled shares
/// per ring are nearest the query's.
const COARSE_PER_CANDIDATE: usize = 10;

/// Rows of each key's list, per candidate wanted.
const LIST_PER_CANDIDATE: usize = 4;

/// The constant of the reciprocal-rank fusion: a row's score is `Σ 1 / (FUSION_K + rank)`.
const FUSION_K: f64 = 10.0;

/// Descriptors searched in two steps: candidates by the keys, then those re-ranked by
/// [`distance`]. Three keys rank the entries (the shape key among the entries whose filled
/// shares per ring, its first terms, are nearest the query's; the profile key and the ring key
/// among all entries: exact k-NN over bytes), and the candidates are the best of the rankings
/// fused. Each key misses what another finds: the shape and ring keys the scans with a hidden
/// sector, the profile key places whose sectors look alike in another order. The entries are
/// kept as their code columns (a byte a code), not as descriptors.
pub struct Searcher {
    params: PlusParams,
    /// Entries.
    n: usize,
    /// Every entry's columns and keys, by sections ([`Section`]): owned (and growing), or
    /// mapped from a cache file.
    store: Store,
}

/// The sections of a searcher's buffer, per entry: the code columns (u8), reach (u8); the first
/// pass's keys ([`firsts`]), the shape key and the profile key (each [`quantized`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Section {
    Columns,
    Reach,
    Firsts,
    Shapes,
    Profiles,
}

const SECTIONS: usize = 5;
const ALL_SECTIONS: [Section; SECTIONS] =
    [Section::Columns, Section::Reach, Section::Firsts, Section::Shapes, Section::Profiles];

impl Section {
    /// Bytes per entry.
    fn entry_bytes(self, p: &PlusParams) -> usize {
        match self {
            Section::Columns => p.len(),
            Section::Reach => 1,
            Section::Firsts => FIRSTS * first_width(p),
            Section::Shapes => shape_len(p),
            Section::Profiles => profile_len(p),
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
pub const SEARCHER_LAYOUT: &str = "toporec-plus/height-field-3";

/// Sections start on 64-byte boundaries.
const SECTION_ALIGN: usize = 64;

/// The byte offsets of the sections for `n` entries, and the buffer's length.
fn layout(n: usize, p: &PlusParams) -> ([usize; SECTIONS], usize) {
    let mut offsets = [0; SECTIONS];
    let mut at = 0;
    for (o, section) in offsets.iter_mut().zip(ALL_SECTIONS) {
        *o = at;
        at = (at + section.bytes_for(n, p)).next_multiple_of(SECTION_ALIGN);
    }
    (offsets, at)
}

/// Bytes a searcher holds per entry (its sections, without their alignment).
pub fn entry_bytes(p: &PlusParams) -> usize {
    ALL_SECTIONS.iter().map(|s| s.entry_bytes(p)).sum()
}

/// A searcher's sections: built in memory (one growing vector each), or mapped from a cache
/// file (read only; the OS pages it in as searches touch it).
enum Store {
    Owned([Vec<u8>; SECTIONS]),
    /// The file's bytes from `body` on, the sections at `offsets` ([`layout`]).
    Mapped {
        map: memmap2::Mmap,
        body: usize,
        offsets: [usize; SECTIONS],
    },
}

/// Key values in [0, 1] as bytes (`round(255 v)`): the narrowing of a search reads a quarter
/// of the memory, and its integer distances are exact and the same on every machine.
fn quantized(values: &[f32]) -> Vec<u8> {
    values.iter().map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect()
}

/// Rows of a block of the first pass's keys. A block holds each key's 8-byte groups
/// group by group, the block's rows side by side (`[key][group][row][8 bytes]`), so that one
/// 32-byte load reads one group of four rows and one sum of absolute differences (`psadbw`)
/// gives their four partial distances.
const BLOCK: usize = 4;

/// Where byte `t` of a row's keys (`width` bytes a key, a multiple of 8) lies in its block.
#[inline(always)]
fn first_offset(t: usize, row_in_block: usize) -> usize {
    (t / 8) * 8 * BLOCK + row_in_block * 8 + t % 8
}

/// Writes `first` (the [`FIRSTS`] keys of one row, in a row) as row `row` of the blocked
/// section `blocks`.
fn put_first(blocks: &mut [u8], row: usize, first: &[u8]) {
    let block = &mut blocks[row / BLOCK * BLOCK * first.len()..][..BLOCK * first.len()];
    for (t, &byte) in first.iter().enumerate() {
        block[first_offset(t, row % BLOCK)] = byte;
    }
}

/// Row `row`'s keys (`row_bytes` bytes) from the blocked section `blocks`.
fn get_first(blocks: &[u8], row: usize, row_bytes: usize) -> Vec<u8> {
    let block = &blocks[row / BLOCK * BLOCK * row_bytes..][..BLOCK * row_bytes];
    (0..row_bytes).map(|t| block[first_offset(t, row % BLOCK)]).collect()
}

/// For each of the [`FIRSTS`] keys of the `n` rows of `blocks` (blocked, [`BLOCK`]; `width`
/// bytes a key, a multiple of 8), the `m[i]` rows nearest the query's (`FIRSTS × width` bytes,
/// in a row) by the L1 distance (the sum of absolute differences), ties to the lower row, in
/// that order: one pass over the rows.
fn nearest_rows_3(
    blocks: &[u8],
    n: usize,
    query: &[u8],
    width: usize,
    m: [usize; FIRSTS],
    allowed: &dyn Fn(usize) -> bool,
) -> [Vec<usize>; FIRSTS] {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { nearest_rows_3_avx2(blocks, n, query, width, m, allowed) };
    }
    nearest_rows_3_portable(blocks, n, query, width, m, allowed)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn nearest_rows_3_avx2(
    blocks: &[u8],
    n: usize,
    query: &[u8],
    width: usize,
    m: [usize; FIRSTS],
    allowed: &dyn Fn(usize) -> bool,
) -> [Vec<usize>; FIRSTS] {
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

fn nearest_rows_3_portable(
    blocks: &[u8],
    n: usize,
    query: &[u8],
    width: usize,
    m: [usize; FIRSTS],
    allowed: &dyn Fn(usize) -> bool,
) -> [Vec<usize>; FIRSTS] {
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

/// The `m[k]` smallest (distance, row) for each of the [`FIRSTS`] keys among the rows
/// `allowed` admits (asked only of a row that would be kept), ties to the lower row. Each list
/// gathers up to `2 m` keys below its bound, then keeps its `m` smallest (a selection, not a
/// heap: a constant cost per key kept).
struct Nearest<'a> {
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

impl Searcher {
    /// A searcher over `descriptors` (`n × len`, row-major), made ready in place of them.
    pub fn new(descriptors: Vec<f32>, params: PlusParams) -> Self {
        use rayon::prelude::*;
        let p = &params;
        let parts: Vec<[Vec<u8>; SECTIONS]> =
            descriptors.par_chunks_exact(p.len()).map(|d| entry(d, p)).collect();
        drop(descriptors);
        let mut sections: [Vec<u8>; SECTIONS] =
            ALL_SECTIONS.map(|section| Vec::with_capacity(section.bytes_for(parts.len(), p)));
        for (row, part) in parts.iter().enumerate() {
            for ((to, from), section) in sections.iter_mut().zip(part).zip(ALL_SECTIONS) {
                section.append(to, row, from, p);
            }
        }
        Searcher { n: parts.len(), params, store: Store::Owned(sections) }
    }

    /// One more entry, after the others (a mapped searcher is copied into memory first).
    pub fn push(&mut self, descriptor: &[f32]) {
        if let Store::Mapped { .. } = self.store {
            *self = self.subset(&(0..self.n).collect::<Vec<_>>());
        }
        let parts = entry(descriptor, &self.params);
        if let Store::Owned(sections) = &mut self.store {
            for ((to, from), section) in sections.iter_mut().zip(&parts).zip(ALL_SECTIONS) {
                section.append(to, self.n, from, &self.params);
            }
        }
        self.n += 1;
    }

    /// The searcher's bytes, its sections laid out as a cache file's body holds them
    /// (`layout`).
    pub fn bytes(&self) -> std::borrow::Cow<'_, [u8]> {
        let (offsets, total) = layout(self.n, &self.params);
        match &self.store {
            Store::Mapped { map, body, .. } => std::borrow::Cow::Borrowed(&map[*body..*body + total]),
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

    /// A searcher over the `n` entries laid out in `map` from byte `body` on (a cache file
    /// written from [`Searcher::bytes`]).
    pub fn mapped(map: memmap2::Mmap, body: usize, n: usize, params: PlusParams) -> Result<Self, String> {
        let (offsets, total) = layout(n, &params);
        if map.len() < body + total {
            return Err(format!(
                "{} bytes for {n} entries, {total} expected",
                map.len().saturating_sub(body)
            ));
        }
        Ok(Searcher { params, n, store: Store::Mapped { map, body, offsets } })
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
        Searcher { params: self.params.clone(), n: rows.len(), store: Store::Owned(sections) }
    }

    /// The same entries searched with other search settings (candidates, shift range); the
    /// descriptor settings must be this searcher's.
    pub fn with_search(mut self, candidates: usize, search_ratio: f64) -> Self {
        self.params.candidates = candidates;
        self.params.search_ratio = search_ratio;
        self
    }

    /// One section of every entry.
    fn section(&self, section: Section) -> &[u8] {
        let i = section as usize;
        let len = section.bytes_for(self.n, &self.params);
        match &self.store {
            Store::Owned(sections) => &sections[i][..len],
            Store::Mapped { map, body, offsets } => &map[body + offsets[i]..body + offsets[i] + len],
        }
    }

    /// One section of entry `row`.
    fn entry_section(&self, section: Section, row: usize) -> &[u8] {
        let per = section.entry_bytes(&self.params);
        &self.section(section)[row * per..(row + 1) * per]
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
        let [by_ring, coarse_shape, coarse_profile] = nearest_rows_3(
            self.section(Section::Firsts),
            self.n,
            &first,
            first_width(p),
            [long, COARSE_PER_CANDIDATE * long, COARSE_PER_CANDIDATE * long],
            allowed,
        );
        let refined = |section: Section, key: &[u8], mut coarse: Vec<usize>| -> Vec<usize> {
            let all = self.section(section);
            let entry = |row: usize| &all[row * key.len()..(row + 1) * key.len()];
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

    /// The `k` best rows for `query`, by (distance, row), with the time of each step.
    pub fn search(&self, query: &[f32], k: usize) -> (Vec<PlusHit>, SearchTimes) {
        self.search_where(query, k, &|_| true)
    }

    /// The `k` best rows for `query` among those `allowed` admits, by (distance, row), with the
    /// time of each step: the rows and distances a searcher of those rows alone would give.
    pub fn search_where(
        &self,
        query: &[f32],
        k: usize,
        allowed: &dyn Fn(usize) -> bool,
    ) -> (Vec<PlusHit>, SearchTimes) {
        let p = &self.params;
        let t = std::time::Instant::now();
        let wanted = p.candidates.max(k);
        // With no more allowed rows than wanted, the keys' lists hold them all.
        let rows = if wanted >= self.len() {
            (0..self.len()).filter(|&row| allowed(row)).collect()
        } else {
            self.candidates(query, wanted, allowed)
        };
        let candidates_secs = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let q = Query::new(query, p);
        let mut hits: Vec<PlusHit> = rows
            .into_iter()
            .map(|row| {
                let (d, yaw) = distance_to(&q, self.entry(row), p);
                (row, d, yaw)
            })
            .collect();
        hits.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        hits.truncate(k);
        (hits, SearchTimes { candidates: candidates_secs, rerank: t.elapsed().as_secs_f64() })
    }
}

/// The sections' bytes of one entry.
fn entry(d: &[f32], p: &PlusParams) -> [Vec<u8>; SECTIONS] {
    let mut columns = vec![0u8; p.len()];
    columns_of(d, p, &mut columns);
    let (shape, profile) = (quantized(&shape_key(d, p)), quantized(&profile_key(d, p)));
    let first = firsts(&shape, &profile, &quantized(&ring_key(d, p)), p);
    [columns, vec![reach(d, p) as u8], first, shape, profile]
}

/// Rows ahead whose bytes a scan of scattered rows asks for.
const PREFETCH_ROWS: usize = 8;

/// Asks for `bytes` to be brought into the cache; a hint, with no effect on results.
#[inline(always)]
fn prefetch(bytes: &[u8]) {
    #[cfg(target_arch = "x86_64")]
    for line in bytes.chunks(64) {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: prefetching reads nothing and cannot fault; the address is within `bytes`.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(line.as_ptr() as *const i8) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = bytes;
}

/// Keys of the first pass, each `rings` bytes.
const FIRSTS: usize = 3;

/// The first pass's keys of an entry, `rings` bytes each: its ring key, the filled shares per
/// ring of its relief channel (the shape key's terms of order 0), and the mean of its unit
/// relief columns (the profile key's first part).
fn firsts(shape: &[u8], profile: &[u8], ring: &[u8], p: &PlusParams) -> Vec<u8> {
    let shares: Vec<u8> = shape[RELIEF * p.rings * shape_terms(p)..(RELIEF + 1) * p.rings * shape_terms(p)]
        .iter()
        .step_by(shape_terms(p))
        .copied()
        .collect();
    let means = &profile[RELIEF * p.rings..(RELIEF + 1) * p.rings];
    let mut out = vec![0u8; FIRSTS * first_width(p)];
    for (k, key) in [ring, &shares, means].into_iter().enumerate() {
        out[k * first_width(p)..k * first_width(p) + p.rings].copy_from_slice(key);
    }
    out
}

/// Bytes of each first-pass key: `rings`, zero-padded to a multiple of 8.
fn first_width(p: &PlusParams) -> usize {
    p.rings.next_multiple_of(8)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Box walls around the sensor, sampled every 20 cm with a few centimetres of noise (in
    /// general position: no two squares at the same height).
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
    fn relief_is_the_height_above_where_the_class_dies() {
        // One row of 1 m squares: peak A (5 m), a saddle (2 m), peak B (4 m), a foot (1 m),
        // in x order A S B D. Heights enter A, B, S, D: B is born apart from A, and S joins
        // them, so B (the younger, lower peak) dies at 2 m; S and D join A's class, which
        // never dies and ends at the lowest square (1 m). Relief: A 5 − 1 = 4 (its
        // persistence), B 4 − 2 = 2 (its persistence), S 2 − 1 = 1, D 1 − 1 = 0.
        let p = PlusParams { cell: 1.0, max_radius: 10.0, ..PlusParams::default() };
        let points = [[0.5, 0.5, 5.0], [1.5, 0.5, 2.0], [2.5, 0.5, 4.0], [3.5, 0.5, 1.0]];
        let field = height_field(&points, &p);
        let (order, relief) = field.relief();
        let at = |x: f64| {
            let k =
                order.iter().position(|&k| (field.centre(k as usize, p.cell).0 - x).abs() < 1e-9).unwrap();
            relief[k]
        };
        assert_eq!([at(0.5), at(1.5), at(2.5), at(3.5)], [4.0, 1.0, 2.0, 0.0]);
        // Two returns above one square: the height channel holds its highest, 5 m + 2 m, as the
        // code round(255 · √(7 / 64)) = round(84.33) = 84; the relief channel the square's relief
        // (5 − 5 = 0: its class ends at the lowest square, itself).
        let two = [[0.5, 0.5, 5.0], [0.6, 0.7, 3.0]];
        let d = describe(&two, &p).unwrap();
        let height: Vec<f32> = d[p.rings * p.sectors..].iter().copied().filter(|&v| v > 0.0).collect();
        assert_eq!(height, [84.0]);
        assert!(d[..p.rings * p.sectors].iter().all(|&v| v == 0.0));
    }

    #[test]
    fn a_quarter_turn_is_matched_exactly_and_its_yaw_found() {
        let p = PlusParams::default();
        let a = describe(&scene(), &p).unwrap();
        assert!(a.iter().any(|&v| v > 0.0));
        for q in 1..4 {
            let b = describe(&turned(&scene(), q), &p).unwrap();
            // The descriptor is the original's, its sectors shifted by a quarter.
            for row in 0..2 * p.rings {
                for s in 0..p.sectors {
                    let shifted = (s + q * p.sectors / 4) % p.sectors;
                    assert_eq!(b[row * p.sectors + shifted], a[row * p.sectors + s]);
                }
            }
            let (d, yaw) = distance(&b, &a, &p);
            assert!(d <= 1e-12, "{q} quarter turns: distance {d}");
            assert_eq!(yaw, 90.0 * q as f64, "{q} quarter turns");
        }
    }

    #[test]
    fn keys_do_not_depend_on_quarter_turns_and_an_empty_scan_has_no_descriptor() {
        let p = PlusParams::default();
        let a = describe(&scene(), &p).unwrap();
        let b = describe(&turned(&scene(), 1), &p).unwrap();
        // The yaw-independent keys: shape, profile, ring.
        let key = |d: &[f32]| [shape_key(d, &p), profile_key(d, &p), ring_key(d, &p)].concat();
        let (ka, kb) = (key(&a), key(&b));
        assert_eq!(ka.len(), shape_len(&p) + profile_len(&p) + p.rings);
        for (x, y) in ka.iter().zip(&kb) {
            assert!((x - y).abs() < 1e-6);
        }
        let far = [[100.0, 0.0, 1.0]];
        assert_eq!(describe(&far, &p).unwrap_err(), "no return within 80 m of the sensor");
        assert!(describe(&[], &p).is_err());
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
        let other: Vec<Point> =
            turned(&scene(), 1).into_iter().map(|q| [q[0] * 1.7, q[1] * 0.6, q[2]]).collect();
        let other = describe(&other, &p).unwrap();
        let (d, _) = distance(&cut, &full, &p);
        assert!(d < distance(&cut, &other, &p).0, "{d}");
    }

    #[test]
    fn the_first_pass_is_the_same_on_every_route() {
        // Rows of three keys of `width` codes, many of them at equal distances, in blocks (a
        // partial last block too): the vector route and the portable loop keep the rows that
        // sorting every row by (distance, row) puts first, in that order.
        for (width, n) in [(24usize, 5000usize), (8, 1001), (264, 70)] {
            let mut rng = crate::rng::SplitMix64(3);
            let rows: Vec<Vec<u8>> =
                (0..n).map(|_| (0..FIRSTS * width).map(|_| (rng.next_u64() % 8) as u8).collect()).collect();
            let mut blocks = vec![0u8; n.div_ceil(BLOCK) * BLOCK * FIRSTS * width];
            for (row, first) in rows.iter().enumerate() {
                put_first(&mut blocks, row, first);
                assert_eq!(&get_first(&blocks, row, FIRSTS * width), first);
            }
            let query = rows[17].clone();
            let l1 = |r: usize, k: usize| -> u32 {
                (k * width..(k + 1) * width).map(|t| rows[r][t].abs_diff(query[t]) as u32).sum()
            };
            let m = [30, 300, 7];
            for allowed in [&(|_| true) as &dyn Fn(usize) -> bool, &|row: usize| row % 2 == 1] {
                let fast = nearest_rows_3(&blocks, n, &query, width, m, allowed);
                let plain = nearest_rows_3_portable(&blocks, n, &query, width, m, allowed);
                assert_eq!(fast, plain, "width {width}");
                for k in 0..FIRSTS {
                    let mut sorted: Vec<(u32, usize)> =
                        (0..n).filter(|&r| allowed(r)).map(|r| (l1(r, k), r)).collect();
                    sorted.sort_unstable();
                    let want: Vec<usize> = sorted.into_iter().take(m[k]).map(|(_, r)| r).collect();
                    assert_eq!(fast[k], want, "width {width}, key {k}");
                }
            }
            assert_eq!(nearest_rows_3(&blocks, n, &query, width, m, &|_| true)[0][0], 17);
        }
    }

    #[test]
    fn a_grown_searcher_and_a_restricted_search_equal_a_searcher_of_those_rows() {
        let p = PlusParams { candidates: 3, ..PlusParams::default() };
        let scenes: Vec<Vec<f32>> = (0..12)
            .map(|i| {
                let s: Vec<Point> = scene()
                    .into_iter()
                    .map(|q| [q[0] * (1.0 + 0.05 * i as f64), q[1] - i as f64, q[2]])
                    .collect();
                describe(&s, &p).unwrap()
            })
            .collect();
        let all: Vec<f32> = scenes.concat();
        let built = Searcher::new(all.clone(), p.clone());
        let mut grown = Searcher::new(Vec::new(), p.clone());
        for d in &scenes {
            grown.push(d);
        }
        assert_eq!(grown.bytes(), built.bytes());
        let query = describe(&turned(&scene(), 1), &p).unwrap();
        // Rows 2, 5, 7 and 9 alone: the same hits as a searcher of those rows, renumbered.
        let kept = [2usize, 5, 7, 9];
        let alone = built.subset(&kept);
        let (restricted, _) = grown.search_where(&query, 2, &|row| kept.contains(&row));
        let (only, _) = alone.search(&query, 2);
        let renumbered: Vec<PlusHit> = only.iter().map(|&(row, d, yaw)| (kept[row], d, yaw)).collect();
        assert_eq!(restricted, renumbered);
    }

    #[test]
    fn search_finds_a_turned_scan_and_its_yaw() {
        let p = PlusParams::default();
        let scenes: Vec<Vec<Point>> = (0..6)
            .map(|i| scene().into_iter().map(|q| [q[0] * (1.0 + 0.15 * i as f64), q[1], q[2]]).collect())
            .collect();
        let db: Vec<f32> = scenes.iter().flat_map(|s| describe(s, &p).unwrap()).collect();
        // Every entry re-ranked (more candidates than entries), and two by the keys.
        for candidates in [50, 2] {
            let searcher = Searcher::new(db.clone(), p.clone()).with_search(candidates, 0.1);
            for (i, s) in scenes.iter().enumerate() {
                let q = describe(&turned(s, 2), &p).unwrap();
                let (hits, _) = searcher.search(&q, 1);
                assert_eq!((hits[0].0, hits[0].2), (i, 180.0), "{candidates} candidates");
            }
        }
    }
}
