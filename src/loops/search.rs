//! A search structure that grows by one scan at a time and answers for the scans a rule
//! allows: the loop detector's ([`super::Detector`]) and `toporec loops`' (which holds every
//! scan in time order and allows each query the earlier ones outside its exclusion window, so
//! both give the same matches).
//!
//! Each method searches as its own searcher does at its default budget, restricted to the
//! allowed rows: toporec-plus by its keys and its distance ([`crate::toporec_plus::Searcher`]),
//! ScanContext by its ring keys' nearest allowed rows re-ranked by its distance, SOLiD by its
//! exact distance to every allowed row, Scan Context++ and LiDAR-Iris by their keys' nearest
//! allowed rows re-ranked by their distances, the others (TopoRec, M2DP, imported vectors) by exact
//! Euclidean distance. Ties go to the lower row.

use crate::baselines::{Method, MethodKind, lidar_iris, scancontext, scancontext_pp, solid};
use crate::toporec_plus;

/// A hit: row, distance, and the yaw of the query relative to the row (degrees), for the
/// methods that estimate one.
pub type LoopHit = (usize, f64, Option<f64>);

/// The growing search structure of one method.
pub struct Growing(Inner);

enum Inner {
    /// toporec-plus's own searcher.
    Plus(toporec_plus::Searcher),
    /// ScanContext: descriptors and ring keys.
    ScanContext { params: scancontext::ScanContextParams, descriptors: Vec<f32>, keys: Vec<f32> },
    /// Scan Context++'s own searcher.
    ScanContextPp(scancontext_pp::Searcher),
    /// LiDAR-Iris's own searcher.
    LidarIris(lidar_iris::Searcher),
    /// SOLiD: descriptors.
    Solid { params: solid::SolidParams, descriptors: Vec<f32> },
    /// Exact Euclidean search over vectors of `dim` values.
    Euclidean { dim: usize, vectors: Vec<f32> },
}

impl Growing {
    /// An empty structure for `method`'s descriptors of `length` values.
    pub fn new(method: &Method, length: usize) -> Self {
        Growing(match &method.kind {
            MethodKind::ToporecPlus(p) => Inner::Plus(toporec_plus::Searcher::new(Vec::new(), p.clone())),
            MethodKind::ScanContext(p) => {
                Inner::ScanContext { params: p.clone(), descriptors: Vec::new(), keys: Vec::new() }
            }
            MethodKind::Solid(p) => Inner::Solid { params: p.clone(), descriptors: Vec::new() },
            MethodKind::LidarIris(p) => Inner::LidarIris(lidar_iris::Searcher::new(Vec::new(), p.clone())),
            MethodKind::ScanContextPp(_) | MethodKind::ScanContextPpCart(_) => {
                Inner::ScanContextPp(scancontext_pp::Searcher::new(
                    Vec::new(),
                    method.scancontext_pp_variant().expect("Scan Context++"),
                ))
            }
            _ => Inner::Euclidean { dim: length.max(1), vectors: Vec::new() },
        })
    }

    /// Rows.
    pub fn len(&self) -> usize {
        match &self.0 {
            Inner::Plus(s) => s.len(),
            Inner::ScanContext { params, descriptors, .. } => descriptors.len() / params.len(),
            Inner::Solid { params, descriptors } => descriptors.len() / params.len(),
            Inner::ScanContextPp(s) => s.len(),
            Inner::LidarIris(s) => s.len(),
            Inner::Euclidean { dim, vectors } => vectors.len() / dim,
        }
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// One more row, after the others.
    pub fn push(&mut self, descriptor: &[f32]) {
        match &mut self.0 {
            Inner::Plus(s) => s.push(descriptor),
            Inner::ScanContext { params, descriptors, keys } => {
                descriptors.extend_from_slice(descriptor);
                keys.extend(scancontext::ring_key(descriptor, params));
            }
            Inner::Solid { descriptors, .. } => descriptors.extend_from_slice(descriptor),
            Inner::ScanContextPp(s) => s.push(descriptor),
            Inner::LidarIris(s) => s.push(descriptor),
            Inner::Euclidean { vectors, .. } => vectors.extend_from_slice(descriptor),
        }
    }

    /// The `k` best rows for `query` among those `allowed` admits, by (distance, row).
    pub fn search(&self, query: &[f32], k: usize, allowed: &dyn Fn(usize) -> bool) -> Vec<LoopHit> {
        let rows = (0..self.len()).filter(|&r| allowed(r));
        // The k smallest by (distance, row): selected in linear time, then sorted.
        let best = |mut scored: Vec<(usize, f64, Option<f64>)>, k: usize| {
            let order = |a: &LoopHit, b: &LoopHit| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0));
            if k == 0 {
                return Vec::new();
            }
            if scored.len() > k {
                scored.select_nth_unstable_by(k - 1, order);
                scored.truncate(k);
            }
            scored.sort_by(order);
            scored
        };
        match &self.0 {
            Inner::Plus(s) => s
                .search_where(query, k, allowed)
                .0
                .into_iter()
                .map(|(row, d, yaw)| (row, d, Some(yaw)))
                .collect(),
            Inner::ScanContext { params: p, descriptors, keys } => {
                // The ring key's nearest allowed rows (exact, squared distances in f64), then
                // the ScanContext distance of each.
                let key = scancontext::ring_key(query, p);
                let by_key: Vec<(usize, f64, Option<f64>)> = rows
                    .map(|r| {
                        let e = &keys[r * p.rings..(r + 1) * p.rings];
                        (r, key.iter().zip(e).map(|(&a, &b)| (a as f64 - b as f64).powi(2)).sum(), None)
                    })
                    .collect();
                let candidates = best(by_key, p.candidates.max(k));
                scancontext::rerank(query, descriptors, candidates.into_iter().map(|c| c.0), k, p)
                    .into_iter()
                    .map(|(r, d, shift)| (r, d, Some(scancontext::yaw_degrees(shift, p))))
                    .collect()
            }
            Inner::ScanContextPp(s) => {
                s.search_where(query, k, allowed).into_iter().map(|(r, d, yaw)| (r, d, Some(yaw))).collect()
            }
            Inner::LidarIris(s) => {
                s.search_where(query, k, allowed).into_iter().map(|(r, d, yaw)| (r, d, Some(yaw))).collect()
            }
            Inner::Solid { params: p, descriptors } => solid::ranked(query, descriptors, rows, k, p)
                .into_iter()
                .map(|(r, d, shift)| (r, d, Some(solid::yaw_degrees(shift, p))))
                .collect(),
            Inner::Euclidean { dim, vectors } => {
                let scored = rows
                    .map(|r| {
                        let v = &vectors[r * dim..(r + 1) * dim];
                        (r, query.iter().zip(v).map(|(&a, &b)| (a as f64 - b as f64).powi(2)).sum(), None)
                    })
                    .collect();
                best(scored, k).into_iter().map(|(r, d2, y)| (r, f64::sqrt(d2), y)).collect()
            }
        }
    }
}
