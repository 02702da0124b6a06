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

pub mod metrics;

/// Appends one formatted line to a report table (a `String`, which cannot fail to grow).
macro_rules! line {
    ($out:expr, $($arg:tt)*) => {{
        $out.push_str(&format!($($arg)*));
        $out.push('\n');
    }};
}

use crate::error::{Error, Result, ResultExt};
use crate::query::{Engine, StepTimes, load_descriptors, mean_p95_ms};
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
    /// Output folder for report.json, report.txt and the plots.
    #[arg(long, short)]
    pub out: PathBuf,
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
    // Descriptors only: the search structure is built once, over the scans kept below.
    let (codebook, db_all) = load_descriptors(&a.db, &a.db_sessions)?;
    let queries_index = a.queries.clone().unwrap_or_else(|| a.db.clone());
    let (query_codebook, queries) = load_descriptors(&queries_index, &a.query_sessions)?;
    if query_codebook.id() != codebook.id() {
        return Err(Error::index(
            &queries_index,
            format!(
                "uses codebook {} but {} uses {}: index the queries with `vectorize.codebook = \"{}\"`",
                query_codebook.id(),
                a.db.display(),
                codebook.id(),
                a.db.join("codebook.json").display()
            ),
        ));
    }
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
    let vectors: Vec<f32> = db_scans.iter().flat_map(|s| s.descriptor.iter().copied()).collect();
    let db = crate::search::Database::new(vectors, codebook.len());
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
    let start = Instant::now();
    // Batched search (one matrix product per block); each query is charged its block's time.
    let mut retrieved: Vec<(Vec<usize>, f64)> = Vec::with_capacity(queries.len());
    for block in queries.chunks(256) {
        let t = Instant::now();
        let flat: Vec<f32> = block.iter().flat_map(|q| q.descriptor.iter().copied()).collect();
        let hits = db.search_many(&flat, k);
        let secs = t.elapsed().as_secs_f64() / block.len() as f64;
        for (q, h) in block.iter().zip(hits) {
            let rows: Vec<usize> =
                h.into_iter().map(|h| h.0).filter(|&r| !is_excluded(q, &db_scans[r])).take(want).collect();
            retrieved.push((rows, secs));
        }
    }
    let wall = start.elapsed().as_secs_f64();
    let search_secs: Vec<f64> = retrieved.iter().map(|r| r.1).collect();
    let mut results = Vec::new();
    let mut table = String::new();
    line!(
        table,
        "places: {} database scans ({}), {} queries ({}); Recall@1% uses the top {k1}",
        n_db,
        a.db.display(),
        queries.len(),
        queries_index.display()
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
    let (mean, p95) = mean_p95_ms(&search_secs);
    line!(
        table,
        "search: mean {mean:.3} ms, p95 {p95:.3} ms per query ({} threads, {:.2} s wall)",
        rayon::current_num_threads(),
        wall
    );
    std::fs::create_dir_all(&a.out).at(&a.out)?;
    let mut plots =
        crate::plot::recall_curves(&a.out.join("recall_at_n"), "Recall@N (queries with a match)", &curves)?;
    let qpts: Vec<([f64; 2], bool)> =
        queries.iter().zip(&success_first).map(|(q, &ok)| (xy(q), ok)).collect();
    let dpts: Vec<[f64; 2]> = db_scans.iter().map(xy).collect();
    let title = format!("top-1 within {} m", a.thresholds.first().copied().unwrap_or(0.0));
    plots.extend(crate::plot::trajectory(&a.out.join("trajectory"), &title, &dpts, &qpts)?);
    let report = json!({
        "protocol": "places",
        "toporec_version": env!("CARGO_PKG_VERSION"),
        "database": {"index": a.db, "sessions": a.db_sessions, "scans": n_db, "map_every_m": a.map_every, "without_pose": db_unposed},
        "queries": {"index": queries_index, "sessions": a.query_sessions, "scans": queries.len(), "query_every_m": a.query_every, "without_pose": query_unposed},
        "codebook_id": codebook.id(),
        "descriptor_length": codebook.len(),
        "min_time_gap_s": a.min_time_gap,
        "one_percent_k": k1,
        "max_n": max_n,
        "results": results,
        "timing": {"search_mean_ms": mean, "search_p95_ms": p95, "threads": rayon::current_num_threads()},
        "plots": plots.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect::<Vec<_>>(),
    });
    write_report(&a.out, &report, &table)?;
    Ok(table)
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
        match *self {
            Perturbation::Original => points.to_vec(),
            Perturbation::Jitter => {
                let mut rng = SplitMix64(seed ^ 0x6A69_7474);
                let mut p = points.to_vec();
                let n = (points.len() as f64 * 0.05).round() as usize;
                for _ in 0..n {
                    let i = rng.below(p.len());
                    for c in p[i].iter_mut() {
                        *c += 1e-3 * rng.normal();
                    }
                }
                p
            }
            Perturbation::Scale(s) => points.iter().map(|q| q.map(|c| c * s)).collect(),
            Perturbation::Translate(t) => {
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
    /// Output folder.
    #[arg(long, short)]
    pub out: PathBuf,
}

/// Runs the perturbation protocol; returns the report text.
pub fn perturbation(a: &PerturbationArgs) -> Result<String> {
    let engine = Engine::open(&a.index, &[])?;
    let n = engine.scans.len();
    let mut rng = SplitMix64(a.seed ^ 0x7065_7274);
    let mut order: Vec<usize> = (0..n).collect();
    let count = ((a.fraction * n as f64).round() as usize).clamp(1, n);
    for i in 0..count {
        let j = i + rng.below(n - i);
        order.swap(i, j);
    }
    let mut chosen: Vec<usize> = order[..count].to_vec();
    chosen.sort_unstable();
    let wanted: std::collections::HashMap<&str, usize> =
        chosen.iter().map(|&r| (engine.scans[r].scan_id.as_str(), r)).collect();
    // Re-read the chosen scans through the index's own sources and preprocessing.
    let mut clouds: Vec<(usize, Vec<[f64; 3]>)> = Vec::new();
    let pipeline = crate::pipeline::config::Pipeline::of_index(&a.index)?;
    for spec in &pipeline.sources {
        for item in spec.open()? {
            let Ok(scan) = item else { continue };
            if let Some(&row) = wanted.get(scan.id.as_str()) {
                let id = scan.id.clone();
                let points = engine
                    .describer
                    .preprocess(scan)
                    .map_err(|skip| Error::invalid(format!("{id}: skipped on re-reading: {}", skip.0)))?;
                clouds.push((row, points));
            }
        }
    }
    if clouds.len() != chosen.len() {
        return Err(Error::index(
            &a.index,
            format!(
                "{} of {} chosen scans could be re-read from the index's sources",
                clouds.len(),
                chosen.len()
            ),
        ));
    }
    let k1 = one_percent_k(n);
    let max_n = clamp_max_n(a.max_n, n);
    let want = max_n.max(k1).min(n);
    let kinds = Perturbation::paper();
    let mut table = String::new();
    line!(
        table,
        "perturbation: {} queries of {n} scans ({}); Recall@1% uses the top {k1}",
        clouds.len(),
        a.index.display()
    );
    let n5 = 5.min(max_n);
    line!(table, "{:<24} {:>9} {:>9} {:>10}", "perturbation", "R@1", format!("R@{n5}"), "R@1%");
    let mut results = Vec::new();
    let mut curves = Vec::new();
    let mut times: Vec<StepTimes> = Vec::new();
    for kind in &kinds {
        let outcomes: Vec<Result<(Option<usize>, StepTimes), crate::describe::DescribeError>> = clouds
            .par_iter()
            .map(|(row, pts)| {
                let seed = a.seed ^ crate::preprocess::seed_of(&engine.scans[*row].scan_id);
                let p = kind.apply(pts, seed);
                let (v, mut t) = engine.describe_points(&p, &engine.scans[*row].scan_id)?;
                let start = Instant::now();
                let hits = engine.search(&v, want);
                t.search = start.elapsed().as_secs_f64();
                Ok((first_hit(&hits.iter().map(|h| h.0).collect::<Vec<_>>(), |r| r == *row), t))
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
        curves.push((kind.name(), rc.at_n.clone()));
        results.push(json!({"perturbation": kind.name(), "recall": rc}));
    }
    let stat = |f: fn(&StepTimes) -> f64| mean_p95_ms(&times.iter().map(f).collect::<Vec<_>>());
    let (pm, pp) = stat(|t| t.persistence);
    let (vm, vp) = stat(|t| t.vectorize);
    let (sm, sp) = stat(|t| t.search);
    line!(
        table,
        "per query (mean / p95 ms): persistence {pm:.2} / {pp:.2}, vectorize {vm:.3} / {vp:.3}, search {sm:.3} / {sp:.3}"
    );
    std::fs::create_dir_all(&a.out).at(&a.out)?;
    let plots =
        crate::plot::recall_curves(&a.out.join("recall_at_n"), "Recall@N under perturbations", &curves)?;
    let report = json!({
        "protocol": "perturbation",
        "toporec_version": env!("CARGO_PKG_VERSION"),
        "index": a.index,
        "database_scans": n,
        "queries": clouds.len(),
        "fraction": a.fraction,
        "seed": a.seed,
        "codebook_id": engine.codebook().id(),
        "descriptor_length": engine.codebook().len(),
        "one_percent_k": k1,
        "results": results,
        "timing_ms": {
            "persistence": {"mean": pm, "p95": pp},
            "vectorize": {"mean": vm, "p95": vp},
            "search": {"mean": sm, "p95": sp},
        },
        "plots": plots.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect::<Vec<_>>(),
    });
    write_report(&a.out, &report, &table)?;
    Ok(table)
}
