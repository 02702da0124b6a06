//! Every method in one index: the committed sample indexed with each (the layout, `verify`,
//! `query --method`, `eval places` side by side, a methods change refused), and vectors made
//! elsewhere imported as one more method.

use crate::util::{self, eval_days, read_json, root};
use toporec::homology::Point;

pub(crate) fn turned(points: &[Point], degrees: f64) -> Vec<Point> {
    let (s, c) = degrees.to_radians().sin_cos();
    points.iter().map(|p| [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]]).collect()
}

/// The committed sample indexed with every method (pipelines/compare.toml asks for TopoRec,
/// toporec-plus, ScanContext and M2DP): the index layout, `verify`, `query --method` (with ScanContext's yaw),
/// `eval places` side by side, and a methods change refused.
#[test]
fn one_run_indexes_every_method_and_query_and_eval_take_each() {
    use crate::util::{run_pipeline, scratch_dir, text, toporec};
    let dir = scratch_dir("multi_method");
    let index = dir.join("index");
    let o = run_pipeline(&root().join("pipelines/compare.toml"), &index, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let said = text(&o.stdout) + &text(&o.stderr);
    assert!(
        said.contains(
            "scancontext (length 1200), scancontext-pp (length 3600), scancontext-pp-cart (length 1600), \
             m2dp (length 192), solid (length 100), lidar-iris (length 72000), ring (length 15300)"
        ),
        "{said}"
    );
    let manifest: serde_json::Value = read_json(&index.join("manifest.json"));
    let methods = manifest["methods"].as_object().unwrap();
    assert_eq!(methods.keys().map(String::as_str).collect::<Vec<_>>(), util::COMPARED[1..]);
    assert_eq!(methods["scancontext"]["length"], 1200);
    assert_eq!(methods["lidar-iris"]["length"], 72000);
    assert_eq!(methods["ring"]["length"], 15300);
    assert_eq!(methods["m2dp"]["length"], 192);
    assert_eq!(methods["solid"]["params"]["fov_up"], 10.67);
    for m in util::COMPARED {
        for s in ["2026-01-01", "2026-01-02"] {
            assert!(index.join(format!("descriptors/method={m}/session={s}")).is_dir(), "{m} {s}");
        }
    }
    let o = toporec(&["verify", "--index", index.to_str().unwrap()]);
    assert!(o.status.success() && text(&o.stdout).contains("ok:"), "{}{}", text(&o.stdout), text(&o.stderr));
    assert!(!text(&o.stderr).contains("note:"), "{}", text(&o.stderr));

    // query: a scan turned by 42 deg is found by ScanContext, with its yaw.
    let day2 = root().join("samples/town/velodyne_data/2026-01-02/velodyne_sync");
    let mut files: Vec<_> = std::fs::read_dir(&day2).unwrap().flatten().map(|e| e.path()).collect();
    files.sort();
    let scan = &files[5];
    let id = format!("2026-01-02/{}", scan.file_stem().unwrap().to_string_lossy());
    let cloud = util::read_cloud(scan);
    let csv = dir.join("turned.csv");
    let mut body = String::from("x,y,z\n");
    for p in turned(&cloud, 42.0) {
        body.push_str(&format!("{:?},{:?},{:?}\n", p[0], p[1], p[2]));
    }
    std::fs::write(&csv, body).unwrap();
    let q = |method: &str, input: &std::path::Path| {
        toporec(&[
            "query",
            "--index",
            index.to_str().unwrap(),
            "--method",
            method,
            "-k",
            "1",
            input.to_str().unwrap(),
        ])
    };
    let o = q("scancontext", &csv);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines[0], toporec::sinks::csv::header(&toporec::sinks::schema::query_hits()));
    let row: Vec<&str> = lines[1].split(',').collect();
    assert_eq!((row[2], row[8]), (id.as_str(), "42.0"), "{out}");
    // SOLiD's range part ignores the turn; its azimuth part gives the yaw.
    let o = q("solid", &csv);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    let row: Vec<&str> = out.lines().nth(1).unwrap().split(',').collect();
    assert_eq!((row[2], row[8]), (id.as_str(), "42.0"), "{out}");
    // LiDAR-Iris: the phase correlation gives the yaw.
    let o = q("lidar-iris", &csv);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    let row: Vec<&str> = out.lines().nth(1).unwrap().split(',').collect();
    assert_eq!((row[2], row[8]), (id.as_str(), "42.0"), "{out}");
    // Scan Context++: the polar context gives the yaw; the Cartesian one finds the scan itself.
    let o = q("scancontext-pp", &csv);
    let out = text(&o.stdout);
    let row: Vec<&str> = out.lines().nth(1).unwrap().split(',').collect();
    assert_eq!((row[2], row[8]), (id.as_str(), "42.0"), "{out}");
    let o = q("scancontext-pp-cart", scan);
    let out = text(&o.stdout);
    let row: Vec<&str> = out.lines().nth(1).unwrap().split(',').collect();
    assert_eq!((row[2], row[4], row[8]), (id.as_str(), "0.0", "0.0"), "{out}");
    // M2DP of the file itself: the very scan, at distance 0 (one scan, one descriptor).
    let o = q("m2dp", scan);
    let out = text(&o.stdout);
    let row: Vec<&str> = out.lines().nth(1).unwrap().split(',').collect();
    assert_eq!((row[2], row[4], row[8]), (id.as_str(), "0.0", ""), "{out}");
    let o = q("pointnetvlad", scan);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o.stderr)
            .contains("holds no descriptors of method `pointnetvlad` (it holds: toporec, lidar-iris, m2dp, ring, scancontext, scancontext-pp, scancontext-pp-cart, solid, toporec-plus)"),
        "{}",
        text(&o.stderr)
    );

    // eval places: every method, side by side, in one report and one Recall@N plot.
    let eval = dir.join("eval");
    let o = eval_days(&index, &eval, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let report: serde_json::Value = read_json(&eval.join("report.json"));
    let r1 = |m: usize| -> Vec<f64> {
        report["methods"][m]["results"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| (r["with_match"]["at_n"][0].as_f64().unwrap() * 32.0 / 100.0).round())
            .collect()
    };
    let names: Vec<&str> =
        report["methods"].as_array().unwrap().iter().map(|m| m["method"].as_str().unwrap()).collect();
    assert_eq!(names, util::COMPARED);
    // Regression values (toporec's own output on the committed sample): R@1 at 5, 10, 20,
    // 50 m, in 32nds of the queries.
    let r1 = |name: &str| r1(names.iter().position(|n| *n == name).unwrap());
    assert_eq!(r1("toporec"), [6.0, 11.0, 13.0, 31.0], "TopoRec");
    assert_eq!(r1("lidar-iris"), [30.0, 30.0, 30.0, 32.0], "LiDAR-Iris");
    assert_eq!(r1("m2dp"), [24.0, 24.0, 26.0, 29.0], "M2DP");
    assert_eq!(r1("scancontext"), [32.0, 32.0, 32.0, 32.0], "ScanContext");
    assert_eq!(r1("scancontext-pp"), [32.0, 32.0, 32.0, 32.0], "Scan Context++, polar");
    assert_eq!(r1("scancontext-pp-cart"), [31.0, 31.0, 31.0, 32.0], "Scan Context++, Cartesian");
    assert_eq!(r1("solid"), [11.0, 13.0, 15.0, 32.0], "SOLiD");
    assert_eq!(r1("toporec-plus"), [32.0, 32.0, 32.0, 32.0], "toporec-plus");
    assert_eq!(r1("ring"), [32.0, 32.0, 32.0, 32.0], "RING");
    for f in
        ["recall_at_n.png", "trajectory_toporec.png", "trajectory_m2dp.png", "trajectory_scancontext.png"]
    {
        assert!(eval.join(f).is_file(), "{f}");
    }
    let sc = names.iter().position(|n| *n == "scancontext").unwrap();
    assert!(report["methods"][sc]["timing_ms"]["rerank"]["mean"].as_f64().unwrap() > 0.0);
    let one = dir.join("eval-m2dp");
    let o = eval_days(&index, &one, &["--method", "m2dp"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let report: serde_json::Value = read_json(&one.join("report.json"));
    assert_eq!(report["methods"].as_array().unwrap().len(), 1);
    assert!(one.join("trajectory.png").is_file());

    // Another set of methods on the same index: refused, with both sets named.
    let toporec_only = dir.join("toporec-only.toml");
    let text_of = std::fs::read_to_string(root().join("pipelines/compare.toml")).unwrap();
    let base = root().join("pipelines").display().to_string();
    let edited = text_of
        .replace(
            "methods = [\"toporec\", \"toporec-plus\", \"scancontext\", \"scancontext-pp\", \"scancontext-pp-cart\", \"m2dp\", \"solid\", \"lidar-iris\", \"ring\"]",
            "methods = [\"toporec\", \"m2dp\"]",
        )
        .replace("\"../", &format!("\"{base}/../"));
    assert!(
        edited.contains("methods = [\"toporec\", \"m2dp\"]"),
        "the methods line of pipelines/compare.toml"
    );
    std::fs::write(&toporec_only, edited).unwrap();
    let o = run_pipeline(&toporec_only, &index, 2);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert!(
        text(&o.stderr).contains("holds the descriptor methods [toporec, lidar-iris"),
        "{}",
        text(&o.stderr)
    );
}

/// `toporec import`: vectors made elsewhere (here, copies of the index's own TopoRec
/// descriptors) become one more method, in each accepted format; `eval` ranks them exactly as the
/// originals; bad files are refused whole.
#[test]
fn imported_vectors_are_one_more_method() {
    use crate::util::{run_pipeline, scratch_dir, text, toporec};
    let dir = scratch_dir("import");
    let index = dir.join("index");
    let o = run_pipeline(&root().join("pipelines/sample.toml"), &index, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let rows = toporec::sinks::index::IndexReader::open(&index).unwrap().descriptors(&[], None).unwrap();
    assert_eq!(rows.len(), 64);
    // CSV with a header, .npy (float32) with an id list, Parquet with a List<float64> column.
    let mut csv = String::from("scan_id");
    (0..rows[0].descriptor.len()).for_each(|i| csv.push_str(&format!(",v{i}")));
    csv.push('\n');
    for r in &rows {
        csv.push_str(&r.scan_id);
        r.descriptor.iter().for_each(|v| csv.push_str(&format!(",{v:?}")));
        csv.push('\n');
    }
    std::fs::write(dir.join("copy.csv"), &csv).unwrap();
    let (n, d) = (rows.len(), rows[0].descriptor.len());
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({n}, {d}), }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut npy = b"\x93NUMPY\x01\x00".to_vec();
    npy.extend((header.len() as u16).to_le_bytes());
    npy.extend(header.as_bytes());
    rows.iter().flat_map(|r| r.descriptor.iter()).for_each(|v| npy.extend(v.to_le_bytes()));
    std::fs::write(dir.join("copy.npy"), npy).unwrap();
    let ids: String = rows.iter().map(|r| format!("{}\n", r.scan_id)).collect();
    std::fs::write(dir.join("copy.ids"), ids).unwrap();
    {
        use arrow::array::{ArrayRef, Float64Builder, ListBuilder, StringArray};
        let mut list = ListBuilder::new(Float64Builder::new());
        for r in &rows {
            r.descriptor.iter().for_each(|&v| list.values().append_value(v as f64));
            list.append(true);
        }
        let ids: ArrayRef =
            std::sync::Arc::new(StringArray::from_iter_values(rows.iter().map(|r| r.scan_id.clone())));
        let batch = arrow::array::RecordBatch::try_from_iter([
            ("scan_id", ids),
            ("descriptor", std::sync::Arc::new(list.finish()) as ArrayRef),
        ])
        .unwrap();
        let file = std::fs::File::create(dir.join("copy.parquet")).unwrap();
        let mut w = parquet::arrow::ArrowWriter::try_new(file, batch.schema(), None).unwrap();
        w.write(&batch).unwrap();
        w.close().unwrap();
    }
    let import = |method: &str, file: &str, extra: &[&str]| {
        let f = dir.join(file);
        let mut a =
            vec!["import", "--index", index.to_str().unwrap(), "--method", method, f.to_str().unwrap()];
        a.extend(extra);
        toporec(&a)
    };
    let ids_path = dir.join("copy.ids");
    for (method, file, extra) in [
        ("copy-csv", "copy.csv", vec![]),
        ("copy_npy", "copy.npy", vec!["--ids", ids_path.to_str().unwrap()]),
        ("copy-parquet", "copy.parquet", vec![]),
    ] {
        let o = import(method, file, &extra);
        assert!(o.status.success(), "{method}: {}", text(&o.stderr));
        assert!(text(&o.stdout).contains("64 scans, length 50"), "{}", text(&o.stdout));
    }
    // Again: replaced, not added.
    let o = import("copy-csv", "copy.csv", &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let o = toporec(&["verify", "--index", index.to_str().unwrap()]);
    assert!(o.status.success(), "{}{}", text(&o.stdout), text(&o.stderr));

    // eval ranks the copies exactly as the originals.
    let out = dir.join("eval");
    let o = eval_days(&index, &out, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let report: serde_json::Value = read_json(&out.join("report.json"));
    let methods = report["methods"].as_array().unwrap();
    let names: Vec<&str> = methods.iter().map(|m| m["method"].as_str().unwrap()).collect();
    assert_eq!(names, ["toporec", "copy-csv", "copy-parquet", "copy_npy"]);
    for m in &methods[1..] {
        assert_eq!(m["results"], methods[0]["results"], "{}", m["method"]);
    }
    // query cannot describe a new scan with vectors made elsewhere.
    let scan = root().join("samples/town/velodyne_data/2026-01-02/velodyne_sync/1767348000000000.bin");
    let o = toporec(&[
        "query",
        "--index",
        index.to_str().unwrap(),
        "--method",
        "copy-csv",
        scan.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("has its vectors imported"), "{}", text(&o.stderr));
    // An up-to-date run keeps them.
    let o = run_pipeline(&root().join("pipelines/sample.toml"), &index, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let m: serde_json::Value = read_json(&index.join("manifest.json"));
    assert_eq!(m["methods"].as_object().unwrap().len(), 3);

    // Refused whole: an unknown id, a wrong length, a reserved name, .npy without ids.
    let bad = csv.replace("2026-01-01/1767261600000000,", "nowhere/1,");
    std::fs::write(dir.join("unknown.csv"), bad).unwrap();
    let o = import("bad", "unknown.csv", &[]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o.stderr).contains("1 scan ids are not in") && text(&o.stderr).contains("nowhere/1"),
        "{}",
        text(&o.stderr)
    );
    let mut short = csv.clone();
    short.push_str("2026-01-01/1767261600000000,1.0\n");
    std::fs::write(dir.join("short.csv"), short).unwrap();
    let o = import("bad", "short.csv", &[]);
    assert!(text(&o.stderr).contains("line 66") || text(&o.stderr).contains("row 65"), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("1 values, the first row has 50"), "{}", text(&o.stderr));
    let o = import("scancontext", "copy.csv", &[]);
    assert!(text(&o.stderr).contains("the name of a computed method"), "{}", text(&o.stderr));
    let o = import("bad", "copy.npy", &[]);
    assert!(text(&o.stderr).contains("give them with --ids"), "{}", text(&o.stderr));
    let m: serde_json::Value = read_json(&index.join("manifest.json"));
    assert!(m["methods"].get("bad").is_none(), "nothing of a refused import is committed");
}
