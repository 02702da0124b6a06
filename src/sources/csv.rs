//! Point clouds as CSV: a header row naming `x`, `y`, `z` (any order, extra columns ignored),
//! then one point per line.

use super::SourceError;
use crate::types::Point;
use std::path::Path;

/// Parses a CSV cloud.
pub fn parse_xyz(bytes: &[u8], path: &Path) -> Result<Vec<Point>, SourceError> {
    let err = |line: usize, message: String| SourceError::Parse { path: path.to_owned(), line, message };
    let text = std::str::from_utf8(bytes).map_err(|e| err(0, format!("not UTF-8 text: {e}")))?;
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
    let Some((_, header)) = lines.next() else {
        return Err(err(1, "empty file: expected a header `x,y,z`".into()));
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let col = |n: &str| names.iter().position(|&c| c == n);
    let (Some(ix), Some(iy), Some(iz)) = (col("x"), col("y"), col("z")) else {
        return Err(err(1, format!("header `{header}` lacks one of the columns x, y, z")));
    };
    let mut points = Vec::new();
    for (i, line) in lines {
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let get = |k: usize| -> Result<f64, SourceError> {
            let f = fields.get(k).ok_or_else(|| {
                err(i + 1, format!("expected {} fields, found {}", names.len(), fields.len()))
            })?;
            f.parse::<f64>().map_err(|_| err(i + 1, format!("`{f}` is not a number")))
        };
        points.push([get(ix)?, get(iy)?, get(iz)?]);
    }
    Ok(points)
}
