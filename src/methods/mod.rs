//! The descriptor methods, behind one interface and one registry.
//!
//! * The TopoRec paper's descriptor (alpha persistence + ATOL): made by the pipeline's stages
//!   with the index's codebook, searched by exact Euclidean k-NN ([`euclidean`]).
//! * The methods computed from the raw scan in the sensor frame, each with its own
//!   preprocessing: toporec's own [`toporec_plus`], and the baselines place recognition is
//!   usually compared against — [`scancontext`] (Kim & Kim 2018), [`scancontext_pp`] (Scan
//!   Context++, Kim, Choi, Kim 2021: its polar and its Cartesian context), [`m2dp`] (He et al.
//!   2016), [`solid`] (Kim, Choi, Kim 2024), [`lidar_iris`] (Wang et al. 2020), [`ring`] (Lu
//!   et al. 2022) and [`ring_plus`] (RING++, Xu, Lu et al. 2023).
//! * Descriptors made elsewhere (PointNetVLAD, PCAN, MinkLoc3D, …), imported into an index with
//!   `toporec import`: stored, searched by Euclidean k-NN, never computed.
//!
//! A computed method is its parameters, a type implementing [`Computed`] (name, settings and
//! their checks, length, describe, its [`Searcher`]); [`REGISTRY`] lists them. Adding one is
//! its module and one entry there: pipeline files, the manifest, `query`, `eval`, `loops`, the
//! online detector, `import`'s reserved names and the Python package find it by name. An index
//! stores each method's descriptors apart (`descriptors/method=<name>/session=<s>/`).

pub mod euclidean;
pub mod lidar_iris;
pub mod m2dp;
pub mod ring;
pub mod ring_plus;
pub mod scancontext;
pub mod scancontext_pp;
pub mod searcher;
pub mod solid;
pub mod toporec_plus;

use crate::types::Point;
pub use searcher::{Hit, SearchBudget, SearchTimes, Searcher};
use serde::de::DeserializeOwned;
use std::sync::Arc;

/// The fewest points a raw-scan method describes a place from: a scan with fewer (a stray
/// two-point file, a frame the sensor dropped) is skipped with the reason, never stored, so it
/// can never match another at distance 0. Real scans hold thousands.
pub const MIN_RAW_POINTS: usize = 100;

/// The name of the TopoRec paper's descriptor (alpha persistence + ATOL).
pub const TOPOREC: &str = "toporec";
/// The kind name of imported methods in the manifest.
pub(crate) const IMPORTED: &str = "imported";

/// The name of the method whose parameters a type holds.
pub trait Named {
    /// The method's name (its [`REGISTRY`] entry's).
    const NAME: &'static str;
}

/// A method's name and its parameters as JSON (the manifest and the effective pipeline record
/// them): what any serializable [`Named`] parameters give.
pub trait Settings {
    /// The method's name.
    fn name(&self) -> &'static str;

    /// The parameters as JSON.
    fn settings(&self) -> serde_json::Value;
}

impl<P: Named + serde::Serialize> Settings for P {
    fn name(&self) -> &'static str {
        P::NAME
    }

    fn settings(&self) -> serde_json::Value {
        serde_json::to_value(self).expect("plain data")
    }
}

/// A descriptor method computed from raw scans: its parameters, and all that `run`, `query`,
/// `eval`, `loops` and the online detector ask of it.
pub trait Computed: Settings + std::fmt::Debug + Send + Sync + 'static {
    /// The parameters' problems, each with its key.
    fn problems(&self) -> Vec<String>;

    /// Descriptor length.
    fn len(&self) -> usize;

    /// Whether the descriptor is empty (never, for valid settings).
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Whether the descriptor's values are bytes, stored as `uint8` rather than `float32`.
    fn stores_bytes(&self) -> bool {
        false
    }

    /// The descriptor of a raw scan (sensor frame, metres, z up), after the method's own
    /// preprocessing; an error, with the reason, when the method cannot describe the scan.
    fn describe(&self, points: &[Point]) -> Result<Vec<f32>, String>;

    /// The method's search structure over `descriptors` (`n × len`, row-major).
    fn searcher(&self, descriptors: Vec<f32>) -> Box<dyn Searcher>;

    /// The steps a search reports times for: `candidates` and `rerank` for the methods that
    /// narrow by keys first, else one `search` step.
    fn search_steps(&self) -> &'static [&'static str] {
        &["search"]
    }

    /// The loop threshold at the method's default settings (calibrated on simulated HDL-64E
    /// drives, docs/loops.md says which and at what precision); `None` where none was calibrated.
    fn default_threshold(&self) -> Option<f64> {
        None
    }

    /// The layout name of the structure cached in the index (`searchers/<method>.searcher`)
    /// for the methods whose structure is worth caching; `None` for the others.
    fn cache_layout(&self) -> Option<&'static str> {
        None
    }

    /// The searcher over `n` entries laid out in `body` (a cache written from
    /// [`Searcher::bytes`]), for the methods with a [`Computed::cache_layout`].
    fn mapped_searcher(
        &self,
        _body: crate::checked_map::CheckedMap,
        _n: usize,
    ) -> Result<Box<dyn Searcher>, String> {
        Err(format!("{}: no cached search structure", self.name()))
    }
}

/// A method the registry knows: its name and how its parameters are read.
pub struct Registered {
    /// The method's name.
    pub name: &'static str,
    from_json: fn(&serde_json::Value) -> Result<Arc<dyn Computed>, String>,
    from_toml: fn(toml::Value) -> Result<Arc<dyn Computed>, String>,
    default: fn() -> Arc<dyn Computed>,
}

/// The registry's entry of the method whose parameters are of type `P`.
const fn entry<P: Computed + Named + DeserializeOwned + Default>() -> Registered {
    fn from_json<P: Computed + DeserializeOwned + Default>(
        v: &serde_json::Value,
    ) -> Result<Arc<dyn Computed>, String> {
        if v.is_null() {
            return Ok(Arc::new(P::default()));
        }
        serde_json::from_value::<P>(v.clone()).map(|p| Arc::new(p) as _).map_err(|e| e.to_string())
    }
    fn from_toml<P: Computed + DeserializeOwned + Default>(
        v: toml::Value,
    ) -> Result<Arc<dyn Computed>, String> {
        v.try_into::<P>().map(|p| Arc::new(p) as _).map_err(|e| e.message().trim().to_string())
    }
    fn default<P: Computed + Default>() -> Arc<dyn Computed> {
        Arc::new(P::default())
    }
    Registered { name: P::NAME, from_json: from_json::<P>, from_toml: from_toml::<P>, default: default::<P> }
}

/// Every method computed from raw scans, in the order messages list them.
pub const REGISTRY: &[Registered] = &[
    entry::<toporec_plus::PlusParams>(),
    entry::<scancontext::ScanContextParams>(),
    entry::<scancontext_pp::PolarParams>(),
    entry::<scancontext_pp::CartParams>(),
    entry::<m2dp::M2dpParams>(),
    entry::<solid::SolidParams>(),
    entry::<lidar_iris::IrisParams>(),
    entry::<ring::RingParams>(),
    entry::<ring_plus::RingPlusParams>(),
];

impl Registered {
    /// The entry of the method named `name`.
    pub fn of(name: &str) -> Option<&'static Registered> {
        REGISTRY.iter().find(|r| r.name == name)
    }

    /// The method at its default settings.
    pub fn default_method(&self) -> Method {
        Method::computed((self.default)())
    }

    /// The method with the settings of its pipeline-file section, unchecked; an error when
    /// they do not parse (the deserializer's message).
    pub(crate) fn method_from_toml(&self, section: toml::Value) -> Result<Method, String> {
        (self.from_toml)(section).map(Method::computed)
    }

    /// The method with the settings an index stored (its manifest, its effective pipeline),
    /// unchecked: a key they lack means what it meant when they were written
    /// ([`stored_settings`]), not today's default.
    pub(crate) fn stored_method(&self, settings: &serde_json::Value) -> Result<Method, String> {
        (self.from_json)(&stored_settings(self.name, settings)).map(Method::computed)
    }
}

/// The settings of the method `kind` an index stored, with what a missing key meant when they
/// were written filled in: toporec-plus's `lateral` was empty by default before the views were
/// the default ([`toporec_plus::PlusParams::from_stored`]).
pub fn stored_settings(kind: &str, settings: &serde_json::Value) -> serde_json::Value {
    let mut settings = if settings.is_null() { serde_json::json!({}) } else { settings.clone() };
    if kind == toporec_plus::NAME {
        toporec_plus::PlusParams::from_stored(&mut settings);
    }
    settings
}

/// The names of the methods computed from raw scans, in the registry's order.
pub fn computed_names() -> Vec<&'static str> {
    REGISTRY.iter().map(|r| r.name).collect()
}

/// Whether the descriptors of the method named `name` are stored as bytes (`uint8`): a
/// computed method's own answer ([`Computed::stores_bytes`]); `float32` for the others.
pub(crate) fn stores_bytes(name: &str) -> bool {
    Registered::of(name).is_some_and(|r| (r.default)().stores_bytes())
}

/// What a method computes.
#[derive(Clone, Debug)]
pub enum MethodKind {
    /// The TopoRec paper's descriptor: the pipeline's preprocess, persistence and codebook.
    Toporec,
    /// A method computed from raw scans (one of [`REGISTRY`]), with its parameters.
    Computed(Arc<dyn Computed>),
    /// Vectors made elsewhere, imported (`toporec import`): stored, never computed.
    Imported {
        /// Their length.
        length: usize,
        /// Where they came from (the file imported).
        source: String,
    },
}

/// A descriptor method of an index.
#[derive(Clone, Debug)]
pub struct Method {
    /// Its name (`toporec`, a computed method's, or an imported one's).
    pub name: String,
    /// What it computes.
    pub kind: MethodKind,
}

impl PartialEq for Method {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name && self.kind_name() == other.kind_name() && self.params() == other.params()
    }
}

impl Method {
    /// The TopoRec paper's descriptor.
    pub fn toporec() -> Self {
        Method { name: TOPOREC.into(), kind: MethodKind::Toporec }
    }

    /// A computed method with these parameters, under its own name.
    pub fn computed(params: Arc<dyn Computed>) -> Self {
        Method { name: params.name().into(), kind: MethodKind::Computed(params) }
    }

    /// A computed method with these parameters, under its own name.
    pub fn of(params: impl Computed) -> Self {
        Self::computed(Arc::new(params))
    }

    /// A method computed from raw scans by its name (one of [`REGISTRY`]) and its settings (the
    /// keys of its pipeline-file section, as JSON; `null` or `{}` for the defaults); an error
    /// naming each problem.
    pub fn from_settings(name: &str, settings: &serde_json::Value) -> Result<Method, String> {
        let method = Self::with_settings(name, settings)?;
        let problems = method.as_computed().map(|c| c.problems()).unwrap_or_default();
        if problems.is_empty() { Ok(method) } else { Err(problems.join("; ")) }
    }

    /// [`Method::from_settings`] without checking the values: an error only for an unknown name
    /// or settings that do not parse (an index's manifest records settings checked when written).
    pub fn with_settings(name: &str, settings: &serde_json::Value) -> Result<Method, String> {
        let Some(entry) = Registered::of(name) else {
            return Err(format!(
                "unknown method `{name}` (computed from raw scans: {})",
                computed_names().join(", ")
            ));
        };
        (entry.from_json)(settings).map(Method::computed).map_err(|e| format!("{name}: {e}"))
    }

    /// The computed method's parameters, for the methods computed from raw scans.
    pub fn as_computed(&self) -> Option<&dyn Computed> {
        match &self.kind {
            MethodKind::Computed(c) => Some(c.as_ref()),
            _ => None,
        }
    }

    /// The kind's name: `toporec`, `imported`, or a computed method's name.
    pub fn kind_name(&self) -> &'static str {
        match &self.kind {
            MethodKind::Toporec => TOPOREC,
            MethodKind::Computed(c) => c.name(),
            MethodKind::Imported { .. } => IMPORTED,
        }
    }

    /// The method's parameters as JSON (recorded in the manifest).
    pub fn params(&self) -> serde_json::Value {
        match &self.kind {
            MethodKind::Toporec => serde_json::json!({}),
            MethodKind::Computed(c) => c.settings(),
            MethodKind::Imported { source, .. } => serde_json::json!({ "source": source }),
        }
    }

    /// Descriptor length (0 for TopoRec, whose length is its codebook's).
    pub fn len(&self) -> usize {
        match &self.kind {
            MethodKind::Toporec => 0,
            MethodKind::Computed(c) => c.len(),
            MethodKind::Imported { length, .. } => *length,
        }
    }

    /// Whether the descriptor is empty (TopoRec, whose length is its codebook's).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The id every descriptor row of the method carries: 16 hex digits of the kind and
    /// parameters.
    pub fn id(&self) -> String {
        let text = format!("{}:{}", self.kind_name(), self.params());
        crate::fingerprint::hex(crate::fingerprint::of_bytes(text.as_bytes()))
    }

    /// Whether the method is computed from raw scans (one of [`REGISTRY`]).
    pub fn is_computed(&self) -> bool {
        self.as_computed().is_some()
    }

    /// The descriptor of a raw scan (sensor frame, metres) for the methods computed from it;
    /// `None` for the others. An error, with the reason, when the method could not describe
    /// the scan.
    pub fn describe_raw(&self, points: &[Point]) -> Option<Result<Vec<f32>, String>> {
        self.as_computed().map(|c| c.describe(points))
    }

    /// The method's search structure over `descriptors` (`n × length`, row-major): its own for
    /// a computed method, exact Euclidean k-NN for the others.
    pub fn searcher(&self, descriptors: Vec<f32>, length: usize) -> Box<dyn Searcher> {
        match &self.kind {
            MethodKind::Computed(c) => c.searcher(descriptors),
            _ => Box::new(euclidean::Euclidean::new(descriptors, length)),
        }
    }

    /// The steps a search of this method reports times for (see [`Computed::search_steps`]).
    pub fn search_steps(&self) -> &'static [&'static str] {
        self.as_computed().map_or(&["search"], |c| c.search_steps())
    }
}

/// The descriptor methods a pipeline computes: the TopoRec one (persistence + ATOL) or not,
/// and the ones computed from raw scans.
#[derive(Clone, Debug, PartialEq)]
pub struct Methods {
    /// Whether the TopoRec descriptor (and so the persistence stage) is wanted.
    pub toporec: bool,
    /// The methods computed from raw scans, as asked for.
    pub computed: Vec<Method>,
}

impl Default for Methods {
    fn default() -> Self {
        Methods { toporec: true, computed: Vec::new() }
    }
}

impl Methods {
    /// The method names, in the order asked for (`toporec` first when wanted).
    pub fn names(&self) -> Vec<String> {
        let mut out: Vec<String> = if self.toporec { vec![TOPOREC.into()] } else { Vec::new() };
        out.extend(self.computed.iter().map(|m| m.name.clone()));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_entry_names_its_method_and_parses_its_defaults() {
        for r in REGISTRY {
            let m = r.default_method();
            assert_eq!(m.name, r.name);
            assert_eq!(m, Method::from_settings(r.name, &serde_json::Value::Null).unwrap());
            assert_eq!(
                m,
                Method::from_settings(r.name, &m.params()).unwrap(),
                "{}: settings round trip",
                r.name
            );
            assert!(m.as_computed().unwrap().problems().is_empty(), "{}", r.name);
            assert_ne!(r.name, TOPOREC);
            assert_ne!(r.name, IMPORTED);
        }
    }
}
