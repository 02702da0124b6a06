//! The keys a search narrows the entries with, independent of the yaw: the shape key, the
//! profile key and the ring key, and the first pass's bytes of each.

use super::distance::columns_of;
use super::{CHANNELS, HEIGHT_SCALE, LEVELS, PlusParams, RELIEF};

/// Terms of the shape key: the magnitudes of the first `SHAPE_TERMS` terms of the discrete
/// Fourier transform along the sectors.
pub(super) const SHAPE_TERMS: usize = 16;

/// The terms per ring of the shape key.
pub(super) fn shape_terms(p: &PlusParams) -> usize {
    SHAPE_TERMS.min(p.sectors / 2 + 1)
}

pub(super) fn shape_len(p: &PlusParams) -> usize {
    CHANNELS * p.rings * shape_terms(p)
}

pub(super) fn profile_len(p: &PlusParams) -> usize {
    2 * CHANNELS * p.rings
}

/// The shape key of a descriptor, independent of the yaw: for each channel and ring, which
/// sectors are filled (1 or 0), and of that, the magnitudes of the first [`SHAPE_TERMS`]
/// Fourier terms along the sectors (a circular shift changes their phases only); each channel
/// scaled to length `1/√2` (all zeros stay zeros). The first term is ScanContext's ring key
/// (the filled share of the ring); the others tell where along the ring the gaps are. Built
/// from what is filled, not from the values, it does not move when fewer returns change them.
pub(super) fn shape_key(descriptor: &[f32], p: &PlusParams) -> Vec<f32> {
    let (rings, sectors) = (p.rings, p.sectors);
    let terms = shape_terms(p);
    let twiddles: Vec<(f64, f64)> = (0..sectors)
        .map(|m| {
            let angle = std::f64::consts::TAU * m as f64 / sectors as f64;
            (angle.cos(), angle.sin())
        })
        .collect();
    let mut out = Vec::with_capacity(shape_len(p));
    for channel in 0..CHANNELS {
        let rows = &descriptor[channel * rings * sectors..(channel + 1) * rings * sectors];
        let mut half = Vec::with_capacity(rings * terms);
        for row in rows.chunks_exact(sectors) {
            for k in 0..terms {
                let (mut re, mut im) = (0.0f64, 0.0f64);
                for (j, _) in row.iter().enumerate().filter(|(_, v)| **v > 0.0) {
                    let (cos, sin) = twiddles[k * j % sectors];
                    re += cos;
                    im -= sin;
                }
                half.push(re.hypot(im));
            }
        }
        let norm = half.iter().map(|v| v * v).sum::<f64>().sqrt() * std::f64::consts::SQRT_2;
        out.extend(half.into_iter().map(|v| if norm > 0.0 { (v / norm) as f32 } else { 0.0 }));
    }
    out
}

/// The profile key of a descriptor, independent of the yaw: the mean and the standard
/// deviation, code by code, of its unit columns (both channels of a sector, each channel's part
/// of unit length scaled by `1/√2`) over the filled sectors — what a sector of this place
/// looks like, whichever sectors are seen. A quarter of the view hidden leaves it nearly as it
/// was, where it moves every term of the shape key.
pub(super) fn profile_key(descriptor: &[f32], p: &PlusParams) -> Vec<f32> {
    let (rings, sectors, height) = (p.rings, p.sectors, p.height());
    let mut columns = vec![0u8; p.polar_len()];
    columns_of(descriptor, p, &mut columns);
    let (mut mean, mut square) = (vec![0f64; height], vec![0f64; height]);
    let mut n = 0usize;
    let mut unit = vec![0f64; height];
    for column in columns.chunks_exact(height) {
        let mut any = false;
        for ch in 0..CHANNELS {
            let part = &column[ch * rings..(ch + 1) * rings];
            let norm = part.iter().map(|&v| (v as f64).powi(2)).sum::<f64>().sqrt();
            any |= norm > 0.0;
            for (u, &v) in unit[ch * rings..(ch + 1) * rings].iter_mut().zip(part) {
                *u = if norm > 0.0 { v as f64 / norm * std::f64::consts::FRAC_1_SQRT_2 } else { 0.0 };
            }
        }
        if any {
            n += 1;
            for ((m, s), &v) in mean.iter_mut().zip(&mut square).zip(&unit) {
                *m += v;
                *s += v * v;
            }
        }
    }
    let _ = sectors;
    let n = n.max(1) as f64;
    let spread = mean.iter().zip(&square).map(|(m, s)| (s / n - (m / n).powi(2)).max(0.0).sqrt());
    mean.iter().map(|m| m / n).chain(spread).map(|v| v as f32).collect()
}

/// The ring key of a descriptor, independent of the yaw: per ring, the mean height of its
/// cells (empty ones count 0) as a share of [`RING_KEY_SCALE`] (at most 1) — ScanContext's ring
/// key.
pub(super) fn ring_key(descriptor: &[f32], p: &PlusParams) -> Vec<f32> {
    let (rings, sectors) = (p.rings, p.sectors);
    let heights = &descriptor[(1 - RELIEF) * rings * sectors..(2 - RELIEF) * rings * sectors];
    heights
        .chunks_exact(sectors)
        .map(|row| {
            let sum: f64 = row.iter().map(|&c| (c as f64 / LEVELS).powi(2)).sum();
            (sum / sectors as f64 * HEIGHT_SCALE / RING_KEY_SCALE).min(1.0) as f32
        })
        .collect()
}

/// The mean height (m) of the largest ring key.
pub(super) const RING_KEY_SCALE: f64 = 16.0;
/// Key values in [0, 1] as bytes (`round(255 v)`): the narrowing of a search reads a quarter
/// of the memory, and its integer distances are exact and the same on every machine.
pub(super) fn quantized(values: &[f32]) -> Vec<u8> {
    values.iter().map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect()
}

/// Keys of the first pass, each `rings` bytes.
pub(super) const FIRSTS: usize = 3;

/// The first pass's keys of an entry, `rings` bytes each: its ring key, the filled shares per
/// ring of its relief channel (the shape key's terms of order 0), and the mean of its unit
/// relief columns (the profile key's first part).
pub(super) fn firsts(shape: &[u8], profile: &[u8], ring: &[u8], p: &PlusParams) -> Vec<u8> {
    let shares: Vec<u8> = shape[RELIEF * p.rings * shape_terms(p)..(RELIEF + 1) * p.rings * shape_terms(p)]
        .iter()
        .step_by(shape_terms(p))
        .copied()
        .collect();
    let means = &profile[RELIEF * p.rings..(RELIEF + 1) * p.rings];
    let mut out = vec![0u8; FIRSTS * first_width(p)];
    for (k, key) in [ring, &shares, means].into_iter().enumerate() {
        out[k * first_width(p)..k * first_width(p) + p.rings].copy_from_slice(key);
    }
    out
}

/// Bytes of each first-pass key: `rings`, zero-padded to a multiple of 8.
pub(super) fn first_width(p: &PlusParams) -> usize {
    p.rings.next_multiple_of(8)
}
