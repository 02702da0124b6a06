//! MCAP files, streamed record by record (the MCAP specification, foxglove/mcap): memory is bounded by the largest
//! chunk, not the file. The `mcap` crate's sans-io [`LinearReader`] walks the file and hands
//! over whole chunk records; toporec decompresses each chunk itself (zstd, lz4 frames, or
//! none) and checks its CRC, so a corrupt chunk costs only its own messages: it is reported
//! (file, chunk number, byte offset) and reading goes on with the next chunk. The summary
//! section is not needed (files without one read the same).

use ::mcap::records::{Record, op};
use ::mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use std::collections::{HashMap, VecDeque};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A channel with its schema, as declared in the file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChannelInfo {
    /// Channel id.
    pub id: u16,
    /// Topic name.
    pub topic: String,
    /// Message encoding (`cdr`, `ros1`, `protobuf`, ...).
    pub message_encoding: String,
    /// Schema name (e.g. `sensor_msgs/msg/PointCloud2`), empty without a schema.
    pub schema_name: String,
    /// Schema encoding (`ros2msg`, `ros1msg`, ...).
    pub schema_encoding: String,
}

/// One message, owning its bytes.
#[derive(Clone, Debug)]
pub struct RawMessage {
    /// Its channel.
    pub channel: Arc<ChannelInfo>,
    /// Log time in nanoseconds.
    pub log_time: u64,
    /// Serialized message.
    pub data: Vec<u8>,
}

/// An error inside the file: where, and what.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct McapFault {
    /// Where (e.g. `chunk 3 at byte 1234`).
    pub location: String,
    /// What went wrong.
    pub message: String,
}

/// Record lengths above this are treated as corruption (no LiDAR chunk is this large).
const RECORD_LIMIT: usize = 1 << 31;

/// A stream of one log's messages, in file order (a corrupt chunk or message is a fault item).
pub(crate) type Messages = Box<dyn Iterator<Item = Result<RawMessage, McapFault>> + Send>;

/// Streams the messages of an MCAP file in file order.
pub struct McapMessages {
    path: PathBuf,
    file: std::io::BufReader<std::fs::File>,
    reader: LinearReader,
    state: State,
    done: bool,
}

#[derive(Default)]
struct State {
    schemas: HashMap<u16, (String, String)>,
    channels: HashMap<u16, Arc<ChannelInfo>>,
    pending: VecDeque<Result<RawMessage, McapFault>>,
    chunks: usize,
    offset: u64,
    past_data_end: bool,
}

impl McapMessages {
    /// Opens `path`.
    pub fn open(path: &Path) -> std::io::Result<Self> {
        let file = std::fs::File::open(path)?;
        // No record is longer than the file: a corrupt length fails at once instead of
        // making the reader buffer gigabytes.
        let limit = usize::try_from(file.metadata()?.len()).unwrap_or(usize::MAX).min(RECORD_LIMIT);
        let file = std::io::BufReader::with_capacity(1 << 20, file);
        let options = LinearReaderOptions::default().with_emit_chunks(true).with_record_length_limit(limit);
        Ok(McapMessages {
            path: path.to_owned(),
            file,
            reader: LinearReader::new_with_options(options),
            state: State { offset: 8, ..State::default() },
            done: false,
        })
    }

    /// The channels seen so far.
    pub fn channels(&self) -> impl Iterator<Item = &Arc<ChannelInfo>> {
        self.state.channels.values()
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Iterator for McapMessages {
    type Item = Result<RawMessage, McapFault>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(item) = self.state.pending.pop_front() {
                return Some(item);
            }
            if self.done {
                return None;
            }
            match self.reader.next_event() {
                None => self.done = true,
                Some(Err(e)) => {
                    self.done = true;
                    let location = format!("after byte {}", self.state.offset);
                    return Some(Err(McapFault { location, message: e.to_string() }));
                }
                Some(Ok(LinearReadEvent::ReadRequest(n))) => {
                    let buf = self.reader.insert(n);
                    match self.file.read(buf) {
                        Ok(k) => self.reader.notify_read(k),
                        Err(e) => {
                            self.done = true;
                            let location = format!("at byte {}", self.state.offset);
                            return Some(Err(McapFault { location, message: e.to_string() }));
                        }
                    }
                }
                Some(Ok(LinearReadEvent::Record { opcode, data })) => {
                    let len = data.len() as u64;
                    self.state.record(opcode, data);
                    self.state.offset += 9 + len;
                }
            }
        }
    }
}

impl State {
    fn fault(&mut self, location: String, message: impl std::fmt::Display) {
        self.pending.push_back(Err(McapFault { location, message: message.to_string() }));
    }

    fn record(&mut self, opcode: u8, data: &[u8]) {
        if opcode == op::DATA_END {
            self.past_data_end = true;
        }
        // The summary repeats schemas and channels; nothing new there.
        if self.past_data_end {
            return;
        }
        let parsed = match ::mcap::parse_record(opcode, data) {
            Ok(r) => r,
            Err(e) => {
                let location = format!("record 0x{opcode:02x} at byte {}", self.offset);
                return self.fault(location, e);
            }
        };
        match parsed {
            Record::Chunk { header, data } => {
                self.chunks += 1;
                let location = format!("chunk {} at byte {}", self.chunks, self.offset);
                match decompress(&header.compression, &data, header.uncompressed_size) {
                    Err(e) => self.fault(location, e),
                    Ok(bytes) => {
                        let crc = crc32fast::hash(&bytes);
                        if header.uncompressed_crc != 0 && crc != header.uncompressed_crc {
                            let m = format!(
                                "CRC mismatch (stored {:08x}, computed {crc:08x})",
                                header.uncompressed_crc
                            );
                            return self.fault(location, m);
                        }
                        self.chunk_records(&bytes, &location);
                    }
                }
            }
            other => {
                let location = format!("byte {}", self.offset);
                self.plain(other, &location);
            }
        }
    }

    fn chunk_records(&mut self, mut bytes: &[u8], location: &str) {
        while !bytes.is_empty() {
            if bytes.len() < 9 {
                return self.fault(location.into(), "truncated record at the end of the chunk");
            }
            let opcode = bytes[0];
            let len = u64::from_le_bytes(bytes[1..9].try_into().unwrap());
            let Some(body) = usize::try_from(len).ok().and_then(|l| bytes.get(9..9 + l)) else {
                return self.fault(location.into(), format!("record length {len} overruns the chunk"));
            };
            match ::mcap::parse_record(opcode, body) {
                Ok(r) => self.plain(r, location),
                Err(e) => self.fault(location.into(), e),
            }
            bytes = &bytes[9 + body.len()..];
        }
    }

    fn plain(&mut self, record: Record<'_>, location: &str) {
        match record {
            Record::Schema { header, .. } => {
                self.schemas.insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(c) => {
                let (schema_name, schema_encoding) =
                    self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                let info = ChannelInfo {
                    id: c.id,
                    topic: c.topic,
                    message_encoding: c.message_encoding,
                    schema_name,
                    schema_encoding,
                };
                self.channels.insert(c.id, Arc::new(info));
            }
            Record::Message { header, data } => match self.channels.get(&header.channel_id) {
                Some(channel) => self.pending.push_back(Ok(RawMessage {
                    channel: channel.clone(),
                    log_time: header.log_time,
                    data: data.into_owned(),
                })),
                None => self
                    .fault(location.into(), format!("message on undeclared channel {}", header.channel_id)),
            },
            _ => {}
        }
    }
}

fn decompress(compression: &str, data: &[u8], size: u64) -> Result<Vec<u8>, String> {
    let size = usize::try_from(size).ok().filter(|&s| s <= RECORD_LIMIT).ok_or("absurd uncompressed size")?;
    let out = match compression {
        "" => data.to_vec(),
        // Streaming decoders, reading at most one byte past the declared size: a corrupt size
        // cannot make us allocate more than the data really holds.
        "zstd" => {
            let mut out = Vec::new();
            zstd::stream::read::Decoder::new(data)
                .and_then(|d| d.take(size as u64 + 1).read_to_end(&mut out))
                .map_err(|e| format!("zstd: {e}"))?;
            out
        }
        "lz4" => {
            let mut out = Vec::new();
            lz4::Decoder::new(data)
                .and_then(|d| d.take(size as u64 + 1).read_to_end(&mut out))
                .map_err(|e| format!("lz4: {e}"))?;
            out
        }
        other => return Err(format!("unsupported chunk compression `{other}`")),
    };
    if out.len() != size {
        return Err(format!("chunk decompressed to {} bytes, header says {size}", out.len()));
    }
    Ok(out)
}

/// Whether a channel carries point clouds toporec decodes (PointCloud2 in CDR or ROS 1,
/// `foxglove.PointCloud` in protobuf).
pub(crate) fn is_point_cloud(c: &ChannelInfo) -> bool {
    matches!(
        (c.schema_name.as_str(), c.message_encoding.as_str()),
        ("sensor_msgs/msg/PointCloud2", "cdr")
            | ("sensor_msgs/PointCloud2", "ros1")
            | ("foxglove.PointCloud", "protobuf")
    )
}

/// The channels listed in the file's summary section, or None when the file has no summary
/// (or it cannot be read): then only a full pass finds them. Reads only the summary.
pub fn summary_channels(path: &Path) -> Option<Vec<ChannelInfo>> {
    use std::io::{Seek, SeekFrom};
    let mut f = std::fs::File::open(path).ok()?;
    let len = f.metadata().ok()?.len();
    // Footer record (1 + 8 + 20 bytes) then the 8-byte magic.
    let tail_len = 37u64;
    if len < 8 + tail_len {
        return None;
    }
    f.seek(SeekFrom::Start(len - tail_len)).ok()?;
    let mut tail = [0u8; 37];
    f.read_exact(&mut tail).ok()?;
    if tail[0] != op::FOOTER || &tail[29..] != ::mcap::MAGIC {
        return None;
    }
    let summary_start = u64::from_le_bytes(tail[9..17].try_into().unwrap());
    let footer_start = len - tail_len;
    if summary_start == 0 || summary_start >= footer_start {
        return None;
    }
    f.seek(SeekFrom::Start(summary_start)).ok()?;
    let mut summary = vec![0u8; (footer_start - summary_start) as usize];
    f.read_exact(&mut summary).ok()?;
    let mut state = State::default();
    let mut bytes = &summary[..];
    while bytes.len() >= 9 {
        let opcode = bytes[0];
        let n = usize::try_from(u64::from_le_bytes(bytes[1..9].try_into().unwrap())).ok()?;
        let body = bytes.get(9..9usize.checked_add(n)?)?;
        if matches!(opcode, op::SCHEMA | op::CHANNEL) {
            state.plain(::mcap::parse_record(opcode, body).ok()?, "summary");
        }
        bytes = &bytes[9 + n..];
    }
    let mut channels: Vec<ChannelInfo> = state.channels.values().map(|c| (**c).clone()).collect();
    channels.sort_by_key(|c| c.id);
    Some(channels)
}

/// Whether the file starts with the MCAP magic.
pub(crate) fn is_mcap(path: &Path) -> bool {
    let mut magic = [0u8; 8];
    std::fs::File::open(path).and_then(|mut f| f.read_exact(&mut magic)).is_ok() && magic == ::mcap::MAGIC
}

/// All channels of an MCAP file: from its summary, else by a full pass.
pub fn channels(path: &Path) -> Result<Vec<ChannelInfo>, super::SourceError> {
    if let Some(c) = summary_channels(path) {
        return Ok(c);
    }
    let mut messages = McapMessages::open(path)
        .map_err(|source| super::SourceError::Io { path: path.to_owned(), source })?;
    for m in messages.by_ref() {
        if let Err(fault) = m {
            tracing::warn!("{}: {}: {}", path.display(), fault.location, fault.message);
        }
    }
    let mut c: Vec<ChannelInfo> = messages.channels().map(|c| (**c).clone()).collect();
    c.sort_by_key(|c| c.id);
    Ok(c)
}
