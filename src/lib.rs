//! # toporec — topological place descriptors from LiDAR logs
//!
//! toporec answers "have I been here before?" with the persistent homology of each scan's
//! 3D alpha complex, vectorized by ATOL and searched by nearest neighbours (the TopoRec
//! method, training-free).
//!
//! Data flows one way:
//!
//! ```text
//!  sources ──► preprocess ──► homology ──► vectorize ──► sinks ──► search / query / eval
//!  NCLT, MCAP,  crop, ground,  alpha        ATOL with a   Parquet    k-NN, Recall@N,
//!  KITTI, CSV   voxel, sample  persistence  codebook      index      plots
//! ```
//!
//! * [`sources`] decode scans from the files users have (a bad scan is a stream item, not an
//!   abort); they know nothing of topology. [`sources::InputKind`] decides what a path is.
//! * [`preprocess`] crops, removes the ground, downsamples, normalizes.
//! * [`homology`] is the engine: Delaunay triangulation, alpha filtration, persistence pairs,
//!   equal to GUDHI's `AlphaComplex` in its `exact` precision.
//! * [`vectorize`] turns diagrams into ATOL descriptors with a saved codebook.
//! * [`describe`] is the one path from a scan to its descriptors through those three stages;
//!   `run`, `query` and `eval` all use it. Beside the TopoRec descriptor it computes the
//!   [`baselines`] (ScanContext, M2DP) from the raw scan, when a pipeline asks for them.
//! * [`sinks`] write and read the index: Hive-partitioned Parquet tables whose schemas are
//!   declared once ([`sinks::schema`]), committed atomically.
//! * [`pipeline`] connects the stages with bounded channels (`toporec run`), as a pipeline
//!   file ([`pipeline::config`]) describes. [`batch`] runs the same per-scan step on batches
//!   handed over in memory and returns the rows as Arrow batches (the Python package and
//!   distributed engines call it).
//!
//! Downstream of the index: [`search`] (exact k-NN), [`query`], [`eval`] (Recall@N,
//! Recall@1 %), [`plot`]; [`import`] adds descriptors made elsewhere. Beside it: [`offline`] fits codebooks and vectorizes stored
//! diagrams, [`simulate`] makes multi-session drives in the formats the sources read, and
//! [`inspect`] describes files. At the bottom, shared by all: [`types`], [`error`],
//! [`fsutil`] (atomic files), [`rng`]. The `toporec` binary is a thin command line over this
//! library.
#![deny(missing_docs)]
#![warn(unreachable_pub)]

pub mod batch;
pub mod describe;
pub mod diagram_csv;
pub mod error;
pub mod eval;
pub(crate) mod fault;
pub mod fingerprint;
pub mod fsutil;
pub mod homology;
pub mod import;
pub mod info;
pub mod inspect;
pub mod loops;
pub mod maintenance;
pub mod methods;
pub mod offline;
pub mod pipeline;
pub mod plot;
pub mod preprocess;
pub mod query;
pub mod rng;
pub mod search;
pub mod simulate;
pub mod sinks;
pub mod sources;
pub mod types;
pub mod vectorize;

pub use error::{Error, Result};

// The names a user of the library (and the Python package, the benches) starts from.
pub use batch::{BatchDescriber, BatchOutput, ScanInput};
pub use describe::Describer;
pub use homology::{Diagram, alpha_persistence};
pub use loops::{Detector, Exclusion};
pub use methods::{Computed, Hit, Method, REGISTRY, SearchBudget, Searcher};
pub use pipeline::config::Pipeline;
pub use pipeline::{RunOptions, RunSummary};
pub use search::Engine;
pub use sinks::index::{IndexReader, IndexWriter};
pub use sources::{Scan, ScanStream};
pub use vectorize::codebook::Codebook;
/// Whether this build has the named crash points of the kill tests (the `fault-injection`
/// feature).
pub const FAULT_INJECTION: bool = fault::ENABLED;
