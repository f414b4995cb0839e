//! Raw recordings: the device metadata plus every stream event, replayable through the same
//! code path as a live device.
//!
//! # File format (`.kfrec`, little-endian, version 2)
//!
//! ```text
//! "KFUSEREC"                  8 bytes magic
//! u32 version = 2
//! 6 × (u32 length, bytes)     firmware (UTF-8), serial (UTF-8), hardware info,
//!                             depth-params response, P0 response, colour-params response
//! u32 CRC-32 of every header byte before it (magic included)
//! records, each:  u8 kind (1 = iso packet, 2 = bulk transfer), u8 status
//!                 (0 completed, 1 error, 2 timed out, 3 cancelled), u32 length, bytes,
//!                 u32 CRC-32 (IEEE, as zlib) of the kind, status, length and bytes
//! end record:     u8 kind = 0xEE, u8 0, u32 length = 8, u64 number of records, u32 CRC-32
//! ```
//!
//! Version 1 (no checksums) is refused with a message saying how to go on. A file without the
//! end record or with a record cut short is *truncated*; a record whose checksum does not match
//! is *corrupt*; both are reported with the record's index and byte offset.
//! [`RecordingReader`] streams the events one at a time (memory bounded by [`MAX_RECORD`]
//! whatever the file size); [`ReadOptions`] can keep the intact prefix of a truncated file and
//! skip corrupt records.

use std::io::{BufReader, Read, Write};
use std::path::{Path, PathBuf};

use crate::backend::{StreamEvent, XferStatus};
use crate::device::{DeviceInfo, StreamKind};
use crate::error::{KinectError, Result};

/// File magic.
pub const MAGIC: &[u8; 8] = b"KFUSEREC";
/// Format version (2: CRC-32 per record and of the header).
pub const VERSION: u32 = 2;
const KIND_ISO: u8 = 1;
const KIND_BULK: u8 = 2;
const KIND_END: u8 = 0xEE;
/// Largest record accepted: a merged isochronous packet (≤ 64 KiB seen) or a bulk transfer
/// (16 KiB) is far smaller; guards against allocating garbage lengths, and bounds the memory a
/// streaming replay holds per record.
pub const MAX_RECORD: usize = 4 << 20;
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
    /// As a backend stream event, without copying the data.
    pub fn into_event(self) -> StreamEvent {
        match self.kind {
            StreamKind::Depth => StreamEvent::IsoPacket { status: self.status, data: self.data },
            StreamKind::Color => StreamEvent::Bulk { status: self.status, data: self.data },
        }
    }

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
        let mut crc = crc32fast::Hasher::new();
        let mut put = |w: &mut W, b: &[u8]| {
            crc.update(b);
            w.write_all(b)
        };
        put(&mut w, MAGIC)?;
        put(&mut w, &VERSION.to_le_bytes())?;
        for f in [
            meta.firmware.as_bytes(),
            meta.serial.as_bytes(),
            &meta.hardware_info,
            &meta.depth_params,
            &meta.p0,
            &meta.color_params,
        ] {
            put(&mut w, &(f.len() as u32).to_le_bytes())?;
            put(&mut w, f)?;
        }
        w.write_all(&crc.finalize().to_le_bytes())?;
        Ok(RecordingWriter { w, count: 0 })
    }

    /// Appends one event (stream-stopped events are not recorded).
    pub fn write_event(&mut self, kind: StreamKind, ev: &StreamEvent) -> std::io::Result<()> {
        let (status, data) = match ev {
            StreamEvent::IsoPacket { status, data } | StreamEvent::Bulk { status, data } => {
                (*status, data)
            }
            StreamEvent::Stopped { .. } | StreamEvent::Retired { .. } => return Ok(()),
        };
        let k = if kind == StreamKind::Depth { KIND_ISO } else { KIND_BULK };
        self.record(k, status_code(status), data)?;
        self.count += 1;
        Ok(())
    }

    /// Writes one record with its checksum.
    fn record(&mut self, kind: u8, status: u8, data: &[u8]) -> std::io::Result<()> {
        let head = record_head(kind, status, data.len() as u32);
        self.w.write_all(&head)?;
        self.w.write_all(data)?;
        self.w.write_all(&record_crc(&head, data).to_le_bytes())
    }

    /// Writes the end record and returns the inner writer.
    pub fn finish(mut self) -> std::io::Result<W> {
        let count = self.count.to_le_bytes();
        self.record(KIND_END, 0, &count)?;
        self.w.flush()?;
        Ok(self.w)
    }

    /// Flushes the inner writer (what was written so far is a valid prefix).
    pub fn flush(&mut self) -> std::io::Result<()> {
        self.w.flush()
    }

    /// Events written so far.
    pub fn count(&self) -> u64 {
        self.count
    }
}

/// Size of the end record: header, u64 count, CRC.
const END_RECORD_BYTES: usize = 6 + 8 + 4;

/// The six header bytes of a record.
fn record_head(kind: u8, status: u8, len: u32) -> [u8; 6] {
    let l = len.to_le_bytes();
    [kind, status, l[0], l[1], l[2], l[3]]
}

/// CRC-32 of a record's header and data.
fn record_crc(head: &[u8; 6], data: &[u8]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(head);
    h.update(data);
    h.finalize()
}

/// How [`RecordingReader`] treats damage.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReadOptions {
    /// A truncated file ends the events at its intact prefix instead of failing
    /// (`kfuse capture --allow-truncated`).
    pub keep_prefix: bool,
    /// A record whose checksum does not match is skipped (and counted) instead of failing
    /// (`kfuse capture --skip-corrupt`). Records whose length field is impossible cannot be
    /// skipped (the next record's position is unknown) and still fail.
    pub skip_corrupt: bool,
}

/// Most runs of skipped records a [`ReadReport`] lists: 1000. Consecutive corrupt records are
/// one run (a zero-filled tail of 2 GB parses as 200 million 10-byte records, which were one
/// entry each and aborted the replay at 3.5 GB); a file damaged in more than 1000 separate
/// places is reported by its totals, the first 1000 runs listed (32 KB), so the report stays
/// within the memory bound of the streaming reader whatever the file.
pub const MAX_SKIPPED_RUNS: usize = 1000;

/// Consecutive records skipped as corrupt (checksum mismatch): a run of the file's bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SkippedRun {
    /// Index of the run's first record (records counted as the reader parsed them).
    pub first_index: u64,
    /// Records in the run.
    pub records: u64,
    /// Byte offset of the run's first record.
    pub offset: u64,
    /// Bytes the run covers.
    pub bytes: u64,
}

/// What a streaming reader found wrong so far.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ReadReport {
    /// Runs of consecutive records skipped because their checksum did not match, in file
    /// order: the first [`MAX_SKIPPED_RUNS`] runs (the totals count every one).
    pub skipped: Vec<SkippedRun>,
    /// Records skipped in all, listed or not.
    pub skipped_records: u64,
    /// Bytes skipped in all, listed or not.
    pub skipped_bytes: u64,
    /// Runs of skipped records beyond [`MAX_SKIPPED_RUNS`], counted but not listed.
    pub unlisted_runs: u64,
    /// The file ended before its end record (only with [`ReadOptions::keep_prefix`]).
    pub truncated: bool,
    /// Where the last skipped record ended (a next one there extends its run).
    last_end: u64,
}

impl ReadReport {
    /// Counts a skipped record of `bytes` at `offset`: it extends the last run when it starts
    /// where that run ended, else opens a run (listed while fewer than [`MAX_SKIPPED_RUNS`]).
    pub fn skip(&mut self, index: u64, offset: u64, bytes: u64) {
        self.skipped_records += 1;
        self.skipped_bytes += bytes;
        let extends = self.skipped_records > 1 && self.last_end == offset;
        self.last_end = offset + bytes;
        if extends
            && self.unlisted_runs == 0
            && let Some(last) = self.skipped.last_mut()
        {
            last.records += 1;
            last.bytes += bytes;
        } else if !extends && self.skipped.len() < MAX_SKIPPED_RUNS {
            self.skipped.push(SkippedRun { first_index: index, records: 1, offset, bytes });
        } else if !extends {
            self.unlisted_runs += 1;
        }
    }
}

/// Streams a recording's events one at a time: holds the metadata and at most one record.
pub struct RecordingReader<R: Read> {
    r: R,
    path: PathBuf,
    pos: u64,
    /// Index of the next record (skipped ones included).
    index: u64,
    opts: ReadOptions,
    meta: RecordingMeta,
    done: bool,
    report: ReadReport,
}

/// Why a read came up short.
enum Short {
    /// End of file after `got` of the wanted bytes.
    Eof(usize),
    /// Another I/O error.
    Io(std::io::Error),
}

impl RecordingReader<BufReader<std::fs::File>> {
    /// Opens a recording file and reads its header.
    /// Opens a recording file and reads its header. Unless [`ReadOptions::keep_prefix`], a
    /// file that does not end with an intact end record is refused here, before any event is
    /// replayed (a replay that stops early would otherwise never reach the damage).
    pub fn open(path: &Path, opts: ReadOptions) -> Result<Self> {
        use std::io::{Seek, SeekFrom};
        let io = |source| KinectError::File { path: path.to_path_buf(), source };
        let f = bounded_read::open_without_blocking(path).map_err(io)?;
        let rd = RecordingReader::new(BufReader::with_capacity(1 << 20, f), path, opts)?;
        if !opts.keep_prefix {
            // A second, independent handle (a cloned one would share the reader's offset).
            let mut f = bounded_read::open_without_blocking(path).map_err(io)?;
            let len = f.seek(SeekFrom::End(0)).map_err(io)?;
            let at = len.saturating_sub(END_RECORD_BYTES as u64);
            let mut end = [0u8; END_RECORD_BYTES];
            let intact = at >= rd.pos && {
                f.seek(SeekFrom::Start(at)).map_err(io)?;
                f.read_exact(&mut end).map_err(io)?;
                let head: [u8; 6] = [end[0], end[1], end[2], end[3], end[4], end[5]];
                let crc = u32::from_le_bytes([end[14], end[15], end[16], end[17]]);
                head == record_head(KIND_END, 0, 8) && crc == record_crc(&head, &end[6..14])
            };
            if !intact {
                return Err(rd.err(
                    len,
                    "truncated: the file does not end with an intact end record (the recording \
                     was cut or is still being written); replay its intact beginning with \
                     --allow-truncated",
                ));
            }
        }
        Ok(rd)
    }
}

impl<R: Read> RecordingReader<R> {
    /// Reads the header from `r`; `path` is only used in messages.
    pub fn new(r: R, path: &Path, opts: ReadOptions) -> Result<Self> {
        let mut rd = RecordingReader {
            r,
            path: path.to_path_buf(),
            pos: 0,
            index: 0,
            opts,
            meta: RecordingMeta {
                firmware: String::new(),
                serial: String::new(),
                hardware_info: Vec::new(),
                depth_params: Vec::new(),
                p0: Vec::new(),
                color_params: Vec::new(),
            },
            done: false,
            report: ReadReport::default(),
        };
        let mut crc = crc32fast::Hasher::new();
        let mut magic = [0u8; 8];
        rd.header_bytes(&mut magic, "magic", &mut crc)?;
        if &magic != MAGIC {
            return Err(rd.err(0, "not a kfuse recording (bad magic)"));
        }
        let mut v = [0u8; 4];
        rd.header_bytes(&mut v, "version", &mut crc)?;
        let v = u32::from_le_bytes(v);
        if v == 1 {
            return Err(rd.err(
                8,
                "format version 1 (written by an older kfuse, without checksums) is no longer \
                 read; record it again with this kfuse, or replay it with the kfuse that wrote it",
            ));
        }
        if v != VERSION {
            return Err(
                rd.err(8, format!("unsupported format version {v} (this kfuse reads {VERSION})"))
            );
        }
        let mut fields = Vec::new();
        for name in
            ["firmware", "serial", "hardware info", "depth params", "P0 tables", "colour params"]
        {
            let mut n = [0u8; 4];
            rd.header_bytes(&mut n, name, &mut crc)?;
            let n = u32::from_le_bytes(n) as usize;
            if n > MAX_META {
                return Err(
                    rd.err(rd.pos - 4, format!("{name} length {n} too large (corrupt header)"))
                );
            }
            let mut f = vec![0u8; n];
            rd.header_bytes(&mut f, name, &mut crc)?;
            fields.push(f);
        }
        let at = rd.pos;
        let mut stored = [0u8; 4];
        rd.header_bytes(&mut stored, "header checksum", &mut crc32fast::Hasher::new())?;
        let (stored, computed) = (u32::from_le_bytes(stored), crc.finalize());
        if stored != computed {
            return Err(rd.err(
                at,
                format!("header checksum mismatch (stored {stored:#010x}, computed {computed:#010x}): the metadata is damaged; record again"),
            ));
        }
        let text = |v: &[u8]| String::from_utf8_lossy(v).into_owned();
        let [fw, serial, hw, dp, p0, cp]: [Vec<u8>; 6] =
            fields.try_into().map_err(|_| rd.err(at, "header fields"))?;
        rd.meta = RecordingMeta {
            firmware: text(&fw),
            serial: text(&serial),
            hardware_info: hw,
            depth_params: dp,
            p0,
            color_params: cp,
        };
        Ok(rd)
    }

    /// The recording's metadata.
    pub fn meta(&self) -> &RecordingMeta {
        &self.meta
    }

    /// What was skipped or cut so far.
    pub fn report(&self) -> &ReadReport {
        &self.report
    }

    fn err(&self, offset: u64, detail: impl Into<String>) -> KinectError {
        KinectError::Recording { path: self.path.clone(), offset, detail: detail.into() }
    }

    /// Fills `buf`, advancing the position by what was read.
    fn fill(&mut self, buf: &mut [u8]) -> std::result::Result<(), Short> {
        let mut got = 0;
        while got < buf.len() {
            match self.r.read(&mut buf[got..]) {
                Ok(0) => {
                    self.pos += got as u64;
                    return Err(Short::Eof(got));
                }
                Ok(n) => got += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    self.pos += got as u64;
                    return Err(Short::Io(e));
                }
            }
        }
        self.pos += got as u64;
        Ok(())
    }

    fn header_bytes(
        &mut self,
        buf: &mut [u8],
        what: &str,
        crc: &mut crc32fast::Hasher,
    ) -> Result<()> {
        let at = self.pos;
        match self.fill(buf) {
            Ok(()) => {
                crc.update(buf);
                Ok(())
            }
            Err(Short::Eof(got)) => Err(self.err(
                at,
                format!("truncated in the header: {what} needs {} bytes, {got} left", buf.len()),
            )),
            Err(Short::Io(source)) => Err(KinectError::File { path: self.path.clone(), source }),
        }
    }

    /// A truncation at `at` (record `index`): an error, or the end of the intact prefix.
    fn truncated(&mut self, at: u64, detail: String) -> Result<Option<RecordedEvent>> {
        self.done = true;
        if self.opts.keep_prefix {
            self.report.truncated = true;
            return Ok(None);
        }
        Err(self.err(
            at,
            format!(
                "truncated: {detail} (record {}); the events before it are intact: replay them \
                 with --allow-truncated",
                self.index
            ),
        ))
    }

    /// The next event: `Ok(None)` after the end record (or at the end of the intact prefix
    /// with [`ReadOptions::keep_prefix`]).
    pub fn next_event(&mut self) -> Result<Option<RecordedEvent>> {
        loop {
            if self.done {
                return Ok(None);
            }
            let at = self.pos;
            let mut head = [0u8; 6];
            match self.fill(&mut head) {
                Ok(()) => {}
                Err(Short::Eof(0)) => {
                    return self.truncated(at, "the file ends without its end record".into());
                }
                Err(Short::Eof(got)) => {
                    return self.truncated(at, format!("record header cut after {got} of 6 bytes"));
                }
                Err(Short::Io(source)) => {
                    return Err(KinectError::File { path: self.path.clone(), source });
                }
            }
            let (kind, st) = (head[0], head[1]);
            let n = u32::from_le_bytes([head[2], head[3], head[4], head[5]]) as usize;
            let index = self.index;
            if n > MAX_RECORD {
                self.done = true;
                return Err(self.err(
                    at,
                    format!(
                        "record {index} is corrupt: length {n} exceeds {MAX_RECORD} bytes; the \
                         records after it cannot be located (the events before it can be \
                         replayed by cutting the file at byte {at} and passing --allow-truncated)"
                    ),
                ));
            }
            let mut data = vec![0u8; n];
            let mut crc = [0u8; 4];
            for buf in [&mut data[..], &mut crc[..]] {
                match self.fill(buf) {
                    Ok(()) => {}
                    Err(Short::Eof(_)) => {
                        return self
                            .truncated(at, format!("record cut short ({n} data bytes declared)"));
                    }
                    Err(Short::Io(source)) => {
                        return Err(KinectError::File { path: self.path.clone(), source });
                    }
                }
            }
            let (stored, computed) = (u32::from_le_bytes(crc), record_crc(&head, &data));
            if stored != computed {
                if self.opts.skip_corrupt {
                    self.report.skip(index, at, self.pos - at);
                    self.index += 1;
                    continue;
                }
                self.done = true;
                return Err(self.err(
                    at,
                    format!(
                        "record {index} is corrupt: checksum mismatch (stored {stored:#010x}, \
                         computed {computed:#010x}); pass --skip-corrupt to leave it out and go on"
                    ),
                ));
            }
            match kind {
                KIND_END => {
                    self.done = true;
                    let count = u64::from_le_bytes(
                        data.as_slice().try_into().map_err(|_| self.err(at, "bad end record"))?,
                    );
                    if count != self.index {
                        return Err(self.err(
                            at,
                            format!("end record counts {count} events, file holds {}", self.index),
                        ));
                    }
                    let mut extra = [0u8; 1];
                    if let Ok(()) = self.fill(&mut extra) {
                        return Err(self.err(self.pos - 1, "data after the end record"));
                    }
                    return Ok(None);
                }
                KIND_ISO | KIND_BULK => {
                    let status = match st {
                        0 => XferStatus::Completed,
                        1 => XferStatus::Error,
                        2 => XferStatus::TimedOut,
                        3 => XferStatus::Cancelled,
                        _ => {
                            return Err(
                                self.err(at, format!("record {index}: unknown status {st}"))
                            );
                        }
                    };
                    self.index += 1;
                    let kind = if kind == KIND_ISO { StreamKind::Depth } else { StreamKind::Color };
                    return Ok(Some(RecordedEvent { kind, status, data }));
                }
                k => {
                    self.done = true;
                    return Err(self.err(at, format!("record {index}: unknown record kind {k:#x}")));
                }
            }
        }
    }
}

/// A source of recorded events for [`crate::sim::SimDevice::replay`] (feature `sim`).
pub trait ReplaySource: Send {
    /// The next event, `Ok(None)` at the end.
    fn next_event(&mut self) -> Result<Option<RecordedEvent>>;
    /// Damage met so far (none for in-memory events).
    fn report(&self) -> ReadReport {
        ReadReport::default()
    }
}

impl<R: Read + Send> ReplaySource for RecordingReader<R> {
    fn next_event(&mut self) -> Result<Option<RecordedEvent>> {
        RecordingReader::next_event(self)
    }
    fn report(&self) -> ReadReport {
        self.report.clone()
    }
}

impl ReplaySource for std::vec::IntoIter<RecordedEvent> {
    fn next_event(&mut self) -> Result<Option<RecordedEvent>> {
        Ok(self.next())
    }
}

/// Parses a recording held in memory (all events at once; for tests and small files).
/// `path` is only used in error messages. With `keep_prefix`, a truncated file yields its
/// intact events and `complete = false`.
pub fn read_recording(bytes: &[u8], path: &Path, keep_prefix: bool) -> Result<Recording> {
    let opts = ReadOptions { keep_prefix, skip_corrupt: false };
    let mut r = RecordingReader::new(bytes, path, opts)?;
    let mut events = Vec::new();
    while let Some(e) = r.next_event()? {
        events.push(e);
    }
    let complete = !r.report.truncated;
    Ok(Recording { meta: r.meta.clone(), events, complete })
}

/// Largest recording [`read_recording_file`] reads into memory: 1 GiB (about 300 depth frames
/// with their colour). Whole-file reading is for tests and short recordings; longer ones are
/// streamed with [`RecordingReader`], whose memory is bounded by [`MAX_RECORD`].
pub const MAX_IN_MEMORY_RECORDING: u64 = 1 << 30;

/// Reads and parses a whole recording file into memory, at most
/// [`MAX_IN_MEMORY_RECORDING`] bytes whatever the file is (see [`RecordingReader`] to stream).
pub fn read_recording_file(path: &Path, keep_prefix: bool) -> Result<Recording> {
    let expected = bounded_read::Expected {
        what: "a recording read whole",
        fix: "replay it with `kfuse capture --replay`, which streams it",
    };
    let b = bounded_read::read_bounded(path, MAX_IN_MEMORY_RECORDING, expected)
        .map_err(|source| KinectError::File { path: PathBuf::from(path), source })?;
    read_recording(&b, path, keep_prefix)
}
