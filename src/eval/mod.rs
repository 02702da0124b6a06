//! `toporec eval`: place-recognition protocols over indexes, each writing `report.json` (every
//! number), a table on stdout, and plots beside the JSON.
//!
//! * [`places()`]: a database index (or some of its sessions) against query descriptors (another
//!   index made with the same codebook, or other sessions): true matches are database scans
//!   within R metres (2D, poses), for each R; Recall@1..N and Recall@1 % under both
//!   denominators. Optional RING-style distance subsampling of map and queries.
//! * [`perturbation`]: the paper's object protocol: a seeded fraction of the index's scans are
//!   re-read, preprocessed as the index did, perturbed (jitter, scaling, translation,
//!   rotation about z), and must retrieve themselves.
//!
//! Both evaluate every descriptor method of the index side by side (`--method` picks some):
//! one report, one table with a block per method, one Recall@N plot with a line per method
//! (and threshold), and each method's time per query split into its steps.

pub mod conditions;
pub mod metrics;
pub mod places;
pub mod report;

pub use places::{PlacesArgs, Protocol, places};

/// Appends one formatted line to a report table (a `String`, which cannot fail to grow).
macro_rules! line {
    ($out:expr, $($arg:tt)*) => {{
        $out.push_str(&format!($($arg)*));
        $out.push('\n');
    }};
}

use crate::error::{Error, Result, ResultExt};
use crate::methods::{Method, MethodKind, TOPOREC};
use crate::ranges;
use crate::rng::SplitMix64;
use crate::search::{Engine, StepTimes, index_methods, step_stats, step_summary};
use metrics::{Denominator, first_hit, one_percent_k, recall};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// The methods to evaluate, as the first of `indexes` records them: those asked for, or every
/// method all `indexes` hold (TopoRec first).
fn chosen_methods(indexes: &[&Path], asked: &[String]) -> Result<Vec<Method>> {
    let mut held: Option<Vec<Method>> = None;
    for index in indexes {
        let here = index_methods(index)?;
        held = Some(match held {
            None => here,
            Some(h) => h.into_iter().filter(|m| here.iter().any(|x| x.name == m.name)).collect(),
        });
    }
    let held = held.unwrap_or_default();
    if asked.is_empty() {
        if held.is_empty() {
            return Err(Error::invalid("the indexes hold no descriptor method in common"));
        }
        return Ok(held);
    }
    let mut out: Vec<Method> = Vec::new();
    for name in asked {
        if out.iter().any(|m| &m.name == name) {
            continue;
        }
        let Some(m) = held.iter().find(|m| &m.name == name) else {
            let common: Vec<&str> = held.iter().map(|m| m.name.as_str()).collect();
            return Err(Error::invalid(format!(
                "--method {name}: not held by {} (common methods: {})",
                indexes.iter().map(|i| i.display().to_string()).collect::<Vec<_>>().join(" and "),
                common.join(", ")
            )));
        };
        out.push(m.clone());
    }
    Ok(out)
}

/// The names of `methods`.
fn names(methods: &[Method]) -> Vec<String> {
    methods.iter().map(|m| m.name.clone()).collect()
}

/// A named Recall@N curve.
pub(crate) type Curve = (String, Vec<f64>);

/// Mean and p95 (ms) of each step a method has (or of its search steps).
fn timing_of(method: &Method, times: &[StepTimes], search_only: bool) -> report::Timing {
    step_stats(method, times, search_only)
        .into_iter()
        .map(|(name, mean, p95)| (name.to_string(), report::StepTiming { mean, p95 }))
        .collect()
}

/// The file names of plots written beside a report.
fn file_names(plots: &[PathBuf]) -> Vec<String> {
    plots.iter().filter_map(|p| p.file_name()).map(|n| n.to_string_lossy().into_owned()).collect()
}

/// `--max-n` clamped to the database size, with a warning.
fn clamp_max_n(max_n: usize, n_db: usize) -> usize {
    if max_n > n_db {
        tracing::warn!(
            "--max-n {max_n}: the database holds {n_db} scans; Recall@N is reported up to N = {n_db}"
        );
    }
    max_n.min(n_db).max(1)
}

/// A perturbation of a preprocessed cloud.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Perturbation {
    /// Unchanged.
    Original,
    /// 5 % of the points moved by N(0, σ = 1e-3) per coordinate.
    Jitter,
    /// Multiplied by a factor.
    Scale(f64),
    /// Shifted.
    Translate([f64; 3]),
    /// Rotated about z by degrees.
    Rotate(f64),
}

impl Perturbation {
    /// The paper's set.
    pub fn paper() -> Vec<Perturbation> {
        use Perturbation::*;
        vec![
            Original,
            Jitter,
            Scale(1.05),
            Scale(0.95),
            Translate([0.2, 0.2, 0.1]),
            Rotate(45.0),
            Rotate(90.0),
            Rotate(135.0),
        ]
    }

    /// Its name in reports.
    pub fn name(&self) -> String {
        match self {
            Perturbation::Original => "original".into(),
            Perturbation::Jitter => "jitter".into(),
            Perturbation::Scale(s) => format!("scale x{s}"),
            Perturbation::Translate(t) => format!("translate ({}, {}, {})", t[0], t[1], t[2]),
            Perturbation::Rotate(d) => format!("rotate {d} deg"),
        }
    }

    /// Applies it (jitter seeded by `seed`).
    pub fn apply(&self, points: &[[f64; 3]], seed: u64) -> Vec<[f64; 3]> {
        self.apply_in(points, seed, 1.0)
    }

    /// Applies it with lengths (jitter σ, translation) in units of `unit`: a raw scan in
    /// metres gets the perturbation its normalized cloud would get when `unit` is the
    /// normalization's scale. Rotations and scaling are about the origin (the sensor).
    pub fn apply_in(&self, points: &[[f64; 3]], seed: u64, unit: f64) -> Vec<[f64; 3]> {
        match *self {
            Perturbation::Original => points.to_vec(),
            Perturbation::Jitter => {
                let mut rng = SplitMix64(seed ^ 0x6A69_7474);
                let mut p = points.to_vec();
                let n = (points.len() as f64 * 0.05).round() as usize;
                for _ in 0..n {
                    let i = rng.below(p.len());
                    for c in p[i].iter_mut() {
                        *c += 1e-3 * unit * rng.normal();
                    }
                }
                p
            }
            Perturbation::Scale(s) => points.iter().map(|q| q.map(|c| c * s)).collect(),
            Perturbation::Translate(t) => {
                let t = t.map(|c| c * unit);
                points.iter().map(|q| [q[0] + t[0], q[1] + t[1], q[2] + t[2]]).collect()
            }
            Perturbation::Rotate(deg) => {
                let (s, c) = deg.to_radians().sin_cos();
                points.iter().map(|q| [c * q[0] - s * q[1], s * q[0] + c * q[1], q[2]]).collect()
            }
        }
    }
}

/// Settings of `eval perturbation` (its command-line arguments).
#[derive(clap::Args, Clone, Debug)]
pub struct PerturbationArgs {
    /// The index.
    #[command(flatten)]
    pub index: crate::flags::IndexFlag,
    /// Share of the scans used as queries: (0, 1].
    #[arg(long, default_value_t = 0.2, value_parser = ranges::fraction)]
    pub fraction: f64,
    /// Seed of the choice and of the jitter.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Largest N of Recall@N: [1, ∞), clamped to the database size.
    #[arg(long, default_value_t = 25, value_parser = ranges::count)]
    pub max_n: usize,
    /// Descriptor methods to compare (repeatable; default: every method the index holds that
    /// can describe a scan, i.e. not imported ones).
    #[arg(long = "method")]
    pub methods: Vec<String>,
    /// The search budget of every method: `default`, `exhaustive` or `matched:N` (see
    /// `eval places --help`).
    #[arg(long, default_value = "default")]
    pub search: crate::methods::SearchBudget,
    /// Output folder.
    #[arg(long, short)]
    pub out: PathBuf,
}

/// A chosen scan, re-read: its raw points (sensor frame), preprocessed points (TopoRec), and
/// the normalization scale of its preprocessing (1 without normalization).
struct Reread {
    scan_id: String,
    raw: Vec<[f64; 3]>,
    preprocessed: Option<Vec<[f64; 3]>>,
    unit: f64,
}

/// Runs the perturbation protocol; returns the report text.
///
/// TopoRec follows the paper: the preprocessed (normalized) cloud is perturbed. ScanContext
/// and M2DP take the raw scan in the sensor frame, perturbed the same way with lengths scaled
/// by the scan's normalization scale (so a 0.2 shift of the normalized cloud is 0.2 × that
/// scale in metres) and rotations about the sensor, then their own preprocessing.
pub fn perturbation(a: &PerturbationArgs) -> Result<String> {
    let mut methods = chosen_methods(&[&a.index.path], &a.methods)?;
    let imported = |m: &Method| matches!(m.kind, MethodKind::Imported { .. });
    if a.methods.is_empty() {
        methods.retain(|m| !imported(m));
    } else if let Some(m) = methods.iter().find(|m| imported(m)) {
        return Err(Error::invalid(format!(
            "--method {}: its vectors are imported; perturbed scans cannot be described with it",
            m.name
        )));
    }
    if methods.is_empty() {
        return Err(Error::invalid("no method of the index can describe a perturbed scan"));
    }
    let methods = names(&methods);
    let engines: Vec<Engine> = methods
        .iter()
        .map(|m| Ok(Engine::open(&a.index.path, &[], m)?.with_budget(a.search)))
        .collect::<Result<Vec<_>>>()?;
    // The queries: a seeded share of the first method's scans.
    let first = &engines[0];
    let n = first.scans.len();
    let mut rng = SplitMix64(a.seed ^ 0x7065_7274);
    let mut order: Vec<usize> = (0..n).collect();
    let count = ((a.fraction * n as f64).round() as usize).clamp(1, n);
    for i in 0..count {
        let j = i + rng.below(n - i);
        order.swap(i, j);
    }
    let mut chosen: Vec<usize> = order[..count].to_vec();
    chosen.sort_unstable();
    let wanted: std::collections::HashSet<&str> =
        chosen.iter().map(|&r| first.scans[r].scan_id.as_str()).collect();
    let clouds = reread(a, &wanted, methods.iter().any(|m| m == TOPOREC))?;
    let mut table = String::new();
    line!(
        table,
        "perturbation: {} queries ({}); methods: {}",
        clouds.len(),
        a.index.path.display(),
        methods.join(", ")
    );
    let kinds = Perturbation::paper();
    let mut entries = Vec::new();
    let mut curves = Vec::new();
    for engine in &engines {
        let (json, c) = perturbation_of(a, engine, &clouds, &kinds, methods.len() > 1, &mut table)?;
        entries.push(json);
        curves.extend(c);
    }
    std::fs::create_dir_all(&a.out).at(&a.out)?;
    let plots =
        crate::plot::recall_curves(&a.out.join("recall_at_n"), "Recall@N under perturbations", &curves)?;
    let report = report::PerturbationReport {
        protocol: report::Protocol::Perturbation,
        toporec_version: env!("CARGO_PKG_VERSION").into(),
        index: a.index.path.clone(),
        queries: clouds.len(),
        fraction: a.fraction,
        seed: a.seed,
        search: a.search.to_string(),
        methods: entries,
        plots: file_names(&plots),
    };
    report::write(&a.out, &report::Report::Perturbation(report), &table)?;
    Ok(table)
}

/// Re-reads the `wanted` scans through the index's own sources: raw points, and (for TopoRec)
/// the index's preprocessing.
fn reread(
    a: &PerturbationArgs,
    wanted: &std::collections::HashSet<&str>,
    toporec: bool,
) -> Result<Vec<Reread>> {
    let pipeline = crate::pipeline::config::Pipeline::of_index(&a.index.path)?;
    // One preprocessing, in metres; the normalization (the last step) then gives TopoRec's
    // cloud and the scale the raw scans' perturbations are measured in.
    let mut metric = pipeline.preprocess.clone();
    metric.normalize = false;
    let mut rows = crate::sinks::index::IndexReader::open(&a.index.path)?.scans()?;
    rows.retain(|r| wanted.contains(r.scan_id.as_str()));
    // In the order the sources yield them.
    rows.sort_by_key(|r| r.seq);
    let places: Vec<_> = rows.iter().map(|r| r.place()).collect();
    let mut clouds = Vec::new();
    for (_, item) in crate::sources::reread::Rereader::new(&pipeline.sources).scans(&places) {
        let Ok(scan) = item else { continue };
        let id = scan.id.clone();
        let (mut preprocessed, mut unit) = (None, 1.0);
        if toporec || pipeline.preprocess.normalize {
            let mut pts = crate::preprocess::preprocess(scan.points.clone(), scan.fingerprint, &metric)
                .map_err(|skip| Error::invalid(format!("{id}: skipped on re-reading: {}", skip.0)))?;
            if pipeline.preprocess.normalize {
                unit = crate::preprocess::normalize(&mut pts);
            }
            preprocessed = toporec.then_some(pts);
        }
        clouds.push(Reread { scan_id: id, raw: scan.points, preprocessed, unit });
    }
    if clouds.len() != wanted.len() {
        return Err(Error::index(
            &a.index.path,
            format!(
                "{} of {} chosen scans could be re-read from the index's sources",
                clouds.len(),
                wanted.len()
            ),
        ));
    }
    Ok(clouds)
}

/// The perturbation protocol with one method; appends its block to `table`.
fn perturbation_of(
    a: &PerturbationArgs,
    engine: &Engine,
    clouds: &[Reread],
    kinds: &[Perturbation],
    several: bool,
    table: &mut String,
) -> Result<(report::PerturbationMethod, Vec<Curve>)> {
    let n = engine.scans.len();
    let rows: std::collections::HashMap<&str, usize> =
        engine.scans.iter().enumerate().map(|(r, s)| (s.scan_id.as_str(), r)).collect();
    let k1 = one_percent_k(n);
    let max_n = clamp_max_n(a.max_n, n);
    let want = max_n.max(k1).min(n);
    let method = &engine.method;
    let name = if several { format!("{}: ", method.name) } else { String::new() };
    let present: Vec<(&Reread, usize)> =
        clouds.iter().filter_map(|c| rows.get(c.scan_id.as_str()).map(|&r| (c, r))).collect();
    line!(table, "{name}{} queries of {n} scans; Recall@1% uses the top {k1}", present.len());
    let n5 = 5.min(max_n);
    line!(table, "{:<24} {:>9} {:>9} {:>10}", "perturbation", "R@1", format!("R@{n5}"), "R@1%");
    let mut results = Vec::new();
    let mut curves = Vec::new();
    let mut times: Vec<StepTimes> = Vec::new();
    let topological = engine.describer.topological;
    for kind in kinds {
        let outcomes: Vec<Result<(Option<usize>, StepTimes)>> = present
            .par_iter()
            .map(|(c, row)| {
                let seed = a.seed ^ crate::preprocess::seed_of(&c.scan_id);
                let p = match (&c.preprocessed, topological) {
                    (Some(pts), true) => kind.apply(pts, seed),
                    _ => kind.apply_in(&c.raw, seed, c.unit),
                };
                let (v, t) =
                    engine.describe_points(&p, &c.scan_id).map_err(|e| Error::invalid(e.to_string()))?;
                let (hits, s) = engine.find(&v, want)?;
                let t = StepTimes { search: s.search, rerank: s.rerank, ..t };
                Ok((first_hit(&hits.iter().map(|h| h.row).collect::<Vec<_>>(), |r| r == *row), t))
            })
            .collect();
        let mut hits = Vec::new();
        for o in outcomes {
            let (h, t) = o?;
            hits.push(h);
            times.push(t);
        }
        let rc = recall(&hits, &vec![true; hits.len()], max_n, n, Denominator::All);
        line!(
            table,
            "{:<24} {:>9.2} {:>9.2} {:>10.2}",
            kind.name(),
            rc.at_n[0],
            rc.at_n[n5 - 1],
            rc.at_one_percent
        );
        let prefix = if several { format!("{}, ", method.name) } else { String::new() };
        curves.push((format!("{prefix}{}", kind.name()), rc.at_n.clone()));
        results.push(report::PerturbationResult { perturbation: kind.name(), recall: rc });
    }
    line!(table, "per query (mean / p95 ms): {}", step_summary(method, &times, false));
    let entry = report::PerturbationMethod {
        method: method.name.clone(),
        id: engine.id.clone(),
        descriptor_length: engine.scans.first().map_or(0, |s| s.descriptor.len()),
        database_scans: n,
        queries: present.len(),
        one_percent_k: k1,
        results,
        timing_ms: timing_of(method, &times, false),
    };
    Ok((entry, curves))
}
