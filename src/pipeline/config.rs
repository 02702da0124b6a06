//! Pipeline files: one TOML file is one complete job. Parsing collects every error in the
//! file — unknown keys, wrong types, bad values, missing inputs — each with its key path,
//! before any data is read (`toporec validate`).
//!
//! ```toml
//! [output]
//! index = "../target/index"          # relative paths are relative to this file
//! [[sources]]                        # one or more; see crate::sources::SourceSpec
//! kind = "nclt"
//! sessions = ["../samples/nclt"]
//! [preprocess]                       # every step optional, applied in this order
//! range = { min = 1.0, max = 80.0 }  # metres from the sensor
//! ground = { method = "plane", threshold = 0.15 }   # or { method = "height", below = -1.5 }
//! voxel = 0.2                        # voxel-grid cell (m)
//! subsample = 4096                   # at most this many points, seeded by scan id
//! normalize = true                   # zero mean, max |coordinate| = 1
//! min_points = 16                    # fewer left: the scan is skipped with the reason
//! [persistence]
//! dims = [0, 1, 2]                   # dimensions stored in the diagrams table
//! squared = true                     # squared radii (GUDHI's default) or radii
//! [vectorize]                        # fit a codebook on this run's diagrams …
//! b = 50
//! dims = "paper"                     # or [0, 1, 2]
//! # codebook = "codebook.json"       # … or load a saved one
//! ```

use crate::sources::SourceSpec;
use crate::vectorize::atol::{Contrast, Weighting};
use crate::vectorize::codebook::{Codebook, CodebookSpec, DimSelection};
use crate::vectorize::kmeans::{Algorithm, KMeansParams};
use serde::de::DeserializeOwned;
use std::path::{Path, PathBuf};
use toml::{Table, Value};

/// A parsed, validated pipeline.
#[derive(Clone, Debug)]
pub struct Pipeline {
    /// The file it came from.
    pub path: PathBuf,
    /// Where the index goes.
    pub index: PathBuf,
    /// Sources, in order.
    pub sources: Vec<SourceSpec>,
    /// Preprocessing.
    pub preprocess: Preprocess,
    /// Persistence settings.
    pub persistence: Persistence,
    /// Vectorizing.
    pub vectorize: Vectorize,
}

/// The preprocess stage's settings (each step optional, applied in field order).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Preprocess {
    /// Keep points whose distance to the sensor is within [min, max] metres.
    pub range: Option<RangeCrop>,
    /// Remove the ground.
    pub ground: Option<Ground>,
    /// Voxel-grid downsampling cell size (m): one centroid per occupied cell.
    pub voxel: Option<f64>,
    /// Keep at most this many points (uniformly, seeded by the scan id).
    pub subsample: Option<usize>,
    /// Centre on the mean and scale so the largest |coordinate| is 1.
    pub normalize: bool,
    /// Scans with fewer points left are skipped (recorded with the reason).
    pub min_points: usize,
}

/// A range crop.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RangeCrop {
    /// Minimum distance (m).
    #[serde(default)]
    pub min: f64,
    /// Maximum distance (m).
    #[serde(default = "infinite")]
    pub max: f64,
}

fn infinite() -> f64 {
    f64::INFINITY
}

/// Ground removal.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "method", rename_all = "lowercase", deny_unknown_fields)]
pub enum Ground {
    /// Drop points with z below `below` (sensor frame, z up).
    Height {
        /// Height threshold (m).
        below: f64,
    },
    /// Fit the ground plane by RANSAC (seeded by scan id; normals within 30° of z) and drop
    /// points within `threshold` of it.
    Plane {
        /// Inlier distance (m).
        #[serde(default = "default_plane_threshold")]
        threshold: f64,
        /// RANSAC iterations.
        #[serde(default = "default_plane_iterations")]
        iterations: usize,
    },
}

fn default_plane_threshold() -> f64 {
    0.2
}

fn default_plane_iterations() -> usize {
    100
}

/// Persistence settings.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Persistence {
    /// Dimensions stored in the diagrams table.
    pub dims: Vec<u8>,
    /// Squared radii (true, GUDHI's default) or radii.
    pub squared: bool,
}

/// Vectorize settings: fit a codebook on this run's diagrams, or load one.
#[derive(Clone, Debug, PartialEq)]
pub enum Vectorize {
    /// Fit with this spec.
    Fit(CodebookSpec),
    /// Use this saved codebook.
    Load(PathBuf, Box<Codebook>),
}

/// All errors of a file, one per line.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {} error(s):\n{}", errors.len(), errors.iter().map(|e| format!("  {e}")).collect::<Vec<_>>().join("\n"))]
pub struct ConfigErrors {
    /// The file.
    pub path: PathBuf,
    /// Each error, starting with its key path.
    pub errors: Vec<String>,
}

/// A table being read: remembers which keys were asked for, to report the others.
struct Section<'a> {
    table: &'a Table,
    path: String,
    seen: Vec<&'static str>,
}

impl<'a> Section<'a> {
    fn new(table: &'a Table, path: &str) -> Self {
        Section { table, path: path.to_string(), seen: Vec::new() }
    }

    fn key(&self, key: &str) -> String {
        if self.path.is_empty() { key.to_string() } else { format!("{}.{key}", self.path) }
    }

    fn get<T: DeserializeOwned>(&mut self, key: &'static str, errors: &mut Vec<String>) -> Option<T> {
        self.seen.push(key);
        let value = self.table.get(key)?;
        match value.clone().try_into::<T>() {
            Ok(v) => Some(v),
            Err(e) => {
                errors.push(format!("{}: {}", self.key(key), e.message().trim()));
                None
            }
        }
    }

    fn table(&mut self, key: &'static str, errors: &mut Vec<String>) -> Option<Section<'a>> {
        self.seen.push(key);
        match self.table.get(key)? {
            Value::Table(t) => Some(Section::new(t, &self.key(key))),
            _ => {
                errors.push(format!("{}: expected a table", self.key(key)));
                None
            }
        }
    }

    fn finish(self, errors: &mut Vec<String>) {
        for k in self.table.keys() {
            if !self.seen.contains(&k.as_str()) {
                errors.push(format!("{}: unknown key", self.key(k)));
            }
        }
    }
}

impl Pipeline {
    /// Reads and validates a pipeline file.
    pub fn load(path: &Path) -> Result<Self, ConfigErrors> {
        let fail = |errors| ConfigErrors { path: path.to_owned(), errors };
        let text = std::fs::read_to_string(path).map_err(|e| fail(vec![e.to_string()]))?;
        Self::parse(&text, path)
    }

    /// Reads a pipeline file without checking that its inputs exist (an index's effective
    /// pipeline, read for its settings).
    pub fn load_settings(path: &Path) -> Result<Self, ConfigErrors> {
        let fail = |errors| ConfigErrors { path: path.to_owned(), errors };
        let text = std::fs::read_to_string(path).map_err(|e| fail(vec![e.to_string()]))?;
        Self::parse_with(&text, path, false)
    }

    /// Parses pipeline text; `path` names the file and anchors relative paths.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigErrors> {
        Self::parse_with(text, path, true)
    }

    fn parse_with(text: &str, path: &Path, check_inputs: bool) -> Result<Self, ConfigErrors> {
        let mut errors = Vec::new();
        let fail = |errors| ConfigErrors { path: path.to_owned(), errors };
        let doc: Table =
            text.parse().map_err(|e: toml::de::Error| fail(vec![e.to_string().trim().to_string()]))?;
        // Absolute, so the effective pipeline written into an index stays valid anywhere.
        let base = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let base = std::path::absolute(base).unwrap_or_else(|_| base.to_owned());
        let resolve = |p: PathBuf| clean(&if p.is_relative() { base.join(p) } else { p });
        let mut root = Section::new(&doc, "");

        let index = match root.table("output", &mut errors) {
            Some(mut s) => {
                let index: Option<PathBuf> = s.get("index", &mut errors);
                s.finish(&mut errors);
                index
            }
            None => None,
        };
        if index.is_none() {
            errors.push("output.index: missing (the index folder to write)".into());
        }

        root.seen.push("sources");
        let mut sources = Vec::new();
        match doc.get("sources") {
            Some(Value::Array(items)) if !items.is_empty() => {
                for (i, item) in items.iter().enumerate() {
                    match item.clone().try_into::<SourceSpec>() {
                        Ok(mut s) => {
                            s.resolve_paths(&base);
                            s.clean_paths(clean);
                            if check_inputs {
                                check_source_paths(&s, i, &mut errors);
                            }
                            sources.push(s);
                        }
                        Err(e) => errors.push(format!("sources[{i}]: {}", e.message().trim())),
                    }
                }
            }
            _ => errors.push("sources: missing (one or more [[sources]] tables)".into()),
        }

        let preprocess = {
            let empty = Table::new();
            let mut s =
                root.table("preprocess", &mut errors).unwrap_or_else(|| Section::new(&empty, "preprocess"));
            let p = Preprocess {
                range: s.get("range", &mut errors),
                ground: s.get("ground", &mut errors),
                voxel: s.get("voxel", &mut errors),
                subsample: s.get("subsample", &mut errors),
                normalize: s.get("normalize", &mut errors).unwrap_or(false),
                min_points: s.get("min_points", &mut errors).unwrap_or(16),
            };
            s.finish(&mut errors);
            if let Some(r) = p.range
                && !(r.min >= 0.0 && r.min < r.max)
            {
                errors.push(format!("preprocess.range: need 0 <= min < max (min {}, max {})", r.min, r.max));
            }
            if let Some(Ground::Plane { threshold, iterations }) = p.ground
                && (threshold.is_nan() || threshold <= 0.0 || iterations == 0)
            {
                errors.push("preprocess.ground: need threshold > 0 and iterations >= 1".into());
            }
            if p.voxel.is_some_and(|v| v.is_nan() || v <= 0.0) {
                errors.push("preprocess.voxel: the cell size must be > 0".into());
            }
            if p.subsample.is_some_and(|n| n < 4) {
                errors.push("preprocess.subsample: must be at least 4 points".into());
            }
            if p.min_points < 4 {
                errors.push("preprocess.min_points: must be at least 4 (a tetrahedron)".into());
            }
            p
        };

        let persistence = {
            let empty = Table::new();
            let mut s =
                root.table("persistence", &mut errors).unwrap_or_else(|| Section::new(&empty, "persistence"));
            let dims: Vec<u8> = s.get("dims", &mut errors).unwrap_or(vec![0, 1, 2]);
            let squared = s.get("squared", &mut errors).unwrap_or(true);
            s.finish(&mut errors);
            if dims.is_empty() || dims.iter().any(|&d| d > 2) {
                errors.push(format!("persistence.dims: expected a list of 0, 1, 2; found {dims:?}"));
            }
            Persistence { dims, squared }
        };

        let vectorize = {
            let empty = Table::new();
            let mut s =
                root.table("vectorize", &mut errors).unwrap_or_else(|| Section::new(&empty, "vectorize"));
            let codebook: Option<PathBuf> = s.get("codebook", &mut errors);
            let dims = match s.get::<Value>("dims", &mut errors) {
                None => Some(DimSelection::Paper),
                Some(Value::String(t)) => {
                    DimSelection::parse(&t).map_err(|e| errors.push(format!("vectorize.{e}"))).ok()
                }
                Some(v) => match v.try_into::<Vec<u8>>() {
                    Ok(list) => {
                        DimSelection::from_list(list).map_err(|e| errors.push(format!("vectorize.{e}"))).ok()
                    }
                    Err(_) => {
                        errors.push("vectorize.dims: expected \"paper\" or a list like [0, 1, 2]".into());
                        None
                    }
                },
            };
            let fit_keys = ["b", "dims", "contrast", "weighting", "kmeans", "seed", "sample_size"];
            let given: Vec<&str> = fit_keys.iter().copied().filter(|k| s.table.contains_key(*k)).collect();
            let d = CodebookSpec::default();
            let kmeans: Option<Algorithm> = s.get("kmeans", &mut errors);
            let spec = CodebookSpec {
                dims: dims.unwrap_or(DimSelection::Paper),
                b: s.get("b", &mut errors).unwrap_or(d.b),
                contrast: s.get::<Contrast>("contrast", &mut errors).unwrap_or(d.contrast),
                weighting: s.get::<Weighting>("weighting", &mut errors).unwrap_or(d.weighting),
                kmeans: KMeansParams {
                    algorithm: kmeans.unwrap_or(Algorithm::MiniBatch),
                    ..KMeansParams::default()
                },
                seed: s.get("seed", &mut errors).unwrap_or(d.seed),
                sample_size: s.get("sample_size", &mut errors).unwrap_or(d.sample_size),
                squared_radii: persistence.squared,
            };
            s.finish(&mut errors);
            if spec.b == 0 {
                errors.push("vectorize.b: must be at least 1".into());
            }
            if spec.sample_size == 0 {
                errors.push("vectorize.sample_size: must be at least 1".into());
            }
            match codebook {
                Some(p) => {
                    if !given.is_empty() {
                        errors.push(format!(
                            "vectorize: {} given with a saved codebook (it fixes them); remove one or the other",
                            given.join(", ")
                        ));
                    }
                    let p = resolve(p);
                    match Codebook::load(&p) {
                        Ok(cb) => {
                            if cb.spec.squared_radii != persistence.squared {
                                errors.push(format!(
                                    "vectorize.codebook: made for {} but persistence.squared = {}",
                                    if cb.spec.squared_radii { "squared radii" } else { "radii" },
                                    persistence.squared
                                ));
                            }
                            Vectorize::Load(p, Box::new(cb))
                        }
                        Err(e) => {
                            errors.push(format!("vectorize.codebook: {e:#}"));
                            Vectorize::Fit(spec)
                        }
                    }
                }
                None => Vectorize::Fit(spec),
            }
        };
        let needed: Vec<u8> = match &vectorize {
            Vectorize::Fit(s) => dims_needed(&s.dims),
            Vectorize::Load(_, cb) => dims_needed(&cb.spec.dims),
        };
        if let Some(d) = needed.iter().find(|d| !persistence.dims.contains(d)) {
            errors.push(format!("persistence.dims: the descriptor needs H{d}; add {d} to the stored dims"));
        }
        root.finish(&mut errors);
        if !errors.is_empty() {
            return Err(fail(errors));
        }
        Ok(Pipeline {
            path: path.to_owned(),
            index: resolve(index.unwrap()),
            sources,
            preprocess,
            persistence,
            vectorize,
        })
    }

    /// The effective pipeline as TOML (absolute paths, defaults filled in, the codebook as
    /// loaded): written into the index beside the tables.
    pub fn effective_toml(&self) -> String {
        let mut doc = Table::new();
        let mut output = Table::new();
        output.insert("index".into(), Value::String(self.index.display().to_string()));
        doc.insert("output".into(), Value::Table(output));
        let sources: Vec<Value> =
            self.sources.iter().map(|s| Value::try_from(s).expect("plain data")).collect();
        doc.insert("sources".into(), Value::Array(sources));
        let pre = Value::try_from(&self.preprocess).expect("plain data");
        doc.insert("preprocess".into(), pre);
        doc.insert("persistence".into(), Value::try_from(&self.persistence).expect("plain data"));
        let mut v = Table::new();
        match &self.vectorize {
            Vectorize::Load(p, _) => {
                v.insert("codebook".into(), Value::String(p.display().to_string()));
            }
            Vectorize::Fit(s) => {
                v.insert("b".into(), Value::Integer(s.b as i64));
                v.insert(
                    "dims".into(),
                    match &s.dims {
                        DimSelection::Paper => Value::String("paper".into()),
                        DimSelection::Dims(d) => {
                            Value::Array(d.iter().map(|&x| Value::Integer(x as i64)).collect())
                        }
                    },
                );
                v.insert("contrast".into(), Value::try_from(s.contrast).expect("plain data"));
                v.insert("weighting".into(), Value::try_from(s.weighting).expect("plain data"));
                v.insert("kmeans".into(), Value::try_from(s.kmeans.algorithm).expect("plain data"));
                v.insert("seed".into(), Value::Integer(s.seed as i64));
                v.insert("sample_size".into(), Value::Integer(s.sample_size as i64));
            }
        }
        doc.insert("vectorize".into(), Value::Table(v));
        format!(
            "# The effective pipeline of this index (resolved by toporec {}).\n{}",
            env!("CARGO_PKG_VERSION"),
            toml::to_string(&doc).expect("TOML of plain data")
        )
    }
}

/// Removes `.` and `name/..` components without touching the file system.
pub fn clean(path: &Path) -> PathBuf {
    use std::path::Component;
    let mut out: Vec<Component> = Vec::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if matches!(out.last(), Some(Component::Normal(_))) => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    if out.is_empty() { PathBuf::from(".") } else { out.iter().collect() }
}

/// Diagram dimensions a descriptor reads.
pub fn dims_needed(dims: &DimSelection) -> Vec<u8> {
    match dims {
        DimSelection::Paper => vec![0, 1, 2],
        DimSelection::Dims(d) => d.clone(),
    }
}

fn check_source_paths(s: &SourceSpec, i: usize, errors: &mut Vec<String>) {
    let mut check = |key: &str, p: &Path| {
        if !p.exists() {
            errors.push(format!("sources[{i}].{key}: {} does not exist", p.display()));
        }
    };
    match s {
        SourceSpec::Nclt(n) => {
            n.sessions.iter().for_each(|p| check("sessions", p));
            n.groundtruth.iter().for_each(|p| check("groundtruth", p));
            if n.sessions.is_empty() {
                errors.push(format!("sources[{i}].sessions: empty"));
            }
        }
        SourceSpec::Mcap(m) => {
            m.files.iter().for_each(|p| check("files", p));
            m.poses.iter().for_each(|p| check("poses", p));
            if m.files.is_empty() {
                errors.push(format!("sources[{i}].files: empty"));
            }
        }
        SourceSpec::Kitti(k) => {
            k.sequences.iter().for_each(|p| check("sequences", p));
            if k.sequences.is_empty() {
                errors.push(format!("sources[{i}].sequences: empty"));
            }
        }
    }
}
