//! Helpers the benchmarks share (each bench uses some of them).
#![allow(dead_code)]

use rayon::prelude::*;
use std::time::Instant;

/// Median milliseconds of `reps` runs of `f`.
pub fn median_ms(reps: usize, mut f: impl FnMut()) -> f64 {
    median(
        (0..reps)
            .map(|_| {
                let s = Instant::now();
                f();
                s.elapsed().as_secs_f64() * 1e3
            })
            .collect(),
    )
}

/// The median of `v` (the upper one of an even count).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// `n` simulated HDL-64E scans (1° azimuth steps, as the evaluation's drives), in two sessions
/// of `n / 2`, 2 m apart, the second reversed.
pub fn simulated_scans(n: usize) -> Vec<Vec<toporec::homology::Point>> {
    use toporec::simulate::{
        Sensor, SensorModel, SimParams,
        scene::{Scene, TownParams},
    };
    let mut sensor = Sensor::new(SensorModel::Hdl64);
    sensor.azimuth_res = 1.0;
    let p = SimParams {
        town: TownParams { blocks: 5, block_size: 60.0, ..TownParams::default() },
        sensor,
        seed: 3,
        scans: Some(n / 2),
        rate: 5.0,
        reverse: true,
        ..SimParams::default()
    };
    (0..2)
        .flat_map(|session| {
            let scene = Scene::town(&p.town, p.seed, session as u64);
            (0..n / 2)
                .into_par_iter()
                .map_init(
                    || scene.mailbox(),
                    |mailbox, i| {
                        let s = toporec::simulate::scan(&p, &scene, session, i, mailbox);
                        s.points.iter().map(|q| q.map(|c| c as f64)).collect::<Vec<[f64; 3]>>()
                    },
                )
                .collect::<Vec<_>>()
        })
        .collect()
}

/// A synthetic database entry: `descriptor` (rows of `sectors` values, then any tail, which
/// stays in place) with its sectors turned
/// by a random shift, its values scaled by a random factor in [0.8, 1.2] and noised by ±5 %
/// (with `codes`, rounded into toporec-plus's byte codes 1..=255; empty cells stay empty).
pub fn turned_copy(
    descriptor: &[f32],
    sectors: usize,
    codes: bool,
    rng: &mut toporec::rng::SplitMix64,
) -> Vec<f32> {
    let shift = rng.below(sectors);
    let scale = 0.8 + 0.4 * rng.next_f64();
    let mut out = Vec::with_capacity(descriptor.len());
    let noised = |v: f32, rng: &mut toporec::rng::SplitMix64| {
        let v = v as f64;
        let w = v * scale * (1.0 + 0.1 * (rng.next_f64() - 0.5));
        match (v > 0.0, codes) {
            (false, _) => 0.0,
            (true, true) => w.round().clamp(1.0, 255.0) as f32,
            (true, false) => w as f32,
        }
    };
    let rows = descriptor.chunks_exact(sectors);
    // What follows the sector rows (toporec-plus's image), noised but not turned: a copy is as
    // long as its descriptor.
    let tail = rows.remainder();
    for row in rows {
        for s in 0..sectors {
            out.push(noised(row[(s + shift) % sectors], rng));
        }
    }
    for &v in tail {
        out.push(noised(v, rng));
    }
    debug_assert_eq!(out.len(), descriptor.len());
    out
}
