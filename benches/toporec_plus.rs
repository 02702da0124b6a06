//! toporec-plus benchmark: its cost per raw scan beside ScanContext's (with its voxel grid) and
//! the TopoRec paper's descriptor with
//! the paper's settings (4,096 points scaled into [-1, 1], alpha persistence, ATOL with b = 10)
//! — design goal: at most 4× — and a search over 100,000 entries (design goal: under 5 ms per
//! query: key candidates, then the re-rank), one thread.
//!
//! Scans: the real KITTI scans of `../shared/data` when present, else simulated ones from
//! `samples/`. The 100,000 database entries are toporec-plus descriptors of those scans, each
//! with its sectors turned by a random shift and its values scaled by a random factor in
//! [0.8, 1.2] and noised, so keys and columns look like real ones.
//!
//! Run: `cargo bench --bench toporec_plus`.

mod common;

use common::median_ms;
use std::path::Path;
use std::time::Instant;
use toporec::homology::{Point, alpha_persistence};
use toporec::preprocess::{Preprocess, preprocess};
use toporec::rng::SplitMix64;
use toporec::toporec_plus::{self, PlusParams, Searcher};
use toporec::vectorize::atol::{Atol, Contrast, Weighting};

fn scans() -> (String, Vec<Vec<Point>>) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let kitti = root.join("../shared/data/kitti/sequences");
    let files: Vec<std::path::PathBuf> = if kitti.is_dir() {
        let mut f: Vec<_> = (0..11)
            .flat_map(|s| {
                let dir = kitti.join(format!("{s:02}/velodyne"));
                std::fs::read_dir(dir).into_iter().flatten().flatten().map(|e| e.path())
            })
            .collect();
        f.sort();
        f.into_iter().step_by(4).take(12).collect()
    } else {
        let dir = root.join("samples/town/velodyne_data/2026-01-01/velodyne_sync");
        let mut f: Vec<_> = std::fs::read_dir(dir).expect("samples").flatten().map(|e| e.path()).collect();
        f.sort();
        f.into_iter().take(12).collect()
    };
    let name =
        if kitti.is_dir() { "KITTI (one scan a sequence and more)" } else { "simulated (samples/town)" };
    (name.into(), files.iter().map(|f| toporec::sources::read_cloud(f, None).expect("a scan")).collect())
}

fn main() {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    pool.install(|| {
        let (name, clouds) = scans();
        let p = PlusParams::default();
        let paper = Preprocess { subsample: Some(4096), normalize: true, ..Preprocess::default() };
        // An ATOL codebook of 10 centres in H2 (the paper's b for KITTI-360), for timing only.
        let centers: Vec<[f64; 2]> = (0..10).map(|i| [0.001 * i as f64, 0.002 + 0.001 * i as f64]).collect();
        let atol = Atol { centers, inertias: vec![0.001; 10], contrast: Contrast::Laplacian, weighting: Weighting::Cloud };
        println!("scans: {name}, {} of them; medians over 5 runs per scan, one thread", clouds.len());
        let mean_points = clouds.iter().map(|c| c.len()).sum::<usize>() / clouds.len();
        let (mut base, mut plus, mut voxels, mut sc) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let scp = toporec::baselines::scancontext::ScanContextParams::default();
        for (i, c) in clouds.iter().enumerate() {
            base.push(median_ms(5, || {
                let pts = preprocess(c.clone(), i as u64, &paper).expect("points");
                let d = alpha_persistence(&pts).expect("diagram");
                let h2: Vec<[f64; 2]> = d.dimension(2).iter().map(|q| [q.birth, q.death]).collect();
                std::hint::black_box(atol.transform(&h2));
            }));
            plus.push(median_ms(5, || {
                std::hint::black_box(toporec_plus::describe(c, &p).unwrap());
            }));
            sc.push(median_ms(5, || {
                let grid = toporec::preprocess::voxel_grid(c, scp.voxel);
                std::hint::black_box(toporec::baselines::scancontext::describe(&grid, &scp));
            }));
            voxels.push(toporec_plus::preprocess(c, &p).len());
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
        let ratios: Vec<f64> = plus.iter().zip(&base).map(|(a, b)| a / b).collect();
        println!("| per raw scan (mean {mean_points} points) | mean ms | slowest ms |");
        println!("|---|---:|---:|");
        println!("| TopoRec, the paper's settings (4,096 points in [-1, 1], persistence, ATOL b = 10) | {:.1} | {:.1} |", mean(&base), max(&base));
        println!(
            "| toporec-plus ({} m voxels: mean {} points; located persistence; {} grids) | {:.1} | {:.1} |",
            p.voxel,
            voxels.iter().sum::<usize>() / voxels.len(),
            p.rotations,
            mean(&plus),
            max(&plus)
        );
        println!("| ScanContext with its 0.5 m voxel grid | {:.1} | {:.1} |", mean(&sc), max(&sc));
        println!("toporec-plus / the paper's: {:.2}× on average, {:.2}× at most (per scan)", mean(&ratios), max(&ratios));
        let to_sc: Vec<f64> = plus.iter().zip(&sc).map(|(a, b)| a / b).collect();
        println!(
            "toporec-plus / ScanContext (design goal: at most 3×): {:.2}× on average, {:.2}× at most (per scan); slowest scans {:.1} against {:.1} ms",
            mean(&to_sc),
            max(&to_sc),
            max(&plus),
            max(&sc)
        );

        // Search over 100,000 entries.
        let n: usize = std::env::var("TOPOREC_BENCH_ENTRIES").ok().and_then(|v| v.parse().ok()).unwrap_or(100_000);
        let described: Vec<Vec<f32>> = clouds.iter().map(|c| toporec_plus::describe(c, &p).unwrap()).collect();
        let t = Instant::now();
        let mut rng = SplitMix64(7);
        let grid = p.grid_len();
        let mut db = Vec::with_capacity(n * p.len());
        for i in 0..n {
            let d = &described[i % described.len()];
            let shift = rng.below(p.sectors);
            let scale = 0.8 + 0.4 * rng.next_f64();
            for block in d.chunks_exact(grid) {
                for row in block.chunks_exact(p.sectors) {
                    for s in 0..p.sectors {
                        let v = row[(s + shift) % p.sectors] as f64;
                        let noise = 1.0 + 0.1 * (rng.next_f64() - 0.5);
                        db.push((v * scale * noise) as f32);
                    }
                }
            }
        }
        let made = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let searcher = Searcher::new(db, p.clone());
        let build = t.elapsed().as_secs_f64();
        let (mut cand, mut rerank, mut total) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..5 {
            for q in &described {
                let s = Instant::now();
                let (hits, times) = searcher.search(q, 25);
                total.push(s.elapsed().as_secs_f64() * 1e3);
                cand.push(times.candidates * 1e3);
                rerank.push(times.rerank * 1e3);
                assert_eq!(hits.len(), 25);
            }
        }
        println!(
            "toporec-plus search, {n} entries ({:.1} GB of descriptors, made in {made:.1} s, key structure built in {build:.1} s), k = 25 ({} candidates): {:.3} ms per query (key candidates {:.3} ms, re-rank {:.3} ms), mean of {} queries",
            (n * p.len() * 4) as f64 / 1e9,
            p.candidates.max(25),
            mean(&total),
            mean(&cand),
            mean(&rerank),
            total.len()
        );

        // The same searcher cached as an index keeps it, then opened by mapping the file, as
        // every query after the first does.
        let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/tmp/bench-plus-cache");
        std::fs::create_dir_all(&dir).expect("scratch folder");
        let path = dir.join("toporec-plus.searcher");
        let rows: Vec<toporec::sinks::index::IndexedScan> = (0..n)
            .map(|i| toporec::sinks::index::IndexedScan {
                scan_id: format!("bench/{i:07}"),
                session: "bench".into(),
                utime: Some(i as i64),
                pose: Some([i as f64, 0.0, 0.0]),
                descriptor: Vec::new(),
                codebook_id: "bench".into(),
            })
            .collect();
        let header = toporec::sinks::index::searchers::Header {
            format_version: 1,
            generation: 1,
            method: "toporec-plus".into(),
            id: "bench".into(),
            params: serde_json::to_value(&p).expect("JSON"),
            rows: n,
            sessions: Vec::new(),
            body: (0, 0),
        };
        let t = Instant::now();
        toporec::sinks::index::searchers::write(&path, &header, &rows, searcher.bytes()).expect("cache written");
        let written = t.elapsed().as_secs_f64();
        drop(searcher);
        let bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        let t = Instant::now();
        let cached = toporec::sinks::index::searchers::open(&path, 1, "bench").expect("a current cache");
        let (body, rows_n) = (cached.header.body.0, cached.header.rows);
        let mapped = Searcher::mapped(cached.map, body, rows_n, p.clone()).expect("mapped");
        let opened = t.elapsed().as_secs_f64();
        let (mut first, mut warm) = (Vec::new(), Vec::new());
        for (round, out) in [(0, &mut first), (1, &mut warm)] {
            let _ = round;
            for q in &described {
                let s = Instant::now();
                std::hint::black_box(mapped.search(q, 25));
                out.push(s.elapsed().as_secs_f64() * 1e3);
            }
        }
        println!(
            "cached: {:.2} GB file ({:.1} KB an entry) written in {written:.1} s; opened (mapped, rows read) in {opened:.2} s; a query {:.3} ms on first touch, {:.3} ms after",
            bytes as f64 / 1e9,
            bytes as f64 / n as f64 / 1e3,
            mean(&first),
            mean(&warm)
        );
        let _ = std::fs::remove_file(&path);
    });
}
