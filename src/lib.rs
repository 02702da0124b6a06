//! # toporec — topological place descriptors from LiDAR logs
//!
//! toporec answers "have I been here before?" with the persistent homology of each scan's
//! 3D alpha complex, vectorized by ATOL and searched by nearest neighbours (the TopoRec
//! method, training-free), beside toporec's own descriptor and the usual baselines.
//!
//! Data flows one way:
//!
//! ```text
//!  sources ──► preprocess ──► homology ──► vectorize ──┐
//!  NCLT, MCAP,  crop, ground,  alpha        ATOL with a  ├─► describe ──► sinks ──► search ──► query, eval,
//!  KITTI, CSV   voxel, sample  persistence  codebook     │   one scan's   Parquet   Engine      loops, batch
//!       └──── raw scan ──► methods: toporec-plus and the baselines (methods::REGISTRY) ┘
//! ```
//!
//! * [`sources`] decode scans from the files users have (a bad scan is a stream item, not an
//!   abort); they know nothing of topology. Each kind is a module and one line of
//!   [`sources::SOURCES`]; [`sources::Input`] decides what a path is.
//! * [`preprocess`] crops, removes the ground, downsamples, normalizes.
//! * [`homology`] is the engine: Delaunay triangulation, alpha filtration, persistence pairs,
//!   equal to GUDHI's `AlphaComplex` in its `exact` precision.
//! * [`vectorize`] turns diagrams into ATOL descriptors with a saved codebook.
//! * [`methods`] holds every descriptor method computed from the raw scan (toporec's own
//!   [`methods::toporec_plus`] and the baselines) behind one interface ([`methods::Computed`])
//!   and one registry ([`methods::REGISTRY`]), and the one search interface every method's
//!   structure implements ([`methods::Searcher`]), exact Euclidean k-NN included.
//! * [`describe`] is the one path from a scan to its descriptors and index rows through those
//!   stages; `run`, `query`, `eval`, `loops` and [`batch`] all use it.
//! * [`sinks`] write and read the index: Hive-partitioned Parquet tables whose schemas (and
//!   every other table toporec writes or takes) are declared once ([`sinks::schema`]),
//!   committed atomically.
//! * [`pipeline`] connects the stages with bounded channels (`toporec run`), as a pipeline
//!   file ([`pipeline::config`]) describes. [`batch`] runs the same per-scan step on batches
//!   handed over in memory and returns the rows as Arrow batches (the Python package and
//!   distributed engines call it).
//! * [`search`] is search over an index in one place: the [`Engine`] loads a method's
//!   descriptors (or maps its cached structure), describes new scans as the index did, and
//!   answers at a search budget.
//!
//! Downstream of the index: [`query`], [`eval`] (Recall@N, Recall@1 %, conditions), [`loops`]
//! (loop closures over an index, and the online [`Detector`]), [`plot`]; [`import`] adds
//! descriptors made elsewhere; [`maintenance`] verifies, compacts and revectorizes an index,
//! and [`repair`] rebuilds its damaged parts;
//! [`info`] and [`inspect`] describe indexes and files, and [`diagram_csv`] reads and writes
//! diagrams as CSV. Beside it: [`offline`] fits codebooks and
//! vectorizes stored diagrams, [`simulate`] makes multi-session drives in the formats the
//! sources read, and [`split`] makes a map and a query session of one drive. At the bottom, shared by all: [`types`], [`error`], [`fsutil`] (atomic files),
//! [`rng`], [`fingerprint`], [`checked_map`] (mapped bytes checked block by block as they are
//! read). The `toporec` binary is a thin command line over this library; the
//! names a user starts from are re-exported here.
#![deny(missing_docs)]
#![warn(unreachable_pub)]

pub mod batch;
pub mod checked_map;
pub mod describe;
pub mod diagram_csv;
pub mod error;
pub mod eval;
pub(crate) mod fault;
pub mod fingerprint;
pub mod flags;
pub mod fsutil;
pub mod homology;
pub mod import;
pub mod info;
pub mod inspect;
pub mod loops;
pub mod maintenance;
pub mod map;
pub mod methods;
pub mod offline;
pub mod pipeline;
pub mod plot;
pub mod preprocess;
pub mod query;
pub mod ranges;
pub mod repair;
pub mod rng;
pub mod search;
pub mod simulate;
pub mod sinks;
pub mod sources;
pub mod split;
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
