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
pub mod spatial_sort;

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

/// The persistence diagram (squared radii) of the alpha complex of `points`.
///
/// ```
/// // The regular octahedron: 7 loops born at 1/2, one void from 2/3 to 1.
/// let pts = [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]];
/// let d = toporec::homology::alpha_persistence(&pts).unwrap();
/// assert_eq!(d.counts(), [6, 7, 1]);
/// assert_eq!(d.dimension(2)[0].death, 1.0);
/// ```
pub fn alpha_persistence(points: &[Point]) -> Result<Diagram, ComplexError> {
    let complex = DelaunayComplex::new(points)?;
    let filtration = Filtration::new(&complex);
    Ok(persistence::persistence(&filtration))
}
