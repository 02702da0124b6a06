//! Work on an index's stored diagrams: fitting a codebook on them, and making the descriptors
//! of the ok scans that have none (after a fit, a resumed run, a new codebook).
//!
//! Only what a codebook reads is decoded. For the paper's rule that is H2: the diagrams files
//! are read with a row filter on `dim` (their small pages let the page index skip the rest);
//! the few scans with fewer than two finite H2 pairs — which fall back to H1, then H0 — are
//! read again, whole, in a second pass. Diagrams files are read one per thread. When a codebook
//! is fitted and then used at once (a first run, `revectorize`), the diagrams read for the fit
//! are kept in memory, up to [`CACHE_PAIRS`] pairs, so the descriptors need no second read.

use super::RunOptions;
use crate::error::{Error, Result};
use crate::homology::Diagram;
use crate::sinks::index::IndexWriter;
use crate::sinks::index::manifest::FileEntry;
use crate::sinks::index::reader::diagrams_in;
use crate::sinks::parquet::{DescriptorRow, Status};
use crate::sinks::schema::tables;
use crate::types::Pose;
use crate::vectorize::atol::AtolError;
use crate::vectorize::codebook::{Codebook, CodebookFitter, CodebookSpec, DimSelection};
use cpu_time::ThreadTime;
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};
use std::path::PathBuf;

/// The dimensions decoded first for a codebook of `dims`.
fn first_dims(dims: &DimSelection) -> Vec<u8> {
    match dims {
        DimSelection::Paper => vec![2],
        DimSelection::Dims(d) => d.clone(),
    }
}

/// What one file gave: the worker's accumulator, the scans delivered, the scans to read whole,
/// the CPU seconds it took.
type FileResult<T> = Result<(T, Vec<String>, Vec<String>, f64)>;

/// Pass A over `files` (in parallel): `work` gets every wanted scan's diagram in the first
/// dimensions, except the paper rule's fallbacks, which are returned.
fn first_pass<T: Send>(
    files: &[StoredPart],
    dims: &DimSelection,
    wanted: &(dyn Fn(&str) -> bool + Sync),
    init: &(dyn Fn() -> T + Sync),
    work: &(dyn Fn(&mut T, String, Diagram) + Sync),
) -> Vec<FileResult<T>> {
    let first = first_dims(dims);
    files
        .par_iter()
        .map(|part| {
            let t = ThreadTime::now();
            let mut acc = init();
            let (mut delivered, mut again) = (Vec::new(), Vec::new());
            let (path, bytes) = part.read()?;
            for d in diagrams_in(&path, bytes, Some(&first))? {
                let (id, diagram) = d?;
                if !wanted(&id) {
                    continue;
                }
                let fallback = *dims == DimSelection::Paper
                    && diagram.dimension(2).iter().filter(|p| p.death.is_finite()).count() < 2;
                if fallback {
                    again.push(id);
                } else {
                    work(&mut acc, id.clone(), diagram);
                    delivered.push(id);
                }
            }
            Ok((acc, delivered, again, t.elapsed().as_secs_f64()))
        })
        .collect()
}

/// Pass B (in parallel): `work` gets the whole diagram of each scan in `ids`.
fn whole_pass<T: Send>(
    files: &[StoredPart],
    ids: &HashSet<String>,
    init: &(dyn Fn() -> T + Sync),
    work: &(dyn Fn(&mut T, String, Diagram) + Sync),
) -> Vec<FileResult<T>> {
    files
        .par_iter()
        .map(|part| {
            let t = ThreadTime::now();
            let mut acc = init();
            let mut delivered = Vec::new();
            let (path, bytes) = part.read()?;
            for d in diagrams_in(&path, bytes, None)? {
                let (id, diagram) = d?;
                if ids.contains(&id) {
                    work(&mut acc, id.clone(), diagram);
                    delivered.push(id);
                }
            }
            Ok((acc, delivered, Vec::new(), t.elapsed().as_secs_f64()))
        })
        .collect()
}

fn pool(threads: usize) -> Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .map_err(|e| Error::invalid(format!("starting {threads} threads: {e}")))
}

/// A committed diagrams part, read with its bytes checked against its commit.
struct StoredPart {
    root: PathBuf,
    generation: u64,
    entry: FileEntry,
}

impl StoredPart {
    fn read(&self) -> Result<(PathBuf, bytes::Bytes)> {
        let bytes = crate::sinks::index::writer::verified(&self.root, &self.entry, self.generation)?;
        Ok((crate::sinks::index::resolve(&self.root, &self.entry.path), bytes))
    }
}

fn diagram_files(writer: &IndexWriter) -> Vec<StoredPart> {
    let (root, generation) = (writer.root().to_owned(), writer.manifest().generation);
    writer
        .manifest()
        .files_of(tables::DIAGRAMS)
        .filter(|f| !writer.dropping(&f.path))
        .map(|f| StoredPart { root: root.clone(), generation, entry: f.clone() })
        .collect()
}

/// Pairs of stored diagrams kept in memory between a fit and the descriptors made with it
/// (24 bytes each: 1.2 GB at most).
pub(crate) const CACHE_PAIRS: usize = 50_000_000;

/// The diagrams a codebook read, kept for the descriptors (in file order), when they fit in
/// [`CACHE_PAIRS`]: the scans' pairs in the dimensions that codebook reads.
pub(crate) struct Cached(Vec<(String, Diagram)>);

/// A file's fitter and, while the budget holds, the diagrams it was fed.
type Fitting = (CodebookFitter, Option<Vec<(String, Diagram)>>);

/// Fits a codebook of `spec` on the stored diagrams of every committed ok scan. The sample
/// depends only on which diagrams the index holds (not on their order), so a run resumed after
/// a crash, or one with another thread count, fits the same codebook. With `keep`, the
/// diagrams read are returned too, when they fit in memory.
pub(crate) fn fit_on_stored(
    writer: &IndexWriter,
    spec: &CodebookSpec,
    threads: usize,
    keep: bool,
) -> Result<(std::result::Result<Codebook, AtolError>, Option<Cached>)> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let ok: HashSet<&str> = writer
        .committed()
        .iter()
        .filter(|(_, c)| c.status == Status::Ok)
        .map(|(id, _)| id.as_str())
        .collect();
    let files = diagram_files(writer);
    let pool = pool(threads)?;
    let kept = AtomicUsize::new(if keep { 0 } else { CACHE_PAIRS + 1 });
    let init = || -> Fitting { (CodebookFitter::new(spec.clone()), Some(Vec::new())) };
    let work = |(f, cache): &mut Fitting, id: String, d: Diagram| {
        f.add(&d, &id);
        if kept.fetch_add(d.len(), Ordering::Relaxed) + d.len() <= CACHE_PAIRS {
            if let Some(c) = cache.as_mut() {
                c.push((id, d));
            }
        } else {
            *cache = None;
        }
    };
    let wanted = |id: &str| ok.contains(id);
    let mut fitter = CodebookFitter::new(spec.clone());
    let mut cached: Option<Vec<(String, Diagram)>> = Some(Vec::new());
    let mut delivered: HashSet<String> = HashSet::new();
    let mut again: HashSet<String> = HashSet::new();
    let mut take = |(f, c): Fitting, cached: &mut Option<Vec<(String, Diagram)>>| {
        fitter.merge(f);
        match (cached.as_mut(), c) {
            (Some(all), Some(c)) => all.extend(c),
            _ => *cached = None,
        }
    };
    for r in pool.install(|| first_pass(&files, &spec.dims, &wanted, &init, &work)) {
        let (f, d, a, _) = r?;
        take(f, &mut cached);
        delivered.extend(d);
        again.extend(a);
    }
    // Fallbacks, and scans without a pair in the first dimensions, read whole.
    again.extend(ok.iter().filter(|id| !delivered.contains(**id)).map(|id| id.to_string()));
    if !again.is_empty() && spec.dims == DimSelection::Paper {
        for r in pool.install(|| whole_pass(&files, &again, &init, &work)) {
            let (f, d, _, _) = r?;
            take(f, &mut cached);
            delivered.extend(d);
        }
    }
    // Ok scans whose stored dimensions hold no pair: empty diagrams.
    for id in ok.iter().filter(|id| !delivered.contains(**id)) {
        fitter.add(&Diagram::default(), id);
    }
    let cached = cached.filter(|_| keep && kept.load(Ordering::Relaxed) <= CACHE_PAIRS).map(Cached);
    Ok((fitter.finish(), cached))
}

/// Where a descriptor row goes and what it carries: session, utime, pose.
type Placement = (String, Option<i64>, Option<Pose>);

/// Descriptors made in one file: rows, CPU seconds vectorizing.
type Made = (Vec<(String, DescriptorRow)>, f64);

/// Descriptors for the committed ok scans that have none (after a codebook fit, a run killed
/// before its descriptors were committed, a new codebook), made from their stored diagrams and
/// committed every `opts.commit_every` scans. Returns the CPU seconds spent vectorizing and
/// reading back (decoding, writing), and the number made.
pub(crate) fn stored_descriptors(
    writer: &mut IndexWriter,
    codebook: &Codebook,
    threads: usize,
    opts: &RunOptions,
    cached: Option<Cached>,
) -> Result<(f64, f64, u64)> {
    let missing: HashMap<String, Placement> = writer
        .committed()
        .iter()
        .filter(|(_, c)| c.status == Status::Ok && !c.has_descriptor)
        .map(|(id, c)| (id.clone(), (c.session.clone(), c.utime, c.pose)))
        .collect();
    if missing.is_empty() {
        return Ok((0.0, 0.0, 0));
    }
    let pool = pool(threads)?;
    let start = ThreadTime::now();
    let files = diagram_files(writer);
    let init = || -> Made { (Vec::new(), 0.0) };
    let describe = |acc: &mut Made, id: String, diagram: &Diagram| {
        let (session, utime, pose) = &missing[&id];
        let t = ThreadTime::now();
        let v = codebook.vectorize(diagram);
        acc.1 += t.elapsed().as_secs_f64();
        acc.0.push((session.clone(), DescriptorRow::new(id, *utime, *pose, &v)));
    };
    let work = |acc: &mut Made, id: String, diagram: Diagram| describe(acc, id, &diagram);
    let wanted = |id: &str| missing.contains_key(id);
    let (mut vectorize_secs, mut files_secs) = (0.0, 0.0);
    let mut delivered: HashSet<String> = HashSet::new();
    let mut again: HashSet<String> = HashSet::new();
    let mut write = |made: Made, writer: &mut IndexWriter, delivered: &mut HashSet<String>| -> Result<()> {
        vectorize_secs += made.1;
        for (session, row) in made.0 {
            // A scan's pairs sit in one file; a second sighting would be a duplicate row.
            if delivered.insert(row.scan_id.clone()) {
                writer.write_descriptor(&session, row, codebook)?;
            }
        }
        if writer.chunk_len() >= opts.commit_every || writer.chunk_age().as_secs_f64() >= opts.commit_seconds
        {
            writer.commit()?;
        }
        Ok(())
    };
    // The diagrams the fit read, still in memory: vectorized in parallel batches, in file order.
    let from_memory = cached.is_some();
    if let Some(Cached(diagrams)) = cached {
        let wanted: Vec<(String, Diagram)> =
            diagrams.into_iter().filter(|(id, _)| missing.contains_key(id)).collect();
        for batch in wanted.chunks(4096) {
            let made: Vec<(Made, f64)> = pool.install(|| {
                batch
                    .par_chunks(64)
                    .map(|part| {
                        let t = ThreadTime::now();
                        let mut acc = init();
                        part.iter().for_each(|(id, d)| describe(&mut acc, id.clone(), d));
                        (acc, t.elapsed().as_secs_f64())
                    })
                    .collect()
            });
            for (m, secs) in made {
                files_secs += secs;
                write(m, writer, &mut delivered)?;
            }
        }
    }
    // Else the files, one per thread at a time, so memory holds one group's descriptors. (A
    // cache holds every scan with pairs: the others get empty diagrams below.)
    let files: Vec<StoredPart> = if from_memory { Vec::new() } else { files };
    for group in files.chunks(threads.max(1)) {
        for r in pool.install(|| first_pass(group, &codebook.spec.dims, &wanted, &init, &work)) {
            let (made, _, a, secs) = r?;
            files_secs += secs;
            again.extend(a);
            write(made, writer, &mut delivered)?;
        }
    }
    again.extend(missing.keys().filter(|id| !delivered.contains(*id)).cloned());
    if !again.is_empty() && codebook.spec.dims == DimSelection::Paper {
        for group in files.chunks(threads.max(1)) {
            for r in pool.install(|| whole_pass(group, &again, &init, &work)) {
                let (made, _, _, secs) = r?;
                files_secs += secs;
                write(made, writer, &mut delivered)?;
            }
        }
    }
    // Ok scans whose stored dimensions hold no pair.
    let empty = codebook.vectorize(&Diagram::default());
    let mut rest: Vec<(&String, &Placement)> =
        missing.iter().filter(|(id, _)| !delivered.contains(*id)).collect();
    rest.sort_by(|a, b| a.0.cmp(b.0));
    let rows: Vec<(String, DescriptorRow)> = rest
        .into_iter()
        .map(|(id, (session, utime, pose))| {
            (session.clone(), DescriptorRow::new(id.clone(), *utime, *pose, &empty))
        })
        .collect();
    write((rows, 0.0), writer, &mut delivered)?;
    let made = delivered.len() as u64;
    writer.commit()?;
    // Reading back: the files' decoding on the pool's threads, and this thread's writing.
    Ok((vectorize_secs, files_secs - vectorize_secs + start.elapsed().as_secs_f64(), made))
}
