//! A uniform sample of weighted diagram points, drawn while diagrams stream by, so codebooks can
//! be fitted on tens of millions of points in bounded memory.
//!
//! It is a bottom-k sample: every point gets a pseudo-random priority from a hash of the key of
//! its diagram (the scan id), its place in the diagram and the seed, and the `capacity` points
//! of smallest priority are kept, in priority order. So the sample is uniform, and it depends
//! only on which diagrams were offered — not on their order, nor on how a run was split into
//! chunks or resumed after a crash.

use crate::rng::SplitMix64;
use crate::types::Point2;

/// One sampled point.
#[derive(Clone, Copy, Debug)]
struct Item {
    priority: u64,
    point: Point2,
    weight: f64,
}

/// At most `capacity` (point, weight) items, each offered item equally likely to be kept.
#[derive(Clone, Debug)]
pub struct Reservoir {
    capacity: usize,
    seed: u64,
    seen: u64,
    items: Vec<Item>,
}

impl Reservoir {
    /// An empty sample.
    pub fn new(capacity: usize, seed: u64) -> Self {
        Reservoir { capacity, seed: seed ^ 0x7265_7365_7276_6F69, seen: 0, items: Vec::new() }
    }

    /// Offers the `index`-th point of the diagram keyed `key`.
    #[inline]
    pub fn push(&mut self, key: u64, index: u64, point: Point2, weight: f64) {
        self.seen += 1;
        let mut rng = SplitMix64(self.seed ^ key.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ index);
        let priority = rng.next_u64();
        self.items.push(Item { priority, point, weight });
        // Amortized: trim to the capacity smallest whenever twice as many are held.
        if self.items.len() >= self.capacity.max(1 << 16).saturating_mul(2) {
            self.trim();
        }
    }

    fn trim(&mut self) {
        if self.items.len() > self.capacity {
            let key = |i: &Item| (i.priority, i.point[0].to_bits(), i.point[1].to_bits());
            self.items.select_nth_unstable_by_key(self.capacity, key);
            self.items.truncate(self.capacity);
        }
    }

    /// Adds another sample of the same capacity and seed (drawn from other diagrams): the
    /// result is the sample of both streams.
    pub fn merge(&mut self, other: Reservoir) {
        self.seen += other.seen;
        self.items.extend(other.items);
        self.trim();
    }

    /// Items offered so far.
    pub fn seen(&self) -> u64 {
        self.seen
    }

    /// The sample, in priority order: points and their weights.
    pub fn into_sample(mut self) -> (Vec<Point2>, Vec<f64>) {
        self.trim();
        self.items.sort_unstable_by_key(|i| (i.priority, i.point[0].to_bits(), i.point[1].to_bits()));
        self.items.iter().map(|i| (i.point, i.weight)).unzip()
    }
}
