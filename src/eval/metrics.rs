//! Place-recognition metrics (PointNetVLAD's `evaluate.py`; the cross-day NCLT protocol of RING): Recall@N and Recall@1 %.
//!
//! A query's retrieval is its database rows sorted by (distance, row) — ties go to the lower
//! row, deterministically. Its *first hit* is the 0-based rank of the first true match.
//! Recall@N = share of queries whose first hit is at rank < N; Recall@1 % uses the top
//! `max(round_half_even(n_db / 100), 1)` rows (Python 3 rounding, as PointNetVLAD's script).
//! Two denominators: queries with at least one true match in the database (PointNetVLAD) or
//! all queries (RING / NCLT: a query without any match counts as a failure).

/// Which queries the recall is divided by.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Denominator {
    /// Queries with at least one true match (PointNetVLAD).
    WithMatch,
    /// All queries (RING / NCLT).
    All,
}

/// The top-k size of Recall@1 %: `max(round_half_even(n_db / 100), 1)`.
pub fn one_percent_k(n_db: usize) -> usize {
    ((n_db as f64 / 100.0).round_ties_even() as usize).max(1)
}

/// Rank of the first retrieved row that is a true match, if any.
pub fn first_hit(retrieved: &[usize], is_match: impl Fn(usize) -> bool) -> Option<usize> {
    retrieved.iter().position(|&r| is_match(r))
}

/// Recall figures for one set of queries.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Recall {
    /// The denominator used.
    pub denominator: Denominator,
    /// Queries counted in the denominator.
    pub evaluated: usize,
    /// Recall@N in percent for N = 1..=len.
    pub at_n: Vec<f64>,
    /// Recall@1 % in percent.
    pub at_one_percent: f64,
    /// The k of Recall@1 %.
    pub one_percent_k: usize,
}

/// Computes recall from each query's first hit (`None`: no match retrieved) and whether it
/// has any true match in the database at all.
pub fn recall(
    first_hits: &[Option<usize>],
    has_match: &[bool],
    max_n: usize,
    n_db: usize,
    denominator: Denominator,
) -> Recall {
    assert_eq!(first_hits.len(), has_match.len());
    let k1 = one_percent_k(n_db);
    let counted: Vec<Option<usize>> = first_hits
        .iter()
        .zip(has_match)
        .filter(|(_, m)| denominator == Denominator::All || **m)
        .map(|(h, _)| *h)
        .collect();
    let evaluated = counted.len();
    let pct = |hits: usize| if evaluated == 0 { 0.0 } else { 100.0 * hits as f64 / evaluated as f64 };
    let at_n =
        (1..=max_n).map(|n| pct(counted.iter().filter(|h| h.is_some_and(|r| r < n)).count())).collect();
    let at_one_percent = pct(counted.iter().filter(|h| h.is_some_and(|r| r < k1)).count());
    Recall { denominator, evaluated, at_n, at_one_percent, one_percent_k: k1 }
}
