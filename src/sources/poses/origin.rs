//! What a run records of where its scans' poses came from.

use super::PoseTable;
use std::path::Path;

/// How a KITTI sequence's scans take their poses, as its origin says it.
const KITTI_JOIN: &str = "by frame";

/// Where the poses of some sessions come from: a pose file, or a log's own messages. A run
/// records one per file or log in the manifest (`info` shows them), with the fingerprint of
/// the poses its rows carry.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PoseOrigin {
    /// The sessions whose scans take them.
    pub sessions: Vec<String>,
    /// Where they come from, in words (the file and its layout, or the log's topic or chain),
    /// with the join's tolerance.
    pub origin: String,
    /// The pose file, when they come from one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<std::path::PathBuf>,
    /// xxh3-64 of the pose file's bytes (and of its times file's), 16 hex digits.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file_xxh3: Option<String>,
    /// Whether the poses are in a frame of their own sessions alone, not shared with other pose
    /// files (a KITTI sequence's `poses.txt`, relative to its own first frame). A log's own
    /// poses (no `file`) always are.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub own_frame: bool,
    /// Scans of those sessions in the index, after the run.
    #[serde(default)]
    pub scans: u64,
    /// Of those, scans with a pose.
    #[serde(default)]
    pub with_pose: u64,
    /// xxh3-64 of every scan's id, time and pose in those sessions, in id order: equal for two
    /// indexes exactly when their rows carry the same poses.
    #[serde(default)]
    pub poses_xxh3: String,
    /// The pose file's time span (µs), for the message when it joins no scan.
    #[serde(skip)]
    pub span_us: Option<(i64, i64)>,
    /// Lines of the pose file that could not be read, and the first one's message.
    #[serde(skip)]
    pub bad_lines: (usize, Option<String>),
}

impl PoseOrigin {
    /// The origin of a pose file's poses (`times`: a KITTI file's times), read now for its
    /// fingerprint, its span and its bad lines; `joined` says how scans take them.
    pub fn of_file(
        sessions: Vec<String>,
        file: &Path,
        times: Option<&Path>,
        table: &PoseTable,
        joined: &str,
    ) -> Self {
        let mut hash = crate::fingerprint::Streaming::default();
        for p in std::iter::once(file).chain(times) {
            if let Ok(bytes) = std::fs::read(p) {
                hash.write(&bytes);
            }
        }
        let times_said = times.map(|t| format!(", times {}", t.display())).unwrap_or_default();
        PoseOrigin {
            sessions,
            origin: format!("{}{times_said} ({joined})", file.display()),
            file: Some(file.to_owned()),
            file_xxh3: Some(crate::fingerprint::hex(hash.take())),
            span_us: table.rows.first().map(|f| f.0).zip(table.rows.last().map(|l| l.0)),
            bad_lines: (table.bad_lines.len(), table.bad_lines.first().cloned()),
            ..Default::default()
        }
    }

    /// What a manifest records of it (the counts and fingerprints, not what reading the file
    /// found on the way).
    pub fn recorded(&self) -> Self {
        PoseOrigin { span_us: None, bad_lines: (0, None), ..self.clone() }
    }

    /// The origin of poses read from a source's own data (a log's messages, a dataset's
    /// side files).
    pub fn of_source(sessions: Vec<String>, origin: String) -> Self {
        PoseOrigin { sessions, origin, ..Default::default() }
    }

    /// The origin of a KITTI sequence's `poses.txt` (`times`: its `times.txt`): by frame, in a
    /// frame of its own, since KITTI's poses are relative to each sequence's first frame.
    pub fn of_kitti_sequence(session: String, file: &Path, times: Option<&Path>) -> Self {
        let table = PoseTable::default();
        PoseOrigin { own_frame: true, ..Self::of_file(vec![session], file, times, &table, KITTI_JOIN) }
    }

    /// Whether these poses are in a frame of their own: a log's own, or a KITTI sequence's. An
    /// index recorded before `own_frame` was says the latter only by its origin's "(by frame)".
    pub fn in_own_frame(&self) -> bool {
        let kitti_words = self
            .origin
            .strip_suffix(')')
            .and_then(|o| o.strip_suffix(KITTI_JOIN))
            .is_some_and(|o| o.ends_with('('));
        self.file.is_none() || self.own_frame || kitti_words
    }

    /// The warning for the pose file's unreadable lines, once: how many, and the first.
    pub fn bad_lines_warning(&self) -> Option<String> {
        let (n, first) = &self.bad_lines;
        let file = self.file.as_deref()?;
        (*n > 0).then(|| {
            format!(
                "{}: {n} line{} could not be read as poses and {} left out (first: {})",
                file.display(),
                if *n == 1 { "" } else { "s" },
                if *n == 1 { "was" } else { "were" },
                first.as_deref().unwrap_or_default()
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::PoseOrigin;

    #[test]
    fn a_kitti_sequences_poses_are_a_frame_of_their_own_however_recorded() {
        let file = Some(std::path::PathBuf::from("00/poses.txt"));
        let kitti = |own_frame| PoseOrigin {
            origin: "00/poses.txt, times 00/times.txt (by frame)".into(),
            file: file.clone(),
            own_frame,
            ..PoseOrigin::default()
        };
        assert!(kitti(true).in_own_frame() && kitti(false).in_own_frame());
        let tum = PoseOrigin {
            origin: "poses.tum (TUM, nearest time within 100 ms)".into(),
            file: file.clone(),
            ..PoseOrigin::default()
        };
        assert!(!tum.in_own_frame(), "a pose file shares its frame");
        assert!(PoseOrigin { file: None, ..tum }.in_own_frame(), "a log's own poses");
    }
}
