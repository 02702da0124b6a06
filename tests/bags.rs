//! Bags: ROS 1 bags (bz2, lz4; with and without their index), rosbag2 folders (sqlite3 and
//! MCAP storage; split, file- and message-compressed variants written here from the real
//! folder), lone `.db3` files, and bad input. The reference is `mcap/kitti_ros2_cdr.mcap`: every
//! bag of `../shared/data/bags` holds its four real KITTI scans.

use crate::util::*;
use std::path::{Path, PathBuf};
use toporec::sources::Source;
use toporec::sources::logs::LogSpec;
use toporec::sources::{Scan, ScanFailure, SourceSpec};

fn collect(spec: SourceSpec) -> (Vec<Scan>, Vec<ScanFailure>) {
    let (mut ok, mut bad) = (Vec::new(), Vec::new());
    for item in spec.open().unwrap_or_else(|e| panic!("{e}")) {
        match item {
            Ok(s) => ok.push(s),
            Err(f) => bad.push(f),
        }
    }
    (ok, bad)
}

fn bag(path: &Path) -> (Vec<Scan>, Vec<ScanFailure>) {
    collect(SourceSpec::new(LogSpec::path(path)))
}

/// The reference scans: the MCAP's.
fn reference(data: &Path) -> Vec<Scan> {
    let (scans, bad) = collect(SourceSpec::new(LogSpec::path(&data.join("mcap/kitti_ros2_cdr.mcap"))));
    assert!(bad.is_empty(), "{bad:?}");
    assert_eq!(scans.len(), 4);
    scans
}

/// `got` holds the reference's scans, bit for bit: points, intensities, times, message indices;
/// ids `<session>/<index>`.
fn assert_same_scans(got: &[Scan], want: &[Scan], session: &str, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: scan count");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(g.points == w.points, "{what}: scan {i}'s points differ");
        assert_eq!(g.intensity, w.intensity, "{what}: scan {i}'s intensities");
        assert_eq!(
            (g.utime, g.message_index, g.raw_points),
            (w.utime, w.message_index, w.raw_points),
            "{what}: {i}"
        );
        assert_eq!(g.id, format!("{session}/{i:06}"), "{what}");
        assert_eq!(g.session, session, "{what}");
    }
}

#[test]
fn every_bag_format_yields_the_mcaps_scans_bit_for_bit() {
    let Some(data) = shared_data("every_bag_format_yields_the_mcaps_scans_bit_for_bit") else { return };
    let want = reference(&data);
    let bags = data.join("bags");
    for (path, session) in [
        (bags.join("kitti00_ros1_bz2.bag"), "kitti00_ros1_bz2"),
        (bags.join("kitti00_ros1_lz4.bag"), "kitti00_ros1_lz4"),
        (bags.join("kitti00_rosbag2_mcap"), "kitti00_rosbag2_mcap"),
        (bags.join("kitti00_rosbag2_sqlite3"), "kitti00_rosbag2_sqlite3"),
        (bags.join("kitti00_rosbag2_sqlite3/kitti00_rosbag2_sqlite3.db3"), "kitti00_rosbag2_sqlite3"),
        (bags.join("kitti00_rosbag2_mcap/kitti00_rosbag2_mcap.mcap"), "kitti00_rosbag2_mcap"),
    ] {
        let (got, bad) = bag(&path);
        assert!(bad.is_empty(), "{}: {bad:?}", path.display());
        assert_same_scans(&got, &want, session, &path.display().to_string());
    }
    // Each bag also holds a String topic: the point-cloud topic is found, or named.
    let spec =
        LogSpec { topic: Some("/chatter".into()), ..LogSpec::path(&bags.join("kitti00_ros1_lz4.bag")) };
    let (_, bad) = collect(SourceSpec::new(spec));
    assert!(bad[0].error.contains("not a PointCloud2"), "{bad:?}");
}

/// A ROS 1 bag's `index_pos` (the bag header's field).
fn index_pos(bytes: &[u8]) -> usize {
    let at = bytes.windows(10).position(|w| w == b"index_pos=").expect("index_pos field") + 10;
    u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap()) as usize
}

/// The bag without its index section, its header's `index_pos` zeroed: a recording cut short.
fn unindexed(bytes: &[u8]) -> Vec<u8> {
    let pos = index_pos(bytes);
    let mut out = bytes[..pos].to_vec();
    let at = out.windows(10).position(|w| w == b"index_pos=").unwrap() + 10;
    out[at..at + 8].fill(0);
    out
}

#[test]
fn a_ros1_bag_without_its_index_reads_the_same_and_a_cut_one_up_to_the_cut() {
    let Some(data) = shared_data("a_ros1_bag_without_its_index_reads_the_same") else { return };
    let want = reference(&data);
    let dir = scratch_dir("bags_unindexed");
    for name in ["kitti00_ros1_bz2", "kitti00_ros1_lz4"] {
        let bytes = std::fs::read(data.join(format!("bags/{name}.bag"))).unwrap();
        let path = dir.join(format!("{name}.bag"));
        let bare = unindexed(&bytes);
        std::fs::write(&path, &bare).unwrap();
        let (got, bad) = bag(&path);
        assert!(bad.is_empty(), "{name}: {bad:?}");
        assert_same_scans(&got, &want, name, name);
        let report = text(&toporec(&["inspect", path.to_str().unwrap()]).stdout);
        assert!(report.contains("index: no (read record by record)"), "{report}");
        // Cut inside its last third: the scans before the cut, then one failure naming the file
        // and the byte where the cut record starts; the scans after it are not claimed gone.
        std::fs::write(&path, &bare[..bare.len() * 2 / 3]).unwrap();
        let (got, bad) = bag(&path);
        assert!(!got.is_empty() && got.len() < 4, "{name}: {} scans", got.len());
        assert_same_scans(&got, &want[..got.len()], name, name);
        assert_eq!(bad.len(), 1, "{bad:?}");
        assert!(
            bad[0].error.contains(&format!("{name}.bag")) && bad[0].error.contains("record at byte"),
            "{}",
            bad[0].error
        );
        assert!(bad[0].error.contains("truncated"), "{}", bad[0].error);
        assert!(bad[0].input_unread);
    }
}

#[test]
fn a_corrupt_chunk_of_an_indexed_bag_costs_only_its_own_messages() {
    let Some(data) = shared_data("a_corrupt_chunk_of_an_indexed_bag") else { return };
    let want = reference(&data);
    let mut bytes = std::fs::read(data.join("bags/kitti00_ros1_lz4.bag")).unwrap();
    // The second chunk's LZ4 frame magic overwritten.
    let magic = [0x04, 0x22, 0x4d, 0x18];
    let frames: Vec<usize> =
        bytes.windows(4).enumerate().filter(|(_, w)| *w == magic).map(|(i, _)| i).collect();
    assert_eq!(frames.len(), 4, "one LZ4 frame per chunk");
    bytes[frames[1]..frames[1] + 4].fill(0);
    let dir = scratch_dir("bags_corrupt_chunk");
    let path = dir.join("corrupt.bag");
    std::fs::write(&path, &bytes).unwrap();
    let (got, bad) = bag(&path);
    assert_eq!(bad.len(), 1, "{bad:?}");
    assert!(
        bad[0].error.contains("corrupt.bag") && bad[0].error.contains("chunk 2 at byte"),
        "{}",
        bad[0].error
    );
    assert!(bad[0].error.contains("lz4"), "{}", bad[0].error);
    // The other chunks' scans, the same as the reference's; numbered as read.
    assert_eq!(got.len(), 3);
    let kept: Vec<&Scan> = want.iter().filter(|w| got.iter().any(|g| g.points == w.points)).collect();
    assert_eq!(kept.len(), 3, "the three other scans, bit for bit");
}

/// A rosbag2 folder of `files` with the given compression, as rosbag2 writes `metadata.yaml`.
fn rosbag2_folder(dir: &Path, storage: &str, files: &[&str], compression: Option<&str>) {
    let (format, mode) = match compression {
        Some(mode) => ("zstd", mode),
        None => ("", ""),
    };
    let list: String = files.iter().map(|f| format!("  - {f}\n")).collect();
    let yaml = format!(
        "rosbag2_bagfile_information:\n  version: 8\n  storage_identifier: {storage}\n  \
         compression_format: '{format}'\n  compression_mode: '{mode}'\n  relative_file_paths:\n{list}"
    );
    std::fs::write(dir.join("metadata.yaml"), yaml).unwrap();
}

fn zstd_file(from: &Path, to: &Path) {
    let bytes = std::fs::read(from).unwrap();
    std::fs::write(to, zstd::encode_all(bytes.as_slice(), 3).unwrap()).unwrap();
}

#[test]
fn rosbag2_folders_split_and_compressed_as_rosbag2_writes_them_read_the_same() {
    let Some(data) = shared_data("rosbag2_folders_split_and_compressed") else { return };
    let want = reference(&data);
    let db3 = data.join("bags/kitti00_rosbag2_sqlite3/kitti00_rosbag2_sqlite3.db3");
    let mcap = data.join("bags/kitti00_rosbag2_mcap/kitti00_rosbag2_mcap.mcap");
    let root = scratch_dir("bags_rosbag2");
    let folder = |name: &str| {
        let d = root.join(name);
        std::fs::create_dir_all(&d).unwrap();
        d
    };
    // Split in two at the third cloud's time: each file keeps its half of the messages.
    let split = folder("split");
    let third = {
        let c = rusqlite::Connection::open(&db3).unwrap();
        let mut s = c
            .prepare(
                "SELECT m.timestamp FROM messages m JOIN topics t ON m.topic_id = t.id \
                 WHERE t.name = '/velodyne_points' ORDER BY m.timestamp",
            )
            .unwrap();
        let times: Vec<i64> = s.query_map([], |r| r.get(0)).unwrap().map(|t| t.unwrap()).collect();
        times[2]
    };
    for (file, keep) in [("split_0.db3", "timestamp < ?1"), ("split_1.db3", "timestamp >= ?1")] {
        std::fs::copy(&db3, split.join(file)).unwrap();
        let c = rusqlite::Connection::open(split.join(file)).unwrap();
        c.execute(&format!("DELETE FROM messages WHERE NOT ({keep})"), [third]).unwrap();
    }
    rosbag2_folder(&split, "sqlite3", &["split_0.db3", "split_1.db3"], None);
    let (got, bad) = bag(&split);
    assert!(bad.is_empty(), "{bad:?}");
    assert_same_scans(&got, &want, "split", "split sqlite3");

    // compression_mode FILE: each storage file zstd-compressed whole.
    let filed = folder("filed");
    for f in ["split_0.db3", "split_1.db3"] {
        zstd_file(&split.join(f), &filed.join(format!("{f}.zstd")));
    }
    rosbag2_folder(&filed, "sqlite3", &["split_0.db3.zstd", "split_1.db3.zstd"], Some("FILE"));
    let (got, bad) = bag(&filed);
    assert!(bad.is_empty(), "{bad:?}");
    assert_same_scans(&got, &want, "filed", "FILE-compressed sqlite3");
    let filed_mcap = folder("filed_mcap");
    zstd_file(&mcap, &filed_mcap.join("a.mcap.zstd"));
    rosbag2_folder(&filed_mcap, "mcap", &["a.mcap.zstd"], Some("FILE"));
    let (got, bad) = bag(&filed_mcap);
    assert!(bad.is_empty(), "{bad:?}");
    assert_same_scans(&got, &want, "filed_mcap", "FILE-compressed mcap");

    // compression_mode MESSAGE: each message's bytes zstd-compressed.
    let per_message = folder("per_message");
    std::fs::copy(&db3, per_message.join("m.db3")).unwrap();
    {
        let c = rusqlite::Connection::open(per_message.join("m.db3")).unwrap();
        let rows: Vec<(i64, Vec<u8>)> = {
            let mut s = c.prepare("SELECT rowid, data FROM messages").unwrap();
            s.query_map([], |r| Ok((r.get(0)?, r.get(1)?))).unwrap().map(|r| r.unwrap()).collect()
        };
        for (rowid, bytes) in rows {
            let packed = zstd::encode_all(bytes.as_slice(), 3).unwrap();
            c.execute("UPDATE messages SET data = ?1 WHERE rowid = ?2", rusqlite::params![packed, rowid])
                .unwrap();
        }
    }
    rosbag2_folder(&per_message, "sqlite3", &["m.db3"], Some("MESSAGE"));
    let (got, bad) = bag(&per_message);
    assert!(bad.is_empty(), "{bad:?}");
    assert_same_scans(&got, &want, "per_message", "MESSAGE-compressed sqlite3");

    // A file the metadata lists but the folder lacks: one failure naming it; the rest is read.
    let missing = folder("missing");
    std::fs::copy(split.join("split_0.db3"), missing.join("split_0.db3")).unwrap();
    rosbag2_folder(&missing, "sqlite3", &["split_0.db3", "gone.db3"], None);
    let (got, bad) = bag(&missing);
    assert_same_scans(&got, &want[..2], "missing", "a missing split file");
    assert_eq!(bad.len(), 1, "{bad:?}");
    assert!(bad[0].error.contains("gone.db3") && bad[0].error.contains("missing"), "{}", bad[0].error);
}

#[test]
fn bad_bags_are_clear_errors_naming_the_file() {
    let dir = scratch_dir("bags_bad");
    let cases: Vec<(PathBuf, &str)> = {
        let db = dir.join("garbage.db3");
        let mut bytes = b"SQLite format 3\0".to_vec();
        bytes.extend(std::iter::repeat_n(0xa5u8, 4096));
        std::fs::write(&db, bytes).unwrap();
        let bag = dir.join("not-v2.bag");
        std::fs::write(&bag, b"#ROSBAG V2.0\n\x05\x00\x00\x00").unwrap();
        let yaml = dir.join("bad-yaml");
        std::fs::create_dir_all(&yaml).unwrap();
        std::fs::write(yaml.join("metadata.yaml"), "rosbag2_bagfile_information: [").unwrap();
        let storage = dir.join("other-storage");
        std::fs::create_dir_all(&storage).unwrap();
        rosbag2_folder(&storage, "bagfs", &["a.bagfs"], None);
        vec![
            (db, "sqlite3"),
            (bag, "bag header"),
            (yaml.clone(), "metadata.yaml"),
            (storage.clone(), "storage `bagfs`"),
        ]
    };
    for (path, needle) in cases {
        let (got, bad) = bag(&path);
        assert!(got.is_empty());
        assert_eq!(bad.len(), 1, "{}: {bad:?}", path.display());
        let e = &bad[0].error;
        assert!(e.contains(path.file_name().unwrap().to_str().unwrap()) && e.contains(needle), "{e}");
        assert!(bad[0].input_unread);
        // inspect says the same, as an error and a non-zero exit, never a panic.
        let o = toporec(&["inspect", path.to_str().unwrap()]);
        assert!(!o.status.success());
        let e = text(&o.stderr);
        assert!(e.contains(needle) && !e.contains("panicked"), "{e}");
    }
}

#[test]
fn a_pipeline_indexes_every_bag_with_every_method_and_query_reads_a_bag() {
    let Some(_) = shared_data("a_pipeline_indexes_every_bag") else { return };
    let dir = scratch_dir("bags_pipeline");
    let index = dir.join("index");
    let (o, summary) = run_with(&root().join("pipelines/rosbag.toml"), &index, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(counter(&summary, "computed"), 16, "{summary}");
    let ids = rows(&index, "scans");
    assert!(ids.iter().any(|r| r.contains("kitti00_ros1_bz2/000003")), "{ids:?}");
    // A second run finds nothing to redo.
    let (o, summary) = run_with(&root().join("pipelines/rosbag.toml"), &index, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!((counter(&summary, "computed"), counter(&summary, "up_to_date")), (0, 16), "{summary}");
    // A bag as a query: each of its scans finds itself (distance 0) in every other bag's copy.
    for method in ["toporec-plus", "scancontext"] {
        let o = toporec(&[
            "query",
            "--index",
            index.to_str().unwrap(),
            "--method",
            method,
            "-k",
            "4",
            "--session",
            "kitti00_rosbag2_sqlite3",
            root().join("../shared/data/bags/kitti00_ros1_lz4.bag").to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        let out = text(&o.stdout);
        let firsts: Vec<&str> = out.lines().skip(1).filter(|l| l.split(',').nth(1) == Some("1")).collect();
        assert_eq!(firsts.len(), 4, "{out}");
        for (i, line) in firsts.iter().enumerate() {
            assert!(line.contains(&format!("kitti00_rosbag2_sqlite3/{i:06}")), "{method}: {line}");
        }
    }
    // Loops over the bags' index: each scan of a later bag closes on its copy in an earlier
    // one (distance 0), and `--verify` reads both raw scans back from the bags and aligns them.
    let csv = dir.join("loops.csv");
    let o = toporec(&[
        "loops",
        "--index",
        index.to_str().unwrap(),
        "--method",
        "scancontext",
        "--threshold",
        "0.01",
        "--verify",
        "-o",
        csv.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let loops = std::fs::read_to_string(&csv).unwrap();
    let header: Vec<&str> = loops.lines().next().unwrap().split(',').collect();
    let column =
        |name: &str| header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("{name}: {header:?}"));
    let (query, matched, verified) = (column("query_scan"), column("matched_scan"), column("verified"));
    let found: Vec<Vec<&str>> = loops.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert_eq!(found.len(), 12, "{loops}");
    for row in &found {
        assert_eq!(row[query].split('/').nth(1), row[matched].split('/').nth(1), "{row:?}");
        assert_eq!(row[verified], "true", "{row:?}");
    }
}

/// A folder of PCD files indexed with every method by a `kind = "clouds"` pipeline; each
/// frame, queried from the folder, finds itself first with every method.
#[test]
fn a_pipeline_indexes_a_pcd_folder_with_every_method() {
    let Some(data) = shared_data("a_pipeline_indexes_a_pcd_folder_with_every_method") else { return };
    let dir = scratch_dir("pcd_folder_pipeline");
    let city = data.join("pcd/kitti_raw_city");
    let mut methods = vec!["toporec".to_string()];
    methods.extend(toporec::methods::computed_names().iter().map(|m| m.to_string()));
    let pipeline = dir.join("clouds.toml");
    std::fs::write(
        &pipeline,
        format!(
            "[output]\nindex = \"unused\"\n\n[[sources]]\nkind = \"clouds\"\nfolders = [{:?}]\n\n\
             [preprocess]\nsubsample = 1024\nnormalize = true\n\n[vectorize]\nb = 8\nseed = 0\n\n\
             [descriptors]\nmethods = {:?}\n",
            city.to_str().unwrap(),
            methods
        ),
    )
    .unwrap();
    let index = dir.join("index");
    let (o, summary) = run_with(&pipeline, &index, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(counter(&summary, "computed"), 2, "{summary}");
    for method in &methods {
        let o = toporec(&[
            "query",
            "--index",
            index.to_str().unwrap(),
            "--method",
            method,
            "-k",
            "1",
            city.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{method}: {}", text(&o.stderr));
        let out = text(&o.stdout);
        let hits: Vec<&str> = out.lines().skip(1).collect();
        assert_eq!(hits.len(), 2, "{method}: {out}");
        for (hit, frame) in hits.iter().zip(["0000000000", "0000000153"]) {
            assert_eq!(hit.matches(frame).count(), 2, "{method}: {hit}");
        }
    }
}

// ------------------------------------------------------------ a small bag, written here

/// A ROS 1 record: header fields, then data.
fn record(fields: &[(&str, &[u8])], data: &[u8]) -> Vec<u8> {
    let mut header = Vec::new();
    for (name, value) in fields {
        let field = [name.as_bytes(), b"=", value].concat();
        header.extend((field.len() as u32).to_le_bytes());
        header.extend(field);
    }
    let mut out = (header.len() as u32).to_le_bytes().to_vec();
    out.extend(header);
    out.extend((data.len() as u32).to_le_bytes());
    out.extend(data);
    out
}

fn connection_record() -> Vec<u8> {
    let described = record(&[("topic", b"/points"), ("type", b"sensor_msgs/PointCloud2")], &[]);
    let block = &described[4..described.len() - 4];
    record(&[("op", &[0x07]), ("conn", &0u32.to_le_bytes()), ("topic", b"/points")], block)
}

/// A ROS 1 `PointCloud2` of `n` points (x, y, z float32), shifted by `k`.
fn ros1_cloud(n: usize, k: usize) -> Vec<u8> {
    use toporec::sources::pointcloud2::{PointCloud2, PointField, serialize};
    let fields = ["x", "y", "z"]
        .iter()
        .enumerate()
        .map(|(i, f)| PointField { name: f.to_string(), offset: 4 * i as u32, datatype: 7, count: 1 })
        .collect();
    let data: Vec<u8> = (0..n * 3).flat_map(|i| (i as f32 * 0.01 + 1.0 + k as f32).to_le_bytes()).collect();
    let cloud = PointCloud2 {
        stamp_ns: 1_000_000_000 * (k as i64 + 1),
        frame_id: "lidar".into(),
        height: 1,
        width: n as u32,
        fields,
        is_bigendian: false,
        point_step: 12,
        row_step: 12 * n as u32,
        data: &data,
    };
    serialize(&cloud, toporec::sources::pointcloud2::Encoding::Ros1)
}

/// A bag of `clouds` messages, one lz4 chunk each, with its index section.
fn small_bag(clouds: usize) -> Vec<u8> {
    let header_len = |index_pos: u64| {
        record(
            &[
                ("op", &[0x03]),
                ("index_pos", &index_pos.to_le_bytes()),
                ("conn_count", &1u32.to_le_bytes()),
                ("chunk_count", &(clouds as u32).to_le_bytes()),
            ],
            &[b' '; 64],
        )
    };
    let mut body = Vec::new();
    let mut positions = Vec::new();
    let start = 13 + header_len(0).len();
    for k in 0..clouds {
        let time = ((k as u64 + 1) & 0xffff_ffff).to_le_bytes();
        let mut inner = if k == 0 { connection_record() } else { Vec::new() };
        inner.extend(record(
            &[("op", &[0x02]), ("conn", &0u32.to_le_bytes()), ("time", &time)],
            &ros1_cloud(50, k),
        ));
        let mut packed = Vec::new();
        let mut enc = lz4::EncoderBuilder::new().build(&mut packed).unwrap();
        std::io::Write::write_all(&mut enc, &inner).unwrap();
        enc.finish().1.unwrap();
        positions.push((start + body.len()) as u64);
        body.extend(record(
            &[("op", &[0x05]), ("compression", b"lz4"), ("size", &(inner.len() as u32).to_le_bytes())],
            &packed,
        ));
    }
    let index_pos = (start + body.len()) as u64;
    body.extend(connection_record());
    for (k, pos) in positions.iter().enumerate() {
        let t = ((k as u64 + 1) & 0xffff_ffff).to_le_bytes();
        let counts = [0u32.to_le_bytes(), 1u32.to_le_bytes()].concat();
        body.extend(record(
            &[
                ("op", &[0x06]),
                ("ver", &1u32.to_le_bytes()),
                ("chunk_pos", &pos.to_le_bytes()),
                ("start_time", &t),
                ("end_time", &t),
                ("count", &1u32.to_le_bytes()),
            ],
            &counts,
        ));
    }
    let mut out = b"#ROSBAG V2.0\n".to_vec();
    out.extend(header_len(index_pos));
    out.extend(body);
    out
}

#[test]
fn a_bag_written_here_reads_by_its_index_and_without_it() {
    let dir = scratch_dir("bags_small");
    let path = dir.join("small.bag");
    let bytes = small_bag(3);
    std::fs::write(&path, &bytes).unwrap();
    let (got, bad) = bag(&path);
    assert!(bad.is_empty(), "{bad:?}");
    assert_eq!(got.len(), 3);
    for (k, s) in got.iter().enumerate() {
        assert_eq!(
            (s.id.as_str(), s.utime, s.points.len()),
            (format!("small/{k:06}").as_str(), Some((k as i64 + 1) * 1_000_000), 50)
        );
        assert_eq!(s.points[0], [1.0 + k as f64, 1.01 + k as f64, 1.02 + k as f64].map(|v| v as f32 as f64));
    }
    let path = dir.join("bare.bag");
    std::fs::write(&path, unindexed(&bytes)).unwrap();
    let (bare, bad) = bag(&path);
    assert!(bad.is_empty(), "{bad:?}");
    assert!(bare.iter().zip(&got).all(|(a, b)| a.points == b.points && a.utime == b.utime));
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 300, failure_persistence: None, ..Default::default() })]

    /// Byte flips and cuts of a valid ROS 1 bag (each case writes a file): the reader, `inspect`
    /// and the scan stream return errors, never panic.
    #[test]
    fn fuzz_mutated_bags_never_panic(
        flips in proptest::collection::vec((0usize..100_000, proptest::prelude::any::<u8>()), 1..7),
        cut in proptest::option::of(0usize..100_000),
    ) {
        let base = small_bag(3);
        let mut b = base.clone();
        for (i, v) in flips {
            let n = b.len();
            b[i % n] = v;
        }
        if let Some(c) = cut {
            b.truncate(c % base.len());
        }
        let target = scratch_dir("bags_fuzz").join(format!("case-{:016x}.bag", fingerprint(&b)));
        std::fs::write(&target, &b).unwrap();
        let _ = LogSpec::path(&target).open().map(|s| s.count());
        let _ = toporec::inspect::inspect(&target);
        let _ = std::fs::remove_file(&target);
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 24, failure_persistence: None, ..Default::default() })]

    /// Byte flips in the first 64 KB of the real rosbag2 `.db3` (SQLite's header and first
    /// pages): an error or fewer scans, never a panic.
    #[test]
    fn fuzz_mutated_db3_never_panics(
        flips in proptest::collection::vec((0usize..65_536, proptest::prelude::any::<u8>()), 1..5),
    ) {
        let Some(data) = shared_data("fuzz_mutated_db3_never_panics") else { return Ok(()) };
        let mut b = std::fs::read(data.join("bags/kitti00_rosbag2_sqlite3/kitti00_rosbag2_sqlite3.db3")).unwrap();
        for (i, v) in flips {
            b[i] = v;
        }
        let target = scratch_dir("db3_fuzz").join(format!("case-{:016x}.db3", fingerprint(&b[..65_536])));
        std::fs::write(&target, &b).unwrap();
        let _ = LogSpec::path(&target).open().map(|s| s.count());
        let _ = toporec::inspect::inspect(&target);
        let _ = std::fs::remove_file(&target);
    }
}

/// A name for a fuzz case's file (cases may run in parallel).
fn fingerprint(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf29ce484222325u64, |h, &b| (h ^ b as u64).wrapping_mul(0x100000001b3))
}

// ------------------------------------------------------------ folders of PCD / PLY files

#[test]
fn a_folder_of_pcd_files_is_a_session_with_frame_or_timestamp_names_and_tum_or_nclt_poses() {
    use toporec::sources::clouds::{CloudsSpec, FileNames, PoseFormat};
    let Some(data) = shared_data("a_folder_of_pcd_files_is_a_session") else { return };
    let city = data.join("pcd/kitti_raw_city");
    let (got, bad) = collect(SourceSpec::new(CloudsSpec::folder(&city)));
    assert!(bad.is_empty(), "{bad:?}");
    let ids: Vec<(&str, Option<i64>)> = got.iter().map(|s| (s.id.as_str(), s.utime)).collect();
    // Frame numbers: no time (loops keep neighbours apart by position).
    assert_eq!(ids, [("kitti_raw_city/0000000000", None), ("kitti_raw_city/0000000153", None)]);
    for s in &got {
        // The file's points, the no-returns at (0, 0, 0) left out as every source does.
        let all = read_cloud(&s.path);
        let returns: Vec<[f64; 3]> = all.iter().copied().filter(|p| *p != [0.0; 3]).collect();
        assert_eq!(s.raw_points, all.len(), "{}", s.id);
        assert!(s.points == returns, "{}: {} of {} points", s.id, s.points.len(), returns.len());
    }
    // The same files named by timestamps (seconds), with TUM poses joined by time, and a file
    // whose name is not a timestamp: a failure naming it, the others read.
    let dir = scratch_dir("clouds_folder").join("drive");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(city.join("0000000000.pcd"), dir.join("1317000000.00.pcd")).unwrap();
    std::fs::copy(city.join("0000000153.pcd"), dir.join("1317000015.30.pcd")).unwrap();
    std::fs::copy(city.join("0000000153.pcd"), dir.join("frame.pcd")).unwrap();
    let tum = dir.with_extension("tum.txt");
    std::fs::write(&tum, "# t x y z qx qy qz qw\n1317000000.02 1 2 3 0 0 0 1\n1317000015.25 4 5 6 0 0 1 0\n")
        .unwrap();
    let spec = CloudsSpec {
        names: FileNames::Seconds,
        poses: Some(tum.clone()),
        poses_format: Some(PoseFormat::Tum),
        ..CloudsSpec::folder(&dir)
    };
    let (got, bad) = collect(SourceSpec::new(spec.clone()));
    assert_eq!(got.len(), 2);
    assert_eq!(got[0].utime, Some(1_317_000_000_000_000));
    let p = got[1].pose.expect("a pose within 100 ms");
    assert_eq!((p.x, p.y, p.z), (4.0, 5.0, 6.0));
    assert!((p.yaw.abs() - std::f64::consts::PI).abs() < 1e-12);
    assert_eq!(bad.len(), 1);
    assert!(
        bad[0].error.contains("frame.pcd") && bad[0].error.contains("not a timestamp"),
        "{}",
        bad[0].error
    );
    // Tighter than the 50 ms gap: no pose, and the reason.
    let (got, _) = collect(SourceSpec::new(CloudsSpec { tolerance_ms: 10.0, ..spec }));
    assert!(got[1].pose.is_none() && got[0].pose.is_none());
    // By line with frame indices: frame 0 takes the first pose.
    let spec =
        CloudsSpec { poses: Some(tum), poses_format: Some(PoseFormat::Tum), ..CloudsSpec::folder(&city) };
    let (got, _) = collect(SourceSpec::new(spec));
    assert_eq!(got[0].pose.map(|p| p.x), Some(1.0));
    assert!(got[1].pose.is_none(), "frame 153 has no pose line");
    // inspect and query take the folder as they take a session.
    let report = text(&toporec(&["inspect", city.to_str().unwrap()]).stdout);
    assert!(
        report.contains("format: folder of clouds") && report.contains("session kitti_raw_city: 2 scans"),
        "{report}"
    );
}
