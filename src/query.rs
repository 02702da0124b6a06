//! `toporec query`: the k nearest database descriptors of new scans, made with the index's own
//! preprocessing and codebook (read from the index, never re-specified), many queries per
//! call, in parallel. Also the engine `eval` uses.

use crate::describe::{DescribeError, Describer};
use crate::error::{Error, Result, ResultExt};
use crate::search::{Database, Hit};
use crate::sinks::index::{IndexReader, IndexedScan};
use crate::sources::{InputKind, Scan, ScanFailure, ScanStream, read_cloud_file};
use crate::vectorize::codebook::Codebook;
use rayon::prelude::*;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `toporec query`.
#[derive(clap::Args, Clone, Debug)]
pub struct QueryArgs {
    /// The index to search.
    #[arg(long)]
    pub index: PathBuf,
    /// Query inputs: cloud files, MCAPs, NCLT sessions, KITTI sequences.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Neighbours per query: [1, ∞), clamped to the database size.
    #[arg(short, default_value_t = 25, value_parser = crate::ranges::count)]
    pub k: usize,
    /// Database sessions (default: all).
    #[arg(long = "session")]
    pub sessions: Vec<String>,
    /// MCAP topic.
    #[arg(long)]
    pub topic: Option<String>,
    /// Output CSV (default stdout).
    #[arg(long, short)]
    pub out: Option<PathBuf>,
}

/// An opened index, ready to answer queries.
pub struct Engine {
    /// The index's preprocessing, persistence units and codebook.
    pub describer: Describer,
    /// Database rows (descriptor, id, session, pose).
    pub scans: Vec<IndexedScan>,
    /// The search structure over `scans`.
    pub db: Database,
}

/// Per-query seconds of each step.
#[derive(Clone, Copy, Debug, Default)]
pub struct StepTimes {
    /// Preprocess + alpha persistence.
    pub persistence: f64,
    /// ATOL.
    pub vectorize: f64,
    /// Nearest-neighbour search.
    pub search: f64,
}

impl Engine {
    /// Opens `index` (only `sessions` as the database, when not empty).
    pub fn open(index: &Path, sessions: &[String]) -> Result<Self> {
        let pipeline = crate::pipeline::config::Pipeline::of_index(index)?;
        let (codebook, scans) = load_descriptors(index, sessions)?;
        let vectors: Vec<f32> = scans.iter().flat_map(|s| s.descriptor.iter().copied()).collect();
        let db = Database::new(vectors, codebook.len());
        let describer = Describer {
            preprocess: pipeline.preprocess,
            squared: pipeline.persistence.squared,
            codebook: Some(codebook),
        };
        Ok(Engine { describer, scans, db })
    }

    /// The index's codebook.
    pub fn codebook(&self) -> &Codebook {
        self.describer.codebook.as_ref().expect("an engine has a codebook")
    }

    /// The descriptor of preprocessed points, with the time of each step.
    pub fn describe_points(
        &self,
        points: &[[f64; 3]],
        label: &str,
    ) -> Result<(Vec<f32>, StepTimes), DescribeError> {
        let d = self.describer.describe_points(points, label);
        let described = d.outcome?;
        let times = StepTimes { persistence: d.times.persistence, vectorize: d.times.vectorize, search: 0.0 };
        Ok((described.descriptor.expect("an engine has a codebook").to_f32(), times))
    }

    /// The `k` nearest database rows.
    pub fn search(&self, descriptor: &[f32], k: usize) -> Vec<Hit> {
        self.db.search(descriptor, k)
    }
}

/// An index's codebook and its descriptors (only `sessions`, when not empty), checked to have
/// been made with that codebook.
pub fn load_descriptors(index: &Path, sessions: &[String]) -> Result<(Codebook, Vec<IndexedScan>)> {
    let reader = IndexReader::open(index)?;
    let codebook = reader.codebook()?;
    let mut scans = reader.descriptors(sessions, Some(codebook.len()))?;
    // A descriptor with a NaN or infinite value (a foreign or damaged table) is never ranked.
    scans.retain(|s| {
        let finite = s.descriptor.iter().all(|v| v.is_finite());
        if !finite {
            tracing::warn!(
                "{}: descriptors of session {}: scan {} has non-finite values; left out",
                index.display(),
                s.session,
                s.scan_id
            );
        }
        finite
    });
    if scans.is_empty() {
        let which = if sessions.is_empty() { String::new() } else { format!(" in sessions {sessions:?}") };
        return Err(Error::index(index, format!("no descriptors{which}")));
    }
    let id = codebook.id();
    if let Some(s) = scans.iter().find(|s| s.codebook_id != id) {
        return Err(Error::index(
            index,
            format!(
                "scan {} was made with codebook {}, the index's codebook.json is {id}",
                s.scan_id, s.codebook_id
            ),
        ));
    }
    if let Some(s) = scans.iter().find(|s| s.descriptor.len() != codebook.len()) {
        return Err(Error::index(
            index,
            format!(
                "scan {} has a descriptor of length {}, the codebook's is {}",
                s.scan_id,
                s.descriptor.len(),
                codebook.len()
            ),
        ));
    }
    Ok((codebook, scans))
}

/// A scan stream for a path given on the command line: an MCAP, an NCLT session (or folder of
/// sessions, or `velodyne_hits.bin`), a KITTI sequence (or `sequences/`), or one cloud file.
pub fn open_path(path: &Path, topic: Option<&str>) -> Result<ScanStream> {
    let kind = InputKind::detect(path)?;
    if let Some(spec) = kind.source(path, topic)? {
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
        let stat = |g: fn(&StepTimes) -> f64| mean_p95_ms(&self.times.iter().map(g).collect::<Vec<_>>());
        let ((pm, pp), (vm, vp), (sm, sp)) =
            (stat(|t| t.persistence), stat(|t| t.vectorize), stat(|t| t.search));
        write!(
            f,
            "{} queries against {} scans; per query (mean / p95 ms): persistence {pm:.2} / {pp:.2}, vectorize {vm:.3} / {vp:.3}, search {sm:.3} / {sp:.3}",
            self.answered, self.database
        )
    }
}

/// The CSV header of query results.
pub const CSV_HEADER: &str = "query_id,rank,scan_id,session,distance,pose_x,pose_y,pose_z";

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
    let mut report = QueryReport { database: engine.scans.len(), ..Default::default() };
    if args.k > engine.scans.len() {
        tracing::warn!("-k {}: the database holds {} scans; returning that many", args.k, engine.scans.len());
    }
    writeln!(out, "{CSV_HEADER}").at(output_name)?;
    for input in &args.inputs {
        let mut stream = open_path(input, args.topic.as_deref())?.peekable();
        while stream.peek().is_some() {
            let scans: Vec<_> = stream.by_ref().take(CHUNK).collect();
            let described: Vec<Result<Answerable, String>> = scans
                .into_par_iter()
                .map(|item| {
                    let scan = item.map_err(|f| f.error)?;
                    let id = scan.id.clone();
                    let d = engine.describer.describe(scan);
                    let times = StepTimes {
                        persistence: d.times.preprocess + d.times.persistence,
                        vectorize: d.times.vectorize,
                        search: 0.0,
                    };
                    match d.outcome {
                        Ok(x) => Ok((id, x.descriptor.expect("an engine has a codebook").to_f32(), times)),
                        Err(DescribeError::Skipped(reason)) => Err(format!("{id}: skipped: {reason}")),
                        Err(e) => Err(e.to_string()),
                    }
                })
                .collect();
            let ok: Vec<&Answerable> = described.iter().filter_map(|r| r.as_ref().ok()).collect();
            let start = Instant::now();
            let flat: Vec<f32> = ok.iter().flat_map(|r| r.1.iter().copied()).collect();
            let hits = engine.db.search_many(&flat, args.k);
            let per_query = start.elapsed().as_secs_f64() / ok.len().max(1) as f64;
            let mut hits = hits.into_iter();
            for r in &described {
                let (id, _, t) = match r {
                    Ok(x) => x,
                    Err(e) => {
                        report.failed += 1;
                        eprintln!("error: {e}");
                        continue;
                    }
                };
                report.answered += 1;
                report.times.push(StepTimes { search: per_query, ..*t });
                for (rank, (row, dist)) in hits.next().expect("one result per query").iter().enumerate() {
                    let s = &engine.scans[*row];
                    let p = s.pose.map(|p| p.map(|x| format!("{x:?}"))).unwrap_or_default();
                    writeln!(
                        out,
                        "{},{},{},{},{dist:?},{},{},{}",
                        csv_field(id),
                        rank + 1,
                        csv_field(&s.scan_id),
                        csv_field(&s.session),
                        p[0],
                        p[1],
                        p[2]
                    )
                    .at(output_name)?;
                }
            }
        }
    }
    out.flush().at(output_name)?;
    Ok(report)
}

/// Quotes a CSV field when needed (RFC 4180).
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

/// Mean and 95th percentile (nearest rank) of a sample, in milliseconds.
pub fn mean_p95_ms(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0);
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let p95 = s[((0.95 * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1];
    (1e3 * s.iter().sum::<f64>() / s.len() as f64, 1e3 * p95)
}
