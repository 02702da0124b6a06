//! Decoding throughput (design goal ≥ 200 MB/s on one core): NCLT `velodyne_sync` records and
//! PointCloud2 messages (ROS 2 CDR from the KITTI MCAP, ROS 1 from the Ouster MCAP), from
//! `../shared/data` when present, else from synthetic buffers of the same layouts; then whole
//! logs read from disk into scans (the same four KITTI scans as an MCAP, two ROS 1 bags and two
//! rosbag2 folders: decompression, records, PointCloud2), MB/s of the log's bytes.
//!
//! Run: `cargo bench --bench decode`.

use std::path::{Path, PathBuf};
use std::time::Instant;
use toporec::sources::Source;
use toporec::sources::mcap_reader::McapMessages;
use toporec::sources::pointcloud2::{self, Encoding, PointCloud2, PointField};

fn rate(name: &str, bytes: usize, mut f: impl FnMut() -> usize) {
    let mut best = f64::INFINITY;
    let mut points = 0;
    for _ in 0..15 {
        let t = Instant::now();
        points = std::hint::black_box(f());
        best = best.min(t.elapsed().as_secs_f64());
    }
    println!(
        "{name:<46} {:>9} bytes {:>8} points  {:>7.0} MB/s (best of 15)",
        bytes,
        points,
        bytes as f64 / best / 1e6
    );
}

fn first_message(path: &Path) -> Option<(Vec<u8>, Encoding)> {
    let m = McapMessages::open(path)
        .ok()?
        .filter_map(Result::ok)
        .find(|m| m.channel.schema_name.contains("PointCloud2"))?;
    let enc = Encoding::of_channel(&m.channel.message_encoding);
    Some((m.data, enc))
}

fn synthetic(n: usize, encoding: Encoding) -> Vec<u8> {
    let fields = ["x", "y", "z", "intensity"]
        .iter()
        .enumerate()
        .map(|(i, f)| PointField { name: f.to_string(), offset: 4 * i as u32, datatype: 7, count: 1 })
        .collect();
    let data: Vec<u8> = (0..n * 4).flat_map(|i| (i as f32 * 0.001 + 1.0).to_le_bytes()).collect();
    let cloud = PointCloud2 {
        stamp_ns: 0,
        frame_id: "x".into(),
        height: 1,
        width: n as u32,
        fields,
        is_bigendian: false,
        point_step: 16,
        row_step: 16 * n as u32,
        data: &data,
    };
    pointcloud2::serialize(&cloud, encoding)
}

fn main() {
    let data = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    let nclt = std::fs::read(data.join("nclt/2012-01-15/velodyne_sync/1326652795280148.bin"))
        .unwrap_or_else(|_| (0..23_546u32).flat_map(|i| [(i % 251) as u8; 8]).collect());
    let p = Path::new("x.bin");
    rate("NCLT velodyne_sync scan", nclt.len(), || {
        toporec::sources::nclt::decode_sync(&nclt, p).unwrap().points.len()
    });
    for (name, file, enc) in [
        ("PointCloud2 ROS 2 CDR (KITTI, point_step 16)", "mcap/kitti_ros2_cdr.mcap", Encoding::Cdr),
        ("PointCloud2 ROS 1 (Ouster, point_step 48)", "mcap/ouster_os1_ros1.mcap", Encoding::Ros1),
    ] {
        let (msg, enc) = first_message(&data.join(file)).unwrap_or_else(|| (synthetic(120_000, enc), enc));
        rate(name, msg.len(), || pointcloud2::parse(&msg, enc).unwrap().decode().unwrap().points.len());
    }
    for (name, log) in [
        ("log → scans: MCAP (zstd chunks)", "mcap/kitti_ros2_cdr.mcap"),
        ("log → scans: ROS 1 bag, bz2 chunks", "bags/kitti00_ros1_bz2.bag"),
        ("log → scans: ROS 1 bag, lz4 chunks", "bags/kitti00_ros1_lz4.bag"),
        ("log → scans: rosbag2, sqlite3", "bags/kitti00_rosbag2_sqlite3"),
        ("log → scans: rosbag2, mcap", "bags/kitti00_rosbag2_mcap"),
    ] {
        let path = data.join(log);
        if !path.exists() {
            println!("{name:<46} skipped: {} is missing", path.display());
            continue;
        }
        let bytes: u64 = walkdir::WalkDir::new(&path)
            .into_iter()
            .flatten()
            .filter(|e| e.file_type().is_file())
            .map(|e| e.metadata().map_or(0, |m| m.len()))
            .sum();
        let spec = toporec::sources::logs::LogSpec::path(&path);
        rate(name, bytes as usize, || spec.open().unwrap().map(|s| s.unwrap().points.len()).sum());
    }
}
