//! RING (Lu et al., *One RING to Rule Them All: Radon Sinogram for Place Recognition,
//! Orientation and Translation Estimation*, IROS 2022), as the authors' CPU path computes it
//! (`lus6-Jenny/RING`: `utils/core.py` `generate_bev` + `generate_RING_cpu`,
//! `utils/vox_utils/vox.py`, `utils/circorr2.py`, the pose of `evaluation/evaluate.py`);
//! `scripts/ring_reference.py` is the numpy transcription the tests hold it to.
//!
//! * **Grid**: points with x, y in (−70, 70) m and z in (1, 20) m (raw metres, sensor frame)
//!   set a 120 × 120 occupancy grid `[x cell][y cell]`; a coordinate's cell is
//!   `x · (1/c) + (1/c) · (70 − c/2)` (c = 140/120 m) rounded half to even. As in the reference,
//!   a point within 0.1 cell of the sensor or whose height coordinate is exactly the slab's
//!   middle is dropped, and cell (0, 0) is always empty.
//! * **Sinogram**: the grid's Radon transform as scikit-image's `radon` computes it (for each
//!   of 120 angles over [0°, 360°), 3° apart, the grid turned about cell (60, 60) by bilinear
//!   sampling, zero outside, summed along its rows; the corners outside the inscribed circle are
//!   lost), then along each angle's row the magnitude of the FFT over the offsets (norm
//!   "ortho"). A translation changes only the phases; a yaw becomes a circular shift of rows.
//! * **Distance**: both sinograms normalized (mean 0, variance + 1e-5 to 1), circularly
//!   cross-correlated along the angles column by column, the magnitudes summed over the
//!   columns; score = peak / (0.15 · 120 · 120), distance = 1 − score. The peak's shift is the
//!   yaw, known modulo 180° (the magnitude makes angles θ and θ + 180° alike).
//! * **Pose**: the query's grid turned by the shift's angle and by that angle − 180° (nearest
//!   cell, as torchvision's `rotate`), each matched to the entry's grid by a 2-D circular
//!   cross-correlation (both normalized by mean and standard deviation); the better peak gives
//!   the yaw and the offset in cells. No ICP refinement (the reference refines with GICP).
//!
//! Hits carry the yaw in degrees (the turn that brings the entry's view onto the query's, as
//! every method reports it) and the query's position in the entry's sensor frame (x forward,
//! y left, metres, on the 140/120 m grid).
//!
//! Where toporec differs from the reference: all arithmetic is float64 (the reference's torch
//! grid and its skimage angles are float32); the descriptor stores the sinogram as float32 and
//! the grid as bits, 16 cells a value.
//!
//! Search: at the default and exhaustive budgets, every entry is correlated with the query (the
//! reference's own evaluation does so). `matched:N` (toporec's addition) first takes the N
//! entries nearest by a yaw-invariant key — the sinogram's normalized columns averaged over the
//! angles — then correlates those.

use super::searcher::{Allowed, Hit, SearchBudget, SearchTimes, allowed_rows, timed};
use crate::types::Point;
use rayon::prelude::*;
use rustfft::num_complex::{Complex32, Complex64};
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// The method's name.
pub(crate) const NAME: &str = "ring";

/// Cells a descriptor value holds of the occupancy grid (bits of an integer below 2¹⁶, exact
/// in float32).
const CELLS_PER_VALUE: usize = 16;

/// RING settings (`[ring]` of a pipeline file); the defaults are the reference's
/// (`utils/config.py`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RingParams {
    /// Cells along each side of the grid (and offsets of the sinogram).
    pub side: usize,
    /// Angles of the sinogram over [0°, 360°) (even: the yaw is found modulo 180°).
    pub angles: usize,
    /// Half the grid's side (m): x and y within (−bound, bound).
    pub bound: f64,
    /// Lowest height kept (m, sensor frame, exclusive).
    pub z_min: f64,
    /// Highest height kept (m, exclusive).
    pub z_max: f64,
}

impl Default for RingParams {
    fn default() -> Self {
        RingParams { side: 120, angles: 120, bound: 70.0, z_min: 1.0, z_max: 20.0 }
    }
}

impl RingParams {
    /// Sinogram values (angles × side).
    pub(crate) fn sinogram_len(&self) -> usize {
        self.angles * self.side
    }

    /// A grid cell's side (m).
    pub fn cell(&self) -> f64 {
        2.0 * self.bound / self.side as f64
    }
}

/// The occupancy grid of a raw scan, `[x cell][y cell]`, 1 where occupied.
pub fn grid(points: &[Point], p: &RingParams) -> Vec<u8> {
    let n = p.side;
    let nf = n as f64;
    let vs = p.cell();
    let vz = p.z_max - p.z_min;
    let (s, sz) = (1.0 / vs, 1.0 / vz);
    // The reference's 4×4 transform from metres to cell coordinates, term by term.
    let (t, tz) = (s * (p.bound - vs / 2.0), sz * (-p.z_min - vz / 2.0));
    let mut out = vec![0u8; n * n];
    for q in points {
        let (x, y, z) = (q[0] * s + t, q[1] * s + t, q[2] * sz + tz);
        let inside = x > -0.5 && x < nf - 0.5 && y > -0.5 && y < nf - 0.5 && z > -0.5 && z < 0.5 && z != 0.0;
        if !inside {
            continue;
        }
        let near = ((t - x).powi(2) + (t - y).powi(2) + (tz - z).powi(2)).sqrt() < 0.1;
        if near {
            continue;
        }
        let (i, j) = (x.round_ties_even().clamp(0.0, nf - 1.0), y.round_ties_even().clamp(0.0, nf - 1.0));
        out[i as usize * n + j as usize] = 1;
    }
    out[0] = 0;
    out
}

/// The Radon transform of a square image (`[row][column]`) as scikit-image's `radon(image, theta, circle=True)`
/// computes it, `[angle][offset]`: for angle θᵢ = i · 360° / angles, the image turned about
/// cell (n/2, n/2) by bilinear sampling (zero outside), summed over its rows.
///
/// Computed from the nonzero cells: each spreads its value to the few output samples whose
/// sampling point falls within one cell of it (found through the inverse turn, each checked
/// with the forward one, as skimage's `warp` computes it). The sums equal the gathered ones up
/// to the order of addition.
pub fn radon(image: &[f64], p: &RingParams) -> Vec<f64> {
    radon_stack(image, 1, p)
}

/// [`radon`] of `channels` images of the same size at once (`[channel][angle][offset]`): the
/// weights a nonzero cell spreads are computed once for all channels, each channel's sums equal
/// to those of its own call.
pub fn radon_stack(images: &[f64], channels: usize, p: &RingParams) -> Vec<f64> {
    let n = p.side;
    let nf = n as f64;
    let cells = n * n;
    let centre = (n / 2) as f64;
    let nonzero: Vec<(f64, f64, usize)> = (0..cells)
        .filter(|&k| (0..channels).any(|c| images[c * cells + k] != 0.0))
        .map(|k| ((k / n) as f64, (k % n) as f64, k))
        .collect();
    // The preimage of a cell's ±1 square is a turned square within √2 of its centre.
    const REACH: f64 = 1.4143;
    let plane = p.angles * n;
    let mut out = vec![0.0f64; channels * plane];
    let mut values = vec![0.0f64; channels];
    for i in 0..p.angles {
        let theta = (i as f64 * (360.0 / p.angles as f64)) * (std::f64::consts::PI / 180.0);
        let (c, s) = (theta.cos(), theta.sin());
        let (r02, r12) = (-centre * (c + s - 1.0), -centre * (c - s - 1.0));
        for &(r, col_in, k) in &nonzero {
            for (ch, v) in values.iter_mut().enumerate() {
                *v = images[ch * cells + k];
            }
            // The output sample at (row, col) reads x = c·col + s·row + r02, y = −s·col + c·row + r12.
            let (u, v) = (col_in - r02, r - r12);
            let (col_c, row_c) = (c * u - s * v, s * u + c * v);
            let (cols_lo, cols_hi) = ((col_c - REACH).ceil().max(0.0), (col_c + REACH).floor().min(nf - 1.0));
            let (rows_lo, rows_hi) = ((row_c - REACH).ceil().max(0.0), (row_c + REACH).floor().min(nf - 1.0));
            let mut cf = cols_lo;
            while cf <= cols_hi {
                let mut sum = 0.0;
                let mut rf = rows_lo;
                while rf <= rows_hi {
                    let x = c * cf + s * rf + r02;
                    let y = -s * cf + c * rf + r12;
                    // Beyond a cell the weight is 0: skip the floors (the sum is unchanged).
                    if (y - r).abs() < 1.0 && (x - col_in).abs() < 1.0 {
                        sum += share(y, r) * share(x, col_in);
                    }
                    rf += 1.0;
                }
                let at = i * n + cf as usize;
                for (ch, &weight) in values.iter().enumerate() {
                    // A zero value adds nothing (its own call skips the cell).
                    if weight != 0.0 {
                        out[ch * plane + at] += weight * sum;
                    }
                }
                cf += 1.0;
            }
        }
    }
    out
}

/// The bilinear weight of cell coordinate `at` in a sample at `t` (as the 2-tap interpolation
/// between ⌊t⌋ and ⌈t⌉ gives it; 1 when `t` is the cell itself).
fn share(t: f64, at: f64) -> f64 {
    let (lo, hi) = (t.floor(), t.ceil());
    let d = t - lo;
    (if lo == at { 1.0 - d } else { 0.0 }) + (if hi == at { d } else { 0.0 })
}

/// [`radon`] gathered as skimage's `warp` samples: every output sample bilinear from its four
/// neighbours, summed over the rows in order.
#[cfg(test)]
fn radon_gathered(image: &[f64], p: &RingParams) -> Vec<f64> {
    let n = p.side;
    let centre = (n / 2) as f64;
    let at = |r: f64, c: f64| -> f64 {
        if r >= 0.0 && c >= 0.0 && (r as usize) < n && (c as usize) < n {
            image[r as usize * n + c as usize]
        } else {
            0.0
        }
    };
    let mut out = vec![0.0f64; p.angles * n];
    for (i, sums) in out.chunks_exact_mut(n).enumerate() {
        let theta = (i as f64 * (360.0 / p.angles as f64)) * (std::f64::consts::PI / 180.0);
        let (c, s) = (theta.cos(), theta.sin());
        let (r02, r12) = (-centre * (c + s - 1.0), -centre * (c - s - 1.0));
        for row in 0..n {
            let rf = row as f64;
            for (col, sum) in sums.iter_mut().enumerate() {
                let cf = col as f64;
                let x = c * cf + s * rf + r02;
                let y = -s * cf + c * rf + r12;
                let (r0, c0, r1, c1) = (y.floor(), x.floor(), y.ceil(), x.ceil());
                let (dr, dc) = (y - r0, x - c0);
                let top = (1.0 - dc) * at(r0, c0) + dc * at(r0, c1);
                let bottom = (1.0 - dc) * at(r1, c0) + dc * at(r1, c1);
                *sum += (1.0 - dr) * top + dr * bottom;
            }
        }
    }
    out
}

/// The translation-invariant sinogram: along each angle's row, |FFT| over the offsets (norm
/// "ortho").
pub fn invariant(sinogram: &[f64], p: &RingParams) -> Vec<f64> {
    let n = p.side;
    let fft = FftPlanner::<f64>::new().plan_fft_forward(n);
    let scale = 1.0 / (n as f64).sqrt();
    let mut out = Vec::with_capacity(sinogram.len());
    let mut buf = vec![Complex64::default(); n];
    for row in sinogram.chunks_exact(n) {
        for (b, &v) in buf.iter_mut().zip(row) {
            *b = Complex64::new(v, 0.0);
        }
        fft.process(&mut buf);
        out.extend(buf.iter().map(|z| {
            let (re, im) = (z.re * scale, z.im * scale);
            (re * re + im * im).sqrt()
        }));
    }
    out
}

/// The RING descriptor of a raw scan: the invariant sinogram (angles × side, float32), then
/// the occupancy grid, 16 cells a value (bit b of value v is cell 16v + b).
pub fn describe(points: &[Point], p: &RingParams) -> Vec<f32> {
    let g = grid(points, p);
    let cells: Vec<f64> = g.iter().map(|&v| v as f64).collect();
    let mut out: Vec<f32> = invariant(&radon(&cells, p), p).into_iter().map(|v| v as f32).collect();
    out.extend(
        g.chunks(CELLS_PER_VALUE)
            .map(|c| c.iter().enumerate().fold(0u32, |acc, (b, &v)| acc | ((v as u32) << b)) as f32),
    );
    out
}

/// The occupancy grid stored in a descriptor.
pub fn stored_grid(descriptor: &[f32], p: &RingParams) -> Vec<u8> {
    let cells = p.side * p.side;
    let packed = &descriptor[p.sinogram_len()..];
    (0..cells).map(|i| ((packed[i / CELLS_PER_VALUE] as u32 >> (i % CELLS_PER_VALUE)) & 1) as u8).collect()
}

/// The angle-axis spectra of a normalized sinogram, column by column: for each offset column,
/// its FFT over the angles (bins 0..=angles/2; the others are their conjugates), norm "ortho".
struct Spectra {
    /// `side` columns × `angles / 2 + 1` bins.
    bins: Vec<Complex32>,
}

/// FFT plans of one setting, shared.
pub(crate) struct Plans {
    angles_forward: Arc<dyn Fft<f64>>,
    angles_inverse: Arc<dyn Fft<f64>>,
    side_forward: Arc<dyn Fft<f64>>,
    side_inverse: Arc<dyn Fft<f64>>,
}

impl Plans {
    fn new(p: &RingParams) -> Self {
        let mut planner = FftPlanner::<f64>::new();
        Plans {
            angles_forward: planner.plan_fft_forward(p.angles),
            angles_inverse: planner.plan_fft_inverse(p.angles),
            side_forward: planner.plan_fft_forward(p.side),
            side_inverse: planner.plan_fft_inverse(p.side),
        }
    }
}

/// One sinogram normalized as `InstanceNorm2d` does: mean 0, divided by
/// √(biased variance + 1e-5).
fn normalized(sinogram: &[f32]) -> Vec<f64> {
    let n = sinogram.len() as f64;
    let mean = sinogram.iter().map(|&x| x as f64).sum::<f64>() / n;
    let var = sinogram.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / n;
    let sd = (var + 1e-5).sqrt();
    sinogram.iter().map(|&x| (x as f64 - mean) / sd).collect()
}

fn spectra(sinogram: &[f32], p: &RingParams, plans: &Plans) -> Spectra {
    let (a, n) = (p.angles, p.side);
    let v = normalized(sinogram);
    let half = a / 2 + 1;
    let scale = 1.0 / (a as f64).sqrt();
    let mut bins = Vec::with_capacity(n * half);
    let mut buf = vec![Complex64::default(); a];
    for col in 0..n {
        for (i, b) in buf.iter_mut().enumerate() {
            *b = Complex64::new(v[i * n + col], 0.0);
        }
        plans.angles_forward.process(&mut buf);
        bins.extend(buf[..half].iter().map(|z| Complex32::new((z.re * scale) as f32, (z.im * scale) as f32)));
    }
    Spectra { bins }
}

/// The correlation of two sinograms over the angle shifts: Σ over columns of
/// |circular cross-correlation| (norm "ortho" both ways), two real columns per complex inverse
/// FFT.
fn correlation(q: &Spectra, m: &Spectra, p: &RingParams, plans: &Plans) -> Vec<f64> {
    let (a, n) = (p.angles, p.side);
    let half = a / 2 + 1;
    let scale = 1.0 / (a as f64).sqrt();
    let mut corr = vec![0.0f64; a];
    let mut buf = vec![Complex64::default(); a];
    let mut scratch = vec![Complex64::default(); plans.angles_inverse.get_inplace_scratch_len()];
    let (mut one, mut two) = (vec![Complex64::default(); half], vec![Complex64::default(); half]);
    let products = |col: usize, out: &mut [Complex64]| {
        let (x, y) = (&q.bins[col * half..(col + 1) * half], &m.bins[col * half..(col + 1) * half]);
        for ((o, x), y) in out.iter_mut().zip(x).zip(y) {
            let z = x * y.conj();
            *o = Complex64::new(z.re as f64, z.im as f64);
        }
    };
    // sqrt(v² + 1e-15), the reference's magnitude, is |v| to 1e-11 wherever |v| > 1e-4.
    let magnitude = |v: f64| if v.abs() > 1e-4 { v.abs() } else { (v * v + 1e-15).sqrt() };
    let mut col = 0;
    while col < n {
        let pair = col + 1 < n;
        products(col, &mut one);
        if pair {
            products(col + 1, &mut two);
        } else {
            two.fill(Complex64::default());
        }
        // Two real columns in one complex transform: the first's spectrum plus i times the
        // second's; the upper half of each mirrors its lower half.
        for k in 0..half {
            buf[k] = one[k] + Complex64::new(-two[k].im, two[k].re);
        }
        for k in half..a {
            let (x, y) = (one[a - k].conj(), two[a - k].conj());
            buf[k] = x + Complex64::new(-y.im, y.re);
        }
        plans.angles_inverse.process_with_scratch(&mut buf, &mut scratch);
        for (c, z) in corr.iter_mut().zip(&buf) {
            *c += magnitude(z.re * scale);
            if pair {
                *c += magnitude(z.im * scale);
            }
        }
        col += 2;
    }
    corr
}

/// The score's peak and its shift (`angles/2 −` the first maximum's place after fftshift); the
/// score is divided by 0.15 · channels · angles · side, as the reference's `circorr2` does.
fn peak(corr: &[f64], channels: usize, p: &RingParams) -> (f64, i64) {
    let a = p.angles;
    let h = a / 2;
    let (mut best, mut at) = (f64::NEG_INFINITY, 0usize);
    for k in 0..a {
        let v = corr[(k + h) % a];
        if v > best {
            best = v;
            at = k;
        }
    }
    let score = best / (0.15 * (channels * a * p.side) as f64);
    (1.0 - score, h as i64 - at as i64)
}

/// How a RING-family descriptor is laid out: `channels` invariant sinograms (angles × side
/// float32 values each), then its grids, which `grids` reads back (`channels` images of
/// side × side cells, `[x cell][y cell]`).
#[derive(Clone, Copy)]
pub(crate) struct Layout {
    pub channels: usize,
    pub grids: fn(&[f32], &RingParams) -> Vec<f64>,
}

/// RING's layout: one sinogram, then the occupancy grid as bits.
const RING_LAYOUT: Layout = Layout { channels: 1, grids: occupancy };

fn occupancy(descriptor: &[f32], p: &RingParams) -> Vec<f64> {
    stored_grid(descriptor, p).iter().map(|&v| v as f64).collect()
}

/// The channel spectra of a descriptor's sinograms.
fn all_spectra(descriptor: &[f32], layout: Layout, p: &RingParams, plans: &Plans) -> Vec<Spectra> {
    descriptor.chunks_exact(p.sinogram_len()).take(layout.channels).map(|s| spectra(s, p, plans)).collect()
}

/// The correlation over the angle shifts summed over the channels (`torch.sum(corr, dim=-3)`).
fn correlation_all(q: &[Spectra], m: &[Spectra], p: &RingParams, plans: &Plans) -> Vec<f64> {
    let mut total = vec![0.0f64; p.angles];
    for (x, y) in q.iter().zip(m) {
        for (t, c) in total.iter_mut().zip(correlation(x, y, p, plans)) {
            *t += c;
        }
    }
    total
}

/// The distance of two descriptors of a layout and the angle shift of the best correlation
/// (the reference's `batch_circorr`).
pub(crate) fn distance_of(query: &[f32], candidate: &[f32], layout: Layout, p: &RingParams) -> (f64, i64) {
    let plans = Plans::new(p);
    let (q, m) = (all_spectra(query, layout, p, &plans), all_spectra(candidate, layout, p, &plans));
    peak(&correlation_all(&q, &m, p, &plans), layout.channels, p)
}

/// The RING distance of two descriptors and the angle shift of the best correlation (the
/// reference's `batch_circorr`).
pub fn distance(query: &[f32], candidate: &[f32], p: &RingParams) -> (f64, i64) {
    distance_of(query, candidate, RING_LAYOUT, p)
}

/// Square images (`channels` of n × n) turned by `degrees` as torchvision's `rotate` turns
/// them (nearest cell, about the centre, zero outside).
fn rotate(images: &[f64], n: usize, degrees: f64) -> Vec<f64> {
    let (s, c) = degrees.to_radians().sin_cos();
    let half = (n as f64 - 1.0) / 2.0;
    let w = n as f64;
    let mut out = vec![0.0; images.len()];
    for i in 0..n {
        let yc = i as f64 - half;
        for j in 0..n {
            let xc = j as f64 - half;
            let gx = (c * xc - s * yc) / (0.5 * w);
            let gy = (s * xc + c * yc) / (0.5 * w);
            let ix = (((gx + 1.0) * w - 1.0) / 2.0).round_ties_even();
            let iy = (((gy + 1.0) * w - 1.0) / 2.0).round_ties_even();
            if ix >= 0.0 && ix < w && iy >= 0.0 && iy < w {
                let from = iy as usize * n + ix as usize;
                for (o, image) in out.chunks_exact_mut(n * n).zip(images.chunks_exact(n * n)) {
                    o[i * n + j] = image[from];
                }
            }
        }
    }
    out
}

/// The 2-D FFTs (norm "ortho") of square images, each channel on its own, after all of them
/// are normalized together by their mean and unbiased standard deviation (the reference's
/// `fn.normalize(a, mean=a.mean(), std=a.std())`).
fn image_spectra(images: &[f64], n: usize, plans: &Plans) -> Vec<Complex64> {
    let mut data: Vec<Complex64> = standardized(images).into_iter().map(|v| Complex64::new(v, 0.0)).collect();
    for image in data.chunks_exact_mut(n * n) {
        fft2(image, n, plans, false);
    }
    data
}

fn fft2(data: &mut [Complex64], n: usize, plans: &Plans, inverse: bool) {
    let fft = if inverse { &plans.side_inverse } else { &plans.side_forward };
    for row in data.chunks_exact_mut(n) {
        fft.process(row);
    }
    let mut col = vec![Complex64::default(); n];
    for j in 0..n {
        for i in 0..n {
            col[i] = data[i * n + j];
        }
        fft.process(&mut col);
        for i in 0..n {
            data[i * n + j] = col[i];
        }
    }
    let scale = 1.0 / n as f64;
    for z in data.iter_mut() {
        *z *= scale;
    }
}

fn standardized(image: &[f64]) -> Vec<f64> {
    let n = image.len() as f64;
    let mean = image.iter().sum::<f64>() / n;
    let sd = (image.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    image.iter().map(|v| (v - mean) / sd).collect()
}

/// The reference's `solve_translation` against an entry's grid spectra: the offset (x, y
/// cells) of the first highest peak (row-major after fftshift) of the 2-D correlations'
/// magnitudes summed over the channels, and the peak.
fn translation(query: &[f64], entry: &[Complex64], n: usize, plans: &Plans) -> (i64, i64, f64) {
    let a = image_spectra(query, n, plans);
    let mut total = vec![0.0f64; n * n];
    for (x, y) in a.chunks_exact(n * n).zip(entry.chunks_exact(n * n)) {
        let mut prod: Vec<Complex64> = x.iter().zip(y).map(|(x, y)| x * y.conj()).collect();
        fft2(&mut prod, n, plans, true);
        for (t, z) in total.iter_mut().zip(&prod) {
            *t += (z.re * z.re + z.im * z.im).sqrt();
        }
    }
    let h = n / 2;
    let (mut best, mut at) = (f64::NEG_INFINITY, (0, 0));
    for i in 0..n {
        for j in 0..n {
            let v = total[((i + h) % n) * n + (j + h) % n];
            if v > best {
                best = v;
                at = (i, j);
            }
        }
    }
    (h as i64 - at.0 as i64, h as i64 - at.1 as i64, best)
}

/// The relative pose of a matched pair: of the two yaws the shift allows (`shift` and
/// `shift − angles/2` steps), the one whose turned query grid correlates better with the
/// entry's, with the offset in cells found for it: `(steps, x cells, y cells)`.
pub fn pose(query: &[f32], candidate: &[f32], shift: i64, p: &RingParams) -> (i64, i64, i64) {
    pose_of(query, candidate, shift, RING_LAYOUT, p)
}

/// [`pose`] for descriptors of a layout.
pub(crate) fn pose_of(
    query: &[f32],
    candidate: &[f32],
    shift: i64,
    layout: Layout,
    p: &RingParams,
) -> (i64, i64, i64) {
    pose_planned(query, candidate, shift, layout, p, &Plans::new(p))
}

fn pose_planned(
    query: &[f32],
    candidate: &[f32],
    shift: i64,
    layout: Layout,
    p: &RingParams,
    plans: &Plans,
) -> (i64, i64, i64) {
    let qg = (layout.grids)(query, p);
    let entry = image_spectra(&(layout.grids)(candidate, p), p.side, plans);
    let step = 360.0 / p.angles as f64;
    let solve = |steps: i64| translation(&rotate(&qg, p.side, steps as f64 * step), &entry, p.side, plans);
    let extra = shift - (p.angles / 2) as i64;
    let (x, y, peak) = solve(shift);
    let (xe, ye, peak_e) = solve(extra);
    // The reference keeps the first unless the other's peak is strictly higher (`error < error_extra`
    // with error = −peak).
    if peak > peak_e { (shift, x, y) } else { (extra, xe, ye) }
}

/// The hit of a pair: the yaw in degrees ([0, 360), the turn that brings the entry's view onto
/// the query's) and the query's position in the entry's frame (m).
#[allow(clippy::too_many_arguments)]
fn hit(
    row: usize,
    distance: f64,
    query: &[f32],
    candidate: &[f32],
    shift: i64,
    layout: Layout,
    p: &RingParams,
    plans: &Plans,
) -> Hit {
    let (steps, x, y) = pose_planned(query, candidate, shift, layout, p, plans);
    // `+ 0.0` turns a −0.0 into 0.0.
    let yaw = (-(steps as f64) * 360.0 / p.angles as f64).rem_euclid(360.0) + 0.0;
    let cell = p.cell();
    Hit { row, distance, yaw_degrees: Some(yaw), offset: Some([x as f64 * cell, y as f64 * cell]) }
}

/// The yaw-invariant key of a descriptor: each normalized sinogram's columns averaged over the
/// angles.
fn key(descriptor: &[f32], layout: Layout, p: &RingParams) -> Vec<f32> {
    let (a, n) = (p.angles, p.side);
    let mut out = Vec::with_capacity(layout.channels * n);
    for sinogram in descriptor.chunks_exact(p.sinogram_len()).take(layout.channels) {
        let v = normalized(sinogram);
        out.extend((0..n).map(|col| ((0..a).map(|i| v[i * n + col]).sum::<f64>() / a as f64) as f32));
    }
    out
}

/// RING-family descriptors searched by correlation with every entry (or with the `matched:N`
/// candidates nearest by the key).
pub(crate) struct Searcher {
    params: RingParams,
    layout: Layout,
    len: usize,
    plans: Plans,
    descriptors: Vec<f32>,
    spectra: Vec<Vec<Spectra>>,
    keys: Vec<f32>,
    candidates: Option<usize>,
}

impl Searcher {
    /// A searcher over `descriptors` (row-major, `len` values a row) of a layout.
    pub(crate) fn new(descriptors: Vec<f32>, params: RingParams, layout: Layout, len: usize) -> Self {
        let plans = Plans::new(&params);
        let spectra =
            descriptors.par_chunks_exact(len).map(|d| all_spectra(d, layout, &params, &plans)).collect();
        let keys = descriptors.chunks_exact(len).flat_map(|d| key(d, layout, &params)).collect();
        Searcher { params, layout, len, plans, descriptors, spectra, keys, candidates: None }
    }

    fn row(&self, i: usize) -> &[f32] {
        &self.descriptors[i * self.len..(i + 1) * self.len]
    }

    /// The rows a search correlates: all (or those allowed), or the `matched:N` nearest by key.
    fn rows(&self, query: &[f32], allowed: Allowed<'_>) -> Vec<usize> {
        let rows = allowed_rows(self.spectra.len(), allowed);
        match self.candidates {
            None => rows.collect(),
            Some(n) => {
                let q = key(query, self.layout, &self.params);
                let width = q.len();
                let mut by_key: Vec<(f32, usize)> = rows
                    .map(|r| {
                        let k = &self.keys[r * width..(r + 1) * width];
                        (k.iter().zip(&q).map(|(a, b)| (a - b) * (a - b)).sum::<f32>(), r)
                    })
                    .collect();
                let order = |a: &(f32, usize), b: &(f32, usize)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
                if by_key.len() > n {
                    by_key.select_nth_unstable_by(n - 1, order);
                    by_key.truncate(n);
                }
                by_key.into_iter().map(|(_, r)| r).collect()
            }
        }
    }

    /// The `k` best rows for `query` by the distance (ties by row), with their poses.
    pub(crate) fn search(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> Vec<Hit> {
        let p = &self.params;
        let layout = self.layout;
        let qs = all_spectra(query, layout, p, &self.plans);
        let rows = self.rows(query, allowed);
        let mut scored: Vec<(usize, f64, i64)> = rows
            .par_iter()
            .map(|&r| {
                let (d, shift) =
                    peak(&correlation_all(&qs, &self.spectra[r], p, &self.plans), layout.channels, p);
                (r, d, shift)
            })
            .collect();
        let order = |a: &(usize, f64, i64), b: &(usize, f64, i64)| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0));
        if k > 0 && scored.len() > k {
            scored.select_nth_unstable_by(k - 1, order);
        }
        scored.truncate(k);
        scored.sort_by(order);
        scored
            .into_par_iter()
            .map(|(r, d, shift)| hit(r, d, query, self.row(r), shift, layout, p, &self.plans))
            .collect()
    }
}

impl super::Searcher for Searcher {
    fn len(&self) -> usize {
        self.spectra.len()
    }

    fn push(&mut self, descriptor: &[f32]) {
        self.descriptors.extend_from_slice(descriptor);
        self.spectra.push(all_spectra(descriptor, self.layout, &self.params, &self.plans));
        self.keys.extend(key(descriptor, self.layout, &self.params));
    }

    fn search(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> (Vec<Hit>, SearchTimes) {
        timed(|| Searcher::search(self, query, k, allowed))
    }

    fn set_budget(&mut self, budget: SearchBudget, _entries: usize) {
        self.candidates = match budget {
            SearchBudget::Default | SearchBudget::Exhaustive => None,
            SearchBudget::Matched(n) => Some(n),
        };
    }
}

impl super::Named for RingParams {
    const NAME: &'static str = NAME;
}

impl super::Computed for RingParams {
    /// The settings' problems, each with its key.
    fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if !(8..=1024).contains(&self.side) {
            out.push(format!("ring.side: must be in [8, 1024]; found {}", self.side));
        }
        if !(2..=3600).contains(&self.angles) || !self.angles.is_multiple_of(2) {
            out.push(format!("ring.angles: must be even, in [2, 3600]; found {}", self.angles));
        }
        if !(self.bound.is_finite() && self.bound > 0.0) {
            out.push(format!("ring.bound: must be in (0, inf) m; found {}", self.bound));
        }
        if !(self.z_min.is_finite() && self.z_max.is_finite() && self.z_max > self.z_min) {
            out.push(format!(
                "ring: need z_min < z_max, both finite (z_min {}, z_max {})",
                self.z_min, self.z_max
            ));
        }
        out
    }

    /// Descriptor length: angles × side sinogram values, then the grid, 16 cells a value.
    fn len(&self) -> usize {
        self.sinogram_len() + (self.side * self.side).div_ceil(CELLS_PER_VALUE)
    }

    fn describe(&self, points: &[Point]) -> Result<Vec<f32>, String> {
        Ok(describe(points, self))
    }

    fn searcher(&self, descriptors: Vec<f32>) -> Box<dyn super::Searcher> {
        Box::new(Searcher::new(descriptors, self.clone(), RING_LAYOUT, self.len()))
    }

    /// Calibrated at precision 0.99 on the seed-11 drive of docs/loops.md: 0.4544 (the
    /// reference's own is 0.48).
    fn default_threshold(&self) -> Option<f64> {
        (*self == RingParams::default()).then_some(0.4544)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scattered_radon_equals_the_gathered_one() {
        let p = RingParams { side: 40, angles: 36, ..RingParams::default() };
        let mut rng = crate::rng::SplitMix64(5);
        for fill in [0.02, 0.3, 1.0] {
            // Occupancy (RING) and nonnegative values (RING++'s features).
            let image: Vec<f64> = (0..40 * 40)
                .map(|_| {
                    if rng.next_f64() < fill {
                        if fill < 1.0 { 1.0 } else { rng.next_f64() * 3.0 }
                    } else {
                        0.0
                    }
                })
                .collect();
            let (a, b) = (radon(&image, &p), radon_gathered(&image, &p));
            let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
            assert!(worst < 1e-9, "fill {fill}: {worst:e}");
            // Stacked with a sparser copy: each channel bit for bit its own transform.
            let sparse: Vec<f64> =
                image.iter().enumerate().map(|(k, &v)| if k % 3 == 0 { v } else { 0.0 }).collect();
            let stacked = radon_stack(&[image.clone(), sparse.clone()].concat(), 2, &p);
            assert_eq!(stacked, [a, radon(&sparse, &p)].concat(), "fill {fill}");
        }
    }
}
