//! A uniform reservoir sample (Vitter's algorithm R) of weighted diagram points, drawn while
//! diagrams stream by, so codebooks can be fitted on tens of millions of points in bounded
//! memory. Seeded: the same seed and input order give the same sample.

use crate::rng::SplitMix64;
use crate::types::Point2;

/// At most `capacity` (point, weight) items, each seen item equally likely to be kept.
#[derive(Clone, Debug)]
pub struct Reservoir {
    capacity: usize,
    seen: u64,
    points: Vec<Point2>,
    weights: Vec<f64>,
    rng: SplitMix64,
}

impl Reservoir {
    /// An empty reservoir.
    pub fn new(capacity: usize, seed: u64) -> Self {
        Reservoir {
            capacity,
            seen: 0,
            points: Vec::with_capacity(capacity.min(1 << 20)),
            weights: Vec::new(),
            rng: SplitMix64(seed ^ 0x7265_7365_7276_6F69),
        }
    }

    /// Offers one item.
    #[inline]
    pub fn push(&mut self, point: Point2, weight: f64) {
        self.seen += 1;
        if self.points.len() < self.capacity {
            self.points.push(point);
            self.weights.push(weight);
        } else {
            let j = self.rng.below(self.seen as usize);
            if j < self.capacity {
                self.points[j] = point;
                self.weights[j] = weight;
            }
        }
    }

    /// Items offered so far.
    pub fn seen(&self) -> u64 {
        self.seen
    }

    /// The sample: points and their weights.
    pub fn sample(&self) -> (&[Point2], &[f64]) {
        (&self.points, &self.weights)
    }
}
