//! Lateral views: a descriptor's polar grid as it would look from an origin moved sideways.
//!
//! A polar grid depends on where the sensor stands: driven back on the other side of a road,
//! a few metres from the first pass, the near structures move by tens of degrees and a ring or
//! two. Scan Context++ answers this by storing copies described from origins moved sideways
//! (its root-shift augmentation). Here the query alone is moved, at search time, and nothing
//! more is stored: the grid is resampled as seen from the origin `(0, shift)` of the sensor
//! frame (y left). Each cell of the view takes the stored grid at its centre's place: the
//! relief channel (a sum over the cell) bilinearly between the four nearest cell centres, as
//! the grid shares a square, scaled by the ratio of the two cells' areas and coded anew
//! against the view's largest; the height channel (a maximum) from the cell its centre falls
//! in. Cells whose centre lies beyond `max_radius` of the sensor are empty. The near cells of
//! a view are coarse (a 4 m ring resampled), the far ones nearly exact.

use super::field::{Place, code};
use super::{CHANNELS, LEVELS, PlusParams, RELIEF};
use std::f64::consts::TAU;

/// The polar grid of the descriptor `d` as seen from the origin (0, `shift`) (m, left of the
/// sensor; negative: right): a descriptor's first part, all a query's matching reads.
pub(super) fn view(d: &[f32], shift: f64, p: &PlusParams) -> Vec<f32> {
    let (rings, sectors) = (p.rings, p.sectors);
    let (ring_width, sector_angle) = (p.max_radius / rings as f64, TAU / sectors as f64);
    let plane = rings * sectors;
    let mut out = d[..p.polar_len()].to_vec();
    let mut relief = vec![0f64; plane];
    for i in 0..rings {
        for j in 0..sectors {
            let (r, t) = ((i as f64 + 0.5) * ring_width, (j as f64 + 0.5) * sector_angle);
            let (x, y) = (r * t.cos(), shift + r * t.sin());
            let (range, azimuth) = (x.hypot(y), y.atan2(x).rem_euclid(TAU));
            let height = &mut out[(CHANNELS - 1 - RELIEF) * plane + i * sectors + j];
            if range >= p.max_radius {
                *height = 0.0;
                continue;
            }
            let stored = |ch: usize, i: usize, j: usize| d[ch * plane + i * sectors + j] as f64;
            let at = Place::at(range / ring_width, azimuth / sector_angle, p);
            *height = stored(CHANNELS - 1 - RELIEF, at.cell.0, at.cell.1) as f32;
            // Codes are square roots of shares: the shares are what add up.
            let share = |i: usize, j: usize| (stored(RELIEF, i, j) / LEVELS).powi(2);
            let ([(inner, w_inner), (outer, w_outer)], [(before, w_before), (after, w_after)]) =
                (at.rings, at.sectors);
            let shared = w_inner * (w_before * share(inner, before) + w_after * share(inner, after))
                + w_outer * (w_before * share(outer, before) + w_after * share(outer, after));
            // A cell's area grows with its ring's radius.
            relief[i * sectors + j] = shared * r / range.max(0.5 * ring_width);
        }
    }
    let largest = relief.iter().copied().fold(0.0, f64::max);
    for (c, &v) in out[RELIEF * plane..(RELIEF + 1) * plane].iter_mut().zip(&relief) {
        *c = if largest > 0.0 { code(v / largest) } else { 0.0 };
    }
    out
}
