//! `toporec run <source>…` and `toporec loops <source>…`: the files a user has, indexed with no
//! pipeline file.
//!
//! Each source is whatever `inspect` recognises ([`crate::sources::Input`]): a message log, an
//! NCLT session, a KITTI sequence, a folder of clouds; its sessions are the ones `inspect` lists.
//! The pipeline is made here — the sources with the options given (`--topic`, the poses), and
//! toporec's defaults with toporec-plus, looking 3 m to either side for revisits driven back a
//! lane over (or the methods asked for) — and kept by the index as
//! every run's is: everything chosen (the topic, where the poses come from, their frames, the
//! tolerance) is written in it, so `toporec run` on it, and `toporec repair`, give the same
//! index. The index goes to `out/<first source's name>` unless `--index` says otherwise, and the
//! next call with the same sources brings it up to date (new or changed scans only). A message
//! log's poses are settled before anything is indexed: a choice that cannot be made (several
//! pose topics, a transform chain that does not reach the cloud's frame, odometry that never
//! overlaps the scans) is an error naming the file and what to pass.

use crate::error::{Error, Result};
use crate::pipeline::config::Pipeline;
use crate::sources::logs::LogSpec;
use crate::sources::poses::{PoseFormat, parse_frames};
use crate::sources::{Input, SourceSpec};
use std::path::{Path, PathBuf};

/// Where the scans of sources given on the command line take their poses and topic.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct SourceOptions {
    /// Message logs: the point-cloud topic (default: the log's only one).
    #[arg(long)]
    pub topic: Option<String>,
    /// Poses from a file instead of the log's own: TUM (`t x y z qx qy qz qw`), KITTI (3 × 4
    /// rows, with --poses-times) or NCLT (`.csv`) layout, joined by the nearest time.
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// The layout of --poses (default: `nclt` for `.csv`, `kitti` with --poses-times, else `tum`).
    #[arg(long, value_enum, requires = "poses")]
    pub poses_format: Option<PoseFormat>,
    /// With KITTI-layout --poses: the times of its rows (its `times.txt`, seconds).
    #[arg(long, requires = "poses")]
    pub poses_times: Option<PathBuf>,
    /// Message logs: the pose topic (nav_msgs/Odometry, geometry_msgs/PoseStamped or
    /// PoseWithCovarianceStamped), or `/tf` for the transform chain (default: the chain from the
    /// cloud's frame to its root when /tf moves it, else the log's only pose topic).
    #[arg(long, conflicts_with = "poses")]
    pub poses_topic: Option<String>,
    /// Message logs: `parent:child`, the transform chain from `parent` down to `child` (the
    /// cloud's frame); with --poses-topic, the frame its poses are of and the cloud's.
    #[arg(long, value_parser = parse_frames, conflicts_with = "poses")]
    pub pose_frames: Option<(String, String)>,
    /// The largest time gap of a pose join (ms, ≥ 0).
    #[arg(long, default_value_t = 100.0, value_parser = crate::ranges::non_negative)]
    pub tolerance_ms: f64,
}

/// What `run <source>…` or `loops <source>…` made: the pipeline (kept by the index), and the
/// sessions the sources hold.
pub struct Made {
    /// The pipeline.
    pub pipeline: Pipeline,
    /// Its text, as the index keeps it.
    pub text: String,
    /// The sessions the sources hold, in order.
    pub sessions: Vec<String>,
    /// Notes on the logs that hold no pose (`<log>: no poses in the log …`); where the others'
    /// come from, the run's summary says ([`crate::pipeline::RunSummary::poses`]).
    pub poses: Vec<String>,
}

/// The default index folder of `sources`: `out/<the first one's name>`.
pub fn default_index(sources: &[PathBuf]) -> PathBuf {
    let first = sources.first().map(|p| {
        let p = p.as_path();
        let name = if p.is_dir() { p.file_name() } else { p.file_stem() };
        name.map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "index".into())
    });
    PathBuf::from("out").join(first.unwrap_or_else(|| "index".into()))
}

/// Refuses the default index folder `index` (`out/<name>`) when it holds an index of other
/// sources: one none of whose sessions comes from any of `made`'s places (a log, a session
/// folder). Two sources of the same name (a copy of a session folder elsewhere, another
/// `drive.bag`) never share an index silently; the same sources, or some of them with others
/// added, reuse it incrementally.
pub fn check_default_index(index: &Path, made: &Made) -> Result<()> {
    if !index.join(crate::sinks::index::MANIFEST_FILE).is_file() {
        return Ok(());
    }
    let Ok(held) = Pipeline::of_index(index) else { return Ok(()) };
    let places = |p: &Pipeline| -> Vec<PathBuf> {
        let mut out: Vec<PathBuf> = p
            .sources
            .iter()
            .flat_map(|s| s.sessions().unwrap_or_default())
            .map(|(_, place)| std::fs::canonicalize(&place).unwrap_or(place))
            .collect();
        out.sort();
        out.dedup();
        out
    };
    let (theirs, ours) = (places(&held), places(&made.pipeline));
    if theirs.is_empty() || ours.iter().any(|p| theirs.contains(p)) {
        return Ok(());
    }
    let list = |v: &[PathBuf]| v.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ");
    Err(Error::index(
        index,
        format!(
            "holds the index of {}, not of {}: give --index DIR for this source's own index (or remove {})",
            list(&theirs),
            list(&ours),
            index.display()
        ),
    ))
}

/// The pipeline of `sources` with `options`, computing `methods` (toporec-plus when empty),
/// into `index`; its logs' poses settled (an error names the file and what to pass).
pub fn pipeline(
    sources: &[PathBuf],
    options: &SourceOptions,
    methods: &[String],
    index: &Path,
) -> Result<Made> {
    if sources.is_empty() {
        return Err(Error::invalid("no source given"));
    }
    let mut specs = Vec::new();
    let mut poses = Vec::new();
    for path in sources {
        // Absolute: the pipeline is anchored at the index, wherever the command ran.
        let path = &std::path::absolute(path).unwrap_or_else(|_| path.clone());
        let input = Input::detect(path)?;
        let Some(spec) = input.source(options.topic.as_deref()) else {
            return Err(Error::invalid(format!(
                "{}: a single cloud file, not a source of scans (a folder of them is one)",
                path.display()
            )));
        };
        let spec = match spec.get::<LogSpec>() {
            Some(log) => {
                let (spec, said) = settle_log_poses(log, path, options)?;
                poses.extend(said);
                spec
            }
            None if options.poses.is_some()
                || options.poses_topic.is_some()
                || options.pose_frames.is_some() =>
            {
                return Err(Error::invalid(format!(
                    "{}: a {}: --poses, --poses-topic and --pose-frames are for message logs (its own poses are read)",
                    path.display(),
                    input.name()
                )));
            }
            None => spec,
        };
        specs.push(spec);
    }
    let mut doc = toml::Table::new();
    let index = std::path::absolute(index).unwrap_or_else(|_| index.to_owned());
    doc.insert(
        "output".into(),
        toml::Value::Table(toml::Table::from_iter([(
            "index".to_string(),
            toml::Value::String(index.display().to_string()),
        )])),
    );
    let tables: Vec<toml::Value> = specs.iter().map(|s| toml::Value::Table(s.table())).collect();
    doc.insert("sources".into(), toml::Value::Array(tables));
    let methods: Vec<String> = if methods.is_empty() {
        vec![crate::methods::toporec_plus::NAME.to_string()]
    } else {
        methods.to_vec()
    };
    // toporec-plus looks sideways too: a robot's own log holds its revisits driven back a lane
    // over (docs/loops.md).
    if methods.iter().any(|m| m == crate::methods::toporec_plus::NAME) {
        let lateral = crate::methods::toporec_plus::PlusParams::for_loops().lateral;
        doc.insert(
            crate::methods::toporec_plus::NAME.into(),
            toml::Value::Table(toml::Table::from_iter([(
                "lateral".to_string(),
                toml::Value::Array(lateral.into_iter().map(toml::Value::Float).collect()),
            )])),
        );
    }
    doc.insert(
        "descriptors".into(),
        toml::Value::Table(toml::Table::from_iter([(
            "methods".to_string(),
            toml::Value::Array(methods.into_iter().map(toml::Value::String).collect()),
        )])),
    );
    let text = toml::to_string(&doc).expect("plain data");
    let pipeline = Pipeline::parse(&text, &index.join(crate::sinks::index::PIPELINE_FILE))?;
    let mut sessions = Vec::new();
    for s in &pipeline.sources {
        sessions.extend(s.sessions()?.into_iter().map(|(name, _)| name));
    }
    let text = pipeline.effective_toml(&index);
    Ok(Made { pipeline, text, sessions, poses })
}

/// A log's spec with its poses settled: the file given, or the log's own as the keys choose or
/// as found, written as explicit keys (so the pipeline says what was chosen). Returns the
/// spec and, when the log holds no pose, a note saying so.
fn settle_log_poses(log: &LogSpec, path: &Path, o: &SourceOptions) -> Result<(SourceSpec, Option<String>)> {
    let mut spec = LogSpec { tolerance_ms: o.tolerance_ms, ..log.clone() };
    if let Some(file) = &o.poses {
        let format =
            o.poses_format.unwrap_or(match (file.extension().and_then(|e| e.to_str()), &o.poses_times) {
                (_, Some(_)) => PoseFormat::Kitti,
                (Some(e), _) if e.eq_ignore_ascii_case("csv") => PoseFormat::Nclt,
                _ => PoseFormat::Tum,
            });
        spec.poses = Some(std::path::absolute(file).unwrap_or_else(|_| file.clone()));
        spec.poses_format = format;
        spec.poses_times =
            o.poses_times.as_ref().map(|t| std::path::absolute(t).unwrap_or_else(|_| t.clone()));
        // Read now: a file that holds no pose of its layout is an error, not a run without poses.
        crate::sources::poses::read_nonempty(file, format, o.poses_times.as_deref(), Some(0))?;
        return Ok((SourceSpec::new(spec), None));
    }
    spec.poses_topic = o.poses_topic.clone();
    spec.pose_frames = o.pose_frames.as_ref().map(|(a, b)| format!("{a}:{b}"));
    let (gathered, choice) = spec.pose_choice(path)?;
    let said = match &choice {
        None => {
            Some(format!("{}: no poses in the log (give --poses FILE for loop distances)", path.display()))
        }
        Some(c) => {
            let tol = (o.tolerance_ms * 1e6).round() as i64;
            gathered.check_overlap(path, c, tol)?;
            let keys = c.keys();
            spec.poses_topic = keys.topic;
            spec.pose_frames = keys.frames.map(|(a, b)| format!("{a}:{b}"));
            None
        }
    };
    Ok((SourceSpec::new(spec), said))
}

/// What `toporec loops <source>…` did.
pub struct Loops {
    /// The pipeline made.
    pub made: Made,
    /// The indexing run.
    pub run: crate::pipeline::RunSummary,
    /// The loops.
    pub loops: crate::loops::Summary,
    /// Scans of the sources' sessions in the index, and how many have a pose.
    pub scans: (usize, usize),
    /// The picture of the loops (PNG and SVG).
    pub picture: Vec<PathBuf>,
    /// Wall seconds.
    pub seconds: f64,
}

/// `toporec loops <source>…`: indexes `a.sources` (into `a.index`, default
/// [`default_index`]), then finds the loops among their sessions, verified unless
/// `a.no_verify`, writes them to `a.out` and draws them beside it (`<out stem>.png`, `.svg`).
pub fn loops(a: &crate::loops::LoopsArgs, threads: usize) -> Result<Loops> {
    let start = std::time::Instant::now();
    let index = a.index.clone().unwrap_or_else(|| default_index(&a.sources));
    let made = pipeline(&a.sources, &a.from, &a.methods, &index)?;
    if a.index.is_none() {
        check_default_index(&index, &made)?;
    }
    let opts = crate::pipeline::RunOptions {
        index: Some(index.clone()),
        progress: !a.no_progress,
        ..crate::pipeline::RunOptions::new(threads)
    };
    let run = crate::pipeline::run(&made.pipeline, &opts)?;
    if run.indexed == 0 {
        return Err(nothing_read(&a.sources, &run));
    }
    let mut args = a.clone();
    args.index = Some(index.clone());
    if args.sessions.is_empty() {
        args.sessions = made.sessions.clone();
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::invalid(format!("worker threads: {e}")))?;
    let summary = pool.install(|| crate::loops::run(&args))?;
    // The picture: each session's trajectory, or its walking order when no scan has a pose.
    let records = crate::sinks::index::IndexReader::open(&index)?.scans()?;
    let chosen: Vec<&crate::sinks::parquet::ScanRow> = records
        .iter()
        .filter(|r| r.status == crate::sinks::parquet::Status::Ok && args.sessions.contains(&r.session))
        .collect();
    let with_pose = chosen.iter().filter(|r| r.pose.is_some()).count();
    let ordered = with_pose == 0;
    let mut walk: Vec<&&crate::sinks::parquet::ScanRow> = chosen.iter().collect();
    walk.sort_by_key(|r| (r.utime.is_none(), r.utime, r.session.clone(), r.scan_id.clone()));
    let place: std::collections::HashMap<&str, [f64; 2]> = walk
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let p = match (&r.pose, ordered) {
                (Some(p), false) => [p.x, p.y],
                (None, false) => [f64::NAN; 2],
                (_, true) => [i as f64, 0.0],
            };
            (r.scan_id.as_str(), p)
        })
        .collect();
    let mut tracks: Vec<(String, Vec<[f64; 2]>)> = Vec::new();
    for session in &args.sessions {
        let track =
            walk.iter().filter(|r| &r.session == session).map(|r| place[r.scan_id.as_str()]).collect();
        tracks.push((session.clone(), track));
    }
    let edges: Vec<crate::plot::LoopEdge> = summary
        .checked
        .iter()
        .filter_map(|r| {
            let (from, to) = (place.get(r.query_scan.as_str())?, place.get(r.matched_scan.as_str())?);
            Some(crate::plot::LoopEdge { from: *from, to: *to, kept: r.accepted })
        })
        .collect();
    let methods: Vec<&str> = summary.methods.iter().map(|m| m.method.as_str()).collect();
    let title = if ordered {
        format!("loops ({}): no poses, scans in walking order", methods.join(", "))
    } else {
        format!("loops ({})", methods.join(", "))
    };
    let picture = crate::plot::loops_map(&a.out.with_extension(""), &title, &tracks, &edges, ordered)?;
    Ok(Loops {
        made,
        run,
        loops: summary,
        scans: (chosen.len(), with_pose),
        picture,
        seconds: start.elapsed().as_secs_f64(),
    })
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

impl std::fmt::Display for Loops {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (scans, posed) = self.scans;
        writeln!(
            f,
            "index: {} ({} scans read, {} computed)",
            self.run.index.display(),
            self.run.read,
            self.run.computed
        )?;
        let run = &self.run;
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
        for p in &self.made.poses {
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
        writeln!(f, "scans: {scans} in sessions {}, {posed} with a pose", self.made.sessions.join(", "))?;
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
        for n in &self.loops.notes {
            writeln!(f, "note: {n}")?;
        }
        for g in &self.loops.g2o {
            writeln!(f, "g2o edges written: {}", g.display())?;
        }
        writeln!(
            f,
            "picture: {}",
            self.picture.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
        )?;
        write!(f, "time: {:.1} s", self.seconds)
    }
}
