//! Vectorization: persistence diagrams → fixed-length descriptors.
//!
//! * [`atol`]: the ATOL model and transform, equal to `gudhi.representations.Atol`.
//! * [`kmeans`]: the quantiser fitting ATOL's centres (mini-batch as scikit-learn, or Lloyd).
//! * [`reservoir`]: the bounded uniform sample the quantiser is fitted on.
//! * [`codebook`]: the saved model — dimension rule, one ATOL per part, JSON file.

pub mod atol;
pub mod codebook;
pub mod kmeans;
pub mod reservoir;
