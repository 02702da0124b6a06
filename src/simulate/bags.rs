//! Simulated drives as a robot records them: a ROS 1 bag (format 2.0, uncompressed chunks with
//! their index) or a rosbag2 folder (MCAP storage), holding the clouds on `/velodyne_points`
//! (frame `velodyne`), the vehicle's odometry on `/odom` (`nav_msgs/Odometry`, frame `odom`,
//! child `base_link`), the same transform on `/tf`, and the sensor's mounting on `/tf_static`
//! (`base_link` → `velodyne`). The sensor's pose in `odom` is the simulated pose, so the poses
//! joined from the log equal the drive's ground truth, unless the odometry drifts
//! ([`super::Drift`]; the truth is then written to `truth/<session>.tum`).

use super::{SessionWriter, SimScan, cloud_message, session_name};
use crate::error::{Result, ResultExt};
use crate::sources::pointcloud2::Encoding;
use crate::sources::rosmsg::{self, Iso, PoseKind, Stamped};
use crate::sources::wire::Wire;
use nalgebra::{Translation3, UnitQuaternion};
use std::path::{Path, PathBuf};

/// Where the sensor sits on the vehicle (`base_link` → `velodyne`): forward and up (m).
const MOUNT: [f64; 3] = [0.27, 0.0, 1.2];

/// The topics written, each with its message kind (`None`: the point clouds).
const TOPICS: [(&str, Option<PoseKind>); 4] = [
    ("/velodyne_points", None),
    ("/odom", Some(PoseKind::Odometry)),
    ("/tf", Some(PoseKind::Tf)),
    ("/tf_static", Some(PoseKind::Tf)),
];

const POINTCLOUD2_MD5: &str = "1158d486dd51d683ce2f1be655c3c181";

fn mounting() -> Iso {
    Iso::from_parts(Translation3::new(MOUNT[0], MOUNT[1], MOUNT[2]), UnitQuaternion::identity())
}

/// The messages of one scan: its cloud, and the vehicle's odometry and transform at its time.
fn messages(s: &SimScan, wire: Wire) -> [(usize, Vec<u8>); 3] {
    let [x, y, z, yaw] = s.odometry;
    let sensor =
        Iso::from_parts(Translation3::new(x, y, z), UnitQuaternion::from_euler_angles(0.0, 0.0, yaw));
    let base = sensor * mounting().inverse();
    let stamp_ns = s.utime * 1000;
    let odom = Stamped { stamp_ns, parent: "odom".into(), child: "base_link".into(), pose: base };
    let encoding = if wire == Wire::Cdr { Encoding::Cdr } else { Encoding::Ros1 };
    [
        (0, cloud_message(s, encoding)),
        (1, rosmsg::odometry(&odom, wire)),
        (2, rosmsg::tf_message(std::slice::from_ref(&odom), wire)),
    ]
}

/// The `/tf_static` message: the mounting, stamped at `stamp_ns`.
fn static_message(stamp_ns: i64, wire: Wire) -> Vec<u8> {
    let s = Stamped { stamp_ns, parent: "base_link".into(), child: "velodyne".into(), pose: mounting() };
    rosmsg::tf_message(&[s], wire)
}

// ------------------------------------------------------------------------------- ROS 1 bag

/// A ROS 1 record: its header fields, then its data.
fn record(out: &mut Vec<u8>, fields: &[(&str, &[u8])], data: &[u8]) {
    let mut header = Vec::new();
    for (name, value) in fields {
        header.extend(((name.len() + 1 + value.len()) as u32).to_le_bytes());
        header.extend(name.as_bytes());
        header.push(b'=');
        header.extend(*value);
    }
    out.extend((header.len() as u32).to_le_bytes());
    out.extend(header);
    out.extend((data.len() as u32).to_le_bytes());
    out.extend(data);
}

/// A ROS time as a bag stores it: seconds in the low 32 bits, nanoseconds in the high.
fn ros_time(ns: i64) -> [u8; 8] {
    let (sec, nsec) = (ns.div_euclid(1_000_000_000) as u64, ns.rem_euclid(1_000_000_000) as u64);
    ((nsec << 32) | (sec & 0xffff_ffff)).to_le_bytes()
}

/// The connection record of topic `conn`.
fn connection(out: &mut Vec<u8>, conn: u32) {
    let (topic, kind) = TOPICS[conn as usize];
    let (type_name, md5, definition) = match kind {
        None => ("sensor_msgs/PointCloud2", POINTCLOUD2_MD5, super::POINTCLOUD2_MSG),
        Some(k) => (k.name(), rosmsg::md5sum(k), rosmsg::definition(k)),
    };
    let mut data = Vec::new();
    let mut fields: Vec<(&str, &[u8])> = vec![
        ("topic", topic.as_bytes()),
        ("type", type_name.as_bytes()),
        ("md5sum", md5.as_bytes()),
        ("message_definition", definition.as_bytes()),
    ];
    if topic == "/tf_static" {
        fields.push(("latching", b"1"));
    }
    // The connection header is a record's header without its length prefix.
    let mut described = Vec::new();
    record(&mut described, &fields, &[]);
    data.extend(&described[4..described.len() - 4]);
    record(out, &[("op", &[0x07]), ("conn", &conn.to_le_bytes()), ("topic", topic.as_bytes())], &data);
}

/// Messages per chunk.
const CHUNK_MESSAGES: usize = 64;

/// `bag/<date>.bag`.
pub(super) struct Ros1Writer {
    path: PathBuf,
    file: crate::fsutil::AtomicFile,
    written: u64,
    /// The open chunk's records, and per connection (time, offset) of its messages.
    chunk: Vec<u8>,
    chunk_index: Vec<Vec<(i64, u32)>>,
    chunk_messages: usize,
    /// Connections already written in some chunk.
    connected: [bool; 4],
    /// Per chunk: its position, time span and message counts per connection.
    chunks: Vec<ChunkInfo>,
}

/// A written chunk: its position, first and last times (ns), and messages per connection.
type ChunkInfo = (u64, i64, i64, Vec<(u32, u32)>);

/// The bag header record, padded to 4096 bytes, as the format lays it out.
fn bag_header(index_pos: u64, conn_count: u32, chunk_count: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let fields: [(&str, &[u8]); 4] = [
        ("op", &[0x03]),
        ("index_pos", &index_pos.to_le_bytes()),
        ("conn_count", &conn_count.to_le_bytes()),
        ("chunk_count", &chunk_count.to_le_bytes()),
    ];
    let mut probe = Vec::new();
    record(&mut probe, &fields, &[]);
    record(&mut out, &fields, &vec![b' '; 4096 - probe.len()]);
    out
}

impl Ros1Writer {
    pub(super) fn new(out: &Path, session: usize) -> Result<Self> {
        let path = out.join("bag").join(format!("{}.bag", session_name(session)));
        let mut file = crate::fsutil::AtomicFile::create(&path)?;
        let mut start = b"#ROSBAG V2.0\n".to_vec();
        start.extend(bag_header(0, 0, 0));
        std::io::Write::write_all(&mut file, &start).at(&path)?;
        Ok(Ros1Writer {
            path,
            file,
            written: start.len() as u64,
            chunk: Vec::new(),
            chunk_index: vec![Vec::new(); TOPICS.len()],
            chunk_messages: 0,
            connected: [false; 4],
            chunks: Vec::new(),
        })
    }

    fn message(&mut self, conn: u32, stamp_ns: i64, data: &[u8]) -> Result<()> {
        if !self.connected[conn as usize] {
            connection(&mut self.chunk, conn);
            self.connected[conn as usize] = true;
        }
        let offset = self.chunk.len() as u32;
        record(
            &mut self.chunk,
            &[("op", &[0x02]), ("conn", &conn.to_le_bytes()), ("time", &ros_time(stamp_ns))],
            data,
        );
        self.chunk_index[conn as usize].push((stamp_ns, offset));
        self.chunk_messages += 1;
        if self.chunk_messages >= CHUNK_MESSAGES { self.flush() } else { Ok(()) }
    }

    /// Writes the open chunk and its index records.
    fn flush(&mut self) -> Result<()> {
        if self.chunk_messages == 0 {
            return Ok(());
        }
        let mut out = Vec::with_capacity(self.chunk.len() + 1024);
        let size = self.chunk.len() as u32;
        record(
            &mut out,
            &[("op", &[0x05]), ("compression", b"none"), ("size", &size.to_le_bytes())],
            &self.chunk,
        );
        let (mut start, mut end, mut counts) = (i64::MAX, i64::MIN, Vec::new());
        for (conn, entries) in self.chunk_index.iter_mut().enumerate() {
            if entries.is_empty() {
                continue;
            }
            let mut data = Vec::with_capacity(entries.len() * 12);
            for (t, offset) in entries.iter() {
                data.extend(ros_time(*t));
                data.extend(offset.to_le_bytes());
                start = start.min(*t);
                end = end.max(*t);
            }
            let conn = conn as u32;
            record(
                &mut out,
                &[
                    ("op", &[0x04]),
                    ("ver", &1u32.to_le_bytes()),
                    ("conn", &conn.to_le_bytes()),
                    ("count", &(entries.len() as u32).to_le_bytes()),
                ],
                &data,
            );
            counts.push((conn, entries.len() as u32));
            entries.clear();
        }
        self.chunks.push((self.written, start, end, counts));
        std::io::Write::write_all(&mut self.file, &out).at(&self.path)?;
        self.written += out.len() as u64;
        self.chunk.clear();
        self.chunk_messages = 0;
        Ok(())
    }
}

impl SessionWriter for Ros1Writer {
    fn write(&mut self, s: &SimScan) -> Result<()> {
        let stamp_ns = s.utime * 1000;
        if s.index == 0 {
            self.message(3, stamp_ns, &static_message(stamp_ns, Wire::Ros1))?;
        }
        for (conn, data) in messages(s, Wire::Ros1) {
            self.message(conn as u32, stamp_ns, &data)?;
        }
        Ok(())
    }

    fn finish(mut self: Box<Self>) -> Result<()> {
        self.flush()?;
        let index_pos = self.written;
        let mut out = Vec::new();
        let conns: Vec<u32> = (0..TOPICS.len() as u32).filter(|&c| self.connected[c as usize]).collect();
        for &c in &conns {
            connection(&mut out, c);
        }
        for (pos, start, end, counts) in &self.chunks {
            let data: Vec<u8> =
                counts.iter().flat_map(|(c, n)| [c.to_le_bytes(), n.to_le_bytes()].concat()).collect();
            record(
                &mut out,
                &[
                    ("op", &[0x06]),
                    ("ver", &1u32.to_le_bytes()),
                    ("chunk_pos", &pos.to_le_bytes()),
                    ("start_time", &ros_time(*start)),
                    ("end_time", &ros_time(*end)),
                    ("count", &(counts.len() as u32).to_le_bytes()),
                ],
                &data,
            );
        }
        std::io::Write::write_all(&mut self.file, &out).at(&self.path)?;
        // The header, now that the index's place is known (same length: written over).
        let header = bag_header(index_pos, conns.len() as u32, self.chunks.len() as u32);
        use std::io::{Seek, SeekFrom, Write};
        self.file.seek(SeekFrom::Start(13)).at(&self.path)?;
        self.file.write_all(&header).at(&self.path)?;
        self.file.commit().map(|_| ())
    }
}

// ------------------------------------------------------------------------- rosbag2 (MCAP)

/// `rosbag2/<date>/`: `metadata.yaml` and `<date>_0.mcap`.
pub(super) struct Rosbag2Writer {
    dir: PathBuf,
    name: String,
    path: PathBuf,
    writer: ::mcap::Writer<crate::fsutil::AtomicFile>,
    channels: [u16; 4],
    counts: [u64; 4],
    span: (i64, i64),
}

impl Rosbag2Writer {
    pub(super) fn new(out: &Path, session: usize) -> Result<Self> {
        let name = session_name(session);
        let dir = out.join("rosbag2").join(&name);
        let path = dir.join(format!("{name}_0.mcap"));
        let mut writer = super::ros2_mcap(&path)?;
        let mut channels = [0u16; 4];
        for (i, (topic, kind)) in TOPICS.iter().enumerate() {
            let (schema, text) = match kind {
                None => ("sensor_msgs/msg/PointCloud2".to_string(), super::POINTCLOUD2_MSG),
                Some(k) => (k.name().replacen('/', "/msg/", 1), rosmsg::definition(*k)),
            };
            let id = writer.add_schema(&schema, "ros2msg", text.as_bytes()).at(&path)?;
            channels[i] = writer.add_channel(id, topic, "cdr", &Default::default()).at(&path)?;
        }
        Ok(Rosbag2Writer { dir, name, path, writer, channels, counts: [0; 4], span: (i64::MAX, i64::MIN) })
    }

    fn message(&mut self, conn: usize, stamp_ns: i64, data: &[u8]) -> Result<()> {
        let header = ::mcap::records::MessageHeader {
            channel_id: self.channels[conn],
            sequence: self.counts[conn] as u32,
            log_time: stamp_ns as u64,
            publish_time: stamp_ns as u64,
        };
        self.writer.write_to_known_channel(&header, data).at(&self.path)?;
        self.counts[conn] += 1;
        self.span = (self.span.0.min(stamp_ns), self.span.1.max(stamp_ns));
        Ok(())
    }
}

impl SessionWriter for Rosbag2Writer {
    fn write(&mut self, s: &SimScan) -> Result<()> {
        let stamp_ns = s.utime * 1000;
        if s.index == 0 {
            self.message(3, stamp_ns, &static_message(stamp_ns, Wire::Cdr))?;
        }
        for (conn, data) in messages(s, Wire::Cdr) {
            self.message(conn, stamp_ns, &data)?;
        }
        Ok(())
    }

    fn finish(mut self: Box<Self>) -> Result<()> {
        self.writer.finish().at(&self.path)?;
        self.writer.into_inner().commit()?;
        let mut topics = String::new();
        for (i, (topic, kind)) in TOPICS.iter().enumerate() {
            let schema = match kind {
                None => "sensor_msgs/msg/PointCloud2".to_string(),
                Some(k) => k.name().replacen('/', "/msg/", 1),
            };
            topics += &format!(
                "    - topic_metadata:\n        name: {topic}\n        type: {schema}\n        serialization_format: cdr\n        offered_qos_profiles: \"\"\n      message_count: {}\n",
                self.counts[i]
            );
        }
        let total: u64 = self.counts.iter().sum();
        let metadata = format!(
            "rosbag2_bagfile_information:\n  version: 8\n  storage_identifier: mcap\n  duration:\n    nanoseconds: {}\n  starting_time:\n    nanoseconds_since_epoch: {}\n  message_count: {total}\n  topics_with_message_count:\n{topics}  compression_format: \"\"\n  compression_mode: \"\"\n  relative_file_paths:\n    - {}_0.mcap\n  files:\n    - path: {}_0.mcap\n      starting_time:\n        nanoseconds_since_epoch: {}\n      duration:\n        nanoseconds: {}\n      message_count: {total}\n",
            self.span.1 - self.span.0,
            self.span.0,
            self.name,
            self.name,
            self.span.0,
            self.span.1 - self.span.0
        );
        crate::fsutil::write_atomic(&self.dir.join("metadata.yaml"), metadata.as_bytes())
    }
}
