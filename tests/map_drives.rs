//! Maps of simulated drives from their logs alone, scored against the truth `simulate` writes:
//! the steps aligned by ICP (`--odometry icp`), and false loops that pass ICP.

use crate::map::{aligned_rmse, tum};
use crate::util::{scratch_dir, text, toporec};
use std::path::Path;

/// `toporec simulate -o sim --format bag` with `drive`'s settings, at 1° azimuth and with the
/// drifting odometry of docs/loops.md's towns: 2 % long, 0.05° a metre to the left, 0.005 m and
/// 0.005 rad of noise a metre.
pub(crate) fn simulate_drifting(sim: &Path, drive: &[&str]) {
    let mut args = vec!["simulate", "-o", sim.to_str().unwrap(), "--format", "bag", "--azimuth-res", "1.0"];
    args.extend(drive);
    args.extend(["--drift-scale", "0.02", "--drift-heading", "0.05", "--drift-noise", "0.005"]);
    let o = toporec(&args);
    assert!(o.status.success(), "{}", text(&o.stderr));
}

/// Two sessions of one town, each odometry 2 % long and in a frame of its own: loops between
/// revisits cannot see the scale, so the map from the logs' steps keeps it; with `--odometry
/// icp` every step is aligned again between the raw scans, and both sessions, after one joint
/// alignment, land within centimetres of the truth.
#[test]
fn icp_odometry_undoes_a_scale_no_loop_can_see() {
    let dir = scratch_dir("icp_odometry");
    let sim = dir.join("sim");
    simulate_drifting(
        &sim,
        &[
            "--sessions",
            "2",
            "--laps",
            "1",
            "--own-frames",
            "--seed",
            "13",
            "--rate",
            "2",
            "--blocks",
            "3",
            "--block-size",
            "40",
        ],
    );
    let sessions = ["2026-01-01", "2026-01-02"];
    let truth: Vec<[f64; 2]> = sessions
        .iter()
        .flat_map(|s| tum(&sim.join(format!("truth/{s}.tum"))))
        .map(|t| [t[1], t[2]])
        .collect();
    let bags: Vec<String> =
        sessions.iter().map(|s| sim.join(format!("bag/{s}.bag")).to_str().unwrap().to_string()).collect();
    // `toporec loops [the bags] --index INDEX … -o OUT.csv --odometry ODOMETRY [extra]`.
    let loops = |with_bags: bool, index: &str, out: &str, odometry: &str, extra: &[&str]| {
        let (index, out) = (dir.join(index), dir.join(format!("{out}.csv")));
        let mut args = vec!["loops"];
        if with_bags {
            args.extend(bags.iter().map(String::as_str));
        }
        let (index, out) = (index.to_str().unwrap(), out.to_str().unwrap());
        args.extend(["--index", index, "--exclude-seconds", "10", "--no-progress", "-o", out]);
        args.extend(["--odometry", odometry]);
        args.extend(extra);
        toporec(&args)
    };
    let ate = |odometry: &str| -> (f64, String) {
        let o = loops(true, "index", odometry, odometry, &[]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        let corrected: Vec<[f64; 2]> = sessions
            .iter()
            .flat_map(|s| tum(&dir.join(format!("{odometry}.{s}.tum"))))
            .map(|t| [t[1], t[2]])
            .collect();
        assert_eq!(corrected.len(), truth.len());
        (aligned_rmse(&corrected, &truth), text(&o.stderr))
    };
    let (from_poses, said) = ate("poses");
    assert!(!said.contains("aligned by ICP"), "{said}");
    let (from_icp, said) = ate("icp");
    println!("ATE of both sessions: the logs' steps {from_poses:.3} m, ICP's {from_icp:.3} m");
    let steps = truth.len() - sessions.len();
    assert!(said.contains(&format!(", {steps} of {steps} steps aligned by ICP")), "{said}");
    assert!(from_poses > 0.3, "the logs' scale left in: {from_poses}");
    assert!(from_icp < 0.1, "{from_icp}");
    // Two methods: the steps are aligned once for both, and toporec-plus's map is the one it
    // makes alone, to the byte.
    let o = loops(true, "index-two", "two", "icp", &["--method", "toporec-plus", "--method", "ring"]);
    let said = text(&o.stderr);
    assert!(o.status.success(), "{said}");
    let aligned = format!(", {steps} of {steps} steps aligned by ICP");
    assert_eq!(said.matches(&aligned).count(), 2, "{said}");
    for s in sessions {
        let alone = std::fs::read(dir.join(format!("icp.{s}.tum"))).unwrap();
        assert_eq!(std::fs::read(dir.join(format!("two.toporec-plus.{s}.tum"))).unwrap(), alone, "{s}");
    }
    // The logs moved away: the steps keep the stored poses', and one warning says so (for both
    // methods: the steps are asked for once).
    std::fs::rename(&sim, dir.join("moved")).unwrap();
    let o = loops(false, "index-two", "moved", "icp", &[]);
    let said = text(&o.stderr);
    assert!(o.status.success(), "{said}");
    let warned: Vec<&str> = said.lines().filter(|l| l.contains("cannot be read again")).collect();
    assert_eq!(warned.len(), 1, "{said}");
    assert!(
        warned[0].contains(&format!("--odometry icp: {} scans cannot be read again", truth.len())),
        "{said}"
    );
    assert!(said.contains(&format!(", 0 of {steps} steps aligned by ICP")), "{said}");
}

/// Town 73 (the seed of docs/loops.md's table), two laps 3.5 m apart, the second reversed: at the
/// threshold of precision 0.99 on the tuning towns (0.3534; the default, calibrated at precision
/// 1, accepts none of them), three first-lap scans at a square block's corners match scans
/// 55–58 m away and pass ICP. The map rejects exactly those three (`in_map` false) and keeps every
/// true loop; from ICP's steps it lies within 0.15 m of the truth.
#[test]
fn false_loops_that_pass_icp_are_rejected_by_the_map() {
    let dir = scratch_dir("false_loops_pass_icp");
    let sim = dir.join("sim");
    simulate_drifting(
        &sim,
        &[
            "--sessions",
            "1",
            "--laps",
            "2",
            "--lap-offset",
            "3.5",
            "--seed",
            "73",
            "--sensor",
            "hdl64",
            "--rate",
            "5",
        ],
    );
    let truth = tum(&sim.join("truth/2026-01-01.tum"));
    let out = dir.join("loops.csv");
    let o = toporec(&[
        "loops",
        sim.join("bag/2026-01-01.bag").to_str().unwrap(),
        "--index",
        dir.join("index").to_str().unwrap(),
        "--exclude-seconds",
        "10",
        "--odometry",
        "icp",
        "--threshold",
        "0.3534",
        "--no-progress",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let table = std::fs::read_to_string(&out).unwrap();
    let mut lines = table.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (q, m, verified, in_map) =
        (column("query_vertex"), column("matched_vertex"), column("verified"), column("in_map"));
    let (mut false_rejected, mut true_kept, mut wrong) = (0, 0, Vec::new());
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        let (a, b) = (&truth[f[q].parse::<usize>().unwrap()], &truth[f[m].parse::<usize>().unwrap()]);
        let apart = (a[1] - b[1]).hypot(a[2] - b[2]);
        assert_eq!(f[verified], "true", "{line}");
        match (apart > 5.0, f[in_map]) {
            (true, "false") => false_rejected += 1,
            (false, "true") => true_kept += 1,
            _ => wrong.push(format!("{line} ({apart:.1} m apart)")),
        }
    }
    assert!(wrong.is_empty(), "{wrong:#?}");
    assert_eq!(false_rejected, 3, "{table}");
    assert!(true_kept >= 90, "{true_kept}");
    let corrected: Vec<[f64; 2]> =
        tum(&dir.join("loops.2026-01-01.tum")).iter().map(|t| [t[1], t[2]]).collect();
    let truth_xy: Vec<[f64; 2]> = truth.iter().map(|t| [t[1], t[2]]).collect();
    let ate = aligned_rmse(&corrected, &truth_xy);
    println!("ATE {ate:.3} m; {true_kept} true loops kept, {false_rejected} false ones rejected");
    assert!(ate < 0.15, "{ate}");
}
