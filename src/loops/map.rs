//! The loops' map: the pose graph of a method's walk and its loops, optimized so that no false
//! loop bends it ([`crate::map::solve`], graduated non-convexity), with sessions in their own
//! frames brought into the first one's through the loops between them.
//!
//! **The graph.** A vertex per scan with a pose, its id the scan's position in the walking order
//! (the loops table's `query_vertex` / `matched_vertex`), at its stored pose (x, y, z and yaw;
//! roll and pitch 0, as the index keeps them). An edge between consecutive scans of a session
//! with their relative pose, its information from a drift model ([`DriftModel`], by default):
//! σ = 2 cm + 2 % of the step for each axis of the translation, 0.002 rad + 0.005 rad a metre
//! for yaw, 0.01 rad for roll and pitch (which the stored poses do not have). With
//! `--odometry icp`, each such step is aligned again by ICP between the two raw scans, starting
//! from the stored step, and measured by the alignment where it passes the check's limits and
//! lies within three of those σ of the stored step (the information as a loop's, below): a
//! LiDAR odometry, metric where the log's may be long or short by a scale no loop can see. An edge per kept loop, from the matched scan to
//! the query, with ICP's relative pose: σ = the alignment's RMSE (at least 5 cm) for the
//! translation, 0.5° for each rotation. Without verification (`--no-verify`), the descriptor's
//! own estimate (x_m, y_m, yaw) at a weaker information: σ = 1 m for the translation, 5° for
//! the yaw, 0.05 rad for roll and pitch; a method that gives none puts no loop in the map. A
//! loop within one session that the odometry alone rules out (`odometry_veto`) is left out of
//! the graph and counted as rejected.
//!
//! **Frames.** Poses from a pose file are in one frame for all the sessions they cover (ground
//! truth, one SLAM run); each log's own poses (its `/odom` or `/tf`) and each KITTI sequence's
//! `poses.txt` (relative to its first frame) are a frame of their own.
//! `--frames shared` or `--frames own` says otherwise. Sessions of one frame keep it: each
//! session's first scan is held. A frame of its own is placed in the first session's frame by
//! its loops to it: each loop between the two proposes a placement; the one most others agree
//! with (within 2 m and 5°) starts the solve, and the map does the rest. A frame with no loop
//! to the first is left in its own frame and named.

use super::odometry_veto::Drift;
pub use super::odometry_veto::DriftModel;
use super::row::LoopRow;
use crate::error::{Result, ResultExt};
use crate::map::lie::Se3;
use crate::map::solve::{Edge, Graph, Options};
use nalgebra::{Isometry3, SMatrix, SVector, Translation3, UnitQuaternion};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Whether sessions share a frame: as their pose origins say, or all in one, or each its own.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Frames {
    /// Pose files share one frame; each log's own poses, and each KITTI sequence's `poses.txt`
    /// (relative to its first frame), are a frame of their own.
    #[default]
    Auto,
    /// Every session's poses are in one frame.
    Shared,
    /// Every session is in a frame of its own.
    Own,
}

/// Where the steps between consecutive scans come from.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Odometry {
    /// The stored poses' steps (the log's odometry, or the pose file's).
    #[default]
    Poses,
    /// Each step aligned again by ICP between the two raw scans, from the stored step; where
    /// the alignment fails its limits or strays from the stored step, the stored step.
    Icp,
}

/// A step between consecutive scans aligned by ICP: the later scan's pose in the earlier's
/// frame, and the alignment's RMSE (m).
#[derive(Clone, Copy, Debug)]
pub struct AlignedStep {
    /// The relative pose.
    pub pose: Isometry3<f64>,
    /// The alignment's point-to-plane RMSE (m).
    pub rmse: f64,
}

/// A scan of the walk with its stored pose.
#[derive(Clone, Debug)]
pub struct Vertex {
    /// The scan.
    pub scan_id: String,
    /// Its session.
    pub session: String,
    /// Its time (µs), when it has one.
    pub utime: Option<i64>,
    /// Its pose: x, y, z, yaw.
    pub pose: Option<crate::types::Pose>,
}

/// One method's map.
#[derive(Clone, Debug, Default)]
pub struct MethodMap {
    /// The method.
    pub method: String,
    /// Scans in the graph (with a pose), and scans left out (none).
    pub vertices: usize,
    /// Scans left out of the graph: no pose.
    pub unposed: usize,
    /// The first few of them, by id.
    pub unposed_named: Vec<String>,
    /// Loops given to the map; of those, kept by it.
    pub loops: (usize, usize),
    /// Loops the odometry alone ruled out, before the solve (counted among the rejected).
    pub vetoed: usize,
    /// With `--odometry icp`: the steps between consecutive scans, and those measured by ICP
    /// (the rest keep the stored step).
    pub steps_aligned: Option<(usize, usize)>,
    /// The cost before and after, and the iterations.
    pub costs: (f64, f64),
    /// Levenberg–Marquardt iterations.
    pub iterations: usize,
    /// Each row's `in_map`, by the row's index among the method's rows.
    pub in_map: Vec<Option<bool>>,
    /// The corrected pose of each walk position (none: not in the graph).
    pub corrected: Vec<Option<Isometry3<f64>>>,
    /// The poses the solve started from (the stored ones, other frames placed).
    pub initial: Vec<Option<Isometry3<f64>>>,
    /// Sessions left in their own frame: no loop to the first session's.
    pub apart: Vec<String>,
    /// Why no map was made (the solve did not converge), when none was.
    pub failed: Option<String>,
    /// The graph before the solve, with each vertex's id (its walking position).
    pub graph: Option<(Vec<i64>, Graph<Se3, 6>)>,
    /// The corrected poses written: TUM and KITTI, per session.
    pub written: Vec<PathBuf>,
    /// Each walk position's session, scan and time (µs), as `corrected` is ordered.
    pub scans: Vec<(String, String, Option<i64>)>,
}

impl std::fmt::Display for MethodMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(why) = &self.failed {
            return writeln!(f, "map ({}): {why}", self.method);
        }
        if self.corrected.is_empty() {
            return writeln!(f, "map ({}): not optimized (--no-optimize)", self.method);
        }
        let (loops, kept) = self.loops;
        let vetoed = match self.vetoed {
            0 => String::new(),
            n => format!(" ({n} by the odometry alone)"),
        };
        let steps = match self.steps_aligned {
            Some((steps, aligned)) => format!(", {aligned} of {steps} steps aligned by ICP"),
            None => String::new(),
        };
        write!(
            f,
            "map ({}): {} scans{steps}, {loops} loops, {kept} kept, {} rejected as inconsistent{vetoed}; cost {:.3} → {:.3} in {} iterations",
            self.method,
            self.vertices,
            loops - kept,
            self.costs.0,
            self.costs.1,
            self.iterations
        )?;
        if self.unposed > 0 {
            let more = if self.unposed > self.unposed_named.len() { ", …" } else { "" };
            write!(
                f,
                "; {} scans without a pose left out ({}{more})",
                self.unposed,
                self.unposed_named.join(", ")
            )?;
        }
        writeln!(f)?;
        if !self.apart.is_empty() {
            writeln!(
                f,
                "note: no loop joins {} to the first session's frame: left in its own frame",
                self.apart.join(", ")
            )?;
        }
        if !self.written.is_empty() {
            let files: Vec<String> = self.written.iter().map(|p| p.display().to_string()).collect();
            writeln!(f, "corrected poses: {}", files.join(", "))?;
        }
        Ok(())
    }
}

fn isometry(p: &crate::types::Pose) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(p.x, p.y, p.z),
        UnitQuaternion::from_euler_angles(0.0, 0.0, p.yaw),
    )
}

fn diagonal(translation: f64, roll_pitch: f64, yaw: f64) -> SMatrix<f64, 6, 6> {
    let t = 1.0 / (translation * translation);
    let rp = 1.0 / (roll_pitch * roll_pitch);
    SMatrix::<f64, 6, 6>::from_diagonal(&SVector::<f64, 6>::from([t, t, t, rp, rp, 1.0 / (yaw * yaw)]))
}

/// The loop edge of a kept row: ICP's relative pose, or the descriptor's without a check.
pub(super) fn loop_edge(r: &LoopRow) -> Option<(Isometry3<f64>, SMatrix<f64, 6, 6>)> {
    if !r.found.accepted {
        return None;
    }
    match r.check {
        Some(c) if c.passed => {
            let [x, y, z, roll, pitch, yaw] = c.relative;
            let pose = Isometry3::from_parts(
                Translation3::new(x, y, z),
                UnitQuaternion::from_euler_angles(roll.to_radians(), pitch.to_radians(), yaw.to_radians()),
            );
            Some((pose, aligned_information(c.rmse)))
        }
        Some(_) => None,
        None => {
            let [x, y] = r.found.offset?;
            let yaw = r.found.yaw_degrees?.to_radians();
            let pose = Isometry3::from_parts(
                Translation3::new(x, y, 0.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            );
            Some((pose, diagonal(1.0, 0.05, 5f64.to_radians())))
        }
    }
}

/// A loop in the graph: its row, the matched scan's and the query's walk positions, the
/// relative pose and its information.
type LoopEdge = (usize, usize, usize, Isometry3<f64>, SMatrix<f64, 6, 6>);

/// The information of a relative pose measured by an ICP alignment (a loop's, or a step's with
/// `--odometry icp`): σ = the alignment's RMSE, at least 5 cm, for the translation; 0.5° for
/// each rotation.
fn aligned_information(rmse: f64) -> SMatrix<f64, 6, 6> {
    let rmse = if rmse.is_finite() { rmse.max(0.05) } else { 0.05 };
    diagonal(rmse, 0.5f64.to_radians(), 0.5f64.to_radians())
}

/// The odometry information of a step of `step` by the drift model.
fn odometry_information(drift: &DriftModel, step: &Isometry3<f64>) -> SMatrix<f64, 6, 6> {
    let (translation, roll_pitch, yaw) = drift.sigmas(step);
    diagonal(translation, roll_pitch, yaw)
}

/// How a map is made: the odometry's drift model, the steps ICP measured (`--odometry icp`,
/// by their walk positions; they replace the stored steps where they agree), and whether to
/// optimize (or only build the graph).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Making<'a> {
    pub drift: DriftModel,
    pub aligned: Option<&'a BTreeMap<(usize, usize), AlignedStep>>,
    pub optimize: bool,
}

/// The odometry's steps of `walk`: the walk positions of each posed scan's previous posed scan
/// in its session and of the scan.
pub(super) fn steps(walk: &[Vertex]) -> Vec<(usize, usize)> {
    let mut last_of: BTreeMap<&str, usize> = BTreeMap::new();
    let mut out = Vec::new();
    for (v, vertex) in walk.iter().enumerate() {
        if vertex.pose.is_none() {
            continue;
        }
        if let Some(&u) = last_of.get(vertex.session.as_str()) {
            out.push((u, v));
        }
        last_of.insert(vertex.session.as_str(), v);
    }
    out
}

/// The stored step from `from` to `to`: the later's pose in the earlier's frame.
pub(super) fn stored_step(from: &Vertex, to: &Vertex) -> Option<Isometry3<f64>> {
    Some(isometry(from.pose.as_ref()?).inverse() * isometry(to.pose.as_ref()?))
}

/// The step an odometry edge measures, its information, and whether ICP measured it: an ICP
/// step (σ = its RMSE, at least 5 cm, for the translation; 0.5° for each rotation, as a loop's)
/// where one is given and lies within three of the stored step's σ of it (see the module doc),
/// else the stored step.
fn odometry_edge(
    stored: &Isometry3<f64>,
    aligned: Option<&AlignedStep>,
    drift: &DriftModel,
) -> (Isometry3<f64>, SMatrix<f64, 6, 6>, bool) {
    if let Some(a) = aligned {
        let (translation, roll_pitch, yaw) = drift.sigmas(stored);
        let off = stored.inverse() * a.pose;
        let agrees = off.translation.vector.norm() <= 3.0 * translation
            && off.rotation.angle() <= 3.0 * roll_pitch.max(yaw);
        if agrees {
            return (a.pose, aligned_information(a.rmse), true);
        }
    }
    (*stored, odometry_information(drift, stored), false)
}

/// Builds and optimizes one method's map over `walk` (by walking order) and its `rows`;
/// `frame_of` gives each session's frame (sessions of one frame share it), `first` the session
/// whose frame the map is in.
pub(super) fn make(
    method: &str,
    walk: &[Vertex],
    rows: &[LoopRow],
    frame_of: &dyn Fn(&str) -> usize,
    first: &str,
    how: &Making,
) -> MethodMap {
    let Making { drift, aligned, optimize } = *how;
    let n = walk.len();
    let mut initial: Vec<Option<Isometry3<f64>>> =
        walk.iter().map(|v| v.pose.as_ref().map(isometry)).collect();
    let mut out = MethodMap {
        method: method.to_string(),
        vertices: initial.iter().flatten().count(),
        unposed: initial.iter().filter(|p| p.is_none()).count(),
        unposed_named: walk
            .iter()
            .zip(&initial)
            .filter(|(_, p)| p.is_none())
            .take(5)
            .map(|(v, _)| v.scan_id.clone())
            .collect(),
        in_map: vec![None; rows.len()],
        scans: walk.iter().map(|v| (v.session.clone(), v.scan_id.clone(), v.utime)).collect(),
        ..MethodMap::default()
    };
    let loops: Vec<LoopEdge> = rows
        .iter()
        .enumerate()
        .filter_map(|(k, r)| {
            let (from, to) = (r.found.row, r.query_vertex);
            if from >= n || to >= n || initial[from].is_none() || initial[to].is_none() {
                return None;
            }
            let (pose, info) = loop_edge(r)?;
            Some((k, from, to, pose, info))
        })
        .collect();
    // Loops the odometry alone rules out stay out of the graph (see `odometry_veto`).
    let steps = steps(walk);
    let veto = Drift::new(&initial, &steps, &drift);
    let (loops, vetoed): (Vec<LoopEdge>, Vec<LoopEdge>) =
        loops.into_iter().partition(|&(_, a, b, z, info)| {
            let odometry = initial[a].expect("posed").inverse() * initial[b].expect("posed");
            !veto.rules_out(a, b, &odometry, &z, 1.0 / info[(0, 0)])
        });
    // Frames: place each other frame in the first's by the loops to the frames placed.
    let frame: Vec<usize> = walk.iter().map(|v| frame_of(&v.session)).collect();
    let anchor = frame_of(first);
    let mut placed = std::collections::BTreeSet::from([anchor]);
    let all: std::collections::BTreeSet<usize> = frame.iter().copied().collect();
    loop {
        let mut best: Option<(usize, Isometry3<f64>, usize)> = None;
        for &f in all.difference(&placed) {
            // Each loop from a placed frame to f proposes where f's poses go.
            let proposals: Vec<Isometry3<f64>> = loops
                .iter()
                .filter_map(|&(_, a, b, z, _)| {
                    let (pa, pb) = (initial[a]?, initial[b]?);
                    if placed.contains(&frame[a]) && frame[b] == f {
                        Some(pa * z * pb.inverse())
                    } else if placed.contains(&frame[b]) && frame[a] == f {
                        Some(pb * z.inverse() * pa.inverse())
                    } else {
                        None
                    }
                })
                .collect();
            for t in &proposals {
                let agree = proposals
                    .iter()
                    .filter(|u| {
                        let d = t.inverse() * *u;
                        d.translation.vector.norm() < 2.0 && d.rotation.angle() < 5f64.to_radians()
                    })
                    .count();
                if best.as_ref().is_none_or(|b| agree > b.2) {
                    best = Some((f, *t, agree));
                }
            }
        }
        let Some((f, t, _)) = best else { break };
        for (v, p) in initial.iter_mut().enumerate() {
            if frame[v] == f {
                *p = p.map(|p| t * p);
            }
        }
        placed.insert(f);
    }
    let mut apart: Vec<String> = Vec::new();
    for v in walk {
        if !placed.contains(&frame_of(&v.session)) && !apart.contains(&v.session) {
            apart.push(v.session.clone());
        }
    }
    out.apart = apart;
    out.initial = initial.clone();

    // The graph over the posed scans.
    let index: Vec<Option<usize>> = {
        let mut next = 0;
        initial
            .iter()
            .map(|p| {
                p.map(|_| {
                    next += 1;
                    next - 1
                })
            })
            .collect()
    };
    let positions: Vec<usize> = (0..n).filter(|&v| index[v].is_some()).collect();
    let poses: Vec<Se3> = positions.iter().map(|&v| Se3(initial[v].expect("posed"))).collect();
    let mut fixed = vec![false; poses.len()];
    let mut edges = Vec::new();
    let mut follows = vec![false; n];
    let mut measured_by_icp = 0;
    for &(u, v) in &steps {
        follows[v] = true;
        let stored = initial[u].expect("posed").inverse() * initial[v].expect("posed");
        let (measured, information, by_icp) =
            odometry_edge(&stored, aligned.and_then(|a| a.get(&(u, v))), &drift);
        measured_by_icp += usize::from(by_icp);
        edges.push(Edge {
            from: index[u].expect("posed"),
            to: index[v].expect("posed"),
            measured: Se3(measured),
            information,
            robust: false,
        });
    }
    for &v in &positions {
        if !follows[v] && (frame[v] == anchor || !placed.contains(&frame[v])) {
            // Each session's first scan is held in the first's frame and in frames left apart;
            // a frame placed by its loops moves with the map.
            fixed[index[v].expect("posed")] = true;
        }
    }
    for &(_, a, b, z, info) in &loops {
        edges.push(Edge {
            from: index[a].expect("posed"),
            to: index[b].expect("posed"),
            measured: Se3(z),
            information: info,
            robust: true,
        });
    }
    let odometry = edges.len() - loops.len();
    out.steps_aligned = aligned.map(|_| (steps.len(), measured_by_icp));
    let mut graph = Graph { poses, fixed, edges };
    graph.hold_one_per_part();
    out.graph = Some((positions.iter().map(|&v| v as i64).collect(), graph.clone()));
    out.loops.0 = loops.len() + vetoed.len();
    out.vetoed = vetoed.len();
    if !optimize {
        return out;
    }
    match graph.optimize(&Options::default()) {
        Ok(solution) => {
            for (k, &(row, ..)) in loops.iter().enumerate() {
                out.in_map[row] = Some(solution.kept(odometry + k));
            }
            for &(row, ..) in &vetoed {
                out.in_map[row] = Some(false);
            }
            out.loops.1 = out.in_map.iter().filter(|m| **m == Some(true)).count();
            out.costs = (solution.initial_cost, solution.cost);
            out.iterations = solution.iterations;
            out.corrected = (0..n).map(|v| index[v].map(|i| graph.poses[i].0)).collect();
        }
        Err(e) => {
            out.failed = Some(format!(
                "the map's solve did not converge in {} iterations (last cost {:.3}); the odometry is kept",
                e.iterations, e.cost
            ));
        }
    }
    out
}

/// `<out stem>.<session>.<extension>` beside `out` (with `method` when several methods ran).
pub(super) fn output_path(out: &Path, method: Option<&str>, session: &str, extension: &str) -> PathBuf {
    let stem = out.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "loops".into());
    let name = match method {
        Some(m) => format!("{stem}.{m}.{session}.{extension}"),
        None => format!("{stem}.{session}.{extension}"),
    };
    out.with_file_name(name)
}

/// Writes each session's corrected poses as TUM (`time x y z qx qy qz qw`, the scans' times in
/// seconds; a session without times numbers its scans 0, 1, …) and in KITTI's layout (the 3 × 4
/// matrix row by row), atomically.
pub(super) fn write_poses(
    map: &MethodMap,
    walk: &[Vertex],
    out: &Path,
    method: Option<&str>,
) -> Result<Vec<PathBuf>> {
    let mut sessions: Vec<&str> = Vec::new();
    for v in walk {
        if !sessions.contains(&v.session.as_str()) {
            sessions.push(&v.session);
        }
    }
    let mut written = Vec::new();
    for session in sessions {
        let (mut tum, mut kitti) = (String::new(), String::new());
        for (k, (v, p)) in walk.iter().zip(&map.corrected).filter(|(v, _)| v.session == session).enumerate() {
            let Some(p) = p else { continue };
            let t = p.translation.vector;
            let q = p.rotation;
            let time = v.utime.map(|u| u as f64 / 1e6).unwrap_or(k as f64);
            tum += &format!(
                "{time:.6} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}\n",
                t.x, t.y, t.z, q.i, q.j, q.k, q.w
            );
            let m = p.to_homogeneous();
            let rows: Vec<String> = (0..3)
                .flat_map(|r| (0..4).map(move |c| (r, c)))
                .map(|(r, c)| format!("{:.9}", m[(r, c)]))
                .collect();
            kitti += &rows.join(" ");
            kitti.push('\n');
        }
        for (extension, text) in [("tum", &tum), ("kitti", &kitti)] {
            let path = output_path(out, method, session, extension);
            let mut file = crate::fsutil::AtomicFile::create(&path)?;
            file.write_all(text.as_bytes()).at(&path)?;
            file.commit()?;
            written.push(path);
        }
    }
    Ok(written)
}

/// The corrected poses of `maps` as a record batch of the `corrected_poses` table
/// ([`crate::sinks::schema::corrected_poses`]): each map's scans in walking order, those out of
/// the graph (no pose) left out; none for a map not made.
pub fn corrected_batch(maps: &[MethodMap]) -> arrow::record_batch::RecordBatch {
    let mut b = crate::sinks::rows::RowBuilder::plain(&crate::sinks::schema::corrected_poses());
    let [method, session, scan, time] = ["method", "session", "scan_id", "time"].map(|n| b.col(n));
    let values = ["x", "y", "z", "qx", "qy", "qz", "qw"].map(|n| b.col(n));
    for m in maps {
        for ((s, id, utime), pose) in m.scans.iter().zip(&m.corrected) {
            let Some(p) = pose else { continue };
            let (t, q) = (p.translation.vector, p.rotation);
            b.text(method, Some(&m.method))
                .text(session, Some(s))
                .text(scan, Some(id))
                .float(time, utime.map(|u| u as f64 / 1e6));
            for (c, v) in values.into_iter().zip([t.x, t.y, t.z, q.i, q.j, q.k, q.w]) {
                b.float(c, Some(v));
            }
            b.end_row();
        }
    }
    b.finish().expect("the columns of the corrected_poses table")
}

/// Writes the map's graph, as it was before the solve, in g2o's format: a `VERTEX_SE3:QUAT` per
/// scan with a pose (id: its walking position), the odometry and loop edges with their
/// information (see the module doc), and a `FIX` line for the held scans; atomically.
pub(super) fn write_g2o(path: &Path, map: &MethodMap) -> Result<()> {
    let text = match &map.graph {
        Some((ids, graph)) => crate::map::g2o::text_3d(ids, graph),
        None => String::new(),
    };
    crate::fsutil::write_atomic(path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::super::row::{Check, Match};
    use super::*;

    /// The default drift model, optimized.
    fn optimized() -> Making<'static> {
        Making { optimize: true, ..Making::default() }
    }

    /// Two laps of a 40 m square block, a scan every 2 m (80 a lap), the second lap's scans
    /// 0.5 m to the side of the first's, as (x, y, yaw).
    fn laps() -> Vec<[f64; 3]> {
        let mut out = Vec::new();
        for lap in 0..2 {
            let side = 0.5 * lap as f64;
            for k in 0..80 {
                let (edge, along) = (k / 20, 2.0 * (k % 20) as f64);
                let (x, y, yaw) = match edge {
                    0 => (along, -side, 0.0),
                    1 => (40.0 + side, along, std::f64::consts::FRAC_PI_2),
                    2 => (40.0 - along, 40.0 + side, std::f64::consts::PI),
                    _ => (-side, 40.0 - along, -std::f64::consts::FRAC_PI_2),
                };
                out.push([x, y, yaw]);
            }
        }
        out
    }

    fn iso(p: [f64; 3]) -> Isometry3<f64> {
        isometry(&crate::types::Pose { x: p[0], y: p[1], z: 0.0, yaw: p[2] })
    }

    fn row(from: usize, to: usize, relative: Isometry3<f64>, session: (&str, &str)) -> LoopRow {
        let (roll, pitch, yaw) = relative.rotation.euler_angles();
        let t = relative.translation.vector;
        LoopRow {
            method: "m".into(),
            query_scan: format!("{to}"),
            query_session: session.1.into(),
            matched_scan: format!("{from}"),
            matched_session: session.0.into(),
            query_vertex: to,
            found: Match {
                row: from,
                distance: 0.1,
                yaw_degrees: None,
                offset: None,
                rank2_distance: None,
                true_distance_m: None,
                accepted: true,
            },
            check: Some(Check {
                passed: true,
                fitness: 0.8,
                rmse: 0.05,
                relative: [t.x, t.y, t.z, roll.to_degrees(), pitch.to_degrees(), yaw.to_degrees()],
            }),
            in_map: None,
        }
    }

    /// The odometry of `truth`: 2 % long, turning 0.003 rad a scan too far.
    fn drifted(truth: &[[f64; 3]]) -> Vec<[f64; 3]> {
        let mut out = vec![truth[0]];
        for k in 1..truth.len() {
            let step = iso(truth[k - 1]).inverse() * iso(truth[k]);
            let (t, yaw) = (step.translation.vector * 1.02, step.rotation.euler_angles().2 + 0.003);
            let p = iso(out[k - 1])
                * Isometry3::from_parts(t.into(), UnitQuaternion::from_euler_angles(0.0, 0.0, yaw));
            out.push([p.translation.x, p.translation.y, p.rotation.euler_angles().2]);
        }
        out
    }

    fn walk(session: &str, poses: &[[f64; 3]]) -> Vec<Vertex> {
        poses
            .iter()
            .enumerate()
            .map(|(k, p)| Vertex {
                scan_id: format!("{k}"),
                session: session.into(),
                utime: Some(k as i64 * 100_000),
                pose: Some(crate::types::Pose { x: p[0], y: p[1], z: 0.0, yaw: p[2] }),
            })
            .collect()
    }

    fn worst(map: &MethodMap, truth: &[[f64; 3]]) -> f64 {
        map.corrected
            .iter()
            .zip(truth)
            .map(|(c, t)| {
                let c = c.expect("in the map");
                ((c.translation.x - t[0]).powi(2) + (c.translation.y - t[1]).powi(2)).sqrt()
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_false_loop_that_passed_icp_is_rejected_and_the_true_ones_kept() {
        let truth = laps();
        let vertices = walk("a", &drifted(&truth));
        // The second lap's scans revisit the first's; one scan pair 28 m apart made a false
        // loop whose relative pose looks plausible (1.2 m ahead, a small turn).
        let mut rows: Vec<LoopRow> = (80..160)
            .step_by(4)
            .map(|k| row(k - 80, k, iso(truth[k - 80]).inverse() * iso(truth[k]), ("a", "a")))
            .collect();
        rows.push(row(30, 130, iso([1.2, 0.3, 0.05]), ("a", "a")));
        let map = make("m", &vertices, &rows, &|_| 0, "a", &optimized());
        assert_eq!(map.in_map.last(), Some(&Some(false)), "{:?}", map.in_map);
        assert!(map.in_map[..rows.len() - 1].iter().all(|k| *k == Some(true)), "{:?}", map.in_map);
        // The loops hold the second lap to the first; what drift the two share, they cannot see.
        let odometry = MethodMap {
            corrected: vertices.iter().map(|v| v.pose.as_ref().map(isometry)).collect(),
            ..map.clone()
        };
        assert!(
            worst(&map, &truth) < 0.5 * worst(&odometry, &truth),
            "{} against {}",
            worst(&map, &truth),
            worst(&odometry, &truth)
        );
    }

    #[test]
    fn false_loops_that_agree_with_each_other_do_not_open_the_lap_they_cross() {
        // One lap of the block: its last scans close it on its first; three consecutive scans
        // at the opposite corner, 56 m away, match the first three as if they were there (a
        // lookalike corner that passed ICP): they agree with each other, not with the odometry.
        let truth = laps()[..80].to_vec();
        let vertices = walk("a", &drifted(&truth));
        let mut rows: Vec<LoopRow> =
            (77..80).map(|k| row(0, k, iso(truth[0]).inverse() * iso(truth[k]), ("a", "a"))).collect();
        let closures = rows.len();
        rows.extend((40..43).map(|k| row(k - 40, k, iso([0.3, 0.1, 0.02]), ("a", "a"))));
        let map = make("m", &vertices, &rows, &|_| 0, "a", &optimized());
        assert!(map.in_map[closures..].iter().all(|k| *k == Some(false)), "{:?}", map.in_map);
        assert!(map.in_map[..closures].iter().all(|k| *k == Some(true)), "{:?}", map.in_map);
    }

    #[test]
    fn a_session_in_its_own_frame_is_brought_into_the_first_and_one_without_loops_left_apart() {
        let truth = laps();
        let (first, second) = (&truth[..80], &truth[80..]);
        // The second session's odometry starts in a frame of its own: turned 90°, 100 m away.
        let elsewhere = iso([100.0, -30.0, std::f64::consts::FRAC_PI_2]);
        let moved: Vec<[f64; 3]> = drifted(second)
            .iter()
            .map(|p| {
                let q = elsewhere * iso(*p);
                [q.translation.x, q.translation.y, q.rotation.euler_angles().2]
            })
            .collect();
        let mut vertices = walk("a", first);
        vertices.extend(walk("b", &moved));
        vertices.extend(walk("c", &first[..10]));
        let rows: Vec<LoopRow> = (80..160)
            .step_by(4)
            .map(|k| row(k - 80, k, iso(truth[k - 80]).inverse() * iso(truth[k]), ("a", "b")))
            .collect();
        let frame = |s: &str| match s {
            "a" => 0,
            "b" => 1,
            _ => 2,
        };
        let map = make("m", &vertices, &rows, &frame, "a", &optimized());
        assert_eq!(map.apart, vec!["c".to_string()]);
        assert!(map.in_map.iter().all(|k| *k == Some(true)), "{:?}", map.in_map);
        // Each revisit sits where it should beside the scan it revisits (0.5 m to the side).
        for k in 80..160 {
            let (a, b) = (map.corrected[k - 80].expect("in the map"), map.corrected[k].expect("in the map"));
            let (ta, tb) = (iso(truth[k - 80]), iso(truth[k]));
            let off = (b.translation.vector - a.translation.vector)
                - (tb.translation.vector - ta.translation.vector);
            assert!(off.norm() < 0.5, "scan {k}: {} m off its place beside {}", off.norm(), k - 80);
        }
        // Session c stays where its own poses put it.
        let c = map.corrected[160].expect("in the map");
        assert!((c.translation.x - first[0][0]).abs() < 1e-9 && (c.translation.y - first[0][1]).abs() < 1e-9);
    }
}
