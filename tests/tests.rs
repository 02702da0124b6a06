//! One integration-test binary (fast to link); a module per area.

mod atol;
mod bad_input;
mod bags;
mod baselines;
mod cli;
mod clouds;
mod codebook;
mod damage;
mod docs;
mod eval;
mod homology;
mod incremental;
mod index;
mod integrity;
mod layout;
mod loops;
mod oneshot;
mod pipeline;
mod pointnetvlad;
mod poses;
mod ring;
mod shard;
mod simulate;
mod sources;
mod toporec_plus;
mod util;
