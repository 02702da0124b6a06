//! What a run did ([`RunSummary`]): the counts, times and methods `toporec run` prints, and
//! their JSON (`--summary-json`).

use crate::sinks::parquet::Status;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

/// What a run did.
#[derive(Clone, Debug, Default)]
pub struct RunSummary {
    /// The index folder.
    pub index: PathBuf,
    /// Scans the sources yielded (every one, up to date or not).
    pub read: u64,
    /// Of those, ok (indexed).
    pub indexed: u64,
    /// Of those, skipped, by reason.
    pub skipped: BTreeMap<String, u64>,
    /// Of those, failed.
    pub errors: u64,
    /// Every failed scan's error (naming its file and scan), in input order.
    pub failures: Vec<String>,
    /// Scans already in the index from the same bytes and settings: not computed.
    pub up_to_date: u64,
    /// Of those, scans whose time or pose changed (their source's poses did): written anew,
    /// nothing recomputed.
    pub rejoined: u64,
    /// Scans new to the index.
    pub added: u64,
    /// Scans whose bytes changed: recomputed, their old rows replaced.
    pub replaced: u64,
    /// Indexed scans the sources no longer yield, removed (`--prune`).
    pub pruned: u64,
    /// Indexed scans the sources no longer yield, kept (no `--prune`).
    pub not_in_sources: u64,
    /// Indexed scans of inputs that could not be read whole this run: kept, never pruned.
    pub not_read: u64,
    /// Scans the sources yielded twice under one id (the later ones are left out).
    pub duplicates: u64,
    /// Scans read without a pose, by reason.
    pub no_pose: BTreeMap<String, u64>,
    /// Scans that went through preprocessing and persistence.
    pub computed: u64,
    /// Descriptors made from stored diagrams (after a codebook fit, or a resumed run).
    pub descriptors_from_stored: u64,
    /// Commits.
    pub commits: u64,
    /// Wall time.
    pub wall: Duration,
    /// CPU seconds per stage (worker stages summed over threads).
    pub stages: BTreeMap<&'static str, f64>,
    /// Codebook id used.
    pub codebook_id: String,
    /// Descriptor length.
    pub descriptor_len: usize,
    /// The descriptor methods (`toporec` first when computed) with their lengths.
    pub methods: Vec<(String, usize)>,
    /// Worker threads.
    pub threads: usize,
    /// Where the scans' poses came from, with the counts of the index's rows after the run.
    pub poses: Vec<crate::sources::poses::PoseOrigin>,
}

impl RunSummary {
    /// Whether some scans failed.
    pub fn partial(&self) -> bool {
        self.errors > 0
    }

    /// The summary as JSON (`toporec run --summary-json`): counts, wall seconds and CPU
    /// seconds per stage.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "index": self.index,
            "scans": {
                "read": self.read,
                "indexed": self.indexed,
                "skipped": self.skipped,
                "errors": self.errors,
                "up_to_date": self.up_to_date,
                "rejoined": self.rejoined,
                "added": self.added,
                "replaced": self.replaced,
                "pruned": self.pruned,
                "not_in_sources": self.not_in_sources,
                "not_read": self.not_read,
                "duplicates": self.duplicates,
                "without_pose": self.no_pose,
                "computed": self.computed,
                "descriptors_from_stored": self.descriptors_from_stored,
            },
            "poses": self.poses,
            "first_errors": self.failures.iter().take(10).collect::<Vec<_>>(),
            "commits": self.commits,
            "codebook_id": self.codebook_id,
            "descriptor_length": self.descriptor_len,
            "methods": self.methods.iter().map(|(m, len)| serde_json::json!({"method": m, "length": len})).collect::<Vec<_>>(),
            "threads": self.threads,
            "wall_seconds": self.wall.as_secs_f64(),
            "cpu_seconds": self.stages,
        })
    }

    /// Counts one scan by its status.
    pub(super) fn count(&mut self, status: Status, error: Option<&str>) {
        self.read += 1;
        match status {
            Status::Ok => self.indexed += 1,
            Status::Skipped => *self.skipped.entry(skip_reason(error.unwrap_or_default())).or_default() += 1,
            Status::Error => {
                self.errors += 1;
                self.failures.push(error.unwrap_or_default().to_string());
            }
        }
    }
}

/// The reason a scan was skipped, without its numbers (a count per reason).
fn skip_reason(error: &str) -> String {
    if error.contains("after preprocessing") {
        return "too few points after preprocessing".into();
    }
    if error.contains("a raw-scan method needs") {
        return format!(
            "fewer than {} points, too few for a raw-scan method",
            crate::methods::MIN_RAW_POINTS
        );
    }
    "skipped".into()
}

impl std::fmt::Display for RunSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let secs = self.wall.as_secs_f64();
        let skipped: u64 = self.skipped.values().sum();
        // Relative to the working folder when inside it: the path the user typed.
        let cwd = std::env::current_dir().unwrap_or_default();
        writeln!(f, "index: {}", self.index.strip_prefix(&cwd).unwrap_or(&self.index).display())?;
        writeln!(
            f,
            "scans: {} read, {} indexed, {skipped} skipped, {} errors",
            self.read, self.indexed, self.errors
        )?;
        for (reason, n) in &self.skipped {
            writeln!(f, "  skipped ({reason}): {n}")?;
        }
        for e in &self.failures {
            writeln!(f, "  error: {e}")?;
        }
        for o in &self.poses {
            if let Some(w) = o.bad_lines_warning() {
                writeln!(f, "warning: {w}")?;
            }
            writeln!(
                f,
                "poses of {}: {}: {} of {} scans with a pose (poses {})",
                o.sessions.join(", "),
                o.origin,
                o.with_pose,
                o.scans,
                o.poses_xxh3
            )?;
        }
        for (reason, n) in &self.no_pose {
            writeln!(f, "  without a pose ({reason}): {n}")?;
        }
        writeln!(
            f,
            "changes: {} up to date, {} added, {} replaced, {} pruned ({} computed, {} commits)",
            self.up_to_date, self.added, self.replaced, self.pruned, self.computed, self.commits
        )?;
        if self.rejoined > 0 {
            writeln!(
                f,
                "  {} up-to-date scans took new poses (their source's poses changed): rows written anew, nothing recomputed",
                self.rejoined
            )?;
        }
        if self.not_in_sources > 0 {
            writeln!(
                f,
                "  {} indexed scans are not in this run's sources: kept (`--prune` removes them)",
                self.not_in_sources
            )?;
        }
        if self.not_read > 0 {
            writeln!(
                f,
                "  {} indexed scans belong to inputs that could not be read: kept (never pruned)",
                self.not_read
            )?;
        }
        if self.duplicates > 0 {
            writeln!(f, "  {} scans came twice under one id: the later ones were left out", self.duplicates)?;
        }
        let methods: Vec<String> = self
            .methods
            .iter()
            .map(|(m, len)| {
                if m == crate::methods::TOPOREC {
                    format!("{m} (length {len}, codebook {})", self.codebook_id)
                } else {
                    format!("{m} (length {len})")
                }
            })
            .collect();
        writeln!(f, "descriptors: {}", methods.join(", "))?;
        writeln!(f, "wall time: {secs:.2} s, {:.1} scans/s", self.read as f64 / secs.max(1e-9))?;
        let stages: Vec<String> = self.stages.iter().map(|(k, v)| format!("{k} {v:.2} s")).collect();
        write!(f, "cpu time: {}", stages.join(", "))
    }
}
