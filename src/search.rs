//! Search over an index, in one place: an [`Engine`] loads one method's stored descriptors (or
//! maps its cached structure), describes new scans as the index made its own, and answers the
//! k best rows through the method's [`Searcher`], at a search budget. `query`, `eval`, `loops`,
//! `offline` and the Python package all search through it.
//!
//! Every descriptor method of an index can answer: TopoRec, M2DP and imported vectors by exact
//! Euclidean k-NN, the other computed methods by their own searchers (candidates by keys,
//! re-ranked by their distances), which also estimate the query's yaw relative to each hit.
//! Imported methods have no way to describe a new scan; `eval` compares them on stored
//! descriptors.

use crate::describe::{DescribeError, Describer};
use crate::error::{Error, Result};
use crate::methods::{Hit, Method, MethodKind, SearchBudget, Searcher, TOPOREC};
use crate::sinks::index::damage::Damage;
use crate::sinks::index::searchers;
use crate::sinks::index::{IndexReader, IndexedScan};
use crate::sources::Scan;
use crate::vectorize::codebook::Codebook;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

/// One method's stored descriptors, checked: all of one length, made by one codebook (or one
/// parameter set), finite.
pub struct Loaded {
    /// The method.
    pub method: Method,
    /// What made them: the codebook id, or the method's id.
    pub id: String,
    /// Descriptor length.
    pub length: usize,
    /// The codebook (TopoRec).
    pub codebook: Option<Codebook>,
    /// The rows.
    pub scans: Vec<IndexedScan>,
}

/// An opened index, ready to answer queries with one method.
pub struct Engine {
    /// How a scan becomes this method's descriptor (the index's preprocessing, persistence
    /// units and codebook for TopoRec; the method alone for the others).
    pub describer: Describer,
    /// The method.
    pub method: Method,
    /// What made the descriptors (codebook or method id).
    pub id: String,
    /// Database rows (id, session, pose; their descriptors, unless the structure was mapped
    /// from the index's cache).
    pub scans: Vec<IndexedScan>,
    /// Descriptor length.
    length: usize,
    searcher: Box<dyn Searcher>,
    /// The cache the searcher is mapped from, when it is: what rebuilds it when a search finds
    /// a block of it damaged.
    cache: Option<CacheOrigin>,
    /// The engine rebuilt from the index after a search found the cache damaged; every later
    /// search goes to it.
    rebuilt: OnceLock<Box<Engine>>,
    rebuilding: Mutex<()>,
}

/// Where a mapped searcher came from.
struct CacheOrigin {
    index: PathBuf,
    method: String,
    damage: Damage,
    budget: Option<SearchBudget>,
}

/// Per-query seconds of each step (those a method does not have stay 0).
#[derive(Clone, Copy, Debug, Default)]
pub struct StepTimes {
    /// TopoRec: preprocess + alpha persistence.
    pub persistence: f64,
    /// TopoRec: ATOL.
    pub vectorize: f64,
    /// A computed method: the descriptor (with the method's preprocessing).
    pub describe: f64,
    /// Nearest-neighbour search (the methods narrowing by keys: the candidates).
    pub search: f64,
    /// The methods narrowing by keys: the re-rank of the candidates.
    pub rerank: f64,
}

impl StepTimes {
    /// The search steps a method has, with their times (of a stored descriptor).
    pub fn search_steps(&self, method: &Method) -> Vec<(&'static str, f64)> {
        let steps = method.search_steps();
        if steps.len() == 2 {
            vec![(steps[0], self.search), (steps[1], self.rerank)]
        } else {
            vec![(steps[0], self.search)]
        }
    }

    /// The steps a method has, with their times.
    pub fn steps(&self, method: &Method) -> Vec<(&'static str, f64)> {
        let mut out = match method.kind {
            MethodKind::Toporec => vec![("persistence", self.persistence), ("vectorize", self.vectorize)],
            MethodKind::Computed(_) => vec![("describe", self.describe)],
            MethodKind::Imported { .. } => Vec::new(),
        };
        out.extend(self.search_steps(method));
        out
    }
}

impl Engine {
    /// Opens `index` to search with `method` (only `sessions` as the database, when not
    /// empty).
    pub fn open(index: &Path, sessions: &[String], method: &str) -> Result<Self> {
        Self::open_with(index, sessions, method, &Damage::refuse())
    }

    /// [`Engine::open`], doing with damaged parts as `damage` says (refuse them, or skip and
    /// record them).
    pub fn open_with(index: &Path, sessions: &[String], method: &str, damage: &Damage) -> Result<Self> {
        let chosen = |s: &IndexedScan| sessions.is_empty() || sessions.contains(&s.session);
        if let Some(engine) = Self::open_cached(index, method, &chosen, damage)? {
            return Ok(engine);
        }
        let loaded = load_method(index, method, sessions, damage)?;
        Self::from_loaded(index, loaded)
    }

    /// For a method whose search structure is cached in the index ([`searchers`],
    /// [`crate::methods::Computed::cache_layout`]), an engine over its rows `chosen` keeps,
    /// mapped from the cache (built and written first, when the cache is missing or stale);
    /// `None` for the other methods. A cache is built only from parts that pass their checks:
    /// when `damage` skipped one, the structure is used but not written.
    pub fn open_cached(
        index: &Path,
        method: &str,
        chosen: &dyn Fn(&IndexedScan) -> bool,
        damage: &Damage,
    ) -> Result<Option<Self>> {
        Self::open_cached_from(index, method, chosen, damage, None)
    }

    /// [`Engine::open_cached`]; given what a search found `damaged` in the cache, the cache is
    /// treated as a damaged one (a warning, then the structure built from the index and cached
    /// again) instead of opened.
    fn open_cached_from(
        index: &Path,
        method: &str,
        chosen: &dyn Fn(&IndexedScan) -> bool,
        damage: &Damage,
        damaged: Option<&str>,
    ) -> Result<Option<Self>> {
        let reader = IndexReader::open(index)?;
        let Some(manifest) = reader.manifest() else { return Ok(None) };
        let Some(entry) = manifest.methods.get(method) else { return Ok(None) };
        let Some(m) = entry.method(method) else { return Ok(None) };
        let Some(computed) = m.as_computed() else { return Ok(None) };
        let Some(layout) = computed.cache_layout() else { return Ok(None) };
        let path = searchers::path(index, method);
        let origin = CacheOrigin {
            index: index.to_path_buf(),
            method: method.to_string(),
            damage: damage.clone(),
            budget: None,
        };
        let opened = match damaged {
            None => searchers::open(&path, manifest.generation, &entry.id, layout),
            Some(why) => searchers::Opened::Damaged(why.to_string()),
        };
        let cached = match opened {
            searchers::Opened::Current(cached) => Some(cached),
            searchers::Opened::Missing | searchers::Opened::Stale => None,
            searchers::Opened::OtherVersion(why) => {
                tracing::warn!(
                    "{}: made by another version of toporec ({why}); rebuilding it",
                    path.display()
                );
                None
            }
            searchers::Opened::Damaged(why) => {
                tracing::warn!("{}: damaged: {why}; rebuilding it", path.display());
                None
            }
        };
        let (searcher, rows, mapped) = match cached {
            Some(cached) => {
                let n = cached.header.rows;
                let searcher =
                    computed.mapped_searcher(cached.body, n).map_err(|e| Error::index(&path, e))?;
                (searcher, cached.rows, true)
            }
            None => {
                let skipped_before = damage.found().len();
                let loaded = load_method(index, method, &[], damage)?;
                let whole = damage.found().len() == skipped_before;
                let vectors: Vec<f32> =
                    loaded.scans.iter().flat_map(|s| s.descriptor.iter().copied()).collect();
                let searcher = computed.searcher(vectors);
                let rows: Vec<IndexedScan> =
                    loaded.scans.into_iter().map(|s| IndexedScan { descriptor: Vec::new(), ..s }).collect();
                let header = searchers::Header::new(
                    manifest.generation,
                    method,
                    &entry.id,
                    entry.params.clone(),
                    layout,
                    rows.len(),
                );
                // An index that cannot be written (read-only, another user's) gets no cache; nor
                // does one read without a damaged part (the cache would pass for the whole).
                if whole {
                    let bytes = searcher.bytes().expect("a cached method's searcher has bytes");
                    if let Err(e) = searchers::write(&path, &header, &rows, &bytes) {
                        tracing::info!("{}: not cached ({e})", path.display());
                    }
                }
                (searcher, rows, false)
            }
        };
        let engine = Engine {
            describer: Describer::of_computed(&m),
            length: m.len(),
            method: m,
            id: entry.id.clone(),
            scans: rows,
            searcher,
            cache: mapped.then_some(origin),
            rebuilt: OnceLock::new(),
            rebuilding: Mutex::new(()),
        };
        let engine = engine.retain(chosen)?;
        // Copying some of the rows read every block.
        if let Some(why) = engine.searcher.damage() {
            return Self::open_cached_from(index, method, chosen, damage, Some(&why));
        }
        if engine.scans.is_empty() {
            let skipped = match damage.found().len() {
                0 => String::new(),
                n => format!(" ({n} damaged parts left out; `toporec verify` names them)"),
            };
            return Err(Error::index(
                index,
                format!("no {method} descriptors among the scans chosen{skipped}"),
            ));
        }
        Ok(Some(engine))
    }

    /// An engine over descriptors already loaded from `index`.
    pub fn from_loaded(index: &Path, loaded: Loaded) -> Result<Self> {
        let describer = match &loaded.method.kind {
            MethodKind::Toporec => {
                let pipeline = crate::pipeline::config::Pipeline::of_index(index)?;
                Describer::toporec(pipeline.preprocess, pipeline.persistence.squared, loaded.codebook.clone())
            }
            _ => Describer::of_computed(&loaded.method),
        };
        Ok(Self::with_describer(loaded, describer))
    }

    /// An engine that searches `loaded` but describes nothing (`eval places`, whose queries
    /// are stored descriptors).
    pub fn search_only(loaded: Loaded) -> Self {
        Self::with_describer(loaded, Describer::nothing())
    }

    fn with_describer(loaded: Loaded, describer: Describer) -> Self {
        let Loaded { method, id, length, scans, .. } = loaded;
        let vectors: Vec<f32> = scans.iter().flat_map(|s| s.descriptor.iter().copied()).collect();
        let searcher = method.searcher(vectors, length);
        Engine {
            describer,
            method,
            id,
            scans,
            length,
            searcher,
            cache: None,
            rebuilt: OnceLock::new(),
            rebuilding: Mutex::new(()),
        }
    }

    /// The engine over the database rows `keep` keeps, in their order (a subset of a cached
    /// structure is copied, not rebuilt).
    pub fn retain(mut self, keep: &dyn Fn(&IndexedScan) -> bool) -> Result<Self> {
        let rows: Vec<usize> = (0..self.scans.len()).filter(|&i| keep(&self.scans[i])).collect();
        if rows.len() == self.scans.len() {
            return Ok(self);
        }
        let scans: Vec<IndexedScan> = rows.iter().map(|&i| self.scans[i].clone()).collect();
        self.searcher = self.searcher.subset(&rows).unwrap_or_else(|| {
            let vectors: Vec<f32> = scans.iter().flat_map(|s| s.descriptor.iter().copied()).collect();
            self.method.searcher(vectors, self.length)
        });
        self.scans = scans;
        Ok(self)
    }

    /// The engine searching at `budget` instead of its method's own settings (the same
    /// entries: nothing rebuilt).
    pub fn with_budget(mut self, budget: SearchBudget) -> Self {
        self.searcher.set_budget(budget, self.scans.len());
        if let Some(cache) = &mut self.cache {
            cache.budget = Some(budget);
        }
        self
    }

    /// The index's codebook (TopoRec engines).
    pub fn codebook(&self) -> Option<&Codebook> {
        self.describer.codebook.as_ref()
    }

    /// The descriptor of points — preprocessed ones for TopoRec, a raw scan (sensor frame)
    /// for the others — with the time of each step.
    pub fn describe_points(
        &self,
        points: &[[f64; 3]],
        label: &str,
    ) -> Result<(Vec<f32>, StepTimes), DescribeError> {
        if self.describer.topological {
            let d = self.describer.describe_points(points, label);
            let described = d.outcome?;
            let times = StepTimes {
                persistence: d.times.persistence,
                vectorize: d.times.vectorize,
                ..Default::default()
            };
            return Ok((described.descriptor.expect("a TopoRec engine has a codebook").to_f32(), times));
        }
        self.describe_raw(points, label)
    }

    /// The descriptor of a raw scan with a computed method (not TopoRec).
    fn describe_raw(&self, points: &[[f64; 3]], label: &str) -> Result<(Vec<f32>, StepTimes), DescribeError> {
        let t = cpu_time::ThreadTime::now();
        let mut d = self.describer.describe_raw(points, label)?;
        let times = StepTimes { describe: t.elapsed().as_secs_f64(), ..Default::default() };
        match d.pop() {
            Some(v) => Ok((v, times)),
            None => Err(DescribeError::Internal {
                label: label.into(),
                message: format!(
                    "method `{}` has its vectors imported: new scans cannot be described",
                    self.method.name
                ),
            }),
        }
    }

    /// A scan's descriptor through every step of the method.
    pub fn describe_scan(&self, scan: Scan) -> Result<(Vec<f32>, StepTimes), DescribeError> {
        if !self.describer.topological {
            let label = format!("{}: scan {}", scan.path.display(), scan.id);
            return self.describe_raw(&scan.points, &label);
        }
        let d = self.describer.describe(scan);
        let times = StepTimes {
            persistence: d.times.preprocess + d.times.persistence,
            vectorize: d.times.vectorize,
            ..Default::default()
        };
        let x = d.outcome?;
        Ok((x.descriptor.expect("a TopoRec engine has a codebook").to_f32(), times))
    }

    /// The `k` best database rows, with the time of each search step.
    pub fn find(&self, descriptor: &[f32], k: usize) -> Result<(Vec<Hit>, StepTimes)> {
        Ok(self.find_many(descriptor, k)?.pop().unwrap_or_default())
    }

    /// The `k` best database rows of each query (`queries` is `m × length`, row-major), each
    /// charged its share of the search time.
    ///
    /// A searcher mapped from the index's cache checks each block of it when a search first
    /// reads it; when one fails, the cache is damaged: a warning naming it, and the searcher is
    /// rebuilt from the index (and cached again) and answers instead. An error when it cannot
    /// be.
    pub fn find_many(&self, queries: &[f32], k: usize) -> Result<Vec<(Vec<Hit>, StepTimes)>> {
        if let Some(rebuilt) = self.rebuilt.get() {
            return rebuilt.find_many(queries, k);
        }
        let found = self.searcher.search_many(queries, self.length, k);
        match self.searcher.damage() {
            None => Ok(found
                .into_iter()
                .map(|(hits, t)| {
                    (hits, StepTimes { search: t.candidates, rerank: t.rerank, ..Default::default() })
                })
                .collect()),
            Some(why) => self.rebuild(&why)?.find_many(queries, k),
        }
    }

    /// The engine rebuilt from the index when its cache was found damaged (`why`): one thread
    /// rebuilds, the others wait for it.
    #[cold]
    fn rebuild(&self, why: &str) -> Result<&Engine> {
        let _one = self.rebuilding.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(rebuilt) = self.rebuilt.get() {
            return Ok(rebuilt);
        }
        let Some(cache) = &self.cache else {
            return Err(Error::invalid(format!("a search structure built in memory reports damage: {why}")));
        };
        let mine: std::collections::HashSet<(&str, &str)> =
            self.scans.iter().map(|s| (s.session.as_str(), s.scan_id.as_str())).collect();
        let chosen = |s: &IndexedScan| mine.contains(&(s.session.as_str(), s.scan_id.as_str()));
        let mut rebuilt =
            Self::open_cached_from(&cache.index, &cache.method, &chosen, &cache.damage, Some(why))?
                .ok_or_else(|| Error::index(&cache.index, format!("{} is no longer cached", cache.method)))?;
        if let Some(budget) = cache.budget {
            rebuilt = rebuilt.with_budget(budget);
        }
        let same = rebuilt.scans.len() == self.scans.len()
            && rebuilt
                .scans
                .iter()
                .zip(&self.scans)
                .all(|(a, b)| a.session == b.session && a.scan_id == b.scan_id);
        if !same {
            return Err(Error::index(
                &cache.index,
                format!("its {} rows changed while it was searched; search again", cache.method),
            ));
        }
        Ok(self.rebuilt.get_or_init(|| Box::new(rebuilt)))
    }
}

/// The methods of an index, as its manifest records them (TopoRec first, when present).
pub fn index_methods(index: &Path) -> Result<Vec<Method>> {
    methods_of(&IndexReader::open(index)?)
}

/// The methods an opened index records (see [`index_methods`]).
fn methods_of(reader: &IndexReader) -> Result<Vec<Method>> {
    let mut out = Vec::new();
    for name in reader.methods()? {
        if name == TOPOREC {
            out.insert(0, Method::toporec());
            continue;
        }
        let entry = reader.manifest().and_then(|m| m.methods.get(&name)).expect("listed by the manifest");
        match entry.method(&name) {
            Some(m) => out.push(m),
            None => tracing::warn!(
                "{}: method `{name}` is of kind `{}`, unknown to this toporec; left out",
                reader.root().display(),
                entry.kind
            ),
        }
    }
    Ok(out)
}

/// One method's descriptors of an index (only `sessions`, when not empty), checked to have
/// been made by one codebook or parameter set, of one length; rows with non-finite values are
/// left out with a warning.
pub(crate) fn load_method(
    index: &Path,
    method: &str,
    sessions: &[String],
    damage: &Damage,
) -> Result<Loaded> {
    IndexReader::read_consistent_with(index, damage, |reader| load_method_from(reader, method, sessions))
}

/// [`load_method`] on an opened index.
fn load_method_from(reader: &IndexReader, method: &str, sessions: &[String]) -> Result<Loaded> {
    let index = reader.root();
    let methods = methods_of(reader)?;
    let Some(m) = methods.iter().find(|m| m.name == method).cloned() else {
        let names: Vec<&str> = methods.iter().map(|m| m.name.as_str()).collect();
        return Err(Error::index(
            index,
            format!("holds no descriptors of method `{method}` (it holds: {})", names.join(", ")),
        ));
    };
    let (codebook, id, length) = match &m.kind {
        MethodKind::Toporec => {
            let cb = reader.codebook()?;
            let (id, len) = (cb.id(), cb.len());
            (Some(cb), id, len)
        }
        _ => {
            let e = reader.manifest().and_then(|x| x.methods.get(method)).expect("listed by the manifest");
            (None, e.id.clone(), e.length)
        }
    };
    let mut scans = reader.descriptors_of(method, sessions, Some(length))?;
    // A descriptor with a NaN or infinite value (a foreign or damaged table) is never ranked.
    scans.retain(|s| {
        let finite = s.descriptor.iter().all(|v| v.is_finite());
        if !finite {
            tracing::warn!(
                "{}: {method} descriptors of session {}: scan {} has non-finite values; left out",
                index.display(),
                s.session,
                s.scan_id
            );
        }
        finite
    });
    if scans.is_empty() {
        let which = if sessions.is_empty() { String::new() } else { format!(" in sessions {sessions:?}") };
        let skipped = match reader.damage().found().len() {
            0 => String::new(),
            n => format!(" outside the {n} damaged parts left out (`toporec verify` names them)"),
        };
        return Err(Error::index(index, format!("no {method} descriptors{which}{skipped}")));
    }
    let what = if codebook.is_some() { "codebook" } else { "method id" };
    if let Some(s) = scans.iter().find(|s| s.codebook_id != id) {
        return Err(Error::index(
            index,
            format!("scan {} was made with {what} {}, the index's is {id}", s.scan_id, s.codebook_id),
        ));
    }
    if let Some(s) = scans.iter().find(|s| s.descriptor.len() != length) {
        return Err(Error::index(
            index,
            format!(
                "scan {} has a {method} descriptor of length {}, the index's is {length}",
                s.scan_id,
                s.descriptor.len()
            ),
        ));
    }
    // Rows in scan order, whatever the files' layout (a merged or a Spark-written index holds
    // the same rows in other files): ties in a search go to the lower row, so the answers
    // depend on the rows alone.
    scans.sort_by(|a, b| (&a.session, &a.scan_id).cmp(&(&b.session, &b.scan_id)));
    Ok(Loaded { method: m, id, length, codebook, scans })
}

/// Mean and p95 (ms) of each step of a method's per-query times: every step, or (`search_only`)
/// those of the search.
pub(crate) fn step_stats(
    method: &Method,
    times: &[StepTimes],
    search_only: bool,
) -> Vec<(&'static str, f64, f64)> {
    let steps = |t: &StepTimes| if search_only { t.search_steps(method) } else { t.steps(method) };
    let names: Vec<&'static str> = steps(&StepTimes::default()).into_iter().map(|s| s.0).collect();
    names
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let (mean, p95) = mean_p95_ms(&times.iter().map(|t| steps(t)[i].1).collect::<Vec<_>>());
            (*name, mean, p95)
        })
        .collect()
}

/// `step mean / p95, …` of a method's per-query times (see [`step_stats`]).
pub(crate) fn step_summary(method: &Method, times: &[StepTimes], search_only: bool) -> String {
    step_stats(method, times, search_only)
        .iter()
        .map(|(name, mean, p95)| format!("{name} {mean:.3} / {p95:.3}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Mean and 95th percentile (nearest rank) of a sample, in milliseconds.
pub(crate) fn mean_p95_ms(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0);
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let p95 = s[((0.95 * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1];
    (1e3 * s.iter().sum::<f64>() / s.len() as f64, 1e3 * p95)
}
