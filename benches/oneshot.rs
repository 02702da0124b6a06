//! What the one command costs against the same work done by hand: `toporec loops drive.bag`
//! (pipeline made from the bag, indexed, loops sought at toporec-plus's threshold, verified by
//! ICP, the picture drawn) against `toporec run drive.toml` + `toporec loops --index … --verify`
//! on a pipeline file that reads the same bag with the same poses (the log's `/tf` chain).
//!
//! The drive: a 1,000-scan simulated ROS 1 bag (HDL-32E at 0.2°, two laps, seed 5; made once
//! into `target/tmp/bench-oneshot`). Each form runs from an empty index, alternating which goes
//! first, `REPS` times on 1 and 2 threads; medians of each and their ratio. Both forms' loops
//! tables are checked to hold the same rows.
//!
//! Then what joining new poses costs: the bag indexed (`toporec run <bag>`, toporec-plus) from an
//! empty index, against the same index brought up to date with another pose file (the log's own
//! poses moved 1 m: every scan's rows written anew, no descriptor computed) and against a run
//! with nothing to do; 2 threads, medians of `REPS`.
//!
//! Run: `cargo bench --bench oneshot` (`-- forms` or `-- rejoin` for one part).

mod common;

use common::median;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

const REPS: usize = 3;

fn toporec(bin: &str, args: &[&str]) {
    let out = Command::new(bin).args(args).output().unwrap();
    assert!(out.status.success(), "toporec {args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

/// The bag (made once).
fn drive(bin: &str, dir: &Path) -> PathBuf {
    let bag = dir.join("sim/bag/2026-01-01.bag");
    if !bag.is_file() {
        let sim = dir.join("sim");
        let _ = std::fs::remove_dir_all(&sim);
        toporec(
            bin,
            &[
                "simulate",
                "-o",
                sim.to_str().unwrap(),
                "--format",
                "bag",
                "--sessions",
                "1",
                "--scans",
                "1000",
                "--laps",
                "2",
                "--seed",
                "5",
            ],
        );
    }
    bag
}

fn seconds(f: impl FnOnce()) -> f64 {
    let t = Instant::now();
    f();
    t.elapsed().as_secs_f64()
}

/// The loops table's rows (CSV lines, sorted).
fn rows(csv: &Path) -> Vec<String> {
    let mut lines: Vec<String> = std::fs::read_to_string(csv).unwrap().lines().map(str::to_string).collect();
    lines.sort();
    lines
}

fn main() {
    let bin = env!("CARGO_BIN_EXE_toporec");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = root.join("target/tmp/bench-oneshot");
    std::fs::create_dir_all(&dir).unwrap();
    let bag = drive(bin, &dir);
    let pipeline = dir.join("drive.toml");
    std::fs::write(
        &pipeline,
        format!(
            "[output]\nindex = \"by-hand\"\n\n[[sources]]\nkind = \"rosbag\"\npaths = [{:?}]\n\n\
             [descriptors]\nmethods = [\"toporec-plus\"]\n[toporec-plus]\nlateral = [3.0]\n",
            bag.display().to_string()
        ),
    )
    .unwrap();
    let only: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).collect();
    let wants = |part: &str| only.is_empty() || only.iter().any(|o| o == part);
    if wants("forms") {
        forms(bin, &bag, &dir, &pipeline);
    }
    if wants("rejoin") {
        rejoin(bin, &bag, &dir);
    }
}

/// The one command against the same work by hand.
fn forms(bin: &str, bag: &Path, dir: &Path, pipeline: &Path) {
    let s = |p: &Path| p.to_str().unwrap().to_string();
    println!("1,000-scan simulated bag ({}), {REPS} runs of each form from an empty index", bag.display());
    println!("{:>8} {:>14} {:>14} {:>7}", "threads", "one command s", "by hand s", "ratio");
    for threads in ["1", "2"] {
        let (mut one, mut hand) = (Vec::new(), Vec::new());
        for rep in 0..REPS {
            let one_index = dir.join("one");
            let hand_index = dir.join("by-hand");
            let one_out = dir.join("one.csv");
            let hand_out = dir.join("by-hand.csv");
            let _ = std::fs::remove_dir_all(&one_index);
            let _ = std::fs::remove_dir_all(&hand_index);
            let run_one = || {
                seconds(|| {
                    toporec(
                        bin,
                        &[
                            "loops",
                            &s(bag),
                            "--index",
                            &s(&one_index),
                            "-o",
                            &s(&one_out),
                            "--no-progress",
                            "-t",
                            threads,
                        ],
                    )
                })
            };
            let run_hand = || {
                seconds(|| {
                    toporec(
                        bin,
                        &["run", &s(pipeline), "--index", &s(&hand_index), "--no-progress", "-t", threads],
                    );
                    toporec(
                        bin,
                        &[
                            "loops",
                            "--index",
                            &s(&hand_index),
                            "--verify",
                            "-o",
                            &s(&hand_out),
                            "--no-progress",
                            "-t",
                            threads,
                        ],
                    );
                })
            };
            if rep % 2 == 0 {
                one.push(run_one());
                hand.push(run_hand());
            } else {
                hand.push(run_hand());
                one.push(run_one());
            }
            assert_eq!(rows(&one_out), rows(&hand_out), "both forms find the same loops");
        }
        let (o, h) = (median(one), median(hand));
        println!("{threads:>8} {o:>14.2} {h:>14.2} {:>7.3}", o / h);
    }
}

/// Indexing the bag, against joining other poses into its index and against a run with
/// nothing to do.
fn rejoin(bin: &str, bag: &Path, dir: &Path) {
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let index = dir.join("rejoin");
    let moved = dir.join("moved.tum");
    let run = |extra: &[&str]| {
        let mut args = vec!["run".to_string(), s(bag), "--index".into(), s(&index), "--no-progress".into()];
        args.extend(["-t".into(), "2".into()]);
        args.extend(extra.iter().map(|a| a.to_string()));
        let out = Command::new(bin).args(&args).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let (mut indexing, mut joining, mut nothing) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..REPS {
        let _ = std::fs::remove_dir_all(&index);
        indexing.push(seconds(|| {
            run(&[]);
        }));
        let mut tum = String::new();
        for r in toporec::sinks::index::IndexReader::open(&index).unwrap().scans().unwrap() {
            let (Some(t), Some(p)) = (r.utime, r.pose) else { continue };
            let (qz, qw) = ((p.yaw / 2.0).sin(), (p.yaw / 2.0).cos());
            tum += &format!("{:.6} {} {} {} 0 0 {qz} {qw}\n", t as f64 * 1e-6, p.x + 1.0, p.y, p.z);
        }
        std::fs::write(&moved, tum).unwrap();
        let mut said = String::new();
        joining.push(seconds(|| said = run(&["--poses", &s(&moved)])));
        assert!(said.contains("1000 up-to-date scans took new poses"), "{said}");
        nothing.push(seconds(|| {
            run(&["--poses", &s(&moved)]);
        }));
    }
    let (i, j, n) = (median(indexing), median(joining), median(nothing));
    println!("\njoining new poses into the 1,000-scan index (2 threads, medians of {REPS})");
    println!("{:>24} {:>8} {:>9}", "", "s", "of index");
    println!("{:>24} {i:>8.2} {:>9.3}", "index from empty", 1.0);
    println!("{:>24} {j:>8.2} {:>9.3}", "join new poses", j / i);
    println!("{:>24} {n:>8.2} {:>9.3}", "nothing to do", n / i);
}
