//! The small value types every stage shares: a point of a cloud, a point of a persistence
//! diagram, a pose. They live here, below every module, so that sources, the engine and the
//! vectorizer need not import one another for a type alias.

/// A point in R³: metres in the sensor frame for scans (z up), or any unit for a bare cloud.
pub type Point = [f64; 3];

/// A point of a persistence diagram: `[birth, death]`.
pub type Point2 = [f64; 2];

/// A pose in a source's world frame (metres, z up; see each source for its frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// x (metres).
    pub x: f64,
    /// y (metres).
    pub y: f64,
    /// z (metres).
    pub z: f64,
    /// Heading about z (radians), when known (0 otherwise).
    pub yaw: f64,
}
