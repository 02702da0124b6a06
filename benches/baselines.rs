//! Baselines benchmark: ScanContext, Scan Context++ (polar and Cartesian), M2DP, SOLiD,
//! LiDAR-Iris, RING and RING++ (and toporec-plus, for the comparison) per scan (design goal: under 2 ms
//! each for a 4096-point scan), and their searches over 100,000 entries (design goal: under 5 ms
//! per query), one thread. LiDAR-Iris's entries take 75 KB each in its searcher and RING's
//! about 120 KB (the descriptor and its angle spectra), RING++'s about 1 MB, so their searches
//! run over 1,000 and 10,000 entries: LiDAR-Iris's row-key pass grows with the entries, the re-rank of its
//! candidates does not; RING and RING++ correlate every entry.
//!
//! Scans: the real KITTI scans of `../shared/data` when present (subsampled to 4096 points, and
//! whole), else simulated ones from `samples/`. The 100,000 database entries are ScanContexts
//! of those scans, each turned by a random yaw and shifted by up to 10 m, so ring keys and
//! columns look like real ones; SOLiD's are the scans' SOLiDs with their azimuth parts rolled by
//! a random shift, scaled by a random factor in [0.8, 1.2] and noised. Scan Context++'s polar
//! entries are three consecutive ScanContext entries (its three copies); its Cartesian ones are
//! the scans' Cartesian contexts moved sideways by a random number of columns and noised.
//! LiDAR-Iris's are the scans' own descriptors, repeated (the cost of its re-rank does not
//! depend on what the candidates hold).
//!
//! Run: `cargo bench --bench baselines` (`TOPOREC_BENCH_DESCRIBE_ONLY=1`: the per-scan table
//! alone).

mod common;

use common::median_ms;
use std::path::Path;
use std::time::Instant;
use toporec::homology::Point;
use toporec::methods::Computed as _;
use toporec::methods::Searcher as _;
use toporec::methods::lidar_iris::{self, IrisParams};
use toporec::methods::m2dp;
use toporec::methods::ring::{self, RingParams};
use toporec::methods::ring_plus::{self, RingPlusParams};
use toporec::methods::scancontext::{self, ScanContextParams, Searcher};
use toporec::methods::scancontext_pp::{self, CartParams, PolarParams, Variant};
use toporec::methods::solid::{self, SolidParams};
use toporec::rng::SplitMix64;

fn scans() -> (String, Vec<Vec<Point>>) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let kitti = root.join("../shared/data/kitti/sequences/00/velodyne");
    let (name, dir) = if kitti.is_dir() {
        ("KITTI 00", kitti)
    } else {
        ("simulated (samples/town)", root.join("samples/town/velodyne_data/2026-01-01/velodyne_sync"))
    };
    let mut files: Vec<_> =
        std::fs::read_dir(&dir).expect("scan folder").flatten().map(|e| e.path()).collect();
    files.sort();
    let clouds =
        files.iter().take(8).map(|f| toporec::sources::read_cloud(f, None).expect("a scan")).collect();
    (name.to_string(), clouds)
}

fn subsample(points: &[Point], n: usize, seed: u64) -> Vec<Point> {
    let mut rng = SplitMix64(seed);
    let mut p = points.to_vec();
    for i in 0..n.min(p.len()) {
        let j = i + rng.below(p.len() - i);
        p.swap(i, j);
    }
    p.truncate(n);
    p
}

/// Milliseconds of each search of each query, every query searched ten times; each search must
/// give 25 hits.
fn query_ms(queries: &[Vec<f32>], search: impl Fn(&[f32]) -> usize) -> Vec<f64> {
    let mut total = Vec::new();
    for _ in 0..10 {
        for q in queries {
            let t = Instant::now();
            let hits = search(q);
            total.push(t.elapsed().as_secs_f64() * 1e3);
            assert_eq!(hits, 25);
        }
    }
    total
}

fn main() {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    pool.install(|| {
        let (name, clouds) = scans();
        let p = ScanContextParams::default();
        let small: Vec<Vec<Point>> = clouds.iter().enumerate().map(|(i, c)| subsample(c, 4096, i as u64)).collect();
        println!("scans: {name}, {} of them; medians over 20 runs per scan, one thread", clouds.len());
        let per = |clouds: &[Vec<Point>], f: &dyn Fn(&[Point])| -> f64 {
            let ms: Vec<f64> = clouds.iter().map(|c| median_ms(20, || f(c))).collect();
            ms.iter().sum::<f64>() / ms.len() as f64
        };
        let voxel = |c: &[Point]| toporec::preprocess::voxel_grid(c, p.voxel);
        let mean_points = clouds.iter().map(|c| c.len()).sum::<usize>() / clouds.len();
        println!("| step | 4096 points | whole scan (mean {mean_points} points) |");
        println!("|---|---:|---:|");
        type Describe<'a> = &'a dyn Fn(&[Point]);
        let sp = SolidParams::default();
        let (pp, ppc) = (PolarParams::default(), CartParams::default());
        let ip = IrisParams::default();
        let plus = toporec::methods::toporec_plus::PlusParams::default();
        let rp = RingParams::default();
        let rpp = RingPlusParams::default();
        let rows: [(&str, Describe); 13] = [
            ("ScanContext descriptor", &|c| {
                std::hint::black_box(scancontext::describe(c, &p));
            }),
            ("ScanContext with its 0.5 m voxel grid", &|c| {
                std::hint::black_box(scancontext::describe(&voxel(c), &p));
            }),
            ("Scan Context++ polar, 3 copies, with its 0.5 m voxel grid", &|c| {
                std::hint::black_box(scancontext_pp::describe_polar(c, &pp));
            }),
            ("Scan Context++ Cartesian, with its 0.5 m voxel grid", &|c| {
                std::hint::black_box(scancontext_pp::describe_cart(c, &ppc));
            }),
            ("M2DP descriptor", &|c| {
                std::hint::black_box(m2dp::describe(c));
            }),
            ("M2DP with a 0.5 m voxel grid", &|c| {
                std::hint::black_box(m2dp::describe(&voxel(c)));
            }),
            ("SOLiD descriptor", &|c| {
                std::hint::black_box(solid::describe(c, &sp));
            }),
            ("SOLiD with its range filter and 0.4 m voxel grid", &|c| {
                std::hint::black_box(solid::describe(&solid::preprocess(c, &sp), &sp));
            }),
            ("LiDAR-Iris image, template and mask", &|c| {
                std::hint::black_box(lidar_iris::describe(c, &ip));
            }),
            ("RING grid, Radon sinogram and its FFT magnitudes", &|c| {
                std::hint::black_box(ring::describe(c, &rp));
            }),
            ("RING++ features, six grids, their sinograms and FFT magnitudes", &|c| {
                std::hint::black_box(ring_plus::describe(c, &rpp).ok());
            }),
            ("RING++ point features alone (scaled cloud, 30 neighbours, eigenvalues)", &|c| {
                std::hint::black_box(ring_plus::point_features(&ring_plus::scaled_cloud(c, &rpp), &rpp).ok());
            }),
            ("toporec-plus (its searches: `cargo bench --bench toporec_plus`)", &|c| {
                std::hint::black_box(toporec::methods::toporec_plus::describe(c, &plus).ok());
            }),
        ];
        for (label, f) in rows {
            println!("| {label} | {:.3} ms | {:.3} ms |", per(&small, f), per(&clouds, f));
        }
        if std::env::var_os("TOPOREC_BENCH_DESCRIBE_ONLY").is_some() {
            return;
        }

        // Search: 100,000 turned and shifted ScanContexts.
        let n = 100_000;
        let base: Vec<Vec<Point>> = clouds.iter().map(|c| voxel(c)).collect();
        let t = Instant::now();
        let mut rng = SplitMix64(7);
        let mut db = Vec::with_capacity(n * p.len());
        let mut solid_db = Vec::with_capacity(n * sp.len());
        for i in 0..n {
            let c = &base[i % base.len()];
            let (s, co) = (rng.next_f64() * std::f64::consts::TAU).sin_cos();
            let (dx, dy) = (rng.next_f64() * 20.0 - 10.0, rng.next_f64() * 20.0 - 10.0);
            let moved: Vec<Point> = c.iter().map(|q| [co * q[0] - s * q[1] + dx, s * q[0] + co * q[1] + dy, q[2]]).collect();
            db.extend(scancontext::describe(&moved, &p));
        }
        // SOLiD entries: each scan's descriptor with its azimuth part rolled by a random shift,
        // scaled by a random factor in [0.8, 1.2] and noised.
        let solid_base: Vec<Vec<f32>> =
            clouds.iter().map(|c| solid::describe(&solid::preprocess(c, &sp), &sp)).collect();
        for i in 0..n {
            let d = &solid_base[i % solid_base.len()];
            let shift = (rng.next_u64() % sp.sectors as u64) as usize;
            let scale = 0.8 + 0.4 * rng.next_f64();
            let mut noisy = |v: f32| (v as f64 * scale * (1.0 + 0.05 * (rng.next_f64() - 0.5))) as f32;
            let r: Vec<f32> = d[..sp.rings].iter().map(|&v| noisy(v)).collect();
            let a: Vec<f32> = (0..sp.sectors).map(|c| noisy(d[sp.rings + (c + shift) % sp.sectors])).collect();
            solid_db.extend(r);
            solid_db.extend(a);
        }
        let made = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let searcher = Searcher::new(db.clone(), p.clone());
        let build = t.elapsed().as_secs_f64();
        let queries: Vec<Vec<f32>> = base.iter().map(|c| scancontext::describe(c, &p)).collect();
        let (mut cand, mut rerank, mut total) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..10 {
            for q in &queries {
                let s = Instant::now();
                let (hits, times) = searcher.search(q, 25, None);
                total.push(s.elapsed().as_secs_f64() * 1e3);
                cand.push(times.candidates * 1e3);
                rerank.push(times.rerank * 1e3);
                assert_eq!(hits.len(), 25);
            }
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        println!(
            "ScanContext search, {n} entries (made in {made:.1} s, ring-key structure built in {build:.2} s), k = 25 ({} candidates): {:.3} ms per query (ring-key candidates {:.3} ms, re-rank {:.3} ms), mean of {} queries",
            p.candidates.max(25),
            mean(&total),
            mean(&cand),
            mean(&rerank),
            total.len()
        );
        // Scan Context++: polar entries of three ScanContexts each; Cartesian entries moved
        // sideways and noised.
        let len = p.len();
        let entry = |row: usize| &db[row % n * len..(row % n + 1) * len];
        let polar_db: Vec<f32> = (0..n).flat_map(|i| (0..3).flat_map(move |c| entry(i + c).to_vec())).collect();
        drop(db);
        let cart_base: Vec<Vec<f32>> = clouds.iter().map(|c| scancontext_pp::describe_cart(c, &ppc)).collect();
        let columns = ppc.columns();
        let mut cart_db = Vec::with_capacity(n * ppc.len());
        for i in 0..n {
            let d = &cart_base[i % cart_base.len()];
            let shift = (rng.next_u64() % columns as u64) as usize;
            for row in d.chunks_exact(columns) {
                for c in 0..columns {
                    let v = row[(c + shift) % columns];
                    cart_db.push(if v > 0.0 { v * (1.0 + 0.05 * (rng.next_f64() as f32 - 0.5)) } else { 0.0 });
                }
            }
        }
        for (label, variant, db, queries) in [
            (
                "Scan Context++ polar",
                Variant::Polar(pp.clone()),
                polar_db,
                base.iter().map(|c| scancontext_pp::describe_polar(c, &PolarParams { voxel: 0.0, ..pp.clone() })).collect::<Vec<_>>(),
            ),
            ("Scan Context++ Cartesian", Variant::Cart(ppc.clone()), cart_db, cart_base.clone()),
        ] {
            let t = Instant::now();
            let s = scancontext_pp::Searcher::new(db, variant.clone());
            let build = t.elapsed().as_secs_f64();
            let total = query_ms(&queries, |q| s.search(q, 25, None).0.len());
            println!(
                "{label} search, {n} entries (keys made in {build:.2} s), k = 25 ({} candidates): {:.3} ms per query (the keys' nearest, then the re-rank), mean of {} queries",
                variant.candidates().max(25),
                mean(&total),
                total.len()
            );
        }
        // LiDAR-Iris: the scans' own descriptors, grown entry by entry.
        let iris_base: Vec<Vec<f32>> = clouds.iter().map(|c| lidar_iris::describe(c, &ip)).collect();
        for iris_n in [1_000, 10_000] {
            let t = Instant::now();
            let mut s = lidar_iris::Searcher::new(Vec::new(), ip.clone());
            for i in 0..iris_n {
                s.push(&iris_base[i % iris_base.len()]);
            }
            let build = t.elapsed().as_secs_f64();
            let total = query_ms(&iris_base, |q| s.search(q, 25, None).0.len());
            println!(
                "LiDAR-Iris search, {iris_n} entries (added in {build:.2} s), k = 25 ({} candidates): {:.3} ms per query (the row keys' nearest, then the phase correlation and Hamming distances, both directions), mean of {} queries",
                ip.candidates.max(25),
                mean(&total),
                total.len()
            );
        }
        // RING: the scans' own descriptors, grown entry by entry; every entry correlated (its
        // default), then the 50 nearest by key (`matched:50`).
        let ring_base: Vec<Vec<f32>> = clouds.iter().map(|c| ring::describe(c, &rp)).collect();
        for ring_n in [1_000, 10_000] {
            let t = Instant::now();
            let mut s = rp.searcher(Vec::new());
            for i in 0..ring_n {
                s.push(&ring_base[i % ring_base.len()]);
            }
            let build = t.elapsed().as_secs_f64();
            let total = query_ms(&ring_base, |q| s.search(q, 25, None).0.len());
            println!(
                "RING search, {ring_n} entries (added in {build:.2} s), k = 25, every entry: {:.3} ms per query (the circular correlation with each, then the poses of the hits), mean of {} queries",
                mean(&total),
                total.len()
            );
            s.set_budget(toporec::methods::SearchBudget::Matched(50), ring_n);
            let total = query_ms(&ring_base, |q| s.search(q, 25, None).0.len());
            println!(
                "RING search, {ring_n} entries, k = 25, matched:50: {:.3} ms per query (the keys' 50 nearest, then their correlation and the hits' poses), mean of {} queries",
                mean(&total),
                total.len()
            );
        }
        // RING++: as RING, six feature channels an entry (~1 MB resident each); one query
        // scan, searched ten times.
        let plus_base: Vec<Vec<f32>> = clouds.iter().map(|c| ring_plus::describe(c, &rpp).expect("a RING++ descriptor")).collect();
        for plus_n in [1_000, 10_000] {
            let t = Instant::now();
            let mut s = rpp.searcher(Vec::new());
            for i in 0..plus_n {
                s.push(&plus_base[i % plus_base.len()]);
            }
            let build = t.elapsed().as_secs_f64();
            let total = query_ms(&plus_base[..1], |q| s.search(q, 25, None).0.len());
            println!(
                "RING++ search, {plus_n} entries (added in {build:.2} s), k = 25, every entry: {:.3} ms per query (the six circular correlations with each, then the poses of the hits), mean of {} queries",
                mean(&total),
                total.len()
            );
            s.set_budget(toporec::methods::SearchBudget::Matched(50), plus_n);
            let total = query_ms(&plus_base[..1], |q| s.search(q, 25, None).0.len());
            println!(
                "RING++ search, {plus_n} entries, k = 25, matched:50: {:.3} ms per query, mean of {} queries",
                mean(&total),
                total.len()
            );
        }
        let t = Instant::now();
        let searcher = solid::Searcher::new(solid_db, sp.clone());
        let build = t.elapsed().as_secs_f64();
        let queries = solid_base;
        let total = query_ms(&queries, |q| searcher.search(q, 25, None).len());
        println!(
            "SOLiD search, {n} entries (unit range parts made in {build:.2} s), k = 25: {:.3} ms per query (every cosine, then the exact distances and yaws of the best), mean of {} queries",
            mean(&total),
            total.len()
        );
    });
}
