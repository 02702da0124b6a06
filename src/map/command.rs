//! `toporec optimize GRAPH.g2o -o OUT.g2o`: any pose graph in g2o's format optimized, written
//! back with its vertices moved.

use super::g2o::{self, G2o, Read};
use super::lie::Pose;
use super::solve::{NotConverged, Options};
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// What `toporec optimize` is asked.
#[derive(clap::Args, Clone, Debug)]
pub struct OptimizeArgs {
    /// The pose graph: g2o's `VERTEX_SE2`/`EDGE_SE2` or `VERTEX_SE3:QUAT`/`EDGE_SE3:QUAT` lines,
    /// `FIX` lines for the held vertices (default: the first one).
    #[arg(value_name = "GRAPH")]
    pub graph: PathBuf,
    /// Where the optimized graph goes: the same lines, the vertices moved.
    #[arg(long, short)]
    pub out: PathBuf,
    /// Weigh the loops (edges between vertices whose ids are not consecutive) by graduated
    /// non-convexity: a loop that disagrees with the rest beyond its own information's χ² bound
    /// is rejected (docs/map.md).
    #[arg(long)]
    pub robust: bool,
    /// Levenberg–Marquardt iterations at most, [1, ∞).
    #[arg(long, default_value_t = 1000, value_parser = crate::ranges::count)]
    pub max_iterations: usize,
    /// Where the solve starts: the file's own vertices, or the chordal relaxation of all edges
    /// (rotations, then translations, by linear least squares; for a graph whose vertices are
    /// far off, as odometry chained over kilometres is).
    #[arg(long, value_enum, default_value_t = Start::File)]
    pub start: Start,
}

/// Where `toporec optimize` starts.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Start {
    /// The graph's own vertices.
    File,
    /// The chordal relaxation ([`super::initialize`]).
    Chordal,
}

/// What `toporec optimize` did.
#[derive(Clone, Debug)]
pub struct Optimized {
    /// `SE(2)` or `SE(3)`.
    pub kind: &'static str,
    /// Vertices, edges, held vertices.
    pub size: (usize, usize, usize),
    /// The cost before and after (GTSAM's `graph.error`: ½ Σ eᵀ Ω e); before is the file's
    /// vertices'.
    pub costs: (f64, f64),
    /// With `--start chordal`, the cost at the chordal start.
    pub start_cost: Option<f64>,
    /// Levenberg–Marquardt iterations.
    pub iterations: usize,
    /// With `--robust`: the loops rejected, as (from id, to id).
    pub rejected: Vec<(i64, i64)>,
    /// Each vertex's id and optimized pose as g2o writes it (x y θ, or x y z qx qy qz qw), in
    /// the file's order.
    pub vertices: Vec<(i64, Vec<f64>)>,
    /// Wall seconds (reading, solving, writing).
    pub seconds: f64,
}

impl std::fmt::Display for Optimized {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (v, e, held) = self.size;
        let start = self.start_cost.map(|c| format!(" → {c:.6} (chordal start)")).unwrap_or_default();
        writeln!(
            f,
            "{} graph: {v} vertices ({held} held), {e} edges; cost {:.6}{start} → {:.6} in {} iterations, {:.2} s",
            self.kind, self.costs.0, self.costs.1, self.iterations, self.seconds
        )?;
        if !self.rejected.is_empty() {
            let shown: Vec<String> = self.rejected.iter().take(20).map(|(a, b)| format!("{a}–{b}")).collect();
            writeln!(f, "loops rejected: {} ({})", self.rejected.len(), shown.join(", "))?;
        }
        Ok(())
    }
}

/// Runs `toporec optimize`: reads the graph, refuses one in disconnected parts (naming them),
/// holds the first vertex when no `FIX` line holds one, optimizes, and writes the result
/// atomically; a solve that does not converge is an error with its last cost, and nothing is
/// written.
pub fn optimize(a: &OptimizeArgs) -> Result<Optimized> {
    optimize_graph(&a.graph, Some(&a.out), a.robust, a.max_iterations, a.start)
}

/// [`optimize`] of the graph at `path`, written to `out` when given (the optimized poses are
/// in [`Optimized::vertices`] either way).
pub fn optimize_graph(
    path: &Path,
    out: Option<&Path>,
    robust: bool,
    max_iterations: usize,
    start: Start,
) -> Result<Optimized> {
    let began = std::time::Instant::now();
    let options = Options { robust, max_iterations, ..Options::default() };
    let mut done = match g2o::read(path)? {
        G2o::Plane(read) => run(read, path, out, &options, start, "SE(2)")?,
        G2o::Space(read) => run(read, path, out, &options, start, "SE(3)")?,
    };
    done.seconds = began.elapsed().as_secs_f64();
    Ok(done)
}

fn run<P: Pose<D> + g2o::FromG2o, const D: usize>(
    mut read: Read<P, D>,
    path: &Path,
    out: Option<&Path>,
    options: &Options,
    start: Start,
    kind: &'static str,
) -> Result<Optimized> {
    let parts = read.graph.parts();
    if parts.len() > 1 {
        let named: Vec<String> = parts
            .iter()
            .take(5)
            .map(|p| {
                let ids: Vec<i64> = p.iter().map(|&v| read.ids[v]).collect();
                let (lo, hi) = (ids.iter().min().unwrap(), ids.iter().max().unwrap());
                format!("{} vertices ({lo}…{hi})", ids.len())
            })
            .collect();
        return Err(Error::invalid(format!(
            "{}: the graph is in {} disconnected parts: {}{}; optimize each on its own",
            path.display(),
            parts.len(),
            named.join(", "),
            if parts.len() > 5 { ", …" } else { "" }
        )));
    }
    if !read.graph.fixed.iter().any(|&f| f) {
        read.graph.fixed[0] = true;
    }
    let held = read.graph.fixed.iter().filter(|&&f| f).count();
    let file_cost = read.graph.cost();
    let start_cost = match start {
        Start::File => None,
        Start::Chordal => {
            read.graph.initialize_chordal().map_err(|super::initialize::NoStart(why)| {
                Error::invalid(format!("{}: no chordal start: {why}", path.display()))
            })?;
            Some(read.graph.cost())
        }
    };
    let solution = read.graph.optimize(options).map_err(|NotConverged { cost, iterations }| {
        Error::invalid(format!(
            "{}: the optimization did not converge in {iterations} iterations (last cost {cost:.6}); nothing written",
            path.display()
        ))
    })?;
    let rejected = (0..read.graph.edges.len())
        .filter(|&e| read.graph.edges[e].robust && !solution.kept(e))
        .map(|e| (read.ids[read.graph.edges[e].from], read.ids[read.graph.edges[e].to]))
        .collect();
    if let Some(out) = out {
        read.write(out)?;
    }
    let vertices = read.ids.iter().zip(&read.graph.poses).map(|(&id, p)| (id, p.to_values())).collect();
    Ok(Optimized {
        kind,
        size: (read.graph.poses.len(), read.graph.edges.len(), held),
        costs: (file_cost, solution.cost),
        start_cost,
        iterations: solution.iterations,
        rejected,
        vertices,
        seconds: 0.0,
    })
}
