//! rosbag2 bags: a folder of `metadata.yaml` and its storage files (split bags are several),
//! each sqlite3 (`.db3`) or MCAP; and one `.db3` file alone.
//!
//! `metadata.yaml` (rosbag2's `rosbag2_bagfile_information`) gives the storage, the files in
//! order (`relative_file_paths`) and the compression. Compression as rosbag2 writes it:
//! `compression_mode: FILE` compresses each storage file whole with zstd (`x.db3.zstd`), which is
//! decompressed to a temporary file before it is read (sqlite3 reads files, not streams; the
//! file is deleted when reading moves on); `MESSAGE` compresses each message's bytes, which are
//! decompressed one by one. A file the metadata lists but the folder lacks is one fault naming
//! it, and the other files are read.
//!
//! sqlite3 storage is read through the columns every rosbag2 version has:
//! `topics(id, name, type, serialization_format)` and `messages(topic_id, timestamp, data)`,
//! messages in timestamp order (ties in insertion order), one message's bytes in memory at a
//! time. A message's log time is its `timestamp` (ns), the time it was recorded.

use super::mcap_reader::{ChannelInfo, McapFault, McapMessages, RawMessage};
use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The metadata file's name in a rosbag2 folder.
pub const METADATA: &str = "metadata.yaml";

/// The first 16 bytes of an SQLite database file.
const SQLITE_MAGIC: &[u8; 16] = b"SQLite format 3\0";

/// Whether `path` is an SQLite database file (by its magic).
pub fn is_sqlite(path: &Path) -> bool {
    let mut magic = [0u8; 16];
    std::fs::File::open(path).and_then(|mut f| f.read_exact(&mut magic)).is_ok() && &magic == SQLITE_MAGIC
}

/// Whether the SQLite database at `path` has rosbag2's tables (`topics` and `messages`); an
/// error (sqlite3's) when it cannot be read as a database.
pub fn has_rosbag2_tables(path: &Path) -> Result<bool, String> {
    let conn = open_sqlite(path)?;
    let count: i64 = conn
        .query_row(
            "SELECT count(*) FROM sqlite_master WHERE type = 'table' AND name IN ('topics', 'messages')",
            [],
            |r| r.get(0),
        )
        .map_err(|e| format!("sqlite3: {e}"))?;
    Ok(count == 2)
}

/// Whether `path` is a rosbag2 folder (holds a `metadata.yaml`).
pub fn is_rosbag2_folder(path: &Path) -> bool {
    path.is_dir() && path.join(METADATA).is_file()
}

/// How the storage files or messages are compressed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Compression {
    /// Neither.
    None,
    /// Each storage file whole (zstd).
    File,
    /// Each message's bytes (zstd).
    Message,
}

/// What `metadata.yaml` says.
#[derive(Clone, Debug, PartialEq)]
pub struct Metadata {
    /// `sqlite3` or `mcap`.
    pub storage: String,
    /// The storage files, in order, as paths in the folder.
    pub files: Vec<PathBuf>,
    /// What is compressed, if anything.
    pub compression: Compression,
}

impl Metadata {
    /// Reads `dir/metadata.yaml`.
    pub fn read(dir: &Path) -> Result<Metadata, String> {
        let path = dir.join(METADATA);
        let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        Metadata::parse(&text, dir).map_err(|e| format!("{}: {e}", path.display()))
    }

    fn parse(text: &str, dir: &Path) -> Result<Metadata, String> {
        let docs = yaml_rust2::YamlLoader::load_from_str(text).map_err(|e| e.to_string())?;
        let info = docs.first().map(|d| &d["rosbag2_bagfile_information"]).filter(|i| !i.is_badvalue());
        let info = info.ok_or("no `rosbag2_bagfile_information`")?;
        let storage = info["storage_identifier"].as_str().ok_or("no `storage_identifier`")?.to_string();
        if storage != "sqlite3" && storage != "mcap" {
            return Err(format!("storage `{storage}`: toporec reads sqlite3 and mcap"));
        }
        let files: Vec<PathBuf> = match info["relative_file_paths"].as_vec() {
            Some(v) => v
                .iter()
                .map(|f| f.as_str().map(|f| dir.join(f)).ok_or("a file path that is not a string"))
                .collect::<Result<_, _>>()?,
            None => return Err("no `relative_file_paths`".into()),
        };
        if files.is_empty() {
            return Err("`relative_file_paths` is empty".into());
        }
        let format = info["compression_format"].as_str().unwrap_or("");
        let mode = info["compression_mode"].as_str().unwrap_or("").to_ascii_uppercase();
        let compression = match (format, mode.as_str()) {
            (_, "" | "NONE") => Compression::None,
            ("zstd", "FILE") => Compression::File,
            ("zstd", "MESSAGE") => Compression::Message,
            (f, m) => {
                return Err(format!("compression `{f}` by `{m}`: toporec reads zstd by FILE or MESSAGE"));
            }
        };
        Ok(Metadata { storage, files, compression })
    }
}

/// A stream of messages from any storage file.
pub(crate) type Messages = Box<dyn Iterator<Item = Result<RawMessage, McapFault>> + Send>;

/// The messages of a rosbag2 folder: its files in order, each read whole before the next.
pub fn folder_messages(dir: &Path) -> Result<Messages, String> {
    let meta = Metadata::read(dir)?;
    let storage = meta.storage.clone();
    let compression = meta.compression;
    Ok(Box::new(meta.files.into_iter().flat_map(move |file| -> Messages {
        match storage_messages(&file, &storage, compression) {
            Ok(m) => m,
            Err(e) => {
                let name = file.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
                Box::new(std::iter::once(Err(McapFault { location: format!("file {name}"), message: e })))
            }
        }
    })))
}

/// The messages of one storage file of a rosbag2 folder.
fn storage_messages(file: &Path, storage: &str, compression: Compression) -> Result<Messages, String> {
    if !file.is_file() {
        return Err("listed in metadata.yaml but missing".into());
    }
    let (path, temp) = if compression == Compression::File {
        let temp = decompress_to_temp(file)?;
        (temp.path().to_owned(), Some(temp))
    } else {
        (file.to_owned(), None)
    };
    let inner: Messages = match storage {
        "sqlite3" => Box::new(Sqlite3Messages::open(&path)?),
        _ => Box::new(McapMessages::open(&path).map_err(|e| e.to_string())?),
    };
    let inner: Messages = match compression {
        Compression::Message => Box::new(inner.map(|m| {
            m.and_then(|mut m| {
                m.data = zstd::decode_all(m.data.as_slice()).map_err(|e| McapFault {
                    location: format!("message at {} ns on {}", m.log_time, m.channel.topic),
                    message: format!("zstd: {e}"),
                })?;
                Ok(m)
            })
        })),
        _ => inner,
    };
    // The temporary file lives until its messages are read.
    Ok(Box::new(KeepAlive { inner, _temp: temp }))
}

struct KeepAlive {
    inner: Messages,
    _temp: Option<tempfile::NamedTempFile>,
}

impl Iterator for KeepAlive {
    type Item = Result<RawMessage, McapFault>;
    fn next(&mut self) -> Option<Self::Item> {
        self.inner.next()
    }
}

fn decompress_to_temp(file: &Path) -> Result<tempfile::NamedTempFile, String> {
    let mut temp = tempfile::NamedTempFile::new().map_err(|e| format!("a temporary file: {e}"))?;
    let src = std::fs::File::open(file).map_err(|e| e.to_string())?;
    zstd::stream::copy_decode(std::io::BufReader::new(src), &mut temp)
        .map_err(|e| format!("zstd (compression_mode FILE): {e}"))?;
    Ok(temp)
}

/// The channels of a rosbag2 folder: the topics of its storage files.
pub fn folder_channels(dir: &Path) -> Result<Vec<ChannelInfo>, String> {
    let meta = Metadata::read(dir)?;
    let mut out: Vec<ChannelInfo> = Vec::new();
    for file in meta.files.iter().filter(|f| f.is_file()) {
        let channels = match (meta.storage.as_str(), meta.compression) {
            // A compressed file's topics need its contents: its messages' channels.
            (_, Compression::File) => {
                let mut seen: Vec<ChannelInfo> = Vec::new();
                for msg in storage_messages(file, &meta.storage, meta.compression)?.flatten() {
                    if !seen.iter().any(|c| c.id == msg.channel.id) {
                        seen.push((*msg.channel).clone());
                    }
                }
                seen
            }
            ("mcap", _) => super::mcap_reader::channels(file).map_err(|e| e.to_string())?,
            _ => sqlite3_channels(&open_sqlite(file)?)?,
        };
        for c in channels {
            if !out.iter().any(|o| o.topic == c.topic && o.schema_name == c.schema_name) {
                out.push(c);
            }
        }
    }
    Ok(out)
}

fn open_sqlite(path: &Path) -> Result<rusqlite::Connection, String> {
    use rusqlite::OpenFlags;
    let flags = OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX;
    let conn = rusqlite::Connection::open_with_flags(path, flags).map_err(|e| format!("sqlite3: {e}"))?;
    Ok(conn)
}

/// The topics table as channels (`cdr` → encoding `cdr`).
fn sqlite3_channels(conn: &rusqlite::Connection) -> Result<Vec<ChannelInfo>, String> {
    let mut stmt = conn
        .prepare("SELECT id, name, type, serialization_format FROM topics ORDER BY id")
        .map_err(|e| format!("sqlite3 topics: {e}"))?;
    let rows = stmt
        .query_map([], |r| {
            Ok((r.get::<_, i64>(0)?, r.get::<_, String>(1)?, r.get::<_, String>(2)?, r.get::<_, String>(3)?))
        })
        .map_err(|e| format!("sqlite3 topics: {e}"))?;
    let mut out = Vec::new();
    for row in rows {
        let (id, name, ty, format) = row.map_err(|e| format!("sqlite3 topics: {e}"))?;
        let id = u16::try_from(id).map_err(|_| format!("sqlite3 topic id {id} outside 0..65536"))?;
        out.push(ChannelInfo {
            id,
            topic: name,
            message_encoding: format,
            schema_name: ty,
            schema_encoding: "ros2msg".into(),
        });
    }
    Ok(out)
}

/// The messages of a rosbag2 sqlite3 file, in timestamp order.
pub struct Sqlite3Messages {
    conn: rusqlite::Connection,
    channels: HashMap<i64, Arc<ChannelInfo>>,
    /// Every message's row id, topic and timestamp, in reading order.
    rows: std::vec::IntoIter<(i64, i64, i64)>,
}

impl Sqlite3Messages {
    /// Opens `path` and lists its messages (not their bytes).
    pub fn open(path: &Path) -> Result<Self, String> {
        let conn = open_sqlite(path)?;
        let channels = sqlite3_channels(&conn)?.into_iter().map(|c| (i64::from(c.id), Arc::new(c))).collect();
        let rows = {
            let mut stmt = conn
                .prepare("SELECT rowid, topic_id, timestamp FROM messages ORDER BY timestamp, rowid")
                .map_err(|e| format!("sqlite3 messages: {e}"))?;
            let rows = stmt
                .query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
                .map_err(|e| format!("sqlite3 messages: {e}"))?;
            rows.collect::<Result<Vec<(i64, i64, i64)>, _>>().map_err(|e| format!("sqlite3 messages: {e}"))?
        };
        Ok(Sqlite3Messages { conn, channels, rows: rows.into_iter() })
    }
}

impl Iterator for Sqlite3Messages {
    type Item = Result<RawMessage, McapFault>;

    fn next(&mut self) -> Option<Self::Item> {
        let (rowid, topic, timestamp) = self.rows.next()?;
        let location = format!("message row {rowid}");
        let Some(channel) = self.channels.get(&topic).cloned() else {
            return Some(Err(McapFault {
                location,
                message: format!("topic id {topic} not in the topics table"),
            }));
        };
        let data = self
            .conn
            .prepare_cached("SELECT data FROM messages WHERE rowid = ?1")
            .and_then(|mut s| s.query_row([rowid], |r| r.get::<_, Vec<u8>>(0)));
        Some(match data {
            Ok(data) => Ok(RawMessage { channel, log_time: timestamp.max(0) as u64, data }),
            Err(e) => Err(McapFault { location, message: format!("sqlite3: {e}") }),
        })
    }
}

/// The channels of a lone `.db3` file.
pub fn sqlite3_file_channels(path: &Path) -> Result<Vec<ChannelInfo>, String> {
    sqlite3_channels(&open_sqlite(path)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metadata_reads_files_storage_and_compression() {
        let text = "rosbag2_bagfile_information:\n  storage_identifier: sqlite3\n  compression_format: zstd\n  compression_mode: FILE\n  relative_file_paths:\n  - a_0.db3.zstd\n  - a_1.db3.zstd\n";
        let m = Metadata::parse(text, Path::new("bag")).unwrap();
        assert_eq!(m.storage, "sqlite3");
        assert_eq!(m.files, vec![PathBuf::from("bag/a_0.db3.zstd"), PathBuf::from("bag/a_1.db3.zstd")]);
        assert_eq!(m.compression, Compression::File);
        let bad = text.replace("sqlite3", "bagfs");
        assert!(Metadata::parse(&bad, Path::new("bag")).unwrap_err().contains("storage `bagfs`"));
        let bad = text.replace("zstd", "lz77");
        assert!(Metadata::parse(&bad, Path::new("bag")).unwrap_err().contains("compression"));
        assert!(Metadata::parse("a: [", Path::new("bag")).is_err());
    }
}
