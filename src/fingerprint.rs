//! Content fingerprints (xxh3-64): a scan's identity is the hash of its raw bytes, and every
//! random choice made for it (the subsample, RANSAC) is seeded from that hash — so one scan
//! gets one descriptor however it is reached (a session folder, a lone file, an MCAP message,
//! `run` or `query`). Settings get a fingerprint too, so an index knows what made its diagrams.

use std::hash::Hasher;
use twox_hash::XxHash3_64;

/// The xxh3-64 of `bytes`.
pub fn of_bytes(bytes: &[u8]) -> u64 {
    XxHash3_64::oneshot(bytes)
}

/// A fingerprint as stored in tables and manifests: 16 lowercase hex digits.
pub fn hex(fingerprint: u64) -> String {
    format!("{fingerprint:016x}")
}

/// An xxh3-64 computed over bytes that arrive in pieces (a scan cut from a packet stream).
#[derive(Default)]
pub(crate) struct Streaming(XxHash3_64);

impl Streaming {
    /// Adds bytes.
    pub(crate) fn write(&mut self, bytes: &[u8]) {
        self.0.write(bytes);
    }

    /// The fingerprint of everything written since the last reset, and a reset.
    pub(crate) fn take(&mut self) -> u64 {
        let h = self.0.finish();
        self.0 = XxHash3_64::default();
        h
    }
}

impl std::fmt::Debug for Streaming {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Streaming")
    }
}
