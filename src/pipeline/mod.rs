//! `toporec run`: the staged streaming processor.
//!
//! ```text
//!  source thread ──jobs──► worker threads ──outcomes──► ordered writer (this thread)
//!  (sources, in order)     Describer: preprocess →      reorders by seq, writes scans +
//!                          persistence (→ vectorize)    diagrams, feeds the codebook fit
//!                                                       └► fit → pass 2: descriptors → commit
//! ```
//!
//! [`run`] is its four steps: pass 1 (sources → workers → ordered writer), the codebook
//! (loaded, or fitted on pass 1's diagrams), pass 2 (descriptors from the staged diagrams,
//! when the codebook was fitted) and the commit. Channels are bounded (crossbeam), and the source may run at most a window of scans
//! ahead of the writer (a credit channel), so memory is bounded whatever the session length.
//! Outcomes are written in input order, so the index does not depend on the thread count.
//! One bad scan is one `error` row; a panic in a stage is caught and recorded the same way.

pub mod config;
mod progress;

use crate::describe::{DescribeError, Describer, StageTimes};
use crate::error::{Error, Result};
use crate::homology::Diagram;
use crate::sinks::index::IndexWriter;
use crate::sinks::index::reader::diagrams;
use crate::sinks::index::writer::ScanCounts;
use crate::sinks::parquet::{DescriptorRow, DescriptorsFile, ScanRow, Status};
use crate::sources::{Scan, ScanFailure};
use crate::types::Pose;
use crate::vectorize::codebook::{Codebook, CodebookFitter};
use config::{Pipeline, Vectorize};
use cpu_time::ThreadTime;
use crossbeam_channel::{Receiver, Sender, bounded};
use progress::Progress;
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
    /// CPU seconds per stage (worker stages summed over threads).
    pub stages: BTreeMap<&'static str, f64>,
    /// Codebook id used.
    pub codebook_id: String,
    /// Descriptor length.
    pub descriptor_len: usize,
    /// Worker threads.
    pub threads: usize,
}

impl RunSummary {
    /// Whether some scans failed.
    pub fn partial(&self) -> bool {
        self.errors > 0
    }

    fn counts(&self) -> ScanCounts {
        ScanCounts {
            read: self.read,
            indexed: self.indexed,
            skipped: self.skipped.values().sum(),
            errors: self.errors,
        }
    }

    /// The summary as JSON (`toporec run --summary-json`): counts, wall seconds and CPU
    /// seconds per stage.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "index": self.index,
            "scans": {
                "read": self.read,
                "indexed": self.indexed,
                "skipped": self.skipped,
                "errors": self.errors,
            },
            "first_errors": self.first_errors,
            "codebook_id": self.codebook_id,
            "descriptor_length": self.descriptor_len,
            "threads": self.threads,
            "wall_seconds": self.wall.as_secs_f64(),
            "cpu_seconds": self.stages,
        })
    }

    fn count(&mut self, row: &ScanRow) {
        self.read += 1;
        match row.status {
            Status::Ok => self.indexed += 1,
            Status::Skipped => {
                *self.skipped.entry("too few points after preprocessing".into()).or_default() += 1
            }
            Status::Error => {
                self.errors += 1;
                if self.first_errors.len() < 10 {
                    self.first_errors.push(row.error.clone().unwrap_or_default());
                }
            }
        }
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
        write!(f, "cpu time: {}", stages.join(", "))
    }
}

/// Runs a pipeline; the summary says what happened (check [`RunSummary::partial`]).
pub fn run(p: &Pipeline, opts: &RunOptions) -> Result<RunSummary> {
    let start = Instant::now();
    let index = opts.index.clone().unwrap_or_else(|| p.index.clone());
    let threads = opts.threads.max(1);
    let loaded = match &p.vectorize {
        Vectorize::Load(_, cb) => Some((**cb).clone()),
        Vectorize::Fit(_) => None,
    };
    let describer =
        Describer { preprocess: p.preprocess.clone(), squared: p.persistence.squared, codebook: loaded };
    let mut writer = IndexWriter::create(&index)?;
    let mut summary = RunSummary { index: index.clone(), threads, ..Default::default() };

    let pass = match index_scans(p, &describer, threads, opts.progress, &mut writer, &mut summary) {
        Ok(pass) => pass,
        Err(e) => {
            writer.abandon();
            return Err(e);
        }
    };
    let t = ThreadTime::now();
    let codebook = match (describer.codebook, pass.fitter) {
        (Some(cb), _) => cb,
        (None, Some(fitter)) => match fitter.finish() {
            Ok(cb) => cb,
            Err(e) => {
                writer.abandon();
                return Err(Error::index(
                    &index,
                    format!(
                        "no codebook could be fitted on this run's diagrams ({e}); no descriptors ({} scans read, {} indexed)",
                        summary.read, summary.indexed
                    ),
                ));
            }
        },
        (None, None) => unreachable!("a codebook is loaded or fitted"),
    };
    let fit_secs = t.elapsed().as_secs_f64();
    let mut stages = pass.stages;
    if pass.fitted {
        let (vectorize, read_back) = vectorize_pass(&mut writer, &codebook, &pass.ok_scans, threads)?;
        stages.vectorize += vectorize;
        summary.stages.insert("read back", read_back);
    }
    let t = ThreadTime::now();
    writer.commit(&codebook, &p.effective_toml(), summary.counts())?;
    let commit_secs = t.elapsed().as_secs_f64();

    summary.codebook_id = codebook.id();
    summary.descriptor_len = codebook.len();
    summary.wall = start.elapsed();
    summary.stages.extend([
        ("read", pass.read_secs),
        ("preprocess", stages.preprocess),
        ("persistence", stages.persistence),
        ("fit", fit_secs),
        ("vectorize", stages.vectorize),
        ("write", pass.write_secs + commit_secs),
    ]);
    Ok(summary)
}

/// One scan handed from the source thread to the workers.
struct Job {
    seq: u64,
    item: std::result::Result<Scan, ScanFailure>,
}

/// A worker's result for one scan.
struct Outcome {
    seq: u64,
    row: ScanRow,
    diagram: Option<Diagram>,
    descriptor: Option<crate::vectorize::codebook::Descriptor>,
    times: StageTimes,
}

/// An ok scan, as the descriptors table needs it.
type OkScan = (String, Option<i64>, Option<Pose>);

/// What pass 1 leaves for the rest of the run.
struct IndexedPass {
    /// The codebook fitter, fed every diagram (when the codebook is fitted).
    fitter: Option<CodebookFitter>,
    /// Whether descriptors still have to be made (pass 2).
    fitted: bool,
    /// The ok scans of each staged diagrams file, in the order written.
    ok_scans: Vec<(String, Vec<OkScan>)>,
    /// Worker CPU time per stage.
    stages: StageTimes,
    /// CPU seconds of the source thread and of the writer.
    read_secs: f64,
    write_secs: f64,
}

/// Pass 1: sources → workers → ordered writer. Writes `scans` and `diagrams` (and
/// `descriptors`, with a loaded codebook).
fn index_scans(
    p: &Pipeline,
    describer: &Describer,
    threads: usize,
    show_progress: bool,
    writer: &mut IndexWriter,
    summary: &mut RunSummary,
) -> Result<IndexedPass> {
    let progress = Progress::new(show_progress, || p.sources.iter().map(|s| s.count_hint()).sum());
    let window = 4 * threads + 8;
    let (job_tx, job_rx) = bounded::<Job>(2 * threads);
    let (out_tx, out_rx) = bounded::<Outcome>(2 * threads);
    let (credit_tx, credit_rx) = bounded::<()>(window);
    (0..window).for_each(|_| credit_tx.send(()).expect("capacity"));
    let fitter = match &p.vectorize {
        Vectorize::Fit(spec) => Some(CodebookFitter::new(spec.clone())),
        Vectorize::Load(..) => None,
    };
    let mut ordered =
        OrderedWriter::new(writer, summary, fitter, describer.codebook.as_ref(), &p.persistence.dims);
    let read_secs = std::thread::scope(|scope| -> Result<f64> {
        let reader = scope.spawn(|| read_sources(p, job_tx, credit_rx));
        for _ in 0..threads {
            let (rx, tx) = (job_rx.clone(), out_tx.clone());
            scope.spawn(move || {
                for job in rx {
                    if tx.send(describe(job, describer)).is_err() {
                        break;
                    }
                }
            });
        }
        drop((job_rx, out_tx));
        for outcome in out_rx {
            let written = ordered.accept(outcome)?;
            progress.tick(ordered.summary);
            // Tell the source that many more scans may start.
            for _ in 0..written {
                let _ = credit_tx.send(());
            }
        }
        Ok(reader.join().expect("source thread"))
    })?;
    progress.finish();
    ordered.finish(read_secs)
}

/// The source thread: every source's scans in order, each waiting for a credit.
fn read_sources(p: &Pipeline, jobs: Sender<Job>, credits: Receiver<()>) -> f64 {
    let t = ThreadTime::now();
    let mut seq = 0u64;
    let mut send = |item| {
        let ok = credits.recv().is_ok() && jobs.send(Job { seq, item }).is_ok();
        seq += 1;
        ok
    };
    'all: for (i, spec) in p.sources.iter().enumerate() {
        let stream = match spec.open() {
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
                if !send(Err(failure)) {
                    break 'all;
                }
                continue;
            }
        };
        for item in stream {
            if !send(item) {
                break 'all;
            }
        }
    }
    t.elapsed().as_secs_f64()
}

/// A worker's step: one scan through the [`Describer`], as a `scans` row and its results.
fn describe(job: Job, describer: &Describer) -> Outcome {
    let seq = job.seq;
    let scan = match job.item {
        Ok(scan) => scan,
        Err(f) => {
            let row = ScanRow {
                scan_id: f.id,
                session: f.session,
                seq,
                source_path: f.path.display().to_string(),
                message_index: f.message_index,
                utime: f.utime,
                pose: None,
                raw_points: 0,
                kept_points: 0,
                status: Status::Error,
                error: Some(f.error),
            };
            return Outcome { seq, row, diagram: None, descriptor: None, times: StageTimes::default() };
        }
    };
    let mut row = ScanRow {
        scan_id: scan.id.clone(),
        session: scan.session.clone(),
        seq,
        source_path: scan.path.display().to_string(),
        message_index: scan.message_index,
        utime: Some(scan.utime),
        pose: scan.pose,
        raw_points: scan.raw_points as u64,
        kept_points: 0,
        status: Status::Ok,
        error: None,
    };
    let d = describer.describe(scan);
    row.kept_points = d.kept_points as u64;
    let (diagram, descriptor) = match d.outcome {
        Ok(x) => (Some(x.diagram), x.descriptor),
        Err(e) => {
            row.status = if matches!(e, DescribeError::Skipped(_)) { Status::Skipped } else { Status::Error };
            row.error = Some(e.to_string());
            (None, None)
        }
    };
    Outcome { seq, row, diagram, descriptor, times: d.times }
}

/// The writer's side of pass 1: puts outcomes back in input order and writes them.
struct OrderedWriter<'a> {
    writer: &'a mut IndexWriter,
    summary: &'a mut RunSummary,
    fitter: Option<CodebookFitter>,
    codebook: Option<&'a Codebook>,
    dims: &'a [u8],
    pending: BTreeMap<u64, Outcome>,
    next: u64,
    descriptor_files: HashMap<String, DescriptorsFile>,
    ok_scans: Vec<(String, Vec<OkScan>)>,
    stages: StageTimes,
    write_secs: f64,
}

impl<'a> OrderedWriter<'a> {
    fn new(
        writer: &'a mut IndexWriter,
        summary: &'a mut RunSummary,
        fitter: Option<CodebookFitter>,
        codebook: Option<&'a Codebook>,
        dims: &'a [u8],
    ) -> Self {
        OrderedWriter {
            writer,
            summary,
            fitter,
            codebook,
            dims,
            pending: BTreeMap::new(),
            next: 0,
            descriptor_files: HashMap::new(),
            ok_scans: Vec::new(),
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
        self.stages += o.times;
        self.summary.count(&o.row);
        // A new staged part starts where the session changes (as in IndexWriter::write_scan).
        if self.ok_scans.last().is_none_or(|(s, _)| *s != o.row.session) {
            self.ok_scans.push((o.row.session.clone(), Vec::new()));
        }
        if let (Some(f), Some(d)) = (self.fitter.as_mut(), &o.diagram) {
            f.add(d);
        }
        if o.row.status == Status::Ok {
            let group = &mut self.ok_scans.last_mut().expect("pushed above").1;
            group.push((o.row.scan_id.clone(), o.row.utime, o.row.pose));
        }
        if let (Some(cb), Some(d)) = (self.codebook, &o.descriptor) {
            let session = &o.row.session;
            if !self.descriptor_files.contains_key(session) {
                let f = self.writer.descriptors_file(session, cb)?;
                self.descriptor_files.insert(session.clone(), f);
            }
            let row = DescriptorRow::new(o.row.scan_id.clone(), o.row.utime, o.row.pose, d);
            self.descriptor_files.get_mut(session).expect("inserted").push(row)?;
        }
        self.writer.write_scan(o.row, o.diagram.as_ref(), self.dims)
    }

    /// Closes the files of pass 1.
    fn finish(self, read_secs: f64) -> Result<IndexedPass> {
        let t = ThreadTime::now();
        self.writer.close_session()?;
        let mut files: Vec<DescriptorsFile> = self.descriptor_files.into_values().collect();
        files.sort_by(|a, b| a.session().cmp(b.session()));
        for f in files {
            self.writer.finish_descriptors(f)?;
        }
        Ok(IndexedPass {
            fitted: self.fitter.is_some(),
            fitter: self.fitter,
            ok_scans: self.ok_scans,
            stages: self.stages,
            read_secs,
            write_secs: self.write_secs + t.elapsed().as_secs_f64(),
        })
    }
}

/// Pass 2 (a codebook fitted on this run): streams each staged diagrams file back,
/// vectorizes in parallel batches and writes the descriptors in order. Returns the CPU seconds
/// spent vectorizing and reading back (decoding and writing included).
fn vectorize_pass(
    writer: &mut IndexWriter,
    codebook: &Codebook,
    ok_scans: &[(String, Vec<OkScan>)],
    threads: usize,
) -> Result<(f64, f64)> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::invalid(format!("starting {threads} threads: {e}")))?;
    let staged = writer.staged_diagrams();
    let t = ThreadTime::now();
    let mut vectorize_secs = 0.0;
    for ((session, path), (ok_session, ok)) in staged.iter().zip(ok_scans) {
        assert_eq!(session, ok_session, "staged files in step with the scans written");
        let mut file = writer.descriptors_file(session, codebook)?;
        let mut groups = diagrams(path)?.peekable();
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
            let rows: Vec<(DescriptorRow, f64)> = pool.install(|| {
                batch
                    .par_iter()
                    .map(|(scan_id, utime, pose, diagram)| {
                        let t = ThreadTime::now();
                        let d = codebook.vectorize(diagram);
                        let secs = t.elapsed().as_secs_f64();
                        (DescriptorRow::new(scan_id.to_string(), *utime, *pose, &d), secs)
                    })
                    .collect()
            });
            for (r, secs) in rows {
                vectorize_secs += secs;
                file.push(r)?;
            }
        }
        writer.finish_descriptors(file)?;
    }
    Ok((vectorize_secs, t.elapsed().as_secs_f64()))
}
