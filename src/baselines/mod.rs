//! The descriptors place recognition is usually compared against, beside the TopoRec one:
//! [`scancontext`] (Kim & Kim 2018), [`scancontext_pp`] (Scan Context++, Kim, Choi, Kim 2021:
//! its polar and its Cartesian context), [`m2dp`] (He et al. 2016) and [`solid`] (Kim, Choi,
//! Kim 2024) and [`lidar_iris`] (Wang et al. 2020), each computed from the raw scan in the sensor frame with its own preprocessing; and descriptors made elsewhere
//! (PointNetVLAD, PCAN, MinkLoc3D, …), imported into an index with `toporec import`.
//!
//! A [`Method`] names one of them with its parameters; an index stores each method's
//! descriptors apart (`descriptors/method=<name>/session=<s>/`), and `query` and `eval` take
//! `--method`.

pub mod lidar_iris;
pub mod m2dp;
pub mod scancontext;
pub mod scancontext_pp;
pub mod solid;

use crate::preprocess::voxel_grid;
use crate::toporec_plus::PlusParams;
use crate::types::Point;
use lidar_iris::IrisParams;
use scancontext::ScanContextParams;
use scancontext_pp::{CartParams, PolarParams};
use solid::SolidParams;

/// The name of the TopoRec paper's descriptor (alpha persistence + ATOL).
pub const TOPOREC: &str = "toporec";
/// The name of ScanContext.
pub const SCANCONTEXT: &str = "scancontext";
/// The name of Scan Context++'s polar context.
pub const SCANCONTEXT_PP: &str = "scancontext-pp";
/// The name of Scan Context++'s Cartesian context.
pub const SCANCONTEXT_PP_CART: &str = "scancontext-pp-cart";
/// The name of M2DP.
pub const M2DP: &str = "m2dp";
/// The name of SOLiD.
pub const SOLID: &str = "solid";
/// The name of LiDAR-Iris.
pub const LIDAR_IRIS: &str = "lidar-iris";
/// The name of the topological scan context ([`crate::toporec_plus`]).
pub const TOPOREC_PLUS: &str = crate::toporec_plus::NAME;
/// The methods computed from raw scans, by name, in the order messages list them.
pub const COMPUTED: [&str; 7] =
    [TOPOREC_PLUS, SCANCONTEXT, SCANCONTEXT_PP, SCANCONTEXT_PP_CART, M2DP, SOLID, LIDAR_IRIS];

/// Whether the descriptors of the method named `name` are bytes, stored as `uint8` rather than
/// `float32`: LiDAR-Iris's image and its bit-packed template and mask (a name an imported
/// method cannot take).
pub fn stores_bytes(name: &str) -> bool {
    name == LIDAR_IRIS
}

/// M2DP settings (`[m2dp]` of a pipeline file).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct M2dpParams {
    /// Voxel-grid cell of the preprocessing (m); none when 0 (the reference uses the raw cloud).
    pub voxel: f64,
}

impl Default for M2dpParams {
    fn default() -> Self {
        M2dpParams { voxel: 0.0 }
    }
}

impl M2dpParams {
    /// The settings' problems, each with its key.
    pub fn problems(&self) -> Vec<String> {
        if self.voxel.is_finite() && self.voxel >= 0.0 {
            Vec::new()
        } else {
            vec![format!("m2dp.voxel: must be in [0, inf) m; found {}", self.voxel)]
        }
    }
}

/// What a method computes.
#[derive(Clone, Debug, PartialEq)]
pub enum MethodKind {
    /// The TopoRec paper's descriptor: the pipeline's preprocess, persistence and codebook.
    Toporec,
    /// ScanContext.
    ScanContext(ScanContextParams),
    /// Scan Context++, its polar context.
    ScanContextPp(PolarParams),
    /// Scan Context++, its Cartesian context.
    ScanContextPpCart(CartParams),
    /// M2DP.
    M2dp(M2dpParams),
    /// SOLiD.
    Solid(SolidParams),
    /// LiDAR-Iris.
    LidarIris(IrisParams),
    /// toporec-plus, the topological scan context.
    ToporecPlus(PlusParams),
    /// Vectors made elsewhere, imported (`toporec import`): stored, never computed.
    Imported {
        /// Their length.
        length: usize,
        /// Where they came from (the file imported).
        source: String,
    },
}

/// A descriptor method of an index.
#[derive(Clone, Debug, PartialEq)]
pub struct Method {
    /// Its name (`toporec`, `scancontext`, `m2dp`, or an imported one's).
    pub name: String,
    /// What it computes.
    pub kind: MethodKind,
}

/// The kind name of imported methods in the manifest.
pub const IMPORTED: &str = "imported";

impl Method {
    /// ScanContext with these parameters.
    pub fn scancontext(p: ScanContextParams) -> Self {
        Method { name: SCANCONTEXT.into(), kind: MethodKind::ScanContext(p) }
    }

    /// Scan Context++'s polar context with these parameters.
    pub fn scancontext_pp(p: PolarParams) -> Self {
        Method { name: SCANCONTEXT_PP.into(), kind: MethodKind::ScanContextPp(p) }
    }

    /// Scan Context++'s Cartesian context with these parameters.
    pub fn scancontext_pp_cart(p: CartParams) -> Self {
        Method { name: SCANCONTEXT_PP_CART.into(), kind: MethodKind::ScanContextPpCart(p) }
    }

    /// M2DP with these parameters.
    pub fn m2dp(p: M2dpParams) -> Self {
        Method { name: M2DP.into(), kind: MethodKind::M2dp(p) }
    }

    /// SOLiD with these parameters.
    pub fn solid(p: SolidParams) -> Self {
        Method { name: SOLID.into(), kind: MethodKind::Solid(p) }
    }

    /// LiDAR-Iris with these parameters.
    pub fn lidar_iris(p: IrisParams) -> Self {
        Method { name: LIDAR_IRIS.into(), kind: MethodKind::LidarIris(p) }
    }

    /// toporec-plus with these parameters.
    pub fn toporec_plus(p: PlusParams) -> Self {
        Method { name: TOPOREC_PLUS.into(), kind: MethodKind::ToporecPlus(p) }
    }

    /// A method computed from raw scans by its name (one of [`COMPUTED`]) and its settings (the
    /// keys of its pipeline-file section, as JSON; `null` or `{}` for the defaults); an error
    /// naming each problem.
    pub fn from_settings(name: &str, settings: &serde_json::Value) -> Result<Method, String> {
        let method = Self::with_settings(name, settings)?;
        let problems = match &method.kind {
            MethodKind::ToporecPlus(p) => p.problems(),
            MethodKind::ScanContext(p) => p.problems(),
            MethodKind::ScanContextPp(p) => p.problems(),
            MethodKind::ScanContextPpCart(p) => p.problems(),
            MethodKind::Solid(p) => p.problems(),
            MethodKind::LidarIris(p) => p.problems(),
            MethodKind::M2dp(p) => p.problems(),
            MethodKind::Toporec | MethodKind::Imported { .. } => Vec::new(),
        };
        if problems.is_empty() { Ok(method) } else { Err(problems.join("; ")) }
    }

    /// [`Method::from_settings`] without checking the values: an error only for an unknown name
    /// or settings that do not parse (an index's manifest records settings checked when written).
    pub fn with_settings(name: &str, settings: &serde_json::Value) -> Result<Method, String> {
        fn parse<T: serde::de::DeserializeOwned + Default>(
            name: &str,
            v: &serde_json::Value,
        ) -> Result<T, String> {
            if v.is_null() {
                return Ok(T::default());
            }
            serde_json::from_value(v.clone()).map_err(|e| format!("{name}: {e}"))
        }
        Ok(match name {
            TOPOREC_PLUS => Method::toporec_plus(parse(name, settings)?),
            SCANCONTEXT => Method::scancontext(parse(name, settings)?),
            SCANCONTEXT_PP => Method::scancontext_pp(parse(name, settings)?),
            SCANCONTEXT_PP_CART => Method::scancontext_pp_cart(parse(name, settings)?),
            SOLID => Method::solid(parse(name, settings)?),
            LIDAR_IRIS => Method::lidar_iris(parse(name, settings)?),
            M2DP => Method::m2dp(parse(name, settings)?),
            _ => {
                return Err(format!(
                    "unknown method `{name}` (computed from raw scans: {})",
                    COMPUTED.join(", ")
                ));
            }
        })
    }

    /// The kind's name (`scancontext`, `scancontext-pp`, `scancontext-pp-cart`, `m2dp`, `solid`,
    /// `lidar-iris`, `toporec-plus`, `imported`, `toporec`).
    pub fn kind_name(&self) -> &'static str {
        match self.kind {
            MethodKind::Toporec => TOPOREC,
            MethodKind::ScanContext(_) => SCANCONTEXT,
            MethodKind::ScanContextPp(_) => SCANCONTEXT_PP,
            MethodKind::ScanContextPpCart(_) => SCANCONTEXT_PP_CART,
            MethodKind::M2dp(_) => M2DP,
            MethodKind::Solid(_) => SOLID,
            MethodKind::LidarIris(_) => LIDAR_IRIS,
            MethodKind::ToporecPlus(_) => TOPOREC_PLUS,
            MethodKind::Imported { .. } => IMPORTED,
        }
    }

    /// The method's parameters as JSON (recorded in the manifest).
    pub fn params(&self) -> serde_json::Value {
        match &self.kind {
            MethodKind::Toporec => serde_json::json!({}),
            MethodKind::ScanContext(p) => serde_json::to_value(p).expect("plain data"),
            MethodKind::ScanContextPp(p) => serde_json::to_value(p).expect("plain data"),
            MethodKind::ScanContextPpCart(p) => serde_json::to_value(p).expect("plain data"),
            MethodKind::M2dp(p) => serde_json::to_value(p).expect("plain data"),
            MethodKind::Solid(p) => serde_json::to_value(p).expect("plain data"),
            MethodKind::LidarIris(p) => serde_json::to_value(p).expect("plain data"),
            MethodKind::ToporecPlus(p) => serde_json::to_value(p).expect("plain data"),
            MethodKind::Imported { source, .. } => serde_json::json!({ "source": source }),
        }
    }

    /// Descriptor length (0 for TopoRec, whose length is its codebook's).
    pub fn len(&self) -> usize {
        match &self.kind {
            MethodKind::Toporec => 0,
            MethodKind::ScanContext(p) => p.len(),
            MethodKind::ScanContextPp(p) => p.len(),
            MethodKind::ScanContextPpCart(p) => p.len(),
            MethodKind::M2dp(_) => m2dp::LEN,
            MethodKind::Solid(p) => p.len(),
            MethodKind::LidarIris(p) => p.len(),
            MethodKind::ToporecPlus(p) => p.len(),
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

    /// Whether the method is computed from raw scans (ScanContext, Scan Context++, M2DP, SOLiD,
    /// LiDAR-Iris, toporec-plus).
    pub fn is_computed(&self) -> bool {
        matches!(
            self.kind,
            MethodKind::ScanContext(_)
                | MethodKind::ScanContextPp(_)
                | MethodKind::ScanContextPpCart(_)
                | MethodKind::M2dp(_)
                | MethodKind::Solid(_)
                | MethodKind::LidarIris(_)
                | MethodKind::ToporecPlus(_)
        )
    }

    /// The descriptor of a raw scan (sensor frame, metres) for the methods computed from it
    /// (ScanContext, Scan Context++, M2DP, SOLiD, LiDAR-Iris, toporec-plus), after the method's own preprocessing (its voxel
    /// grid); `None` for the others. An error, with the reason, when the method could not
    /// describe the scan (toporec-plus: no return within its radius).
    pub fn describe_raw(&self, points: &[Point]) -> Option<Result<Vec<f32>, String>> {
        let grid = |voxel: f64| if voxel > 0.0 { voxel_grid(points, voxel) } else { points.to_vec() };
        match &self.kind {
            MethodKind::ScanContext(p) => Some(Ok(scancontext::describe(&grid(p.voxel), p))),
            MethodKind::ScanContextPp(p) => Some(Ok(scancontext_pp::describe_polar(points, p))),
            MethodKind::ScanContextPpCart(p) => Some(Ok(scancontext_pp::describe_cart(points, p))),
            MethodKind::M2dp(p) => Some(Ok(m2dp::describe(&grid(p.voxel)))),
            MethodKind::Solid(p) => Some(Ok(solid::describe(&solid::preprocess(points, p), p))),
            MethodKind::LidarIris(p) => Some(Ok(lidar_iris::describe(points, p))),
            MethodKind::ToporecPlus(p) => Some(crate::toporec_plus::describe(points, p)),
            _ => None,
        }
    }
}

impl Method {
    /// Scan Context++'s settings, for its two methods.
    pub fn scancontext_pp_variant(&self) -> Option<scancontext_pp::Variant> {
        match &self.kind {
            MethodKind::ScanContextPp(p) => Some(scancontext_pp::Variant::Polar(p.clone())),
            MethodKind::ScanContextPpCart(p) => Some(scancontext_pp::Variant::Cart(p.clone())),
            _ => None,
        }
    }
}

/// The descriptor methods a pipeline computes: the TopoRec one (persistence + ATOL) or not,
/// and the ones computed from raw scans.
#[derive(Clone, Debug, PartialEq)]
pub struct Methods {
    /// Whether the TopoRec descriptor (and so the persistence stage) is wanted.
    pub toporec: bool,
    /// ScanContext and M2DP, as asked for.
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
