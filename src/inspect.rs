//! `toporec inspect PATH`: what a file or folder holds, read the way a run would read it.

use crate::error::Result;
use crate::sources::logs::LogKind;
use crate::sources::mcap_reader::is_point_cloud;
use crate::sources::pointcloud2::{self, Encoding};
use crate::sources::{Input, Scan, ScanStream, read_cloud};
use std::collections::BTreeMap;
use std::path::Path;

/// Appends one formatted line to a report (a `String`, which cannot fail to grow).
macro_rules! line {
    ($out:expr, $($arg:tt)*) => {{
        $out.push_str(&format!($($arg)*));
        $out.push('\n');
    }};
}

/// The report, as text.
pub fn inspect(path: &Path) -> Result<String> {
    let input = Input::detect(path)?;
    let mut out = format!("path: {}\nformat: {}\n", path.display(), input.name());
    if let Some(log) = LogKind::detect(path).filter(|_| matches!(input, Input::Source(_))) {
        log_report(path, log, &mut out)?;
        return Ok(out);
    }
    match input.source(None) {
        Some(spec) => {
            for l in spec.overview()? {
                line!(out, "{l}");
            }
            scans_report(spec.open()?, &mut out);
        }
        None => {
            let points = read_cloud(path, None)?;
            line!(out, "points: {}", points.len());
            line!(out, "range: max {:.2} m", max_range(&points));
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

fn scans_report(stream: ScanStream, out: &mut String) {
    let mut sessions: BTreeMap<String, usize> = BTreeMap::new();
    let (mut kept, mut raw, mut errors) = (Vec::new(), Vec::new(), Vec::new());
    let (mut first, mut last, mut posed) = (None::<i64>, None::<i64>, 0);
    let mut no_pose: BTreeMap<String, usize> = BTreeMap::new();
    let mut max_r = 0.0f64;
    let mut rings = (u16::MAX, 0u16);
    for item in stream {
        match item {
            Ok(Scan { session, points, raw_points, utime, pose, ring, no_pose: why, .. }) => {
                if let Some(why) = why {
                    *no_pose.entry(why.to_string()).or_default() += 1;
                }
                *sessions.entry(session).or_default() += 1;
                kept.push(points.len());
                raw.push(raw_points);
                if let Some(utime) = utime {
                    first = Some(first.map_or(utime, |f: i64| f.min(utime)));
                    last = Some(last.map_or(utime, |l: i64| l.max(utime)));
                }
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
        line!(out, "session {s}: {c} scans");
    }
    line!(out, "scans: {n} ok, {} failed", errors.len());
    line!(out, "points per scan: {}", stats(&mut kept));
    line!(out, "raw points per scan: {}", stats(&mut raw));
    if rings.0 <= rings.1 {
        line!(out, "ring ids: {}..{}", rings.0, rings.1);
    }
    line!(out, "max range: {max_r:.2} m");
    line!(out, "time span: {}", time_span(first, last));
    line!(out, "poses joined: {posed} of {n}");
    for (why, count) in &no_pose {
        line!(out, "  without a pose ({why}): {count}");
    }
    for e in errors.iter().take(20) {
        line!(out, "error: {e}");
    }
}

/// The topics of a message log (MCAP, ROS 1 bag, rosbag2), each with its messages and, for
/// point clouds, what decoding them gives.
fn log_report(path: &Path, log: LogKind, out: &mut String) -> Result<()> {
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
    let index = match log {
        LogKind::Mcap => {
            let summary = crate::sources::mcap_reader::summary_channels(path).is_some();
            format!("summary section: {}", if summary { "yes" } else { "no" })
        }
        LogKind::Ros1Bag => {
            let indexed = crate::sources::ros1bag::indexed_counts(path).is_some();
            format!("index: {}", if indexed { "yes" } else { "no (read record by record)" })
        }
        LogKind::Rosbag2 => match crate::sources::rosbag2::Metadata::read(path) {
            Ok(m) => {
                format!("storage: {}, {} file(s), compression: {:?}", m.storage, m.files.len(), m.compression)
            }
            Err(e) => return Err(crate::sources::SourceError::invalid(path, e).into()),
        },
        LogKind::Sqlite3 => "storage: sqlite3".to_string(),
    };
    let mut topics: BTreeMap<String, Topic> = BTreeMap::new();
    let mut faults = Vec::new();
    for m in log.messages(path)? {
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
    line!(out, "{index}");
    line!(out, "topics: {}", topics.len());
    for (name, t) in &mut topics {
        line!(out, "  {name}  [{} / {}]  {} messages", t.schema, t.encoding, t.messages);
        if !t.raw.is_empty() || t.bad > 0 {
            line!(out, "    point clouds: {} ok, {} undecodable", t.kept.len(), t.bad);
            line!(out, "    points per scan (kept): {}", stats(&mut t.kept));
            line!(out, "    raw points per scan: {}", stats(&mut t.raw));
            line!(out, "    time span (log time): {}", time_span(t.first, t.last));
        }
    }
    log_poses(path, out);
    line!(out, "scan time: the header stamp, else the log time");
    line!(out, "corrupt records: {}", faults.len());
    for f in faults.iter().take(20) {
        line!(out, "error: {}: {f}", path.display());
    }
    Ok(())
}

/// Where a log's scans would take their poses: the candidates (the transform chain from the
/// cloud's frame, the pose topics) and the one used without flags, or why none can be chosen.
fn log_poses(path: &Path, out: &mut String) {
    let kind = match crate::sources::logs::LogKind::detect(path) {
        Some(k) => k,
        None => return,
    };
    let gathered = (|| -> std::result::Result<_, crate::sources::SourceError> {
        let channels = kind.channels(path)?;
        let clouds: Vec<&str> =
            channels.iter().filter(|c| is_point_cloud(c)).map(|c| c.topic.as_str()).collect();
        let cloud = clouds.first().copied().unwrap_or_default().to_string();
        crate::sources::poses::LogPoses::gather(path, &channels, kind.messages(path)?, &cloud)
    })();
    let gathered = match gathered {
        Ok(g) => g,
        Err(e) => {
            line!(out, "poses: cannot be read: {e}");
            return;
        }
    };
    if let Some(frame) = &gathered.cloud_frame {
        let chain = gathered.tf.chain(frame);
        if chain.len() > 1 {
            let mut down = chain.clone();
            down.reverse();
            line!(out, "pose candidate: /tf chain {}", down.join(" → "));
        }
    }
    for t in gathered.topic_list() {
        line!(out, "pose candidate: {t}");
    }
    match gathered.choose(path, &crate::sources::poses::PoseKeys::default()) {
        Ok(Some(choice)) => line!(
            out,
            "poses joined: from {} (--poses-topic and --pose-frames choose otherwise)",
            choice.describe()
        ),
        Ok(None) => {
            line!(out, "poses joined: none in the log (give --poses FILE: TUM, KITTI or NCLT layout)")
        }
        Err(e) => line!(out, "poses joined: none chosen: {e}"),
    }
}
