//! Asynchronous libusb transfers (isochronous depth, bulk colour) — the only `unsafe` code of
//! kfuse. rusb has no isochronous API, so this drives `libusb1-sys` (re-exported as
//! `rusb::ffi`) directly, following protocol §5.5: a pool of transfers that resubmit themselves on
//! completion, per-packet data handed over in descriptor order at offsets `i × packet_size`
//! (always advancing by the nominal size), a failed submission or resubmission retiring that
//! transfer only (`crate::pool`: the stream ends when none is left).
//!
//! Lifetime rule: a transfer and its buffer are freed only once libusb has returned it (its
//! callback ran with resubmission disabled or cancellation); if cancellation does not finish
//! within the stop bound, the pool is leaked rather than freed under libusb's feet.
#![allow(unsafe_code)]

use std::os::raw::{c_int, c_uint, c_void};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use rusb::ffi;
use rusb::ffi::constants::{
    LIBUSB_TRANSFER_CANCELLED, LIBUSB_TRANSFER_COMPLETED, LIBUSB_TRANSFER_NO_DEVICE,
    LIBUSB_TRANSFER_TIMED_OUT, LIBUSB_TRANSFER_TYPE_ISOCHRONOUS,
};

use crate::backend::{EventSink, StopReason, StreamEvent, XferStatus};
use crate::error::UsbError;
use crate::pool::{resubmit_failed, submit_pool};

struct Shared {
    /// Where the pool's events go: the device's frame sink, which assembles frames here, on
    /// the event thread (protocol §5.5), instead of queueing packets for the consumer.
    sink: Arc<dyn EventSink>,
    iso: bool,
    packet_size: usize,
    stopping: AtomicBool,
    in_flight: AtomicUsize,
}

impl Shared {
    fn send(&self, ev: StreamEvent) {
        self.sink.deliver(ev);
    }
}

fn status_of(s: c_int) -> XferStatus {
    match s {
        LIBUSB_TRANSFER_COMPLETED => XferStatus::Completed,
        LIBUSB_TRANSFER_TIMED_OUT => XferStatus::TimedOut,
        LIBUSB_TRANSFER_CANCELLED => XferStatus::Cancelled,
        _ => XferStatus::Error,
    }
}

/// What a completion callback does with a transfer that came back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Disposition {
    /// The device is gone: retire the transfer and report `Disconnected`.
    Disconnected,
    /// Cancelled, or the pool is stopping: retire silently.
    Retire,
    /// Hand its data over and resubmit.
    Deliver,
}

fn disposition(status: c_int, stopping: bool) -> Disposition {
    if status == LIBUSB_TRANSFER_NO_DEVICE {
        Disposition::Disconnected
    } else if status == LIBUSB_TRANSFER_CANCELLED || stopping {
        Disposition::Retire
    } else {
        Disposition::Deliver
    }
}

/// Linux's errno for "out of memory" (`asm-generic/errno-base.h`): what usbfs returns when a
/// transfer would exceed `usbfs_memory_mb`.
const ENOMEM: i32 = 12;

/// The transport error of a failed `libusb_submit_transfer` returning `rc`, `errno` the OS error
/// right after the call. libusb 1.0.27 reports usbfs's `ENOMEM` as `NO_MEM` for bulk transfers
/// but as `IO` for isochronous ones (`linux_usbfs.c` `submit_iso_transfer`), hence the errno.
fn submit_error(rc: c_int, errno: Option<i32>) -> UsbError {
    match rc {
        ffi::constants::LIBUSB_ERROR_NO_DEVICE => UsbError::NoDevice,
        ffi::constants::LIBUSB_ERROR_NO_MEM => UsbError::NoMem,
        ffi::constants::LIBUSB_ERROR_IO if errno == Some(ENOMEM) => UsbError::NoMem,
        _ => UsbError::Io,
    }
}

/// Submits `t`, returning its transport error on failure.
///
/// # Safety
/// `t` must be a filled transfer that is not in flight.
unsafe fn submit(t: *mut ffi::libusb_transfer) -> Result<(), UsbError> {
    // SAFETY: guaranteed by the caller.
    let rc = unsafe { ffi::libusb_submit_transfer(t) };
    if rc == 0 {
        return Ok(());
    }
    Err(submit_error(rc, std::io::Error::last_os_error().raw_os_error()))
}

/// One isochronous packet descriptor as libusb reports it on completion.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct IsoDesc {
    status: c_int,
    actual_length: c_uint,
}

/// The isochronous bookkeeping of protocol §5.5: one event per descriptor, in order; packet `i`'s
/// data starts at the **nominal** offset `i × packet_size` whatever happened to earlier packets
/// (the reference's \[QUIRK\] of advancing only past completed packets is not reproduced); its
/// length is `actual_length` clamped to the packet size and to the buffer; only completed
/// packets carry data.
fn iso_events(buffer: &[u8], descs: &[IsoDesc], packet_size: usize) -> Vec<StreamEvent> {
    descs
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let status = status_of(d.status);
            let data = if status == XferStatus::Completed {
                let start = i.saturating_mul(packet_size).min(buffer.len());
                let len = (d.actual_length as usize).min(packet_size).min(buffer.len() - start);
                buffer[start..start + len].to_vec()
            } else {
                Vec::new()
            };
            StreamEvent::IsoPacket { status, data }
        })
        .collect()
}

/// A bulk transfer's event: its first `actual_length` bytes (clamped to the buffer) when
/// completed, nothing otherwise.
fn bulk_event(status: c_int, buffer: &[u8], actual_length: c_int) -> StreamEvent {
    let status = status_of(status);
    let data = if status == XferStatus::Completed {
        buffer[..(actual_length.max(0) as usize).min(buffer.len())].to_vec()
    } else {
        Vec::new()
    };
    StreamEvent::Bulk { status, data }
}

/// Reads a completed transfer's buffer and descriptors and turns them into events.
///
/// # Safety
/// `tr.buffer` must point to `tr.length` readable bytes and, for an isochronous transfer,
/// `tr.num_iso_packets` descriptors must follow the struct (as `libusb_alloc_transfer(n)`
/// with `n ≥ num_iso_packets` provides).
unsafe fn transfer_events(
    tr: &ffi::libusb_transfer,
    iso: bool,
    packet_size: usize,
) -> Vec<StreamEvent> {
    let len = tr.length.max(0) as usize;
    let buffer: &[u8] = if tr.buffer.is_null() || len == 0 {
        &[]
    } else {
        // SAFETY: the caller guarantees `length` readable bytes at `buffer`.
        unsafe { std::slice::from_raw_parts(tr.buffer, len) }
    };
    if iso {
        let n = tr.num_iso_packets.max(0) as usize;
        // SAFETY: the caller guarantees `n` descriptors in the flexible array member.
        let descs = unsafe { std::slice::from_raw_parts(tr.iso_packet_desc.as_ptr(), n) };
        let descs: Vec<IsoDesc> = descs
            .iter()
            .map(|d| IsoDesc { status: d.status, actual_length: d.actual_length })
            .collect();
        iso_events(buffer, &descs, packet_size)
    } else {
        vec![bulk_event(tr.status, buffer, tr.actual_length)]
    }
}

extern "system" fn on_complete(t: *mut ffi::libusb_transfer) {
    // SAFETY: libusb calls this with a transfer we allocated and submitted; it stays allocated
    // until `TransferPool::drop` frees it, which only happens after `in_flight` reached zero,
    // i.e. after this callback has returned without resubmitting.
    let tr = unsafe { &mut *t };
    // SAFETY: `user_data` is `Arc::as_ptr` of the pool's `Shared`; the pool holds that Arc for
    // as long as any transfer can call back (see `Drop`).
    let shared = unsafe { &*(tr.user_data as *const Shared) };
    match disposition(tr.status, shared.stopping.load(Ordering::SeqCst)) {
        Disposition::Disconnected => {
            shared.in_flight.fetch_sub(1, Ordering::SeqCst);
            shared.send(StreamEvent::Stopped { reason: StopReason::Disconnected });
            return;
        }
        Disposition::Retire => {
            shared.in_flight.fetch_sub(1, Ordering::SeqCst);
            return;
        }
        Disposition::Deliver => {}
    }
    // SAFETY: the pool filled this transfer with a buffer of `length` = packets × packet_size
    // bytes (or `packet_size` for bulk) that it owns until the transfer is freed, and allocated
    // it with `num_iso_packets` descriptors.
    for ev in unsafe { transfer_events(tr, shared.iso, shared.packet_size) } {
        shared.send(ev);
    }
    // SAFETY: resubmitting a transfer from its own completion callback is allowed by libusb.
    if let Err(e) = unsafe { submit(t) } {
        // Retire this transfer only; the stream ends when none is left (protocol §5.5).
        let left = shared.in_flight.fetch_sub(1, Ordering::SeqCst).saturating_sub(1);
        for ev in resubmit_failed(e, left) {
            shared.send(ev);
        }
    }
}

/// A pool of self-resubmitting transfers on one endpoint.
pub(crate) struct TransferPool {
    shared: Arc<Shared>,
    transfers: Vec<*mut ffi::libusb_transfer>,
    _buffers: Vec<Box<[u8]>>,
}

// SAFETY: the raw transfer pointers are only touched by libusb (its event thread) and by this
// pool's methods, which libusb allows from any thread; the shared state is Sync.
unsafe impl Send for TransferPool {}

impl TransferPool {
    /// Allocates and submits `count` transfers on `endpoint`: isochronous with `packets` ×
    /// `packet_size` bytes, or bulk of `packet_size` bytes when `packets == 0`.
    #[allow(clippy::too_many_arguments)] // mirrors libusb's transfer fields one to one
    pub(crate) fn start(
        dev: *mut ffi::libusb_device_handle,
        endpoint: u8,
        count: usize,
        packets: usize,
        packet_size: usize,
        sink: Arc<dyn EventSink>,
        timeout: Duration,
    ) -> Result<Self, UsbError> {
        let shared = Arc::new(Shared {
            sink,
            iso: packets > 0,
            packet_size,
            stopping: AtomicBool::new(false),
            in_flight: AtomicUsize::new(0),
        });
        let mut pool = TransferPool { shared, transfers: Vec::new(), _buffers: Vec::new() };
        let len = packet_size * packets.max(1);
        for _ in 0..count {
            // SAFETY: plain allocation; null is checked below.
            let t = unsafe { ffi::libusb_alloc_transfer(packets as c_int) };
            if t.is_null() {
                pool.stop(Duration::from_secs(2));
                return Err(UsbError::Io);
            }
            let mut buf = vec![0u8; len].into_boxed_slice();
            let user = Arc::as_ptr(&pool.shared) as *mut c_void;
            // SAFETY: `t` is a fresh transfer with room for `packets` descriptors; `buf` lives in
            // the pool (boxed, never moved) as long as the transfer.
            unsafe {
                if packets > 0 {
                    ffi::libusb_fill_iso_transfer(
                        t,
                        dev,
                        endpoint,
                        buf.as_mut_ptr(),
                        len as c_int,
                        packets as c_int,
                        on_complete,
                        user,
                        timeout.as_millis() as c_uint,
                    );
                    for i in 0..packets {
                        (*(*t).iso_packet_desc.as_mut_ptr().add(i)).length = packet_size as c_uint;
                    }
                    debug_assert_eq!((*t).transfer_type, LIBUSB_TRANSFER_TYPE_ISOCHRONOUS);
                } else {
                    ffi::libusb_fill_bulk_transfer(
                        t,
                        dev,
                        endpoint,
                        buf.as_mut_ptr(),
                        len as c_int,
                        on_complete,
                        user,
                        timeout.as_millis() as c_uint,
                    );
                }
            }
            pool.transfers.push(t);
            pool._buffers.push(buf);
        }
        // The pool starts if at least one transfer went in flight (protocol §5.5); the others
        // are reported retired.
        let submitted = submit_pool(pool.transfers.len(), |i| {
            let t = pool.transfers[i];
            pool.shared.in_flight.fetch_add(1, Ordering::SeqCst);
            // SAFETY: `t` was filled above and is not in flight.
            let r = unsafe { submit(t) };
            if r.is_err() {
                pool.shared.in_flight.fetch_sub(1, Ordering::SeqCst);
            }
            r
        });
        match submitted {
            Ok(s) => {
                for ev in s.retired_events() {
                    pool.shared.send(ev);
                }
                Ok(pool)
            }
            Err(e) => {
                pool.stop(Duration::from_secs(2));
                Err(e)
            }
        }
    }

    /// Disables resubmission, cancels every transfer and waits up to `max_wait` for them to
    /// come back (the backend's event thread keeps servicing libusb meanwhile). Returns false
    /// on timeout.
    pub(crate) fn stop(&mut self, max_wait: Duration) -> bool {
        self.shared.stopping.store(true, Ordering::SeqCst);
        for &t in &self.transfers {
            // SAFETY: cancelling a transfer that is not in flight returns an error and is
            // otherwise harmless.
            unsafe { ffi::libusb_cancel_transfer(t) };
        }
        let deadline = Instant::now() + max_wait;
        while self.shared.in_flight.load(Ordering::SeqCst) > 0 {
            if Instant::now() > deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        true
    }
}

impl Drop for TransferPool {
    fn drop(&mut self) {
        if !self.stop(Duration::from_secs(2)) {
            // Transfers still owned by libusb: leak them (and the shared state they point to)
            // instead of freeing memory libusb may still write.
            std::mem::forget(Arc::clone(&self.shared));
            std::mem::forget(std::mem::take(&mut self._buffers));
            return;
        }
        for &t in &self.transfers {
            // SAFETY: every transfer came back (in_flight == 0) and is never used again.
            unsafe { ffi::libusb_free_transfer(t) };
        }
    }
}

#[cfg(test)]
mod tests {
    //! The libusb-side bookkeeping without a device: synthetic descriptors, and real
    //! `libusb_transfer` structs (allocation needs no device or context) filled by hand.
    use super::*;
    use crate::raw::RAW_FRAME_BYTES;
    use crate::stream::{DepthAssembler, packetize_depth_frame};
    use rusb::ffi::constants::{
        LIBUSB_ERROR_IO, LIBUSB_TRANSFER_ERROR, LIBUSB_TRANSFER_OVERFLOW, LIBUSB_TRANSFER_STALL,
    };

    const OK: c_int = LIBUSB_TRANSFER_COMPLETED;

    fn d(status: c_int, actual_length: c_uint) -> IsoDesc {
        IsoDesc { status, actual_length }
    }

    fn iso(status: XferStatus, data: &[u8]) -> StreamEvent {
        StreamEvent::IsoPacket { status, data: data.to_vec() }
    }

    /// Packet i's bytes are `i * 16 + k`: the expected slices are written out by hand.
    #[test]
    fn iso_events_use_nominal_offsets_and_statuses() {
        let buf: Vec<u8> = (0..64u8).collect();
        let descs =
            [d(OK, 16), d(LIBUSB_TRANSFER_ERROR, 16), d(OK, 5), d(LIBUSB_TRANSFER_TIMED_OUT, 16)];
        let ev = iso_events(&buf, &descs, 16);
        assert_eq!(
            ev,
            [
                iso(XferStatus::Completed, &(0..16).collect::<Vec<u8>>()),
                iso(XferStatus::Error, &[]),
                // After a failed packet the next one still starts at 2 × 16, not at 16.
                iso(XferStatus::Completed, &[32, 33, 34, 35, 36]),
                iso(XferStatus::TimedOut, &[]),
            ]
        );
        // Stall, overflow and cancelled map to Error / Cancelled without data.
        let ev = iso_events(
            &buf,
            &[
                d(LIBUSB_TRANSFER_STALL, 3),
                d(LIBUSB_TRANSFER_OVERFLOW, 3),
                d(LIBUSB_TRANSFER_CANCELLED, 3),
            ],
            16,
        );
        assert_eq!(
            ev,
            [
                iso(XferStatus::Error, &[]),
                iso(XferStatus::Error, &[]),
                iso(XferStatus::Cancelled, &[])
            ]
        );
        // Zero-length completed packets (the gaps between depth sub-packets) stay empty.
        assert_eq!(iso_events(&buf, &[d(OK, 0)], 16), [iso(XferStatus::Completed, &[])]);
    }

    /// Lengths a misbehaving host controller could report never read outside the packet or
    /// the buffer.
    #[test]
    fn iso_events_clamp_lengths() {
        let buf: Vec<u8> = (0..40u8).collect();
        // actual_length above the packet size is clamped to it; the third packet's slot is
        // cut by the end of the buffer (40 bytes for 3 × 16); the fourth lies beyond it.
        let ev = iso_events(&buf, &[d(OK, 999), d(OK, 16), d(OK, 16), d(OK, 16)], 16);
        assert_eq!(
            ev,
            [
                iso(XferStatus::Completed, &(0..16).collect::<Vec<u8>>()),
                iso(XferStatus::Completed, &(16..32).collect::<Vec<u8>>()),
                iso(XferStatus::Completed, &(32..40).collect::<Vec<u8>>()),
                iso(XferStatus::Completed, &[]),
            ]
        );
        assert_eq!(iso_events(&buf, &[d(OK, 5)], 0), [iso(XferStatus::Completed, &[])]);
        assert_eq!(iso_events(&[], &[d(OK, 5)], 16), [iso(XferStatus::Completed, &[])]);
    }

    #[test]
    fn bulk_event_takes_actual_length() {
        let buf: Vec<u8> = (0..10u8).collect();
        assert_eq!(
            bulk_event(OK, &buf, 4),
            StreamEvent::Bulk { status: XferStatus::Completed, data: vec![0, 1, 2, 3] }
        );
        assert_eq!(
            bulk_event(OK, &buf, 99),
            StreamEvent::Bulk { status: XferStatus::Completed, data: buf.clone() }
        );
        assert_eq!(
            bulk_event(OK, &buf, -1),
            StreamEvent::Bulk { status: XferStatus::Completed, data: vec![] }
        );
        assert_eq!(
            bulk_event(LIBUSB_TRANSFER_ERROR, &buf, 4),
            StreamEvent::Bulk { status: XferStatus::Error, data: vec![] }
        );
        assert_eq!(
            bulk_event(LIBUSB_TRANSFER_TIMED_OUT, &buf, 4),
            StreamEvent::Bulk { status: XferStatus::TimedOut, data: vec![] }
        );
    }

    #[test]
    fn disposition_of_completions() {
        assert_eq!(disposition(LIBUSB_TRANSFER_NO_DEVICE, false), Disposition::Disconnected);
        assert_eq!(disposition(LIBUSB_TRANSFER_NO_DEVICE, true), Disposition::Disconnected);
        assert_eq!(disposition(LIBUSB_TRANSFER_CANCELLED, false), Disposition::Retire);
        assert_eq!(disposition(OK, true), Disposition::Retire);
        for s in [OK, LIBUSB_TRANSFER_ERROR, LIBUSB_TRANSFER_TIMED_OUT, LIBUSB_TRANSFER_STALL] {
            assert_eq!(disposition(s, false), Disposition::Deliver, "{s}");
        }
    }

    #[test]
    fn submit_errors_name_usbfs_memory() {
        use ffi::constants::{LIBUSB_ERROR_NO_DEVICE, LIBUSB_ERROR_NO_MEM};
        assert_eq!(submit_error(LIBUSB_ERROR_NO_DEVICE, None), UsbError::NoDevice);
        assert_eq!(submit_error(LIBUSB_ERROR_NO_MEM, None), UsbError::NoMem);
        // Isochronous: libusb says IO, errno says ENOMEM.
        assert_eq!(submit_error(LIBUSB_ERROR_IO, Some(ENOMEM)), UsbError::NoMem);
        assert_eq!(submit_error(LIBUSB_ERROR_IO, Some(5)), UsbError::Io);
        assert_eq!(submit_error(LIBUSB_ERROR_IO, None), UsbError::Io);
    }

    /// Packets laid out as a host controller fills real `libusb_transfer`s (8 descriptors of
    /// 33 792 bytes each, data at the nominal offsets), with an extra failed descriptor holding
    /// garbage in the middle of frame 1, go through the same unsafe extraction as the callback
    /// and the depth assembler: all three frames come out bit-exact. Reading from the wrong
    /// offset after the failed packet (the reference's quirk) would corrupt frame 1.
    #[test]
    fn real_transfer_structs_reassemble_frames() {
        const PACKETS: usize = 8;
        const PS: usize = 33_792;
        let frames: Vec<Vec<u8>> = (0..3u32)
            .map(|f| {
                (0..RAW_FRAME_BYTES).map(|i| ((i * 7 + f as usize * 101) % 251) as u8).collect()
            })
            .collect();
        // (status, bytes) per descriptor slot.
        let mut slots: Vec<(c_int, Vec<u8>)> = Vec::new();
        for (f, raw) in frames.iter().enumerate() {
            let packets = packetize_depth_frame(
                raw,
                f as u32,
                1000 + 267 * f as u32,
                PS,
                [1, 2, 3, 1, 2, 3, 1, 2, 3, 1],
            );
            for (k, p) in packets.into_iter().enumerate() {
                if f == 1 && k == 20 {
                    slots.push((LIBUSB_TRANSFER_ERROR, vec![0xEE; PS]));
                }
                slots.push((OK, p));
            }
        }
        let mut asm = DepthAssembler::new();
        let mut got = Vec::new();
        let mut errors = 0;
        for chunk in slots.chunks(PACKETS) {
            let mut buf = vec![0u8; PACKETS * PS];
            // SAFETY: allocation only; checked for null below, freed at the end of this block.
            let t = unsafe { ffi::libusb_alloc_transfer(PACKETS as c_int) };
            assert!(!t.is_null());
            // SAFETY: `t` has room for PACKETS descriptors; `buf` outlives every use of `t`.
            let events = unsafe {
                let tr = &mut *t;
                tr.buffer = buf.as_mut_ptr();
                tr.length = (PACKETS * PS) as c_int;
                tr.num_iso_packets = chunk.len() as c_int;
                tr.status = OK;
                for (i, (status, data)) in chunk.iter().enumerate() {
                    buf[i * PS..i * PS + data.len()].copy_from_slice(data);
                    let desc = &mut *tr.iso_packet_desc.as_mut_ptr().add(i);
                    desc.length = PS as c_uint;
                    desc.status = *status;
                    desc.actual_length = if *status == OK { data.len() as c_uint } else { 0 };
                }
                let ev = transfer_events(tr, true, PS);
                ffi::libusb_free_transfer(t);
                ev
            };
            assert_eq!(events.len(), chunk.len());
            for ev in events {
                match ev {
                    StreamEvent::IsoPacket { status: XferStatus::Completed, data } => {
                        if let Some(f) = asm.push(&data) {
                            got.push((
                                f.sequence,
                                f.data == frames[f.sequence as usize].as_slice(),
                            ));
                        }
                    }
                    StreamEvent::IsoPacket { .. } => errors += 1,
                    e => panic!("unexpected {e:?}"),
                }
            }
        }
        assert_eq!(errors, 1);
        assert_eq!(got, [(0, true), (1, true), (2, true)]);
        assert_eq!((asm.stats.incomplete_frames, asm.stats.skipped_frames), (0, 0));
    }
}
