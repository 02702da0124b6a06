//! `toporec optimize`: public and made-up g2o graphs, the robust cost, and bad input.

use crate::util::{g2o_se3_edges, python_with, scratch_dir, shared_data, text, toporec};
use std::fmt::Write as _;
use std::path::Path;

/// A square block driven twice as an SE(2) g2o graph: odometry 3 % long and turning 0.02 rad a
/// step too far, a true loop at each corner, and (with `false_loop`) scan 5 said to be 3 m to the
/// side of scan 35, which it is not.
fn square_g2o(false_loop: bool) -> String {
    let mut truth = vec![(0.0f64, 0.0f64, 0.0f64)];
    for k in 0..39 {
        let (x, y, t) = truth[k];
        let turn = if k % 10 == 9 { std::f64::consts::FRAC_PI_2 } else { 0.0 };
        truth.push((x + t.cos(), y + t.sin(), t + turn));
    }
    let relative = |a: (f64, f64, f64), b: (f64, f64, f64)| {
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        (a.2.cos() * dx + a.2.sin() * dy, -a.2.sin() * dx + a.2.cos() * dy, b.2 - a.2)
    };
    let info = "100 0 0 100 0 1000";
    let mut text = String::new();
    let mut pose = truth[0];
    let mut edges = String::new();
    for k in 0..40 {
        writeln!(text, "VERTEX_SE2 {k} {} {} {}", pose.0, pose.1, pose.2).unwrap();
        if k < 39 {
            let (dx, dy, dt) = relative(truth[k], truth[k + 1]);
            let (dx, dy, dt) = (dx * 1.03, dy * 1.03, dt + 0.02);
            writeln!(edges, "EDGE_SE2 {k} {} {dx} {dy} {dt} {info}", k + 1).unwrap();
            pose = (
                pose.0 + pose.2.cos() * dx - pose.2.sin() * dy,
                pose.1 + pose.2.sin() * dx + pose.2.cos() * dy,
                pose.2 + dt,
            );
        }
    }
    for (a, b) in [(0, 20), (9, 29), (10, 30), (19, 39)] {
        let (dx, dy, dt) = relative(truth[a], truth[b]);
        writeln!(edges, "EDGE_SE2 {a} {b} {dx} {dy} {dt} {info}").unwrap();
    }
    if false_loop {
        writeln!(edges, "EDGE_SE2 5 35 0 3 0 {info}").unwrap();
    }
    text + "# a comment stays\n" + &edges
}

/// The vertices' positions of an SE(2) g2o file, by id.
fn positions(path: &Path) -> Vec<(f64, f64)> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| l.starts_with("VERTEX_SE2"))
        .map(|l| {
            let w: Vec<f64> = l.split_whitespace().skip(2).map(|w| w.parse().unwrap()).collect();
            (w[0], w[1])
        })
        .collect()
}

#[test]
fn optimize_writes_the_same_graph_with_its_vertices_moved() {
    let dir = scratch_dir("optimize_writes_the_same_graph");
    let graph = dir.join("square.g2o");
    std::fs::write(&graph, square_g2o(false)).unwrap();
    let out = dir.join("out.g2o");
    let o = toporec(&["optimize", graph.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stdout).contains("SE(2) graph: 40 vertices (1 held), 43 edges"), "{}", text(&o.stdout));
    let (before, after) = (std::fs::read_to_string(&graph).unwrap(), std::fs::read_to_string(&out).unwrap());
    let (before, after): (Vec<&str>, Vec<&str>) = (before.lines().collect(), after.lines().collect());
    assert_eq!(before.len(), after.len());
    for (b, a) in before.iter().zip(&after) {
        if b.starts_with("VERTEX_SE2") {
            assert_eq!(b.split_whitespace().nth(1), a.split_whitespace().nth(1), "ids in order");
        } else {
            assert_eq!(b, a, "every other line as it was");
        }
    }
    // The first vertex is held; the loops pull the far corner back within 0.6 m of its truth
    // (the odometry alone leaves it more than 3 m off).
    let moved = positions(&out);
    assert_eq!(moved[0], (0.0, 0.0));
    let drifted = positions(&graph)[39];
    let truth = (0.0, 1.0);
    let off = |p: (f64, f64)| ((p.0 - truth.0).powi(2) + (p.1 - truth.1).powi(2)).sqrt();
    assert!(off(drifted) > 3.0, "{}", off(drifted));
    assert!(off(moved[39]) < 0.6, "{}", off(moved[39]));
}

#[test]
fn optimize_robust_rejects_the_loop_that_disagrees() {
    let dir = scratch_dir("optimize_robust_rejects");
    let graph = dir.join("square.g2o");
    std::fs::write(&graph, square_g2o(true)).unwrap();
    let clean = dir.join("clean.g2o");
    std::fs::write(&clean, square_g2o(false)).unwrap();
    let run = |input: &Path, out: &Path, robust: bool| {
        let mut args = vec!["optimize", input.to_str().unwrap(), "-o", out.to_str().unwrap()];
        if robust {
            args.push("--robust");
        }
        let o = toporec(&args);
        assert!(o.status.success(), "{}", text(&o.stderr));
        (text(&o.stdout), positions(out))
    };
    let (said, robust) = run(&graph, &dir.join("robust.g2o"), true);
    assert!(said.contains("loops rejected: 1 (5–35)"), "{said}");
    let (_, plain) = run(&graph, &dir.join("plain.g2o"), false);
    let (said, without) = run(&clean, &dir.join("without.g2o"), true);
    assert!(!said.contains("rejected"), "{said}");
    let apart = |a: &[(f64, f64)], b: &[(f64, f64)]| {
        a.iter().zip(b).map(|(p, q)| ((p.0 - q.0).powi(2) + (p.1 - q.1).powi(2)).sqrt()).fold(0.0, f64::max)
    };
    // The robust map is the map without the false loop; least squares is bent by it.
    assert!(apart(&robust, &without) < 1e-3, "{}", apart(&robust, &without));
    assert!(apart(&plain, &without) > 0.5, "{}", apart(&plain, &without));
}

#[test]
fn optimize_names_the_line_of_a_bad_graph_and_writes_nothing() {
    let dir = scratch_dir("optimize_bad_graph");
    let out = dir.join("out.g2o");
    let good = square_g2o(false);
    let cases: Vec<(&str, String, &str)> = vec![
        // Lines 1–40 are the vertices, 41 the comment, 42 on the edges.
        ("unknown.g2o", good.replacen("EDGE_SE2 3 4", "EDGE_SE9 3 4", 1), ":45: unknown line `EDGE_SE9`"),
        ("short.g2o", good.clone() + "VERTEX_SE2 95 1 2\n", ":85: expected 3 numbers after `VERTEX_SE2`"),
        (
            "number.g2o",
            good.replacen("EDGE_SE2 0 1 ", "EDGE_SE2 0 1 x", 1),
            ":42: expected 9 numbers after `EDGE_SE2`",
        ),
        ("missing.g2o", good.clone() + "EDGE_SE2 0 77 1 0 0 1 0 0 1 0 1\n", ":85: no vertex 77 in the file"),
        (
            "mixed.g2o",
            good.clone() + "VERTEX_SE3:QUAT 90 0 0 0 0 0 0 1\n",
            ":85: `VERTEX_SE3:QUAT` in a graph of VERTEX_SE2",
        ),
        (
            "parts.g2o",
            good.clone() + "VERTEX_SE2 90 0 0 0\nVERTEX_SE2 91 1 0 0\nEDGE_SE2 90 91 1 0 0 1 0 0 1 0 1\n",
            "the graph is in 2 disconnected parts: 40 vertices (0…39), 2 vertices (90…91)",
        ),
        ("empty.g2o", "# nothing\n".to_string(), "not a g2o pose graph"),
    ];
    for (name, content, said) in cases {
        let graph = dir.join(name);
        std::fs::write(&graph, &content).unwrap();
        let o = toporec(&["optimize", graph.to_str().unwrap(), "-o", out.to_str().unwrap()]);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{name}: {err}");
        assert!(err.contains(name), "{name}: {err}");
        assert!(err.contains(said), "{name}: wanted {said:?} in {err}");
        assert!(!out.exists(), "{name}: nothing written");
    }
    // A solve that does not converge says so, with its last cost, and writes nothing.
    let graph = dir.join("square.g2o");
    std::fs::write(&graph, &good).unwrap();
    let o =
        toporec(&["optimize", graph.to_str().unwrap(), "-o", out.to_str().unwrap(), "--max-iterations", "1"]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("did not converge in 1 iterations (last cost"), "{err}");
    assert!(!out.exists());
}

/// The parking garage (3D, 1,661 poses): toporec's result, read back and scored by GTSAM's own
/// `graph.error`, is within 0.1 % of the cost GTSAM's Levenberg–Marquardt reaches (0.634192, at
/// GTSAM 4.3's defaults from the file's initial guess; scripts/optimize_bench.py).
#[test]
fn optimize_reaches_gtsams_cost_on_the_parking_garage() {
    let Some(data) = shared_data("optimize_reaches_gtsams_cost") else { return };
    let dir = scratch_dir("optimize_parking_garage");
    let graph = data.join("posegraphs/parking-garage.g2o");
    let out = dir.join("out.g2o");
    let o = toporec(&["optimize", graph.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(
        text(&o.stdout).contains("SE(3) graph: 1661 vertices (1 held), 6275 edges"),
        "{}",
        text(&o.stdout)
    );
    if !python_with("optimize_reaches_gtsams_cost", &["gtsam"]) {
        return;
    }
    let score = std::process::Command::new("python3")
        .args([
            "-c",
            "import sys, gtsam\n\
             graph, _ = gtsam.readG2o(sys.argv[1], True)\n\
             _, values = gtsam.readG2o(sys.argv[2], True)\n\
             print(graph.error(values))",
            graph.to_str().unwrap(),
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(score.status.success(), "{}", text(&score.stderr));
    let cost: f64 = text(&score.stdout).trim().parse().unwrap();
    assert!(cost <= 0.634192 * 1.001, "GTSAM scores toporec's result {cost}");
}

/// w20000's vertices are its odometry chained over 20,000 poses, far from the solution: from
/// there Levenberg–Marquardt crawls (260 iterations to a cost of 806.67). From the chordal
/// relaxation it reaches a far lower minimum in a few iterations (seen: the start at 75.98,
/// 18.77 after 21 iterations).
#[test]
fn optimize_from_the_chordal_start_solves_w20000_in_a_few_iterations() {
    let Some(data) = shared_data("optimize_from_the_chordal_start") else { return };
    let dir = scratch_dir("optimize_chordal_w20000");
    let graph = data.join("posegraphs/w20000.g2o");
    let out = dir.join("out.g2o");
    let o =
        toporec(&["optimize", graph.to_str().unwrap(), "-o", out.to_str().unwrap(), "--start", "chordal"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let said = text(&o.stdout);
    // "… cost 52147703.791569 → 75.981607 (chordal start) → 18.772897 in 21 iterations, …"
    let after = said.split("(chordal start) → ").nth(1).unwrap_or_else(|| panic!("{said}"));
    let cost: f64 = after.split(' ').next().unwrap().parse().unwrap();
    let iterations: usize = after.split(" in ").nth(1).unwrap().split(' ').next().unwrap().parse().unwrap();
    assert!(cost < 25.0 && iterations < 50, "{said}");
    assert!(out.exists());
}

/// A TUM file's rows: time, x, y, z, yaw.
pub(crate) fn tum(path: &Path) -> Vec<[f64; 5]> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|w| w.parse().unwrap()).collect();
            let (qx, qy, qz, qw) = (v[4], v[5], v[6], v[7]);
            [v[0], v[1], v[2], v[3], (2.0 * (qw * qz + qx * qy)).atan2(1.0 - 2.0 * (qy * qy + qz * qz))]
        })
        .collect()
}

/// The cells of `size` m holding the points of a binary PLY written by `loops --cloud` (at its
/// 0.2 m: one point a cell), its length checked against its header.
fn ply_cells(path: &std::path::Path, size: f64) -> std::collections::HashSet<[i64; 3]> {
    let bytes = std::fs::read(path).unwrap();
    let end = bytes.windows(11).position(|w| w == b"end_header\n").expect("a PLY header") + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"), "{header}");
    let n: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .and_then(|n| n.parse().ok())
        .expect("a vertex count");
    assert_eq!(bytes.len() - end, n * 12, "x, y, z as float32");
    let cells: std::collections::HashSet<[i64; 3]> = bytes[end..]
        .chunks_exact(12)
        .map(|p| {
            let c = |i: usize| f32::from_le_bytes(p[i..i + 4].try_into().unwrap()) as f64;
            [c(0), c(4), c(8)].map(|v| (v / size).floor() as i64)
        })
        .collect();
    assert!(size > 0.2 || cells.len() == n, "one point a cell");
    cells
}

/// The cost after the solve that a summary gives (`… cost 7.012 → 5.946 in 3 iterations`): the
/// number after the text's first ` → `.
fn solved_cost(summary: &str) -> f64 {
    summary
        .split(" → ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|c| c.parse().ok())
        .expect("a cost")
}

/// The RMSE of the positions (x, y) of two trajectories of the same scans.
fn position_rmse(a: &[[f64; 5]], b: &[[f64; 5]]) -> f64 {
    assert_eq!(a.len(), b.len());
    let sum: f64 = a.iter().zip(b).map(|(p, q)| (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sum();
    (sum / a.len() as f64).sqrt()
}

/// `samples/drive.bag` driven with odometry 3 % long and turning 0.004 rad a scan too far
/// (given as `--poses`): the map pulls the trajectory back to within a quarter of the
/// odometry's error, keeps every loop, writes TUM and KITTI, and its `--g2o` graph is the one it
/// optimized (`toporec optimize --robust` reaches the same cost; GTSAM reads it).
#[test]
fn loops_make_a_map_that_undoes_the_odometrys_drift() {
    let dir = scratch_dir("loops_make_a_map");
    let bag = crate::util::root().join("samples/drive.bag");
    let run = |extra: &[&str]| {
        let mut args = vec!["loops", bag.to_str().unwrap(), "--no-progress"];
        args.extend_from_slice(extra);
        let o = toporec(&args);
        assert!(o.status.success(), "{}", text(&o.stderr));
        text(&o.stdout) + &text(&o.stderr)
    };
    // The bag's own poses, optimized with its loops: the reference trajectory.
    let (truth_index, truth_out) = (dir.join("truth-index"), dir.join("truth/loops.csv"));
    let truth_cloud = dir.join("truth/cloud.ply");
    run(&[
        "--index",
        truth_index.to_str().unwrap(),
        "-o",
        truth_out.to_str().unwrap(),
        "--cloud",
        truth_cloud.to_str().unwrap(),
    ]);
    let truth = tum(&dir.join("truth/loops.drive.tum"));
    assert_eq!(truth.len(), 96);
    // The same drive from a drifting odometry.
    let mut drifted = vec![truth[0]];
    for k in 1..truth.len() {
        let (a, b) = (truth[k - 1], truth[k]);
        let (dx, dy) = (b[1] - a[1], b[2] - a[2]);
        let (forward, left) = (a[4].cos() * dx + a[4].sin() * dy, -a[4].sin() * dx + a[4].cos() * dy);
        let turn = (b[4] - a[4] + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI)
            - std::f64::consts::PI;
        let (forward, left, turn) = (forward * 1.03, left * 1.03, turn + 0.004);
        let p = drifted[k - 1];
        drifted.push([
            b[0],
            p[1] + p[4].cos() * forward - p[4].sin() * left,
            p[2] + p[4].sin() * forward + p[4].cos() * left,
            b[3],
            p[4] + turn,
        ]);
    }
    let odometry = dir.join("odometry.tum");
    let lines: Vec<String> = drifted
        .iter()
        .map(|p| {
            format!(
                "{:.6} {} {} {} 0 0 {} {}",
                p[0],
                p[1],
                p[2],
                p[3],
                (p[4] / 2.0).sin(),
                (p[4] / 2.0).cos()
            )
        })
        .collect();
    std::fs::write(&odometry, lines.join("\n") + "\n").unwrap();
    let (index, out, g2o) = (dir.join("index"), dir.join("map/loops.csv"), dir.join("map/graph"));
    // The drive from the drifting odometry, into `index`, its rows to `table`.
    let from_odometry = |table: &Path, extra: &[&str]| {
        let mut args = vec![
            "--poses",
            odometry.to_str().unwrap(),
            "--index",
            index.to_str().unwrap(),
            "-o",
            table.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        run(&args)
    };
    let said = from_odometry(
        &out,
        &["--g2o", g2o.to_str().unwrap(), "--cloud", dir.join("map/cloud.ply").to_str().unwrap()],
    );
    assert!(said.contains("map (toporec-plus): 96 scans, 16 loops, 16 kept, 0 rejected"), "{said}");
    // The cloud: the scans at the corrected poses fill the reference's 1 m cells far better
    // than at the odometry's, and are the same bytes on one thread.
    let in_map = ply_cells(&dir.join("map/cloud.ply"), 0.2);
    let cloud_line =
        format!("cloud: {} ({} points from 96 scans)", dir.join("map/cloud.ply").display(), in_map.len());
    assert!(said.contains(&cloud_line), "{said}");
    let odometry_cloud = dir.join("map/odometry.ply");
    let (o1, c1) = (dir.join("one/loops.csv"), dir.join("one/cloud.ply"));
    from_odometry(&o1, &["--no-optimize", "--cloud", odometry_cloud.to_str().unwrap()]);
    from_odometry(&o1, &["--threads", "1", "--cloud", c1.to_str().unwrap()]);
    let shared = |cloud: &std::path::Path| {
        let (cells, reference) = (ply_cells(cloud, 1.0), ply_cells(&truth_cloud, 1.0));
        cells.intersection(&reference).count() as f64 / cells.union(&reference).count() as f64
    };
    let (map_shared, odometry_shared) = (shared(&dir.join("map/cloud.ply")), shared(&odometry_cloud));
    println!("cloud cells shared with the reference's: map {map_shared:.3}, odometry {odometry_shared:.3}");
    // Measured: 0.400 against 0.252.
    assert!(map_shared > 1.4 * odometry_shared, "map {map_shared}, odometry {odometry_shared}");
    assert_eq!(std::fs::read(&c1).unwrap(), std::fs::read(dir.join("map/cloud.ply")).unwrap());
    let corrected = tum(&dir.join("map/loops.drive.tum"));
    let (before, after) = (position_rmse(&drifted, &truth), position_rmse(&corrected, &truth));
    println!("position RMSE against the reference: odometry {before:.3} m, map {after:.3} m");
    assert!(before > 5.0, "{before}");
    assert!(after < 0.25 * before, "{after} against {before}");
    // KITTI's layout: the same poses, 3 × 4 row by row.
    let kitti = std::fs::read_to_string(dir.join("map/loops.drive.kitti")).unwrap();
    let rows: Vec<Vec<f64>> =
        kitti.lines().map(|l| l.split_whitespace().map(|w| w.parse().unwrap()).collect()).collect();
    assert_eq!(rows.len(), 96);
    for (r, c) in rows.iter().zip(&corrected) {
        assert_eq!(r.len(), 12);
        assert!((r[3] - c[1]).abs() < 1e-5 && (r[7] - c[2]).abs() < 1e-5, "{r:?} {c:?}");
    }
    // Every kept loop is in the map.
    let table = std::fs::read_to_string(&out).unwrap();
    let header: Vec<&str> = table.lines().next().unwrap().split(',').collect();
    let column = header.iter().position(|c| *c == "in_map").expect("an in_map column");
    assert!(table.lines().skip(1).all(|l| l.split(',').nth(column) == Some("true")), "{table}");
    // The graph written is the graph solved.
    let graph = dir.join("map/graph.toporec-plus.g2o");
    let text_of = std::fs::read_to_string(&graph).unwrap();
    assert_eq!(text_of.lines().filter(|l| l.starts_with("VERTEX_SE3:QUAT")).count(), 96);
    assert_eq!(text_of.lines().filter(|l| l.starts_with("EDGE_SE3:QUAT")).count(), 95 + 16);
    assert_eq!(text_of.lines().last(), Some("FIX 0"));
    let o = toporec(&[
        "optimize",
        graph.to_str().unwrap(),
        "-o",
        dir.join("optimized.g2o").to_str().unwrap(),
        "--robust",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let solved = text(&o.stdout);
    // The same solve: the summary rounds the cost to 3 decimals.
    assert!((solved_cost(&said) - solved_cost(&solved)).abs() <= 5e-4 + 1e-9, "{said}\n{solved}");
    if python_with("loops_make_a_map", &["gtsam"]) {
        let o = std::process::Command::new("python3")
            .args([
                "-c",
                "import sys, gtsam\ng, v = gtsam.readG2o(sys.argv[1], True)\nprint(g.size(), v.size())",
                graph.to_str().unwrap(),
            ])
            .output()
            .unwrap();
        assert_eq!(text(&o.stdout).trim(), "111 96", "{}", text(&o.stderr));
    }
    // Wrong loops: a quarter of the loops (4 of 16) replaced by random scan pairs more than 5 m
    // apart, each given a small, plausible relative pose at ICP's information. The map rejects
    // every one and ends as near the reference as without them.
    let clean_error = vertex_rmse(&dir.join("optimized.g2o"), &truth);
    let lines: Vec<String> = text_of.lines().map(str::to_string).collect();
    let loop_lines: Vec<usize> = (0..lines.len())
        .filter(|&i| {
            let w: Vec<&str> = lines[i].split(' ').collect();
            w[0] == "EDGE_SE3:QUAT" && w[2].parse::<i64>().unwrap() - w[1].parse::<i64>().unwrap() != 1
        })
        .collect();
    assert_eq!(loop_lines.len(), 16);
    let mut seed = 12345u64;
    let mut next = |n: u64| {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seed >> 33) % n
    };
    let mut wrong_lines = lines.clone();
    let mut wrong = Vec::new();
    for &at in loop_lines.iter().step_by(4).take(4) {
        let (a, b) = loop {
            let (a, b) = (next(96) as usize, next(96) as usize);
            let apart = ((truth[a][1] - truth[b][1]).powi(2) + (truth[a][2] - truth[b][2]).powi(2)).sqrt();
            if a + 5 < b && apart > 5.0 {
                break (a, b);
            }
        };
        let (x, y, yaw) = (
            next(400) as f64 / 100.0 - 2.0,
            next(200) as f64 / 100.0 - 1.0,
            (next(100) as f64 / 10.0 - 5.0).to_radians(),
        );
        let info = lines[at].split(' ').skip(10).collect::<Vec<_>>().join(" ");
        wrong_lines[at] =
            format!("EDGE_SE3:QUAT {a} {b} {x} {y} 0 0 0 {} {} {info}", (yaw / 2.0).sin(), (yaw / 2.0).cos());
        wrong.push(format!("{a}–{b}"));
    }
    let wrong_graph = dir.join("wrong.g2o");
    std::fs::write(&wrong_graph, wrong_lines.join("\n") + "\n").unwrap();
    let solved = dir.join("wrong-optimized.g2o");
    let o = toporec(&["optimize", wrong_graph.to_str().unwrap(), "-o", solved.to_str().unwrap(), "--robust"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let said = text(&o.stdout);
    for w in &wrong {
        assert!(said.contains(w.as_str()), "{w} not rejected: {said}");
    }
    assert!(said.contains(&format!("loops rejected: {} (", wrong.len())), "only the wrong ones: {said}");
    let wrong_error = vertex_rmse(&solved, &truth);
    println!("position RMSE: clean {clean_error:.3} m, with a quarter of the loops wrong {wrong_error:.3} m");
    assert!(wrong_error <= 1.1 * clean_error, "{wrong_error} against {clean_error}");
    // --no-optimize: no map, no corrected poses, in_map null.
    let plain = dir.join("plain/loops.csv");
    let said = run(&[
        "--poses",
        odometry.to_str().unwrap(),
        "--index",
        index.to_str().unwrap(),
        "-o",
        plain.to_str().unwrap(),
        "--no-optimize",
    ]);
    assert!(!said.contains("map ("), "{said}");
    assert!(!dir.join("plain/loops.drive.tum").exists());
    let table = std::fs::read_to_string(&plain).unwrap();
    assert!(table.lines().skip(1).all(|l| l.split(',').nth(column) == Some("")), "{table}");
}

/// The RMSE of an SE(3) g2o file's vertex positions (x, y; vertex k the k-th row) against `truth`.
fn vertex_rmse(graph: &Path, truth: &[[f64; 5]]) -> f64 {
    let poses: Vec<[f64; 5]> = std::fs::read_to_string(graph)
        .unwrap()
        .lines()
        .filter_map(|l| l.strip_prefix("VERTEX_SE3:QUAT "))
        .map(|l| {
            let v: Vec<f64> = l.split(' ').map(|w| w.parse().unwrap()).collect();
            [0.0, v[1], v[2], v[3], 0.0]
        })
        .collect();
    position_rmse(&poses, truth)
}

/// The RMSE of `estimate`'s positions (x, y) against `truth`'s after one rigid planar
/// alignment (the closed form of Umeyama's, without scale).
pub(crate) fn aligned_rmse(estimate: &[[f64; 2]], truth: &[[f64; 2]]) -> f64 {
    let n = estimate.len() as f64;
    let mean =
        |p: &[[f64; 2]]| [p.iter().map(|q| q[0]).sum::<f64>() / n, p.iter().map(|q| q[1]).sum::<f64>() / n];
    let (me, mt) = (mean(estimate), mean(truth));
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for (e, t) in estimate.iter().zip(truth) {
        let (ex, ey, tx, ty) = (e[0] - me[0], e[1] - me[1], t[0] - mt[0], t[1] - mt[1]);
        sxx += ex * tx + ey * ty;
        sxy += ex * ty - ey * tx;
    }
    let angle = sxy.atan2(sxx);
    let (c, s) = (angle.cos(), angle.sin());
    let sum: f64 = estimate
        .iter()
        .zip(truth)
        .map(|(e, t)| {
            let (ex, ey) = (e[0] - me[0], e[1] - me[1]);
            let (x, y) = (c * ex - s * ey + mt[0], s * ex + c * ey + mt[1]);
            (x - t[0]).powi(2) + (y - t[1]).powi(2)
        })
        .sum();
    (sum / n).sqrt()
}

/// `simulate --drift-…` logs an odometry that drifts as asked, starting at the origin with
/// `--own-frames`, and writes the truth beside it; from that log alone, the map of a two-lap
/// drive (the second lap reversed, 1.5 m over) is within a quarter of the odometry's error.
#[test]
fn a_drifting_simulated_odometry_is_corrected_by_the_map() {
    let dir = scratch_dir("drifting_simulated_odometry");
    let sim = dir.join("sim");
    crate::map_drives::simulate_drifting(
        &sim,
        &[
            "--sessions",
            "1",
            "--laps",
            "2",
            "--lap-offset",
            "1.5",
            "--seed",
            "13",
            "--rate",
            "2",
            "--blocks",
            "3",
            "--block-size",
            "40",
            "--own-frames",
        ],
    );
    let truth = tum(&sim.join("truth/2026-01-01.tum"));
    assert_eq!(truth.len(), 64);
    let bag = sim.join("bag/2026-01-01.bag");
    let out = dir.join("loops.csv");
    let o = toporec(&[
        "loops",
        bag.to_str().unwrap(),
        "--index",
        dir.join("index").to_str().unwrap(),
        "--exclude-seconds",
        "10",
        "-o",
        out.to_str().unwrap(),
        "--g2o",
        dir.join("graph.g2o").to_str().unwrap(),
        "--no-progress",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    // The log's odometry (the graph's vertices): from the origin, 2 % long.
    let odometry: Vec<[f64; 2]> = std::fs::read_to_string(dir.join("graph.toporec-plus.g2o"))
        .unwrap()
        .lines()
        .filter_map(|l| l.strip_prefix("VERTEX_SE3:QUAT "))
        .map(|l| {
            let v: Vec<f64> = l.split(' ').map(|w| w.parse().unwrap()).collect();
            [v[1], v[2]]
        })
        .collect();
    assert_eq!(odometry.len(), 64);
    assert!(odometry[0][0].abs() < 1e-6 && odometry[0][1].abs() < 1e-6, "{:?}", odometry[0]);
    let length =
        |p: &[[f64; 2]]| p.windows(2).map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1])).sum::<f64>();
    let truth_xy: Vec<[f64; 2]> = truth.iter().map(|t| [t[1], t[2]]).collect();
    let ratio = length(&odometry) / length(&truth_xy);
    assert!((ratio - 1.02).abs() < 0.01, "{ratio}");
    let corrected: Vec<[f64; 2]> =
        tum(&dir.join("loops.2026-01-01.tum")).iter().map(|t| [t[1], t[2]]).collect();
    let (before, after) = (aligned_rmse(&odometry, &truth_xy), aligned_rmse(&corrected, &truth_xy));
    println!("ATE: odometry {before:.3} m, map {after:.3} m");
    assert!(before > 2.0 && after < 0.25 * before, "{after} against {before}");
}

/// Without the check, `--g2o` writes the graph the map solves all the same: each loop carries
/// toporec-plus's own pose (`x_m`, `y_m`, the yaw) at the map's weaker information (σ = 1 m, so
/// 1 on each axis), and `toporec optimize --robust` reaches the cost the summary gives.
#[test]
fn an_unverified_map_writes_the_graph_it_solves() {
    let dir = scratch_dir("unverified_map_graph");
    let bag = crate::util::root().join("samples/drive.bag");
    let (index, out, stem) = (dir.join("index"), dir.join("loops.csv"), dir.join("graph.g2o"));
    let path = |p: &Path| p.to_str().unwrap().to_string();
    let o = toporec(&[
        "loops",
        &path(&bag),
        "--no-progress",
        "--no-verify",
        "--index",
        &path(&index),
        "-o",
        &path(&out),
        "--g2o",
        &path(&stem),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let stderr = text(&o.stderr);
    let said = stderr.lines().find(|l| l.starts_with("map (toporec-plus)")).expect("a map").to_string();
    let graph = dir.join("graph.toporec-plus.g2o");
    let body = std::fs::read_to_string(&graph).expect("the graph is written without the check");
    let vertices = body.lines().filter(|l| l.starts_with("VERTEX_SE3:QUAT ")).count();
    let edges = g2o_se3_edges(&body);
    let table = std::fs::read_to_string(&out).unwrap();
    let header: Vec<&str> = table.lines().next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let kept: Vec<Vec<&str>> = table.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert!(!kept.is_empty());
    assert_eq!(
        edges.len(),
        vertices - 1 + kept.len(),
        "one session: the odometry's edges, then a loop's per row"
    );
    for (e, row) in edges[vertices - 1..].iter().zip(&kept) {
        let (x, y): (f64, f64) = (row[column("x_m")].parse().unwrap(), row[column("y_m")].parse().unwrap());
        assert!((e[2] - x).abs() < 1e-9 && (e[3] - y).abs() < 1e-9, "edge {e:?}, row {row:?}");
        assert_eq!(e[9], 1.0, "the translation's information at σ = 1 m");
    }
    let o = toporec(&["optimize", &path(&graph), "-o", &path(&dir.join("optimized.g2o")), "--robust"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    // The summary rounds the cost to 3 decimals.
    assert!(
        (solved_cost(&said) - solved_cost(&text(&o.stdout))).abs() <= 5e-4 + 1e-9,
        "{said}\n{}",
        text(&o.stdout)
    );
}

/// A town of 2 × 2 square blocks whose sides look alike, driven twice at 5 m steps (VLP-16,
/// two scans a second), the second lap reversed 3.5 m over, the log's odometry exact: a dozen
/// loops between lookalike sides, 55–94 m from their scans, pass ICP. Given the odometry's own
/// quality (`--odometry-drift 0.005,0.001`), the map rejects every one of them by the odometry
/// alone, keeps every true loop, and stays on the odometry. (With the default model, 2 % and
/// 0.005 rad a metre, σ reaches about 25 m over the 48 steps that three consecutive false loops
/// span, and the three bend the map: docs/loops.md.)
#[test]
fn an_odometry_given_as_good_as_it_is_keeps_the_map_from_lookalike_loops() {
    let dir = scratch_dir("odometry_drift_model");
    let bag = crate::util::simulate_lookalike_laps(&dir.join("sim"));
    let path = |p: &Path| p.to_str().unwrap().to_string();
    let (out, graph) = (dir.join("loops.csv"), dir.join("loops.g2o"));
    let o = toporec(&[
        "loops",
        &path(&bag),
        "--index",
        &path(&dir.join("index")),
        "-o",
        &path(&out),
        "--g2o",
        &path(&graph),
        "--all",
        "--exclude-seconds",
        "10",
        "--odometry-drift",
        "0.005,0.001",
        "--no-progress",
        "-t",
        "2",
    ]);
    let stderr = text(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let table = std::fs::read_to_string(&out).unwrap();
    let header: Vec<&str> = table.lines().next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (mut false_loops, mut true_loops) = (0, 0);
    for l in table.lines().skip(1) {
        let c: Vec<&str> = l.split(',').collect();
        if c[column("verified")] != "true" {
            continue;
        }
        let off: f64 = c[column("true_distance_m")].parse().unwrap();
        if off > 5.0 {
            assert_eq!(c[column("in_map")], "false", "a false loop kept: {l}");
            false_loops += 1;
        } else {
            assert_eq!(c[column("in_map")], "true", "a true loop rejected: {l}");
            true_loops += 1;
        }
    }
    assert!(false_loops >= 10 && true_loops >= 40, "{false_loops} false, {true_loops} true");
    let said = stderr.lines().find(|l| l.starts_with("map (toporec-plus)")).expect("a map");
    assert!(said.contains(&format!("({false_loops} by the odometry alone)")), "{said}");
    let corrected = tum(&dir.join("loops.2026-01-01.tum"));
    let rmse = vertex_rmse(&dir.join("loops.toporec-plus.g2o"), &corrected);
    assert!(rmse < 0.1, "the map {rmse:.3} m from the exact odometry");
}
