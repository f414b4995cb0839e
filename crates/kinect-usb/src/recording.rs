//! Raw recordings: the device metadata plus every stream event, replayable through the same
//! code path as a live device.
//!
//! # File format (`.kfrec`, little-endian, version 1)
//!
//! ```text
//! "KFUSEREC"                  8 bytes magic
//! u32 version = 1
//! 6 × (u32 length, bytes)     firmware (UTF-8), serial (UTF-8), hardware info,
//!                             depth-params response, P0 response, colour-params response
//! records, each:  u8 kind (1 = iso packet, 2 = bulk transfer), u8 status
//!                 (0 completed, 1 error, 2 timed out, 3 cancelled), u32 length, bytes
//! end record:     u8 kind = 0xEE, u8 0, u32 length = 8, u64 number of records
//! ```
//!
//! A file without the end record, with a record cut short, or whose count disagrees is
//! reported as truncated/corrupt with the byte offset; [`read_recording`] can optionally keep
//! the intact prefix.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::backend::{StreamEvent, XferStatus};
use crate::device::{DeviceInfo, StreamKind};
use crate::error::{KinectError, Result};

/// File magic.
pub const MAGIC: &[u8; 8] = b"KFUSEREC";
/// Format version.
pub const VERSION: u32 = 1;
const KIND_ISO: u8 = 1;
const KIND_BULK: u8 = 2;
const KIND_END: u8 = 0xEE;
/// Largest record accepted (a merged iso packet or a bulk transfer is far smaller; guards
/// against allocating garbage lengths).
const MAX_RECORD: usize = 4 << 20;
/// Largest metadata field (the P0 response is 1.3 MB).
const MAX_META: usize = 4 << 20;

/// Metadata stored in a recording.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordingMeta {
    /// Firmware version string.
    pub firmware: String,
    /// Serial number.
    pub serial: String,
    /// Hardware info response.
    pub hardware_info: Vec<u8>,
    /// Depth parameter response.
    pub depth_params: Vec<u8>,
    /// P0 response.
    pub p0: Vec<u8>,
    /// Colour parameter response.
    pub color_params: Vec<u8>,
}

impl RecordingMeta {
    /// From the information read at start.
    pub fn from_info(i: &DeviceInfo) -> Self {
        RecordingMeta {
            firmware: i.firmware.clone(),
            serial: i.serial.clone(),
            hardware_info: i.hardware_info.clone(),
            depth_params: i.raw_depth_params.clone(),
            p0: i.raw_p0.clone(),
            color_params: i.raw_color_params.clone(),
        }
    }
}

/// One recorded event.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordedEvent {
    /// Stream.
    pub kind: StreamKind,
    /// Status.
    pub status: XferStatus,
    /// Data.
    pub data: Vec<u8>,
}

impl RecordedEvent {
    /// As a backend stream event.
    pub fn to_event(&self) -> StreamEvent {
        match self.kind {
            StreamKind::Depth => {
                StreamEvent::IsoPacket { status: self.status, data: self.data.clone() }
            }
            StreamKind::Color => StreamEvent::Bulk { status: self.status, data: self.data.clone() },
        }
    }
}

/// A parsed recording.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Recording {
    /// Metadata.
    pub meta: RecordingMeta,
    /// Events in order.
    pub events: Vec<RecordedEvent>,
    /// False when only the intact prefix of a truncated file was kept.
    pub complete: bool,
}

fn status_code(s: XferStatus) -> u8 {
    match s {
        XferStatus::Completed => 0,
        XferStatus::Error => 1,
        XferStatus::TimedOut => 2,
        XferStatus::Cancelled => 3,
    }
}

/// Streaming writer.
pub struct RecordingWriter<W: Write> {
    w: W,
    count: u64,
}

impl<W: Write> RecordingWriter<W> {
    /// Writes the header.
    pub fn new(mut w: W, meta: &RecordingMeta) -> std::io::Result<Self> {
        w.write_all(MAGIC)?;
        w.write_all(&VERSION.to_le_bytes())?;
        for f in [
            meta.firmware.as_bytes(),
            meta.serial.as_bytes(),
            &meta.hardware_info,
            &meta.depth_params,
            &meta.p0,
            &meta.color_params,
        ] {
            w.write_all(&(f.len() as u32).to_le_bytes())?;
            w.write_all(f)?;
        }
        Ok(RecordingWriter { w, count: 0 })
    }

    /// Appends one event (stream-stopped events are not recorded).
    pub fn write_event(&mut self, kind: StreamKind, ev: &StreamEvent) -> std::io::Result<()> {
        let (status, data) = match ev {
            StreamEvent::IsoPacket { status, data } | StreamEvent::Bulk { status, data } => {
                (*status, data)
            }
            StreamEvent::Stopped { .. } => return Ok(()),
        };
        let k = if kind == StreamKind::Depth { KIND_ISO } else { KIND_BULK };
        self.w.write_all(&[k, status_code(status)])?;
        self.w.write_all(&(data.len() as u32).to_le_bytes())?;
        self.w.write_all(data)?;
        self.count += 1;
        Ok(())
    }

    /// Writes the end record and returns the inner writer.
    pub fn finish(mut self) -> std::io::Result<W> {
        self.w.write_all(&[KIND_END, 0])?;
        self.w.write_all(&8u32.to_le_bytes())?;
        self.w.write_all(&self.count.to_le_bytes())?;
        self.w.flush()?;
        Ok(self.w)
    }
}

struct Cursor<'a> {
    b: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl<'a> Cursor<'a> {
    fn err(&self, detail: impl Into<String>) -> KinectError {
        KinectError::Recording {
            path: self.path.to_path_buf(),
            offset: self.pos as u64,
            detail: detail.into(),
        }
    }
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        if self.b.len() - self.pos < n {
            return Err(self.err(format!(
                "truncated: {what} needs {n} bytes, {} left",
                self.b.len() - self.pos
            )));
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn u32(&mut self, what: &str) -> Result<u32> {
        let s = self.take(4, what)?;
        Ok(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
    }
}

/// Parses a recording held in memory. `path` is only used in error messages. With
/// `keep_prefix`, a truncated file yields its intact events and `complete = false`.
pub fn read_recording(bytes: &[u8], path: &Path, keep_prefix: bool) -> Result<Recording> {
    let mut c = Cursor { b: bytes, pos: 0, path };
    if c.take(8, "magic")? != MAGIC {
        return Err(c.err("not a kfuse recording (bad magic)"));
    }
    let v = c.u32("version")?;
    if v != VERSION {
        return Err(c.err(format!("unsupported version {v}")));
    }
    let mut fields = Vec::new();
    for name in
        ["firmware", "serial", "hardware info", "depth params", "P0 tables", "colour params"]
    {
        let n = c.u32(name)? as usize;
        if n > MAX_META {
            return Err(c.err(format!("{name} length {n} too large")));
        }
        fields.push(c.take(n, name)?.to_vec());
    }
    let text = |v: &Vec<u8>| String::from_utf8_lossy(v).into_owned();
    let meta = RecordingMeta {
        firmware: text(&fields[0]),
        serial: text(&fields[1]),
        hardware_info: fields[2].clone(),
        depth_params: fields[3].clone(),
        p0: fields[4].clone(),
        color_params: fields[5].clone(),
    };
    let mut events = Vec::new();
    loop {
        let start = c.pos;
        let rec = (|| -> Result<Option<RecordedEvent>> {
            let h = c.take(2, "record header")?;
            let (kind, st) = (h[0], h[1]);
            let n = c.u32("record length")? as usize;
            if n > MAX_RECORD {
                return Err(c.err(format!("record length {n} too large (corrupt)")));
            }
            let data = c.take(n, "record data")?;
            match kind {
                KIND_END => {
                    if n != 8 {
                        return Err(c.err("bad end record"));
                    }
                    let count =
                        u64::from_le_bytes(data.try_into().map_err(|_| c.err("bad end record"))?);
                    if count != events.len() as u64 {
                        return Err(c.err(format!(
                            "end record counts {count} events, file holds {}",
                            events.len()
                        )));
                    }
                    Ok(None)
                }
                KIND_ISO | KIND_BULK => {
                    let status = match st {
                        0 => XferStatus::Completed,
                        1 => XferStatus::Error,
                        2 => XferStatus::TimedOut,
                        3 => XferStatus::Cancelled,
                        _ => return Err(c.err(format!("unknown status {st}"))),
                    };
                    let kind = if kind == KIND_ISO { StreamKind::Depth } else { StreamKind::Color };
                    Ok(Some(RecordedEvent { kind, status, data: data.to_vec() }))
                }
                k => Err(c.err(format!("unknown record kind {k:#x}"))),
            }
        })();
        match rec {
            Ok(Some(e)) => events.push(e),
            Ok(None) => {
                if c.pos != bytes.len() {
                    return Err(c.err("data after the end record"));
                }
                return Ok(Recording { meta, events, complete: true });
            }
            Err(e) => {
                if keep_prefix && c.pos >= start {
                    return Ok(Recording { meta, events, complete: false });
                }
                return Err(e);
            }
        }
    }
}

/// Reads and parses a recording file.
pub fn read_recording_file(path: &Path, keep_prefix: bool) -> Result<Recording> {
    let b = std::fs::read(path)
        .map_err(|source| KinectError::File { path: PathBuf::from(path), source })?;
    read_recording(&b, path, keep_prefix)
}
