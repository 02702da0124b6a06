//! Alpha-persistence benchmark, per cloud:
//! - the step times (Delaunay complex, filtration, persistence) and the whole diagram on one
//!   and on two threads (`alpha_persistence` inside a rayon pool of that size), with the
//!   two-thread speed-up (the median of the per-round ratios);
//! - the ratio to CGAL's `Delaunay_triangulation_3` alone (EPICK, points inserted as a range),
//!   when `scripts/build_cgal_reference.sh` has built its reference program: the two run
//!   interleaved (toporec, CGAL, toporec, CGAL, …) and each ratio is the median of the
//!   per-round ratios, since these machines drift between runs;
//! - the peak heap memory of one whole diagram, per point (a counting allocator);
//! - GUDHI on the same clouds (if `python3` with `gudhi` is available, `scripts/gudhi_bench.py`):
//!   its default precision (`safe`) and `exact` (the mode whose diagrams toporec reproduces),
//!   with the pair counts of both beside toporec's.
//!
//! Run: `cargo bench --bench alpha` (add `-- --quick` for fewer repetitions).
//! Clouds: synthetic (uniform cube, the LiDAR-like fixture, a simulated scan of `samples/`)
//! always; real KITTI / NCLT scans from `../shared/data` when present, subsampled with a fixed
//! seed, and whole (the NCLT scan, 23,546 points; frame 0 of KITTI sequences 00, 05 and 08,
//! 123,000-127,000 points each).

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};
use std::time::{Duration, Instant};
use toporec::homology::{DelaunayComplex, Filtration, Point, alpha_persistence, persistence::persistence};
use toporec::rng::SplitMix64;

/// The system allocator, counting live bytes and their peak.
struct Counting;
static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = LIVE.fetch_add(layout.size(), Relaxed) + layout.size();
            PEAK.fetch_max(now, Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            if new_size >= layout.size() {
                let now = LIVE.fetch_add(new_size - layout.size(), Relaxed) + new_size - layout.size();
                PEAK.fetch_max(now, Relaxed);
            } else {
                LIVE.fetch_sub(layout.size() - new_size, Relaxed);
            }
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Peak heap bytes that `f` adds above what was live when it started.
fn peak_bytes<T>(f: impl FnOnce() -> T) -> usize {
    let base = LIVE.load(Relaxed);
    PEAK.store(base, Relaxed);
    let out = f();
    let peak = PEAK.load(Relaxed) - base;
    drop(out);
    peak
}

/// The CGAL reference program, kept running: a CSV path in, `ms,cells` out.
struct Cgal {
    _child: Child,
    input: ChildStdin,
    output: BufReader<ChildStdout>,
}

impl Cgal {
    fn start() -> Result<Self, String> {
        let bin = std::env::var_os("TOPOREC_CGAL_BIN")
            .map(PathBuf::from)
            .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("target/cgal/delaunay_3"));
        if !bin.is_file() {
            return Err(format!("{} not built (run scripts/build_cgal_reference.sh)", bin.display()));
        }
        let mut child = Command::new(&bin)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .map_err(|e| format!("{}: {e}", bin.display()))?;
        let input = child.stdin.take().expect("piped");
        let output = BufReader::new(child.stdout.take().expect("piped"));
        Ok(Cgal { _child: child, input, output })
    }

    /// Milliseconds of one triangulation of the cloud at `path` (after a warm-up), and its
    /// finite cells.
    fn time(&mut self, path: &Path) -> Option<(f64, usize)> {
        writeln!(self.input, "{}", path.display()).ok()?;
        self.input.flush().ok()?;
        let mut line = String::new();
        self.output.read_line(&mut line).ok()?;
        let (ms, cells) = line.trim().split_once(',')?;
        Some((ms.parse().ok()?, cells.parse().ok()?))
    }
}

struct Cloud {
    name: String,
    points: Vec<Point>,
}

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

fn read_csv(path: &Path) -> Option<Vec<Point>> {
    let bytes = std::fs::read(path).ok()?;
    toporec::sources::csv::parse_xyz(&bytes, path).ok()
}

fn clouds() -> Vec<Cloud> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut out = vec![Cloud { name: "uniform_cube_4096".into(), points: uniform_cube(4096, 1) }];
    if let Some(p) = read_csv(&root.join("tests/fixtures/clouds/lidar_like_4096.csv")) {
        out.push(Cloud { name: "lidar_like_4096".into(), points: p });
    }
    // A simulated HDL-32E scan from samples/ (5 mm-quantized NCLT format, planar walls).
    let town = root.join("samples/town/velodyne_data/2026-01-01/velodyne_sync/1767261600000000.bin");
    if let Ok(p) = toporec::sources::read_cloud(&town, None) {
        out.push(Cloud { name: format!("town_sample_full_{}", p.len()), points: p });
    }
    let data = root.join("../shared/data");
    let kitti = data.join("kitti/sequences/00/velodyne/000000.bin");
    let nclt = data.join("nclt/2012-01-15/velodyne_sync/1326652795280148.bin");
    let kitti_pts = toporec::sources::read_cloud(&kitti, None).ok();
    let nclt_pts = toporec::sources::read_cloud(&nclt, None).ok();
    if let Some(k) = &kitti_pts {
        out.push(Cloud { name: "kitti_00_000000_4096".into(), points: subsample(k, 4096, 7) });
    }
    if let Some(k) = &nclt_pts {
        out.push(Cloud { name: "nclt_2012-01-15_4096".into(), points: subsample(k, 4096, 7) });
    }
    out.push(Cloud { name: "uniform_cube_30000".into(), points: uniform_cube(30_000, 2) });
    if let Some(k) = &kitti_pts {
        out.push(Cloud { name: "kitti_00_000000_30000".into(), points: subsample(k, 30_000, 7) });
    }
    if let Some(k) = &nclt_pts {
        out.push(Cloud { name: format!("nclt_2012-01-15_full_{}", k.len()), points: k.clone() });
    }
    // Whole HDL-64E scans, above 100,000 points: where two threads should pay most. Frame 0
    // of sequences 00 (a suburb), 05 and 08 (other streets and seasons).
    if let Some(k) = &kitti_pts {
        out.push(Cloud { name: format!("kitti_00_000000_full_{}", k.len()), points: k.clone() });
    }
    for sequence in ["05", "08"] {
        let path = data.join(format!("kitti/sequences/{sequence}/velodyne/000000.bin"));
        if let Ok(k) = toporec::sources::read_cloud(&path, None) {
            out.push(Cloud { name: format!("kitti_{sequence}_000000_full_{}", k.len()), points: k });
        }
    }
    if kitti_pts.is_none() {
        println!("note: ../shared/data absent: real-scan clouds skipped");
    }
    out
}

#[derive(Default, Clone, Copy)]
struct Times {
    delaunay: Duration,
    filtration: Duration,
    persistence: Duration,
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn run(points: &[Point], reps: usize) -> (Times, [usize; 3]) {
    let (mut d, mut f, mut p) = (Vec::new(), Vec::new(), Vec::new());
    let mut counts = [0; 3];
    for _ in 0..reps {
        let t0 = Instant::now();
        let complex = DelaunayComplex::new(points).expect("finite cloud");
        let t1 = Instant::now();
        let filtration = Filtration::new(&complex);
        let t2 = Instant::now();
        let diagram = persistence(&filtration);
        let t3 = Instant::now();
        counts = diagram.counts();
        d.push(t1 - t0);
        f.push(t2 - t1);
        p.push(t3 - t2);
    }
    (Times { delaunay: median(d), filtration: median(f), persistence: median(p) }, counts)
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn time_ms<T>(f: impl FnOnce() -> T) -> f64 {
    let t = Instant::now();
    let out = f();
    let elapsed = t.elapsed();
    drop(out);
    ms(elapsed)
}

fn median_f(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// One cloud's figures.
struct Row<'a> {
    cloud: &'a Cloud,
    steps: Times,
    counts: [usize; 3],
    whole: [f64; 2],
    /// Median of the per-round ratios whole (1 thread) / whole (2 threads).
    speedup: f64,
    /// CGAL ms, then the median per-round ratios Delaunay / CGAL, whole (1 thread) / CGAL,
    /// whole (2 threads) / CGAL, and CGAL's finite cells.
    cgal: Option<(f64, [f64; 3], usize)>,
    tets: usize,
    peak: usize,
    path: PathBuf,
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let clouds = clouds();
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("bench-clouds");
    std::fs::create_dir_all(&dir).expect("bench dir");
    let pools = [1, 2].map(|n| rayon::ThreadPoolBuilder::new().num_threads(n).build().expect("a pool"));
    let mut cgal = match Cgal::start() {
        Ok(c) => Some(c),
        Err(e) => {
            println!("note: CGAL comparison skipped: {e}");
            None
        }
    };
    let mut rows = Vec::new();
    for c in &clouds {
        let large = c.points.len() > 10_000;
        let reps = if quick {
            3
        } else if large {
            7
        } else {
            21
        };
        let (steps, counts) = pools[0].install(|| run(&c.points, reps));
        let path = dir.join(format!("{}.csv", c.name));
        let mut text = String::from("x,y,z\n");
        for p in &c.points {
            text.push_str(&format!("{:?},{:?},{:?}\n", p[0], p[1], p[2]));
        }
        std::fs::write(&path, text).expect("write cloud");
        let peak = pools[0].install(|| peak_bytes(|| alpha_persistence(&c.points).expect("finite cloud")));
        let tets = DelaunayComplex::new(&c.points).expect("finite cloud").tets.len();
        // Interleaved rounds: toporec's Delaunay, its whole diagram on 1 and 2 threads, CGAL.
        let rounds = if quick {
            5
        } else if large {
            7
        } else {
            11
        };
        let (mut whole, mut ratios, mut cgal_ms) = ([vec![], vec![]], [vec![], vec![], vec![]], vec![]);
        let mut speedups = Vec::new();
        let mut cgal_cells = 0;
        for _ in 0..rounds {
            let d = pools[0].install(|| time_ms(|| DelaunayComplex::new(&c.points).expect("finite cloud")));
            let w = [0, 1].map(|k| {
                pools[k].install(|| time_ms(|| alpha_persistence(&c.points).expect("finite cloud")))
            });
            whole[0].push(w[0]);
            whole[1].push(w[1]);
            speedups.push(w[0] / w[1]);
            if let Some(reference) = cgal.as_mut() {
                match reference.time(&path) {
                    Some((m, cells)) => {
                        cgal_ms.push(m);
                        cgal_cells = cells;
                        for (k, t) in [d, w[0], w[1]].into_iter().enumerate() {
                            ratios[k].push(t / m);
                        }
                    }
                    None => {
                        println!("note: CGAL comparison stopped: no answer on {}", path.display());
                        cgal = None;
                    }
                }
            }
        }
        let whole = whole.map(median_f);
        let speedup = median_f(speedups);
        let cgal_row = (!cgal_ms.is_empty() && cgal.is_some())
            .then(|| (median_f(cgal_ms), ratios.map(median_f), cgal_cells));
        rows.push(Row { cloud: c, steps, counts, whole, speedup, cgal: cgal_row, tets, peak, path });
    }
    println!("one thread unless said; medians; ratios are medians of interleaved per-round ratios");
    println!(
        "| cloud | points | Delaunay ms | filtration ms | persistence ms | (filtration + persistence) / Delaunay | whole ms, 1 thread | whole ms, 2 threads | 2-thread speed-up | CGAL triangulation ms | Delaunay / CGAL | whole / CGAL | whole (2 threads) / CGAL | tetrahedra (toporec; CGAL) | peak bytes / point |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|");
    for r in &rows {
        let (cg, ratios, cells) = match r.cgal {
            Some((m, q, cells)) => (format!("{m:.2}"), q.map(|x| format!("{x:.2}")), cells.to_string()),
            None => ("n/a".into(), ["n/a".to_string(), "n/a".into(), "n/a".into()], "n/a".into()),
        };
        println!(
            "| {} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2}x | {} | {} | {} | {} | {}; {} | {:.0} |",
            r.cloud.name,
            r.cloud.points.len(),
            ms(r.steps.delaunay),
            ms(r.steps.filtration),
            ms(r.steps.persistence),
            (r.steps.filtration + r.steps.persistence).as_secs_f64() / r.steps.delaunay.as_secs_f64(),
            r.whole[0],
            r.whole[1],
            r.speedup,
            cg,
            ratios[0],
            ratios[1],
            ratios[2],
            r.tets,
            cells,
            r.peak as f64 / r.cloud.points.len() as f64
        );
    }
    gudhi_table(&rows, quick);
}

/// GUDHI on the same clouds, if available, beside toporec's whole time on one thread.
fn gudhi_table(rows: &[Row], quick: bool) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/gudhi_bench.py");
    // name -> (safe ms, safe counts, exact ms, exact counts)
    let mut gudhi: std::collections::HashMap<String, (f64, String, f64, String)> = Default::default();
    let paths: Vec<String> = rows.iter().map(|r| r.path.display().to_string()).collect();
    match Command::new("python3")
        .arg(&script)
        .arg("--reps")
        .arg(if quick { "1" } else { "3" })
        .args(&paths)
        .output()
    {
        Ok(o) if o.status.success() => {
            for line in String::from_utf8_lossy(&o.stdout).lines() {
                let f: Vec<&str> = line.split(',').collect();
                if f.len() == 5
                    && let (Ok(safe), Ok(exact)) = (f[1].parse::<f64>(), f[3].parse::<f64>())
                {
                    gudhi.insert(f[0].to_string(), (safe, f[2].to_string(), exact, f[4].to_string()));
                }
            }
        }
        Ok(o) => {
            println!(
                "note: GUDHI comparison skipped: {}",
                String::from_utf8_lossy(&o.stderr).lines().last().unwrap_or("")
            );
            return;
        }
        Err(e) => {
            println!("note: GUDHI comparison skipped: python3: {e}");
            return;
        }
    }
    println!();
    println!(
        "| cloud | points | toporec whole ms, 1 thread | GUDHI ms | speed-up | GUDHI exact ms | speed-up vs exact | pairs H0/H1/H2 (toporec; GUDHI; GUDHI exact) | equal to exact |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---|---|");
    for r in rows {
        let total = r.whole[0];
        let ours = format!("{}/{}/{}", r.counts[0], r.counts[1], r.counts[2]);
        let Some((g, gc, x, xc)) = gudhi.get(&r.cloud.name) else {
            println!(
                "| {} | {} | {total:.2} | n/a | n/a | n/a | n/a | {ours} | n/a |",
                r.cloud.name,
                r.cloud.points.len()
            );
            continue;
        };
        println!(
            "| {} | {} | {total:.2} | {g:.1} | {:.1}x | {x:.1} | {:.1}x | {ours}; {gc}; {xc} | {} |",
            r.cloud.name,
            r.cloud.points.len(),
            g / total,
            x / total,
            if &ours == xc { "yes" } else { "NO" }
        );
    }
}
