//! Search, metrics, `query`, `eval places`, `eval perturbation` and plots.

use crate::util::*;
use toporec::eval::metrics::{Denominator, first_hit, one_percent_k, recall};
use toporec::methods::euclidean::Database;
use toporec::rng::SplitMix64;

#[test]
fn recall_metrics_on_hand_made_cases() {
    // Python 3 rounding (half to even) for the Recall@1% k.
    assert_eq!([50, 149, 150, 250, 350, 1000, 1].map(one_percent_k), [1, 1, 2, 2, 4, 10, 1]);
    // 4 queries, n_db = 300 (k1 = 3): hits at rank 0, 2, none-with-match, none-without-match.
    let hits = [Some(0), Some(2), None, None];
    let has = [true, true, true, false];
    let with = recall(&hits, &has, 5, 300, Denominator::WithMatch);
    assert_eq!(with.evaluated, 3);
    let third = 100.0 / 3.0;
    assert_eq!(with.at_n, vec![third, third, 2.0 * third, 2.0 * third, 2.0 * third]);
    assert_eq!((with.one_percent_k, with.at_one_percent), (3, 2.0 * third));
    let all = recall(&hits, &has, 5, 300, Denominator::All);
    assert_eq!(
        (all.evaluated, all.at_n[0], all.at_one_percent),
        (4, 25.0, 50.0),
        "a query without match is a failure"
    );
    assert_eq!(recall(&[], &[], 3, 10, Denominator::All).at_n, vec![0.0; 3], "no queries: 0, not NaN");
    // First hit over a retrieval list.
    assert_eq!(first_hit(&[7, 3, 9], |r| r == 9), Some(2));
    assert_eq!(first_hit(&[7, 3], |r| r == 9), None);
    // Ties in distance go to the lower row, on every route.
    for b in [2, 40] {
        let mut v = vec![0.0f32; 4 * b];
        v[0] = 1.0; // row 0 at distance 1 from the origin
        v[b] = -1.0; // row 1 at distance 1 too
        v[2 * b] = 3.0;
        v[3 * b + 1] = 1.0; // row 3 at distance 1
        let db = Database::new(v, b);
        let hits: Vec<usize> = db.search(&vec![0.0; b], 3).iter().map(|h| h.0).collect();
        assert_eq!(hits, [0, 1, 3], "b = {b}");
    }
}

#[test]
fn every_search_route_equals_brute_force() {
    let mut rng = SplitMix64(9);
    for (n, b) in [(3000, 3), (3000, 8), (3000, 13), (2500, 50), (800, 300)] {
        let data: Vec<f32> = (0..n * b).map(|_| (rng.next_f64() * 4.0).powi(2) as f32).collect();
        let db = Database::new(data, b);
        let queries: Vec<f32> = (0..70 * b).map(|_| (rng.next_f64() * 4.0).powi(2) as f32).collect();
        let many = db.search_many(&queries, 10);
        for (i, q) in queries.chunks(b).enumerate() {
            let brute = db.brute_force(q, 10);
            assert_eq!(many[i], brute, "n {n} b {b} query {i} (batched)");
            assert_eq!(db.search(q, 10), brute, "n {n} b {b} query {i} (single)");
        }
        // k larger than the database.
        assert_eq!(db.search(&queries[..b], n + 5).len(), n);
    }
}

/// A real `report.json` validates against `schemas/report.json` (a JSON Schema validator, where
/// one is installed).
fn assert_matches_report_schema(report: &std::path::Path) {
    if !python_with("report JSON Schema validation", &["jsonschema"]) {
        return;
    }
    let script = format!(
        "import json, jsonschema; jsonschema.validate(json.load(open({:?})), json.load(open({:?})))",
        report.display().to_string(),
        root().join("schemas/report.json").display().to_string()
    );
    let o = std::process::Command::new("python3").args(["-c", &script]).output().unwrap();
    assert!(o.status.success(), "{}: {}", report.display(), text(&o.stderr));
}

#[test]
fn query_and_eval_places_on_the_sample_and_on_nclt() {
    let dir = scratch_dir("eval_places");
    let index = dir.join("index");
    let o = run_pipeline(&root().join("pipelines/sample.toml"), &index, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));

    // Query with a whole session: each scan finds itself first, at distance 0.
    let session = root().join("samples/town/velodyne_data/2026-01-02");
    let o = toporec(&["query", "--index", index.to_str().unwrap(), session.to_str().unwrap(), "-k", "3"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    let rows: Vec<Vec<&str>> = out.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 32 * 3);
    for r in rows.iter().filter(|r| r[1] == "1") {
        assert_eq!((r[0], r[4]), (r[2], "0.0"), "{r:?}");
    }
    assert!(text(&o.stderr).contains("per query (mean / p95 ms): persistence"), "{}", text(&o.stderr));

    // Day 2 against day 1.
    let eval = dir.join("eval");
    let o = eval_days(&index, &eval, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let report: serde_json::Value = read_json(&eval.join("report.json"));
    assert_matches_report_schema(&eval.join("report.json"));
    let m = &report["methods"][0];
    assert_eq!(m["method"], "toporec");
    assert_eq!(m["database_scans"], 32);
    assert_eq!(m["one_percent_k"], 1);
    let results = m["results"].as_array().unwrap();
    assert_eq!(
        results.iter().map(|r| r["threshold_m"].as_f64().unwrap()).collect::<Vec<_>>(),
        [5.0, 10.0, 20.0, 50.0]
    );
    for r in results {
        let at_n = r["with_match"]["at_n"].as_array().unwrap();
        assert_eq!(at_n.len(), 25);
        let v: Vec<f64> = at_n.iter().map(|x| x.as_f64().unwrap()).collect();
        assert!(v.windows(2).all(|w| w[0] <= w[1]), "Recall@N is non-decreasing");
        assert_eq!(r["all_queries"]["evaluated"], 32);
    }
    // The largest threshold covers the 160 m loop: every query has a match.
    assert_eq!(results[3]["with_match"]["evaluated"], 32);
    // Regression values (toporec's own output on the committed sample, no outside reference):
    // R@1 at 5, 10, 20, 50 m is 6, 11, 13 and 31 of 32 queries.
    let r1: Vec<f64> = results.iter().map(|r| r["with_match"]["at_n"][0].as_f64().unwrap()).collect();
    assert_eq!(r1, [600.0 / 32.0, 1100.0 / 32.0, 1300.0 / 32.0, 3100.0 / 32.0], "R@1 at 5, 10, 20, 50 m");
    for f in ["recall_at_n.png", "recall_at_n.svg", "trajectory.png", "trajectory.svg", "report.txt"] {
        assert!(eval.join(f).metadata().unwrap().len() > 500, "{f}");
    }
    // A persistence diagram plot.
    let stem = dir.join("diagram");
    let id = rows[0][2];
    let o = toporec(&[
        "plot",
        "diagram",
        "--index",
        index.to_str().unwrap(),
        "--scan",
        id,
        "-o",
        stem.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(dir.join("diagram.png").is_file() && dir.join("diagram.svg").is_file());
    let o = toporec(&[
        "plot",
        "diagram",
        "--index",
        index.to_str().unwrap(),
        "--scan",
        "nope",
        "-o",
        stem.to_str().unwrap(),
    ]);
    assert!(text(&o.stderr).contains("no scan nope"), "{}", text(&o.stderr));

    // nclt_from_kitti against itself (a query never retrieves itself).
    let Some(_) = shared_data("eval places on nclt_from_kitti") else { return };
    let nidx = dir.join("nclt");
    let o = run_pipeline(&root().join("pipelines/nclt.toml"), &nidx, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let neval = dir.join("nclt-eval");
    let o = toporec(&["eval", "places", "--db", nidx.to_str().unwrap(), "-o", neval.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let report: serde_json::Value = read_json(&neval.join("report.json"));
    assert_eq!(report["methods"][0]["query_scans"], 14);
    // Regression values (toporec's own output; the 14 scans are not revisits, so this is a
    // check of the protocol on real geometry, not a claim): R@1 is 9 of 14 at 5 m and 14 of 14
    // from 10 m.
    let r1: Vec<f64> = report["methods"][0]["results"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["with_match"]["at_n"][0].as_f64().unwrap())
        .collect();
    assert_eq!(r1, [900.0 / 14.0, 100.0, 100.0, 100.0], "R@1 at 5, 10, 20, 50 m");
}

#[test]
fn perturbation_protocol_on_kitti() {
    let Some(_) = shared_data("perturbation_protocol_on_kitti") else { return };
    let dir = scratch_dir("eval_perturbation");
    let index = dir.join("index");
    let o = run_pipeline(&root().join("pipelines/kitti.toml"), &index, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = dir.join("eval");
    let o = toporec(&[
        "eval",
        "perturbation",
        "--index",
        index.to_str().unwrap(),
        "--fraction",
        "1",
        // R@1 alone is asserted: the same as at the default N of 25, without the relative
        // poses of 24 more hits a query (RING's and RING++'s are most of this test's time).
        "--max-n",
        "1",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    println!("{}", text(&o.stdout));
    let report: serde_json::Value = read_json(&out.join("report.json"));
    assert_matches_report_schema(&out.join("report.json"));
    assert_eq!(report["queries"], 48);
    // Original, translation and rotations about z: the descriptor is invariant, so 48 of 48.
    // Jitter and scaling: regression values (toporec's own output: 45, 48 and 47 of 48; the
    // paper reports 100 %, 68.25 % and 71.43 % on KITTI-360, not comparable scan for scan).
    let expected = [
        ("original", 100.0),
        ("jitter", 4500.0 / 48.0),
        ("scale x1.05", 100.0),
        ("scale x0.95", 4700.0 / 48.0),
        ("translate (0.2, 0.2, 0.1)", 100.0),
        ("rotate 45 deg", 100.0),
        ("rotate 90 deg", 100.0),
        ("rotate 135 deg", 100.0),
    ];
    let got: Vec<(String, f64)> = report["methods"][0]["results"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| (r["perturbation"].as_str().unwrap().to_string(), r["recall"]["at_n"][0].as_f64().unwrap()))
        .collect();
    assert_eq!(got, expected.map(|(n, r)| (n.to_string(), r)), "R@1 per perturbation");
    for k in ["persistence", "vectorize", "search"] {
        assert!(report["methods"][0]["timing_ms"][k]["p95"].as_f64().unwrap() > 0.0, "{k}");
    }
    // The baselines beside it (pipelines/kitti.toml asks for them), on the raw scans perturbed
    // alike (lengths in units of each scan's normalization scale, turns about the sensor).
    // Regression values (toporec's own output): R@1 per perturbation, in 48ths.
    let methods: Vec<&str> =
        report["methods"].as_array().unwrap().iter().map(|m| m["method"].as_str().unwrap()).collect();
    assert_eq!(methods, EVERY_METHOD);
    let r1 = |name: &str| -> Vec<f64> {
        let m = methods.iter().position(|m| *m == name).unwrap_or_else(|| panic!("{name}: {methods:?}"));
        report["methods"][m]["results"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| (r["recall"]["at_n"][0].as_f64().unwrap() * 48.0 / 100.0).round())
            .collect()
    };
    // M2DP: invariant to shifts and scale, not to turns (its PCA sign convention).
    assert_eq!(r1("m2dp"), [48.0, 48.0, 48.0, 48.0, 48.0, 18.0, 5.0, 1.0], "M2DP R@1");
    // ScanContext: turns are column shifts (exact for 90 deg, half a sector off for 45 and
    // 135 deg); a shift of 0.2 normalized units is metres of sensor motion.
    assert_eq!(r1("scancontext"), [48.0, 48.0, 48.0, 48.0, 1.0, 34.0, 48.0, 34.0], "ScanContext R@1");
    // toporec-plus: turns by whole sectors are shifts (exact at 90 deg), turns between them the
    // query's interpolated columns (45 and 135 deg also turn the height field's squares against
    // the scan; the fine stage's offset keeps the right scan first); a 5 % scaling moves
    // structures across squares and rings and the image's cells (2 of 48 larger, 4 smaller: the
    // scan against itself, the offset is 0, and with the vehicle's cells left out of the image a
    // neighbouring frame of its sequence is posed as near twice more); a shift of
    // metres moves the sensor, as for ScanContext (its lateral views find 2 of 48 still).
    // SOLiD: counts per range and elevation bin, blind to turns; scaling moves points across
    // range bins; a shift of metres moves the sensor.
    assert_eq!(r1("solid"), [48.0, 48.0, 23.0, 22.0, 0.0, 48.0, 48.0, 48.0], "SOLiD R@1");
    assert_eq!(r1("toporec-plus"), [48.0, 48.0, 46.0, 44.0, 2.0, 48.0, 48.0, 48.0], "toporec-plus R@1");
    // LiDAR-Iris: a turn is a column shift of its 1° columns, which the phase correlation finds
    // (45° and 135° as well as 90°); a 5 % scaling moves points across its 1 m rows (2 of 48
    // at ×1.05); a shift of metres moves the sensor.
    assert_eq!(r1("lidar-iris"), [48.0, 48.0, 46.0, 48.0, 0.0, 48.0, 48.0, 48.0], "LiDAR-Iris R@1");
    // Scan Context++: the polar context as ScanContext (its root-shifted copies do not help a
    // turn; one scan of 48 fewer at 45° and 135°). The Cartesian context is not turn-invariant:
    // a turn other than 180° reshapes it.
    assert_eq!(
        r1("scancontext-pp"),
        [48.0, 48.0, 48.0, 48.0, 1.0, 33.0, 48.0, 33.0],
        "Scan Context++ polar R@1"
    );
    assert_eq!(
        r1("scancontext-pp-cart"),
        [48.0, 48.0, 47.0, 46.0, 2.0, 2.0, 0.0, 2.0],
        "Scan Context++ Cartesian R@1"
    );
    // RING: a turn rolls its sinogram's rows by whole 3° steps or between them (found either
    // way); a 5 % scaling moves occupied cells; a shift of the normalized 0.2 units moves the
    // sensor by metres the 1.17 m cells and the crop to 70 m see (its invariance is to the
    // phases of a cropped grid, not to a new view).
    assert_eq!(r1("ring"), [48.0, 48.0, 44.0, 43.0, 2.0, 48.0, 48.0, 48.0], "RING R@1");
    // RING++: RING's steps on six feature grids; after the shift it finds 25 of 48 (RING 2).
    assert_eq!(r1("ring-plus"), [48.0, 48.0, 45.0, 43.0, 25.0, 47.0, 48.0, 47.0], "RING++ R@1");
    for k in ["describe", "search"] {
        let m2dp = methods.iter().position(|m| *m == "m2dp").unwrap();
        assert!(report["methods"][m2dp]["timing_ms"][k]["p95"].as_f64().unwrap() > 0.0, "m2dp {k}");
    }
    for k in ["describe", "candidates", "rerank"] {
        let sc = methods.iter().position(|m| *m == "scancontext").unwrap();
        assert!(report["methods"][sc]["timing_ms"][k]["p95"].as_f64().unwrap() > 0.0, "scancontext {k}");
    }
}
