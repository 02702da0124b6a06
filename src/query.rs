//! `toporec query`: the k nearest database descriptors of new scans, made with the index's own
//! preprocessing and codebook (or the method's parameters), read from the index, never
//! re-specified; many queries per call, in parallel. Also the engine `eval` uses.
//!
//! Every descriptor method of an index can answer (`--method`): TopoRec and M2DP by exact
//! Euclidean k-NN, ScanContext by ring-key candidates re-ranked with its column-shift
//! distance, whose best shift is the query's yaw relative to the hit. Imported methods have no
//! way to describe a new scan here; `eval` compares them on stored descriptors.

use crate::baselines::scancontext::{self, Searcher};
use crate::baselines::{Method, MethodKind, TOPOREC};
use crate::describe::{DescribeError, Describer};
use crate::error::{Error, Result, ResultExt};
use crate::search::{Database, Hit};
use crate::sinks::index::{IndexReader, IndexedScan, searchers};
use crate::sources::{InputKind, Scan, ScanFailure, ScanStream, read_cloud_file};
use crate::vectorize::codebook::Codebook;
use rayon::prelude::*;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `toporec query`.
#[derive(Clone, Debug)]
pub struct QueryArgs {
    /// The index to search.
    pub index: PathBuf,
    /// Query inputs: cloud files, MCAPs, NCLT sessions, KITTI sequences.
    pub inputs: Vec<PathBuf>,
    /// Neighbours per query: [1, ∞), clamped to the database size.
    pub k: usize,
    /// The descriptor method to search with (one the index holds; `toporec info` lists them).
    pub method: String,
    /// Database sessions (default: all).
    pub sessions: Vec<String>,
    /// MCAP topic.
    pub topic: Option<String>,
    /// Output CSV (default stdout).
    pub out: Option<PathBuf>,
}

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

/// The search structure of one method.
enum Search {
    Vectors(Database),
    ScanContext(Searcher),
    Solid(crate::baselines::solid::Searcher),
    ScanContextPp(crate::baselines::scancontext_pp::Searcher),
    LidarIris(crate::baselines::lidar_iris::Searcher),
    Plus(crate::toporec_plus::Searcher),
}

impl Search {
    /// The structure `method` searches `scans`' descriptors (of `length`) with.
    fn over(method: &Method, scans: &[IndexedScan], length: usize) -> Self {
        let vectors: Vec<f32> = scans.iter().flat_map(|s| s.descriptor.iter().copied()).collect();
        match &method.kind {
            MethodKind::ScanContext(p) => Search::ScanContext(Searcher::new(vectors, p.clone())),
            MethodKind::Solid(p) => Search::Solid(crate::baselines::solid::Searcher::new(vectors, p.clone())),
            MethodKind::ToporecPlus(p) => {
                Search::Plus(crate::toporec_plus::Searcher::new(vectors, p.clone()))
            }
            MethodKind::LidarIris(p) => {
                Search::LidarIris(crate::baselines::lidar_iris::Searcher::new(vectors, p.clone()))
            }
            MethodKind::ScanContextPp(_) | MethodKind::ScanContextPpCart(_) => {
                let variant = method.scancontext_pp_variant().expect("a Scan Context++ method");
                Search::ScanContextPp(crate::baselines::scancontext_pp::Searcher::new(vectors, variant))
            }
            _ => Search::Vectors(Database::new(vectors, length)),
        }
    }
}

/// How much a method's search re-ranks (`eval --search`), so that methods compare at equal
/// budgets. Methods searched by exact k-NN (TopoRec, M2DP) search every entry at any budget.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SearchBudget {
    /// Each method's own settings (ScanContext: 10 ring-key candidates, ±3 sectors around
    /// the sector-key alignment; toporec-plus: 100 candidates).
    #[default]
    Default,
    /// Every database entry re-ranked at every shift (toporec-plus: of every turned grid).
    Exhaustive,
    /// The same for every method that has them: this many re-ranked candidates, and the
    /// shifts within ±[`MATCHED_SHIFTS`] sectors of the coarse alignment.
    Matched(usize),
}

/// The shift range of a matched budget, in sectors each side (ScanContext's default).
pub const MATCHED_SHIFTS: usize = 3;

impl std::str::FromStr for SearchBudget {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "default" => Ok(SearchBudget::Default),
            "exhaustive" => Ok(SearchBudget::Exhaustive),
            _ => match s.strip_prefix("matched:").map(str::parse::<usize>) {
                Some(Ok(n)) if n >= 1 => Ok(SearchBudget::Matched(n)),
                _ => Err(format!("`{s}`: expected default, exhaustive or matched:N (N ≥ 1 candidates)")),
            },
        }
    }
}

impl std::fmt::Display for SearchBudget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SearchBudget::Default => f.write_str("default"),
            SearchBudget::Exhaustive => f.write_str("exhaustive"),
            SearchBudget::Matched(n) => write!(f, "matched:{n}"),
        }
    }
}

impl SearchBudget {
    /// `method` with its search settings set to this budget over a database of `entries`
    /// (its descriptor settings, and so its id, unchanged).
    pub fn apply(self, method: &Method, entries: usize) -> Method {
        // A share of the sectors that gives `shifts` each side: round(0.5 · ratio · sectors).
        let ratio = |shifts: usize, sectors: usize| (2.0 * shifts as f64 / sectors.max(1) as f64).min(1.0);
        let mut m = method.clone();
        match (&mut m.kind, self) {
            (_, SearchBudget::Default) => {}
            (MethodKind::ScanContext(p), SearchBudget::Exhaustive) => {
                (p.candidates, p.search_ratio) = (entries.max(1), 1.0)
            }
            (MethodKind::ToporecPlus(p), SearchBudget::Exhaustive) => {
                (p.candidates, p.search_ratio) = (entries.max(1), 1.0)
            }
            (MethodKind::ScanContextPp(p), SearchBudget::Exhaustive) => {
                (p.candidates, p.search_ratio) = (entries.max(1), 1.0)
            }
            (MethodKind::ScanContextPpCart(p), SearchBudget::Exhaustive) => {
                (p.candidates, p.search_ratio) = (entries.max(1), 1.0)
            }
            (MethodKind::LidarIris(p), SearchBudget::Exhaustive) => p.candidates = entries.max(1),
            // Its shifts are always the five around the phase correlation's peak.
            (MethodKind::LidarIris(p), SearchBudget::Matched(n)) => p.candidates = n,
            (MethodKind::ScanContextPp(p), SearchBudget::Matched(n)) => {
                (p.candidates, p.search_ratio) = (n, ratio(MATCHED_SHIFTS, p.sectors))
            }
            (MethodKind::ScanContextPpCart(p), SearchBudget::Matched(n)) => {
                (p.candidates, p.search_ratio) = (n, ratio(MATCHED_SHIFTS, p.columns()))
            }
            (MethodKind::ScanContext(p), SearchBudget::Matched(n)) => {
                (p.candidates, p.search_ratio) = (n, ratio(MATCHED_SHIFTS, p.sectors))
            }
            (MethodKind::ToporecPlus(p), SearchBudget::Matched(n)) => {
                (p.candidates, p.search_ratio) = (n, ratio(MATCHED_SHIFTS, p.sectors))
            }
            _ => {}
        }
        m
    }
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
    /// Database rows (descriptor, id, session, pose).
    pub scans: Vec<IndexedScan>,
    search: Search,
}

/// Per-query seconds of each step (those a method does not have stay 0).
#[derive(Clone, Copy, Debug, Default)]
pub struct StepTimes {
    /// TopoRec: preprocess + alpha persistence.
    pub persistence: f64,
    /// TopoRec: ATOL.
    pub vectorize: f64,
    /// ScanContext, M2DP: the descriptor (with the method's preprocessing).
    pub describe: f64,
    /// Nearest-neighbour search (ScanContext: the ring-key candidates).
    pub search: f64,
    /// ScanContext: the re-rank of the candidates.
    pub rerank: f64,
}

impl StepTimes {
    /// The search steps a method has, with their times (of a stored descriptor).
    pub fn search_steps(&self, method: &Method) -> Vec<(&'static str, f64)> {
        match method.kind {
            MethodKind::ScanContext(_) | MethodKind::ToporecPlus(_) => {
                vec![("candidates", self.search), ("rerank", self.rerank)]
            }
            _ => vec![("search", self.search)],
        }
    }

    /// The steps a method has, with their times.
    pub fn steps(&self, method: &Method) -> Vec<(&'static str, f64)> {
        match method.kind {
            MethodKind::Toporec => {
                vec![
                    ("persistence", self.persistence),
                    ("vectorize", self.vectorize),
                    ("search", self.search),
                ]
            }
            MethodKind::ScanContext(_) | MethodKind::ToporecPlus(_) => {
                vec![("describe", self.describe), ("candidates", self.search), ("rerank", self.rerank)]
            }
            MethodKind::M2dp(_)
            | MethodKind::Solid(_)
            | MethodKind::LidarIris(_)
            | MethodKind::ScanContextPp(_)
            | MethodKind::ScanContextPpCart(_) => {
                vec![("describe", self.describe), ("search", self.search)]
            }
            MethodKind::Imported { .. } => vec![("search", self.search)],
        }
    }
}

/// Each query of `queries` (`len` values each, in parallel) searched by `search`, whose hits
/// are (row, distance, yaw in degrees), timed as one search step.
fn timed_each(
    queries: &[f32],
    len: usize,
    search: impl Fn(&[f32]) -> Vec<(usize, f64, f64)> + Sync,
) -> Vec<(Vec<Found>, StepTimes)> {
    queries
        .par_chunks(len)
        .map(|q| {
            let t = Instant::now();
            let hits = search(q);
            let search = t.elapsed().as_secs_f64();
            let found =
                hits.into_iter().map(|(row, distance, yaw)| Found { row, distance, yaw_degrees: Some(yaw) });
            (found.collect(), StepTimes { search, ..Default::default() })
        })
        .collect()
}

/// A search result: database row, distance, and for ScanContext the yaw of the query
/// relative to the hit (degrees, [0, 360)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Found {
    /// Database row.
    pub row: usize,
    /// Distance (Euclidean; ScanContext: its cosine distance in [0, 1]).
    pub distance: f64,
    /// ScanContext: the yaw its best column shift stands for.
    pub yaw_degrees: Option<f64>,
}

impl Engine {
    /// Opens `index` to search with `method` (only `sessions` as the database, when not
    /// empty).
    pub fn open(index: &Path, sessions: &[String], method: &str) -> Result<Self> {
        if let Some(engine) =
            Self::open_cached(index, method, &|s| sessions.is_empty() || sessions.contains(&s.session))?
        {
            return Ok(engine);
        }
        let loaded = load_method(index, method, sessions)?;
        Self::from_loaded(index, loaded)
    }

    /// For a method whose search structure is cached in the index ([`searchers`]: toporec-plus),
    /// an engine over its rows `chosen` keeps, mapped from the cache (built and written first,
    /// when the cache is missing or stale); `None` for the other methods.
    pub fn open_cached(
        index: &Path,
        method: &str,
        chosen: &dyn Fn(&IndexedScan) -> bool,
    ) -> Result<Option<Self>> {
        let reader = IndexReader::open(index)?;
        let Some(manifest) = reader.manifest() else { return Ok(None) };
        let Some(entry) = manifest.methods.get(method) else { return Ok(None) };
        let Some(m) = entry.method(method) else { return Ok(None) };
        let MethodKind::ToporecPlus(params) = &m.kind else { return Ok(None) };
        let path = searchers::path(index, method);
        let (searcher, rows) = match searchers::open(
            &path,
            manifest.generation,
            &entry.id,
            crate::toporec_plus::SEARCHER_LAYOUT,
        ) {
            Some(cached) => {
                let (body, n) = (cached.header.body.0, cached.header.rows);
                let searcher = crate::toporec_plus::Searcher::mapped(cached.map, body, n, params.clone())
                    .map_err(|e| Error::index(&path, e))?;
                (searcher, cached.rows)
            }
            None => {
                let loaded = load_method(index, method, &[])?;
                let vectors: Vec<f32> =
                    loaded.scans.iter().flat_map(|s| s.descriptor.iter().copied()).collect();
                let searcher = crate::toporec_plus::Searcher::new(vectors, params.clone());
                let rows: Vec<IndexedScan> =
                    loaded.scans.into_iter().map(|s| IndexedScan { descriptor: Vec::new(), ..s }).collect();
                let header = searchers::Header {
                    format_version: searchers::FORMAT_VERSION,
                    generation: manifest.generation,
                    method: method.to_string(),
                    id: entry.id.clone(),
                    params: entry.params.clone(),
                    layout: crate::toporec_plus::SEARCHER_LAYOUT.to_string(),
                    rows: rows.len(),
                    sessions: Vec::new(),
                    body: (0, 0),
                };
                // An index that cannot be written (read-only, another user's) gets no cache.
                if let Err(e) = searchers::write(&path, &header, &rows, &searcher.bytes()) {
                    tracing::info!("{}: not cached ({e})", path.display());
                }
                (searcher, rows)
            }
        };
        let keep: Vec<usize> = (0..rows.len()).filter(|&i| chosen(&rows[i])).collect();
        let (searcher, rows) = if keep.len() == rows.len() {
            (searcher, rows)
        } else {
            let subset = searcher.subset(&keep);
            let rows = keep.iter().map(|&i| rows[i].clone()).collect();
            (subset, rows)
        };
        if rows.is_empty() {
            return Err(Error::index(index, format!("no {method} descriptors among the scans chosen")));
        }
        let describer = Describer {
            topological: false,
            computed: vec![m.clone()],
            ..Describer::toporec(Default::default(), true, None)
        };
        Ok(Some(Engine {
            describer,
            method: m,
            id: entry.id.clone(),
            scans: rows,
            search: Search::Plus(searcher),
        }))
    }

    /// An engine over descriptors already loaded from `index`.
    pub fn from_loaded(index: &Path, loaded: Loaded) -> Result<Self> {
        let Loaded { method, id, length, codebook, scans } = loaded;
        let describer = match &method.kind {
            MethodKind::Toporec => {
                let pipeline = crate::pipeline::config::Pipeline::of_index(index)?;
                Describer::toporec(pipeline.preprocess, pipeline.persistence.squared, codebook)
            }
            _ => Describer {
                topological: false,
                computed: if method.is_computed() { vec![method.clone()] } else { Vec::new() },
                ..Describer::toporec(Default::default(), true, None)
            },
        };
        let search = Search::over(&method, &scans, length);
        Ok(Engine { describer, method, id, scans, search })
    }

    /// An engine that searches `loaded` but describes nothing (`eval places`, whose queries
    /// are stored descriptors).
    pub fn search_only(loaded: Loaded) -> Self {
        let Loaded { method, id, length, scans, .. } = loaded;
        let search = Search::over(&method, &scans, length);
        let describer =
            Describer { topological: false, ..Describer::toporec(Default::default(), true, None) };
        Engine { describer, method, id, scans, search }
    }

    /// The engine over the database rows `keep` keeps, in their order (a subset of a cached
    /// structure is copied, not rebuilt).
    pub fn retain(mut self, keep: &dyn Fn(&IndexedScan) -> bool) -> Result<Self> {
        let rows: Vec<usize> = (0..self.scans.len()).filter(|&i| keep(&self.scans[i])).collect();
        if rows.len() == self.scans.len() {
            return Ok(self);
        }
        let scans: Vec<IndexedScan> = rows.iter().map(|&i| self.scans[i].clone()).collect();
        self.search = match self.search {
            Search::Plus(s) => Search::Plus(s.subset(&rows)),
            _ => {
                let length = scans.first().map_or(0, |s| s.descriptor.len());
                Search::over(&self.method, &scans, length)
            }
        };
        self.scans = scans;
        Ok(self)
    }

    /// The engine searching at `budget` instead of its method's own settings.
    pub fn with_budget(mut self, budget: SearchBudget) -> Self {
        if budget == SearchBudget::Default {
            return self;
        }
        let searched = budget.apply(&self.method, self.scans.len());
        self.search = match (self.search, &searched.kind) {
            // The same entries, other search settings: nothing rebuilt.
            (Search::Plus(s), MethodKind::ToporecPlus(p)) => {
                Search::Plus(s.with_search(p.candidates, p.search_ratio))
            }
            (search, _) => {
                let length = self.scans.first().map_or(0, |s| s.descriptor.len());
                if length == 0 { search } else { Search::over(&searched, &self.scans, length) }
            }
        };
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

    /// The `k` nearest database rows.
    pub fn search(&self, descriptor: &[f32], k: usize) -> Vec<Hit> {
        self.find(descriptor, k).0.into_iter().map(|f| (f.row, f.distance)).collect()
    }

    /// The `k` best database rows, with the time of each search step.
    pub fn find(&self, descriptor: &[f32], k: usize) -> (Vec<Found>, StepTimes) {
        self.find_many(descriptor, k).pop().unwrap_or_default()
    }

    /// The `k` best database rows of each query (`queries` is `m × length`, row-major), each
    /// charged its share of the search time.
    pub fn find_many(&self, queries: &[f32], k: usize) -> Vec<(Vec<Found>, StepTimes)> {
        match &self.search {
            Search::Vectors(db) => {
                let m = queries.len() / db.dim().max(1);
                let t = Instant::now();
                let hits = db.search_many(queries, k);
                let search = t.elapsed().as_secs_f64() / m.max(1) as f64;
                hits.into_iter()
                    .map(|h| {
                        let found =
                            h.into_iter().map(|(row, distance)| Found { row, distance, yaw_degrees: None });
                        (found.collect(), StepTimes { search, ..Default::default() })
                    })
                    .collect()
            }
            Search::ScanContext(sc) => queries
                .par_chunks(sc.params().len())
                .map(|q| {
                    let (hits, t) = sc.search(q, k);
                    let found = hits.into_iter().map(|(row, distance, shift)| Found {
                        row,
                        distance,
                        yaw_degrees: Some(scancontext::yaw_degrees(shift, sc.params())),
                    });
                    (
                        found.collect(),
                        StepTimes { search: t.candidates, rerank: t.rerank, ..Default::default() },
                    )
                })
                .collect(),
            Search::Solid(solid) => timed_each(queries, solid.params().len(), |q| {
                let yaw = |shift| crate::baselines::solid::yaw_degrees(shift, solid.params());
                solid
                    .search(q, k)
                    .into_iter()
                    .map(|(row, distance, shift)| (row, distance, yaw(shift)))
                    .collect()
            }),
            Search::ScanContextPp(pp) => timed_each(queries, pp.variant().len(), |q| pp.search(q, k)),
            Search::LidarIris(iris) => timed_each(queries, iris.params().len(), |q| iris.search(q, k)),
            Search::Plus(plus) => queries
                .par_chunks(plus.params().len())
                .map(|q| {
                    let (hits, t) = plus.search(q, k);
                    let found = hits.into_iter().map(|(row, distance, yaw)| Found {
                        row,
                        distance,
                        yaw_degrees: Some(yaw),
                    });
                    (
                        found.collect(),
                        StepTimes { search: t.candidates, rerank: t.rerank, ..Default::default() },
                    )
                })
                .collect(),
        }
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
            out.insert(0, Method { name, kind: MethodKind::Toporec });
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
pub fn load_method(index: &Path, method: &str, sessions: &[String]) -> Result<Loaded> {
    IndexReader::read_consistent(index, |reader| load_method_from(reader, method, sessions))
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
        return Err(Error::index(index, format!("no {method} descriptors{which}")));
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

/// An index's codebook and its TopoRec descriptors (only `sessions`, when not empty).
pub fn load_descriptors(index: &Path, sessions: &[String]) -> Result<(Codebook, Vec<IndexedScan>)> {
    let loaded = load_method(index, TOPOREC, sessions)?;
    Ok((loaded.codebook.expect("TopoRec has a codebook"), loaded.scans))
}

/// A scan stream for a path given on the command line: an MCAP, an NCLT session (or folder of
/// sessions, or `velodyne_hits.bin`), a KITTI sequence (or `sequences/`), or one cloud file.
pub fn open_path(path: &Path, topic: Option<&str>) -> Result<ScanStream> {
    let kind = InputKind::detect(path)?;
    if let Some(spec) = kind.source(path, topic)? {
        return Ok(spec.open()?);
    }
    let points = read_cloud_file(path, None);
    let id = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let item = match points {
        Ok((points, fingerprint)) => Ok(Scan {
            id: id.clone(),
            fingerprint,
            session: "query".into(),
            path: path.to_owned(),
            message_index: None,
            utime: 0,
            raw_points: points.len(),
            points,
            intensity: None,
            ring: None,
            pose: None,
            no_pose: Some(crate::sources::NoPose::NoGroundTruth),
        }),
        Err(e) => Err(ScanFailure::of_file(id, "query", path, None, e.to_string())),
    };
    Ok(Box::new(std::iter::once(item)))
}

/// What a query run did.
#[derive(Clone, Debug, Default)]
pub struct QueryReport {
    /// The method.
    pub method: Option<Method>,
    /// Queries answered.
    pub answered: usize,
    /// Queries that failed (each printed on stderr).
    pub failed: usize,
    /// Database scans searched.
    pub database: usize,
    /// Per-query step times.
    pub times: Vec<StepTimes>,
}

impl std::fmt::Display for QueryReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let Some(method) = &self.method else { return write!(f, "no queries") };
        let steps = step_summary(method, &self.times, false);
        write!(
            f,
            "{} queries against {} scans ({}); per query (mean / p95 ms): {steps}",
            self.answered, self.database, method.name
        )
    }
}

/// Mean and p95 (ms) of each step of a method's per-query times: every step, or (`search_only`)
/// those of the search.
pub fn step_stats(method: &Method, times: &[StepTimes], search_only: bool) -> Vec<(&'static str, f64, f64)> {
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
pub fn step_summary(method: &Method, times: &[StepTimes], search_only: bool) -> String {
    step_stats(method, times, search_only)
        .iter()
        .map(|(name, mean, p95)| format!("{name} {mean:.3} / {p95:.3}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The CSV header of query results (`yaw_deg`: ScanContext's yaw estimate, empty otherwise).
pub const CSV_HEADER: &str = "query_id,rank,scan_id,session,distance,pose_x,pose_y,pose_z,yaw_deg";

/// A described query: its id, descriptor and step times.
type Answerable = (String, Vec<f32>, StepTimes);

/// Queries per parallel chunk: descriptors in parallel, then one batched search.
const CHUNK: usize = 64;

/// Runs the queries of `args` against `engine`, streaming CSV rows to `out`; each failed
/// query is reported on stderr and counted.
pub fn run(
    engine: &Engine,
    args: &QueryArgs,
    out: &mut dyn Write,
    output_name: &Path,
) -> Result<QueryReport> {
    let mut report = QueryReport {
        method: Some(engine.method.clone()),
        database: engine.scans.len(),
        ..Default::default()
    };
    if args.k > engine.scans.len() {
        tracing::warn!("-k {}: the database holds {} scans; returning that many", args.k, engine.scans.len());
    }
    if !engine.describer.topological && !engine.method.is_computed() {
        return Err(Error::invalid(format!(
            "method `{}` has its vectors imported: `query` cannot describe new scans with it (`eval` compares stored ones)",
            engine.method.name
        )));
    }
    writeln!(out, "{CSV_HEADER}").at(output_name)?;
    for input in &args.inputs {
        let mut stream = open_path(input, args.topic.as_deref())?.peekable();
        while stream.peek().is_some() {
            let scans: Vec<_> = stream.by_ref().take(CHUNK).collect();
            let described: Vec<Result<Answerable, String>> = scans
                .into_par_iter()
                .map(|item| {
                    let scan = item.map_err(|f| f.error)?;
                    let id = scan.id.clone();
                    match engine.describe_scan(scan) {
                        Ok((v, times)) => Ok((id, v, times)),
                        Err(DescribeError::Skipped(reason)) => Err(format!("{id}: skipped: {reason}")),
                        Err(e) => Err(e.to_string()),
                    }
                })
                .collect();
            let flat: Vec<f32> =
                described.iter().filter_map(|r| r.as_ref().ok()).flat_map(|r| r.1.iter().copied()).collect();
            let mut found = engine.find_many(&flat, args.k).into_iter();
            for r in &described {
                let (id, _, t) = match r {
                    Ok(x) => x,
                    Err(e) => {
                        report.failed += 1;
                        eprintln!("error: {e}");
                        continue;
                    }
                };
                let (hits, search) = found.next().expect("one result per query");
                report.answered += 1;
                report.times.push(StepTimes { search: search.search, rerank: search.rerank, ..*t });
                for (rank, f) in hits.iter().enumerate() {
                    let s = &engine.scans[f.row];
                    let p = s.pose.map(|p| p.map(|x| format!("{x:?}"))).unwrap_or_default();
                    let yaw = f.yaw_degrees.map(|y| format!("{y:?}")).unwrap_or_default();
                    writeln!(
                        out,
                        "{},{},{},{},{:?},{},{},{},{yaw}",
                        csv_field(id),
                        rank + 1,
                        csv_field(&s.scan_id),
                        csv_field(&s.session),
                        f.distance,
                        p[0],
                        p[1],
                        p[2]
                    )
                    .at(output_name)?;
                }
            }
        }
    }
    out.flush().at(output_name)?;
    Ok(report)
}

/// Quotes a CSV field when needed (RFC 4180).
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

/// Mean and 95th percentile (nearest rank) of a sample, in milliseconds.
pub fn mean_p95_ms(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0);
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let p95 = s[((0.95 * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1];
    (1e3 * s.iter().sum::<f64>() / s.len() as f64, 1e3 * p95)
}
