//! ROS 1 bags (format 2.0, the ROS wiki's `Bags/Format/2.0`), streamed chunk by chunk: memory
//! is one decompressed chunk, not the file.
//!
//! A bag is `#ROSBAG V2.0\n` and records, each a header (`name=value` fields, `op` among them)
//! and data. Messages (op 0x02) and their connections (0x07) sit in chunks (0x05), compressed
//! `none`, `bz2` or `lz4` (LZ4 frames); the index section at the bag header's `index_pos` repeats
//! the connections and lists every chunk (chunk info, 0x06). When the index is there, its
//! connections name the topics without reading a chunk, and reading walks the chunks it lists,
//! so a corrupt chunk costs only its own messages. A bag without an index (a recording cut
//! short: `index_pos` 0) is read record by record to its end, in the same order; a damaged
//! record there ends the reading with a fault naming its byte offset.
//!
//! Messages come out as MCAP's do ([`RawMessage`], encoding `ros1`, the connection's `type` as
//! the schema name); a message's log time is its record time.

use super::mcap_reader::{ChannelInfo, McapFault, RawMessage};
use std::collections::{HashMap, VecDeque};
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The first bytes of every ROS 1 bag.
pub const MAGIC: &[u8; 13] = b"#ROSBAG V2.0\n";

const OP_MESSAGE: u8 = 0x02;
const OP_BAG_HEADER: u8 = 0x03;
const OP_INDEX: u8 = 0x04;
const OP_CHUNK: u8 = 0x05;
const OP_CHUNK_INFO: u8 = 0x06;
const OP_CONNECTION: u8 = 0x07;

/// No header or chunk of a LiDAR bag comes near this; a larger length is corruption.
const RECORD_LIMIT: u64 = 1 << 31;

/// Whether the file starts with the ROS 1 bag magic.
pub fn is_ros1_bag(path: &Path) -> bool {
    let mut magic = [0u8; 13];
    std::fs::File::open(path).and_then(|mut f| f.read_exact(&mut magic)).is_ok() && &magic == MAGIC
}

/// A record's header fields, by name.
struct Fields<'a>(Vec<(&'a [u8], &'a [u8])>);

impl<'a> Fields<'a> {
    fn parse(mut bytes: &'a [u8]) -> Result<Self, String> {
        let mut fields = Vec::new();
        while !bytes.is_empty() {
            let len = bytes.get(..4).map(|b| u32::from_le_bytes(b.try_into().unwrap()) as usize);
            let field = len.and_then(|l| bytes.get(4..4 + l)).ok_or("header field overruns the header")?;
            let eq = field.iter().position(|&b| b == b'=').ok_or("header field without `=`")?;
            fields.push((&field[..eq], &field[eq + 1..]));
            bytes = &bytes[4 + field.len()..];
        }
        Ok(Fields(fields))
    }

    fn get(&self, name: &str) -> Result<&'a [u8], String> {
        self.0
            .iter()
            .find(|(n, _)| *n == name.as_bytes())
            .map(|(_, v)| *v)
            .ok_or(format!("no `{name}` field"))
    }

    fn u8(&self, name: &str) -> Result<u8, String> {
        self.get(name)?.first().copied().ok_or(format!("empty `{name}` field"))
    }

    fn u32(&self, name: &str) -> Result<u32, String> {
        let v = self.get(name)?;
        Ok(u32::from_le_bytes(v.try_into().map_err(|_| format!("`{name}` is not 4 bytes"))?))
    }

    fn u64(&self, name: &str) -> Result<u64, String> {
        let v = self.get(name)?;
        Ok(u64::from_le_bytes(v.try_into().map_err(|_| format!("`{name}` is not 8 bytes"))?))
    }

    fn text(&self, name: &str) -> Result<String, String> {
        Ok(String::from_utf8_lossy(self.get(name)?).into_owned())
    }

    /// A ROS time field (u32 seconds, u32 nanoseconds) in nanoseconds.
    fn time_ns(&self, name: &str) -> Result<u64, String> {
        let t = self.u64(name)?;
        Ok((t & 0xffff_ffff) * 1_000_000_000 + (t >> 32))
    }
}

/// One record, owning its header and data.
struct Record {
    header: Vec<u8>,
    data: Vec<u8>,
}

/// Reads the record at the reader's position; `Ok(None)` at the end of the file.
fn read_record(r: &mut impl Read, file_len: u64) -> Result<Option<Record>, String> {
    let mut len = [0u8; 4];
    match r.read(&mut len[..1]) {
        Ok(0) => return Ok(None),
        Ok(_) => r.read_exact(&mut len[1..]).map_err(|e| format!("header length: {e}"))?,
        Err(e) => return Err(e.to_string()),
    }
    let header = read_part(r, "header", u32::from_le_bytes(len), file_len)?;
    let mut data_len = [0u8; 4];
    r.read_exact(&mut data_len).map_err(|e| format!("truncated record (data length: {e})"))?;
    let data = read_part(r, "data", u32::from_le_bytes(data_len), file_len)?;
    Ok(Some(Record { header, data }))
}

/// `len` bytes of a record's `what` (header or data), checked against the file's length.
fn read_part(r: &mut impl Read, what: &str, len: u32, file_len: u64) -> Result<Vec<u8>, String> {
    let len = u64::from(len);
    if len > file_len.min(RECORD_LIMIT) {
        return Err(format!("{what} length {len} exceeds the file"));
    }
    let mut out = Vec::new();
    r.take(len).read_to_end(&mut out).map_err(|e| format!("{what}: {e}"))?;
    if out.len() as u64 != len {
        return Err(format!("truncated {what} ({} of {len} bytes)", out.len()));
    }
    Ok(out)
}

/// The bag header's fields that say where the index is.
struct BagHeader {
    index_pos: u64,
}

/// What a bag's index says: its connections and the start of every chunk.
struct BagIndex {
    channels: Vec<ChannelInfo>,
    chunk_positions: Vec<u64>,
    /// Messages per connection, summed over the chunk infos.
    counts: HashMap<u16, u64>,
}

fn channel_of(fields: &Fields<'_>, data: &[u8]) -> Result<ChannelInfo, String> {
    let conn = fields.u32("conn")?;
    let id = u16::try_from(conn).map_err(|_| format!("connection id {conn} above 65535"))?;
    let described = Fields::parse(data)?;
    Ok(ChannelInfo {
        id,
        topic: fields.text("topic")?,
        message_encoding: "ros1".into(),
        schema_name: described.text("type")?,
        schema_encoding: "ros1msg".into(),
    })
}

/// Streams the messages of a ROS 1 bag in file order.
pub struct Ros1Messages {
    path: PathBuf,
    file: BufReader<std::fs::File>,
    file_len: u64,
    /// The chunks still to read, from the index; None: a record-by-record walk.
    chunks: Option<VecDeque<u64>>,
    channels: HashMap<u16, Arc<ChannelInfo>>,
    pending: VecDeque<Result<RawMessage, McapFault>>,
    /// Where the walk is (byte offset), and chunks read so far.
    offset: u64,
    chunk_count: usize,
    done: bool,
}

impl Ros1Messages {
    /// Opens `path`: checks the magic, reads the bag header and, when present, the index.
    pub fn open(path: &Path) -> Result<Self, String> {
        let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
        let file_len = file.metadata().map_err(|e| e.to_string())?.len();
        let mut file = BufReader::with_capacity(1 << 20, file);
        let mut magic = [0u8; 13];
        file.read_exact(&mut magic).map_err(|_| "shorter than a ROS 1 bag's magic".to_string())?;
        if &magic != MAGIC {
            return Err("not a ROS 1 bag (no `#ROSBAG V2.0` magic)".into());
        }
        let header = read_bag_header(&mut file, file_len)?;
        let offset = file.stream_position().map_err(|e| e.to_string())?;
        let index = match header.index_pos {
            0 => None,
            pos if pos < offset || pos >= file_len => None,
            pos => read_index(&mut file, pos, file_len).ok(),
        };
        let mut reader = Ros1Messages {
            path: path.to_owned(),
            file,
            file_len,
            chunks: None,
            channels: HashMap::new(),
            pending: VecDeque::new(),
            offset,
            chunk_count: 0,
            done: false,
        };
        if let Some(index) = index {
            reader.channels = index.channels.into_iter().map(|c| (c.id, Arc::new(c))).collect();
            reader.chunks = Some(index.chunk_positions.into());
        }
        reader.file.seek(SeekFrom::Start(offset)).map_err(|e| e.to_string())?;
        Ok(reader)
    }

    /// The channels known so far (all of them, when the bag has an index).
    pub fn channels(&self) -> impl Iterator<Item = &Arc<ChannelInfo>> {
        self.channels.values()
    }

    /// Whether the bag's index was read.
    pub fn indexed(&self) -> bool {
        self.chunks.is_some()
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn fault(&mut self, location: String, message: impl std::fmt::Display) {
        self.pending.push_back(Err(McapFault { location, message: message.to_string() }));
    }

    /// Reads the next record of the walk (indexed: the next chunk listed).
    fn step(&mut self) {
        if let Some(chunks) = &mut self.chunks {
            let Some(pos) = chunks.pop_front() else {
                self.done = true;
                return;
            };
            self.offset = pos;
            if let Err(e) = self.file.seek(SeekFrom::Start(pos)) {
                self.done = true;
                return self.fault(format!("chunk at byte {pos}"), e);
            }
        }
        let at = self.offset;
        let record = match read_record(&mut self.file, self.file_len) {
            Ok(Some(r)) => r,
            Ok(None) => {
                self.done = true;
                return;
            }
            Err(e) => {
                // Without an index nothing says where the next record starts.
                if self.chunks.is_none() {
                    self.done = true;
                }
                return self.fault(format!("record at byte {at}"), e);
            }
        };
        self.offset = at + 8 + record.header.len() as u64 + record.data.len() as u64;
        let fields = match Fields::parse(&record.header) {
            Ok(f) => f,
            Err(e) => return self.fault(format!("record at byte {at}"), e),
        };
        let op = match fields.u8("op") {
            Ok(op) => op,
            Err(e) => return self.fault(format!("record at byte {at}"), e),
        };
        match op {
            OP_CHUNK => {
                self.chunk_count += 1;
                let location = format!("chunk {} at byte {at}", self.chunk_count);
                match chunk_bytes(&fields, &record.data) {
                    Ok(bytes) => self.chunk_records(&bytes, &location),
                    Err(e) => self.fault(location, e),
                }
            }
            OP_CONNECTION | OP_MESSAGE => {
                let location = format!("record at byte {at}");
                self.inner_record(&fields, record.data, &location);
            }
            // The index section after the last chunk: a walk is done.
            OP_CHUNK_INFO if self.chunks.is_none() => self.done = true,
            OP_INDEX | OP_BAG_HEADER | OP_CHUNK_INFO => {}
            other => self.fault(format!("record at byte {at}"), format!("unknown op 0x{other:02x}")),
        }
    }

    fn chunk_records(&mut self, mut bytes: &[u8], location: &str) {
        while !bytes.is_empty() {
            let mut cursor = bytes;
            let record = match read_record(&mut cursor, bytes.len() as u64) {
                Ok(Some(r)) => r,
                Ok(None) => return,
                Err(e) => return self.fault(location.into(), format!("inside the chunk: {e}")),
            };
            bytes = cursor;
            match Fields::parse(&record.header) {
                Ok(fields) => self.inner_record(&fields, record.data, location),
                Err(e) => self.fault(location.into(), e),
            }
        }
    }

    fn inner_record(&mut self, fields: &Fields<'_>, data: Vec<u8>, location: &str) {
        let op = fields.u8("op");
        let result = match op {
            Ok(OP_CONNECTION) => channel_of(fields, &data).map(|c| {
                self.channels.entry(c.id).or_insert_with(|| Arc::new(c));
            }),
            Ok(OP_MESSAGE) => (|| {
                let conn = fields.u32("conn")?;
                let log_time = fields.time_ns("time")?;
                let channel = u16::try_from(conn)
                    .ok()
                    .and_then(|id| self.channels.get(&id))
                    .ok_or(format!("message on undeclared connection {conn}"))?
                    .clone();
                self.pending.push_back(Ok(RawMessage { channel, log_time, data }));
                Ok(())
            })(),
            Ok(other) => Err(format!("op 0x{other:02x} inside a chunk")),
            Err(e) => Err(e),
        };
        if let Err(e) = result {
            self.fault(location.into(), e);
        }
    }
}

impl Iterator for Ros1Messages {
    type Item = Result<RawMessage, McapFault>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(item) = self.pending.pop_front() {
                return Some(item);
            }
            if self.done {
                return None;
            }
            self.step();
        }
    }
}

fn read_bag_header(file: &mut BufReader<std::fs::File>, file_len: u64) -> Result<BagHeader, String> {
    let record =
        read_record(file, file_len).map_err(|e| format!("bag header: {e}"))?.ok_or("no bag header record")?;
    let fields = Fields::parse(&record.header).map_err(|e| format!("bag header: {e}"))?;
    if fields.u8("op")? != OP_BAG_HEADER {
        return Err("the first record is not a bag header".into());
    }
    Ok(BagHeader { index_pos: fields.u64("index_pos")? })
}

fn read_index(file: &mut BufReader<std::fs::File>, pos: u64, file_len: u64) -> Result<BagIndex, String> {
    file.seek(SeekFrom::Start(pos)).map_err(|e| e.to_string())?;
    let mut index = BagIndex { channels: Vec::new(), chunk_positions: Vec::new(), counts: HashMap::new() };
    while let Some(record) = read_record(file, file_len)? {
        let fields = Fields::parse(&record.header)?;
        match fields.u8("op")? {
            OP_CONNECTION => index.channels.push(channel_of(&fields, &record.data)?),
            OP_CHUNK_INFO => {
                let chunk_pos = fields.u64("chunk_pos")?;
                if chunk_pos >= pos {
                    return Err(format!("chunk position {chunk_pos} inside the index"));
                }
                index.chunk_positions.push(chunk_pos);
                for pair in record.data.chunks_exact(8) {
                    let conn = u32::from_le_bytes(pair[..4].try_into().unwrap());
                    let count = u32::from_le_bytes(pair[4..].try_into().unwrap());
                    if let Ok(id) = u16::try_from(conn) {
                        *index.counts.entry(id).or_default() += u64::from(count);
                    }
                }
            }
            _ => {}
        }
    }
    index.chunk_positions.sort_unstable();
    index.chunk_positions.dedup();
    index.channels.sort_by_key(|c| c.id);
    Ok(index)
}

/// A chunk's records, decompressed.
fn chunk_bytes(fields: &Fields<'_>, data: &[u8]) -> Result<Vec<u8>, String> {
    let compression = fields.text("compression")?;
    let size = u64::from(fields.u32("size")?);
    let mut out = Vec::new();
    match compression.as_str() {
        "none" => out.extend_from_slice(data),
        // Streaming decoders reading at most one byte past the declared size: a corrupt size
        // cannot make us allocate more than the data holds.
        "bz2" => {
            bzip2::read::BzDecoder::new(data)
                .take(size + 1)
                .read_to_end(&mut out)
                .map_err(|e| format!("bz2: {e}"))?;
        }
        "lz4" => {
            lz4::Decoder::new(data)
                .and_then(|d| d.take(size + 1).read_to_end(&mut out))
                .map_err(|e| format!("lz4: {e}"))?;
        }
        other => return Err(format!("unsupported chunk compression `{other}`")),
    }
    if out.len() as u64 != size {
        return Err(format!("chunk decompressed to {} bytes, header says {size}", out.len()));
    }
    Ok(out)
}

/// The connections of a bag: from its index, else by a pass over every chunk.
pub fn channels(path: &Path) -> Result<Vec<ChannelInfo>, String> {
    let mut messages = Ros1Messages::open(path)?;
    if !messages.indexed() {
        for m in messages.by_ref() {
            if let Err(fault) = m {
                tracing::warn!("{}: {}: {}", path.display(), fault.location, fault.message);
            }
        }
    }
    let mut c: Vec<ChannelInfo> = messages.channels().map(|c| (**c).clone()).collect();
    c.sort_by_key(|c| c.id);
    Ok(c)
}

/// Messages per connection id as the index counts them; None without an index.
pub fn indexed_counts(path: &Path) -> Option<HashMap<u16, u64>> {
    let file = std::fs::File::open(path).ok()?;
    let file_len = file.metadata().ok()?.len();
    let mut file = BufReader::new(file);
    let mut magic = [0u8; 13];
    file.read_exact(&mut magic).ok()?;
    let header = read_bag_header(&mut file, file_len).ok()?;
    (header.index_pos != 0).then_some(())?;
    read_index(&mut file, header.index_pos, file_len).ok().map(|i| i.counts)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A record: header fields, then data.
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

    fn connection(conn: u32, topic: &str, ty: &str) -> Vec<u8> {
        let described = record(&[("topic", topic.as_bytes()), ("type", ty.as_bytes())], &[]);
        // The connection's data is a bare header block (no lengths around it).
        let block = &described[4..described.len() - 4];
        record(&[("op", &[OP_CONNECTION]), ("conn", &conn.to_le_bytes()), ("topic", topic.as_bytes())], block)
    }

    fn message(conn: u32, sec: u32, nsec: u32, data: &[u8]) -> Vec<u8> {
        let time = (u64::from(nsec) << 32) | u64::from(sec);
        record(&[("op", &[OP_MESSAGE]), ("conn", &conn.to_le_bytes()), ("time", &time.to_le_bytes())], data)
    }

    fn bag(index_pos: u64, body: &[u8]) -> Vec<u8> {
        let mut out = MAGIC.to_vec();
        out.extend(record(
            &[
                ("op", &[OP_BAG_HEADER]),
                ("index_pos", &index_pos.to_le_bytes()),
                ("conn_count", &1u32.to_le_bytes()),
                ("chunk_count", &1u32.to_le_bytes()),
            ],
            &[b' '; 16],
        ));
        out.extend(body);
        out
    }

    fn write(bytes: &[u8]) -> tempfile::NamedTempFile {
        let mut f = tempfile::NamedTempFile::new().unwrap();
        std::io::Write::write_all(&mut f, bytes).unwrap();
        f
    }

    #[test]
    fn an_unindexed_bag_reads_in_order_and_a_cut_record_is_a_fault() {
        let inner = [
            connection(0, "/points", "sensor_msgs/PointCloud2"),
            message(0, 5, 7, b"one"),
            message(0, 6, 0, b"two"),
        ]
        .concat();
        let chunk = record(
            &[("op", &[OP_CHUNK]), ("compression", b"none"), ("size", &(inner.len() as u32).to_le_bytes())],
            &inner,
        );
        let bytes = bag(0, &chunk);
        let f = write(&bytes);
        let got: Vec<_> = Ros1Messages::open(f.path()).unwrap().collect();
        assert_eq!(got.len(), 2);
        let first = got[0].as_ref().unwrap();
        assert_eq!((first.log_time, first.data.as_slice()), (5_000_000_007, &b"one"[..]));
        assert_eq!(first.channel.schema_name, "sensor_msgs/PointCloud2");
        assert_eq!(first.channel.message_encoding, "ros1");
        // Cut inside the chunk: one fault naming the record's byte offset, nothing else.
        let f = write(&bytes[..bytes.len() - 3]);
        let got: Vec<_> = Ros1Messages::open(f.path()).unwrap().collect();
        assert_eq!(got.len(), 1);
        let fault = got[0].as_ref().unwrap_err();
        assert!(fault.location.starts_with("record at byte "), "{fault:?}");
        assert!(fault.message.contains("truncated"), "{fault:?}");
    }

    #[test]
    fn an_unknown_compression_and_a_wrong_size_are_faults_of_their_chunk() {
        for (compression, size) in [(&b"gzip"[..], 3u32), (&b"none"[..], 4)] {
            let chunk = record(
                &[("op", &[OP_CHUNK]), ("compression", compression), ("size", &size.to_le_bytes())],
                b"abc",
            );
            let f = write(&bag(0, &chunk));
            let got: Vec<_> = Ros1Messages::open(f.path()).unwrap().collect();
            assert_eq!(got.len(), 1);
            assert!(got[0].as_ref().unwrap_err().location.starts_with("chunk 1 at byte "));
        }
    }

    #[test]
    fn not_a_bag_is_refused() {
        let f = write(b"#ROSBAG V1.2\nxxxxxxxx");
        assert!(Ros1Messages::open(f.path()).err().unwrap().contains("not a ROS 1 bag"));
        assert!(!is_ros1_bag(f.path()));
    }
}
