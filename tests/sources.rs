//! Sources: real files in ../shared/data (NCLT, KITTI, MCAP), NCLT sessions and
//! `velodyne_hits` streams written here with bad files and garbage ground truth, and fuzzed
//! ground-truth files.

use crate::util::*;
use proptest::prelude::*;
use std::path::{Path, PathBuf};
use toporec::sources::kitti::KittiSpec;
use toporec::sources::logs::LogSpec;
use toporec::sources::nclt::{HITS_MAGIC, HitsScans, NcltSpec};
use toporec::sources::poses::PoseTable;
use toporec::sources::{Scan, ScanFailure, SourceSpec};

fn collect(spec: SourceSpec) -> (Vec<Scan>, Vec<ScanFailure>) {
    let mut ok = Vec::new();
    let mut bad = Vec::new();
    for item in spec.open().unwrap_or_else(|e| panic!("{e}")) {
        match item {
            Ok(s) => ok.push(s),
            Err(f) => bad.push(f),
        }
    }
    (ok, bad)
}

// ---------------------------------------------------------------- real files

#[test]
fn real_nclt_scan() {
    let Some(data) = shared_data("real_nclt_scan") else { return };
    let (scans, bad) = collect(SourceSpec::new(NcltSpec::sessions(vec![data.join("nclt/2012-01-15")])));
    assert!(bad.is_empty());
    assert_eq!(scans.len(), 1);
    let s = &scans[0];
    assert_eq!((s.points.len(), s.raw_points), (23_546, 23_546));
    assert_eq!(
        (s.id.as_str(), s.session.as_str(), s.utime),
        ("2012-01-15/1326652795280148", "2012-01-15", Some(1326652795280148))
    );
    let ring = s.ring.as_ref().unwrap();
    assert_eq!((ring.iter().min(), ring.iter().max()), (Some(&0), Some(&31)));
    let mut ids: Vec<u16> = ring.clone();
    ids.sort();
    ids.dedup();
    assert_eq!(ids.len(), 32, "all 32 lasers present");
    let max_range =
        s.points.iter().map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()).fold(0.0, f64::max);
    assert!(max_range <= 81.0 && max_range > 75.0, "max range {max_range}");
    assert!(s.pose.is_none(), "no ground truth beside this scan");
}

#[test]
fn real_ros1_mcap() {
    let Some(data) = shared_data("real_ros1_mcap") else { return };
    let path = data.join("mcap/ouster_os1_ros1.mcap");
    let (scans, bad) = collect(SourceSpec::new(LogSpec::path(&path)));
    assert!(bad.is_empty(), "{bad:?}");
    assert_eq!(scans.len(), 2, "2 clouds on /os1_cloud_node/points");
    for (i, s) in scans.iter().enumerate() {
        assert_eq!(s.raw_points, 131_072, "64 x 2048 before dropping");
        assert_eq!(s.message_index, Some(i as u64));
        assert_eq!(s.id, format!("ouster_os1_ros1/{i:06}"));
        assert_eq!(s.intensity.as_ref().unwrap().len(), s.points.len());
        assert!(s.ring.as_ref().unwrap().iter().all(|&r| r < 64));
        assert!(s.points.iter().all(|p| p.iter().all(|v| v.is_finite()) && *p != [0.0; 3]));
    }
    // Kept after dropping the (0, 0, 0) no-returns: counted independently with the Python `mcap`
    // reader and numpy (points with finite x, y, z other than (0, 0, 0)).
    assert_eq!([scans[0].points.len(), scans[1].points.len()], [45_716, 45_809]);
}

fn kitti_points(path: &Path) -> Vec<[f64; 3]> {
    read_cloud(path)
}

#[test]
fn real_ros2_mcap_equals_kitti_files() {
    let Some(data) = shared_data("real_ros2_mcap_equals_kitti_files") else { return };
    let (scans, bad) = collect(SourceSpec::new(LogSpec::path(&data.join("mcap/kitti_ros2_cdr.mcap"))));
    assert!(bad.is_empty(), "{bad:?}");
    let counts: Vec<usize> = scans.iter().map(|s| s.points.len()).collect();
    // The KITTI files' record counts (numpy: file size / 16; none is (0, 0, 0)).
    assert_eq!(counts, [121_618, 121_671, 123_034, 122_914]);
    for (s, frame) in scans.iter().zip(["000094", "000095", "000198", "000199"]) {
        let k = kitti_points(&data.join(format!("kitti/sequences/00/velodyne/{frame}.bin")));
        // Both decode float32 to f64 losslessly: equal as float32 means equal here.
        assert!(s.points == k, "message {:?} differs from KITTI {frame}", s.message_index);
    }
}

#[test]
fn real_nclt_session_joins_ground_truth() {
    let Some(data) = shared_data("real_nclt_session_joins_ground_truth") else { return };
    // The folder holding the session: expanded to its sessions; ground truth found beside.
    let (scans, bad) = collect(SourceSpec::new(NcltSpec::sessions(vec![data.join("nclt_from_kitti")])));
    assert!(bad.is_empty());
    assert_eq!(scans.len(), 14);
    assert!(scans.windows(2).all(|w| w[0].utime < w[1].utime), "sorted by utime");
    let gt = PoseTable::read_nclt(&data.join("nclt_from_kitti/groundtruth_2011-10-03.csv")).unwrap();
    for s in &scans {
        let pose = s.pose.unwrap_or_else(|| panic!("{} has no pose", s.id));
        let row = gt.rows.iter().find(|r| Some(r.0) == s.utime).expect("an exact ground-truth row");
        assert_eq!(Some(pose), row.1);
    }
    // z up: the ground (2 m below the sensor) has negative z.
    let zs: Vec<f64> = scans[0].points.iter().map(|p| p[2]).collect();
    let below = zs.iter().filter(|&&z| z < -1.0).count();
    assert!(below > zs.len() / 4, "most returns are ground below the sensor: {below}/{}", zs.len());
}

#[test]
fn real_kitti_sequence_with_times_and_poses() {
    let Some(data) = shared_data("real_kitti_sequence_with_times_and_poses") else { return };
    let dir = data.join("kitti/sequences/00");
    let (scans, bad) = collect(SourceSpec::new(KittiSpec { sequences: vec![dir.clone()] }));
    assert!(bad.is_empty());
    let ids: Vec<&str> = scans.iter().map(|s| s.id.as_str()).collect();
    assert_eq!(
        ids,
        [
            "00/000000",
            "00/000003",
            "00/000006",
            "00/000009",
            "00/000094",
            "00/000095",
            "00/000198",
            "00/000199"
        ]
    );
    let times: Vec<f64> = std::fs::read_to_string(dir.join("times.txt"))
        .unwrap()
        .lines()
        .map(|l| l.trim().parse().unwrap())
        .collect();
    let pose_line: Vec<f64> = std::fs::read_to_string(dir.join("poses.txt"))
        .unwrap()
        .lines()
        .nth(198)
        .unwrap()
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    let s = &scans[6];
    assert_eq!(s.utime, Some((times[198] * 1e6).round() as i64));
    let p = s.pose.unwrap();
    assert_eq!(
        (p.x, p.y, p.z),
        (pose_line[11], -pose_line[3], -pose_line[7]),
        "camera (x right, y down, z fwd) → z up"
    );
}

// ---------------------------------------------------------------- PointCloud2 byte fixtures

fn nclt_record(p: [f64; 3], intensity: u8, laser: u8) -> [u8; 8] {
    // Stored z down: (x, −y, −z) of the exposed point.
    let q = [p[0], -p[1], -p[2]].map(|v| ((v + 100.0) / 0.005).round() as u16);
    let mut r = [0u8; 8];
    r[0..2].copy_from_slice(&q[0].to_le_bytes());
    r[2..4].copy_from_slice(&q[1].to_le_bytes());
    r[4..6].copy_from_slice(&q[2].to_le_bytes());
    r[6] = intensity;
    r[7] = laser;
    r
}

#[test]
fn nclt_session_with_bad_files_and_garbage_ground_truth() {
    let dir = scratch_dir("nclt_session");
    let session = dir.join("2020-01-01");
    let sync = session.join("velodyne_sync");
    std::fs::create_dir_all(&sync).unwrap();
    for (utime, n) in [(1_000_000i64, 10usize), (2_000_000, 12), (3_000_000, 9)] {
        let bytes: Vec<u8> =
            (0..n).flat_map(|i| nclt_record([i as f64, 2.0, -1.5], 7, (i % 32) as u8)).collect();
        std::fs::write(sync.join(format!("{utime}.bin")), bytes).unwrap();
    }
    // A truncated scan (not a multiple of 8 bytes) and a non-utime name.
    std::fs::write(sync.join("2500000.bin"), [0u8; 13]).unwrap();
    std::fs::write(sync.join("notes.bin"), [0u8; 8]).unwrap();
    std::fs::write(
        dir.join("groundtruth_2020-01-01.csv"),
        "1000010,1.0,2.0,3.0,0,0,0.5\ngarbage line\n2000000,NaN,NaN,NaN,NaN,NaN,NaN\n2100000,4.0,5.0,6.0,0,0,0\n3000000,7,8,9,0,0\n",
    )
    .unwrap();
    let gt = PoseTable::read_nclt(&dir.join("groundtruth_2020-01-01.csv")).unwrap();
    assert_eq!((gt.rows.len(), gt.non_finite_rows, gt.bad_lines.len()), (3, 1, 2));
    // Named by line: the run that reads the file warns once, with the file and the count.
    assert!(gt.bad_lines[0].starts_with("line 2: "), "{}", gt.bad_lines[0]);
    assert!(gt.bad_lines[1].starts_with("line 5: "), "short row");
    let spec = NcltSpec { tolerance_ms: 150.0, ..NcltSpec::sessions(vec![session.clone()]) };
    let (scans, bad) = collect(SourceSpec::new(spec));
    assert_eq!(
        scans.iter().map(|s| s.utime).collect::<Vec<_>>(),
        [Some(1_000_000), Some(2_000_000), Some(3_000_000)]
    );
    assert_eq!(bad.len(), 2);
    assert!(bad.iter().any(|f| f.error.contains("2500000.bin: truncated")), "{bad:?}");
    assert!(bad.iter().any(|f| f.error.contains("notes.bin: file name is not a utime")), "{bad:?}");
    // Poses: nearest row within 150 ms, exposed z up: (x, −y, −z), yaw = −heading.
    let p0 = scans[0].pose.unwrap();
    assert_eq!((p0.x, p0.y, p0.z, p0.yaw), (1.0, -2.0, -3.0, -0.5));
    // The nearest row (at the same utime) is NaN: no pose, and the reason, though a finite
    // row is 100 ms away.
    assert_eq!((scans[1].pose, scans[1].no_pose), (None, Some(toporec::sources::NoPose::NonFinite)));
    assert!(scans[2].pose.is_none(), "the 3 s row was garbage: no pose within 150 ms");
    // Points round-trip the 5 mm quantization, z up.
    assert_eq!(scans[0].points[3], [3.0, 2.0, -1.5]);
    assert_eq!(scans[0].ring.as_ref().unwrap()[3], 3);
}

fn hits_packet(utime: u64, hits: &[[u8; 8]]) -> Vec<u8> {
    let mut p = HITS_MAGIC.to_vec();
    p.extend((hits.len() as u32).to_le_bytes());
    p.extend(utime.to_le_bytes());
    p.extend([0u8; 4]);
    hits.iter().for_each(|h| p.extend(h));
    p
}

/// Packets every 1 ms, each 3 hits at one azimuth, turning 10° per packet: 36 per turn.
fn hits_stream(packets: usize) -> Vec<u8> {
    (0..packets)
        .flat_map(|k| {
            let a = (k as f64 * 10.0 + 5.0).to_radians();
            let hits: Vec<[u8; 8]> =
                (0..3).map(|l| nclt_record([10.0 * a.cos(), 10.0 * a.sin(), l as f64], 1, l)).collect();
            hits_packet(1_000_000 + 1000 * k as u64, &hits)
        })
        .collect()
}

#[test]
fn velodyne_hits_cut_by_revolution_or_period_and_resync_after_garbage() {
    let bytes = hits_stream(36 * 3 + 10);
    let scans = |bytes: Vec<u8>, period: Option<i64>| -> (Vec<Scan>, Vec<ScanFailure>) {
        let it = HitsScans::new(
            std::io::Cursor::new(bytes),
            PathBuf::from("s/velodyne_hits.bin"),
            "s".into(),
            period,
            None,
            0,
        );
        let (mut ok, mut bad) = (vec![], vec![]);
        for x in it {
            match x {
                Ok(s) => ok.push(s),
                Err(f) => bad.push(f),
            }
        }
        (ok, bad)
    };
    let (ok, bad) = scans(bytes.clone(), None);
    assert!(bad.is_empty());
    assert_eq!(
        ok.iter().map(|s| s.points.len()).collect::<Vec<_>>(),
        [108, 108, 108, 30],
        "3 turns + the rest"
    );
    assert_eq!(ok[1].utime, Some(1_036_000));
    assert_eq!(ok[1].id, "s/1036000");
    // By period: 50 ms.
    let (ok, _) = scans(bytes.clone(), Some(50_000));
    assert_eq!(ok.iter().map(|s| s.points.len()).collect::<Vec<_>>(), [150, 150, 54]);
    // Garbage between packets: reported with its byte offset, then reading resumes.
    let packet = hits_stream(1).len();
    let mut g = bytes[..packet * 5].to_vec();
    g.extend(b"garbage!");
    g.extend(&bytes[packet * 5..]);
    let (ok, bad) = scans(g, None);
    assert_eq!(bad.len(), 1);
    assert!(
        bad[0].error.contains("velodyne_hits.bin: byte") && bad[0].error.contains("bad packet magic"),
        "{}",
        bad[0].error
    );
    assert_eq!(ok.iter().map(|s| s.points.len()).sum::<usize>(), 118 * 3);
    // Truncated tail: the scans so far, then an error.
    let (ok, bad) = scans(bytes[..bytes.len() - 5].to_vec(), None);
    assert_eq!(bad.len(), 1);
    assert!(bad[0].error.contains("truncated"));
    assert_eq!(ok.iter().map(|s| s.points.len()).sum::<usize>(), 117 * 3);
}

// ---------------------------------------------------------------- fuzzing

// NCLT and KITTI decoding, 1,500 inputs each.
proptest! {
    #![proptest_config(ProptestConfig { cases: 1500, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn fuzz_hits_and_sync_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300), prefix in any::<bool>()) {
        let mut input = if prefix { hits_stream(2) } else { vec![] };
        input.extend(&bytes);
        let path = PathBuf::from("fuzz/velodyne_hits.bin");
        for _ in HitsScans::new(std::io::Cursor::new(input.clone()), path.clone(), "f".into(), None, None, 0) {}
        let _ = toporec::sources::nclt::decode_sync(&input, &path);
        let _ = toporec::sources::kitti::decode(&input, &path);
    }
}

/// A ground-truth line: a real row, or one of the things users' files hold.
fn gt_line() -> impl Strategy<Value = String> {
    let number = prop_oneof![
        (-1e6f64..1e6).prop_map(|x| x.to_string()),
        Just("NaN".to_string()),
        Just("inf".to_string()),
        Just("-inf".to_string()),
        Just("".to_string()),
        Just("\"1.5\"".to_string()),
        Just("x".to_string()),
    ];
    (proptest::collection::vec(number, 0..10), 0i64..10_000_000).prop_map(|(fields, utime)| {
        let mut row = vec![utime.to_string()];
        row.extend(fields);
        row.join(",")
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    /// Ground-truth and pose files as they come: a byte-order mark, CRLF, empty lines, NaN and
    /// inf, extra or missing columns. Parsing never panics; every kept pose is finite; and a
    /// scan joined to a row gets a finite pose or none, with the reason.
    #[test]
    fn fuzz_ground_truth_files(lines in proptest::collection::vec(gt_line(), 0..40), bom: bool, crlf: bool, utime in 0i64..10_000_000) {
        let end = if crlf { "\r\n" } else { "\n" };
        let mut text = if bom { "\u{feff}".to_string() } else { String::new() };
        text += &lines.join(end);
        let gt = PoseTable::parse_nclt(text.as_bytes(), Path::new("groundtruth_fuzz.csv"));
        for (_, pose) in &gt.rows {
            if let Some(p) = pose {
                prop_assert!([p.x, p.y, p.z, p.yaw].iter().all(|v| v.is_finite()));
            }
        }
        prop_assert!(gt.rows.len() + gt.bad_lines.len() <= lines.len());
        if let Ok(p) = gt.pose_at(utime, 100_000) {
            prop_assert!([p.x, p.y, p.z, p.yaw].iter().all(|v| v.is_finite()));
        }
    }

    /// KITTI side files with the same oddities: never a panic, never a non-finite pose.
    #[test]
    fn fuzz_kitti_side_files(times in proptest::collection::vec(prop_oneof![Just("0.1".to_string()), Just("nan".to_string()), Just("inf".to_string()), Just("".to_string()), Just("x".to_string())], 0..8),
                             poses in proptest::collection::vec(proptest::collection::vec(prop_oneof![Just("1".to_string()), Just("0".to_string()), Just("nan".to_string()), Just("inf".to_string())], 11..13), 0..8),
                             bom: bool, crlf: bool) {
        let dir = std::env::temp_dir().join(format!("toporec-fuzz-kitti-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("velodyne")).unwrap();
        let end = if crlf { "\r\n" } else { "\n" };
        let prefix = if bom { "\u{feff}" } else { "" };
        std::fs::write(dir.join("times.txt"), format!("{prefix}{}", times.join(end))).unwrap();
        let rows: Vec<String> = poses.iter().map(|r| r.join(" ")).collect();
        std::fs::write(dir.join("poses.txt"), format!("{prefix}{}", rows.join(end))).unwrap();
        if let Ok(seq) = toporec::sources::kitti::Sequence::read(&dir) {
            for p in seq.poses.iter().flatten() {
                prop_assert!([p.x, p.y, p.z, p.yaw].iter().all(|v| v.is_finite()));
            }
            prop_assert!(seq.times.iter().flatten().all(|t| t.is_finite()));
        }
    }
}
