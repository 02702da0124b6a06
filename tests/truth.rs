//! What `toporec loops <log>` and `toporec run` report is true: poses that change are joined
//! again (without recomputing a descriptor), an index belongs to its sources, every failure is
//! named, degenerate input is never taken for a place, clouds without times are kept apart by
//! position, a log is recognised by its content, and poses of unrelated frames are never compared.

use crate::util::*;
use std::path::{Path, PathBuf};
use std::process::Output;
use toporec::sinks::index::IndexReader;

/// Runs `toporec` in `dir` (where a default index `out/<name>` goes).
fn toporec_in(dir: &Path, args: &[&str]) -> Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_toporec"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run toporec")
}

/// The sample bag copied into `dir`.
fn bag_in(dir: &Path) -> PathBuf {
    let bag = dir.join("drive.bag");
    std::fs::copy(root().join("samples/drive.bag"), &bag).unwrap();
    bag
}

/// Every scan's (id, time, pose) of an index, by id.
fn poses(index: &Path) -> Vec<(String, Option<i64>, Option<[f64; 4]>)> {
    let mut rows: Vec<_> = IndexReader::open(index)
        .unwrap()
        .scans()
        .unwrap()
        .into_iter()
        .map(|r| (r.scan_id, r.utime, r.pose.map(|p| [p.x, p.y, p.z, p.yaw])))
        .collect();
    rows.sort_by(|a, b| a.0.cmp(&b.0));
    rows
}

/// A TUM file of the index's poses, scaled by `scale`; `shift_odd_ms` moves every other pose in
/// time.
fn tum_of(index: &Path, path: &Path, scale: f64, shift_odd_ms: f64) {
    let mut text = String::new();
    for (i, (_, t, p)) in poses(index).into_iter().enumerate() {
        let ([x, y, z, yaw], t) = (p.unwrap(), t.unwrap() as f64 * 1e-6);
        let t = if i % 2 == 1 { t + shift_odd_ms * 1e-3 } else { t };
        let (qz, qw) = ((yaw / 2.0).sin(), (yaw / 2.0).cos());
        text += &format!("{t:.6} {} {} {} 0 0 {qz} {qw}\n", x * scale, y * scale, z * scale);
    }
    std::fs::write(path, text).unwrap();
}

/// The `true_distance_m` column of a loops CSV.
fn true_distances(csv: &Path) -> Vec<f64> {
    let text = std::fs::read_to_string(csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let at = header.iter().position(|c| *c == "true_distance_m").unwrap();
    lines.map(|l| l.split(',').nth(at).unwrap().parse().unwrap()).collect()
}

fn loops(dir: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["loops", "drive.bag", "--no-progress", "-t", "2"];
    args.extend_from_slice(extra);
    toporec_in(dir, &args)
}

#[test]
fn a_changed_pose_source_is_joined_again_without_recomputing() {
    let dir = scratch_dir("truth_rejoin");
    bag_in(&dir);
    let o = loops(&dir, &["-o", "first.csv"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let index = dir.join("out/drive");
    let from_log = poses(&index);
    let first = true_distances(&dir.join("first.csv"));
    assert!(!first.is_empty());

    // Another file: the same trajectory three times as large.
    tum_of(&index, &dir.join("scaled.tum"), 3.0, 0.0);
    let o = loops(&dir, &["-o", "scaled.csv", "--poses", "scaled.tum"]);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("(96 scans read, 0 computed)"), "nothing recomputed: {err}");
    assert!(err.contains("poses of drive: ") && err.contains("scaled.tum (tum layout"), "{err}");
    let scaled = true_distances(&dir.join("scaled.csv"));
    assert_eq!(scaled.len(), first.len());
    for (a, b) in first.iter().zip(&scaled) {
        assert!((b - 3.0 * a).abs() < 1e-6 * b.max(1.0), "{a} × 3 = {b}");
    }
    // A fresh index of the same bag and poses holds the same rows and finds the same loops.
    let o = loops(&dir, &["-o", "fresh.csv", "--poses", "scaled.tum", "--index", "fresh"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(poses(&index), poses(&dir.join("fresh")));
    assert_eq!(
        std::fs::read_to_string(dir.join("scaled.csv")).unwrap(),
        std::fs::read_to_string(dir.join("fresh.csv")).unwrap()
    );
    assert_eq!(rows(&index, "descriptors"), rows(&dir.join("fresh"), "descriptors"));
    let info = text(&toporec(&["info", "--index", index.to_str().unwrap()]).stdout);
    assert!(info.contains("poses:") && info.contains("scaled.tum") && info.contains("file "), "{info}");

    // The file's content changes: twice as large.
    tum_of(&dir.join("fresh"), &dir.join("scaled.tum"), 2.0 / 3.0, 0.0);
    let o = loops(&dir, &["-o", "edited.csv", "--poses", "scaled.tum"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    for (a, b) in first.iter().zip(&true_distances(&dir.join("edited.csv"))) {
        assert!((b - 2.0 * a).abs() < 1e-6 * b.max(1.0), "{a} × 2 = {b}");
    }

    // The tolerance: every other pose 50 ms off its scan joins within 100 ms, not within 20.
    tum_of(&dir.join("fresh"), &dir.join("shifted.tum"), 1.0 / 3.0, 50.0);
    let o = loops(&dir, &["-o", "wide.csv", "--poses", "shifted.tum"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(poses(&index).iter().all(|r| r.2.is_some()));
    let o = loops(&dir, &["-o", "narrow.csv", "--poses", "shifted.tum", "--tolerance-ms", "20"]);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("48 of 96 scans with a pose"), "{err}");
    assert_eq!(poses(&index).iter().filter(|r| r.2.is_some()).count(), 48);

    // The log's own poses again, then other frames: base_link's poses, not the sensor's.
    let o = loops(&dir, &["-o", "log.csv"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(poses(&index), from_log, "the log's poses, as the first run joined them");
    let o = loops(&dir, &["-o", "frames.csv", "--pose-frames", "odom:base_link"]);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("0 computed") && err.contains("/tf chain odom → base_link"), "{err}");
    let base = poses(&index);
    assert!(base.iter().zip(&from_log).all(|(b, l)| b.2.unwrap()[2] != l.2.unwrap()[2]), "z differs");
    // The topic: /odom gives base_link's poses too, mounted to the sensor by /tf_static.
    let o = loops(&dir, &["-o", "odom.csv", "--poses-topic", "/odom"]);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("/odom in the log"), "{err}");
    for (a, b) in poses(&index).iter().zip(&from_log) {
        let (a, b) = (a.2.unwrap(), b.2.unwrap());
        assert!((0..4).all(|k| (a[k] - b[k]).abs() < 1e-6), "{a:?} {b:?}");
    }
}

#[test]
fn a_pipeline_files_edited_ground_truth_is_joined_again() {
    let dir = scratch_dir("truth_rejoin_pipeline");
    let data = sample_copy(&dir, &["2026-01-01"]);
    let pipeline = sample_pipeline(&dir, &data, 512);
    let index = dir.join("index");
    let (o, _) = run_with(&pipeline, &index, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let before = poses(&index);
    let gt = data.join("ground_truth/groundtruth_2026-01-01.csv");
    let edited: String = std::fs::read_to_string(&gt)
        .unwrap()
        .lines()
        .map(|l| {
            let mut c: Vec<String> = l.split(',').map(str::to_string).collect();
            c[1] = format!("{}", c[1].parse::<f64>().unwrap() + 10.0);
            c.join(",") + "\n"
        })
        .collect();
    std::fs::write(&gt, edited).unwrap();
    let (o, summary) = run_with(&pipeline, &index, &[]);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert_eq!((counter(&summary, "computed"), counter(&summary, "rejoined")), (0, 32), "{err}");
    assert!(err.contains("groundtruth_2026-01-01.csv (NCLT layout"), "{err}");
    for (a, b) in poses(&index).iter().zip(&before) {
        assert!((a.2.unwrap()[0] - b.2.unwrap()[0] - 10.0).abs() < 1e-9);
    }
    let manifest = read_json(&index.join("manifest.json"));
    assert_eq!(manifest["poses"][0]["with_pose"], 32, "{manifest}");
}

#[test]
fn a_default_index_of_other_sources_is_refused_and_the_same_source_reuses_its_own() {
    let dir = scratch_dir("truth_owner");
    let data = sample_copy(&dir.join("a"), &["2026-01-01"]);
    let session = data.join("velodyne_data/2026-01-01");
    // A copy of the session elsewhere, without its ground truth: the same folder name.
    let copy = dir.join("b/2026-01-01/velodyne_sync");
    std::fs::create_dir_all(&copy).unwrap();
    for f in std::fs::read_dir(session.join("velodyne_sync")).unwrap().flatten() {
        std::fs::copy(f.path(), copy.join(f.file_name())).unwrap();
    }
    let args = |s: &Path| -> Vec<String> {
        ["loops", s.to_str().unwrap(), "--no-progress", "--no-verify", "-o", "l.csv"]
            .map(String::from)
            .to_vec()
    };
    let run = |s: &Path| {
        let a = args(s);
        toporec_in(&dir, &a.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let o = run(&session);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("32 of 32 scans with a pose"), "{err}");
    let o = run(&dir.join("b/2026-01-01"));
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("holds the index of") && err.contains("a/town") && err.contains("b/2026-01-01"),
        "{err}"
    );
    assert!(err.contains("--index"), "{err}");
    // The same source again: its own index, brought up to date (nothing computed).
    let o = run(&session);
    let err = text(&o.stderr);
    assert!(o.status.success() && err.contains("0 computed"), "{err}");
    // `run <source>` keeps the same rule.
    let o = toporec_in(&dir, &["run", dir.join("b/2026-01-01").to_str().unwrap(), "--no-progress"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
}

#[test]
fn every_scan_that_cannot_be_read_is_named_and_nothing_else_is_said_twice() {
    let Some(data) = shared_data("every_scan_that_cannot_be_read_is_named") else { return };
    let dir = scratch_dir("truth_failures");
    let mixed = dir.join("mixed");
    std::fs::create_dir_all(&mixed).unwrap();
    std::fs::copy(data.join("pcd/nebula/velodyne_vlp16.pcd"), mixed.join("a.pcd")).unwrap();
    std::fs::write(mixed.join("b.pcd"), "not a cloud\n").unwrap();
    let o = toporec_in(&dir, &["loops", "mixed", "--no-progress", "-o", "l.csv"]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("1 errors") && err.contains("error: ") && err.contains("b.pcd: PCD header"),
        "{err}"
    );
    assert!(!err.contains('\u{1b}'), "no colour codes when stderr is not a terminal: {err:?}");

    // Nothing readable: the reasons, exit 2.
    let garbage = dir.join("garbage");
    std::fs::create_dir_all(&garbage).unwrap();
    for name in ["x.pcd", "y.pcd"] {
        std::fs::write(garbage.join(name), "junk\n").unwrap();
    }
    let o = toporec_in(&dir, &["loops", "garbage", "--no-progress", "-o", "l.csv"]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("no scan could be read") && err.contains("x.pcd: PCD header"), "{err}");

    // A pose file: an unreadable one is named as the pose file.
    bag_in(&dir);
    let o = loops(&dir, &["-o", "l.csv", "--poses", "missing.txt"]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("missing.txt: cannot read the pose file"), "{err}");
    // One good line that joins no scan, then garbage: one warning, then an error with both spans.
    let mut tum = String::from("# t x y z qx qy qz qw\n5.0 1 2 3 0 0 0 1\n");
    for _ in 0..7 {
        tum += "garbage\n";
    }
    std::fs::write(dir.join("bad.tum"), tum).unwrap();
    let o = loops(&dir, &["-o", "l.csv", "--poses", "bad.tum"]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(err.matches("7 of its lines could not be read").count(), 1, "{err}");
    assert!(err.contains("first: line 3"), "{err}");
    assert!(err.contains("joins none of the 96 scans") && err.contains("poses 5.000 s to 5.000 s"), "{err}");
    assert!(err.contains("scans 1767261600.000 s"), "{err}");
    let lines: Vec<&str> = err.lines().collect();
    let mut unique = lines.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(unique.len(), lines.len(), "nothing printed twice: {err}");
}

#[test]
fn degenerate_input_is_skipped_with_its_reason_and_never_matched() {
    let Some(data) = shared_data("degenerate_input_is_skipped") else { return };
    let dir = scratch_dir("truth_degenerate");
    let folder = dir.join("clouds");
    std::fs::create_dir_all(&folder).unwrap();
    for i in 0..4 {
        std::fs::copy(data.join("pcd/nebula/velodyne_vlp16.pcd"), folder.join(format!("{i}.pcd"))).unwrap();
    }
    for i in 4..7 {
        std::fs::copy(data.join("pcd/nebula/ascii_xyz.pcd"), folder.join(format!("{i}.pcd"))).unwrap();
    }
    let o = toporec_in(
        &dir,
        &["loops", "clouds", "--no-progress", "--exclude-scans", "0", "--all", "--no-verify", "-o", "l.csv"],
    );
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("3 skipped") && err.contains("fewer than 100 points"), "{err}");
    let scans = IndexReader::open(&dir.join("out/clouds")).unwrap().scans().unwrap();
    let skipped: Vec<_> =
        scans.iter().filter(|s| s.status == toporec::sinks::parquet::Status::Skipped).collect();
    assert_eq!(skipped.len(), 3);
    assert!(skipped.iter().all(|s| s.error.as_deref().unwrap().contains("2 points, fewer than the 100")));
    let table = std::fs::read_to_string(dir.join("l.csv")).unwrap();
    let mut lines = table.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|c| *c == name).unwrap();
    let (d, r2, q, m) = (col("distance"), col("rank2_distance"), col("query_scan"), col("matched_scan"));
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert!(!rows.is_empty());
    for r in &rows {
        assert!(!["4", "5", "6"].iter().any(|k| r[q].ends_with(k) || r[m].ends_with(k)), "{r:?}");
        if let Ok(second) = r[r2].parse::<f64>() {
            assert!(second >= r[d].parse::<f64>().unwrap(), "rank2_distance below distance: {r:?}");
        }
    }
    for bad in ["-1", "0", "nan", "inf"] {
        let flag = format!("--threshold={bad}");
        let o = toporec_in(&dir, &["loops", "clouds", "--no-progress", &flag, "-o", "l.csv"]);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{bad}: {err}");
        assert!(err.contains("--threshold"), "{err}");
    }
}

#[test]
fn rank2_distance_is_never_below_distance_on_a_drive() {
    let dir = scratch_dir("truth_rank2");
    bag_in(&dir);
    let o = loops(&dir, &["-o", "all.csv", "--all", "--no-verify", "--exclude-seconds", "5"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let text = std::fs::read_to_string(dir.join("all.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|c| *c == name).unwrap();
    let (d, r2) = (col("distance"), col("rank2_distance"));
    let mut n = 0;
    for l in lines {
        let c: Vec<&str> = l.split(',').collect();
        if let (Ok(a), Ok(b)) = (c[d].parse::<f64>(), c[r2].parse::<f64>()) {
            assert!(b >= a, "{l}");
            n += 1;
        }
    }
    assert!(n > 50, "{n} rows with a runner-up");
}

#[test]
fn clouds_without_times_are_kept_apart_by_position() {
    let Some(data) = shared_data("clouds_without_times") else { return };
    let dir = scratch_dir("truth_untimed");
    let folder = dir.join("clouds");
    std::fs::create_dir_all(&folder).unwrap();
    for i in 0..6 {
        std::fs::copy(data.join("pcd/nebula/velodyne_vlp16.pcd"), folder.join(format!("{i:04}.pcd")))
            .unwrap();
    }
    let o = toporec_in(&dir, &["loops", "clouds", "--no-progress", "-o", "l.csv"]);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("6 of 6 scans have no time") && err.contains("within 300 positions"), "{err}");
    assert!(err.contains("no loop could be sought") && err.contains("--exclude-seconds 30"), "{err}");
    let scans = IndexReader::open(&dir.join("out/clouds")).unwrap().scans().unwrap();
    assert!(scans.iter().all(|s| s.utime.is_none()), "no made-up times");
    // By position: a scan two files on from another is a candidate.
    let o = toporec_in(&dir, &["loops", "clouds", "--no-progress", "--exclude-scans", "1", "-o", "l.csv"]);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(!err.contains("no loop could be sought"), "{err}");
    let table = std::fs::read_to_string(dir.join("l.csv")).unwrap();
    assert!(table.lines().count() > 1, "{table}");
    for l in table.lines().skip(1) {
        let c: Vec<&str> = l.split(',').collect();
        let frame = |s: &str| s.rsplit('/').next().unwrap().parse::<i64>().unwrap();
        assert!(frame(c[1]) - frame(c[3]) > 1, "{l}");
    }
}

#[test]
fn a_file_named_as_a_log_is_recognised_by_its_content() {
    let Some(data) = shared_data("a_file_named_as_a_log") else { return };
    let dir = scratch_dir("truth_logs");
    std::fs::write(dir.join("empty.bag"), "").unwrap();
    std::fs::write(dir.join("text.bag"), "hello\n").unwrap();
    std::fs::write(dir.join("old.bag"), "#ROSBAG V1.2\n\0\0\0\0").unwrap();
    std::fs::write(dir.join("junk.mcap"), "junk\n").unwrap();
    std::fs::write(dir.join("junk.db3"), "junk\n").unwrap();
    {
        let c = rusqlite::Connection::open(dir.join("plain.db3")).unwrap();
        c.execute("CREATE TABLE notes (x TEXT)", []).unwrap();
    }
    for (file, said) in [
        ("empty.bag", "not a ROS 1 bag: no `#ROSBAG V2.0` header (found an empty file)"),
        ("text.bag", "not a ROS 1 bag: no `#ROSBAG V2.0` header (found text: `hello`)"),
        ("old.bag", "not a ROS 1 bag toporec reads: a `#ROSBAG V1.2` header"),
        ("junk.mcap", "not an MCAP file: no MCAP magic (found text: `junk`)"),
        ("junk.db3", "not a rosbag2 .db3 file: no SQLite header"),
        ("plain.db3", "a SQLite database without rosbag2's tables"),
    ] {
        let o = toporec_in(&dir, &["loops", file, "--no-progress", "-o", "l.csv"]);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{file}: {err}");
        assert!(err.contains(said), "{file}: {err}");
        assert!(!dir.join("out").exists() && !dir.join("l.csv").exists(), "{file}: nothing written");
    }
    // A valid MCAP named `.bag` is read as the MCAP it is.
    std::fs::copy(data.join("mcap/kitti_ros2_cdr.mcap"), dir.join("real.bag")).unwrap();
    let o = toporec_in(&dir, &["loops", "real.bag", "--no-progress", "--no-verify", "-o", "l.csv"]);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("(4 scans read"), "{err}");
}

#[test]
fn loops_help_says_what_the_one_command_does() {
    let top = text(&toporec(&["--help"]).stdout);
    assert!(top.contains("loops <log>") && top.contains("out/<log name>") && top.contains(".png"), "{top}");
    let help = text(&toporec(&["loops", "--help"]).stdout);
    assert!(
        help.contains("default: the one calibrated for the method's settings") && help.contains("> 0"),
        "{help}"
    );
}

#[test]
fn a_single_scan_is_said_to_leave_nothing_to_match() {
    let Some(data) = shared_data("a_single_scan_is_said_to_leave_nothing_to_match") else { return };
    let dir = scratch_dir("truth_single_scan");
    let session = data.join("nclt/2012-01-15");
    let o = toporec_in(&dir, &["loops", session.to_str().unwrap(), "--no-progress", "-o", "l.csv"]);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("1 scans read") || err.contains("1 scan read"), "{err}");
    assert!(err.contains("no loop could be sought: one scan"), "{err}");
}

#[test]
fn an_output_that_is_a_directory_is_refused_before_anything_is_written() {
    let dir = scratch_dir("truth_out_directory");
    bag_in(&dir);
    std::fs::create_dir_all(dir.join("table")).unwrap();
    let o = loops(&dir, &["-o", "table"]);
    assert!(!o.status.success());
    assert!(text(&o.stderr).contains("table: is a directory"), "{}", text(&o.stderr));
    let mut left: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, ["drive.bag", "table"], "no index, poses or picture written");
}

#[test]
fn kitti_sequences_are_frames_of_their_own() {
    // Each sequence's poses.txt starts at its own first frame: two sequences' first scans both
    // sit at the origin without being one place.
    let Some(data) = shared_data("kitti_sequences_are_frames_of_their_own") else { return };
    let dir = scratch_dir("truth_kitti_frames");
    let seq = |n: &str| data.join("kitti/sequences").join(n).to_string_lossy().into_owned();
    let (s00, s01, s02) = (seq("00"), seq("01"), seq("02"));
    let common = ["--no-progress", "--no-optimize", "--all", "--exclude-seconds", "0.5", "-t", "2"];
    let mut args = vec!["loops", s00.as_str(), s01.as_str(), s02.as_str(), "-o", "l.csv"];
    args.extend_from_slice(&common);
    let o = toporec_in(&dir, &args);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let info = toporec_in(&dir, &["info", "--index", "out/00"]);
    assert_eq!(text(&info.stdout).matches("a frame of its own").count(), 3, "{}", text(&info.stdout));
    // The revisits of the three are those of each alone: none is counted across sequences.
    let revisits = |session: Option<&str>| -> (usize, String) {
        let mut args = vec!["loops", "--index", "out/00", "-o", "i.csv"];
        args.extend_from_slice(&common);
        if let Some(s) = session {
            args.extend_from_slice(&["--session", s]);
        }
        let o = toporec_in(&dir, &args);
        let err = text(&o.stderr);
        assert!(o.status.success(), "{err}");
        let line = err.lines().find(|l| l.starts_with("loops (toporec-plus)")).unwrap().to_string();
        let n = line.split(" revisits found").next().filter(|_| line.contains(" revisits found"));
        (n.map_or(0, |n| n.rsplit(" of ").next().unwrap().parse().unwrap()), line)
    };
    let each: usize = ["00", "01", "02"].into_iter().map(|s| revisits(Some(s)).0).sum();
    let (all, line) = revisits(None);
    assert!(each > 0, "sequence 00 revisits its start");
    assert_eq!(all, each, "{line}");
    for csv in ["l.csv", "i.csv"] {
        let table = std::fs::read_to_string(dir.join(csv)).unwrap();
        let header: Vec<&str> = table.lines().next().unwrap().split(',').collect();
        let at = |name: &str| header.iter().position(|c| *c == name).unwrap();
        let (q, m, t) = (at("query_session"), at("matched_session"), at("true_distance_m"));
        let (mut within, mut across) = (0, 0);
        for l in table.lines().skip(1) {
            let c: Vec<&str> = l.split(',').collect();
            if c[q] == c[m] {
                assert!(c[t].parse::<f64>().is_ok(), "{csv}: {l}");
                within += 1;
            } else {
                assert_eq!(c[t], "", "{csv}: no true distance between two sequences: {l}");
                across += 1;
            }
        }
        assert!(within > 0 && across > 0, "{csv}: {within} within a sequence, {across} across");
    }
}
