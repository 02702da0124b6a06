//! Message logs at the byte level: every PointCloud2 layout variant, MCAP compressions and
//! summary-less files, corrupt and truncated MCAPs, Foxglove's protobuf clouds, and fuzzed
//! MCAP files.

use crate::util::*;
use proptest::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use toporec::sources::Source;
use toporec::sources::logs::LogSpec;
use toporec::sources::mcap_reader::McapMessages;
use toporec::sources::pointcloud2::{self, Encoding, PointCloud2, PointField, datatype};
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

struct Layout {
    fields: Vec<PointField>,
    point_step: u32,
    big: bool,
}

fn field(name: &str, offset: u32, datatype: u8) -> PointField {
    PointField { name: name.into(), offset, datatype, count: 1 }
}

fn put(buf: &mut [u8], datatype: u8, big: bool, v: f64) {
    macro_rules! w {
        ($t:ty) => {{
            let b = if big { (v as $t).to_be_bytes() } else { (v as $t).to_le_bytes() };
            buf[..b.len()].copy_from_slice(&b);
        }};
    }
    match datatype {
        datatype::INT8 => w!(i8),
        datatype::UINT8 => w!(u8),
        datatype::INT16 => w!(i16),
        datatype::UINT16 => w!(u16),
        datatype::INT32 => w!(i32),
        datatype::UINT32 => w!(u32),
        datatype::FLOAT32 => w!(f32),
        _ => w!(f64),
    }
}

/// Points (x, y, z, intensity, ring) → a serialized cloud with the layout; `height` rows with
/// `row_pad` bytes of padding per row.
fn cloud_bytes(
    points: &[[f64; 5]],
    layout: &Layout,
    height: u32,
    row_pad: u32,
    encoding: Encoding,
) -> Vec<u8> {
    let width = points.len() as u32 / height;
    let row_step = width * layout.point_step + row_pad;
    let mut data = vec![0xEEu8; (row_step * height) as usize];
    for (i, p) in points.iter().enumerate() {
        let (row, col) = (i as u32 / width, i as u32 % width);
        let base = (row * row_step + col * layout.point_step) as usize;
        for f in &layout.fields {
            let v = match f.name.as_str() {
                "x" => p[0],
                "y" => p[1],
                "z" => p[2],
                "intensity" => p[3],
                "ring" => p[4],
                _ => 7.0,
            };
            put(&mut data[base + f.offset as usize..], f.datatype, layout.big, v);
        }
    }
    let cloud = PointCloud2 {
        stamp_ns: 1_700_000_000_123_456_789,
        frame_id: "lidar".into(),
        height,
        width,
        fields: layout.fields.clone(),
        is_bigendian: layout.big,
        point_step: layout.point_step,
        row_step,
        data: &data,
    };
    pointcloud2::serialize(&cloud, encoding)
}

fn sample_points() -> Vec<[f64; 5]> {
    (0..12)
        .map(|i| {
            [i as f64 * 0.5 - 2.0, 1.0 + i as f64 * 0.25, -0.75 * i as f64, 10.0 * i as f64, (i % 4) as f64]
        })
        .collect()
}

#[test]
fn pointcloud2_layouts_decode_by_their_fields() {
    use datatype::*;
    let layouts = [
        (
            "plain f32 LE",
            Layout {
                fields: vec![
                    field("x", 0, FLOAT32),
                    field("y", 4, FLOAT32),
                    field("z", 8, FLOAT32),
                    field("intensity", 12, FLOAT32),
                ],
                point_step: 16,
                big: false,
            },
        ),
        (
            "big-endian",
            Layout {
                fields: vec![
                    field("x", 0, FLOAT32),
                    field("y", 4, FLOAT32),
                    field("z", 8, FLOAT32),
                    field("intensity", 12, UINT16),
                    field("ring", 14, UINT8),
                ],
                point_step: 16,
                big: true,
            },
        ),
        (
            "float64",
            Layout {
                fields: vec![field("x", 0, FLOAT64), field("y", 8, FLOAT64), field("z", 16, FLOAT64)],
                point_step: 24,
                big: false,
            },
        ),
        (
            "extra fields + padding, shuffled order",
            Layout {
                fields: vec![
                    field("t", 0, UINT32),
                    field("z", 12, FLOAT32),
                    field("ring", 16, UINT16),
                    field("x", 4, FLOAT32),
                    field("y", 8, FLOAT32),
                    field("noise", 18, INT16),
                    field("intensity", 20, INT8),
                ],
                point_step: 48,
                big: false,
            },
        ),
    ];
    let points = sample_points();
    for (name, layout) in &layouts {
        for encoding in [Encoding::Cdr, Encoding::Ros1] {
            for (height, pad) in [(1, 0), (3, 5)] {
                let bytes = cloud_bytes(&points, layout, height, pad, encoding);
                let msg = pointcloud2::parse(&bytes, encoding).unwrap_or_else(|e| panic!("{name}: {e}"));
                assert_eq!((msg.stamp_ns, msg.frame_id.as_str()), (1_700_000_000_123_456_789, "lidar"));
                let cloud = msg.decode().unwrap_or_else(|e| panic!("{name}: {e}"));
                assert_eq!(cloud.raw_points, 12);
                // The first sample point is (−2, 1, 0): kept (only exact zeros are dropped).
                let expected: Vec<[f64; 3]> = points.iter().map(|p| [p[0], p[1], p[2]]).collect();
                assert_eq!(cloud.points, expected, "{name} {encoding:?} height {height}");
                let has = |f: &str| layout.fields.iter().any(|x| x.name == f);
                assert_eq!(cloud.intensity.is_some(), has("intensity"), "{name}");
                if let Some(i) = &cloud.intensity {
                    let want: Vec<f32> = points
                        .iter()
                        .map(|p| if name.contains("extra") { p[3].min(127.0) as f32 } else { p[3] as f32 })
                        .collect();
                    assert_eq!(i, &want, "{name}");
                }
                if let Some(r) = &cloud.ring {
                    assert_eq!(r, &points.iter().map(|p| p[4] as u16).collect::<Vec<_>>(), "{name}");
                }
            }
        }
    }
}

#[test]
fn pointcloud2_drops_nan_and_zero_points_and_rejects_bad_layouts() {
    use datatype::*;
    let layout = Layout {
        fields: vec![field("x", 0, FLOAT32), field("y", 4, FLOAT32), field("z", 8, FLOAT32)],
        point_step: 12,
        big: false,
    };
    let mut points = sample_points();
    points[3][1] = f64::NAN;
    points[5][0] = f64::INFINITY;
    points[7] = [0.0; 5];
    let bytes = cloud_bytes(&points, &layout, 1, 0, Encoding::Cdr);
    let cloud = pointcloud2::parse(&bytes, Encoding::Cdr).unwrap().decode().unwrap();
    assert_eq!((cloud.raw_points, cloud.points.len()), (12, 9));
    // No x/y/z.
    let no_xyz =
        Layout { fields: vec![field("a", 0, FLOAT32), field("b", 4, FLOAT32)], point_step: 8, big: false };
    let e = pointcloud2::parse(&cloud_bytes(&points, &no_xyz, 1, 0, Encoding::Cdr), Encoding::Cdr)
        .unwrap()
        .decode()
        .unwrap_err();
    assert!(e.contains("no x, y, z"), "{e}");
    // point_step smaller than the fields.
    let mut small = cloud_bytes(&points, &layout, 1, 0, Encoding::Ros1);
    let msg = pointcloud2::parse(&small, Encoding::Ros1).unwrap();
    let bad = PointCloud2 { point_step: 10, row_step: 120, ..msg.clone() };
    let e = bad.decode().unwrap_err();
    assert!(e.contains("does not fit in point_step 10"), "{e}");
    // Data shorter than height × row_step; a message cut short.
    let short = PointCloud2 { data: &msg.data[..100], ..msg.clone() };
    assert!(short.decode().unwrap_err().contains("needs 144"));
    small.truncate(small.len() - 30);
    assert!(pointcloud2::parse(&small, Encoding::Ros1).unwrap_err().contains("message ends inside data"));
}

// ---------------------------------------------------------------- MCAP fixtures

const ROS2_SCHEMA: &str = "sensor_msgs/msg/PointCloud2";

struct McapOptions {
    compression: Option<mcap::Compression>,
    summary: bool,
    chunk_size: Option<u64>,
}

/// Writes `clouds` (serialized CDR PointCloud2) on /points plus chatter on /other.
fn write_mcap(path: &Path, clouds: &[Vec<u8>], o: &McapOptions) {
    let mut opts =
        mcap::WriteOptions::new().compression(o.compression).chunk_size(o.chunk_size).profile("ros2");
    if !o.summary {
        opts = opts
            .emit_summary_records(false)
            .emit_summary_offsets(false)
            .emit_statistics(false)
            .emit_chunk_indexes(false)
            .emit_message_indexes(false)
            .emit_attachment_indexes(false)
            .emit_metadata_indexes(false);
    }
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = opts.create(file).unwrap();
    let schema = w.add_schema(ROS2_SCHEMA, "ros2msg", b"# PointCloud2").unwrap();
    let cloud_channel = w.add_channel(schema, "/points", "cdr", &BTreeMap::new()).unwrap();
    let other_schema = w.add_schema("std_msgs/msg/String", "ros2msg", b"string data").unwrap();
    let other = w.add_channel(other_schema, "/other", "cdr", &BTreeMap::new()).unwrap();
    for (i, c) in clouds.iter().enumerate() {
        let header = |channel_id, t: u64| mcap::records::MessageHeader {
            channel_id,
            sequence: i as u32,
            log_time: t,
            publish_time: t,
        };
        w.write_to_known_channel(&header(other, 10 * i as u64), b"\x00\x01\x00\x00\x03\x00\x00\x00hi\x00")
            .unwrap();
        w.write_to_known_channel(&header(cloud_channel, 10 * i as u64 + 5), c).unwrap();
    }
    w.finish().unwrap();
}

fn test_clouds(n: usize) -> Vec<Vec<u8>> {
    use datatype::*;
    let layout = Layout {
        fields: vec![
            field("x", 0, FLOAT32),
            field("y", 4, FLOAT32),
            field("z", 8, FLOAT32),
            field("intensity", 12, FLOAT32),
        ],
        point_step: 16,
        big: false,
    };
    (0..n)
        .map(|k| {
            let pts: Vec<[f64; 5]> =
                sample_points().iter().map(|p| [p[0] + k as f64, p[1], p[2], p[3], p[4]]).collect();
            cloud_bytes(&pts, &layout, 1, 0, Encoding::Cdr)
        })
        .collect()
}

#[test]
fn mcap_zstd_lz4_plain_and_summaryless_files_read_alike() {
    let dir = scratch_dir("mcap_variants");
    let clouds = test_clouds(5);
    let mut reference: Option<Vec<Scan>> = None;
    for (name, compression, summary) in [
        ("zstd", Some(mcap::Compression::Zstd), true),
        ("lz4", Some(mcap::Compression::Lz4), true),
        ("none", None, true),
        ("zstd-no-summary", Some(mcap::Compression::Zstd), false),
        ("lz4-no-summary", Some(mcap::Compression::Lz4), false),
    ] {
        let path = dir.join(format!("{name}.mcap"));
        write_mcap(&path, &clouds, &McapOptions { compression, summary, chunk_size: Some(600) });
        assert_eq!(toporec::sources::mcap_reader::summary_channels(&path).is_some(), summary, "{name}");
        let spec = LogSpec { session: Some("s".into()), ..LogSpec::path(&path) };
        let (scans, bad) = collect(SourceSpec::new(spec));
        assert!(bad.is_empty(), "{name}: {bad:?}");
        assert_eq!(scans.len(), 5, "{name}");
        assert_eq!(scans[2].points[0], [0.0, 1.0, 0.0], "{name}: (-2 + 2, 1, 0)");
        assert_eq!(scans[0].utime, Some(1_700_000_000_123_456), "{name}: header stamp in µs");
        let scans: Vec<Scan> = scans.into_iter().map(|s| Scan { path: PathBuf::new(), ..s }).collect();
        match &reference {
            None => reference = Some(scans),
            Some(r) => assert_eq!(&scans, r, "{name} reads like zstd"),
        }
    }
}

#[test]
fn mcap_message_ranges_partition_the_file() {
    let dir = scratch_dir("mcap_ranges");
    let path = dir.join("ranges.mcap");
    write_mcap(
        &path,
        &test_clouds(7),
        &McapOptions { compression: Some(mcap::Compression::Zstd), summary: true, chunk_size: Some(600) },
    );
    let spec = LogSpec { session: Some("s".into()), ..LogSpec::path(&path) };
    let (whole, bad) = collect(SourceSpec::new(spec.clone()));
    assert!(bad.is_empty());
    assert_eq!(toporec::sources::logs::count_scans(&path, None).unwrap(), ("/points".to_string(), 7));
    let mut pieces = Vec::new();
    for first in (0..9).step_by(3) {
        let part: Vec<Scan> = spec.open_range(&path, first..first + 3).unwrap().map(|s| s.unwrap()).collect();
        assert_eq!(part.len(), (7 - first.min(7)).min(3) as usize, "range {first}..{}", first + 3);
        pieces.extend(part);
    }
    assert_eq!(pieces, whole, "the ranges' scans are the file's, ids, times and indices included");
}

#[test]
fn corrupt_and_truncated_mcap_lose_only_the_bad_chunk() {
    let dir = scratch_dir("mcap_corrupt");
    let clouds = test_clouds(6);
    let path = dir.join("good.mcap");
    // Small chunks: about one cloud per chunk.
    write_mcap(
        &path,
        &clouds,
        &McapOptions { compression: Some(mcap::Compression::Zstd), summary: true, chunk_size: Some(300) },
    );
    let bytes = std::fs::read(&path).unwrap();
    // Flip bytes in the middle of the file: inside some chunk's compressed data.
    let mut corrupt = bytes.clone();
    let mid = bytes.len() / 2;
    for b in &mut corrupt[mid..mid + 16] {
        *b ^= 0x5A;
    }
    let bad_path = dir.join("corrupt.mcap");
    std::fs::write(&bad_path, &corrupt).unwrap();
    let (scans, bad) = collect(SourceSpec::new(LogSpec::path(&bad_path)));
    assert!(!bad.is_empty(), "the corruption is reported");
    assert!(scans.len() >= 4 && scans.len() < 6, "{} scans survive", scans.len());
    for f in &bad {
        assert!(
            f.error.contains("corrupt.mcap") && (f.error.contains("chunk") || f.error.contains("byte")),
            "{}",
            f.error
        );
    }
    // Truncated: the scans before the cut, then one error naming the file.
    let cut = dir.join("truncated.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let spec = LogSpec { topic: Some("/points".into()), ..LogSpec::path(&cut) };
    let (scans, bad) = collect(SourceSpec::new(spec));
    assert!((2..6).contains(&scans.len()), "{} scans before the cut", scans.len());
    assert_eq!(bad.len(), 1);
    assert!(bad[0].error.contains("truncated.mcap"), "{}", bad[0].error);
    // A message without x/y/z on the topic: that message fails, the rest read.
    let mut mixed = test_clouds(3);
    let no_xyz = Layout { fields: vec![field("a", 0, datatype::FLOAT32)], point_step: 4, big: false };
    mixed[1] = cloud_bytes(&sample_points(), &no_xyz, 1, 0, Encoding::Cdr);
    let p = dir.join("mixed.mcap");
    write_mcap(&p, &mixed, &McapOptions { compression: None, summary: true, chunk_size: None });
    let (scans, bad) = collect(SourceSpec::new(LogSpec::path(&p)));
    assert_eq!(scans.len(), 2);
    assert_eq!(bad.len(), 1);
    assert_eq!(bad[0].message_index, Some(1));
    assert!(
        bad[0].error.contains("mixed.mcap: message 1 on /points: PointCloud2 has no x, y, z"),
        "{}",
        bad[0].error
    );
    // Wrong topic names are explained.
    let (scans, bad) =
        collect(SourceSpec::new(LogSpec { topic: Some("/other".into()), ..LogSpec::path(&p) }));
    assert!(scans.is_empty() && bad.len() == 1, "one failure for the file");
    assert!(bad[0].input_unread && bad[0].error.contains("std_msgs/msg/String"), "{}", bad[0].error);
}

const FUZZ_CASES: u32 = 1500;

proptest! {
    #![proptest_config(ProptestConfig { cases: FUZZ_CASES, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn fuzz_pointcloud2_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..400), kind in 0u8..3) {
        let enc = [Encoding::Ros1, Encoding::Cdr, Encoding::FoxgloveProtobuf][kind as usize];
        if let Ok(c) = pointcloud2::parse(&bytes, enc) {
            let _ = c.decode();
        }
    }

    #[test]
    fn fuzz_mutated_pointcloud2_never_panics(flips in proptest::collection::vec((0usize..400, any::<u8>()), 1..8)) {
        let mut bytes = test_clouds(1).remove(0);
        for (i, b) in flips {
            let n = bytes.len();
            bytes[i % n] = b;
        }
        if let Ok(c) = pointcloud2::parse(&bytes, Encoding::Cdr) {
            let _ = c.decode();
        }
    }

}

#[test]
fn fuzz_mutated_mcap_files_never_panic() {
    // Random byte flips in a valid zstd MCAP (not via proptest: each case writes a file).
    let dir = scratch_dir("mcap_fuzz");
    let path = dir.join("base.mcap");
    write_mcap(
        &path,
        &test_clouds(4),
        &McapOptions { compression: Some(mcap::Compression::Zstd), summary: true, chunk_size: Some(400) },
    );
    let base = std::fs::read(&path).unwrap();
    let mut rng = toporec::rng::SplitMix64(5);
    let target = dir.join("case.mcap");
    for _ in 0..300 {
        let mut b = base.clone();
        for _ in 0..1 + rng.below(6) {
            let i = rng.below(b.len());
            b[i] = rng.next_u64() as u8;
        }
        if rng.below(4) == 0 {
            b.truncate(rng.below(b.len()));
        }
        std::fs::write(&target, &b).unwrap();
        let _ = LogSpec::path(&target).open().map(|s| s.count());
        let _ = McapMessages::open(&target).map(|m| m.count());
        let _ = toporec::inspect::inspect(&target);
    }
}

/// Protobuf encoding helpers for a `foxglove.PointCloud` fixture.
fn pb_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn pb_bytes(out: &mut Vec<u8>, field: u64, bytes: &[u8]) {
    pb_varint(out, field << 3 | 2);
    pb_varint(out, bytes.len() as u64);
    out.extend(bytes);
}

fn foxglove_cloud(points: &[[f64; 5]]) -> Vec<u8> {
    let mut ts = Vec::new();
    pb_varint(&mut ts, 1 << 3);
    pb_varint(&mut ts, 1_700_000_000);
    pb_varint(&mut ts, 2 << 3);
    pb_varint(&mut ts, 250_000_000);
    let mut m = Vec::new();
    pb_bytes(&mut m, 1, &ts);
    pb_bytes(&mut m, 2, b"lidar");
    pb_bytes(&mut m, 3, &[0x0a, 0x00]); // pose: an empty position (ignored)
    m.push(4 << 3 | 5);
    m.extend(14u32.to_le_bytes()); // point_stride: x, y, z f32 + intensity u16
    // NumericType: FLOAT32 = 7, UINT16 = 3.
    for (name, offset, ty) in [("x", 0u32, 7u64), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 3)] {
        let mut f = Vec::new();
        pb_bytes(&mut f, 1, name.as_bytes());
        f.push(2 << 3 | 5);
        f.extend(offset.to_le_bytes());
        pb_varint(&mut f, 3 << 3);
        pb_varint(&mut f, ty);
        pb_bytes(&mut m, 5, &f);
    }
    let mut data = Vec::new();
    for p in points {
        for v in &p[..3] {
            data.extend((*v as f32).to_le_bytes());
        }
        data.extend((p[3] as u16).to_le_bytes());
    }
    pb_bytes(&mut m, 6, &data);
    pb_varint(&mut m, 100 << 3 | 2); // an unknown newer field (uuid): skipped
    pb_varint(&mut m, 2);
    m.extend(b"id");
    m
}

#[test]
fn foxglove_pointcloud_protobuf_in_mcap() {
    let dir = scratch_dir("mcap_foxglove");
    let path = dir.join("fox.mcap");
    let points = sample_points();
    {
        let file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        let mut w =
            mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd)).create(file).unwrap();
        let schema = w.add_schema("foxglove.PointCloud", "protobuf", b"(FileDescriptorSet)").unwrap();
        let ch = w.add_channel(schema, "/lidar", "protobuf", &BTreeMap::new()).unwrap();
        for i in 0..3u32 {
            let h = mcap::records::MessageHeader {
                channel_id: ch,
                sequence: i,
                log_time: i as u64,
                publish_time: i as u64,
            };
            w.write_to_known_channel(&h, &foxglove_cloud(&points)).unwrap();
        }
        w.finish().unwrap();
    }
    let (scans, bad) = collect(SourceSpec::new(LogSpec::path(&path)));
    assert!(bad.is_empty(), "{bad:?}");
    assert_eq!(scans.len(), 3);
    let expected: Vec<[f64; 3]> = points.iter().map(|p| [p[0], p[1], p[2]]).collect();
    assert_eq!(scans[0].points, expected);
    assert_eq!(scans[0].utime, Some(1_700_000_000_250_000));
    assert_eq!(scans[0].intensity.as_ref().unwrap()[5], 50.0);
    // Truncated protobuf: an error for that message, not a panic.
    let msg = foxglove_cloud(&points);
    for cut in [1, 5, 17, msg.len() - 3] {
        let r = pointcloud2::parse(&msg[..cut], Encoding::FoxgloveProtobuf).and_then(|c| c.decode());
        assert!(r.is_err(), "cut at {cut}");
    }
}
