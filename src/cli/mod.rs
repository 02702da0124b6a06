//! The `toporec` command line: clap declarations and dispatch to the library. Every command
//! ends with one exit code: 0 = all done, 1 = partial (some scans or queries failed, the rest
//! was written), 2 = failed. Errors are printed once, on one line naming the input; a closed
//! output pipe ends a command quietly.

mod args;

use args::*;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use toporec::eval::{PerturbationArgs, PlacesArgs};
use toporec::fsutil::AtomicFile;
use toporec::homology::alpha_persistence;
use toporec::maintenance::RevectorizeArgs;
use toporec::offline::{FitArgs, VectorizeArgs};
use toporec::pipeline::RunOptions;
use toporec::pipeline::config::{Pipeline, Vectorize};
use toporec::query::QueryArgs;
use toporec::simulate::SimulateArgs;
use toporec::sinks::index::IndexReader;
use toporec::sources::logs::LogSpec;
use toporec::sources::read_cloud;

/// Topological place descriptors from LiDAR logs.
#[derive(Parser, Debug)]
#[command(name = "toporec", version, about)]
struct Cli {
    /// Log level (error, warn, info, debug, trace); also RUST_LOG.
    #[arg(long, global = true, default_value = "warn")]
    log_level: String,
    /// The subcommand.
    #[command(subcommand)]
    command: Command,
}

/// Subcommands.
#[derive(Subcommand, Debug)]
enum Command {
    /// Run a pipeline file: sources → preprocess → persistence → vectorize → Parquet index.
    Run(RunArgs),
    /// Find the k nearest indexed scans of new scans (files, MCAPs, sessions, sequences).
    Query(QueryArgs),
    /// Loop closures of a robot's logs: `loops <log>…` indexes them under `out/<log name>`
    /// (again only what changed), finds each scan's match among the earlier ones (its own
    /// session's last 30 s left out) below the method's calibrated threshold, verifies it by
    /// ICP and draws the drive with its loops beside the table (`<out stem>.png`);
    /// `loops --index DIR` does the same on an index. Parquet or CSV.
    Loops(toporec::loops::LoopsArgs),
    /// Optimize a pose graph (g2o: SE(2) or SE(3), FIX lines), written back with its vertices
    /// moved; --robust rejects the loops that disagree with the rest.
    Optimize(toporec::map::OptimizeArgs),
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
    /// Split one NCLT session into a map session (every Nth scan) and a query session (the
    /// others), to measure fine localization along one drive.
    Split(toporec::split::SplitArgs),
    /// Write the Parquet table schemas and the report's JSON Schema (what `schemas/` holds).
    #[command(hide = true)]
    Schemas(SchemasArgs),
    /// Print the persistence diagram of one cloud's alpha complex as CSV (dim,birth,death).
    Diagram(DiagramArgs),
    /// Describe what a file or folder holds (format, scans, topics, points, time span, poses).
    Inspect(InspectArgs),
    /// Fit an ATOL codebook on diagram CSV files or index folders and save it as JSON.
    Fit(FitArgs),
    /// Turn diagram CSV files or index folders into descriptors with a saved codebook.
    Vectorize(VectorizeArgs),
    /// Rebuild an index's descriptors from its stored diagrams with a new codebook (no source
    /// is read, no persistence computed), switching to it atomically.
    Revectorize(RevectorizeArgs),
    /// Merge an index's small part files (left by chunked commits) into one per partition.
    Compact(IndexArgs),
    /// What an index holds: sessions with scans per status, descriptor methods, generation,
    /// size, pipeline; or (`--files`) the committed files, one generation, for other readers.
    Info(InfoArgs),
    /// Check an index against its manifest (files, sizes, checksums, rows, codebook, every ok
    /// scan's rows, part files no commit names); exit 1 with the list of problems.
    Verify(VerifyArgs),
    /// Store descriptors made elsewhere (Parquet, .npy with scan ids, CSV) as one more method
    /// of an index, matched to its scans by id.
    Import(toporec::import::ImportArgs),
    /// Rebuild the parts of an index that fail their checksums, from its stored diagrams and
    /// its pipeline's sources, in one commit; scans whose source is gone or changed are named.
    Repair(RepairArgs),
}

/// `toporec eval` protocols.
#[derive(Subcommand, Debug)]
enum EvalCommand {
    /// Database scans vs query scans, true matches within R metres, under conditions.
    Places(Box<PlacesArgs>),
    /// The paper's object protocol: perturbed index scans must find themselves.
    Perturbation(PerturbationArgs),
}

/// `toporec plot` kinds.
#[derive(Subcommand, Debug)]
enum PlotCommand {
    /// The persistence diagram of one indexed scan (PNG + SVG).
    Diagram(PlotDiagramArgs),
}

/// How a command ended, when it did not fail.
enum Done {
    /// Everything done.
    All,
    /// Some items failed; the rest was done (exit 1).
    Partial,
}

/// Entry point of the binary.
pub fn main() -> ExitCode {
    // Past a file-size limit (`ulimit -f`) a write then fails with EFBIG, reported with its path
    // and handled like a full disk, instead of SIGXFSZ killing the process without a word.
    // SAFETY: setting a signal's disposition to SIG_IGN before any other thread starts.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => return usage_error(e),
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(&cli.log_level));
    // Colour only for a terminal: a log file or a pipe gets plain text.
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_ansi(ansi).init();
    let result = match cli.command {
        Command::Run(args) => run(args),
        Command::Validate(args) => validate(args).map(|()| Done::All),
        Command::Schemas(args) => schemas(args).map(|()| Done::All),
        Command::Query(args) => query(args),
        Command::Eval(EvalCommand::Places(a)) => places(*a),
        Command::Eval(EvalCommand::Perturbation(a)) => perturbation(a),
        Command::Plot(PlotCommand::Diagram(a)) => plot_diagram(a).map(|()| Done::All),
        Command::Simulate(args) => simulate(args).map(|()| Done::All),
        Command::Split(args) => toporec::split::split(&args)
            .map_err(Into::into)
            .and_then(|r| print(&format!("{r}\n")))
            .map(|()| Done::All),
        Command::Diagram(args) => diagram(args).map(|()| Done::All),
        Command::Inspect(args) => toporec::inspect::inspect(&args.path)
            .map_err(Into::into)
            .and_then(|r| print(&r))
            .map(|()| Done::All),
        Command::Fit(args) => fit(args).map(|()| Done::All),
        Command::Vectorize(args) => vectorize(args).map(|()| Done::All),
        Command::Revectorize(args) => revectorize(args).map(|()| Done::All),
        Command::Compact(args) => compact(args).map(|()| Done::All),
        Command::Verify(args) => verify(args),
        Command::Info(args) => info(args),
        Command::Import(args) => import(args).map(|()| Done::All),
        Command::Loops(args) => loops(args),
        Command::Optimize(args) => toporec::map::optimize(&args)
            .map_err(Into::into)
            .and_then(|r| print(&format!("{r}written: {}\n", args.out.display())))
            .map(|()| Done::All),
        Command::Repair(args) => repair(args),
    };
    match result {
        Ok(Done::All) => ExitCode::SUCCESS,
        Ok(Done::Partial) => ExitCode::from(1),
        Err(e) if is_broken_pipe(&e) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            ExitCode::from(2)
        }
    }
}

/// A command-line error (an unknown flag, a value out of range) as one line naming the flag, the
/// value and the range, exit 2; help and version print as usual.
fn usage_error(e: clap::Error) -> ExitCode {
    use clap::error::ErrorKind;
    if matches!(
        e.kind(),
        ErrorKind::DisplayHelp
            | ErrorKind::DisplayVersion
            | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
    ) {
        e.exit();
    }
    let text = e.render().to_string();
    let first: Vec<&str> = text.lines().map(str::trim).take_while(|l| !l.is_empty()).collect();
    eprintln!("{}", first.join(" "));
    ExitCode::from(2)
}

/// Prints to stdout (a closed pipe surfaces as an error that ends the command quietly).
fn print(text: &str) -> Result<()> {
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())?;
    out.flush()?;
    Ok(())
}

/// Whether the error is a write to a closed pipe.
fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>().is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// The error and its causes on one line, each message once (a cause already quoted by the
/// message above it is not repeated).
fn one_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if !line.contains(&text) {
            if !line.is_empty() {
                line.push_str(": ");
            }
            line.push_str(&text);
        }
    }
    line
}

fn run(args: RunArgs) -> Result<Done> {
    let is_pipeline = |p: &PathBuf| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    let (pipeline, index) = match args.inputs.as_slice() {
        [one] if is_pipeline(one) => (Pipeline::load(one)?, args.index.clone()),
        inputs => {
            if let Some(p) = inputs.iter().find(|p| is_pipeline(p)) {
                bail!("{}: a pipeline file is given alone (the others are sources)", p.display());
            }
            use toporec::pipeline::from_sources::{check_default_index, default_index, made};
            let index = args.index.clone().unwrap_or_else(|| default_index(inputs));
            let made = made(inputs, &args.from, &args.methods, &index)?;
            if args.index.is_none() {
                check_default_index(&index, &made)?;
            }
            for p in &made.poses {
                eprintln!("{p}");
            }
            print(&made.text)?;
            (made.pipeline, Some(index))
        }
    };
    let opts = RunOptions {
        index,
        progress: !args.no_progress,
        full: args.full,
        prune: args.prune,
        commit_every: args.commit_every,
        commit_seconds: args.commit_seconds,
        shard: args.shard,
        ..RunOptions::new(args.threads.count())
    };
    let summary = toporec::pipeline::run(&pipeline, &opts)?;
    eprintln!("{summary}");
    if let Some(path) = &args.summary_json {
        let text = serde_json::to_string_pretty(&summary.to_json())? + "\n";
        toporec::fsutil::write_atomic(path, text.as_bytes())?;
    }
    if summary.partial() {
        eprintln!(
            "partial: {} of {} scans failed (see the scans table's error column)",
            summary.errors, summary.read
        );
        return Ok(Done::Partial);
    }
    Ok(Done::All)
}

fn validate(args: ValidateArgs) -> Result<()> {
    let p = Pipeline::load(&args.pipeline)?;
    let vectorize = match &p.vectorize {
        Vectorize::Fit(s) => format!("fit b = {} dims {}", s.b, s.dims),
        Vectorize::Load(path, cb) => format!("codebook {} ({})", cb.id(), path.display()),
    };
    print(&format!(
        "{}: ok ({} source(s), index {}, {vectorize})\n",
        args.pipeline.display(),
        p.sources.len(),
        p.index.display()
    ))
}

fn loops(a: toporec::loops::LoopsArgs) -> Result<Done> {
    let done = toporec::loops::run(&a, a.threads.count())?;
    eprint!("{done}");
    print(&format!("written: {}\n", a.out.display()))?;
    let damaged = report_damage(&done.loops.damaged);
    Ok(if done.partial() || damaged { Done::Partial } else { Done::All })
}

fn import(a: toporec::import::ImportArgs) -> Result<()> {
    let r = toporec::import::import(&a)?;
    print(&format!(
        "{}: method {} stored: {} scans, length {}, id {}\n",
        a.index.path.display(),
        a.method,
        r.rows,
        r.length,
        r.id
    ))
}

fn places(a: PlacesArgs) -> Result<Done> {
    let (table, damaged) = toporec::eval::places(&a)?;
    print(&format!("{table}written: {}\n", a.out.join("report.json").display()))?;
    Ok(if report_damage(&damaged) { Done::Partial } else { Done::All })
}

fn perturbation(a: PerturbationArgs) -> Result<Done> {
    let table = toporec::eval::perturbation(&a)?;
    print(&format!("{table}written: {}\n", a.out.join("report.json").display()))?;
    Ok(Done::All)
}

fn simulate(a: SimulateArgs) -> Result<()> {
    let params = a.params()?;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(a.threads.count()).build()?;
    let start = std::time::Instant::now();
    let n = pool.install(|| toporec::simulate::simulate(&params, &a.format, &a.out))?;
    let secs = start.elapsed().as_secs_f64();
    eprintln!(
        "simulated {n} scans ({} sessions) into {} in {secs:.2} s ({:.0} scans/s)",
        a.sessions,
        a.out.display(),
        n as f64 / secs
    );
    Ok(())
}

/// Names each damaged part a skipping read left out, and the scans it held, on stderr;
/// whether there was any.
fn report_damage(damaged: &[toporec::sinks::index::damage::DamagedPart]) -> bool {
    for d in damaged {
        eprintln!("warning: {}", d.describe());
    }
    if !damaged.is_empty() {
        eprintln!(
            "partial: {} damaged parts left out; `toporec repair --index {}` rebuilds them",
            damaged.len(),
            damaged[0].index.display()
        );
    }
    !damaged.is_empty()
}

fn query(a: QueryArgs) -> Result<Done> {
    let damage = toporec::sinks::index::damage::Damage::skipping(a.skip_damaged);
    let engine = toporec::search::Engine::open_with(&a.index.path, &a.sessions, &a.method, &damage)?;
    let report = match &a.out {
        Some(path) => {
            let mut file = AtomicFile::create(path)?;
            let report = toporec::query::run(&engine, &a, &mut file, path)?;
            file.commit()?;
            report
        }
        None => {
            let mut out = std::io::BufWriter::new(std::io::stdout().lock());
            toporec::query::run(&engine, &a, &mut out, Path::new("<stdout>"))?
        }
    };
    eprintln!("{report}");
    let damaged = report_damage(&toporec::sinks::index::holdings::held_scans(damage.found())?);
    match (report.failed, report.answered) {
        (0, _) if damaged => Ok(Done::Partial),
        (0, _) => Ok(Done::All),
        (f, 0) => bail!("all {f} queries failed"),
        (f, n) => {
            eprintln!("partial: {f} of {} queries failed", f + n);
            Ok(Done::Partial)
        }
    }
}

fn plot_diagram(a: PlotDiagramArgs) -> Result<()> {
    let d = IndexReader::read_consistent(&a.index.path, |r| r.diagram_of(&a.scan))?
        .with_context(|| format!("{}: no scan {} in the diagrams table", a.index.path.display(), a.scan))?;
    let stem =
        a.out.unwrap_or_else(|| PathBuf::from(format!("diagram_{}", a.scan.replace(['/', '\\'], "_"))));
    let files = toporec::plot::diagram(&stem, &format!("persistence diagram of {}", a.scan), &d)?;
    print(&files.iter().map(|p| format!("{}\n", p.display())).collect::<String>())
}

fn schemas(args: SchemasArgs) -> Result<()> {
    for t in toporec::sinks::schema::all() {
        let path = args.dir.join(format!("{}.json", t.name));
        toporec::fsutil::write_atomic(&path, toporec::sinks::schema::render_json(&t).as_bytes())?;
    }
    let report = args.dir.join(REPORT_SCHEMA);
    toporec::fsutil::write_atomic(&report, toporec::eval::report::schema().as_bytes())?;
    Ok(())
}

/// The file of `report.json`'s schema in `schemas/`.
const REPORT_SCHEMA: &str = "report.json";

/// Minimum number of input points for `toporec diagram`.
const MIN_POINTS: usize = 4;

fn diagram(args: DiagramArgs) -> Result<()> {
    if let Some(d) = args.dims.iter().find(|&&d| d > 2) {
        bail!("--dims: dimension {d} is not one of 0, 1, 2");
    }
    let points = match args.format {
        Some(f) => read_cloud(&args.cloud, Some(f))?,
        None if toporec::sources::logs::LogKind::detect(&args.cloud).is_some() => log_cloud(&args)?,
        None => read_cloud(&args.cloud, None)?,
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
    toporec::diagram_csv::write(&diagram, &mut std::io::stdout().lock())?;
    Ok(())
}

/// The `--index`th point cloud of a message log (MCAP, ROS 1 bag, rosbag2).
fn log_cloud(args: &DiagramArgs) -> Result<Vec<toporec::types::Point>> {
    let spec = LogSpec { topic: args.topic.clone(), ..LogSpec::path(&args.cloud) };
    let end = args.index.saturating_add(1);
    for item in spec.open_range(&args.cloud, args.index..end)? {
        match item {
            Ok(scan) if scan.message_index == Some(args.index) => return Ok(scan.points),
            Err(f) if f.message_index == Some(args.index) => bail!("{}", f.error),
            _ => {}
        }
    }
    bail!("{}: no point-cloud message with index {}", args.cloud.display(), args.index)
}

fn fit(args: FitArgs) -> Result<()> {
    if let (Some(path), Some(fraction)) = (&args.pipeline, args.sample) {
        let pipeline = Pipeline::load(path)?;
        let index = args.index.clone().unwrap_or_else(|| pipeline.index.clone());
        let (codebook, scans) = toporec::pipeline::shard::fit_sample(
            &pipeline,
            &index,
            fraction,
            toporec::flags::Threads::default().count(),
        )?;
        eprintln!(
            "codebook {} (dims {}, length {}) fitted on {scans} scans, frozen in {}",
            codebook.id(),
            codebook.spec.dims,
            codebook.len(),
            index.display()
        );
        return Ok(());
    }
    let codebook = toporec::offline::fit(&args)?;
    eprintln!(
        "codebook {} (dims {}, length {}) written to {}",
        codebook.id(),
        codebook.spec.dims,
        codebook.len(),
        args.out.as_deref().unwrap_or(std::path::Path::new("-")).display()
    );
    Ok(())
}

fn vectorize(args: VectorizeArgs) -> Result<()> {
    let mut stdout = std::io::BufWriter::new(std::io::stdout().lock());
    let (codebook, rows) = toporec::offline::vectorize(&args, &mut stdout)?;
    if let Some(out) = &args.out {
        eprintln!("{rows} descriptors (length {}) written to {}", codebook.len(), out.display());
    }
    Ok(())
}

fn revectorize(args: RevectorizeArgs) -> Result<()> {
    let r = toporec::maintenance::revectorize(&args, args.threads.count())?;
    eprintln!(
        "{}: codebook {} -> {} (length {}), {} descriptors from stored diagrams in {:.2} s ({:.0} scans/s)",
        args.index.path.display(),
        r.old_codebook.as_deref().unwrap_or("none"),
        r.codebook.id(),
        r.codebook.len(),
        r.descriptors,
        r.seconds,
        r.descriptors as f64 / r.seconds.max(1e-9)
    );
    Ok(())
}

fn compact(args: IndexArgs) -> Result<()> {
    let (merged, into) = toporec::maintenance::compact(&args.index.path)?;
    eprintln!("{}: {merged} part files merged into {into}", args.index.path.display());
    Ok(())
}

fn info(args: InfoArgs) -> Result<Done> {
    if let Some(table) = &args.files {
        let table = Some(table.as_str()).filter(|t| !t.is_empty());
        let files = toporec::info::files(&args.index.path, table, args.method.as_deref())?;
        print(&files.iter().map(|p| format!("{}\n", p.display())).collect::<String>())?;
        return Ok(Done::All);
    }
    let damage = toporec::sinks::index::damage::Damage::skipping(args.skip_damaged);
    let info = toporec::info::info_with(&args.index.path, &damage)?;
    if args.json {
        print(&(serde_json::to_string_pretty(&info)? + "\n"))?;
    } else {
        print(&info.to_string())?;
    }
    let damaged = toporec::sinks::index::holdings::held_scans(damage.found())?;
    Ok(if report_damage(&damaged) { Done::Partial } else { Done::All })
}

fn repair(args: RepairArgs) -> Result<Done> {
    let threads = args.threads.count();
    let r =
        toporec::repair::repair(&toporec::repair::RepairArgs { index: args.index.path.clone(), threads })?;
    if r.damaged.is_empty() {
        print(&format!("{}: every part is as committed; nothing to repair\n", args.index.path.display()))?;
        return Ok(Done::All);
    }
    let mut text = String::new();
    for d in &r.damaged {
        text.push_str(&format!(
            "damaged: {} ({}: {}; its commit recorded {}): {} scans\n",
            d.path,
            d.what(),
            d.found,
            d.expected,
            d.scans.len()
        ));
    }
    text.push_str(&format!(
        "{}: repaired in one commit in {:.2} s: {} scans read again from their sources, {} descriptors made from stored diagrams\n",
        args.index.path.display(),
        r.seconds,
        r.from_sources,
        r.from_diagrams
    ));
    for m in &r.imported {
        text.push_str(&format!("imported method {m}: its damaged rows cannot be rebuilt; import it again\n"));
    }
    for l in &r.lost {
        text.push_str(&format!("lost: {} (session {}): {}\n", l.scan_id, l.session, l.why));
    }
    print(&text)?;
    Ok(if r.lost.is_empty() && r.imported.is_empty() { Done::All } else { Done::Partial })
}

fn verify(args: VerifyArgs) -> Result<Done> {
    let v = toporec::maintenance::verify(&args.index.path, args.allow_orphans)?;
    print(&format!("{}: {v}\n", args.index.path.display()))?;
    Ok(if v.problems.is_empty() { Done::All } else { Done::Partial })
}
