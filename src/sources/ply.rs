//! PLY (the Stanford polygon format): a text header (`format ascii|binary_little_endian|
//! binary_big_endian 1.0`, `element NAME COUNT`, `property TYPE NAME`, `property list CTYPE
//! ITYPE NAME`, `end_header`), then each element's rows in the header's order. The points are
//! the `vertex` element's `x`, `y`, `z`, of any numeric type; every other property and element
//! is read past. Points with a non-finite coordinate are left out.

use super::SourceError;
use crate::types::Point;
use std::path::Path;

/// How the rows are stored.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Format {
    Ascii,
    Little,
    Big,
}

/// A property: its scalar type's size and kind, or a list (count type, item type).
#[derive(Clone, Debug)]
struct Property {
    name: String,
    scalar: (usize, u8),
    list: Option<(usize, u8)>,
}

struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

/// A type name's (size, kind): kind `i` signed, `u` unsigned, `f` float.
fn scalar(name: &str) -> Option<(usize, u8)> {
    Some(match name {
        "char" | "int8" => (1, b'i'),
        "uchar" | "uint8" => (1, b'u'),
        "short" | "int16" => (2, b'i'),
        "ushort" | "uint16" => (2, b'u'),
        "int" | "int32" => (4, b'i'),
        "uint" | "uint32" => (4, b'u'),
        "float" | "float32" => (4, b'f'),
        "double" | "float64" => (8, b'f'),
        _ => return None,
    })
}

/// A binary value at the start of `b`, as f64.
fn value(b: &[u8], (size, kind): (usize, u8), format: Format) -> f64 {
    let mut a = [0u8; 8];
    a[..size].copy_from_slice(&b[..size]);
    if format == Format::Big {
        a[..size].reverse();
    }
    match (kind, size) {
        (b'f', 4) => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
        (b'f', _) => f64::from_le_bytes(a),
        (b'i', 1) => a[0] as i8 as f64,
        (b'i', 2) => i16::from_le_bytes([a[0], a[1]]) as f64,
        (b'i', _) => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
        (_, 1) => a[0] as f64,
        (_, 2) => u16::from_le_bytes([a[0], a[1]]) as f64,
        _ => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
    }
}

/// Decodes a PLY file's bytes to its vertices (metres).
pub fn decode(bytes: &[u8], path: &Path) -> Result<Vec<Point>, SourceError> {
    let bad = |m: String| SourceError::invalid(path, m);
    let mut at = 0;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut first = true;
    loop {
        let end = bytes[at..]
            .iter()
            .position(|&b| b == b'\n')
            .ok_or_else(|| bad("PLY header without end_header".into()))?;
        let line = std::str::from_utf8(&bytes[at..at + end])
            .map_err(|_| bad(format!("PLY header: line at byte {at} is not text")))?
            .trim();
        at += end + 1;
        if first {
            if line != "ply" {
                return Err(bad("not a PLY file (no `ply` line first)".into()));
            }
            first = false;
            continue;
        }
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", f, _] => {
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::Little,
                    "binary_big_endian" => Format::Big,
                    other => return Err(bad(format!("PLY: unknown format `{other}`"))),
                })
            }
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count.parse().map_err(|_| bad(format!("PLY: element {name}: count `{count}`")))?,
                properties: Vec::new(),
            }),
            ["property", "list", c, t, name] => {
                let e = elements.last_mut().ok_or_else(|| bad("PLY: property before any element".into()))?;
                let (c, t) = scalar(c)
                    .zip(scalar(t))
                    .ok_or_else(|| bad(format!("PLY: property list {name}: unknown type")))?;
                e.properties.push(Property { name: name.to_string(), scalar: t, list: Some((c.0, c.1)) });
            }
            ["property", t, name] => {
                let e = elements.last_mut().ok_or_else(|| bad("PLY: property before any element".into()))?;
                let s = scalar(t).ok_or_else(|| bad(format!("PLY: property {name}: unknown type `{t}`")))?;
                e.properties.push(Property { name: name.to_string(), scalar: s, list: None });
            }
            ["end_header"] => break,
            _ => {}
        }
    }
    let format = format.ok_or_else(|| bad("PLY header without a format line".into()))?;
    let mut points = Vec::new();
    let mut found = false;
    let mut words = if format == Format::Ascii {
        Some(
            std::str::from_utf8(&bytes[at..])
                .map_err(|_| bad("PLY: ascii data is not text".into()))?
                .split_whitespace(),
        )
    } else {
        None
    };
    for e in &elements {
        let xyz: Option<Vec<usize>> =
            ["x", "y", "z"].iter().map(|n| e.properties.iter().position(|p| p.name == *n)).collect();
        let xyz = if e.name == "vertex" {
            found = true;
            Some(xyz.ok_or_else(|| bad("PLY: the vertex element has no x, y and z".into()))?)
        } else {
            None
        };
        let mut row = vec![0f64; e.properties.len()];
        for i in 0..e.count {
            for (k, p) in e.properties.iter().enumerate() {
                let name = &e.name;
                let cut = |at: usize| bad(format!("PLY: element {name} row {i}: data cut short (byte {at})"));
                let mut read = |s: (usize, u8)| -> Result<f64, SourceError> {
                    match words.as_mut() {
                        Some(w) => {
                            let t = w.next().ok_or_else(|| cut(at))?;
                            t.parse().map_err(|_| bad(format!("PLY: element {} row {i}: `{t}`", e.name)))
                        }
                        None => {
                            let b = bytes.get(at..at + s.0).ok_or_else(|| cut(at))?;
                            at += s.0;
                            Ok(value(b, s, format))
                        }
                    }
                };
                match p.list {
                    Some(c) => {
                        let n = read(c)?;
                        if !(0.0..=1e9).contains(&n) {
                            return Err(bad(format!("PLY: element {} row {i}: list of {n}", e.name)));
                        }
                        for _ in 0..n as usize {
                            read(p.scalar)?;
                        }
                    }
                    None => row[k] = read(p.scalar)?,
                }
            }
            if let Some(xyz) = &xyz {
                points.push([row[xyz[0]], row[xyz[1]], row[xyz[2]]]);
            }
        }
    }
    if !found {
        return Err(bad("PLY: no vertex element".into()));
    }
    points.retain(|p| p.iter().all(|v| v.is_finite()));
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_encoding_and_skipped_properties() {
        let p = Path::new("t.ply");
        let ascii = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty uchar red\nproperty float y\nproperty double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n1 255 2 3\n-1.5 0 2.5 4\n3 0 1 2\n";
        assert_eq!(decode(ascii.as_bytes(), p).unwrap(), vec![[1.0, 2.0, 3.0], [-1.5, 2.5, 4.0]]);
        for (name, big) in [("binary_little_endian", false), ("binary_big_endian", true)] {
            let mut b = format!(
                "ply\nformat {name} 1.0\nelement face 1\nproperty list uchar int vertex_indices\nelement vertex 1\nproperty short x\nproperty float y\nproperty double z\nend_header\n"
            )
            .into_bytes();
            let mut push = |v: &[u8]| {
                b.extend(if big { v.iter().rev().copied().collect::<Vec<_>>() } else { v.to_vec() })
            };
            push(&[2]);
            push(&7i32.to_le_bytes());
            push(&8i32.to_le_bytes());
            push(&(-3i16).to_le_bytes());
            push(&0.5f32.to_le_bytes());
            push(&6.25f64.to_le_bytes());
            assert_eq!(decode(&b, p).unwrap(), vec![[-3.0, 0.5, 6.25]], "{name}");
        }
    }

    #[test]
    fn bad_files_are_errors_naming_the_file() {
        let p = Path::new("bad.ply");
        for (text, needle) in [
            (
                "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n",
                "no x, y and z",
            ),
            (
                "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n",
                "cut short",
            ),
            ("ply\nformat binary_middle_endian 1.0\nend_header\n", "unknown format"),
            ("plx\n", "not a PLY"),
            ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "end_header"),
        ] {
            let e = decode(text.as_bytes(), p).unwrap_err().to_string();
            assert!(e.contains("bad.ply") && e.contains(needle), "{e}");
        }
    }
}
