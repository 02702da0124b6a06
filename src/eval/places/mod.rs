//! `eval places`: database scans against query scans with poses, every method of the index
//! side by side, under real-world conditions.
//!
//! A query's true matches are the database scans within R metres (2D), for each R of
//! `--thresholds`; Recall@N and Recall@1 % under both denominators. Beside them:
//!
//! * **nearest database scan**: the share of queries whose top-1 is the database scan closest
//!   to them (ties within 1 µm count);
//! * **loop closure** ([`super::metrics::loop_closure`]): a top-1 accepted when its descriptor
//!   distance is under a threshold, true within `--revisit-radius`; the threshold swept, the
//!   precision–recall curve plotted, F1 max and recall at 100 % precision reported.
//!
//! `--condition` ([`super::conditions`]) re-reads each query scan through the query index's
//! sources, applies the condition to the raw scan, and lets each method describe it as the
//! database index does (its preprocessing, codebook, parameters) before searching; without
//! it (or with `as-recorded`) the stored descriptors are the queries. `--db-scan` and
//! `--query-scan` choose scans by id; `--within-session` compares poses only inside a session
//! (KITTI's sequences each have their own frame).
//!
//! Choosing the scans is `choose`; describing the queries again under each condition,
//! `redescribe`.

mod choose;
mod pointnetvlad;
mod redescribe;

use super::conditions::Condition;
use super::metrics::{Denominator, LoopClosure, Recall, first_hit, loop_closure, one_percent_k, recall};
use super::report::{
    self, ConditionResult, DatabaseSide, EvaluatedCondition, LoopClosureResult, Nearest, PlacesMethod,
    PlacesReport, QuerySide, Report, ThresholdResult, Top1, Top1Row,
};
use super::{Curve, chosen_methods, clamp_max_n, file_names, names, timing_of};
use crate::error::{Error, Result, ResultExt};
use crate::methods::Hit;
use crate::methods::TOPOREC;
use crate::ranges;
use crate::search::{Engine, Loaded, StepTimes, load_method, step_summary};
use crate::sinks::index::IndexedScan;
use crate::sinks::index::damage::{Damage, DamagedPart};
use crate::sinks::index::holdings::held_scans;
pub(crate) use choose::Chooser;
use choose::{subsample, xy};
use rayon::prelude::*;
use redescribe::redescribe;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Appends one formatted line to a report table.
macro_rules! line {
    ($out:expr, $($arg:tt)*) => {{
        $out.push_str(&format!($($arg)*));
        $out.push('\n');
    }};
}

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
    /// Database scans: only those whose id matches one of these patterns (`*` any run of
    /// characters, `?` one, `[…]` one of; repeatable; default all).
    #[arg(long = "db-scan")]
    pub db_scans: Vec<String>,
    /// Query scans likewise.
    #[arg(long = "query-scan")]
    pub query_scans: Vec<String>,
    /// Poses of different sessions are in different frames (KITTI's sequences): a query's
    /// true matches, and its nearest database scan, are in its own session only.
    #[arg(long)]
    pub within_session: bool,
    /// Revisit thresholds R (m), each in (0, ∞).
    #[arg(long, value_delimiter = ',', default_value = "5,10,20,50", value_parser = ranges::positive)]
    pub thresholds: Vec<f64>,
    /// Largest N of Recall@N: [1, ∞), clamped to the database size.
    #[arg(long, default_value_t = 25, value_parser = ranges::count)]
    pub max_n: usize,
    /// Keep a map scan only if farther than this (m, in (0, ∞)) from the last kept (RING).
    #[arg(long, value_parser = ranges::positive)]
    pub map_every: Option<f64>,
    /// Same for query scans.
    #[arg(long, value_parser = ranges::positive)]
    pub query_every: Option<f64>,
    /// Ignore database scans of the query's session closer in time than this (s, [0, ∞)); a
    /// query never retrieves itself.
    #[arg(long, default_value_t = 0.0, value_parser = ranges::non_negative)]
    pub min_time_gap: f64,
    /// Conditions applied to each raw query scan before each method describes it
    /// (repeatable): as-recorded, yaw[=DEG], occlusion[=DEG], drop[=F], beams[=N],
    /// offset[=M], max-range[=M], paper. Default: as-recorded (the stored descriptors).
    #[arg(long = "condition")]
    pub conditions: Vec<String>,
    /// Seed of the conditions' random choices (with each scan's id).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Loop closure: an accepted top-1 within this many metres is a true positive, (0, ∞).
    #[arg(long, default_value_t = 5.0, value_parser = ranges::positive)]
    pub revisit_radius: f64,
    /// Descriptor methods to compare (repeatable; default: every method both indexes hold).
    #[arg(long = "method")]
    pub methods: Vec<String>,
    /// The search budget of every method: `default` (each method's own settings),
    /// `exhaustive` (every database entry re-ranked at every shift), or `matched:N` (N
    /// re-ranked candidates and shifts within ±3 sectors, for every method that has them).
    #[arg(long, default_value = "default")]
    pub search: crate::methods::SearchBudget,
    /// The protocol: `places` (thresholds over poses, above), or `pointnetvlad` (the
    /// PointNetVLAD benchmark's test sets and metric, on an index of its submaps).
    #[arg(long, value_enum, default_value = "places")]
    pub protocol: Protocol,
    /// Answer from the intact parts when some part of the index fails its checksum: every
    /// damaged part and the scans it held are named, and the command exits 1.
    #[arg(long)]
    pub skip_damaged: bool,
    /// Output folder for report.json, report.txt and the plots.
    #[arg(long, short)]
    pub out: PathBuf,
}

/// The protocols of `eval places`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Protocol {
    /// Database and query sessions, true matches within each threshold.
    Places,
    /// The PointNetVLAD benchmark (its own sets).
    Pointnetvlad,
}

/// The conditions asked for (as-recorded when none), each once, in order.
fn parse_conditions(asked: &[String]) -> Result<Vec<Condition>> {
    let mut out: Vec<Condition> = Vec::new();
    for text in asked {
        for c in Condition::parse(text).map_err(|e| Error::invalid(format!("--condition {e}")))? {
            if !out.contains(&c) {
                out.push(c);
            }
        }
    }
    if out.is_empty() {
        out.push(Condition::AsRecorded);
    }
    Ok(out)
}

/// Runs the places protocol; returns the report text (also written beside the JSON).
pub fn places(a: &PlacesArgs) -> Result<(String, Vec<DamagedPart>)> {
    let damage = Damage::skipping(a.skip_damaged);
    if a.protocol == Protocol::Pointnetvlad {
        return pointnetvlad::places(a, &damage);
    }
    let conditions = parse_conditions(&a.conditions)?;
    let queries_index = a.queries.clone().unwrap_or_else(|| a.db.clone());
    let methods = names(&chosen_methods(&[&a.db, &queries_index], &a.methods)?);
    let mut table = String::new();
    line!(
        table,
        "places: database {}, queries {}; methods: {}; conditions: {}",
        a.db.display(),
        queries_index.display(),
        methods.join(", "),
        conditions.iter().map(Condition::name).collect::<Vec<_>>().join(", ")
    );
    std::fs::create_dir_all(&a.out).at(&a.out)?;
    let prepared: Vec<Prepared> =
        methods.iter().map(|m| Prepared::new(a, &queries_index, m, &damage)).collect::<Result<_>>()?;
    let damaged = held_scans(damage.found())?;
    if !damaged.is_empty() {
        line!(table, "left out: {} damaged parts (report.json lists them and their scans)", damaged.len());
    }
    let (redescribed, mean_unit) = if conditions.iter().any(|c| *c != Condition::AsRecorded) {
        redescribe(a, &queries_index, &prepared, &conditions)?
    } else {
        (HashMap::new(), None)
    };
    // The paper's lengths are in units of each scan's normalization scale: labelled in metres.
    let labels: Vec<String> = conditions.iter().map(|c| c.label(mean_unit)).collect();
    let several = methods.len() > 1;
    let (mut entries, mut curves, mut plots, mut pr, mut summary) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (mi, p) in prepared.iter().enumerate() {
        let mut per_condition = Vec::new();
        for (ci, condition) in conditions.iter().enumerate() {
            let described = redescribed.get(&(ci, mi));
            let r = p.evaluate(a, condition, &labels[ci], described, several, ci == 0, &mut table)?;
            let label = if several { format!("{}, {}", p.name, labels[ci]) } else { labels[ci].clone() };
            if let Some(lc) = &r.loop_closure {
                pr.push((label.clone(), lc.curve.iter().map(|q| (q.recall, q.precision)).collect()));
            }
            if ci == 0 {
                let prefix = if several { format!("{}, ", p.name) } else { String::new() };
                curves.extend(r.curves.iter().map(|(name, v)| (format!("{prefix}{name}"), v.clone())));
                plots.extend(r.plots.iter().cloned());
            }
            summary.push((labels[ci].clone(), p.name.clone(), r.summary.clone()));
            per_condition.push(r.result);
        }
        let mut entry = p.entry.clone();
        if let Some(first) = per_condition.first().and_then(|c| c.evaluated.as_ref()) {
            entry.results = Some(first.results.clone());
            entry.timing_ms = Some(first.timing_ms.clone());
        }
        entry.conditions = per_condition;
        entries.push(entry);
    }
    write_summary(&mut table, a, &summary);
    plots.extend(crate::plot::recall_curves(
        &a.out.join("recall_at_n"),
        "Recall@N (queries with a match)",
        &curves,
    )?);
    plots.extend(crate::plot::precision_recall(
        &a.out.join("precision_recall"),
        &format!("Loop closure: top-1 within {} m", a.revisit_radius),
        &pr,
    )?);
    let report = PlacesReport {
        protocol: report::Protocol::Places,
        toporec_version: env!("CARGO_PKG_VERSION").into(),
        database: DatabaseSide {
            index: a.db.clone(),
            sessions: a.db_sessions.clone(),
            scans: a.db_scans.clone(),
            map_every_m: a.map_every,
        },
        queries: QuerySide {
            index: queries_index.clone(),
            sessions: a.query_sessions.clone(),
            scans: a.query_scans.clone(),
            query_every_m: a.query_every,
        },
        within_session: a.within_session,
        min_time_gap_s: a.min_time_gap,
        revisit_radius_m: a.revisit_radius,
        seed: a.seed,
        search: a.search.to_string(),
        conditions: labels,
        threads: rayon::current_num_threads(),
        methods: entries,
        plots: file_names(&plots),
        damaged: damaged.clone(),
    };
    report::write(&a.out, &Report::Places(report), &table)?;
    Ok((table, damaged))
}

/// One (condition, method) line of the summary: R@1 per threshold, nearest, F1 max and
/// recall at 100 % precision (`None`: not applicable).
type SummaryRow = Option<(Vec<Option<f64>>, Option<f64>, f64, f64)>;

fn write_summary(table: &mut String, a: &PlacesArgs, rows: &[(String, String, SummaryRow)]) {
    line!(
        table,
        "\nsummary: R@1 (%) within R of the query, its nearest database scan, loop closure within {} m",
        a.revisit_radius
    );
    let mut head = format!("{:<32} {:<14}", "condition", "method");
    for r in &a.thresholds {
        head.push_str(&format!(" {:>8}", format!("{r} m")));
    }
    head.push_str(&format!(" {:>8} {:>8} {:>8}", "nearest", "F1 max", "R@P100"));
    line!(table, "{head}");
    let cell = |v: Option<f64>| v.map_or_else(|| "-".to_string(), |v| format!("{v:.1}"));
    for (condition, method, row) in rows {
        let mut text = format!("{condition:<32} {method:<14}");
        match row {
            None => text.push_str(" n/a"),
            Some((r1, nearest, f1, rp)) => {
                for v in r1 {
                    text.push_str(&format!(" {:>8}", cell(*v)));
                }
                text.push_str(&format!(" {:>8} {:>8.1} {:>8.1}", cell(*nearest), f1, rp));
            }
        }
        line!(table, "{text}");
    }
}

/// A re-described query: its descriptor and step times, or why there is none.
type Redescribed = Result<(Vec<f32>, StepTimes), String>;

/// One method's database and queries, ready to be searched.
struct Prepared {
    name: String,
    engine: Engine,
    queries: Vec<IndexedScan>,
    db_unposed: usize,
    query_unposed: usize,
    /// Its report entry, without results yet.
    entry: PlacesMethod,
}

/// What one (method, condition) computed: the numbers, before any text or plot.
struct Computed {
    /// Why the condition does not apply (no query could be described under it).
    not_applicable: Option<String>,
    /// Queries described, and those that could not be.
    described: usize,
    not_described: usize,
    /// Database scans, Recall@1 % k, Recall@N's largest N, descriptor length.
    n_db: usize,
    k1: usize,
    max_n: usize,
    length: usize,
    /// Per threshold: (threshold, with a match, all queries).
    recalls: Vec<(f64, Recall, Recall)>,
    /// Whether each query's top-1 is within the first threshold.
    success_first: Vec<bool>,
    /// The nearest database scan as the top-1: queries judged, and the share (%).
    nearest: Nearest,
    loop_closure: Option<LoopClosure>,
    top1: Vec<Top1Row>,
    search_times: Vec<StepTimes>,
    describe_times: Vec<StepTimes>,
    wall: f64,
}

/// One (method, condition)'s results, as reported.
struct Evaluated {
    result: ConditionResult,
    curves: Vec<Curve>,
    plots: Vec<PathBuf>,
    loop_closure: Option<LoopClosure>,
    summary: SummaryRow,
}

impl Prepared {
    fn new(a: &PlacesArgs, queries_index: &Path, method: &str, damage: &Damage) -> Result<Prepared> {
        // A method with a cached search structure (toporec-plus) searches a copy of the chosen
        // rows of it; the others build theirs from the descriptors.
        let in_sessions = |s: &IndexedScan| a.db_sessions.is_empty() || a.db_sessions.contains(&s.session);
        let cached = Engine::open_cached(&a.db, method, &in_sessions, damage)?;
        let db_loaded = match &cached {
            Some(e) => Loaded {
                method: e.method.clone(),
                id: e.id.clone(),
                length: e.method.len(),
                codebook: None,
                scans: e.scans.clone(),
            },
            None => load_method(&a.db, method, &a.db_sessions, damage)?,
        };
        let q_loaded = load_method(queries_index, method, &a.query_sessions, damage)?;
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
        let mut db_loaded = db_loaded;
        let (db_chooser, query_chooser) =
            (Chooser::new("--db-scan", &a.db_scans)?, Chooser::new("--query-scan", &a.query_scans)?);
        let db_all: Vec<IndexedScan> = std::mem::take(&mut db_loaded.scans)
            .into_iter()
            .filter(|s| db_chooser.chosen(&s.scan_id))
            .collect();
        let queries: Vec<IndexedScan> =
            q_loaded.scans.into_iter().filter(|s| query_chooser.chosen(&s.scan_id)).collect();
        let db_unposed = db_all.iter().filter(|s| s.pose.is_none()).count();
        let query_unposed = queries.iter().filter(|s| s.pose.is_none()).count();
        let db_scans = subsample(db_all.into_iter().filter(|s| s.pose.is_some()).collect(), a.map_every);
        let queries = subsample(queries.into_iter().filter(|s| s.pose.is_some()).collect(), a.query_every);
        if db_scans.is_empty() || queries.is_empty() {
            return Err(Error::invalid(format!(
                "places needs poses: {} database and {} query scans are chosen and have one ({} without)",
                db_scans.len(),
                queries.len(),
                db_unposed + query_unposed
            )));
        }
        let (id, length) = (db_loaded.id.clone(), db_loaded.length);
        db_loaded.scans = db_scans;
        let n_db = db_loaded.scans.len();
        let engine = match cached {
            Some(e) => {
                let keep: HashSet<&str> = db_loaded.scans.iter().map(|s| s.scan_id.as_str()).collect();
                e.retain(&|s| keep.contains(s.scan_id.as_str()))?
            }
            None => Engine::from_loaded(&a.db, db_loaded)?,
        }
        .with_budget(a.search);
        let entry = PlacesMethod {
            method: method.to_string(),
            id,
            descriptor_length: length,
            database_scans: n_db,
            database_without_pose: db_unposed,
            query_scans: queries.len(),
            queries_without_pose: query_unposed,
            one_percent_k: one_percent_k(n_db),
            max_n: clamp_max_n(a.max_n, n_db),
            results: None,
            timing_ms: None,
            conditions: Vec::new(),
        };
        Ok(Prepared { name: method.to_string(), engine, queries, db_unposed, query_unposed, entry })
    }

    /// Whether database row `d` may not be retrieved for query `q` (itself, or too close in
    /// time in its own session).
    fn excluded(&self, a: &PlacesArgs, q: &IndexedScan, d: &IndexedScan) -> bool {
        q.scan_id == d.scan_id
            || (q.session == d.session
                && q.utime.zip(d.utime).is_some_and(|(x, y)| ((x - y).abs() as f64) < a.min_time_gap * 1e6))
    }

    /// The distance (m, 2D) of query `q` to database row `row`; infinite across sessions with
    /// `--within-session`.
    fn distance(&self, a: &PlacesArgs, q: &IndexedScan, row: usize) -> f64 {
        let d = &self.engine.scans[row];
        if a.within_session && d.session != q.session {
            return f64::INFINITY;
        }
        let (p, r) = (xy(q), xy(d));
        (p[0] - r[0]).hypot(p[1] - r[1])
    }

    /// A (method, condition): computed, written into the text table, plotted (the first
    /// condition's trajectory), and put in the report's form.
    #[expect(clippy::too_many_arguments, reason = "one call site, each argument a different input")]
    fn evaluate(
        &self,
        a: &PlacesArgs,
        condition: &Condition,
        label: &str,
        described: Option<&HashMap<String, Redescribed>>,
        several: bool,
        detailed: bool,
        table: &mut String,
    ) -> Result<Evaluated> {
        let c = self.compute(a, condition, described);
        self.write_table(a, &c, label, several, detailed, table);
        let plots =
            if detailed && c.not_applicable.is_none() { self.plot(a, &c, several)? } else { Vec::new() };
        Ok(self.reported(a, c, label, plots))
    }

    /// The numbers of one condition.
    fn compute(
        &self,
        a: &PlacesArgs,
        condition: &Condition,
        described: Option<&HashMap<String, Redescribed>>,
    ) -> Computed {
        let db = &self.engine.scans;
        let n_db = db.len();
        // Clamped (and warned about) once, when the method was prepared.
        let max_n = self.entry.max_n;
        let k1 = one_percent_k(n_db);
        let want = max_n.max(k1).min(n_db);
        // The queries' descriptors under this condition (`None`: not described).
        let vectors: Vec<Option<&[f32]>> = match (condition, described) {
            (Condition::AsRecorded, _) | (_, None) => {
                self.queries.iter().map(|q| Some(&q.descriptor[..])).collect()
            }
            (_, Some(map)) => self
                .queries
                .iter()
                .map(|q| map.get(&q.scan_id).and_then(|r| r.as_ref().ok()).map(|(v, _)| &v[..]))
                .collect(),
        };
        let describe_times: Vec<StepTimes> = described
            .filter(|_| *condition != Condition::AsRecorded)
            .map(|map| {
                self.queries
                    .iter()
                    .filter_map(|q| map.get(&q.scan_id)?.as_ref().ok().map(|(_, t)| *t))
                    .collect()
            })
            .unwrap_or_default();
        let failures: Vec<&str> = match described {
            Some(map) if *condition != Condition::AsRecorded => self
                .queries
                .iter()
                .filter_map(|q| map.get(&q.scan_id)?.as_ref().err().map(|e| e.as_str()))
                .collect(),
            _ => Vec::new(),
        };
        let mut c = Computed {
            not_applicable: None,
            described: 0,
            not_described: failures.len(),
            n_db,
            k1,
            max_n,
            length: 0,
            recalls: Vec::new(),
            success_first: Vec::new(),
            nearest: Nearest { queries: 0, recall_at_1: None },
            loop_closure: None,
            top1: Vec::new(),
            search_times: Vec::new(),
            describe_times,
            wall: 0.0,
        };
        if vectors.iter().all(Option::is_none) {
            c.not_applicable =
                Some(failures.first().copied().unwrap_or("no query could be described").to_string());
            return c;
        }
        let skips: Vec<usize> =
            self.queries.par_iter().map(|q| db.iter().filter(|d| self.excluded(a, q, d)).count()).collect();
        let k = (want + skips.iter().copied().max().unwrap_or(0)).min(n_db);
        let start = Instant::now();
        c.length = vectors.iter().flatten().next().map_or(0, |v| v.len());
        let mut retrieved: Vec<Option<(Vec<Hit>, StepTimes)>> = vec![None; self.queries.len()];
        let described_rows: Vec<usize> = (0..self.queries.len()).filter(|&i| vectors[i].is_some()).collect();
        c.described = described_rows.len();
        for block in described_rows.chunks(256) {
            let flat: Vec<f32> = block.iter().flat_map(|&i| vectors[i].unwrap().iter().copied()).collect();
            debug_assert_eq!(flat.len(), block.len() * c.length);
            let found = match self.engine.find_many(&flat, k) {
                Ok(found) => found,
                Err(e) => {
                    c.not_applicable = Some(format!("the search failed: {e}"));
                    return c;
                }
            };
            for (&i, (hits, t)) in block.iter().zip(found) {
                let q = &self.queries[i];
                let kept: Vec<Hit> =
                    hits.into_iter().filter(|h| !self.excluded(a, q, &db[h.row])).take(want).collect();
                retrieved[i] = Some((kept, t));
            }
        }
        c.wall = start.elapsed().as_secs_f64();
        c.search_times = retrieved.iter().flatten().map(|r| r.1).collect();
        let rows_of = |i: usize| -> Vec<usize> {
            retrieved[i].as_ref().map_or_else(Vec::new, |(h, _)| h.iter().map(|f| f.row).collect())
        };
        // Each query's distance to its nearest eligible database scan.
        let nearest: Vec<f64> = self
            .queries
            .par_iter()
            .map(|q| {
                (0..n_db)
                    .filter(|&row| !self.excluded(a, q, &db[row]))
                    .map(|row| self.distance(a, q, row))
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        for &r in &a.thresholds {
            let has: Vec<bool> = nearest.iter().map(|&d| d <= r).collect();
            let hits: Vec<Option<usize>> = self
                .queries
                .iter()
                .enumerate()
                .map(|(i, q)| first_hit(&rows_of(i), |row| self.distance(a, q, row) <= r))
                .collect();
            if c.success_first.is_empty() {
                c.success_first = hits.iter().map(|h| *h == Some(0)).collect();
            }
            let with = recall(&hits, &has, max_n, n_db, Denominator::WithMatch);
            let all = recall(&hits, &has, max_n, n_db, Denominator::All);
            c.recalls.push((r, with, all));
        }
        // Nearest database scan: the top-1 is the closest eligible one.
        let judged: Vec<usize> = (0..self.queries.len()).filter(|&i| nearest[i].is_finite()).collect();
        let nearest_hits = judged
            .iter()
            .filter(|&&i| {
                rows_of(i)
                    .first()
                    .is_some_and(|&top| self.distance(a, &self.queries[i], top) <= nearest[i] + 1e-6)
            })
            .count();
        c.nearest = Nearest {
            queries: judged.len(),
            recall_at_1: (!judged.is_empty()).then(|| 100.0 * nearest_hits as f64 / judged.len() as f64),
        };
        // Loop closure at the revisit radius.
        let (mut top_distance, mut top_within) = (Vec::new(), Vec::new());
        for (i, q) in self.queries.iter().enumerate() {
            match retrieved[i].as_ref().and_then(|(h, _)| h.first()) {
                Some(f) => {
                    top_distance.push(f.distance);
                    top_within.push(self.distance(a, q, f.row) <= a.revisit_radius);
                }
                None => {
                    top_distance.push(f64::INFINITY);
                    top_within.push(false);
                }
            }
        }
        let has_revisit: Vec<bool> = nearest.iter().map(|&d| d <= a.revisit_radius).collect();
        c.loop_closure = Some(loop_closure(&top_distance, &top_within, &has_revisit));
        // Each query's top-1 (id, descriptor distance, metres), for finding the failures.
        let finite = |x: f64| x.is_finite().then_some(x);
        c.top1 = self
            .queries
            .iter()
            .enumerate()
            .map(|(i, q)| match retrieved[i].as_ref().and_then(|(h, _)| h.first()) {
                Some(f) => (
                    q.scan_id.clone(),
                    Some(db[f.row].scan_id.clone()),
                    finite(f.distance),
                    finite(self.distance(a, q, f.row)),
                    finite(nearest[i]),
                ),
                None => (q.scan_id.clone(), None, None, None, finite(nearest[i])),
            })
            .collect();
        c
    }

    /// One condition's lines of the text table (the detailed block for the first condition).
    fn write_table(
        &self,
        a: &PlacesArgs,
        c: &Computed,
        label: &str,
        several: bool,
        detailed: bool,
        table: &mut String,
    ) {
        let name = if several { format!("{}: ", self.name) } else { String::new() };
        if let Some(why) = &c.not_applicable {
            line!(table, "{name}{label}: not applicable ({why})");
            return;
        }
        if !detailed {
            return;
        }
        line!(
            table,
            "{name}{} database scans, {} queries (length {}); Recall@1% uses the top {}",
            c.n_db,
            self.queries.len(),
            c.length,
            c.k1
        );
        if self.db_unposed + self.query_unposed > 0 {
            line!(
                table,
                "left out, without a pose: {} database and {} query scans",
                self.db_unposed,
                self.query_unposed
            );
        }
        let (n5, n25) = (5.min(c.max_n), 25.min(c.max_n));
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
        let at = |rc: &Recall, n: usize| rc.at_n[n - 1];
        for (r, with, all) in &c.recalls {
            line!(
                table,
                "{r:>7} {:>10} {:>9.2} {:>9.2} {:>9.2} {:>10.2} | {:>9.2} {:>9.2} {:>10.2}",
                with.evaluated,
                at(with, 1),
                at(with, n5),
                at(with, n25),
                with.at_one_percent,
                at(all, 1),
                at(all, n5),
                all.at_one_percent
            );
        }
        let lc = c.loop_closure.as_ref().expect("computed with the results");
        line!(
            table,
            "nearest database scan: {} %; loop closure within {} m: F1 max {:.1} %, recall at 100 % precision {:.1} %",
            c.nearest.recall_at_1.map_or("-".into(), |v| format!("{v:.2}")),
            a.revisit_radius,
            lc.f1_max,
            lc.recall_at_full_precision
        );
        line!(
            table,
            "search per query (mean / p95 ms): {} ({} threads, {:.2} s wall)",
            step_summary(&self.engine.method, &c.search_times, true),
            rayon::current_num_threads(),
            c.wall
        );
    }

    /// The bird's-eye trajectory of one condition: queries by top-1 success at the first
    /// threshold.
    fn plot(&self, a: &PlacesArgs, c: &Computed, several: bool) -> Result<Vec<PathBuf>> {
        let qpts: Vec<([f64; 2], bool)> =
            self.queries.iter().zip(&c.success_first).map(|(q, &ok)| (xy(q), ok)).collect();
        let dpts: Vec<[f64; 2]> = self.engine.scans.iter().map(xy).collect();
        let name = if several { format!("{}: ", self.name) } else { String::new() };
        let title = format!("{name}top-1 within {} m", a.thresholds.first().copied().unwrap_or(0.0));
        let stem = if several { format!("trajectory_{}", self.name) } else { "trajectory".into() };
        crate::plot::trajectory(&a.out.join(stem), &title, &dpts, &qpts)
    }

    /// One condition in the report's form, with its curves and summary row.
    fn reported(&self, a: &PlacesArgs, c: Computed, label: &str, plots: Vec<PathBuf>) -> Evaluated {
        let mut result = ConditionResult {
            condition: label.to_string(),
            queries: self.queries.len(),
            not_applicable: None,
            evaluated: None,
        };
        if let Some(why) = c.not_applicable {
            result.not_applicable = Some(why);
            return Evaluated { result, curves: Vec::new(), plots, loop_closure: None, summary: None };
        }
        let method = &self.engine.method;
        let mut timing = timing_of(method, &c.search_times, true);
        if !c.describe_times.is_empty() {
            for (step, t) in timing_of(method, &c.describe_times, false) {
                timing.entry(step).or_insert(t);
            }
        }
        let lc = c.loop_closure.expect("computed with the results");
        let r1 = c.recalls.iter().map(|(_, with, _)| (with.evaluated > 0).then(|| with.at_n[0])).collect();
        let curves = c.recalls.iter().map(|(r, with, _)| (format!("R = {r} m"), with.at_n.clone())).collect();
        let results = c
            .recalls
            .into_iter()
            .map(|(threshold_m, with_match, all_queries)| ThresholdResult {
                threshold_m,
                queries_with_match: with_match.evaluated,
                with_match,
                all_queries,
            })
            .collect();
        let columns = ["query", "top1", "distance", "metres", "nearest_metres"].map(String::from).to_vec();
        let summary = Some((r1, c.nearest.recall_at_1, lc.f1_max, lc.recall_at_full_precision));
        result.evaluated = Some(Box::new(EvaluatedCondition {
            described: c.described,
            not_described: c.not_described,
            results,
            nearest: c.nearest,
            loop_closure: LoopClosureResult { radius_m: a.revisit_radius, result: lc.clone() },
            top1: Top1 { columns, rows: c.top1 },
            timing_ms: timing,
        }));
        Evaluated { result, curves, plots, summary, loop_closure: Some(lc) }
    }
}

#[cfg(test)]
mod tests {
    use super::Chooser;

    #[test]
    fn globs() {
        let one = |p: &str, id: &str| Chooser::new("--db-scan", &[p.to_string()]).unwrap().chosen(id);
        assert!(one("*/000003", "05/000003"));
        assert!(one("00/00009?", "00/000095"));
        assert!(!one("*/000003", "05/000033"));
        assert!(one("*", ""));
        assert!(one("a*b*c", "axxbyyc"));
        assert!(!one("a*b*c", "axxbyy"));
        assert!(Chooser::new("--db-scan", &[]).unwrap().chosen("anything"));
        let e = Chooser::new("--query-scan", &["05/[0-9".into()]).err().unwrap().to_string();
        assert!(e.contains("--query-scan `05/[0-9`"), "{e}");
    }
}
