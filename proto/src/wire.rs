//! Little-endian binary encoding shared by the bundle format and the shape-operator cache.
//!
//! Invariant: [`Reader`] never panics and never allocates more than the bytes it has been given
//! can justify: every length is checked against what remains before a vector is reserved.

/// Why bytes could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    #[error("truncated: needed {needed} bytes at offset {offset}, {available} available")]
    Truncated {
        offset: usize,
        needed: usize,
        available: usize,
    },
    #[error("{0}")]
    Invalid(String),
}

/// Appends values to a byte vector.
#[derive(Default)]
pub struct Writer {
    pub bytes: Vec<u8>,
}

impl Writer {
    pub fn new() -> Self {
        Self::default()
    }
    pub fn u8(&mut self, v: u8) {
        self.bytes.push(v);
    }
    pub fn u32(&mut self, v: u32) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }
    pub fn u64(&mut self, v: u64) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }
    pub fn f32(&mut self, v: f32) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }
    pub fn f64(&mut self, v: f64) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }
    pub fn str(&mut self, s: &str) {
        self.u32(s.len() as u32);
        self.bytes.extend_from_slice(s.as_bytes());
    }
    pub fn f32s(&mut self, v: &[f32]) {
        self.u64(v.len() as u64);
        self.bytes.reserve(4 * v.len());
        for x in v {
            self.f32(*x);
        }
    }
    pub fn f64s(&mut self, v: &[f64]) {
        self.u64(v.len() as u64);
        self.bytes.reserve(8 * v.len());
        for x in v {
            self.f64(*x);
        }
    }
    pub fn u32s(&mut self, v: &[u32]) {
        self.u64(v.len() as u64);
        self.bytes.reserve(4 * v.len());
        for x in v {
            self.u32(*x);
        }
    }
}

/// Reads values back, checking bounds.
pub struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub fn new(bytes: &'a [u8]) -> Self {
        Reader { bytes, pos: 0 }
    }
    pub fn remaining(&self) -> usize {
        self.bytes.len() - self.pos
    }
    pub fn position(&self) -> usize {
        self.pos
    }
    pub fn take(&mut self, n: usize) -> Result<&'a [u8], WireError> {
        if n > self.remaining() {
            return Err(WireError::Truncated {
                offset: self.pos,
                needed: n,
                available: self.remaining(),
            });
        }
        let out = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(out)
    }
    pub fn u8(&mut self) -> Result<u8, WireError> {
        Ok(self.take(1)?[0])
    }
    pub fn u32(&mut self) -> Result<u32, WireError> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }
    pub fn u64(&mut self) -> Result<u64, WireError> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    pub fn f32(&mut self) -> Result<f32, WireError> {
        Ok(f32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }
    pub fn f64(&mut self) -> Result<f64, WireError> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    pub fn str(&mut self) -> Result<String, WireError> {
        let n = self.u32()? as usize;
        let bytes = self.take(n)?;
        String::from_utf8(bytes.to_vec())
            .map_err(|_| WireError::Invalid("string is not UTF-8".into()))
    }
    fn len(&mut self, elem: usize) -> Result<usize, WireError> {
        let n = self.u64()?;
        let bytes = n
            .checked_mul(elem as u64)
            .filter(|b| *b <= self.remaining() as u64);
        match bytes {
            Some(_) => Ok(n as usize),
            None => Err(WireError::Truncated {
                offset: self.pos,
                needed: n.saturating_mul(elem as u64).min(usize::MAX as u64) as usize,
                available: self.remaining(),
            }),
        }
    }
    pub fn f32s(&mut self) -> Result<Vec<f32>, WireError> {
        let n = self.len(4)?;
        let raw = self.take(n * 4)?;
        Ok(raw
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect())
    }
    pub fn f64s(&mut self) -> Result<Vec<f64>, WireError> {
        let n = self.len(8)?;
        let raw = self.take(n * 8)?;
        Ok(raw
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect())
    }
    pub fn u32s(&mut self) -> Result<Vec<u32>, WireError> {
        let n = self.len(4)?;
        let raw = self.take(n * 4)?;
        Ok(raw
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
            .collect())
    }
    /// A LEB128 varint of at most [`VARINT_MAX_BYTES`] bytes (what [`push_varint`] writes for
    /// a value below 2³⁵), refused when longer.
    pub fn varint(&mut self) -> Result<u64, WireError> {
        let mut v: u64 = 0;
        for shift in (0..7 * VARINT_MAX_BYTES).step_by(7) {
            let b = self.u8()?;
            v |= ((b & 0x7f) as u64) << shift;
            if b & 0x80 == 0 {
                return Ok(v);
            }
        }
        Err(WireError::Invalid(format!(
            "varint longer than {VARINT_MAX_BYTES} bytes"
        )))
    }
}

/// The longest varint [`Reader::varint`] reads: 35 bits, room for a u32 or a zigzagged step
/// between two u32s.
pub const VARINT_MAX_BYTES: usize = 5;

/// Appends `v` as a LEB128 varint: 7 bits a byte, low bits first, the top bit set on every byte
/// but the last.
pub fn push_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// FNV-1a 64-bit checksum (detects corruption, not tampering).
pub fn checksum(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf29ce484222325;
    for b in bytes {
        h ^= *b as u64;
        h = h.wrapping_mul(0x100000001b3);
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn reader_never_panics_on_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
            let mut r = Reader::new(&bytes);
            let _ = r.f32s();
            let _ = r.str();
            let _ = r.u32s();
            let _ = r.f64s();
        }

        #[test]
        fn values_round_trip(a in any::<u32>(), b in proptest::collection::vec(any::<f32>(), 0..64), s in ".{0,20}") {
            let mut w = Writer::new();
            w.u32(a);
            w.f32s(&b);
            w.str(&s);
            let mut r = Reader::new(&w.bytes);
            prop_assert_eq!(r.u32().unwrap(), a);
            let back = r.f32s().unwrap();
            prop_assert_eq!(back.len(), b.len());
            for (x, y) in back.iter().zip(&b) {
                prop_assert_eq!(x.to_bits(), y.to_bits());
            }
            prop_assert_eq!(r.str().unwrap(), s);
            prop_assert_eq!(r.remaining(), 0);
        }
    }
}
