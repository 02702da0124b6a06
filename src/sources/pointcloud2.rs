//! `sensor_msgs/PointCloud2` messages (`sensor_msgs/msg/PointCloud2.msg`) in the ROS 2 CDR and
//! ROS 1 serializations, and Foxglove's `PointCloud` (protobuf),
//! decoded by the message's own `fields`: x, y, z and optional intensity and ring of any
//! numeric type, any `point_step` and `row_step`, either byte order, organized or not.
//! Points with a non-finite coordinate and exact `(0, 0, 0)` points (the no-return value of
//! Ouster and others) are dropped; `raw_points` counts them all.

use super::wire::{Reader, Wire, Writer};

/// Datatype codes of `sensor_msgs/PointField`.
pub mod datatype {
    /// int8
    pub const INT8: u8 = 1;
    /// uint8
    pub const UINT8: u8 = 2;
    /// int16
    pub const INT16: u8 = 3;
    /// uint16
    pub const UINT16: u8 = 4;
    /// int32
    pub const INT32: u8 = 5;
    /// uint32
    pub const UINT32: u8 = 6;
    /// float32
    pub const FLOAT32: u8 = 7;
    /// float64
    pub const FLOAT64: u8 = 8;
}

/// Size in bytes of a PointField datatype.
pub(crate) fn datatype_size(datatype: u8) -> Option<usize> {
    Some(match datatype {
        1 | 2 => 1,
        3 | 4 => 2,
        5..=7 => 4,
        8 => 8,
        _ => return None,
    })
}

/// One `PointField`.
#[derive(Clone, Debug, PartialEq)]
pub struct PointField {
    /// Field name.
    pub name: String,
    /// Byte offset in a point.
    pub offset: u32,
    /// Datatype code.
    pub datatype: u8,
    /// Element count.
    pub count: u32,
}

/// A parsed `PointCloud2`, borrowing its data.
#[derive(Clone, Debug)]
pub struct PointCloud2<'a> {
    /// Header stamp in nanoseconds.
    pub stamp_ns: i64,
    /// Header frame id.
    pub frame_id: String,
    /// Rows (1 for unorganized clouds).
    pub height: u32,
    /// Points per row.
    pub width: u32,
    /// Field layout.
    pub fields: Vec<PointField>,
    /// Byte order of `data`.
    pub is_bigendian: bool,
    /// Bytes per point.
    pub point_step: u32,
    /// Bytes per row.
    pub row_step: u32,
    /// Point bytes.
    pub data: &'a [u8],
}

/// The encodings understood.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// ROS 2 CDR (with its 4-byte encapsulation header).
    Cdr,
    /// ROS 1 serialization.
    Ros1,
    /// `foxglove.PointCloud` in protobuf.
    FoxgloveProtobuf,
}

impl Encoding {
    /// The encoding of an MCAP channel's messages.
    pub fn of_channel(message_encoding: &str) -> Self {
        match message_encoding {
            "cdr" => Encoding::Cdr,
            "protobuf" => Encoding::FoxgloveProtobuf,
            _ => Encoding::Ros1,
        }
    }
}

/// Parses a serialized `PointCloud2` (or `foxglove.PointCloud`).
pub fn parse(buf: &[u8], encoding: Encoding) -> Result<PointCloud2<'_>, String> {
    let wire = match encoding {
        Encoding::FoxgloveProtobuf => return parse_foxglove(buf),
        Encoding::Cdr => Wire::Cdr,
        Encoding::Ros1 => Wire::Ros1,
    };
    let mut c = Reader::new(buf, wire)?;
    let (stamp_ns, frame_id) = c.header()?;
    let height = c.u32("height")?;
    let width = c.u32("width")?;
    let n_fields = c.u32("fields")? as usize;
    if n_fields > 1024 {
        return Err(format!("{n_fields} fields: corrupt message"));
    }
    let mut fields = Vec::with_capacity(n_fields);
    for _ in 0..n_fields {
        let name = c.string("field name")?;
        let offset = c.u32("field offset")?;
        let datatype = c.u8("field datatype")?;
        let count = c.u32("field count")?;
        fields.push(PointField { name, offset, datatype, count });
    }
    let is_bigendian = c.u8("is_bigendian")? != 0;
    let point_step = c.u32("point_step")?;
    let row_step = c.u32("row_step")?;
    let len = c.u32("data")? as usize;
    let data = c.take(len, "data")?;
    Ok(PointCloud2 { stamp_ns, frame_id, height, width, fields, is_bigendian, point_step, row_step, data })
}

/// Points of a cloud in metres, with optional per-point channels.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DecodedCloud {
    /// Kept points.
    pub points: Vec<[f64; 3]>,
    /// Intensity of kept points, when the cloud has a field `intensity` (or `reflectance`).
    pub intensity: Option<Vec<f32>>,
    /// Ring of kept points, when the cloud has a field `ring` (or `laser_id`).
    pub ring: Option<Vec<u16>>,
    /// Points in the message, before dropping non-finite and zero points.
    pub raw_points: usize,
}

type ReadFn = fn(&[u8]) -> f64;

fn read_fn(datatype: u8, big: bool) -> Option<ReadFn> {
    macro_rules! f {
        ($t:ty, $n:expr) => {
            if big {
                |b: &[u8]| <$t>::from_be_bytes(b[..$n].try_into().unwrap()) as f64
            } else {
                |b: &[u8]| <$t>::from_le_bytes(b[..$n].try_into().unwrap()) as f64
            }
        };
    }
    Some(match datatype {
        datatype::INT8 => |b: &[u8]| b[0] as i8 as f64,
        datatype::UINT8 => |b: &[u8]| b[0] as f64,
        datatype::INT16 => f!(i16, 2),
        datatype::UINT16 => f!(u16, 2),
        datatype::INT32 => f!(i32, 4),
        datatype::UINT32 => f!(u32, 4),
        datatype::FLOAT32 => f!(f32, 4),
        datatype::FLOAT64 => f!(f64, 8),
        _ => return None,
    })
}

impl PointCloud2<'_> {
    /// Looks up a field by name; checks it fits in `point_step`.
    fn field(&self, names: &[&str]) -> Result<Option<(usize, ReadFn)>, String> {
        let Some(f) = self.fields.iter().find(|f| names.contains(&f.name.as_str())) else {
            return Ok(None);
        };
        let size = datatype_size(f.datatype)
            .ok_or_else(|| format!("field `{}` has unknown datatype {}", f.name, f.datatype))?;
        if f.offset as usize + size > self.point_step as usize {
            return Err(format!(
                "field `{}` (offset {}, {size} bytes) does not fit in point_step {}",
                f.name, f.offset, self.point_step
            ));
        }
        Ok(Some((f.offset as usize, read_fn(f.datatype, self.is_bigendian).unwrap())))
    }

    /// Decodes the points (see the module doc for what is dropped).
    pub fn decode(&self) -> Result<DecodedCloud, String> {
        let [x, y, z] = ["x", "y", "z"].map(|n| self.field(&[n]));
        let (Some(x), Some(y), Some(z)) = (x?, y?, z?) else {
            let names: Vec<&str> = self.fields.iter().map(|f| f.name.as_str()).collect();
            return Err(format!("PointCloud2 has no x, y, z fields (fields: {names:?})"));
        };
        let intensity = self.field(&["intensity", "reflectance", "i"])?;
        let ring = self.field(&["ring", "laser_id"])?;
        let (h, w, ps, rs) =
            (self.height as usize, self.width as usize, self.point_step as usize, self.row_step as usize);
        if w > 0 && h > 0 && ps == 0 {
            return Err("point_step is 0".into());
        }
        if h > 0 && rs < w * ps {
            return Err(format!("row_step {rs} is smaller than width {w} × point_step {ps}"));
        }
        let needed = if h == 0 { 0 } else { (h - 1) * rs + w * ps };
        if self.data.len() < needed {
            return Err(format!(
                "data has {} bytes; height {h} × row_step {rs} needs {needed}",
                self.data.len()
            ));
        }
        let raw = h * w;
        let mut out = DecodedCloud {
            points: Vec::with_capacity(raw),
            intensity: intensity.map(|_| Vec::with_capacity(raw)),
            ring: ring.map(|_| Vec::with_capacity(raw)),
            raw_points: raw,
        };
        for row in 0..h {
            let row_bytes = &self.data[row * rs..row * rs + w * ps];
            for p in row_bytes.chunks_exact(ps) {
                let q = [x.1(&p[x.0..]), y.1(&p[y.0..]), z.1(&p[z.0..])];
                if !super::is_return(&q) {
                    continue;
                }
                out.points.push(q);
                if let (Some(v), Some(f)) = (&mut out.intensity, intensity) {
                    v.push(f.1(&p[f.0..]) as f32);
                }
                if let (Some(v), Some(f)) = (&mut out.ring, ring) {
                    v.push(f.1(&p[f.0..]) as u16);
                }
            }
        }
        Ok(out)
    }
}

/// Serializes a `PointCloud2` little-endian (test fixtures, the simulator's MCAP writer).
pub fn serialize(cloud: &PointCloud2<'_>, encoding: Encoding) -> Vec<u8> {
    assert_ne!(encoding, Encoding::FoxgloveProtobuf, "serialize writes PointCloud2");
    let wire = if encoding == Encoding::Cdr { Wire::Cdr } else { Wire::Ros1 };
    let mut out = Writer::new(wire, cloud.data.len() + 256);
    out.header(cloud.stamp_ns, &cloud.frame_id);
    out.u32(cloud.height);
    out.u32(cloud.width);
    out.u32(cloud.fields.len() as u32);
    for f in &cloud.fields {
        out.string(&f.name);
        out.u32(f.offset);
        out.u8(f.datatype);
        out.u32(f.count);
    }
    out.u8(cloud.is_bigendian as u8);
    out.u32(cloud.point_step);
    out.u32(cloud.row_step);
    out.u32(cloud.data.len() as u32);
    out.bytes(cloud.data);
    out.u8(1); // is_dense
    out.finish()
}

/// Parses a `foxglove.PointCloud` protobuf message (Foxglove's `PointCloud.proto` schema) into the PointCloud2 form
/// (one row, little-endian), mapping Foxglove's numeric types onto PointField codes. The
/// message's `pose` is ignored: points stay in the cloud's own frame.
pub(crate) fn parse_foxglove(buf: &[u8]) -> Result<PointCloud2<'_>, String> {
    let mut pb = Protobuf { buf, pos: 0 };
    let mut cloud = PointCloud2 {
        stamp_ns: 0,
        frame_id: String::new(),
        height: 1,
        width: 0,
        fields: Vec::new(),
        is_bigendian: false,
        point_step: 0,
        row_step: 0,
        data: &[],
    };
    while let Some((field, wire)) = pb.key()? {
        match (field, wire) {
            (1, 2) => {
                let mut ts = Protobuf { buf: pb.bytes()?, pos: 0 };
                let (mut sec, mut nsec) = (0i64, 0i64);
                while let Some((f, w)) = ts.key()? {
                    match (f, w) {
                        (1, 0) => sec = ts.varint()? as i64,
                        (2, 0) => nsec = ts.varint()? as i32 as i64,
                        _ => ts.skip(w)?,
                    }
                }
                cloud.stamp_ns = sec * 1_000_000_000 + nsec;
            }
            (2, 2) => cloud.frame_id = String::from_utf8_lossy(pb.bytes()?).into_owned(),
            (4, 5) => cloud.point_step = pb.fixed32()?,
            (5, 2) => {
                let mut f = Protobuf { buf: pb.bytes()?, pos: 0 };
                let mut field = PointField { name: String::new(), offset: 0, datatype: 0, count: 1 };
                while let Some((k, w)) = f.key()? {
                    match (k, w) {
                        (1, 2) => field.name = String::from_utf8_lossy(f.bytes()?).into_owned(),
                        (2, 5) => field.offset = f.fixed32()?,
                        (3, 0) => {
                            // Foxglove NumericType → PointField datatype.
                            field.datatype = match f.varint()? {
                                1 => datatype::UINT8,
                                2 => datatype::INT8,
                                3 => datatype::UINT16,
                                4 => datatype::INT16,
                                5 => datatype::UINT32,
                                6 => datatype::INT32,
                                7 => datatype::FLOAT32,
                                8 => datatype::FLOAT64,
                                other => {
                                    return Err(format!(
                                        "field `{}`: unknown numeric type {other}",
                                        field.name
                                    ));
                                }
                            }
                        }
                        _ => f.skip(w)?,
                    }
                }
                cloud.fields.push(field);
            }
            (6, 2) => cloud.data = pb.bytes()?,
            _ => pb.skip(wire)?,
        }
    }
    if cloud.point_step > 0 {
        cloud.width = (cloud.data.len() / cloud.point_step as usize) as u32;
        cloud.row_step = cloud.width * cloud.point_step;
    } else if !cloud.data.is_empty() {
        return Err("point_stride is 0".into());
    }
    Ok(cloud)
}

/// A protobuf wire-format cursor (just what `foxglove.PointCloud` needs).
struct Protobuf<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Protobuf<'a> {
    fn varint(&mut self) -> Result<u64, String> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let b = *self.buf.get(self.pos).ok_or("protobuf: truncated varint")?;
            self.pos += 1;
            v |= ((b & 0x7f) as u64) << shift;
            if b & 0x80 == 0 {
                return Ok(v);
            }
        }
        Err("protobuf: varint too long".into())
    }

    fn key(&mut self) -> Result<Option<(u64, u8)>, String> {
        if self.pos >= self.buf.len() {
            return Ok(None);
        }
        let k = self.varint()?;
        Ok(Some((k >> 3, (k & 7) as u8)))
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end =
            self.pos.checked_add(n).filter(|&e| e <= self.buf.len()).ok_or("protobuf: truncated field")?;
        let s = &self.buf[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    fn bytes(&mut self) -> Result<&'a [u8], String> {
        let n = usize::try_from(self.varint()?).map_err(|_| "protobuf: length overflow")?;
        self.take(n)
    }

    fn fixed32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }

    fn skip(&mut self, wire: u8) -> Result<(), String> {
        match wire {
            0 => self.varint().map(drop),
            1 => self.take(8).map(drop),
            2 => self.bytes().map(drop),
            5 => self.take(4).map(drop),
            w => Err(format!("protobuf: unsupported wire type {w}")),
        }
    }
}
