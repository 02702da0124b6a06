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
//! * [`sources`] decode point clouds from files; they know nothing of topology.
//! * [`homology`] is the engine: Delaunay triangulation, alpha filtration, persistence pairs.
//! * [`vectorize`] turns diagrams into ATOL descriptors.
//! * [`cli`] wires them into the `toporec` command.
#![deny(missing_docs)]

pub mod cli;
pub mod diagram_csv;
pub mod eval;
pub mod fsutil;
pub mod homology;
pub mod inspect;
pub mod pipeline;
pub mod plot;
pub mod preprocess;
pub mod query;
pub mod rng;
pub mod search;
pub mod simulate;
pub mod sinks;
pub mod sources;
pub mod vectorize;
