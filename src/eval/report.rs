//! `report.json`, typed: what `eval places` (both protocols) and `eval perturbation` write, as
//! serde structs the evaluations fill. Its JSON Schema, [`schema`], is rendered into
//! `schemas/report.json` beside the Parquet schemas (a test keeps the two equal), so a script
//! reading reports has a contract.

use super::metrics::{LoopClosure, Recall};
use crate::sinks::index::damage::DamagedPart;
use schemars::JsonSchema;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// One method on one dataset: the mean over run pairs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, schemars::JsonSchema)]
pub struct DatasetRecall {
    /// The dataset.
    pub dataset: &'static str,
    /// Run pairs averaged over.
    pub pairs: usize,
    /// Run pairs without a query with a true match (left out, as they would divide by zero in
    /// the reference).
    pub pairs_without_queries: usize,
    /// Mean Recall@N, N = 1..=25, in %.
    pub recall_at_n: Vec<f64>,
    /// Mean Recall@1 %, in %.
    pub recall_at_one_percent: f64,
}

/// A `report.json`: one of the three protocols (its `protocol` field says which).
#[derive(Clone, Debug, Serialize, JsonSchema)]
#[serde(untagged)]
pub enum Report {
    /// `eval places`.
    Places(PlacesReport),
    /// `eval places --protocol pointnetvlad`.
    PointNetVlad(PointNetVladReport),
    /// `eval perturbation`.
    Perturbation(PerturbationReport),
}

/// Which evaluation made a report.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Protocol {
    /// Database against query scans, true matches within thresholds over poses.
    Places,
    /// The PointNetVLAD benchmark's test sets and metric.
    Pointnetvlad,
    /// The TopoRec paper's object protocol: perturbed index scans find themselves.
    Perturbation,
}

/// Mean and 95th percentile of a step's time per query, in milliseconds.
#[derive(Clone, Copy, Debug, Serialize, JsonSchema)]
pub struct StepTiming {
    /// Mean.
    pub mean: f64,
    /// 95th percentile.
    pub p95: f64,
}

/// Step → its time per query (the steps a method has: `persistence`, `describe`, `search`,
/// `candidates`, `rerank`, …).
pub(crate) type Timing = BTreeMap<String, StepTiming>;

/// `eval places`.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct PlacesReport {
    /// `places`.
    pub protocol: Protocol,
    /// The toporec that wrote it.
    pub toporec_version: String,
    /// The database side.
    pub database: DatabaseSide,
    /// The query side.
    pub queries: QuerySide,
    /// Poses compared inside a session only.
    pub within_session: bool,
    /// A query's own session's scans within this many seconds are not retrieved.
    pub min_time_gap_s: f64,
    /// The loop-closure radius (m).
    pub revisit_radius_m: f64,
    /// The conditions' seed.
    pub seed: u64,
    /// The search budget: `default`, `exhaustive` or `matched:N`.
    pub search: String,
    /// The conditions, labelled as in the tables.
    pub conditions: Vec<String>,
    /// Worker threads.
    pub threads: usize,
    /// One entry per method.
    pub methods: Vec<PlacesMethod>,
    /// The plot files written beside the report.
    pub plots: Vec<String>,
    /// Damaged parts left out (`--skip-damaged`), each with the scans it held.
    pub damaged: Vec<DamagedPart>,
}

/// The database of `eval places`.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct DatabaseSide {
    /// The index.
    pub index: PathBuf,
    /// Its sessions used (all when empty).
    pub sessions: Vec<String>,
    /// The scan-id globs of `--db-scan` (all when empty).
    pub scans: Vec<String>,
    /// `--map-every` (m).
    pub map_every_m: Option<f64>,
}

/// The queries of `eval places`.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct QuerySide {
    /// The index.
    pub index: PathBuf,
    /// Its sessions used (all when empty).
    pub sessions: Vec<String>,
    /// The scan-id globs of `--query-scan` (all when empty).
    pub scans: Vec<String>,
    /// `--query-every` (m).
    pub query_every_m: Option<f64>,
}

/// One method of `eval places`.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct PlacesMethod {
    /// The method.
    pub method: String,
    /// What made its descriptors: the codebook id, or the method's id.
    pub id: String,
    /// Descriptor length.
    pub descriptor_length: usize,
    /// Database scans with a pose.
    pub database_scans: usize,
    /// Database scans left out, without a pose.
    pub database_without_pose: usize,
    /// Query scans with a pose.
    pub query_scans: usize,
    /// Query scans left out, without a pose.
    pub queries_without_pose: usize,
    /// The k of Recall@1 %.
    pub one_percent_k: usize,
    /// The largest N of Recall@N.
    pub max_n: usize,
    /// The first condition's results per threshold (null when it did not apply).
    pub results: Option<Vec<ThresholdResult>>,
    /// The first condition's search times (null when it did not apply).
    pub timing_ms: Option<Timing>,
    /// Every condition, in the order asked.
    pub conditions: Vec<ConditionResult>,
}

/// One condition of one method. A condition that does not apply to the data has
/// `not_applicable` and no results.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct ConditionResult {
    /// The condition's label.
    pub condition: String,
    /// Query scans.
    pub queries: usize,
    /// Why it does not apply (the first query's reason).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub not_applicable: Option<String>,
    /// Its results, when it applies.
    #[serde(flatten)]
    pub evaluated: Option<Box<EvaluatedCondition>>,
}

/// The results of a condition that applied.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct EvaluatedCondition {
    /// Queries described under the condition.
    pub described: usize,
    /// Queries that could not be described under it.
    pub not_described: usize,
    /// Per threshold.
    pub results: Vec<ThresholdResult>,
    /// The nearest database scan as the top-1.
    pub nearest: Nearest,
    /// Loop closure: top-1 within the revisit radius, over the descriptor distance threshold.
    pub loop_closure: LoopClosureResult,
    /// Each query's top-1.
    pub top1: Top1,
    /// Search (and describing) times per query.
    pub timing_ms: Timing,
}

/// Recall within one threshold.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct ThresholdResult {
    /// The threshold (m).
    pub threshold_m: f64,
    /// Queries with at least one true match.
    pub queries_with_match: usize,
    /// Recall over the queries with a match (PointNetVLAD's denominator).
    pub with_match: Recall,
    /// Recall over every query (a query without a match is a failure).
    pub all_queries: Recall,
}

/// The nearest database scan as the top-1.
#[derive(Clone, Copy, Debug, Serialize, JsonSchema)]
pub struct Nearest {
    /// Queries with an eligible database scan.
    pub queries: usize,
    /// Share (%) whose top-1 is the nearest eligible scan; null without queries.
    pub recall_at_1: Option<f64>,
}

/// Loop closure at a revisit radius.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct LoopClosureResult {
    /// The revisit radius (m).
    pub radius_m: f64,
    /// F1 max, recall at 100 % precision, the precision-recall curve.
    pub result: LoopClosure,
}

/// Each query's top-1: `[query, top1, distance, metres, nearest_metres]` rows (`top1`,
/// `distance` and `metres` null when nothing was retrieved; metres null when infinite).
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct Top1 {
    /// The column names.
    pub columns: Vec<String>,
    /// One row per query.
    pub rows: Vec<Top1Row>,
}

/// `(query, top1, descriptor distance, metres to the top-1, metres to the nearest)`.
pub(crate) type Top1Row = (String, Option<String>, Option<f64>, Option<f64>, Option<f64>);

/// `eval perturbation`.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct PerturbationReport {
    /// `perturbation`.
    pub protocol: Protocol,
    /// The toporec that wrote it.
    pub toporec_version: String,
    /// The index.
    pub index: PathBuf,
    /// Perturbed query scans.
    pub queries: usize,
    /// `--fraction`.
    pub fraction: f64,
    /// `--seed`.
    pub seed: u64,
    /// The search budget.
    pub search: String,
    /// One entry per method.
    pub methods: Vec<PerturbationMethod>,
    /// The plot files written beside the report.
    pub plots: Vec<String>,
}

/// One method of `eval perturbation`.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct PerturbationMethod {
    /// The method.
    pub method: String,
    /// The codebook or method id.
    pub id: String,
    /// Descriptor length.
    pub descriptor_length: usize,
    /// Database scans.
    pub database_scans: usize,
    /// Query scans.
    pub queries: usize,
    /// The k of Recall@1 %.
    pub one_percent_k: usize,
    /// One entry per perturbation.
    pub results: Vec<PerturbationResult>,
    /// Describing and search times per query.
    pub timing_ms: Timing,
}

/// Recall under one perturbation.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct PerturbationResult {
    /// The perturbation.
    pub perturbation: String,
    /// Recall of the perturbed scans finding themselves.
    pub recall: Recall,
}

/// `eval places --protocol pointnetvlad`.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct PointNetVladReport {
    /// `pointnetvlad`.
    pub protocol: Protocol,
    /// The toporec that wrote it.
    pub toporec_version: String,
    /// The index of the benchmark's submaps.
    pub index: PathBuf,
    /// A true match lies within this many metres.
    pub match_radius_m: f64,
    /// Recall@N up to this N.
    pub neighbours: usize,
    /// The search budget.
    pub search: String,
    /// The test sets formed.
    pub datasets: Vec<DatasetRuns>,
    /// Why some sets could not be formed.
    pub notes: Vec<String>,
    /// One entry per method.
    pub methods: Vec<PointNetVladMethod>,
    /// The plot files written beside the report.
    pub plots: Vec<String>,
    /// Damaged parts left out (`--skip-damaged`), each with the scans it held.
    pub damaged: Vec<DamagedPart>,
}

/// A test set and its runs.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct DatasetRuns {
    /// `oxford`, `business`, `residential`, `university`.
    pub name: String,
    /// Its runs.
    pub runs: Vec<String>,
}

/// One method of the PointNetVLAD protocol.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct PointNetVladMethod {
    /// The method.
    pub method: String,
    /// The codebook or method id.
    pub id: String,
    /// Per test set.
    pub datasets: Vec<DatasetRecall>,
}

/// The JSON Schema of [`Report`], as `schemas/report.json` holds it.
pub fn schema() -> String {
    let schema = schemars::schema_for!(Report);
    serde_json::to_string_pretty(&schema).expect("JSON of a schema") + "\n"
}

/// Writes `report.json` (and `report.txt`, the text tables) into `out`.
pub fn write(out: &std::path::Path, report: &Report, table: &str) -> crate::error::Result<()> {
    let json = serde_json::to_string_pretty(report).expect("JSON of plain values") + "\n";
    crate::fsutil::write_atomic(&out.join("report.json"), json.as_bytes())?;
    crate::fsutil::write_atomic(&out.join("report.txt"), table.as_bytes())
}
