//! End-to-end pipeline benchmark: simulated HDL-32E scans (NCLT files) → preprocess to 4096
//! points → alpha persistence → ATOL (b = 50, fitted) → Parquet, with 1 and 2 worker threads,
//! on 200 and 2,000 scans. Reports scans/s, the speed-up of 2 threads over 1 (design goal
//! ≥ 1.7×), the pipeline overhead and peak RSS (design goal: 2,000 scans within 20 % of 200),
//! measured by /usr/bin/time.
//!
//! Overhead is the share of the workers' capacity (wall time × threads) not spent computing
//! persistence or descriptors, from the CPU seconds per stage that `run --summary-json` reports
//! (design goal < 10 %). Reading sources, preprocessing, writing, reading staged diagrams back
//! and waiting all count as overhead.
//!
//! Run: `cargo bench --bench pipeline` (about 2 minutes on 2 cores).
//!
//! `cargo bench --bench pipeline -- --whole` measures the indexing rate on whole scans
//! instead: 100 simulated HDL-32E scans with a finer azimuth (0.35 deg, about 21,000 points
//! each) through the same pipeline without the 4,096-point subsample, on 1 and 2 threads,
//! as scans/s and scans/s per core (about 4 minutes). `TOPOREC_BENCH_BIN` runs another build
//! of `toporec` on the same data (a before / after comparison).

use std::path::Path;
use std::process::Command;

struct Run {
    wall: f64,
    rss_kb: u64,
    scans_per_s: f64,
    /// CPU seconds per stage.
    cpu: serde_json::Value,
}

fn run(bin: &str, pipeline: &Path, index: &Path, threads: usize, extra: &[&str]) -> Run {
    let summary = index.with_extension("summary.json");
    // A fresh index each time: the bench measures whole runs.
    let _ = std::fs::remove_dir_all(index);
    let out = Command::new("/usr/bin/time")
        .args(["-f", "RSS_KB %M"])
        .arg(bin)
        .args([
            "run",
            pipeline.to_str().unwrap(),
            "--index",
            index.to_str().unwrap(),
            "-t",
            &threads.to_string(),
            "--no-progress",
            "--summary-json",
            summary.to_str().unwrap(),
        ])
        .args(extra)
        .output()
        .expect("/usr/bin/time");
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    let rss_kb = err
        .lines()
        .find_map(|l| l.strip_prefix("RSS_KB "))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("no RSS_KB line in {err}"));
    let s: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
    let wall = s["wall_seconds"].as_f64().unwrap();
    let read = s["scans"]["read"].as_f64().unwrap();
    Run { wall, rss_kb, scans_per_s: read / wall, cpu: s["cpu_seconds"].clone() }
}

/// Simulated NCLT-format scans under `data` (made once).
fn simulate(bin: &str, data: &Path, scans: usize, azimuth_res: &str) {
    if data.join("velodyne_data").is_dir() {
        return;
    }
    let st = Command::new(bin)
        .args(["simulate", "-o", data.to_str().unwrap(), "--sessions", "1", "--scans", &scans.to_string()])
        .args(["--azimuth-res", azimuth_res, "--seed", "3"])
        .status()
        .unwrap();
    assert!(st.success());
}

/// The paper's pipeline on whole scans: no subsample.
fn whole_scans(bin: &str, root: &Path) {
    let data = root.join("data-whole-100");
    simulate(env!("CARGO_BIN_EXE_toporec"), &data, 100, "0.35");
    let sessions = data.join("velodyne_data");
    let points: u64 = std::fs::read_dir(sessions.join("2026-01-01/velodyne_sync"))
        .unwrap()
        .map(|e| e.unwrap().metadata().unwrap().len() / 8)
        .sum();
    let pipeline = root.join("bench-whole.toml");
    std::fs::write(
        &pipeline,
        format!(
            "[output]\nindex = \"idx\"\n[[sources]]\nkind = \"nclt\"\nsessions = [\"{}\"]\n[preprocess]\nnormalize = true\n[vectorize]\nb = 50\n",
            sessions.display()
        ),
    )
    .unwrap();
    println!("whole scans: 100 simulated HDL-32E scans, {} points a scan on average; {bin}", points / 100);
    for threads in [1, 2] {
        let r = run(bin, &pipeline, &root.join(format!("index-whole-{threads}")), threads, &[]);
        println!(
            "{threads} thread(s): {:.2} scans/s, {:.2} scans/s per core, wall {:.1} s, peak RSS {} MB; persistence cpu {:.1} s",
            r.scans_per_s,
            r.scans_per_s / threads as f64,
            r.wall,
            r.rss_kb / 1024,
            r.cpu["persistence"].as_f64().unwrap_or(0.0)
        );
    }
}

fn main() {
    let own = env!("CARGO_BIN_EXE_toporec");
    let other = std::env::var("TOPOREC_BENCH_BIN").ok();
    let bin = other.as_deref().unwrap_or(own);
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/tmp/bench-pipeline");
    if std::env::args().any(|a| a == "--whole") {
        whole_scans(bin, &root);
        return;
    }
    let mut results = Vec::new();
    for scans in [200usize, 2000] {
        let data = root.join(format!("data-{scans}"));
        simulate(own, &data, scans, "0.4");
        let pipeline = root.join(format!("bench-{scans}.toml"));
        std::fs::write(
            &pipeline,
            format!(
                "[output]\nindex = \"idx\"\n[[sources]]\nkind = \"nclt\"\nsessions = [\"{}\"]\n[preprocess]\nsubsample = 4096\nnormalize = true\n[vectorize]\nb = 50\n",
                data.join("velodyne_data").display()
            ),
        )
        .unwrap();
        for threads in [1, 2] {
            let r = run(bin, &pipeline, &root.join(format!("index-{scans}-{threads}")), threads, &[]);
            let cpu = |stage: &str| r.cpu[stage].as_f64().unwrap_or(0.0);
            let useful = cpu("persistence") + cpu("vectorize");
            let overhead = 1.0 - useful / (r.wall * threads as f64);
            let stages: Vec<String> = r
                .cpu
                .as_object()
                .unwrap()
                .iter()
                .map(|(k, v)| format!("{k} {:.2}", v.as_f64().unwrap()))
                .collect();
            println!(
                "{scans:>5} scans, {threads} thread(s): {:.1} scans/s, wall {:.1} s, overhead {:.1} %, peak RSS {} MB; cpu s: {}",
                r.scans_per_s,
                r.wall,
                100.0 * overhead,
                r.rss_kb / 1024,
                stages.join(", ")
            );
            results.push((scans, threads, r));
        }
    }
    let get = |s, t| &results.iter().find(|r| r.0 == s && r.1 == t).unwrap().2;
    // The cost of chunked commits: the default (every 500 scans) against one commit at the end,
    // alternated, 2,000 scans on 2 threads.
    let pipeline = root.join("bench-2000.toml");
    let mut walls = [Vec::new(), Vec::new()];
    for _ in 0..2 {
        for (i, extra) in
            [&[][..], &["--commit-every", "1000000", "--commit-seconds", "1e9"][..]].iter().enumerate()
        {
            walls[i].push(run(bin, &pipeline, &root.join("index-commits"), 2, extra).wall);
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    println!(
        "chunked commits (every 500 scans) vs one commit, 2,000 scans, 2 threads: {:.1} s vs {:.1} s wall ({:+.1} %, design goal < 5 %)",
        mean(&walls[0]),
        mean(&walls[1]),
        100.0 * (mean(&walls[0]) / mean(&walls[1]) - 1.0)
    );
    println!(
        "speed-up 2 vs 1 thread (2,000 scans): {:.2}x (design goal >= 1.7x)",
        get(2000, 2).scans_per_s / get(2000, 1).scans_per_s
    );
    println!(
        "peak RSS 2,000 vs 200 scans (2 threads): {:.2}x (design goal <= 1.2x)",
        get(2000, 2).rss_kb as f64 / get(200, 2).rss_kb as f64
    );
}
