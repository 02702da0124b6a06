//! The `toporec` command line: parses flags, runs a subcommand, maps the outcome to an exit
//! code (0 ok, 1 partial, 2 failed). Errors are printed as one line naming the file.

use crate::diagram_csv;
use crate::homology::alpha_persistence;
use crate::pipeline::RunOptions;
use crate::pipeline::config::Pipeline;
use crate::sources::mcap::McapSpec;
use crate::sources::{CloudFormat, read_cloud};
use crate::vectorize::atol::{Contrast, Weighting};
use crate::vectorize::codebook::{Codebook, CodebookFitter, CodebookSpec, DimSelection};
use crate::vectorize::kmeans::{Algorithm, KMeansParams};
use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

/// Topological place descriptors from LiDAR logs.
#[derive(Parser, Debug)]
#[command(name = "toporec", version, about)]
pub struct Cli {
    /// Log level (error, warn, info, debug, trace); also RUST_LOG.
    #[arg(long, global = true, default_value = "warn")]
    pub log_level: String,
    /// The subcommand.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Run a pipeline file: sources → preprocess → persistence → vectorize → Parquet index.
    Run(RunArgs),
    /// Find the k nearest indexed scans of new scans (files, MCAPs, sessions, sequences).
    Query(QueryArgs),
    /// Evaluate place recognition on indexes (Recall@N, Recall@1%), with a JSON report and plots.
    #[command(subcommand)]
    Eval(EvalCommand),
    /// Plots from an index.
    #[command(subcommand)]
    Plot(PlotCommand),
    /// Check a pipeline file (every error at once, with key paths) without reading data.
    Validate(ValidateArgs),
    /// Generate multi-session LiDAR drives through a procedural town (NCLT, MCAP, KITTI files).
    Simulate(SimulateArgs),
    /// Write the Parquet table schemas as JSON (what `schemas/` holds).
    #[command(hide = true)]
    Schemas(SchemasArgs),
    /// Print the persistence diagram of one cloud's alpha complex as CSV (dim,birth,death).
    Diagram(DiagramArgs),
    /// Describe what a file or folder holds (format, scans, topics, points, time span, poses).
    Inspect(InspectArgs),
    /// Fit an ATOL codebook on diagram CSV files and save it as JSON.
    Fit(FitArgs),
    /// Turn diagram CSV files into descriptors with a saved codebook (CSV rows on stdout or --out).
    Vectorize(VectorizeArgs),
}

/// Arguments of `toporec run`.
#[derive(clap::Args, Debug)]
pub struct RunArgs {
    /// The pipeline file (TOML).
    #[arg(default_value = "pipelines/sample.toml")]
    pub pipeline: PathBuf,
    /// Worker threads (default: all cores).
    #[arg(long, short)]
    pub threads: Option<usize>,
    /// Write the index here instead of the file's `output.index`.
    #[arg(long)]
    pub index: Option<PathBuf>,
    /// No progress bar or progress lines.
    #[arg(long)]
    pub no_progress: bool,
}

/// Arguments of `toporec simulate`.
#[derive(clap::Args, Debug)]
pub struct SimulateArgs {
    /// Output folder.
    #[arg(long, short)]
    pub out: PathBuf,
    /// Formats to write.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "nclt")]
    pub format: Vec<crate::simulate::Format>,
    /// Sessions (days) driving the same loop.
    #[arg(long, default_value_t = 2)]
    pub sessions: usize,
    /// Seed of the town, routes and noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Scans per session (default: one loop).
    #[arg(long)]
    pub scans: Option<usize>,
    /// Sensor model.
    #[arg(long, value_enum, default_value = "hdl32")]
    pub sensor: crate::simulate::SensorModel,
    /// Azimuth resolution (degrees).
    #[arg(long, default_value_t = 0.2)]
    pub azimuth_res: f64,
    /// Driving speed (m/s).
    #[arg(long, default_value_t = 10.0)]
    pub speed: f64,
    /// Scan rate (Hz).
    #[arg(long, default_value_t = 10.0)]
    pub rate: f64,
    /// Blocks per side of the town.
    #[arg(long, default_value_t = 3)]
    pub blocks: usize,
    /// Street spacing (m).
    #[arg(long, default_value_t = 60.0)]
    pub block_size: f64,
    /// Ground slope along x and y (dz/dx,dz/dy).
    #[arg(long, value_delimiter = ',', default_value = "0,0")]
    pub slope: Vec<f64>,
    /// Odd sessions drive the loop in the opposite direction.
    #[arg(long)]
    pub reverse: bool,
    /// Probability that a return is lost.
    #[arg(long, default_value_t = 0.08)]
    pub dropout: f64,
    /// Maximum range (m).
    #[arg(long, default_value_t = 100.0)]
    pub max_range: f64,
    /// Range noise σ (m).
    #[arg(long, default_value_t = 0.02)]
    pub range_noise: f64,
    /// Sensor height above the ground (m).
    #[arg(long, default_value_t = 1.9)]
    pub height: f64,
    /// Worker threads (default: all cores).
    #[arg(long, short)]
    pub threads: Option<usize>,
}

/// Arguments of `toporec query`.
#[derive(clap::Args, Debug)]
pub struct QueryArgs {
    /// The index to search.
    #[arg(long)]
    pub index: PathBuf,
    /// Query inputs: cloud files, MCAPs, NCLT sessions, KITTI sequences.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Neighbours per query.
    #[arg(short, default_value_t = 25)]
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

/// `toporec eval` protocols.
#[derive(Subcommand, Debug)]
pub enum EvalCommand {
    /// Database scans vs query scans, true matches within R metres.
    Places(PlacesCli),
    /// The paper's object protocol: perturbed index scans must find themselves.
    Perturbation(PerturbationCli),
}

/// Arguments of `toporec eval places`.
#[derive(clap::Args, Debug)]
pub struct PlacesCli {
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
    /// Revisit thresholds R (m).
    #[arg(long, value_delimiter = ',', default_value = "5,10,20,50")]
    pub thresholds: Vec<f64>,
    /// Largest N of Recall@N.
    #[arg(long, default_value_t = 25)]
    pub max_n: usize,
    /// Keep a map scan only if farther than this (m) from the last kept (RING).
    #[arg(long)]
    pub map_every: Option<f64>,
    /// Same for query scans.
    #[arg(long)]
    pub query_every: Option<f64>,
    /// Ignore database scans of the query's session closer in time than this (s).
    #[arg(long, default_value_t = 0.0)]
    pub min_time_gap: f64,
    /// Output folder for report.json, report.txt and the plots.
    #[arg(long, short)]
    pub out: PathBuf,
}

/// Arguments of `toporec eval perturbation`.
#[derive(clap::Args, Debug)]
pub struct PerturbationCli {
    /// The index.
    #[arg(long)]
    pub index: PathBuf,
    /// Share of the scans used as queries.
    #[arg(long, default_value_t = 0.2)]
    pub fraction: f64,
    /// Seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Largest N of Recall@N.
    #[arg(long, default_value_t = 25)]
    pub max_n: usize,
    /// Output folder.
    #[arg(long, short)]
    pub out: PathBuf,
}

/// `toporec plot` kinds.
#[derive(Subcommand, Debug)]
pub enum PlotCommand {
    /// The persistence diagram of one indexed scan (PNG + SVG).
    Diagram(PlotDiagramArgs),
}

/// Arguments of `toporec plot diagram`.
#[derive(clap::Args, Debug)]
pub struct PlotDiagramArgs {
    /// The index.
    #[arg(long)]
    pub index: PathBuf,
    /// The scan id.
    #[arg(long)]
    pub scan: String,
    /// Output file stem (default: `diagram_<scan id>` in the current folder).
    #[arg(long, short)]
    pub out: Option<PathBuf>,
}

/// Arguments of `toporec validate`.
#[derive(clap::Args, Debug)]
pub struct ValidateArgs {
    /// The pipeline file (TOML).
    pub pipeline: PathBuf,
}

/// Arguments of `toporec schemas`.
#[derive(clap::Args, Debug)]
pub struct SchemasArgs {
    /// Folder to write `<table>.json` into.
    pub dir: PathBuf,
}

/// Arguments of `toporec inspect`.
#[derive(clap::Args, Debug)]
pub struct InspectArgs {
    /// A cloud file, an MCAP, an NCLT session (or folder of sessions), a KITTI sequence.
    pub path: PathBuf,
}

/// Arguments of `toporec fit`.
#[derive(clap::Args, Debug)]
pub struct FitArgs {
    /// Diagram CSV files (dim,birth,death) as `toporec diagram` writes them, or index folders
    /// (their diagrams tables).
    #[arg(required = true)]
    pub diagrams: Vec<PathBuf>,
    /// Where to write the codebook (JSON).
    #[arg(long, short)]
    pub out: PathBuf,
    /// Centres per codebook (the descriptor length per part).
    #[arg(long, short, default_value_t = 50)]
    pub b: usize,
    /// `paper` (H2, else H1, else H0) or a list like `0,1,2` (one codebook per dimension).
    #[arg(long, default_value = "paper", value_parser = DimSelection::parse)]
    pub dims: DimSelection,
    /// ATOL contrast: gaussian, laplacian or indicator.
    #[arg(long, default_value = "laplacian", value_parser = parse_contrast)]
    pub contrast: Contrast,
    /// ATOL weighting: cloud (sum) or iidproba (mean).
    #[arg(long, default_value = "cloud", value_parser = parse_weighting)]
    pub weighting: Weighting,
    /// The quantiser.
    #[arg(long, value_enum, default_value = "minibatch")]
    pub kmeans: Algorithm,
    /// Points kept (uniform reservoir sample) per codebook for fitting.
    #[arg(long, default_value_t = 100_000)]
    pub sample_size: usize,
    /// Seed of sampling and k-means.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Record that the diagrams are in radii, not squared radii.
    #[arg(long)]
    pub radius: bool,
}

/// Arguments of `toporec vectorize`.
#[derive(clap::Args, Debug)]
pub struct VectorizeArgs {
    /// Diagram CSV files or index folders.
    #[arg(required = true)]
    pub diagrams: Vec<PathBuf>,
    /// The codebook (JSON from `toporec fit`).
    #[arg(long, short)]
    pub codebook: PathBuf,
    /// Output: `*.parquet` for a descriptors table (the index's schema), else CSV
    /// `diagram,dim_used,v1..vb` (default stdout).
    #[arg(long, short)]
    pub out: Option<PathBuf>,
}

fn parse_contrast(s: &str) -> Result<Contrast, String> {
    serde_json::from_value(serde_json::Value::String(s.into()))
        .map_err(|_| format!("`{s}` is not one of gaussian, laplacian, indicator"))
}

fn parse_weighting(s: &str) -> Result<Weighting, String> {
    serde_json::from_value(serde_json::Value::String(s.into()))
        .map_err(|_| format!("`{s}` is not one of cloud, iidproba"))
}

/// Arguments of `toporec diagram`.
#[derive(clap::Args, Debug)]
pub struct DiagramArgs {
    /// The cloud: .csv (header x,y,z), KITTI .bin, or NCLT velodyne_sync .bin.
    pub cloud: PathBuf,
    /// Dimensions to print, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "0,1,2")]
    pub dims: Vec<u8>,
    /// Print radii instead of squared radii (GUDHI's output_squared_values=False).
    #[arg(long)]
    pub radius: bool,
    /// The file format; detected from the path when omitted (MCAP by its magic).
    #[arg(long, value_enum)]
    pub format: Option<CloudFormat>,
    /// MCAP: the Nth point-cloud message (0-based) of the topic.
    #[arg(long, default_value_t = 0)]
    pub index: u64,
    /// MCAP: the topic (default: the file's only point-cloud topic).
    #[arg(long)]
    pub topic: Option<String>,
}

/// Entry point of the binary.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(&cli.log_level));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).init();
    let result = match cli.command {
        Command::Run(args) => return run(args),
        Command::Validate(args) => validate(args),
        Command::Schemas(args) => schemas(args),
        Command::Query(args) => query(args),
        Command::Eval(EvalCommand::Places(a)) => {
            let args = crate::eval::PlacesArgs {
                db: a.db,
                db_sessions: a.db_sessions,
                queries: a.queries,
                query_sessions: a.query_sessions,
                thresholds: a.thresholds,
                max_n: a.max_n,
                map_every: a.map_every,
                query_every: a.query_every,
                min_time_gap: a.min_time_gap,
                out: a.out.clone(),
            };
            crate::eval::places(&args)
                .map(|t| println!("{t}written: {}", a.out.join("report.json").display()))
        }
        Command::Eval(EvalCommand::Perturbation(a)) => {
            let args = crate::eval::PerturbationArgs {
                index: a.index,
                fraction: a.fraction,
                seed: a.seed,
                max_n: a.max_n,
                out: a.out.clone(),
            };
            crate::eval::perturbation(&args)
                .map(|t| println!("{t}written: {}", a.out.join("report.json").display()))
        }
        Command::Plot(PlotCommand::Diagram(a)) => plot_diagram(a),
        Command::Simulate(args) => simulate(args),
        Command::Diagram(args) => diagram(args),
        Command::Inspect(args) => crate::inspect::inspect(&args.path).map(|report| print!("{report}")),
        Command::Fit(args) => fit(args),
        Command::Vectorize(args) => vectorize(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            ExitCode::from(2)
        }
    }
}

fn run(args: RunArgs) -> ExitCode {
    let pipeline = match Pipeline::load(&args.pipeline) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let threads = args.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let opts = RunOptions { threads, index: args.index, progress: !args.no_progress };
    match crate::pipeline::run(&pipeline, &opts) {
        Ok(summary) => {
            eprintln!("{summary}");
            if summary.partial() {
                eprintln!(
                    "partial: {} of {} scans failed (see the scans table's error column)",
                    summary.errors, summary.read
                );
                ExitCode::from(1)
            } else {
                ExitCode::SUCCESS
            }
        }
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            ExitCode::from(2)
        }
    }
}

fn validate(args: ValidateArgs) -> Result<()> {
    let p = Pipeline::load(&args.pipeline)?;
    println!(
        "{}: ok ({} source(s), index {}, {})",
        args.pipeline.display(),
        p.sources.len(),
        p.index.display(),
        match &p.vectorize {
            crate::pipeline::config::Vectorize::Fit(s) => format!("fit b = {} dims {}", s.b, s.dims),
            crate::pipeline::config::Vectorize::Load(path, cb) =>
                format!("codebook {} ({})", cb.id(), path.display()),
        }
    );
    Ok(())
}

fn simulate(a: SimulateArgs) -> Result<()> {
    use crate::simulate::{Sensor, SimParams, scene::TownParams};
    if a.slope.len() != 2 {
        bail!("--slope: expected two numbers dz/dx,dz/dy");
    }
    let mut sensor = Sensor::new(a.sensor);
    sensor.azimuth_res = a.azimuth_res;
    sensor.dropout = a.dropout;
    sensor.max_range = a.max_range;
    sensor.range_noise = a.range_noise;
    sensor.height = a.height;
    let p = SimParams {
        town: TownParams {
            blocks: a.blocks,
            block_size: a.block_size,
            slope: [a.slope[0], a.slope[1]],
            ..TownParams::default()
        },
        sensor,
        sessions: a.sessions,
        seed: a.seed,
        scans: a.scans,
        speed: a.speed,
        rate: a.rate,
        reverse: a.reverse,
        ..SimParams::default()
    };
    if a.blocks == 0 || a.block_size <= 20.0 || a.rate <= 0.0 || a.speed <= 0.0 || a.azimuth_res <= 0.0 {
        bail!(
            "simulate: need blocks >= 1, block size > 20 m, and positive rate, speed and azimuth resolution"
        );
    }
    let threads = a.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build()?;
    let start = std::time::Instant::now();
    let n = pool.install(|| crate::simulate::simulate(&p, &a.format, &a.out))?;
    let secs = start.elapsed().as_secs_f64();
    eprintln!(
        "simulated {n} scans ({} sessions) into {} in {secs:.2} s ({:.0} scans/s)",
        a.sessions,
        a.out.display(),
        n as f64 / secs
    );
    Ok(())
}

fn query(a: QueryArgs) -> Result<()> {
    use rayon::prelude::*;
    let engine = crate::query::Engine::open(&a.index, &a.sessions)?;
    // Rows stream out: to a temporary file renamed at the end, or to stdout.
    let tmp = a.out.as_ref().map(|p| crate::fsutil::temp_path(p));
    let mut out: Box<dyn Write> = match &tmp {
        Some(t) => Box::new(std::io::BufWriter::new(
            std::fs::File::create(t).with_context(|| t.display().to_string())?,
        )),
        None => Box::new(std::io::BufWriter::new(std::io::stdout().lock())),
    };
    writeln!(out, "query_id,rank,scan_id,session,distance,pose_x,pose_y,pose_z")
        .or_else(ignore_broken_pipe)?;
    let mut times = Vec::new();
    let mut failures = 0;
    // Streamed a chunk at a time: descriptors in parallel, then one batched search per chunk.
    let chunk = 64;
    for input in &a.inputs {
        let mut stream = crate::query::open_path(input, a.topic.as_deref())?.peekable();
        while stream.peek().is_some() {
            let scans: Vec<_> = stream.by_ref().take(chunk).collect();
            let described: Vec<_> = scans
                .into_par_iter()
                .map(|item| {
                    let scan = item.map_err(|f| f.error)?;
                    let id = scan.id.clone();
                    let points = engine.preprocess(scan)?;
                    let (v, t) = engine.describe(&points, &id)?;
                    Ok::<_, String>((id, v, t))
                })
                .collect();
            let ok: Vec<&(String, Vec<f32>, crate::query::StepTimes)> =
                described.iter().filter_map(|r| r.as_ref().ok()).collect();
            let start = std::time::Instant::now();
            let flat: Vec<f32> = ok.iter().flat_map(|r| r.1.iter().copied()).collect();
            let hits = engine.db.search_many(&flat, a.k);
            let per_query = start.elapsed().as_secs_f64() / ok.len().max(1) as f64;
            let mut hits = hits.into_iter();
            for r in &described {
                let (id, _, t) = match r {
                    Ok(x) => x,
                    Err(e) => {
                        failures += 1;
                        eprintln!("error: {e}");
                        continue;
                    }
                };
                times.push(crate::query::StepTimes { search: per_query, ..*t });
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
                    .or_else(ignore_broken_pipe)?;
                }
            }
        }
    }
    out.flush().or_else(ignore_broken_pipe)?;
    drop(out);
    if let (Some(t), Some(p)) = (&tmp, &a.out) {
        std::fs::rename(t, p).with_context(|| p.display().to_string())?;
    }
    let stat = |f: fn(&crate::query::StepTimes) -> f64| {
        crate::query::mean_p95_ms(&times.iter().map(f).collect::<Vec<_>>())
    };
    let ((pm, pp), (vm, vp), (sm, sp)) = (stat(|t| t.persistence), stat(|t| t.vectorize), stat(|t| t.search));
    eprintln!(
        "{} queries against {} scans; per query (mean / p95 ms): persistence {pm:.2} / {pp:.2}, vectorize {vm:.3} / {vp:.3}, search {sm:.3} / {sp:.3}",
        times.len(),
        engine.scans.len()
    );
    if failures > 0 {
        bail!("{failures} quer(ies) failed");
    }
    Ok(())
}

fn plot_diagram(a: PlotDiagramArgs) -> Result<()> {
    let d = crate::sinks::index::diagram_of(&a.index, &a.scan)?
        .with_context(|| format!("{}: no scan {} in the diagrams table", a.index.display(), a.scan))?;
    let stem =
        a.out.unwrap_or_else(|| PathBuf::from(format!("diagram_{}", a.scan.replace(['/', '\\'], "_"))));
    for p in crate::plot::diagram(&stem, &format!("persistence diagram of {}", a.scan), &d)? {
        println!("{}", p.display());
    }
    Ok(())
}

fn schemas(args: SchemasArgs) -> Result<()> {
    for t in crate::sinks::schema::all() {
        crate::fsutil::write_atomic(
            &args.dir.join(format!("{}.json", t.name)),
            crate::sinks::schema::render_json(&t).as_bytes(),
        )?;
    }
    Ok(())
}

/// The error chain on one line.
fn one_line(e: &anyhow::Error) -> String {
    e.chain().map(|c| c.to_string()).collect::<Vec<_>>().join(": ")
}

/// Minimum number of input points for `toporec diagram`.
const MIN_POINTS: usize = 4;

fn diagram(args: DiagramArgs) -> Result<()> {
    if let Some(d) = args.dims.iter().find(|&&d| d > 2) {
        bail!("--dims: dimension {d} is not one of 0, 1, 2");
    }
    let points = if args.format.is_none() && crate::inspect::is_mcap(&args.cloud) {
        mcap_cloud(&args)?
    } else {
        read_cloud(&args.cloud, args.format)?
    };
    if points.len() < MIN_POINTS {
        bail!("{}: {} point(s); a diagram needs at least {MIN_POINTS}", args.cloud.display(), points.len());
    }
    let start = std::time::Instant::now();
    let mut diagram = alpha_persistence(&points).with_context(|| args.cloud.display().to_string())?;
    tracing::info!(points = points.len(), pairs = diagram.len(), elapsed = ?start.elapsed(), "diagram computed");
    diagram.retain_dims(&args.dims);
    if args.radius {
        diagram = diagram.to_radii();
    }
    diagram_csv::write(&diagram, &mut std::io::stdout().lock()).or_else(ignore_broken_pipe)?;
    Ok(())
}

/// The `--index`th point cloud of an MCAP file.
fn mcap_cloud(args: &DiagramArgs) -> Result<Vec<crate::homology::Point>> {
    let spec = McapSpec { topic: args.topic.clone(), ..McapSpec::file(&args.cloud) };
    for item in spec.open()? {
        match item {
            Ok(scan) if scan.message_index == Some(args.index) => return Ok(scan.points),
            Err(f) if f.message_index == Some(args.index) => bail!("{}", f.error),
            _ => {}
        }
    }
    bail!("{}: no point-cloud message with index {}", args.cloud.display(), args.index)
}

fn ignore_broken_pipe(e: std::io::Error) -> std::io::Result<()> {
    if e.kind() == std::io::ErrorKind::BrokenPipe { Ok(()) } else { Err(e) }
}

fn fit(args: FitArgs) -> Result<()> {
    let spec = CodebookSpec {
        dims: args.dims,
        b: args.b,
        contrast: args.contrast,
        weighting: args.weighting,
        kmeans: KMeansParams { algorithm: args.kmeans, ..KMeansParams::default() },
        sample_size: args.sample_size,
        seed: args.seed,
        squared_radii: !args.radius,
    };
    let mut fitter = CodebookFitter::new(spec);
    for item in diagram_inputs(&args.diagrams) {
        fitter.add(&item?.1);
    }
    let start = std::time::Instant::now();
    let codebook = fitter.finish().context("fitting the codebook")?;
    tracing::info!(elapsed = ?start.elapsed(), "codebook fitted");
    codebook.save(&args.out)?;
    eprintln!(
        "codebook {} (dims {}, length {}) written to {}",
        codebook.id(),
        codebook.spec.dims,
        codebook.len(),
        args.out.display()
    );
    Ok(())
}

/// Diagrams from CSV files (id = the path) or index folders (id = the scan id), streamed.
fn diagram_inputs(
    paths: &[PathBuf],
) -> impl Iterator<Item = Result<(String, crate::homology::Diagram)>> + '_ {
    paths.iter().flat_map(|path| -> Box<dyn Iterator<Item = Result<(String, crate::homology::Diagram)>>> {
        if path.is_dir() {
            match crate::sinks::index::table_files(path, "diagrams") {
                Ok(files) => {
                    Box::new(files.into_iter().flat_map(|(_, f)| match crate::sinks::index::diagrams(&f) {
                        Ok(it) => Box::new(it) as Box<dyn Iterator<Item = _>>,
                        Err(e) => Box::new(std::iter::once(Err(e))),
                    }))
                }
                Err(e) => Box::new(std::iter::once(Err(e))),
            }
        } else {
            Box::new(std::iter::once(diagram_csv::read(path).map(|d| (path.display().to_string(), d))))
        }
    })
}

fn vectorize(args: VectorizeArgs) -> Result<()> {
    let codebook = Codebook::load(&args.codebook)?;
    if let Some(out) = args.out.as_ref().filter(|o| o.extension().is_some_and(|e| e == "parquet")) {
        let tmp = crate::fsutil::temp_path(out);
        let mut file = crate::sinks::parquet::DescriptorsFile::create(&tmp, codebook.len(), &codebook.id())?;
        let mut rows = 0;
        for item in diagram_inputs(&args.diagrams) {
            let (id, diagram) = item?;
            file.push(crate::sinks::parquet::DescriptorRow::new(
                id,
                None,
                None,
                &codebook.vectorize(&diagram),
            ))?;
            rows += 1;
        }
        file.finish()?;
        std::fs::rename(&tmp, out).with_context(|| out.display().to_string())?;
        eprintln!("{rows} descriptors (length {}) written to {}", codebook.len(), out.display());
        return Ok(());
    }
    let mut text = String::from("diagram,dim_used");
    for j in 1..=codebook.len() {
        text += &format!(",v{j}");
    }
    text.push('\n');
    for item in diagram_inputs(&args.diagrams) {
        let (id, diagram) = item?;
        let d = codebook.vectorize(&diagram);
        let dim = d.dim_used.map(|d| d.to_string()).unwrap_or_default();
        text += &format!("{},{dim}", csv_field(&id));
        for v in &d.values {
            text += &format!(",{v:?}");
        }
        text.push('\n');
    }
    match &args.out {
        Some(out) => crate::fsutil::write_atomic(out, text.as_bytes()),
        None => std::io::stdout()
            .lock()
            .write_all(text.as_bytes())
            .or_else(ignore_broken_pipe)
            .map_err(Into::into),
    }
}

/// Quotes a CSV field when needed (RFC 4180).
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}
