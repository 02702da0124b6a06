//! LiDAR-Iris (Wang, Sun, Xu, Sarma, Yang, Kong, *LiDAR Iris for Loop-Closure Detection*,
//! IROS 2020), as the authors' code computes it (`BigMoWangying/LiDAR-Iris`,
//! `LidarIris/LidarIris.cpp`).
//!
//! * **The image.** 80 × 360 pixels: row ⌊√(x² + y²)⌋ (1 m bins; everything beyond 79 m in the
//!   last row), column ⌊θ + 180.5⌋ with θ = atan2(y, x) in degrees (clamped to 359, so the
//!   half degree before +180° joins column 359, not 0, as in the reference). Each pixel is a
//!   byte of 8 height bits: a point sets bit ⌈z + `height_offset`⌉ clamped to 0–7 (the
//!   reference's +5 m, made for KITTI's HDL-64E 1.73 m above the road: bit k covers heights
//!   (k − 6, k − 5] m above the sensor, the lowest and highest bits everything beyond).
//! * **The filter bank.** Each image row, as 360 values, is filtered by `scales` (4) 1-D
//!   log-Gabor filters in the frequency domain: `H(f) = exp(−ln²(f / f₀) / (2 ln² σ))` for the
//!   frequencies f = k / 360, k = 1 … 180, zero at k = 0 and above 180 (one-sided, so the output
//!   is complex), with f₀ = 1 / (`min_wavelength` · `mult`ˢ) (18 · 1.6ˢ) and σ = `sigma_on_f`
//!   (0.75). The inverse transform is unnormalised, as OpenCV's `idft` without `DFT_SCALE`.
//! * **Template and mask.** Per scale, a template bit is set where the real part is positive
//!   and another where the imaginary part is; the mask is set where the magnitude is below
//!   10⁻⁴. The template is 2 · `scales` planes of 80 × 360 bits (the real parts of every scale,
//!   then the imaginary parts, the reference's `vconcat` order); the mask `scales` planes (the
//!   reference stores each twice, for the real and the imaginary plane).
//! * **The descriptor,** one byte per value (stored bit-packed, as `uint8`, in the index): the
//!   image (28,800 bytes), then the template and the mask packed eight columns to a byte, the
//!   first column in the highest bit (as `numpy.packbits`): 28,800 and 14,400 bytes at 4 scales.
//! * **The distance.** Phase correlation of the two images (the normalised cross-power
//!   spectrum of their 2-D Fourier transforms, transformed back) gives the column shift `s` of
//!   the query against the candidate at its peak; the distance is the least masked Hamming
//!   distance over the shifts `s − 2 … s + 2`: the template bits that differ, over the bits
//!   that neither mask covers, the candidate's template and mask turned by the shift. With
//!   `reverse` (the reference's match mode 2) the query turned by 180° is matched the same way,
//!   and the better of the two counts (the turned one on a tie, as the reference). Its peak is
//!   the forward peak moved by 180 columns (turning multiplies the spectrum's column
//!   frequency k by (−1)ᵏ, which rolls the correlation surface), so it is not computed again.
//!   The yaw of
//!   the query against the candidate is the shift, one degree a column.
//!
//! Where toporec departs from the reference code:
//! * The reference computes in float32 (OpenCV `Mat1f`); toporec in float64.
//! * A template bit is set where its part exceeds 10⁻⁶ rather than 0. Where the exact part is
//!   zero (the imaginary part at the centre of a row's symmetric stretch, a lone pixel's for
//!   one) the reference reads the sign of rounding noise, which differs from one FFT library to
//!   another; the margin makes the template a function of the image. Below the mask's 10⁻⁴
//!   magnitude no unmasked bit is affected.
//! * The reference's `FFTMatch` is a log-polar Fourier–Mellin matcher: it first estimates a
//!   rotation and a scale of the image plane, warps the candidate by them, then phase-correlates
//!   and truncates the sub-pixel peak towards zero. The paper describes the phase correlation
//!   alone, which is what a yaw is in this image (a column shift); toporec does that and takes
//!   the integer peak (the first in row-major order on a tie). The ±2 shifts around it cover a
//!   peak one column off.
//! * When no bit is comparable (both masks cover everything: two empty scans) the reference's
//!   distance is NaN; toporec's is 1.
//! * The reference matches pairs. For search, the candidates are the `candidates` (10, the
//!   count third-party wrappers use) rows whose **row key** lies nearest the query's
//!   (Euclidean, float32): the number of height bits set in each image row, 80 values that do
//!   not depend on the yaw. The candidates are re-ranked by the distance above; an exhaustive
//!   budget re-ranks every row.

use super::Computed;
use super::searcher::{Allowed, Hit, SearchBudget, SearchTimes, timed};
use crate::types::Point;
use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// The method's name.
pub(crate) const NAME: &str = "lidar-iris";

/// Image rows: 1 m range bins to 80 m.
pub const ROWS: usize = 80;
/// Image columns: 1° azimuth bins.
pub const COLUMNS: usize = 360;
/// Bytes of a bit-packed image row.
const ROW_BYTES: usize = COLUMNS / 8;
/// u64 words of a row of bits.
const WORDS: usize = COLUMNS.div_ceil(64);
/// The bits of the last word of a row that belong to it.
const LAST_WORD_BITS: u64 = (1u64 << (COLUMNS - 64 * (WORDS - 1))) - 1;
/// A template bit is set where its part of the filter output exceeds this.
pub(crate) const SIGN_MARGIN: f64 = 1e-6;
/// A mask bit is set where the filter output's magnitude is below this.
pub(crate) const MASK_BELOW: f64 = 1e-4;

/// LiDAR-Iris settings (`[lidar-iris]` of a pipeline file); the defaults are the reference's.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IrisParams {
    /// log-Gabor scales (the reference's `nscale`).
    pub scales: usize,
    /// Wavelength of the first scale, in columns (`minWaveLength`).
    pub min_wavelength: f64,
    /// Ratio of one scale's wavelength to the previous one's (`mult`).
    pub mult: f64,
    /// Bandwidth: the filters' σ over their centre frequency (`sigmaOnf`), in (0, 1).
    pub sigma_on_f: f64,
    /// Height added to z before its bit is taken (m): 5 in the reference, made for a sensor
    /// 1.73 m above the road (KITTI). For a sensor mounted h m up, 3.27 + h keeps the bits at
    /// the same heights above the road.
    pub height_offset: f64,
    /// Row-key candidates re-ranked by the distance.
    pub candidates: usize,
    /// Also match the query turned by 180° (the reference's match mode 2).
    pub reverse: bool,
}

impl Default for IrisParams {
    fn default() -> Self {
        IrisParams {
            scales: 4,
            min_wavelength: 18.0,
            mult: 1.6,
            sigma_on_f: 0.75,
            height_offset: 5.0,
            candidates: 10,
            reverse: true,
        }
    }
}

impl IrisParams {
    /// Template bytes: 2 · scales planes of packed rows.
    fn template_bytes(&self) -> usize {
        2 * self.scales * ROWS * ROW_BYTES
    }

    /// Mask bytes: scales planes of packed rows.
    fn mask_bytes(&self) -> usize {
        self.scales * ROWS * ROW_BYTES
    }
}

/// The LiDAR-Iris image: `ROWS × COLUMNS` bytes of height bits, row-major. Points with a
/// non-finite coordinate are skipped.
pub fn image(points: &[Point], p: &IrisParams) -> Vec<u8> {
    let mut img = vec![0u8; ROWS * COLUMNS];
    for q in points.iter().filter(|q| q.iter().all(|v| v.is_finite())) {
        let range = (q[0] * q[0] + q[1] * q[1]).sqrt();
        let yaw = q[1].atan2(q[0]).to_degrees() + 180.0;
        let row = clamp(range.floor(), ROWS - 1);
        let bit = clamp((q[2] + p.height_offset).ceil(), 7);
        let column = clamp((yaw + 0.5).floor(), COLUMNS - 1);
        img[row * COLUMNS + column] |= 1 << bit;
    }
    img
}

/// `v` (an integer value) clamped into `0..=hi`.
fn clamp(v: f64, hi: usize) -> usize {
    if v <= 0.0 { 0 } else { (v as usize).min(hi) }
}

/// The filters and transforms LiDAR-Iris needs, planned once.
struct Bank {
    /// One-sided log-Gabor filters, `COLUMNS` values each.
    filters: Vec<Vec<f64>>,
    row_forward: Arc<dyn Fft<f64>>,
    row_inverse: Arc<dyn Fft<f64>>,
    column_forward: Arc<dyn Fft<f64>>,
    column_inverse: Arc<dyn Fft<f64>>,
}

impl Bank {
    fn new(p: &IrisParams) -> Self {
        let mut planner = FftPlanner::new();
        let half = COLUMNS / 2;
        let mut wavelength = p.min_wavelength;
        let mut filters = Vec::with_capacity(p.scales);
        let spread = 2.0 * (p.sigma_on_f.ln() * p.sigma_on_f.ln());
        for _ in 0..p.scales {
            let centre = 1.0 / wavelength;
            let mut h = vec![0.0; COLUMNS];
            for (k, v) in h.iter_mut().enumerate().take(half + 1).skip(1) {
                let l = (k as f64 / COLUMNS as f64 / centre).ln();
                *v = (-(l * l) / spread).exp();
            }
            filters.push(h);
            wavelength *= p.mult;
        }
        Bank {
            filters,
            row_forward: planner.plan_fft_forward(COLUMNS),
            row_inverse: planner.plan_fft_inverse(COLUMNS),
            column_forward: planner.plan_fft_forward(ROWS),
            column_inverse: planner.plan_fft_inverse(ROWS),
        }
    }

    /// The template and the mask of `img`, bit-packed (see the module doc).
    fn encode(&self, img: &[u8], p: &IrisParams) -> (Vec<u8>, Vec<u8>) {
        let mut template = vec![0u8; p.template_bytes()];
        let mut mask = vec![0u8; p.mask_bytes()];
        let plane = ROWS * ROW_BYTES;
        let mut spectrum = vec![Complex64::default(); COLUMNS];
        let mut out = vec![Complex64::default(); COLUMNS];
        let mut scratch = self.scratch();
        for row in 0..ROWS {
            let pixels = &img[row * COLUMNS..(row + 1) * COLUMNS];
            let at = row * ROW_BYTES;
            if pixels.iter().all(|&v| v == 0) {
                // The filters' output is exactly zero: no template bit, every mask bit.
                for s in 0..p.scales {
                    mask[s * plane + at..s * plane + at + ROW_BYTES].fill(0xff);
                }
                continue;
            }
            for (c, &v) in spectrum.iter_mut().zip(pixels) {
                *c = Complex64::new(v as f64, 0.0);
            }
            self.row_forward.process_with_scratch(&mut spectrum, &mut scratch);
            for (s, h) in self.filters.iter().enumerate() {
                for ((o, x), &g) in out.iter_mut().zip(&spectrum).zip(h) {
                    *o = x * g;
                }
                self.row_inverse.process_with_scratch(&mut out, &mut scratch);
                for (c, y) in out.iter().enumerate() {
                    let bit = 0x80u8 >> (c % 8);
                    let byte = at + c / 8;
                    if y.re > SIGN_MARGIN {
                        template[s * plane + byte] |= bit;
                    }
                    if y.im > SIGN_MARGIN {
                        template[(p.scales + s) * plane + byte] |= bit;
                    }
                    // |y| < MASK_BELOW, without hypot's cost (most of the encoding's time).
                    if y.norm_sqr() < MASK_BELOW * MASK_BELOW {
                        mask[s * plane + byte] |= bit;
                    }
                }
            }
        }
        (template, mask)
    }

    /// The 2-D Fourier transform of an image, transposed: column frequency by row frequency
    /// (`COLUMNS × ROWS`), as [`Bank::correlation_shift`] takes it.
    fn spectrum(&self, img: &[u8]) -> Vec<Complex64> {
        let mut f: Vec<Complex64> = img.iter().map(|&v| Complex64::new(v as f64, 0.0)).collect();
        let mut scratch = self.scratch();
        // Every row's transform in one call, then every column's, contiguous once transposed.
        self.row_forward.process_with_scratch(&mut f, &mut scratch);
        let mut t = transposed(&f, ROWS, COLUMNS);
        self.column_forward.process_with_scratch(&mut t, &mut scratch);
        t
    }

    /// Scratch space for any of the bank's transforms.
    fn scratch(&self) -> Vec<Complex64> {
        let len = [&self.row_forward, &self.row_inverse, &self.column_forward, &self.column_inverse]
            .iter()
            .map(|f| f.get_inplace_scratch_len())
            .max()
            .unwrap_or(0);
        vec![Complex64::default(); len]
    }

    /// The column shift at the peak of the phase correlation of `query` against `candidate`
    /// (their transposed spectra, [`Bank::spectrum`]), in (−180, 180].
    fn correlation_shift(&self, query: &[Complex64], candidate: &[Complex64]) -> i64 {
        let mut r: Vec<Complex64> = query
            .iter()
            .zip(candidate)
            .map(|(q, c)| {
                let x = q * c.conj();
                let m = x.norm_sqr().sqrt();
                if m > 0.0 { x / m } else { Complex64::default() }
            })
            .collect();
        let mut scratch = self.scratch();
        self.column_inverse.process_with_scratch(&mut r, &mut scratch);
        let mut surface = transposed(&r, COLUMNS, ROWS);
        self.row_inverse.process_with_scratch(&mut surface, &mut scratch);
        let mut best = (f64::NEG_INFINITY, 0usize);
        for (i, v) in surface.iter().enumerate() {
            if v.re > best.0 {
                best = (v.re, i);
            }
        }
        let c = (best.1 % COLUMNS) as i64;
        if c > (COLUMNS / 2) as i64 { c - COLUMNS as i64 } else { c }
    }
}

/// The `columns × rows` transpose of a row-major `rows × columns` matrix.
fn transposed(m: &[Complex64], rows: usize, columns: usize) -> Vec<Complex64> {
    let mut t = vec![Complex64::default(); m.len()];
    for (r, row) in m.chunks_exact(columns).enumerate() {
        for (c, v) in row.iter().enumerate() {
            t[c * rows + r] = *v;
        }
    }
    t
}

/// The LiDAR-Iris descriptor of a raw scan (see the module doc), one byte per value.
pub fn describe(points: &[Point], p: &IrisParams) -> Vec<f32> {
    let img = image(points, p);
    let (template, mask) = Bank::new(p).encode(&img, p);
    img.iter().chain(&template).chain(&mask).map(|&v| v as f32).collect()
}

/// The row key: the height bits set in each image row (80 values, independent of the yaw).
pub fn row_key(descriptor: &[f32]) -> Vec<f32> {
    descriptor[..ROWS * COLUMNS]
        .chunks_exact(COLUMNS)
        .map(|row| row.iter().map(|&v| (v as u8).count_ones()).sum::<u32>() as f32)
        .collect()
}

/// Packed rows (`ROW_BYTES` bytes, first column in the highest bit) as rows of `WORDS` u64
/// words, column c at bit c % 64 of word c / 64.
fn words(packed: &[f32]) -> Vec<u64> {
    let mut out = vec![0u64; packed.len() / ROW_BYTES * WORDS];
    for (row, bytes) in packed.chunks_exact(ROW_BYTES).enumerate() {
        for (b, &v) in bytes.iter().enumerate() {
            let v = v as u8;
            for bit in 0..8 {
                if v & (0x80 >> bit) != 0 {
                    let c = b * 8 + bit;
                    out[row * WORDS + c / 64] |= 1 << (c % 64);
                }
            }
        }
    }
    out
}

/// Rows of bits (as [`words`]) written twice over, `2 · WORDS` words a row, so that any
/// circular turn of a row is a window of it.
fn doubled(rows: &[u64]) -> Vec<u64> {
    let mut out = vec![0u64; rows.len() * 2];
    // The second copy starts at bit COLUMNS: word `whole`, bit `part`.
    let (whole, part) = (COLUMNS / 64, COLUMNS % 64);
    for (w, d) in rows.chunks_exact(WORDS).zip(out.chunks_exact_mut(2 * WORDS)) {
        d[..WORDS].copy_from_slice(w);
        for (i, &v) in w.iter().enumerate() {
            d[whole + i] |= v << part;
            if part > 0 && whole + i + 1 < 2 * WORDS {
                d[whole + i + 1] |= v >> (64 - part);
            }
        }
    }
    out
}

/// Word `i` of the row whose column c is column (c + `offset`) mod 360 of the doubled row `d`.
#[inline(always)]
fn window(d: &[u64], offset: usize, i: usize) -> u64 {
    let (w, o) = (offset / 64 + i, offset % 64);
    let v = if o == 0 { d[w] } else { (d[w] >> o) | (d[w + 1] << (64 - o)) };
    if i == WORDS - 1 { v & LAST_WORD_BITS } else { v }
}

/// A stored entry, ready to be compared.
struct Entry {
    image: Vec<u8>,
    template: Vec<u64>,
    mask: Vec<u64>,
}

impl Entry {
    fn new(descriptor: &[f32], p: &IrisParams) -> Self {
        let (img, rest) = descriptor.split_at(ROWS * COLUMNS);
        let (template, mask) = rest.split_at(p.template_bytes());
        Entry { image: img.iter().map(|&v| v as u8).collect(), template: words(template), mask: words(mask) }
    }
}

/// A query, ready to be compared with entries.
struct Query {
    spectrum: Vec<Complex64>,
    template: Vec<u64>,
    mask: Vec<u64>,
}

impl Query {
    fn new(descriptor: &[f32], p: &IrisParams, bank: &Bank) -> Self {
        let e = Entry::new(descriptor, p);
        Query { spectrum: bank.spectrum(&e.image), template: doubled(&e.template), mask: doubled(&e.mask) }
    }
}

/// The best (distance, shift) over the shifts `centre − 2 … centre + 2` of the candidate against
/// the query (the first on a tie); `turn` is the query's own turn (0 or 180 columns).
fn hamming(c: &Entry, q: &Query, centre: i64, turn: i64, p: &IrisParams) -> (f64, i64) {
    let plane = ROWS * WORDS;
    let mut best: Option<(f64, i64)> = None;
    for shift in centre - 2..=centre + 2 {
        // The candidate turned by `shift` against the query turned by `turn` counts the same
        // bits as the candidate against the query turned by `turn − shift`: the query's window
        // at offset (shift − turn) mod 360.
        let offset = (shift - turn).rem_euclid(COLUMNS as i64) as usize;
        let (mut differ, mut masked) = (0u64, 0u64);
        for s in 0..p.scales {
            for row in 0..ROWS {
                let m_at = s * plane + row * WORDS;
                let dm = (s * ROWS + row) * 2 * WORDS;
                for i in 0..WORDS {
                    let mask = c.mask[m_at + i] | window(&q.mask[dm..], offset, i);
                    masked += mask.count_ones() as u64;
                    for part in [s, p.scales + s] {
                        let t_at = part * plane + row * WORDS;
                        let dt = (part * ROWS + row) * 2 * WORDS;
                        let t = c.template[t_at + i] ^ window(&q.template[dt..], offset, i);
                        differ += (t & !mask).count_ones() as u64;
                    }
                }
            }
        }
        let total = (2 * p.scales * ROWS * COLUMNS) as u64 - 2 * masked;
        let d = if total == 0 { 1.0 } else { differ as f64 / total as f64 };
        if best.is_none_or(|b| d < b.0) {
            best = Some((d, shift));
        }
    }
    best.expect("five shifts")
}

/// The result of comparing a query with a candidate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Match {
    /// The masked Hamming distance, in [0, 1].
    pub distance: f64,
    /// The yaw of the query relative to the candidate (degrees, [0, 360)).
    pub yaw_degrees: f64,
    /// Whether the query turned by 180° matched better (`reverse`).
    pub reversed: bool,
}

fn compare_prepared(c: &Entry, q: &Query, p: &IrisParams, bank: &Bank) -> Match {
    let spectrum = bank.spectrum(&c.image);
    let peak = bank.correlation_shift(&q.spectrum, &spectrum);
    let forward = hamming(c, q, peak, 0, p);
    let yaw = |shift: i64| shift.rem_euclid(COLUMNS as i64) as f64;
    if p.reverse {
        // Turning the query by 180 columns multiplies its column frequency k by (−1)^k, which
        // rolls the correlation surface by 180 columns: the turned query's peak is the forward
        // one moved by 180 (the reference transforms again; the cross-check test compares).
        let half = COLUMNS as i64 / 2;
        let turned_peak = if peak > 0 { peak - half } else { peak + half };
        let turned = hamming(c, q, turned_peak, half, p);
        if turned.0 <= forward.0 {
            // The turned one on a tie, as the reference (`dis1 < dis2` keeps the forward one).
            return Match { distance: turned.0, yaw_degrees: yaw(turned.1 + half), reversed: true };
        }
    }
    Match { distance: forward.0, yaw_degrees: yaw(forward.1), reversed: false }
}

/// The LiDAR-Iris distance and yaw of a query descriptor against a candidate's.
pub fn compare(query: &[f32], candidate: &[f32], p: &IrisParams) -> Match {
    let bank = Bank::new(p);
    compare_prepared(&Entry::new(candidate, p), &Query::new(query, p, &bank), p, &bank)
}

/// LiDAR-Iris descriptors searched by row key, then re-ranked by [`compare`]'s distance.
/// It grows by [`super::Searcher::push`].
pub struct Searcher {
    params: IrisParams,
    bank: Bank,
    entries: Vec<Entry>,
    /// Row keys, `ROWS` values each.
    keys: Vec<f32>,
}

impl Searcher {
    /// A searcher over `descriptors` (row-major, `params.len()` a row).
    pub fn new(descriptors: Vec<f32>, params: IrisParams) -> Self {
        let mut s = Searcher { bank: Bank::new(&params), params, entries: Vec::new(), keys: Vec::new() };
        for d in descriptors.chunks_exact(s.params.len()) {
            super::Searcher::push(&mut s, d);
        }
        s
    }

    /// The settings.
    pub fn params(&self) -> &IrisParams {
        &self.params
    }

    /// The `k` best rows for `query` (among those `allowed` admits), by (distance, row).
    pub fn ranked(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> Vec<Hit> {
        if k == 0 {
            return Vec::new();
        }
        let wanted = self.params.candidates.max(k);
        let key = row_key(query);
        let mut by_key: Vec<(usize, f32)> = self
            .keys
            .chunks_exact(ROWS)
            .enumerate()
            .filter(|(r, _)| allowed.is_none_or(|a| a(*r)))
            .map(|(r, row)| (r, row.iter().zip(&key).map(|(a, b)| (a - b) * (a - b)).sum::<f32>()))
            .collect();
        let order = |a: &(usize, f32), b: &(usize, f32)| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0));
        if by_key.len() > wanted {
            by_key.select_nth_unstable_by(wanted - 1, order);
            by_key.truncate(wanted);
        }
        let q = Query::new(query, &self.params, &self.bank);
        let mut hits: Vec<(usize, Match)> = by_key
            .into_iter()
            .map(|(r, _)| (r, compare_prepared(&self.entries[r], &q, &self.params, &self.bank)))
            .collect();
        hits.sort_by(|a, b| a.1.distance.total_cmp(&b.1.distance).then(a.0.cmp(&b.0)));
        hits.truncate(k);
        hits.into_iter().map(|(r, m)| Hit::turned(r, m.distance, m.yaw_degrees)).collect()
    }
}

impl super::Searcher for Searcher {
    /// Rows.
    fn len(&self) -> usize {
        self.entries.len()
    }

    /// One more row.
    fn push(&mut self, descriptor: &[f32]) {
        self.keys.extend(row_key(descriptor));
        self.entries.push(Entry::new(descriptor, &self.params));
    }

    fn search(&self, query: &[f32], k: usize, allowed: Allowed<'_>) -> (Vec<Hit>, SearchTimes) {
        timed(|| self.ranked(query, k, allowed))
    }

    /// The shifts are always the five around the phase correlation's peak.
    fn set_budget(&mut self, budget: SearchBudget, entries: usize) {
        if let Some(n) = budget.candidates(entries) {
            self.params.candidates = n;
        }
    }
}

impl super::Named for IrisParams {
    const NAME: &'static str = NAME;
}

impl super::Computed for IrisParams {
    /// The settings' problems, each with its key.
    fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if !(1..=16).contains(&self.scales) {
            out.push(format!("lidar-iris.scales: must be in [1, 16]; found {}", self.scales));
        }
        if !(self.min_wavelength.is_finite() && self.min_wavelength >= 2.0) {
            out.push(format!(
                "lidar-iris.min_wavelength: must be at least 2 columns; found {}",
                self.min_wavelength
            ));
        }
        if !(self.mult.is_finite() && self.mult > 0.0) {
            out.push(format!("lidar-iris.mult: must be in (0, inf); found {}", self.mult));
        }
        if !(self.sigma_on_f > 0.0 && self.sigma_on_f < 1.0) {
            out.push(format!("lidar-iris.sigma_on_f: must be in (0, 1); found {}", self.sigma_on_f));
        }
        if !self.height_offset.is_finite() {
            out.push(format!("lidar-iris.height_offset: must be finite; found {}", self.height_offset));
        }
        if self.candidates == 0 {
            out.push("lidar-iris.candidates: must be at least 1; found 0".into());
        }
        out
    }

    /// Descriptor length (bytes): the image, the template and the mask.
    fn len(&self) -> usize {
        ROWS * COLUMNS + self.template_bytes() + self.mask_bytes()
    }

    /// Its image, then its template and mask bit-packed: bytes.
    fn stores_bytes(&self) -> bool {
        true
    }

    fn describe(&self, points: &[Point]) -> Result<Vec<f32>, String> {
        Ok(describe(points, self))
    }

    fn searcher(&self, descriptors: Vec<f32>) -> Box<dyn super::Searcher> {
        Box::new(Searcher::new(descriptors, self.clone()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_window_of_the_doubled_row_is_the_row_turned() {
        let mut rng = crate::rng::SplitMix64(7);
        let bits: Vec<bool> = (0..COLUMNS).map(|_| rng.next_f64() < 0.5).collect();
        let mut row = vec![0u64; WORDS];
        for (c, &b) in bits.iter().enumerate() {
            if b {
                row[c / 64] |= 1 << (c % 64);
            }
        }
        let d = doubled(&row);
        for offset in [0, 1, 63, 64, 65, 180, 300, 359] {
            for c in 0..COLUMNS {
                let got = window(&d, offset, c / 64) >> (c % 64) & 1 == 1;
                assert_eq!(got, bits[(c + offset) % COLUMNS], "offset {offset}, column {c}");
            }
            assert_eq!(window(&d, offset, WORDS - 1) & !LAST_WORD_BITS, 0);
        }
    }

    #[test]
    fn packed_bytes_read_first_column_highest() {
        let mut packed = vec![0.0f32; ROW_BYTES];
        packed[0] = 0x80 as f32; // column 0
        packed[44] = 0x01 as f32; // column 359
        let w = words(&packed);
        assert_eq!(w[0], 1);
        assert_eq!(w[5], 1 << (359 - 320));
    }
}
