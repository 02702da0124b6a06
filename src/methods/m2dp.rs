//! M2DP (He, Wang & Zhang, IROS 2016), as the authors' MATLAB code computes it
//! (`LiHeUA/M2DP`, `M2DP.m` and `CountVote2D.c`): a 192-value global descriptor.
//!
//! 1. The cloud is centred and turned into its principal axes (PCA): x along the direction of
//!    largest variance, then y, then z.
//! 2. It is projected onto 4 × 16 planes, whose normals have azimuths −90°, −30°, 30°, 90° and
//!    elevations 0°, 6°, …, 90°. On each plane, the points are counted in 16 angular × 8 radial
//!    bins (radii on a quadratic scale up to the cloud's largest distance from its centre),
//!    divided by the number of points: one row of a 64 × 128 matrix.
//! 3. The descriptor is the matrix's first left singular vector (64 values) followed by its first
//!    right singular vector (128 values). Distances are Euclidean.
//!
//! Sign conventions (the reference leaves them to MATLAB): each principal direction is signed
//! so that its component of largest magnitude is positive (what MATLAB's `pca` does), and the
//! singular pair so that the left vector sums to a non-negative value (the matrix is
//! non-negative, so its leading singular vectors can be taken non-negative).

use crate::types::Point;
use nalgebra::{DMatrix, Matrix3, SymmetricEigen, Vector3};

/// The method's name.
pub(crate) const NAME: &str = "m2dp";

/// M2DP settings (`[m2dp]` of a pipeline file).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct M2dpParams {
    /// Voxel-grid cell of the preprocessing (m); none when 0 (the reference uses the raw cloud).
    pub voxel: f64,
}

impl Default for M2dpParams {
    fn default() -> Self {
        M2dpParams { voxel: 0.0 }
    }
}

impl super::Named for M2dpParams {
    const NAME: &'static str = NAME;
}

impl super::Computed for M2dpParams {
    fn problems(&self) -> Vec<String> {
        if self.voxel.is_finite() && self.voxel >= 0.0 {
            Vec::new()
        } else {
            vec![format!("m2dp.voxel: must be in [0, inf) m; found {}", self.voxel)]
        }
    }

    fn len(&self) -> usize {
        LEN
    }

    fn describe(&self, points: &[Point]) -> Result<Vec<f32>, String> {
        let grid = if self.voxel > 0.0 {
            crate::preprocess::voxel_grid(points, self.voxel)
        } else {
            points.to_vec()
        };
        Ok(describe(&grid))
    }

    /// Distances are Euclidean: exact k-NN.
    fn searcher(&self, descriptors: Vec<f32>) -> Box<dyn super::Searcher> {
        Box::new(super::euclidean::Euclidean::new(descriptors, LEN))
    }
}

/// Azimuths of the projection normals.
const AZIMUTHS: usize = 4;
/// Elevations of the projection normals.
const ELEVATIONS: usize = 16;
/// Angular bins per plane.
const ANGULAR: usize = 16;
/// Radial bins per plane.
const RADIAL: usize = 8;
/// Descriptor length: 64 + 128.
pub(crate) const LEN: usize = AZIMUTHS * ELEVATIONS + ANGULAR * RADIAL;

/// The cloud's principal axes, as the rows of a matrix: decreasing variance, each signed so
/// that its largest-magnitude component is positive.
fn principal_axes(centred: &[Vector3<f64>]) -> Matrix3<f64> {
    let mut cov = Matrix3::zeros();
    for p in centred {
        cov += p * p.transpose();
    }
    let eig = SymmetricEigen::new(cov);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]).then(a.cmp(&b)));
    let mut axes = Matrix3::zeros();
    for (row, &k) in order.iter().enumerate() {
        let mut v: Vector3<f64> = eig.eigenvectors.column(k).into_owned();
        let largest = (0..3).max_by(|&a, &b| v[a].abs().total_cmp(&v[b].abs()).then(b.cmp(&a))).unwrap_or(0);
        if v[largest] < 0.0 {
            v = -v;
        }
        axes.set_row(row, &v.transpose());
    }
    axes
}

/// Angles (radians) closer than this, relative, to a bin edge are binned by `atan2` exactly as
/// the reference does; the others by the signs of cross products (no `atan2`, same bin).
const EDGE_GUARD: f64 = 1e-9;

/// sin and cos of 22.5°, the angular bin width.
const SIN_22_5: f64 = 0.382_683_432_365_089_8;
const COS_22_5: f64 = 0.923_879_532_511_286_7;

/// The M2DP descriptor of a cloud (192 values); all zeros for fewer than 2 distinct points.
pub fn describe(points: &[Point]) -> Vec<f32> {
    let n = points.len();
    if n < 2 {
        return vec![0.0; LEN];
    }
    let mean = points.iter().fold(Vector3::zeros(), |m, p| m + Vector3::new(p[0], p[1], p[2])) / n as f64;
    let centred: Vec<Vector3<f64>> = points.iter().map(|p| Vector3::new(p[0], p[1], p[2]) - mean).collect();
    let axes = principal_axes(&centred);
    // Structure of arrays: the projections below run over contiguous coordinates.
    let (mut xs, mut ys, mut zs) = (Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n));
    let mut max_rho2 = 0.0f64;
    for p in &centred {
        let q = axes * p;
        max_rho2 = max_rho2.max(q.norm_squared());
        xs.push(q.x);
        ys.push(q.y);
        zs.push(q.z);
    }
    if max_rho2 == 0.0 {
        return vec![0.0; LEN];
    }
    // Radial edges: (k / 8)² · maxRho (quadratic spacing), the last one nudged up.
    let mut rho_edges: Vec<f64> =
        (0..=RADIAL).map(|k| (k as f64 / RADIAL as f64).powi(2) * max_rho2.sqrt()).collect();
    rho_edges[RADIAL] += 0.001;
    let theta_edges: Vec<f64> = (0..=ANGULAR)
        .map(|k| -std::f64::consts::PI + 2.0 * std::f64::consts::PI * k as f64 / ANGULAR as f64)
        .collect();
    let inner: [f64; RADIAL - 1] = std::array::from_fn(|j| rho_edges[j + 1]);
    let mut a = DMatrix::<f64>::zeros(AZIMUTHS * ELEVATIONS, ANGULAR * RADIAL);
    let (mut us, mut vs) = (vec![0.0f64; n], vec![0.0f64; n]);
    let mut bins = vec![0.0f64; n];
    for ip in 0..AZIMUTHS {
        let az = -std::f64::consts::FRAC_PI_2 + std::f64::consts::PI * ip as f64 / (AZIMUTHS - 1) as f64;
        for iq in 0..ELEVATIONS {
            let el = std::f64::consts::FRAC_PI_2 * iq as f64 / (ELEVATIONS - 1) as f64;
            let normal = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
            let h = normal.x;
            let px = Vector3::new(1.0, 0.0, 0.0) - h * normal;
            let py = normal.cross(&px);
            let plane = Plane { px: [px.x, px.y, px.z], py: [py.x, py.y, py.z], inner };
            bin_points(&plane, [&xs, &ys, &zs], &mut us, &mut vs, &mut bins);
            // Counts in four interleaved tables: consecutive points rarely wait on each other's
            // increment of one cell.
            let mut counts = [[0u32; ANGULAR * RADIAL]; 4];
            for (i, &b) in bins.iter().enumerate() {
                let b = b as usize;
                let mut cell = b & 127;
                if b & 128 != 0 {
                    let theta = vs[i].atan2(us[i]);
                    let angular =
                        (0..ANGULAR - 1).find(|&k| theta < theta_edges[k + 1]).unwrap_or(ANGULAR - 1);
                    cell = (cell & !15) | angular;
                }
                counts[i & 3][cell] += 1;
            }
            let row = ip * ELEVATIONS + iq;
            for cell in 0..ANGULAR * RADIAL {
                let radial_major = (cell >> 4) * ANGULAR + (cell & 15);
                a[(row, radial_major)] = counts.iter().map(|c| c[cell] as f64).sum();
            }
        }
    }
    a /= n as f64;
    let (u, v) = leading_singular_pair(&a);
    let sign = if u.sum() < 0.0 { -1.0 } else { 1.0 };
    u.iter().chain(v.iter()).map(|x| (sign * x) as f32).collect()
}

/// One projection plane: its (unnormalized) axes and the inner radial edges.
struct Plane {
    px: [f64; 3],
    py: [f64; 3],
    inner: [f64; RADIAL - 1],
}

/// Projects the points onto a plane (`us`, `vs`) and bins them: `radial · 16 + angular` (as
/// f64, which keeps the loop in vector registers), plus 128 for a point on (or within rounding of) an angular edge, which the caller bins by
/// the reference's own test. The same arithmetic on every x86-64 (no fused multiply-add), with
/// AVX2 where the CPU has it.
fn bin_points(plane: &Plane, xyz: [&[f64]; 3], us: &mut [f64], vs: &mut [f64], bins: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { bin_points_avx2(plane, xyz, us, vs, bins) };
    }
    bin_points_portable(plane, xyz, us, vs, bins)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn bin_points_avx2(plane: &Plane, xyz: [&[f64]; 3], us: &mut [f64], vs: &mut [f64], bins: &mut [f64]) {
    bin_points_portable(plane, xyz, us, vs, bins)
}

#[inline(always)]
fn bin_points_portable(plane: &Plane, xyz: [&[f64]; 3], us: &mut [f64], vs: &mut [f64], bins: &mut [f64]) {
    let ([xs, ys, zs], px, py) = (xyz, plane.px, plane.py);
    for i in 0..us.len() {
        let (x, y, z) = (xs[i], ys[i], zs[i]);
        us[i] = x * px[0] + y * px[1] + z * px[2];
        vs[i] = x * py[0] + y * py[1] + z * py[2];
    }
    for ((b, &u), &v) in bins.iter_mut().zip(us.iter()).zip(vs.iter()) {
        let rho = (u * u + v * v).sqrt();
        // Folded into the first quadrant (β ∈ [0°, 90°]), the angle's 22.5° sub-bin is how
        // many of the edges 22.5°, 45°, 67.5° lie below it (signs of cross products); the
        // quadrant maps it back: bin 8 + k, 15 − k, 7 − k or k. (Counted in f64 lanes: no
        // mixing of integer and float vectors.)
        let (au, av) = (u.abs(), v.abs());
        let s22 = av * COS_22_5 - au * SIN_22_5;
        let s45 = av - au;
        let s67 = av * SIN_22_5 - au * COS_22_5;
        let k = (if s22 > 0.0 { 1.0 } else { 0.0 })
            + (if s45 > 0.0 { 1.0 } else { 0.0 })
            + (if s67 > 0.0 { 1.0 } else { 0.0 });
        // (Plain selects, not f64::min, whose NaN rules keep it out of vector registers.)
        let lesser = |a: f64, b: f64| if a < b { a } else { b };
        let closest = lesser(lesser(lesser(au, av), lesser(s22.abs(), s45.abs())), s67.abs());
        let angular = match (u >= 0.0, v > 0.0) {
            (true, true) => 8.0 + k,
            (false, true) => 15.0 - k,
            (true, false) => 7.0 - k,
            (false, false) => k,
        };
        let mut radial = 0.0f64;
        for &e in &plane.inner {
            radial += if rho >= e { 1.0 } else { 0.0 };
        }
        let near = if (closest <= EDGE_GUARD * rho) | (rho == 0.0) { 128.0 } else { 0.0 };
        *b = near + radial * 16.0 + angular;
    }
}

/// The first left and right singular vectors of `a` (64 × 128): the leading eigenvector u of
/// the 64 × 64 matrix A·Aᵀ, and v = Aᵀu / σ — the pair an SVD gives, up to a common sign, at a
/// fraction of its cost. The eigenvector comes from power iteration (A ≥ 0, so its leading
/// eigenvalue is well apart from the next in practice), checked by its residual; when that
/// does not converge, from a full symmetric eigendecomposition.
fn leading_singular_pair(a: &DMatrix<f64>) -> (nalgebra::DVector<f64>, nalgebra::DVector<f64>) {
    let gram = a * a.transpose();
    let u = power_iteration(&gram).unwrap_or_else(|| {
        let eig = SymmetricEigen::new(gram.clone());
        let first = eig
            .eigenvalues
            .iter()
            .enumerate()
            .max_by(|x, y| x.1.total_cmp(y.1).then(y.0.cmp(&x.0)))
            .map_or(0, |(i, _)| i);
        eig.eigenvectors.column(first).into_owned()
    });
    let v = a.transpose() * &u;
    let sigma = v.norm();
    let v = if sigma > 0.0 { v / sigma } else { v };
    (u, v)
}

/// The unit leading eigenvector of a symmetric non-negative matrix by power iteration, once
/// successive iterates agree to 1e-13; `None` after 10,000 iterations without that.
fn power_iteration(g: &DMatrix<f64>) -> Option<nalgebra::DVector<f64>> {
    let n = g.nrows();
    let mut x = nalgebra::DVector::<f64>::from_element(n, 1.0 / (n as f64).sqrt());
    for _ in 0..10_000 {
        let mut y = g * &x;
        let norm = y.norm();
        if norm == 0.0 || !norm.is_finite() {
            return None;
        }
        y /= norm;
        let change = (&y - &x).amax();
        x = y;
        if change < 1e-13 {
            return Some(x);
        }
    }
    None
}
