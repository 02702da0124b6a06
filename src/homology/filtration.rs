//! Alpha filtration values on a [`DelaunayComplex`], exactly as GUDHI assigns them
//! (GUDHI 3.13, `Alpha_complex.h::create_complex`): top-dimensional simplices get their squared circumradius; going down,
//! a face that is not Gabriel with respect to some coface (the opposite vertex lies strictly
//! inside its smallest circumsphere) is *attached* and takes the minimum value of its
//! cofaces; any other face gets its own smallest-circumsphere radius². Vertices are 0.
//!
//! Every value remembers the simplex whose circumradius it is (`source`), so that two values
//! can be compared exactly ([`Filtration::cmp`]); the simplex orders used for persistence are
//! total: (value, index).

use super::complex::{DelaunayComplex, OUTSIDE};
use super::exact::{
    ExactRadius2, Point, Radius2, compare_radius2_exact, edge_obtuse, radius2, radius2_correctly_rounded,
    tet_circumsphere, triangle_gabriel,
};
use rayon::prelude::*;
use std::cell::OnceCell;
use std::cmp::Ordering;

/// One filtration value: an `f64` with an error bound and the simplex it comes from.
#[derive(Clone, Copy, Debug)]
pub struct Value {
    /// Squared radius (rounded).
    pub value: f64,
    /// Relative error bound of `value` (rounded up to `f32`: 16-byte values).
    pub rel_err: f32,
    /// The simplex whose squared circumradius this is: `dim << 30 | index`.
    pub source: u32,
}

const DIM_SHIFT: u32 = 30;
/// Error bounds wider than this are tightened by exact evaluation (see [`tighten`]).
const TIGHT_REL_ERR: f64 = 1e-9;
const INDEX_MASK: u32 = (1 << DIM_SHIFT) - 1;
/// Simplices per rayon task: large clouds split evenly.
const PAR_CHUNK: usize = 4096;
/// Below this many points a cloud stays on the calling thread: at 1,024 points two threads
/// were no faster than one and their calls' times spread wider, at 2,048 they were ~8 %
/// faster (`cargo bench --bench calls`, docs/engine.md).
const PARALLEL_FROM_POINTS: usize = 2048;

/// Whether the engine spreads the work on `complex` over the rayon pool.
pub(crate) fn in_parallel(complex: &DelaunayComplex) -> bool {
    complex.points.len() >= PARALLEL_FROM_POINTS
}

/// `rayon::join` on the pool when `parallel`, else the two calls in turn on this thread.
pub(crate) fn join_if<A: Send, B: Send>(
    parallel: bool,
    a: impl FnOnce() -> A + Send,
    b: impl FnOnce() -> B + Send,
) -> (A, B) {
    if parallel { rayon::join(a, b) } else { (a(), b()) }
}

/// `f` over `(index, item)` of `items`, in parallel chunks when `parallel`; the same results
/// in the same order either way.
fn map_indexed<T: Sync, U: Send>(
    items: &[T],
    parallel: bool,
    f: impl Fn((usize, &T)) -> U + Sync + Send,
) -> Vec<U> {
    if parallel {
        items.par_iter().with_min_len(PAR_CHUNK).enumerate().map(f).collect()
    } else {
        items.iter().enumerate().map(f).collect()
    }
}

impl Value {
    fn unset() -> Self {
        // Above every value with a zero error bound, so that `cmp`'s f64 test puts it last;
        // only its exact path must know it (no simplex to evaluate).
        Value { value: f64::MAX, rel_err: 0.0, source: u32::MAX }
    }
    fn is_set(&self) -> bool {
        self.source != u32::MAX
    }

    /// Absolute error bound of `value`.
    #[inline]
    pub fn abs_err(&self) -> f64 {
        self.rel_err as f64 * self.value.abs()
    }
}

/// Filtration values of every edge, triangle and tetrahedron, plus their orders.
pub struct Filtration<'a> {
    /// The complex.
    pub complex: &'a DelaunayComplex,
    /// Edge values.
    pub edges: Vec<Value>,
    /// Triangle values.
    pub triangles: Vec<Value>,
    /// Tetrahedron values.
    pub tets: Vec<Value>,
    /// Edge ids in filtration order.
    pub edge_order: Vec<u32>,
    /// Triangle ids in filtration order.
    pub triangle_order: Vec<u32>,
    /// Tetrahedron ids in filtration order.
    pub tet_order: Vec<u32>,
}

impl<'a> Filtration<'a> {
    /// Computes the alpha filtration of `complex`, on the threads of the current rayon pool
    /// (the values and orders do not depend on how many).
    pub fn new(complex: &'a DelaunayComplex) -> Self {
        let pts = &complex.points;
        let parallel = in_parallel(complex);
        // Tetrahedra: own circumradius, and which of their facets they attach: a facet is
        // attached when the opposite vertex is strictly inside its smallest circumsphere
        // (decided from the tetrahedron's circumcentre, exactly when that is too close to
        // call). Independent per tetrahedron.
        let per_tet: Vec<(Value, u8)> = map_indexed(&complex.tets, parallel, |(ti, t)| {
            let v = t.map(|x| pts[x as usize]);
            let (r, gabriel) = tet_circumsphere(&v);
            let mut attaches = 0u8;
            for i in 0..4 {
                let is_gabriel = gabriel[i].unwrap_or_else(|| {
                    let w = complex.triangles[complex.tet_tris[ti][i] as usize];
                    triangle_gabriel(&pts[w[0] as usize], &pts[w[1] as usize], &pts[w[2] as usize], &v[i])
                });
                attaches |= u8::from(!is_gabriel) << i;
            }
            (own(tighten(r, &v), 3, ti), attaches)
        });
        let tets: Vec<Value> = per_tet.iter().map(|p| p.0).collect();
        let cmp = |a: Value, b: Value| compare(complex, a, b);
        // Triangles: the least value of the tetrahedra that attach them (the lower-numbered
        // one on a tie), else their own smallest-circumsphere radius².
        let triangles: Vec<Value> = map_indexed(&complex.triangles, parallel, |(i, t)| {
            let mut best = Value::unset();
            if let Some(cofaces) = complex.tri_cofaces.get(i) {
                // Cofaces come in increasing order (the outside last).
                for &c in cofaces.iter().filter(|&&c| c != OUTSIDE) {
                    let slot = complex.tet_tris[c as usize].iter().position(|&x| x as usize == i);
                    let attached = slot.is_some_and(|s| per_tet[c as usize].1 >> s & 1 == 1);
                    if attached && cmp(tets[c as usize], best) == Ordering::Less {
                        best = tets[c as usize];
                    }
                }
            }
            if best.is_set() {
                best
            } else {
                let v = t.map(|x| pts[x as usize]);
                own(tighten(radius2(&v), &v), 2, i)
            }
        });
        drop(per_tet);
        // Edges: attached iff some triangle coface is not Gabriel (the opposite angle is
        // obtuse); then the minimum over all triangle cofaces (that minimum is reached at a
        // non-Gabriel coface, so this equals GUDHI's top-down propagation whatever its
        // visiting order). The obtuse tests run per triangle on the pool; the minimum is taken
        // in triangle order, the lower-numbered triangle kept on a tie.
        // (The tests are branch-free unless their filters cannot decide: the outcomes are
        // unpredictable, and they run three times per triangle.)
        let obtuse: Vec<u8> = map_indexed(&complex.triangles, parallel, |(_, t)| {
            let v = t.map(|x| pts[x as usize]);
            let mut mask = 0u8;
            for i in 0..3 {
                let (p, q) = ((i + 1) % 3, (i + 2) % 3);
                mask |= u8::from(edge_obtuse(&v[p], &v[q], &v[i])) << i;
            }
            mask
        });
        let mut edges = vec![Value::unset(); complex.edges.len()];
        let mut attached = vec![false; complex.edges.len()];
        for (ti, &cand) in triangles.iter().enumerate() {
            for i in 0..3 {
                let e = complex.tri_edges[ti][i] as usize;
                attached[e] |= obtuse[ti] >> i & 1 == 1;
                let cur = edges[e];
                edges[e] = if cmp(cand, cur) == Ordering::Less { cand } else { cur };
            }
        }
        drop(obtuse);
        for (i, e) in complex.edges.iter().enumerate() {
            if !attached[i] {
                edges[i] = own(radius2(&[pts[e[0] as usize], pts[e[1] as usize]]), 1, i);
            }
        }
        let ((edge_order, triangle_order), tet_order) = join_if(
            parallel,
            || join_if(parallel, || order(complex, &edges), || order(complex, &triangles)),
            || order(complex, &tets),
        );
        Filtration { complex, edges, triangles, tets, edge_order, triangle_order, tet_order }
    }

    /// Exact comparison of two filtration values; an unset value is above every set one.
    #[inline]
    pub fn cmp(&self, a: Value, b: Value) -> Ordering {
        compare(self.complex, a, b)
    }
    /// The (birth, death) values of a finite pair, or `None` if it has zero length as GUDHI's
    /// `exact` mode sees it: birth and death, each computed exactly and rounded to a double,
    /// coincide. The `f64` values decide when they differ by more than their certified error;
    /// otherwise the exact values are compared, and rounded when they differ (a sub-ulp
    /// difference is zero length there too).
    pub fn pair_values(&self, birth: Value, death: Value) -> Option<(f64, f64)> {
        if death.value - birth.value > birth.abs_err() + death.abs_err() {
            return Some((birth.value, death.value));
        }
        if self.cmp(birth, death) != Ordering::Less {
            return None;
        }
        let (b, d) = (self.correctly_rounded(birth), self.correctly_rounded(death));
        (b < d).then_some((b, d))
    }

    /// The exact value of `v` rounded to the nearest double.
    pub fn correctly_rounded(&self, v: Value) -> f64 {
        let mut p = [[0.0; 3]; 4];
        let n = source_points(self.complex, v.source, &mut p);
        radius2_correctly_rounded(&p[..n])
    }
}

/// Simplex ids sorted by (exact value, id): a radix sort on the high 32 bits of the
/// `f64` (values are non-negative, so the bits order like the values), runs of equal
/// high bits sorted by the full value, then an exact re-sort inside each cluster whose
/// error intervals overlap (rare outside ties). The sort moves whole keys (value, id, error
/// bound), so no pass gathers from `values` in sorted order: above 20,000 points those
/// gathers, one cache miss each, cost more than the sort.
fn order(complex: &DelaunayComplex, values: &[Value]) -> Vec<u32> {
    let keys: Vec<SortKey> = values
        .iter()
        .enumerate()
        .map(|(i, v)| SortKey { bits: v.value.to_bits(), id: i as u32, rel_err: v.rel_err })
        .collect();
    let mut sorted = radix_sort_high32(keys);
    let n = sorted.len();
    let mut start = 0;
    while start < n {
        let high = sorted[start].bits >> 32;
        let mut end = start + 1;
        while end < n && sorted[end].bits >> 32 == high {
            end += 1;
        }
        if end - start > 1 {
            sorted[start..end].sort_unstable_by_key(|k| (k.bits, k.id));
        }
        start = end;
    }
    let mut suffix_min_lower = vec![f64::INFINITY; n + 1];
    for k in (0..n).rev() {
        let (value, err) = sorted[k].value_and_err();
        suffix_min_lower[k] = suffix_min_lower[k + 1].min(value - err);
    }
    let mut o: Vec<u32> = sorted.iter().map(|k| k.id).collect();
    let mut start = 0;
    let mut max_upper = f64::NEG_INFINITY;
    for k in 0..n {
        let (value, err) = sorted[k].value_and_err();
        max_upper = max_upper.max(value + err);
        // Split after k when nothing before can exceed anything after.
        if max_upper < suffix_min_lower[k + 1] {
            if k > start {
                sort_cluster(complex, values, &mut o[start..=k]);
            }
            start = k + 1;
            max_upper = f64::NEG_INFINITY;
        }
    }
    o
}

/// What [`order`] sorts: a value's bits, its simplex and its error bound.
#[derive(Clone, Copy, Default)]
struct SortKey {
    bits: u64,
    id: u32,
    rel_err: f32,
}

impl SortKey {
    /// The value and its absolute error bound (as [`Value::abs_err`]).
    #[inline]
    fn value_and_err(&self) -> (f64, f64) {
        let value = f64::from_bits(self.bits);
        (value, self.rel_err as f64 * value.abs())
    }
}

/// Sorts a cluster of simplices whose error intervals overlap by (exact value, id). A pair the
/// `f64` bounds decide costs no exact work; otherwise each member's value is evaluated exactly
/// once, when first needed. The cluster comes in (f64 value, id) order, the exact order but for
/// sub-ulp differences and ties, so the stable sort (which finds sorted runs) makes about one
/// comparison per member.
fn sort_cluster(complex: &DelaunayComplex, values: &[Value], cluster: &mut [u32]) {
    // Most clusters are values shared by simplices (a tetrahedron's value on the facets it
    // attaches), already in order: checked without allocating.
    let decided = cluster.windows(2).all(|w| {
        let (a, b) = (values[w[0] as usize], values[w[1] as usize]);
        compare_bounds(a, b).is_some_and(|o| o.then(w[0].cmp(&w[1])) == Ordering::Less)
    });
    if decided {
        return;
    }
    let exact: Vec<OnceCell<ExactRadius2>> = (0..cluster.len()).map(|_| OnceCell::new()).collect();
    let exact_of = |k: usize, v: Value| {
        exact[k].get_or_init(|| {
            let mut p = [[0.0; 3]; 4];
            let n = source_points(complex, v.source, &mut p);
            ExactRadius2::new(&p[..n])
        })
    };
    let mut keyed: Vec<(usize, u32)> = cluster.iter().copied().enumerate().collect();
    keyed.sort_by(|&(ka, i), &(kb, j)| {
        let (a, b) = (values[i as usize], values[j as usize]);
        match compare_bounds(a, b) {
            Some(o) => o,
            None => exact_of(ka, a).cmp(exact_of(kb, b)),
        }
        .then(i.cmp(&j))
    });
    for (slot, k) in cluster.iter_mut().zip(keyed) {
        *slot = k.1;
    }
}

/// The order of two set values when their sources or error bounds decide it.
#[inline]
fn compare_bounds(a: Value, b: Value) -> Option<Ordering> {
    if a.source == b.source {
        return Some(Ordering::Equal);
    }
    let margin = a.abs_err() + b.abs_err();
    if b.value - a.value > margin {
        Some(Ordering::Less)
    } else if a.value - b.value > margin {
        Some(Ordering::Greater)
    } else {
        None
    }
}

/// Exact comparison of two filtration values of `complex`; an unset value is above every set
/// one.
#[inline]
fn compare(complex: &DelaunayComplex, a: Value, b: Value) -> Ordering {
    if a.source == b.source {
        return Ordering::Equal;
    }
    let margin = a.abs_err() + b.abs_err();
    if b.value - a.value > margin {
        return Ordering::Less;
    }
    if a.value - b.value > margin {
        return Ordering::Greater;
    }
    if !(a.is_set() && b.is_set()) {
        // Both unset would have equal sources.
        return if a.is_set() { Ordering::Less } else { Ordering::Greater };
    }
    let mut pa = [[0.0; 3]; 4];
    let mut pb = [[0.0; 3]; 4];
    let na = source_points(complex, a.source, &mut pa);
    let nb = source_points(complex, b.source, &mut pb);
    compare_radius2_exact(&pa[..na], &pb[..nb])
}

/// The vertices of the simplex a value comes from.
fn source_points(c: &DelaunayComplex, source: u32, out: &mut [Point; 4]) -> usize {
    let i = (source & INDEX_MASK) as usize;
    let verts: &[u32] = match source >> DIM_SHIFT {
        1 => &c.edges[i],
        2 => &c.triangles[i],
        _ => &c.tets[i],
    };
    for (k, &v) in verts.iter().enumerate() {
        out[k] = c.points[v as usize];
    }
    verts.len()
}

/// A value whose error bound is wide (a near-flat simplex: a huge circumradius computed by
/// cancellation) is replaced by its correctly rounded exact value. A wide interval would
/// otherwise overlap thousands of others, fusing them into one cluster that `order` must
/// sort by exact comparisons (seen on simulated 5 mm-quantized scans: a 57,733-edge cluster).
fn tighten(r: Radius2, points: &[Point]) -> Radius2 {
    if r.rel_err <= TIGHT_REL_ERR {
        return r;
    }
    let exact = radius2_correctly_rounded(points);
    if exact.is_normal() { Radius2 { value: exact, rel_err: 2.0 * f64::EPSILON } } else { r }
}

#[inline]
fn own(r: Radius2, dim: u32, index: usize) -> Value {
    // Round the bound up: a wider bound only sends more comparisons to the exact path.
    let rel_err = (r.rel_err as f32) * (1.0 + f32::EPSILON);
    Value { value: r.value, rel_err, source: (dim << DIM_SHIFT) | index as u32 }
}

/// LSD radix sort of keys by the high 32 bits of their value (11-bit digits; digits equal
/// across all keys are skipped). Stable, so equal high bits stay in id order.
fn radix_sort_high32(mut a: Vec<SortKey>) -> Vec<SortKey> {
    let mut b = vec![SortKey::default(); a.len()];
    let (mut and_all, mut or_all) = (u64::MAX, 0u64);
    for k in &a {
        and_all &= k.bits;
        or_all |= k.bits;
    }
    let varying = (and_all ^ or_all) >> 32;
    for shift in [32, 43, 54] {
        let digit = |k: &SortKey| ((k.bits >> shift) & 0x7ff) as usize;
        if (varying << 32 >> shift) & 0x7ff == 0 {
            continue;
        }
        let mut count = vec![0usize; 2049];
        for k in &a {
            count[digit(k) + 1] += 1;
        }
        for d in 0..2048 {
            count[d + 1] += count[d];
        }
        for k in &a {
            let d = digit(k);
            b[count[d]] = *k;
            count[d] += 1;
        }
        std::mem::swap(&mut a, &mut b);
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wide_bounds_are_tightened_to_the_correctly_rounded_value() {
        // A nearly flat tetrahedron on a tilted plane: its tiny volume comes from cancellation.
        let third = 1.0 / 3.0;
        let v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [third, third, third + 1e-9]];
        let r = radius2(&v);
        assert!(r.rel_err > TIGHT_REL_ERR, "{}", r.rel_err);
        let t = tighten(r, &v);
        assert_eq!(t.value, radius2_correctly_rounded(&v));
        assert!((r.value - t.value).abs() <= r.rel_err * t.value);
        let flat = radius2(&v[..3]);
        assert_eq!(tighten(flat, &v[..3]).value, flat.value, "tight bounds are kept");
    }
}
