//! Insertion order for the Delaunay construction: a biased randomized insertion order (BRIO)
//! whose rounds are each sorted along a 3D Hilbert curve, so consecutive insertions are close
//! in space (short walks) while the rounds keep the randomized bound on conflict sizes.

use super::exact::Point;

/// Bits per axis of the Hilbert key (3 × 21 = 63 bits).
const BITS: u32 = 21;
/// Rounds smaller than this are merged into the next one.
const MIN_ROUND: usize = 64;

/// Returns the point indices in BRIO + Hilbert order. Deterministic for a given input.
pub(crate) fn brio_order(points: &[Point]) -> Vec<u32> {
    let n = points.len();
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let extent = (0..3).map(|k| hi[k] - lo[k]).fold(0.0f64, f64::max);
    let scale = if extent > 0.0 { ((1u64 << BITS) - 1) as f64 / extent } else { 0.0 };
    let keys: Vec<u64> = points
        .iter()
        .map(|p| {
            let q = [0, 1, 2].map(|k| ((p[k] - lo[k]) * scale) as u32);
            hilbert_key(q)
        })
        .collect();

    // Deterministic shuffle, then rounds of doubling size.
    let mut order: Vec<u32> = (0..n as u32).collect();
    let mut rng = crate::rng::SplitMix64(0x2545_F491_4F6C_DD1D);
    for i in (1..n).rev() {
        order.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
    }
    let mut end = n;
    let mut bounds = vec![n];
    while end > MIN_ROUND {
        end /= 2;
        bounds.push(end);
    }
    bounds.push(0);
    bounds.reverse();
    bounds.dedup();
    for w in bounds.windows(2) {
        order[w[0]..w[1]].sort_unstable_by_key(|&i| (keys[i as usize], i));
    }
    order
}

/// Hilbert index of a point with `BITS`-bit coordinates (Skilling's transpose algorithm).
/// Branch-free: the data-dependent branches of the textbook form mispredict about half the
/// time, which made this the slowest part of the ordering.
fn hilbert_key(mut x: [u32; 3]) -> u64 {
    let m = 1u32 << (BITS - 1);
    let mut q = m;
    while q > 1 {
        let p = q - 1;
        for i in 0..3 {
            // Bit set: invert the low bits of x[0]; else exchange them with x[i].
            let set = ((x[i] & q) != 0) as u32;
            let invert = p & set.wrapping_neg();
            let t = (x[0] ^ x[i]) & p & !invert;
            x[0] ^= invert | t;
            x[i] ^= t;
        }
        q >>= 1;
    }
    x[1] ^= x[0];
    x[2] ^= x[1];
    // t = XOR of (q - 1) over the set bits q > 1 of x[2]: a prefix XOR from the top bit down.
    let mut t = 0;
    let mut q = m;
    while q > 1 {
        t ^= (q - 1) & (((x[2] & q) != 0) as u32).wrapping_neg();
        q >>= 1;
    }
    for v in &mut x {
        *v ^= t;
    }
    spread3(x[0]) << 2 | spread3(x[1]) << 1 | spread3(x[2])
}

/// The 21 low bits of `v` spread to every third bit (bit b to bit 3b).
#[inline]
fn spread3(v: u32) -> u64 {
    let mut x = v as u64 & 0x1f_ffff;
    x = (x | x << 32) & 0x001f_0000_0000_ffff;
    x = (x | x << 16) & 0x001f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The textbook form of Skilling's algorithm: the oracle for the branch-free one.
    fn hilbert_key_textbook(mut x: [u32; 3]) -> u64 {
        let m = 1u32 << (BITS - 1);
        let mut q = m;
        while q > 1 {
            let p = q - 1;
            for i in 0..3 {
                if x[i] & q != 0 {
                    x[0] ^= p;
                } else {
                    let t = (x[0] ^ x[i]) & p;
                    x[0] ^= t;
                    x[i] ^= t;
                }
            }
            q >>= 1;
        }
        for i in 1..3 {
            x[i] ^= x[i - 1];
        }
        let mut t = 0;
        let mut q = m;
        while q > 1 {
            if x[2] & q != 0 {
                t ^= q - 1;
            }
            q >>= 1;
        }
        for v in &mut x {
            *v ^= t;
        }
        let mut key = 0u64;
        for b in (0..BITS).rev() {
            for v in &x {
                key = (key << 1) | ((v >> b) & 1) as u64;
            }
        }
        key
    }

    #[test]
    fn branch_free_keys_equal_the_textbook_algorithm() {
        let mut rng = crate::rng::SplitMix64(5);
        for k in 0..100_000u32 {
            let x = if k < 512 {
                [k & 7, k >> 3 & 7, k >> 6]
            } else {
                [0, 1, 2].map(|_| (rng.next_u64() >> 43) as u32)
            };
            assert_eq!(hilbert_key(x), hilbert_key_textbook(x), "{x:?}");
        }
    }

    #[test]
    fn hilbert_keys_are_a_continuous_bijection_on_grids_at_the_origin() {
        // A Hilbert curve starting at the origin visits the 2^k cube there first: its 8^k
        // cells get exactly the keys 0..8^k, and consecutive keys are face-adjacent cells.
        for k in 1..=4u32 {
            let side = 1u32 << k;
            let mut by_key = vec![None; 1 << (3 * k)];
            for x in 0..side {
                for y in 0..side {
                    for z in 0..side {
                        let key = hilbert_key([x, y, z]) as usize;
                        assert!(key < by_key.len(), "k {k}: key {key} of {:?} outside 0..8^k", [x, y, z]);
                        assert!(by_key[key].is_none(), "k {k}: key {key} given twice");
                        by_key[key] = Some([x, y, z]);
                    }
                }
            }
            for (i, w) in by_key.windows(2).enumerate() {
                let (a, b) = (w[0].expect("every key taken"), w[1].expect("every key taken"));
                let steps: u32 = (0..3).map(|j| a[j].abs_diff(b[j])).sum();
                assert_eq!(steps, 1, "k {k}: keys {i} and {} are cells {a:?} and {b:?}", i + 1);
            }
        }
    }

    #[test]
    fn order_is_a_permutation() {
        let pts: Vec<Point> =
            (0..1000).map(|i| [(i % 10) as f64, (i / 10 % 10) as f64, (i / 100) as f64]).collect();
        let mut o = brio_order(&pts);
        o.sort();
        assert_eq!(o, (0..1000).collect::<Vec<u32>>());
    }
}
