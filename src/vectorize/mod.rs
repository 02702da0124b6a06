//! Vectorization: persistence diagrams → fixed-length descriptors.
//!
//! Owns the ATOL model (centres, inertias, contrast, weighting) and its transform. Fitting the
//! centres (k-means) is not here yet; [`atol::Atol::from_centers`] builds a model from given
//! centres exactly as GUDHI's `Atol.fit` does after its quantiser has run.

pub mod atol;
