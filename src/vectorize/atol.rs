//! ATOL (Royer et al. 2021) exactly as `gudhi.representations.Atol` 3.13 (REFERENCE §2):
//! centres sorted lexicographically by (death, birth), inertias = half the distance to the
//! nearest distinct centre, and `v_j = Σ_i w_i · C(‖x_i − c_j‖ / σ_j)` for the contrasts
//! gaussian, laplacian, indicator and the weightings cloud (w = 1) and iidproba (w = 1/n).
//! Points with an infinite coordinate contribute 0 to finite centres (and NaN against the
//! infinite filler centres, as in GUDHI).

/// A diagram point (birth, death).
pub type Point2 = [f64; 2];

/// The contrast function.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
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
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
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
    /// The quantiser returned no centre.
    #[error("ATOL needs at least one centre")]
    NoCentre,
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

impl Atol {
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
    pub fn transform_into(&self, measure: &[Point2], out: &mut [f64]) {
        out.iter_mut().for_each(|x| *x = 0.0);
        if measure.is_empty() {
            return;
        }
        let w = match self.weighting {
            Weighting::Cloud => 1.0,
            Weighting::Iidproba => 1.0 / measure.len() as f64,
        };
        for (j, (c, &s)) in self.centers.iter().zip(&self.inertias).enumerate() {
            let mut acc = 0.0;
            match self.contrast {
                Contrast::Gaussian => {
                    for x in measure {
                        let d = dist(x, c);
                        acc += w * (-(d * d) / (s * s)).exp();
                    }
                }
                Contrast::Laplacian => {
                    for x in measure {
                        acc += w * (-dist(x, c) / s).exp();
                    }
                }
                Contrast::Indicator => {
                    for x in measure {
                        let t = 2.0 - dist(x, c) / s;
                        // np.clip keeps NaN.
                        acc += w * if t.is_nan() { t } else { t.clamp(0.0, 1.0) };
                    }
                }
            }
            out[j] = acc;
        }
    }
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
