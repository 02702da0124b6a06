//! Loop closures: `toporec loops` over an index, and the online [`Detector`].
//!
//! The index's scans are walked in time order (by timestamp, then session and scan id; scans
//! without a timestamp last). Each scan is searched against the scans before it, leaving out
//! those of its own session within `exclude_seconds` (or `exclude_scans` positions) of it, by
//! the method's own search at its default budget over those allowed scans alone
//! (the method's [`crate::methods::Searcher`], restricted to them); the online [`Detector`] does the same one scan at a time, so both give
//! the same matches. The best allowed match is a loop when its descriptor distance is below the
//! threshold. Each row keeps the runner-up's distance (a margin for the user's own checks) and,
//! where both scans have poses, their true distance.
//!
//! Thresholds: given, read from a calibration file, calibrated on the index's own poses
//! ([`calibrate`]: the largest threshold whose accepted matches reach a target precision), or
//! the method's documented default ([`default_threshold`]).

pub mod detector;
pub mod icp;
pub mod verify;

pub use detector::{Detector, Match};

use crate::error::{Error, Result, ResultExt};
use crate::ranges;
use crate::search::Engine;
use crate::sinks::index::damage::Damage;
use crate::sinks::index::reader::IndexedScan;
use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};

/// What `toporec loops` is asked.
#[derive(clap::Args, Clone, Debug)]
pub struct LoopsArgs {
    /// Logs, sessions or folders to index and search, with no pipeline file (what `inspect`
    /// reads: ROS 1 bags, rosbag2 folders, MCAP files, NCLT sessions, KITTI sequences, folders of
    /// PCD/PLY files); loops are sought among their sessions, verified unless --no-verify.
    #[arg(value_name = "SOURCE", required_unless_present = "index")]
    pub sources: Vec<PathBuf>,
    /// The index (with sources: where they are indexed, default `out/<first source's name>`).
    #[arg(long)]
    pub index: Option<PathBuf>,
    /// Where the sources' scans take their poses and topic.
    #[command(flatten)]
    pub from: crate::oneshot::SourceOptions,
    /// The descriptor methods (repeatable; default: every method of the index; with sources,
    /// toporec-plus, with lateral views of 3 m).
    #[arg(long = "method")]
    pub methods: Vec<String>,
    /// Only these sessions' scans, as queries and as matches (repeatable; default: all; with
    /// sources, theirs).
    #[arg(long = "session")]
    pub sessions: Vec<String>,
    /// Same-session scans closer in time than this are not loops (seconds, ≥ 0).
    #[arg(long, default_value_t = 30.0, value_parser = ranges::non_negative)]
    pub exclude_seconds: f64,
    /// Same-session scans this many positions apart or fewer are not loops (instead of
    /// --exclude-seconds).
    #[arg(long, conflicts_with = "exclude_seconds")]
    pub exclude_scans: Option<usize>,
    /// Matches with a descriptor distance below this are loops (a distance in the method's own
    /// units, > 0; default: the method's calibrated one, 0.3534 for toporec-plus with sources).
    #[arg(long, value_parser = ranges::positive)]
    pub threshold: Option<f64>,
    /// The thresholds of a calibration file (`--calibrate` writes it).
    #[arg(long, conflicts_with = "threshold")]
    pub threshold_from: Option<PathBuf>,
    /// Pick each method's threshold on the index's poses: the largest reaching
    /// --target-precision; written to `<output stem>.calibration.json`.
    #[arg(long, conflicts_with_all = ["threshold", "threshold_from"])]
    pub calibrate: bool,
    /// The precision a calibrated threshold reaches, (0, 1].
    #[arg(long, default_value_t = 0.99, value_parser = ranges::fraction)]
    pub target_precision: f64,
    /// A match is true when its scans' poses are this close (m, > 0).
    #[arg(long, default_value_t = 5.0, value_parser = ranges::positive)]
    pub revisit_radius: f64,
    /// A match farther than the revisit radius but within this (m) is neither true nor false:
    /// left out of the scores (LoGG3D-Net's 3 m / 20 m band). Default: false beyond the radius.
    #[arg(long, value_parser = ranges::positive)]
    pub false_beyond: Option<f64>,
    /// Check each match below the threshold by aligning the two raw scans (point-to-plane ICP,
    /// read again from the index's source files); keep those that pass the limits.
    #[arg(long, conflicts_with = "no_verify")]
    pub verify: bool,
    /// With sources: do not verify (they are verified by default).
    #[arg(long)]
    pub no_verify: bool,
    /// What a kept alignment must reach.
    #[command(flatten)]
    pub limits: verify::Limits,
    /// Write each method's verified loops as g2o `EDGE_SE3:QUAT` lines, to `<stem>.<method>.g2o`
    /// beside this path (with verification).
    #[arg(long)]
    pub g2o: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
    /// Worker threads, [1, ∞) (default: all cores).
    #[arg(long, short, value_parser = ranges::count)]
    pub threads: Option<usize>,
    /// Write every scan's best match, accepted or not (an `accepted` column says which).
    #[arg(long)]
    pub all: bool,
    /// Answer from the intact parts when some part of the index fails its checksum: every
    /// damaged part and the scans it held are named, and the command exits 1.
    #[arg(long)]
    pub skip_damaged: bool,
    /// Output: `.parquet` (zstd) or `.csv`.
    #[arg(long, short, default_value = "loops.parquet")]
    pub out: PathBuf,
}

/// One scan's best allowed match.
#[derive(Clone, Debug, PartialEq)]
pub struct LoopRow {
    /// The method.
    pub method: String,
    /// The scan.
    pub query_scan: String,
    /// Its session.
    pub query_session: String,
    /// The earlier scan it matches.
    pub matched_scan: String,
    /// Its session.
    pub matched_session: String,
    /// Descriptor distance.
    pub distance: f64,
    /// The yaw of the query relative to the match (degrees), for methods that give one.
    pub yaw_degrees: Option<f64>,
    /// The query's estimated position in the match's sensor frame (x forward, y left, m), for
    /// methods that give one.
    pub offset: Option<[f64; 2]>,
    /// The runner-up's distance: the second allowed match's, or the match's own where the
    /// method ranked the runner-up below it although it lies nearer in descriptor distance
    /// (toporec-plus orders its few best by their pose too). Never below `distance`, so
    /// `rank2_distance − distance` is a margin ≥ 0: how clearly the match won.
    pub rank2_distance: Option<f64>,
    /// The distance between the two scans' poses (m), when both have one.
    pub true_distance_m: Option<f64>,
    /// Whether the distance is below the threshold (and, with `--verify`, the scans align).
    pub accepted: bool,
    /// The query's position in the walking order (its g2o vertex).
    pub query_vertex: usize,
    /// The matched scan's.
    pub matched_vertex: usize,
    /// The geometric check (`--verify`), of the rows below the threshold.
    pub check: Option<verify::Check>,
}

/// Which earlier scans a scan may be matched with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Exclusion {
    /// Same-session scans closer in time than this (seconds) are left out.
    Seconds(f64),
    /// Same-session scans this many positions apart or fewer are left out.
    Scans(usize),
}

/// The scans' walking order: by timestamp (none last), then session and scan id.
pub(crate) fn time_order(scans: &[IndexedScan]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..scans.len()).collect();
    order.sort_by(|&a, &b| {
        let (x, y) = (&scans[a], &scans[b]);
        (x.utime.is_none(), x.utime, &x.session, &x.scan_id).cmp(&(
            y.utime.is_none(),
            y.utime,
            &y.session,
            &y.scan_id,
        ))
    });
    order
}

/// The best two allowed matches of every scan with an earlier allowed scan, in time order:
/// `(query row, [(row, distance, yaw)], …)`.
type Matches = Vec<(usize, Vec<crate::methods::Hit>)>;

/// Which scans each scan may be matched with: earlier in `time_order`, and outside its own
/// session's exclusion window.
pub struct Allowed<'a> {
    scans: &'a [IndexedScan],
    exclusion: Exclusion,
    /// The scans in time order.
    pub order: Vec<usize>,
    position: Vec<usize>,
    in_session: Vec<usize>,
}

impl<'a> Allowed<'a> {
    /// The rule over `scans`.
    pub fn new(scans: &'a [IndexedScan], exclusion: Exclusion) -> Self {
        let order = time_order(scans);
        let mut position = vec![0usize; scans.len()];
        for (p, &row) in order.iter().enumerate() {
            position[row] = p;
        }
        // Position within the session's own time order, for `Exclusion::Scans`.
        let mut in_session = vec![0usize; scans.len()];
        let mut seen: HashMap<&str, usize> = HashMap::new();
        for &row in &order {
            let n = seen.entry(scans[row].session.as_str()).or_insert(0);
            in_session[row] = *n;
            *n += 1;
        }
        Allowed { scans, exclusion, order, position, in_session }
    }

    /// The position of `row` in the time order.
    pub fn position(&self, row: usize) -> usize {
        self.position[row]
    }

    /// Whether `row` may be matched with `query`.
    pub fn allows(&self, query: usize, row: usize) -> bool {
        let scans = self.scans;
        if self.position[row] >= self.position[query] {
            return false;
        }
        // Sessions compared by name: 0 for the query's, 1 for another.
        let session = |r: usize| u32::from(scans[r].session != scans[query].session);
        detector::allowed_by(
            self.exclusion,
            (0, self.in_session[query], scans[query].utime),
            (session(row), self.in_session[row], scans[row].utime),
        )
    }

    /// Which scans have an allowed scan within `radius` metres (both with poses): the scans a
    /// true loop could be found for.
    pub fn with_revisit(&self, radius: f64) -> Vec<bool> {
        let cell = |p: [f64; 3]| p.map(|c| (c / radius).floor() as i64);
        let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
        for (row, s) in self.scans.iter().enumerate() {
            if let Some(p) = s.pose {
                grid.entry(cell(p)).or_default().push(row);
            }
        }
        let near = |query: usize, q: [f64; 3], c: [i64; 3]| {
            grid.get(&c).is_some_and(|rows| {
                rows.iter().any(|&r| {
                    self.allows(query, r) && self.scans[r].pose.is_some_and(|p| distance3(p, q) <= radius)
                })
            })
        };
        (0..self.scans.len())
            .map(|query| {
                let Some(q) = self.scans[query].pose else { return false };
                let c = cell(q);
                (0..27).any(|k| near(query, q, [c[0] + k % 3 - 1, c[1] + k / 3 % 3 - 1, c[2] + k / 9 - 1]))
            })
            .collect()
    }
}

/// Every scan's best allowed earlier matches (up to two), in time order, counting the scans
/// searched on `bar`; `queries[i]` is the descriptor of `engine.scans[i]`, and `rule` is over
/// `engine.scans`. The scans are searched in one structure holding them in time order, each
/// query restricted to its allowed rows: the matches a [`Detector`] given the scans in that
/// order finds.
fn best_matches_counted(
    engine: &Engine,
    queries: &[Vec<f32>],
    rule: &Allowed,
    bar: Option<&indicatif::ProgressBar>,
) -> Matches {
    use rayon::prelude::*;
    let order = &rule.order;
    let mut growing = engine.method.searcher(Vec::new(), queries.first().map_or(0, |d| d.len()));
    for &row in order {
        growing.push(&queries[row]);
    }
    order
        .par_iter()
        .enumerate()
        .filter_map(|(at, &query)| {
            if let Some(b) = bar {
                b.inc(1);
            }
            let allowed = |position: usize| position < at && rule.allows(query, order[position]);
            let (best, _) = growing.search(&queries[query], 2, Some(&allowed));
            (!best.is_empty()).then(|| {
                (query, best.into_iter().map(|h| crate::methods::Hit { row: order[h.row], ..h }).collect())
            })
        })
        .collect()
}

/// The rows of one method: each scan's best allowed match, not yet accepted (the threshold
/// decides that), the scans' vertices their positions in `rule`'s time order.
pub fn rows(engine: &Engine, matches: &Matches, rule: &Allowed) -> Vec<LoopRow> {
    let scans = &engine.scans;
    matches
        .iter()
        .filter_map(|(query, best)| {
            let crate::methods::Hit { row, distance, yaw_degrees: yaw, offset } = *best.first()?;
            let (q, m) = (&scans[*query], &scans[row]);
            Some(LoopRow {
                method: engine.method.name.clone(),
                query_scan: q.scan_id.clone(),
                query_session: q.session.clone(),
                matched_scan: m.scan_id.clone(),
                matched_session: m.session.clone(),
                distance,
                yaw_degrees: yaw,
                offset,
                // Never below the match's own: a method that ranks by more than the distance
                // (toporec-plus's pose) may put a candidate nearer in distance second.
                rank2_distance: best.get(1).map(|b| b.distance.max(distance)),
                true_distance_m: match (q.pose, m.pose) {
                    (Some(a), Some(b)) => Some(distance3(a, b)),
                    _ => None,
                },
                accepted: false,
                query_vertex: rule.position(*query),
                matched_vertex: rule.position(row),
                check: None,
            })
        })
        .collect()
}

pub(crate) fn distance3(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// A calibrated threshold.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Calibration {
    /// The method.
    pub method: String,
    /// What made its descriptors (codebook or method id): a threshold holds for those only.
    pub id: String,
    /// Matches below it are loops.
    pub threshold: f64,
    /// The precision asked for.
    pub target_precision: f64,
    /// The precision reached on the calibration drive.
    pub precision: f64,
    /// Accepted matches on the calibration drive.
    pub accepted: usize,
    /// Matches with poses on the calibration drive.
    pub matches: usize,
    /// A match was true within this distance (m).
    pub revisit_radius_m: f64,
}

/// The largest threshold whose accepted matches reach `target` precision, from `(distance,
/// true)` pairs: the matches sorted by distance, the longest prefix with that precision, and
/// the threshold halfway between its last distance and the next one (just above it when it is
/// the last); `None` when no prefix reaches it.
pub fn calibrate(matches: &[(f64, bool)], target: f64) -> Option<f64> {
    let mut sorted: Vec<(f64, bool)> = matches.to_vec();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut best = None;
    let mut true_so_far = 0usize;
    for (i, &(d, t)) in sorted.iter().enumerate() {
        true_so_far += usize::from(t);
        // A prefix must end between distinct distances: a threshold cannot split a tie.
        let next = sorted.get(i + 1).map(|n| n.0);
        if next == Some(d) {
            continue;
        }
        if true_so_far as f64 >= target * (i + 1) as f64 {
            best = Some(match next {
                Some(n) => d + (n - d) / 2.0,
                None => d + d.abs().max(f64::MIN_POSITIVE) * 1e-9,
            });
        }
    }
    best
}

/// What a run found for one method.
#[derive(Clone, Debug, Default)]
pub struct MethodSummary {
    /// The method.
    pub method: String,
    /// Its threshold.
    pub threshold: f64,
    /// Scans with an allowed earlier scan (a best match).
    pub matched: usize,
    /// Matches below the threshold.
    pub accepted: usize,
    /// Accepted matches whose scans both have poses.
    pub accepted_with_poses: usize,
    /// Those within the revisit radius.
    pub true_positives: usize,
    /// Scans with an allowed earlier scan within the revisit radius.
    pub revisits: usize,
    /// Those whose accepted match is within the radius.
    pub revisits_found: usize,
    /// The threshold swept over every match with poses (the loop-closure protocol of the
    /// KITTI evaluations): F1 max, recall at 100 % precision; `None` without poses.
    pub curve: Option<crate::eval::metrics::LoopClosure>,
    /// The area under that precision–recall curve (0–1).
    pub auc: Option<f64>,
    /// With `--verify`: the matches below the threshold that were checked (`accepted` are those
    /// kept).
    pub verified: Option<usize>,
    /// Scans searched.
    pub scans: usize,
    /// Of those, scans without a time (kept apart from their neighbours by position).
    pub untimed: usize,
}

impl MethodSummary {
    /// What the exclusion did, when the user should know: scans without a time kept apart by
    /// position, and no scan left with a candidate (with why).
    pub fn exclusion_notes(&self, exclusion: Exclusion) -> Vec<String> {
        let mut out = Vec::new();
        if let (Exclusion::Seconds(s), true) = (exclusion, self.untimed > 0) {
            out.push(format!(
                "{} of {} scans have no time: a scan's neighbours within {} positions are left out (the {s} s \
                 exclusion at {} Hz; --exclude-scans N sets it)",
                self.untimed,
                self.scans,
                detector::untimed_window(s),
                detector::UNTIMED_RATE_HZ
            ));
        }
        if self.matched == 0 && self.scans > 1 {
            let window = match exclusion {
                Exclusion::Scans(n) => format!("--exclude-scans {n}"),
                Exclusion::Seconds(s) if self.untimed > 0 => {
                    format!("--exclude-seconds {s}, {} positions without times", detector::untimed_window(s))
                }
                Exclusion::Seconds(s) => format!("--exclude-seconds {s}"),
            };
            out.push(format!(
                "no loop could be sought: each of the {} scans has every earlier scan of its session within the \
                 exclusion ({window}); lower it, or add another session",
                self.scans
            ));
        }
        out
    }
}

/// What a run found, per method.
#[derive(Clone, Debug, Default)]
pub struct Summary {
    /// Per method.
    pub methods: Vec<MethodSummary>,
    /// The calibration files written.
    pub calibrations: Vec<PathBuf>,
    /// The g2o files written, one per method.
    pub g2o: Vec<PathBuf>,
    /// Every match below its method's threshold, accepted or rejected by its check.
    pub checked: Vec<LoopRow>,
    /// Damaged parts left out (`skip_damaged`), each with the scans it held.
    pub damaged: Vec<crate::sinks::index::damage::DamagedPart>,
    /// What the exclusion did, where the user should know (see
    /// [`MethodSummary::exclusion_notes`]), once per distinct note.
    pub notes: Vec<String>,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for m in &self.methods {
            match m.verified {
                None => write!(
                    f,
                    "loops ({}): {} scans matched an earlier one, {} below {:.6}",
                    m.method, m.matched, m.accepted, m.threshold
                )?,
                Some(checked) => write!(
                    f,
                    "loops ({}): {} scans matched an earlier one, {checked} below {:.6}, {} of them verified by ICP",
                    m.method, m.matched, m.threshold, m.accepted
                )?,
            }
            if m.accepted_with_poses > 0 {
                let precision = 100.0 * m.true_positives as f64 / m.accepted_with_poses as f64;
                write!(
                    f,
                    "; {} of {} with poses true: precision {precision:.1} %",
                    m.true_positives, m.accepted_with_poses
                )?;
            }
            if m.revisits > 0 {
                let recall = 100.0 * m.revisits_found as f64 / m.revisits as f64;
                write!(f, "; {} of {} revisits found: recall {recall:.1} %", m.revisits_found, m.revisits)?;
            }
            if let (Some(c), Some(auc)) = (&m.curve, m.auc) {
                write!(
                    f,
                    "; every threshold: F1 max {:.1} %{}, recall at 100 % precision {:.1} %, EP {:.1} %, AUC {auc:.3}",
                    c.f1_max,
                    c.f1_max_threshold.map_or_else(String::new, |t| format!(" (at {t:.6})")),
                    c.recall_at_full_precision,
                    crate::eval::metrics::extended_precision(c)
                )?;
            }
            writeln!(f)?;
        }
        for n in &self.notes {
            writeln!(f, "note: {n}")?;
        }
        for c in &self.calibrations {
            writeln!(f, "calibration written: {}", c.display())?;
        }
        for g in &self.g2o {
            writeln!(f, "g2o edges written: {}", g.display())?;
        }
        Ok(())
    }
}

/// A progress bar over `len` items on a terminal (when `enabled`), else none.
pub(crate) fn progress_bar(enabled: bool, len: usize, what: &str) -> Option<indicatif::ProgressBar> {
    use std::io::IsTerminal;
    (enabled && std::io::stderr().is_terminal()).then(|| {
        let b = indicatif::ProgressBar::new(len as u64);
        let template =
            format!("{{elapsed_precise}} [{{bar:30}}] {{pos}}/{{len}} {what} ({{per_sec}}, ETA {{eta}})");
        b.set_style(indicatif::ProgressStyle::with_template(&template).expect("template"));
        b
    })
}

/// The default threshold of a method at its default settings: the threshold calibrated to
/// precision 0.99 (revisits within 5 m, 30 s excluded) on the simulated HDL-64E drive of
/// docs/loops.md. `None` for the other methods and settings (their distances differ).
pub fn default_threshold(method: &crate::methods::Method) -> Option<f64> {
    method.as_computed().and_then(|c| c.default_threshold())
}

/// The threshold of one method: given, from a calibration file (which must be the method's and
/// of its descriptors), calibrated (`None` until then), or the method's default.
fn given_threshold(a: &LoopsArgs, method: &str, engine: &Engine) -> Result<Option<f64>> {
    let id = &engine.id;
    if let Some(t) = a.threshold {
        return Ok(Some(t));
    }
    let Some(path) = &a.threshold_from else {
        if a.calibrate {
            return Ok(None);
        }
        return default_threshold(&engine.method).map(Some).ok_or_else(|| {
            Error::invalid(format!(
                "`{method}` has no default threshold at its settings: give --threshold D, --threshold-from FILE, \
                 or --calibrate on a drive with poses"
            ))
        });
    };
    let text = std::fs::read_to_string(path).at(path)?;
    let all: Vec<Calibration> = serde_json::from_str(&text)
        .map_err(|e| Error::invalid(format!("{}: not a toporec loops calibration: {e}", path.display())))?;
    let Some(c) = all.iter().find(|c| c.method == method) else {
        return Err(Error::invalid(format!("{}: no threshold for method `{method}`", path.display())));
    };
    if c.id != *id {
        return Err(Error::invalid(format!(
            "{}: the threshold of `{method}` was calibrated on descriptors {}, the index holds {id}",
            path.display(),
            c.id
        )));
    }
    Ok(Some(c.threshold))
}

/// Where `--g2o PATH` writes `method`'s edges: `<stem>.<method>.g2o` beside `PATH`, one file
/// per method whatever their number, so a script's path does not depend on `--method`.
pub fn g2o_path(path: &Path, method: &str) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "loops".into());
    path.with_file_name(format!("{stem}.{method}.g2o"))
}

impl LoopsArgs {
    /// Whether the matches below the threshold are verified: with sources unless
    /// `--no-verify`, on an index with `--verify`.
    pub fn verifies(&self) -> bool {
        if self.sources.is_empty() { self.verify } else { !self.no_verify }
    }
}

/// Runs `toporec loops`: the rows of every method, written to `a.out`; with `calibrate`, the
/// thresholds written beside it (`<out stem>.calibration.json`).
pub fn run(a: &LoopsArgs) -> Result<Summary> {
    if !(a.target_precision > 0.0 && a.target_precision <= 1.0) {
        return Err(Error::invalid(format!("--target-precision {}: must be in (0, 1]", a.target_precision)));
    }
    if let Some(band) = a.false_beyond.filter(|&b| b <= a.revisit_radius || b.is_nan()) {
        return Err(Error::invalid(format!(
            "--false-beyond {band}: must be beyond --revisit-radius {}",
            a.revisit_radius
        )));
    }
    if a.threshold.is_some() as u8 + a.threshold_from.is_some() as u8 + a.calibrate as u8 > 1 {
        return Err(Error::invalid("--threshold, --threshold-from and --calibrate: give one".to_string()));
    }
    let Some(index) = a.index.as_deref() else {
        return Err(Error::invalid("loops: give --index DIR, or sources to index"));
    };
    let methods: Vec<String> = if a.methods.is_empty() {
        crate::search::index_methods(index)?.into_iter().map(|m| m.name).collect()
    } else {
        a.methods.clone()
    };
    let verifying = a.verifies();
    if a.g2o.is_some() && !verifying {
        return Err(Error::invalid(
            "--g2o: needs the loops verified (the relative pose comes from the alignment)".to_string(),
        ));
    }
    let in_sessions = |s: &IndexedScan| a.sessions.is_empty() || a.sessions.contains(&s.session);
    let exclusion = match a.exclude_scans {
        Some(n) => Exclusion::Scans(n),
        None => Exclusion::Seconds(a.exclude_seconds),
    };
    let mut summary = Summary::default();
    let mut all_rows = Vec::new();
    let mut calibrations = Vec::new();
    let damage = Damage::skipping(a.skip_damaged);
    for method in &methods {
        let engine = Engine::open_with(index, &[], method, &damage)?.retain(&in_sessions)?;
        if engine.scans.is_empty() {
            return Err(Error::index(index, format!("no {method} descriptors in sessions {:?}", a.sessions)));
        }
        let queries = query_descriptors(index, &engine, &damage)?;
        let rule = Allowed::new(&engine.scans, exclusion);
        let bar = progress_bar(!a.no_progress, engine.scans.len(), &format!("scans searched ({method})"));
        let matches = best_matches_counted(&engine, &queries, &rule, bar.as_ref());
        if let Some(b) = bar {
            b.finish_and_clear();
        }
        let mut rows = rows(&engine, &matches, &rule);
        let threshold = match given_threshold(a, method, &engine)? {
            Some(t) => t,
            None => {
                let judged: Vec<(f64, bool)> = rows
                    .iter()
                    .filter_map(|r| r.true_distance_m.map(|t| (r.distance, t <= a.revisit_radius)))
                    .collect();
                // No threshold reaching the precision: 0, which accepts nothing.
                let t = calibrate(&judged, a.target_precision).unwrap_or_else(|| {
                    tracing::warn!(
                        "--calibrate: no threshold of `{method}` reaches precision {} on this index ({} matches \
                         with poses); its threshold is 0: no loop accepted",
                        a.target_precision,
                        judged.len()
                    );
                    0.0
                });
                let accepted: Vec<&(f64, bool)> = judged.iter().filter(|j| j.0 < t).collect();
                // (Vacuously 1 when nothing is accepted.)
                let precision = accepted.iter().filter(|j| j.1).count() as f64 / accepted.len().max(1) as f64
                    + f64::from(u8::from(accepted.is_empty()));
                calibrations.push(Calibration {
                    method: method.clone(),
                    id: engine.id.clone(),
                    threshold: t,
                    target_precision: a.target_precision,
                    precision,
                    accepted: accepted.len(),
                    matches: judged.len(),
                    revisit_radius_m: a.revisit_radius,
                });
                t
            }
        };
        for r in &mut rows {
            r.accepted = r.distance < threshold;
        }
        let below_threshold = rows.iter().filter(|r| r.accepted).count();
        if verifying {
            let checks = verify::check(index, &rows, a.limits, !a.no_progress, &damage)?;
            for (r, c) in rows.iter_mut().zip(checks) {
                r.check = c;
                r.accepted &= c.is_some_and(|c| c.passed);
            }
        }
        let is_true = |r: &LoopRow| r.true_distance_m.is_some_and(|d| d <= a.revisit_radius);
        // Between the radius and `--false-beyond`: neither true nor false.
        let in_band = |t: f64| t > a.revisit_radius && a.false_beyond.is_some_and(|band| t <= band);
        let with_revisit = rule.with_revisit(a.revisit_radius);
        // Whether a row's query has an allowed revisit (one row per query).
        let has_revisit = |r: &LoopRow| with_revisit[rule.order[r.query_vertex]];
        let (curve, auc) = protocol_scores(&rows, &has_revisit, a.revisit_radius, a.false_beyond);
        summary.methods.push(MethodSummary {
            method: method.clone(),
            threshold,
            matched: rows.len(),
            accepted: rows.iter().filter(|r| r.accepted).count(),
            accepted_with_poses: rows
                .iter()
                .filter(|r| r.accepted && r.true_distance_m.is_some_and(|t| !in_band(t)))
                .count(),
            true_positives: rows.iter().filter(|r| r.accepted && is_true(r)).count(),
            revisits: with_revisit.iter().filter(|&&w| w).count(),
            revisits_found: rows.iter().filter(|r| r.accepted && is_true(r) && has_revisit(r)).count(),
            curve,
            auc,
            verified: verifying.then_some(below_threshold),
            scans: engine.scans.len(),
            untimed: engine.scans.iter().filter(|s| s.utime.is_none()).count(),
        });
        let notes = summary.methods.last().expect("pushed").exclusion_notes(exclusion);
        for n in notes {
            if !summary.notes.contains(&n) {
                summary.notes.push(n);
            }
        }
        if let Some(path) = &a.g2o {
            let path = g2o_path(path, method);
            verify::write_g2o(&path, &rows)?;
            summary.g2o.push(path);
        }
        summary.checked.extend(rows.iter().filter(|r| r.accepted || r.check.is_some()).cloned());
        all_rows.extend(rows.into_iter().filter(|r| a.all || r.accepted));
    }
    write_rows(&a.out, &all_rows)?;
    if a.calibrate {
        let path = calibration_path(&a.out);
        let text = serde_json::to_string_pretty(&calibrations).expect("plain data") + "\n";
        crate::fsutil::write_atomic(&path, text.as_bytes())?;
        summary.calibrations.push(path);
    }
    summary.damaged = crate::sinks::index::holdings::held_scans(damage.found())?;
    Ok(summary)
}

/// The loop-closure protocol's scores of one method's rows: every match whose scans both have
/// poses, true within `radius`, false beyond it (beyond `false_beyond` when given; matches in
/// between are left out), a scan with an allowed revisit and a rejected match a false negative;
/// the threshold swept over every distance ([`crate::eval::metrics::loop_closure`]) and the
/// area under the curve ([`crate::eval::metrics::pr_auc`]).
fn protocol_scores(
    rows: &[LoopRow],
    has_revisit: &dyn Fn(&LoopRow) -> bool,
    radius: f64,
    false_beyond: Option<f64>,
) -> (Option<crate::eval::metrics::LoopClosure>, Option<f64>) {
    let (mut distance, mut within, mut revisit) = (Vec::new(), Vec::new(), Vec::new());
    for r in rows {
        let Some(t) = r.true_distance_m else { continue };
        if t > radius && false_beyond.is_some_and(|band| t <= band) {
            continue;
        }
        distance.push(r.distance);
        within.push(t <= radius);
        revisit.push(has_revisit(r));
    }
    if distance.is_empty() {
        return (None, None);
    }
    let curve = crate::eval::metrics::loop_closure(&distance, &within, &revisit);
    let auc = crate::eval::metrics::pr_auc(&curve.curve);
    (Some(curve), Some(auc))
}

/// The descriptor of each of `engine`'s scans: its own, or read from the index when the
/// engine searches a cached structure that keeps none (toporec-plus).
fn query_descriptors(index: &Path, engine: &Engine, damage: &Damage) -> Result<Vec<Vec<f32>>> {
    if engine.scans.iter().all(|s| !s.descriptor.is_empty()) {
        return Ok(engine.scans.iter().map(|s| s.descriptor.clone()).collect());
    }
    let loaded = crate::search::load_method(index, &engine.method.name, &[], damage)?;
    let mut by_id: HashMap<String, Vec<f32>> =
        loaded.scans.into_iter().map(|s| (s.scan_id, s.descriptor)).collect();
    engine
        .scans
        .iter()
        .map(|s| {
            by_id.remove(&s.scan_id).ok_or_else(|| {
                Error::index(index, format!("scan {} has no {} descriptor", s.scan_id, engine.method.name))
            })
        })
        .collect()
}

/// Where `--calibrate` writes its thresholds: beside the output, `<stem>.calibration.json`.
pub(crate) fn calibration_path(out: &Path) -> PathBuf {
    let stem = out.file_stem().map_or_else(|| "loops".into(), |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}.calibration.json"))
}

/// The rows as a record batch of the `loops` table ([`crate::sinks::schema::loops`]).
pub(crate) fn rows_batch(rows: &[LoopRow]) -> arrow::record_batch::RecordBatch {
    let mut b = crate::sinks::rows::RowBuilder::plain(&crate::sinks::schema::loops());
    let [method, query, query_session, matched, matched_session] =
        ["method", "query_scan", "query_session", "matched_scan", "matched_session"].map(|n| b.col(n));
    let [distance, yaw, x_m, y_m, rank2, truth, accepted] =
        ["distance", "yaw_degrees", "x_m", "y_m", "rank2_distance", "true_distance_m", "accepted"]
            .map(|n| b.col(n));
    let [query_vertex, matched_vertex, verified, fitness, rmse] =
        ["query_vertex", "matched_vertex", "verified", "icp_fitness", "icp_rmse"].map(|n| b.col(n));
    let relative =
        ["rel_x", "rel_y", "rel_z", "rel_roll_deg", "rel_pitch_deg", "rel_yaw_deg"].map(|n| b.col(n));
    let finite = |v: f64| v.is_finite().then_some(v);
    for r in rows {
        b.text(method, Some(&r.method))
            .text(query, Some(&r.query_scan))
            .text(query_session, Some(&r.query_session))
            .text(matched, Some(&r.matched_scan))
            .text(matched_session, Some(&r.matched_session))
            .float(distance, Some(r.distance))
            .float(yaw, r.yaw_degrees)
            .float(x_m, r.offset.map(|o| o[0]))
            .float(y_m, r.offset.map(|o| o[1]))
            .float(rank2, r.rank2_distance)
            .float(truth, r.true_distance_m)
            .boolean(accepted, Some(r.accepted))
            .uint(query_vertex, Some(r.query_vertex as u64))
            .uint(matched_vertex, Some(r.matched_vertex as u64))
            .boolean(verified, r.check.map(|c| c.passed))
            .float(fitness, r.check.map(|c| c.fitness))
            .float(rmse, r.check.and_then(|c| finite(c.rmse)));
        for (k, col) in relative.into_iter().enumerate() {
            b.float(col, r.check.and_then(|c| finite(c.relative[k])));
        }
        b.end_row();
    }
    b.finish().expect("the columns of the loops table")
}

/// Writes the rows to `path`: CSV when it ends in `.csv`, else Parquet (zstd), atomically.
pub(crate) fn write_rows(path: &Path, rows: &[LoopRow]) -> Result<()> {
    let batch = rows_batch(rows);
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")) {
        let mut file = crate::fsutil::AtomicFile::create(path)?;
        let header = crate::sinks::csv::header(&crate::sinks::schema::loops());
        file.write_all(format!("{header}\n{}", crate::sinks::csv::rows(&batch)).as_bytes()).at(path)?;
        file.commit()?;
        return Ok(());
    }
    let mut file = crate::sinks::parquet::TableFile::with_schema(path, batch.schema())?;
    file.write_batch(&batch)?;
    let (staged, _) = file.finish()?;
    staged.publish()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calibration_by_hand() {
        // Sorted: 0.1 T, 0.2 T, 0.3 F, 0.4 T, 0.5 F. Prefix precisions: 1, 1, 2/3, 3/4, 3/5.
        let m = [(0.4, true), (0.1, true), (0.5, false), (0.3, false), (0.2, true)];
        // 0.75: the longest prefix is the first four; halfway between 0.4 and 0.5.
        assert_eq!(calibrate(&m, 0.75), Some(0.45));
        // 0.99: the first two; halfway between 0.2 and 0.3.
        assert_eq!(calibrate(&m, 0.99), Some(0.25));
        // 0.6: every match; just above the last.
        assert!(calibrate(&m, 0.6).is_some_and(|t| t > 0.5 && t < 0.5 + 1e-6));
        // None reach it when the nearest match is false.
        assert_eq!(calibrate(&[(0.1, false), (0.2, true)], 0.9), None);
        // A tie is not split: 0.1 T and 0.1 F together have precision 1/2.
        assert_eq!(calibrate(&[(0.1, true), (0.1, false), (0.3, true)], 0.9), None);
    }
}
