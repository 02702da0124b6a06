//! `toporec loops <source>…` and `toporec run <source>…`: a log indexed and its loops found in
//! one command, with no pipeline file, its poses from the log; the same loops as a pipeline file
//! and `loops --verify` find; every bad input a clear error naming the file and what to pass.

use crate::util::*;
use std::path::{Path, PathBuf};
use toporec::sources::pointcloud2::{Encoding, PointCloud2, PointField, serialize};
use toporec::sources::rosmsg::{Iso, Stamped, odometry, tf_message};
use toporec::sources::wire::Wire;

/// A two-lap drive (the second the other way) simulated as a ROS 1 bag, a rosbag2 folder and
/// an MCAP with its ground truth, in `dir`.
fn drive(dir: &Path) -> PathBuf {
    let o = toporec(&[
        "simulate",
        "-o",
        dir.to_str().unwrap(),
        "--format",
        "bag,rosbag2,mcap",
        "--sessions",
        "1",
        "--laps",
        "2",
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
        "4",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    dir.to_owned()
}

/// The rows of a loops CSV, the true distance rounded to the millimetre (the poses come from
/// different files).
fn loop_rows(path: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let truth = header.iter().position(|c| *c == "true_distance_m").unwrap();
    lines
        .map(|l| {
            let mut cells: Vec<String> = l.split(',').map(str::to_string).collect();
            if let Ok(v) = cells[truth].parse::<f64>() {
                cells[truth] = format!("{v:.3}");
            }
            cells.join(",")
        })
        .collect()
}

#[test]
fn one_command_on_a_bag_finds_the_loops_a_pipeline_and_loops_verify_find_on_its_mcap() {
    let dir = drive(&scratch_dir("oneshot_drive"));
    let bag = dir.join("bag/2026-01-01.bag");
    let out = dir.join("loops.csv");
    let o = toporec(&[
        "loops",
        bag.to_str().unwrap(),
        "--index",
        dir.join("idx").to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--g2o",
        dir.join("loops.g2o").to_str().unwrap(),
        "--no-progress",
    ]);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("/tf chain odom → velodyne in the log"), "{err}");
    assert!(err.contains("with a pose") && err.contains("verified by ICP"), "{err}");
    assert!(dir.join("loops.png").is_file() && dir.join("loops.svg").is_file(), "the picture");
    assert!(dir.join("loops.toporec-plus.g2o").is_file(), "g2o per method");
    let ours = loop_rows(&out);
    assert!(ours.len() >= 10, "the second lap closes loops: {ours:?}");
    // toporec-plus with lateral views, written in the pipeline the index keeps.
    let made = std::fs::read_to_string(dir.join("idx/pipeline.toml")).unwrap();
    assert!(made.contains("lateral = [3.0]"), "{made}");
    assert!(err.contains("below 0.3289"), "the threshold of those settings: {err}");

    // By hand: the MCAP copy with its ground-truth file, a pipeline (toporec-plus with the
    // lateral views the one command chooses), then loops --verify.
    let mcap = dir.join("mcap/2026-01-01.mcap");
    let pipeline = format!(
        "[output]\nindex = {:?}\n[[sources]]\nkind = \"rosbag\"\npaths = [{:?}]\nposes = {:?}\n[descriptors]\nmethods = [\"toporec-plus\"]\n[toporec-plus]\nlateral = [3.0]\n",
        dir.join("by-hand").display().to_string(),
        mcap.display().to_string(),
        dir.join("mcap/groundtruth_2026-01-01.csv").display().to_string()
    );
    std::fs::write(dir.join("by-hand.toml"), pipeline).unwrap();
    let o = toporec(&["run", dir.join("by-hand.toml").to_str().unwrap(), "--no-progress"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let theirs = dir.join("by-hand.csv");
    let o = toporec(&[
        "loops",
        "--index",
        dir.join("by-hand").to_str().unwrap(),
        "--verify",
        "-o",
        theirs.to_str().unwrap(),
        "--no-progress",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(ours, loop_rows(&theirs), "the same loops, matches and checks");

    // The next call is incremental: nothing computed again.
    let o = toporec(&[
        "loops",
        bag.to_str().unwrap(),
        "--index",
        dir.join("idx").to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--no-progress",
    ]);
    assert!(text(&o.stderr).contains("0 computed"), "{}", text(&o.stderr));
    assert_eq!(loop_rows(&out), ours);

    // The rosbag2 copy of the drive: the same loops.
    let out2 = dir.join("loops2.csv");
    let o = toporec(&[
        "loops",
        dir.join("rosbag2/2026-01-01").to_str().unwrap(),
        "--index",
        dir.join("idx2").to_str().unwrap(),
        "-o",
        out2.to_str().unwrap(),
        "--no-progress",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(loop_rows(&out2), ours);
}

#[test]
fn run_on_a_source_prints_its_pipeline_and_that_pipeline_gives_the_same_index() {
    let dir = scratch_dir("oneshot_run");
    let o = toporec(&[
        "simulate",
        "-o",
        dir.to_str().unwrap(),
        "--format",
        "bag",
        "--sessions",
        "1",
        "--scans",
        "8",
        "--sensor",
        "vlp16",
        "--azimuth-res",
        "2",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let bag = dir.join("bag/2026-01-01.bag");
    let o =
        toporec(&["run", bag.to_str().unwrap(), "--index", dir.join("a").to_str().unwrap(), "--no-progress"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let pipeline = text(&o.stdout);
    assert!(
        pipeline.contains("poses_topic = \"/tf\"") && pipeline.contains("pose_frames = \"odom:velodyne\""),
        "{pipeline}"
    );
    assert_eq!(pipeline, std::fs::read_to_string(dir.join("a/pipeline.toml")).unwrap());
    let p = dir.join("printed.toml");
    std::fs::write(&p, &pipeline).unwrap();
    let o =
        toporec(&["run", p.to_str().unwrap(), "--index", dir.join("b").to_str().unwrap(), "--no-progress"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    for table in ["scans", "diagrams", "descriptors"] {
        assert_eq!(rows(&dir.join("a"), table), rows(&dir.join("b"), table), "{table}");
    }
}

/// An MCAP of `clouds` (topic, frame, stamps in s) and pose messages (topic, kind, stamped).
fn log_with(path: &Path, clouds: &[(&str, &str, f64)], poses: &[(&str, &str, Stamped)]) {
    let file = std::fs::File::create(path).unwrap();
    let mut w = mcap::WriteOptions::new().profile("ros2").create(std::io::BufWriter::new(file)).unwrap();
    let mut channels = std::collections::HashMap::new();
    let mut channel = |w: &mut mcap::Writer<_>, topic: &str, schema: &str| -> u16 {
        *channels.entry(topic.to_string()).or_insert_with(|| {
            let s = w.add_schema(schema, "ros2msg", b"").unwrap();
            w.add_channel(s, topic, "cdr", &Default::default()).unwrap()
        })
    };
    let mut messages: Vec<(u64, u16, Vec<u8>)> = Vec::new();
    for (topic, frame, t) in clouds {
        let data: Vec<u8> = (0..300)
            .flat_map(|i| [i as f32 * 0.1, (i % 7) as f32, 1.0].map(f32::to_le_bytes))
            .flatten()
            .collect();
        let fields = ["x", "y", "z"]
            .iter()
            .enumerate()
            .map(|(i, n)| PointField { name: n.to_string(), offset: 4 * i as u32, datatype: 7, count: 1 })
            .collect();
        let stamp_ns = (t * 1e9) as i64;
        let cloud = PointCloud2 {
            stamp_ns,
            frame_id: frame.to_string(),
            height: 1,
            width: 300,
            fields,
            is_bigendian: false,
            point_step: 12,
            row_step: 3600,
            data: &data,
        };
        let c = channel(&mut w, topic, "sensor_msgs/msg/PointCloud2");
        messages.push((stamp_ns as u64, c, serialize(&cloud, Encoding::Cdr)));
    }
    for (topic, schema, s) in poses {
        let c = channel(&mut w, topic, schema);
        let data = if schema.contains("TFMessage") {
            tf_message(std::slice::from_ref(s), Wire::Cdr)
        } else {
            odometry(s, Wire::Cdr)
        };
        messages.push((s.stamp_ns as u64, c, data));
    }
    messages.sort_by_key(|m| m.0);
    for (i, (t, c, data)) in messages.into_iter().enumerate() {
        let header =
            mcap::records::MessageHeader { channel_id: c, sequence: i as u32, log_time: t, publish_time: t };
        w.write_to_known_channel(&header, &data).unwrap();
    }
    w.finish().unwrap();
}

fn at(t: f64, parent: &str, child: &str, x: f64) -> Stamped {
    Stamped {
        stamp_ns: (t * 1e9) as i64,
        parent: parent.into(),
        child: child.into(),
        pose: Iso::translation(x, 0.0, 0.0),
    }
}

#[test]
fn bad_logs_and_pose_choices_are_clear_errors_naming_the_file_and_what_to_pass() {
    let dir = scratch_dir("oneshot_bad");
    let clouds = |topic: &'static str| -> Vec<(&'static str, &'static str, f64)> {
        (0..4).map(|k| (topic, "lidar", 1.0 + k as f64)).collect()
    };
    let loops = |path: &Path, extra: &[&str]| {
        let mut args = vec!["loops", path.to_str().unwrap(), "--index"];
        let index = dir.join(format!("idx-{}", path.file_stem().unwrap().to_string_lossy()));
        args.push(index.to_str().unwrap());
        let out = dir.join("loops.csv");
        args.extend(["-o", out.to_str().unwrap()]);
        args.extend(extra);
        let o = toporec(&args);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{path:?} {extra:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        assert_eq!(err.lines().filter(|l| l.starts_with("error:")).count(), 1, "one error line: {err}");
        err
    };
    let names =
        |err: &str, path: &Path| assert!(err.contains(path.to_str().unwrap()), "names {path:?}: {err}");
    // No point cloud.
    let p = dir.join("no_cloud.mcap");
    log_with(&p, &[], &[("/odom", "nav_msgs/msg/Odometry", at(1.0, "odom", "lidar", 0.0))]);
    let e = loops(&p, &[]);
    assert!(e.contains("no sensor_msgs/PointCloud2 topic"), "{e}");
    names(&e, &p);
    // Several point-cloud topics and no --topic.
    let p = dir.join("two_clouds.mcap");
    let mut both = clouds("/a");
    both.extend(clouds("/b"));
    log_with(&p, &both, &[]);
    let e = loops(&p, &[]);
    assert!(e.contains("several point-cloud topics"), "{e}");
    names(&e, &p);
    // Several pose topics, no /tf chain, no --poses-topic.
    let p = dir.join("two_odoms.mcap");
    let odom = |topic: &'static str| (topic, "nav_msgs/msg/Odometry", at(1.0, "odom", "lidar", 0.0));
    log_with(&p, &clouds("/points"), &[odom("/odom"), odom("/odom2")]);
    let e = loops(&p, &[]);
    assert!(e.contains("several pose topics") && e.contains("--poses-topic"), "{e}");
    names(&e, &p);
    // Odometry that never overlaps the scans.
    let p = dir.join("late_odom.mcap");
    log_with(&p, &clouds("/points"), &[("/odom", "nav_msgs/msg/Odometry", at(500.0, "odom", "lidar", 0.0))]);
    let e = loops(&p, &[]);
    assert!(e.contains("no pose within 100 ms of any scan"), "{e}");
    names(&e, &p);
    // A chain that does not reach the cloud's frame.
    let p = dir.join("short_chain.mcap");
    let tf: Vec<_> = (0..5)
        .map(|k| ("/tf", "tf2_msgs/msg/TFMessage", at(1.0 + k as f64, "odom", "base_link", k as f64)))
        .collect();
    log_with(&p, &clouds("/points"), &tf);
    let e = loops(&p, &["--pose-frames", "odom:lidar"]);
    assert!(e.contains("no /tf chain from odom to lidar") && e.contains("--pose-frames"), "{e}");
    names(&e, &p);
    // A pose file in no known layout.
    let p = dir.join("plain.mcap");
    log_with(&p, &clouds("/points"), &[]);
    let junk = dir.join("poses.txt");
    std::fs::write(&junk, "these are not poses\n1 2 3\n").unwrap();
    let e = loops(&p, &["--poses", junk.to_str().unwrap()]);
    assert!(e.contains("--poses-format"), "{e}");
    names(&e, &junk);
}
