//! Rows of a declared table, written and read by column name ([`super::schema`] declares every
//! table once): [`RowBuilder`] builds a record batch of a table's columns, in its declared order,
//! from values set by name; [`Columns`] gives the columns of a batch read back by name. A column
//! a row does not set is null, so a nullable column added to a declaration needs no change where
//! rows are made until its value is; no code outside these two reads or writes a column by its
//! position.

use super::schema::Table;
use arrow::array::{
    Array, ArrayRef, AsArray, BooleanBuilder, FixedSizeListBuilder, Float32Builder, Float64Builder,
    Int64Builder, RecordBatch, StringBuilder, UInt8Builder, UInt32Builder, UInt64Builder,
};
use arrow::datatypes::{DataType, Schema};
use std::sync::Arc;

/// A column being built.
enum Builder {
    Text(StringBuilder),
    U64(UInt64Builder),
    I64(Int64Builder),
    U32(UInt32Builder),
    U8(UInt8Builder),
    F64(Float64Builder),
    Bool(BooleanBuilder),
    F32List(FixedSizeListBuilder<Float32Builder>),
    U8List(FixedSizeListBuilder<UInt8Builder>),
}

impl Builder {
    fn of(t: &DataType) -> Builder {
        match t {
            DataType::Utf8 => Builder::Text(StringBuilder::new()),
            DataType::UInt64 => Builder::U64(UInt64Builder::new()),
            DataType::Int64 => Builder::I64(Int64Builder::new()),
            DataType::UInt32 => Builder::U32(UInt32Builder::new()),
            DataType::UInt8 => Builder::U8(UInt8Builder::new()),
            DataType::Float64 => Builder::F64(Float64Builder::new()),
            DataType::Boolean => Builder::Bool(BooleanBuilder::new()),
            DataType::FixedSizeList(item, n) => match item.data_type() {
                DataType::Float32 => Builder::F32List(
                    FixedSizeListBuilder::new(Float32Builder::new(), *n).with_field(item.clone()),
                ),
                DataType::UInt8 => Builder::U8List(
                    FixedSizeListBuilder::new(UInt8Builder::new(), *n).with_field(item.clone()),
                ),
                other => unreachable!("no declared list of {other}"),
            },
            other => unreachable!("no declared column of type {other}"),
        }
    }

    fn len(&self) -> usize {
        use arrow::array::ArrayBuilder;
        match self {
            Builder::Text(b) => b.len(),
            Builder::U64(b) => b.len(),
            Builder::I64(b) => b.len(),
            Builder::U32(b) => b.len(),
            Builder::U8(b) => b.len(),
            Builder::F64(b) => b.len(),
            Builder::Bool(b) => b.len(),
            Builder::F32List(b) => b.len(),
            Builder::U8List(b) => b.len(),
        }
    }

    fn null(&mut self) {
        match self {
            Builder::Text(b) => b.append_null(),
            Builder::U64(b) => b.append_null(),
            Builder::I64(b) => b.append_null(),
            Builder::U32(b) => b.append_null(),
            Builder::U8(b) => b.append_null(),
            Builder::F64(b) => b.append_null(),
            Builder::Bool(b) => b.append_null(),
            Builder::F32List(b) => {
                let n = b.value_length() as usize;
                b.values().append_nulls(n);
                b.append(false);
            }
            Builder::U8List(b) => {
                let n = b.value_length() as usize;
                b.values().append_nulls(n);
                b.append(false);
            }
        }
    }

    fn finish(&mut self) -> ArrayRef {
        match self {
            Builder::Text(b) => Arc::new(b.finish()),
            Builder::U64(b) => Arc::new(b.finish()),
            Builder::I64(b) => Arc::new(b.finish()),
            Builder::U32(b) => Arc::new(b.finish()),
            Builder::U8(b) => Arc::new(b.finish()),
            Builder::F64(b) => Arc::new(b.finish()),
            Builder::Bool(b) => Arc::new(b.finish()),
            Builder::F32List(b) => Arc::new(b.finish()),
            Builder::U8List(b) => Arc::new(b.finish()),
        }
    }
}

/// A column of a [`RowBuilder`], found by name once (for the tables of many rows).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Col(usize);

/// A record batch of a declared table, built row by row from values set by column name.
pub struct RowBuilder {
    schema: Arc<Schema>,
    names: Vec<&'static str>,
    columns: Vec<Builder>,
    rows: usize,
}

impl RowBuilder {
    /// A builder of `table`'s rows, its batches of `schema` (the table's, with its metadata).
    pub fn new(table: &Table, schema: Arc<Schema>) -> Self {
        RowBuilder {
            names: table.columns.iter().map(|c| c.name).collect(),
            columns: table.columns.iter().map(|c| Builder::of(&c.data_type)).collect(),
            schema,
            rows: 0,
        }
    }

    /// A builder of `table`'s rows, its batches of the table's plain schema.
    pub fn plain(table: &Table) -> Self {
        Self::new(table, table.plain_schema())
    }

    /// The column named `name` (one the table declares).
    pub fn col(&self, name: &str) -> Col {
        Col(self
            .names
            .iter()
            .position(|n| *n == name)
            .unwrap_or_else(|| panic!("no declared column `{name}`")))
    }

    fn at(&mut self, c: Col) -> &mut Builder {
        let b = &mut self.columns[c.0];
        debug_assert_eq!(b.len(), self.rows, "column `{}` set twice in a row", self.names[c.0]);
        b
    }

    /// Sets a text column of this row.
    pub fn text(&mut self, c: Col, v: Option<&str>) -> &mut Self {
        match self.at(c) {
            Builder::Text(b) => b.append_option(v),
            _ => panic!("column `{}` is not text", self.names[c.0]),
        }
        self
    }

    /// Sets an unsigned integer column (uint64, uint32 or uint8) of this row.
    pub fn uint(&mut self, c: Col, v: Option<u64>) -> &mut Self {
        match self.at(c) {
            Builder::U64(b) => b.append_option(v),
            Builder::U32(b) => b.append_option(v.map(|v| u32::try_from(v).expect("a u32 value"))),
            Builder::U8(b) => b.append_option(v.map(|v| u8::try_from(v).expect("a u8 value"))),
            _ => panic!("column `{}` is not an unsigned integer", self.names[c.0]),
        }
        self
    }

    /// Sets an int64 column of this row.
    pub fn int(&mut self, c: Col, v: Option<i64>) -> &mut Self {
        match self.at(c) {
            Builder::I64(b) => b.append_option(v),
            _ => panic!("column `{}` is not int64", self.names[c.0]),
        }
        self
    }

    /// Sets a float64 column of this row.
    pub fn float(&mut self, c: Col, v: Option<f64>) -> &mut Self {
        match self.at(c) {
            Builder::F64(b) => b.append_option(v),
            _ => panic!("column `{}` is not float64", self.names[c.0]),
        }
        self
    }

    /// Sets a boolean column of this row.
    pub fn boolean(&mut self, c: Col, v: Option<bool>) -> &mut Self {
        match self.at(c) {
            Builder::Bool(b) => b.append_option(v),
            _ => panic!("column `{}` is not boolean", self.names[c.0]),
        }
        self
    }

    /// Sets a fixed-size list column of this row (float32 items, or uint8 items from values
    /// that are bytes).
    pub fn list(&mut self, c: Col, v: &[f32]) -> &mut Self {
        match self.at(c) {
            Builder::F32List(b) => {
                b.values().append_slice(v);
                b.append(true);
            }
            Builder::U8List(b) => {
                for &x in v {
                    b.values().append_value(x as u8);
                }
                b.append(true);
            }
            _ => panic!("column `{}` is not a list", self.names[c.0]),
        }
        self
    }

    /// Ends the row: a column it did not set is null.
    pub fn end_row(&mut self) {
        self.rows += 1;
        for b in &mut self.columns {
            if b.len() < self.rows {
                b.null();
            }
        }
    }

    /// Rows since the last [`RowBuilder::finish`].
    pub fn len(&self) -> usize {
        self.rows
    }

    /// Whether no row was added since the last [`RowBuilder::finish`].
    pub fn is_empty(&self) -> bool {
        self.rows == 0
    }

    /// The rows added since the last call, as a batch; an error names a non-nullable column a
    /// row left null.
    pub fn finish(&mut self) -> Result<RecordBatch, arrow::error::ArrowError> {
        self.rows = 0;
        let columns: Vec<ArrayRef> = self.columns.iter_mut().map(Builder::finish).collect();
        RecordBatch::try_new(self.schema.clone(), columns)
    }
}

/// The columns of a batch read back, by name, of the types the table declares.
pub struct Columns {
    names: Vec<&'static str>,
    columns: Vec<ArrayRef>,
}

impl Columns {
    /// Columns named `names`, in that order.
    pub(crate) fn new(names: Vec<&'static str>, columns: Vec<ArrayRef>) -> Self {
        Columns { names, columns }
    }

    /// The column named `name` (one that was read).
    pub fn get(&self, name: &str) -> &ArrayRef {
        let i =
            self.names.iter().position(|n| *n == name).unwrap_or_else(|| panic!("column `{name}` not read"));
        &self.columns[i]
    }

    /// Rows.
    pub fn len(&self) -> usize {
        self.columns.first().map_or(0, |c| c.len())
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// A text column.
    pub fn text(&self, name: &str) -> &arrow::array::StringArray {
        self.get(name).as_string::<i32>()
    }

    /// A uint64 column.
    pub fn uint64(&self, name: &str) -> &arrow::array::UInt64Array {
        self.get(name).as_primitive::<arrow::datatypes::UInt64Type>()
    }

    /// A uint8 column.
    pub fn uint8(&self, name: &str) -> &arrow::array::UInt8Array {
        self.get(name).as_primitive::<arrow::datatypes::UInt8Type>()
    }

    /// An int64 column.
    pub fn int64(&self, name: &str) -> &arrow::array::Int64Array {
        self.get(name).as_primitive::<arrow::datatypes::Int64Type>()
    }

    /// A float64 column.
    pub fn float64(&self, name: &str) -> &arrow::array::Float64Array {
        self.get(name).as_primitive::<arrow::datatypes::Float64Type>()
    }

    /// The columns in the order read.
    pub(crate) fn into_arrays(self) -> Vec<ArrayRef> {
        self.columns
    }
}
