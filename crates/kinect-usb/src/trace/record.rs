//! Writing a trace: [`TracingBackend`] wraps any backend, records each call and, through a
//! sink wrapper, each stream event as it completes (on the completion side).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use super::format::{CallOp, CallRecord, FLAG_PAYLOAD, TAG_END, TraceRecord, TracedEvent, encode};
use super::{
    TRACE_BULK_HEAD, TRACE_BULK_TAIL, TRACE_ISO_TAIL, TRACE_MAGIC, TRACE_MAX_EVENT_BYTES,
    TRACE_VERSION,
};
use crate::backend::{
    EventSink, ResetOutcome, Serviced, StreamEvent, StreamHandle, StreamSpec, UsbBackend,
};
use crate::error::{KinectError, Result, UsbError};

/// What a finished trace holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TraceSummary {
    /// Records written (calls, stream starts and stops, events).
    pub records: u64,
    /// Events counted but not written ([`TRACE_MAX_EVENT_BYTES`] reached).
    pub omitted: u64,
    /// Bytes of the file.
    pub bytes: u64,
}

struct Writer {
    w: Option<BufWriter<File>>,
    tmp: PathBuf,
    path: PathBuf,
    start: Instant,
    payload: bool,
    records: u64,
    omitted: u64,
    event_bytes: u64,
    bytes: u64,
    error: Option<std::io::Error>,
    scratch: Vec<u8>,
}

impl Writer {
    fn now(&self) -> u64 {
        self.start.elapsed().as_micros() as u64
    }

    /// Writes one record; returns its size in the file.
    fn put(&mut self, tag: u8, body: &[u8]) -> u64 {
        let n = (1 + 4 + body.len() + 4) as u64;
        if let (Some(w), None) = (self.w.as_mut(), &self.error) {
            let len = (body.len() as u32).to_le_bytes();
            let mut crc = crc32fast::Hasher::new();
            crc.update(&[tag]);
            crc.update(&len);
            crc.update(body);
            let r = w
                .write_all(&[tag])
                .and_then(|()| w.write_all(&len))
                .and_then(|()| w.write_all(body))
                .and_then(|()| w.write_all(&crc.finalize().to_le_bytes()));
            if let Err(e) = r {
                self.error = Some(e);
            }
            self.bytes += n;
        }
        n
    }

    fn record(&mut self, r: &TraceRecord) {
        if self.w.is_none() {
            return;
        }
        let is_event = matches!(r, TraceRecord::Event { .. });
        if is_event && self.event_bytes >= TRACE_MAX_EVENT_BYTES {
            self.omitted += 1;
            return;
        }
        let mut body = std::mem::take(&mut self.scratch);
        body.clear();
        let tag = encode(r, &mut body);
        let n = self.put(tag, &body);
        self.scratch = body;
        self.records += 1;
        if is_event {
            self.event_bytes += n;
        }
    }
}

/// A trace being written, shared by the [`TracingBackend`] and its streams' sinks. Call
/// [`TraceHandle::finish`] once the device is closed: it writes the end record and renames the
/// file into place (dropping an unfinished handle removes the temporary file).
#[derive(Clone)]
pub struct TraceHandle {
    inner: Arc<Mutex<Writer>>,
}

impl TraceHandle {
    /// Starts a trace to `path` (written beside it, renamed at [`Self::finish`]); `payload`
    /// keeps every event's whole payload instead of its framing bytes.
    pub fn create(path: &Path, payload: bool) -> Result<Self> {
        let file_err = |source| KinectError::File { path: path.to_path_buf(), source };
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let tmp = path.with_file_name(format!(".{name}.{}.partial", std::process::id()));
        let mut w = BufWriter::new(File::create(&tmp).map_err(file_err)?);
        let mut h = Vec::with_capacity(28);
        h.extend_from_slice(TRACE_MAGIC);
        h.extend_from_slice(&TRACE_VERSION.to_le_bytes());
        h.extend_from_slice(&(if payload { FLAG_PAYLOAD } else { 0 }).to_le_bytes());
        let epoch = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_micros() as u64);
        h.extend_from_slice(&epoch.to_le_bytes());
        h.extend_from_slice(&crc32fast::hash(&h).to_le_bytes());
        if let Err(e) = w.write_all(&h) {
            let _ = std::fs::remove_file(&tmp);
            return Err(file_err(e));
        }
        let writer = Writer {
            w: Some(w),
            tmp,
            path: path.to_path_buf(),
            start: Instant::now(),
            payload,
            records: 0,
            omitted: 0,
            event_bytes: 0,
            bytes: h.len() as u64,
            error: None,
            scratch: Vec::new(),
        };
        Ok(TraceHandle { inner: Arc::new(Mutex::new(writer)) })
    }

    fn lock(&self) -> MutexGuard<'_, Writer> {
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn record(&self, r: TraceRecord) {
        self.lock().record(&r);
    }

    fn now(&self) -> u64 {
        self.lock().now()
    }

    fn event(&self, ep: u8, ev: &StreamEvent) {
        let mut w = self.lock();
        let t_us = w.now();
        let payload = w.payload;
        let framing = |data: &[u8], head: usize, tail: usize| {
            if payload {
                return (data.to_vec(), Vec::new());
            }
            let h = head.min(data.len());
            let t = tail.min(data.len() - h);
            (data[..h].to_vec(), data[data.len() - t..].to_vec())
        };
        let event = match ev {
            StreamEvent::IsoPacket { status, data } => {
                let (head, tail) = framing(data, 0, TRACE_ISO_TAIL);
                TracedEvent::Iso { status: *status, length: data.len() as u32, head, tail }
            }
            StreamEvent::Bulk { status, data } => {
                let (head, tail) = framing(data, TRACE_BULK_HEAD, TRACE_BULK_TAIL);
                TracedEvent::Bulk { status: *status, length: data.len() as u32, head, tail }
            }
            StreamEvent::Retired { error, in_flight } => {
                TracedEvent::Retired { error: *error, in_flight: *in_flight as u32 }
            }
            StreamEvent::Stopped { reason } => TracedEvent::Stopped { reason: *reason },
        };
        w.record(&TraceRecord::Event { t_us, ep, event });
    }

    /// Writes the end record and publishes the file at its name. Errors: a write that failed
    /// during the session (the first one), or the final flush or rename.
    pub fn finish(&self) -> Result<TraceSummary> {
        let mut w = self.lock();
        let Some(mut file) = w.w.take() else {
            return Err(KinectError::Invalid("the USB trace was already finished".into()));
        };
        let (records, omitted, path, tmp) = (w.records, w.omitted, w.path.clone(), w.tmp.clone());
        let mut end = Vec::with_capacity(24);
        end.extend_from_slice(&0u64.to_le_bytes());
        end.extend_from_slice(&records.to_le_bytes());
        end.extend_from_slice(&omitted.to_le_bytes());
        let len = (end.len() as u32).to_le_bytes();
        let mut crc = crc32fast::Hasher::new();
        crc.update(&[TAG_END]);
        crc.update(&len);
        crc.update(&end);
        let r = match w.error.take() {
            Some(e) => Err(e),
            None => file
                .write_all(&[TAG_END])
                .and_then(|()| file.write_all(&len))
                .and_then(|()| file.write_all(&end))
                .and_then(|()| file.write_all(&crc.finalize().to_le_bytes()))
                .and_then(|()| file.into_inner().map_err(|e| e.into_error()))
                .and_then(|f| f.sync_all())
                .and_then(|()| std::fs::rename(&tmp, &path)),
        };
        if let Err(source) = r {
            let _ = std::fs::remove_file(&tmp);
            return Err(KinectError::File { path, source });
        }
        Ok(TraceSummary { records, omitted, bytes: w.bytes + 9 + end.len() as u64 })
    }
}

impl Drop for Writer {
    fn drop(&mut self) {
        if self.w.take().is_some() {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

struct TracingSink {
    inner: Arc<dyn EventSink>,
    trace: TraceHandle,
    ep: u8,
}

impl EventSink for TracingSink {
    fn deliver(&self, ev: StreamEvent) {
        self.trace.event(self.ep, &ev);
        self.inner.deliver(ev);
    }
}

/// A backend that records every call and stream event of `inner` in a trace.
pub struct TracingBackend<B: UsbBackend> {
    inner: B,
    trace: TraceHandle,
    /// Endpoint of each started stream.
    streams: Vec<(StreamHandle, u8)>,
}

impl<B: UsbBackend> TracingBackend<B> {
    /// Traces `inner` into `trace`.
    pub fn new(inner: B, trace: TraceHandle) -> Self {
        TracingBackend { inner, trace, streams: Vec::new() }
    }

    /// The traced backend.
    pub fn inner(&self) -> &B {
        &self.inner
    }

    #[allow(clippy::too_many_arguments)] // one field of the record each
    fn call(
        &self,
        op: CallOp,
        a: u8,
        b: u8,
        value: u16,
        index: u16,
        req_len: usize,
        result: std::result::Result<u32, UsbError>,
        data: &[u8],
    ) {
        let t_us = self.trace.now();
        let rec = CallRecord {
            t_us,
            op,
            a,
            b,
            value,
            index,
            req_len: req_len as u32,
            result,
            data: data.to_vec(),
        };
        self.trace.record(TraceRecord::Call(rec));
    }

    fn simple<T>(
        &mut self,
        op: CallOp,
        a: u8,
        b: u8,
        f: impl FnOnce(&mut B) -> std::result::Result<T, UsbError>,
        num: impl Fn(&T) -> u32,
    ) -> std::result::Result<T, UsbError> {
        let r = f(&mut self.inner);
        self.call(op, a, b, 0, 0, 0, r.as_ref().map(&num).map_err(|e| *e), &[]);
        r
    }
}

impl<B: UsbBackend> UsbBackend for TracingBackend<B> {
    fn active_config(&mut self) -> std::result::Result<u8, UsbError> {
        self.simple(CallOp::ActiveConfig, 0, 0, |b| b.active_config(), |c| *c as u32)
    }
    fn set_config(&mut self, cfg: u8) -> std::result::Result<(), UsbError> {
        self.simple(CallOp::SetConfig, cfg, 0, |b| b.set_config(cfg), |_| 0)
    }
    fn reset(&mut self) -> std::result::Result<ResetOutcome, UsbError> {
        self.simple(
            CallOp::Reset,
            0,
            0,
            |b| b.reset(),
            |o| (*o == ResetOutcome::Reenumerated) as u32,
        )
    }
    fn reopen(&mut self, wait: Duration) -> std::result::Result<(), UsbError> {
        self.simple(CallOp::Reopen, 0, 0, |b| b.reopen(wait), |_| 0)
    }
    fn claim(&mut self, iface: u8) -> std::result::Result<(), UsbError> {
        self.simple(CallOp::Claim, iface, 0, |b| b.claim(iface), |_| 0)
    }
    fn release(&mut self, iface: u8) -> std::result::Result<(), UsbError> {
        self.simple(CallOp::Release, iface, 0, |b| b.release(iface), |_| 0)
    }
    fn set_alt(&mut self, iface: u8, alt: u8) -> std::result::Result<(), UsbError> {
        self.simple(CallOp::SetAlt, iface, alt, |b| b.set_alt(iface, alt), |_| 0)
    }
    fn control_out(
        &mut self,
        req_type: u8,
        req: u8,
        value: u16,
        index: u16,
        data: &[u8],
        timeout: Duration,
    ) -> std::result::Result<usize, UsbError> {
        let r = self.inner.control_out(req_type, req, value, index, data, timeout);
        let num = r.map(|n| n as u32);
        self.call(CallOp::ControlOut, req_type, req, value, index, data.len(), num, data);
        r
    }
    fn bulk_out(
        &mut self,
        ep: u8,
        data: &[u8],
        timeout: Duration,
    ) -> std::result::Result<usize, UsbError> {
        let r = self.inner.bulk_out(ep, data, timeout);
        self.call(CallOp::BulkOut, ep, 0, 0, 0, data.len(), r.map(|n| n as u32), data);
        r
    }
    fn bulk_in(
        &mut self,
        ep: u8,
        buf: &mut [u8],
        timeout: Duration,
    ) -> std::result::Result<usize, UsbError> {
        let r = self.inner.bulk_in(ep, buf, timeout);
        let got = r.as_ref().map_or(&[][..], |n| &buf[..(*n).min(buf.len())]);
        self.call(CallOp::BulkIn, ep, 0, 0, 0, buf.len(), r.map(|n| n as u32), got);
        r
    }
    fn clear_halt(&mut self, ep: u8) -> std::result::Result<(), UsbError> {
        self.simple(CallOp::ClearHalt, ep, 0, |b| b.clear_halt(ep), |_| 0)
    }
    fn iso_bytes_per_interval(&mut self, ep: u8, alt: u8) -> std::result::Result<u32, UsbError> {
        self.simple(
            CallOp::IsoBytesPerInterval,
            ep,
            alt,
            |b| b.iso_bytes_per_interval(ep, alt),
            |n| *n,
        )
    }
    fn start_stream(
        &mut self,
        spec: StreamSpec,
        sink: Arc<dyn EventSink>,
    ) -> std::result::Result<StreamHandle, UsbError> {
        let ep = match spec {
            StreamSpec::Bulk { ep, .. } | StreamSpec::Iso { ep, .. } => ep,
        };
        // The start is written before the transfers are submitted: their events (from the
        // completion thread) follow it in the file.
        let t_us = self.trace.now();
        let wrapped = Arc::new(TracingSink { inner: sink, trace: self.trace.clone(), ep });
        self.trace.record(TraceRecord::StreamStart { t_us, spec, result: Ok(()) });
        let r = self.inner.start_stream(spec, wrapped);
        match r {
            Ok(h) => self.streams.push((h, ep)),
            Err(e) => {
                let t_us = self.trace.now();
                self.trace.record(TraceRecord::StreamStop { t_us, ep, result: Err(e) });
            }
        }
        r
    }
    fn service(&mut self, timeout: Duration) -> std::result::Result<Serviced, UsbError> {
        self.inner.service(timeout)
    }
    fn stop_stream(
        &mut self,
        h: StreamHandle,
        max_wait: Duration,
    ) -> std::result::Result<(), UsbError> {
        let r = self.inner.stop_stream(h, max_wait);
        let ep = self.streams.iter().find(|(s, _)| *s == h).map_or(0, |s| s.1);
        self.streams.retain(|(s, _)| *s != h);
        let t_us = self.trace.now();
        self.trace.record(TraceRecord::StreamStop { t_us, ep, result: r });
        r
    }
}
