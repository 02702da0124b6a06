//! `toporec optimize`: public and made-up g2o graphs, the robust cost, and bad input.

use crate::util::{python_with, scratch_dir, shared_data, text, toporec};
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
