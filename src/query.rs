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
use crate::sinks::index::IndexedScan;
use crate::sources::{Input, Scan, ScanFailure, ScanStream, read_cloud_file};
use arrow::array::{ArrayRef, Float64Array, RecordBatch, StringArray, UInt32Array};
use rayon::prelude::*;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Arguments of `toporec query`.
#[derive(clap::Args, Clone, Debug)]
pub struct QueryArgs {
    /// The index to search.
    #[arg(long)]
    pub index: PathBuf,
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
            utime: 0,
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
    let rows: Vec<(&str, u32, &Hit)> = answers
        .iter()
        .flat_map(|(id, hits)| hits.iter().zip(1..).map(move |(h, rank)| (*id, rank, h)))
        .collect();
    let scans: Vec<&IndexedScan> = rows.iter().map(|r| &engine.scans[r.2.row]).collect();
    let pose = |i: usize| -> ArrayRef {
        Arc::new(Float64Array::from(scans.iter().map(|s| s.pose.map(|p| p[i])).collect::<Vec<_>>()))
    };
    let columns: Vec<ArrayRef> = vec![
        Arc::new(StringArray::from(rows.iter().map(|r| r.0).collect::<Vec<_>>())),
        Arc::new(UInt32Array::from(rows.iter().map(|r| r.1).collect::<Vec<_>>())),
        Arc::new(StringArray::from(scans.iter().map(|s| s.scan_id.as_str()).collect::<Vec<_>>())),
        Arc::new(StringArray::from(scans.iter().map(|s| s.session.as_str()).collect::<Vec<_>>())),
        Arc::new(Float64Array::from(rows.iter().map(|r| r.2.distance).collect::<Vec<_>>())),
        pose(0),
        pose(1),
        pose(2),
        Arc::new(Float64Array::from(rows.iter().map(|r| r.2.yaw_degrees).collect::<Vec<_>>())),
        Arc::new(Float64Array::from(rows.iter().map(|r| r.2.offset.map(|o| o[0])).collect::<Vec<_>>())),
        Arc::new(Float64Array::from(rows.iter().map(|r| r.2.offset.map(|o| o[1])).collect::<Vec<_>>())),
    ];
    RecordBatch::try_new(crate::sinks::schema::query_hits().plain_schema(), columns)
        .expect("the columns of the query table")
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
            let mut found = engine.find_many(&flat, args.k).into_iter();
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
