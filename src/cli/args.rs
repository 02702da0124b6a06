//! The command line's arguments, declared for clap: each maps onto the library's plain
//! struct or enum of the same name (`From`), so the library, the Python package and the Spark
//! job share those without depending on the command-line framework.

use super::ranges;
use std::path::PathBuf;
use toporec::methods::TOPOREC;
use toporec::vectorize::codebook::DimSelection;

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
    #[arg(long, default_value = TOPOREC)]
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
    pub search: toporec::methods::SearchBudget,
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

/// Settings of `eval perturbation` (its command-line arguments).
#[derive(clap::Args, Clone, Debug)]
pub struct PerturbationArgs {
    /// The index.
    #[arg(long)]
    pub index: PathBuf,
    /// Share of the scans used as queries: (0, 1].
    #[arg(long, default_value_t = 0.2, value_parser = ranges::fraction)]
    pub fraction: f64,
    /// Seed of the choice and of the jitter.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Largest N of Recall@N: [1, ∞), clamped to the database size.
    #[arg(long, default_value_t = 25, value_parser = ranges::count)]
    pub max_n: usize,
    /// Descriptor methods to compare (repeatable; default: every method the index holds that
    /// can describe a scan, i.e. not imported ones).
    #[arg(long = "method")]
    pub methods: Vec<String>,
    /// The search budget of every method: `default`, `exhaustive` or `matched:N` (see
    /// `eval places --help`).
    #[arg(long, default_value = "default")]
    pub search: toporec::methods::SearchBudget,
    /// Output folder.
    #[arg(long, short)]
    pub out: PathBuf,
}

/// Arguments of `toporec revectorize`.
#[derive(clap::Args, Clone, Debug)]
pub struct RevectorizeArgs {
    /// The index.
    #[arg(long)]
    pub index: PathBuf,
    /// Use this saved codebook (else fit one on the stored diagrams with the settings below).
    #[arg(long, conflicts_with_all = ["b", "dims", "contrast", "weighting", "kmeans", "sample_size", "seed"])]
    pub codebook: Option<PathBuf>,
    /// The settings of the codebook to fit.
    #[command(flatten)]
    pub fit: CodebookArgs,
    /// Worker threads, [1, ∞) (default: all cores).
    #[arg(long, short, value_parser = ranges::count)]
    pub threads: Option<usize>,
}

/// How to fit a codebook (`toporec fit`, `toporec revectorize`).
#[derive(clap::Args, Clone, Debug)]
pub struct CodebookArgs {
    /// Centres per codebook (the descriptor length per part): [1, 100000].
    #[arg(long, short, default_value_t = 50, value_parser = ranges::centres)]
    pub b: usize,
    /// `paper` (H2, else H1, else H0) or a list like `0,1,2` (one codebook per dimension).
    #[arg(long, default_value = "paper", value_parser = DimSelection::parse)]
    pub dims: DimSelection,
    /// ATOL contrast: gaussian, laplacian or indicator.
    #[arg(long, value_enum, default_value = "laplacian")]
    pub contrast: Contrast,
    /// ATOL weighting: cloud (sum) or iidproba (mean).
    #[arg(long, value_enum, default_value = "cloud")]
    pub weighting: Weighting,
    /// The quantiser.
    #[arg(long, value_enum, default_value = "minibatch")]
    pub kmeans: Algorithm,
    /// Points kept (uniform sample) per codebook for fitting: [1, ∞).
    #[arg(long, default_value_t = 100_000, value_parser = ranges::count)]
    pub sample_size: usize,
    /// Seed of sampling and k-means.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Arguments of `toporec fit`.
#[derive(clap::Args, Clone, Debug)]
pub struct FitArgs {
    /// Diagram CSV files (dim,birth,death) as `toporec diagram` writes them, or index folders
    /// (their diagrams tables).
    #[arg(required_unless_present = "pipeline", conflicts_with = "pipeline")]
    pub diagrams: Vec<PathBuf>,
    /// Where to write the codebook (JSON).
    #[arg(long, short, required_unless_present = "pipeline")]
    pub out: Option<PathBuf>,
    /// Instead of diagram files: fit the pipeline's codebook (its `[vectorize]` settings) on a
    /// sample of its scans and freeze it in its index, before a sharded run.
    #[arg(long, requires = "sample")]
    pub pipeline: Option<PathBuf>,
    /// With --pipeline: the fraction of scans, (0, 1], chosen by a hash of the scan id.
    #[arg(long, requires = "pipeline")]
    pub sample: Option<f64>,
    /// With --pipeline: the index to freeze the codebook in (default: the file's).
    #[arg(long, requires = "pipeline")]
    pub index: Option<PathBuf>,
    /// The codebook's settings.
    #[command(flatten)]
    pub codebook: CodebookArgs,
    /// Record that the diagrams are in radii, not squared radii.
    #[arg(long)]
    pub radius: bool,
}

/// Arguments of `toporec vectorize`.
#[derive(clap::Args, Clone, Debug)]
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

/// Arguments of `toporec import`.
#[derive(clap::Args, Clone, Debug)]
pub struct ImportArgs {
    /// The index.
    #[arg(long)]
    pub index: PathBuf,
    /// The method's name (letters, digits, `_`, `-`; not one of toporec's own methods).
    #[arg(long)]
    pub method: String,
    /// The vectors: `.parquet`, `.npy` (with `--ids`) or `.csv`.
    pub file: PathBuf,
    /// For `.npy`: the scan ids, one per line, in row order.
    #[arg(long)]
    pub ids: Option<PathBuf>,
}

/// Arguments of `toporec loops`.
#[derive(clap::Args, Debug)]
pub struct LoopsArgs {
    /// The index.
    #[arg(long)]
    pub index: PathBuf,
    /// The descriptor methods (repeatable; default: every method of the index).
    #[arg(long = "method")]
    pub methods: Vec<String>,
    /// Same-session scans closer in time than this are not loops (seconds, ≥ 0).
    #[arg(long, default_value_t = 30.0, value_parser = ranges::non_negative)]
    pub exclude_seconds: f64,
    /// Same-session scans this many positions apart or fewer are not loops (instead of
    /// --exclude-seconds).
    #[arg(long, conflicts_with = "exclude_seconds")]
    pub exclude_scans: Option<usize>,
    /// Matches with a descriptor distance below this are loops.
    #[arg(long, value_parser = ranges::finite)]
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
    #[arg(long)]
    pub verify: bool,
    /// `--verify`: the least share of the query's voxels the alignment pairs, [0, 1].
    #[arg(long, default_value_t = 0.5, value_parser = ranges::fraction, requires = "verify")]
    pub min_fitness: f64,
    /// `--verify`: the largest point-to-plane RMSE of the alignment (m, > 0).
    #[arg(long, default_value_t = 0.15, value_parser = ranges::positive, requires = "verify")]
    pub max_rmse: f64,
    /// Write the verified loops as g2o `EDGE_SE3:QUAT` lines (with `--verify` and one --method).
    #[arg(long)]
    pub g2o: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
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

/// Arguments of `toporec split`.
#[derive(clap::Args, Debug)]
pub struct SplitArgs {
    /// The NCLT session folder (holding velodyne_sync/).
    pub session: PathBuf,
    /// Every this-many-th scan goes to the map session, the others to the query session: [2, 10⁶].
    #[arg(long, default_value_t = 3, value_parser = |s: &str| ranges::count_within(s, 2, 1_000_000))]
    pub every: usize,
    /// The position of the first map scan, in [0, every).
    #[arg(long, default_value_t = 0)]
    pub first: usize,
    /// The names of the map and the query sessions.
    #[arg(long, value_delimiter = ',', num_args = 2, default_values = ["map", "query"])]
    pub names: Vec<String>,
    /// The drive's ground truth (default: groundtruth_<session>.csv found beside the session).
    #[arg(long)]
    pub groundtruth: Option<PathBuf>,
    /// Copy the scan files (default: absolute symbolic links to them).
    #[arg(long)]
    pub copy: bool,
    /// The folder the two sessions are written into.
    #[arg(long, short)]
    pub out: PathBuf,
}

impl From<SplitArgs> for toporec::split::SplitArgs {
    fn from(a: SplitArgs) -> Self {
        toporec::split::SplitArgs {
            session: a.session,
            every: a.every,
            first: a.first,
            names: (a.names[0].clone(), a.names[1].clone()),
            groundtruth: a.groundtruth,
            copy: a.copy,
            out: a.out,
        }
    }
}

/// Arguments of `toporec simulate`.
#[derive(clap::Args, Debug)]
pub struct SimulateArgs {
    /// Output folder.
    #[arg(long, short)]
    pub out: PathBuf,
    /// Formats to write.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "nclt")]
    pub format: Vec<Format>,
    /// Sessions (days) driving the same loop: [1, 1000].
    #[arg(long, default_value_t = 2, value_parser = |s: &str| ranges::count_within(s, 1, 1000))]
    pub sessions: usize,
    /// Seed of the town, routes and noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Scans per session, [1, ∞) (default: one loop).
    #[arg(long, value_parser = ranges::count)]
    pub scans: Option<usize>,
    /// Sensor model.
    #[arg(long, value_enum, default_value = "hdl32")]
    pub sensor: SensorModel,
    /// Azimuth resolution (degrees): [0.01, 10].
    #[arg(long, default_value_t = 0.2, value_parser = ranges::azimuth_resolution)]
    pub azimuth_res: f64,
    /// Driving speed (m/s): (0, ∞).
    #[arg(long, default_value_t = 10.0, value_parser = ranges::positive)]
    pub speed: f64,
    /// Scan rate (Hz): (0, ∞).
    #[arg(long, default_value_t = 10.0, value_parser = ranges::positive)]
    pub rate: f64,
    /// Blocks per side of the town: [1, 50].
    #[arg(long, default_value_t = 3, value_parser = ranges::blocks)]
    pub blocks: usize,
    /// Street spacing (m): (20, 10000].
    #[arg(long, default_value_t = 60.0, value_parser = ranges::block_size)]
    pub block_size: f64,
    /// Ground slope along x and y (dz/dx,dz/dy), each in [-1, 1].
    #[arg(long, value_delimiter = ',', default_value = "0,0", value_parser = |s: &str| ranges::within(s, -1.0, 1.0))]
    pub slope: Vec<f64>,
    /// Odd sessions drive the loop in the opposite direction.
    #[arg(long)]
    pub reverse: bool,
    /// Laps of the loop per session, [1, 1000]: even laps (2nd, 4th…) the other way, each lap
    /// `--lap-offset` metres further right, the parked cars moved between laps.
    #[arg(long, default_value_t = 1, value_parser = |s: &str| ranges::count_within(s, 1, 1000))]
    pub laps: usize,
    /// Lateral offset of each lap from the one before (m), [-20, 20].
    #[arg(long, default_value_t = 0.0, value_parser = |s: &str| ranges::within(s, -20.0, 20.0))]
    pub lap_offset: f64,
    /// Probability that a return is lost: [0, 1).
    #[arg(long, default_value_t = 0.08, value_parser = ranges::probability)]
    pub dropout: f64,
    /// Maximum range (m): (0, 10000].
    #[arg(long, default_value_t = 100.0, value_parser = |s: &str| ranges::within(s, f64::MIN_POSITIVE, 10_000.0))]
    pub max_range: f64,
    /// Range noise σ (m): [0, ∞).
    #[arg(long, default_value_t = 0.02, value_parser = ranges::non_negative)]
    pub range_noise: f64,
    /// Sensor height above the ground (m): [-100, 100].
    #[arg(long, default_value_t = 1.9, value_parser = |s: &str| ranges::within(s, -100.0, 100.0))]
    pub height: f64,
    /// Worker threads, [1, ∞) (default: all cores).
    #[arg(long, short, value_parser = ranges::count)]
    pub threads: Option<usize>,
}

/// Which k-means to run.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Algorithm {
    /// scikit-learn's `MiniBatchKMeans` (the paper's quantiser).
    #[value(name = "minibatch")]
    MiniBatch,
    /// Full-batch Lloyd iterations.
    Lloyd,
}

/// The contrast function.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Contrast {
    /// `exp(−d² / σ²)`.
    Gaussian,
    /// `exp(−d / σ)`.
    Laplacian,
    /// `clip(2 − d / σ, 0, 1)`.
    Indicator,
}

/// Per-point weights of a measure.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Weighting {
    /// Every point weighs 1 (a sum).
    Cloud,
    /// Every point weighs 1/n (a mean).
    Iidproba,
}

/// Output formats.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// NCLT layout.
    Nclt,
    /// ROS 2 MCAP.
    Mcap,
    /// KITTI odometry layout.
    Kitti,
}

/// Sensor models.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SensorModel {
    /// 32 beams, −30.67° to +10.67° (Velodyne HDL-32E, NCLT's sensor).
    Hdl32,
    /// 64 beams, −24.9° to +2° (Velodyne HDL-64E, KITTI's sensor).
    Hdl64,
    /// 16 beams, −15° to +15° (Velodyne VLP-16).
    Vlp16,
}

/// The protocols of `eval places`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Protocol {
    /// Database and query sessions, true matches within each threshold.
    Places,
    /// The PointNetVLAD benchmark (its own sets).
    Pointnetvlad,
}

impl From<QueryArgs> for toporec::query::QueryArgs {
    fn from(a: QueryArgs) -> Self {
        toporec::query::QueryArgs {
            index: a.index,
            inputs: a.inputs,
            k: a.k,
            method: a.method,
            sessions: a.sessions,
            topic: a.topic,
            skip_damaged: a.skip_damaged,
            out: a.out,
        }
    }
}

impl From<PlacesArgs> for toporec::eval::PlacesArgs {
    fn from(a: PlacesArgs) -> Self {
        toporec::eval::PlacesArgs {
            db: a.db,
            db_sessions: a.db_sessions,
            queries: a.queries,
            query_sessions: a.query_sessions,
            db_scans: a.db_scans,
            query_scans: a.query_scans,
            within_session: a.within_session,
            thresholds: a.thresholds,
            max_n: a.max_n,
            map_every: a.map_every,
            query_every: a.query_every,
            min_time_gap: a.min_time_gap,
            conditions: a.conditions,
            seed: a.seed,
            revisit_radius: a.revisit_radius,
            methods: a.methods,
            search: a.search,
            protocol: a.protocol.into(),
            skip_damaged: a.skip_damaged,
            out: a.out,
        }
    }
}

impl From<PerturbationArgs> for toporec::eval::PerturbationArgs {
    fn from(a: PerturbationArgs) -> Self {
        toporec::eval::PerturbationArgs {
            index: a.index,
            fraction: a.fraction,
            seed: a.seed,
            max_n: a.max_n,
            methods: a.methods,
            search: a.search,
            out: a.out,
        }
    }
}

impl From<RevectorizeArgs> for toporec::maintenance::RevectorizeArgs {
    fn from(a: RevectorizeArgs) -> Self {
        toporec::maintenance::RevectorizeArgs {
            index: a.index,
            codebook: a.codebook,
            fit: a.fit.into(),
            threads: a.threads,
        }
    }
}

impl From<CodebookArgs> for toporec::offline::CodebookArgs {
    fn from(a: CodebookArgs) -> Self {
        toporec::offline::CodebookArgs {
            b: a.b,
            dims: a.dims,
            contrast: a.contrast.into(),
            weighting: a.weighting.into(),
            kmeans: a.kmeans.into(),
            sample_size: a.sample_size,
            seed: a.seed,
        }
    }
}

impl From<FitArgs> for toporec::offline::FitArgs {
    fn from(a: FitArgs) -> Self {
        toporec::offline::FitArgs {
            diagrams: a.diagrams,
            out: a.out,
            pipeline: a.pipeline,
            sample: a.sample,
            index: a.index,
            codebook: a.codebook.into(),
            radius: a.radius,
        }
    }
}

impl From<VectorizeArgs> for toporec::offline::VectorizeArgs {
    fn from(a: VectorizeArgs) -> Self {
        toporec::offline::VectorizeArgs { diagrams: a.diagrams, codebook: a.codebook, out: a.out }
    }
}

impl From<ImportArgs> for toporec::import::ImportArgs {
    fn from(a: ImportArgs) -> Self {
        toporec::import::ImportArgs { index: a.index, method: a.method, file: a.file, ids: a.ids }
    }
}

impl From<LoopsArgs> for toporec::loops::LoopsArgs {
    fn from(a: LoopsArgs) -> Self {
        toporec::loops::LoopsArgs {
            index: a.index,
            methods: a.methods,
            exclude_seconds: a.exclude_seconds,
            exclude_scans: a.exclude_scans,
            threshold: a.threshold,
            threshold_from: a.threshold_from,
            calibrate: a.calibrate,
            target_precision: a.target_precision,
            revisit_radius: a.revisit_radius,
            false_beyond: a.false_beyond,
            verify: a.verify.then_some(toporec::loops::verify::Limits {
                min_fitness: a.min_fitness,
                max_rmse: a.max_rmse,
            }),
            g2o: a.g2o,
            all: a.all,
            progress: !a.no_progress,
            skip_damaged: a.skip_damaged,
            out: a.out,
        }
    }
}

impl From<SimulateArgs> for toporec::simulate::SimulateArgs {
    fn from(a: SimulateArgs) -> Self {
        toporec::simulate::SimulateArgs {
            out: a.out,
            format: a.format.into_iter().map(Into::into).collect(),
            sessions: a.sessions,
            seed: a.seed,
            scans: a.scans,
            sensor: a.sensor.into(),
            azimuth_res: a.azimuth_res,
            speed: a.speed,
            rate: a.rate,
            blocks: a.blocks,
            block_size: a.block_size,
            slope: a.slope,
            reverse: a.reverse,
            laps: a.laps,
            lap_offset: a.lap_offset,
            dropout: a.dropout,
            max_range: a.max_range,
            range_noise: a.range_noise,
            height: a.height,
            threads: a.threads,
        }
    }
}

impl From<Algorithm> for toporec::vectorize::kmeans::Algorithm {
    fn from(v: Algorithm) -> Self {
        match v {
            Algorithm::MiniBatch => toporec::vectorize::kmeans::Algorithm::MiniBatch,
            Algorithm::Lloyd => toporec::vectorize::kmeans::Algorithm::Lloyd,
        }
    }
}

impl From<Contrast> for toporec::vectorize::atol::Contrast {
    fn from(v: Contrast) -> Self {
        match v {
            Contrast::Gaussian => toporec::vectorize::atol::Contrast::Gaussian,
            Contrast::Laplacian => toporec::vectorize::atol::Contrast::Laplacian,
            Contrast::Indicator => toporec::vectorize::atol::Contrast::Indicator,
        }
    }
}

impl From<Weighting> for toporec::vectorize::atol::Weighting {
    fn from(v: Weighting) -> Self {
        match v {
            Weighting::Cloud => toporec::vectorize::atol::Weighting::Cloud,
            Weighting::Iidproba => toporec::vectorize::atol::Weighting::Iidproba,
        }
    }
}

impl From<Format> for toporec::simulate::Format {
    fn from(v: Format) -> Self {
        match v {
            Format::Nclt => toporec::simulate::Format::Nclt,
            Format::Mcap => toporec::simulate::Format::Mcap,
            Format::Kitti => toporec::simulate::Format::Kitti,
        }
    }
}

impl From<SensorModel> for toporec::simulate::SensorModel {
    fn from(v: SensorModel) -> Self {
        match v {
            SensorModel::Hdl32 => toporec::simulate::SensorModel::Hdl32,
            SensorModel::Hdl64 => toporec::simulate::SensorModel::Hdl64,
            SensorModel::Vlp16 => toporec::simulate::SensorModel::Vlp16,
        }
    }
}

impl From<Protocol> for toporec::eval::places::Protocol {
    fn from(v: Protocol) -> Self {
        match v {
            Protocol::Places => toporec::eval::places::Protocol::Places,
            Protocol::Pointnetvlad => toporec::eval::places::Protocol::Pointnetvlad,
        }
    }
}
