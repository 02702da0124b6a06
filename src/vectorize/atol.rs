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
pub struct AtolFitter {
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
    pub fn new(
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
    pub fn add(&mut self, measure: &[Point2], key: u64) {
        self.measures += 1;
        let w = match self.weighting {
            Weighting::Cloud => 1.0,
            Weighting::Iidproba => 1.0 / measure.len() as f64,
        };
        for (i, p) in measure.iter().enumerate().filter(|(_, p)| !p[0].is_infinite() && !p[1].is_infinite()) {
            self.reservoir.push(key, i as u64, *p, w);
        }
    }

    /// Finite points offered so far.
    pub fn points_seen(&self) -> u64 {
        self.reservoir.seen()
    }

    /// Runs the quantiser and builds the model.
    pub fn finish(self) -> Result<Atol, AtolError> {
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
    /// Fits a model on all points of `measures` (no sampling limit); see [`AtolFitter`].
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
                Contrast::Gaussian => {
                    let inv2 = inv * inv;
                    for ((t, x), y) in terms.iter_mut().zip(&xs).zip(&ys) {
                        let (dx, dy) = (x - c[0], y - c[1]);
                        *t = (-(dx * dx + dy * dy) * inv2).exp();
                    }
                }
                Contrast::Laplacian => {
                    for ((t, x), y) in terms.iter_mut().zip(&xs).zip(&ys) {
                        let (dx, dy) = (x - c[0], y - c[1]);
                        *t = (-(dx * dx + dy * dy).sqrt() * inv).exp();
                    }
                }
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
