//! Keeping an index healthy: `toporec verify` (does it hold what its manifest says?),
//! `toporec compact` (merge the small part files of chunked commits) and `toporec revectorize`
//! (a new codebook for the stored diagrams, switched to atomically). `compact` and
//! `revectorize` take the index's writer lock, like `run`.

use crate::error::{Error, Result};
use crate::methods::TOPOREC;
use crate::offline::CodebookArgs;
use crate::pipeline::config::{Pipeline, dims_needed};
use crate::pipeline::{RunOptions, fit_on_stored, stored_descriptors};

use crate::sinks::index::IndexWriter;
use crate::sinks::index::manifest::{Manifest, file_checksum};
use crate::sinks::index::reader::{read_scans, scan_ids};
use crate::sinks::index::{MANIFEST_FILE, reader};
use crate::sinks::parquet::Status;
use crate::sinks::schema::tables;
use crate::vectorize::codebook::Codebook;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

/// Arguments of `toporec revectorize`.
#[derive(clap::Args, Clone, Debug)]
pub struct RevectorizeArgs {
    /// The index.
    #[command(flatten)]
    pub index: crate::flags::IndexFlag,
    /// Use this saved codebook (else fit one on the stored diagrams with the settings below).
    #[arg(long, conflicts_with_all = ["b", "dims", "contrast", "weighting", "kmeans", "sample_size", "seed"])]
    pub codebook: Option<PathBuf>,
    /// The settings of the codebook to fit.
    #[command(flatten)]
    pub fit: CodebookArgs,
    /// Worker threads.
    #[command(flatten)]
    pub threads: crate::flags::Threads,
}

/// What `revectorize` did.
#[derive(Clone, Debug)]
pub struct Revectorized {
    /// The codebook before.
    pub old_codebook: Option<String>,
    /// The codebook now.
    pub codebook: Codebook,
    /// Descriptors written.
    pub descriptors: u64,
    /// Seconds.
    pub seconds: f64,
}

/// Rebuilds the descriptors table from the stored diagrams with a new codebook (loaded or
/// fitted), and switches the index to it in one commit. Reads no source file and computes no
/// persistence.
pub fn revectorize(args: &RevectorizeArgs, threads: usize) -> Result<Revectorized> {
    let start = std::time::Instant::now();
    let pipeline = Pipeline::of_index(&args.index.path)?;
    let mut writer = IndexWriter::open(&args.index.path, &pipeline.settings_hash(), false)?;
    if writer.manifest().generation == 0 {
        return Err(Error::index(&args.index.path, "empty: nothing to revectorize (run a pipeline first)"));
    }
    let old_codebook = writer.manifest().codebook_id.clone();
    // Every diagrams file is read: each is checked against its checksum first, so damage is
    // refused rather than turned into descriptors with fresh checksums.
    let files: Vec<_> = writer.manifest().files_of(tables::DIAGRAMS).cloned().collect();
    for f in &files {
        writer.verified_path(f)?;
    }
    let squared = pipeline.persistence.squared;
    let (codebook, cached) = match &args.codebook {
        Some(path) => (Codebook::load(path)?, None),
        None => {
            let (codebook, cached) = fit_on_stored(&writer, &args.fit.spec(squared), threads, true)?;
            let codebook = codebook
                .map_err(|e| Error::index(&args.index.path, format!("no codebook could be fitted: {e}")))?;
            (codebook, cached)
        }
    };
    if codebook.spec.squared_radii != squared {
        return Err(Error::invalid(format!(
            "the codebook is made for {}, the index stores {}",
            if codebook.spec.squared_radii { "squared radii" } else { "radii" },
            if squared { "squared radii" } else { "radii" }
        )));
    }
    if let Some(d) = dims_needed(&codebook.spec.dims).iter().find(|d| !pipeline.persistence.dims.contains(d))
    {
        return Err(Error::invalid(format!("the codebook reads H{d}, which the index does not store")));
    }
    writer.drop_descriptors();
    writer.set_codebook(codebook.clone(), None);
    // One commit at the end: readers see the old codebook and descriptors, or the new ones.
    let opts =
        RunOptions { commit_every: u64::MAX, commit_seconds: f64::INFINITY, ..RunOptions::new(threads) };
    crate::fault::point("revectorize-mid");
    let (_, _, descriptors) = stored_descriptors(&mut writer, &codebook, threads, &opts, cached)?;
    writer.commit()?;
    Ok(Revectorized { old_codebook, codebook, descriptors, seconds: start.elapsed().as_secs_f64() })
}

/// Merges the part files of each partition (see [`IndexWriter::compact`]); returns how many
/// files were merged into how many.
pub fn compact(index: &Path) -> Result<(usize, usize)> {
    let manifest = Manifest::load(&index.join(MANIFEST_FILE))?
        .ok_or_else(|| Error::index(index, "no manifest.json: not an index toporec wrote"))?;
    let mut writer = IndexWriter::open(index, &manifest.settings_hash, false)?;
    writer.compact()
}

/// What `verify` found.
#[derive(Clone, Debug, Default)]
pub struct Verification {
    /// Files checked.
    pub files: usize,
    /// Scans in the index.
    pub scans: usize,
    /// Problems, each naming its file or scan.
    pub problems: Vec<String>,
    /// Notes that are not problems (foreign files; uncommitted files, with `--allow-orphans`).
    pub notes: Vec<String>,
}

impl std::fmt::Display for Verification {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for n in &self.notes {
            writeln!(f, "note: {n}")?;
        }
        for p in &self.problems {
            writeln!(f, "problem: {p}")?;
        }
        if self.problems.is_empty() {
            write!(f, "ok: {} files, {} scans", self.files, self.scans)
        } else {
            write!(f, "{} problem(s) in {} files, {} scans", self.problems.len(), self.files, self.scans)
        }
    }
}

/// Checks an index against its manifest: every named file exists with its size, checksum and
/// row count and reads as its table; the codebook ids agree; every ok scan has its diagram and
/// descriptor rows; the counts add up.
pub fn verify(index: &Path, allow_orphans: bool) -> Result<Verification> {
    // Read as it is: a commit a kill left half done shows as files no commit names (the next
    // reader or writer completes it).
    let manifest = Manifest::load(&index.join(MANIFEST_FILE))?
        .ok_or_else(|| Error::index(index, "no manifest.json: not an index toporec wrote"))?;
    let mut v = Verification { files: manifest.files.len(), ..Default::default() };
    // toporec's own files that no commit names: what a glob of the tables would see (a writer
    // at work, or one killed: the next writer removes them).
    for rel in crate::sinks::index::recovery::orphans(index, &manifest) {
        // Part files in the table folders are what a glob sees; staged and temporary files
        // are not.
        let visible = rel.ends_with(".parquet");
        if visible && !allow_orphans {
            v.problems.push(format!(
                "{rel}: not committed, and seen by a glob of the table (a writer at work, or killed; \
                 the next writer or reader removes it)"
            ));
        } else {
            v.notes.push(format!(
                "{rel}: not committed (a writer at work, or killed; the next writer removes it)"
            ));
        }
    }
    for rel in crate::sinks::index::recovery::foreign(index) {
        v.notes.push(format!("{rel}: foreign (not toporec's; left alone)"));
    }
    // Search caches: current, stale (the next query rebuilds it), or damaged (a problem; the next
    // query rebuilds it too, with a warning).
    let caches = index.join(crate::sinks::index::SEARCHERS_DIR);
    let mut current_caches: Vec<(String, String)> = Vec::new();
    for e in std::fs::read_dir(&caches).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let rel = format!("{}/{name}", crate::sinks::index::SEARCHERS_DIR);
        let layout = |method: &str| {
            let m = manifest.methods.get(method).and_then(|entry| entry.method(method));
            m.and_then(|m| m.as_computed().and_then(|c| c.cache_layout()))
        };
        if crate::fsutil::is_temp_name(&name) {
            continue;
        }
        use crate::sinks::index::searchers::{Check, check};
        match check(&e.path()) {
            Check::Intact(h) if h.generation == manifest.generation && layout(&h.method) == Some(h.layout.as_str()) => {
                v.notes.push(format!("{rel}: search cache of {} ({} rows), current", h.method, h.rows));
                current_caches.push((rel, h.method));
            }
            Check::Intact(h) if h.generation == manifest.generation => v.notes.push(format!(
                "{rel}: search cache of {} made by another version of toporec: stale, rebuilt by the next query",
                h.method
            )),
            Check::Intact(h) => v.notes.push(format!(
                "{rel}: search cache of {} from generation {} (the index is at {}): stale, rebuilt by the next query",
                h.method, h.generation, manifest.generation
            )),
            Check::OtherFormat(version) => v.notes.push(format!(
                "{rel}: search cache of format {version}, made by another version of toporec: stale, rebuilt by the next query"
            )),
            Check::Damaged(why) => v.problems.push(format!(
                "{rel}: damaged search cache: {why} (the next query warns and rebuilds it)"
            )),
        }
    }
    // Each file: present, intact, readable as its table.
    let codebook = match manifest.codebook(index) {
        Ok(cb) => cb,
        Err(e) => {
            v.problems.push(e.to_string());
            None
        }
    };
    if let Some(cb) = &codebook
        && manifest.codebook_id.as_deref() != Some(cb.id().as_str())
    {
        v.problems.push(format!(
            "manifest.json: codebook_id {:?} is not its codebook's id {}",
            manifest.codebook_id,
            cb.id()
        ));
    }
    let mut intact: Vec<&crate::sinks::index::manifest::FileEntry> = Vec::new();
    // The methods with a descriptors part that fails its check: a cache of theirs was built
    // from parts that are not as committed now.
    let mut damaged_methods: HashSet<String> = HashSet::new();
    // The partitions with a damaged part: their scans' missing rows are that damage, said once.
    let mut damaged_partitions: HashSet<(String, String, String)> = HashSet::new();
    let repair = format!("`toporec repair --index {}` rebuilds it", index.display());
    for f in &manifest.files {
        let path = crate::sinks::index::resolve(index, &f.path);
        let partition = (f.table.clone(), f.method_name().to_string(), f.session.clone());
        let mut damaged = |v: &mut Verification, what: String| {
            v.problems.push(format!("{}: {what}; {repair}", f.path));
            damaged_partitions.insert(partition.clone());
        };
        if !path.is_file() {
            damaged(&mut v, "missing".into());
            if f.table == tables::DESCRIPTORS {
                damaged_methods.insert(f.method_name().to_string());
            }
            continue;
        }
        let (bytes, xxh3) = file_checksum(&path)?;
        if bytes != f.bytes || xxh3 != f.xxh3 {
            damaged(
                &mut v,
                format!(
                    "{bytes} bytes, checksum {xxh3}; the manifest says {} bytes, checksum {}",
                    f.bytes, f.xxh3
                ),
            );
            if f.table == tables::DESCRIPTORS {
                damaged_methods.insert(f.method_name().to_string());
            }
            continue;
        }
        // A descriptors file: its method's length and id (the codebook's, for TopoRec).
        let method = f.method_name();
        let (length, id, what) = if f.table != tables::DESCRIPTORS || method == TOPOREC {
            (manifest.descriptor_length, manifest.codebook_id.clone(), "codebook")
        } else if let Some(e) = manifest.methods.get(method) {
            (Some(e.length), Some(e.id.clone()), "method id")
        } else {
            v.problems.push(format!(
                "{}: descriptors of method `{method}`, which the manifest does not list",
                f.path
            ));
            continue;
        };
        match reader::check_file(&path, &f.table, length) {
            Ok(info) => {
                if info.rows != f.rows {
                    v.problems.push(format!("{}: {} rows, the manifest says {}", f.path, info.rows, f.rows));
                }
                if f.table == tables::DESCRIPTORS && info.codebook_id != id && info.rows > 0 {
                    v.problems.push(format!(
                        "{}: made with {what} {:?}, the index's is {:?}",
                        f.path, info.codebook_id, id
                    ));
                }
                intact.push(f);
            }
            Err(e) => v.problems.push(e.to_string()),
        }
    }
    for (rel, method) in current_caches.iter().filter(|(_, m)| damaged_methods.contains(m)) {
        v.problems.push(format!(
            "{rel}: search cache of {method}, whose descriptors parts fail their checks: not to be \
             trusted ({repair} and the cache)"
        ));
    }
    // Rows: every ok scan with its diagram and descriptor, counts as the manifest says.
    let mut status: HashMap<String, Status> = HashMap::new();
    let mut session_of: HashMap<String, String> = HashMap::new();
    let mut counts = crate::sinks::index::manifest::Counts::default();
    for f in intact.iter().filter(|f| f.table == tables::SCANS) {
        for r in read_scans(&crate::sinks::index::resolve(index, &f.path), &f.session)? {
            session_of.insert(r.scan_id.clone(), r.session.clone());
            if status.insert(r.scan_id.clone(), r.status).is_some() {
                v.problems.push(format!("scan {}: more than one row in scans", r.scan_id));
            }
            counts.scans += 1;
            match r.status {
                Status::Ok => counts.ok += 1,
                Status::Skipped => counts.skipped += 1,
                Status::Error => counts.errors += 1,
            }
        }
    }
    v.scans = status.len();
    if counts != manifest.counts {
        v.problems
            .push(format!("manifest.json: counts {:?}, the scans table holds {counts:?}", manifest.counts));
    }
    let ids_of = |table: &str, method: Option<&str>| -> Result<HashMap<String, usize>> {
        let mut out: HashMap<String, usize> = HashMap::new();
        let files = intact.iter().filter(|f| f.table == table && method.is_none_or(|m| f.method_name() == m));
        for f in files {
            for id in scan_ids(&crate::sinks::index::resolve(index, &f.path))? {
                *out.entry(id).or_default() += 1;
            }
        }
        Ok(out)
    };
    // Whether a scan's rows of a table (and method) would be in a damaged part of its session.
    let in_damaged = |table: &str, method: &str, id: &str| {
        let method = if table == tables::DESCRIPTORS { method } else { TOPOREC };
        session_of
            .get(id)
            .is_some_and(|s| damaged_partitions.contains(&(table.to_string(), method.to_string(), s.clone())))
    };
    let stored_h0 = Pipeline::of_index(index)
        .map(|p| p.methods.toporec && p.persistence.dims.contains(&0))
        .unwrap_or(true);
    let with_pairs = ids_of(tables::DIAGRAMS, None)?;
    let mut ok: Vec<&String> = status.iter().filter(|(_, s)| **s == Status::Ok).map(|(id, _)| id).collect();
    ok.sort();
    for id in &ok {
        // Every ok scan has H0 pairs (its points are born at 0), when H0 is stored.
        if stored_h0 && !with_pairs.contains_key(*id) && !in_damaged(tables::DIAGRAMS, TOPOREC, id) {
            v.problems.push(format!("scan {id}: ok, but no rows in diagrams"));
        }
    }
    // Each method: one row per ok scan (TopoRec once it has a codebook; computed methods
    // always; imported ones may cover some scans only), never a row of another scan.
    let mut methods: Vec<(String, bool)> = vec![(TOPOREC.to_string(), codebook.is_some())];
    methods.extend(manifest.methods.iter().map(|(m, e)| (m.clone(), e.kind != crate::methods::IMPORTED)));
    for (method, complete) in &methods {
        let with_descriptor = ids_of(tables::DESCRIPTORS, Some(method))?;
        let what =
            if method == TOPOREC { "descriptors".to_string() } else { format!("{method} descriptors") };
        for id in &ok {
            match with_descriptor.get(*id) {
                None if *complete && !in_damaged(tables::DESCRIPTORS, method, id) => {
                    v.problems.push(format!("scan {id}: ok, but no row in {what}"))
                }
                Some(n) if *n > 1 => v.problems.push(format!("scan {id}: {n} rows in {what}")),
                _ => {}
            }
        }
        for id in with_descriptor.keys() {
            if status.get(id) != Some(&Status::Ok) {
                v.problems.push(format!("scan {id}: rows in {what}, but not an ok scan"));
            }
        }
    }
    for id in with_pairs.keys() {
        if status.get(id) != Some(&Status::Ok) {
            v.problems.push(format!("scan {id}: rows in diagrams or descriptors, but not an ok scan"));
        }
    }
    v.problems.sort();
    v.problems.dedup();
    Ok(v)
}
