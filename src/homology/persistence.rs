//! Persistence pairs of an alpha [`Filtration`] in dimensions 0, 1, 2 over Z/2.
//!
//! * H0: union-find over the edges in filtration order (negative edges merge components).
//! * Top dimension (H2 in 3D, H1 in 2D): union-find over the dual graph — top cells plus the
//!   outside cell — with the faces in *reverse* order (Alexander duality). Each component
//!   remembers its oldest-in-reverse (largest rank) cell; a face joining two components pairs
//!   with the younger one's cell.
//! * H1 in 3D: column reduction of only the triangles that the dual pass left unpaired
//!   (clearing), each column holding only *positive* edges (compression: negative rows can
//!   never become pivots).
//!
//! Pairs whose birth and death values are exactly equal are dropped (GUDHI's
//! `min_persistence = 0`); H0 gets one essential class (0, +inf).

use super::filtration::{Filtration, Value};
use super::{Diagram, Pair};
use std::cmp::Ordering;

/// The simplex whose entrance kills a class: where the class "is" in space.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Killer {
    /// An edge (H0: it merges two components).
    Edge(u32),
    /// A triangle (H1: it fills a loop).
    Triangle(u32),
    /// A tetrahedron (H2: it fills a void).
    Tet(u32),
    /// None: the essential H0 class.
    Never,
}

/// Computes the persistence diagram (squared radii) of `f`.
pub fn persistence(f: &Filtration) -> Diagram {
    let mut pairs = Vec::new();
    pairs_of(f, |pair, _| pairs.push(pair));
    Diagram::new(pairs)
}

/// Every pair of `f` (zero-length pairs dropped, as in [`persistence`]) with the simplex that
/// kills it, in the order the passes find them.
pub fn located_pairs(f: &Filtration) -> Vec<(Pair, Killer)> {
    let mut out = Vec::new();
    pairs_of(f, |pair, killer| out.push((pair, killer)));
    out
}

/// Runs the passes, handing each pair and its killer to `emit`. In 3D the H0 pass and the
/// dual (H2) pass are independent and run side by side on the current rayon pool; their
/// pairs are handed on in the same order whatever the number of threads.
fn pairs_of(f: &Filtration, mut emit: impl FnMut(Pair, Killer)) {
    let c = f.complex;
    if c.dim == 0 {
        return;
    }
    if c.dim == 3 {
        let ((h0, edge_positive), (h2, negative)) = rayon::join(|| h0_pass(f), || dual_pass_3d(f));
        for (pair, killer) in h0.into_iter().chain(h2) {
            emit(pair, killer);
        }
        reduce_h1(f, &edge_positive, &negative, &mut emit);
        return;
    }
    let (h0, edge_positive) = h0_pass(f);
    for (pair, killer) in h0 {
        emit(pair, killer);
    }
    if c.dim == 2 {
        // H1 by duality: triangles + outside, edges in reverse order.
        let mut rank = vec![0u32; c.triangles.len()];
        for (r, &t) in f.triangle_order.iter().enumerate() {
            rank[t as usize] = r as u32;
        }
        let mut dual = ElderUnionFind::new(&rank);
        for &e in f.edge_order.iter().rev() {
            let [a, b] = c.edge_cofaces[e as usize];
            if let Some(t) = dual.union(a, b) {
                debug_assert!(edge_positive[e as usize], "duality: dual merges are positive edges");
                push_finite(
                    f,
                    &mut emit,
                    1,
                    f.edges[e as usize],
                    f.triangles[t as usize],
                    Killer::Triangle(t),
                );
            }
        }
    }
}

/// H0 (vertices are all born at 0): union-find over the edges in filtration order. Returns
/// its pairs, the essential class last, and which edges are positive (close a loop).
fn h0_pass(f: &Filtration) -> (Vec<(Pair, Killer)>, Vec<bool>) {
    let c = f.complex;
    let mut uf = UnionFind::new(c.points.len());
    let mut edge_positive = vec![false; c.edges.len()];
    let mut pairs = Vec::with_capacity(c.points.len());
    for &e in &f.edge_order {
        let [u, v] = c.edges[e as usize];
        if uf.union(u, v) {
            pairs.push((Pair { dim: 0, birth: 0.0, death: f.edges[e as usize].value }, Killer::Edge(e)));
        } else {
            edge_positive[e as usize] = true;
        }
    }
    pairs.push((Pair { dim: 0, birth: 0.0, death: f64::INFINITY }, Killer::Never));
    (pairs, edge_positive)
}

/// H2 in 3D by duality: tetrahedra + outside, triangles in reverse order. Returns its pairs
/// and the negative triangles (those that kill a loop), in filtration order.
fn dual_pass_3d(f: &Filtration) -> (Vec<(Pair, Killer)>, Vec<u32>) {
    let c = f.complex;
    let mut rank = vec![0u32; c.tets.len()];
    for (r, &t) in f.tet_order.iter().enumerate() {
        rank[t as usize] = r as u32;
    }
    let mut dual = ElderUnionFind::new(&rank);
    let mut pairs = Vec::new();
    let mut negative = Vec::with_capacity(c.triangles.len() - c.tets.len() + 1);
    for &t in f.triangle_order.iter().rev() {
        let [a, b] = c.tri_cofaces[t as usize];
        match dual.union(a, b) {
            Some(tet) => push_finite(
                f,
                &mut |pair, killer| pairs.push((pair, killer)),
                2,
                f.triangles[t as usize],
                f.tets[tet as usize],
                Killer::Tet(tet),
            ),
            None => negative.push(t),
        }
    }
    negative.reverse();
    (pairs, negative)
}

/// Records a finite pair unless it has zero length (see [`Filtration::pair_values`]).
fn push_finite(
    f: &Filtration,
    emit: &mut impl FnMut(Pair, Killer),
    dim: u8,
    birth: Value,
    death: Value,
    killer: Killer,
) {
    if let Some((birth, death)) = f.pair_values(birth, death) {
        emit(Pair { dim, birth, death }, killer);
    }
}

/// H1 pairs: reduce the columns (positive edges, by rank) of the negative triangles, given
/// in filtration order.
fn reduce_h1(f: &Filtration, edge_positive: &[bool], negative: &[u32], emit: &mut impl FnMut(Pair, Killer)) {
    let c = f.complex;
    let mut edge_rank = vec![0u32; c.edges.len()];
    for (r, &e) in f.edge_order.iter().enumerate() {
        edge_rank[e as usize] = r as u32;
    }
    // owner[rank] = index of the stored reduced column whose pivot is that edge rank.
    let mut owner = vec![u32::MAX; c.edges.len()];
    let mut store: Vec<u32> = Vec::new();
    let mut store_start: Vec<u32> = Vec::new();
    let mut col: Vec<u32> = Vec::with_capacity(16);
    let mut tmp: Vec<u32> = Vec::with_capacity(16);
    for &t in negative {
        col.clear();
        for &e in &c.tri_edges[t as usize] {
            if edge_positive[e as usize] {
                col.push(edge_rank[e as usize]);
            }
        }
        // At most three entries: a sorting network.
        if col.len() >= 2 && col[0] < col[1] {
            col.swap(0, 1);
        }
        if col.len() == 3 {
            if col[1] < col[2] {
                col.swap(1, 2);
            }
            if col[0] < col[1] {
                col.swap(0, 1);
            }
        }
        loop {
            let Some(&pivot) = col.first() else {
                debug_assert!(false, "a negative triangle cannot reduce to zero");
                break;
            };
            let k = owner[pivot as usize];
            if k == u32::MAX {
                owner[pivot as usize] = store_start.len() as u32;
                store_start.push(store.len() as u32);
                store.extend_from_slice(&col);
                let e = f.edge_order[pivot as usize];
                push_finite(f, emit, 1, f.edges[e as usize], f.triangles[t as usize], Killer::Triangle(t));
                break;
            }
            let s = store_start[k as usize] as usize;
            let end = store_start.get(k as usize + 1).map_or(store.len(), |&x| x as usize);
            symmetric_difference_desc(&col, &store[s..end], &mut tmp);
            std::mem::swap(&mut col, &mut tmp);
        }
    }
}

/// `out = a Δ b` for two strictly decreasing lists.
fn symmetric_difference_desc(a: &[u32], b: &[u32], out: &mut Vec<u32>) {
    out.clear();
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        match a[i].cmp(&b[j]) {
            Ordering::Greater => {
                out.push(a[i]);
                i += 1;
            }
            Ordering::Less => {
                out.push(b[j]);
                j += 1;
            }
            Ordering::Equal => {
                i += 1;
                j += 1;
            }
        }
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
}

/// Union-find with path halving and union by size.
struct UnionFind {
    parent: Vec<u32>,
    size: Vec<u32>,
}

impl UnionFind {
    fn new(n: usize) -> Self {
        UnionFind { parent: (0..n as u32).collect(), size: vec![1; n] }
    }
    #[inline]
    fn find(&mut self, mut x: u32) -> u32 {
        while self.parent[x as usize] != x {
            let g = self.parent[self.parent[x as usize] as usize];
            self.parent[x as usize] = g;
            x = g;
        }
        x
    }
    /// Merges the sets of `a` and `b`; false if they were one set.
    #[inline]
    fn union(&mut self, a: u32, b: u32) -> bool {
        let (a, b) = (self.find(a), self.find(b));
        if a == b {
            return false;
        }
        self.link(a, b);
        true
    }
    /// Links two distinct roots (the smaller set under the larger); returns the new root.
    #[inline]
    fn link(&mut self, mut a: u32, mut b: u32) -> u32 {
        if self.size[a as usize] < self.size[b as usize] {
            std::mem::swap(&mut a, &mut b);
        }
        self.parent[b as usize] = a;
        self.size[a as usize] += self.size[b as usize];
        a
    }
}

/// Union-find over top cells plus the outside (index = number of cells, rank +inf) where
/// each root knows the largest rank in its set.
struct ElderUnionFind {
    uf: UnionFind,
    elder_rank: Vec<u32>,
    cell_of_rank_root: Vec<u32>,
    outside: u32,
}

impl ElderUnionFind {
    fn new(rank: &[u32]) -> Self {
        let n = rank.len();
        let mut elder_rank: Vec<u32> = rank.to_vec();
        elder_rank.push(u32::MAX);
        ElderUnionFind {
            uf: UnionFind::new(n + 1),
            elder_rank,
            cell_of_rank_root: (0..=n as u32).collect(),
            outside: n as u32,
        }
    }
    /// Joins the sets of cells `a` and `b` (`OUTSIDE` allowed). Returns the cell that dies
    /// (the younger set's eldest cell), or `None` if they were already one set.
    fn union(&mut self, a: u32, b: u32) -> Option<u32> {
        let a = if a == u32::MAX { self.outside } else { a };
        let b = if b == u32::MAX { self.outside } else { b };
        let (ra, rb) = (self.uf.find(a), self.uf.find(b));
        if ra == rb {
            return None;
        }
        let (ea, eb) = (self.elder_rank[ra as usize], self.elder_rank[rb as usize]);
        let (young, old) = if ea < eb { (ra, rb) } else { (rb, ra) };
        let dying = self.cell_of_rank_root[young as usize];
        let (keep_rank, keep_cell) = (self.elder_rank[old as usize], self.cell_of_rank_root[old as usize]);
        let root = self.uf.link(ra, rb);
        self.elder_rank[root as usize] = keep_rank;
        self.cell_of_rank_root[root as usize] = keep_cell;
        Some(dying)
    }
}
