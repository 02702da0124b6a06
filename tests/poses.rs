//! Poses from the log itself: `/tf` and `/tf_static` chains, odometry with the sensor's mounting,
//! and pose files (TUM, KITTI, NCLT), joined at each scan's header stamp. The real bags of
//! `../shared/data/bags` carry KITTI's own poses (an independent writer made them): the joined
//! poses equal `odom_expected.csv`.

use crate::util::*;
use std::path::{Path, PathBuf};
use toporec::sources::Source;
use toporec::sources::logs::LogSpec;

/// `(frame, x, y, z, yaw°)` of `odom_expected.csv`.
fn expected(bags: &Path) -> Vec<(u64, [f64; 4])> {
    let text = std::fs::read_to_string(bags.join("odom_expected.csv")).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            (v[0] as u64, [v[2], v[3], v[4], v[5]])
        })
        .collect()
}

/// The scans' poses (x, y, z, yaw°) a spec joins, in order.
fn joined(spec: LogSpec) -> Vec<[f64; 4]> {
    spec.open()
        .unwrap()
        .map(|s| {
            let s = s.unwrap_or_else(|f| panic!("{f}"));
            let p = s.pose.unwrap_or_else(|| panic!("scan {} has no pose ({:?})", s.id, s.no_pose));
            [p.x, p.y, p.z, p.yaw.to_degrees()]
        })
        .collect()
}

fn assert_poses(got: &[[f64; 4]], want: &[(u64, [f64; 4])], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}");
    for (g, (frame, w)) in got.iter().zip(want) {
        for k in 0..3 {
            assert!((g[k] - w[k]).abs() <= 1e-3, "{what}, frame {frame}: {g:?} against {w:?} (1 mm)");
        }
        let dyaw = (g[3] - w[3] + 180.0).rem_euclid(360.0) - 180.0;
        assert!(dyaw.abs() <= 0.01, "{what}, frame {frame}: yaw {} against {} (0.01°)", g[3], w[3]);
    }
}

#[test]
fn the_real_bags_poses_equal_kittis_from_the_tf_chain_and_from_odometry_with_its_mounting() {
    let Some(data) = shared_data("poses_real_bags") else { return };
    let bags = data.join("bags");
    let want = expected(&bags);
    for log in ["kitti00_odom_ros1.bag", "kitti00_odom_rosbag2_mcap"] {
        let path = bags.join(log);
        // Without keys: the /tf chain odom → base_link → velodyne.
        let (_, choice) = LogSpec::path(&path).pose_choice(&path).unwrap();
        let choice = choice.expect("a choice");
        assert_eq!(choice.describe(), "/tf chain odom → velodyne", "{log}");
        assert_poses(&joined(LogSpec::path(&path)), &want, &format!("{log}, /tf"));
        // /odom gives base_link's pose: the mounting from /tf_static makes it the sensor's.
        let odom = LogSpec { poses_topic: Some("/odom".into()), ..LogSpec::path(&path) };
        assert_poses(&joined(odom), &want, &format!("{log}, /odom"));
        // The frames named.
        let frames = LogSpec { pose_frames: Some("odom:velodyne".into()), ..LogSpec::path(&path) };
        assert_poses(&joined(frames), &want, &format!("{log}, odom:velodyne"));
    }
}

#[test]
fn inspect_lists_the_pose_candidates_and_the_one_it_would_use() {
    let Some(data) = shared_data("poses_inspect") else { return };
    let o = toporec(&["inspect", data.join("bags/kitti00_odom_ros1.bag").to_str().unwrap()]);
    let out = text(&o.stdout);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(out.contains("pose candidate: /tf chain odom → base_link → velodyne"), "{out}");
    assert!(out.contains("pose candidate: /odom (nav_msgs/Odometry, of base_link"), "{out}");
    assert!(out.contains("poses joined: from /tf chain odom → velodyne"), "{out}");
    // A bag without poses says so.
    let o = toporec(&["inspect", data.join("bags/kitti00_ros1_lz4.bag").to_str().unwrap()]);
    assert!(text(&o.stdout).contains("poses joined: none in the log"), "{}", text(&o.stdout));
}

/// A drive simulated as a ROS 1 bag and a rosbag2 folder (odometry, /tf, /tf_static) and as an
/// MCAP with its ground-truth file, in `dir`.
fn simulated(dir: &Path, scans: usize) -> PathBuf {
    let o = toporec(&[
        "simulate",
        "-o",
        dir.to_str().unwrap(),
        "--format",
        "bag,rosbag2,mcap",
        "--sessions",
        "1",
        "--scans",
        &scans.to_string(),
        "--sensor",
        "vlp16",
        "--azimuth-res",
        "2",
        "--rate",
        "2",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    dir.to_owned()
}

/// The simulated drive's ground-truth file.
fn ground_truth(dir: &Path) -> toporec::sources::poses::PoseTable {
    toporec::sources::poses::PoseTable::read_nclt(&dir.join("mcap/groundtruth_2026-01-01.csv")).unwrap()
}

/// A ground truth scan by scan: (scan index, [x, y, z, yaw°]).
fn truth(gt: &toporec::sources::poses::PoseTable) -> Vec<(u64, [f64; 4])> {
    gt.rows
        .iter()
        .enumerate()
        .map(|(i, (_, p))| {
            let p = p.unwrap();
            (i as u64, [p.x, p.y, p.z, p.yaw.to_degrees()])
        })
        .collect()
}

#[test]
fn a_simulated_bags_poses_are_its_ground_truth() {
    let dir = simulated(&scratch_dir("poses_simulated"), 12);
    let want = truth(&ground_truth(&dir));
    for log in ["bag/2026-01-01.bag", "rosbag2/2026-01-01"] {
        let path = dir.join(log);
        assert_poses(&joined(LogSpec::path(&path)), &want, &format!("{log}, /tf"));
        let odom = LogSpec { poses_topic: Some("/odom".into()), ..LogSpec::path(&path) };
        assert_poses(&joined(odom), &want, &format!("{log}, /odom"));
    }
}

#[test]
fn pose_files_in_tum_kitti_and_nclt_layouts_are_joined_by_time() {
    let dir = simulated(&scratch_dir("poses_files"), 6);
    let bag = dir.join("bag/2026-01-01.bag");
    let gt = ground_truth(&dir);
    let want = truth(&gt);
    let (mut tum, mut kitti, mut times) = (String::new(), String::new(), String::new());
    let t0 = gt.rows[0].0;
    for (t, p) in &gt.rows {
        let p = p.unwrap();
        let (s, c) = (p.yaw / 2.0).sin_cos();
        tum += &format!("{} {} {} {} 0 0 {s} {c}\n", *t as f64 * 1e-6, p.x, p.y, p.z);
        let (sy, cy) = p.yaw.sin_cos();
        kitti += &format!("{cy} {} 0 {} {sy} {cy} 0 {} 0 0 1 {}\n", -sy, p.x, p.y, p.z);
        times += &format!("{}\n", (t - t0) as f64 * 1e-6);
    }
    let write = |name: &str, text: &str| {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    let (tum, kitti, times) =
        (write("poses_tum.txt", &tum), write("poses_kitti.txt", &kitti), write("times.txt", &times));
    use toporec::sources::poses::PoseFormat;
    let with = |poses: &Path, format: PoseFormat, times: Option<&Path>| LogSpec {
        poses: Some(poses.to_owned()),
        poses_format: Some(format),
        poses_times: times.map(Path::to_owned),
        ..LogSpec::path(&bag)
    };
    assert_poses(&joined(with(&tum, PoseFormat::Tum, None)), &want, "TUM");
    assert_poses(&joined(with(&kitti, PoseFormat::Kitti, Some(&times))), &want, "KITTI with times.txt");
    let nclt = dir.join("mcap/groundtruth_2026-01-01.csv");
    assert_poses(&joined(with(&nclt, PoseFormat::Nclt, None)), &want, "NCLT");
    // KITTI rows without their times: a clear error.
    let e = match with(&kitti, PoseFormat::Kitti, None).open() {
        Ok(mut s) => s.next().unwrap().unwrap_err().error,
        Err(e) => e.to_string(),
    };
    assert!(e.contains("poses_times"), "{e}");
}
