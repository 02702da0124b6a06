//! The command line's own arguments: those of the commands that drive the binary rather than
//! a library call with options of its own (`run`, `info`, `verify`, `diagram`, …). The other
//! commands take the library's option types, which carry their clap declarations
//! (`toporec::query::QueryArgs`, `toporec::eval::PlacesArgs`, …): each option and its doc live
//! in one place.

use std::path::PathBuf;
use toporec::ranges;

/// An index folder.
#[derive(clap::Args, Debug)]
pub struct IndexArgs {
    /// The index.
    #[command(flatten)]
    pub index: toporec::flags::IndexFlag,
}

/// Arguments of `toporec info`.
#[derive(clap::Args, Debug)]
pub struct InfoArgs {
    /// The index.
    #[command(flatten)]
    pub index: toporec::flags::IndexFlag,
    /// Print as JSON.
    #[arg(long, conflicts_with = "files")]
    pub json: bool,
    /// Print the committed files (absolute paths, one per line) instead: all of them, or
    /// those of one table (`scans`, `diagrams`, `descriptors`).
    #[arg(long, value_name = "TABLE", num_args = 0..=1, default_missing_value = "")]
    pub files: Option<String>,
    /// With `--files descriptors`: only this method's files.
    #[arg(long, requires = "files")]
    pub method: Option<String>,
    /// Count the scans of the intact parts when some part fails its checksum (each damaged
    /// part named; exit 1).
    #[arg(long)]
    pub skip_damaged: bool,
}

/// Arguments of `toporec verify`.
#[derive(clap::Args, Debug)]
pub struct VerifyArgs {
    /// The index.
    #[command(flatten)]
    pub index: toporec::flags::IndexFlag,
    /// Report part files no commit names (a writer at work, or killed) as notes, not problems.
    #[arg(long)]
    pub allow_orphans: bool,
}

/// Arguments of `toporec run`.
#[derive(clap::Args, Debug)]
pub struct RunArgs {
    /// The pipeline file (TOML); or logs, sessions and folders to index with no pipeline file
    /// (what `inspect` reads; the index goes to `out/<first source's name>` unless --index says
    /// otherwise, and the pipeline made is printed and kept by the index).
    #[arg(value_name = "PIPELINE.toml | SOURCE", default_value = "pipelines/sample.toml")]
    pub inputs: Vec<PathBuf>,
    /// With sources: the descriptor methods (repeatable; default: toporec-plus).
    #[arg(long = "method")]
    pub methods: Vec<String>,
    /// With sources: where their scans take their poses and topic.
    #[command(flatten)]
    pub from: toporec::sources::SourceOptions,
    /// Worker threads.
    #[command(flatten)]
    pub threads: toporec::flags::Threads,
    /// Write the index here instead of the file's `output.index` (with sources, instead of
    /// `out/<first source's name>`).
    #[arg(long)]
    pub index: Option<PathBuf>,
    /// No progress bar or progress lines.
    #[arg(long)]
    pub no_progress: bool,
    /// Also write the run's summary as JSON (counts, wall and CPU seconds per stage) here.
    #[arg(long)]
    pub summary_json: Option<PathBuf>,
    /// Rebuild the index from scratch (needed when preprocess or persistence settings change).
    #[arg(long)]
    pub full: bool,
    /// Remove indexed scans this run's sources no longer yield (without it they are kept and
    /// reported).
    #[arg(long)]
    pub prune: bool,
    /// Commit after this many scans: [1, ∞).
    #[arg(long, default_value_t = 500, value_parser = clap::value_parser!(u64).range(1..))]
    pub commit_every: u64,
    /// Commit after this many seconds: (0, ∞).
    #[arg(long, default_value_t = 60.0, value_parser = ranges::positive)]
    pub commit_seconds: f64,
    /// Index only shard I of N (I from 0: `0/4` .. `3/4`), then merge it into the index; the
    /// shards of one job may run at once. Needs the index's codebook (`toporec fit --pipeline`).
    #[arg(long, value_parser = toporec::pipeline::Shard::parse)]
    pub shard: Option<toporec::pipeline::Shard>,
}

/// Arguments of `toporec plot diagram`.
#[derive(clap::Args, Debug)]
pub struct PlotDiagramArgs {
    /// The index.
    #[command(flatten)]
    pub index: toporec::flags::IndexFlag,
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

/// Arguments of `toporec diagram`.
#[derive(clap::Args, Debug)]
pub struct DiagramArgs {
    /// The cloud: .csv (header x,y,z), KITTI .bin, NCLT velodyne_sync .bin, .pcd, .ply; or a
    /// message log (MCAP, ROS 1 bag, rosbag2 folder or .db3) with --index.
    pub cloud: PathBuf,
    /// Dimensions to print, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "0,1,2")]
    pub dims: Vec<u8>,
    /// Print radii instead of squared radii (GUDHI's output_squared_values=False).
    #[arg(long)]
    pub radius: bool,
    /// The file format; detected from the path when omitted (MCAP by its magic).
    #[arg(long, value_enum)]
    pub format: Option<toporec::sources::CloudFormat>,
    /// MCAP or bag: the Nth point-cloud message (0-based) of the topic.
    #[arg(long, default_value_t = 0)]
    pub index: u64,
    /// MCAP or bag: the topic (default: its only point-cloud topic).
    #[arg(long)]
    pub topic: Option<String>,
}

/// Arguments of `toporec repair`.
#[derive(clap::Args, Debug)]
pub struct RepairArgs {
    /// The index.
    #[command(flatten)]
    pub index: toporec::flags::IndexFlag,
    /// Worker threads.
    #[command(flatten)]
    pub threads: toporec::flags::Threads,
}
