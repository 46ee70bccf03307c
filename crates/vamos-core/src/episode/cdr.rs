//! CDR (OMG XCDR version 1, the ROS 2 `cdr` message encoding): a bounds-checked decoder
//! and a little-endian encoder.
//!
//! A payload starts with a 4-byte encapsulation header: `00 00` (big endian) or `00 01`
//! (little endian), then two option bytes (ignored). Primitives are aligned to their own
//! size (8-byte types to 8) relative to the first byte after that header. Strings are a
//! `u32` length counting a trailing NUL, the bytes, and the NUL; sequences a `u32` element
//! count then the elements. Every length is checked against the bytes left before
//! anything is allocated, so a corrupt length field cannot ask for more memory than the
//! payload holds.

/// Errors of decoding a CDR payload.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CdrError {
    /// The payload ends before a field does.
    #[error("payload truncated: {field} needs {needed} bytes at offset {offset}, {available} left")]
    Truncated {
        /// The field being read.
        field: &'static str,
        /// Offset in the payload (after the encapsulation header).
        offset: usize,
        /// Bytes needed.
        needed: usize,
        /// Bytes left.
        available: usize,
    },
    /// The encapsulation header is not plain CDR (e.g. a parameter-list or XCDR2 kind).
    #[error("unsupported CDR encapsulation {kind:#06x}")]
    Encapsulation {
        /// The representation identifier (first two bytes, big endian).
        kind: u16,
    },
    /// A string is not NUL-terminated UTF-8.
    #[error("{field}: malformed string ({reason})")]
    BadString {
        /// The field being read.
        field: &'static str,
        /// What is wrong.
        reason: &'static str,
    },
}

/// Reads a CDR payload field by field.
#[derive(Debug, Clone)]
pub struct CdrReader<'a> {
    body: &'a [u8],
    pos: usize,
    little_endian: bool,
}

macro_rules! read_prim {
    ($name:ident, $t:ty, $n:expr) => {
        /// Reads one aligned value.
        pub fn $name(&mut self, field: &'static str) -> Result<$t, CdrError> {
            let b = self.take_aligned(field, $n, $n)?;
            let mut a = [0u8; $n];
            a.copy_from_slice(b);
            Ok(if self.little_endian {
                <$t>::from_le_bytes(a)
            } else {
                <$t>::from_be_bytes(a)
            })
        }
    };
}

impl<'a> CdrReader<'a> {
    /// Checks the encapsulation header and positions the reader at the first field.
    pub fn new(payload: &'a [u8]) -> Result<Self, CdrError> {
        if payload.len() < 4 {
            return Err(CdrError::Truncated {
                field: "encapsulation header",
                offset: 0,
                needed: 4,
                available: payload.len(),
            });
        }
        let kind = u16::from_be_bytes([payload[0], payload[1]]);
        let little_endian = match kind {
            0x0000 => false,
            0x0001 => true,
            _ => return Err(CdrError::Encapsulation { kind }),
        };
        Ok(Self {
            body: &payload[4..],
            pos: 0,
            little_endian,
        })
    }

    /// Whether the payload is little endian.
    pub fn is_little_endian(&self) -> bool {
        self.little_endian
    }

    /// The read position (bytes after the encapsulation header).
    pub fn position(&self) -> usize {
        self.pos
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.body.len() - self.pos
    }

    fn take_aligned(
        &mut self,
        field: &'static str,
        align: usize,
        n: usize,
    ) -> Result<&'a [u8], CdrError> {
        let start = self.pos.next_multiple_of(align);
        let available = self.body.len().saturating_sub(start);
        if n > available {
            return Err(CdrError::Truncated {
                field,
                offset: start,
                needed: n,
                available,
            });
        }
        self.pos = start + n;
        Ok(&self.body[start..start + n])
    }

    read_prim!(u16, u16, 2);
    read_prim!(i32, i32, 4);
    read_prim!(u32, u32, 4);
    read_prim!(i64, i64, 8);
    read_prim!(u64, u64, 8);
    read_prim!(f32, f32, 4);
    read_prim!(f64, f64, 8);

    /// Reads one byte.
    pub fn u8(&mut self, field: &'static str) -> Result<u8, CdrError> {
        Ok(self.take_aligned(field, 1, 1)?[0])
    }

    /// Reads a boolean (any non-zero byte is true).
    pub fn bool(&mut self, field: &'static str) -> Result<bool, CdrError> {
        Ok(self.u8(field)? != 0)
    }

    /// Reads a string.
    pub fn string(&mut self, field: &'static str) -> Result<String, CdrError> {
        let len = self.u32(field)? as usize;
        if len == 0 {
            // Some writers encode the empty string without its NUL.
            return Ok(String::new());
        }
        let bytes = self.take_aligned(field, 1, len)?;
        let (last, text) = bytes.split_last().ok_or(CdrError::BadString {
            field,
            reason: "empty",
        })?;
        if *last != 0 {
            return Err(CdrError::BadString {
                field,
                reason: "no terminating NUL",
            });
        }
        std::str::from_utf8(text)
            .map(str::to_owned)
            .map_err(|_| CdrError::BadString {
                field,
                reason: "not UTF-8",
            })
    }

    /// Reads a `u8` sequence, borrowing its bytes.
    pub fn bytes(&mut self, field: &'static str) -> Result<&'a [u8], CdrError> {
        let n = self.u32(field)? as usize;
        self.take_aligned(field, 1, n)
    }

    /// Reads a sequence length for elements of `elem_min_bytes` bytes at least, checking
    /// that the payload can hold that many before the caller allocates.
    pub fn sequence_len(
        &mut self,
        field: &'static str,
        elem_min_bytes: usize,
    ) -> Result<usize, CdrError> {
        let n = self.u32(field)? as usize;
        let needed = n.saturating_mul(elem_min_bytes.max(1));
        if needed > self.remaining() {
            return Err(CdrError::Truncated {
                field,
                offset: self.pos,
                needed,
                available: self.remaining(),
            });
        }
        Ok(n)
    }

    /// Reads a `float64` sequence.
    pub fn f64_seq(&mut self, field: &'static str) -> Result<Vec<f64>, CdrError> {
        let n = self.sequence_len(field, 8)?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            out.push(self.f64(field)?);
        }
        Ok(out)
    }

    /// Reads a fixed-size `float64` array.
    pub fn f64_array<const N: usize>(&mut self, field: &'static str) -> Result<[f64; N], CdrError> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64(field)?;
        }
        Ok(out)
    }

    /// Reads a string sequence.
    pub fn string_seq(&mut self, field: &'static str) -> Result<Vec<String>, CdrError> {
        // Each string takes at least its 4-byte length.
        let n = self.sequence_len(field, 4)?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            out.push(self.string(field)?);
        }
        Ok(out)
    }
}

/// Writes a little-endian CDR payload (with its encapsulation header).
#[derive(Debug, Clone)]
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        Self::new()
    }
}

impl CdrWriter {
    /// An empty little-endian payload (header `00 01 00 00`).
    pub fn new() -> Self {
        Self::with_capacity(64)
    }

    /// As [`CdrWriter::new`] with room for `bytes` of fields.
    pub fn with_capacity(bytes: usize) -> Self {
        let mut buf = Vec::with_capacity(bytes + 4);
        buf.extend_from_slice(&[0, 1, 0, 0]);
        Self { buf }
    }

    fn align(&mut self, n: usize) {
        let body = self.buf.len() - 4;
        let pad = body.next_multiple_of(n) - body;
        self.buf.extend(std::iter::repeat_n(0u8, pad));
    }

    /// Writes one byte.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// Writes a boolean.
    pub fn bool(&mut self, v: bool) {
        self.buf.push(u8::from(v));
    }

    /// Writes an aligned `i32`.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes an aligned `u32`.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes an aligned `f64`.
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes a string (length with NUL, bytes, NUL). Lengths over `u32::MAX` saturate,
    /// which a reader then rejects; ROS strings are far shorter.
    pub fn string(&mut self, s: &str) {
        self.u32(u32::try_from(s.len() + 1).unwrap_or(u32::MAX));
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    /// Writes a `u8` sequence.
    pub fn bytes(&mut self, b: &[u8]) {
        self.u32(u32::try_from(b.len()).unwrap_or(u32::MAX));
        self.buf.extend_from_slice(b);
    }

    /// Writes a `float64` sequence.
    pub fn f64_seq(&mut self, v: &[f64]) {
        self.u32(u32::try_from(v.len()).unwrap_or(u32::MAX));
        for &x in v {
            self.f64(x);
        }
    }

    /// Writes a fixed-size `float64` array.
    pub fn f64_array(&mut self, v: &[f64]) {
        for &x in v {
            self.f64(x);
        }
    }

    /// Writes a string sequence.
    pub fn string_seq(&mut self, v: &[String]) {
        self.u32(u32::try_from(v.len()).unwrap_or(u32::MAX));
        for s in v {
            self.string(s);
        }
    }

    /// The finished payload.
    pub fn into_bytes(self) -> Vec<u8> {
        self.buf
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_with_alignment_relative_to_the_body() {
        let mut w = CdrWriter::new();
        w.u8(7);
        w.f64(1.5);
        w.string("ab");
        w.bool(true);
        w.i32(-3);
        w.f64_seq(&[2.0, -4.25]);
        w.string_seq(&["x".into(), "".into()]);
        let b = w.into_bytes();
        // u8 at 0, pad to 8, f64 at 8..16, len at 16..20, "ab\0" at 20..23, bool at 23,
        // i32 at 24..28, seq len at 28..32, f64s at 32..48, seq len 48..52, "x\0" len
        // 52..56 + 56..58, pad to 60, "" len 60..64 + NUL at 64.
        assert_eq!(&b[..4], &[0, 1, 0, 0]);
        assert_eq!(b[4 + 8..4 + 16], 1.5f64.to_le_bytes());
        assert_eq!(b.len(), 4 + 65);
        let mut r = CdrReader::new(&b).unwrap();
        assert_eq!(r.u8("a").unwrap(), 7);
        assert_eq!(r.f64("b").unwrap(), 1.5);
        assert_eq!(r.position(), 16);
        assert_eq!(r.string("c").unwrap(), "ab");
        assert!(r.bool("d").unwrap());
        assert_eq!(r.i32("e").unwrap(), -3);
        assert_eq!(r.f64_seq("f").unwrap(), vec![2.0, -4.25]);
        assert_eq!(r.string_seq("g").unwrap(), vec!["x", ""]);
        assert_eq!(r.remaining(), 0);
    }

    #[test]
    fn big_endian_payloads_decode() {
        // header 00 00 = CDR_BE; u32 0x01020304, pad, f64 2.0 at body offset 8.
        let mut p = vec![0, 0, 0, 0, 1, 2, 3, 4, 0, 0, 0, 0];
        p.extend_from_slice(&2.0f64.to_be_bytes());
        let mut r = CdrReader::new(&p).unwrap();
        assert!(!r.is_little_endian());
        assert_eq!(r.u32("a").unwrap(), 0x0102_0304);
        assert_eq!(r.f64("b").unwrap(), 2.0);
    }

    #[test]
    fn lying_lengths_and_bad_headers_are_errors() {
        // A sequence claiming 2^31 doubles in a 12-byte payload: no allocation, an error.
        let p = [0u8, 1, 0, 0, 0, 0, 0, 0x80, 1, 2, 3, 4];
        let mut r = CdrReader::new(&p).unwrap();
        assert!(matches!(
            r.f64_seq("position"),
            Err(CdrError::Truncated {
                field: "position",
                ..
            })
        ));
        let mut r = CdrReader::new(&p).unwrap();
        assert!(matches!(r.bytes("data"), Err(CdrError::Truncated { .. })));
        assert!(matches!(
            CdrReader::new(&[0, 2, 0, 0]),
            Err(CdrError::Encapsulation { kind: 2 })
        ));
        assert!(matches!(
            CdrReader::new(&[0, 1]),
            Err(CdrError::Truncated { .. })
        ));
        // A string without its NUL.
        let p = [0u8, 1, 0, 0, 2, 0, 0, 0, b'a', b'b'];
        let mut r = CdrReader::new(&p).unwrap();
        assert!(matches!(r.string("s"), Err(CdrError::BadString { .. })));
    }
}
