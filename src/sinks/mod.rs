//! Sinks: the index — Parquet tables (zstd, Hive-partitioned by session), the codebook and
//! the effective pipeline. [`schema`] declares the tables once; [`parquet`] writes them;
//! [`index`] lays out the folder and commits a run atomically.

pub mod csv;
pub mod index;
pub mod parquet;
pub mod schema;
