//! One integration-test binary (fast to link); a module per area.

mod cli;
mod homology;
mod util;
