//! Named fault points for crash tests, compiled in only with the `fault-injection` feature (the
//! test suite enables it; a plain `cargo build --release` leaves it out, and then every call
//! here is an empty inline function).
//!
//! * `TOPOREC_FAULT=<point>` (or `<point>@<n>`: its n-th passage, from 1) kills the process with
//!   SIGKILL at that point — no destructor runs, as after `kill -9` or a power loss — after one
//!   line on stderr, `fault injection: killed at <point>`, so a test knows the point was reached.
//! * `TOPOREC_CELL_LIMIT=<n>` lowers the engine's cell limit (2^30) to `n`, so that a small
//!   cloud shows what a cloud past the limit gets.
//! * `TOPOREC_COMMIT_PAUSE_MS=<ms>` sleeps that long inside each commit, between placing the
//!   files and writing the manifest: a window for tests that race a second process against a
//!   commit.
//!
//! The points, in the order a commit passes them: `after-staging` (the chunk's files complete
//! in `.staging/`, no manifest yet), `after-manifest` (the new manifest written, no file renamed
//! into place), `mid-renames` (one file renamed, the others not); and `full-mid` (a `run --full`
//! after its first chunk, the old index still the committed one), `compact-mid` (the merged
//! files staged, the commit not begun) and `revectorize-mid` (the new codebook fitted, its
//! descriptors not yet made).

/// Passes the fault point `name` (see the module doc).
#[inline]
pub(crate) fn point(name: &str) {
    #[cfg(feature = "fault-injection")]
    enabled::point(name);
    #[cfg(not(feature = "fault-injection"))]
    let _ = name;
}

/// Sleeps for `TOPOREC_COMMIT_PAUSE_MS`, when set (see the module doc).
#[inline]
pub(crate) fn commit_pause() {
    #[cfg(feature = "fault-injection")]
    enabled::commit_pause();
}

/// The most cells a Delaunay triangulation may hold: `limit`, or `TOPOREC_CELL_LIMIT` when
/// set (tests reach the limit with small clouds).
#[inline]
pub(crate) fn cell_limit(limit: usize) -> usize {
    #[cfg(feature = "fault-injection")]
    if let Some(v) = std::env::var("TOPOREC_CELL_LIMIT").ok().and_then(|v| v.parse().ok()) {
        return v;
    }
    limit
}

/// Whether this build has the fault points (`toporec --version` says so too).
pub(crate) const ENABLED: bool = cfg!(feature = "fault-injection");

#[cfg(feature = "fault-injection")]
mod enabled {
    use std::io::Write;
    use std::sync::atomic::{AtomicU64, Ordering};

    static PASSED: AtomicU64 = AtomicU64::new(0);

    pub(crate) fn point(name: &str) {
        let Ok(wanted) = std::env::var("TOPOREC_FAULT") else { return };
        let (point, nth) = match wanted.split_once('@') {
            Some((p, n)) => (p.to_string(), n.parse().unwrap_or(1)),
            None => (wanted, 1),
        };
        if point != name {
            return;
        }
        if PASSED.fetch_add(1, Ordering::SeqCst) + 1 < nth {
            return;
        }
        let _ = writeln!(std::io::stderr(), "fault injection: killed at {name}");
        // SAFETY: kill(2) on our own pid with a valid signal number; it does not return.
        unsafe {
            libc::kill(libc::getpid(), libc::SIGKILL);
        }
    }

    pub(crate) fn commit_pause() {
        if let Some(ms) = std::env::var("TOPOREC_COMMIT_PAUSE_MS").ok().and_then(|v| v.parse().ok()) {
            std::thread::sleep(std::time::Duration::from_millis(ms));
        }
    }
}
