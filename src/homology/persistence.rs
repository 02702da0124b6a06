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

use super::complex::OUTSIDE;
use super::filtration::{Filtration, Value, in_parallel, join_if};
use super::{Diagram, Pair};
use std::cmp::Ordering;

/// The simplex whose entrance kills a class: where the class "is" in space.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Killer {
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
pub(crate) fn located_pairs(f: &Filtration) -> Vec<(Pair, Killer)> {
    let mut out = Vec::new();
    pairs_of(f, |pair, killer| out.push((pair, killer)));
    out
}

/// Runs the passes, handing each pair and its killer to `emit`. In 3D the H0 pass and the
/// dual (H2) pass are independent and run side by side on the current rayon pool (from
/// 2,048 points, see `in_parallel`); their pairs are handed on in the same order whatever
/// the number of threads.
fn pairs_of(f: &Filtration, mut emit: impl FnMut(Pair, Killer)) {
    let c = f.complex;
    if c.dim == 0 {
        return;
    }
    if c.dim == 3 {
        // H2 by duality: tetrahedra + outside, triangles in reverse order.
        let tets = Dual {
            dim: 2,
            face_order: &f.triangle_order,
            face_cofaces: &c.tri_cofaces,
            face_values: &f.triangles,
            cell_order: &f.tet_order,
            cell_values: &f.tets,
            killer: Killer::Tet,
        };
        let ((h0, positive_rank), (h2, tri_rank, negative)) =
            join_if(in_parallel(c), || h0_pass(f), || dual_pass(f, &tets));
        for (pair, killer) in h0.into_iter().chain(h2) {
            emit(pair, killer);
        }
        reduce_h1(f, &positive_rank, tri_rank, &negative, &mut emit);
        return;
    }
    let (h0, positive_rank) = h0_pass(f);
    for (pair, killer) in h0 {
        emit(pair, killer);
    }
    if c.dim == 2 {
        // H1 by duality: triangles + outside, edges in reverse order.
        let triangles = Dual {
            dim: 1,
            face_order: &f.edge_order,
            face_cofaces: &c.edge_cofaces,
            face_values: &f.edges,
            cell_order: &f.triangle_order,
            cell_values: &f.triangles,
            killer: Killer::Triangle,
        };
        let (h1, _, negative) = dual_pass(f, &triangles);
        debug_assert!(
            {
                let mut negative = negative.iter().peekable();
                f.edge_order.iter().enumerate().all(|(r, &e)| {
                    negative.next_if_eq(&&(r as u32)).is_some() || positive_rank[e as usize] != NEGATIVE
                })
            },
            "duality: dual merges are positive edges"
        );
        for (pair, killer) in h1 {
            emit(pair, killer);
        }
    }
}

/// Marks an edge that is not positive in [`h0_pass`]'s ranks, and an empty row slot.
const NEGATIVE: u32 = u32::MAX;

/// H0 (vertices are all born at 0): union-find over the edges in filtration order. Returns
/// its pairs, the essential class last, and for each edge its filtration rank if it is
/// positive (closes a loop), else [`NEGATIVE`]: the rows of the H1 columns.
fn h0_pass(f: &Filtration) -> (Vec<(Pair, Killer)>, Vec<u32>) {
    let c = f.complex;
    let mut uf = UnionFind::new(c.points.len());
    let mut positive_rank = vec![NEGATIVE; c.edges.len()];
    let mut pairs = Vec::with_capacity(c.points.len());
    for (r, &e) in f.edge_order.iter().enumerate() {
        let [u, v] = c.edges[e as usize];
        if uf.union(u, v) {
            pairs.push((Pair { dim: 0, birth: 0.0, death: f.edges[e as usize].value }, Killer::Edge(e)));
        } else {
            positive_rank[e as usize] = r as u32;
        }
    }
    pairs.push((Pair { dim: 0, birth: 0.0, death: f64::INFINITY }, Killer::Never));
    (pairs, positive_rank)
}

/// The rank of each simplex in `order`.
fn ranks(order: &[u32]) -> Vec<u32> {
    let mut rank = vec![0u32; order.len()];
    for (r, &s) in order.iter().enumerate() {
        rank[s as usize] = r as u32;
    }
    rank
}

/// A dual pass: the top cells plus the outside, joined by their faces taken in reverse
/// filtration order (Alexander duality). A face that joins two components kills the younger
/// one's eldest cell: a class of dimension `dim`, born with the face.
struct Dual<'a> {
    dim: u8,
    face_order: &'a [u32],
    /// Each face's two cells ([`OUTSIDE`] for the hull side).
    face_cofaces: &'a [[u32; 2]],
    face_values: &'a [Value],
    cell_order: &'a [u32],
    cell_values: &'a [Value],
    killer: fn(u32) -> Killer,
}

/// Runs a dual pass. Returns its pairs, each face's rank, and the ranks of the faces that
/// join no two components (the negative ones: in 3D, the triangles that kill a loop),
/// increasing.
///
/// It works in rank space, because in filtration order the simplices are scattered over
/// memory: each face's two cofaces are first written as cell ranks at the face's rank (one
/// pass in face-id order, where neighbouring faces have neighbouring cofaces), so that the
/// pass itself reads them in sequence; cell `r` of the union-find is the one of rank `r`, the
/// outside is rank `n`, and every root is the eldest (largest rank) of its set, so a merge
/// links the younger root under the elder one and the younger root is the cell that dies.
fn dual_pass(f: &Filtration, d: &Dual) -> (Vec<(Pair, Killer)>, Vec<u32>, Vec<u32>) {
    let (nfaces, ncells) = (d.face_order.len(), d.cell_order.len());
    let outside = ncells as u32;
    let face_rank = ranks(d.face_order);
    let mut cofaces = vec![[0u32; 2]; nfaces];
    {
        let cell_rank = ranks(d.cell_order);
        for (face, ab) in d.face_cofaces.iter().enumerate() {
            cofaces[face_rank[face] as usize] =
                ab.map(|x| if x == OUTSIDE { outside } else { cell_rank[x as usize] });
        }
    }
    let mut parent: Vec<u32> = (0..=outside).collect();
    let mut pairs = Vec::new();
    let mut negative = Vec::with_capacity((nfaces + 1).saturating_sub(ncells));
    for (r, &[a, b]) in cofaces.iter().enumerate().rev() {
        let (ra, rb) = (find_root(&mut parent, a), find_root(&mut parent, b));
        if ra == rb {
            negative.push(r as u32);
            continue;
        }
        let (young, old) = if ra < rb { (ra, rb) } else { (rb, ra) };
        parent[young as usize] = old;
        let (face, cell) = (d.face_order[r], d.cell_order[young as usize]);
        push_finite(
            f,
            &mut |pair, killer| pairs.push((pair, killer)),
            d.dim,
            d.face_values[face as usize],
            d.cell_values[cell as usize],
            (d.killer)(cell),
        );
    }
    negative.reverse();
    (pairs, face_rank, negative)
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
/// by rank, increasing. Each triangle's column is first written at its rank (one pass in
/// triangle-id order, as in [`dual_pass`]), so that the reduction reads them in sequence.
fn reduce_h1(
    f: &Filtration,
    positive_rank: &[u32],
    tri_rank: Vec<u32>,
    negative: &[u32],
    emit: &mut impl FnMut(Pair, Killer),
) {
    let c = f.complex;
    let mut columns = vec![[NEGATIVE; 3]; c.triangles.len()];
    for (t, edges) in c.tri_edges.iter().enumerate() {
        columns[tri_rank[t] as usize] = edges.map(|e| positive_rank[e as usize]);
    }
    drop(tri_rank);
    // owner[rank] = index of the stored reduced column whose pivot is that edge rank.
    let mut owner = vec![u32::MAX; c.edges.len()];
    let mut store: Vec<u32> = Vec::new();
    let mut store_start: Vec<u32> = Vec::new();
    let mut col: Vec<u32> = Vec::with_capacity(16);
    let mut tmp: Vec<u32> = Vec::with_capacity(16);
    for &r in negative {
        let t = f.triangle_order[r as usize];
        col.clear();
        col.extend(columns[r as usize].iter().copied().filter(|&x| x != NEGATIVE));
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
    /// Merges the sets of `a` and `b` (the smaller under the larger); false if they were
    /// one set.
    #[inline]
    fn union(&mut self, a: u32, b: u32) -> bool {
        let (mut a, mut b) = (find_root(&mut self.parent, a), find_root(&mut self.parent, b));
        if a == b {
            return false;
        }
        if self.size[a as usize] < self.size[b as usize] {
            std::mem::swap(&mut a, &mut b);
        }
        self.parent[b as usize] = a;
        self.size[a as usize] += self.size[b as usize];
        true
    }
}

/// The root of `x` in a forest of parent links, halving the path on the way.
#[inline]
fn find_root(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let g = parent[parent[x as usize] as usize];
        parent[x as usize] = g;
        x = g;
    }
    x
}
