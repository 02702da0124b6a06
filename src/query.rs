//! `toporec query`: the k nearest database descriptors of new scans, made with the index's own
//! preprocessing and codebook (read from the index, never re-specified), many queries per
//! call, in parallel. Also the engine `eval` uses.

use crate::homology::alpha_persistence;
use crate::inspect;
use crate::pipeline::config::Pipeline;
use crate::preprocess::{Skip, preprocess};
use crate::search::{Database, Hit};
use crate::sinks::index::{IndexedScan, read_descriptors};
use crate::sources::{Scan, ScanFailure, ScanStream, read_cloud};
use crate::vectorize::codebook::Codebook;
use anyhow::{Context, Result, bail};
use std::path::Path;
use std::time::Instant;

/// An opened index, ready to answer queries.
pub struct Engine {
    /// The index's effective pipeline (preprocess and persistence settings).
    pub pipeline: Pipeline,
    /// The index's codebook.
    pub codebook: Codebook,
    /// Database rows (descriptor, id, session, pose).
    pub scans: Vec<IndexedScan>,
    /// The search structure over `scans`.
    pub db: Database,
}

/// Per-query seconds of each step.
#[derive(Clone, Copy, Debug, Default)]
pub struct StepTimes {
    /// Preprocess + alpha persistence.
    pub persistence: f64,
    /// ATOL.
    pub vectorize: f64,
    /// Nearest-neighbour search.
    pub search: f64,
}

impl Engine {
    /// Opens `index` (only `sessions` as the database, when not empty).
    pub fn open(index: &Path, sessions: &[String]) -> Result<Self> {
        let pipeline =
            Pipeline::load_settings(&index.join("pipeline.toml")).map_err(|e| anyhow::anyhow!("{e}"))?;
        let (codebook, scans) = load_descriptors(index, sessions)?;
        let vectors: Vec<f32> = scans.iter().flat_map(|s| s.descriptor.iter().copied()).collect();
        let db = Database::new(vectors, codebook.len());
        Ok(Engine { pipeline, codebook, scans, db })
    }

    /// A scan's preprocessed points, as the index made them.
    pub fn preprocess(&self, scan: Scan) -> Result<Vec<[f64; 3]>, String> {
        preprocess(scan.points, &scan.id, &self.pipeline.preprocess)
            .map_err(|Skip(r)| format!("{}: skipped: {r}", scan.id))
    }

    /// The descriptor of preprocessed points, with the time of each step.
    pub fn describe(&self, points: &[[f64; 3]], label: &str) -> Result<(Vec<f32>, StepTimes), String> {
        let mut t = StepTimes::default();
        let start = Instant::now();
        let d = alpha_persistence(points).map_err(|e| format!("{label}: {e}"))?;
        let d = if self.pipeline.persistence.squared { d } else { d.to_radii() };
        t.persistence = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let v = self.codebook.vectorize(&d).to_f32();
        t.vectorize = start.elapsed().as_secs_f64();
        Ok((v, t))
    }

    /// The `k` nearest database rows.
    pub fn search(&self, descriptor: &[f32], k: usize) -> Vec<Hit> {
        self.db.search(descriptor, k)
    }
}

/// An index's codebook and its descriptors (only `sessions`, when not empty), checked to have
/// been made with that codebook.
pub fn load_descriptors(index: &Path, sessions: &[String]) -> Result<(Codebook, Vec<IndexedScan>)> {
    let codebook = Codebook::load(&index.join("codebook.json"))?;
    let scans = read_descriptors(index, sessions)?;
    if scans.is_empty() {
        bail!(
            "{}: no descriptors{}",
            index.display(),
            if sessions.is_empty() { String::new() } else { format!(" in sessions {sessions:?}") }
        );
    }
    let id = codebook.id();
    if let Some(s) = scans.iter().find(|s| s.codebook_id != id) {
        bail!(
            "{}: scan {} was made with codebook {}, the index's codebook.json is {id}",
            index.display(),
            s.scan_id,
            s.codebook_id
        );
    }
    Ok((codebook, scans))
}

/// A scan stream for a path given on the command line: an MCAP, an NCLT session (or folder of
/// sessions, or `velodyne_hits.bin`), a KITTI sequence (or `sequences/`), or one cloud file.
pub fn open_path(path: &Path, topic: Option<&str>) -> Result<ScanStream> {
    let kind = inspect::detect(path)?;
    if let Some(spec) = inspect::source_spec(path, kind, topic)? {
        return spec.open().with_context(|| path.display().to_string());
    }
    let points = read_cloud(path, None);
    let id = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let item = match points {
        Ok(points) => Ok(Scan {
            id: id.clone(),
            session: "query".into(),
            path: path.to_owned(),
            message_index: None,
            utime: 0,
            raw_points: points.len(),
            points,
            intensity: None,
            ring: None,
            pose: None,
        }),
        Err(e) => Err(ScanFailure::of_file(id, "query", path, None, e.to_string())),
    };
    Ok(Box::new(std::iter::once(item)))
}

/// Mean and 95th percentile (nearest rank) of a sample, in milliseconds.
pub fn mean_p95_ms(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0);
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let p95 = s[((0.95 * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1];
    (1e3 * s.iter().sum::<f64>() / s.len() as f64, 1e3 * p95)
}
