//! CSV renderings of the tables toporec writes as CSV beside Arrow or Parquet (`query`'s hits,
//! `loops`' rows): one renderer of a declared table's record batch, so that a CSV file and its
//! Arrow twin cannot drift apart.
//!
//! Values: strings quoted when needed (RFC 4180), floats as Rust prints them to round-trip
//! (`0.1`, `1.0`, `NaN`), integers and booleans plainly, nulls as empty fields.

use arrow::array::{Array, AsArray, RecordBatch};
use arrow::datatypes::{DataType, Float64Type, Int64Type, UInt32Type, UInt64Type};
use std::fmt::Write as _;

/// Quotes a CSV field when needed (RFC 4180).
pub fn field(s: &str) -> String {
    if s.contains([',', '"', '\n']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

/// The header line of a table: its column names, comma-separated (no line end).
pub fn header(table: &super::schema::Table) -> String {
    table.columns.iter().map(|c| c.name).collect::<Vec<_>>().join(",")
}

/// The rows of `batch`, one line each (with its line end).
pub fn rows(batch: &RecordBatch) -> String {
    let mut out = String::new();
    for row in 0..batch.num_rows() {
        for (i, column) in batch.columns().iter().enumerate() {
            if i > 0 {
                out.push(',');
            }
            value(&mut out, column.as_ref(), row);
        }
        out.push('\n');
    }
    out
}

/// One value of a column.
fn value(out: &mut String, column: &dyn Array, row: usize) {
    if column.is_null(row) {
        return;
    }
    let _ = match column.data_type() {
        DataType::Utf8 => write!(out, "{}", field(column.as_string::<i32>().value(row))),
        DataType::Float64 => write!(out, "{:?}", column.as_primitive::<Float64Type>().value(row)),
        DataType::UInt32 => write!(out, "{}", column.as_primitive::<UInt32Type>().value(row)),
        DataType::UInt64 => write!(out, "{}", column.as_primitive::<UInt64Type>().value(row)),
        DataType::Int64 => write!(out, "{}", column.as_primitive::<Int64Type>().value(row)),
        DataType::Boolean => write!(out, "{}", column.as_boolean().value(row)),
        other => unreachable!("no CSV table has a column of type {other}"),
    };
}
