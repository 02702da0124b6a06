//! The PointNetVLAD benchmark's protocol (Uy & Lee, CVPR 2018), as its
//! `generating_queries/generate_test_sets.py` and `evaluate.py` compute it, on an index of the
//! benchmark's test submaps (`kind = "pointnetvlad"`):
//!
//! * datasets: Oxford (23 of its 45 runs, sorted by name: indices 5–7, 9–19, 22, 24, 31–33, 38,
//!   39, 43, 44) and the in-house areas (sorted runs 0–4 business, 5–9 residential, 10–14
//!   university);
//! * the database of a run is every test submap of it; its queries are the submaps strictly
//!   inside a test region (squares of half-width 150 m around fixed UTM centres; business: every
//!   submap);
//! * for each ordered pair of runs (database m, queries n, m ≠ n), each query with at least one
//!   database submap within 25 m (inclusive) retrieves its 25 nearest descriptors: Recall@N counts
//!   the first true match at rank < N, Recall@1 % within the top `max(round_half_even(n / 100), 1)`;
//!   queries without a true match are skipped;
//! * a dataset's figure is the plain mean over its run pairs.

use super::PlacesArgs;
use crate::error::{Error, Result, ResultExt};
use crate::eval::metrics::{Denominator, first_hit, one_percent_k, recall};
use crate::eval::report::DatasetRecall;
use crate::eval::report::{self as report, Report};
use crate::eval::{chosen_methods, file_names, names};
use crate::search::{Engine, Loaded, load_method};
use crate::sinks::index::IndexedScan;
use crate::sinks::index::damage::{Damage, DamagedPart};
use crate::sinks::index::holdings::held_scans;
use std::collections::BTreeMap;
use std::path::Path;

/// Oxford runs of the test sets: indices into the sorted run folders.
pub(crate) const OXFORD_RUNS: [usize; 23] =
    [5, 6, 7, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 22, 24, 31, 32, 33, 38, 39, 43, 44];
/// Oxford test regions (northing, easting).
const OXFORD_REGIONS: [[f64; 2]; 4] = [
    [5735712.768124, 620084.402381],
    [5735611.299219, 620540.270327],
    [5735237.358209, 620543.094379],
    [5734749.303802, 619932.693364],
];
/// University area test regions.
const UNIVERSITY_REGIONS: [[f64; 2]; 3] =
    [[363621.292362, 142864.19756], [364788.795462, 143125.746609], [363597.507711, 144011.414174]];
/// Residential area test regions.
const RESIDENTIAL_REGIONS: [[f64; 2]; 3] =
    [[360895.486453, 144999.915143], [362357.024536, 144894.825301], [361368.907155, 145209.663042]];
/// Centres (northing, easting) of test regions.
type Regions = &'static [[f64; 2]];
/// Half-width of a test region (m).
const REGION_HALF_WIDTH: f64 = 150.0;
/// A database submap within this distance (m, inclusive) of a query is a true match.
pub(crate) const MATCH_RADIUS: f64 = 25.0;
/// Neighbours retrieved per query (and the largest N of Recall@N).
pub(crate) const NEIGHBOURS: usize = 25;

/// One dataset of the benchmark: its runs (sessions) and query regions (`None`: every submap is
/// a query).
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Dataset {
    /// `oxford`, `business`, `residential`, `university`.
    pub name: &'static str,
    /// Its runs, in the benchmark's order.
    pub runs: Vec<String>,
    /// Query regions (centres), or every submap.
    pub regions: Option<&'static [[f64; 2]]>,
}

/// The datasets an index's benchmark folder holds, and notes on those it cannot form.
pub(super) fn datasets(
    spec: &crate::sources::pointnetvlad::PointNetVladSpec,
) -> Result<(Vec<Dataset>, Vec<String>)> {
    let runs = spec.runs()?;
    let names =
        |set: &str| -> Vec<String> { runs.iter().filter(|r| r.set == set).map(|r| r.name.clone()).collect() };
    let (oxford, inhouse) = (names("oxford"), names("inhouse"));
    let mut out = Vec::new();
    let mut notes = Vec::new();
    if !oxford.is_empty() {
        if oxford.len() > OXFORD_RUNS[OXFORD_RUNS.len() - 1] {
            let runs = OXFORD_RUNS.iter().map(|&i| oxford[i].clone()).collect();
            out.push(Dataset { name: "oxford", runs, regions: Some(&OXFORD_REGIONS) });
        } else {
            notes.push(format!(
                "oxford: {} runs; its test sets take runs {}..{} of the 45 it ships with; left out",
                oxford.len(),
                OXFORD_RUNS[0],
                OXFORD_RUNS[OXFORD_RUNS.len() - 1]
            ));
        }
    }
    let areas: [(&'static str, usize, Option<Regions>); 3] = [
        ("business", 0, None),
        ("residential", 5, Some(&RESIDENTIAL_REGIONS)),
        ("university", 10, Some(&UNIVERSITY_REGIONS)),
    ];
    for (name, first, regions) in areas {
        match inhouse.get(first..first + 5) {
            Some(runs) => out.push(Dataset { name, runs: runs.to_vec(), regions }),
            None if !inhouse.is_empty() => notes.push(format!(
                "{name}: the in-house runs {first}..{} are not all there ({} in-house runs); left out",
                first + 4,
                inhouse.len()
            )),
            None => {}
        }
    }
    Ok((out, notes))
}

/// Whether a position is a query of a dataset.
fn is_query(p: [f64; 3], regions: Option<&[[f64; 2]]>) -> bool {
    regions.is_none_or(|rs| {
        rs.iter().any(|c| {
            (c[0] - REGION_HALF_WIDTH < p[0] && p[0] < c[0] + REGION_HALF_WIDTH)
                && (c[1] - REGION_HALF_WIDTH < p[1] && p[1] < c[1] + REGION_HALF_WIDTH)
        })
    })
}

/// The protocol on one method's descriptors.
pub(crate) fn evaluate_method(
    index: &Path,
    method: &str,
    sets: &[Dataset],
    budget: crate::methods::SearchBudget,
    damage: &Damage,
) -> Result<(String, Vec<DatasetRecall>)> {
    let loaded = load_method(index, method, &[], damage)?;
    let (id, length, method_def) = (loaded.id.clone(), loaded.length, loaded.method.clone());
    let mut by_run: BTreeMap<String, Vec<IndexedScan>> = BTreeMap::new();
    for s in loaded.scans.into_iter().filter(|s| s.pose.is_some()) {
        by_run.entry(s.session.clone()).or_default().push(s);
    }
    let mut out = Vec::new();
    for set in sets {
        let runs: Vec<&[IndexedScan]> =
            set.runs.iter().map(|r| by_run.get(r).map(|v| v.as_slice()).unwrap_or(&[])).collect();
        let engines: Vec<Option<Engine>> = runs
            .iter()
            .map(|scans| {
                (!scans.is_empty()).then(|| {
                    Engine::search_only(Loaded {
                        method: method_def.clone(),
                        id: id.clone(),
                        length,
                        codebook: None,
                        scans: scans.to_vec(),
                    })
                    .with_budget(budget)
                })
            })
            .collect();
        let (mut sum_n, mut sum_one, mut pairs, mut empty) = (vec![0.0; NEIGHBOURS], 0.0, 0usize, 0usize);
        for (m, engine) in engines.iter().enumerate() {
            let Some(engine) = engine else { continue };
            let db = &engine.scans;
            let k = NEIGHBOURS.max(one_percent_k(db.len())).min(db.len());
            for (n, queries) in runs.iter().enumerate() {
                if m == n {
                    continue;
                }
                let (mut hits, mut has) = (Vec::new(), Vec::new());
                for q in queries.iter().filter(|q| is_query(q.pose.expect("posed"), set.regions)) {
                    let p = q.pose.expect("posed");
                    let positive = |row: usize| {
                        let d = db[row].pose.expect("posed");
                        (p[0] - d[0]).hypot(p[1] - d[1]) <= MATCH_RADIUS
                    };
                    if !(0..db.len()).any(positive) {
                        continue;
                    }
                    let (found, _) = engine.find(&q.descriptor, k)?;
                    let rows: Vec<usize> = found.iter().map(|f| f.row).collect();
                    hits.push(first_hit(&rows, positive));
                    has.push(true);
                }
                let rc = recall(&hits, &has, NEIGHBOURS, db.len(), Denominator::WithMatch);
                if rc.evaluated == 0 {
                    empty += 1;
                    continue;
                }
                sum_n.iter_mut().zip(&rc.at_n).for_each(|(s, v)| *s += v);
                sum_one += rc.at_one_percent;
                pairs += 1;
            }
        }
        let mean = |v: f64| if pairs == 0 { 0.0 } else { v / pairs as f64 };
        out.push(DatasetRecall {
            dataset: set.name,
            pairs,
            pairs_without_queries: empty,
            recall_at_n: sum_n.into_iter().map(mean).collect(),
            recall_at_one_percent: mean(sum_one),
        });
    }
    Ok((id, out))
}

/// Runs the protocol on every chosen method of `index`; returns the report text and JSON.
pub(super) fn evaluate(
    index: &Path,
    methods: &[String],
    budget: crate::methods::SearchBudget,
    damage: &Damage,
) -> Result<(String, super::report::PointNetVladReport, Vec<super::Curve>)> {
    let pipeline = crate::pipeline::config::Pipeline::of_index(index)?;
    let Some(spec) = pipeline.sources.iter().find_map(|s| s.pointnetvlad()) else {
        return Err(Error::index(
            index,
            "not an index of the PointNetVLAD benchmark (no `pointnetvlad` source)",
        ));
    };
    let (sets, notes) = datasets(spec)?;
    if sets.is_empty() {
        return Err(Error::index(
            index,
            format!("no PointNetVLAD test set can be formed: {}", notes.join("; ")),
        ));
    }
    let mut table = String::new();
    let mut entries = Vec::new();
    let mut curves = Vec::new();
    table.push_str(&format!(
        "pointnetvlad: {} ({}); methods: {}\n",
        index.display(),
        sets.iter().map(|s| s.name).collect::<Vec<_>>().join(", "),
        methods.join(", ")
    ));
    for n in &notes {
        table.push_str(&format!("note: {n}\n"));
    }
    table.push_str(&format!(
        "{:<14} {:<12} {:>6} {:>9} {:>9} {:>9} {:>9}\n",
        "method", "dataset", "pairs", "R@1", "R@5", "R@25", "R@1%"
    ));
    for method in methods {
        let (id, results) = evaluate_method(index, method, &sets, budget, damage)?;
        for r in &results {
            table.push_str(&format!(
                "{:<14} {:<12} {:>6} {:>9.2} {:>9.2} {:>9.2} {:>9.2}\n",
                method,
                r.dataset,
                r.pairs,
                r.recall_at_n[0],
                r.recall_at_n[4],
                r.recall_at_n[NEIGHBOURS - 1],
                r.recall_at_one_percent
            ));
            let prefix = if methods.len() > 1 { format!("{method}, ") } else { String::new() };
            curves.push((format!("{prefix}{}", r.dataset), r.recall_at_n.clone()));
        }
        entries.push(super::report::PointNetVladMethod { method: method.clone(), id, datasets: results });
    }
    let report = super::report::PointNetVladReport {
        protocol: super::report::Protocol::Pointnetvlad,
        toporec_version: env!("CARGO_PKG_VERSION").into(),
        index: index.to_owned(),
        match_radius_m: MATCH_RADIUS,
        neighbours: NEIGHBOURS,
        search: budget.to_string(),
        datasets: sets
            .iter()
            .map(|s| super::report::DatasetRuns { name: s.name.to_string(), runs: s.runs.clone() })
            .collect(),
        notes,
        methods: entries,
        plots: Vec::new(),
        damaged: Vec::new(),
    };
    Ok((table, report, curves))
}

/// `eval places --protocol pointnetvlad`: the benchmark's own database and query sets.
pub(crate) fn places(a: &PlacesArgs, damage: &Damage) -> Result<(String, Vec<DamagedPart>)> {
    if a.queries.is_some() || !a.db_sessions.is_empty() || !a.query_sessions.is_empty() {
        return Err(Error::invalid(
            "--protocol pointnetvlad pairs the benchmark's own runs: --queries, --db-session and --query-session do not apply",
        ));
    }
    let methods = names(&chosen_methods(&[&a.db], &a.methods)?);
    let (table, report, curves) = evaluate(&a.db, &methods, a.search, damage)?;
    std::fs::create_dir_all(&a.out).at(&a.out)?;
    let plots =
        crate::plot::recall_curves(&a.out.join("recall_at_n"), "Recall@N (PointNetVLAD protocol)", &curves)?;
    let mut report = report;
    report.plots = file_names(&plots);
    report.damaged = held_scans(damage.found())?;
    let damaged = report.damaged.clone();
    report::write(&a.out, &Report::PointNetVlad(report), &table)?;
    Ok((table, damaged))
}
