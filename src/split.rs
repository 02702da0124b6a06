//! `toporec split`: one NCLT session as two — every `every`-th scan (from the `first`) a map
//! session, the others a query session — so that one drive measures fine localization: each
//! query is a scan between map scans, and `eval places --db-session map --query-session query`
//! asks whether its top-1 is the nearest map scan.
//!
//! The scans are taken in time order (their file names are their times, µs). Each new session
//! is an NCLT session folder (`<out>/<name>/velodyne_sync/<utime>.bin`) whose files link to the
//! originals (absolute symbolic links; `--copy` copies them), with the drive's ground truth
//! beside it (`<out>/groundtruth_<name>.csv`, the whole file: the NCLT source joins poses by
//! time). Nothing is written over: an output session folder that exists is an error.

use crate::error::{Error, Result, ResultExt};
use crate::ranges;
use std::path::{Path, PathBuf};

/// What `toporec split` is asked.
#[derive(clap::Args, Clone, Debug)]
pub struct SplitArgs {
    /// The NCLT session folder (holding velodyne_sync/).
    pub session: PathBuf,
    /// Every this-many-th scan goes to the map session, the others to the query session: [2, 10⁶].
    #[arg(long, default_value_t = 3, value_parser = |s: &str| ranges::count_within(s, 2, 1_000_000))]
    pub every: usize,
    /// The position of the first map scan, in [0, every).
    #[arg(long, default_value_t = 0)]
    pub first: usize,
    /// The names of the map and the query sessions.
    #[arg(long, value_delimiter = ',', num_args = 2, default_values = ["map", "query"])]
    pub names: Vec<String>,
    /// The drive's ground truth (default: `groundtruth_<session>.csv` found beside the session).
    #[arg(long)]
    pub groundtruth: Option<PathBuf>,
    /// Copy the scan files (default: absolute symbolic links to them).
    #[arg(long)]
    pub copy: bool,
    /// The folder the two sessions are written into.
    #[arg(long, short)]
    pub out: PathBuf,
}

/// What was written.
#[derive(Clone, Debug, PartialEq)]
pub struct SplitReport {
    /// The map session's folder and its scan count.
    pub map: (PathBuf, usize),
    /// The query session's folder and its scan count.
    pub query: (PathBuf, usize),
    /// The ground truth both sessions got.
    pub groundtruth: PathBuf,
}

impl std::fmt::Display for SplitReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "map: {} ({} scans)", self.map.0.display(), self.map.1)?;
        writeln!(f, "query: {} ({} scans)", self.query.0.display(), self.query.1)?;
        write!(f, "ground truth: {}", self.groundtruth.display())
    }
}

/// Splits the session (see the module doc).
pub fn split(a: &SplitArgs) -> Result<SplitReport> {
    if a.every < 2 || a.first >= a.every {
        return Err(Error::invalid(format!(
            "--every {} --first {}: need every ≥ 2 and first in [0, every)",
            a.every, a.first
        )));
    }
    let [map, query] = a.names.as_slice() else {
        return Err(Error::invalid(format!(
            "--names: two names (the map's, the query's), found {:?}",
            a.names
        )));
    };
    if map == query || [map, query].iter().any(|n| n.is_empty() || n.contains(['/', '\\'])) {
        return Err(Error::invalid(format!(
            "session names {:?} and {:?}: two different names, no slashes",
            map, query
        )));
    }
    let scans_dir = a.session.join("velodyne_sync");
    let mut scans: Vec<(u64, PathBuf)> = std::fs::read_dir(&scans_dir)
        .at(&scans_dir)?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "bin"))
        .map(|p| {
            let utime = p.file_stem().and_then(|s| s.to_str()).and_then(|s| s.parse::<u64>().ok());
            utime.map(|t| (t, p.clone())).ok_or_else(|| {
                Error::invalid(format!("{}: not an NCLT scan name (<utime>.bin)", p.display()))
            })
        })
        .collect::<Result<_>>()?;
    if scans.is_empty() {
        return Err(Error::invalid(format!("{}: no scans (<utime>.bin)", scans_dir.display())));
    }
    scans.sort();
    let session = a.session.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let groundtruth = match &a.groundtruth {
        Some(g) => g.clone(),
        None => crate::sources::poses::find_for_session(&a.session, &session).ok_or_else(|| {
            Error::invalid(format!(
                "{}: no groundtruth_{session}.csv beside the session; give --groundtruth",
                a.session.display()
            ))
        })?,
    };
    let truth = std::fs::read(&groundtruth).at(&groundtruth)?;
    let mut counts = [0usize; 2];
    let outs = [map, query].map(|name| a.out.join(name));
    for dir in &outs {
        if dir.exists() {
            return Err(Error::invalid(format!("{}: exists; split into a new folder", dir.display())));
        }
        let sync = dir.join("velodyne_sync");
        std::fs::create_dir_all(&sync).at(&sync)?;
    }
    for (k, (_, path)) in scans.iter().enumerate() {
        let which = usize::from(k % a.every != a.first);
        counts[which] += 1;
        let to = outs[which].join("velodyne_sync").join(path.file_name().expect("a file"));
        place(path, &to, a.copy)?;
    }
    for name in [map, query] {
        let to = a.out.join(format!("groundtruth_{name}.csv"));
        crate::fsutil::write_atomic(&to, &truth)?;
    }
    Ok(SplitReport { map: (outs[0].clone(), counts[0]), query: (outs[1].clone(), counts[1]), groundtruth })
}

/// `to` as a link to `from` (absolute), or a copy of it.
fn place(from: &Path, to: &Path, copy: bool) -> Result<()> {
    if copy {
        return std::fs::copy(from, to).map(drop).at(to);
    }
    let target = std::path::absolute(from).at(from)?;
    #[cfg(unix)]
    return std::os::unix::fs::symlink(&target, to).at(to);
    #[cfg(not(unix))]
    return std::fs::copy(&target, to).map(drop).at(to);
}
