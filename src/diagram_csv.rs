//! Diagram CSV files: header `dim,birth,death`, one pair per row, `inf` for the essential
//! class. `toporec diagram` writes them; `toporec fit` and `toporec vectorize` read them.

use crate::error::{Error, Result, ResultExt};
use crate::homology::{Diagram, Pair};
use std::io::Write;
use std::path::Path;

/// A line of a diagram CSV that cannot be read.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("line {line}: {message}")]
pub struct ParseError {
    /// 1-based line number.
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

/// Writes `dim,birth,death` rows; floats in shortest round-trip form, `inf` for infinity.
pub fn write(d: &Diagram, out: &mut impl Write) -> std::io::Result<()> {
    let mut w = std::io::BufWriter::new(out);
    writeln!(w, "dim,birth,death")?;
    for p in d.pairs() {
        writeln!(w, "{},{:?},{:?}", p.dim, p.birth, p.death)?;
    }
    w.flush()
}

/// Reads a diagram CSV; errors name the file and the line.
pub fn read(path: &Path) -> Result<Diagram> {
    let text = std::fs::read_to_string(path).at(path)?;
    parse(&text).map_err(|e| Error::Diagram { path: path.to_owned(), message: e.to_string() })
}

/// Parses the text of a diagram CSV (with the `csv` crate: a byte-order mark, Windows line ends
/// and quoted fields are fine).
pub fn parse(text: &str) -> Result<Diagram, ParseError> {
    let mut reader =
        csv::ReaderBuilder::new().flexible(true).trim(csv::Trim::All).from_reader(text.as_bytes());
    let header =
        reader.headers().map_err(|e| ParseError { line: 1, message: format!("not CSV: {e}") })?.clone();
    let names: Vec<&str> = header.iter().collect();
    if names.iter().all(|n| n.is_empty()) {
        let message = "empty file (expected header `dim,birth,death`)".into();
        return Err(ParseError { line: 1, message });
    }
    if names != ["dim", "birth", "death"] {
        let message = format!("expected header `dim,birth,death`, found `{}`", names.join(","));
        return Err(ParseError { line: 1, message });
    }
    let mut pairs = Vec::new();
    for (line, record) in crate::sources::csv::numbered_records(&mut reader) {
        let record = record.map_err(|e| ParseError { line, message: format!("not CSV: {e}") })?;
        let text: Vec<&str> = record.iter().collect();
        let bad = |what: &str| ParseError { line, message: format!("{what}: `{}`", text.join(",")) };
        let [dim, birth, death] = text[..] else {
            return Err(bad("expected 3 fields"));
        };
        let dim: u8 = dim.parse().ok().filter(|d| *d <= 2).ok_or_else(|| bad("dim must be 0, 1 or 2"))?;
        let birth: f64 = birth.parse().map_err(|_| bad("birth is not a number"))?;
        let death: f64 = death.parse().map_err(|_| bad("death is not a number"))?;
        if birth.is_nan() || death.is_nan() || !birth.is_finite() || death < birth {
            return Err(bad("need finite birth <= death"));
        }
        pairs.push(Pair { dim, birth, death });
    }
    Ok(Diagram::new(pairs))
}
