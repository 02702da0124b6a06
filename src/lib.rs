//! # toporec — topological place descriptors from LiDAR logs
//!
//! toporec answers "have I been here before?" with the persistent homology of each scan's
//! 3D alpha complex, vectorized by ATOL and searched by nearest neighbours (the TopoRec
//! method, training-free).
//!
//! Data flows one way:
//!
//! ```text
//! sources ──► preprocess ──► homology (alpha persistence) ──► vectorize (ATOL) ──► sinks
//! (NCLT, MCAP, KITTI, CSV)                                                     (Parquet)
//! ```
//!
//! * [`sources`] decode scans from files (streams; a bad scan is an item, not an abort);
//!   they know nothing of topology.
//! * [`preprocess`] crops, removes the ground, downsamples, normalizes.
//! * [`homology`] is the engine: Delaunay triangulation, alpha filtration, persistence pairs.
//! * [`vectorize`] turns diagrams into ATOL descriptors with a saved codebook.
//! * [`sinks`] write the index: Hive-partitioned Parquet tables, committed atomically.
//! * [`pipeline`] connects the stages with bounded channels (`toporec run`).
//!
//! Downstream of the index: [`search`] (exact k-NN), [`query`], [`eval`] (Recall@N,
//! Recall@1 %), [`plot`]. Beside it: [`simulate`] makes multi-session drives in the formats
//! the sources read, and [`inspect`] describes files. [`cli`] wires all of it into `toporec`.
#![deny(missing_docs)]

pub mod describe;
pub mod diagram_csv;
pub mod error;
pub mod eval;
pub mod fsutil;
pub mod homology;
pub mod inspect;
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
