//! A start for graphs whose own initial guess is far from the solution: chordal relaxation
//! (Martinec and Pajdla, *Robust rotation and translation estimation in multiview
//! reconstruction*, CVPR 2007; Carlone, Tron, Daniilidis and Dellaert, *Initialization
//! techniques for 3D SLAM: a survey on rotation estimation and its use in pose graph
//! optimization*, ICRA 2015), as GTSAM's `InitializePose3` and `InitializePose2` do.
//!
//! Odometry chained over kilometres carries its heading error into every later pose, and
//! Levenberg–Marquardt started there crawls or stops in a local minimum. The rotations are found
//! first, by linear least squares over all edges at once: each edge asks `R_j = R_i R_ij`, which
//! is linear in the rotation matrices' rows when their orthogonality is dropped; each solution
//! is then projected back onto the rotations (by SVD). With the rotations known, the translations
//! are linear too: each edge asks `t_j = t_i + R_i t_ij`. Both are solved by [`super::sparse`]'s
//! block Cholesky on the graph's own pattern; the held poses stay where they are.

use super::lie::Pose;
use super::solve::Graph;
use super::sparse::{Factor, NotPositive};
use nalgebra::{Isometry3, Matrix3, Rotation3, SVector, Translation3, UnitQuaternion, Vector3};

/// Why a start could not be made: a part of the graph holds no pose (the gauge), or the linear
/// systems are singular.
#[derive(Debug, PartialEq)]
pub struct NoStart(pub String);

impl<P: Pose<D>, const D: usize> Graph<P, D> {
    /// Replaces the free poses by the chordal relaxation's estimate (see the module doc). Every
    /// connected part needs a held pose.
    pub fn initialize_chordal(&mut self) -> Result<(), NoStart> {
        let (variable, free) = self.variables();
        if free.is_empty() {
            return Ok(());
        }
        if self.fixed.iter().all(|&f| !f) {
            return Err(NoStart("no pose is held".into()));
        }
        let pattern = self.pattern(&variable, free.len());
        let poses: Vec<Isometry3<f64>> = self.poses.iter().map(|p| p.to_3d()).collect();
        let measured: Vec<Isometry3<f64>> = self.edges.iter().map(|e| e.measured.to_3d()).collect();
        let singular = |_: NotPositive| NoStart("a part of the graph holds no pose".into());

        // Rotations: row k of each R as an unknown 3-vector x; an edge asks x_j = R_ijᵀ x_i,
        // weighed by its rotation information's mean.
        let mut h = Factor::<3>::zeros(&pattern);
        let mut rhs = [(); 3].map(|_| vec![Vector3::zeros(); free.len()]);
        for (e, z) in self.edges.iter().zip(&measured) {
            let w = rotation_weight(&e.information);
            let r = z.rotation.to_rotation_matrix().into_inner();
            let (vi, vj) = (variable[e.from], variable[e.to]);
            let ri = poses[e.from].rotation.to_rotation_matrix().into_inner();
            let rj = poses[e.to].rotation.to_rotation_matrix().into_inner();
            let eye = Matrix3::identity() * w;
            match (vi != usize::MAX, vj != usize::MAX) {
                (true, true) => {
                    h.add_diagonal(vi, &eye);
                    h.add_diagonal(vj, &eye);
                    h.add_off(vj, vi, &(-r.transpose() * w));
                }
                (true, false) => {
                    h.add_diagonal(vi, &eye);
                    for (k, b) in rhs.iter_mut().enumerate() {
                        b[vi] += r * rj.row(k).transpose() * w;
                    }
                }
                (false, true) => {
                    h.add_diagonal(vj, &eye);
                    for (k, b) in rhs.iter_mut().enumerate() {
                        b[vj] += r.transpose() * ri.row(k).transpose() * w;
                    }
                }
                (false, false) => {}
            }
        }
        h.factor().map_err(singular)?;
        let rows = rhs.map(|b| h.solve(&b));
        let rotations: Vec<Matrix3<f64>> = (0..self.poses.len())
            .map(|v| match variable[v] {
                usize::MAX => poses[v].rotation.to_rotation_matrix().into_inner(),
                k => nearest_rotation(&Matrix3::from_rows(&[
                    rows[0][k].transpose(),
                    rows[1][k].transpose(),
                    rows[2][k].transpose(),
                ])),
            })
            .collect();

        // Translations: an edge asks t_j − t_i = R_i t_ij, weighed by its translation
        // information turned into the world frame.
        let mut h = Factor::<3>::zeros(&pattern);
        let mut rhs = vec![Vector3::zeros(); free.len()];
        for (e, z) in self.edges.iter().zip(&measured) {
            let w = translation_weight(&e.information);
            let ri = rotations[e.from];
            let omega = ri * w * ri.transpose();
            let c = ri * z.translation.vector;
            let (vi, vj) = (variable[e.from], variable[e.to]);
            match (vi != usize::MAX, vj != usize::MAX) {
                (true, true) => {
                    h.add_diagonal(vi, &omega);
                    h.add_diagonal(vj, &omega);
                    h.add_off(vj, vi, &(-omega));
                    rhs[vj] += omega * c;
                    rhs[vi] -= omega * c;
                }
                (true, false) => {
                    h.add_diagonal(vi, &omega);
                    rhs[vi] += omega * (poses[e.to].translation.vector - c);
                }
                (false, true) => {
                    h.add_diagonal(vj, &omega);
                    rhs[vj] += omega * (poses[e.from].translation.vector + c);
                }
                (false, false) => {}
            }
        }
        h.factor().map_err(singular)?;
        let translations = h.solve(&rhs);
        for (k, &v) in free.iter().enumerate() {
            let rotation =
                UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rotations[v]));
            let iso = Isometry3::from_parts(Translation3::from(translations[k]), rotation);
            self.poses[v] = P::from_3d(&iso);
        }
        Ok(())
    }
}

/// The nearest rotation to `m` (Frobenius norm): `U diag(1, 1, det(U Vᵀ)) Vᵀ`.
fn nearest_rotation(m: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u.expect("asked for U"), svd.v_t.expect("asked for Vᵀ"));
    let d = (u * v_t).determinant().signum();
    u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t
}

/// An edge's rotation weight: the mean of its information's rotation diagonal (the last
/// `D − 3` entries in space, the last one in the plane), 1 when it gives none.
fn rotation_weight<const D: usize>(information: &nalgebra::SMatrix<f64, D, D>) -> f64 {
    let first = if D == 6 { 3 } else { 2 };
    let diagonal: SVector<f64, D> = information.diagonal();
    let w = (first..D).map(|k| diagonal[k]).sum::<f64>() / (D - first) as f64;
    if w.is_finite() && w > 0.0 { w } else { 1.0 }
}

/// An edge's translation information as a 3 × 3 block (in the plane, the 2 × 2 block with z
/// weighed as the mean of x and y, which the planar graph's translations never use).
fn translation_weight<const D: usize>(information: &nalgebra::SMatrix<f64, D, D>) -> Matrix3<f64> {
    let mut w = Matrix3::zeros();
    let n = if D == 6 { 3 } else { 2 };
    for i in 0..n {
        for j in 0..n {
            w[(i, j)] = information[(i, j)];
        }
    }
    if n == 2 {
        w[(2, 2)] = 0.5 * (w[(0, 0)] + w[(1, 1)]);
    }
    if w.cholesky().is_some() { w } else { Matrix3::identity() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::lie::{Se2, Se3};
    use crate::map::solve::{Edge, Options};
    use crate::rng::SplitMix64;
    use nalgebra::{Isometry2, SMatrix, Vector2};

    /// A walk round a square block several times in the plane: the truth, and a graph of its
    /// odometry (each step's heading off by a bias and noise) with a loop at every corner
    /// passed before.
    fn block_walk(laps: usize, seed: u64) -> (Vec<Se2>, Graph<Se2, 3>) {
        let mut rng = SplitMix64(seed);
        let mut truth = vec![Se2(Isometry2::identity())];
        let side = 20;
        for step in 0..laps * 4 * side {
            let turn = if (step + 1) % side == 0 { std::f64::consts::FRAC_PI_2 } else { 0.0 };
            let last = *truth.last().unwrap();
            truth.push(last.compose(&Se2(Isometry2::new(Vector2::new(1.0, 0.0), turn))));
        }
        let information = SMatrix::<f64, 3, 3>::from_diagonal(&SVector::<f64, 3>::new(100.0, 100.0, 400.0));
        let mut edges = Vec::new();
        let mut odometry = vec![truth[0]];
        for i in 0..truth.len() - 1 {
            let z = truth[i].inverse().compose(&truth[i + 1]);
            let noisy = z.compose(&Se2(Isometry2::new(Vector2::new(0.0, 0.0), 0.03 + 0.02 * rng.normal())));
            odometry.push(odometry[i].compose(&noisy));
            edges.push(Edge { from: i, to: i + 1, measured: noisy, information, robust: false });
        }
        for j in 0..truth.len() {
            for i in 0..j.saturating_sub(2 * side) {
                if i % side == 0
                    && (truth[i].position()[0] - truth[j].position()[0])
                        .hypot(truth[i].position()[1] - truth[j].position()[1])
                        < 1e-6
                {
                    let z = truth[i].inverse().compose(&truth[j]);
                    edges.push(Edge { from: i, to: j, measured: z, information, robust: true });
                }
            }
        }
        let mut fixed = vec![false; truth.len()];
        fixed[0] = true;
        (truth, Graph { poses: odometry, fixed, edges })
    }

    fn rmse(a: &[Se2], b: &[Se2]) -> f64 {
        let s: f64 = a
            .iter()
            .zip(b)
            .map(|(p, q)| {
                let (p, q) = (p.position(), q.position());
                (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)
            })
            .sum();
        (s / a.len() as f64).sqrt()
    }

    #[test]
    fn a_walk_whose_heading_drifted_by_radians_starts_near_the_truth() {
        // 0.03 rad a step of heading bias: after 8 laps of 80 steps the odometry has turned
        // about 19 rad too far. Both solves are plain least squares (no loop is wrong).
        let (truth, mut graph) = block_walk(8, 5);
        let from_odometry = rmse(&graph.poses, &truth);
        let options = Options { robust: false, ..Options::default() };
        let mut plain = graph.clone();
        let plain_solved = plain.optimize(&options).unwrap();
        graph.initialize_chordal().unwrap();
        let started = rmse(&graph.poses, &truth);
        let solved = graph.optimize(&options).unwrap();
        let said = format!(
            "odometry {from_odometry} m off; chordal start {started} m; solved from it {} m, {} iterations, cost {}; \
             from the odometry {} m, {} iterations, cost {}",
            rmse(&graph.poses, &truth),
            solved.iterations,
            solved.cost,
            rmse(&plain.poses, &truth),
            plain_solved.iterations,
            plain_solved.cost
        );
        // (Seen: 14.7 m, 1.24 m; 0.10 m in 4 iterations, cost 123.5; 7.10 m, cost 85,100.)
        assert!(from_odometry > 10.0 && started < 2.0, "{said}");
        // Levenberg–Marquardt from there reaches the truth's neighbourhood in a few iterations,
        // where from the odometry it stops in a local minimum.
        assert!(rmse(&graph.poses, &truth) < 0.5 && solved.iterations < 20, "{said}");
        assert!(solved.cost * 100.0 < plain_solved.cost, "{said}");
    }

    #[test]
    fn exact_measurements_give_the_truth_in_space() {
        // A 3D graph whose edges are exact: the relaxation is tight, so the start is the truth.
        let mut rng = SplitMix64(9);
        let truth: Vec<Se3> = (0..30)
            .map(|_| {
                Se3(Isometry3::new(
                    Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 5.0,
                    Vector3::new(rng.normal(), rng.normal(), rng.normal()),
                ))
            })
            .collect();
        let information = SMatrix::<f64, 6, 6>::identity();
        let mut edges = Vec::new();
        for i in 0..truth.len() {
            for j in [i + 1, i + 7] {
                if j < truth.len() {
                    let measured = truth[i].inverse().compose(&truth[j]);
                    edges.push(Edge { from: i, to: j, measured, information, robust: false });
                }
            }
        }
        let mut fixed = vec![false; truth.len()];
        fixed[0] = true;
        let poses = (0..truth.len()).map(|i| if i == 0 { truth[0] } else { Se3::identity() }).collect();
        let mut graph = Graph { poses, fixed, edges };
        graph.initialize_chordal().unwrap();
        for (p, t) in graph.poses.iter().zip(&truth) {
            let off = p.inverse().compose(t).log();
            assert!(off.norm() < 1e-9, "{off:?}");
        }
    }
}
