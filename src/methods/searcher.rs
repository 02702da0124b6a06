//! The one search interface every method's structure implements ([`Searcher`]): it grows by
//! [`Searcher::push`], answers the `k` best rows for a query among all rows or among those a
//! rule allows (`loops` and the online detector), and takes a search budget
//! ([`SearchBudget`]) in place. `query`, `eval`, `loops` and the Python package search through
//! it and nothing else.

use rayon::prelude::*;

/// One answer of a search: the database row, the method's distance, and what the method
/// estimates of the query's pose relative to the row.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Hit {
    /// Database row.
    pub row: usize,
    /// Distance (Euclidean for vectors; the method's own for the others).
    pub distance: f64,
    /// The yaw of the query relative to the row (degrees, [0, 360), counter-clockwise seen from
    /// above), for the methods that estimate one.
    pub yaw_degrees: Option<f64>,
    /// The query's position in the row's sensor frame (x forward, y left, metres), for the
    /// methods that estimate one.
    pub offset: Option<[f64; 2]>,
}

impl Hit {
    /// A hit with a distance only.
    pub fn at(row: usize, distance: f64) -> Self {
        Hit { row, distance, ..Default::default() }
    }

    /// A hit with a distance and a yaw.
    pub fn turned(row: usize, distance: f64, yaw_degrees: f64) -> Self {
        Hit { row, distance, yaw_degrees: Some(yaw_degrees), offset: None }
    }
}

/// Seconds one search spent in each step. A method searched in one step charges it all to
/// `candidates`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SearchTimes {
    /// Narrowing the rows (keys' nearest neighbours; the whole search for one-step methods).
    pub candidates: f64,
    /// Re-ranking the candidates by the method's distance.
    pub rerank: f64,
}

/// Which rows a search may answer with: all, or those a rule admits.
pub type Allowed<'a> = Option<&'a dyn Fn(usize) -> bool>;

/// A method's search structure over database descriptors (rows `0..len()` in the order
/// pushed).
pub trait Searcher: Send + Sync {
    /// Rows.
    fn len(&self) -> usize;

    /// Whether there are no rows.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// One more row, after the others.
    fn push(&mut self, descriptor: &[f32]);

    /// The `k` best rows for `query` (among those `allowed` admits, when given), by (distance,
    /// row), with the time of each step. A search restricted to some rows answers as a
    /// searcher of those rows alone would.
    fn search(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> (Vec<Hit>, SearchTimes);

    /// [`Searcher::search`] of each query of `queries` (`m × dim`, row-major) over every row,
    /// in parallel.
    fn search_many(&self, queries: &[f32], dim: usize, k: usize) -> Vec<(Vec<Hit>, SearchTimes)> {
        queries.par_chunks(dim.max(1)).map(|q| self.search(q, k, None)).collect()
    }

    /// Searches at `budget` over `entries` rows from now on (the stored rows unchanged).
    fn set_budget(&mut self, budget: SearchBudget, entries: usize);

    /// The rows `rows` (in that order) in a searcher of their own, when the structure can copy
    /// them without their descriptors (a mapped cache); `None`: rebuild from the descriptors.
    fn subset(&self, _rows: &[usize]) -> Option<Box<dyn Searcher>> {
        None
    }

    /// The structure's bytes as a cache file's body holds them, for the methods whose structure
    /// is cached in the index ([`super::Computed::cache_layout`]).
    fn bytes(&self) -> Option<std::borrow::Cow<'_, [u8]>> {
        None
    }

    /// What failed, when bytes a search read from a mapped cache failed their checksum
    /// ([`crate::checked_map`]): the answers of every search since it was opened are then not
    /// to be trusted.
    fn damage(&self) -> Option<String> {
        None
    }
}

/// How much a method's search re-ranks (`eval --search`), so that methods compare at equal
/// budgets. Methods searched by exact k-NN (TopoRec, M2DP) search every entry at any budget.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SearchBudget {
    /// Each method's own settings (ScanContext: 10 ring-key candidates, ±3 sectors around
    /// the sector-key alignment; toporec-plus: 50 candidates).
    #[default]
    Default,
    /// Every database entry re-ranked at every shift (toporec-plus: of every turned grid).
    Exhaustive,
    /// The same for every method that has them: this many re-ranked candidates, and the
    /// shifts within ±`MATCHED_SHIFTS` sectors of the coarse alignment.
    Matched(usize),
}

/// The shift range of a matched budget, in sectors each side (ScanContext's default).
pub(crate) const MATCHED_SHIFTS: usize = 3;

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
    /// The candidates and the shift share (`search_ratio`) of a method searched by candidates
    /// and shifts, with `sectors` shifts, over `entries` rows; `None` at the default budget
    /// (the method's own settings).
    pub fn candidates_and_ratio(self, sectors: usize, entries: usize) -> Option<(usize, f64)> {
        match self {
            SearchBudget::Default => None,
            SearchBudget::Exhaustive => Some((entries.max(1), 1.0)),
            // A share of the sectors that gives MATCHED_SHIFTS each side: round(0.5 · ratio · sectors).
            SearchBudget::Matched(n) => {
                Some((n, (2.0 * MATCHED_SHIFTS as f64 / sectors.max(1) as f64).min(1.0)))
            }
        }
    }

    /// The candidates of a method searched by candidates alone (its shifts fixed) over
    /// `entries` rows; `None` at the default budget.
    pub fn candidates(self, entries: usize) -> Option<usize> {
        self.candidates_and_ratio(1, entries).map(|(n, _)| n)
    }
}

/// The `k` smallest of `scored` by (distance, row): selected in linear time, then sorted.
pub(crate) fn k_best(mut scored: Vec<(usize, f64)>, k: usize) -> Vec<(usize, f64)> {
    let order = |a: &(usize, f64), b: &(usize, f64)| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0));
    if k == 0 {
        return Vec::new();
    }
    if scored.len() > k {
        scored.select_nth_unstable_by(k - 1, order);
        scored.truncate(k);
    }
    scored.sort_by(order);
    scored
}

/// The rows `0..n` that `allowed` admits.
pub(crate) fn allowed_rows(n: usize, allowed: Allowed<'_>) -> impl Iterator<Item = usize> + '_ {
    (0..n).filter(move |&r| allowed.is_none_or(|a| a(r)))
}

/// The yaw (degrees, in [0, 360)) that a circular shift by `shift` of `sectors` columns stands
/// for.
pub fn shift_degrees(shift: usize, sectors: usize) -> f64 {
    shift as f64 * 360.0 / sectors as f64
}

/// Times one search charged to a single step.
pub fn timed<T>(f: impl FnOnce() -> T) -> (T, SearchTimes) {
    let t = std::time::Instant::now();
    let out = f();
    (out, SearchTimes { candidates: t.elapsed().as_secs_f64(), rerank: 0.0 })
}
