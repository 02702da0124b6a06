//! Odd but possible input, through the built binary: each case ends in the right answer or a
//! one-line error naming the input (file, flag or key), never a hang, a panic or a wrong
//! result, and within 20 s.

use crate::util::*;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

/// Runs `toporec args` (in `dir`), failing the test if it takes more than 20 s.
fn within_20s(args: &[&str], dir: &Path) -> Output {
    let child = Command::new(env!("CARGO_BIN_EXE_toporec"))
        .args(args)
        .current_dir(dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    match rx.recv_timeout(Duration::from_secs(20)) {
        Ok(o) => o.unwrap(),
        Err(_) => {
            let _ = Command::new("kill").args(["-9", &pid.to_string()]).status();
            panic!("toporec {args:?} did not finish within 20 s (a hang)");
        }
    }
}

/// One row of the table: the exit code, and for failures a single line naming `names`.
fn check(case: &str, o: &Output, code: i32, names: &[&str]) {
    let err = text(&o.stderr);
    assert!(!err.contains("panicked at"), "{case}: panicked: {err}");
    assert_eq!(o.status.code(), Some(code), "{case}: exit code; stderr: {err}");
    if code == 2 {
        let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error")).collect();
        assert_eq!(lines.len(), 1, "{case}: one error line: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{case}: nothing but the error: {err}");
        for n in names {
            assert!(lines[0].contains(n), "{case}: `{n}` not named in: {}", lines[0]);
        }
    }
    println!("ok  {case}: exit {code}");
}

/// A copy of the sample drive, its day-1 ground truth with one row made `value`.
fn sample_with_bad_pose(dir: &Path, value: &str) -> PathBuf {
    let data = dir.join("town");
    let o = Command::new("cp")
        .args(["-r", root().join("samples/town").to_str().unwrap(), data.to_str().unwrap()])
        .status();
    assert!(o.unwrap().success());
    let gt = data.join("ground_truth/groundtruth_2026-01-01.csv");
    let text = std::fs::read_to_string(&gt).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let mut fields: Vec<String> = lines[3].split(',').map(String::from).collect();
    fields[1] = value.to_string();
    lines[3] = fields.join(",");
    std::fs::write(&gt, lines.join("\n") + "\n").unwrap();
    let pipeline = dir.join("p.toml");
    let sample = std::fs::read_to_string(root().join("pipelines/sample.toml")).unwrap();
    let body = sample
        .replace(
            "\"../samples/town/velodyne_data\"",
            &format!("{:?}", data.join("velodyne_data").display().to_string()),
        )
        .replace("subsample = 4096", "subsample = 512")
        .replace("b = 50 ", "b = 8 ");
    std::fs::write(&pipeline, body).unwrap();
    pipeline
}

#[test]
fn bad_inputs_table() {
    let dir = scratch_dir("bad_inputs");
    let d = dir.as_path();
    let run = |args: &[&str]| within_20s(args, d);

    // 1. A ground-truth row with `inf`: the run indexes the scan without a pose and says so;
    //    `eval places` leaves it out, says how many, and finishes (with its plots).
    let pipeline = sample_with_bad_pose(d, "inf");
    let o = run(&["run", pipeline.to_str().unwrap(), "--index", "idx", "--no-progress"]);
    check("ground truth with inf: run", &o, 0, &[]);
    assert!(
        text(&o.stderr).contains("without a pose (a non-finite ground-truth pose): 1"),
        "{}",
        text(&o.stderr)
    );
    let o = run(&[
        "eval",
        "places",
        "--db",
        "idx",
        "--db-session",
        "2026-01-02",
        "--query-session",
        "2026-01-01",
        "-o",
        "ev",
    ]);
    check("ground truth with inf: eval places", &o, 0, &[]);
    assert!(
        text(&o.stdout).contains("left out, without a pose: 0 database and 1 query scans"),
        "{}",
        text(&o.stdout)
    );
    assert!(d.join("ev/report.json").is_file() && d.join("ev/trajectory.png").is_file());
    let o = run(&["inspect", dir.join("town/velodyne_data").to_str().unwrap()]);
    check("ground truth with inf: inspect", &o, 0, &[]);
    assert!(
        text(&o.stdout).contains("without a pose (a non-finite ground-truth pose): 1"),
        "{}",
        text(&o.stdout)
    );

    // 2. The index's copy of the pipeline records the --index the run used.
    let recorded = std::fs::read_to_string(d.join("idx/pipeline.toml")).unwrap();
    assert!(recorded.contains(&format!("index = {:?}", d.join("idx").display().to_string())), "{recorded}");

    // 3. Flags without ranges: refused, naming the flag, the value and the range.
    let flags: [(&str, &[&str], &[&str]); 12] = [
        (
            "--max-n 0",
            &["eval", "places", "--db", "idx", "-o", "ev", "--max-n", "0"],
            &["--max-n", "0", "[1,"],
        ),
        (
            "--thresholds nan,-1",
            &["eval", "places", "--db", "idx", "-o", "ev", "--thresholds", "nan,-1"],
            &["--thresholds", "nan"],
        ),
        (
            "--map-every nan",
            &["eval", "places", "--db", "idx", "-o", "ev", "--map-every", "nan"],
            &["--map-every", "nan"],
        ),
        (
            "--min-time-gap -1",
            &["eval", "places", "--db", "idx", "-o", "ev", "--min-time-gap=-1"],
            &["--min-time-gap", "-1"],
        ),
        (
            "--fraction nan",
            &["eval", "perturbation", "--index", "idx", "-o", "ev", "--fraction", "nan"],
            &["--fraction", "nan", "(0, 1]"],
        ),
        ("-k 0", &["query", "--index", "idx", "x.csv", "-k", "0"], &["-k", "0"]),
        ("--speed nan", &["simulate", "-o", "sim", "--speed", "nan"], &["--speed", "nan"]),
        ("--rate inf", &["simulate", "-o", "sim", "--rate", "inf"], &["--rate", "inf"]),
        ("--sessions 0", &["simulate", "-o", "sim", "--sessions", "0"], &["--sessions", "0"]),
        (
            "--azimuth-res 1e-9",
            &["simulate", "-o", "sim", "--azimuth-res", "1e-9"],
            &["--azimuth-res", "1e-9", "[0.01, 10]"],
        ),
        ("--commit-seconds 0", &["run", "p.toml", "--commit-seconds", "0"], &["--commit-seconds", "0"]),
        ("an unknown flag", &["run", "p.toml", "--colour"], &["--colour"]),
    ];
    for (case, args, names) in flags {
        check(case, &run(args), 2, names);
    }
    assert!(!d.join("sim").exists(), "a refused simulate writes nothing");

    // 3b. The descriptor methods' flags, keys and files.
    std::fs::write(d.join("nan.csv"), "scan_id,a,b\n2026-01-01/1767261600000000,1.0,nan\n").unwrap();
    std::fs::write(
        d.join("cut.npy"),
        b"\x93NUMPY\x01\x00\x3d\x00{'descr': '<f4', 'fortran_order': False, 'shape': (64, 50), }",
    )
    .unwrap();
    std::fs::write(d.join("ids.txt"), "a\n").unwrap();
    let methods: [(&str, &[&str], &[&str]); 10] = [
        (
            "query --method nope",
            &["query", "--index", "idx", "--method", "nope", "x.csv"],
            &["idx", "`nope`"],
        ),
        (
            "eval places --method nope",
            &["eval", "places", "--db", "idx", "-o", "ev", "--method", "nope"],
            &["--method nope"],
        ),
        (
            "eval places --condition nonsense",
            &["eval", "places", "--db", "idx", "-o", "ev", "--condition", "nonsense"],
            &["--condition", "unknown condition `nonsense`"],
        ),
        (
            "eval places --condition occlusion=400",
            &["eval", "places", "--db", "idx", "-o", "ev", "--condition", "occlusion=400"],
            &["--condition", "occlusion=400", "[0, 360]"],
        ),
        (
            "eval places --revisit-radius 0",
            &["eval", "places", "--db", "idx", "-o", "ev", "--revisit-radius", "0"],
            &["--revisit-radius"],
        ),
        (
            "import --method toporec",
            &["import", "--index", "idx", "--method", "toporec", "nan.csv"],
            &["--method toporec"],
        ),
        (
            "import --method a/b",
            &["import", "--index", "idx", "--method", "a/b", "nan.csv"],
            &["--method", "a/b"],
        ),
        (
            "import a NaN",
            &["import", "--index", "idx", "--method", "x", "nan.csv"],
            &["nan.csv", "row 1", "not finite"],
        ),
        (
            "import a cut .npy",
            &["import", "--index", "idx", "--method", "x", "cut.npy", "--ids", "ids.txt"],
            &["cut.npy", "shape (64, 50)"],
        ),
        (
            "import into no index",
            &["import", "--index", "nowhere", "--method", "x", "nan.csv"],
            &["nowhere", "no manifest.json"],
        ),
    ];
    for (case, args, names) in methods {
        check(case, &run(args), 2, names);
    }
    let base = std::fs::read_to_string(&pipeline).unwrap();
    let keys: [(&str, &str, &[&str]); 6] = [
        (
            "an unknown method",
            "[descriptors]\nmethods = [\"toporec\", \"nope\"]\n",
            &["descriptors.methods", "`nope`"],
        ),
        ("no method", "[descriptors]\nmethods = []\n", &["descriptors.methods: empty"]),
        (
            "scancontext out of range",
            "[descriptors]\nmethods = [\"scancontext\"]\n[scancontext]\nrings = 0\nmax_radius = nan\n",
            &["scancontext", "rings", "max_radius"],
        ),
        ("an unknown m2dp key", "[m2dp]\nvoxels = 1.0\n", &["m2dp", "voxels"]),
        (
            "toporec-plus out of range",
            "[descriptors]\nmethods = [\"toporec-plus\"]\n[toporec-plus]\ncell = 0\nsectors = 2\nturns = 17\nsearch_ratio = 2\nlidar_height = inf\n",
            &[
                "toporec-plus.cell",
                "sectors",
                "toporec-plus.turns",
                "toporec-plus.search_ratio",
                "toporec-plus.lidar_height",
            ],
        ),
        ("an unknown toporec-plus key", "[toporec-plus]\nvoxels = 1.0\n", &["toporec-plus", "voxels"]),
    ];
    for (case, extra, names) in keys {
        let file = d.join("methods.toml");
        std::fs::write(&file, format!("{base}\n{extra}")).unwrap();
        let o = run(&["validate", file.to_str().unwrap()]);
        let err = text(&o.stderr);
        assert!(!err.contains("panicked at"), "{case}: {err}");
        assert_eq!(o.status.code(), Some(2), "{case}: {err}");
        for n in names {
            assert!(err.contains(n), "{case}: `{n}` not named in: {err}");
        }
        println!("ok  {case}: exit 2");
    }

    // 4. `--max-n` smaller than the columns of the table: the headers follow it, no NaN.
    let o = run(&[
        "eval",
        "places",
        "--db",
        "idx",
        "--db-session",
        "2026-01-02",
        "--query-session",
        "2026-01-01",
        "-o",
        "ev3",
        "--max-n",
        "3",
    ]);
    check("--max-n 3", &o, 0, &[]);
    assert!(
        text(&o.stdout).contains("R@3")
            && !text(&o.stdout).contains("R@25")
            && !text(&o.stdout).contains("NaN"),
        "{}",
        text(&o.stdout)
    );
    // -k larger than the database: clamped with a warning.
    let one = root().join("samples/town/velodyne_data/2026-01-02/velodyne_sync/1767348000000000.bin");
    let o = run(&["query", "--index", "idx", one.to_str().unwrap(), "-k", "1000"]);
    check("-k 1000 on 64 scans", &o, 0, &[]);
    assert_eq!(text(&o.stdout).lines().count(), 65, "header and every scan");
    assert!(text(&o.stderr).contains("-k 1000: the database holds 64 scans"), "{}", text(&o.stderr));

    // 5. Inputs as users have them: a cloud CSV from Excel (byte-order mark, CRLF, quotes).
    std::fs::write(
        d.join("excel.csv"),
        b"\xef\xbb\xbf\"x\",\"y\",\"z\"\r\n0,0,0\r\n1,0,0\r\n0,1,0\r\n0,0,1\r\n1,1,1\r\n",
    )
    .unwrap();
    let o = run(&["diagram", "excel.csv"]);
    check("cloud CSV with a byte-order mark and CRLF", &o, 0, &[]);
    assert!(text(&o.stdout).starts_with("dim,birth,death\n0,0.0,"), "{}", text(&o.stdout));
    // A session reached twice: refused at the start (and by validate), naming both paths.
    let sessions = root().join("samples/town/velodyne_data");
    std::fs::write(
        d.join("twice.toml"),
        format!(
            "[output]\nindex = \"twice\"\n[[sources]]\nkind = \"nclt\"\nsessions = [{:?}]\n[[sources]]\nkind = \"nclt\"\nsessions = [{:?}]\n",
            sessions.display().to_string(),
            sessions.join("2026-01-01").display().to_string()
        ),
    )
    .unwrap();
    for command in ["run", "validate"] {
        let o = run(&[command, "twice.toml"]);
        check(
            &format!("a session reached twice: {command}"),
            &o,
            2,
            &["twice.toml", "2026-01-01", "comes twice"],
        );
    }
    assert!(!d.join("twice").exists(), "refused before anything is written");
    // Two sessions of one name from different folders.
    let other = d.join("other/2026-01-01");
    std::fs::create_dir_all(other.join("velodyne_sync")).unwrap();
    std::fs::copy(&one, other.join("velodyne_sync/1767348000000000.bin")).unwrap();
    std::fs::write(
        d.join("same-name.toml"),
        format!(
            "[output]\nindex = \"same\"\n[[sources]]\nkind = \"nclt\"\nsessions = [{:?}, {:?}]\n",
            sessions.join("2026-01-01").display().to_string(),
            other.display().to_string()
        ),
    )
    .unwrap();
    check(
        "two sessions of one name",
        &run(&["validate", "same-name.toml"]),
        2,
        &["comes twice", "other/2026-01-01"],
    );

    // 6. A closed pipe ends a command quietly.
    let mut child = Command::new(env!("CARGO_BIN_EXE_toporec"))
        .args(["eval", "places", "--db", "idx", "-o", "ev4"])
        .current_dir(d)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    check("eval places | head (closed pipe)", &o, 0, &[]);
    let mut child = Command::new(env!("CARGO_BIN_EXE_toporec"))
        .args(["query", "--index", "idx", sessions.to_str().unwrap()])
        .current_dir(d)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    check("query | head (closed pipe)", &child.wait_with_output().unwrap(), 0, &[]);

    // 7. One rule for exit codes: a query with one bad input of two is partial (1), with its rows.
    std::fs::write(d.join("broken.bin"), [0u8; 7]).unwrap();
    let o = run(&["query", "--index", "idx", one.to_str().unwrap(), "broken.bin", "-k", "2"]);
    check("query with one bad input", &o, 1, &[]);
    assert_eq!(text(&o.stdout).lines().count(), 3, "the good query's rows");
    assert!(
        text(&o.stderr).contains("broken.bin") && text(&o.stderr).contains("truncated"),
        "{}",
        text(&o.stderr)
    );

    // 8. Clouds out of the engine's range: refused, naming the range; in range: answered.
    let mut big = String::from("x,y,z\n");
    for p in read_cloud(&root().join("tests/fixtures/clouds/unit_cube_300_rng1.csv")) {
        big += &format!("{:?},{:?},{:?}\n", p[0] * 1e200, p[1] * 1e200, p[2] * 1e200);
    }
    std::fs::write(d.join("huge.csv"), big).unwrap();
    check("a cloud at 1e200", &run(&["diagram", "huge.csv"]), 2, &["huge.csv", "range of doubles"]);
    let mut tiny = String::from("x,y,z\n0,0,0\n1,0,0\n0,1,0\n0,0,1\n");
    tiny += "1e-40,0,0\n";
    std::fs::write(d.join("close.csv"), tiny).unwrap();
    check(
        "distinct points 1e-40 apart",
        &run(&["diagram", "close.csv"]),
        2,
        &["close.csv", "closer than 2^-100"],
    );

    // 9. Write failures: an index path that is a file; a file-size limit mid-run.
    std::fs::write(d.join("a-file"), b"").unwrap();
    check(
        "index path is a file",
        &run(&["run", "p.toml", "--index", "a-file", "--no-progress"]),
        2,
        &["a-file"],
    );

    // 10. An index folder that is someone else's: refused, naming what it holds, untouched.
    std::fs::create_dir_all(d.join("theirs/scans")).unwrap();
    std::fs::write(d.join("theirs/notes.csv"), b"a\n").unwrap();
    check(
        "an index folder that is not an index",
        &run(&["run", "p.toml", "--index", "theirs", "--no-progress"]),
        2,
        &["theirs", "not a toporec index", "notes.csv, scans/"],
    );
    assert!(d.join("theirs/notes.csv").is_file() && !d.join("theirs/manifest.json").exists());

    // 11. A cloud whose Delaunay triangulation needs more cells than the engine numbers (the
    //     limit lowered to 100 cells, as a cloud of points on a few curves reaches 2^30).
    let cube = root().join("tests/fixtures/clouds/unit_cube_300_rng1.csv");
    let o = Command::new(env!("CARGO_BIN_EXE_toporec"))
        .args(["diagram", cube.to_str().unwrap()])
        .env("TOPOREC_CELL_LIMIT", "100")
        .output()
        .unwrap();
    check("a cloud past the engine's cell limit", &o, 2, &["unit_cube_300_rng1.csv", "more than 100 cells"]);
}

#[test]
fn plot_file_names_keep_every_dot_of_the_scan_id() {
    // Session `drive.v2`: the default names of two scans' plots differ (`diagram_drive.v2_<n>`).
    let dir = scratch_dir("bad_inputs_plot_names");
    let from = root().join("samples/town/velodyne_data/2026-01-01/velodyne_sync");
    let sync = dir.join("data/drive.v2/velodyne_sync");
    std::fs::create_dir_all(&sync).unwrap();
    let mut bins: Vec<PathBuf> = std::fs::read_dir(&from).unwrap().flatten().map(|e| e.path()).collect();
    bins.sort();
    for b in &bins[..2] {
        std::fs::copy(b, sync.join(b.file_name().unwrap())).unwrap();
    }
    let p = dir.join("p.toml");
    let body = format!(
        "[output]\nindex = \"idx\"\n[[sources]]\nkind = \"nclt\"\nsessions = [{:?}]\n\
         [preprocess]\nsubsample = 512\nnormalize = true\n[vectorize]\nb = 2\n",
        dir.join("data").display().to_string()
    );
    std::fs::write(&p, body).unwrap();
    let o = within_20s(&["run", p.to_str().unwrap(), "--no-progress"], &dir);
    check("a session named drive.v2", &o, 0, &[]);
    let mut made = Vec::new();
    for b in &bins[..2] {
        let scan = format!("drive.v2/{}", b.file_stem().unwrap().to_string_lossy());
        let o = within_20s(&["plot", "diagram", "--index", "idx", "--scan", &scan], &dir);
        check("plot diagram of a scan of drive.v2", &o, 0, &[]);
        made.push(text(&o.stdout));
    }
    assert_ne!(made[0], made[1], "two scans, two files");
    let stem = format!("diagram_drive.v2_{}", bins[0].file_stem().unwrap().to_string_lossy());
    assert!(
        made[0].contains(&format!("{stem}.png")) && dir.join(format!("{stem}.svg")).is_file(),
        "{}",
        made[0]
    );
}

#[test]
fn a_write_failure_keeps_committed_chunks_and_leaves_no_file_behind() {
    let dir = scratch_dir("bad_inputs_write_failure");
    let index = dir.join("idx");
    let pipeline = root().join("pipelines/sample.toml");
    // 600 KiB per file: toporec ignores SIGXFSZ, so a write past it fails with EFBIG, an error
    // with its path, instead of killing the process without a word.
    let script = format!(
        "ulimit -f 600; exec {} run {} --index {} --no-progress --commit-every 4",
        env!("CARGO_BIN_EXE_toporec"),
        pipeline.display(),
        index.display()
    );
    let o = Command::new("bash").args(["-c", &script]).output().unwrap();
    check("a file-size limit mid-run", &o, 2, &["File too large", "idx/.staging/part-"]);
    let err = text(&o.stderr);
    assert_eq!(err.matches("File too large").count(), 1, "the OS error once: {err}");
    // The committed chunks stay; nothing uncommitted is left behind.
    let manifest: serde_json::Value = read_json(&index.join("manifest.json"));
    let committed = manifest["counts"]["scans"].as_u64().unwrap();
    assert!(committed > 0, "some chunks committed before the failure");
    let leftovers: Vec<String> = walk(&index)
        .into_iter()
        .map(|p| p.strip_prefix(&index).unwrap().display().to_string())
        .filter(|p| p.contains(".partial-") || p.starts_with(".staging"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    let o = toporec(&["verify", "--index", index.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stdout));
    // The next run resumes from the committed chunks.
    let o = run_pipeline(&pipeline, &index, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains(&format!("changes: {committed} up to date")), "{}", text(&o.stderr));
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        if e.path().is_dir() {
            out.extend(walk(&e.path()));
        } else {
            out.push(e.path());
        }
    }
    out
}
