//! `toporec eval`: place-recognition protocols over indexes, each writing `report.json` (every
//! number), a table on stdout, and plots beside the JSON.
//!
//! * [`places`]: a database index (or some of its sessions) against query descriptors (another
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

pub mod metrics;
pub mod pointnetvlad;

/// Appends one formatted line to a report table (a `String`, which cannot fail to grow).
macro_rules! line {
    ($out:expr, $($arg:tt)*) => {{
        $out.push_str(&format!($($arg)*));
        $out.push('\n');
    }};
}

use crate::baselines::{Method, MethodKind, TOPOREC};
use crate::error::{Error, Result, ResultExt};
use crate::query::{Engine, Found, StepTimes, index_methods, load_method, step_stats, step_summary};
use crate::rng::SplitMix64;
use crate::sinks::index::IndexedScan;
use metrics::{Denominator, Recall, first_hit, one_percent_k, recall};
use rayon::prelude::*;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Settings of `eval places` (its command-line arguments).
#[derive(clap::Args, Clone, Debug)]
pub struct PlacesArgs {
    /// The database index.
    #[arg(long)]
    pub db: PathBuf,
    /// Database sessions (repeatable; default all).
    #[arg(long = "db-session")]
    pub db_sessions: Vec<String>,
    /// The query index (default: the database index; must share its codebook).
    #[arg(long)]
    pub queries: Option<PathBuf>,
    /// Query sessions (repeatable; default all).
    #[arg(long = "query-session")]
    pub query_sessions: Vec<String>,
    /// Revisit thresholds R (m), each in (0, ∞).
    #[arg(long, value_delimiter = ',', default_value = "5,10,20,50", value_parser = crate::ranges::positive)]
    pub thresholds: Vec<f64>,
    /// Largest N of Recall@N: [1, ∞), clamped to the database size.
    #[arg(long, default_value_t = 25, value_parser = crate::ranges::count)]
    pub max_n: usize,
    /// Keep a map scan only if farther than this (m, in (0, ∞)) from the last kept (RING).
    #[arg(long, value_parser = crate::ranges::positive)]
    pub map_every: Option<f64>,
    /// Same for query scans.
    #[arg(long, value_parser = crate::ranges::positive)]
    pub query_every: Option<f64>,
    /// Ignore database scans of the query's session closer in time than this (s, [0, ∞)); a
    /// query never retrieves itself.
    #[arg(long, default_value_t = 0.0, value_parser = crate::ranges::non_negative)]
    pub min_time_gap: f64,
    /// Descriptor methods to compare (repeatable; default: every method both indexes hold).
    #[arg(long = "method")]
    pub methods: Vec<String>,
    /// The protocol: `places` (thresholds over poses, above), or `pointnetvlad` (the
    /// PointNetVLAD benchmark's test sets and metric, on an index of its submaps).
    #[arg(long, value_enum, default_value = "places")]
    pub protocol: Protocol,
    /// Output folder for report.json, report.txt and the plots.
    #[arg(long, short)]
    pub out: PathBuf,
}

/// The protocols of `eval places`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Protocol {
    /// Database and query sessions, true matches within each threshold.
    Places,
    /// The PointNetVLAD benchmark ([`pointnetvlad`]).
    Pointnetvlad,
}

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

fn xy(s: &IndexedScan) -> [f64; 2] {
    let p = s.pose.expect("filtered to posed scans");
    [p[0], p[1]]
}

fn subsample(scans: Vec<IndexedScan>, every: Option<f64>) -> Vec<IndexedScan> {
    let Some(every) = every else { return scans };
    let mut last: Option<[f64; 2]> = None;
    scans
        .into_iter()
        .filter(|s| {
            let p = xy(s);
            let keep = last.is_none_or(|l| (p[0] - l[0]).hypot(p[1] - l[1]) > every);
            if keep {
                last = Some(p);
            }
            keep
        })
        .collect()
}

/// Runs the places protocol; returns the report text (also written beside the JSON).
pub fn places(a: &PlacesArgs) -> Result<String> {
    if a.protocol == Protocol::Pointnetvlad {
        return pointnetvlad_places(a);
    }
    let queries_index = a.queries.clone().unwrap_or_else(|| a.db.clone());
    let methods = names(&chosen_methods(&[&a.db, &queries_index], &a.methods)?);
    let mut table = String::new();
    line!(
        table,
        "places: database {}, queries {}; methods: {}",
        a.db.display(),
        queries_index.display(),
        methods.join(", ")
    );
    let mut entries = Vec::new();
    let mut curves = Vec::new();
    let mut plots = Vec::new();
    std::fs::create_dir_all(&a.out).at(&a.out)?;
    for method in &methods {
        let m = places_of(a, &queries_index, method, methods.len() > 1, &mut table)?;
        let prefix = if methods.len() > 1 { format!("{method}, ") } else { String::new() };
        curves.extend(m.curves.into_iter().map(|(name, v)| (format!("{prefix}{name}"), v)));
        plots.extend(m.plots);
        entries.push(m.json);
    }
    plots.extend(crate::plot::recall_curves(
        &a.out.join("recall_at_n"),
        "Recall@N (queries with a match)",
        &curves,
    )?);
    let report = json!({
        "protocol": "places",
        "toporec_version": env!("CARGO_PKG_VERSION"),
        "database": {"index": a.db, "sessions": a.db_sessions, "map_every_m": a.map_every},
        "queries": {"index": queries_index, "sessions": a.query_sessions, "query_every_m": a.query_every},
        "min_time_gap_s": a.min_time_gap,
        "threads": rayon::current_num_threads(),
        "methods": entries,
        "plots": plots.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect::<Vec<_>>(),
    });
    write_report(&a.out, &report, &table)?;
    Ok(table)
}

/// A named Recall@N curve.
pub(crate) type Curve = (String, Vec<f64>);

/// `eval places --protocol pointnetvlad`: the benchmark's own database and query sets.
fn pointnetvlad_places(a: &PlacesArgs) -> Result<String> {
    if a.queries.is_some() || !a.db_sessions.is_empty() || !a.query_sessions.is_empty() {
        return Err(Error::invalid(
            "--protocol pointnetvlad pairs the benchmark's own runs: --queries, --db-session and --query-session do not apply",
        ));
    }
    let methods = names(&chosen_methods(&[&a.db], &a.methods)?);
    let (table, report, curves) = pointnetvlad::evaluate(&a.db, &methods)?;
    std::fs::create_dir_all(&a.out).at(&a.out)?;
    let plots =
        crate::plot::recall_curves(&a.out.join("recall_at_n"), "Recall@N (PointNetVLAD protocol)", &curves)?;
    let mut report = report;
    report["plots"] = json!(
        plots.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect::<Vec<_>>()
    );
    write_report(&a.out, &report, &table)?;
    Ok(table)
}

/// One method's part of a places report.
struct MethodPlaces {
    json: serde_json::Value,
    curves: Vec<Curve>,
    plots: Vec<PathBuf>,
}

/// The places protocol with one method; appends its block to `table`.
fn places_of(
    a: &PlacesArgs,
    queries_index: &Path,
    method: &str,
    several: bool,
    table: &mut String,
) -> Result<MethodPlaces> {
    // Descriptors only: the search structure is built once, over the scans kept below.
    let db_loaded = load_method(&a.db, method, &a.db_sessions)?;
    let q_loaded = load_method(queries_index, method, &a.query_sessions)?;
    if q_loaded.id != db_loaded.id {
        let hint = if method == TOPOREC {
            format!(
                ": index the queries with `vectorize.codebook = \"{}\"`",
                a.db.join("codebook.json").display()
            )
        } else {
            format!(": index both with the same [{method}] parameters")
        };
        let what = if method == TOPOREC { "codebook" } else { "method id" };
        return Err(Error::index(
            queries_index,
            format!(
                "{method}: uses {what} {} but {} uses {}{hint}",
                q_loaded.id,
                a.db.display(),
                db_loaded.id
            ),
        ));
    }
    let (id, length, method_def) = (db_loaded.id.clone(), db_loaded.length, db_loaded.method.clone());
    let (db_all, queries) = (db_loaded.scans, q_loaded.scans);
    let (db_unposed, query_unposed) = (
        db_all.iter().filter(|s| s.pose.is_none()).count(),
        queries.iter().filter(|s| s.pose.is_none()).count(),
    );
    let unposed = db_unposed + query_unposed;
    let db_scans = subsample(db_all.into_iter().filter(|s| s.pose.is_some()).collect(), a.map_every);
    let queries = subsample(queries.into_iter().filter(|s| s.pose.is_some()).collect(), a.query_every);
    if db_scans.is_empty() || queries.is_empty() {
        return Err(Error::invalid(format!(
            "places needs poses: {} database and {} query scans have one ({unposed} without)",
            db_scans.len(),
            queries.len()
        )));
    }
    let n_db = db_scans.len();
    let k1 = one_percent_k(n_db);
    let gap_us = a.min_time_gap * 1e6;
    let is_excluded = |q: &IndexedScan, d: &IndexedScan| {
        q.scan_id == d.scan_id
            || (q.session == d.session
                && q.utime.zip(d.utime).is_some_and(|(x, y)| ((x - y).abs() as f64) < gap_us))
    };
    let max_n = clamp_max_n(a.max_n, n_db);
    let want = max_n.max(k1).min(n_db);
    let skips: Vec<usize> =
        queries.par_iter().map(|q| db_scans.iter().filter(|d| is_excluded(q, d)).count()).collect();
    let k = (want + skips.iter().copied().max().unwrap_or(0)).min(n_db);
    let loaded = crate::query::Loaded {
        method: method_def.clone(),
        id: id.clone(),
        length,
        codebook: None,
        scans: db_scans,
    };
    let engine = Engine::search_only(loaded);
    let db_scans = &engine.scans;
    let start = Instant::now();
    // Batched search (one matrix product per block); each query is charged its block's time.
    let mut retrieved: Vec<(Vec<usize>, StepTimes)> = Vec::with_capacity(queries.len());
    for block in queries.chunks(256) {
        let flat: Vec<f32> = block.iter().flat_map(|q| q.descriptor.iter().copied()).collect();
        for (q, (hits, t)) in block.iter().zip(engine.find_many(&flat, k)) {
            let rows: Vec<usize> = hits
                .into_iter()
                .map(|h: Found| h.row)
                .filter(|&r| !is_excluded(q, &db_scans[r]))
                .take(want)
                .collect();
            retrieved.push((rows, t));
        }
    }
    let wall = start.elapsed().as_secs_f64();
    let search_times: Vec<StepTimes> = retrieved.iter().map(|r| r.1).collect();
    let mut results = Vec::new();
    let name = if several { format!("{method}: ") } else { String::new() };
    line!(
        table,
        "{name}{} database scans, {} queries (length {length}); Recall@1% uses the top {k1}",
        n_db,
        queries.len()
    );
    if unposed > 0 {
        line!(table, "left out, without a pose: {db_unposed} database and {query_unposed} query scans");
    }
    let (n5, n25) = (5.min(max_n), 25.min(max_n));
    line!(
        table,
        "{:>7} {:>10} {:>9} {:>9} {:>9} {:>10} | {:>9} {:>9} {:>10}",
        "R (m)",
        "w/ match",
        "R@1",
        format!("R@{n5}"),
        format!("R@{n25}"),
        "R@1%",
        "all: R@1",
        format!("R@{n5}"),
        "R@1%"
    );
    let mut curves = Vec::new();
    let mut success_first = Vec::new();
    let plan_distance = |q: &IndexedScan, row: usize| {
        let (p, d) = (xy(q), xy(&db_scans[row]));
        (p[0] - d[0]).hypot(p[1] - d[1])
    };
    // Distance from each query to its nearest eligible database scan: it has a true match
    // within R iff this is ≤ R (one pass, not one per threshold).
    let nearest: Vec<f64> = queries
        .par_iter()
        .map(|q| {
            (0..n_db)
                .filter(|&row| !is_excluded(q, &db_scans[row]))
                .map(|row| plan_distance(q, row))
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    for &r in &a.thresholds {
        let has: Vec<bool> = nearest.iter().map(|&d| d <= r).collect();
        let hits: Vec<Option<usize>> = queries
            .iter()
            .zip(&retrieved)
            .map(|(q, (rows, _))| first_hit(rows, |row| plan_distance(q, row) <= r))
            .collect();
        if success_first.is_empty() {
            success_first = hits.iter().map(|h| *h == Some(0)).collect();
        }
        let with = recall(&hits, &has, max_n, n_db, Denominator::WithMatch);
        let all = recall(&hits, &has, max_n, n_db, Denominator::All);
        let at = |rc: &Recall, n: usize| rc.at_n[n - 1];
        line!(
            table,
            "{r:>7} {:>10} {:>9.2} {:>9.2} {:>9.2} {:>10.2} | {:>9.2} {:>9.2} {:>10.2}",
            with.evaluated,
            at(&with, 1),
            at(&with, n5),
            at(&with, n25),
            with.at_one_percent,
            at(&all, 1),
            at(&all, n5),
            all.at_one_percent
        );
        curves.push((format!("R = {r} m"), with.at_n.clone()));
        results.push(json!({"threshold_m": r, "queries_with_match": with.evaluated, "with_match": with, "all_queries": all}));
    }
    line!(
        table,
        "search per query (mean / p95 ms): {} ({} threads, {:.2} s wall)",
        step_summary(&method_def, &search_times, true),
        rayon::current_num_threads(),
        wall
    );
    let qpts: Vec<([f64; 2], bool)> =
        queries.iter().zip(&success_first).map(|(q, &ok)| (xy(q), ok)).collect();
    let dpts: Vec<[f64; 2]> = db_scans.iter().map(xy).collect();
    let title = format!("{name}top-1 within {} m", a.thresholds.first().copied().unwrap_or(0.0));
    let stem = if several { format!("trajectory_{method}") } else { "trajectory".into() };
    let plots = crate::plot::trajectory(&a.out.join(stem), &title, &dpts, &qpts)?;
    let json = json!({
        "method": method,
        "id": id,
        "descriptor_length": length,
        "database_scans": n_db,
        "database_without_pose": db_unposed,
        "query_scans": queries.len(),
        "queries_without_pose": query_unposed,
        "one_percent_k": k1,
        "max_n": max_n,
        "results": results,
        "timing_ms": timing_json(&method_def, &search_times, true),
    });
    Ok(MethodPlaces { json, curves, plots })
}

/// Mean and p95 (ms) of each step a method has (or of its search steps).
fn timing_json(method: &Method, times: &[StepTimes], search_only: bool) -> serde_json::Value {
    let mut out = serde_json::Map::new();
    for (name, mean, p95) in step_stats(method, times, search_only) {
        out.insert(name.to_string(), json!({"mean": mean, "p95": p95}));
    }
    serde_json::Value::Object(out)
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

fn write_report(out: &Path, report: &serde_json::Value, table: &str) -> Result<()> {
    crate::fsutil::write_atomic(
        &out.join("report.json"),
        (serde_json::to_string_pretty(report).expect("JSON of plain values") + "\n").as_bytes(),
    )?;
    crate::fsutil::write_atomic(&out.join("report.txt"), table.as_bytes())
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
    #[arg(long)]
    pub index: PathBuf,
    /// Share of the scans used as queries: (0, 1].
    #[arg(long, default_value_t = 0.2, value_parser = crate::ranges::fraction)]
    pub fraction: f64,
    /// Seed of the choice and of the jitter.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Largest N of Recall@N: [1, ∞), clamped to the database size.
    #[arg(long, default_value_t = 25, value_parser = crate::ranges::count)]
    pub max_n: usize,
    /// Descriptor methods to compare (repeatable; default: every method the index holds that
    /// can describe a scan, i.e. not imported ones).
    #[arg(long = "method")]
    pub methods: Vec<String>,
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
    let mut methods = chosen_methods(&[&a.index], &a.methods)?;
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
    let engines: Vec<Engine> =
        methods.iter().map(|m| Engine::open(&a.index, &[], m)).collect::<Result<Vec<_>>>()?;
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
        a.index.display(),
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
    let report = json!({
        "protocol": "perturbation",
        "toporec_version": env!("CARGO_PKG_VERSION"),
        "index": a.index,
        "queries": clouds.len(),
        "fraction": a.fraction,
        "seed": a.seed,
        "methods": entries,
        "plots": plots.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect::<Vec<_>>(),
    });
    write_report(&a.out, &report, &table)?;
    Ok(table)
}

/// Re-reads the `wanted` scans through the index's own sources: raw points, and (for TopoRec)
/// the index's preprocessing.
fn reread(
    a: &PerturbationArgs,
    wanted: &std::collections::HashSet<&str>,
    toporec: bool,
) -> Result<Vec<Reread>> {
    let pipeline = crate::pipeline::config::Pipeline::of_index(&a.index)?;
    // One preprocessing, in metres; the normalization (the last step) then gives TopoRec's
    // cloud and the scale the raw scans' perturbations are measured in.
    let mut metric = pipeline.preprocess.clone();
    metric.normalize = false;
    let mut clouds = Vec::new();
    for spec in &pipeline.sources {
        for item in spec.open()? {
            let Ok(scan) = item else { continue };
            if !wanted.contains(scan.id.as_str()) {
                continue;
            }
            let id = scan.id.clone();
            let (mut preprocessed, mut unit) = (None, 1.0);
            if toporec || pipeline.preprocess.normalize {
                let mut pts =
                    crate::preprocess::preprocess(scan.points.clone(), scan.fingerprint, &metric)
                        .map_err(|skip| Error::invalid(format!("{id}: skipped on re-reading: {}", skip.0)))?;
                if pipeline.preprocess.normalize {
                    unit = crate::preprocess::normalize(&mut pts);
                }
                preprocessed = toporec.then_some(pts);
            }
            clouds.push(Reread { scan_id: id, raw: scan.points, preprocessed, unit });
        }
    }
    if clouds.len() != wanted.len() {
        return Err(Error::index(
            &a.index,
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
) -> Result<(serde_json::Value, Vec<Curve>)> {
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
        let outcomes: Vec<Result<(Option<usize>, StepTimes), crate::describe::DescribeError>> = present
            .par_iter()
            .map(|(c, row)| {
                let seed = a.seed ^ crate::preprocess::seed_of(&c.scan_id);
                let p = match (&c.preprocessed, topological) {
                    (Some(pts), true) => kind.apply(pts, seed),
                    _ => kind.apply_in(&c.raw, seed, c.unit),
                };
                let (v, t) = engine.describe_points(&p, &c.scan_id)?;
                let (hits, s) = engine.find(&v, want);
                let t = StepTimes { search: s.search, rerank: s.rerank, ..t };
                Ok((first_hit(&hits.iter().map(|h| h.row).collect::<Vec<_>>(), |r| r == *row), t))
            })
            .collect();
        let mut hits = Vec::new();
        for o in outcomes {
            let (h, t) = o.map_err(|e| Error::invalid(e.to_string()))?;
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
        results.push(json!({"perturbation": kind.name(), "recall": rc}));
    }
    line!(table, "per query (mean / p95 ms): {}", step_summary(method, &times, false));
    let json = json!({
        "method": method.name,
        "id": engine.id,
        "descriptor_length": engine.scans.first().map_or(0, |s| s.descriptor.len()),
        "database_scans": n,
        "queries": present.len(),
        "one_percent_k": k1,
        "results": results,
        "timing_ms": timing_json(method, &times, false),
    });
    Ok((json, curves))
}
