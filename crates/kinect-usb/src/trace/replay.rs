//! Replaying a trace: [`TraceReplay`] is a backend that answers the device's calls from the
//! trace (each call must be the one recorded, bytes sent included: the same protocol code
//! replays the same transcript) and, once the application services its streams, delivers the
//! recorded events to the same sinks, i.e. the same frame parsers, as a live sensor.
//! Calls made while streaming (settings, the stop sequence) are not replayed: the trace then
//! behaves as a sensor that is gone.

use std::collections::VecDeque;
use std::fs::File;
use std::io::BufReader;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::TraceReader;
use super::format::{CallOp, CallRecord, TraceRecord, TracedEvent};
use crate::backend::{
    EventSink, ResetOutcome, Serviced, StopReason, StreamEvent, StreamHandle, StreamSpec,
    UsbBackend,
};
use crate::device::{DeviceInfo, Frame, KinectDevice, StreamCounters, StreamKind};
use crate::error::{KinectError, Result, UsbError};

/// Stream events a trace may hold between two calls of the start sequence (a stream started
/// first delivers while the second starts): a colour pool's 20 transfers and a depth pool's
/// 60 × 8 packets complete within a few milliseconds, far fewer than this; more is damage.
const MAX_PENDING_EVENTS: usize = 4096;

/// Longest wait for a frame during a replay: the replay delivers without waiting, so this is
/// reached only if a stream never ends.
const REPLAY_FRAME_WAIT: Duration = Duration::from_secs(1);

/// A backend answering from a trace (module docs).
pub struct TraceReplay {
    reader: TraceReader<BufReader<File>>,
    lookahead: Option<TraceRecord>,
    pending: VecDeque<(u8, TracedEvent)>,
    sinks: Vec<(u8, StreamHandle, Arc<dyn EventSink>)>,
    streaming: bool,
    ended: bool,
    error: Option<KinectError>,
    calls: u64,
    events: u64,
}

impl TraceReplay {
    /// Opens the trace at `path` (its header checked).
    pub fn open(path: &Path) -> Result<Self> {
        Ok(TraceReplay {
            reader: TraceReader::open(path)?,
            lookahead: None,
            pending: VecDeque::new(),
            sinks: Vec::new(),
            streaming: false,
            ended: false,
            error: None,
            calls: 0,
            events: 0,
        })
    }

    /// The damage or divergence that stopped the replay, if any.
    pub fn take_error(&mut self) -> Option<KinectError> {
        self.error.take()
    }

    fn next(&mut self) -> Option<TraceRecord> {
        if let Some(r) = self.lookahead.take() {
            return Some(r);
        }
        if self.error.is_some() {
            return None;
        }
        match self.reader.next_record() {
            Ok(r) => r,
            Err(e) => {
                self.error = Some(e);
                None
            }
        }
    }

    /// The next record that is not a stream event (events on the way are kept for
    /// [`UsbBackend::service`]).
    fn next_control(&mut self) -> Option<TraceRecord> {
        loop {
            match self.next()? {
                TraceRecord::Event { ep, event, .. } => {
                    if self.pending.len() >= MAX_PENDING_EVENTS {
                        self.diverge(format!(
                            "more than {MAX_PENDING_EVENTS} stream events between two calls of \
                             the start sequence"
                        ));
                        return None;
                    }
                    self.pending.push_back((ep, event));
                }
                r => return Some(r),
            }
        }
    }

    /// After the start record of the stream on `ep`: the error of its start, if it failed.
    /// The recorder writes a failed start's stop right after its start, from the same thread;
    /// only events of a stream already running (completions during the start call) can come
    /// between. So the start succeeded once this stream's own first event, a record that is
    /// not an event, or [`MAX_PENDING_EVENTS`] events of the other stream come first (the
    /// last stream started is followed by the whole capture's events until the stop sequence:
    /// scanning to that next call would hold them all). Events read are kept for
    /// [`UsbBackend::service`].
    fn failed_start(&mut self, ep: u8) -> Option<UsbError> {
        loop {
            match self.next()? {
                TraceRecord::StreamStop { ep: e, result: Err(err), .. } if e == ep => {
                    return Some(err);
                }
                TraceRecord::Event { ep: e, event, .. } => {
                    self.pending.push_back((e, event));
                    if e == ep || self.pending.len() >= MAX_PENDING_EVENTS {
                        return None;
                    }
                }
                r => {
                    self.lookahead = Some(r);
                    return None;
                }
            }
        }
    }

    fn diverge(&mut self, detail: String) {
        if self.error.is_none() {
            let (path, offset) = (self.reader.path().to_path_buf(), self.reader.offset());
            self.error = Some(KinectError::Trace { path, offset, detail });
        }
    }

    /// Answers call `op` from the trace: the next record must be that call with the same
    /// arguments (and bytes sent).
    fn call(
        &mut self,
        op: CallOp,
        (a, b, value, index): (u8, u8, u16, u16),
        sent: &[u8],
    ) -> std::result::Result<CallRecord, UsbError> {
        if self.streaming || self.error.is_some() {
            return Err(UsbError::NoDevice);
        }
        let rec = self.next_control();
        match rec {
            Some(TraceRecord::Call(c))
                if c.op == op
                    && (c.a, c.b, c.value, c.index) == (a, b, value, index)
                    && (!matches!(op, CallOp::BulkOut | CallOp::ControlOut) || c.data == sent) =>
            {
                self.calls += 1;
                Ok(c)
            }
            other => {
                let found = match &other {
                    Some(TraceRecord::Call(c)) => {
                        format!(
                            "{:?}({:#04x}, {:#04x}, {}, {:#x})",
                            c.op, c.a, c.b, c.value, c.index
                        )
                    }
                    Some(r) => format!("{r:?}").chars().take(80).collect(),
                    None => "its end".into(),
                };
                self.diverge(format!(
                    "the replay's call {} is {op:?}({a:#04x}, {b:#04x}, {value}, {index:#x}) but \
                     the trace has {found}: it was recorded by another version of kfuse's \
                     protocol code",
                    self.calls
                ));
                Err(UsbError::Io)
            }
        }
    }

    fn deliver(&mut self, ep: u8, ev: TracedEvent) {
        let ev = match ev {
            TracedEvent::Iso { status, length, head, tail } => {
                StreamEvent::IsoPacket { status, data: TracedEvent::payload(length, &head, &tail) }
            }
            TracedEvent::Bulk { status, length, head, tail } => {
                StreamEvent::Bulk { status, data: TracedEvent::payload(length, &head, &tail) }
            }
            TracedEvent::Retired { error, in_flight } => {
                StreamEvent::Retired { error, in_flight: in_flight as usize }
            }
            TracedEvent::Stopped { reason } => StreamEvent::Stopped { reason },
        };
        self.events += 1;
        if let Some((_, _, sink)) = self.sinks.iter().find(|s| s.0 == ep) {
            sink.deliver(ev);
        }
    }

    fn end_streams(&mut self, reason: StopReason) {
        self.ended = true;
        for (_, _, sink) in &self.sinks {
            sink.deliver(StreamEvent::Stopped { reason });
        }
    }
}

fn plain(r: std::result::Result<CallRecord, UsbError>) -> std::result::Result<(), UsbError> {
    r?.result.map(|_| ())
}

impl UsbBackend for TraceReplay {
    fn active_config(&mut self) -> std::result::Result<u8, UsbError> {
        Ok(self.call(CallOp::ActiveConfig, (0, 0, 0, 0), &[])?.result? as u8)
    }
    fn set_config(&mut self, cfg: u8) -> std::result::Result<(), UsbError> {
        plain(self.call(CallOp::SetConfig, (cfg, 0, 0, 0), &[]))
    }
    fn reset(&mut self) -> std::result::Result<ResetOutcome, UsbError> {
        let r = self.call(CallOp::Reset, (0, 0, 0, 0), &[])?.result?;
        Ok(if r == 1 { ResetOutcome::Reenumerated } else { ResetOutcome::Ok })
    }
    fn reopen(&mut self, _wait: Duration) -> std::result::Result<(), UsbError> {
        plain(self.call(CallOp::Reopen, (0, 0, 0, 0), &[]))
    }
    fn claim(&mut self, iface: u8) -> std::result::Result<(), UsbError> {
        plain(self.call(CallOp::Claim, (iface, 0, 0, 0), &[]))
    }
    fn release(&mut self, iface: u8) -> std::result::Result<(), UsbError> {
        plain(self.call(CallOp::Release, (iface, 0, 0, 0), &[]))
    }
    fn set_alt(&mut self, iface: u8, alt: u8) -> std::result::Result<(), UsbError> {
        plain(self.call(CallOp::SetAlt, (iface, alt, 0, 0), &[]))
    }
    fn control_out(
        &mut self,
        req_type: u8,
        req: u8,
        value: u16,
        index: u16,
        data: &[u8],
        _timeout: Duration,
    ) -> std::result::Result<usize, UsbError> {
        Ok(self.call(CallOp::ControlOut, (req_type, req, value, index), data)?.result? as usize)
    }
    fn bulk_out(
        &mut self,
        ep: u8,
        data: &[u8],
        _timeout: Duration,
    ) -> std::result::Result<usize, UsbError> {
        Ok(self.call(CallOp::BulkOut, (ep, 0, 0, 0), data)?.result? as usize)
    }
    fn bulk_in(
        &mut self,
        ep: u8,
        buf: &mut [u8],
        _timeout: Duration,
    ) -> std::result::Result<usize, UsbError> {
        let c = self.call(CallOp::BulkIn, (ep, 0, 0, 0), &[])?;
        let n = c.result? as usize;
        if c.data.len() != n || n > buf.len() {
            return Err(UsbError::Overflow);
        }
        buf[..n].copy_from_slice(&c.data);
        Ok(n)
    }
    fn clear_halt(&mut self, ep: u8) -> std::result::Result<(), UsbError> {
        plain(self.call(CallOp::ClearHalt, (ep, 0, 0, 0), &[]))
    }
    fn iso_bytes_per_interval(&mut self, ep: u8, alt: u8) -> std::result::Result<u32, UsbError> {
        self.call(CallOp::IsoBytesPerInterval, (ep, alt, 0, 0), &[])?.result
    }
    fn start_stream(
        &mut self,
        spec: StreamSpec,
        sink: Arc<dyn EventSink>,
    ) -> std::result::Result<StreamHandle, UsbError> {
        if self.streaming || self.error.is_some() {
            return Err(UsbError::NoDevice);
        }
        let ep = match spec {
            StreamSpec::Bulk { ep, .. } | StreamSpec::Iso { ep, .. } => ep,
        };
        match self.next_control() {
            Some(TraceRecord::StreamStart { spec: s, .. }) if s == spec => {}
            other => {
                let found: String = format!("{other:?}").chars().take(80).collect();
                self.diverge(format!(
                    "the replay starts the stream {spec:?} but the trace has {found}"
                ));
                return Err(UsbError::Io);
            }
        }
        if let Some(err) = self.failed_start(ep) {
            return Err(err);
        }
        let h = StreamHandle(self.sinks.len() as u32 + 1);
        self.sinks.push((ep, h, sink));
        Ok(h)
    }
    fn service(&mut self, _timeout: Duration) -> std::result::Result<Serviced, UsbError> {
        self.streaming = true;
        if self.ended {
            return Ok(Serviced::Idle);
        }
        if let Some((ep, ev)) = self.pending.pop_front() {
            self.deliver(ep, ev);
            return Ok(Serviced::Delivered);
        }
        loop {
            match self.next() {
                Some(TraceRecord::Event { ep, event, .. }) => {
                    self.deliver(ep, event);
                    return Ok(Serviced::Delivered);
                }
                // Calls while streaming and the stop sequence are not replayed.
                Some(_) => {}
                None => {
                    let reason = if self.error.is_some() {
                        StopReason::Stalled
                    } else {
                        StopReason::Requested
                    };
                    self.end_streams(reason);
                    return Ok(Serviced::Delivered);
                }
            }
        }
    }
    fn stop_stream(
        &mut self,
        _h: StreamHandle,
        _max_wait: Duration,
    ) -> std::result::Result<(), UsbError> {
        Ok(())
    }
}

/// One frame the parsers assembled during a replay.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReplayedFrame {
    /// Which stream.
    pub kind: StreamKind,
    /// Its sequence number.
    pub sequence: u32,
    /// Its sensor timestamp (0.125 ms units).
    pub timestamp: u32,
}

/// How the traced streams ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TraceEnd {
    /// The trace ended with the streams running (the capture stopped them).
    EndOfTrace,
    /// The sensor disappeared during the capture.
    Disconnected,
    /// A stream stopped with this error.
    Stopped(String),
}

/// What a replay found: the device information the protocol code parsed, the frames the
/// stream parsers assembled and their counters.
#[derive(Debug, Clone)]
pub struct TraceReplayReport {
    /// Parsed from the recorded replies.
    pub info: DeviceInfo,
    /// Every frame assembled, in order.
    pub frames: Vec<ReplayedFrame>,
    /// The parsers' counters.
    pub counters: StreamCounters,
    /// How the streams ended.
    pub end: TraceEnd,
    /// Calls replayed.
    pub calls: u64,
    /// Stream events replayed.
    pub events: u64,
    /// Events the recorder left out (the trace reached its size bound).
    pub omitted: u64,
    /// Whether the trace carried whole payloads.
    pub payload: bool,
    /// Warnings of the device code (non-zero status words, retired transfers).
    pub warnings: Vec<String>,
}

/// Replays the trace at `path` through `KinectDevice` (open, start of both streams, every
/// frame taken). Errors: a damaged trace or one whose calls differ from what this kfuse's
/// protocol code asks ([`KinectError::Trace`], one line), or the error the device code
/// returned for the recorded replies (as it did live).
pub fn replay_trace(path: &Path) -> Result<TraceReplayReport> {
    let replay = Arc::new(Mutex::new(TraceReplay::open(path)?));
    let lock = || replay.lock().unwrap_or_else(|p| p.into_inner());
    let fail = |e: KinectError| lock().take_error().unwrap_or(e);
    let mut dev = KinectDevice::open(replay.clone()).map_err(fail)?;
    let info = dev.start(true, true).map_err(fail)?.clone();
    let mut frames = Vec::new();
    let end = loop {
        match dev.next_frame(REPLAY_FRAME_WAIT, &mut |_, _| {}) {
            Ok(Some(Frame::Depth(f))) => frames.push(ReplayedFrame {
                kind: StreamKind::Depth,
                sequence: f.sequence,
                timestamp: f.timestamp,
            }),
            Ok(Some(Frame::Color(_, m))) => frames.push(ReplayedFrame {
                kind: StreamKind::Color,
                sequence: m.sequence,
                timestamp: m.timestamp,
            }),
            Ok(None) | Err(KinectError::EndOfStream) => break TraceEnd::EndOfTrace,
            Err(KinectError::Disconnected { .. }) => break TraceEnd::Disconnected,
            Err(e) => break TraceEnd::Stopped(e.to_string()),
        }
    };
    if let Some(e) = lock().take_error() {
        return Err(e);
    }
    let counters = dev.counters();
    let warnings = dev.warnings.clone();
    drop(dev);
    let r = lock();
    Ok(TraceReplayReport {
        info,
        frames,
        counters,
        end,
        calls: r.calls,
        events: r.events,
        omitted: r.reader.omitted().unwrap_or(0),
        payload: r.reader.payload(),
        warnings,
    })
}
