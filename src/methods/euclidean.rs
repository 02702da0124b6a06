//! Exact k-nearest-neighbour search over descriptors (Euclidean): the search of TopoRec, M2DP
//! and imported vectors (`Euclidean`), and of ScanContext's ring keys.
//!
//! Three routes, one answer: a kiddo k-d tree for short descriptors (b ≤ 16, padded with
//! zeros to 4, 8 or 16 — padding does not change distances), a batched matrix product
//! (nalgebra) for long ones — `‖q − x‖² = ‖q‖² + ‖x‖² − 2 q·x` in f32 picks candidates, which are
//! re-ranked with exact f64 distances, and a query whose candidate cut is not provably safe
//! under the f32 error bound falls back to the scan — and the plain scan itself
//! ([`Database::brute_force`]), the reference. Results are `(row, distance)` sorted by
//! (distance, row), distances computed in f64 from the f32 descriptors.

use super::searcher::{Allowed, Hit, SearchBudget, SearchTimes, Searcher, allowed_rows, k_best};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::DMatrix;
use rayon::prelude::*;
use std::num::NonZeroUsize;

/// A neighbour: database row and Euclidean distance.
pub(crate) type Neighbour = (usize, f64);

enum Tree {
    K4(ImmutableKdTree<f64, 4>),
    K8(ImmutableKdTree<f64, 8>),
    K16(ImmutableKdTree<f64, 16>),
}

/// Database descriptors with a search structure.
pub struct Database {
    b: usize,
    /// Column-major `b × n`: each column a descriptor — the same memory as row-major `n × b`.
    matrix: DMatrix<f32>,
    tree: Option<Tree>,
    norms: Vec<f32>,
    max_norm: f32,
}

/// Descriptors up to this length use the k-d tree.
pub(crate) const KD_TREE_MAX_B: usize = 16;

fn padded<const K: usize>(v: &[f32]) -> [f64; K] {
    let mut out = [0.0; K];
    out.iter_mut().zip(v).for_each(|(o, &x)| *o = x as f64);
    out
}

/// The k-d tree of `rows` padded to `K` values; `None` when kiddo refuses them.
fn built<const K: usize>(rows: &[&[f32]]) -> Option<ImmutableKdTree<f64, K>> {
    ImmutableKdTree::new_from_slice(&rows.iter().map(|r| padded::<K>(r)).collect::<Vec<_>>()).ok()
}

/// The `n` rows of a tree nearest `q`.
fn nearest<const K: usize>(tree: &ImmutableKdTree<f64, K>, q: &[f32], n: NonZeroUsize) -> Vec<usize> {
    let point = padded::<K>(q);
    let found = tree.query(&point).nearest_n::<SquaredEuclidean<f64>>(n).execute();
    found.iter().map(|h| h.item as usize).collect()
}

impl Database {
    /// Builds the database over `vectors` (`n × b`, row-major).
    pub fn new(vectors: Vec<f32>, b: usize) -> Self {
        assert!(b > 0 && vectors.len().is_multiple_of(b), "vectors must be n × b");
        let rows: Vec<&[f32]> = vectors.chunks_exact(b).collect();
        // (A tree that cannot be built — kiddo refuses some degenerate inputs — means the
        // matrix route.)
        let tree = if b <= KD_TREE_MAX_B && !rows.is_empty() {
            match b {
                0..=4 => built::<4>(&rows).map(Tree::K4),
                5..=8 => built::<8>(&rows).map(Tree::K8),
                _ => built::<16>(&rows).map(Tree::K16),
            }
        } else {
            None
        };
        let norms: Vec<f32> = rows.iter().map(|r| r.iter().map(|x| x * x).sum::<f32>().sqrt()).collect();
        let max_norm = norms.iter().copied().fold(0.0, f32::max);
        let n = rows.len();
        let matrix = DMatrix::from_vec(b, n, vectors);
        Database { b, matrix, tree, norms, max_norm }
    }

    /// Rows.
    pub fn len(&self) -> usize {
        self.matrix.ncols()
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Descriptor length.
    pub fn dim(&self) -> usize {
        self.b
    }

    /// The descriptors, row-major (`n × b`).
    pub fn vectors(&self) -> &[f32] {
        self.matrix.as_slice()
    }

    /// Exact squared distance in f64.
    fn dist2(&self, q: &[f32], row: usize) -> f64 {
        let x = &self.matrix.as_slice()[row * self.b..(row + 1) * self.b];
        q.iter().zip(x).map(|(&a, &b)| (a as f64 - b as f64).powi(2)).sum()
    }

    fn finish(mut hits: Vec<(usize, f64)>, k: usize) -> Vec<Neighbour> {
        hits.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        hits.truncate(k);
        hits.into_iter().map(|(i, d2)| (i, d2.sqrt())).collect()
    }

    /// The reference: scan every row.
    pub fn brute_force(&self, q: &[f32], k: usize) -> Vec<Neighbour> {
        assert_eq!(q.len(), self.b, "query length");
        Self::finish((0..self.len()).map(|i| (i, self.dist2(q, i))).collect(), k)
    }

    /// The `k` nearest rows of one query.
    pub fn search(&self, q: &[f32], k: usize) -> Vec<Neighbour> {
        self.search_many(q, k).pop().unwrap_or_default()
    }

    /// The `k` nearest rows of each query (`queries` is `m × b`, row-major), in parallel.
    pub fn search_many(&self, queries: &[f32], k: usize) -> Vec<Vec<Neighbour>> {
        assert_eq!(queries.len() % self.b, 0, "queries must be m × b");
        let k = k.min(self.len());
        if k == 0 {
            return vec![Vec::new(); queries.len() / self.b];
        }
        match &self.tree {
            Some(tree) => queries.par_chunks(self.b).map(|q| self.tree_search(tree, q, k)).collect(),
            None => queries
                .par_chunks(self.b * MATRIX_BLOCK)
                .flat_map_iter(|block| self.matrix_search(block, k))
                .collect(),
        }
    }

    fn tree_search(&self, tree: &Tree, q: &[f32], k: usize) -> Vec<Neighbour> {
        let n = NonZeroUsize::new(k).expect("k > 0");
        let rows = match tree {
            Tree::K4(t) => nearest::<4>(t, q, n),
            Tree::K8(t) => nearest::<8>(t, q, n),
            Tree::K16(t) => nearest::<16>(t, q, n),
        };
        // Same distance formula as the scan (the tree's sums are in the same order).
        Self::finish(rows.into_iter().map(|i| (i, self.dist2(q, i))).collect(), k)
    }

    fn matrix_search(&self, block: &[f32], k: usize) -> Vec<Vec<Neighbour>> {
        let m = block.len() / self.b;
        let db = &self.matrix;
        // m × n dot products as one GEMM (matrixmultiply's blocked kernels): Qᵀ·D with Qᵀ
        // built directly (row-major m × b is column-major b × m, so transpose the small side).
        // A few queries: matrix–vector products instead (GEMM would repack the database).
        let dots = if m >= 8 {
            DMatrix::from_row_slice(m, self.b, block) * db
        } else {
            db.tr_mul(&DMatrix::from_column_slice(self.b, m, block)).transpose()
        };
        let n = self.len();
        let extra = 16.min(n - k);
        (0..m)
            .map(|j| {
                let q = &block[j * self.b..(j + 1) * self.b];
                let qn2: f32 = q.iter().map(|x| x * x).sum();
                let qn = qn2.sqrt();
                let mut approx: Vec<(f32, usize)> =
                    (0..n).map(|i| (qn2 + self.norms[i] * self.norms[i] - 2.0 * dots[(j, i)], i)).collect();
                let cut = k + extra;
                if cut < n {
                    approx.select_nth_unstable_by(cut, |a, b| a.0.total_cmp(&b.0));
                }
                let threshold = if cut < n { approx[cut].0 as f64 } else { f64::INFINITY };
                let hits = Self::finish(
                    approx[..cut.min(n)].iter().map(|&(_, i)| (i, self.dist2(q, i))).collect(),
                    k,
                );
                // Rows outside the candidates have approx ≥ threshold, so exact ≥ threshold − err.
                // err bounds the f32 rounding of norms and dot products (generously).
                let err = 4.0
                    * (self.b as f64 + 2.0)
                    * f32::EPSILON as f64
                    * (qn as f64 + self.max_norm as f64).powi(2);
                let kth = hits.last().map_or(0.0, |h| h.1 * h.1);
                if kth < threshold - err { hits } else { self.brute_force(q, k) }
            })
            .collect()
    }
}

/// Queries per matrix product.
const MATRIX_BLOCK: usize = 64;

/// Exact Euclidean search that grows: built over a database ([`Database`]'s routes), or
/// scanning its rows once it has grown or when some rows are ruled out (squared distances in
/// f64, as [`Database::brute_force`]).
pub(crate) struct Euclidean {
    dim: usize,
    store: Store,
}

enum Store {
    Indexed(Database),
    Plain(Vec<f32>),
}

impl Euclidean {
    /// A searcher over `vectors` (`n × dim`, row-major).
    pub(crate) fn new(vectors: Vec<f32>, dim: usize) -> Self {
        let dim = dim.max(1);
        let store = if vectors.is_empty() {
            Store::Plain(vectors)
        } else {
            Store::Indexed(Database::new(vectors, dim))
        };
        Euclidean { dim, store }
    }

    fn vectors(&self) -> &[f32] {
        match &self.store {
            Store::Indexed(db) => db.vectors(),
            Store::Plain(v) => v,
        }
    }

    /// The `k` nearest rows (among those `allowed` admits) with their distances.
    pub(crate) fn nearest(&self, q: &[f32], k: usize, allowed: Allowed<'_>) -> Vec<Neighbour> {
        if let (Store::Indexed(db), None) = (&self.store, allowed) {
            return db.search(q, k);
        }
        let (dim, v) = (self.dim, self.vectors());
        let scored = allowed_rows(v.len() / dim, allowed)
            .map(|r| {
                (
                    r,
                    q.iter()
                        .zip(&v[r * dim..(r + 1) * dim])
                        .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
                        .sum(),
                )
            })
            .collect();
        k_best(scored, k).into_iter().map(|(r, d2)| (r, d2.sqrt())).collect()
    }
}

impl Searcher for Euclidean {
    fn len(&self) -> usize {
        self.vectors().len() / self.dim
    }

    fn push(&mut self, descriptor: &[f32]) {
        if let Store::Indexed(db) = &mut self.store {
            let vectors = std::mem::replace(&mut db.matrix, DMatrix::zeros(0, 0)).data.into();
            self.store = Store::Plain(vectors);
        }
        if let Store::Plain(v) = &mut self.store {
            v.extend_from_slice(descriptor);
        }
    }

    fn search(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> (Vec<Hit>, SearchTimes) {
        super::searcher::timed(|| {
            self.nearest(query, k, allowed).into_iter().map(|(r, d)| Hit::at(r, d)).collect()
        })
    }

    fn search_many(&self, queries: &[f32], dim: usize, k: usize) -> Vec<(Vec<Hit>, SearchTimes)> {
        let Store::Indexed(db) = &self.store else {
            return queries.par_chunks(dim.max(1)).map(|q| self.search(q, k, None)).collect();
        };
        // One batched search (the matrix route multiplies blocks of queries), its time shared.
        let m = queries.len() / dim.max(1);
        let t = std::time::Instant::now();
        let hits = db.search_many(queries, k);
        let each = t.elapsed().as_secs_f64() / m.max(1) as f64;
        hits.into_iter()
            .map(|h| {
                let found = h.into_iter().map(|(r, d)| Hit::at(r, d)).collect();
                (found, SearchTimes { candidates: each, rerank: 0.0 })
            })
            .collect()
    }

    fn set_budget(&mut self, _budget: SearchBudget, _entries: usize) {}
}
