//! Sources: decoding point clouds from the files users already have.
//!
//! Owns byte layouts and file formats; knows nothing of topology. Every error names the file
//! and, where it applies, the record or line.
//!
//! Axis convention: clouds are exposed in metres in the sensor frame, right-handed with z up.
//! KITTI already is (x forward, y left, z up); NCLT stores z down (NED-like), so its records
//! are rotated by 180° about x: `(x, y, z) → (x, -y, -z)` (a rotation, so distances — and
//! hence diagrams — are unchanged).

pub mod csv;
pub mod kitti;
pub mod nclt;

use crate::homology::Point;
use std::path::{Path, PathBuf};

/// An error reading a source, naming the file.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file size is not a whole number of records.
    #[error("{path}: truncated: {len} bytes is not a multiple of the {record}-byte record size")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Its length in bytes.
        len: usize,
        /// The record size.
        record: usize,
    },
    /// A text line could not be parsed.
    #[error("{path}:{line}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A point has a NaN or infinite coordinate.
    #[error("{path}: point {index} has a non-finite coordinate")]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// 0-based point index.
        index: usize,
    },
    /// The format could not be determined.
    #[error("{path}: unknown cloud format (expected .csv or .bin; use --format)")]
    UnknownFormat {
        /// The file.
        path: PathBuf,
    },
}

/// A single-cloud file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum CloudFormat {
    /// CSV with a header naming columns `x`, `y`, `z`.
    Csv,
    /// KITTI `.bin`: float32 x, y, z, reflectance.
    Kitti,
    /// NCLT `velodyne_sync` `.bin`: 8-byte records.
    Nclt,
}

impl CloudFormat {
    /// Guesses the format from the path: `.csv`; `.bin` under a `velodyne_sync` folder is
    /// NCLT, any other `.bin` KITTI.
    pub fn detect(path: &Path) -> Option<Self> {
        match path.extension()?.to_str()?.to_ascii_lowercase().as_str() {
            "csv" => Some(CloudFormat::Csv),
            "bin" => {
                let parent = path.parent().and_then(|p| p.file_name()).and_then(|n| n.to_str());
                Some(if parent == Some("velodyne_sync") { CloudFormat::Nclt } else { CloudFormat::Kitti })
            }
            _ => None,
        }
    }
}

/// Reads one cloud from `path` in `format` (detected from the path if `None`).
pub fn read_cloud(path: &Path, format: Option<CloudFormat>) -> Result<Vec<Point>, SourceError> {
    let format = format
        .or_else(|| CloudFormat::detect(path))
        .ok_or_else(|| SourceError::UnknownFormat { path: path.to_owned() })?;
    let bytes = std::fs::read(path).map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
    let points = match format {
        CloudFormat::Csv => csv::parse_xyz(&bytes, path)?,
        CloudFormat::Kitti => kitti::decode(&bytes, path)?.points,
        CloudFormat::Nclt => nclt::decode_sync(&bytes, path)?.points,
    };
    if let Some(index) = points.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        return Err(SourceError::NonFinite { path: path.to_owned(), index });
    }
    Ok(points)
}
