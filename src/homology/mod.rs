//! Persistent homology of the 3D alpha complex — the engine of toporec.
//!
//! `points → DelaunayComplex → Filtration → persistence → Diagram`, matching GUDHI 3.13's
//! `AlphaComplex(points).create_simplex_tree().persistence()` (`Alpha_complex.h`,
//! `simplex_tree.py`): squared-radius filtration, duplicates merged, zero-length pairs dropped, one `(0, inf)` class in H0, and
//! H0..H(d-1) for a complex of dimension d (a single point gives an empty diagram).
//!
//! Combinatorics are exact (robust predicates, exact Gabriel tests); filtration values are
//! `f64` but compared exactly when their error bounds overlap, so tied values tie.

pub mod complex;
pub mod delaunay;
pub mod exact;
pub mod filtration;
pub mod persistence;
pub(crate) mod spatial_sort;

pub use complex::{ComplexError, DelaunayComplex};
pub use exact::Point;
pub use filtration::Filtration;

/// One persistence pair.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pair {
    /// Homology dimension.
    pub dim: u8,
    /// Birth value.
    pub birth: f64,
    /// Death value (`+inf` for the essential class).
    pub death: f64,
}

/// A persistence diagram: pairs sorted by (dim, birth, death).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Diagram {
    pairs: Vec<Pair>,
}

impl Diagram {
    /// Sorts `pairs` into a diagram (pairs read back from an index come sorted: checked, not
    /// sorted again).
    pub fn new(mut pairs: Vec<Pair>) -> Self {
        let order = |a: &Pair, b: &Pair| {
            a.dim.cmp(&b.dim).then(a.birth.total_cmp(&b.birth)).then(a.death.total_cmp(&b.death))
        };
        if !pairs.is_sorted_by(|a, b| order(a, b).is_le()) {
            pairs.sort_unstable_by(order);
        }
        Diagram { pairs }
    }

    /// All pairs, sorted by (dim, birth, death).
    pub fn pairs(&self) -> &[Pair] {
        &self.pairs
    }

    /// The pairs of one dimension.
    pub fn dimension(&self, dim: u8) -> &[Pair] {
        let start = self.pairs.partition_point(|p| p.dim < dim);
        let end = self.pairs.partition_point(|p| p.dim <= dim);
        &self.pairs[start..end]
    }

    /// Number of pairs per dimension 0, 1, 2.
    pub fn counts(&self) -> [usize; 3] {
        [0, 1, 2].map(|d| self.dimension(d).len())
    }

    /// The same diagram in radii (square roots of the squared radii).
    pub fn to_radii(&self) -> Diagram {
        Diagram {
            pairs: self
                .pairs
                .iter()
                .map(|p| Pair { dim: p.dim, birth: p.birth.sqrt(), death: p.death.sqrt() })
                .collect(),
        }
    }

    /// Keeps only the given dimensions.
    pub fn retain_dims(&mut self, dims: &[u8]) {
        self.pairs.retain(|p| dims.contains(&p.dim));
    }

    /// Number of pairs.
    pub fn len(&self) -> usize {
        self.pairs.len()
    }

    /// Whether there are no pairs.
    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }
}

/// Distinct points must be at least this far apart, relative to the cloud's extent, as a
/// power of two: beyond, the filtered predicates could underflow.
pub(crate) const MIN_SPACING_EXPONENT: i32 = -100;

/// The binary exponent `e` with `x = m · 2^e`, `m` in [1/2, 1) (`x` > 0, subnormals included).
fn exponent(x: f64) -> i32 {
    if x < f64::MIN_POSITIVE {
        return exponent(x * 2f64.powi(64)) - 64;
    }
    ((x.to_bits() >> 52) & 0x7ff) as i32 - 1022
}

/// `x · 2^k`, exact whenever the result is a normal double (in steps that stay normal).
fn scale_pow2(mut x: f64, mut k: i32) -> f64 {
    while k != 0 {
        let step = k.clamp(-1000, 1000);
        x *= f64::from_bits(((step + 1023) as u64) << 52);
        k -= step;
    }
    x
}

/// The persistence diagram (squared radii) of the alpha complex of `points`.
///
/// The cloud is first scaled by a power of two so that its largest |coordinate| lies in
/// [1/2, 1) — exact in floating point — computed there, and its squared radii scaled back by
/// the square of that power (exact too): so the engine's filters never overflow or underflow,
/// whatever the cloud's magnitude. Clouds it cannot compute exactly are refused, never answered
/// wrongly: distinct points closer than 2^`MIN_SPACING_EXPONENT` of the extent, or squared
/// radii outside the range of doubles.
///
/// ```
/// // The regular octahedron: 7 loops born at 1/2, one void from 2/3 to 1.
/// let pts = [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]];
/// let d = toporec::homology::alpha_persistence(&pts).unwrap();
/// assert_eq!(d.counts(), [6, 7, 1]);
/// assert_eq!(d.dimension(2)[0].death, 1.0);
/// ```
pub fn alpha_persistence(points: &[Point]) -> Result<Diagram, ComplexError> {
    if let Some((index, p)) = points.iter().enumerate().find(|(_, p)| !p.iter().all(|c| c.is_finite())) {
        return Err(ComplexError::NonFinite { index, x: p[0], y: p[1], z: p[2] });
    }
    let extent = points.iter().flatten().fold(0.0f64, |m, c| m.max(c.abs()));
    if extent == 0.0 {
        return raw_persistence(points);
    }
    let e = exponent(extent);
    let scaled: Vec<Point> = points.iter().map(|p| p.map(|c| scale_pow2(c, -e))).collect();
    // Distinct points differ in some axis by at least that axis's smallest gap.
    let mut smallest = f64::INFINITY;
    for axis in 0..3 {
        let mut v: Vec<f64> = scaled.iter().map(|p| p[axis]).collect();
        v.sort_unstable_by(f64::total_cmp);
        let gap = v.windows(2).map(|w| w[1] - w[0]).filter(|g| *g > 0.0).fold(f64::INFINITY, f64::min);
        smallest = smallest.min(gap);
    }
    if smallest < scale_pow2(1.0, MIN_SPACING_EXPONENT) {
        return Err(ComplexError::TooClose { min_exponent: MIN_SPACING_EXPONENT, found: exponent(smallest) });
    }
    let mut diagram = raw_persistence(&scaled)?;
    if e == 0 {
        return Ok(diagram);
    }
    let values = diagram.pairs.iter().flat_map(|p| [p.birth, p.death]).filter(|v| v.is_finite() && *v > 0.0);
    let (lo, hi) =
        values.fold((i32::MAX, i32::MIN), |(lo, hi), v| (lo.min(exponent(v)), hi.max(exponent(v))));
    // v = m · 2^x scales to m · 2^(x + 2e): normal while x + 2e - 1 lies in [-1022, 1023].
    if lo != i32::MAX && (lo - 1 + 2 * e < -1022 || hi - 1 + 2 * e > 1023) {
        return Err(ComplexError::OutOfRange { lo: lo - 1 + 2 * e, hi: hi - 1 + 2 * e });
    }
    for p in &mut diagram.pairs {
        p.birth = scale_pow2(p.birth, 2 * e);
        p.death = scale_pow2(p.death, 2 * e);
    }
    Ok(diagram)
}

/// A persistence pair and where its class dies: the centroid of the simplex whose entrance
/// kills it (H0: the merging edge's midpoint; H1: the triangle that fills the loop; H2: the
/// tetrahedron that fills the void), in the input's coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocatedPair {
    /// The pair (squared radii).
    pub pair: Pair,
    /// Where it dies (`None` for the essential H0 class).
    pub at: Option<Point>,
}

/// The pairs of [`alpha_persistence`] (the same multiset) with their locations, in no
/// particular order.
pub fn alpha_persistence_located(points: &[Point]) -> Result<Vec<LocatedPair>, ComplexError> {
    if let Some((index, p)) = points.iter().enumerate().find(|(_, p)| !p.iter().all(|c| c.is_finite())) {
        return Err(ComplexError::NonFinite { index, x: p[0], y: p[1], z: p[2] });
    }
    let extent = points.iter().flatten().fold(0.0f64, |m, c| m.max(c.abs()));
    let e = if extent == 0.0 { 0 } else { exponent(extent) };
    let scaled: Vec<Point> = points.iter().map(|p| p.map(|c| scale_pow2(c, -e))).collect();
    let complex = DelaunayComplex::new(&scaled)?;
    let filtration = Filtration::new(&complex);
    let centroid = |vertices: &[u32]| -> Point {
        let mut sum = [0.0; 3];
        for &v in vertices {
            let q = complex.points[v as usize];
            for k in 0..3 {
                sum[k] += q[k];
            }
        }
        sum.map(|c| scale_pow2(c / vertices.len() as f64, e))
    };
    let located = persistence::located_pairs(&filtration)
        .into_iter()
        .map(|(p, killer)| {
            let at = match killer {
                persistence::Killer::Edge(i) => Some(centroid(&complex.edges[i as usize])),
                persistence::Killer::Triangle(i) => Some(centroid(&complex.triangles[i as usize])),
                persistence::Killer::Tet(i) => Some(centroid(&complex.tets[i as usize])),
                persistence::Killer::Never => None,
            };
            let pair =
                Pair { dim: p.dim, birth: scale_pow2(p.birth, 2 * e), death: scale_pow2(p.death, 2 * e) };
            LocatedPair { pair, at }
        })
        .collect();
    Ok(located)
}

/// The engine on points as given.
fn raw_persistence(points: &[Point]) -> Result<Diagram, ComplexError> {
    let complex = DelaunayComplex::new(points)?;
    let filtration = Filtration::new(&complex);
    Ok(persistence::persistence(&filtration))
}
