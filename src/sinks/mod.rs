//! Sinks: the index — Parquet tables (zstd, Hive-partitioned by session), the codebook and
//! the effective pipeline. [`schema`] declares the tables once; [`rows`] builds and reads their
//! rows by column name; [`parquet`] writes them; [`index`] lays out the folder and commits a run
//! atomically.

pub mod csv;
pub mod index;
pub mod parquet;
pub mod rows;
pub mod schema;
