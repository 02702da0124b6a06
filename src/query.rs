//! `toporec query`: the k nearest database descriptors of new scans, made with the index's own
//! preprocessing and codebook (or the method's parameters), read from the index, never
//! re-specified; many queries per call, in parallel, through the [`crate::search::Engine`].
//! Every descriptor method of an index can answer (`--method`); the methods that estimate the
//! query's yaw relative to a hit fill `yaw_deg`.

use crate::describe::DescribeError;
use crate::error::{Error, Result, ResultExt};
use crate::methods::{Hit, Method};
use crate::ranges;
use crate::search::{Engine, StepTimes, step_summary};
use crate::sinks::csv;
use crate::sinks::rows::RowBuilder;
use crate::sources::{Input, Scan, ScanFailure, ScanStream, read_cloud_file};
use arrow::array::RecordBatch;
use rayon::prelude::*;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Arguments of `toporec query`.
#[derive(clap::Args, Clone, Debug)]
pub struct QueryArgs {
    /// The index.
    #[command(flatten)]
    pub index: crate::flags::IndexFlag,
    /// Query inputs: cloud files (csv, bin, pcd, ply), MCAPs, ROS 1 bags, rosbag2 folders, NCLT
    /// sessions, KITTI sequences.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Neighbours per query: [1, ∞), clamped to the database size.
    #[arg(short, default_value_t = 25, value_parser = ranges::count)]
    pub k: usize,
    /// The descriptor method to search with (one the index holds; `toporec info` lists them).
    #[arg(long, default_value = crate::methods::TOPOREC)]
    pub method: String,
    /// Database sessions (default: all).
    #[arg(long = "session")]
    pub sessions: Vec<String>,
    /// The point-cloud topic of an MCAP or bag (default: its only one).
    #[arg(long)]
    pub topic: Option<String>,
    /// Answer from the intact parts when some part of the index fails its checksum: every
    /// damaged part and the scans it held are named, and the command exits 1.
    #[arg(long)]
    pub skip_damaged: bool,
    /// Output CSV (default stdout).
    #[arg(long, short)]
    pub out: Option<PathBuf>,
}

/// A scan stream for a path given on the command line: an MCAP, an NCLT session (or folder of
/// sessions, or `velodyne_hits.bin`), a KITTI sequence (or `sequences/`), or one cloud file.
pub fn open_path(path: &Path, topic: Option<&str>) -> Result<ScanStream> {
    if let Some(spec) = Input::detect(path)?.source(topic) {
        return Ok(spec.open()?);
    }
    let points = read_cloud_file(path, None);
    let id = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let item = match points {
        Ok((points, fingerprint)) => Ok(Scan {
            id: id.clone(),
            fingerprint,
            session: "query".into(),
            path: path.to_owned(),
            message_index: None,
            utime: None,
            raw_points: points.len(),
            points,
            intensity: None,
            ring: None,
            pose: None,
            no_pose: Some(crate::sources::NoPose::NoGroundTruth),
        }),
        Err(e) => Err(ScanFailure::of_file(id, "query", path, None, e.to_string())),
    };
    Ok(Box::new(std::iter::once(item)))
}

/// What a query run did.
#[derive(Clone, Debug, Default)]
pub struct QueryReport {
    /// The method.
    pub method: Option<Method>,
    /// Queries answered.
    pub answered: usize,
    /// Queries that failed (each printed on stderr).
    pub failed: usize,
    /// Database scans searched.
    pub database: usize,
    /// Per-query step times.
    pub times: Vec<StepTimes>,
}

impl std::fmt::Display for QueryReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let Some(method) = &self.method else { return write!(f, "no queries") };
        let steps = step_summary(method, &self.times, false);
        write!(
            f,
            "{} queries against {} scans ({}); per query (mean / p95 ms): {steps}",
            self.answered, self.database, method.name
        )
    }
}

/// The hits of answered queries (each query's id and its hits, best first) as a record batch
/// of the `query` table ([`crate::sinks::schema::query_hits`]): `query`'s CSV and the Python
/// package's Arrow table.
pub fn hits_batch(engine: &Engine, answers: &[(&str, &[Hit])]) -> RecordBatch {
    use crate::sinks::schema::columns as C;
    let mut b = RowBuilder::plain(&crate::sinks::schema::query_hits());
    let [query, rank, scan, session, distance] =
        ["query_id", "rank", C::SCAN_ID, C::SESSION, "distance"].map(|n| b.col(n));
    let [x, y, z, yaw, x_m, y_m] =
        [C::POSE_X, C::POSE_Y, C::POSE_Z, "yaw_deg", "x_m", "y_m"].map(|n| b.col(n));
    for (id, hits) in answers {
        for (h, r) in hits.iter().zip(1u64..) {
            let s = &engine.scans[h.row];
            b.text(query, Some(id))
                .uint(rank, Some(r))
                .text(scan, Some(&s.scan_id))
                .text(session, Some(&s.session))
                .float(distance, Some(h.distance))
                .float(x, s.pose.map(|p| p[0]))
                .float(y, s.pose.map(|p| p[1]))
                .float(z, s.pose.map(|p| p[2]))
                .float(yaw, h.yaw_degrees)
                .float(x_m, h.offset.map(|o| o[0]))
                .float(y_m, h.offset.map(|o| o[1]))
                .end_row();
        }
    }
    b.finish().expect("the columns of the query table")
}

/// A described query: its id, descriptor and step times.
type Answerable = (String, Vec<f32>, StepTimes);

/// Queries per parallel chunk: descriptors in parallel, then one batched search.
const CHUNK: usize = 64;

/// Runs the queries of `args` against `engine`, streaming CSV rows to `out`; each failed
/// query is reported on stderr and counted.
pub fn run(
    engine: &Engine,
    args: &QueryArgs,
    out: &mut dyn Write,
    output_name: &Path,
) -> Result<QueryReport> {
    let mut report = QueryReport {
        method: Some(engine.method.clone()),
        database: engine.scans.len(),
        ..Default::default()
    };
    if args.k > engine.scans.len() {
        tracing::warn!("-k {}: the database holds {} scans; returning that many", args.k, engine.scans.len());
    }
    if !engine.describer.topological && !engine.method.is_computed() {
        return Err(Error::invalid(format!(
            "method `{}` has its vectors imported: `query` cannot describe new scans with it (`eval` compares stored ones)",
            engine.method.name
        )));
    }
    writeln!(out, "{}", csv::header(&crate::sinks::schema::query_hits())).at(output_name)?;
    for input in &args.inputs {
        let mut stream = open_path(input, args.topic.as_deref())?.peekable();
        while stream.peek().is_some() {
            let scans: Vec<_> = stream.by_ref().take(CHUNK).collect();
            let described: Vec<Result<Answerable, String>> = scans
                .into_par_iter()
                .map(|item| {
                    let scan = item.map_err(|f| f.error)?;
                    let id = scan.id.clone();
                    match engine.describe_scan(scan) {
                        Ok((v, times)) => Ok((id, v, times)),
                        Err(DescribeError::Skipped(reason)) => Err(format!("{id}: skipped: {reason}")),
                        Err(e) => Err(e.to_string()),
                    }
                })
                .collect();
            let flat: Vec<f32> =
                described.iter().filter_map(|r| r.as_ref().ok()).flat_map(|r| r.1.iter().copied()).collect();
            let mut found = engine.find_many(&flat, args.k)?.into_iter();
            let mut answers: Vec<(&str, Vec<Hit>)> = Vec::new();
            for r in &described {
                let (id, _, t) = match r {
                    Ok(x) => x,
                    Err(e) => {
                        report.failed += 1;
                        eprintln!("error: {e}");
                        continue;
                    }
                };
                let (hits, search) = found.next().expect("one result per query");
                report.answered += 1;
                report.times.push(StepTimes { search: search.search, rerank: search.rerank, ..*t });
                answers.push((id, hits));
            }
            let answers: Vec<(&str, &[Hit])> = answers.iter().map(|(id, h)| (*id, h.as_slice())).collect();
            out.write_all(csv::rows(&hits_batch(engine, &answers)).as_bytes()).at(output_name)?;
        }
    }
    out.flush().at(output_name)?;
    Ok(report)
}
