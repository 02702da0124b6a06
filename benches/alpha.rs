//! Alpha-persistence benchmark: times Delaunay, filtration and persistence separately on
//! 4096- and 30,000-point clouds, then (if `python3` with `gudhi` is available) runs
//! `scripts/gudhi_bench.py` on the very same clouds and prints both side by side: GUDHI in
//! its default precision (`safe`, the reference of the speed goal) and in `exact` (the
//! mode whose diagrams toporec reproduces).
//!
//! Run: `cargo bench --bench alpha` (add `-- --quick` for fewer repetitions).
//! Clouds: synthetic (uniform cube, the LiDAR-like fixture, a simulated scan of `samples/`) always; real KITTI / NCLT scans
//! from `../shared/data` when present, subsampled with a fixed seed.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};
use toporec::homology::{DelaunayComplex, Filtration, Point, persistence::persistence};
use toporec::rng::SplitMix64;

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

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let clouds = clouds();
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("bench-clouds");
    std::fs::create_dir_all(&dir).expect("bench dir");
    let mut rows = Vec::new();
    for c in &clouds {
        let reps = if quick {
            3
        } else if c.points.len() > 10_000 {
            7
        } else {
            21
        };
        let (t, counts) = run(&c.points, reps);
        let path = dir.join(format!("{}.csv", c.name));
        let mut text = String::from("x,y,z\n");
        for p in &c.points {
            text.push_str(&format!("{:?},{:?},{:?}\n", p[0], p[1], p[2]));
        }
        std::fs::write(&path, text).expect("write cloud");
        rows.push((c, t, counts, path));
    }
    // GUDHI on the same clouds, if available.
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/gudhi_bench.py");
    // name -> (safe ms, safe counts, exact ms, exact counts)
    let mut gudhi: std::collections::HashMap<String, (f64, String, f64, String)> = Default::default();
    let paths: Vec<String> = rows.iter().map(|r| r.3.display().to_string()).collect();
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
        Ok(o) => println!(
            "note: GUDHI comparison skipped: {}",
            String::from_utf8_lossy(&o.stderr).lines().last().unwrap_or("")
        ),
        Err(e) => println!("note: GUDHI comparison skipped: python3: {e}"),
    }
    println!(
        "| cloud | points | Delaunay ms | filtration ms | persistence ms | toporec total ms | GUDHI ms | speed-up | GUDHI exact ms | speed-up vs exact | pairs H0/H1/H2 (toporec; GUDHI; GUDHI exact) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|");
    for (c, t, counts, _) in &rows {
        let total = ms(t.delaunay) + ms(t.filtration) + ms(t.persistence);
        let na = || "n/a".to_string();
        let (g, speedup, gc, x, speedup_x, xc) = match gudhi.get(&c.name) {
            Some((g, gc, x, xc)) => (
                format!("{g:.1}"),
                format!("{:.1}x", g / total),
                gc.clone(),
                format!("{x:.1}"),
                format!("{:.1}x", x / total),
                xc.clone(),
            ),
            None => (na(), na(), na(), na(), na(), na()),
        };
        println!(
            "| {} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {} | {} | {} | {} | {}/{}/{}; {}; {} |",
            c.name,
            c.points.len(),
            ms(t.delaunay),
            ms(t.filtration),
            ms(t.persistence),
            total,
            g,
            speedup,
            x,
            speedup_x,
            counts[0],
            counts[1],
            counts[2],
            gc,
            xc
        );
    }
}
