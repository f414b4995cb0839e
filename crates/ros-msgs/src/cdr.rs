//! CDR as ROS 2 puts it on the wire and in bags: OMG XCDR version 1 ("plain CDR"), little
//! endian, after the 4-byte encapsulation header `00 01 00 00` (representation identifier
//! `CDR_LE` = `0x0001`, then two option bytes, zero).
//!
//! Rules (OMG DDS-XTypes 1.3, §7.4.1 "XCDR version 1"; the same as Fast CDR's default and
//! `rosbags`' serialiser):
//!
//! - a primitive of size 1, 2, 4 or 8 bytes starts at an offset that is a multiple of its size,
//!   padding with zero bytes; offsets count from the first byte **after** the encapsulation
//!   header;
//! - a `string` is a `uint32` length that counts the terminating NUL, the bytes, the NUL;
//! - a sequence (`T[]`) is a `uint32` element count, then the elements; a fixed array (`T[N]`)
//!   is the elements alone;
//! - a struct is its fields in order, with no padding of its own; `bool` is one byte, 0 or 1;
//! - nothing is added after the last field.

use crate::CdrError;

/// The encapsulation header of every message kfuse writes: `CDR_LE`, options 0.
pub const ENCAPSULATION_CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Trailing bytes after a message's last field that the decoder accepts when they are zero:
/// some writers (Fast CDR with its `serialize_encapsulation` padding, rmw's serialized
/// messages) round the message up to a multiple of 4 bytes, which adds at most 3.
pub const MAX_TRAILING_PADDING: usize = 3;

/// Writes one message body after the encapsulation header.
#[derive(Debug, Default)]
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl CdrWriter {
    /// A writer whose buffer starts with [`ENCAPSULATION_CDR_LE`].
    pub fn new() -> Self {
        Self::with_capacity(0)
    }

    /// A writer with room for `body` bytes after the header.
    pub fn with_capacity(body: usize) -> Self {
        let mut buf = Vec::with_capacity(body.saturating_add(ENCAPSULATION_CDR_LE.len()));
        buf.extend_from_slice(&ENCAPSULATION_CDR_LE);
        Self { buf }
    }

    /// The message: header and body.
    pub fn into_bytes(self) -> Vec<u8> {
        self.buf
    }

    fn align(&mut self, n: usize) {
        let offset = self.buf.len() - ENCAPSULATION_CDR_LE.len();
        let pad = (n - offset % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    /// A `uint8` (or `byte`, `char`).
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// A `bool`: one byte, 0 or 1.
    pub fn bool(&mut self, v: bool) {
        self.buf.push(u8::from(v));
    }

    /// A `uint32`, aligned to 4.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// An `int32`, aligned to 4.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A `float64`, aligned to 8.
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A sequence's element count (or a string's length): a `uint32`. Error: more than
    /// `u32::MAX`, which CDR cannot state.
    pub fn count(&mut self, n: usize, what: &'static str) -> Result<(), CdrError> {
        let n = u32::try_from(n).map_err(|_| CdrError::TooLong { what, len: n })?;
        self.u32(n);
        Ok(())
    }

    /// A `string`: its length with the NUL, the bytes, the NUL. Error: a NUL inside the text
    /// (the reader would stop there) or a text too long for CDR.
    pub fn string(&mut self, s: &str, what: &'static str) -> Result<(), CdrError> {
        if s.as_bytes().contains(&0) {
            return Err(CdrError::NulInString { what });
        }
        self.count(s.len() + 1, what)?;
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
        Ok(())
    }

    /// A `uint8[]`: its count and the bytes.
    pub fn bytes(&mut self, b: &[u8], what: &'static str) -> Result<(), CdrError> {
        self.count(b.len(), what)?;
        self.buf.extend_from_slice(b);
        Ok(())
    }

    /// A `float64[N]` (no count) or, after [`CdrWriter::count`], a sequence's elements.
    pub fn f64s(&mut self, v: &[f64]) {
        for &x in v {
            self.f64(x);
        }
    }
}

/// Reads one message body after the encapsulation header; every length is checked against the
/// bytes left before anything is allocated.
#[derive(Debug)]
pub struct CdrReader<'a> {
    body: &'a [u8],
    pos: usize,
}

impl<'a> CdrReader<'a> {
    /// A reader of `message` (header and body). Error: shorter than the header, or a header
    /// other than [`ENCAPSULATION_CDR_LE`] (big-endian and XCDR2 messages are not read).
    pub fn new(message: &'a [u8]) -> Result<Self, CdrError> {
        let Some((head, body)) = message.split_first_chunk::<4>() else {
            return Err(CdrError::Truncated {
                what: "encapsulation header",
                offset: 0,
                need: ENCAPSULATION_CDR_LE.len(),
                left: message.len(),
            });
        };
        if *head != ENCAPSULATION_CDR_LE {
            return Err(CdrError::Encapsulation(*head));
        }
        Ok(Self { body, pos: 0 })
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.body.len() - self.pos
    }

    /// Checks that the message ends here (or after at most [`MAX_TRAILING_PADDING`] zero
    /// bytes).
    pub fn finish(self, what: &'static str) -> Result<(), CdrError> {
        let rest = &self.body[self.pos..];
        if rest.len() > MAX_TRAILING_PADDING || rest.iter().any(|&b| b != 0) {
            return Err(CdrError::Trailing { what, extra: rest.len() });
        }
        Ok(())
    }

    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], CdrError> {
        if n > self.remaining() {
            return Err(CdrError::Truncated {
                what,
                offset: self.pos,
                need: n,
                left: self.remaining(),
            });
        }
        let s = &self.body[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn align(&mut self, n: usize, what: &'static str) -> Result<(), CdrError> {
        let pad = (n - self.pos % n) % n;
        self.take(pad, what).map(|_| ())
    }

    fn array<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], CdrError> {
        self.align(N, what)?;
        let s = self.take(N, what)?;
        let mut a = [0; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    /// A `uint8`.
    pub fn u8(&mut self, what: &'static str) -> Result<u8, CdrError> {
        Ok(self.take(1, what)?[0])
    }

    /// A `bool`. Error: a byte other than 0 or 1.
    pub fn bool(&mut self, what: &'static str) -> Result<bool, CdrError> {
        match self.u8(what)? {
            0 => Ok(false),
            1 => Ok(true),
            value => Err(CdrError::Bool { what, value }),
        }
    }

    /// A `uint32`.
    pub fn u32(&mut self, what: &'static str) -> Result<u32, CdrError> {
        self.array::<4>(what).map(u32::from_le_bytes)
    }

    /// An `int32`.
    pub fn i32(&mut self, what: &'static str) -> Result<i32, CdrError> {
        self.array::<4>(what).map(i32::from_le_bytes)
    }

    /// A `float64`.
    pub fn f64(&mut self, what: &'static str) -> Result<f64, CdrError> {
        self.array::<8>(what).map(f64::from_le_bytes)
    }

    /// A sequence's element count, checked: `count × min_element_bytes` must fit in the bytes
    /// left, so that a claimed length of gigabytes fails here instead of allocating.
    pub fn count(
        &mut self,
        min_element_bytes: usize,
        what: &'static str,
    ) -> Result<usize, CdrError> {
        let n = self.u32(what)? as usize;
        let need = n.saturating_mul(min_element_bytes.max(1));
        if need > self.remaining() {
            return Err(CdrError::LengthTooLarge {
                what,
                offset: self.pos,
                claimed: n,
                left: self.remaining(),
            });
        }
        Ok(n)
    }

    /// A `string`. Error: a length of 0 (no NUL), no NUL at the end, or text that is not UTF-8.
    pub fn string(&mut self, what: &'static str) -> Result<String, CdrError> {
        let n = self.count(1, what)?;
        let s = self.take(n, what)?;
        let Some((&0, text)) = s.split_last() else {
            return Err(CdrError::String { what, why: "no terminating NUL" });
        };
        let text =
            std::str::from_utf8(text).map_err(|_| CdrError::String { what, why: "not UTF-8" })?;
        Ok(text.to_owned())
    }

    /// A `uint8[]`.
    pub fn bytes(&mut self, what: &'static str) -> Result<Vec<u8>, CdrError> {
        let n = self.count(1, what)?;
        Ok(self.take(n, what)?.to_vec())
    }

    /// A `float64[N]`.
    pub fn f64_array<const N: usize>(&mut self, what: &'static str) -> Result<[f64; N], CdrError> {
        let mut a = [0.0; N];
        for v in &mut a {
            *v = self.f64(what)?;
        }
        Ok(a)
    }

    /// A `float64[]`.
    pub fn f64_seq(&mut self, what: &'static str) -> Result<Vec<f64>, CdrError> {
        // Counted against 8 bytes per element before the padding to 8 is known; the padding
        // is at most 4 bytes here, so a count that passes can still run out, and `f64` says so.
        let n = self.count(8, what)?;
        (0..n).map(|_| self.f64(what)).collect()
    }
}
