//! PCD (the Point Cloud Library's format): a text header (`FIELDS`, `SIZE`, `TYPE`, `COUNT`,
//! `WIDTH`, `HEIGHT`, `VIEWPOINT`, `POINTS`, `DATA`), then the points as `ascii` lines, `binary`
//! records (point by point), or `binary_compressed`: a u32 compressed size, a u32
//! uncompressed size and LZF data that decompresses field by field (all x, then all y, …).
//!
//! The points are the fields named `x`, `y`, `z` (any `SIZE` 1/2/4/8 of `TYPE` I, U or F; the
//! first value where `COUNT` > 1); every other field, PCL's `_` padding included, is skipped.
//! Points with a non-finite coordinate (an organized cloud's missing returns) are left out. A
//! `VIEWPOINT` other than the identity is applied: the points are returned in the sensor frame
//! it names. Bytes after the last point (PCL writes some) are ignored.

use super::SourceError;
use crate::types::Point;
use std::path::Path;

/// One field of the header.
#[derive(Clone, Debug)]
struct Field {
    name: String,
    size: usize,
    kind: u8,
    count: usize,
}

/// The storage of the points.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Data {
    Ascii,
    Binary,
    Compressed,
}

/// The parsed header: fields, point count, viewpoint (tx ty tz qw qx qy qz), storage, and
/// where the data starts.
struct Header {
    fields: Vec<Field>,
    points: usize,
    viewpoint: [f64; 7],
    data: Data,
    start: usize,
}

fn header(bytes: &[u8], path: &Path) -> Result<Header, SourceError> {
    let bad = |m: String| SourceError::invalid(path, m);
    let (mut names, mut sizes, mut types, mut counts) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut width, mut height, mut points) = (None, None, None);
    let mut viewpoint = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
    let mut at = 0;
    loop {
        let Some(end) = bytes[at..].iter().position(|&b| b == b'\n') else {
            return Err(bad("PCD header without a DATA line".into()));
        };
        let line = std::str::from_utf8(&bytes[at..at + end])
            .map_err(|_| bad(format!("PCD header: line at byte {at} is not text")))?
            .trim();
        at += end + 1;
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut words = line.split_whitespace();
        let key = words.next().unwrap_or_default().to_ascii_uppercase();
        let rest: Vec<&str> = words.collect();
        let number = |w: &str| -> Result<usize, SourceError> {
            w.parse().map_err(|_| bad(format!("PCD header: {key} `{w}` is not a count")))
        };
        match key.as_str() {
            "VERSION" => {}
            "FIELDS" => names = rest.iter().map(|s| s.to_string()).collect(),
            "SIZE" => sizes = rest.iter().map(|w| number(w)).collect::<Result<_, _>>()?,
            "TYPE" => {
                types = rest.iter().map(|w| w.bytes().next().unwrap_or(b'?').to_ascii_uppercase()).collect()
            }
            "COUNT" => counts = rest.iter().map(|w| number(w)).collect::<Result<_, _>>()?,
            "WIDTH" => width = Some(number(rest.first().copied().unwrap_or_default())?),
            "HEIGHT" => height = Some(number(rest.first().copied().unwrap_or_default())?),
            "POINTS" => points = Some(number(rest.first().copied().unwrap_or_default())?),
            "VIEWPOINT" => {
                let v: Vec<f64> = rest.iter().filter_map(|w| w.parse().ok()).collect();
                if v.len() != 7 || !v.iter().all(|x| x.is_finite()) {
                    return Err(bad(format!("PCD header: VIEWPOINT `{}` is not 7 numbers", rest.join(" "))));
                }
                viewpoint.copy_from_slice(&v);
            }
            "DATA" => {
                let data = match rest.first().map(|w| w.to_ascii_lowercase()).as_deref() {
                    Some("ascii") => Data::Ascii,
                    Some("binary") => Data::Binary,
                    Some("binary_compressed") => Data::Compressed,
                    other => return Err(bad(format!("PCD: unknown DATA `{}`", other.unwrap_or("")))),
                };
                if counts.is_empty() {
                    counts = vec![1; names.len()];
                }
                if sizes.len() != names.len() || types.len() != names.len() || counts.len() != names.len() {
                    return Err(bad(format!(
                        "PCD header: {} FIELDS but {} SIZE, {} TYPE and {} COUNT",
                        names.len(),
                        sizes.len(),
                        types.len(),
                        counts.len()
                    )));
                }
                let fields: Vec<Field> = (0..names.len())
                    .map(|i| Field {
                        name: names[i].clone(),
                        size: sizes[i],
                        kind: types[i],
                        count: counts[i],
                    })
                    .collect();
                for f in &fields {
                    let ok = match f.kind {
                        b'F' => matches!(f.size, 4 | 8),
                        b'I' | b'U' => matches!(f.size, 1 | 2 | 4 | 8),
                        _ => false,
                    };
                    if !ok || f.count == 0 {
                        return Err(bad(format!(
                            "PCD header: field `{}` has SIZE {} TYPE {} COUNT {}",
                            f.name, f.size, f.kind as char, f.count
                        )));
                    }
                }
                let stated = width.zip(height).map(|(w, h)| w.saturating_mul(h));
                let points = match (points, stated) {
                    (Some(p), Some(s)) if p != s => {
                        return Err(bad(format!("PCD header: POINTS {p} but WIDTH × HEIGHT {s}")));
                    }
                    (Some(p), _) => p,
                    (None, Some(s)) => s,
                    (None, None) => return Err(bad("PCD header: no POINTS nor WIDTH and HEIGHT".into())),
                };
                return Ok(Header { fields, points, viewpoint, data, start: at });
            }
            _ => {}
        }
    }
}

/// A value of `field` stored in `b` (little-endian), as f64.
fn value(b: &[u8], f: &Field) -> f64 {
    let mut a = [0u8; 8];
    a[..f.size].copy_from_slice(&b[..f.size]);
    match (f.kind, f.size) {
        (b'F', 4) => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
        (b'F', _) => f64::from_le_bytes(a),
        (b'I', 1) => a[0] as i8 as f64,
        (b'I', 2) => i16::from_le_bytes([a[0], a[1]]) as f64,
        (b'I', 4) => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
        (b'I', _) => i64::from_le_bytes(a) as f64,
        (_, 1) => a[0] as f64,
        (_, 2) => u16::from_le_bytes([a[0], a[1]]) as f64,
        (_, 4) => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
        _ => u64::from_le_bytes(a) as f64,
    }
}

/// Decodes a PCD file's bytes to its points (sensor frame, metres).
pub fn decode(bytes: &[u8], path: &Path) -> Result<Vec<Point>, SourceError> {
    let bad = |m: String| SourceError::invalid(path, m);
    let h = header(bytes, path)?;
    let xyz: Vec<usize> = ["x", "y", "z"]
        .iter()
        .map(|n| h.fields.iter().position(|f| f.name == *n))
        .collect::<Option<_>>()
        .ok_or_else(|| bad("PCD: no x, y and z fields".into()))?;
    let widths: Vec<usize> = h.fields.iter().map(|f| f.size * f.count).collect();
    let record: usize = widths.iter().sum();
    let offsets: Vec<usize> = widths.iter().scan(0, |o, w| Some(std::mem::replace(o, *o + w))).collect();
    let data = &bytes[h.start..];
    let n = h.points;
    let mut points = Vec::with_capacity(n);
    match h.data {
        Data::Ascii => {
            let text = std::str::from_utf8(data).map_err(|_| bad("PCD: ascii data is not text".into()))?;
            let mut lines = text.lines().filter(|l| !l.trim().is_empty());
            let columns: Vec<usize> = h.fields.iter().map(|f| f.count).collect();
            let starts: Vec<usize> =
                columns.iter().scan(0, |o, c| Some(std::mem::replace(o, *o + c))).collect();
            for i in 0..n {
                let line = lines.next().ok_or_else(|| bad(format!("PCD: {n} points stated, {i} present")))?;
                let words: Vec<&str> = line.split_whitespace().collect();
                let get = |k: usize| -> Result<f64, SourceError> {
                    let w = words
                        .get(starts[xyz[k]])
                        .ok_or_else(|| bad(format!("PCD: point {i}: too few values")))?;
                    w.parse().map_err(|_| bad(format!("PCD: point {i}: `{w}` is not a number")))
                };
                points.push([get(0)?, get(1)?, get(2)?]);
            }
        }
        Data::Binary => {
            let need = n.checked_mul(record).ok_or_else(|| bad("PCD: POINTS too large".into()))?;
            if data.len() < need {
                return Err(bad(format!(
                    "PCD: {n} points of {record} bytes need {need} bytes after the header (byte {}), {} present",
                    h.start,
                    data.len()
                )));
            }
            for r in data[..need].chunks_exact(record.max(1)) {
                let get = |k: usize| value(&r[offsets[xyz[k]]..], &h.fields[xyz[k]]);
                points.push([get(0), get(1), get(2)]);
            }
        }
        Data::Compressed => {
            let word = |o: usize| -> Result<usize, SourceError> {
                data.get(o..o + 4)
                    .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
                    .ok_or_else(|| bad("PCD: binary_compressed data cut short before its sizes".into()))
            };
            let (packed, unpacked) = (word(0)?, word(4)?);
            let need = n.checked_mul(record).ok_or_else(|| bad("PCD: POINTS too large".into()))?;
            if unpacked != need {
                return Err(bad(format!(
                    "PCD: binary_compressed states {unpacked} bytes uncompressed; {n} points of {record} bytes are {need}"
                )));
            }
            let body = data.get(8..8 + packed).ok_or_else(|| {
                bad(format!(
                    "PCD: binary_compressed states {packed} compressed bytes, {} present",
                    data.len() - 8
                ))
            })?;
            let plain = if need == 0 {
                Vec::new()
            } else {
                lzf::decompress(body, need)
                    .map_err(|e| bad(format!("PCD: LZF data does not decompress: {e:?}")))?
            };
            if plain.len() != need {
                return Err(bad(format!("PCD: LZF data decompresses to {} bytes, not {need}", plain.len())));
            }
            // Field by field: field f's values for every point start at n × its offset.
            for i in 0..n {
                let get = |k: usize| {
                    let f = xyz[k];
                    value(&plain[n * offsets[f] + i * widths[f]..], &h.fields[f])
                };
                points.push([get(0), get(1), get(2)]);
            }
        }
    }
    points.retain(|p| p.iter().all(|v| v.is_finite()));
    Ok(apply_viewpoint(points, &h.viewpoint))
}

/// The points in the frame of the sensor the viewpoint places (identity: unchanged).
fn apply_viewpoint(points: Vec<Point>, v: &[f64; 7]) -> Vec<Point> {
    if *v == [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0] {
        return points;
    }
    let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(v[3], v[4], v[5], v[6]));
    let t = nalgebra::Vector3::new(v[0], v[1], v[2]);
    let inverse = q.inverse();
    points
        .into_iter()
        .map(|p| {
            let s = inverse * (nalgebra::Vector3::new(p[0], p[1], p[2]) - t);
            [s.x, s.y, s.z]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pcd(header: &str, body: &[u8]) -> Vec<u8> {
        let mut b = header.as_bytes().to_vec();
        b.extend_from_slice(body);
        b
    }

    #[test]
    fn ascii_binary_and_padding() {
        let p = Path::new("t.pcd");
        let text =
            "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 3\n4 5 nan\n";
        assert_eq!(decode(text.as_bytes(), p).unwrap(), vec![[1.0, 2.0, 3.0]]);
        // x as f64, a padding field of 3 bytes, y as i16, z as u8 with COUNT 2, trailing bytes.
        let head = "FIELDS x _ y z\nSIZE 8 1 2 1\nTYPE F U I U\nCOUNT 1 3 1 2\nPOINTS 1\nDATA binary\n";
        let mut body = 1.5f64.to_le_bytes().to_vec();
        body.extend_from_slice(&[9, 9, 9]);
        body.extend_from_slice(&(-7i16).to_le_bytes());
        body.extend_from_slice(&[200, 1, 0xAA, 0xBB]);
        assert_eq!(decode(&pcd(head, &body), p).unwrap(), vec![[1.5, -7.0, 200.0]]);
    }

    #[test]
    fn bad_headers_and_short_data_are_errors_naming_the_file() {
        let p = Path::new("bad.pcd");
        let cases: [(&str, &[u8], &str); 5] = [
            (
                "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 3\nHEIGHT 1\nPOINTS 2\nDATA binary\n",
                &[],
                "WIDTH × HEIGHT",
            ),
            ("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 2\nDATA binary\n", &[0; 12], "need 24 bytes"),
            ("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 2\nDATA packed\n", &[], "unknown DATA"),
            ("FIELDS a b c\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA binary\n", &[0; 12], "no x, y and z"),
            (
                "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA binary_compressed\n",
                &[4, 0, 0, 0, 12, 0, 0, 0, 1, 2, 3, 4],
                "LZF",
            ),
        ];
        for (head, body, needle) in cases {
            let e = decode(&pcd(head, body), p).unwrap_err().to_string();
            assert!(e.contains("bad.pcd") && e.contains(needle), "{e}");
        }
    }
}
