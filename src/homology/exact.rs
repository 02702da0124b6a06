//! Geometric quantities of the alpha filtration, computed in `f64` with a certified error
//! bound and decided exactly (big integers) only when the bound cannot decide.
//!
//! Owns: squared circumradii of edges, triangles and tetrahedra (`radius2`), the exact
//! comparison of two such radii (`compare_radius2_exact`), and the Gabriel tests
//! (`edge_obtuse`, `triangle_gabriel`). Does not own the orientation / in-sphere
//! predicates of the triangulation, which come from the `robust` crate.
//!
//! Exactness matters because mathematically tied filtration values (lattices, 5 mm-quantized
//! NCLT scans) must compare equal, or zero-length pairs would leak into the diagram.

use num_bigint::BigInt;
use num_traits::{Signed, Zero};
use std::cmp::Ordering;

pub use crate::types::Point;

const EPS: f64 = f64::EPSILON * 0.5;

/// A squared radius in `f64` with a bound on its relative error.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Radius2 {
    /// The value, rounded.
    pub value: f64,
    /// `|value - exact| <= rel_err * value`.
    pub rel_err: f64,
}

#[inline]
fn sub(a: &Point, b: &Point) -> Point {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
fn dot(a: &Point, b: &Point) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
fn cross(a: &Point, b: &Point) -> Point {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
#[inline]
fn abs3(a: &Point) -> Point {
    [a[0].abs(), a[1].abs(), a[2].abs()]
}
#[inline]
fn scale(a: &Point, s: f64) -> Point {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline]
fn add(a: &Point, b: &Point) -> Point {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// Squared radius of the smallest circumsphere of a simplex given by 2, 3 or 4 vertices.
pub(crate) fn radius2(v: &[Point]) -> Radius2 {
    match v.len() {
        2 => {
            let a = sub(&v[1], &v[0]);
            Radius2 { value: dot(&a, &a) * 0.25, rel_err: 8.0 * EPS }
        }
        3 => {
            let a = sub(&v[1], &v[0]);
            let b = sub(&v[2], &v[0]);
            let c = sub(&b, &a);
            let n = cross(&a, &b);
            let n2 = dot(&n, &n);
            let perm = cross_abs(&abs3(&a), &abs3(&b));
            let perm_norm = dot(&perm, &perm).sqrt();
            let value = dot(&a, &a) * dot(&b, &b) * dot(&c, &c) / (4.0 * n2);
            let rel_err = 64.0 * EPS * (1.0 + perm_norm / n2.sqrt());
            Radius2 { value, rel_err: if value.is_finite() { rel_err } else { f64::INFINITY } }
        }
        4 => tet_circumsphere(&[v[0], v[1], v[2], v[3]]).0,
        _ => Radius2 { value: 0.0, rel_err: 0.0 },
    }
}

/// The squared circumradius of the tetrahedron `v` and, for each facet `i` (opposite `v[i]`),
/// whether that facet is Gabriel with respect to `v[i]` — `Some(false)` when `v[i]` lies
/// strictly inside the facet's smallest circumsphere, `None` when the `f64` filter cannot
/// decide (then ask [`triangle_gabriel`]).
///
/// Both spheres pass through the facet's circumcircle, so `v[i]` is inside the facet's
/// sphere exactly when the tetrahedron's circumcentre lies strictly beyond facet `i`, i.e.
/// when its barycentric coordinate `λ_i` is negative. With `a, b, c` the edges from `v[0]`,
/// `d = a·(b×c)` and `N = |a|²(b×c) + |b|²(c×a) + |c|²(a×b)` (centre offset `N / 2d`),
/// `λ_1..λ_3 = N·(b×c), N·(c×a), N·(a×b)` over `2d²` and `λ_0 = 2d² − N·(b×c + c×a + a×b)`
/// over `2d²`: the quantities of the radius itself, so the four tests are nearly free.
pub(crate) fn tet_circumsphere(v: &[Point; 4]) -> (Radius2, [Option<bool>; 4]) {
    let a = sub(&v[1], &v[0]);
    let b = sub(&v[2], &v[0]);
    let c = sub(&v[3], &v[0]);
    let bc = cross(&b, &c);
    let ca = cross(&c, &a);
    let ab = cross(&a, &b);
    let d = dot(&a, &bc);
    let (a2, b2, c2) = (dot(&a, &a), dot(&b, &b), dot(&c, &c));
    let num = add(&add(&scale(&bc, a2), &scale(&ca, b2)), &scale(&ab, c2));
    let (aa, ab_, ac) = (abs3(&a), abs3(&b), abs3(&c));
    let pbc = cross_abs(&ab_, &ac);
    let pca = cross_abs(&ac, &aa);
    let pab = cross_abs(&aa, &ab_);
    let perm_d = dot(&aa, &pbc);
    let perm_n = add(&add(&scale(&pbc, a2), &scale(&pca, b2)), &scale(&pab, c2));
    let n2 = dot(&num, &num);
    let value = n2 / (4.0 * d * d);
    let rel_err = 64.0 * EPS * (1.0 + dot(&perm_n, &perm_n).sqrt() / n2.sqrt() + perm_d / d.abs());
    let radius = Radius2 { value, rel_err: if value.is_finite() { rel_err } else { f64::INFINITY } };
    // Sign of a degree-6 polynomial evaluated in f64: certain when beyond 64ε × its
    // permanent (the same kind of bound as the other filters here, with margin).
    let decide = |x: f64, perm: f64| {
        let bound = 64.0 * EPS * perm;
        if x > bound {
            Some(true)
        } else if x < -bound {
            Some(false)
        } else {
            None
        }
    };
    let s = add(&add(&bc, &ca), &ab);
    let ps = add(&add(&pbc, &pca), &pab);
    let gabriel = [
        decide(2.0 * d * d - dot(&num, &s), 2.0 * perm_d * perm_d + dot(&perm_n, &ps)),
        decide(dot(&num, &bc), dot(&perm_n, &pbc)),
        decide(dot(&num, &ca), dot(&perm_n, &pca)),
        decide(dot(&num, &ab), dot(&perm_n, &pab)),
    ];
    (radius, gabriel)
}

#[inline]
fn cross_abs(a: &Point, b: &Point) -> Point {
    [a[1] * b[2] + a[2] * b[1], a[2] * b[0] + a[0] * b[2], a[0] * b[1] + a[1] * b[0]]
}

/// `true` iff `w` lies strictly inside the diametral sphere of the edge `p q` (the angle at
/// `w` is obtuse). The f64 filter decides without branching; the exact test is out of line.
#[inline]
pub(crate) fn edge_obtuse(p: &Point, q: &Point, w: &Point) -> bool {
    let a = sub(p, w);
    let b = sub(q, w);
    let d = dot(&a, &b);
    let perm = dot(&abs3(&a), &abs3(&b));
    if d.abs() <= 16.0 * EPS * perm {
        return edge_obtuse_exact(p, q, w);
    }
    d < 0.0
}

#[cold]
#[inline(never)]
fn edge_obtuse_exact(p: &Point, q: &Point, w: &Point) -> bool {
    let e = Exact::new(&[*p, *q, *w]);
    let (p, q, w) = (e.pt(0), e.pt(1), e.pt(2));
    dot_b(&sub_b(&p, &w), &sub_b(&q, &w)).is_negative()
}

/// `true` iff `w` lies on or outside the smallest circumsphere of the triangle `p q r`.
#[inline]
pub(crate) fn triangle_gabriel(p: &Point, q: &Point, r: &Point, w_point: &Point) -> bool {
    // inside  <=>  |w'|² |n|² - (M × n)·w' < 0  with a = q-p, b = r-p, w' = w-p,
    // n = a × b, M = |a|² b - |b|² a (the circumcentre offset is (M × n) / (2|n|²)).
    let a = sub(q, p);
    let b = sub(r, p);
    let w = sub(w_point, p);
    let n = cross(&a, &b);
    let a2 = dot(&a, &a);
    let b2 = dot(&b, &b);
    let m = sub(&scale(&b, a2), &scale(&a, b2));
    let mn = cross(&m, &n);
    let lhs = dot(&w, &w) * dot(&n, &n);
    let rhs = dot(&mn, &w);
    let det = lhs - rhs;
    let (aa, ba, wa) = (abs3(&a), abs3(&b), abs3(&w));
    let na = cross_abs(&aa, &ba);
    let ma = add(&scale(&ba, a2), &scale(&aa, b2));
    let perm = dot(&wa, &wa) * dot(&na, &na) + dot(&cross_abs(&ma, &na), &wa);
    let bound = 64.0 * EPS * perm;
    if det > bound {
        return true;
    }
    if det < -bound {
        return false;
    }
    let e = Exact::new(&[*p, *q, *r, *w_point]);
    let (p, q, r, w) = (e.pt(0), e.pt(1), e.pt(2), e.pt(3));
    let a = sub_b(&q, &p);
    let b = sub_b(&r, &p);
    let w = sub_b(&w, &p);
    let n = cross_b(&a, &b);
    let a2 = dot_b(&a, &a);
    let b2 = dot_b(&b, &b);
    let m = sub_b(&scale_b(&b, &a2), &scale_b(&a, &b2));
    let det = dot_b(&w, &w) * dot_b(&n, &n) - dot_b(&cross_b(&m, &n), &w);
    !det.is_negative()
}

/// Exact comparison of the squared circumradii of two simplices (2 to 4 vertices each).
pub(crate) fn compare_radius2_exact(va: &[Point], vb: &[Point]) -> Ordering {
    let mut all: Vec<Point> = Vec::with_capacity(va.len() + vb.len());
    all.extend_from_slice(va);
    all.extend_from_slice(vb);
    let e = Exact::new(&all);
    let (na, da) = exact_radius2(&e, 0, va.len());
    let (nb, db) = exact_radius2(&e, va.len(), vb.len());
    (na * db).cmp(&(nb * da))
}

/// A squared circumradius held exactly: `num / den · 2^exp2` (`den > 0`).
pub(crate) struct ExactRadius2 {
    num: BigInt,
    den: BigInt,
    exp2: i32,
}

impl ExactRadius2 {
    /// The exact squared circumradius of a simplex (2 to 4 vertices).
    pub(crate) fn new(v: &[Point]) -> Self {
        let e = Exact::new(v);
        let (num, den) = exact_radius2(&e, 0, v.len());
        ExactRadius2 { num, den, exp2: 2 * e.emin }
    }
}

impl Ord for ExactRadius2 {
    /// Cross-multiplied, the smaller power of two brought up to the larger.
    fn cmp(&self, other: &Self) -> Ordering {
        let a = &self.num * &other.den;
        let b = &other.num * &self.den;
        match self.exp2.cmp(&other.exp2) {
            Ordering::Equal => a.cmp(&b),
            Ordering::Greater => (a << (self.exp2 - other.exp2) as u32).cmp(&b),
            Ordering::Less => a.cmp(&(b << (other.exp2 - self.exp2) as u32)),
        }
    }
}
impl PartialOrd for ExactRadius2 {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl PartialEq for ExactRadius2 {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for ExactRadius2 {}

/// The squared circumradius of a simplex (2 to 4 vertices), computed exactly and rounded to
/// the nearest double (ties to even) — the value GUDHI's `precision='exact'` reports.
pub(crate) fn radius2_correctly_rounded(v: &[Point]) -> f64 {
    let e = Exact::new(v);
    let (num, den) = exact_radius2(&e, 0, v.len());
    round_ratio(&num, &den, 2 * e.emin)
}

/// `num / den · 2^exp2` rounded to nearest-even (`num >= 0`, `den > 0`).
fn round_ratio(num: &BigInt, den: &BigInt, exp2: i32) -> f64 {
    if num.is_zero() {
        return 0.0;
    }
    // Scale so that the integer quotient has at least 55 bits.
    let shift = den.bits() as i64 - num.bits() as i64 + 55;
    let (n, d) = if shift >= 0 {
        (num << (shift as u64), den.clone())
    } else {
        (num.clone(), den << ((-shift) as u64))
    };
    let (q, r) = num_integer::Integer::div_rem(&n, &d);
    let sticky = !r.is_zero();
    let bits = q.bits() as i64;
    let extra = bits - 53;
    let q = q.magnitude();
    let mut mant: u64 = (q >> (extra as u64)).iter_u64_digits().next().unwrap_or(0);
    let low = q - ((num_bigint::BigUint::from(mant)) << (extra as u64));
    let half = num_bigint::BigUint::from(1u8) << ((extra - 1) as u64);
    let up = low > half || (low == half && (sticky || mant & 1 == 1));
    let mut exp = extra - shift + exp2 as i64;
    if up {
        mant += 1;
        if mant == 1 << 53 {
            mant >>= 1;
            exp += 1;
        }
    }
    ldexp(mant as f64, exp)
}

/// `x · 2^k`, exact while the result is a normal double.
fn ldexp(mut x: f64, mut k: i64) -> f64 {
    while k != 0 {
        let step = k.clamp(-1000, 1000);
        x *= f64::from_bits(((step + 1023) as u64) << 52);
        k -= step;
    }
    x
}

/// Exact squared radius as `num / den` (den > 0) of points `start..start+len` of `e`.
fn exact_radius2(e: &Exact, start: usize, len: usize) -> (BigInt, BigInt) {
    let p = e.pt(start);
    match len {
        2 => {
            let a = sub_b(&e.pt(start + 1), &p);
            (dot_b(&a, &a), BigInt::from(4))
        }
        3 => {
            let a = sub_b(&e.pt(start + 1), &p);
            let b = sub_b(&e.pt(start + 2), &p);
            let c = sub_b(&b, &a);
            let n = cross_b(&a, &b);
            (dot_b(&a, &a) * dot_b(&b, &b) * dot_b(&c, &c), dot_b(&n, &n) * 4)
        }
        4 => {
            let a = sub_b(&e.pt(start + 1), &p);
            let b = sub_b(&e.pt(start + 2), &p);
            let c = sub_b(&e.pt(start + 3), &p);
            let bc = cross_b(&b, &c);
            let ca = cross_b(&c, &a);
            let ab = cross_b(&a, &b);
            let d = dot_b(&a, &bc);
            let num = add_b(
                &add_b(&scale_b(&bc, &dot_b(&a, &a)), &scale_b(&ca, &dot_b(&b, &b))),
                &scale_b(&ab, &dot_b(&c, &c)),
            );
            (dot_b(&num, &num), &d * &d * 4)
        }
        _ => (BigInt::zero(), BigInt::from(1)),
    }
}

type BPoint = [BigInt; 3];

/// Points converted exactly to integers sharing one power-of-two scale.
struct Exact {
    pts: Vec<BPoint>,
    /// Every coordinate is `pts[i][k] · 2^emin`.
    emin: i32,
}

impl Exact {
    fn new(points: &[Point]) -> Self {
        let mut emin = i32::MAX;
        let decoded: Vec<[(i64, i32); 3]> = points
            .iter()
            .map(|p| {
                p.map(|x| {
                    let (m, e) = decode(x);
                    if m != 0 {
                        emin = emin.min(e);
                    }
                    (m, e)
                })
            })
            .collect();
        if emin == i32::MAX {
            emin = 0;
        }
        let pts = decoded
            .iter()
            .map(|c| {
                c.map(|(m, e)| if m == 0 { BigInt::zero() } else { BigInt::from(m) << ((e - emin) as u32) })
            })
            .collect();
        Exact { pts, emin }
    }
    fn pt(&self, i: usize) -> BPoint {
        self.pts[i].clone()
    }
}

/// `x = m · 2^e` exactly.
fn decode(x: f64) -> (i64, i32) {
    if x == 0.0 {
        return (0, 0);
    }
    let bits = x.to_bits();
    let sign = if bits >> 63 == 0 { 1 } else { -1 };
    let exp = ((bits >> 52) & 0x7ff) as i32;
    let frac = (bits & 0x000f_ffff_ffff_ffff) as i64;
    let (m, e) = if exp == 0 { (frac, -1074) } else { (frac | (1 << 52), exp - 1075) };
    (sign * m, e)
}

fn sub_b(a: &BPoint, b: &BPoint) -> BPoint {
    [&a[0] - &b[0], &a[1] - &b[1], &a[2] - &b[2]]
}
fn add_b(a: &BPoint, b: &BPoint) -> BPoint {
    [&a[0] + &b[0], &a[1] + &b[1], &a[2] + &b[2]]
}
fn dot_b(a: &BPoint, b: &BPoint) -> BigInt {
    &a[0] * &b[0] + &a[1] * &b[1] + &a[2] * &b[2]
}
fn cross_b(a: &BPoint, b: &BPoint) -> BPoint {
    [&a[1] * &b[2] - &a[2] * &b[1], &a[2] * &b[0] - &a[0] * &b[2], &a[0] * &b[1] - &a[1] * &b[0]]
}
fn scale_b(a: &BPoint, s: &BigInt) -> BPoint {
    [&a[0] * s, &a[1] * s, &a[2] * s]
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: [Point; 4] = [
        [-0.5453279550656607, -0.36648332058049427, 0.5947309146654682],
        [0.3525093415019491, -0.217780898796182, -0.33437214426723094],
        [0.19661750717437965, -0.6265316287925733, 0.3455120880292426],
        [0.8836057305398743, -0.503508570740858, 0.8977623036666365],
    ];

    #[test]
    fn correctly_rounded_radii_match_exact_rationals() {
        // Expected: Python `float(Fraction(...))` of the exact circumradius², correctly rounded.
        assert_eq!(radius2_correctly_rounded(&P), 1.7508375524540045);
        assert_eq!(radius2_correctly_rounded(&P[..3]), 0.4556293062437632);
        assert_eq!(radius2_correctly_rounded(&[[0.0; 3], [0.0, 0.0, 3.0]]), 2.25);
        assert_eq!(
            radius2_correctly_rounded(&[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
            0.75
        );
        // Ratios that need rounding.
        assert_eq!(round_ratio(&BigInt::from(1), &BigInt::from(3), 0), 1.0 / 3.0);
        assert_eq!(round_ratio(&BigInt::from(2), &BigInt::from(3), -4), 2.0 / 3.0 / 16.0);
        assert_eq!(round_ratio(&(BigInt::from(1) << 200u32), &BigInt::from(7), -200), 1.0 / 7.0);
    }

    #[test]
    fn f64_radius_is_within_its_error_bound() {
        for v in [&P[..2], &P[..3], &P[..]] {
            let r = radius2(v);
            let exact = radius2_correctly_rounded(v);
            assert!((r.value - exact).abs() <= r.rel_err * exact, "{v:?}");
        }
    }

    #[test]
    fn tet_facet_signs_agree_with_the_triangle_gabriel_test() {
        // Random tetrahedra and integer-lattice ones (where the circumcentre often lies on a
        // facet, so the filter must answer `None`, never a wrong sign).
        let mut rng = crate::rng::SplitMix64(11);
        let (mut decided, mut ties) = (0, 0);
        for k in 0..20_000 {
            let lattice = k % 2 == 1;
            let v: [Point; 4] = std::array::from_fn(|_| {
                [0, 1, 2].map(|_| {
                    if lattice { (rng.below(4) as f64) * 0.5 - 1.0 } else { rng.next_f64() * 2.0 - 1.0 }
                })
            });
            if crate::homology::delaunay::orient3d(&v[0], &v[1], &v[2], &v[3]) == 0.0 {
                continue;
            }
            let (r, gabriel) = tet_circumsphere(&v);
            let exact = radius2_correctly_rounded(&v);
            assert!((r.value - exact).abs() <= r.rel_err * exact, "{v:?}");
            for i in 0..4 {
                let f: Vec<Point> = (0..4).filter(|&j| j != i).map(|j| v[j]).collect();
                let exact = triangle_gabriel(&f[0], &f[1], &f[2], &v[i]);
                match gabriel[i] {
                    Some(g) => {
                        assert_eq!(g, exact, "{v:?} facet {i}");
                        decided += 1;
                    }
                    None => ties += 1,
                }
            }
        }
        assert!(decided > 30_000 && ties > 100, "decided {decided}, undecided {ties}");
    }

    #[test]
    fn gabriel_tests_on_the_boundary_count_as_gabriel() {
        let (p, q) = ([0.0, 0.0, 0.0], [2.0, 0.0, 0.0]);
        assert!(!edge_obtuse(&p, &q, &[1.0, 1.0, 0.0]), "on the diametral sphere");
        assert!(edge_obtuse(&p, &q, &[1.0, 0.5, 0.0]));
        assert!(!edge_obtuse(&p, &q, &[1.0, 1.5, 0.0]));
        let (a, b, c) = ([0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]);
        // Smallest circumsphere: centre (1, 1, 0), radius² 2.
        assert!(triangle_gabriel(&a, &b, &c, &[2.0, 2.0, 0.0]), "on the sphere");
        assert!(!triangle_gabriel(&a, &b, &c, &[1.0, 1.0, 1.0]));
        assert!(triangle_gabriel(&a, &b, &c, &[1.0, 1.0, 1.5]));
    }
}
