//! Shared helpers: fixture loading, diagram comparison with a stated tolerance.

use std::path::{Path, PathBuf};
use toporec::homology::{Diagram, Point};

/// Every method `pipelines/kitti.toml` indexes, in the order `eval` reports them (TopoRec
/// first, then by name).
pub const EVERY_METHOD: [&str; 10] = [
    "toporec",
    "lidar-iris",
    "m2dp",
    "ring",
    "ring-plus",
    "scancontext",
    "scancontext-pp",
    "scancontext-pp-cart",
    "solid",
    "toporec-plus",
];

/// The methods `pipelines/compare.toml` indexes (those within 10x ScanContext's cost per raw
/// scan: every method but RING++), in the order `eval` reports them.
pub const COMPARED: [&str; 9] = [
    "toporec",
    "lidar-iris",
    "m2dp",
    "ring",
    "scancontext",
    "scancontext-pp",
    "scancontext-pp-cart",
    "solid",
    "toporec-plus",
];

/// The crate root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Whether missing data or tools fail the test instead of skipping it (`TOPOREC_REQUIRE_DATA=1`,
/// which CI sets).
pub fn data_required() -> bool {
    std::env::var("TOPOREC_REQUIRE_DATA").is_ok_and(|v| !v.is_empty() && v != "0")
}

/// Skips a test whose data or tool is missing, with a clear line; under
/// `TOPOREC_REQUIRE_DATA=1` fails it instead.
pub fn skip(test: &str, why: &str) {
    assert!(
        !data_required(),
        "{test}: {why} (TOPOREC_REQUIRE_DATA is set, so this fails instead of skipping)"
    );
    println!("SKIP {test}: {why}");
}

/// `../shared/data` beside the repository, if present (skips otherwise; see [`skip`]).
pub fn shared_data(test: &str) -> Option<PathBuf> {
    let p = root().join("../shared/data");
    if p.is_dir() {
        Some(p)
    } else {
        skip(test, "../shared/data is absent");
        None
    }
}

/// Whether `python3` can import `modules` (skips otherwise; see [`skip`]).
pub fn python_with(test: &str, modules: &[&str]) -> bool {
    let probe = std::process::Command::new("python3")
        .args(["-c", &format!("import {}", modules.join(", "))])
        .output();
    if probe.is_ok_and(|o| o.status.success()) {
        true
    } else {
        skip(test, &format!("python3 with {} is not installed", modules.join(", ")));
        false
    }
}

pub fn read_cloud(path: &Path) -> Vec<Point> {
    toporec::sources::read_cloud(path, None).unwrap_or_else(|e| panic!("{e}"))
}

/// Reads a `dim,birth,death` CSV into per-dimension pair lists.
pub fn read_diagram_csv(path: &Path) -> [Vec<(f64, f64)>; 3] {
    let text = std::fs::read_to_string(path).unwrap();
    parse_diagram_csv(&text)
}

pub fn parse_diagram_csv(text: &str) -> [Vec<(f64, f64)>; 3] {
    let mut out: [Vec<(f64, f64)>; 3] = Default::default();
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let d: usize = f[0].parse().unwrap();
        out[d].push((f[1].parse().unwrap(), f[2].parse().unwrap()));
    }
    out
}

pub fn by_dim(d: &Diagram) -> [Vec<(f64, f64)>; 3] {
    [0u8, 1, 2].map(|k| d.dimension(k).iter().map(|p| (p.birth, p.death)).collect())
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    if a.is_infinite() || b.is_infinite() {
        return a == b;
    }
    (a - b).abs() <= tol * a.abs().max(b.abs())
}

/// Asserts equal pair counts per dimension and a one-to-one matching of the pairs whose birth
/// and death agree within `rel_tol` relative (greedy, over pairs sorted by (birth, death)).
pub fn assert_diagrams_match(
    ours: &[Vec<(f64, f64)>; 3],
    reference: &[Vec<(f64, f64)>; 3],
    rel_tol: f64,
    what: &str,
) {
    for d in 0..3 {
        assert_eq!(ours[d].len(), reference[d].len(), "{what}: H{d} pair count");
        let mut a = ours[d].clone();
        let mut b = reference[d].clone();
        let key = |x: &(f64, f64), y: &(f64, f64)| x.0.total_cmp(&y.0).then(x.1.total_cmp(&y.1));
        a.sort_by(key);
        b.sort_by(key);
        let mut used = vec![false; b.len()];
        for (i, p) in a.iter().enumerate() {
            // A tied birth can swap neighbours in the sort: look within a window of ranks.
            let (lo, hi) = (i.saturating_sub(256), (i + 257).min(b.len()));
            let found = (lo..hi)
                .filter(|&j| !used[j] && close(p.0, b[j].0, rel_tol) && close(p.1, b[j].1, rel_tol))
                .min_by_key(|&j| j.abs_diff(i));
            match found {
                Some(j) => used[j] = true,
                None => panic!(
                    "{what}: H{d} pair {p:?} (rank {i}) has no reference pair within {rel_tol:e} relative"
                ),
            }
        }
    }
}

/// A fresh, empty scratch folder under target/tmp for one test.
pub fn scratch_dir(test: &str) -> PathBuf {
    let dir = root().join("target/tmp/tests").join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs the `toporec` binary.
pub fn toporec(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_toporec")).args(args).output().expect("run toporec")
}

/// Simulates two laps through a town of 2 × 2 blocks of 40 m whose sides look alike, the second
/// lap reversed 3.5 m over, a VLP-16 at 2° and two scans a second (5 m steps), into `sim` as a
/// ROS 1 bag whose odometry is exact; returns the bag. Lookalike loops pass ICP on it.
pub fn simulate_lookalike_laps(sim: &Path) -> PathBuf {
    let o = toporec(&[
        "simulate",
        "-o",
        sim.to_str().unwrap(),
        "--format",
        "bag",
        "--sessions",
        "1",
        "--laps",
        "2",
        "--lap-offset",
        "3.5",
        "--blocks",
        "2",
        "--block-size",
        "40",
        "--sensor",
        "vlp16",
        "--azimuth-res",
        "2",
        "--rate",
        "2",
        "--seed",
        "13",
    ]);
    assert!(o.status.success(), "simulate: {}", text(&o.stderr));
    sim.join("bag/2026-01-01.bag")
}

/// Lossy UTF-8 of captured output.
pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The numbers of each `EDGE_SE3:QUAT` line of a g2o file's text, in order: the two vertices,
/// x y z qx qy qz qw, then the information's upper triangle.
pub fn g2o_se3_edges(graph: &str) -> Vec<Vec<f64>> {
    graph
        .lines()
        .filter_map(|l| l.strip_prefix("EDGE_SE3:QUAT "))
        .map(|l| l.split(' ').map(|w| w.parse::<f64>().unwrap()).collect())
        .collect()
}

/// `toporec run PIPELINE --index INDEX -t THREADS --no-progress`.
pub fn run_pipeline(pipeline: &Path, index: &Path, threads: usize) -> std::process::Output {
    let threads = threads.to_string();
    toporec(&[
        "run",
        pipeline.to_str().unwrap(),
        "--index",
        index.to_str().unwrap(),
        "-t",
        &threads,
        "--no-progress",
    ])
}

/// The one committed part file of `table` for `session` in an index.
pub fn part_file(index: &Path, table: &str, session: &str) -> PathBuf {
    let files = toporec::sinks::index::IndexReader::open(index).unwrap().files(table).unwrap();
    let mine: Vec<PathBuf> = files.into_iter().filter(|(s, _)| s == session).map(|(_, p)| p).collect();
    assert_eq!(mine.len(), 1, "{table}/{session}: {mine:?}");
    mine.into_iter().next().unwrap()
}

/// A JSON file (a report, a manifest).
pub fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// `eval places` on `index`: day 2 of the sample drive (2026-01-02) against day 1, into `out`,
/// with `extra` flags.
pub fn eval_days(index: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec!["eval", "places", "--db", index.to_str().unwrap(), "--db-session", "2026-01-01"];
    args.extend(["--query-session", "2026-01-02", "-o", out.to_str().unwrap()]);
    args.extend(extra);
    toporec(&args)
}

/// `toporec run` with extra flags; returns the output and the summary JSON.
pub fn run_with(pipeline: &Path, index: &Path, extra: &[&str]) -> (std::process::Output, serde_json::Value) {
    let summary = index.with_extension("summary.json");
    let _ = std::fs::remove_file(&summary);
    let mut args = vec![
        "run",
        pipeline.to_str().unwrap(),
        "--index",
        index.to_str().unwrap(),
        "-t",
        "2",
        "--no-progress",
        "--summary-json",
        summary.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = toporec(&args);
    let json = std::fs::read_to_string(&summary).ok().and_then(|t| serde_json::from_str(&t).ok());
    (o, json.unwrap_or(serde_json::Value::Null))
}

pub fn counter(summary: &serde_json::Value, key: &str) -> u64 {
    summary["scans"][key].as_u64().unwrap_or_else(|| panic!("no scans.{key} in {summary}"))
}

/// Every committed row of a table as text, sorted (file layout aside, the table's content).
pub fn rows(index: &Path, table: &str) -> Vec<String> {
    use arrow::util::display::{ArrayFormatter, FormatOptions};
    let mut out = Vec::new();
    let reader = toporec::sinks::index::IndexReader::open(index).unwrap();
    for (session, path) in reader.files(table).unwrap() {
        let f = std::fs::File::open(&path).unwrap();
        for batch in parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(f)
            .unwrap()
            .build()
            .unwrap()
        {
            let batch = batch.unwrap();
            let options = FormatOptions::default();
            let columns: Vec<ArrayFormatter> = batch
                .columns()
                .iter()
                .map(|c| ArrayFormatter::try_new(c.as_ref(), &options).unwrap())
                .collect();
            for i in 0..batch.num_rows() {
                let cells: Vec<String> = columns.iter().map(|c| c.value(i).to_string()).collect();
                out.push(format!("{session}|{}", cells.join("|")));
            }
        }
    }
    out.sort();
    out
}

/// A copy of the sample drive (both sessions, or only the first).
pub fn sample_copy(dir: &Path, sessions: &[&str]) -> PathBuf {
    let data = dir.join("town");
    for s in sessions {
        let from = root().join(format!("samples/town/velodyne_data/{s}"));
        let to = data.join(format!("velodyne_data/{s}"));
        std::fs::create_dir_all(to.join("velodyne_sync")).unwrap();
        for f in std::fs::read_dir(from.join("velodyne_sync")).unwrap().flatten() {
            std::fs::copy(f.path(), to.join("velodyne_sync").join(f.file_name())).unwrap();
        }
        let gt = format!("ground_truth/groundtruth_{s}.csv");
        std::fs::create_dir_all(data.join("ground_truth")).unwrap();
        std::fs::copy(root().join("samples/town").join(&gt), data.join(&gt)).unwrap();
    }
    data
}

/// The sample pipeline over `data`, with `subsample` points.
pub fn sample_pipeline(dir: &Path, data: &Path, subsample: usize) -> PathBuf {
    let text = std::fs::read_to_string(root().join("pipelines/sample.toml")).unwrap();
    let text = text
        .replace(
            "\"../samples/town/velodyne_data\"",
            &format!("{:?}", data.join("velodyne_data").display().to_string()),
        )
        .replace("subsample = 4096", &format!("subsample = {subsample}"));
    let p = dir.join(format!("sample-{subsample}.toml"));
    std::fs::write(&p, text).unwrap();
    p
}
