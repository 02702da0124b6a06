//! `toporec run`: the staged streaming processor, incremental and crash-safe.
//!
//! ```text
//!  source thread ──jobs──► worker threads ──outcomes──► ordered writer (this thread)
//!  reads each scan, skips   Describer: preprocess →      reorders by seq, adds rows to the
//!  the up-to-date ones      persistence (→ vectorize)    open chunk, commits every N scans
//!                                                        or T seconds
//!  then: prune → fit the codebook (first run) → descriptors of ok scans without one
//! ```
//!
//! A scan is up to date when the index holds a row of the same id made from the same bytes
//! (content fingerprint) with the same settings; only the others are computed, and their old
//! rows replaced. The index's settings (preprocess, persistence) and codebook are fixed once
//! set: a run with other settings is refused unless `--full` rebuilds the index. Rows are
//! committed in chunks through [`IndexWriter`]; a run killed at any moment resumes from its
//! last commit. Channels are bounded (crossbeam), and the source may run at most a window of
//! scans ahead of the writer, so memory is bounded whatever the session length. Outcomes are
//! written in input order, so the index does not depend on the thread count. One bad scan is
//! one `error` row; a panic in a stage is caught and recorded the same way. [`shard`] splits
//! a run across processes (`--shard I/N`).

pub mod config;
pub mod from_sources;
mod progress;
pub mod shard;
mod stored;
mod summary;

pub(crate) use stored::{fit_on_stored, stored_descriptors};
pub use summary::RunSummary;

use crate::describe::{Describer, ScanResult, StageTimes};
use crate::error::{Error, Result};
use crate::sinks::index::IndexWriter;
use crate::sinks::index::writer::{CommittedScan, Joined};
use crate::sinks::parquet::Status;
use crate::sources::{Scan, ScanFailure};
use crate::vectorize::codebook::Codebook;
use config::{Pipeline, Vectorize};
use cpu_time::ThreadTime;
use crossbeam_channel::{Receiver, Sender, bounded};
use progress::Progress;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

/// Runtime options (everything else is in the pipeline file).
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Worker threads (≥ 1).
    pub threads: usize,
    /// Write the index here instead of the file's `output.index`.
    pub index: Option<PathBuf>,
    /// Show a progress bar (when stderr is a terminal) or periodic log lines.
    pub progress: bool,
    /// Rebuild the index from scratch.
    pub full: bool,
    /// Remove indexed scans that this run's sources no longer yield.
    pub prune: bool,
    /// Commit after this many scans.
    pub commit_every: u64,
    /// Commit after this many seconds.
    pub commit_seconds: f64,
    /// Index only this shard's scans, then merge them into the index ([`shard`]).
    pub shard: Option<Shard>,
}

/// One of `count` shards of a run (`--shard index/count`, index from 0).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// This shard, in 0..count.
    pub index: u32,
    /// How many shards.
    pub count: u32,
}

impl RunOptions {
    /// Defaults: all cores, progress, incremental, commits every 500 scans or 60 s.
    pub fn new(threads: usize) -> Self {
        RunOptions {
            threads,
            index: None,
            progress: true,
            full: false,
            prune: false,
            commit_every: 500,
            commit_seconds: 60.0,
            shard: None,
        }
    }
}

/// Runs a pipeline; the summary says what happened (check [`RunSummary::partial`]).
pub fn run(p: &Pipeline, opts: &RunOptions) -> Result<RunSummary> {
    match opts.shard {
        Some(s) => shard::run(p, opts, s),
        None => run_index(p, opts, None),
    }
}

/// A run into `opts.index` (or the file's); for a shard, with the main index's codebook and
/// what it holds up to date, indexing only the shard's scans.
fn run_index(p: &Pipeline, opts: &RunOptions, main: Option<&shard::MainIndex>) -> Result<RunSummary> {
    let start = Instant::now();
    let index = opts.index.clone().unwrap_or_else(|| p.index.clone());
    let threads = opts.threads.max(1);
    let settings = p.settings_hash();
    let mut writer = IndexWriter::open(&index, &settings, opts.full)?;
    let indexed_before = writer.manifest().generation > 0;
    if indexed_before && writer.manifest().settings_hash != settings {
        return Err(Error::index(&index, settings_change(&writer, p)));
    }
    let codebook = match main {
        Some(m) => m.codebook.clone(),
        None if p.methods.toporec => frozen_codebook(&writer, p, &index)?,
        None => None,
    };
    let mut methods = writer.manifest().methods.clone();
    methods.retain(|_, e| e.kind == crate::methods::IMPORTED);
    methods.extend(crate::sinks::index::manifest::MethodEntry::of_computed(&p.methods));
    writer.set_methods(methods);
    let pipeline_toml = p.effective_toml(&index);
    if let (Some(cb), false) = (&codebook, writer.manifest().codebook.is_some()) {
        writer.set_codebook(cb.clone(), Some(pipeline_toml.clone()));
    } else {
        writer.set_pipeline(pipeline_toml.clone());
    }
    let describer = Describer {
        preprocess: p.preprocess.clone(),
        squared: p.persistence.squared,
        codebook: codebook.clone(),
        topological: p.methods.toporec,
        computed: p.methods.computed.clone(),
    };
    let mut summary = RunSummary { index: index.clone(), threads, ..Default::default() };

    let pass = index_scans(p, &describer, &settings, opts, main, &mut writer, &mut summary)?;
    let mut stages = pass.stages;

    // Scans the sources no longer yield. A scan is gone only when its input was read whole: one
    // of an input that failed to be read may simply not have been reached.
    let (mut gone, mut not_read) = (Vec::new(), 0u64);
    for (id, c) in writer.committed().iter().filter(|(id, _)| !pass.seen.contains(*id)) {
        if pass.unread_source || pass.unread_sessions.contains(&c.session) {
            not_read += 1;
        } else {
            gone.push(id.clone());
        }
    }
    summary.not_read = not_read;
    if opts.prune {
        gone.iter().for_each(|id| writer.remove(id));
        writer.commit()?;
        summary.pruned = gone.len() as u64;
    } else {
        summary.not_in_sources = gone.len() as u64;
    }

    // The codebook: frozen in the index, or fitted now on every committed diagram.
    let t = ThreadTime::now();
    let (mut fit_secs, mut read_back) = (0.0, 0.0);
    if p.methods.toporec {
        let (codebook, cached) = match codebook {
            Some(cb) => (cb, None),
            None => {
                let (cb, cached) = fit_codebook(&writer, p, &index, threads)?;
                writer.set_codebook(cb.clone(), Some(pipeline_toml));
                writer.commit()?;
                (cb, cached)
            }
        };
        fit_secs = t.elapsed().as_secs_f64();
        let (vectorize, read, made) = stored_descriptors(&mut writer, &codebook, threads, opts, cached)?;
        stages.vectorize += vectorize;
        read_back = read;
        summary.descriptors_from_stored = made;
        summary.codebook_id = codebook.id();
        summary.descriptor_len = codebook.len();
        summary.methods.push((crate::methods::TOPOREC.into(), codebook.len()));
    }
    summary.methods.extend(p.methods.computed.iter().map(|m| (m.name.clone(), m.len())));
    if main.is_none() {
        summary.poses = pose_origins(p, writer.committed());
        writer.set_pose_origins(summary.poses.clone());
    }
    // A rebuild switches the index to its new generation here, in one commit.
    writer.finish()?;
    if let Some(e) = summary.poses.iter().find_map(|o| joins_nothing(o, writer.committed())) {
        return Err(Error::invalid(e));
    }
    summary.commits = writer.commits();
    summary.wall = start.elapsed();
    summary.stages = BTreeMap::from([
        ("read", pass.read_secs),
        ("preprocess", stages.preprocess),
        ("persistence", stages.persistence),
        ("fit", fit_secs),
        ("vectorize", stages.vectorize),
        ("baselines", stages.baselines),
        ("read back", read_back),
        ("write", pass.write_secs),
    ]);
    Ok(summary)
}

/// Where the sources' poses come from, each with the counts and fingerprint of the poses the
/// committed rows of its sessions carry.
fn pose_origins(p: &Pipeline, committed: &Known) -> Vec<crate::sources::poses::PoseOrigin> {
    let mut origins: Vec<_> = p.sources.iter().flat_map(|s| s.pose_origins()).collect();
    for o in &mut origins {
        let mut rows: Vec<(&String, &CommittedScan)> = committed
            .iter()
            .filter(|(_, c)| c.status != Status::Error && o.sessions.contains(&c.session))
            .collect();
        rows.sort_by(|a, b| a.0.cmp(b.0));
        let mut hash = crate::fingerprint::Streaming::default();
        for (id, c) in &rows {
            hash.write(id.as_bytes());
            hash.write(&c.utime.unwrap_or(i64::MIN).to_le_bytes());
            if let Some(p) = c.pose {
                [p.x, p.y, p.z, p.yaw].iter().for_each(|v| hash.write(&v.to_le_bytes()));
            }
        }
        o.scans = rows.len() as u64;
        o.with_pose = rows.iter().filter(|(_, c)| c.pose.is_some()).count() as u64;
        o.poses_xxh3 = crate::fingerprint::hex(hash.take());
    }
    origins
}

/// Why a pose file joined none of its sessions' scans, with both time spans; `None` when it
/// joined some (or there is no scan, or no file).
fn joins_nothing(o: &crate::sources::poses::PoseOrigin, committed: &Known) -> Option<String> {
    let file = o.file.as_ref()?;
    if o.scans == 0 || o.with_pose > 0 {
        return None;
    }
    let times = committed.values().filter(|c| o.sessions.contains(&c.session)).filter_map(|c| c.utime);
    let (first, last) = times.fold((i64::MAX, i64::MIN), |(a, b), t| (a.min(t), b.max(t)));
    let span = |s: Option<(i64, i64)>| match s {
        Some((a, b)) => format!("{:.3} s to {:.3} s", a as f64 * 1e-6, b as f64 * 1e-6),
        None => "none".into(),
    };
    let bad = match &o.bad_lines {
        (0, _) => String::new(),
        (n, first) => {
            format!("; {n} of its lines could not be read (first: {})", first.as_deref().unwrap_or_default())
        }
    };
    Some(format!(
        "{}: the pose file joins none of the {} scans of {} (scans {}, poses {}){bad}; check its clocks and \
         layout, or the join's tolerance",
        file.display(),
        o.scans,
        o.sessions.join(", "),
        span((first <= last).then_some((first, last))),
        span(o.span_us)
    ))
}

/// Why an index's settings differ from a pipeline's.
fn settings_change(writer: &IndexWriter, p: &Pipeline) -> String {
    let manifest = writer.manifest();
    let mut held: Vec<String> = manifest
        .methods
        .iter()
        .filter(|(_, e)| e.kind != crate::methods::IMPORTED)
        .map(|(m, e)| format!("{m} {}", e.id))
        .collect();
    if manifest.codebook.is_some() || manifest.descriptor_files_of(crate::methods::TOPOREC).next().is_some() {
        held.insert(0, crate::methods::TOPOREC.into());
    }
    let mut wanted: Vec<String> =
        p.methods.computed.iter().map(|m| format!("{} {}", m.name, m.id())).collect();
    wanted.sort();
    if p.methods.toporec {
        wanted.insert(0, crate::methods::TOPOREC.into());
    }
    if let Some(hint) = views_only(manifest, p) {
        return hint;
    }
    if held != wanted && manifest.counts.ok > 0 {
        format!(
            "holds the descriptor methods [{}], this pipeline asks for [{}] (or other parameters); \
             rebuild it with `toporec run --full` (every scan is recomputed)",
            held.join(", "),
            wanted.join(", ")
        )
    } else {
        "made with other preprocess or persistence settings than this pipeline's; \
         rebuild it with `toporec run --full` (every scan is recomputed)"
            .into()
    }
}

/// When the index's toporec-plus differs from the pipeline's in its lateral views alone (an
/// index made before the views were the default, its pipeline file run again): what to do.
/// The views are a search-time setting, but they are part of the method's id, so the run
/// keeps neither silently.
fn views_only(manifest: &crate::sinks::index::manifest::Manifest, p: &Pipeline) -> Option<String> {
    let name = crate::methods::toporec_plus::NAME;
    // Both as read: the index's with what its stored settings meant, every default filled in.
    let held = manifest.methods.get(name).filter(|e| e.kind == name)?.method(name)?;
    let wanted = p.methods.computed.iter().find(|m| m.name == name)?;
    let (mut held, mut wanted) = (held.params(), wanted.params());
    // An empty `lateral` is left out of the settings.
    let views = |v: Option<serde_json::Value>| v.map_or_else(|| "[]".to_string(), |v| v.to_string());
    let held_views = views(held.as_object_mut()?.remove("lateral"));
    let wanted_views = views(wanted.as_object_mut()?.remove("lateral"));
    (held == wanted && held_views != wanted_views).then(|| {
        format!(
            "its {name} was made with `lateral = {held_views}` (none was the default before [3.0]), this pipeline asks for \
             `lateral = {wanted_views}`: to keep the index's settings, write `lateral = {held_views}` in the pipeline's [{name}]; \
             to move the index to the pipeline's, `toporec run --full` (docs/loops.md, \"One toporec-plus\")",
        )
    })
}

/// The codebook the run must use: the index's (checked against the pipeline's), or the
/// pipeline's saved one for a new index; `None` when it is to be fitted on this run.
fn frozen_codebook(writer: &IndexWriter, p: &Pipeline, index: &std::path::Path) -> Result<Option<Codebook>> {
    let frozen = writer.manifest().codebook(index)?;
    match (frozen, &p.vectorize) {
        (Some(cb), Vectorize::Fit(spec)) if cb.spec != spec.clone() => Err(Error::index(
            index,
            format!(
                "its codebook {} was fitted with other [vectorize] settings than this pipeline's; \
                 switch codebooks with `toporec revectorize`, or rebuild with `toporec run --full`",
                cb.id()
            ),
        )),
        (Some(cb), Vectorize::Load(path, loaded)) if loaded.id() != cb.id() => Err(Error::index(
            index,
            format!(
                "its codebook is {}, the pipeline's ({}) is {}; switch with `toporec revectorize --codebook`",
                cb.id(),
                path.display(),
                loaded.id()
            ),
        )),
        (Some(cb), _) => Ok(Some(cb)),
        (None, Vectorize::Load(_, loaded)) => Ok(Some((**loaded).clone())),
        (None, Vectorize::Fit(_)) => Ok(None),
    }
}

/// One scan handed from the source thread to the workers.
struct Job {
    /// Order among the computed scans (the writer's reordering key).
    seq: u64,
    /// Position among all the scans the sources yielded (the `seq` column).
    position: u64,
    item: std::result::Result<Scan, ScanFailure>,
}

/// A worker's result for one scan.
struct Outcome {
    seq: u64,
    scan: ScanResult,
}

/// What the index holds for a scan, as the source thread needs it.
pub(crate) type Known = HashMap<String, CommittedScan>;

/// What pass 1 leaves for the rest of the run.
struct IndexedPass {
    /// Ids the sources yielded.
    seen: HashSet<String>,
    /// Sessions with an input that could not be read whole.
    unread_sessions: HashSet<String>,
    /// A source failed before naming its sessions.
    unread_source: bool,
    /// Worker CPU time per stage.
    stages: StageTimes,
    /// CPU seconds of the source thread and of the writer.
    read_secs: f64,
    write_secs: f64,
}

/// What the source thread found.
#[derive(Default)]
struct SourceReport {
    seen: HashSet<String>,
    /// Up-to-date scans: (status, error).
    up_to_date: Vec<(Status, Option<String>)>,
    /// Up-to-date scans whose time or pose the source now gives otherwise (its poses changed):
    /// written anew, nothing recomputed.
    rejoined: Vec<(String, Joined)>,
    added: u64,
    replaced: u64,
    duplicates: u64,
    no_pose: BTreeMap<String, u64>,
    /// Sessions with an input that could not be read whole: their scans are never pruned.
    unread_sessions: HashSet<String>,
    /// A source failed before naming its sessions: no scan is pruned.
    unread_source: bool,
    secs: f64,
}

/// Pass 1: sources → workers → ordered writer; commits chunks as it goes.
fn index_scans(
    p: &Pipeline,
    describer: &Describer,
    settings: &str,
    opts: &RunOptions,
    main: Option<&shard::MainIndex>,
    writer: &mut IndexWriter,
    summary: &mut RunSummary,
) -> Result<IndexedPass> {
    let threads = opts.threads.max(1);
    let progress = Progress::new(opts.progress, || p.sources.iter().map(|s| s.count_hint()).sum());
    let window = 4 * threads + 8;
    let (job_tx, job_rx) = bounded::<Job>(2 * threads);
    let (out_tx, out_rx) = bounded::<Outcome>(2 * threads);
    let (credit_tx, credit_rx) = bounded::<()>(window);
    (0..window).for_each(|_| credit_tx.send(()).expect("capacity"));
    let mut known = main.map(|m| m.known.clone()).unwrap_or_default();
    known.extend(writer.committed().iter().map(|(k, v)| (k.clone(), v.clone())));
    let known: Arc<Known> = Arc::new(known);
    let shard = main.map(|m| m.shard);
    let mut ordered = OrderedWriter::new(writer, summary, describer, &p.persistence.dims, opts);
    let report = std::thread::scope(|scope| -> Result<SourceReport> {
        let known = known.clone();
        let reader = scope.spawn(move || read_sources(p, settings, &known, shard, job_tx, credit_rx));
        for _ in 0..threads {
            let (rx, tx) = (job_rx.clone(), out_tx.clone());
            scope.spawn(move || {
                for job in rx {
                    if tx.send(describe(job, describer, settings)).is_err() {
                        break;
                    }
                }
            });
        }
        drop((job_rx, out_tx));
        let mut failed = None;
        for outcome in out_rx {
            match ordered.accept(outcome) {
                Ok(written) => {
                    progress.tick(ordered.summary);
                    // Tell the source that many more scans may start.
                    for _ in 0..written {
                        let _ = credit_tx.send(());
                    }
                }
                Err(e) => {
                    // Stop the source and the workers; what is committed stays.
                    failed = Some(e);
                    break;
                }
            }
        }
        drop(credit_tx);
        let report = reader.join().expect("source thread");
        match failed {
            Some(e) => Err(e),
            None => Ok(report),
        }
    })?;
    progress.finish();
    let (stages, mut write_secs) = (ordered.stages, ordered.write_secs);
    let t = ThreadTime::now();
    for (id, joined) in &report.rejoined {
        ordered.writer.rejoin(id, *joined);
    }
    ordered.writer.commit()?;
    write_secs += t.elapsed().as_secs_f64();
    for (status, error) in &report.up_to_date {
        summary.count(*status, error.as_deref());
    }
    summary.up_to_date = report.up_to_date.len() as u64;
    summary.rejoined = report.rejoined.len() as u64;
    summary.added = report.added;
    summary.replaced = report.replaced;
    summary.duplicates = report.duplicates;
    summary.no_pose = report.no_pose;
    Ok(IndexedPass {
        seen: report.seen,
        unread_sessions: report.unread_sessions,
        unread_source: report.unread_source,
        stages,
        read_secs: report.secs,
        write_secs,
    })
}

/// The source thread: every source's scans in order; the up-to-date ones are counted, the
/// others sent to the workers, each waiting for a credit.
fn read_sources(
    p: &Pipeline,
    settings: &str,
    known: &Known,
    shard: Option<Shard>,
    jobs: Sender<Job>,
    credits: Receiver<()>,
) -> SourceReport {
    let t = ThreadTime::now();
    let mut report = SourceReport::default();
    let (mut seq, mut position) = (0u64, 0u64);
    let mut consider =
        |item: std::result::Result<Scan, ScanFailure>, by_file: bool, report: &mut SourceReport| -> bool {
            let (id, fingerprint, error) = match &item {
                Ok(s) => (s.id.clone(), Some(s.fingerprint), None),
                Err(f) => (f.id.clone(), f.fingerprint, Some(f.error.clone())),
            };
            if let Some(shard) = shard {
                let key = match (&item, by_file) {
                    (Ok(s), true) => &s.session,
                    (Err(f), true) => &f.session,
                    _ => &id,
                };
                if !shard.owns(key) {
                    // Another shard's: it keeps its place in the input.
                    position += 1;
                    return true;
                }
            }
            if let Ok(Scan { no_pose: Some(why), .. }) = &item {
                *report.no_pose.entry(why.to_string()).or_default() += 1;
            }
            position += 1;
            if !report.seen.insert(id.clone()) {
                tracing::warn!("scan {id} came twice; the later one is left out");
                report.duplicates += 1;
                return true;
            }
            let fingerprint = fingerprint.map(crate::fingerprint::hex);
            let joined = item.as_ref().ok().map(|s| Joined { utime: s.utime, pose: s.pose });
            match known.get(&id) {
                Some(c)
                    if c.settings_hash == settings
                        && c.fingerprint == fingerprint
                        && (error.is_none() || c.error == error)
                        // A scan of the main index (a shard's run) is computed again instead.
                        && (shard.is_none() || joined.is_none_or(|j| j == c.joined())) =>
                {
                    report.up_to_date.push((c.status, c.error.clone()));
                    if let Some(j) = joined.filter(|j| *j != c.joined()) {
                        report.rejoined.push((id, j));
                    }
                    return true;
                }
                Some(_) => report.replaced += 1,
                None => report.added += 1,
            }
            let ok = credits.recv().is_ok() && jobs.send(Job { seq, position: position - 1, item }).is_ok();
            seq += 1;
            ok
        };
    'all: for (i, spec) in p.sources.iter().enumerate() {
        let stream = match spec.open() {
            Ok(s) => s,
            Err(e) => {
                // The sessions it would have yielded, when a listing tells; else none may be pruned.
                match spec.sessions() {
                    Ok(sessions) => report.unread_sessions.extend(sessions.into_iter().map(|(s, _)| s)),
                    Err(_) => report.unread_source = true,
                }
                let failure = ScanFailure {
                    id: format!("source[{i}]"),
                    session: format!("source-{i}"),
                    path: PathBuf::new(),
                    message_index: None,
                    utime: None,
                    fingerprint: None,
                    error: e.to_string(),
                    input_unread: true,
                };
                if !consider(Err(failure), false, &mut report) {
                    break 'all;
                }
                continue;
            }
        };
        let by_file = spec.shards_by_session();
        for item in stream {
            if let Err(f) = &item
                && f.input_unread
            {
                report.unread_sessions.insert(f.session.clone());
            }
            if !consider(item, by_file, &mut report) {
                break 'all;
            }
        }
    }
    report.secs = t.elapsed().as_secs_f64();
    report
}

/// A worker's step: one scan through the [`Describer`], as a `scans` row and its results.
fn describe(job: Job, describer: &Describer, settings: &str) -> Outcome {
    Outcome { seq: job.seq, scan: describer.scan_rows(job.item, job.position, settings) }
}

/// The writer's side of pass 1: puts outcomes back in input order and writes them.
struct OrderedWriter<'a> {
    writer: &'a mut IndexWriter,
    summary: &'a mut RunSummary,
    /// The codebook's id, when scans get their TopoRec descriptor now.
    codebook_id: Option<String>,
    /// Name and id of each computed method, in the describer's order.
    computed: Vec<(String, String)>,
    dims: &'a [u8],
    opts: &'a RunOptions,
    pending: BTreeMap<u64, Outcome>,
    next: u64,
    stages: StageTimes,
    write_secs: f64,
}

impl<'a> OrderedWriter<'a> {
    fn new(
        writer: &'a mut IndexWriter,
        summary: &'a mut RunSummary,
        describer: &Describer,
        dims: &'a [u8],
        opts: &'a RunOptions,
    ) -> Self {
        OrderedWriter {
            writer,
            summary,
            codebook_id: describer.codebook.as_ref().map(|c| c.id()),
            computed: describer.computed_ids(),
            dims,
            opts,
            pending: BTreeMap::new(),
            next: 0,
            stages: StageTimes::default(),
            write_secs: 0.0,
        }
    }

    /// Takes one outcome; writes every outcome now in order. Returns how many were written.
    fn accept(&mut self, outcome: Outcome) -> Result<usize> {
        self.pending.insert(outcome.seq, outcome);
        let mut written = 0;
        while let Some(o) = self.pending.remove(&self.next) {
            self.next += 1;
            written += 1;
            let t = ThreadTime::now();
            self.write(o)?;
            self.write_secs += t.elapsed().as_secs_f64();
        }
        Ok(written)
    }

    fn write(&mut self, o: Outcome) -> Result<()> {
        let o = o.scan;
        self.stages += o.times;
        self.summary.count(o.row.status, o.row.error.as_deref());
        self.summary.computed += 1;
        let descriptors = o.method_descriptors(self.codebook_id.as_deref(), &self.computed);
        self.writer.write_scan(o.row, o.diagram.as_ref(), self.dims, descriptors)?;
        if self.writer.chunk_len() >= self.opts.commit_every
            || self.writer.chunk_age().as_secs_f64() >= self.opts.commit_seconds
        {
            self.writer.commit()?;
        }
        Ok(())
    }
}

/// Fits the pipeline's codebook on every committed ok scan's diagram. The diagrams are not
/// kept: the vectorize pass reads them again, so a run's memory does not grow with its scans.
fn fit_codebook(
    writer: &IndexWriter,
    p: &Pipeline,
    index: &std::path::Path,
    threads: usize,
) -> Result<(Codebook, Option<stored::Cached>)> {
    let Vectorize::Fit(spec) = &p.vectorize else { unreachable!("a loaded codebook is never fitted") };
    let counts = writer.manifest().counts;
    let (codebook, cached) = fit_on_stored(writer, spec, threads, false)?;
    let codebook = codebook.map_err(|e| {
        Error::index(
            index,
            format!(
                "no codebook could be fitted on its diagrams ({e}); no descriptors ({} scans, {} ok)",
                counts.scans, counts.ok
            ),
        )
    })?;
    Ok((codebook, cached))
}
