//! Place-recognition metrics (PointNetVLAD's `evaluate.py`; the cross-day NCLT protocol of RING): Recall@N and Recall@1 %.
//!
//! A query's retrieval is its database rows sorted by (distance, row) — ties go to the lower
//! row, deterministically. Its *first hit* is the 0-based rank of the first true match.
//! Recall@N = share of queries whose first hit is at rank < N; Recall@1 % uses the top
//! `max(round_half_even(n_db / 100), 1)` rows (Python 3 rounding, as PointNetVLAD's script).
//! Two denominators: queries with at least one true match in the database (PointNetVLAD) or
//! all queries (RING / NCLT: a query without any match counts as a failure).

/// Which queries the recall is divided by.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, schemars::JsonSchema)]
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
#[derive(Clone, Debug, PartialEq, serde::Serialize, schemars::JsonSchema)]
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

/// One point of a precision–recall curve: queries whose top-1 distance is at most
/// `threshold` are accepted as loop closures.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, schemars::JsonSchema)]
pub struct PrPoint {
    /// Descriptor-distance threshold.
    pub threshold: f64,
    /// True positives / accepted, in percent.
    pub precision: f64,
    /// True positives / (true positives + false negatives), in percent.
    pub recall: f64,
}

/// Loop-closure detection as SLAM front ends use it: a query's top-1 is accepted when its
/// descriptor distance is at most a threshold; an accepted top-1 within the revisit radius of
/// the query is a true positive, one farther a false positive; a rejected query that has a
/// database scan within the radius is a false negative. The threshold is swept over every
/// top-1 distance.
#[derive(Clone, Debug, PartialEq, serde::Serialize, schemars::JsonSchema)]
pub struct LoopClosure {
    /// Queries.
    pub queries: usize,
    /// Queries with a database scan within the radius.
    pub revisits: usize,
    /// The largest F1 (percent) along the curve.
    pub f1_max: f64,
    /// The threshold that attains it.
    pub f1_max_threshold: Option<f64>,
    /// The largest recall (percent) with no false positive.
    pub recall_at_full_precision: f64,
    /// The curve, by increasing threshold (one point per distinct top-1 distance).
    pub curve: Vec<PrPoint>,
}

/// [`LoopClosure`] of queries given each one's top-1 distance, whether that top-1 lies within
/// the radius, and whether any database scan does.
pub fn loop_closure(top1_distance: &[f64], top1_within: &[bool], has_revisit: &[bool]) -> LoopClosure {
    assert!(top1_distance.len() == top1_within.len() && top1_within.len() == has_revisit.len());
    let revisits = has_revisit.iter().filter(|&&h| h).count();
    let mut order: Vec<usize> = (0..top1_distance.len()).collect();
    order.sort_by(|&a, &b| top1_distance[a].total_cmp(&top1_distance[b]).then(a.cmp(&b)));
    let (mut tp, mut fp, mut accepted_revisits) = (0usize, 0usize, 0usize);
    let mut out = LoopClosure {
        queries: top1_distance.len(),
        revisits,
        f1_max: 0.0,
        f1_max_threshold: None,
        recall_at_full_precision: 0.0,
        curve: Vec::new(),
    };
    for (j, &i) in order.iter().enumerate() {
        if top1_within[i] {
            tp += 1;
        } else {
            fp += 1;
        }
        if has_revisit[i] {
            accepted_revisits += 1;
        }
        // Equal distances are accepted together.
        if order.get(j + 1).is_some_and(|&next| top1_distance[next] == top1_distance[i]) {
            continue;
        }
        let false_negatives = revisits - accepted_revisits;
        let precision = tp as f64 / (tp + fp) as f64;
        let recall = if tp + false_negatives == 0 { 0.0 } else { tp as f64 / (tp + false_negatives) as f64 };
        out.curve.push(PrPoint {
            threshold: top1_distance[i],
            precision: 100.0 * precision,
            recall: 100.0 * recall,
        });
        if precision + recall > 0.0 {
            let f1 = 200.0 * precision * recall / (precision + recall);
            if f1 > out.f1_max {
                out.f1_max = f1;
                out.f1_max_threshold = Some(top1_distance[i]);
            }
        }
        if fp == 0 {
            out.recall_at_full_precision = 100.0 * recall;
        }
    }
    out
}

/// The area under a precision–recall curve (0–1): the precision of each point times the recall
/// it adds over the point before (from recall 0), as average precision is computed.
pub(crate) fn pr_auc(curve: &[PrPoint]) -> f64 {
    let mut last_recall = 0.0;
    let mut area = 0.0;
    for p in curve {
        area += (p.recall - last_recall).max(0.0) / 100.0 * p.precision / 100.0;
        last_recall = last_recall.max(p.recall);
    }
    area
}

/// Extended precision (percent): the mean of the precision at the lowest threshold (the curve's
/// first point, the least recall) and the recall at 100 % precision — Ferrarini, Waheed,
/// Waheed, Ehsan, Milford and McDonald-Maier, *Exploring performance bounds of visual place
/// recognition using extended precision*, IEEE RA-L 5(2), 2020. 0 for an empty curve.
pub(crate) fn extended_precision(lc: &LoopClosure) -> f64 {
    lc.curve.first().map_or(0.0, |first| (first.precision + lc.recall_at_full_precision) / 2.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Five queries, by hand:
    ///
    /// | query | top-1 distance | top-1 within R | a scan within R |
    /// |---|---|---|---|
    /// | a | 0.1 | yes | yes |
    /// | b | 0.2 | yes | yes |
    /// | c | 0.3 | no  | yes |
    /// | d | 0.4 | yes | yes |
    /// | e | 0.5 | no  | no  |
    ///
    /// threshold 0.1: TP 1, FP 0, FN 3 (b, c, d rejected with a revisit): P 100, R 25, F1 40;
    /// 0.2: TP 2, FP 0, FN 2: P 100, R 50, F1 66.7; 0.3: TP 2, FP 1 (c), FN 1 (d): P 66.7,
    /// R 66.7, F1 66.7; 0.4: TP 3, FP 1, FN 0: P 75, R 100, F1 85.7; 0.5: TP 3, FP 2: P 60,
    /// R 100, F1 75. F1 max 85.7 at 0.4; recall at 100 % precision 50.
    #[test]
    fn precision_recall_matches_the_hand_computed_example() {
        let lc = loop_closure(
            &[0.3, 0.1, 0.5, 0.2, 0.4],
            &[false, true, false, true, true],
            &[true, true, false, true, true],
        );
        let want = [
            (0.1, 100.0, 25.0),
            (0.2, 100.0, 50.0),
            (0.3, 200.0 / 3.0, 200.0 / 3.0),
            (0.4, 75.0, 100.0),
            (0.5, 60.0, 100.0),
        ];
        assert_eq!(lc.curve.len(), 5);
        for (p, (t, prec, rec)) in lc.curve.iter().zip(want) {
            assert_eq!(p.threshold, t);
            assert!((p.precision - prec).abs() < 1e-9 && (p.recall - rec).abs() < 1e-9, "{p:?}");
        }
        assert!((lc.f1_max - 600.0 / 7.0).abs() < 1e-9, "{}", lc.f1_max);
        assert_eq!(lc.f1_max_threshold, Some(0.4));
        assert_eq!(lc.recall_at_full_precision, 50.0);
        assert_eq!((lc.queries, lc.revisits), (5, 4));
        // AUC: 0.25 × 1 + 0.25 × 1 + (2/3 − 1/2) × 2/3 + (1 − 2/3) × 3/4 + 0 = 0.8611…
        let auc = 0.25 + 0.25 + (2.0 / 3.0 - 0.5) * (2.0 / 3.0) + (1.0 / 3.0) * 0.75;
        assert!((pr_auc(&lc.curve) - auc).abs() < 1e-12, "{}", pr_auc(&lc.curve));
        // EP: precision 100 at the first threshold, recall 50 at 100 % precision.
        assert_eq!(extended_precision(&lc), 75.0);
    }

    #[test]
    fn ties_are_accepted_together() {
        let lc = loop_closure(&[0.2, 0.2, 0.1], &[true, false, true], &[true, true, true]);
        assert_eq!(lc.curve.len(), 2);
        assert!((lc.curve[1].precision - 200.0 / 3.0).abs() < 1e-9);
        assert!((lc.recall_at_full_precision - 100.0 / 3.0).abs() < 1e-9);
    }
}
