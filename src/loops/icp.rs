//! The geometric check of a loop: the two scans aligned by point-to-plane ICP (Chen and
//! Medioni, *Object modelling by registration of multiple range images*, 1992; the linearised
//! least-squares step of Low, *Linear least-squares optimization for point-to-plane ICP surface
//! registration*, 2004) on voxelized scans, from an initial guess (the descriptor's yaw).
//!
//! Each target voxel's normal is the least-variance direction of its nearest neighbours. Each
//! iteration pairs every transformed source point with its nearest target voxel within a
//! correspondence distance (shrinking over the stages, coarse to fine), and solves the 6×6
//! normal equations of the point-to-plane residuals for a small rotation and a translation.
//!
//! The source is paired at a resolution per stage (2 m, 1 m, then the target's 0.5 m), as
//! KISS-ICP registers a downsampled scan against a finer map: the coarse stages, which slide the
//! scans into place, are cheap, and the last sets the pose. The descriptor's yaw is known up to
//! its sign, so both guesses try a few coarse steps and the one pairing more source voxels goes
//! on. The result is scored at the final pose on the source's 0.5 m voxels: how much of the
//! source found a partner within the last stage's distance (the fitness) and how far off the
//! planes the partners are (the RMSE), which a caller compares with its thresholds. A target is
//! made ready once ([`Target`]: voxels, k-d tree, normals) and aligned against as often as needed.
//!
//! Most of the work is finding each source voxel's nearest target voxel, step after step, while
//! the steps shrink to millimetres. Each voxel keeps its few nearest candidates from its last
//! search and answers from them for as long as they provably hold the answer a new search would
//! give (`Pairing`): the alignments are the same, with a fraction of the searches.

use crate::types::Point;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3, Vector6};
use std::num::NonZeroUsize;

/// ICP settings.
#[derive(Clone, Debug, PartialEq)]
pub struct IcpParams {
    /// Voxel size of the target and of the source as the score counts it (m).
    pub voxel: f64,
    /// Voxel size of the source in each stage (m), one per stage; a stage pairs the source's
    /// voxels at its size (none finer than `voxel`).
    pub source_voxels: Vec<f64>,
    /// Neighbours that give a target voxel its normal.
    pub normal_neighbours: usize,
    /// The correspondence distances of the stages, coarse to fine (m), each run until it
    /// converges or for `iterations` steps.
    pub stages: Vec<f64>,
    /// Steps per stage, at most.
    pub iterations: usize,
    /// Steps of the first stage each initial guess gets before the best goes on alone.
    pub trial_iterations: usize,
    /// A stage has converged when a step turns by less than this (radians) and moves by less
    /// than this (m).
    pub tolerance: f64,
}

impl Default for IcpParams {
    fn default() -> Self {
        IcpParams {
            voxel: 0.5,
            source_voxels: vec![2.0, 1.0, 0.5],
            normal_neighbours: 10,
            stages: vec![3.0, 1.5, 0.75],
            iterations: 20,
            trial_iterations: 5,
            tolerance: 1e-4,
        }
    }
}

/// An alignment of a source scan onto a target scan.
#[derive(Clone, Debug)]
pub struct Alignment {
    /// Maps source-frame points into the target's frame.
    pub pose: Isometry3<f64>,
    /// The share of source voxels with a target voxel within the last stage's distance.
    pub fitness: f64,
    /// The root mean square of their point-to-plane distances (m).
    pub rmse: f64,
}

/// A target scan made ready to align against: its voxels, their k-d tree and normals.
pub struct Target {
    voxels: Vec<Point>,
    tree: ImmutableKdTree<f64, 3>,
    normals: Vec<Option<Vector3<f64>>>,
}

impl Target {
    /// `points`, a raw scan in its sensor frame, voxelized at `p.voxel`, with each voxel's normal.
    pub fn new(points: &[Point], p: &IcpParams) -> Result<Target, String> {
        Target::of_voxels(crate::preprocess::voxel_grid(points, p.voxel), p)
    }

    /// A scan already voxelized at `p.voxel`, with each voxel's normal.
    pub fn of_voxels(voxels: Vec<Point>, p: &IcpParams) -> Result<Target, String> {
        let k = p.normal_neighbours.max(3);
        if voxels.len() < k {
            return Err(format!("too few points to align ({} target voxels)", voxels.len()));
        }
        let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&voxels)
            .map_err(|e| format!("the target's k-d tree cannot be built: {e:?}"))?;
        let k = NonZeroUsize::new(k).expect("k ≥ 3");
        let normals = voxels
            .iter()
            .map(|q| {
                let near = tree.query(q).nearest_n::<SquaredEuclidean<f64>>(k).execute();
                let n = near.len() as f64;
                let mean =
                    near.iter().map(|h| Vector3::from(voxels[h.item as usize])).sum::<Vector3<f64>>() / n;
                let cov = near
                    .iter()
                    .map(|h| {
                        let d = Vector3::from(voxels[h.item as usize]) - mean;
                        d * d.transpose()
                    })
                    .sum::<Matrix3<f64>>();
                let eig = cov.symmetric_eigen();
                let normal = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
                normal.iter().all(|c| c.is_finite()).then_some(normal)
            })
            .collect();
        Ok(Target { voxels, tree, normals })
    }

    /// The residual and normal of target voxel `i` for the point `x`: `None` when the voxel has
    /// no normal.
    fn residual(&self, i: usize, x: &Point3<f64>) -> Option<(f64, Vector3<f64>)> {
        let n = self.normals[i]?;
        Some((n.dot(&(x.coords - Vector3::from(self.voxels[i]))), n))
    }
}

/// Candidates a [`Pairing`] keeps per source voxel.
const KEPT: usize = 4;

/// The search bound of a stage over its correspondence distance: the margin a source voxel may
/// move before its kept candidates must be sought again.
const BOUND_OVER_REACH: f64 = 1.5;

/// One stage's pairing of source voxels with their nearest target voxels within `reach`,
/// kept between steps. Each voxel keeps the [`KEPT`] nearest target voxels within a wider
/// bound, found where it was when last searched. A step moves each voxel by `δ` from there;
/// every target voxel not kept was beyond the bound, or beyond the farthest kept one, so it is
/// now at least that far less `δ`. While `δ` stays below the bound's margin over `reach`, and
/// the nearest kept candidate is nearer than anything not kept could now be, that candidate is
/// the nearest target voxel within reach — exactly what a new search would return — and no
/// search is made. Late steps move by millimetres, so most steps search for few voxels.
struct Pairing<'t> {
    target: &'t Target,
    reach: f64,
    bound: f64,
    kept: Vec<Kept>,
}

/// A source voxel's kept candidates: where it was searched from, and the nearest target voxels
/// within the bound then (index, distance), nearest first.
#[derive(Clone, Copy)]
struct Kept {
    at: Option<Point3<f64>>,
    near: [(u32, f64); KEPT],
    found: usize,
}

impl<'t> Pairing<'t> {
    fn new(target: &'t Target, reach: f64, points: usize) -> Pairing<'t> {
        let kept = vec![Kept { at: None, near: [(0, 0.0); KEPT], found: 0 }; points];
        Pairing { target, reach, bound: reach * BOUND_OVER_REACH, kept }
    }

    /// The nearest target voxel to `x` (source voxel `i` moved) within the reach, if it has a
    /// normal: its point-to-plane residual and the normal.
    fn partner(&mut self, i: usize, x: &Point3<f64>) -> Option<(f64, Vector3<f64>)> {
        let nearest = match self.kept_nearest(i, x) {
            Some(found) => found,
            None => self.search(i, x),
        };
        self.target.residual(nearest? as usize, x)
    }

    /// The answer of voxel `i`'s kept candidates at `x`: `None` when they cannot tell (it moved
    /// too far, or a candidate not kept may now be as near), else the nearest within reach.
    fn kept_nearest(&self, i: usize, x: &Point3<f64>) -> Option<Option<u32>> {
        let k = &self.kept[i];
        let moved = (x - k.at?).norm();
        if moved >= self.bound - self.reach {
            return None;
        }
        // (Squared distances, as the search compares them.)
        let mut best: Option<(u32, f64)> = None;
        let mut tie = false;
        for &(item, _) in &k.near[..k.found] {
            let d = (x.coords - Vector3::from(self.target.voxels[item as usize])).norm_squared();
            match best {
                Some((_, b)) if d == b => tie = true,
                Some((_, b)) if d > b => {}
                _ => (best, tie) = (Some((item, d)), false),
            }
        }
        if tie {
            return None;
        }
        let Some((item, d)) = best else { return Some(None) };
        // A voxel not kept (when all KEPT were found) was at least as far as the farthest kept.
        if k.found == KEPT && d.sqrt() >= k.near[KEPT - 1].1 - moved {
            return None;
        }
        Some((d <= self.reach * self.reach).then_some(item))
    }

    /// Searches the target for voxel `i` at `x`, keeping what it finds; the nearest within reach.
    fn search(&mut self, i: usize, x: &Point3<f64>) -> Option<u32> {
        let kept = NonZeroUsize::new(KEPT).expect("KEPT > 0");
        let hits = self
            .target
            .tree
            .query(&[x.x, x.y, x.z])
            .nearest_n::<SquaredEuclidean<f64>>(kept)
            .within(self.bound * self.bound)
            .execute();
        let k = &mut self.kept[i];
        k.at = Some(*x);
        k.found = hits.len().min(KEPT);
        for (slot, h) in k.near.iter_mut().zip(&hits) {
            *slot = (h.item, h.distance.sqrt());
        }
        let first = hits.first()?;
        (first.distance <= self.reach * self.reach).then_some(first.item)
    }
}

/// A source scan made ready to align: its voxels at the score's size and, for each stage
/// paired coarser, at that stage's.
pub struct Source {
    fine: Vec<Point>,
    coarser: Vec<Option<Vec<Point>>>,
}

impl Source {
    /// `points`, a raw scan in its sensor frame, voxelized at `p.voxel` and at each stage's
    /// size.
    pub fn new(points: &[Point], p: &IcpParams) -> Source {
        Source::of_voxels(crate::preprocess::voxel_grid(points, p.voxel), p)
    }

    /// A scan already voxelized at `p.voxel`, voxelized again at each coarser stage's size.
    pub fn of_voxels(fine: Vec<Point>, p: &IcpParams) -> Source {
        let coarser = (0..p.stages.len())
            .map(|i| {
                let size = p.source_voxels.get(i).copied().unwrap_or(p.voxel);
                (size > p.voxel).then(|| crate::preprocess::voxel_grid(&fine, size))
            })
            .collect();
        Source { fine, coarser }
    }

    /// The voxels stage `i` pairs.
    fn stage(&self, i: usize) -> &[Point] {
        self.coarser.get(i).and_then(Option::as_deref).unwrap_or(&self.fine)
    }
}

/// Aligns `source` onto `target` (each a raw scan in its sensor frame) from `initial`.
pub fn align(
    source: &[Point],
    target: &[Point],
    initial: Isometry3<f64>,
    p: &IcpParams,
) -> Result<Alignment, String> {
    align_ready(&Source::new(source, p), &Target::new(target, p)?, initial, p)
}

/// [`align`] of a source and a target made ready.
pub fn align_ready(
    source: &Source,
    target: &Target,
    initial: Isometry3<f64>,
    p: &IcpParams,
) -> Result<Alignment, String> {
    align_best(source, target, &[initial], p)
}

/// The alignment from the best of several initial guesses: each runs `p.trial_iterations`
/// steps of the first (coarsest) stage, and the one that pairs the most source voxels goes on
/// alone through the rest of the stages.
pub fn align_best(
    source: &Source,
    target: &Target,
    initials: &[Isometry3<f64>],
    p: &IcpParams,
) -> Result<Alignment, String> {
    if source.fine.len() < 6 {
        return Err(format!("too few points to align ({} source voxels)", source.fine.len()));
    }
    let (Some(&first), finer) = (p.stages.first(), p.stages.get(1..).unwrap_or_default()) else {
        return Err("no ICP stage".into());
    };
    let mut best: Option<(Isometry3<f64>, usize, Pairing)> = None;
    let mut last_error = String::from("no initial guess");
    let trial = if initials.len() > 1 { p.trial_iterations.min(p.iterations) } else { p.iterations };
    for &initial in initials {
        let mut pairing = Pairing::new(target, first, source.stage(0).len());
        match run_stage(source.stage(0), &mut pairing, initial, trial, p) {
            Ok((pose, paired)) if best.as_ref().is_none_or(|b| paired > b.1) => {
                best = Some((pose, paired, pairing))
            }
            Ok(_) => {}
            Err(e) => last_error = e,
        }
    }
    let Some((mut pose, _, mut pairing)) = best else { return Err(last_error) };
    if trial < p.iterations {
        pose = run_stage(source.stage(0), &mut pairing, pose, p.iterations - trial, p)?.0;
    }
    for (i, &reach) in finer.iter().enumerate() {
        pairing = Pairing::new(target, reach, source.stage(i + 1).len());
        pose = run_stage(source.stage(i + 1), &mut pairing, pose, p.iterations, p)?.0;
    }
    // The score, at the final pose, of the source's voxels at the target's size (the last
    // stage's own pairing when it paired them).
    let reach = p.stages.last().copied().unwrap_or(p.voxel);
    let last = source.stage(p.stages.len() - 1);
    if !std::ptr::eq(last, source.fine.as_slice()) {
        pairing = Pairing::new(target, reach, source.fine.len());
    }
    let (mut paired, mut squares) = (0usize, 0.0);
    for (i, s) in source.fine.iter().enumerate() {
        if let Some((r, _)) = pairing.partner(i, &(pose * Point3::from(*s))) {
            paired += 1;
            squares += r * r;
        }
    }
    if paired < 6 {
        return Err(format!("no overlap: {paired} source voxels within {reach} m of the target"));
    }
    Ok(Alignment {
        pose,
        fitness: paired as f64 / source.fine.len() as f64,
        rmse: (squares / paired as f64).sqrt(),
    })
}

/// One stage from `pose`: Gauss–Newton steps pairing `points` within `reach`, until a step is
/// below the tolerance or for `p.iterations` steps; the pose and its last step's pairs.
fn run_stage(
    points: &[Point],
    pairing: &mut Pairing,
    mut pose: Isometry3<f64>,
    iterations: usize,
    p: &IcpParams,
) -> Result<(Isometry3<f64>, usize), String> {
    let mut paired = 0;
    for _ in 0..iterations {
        let (mut h, mut g) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
        paired = 0;
        for (i, s) in points.iter().enumerate() {
            let x = pose * Point3::from(*s);
            let Some((r, n)) = pairing.partner(i, &x) else { continue };
            let c = x.coords.cross(&n);
            let j = Vector6::new(c.x, c.y, c.z, n.x, n.y, n.z);
            h += j * j.transpose();
            g += j * r;
            paired += 1;
        }
        if paired < 6 {
            let reach = pairing.reach;
            return Err(format!("no overlap: {paired} source voxels within {reach} m of the target"));
        }
        let Some(step) = h.cholesky().map(|c| c.solve(&(-g))) else {
            return Err("degenerate geometry: the alignment is not determined".into());
        };
        let turn = Vector3::new(step[0], step[1], step[2]);
        let shift = Vector3::new(step[3], step[4], step[5]);
        pose =
            Isometry3::from_parts(Translation3::from(shift), UnitQuaternion::from_scaled_axis(turn)) * pose;
        if turn.norm() < p.tolerance && shift.norm() < p.tolerance {
            break;
        }
    }
    Ok((pose, paired))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// The nearest of `voxels` to `x` within `reach` (by brute force), and its squared distance.
    fn nearest(voxels: &[Point], x: &Point3<f64>, reach: f64) -> Option<(usize, f64)> {
        voxels
            .iter()
            .enumerate()
            .map(|(i, v)| (i, (x.coords - Vector3::from(*v)).norm_squared()))
            .filter(|&(_, d)| d <= reach * reach)
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    #[test]
    fn kept_candidates_answer_as_a_new_search_would() {
        // Voxels on a few planes, as a scan's walls and ground give them, and source points
        // walking among them by steps from centimetres to a metre: whether a point's answer
        // comes from its kept candidates or from a new search, it is the nearest within reach.
        let mut rng = SplitMix64(7);
        let mut voxels = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (u, v) = (i as f64 * 0.5 - 10.0, j as f64 * 0.5 - 10.0);
                voxels.push([u, v, -1.7 + 0.01 * rng.normal()]);
                voxels.push([u, 6.0 + 0.02 * rng.normal(), v * 0.3]);
                voxels.push([8.0 + 0.02 * rng.normal(), u, v * 0.3]);
            }
        }
        let target = Target::of_voxels(voxels.clone(), &IcpParams::default()).unwrap();
        let mut points: Vec<Point3<f64>> = (0..500)
            .map(|_| {
                Point3::new(
                    20.0 * rng.next_f64() - 10.0,
                    20.0 * rng.next_f64() - 6.0,
                    3.0 * rng.next_f64() - 2.0,
                )
            })
            .collect();
        let (mut reused, mut searched) = (0, 0);
        for reach in [3.0, 1.5, 0.75] {
            let mut pairing = Pairing::new(&target, reach, points.len());
            for step in 0..30 {
                let size = [0.01, 0.05, 0.3, 1.0][step % 4];
                for (i, x) in points.iter_mut().enumerate() {
                    *x += Vector3::new(rng.normal(), rng.normal(), rng.normal()) * size;
                    match pairing.kept_nearest(i, x) {
                        Some(_) => reused += 1,
                        None => searched += 1,
                    }
                    let want = nearest(&voxels, x, reach).and_then(|(k, _)| target.residual(k, x));
                    let got = pairing.partner(i, x);
                    assert_eq!(got.map(|g| g.0), want.map(|w| w.0), "point {i} at {x:?}, reach {reach}");
                }
            }
        }
        // Both ways were exercised.
        assert!(reused > 1000 && searched > 1000, "{reused} answers kept, {searched} searched");
    }
}
