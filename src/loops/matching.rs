//! The search: the scans walked in time order, each matched with its best allowed earlier
//! scans by the method's own search, restricted to them ([`Allowed`]), as the online
//! [`super::Detector`] matches them one at a time.

use super::exclusion::{Exclusion, allowed_by, distance3};
use super::row::{LoopRow, Match};
use crate::error::{Error, Result};
use crate::search::Engine;
use crate::sinks::index::damage::Damage;
use crate::sinks::index::reader::IndexedScan;
use std::collections::HashMap;
use std::path::Path;

/// The scans' walking order: by timestamp (none last), then session and scan id.
pub(crate) fn time_order(scans: &[IndexedScan]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..scans.len()).collect();
    order.sort_by(|&a, &b| {
        let (x, y) = (&scans[a], &scans[b]);
        (x.utime.is_none(), x.utime, &x.session, &x.scan_id).cmp(&(
            y.utime.is_none(),
            y.utime,
            &y.session,
            &y.scan_id,
        ))
    });
    order
}

/// The best two allowed matches of every scan with an earlier allowed scan, in time order:
/// `(query row, [(row, distance, yaw)], …)`.
pub(super) type Matches = Vec<(usize, Vec<crate::methods::Hit>)>;

/// Which scans each scan may be matched with: earlier in `time_order`, and outside its own
/// session's exclusion window.
pub struct Allowed<'a> {
    scans: &'a [IndexedScan],
    exclusion: Exclusion,
    /// The scans in time order.
    pub order: Vec<usize>,
    position: Vec<usize>,
    in_session: Vec<usize>,
}

impl<'a> Allowed<'a> {
    /// The rule over `scans`.
    pub fn new(scans: &'a [IndexedScan], exclusion: Exclusion) -> Self {
        let order = time_order(scans);
        let mut position = vec![0usize; scans.len()];
        for (p, &row) in order.iter().enumerate() {
            position[row] = p;
        }
        // Position within the session's own time order, for `Exclusion::Scans`.
        let mut in_session = vec![0usize; scans.len()];
        let mut seen: HashMap<&str, usize> = HashMap::new();
        for &row in &order {
            let n = seen.entry(scans[row].session.as_str()).or_insert(0);
            in_session[row] = *n;
            *n += 1;
        }
        Allowed { scans, exclusion, order, position, in_session }
    }

    /// The position of `row` in the time order.
    pub fn position(&self, row: usize) -> usize {
        self.position[row]
    }

    /// Whether `row` may be matched with `query`.
    pub fn allows(&self, query: usize, row: usize) -> bool {
        let scans = self.scans;
        if self.position[row] >= self.position[query] {
            return false;
        }
        // Sessions compared by name: 0 for the query's, 1 for another.
        let session = |r: usize| u32::from(scans[r].session != scans[query].session);
        allowed_by(
            self.exclusion,
            (0, self.in_session[query], scans[query].utime),
            (session(row), self.in_session[row], scans[row].utime),
        )
    }

    /// Which scans have an allowed scan within `radius` metres (both with poses, in one frame:
    /// `frame_of` gives a session's): the scans a true loop could be found for.
    pub fn with_revisit(&self, radius: f64, frame_of: &dyn Fn(&str) -> usize) -> Vec<bool> {
        let frame: Vec<usize> = self.scans.iter().map(|s| frame_of(&s.session)).collect();
        let cell = |p: [f64; 3]| p.map(|c| (c / radius).floor() as i64);
        let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
        for (row, s) in self.scans.iter().enumerate() {
            if let Some(p) = s.pose {
                grid.entry(cell(p)).or_default().push(row);
            }
        }
        let near = |query: usize, q: [f64; 3], c: [i64; 3]| {
            grid.get(&c).is_some_and(|rows| {
                rows.iter().any(|&r| {
                    frame[r] == frame[query]
                        && self.allows(query, r)
                        && self.scans[r].pose.is_some_and(|p| distance3(p, q) <= radius)
                })
            })
        };
        (0..self.scans.len())
            .map(|query| {
                let Some(q) = self.scans[query].pose else { return false };
                let c = cell(q);
                (0..27).any(|k| near(query, q, [c[0] + k % 3 - 1, c[1] + k / 3 % 3 - 1, c[2] + k / 9 - 1]))
            })
            .collect()
    }
}

/// Every scan's best allowed earlier matches (up to two), in time order, counting the scans
/// searched on `bar`; `queries[i]` is the descriptor of `engine.scans[i]`, and `rule` is over
/// `engine.scans`. The scans are searched in one structure holding them in time order, each
/// query restricted to its allowed rows: the matches a [`Detector`] given the scans in that
/// order finds.
pub(super) fn best_matches_counted(
    engine: &Engine,
    queries: &[Vec<f32>],
    rule: &Allowed,
    bar: Option<&indicatif::ProgressBar>,
) -> Matches {
    use rayon::prelude::*;
    let order = &rule.order;
    let mut growing = engine.method.searcher(Vec::new(), queries.first().map_or(0, |d| d.len()));
    for &row in order {
        growing.push(&queries[row]);
    }
    order
        .par_iter()
        .enumerate()
        .filter_map(|(at, &query)| {
            if let Some(b) = bar {
                b.inc(1);
            }
            let allowed = |position: usize| position < at && rule.allows(query, order[position]);
            let (best, _) = growing.search(&queries[query], 2, Some(&allowed));
            (!best.is_empty()).then(|| {
                (query, best.into_iter().map(|h| crate::methods::Hit { row: order[h.row], ..h }).collect())
            })
        })
        .collect()
}

/// The rows of one method: each scan's best allowed match, not yet accepted (the threshold
/// decides that), the scans' vertices their positions in `rule`'s time order.
pub fn rows(engine: &Engine, matches: &Matches, rule: &Allowed) -> Vec<LoopRow> {
    let scans = &engine.scans;
    matches
        .iter()
        .filter_map(|(query, best)| {
            let row = best.first()?.row;
            let (q, m) = (&scans[*query], &scans[row]);
            let truth = match (q.pose, m.pose) {
                (Some(a), Some(b)) => Some(distance3(a, b)),
                _ => None,
            };
            let found = Match::of_hits(best, rule.position(row), truth)?;
            Some(LoopRow {
                method: engine.method.name.clone(),
                query_scan: q.scan_id.clone(),
                query_session: q.session.clone(),
                matched_scan: m.scan_id.clone(),
                matched_session: m.session.clone(),
                query_vertex: rule.position(*query),
                found,
                check: None,
                in_map: None,
            })
        })
        .collect()
}

/// The descriptor of each of `engine`'s scans: its own, or read from the index when the
/// engine searches a cached structure that keeps none (toporec-plus).
pub(super) fn query_descriptors(index: &Path, engine: &Engine, damage: &Damage) -> Result<Vec<Vec<f32>>> {
    if engine.scans.iter().all(|s| !s.descriptor.is_empty()) {
        return Ok(engine.scans.iter().map(|s| s.descriptor.clone()).collect());
    }
    let loaded = crate::search::load_method(index, &engine.method.name, &[], damage)?;
    let mut by_id: HashMap<String, Vec<f32>> =
        loaded.scans.into_iter().map(|s| (s.scan_id, s.descriptor)).collect();
    engine
        .scans
        .iter()
        .map(|s| {
            by_id.remove(&s.scan_id).ok_or_else(|| {
                Error::index(index, format!("scan {} has no {} descriptor", s.scan_id, engine.method.name))
            })
        })
        .collect()
}
