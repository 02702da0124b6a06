//! One call of `alpha_persistence`, as a user times it: in fresh processes, on the global
//! rayon pool of 1 and of 2 threads (`RAYON_NUM_THREADS`), 41 calls a process on the same
//! cloud. Reports, per cloud size:
//! - the first call of a process against the median of its later calls (goal: within 1.5x);
//! - the median and the 95th percentile of the later calls on 2 threads against 1 thread
//!   (goal: within 1.03x, or faster);
//! - for the first call, the page faults and the heap it touched (from `getrusage`), so that
//!   where its time goes can be read off.
//!
//! Processes of the two thread counts alternate (1, 2, 1, 2, ...) so that drift of the machine
//! falls on both. Clouds: KITTI 00 / 000000 of `../shared/data` cut to 1,024, 4,096, 16,384 and
//! 30,000 points (fixed seed) and whole; without the data, uniform cubes of those sizes.
//!
//! Run: `cargo bench --bench calls` (about 8 minutes on 2 cores; `-- --quick` for 2 processes
//! a thread count and no whole scan).

use std::path::Path;
use std::process::Command;
use std::time::Instant;
use toporec::homology::{Point, alpha_persistence};
use toporec::rng::SplitMix64;

const CALLS: usize = 41;

fn uniform_cube(n: usize, seed: u64) -> Vec<Point> {
    let mut rng = SplitMix64(seed);
    (0..n).map(|_| [0, 1, 2].map(|_| rng.next_f64() * 2.0 - 1.0)).collect()
}

fn subsample(points: &[Point], n: usize, seed: u64) -> Vec<Point> {
    let mut idx: Vec<usize> = (0..points.len()).collect();
    let mut rng = SplitMix64(seed);
    for i in 0..n.min(idx.len()) {
        let j = i + (rng.next_u64() % (idx.len() - i) as u64) as usize;
        idx.swap(i, j);
    }
    idx.truncate(n);
    idx.sort_unstable();
    idx.iter().map(|&i| points[i]).collect()
}

/// The cloud of a size (`0`: the whole scan) and its name.
fn cloud(size: usize) -> (String, Vec<Point>) {
    let kitti =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/kitti/sequences/00/velodyne/000000.bin");
    match toporec::sources::read_cloud(&kitti, None) {
        Ok(p) if size == 0 => (format!("kitti_00_000000_full_{}", p.len()), p),
        Ok(p) => (format!("kitti_00_000000_{size}"), subsample(&p, size, 7)),
        Err(_) => {
            let n = if size == 0 { 124_668 } else { size };
            (format!("uniform_cube_{n}"), uniform_cube(n, 3))
        }
    }
}

/// (minor page faults, max RSS in KiB) of this process so far.
fn rusage() -> (i64, i64) {
    let mut u = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage fills the struct it is given.
    unsafe { libc::getrusage(libc::RUSAGE_SELF, u.as_mut_ptr()) };
    // SAFETY: zeroed and then filled by the kernel.
    let u = unsafe { u.assume_init() };
    (u.ru_minflt, u.ru_maxrss)
}

/// Child mode: `calls SIZE`; prints `faults_first rss_first_kib ms ms ms ...`.
fn child(size: usize) {
    let (_, points) = cloud(size);
    let mut ms = Vec::with_capacity(CALLS);
    let mut first = (0, 0);
    for call in 0..CALLS {
        let (f0, _) = rusage();
        let t = Instant::now();
        let diagram = alpha_persistence(&points).expect("a finite cloud");
        ms.push(t.elapsed().as_secs_f64() * 1e3);
        if call == 0 {
            let (f1, rss) = rusage();
            first = (f1 - f0, rss);
        }
        std::hint::black_box(diagram);
    }
    let times: Vec<String> = ms.iter().map(|m| format!("{m:.3}")).collect();
    println!("{} {} {}", first.0, first.1, times.join(" "));
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    let k = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[k]
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    quantile(&s, 0.5)
}

/// Per process: first call ms, faults of the first call, RSS after it, later calls ms.
struct Process {
    first: f64,
    faults: i64,
    rss_kib: i64,
    later: Vec<f64>,
}

fn spawn(size: usize, threads: usize) -> Process {
    let exe = std::env::current_exe().expect("the bench binary");
    let out = Command::new(exe)
        .args(["--child", &size.to_string()])
        .env("RAYON_NUM_THREADS", threads.to_string())
        .output()
        .expect("run a child");
    assert!(out.status.success(), "child failed: {}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().last().expect("a line");
    let f: Vec<f64> = line.split(' ').map(|x| x.parse().expect("a number")).collect();
    Process { faults: f[0] as i64, rss_kib: f[1] as i64, first: f[2], later: f[3..].to_vec() }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if let Some(i) = args.iter().position(|a| a == "--child") {
        child(args[i + 1].parse().expect("a size"));
        return;
    }
    let quick = args.iter().any(|a| a == "--quick");
    let mut sizes = vec![1024, 4096, 16_384, 30_000];
    if !quick {
        sizes.push(0);
    }
    println!(
        "{CALLS} calls a process, fresh processes alternating 1 and 2 threads; later = calls 2..{CALLS}"
    );
    println!(
        "| cloud | points | processes a thread count | first call ms, 1 thread (min-max) | first / later median, 1 thread (max) | first / later median, 2 threads (max) | later median ms, 1; 2 threads | median 2 / 1 threads | p95 ms, 1; 2 threads | p95 2 / 1 threads | first call's page faults; RSS MiB after it |"
    );
    println!("|---|---:|---:|---|---:|---:|---|---:|---|---:|---|");
    for size in sizes {
        let (name, points) = cloud(size);
        let processes = if quick || size == 0 { 2 } else { 5 };
        let mut by_threads: [Vec<Process>; 2] = [vec![], vec![]];
        for _ in 0..processes {
            for (k, threads) in [1, 2].into_iter().enumerate() {
                by_threads[k].push(spawn(size, threads));
            }
        }
        // Later calls of all processes of a thread count, pooled.
        let pooled = by_threads.each_ref().map(|ps| {
            let mut v: Vec<f64> = ps.iter().flat_map(|p| p.later.iter().copied()).collect();
            v.sort_by(f64::total_cmp);
            v
        });
        let med = pooled.each_ref().map(|v| quantile(v, 0.5));
        let p95 = pooled.each_ref().map(|v| quantile(v, 0.95));
        let first_ratio = by_threads.each_ref().map(|ps| {
            let r: Vec<f64> = ps.iter().map(|p| p.first / median(&p.later)).collect();
            (median(&r), r.iter().copied().fold(0.0, f64::max))
        });
        let firsts: Vec<f64> = by_threads[0].iter().map(|p| p.first).collect();
        let (lo, hi) = (
            firsts.iter().copied().fold(f64::INFINITY, f64::min),
            firsts.iter().copied().fold(0.0, f64::max),
        );
        let faults = median(&by_threads[0].iter().map(|p| p.faults as f64).collect::<Vec<_>>());
        let rss = median(&by_threads[0].iter().map(|p| p.rss_kib as f64).collect::<Vec<_>>()) / 1024.0;
        println!(
            "| {name} | {} | {processes} | {lo:.1}-{hi:.1} | {:.2} ({:.2}) | {:.2} ({:.2}) | {:.1}; {:.1} | {:.3} | {:.1}; {:.1} | {:.3} | {faults:.0}; {rss:.0} |",
            points.len(),
            first_ratio[0].0,
            first_ratio[0].1,
            first_ratio[1].0,
            first_ratio[1].1,
            med[0],
            med[1],
            med[1] / med[0],
            p95[0],
            p95[1],
            p95[1] / p95[0],
        );
    }
}
