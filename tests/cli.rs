//! The `toporec` binary: output format, format detection, and one-line errors on bad input.

use crate::util::*;
use std::path::Path;
use std::process::Output;

fn stdout(o: &Output) -> String {
    text(&o.stdout)
}

fn stderr(o: &Output) -> String {
    text(&o.stderr)
}

#[test]
fn diagram_prints_sorted_round_tripping_csv() {
    let cloud = root().join("tests/fixtures/clouds/torus_1000.csv");
    let o = toporec(&["diagram", cloud.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    assert!(text.starts_with("dim,birth,death\n"));
    let rows: Vec<(u8, f64, f64)> = text
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[0].parse().unwrap(), f[1].parse().unwrap(), f[2].parse().unwrap())
        })
        .collect();
    let mut sorted = rows.clone();
    sorted.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)).then(a.2.total_cmp(&b.2)));
    assert_eq!(rows, sorted, "rows sorted by (dim, birth, death)");
    assert_eq!(rows.iter().filter(|r| r.2.is_infinite()).count(), 1);
    // Printed values parse back to exactly the library's values.
    let lib = toporec::homology::alpha_persistence(&read_cloud(&cloud)).unwrap();
    let lib: Vec<(u8, f64, f64)> = lib.pairs().iter().map(|p| (p.dim, p.birth, p.death)).collect();
    assert_eq!(rows, lib);
    assert_diagrams_match(
        &parse_diagram_csv(&text),
        &read_diagram_csv(&root().join("tests/fixtures/diagrams/torus_1000.csv")),
        1e-9,
        "cli",
    );
}

#[test]
fn diagram_dims_and_radius_options() {
    let cloud = root().join("tests/fixtures/clouds/uniform_cube_500.csv");
    let sq = parse_diagram_csv(&stdout(&toporec(&["diagram", cloud.to_str().unwrap(), "--dims", "2"])));
    assert!(sq[0].is_empty() && sq[1].is_empty() && sq[2].len() == 632);
    let r = parse_diagram_csv(&stdout(&toporec(&[
        "diagram",
        cloud.to_str().unwrap(),
        "--dims",
        "2",
        "--radius",
    ])));
    for (a, b) in sq[2].iter().zip(&r[2]) {
        assert_eq!(a.0.sqrt(), b.0);
        assert_eq!(a.1.sqrt(), b.1);
    }
}

/// Asserts a failed run with a one-line error naming `name`, and no panic.
fn assert_clean_error(o: &Output, name: &str, what: &str) {
    let err = stderr(o);
    assert!(!o.status.success(), "{what}: should fail");
    assert_eq!(o.status.code(), Some(2), "{what}: exit code");
    assert!(!err.contains("panicked"), "{what}: panicked: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{what}: one line: {err}");
    assert!(err.contains(name), "{what}: names the file: {err}");
}

#[test]
fn bad_inputs_give_one_line_errors() {
    let dir = std::env::temp_dir().join(format!("toporec-cli-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("velodyne_sync")).unwrap();
    let write = |name: &str, bytes: &[u8]| {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    let cases: Vec<(std::path::PathBuf, &str)> = vec![
        (dir.join("missing.csv"), "missing file"),
        (write("truncated.bin", &[0u8; 16 * 5 + 3]), "truncated KITTI .bin"),
        (write("velodyne_sync/1.bin", &[0u8; 8 * 5 + 1]), "truncated NCLT .bin"),
        (write("nan.csv", b"x,y,z\n0,0,0\n1,0,0\nNaN,1,0\n0,0,1\n0,1,1\n"), "NaN coordinate"),
        (write("inf.csv", b"x,y,z\n0,0,0\n1,0,0\ninf,1,0\n0,0,1\n"), "infinite coordinate"),
        (write("empty.csv", b""), "empty file"),
        (write("empty.bin", b""), "empty .bin"),
        (write("three.csv", b"x,y,z\n0,0,0\n1,0,0\n0,1,0\n"), "fewer than 4 points"),
        (write("header.csv", b"a,b\n1,2\n"), "bad header"),
        (write("text.csv", b"x,y,z\n1,2,three\n"), "not a number"),
        (write("cloud.xyz", b"1 2 3\n"), "unknown format"),
    ];
    for (path, what) in &cases {
        let o = toporec(&["diagram", path.to_str().unwrap()]);
        assert_clean_error(&o, path.file_name().unwrap().to_str().unwrap(), what);
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn nclt_format_chosen_by_folder_or_flag() {
    // Four records: the NCLT decoding gives a tetrahedron with 1 m edges along the axes.
    let rec = |x: u16, y: u16, z: u16| {
        let mut r = Vec::new();
        for v in [x, y, z] {
            r.extend_from_slice(&v.to_le_bytes());
        }
        r.extend_from_slice(&[7, 3]);
        r
    };
    let base = 20_000u16; // 0 m
    let bytes: Vec<u8> = [
        rec(base, base, base),
        rec(base + 200, base, base),
        rec(base, base + 200, base),
        rec(base, base, base + 200),
    ]
    .concat();
    let dir = std::env::temp_dir().join(format!("toporec-nclt-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("velodyne_sync")).unwrap();
    let in_sync = dir.join("velodyne_sync/1000.bin");
    std::fs::write(&in_sync, &bytes).unwrap();
    let elsewhere = dir.join("1000.bin");
    std::fs::write(&elsewhere, &bytes).unwrap();
    let by_folder = stdout(&toporec(&["diagram", in_sync.to_str().unwrap()]));
    let by_flag = stdout(&toporec(&["diagram", elsewhere.to_str().unwrap(), "--format", "nclt"]));
    assert_eq!(by_folder, by_flag);
    let d = parse_diagram_csv(&by_folder);
    let mut deaths: Vec<f64> = d[0].iter().map(|p| p.1).collect();
    deaths.sort_by(f64::total_cmp);
    assert_eq!(deaths, vec![0.25, 0.25, 0.25, f64::INFINITY], "1 m edges: (1/2)² = 0.25");
    // As KITTI, the same 32 bytes are two 16-byte records: too few points.
    let o = toporec(&["diagram", elsewhere.to_str().unwrap()]);
    assert_clean_error(&o, "1000.bin", "KITTI reading of NCLT bytes");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn real_kitti_and_nclt_scans() {
    let Some(data) = shared_data("real_kitti_and_nclt_scans") else { return };
    let nclt = data.join("nclt/2012-01-15/velodyne_sync/1326652795280148.bin");
    let o = toporec(&["diagram", nclt.to_str().unwrap(), "--dims", "2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(parse_diagram_csv(&stdout(&o))[2].len(), 5_546);
    let kitti = data.join("kitti/sequences/00/velodyne/000094.bin");
    let o = toporec(&["diagram", kitti.to_str().unwrap(), "--dims", "0"]);
    assert!(o.status.success(), "{}", stderr(&o));
    // KITTI scans carry duplicate points: H0 counts distinct points.
    let h0 = parse_diagram_csv(&stdout(&o))[0].len();
    let pts = read_cloud(Path::new(&kitti));
    let mut distinct: Vec<[u64; 3]> = pts.iter().map(|p| p.map(|x| (x + 0.0).to_bits())).collect();
    distinct.sort();
    distinct.dedup();
    assert_eq!(h0, distinct.len());
}

#[test]
fn fit_then_vectorize_from_diagram_files() {
    let dir = scratch_dir("cli_fit_vectorize");
    let diagrams: Vec<String> = ["uniform_cube_500", "torus_1000", "two_spheres_800", "lidar_like_4096"]
        .iter()
        .map(|n| root().join(format!("tests/fixtures/diagrams/{n}.csv")).display().to_string())
        .collect();
    let cb = dir.join("codebook.json");
    let mut args = vec!["fit", "-o", cb.to_str().unwrap(), "-b", "8", "--dims", "0,1,2", "--seed", "3"];
    args.extend(diagrams.iter().map(String::as_str));
    let o = toporec(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("length 24"), "{}", stderr(&o));
    // Fitting again gives the same bytes.
    let first = std::fs::read(&cb).unwrap();
    assert!(toporec(&args).status.success());
    assert_eq!(std::fs::read(&cb).unwrap(), first, "same seed, same codebook file");

    let mut args = vec!["vectorize", "-c", cb.to_str().unwrap()];
    args.extend(diagrams.iter().map(String::as_str));
    let o = toporec(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header.len(), 2 + 24);
    assert_eq!(&header[..3], ["diagram", "dim_used", "v1"]);
    // Rows equal the library's vectorization of the same files.
    let codebook = toporec::vectorize::codebook::Codebook::load(&cb).unwrap();
    for (line, path) in lines.zip(&diagrams) {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f[0], path);
        let values: Vec<f64> = f[2..].iter().map(|v| v.parse().unwrap()).collect();
        let expected = codebook.vectorize(&toporec::diagram_csv::read(Path::new(path)).unwrap());
        assert_eq!(values, expected.values);
    }
    // Bad inputs: one line naming the file.
    let bad = dir.join("bad.csv");
    std::fs::write(&bad, "dim,birth,death\n1,0.5,0.2\n").unwrap();
    let o = toporec(&["fit", "-o", cb.to_str().unwrap(), bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("bad.csv") && stderr(&o).contains("line 2"), "{}", stderr(&o));
    let only_h0 = dir.join("h0.csv");
    std::fs::write(&only_h0, "dim,birth,death\n0,0.0,inf\n").unwrap();
    let o = toporec(&["fit", "-o", dir.join("x.json").to_str().unwrap(), only_h0.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("infinite components only"), "{}", stderr(&o));
    assert!(!dir.join("x.json").exists(), "no codebook written on failure");
    let o = toporec(&["vectorize", "-c", bad.to_str().unwrap(), diagrams[0].as_str()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("bad.csv: not JSON"), "{}", stderr(&o));
}

#[test]
fn inspect_and_diagram_of_an_mcap_message() {
    let Some(data) = shared_data("inspect_and_diagram_of_an_mcap_message") else { return };
    let o = toporec(&["inspect", data.join("mcap/ouster_os1_ros1.mcap").to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    assert!(text.contains("format: mcap"), "{text}");
    assert!(text.contains("/os1_cloud_node/points  [sensor_msgs/PointCloud2 / ros1]  2 messages"), "{text}");
    assert!(text.contains("raw points per scan: min 131072 / median 131072 / max 131072"), "{text}");
    let o = toporec(&["inspect", data.join("nclt_from_kitti").to_str().unwrap()]);
    let text = stdout(&o);
    assert!(text.contains("format: nclt sessions") && text.contains("poses joined: 14 of 14"), "{text}");

    // `diagram --index 1` of the ROS 2 MCAP is the diagram of KITTI frame 95.
    let mcap = data.join("mcap/kitti_ros2_cdr.mcap");
    let a = toporec(&["diagram", mcap.to_str().unwrap(), "--index", "1", "--dims", "2"]);
    assert!(a.status.success(), "{}", stderr(&a));
    let b = toporec(&[
        "diagram",
        data.join("kitti/sequences/00/velodyne/000095.bin").to_str().unwrap(),
        "--dims",
        "2",
    ]);
    assert_eq!(stdout(&a), stdout(&b));
    let o = toporec(&["diagram", mcap.to_str().unwrap(), "--index", "9"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("kitti_ros2_cdr.mcap: no point-cloud message with index 9"),
        "{}",
        stderr(&o)
    );
    let o = toporec(&["inspect", root().join("Cargo.toml").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("Cargo.toml: unknown cloud format"), "{}", stderr(&o));
}

#[test]
fn info_says_what_an_index_holds() {
    let dir = scratch_dir("cli_info");
    let index = dir.join("index");
    let pipeline = root().join("pipelines/compare.toml");
    assert!(run_pipeline(&pipeline, &index, 2).status.success());
    let idx = index.to_str().unwrap();
    let o = toporec(&["info", "--index", idx]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = stdout(&o);
    for needle in [
        "scans: 64 (64 ok, 0 skipped, 0 errors)",
        "2026-01-01        32       32        0        0",
        "toporec: length 50, codebook ",
        "scancontext: length 1200, id ",
        "toporec-plus: length 4000, id ",
        "m2dp: length 192, id ",
        "solid: length 100, id ",
        "[descriptors]",
    ] {
        assert!(out.contains(needle), "`{needle}` missing from:\n{out}");
    }
    // The JSON form: counts per session, every method with its settings and rows, the size.
    let o = toporec(&["info", "--index", idx, "--json"]);
    let info: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(info["sessions"]["2026-01-02"]["ok"], 32);
    assert_eq!(info["methods"]["scancontext"]["settings"]["rings"], 20);
    assert_eq!(info["methods"]["toporec"]["settings"]["b"], 50);
    for m in ["toporec", "toporec-plus", "scancontext", "m2dp", "solid"] {
        assert_eq!(info["methods"][m]["rows"], 64, "{m}");
    }
    let manifest = read_json(&index.join("manifest.json"));
    assert_eq!(info["generation"], manifest["generation"]);
    let bytes: u64 = manifest["files"].as_array().unwrap().iter().map(|f| f["bytes"].as_u64().unwrap()).sum();
    assert_eq!(info["bytes"], bytes);
    // --files: one generation's files; of one table, of one method.
    let o = toporec(&["info", "--index", idx, "--files", "descriptors", "--method", "m2dp"]);
    let files: Vec<String> = stdout(&o).lines().map(String::from).collect();
    assert_eq!(files.len(), 2, "{files:?}");
    assert!(files.iter().all(|f| f.contains("/descriptors/method=m2dp/session=") && Path::new(f).is_file()));
    let o = toporec(&["info", "--index", idx, "--files", "tables"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("`tables` is not a table"), "{}", stderr(&o));
    let o = toporec(&["info", "--index", dir.join("missing").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("no such index folder"), "{}", stderr(&o));
}

#[test]
fn split_makes_a_map_and_a_query_session_of_one_drive() {
    // The sample's first day (32 scans): every 3rd scan from the first to the map, the rest to
    // the queries, each file a link to the original, the ground truth beside both.
    let dir = scratch_dir("split");
    let session = root().join("samples/town/velodyne_data/2026-01-01");
    let out = dir.join("split");
    let o = toporec(&["split", session.to_str().unwrap(), "--every", "3", "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut scans: Vec<_> =
        std::fs::read_dir(session.join("velodyne_sync")).unwrap().flatten().map(|e| e.path()).collect();
    scans.sort();
    assert_eq!(scans.len(), 32);
    let listed = |name: &str| {
        let mut v: Vec<_> = std::fs::read_dir(out.join(name).join("velodyne_sync"))
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };
    let name = |p: &std::path::PathBuf| p.file_name().unwrap().to_string_lossy().into_owned();
    let (map, query) = (listed("map"), listed("query"));
    assert_eq!(map, scans.iter().step_by(3).map(name).collect::<Vec<_>>());
    assert_eq!(map.len() + query.len(), 32);
    assert!(query.iter().all(|q| !map.contains(q)));
    // A link reads as the original; the ground truth is the drive's.
    let first = out.join("map/velodyne_sync").join(&map[0]);
    assert_eq!(std::fs::read(&first).unwrap(), std::fs::read(&scans[0]).unwrap());
    let truth = std::fs::read(root().join("samples/town/ground_truth/groundtruth_2026-01-01.csv")).unwrap();
    for s in ["map", "query"] {
        assert_eq!(std::fs::read(out.join(format!("groundtruth_{s}.csv"))).unwrap(), truth);
    }
    assert!(stdout(&o).contains("(11 scans)") && stdout(&o).contains("(21 scans)"), "{}", stdout(&o));
    // Nothing is written over; the settings are checked.
    let again = toporec(&["split", session.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert_clean_error(&again, "exists; split into a new folder", "split twice");
    let bad = toporec(&[
        "split",
        session.to_str().unwrap(),
        "--every",
        "3",
        "--first",
        "3",
        "-o",
        dir.join("x").to_str().unwrap(),
    ]);
    assert_clean_error(&bad, "first in [0, every)", "split --first 3");
}

/// Every command's subcommands, from `toporec [COMMAND] --help`'s `Commands:` section
/// (`help` left out).
fn subcommands(path: &[&str]) -> Vec<String> {
    let mut args: Vec<&str> = path.to_vec();
    args.push("--help");
    let help = stdout(&toporec(&args));
    let Some((_, list)) = help.split_once("Commands:\n") else { return Vec::new() };
    list.lines()
        .take_while(|l| l.starts_with("  "))
        .filter(|l| l.len() > 2 && !l[2..].starts_with(' '))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .map(str::to_string)
        .collect()
}

/// The `--help` of every command is kept in `tests/fixtures/help/` (the options, their ranges
/// and defaults): a change to the command line shows as a change of these files, never as a
/// silent loss. `TOPOREC_BLESS=1` writes them anew.
#[test]
fn every_commands_help_is_as_recorded() {
    let dir = root().join("tests/fixtures/help");
    let bless = std::env::var("TOPOREC_BLESS").is_ok_and(|v| v == "1");
    let mut commands: Vec<Vec<String>> = vec![Vec::new()];
    let mut i = 0;
    while i < commands.len() {
        let path: Vec<&str> = commands[i].iter().map(String::as_str).collect();
        for sub in subcommands(&path) {
            let mut next = commands[i].clone();
            next.push(sub);
            commands.push(next);
        }
        i += 1;
    }
    assert!(commands.len() > 20, "{commands:?}");
    let mut expected: Vec<String> = Vec::new();
    for command in &commands {
        let name = if command.is_empty() { "toporec".to_string() } else { command.join("-") };
        let mut args: Vec<&str> = command.iter().map(String::as_str).collect();
        args.push("--help");
        let o = toporec(&args);
        assert!(o.status.success(), "{args:?}");
        let file = dir.join(format!("{name}.txt"));
        expected.push(format!("{name}.txt"));
        if bless {
            std::fs::create_dir_all(&dir).unwrap();
            std::fs::write(&file, &o.stdout).unwrap();
            continue;
        }
        let recorded = std::fs::read_to_string(&file)
            .unwrap_or_else(|_| panic!("{}: missing; run with TOPOREC_BLESS=1", file.display()));
        assert_eq!(
            stdout(&o),
            recorded,
            "`toporec {} --help` differs from {}",
            command.join(" "),
            file.display()
        );
    }
    let mut on_disk: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    on_disk.sort();
    expected.sort();
    assert_eq!(on_disk, expected, "tests/fixtures/help/ holds one file per command");
}
