//! Point clouds as CSV: a header row naming `x`, `y`, `z` (any order, extra columns ignored),
//! then one point per line. Read with the `csv` crate: a byte-order mark (Excel's "CSV
//! UTF-8"), Windows line ends and quoted fields are fine.

use super::SourceError;
use crate::types::Point;
use std::path::Path;

/// The records of a CSV reader, each with the line it starts on (1-based), blank records left
/// out. A malformed record is an `Err` item; reading goes on after it.
pub(crate) fn numbered_records<R: std::io::Read>(
    reader: &mut csv::Reader<R>,
) -> impl Iterator<Item = (usize, Result<csv::StringRecord, csv::Error>)> + '_ {
    std::iter::from_fn(move || {
        loop {
            let line = reader.position().line() as usize;
            let mut record = csv::StringRecord::new();
            return match reader.read_record(&mut record) {
                Ok(false) => None,
                Ok(true) if record.iter().all(str::is_empty) => continue,
                Ok(true) => Some((line, Ok(record))),
                Err(e) => Some((line, Err(e))),
            };
        }
    })
}

/// Parses a CSV cloud.
pub fn parse_xyz(bytes: &[u8], path: &Path) -> Result<Vec<Point>, SourceError> {
    let err = |line: usize, message: String| SourceError::Parse { path: path.to_owned(), line, message };
    let mut reader = csv::ReaderBuilder::new().flexible(true).trim(csv::Trim::All).from_reader(bytes);
    let header = reader.headers().map_err(|e| err(1, format!("not CSV: {e}")))?.clone();
    if header.iter().all(str::is_empty) {
        return Err(err(1, "empty file: expected a header `x,y,z`".into()));
    }
    let col = |n: &str| header.iter().position(|c| c == n);
    let (Some(ix), Some(iy), Some(iz)) = (col("x"), col("y"), col("z")) else {
        let names: Vec<&str> = header.iter().collect();
        return Err(err(1, format!("header `{}` lacks one of the columns x, y, z", names.join(","))));
    };
    let mut points = Vec::new();
    for (line, record) in numbered_records(&mut reader) {
        let record = record.map_err(|e| err(line, format!("not CSV: {e}")))?;
        let get = |k: usize| -> Result<f64, SourceError> {
            let f = record.get(k).ok_or_else(|| {
                err(line, format!("expected {} fields, found {}", header.len(), record.len()))
            })?;
            f.parse::<f64>().map_err(|_| err(line, format!("`{f}` is not a number")))
        };
        points.push([get(ix)?, get(iy)?, get(iz)?]);
    }
    Ok(points)
}
