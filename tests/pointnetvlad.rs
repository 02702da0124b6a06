//! The PointNetVLAD benchmark: a benchmark-layout folder made from a simulated drive, read by
//! the `pointnetvlad` source, evaluated by `eval places --protocol pointnetvlad`, against a
//! transcription of the benchmark's own scripts and against a hand-computed example.

use crate::util::*;
use std::path::{Path, PathBuf};
use toporec::homology::Point;

/// A submap to write: timestamp, (northing, easting), points.
type Submap = (i64, [f64; 2], Vec<Point>);

/// Writes one submap: 4096 points as float64 (x, y, z per point), as the benchmark ships them.
fn write_submap(path: &Path, points: &[Point]) {
    let mut bytes = Vec::with_capacity(4096 * 24);
    for i in 0..4096 {
        let p = points[i % points.len()];
        p.iter().for_each(|c| bytes.extend(c.to_le_bytes()));
    }
    std::fs::write(path, bytes).unwrap();
}

/// An in-house benchmark folder of 5 runs (the business area) from a simulated drive: each
/// scan subsampled to 4096 points, centred and scaled into [−1, 1]; centroids at the poses,
/// moved into UTM-like coordinates.
fn benchmark_from_simulation(dir: &Path, scans: usize) -> PathBuf {
    let sim = dir.join("sim");
    let o = toporec(&[
        "simulate",
        "-o",
        sim.to_str().unwrap(),
        "--format",
        "nclt",
        "--sessions",
        "5",
        "--scans",
        &scans.to_string(),
        "--seed",
        "3",
        "--azimuth-res",
        "1.0",
        "--rate",
        "2",
        "--blocks",
        "3",
        "--block-size",
        "40",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let root = dir.join("benchmark_datasets");
    let spec = toporec::sources::SourceSpec::new(
        toml::from_str::<toporec::sources::nclt::NcltSpec>(&format!(
            "sessions = [{:?}]",
            sim.join("velodyne_data").display().to_string()
        ))
        .unwrap(),
    );
    let mut by_session: std::collections::BTreeMap<String, Vec<Submap>> = Default::default();
    for scan in spec.open().unwrap() {
        let scan = scan.unwrap();
        let pose = scan.pose.unwrap();
        let mut pts = scan.points;
        toporec::preprocess::normalize(&mut pts);
        let step = (pts.len() / 4096).max(1);
        let pts: Vec<Point> = pts.into_iter().step_by(step).take(4096).collect();
        by_session.entry(scan.session.clone()).or_default().push((
            scan.utime.unwrap(),
            [360000.0 + pose.x, 140000.0 + pose.y],
            pts,
        ));
    }
    assert_eq!(by_session.len(), 5);
    for (k, (_, rows)) in by_session.into_iter().enumerate() {
        let run = root.join(format!("inhouse_datasets/business_run{k}"));
        std::fs::create_dir_all(run.join("pointcloud_25m_25")).unwrap();
        let mut csv = String::from("timestamp,northing,easting\n");
        for (t, [n, e], pts) in rows {
            write_submap(&run.join(format!("pointcloud_25m_25/{t}.bin")), &pts);
            csv.push_str(&format!("{t},{n:?},{e:?}\n"));
        }
        std::fs::write(run.join("pointcloud_centroids_25.csv"), csv).unwrap();
    }
    root
}

fn pipeline(dir: &Path, root: &Path, methods: &str) -> PathBuf {
    let p = dir.join("pnv.toml");
    let text = format!(
        "[output]\nindex = {:?}\n[[sources]]\nkind = \"pointnetvlad\"\nroot = {:?}\n[vectorize]\nb = 16\n[descriptors]\nmethods = {methods}\n",
        dir.join("index").display().to_string(),
        root.display().to_string()
    );
    std::fs::write(&p, text).unwrap();
    p
}

/// The protocol on a generated benchmark folder equals the transcription of
/// `generate_test_sets.py` + `evaluate.py` (`scripts/pointnetvlad_reference.py`), within 1e-9.
#[test]
fn pointnetvlad_protocol_matches_the_reference_scripts() {
    let dir = scratch_dir("pointnetvlad");
    let root = benchmark_from_simulation(&dir, 16);
    // The source reads the folder as it ships: 5 runs, 16 submaps each, poses from the CSVs.
    let index = dir.join("index");
    let o = run_pipeline(&pipeline(&dir, &root, "[\"toporec\", \"m2dp\"]"), &index, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("scans: 80 read, 80 indexed"), "{}", text(&o.stderr));
    let out = dir.join("eval");
    let o = toporec(&[
        "eval",
        "places",
        "--protocol",
        "pointnetvlad",
        "--db",
        index.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    println!("{}", text(&o.stdout));
    let ours = read_json(&out.join("report.json"));
    if !python_with("pointnetvlad_protocol_matches_the_reference_scripts", &["numpy", "pyarrow", "sklearn"]) {
        return;
    }
    for (i, method) in ["toporec", "m2dp"].iter().enumerate() {
        let o = std::process::Command::new("python3")
            .arg(crate::util::root().join("scripts/pointnetvlad_reference.py"))
            .args([root.to_str().unwrap(), index.to_str().unwrap(), method])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
        let theirs: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let mine = &ours["methods"][i];
        assert_eq!(mine["method"], *method);
        let business = &mine["datasets"][0];
        assert_eq!(business["dataset"], "business");
        assert_eq!(business["pairs"], theirs["business"]["pairs"], "{method}");
        let a: Vec<f64> =
            business["recall_at_n"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let b: Vec<f64> = theirs["business"]["recall_at_n"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert_eq!(a.len(), 25);
        let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(worst < 1e-9, "{method}: Recall@N differs by {worst}: {a:?} vs {b:?}");
        let one = business["recall_at_one_percent"].as_f64().unwrap();
        let one_ref = theirs["business"]["recall_at_one_percent"].as_f64().unwrap();
        assert!((one - one_ref).abs() < 1e-9, "{method}: Recall@1% {one} vs {one_ref}");
        println!(
            "{method}: business, {} pairs, R@1 {:.2}, R@1% {one:.2} (reference {one_ref:.2})",
            business["pairs"], a[0]
        );
    }
}

/// A hand-computed case: 5 runs of 2 submaps (A and B, 100 m apart), with imported
/// one-value descriptors that swap A and B in the last run. Of the 20 run pairs, the 8 that
/// involve the last run find the true match at rank 2, the 12 others at rank 1: Recall@1 =
/// Recall@1 % (the top 1 of 2) = 60 %, Recall@2.. = 100 %.
#[test]
fn pointnetvlad_metric_on_a_hand_computed_example() {
    let dir = scratch_dir("pointnetvlad_hand");
    let root = dir.join("benchmark_datasets");
    let mut rng = toporec::rng::SplitMix64(5);
    let mut ids = String::from("scan_id,value\n");
    for k in 0..5 {
        let run = root.join(format!("inhouse_datasets/business_run{k}"));
        std::fs::create_dir_all(run.join("pointcloud_25m_25")).unwrap();
        let mut csv = String::from("timestamp,northing,easting\n");
        for (t, northing) in [(1000 + k, 360000.0), (2000 + k, 360100.0)] {
            let pts: Vec<Point> = (0..4096)
                .map(|_| [rng.next_f64() - 0.5, rng.next_f64() - 0.5, rng.next_f64() - 0.5])
                .collect();
            write_submap(&run.join(format!("pointcloud_25m_25/{t}.bin")), &pts);
            csv.push_str(&format!("{t},{northing:?},140000.0\n"));
            let a_is_zero = (t < 2000) != (k == 4);
            ids.push_str(&format!("business_run{k}/{t},{}\n", if a_is_zero { 0.0 } else { 10.0 }));
        }
        std::fs::write(run.join("pointcloud_centroids_25.csv"), csv).unwrap();
    }
    let index = dir.join("index");
    let o = run_pipeline(&pipeline(&dir, &root, "[\"m2dp\"]"), &index, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    std::fs::write(dir.join("hand.csv"), ids).unwrap();
    let f = dir.join("hand.csv");
    let o = toporec(&["import", "--index", index.to_str().unwrap(), "--method", "hand", f.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = dir.join("eval");
    let o = toporec(&[
        "eval",
        "places",
        "--protocol",
        "pointnetvlad",
        "--db",
        index.to_str().unwrap(),
        "--method",
        "hand",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let r = &read_json(&out.join("report.json"))["methods"][0]["datasets"][0];
    assert_eq!(r["pairs"], 20);
    assert_eq!(r["recall_at_n"][0].as_f64().unwrap(), 60.0);
    assert_eq!(r["recall_at_n"][1].as_f64().unwrap(), 100.0);
    assert_eq!(r["recall_at_one_percent"].as_f64().unwrap(), 60.0);
    // The protocol pairs the benchmark's own runs: session flags are refused.
    let o = toporec(&[
        "eval",
        "places",
        "--protocol",
        "pointnetvlad",
        "--db",
        index.to_str().unwrap(),
        "--db-session",
        "x",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
}

/// Bad benchmark files: a submap of another size is an error of that scan, naming the file (the
/// others are indexed, exit 1); a bad CSV line names the file and the line (`file:line:`); a folder that is not
/// the benchmark is refused.
#[test]
fn pointnetvlad_bad_files() {
    let dir = scratch_dir("pointnetvlad_bad");
    let root = dir.join("benchmark_datasets");
    let run = root.join("oxford/2014-05-19-13-20-57");
    std::fs::create_dir_all(run.join("pointcloud_20m")).unwrap();
    let pts: Vec<Point> = (0..4096)
        .map(|i| [(i % 16) as f64 / 16.0, (i / 16 % 16) as f64 / 16.0, (i / 256) as f64 / 16.0])
        .collect();
    write_submap(&run.join("pointcloud_20m/100.bin"), &pts);
    std::fs::write(run.join("pointcloud_20m/200.bin"), vec![0u8; 4096 * 8]).unwrap();
    std::fs::write(
        run.join("pointcloud_locations_20m.csv"),
        "timestamp,northing,easting\n100,5735712.0,620084.0\n200,5735713.0,620085.0\n",
    )
    .unwrap();
    let o = run_pipeline(&pipeline(&dir, &root, "[\"m2dp\"]"), &dir.join("index"), 1);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    let err = text(&o.stderr);
    assert!(
        err.contains("200.bin")
            && err.contains("32768 bytes; a PointNetVLAD submap is 4096 x 3 float64 values"),
        "{err}"
    );
    assert!(!err.contains("panicked at"), "{err}");
    std::fs::write(run.join("pointcloud_locations_20m.csv"), "timestamp,northing,easting\n100,5735712.0\n")
        .unwrap();
    let o = run_pipeline(&pipeline(&dir, &root, "[\"m2dp\"]"), &dir.join("index2"), 1);
    let err = text(&o.stderr);
    assert!(err.contains("pointcloud_locations_20m.csv:2: expected timestamp,northing,easting"), "{err}");
    let o = run_pipeline(&pipeline(&dir, &dir.join("index"), "[\"m2dp\"]"), &dir.join("index3"), 1);
    let err = text(&o.stderr);
    assert!(err.contains("not a PointNetVLAD benchmark folder"), "{err}");
    assert!(!err.contains("panicked at"), "{err}");
}
