//! The `.kftrace` records and their byte encoding (format described in [`super`]).

use crate::backend::{StopReason, StreamSpec, XferStatus};
use crate::error::UsbError;

/// File magic.
pub const TRACE_MAGIC: &[u8; 8] = b"KFUSETRC";
/// Format version.
pub const TRACE_VERSION: u32 = 1;
/// Header flag: every stream event carries its whole payload (`--usb-trace-payload`).
pub const FLAG_PAYLOAD: u32 = 1;
/// Largest record body accepted: the biggest control reply is the P0 tables' 1.3 MB (protocol
/// §4.6) and the biggest stream event a bulk transfer or an isochronous packet of at most
/// 49 152 bytes (§2.2); a length beyond this is damage, refused before anything is allocated.
pub const TRACE_MAX_RECORD: usize = 8 << 20;
/// Largest payload length an event may claim (a replay allocates that many bytes): the same
/// bound as a record.
pub const TRACE_MAX_EVENT_LENGTH: u32 = TRACE_MAX_RECORD as u32;

pub(super) const TAG_CALL: u8 = 1;
pub(super) const TAG_STREAM_START: u8 = 2;
pub(super) const TAG_EVENT: u8 = 3;
pub(super) const TAG_STREAM_STOP: u8 = 4;
pub(super) const TAG_END: u8 = 0xEE;

/// Which [`crate::backend::UsbBackend`] call a [`CallRecord`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CallOp {
    /// `active_config`.
    ActiveConfig = 1,
    /// `set_config(a)`.
    SetConfig = 2,
    /// `reset` (`ret`: 0 still there, 1 re-enumerated).
    Reset = 3,
    /// `reopen`.
    Reopen = 4,
    /// `claim(a)`.
    Claim = 5,
    /// `release(a)`.
    Release = 6,
    /// `set_alt(a, b)`.
    SetAlt = 7,
    /// `control_out(a = request type, b = request, value, index, data)`.
    ControlOut = 8,
    /// `bulk_out(a = endpoint, data)`.
    BulkOut = 9,
    /// `bulk_in(a = endpoint, buffer of req_len)`: `data` is what came back.
    BulkIn = 10,
    /// `clear_halt(a)`.
    ClearHalt = 11,
    /// `iso_bytes_per_interval(a = endpoint, b = alt)`.
    IsoBytesPerInterval = 12,
}

impl CallOp {
    fn from_u8(v: u8) -> Option<Self> {
        use CallOp::*;
        [
            ActiveConfig,
            SetConfig,
            Reset,
            Reopen,
            Claim,
            Release,
            SetAlt,
            ControlOut,
            BulkOut,
            BulkIn,
            ClearHalt,
            IsoBytesPerInterval,
        ]
        .into_iter()
        .find(|o| *o as u8 == v)
    }
}

/// One control-side call and its outcome.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CallRecord {
    /// Microseconds since the trace started.
    pub t_us: u64,
    /// The call.
    pub op: CallOp,
    /// First byte argument (interface, endpoint, configuration or request type).
    pub a: u8,
    /// Second byte argument (alt setting or request).
    pub b: u8,
    /// `wValue` of a control request.
    pub value: u16,
    /// `wIndex` of a control request.
    pub index: u16,
    /// Size of the caller's buffer (bulk IN).
    pub req_len: u32,
    /// The returned number (bytes moved, configuration, bytes per interval, reset outcome), or
    /// the transport error.
    pub result: Result<u32, UsbError>,
    /// Bytes sent (control, bulk OUT) or received (bulk IN).
    pub data: Vec<u8>,
}

/// One stream event as traced: lengths and statuses, with only the framing bytes of the
/// payload (or all of it with [`FLAG_PAYLOAD`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TracedEvent {
    /// An isochronous packet (`head` empty unless the payload is traced).
    Iso {
        /// Status.
        status: XferStatus,
        /// `actual_length`.
        length: u32,
        /// The packet's first bytes.
        head: Vec<u8>,
        /// The packet's last bytes.
        tail: Vec<u8>,
    },
    /// A bulk transfer.
    Bulk {
        /// Status.
        status: XferStatus,
        /// `actual_length`.
        length: u32,
        /// The transfer's first bytes.
        head: Vec<u8>,
        /// The transfer's last bytes.
        tail: Vec<u8>,
    },
    /// A transfer of the pool was retired.
    Retired {
        /// Why.
        error: UsbError,
        /// Transfers still in flight.
        in_flight: u32,
    },
    /// The stream ended.
    Stopped {
        /// Why.
        reason: StopReason,
    },
}

impl TracedEvent {
    /// The payload as a parser sees it on replay: `length` bytes, zero but for the traced head
    /// and tail at their places.
    pub fn payload(length: u32, head: &[u8], tail: &[u8]) -> Vec<u8> {
        let mut p = vec![0u8; length as usize];
        let h = head.len().min(p.len());
        p[..h].copy_from_slice(&head[..h]);
        let (n, t) = (p.len(), tail.len().min(p.len() - h));
        p[n - t..].copy_from_slice(&tail[tail.len() - t..]);
        p
    }
}

/// One record of a trace.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TraceRecord {
    /// A control-side call.
    Call(CallRecord),
    /// A stream was started.
    StreamStart {
        /// Microseconds since the trace started.
        t_us: u64,
        /// What was asked.
        spec: StreamSpec,
        /// Whether it started.
        result: Result<(), UsbError>,
    },
    /// An event of the stream on endpoint `ep`.
    Event {
        /// Microseconds since the trace started (completion time).
        t_us: u64,
        /// The stream's endpoint.
        ep: u8,
        /// What happened.
        event: TracedEvent,
    },
    /// A stream was stopped.
    StreamStop {
        /// Microseconds since the trace started.
        t_us: u64,
        /// The stream's endpoint.
        ep: u8,
        /// Whether the stop succeeded.
        result: Result<(), UsbError>,
    },
}

const USB_ERRORS: [UsbError; 9] = [
    UsbError::Timeout,
    UsbError::Stall,
    UsbError::Busy,
    UsbError::NoDevice,
    UsbError::Overflow,
    UsbError::Access,
    UsbError::NoMem,
    UsbError::Io,
    UsbError::NotSupported,
];
const STATUSES: [XferStatus; 4] =
    [XferStatus::Completed, XferStatus::Error, XferStatus::TimedOut, XferStatus::Cancelled];
const REASONS: [StopReason; 3] =
    [StopReason::Requested, StopReason::Disconnected, StopReason::Stalled];

fn error_code(e: UsbError) -> u8 {
    USB_ERRORS.iter().position(|x| *x == e).map_or(0, |i| i as u8 + 1)
}
fn result_code<T>(r: &Result<T, UsbError>) -> u8 {
    r.as_ref().err().map_or(0, |e| error_code(*e))
}
fn code_of<T: PartialEq + Copy>(table: &[T], v: T) -> u8 {
    table.iter().position(|x| *x == v).unwrap_or(0) as u8
}

/// Appends the body of `r` (its tag returned) to `out`.
pub(super) fn encode(r: &TraceRecord, out: &mut Vec<u8>) -> u8 {
    let bytes = |out: &mut Vec<u8>, b: &[u8]| {
        out.extend_from_slice(&(b.len() as u32).to_le_bytes());
        out.extend_from_slice(b);
    };
    match r {
        TraceRecord::Call(c) => {
            out.extend_from_slice(&c.t_us.to_le_bytes());
            out.extend_from_slice(&[c.op as u8, c.a, c.b]);
            out.extend_from_slice(&c.value.to_le_bytes());
            out.extend_from_slice(&c.index.to_le_bytes());
            out.extend_from_slice(&c.req_len.to_le_bytes());
            out.push(result_code(&c.result));
            out.extend_from_slice(&c.result.unwrap_or(0).to_le_bytes());
            bytes(out, &c.data);
            TAG_CALL
        }
        TraceRecord::StreamStart { t_us, spec, result } => {
            out.extend_from_slice(&t_us.to_le_bytes());
            let (kind, ep, transfers, packets, size) = match *spec {
                StreamSpec::Bulk { ep, transfers, size } => (0u8, ep, transfers, 0, size),
                StreamSpec::Iso { ep, transfers, packets, packet_size } => {
                    (1u8, ep, transfers, packets, packet_size)
                }
            };
            out.extend_from_slice(&[kind, ep]);
            for v in [transfers, packets, size] {
                out.extend_from_slice(&(v as u32).to_le_bytes());
            }
            out.push(result_code(result));
            TAG_STREAM_START
        }
        TraceRecord::Event { t_us, ep, event } => {
            out.extend_from_slice(&t_us.to_le_bytes());
            out.push(*ep);
            let (kind, code, length, head, tail): (u8, u8, u32, &[u8], &[u8]) = match event {
                TracedEvent::Iso { status, length, head, tail } => {
                    (1, code_of(&STATUSES, *status), *length, head, tail)
                }
                TracedEvent::Bulk { status, length, head, tail } => {
                    (2, code_of(&STATUSES, *status), *length, head, tail)
                }
                TracedEvent::Retired { error, in_flight } => {
                    (3, error_code(*error), *in_flight, &[], &[])
                }
                TracedEvent::Stopped { reason } => (4, code_of(&REASONS, *reason), 0, &[], &[]),
            };
            out.extend_from_slice(&[kind, code]);
            out.extend_from_slice(&length.to_le_bytes());
            bytes(out, head);
            bytes(out, tail);
            TAG_EVENT
        }
        TraceRecord::StreamStop { t_us, ep, result } => {
            out.extend_from_slice(&t_us.to_le_bytes());
            out.extend_from_slice(&[*ep, result_code(result)]);
            TAG_STREAM_STOP
        }
    }
}

/// Reads fields of a record body, every length checked against what is left.
pub(super) struct Fields<'a> {
    b: &'a [u8],
}

impl<'a> Fields<'a> {
    pub(super) fn new(b: &'a [u8]) -> Self {
        Fields { b }
    }
    pub(super) fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        if n > self.b.len() {
            return Err(format!("a field of {n} bytes runs past the end of its record"));
        }
        let (h, t) = self.b.split_at(n);
        self.b = t;
        Ok(h)
    }
    pub(super) fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }
    pub(super) fn u16(&mut self) -> Result<u16, String> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into().unwrap_or_default()))
    }
    pub(super) fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().unwrap_or_default()))
    }
    pub(super) fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().unwrap_or_default()))
    }
    fn bytes(&mut self) -> Result<Vec<u8>, String> {
        let n = self.u32()? as usize;
        Ok(self.take(n)?.to_vec())
    }
    pub(super) fn done(&self) -> Result<(), String> {
        if self.b.is_empty() {
            Ok(())
        } else {
            Err(format!("{} unexpected bytes at the end of a record", self.b.len()))
        }
    }
}

fn usb_result(code: u8) -> Result<Result<(), UsbError>, String> {
    match code {
        0 => Ok(Ok(())),
        c => USB_ERRORS
            .get(c as usize - 1)
            .map(|e| Err(*e))
            .ok_or_else(|| format!("unknown USB error code {c}")),
    }
}

fn from_table<T: Copy>(table: &[T], code: u8, what: &str) -> Result<T, String> {
    table.get(code as usize).copied().ok_or_else(|| format!("unknown {what} code {code}"))
}

/// Decodes the body of a record of `tag`.
pub(super) fn decode(tag: u8, body: &[u8]) -> Result<TraceRecord, String> {
    let mut f = Fields::new(body);
    let t_us = f.u64()?;
    let r = match tag {
        TAG_CALL => {
            let op = f.u8()?;
            let op = CallOp::from_u8(op).ok_or_else(|| format!("unknown call code {op}"))?;
            let (a, b) = (f.u8()?, f.u8()?);
            let (value, index, req_len) = (f.u16()?, f.u16()?, f.u32()?);
            let code = f.u8()?;
            let ret = f.u32()?;
            let data = f.bytes()?;
            let result = usb_result(code)?.map(|()| ret);
            TraceRecord::Call(CallRecord { t_us, op, a, b, value, index, req_len, result, data })
        }
        TAG_STREAM_START => {
            let (kind, ep) = (f.u8()?, f.u8()?);
            let (transfers, packets, size) =
                (f.u32()? as usize, f.u32()? as usize, f.u32()? as usize);
            let spec = match kind {
                0 => StreamSpec::Bulk { ep, transfers, size },
                1 => StreamSpec::Iso { ep, transfers, packets, packet_size: size },
                k => return Err(format!("unknown stream kind {k}")),
            };
            TraceRecord::StreamStart { t_us, spec, result: usb_result(f.u8()?)? }
        }
        TAG_EVENT => {
            let ep = f.u8()?;
            let (kind, code, length) = (f.u8()?, f.u8()?, f.u32()?);
            let (head, tail) = (f.bytes()?, f.bytes()?);
            let event = match kind {
                1 | 2 => {
                    if length > TRACE_MAX_EVENT_LENGTH {
                        return Err(format!(
                            "an event of {length} bytes (at most {TRACE_MAX_EVENT_LENGTH})"
                        ));
                    }
                    if head.len() + tail.len() > length as usize {
                        return Err(format!(
                            "an event of {length} bytes with {} traced bytes",
                            head.len() + tail.len()
                        ));
                    }
                    let status = from_table(&STATUSES, code, "transfer status")?;
                    if kind == 1 {
                        TracedEvent::Iso { status, length, head, tail }
                    } else {
                        TracedEvent::Bulk { status, length, head, tail }
                    }
                }
                3 => match usb_result(code)? {
                    Err(error) => TracedEvent::Retired { error, in_flight: length },
                    Ok(()) => return Err("a retirement without an error".into()),
                },
                4 => TracedEvent::Stopped { reason: from_table(&REASONS, code, "stop reason")? },
                k => return Err(format!("unknown event kind {k}")),
            };
            TraceRecord::Event { t_us, ep, event }
        }
        TAG_STREAM_STOP => {
            let ep = f.u8()?;
            TraceRecord::StreamStop { t_us, ep, result: usb_result(f.u8()?)? }
        }
        t => return Err(format!("unknown record tag {t:#04x}")),
    };
    f.done()?;
    Ok(r)
}
