//! The index folder: Hive-partitioned Parquet tables plus the codebook and the effective
//! pipeline.
//!
//! ```text
//! INDEX/
//!   scans/session=<s>/part-0.parquet      diagrams/session=<s>/part-0.parquet
//!   descriptors/session=<s>/part-0.parquet
//!   codebook.json   pipeline.toml   manifest.json
//! ```
//!
//! A run writes everything into `INDEX/.staging-<pid>/` and only at the end moves each
//! partition into place (a rename on the same file system), so readers never see a
//! half-written file and a crashed run leaves the previous index intact (its staging folder
//! is removed by the next run). A run that fits a new codebook replaces the whole index; a run
//! with the index's own saved codebook replaces only the sessions it wrote — the hook for
//! incremental re-indexing.

use super::parquet::{DescriptorsFile, DiagramsFile, ScanRow, ScansFile, Status};
use crate::homology::{Diagram, Pair};
use crate::sources::Pose;
use anyhow::{Context, Result};
use arrow::array::{Array, AsArray, RecordBatch};
use arrow::datatypes::{Float64Type, Int64Type, UInt8Type};
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The partition folder name of a session: `session=<name>` with characters other than
/// letters, digits, `-`, `_`, `.` percent-encoded (as Hive does).
pub fn partition(session: &str) -> String {
    let mut s = String::from("session=");
    for b in session.bytes() {
        if b.is_ascii_alphanumeric() || b"-_.".contains(&b) {
            s.push(b as char);
        } else {
            s.push_str(&format!("%{b:02X}"));
        }
    }
    s
}

/// A finished file in staging.
#[derive(Clone, Debug)]
pub struct WrittenFile {
    /// `scans`, `diagrams` or `descriptors`.
    pub table: &'static str,
    /// Session.
    pub session: String,
    /// Path (in staging until committed).
    pub path: PathBuf,
    /// Rows.
    pub rows: u64,
}

struct SessionFiles {
    session: String,
    scans: ScansFile,
    diagrams: DiagramsFile,
}

/// Writes a new index into staging, then commits it.
pub struct IndexWriter {
    root: PathBuf,
    staging: PathBuf,
    current: Option<SessionFiles>,
    parts: HashMap<(&'static str, String), usize>,
    /// Files finished so far, in order.
    pub written: Vec<WrittenFile>,
}

impl IndexWriter {
    /// Prepares `root` (created if needed; stale staging folders of crashed runs removed).
    pub fn create(root: &Path) -> Result<Self> {
        std::fs::create_dir_all(root)
            .with_context(|| format!("{}: creating the index folder", root.display()))?;
        for e in std::fs::read_dir(root)?.flatten() {
            if e.file_name().to_string_lossy().starts_with(".staging-") {
                tracing::info!("{}: removing a crashed run's staging folder", e.path().display());
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
        let staging = root.join(format!(".staging-{}", std::process::id()));
        std::fs::create_dir_all(&staging)?;
        Ok(IndexWriter {
            root: root.to_owned(),
            staging,
            current: None,
            parts: HashMap::new(),
            written: Vec::new(),
        })
    }

    /// The next part path of `table` for `session`, in staging.
    pub fn part_path(&mut self, table: &'static str, session: &str) -> PathBuf {
        let n = self.parts.entry((table, session.to_string())).or_insert(0);
        let p = self.staging.join(table).join(partition(session)).join(format!("part-{n}.parquet"));
        *n += 1;
        p
    }

    /// Writes one scan's row and, for an ok scan, its pairs in `dims`.
    pub fn write_scan(&mut self, row: ScanRow, diagram: Option<&Diagram>, dims: &[u8]) -> Result<()> {
        if self.current.as_ref().is_none_or(|c| c.session != row.session) {
            self.close_session()?;
            let scans = ScansFile::create(&self.part_path("scans", &row.session))?;
            let diagrams = DiagramsFile::create(&self.part_path("diagrams", &row.session))?;
            self.current = Some(SessionFiles { session: row.session.clone(), scans, diagrams });
        }
        let files = self.current.as_mut().expect("opened above");
        if let Some(d) = diagram {
            files.diagrams.push(&row.scan_id, d, dims)?;
        }
        files.scans.push(row)
    }

    /// Closes the open session's files.
    pub fn close_session(&mut self) -> Result<()> {
        if let Some(f) = self.current.take() {
            let (path, rows) = f.scans.finish()?;
            self.written.push(WrittenFile { table: "scans", session: f.session.clone(), path, rows });
            let (path, rows) = f.diagrams.finish()?;
            self.written.push(WrittenFile { table: "diagrams", session: f.session, path, rows });
        }
        Ok(())
    }

    /// A descriptors file for `session` in staging.
    pub fn descriptors_file(
        &mut self,
        session: &str,
        b: usize,
        codebook_id: &str,
    ) -> Result<DescriptorsFile> {
        let path = self.part_path("descriptors", session);
        DescriptorsFile::create(&path, b, codebook_id)
    }

    /// Records a finished descriptors file.
    pub fn finished(&mut self, table: &'static str, session: &str, (path, rows): (PathBuf, u64)) {
        self.written.push(WrittenFile { table, session: session.to_string(), path, rows });
    }

    /// Files of one table, in the order written.
    pub fn files(&self, table: &str) -> Vec<WrittenFile> {
        self.written.iter().filter(|w| w.table == table).cloned().collect()
    }

    /// Moves the staged partitions (and `extra` files such as `codebook.json`) into the index.
    /// `replace_all` removes partitions of sessions this run did not write.
    pub fn commit(mut self, extra: &[(&str, Vec<u8>)], replace_all: bool) -> Result<PathBuf> {
        self.close_session()?;
        for table in ["scans", "diagrams", "descriptors"] {
            let live = self.root.join(table);
            if replace_all && live.exists() {
                std::fs::remove_dir_all(&live).with_context(|| format!("{}: removing", live.display()))?;
            }
            let staged = self.staging.join(table);
            if !staged.exists() {
                continue;
            }
            std::fs::create_dir_all(&live)?;
            for part in std::fs::read_dir(&staged)?.flatten() {
                let target = live.join(part.file_name());
                if target.exists() {
                    std::fs::remove_dir_all(&target)
                        .with_context(|| format!("{}: removing", target.display()))?;
                }
                std::fs::rename(part.path(), &target)
                    .with_context(|| format!("{}: moving into place", target.display()))?;
            }
        }
        for (name, bytes) in extra {
            crate::fsutil::write_atomic(&self.root.join(name), bytes)?;
        }
        std::fs::remove_dir_all(&self.staging).ok();
        Ok(self.root.clone())
    }

    /// Deletes the staging folder (a run that fails before committing).
    pub fn abandon(self) {
        std::fs::remove_dir_all(&self.staging).ok();
    }
}

fn open(path: &Path) -> Result<impl Iterator<Item = Result<RecordBatch, arrow::error::ArrowError>> + use<>> {
    let file = std::fs::File::open(path).with_context(|| format!("{}: opening", path.display()))?;
    Ok(ParquetRecordBatchReaderBuilder::try_new(file)?.with_batch_size(8192).build()?)
}

/// The ok scans of a `scans` file, in order: (scan_id, utime, pose).
pub fn ok_scans(path: &Path) -> Result<Vec<(String, Option<i64>, Option<Pose>)>> {
    let mut out = Vec::new();
    for batch in open(path)? {
        let b = batch?;
        let col =
            |name: &str| b.column_by_name(name).unwrap_or_else(|| panic!("scans has column {name}")).clone();
        let ids = col("scan_id");
        let ids = ids.as_string::<i32>();
        let status = col("status");
        let status = status.as_string::<i32>();
        let utime = col("utime");
        let utime = utime.as_primitive::<Int64Type>();
        let [x, y, z, yaw] = ["pose_x", "pose_y", "pose_z", "pose_yaw"].map(col);
        let [x, y, z, yaw] = [&x, &y, &z, &yaw].map(|c| c.as_primitive::<Float64Type>().clone());
        for i in 0..b.num_rows() {
            if status.value(i) != Status::Ok.as_str() {
                continue;
            }
            let pose = (!x.is_null(i)).then(|| Pose {
                x: x.value(i),
                y: y.value(i),
                z: z.value(i),
                yaw: yaw.value(i),
            });
            out.push((ids.value(i).to_string(), (!utime.is_null(i)).then(|| utime.value(i)), pose));
        }
    }
    Ok(out)
}

/// Streams the diagrams of a `diagrams` file, one scan at a time, in file order.
pub fn diagrams(path: &Path) -> Result<impl Iterator<Item = Result<(String, Diagram)>> + use<>> {
    let mut batches = open(path)?;
    let mut current: Option<(String, Vec<Pair>)> = None;
    let mut buffered: std::collections::VecDeque<(String, Diagram)> = Default::default();
    let mut done = false;
    Ok(std::iter::from_fn(move || {
        loop {
            if let Some(d) = buffered.pop_front() {
                return Some(Ok(d));
            }
            if done {
                return None;
            }
            match batches.next() {
                None => {
                    done = true;
                    if let Some((id, pairs)) = current.take() {
                        return Some(Ok((id, Diagram::new(pairs))));
                    }
                }
                Some(Err(e)) => {
                    done = true;
                    return Some(Err(e.into()));
                }
                Some(Ok(b)) => {
                    let ids = b.column(0).as_string::<i32>();
                    let dims = b.column(1).as_primitive::<UInt8Type>();
                    let births = b.column(2).as_primitive::<Float64Type>();
                    let deaths = b.column(3).as_primitive::<Float64Type>();
                    for i in 0..b.num_rows() {
                        let id = ids.value(i);
                        if current.as_ref().is_none_or(|c| c.0 != id) {
                            if let Some((id, pairs)) = current.take() {
                                buffered.push_back((id, Diagram::new(pairs)));
                            }
                            current = Some((id.to_string(), Vec::new()));
                        }
                        let pair =
                            Pair { dim: dims.value(i), birth: births.value(i), death: deaths.value(i) };
                        current.as_mut().expect("set above").1.push(pair);
                    }
                }
            }
        }
    }))
}

/// Decodes a `session=<name>` partition folder name.
pub fn session_of(partition: &str) -> Option<String> {
    let enc = partition.strip_prefix("session=")?;
    let bytes = enc.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' && i + 2 < bytes.len() {
            let hex = std::str::from_utf8(&bytes[i + 1..i + 3]).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// The part files of `table` in an index, with their sessions, sorted by (session, part).
pub fn table_files(root: &Path, table: &str) -> Result<Vec<(String, PathBuf)>> {
    let dir = root.join(table);
    let mut out = Vec::new();
    for e in std::fs::read_dir(&dir)
        .with_context(|| format!("{}: not an index (no {table}/)", root.display()))?
        .flatten()
    {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(session) = session_of(&name) else { continue };
        for f in std::fs::read_dir(e.path())?.flatten() {
            let p = f.path();
            if p.extension().is_some_and(|x| x == "parquet") {
                out.push((session.clone(), p));
            }
        }
    }
    out.sort_by(|a, b| {
        let part = |p: &Path| {
            p.file_stem()
                .and_then(|s| s.to_str())
                .and_then(|s| s.strip_prefix("part-"))
                .and_then(|n| n.parse::<u64>().ok())
        };
        a.0.cmp(&b.0).then(part(&a.1).cmp(&part(&b.1)))
    });
    Ok(out)
}

/// One row of `descriptors`, with its session.
#[derive(Clone, Debug, PartialEq)]
pub struct IndexedScan {
    /// Scan id.
    pub scan_id: String,
    /// Session.
    pub session: String,
    /// Timestamp (µs).
    pub utime: Option<i64>,
    /// Position, when known.
    pub pose: Option<[f64; 3]>,
    /// The descriptor.
    pub descriptor: Vec<f32>,
    /// Codebook id.
    pub codebook_id: String,
}

/// Reads the descriptors of an index (only `sessions`, when not empty), in (session, part,
/// row) order.
pub fn read_descriptors(root: &Path, sessions: &[String]) -> Result<Vec<IndexedScan>> {
    use arrow::array::Float32Array;
    let mut out = Vec::new();
    for (session, path) in table_files(root, "descriptors")? {
        if !sessions.is_empty() && !sessions.contains(&session) {
            continue;
        }
        for batch in open(&path)? {
            let b = batch?;
            let col = |name: &str| {
                b.column_by_name(name)
                    .cloned()
                    .with_context(|| format!("{}: no column {name}", path.display()))
            };
            let ids = col("scan_id")?;
            let ids = ids.as_string::<i32>();
            let utime = col("utime")?;
            let utime = utime.as_primitive::<Int64Type>();
            let [x, y, z] = [col("pose_x")?, col("pose_y")?, col("pose_z")?];
            let [x, y, z] = [&x, &y, &z].map(|c| c.as_primitive::<Float64Type>().clone());
            let vec = col("descriptor")?;
            let vec = vec.as_fixed_size_list();
            let cb = col("codebook_id")?;
            let cb = cb.as_string::<i32>();
            for i in 0..b.num_rows() {
                let v = vec.value(i);
                let v = v.as_any().downcast_ref::<Float32Array>().context("descriptor items are float32")?;
                out.push(IndexedScan {
                    scan_id: ids.value(i).to_string(),
                    session: session.clone(),
                    utime: (!utime.is_null(i)).then(|| utime.value(i)),
                    pose: (!x.is_null(i)).then(|| [x.value(i), y.value(i), z.value(i)]),
                    descriptor: v.values().to_vec(),
                    codebook_id: cb.value(i).to_string(),
                });
            }
        }
    }
    Ok(out)
}

/// The diagram of one scan (searching every diagrams file of the index).
pub fn diagram_of(root: &Path, scan_id: &str) -> Result<Option<Diagram>> {
    for (_, path) in table_files(root, "diagrams")? {
        for d in diagrams(&path)? {
            let (id, diagram) = d?;
            if id == scan_id {
                return Ok(Some(diagram));
            }
        }
    }
    Ok(None)
}
