//! Scan Context++ (Kim, Choi, Kim, *Scan Context++: Structural Place Recognition Robust to
//! Rotation and Lateral Variations in Urban Environments*, IEEE T-RO 2021), as the authors'
//! MATLAB code computes it (`gisbi-kim/scancontext_tro`: `tro2022/scancontext/desc/
//! ptcloud2polarcontextAug.m`, `ptcloud2cartcontext.m`, `sc2invkey.m`, `sc2vkey.m`,
//! `alg/alignUsingSectorKey.m`, `alg/sc_dist_fast.m`, `batch_processor/
//! makeAugmentedExperienceEquiDistTreeMerge.m`). Two contexts, two methods:
//!
//! * **`scancontext-pp`, the polar context (PC).** After a 0.5 m voxel grid and `z +=
//!   lidar_height` (1.9 m), `rings × sectors` bins (20 × 60) over `max_radius` (80 m): a point
//!   at range r = √(x² + y²) and azimuth θ ∈ [0°, 360°) falls in ring ⌊r / (max_radius /
//!   rings)⌋ (points beyond the radius in the last ring) and sector ⌈θ / (360° / sectors)⌉
//!   (sector 1 at θ = 0), counted from 1. A bin holds the largest z of its points when it has
//!   at least `min_points` (5) of them, else 0. **Root-shift augmentation:** the scan is
//!   described again from origins moved by `shift` (2 m): `copies` (3) contexts a scan, the
//!   original then the origins at (0, −shift) and (0, +shift), lateral to the sensor; five
//!   copies add (−shift, −shift) and (+shift, −shift), the reference's order. All are stored,
//!   row by row, copy after copy.
//! * **`scancontext-pp-cart`, the Cartesian context (CC).** After the same voxel grid and
//!   height, the points with −x_max < x < x_max and −y_max < y < y_max (x and y both nonzero)
//!   fall in `⌊(x + x_max) / x_unit⌋ × ⌊(y + y_max) / y_unit⌋` bins, 40 × 40 at the defaults
//!   (5 m along the heading × 2 m across, to 100 m ahead and behind and 40 m each side); a bin
//!   holds the largest z of its points, never below 0.
//!
//! Search, for both: the ring key (each row's mean) finds `candidates` (50) by Euclidean
//! distance; each candidate is then compared by ScanContext's distance: `1 −` the mean cosine
//! of the columns both contexts fill, over the column shifts within `round(search_ratio ·
//! columns / 2)` of the shift that best aligns the sector keys (each column's mean). For the
//! polar context the query's own context is compared with each of the candidate's copies,
//! their keys included, and the best copy counts; the shift is a yaw. For the Cartesian
//! context a column shift is a lateral move (`y_unit` a column); with `reverse` the query is
//! also compared turned by 180° (rows and columns reversed), the paper's answer to revisits
//! driven the other way, and the yaw is 0° or 180°.
//!
//! Where toporec departs from the reference code: `sc_dist_fast.m` shifts the query by the
//! sector-key alignment with the opposite sign and accumulates every shift tried onto the
//! previous one; toporec tries each shift around the alignment from the unshifted query, as
//! the paper describes and as its ScanContext does. `ptcloud2cartcontext.m` bins x as
//! `sign(x) · ⌊|x| / x_unit⌋ + ⌊num_x / 2⌋ + 1`, which folds (−x_unit, x_unit) into one bin
//! twice as wide and leaves the first bin empty; toporec bins evenly, as the paper's grid. A
//! point exactly at an origin has no azimuth (0/0): the MATLAB code skips it, as toporec
//! does. When no column is filled in both contexts the MATLAB distance is 0/0; toporec's is 1.

use super::Computed;
use super::scancontext::{self, ScanContextParams};
use super::searcher::{Allowed, Hit, SearchBudget, SearchTimes, timed};
use crate::types::Point;

/// The name of Scan Context++'s polar context.
pub(crate) const POLAR: &str = "scancontext-pp";
/// The name of Scan Context++'s Cartesian context.
pub(crate) const CARTESIAN: &str = "scancontext-pp-cart";

/// Scan Context++ polar-context settings (`[scancontext-pp]` of a pipeline file).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PolarParams {
    /// Rings (radial bins).
    pub rings: usize,
    /// Sectors (azimuthal bins).
    pub sectors: usize,
    /// Radius of the described disc (m); farther points fall in the last ring.
    pub max_radius: f64,
    /// Added to every z (m): the sensor's height above the ground.
    pub lidar_height: f64,
    /// A bin with fewer points is empty (0).
    pub min_points: usize,
    /// Contexts stored a scan: 1 (the scan's own), 3 (and its origin moved `shift` to either
    /// side) or 5 (and two more, behind on either side).
    pub copies: usize,
    /// How far the augmented origins are moved (m).
    pub shift: f64,
    /// Candidates taken by the ring key before the re-rank (at least the k asked for).
    pub candidates: usize,
    /// Shifts tried around the sector-key alignment: `round(search_ratio · sectors / 2)` each
    /// side.
    pub search_ratio: f64,
    /// Voxel-grid cell of the preprocessing (m); none when 0.
    pub voxel: f64,
}

impl Default for PolarParams {
    fn default() -> Self {
        PolarParams {
            rings: 20,
            sectors: 60,
            max_radius: 80.0,
            lidar_height: 1.9,
            min_points: 5,
            copies: 3,
            shift: 2.0,
            candidates: 50,
            search_ratio: 0.1,
            voxel: 0.5,
        }
    }
}

/// Scan Context++ Cartesian-context settings (`[scancontext-pp-cart]` of a pipeline file).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CartParams {
    /// Half the length described along the heading (x, m).
    pub x_max: f64,
    /// Half the width described across the heading (y, m).
    pub y_max: f64,
    /// Bin length along the heading (m).
    pub x_unit: f64,
    /// Bin width across the heading (m); one column shift is a lateral move of this much.
    pub y_unit: f64,
    /// Added to every z (m): the sensor's height above the ground.
    pub lidar_height: f64,
    /// Whether the query is also compared turned by 180° (revisits driven the other way).
    pub reverse: bool,
    /// Candidates taken by the row key before the re-rank (at least the k asked for).
    pub candidates: usize,
    /// Column shifts tried around the column-key alignment: `round(search_ratio · columns /
    /// 2)` each side.
    pub search_ratio: f64,
    /// Voxel-grid cell of the preprocessing (m); none when 0.
    pub voxel: f64,
}

impl Default for CartParams {
    fn default() -> Self {
        CartParams {
            x_max: 100.0,
            y_max: 40.0,
            x_unit: 5.0,
            y_unit: 2.0,
            lidar_height: 1.9,
            reverse: true,
            candidates: 50,
            search_ratio: 0.1,
            voxel: 0.5,
        }
    }
}

fn common_problems(name: &str, candidates: usize, search_ratio: f64, voxel: f64, height: f64) -> Vec<String> {
    let mut out = Vec::new();
    if candidates == 0 {
        out.push(format!("{name}.candidates: must be in [1, inf)"));
    }
    if !(0.0..=1.0).contains(&search_ratio) {
        out.push(format!("{name}.search_ratio: must be in [0, 1]; found {search_ratio}"));
    }
    if !(voxel.is_finite() && voxel >= 0.0) {
        out.push(format!("{name}.voxel: must be in [0, inf) m; found {voxel}"));
    }
    if !height.is_finite() {
        out.push(format!("{name}.lidar_height: must be finite; found {height}"));
    }
    out
}

impl PolarParams {
    /// One context's values: rings × sectors.
    pub fn context_len(&self) -> usize {
        self.rings * self.sectors
    }

    /// The augmented origins (x, y), in the reference's order, the sensor's own first.
    pub fn origins(&self) -> Vec<(f64, f64)> {
        let s = self.shift;
        [(0.0, 0.0), (0.0, -s), (0.0, s), (-s, -s), (s, -s)][..self.copies].to_vec()
    }
}

impl CartParams {
    /// Bins along the heading: `round(2 · x_max / x_unit)`.
    pub fn rows(&self) -> usize {
        (2.0 * self.x_max / self.x_unit).round().max(0.0) as usize
    }

    /// Bins across the heading: `round(2 · y_max / y_unit)`.
    pub fn columns(&self) -> usize {
        (2.0 * self.y_max / self.y_unit).round().max(0.0) as usize
    }
}

/// The points a context describes: on the voxel grid (none when `voxel` is 0).
fn preprocess(points: &[Point], voxel: f64) -> Vec<Point> {
    if voxel > 0.0 { crate::preprocess::voxel_grid(points, voxel) } else { points.to_vec() }
}

/// The polar context of points already preprocessed, seen from `origin`: `rings × sectors`
/// values, row by row.
fn polar_context(points: &[Point], origin: (f64, f64), p: &PolarParams) -> Vec<f32> {
    let (rings, sectors) = (p.rings, p.sectors);
    let gap = p.max_radius / rings as f64;
    let sector_angle = 360.0 / sectors as f64;
    let mut top = vec![f64::NEG_INFINITY; rings * sectors];
    let mut count = vec![0usize; rings * sectors];
    for q in points {
        let (x, y, z) = (q[0] - origin.0, q[1] - origin.1, q[2] + p.lidar_height);
        if x == 0.0 && y == 0.0 {
            continue;
        }
        let r = (x * x + y * y).sqrt();
        let ring = ((r / gap).floor() as usize).min(rings - 1);
        let sector =
            ((scancontext::azimuth_degrees(x, y) / sector_angle).ceil() as usize).clamp(1, sectors) - 1;
        let bin = ring * sectors + sector;
        count[bin] += 1;
        top[bin] = top[bin].max(z);
    }
    top.iter().zip(&count).map(|(&z, &n)| if n >= p.min_points.max(1) { z as f32 } else { 0.0 }).collect()
}

/// The polar descriptor of a raw scan (sensor frame, metres): its `copies` contexts.
pub fn describe_polar(points: &[Point], p: &PolarParams) -> Vec<f32> {
    let grid = preprocess(points, p.voxel);
    p.origins().into_iter().flat_map(|o| polar_context(&grid, o, p)).collect()
}

/// The Cartesian context of a raw scan (sensor frame, metres): rows (along the heading, from
/// −x_max) × columns (across it, from −y_max), row by row.
pub fn describe_cart(points: &[Point], p: &CartParams) -> Vec<f32> {
    let (rows, columns) = (p.rows(), p.columns());
    let mut img = vec![0.0f64; rows * columns];
    for q in preprocess(points, p.voxel) {
        let (x, y, z) = (q[0], q[1], q[2] + p.lidar_height);
        if x == 0.0 || y == 0.0 || x.abs() >= p.x_max || y.abs() >= p.y_max {
            continue;
        }
        let row = (((x + p.x_max) / p.x_unit).floor() as usize).min(rows - 1);
        let column = (((y + p.y_max) / p.y_unit).floor() as usize).min(columns - 1);
        let b = &mut img[row * columns + column];
        *b = b.max(z);
    }
    img.into_iter().map(|v| v as f32).collect()
}

/// A context's row means (the ring key of the polar context; across the heading for the
/// Cartesian one, where it does not change with a lateral move).
pub fn row_key(context: &[f32], columns: usize) -> Vec<f32> {
    scancontext::ring_key(context, &shape(context.len() / columns, columns, 0.0))
}

/// ScanContext's settings for a context of this shape: its distance and key functions apply.
fn shape(rows: usize, columns: usize, search_ratio: f64) -> ScanContextParams {
    ScanContextParams { rings: rows, sectors: columns, search_ratio, ..ScanContextParams::default() }
}

/// A context turned by 180° about z: rows and columns reversed.
fn turned_round(context: &[f32]) -> Vec<f32> {
    context.iter().rev().copied().collect()
}

/// Either context's settings, as one searcher takes them.
#[derive(Clone, Debug, PartialEq)]
pub enum Variant {
    /// The polar context with its augmented copies.
    Polar(PolarParams),
    /// The Cartesian context.
    Cart(CartParams),
}

impl Variant {
    /// Descriptor length.
    pub fn len(&self) -> usize {
        match self {
            Variant::Polar(p) => p.len(),
            Variant::Cart(p) => p.len(),
        }
    }

    /// Whether the descriptor is empty (never, for valid settings).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Candidates before the re-rank.
    pub fn candidates(&self) -> usize {
        match self {
            Variant::Polar(p) => p.candidates,
            Variant::Cart(p) => p.candidates,
        }
    }

    /// Contexts stored a scan.
    fn copies(&self) -> usize {
        match self {
            Variant::Polar(p) => p.copies,
            Variant::Cart(_) => 1,
        }
    }

    /// Rows and columns of one context.
    fn grid(&self) -> (usize, usize) {
        match self {
            Variant::Polar(p) => (p.rings, p.sectors),
            Variant::Cart(p) => (p.rows(), p.columns()),
        }
    }

    /// The contexts a stored descriptor is compared by (the polar copies; the one Cartesian
    /// context).
    fn stored<'a>(&self, descriptor: &'a [f32]) -> impl Iterator<Item = &'a [f32]> {
        let (rows, columns) = self.grid();
        descriptor.chunks_exact(rows * columns)
    }

    /// The contexts a query is compared with, each with the yaw it stands for beyond the
    /// shift: the polar query's own (0°); the Cartesian query's as it is (0°) and, with
    /// `reverse`, turned round (180°).
    fn probes(&self, query: &[f32]) -> Vec<(Vec<f32>, bool)> {
        let (rows, columns) = self.grid();
        let own = query[..rows * columns].to_vec();
        match self {
            Variant::Cart(p) if p.reverse => {
                let round = turned_round(&own);
                vec![(own, false), (round, true)]
            }
            _ => vec![(own, false)],
        }
    }
}

/// A Scan Context++ comparison: the distance, the column shift that attains it, and whether
/// the query was turned round (the Cartesian context's reverse check).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Match {
    /// `1 −` the mean column cosine at the best shift (1 when no column is filled in both).
    pub distance: f64,
    /// The column shift: the candidate's column `c` lines up with the query's `(c + shift) mod
    /// columns`.
    pub shift: usize,
    /// Whether the query was turned by 180° (Cartesian context only).
    pub reversed: bool,
}

impl Match {
    /// The yaw of the query relative to the candidate (degrees, [0, 360)): the polar shift's
    /// angle, or 0° / 180° for the Cartesian context.
    pub fn yaw_degrees(&self, v: &Variant) -> f64 {
        match v {
            Variant::Polar(p) => self.shift as f64 * 360.0 / p.sectors as f64,
            Variant::Cart(_) if self.reversed => 180.0,
            Variant::Cart(_) => 0.0,
        }
    }
}

/// The Scan Context++ distance of a query descriptor to a stored one: the best, over the
/// query's probes and the stored contexts, of ScanContext's distance around the sector-key
/// alignment (ties to the first probe, then the first copy, then the lowest shift).
pub fn compare(query: &[f32], candidate: &[f32], v: &Variant) -> Match {
    compare_probes(&v.probes(query), candidate, v)
}

/// [`compare`] with the query's probes made once ([`Variant::probes`]), for a search that
/// compares one query with many candidates.
fn compare_probes(probes: &[(Vec<f32>, bool)], candidate: &[f32], v: &Variant) -> Match {
    let (rows, columns) = v.grid();
    let ratio = match v {
        Variant::Polar(p) => p.search_ratio,
        Variant::Cart(p) => p.search_ratio,
    };
    let sc = shape(rows, columns, ratio);
    let mut best = Match { distance: f64::INFINITY, shift: 0, reversed: false };
    for (probe, reversed) in probes {
        for context in v.stored(candidate) {
            let (distance, shift) = scancontext::distance(probe, context, &sc);
            if distance < best.distance {
                best = Match { distance, shift, reversed: *reversed };
            }
        }
    }
    best
}

/// The squared Euclidean distance of two keys in float32, summed in eight lanes (so that it
/// vectorizes).
fn squared_distance(a: &[f32], b: &[f32]) -> f32 {
    let mut lanes = [0.0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca.remainder().iter().zip(cb.remainder()).map(|(&x, &y)| (x - y) * (x - y)).sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..8 {
            lanes[i] += (x[i] - y[i]) * (x[i] - y[i]);
        }
    }
    lanes.iter().sum::<f32>() + tail
}

/// Scan Context++ descriptors searched as the reference does: the rows whose keys lie
/// nearest the query's (Euclidean, in float32; the nearest of a row's copies, or of the
/// query's probes) are the candidates, re-ranked by [`compare`]. It grows by [`super::Searcher::push`].
pub struct Searcher {
    variant: Variant,
    descriptors: Vec<f32>,
    /// Each row's keys, one per stored context, `rows_per_context` values each.
    keys: Vec<f32>,
}

impl Searcher {
    /// A searcher over `descriptors` (row-major, `variant.len()` a row).
    pub fn new(descriptors: Vec<f32>, variant: Variant) -> Self {
        let mut s = Searcher { variant, descriptors: Vec::new(), keys: Vec::new() };
        for d in descriptors.chunks_exact(s.variant.len()) {
            super::Searcher::push(&mut s, d);
        }
        s
    }

    /// The settings.
    pub fn variant(&self) -> &Variant {
        &self.variant
    }

    /// The `k` best rows for `query` (among those `allowed` admits), by (distance, row).
    pub fn ranked(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> Vec<Hit> {
        let wanted = self.variant.candidates().max(k);
        if k == 0 {
            return Vec::new();
        }
        let (rows, columns) = self.variant.grid();
        let per_row = self.variant.copies() * rows;
        let probes = self.variant.probes(query);
        let probe_keys: Vec<Vec<f32>> = probes.iter().map(|(c, _)| row_key(c, columns)).collect();
        // Squared key distances in float32, each row's nearest copy against the nearest probe:
        // a tight loop the compiler vectorizes (candidates only; the re-rank is in float64).
        let mut by_key: Vec<(usize, f64)> = Vec::with_capacity(self.descriptors.len() / self.variant.len());
        for (r, keys) in self.keys.chunks_exact(per_row).enumerate() {
            if !allowed.is_none_or(|a| a(r)) {
                continue;
            }
            let mut d = f32::INFINITY;
            for key in keys.chunks_exact(rows) {
                for pk in &probe_keys {
                    d = d.min(squared_distance(pk, key));
                }
            }
            by_key.push((r, d as f64));
        }
        let order = |a: &(usize, f64), b: &(usize, f64)| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0));
        if by_key.len() > wanted {
            by_key.select_nth_unstable_by(wanted - 1, order);
            by_key.truncate(wanted);
        }
        let len = self.variant.len();
        let mut hits: Vec<(usize, Match)> = by_key
            .into_iter()
            .map(|(r, _)| {
                (r, compare_probes(&probes, &self.descriptors[r * len..(r + 1) * len], &self.variant))
            })
            .collect();
        hits.sort_by(|a, b| a.1.distance.total_cmp(&b.1.distance).then(a.0.cmp(&b.0)));
        hits.truncate(k);
        hits.into_iter().map(|(r, m)| Hit::turned(r, m.distance, m.yaw_degrees(&self.variant))).collect()
    }
}

impl super::Searcher for Searcher {
    /// Rows.
    fn len(&self) -> usize {
        self.descriptors.len() / self.variant.len().max(1)
    }

    /// One more row.
    fn push(&mut self, descriptor: &[f32]) {
        let (_, columns) = self.variant.grid();
        self.descriptors.extend_from_slice(descriptor);
        for context in self.variant.stored(descriptor) {
            self.keys.extend(row_key(context, columns));
        }
    }

    fn search(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> (Vec<Hit>, SearchTimes) {
        timed(|| self.ranked(query, k, allowed))
    }

    fn set_budget(&mut self, budget: SearchBudget, entries: usize) {
        match &mut self.variant {
            Variant::Polar(p) => {
                if let Some(s) = budget.candidates_and_ratio(p.sectors, entries) {
                    (p.candidates, p.search_ratio) = s;
                }
            }
            Variant::Cart(p) => {
                if let Some(s) = budget.candidates_and_ratio(p.columns(), entries) {
                    (p.candidates, p.search_ratio) = s;
                }
            }
        }
    }
}

impl super::Named for PolarParams {
    const NAME: &'static str = POLAR;
}

impl super::Computed for PolarParams {
    /// The settings' problems, each with its key.
    fn problems(&self) -> Vec<String> {
        let name = POLAR;
        let mut out =
            common_problems(name, self.candidates, self.search_ratio, self.voxel, self.lidar_height);
        out.extend(scancontext::polar_grid_problems(name, self.rings, self.sectors, self.max_radius));
        if ![1, 3, 5].contains(&self.copies) {
            out.push(format!("{name}.copies: must be 1, 3 or 5; found {}", self.copies));
        }
        if !(self.shift.is_finite() && self.shift >= 0.0) {
            out.push(format!("{name}.shift: must be in [0, inf) m; found {}", self.shift));
        }
        out
    }

    /// Descriptor length: copies × rings × sectors.
    fn len(&self) -> usize {
        self.copies * self.context_len()
    }

    fn describe(&self, points: &[Point]) -> Result<Vec<f32>, String> {
        Ok(describe_polar(points, self))
    }

    fn searcher(&self, descriptors: Vec<f32>) -> Box<dyn super::Searcher> {
        Box::new(Searcher::new(descriptors, Variant::Polar(self.clone())))
    }
}

impl super::Named for CartParams {
    const NAME: &'static str = CARTESIAN;
}

impl super::Computed for CartParams {
    /// The settings' problems, each with its key.
    fn problems(&self) -> Vec<String> {
        let name = CARTESIAN;
        let mut out =
            common_problems(name, self.candidates, self.search_ratio, self.voxel, self.lidar_height);
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !(positive(self.x_max) && positive(self.y_max) && positive(self.x_unit) && positive(self.y_unit)) {
            out.push(format!(
                "{name}: x_max, y_max, x_unit and y_unit must be in (0, inf) m (found {}, {}, {}, {})",
                self.x_max, self.y_max, self.x_unit, self.y_unit
            ));
        } else if !(1..=1000).contains(&self.rows()) || !(1..=1000).contains(&self.columns()) {
            out.push(format!(
                "{name}: need 1 to 1000 bins each way (found {} × {})",
                self.rows(),
                self.columns()
            ));
        }
        out
    }

    /// Descriptor length: rows × columns.
    fn len(&self) -> usize {
        self.rows() * self.columns()
    }

    fn describe(&self, points: &[Point]) -> Result<Vec<f32>, String> {
        Ok(describe_cart(points, self))
    }

    fn searcher(&self, descriptors: Vec<f32>) -> Box<dyn super::Searcher> {
        Box::new(Searcher::new(descriptors, Variant::Cart(self.clone())))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cartesian_bins_are_even_across_zero() {
        // The reference folds (−5, 5) m into one bin; toporec's bins are each 5 m long.
        let p = CartParams { voxel: 0.0, lidar_height: 0.0, ..CartParams::default() };
        let at = |x: f64| {
            let img = describe_cart(&[[x, 1.0, 3.0]], &p);
            img.iter().position(|&v| v > 0.0).map(|i| i / p.columns())
        };
        assert_eq!((at(-1.0), at(1.0), at(-99.0), at(99.9)), (Some(19), Some(20), Some(0), Some(39)));
        assert_eq!(at(100.0), None);
    }

    #[test]
    fn the_searcher_finds_what_compare_ranks_first() {
        let p = PolarParams { rings: 4, sectors: 8, copies: 3, candidates: 100, ..PolarParams::default() };
        let v = Variant::Polar(p.clone());
        let mut rng = crate::rng::SplitMix64(5);
        let db: Vec<f32> = (0..40 * p.len()).map(|_| (rng.next_f64() * 4.0).floor() as f32).collect();
        let s = Searcher::new(db.clone(), v.clone());
        let q = &db[7 * p.len()..8 * p.len()];
        let hits = s.ranked(q, 3, None);
        assert_eq!(hits[0].row, 7);
        assert_eq!(hits[0].distance, 0.0);
        let mut exact: Vec<(usize, f64)> =
            (0..40).map(|r| (r, compare(q, &db[r * p.len()..(r + 1) * p.len()], &v).distance)).collect();
        exact.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        assert_eq!(hits.iter().map(|h| (h.row, h.distance)).collect::<Vec<_>>(), exact[..3]);
        assert!(s.ranked(q, 3, Some(&|r| r != 7)).iter().all(|h| h.row != 7));
    }
}
