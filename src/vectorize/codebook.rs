//! The saved descriptor model: which diagram dimensions are vectorized and the ATOL model of
//! each, with everything needed to make the same descriptors in a later run.
//!
//! Two descriptor layouts:
//! * [`DimSelection::Paper`] (the TopoRec paper): one codebook; each scan uses its H2 pairs if
//!   there are at least 2 finite ones, else H1 under the same rule, else H0.
//! * [`DimSelection::Dims`]: one codebook per listed dimension, fitted on that dimension's
//!   points; the descriptor is their concatenation (length = Σ b).
//!
//! The file is JSON (`"format": "toporec-codebook"`); non-finite numbers are written as the
//! strings `"inf"`, `"-inf"`, `"nan"` since JSON has no such numbers. The codebook id is a
//! hash of the file's content, so descriptors can name the codebook they were made with.

use super::atol::{Atol, AtolError, AtolFitter, Contrast, Point2, Weighting};
use super::kmeans::KMeansParams;
use crate::homology::{Diagram, Pair};
use serde_json::{Value, json};
use std::path::Path;

/// A codebook setting or file content that cannot be used, with what is wrong.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct CodebookError(pub String);

impl From<String> for CodebookError {
    fn from(s: String) -> Self {
        CodebookError(s)
    }
}

impl From<&str> for CodebookError {
    fn from(s: &str) -> Self {
        CodebookError(s.to_string())
    }
}

/// Which diagram dimensions make the descriptor.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DimSelection {
    /// H2 if it has ≥ 2 finite pairs, else H1 likewise, else H0 (the paper's rule).
    Paper,
    /// One codebook per dimension, concatenated in the listed order.
    Dims(Vec<u8>),
}

impl DimSelection {
    /// Parses `paper` or a comma-separated list like `0,1,2`.
    pub fn parse(s: &str) -> Result<Self, CodebookError> {
        if s == "paper" {
            return Ok(DimSelection::Paper);
        }
        let dims = s
            .split(',')
            .map(|d| d.trim().parse::<u8>().ok().filter(|d| *d <= 2))
            .collect::<Option<Vec<u8>>>()
            .ok_or_else(|| {
                CodebookError(format!("dims: expected `paper` or a list of 0, 1, 2; found `{s}`"))
            })?;
        Self::from_list(dims)
    }

    /// A list of distinct dimensions 0..=2.
    pub fn from_list(dims: Vec<u8>) -> Result<Self, CodebookError> {
        if dims.is_empty() || dims.iter().any(|&d| d > 2) {
            return Err(CodebookError(format!("dims: expected a non-empty list of 0, 1, 2; found {dims:?}")));
        }
        let mut sorted = dims.clone();
        sorted.sort();
        sorted.dedup();
        if sorted.len() != dims.len() {
            return Err(CodebookError(format!("dims: {dims:?} repeats a dimension")));
        }
        Ok(DimSelection::Dims(dims))
    }

    fn to_json(&self) -> Value {
        match self {
            DimSelection::Paper => json!("paper"),
            DimSelection::Dims(d) => json!(d),
        }
    }
}

impl std::fmt::Display for DimSelection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DimSelection::Paper => f.write_str("paper"),
            DimSelection::Dims(d) => f.write_str(&d.iter().map(u8::to_string).collect::<Vec<_>>().join(",")),
        }
    }
}

/// The paper's choice for one diagram: the dimension used and its points.
pub fn paper_measure(diagram: &Diagram) -> (u8, Vec<Point2>) {
    for dim in [2u8, 1] {
        let pairs = diagram.dimension(dim);
        if pairs.iter().filter(|p| p.death.is_finite()).count() >= 2 {
            return (dim, points(pairs));
        }
    }
    (0, points(diagram.dimension(0)))
}

fn points(pairs: &[Pair]) -> Vec<Point2> {
    pairs.iter().map(|p| [p.birth, p.death]).collect()
}

/// How to fit a codebook.
#[derive(Clone, Debug, PartialEq)]
pub struct CodebookSpec {
    /// Dimensions used.
    pub dims: DimSelection,
    /// Centres per codebook.
    pub b: usize,
    /// ATOL contrast.
    pub contrast: Contrast,
    /// ATOL weighting.
    pub weighting: Weighting,
    /// The k-means quantiser.
    pub kmeans: KMeansParams,
    /// Reservoir size per codebook (points kept for fitting).
    pub sample_size: usize,
    /// Seed of the reservoir and of k-means.
    pub seed: u64,
    /// Whether the diagrams are in squared radii (GUDHI's default) rather than radii.
    pub squared_radii: bool,
}

impl Default for CodebookSpec {
    fn default() -> Self {
        CodebookSpec {
            dims: DimSelection::Paper,
            b: 50,
            contrast: Contrast::Laplacian,
            weighting: Weighting::Cloud,
            kmeans: KMeansParams::default(),
            sample_size: 100_000,
            seed: 0,
            squared_radii: true,
        }
    }
}

/// One fitted part of a codebook.
#[derive(Clone, Debug, PartialEq)]
pub struct CodebookPart {
    /// The diagram dimension (None in paper mode, where it varies per scan).
    pub dim: Option<u8>,
    /// Finite points offered while fitting.
    pub points_seen: u64,
    /// The ATOL model.
    pub atol: Atol,
}

/// A fitted codebook: the spec it was made with and one ATOL model per part.
#[derive(Clone, Debug, PartialEq)]
pub struct Codebook {
    /// How it was fitted.
    pub spec: CodebookSpec,
    /// The toporec version that fitted it.
    pub toporec_version: String,
    /// One part (paper) or one per dimension.
    pub parts: Vec<CodebookPart>,
}

/// A descriptor: the vector and, in paper mode, the dimension used.
#[derive(Clone, Debug, PartialEq)]
pub struct Descriptor {
    /// The ATOL vector (length [`Codebook::len`]).
    pub values: Vec<f64>,
    /// The diagram dimension the vector was made from (paper mode).
    pub dim_used: Option<u8>,
}

impl Descriptor {
    /// The vector as stored in the index: float32.
    pub fn to_f32(&self) -> Vec<f32> {
        self.values.iter().map(|&v| v as f32).collect()
    }
}

/// Streams diagrams into the fitters of a codebook.
#[derive(Clone, Debug)]
pub struct CodebookFitter {
    spec: CodebookSpec,
    fitters: Vec<(Option<u8>, AtolFitter)>,
}

impl CodebookFitter {
    /// A fitter for `spec`.
    pub fn new(spec: CodebookSpec) -> Self {
        let dims: Vec<Option<u8>> = match &spec.dims {
            DimSelection::Paper => vec![None],
            DimSelection::Dims(d) => d.iter().map(|&d| Some(d)).collect(),
        };
        let fitters = dims
            .into_iter()
            .map(|dim| {
                // Each part gets its own stream, so parts do not depend on one another.
                let seed = spec.seed.wrapping_add(dim.map_or(0, |d| d as u64 + 1).wrapping_mul(0x9E37_79B9));
                let f = AtolFitter::new(
                    spec.b,
                    spec.contrast,
                    spec.weighting,
                    spec.kmeans.clone(),
                    spec.sample_size,
                    seed,
                );
                (dim, f)
            })
            .collect();
        CodebookFitter { spec, fitters }
    }

    /// Adds one scan's diagram; `id` names it (the scan id). The fitted codebook depends on
    /// the set of diagrams offered, not on their order.
    pub fn add(&mut self, diagram: &Diagram, id: &str) {
        let key = crate::fingerprint::of_bytes(id.as_bytes());
        for (dim, fitter) in &mut self.fitters {
            match dim {
                None => fitter.add(&paper_measure(diagram).1, key),
                Some(d) => fitter.add(&points(diagram.dimension(*d)), key),
            }
        }
    }

    /// Adds a fitter of the same spec fed with other diagrams: as if this one had seen them
    /// too (the sample is order-independent, so fitters can run in parallel).
    pub fn merge(&mut self, other: CodebookFitter) {
        for ((_, mine), (_, theirs)) in self.fitters.iter_mut().zip(other.fitters) {
            mine.merge(theirs);
        }
    }

    /// Fits every part.
    pub fn finish(self) -> Result<Codebook, AtolError> {
        let parts = self
            .fitters
            .into_iter()
            .map(|(dim, f)| {
                let points_seen = f.points_seen();
                Ok(CodebookPart { dim, points_seen, atol: f.finish()? })
            })
            .collect::<Result<_, AtolError>>()?;
        Ok(Codebook { spec: self.spec, toporec_version: env!("CARGO_PKG_VERSION").into(), parts })
    }
}

/// The file format tag and version written into every codebook.
pub(crate) const FORMAT: &str = "toporec-codebook";
/// Codebook file format version; newer files are refused.
pub const FORMAT_VERSION: u64 = 1;

impl Codebook {
    /// Descriptor length (Σ b over the parts).
    pub fn len(&self) -> usize {
        self.parts.iter().map(|p| p.atol.len()).sum()
    }

    /// Whether the descriptor is empty (never, for a fitted codebook).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The descriptor of one diagram.
    pub fn vectorize(&self, diagram: &Diagram) -> Descriptor {
        let mut values = vec![0.0; self.len()];
        let mut dim_used = None;
        let mut offset = 0;
        for part in &self.parts {
            let out = &mut values[offset..offset + part.atol.len()];
            match part.dim {
                None => {
                    let (d, measure) = paper_measure(diagram);
                    dim_used = Some(d);
                    part.atol.transform_into(&measure, out);
                }
                Some(d) => part.atol.transform_into(&points(diagram.dimension(d)), out),
            }
            offset += part.atol.len();
        }
        Descriptor { values, dim_used }
    }

    /// The codebook as JSON.
    pub fn to_json(&self) -> Value {
        let s = &self.spec;
        let parts: Vec<Value> = self
            .parts
            .iter()
            .map(|p| {
                json!({
                    "dim": p.dim,
                    "points_seen": p.points_seen,
                    "centers": p.atol.centers.iter().map(|c| json!([num(c[0]), num(c[1])])).collect::<Vec<_>>(),
                    "inertias": p.atol.inertias.iter().map(|&x| num(x)).collect::<Vec<_>>(),
                })
            })
            .collect();
        json!({
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "toporec_version": self.toporec_version,
            "dims": s.dims.to_json(),
            "b": s.b,
            "contrast": s.contrast,
            "weighting": s.weighting,
            "squared_radii": s.squared_radii,
            "seed": s.seed,
            "sample_size": s.sample_size,
            "kmeans": s.kmeans,
            "parts": parts,
        })
    }

    /// A short stable id: FNV-1a 64 of the compact JSON, in hex.
    pub fn id(&self) -> String {
        let bytes = serde_json::to_vec(&self.to_json()).expect("JSON of plain values");
        format!("{:016x}", crate::rng::fnv1a64(&bytes))
    }

    /// Writes the codebook (pretty JSON) atomically: a temporary file renamed into place.
    pub fn save(&self, path: &Path) -> crate::error::Result<()> {
        let text = serde_json::to_string_pretty(&self.to_json()).expect("JSON of plain values") + "\n";
        crate::fsutil::write_atomic(path, text.as_bytes())
    }

    /// Reads a codebook file.
    pub fn load(path: &Path) -> crate::error::Result<Self> {
        use crate::error::{Error, ResultExt};
        let text = std::fs::read_to_string(path).at(path)?;
        let bad = |message: String| Error::Codebook { path: path.to_owned(), message };
        let value: Value = serde_json::from_str(&text).map_err(|e| bad(format!("not JSON: {e}")))?;
        Self::from_json(&value).map_err(|e| bad(e.0))
    }

    /// Parses the JSON form.
    pub fn from_json(v: &Value) -> Result<Self, CodebookError> {
        if v["format"] != FORMAT {
            return Err(format!("not a toporec codebook (format = {})", v["format"]).into());
        }
        let version = v["format_version"].as_u64().ok_or("format_version missing")?;
        if version > FORMAT_VERSION {
            return Err(format!(
                "codebook format {version} is newer than this toporec reads ({FORMAT_VERSION})"
            )
            .into());
        }
        let dims = match v.get("dims") {
            Some(Value::String(s)) if s == "paper" => DimSelection::Paper,
            _ => DimSelection::from_list(get(v, "dims")?)?,
        };
        let spec = CodebookSpec {
            dims,
            b: get(v, "b")?,
            contrast: get(v, "contrast")?,
            weighting: get(v, "weighting")?,
            kmeans: get(v, "kmeans")?,
            sample_size: get(v, "sample_size")?,
            seed: get(v, "seed")?,
            squared_radii: get(v, "squared_radii")?,
        };
        let mut parts = Vec::new();
        for (i, p) in v["parts"].as_array().ok_or("parts: expected a list")?.iter().enumerate() {
            let bad = |what: &str| format!("parts[{i}]: {what}");
            let dim = match &p["dim"] {
                Value::Null => None,
                d => {
                    Some(d.as_u64().filter(|d| *d <= 2).ok_or_else(|| bad("dim must be null, 0, 1 or 2"))?
                        as u8)
                }
            };
            let centers = p["centers"]
                .as_array()
                .ok_or_else(|| bad("centers: expected a list"))?
                .iter()
                .map(|c| match c.as_array().map(Vec::as_slice) {
                    Some([x, y]) => Some([from_num(x)?, from_num(y)?]),
                    _ => None,
                })
                .collect::<Option<Vec<Point2>>>()
                .ok_or_else(|| bad("centers: expected [birth, death] pairs"))?;
            let inertias = p["inertias"]
                .as_array()
                .ok_or_else(|| bad("inertias: expected a list"))?
                .iter()
                .map(from_num)
                .collect::<Option<Vec<f64>>>()
                .ok_or_else(|| bad("inertias: expected numbers"))?;
            if centers.len() != inertias.len() || centers.is_empty() {
                return Err(bad("centers and inertias must be non-empty and of equal length").into());
            }
            let points_seen = p["points_seen"].as_u64().unwrap_or(0);
            let atol = Atol { centers, inertias, contrast: spec.contrast, weighting: spec.weighting };
            parts.push(CodebookPart { dim, points_seen, atol });
        }
        let expected: Vec<Option<u8>> = match &spec.dims {
            DimSelection::Paper => vec![None],
            DimSelection::Dims(d) => d.iter().map(|&d| Some(d)).collect(),
        };
        if parts.iter().map(|p| p.dim).collect::<Vec<_>>() != expected {
            return Err(format!("parts do not match dims = {}", spec.dims).into());
        }
        let toporec_version = v["toporec_version"].as_str().unwrap_or("unknown").to_string();
        Ok(Codebook { spec, toporec_version, parts })
    }
}

/// Field `key` of `v`, deserialized.
fn get<T: serde::de::DeserializeOwned>(v: &Value, key: &str) -> Result<T, CodebookError> {
    let field = v.get(key).ok_or_else(|| CodebookError(format!("`{key}` missing")))?;
    serde_json::from_value(field.clone()).map_err(|e| CodebookError(format!("{key}: {e}")))
}

/// A JSON number, or a string for non-finite values.
fn num(x: f64) -> Value {
    if x.is_finite() {
        json!(x)
    } else if x.is_nan() {
        json!("nan")
    } else if x > 0.0 {
        json!("inf")
    } else {
        json!("-inf")
    }
}

fn from_num(v: &Value) -> Option<f64> {
    match v {
        Value::Number(n) => n.as_f64(),
        Value::String(s) => match s.as_str() {
            "inf" => Some(f64::INFINITY),
            "-inf" => Some(f64::NEG_INFINITY),
            "nan" => Some(f64::NAN),
            _ => None,
        },
        _ => None,
    }
}
