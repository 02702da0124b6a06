//! The index's tables, declared once: column names, Arrow types, nullability, meaning.
//! `schemas/*.json` is rendered from here ([`render_json`]) and a test keeps them equal.
//! Every table is partitioned Hive style by `session` (`<table>/session=<name>/part-N.parquet`):
//! the session column comes from the path, as Spark, DuckDB, DataFusion, Polars and pyarrow
//! expect, and is not repeated inside the files.

use arrow::datatypes::{DataType, Field, Schema};
use std::sync::Arc;

/// Version of the table layout, written into every file's key-value metadata.
pub const SCHEMA_VERSION: &str = "1";
/// Key-value metadata keys.
pub mod meta {
    /// Table layout version.
    pub const SCHEMA_VERSION: &str = "toporec.schema_version";
    /// Table name.
    pub const TABLE: &str = "toporec.table";
    /// toporec version that wrote the file.
    pub const WRITER: &str = "toporec.version";
    /// Codebook id (descriptors only).
    pub const CODEBOOK_ID: &str = "toporec.codebook_id";
}

/// One column.
pub struct Column {
    /// Name.
    pub name: &'static str,
    /// Arrow type.
    pub data_type: DataType,
    /// Whether nulls occur.
    pub nullable: bool,
    /// What it holds.
    pub doc: &'static str,
}

/// A table of the index.
pub struct Table {
    /// Folder name under the index.
    pub name: &'static str,
    /// What a row is.
    pub doc: &'static str,
    /// Columns (without the `session` partition column).
    pub columns: Vec<Column>,
}

fn col(name: &'static str, data_type: DataType, nullable: bool, doc: &'static str) -> Column {
    Column { name, data_type, nullable, doc }
}

/// `scans`: one row per scan read (ok, skipped or error).
pub fn scans() -> Table {
    use DataType::*;
    Table {
        name: "scans",
        doc: "One row per scan read, whatever happened to it.",
        columns: vec![
            col(
                "scan_id",
                Utf8,
                false,
                "stable id: <session>/<utime> (NCLT), <session>/<frame> (KITTI), <session>/<index> (MCAP)",
            ),
            col("seq", UInt64, false, "position in the run's input order"),
            col("source_path", Utf8, false, "file the scan came from"),
            col("message_index", UInt64, true, "MCAP: index of the message among the topic's point clouds"),
            col(
                "utime",
                Int64,
                true,
                "timestamp, microseconds since the Unix epoch (KITTI: since the sequence start)",
            ),
            col("pose_x", Float64, true, "ground-truth position x (m, z-up world frame of the source)"),
            col("pose_y", Float64, true, "ground-truth position y (m)"),
            col("pose_z", Float64, true, "ground-truth position z (m)"),
            col("pose_yaw", Float64, true, "ground-truth heading about z (rad)"),
            col("raw_points", UInt64, false, "points in the record, before dropping NaN/zero points"),
            col("kept_points", UInt64, false, "points after preprocessing (the alpha complex's input)"),
            col("status", Utf8, false, "ok | skipped | error"),
            col("error", Utf8, true, "why the scan was skipped or failed (names the file and message/line)"),
        ],
    }
}

/// `diagrams`: one row per persistence pair.
pub fn diagrams() -> Table {
    use DataType::*;
    Table {
        name: "diagrams",
        doc: "One row per persistence pair of an ok scan (zero-length pairs dropped, as GUDHI).",
        columns: vec![
            col("scan_id", Utf8, false, "the scan"),
            col("dim", UInt8, false, "homology dimension 0, 1 or 2"),
            col("birth", Float64, false, "birth (squared radius unless persistence.squared = false)"),
            col("death", Float64, false, "death; +inf for the essential H0 class"),
        ],
    }
}

/// `descriptors`: one row per ok scan; `b` is the descriptor length.
pub fn descriptors(b: usize) -> Table {
    use DataType::*;
    let item = Arc::new(Field::new("item", Float32, false));
    Table {
        name: "descriptors",
        doc: "One ATOL descriptor per ok scan.",
        columns: vec![
            col("scan_id", Utf8, false, "the scan"),
            col("utime", Int64, true, "timestamp (µs)"),
            col("pose_x", Float64, true, "ground-truth x (m)"),
            col("pose_y", Float64, true, "ground-truth y (m)"),
            col("pose_z", Float64, true, "ground-truth z (m)"),
            col(
                "dim_used",
                UInt8,
                true,
                "paper rule: the diagram dimension vectorized (null with concatenated dims)",
            ),
            col("descriptor", FixedSizeList(item, b as i32), false, "the ATOL vector (length b, float32)"),
            col("codebook_id", Utf8, false, "id of codebook.json it was made with"),
        ],
    }
}

impl Table {
    /// The Arrow schema with toporec's key-value metadata.
    pub fn arrow_schema(&self, extra: &[(&str, String)]) -> Arc<Schema> {
        let fields: Vec<Field> =
            self.columns.iter().map(|c| Field::new(c.name, c.data_type.clone(), c.nullable)).collect();
        let mut metadata = std::collections::HashMap::from([
            (meta::SCHEMA_VERSION.to_string(), SCHEMA_VERSION.to_string()),
            (meta::TABLE.to_string(), self.name.to_string()),
            (meta::WRITER.to_string(), env!("CARGO_PKG_VERSION").to_string()),
        ]);
        metadata.extend(extra.iter().map(|(k, v)| (k.to_string(), v.clone())));
        Arc::new(Schema::new_with_metadata(fields, metadata))
    }
}

fn type_name(t: &DataType) -> String {
    match t {
        DataType::FixedSizeList(item, _) => format!("fixed_size_list<{}>[b]", type_name(item.data_type())),
        other => other.to_string().to_lowercase(),
    }
}

/// The JSON rendering kept in `schemas/<table>.json`.
pub fn render_json(t: &Table) -> String {
    let columns: Vec<serde_json::Value> = t
        .columns
        .iter()
        .map(|c| serde_json::json!({"name": c.name, "type": type_name(&c.data_type), "nullable": c.nullable, "description": c.doc}))
        .collect();
    let v = serde_json::json!({
        "table": t.name,
        "description": t.doc,
        "schema_version": SCHEMA_VERSION,
        "layout": format!("{}/session=<session>/part-<n>.parquet (zstd)", t.name),
        "partition_columns": [{"name": "session", "type": "utf8", "description": "NCLT date folder, KITTI sequence, or MCAP file stem (from the path)"}],
        "columns": columns,
    });
    serde_json::to_string_pretty(&v).expect("JSON") + "\n"
}

/// All tables (descriptors with a placeholder length).
pub fn all() -> Vec<Table> {
    vec![scans(), diagrams(), descriptors(1)]
}
