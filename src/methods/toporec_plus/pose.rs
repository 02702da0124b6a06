//! The fine stage: where the query stands relative to a candidate, and so which of several
//! neighbouring candidates is the nearest.
//!
//! Beside its polar grid, a descriptor holds a Cartesian **image** of the scan around the
//! sensor: `image_side` × `image_side` cells of `image_cell` metres, each the height code of
//! the highest square of the height field in it (the height channel's codes; 0 where none).
//! Given the yaw the polar match found, the query's image is turned by it (bilinear) and
//! phase-correlated with the candidate's (both zero-padded, the two real images in one complex
//! FFT), the cells around the sensor left out of both (`NEAR_FIELD_M`: the vehicle's own
//! returns fill them alike in every scan and would draw each pose toward no shift); the
//! correlation's peak, refined between cells by the centroid of the peak and its two neighbours
//! on each axis, is the query's position in the candidate's sensor frame: x forward, y left,
//! metres.
//!
//! Neighbouring scans of a drive lie a fraction of a cell apart, so the refinement carries the
//! estimate. A parabola through the peak and its neighbours, as commonly used, draws a sub-cell
//! shift toward the cell's centre: on the real city drive of docs/evaluation.md it estimates
//! the forward offset at about half its size. The centroid, its negative neighbours counted as
//! 0, halves the median error there. The fine stage's ranking still uses the parabola's forward
//! offset ([`Pose::ranked_x`]): its weight and near-tie limit were chosen with it.

use super::PlusParams;
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// The query's position in a candidate's sensor frame (m), and the height of the phase
/// correlation's peak (1 for two images equal up to the shift).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Forward (m).
    pub x: f64,
    /// Left (m).
    pub y: f64,
    /// The normalized correlation's peak, in (0, 1].
    pub peak: f64,
    /// Forward (m), the peak refined by a parabola instead: what the fine stage ranks
    /// near-ties by (the module's doc says why).
    pub ranked_x: f64,
}

/// The image's codes of a height field's filled squares (`centres` and `codes` side by side),
/// row by row: `[x cell][y cell]`, the highest code of the squares in a cell.
pub(super) fn image(centres: impl Iterator<Item = ((f64, f64), f32)>, p: &PlusParams) -> Vec<f32> {
    let n = p.image_side;
    let half = n as f64 / 2.0;
    let mut out = vec![0f32; n * n];
    for ((x, y), code) in centres {
        let (i, j) = ((x / p.image_cell + half).floor(), (y / p.image_cell + half).floor());
        if (0.0..n as f64).contains(&i) && (0.0..n as f64).contains(&j) {
            let c = &mut out[i as usize * n + j as usize];
            *c = c.max(code);
        }
    }
    out
}

/// Phase correlation of images of one size, planned once.
pub(super) struct Aligner {
    n: usize,
    pad: usize,
    forward: Arc<dyn Fft<f32>>,
    inverse: Arc<dyn Fft<f32>>,
}

impl Aligner {
    /// The aligner of `p`'s images: `image_side` cells, padded to 1.5 times that, rounded up to
    /// a multiple of 8 (so that shifts up to a quarter of the image do not wrap onto the image,
    /// and the transform's length has small factors).
    pub(super) fn new(p: &PlusParams) -> Self {
        let n = p.image_side;
        let pad = (n + n / 2).next_multiple_of(8);
        let mut planner = FftPlanner::new();
        Aligner { n, pad, forward: planner.plan_fft_forward(pad), inverse: planner.plan_fft_inverse(pad) }
    }

    /// The query's pose in the candidate's frame from their images (codes, `image_side²`
    /// each), the query's turned by `yaw_degrees` first (the polar match's yaw: the query's
    /// view is the candidate's turned counter-clockwise by it).
    pub(super) fn pose(&self, query: &[u8], candidate: &[u8], yaw_degrees: f64, p: &PlusParams) -> Pose {
        let (n, pad) = (self.n, self.pad);
        let turned = turn(query, n, yaw_degrees.to_radians());
        let near = near_field(n, p.image_cell);
        // The candidate in the real part, the turned query in the imaginary part; the near
        // field left out of both.
        let mut z = vec![Complex32::new(0.0, 0.0); pad * pad];
        for i in 0..n {
            for j in 0..n {
                if !(near.contains(&i) && near.contains(&j)) {
                    z[i * pad + j] = Complex32::new(candidate[i * n + j] as f32, turned[i * n + j]);
                }
            }
        }
        self.transform(&mut z, &self.forward);
        // Each image's spectrum from the mixed one; their normalized cross-power.
        let mut cross = vec![Complex32::new(0.0, 0.0); pad * pad];
        let mut largest = 0f32;
        for a in 0..pad {
            for b in 0..pad {
                let zk = z[a * pad + b];
                let zm = z[((pad - a) % pad) * pad + (pad - b) % pad].conj();
                let m = (zk + zm) * 0.5;
                let q = (zk - zm) * Complex32::new(0.0, -0.5);
                let r = m * q.conj();
                largest = largest.max(r.norm());
                cross[a * pad + b] = r;
            }
        }
        let floor = largest * 1e-6 + f32::MIN_POSITIVE;
        cross.iter_mut().for_each(|r| *r /= r.norm() + floor);
        self.transform(&mut cross, &self.inverse);
        let value = |a: usize, b: usize| cross[(a % pad) * pad + b % pad].re as f64;
        let (mut best, mut at) = (f64::NEG_INFINITY, (0, 0));
        for a in 0..pad {
            for b in 0..pad {
                if value(a, b) > best {
                    (best, at) = (value(a, b), (a, b));
                }
            }
        }
        let (a, b) = at;
        let before_after = |da: usize, db: usize| (value(a + pad - da, b + pad - db), value(a + da, b + db));
        let ((behind, ahead), (right, left)) = (before_after(1, 0), before_after(0, 1));
        let signed = |k: usize, d: f64| if k >= pad / 2 { k as f64 + d - pad as f64 } else { k as f64 + d };
        let scale = (pad * pad) as f64;
        Pose {
            x: signed(a, centroid(behind, best, ahead)) * p.image_cell,
            y: signed(b, centroid(right, best, left)) * p.image_cell,
            peak: best / scale,
            ranked_x: signed(a, vertex(behind, best, ahead)) * p.image_cell,
        }
    }

    /// The 2D transform of `z` (`pad × pad`, row-major) in place: the rows, then the columns.
    fn transform(&self, z: &mut [Complex32], fft: &Arc<dyn Fft<f32>>) {
        let pad = self.pad;
        fft.process(z);
        transpose(z, pad);
        fft.process(z);
        transpose(z, pad);
    }
}

/// How far the fine stage's images reach around the sensor before they are left out of the
/// correlation (m, along each axis): the vehicle that carries the sensor. Its own returns lie
/// in the same cells of every scan, so they correlate best at no shift and draw a pose toward
/// the candidate. A car is about 2 m wide and 4–5 m long, its sensor near the middle of the
/// roof (on the KITTI recordings of docs/evaluation.md, a few dozen returns a scan lie within
/// 2 m of the sensor, off the car itself).
const NEAR_FIELD_M: f64 = 2.0;

/// The rows (and columns) of an `n`-cell image whose cells lie within [`NEAR_FIELD_M`] of the
/// sensor, at least the two cells around it: the sensor stands at the corner between rows
/// `n/2 - 1` and `n/2`.
fn near_field(n: usize, cell: f64) -> std::ops::Range<usize> {
    let k = ((NEAR_FIELD_M / cell).floor() as usize).clamp(1, n / 2);
    n / 2 - k..n / 2 + k
}

/// The sub-cell offset of a peak from its value and its neighbours' before and after it: their
/// centroid, a negative neighbour counted as 0 (in [-0.5, 0.5]).
fn centroid(before: f64, peak: f64, after: f64) -> f64 {
    let (before, after) = (before.max(0.0), after.max(0.0));
    let mass = before + peak + after;
    if mass > 0.0 { (after - before) / mass } else { 0.0 }
}

/// The sub-cell offset of a peak by the vertex of the parabola through it and its neighbours
/// (in [-0.5, 0.5]; 0 where they do not curve down).
fn vertex(before: f64, peak: f64, after: f64) -> f64 {
    let curvature = before - 2.0 * peak + after;
    if curvature < 0.0 { (0.5 * (before - after) / curvature).clamp(-0.5, 0.5) } else { 0.0 }
}

/// A square matrix transposed in place.
fn transpose(z: &mut [Complex32], n: usize) {
    for i in 0..n {
        for j in i + 1..n {
            z.swap(i * n + j, j * n + i);
        }
    }
}

/// The image `codes` (`n × n`) turned by `angle` (radians, counter-clockwise) about the sensor:
/// the value at cell `c` is the image's at `R(angle) c`, bilinear, 0 outside.
fn turn(codes: &[u8], n: usize, angle: f64) -> Vec<f32> {
    let (sin, cos) = angle.sin_cos();
    let centre = (n as f64 - 1.0) / 2.0;
    let at = |i: isize, j: isize| -> f32 {
        if i < 0 || j < 0 || i >= n as isize || j >= n as isize {
            0.0
        } else {
            codes[i as usize * n + j as usize] as f32
        }
    };
    let mut out = vec![0f32; n * n];
    for a in 0..n {
        for b in 0..n {
            let (x, y) = (a as f64 - centre, b as f64 - centre);
            let (u, v) = (centre + cos * x - sin * y, centre + sin * x + cos * y);
            let (i, j) = (u.floor(), v.floor());
            let (fu, fv) = ((u - i) as f32, (v - j) as f32);
            let (i, j) = (i as isize, j as isize);
            out[a * n + b] = (1.0 - fu) * ((1.0 - fv) * at(i, j) + fv * at(i, j + 1))
                + fu * ((1.0 - fv) * at(i + 1, j) + fv * at(i + 1, j + 1));
        }
    }
    out
}
