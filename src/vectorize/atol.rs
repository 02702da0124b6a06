//! ATOL (Royer et al. 2021) exactly as `gudhi.representations.Atol` 3.13 (`gudhi/representations/vector_methods.py`):
//! centres sorted lexicographically by (death, birth), inertias = half the distance to the
//! nearest distinct centre, and `v_j = Σ_i w_i · C(‖x_i − c_j‖ / σ_j)` for the contrasts
//! gaussian, laplacian, indicator and the weightings cloud (w = 1) and iidproba (w = 1/n).
//! Points with an infinite coordinate contribute 0 to finite centres (and NaN against the
//! infinite filler centres, as in GUDHI).

use super::kmeans::{self, KMeansError, KMeansParams};
use super::reservoir::Reservoir;

pub use crate::types::Point2;

/// The contrast function.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Contrast {
    /// `exp(−d² / σ²)`.
    Gaussian,
    /// `exp(−d / σ)`.
    Laplacian,
    /// `clip(2 − d / σ, 0, 1)`.
    Indicator,
}

/// Per-point weights of a measure.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Weighting {
    /// Every point weighs 1 (a sum).
    Cloud,
    /// Every point weighs 1/n (a mean).
    Iidproba,
}

/// Errors building a model, with GUDHI's messages.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum AtolError {
    /// No measure at all.
    #[error("Cannot fit Atol on empty target.")]
    EmptyTarget,
    /// Every point has an infinite coordinate.
    #[error("Cannot fit Atol on measure with infinite components only.")]
    OnlyInfinite,
    /// The quantiser returned no centre, or `b` is 0.
    #[error("ATOL needs at least one centre")]
    NoCentre,
    /// The k-means quantiser failed.
    #[error(transparent)]
    KMeans(#[from] KMeansError),
}

/// A fitted ATOL model.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Atol {
    /// Centres, sorted by (death, birth); `[inf, inf]` fillers last when the fit had too few
    /// points.
    pub centers: Vec<Point2>,
    /// Scale σ of each centre.
    pub inertias: Vec<f64>,
    /// Contrast function.
    pub contrast: Contrast,
    /// Weighting.
    pub weighting: Weighting,
}

/// Fits an ATOL model on measures streamed one at a time, as `Atol(quantiser).fit(measures)`
/// with a k-means quantiser of `b` clusters: weights from the weighting method, points with an
/// infinite coordinate removed, `b` lowered to the number of points when there are fewer (then
/// filled with `[inf, inf]` centres). Holds at most `sample_size` points: the quantiser is
/// fitted on a uniform reservoir sample of the finite points.
#[derive(Clone, Debug)]
pub(crate) struct AtolFitter {
    b: usize,
    contrast: Contrast,
    weighting: Weighting,
    kmeans: KMeansParams,
    seed: u64,
    reservoir: Reservoir,
    measures: u64,
}

impl AtolFitter {
    /// A fitter for `b` centres, sampling at most `sample_size` points, seeded by `seed`.
    pub(crate) fn new(
        b: usize,
        contrast: Contrast,
        weighting: Weighting,
        kmeans: KMeansParams,
        sample_size: usize,
        seed: u64,
    ) -> Self {
        AtolFitter {
            b,
            contrast,
            weighting,
            kmeans,
            seed,
            reservoir: Reservoir::new(sample_size, seed),
            measures: 0,
        }
    }

    /// Adds one measure (a diagram's points; infinite points are counted for `iidproba`'s
    /// weights, then dropped). `key` names the measure (a hash of its scan id): the sample
    /// depends on the keys offered, not on their order.
    pub(crate) fn add(&mut self, measure: &[Point2], key: u64) {
        self.measures += 1;
        let w = match self.weighting {
            Weighting::Cloud => 1.0,
            Weighting::Iidproba => 1.0 / measure.len() as f64,
        };
        for (i, p) in measure.iter().enumerate().filter(|(_, p)| !p[0].is_infinite() && !p[1].is_infinite()) {
            self.reservoir.push(key, i as u64, *p, w);
        }
    }

    /// Adds a fitter of the same settings fed with other measures (fitting in parallel).
    pub(crate) fn merge(&mut self, other: AtolFitter) {
        self.measures += other.measures;
        self.reservoir.merge(other.reservoir);
    }

    /// Finite points offered so far.
    pub(crate) fn points_seen(&self) -> u64 {
        self.reservoir.seen()
    }

    /// Runs the quantiser and builds the model.
    pub(crate) fn finish(self) -> Result<Atol, AtolError> {
        if self.b == 0 {
            return Err(AtolError::NoCentre);
        }
        if self.measures == 0 {
            return Err(AtolError::EmptyTarget);
        }
        let (points, weights) = self.reservoir.into_sample();
        let (points, weights) = (&points[..], &weights[..]);
        if points.is_empty() {
            return Err(AtolError::OnlyInfinite);
        }
        let k = self.b.min(points.len());
        if k < self.b {
            tracing::warn!(
                points = points.len(),
                b = self.b,
                "ATOL: too few points to fit b centres; adding meaningless (inf) centres"
            );
        }
        let centers = kmeans::fit(points, weights, k, &self.kmeans, self.seed)?;
        Atol::from_centers(centers, self.b, points, self.contrast, self.weighting)
    }
}

impl Atol {
    /// Fits a model on all points of `measures` (no sampling limit); see `AtolFitter`.
    pub fn fit(
        measures: &[&[Point2]],
        b: usize,
        contrast: Contrast,
        weighting: Weighting,
        kmeans: &KMeansParams,
        seed: u64,
    ) -> Result<Self, AtolError> {
        let mut fitter = AtolFitter::new(b, contrast, weighting, kmeans.clone(), usize::MAX, seed);
        measures.iter().enumerate().for_each(|(i, m)| fitter.add(m, i as u64));
        fitter.finish()
    }

    /// Builds the model from the quantiser's raw centres, as `Atol.fit` does after
    /// `quantiser.fit`: `target_clusters` is the requested number of centres `b`, and
    /// `fit_points` the finite points the quantiser was fitted on (only their diameter is used,
    /// when a single centre was fitted). If fewer centres than `b` were fitted (too few points),
    /// `[inf, inf]` centres with σ = 0 are appended.
    pub fn from_centers(
        mut centers: Vec<Point2>,
        target_clusters: usize,
        fit_points: &[Point2],
        contrast: Contrast,
        weighting: Weighting,
    ) -> Result<Self, AtolError> {
        if centers.is_empty() {
            return Err(AtolError::NoCentre);
        }
        // np.lexsort(centers.T): the last coordinate is the primary key; stable.
        centers.sort_by(|a, b| a[1].total_cmp(&b[1]).then(a[0].total_cmp(&b[0])));
        let mut inertias = if centers.len() == 1 {
            let d = diameter(fit_points) / 2.0;
            vec![if d == 0.0 { 1.0 } else { d }]
        } else {
            centers
                .iter()
                .map(|c| {
                    let nearest = centers
                        .iter()
                        .map(|o| dist(c, o))
                        .filter(|&d| d != 0.0)
                        .fold(f64::INFINITY, f64::min);
                    nearest / 2.0
                })
                .collect()
        };
        while centers.len() < target_clusters {
            centers.push([f64::INFINITY; 2]);
            inertias.push(0.0);
        }
        Ok(Atol { centers, inertias, contrast, weighting })
    }

    /// Descriptor length `b`.
    pub fn len(&self) -> usize {
        self.centers.len()
    }

    /// Whether the model has no centre.
    pub fn is_empty(&self) -> bool {
        self.centers.is_empty()
    }

    /// The ATOL vector of one measure (an empty measure gives zeros).
    pub fn transform(&self, measure: &[Point2]) -> Vec<f64> {
        let mut v = vec![0.0; self.centers.len()];
        self.transform_into(measure, &mut v);
        v
    }

    /// [`Atol::transform`] into a caller's buffer of length `b`.
    ///
    /// Loops centre-outer, point-inner over struct-of-arrays coordinates, multiplying by σ's
    /// reciprocal and summing in four lanes: each term is within an ulp or two of GUDHI's.
    pub fn transform_into(&self, measure: &[Point2], out: &mut [f64]) {
        out.iter_mut().for_each(|x| *x = 0.0);
        if measure.is_empty() {
            return;
        }
        let w = match self.weighting {
            Weighting::Cloud => 1.0,
            Weighting::Iidproba => 1.0 / measure.len() as f64,
        };
        let xs: Vec<f64> = measure.iter().map(|p| p[0]).collect();
        let ys: Vec<f64> = measure.iter().map(|p| p[1]).collect();
        let mut terms = vec![0.0; xs.len()];
        for (j, (c, &s)) in self.centers.iter().zip(&self.inertias).enumerate() {
            let inv = 1.0 / s;
            // σ = 0 or ∞ (filler or coincident centres) gives 0·∞ and ∞/∞ cases: there, take
            // GUDHI's literal division.
            let literal = !(inv.is_finite() && inv > 0.0);
            let each = |f: &dyn Fn(f64) -> f64, terms: &mut [f64]| {
                for ((t, x), y) in terms.iter_mut().zip(&xs).zip(&ys) {
                    let (dx, dy) = (x - c[0], y - c[1]);
                    *t = f((dx * dx + dy * dy).sqrt());
                }
            };
            match self.contrast {
                Contrast::Gaussian if literal => each(&|d| (-(d * d) / (s * s)).exp(), &mut terms),
                Contrast::Laplacian if literal => each(&|d| (-d / s).exp(), &mut terms),
                Contrast::Gaussian => contrast_terms(&xs, &ys, *c, inv * inv, true, &mut terms),
                Contrast::Laplacian => contrast_terms(&xs, &ys, *c, inv, false, &mut terms),
                Contrast::Indicator => each(
                    &|d| {
                        let t = 2.0 - d / s;
                        // np.clip keeps NaN.
                        if t.is_nan() { t } else { t.clamp(0.0, 1.0) }
                    },
                    &mut terms,
                ),
            }
            out[j] = w * sum(&terms);
        }
    }
}

/// The gaussian (`e^(−d²·scale)`) or laplacian (`e^(−d·scale)`) term of each point `(x, y)`
/// for the centre `c`. With AVX2, the same operations four values at a time: results are
/// bit-identical on every x86-64 (no fused multiply-add is used).
fn contrast_terms(xs: &[f64], ys: &[f64], c: Point2, scale: f64, gaussian: bool, terms: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { contrast_terms_avx2(xs, ys, c, scale, gaussian, terms) };
    }
    contrast_terms_portable(xs, ys, c, scale, gaussian, terms)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn contrast_terms_avx2(xs: &[f64], ys: &[f64], c: Point2, scale: f64, gaussian: bool, terms: &mut [f64]) {
    contrast_terms_portable(xs, ys, c, scale, gaussian, terms)
}

#[inline(always)]
fn contrast_terms_portable(xs: &[f64], ys: &[f64], c: Point2, scale: f64, gaussian: bool, terms: &mut [f64]) {
    if gaussian {
        for ((t, x), y) in terms.iter_mut().zip(xs).zip(ys) {
            let (dx, dy) = (x - c[0], y - c[1]);
            *t = exp_nonpositive(-(dx * dx + dy * dy) * scale);
        }
    } else {
        for ((t, x), y) in terms.iter_mut().zip(xs).zip(ys) {
            let (dx, dy) = (x - c[0], y - c[1]);
            *t = exp_nonpositive(-(dx * dx + dy * dy).sqrt() * scale);
        }
    }
}

/// `e^x` for `x ≤ 0` (and `-∞`, giving 0), within 2 ulp of the correctly rounded value, with
/// subnormal results rounded once. Branch-free, so the contrast loops vectorize (libm's `exp`
/// is a call per value, and was most of the time of a transform). Range reduction by ln 2
/// (Cody–Waite), Taylor polynomial of degree 13 on |r| ≤ ln 2 / 2, scaling by 2^k in two
/// halves so that every intermediate stays a normal number.
#[inline(always)]
fn exp_nonpositive(x: f64) -> f64 {
    // Adding 2^52 + 2^51 rounds a double of magnitude < 2^51 to an integer.
    const ROUND: f64 = 6_755_399_441_055_744.0;
    const INV_LN2: f64 = std::f64::consts::LOG2_E;
    // ln 2 split in two (fdlibm's constants): k · LN2_HI is exact for |k| < 2^11.
    const LN2_HI: f64 = f64::from_bits(0x3FE6_2E42_FEE0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3DEA_39EF_3579_3C76);
    // Below, e^x rounds to zero (and the halves of k stay above −1022).
    let x = x.max(-746.0);
    let k = (x * INV_LN2 + ROUND) - ROUND;
    let r = (x - k * LN2_HI) - k * LN2_LO;
    // Σ r^n / n! for n ≤ 13, Horner.
    let mut p = 1.0 / 6_227_020_800.0;
    for n in (1..=12).rev() {
        p = p * r + INV_FACTORIAL[n];
    }
    let p = p * r + 1.0;
    let k1 = (k * 0.5 + ROUND) - ROUND;
    p * pow2(k1) * pow2(k - k1)
}

/// 1 / n! for n = 0..=12.
const INV_FACTORIAL: [f64; 13] = [
    1.0,
    1.0,
    1.0 / 2.0,
    1.0 / 6.0,
    1.0 / 24.0,
    1.0 / 120.0,
    1.0 / 720.0,
    1.0 / 5_040.0,
    1.0 / 40_320.0,
    1.0 / 362_880.0,
    1.0 / 3_628_800.0,
    1.0 / 39_916_800.0,
    1.0 / 479_001_600.0,
];

/// `2^m` for an integer-valued `m` in −1022..=1023, built from its exponent bits.
#[inline(always)]
fn pow2(m: f64) -> f64 {
    // m + 1023 lands in the low mantissa bits of 2^52 + (m + 1023).
    const TWO52: f64 = 4_503_599_627_370_496.0;
    let biased = (m + (1023.0 + TWO52)).to_bits() & ((1u64 << 52) - 1);
    f64::from_bits(biased << 52)
}

/// A sum in four interleaved lanes (vectorizes; the order differs from numpy's pairwise sum
/// by rounding only).
fn sum(v: &[f64]) -> f64 {
    let mut lanes = [0.0; 4];
    let chunks = v.chunks_exact(4);
    let rest: f64 = chunks.remainder().iter().sum();
    for c in chunks {
        for k in 0..4 {
            lanes[k] += c[k];
        }
    }
    (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]) + rest
}

#[inline]
fn dist(a: &Point2, b: &Point2) -> f64 {
    let (dx, dy) = (a[0] - b[0], a[1] - b[1]);
    (dx * dx + dy * dy).sqrt()
}

/// Largest pairwise distance (0 for fewer than two points): brute force over the convex hull.
fn diameter(points: &[Point2]) -> f64 {
    let hull = convex_hull(points);
    let mut best = 0.0f64;
    for (i, a) in hull.iter().enumerate() {
        for b in &hull[i + 1..] {
            best = best.max(dist(a, b));
        }
    }
    best
}

/// Andrew's monotone chain (collinear points dropped; all points kept if fewer than 3).
fn convex_hull(points: &[Point2]) -> Vec<Point2> {
    let mut p: Vec<Point2> = points.to_vec();
    p.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    let cross =
        |o: &Point2, a: &Point2, b: &Point2| (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
    let mut hull: Vec<Point2> = Vec::with_capacity(2 * p.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &Point2>> =
            if pass == 0 { Box::new(p.iter()) } else { Box::new(p.iter().rev()) };
        for q in iter {
            while hull.len() >= start + 2 && cross(&hull[hull.len() - 2], &hull[hull.len() - 1], q) <= 0.0 {
                hull.pop();
            }
            hull.push(*q);
        }
        hull.pop();
    }
    hull
}

#[cfg(test)]
mod tests {
    use super::exp_nonpositive;

    #[test]
    fn exp_nonpositive_equals_libm_within_two_ulp() {
        let mut rng = crate::rng::SplitMix64(11);
        let mut worst = 0.0f64;
        for i in 0..2_000_000 {
            let x = match i % 4 {
                0 => -rng.next_f64() * 1.0,
                1 => -rng.next_f64() * 50.0,
                2 => -rng.next_f64() * 708.0,
                _ => -rng.next_f64() * 746.0,
            };
            let (ours, libm) = (exp_nonpositive(x), x.exp());
            if libm >= f64::MIN_POSITIVE {
                worst = worst.max((ours - libm).abs() / libm);
            } else {
                // Subnormal: within two units of the last place there.
                assert!((ours - libm).abs() <= 2.0 * 4.9e-324, "x {x}: {ours:e} vs {libm:e}");
            }
        }
        assert!(worst <= 2.0 * f64::EPSILON, "largest relative difference {worst:e}");
        assert_eq!(exp_nonpositive(0.0), 1.0);
        assert_eq!(exp_nonpositive(f64::NEG_INFINITY), 0.0);
        assert_eq!(exp_nonpositive(-800.0), 0.0);
    }
}
