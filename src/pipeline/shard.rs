//! Runs split across processes or machines: `toporec run --shard I/N` for batch schedulers
//! (Slurm arrays, Kubernetes indexed jobs), and `toporec fit --pipeline` that fits the one
//! codebook every shard uses.
//!
//! A shard takes the scans whose key hashes to it: `xxh3(scan id) mod N = I` (MCAP: the
//! session, so a log file is read by one shard only). The scan id is known before the scan's
//! bytes are decoded and never changes for a file, so the split is deterministic and a re-run
//! of a shard meets the same scans. Every scan keeps its position in the whole input as its
//! `seq`.
//!
//! Concurrency: per-shard indexes plus a merge, not a shared writer. Shard `I` of `N` indexes
//! into `INDEX/shards/I-of-N/` — an ordinary index with its own lock, chunked commits and crash
//! recovery, using the main index's frozen codebook and skipping what the main index already
//! holds up to date — and then merges it into `INDEX` under the main index's lock, waiting for
//! its turn: its files are hard-linked in under new part numbers and one manifest commit
//! publishes them, replacing any rows of the same scans. Shards never write the same file, the
//! lock is held only for the merge (seconds), a killed shard loses nothing committed to its
//! folder (re-run it), and a shard killed between the merge's commit and the removal of its
//! folder re-merges the same rows harmlessly.

use super::config::{Pipeline, Vectorize};
use super::{RunOptions, RunSummary, Shard};
use crate::describe::Describer;
use crate::error::{Error, Result, ResultExt};
use crate::sinks::index::MANIFEST_FILE;
use crate::sinks::index::manifest::{Manifest, MethodEntry};
use crate::sinks::index::writer::{IndexWriter, committed_scans};
use crate::vectorize::codebook::{Codebook, CodebookFitter};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

impl Shard {
    /// Parses `I/N` (0 ≤ I < N).
    pub fn parse(s: &str) -> std::result::Result<Shard, String> {
        let (i, n) = s.split_once('/').ok_or_else(|| format!("`{s}`: expected I/N, like 0/4"))?;
        let (index, count): (u32, u32) = match (i.trim().parse(), n.trim().parse()) {
            (Ok(i), Ok(n)) => (i, n),
            _ => return Err(format!("`{s}`: expected I/N with whole numbers, like 0/4")),
        };
        if count == 0 || index >= count {
            return Err(format!("`{s}`: the shard index I counts from 0 and is less than N"));
        }
        Ok(Shard { index, count })
    }

    /// Whether a scan of key `key` (its id; MCAP: its session) is this shard's.
    pub fn owns(&self, key: &str) -> bool {
        crate::fingerprint::of_bytes(key.as_bytes()) % self.count as u64 == self.index as u64
    }

    /// The shard's own index folder inside the main index.
    pub fn dir(&self, main: &Path) -> PathBuf {
        main.join("shards").join(format!("{}-of-{}", self.index, self.count))
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// What a shard takes from the main index.
pub(super) struct MainIndex {
    pub(super) shard: Shard,
    pub(super) codebook: Option<Codebook>,
    pub(super) known: super::Known,
}

/// `toporec run --shard`: index this shard's scans into its folder, then merge it.
pub(super) fn run(p: &Pipeline, opts: &RunOptions, shard: Shard) -> Result<RunSummary> {
    let start = Instant::now();
    let main = opts.index.clone().unwrap_or_else(|| p.index.clone());
    if opts.full || opts.prune {
        return Err(Error::invalid(
            "--shard with --full or --prune: rebuild or prune the index in one unsharded run",
        ));
    }
    let needs = "a sharded run needs the index's codebook first: `toporec fit --pipeline FILE --sample F` (or one unsharded run)";
    let settings = p.settings_hash();
    freeze_saved_codebook(p, &main, &settings)?;
    let manifest = Manifest::load(&main.join(MANIFEST_FILE))?.ok_or_else(|| Error::index(&main, needs))?;
    if manifest.settings_hash != settings {
        return Err(Error::index(
            &main,
            format!(
                "made with settings {}, this pipeline has {settings}: every shard must run the index's pipeline",
                manifest.settings_hash
            ),
        ));
    }
    let codebook = match p.methods.toporec {
        true => Some(manifest.codebook(&main)?.ok_or_else(|| Error::index(&main, needs))?),
        false => None,
    };
    if let (Vectorize::Load(path, wanted), Some(held)) = (&p.vectorize, &codebook)
        && wanted.id() != held.id()
    {
        return Err(Error::index(
            &main,
            format!(
                "holds codebook {}, the pipeline asks for {} ({}); switch codebooks with `toporec revectorize`",
                held.id(),
                wanted.id(),
                path.display()
            ),
        ));
    }
    let known = committed_scans(&main, &manifest, &Default::default())?;
    let dir = shard.dir(&main);
    let shard_opts = RunOptions { index: Some(dir.clone()), shard: None, ..opts.clone() };
    let context = MainIndex { shard, codebook, known };
    let mut summary = super::run_index(p, &shard_opts, Some(&context))?;
    // The merge: one commit under the main index's lock, shards taking turns.
    let t = Instant::now();
    let mut writer = IndexWriter::open_waiting(&main, &settings)?;
    let merged = writer.absorb(&dir)?;
    writer.commit()?;
    drop(writer);
    std::fs::remove_dir_all(&dir).at(&dir)?;
    let _ = std::fs::remove_dir(main.join("shards"));
    tracing::info!(shard = %shard, scans = merged, "shard merged into {}", main.display());
    summary.stages.insert("merge", t.elapsed().as_secs_f64());
    summary.index = main;
    summary.wall = start.elapsed();
    Ok(summary)
}

/// A pipeline that needs no fitted codebook — it names a saved one (`[vectorize] codebook`),
/// or has no TopoRec descriptor — starts a new index for its shards itself: the first shard to
/// take the index's lock records the settings, the methods and the codebook in its manifest;
/// the others find them there.
fn freeze_saved_codebook(p: &Pipeline, main: &Path, settings: &str) -> Result<()> {
    let saved = match &p.vectorize {
        Vectorize::Load(_, cb) if p.methods.toporec => Some((**cb).clone()),
        _ if !p.methods.toporec => None,
        _ => return Ok(()),
    };
    if Manifest::load(&main.join(MANIFEST_FILE))?.is_some_and(|m| m.generation > 0) {
        return Ok(());
    }
    let mut writer = IndexWriter::open_waiting(main, settings)?;
    if writer.manifest().generation > 0 {
        return Ok(()); // another shard was first
    }
    let mut methods = writer.manifest().methods.clone();
    methods.retain(|_, e| e.kind == crate::methods::IMPORTED);
    methods.extend(MethodEntry::of_computed(&p.methods));
    writer.set_methods(methods);
    match saved {
        Some(cb) => writer.set_codebook(cb, Some(p.effective_toml(main))),
        None => writer.set_pipeline(p.effective_toml(main)),
    }
    writer.commit()
}

/// `toporec fit --pipeline`: fits the pipeline's codebook on the scans whose id hashes below
/// `fraction` of the hash range (a deterministic sample, the same for every caller), and
/// freezes it in `index` (created when needed) with the pipeline's settings and methods.
pub fn fit_sample(p: &Pipeline, index: &Path, fraction: f64, threads: usize) -> Result<(Codebook, u64)> {
    let Vectorize::Fit(spec) = &p.vectorize else {
        return Err(Error::invalid(
            "the pipeline loads its codebook (`[vectorize] codebook`): nothing to fit",
        ));
    };
    if !(fraction > 0.0 && fraction <= 1.0) {
        return Err(Error::invalid(format!("--sample {fraction}: expected a fraction in (0, 1]")));
    }
    let settings = p.settings_hash();
    let mut writer = IndexWriter::open(index, &settings, false)?;
    if let Some(cb) = writer.manifest().codebook(index)? {
        return Err(Error::index(
            index,
            format!("it has its codebook {} already; switch codebooks with `toporec revectorize`", cb.id()),
        ));
    }
    if writer.manifest().generation > 0 && writer.manifest().settings_hash != settings {
        return Err(Error::index(index, "made with other settings than this pipeline's; use a new folder"));
    }
    let threshold = if fraction >= 1.0 { u64::MAX } else { (fraction * u64::MAX as f64) as u64 };
    let describer = Describer::toporec(p.preprocess.clone(), p.persistence.squared, None);
    let mut streams = Vec::new();
    for source in &p.sources {
        streams.push(source.open()?);
    }
    let sampled = streams
        .into_iter()
        .flatten()
        .filter_map(|item| item.ok())
        .filter(move |scan| crate::fingerprint::of_bytes(scan.id.as_bytes()) <= threshold);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .map_err(|e| Error::invalid(format!("thread pool: {e}")))?;
    let (fitter, scans) = pool.install(|| {
        sampled
            .par_bridge()
            .fold(
                || (CodebookFitter::new(spec.clone()), 0u64),
                |(mut f, n), scan| {
                    let id = scan.id.clone();
                    match describer.describe(scan).outcome {
                        Ok(described) => {
                            if let Some(d) = described.diagram {
                                f.add(&d, &id);
                            }
                            (f, n + 1)
                        }
                        Err(_) => (f, n),
                    }
                },
            )
            .reduce(
                || (CodebookFitter::new(spec.clone()), 0),
                |(mut a, n), (b, m)| {
                    a.merge(b);
                    (a, n + m)
                },
            )
    });
    let codebook = fitter.finish().map_err(|e| {
        Error::index(index, format!("no codebook could be fitted on the {scans} sampled scans: {e}"))
    })?;
    let mut methods = writer.manifest().methods.clone();
    methods.retain(|_, e| e.kind == crate::methods::IMPORTED);
    methods.extend(MethodEntry::of_computed(&p.methods));
    writer.set_methods(methods);
    writer.set_codebook(codebook.clone(), Some(p.effective_toml(index)));
    writer.commit()?;
    Ok((codebook, scans))
}
