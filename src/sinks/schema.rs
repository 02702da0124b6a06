//! Every table toporec reads or writes, declared once: column names, Arrow types, nullability,
//! meaning. `schemas/*.json` is rendered from here ([`render_json`]) and a test keeps them equal.
//!
//! * The index's tables ([`scans`], [`diagrams`], [`descriptors`]) are partitioned Hive style
//!   by `session` (`<table>/session=<name>/part-N.parquet`; descriptors by method too,
//!   `descriptors/method=<m>/session=<name>/`): partition columns come from the path, as Spark,
//!   DuckDB, DataFusion, Polars and pyarrow expect, and are not repeated inside the files.
//! * The tables of commands: `query`'s hits ([`query_hits`]: CSV, and Arrow from Python) and
//!   `loops`' rows ([`loops`]: Parquet or CSV); their CSV is rendered from the same record
//!   batch ([`super::csv`]).
//! * The input contract of [`crate::batch`] ([`batch_inputs`]): the Arrow batches the Python
//!   package and the distributed engines hand over.

use arrow::datatypes::{DataType, Field, Schema};
use std::sync::Arc;

/// Version of the table layout, written into every file's key-value metadata.
pub(crate) const SCHEMA_VERSION: &str = "2";
/// Key-value metadata keys.
pub mod meta {
    /// Table layout version.
    pub const SCHEMA_VERSION: &str = "toporec.schema_version";
    /// Table name.
    pub const TABLE: &str = "toporec.table";
    /// toporec version that wrote the file.
    pub const WRITER: &str = "toporec.version";
    /// Codebook id (TopoRec descriptors) or method id (other methods' descriptors).
    pub const CODEBOOK_ID: &str = "toporec.codebook_id";
    /// The descriptor method (descriptors only).
    pub const METHOD: &str = "toporec.method";
}

/// Column names, the one place they are spelled (writers and readers use these).
pub mod columns {
    /// The Hive partition column of every table (`session=<s>/` in the path, not in the files).
    pub const SESSION: &str = "session";
    /// The scan's id (every table).
    pub const SCAN_ID: &str = "scan_id";
    /// xxh3-64 of the scan's raw bytes (`scans`).
    pub const FINGERPRINT: &str = "fingerprint";
    /// Fingerprint of the settings that made the row (`scans`).
    pub const SETTINGS_HASH: &str = "settings_hash";
    /// Position in the run's input order (`scans`).
    pub const SEQ: &str = "seq";
    /// The scan's file (`scans`).
    pub const SOURCE_PATH: &str = "source_path";
    /// MCAP message index (`scans`).
    pub const MESSAGE_INDEX: &str = "message_index";
    /// Timestamp, µs (`scans`, `descriptors`).
    pub const UTIME: &str = "utime";
    /// Pose x (`scans`, `descriptors`).
    pub const POSE_X: &str = "pose_x";
    /// Pose y.
    pub const POSE_Y: &str = "pose_y";
    /// Pose z.
    pub const POSE_Z: &str = "pose_z";
    /// Pose heading (`scans`).
    pub const POSE_YAW: &str = "pose_yaw";
    /// Points in the record (`scans`).
    pub const RAW_POINTS: &str = "raw_points";
    /// Points after preprocessing (`scans`).
    pub const KEPT_POINTS: &str = "kept_points";
    /// ok | skipped | error (`scans`).
    pub const STATUS: &str = "status";
    /// Why skipped or failed (`scans`).
    pub const ERROR: &str = "error";
    /// Homology dimension (`diagrams`).
    pub const DIM: &str = "dim";
    /// Birth (`diagrams`).
    pub const BIRTH: &str = "birth";
    /// Death (`diagrams`).
    pub const DEATH: &str = "death";
    /// Paper rule's dimension (`descriptors`).
    pub const DIM_USED: &str = "dim_used";
    /// The vector (`descriptors`).
    pub const DESCRIPTOR: &str = "descriptor";
    /// Codebook id (`descriptors`).
    pub const CODEBOOK_ID: &str = "codebook_id";
}

/// Table names (folders under the index).
pub mod tables {
    /// One row per scan read.
    pub const SCANS: &str = "scans";
    /// One row per persistence pair.
    pub const DIAGRAMS: &str = "diagrams";
    /// One row per ok scan.
    pub const DESCRIPTORS: &str = "descriptors";
    /// All three, in the order a run writes them.
    pub const ALL: [&str; 3] = [SCANS, DIAGRAMS, DESCRIPTORS];
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

/// A table.
pub struct Table {
    /// Its name: the folder under the index, or the table's name in `schemas/`.
    pub name: &'static str,
    /// What a row is.
    pub doc: &'static str,
    /// Where its rows are: in the index, partitioned by session, or elsewhere (said in words).
    pub layout: Layout,
    /// Columns (without the `session` partition column).
    pub columns: Vec<Column>,
}

/// Where a table's rows are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// In the index: `<name>/session=<session>/part-<n>.parquet` (zstd).
    Index,
    /// Elsewhere, as the text says.
    Other(&'static str),
}

fn col(name: &'static str, data_type: DataType, nullable: bool, doc: &'static str) -> Column {
    Column { name, data_type, nullable, doc }
}

/// `scans`: one row per scan read (ok, skipped or error).
pub fn scans() -> Table {
    use DataType::*;
    use columns as C;
    Table {
        name: tables::SCANS,
        doc: "One row per scan read, whatever happened to it.",
        layout: Layout::Index,
        columns: vec![
            col(
                C::SCAN_ID,
                Utf8,
                false,
                "stable id: <session>/<utime> (NCLT), <session>/<frame> (KITTI), <session>/<index> (MCAP)",
            ),
            col(
                C::FINGERPRINT,
                Utf8,
                true,
                "xxh3-64 of the scan's raw bytes (16 hex digits; the file, MCAP message or packets); null when unreadable",
            ),
            col(
                C::SETTINGS_HASH,
                Utf8,
                false,
                "fingerprint of the preprocess and persistence settings that made this row (manifest settings_hash)",
            ),
            col(C::SEQ, UInt64, false, "position in the input order of the run that indexed the scan"),
            col(C::SOURCE_PATH, Utf8, false, "file the scan came from"),
            col(C::MESSAGE_INDEX, UInt64, true, "MCAP: index of the message among the topic's point clouds"),
            col(
                C::UTIME,
                Int64,
                true,
                "timestamp, microseconds since the Unix epoch (KITTI: since the sequence start)",
            ),
            col(C::POSE_X, Float64, true, "ground-truth position x (m, z-up world frame of the source)"),
            col(C::POSE_Y, Float64, true, "ground-truth position y (m)"),
            col(C::POSE_Z, Float64, true, "ground-truth position z (m)"),
            col(C::POSE_YAW, Float64, true, "ground-truth heading about z (rad)"),
            col(C::RAW_POINTS, UInt64, false, "points in the record, before dropping NaN/zero points"),
            col(C::KEPT_POINTS, UInt64, false, "points after preprocessing (the alpha complex's input)"),
            col(C::STATUS, Utf8, false, "ok | skipped | error"),
            col(C::ERROR, Utf8, true, "why the scan was skipped or failed (names the file and message/line)"),
        ],
    }
}

/// `diagrams`: one row per persistence pair.
pub fn diagrams() -> Table {
    use DataType::*;
    use columns as C;
    Table {
        name: tables::DIAGRAMS,
        doc: "One row per persistence pair of an ok scan (zero-length pairs dropped, as GUDHI).",
        layout: Layout::Index,
        columns: vec![
            col(C::SCAN_ID, Utf8, false, "the scan"),
            col(C::DIM, UInt8, false, "homology dimension 0, 1 or 2"),
            col(C::BIRTH, Float64, false, "birth (squared radius unless persistence.squared = false)"),
            col(C::DEATH, Float64, false, "death; +inf for the essential H0 class"),
        ],
    }
}

/// `descriptors`: one row per ok scan and method; `b` is the method's descriptor length.
pub fn descriptors(b: usize) -> Table {
    descriptors_of(b, DataType::Float32)
}

/// The `descriptors` table of `method`: its values `uint8` for the methods whose descriptors
/// are bytes ([`crate::methods::stores_bytes`]), `float32` for the others.
pub(crate) fn descriptors_for(method: &str, b: usize) -> Table {
    descriptors_of(b, if crate::methods::stores_bytes(method) { DataType::UInt8 } else { DataType::Float32 })
}

fn descriptors_of(b: usize, values: DataType) -> Table {
    use DataType::*;
    use columns as C;
    let item = Arc::new(Field::new("item", values, false));
    Table {
        name: tables::DESCRIPTORS,
        layout: Layout::Index,
        doc: "One descriptor per ok scan, per method (descriptors/method=<m>/session=<s>/): the TopoRec ATOL vector, a method computed from the raw scan (toporec-plus and the baselines; the manifest's `methods` names them), or an imported one.",
        columns: vec![
            col(C::SCAN_ID, Utf8, false, "the scan"),
            col(C::UTIME, Int64, true, "timestamp (µs)"),
            col(C::POSE_X, Float64, true, "ground-truth x (m)"),
            col(C::POSE_Y, Float64, true, "ground-truth y (m)"),
            col(C::POSE_Z, Float64, true, "ground-truth z (m)"),
            col(
                C::DIM_USED,
                UInt8,
                true,
                "paper rule: the diagram dimension vectorized (null with concatenated dims)",
            ),
            col(
                C::DESCRIPTOR,
                FixedSizeList(item, b as i32),
                false,
                "the vector (length b, float32); uint8 for lidar-iris (its image, then its template and mask bit-packed)",
            ),
            col(
                C::CODEBOOK_ID,
                Utf8,
                false,
                "what made it: the codebook id (TopoRec) or the method's id (manifest `methods`)",
            ),
        ],
    }
}

/// The columns of a match's estimated offset, in `query`'s and `loops`' tables alike.
const X_M: &str = "x_m";
const Y_M: &str = "y_m";
const OFFSET_X_DOC: &str = "the query's estimated position in the database scan's sensor frame: x, forward (m), for the methods that estimate one";
const OFFSET_Y_DOC: &str = "likewise y, left (m)";

/// `query`'s hits: one row per query and rank (CSV from `toporec query`, Arrow from Python's
/// `Index.query`).
pub fn query_hits() -> Table {
    use DataType::*;
    Table {
        name: "query",
        doc: "One row per query scan and rank: its k best database scans.",
        layout: Layout::Other(
            "CSV from `toporec query` (stdout or -o); Arrow from the Python package's Index.query",
        ),
        columns: vec![
            col("query_id", Utf8, false, "the query scan's id"),
            col("rank", UInt32, false, "1 for the best database scan"),
            col(columns::SCAN_ID, Utf8, false, "the database scan"),
            col(columns::SESSION, Utf8, false, "its session"),
            col("distance", Float64, false, "the method's distance (Euclidean for vectors)"),
            col(columns::POSE_X, Float64, true, "the database scan's ground-truth x (m)"),
            col(columns::POSE_Y, Float64, true, "its y (m)"),
            col(columns::POSE_Z, Float64, true, "its z (m)"),
            col(
                "yaw_deg",
                Float64,
                true,
                "the query's yaw relative to the database scan (degrees, [0, 360)), for the methods that estimate one",
            ),
            col(X_M, Float64, true, OFFSET_X_DOC),
            col(Y_M, Float64, true, OFFSET_Y_DOC),
        ],
    }
}

/// `loops`' rows: one per scan with an allowed earlier scan (its best match).
pub fn loops() -> Table {
    use DataType::*;
    let check = "the geometric check (`--verify`) of a match below the threshold";
    Table {
        name: "loops",
        doc: "One row per scan's best allowed earlier match (the loops only, unless --all).",
        layout: Layout::Other(
            "one file from `toporec loops -o`: Parquet (zstd), or CSV when it ends in .csv",
        ),
        columns: vec![
            col("method", Utf8, false, "the descriptor method"),
            col("query_scan", Utf8, false, "the scan"),
            col("query_session", Utf8, false, "its session"),
            col("matched_scan", Utf8, false, "the earlier scan it matches"),
            col("matched_session", Utf8, false, "its session"),
            col("distance", Float64, false, "descriptor distance"),
            col(
                "yaw_degrees",
                Float64,
                true,
                "the query's yaw relative to the match (degrees), for methods that give one",
            ),
            col(X_M, Float64, true, OFFSET_X_DOC),
            col(Y_M, Float64, true, OFFSET_Y_DOC),
            col(
                "rank2_distance",
                Float64,
                true,
                "the runner-up's distance, never below `distance` (the match's own where the method ranked a nearer one second): rank2_distance - distance is the margin",
            ),
            col(
                "true_distance_m",
                Float64,
                true,
                "the distance between the two scans' poses (m), when both have one",
            ),
            col("accepted", Boolean, false, "below the threshold (and, with --verify, aligned): a loop"),
            col("query_vertex", UInt64, false, "the query's position in the walking order (its g2o vertex)"),
            col("matched_vertex", UInt64, false, "the matched scan's"),
            col("verified", Boolean, true, check),
            col(
                "icp_fitness",
                Float64,
                true,
                "ICP: the share of the query's points with a partner within the last stage's distance",
            ),
            col("icp_rmse", Float64, true, "ICP: the root mean square of their point-to-plane distances (m)"),
            col("rel_x", Float64, true, "ICP: the query's pose in the match's sensor frame, x (m)"),
            col("rel_y", Float64, true, "y (m)"),
            col("rel_z", Float64, true, "z (m)"),
            col("rel_roll_deg", Float64, true, "roll (degrees)"),
            col("rel_pitch_deg", Float64, true, "pitch (degrees)"),
            col("rel_yaw_deg", Float64, true, "yaw (degrees)"),
            col(
                "in_map",
                Boolean,
                true,
                "whether the optimized map kept the loop (true) or rejected it as inconsistent with the odometry and the other loops (false); null when no map was made (no poses, --no-optimize) or the row is no loop",
            ),
        ],
    }
}

/// `corrected_poses`: one row per scan in a map, at its corrected pose.
pub fn corrected_poses() -> Table {
    use DataType::*;
    Table {
        name: "corrected_poses",
        doc: "One row per scan of a method's map (`toporec loops` where the scans have poses), at its corrected sensor pose in the map's frame (the first session's).",
        layout: Layout::Other(
            "the poses table of the Python package's `toporec.loops(..., with_poses=True)`; the same poses as the command's `<output stem>.<session>.tum` files",
        ),
        columns: vec![
            col("method", Utf8, false, "the descriptor method whose loops made the map"),
            col(columns::SESSION, Utf8, false, "the scan's session"),
            col(columns::SCAN_ID, Utf8, false, "the scan"),
            col("time", Float64, true, "its timestamp (s); null for a scan without one"),
            col("x", Float64, false, "position (m)"),
            col("y", Float64, false, "position (m)"),
            col("z", Float64, false, "position (m)"),
            col("qx", Float64, false, "orientation, a unit quaternion"),
            col("qy", Float64, false, "orientation"),
            col("qz", Float64, false, "orientation"),
            col("qw", Float64, false, "orientation"),
        ],
    }
}

/// The input batches of [`crate::batch`]: one row per scan (or MCAP message range). Only
/// `path` is required; a row carries the file's bytes (`content`), its points (`points`), or
/// neither (the file is read from `path`).
pub fn batch_inputs() -> Table {
    use DataType::*;
    let points = List(Arc::new(Field::new("item", Float64, true)));
    Table {
        name: "batch_inputs",
        doc: "One row per scan handed over to toporec::batch (or one MCAP message range).",
        layout: Layout::Other(
            "Arrow record batches given to the Python package's describe_batch and the Spark job (mapInArrow)",
        ),
        columns: vec![
            col(
                "path",
                Utf8,
                false,
                "the scan file (names the scan and its session by the sources' layouts)",
            ),
            col("content", Binary, true, "the file's bytes"),
            col("points", points, true, "x, y, z of every point in the sensor frame (m), flattened"),
            col("format", Utf8, true, "nclt | kitti | mcap; from the path's layout when absent"),
            col(columns::SCAN_ID, Utf8, true, "the scan id (required with points)"),
            col(columns::SESSION, Utf8, true, "its session (with points; default: the scan id's first part)"),
            col(columns::SEQ, UInt64, true, "position in the job's input order (default: the row's)"),
            col(columns::UTIME, Int64, true, "timestamp, µs (with points)"),
            col(columns::POSE_X, Float64, true, "ground-truth x (m, with points)"),
            col(columns::POSE_Y, Float64, true, "ground-truth y (m)"),
            col(columns::POSE_Z, Float64, true, "ground-truth z (m)"),
            col(columns::POSE_YAW, Float64, true, "ground-truth heading (rad)"),
            col("first_message", UInt64, true, "mcap rows: the first message index of the range"),
            col("message_count", UInt64, true, "mcap rows: how many messages"),
        ],
    }
}

impl Table {
    /// The column named `name`.
    pub fn column(&self, name: &str) -> Option<&Column> {
        self.columns.iter().find(|c| c.name == name)
    }

    /// The Arrow schema of the columns, without metadata.
    pub fn plain_schema(&self) -> Arc<Schema> {
        Arc::new(Schema::new(
            self.columns
                .iter()
                .map(|c| Field::new(c.name, c.data_type.clone(), c.nullable))
                .collect::<Vec<_>>(),
        ))
    }

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
        DataType::List(item) => format!("list<{}>", type_name(item.data_type())),
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
    let v = match t.layout {
        Layout::Index => serde_json::json!({
            "table": t.name,
            "description": t.doc,
            "schema_version": SCHEMA_VERSION,
            "layout": format!("{}/session=<session>/part-<n>.parquet (zstd)", t.name),
            "partition_columns": [{"name": "session", "type": "utf8", "description": "NCLT date folder, KITTI sequence, or MCAP file stem (from the path)"}],
            "columns": columns,
        }),
        Layout::Other(layout) => serde_json::json!({
            "table": t.name,
            "description": t.doc,
            "layout": layout,
            "columns": columns,
        }),
    };
    serde_json::to_string_pretty(&v).expect("JSON") + "\n"
}

/// All tables (descriptors with a placeholder length).
pub fn all() -> Vec<Table> {
    vec![scans(), diagrams(), descriptors(1), query_hits(), loops(), corrected_poses(), batch_inputs()]
}
