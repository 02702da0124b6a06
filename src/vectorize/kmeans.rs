//! The k-means quantiser behind ATOL's codebook (scikit-learn 1.9.1,
//! `sklearn/cluster/_kmeans.py` and `_k_means_minibatch.pyx`).
//!
//! [`Algorithm::MiniBatch`] follows scikit-learn 1.9.1's `MiniBatchKMeans` step by step:
//! k-means++ (greedy, `2 + ⌊ln k⌋` local trials) on `init_size` points drawn with replacement,
//! then mini-batches drawn with replacement ∝ sample weight, per-centre learning rate 1/N_j,
//! random reassignment of starved centres, and early stopping when the smoothed batch inertia
//! has not improved for `max_no_improvement` steps. The random streams are toporec's own
//! (SplitMix64), so centres equal sklearn's in quality, not bit for bit.
//! [`Algorithm::Lloyd`] runs full Lloyd iterations from the same seeding.
//!
//! Everything is a function of (points, weights, parameters, seed): mini-batch steps are
//! sequential, and Lloyd's parallel assignment reduces fixed-size chunks in a fixed order, so
//! results are bit-identical for any thread count.

use crate::rng::SplitMix64;
use crate::types::Point2;
use rayon::prelude::*;

/// Which k-means to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Algorithm {
    /// scikit-learn's `MiniBatchKMeans` (the paper's quantiser).
    #[value(name = "minibatch")]
    MiniBatch,
    /// Full-batch Lloyd iterations.
    Lloyd,
}

/// k-means parameters; the defaults are scikit-learn's.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct KMeansParams {
    /// The algorithm.
    pub algorithm: Algorithm,
    /// Mini-batch size (1024).
    pub batch_size: usize,
    /// Epochs for mini-batch (100), iterations for Lloyd (300).
    pub max_iter: Option<usize>,
    /// Early-stop patience of mini-batch, in steps (10).
    pub max_no_improvement: usize,
    /// Centres with fewer than this fraction of the largest count are reassigned (0.01).
    pub reassignment_ratio: f64,
    /// Lloyd's relative tolerance on the centre shift (1e-4, × mean per-feature variance).
    pub tol: f64,
}

impl Default for KMeansParams {
    fn default() -> Self {
        KMeansParams {
            algorithm: Algorithm::MiniBatch,
            batch_size: 1024,
            max_iter: None,
            max_no_improvement: 10,
            reassignment_ratio: 0.01,
            tol: 1e-4,
        }
    }
}

/// Errors of [`fit`].
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum KMeansError {
    /// Fewer points than centres (ATOL lowers `k` before calling).
    #[error("k-means: {points} point(s) for {k} centre(s)")]
    TooFewPoints {
        /// Number of points.
        points: usize,
        /// Number of centres asked for.
        k: usize,
    },
    /// A weight is negative, NaN or all weights are zero.
    #[error("k-means: sample weights must be finite, non-negative and not all zero")]
    BadWeights,
    /// A point has a non-finite coordinate.
    #[error("k-means: point {0} is not finite")]
    NonFinite(usize),
}

/// Fits `k` centres to weighted points (weights ≥ 0, e.g. ATOL's cloud/iidproba weights).
pub fn fit(
    points: &[Point2],
    weights: &[f64],
    k: usize,
    params: &KMeansParams,
    seed: u64,
) -> Result<Vec<Point2>, KMeansError> {
    assert_eq!(points.len(), weights.len(), "one weight per point");
    let n = points.len();
    if k == 0 || n < k {
        return Err(KMeansError::TooFewPoints { points: n, k });
    }
    if let Some(i) = points.iter().position(|p| !(p[0].is_finite() && p[1].is_finite())) {
        return Err(KMeansError::NonFinite(i));
    }
    if weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) || weights.iter().all(|&w| w == 0.0) {
        return Err(KMeansError::BadWeights);
    }
    let mut rng = SplitMix64(seed ^ 0x6B6D_6561_6E73_2B2B);
    let batch = params.batch_size.max(1).min(n);
    let init_size = if 3 * batch < k { 3 * k } else { 3 * batch }.min(n);
    // sklearn draws the init subset uniformly (randint), then seeds ∝ its weights.
    let init: Vec<usize> = (0..init_size).map(|_| rng.below(n)).collect();
    let init_points: Vec<Point2> = init.iter().map(|&i| points[i]).collect();
    let init_weights: Vec<f64> = init.iter().map(|&i| weights[i]).collect();
    let centers = kmeans_plus_plus(&init_points, &init_weights, k, &mut rng);
    Ok(match params.algorithm {
        Algorithm::MiniBatch => minibatch(points, weights, centers, batch, params, &mut rng),
        Algorithm::Lloyd => lloyd(points, weights, centers, params),
    })
}

/// The k-means objective: Σ w_i · min_j ‖x_i − c_j‖².
pub fn inertia(points: &[Point2], weights: &[f64], centers: &[Point2]) -> f64 {
    points.iter().zip(weights).map(|(p, w)| w * nearest(p, centers).1).sum()
}

#[inline]
fn dist2(a: &Point2, b: &Point2) -> f64 {
    let (dx, dy) = (a[0] - b[0], a[1] - b[1]);
    dx * dx + dy * dy
}

/// Index of, and squared distance to, the nearest centre (first one on ties, as sklearn).
#[inline]
fn nearest(p: &Point2, centers: &[Point2]) -> (usize, f64) {
    let mut best = (0, f64::INFINITY);
    for (j, c) in centers.iter().enumerate() {
        let d = dist2(p, c);
        if d < best.1 {
            best = (j, d);
        }
    }
    best
}

/// Index `i` with `cumulative[i-1] <= u < cumulative[i]` (numpy's `searchsorted`, clipped).
fn pick(cumulative: &[f64], u: f64) -> usize {
    cumulative.partition_point(|&c| c <= u).min(cumulative.len() - 1)
}

fn cumulative(values: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut acc = 0.0;
    values
        .map(|v| {
            acc += v;
            acc
        })
        .collect()
}

/// Greedy k-means++ as sklearn's `_kmeans_plusplus`.
fn kmeans_plus_plus(points: &[Point2], weights: &[f64], k: usize, rng: &mut SplitMix64) -> Vec<Point2> {
    let trials = 2 + (k as f64).ln() as usize;
    let wsum = cumulative(weights.iter().copied());
    let first = pick(&wsum, rng.next_f64() * wsum[wsum.len() - 1]);
    let mut centers = vec![points[first]];
    let mut closest: Vec<f64> = points.iter().map(|p| dist2(p, &points[first])).collect();
    let mut candidate = vec![0.0; points.len()];
    let mut best = vec![0.0; points.len()];
    while centers.len() < k {
        let potential = cumulative(closest.iter().zip(weights).map(|(d, w)| d * w));
        let total = potential[potential.len() - 1];
        let mut best_pot = f64::INFINITY;
        let mut best_id = 0;
        for _ in 0..trials {
            // All points on chosen centres: any point will do (duplicates are legal centres).
            let id =
                if total > 0.0 { pick(&potential, rng.next_f64() * total) } else { rng.below(points.len()) };
            let mut pot = 0.0;
            for ((c, p), (d, w)) in candidate.iter_mut().zip(points).zip(closest.iter().zip(weights)) {
                *c = d.min(dist2(p, &points[id]));
                pot += *c * w;
            }
            if pot < best_pot {
                best_pot = pot;
                best_id = id;
                std::mem::swap(&mut best, &mut candidate);
            }
        }
        centers.push(points[best_id]);
        std::mem::swap(&mut closest, &mut best);
    }
    centers
}

fn minibatch(
    points: &[Point2],
    weights: &[f64],
    mut centers: Vec<Point2>,
    batch: usize,
    params: &KMeansParams,
    rng: &mut SplitMix64,
) -> Vec<Point2> {
    let (n, k) = (points.len(), centers.len());
    let wsum = cumulative(weights.iter().copied());
    let wtotal = wsum[n - 1];
    let n_steps = params.max_iter.unwrap_or(100) * n / batch;
    let alpha = (2.0 * batch as f64 / (n as f64 + 1.0)).min(1.0);
    let mut counts = vec![0.0f64; k];
    let mut since_reassign = 0usize;
    let (mut ewa, mut ewa_min): (Option<f64>, Option<f64>) = (None, None);
    let mut no_improvement = 0;
    let mut batch_points = vec![[0.0; 2]; batch];
    let mut labels = vec![0usize; batch];
    let mut sums = vec![[0.0f64; 2]; k];
    let mut members = vec![0.0f64; k];
    for step in 0..n_steps {
        for b in batch_points.iter_mut() {
            *b = points[pick(&wsum, rng.next_f64() * wtotal)];
        }
        since_reassign += batch;
        let reassign = if counts.contains(&0.0) || since_reassign >= 10 * k {
            since_reassign = 0;
            true
        } else {
            false
        };
        // Assign with the old centres; the batch inertia is measured before the update.
        sums.iter_mut().for_each(|s| *s = [0.0; 2]);
        members.iter_mut().for_each(|m| *m = 0.0);
        let mut batch_inertia = 0.0;
        for (p, l) in batch_points.iter().zip(labels.iter_mut()) {
            let (j, d) = nearest(p, &centers);
            *l = j;
            batch_inertia += d;
            sums[j][0] += p[0];
            sums[j][1] += p[1];
            members[j] += 1.0;
        }
        for j in 0..k {
            if members[j] > 0.0 {
                let scaled = [centers[j][0] * counts[j] + sums[j][0], centers[j][1] * counts[j] + sums[j][1]];
                counts[j] += members[j];
                let a = 1.0 / counts[j];
                centers[j] = [scaled[0] * a, scaled[1] * a];
            }
        }
        if reassign && params.reassignment_ratio > 0.0 {
            reassign_starved(&mut centers, &mut counts, &batch_points, params.reassignment_ratio, rng);
        }
        // Early stop on the smoothed batch inertia (sklearn ignores the first step).
        if step == 0 {
            continue;
        }
        let b = batch_inertia / batch as f64;
        let e = match ewa {
            None => b,
            Some(e) => e * (1.0 - alpha) + b * alpha,
        };
        ewa = Some(e);
        if ewa_min.is_none_or(|m| e < m) {
            no_improvement = 0;
            ewa_min = Some(e);
        } else {
            no_improvement += 1;
        }
        if no_improvement >= params.max_no_improvement {
            tracing::debug!(step, n_steps, "mini-batch k-means converged (no improvement)");
            break;
        }
    }
    centers
}

/// sklearn's random reassignment: centres whose count is below `ratio × max count` (at most
/// half a batch of them, the smallest counts first) move to distinct random batch points.
fn reassign_starved(
    centers: &mut [Point2],
    counts: &mut [f64],
    batch_points: &[Point2],
    ratio: f64,
    rng: &mut SplitMix64,
) {
    let max = counts.iter().copied().fold(0.0, f64::max);
    let mut starved: Vec<usize> = (0..counts.len()).filter(|&j| counts[j] < ratio * max).collect();
    let cap = batch_points.len() / 2;
    if starved.len() > cap {
        // Keep the `cap` smallest counts (argsort is stable: ties by index).
        starved.sort_by(|&a, &b| counts[a].total_cmp(&counts[b]).then(a.cmp(&b)));
        starved.truncate(cap);
    }
    if starved.is_empty() {
        return;
    }
    let keep_min =
        (0..counts.len()).filter(|j| !starved.contains(j)).map(|j| counts[j]).fold(f64::INFINITY, f64::min);
    // Distinct batch positions: a partial Fisher–Yates shuffle.
    let mut order: Vec<usize> = (0..batch_points.len()).collect();
    for (i, &j) in starved.iter().enumerate() {
        let r = i + rng.below(order.len() - i);
        order.swap(i, r);
        centers[j] = batch_points[order[i]];
        counts[j] = keep_min;
    }
}

/// Points per parallel chunk in Lloyd; fixed so sums do not depend on the thread count.
const LLOYD_CHUNK: usize = 8192;

fn lloyd(points: &[Point2], weights: &[f64], mut centers: Vec<Point2>, params: &KMeansParams) -> Vec<Point2> {
    let k = centers.len();
    let wtotal: f64 = weights.iter().sum();
    let variance: f64 = (0..2)
        .map(|c| {
            let mean = points.iter().zip(weights).map(|(p, w)| p[c] * w).sum::<f64>() / wtotal;
            points.iter().zip(weights).map(|(p, w)| w * (p[c] - mean).powi(2)).sum::<f64>() / wtotal
        })
        .sum::<f64>()
        / 2.0;
    let tol = params.tol * variance;
    for iteration in 0..params.max_iter.unwrap_or(300) {
        let partial: Vec<(Vec<[f64; 2]>, Vec<f64>)> = points
            .par_chunks(LLOYD_CHUNK)
            .zip(weights.par_chunks(LLOYD_CHUNK))
            .map(|(ps, ws)| {
                let mut sums = vec![[0.0; 2]; k];
                let mut mass = vec![0.0; k];
                for (p, w) in ps.iter().zip(ws) {
                    let j = nearest(p, &centers).0;
                    sums[j][0] += p[0] * w;
                    sums[j][1] += p[1] * w;
                    mass[j] += w;
                }
                (sums, mass)
            })
            .collect();
        let mut sums = vec![[0.0; 2]; k];
        let mut mass = vec![0.0; k];
        for (s, m) in &partial {
            for j in 0..k {
                sums[j][0] += s[j][0];
                sums[j][1] += s[j][1];
                mass[j] += m[j];
            }
        }
        let mut shift = 0.0;
        for j in 0..k {
            // An empty cluster keeps its centre.
            if mass[j] > 0.0 {
                let c = [sums[j][0] / mass[j], sums[j][1] / mass[j]];
                shift += dist2(&c, &centers[j]);
                centers[j] = c;
            }
        }
        if shift <= tol {
            tracing::debug!(iteration, "Lloyd k-means converged");
            break;
        }
    }
    centers
}
