//! USB traces a user can send (`.kftrace`): the control transcript and the stream transfers'
//! headers of a session, recorded at the [`UsbBackend`](crate::backend::UsbBackend) boundary by
//! [`TracingBackend`], and replayed through the same protocol code and stream parsers
//! ([`replay_trace`]: `KinectDevice` over a backend that answers from the trace).
//!
//! # File format (`.kftrace`, little-endian, version 1)
//!
//! ```text
//! "KFUSETRC"            8 bytes magic
//! u32 version = 1
//! u32 flags             bit 0: events carry their whole payload
//! u64 start             host time the trace began, µs since the Unix epoch
//! u32 CRC-32 of the header bytes before it
//! records, each:        u8 tag, u32 body length (≤ TRACE_MAX_RECORD), body,
//!                       u32 CRC-32 of tag, length and body
//!   every body starts:  u64 µs since the trace began
//!   tag 1 call:         u8 op, u8 a, u8 b, u16 value, u16 index, u32 buffer size,
//!                       u8 error (0 = ok, 1..9 timeout, stall, busy, no device, overflow,
//!                       access, no memory, I/O, not supported), u32 returned number,
//!                       u32 n, n bytes (sent, or received by a bulk IN)
//!   tag 2 stream start: u8 kind (0 bulk, 1 isochronous), u8 endpoint, u32 transfers,
//!                       u32 packets per transfer, u32 bytes per packet / transfer, u8 error
//!   tag 3 event:        u8 endpoint, u8 kind (1 iso packet, 2 bulk transfer, 3 retired,
//!                       4 stopped), u8 status (0 completed, 1 error, 2 timed out,
//!                       3 cancelled) / error / stop reason (0 requested, 1 disconnected,
//!                       2 stalled), u32 actual length / transfers still in flight,
//!                       u32 n, n head bytes, u32 m, m tail bytes
//!   tag 4 stream stop:  u8 endpoint, u8 error
//! end record:           tag 0xEE, body u64 0, u64 records, u64 events left out
//! ```
//!
//! Without the payload flag an event keeps only what the parsers frame with: the last
//! [`TRACE_ISO_TAIL`] bytes of an isochronous packet (the depth footer, protocol §7) and the
//! first [`TRACE_BULK_HEAD`] and last [`TRACE_BULK_TAIL`] bytes of a bulk transfer (the colour
//! header, JPEG end, filler and footer, §6); no image. Events after [`TRACE_MAX_EVENT_BYTES`]
//! are counted in the end record instead of written. A trace is written to a temporary file
//! beside its name and renamed into place when it is finished, so a trace that exists is
//! whole; a missing end record, a checksum that does not match or an out-of-range field is
//! refused with [`KinectError::Trace`](crate::KinectError::Trace).

mod format;
mod record;
mod replay;

pub use format::{
    CallOp, CallRecord, FLAG_PAYLOAD, TRACE_MAGIC, TRACE_MAX_EVENT_LENGTH, TRACE_MAX_RECORD,
    TRACE_VERSION, TraceRecord, TracedEvent,
};
pub use record::{TraceHandle, TraceSummary, TracingBackend};
pub use replay::{ReplayedFrame, TraceEnd, TraceReplay, TraceReplayReport, replay_trace};

use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use crate::error::{KinectError, Result};
use format::{TAG_END, decode};

/// Bytes kept from the end of an isochronous packet: the 152-byte depth footer (protocol §7),
/// which ends a sub-packet and may straddle its last two packets (each keeps its own tail).
pub const TRACE_ISO_TAIL: usize = 152;
/// Bytes kept from the start of a bulk transfer: the colour packet's sequence and magic
/// (protocol §6).
pub const TRACE_BULK_HEAD: usize = 8;
/// Bytes kept from the end of a bulk transfer: the 56-byte colour footer, the filler before it
/// (the simulator's is at most 252 bytes, a real sensor's has not been seen longer) and the
/// JPEG end marker with its 0–3 padding bytes, with room to spare.
pub const TRACE_BULK_TAIL: usize = 1024;
/// Event bytes written at most (records, headers included): about a minute of both streams'
/// headers, a file small enough to attach to a bug report; later events are counted only.
pub const TRACE_MAX_EVENT_BYTES: u64 = 64 << 20;
/// Header bytes (magic, version, flags, start, CRC).
const HEADER_BYTES: usize = 8 + 4 + 4 + 8 + 4;

fn trace_err(path: &Path, offset: u64, detail: impl Into<String>) -> KinectError {
    KinectError::Trace { path: path.to_path_buf(), offset, detail: detail.into() }
}

/// Reads a trace one record at a time (memory bounded by [`TRACE_MAX_RECORD`]).
pub struct TraceReader<R: Read> {
    r: R,
    path: PathBuf,
    offset: u64,
    flags: u32,
    records: u64,
    omitted: Option<u64>,
}

impl TraceReader<BufReader<std::fs::File>> {
    /// Opens `path` and checks its header.
    pub fn open(path: &Path) -> Result<Self> {
        let f = std::fs::File::open(path)
            .map_err(|source| KinectError::File { path: path.to_path_buf(), source })?;
        Self::new(BufReader::new(f), path)
    }
}

impl<R: Read> TraceReader<R> {
    /// Reads and checks the header of `r` (`path` names it in errors).
    pub fn new(mut r: R, path: &Path) -> Result<Self> {
        let mut h = [0u8; HEADER_BYTES];
        let got = read_full(&mut r, &mut h).map_err(|e| trace_err(path, 0, e.to_string()))?;
        if got >= 8 && &h[..8] != TRACE_MAGIC {
            return Err(trace_err(path, 0, "not a kfuse USB trace (no KFUSETRC magic)"));
        }
        if got < HEADER_BYTES {
            return Err(trace_err(path, got as u64, "truncated header"));
        }
        let version = u32::from_le_bytes([h[8], h[9], h[10], h[11]]);
        if version != TRACE_VERSION {
            return Err(trace_err(
                path,
                8,
                format!(
                    "format version {version}, this kfuse reads version {TRACE_VERSION}; \
                     replay it with the kfuse that recorded it"
                ),
            ));
        }
        let crc = u32::from_le_bytes([h[24], h[25], h[26], h[27]]);
        if crc32fast::hash(&h[..24]) != crc {
            return Err(trace_err(path, 24, "header checksum does not match"));
        }
        let flags = u32::from_le_bytes([h[12], h[13], h[14], h[15]]);
        Ok(TraceReader {
            r,
            path: path.to_path_buf(),
            offset: HEADER_BYTES as u64,
            flags,
            records: 0,
            omitted: None,
        })
    }

    /// Whether events carry their whole payload.
    pub fn payload(&self) -> bool {
        self.flags & FLAG_PAYLOAD != 0
    }

    /// Events left out because the trace reached [`TRACE_MAX_EVENT_BYTES`] (known once the
    /// end record was read).
    pub fn omitted(&self) -> Option<u64> {
        self.omitted
    }

    /// The file this reads.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Byte offset of the next record.
    pub fn offset(&self) -> u64 {
        self.offset
    }

    /// The next record; `None` after the end record. A file that stops before its end record,
    /// a checksum mismatch or a malformed record is an error naming the byte offset.
    pub fn next_record(&mut self) -> Result<Option<TraceRecord>> {
        if self.omitted.is_some() {
            return Ok(None);
        }
        let at = self.offset;
        let mut head = [0u8; 5];
        let got = read_full(&mut self.r, &mut head).map_err(|e| self.err(at, e.to_string()))?;
        if got < head.len() {
            return Err(self.err(at, "truncated: the trace ends without its end record"));
        }
        let len = u32::from_le_bytes([head[1], head[2], head[3], head[4]]) as usize;
        if len > TRACE_MAX_RECORD {
            return Err(self.err(
                at,
                format!("a record of {len} bytes (at most {TRACE_MAX_RECORD}): damaged"),
            ));
        }
        let mut body = vec![0u8; len + 4];
        let got = read_full(&mut self.r, &mut body).map_err(|e| self.err(at, e.to_string()))?;
        if got < body.len() {
            return Err(self.err(at, "truncated: the trace ends inside a record"));
        }
        let crc = u32::from_le_bytes([body[len], body[len + 1], body[len + 2], body[len + 3]]);
        let mut h = crc32fast::Hasher::new();
        h.update(&head);
        h.update(&body[..len]);
        if h.finalize() != crc {
            return Err(self.err(at, format!("record {} checksum does not match", self.records)));
        }
        self.offset += (5 + len + 4) as u64;
        let body = &body[..len];
        if head[0] == TAG_END {
            let mut f = format::Fields::new(body);
            let end = (|| Ok::<_, String>((f.u64()?, f.u64()?, f.u64()?, f.done()?)))();
            let (_, count, omitted, ()) = end.map_err(|e| self.err(at, e))?;
            if count != self.records {
                return Err(self.err(
                    at,
                    format!("the end record counts {count} records, {} were read", self.records),
                ));
            }
            self.omitted = Some(omitted);
            return Ok(None);
        }
        let r = decode(head[0], body).map_err(|e| self.err(at, e))?;
        self.records += 1;
        Ok(Some(r))
    }

    fn err(&self, offset: u64, detail: impl Into<String>) -> KinectError {
        trace_err(&self.path, offset, detail)
    }
}

/// Reads until `buf` is full or the end of `r`; returns the bytes read.
fn read_full(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

/// Every record of the trace at `path` (checked whole: a damaged trace is an error).
pub fn read_trace(path: &Path) -> Result<Vec<TraceRecord>> {
    let mut r = TraceReader::open(path)?;
    let mut out = Vec::new();
    while let Some(rec) = r.next_record()? {
        out.push(rec);
    }
    Ok(out)
}
