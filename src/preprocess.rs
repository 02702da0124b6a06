//! The preprocess stage: range crop → ground removal → voxel grid → subsample → normalize,
//! each optional and each with its own settings type and validation. Deterministic: the
//! random parts (RANSAC, subsampling) are seeded by the scan's content fingerprint, so a scan
//! is prepared the same way however it is reached.

use crate::rng::SplitMix64;
use crate::types::Point;
use std::collections::HashMap;

/// The preprocess stage's settings (`[preprocess]` of a pipeline file): each step optional,
/// applied in field order.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Preprocess {
    /// Keep points whose distance to the sensor is within [min, max] metres.
    pub range: Option<RangeCrop>,
    /// Remove the ground.
    pub ground: Option<Ground>,
    /// Voxel-grid downsampling cell size (m): one centroid per occupied cell.
    pub voxel: Option<f64>,
    /// Keep at most this many points (uniformly, seeded by the scan's fingerprint).
    pub subsample: Option<usize>,
    /// Centre on the mean and scale so the largest |coordinate| is 1.
    pub normalize: bool,
    /// Scans with fewer points left are skipped (recorded with the reason).
    pub min_points: usize,
}

/// A range crop.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RangeCrop {
    /// Minimum distance (m).
    #[serde(default)]
    pub min: f64,
    /// Maximum distance (m).
    #[serde(default = "infinite")]
    pub max: f64,
}

fn infinite() -> f64 {
    f64::INFINITY
}

/// Ground removal.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "method", rename_all = "lowercase", deny_unknown_fields)]
pub enum Ground {
    /// Drop points with z below `below` (sensor frame, z up).
    Height {
        /// Height threshold (m).
        below: f64,
    },
    /// Fit the ground plane by RANSAC (seeded by the scan's fingerprint; normals within 30° of z) and drop
    /// points within `threshold` of it.
    Plane {
        /// Inlier distance (m).
        #[serde(default = "default_plane_threshold")]
        threshold: f64,
        /// RANSAC iterations.
        #[serde(default = "default_plane_iterations")]
        iterations: usize,
    },
}

fn default_plane_threshold() -> f64 {
    0.2
}

fn default_plane_iterations() -> usize {
    100
}

impl Default for Preprocess {
    /// No step, at least 16 points.
    fn default() -> Self {
        Preprocess {
            range: None,
            ground: None,
            voxel: None,
            subsample: None,
            normalize: false,
            min_points: 16,
        }
    }
}

impl Preprocess {
    /// The settings' problems, each starting with its key path (`preprocess.voxel: ...`).
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if let Some(r) = &self.range {
            out.extend(r.problems());
        }
        if let Some(g) = &self.ground {
            out.extend(g.problems());
        }
        if let Some(v) = self.voxel.filter(|v| !(v.is_finite() && *v > 0.0)) {
            out.push(format!("preprocess.voxel: the cell size must be > 0 (m, finite); found {v}"));
        }
        if let Some(n) = self.subsample.filter(|n| !(4..=100_000_000).contains(n)) {
            out.push(format!("preprocess.subsample: must be in [4, 100000000] points; found {n}"));
        }
        if !(4..=100_000_000).contains(&self.min_points) {
            out.push(format!(
                "preprocess.min_points: must be in [4, 100000000] (at least a tetrahedron); found {}",
                self.min_points
            ));
        }
        out
    }
}

impl RangeCrop {
    /// Problems of `preprocess.range`.
    pub fn problems(&self) -> Vec<String> {
        if self.min.is_finite() && self.min >= 0.0 && self.min < self.max {
            Vec::new()
        } else {
            vec![format!(
                "preprocess.range: need 0 <= min < max, min finite (m; min {}, max {})",
                self.min, self.max
            )]
        }
    }
}

impl Ground {
    /// Problems of `preprocess.ground`.
    pub fn problems(&self) -> Vec<String> {
        match *self {
            Ground::Plane { threshold, iterations }
                if !(threshold.is_finite() && threshold > 0.0 && (1..=1_000_000).contains(&iterations)) =>
            {
                vec![format!(
                    "preprocess.ground: need threshold in (0, inf) m and iterations in [1, 1000000] (threshold {threshold}, iterations {iterations})"
                )]
            }
            Ground::Height { below } if !below.is_finite() => {
                vec![format!("preprocess.ground: `below` must be a finite height (m); found {below}")]
            }
            _ => Vec::new(),
        }
    }
}

/// Why a scan was skipped.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Skip(pub String);

/// A stable 64-bit seed from a scan id (FNV-1a).
pub fn seed_of(id: &str) -> u64 {
    crate::rng::fnv1a64(id.as_bytes())
}

/// Runs the stage with random choices seeded by `seed` (the scan's content fingerprint);
/// `Err` when fewer than `min_points` points remain.
pub fn preprocess(mut points: Vec<Point>, seed: u64, p: &Preprocess) -> Result<Vec<Point>, Skip> {
    let mut rng = SplitMix64(seed);
    if let Some(r) = p.range {
        points.retain(|q| {
            let d = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
            d >= r.min && d <= r.max
        });
    }
    match p.ground {
        Some(Ground::Height { below }) => points.retain(|q| q[2] >= below),
        Some(Ground::Plane { threshold, iterations }) => {
            if let Some(plane) = ransac_ground(&points, threshold, iterations, &mut rng) {
                points.retain(|q| plane_distance(&plane, q).abs() > threshold);
            }
        }
        None => {}
    }
    if let Some(size) = p.voxel {
        points = voxel_grid(&points, size);
    }
    if let Some(n) = p.subsample {
        points = subsample(points, n, &mut rng);
    }
    if points.len() < p.min_points {
        return Err(Skip(format!(
            "{} points after preprocessing (min_points = {})",
            points.len(),
            p.min_points
        )));
    }
    if p.normalize {
        normalize(&mut points);
    }
    Ok(points)
}

/// A plane `n·x + d = 0` with unit normal.
type Plane = ([f64; 3], f64);

fn plane_distance(p: &Plane, q: &Point) -> f64 {
    p.0[0] * q[0] + p.0[1] * q[1] + p.0[2] * q[2] + p.1
}

/// RANSAC over planes whose normal is within 30° of z: the one with most inliers (scored on
/// at most 2,000 sampled points).
fn ransac_ground(points: &[Point], threshold: f64, iterations: usize, rng: &mut SplitMix64) -> Option<Plane> {
    if points.len() < 3 {
        return None;
    }
    let sample: Vec<Point> = if points.len() > 2000 {
        (0..2000).map(|_| points[rng.below(points.len())]).collect()
    } else {
        points.to_vec()
    };
    let min_cos = 30f64.to_radians().cos();
    let mut best: Option<(usize, Plane)> = None;
    for _ in 0..iterations {
        let [a, b, c] = [0; 3].map(|_| points[rng.below(points.len())]);
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        if len == 0.0 || (n[2] / len).abs() < min_cos {
            continue;
        }
        let n = [n[0] / len, n[1] / len, n[2] / len];
        let plane = (n, -(n[0] * a[0] + n[1] * a[1] + n[2] * a[2]));
        let inliers = sample.iter().filter(|q| plane_distance(&plane, q).abs() <= threshold).count();
        if best.is_none_or(|(k, _)| inliers > k) {
            best = Some((inliers, plane));
        }
    }
    best.map(|(_, p)| p)
}

/// One centroid per occupied cell, in cell order (deterministic); the cells' corners on the
/// multiples of `size`.
pub fn voxel_grid(points: &[Point], size: f64) -> Vec<Point> {
    voxel_cells(points, size, 0.0)
}

/// [`voxel_grid`] with the cells' centres on the multiples of `size`: the grid is its own
/// mirror image through the origin, so a quarter turn about z maps its cells onto its cells
/// (even for a point exactly on an axis).
pub fn voxel_grid_centred<'a>(points: impl IntoIterator<Item = &'a Point>, size: f64) -> Vec<Point> {
    voxel_cells(points, size, 0.5)
}

fn voxel_cells<'a>(points: impl IntoIterator<Item = &'a Point>, size: f64, offset: f64) -> Vec<Point> {
    /// A cell's coordinate sum and point count.
    type Cell = ([f64; 3], u32);
    let points = points.into_iter();
    // A few points a cell (a filter gives only its upper bound).
    let mut cells: HashMap<[i64; 3], Cell> = HashMap::with_capacity(points.size_hint().1.unwrap_or(0) / 4);
    for q in points {
        let key = q.map(|c| (c / size + offset).floor() as i64);
        let e = cells.entry(key).or_insert(([0.0; 3], 0));
        e.0.iter_mut().zip(q).for_each(|(s, c)| *s += c);
        e.1 += 1;
    }
    let mut cells: Vec<([i64; 3], Cell)> = cells.into_iter().collect();
    cells.sort_unstable_by_key(|c| c.0);
    cells.into_iter().map(|(_, (s, n))| s.map(|c| c / n as f64)).collect()
}

/// At most `n` points chosen uniformly (partial Fisher–Yates), kept in their original order.
pub fn subsample(points: Vec<Point>, n: usize, rng: &mut SplitMix64) -> Vec<Point> {
    if points.len() <= n {
        return points;
    }
    let mut idx: Vec<u32> = (0..points.len() as u32).collect();
    for i in 0..n {
        let j = i + rng.below(idx.len() - i);
        idx.swap(i, j);
    }
    let mut chosen = idx[..n].to_vec();
    chosen.sort_unstable();
    chosen.into_iter().map(|i| points[i as usize]).collect()
}

/// Zero mean, largest |coordinate| 1 (the PointNetVLAD convention). Returns the scale divided
/// by (the largest |coordinate| about the mean; 1 when the points coincide).
pub fn normalize(points: &mut [Point]) -> f64 {
    let n = points.len() as f64;
    let mean = [0, 1, 2].map(|k| points.iter().map(|q| q[k]).sum::<f64>() / n);
    let mut scale = 0.0f64;
    for q in points.iter_mut() {
        for k in 0..3 {
            q[k] -= mean[k];
            scale = scale.max(q[k].abs());
        }
    }
    if scale > 0.0 {
        points.iter_mut().for_each(|q| *q = q.map(|c| c / scale));
        scale
    } else {
        1.0
    }
}
