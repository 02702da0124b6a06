//! Which earlier scans a scan may be matched with: the rule the search and the online detector
//! share.

/// Which earlier scans a scan may be matched with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Exclusion {
    /// Same-session scans closer in time than this (seconds) are left out.
    Seconds(f64),
    /// Same-session scans this many positions apart or fewer are left out.
    Scans(usize),
}

/// The rate at which a window of seconds is counted in scans for scans without a time (a
/// folder of clouds named by frame): a LiDAR's usual 10 Hz.
pub(super) const UNTIMED_RATE_HZ: f64 = 10.0;

/// The scans a window of `seconds` spans at [`UNTIMED_RATE_HZ`]: how many neighbours of a scan
/// without a time are left out.
pub(super) fn untimed_window(seconds: f64) -> usize {
    (seconds * UNTIMED_RATE_HZ).ceil() as usize
}

/// Whether an earlier scan (session, position in its session, time) may be matched with a
/// later one: always from another session; from the same session, when farther apart than the
/// exclusion. Scans without a time are kept apart by position instead: the window's seconds
/// counted at [`UNTIMED_RATE_HZ`] ([`untimed_window`]), never by a made-up time.
pub(crate) fn allowed_by(
    exclusion: Exclusion,
    query: (u32, usize, Option<i64>),
    row: (u32, usize, Option<i64>),
) -> bool {
    if query.0 != row.0 {
        return true;
    }
    match exclusion {
        Exclusion::Scans(n) => query.1.abs_diff(row.1) > n,
        Exclusion::Seconds(s) => match (query.2, row.2) {
            (Some(a), Some(b)) => (a - b).unsigned_abs() as f64 >= s * 1e6,
            _ => query.1.abs_diff(row.1) > untimed_window(s),
        },
    }
}

/// The distance between two poses (m).
pub(crate) fn distance3(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}
