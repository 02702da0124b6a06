//! The `toporec` command line: parses flags, runs a subcommand, maps the outcome to an exit
//! code (0 ok, 1 partial, 2 failed). Errors are printed as one line naming the file.

use crate::homology::{Diagram, alpha_persistence};
use crate::sources::{CloudFormat, read_cloud};
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
    /// Print the persistence diagram of one cloud's alpha complex as CSV (dim,birth,death).
    Diagram(DiagramArgs),
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
    /// The file format; detected from the path when omitted.
    #[arg(long, value_enum)]
    pub format: Option<CloudFormat>,
}

/// Entry point of the binary.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(&cli.log_level));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).init();
    let result = match cli.command {
        Command::Diagram(args) => diagram(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            ExitCode::from(2)
        }
    }
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
    let points = read_cloud(&args.cloud, args.format)?;
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
    write_diagram_csv(&diagram, &mut std::io::stdout().lock()).or_else(ignore_broken_pipe)?;
    Ok(())
}

fn ignore_broken_pipe(e: std::io::Error) -> std::io::Result<()> {
    if e.kind() == std::io::ErrorKind::BrokenPipe { Ok(()) } else { Err(e) }
}

/// Writes `dim,birth,death` rows; floats in shortest round-trip form, `inf` for infinity.
pub fn write_diagram_csv(d: &Diagram, out: &mut impl Write) -> std::io::Result<()> {
    let mut w = std::io::BufWriter::new(out);
    writeln!(w, "dim,birth,death")?;
    for p in d.pairs() {
        writeln!(w, "{},{:?},{:?}", p.dim, p.birth, p.death)?;
    }
    w.flush()
}
