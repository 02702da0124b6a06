//! `toporec run`: the staged streaming processor.
//!
//! ```text
//!  source thread ──jobs──► worker threads ──outcomes──► writer (this thread)
//!  (sources, in order)     preprocess → persistence       reorders by seq, writes scans +
//!                          (→ vectorize, saved codebook)  diagrams, feeds the codebook fit
//!                                                         └► pass 2: descriptors
//! ```
//!
//! Channels are bounded (crossbeam), and the source may run at most `window` scans ahead of
//! the writer (a credit channel), so memory is bounded whatever the session length. Outcomes
//! are written in input order, so the index does not depend on the thread count. When the
//! codebook is fitted on this run, descriptors come in a second pass that streams the
//! diagrams back from the staged Parquet files. One bad scan is one `error` row; a panic in
//! a stage is caught and recorded the same way.

pub mod config;

use crate::homology::{Diagram, alpha_persistence};
use crate::preprocess::{Skip, preprocess};
use crate::sinks::index::{self, IndexWriter};
use crate::sinks::parquet::{DescriptorRow, ScanRow, Status};
use crate::sources::{Scan, ScanFailure};
use crate::vectorize::codebook::{Codebook, CodebookFitter, Descriptor};
use anyhow::{Context, Result};
use config::{Pipeline, Vectorize};
use crossbeam_channel::bounded;
use rayon::prelude::*;
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Runtime options (everything else is in the pipeline file).
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Worker threads (≥ 1).
    pub threads: usize,
    /// Write the index here instead of the file's `output.index`.
    pub index: Option<PathBuf>,
    /// Show a progress bar (when stderr is a terminal) or periodic log lines.
    pub progress: bool,
}

/// What a run did.
#[derive(Clone, Debug, Default)]
pub struct RunSummary {
    /// The index folder.
    pub index: PathBuf,
    /// Scans read (every row of `scans`).
    pub read: u64,
    /// Scans indexed (status ok).
    pub indexed: u64,
    /// Skipped, by reason.
    pub skipped: BTreeMap<String, u64>,
    /// Scans that failed.
    pub errors: u64,
    /// First error messages (at most 10).
    pub first_errors: Vec<String>,
    /// Wall time.
    pub wall: Duration,
    /// Seconds per stage (worker stages summed over threads).
    pub stages: BTreeMap<&'static str, f64>,
    /// Codebook id used.
    pub codebook_id: String,
    /// Descriptor length.
    pub descriptor_len: usize,
}

impl RunSummary {
    /// Whether some scans failed.
    pub fn partial(&self) -> bool {
        self.errors > 0
    }
}

impl std::fmt::Display for RunSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let secs = self.wall.as_secs_f64();
        let skipped: u64 = self.skipped.values().sum();
        writeln!(f, "index: {}", self.index.display())?;
        writeln!(
            f,
            "scans: {} read, {} indexed, {skipped} skipped, {} errors",
            self.read, self.indexed, self.errors
        )?;
        for (reason, n) in &self.skipped {
            writeln!(f, "  skipped ({reason}): {n}")?;
        }
        for e in &self.first_errors {
            writeln!(f, "  error: {e}")?;
        }
        writeln!(f, "descriptors: length {}, codebook {}", self.descriptor_len, self.codebook_id)?;
        writeln!(f, "wall time: {secs:.2} s, {:.1} scans/s", self.read as f64 / secs.max(1e-9))?;
        let stages: Vec<String> = self.stages.iter().map(|(k, v)| format!("{k} {v:.2} s")).collect();
        write!(f, "stage time: {}", stages.join(", "))
    }
}

struct Job {
    seq: u64,
    item: Result<Scan, ScanFailure>,
}

struct Outcome {
    seq: u64,
    row: ScanRow,
    diagram: Option<Diagram>,
    descriptor: Option<Descriptor>,
    /// preprocess, persistence, vectorize seconds.
    times: [f64; 3],
}

/// Runs a pipeline; the summary says what happened (check [`RunSummary::partial`]).
pub fn run(p: &Pipeline, opts: &RunOptions) -> Result<RunSummary> {
    let start = Instant::now();
    let index_dir = opts.index.clone().unwrap_or_else(|| p.index.clone());
    let threads = opts.threads.max(1);
    let loaded: Option<&Codebook> = match &p.vectorize {
        Vectorize::Load(_, cb) => Some(cb),
        Vectorize::Fit(_) => None,
    };
    let previous_codebook = Codebook::load(&index_dir.join("codebook.json")).ok().map(|c| c.id());
    let mut writer = IndexWriter::create(&index_dir)?;
    let mut fitter = match &p.vectorize {
        Vectorize::Fit(spec) => Some(CodebookFitter::new(spec.clone())),
        Vectorize::Load(..) => None,
    };
    let mut summary = RunSummary { index: index_dir.clone(), ..Default::default() };
    let progress = Progress::new(opts.progress, || p.sources.iter().map(|s| s.count_hint()).sum());

    // Pass 1: sources → workers → ordered writer.
    let window = 4 * threads + 8;
    let (job_tx, job_rx) = bounded::<Job>(2 * threads);
    let (out_tx, out_rx) = bounded::<Outcome>(2 * threads);
    let (credit_tx, credit_rx) = bounded::<()>(window);
    (0..window).for_each(|_| credit_tx.send(()).expect("capacity"));
    let mut descriptor_files: HashMap<String, crate::sinks::parquet::DescriptorsFile> = HashMap::new();
    let mut stage = [0.0f64; 3];
    let mut write_secs = 0.0;
    let read_secs = std::thread::scope(|scope| -> Result<f64> {
        let sources = &p.sources;
        let reader = scope.spawn(move || {
            let mut seq = 0u64;
            let mut secs = 0.0;
            'all: for (i, spec) in sources.iter().enumerate() {
                let t = Instant::now();
                let opened = spec.open();
                secs += t.elapsed().as_secs_f64();
                let mut stream = match opened {
                    Ok(s) => s,
                    Err(e) => {
                        let failure = ScanFailure {
                            id: format!("source[{i}]"),
                            session: format!("source-{i}"),
                            path: PathBuf::new(),
                            message_index: None,
                            utime: None,
                            error: e.to_string(),
                        };
                        if credit_rx.recv().is_err() || job_tx.send(Job { seq, item: Err(failure) }).is_err()
                        {
                            break 'all;
                        }
                        seq += 1;
                        continue;
                    }
                };
                loop {
                    let t = Instant::now();
                    let Some(item) = stream.next() else { break };
                    secs += t.elapsed().as_secs_f64();
                    if credit_rx.recv().is_err() || job_tx.send(Job { seq, item }).is_err() {
                        break 'all;
                    }
                    seq += 1;
                }
            }
            secs
        });
        for _ in 0..threads {
            let (rx, tx) = (job_rx.clone(), out_tx.clone());
            scope.spawn(move || {
                for job in rx {
                    if tx.send(process(job, p, loaded)).is_err() {
                        break;
                    }
                }
            });
        }
        drop((job_rx, out_tx));
        let mut pending: BTreeMap<u64, Outcome> = BTreeMap::new();
        let mut next = 0u64;
        for outcome in out_rx {
            pending.insert(outcome.seq, outcome);
            while let Some(o) = pending.remove(&next) {
                next += 1;
                let t = Instant::now();
                stage.iter_mut().zip(o.times).for_each(|(s, x)| *s += x);
                account(&mut summary, &o.row);
                progress.tick(&summary);
                if let (Some(f), Some(d)) = (fitter.as_mut(), &o.diagram) {
                    f.add(d);
                }
                if let (Some(cb), Some(d)) = (loaded, o.descriptor) {
                    let session = o.row.session.clone();
                    if !descriptor_files.contains_key(&session) {
                        let f = writer.descriptors_file(&session, cb.len(), &cb.id())?;
                        descriptor_files.insert(session.clone(), f);
                    }
                    let row = DescriptorRow::new(o.row.scan_id.clone(), o.row.utime, o.row.pose, &d);
                    descriptor_files.get_mut(&session).expect("inserted").push(row)?;
                }
                writer.write_scan(o.row, o.diagram.as_ref(), &p.persistence.dims)?;
                write_secs += t.elapsed().as_secs_f64();
                // Tell the source one more scan may start.
                let _ = credit_tx.send(());
            }
        }
        Ok(reader.join().expect("source thread"))
    })?;
    writer.close_session()?;
    for (session, f) in descriptor_files {
        writer.finished("descriptors", &session, f.finish()?);
    }
    progress.finish();

    // The codebook: loaded, or fitted now on the diagrams seen (in input order).
    let t = Instant::now();
    let codebook = match (loaded, fitter) {
        (Some(cb), _) => cb.clone(),
        (None, Some(f)) => match f.finish() {
            Ok(cb) => cb,
            Err(e) => {
                let err = anyhow::anyhow!(
                    "no codebook could be fitted on this run's diagrams ({e}); no descriptors"
                );
                writer.abandon();
                return Err(err.context(format!("{} scans read, {} indexed", summary.read, summary.indexed)));
            }
        },
        (None, None) => unreachable!("fit or load"),
    };
    let fit_secs = t.elapsed().as_secs_f64();

    // Pass 2 (fitted codebook): descriptors from the staged diagrams.
    let mut vectorize_secs = stage[2];
    if loaded.is_none() {
        let t = Instant::now();
        vectorize_pass(&mut writer, &codebook, threads)?;
        vectorize_secs += t.elapsed().as_secs_f64();
    }
    let t = Instant::now();
    let manifest = manifest(&summary, &codebook, &writer);
    let extra = [
        ("codebook.json", (serde_json::to_string_pretty(&codebook.to_json())? + "\n").into_bytes()),
        ("pipeline.toml", p.effective_toml().into_bytes()),
        ("manifest.json", (serde_json::to_string_pretty(&manifest)? + "\n").into_bytes()),
    ];
    let replace_all = previous_codebook.as_deref() != Some(codebook.id().as_str());
    writer.commit(&extra, replace_all)?;
    write_secs += t.elapsed().as_secs_f64();

    summary.codebook_id = codebook.id();
    summary.descriptor_len = codebook.len();
    summary.wall = start.elapsed();
    summary.stages = BTreeMap::from([
        ("read", read_secs),
        ("preprocess", stage[0]),
        ("persistence", stage[1]),
        ("fit", fit_secs),
        ("vectorize", vectorize_secs),
        ("write", write_secs),
    ]);
    Ok(summary)
}

fn account(s: &mut RunSummary, row: &ScanRow) {
    s.read += 1;
    match row.status {
        Status::Ok => s.indexed += 1,
        Status::Skipped => *s.skipped.entry("too few points after preprocessing".into()).or_default() += 1,
        Status::Error => {
            s.errors += 1;
            if s.first_errors.len() < 10 {
                s.first_errors.push(row.error.clone().unwrap_or_default());
            }
        }
    }
}

/// One scan through preprocess → persistence (→ vectorize); never panics.
fn process(job: Job, p: &Pipeline, codebook: Option<&Codebook>) -> Outcome {
    let seq = job.seq;
    let mut row = match &job.item {
        Ok(s) => ScanRow {
            scan_id: s.id.clone(),
            session: s.session.clone(),
            seq,
            source_path: s.path.display().to_string(),
            message_index: s.message_index,
            utime: Some(s.utime),
            pose: s.pose,
            raw_points: s.raw_points as u64,
            kept_points: 0,
            status: Status::Ok,
            error: None,
        },
        Err(f) => ScanRow {
            scan_id: f.id.clone(),
            session: f.session.clone(),
            seq,
            source_path: f.path.display().to_string(),
            message_index: f.message_index,
            utime: f.utime,
            pose: None,
            raw_points: 0,
            kept_points: 0,
            status: Status::Error,
            error: Some(f.error.clone()),
        },
    };
    let mut outcome = Outcome { seq, row: row.clone(), diagram: None, descriptor: None, times: [0.0; 3] };
    let Ok(scan) = job.item else { return outcome };
    let label = format!("{}: scan {}", scan.path.display(), scan.id);
    let work = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let mut times = [0.0; 3];
        let t = Instant::now();
        let points = preprocess(scan.points, &scan.id, &p.preprocess);
        times[0] = t.elapsed().as_secs_f64();
        let points = match points {
            Ok(points) => points,
            Err(Skip(reason)) => return (Err((Status::Skipped, reason)), 0, None, None, times),
        };
        let kept = points.len() as u64;
        let t = Instant::now();
        let diagram =
            alpha_persistence(&points).map(|d| if p.persistence.squared { d } else { d.to_radii() });
        times[1] = t.elapsed().as_secs_f64();
        let diagram = match diagram {
            Ok(d) => d,
            Err(e) => return (Err((Status::Error, format!("{label}: {e}"))), kept, None, None, times),
        };
        let t = Instant::now();
        let descriptor = codebook.map(|cb| cb.vectorize(&diagram));
        times[2] = t.elapsed().as_secs_f64();
        (Ok(()), kept, Some(diagram), descriptor, times)
    }));
    match work {
        Ok((status, kept, diagram, descriptor, times)) => {
            row.kept_points = kept;
            if let Err((s, reason)) = status {
                row.status = s;
                row.error = Some(reason);
            }
            outcome = Outcome { seq, row, diagram, descriptor, times };
        }
        Err(panic) => {
            let msg = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()));
            row.status = Status::Error;
            row.error = Some(format!("{label}: internal error: {}", msg.unwrap_or_default()));
            outcome.row = row;
        }
    }
    outcome
}

/// Pass 2: streams each session's staged scans + diagrams, vectorizes in parallel batches,
/// writes descriptors in order.
fn vectorize_pass(writer: &mut IndexWriter, codebook: &Codebook, threads: usize) -> Result<()> {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build()?;
    let id = codebook.id();
    let scans = writer.files("scans");
    let diagrams = writer.files("diagrams");
    for (s, d) in scans.iter().zip(&diagrams) {
        anyhow::ensure!(s.session == d.session, "staged files out of step");
        let mut file = writer.descriptors_file(&s.session, codebook.len(), &id)?;
        let mut groups = index::diagrams(&d.path)?.peekable();
        let ok = index::ok_scans(&s.path)?;
        // Small batches: each holds its diagrams in memory.
        for chunk in ok.chunks(64) {
            let mut batch = Vec::with_capacity(chunk.len());
            for (scan_id, utime, pose) in chunk {
                // A scan whose stored dimensions hold no pair has no diagram rows.
                let diagram = match groups.peek() {
                    Some(Ok((gid, _))) if gid == scan_id => groups.next().expect("peeked")?.1,
                    Some(Err(_)) => return Err(groups.next().expect("peeked").unwrap_err()),
                    _ => Diagram::default(),
                };
                batch.push((scan_id, *utime, *pose, diagram));
            }
            let rows: Vec<DescriptorRow> = pool.install(|| {
                batch
                    .par_iter()
                    .map(|(scan_id, utime, pose, diagram)| {
                        DescriptorRow::new(scan_id.to_string(), *utime, *pose, &codebook.vectorize(diagram))
                    })
                    .collect()
            });
            for r in rows {
                file.push(r)?;
            }
        }
        let finished = file.finish().with_context(|| format!("descriptors of session {}", s.session))?;
        writer.finished("descriptors", &s.session, finished);
    }
    Ok(())
}

fn manifest(s: &RunSummary, codebook: &Codebook, writer: &IndexWriter) -> serde_json::Value {
    let files: Vec<serde_json::Value> = writer
        .written
        .iter()
        .map(|w| {
            let name = w.path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            serde_json::json!({
                "table": w.table,
                "session": w.session,
                "path": format!("{}/{}/{name}", w.table, index::partition(&w.session)),
                "rows": w.rows,
            })
        })
        .collect();
    serde_json::json!({
        "toporec_version": env!("CARGO_PKG_VERSION"),
        "schema_version": crate::sinks::schema::SCHEMA_VERSION,
        "codebook_id": codebook.id(),
        "descriptor_length": codebook.len(),
        "scans": {"read": s.read, "indexed": s.indexed, "skipped": s.skipped.values().sum::<u64>(), "errors": s.errors},
        "files": files,
    })
}

/// Progress: an indicatif spinner on a terminal, a log line every 10 s otherwise.
struct Progress {
    bar: Option<indicatif::ProgressBar>,
    start: Instant,
    last: std::cell::Cell<Instant>,
    enabled: bool,
}

impl Progress {
    /// `total`: the number of scans when the sources can tell cheaply (a bar with ETA),
    /// else a spinner.
    fn new(enabled: bool, total: impl FnOnce() -> Option<u64>) -> Self {
        use std::io::IsTerminal;
        let bar = (enabled && std::io::stderr().is_terminal()).then(|| {
            let (b, template) = match total() {
                Some(n) => (
                    indicatif::ProgressBar::new(n),
                    "{elapsed_precise} [{bar:30}] {pos}/{len} scans ({per_sec}, ETA {eta}) {msg}",
                ),
                None => (
                    indicatif::ProgressBar::new_spinner(),
                    "{spinner} {elapsed_precise} {pos} scans ({per_sec}) {msg}",
                ),
            };
            b.set_style(indicatif::ProgressStyle::with_template(template).expect("template"));
            b.enable_steady_tick(Duration::from_millis(200));
            b
        });
        Progress { bar, start: Instant::now(), last: std::cell::Cell::new(Instant::now()), enabled }
    }

    fn tick(&self, s: &RunSummary) {
        if let Some(b) = &self.bar {
            b.set_position(s.read);
            b.set_message(format!("{} indexed, {} errors", s.indexed, s.errors));
        } else if self.enabled && self.last.get().elapsed() >= Duration::from_secs(10) {
            self.last.set(Instant::now());
            let rate = s.read as f64 / self.start.elapsed().as_secs_f64();
            eprintln!(
                "toporec: {} scans read, {} indexed, {} errors, {rate:.1} scans/s",
                s.read, s.indexed, s.errors
            );
        }
    }

    fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}
