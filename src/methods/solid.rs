//! SOLiD (Kim, Choi, Kim, *SOLiD: Spatially Organized and Lightweight Global Descriptor for
//! FOV-constrained LiDAR Place Recognition*, IEEE RA-L 2024), as the authors' code computes it
//! (`sparolab/solid`: `cpp/src/solid.cpp`, `cpp/include/solid_module.h`, `python/utils/solid.py`).
//!
//! * Preprocessing: points closer than `min_range` (3 m) or farther than `max_range` (80 m) from
//!   the sensor (3D distance, both strict) are dropped, then a voxel grid of `voxel` (0.4 m).
//! * Counts: each point falls in range bin ⌊d / (max_range / rings)⌋ (d = √(x² + y²)), azimuth
//!   bin ⌊θ / (360° / sectors)⌋ (θ ∈ [0°, 360°)) and elevation bin
//!   ⌊(φ − fov_down) / ((fov_up − fov_down) / elevations)⌋ (φ = atan2(z, d) in degrees), each
//!   clamped into range; a zero x or y is taken as 0.001, as the references do. Two count
//!   matrices: range × elevation (40 × 32) and azimuth × elevation (60 × 32).
//! * The weight of an elevation bin is its count over the whole scan, min-max normalised.
//! * The descriptor: `r = R · w` (40 values, independent of the yaw) then `a = A · w` (60
//!   values), stored as float32. Two scans compare by `1 −` the cosine similarity of their `r`;
//!   the yaw between them is the circular shift `s` of `a` with the least L1 difference,
//!   `s · 360° / sectors`.
//!
//! Where the references differ, toporec follows the C++ code for the settings (32 elevation
//! bins, the HDL-64E field of view +2° / −24.8°, a 0.4 m voxel grid) and for the elevation
//! bins (clamped, where the Python code wraps a negative bin to the top ones); and the Python
//! code for the yaw (`np.roll` of the candidate, `argmin · 6°`), where the C++ `pose_estimation`
//! shifts the query the other way and adds one sector to the result. When every elevation bin
//! holds the same count the min-max weight is 0/0 in both references; toporec weighs every bin
//! 1 there. A scan with no point left has an all-zero descriptor, at distance 1 from every scan.
//!
//! Search: every entry's cosine with the query, as float32 dot products of the unit `r`
//! vectors (40 values); the entries within the dot products' rounding
//! bound of the k-th best are ranked by the exact distance. So every budget is exhaustive. The
//! yaw is computed for the hits only.

use super::Computed;
use super::searcher::{Allowed, Hit, SearchBudget, SearchTimes, allowed_rows, timed};
use crate::types::Point;

/// The method's name.
pub(crate) const NAME: &str = "solid";

/// SOLiD settings (`[solid]` of a pipeline file). The field of view is the sensor's: the
/// defaults are the HDL-64E's (KITTI); an HDL-32E (NCLT) is +10.67° / −30.67°, a VLP-16
/// ±15°, an Ouster OS1-64 ±22.5°.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SolidParams {
    /// Range bins.
    pub rings: usize,
    /// Azimuth bins.
    pub sectors: usize,
    /// Elevation bins.
    pub elevations: usize,
    /// Upper edge of the vertical field of view (degrees).
    pub fov_up: f64,
    /// Lower edge of the vertical field of view (degrees).
    pub fov_down: f64,
    /// Points nearer than this are dropped (m).
    pub min_range: f64,
    /// Points farther than this are dropped, and the range bins span it (m).
    pub max_range: f64,
    /// Voxel-grid cell of the preprocessing (m); none when 0.
    pub voxel: f64,
}

impl Default for SolidParams {
    fn default() -> Self {
        SolidParams {
            rings: 40,
            sectors: 60,
            elevations: 32,
            fov_up: 2.0,
            fov_down: -24.8,
            min_range: 3.0,
            max_range: 80.0,
            voxel: 0.4,
        }
    }
}

impl SolidParams {}

/// The points SOLiD describes: within (min_range, max_range) of the sensor, then on the voxel
/// grid.
pub fn preprocess(points: &[Point], p: &SolidParams) -> Vec<Point> {
    let (lo, hi) = (p.min_range * p.min_range, p.max_range * p.max_range);
    let kept: Vec<Point> = points
        .iter()
        .filter(|q| {
            let d2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2];
            d2 > lo && d2 < hi
        })
        .copied()
        .collect();
    if p.voxel > 0.0 { crate::preprocess::voxel_grid(&kept, p.voxel) } else { kept }
}

/// A bin index: ⌊v / gap⌋ clamped into `0..n`.
fn bin(v: f64, gap: f64, n: usize) -> usize {
    let i = (v / gap).floor();
    if i <= 0.0 { 0 } else { (i as usize).min(n - 1) }
}

/// The SOLiD descriptor of points already preprocessed ([`preprocess`]): `r` (rings values)
/// then `a` (sectors values).
pub fn describe(points: &[Point], p: &SolidParams) -> Vec<f32> {
    let (nr, ns, ne) = (p.rings, p.sectors, p.elevations);
    let gap_range = p.max_range / nr as f64;
    let gap_azimuth = 360.0 / ns as f64;
    let gap_elevation = (p.fov_up - p.fov_down) / ne as f64;
    let mut range_counts = vec![0.0f64; nr * ne];
    let mut azimuth_counts = vec![0.0f64; ns * ne];
    for q in points {
        let x = if q[0] == 0.0 { 0.001 } else { q[0] };
        let y = if q[1] == 0.0 { 0.001 } else { q[1] };
        let d = (x * x + y * y).sqrt();
        let elevation = q[2].atan2(d).to_degrees();
        let (r, s, e) = (
            bin(d, gap_range, nr),
            // SOLiD's `xy2theta` is ScanContext's.
            bin(super::scancontext::azimuth_degrees(x, y), gap_azimuth, ns),
            bin(elevation - p.fov_down, gap_elevation, ne),
        );
        range_counts[r * ne + e] += 1.0;
        azimuth_counts[s * ne + e] += 1.0;
    }
    let mut weight: Vec<f64> = (0..ne).map(|e| (0..nr).map(|r| range_counts[r * ne + e]).sum()).collect();
    let (min, max) =
        weight.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &w| (a.min(w), b.max(w)));
    for w in &mut weight {
        *w = if max > min { (*w - min) / (max - min) } else { 1.0 };
    }
    let weigh = |counts: &[f64], rows: usize| -> Vec<f32> {
        (0..rows).map(|i| (0..ne).map(|e| counts[i * ne + e] * weight[e]).sum::<f64>() as f32).collect()
    };
    let mut out = weigh(&range_counts, nr);
    out.extend(weigh(&azimuth_counts, ns));
    out
}

/// `1 −` the cosine similarity of two descriptors' range parts (1 when either is all zero).
pub fn distance(query: &[f32], candidate: &[f32], p: &SolidParams) -> f64 {
    let (q, c) = (&query[..p.rings], &candidate[..p.rings]);
    let (mut dot, mut nq, mut nc) = (0.0f64, 0.0f64, 0.0f64);
    for (&a, &b) in q.iter().zip(c) {
        let (a, b) = (a as f64, b as f64);
        dot += a * b;
        nq += a * a;
        nc += b * b;
    }
    if nq == 0.0 || nc == 0.0 { 1.0 } else { 1.0 - dot / (nq.sqrt() * nc.sqrt()) }
}

/// The circular shift `s` of the candidate's azimuth part with the least L1 difference to the
/// query's (`Σ_c |a_q[(c + s) mod n] − a_c[c]|`, the lowest `s` on a tie): the query is the
/// candidate turned by [`yaw_degrees`]`(s)`.
pub fn yaw_shift(query: &[f32], candidate: &[f32], p: &SolidParams) -> usize {
    let n = p.sectors;
    let (q, c) = (&query[p.rings..p.rings + n], &candidate[p.rings..p.rings + n]);
    let mut best = (f64::INFINITY, 0);
    for s in 0..n {
        let l1: f64 = (0..n).map(|i| (q[(i + s) % n] as f64 - c[i] as f64).abs()).sum();
        if l1 < best.0 {
            best = (l1, s);
        }
    }
    best.1
}

/// The yaw (degrees, in [0, 360)) that a shift stands for.
pub fn yaw_degrees(shift: usize, p: &SolidParams) -> f64 {
    super::searcher::shift_degrees(shift, p.sectors)
}

/// A hit: database row, SOLiD distance, and the yaw shift.
pub(crate) type SolidHit = (usize, f64, usize);

/// SOLiD descriptors searched by their unit range parts: every entry's float32 dot product
/// with the query's (the cosine), then the entries within the dot products' rounding bound of
/// the k-th best ranked by the exact SOLiD distance (f64), and their yaws estimated.
pub struct Searcher {
    params: SolidParams,
    descriptors: Vec<f32>,
    /// Unit range parts, `rings` a row.
    keys: Vec<f32>,
}

/// The unit range part of a descriptor (all zero stays zero).
fn unit_range(d: &[f32], p: &SolidParams) -> Vec<f32> {
    let r = &d[..p.rings];
    let norm = r.iter().map(|&v| v as f64 * v as f64).sum::<f64>().sqrt();
    r.iter().map(|&v| if norm > 0.0 { (v as f64 / norm) as f32 } else { 0.0 }).collect()
}

/// A bound on the error of a float32 dot product of two unit vectors of `n` values, their
/// rounding to float32 included: below `n · 2⁻²³`; four times that leaves room.
fn dot_error_bound(n: usize) -> f32 {
    4.0 * n as f32 * f32::EPSILON
}

impl Searcher {
    /// A searcher over `descriptors` (row-major, `params.len()` a row).
    pub fn new(descriptors: Vec<f32>, params: SolidParams) -> Self {
        let keys: Vec<f32> =
            descriptors.chunks_exact(params.len()).flat_map(|d| unit_range(d, &params)).collect();
        Searcher { keys, descriptors, params }
    }

    /// The settings.
    pub fn params(&self) -> &SolidParams {
        &self.params
    }

    /// The `k` nearest rows to `query` by the SOLiD distance, nearest first (ties by row);
    /// among the rows `allowed` admits, every allowed row's distance.
    pub fn search(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> Vec<SolidHit> {
        if allowed.is_some() {
            let rows = allowed_rows(self.descriptors.len() / self.params.len(), allowed);
            return ranked(query, &self.descriptors, rows, k, &self.params);
        }
        let rings = self.params.rings;
        let q = unit_range(query, &self.params);
        let dots: Vec<f32> =
            self.keys.chunks_exact(rings).map(|key| key.iter().zip(&q).map(|(a, b)| a * b).sum()).collect();
        let k = k.min(dots.len());
        if k == 0 {
            return Vec::new();
        }
        let mut order = dots.clone();
        let (_, kth, _) = order.select_nth_unstable_by(k - 1, |a, b| b.total_cmp(a));
        let cut = *kth - dot_error_bound(rings);
        ranked(query, &self.descriptors, (0..dots.len()).filter(|&row| dots[row] >= cut), k, &self.params)
    }
}

impl super::Searcher for Searcher {
    fn len(&self) -> usize {
        self.descriptors.len() / self.params.len()
    }

    fn push(&mut self, descriptor: &[f32]) {
        self.descriptors.extend_from_slice(descriptor);
        self.keys.extend(unit_range(descriptor, &self.params));
    }

    fn search(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> (Vec<Hit>, SearchTimes) {
        timed(|| {
            let hits = Searcher::search(self, query, k, allowed).into_iter();
            hits.map(|(row, d, shift)| Hit::turned(row, d, yaw_degrees(shift, &self.params))).collect()
        })
    }

    /// Every entry is compared at every shift whatever the budget.
    fn set_budget(&mut self, _budget: SearchBudget, _entries: usize) {}
}

impl super::Named for SolidParams {
    const NAME: &'static str = NAME;
}

impl super::Computed for SolidParams {
    /// The settings' problems, each with its key.
    fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        for (key, v) in [("rings", self.rings), ("sectors", self.sectors), ("elevations", self.elevations)] {
            if !(1..=3600).contains(&v) {
                out.push(format!("solid.{key}: must be in [1, 3600]; found {v}"));
            }
        }
        if !(self.fov_up.is_finite() && self.fov_down.is_finite() && self.fov_up > self.fov_down) {
            out.push(format!(
                "solid: need fov_up > fov_down, both finite (fov_up {}, fov_down {})",
                self.fov_up, self.fov_down
            ));
        }
        if !(self.min_range.is_finite()
            && self.max_range.is_finite()
            && self.min_range >= 0.0
            && self.max_range > self.min_range)
        {
            out.push(format!(
                "solid: need 0 <= min_range < max_range, both finite (min_range {}, max_range {})",
                self.min_range, self.max_range
            ));
        }
        if !(self.voxel.is_finite() && self.voxel >= 0.0) {
            out.push(format!("solid.voxel: must be in [0, inf) m; found {}", self.voxel));
        }
        out
    }

    /// Descriptor length: rings + sectors.
    fn len(&self) -> usize {
        self.rings + self.sectors
    }

    fn describe(&self, points: &[Point]) -> Result<Vec<f32>, String> {
        Ok(describe(&preprocess(points, self), self))
    }

    fn searcher(&self, descriptors: Vec<f32>) -> Box<dyn super::Searcher> {
        Box::new(Searcher::new(descriptors, self.clone()))
    }
}

/// The `k` nearest of the `rows` of `descriptors` (row-major) to `query` by the SOLiD distance
/// (ties by row), each with its yaw shift.
pub fn ranked(
    query: &[f32],
    descriptors: &[f32],
    rows: impl Iterator<Item = usize>,
    k: usize,
    p: &SolidParams,
) -> Vec<SolidHit> {
    let len = p.len();
    let at = |row: usize| &descriptors[row * len..(row + 1) * len];
    let mut hits: Vec<(usize, f64)> = rows.map(|row| (row, distance(query, at(row), p))).collect();
    let order = |a: &(usize, f64), b: &(usize, f64)| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0));
    // The k smallest selected in linear time (every allowed row, in the loop search), then sorted.
    if k > 0 && hits.len() > k {
        hits.select_nth_unstable_by(k - 1, order);
    }
    hits.truncate(k);
    hits.sort_by(order);
    hits.into_iter().map(|(row, d)| (row, d, yaw_shift(query, at(row), p))).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_search_ranks_as_the_exact_distance_does() {
        let p = SolidParams { rings: 6, sectors: 4, ..SolidParams::default() };
        let mut rng = crate::rng::SplitMix64(3);
        let mut db: Vec<f32> = (0..500 * p.len()).map(|_| (rng.next_f64() * 10.0).floor() as f32).collect();
        // Ties: rows 10 and 20 equal row 5; row 30 is a multiple of it (the same cosine).
        let row = |db: &[f32], i: usize| db[i * p.len()..(i + 1) * p.len()].to_vec();
        let five = row(&db, 5);
        db[10 * p.len()..11 * p.len()].copy_from_slice(&five);
        db[20 * p.len()..21 * p.len()].copy_from_slice(&five);
        let scaled: Vec<f32> = five.iter().map(|v| v * 3.0).collect();
        db[30 * p.len()..31 * p.len()].copy_from_slice(&scaled);
        let searcher = Searcher::new(db.clone(), p.clone());
        for q in [row(&db, 5), row(&db, 77), vec![0.0; p.len()]] {
            let mut exact: Vec<(usize, f64)> =
                (0..500).map(|i| (i, distance(&q, &row(&db, i), &p))).collect();
            exact.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            let got: Vec<(usize, f64)> =
                searcher.search(&q, 7, None).into_iter().map(|h| (h.0, h.1)).collect();
            assert_eq!(got, exact[..7]);
        }
        assert!(searcher.search(&row(&db, 1), 0, None).is_empty());
        assert_eq!(searcher.search(&row(&db, 1), 9999, None).len(), 500);
    }

    #[test]
    fn bins_clamp_at_both_ends() {
        assert_eq!(bin(-0.5, 1.0, 4), 0);
        assert_eq!(bin(3.99, 1.0, 4), 3);
        assert_eq!(bin(9.0, 1.0, 4), 3);
    }
}
