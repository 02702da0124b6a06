//! Loop closures: `toporec loops`, from a robot's logs in one command or over an index, and the
//! online [`Detector`].
//!
//! The one command runs its stages here, one way: the sources given → the pipeline made from
//! them ([`crate::pipeline::from_sources`]) → the index, brought up to date → the loops sought
//! (`of_index`: every method's rows, thresholded, checked, scored, written) → the picture
//! (`picture`, drawn from the search's own walk, so `loops --index` draws it too). With
//! `--index` alone, the first two stages are left out.
//!
//! The index's scans are walked in time order (by timestamp, then session and scan id; scans
//! without a timestamp last). Each scan is searched against the scans before it, leaving out
//! those of its own session within `exclude_seconds` (or `exclude_scans` positions) of it, by
//! the method's own search at its default budget over those allowed scans alone
//! (the method's [`crate::methods::Searcher`], restricted to them: `matching`); the online
//! [`Detector`] does the same one scan at a time, so both give the same matches. The best
//! allowed match is a loop when its descriptor distance is below the threshold
//! (`threshold`). Each row ([`LoopRow`]) keeps the runner-up's distance (a margin for the
//! user's own checks) and, where both scans have poses, their true distance.

pub mod cloud;
pub mod detector;
mod exclusion;
pub mod icp;
pub mod map;
mod matching;
mod odometry_veto;
mod of_index;
mod picture;
mod row;
mod summary;
mod threshold;
pub mod verify;

pub use detector::{Detector, Match};
pub use exclusion::Exclusion;
pub use matching::{Allowed, rows};
pub use picture::Walked;
pub use row::{LoopRow, g2o_path};
pub(crate) use summary::progress_bar;
pub use summary::{MethodSummary, Summary};
pub use threshold::{calibrate, default_threshold};

use crate::error::{Error, Result};
use crate::pipeline::RunSummary;
use crate::pipeline::from_sources::{Made, check_default_index, default_index, made};
use crate::ranges;
use std::path::PathBuf;

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
    pub from: crate::sources::SourceOptions,
    /// The descriptor methods (repeatable; default: every method of the index; with sources,
    /// toporec-plus).
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
    /// units, > 0; default: the one calibrated for the method's settings, `info` shows it: 0.3289 for
    /// toporec-plus).
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
    /// Write each method's pose graph (g2o) to `<stem>.<method>.g2o` beside this path: where the
    /// scans have poses, the graph the map solves (vertices, odometry, kept loops); otherwise the
    /// loops' `EDGE_SE3:QUAT` lines alone. Unverified loops carry the descriptor's pose, weaker.
    #[arg(long)]
    pub g2o: Option<PathBuf>,
    /// Make no map: leave the pose graph unoptimized (by default, where the scans have poses,
    /// the loops and the odometry are optimized into corrected poses, `<output stem>.<session>.tum`
    /// and `.kitti`, and each loop's `in_map` says whether the map kept it).
    #[arg(long)]
    pub no_optimize: bool,
    /// Write the scans at the map's corrected poses (with --no-optimize, at their own poses) into
    /// one point cloud, a binary PLY for a point-cloud viewer (with several methods,
    /// `<stem>.<method>.ply` beside this path).
    #[arg(long, value_name = "FILE.ply")]
    pub cloud: Option<PathBuf>,
    /// The cloud's cell size (m, > 0): one point, the mean of those in it, per occupied cell.
    #[arg(long, default_value_t = 0.2, value_parser = ranges::positive, requires = "cloud")]
    pub cloud_voxel: f64,
    /// The steps between consecutive scans of a session in the map: `poses`, the stored poses'
    /// (the log's odometry or the pose file's), or `icp`, each step aligned again between the two
    /// raw scans from the stored one (one alignment a scan, about 1.8× the command's time on a
    /// 1,000-scan drive; it undoes an odometry's scale error, which no loop can see).
    #[arg(long, value_enum, default_value_t = map::Odometry::Poses)]
    pub odometry: map::Odometry,
    /// The odometry's drift model in the map, TRANSLATION,YAW: each step's σ is 2 cm +
    /// TRANSLATION × its length for each axis of its translation, and 0.002 rad + YAW rad a
    /// metre for its yaw. It weighs the odometry against the loops and rules out the loops
    /// that the odometry alone contradicts; the default allows for a wheel odometry's drift,
    /// and an odometry known to be better (a LiDAR odometry, ground truth) should say so: a
    /// model looser than the odometry lets a few false loops that agree with each other bend
    /// the map.
    #[arg(long, default_value = "0.02,0.005", value_name = "TRANSLATION,YAW")]
    pub odometry_drift: map::DriftModel,
    /// Which sessions' poses share a frame: auto (pose files share one; each log's own poses, and
    /// each KITTI sequence's `poses.txt`, are a frame of their own), shared or own.
    #[arg(long, value_enum, default_value_t = map::Frames::Auto)]
    pub frames: map::Frames,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
    /// Worker threads.
    #[command(flatten)]
    pub threads: crate::flags::Threads,
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

impl LoopsArgs {
    /// Whether the matches below the threshold are verified: with sources unless
    /// `--no-verify`, on an index with `--verify`.
    pub fn verifies(&self) -> bool {
        if self.sources.is_empty() { self.verify } else { !self.no_verify }
    }
}

/// What the sources were made into and how their indexing went (`loops <source>…`).
pub struct Indexed {
    /// The pipeline made.
    pub made: Made,
    /// The indexing run.
    pub run: RunSummary,
}

/// What `toporec loops` did.
pub struct Outcome {
    /// With sources: the pipeline made and the indexing run.
    pub indexed: Option<Indexed>,
    /// The loops.
    pub loops: Summary,
    /// Scans of the sessions searched, and how many have a pose.
    pub scans: (usize, usize),
    /// The picture of the loops (PNG and SVG); none for an index without poses.
    pub picture: Vec<PathBuf>,
    /// Wall seconds.
    pub seconds: f64,
}

impl Outcome {
    /// Whether some scan failed to be read, or a damaged part was left out.
    pub fn partial(&self) -> bool {
        self.indexed.as_ref().is_some_and(|i| i.run.partial()) || !self.loops.damaged.is_empty()
    }
}

/// Runs `toporec loops` on `threads` worker threads. With sources: indexes them (into
/// `a.index`, default `out/<first source's name>`), then finds the loops among their sessions,
/// verified unless `a.no_verify`. With `--index`: the loops of that index. Either way the rows
/// go to `a.out`, and the picture beside it (`<out stem>.png`, `.svg`; for an index, when its
/// scans have poses).
pub fn run(a: &LoopsArgs, threads: usize) -> Result<Outcome> {
    let start = std::time::Instant::now();
    // Said before any work, so that no output is written beside a table that cannot be.
    if a.out.is_dir() {
        return Err(Error::invalid(format!(
            "{}: is a directory; -o names the loops table's file",
            a.out.display()
        )));
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .map_err(|e| Error::invalid(format!("worker threads: {e}")))?;
    let mut args = a.clone();
    let indexed = if a.sources.is_empty() {
        None
    } else {
        let index = a.index.clone().unwrap_or_else(|| default_index(&a.sources));
        let made = made(&a.sources, &a.from, &a.methods, &index)?;
        if a.index.is_none() {
            check_default_index(&index, &made)?;
        }
        let opts = crate::pipeline::RunOptions {
            index: Some(index.clone()),
            progress: !a.no_progress,
            ..crate::pipeline::RunOptions::new(threads.max(1))
        };
        let run = crate::pipeline::run(&made.pipeline, &opts)?;
        if run.indexed == 0 {
            return Err(nothing_read(&a.sources, &run));
        }
        args.index = Some(index);
        if args.sessions.is_empty() {
            args.sessions = made.sessions.clone();
        }
        Some(Indexed { made, run })
    };
    let loops = pool.install(|| of_index::search(&args))?;
    let sessions: Vec<String> = if args.sessions.is_empty() {
        let mut all: Vec<String> = Vec::new();
        for w in &loops.walk {
            if !all.contains(&w.session) {
                all.push(w.session.clone());
            }
        }
        all.sort();
        all
    } else {
        args.sessions.clone()
    };
    let walked: Vec<&Walked> = loops.walk.iter().filter(|w| sessions.contains(&w.session)).collect();
    let scans = (walked.len(), walked.iter().filter(|w| w.pose.is_some()).count());
    let picture =
        if indexed.is_some() || scans.1 > 0 { picture::draw(&a.out, &loops, &sessions)? } else { Vec::new() };
    Ok(Outcome { indexed, loops, scans, picture, seconds: start.elapsed().as_secs_f64() })
}

/// The error of a run of `sources` that left no scan to search: every scan failed or was
/// skipped; the first reasons are given.
fn nothing_read(sources: &[PathBuf], run: &crate::pipeline::RunSummary) -> Error {
    let names: Vec<String> = sources.iter().map(|p| p.display().to_string()).collect();
    let skipped: u64 = run.skipped.values().sum();
    let mut reasons: Vec<String> = run.failures.iter().take(3).cloned().collect();
    reasons.extend(run.skipped.keys().map(|k| format!("skipped: {k}")).take(3 - reasons.len().min(3)));
    let reasons = if reasons.is_empty() { "no scan in them".to_string() } else { reasons.join("; ") };
    Error::invalid(format!(
        "{}: no scan could be read and described ({} read, {} errors, {skipped} skipped): {reasons}",
        names.join(", "),
        run.read,
        run.errors
    ))
}

impl std::fmt::Display for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let Some(Indexed { made, run }) = &self.indexed else {
            write!(f, "{}", self.loops)?;
            if !self.picture.is_empty() {
                let files: Vec<String> = self.picture.iter().map(|p| p.display().to_string()).collect();
                writeln!(f, "picture: {}", files.join(", "))?;
            }
            return Ok(());
        };
        let (scans, posed) = self.scans;
        writeln!(f, "index: {} ({} scans read, {} computed)", run.index.display(), run.read, run.computed)?;
        if run.errors > 0 || !run.skipped.is_empty() {
            let skipped: u64 = run.skipped.values().sum();
            writeln!(
                f,
                "scans: {} read, {} indexed, {skipped} skipped, {} errors",
                run.read, run.indexed, run.errors
            )?;
            for (reason, n) in &run.skipped {
                writeln!(f, "  skipped ({reason}): {n}")?;
            }
            for e in &run.failures {
                writeln!(f, "  error: {e}")?;
            }
        }
        for p in &made.poses {
            writeln!(f, "{p}")?;
        }
        for o in &run.poses {
            if let Some(w) = o.bad_lines_warning() {
                writeln!(f, "warning: {w}")?;
            }
            writeln!(
                f,
                "poses of {}: {}: {} of {} scans with a pose",
                o.sessions.join(", "),
                o.origin,
                o.with_pose,
                o.scans
            )?;
        }
        writeln!(f, "scans: {scans} in sessions {}, {posed} with a pose", made.sessions.join(", "))?;
        for m in &self.loops.methods {
            match m.verified {
                Some(checked) => writeln!(
                    f,
                    "loops ({}): {checked} matches below {:.4}, {} verified by ICP and kept",
                    m.method, m.threshold, m.accepted
                )?,
                None => writeln!(
                    f,
                    "loops ({}): {} below {:.4} (not verified)",
                    m.method, m.accepted, m.threshold
                )?,
            }
        }
        for m in &self.loops.maps {
            write!(f, "{m}")?;
        }
        for n in &self.loops.notes {
            writeln!(f, "note: {n}")?;
        }
        self.loops.fmt_written(f)?;
        writeln!(
            f,
            "picture: {}",
            self.picture.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
        )?;
        writeln!(f, "time: {:.1} s", self.seconds)
    }
}
