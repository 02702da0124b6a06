//! RING++ (Xu, Lu et al., *RING++: Roto-Translation Invariant Gram for Global Localization on a
//! Sparse Scan Map*, T-RO 2023): RING's sinogram, correlation and pose on six bird's-eye-view
//! grids of local geometric features instead of one occupancy grid, as the authors' feature
//! path computes them (`lus6-Jenny/RING`: `utils/core.py` `generate_bev_feats`,
//! `utils/extract_local_descriptor.py` `build_neighbors_NN`, the CUDA kernels
//! `calculate_features` and `point2gridmap` of `utils/generate_bev_pointfeat_cython`, the
//! KITTI loader's `read_pc` and `normalize_pc`); `scripts/ring_reference.py` is the numpy
//! transcription the tests hold it to.
//!
//! * **Cloud**: points at the origin (all coordinates within 1e-8) and at or below the ground
//!   level (z ≤ −1 m) are dropped, duplicates removed; of the rest, those with |x|, |y| < 70 m
//!   and z < 10 m are kept and scaled to x/70, y/70, z/10 in float32.
//! * **Features**: for each point, its 30 nearest neighbours in the scaled cloud (itself
//!   included); their covariance (divided by 29) gives the eigenvalues λ₁ ≥ λ₂ ≥ λ₃ and those of
//!   its x, y block μ₁ ≥ μ₂. Six of the kernel's 13 values (its columns 0, 1, 3, 10, 11, 12):
//!   change of curvature λ₃/Σλ, omnivariance (Πλ/(Σλ)³)^⅓, eigenentropy −Σ (λᵢ/Σλ) ln(λᵢ/Σλ),
//!   2-D linearity μ₂/μ₁, the neighbours' height range and height variance (divided by 30).
//!   A value that is not a number (a degenerate neighbourhood) counts as absent.
//! * **Grids**: 120 × 120 cells over the scaled square [−1, 1)², cell ⌊(v + 1) / g⌋ with
//!   g = float32(2/120); each cell holds, per feature, the largest value of its points, and 0
//!   when none is larger (the kernel starts every cell's maximum at 0).
//! * **Sinograms, distance, pose**: RING's ([`super::ring`]) on each grid: skimage's Radon
//!   transform and |FFT| per feature; the correlations' magnitudes summed over the six,
//!   score = peak / (0.15 · 6 · 120 · 120); for the pose, the six grids normalized together,
//!   turned and 2-D correlated per feature, the magnitudes summed.
//!
//! Where toporec differs from the reference: the reference computes the Radon transform of the
//! feature grids on the GPU with `torch-radon` (120 angles over [0, 2π] with the endpoint); toporec
//! uses RING's CPU transform (skimage's `radon`, 3° apart, no endpoint) for both, so the yaw
//! step is 3° for both. The kernel's per-cell maximum is a race between GPU threads; toporec
//! takes the true maximum. Arithmetic is float64 where the reference's is float32 (the
//! neighbours' covariance and eigenvalues, the features). A cloud of fewer than 30 points takes
//! all of them as each point's neighbours (the reference refuses it).
//!
//! The descriptor: the six invariant sinograms (120 × 120 float32 each), then the six grids
//! (120 × 120 float32 each): 172,800 values.

use super::ring::{self, Layout, RingParams};
use crate::types::Point;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix2, Matrix3, Vector3};
use rayon::prelude::*;
use std::num::NonZeroUsize;

/// The method's name.
pub(crate) const NAME: &str = "ring-plus";

/// Features a point carries and a descriptor holds grids of.
pub const FEATURES: usize = 6;

/// RING++ settings (`[ring-plus]` of a pipeline file); the defaults are the reference's
/// (`utils/config.py`, the KITTI loader's bounds and ground level, 30 neighbours).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RingPlusParams {
    /// Cells along each side of the grids (and offsets of the sinograms).
    pub side: usize,
    /// Angles of the sinograms over [0°, 360°) (even: the yaw is found modulo 180°).
    pub angles: usize,
    /// Half the grids' side (m): x and y within (−bound, bound); x and y are scaled by it.
    pub bound: f64,
    /// Ground level (m, sensor frame): points at or below it are dropped.
    pub ground: f64,
    /// Highest height kept (m, exclusive); heights are scaled by it.
    pub z_max: f64,
    /// Neighbours of a point its features are computed from (itself included).
    pub neighbours: usize,
}

impl Default for RingPlusParams {
    fn default() -> Self {
        RingPlusParams { side: 120, angles: 120, bound: 70.0, ground: -1.0, z_max: 10.0, neighbours: 30 }
    }
}

impl RingPlusParams {
    /// The grid and sinogram geometry RING's functions take.
    fn geometry(&self) -> RingParams {
        RingParams {
            side: self.side,
            angles: self.angles,
            bound: self.bound,
            z_min: self.ground,
            z_max: self.z_max,
        }
    }

    fn cells(&self) -> usize {
        self.side * self.side
    }
}

/// The reference's loader and normalization: origin points, points at or below the ground and
/// duplicates dropped; then |x|, |y| < bound and z < z_max kept, scaled to float32 x/bound,
/// y/bound, z/z_max.
pub fn scaled_cloud(points: &[Point], p: &RingPlusParams) -> Vec<[f32; 3]> {
    let mut kept: Vec<Point> = points
        .iter()
        .filter(|q| !q.iter().all(|c| c.abs() <= 1e-8) && q[2] > p.ground && q.iter().all(|c| c.is_finite()))
        .copied()
        .collect();
    kept.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])).then(a[2].total_cmp(&b[2])));
    kept.dedup();
    let (bound, ground, z_max) = (p.bound as f32, p.ground as f32, p.z_max as f32);
    kept.iter()
        .map(|q| [q[0] as f32, q[1] as f32, q[2] as f32])
        .filter(|q| q[0].abs() < bound && q[1].abs() < bound && q[2] > ground && q[2] < z_max)
        .map(|q| [q[0] / bound, q[1] / bound, q[2] / z_max])
        .collect()
}

/// The six features of each point of a scaled cloud (see the module's doc), NaN where the
/// kernel's arithmetic gives no number.
pub fn point_features(cloud: &[[f32; 3]], p: &RingPlusParams) -> Result<Vec<[f64; FEATURES]>, String> {
    if cloud.is_empty() {
        return Ok(Vec::new());
    }
    let pts: Vec<[f64; 3]> = cloud.iter().map(|q| q.map(|c| c as f64)).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&pts)
        .map_err(|e| format!("ring-plus: the cloud's k-d tree cannot be built: {e:?}"))?;
    let k = p.neighbours.min(pts.len()).max(1);
    let n = NonZeroUsize::new(k).expect("k > 0");
    Ok(pts
        .par_iter()
        .map(|q| {
            let near = tree.query(q).nearest_n::<SquaredEuclidean<f64>>(n).execute();
            let nb: Vec<Vector3<f64>> = near.iter().map(|h| Vector3::from(pts[h.item as usize])).collect();
            features(&nb)
        })
        .collect())
}

/// The kernel's `calculate_features` columns 0, 1, 3, 10, 11, 12 for one neighbourhood.
fn features(nb: &[Vector3<f64>]) -> [f64; FEATURES] {
    let k = nb.len() as f64;
    let mean = nb.iter().sum::<Vector3<f64>>() / k;
    // `np.matmul(P.T, P) / (k - 1)`; a single neighbour divides by 0 (no number, as numpy).
    let cov = nb.iter().map(|v| (v - mean) * (v - mean).transpose()).sum::<Matrix3<f64>>() / (k - 1.0);
    let mut l: Vec<f64> = cov.symmetric_eigenvalues().iter().copied().collect();
    l.sort_by(|a, b| b.total_cmp(a));
    let block = Matrix2::new(cov[(0, 0)], cov[(0, 1)], cov[(1, 0)], cov[(1, 1)]);
    let mut m: Vec<f64> = block.symmetric_eigenvalues().iter().copied().collect();
    m.sort_by(|a, b| b.total_cmp(a));
    let sum = l[0] + l[1] + l[2];
    let prod = l[0] * l[1] * l[2];
    let change_of_curvature = l[2] / sum;
    let omnivariance = (prod / sum.powi(3)).powf(1.0 / 3.0);
    let eigenentropy = -l.iter().map(|&x| (x / sum) * (x / sum).ln()).sum::<f64>();
    let linearity_2d = m[1] / m[0];
    let (lo, hi) =
        nb.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v[2]), hi.max(v[2])));
    let z_mean = nb.iter().map(|v| v[2]).sum::<f64>() / k;
    let z_variance = nb.iter().map(|v| (v[2] - z_mean).powi(2)).sum::<f64>() / k;
    [change_of_curvature, omnivariance, eigenentropy, linearity_2d, hi - lo, z_variance]
}

/// The six feature grids (`[feature][x cell][y cell]`): per cell and feature, the largest value
/// of the cell's points, 0 when none is larger (the kernel's `point2gridmap`).
pub fn grids(cloud: &[[f32; 3]], values: &[[f64; FEATURES]], p: &RingPlusParams) -> Vec<f64> {
    let n = p.side;
    // `gap_x = 2.0 * (float)max_length / (float)num_x`, stored in a float; the index is
    // computed in double from the float coordinate.
    let gap = (2.0 / n as f64) as f32 as f64;
    let index = |v: f32| -> usize {
        let v = if v == 0.0 {
            0.0001
        } else if v > 1.0 {
            0.9999
        } else if v < -1.0 {
            -0.9999
        } else {
            v
        };
        (((v as f64 + 1.0) / gap).floor().max(0.0) as usize).min(n - 1)
    };
    let mut out = vec![0.0f64; FEATURES * p.cells()];
    for (q, f) in cloud.iter().zip(values) {
        let cell = index(q[0]) * n + index(q[1]);
        for (c, &v) in f.iter().enumerate() {
            let slot = &mut out[c * p.cells() + cell];
            // NaN never wins (`max_h < value` is false), as in the kernel.
            if *slot < v {
                *slot = v;
            }
        }
    }
    out
}

/// The RING++ descriptor of a raw scan: six invariant sinograms, then the six grids.
pub fn describe(points: &[Point], p: &RingPlusParams) -> Result<Vec<f32>, String> {
    let cloud = scaled_cloud(points, p);
    let values = point_features(&cloud, p)?;
    let g = grids(&cloud, &values, p);
    let geometry = p.geometry();
    let sinograms = ring::radon_stack(&g, FEATURES, &geometry);
    let mut out: Vec<f32> = Vec::with_capacity(2 * FEATURES * p.cells());
    for s in sinograms.chunks_exact(geometry.sinogram_len()) {
        out.extend(ring::invariant(s, &geometry).into_iter().map(|v| v as f32));
    }
    out.extend(g.iter().map(|&v| v as f32));
    Ok(out)
}

/// The feature grids stored in a descriptor.
fn stored_grids(descriptor: &[f32], p: &RingParams) -> Vec<f64> {
    descriptor[FEATURES * p.sinogram_len()..].iter().map(|&v| v as f64).collect()
}

const LAYOUT: Layout = Layout { channels: FEATURES, grids: stored_grids };

/// The RING++ distance of two descriptors and the angle shift of the best correlation.
pub fn distance(query: &[f32], candidate: &[f32], p: &RingPlusParams) -> (f64, i64) {
    ring::distance_of(query, candidate, LAYOUT, &p.geometry())
}

/// The relative pose of a matched pair, as [`ring::pose`]: `(steps, x cells, y cells)`.
pub fn pose(query: &[f32], candidate: &[f32], shift: i64, p: &RingPlusParams) -> (i64, i64, i64) {
    ring::pose_of(query, candidate, shift, LAYOUT, &p.geometry())
}

impl super::Named for RingPlusParams {
    const NAME: &'static str = NAME;
}

impl super::Computed for RingPlusParams {
    /// The settings' problems, each with its key.
    fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if !(8..=1024).contains(&self.side) {
            out.push(format!("ring-plus.side: must be in [8, 1024]; found {}", self.side));
        }
        if !(2..=3600).contains(&self.angles) || !self.angles.is_multiple_of(2) {
            out.push(format!("ring-plus.angles: must be even, in [2, 3600]; found {}", self.angles));
        }
        if !(self.bound.is_finite() && self.bound > 0.0) {
            out.push(format!("ring-plus.bound: must be in (0, inf) m; found {}", self.bound));
        }
        if !(self.ground.is_finite()
            && self.z_max.is_finite()
            && self.z_max > 0.0
            && self.ground < self.z_max)
        {
            out.push(format!(
                "ring-plus: need ground < z_max, z_max > 0, both finite (ground {}, z_max {})",
                self.ground, self.z_max
            ));
        }
        if !(2..=1000).contains(&self.neighbours) {
            out.push(format!("ring-plus.neighbours: must be in [2, 1000]; found {}", self.neighbours));
        }
        out
    }

    /// Descriptor length: six sinograms of angles × side values, then six grids of side².
    fn len(&self) -> usize {
        FEATURES * (self.angles * self.side + self.cells())
    }

    fn describe(&self, points: &[Point]) -> Result<Vec<f32>, String> {
        describe(points, self)
    }

    fn searcher(&self, descriptors: Vec<f32>) -> Box<dyn super::Searcher> {
        Box::new(ring::Searcher::new(descriptors, self.geometry(), LAYOUT, self.len()))
    }

    /// Calibrated at precision 0.99 on the seed-11 drive of docs/loops.md: 0.4390.
    fn default_threshold(&self) -> Option<f64> {
        (*self == RingPlusParams::default()).then_some(0.4390)
    }
}
