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

    /// The nearest voxel to `x` within `reach` that has a normal: its point-to-plane residual and
    /// the normal.
    fn partner(&self, x: &Point3<f64>, reach: f64) -> Option<(f64, Vector3<f64>)> {
        // Bounded by the reach: a source point far from the target ends its search early.
        let one = NonZeroUsize::new(1).expect("1 > 0");
        let hits = self
            .tree
            .query(&[x.x, x.y, x.z])
            .nearest_n::<SquaredEuclidean<f64>>(one)
            .within(reach * reach)
            .execute();
        let i = hits.first()?.item as usize;
        let n = self.normals[i]?;
        Some((n.dot(&(x.coords - Vector3::from(self.voxels[i]))), n))
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
    let mut best: Option<(Isometry3<f64>, usize)> = None;
    let mut last_error = String::from("no initial guess");
    let trial = if initials.len() > 1 { p.trial_iterations.min(p.iterations) } else { p.iterations };
    for &initial in initials {
        match run_stage(source.stage(0), target, initial, first, trial, p) {
            Ok((pose, paired)) if best.is_none_or(|b| paired > b.1) => best = Some((pose, paired)),
            Ok(_) => {}
            Err(e) => last_error = e,
        }
    }
    let Some((mut pose, _)) = best else { return Err(last_error) };
    if trial < p.iterations {
        pose = run_stage(source.stage(0), target, pose, first, p.iterations - trial, p)?.0;
    }
    for (i, &reach) in finer.iter().enumerate() {
        pose = run_stage(source.stage(i + 1), target, pose, reach, p.iterations, p)?.0;
    }
    // The score, at the final pose, of the source's voxels at the target's size.
    let reach = p.stages.last().copied().unwrap_or(p.voxel);
    let (mut paired, mut squares) = (0usize, 0.0);
    for s in &source.fine {
        if let Some((r, _)) = target.partner(&(pose * Point3::from(*s)), reach) {
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
    target: &Target,
    mut pose: Isometry3<f64>,
    reach: f64,
    iterations: usize,
    p: &IcpParams,
) -> Result<(Isometry3<f64>, usize), String> {
    let mut paired = 0;
    for _ in 0..iterations {
        let (mut h, mut g) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
        paired = 0;
        for s in points {
            let x = pose * Point3::from(*s);
            let Some((r, n)) = target.partner(&x, reach) else { continue };
            let c = x.coords.cross(&n);
            let j = Vector6::new(c.x, c.y, c.z, n.x, n.y, n.z);
            h += j * j.transpose();
            g += j * r;
            paired += 1;
        }
        if paired < 6 {
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
