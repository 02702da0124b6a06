//! Alpha filtration values on a [`DelaunayComplex`], exactly as GUDHI assigns them
//! (REFERENCE §1.3): top-dimensional simplices get their squared circumradius; going down,
//! a face that is not Gabriel with respect to some coface (the opposite vertex lies strictly
//! inside its smallest circumsphere) is *attached* and takes the minimum value of its
//! cofaces; any other face gets its own smallest-circumsphere radius². Vertices are 0.
//!
//! Every value remembers the simplex whose circumradius it is (`source`), so that two values
//! can be compared exactly ([`Filtration::cmp`]); the simplex orders used for persistence are
//! total: (value, index).

use super::complex::DelaunayComplex;
use super::exact::{
    Point, Radius2, compare_radius2_exact, edge_gabriel, radius2, radius2_correctly_rounded, triangle_gabriel,
};
use std::cmp::Ordering;

/// One filtration value: an `f64` with an error bound and the simplex it comes from.
#[derive(Clone, Copy, Debug)]
pub struct Value {
    /// Squared radius (rounded).
    pub value: f64,
    /// Relative error bound of `value`.
    pub rel_err: f64,
    /// The simplex whose squared circumradius this is: `dim << 30 | index`.
    pub source: u32,
}

const DIM_SHIFT: u32 = 30;
const INDEX_MASK: u32 = (1 << DIM_SHIFT) - 1;

impl Value {
    fn unset() -> Self {
        Value { value: f64::NAN, rel_err: 0.0, source: u32::MAX }
    }
    fn is_set(&self) -> bool {
        self.source != u32::MAX
    }

    /// Absolute error bound of `value`.
    #[inline]
    pub fn abs_err(&self) -> f64 {
        self.rel_err * self.value.abs()
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
    /// Computes the alpha filtration of `complex`.
    pub fn new(complex: &'a DelaunayComplex) -> Self {
        let pts = &complex.points;
        let mut f = Filtration {
            complex,
            edges: vec![Value::unset(); complex.edges.len()],
            triangles: vec![Value::unset(); complex.triangles.len()],
            tets: Vec::with_capacity(complex.tets.len()),
            edge_order: Vec::new(),
            triangle_order: Vec::new(),
            tet_order: Vec::new(),
        };
        // Tetrahedra: own circumradius.
        for (i, t) in complex.tets.iter().enumerate() {
            let r =
                radius2(&[pts[t[0] as usize], pts[t[1] as usize], pts[t[2] as usize], pts[t[3] as usize]]);
            f.tets.push(own(r, 3, i));
        }
        // Triangles: attached to a tetrahedron whose opposite vertex is strictly inside.
        for (ti, t) in complex.tets.iter().enumerate() {
            for i in 0..4 {
                let tri = complex.tet_tris[ti][i] as usize;
                let v = complex.triangles[tri];
                let (a, b, c) = (&pts[v[0] as usize], &pts[v[1] as usize], &pts[v[2] as usize]);
                if !triangle_gabriel(a, b, c, &pts[t[i] as usize]) {
                    let cand = f.tets[ti];
                    let cur = f.triangles[tri];
                    if !cur.is_set() || f.cmp(cand, cur) == Ordering::Less {
                        f.triangles[tri] = cand;
                    }
                }
            }
        }
        for (i, t) in complex.triangles.iter().enumerate() {
            if !f.triangles[i].is_set() {
                let r = radius2(&[pts[t[0] as usize], pts[t[1] as usize], pts[t[2] as usize]]);
                f.triangles[i] = own(r, 2, i);
            }
        }
        // Edges: attached iff some triangle coface is not Gabriel; then the minimum over all
        // triangle cofaces (that minimum is reached at a non-Gabriel coface, so this equals
        // GUDHI's top-down propagation whatever its visiting order).
        let mut attached = vec![false; complex.edges.len()];
        let mut min_coface = vec![Value::unset(); complex.edges.len()];
        for (ti, t) in complex.triangles.iter().enumerate() {
            for i in 0..3 {
                let e = complex.tri_edges[ti][i] as usize;
                let ev = complex.edges[e];
                if !attached[e]
                    && !edge_gabriel(&pts[ev[0] as usize], &pts[ev[1] as usize], &pts[t[i] as usize])
                {
                    attached[e] = true;
                }
                let cand = f.triangles[ti];
                let cur = min_coface[e];
                if !cur.is_set() || f.cmp(cand, cur) == Ordering::Less {
                    min_coface[e] = cand;
                }
            }
        }
        for (i, e) in complex.edges.iter().enumerate() {
            f.edges[i] = if attached[i] {
                min_coface[i]
            } else {
                own(radius2(&[pts[e[0] as usize], pts[e[1] as usize]]), 1, i)
            };
        }
        f.edge_order = f.order(&f.edges);
        f.triangle_order = f.order(&f.triangles);
        f.tet_order = f.order(&f.tets);
        f
    }

    /// Simplex ids sorted by (exact value, id): a radix sort on the `f64` bits, then an exact
    /// re-sort inside each cluster whose error intervals overlap (rare outside ties).
    fn order(&self, values: &[Value]) -> Vec<u32> {
        let keyed: Vec<(u64, u32)> =
            values.iter().enumerate().map(|(i, v)| (v.value.to_bits(), i as u32)).collect();
        let mut o: Vec<u32> = radix_sort(keyed).into_iter().map(|(_, i)| i).collect();
        let lower = |i: u32| values[i as usize].value - values[i as usize].abs_err();
        let upper = |i: u32| values[i as usize].value + values[i as usize].abs_err();
        let n = o.len();
        let mut suffix_min_lower = vec![f64::INFINITY; n + 1];
        for k in (0..n).rev() {
            suffix_min_lower[k] = suffix_min_lower[k + 1].min(lower(o[k]));
        }
        let mut start = 0;
        let mut max_upper = f64::NEG_INFINITY;
        for k in 0..n {
            max_upper = max_upper.max(upper(o[k]));
            // Split after k when nothing before can exceed anything after.
            if max_upper < suffix_min_lower[k + 1] {
                if k > start {
                    o[start..=k].sort_unstable_by(|&i, &j| {
                        self.cmp(values[i as usize], values[j as usize]).then(i.cmp(&j))
                    });
                }
                start = k + 1;
                max_upper = f64::NEG_INFINITY;
            }
        }
        o
    }

    /// Exact comparison of two filtration values.
    #[inline]
    pub fn cmp(&self, a: Value, b: Value) -> Ordering {
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
        let mut pa = [[0.0; 3]; 4];
        let mut pb = [[0.0; 3]; 4];
        let na = self.source_points(a.source, &mut pa);
        let nb = self.source_points(b.source, &mut pb);
        compare_radius2_exact(&pa[..na], &pb[..nb])
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
        let n = self.source_points(v.source, &mut p);
        radius2_correctly_rounded(&p[..n])
    }

    fn source_points(&self, source: u32, out: &mut [Point; 4]) -> usize {
        let c = self.complex;
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
}

#[inline]
fn own(r: Radius2, dim: u32, index: usize) -> Value {
    Value { value: r.value, rel_err: r.rel_err, source: (dim << DIM_SHIFT) | index as u32 }
}

/// LSD radix sort by key (8-bit digits; digits equal across all keys are skipped), stable,
/// so equal keys stay in id order.
fn radix_sort(mut a: Vec<(u64, u32)>) -> Vec<(u64, u32)> {
    let mut b = vec![(0u64, 0u32); a.len()];
    let (mut and_all, mut or_all) = (u64::MAX, 0u64);
    for &(k, _) in &a {
        and_all &= k;
        or_all |= k;
    }
    let varying = and_all ^ or_all;
    for shift in (0..64).step_by(8) {
        if (varying >> shift) & 0xff == 0 {
            continue;
        }
        let mut count = [0usize; 257];
        for &(k, _) in &a {
            count[((k >> shift) & 0xff) as usize + 1] += 1;
        }
        for d in 0..256 {
            count[d + 1] += count[d];
        }
        for &x in &a {
            let d = ((x.0 >> shift) & 0xff) as usize;
            b[count[d]] = x;
            count[d] += 1;
        }
        std::mem::swap(&mut a, &mut b);
    }
    a
}
