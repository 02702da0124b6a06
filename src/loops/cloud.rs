//! `toporec loops --cloud FILE.ply`: the scans placed at the map's corrected poses (or, with
//! `--no-optimize`, at their stored ones) in one point cloud, for a point-cloud viewer.
//!
//! Each scan is read again from where the index found it ([`crate::sources::reread`], one at a
//! time), moved into the map's frame, and pooled into a world grid of `--cloud-voxel` cells; a
//! cell's point is the mean of the points in it. The sums are kept in whole micrometres, so the
//! cloud is the same whatever order the scans arrive in (and on any number of threads). Written
//! as a binary little-endian PLY (`x`, `y`, `z` as float32, metres), atomically.

use super::map::Vertex;
use crate::error::{Result, ResultExt};
use crate::sinks::index::reader::ScanRecord;
use nalgebra::{Isometry3, Point3};
use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

/// What a cloud holds.
#[derive(Clone, Debug, PartialEq)]
pub struct Written {
    /// The file.
    pub path: std::path::PathBuf,
    /// Its points (one per occupied cell).
    pub points: usize,
    /// The scans placed in it.
    pub scans: usize,
    /// The scans with a pose that could not be read again: how many, and the first one's reason.
    pub unread: (usize, Option<String>),
}

/// Writes the scans of `walk` that have a pose in `poses` (by walking position) into `path`,
/// each found again by its `scans` row in `stored` (by session and scan id).
pub(super) fn write(
    index: &Path,
    walk: &[Vertex],
    poses: &[Option<Isometry3<f64>>],
    stored: &HashMap<(String, String), ScanRecord>,
    path: &Path,
    voxel: f64,
) -> Result<Written> {
    let placed: HashMap<&str, Isometry3<f64>> =
        walk.iter().zip(poses).filter_map(|(v, p)| Some((v.scan_id.as_str(), (*p)?))).collect();
    let places: Vec<_> = walk
        .iter()
        .zip(poses)
        .filter(|(_, p)| p.is_some())
        .filter_map(|(v, _)| stored.get(&(v.session.clone(), v.scan_id.clone())))
        .map(|r| r.place())
        .collect();
    let sources = crate::pipeline::config::Pipeline::of_index(index).map(|p| p.sources).unwrap_or_default();
    let rereader = crate::sources::reread::Rereader::new(&sources).points_only();
    // A cell's coordinate sums (µm) and point count.
    let mut cells: HashMap<[i64; 3], ([i64; 3], u32)> = HashMap::new();
    let (mut scans, mut first_unread) = (0usize, None);
    for (id, scan) in rereader.stream(&places) {
        let Some(pose) = placed.get(id.as_str()) else { continue };
        let scan = match scan {
            Ok(scan) => scan,
            Err(f) => {
                first_unread.get_or_insert(format!("{id}: {}", f.error));
                continue;
            }
        };
        scans += 1;
        for q in &scan.points {
            let w = pose * Point3::from(*q);
            let key = [w.x, w.y, w.z].map(|c| (c / voxel).floor() as i64);
            let e = cells.entry(key).or_insert(([0; 3], 0));
            for (s, c) in e.0.iter_mut().zip([w.x, w.y, w.z]) {
                *s += (c * 1e6).round() as i64;
            }
            e.1 += 1;
        }
    }
    // Every scan with a pose not placed: unreadable, or no longer where the index found it.
    let unread = (placed.len() - scans, first_unread);
    let mut keys: Vec<&[i64; 3]> = cells.keys().collect();
    keys.sort_unstable();
    let mut bytes = format!(
        "ply\nformat binary_little_endian 1.0\ncomment toporec loops: the scans at the map's poses, {voxel} m cells\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
        keys.len()
    )
    .into_bytes();
    bytes.reserve(keys.len() * 12);
    for k in &keys {
        let (sums, n) = cells[*k];
        for s in sums {
            bytes.extend_from_slice(&((s as f64 / 1e6 / n as f64) as f32).to_le_bytes());
        }
    }
    let mut file = crate::fsutil::AtomicFile::create(path)?;
    file.write_all(&bytes).at(path)?;
    file.commit()?;
    Ok(Written { path: path.to_path_buf(), points: keys.len(), scans, unread })
}
