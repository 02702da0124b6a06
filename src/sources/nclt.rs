//! NCLT Velodyne HDL-32E `velodyne_sync/<utime>.bin` scans (REFERENCE §6.1): little-endian
//! 8-byte records `x: u16, y: u16, z: u16, intensity: u8, laser_id: u8`, metric value
//! `raw · 0.005 − 100` m. Stored with z down; exposed as `(x, −y, −z)` (z up, see
//! [`super`]).

use super::SourceError;
use crate::homology::Point;
use std::path::Path;

/// Bytes per record.
pub const RECORD: usize = 8;
/// Metres per raw unit.
pub const SCALE: f64 = 0.005;
/// Offset in metres.
pub const OFFSET: f64 = -100.0;

/// A decoded NCLT scan.
#[derive(Debug, Default)]
pub struct NcltScan {
    /// Points in metres, z up.
    pub points: Vec<Point>,
    /// Intensity per point.
    pub intensity: Vec<u8>,
    /// Laser id (ring) per point, 0..31.
    pub laser: Vec<u8>,
}

/// Decodes one `velodyne_sync` buffer.
pub fn decode_sync(bytes: &[u8], path: &Path) -> Result<NcltScan, SourceError> {
    if bytes.len() % RECORD != 0 {
        return Err(SourceError::Truncated { path: path.to_owned(), len: bytes.len(), record: RECORD });
    }
    let n = bytes.len() / RECORD;
    let mut scan = NcltScan {
        points: Vec::with_capacity(n),
        intensity: Vec::with_capacity(n),
        laser: Vec::with_capacity(n),
    };
    for r in bytes.chunks_exact(RECORD) {
        let c = |o: usize| u16::from_le_bytes([r[o], r[o + 1]]) as f64 * SCALE + OFFSET;
        scan.points.push([c(0), -c(2), -c(4)]);
        scan.intensity.push(r[6]);
        scan.laser.push(r[7]);
    }
    Ok(scan)
}
