//! toporec-plus benchmark: its cost per raw scan beside ScanContext's (with its voxel grid) and
//! the TopoRec paper's descriptor with the paper's settings (4,096 points scaled into [-1, 1],
//! alpha persistence, ATOL with b = 10) — design goal: at most 3× ScanContext — on whole
//! KITTI scans and on simulated HDL-64E scans; and a search over a large database (design
//! goals: a searcher over 1,000,000 entries opened in at most 2 s from the index's cache, a
//! query under 10 ms at the default budget, at most 8 KB resident an entry), one thread.
//!
//! Scans: the real KITTI scans of `../shared/data` when present, and simulated HDL-64E scans
//! (`toporec simulate`'s town, seed 3). The database (`TOPOREC_BENCH_ENTRIES`, default
//! 1,000,000) holds the descriptors of 10,000 distinct simulated scans (one drive of 5,000
//! scans a session, two sessions), each repeated with its sectors turned by a random shift and
//! its codes scaled by a random factor in [0.8, 1.2] and noised, so keys and columns look like
//! real ones; a copy keeps what follows the sector rows (the image), noised. The entries are
//! made as the copies come, 10,000 at a time (`toporec_plus::Builder`), so the descriptors are
//! never all held. The searcher is at toporec-plus's defaults (lateral views 3 m to either
//! side); the queries are also timed with and without the views, interleaved, over the same
//! searcher. It
//! reports the peak resident memory once built and the resident memory while answering, and
//! how well the default budget agrees with an exhaustive search (every entry re-ranked) on
//! `TOPOREC_BENCH_EXHAUSTIVE` fresh copies (default 4).
//!
//! Run: `cargo bench --bench toporec_plus`.

mod common;

use common::{median, median_ms, simulated_scans, turned_copy};
use std::path::Path;
use std::time::Instant;
use toporec::homology::{Point, alpha_persistence};
use toporec::methods::Computed as _;
use toporec::methods::toporec_plus::{self, PlusParams, Searcher};
use toporec::preprocess::{Preprocess, preprocess};
use toporec::rng::SplitMix64;
use toporec::vectorize::atol::{Atol, Contrast, Weighting};

/// A line of /proc/self/status in kB (`VmHWM`: the peak resident memory; `VmRSS`: now); 0
/// where there is none.
fn memory_kb(field: &str) -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find_map(|l| {
                l.strip_prefix(field)?.strip_prefix(':')?.trim().strip_suffix("kB")?.trim().parse().ok()
            })
        })
        .unwrap_or(0)
}

fn kitti_scans() -> Option<Vec<Vec<Point>>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let kitti = root.join("../shared/data/kitti/sequences");
    if !kitti.is_dir() {
        return None;
    }
    let mut f: Vec<_> = (0..11)
        .flat_map(|s| {
            let dir = kitti.join(format!("{s:02}/velodyne"));
            std::fs::read_dir(dir).into_iter().flatten().flatten().map(|e| e.path())
        })
        .collect();
    f.sort();
    Some(
        f.into_iter()
            .step_by(4)
            .take(12)
            .map(|f| toporec::sources::read_cloud(&f, None).expect("a scan"))
            .collect(),
    )
}

/// Per-scan medians of 5 runs (ms): the paper's descriptor, toporec-plus, ScanContext.
fn costs(clouds: &[Vec<Point>], p: &PlusParams) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let paper = Preprocess { subsample: Some(4096), normalize: true, ..Preprocess::default() };
    // An ATOL codebook of 10 centres in H2 (the paper's b for KITTI-360), for timing only.
    let centers: Vec<[f64; 2]> = (0..10).map(|i| [0.001 * i as f64, 0.002 + 0.001 * i as f64]).collect();
    let atol = Atol {
        centers,
        inertias: vec![0.001; 10],
        contrast: Contrast::Laplacian,
        weighting: Weighting::Cloud,
    };
    let scp = toporec::methods::scancontext::ScanContextParams::default();
    let (mut base, mut plus, mut sc) = (Vec::new(), Vec::new(), Vec::new());
    for (i, c) in clouds.iter().enumerate() {
        base.push(median_ms(5, || {
            let pts = preprocess(c.clone(), i as u64, &paper).expect("points");
            let d = alpha_persistence(&pts).expect("diagram");
            let h2: Vec<[f64; 2]> = d.dimension(2).iter().map(|q| [q.birth, q.death]).collect();
            std::hint::black_box(atol.transform(&h2));
        }));
        plus.push(median_ms(5, || {
            std::hint::black_box(toporec_plus::describe(c, p).unwrap());
        }));
        sc.push(median_ms(5, || {
            let grid = toporec::preprocess::voxel_grid(c, scp.voxel);
            std::hint::black_box(toporec::methods::scancontext::describe(&grid, &scp));
        }));
    }
    (base, plus, sc)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn max(v: &[f64]) -> f64 {
    v.iter().copied().fold(0.0, f64::max)
}

fn report_costs(name: &str, clouds: &[Vec<Point>], p: &PlusParams) {
    let (base, plus, sc) = costs(clouds, p);
    let mean_points = clouds.iter().map(|c| c.len()).sum::<usize>() / clouds.len();
    println!(
        "\n{name}: {} scans, mean {mean_points} points; medians of 5 runs per scan, one thread",
        clouds.len()
    );
    println!("| per raw scan | mean ms | slowest scan ms |");
    println!("|---|---:|---:|");
    println!(
        "| TopoRec, the paper's settings (4,096 points in [-1, 1], persistence, ATOL b = 10) | {:.2} | {:.2} |",
        mean(&base),
        max(&base)
    );
    println!(
        "| toporec-plus ({} m squares, height-field persistence, 2 channels) | {:.2} | {:.2} |",
        p.cell,
        mean(&plus),
        max(&plus)
    );
    println!("| ScanContext with its 0.5 m voxel grid | {:.2} | {:.2} |", mean(&sc), max(&sc));
    let to_sc: Vec<f64> = plus.iter().zip(&sc).map(|(a, b)| a / b).collect();
    println!(
        "toporec-plus / ScanContext (design goal: at most 3×): {:.2}× on average, {:.2}× at most (per scan); {:.2}× on the mean times; slowest scans {:.2} against {:.2} ms",
        mean(&to_sc),
        max(&to_sc),
        mean(&plus) / mean(&sc),
        max(&plus),
        max(&sc)
    );
}

fn main() {
    let p = PlusParams::default();
    let distinct: usize =
        std::env::var("TOPOREC_BENCH_DISTINCT").ok().and_then(|v| v.parse().ok()).unwrap_or(10_000);
    // Simulated on both cores (not timed), described on one.
    let simulated = simulated_scans(distinct);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    pool.install(move || {
        if let Some(kitti) = kitti_scans() {
            report_costs("KITTI (whole scans of the shared data)", &kitti, &p);
        } else {
            println!("KITTI scans: ../shared/data is absent; simulated scans only");
        }
        let sample: Vec<Vec<Point>> = simulated.iter().step_by(simulated.len() / 24).take(24).cloned().collect();
        report_costs("simulated HDL-64E (1° azimuth)", &sample, &p);
        // Search over a large database: the distinct scans, then copies turned and noised.
        let n: usize =
            std::env::var("TOPOREC_BENCH_ENTRIES").ok().and_then(|v| v.parse().ok()).unwrap_or(1_000_000);
        let t = Instant::now();
        let described: Vec<Vec<f32>> = simulated.iter().map(|c| toporec_plus::describe(c, &p).unwrap()).collect();
        drop(simulated);
        // The entries made as their descriptors come, a batch at a time: the descriptors are
        // never all held (at 1,000,000 they would take 16 GB as float32).
        let mut rng = SplitMix64(7);
        let mut builder = toporec_plus::Builder::new(p.clone(), n);
        let batch_entries = 10_000;
        let mut batch = Vec::with_capacity(batch_entries * p.len());
        for i in 0..n {
            let d = &described[i % described.len()];
            if i < described.len() {
                batch.extend_from_slice(d);
            } else {
                batch.extend(turned_copy(d, p.sectors, true, &mut rng));
            }
            if batch.len() == batch_entries * p.len() {
                builder.extend(&batch);
                batch.clear();
            }
        }
        builder.extend(&batch);
        drop(batch);
        let searcher = builder.finish();
        let build = t.elapsed().as_secs_f64();
        let peak_built = memory_kb("VmHWM");
        let queries: Vec<Vec<f32>> = described.iter().step_by(described.len() / 24).take(24).cloned().collect();
        let (mut cand, mut rerank, mut total) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..5 {
            for q in &queries {
                let s = Instant::now();
                let (hits, times) = searcher.search(q, 25);
                total.push(s.elapsed().as_secs_f64() * 1e3);
                cand.push(times.candidates * 1e3);
                rerank.push(times.rerank * 1e3);
                assert_eq!(hits.len(), 25);
            }
        }
        println!(
            "\ntoporec-plus search, {n} entries ({distinct} distinct scans; described, copied and made into entries in {build:.1} s; {} bytes an entry), k = 25 ({} candidates): {:.3} ms per query (key candidates {:.3} ms, re-rank {:.3} ms), mean of {} queries",
            toporec_plus::entry_bytes(&p),
            p.candidates.max(25),
            mean(&total),
            mean(&cand),
            mean(&rerank),
            total.len()
        );
        println!(
            "memory: peak resident {:.2} GB once built; resident while answering {:.2} GB (the searcher's entries {:.2} GB)",
            peak_built as f64 / 1e6,
            memory_kb("VmRSS") as f64 / 1e6,
            (toporec_plus::entry_bytes(&p) * n) as f64 / 1e9
        );
        // Agreement with an exhaustive search (every entry re-ranked) on fresh copies, not in
        // the database, of a few distinct scans.
        let sample: usize =
            std::env::var("TOPOREC_BENCH_EXHAUSTIVE").ok().and_then(|v| v.parse().ok()).unwrap_or(4);
        let mut searcher = searcher;
        let (mut same_first, mut shared) = (0, 0.0);
        let t = Instant::now();
        for q in described.iter().step_by((described.len() / sample.max(1)).max(1)).take(sample) {
            let q = turned_copy(q, p.sectors, true, &mut rng);
            let budget: Vec<usize> = searcher.search(&q, 25).0.iter().map(|h| h.row).collect();
            searcher.set_search(n, p.search_ratio);
            let all: Vec<usize> = searcher.search(&q, 25).0.iter().map(|h| h.row).collect();
            searcher.set_search(p.candidates, p.search_ratio);
            same_first += (budget.first() == all.first()) as usize;
            shared += budget.iter().filter(|r| all.contains(r)).count() as f64 / all.len().max(1) as f64;
        }
        println!(
            "against an exhaustive search ({sample} fresh copies as queries, {:.0} s): the same best entry for {same_first}, {:.1} % of the 25 best shared",
            t.elapsed().as_secs_f64(),
            100.0 * shared / sample.max(1) as f64
        );

        // The lateral views of the defaults against none (`PlusParams::plain`): a search-time
        // setting over the same entries, switched query by query.
        let mut searcher = searcher;
        let views = PlusParams::default().lateral;
        let (mut plain_ms, mut views_ms, mut plain_rerank, mut views_rerank) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for round in 0..4 {
            for q in &queries {
                for (lateral, out, rerank) in
                    [(Vec::new(), &mut plain_ms, &mut plain_rerank), (views.clone(), &mut views_ms, &mut views_rerank)]
                {
                    searcher.set_lateral(lateral);
                    let t = Instant::now();
                    let (_, times) = std::hint::black_box(searcher.search(q, 25));
                    if round > 0 {
                        out.push(t.elapsed().as_secs_f64() * 1e3);
                        rerank.push(times.rerank * 1e3);
                    }
                }
            }
        }
        searcher.set_lateral(views.clone());
        let (queries_timed, plain_q, views_q) = (views_ms.len(), median(plain_ms), median(views_ms));
        println!(
            "with lateral views {views:?} m: a query {views_q:.3} ms (re-rank {:.3} ms) against {plain_q:.3} ms (re-rank {:.3} ms) without (medians of {} interleaved queries each): {:.3}x",
            median(views_rerank),
            median(plain_rerank),
            queries_timed,
            views_q / plain_q
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
        let header = toporec::sinks::index::searchers::Header::new(
            1,
            "toporec-plus",
            "bench",
            serde_json::to_value(&p).expect("JSON"),
            toporec_plus::SEARCHER_LAYOUT,
            n,
        );
        let t = Instant::now();
        toporec::sinks::index::searchers::write(&path, &header, &rows, &searcher.bytes()).expect("cache written");
        let written = t.elapsed().as_secs_f64();
        drop(searcher);
        let bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        // Opening checks the header and the rows; each block of the body is checked when a
        // search first reads it. Measured from the page cache (warm), and after dropping it
        // (cold; needs the right to write /proc/sys/vm/drop_caches, else not measured), with
        // the first queries after a cold open: they read, and check, the blocks they touch.
        let open = || {
            let t = Instant::now();
            let toporec::sinks::index::searchers::Opened::Current(cached) =
                toporec::sinks::index::searchers::open(&path, 1, "bench", toporec_plus::SEARCHER_LAYOUT)
            else {
                panic!("a current cache")
            };
            let rows_n = cached.header.rows;
            let mapped = Searcher::mapped(cached.body, rows_n, p.clone()).expect("mapped");
            (mapped, t.elapsed().as_secs_f64())
        };
        let cold = std::fs::write("/proc/sys/vm/drop_caches", "3").ok().map(|()| {
            let (mapped, opened) = open();
            let ms: Vec<f64> = queries
                .iter()
                .map(|q| {
                    let t = Instant::now();
                    std::hint::black_box(mapped.search(q, 25));
                    t.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            (opened, ms[0], ms[1..].iter().sum::<f64>() / (ms.len() - 1).max(1) as f64)
        });
        let mut warm_opens = Vec::new();
        for _ in 0..3 {
            warm_opens.push(open().1);
        }
        let (mapped, opened) = open();
        warm_opens.push(opened);
        // The same bytes mapped without any check, as a cache was opened before checksums:
        // the queries of both alternate, so that the machine's drift falls on both alike.
        let file = std::fs::File::open(&path).expect("the cache");
        // SAFETY: the file is not written while mapped.
        let plain = unsafe { memmap2::Mmap::map(&file) }.expect("mapped");
        let (body, size) = toporec::sinks::index::searchers::header(&path).expect("intact").body;
        let plain = toporec::checked_map::CheckedMap::unchecked(plain, body, size);
        let unchecked = Searcher::mapped(plain, n, p.clone()).expect("mapped");
        let (mut checked_ms, mut unchecked_ms) = (Vec::new(), Vec::new());
        for round in 0..10 {
            for q in &queries {
                for (s, out) in [(&mapped, &mut checked_ms), (&unchecked, &mut unchecked_ms)] {
                    let t = Instant::now();
                    std::hint::black_box(s.search(q, 25));
                    // The first round touches the pages: left out of both.
                    if round > 0 {
                        out.push(t.elapsed().as_secs_f64() * 1e3);
                    }
                }
            }
        }
        let queries_timed = checked_ms.len();
        let warm_open = median(warm_opens);
        let (checked, unchecked) = (median(checked_ms), median(unchecked_ms));
        println!(
            "cached: {:.2} GB file ({:.1} KB an entry) written in {written:.1} s; opened (header and rows checked) in {warm_open:.2} s from the page cache (median of 4); cold: {}",
            bytes as f64 / 1e9,
            bytes as f64 / n as f64 / 1e3,
            cold.map_or("not measured".into(), |c| format!(
                "opened in {:.2} s, then the first query {:.1} ms and the next {} {:.1} ms each (their blocks read and checked)",
                c.0,
                c.1,
                queries.len() - 1,
                c.2
            ))
        );
        println!(
            "a query of the checked cache (its blocks checked once read) {checked:.3} ms, of the same bytes mapped unchecked {unchecked:.3} ms (medians of {} interleaved queries each): {:.3}x",
            queries_timed,
            checked / unchecked
        );
        let _ = std::fs::remove_file(&path);
    });
}
