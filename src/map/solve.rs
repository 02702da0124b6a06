//! A pose graph and its optimization: Levenberg–Marquardt over the poses (the normal equations
//! solved by [`super::sparse`]), each edge's error `Log(Z⁻¹ X_i⁻¹ X_j)` weighted by its
//! information matrix, the cost `½ Σ w eᵀ Ω e` (GTSAM's `graph.error`).
//!
//! **Robust edges.** An edge marked robust (a loop) may be wrong. With `robust`, such edges are
//! weighed by graduated non-convexity with a truncated least-squares cost (Yang, Antonante,
//! Tzoumas, Carlone, *Graduated Non-Convexity for Robust Spatial Perception*, RA-L 2020): a loop
//! whose error, in the units of its own information, exceeds the χ² bound of its degrees of
//! freedom at 0.99 (11.34 for 3, 16.81 for 6) after the others have settled costs nothing and
//! pulls nothing. Its weight starts at 1 and is driven to 0 or 1 as the cost goes from convex
//! (least squares) to the truncated one, each step a solve warm-started from the last; a loop is
//! kept when its final weight is above ½. The bound comes from the edge's own information, not
//! from any drive: a loop is rejected because it disagrees with the odometry and with the other
//! loops by more than its stated uncertainty allows.

use super::lie::Pose;
use super::sparse::{Factor, Pattern};
use nalgebra::{SMatrix, SVector};

/// One edge: the relative pose `measured` of vertex `to` in vertex `from`'s frame.
#[derive(Clone, Debug)]
pub struct Edge<P, const D: usize> {
    /// The first vertex (by index).
    pub from: usize,
    /// The second.
    pub to: usize,
    /// `X_from⁻¹ X_to` as measured.
    pub measured: P,
    /// The information matrix of its error (g2o's order: translation, then rotation).
    pub information: SMatrix<f64, D, D>,
    /// Whether it may be wrong (a loop): weighed by the robust cost.
    pub robust: bool,
}

/// A pose graph: poses by index, which are held, and the edges.
#[derive(Clone, Debug)]
pub struct Graph<P, const D: usize> {
    /// The poses (the initial guess, then the solution).
    pub poses: Vec<P>,
    /// Whether each pose is held where it is.
    pub fixed: Vec<bool>,
    /// The edges.
    pub edges: Vec<Edge<P, D>>,
}

/// How to optimize.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    /// Weigh the robust edges by graduated non-convexity (see the module doc).
    pub robust: bool,
    /// Levenberg–Marquardt iterations at most, per solve.
    pub max_iterations: usize,
    /// A solve has converged when an iteration lowers the cost by less than this fraction of it
    /// (1e-5, GTSAM's `relativeErrorTol`).
    pub relative_tolerance: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options { robust: true, max_iterations: 1000, relative_tolerance: 1e-5 }
    }
}

/// What an optimization did.
#[derive(Clone, Debug)]
pub struct Solution {
    /// The cost of the initial guess, every edge weighed 1.
    pub initial_cost: f64,
    /// The final cost (the robust edges at their final weights).
    pub cost: f64,
    /// Levenberg–Marquardt iterations, over every solve.
    pub iterations: usize,
    /// Each edge's weight: 1 for the edges that are not robust; the kept loops near 1, the
    /// rejected ones near 0.
    pub weights: Vec<f64>,
}

impl Solution {
    /// Whether edge `e` is kept (its weight above ½).
    pub fn kept(&self, e: usize) -> bool {
        self.weights[e] > 0.5
    }
}

/// Why an optimization failed: it did not converge (its last cost, the iterations spent).
#[derive(Clone, Debug, PartialEq)]
pub struct NotConverged {
    /// The cost when it stopped.
    pub cost: f64,
    /// Iterations spent.
    pub iterations: usize,
}

/// The χ² bound of `dof` degrees of freedom at probability 0.99.
fn chi2_99(dof: usize) -> f64 {
    match dof {
        3 => 11.345,
        6 => 16.812,
        _ => unreachable!("SE(2) or SE(3)"),
    }
}

impl<P: Pose<D>, const D: usize> Graph<P, D> {
    /// The error of edge `e` at `poses`.
    fn error(&self, poses: &[P], e: &Edge<P, D>, measured_inverse: &P) -> SVector<f64, D> {
        poses[e.from].between_error(&poses[e.to], measured_inverse)
    }

    /// `½ Σ w eᵀ Ω e` at `poses`.
    fn cost_at(&self, poses: &[P], weights: &[f64], inverses: &[P]) -> f64 {
        self.edges
            .iter()
            .zip(weights)
            .zip(inverses)
            .map(|((e, w), z)| {
                let r = self.error(poses, e, z);
                0.5 * w * (r.transpose() * e.information * r)[0]
            })
            .sum()
    }

    /// Each edge's `eᵀ Ω e` at the current poses.
    pub fn squared_errors(&self) -> Vec<f64> {
        self.edges
            .iter()
            .map(|e| {
                let r = self.error(&self.poses, e, &e.measured.inverse());
                (r.transpose() * e.information * r)[0]
            })
            .collect()
    }

    /// The cost of the current poses, every edge weighed 1.
    pub fn cost(&self) -> f64 {
        let inverses: Vec<P> = self.edges.iter().map(|e| e.measured.inverse()).collect();
        self.cost_at(&self.poses, &vec![1.0; self.edges.len()], &inverses)
    }

    /// Optimizes the poses in place (see the module doc). Every connected part of the graph
    /// needs a held pose; [`Graph::hold_one_per_part`] gives each one.
    pub fn optimize(&mut self, options: &Options) -> Result<Solution, NotConverged> {
        let initial_cost = self.cost();
        let mut weights = vec![1.0; self.edges.len()];
        let mut iterations = self.least_squares(&weights, options, 0)?;
        let robust: Vec<usize> = (0..self.edges.len()).filter(|&e| self.edges[e].robust).collect();
        if options.robust && !robust.is_empty() {
            let bound = chi2_99(D);
            let r2 = self.squared_errors();
            let worst = robust.iter().map(|&e| r2[e]).fold(0.0, f64::max);
            if worst > bound {
                // μ from the worst residual, so the first surrogate is convex over all of them.
                let mut mu = bound / (2.0 * worst - bound).max(1e-12);
                for _ in 0..1000 {
                    let r2 = self.squared_errors();
                    let before = weights.clone();
                    for &e in &robust {
                        weights[e] = tls_weight(r2[e], bound, mu);
                    }
                    iterations += self.least_squares(&weights, options, iterations)?;
                    let binary = robust.iter().all(|&e| weights[e] < 1e-6 || weights[e] > 1.0 - 1e-6);
                    let still = robust.iter().all(|&e| (weights[e] - before[e]).abs() < 1e-9);
                    if binary && still {
                        break;
                    }
                    mu *= 1.4;
                }
            }
        }
        let inverses: Vec<P> = self.edges.iter().map(|e| e.measured.inverse()).collect();
        let cost = self.cost_at(&self.poses, &weights, &inverses);
        Ok(Solution { initial_cost, cost, iterations, weights })
    }

    /// Holds the first pose of every connected part that holds none (the gauge); returns the
    /// parts, each as its poses.
    pub fn hold_one_per_part(&mut self) -> Vec<Vec<usize>> {
        let parts = self.parts();
        for part in &parts {
            if !part.iter().any(|&v| self.fixed[v]) {
                self.fixed[part[0]] = true;
            }
        }
        parts
    }

    /// The connected parts of the graph, each as its poses ascending, by their first pose.
    pub fn parts(&self) -> Vec<Vec<usize>> {
        let n = self.poses.len();
        let mut parent: Vec<usize> = (0..n).collect();
        fn root(parent: &mut [usize], mut v: usize) -> usize {
            while parent[v] != v {
                parent[v] = parent[parent[v]];
                v = parent[v];
            }
            v
        }
        for e in &self.edges {
            let (a, b) = (root(&mut parent, e.from), root(&mut parent, e.to));
            if a != b {
                parent[a.max(b)] = a.min(b);
            }
        }
        let mut parts: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
        for v in 0..n {
            let r = root(&mut parent, v);
            parts.entry(r).or_default().push(v);
        }
        parts.into_values().collect()
    }

    /// The variables, the poses not held: each pose's variable (`usize::MAX` when held), and
    /// each variable's pose.
    pub(super) fn variables(&self) -> (Vec<usize>, Vec<usize>) {
        let mut variable = vec![usize::MAX; self.poses.len()];
        let mut free: Vec<usize> = Vec::new();
        for (v, &held) in self.fixed.iter().enumerate() {
            if !held {
                variable[v] = free.len();
                free.push(v);
            }
        }
        (variable, free)
    }

    /// The normal equations' pattern over `count` variables: the edges between two of them.
    pub(super) fn pattern(&self, variable: &[usize], count: usize) -> Pattern {
        let links: Vec<(usize, usize)> = self
            .edges
            .iter()
            .filter(|e| variable[e.from] != usize::MAX && variable[e.to] != usize::MAX)
            .map(|e| (variable[e.from], variable[e.to]))
            .collect();
        Pattern::new(count, &links)
    }

    /// Levenberg–Marquardt on the weighted least-squares cost, from the current poses; returns
    /// the iterations spent (`spent`: before this solve, for the error's count).
    fn least_squares(
        &mut self,
        weights: &[f64],
        options: &Options,
        spent: usize,
    ) -> Result<usize, NotConverged> {
        let (variable, free) = self.variables();
        if free.is_empty() {
            return Ok(0);
        }
        let pattern = self.pattern(&variable, free.len());
        let inverses: Vec<P> = self.edges.iter().map(|e| e.measured.inverse()).collect();
        let mut cost = self.cost_at(&self.poses, weights, &inverses);
        // λ starts at GTSAM's 1e-5 and moves by tens (Marquardt's damping on the diagonal's
        // scale converged in fewer iterations than GTSAM's λI or Nielsen's gain-ratio rule on
        // the public graphs of docs/performance.md).
        let mut lambda = 1e-5;
        for iteration in 0..options.max_iterations {
            let (hessian, gradient) = self.normal_equations(&pattern, &variable, weights, &inverses);
            // Marquardt's damping, λ on the diagonal's own scale (every pose a little, so a pose
            // an edge barely constrains cannot make the system singular).
            let diagonal: Vec<SVector<f64, D>> =
                (0..free.len()).map(|v| hessian.diagonal_of(v).diagonal().map(|x| x.max(1e-9))).collect();
            let mut accepted = false;
            for _ in 0..30 {
                let mut trial = hessian.clone();
                for (k, d) in diagonal.iter().enumerate() {
                    trial.add_diagonal(k, &SMatrix::<f64, D, D>::from_diagonal(&(d * lambda)));
                }
                if trial.factor().is_err() {
                    lambda *= 10.0;
                    continue;
                }
                let step = trial.solve(&gradient.iter().map(|g| -g).collect::<Vec<_>>());
                let moved: Vec<P> = self
                    .poses
                    .iter()
                    .enumerate()
                    .map(|(v, p)| if variable[v] == usize::MAX { *p } else { p.retract(&step[variable[v]]) })
                    .collect();
                let new_cost = self.cost_at(&moved, weights, &inverses);
                if new_cost.is_finite() && new_cost <= cost {
                    let decrease = cost - new_cost;
                    self.poses = moved;
                    cost = new_cost;
                    lambda = (lambda / 10.0).max(1e-12);
                    accepted = true;
                    if decrease <= options.relative_tolerance * cost.max(f64::MIN_POSITIVE) {
                        return Ok(iteration + 1);
                    }
                    break;
                }
                lambda *= 10.0;
                if lambda > 1e16 {
                    break;
                }
            }
            if !accepted {
                // No step lowers the cost: a minimum, as far as this precision sees.
                return Ok(iteration + 1);
            }
        }
        Err(NotConverged { cost, iterations: spent + options.max_iterations })
    }

    /// The Gauss–Newton normal equations `H δ = −g` at the current poses over the variables:
    /// `H` on `pattern`, `g` by variable.
    fn normal_equations<'p>(
        &self,
        pattern: &'p Pattern,
        variable: &[usize],
        weights: &[f64],
        inverses: &[P],
    ) -> (Factor<'p, D>, Vec<SVector<f64, D>>) {
        let mut h = Factor::<D>::zeros(pattern);
        let mut g = vec![SVector::<f64, D>::zeros(); pattern.len()];
        for ((e, &w), z) in self.edges.iter().zip(weights).zip(inverses) {
            if w == 0.0 {
                continue;
            }
            let (vi, vj) = (variable[e.from], variable[e.to]);
            if vi == usize::MAX && vj == usize::MAX {
                continue;
            }
            let r = self.error(&self.poses, e, z);
            let (ji, jj) = self.jacobians(e, z);
            let omega = e.information * w;
            if vi != usize::MAX {
                h.add_diagonal(vi, &(ji.transpose() * omega * ji));
                g[vi] += ji.transpose() * omega * r;
            }
            if vj != usize::MAX {
                h.add_diagonal(vj, &(jj.transpose() * omega * jj));
                g[vj] += jj.transpose() * omega * r;
            }
            if vi != usize::MAX && vj != usize::MAX && vi != vj {
                h.add_off(vj, vi, &(jj.transpose() * omega * ji));
            }
        }
        (h, g)
    }

    /// The Jacobians of an edge's error with respect to right perturbations of its two poses,
    /// by central differences (exact to about 1e-10).
    fn jacobians(&self, e: &Edge<P, D>, z: &P) -> (SMatrix<f64, D, D>, SMatrix<f64, D, D>) {
        const H: f64 = 1e-6;
        let (pi, pj) = (self.poses[e.from], self.poses[e.to]);
        let mut ji = SMatrix::<f64, D, D>::zeros();
        let mut jj = SMatrix::<f64, D, D>::zeros();
        for k in 0..D {
            let mut d = SVector::<f64, D>::zeros();
            d[k] = H;
            let plus_i = pi.retract(&d).between_error(&pj, z);
            let minus_i = pi.retract(&(-d)).between_error(&pj, z);
            ji.set_column(k, &((plus_i - minus_i) / (2.0 * H)));
            let plus_j = pi.between_error(&pj.retract(&d), z);
            let minus_j = pi.between_error(&pj.retract(&(-d)), z);
            jj.set_column(k, &((plus_j - minus_j) / (2.0 * H)));
        }
        (ji, jj)
    }
}

/// The weight of a residual `r2` (`eᵀ Ω e`) under the truncated least-squares cost of bound
/// `bound` at the graduated non-convexity's `mu`.
fn tls_weight(r2: f64, bound: f64, mu: f64) -> f64 {
    if r2 >= (mu + 1.0) / mu * bound {
        0.0
    } else if r2 <= mu / (mu + 1.0) * bound {
        1.0
    } else {
        ((bound * mu * (mu + 1.0) / r2).sqrt() - mu).clamp(0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::super::lie::{Se2, Se3};
    use super::*;
    use nalgebra::{Isometry2, Isometry3, Vector2, Vector3};

    /// A square driven twice: odometry with a bias, a true loop at each corner, and one false loop.
    fn square() -> (Graph<Se2, 3>, Vec<Se2>) {
        let mut truth = Vec::new();
        let mut pose = Isometry2::identity();
        for k in 0..40 {
            truth.push(Se2(pose));
            let turn = if k % 10 == 9 { std::f64::consts::FRAC_PI_2 } else { 0.0 };
            pose *= Isometry2::new(Vector2::new(1.0, 0.0), turn);
        }
        let info = SMatrix::<f64, 3, 3>::from_diagonal(&SVector::<f64, 3>::new(100.0, 100.0, 1000.0));
        let mut edges = Vec::new();
        let mut guess = vec![truth[0]];
        for k in 0..39 {
            let rel = truth[k].inverse().compose(&truth[k + 1]);
            // A drifting odometry: 3 % long and 0.02 rad to the left a step.
            let biased = Se2(Isometry2::new(rel.0.translation.vector * 1.03, rel.0.rotation.angle() + 0.02));
            edges.push(Edge { from: k, to: k + 1, measured: biased, information: info, robust: false });
            guess.push(guess[k].compose(&biased));
        }
        for (a, b) in [(0, 20), (9, 29), (10, 30), (19, 39)] {
            let rel = truth[a].inverse().compose(&truth[b]);
            edges.push(Edge { from: a, to: b, measured: rel, information: info, robust: true });
        }
        // A false loop: scan 5 said to be where scan 25 is... but 3 m off to its side.
        let wrong = Se2(Isometry2::new(Vector2::new(0.0, 3.0), 0.0));
        edges.push(Edge { from: 5, to: 35, measured: wrong, information: info, robust: true });
        let n = guess.len();
        let mut fixed = vec![false; n];
        fixed[0] = true;
        (Graph { poses: guess, fixed, edges }, truth)
    }

    #[test]
    fn the_robust_map_keeps_true_loops_and_rejects_a_false_one() {
        let (mut g, truth) = square();
        let s = g.optimize(&Options::default()).unwrap();
        let false_loop = g.edges.len() - 1;
        assert!(!s.kept(false_loop), "{:?}", s.weights);
        assert!((0..g.edges.len() - 1).all(|e| s.kept(e)), "{:?}", s.weights);
        // Kept, the true loops give the map least squares gives without the false one.
        let (mut clean, _) = square();
        clean.edges.pop();
        clean.optimize(&Options { robust: false, ..Options::default() }).unwrap();
        let apart = |a: &[Se2], b: &[Se2]| {
            a.iter()
                .zip(b)
                .map(|(a, b)| (a.0.translation.vector - b.0.translation.vector).norm())
                .fold(0.0, f64::max)
        };
        assert!(
            apart(&g.poses, &clean.poses) < 1e-4,
            "{} m from the map without it",
            apart(&g.poses, &clean.poses)
        );
        let worst = apart(&g.poses, &truth);
        assert!(worst < 1.0, "{worst} m from the truth");
        // Without the robust cost, the false loop bends the map.
        let (mut plain, truth) = square();
        plain.optimize(&Options { robust: false, ..Options::default() }).unwrap();
        let bent = apart(&plain.poses, &truth);
        assert!(bent > 2.0 * worst, "{bent} against {worst}");
    }

    #[test]
    fn a_consistent_3d_graph_is_solved_to_its_truth() {
        let mut truth = Vec::new();
        let mut pose = Isometry3::identity();
        for k in 0..30 {
            truth.push(Se3(pose));
            pose *= Isometry3::new(
                Vector3::new(1.0, 0.1 * (k as f64).sin(), 0.05),
                Vector3::new(0.01, -0.02, 0.2),
            );
        }
        let info = SMatrix::<f64, 6, 6>::identity() * 50.0;
        let mut edges = Vec::new();
        let mut guess = vec![truth[0]];
        for k in 0..29 {
            let rel = truth[k].inverse().compose(&truth[k + 1]);
            edges.push(Edge { from: k, to: k + 1, measured: rel, information: info, robust: false });
            // A guess off the measurements, to be pulled back.
            guess.push(Se3(guess[k].0
                * rel.0
                * Isometry3::new(Vector3::new(0.05, 0.0, 0.0), Vector3::new(0.0, 0.0, 0.01))));
        }
        edges.push(Edge {
            from: 0,
            to: 29,
            measured: truth[0].inverse().compose(&truth[29]),
            information: info,
            robust: true,
        });
        let mut fixed = vec![false; 30];
        fixed[0] = true;
        let mut g = Graph { poses: guess, fixed, edges };
        let s = g.optimize(&Options::default()).unwrap();
        assert!(s.cost < 1e-12, "{}", s.cost);
        for (a, b) in g.poses.iter().zip(&truth) {
            assert!((a.0.translation.vector - b.0.translation.vector).norm() < 1e-6);
        }
    }
}
