//! The distance of two descriptors: columns compared by mean cosine at every sector shift and
//! sub-sector turn of the query, with an AVX2 build of the same integer sums.

use super::{CHANNELS, LEVELS, PlusParams};

/// A descriptor's codes as bytes, column by column: `[sector][channel][ring]`.
pub(super) fn columns_of(descriptor: &[f32], p: &PlusParams, out: &mut [u8]) {
    let (rings, sectors, height) = (p.rings, p.sectors, p.height());
    for ch in 0..CHANNELS {
        for r in 0..rings {
            let row = &descriptor[(ch * rings + r) * sectors..(ch * rings + r + 1) * sectors];
            for (s, &v) in row.iter().enumerate() {
                out[s * height + ch * rings + r] = v.clamp(0.0, LEVELS as f32) as u8;
            }
        }
    }
}

/// The rings of a descriptor out to the outermost one holding a code.
pub(super) fn reach(descriptor: &[f32], p: &PlusParams) -> usize {
    let (rings, sectors) = (p.rings, p.sectors);
    (0..rings)
        .rev()
        .find(|&r| {
            (0..CHANNELS).any(|ch| {
                let row = (ch * rings + r) * sectors;
                descriptor[row..row + sectors].iter().any(|v| *v != 0.0)
            })
        })
        .map_or(0, |r| r + 1)
}

/// A query made ready for matching: its columns turned by `t/turns` of a sector for each t
/// (`[turn][sector][channel][ring]`, interpolated between neighbouring sectors and scaled by
/// `turns`: exact integers), and its reach.
pub(super) struct Query {
    turned: Vec<i16>,
    reach: usize,
}

impl Query {
    pub(super) fn new(descriptor: &[f32], p: &PlusParams) -> Self {
        let (sectors, height, turns) = (p.sectors, p.height(), p.turns);
        let mut columns = vec![0u8; sectors * height];
        columns_of(descriptor, p, &mut columns);
        let mut turned = vec![0i16; turns * sectors * height];
        for t in 0..turns {
            let block = &mut turned[t * sectors * height..(t + 1) * sectors * height];
            for s in 0..sectors {
                let (a, b) =
                    (&columns[s * height..(s + 1) * height], &columns[((s + 1) % sectors) * height..]);
                for (h, o) in block[s * height..(s + 1) * height].iter_mut().enumerate() {
                    *o = ((turns - t) * a[h] as usize + t * b[h] as usize) as i16;
                }
            }
        }
        Query { turned, reach: reach(descriptor, p) }
    }
}

/// One database entry's columns (`[sector][channel][ring]` codes) and reach.
#[derive(Clone, Copy)]
pub(super) struct Entry<'a> {
    pub(super) columns: &'a [u8],
    pub(super) reach: usize,
}

/// The dot product of two column parts, exact (codes below 2^12, at most 200 of them).
#[inline(always)]
pub(super) fn dot(a: &[i16], b: &[i16]) -> i32 {
    a.iter().zip(b).map(|(&x, &y)| x as i32 * y as i32).sum()
}

/// Per column part (`[sector][channel]`), `1/‖part‖` over the first `reach` rings, 0 for an
/// empty part.
pub(super) fn inverse_norms(columns: &[i16], p: &PlusParams, reach: usize) -> Vec<f64> {
    columns
        .chunks_exact(p.rings)
        .map(|part| {
            let n = dot(&part[..reach], &part[..reach]);
            if n > 0 { 1.0 / (n as f64).sqrt() } else { 0.0 }
        })
        .collect()
}

/// The distance of a ready query to an entry, in [0, 1], and the yaw of the query relative to
/// it (degrees, [0, 360), counter-clockwise seen from above). Every shift of the unturned
/// query is compared on the relief columns; then, for every turn, the shifts within the
/// search radius of the best one, on both channels (every shift and turn when the radius
/// covers the sectors). Per channel, `1 −` the mean cosine of the columns filled in both over
/// the first `reach` rings, candidate column `b` against query column `(b + shift) mod
/// sectors` (1 for a channel with none filled in both); the channels averaged. The dot
/// products are exact integers: the AVX2 build computes the same sums.
pub(super) fn distance_to(q: &Query, c: Entry<'_>, p: &PlusParams) -> (f64, f64) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { distance_to_avx2(q, c, p) };
    }
    distance_to_portable(q, c, p)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) fn distance_to_avx2(q: &Query, c: Entry<'_>, p: &PlusParams) -> (f64, f64) {
    distance_to_portable(q, c, p)
}

#[inline(always)]
pub(super) fn distance_to_portable(q: &Query, c: Entry<'_>, p: &PlusParams) -> (f64, f64) {
    let (rings, sectors, height) = (p.rings, p.sectors, p.height());
    let block = sectors * height;
    // Compared where both reach; the outermost ring of a cut scan is half empty (shared with
    // the ring beyond): left out.
    let reach = q.reach.min(c.reach).max(1);
    let reach = if reach < rings { (reach - 1).max(1) } else { reach };
    let candidate: Vec<i16> = c.columns.iter().map(|&v| v as i16).collect();
    let inverse_c = inverse_norms(&candidate, p, reach);
    let inverse_q: Vec<Vec<f64>> =
        (0..p.turns).map(|t| inverse_norms(&q.turned[t * block..(t + 1) * block], p, reach)).collect();
    // Per channel, the candidate's filled sectors: the only ones a sum can take.
    let filled: [Vec<usize>; CHANNELS] =
        std::array::from_fn(|ch| (0..sectors).filter(|&b| inverse_c[b * CHANNELS + ch] > 0.0).collect());
    // The sums are a function's, not a closure's: a closure is compiled on its own, without
    // `distance_to_avx2`'s features.
    let sides = |t: usize| Sides {
        query: &q.turned[t * block..(t + 1) * block],
        query_inverse: &inverse_q[t],
        candidate: &candidate,
        candidate_inverse: &inverse_c,
        filled: &filled,
    };
    let radius = (0.5 * p.search_ratio * sectors as f64).round() as usize;
    let shifts: Vec<usize> = if 2 * radius + 1 >= sectors {
        (0..sectors).collect()
    } else {
        let mut coarse = (f64::INFINITY, 0usize);
        for shift in 0..sectors {
            let d = mean_cosine_distance(sides(0), p, reach, shift, 1);
            if d < coarse.0 {
                coarse = (d, shift);
            }
        }
        let mut out: Vec<usize> =
            (0..=2 * radius).map(|i| (coarse.1 + sectors + i - radius) % sectors).collect();
        out.sort_unstable();
        out.dedup();
        out
    };
    let mut best = (f64::INFINITY, 0.0);
    for t in 0..p.turns {
        for &shift in &shifts {
            let d = mean_cosine_distance(sides(t), p, reach, shift, CHANNELS);
            if d < best.0 {
                let yaw = ((shift as f64 + t as f64 / p.turns as f64) * p.sector_degrees()).rem_euclid(360.0);
                best = (d, yaw);
            }
        }
    }
    (best.0.clamp(0.0, 1.0), best.1)
}

/// One query turn's columns and one candidate's, with their inverse norms
/// ([`inverse_norms`]) and the candidate's filled sectors per channel.
pub(super) struct Sides<'a> {
    query: &'a [i16],
    query_inverse: &'a [f64],
    candidate: &'a [i16],
    candidate_inverse: &'a [f64],
    filled: &'a [Vec<usize>; CHANNELS],
}

/// `1 −` the mean cosine per channel of the query's columns turned by `shift` sectors
/// against the candidate's, over the first `reach` rings, averaged over the first
/// `channels`: candidate column `b` against query column `(b + shift) mod sectors`, in the
/// order of `b`, where both are filled. A function, not a closure, so that it is compiled
/// inside [`distance_to_avx2`] with its features.
#[inline(always)]
pub(super) fn mean_cosine_distance(
    sides: Sides<'_>,
    p: &PlusParams,
    reach: usize,
    shift: usize,
    channels: usize,
) -> f64 {
    let (rings, sectors, height) = (p.rings, p.sectors, p.height());
    let mut total = 0.0;
    for ch in 0..channels {
        let (mut sum, mut count) = (0.0f64, 0usize);
        for &b in &sides.filled[ch] {
            let a = if b + shift >= sectors { b + shift - sectors } else { b + shift };
            let x = sides.query_inverse[a * CHANNELS + ch];
            if x > 0.0 {
                let y = sides.candidate_inverse[b * CHANNELS + ch];
                let qa = &sides.query[a * height + ch * rings..a * height + ch * rings + reach];
                let cb = &sides.candidate[b * height + ch * rings..b * height + ch * rings + reach];
                sum += dot(qa, cb) as f64 * x * y;
                count += 1;
            }
        }
        total += if count > 0 { 1.0 - sum / count as f64 } else { 1.0 };
    }
    total / channels as f64
}

/// The distance of `query` to `candidate` (both descriptors), in [0, 1] (1 when no column is
/// filled in both), and the yaw of the query relative to the candidate (degrees, [0, 360),
/// counter-clockwise seen from above) that attains it.
pub fn distance(query: &[f32], candidate: &[f32], p: &PlusParams) -> (f64, f64) {
    let mut columns = vec![0u8; p.polar_len()];
    columns_of(candidate, p, &mut columns);
    distance_to(&Query::new(query, p), Entry { columns: &columns, reach: reach(candidate, p) }, p)
}
