//! ScanContext (Kim & Kim, IROS 2018), as the authors' C++ implementation computes it
//! (`irapkaist/scancontext`, `Scancontext.cpp`; the same in `gisbi-kim/SC-A-LOAM`).
//!
//! * The descriptor: `rings × sectors` bins (20 × 60) over a disc of `max_radius` (80 m) around
//!   the sensor; a point at range r = √(x² + y²) and azimuth θ ∈ [0°, 360°) falls in ring
//!   ⌈r / max_radius · rings⌉ and sector ⌈θ / 360° · sectors⌉ (both clamped to 1..); points
//!   beyond `max_radius` are left out. A bin holds the largest `z + lidar_height` (2 m) of its
//!   points, 0 when it has none. Stored row by row (ring-major), as float32.
//! * The ring key (one mean per ring) finds candidates in a k-d tree; the sector key (one mean
//!   per sector) aligns a pair coarsely; the distance is `1 −` the mean cosine similarity of the
//!   columns both scans fill, minimised over the shifts within `search_ratio · sectors / 2` of
//!   the coarse one. The best shift gives the yaw between the scans: `shift · 360° / sectors`.
//!
//! Where the references differ: the MATLAB and Python versions bin points beyond the range into
//! the last ring, keep bins of fewer than 5 points empty (MATLAB), take the raw height (MATLAB)
//! or clip negative heights to 0 (Python), and try all 60 shifts. toporec follows the C++ code,
//! which SC-A-LOAM and most systems deploy. The input is expected pre-downsampled (the paper: a
//! 0.5 m voxel grid), which the method's preprocessing does.

use super::Computed;
use super::euclidean::Euclidean;
use super::searcher::{Allowed, Hit, SearchBudget, SearchTimes};
use crate::types::Point;

/// The method's name.
pub(crate) const NAME: &str = "scancontext";

/// ScanContext settings (`[scancontext]` of a pipeline file).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScanContextParams {
    /// Rings (radial bins).
    pub rings: usize,
    /// Sectors (azimuthal bins).
    pub sectors: usize,
    /// Radius of the described disc (m).
    pub max_radius: f64,
    /// Added to every z (m): the sensor's height above the ground.
    pub lidar_height: f64,
    /// Candidates taken from the ring-key tree before the re-rank (at least the k asked for).
    pub candidates: usize,
    /// Shifts tried around the coarse alignment: `round(search_ratio · sectors / 2)` each side.
    pub search_ratio: f64,
    /// Voxel-grid cell of the preprocessing (m); none when 0.
    pub voxel: f64,
}

impl Default for ScanContextParams {
    fn default() -> Self {
        ScanContextParams {
            rings: 20,
            sectors: 60,
            max_radius: 80.0,
            lidar_height: 2.0,
            candidates: 10,
            search_ratio: 0.1,
            voxel: 0.5,
        }
    }
}

impl ScanContextParams {}

/// The bin value of an empty bin while filling (the C++ `NO_POINT`).
const NO_POINT: f64 = -1000.0;

/// The azimuth of (x, y) in degrees, [0, 360), as the C++ `xy2theta` (quadrant-wise atan;
/// SOLiD's references use the same function).
pub(crate) fn azimuth_degrees(x: f64, y: f64) -> f64 {
    let deg = |r: f64| r.to_degrees();
    if x >= 0.0 && y >= 0.0 {
        deg((y / x).atan())
    } else if x < 0.0 && y >= 0.0 {
        180.0 - deg((y / -x).atan())
    } else if x < 0.0 && y < 0.0 {
        180.0 + deg((y / x).atan())
    } else {
        360.0 - deg((-y / x).atan())
    }
}

/// The ScanContext of a cloud in the sensor frame (metres, z up): `rings × sectors` values,
/// row by row.
pub fn describe(points: &[Point], p: &ScanContextParams) -> Vec<f32> {
    let (rings, sectors) = (p.rings, p.sectors);
    let mut bins = vec![NO_POINT; rings * sectors];
    for q in points {
        let (x, y, z) = (q[0], q[1], q[2] + p.lidar_height);
        let r = (x * x + y * y).sqrt();
        if r > p.max_radius {
            continue;
        }
        // At the origin the C++ atan is 0/0; such a point is in the first sector.
        let theta = if r == 0.0 { 0.0 } else { azimuth_degrees(x, y) };
        let ring = ((r / p.max_radius * rings as f64).ceil() as usize).clamp(1, rings);
        let sector = ((theta / 360.0 * sectors as f64).ceil() as usize).clamp(1, sectors);
        let b = &mut bins[(ring - 1) * sectors + sector - 1];
        if z > *b {
            *b = z;
        }
    }
    bins.into_iter().map(|v| if v == NO_POINT { 0.0 } else { v as f32 }).collect()
}

/// The ring key: the mean of each ring (row).
pub fn ring_key(sc: &[f32], p: &ScanContextParams) -> Vec<f32> {
    sc.chunks_exact(p.sectors)
        .map(|row| (row.iter().map(|&v| v as f64).sum::<f64>() / p.sectors as f64) as f32)
        .collect()
}

/// The sector key: the mean of each sector (column).
pub fn sector_key(sc: &[f32], p: &ScanContextParams) -> Vec<f64> {
    (0..p.sectors)
        .map(|c| (0..p.rings).map(|r| sc[r * p.sectors + c] as f64).sum::<f64>() / p.rings as f64)
        .collect()
}

/// Each column's sum of squares (its squared norm), summed over the rings in order.
fn column_norms2(sc: &[f32], p: &ScanContextParams) -> Vec<f64> {
    let mut out = vec![0.0f64; p.sectors];
    for row in sc.chunks_exact(p.sectors) {
        for (n, &v) in out.iter_mut().zip(row) {
            *n += v as f64 * v as f64;
        }
    }
    out
}

/// `1 −` the mean cosine similarity of the columns both descriptors fill, with `b`'s column
/// `c` compared to `a`'s column `(c + shift) mod sectors` (`b` shifted by `shift`); `None` when
/// no column is filled in both. `na` and `nb` are the columns' squared norms
/// ([`column_norms2`]).
fn direct_distance(
    a: &[f32],
    b: &[f32],
    na: &[f64],
    nb: &[f64],
    shift: usize,
    p: &ScanContextParams,
) -> Option<f64> {
    let (rings, sectors) = (p.rings, p.sectors);
    let (mut sum, mut count) = (0.0, 0usize);
    for c in 0..sectors {
        let ca = (c + shift) % sectors;
        let (na, nb) = (na[ca], nb[c]);
        if na == 0.0 || nb == 0.0 {
            continue;
        }
        let mut dot = 0.0f64;
        for r in 0..rings {
            dot += a[r * sectors + ca] as f64 * b[r * sectors + c] as f64;
        }
        sum += dot / (na.sqrt() * nb.sqrt());
        count += 1;
    }
    (count > 0).then(|| 1.0 - sum / count as f64)
}

/// The ScanContext distance of `query` to `candidate` and the shift that attains it: the
/// candidate's column `c` lines up with the query's column `(c + shift) mod sectors`, so the
/// query is the candidate turned by `shift · 360° / sectors` (counter-clockwise, seen from
/// above). Columns empty in either descriptor are left out; when none is left, the distance is
/// 1 (nothing alike).
pub fn distance(query: &[f32], candidate: &[f32], p: &ScanContextParams) -> (f64, usize) {
    let sectors = p.sectors;
    let (kq, kc) = (sector_key(query, p), sector_key(candidate, p));
    // Coarse: the shift of the candidate's sector key closest to the query's.
    let mut coarse = (f64::INFINITY, 0usize);
    for s in 0..sectors {
        let d: f64 = (0..sectors).map(|c| (kq[(c + s) % sectors] - kc[c]).powi(2)).sum::<f64>();
        if d < coarse.0 {
            coarse = (d, s);
        }
    }
    let radius = (0.5 * p.search_ratio * sectors as f64).round() as usize;
    let mut shifts: Vec<usize> =
        (0..=2 * radius).map(|i| (coarse.1 + sectors + i % sectors - radius % sectors) % sectors).collect();
    shifts.sort_unstable();
    shifts.dedup();
    let (nq, nc) = (column_norms2(query, p), column_norms2(candidate, p));
    let mut best = (f64::INFINITY, coarse.1);
    for s in shifts {
        let d = direct_distance(query, candidate, &nq, &nc, s, p).unwrap_or(1.0);
        if d < best.0 {
            best = (d, s);
        }
    }
    best
}

/// The yaw (degrees, in [0, 360)) that a shift stands for.
pub fn yaw_degrees(shift: usize, p: &ScanContextParams) -> f64 {
    super::searcher::shift_degrees(shift, p.sectors)
}

/// A hit: database row, ScanContext distance, and the column shift that attains it.
pub(crate) type ScHit = (usize, f64, usize);

/// The problems of a polar grid's settings (ScanContext's and Scan Context++'s), each with the
/// method's key.
pub(crate) fn polar_grid_problems(name: &str, rings: usize, sectors: usize, max_radius: f64) -> Vec<String> {
    let mut out = Vec::new();
    if !(1..=1000).contains(&rings) || !(1..=3600).contains(&sectors) {
        out.push(format!(
            "{name}: need rings in [1, 1000] and sectors in [1, 3600] (rings {rings}, sectors {sectors})"
        ));
    }
    if !(max_radius.is_finite() && max_radius > 0.0) {
        out.push(format!("{name}.max_radius: must be in (0, inf) m; found {max_radius}"));
    }
    out
}

/// ScanContexts searched as the reference does: the ring keys' nearest neighbours (exact,
/// Euclidean) are the candidates, re-ranked by the ScanContext distance. For Recall@N the
/// candidates are at least N: `max(candidates, k)`.
pub struct Searcher {
    params: ScanContextParams,
    descriptors: Vec<f32>,
    keys: Euclidean,
}

impl Searcher {
    /// A searcher over `descriptors` (`n × rings·sectors`, row-major).
    pub fn new(descriptors: Vec<f32>, params: ScanContextParams) -> Self {
        let keys: Vec<f32> =
            descriptors.chunks_exact(params.len()).flat_map(|d| ring_key(d, &params)).collect();
        let keys = Euclidean::new(keys, params.rings);
        Searcher { params, descriptors, keys }
    }

    /// The parameters.
    pub fn params(&self) -> &ScanContextParams {
        &self.params
    }

    /// The `k` best rows for `query` (among those `allowed` admits), by (distance, row), each
    /// with its best column shift, and the time of each step.
    pub fn ranked(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> (Vec<ScHit>, SearchTimes) {
        let p = &self.params;
        let t = std::time::Instant::now();
        let wanted = p.candidates.max(k).min(super::Searcher::len(self));
        let candidates = self.keys.nearest(&ring_key(query, p), wanted, allowed);
        let candidates_secs = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let hits = rerank(query, &self.descriptors, candidates.into_iter().map(|(row, _)| row), k, p);
        (hits, SearchTimes { candidates: candidates_secs, rerank: t.elapsed().as_secs_f64() })
    }
}

impl super::Searcher for Searcher {
    fn len(&self) -> usize {
        self.keys.len()
    }

    fn push(&mut self, descriptor: &[f32]) {
        self.descriptors.extend_from_slice(descriptor);
        self.keys.push(&ring_key(descriptor, &self.params));
    }

    fn search(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> (Vec<Hit>, SearchTimes) {
        let (hits, times) = self.ranked(query, k, allowed);
        let hits =
            hits.into_iter().map(|(row, d, shift)| Hit::turned(row, d, yaw_degrees(shift, &self.params)));
        (hits.collect(), times)
    }

    fn set_budget(&mut self, budget: SearchBudget, entries: usize) {
        if let Some((candidates, ratio)) = budget.candidates_and_ratio(self.params.sectors, entries) {
            (self.params.candidates, self.params.search_ratio) = (candidates, ratio);
        }
    }
}

impl super::Named for ScanContextParams {
    const NAME: &'static str = NAME;
}

impl super::Computed for ScanContextParams {
    /// The settings' problems, each with its key.
    fn problems(&self) -> Vec<String> {
        let mut out = polar_grid_problems(NAME, self.rings, self.sectors, self.max_radius);
        if !self.lidar_height.is_finite() {
            out.push(format!("scancontext.lidar_height: must be finite; found {}", self.lidar_height));
        }
        if self.candidates == 0 {
            out.push("scancontext.candidates: must be in [1, inf)".into());
        }
        if !(0.0..=1.0).contains(&self.search_ratio) {
            out.push(format!("scancontext.search_ratio: must be in [0, 1]; found {}", self.search_ratio));
        }
        if !(self.voxel.is_finite() && self.voxel >= 0.0) {
            out.push(format!("scancontext.voxel: must be in [0, inf) m; found {}", self.voxel));
        }
        out
    }

    /// Descriptor length: rings × sectors.
    fn len(&self) -> usize {
        self.rings * self.sectors
    }

    fn describe(&self, points: &[Point]) -> Result<Vec<f32>, String> {
        let grid = if self.voxel > 0.0 {
            crate::preprocess::voxel_grid(points, self.voxel)
        } else {
            points.to_vec()
        };
        Ok(describe(&grid, self))
    }

    fn searcher(&self, descriptors: Vec<f32>) -> Box<dyn super::Searcher> {
        Box::new(Searcher::new(descriptors, self.clone()))
    }

    fn search_steps(&self) -> &'static [&'static str] {
        &["candidates", "rerank"]
    }

    fn default_threshold(&self) -> Option<f64> {
        (*self == ScanContextParams::default()).then_some(0.5335)
    }
}

/// The `k` best of the `candidates` rows of `descriptors` (row-major) for `query` by the
/// ScanContext distance, by (distance, row).
pub fn rerank(
    query: &[f32],
    descriptors: &[f32],
    candidates: impl Iterator<Item = usize>,
    k: usize,
    p: &ScanContextParams,
) -> Vec<ScHit> {
    let len = p.len();
    let mut hits: Vec<ScHit> = candidates
        .map(|row| {
            let (d, shift) = distance(query, &descriptors[row * len..(row + 1) * len], p);
            (row, d, shift)
        })
        .collect();
    hits.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
    hits.truncate(k);
    hits
}
