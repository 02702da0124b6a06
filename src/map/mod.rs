//! The map: loops made into a corrected trajectory. A pose graph — a vertex per scan at its
//! pose, an edge between consecutive scans of a session with their relative pose, an edge per
//! kept loop with the alignment's — optimized so that no false loop bends it ([`solve`]: robust
//! Levenberg–Marquardt over [`lie`]'s SE(2) and SE(3), the normal equations solved by
//! [`sparse`]'s block Cholesky); g2o's format read and written ([`g2o`]), so any graph can be
//! optimized (`toporec optimize`), from its own initial guess or from [`initialize`]'s chordal
//! relaxation.

mod command;
pub mod g2o;
pub mod initialize;
pub mod lie;
pub mod solve;
pub mod sparse;

pub use command::{OptimizeArgs, Optimized, Start, optimize, optimize_graph};
