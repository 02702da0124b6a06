//! KITTI Velodyne `.bin` scans: little-endian float32 records `x, y, z, reflectance`
//! (x forward, y left, z up, metres).

use super::SourceError;
use crate::homology::Point;
use std::path::Path;

/// Bytes per KITTI record.
pub const RECORD: usize = 16;

/// A decoded KITTI scan.
#[derive(Debug, Default)]
pub struct KittiScan {
    /// Points in metres.
    pub points: Vec<Point>,
    /// Reflectance per point.
    pub reflectance: Vec<f32>,
}

/// Decodes a KITTI `.bin` buffer.
pub fn decode(bytes: &[u8], path: &Path) -> Result<KittiScan, SourceError> {
    if bytes.len() % RECORD != 0 {
        return Err(SourceError::Truncated { path: path.to_owned(), len: bytes.len(), record: RECORD });
    }
    let n = bytes.len() / RECORD;
    let mut scan = KittiScan { points: Vec::with_capacity(n), reflectance: Vec::with_capacity(n) };
    for r in bytes.chunks_exact(RECORD) {
        let f = |o: usize| f32::from_le_bytes([r[o], r[o + 1], r[o + 2], r[o + 3]]);
        scan.points.push([f(0) as f64, f(4) as f64, f(8) as f64]);
        scan.reflectance.push(f(12));
    }
    Ok(scan)
}
