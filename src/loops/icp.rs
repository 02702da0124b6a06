//! The geometric check of a loop: the two scans aligned by point-to-plane ICP (Chen and
//! Medioni, *Object modelling by registration of multiple range images*, 1992; the linearised
//! least-squares step of Low, *Linear least-squares optimization for point-to-plane ICP surface
//! registration*, 2004) on voxelized scans, from an initial guess (the descriptor's yaw).
//!
//! Each target point's normal is the least-variance direction of its nearest neighbours. Each
//! iteration pairs every transformed source point with its nearest target point within a
//! correspondence distance (shrinking over the iterations, coarse to fine), and solves the 6×6
//! normal equations of the point-to-plane residuals for a small rotation and a translation. The
//! result says how much of the source found a partner (the fitness) and how far off the planes
//! the partners are (the RMSE), which a caller compares with its thresholds.

use crate::types::Point;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};
use std::num::NonZeroUsize;

/// ICP settings.
#[derive(Clone, Debug, PartialEq)]
pub struct IcpParams {
    /// Voxel size of both scans before aligning (m).
    pub voxel: f64,
    /// Neighbours that give a target point its normal.
    pub normal_neighbours: usize,
    /// The correspondence distances of the stages, coarse to fine (m), each run until it
    /// converges or for `iterations` steps.
    pub stages: Vec<f64>,
    /// Steps per stage, at most.
    pub iterations: usize,
}

impl Default for IcpParams {
    fn default() -> Self {
        IcpParams { voxel: 0.5, normal_neighbours: 10, stages: vec![3.0, 1.5, 0.75], iterations: 20 }
    }
}

/// An alignment of a source scan onto a target scan.
#[derive(Clone, Debug)]
pub struct Alignment {
    /// Maps source-frame points into the target's frame.
    pub pose: Isometry3<f64>,
    /// The share of source points with a target point within the last stage's distance.
    pub fitness: f64,
    /// The root mean square of their point-to-plane distances (m).
    pub rmse: f64,
}

/// Aligns `source` onto `target` (each a raw scan in its sensor frame) from `initial`.
pub fn align(
    source: &[Point],
    target: &[Point],
    initial: Isometry3<f64>,
    p: &IcpParams,
) -> Result<Alignment, String> {
    let source = crate::preprocess::voxel_grid(source, p.voxel);
    let target = crate::preprocess::voxel_grid(target, p.voxel);
    let k = p.normal_neighbours.max(3);
    if source.len() < 6 || target.len() < k {
        return Err(format!("too few points to align ({} and {} voxels)", source.len(), target.len()));
    }
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&target)
        .map_err(|e| format!("the target's k-d tree cannot be built: {e:?}"))?;
    let nearest = |q: &[f64; 3], n: usize| -> Vec<(usize, f64)> {
        tree.query(q)
            .nearest_n::<SquaredEuclidean<f64>>(NonZeroUsize::new(n).expect("n > 0"))
            .execute()
            .iter()
            .map(|h| (h.item as usize, h.distance))
            .collect()
    };
    let normals: Vec<Option<Vector3<f64>>> = target
        .iter()
        .map(|q| {
            let near = nearest(q, k);
            let pts: Vec<Vector3<f64>> = near.iter().map(|&(i, _)| Vector3::from(target[i])).collect();
            let mean = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
            let cov = pts.iter().map(|v| (v - mean) * (v - mean).transpose()).sum::<Matrix3<f64>>();
            let eig = cov.symmetric_eigen();
            let smallest = eig.eigenvalues.imin();
            let n = eig.eigenvectors.column(smallest).into_owned();
            n.iter().all(|c| c.is_finite()).then_some(n)
        })
        .collect();

    let mut pose = initial;
    let mut last = (0.0, f64::INFINITY);
    for &reach in &p.stages {
        for _ in 0..p.iterations {
            let (mut h, mut g) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
            let (mut paired, mut squares) = (0usize, 0.0);
            for s in &source {
                let x = pose * nalgebra::Point3::from(*s);
                let Some(&(i, d2)) = nearest(&[x.x, x.y, x.z], 1).first() else { continue };
                let Some(n) = normals[i] else { continue };
                if d2 > reach * reach {
                    continue;
                }
                let r = n.dot(&(x.coords - Vector3::from(target[i])));
                let c = x.coords.cross(&n);
                let j = Vector6::new(c.x, c.y, c.z, n.x, n.y, n.z);
                h += j * j.transpose();
                g += j * r;
                paired += 1;
                squares += r * r;
            }
            if paired < 6 {
                return Err(format!("no overlap: {paired} source voxels within {reach} m of the target"));
            }
            last = (paired as f64 / source.len() as f64, (squares / paired as f64).sqrt());
            let Some(step) = h.cholesky().map(|c| c.solve(&(-g))) else {
                return Err("degenerate geometry: the alignment is not determined".into());
            };
            let rotation = UnitQuaternion::from_scaled_axis(Vector3::new(step[0], step[1], step[2]));
            let update = Isometry3::from_parts(Translation3::new(step[3], step[4], step[5]), rotation);
            pose = update * pose;
            if step.norm() < 1e-6 {
                break;
            }
        }
    }
    Ok(Alignment { pose, fitness: last.0, rmse: last.1 })
}
