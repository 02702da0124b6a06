//! `toporec loops --verify`: each accepted match checked by aligning the two raw scans
//! ([`super::icp`]), read again from the files the index was made from; a match is kept when
//! the alignment's fitness and RMSE pass the limits. The relative pose goes into the rows and,
//! on request, into g2o `EDGE_SE3:QUAT` lines for a pose-graph back end.

use super::icp::{self, IcpParams};
pub use super::row::Check;
use super::row::LoopRow;
use crate::error::{Result, ResultExt};
use crate::types::Point;
use nalgebra::{Isometry3, Vector3};
use std::collections::{HashMap, HashSet};
use std::io::Write;
use std::path::Path;

/// What a kept alignment must reach.
#[derive(clap::Args, Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// `--verify`: the least share of the query's voxels the alignment pairs, [0, 1].
    #[arg(long, default_value_t = 0.5, value_parser = crate::ranges::fraction, requires = "verify")]
    pub min_fitness: f64,
    /// `--verify`: the largest point-to-plane RMSE of the alignment (m, > 0).
    #[arg(long, default_value_t = 0.15, value_parser = crate::ranges::positive, requires = "verify")]
    pub max_rmse: f64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits { min_fitness: 0.5, max_rmse: 0.15 }
    }
}

/// The raw scans `ids` of `index`, voxelized for ICP: each read again from where the index
/// found it ([`crate::sources::reread`]: a scan file alone, a log's messages in one pass), points
/// only; a scan that cannot be read maps to the reason. One warning counts those scans, naming
/// the option that asked and what follows for them (`consequence`).
fn load(
    index: &Path,
    ids: &HashSet<&str>,
    voxel: f64,
    damage: &crate::sinks::index::damage::Damage,
    consequence: (&str, &str),
) -> Result<HashMap<String, std::result::Result<Vec<Point>, String>>> {
    let reader = crate::sinks::index::IndexReader::open_with(index, damage)?;
    let places: Vec<_> =
        reader.scans()?.iter().filter(|r| ids.contains(r.scan_id.as_str())).map(|r| r.place()).collect();
    // The index's pipeline says how each source was read (a log's topic).
    let sources = crate::pipeline::config::Pipeline::of_index(index).map(|p| p.sources).unwrap_or_default();
    let rereader = crate::sources::reread::Rereader::new(&sources).points_only();
    let mut out: HashMap<String, std::result::Result<Vec<Point>, String>> = rereader
        .scans(&places)
        .into_iter()
        .map(|(id, scan)| {
            let points = scan.map(|s| crate::preprocess::voxel_grid(&s.points, voxel)).map_err(|f| f.error);
            (id, points)
        })
        .collect();
    for id in ids {
        out.entry(id.to_string()).or_insert_with(|| Err("not in the index's scans table".into()));
    }
    let mut unreadable: Vec<(&String, &String)> =
        out.iter().filter_map(|(id, points)| points.as_ref().err().map(|e| (id, e))).collect();
    unreadable.sort();
    if let Some((id, e)) = unreadable.first() {
        let n = unreadable.len();
        let scans = if n == 1 { "scan" } else { "scans" };
        let (option, consequence) = consequence;
        tracing::warn!("{option}: {n} {scans} cannot be read again, {consequence} (the first, {id}: {e})");
    }
    Ok(out)
}

/// Checks the accepted rows of `rows` (in parallel), returning each one's check (`None` for
/// the rows not checked); a row whose scans cannot be read or aligned fails its check (the
/// unreadable scans and the alignments that failed each counted in one warning).
pub fn check(
    index: &Path,
    rows: &[LoopRow],
    limits: Limits,
    progress: bool,
    damage: &crate::sinks::index::damage::Damage,
) -> Result<Vec<Option<Check>>> {
    use rayon::prelude::*;
    let p = IcpParams::default();
    let bar =
        super::progress_bar(progress, rows.iter().filter(|r| r.found.accepted).count(), "matches aligned");
    let ids: HashSet<&str> = rows
        .iter()
        .filter(|r| r.found.accepted)
        .flat_map(|r| [r.query_scan.as_str(), r.matched_scan.as_str()])
        .collect();
    let clouds = load(index, &ids, p.voxel, damage, ("--verify", "their matches fail the check"))?;
    // Each scan made ready once, as a target where it is matched and as a source where it asks.
    let side = |query: bool| -> HashSet<&str> {
        rows.iter()
            .filter(|r| r.found.accepted)
            .map(|r| if query { r.query_scan.as_str() } else { r.matched_scan.as_str() })
            .collect()
    };
    let ready = |id: &str| clouds.get(id).and_then(|c| c.as_ref().ok());
    // (`load` voxelized them at `p.voxel` already.)
    let sources: HashMap<&str, icp::Source> = side(true)
        .into_par_iter()
        .filter_map(|id| ready(id).map(|c| (id, icp::Source::of_voxels(c.clone(), &p))))
        .collect();
    let targets: HashMap<&str, std::result::Result<icp::Target, String>> = side(false)
        .into_par_iter()
        .filter_map(|id| ready(id).map(|c| (id, icp::Target::of_voxels(c.clone(), &p))))
        .collect();
    // Alignments that failed: how many, and the first one's reason.
    let failed = std::sync::Mutex::new((0usize, String::new()));
    let checks = rows
        .par_iter()
        .map(|r| {
            if !r.found.accepted {
                return None;
            }
            if let Some(b) = &bar {
                b.inc(1);
            }
            let failure = Check { passed: false, fitness: 0.0, rmse: f64::NAN, relative: [f64::NAN; 6] };
            let (Some(q), Some(m)) =
                (sources.get(r.query_scan.as_str()), targets.get(r.matched_scan.as_str()))
            else {
                return Some(failure);
            };
            match m
                .as_ref()
                .map_err(Clone::clone)
                .and_then(|m| best_alignment(q, m, r.found.yaw_degrees, r.found.offset, &p))
            {
                Ok(a) => Some(Check {
                    passed: a.fitness >= limits.min_fitness && a.rmse <= limits.max_rmse,
                    fitness: a.fitness,
                    rmse: a.rmse,
                    relative: relative(&a.pose),
                }),
                Err(e) => {
                    let mut f = failed.lock().expect("not poisoned");
                    if f.0 == 0 {
                        f.1 = format!("{} against {}: {e}", r.query_scan, r.matched_scan);
                    }
                    f.0 += 1;
                    Some(failure)
                }
            }
        })
        .collect();
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let (n, first) = failed.into_inner().expect("not poisoned");
    if n > 0 {
        tracing::warn!("--verify: {n} matches could not be aligned, failing the check (the first: {first})");
    }
    Ok(checks)
}

/// The steps `pairs` (walk positions in `walk`: an earlier scan, a later one of its session, and
/// their stored step) aligned again by ICP from the stored step, in parallel; a step is given
/// where its alignment passes `limits` (the unreadable scans counted in one warning by [`load`]).
pub(super) fn align_steps(
    index: &Path,
    walk: &[super::map::Vertex],
    pairs: &[(usize, usize, Isometry3<f64>)],
    limits: Limits,
    progress: bool,
    damage: &crate::sinks::index::damage::Damage,
) -> Result<std::collections::BTreeMap<(usize, usize), super::map::AlignedStep>> {
    use rayon::prelude::*;
    let p = IcpParams::default();
    let ids: HashSet<&str> =
        pairs.iter().flat_map(|&(u, v, _)| [walk[u].scan_id.as_str(), walk[v].scan_id.as_str()]).collect();
    let clouds = load(index, &ids, p.voxel, damage, ("--odometry icp", "their steps are the stored poses'"))?;
    let bar = super::progress_bar(progress, pairs.len(), "steps aligned");
    // Each scan is the target of its next step and the source of its own: made ready once as
    // each, so a pair builds its own two.
    let aligned = pairs
        .par_iter()
        .filter_map(|&(u, v, stored)| {
            if let Some(b) = &bar {
                b.inc(1);
            }
            let earlier = clouds.get(walk[u].scan_id.as_str())?.as_ref().ok()?;
            let later = clouds.get(walk[v].scan_id.as_str())?.as_ref().ok()?;
            let target = icp::Target::of_voxels(earlier.clone(), &p).ok()?;
            let source = icp::Source::of_voxels(later.clone(), &p);
            let a = icp::align_ready(&source, &target, stored, &p).ok()?;
            (a.fitness >= limits.min_fitness && a.rmse <= limits.max_rmse)
                .then_some(((u, v), super::map::AlignedStep { pose: a.pose, rmse: a.rmse }))
        })
        .collect();
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    Ok(aligned)
}

/// The alignment from the descriptor's yaw taken either way round (the methods differ in its
/// sign; at 0° and 180° both are one), the better after the coarse stage going on
/// ([`icp::align_best`]); each starts at the method's estimate of the query's position in the
/// match's frame, where it gives one.
fn best_alignment(
    query: &icp::Source,
    matched: &icp::Target,
    yaw_degrees: Option<f64>,
    offset: Option<[f64; 2]>,
    p: &IcpParams,
) -> std::result::Result<icp::Alignment, String> {
    let [x, y] = offset.unwrap_or([0.0, 0.0]);
    let yaw = yaw_degrees.unwrap_or(0.0);
    let mut guesses = vec![yaw];
    if (yaw.rem_euclid(180.0)).abs() > 1e-9 {
        guesses.push(-yaw);
    }
    let initials: Vec<Isometry3<f64>> = guesses
        .into_iter()
        .map(|g| Isometry3::new(Vector3::new(x, y, 0.0), Vector3::z() * g.to_radians()))
        .collect();
    icp::align_best(query, matched, &initials, p)
}

/// x, y, z (m), roll, pitch, yaw (degrees) of a pose.
fn relative(pose: &Isometry3<f64>) -> [f64; 6] {
    let t = pose.translation.vector;
    let (roll, pitch, yaw) = pose.rotation.euler_angles();
    [t.x, t.y, t.z, roll.to_degrees(), pitch.to_degrees(), yaw.to_degrees()]
}

/// Writes one g2o `EDGE_SE3:QUAT` line per loop the map would take (`map::loop_edge`:
/// accepted and, where checked, verified): from the matched scan's vertex to the query's (their
/// positions in the walking order), the query's pose in the match's frame as x y z qx qy qz qw,
/// and the upper triangle of the loop's information as the map weighs it (verified: translation
/// 1/σ² with σ the RMSE, at least 5 cm, rotation 1/σ² with σ = 0.5°; unchecked, the
/// descriptor's pose: σ = 1 m, 5° of yaw).
pub(crate) fn write_g2o(path: &Path, rows: &[LoopRow]) -> Result<()> {
    let mut text = String::new();
    for r in rows {
        let Some((pose, information)) = super::map::loop_edge(r) else { continue };
        let (from, to) = (r.found.row, r.query_vertex);
        let (t, q) = (pose.translation.vector, pose.rotation);
        let info: Vec<String> = (0..6)
            .flat_map(|i| (i..6).map(move |j| (i, j)))
            .map(|(i, j)| format!("{:?}", information[(i, j)]))
            .collect();
        text.push_str(&format!(
            "EDGE_SE3:QUAT {from} {to} {:?} {:?} {:?} {:?} {:?} {:?} {:?} {}\n",
            t.x,
            t.y,
            t.z,
            q.i,
            q.j,
            q.k,
            q.w,
            info.join(" ")
        ));
    }
    let mut file = crate::fsutil::AtomicFile::create(path)?;
    file.write_all(text.as_bytes()).at(path)?;
    file.commit()?;
    Ok(())
}
