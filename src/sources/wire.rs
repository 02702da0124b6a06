//! The two serializations of ROS messages, read and written field by field: ROS 2's CDR
//! (a 4-byte encapsulation header, then each value aligned to its size from there, in the byte
//! order the header names; XCDR2 aligns 8-byte values to 4) and ROS 1's (packed little-endian).
//! `sensor_msgs/PointCloud2` ([`super::pointcloud2`]) and the pose messages ([`super::rosmsg`])
//! are read and written through these.

/// The serializations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wire {
    /// ROS 2 CDR (with its 4-byte encapsulation header).
    Cdr,
    /// ROS 1.
    Ros1,
}

/// A cursor over a serialized message.
pub(crate) struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
    little: bool,
    /// Alignment origin (CDR: 4, after the encapsulation header); None = packed (ROS 1).
    origin: Option<usize>,
    /// XCDR2 aligns 8-byte values to 4.
    max_align: usize,
}

impl<'a> Reader<'a> {
    /// A reader of `buf` in `wire` (for CDR, after checking its encapsulation header).
    pub(crate) fn new(buf: &'a [u8], wire: Wire) -> Result<Self, String> {
        Ok(match wire {
            Wire::Cdr => {
                if buf.len() < 4 {
                    return Err("message shorter than the 4-byte CDR header".into());
                }
                let kind = buf[1];
                let xcdr2 = matches!(kind, 0x06..=0x0b | 0x10..=0x15);
                Reader {
                    buf,
                    pos: 4,
                    little: kind % 2 == 1,
                    origin: Some(4),
                    max_align: if xcdr2 { 4 } else { 8 },
                }
            }
            Wire::Ros1 => Reader { buf, pos: 0, little: true, origin: None, max_align: 8 },
        })
    }

    fn align(&mut self, n: usize) {
        if let Some(o) = self.origin {
            let n = n.min(self.max_align);
            let rel = self.pos - o;
            self.pos = o + rel.div_ceil(n) * n;
        }
    }

    /// The next `n` bytes.
    pub(crate) fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.buf.len());
        let end = end
            .ok_or_else(|| format!("message ends inside {what} (needs {n} bytes at offset {})", self.pos))?;
        let s = &self.buf[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    /// A byte.
    pub(crate) fn u8(&mut self, what: &str) -> Result<u8, String> {
        Ok(self.take(1, what)?[0])
    }

    /// A 32-bit unsigned integer.
    pub(crate) fn u32(&mut self, what: &str) -> Result<u32, String> {
        self.align(4);
        let b: [u8; 4] = self.take(4, what)?.try_into().expect("4 bytes");
        Ok(if self.little { u32::from_le_bytes(b) } else { u32::from_be_bytes(b) })
    }

    /// A float64.
    pub(crate) fn f64(&mut self, what: &str) -> Result<f64, String> {
        self.align(8);
        let b: [u8; 8] = self.take(8, what)?.try_into().expect("8 bytes");
        Ok(if self.little { f64::from_le_bytes(b) } else { f64::from_be_bytes(b) })
    }

    /// A string.
    pub(crate) fn string(&mut self, what: &str) -> Result<String, String> {
        let len = self.u32(what)? as usize;
        let bytes = self.take(len, what)?;
        // CDR counts the terminating NUL; ROS 1 does not.
        let bytes = if self.origin.is_some() { bytes.strip_suffix(&[0]).unwrap_or(bytes) } else { bytes };
        Ok(String::from_utf8_lossy(bytes).into_owned())
    }

    /// A `std_msgs/Header`: its stamp (ns) and frame id (ROS 1's `seq` read and dropped).
    pub(crate) fn header(&mut self) -> Result<(i64, String), String> {
        let stamp_ns = if self.origin.is_some() {
            let sec = self.u32("header.stamp.sec")? as i32 as i64;
            sec * 1_000_000_000 + self.u32("header.stamp.nanosec")? as i64
        } else {
            self.u32("header.seq")?;
            let sec = self.u32("header.stamp.secs")? as i64;
            sec * 1_000_000_000 + self.u32("header.stamp.nsecs")? as i64
        };
        Ok((stamp_ns, self.string("header.frame_id")?))
    }
}

/// A message being serialized, little-endian.
pub(crate) struct Writer {
    out: Vec<u8>,
    cdr: bool,
}

impl Writer {
    /// An empty message in `wire` (CDR: its little-endian encapsulation header written).
    pub(crate) fn new(wire: Wire, capacity: usize) -> Self {
        let mut out = Vec::with_capacity(capacity + 4);
        let cdr = wire == Wire::Cdr;
        if cdr {
            out.extend_from_slice(&[0, 1, 0, 0]);
        }
        Writer { out, cdr }
    }

    fn align(&mut self, n: usize) {
        if self.cdr {
            while !(self.out.len() - 4).is_multiple_of(n) {
                self.out.push(0);
            }
        }
    }

    /// A byte.
    pub(crate) fn u8(&mut self, v: u8) {
        self.out.push(v);
    }

    /// A 32-bit unsigned integer.
    pub(crate) fn u32(&mut self, v: u32) {
        self.align(4);
        self.out.extend_from_slice(&v.to_le_bytes());
    }

    /// A float64.
    pub(crate) fn f64(&mut self, v: f64) {
        self.align(8);
        self.out.extend_from_slice(&v.to_le_bytes());
    }

    /// Raw bytes.
    pub(crate) fn bytes(&mut self, b: &[u8]) {
        self.out.extend_from_slice(b);
    }

    /// A string.
    pub(crate) fn string(&mut self, s: &str) {
        self.u32((s.len() + self.cdr as usize) as u32);
        self.out.extend_from_slice(s.as_bytes());
        if self.cdr {
            self.out.push(0);
        }
    }

    /// A `std_msgs/Header` with stamp `stamp_ns` and `frame_id` (ROS 1's `seq` 0).
    pub(crate) fn header(&mut self, stamp_ns: i64, frame_id: &str) {
        let (sec, nsec) = (stamp_ns.div_euclid(1_000_000_000), stamp_ns.rem_euclid(1_000_000_000));
        if !self.cdr {
            self.u32(0);
        }
        self.u32(sec as u32);
        self.u32(nsec as u32);
        self.string(frame_id);
    }

    /// The serialized message.
    pub(crate) fn finish(self) -> Vec<u8> {
        self.out
    }
}
