//! `toporec inspect PATH`: what a file or folder holds, read the way a run would read it.

use crate::sources::kitti::KittiSpec;
use crate::sources::mcap::McapSpec;
use crate::sources::mcap_reader::{McapMessages, is_point_cloud};
use crate::sources::nclt::{NcltReader, NcltSpec, is_session};
use crate::sources::pointcloud2::{self, Encoding};
use crate::sources::{CloudFormat, Scan, ScanStream, SourceError, SourceSpec, read_cloud};
use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::{Path, PathBuf};

/// What a path is.
pub fn detect(path: &Path) -> Result<&'static str, SourceError> {
    if path.is_dir() {
        if is_session(path) {
            return Ok("nclt session");
        }
        if path.join("velodyne").is_dir() {
            return Ok("kitti sequence");
        }
        let children: Vec<_> = std::fs::read_dir(path)
            .map_err(|source| SourceError::Io { path: path.to_owned(), source })?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .collect();
        if children.iter().any(|c| is_session(c)) {
            return Ok("nclt sessions");
        }
        if children.iter().any(|c| c.join("velodyne").is_dir()) {
            return Ok("kitti sequences");
        }
        return Err(SourceError::invalid(path, "no NCLT session or KITTI sequence here"));
    }
    if is_mcap(path) {
        return Ok("mcap");
    }
    if path.file_name().is_some_and(|n| n == "velodyne_hits.bin") {
        return Ok("nclt velodyne_hits");
    }
    match CloudFormat::detect(path) {
        Some(CloudFormat::Csv) => Ok("csv cloud"),
        Some(CloudFormat::Kitti) => Ok("kitti scan"),
        Some(CloudFormat::Nclt) => Ok("nclt velodyne_sync scan"),
        None => Err(SourceError::UnknownFormat { path: path.to_owned() }),
    }
}

/// Whether the file starts with the MCAP magic.
pub fn is_mcap(path: &Path) -> bool {
    let mut magic = [0u8; 8];
    std::fs::File::open(path).and_then(|mut f| std::io::Read::read_exact(&mut f, &mut magic)).is_ok()
        && magic == ::mcap::MAGIC
}

/// The source a path of kind `kind` (from [`detect`]) stands for; None for a single cloud
/// file. `topic` picks the MCAP topic.
pub fn source_spec(path: &Path, kind: &str, topic: Option<&str>) -> Result<Option<SourceSpec>, SourceError> {
    Ok(Some(match kind {
        "mcap" => SourceSpec::Mcap(McapSpec { topic: topic.map(String::from), ..McapSpec::file(path) }),
        "nclt session" | "nclt sessions" => SourceSpec::Nclt(NcltSpec::sessions(vec![path.to_owned()])),
        "nclt velodyne_hits" => {
            let dir = path.parent().unwrap_or(Path::new(".")).to_owned();
            SourceSpec::Nclt(NcltSpec { reader: NcltReader::Hits, ..NcltSpec::sessions(vec![dir]) })
        }
        "kitti sequence" => SourceSpec::Kitti(KittiSpec { sequences: vec![path.to_owned()] }),
        "kitti sequences" => {
            let entries = std::fs::read_dir(path)
                .map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
            let mut sequences: Vec<PathBuf> =
                entries.flatten().map(|e| e.path()).filter(|p| p.join("velodyne").is_dir()).collect();
            sequences.sort();
            SourceSpec::Kitti(KittiSpec { sequences })
        }
        _ => return Ok(None),
    }))
}

/// The report, as text.
pub fn inspect(path: &Path) -> anyhow::Result<String> {
    let kind = detect(path)?;
    let mut out = format!("path: {}\nformat: {kind}\n", path.display());
    match source_spec(path, kind, None)? {
        Some(SourceSpec::Mcap(_)) => mcap_report(path, &mut out)?,
        Some(spec) => {
            match &spec {
                SourceSpec::Nclt(n) if n.reader == NcltReader::Sync => {
                    writeln!(out, "sessions: {}", n.session_dirs()?.len())?
                }
                SourceSpec::Kitti(k) => writeln!(out, "sequences: {}", k.sequences.len())?,
                _ => {}
            }
            scans_report(spec.open()?, &mut out)?;
        }
        None => {
            let points = read_cloud(path, None)?;
            writeln!(out, "points: {}", points.len())?;
            writeln!(out, "range: max {:.2} m", max_range(&points))?;
        }
    }
    Ok(out)
}

fn max_range(points: &[[f64; 3]]) -> f64 {
    points.iter().map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()).fold(0.0, f64::max)
}

fn stats(counts: &mut [usize]) -> String {
    if counts.is_empty() {
        return "-".into();
    }
    counts.sort_unstable();
    format!("min {} / median {} / max {}", counts[0], counts[counts.len() / 2], counts[counts.len() - 1])
}

fn time_span(first: Option<i64>, last: Option<i64>) -> String {
    match (first, last) {
        (Some(a), Some(b)) => format!("{a} .. {b} µs ({:.3} s)", (b - a) as f64 / 1e6),
        _ => "-".into(),
    }
}

fn scans_report(stream: ScanStream, out: &mut String) -> anyhow::Result<()> {
    let mut sessions: BTreeMap<String, usize> = BTreeMap::new();
    let (mut kept, mut raw, mut errors) = (Vec::new(), Vec::new(), Vec::new());
    let (mut first, mut last, mut posed) = (None::<i64>, None::<i64>, 0);
    let mut max_r = 0.0f64;
    let mut rings = (u16::MAX, 0u16);
    for item in stream {
        match item {
            Ok(Scan { session, points, raw_points, utime, pose, ring, .. }) => {
                *sessions.entry(session).or_default() += 1;
                kept.push(points.len());
                raw.push(raw_points);
                first = Some(first.map_or(utime, |f| f.min(utime)));
                last = Some(last.map_or(utime, |l| l.max(utime)));
                posed += pose.is_some() as usize;
                max_r = max_r.max(max_range(&points));
                if let Some(r) = ring {
                    rings = r.iter().fold(rings, |(lo, hi), &x| (lo.min(x), hi.max(x)));
                }
            }
            Err(f) => errors.push(f.error),
        }
    }
    let n = kept.len();
    for (s, c) in &sessions {
        writeln!(out, "session {s}: {c} scans")?;
    }
    writeln!(out, "scans: {n} ok, {} failed", errors.len())?;
    writeln!(out, "points per scan: {}", stats(&mut kept))?;
    writeln!(out, "raw points per scan: {}", stats(&mut raw))?;
    if rings.0 <= rings.1 {
        writeln!(out, "ring ids: {}..{}", rings.0, rings.1)?;
    }
    writeln!(out, "max range: {max_r:.2} m")?;
    writeln!(out, "time span: {}", time_span(first, last))?;
    writeln!(out, "poses joined: {posed} of {n}")?;
    for e in errors.iter().take(20) {
        writeln!(out, "error: {e}")?;
    }
    Ok(())
}

fn mcap_report(path: &Path, out: &mut String) -> anyhow::Result<()> {
    #[derive(Default)]
    struct Topic {
        schema: String,
        encoding: String,
        messages: usize,
        kept: Vec<usize>,
        raw: Vec<usize>,
        first: Option<i64>,
        last: Option<i64>,
        bad: usize,
    }
    let summary = crate::sources::mcap_reader::summary_channels(path).is_some();
    let mut topics: BTreeMap<String, Topic> = BTreeMap::new();
    let mut faults = Vec::new();
    let mut messages = McapMessages::open(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    for m in messages.by_ref() {
        let m = match m {
            Ok(m) => m,
            Err(f) => {
                faults.push(format!("{}: {}", f.location, f.message));
                continue;
            }
        };
        let t = topics.entry(m.channel.topic.clone()).or_default();
        t.schema = m.channel.schema_name.clone();
        t.encoding = m.channel.message_encoding.clone();
        t.messages += 1;
        let utime = (m.log_time / 1000) as i64;
        t.first = Some(t.first.map_or(utime, |f| f.min(utime)));
        t.last = Some(t.last.map_or(utime, |l| l.max(utime)));
        if is_point_cloud(&m.channel) {
            let encoding = Encoding::of_channel(&m.channel.message_encoding);
            match pointcloud2::parse(&m.data, encoding).and_then(|c| c.decode()) {
                Ok(c) => {
                    t.kept.push(c.points.len());
                    t.raw.push(c.raw_points);
                }
                Err(_) => t.bad += 1,
            }
        }
    }
    writeln!(out, "summary section: {}", if summary { "yes" } else { "no" })?;
    writeln!(out, "topics: {}", topics.len())?;
    for (name, t) in &mut topics {
        writeln!(out, "  {name}  [{} / {}]  {} messages", t.schema, t.encoding, t.messages)?;
        if !t.raw.is_empty() || t.bad > 0 {
            writeln!(out, "    point clouds: {} ok, {} undecodable", t.kept.len(), t.bad)?;
            writeln!(out, "    points per scan (kept): {}", stats(&mut t.kept))?;
            writeln!(out, "    raw points per scan: {}", stats(&mut t.raw))?;
            writeln!(out, "    time span (log time): {}", time_span(t.first, t.last))?;
        }
    }
    writeln!(out, "poses joined: no (give `poses` in a pipeline file)")?;
    writeln!(out, "corrupt records: {}", faults.len())?;
    for f in faults.iter().take(20) {
        writeln!(out, "error: {}: {f}", path.display())?;
    }
    Ok(())
}
