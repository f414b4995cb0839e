//! Asynchronous libusb transfers (isochronous depth, bulk colour) — the only `unsafe` code of
//! kfuse. rusb has no isochronous API, so this drives `libusb1-sys` (re-exported as
//! `rusb::ffi`) directly, following spec §5.5: a pool of transfers that resubmit themselves on
//! completion, per-packet data handed over in descriptor order at offsets `i × packet_size`
//! (always advancing by the nominal size), failed resubmission surfaced as a `Stopped` event.
//!
//! Lifetime rule: a transfer and its buffer are freed only once libusb has returned it (its
//! callback ran with resubmission disabled or cancellation); if cancellation does not finish
//! within the stop bound, the pool is leaked rather than freed under libusb's feet.
#![allow(unsafe_code)]

use std::os::raw::{c_int, c_uint, c_void};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::Sender;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rusb::ffi;
use rusb::ffi::constants::{
    LIBUSB_TRANSFER_CANCELLED, LIBUSB_TRANSFER_COMPLETED, LIBUSB_TRANSFER_NO_DEVICE, LIBUSB_TRANSFER_TIMED_OUT,
    LIBUSB_TRANSFER_TYPE_ISOCHRONOUS,
};

use crate::backend::{StopReason, StreamEvent, StreamHandle, XferStatus};
use crate::error::UsbError;

/// Event sender shared by every transfer of a backend.
pub(crate) type EventTx = Sender<(StreamHandle, StreamEvent)>;

struct Shared {
    tx: Mutex<EventTx>,
    handle: StreamHandle,
    iso: bool,
    packet_size: usize,
    stopping: AtomicBool,
    in_flight: AtomicUsize,
}

impl Shared {
    fn send(&self, ev: StreamEvent) {
        if let Ok(tx) = self.tx.lock() {
            let _ = tx.send((self.handle, ev));
        }
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

extern "system" fn on_complete(t: *mut ffi::libusb_transfer) {
    // SAFETY: libusb calls this with a transfer we allocated and submitted; it stays allocated
    // until `TransferPool::drop` frees it, which only happens after `in_flight` reached zero,
    // i.e. after this callback has returned without resubmitting.
    let tr = unsafe { &mut *t };
    // SAFETY: `user_data` is `Arc::as_ptr` of the pool's `Shared`; the pool holds that Arc for
    // as long as any transfer can call back (see `Drop`).
    let shared = unsafe { &*(tr.user_data as *const Shared) };
    if tr.status == LIBUSB_TRANSFER_NO_DEVICE {
        shared.in_flight.fetch_sub(1, Ordering::SeqCst);
        shared.send(StreamEvent::Stopped { reason: StopReason::Disconnected });
        return;
    }
    if tr.status == LIBUSB_TRANSFER_CANCELLED || shared.stopping.load(Ordering::SeqCst) {
        shared.in_flight.fetch_sub(1, Ordering::SeqCst);
        return;
    }
    if shared.iso {
        let n = tr.num_iso_packets.max(0) as usize;
        for i in 0..n {
            // SAFETY: the transfer was allocated with `n` iso packet descriptors that follow the
            // struct in memory (`iso_packet_desc` is the C flexible array member).
            let d = unsafe { &*tr.iso_packet_desc.as_ptr().add(i) };
            let status = status_of(d.status);
            let len = (d.actual_length as usize).min(shared.packet_size);
            let data = if status == XferStatus::Completed {
                // SAFETY: the buffer holds `n × packet_size` bytes; packet i starts at
                // `i × packet_size` (always the nominal offset, spec §5.5) and `len` ≤ packet_size.
                unsafe { std::slice::from_raw_parts(tr.buffer.add(i * shared.packet_size), len) }.to_vec()
            } else {
                Vec::new()
            };
            shared.send(StreamEvent::IsoPacket { status, data });
        }
    } else {
        let status = status_of(tr.status);
        let len = (tr.actual_length.max(0) as usize).min(tr.length.max(0) as usize);
        let data = if status == XferStatus::Completed {
            // SAFETY: the buffer holds `length` bytes, `actual_length` ≤ `length`.
            unsafe { std::slice::from_raw_parts(tr.buffer, len) }.to_vec()
        } else {
            Vec::new()
        };
        shared.send(StreamEvent::Bulk { status, data });
    }
    // SAFETY: resubmitting a transfer from its own completion callback is allowed by libusb.
    let rc = unsafe { ffi::libusb_submit_transfer(t) };
    if rc != 0 {
        shared.in_flight.fetch_sub(1, Ordering::SeqCst);
        let reason = if rc == ffi::constants::LIBUSB_ERROR_NO_DEVICE { StopReason::Disconnected } else { StopReason::Stalled };
        shared.send(StreamEvent::Stopped { reason });
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
    pub(crate) fn start(
        dev: *mut ffi::libusb_device_handle,
        endpoint: u8,
        count: usize,
        packets: usize,
        packet_size: usize,
        handle: StreamHandle,
        tx: EventTx,
        timeout: Duration,
    ) -> Result<Self, UsbError> {
        let shared = Arc::new(Shared {
            tx: Mutex::new(tx),
            handle,
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
                    ffi::libusb_fill_iso_transfer(t, dev, endpoint, buf.as_mut_ptr(), len as c_int, packets as c_int, on_complete, user, timeout.as_millis() as c_uint);
                    for i in 0..packets {
                        (*(*t).iso_packet_desc.as_mut_ptr().add(i)).length = packet_size as c_uint;
                    }
                    debug_assert_eq!((*t).transfer_type, LIBUSB_TRANSFER_TYPE_ISOCHRONOUS);
                } else {
                    ffi::libusb_fill_bulk_transfer(t, dev, endpoint, buf.as_mut_ptr(), len as c_int, on_complete, user, timeout.as_millis() as c_uint);
                }
            }
            pool.transfers.push(t);
            pool._buffers.push(buf);
        }
        for &t in &pool.transfers {
            pool.shared.in_flight.fetch_add(1, Ordering::SeqCst);
            // SAFETY: `t` was filled above and is not in flight.
            let rc = unsafe { ffi::libusb_submit_transfer(t) };
            if rc != 0 {
                pool.shared.in_flight.fetch_sub(1, Ordering::SeqCst);
                pool.stop(Duration::from_secs(2));
                return Err(if rc == ffi::constants::LIBUSB_ERROR_NO_DEVICE { UsbError::NoDevice } else { UsbError::Io });
            }
        }
        Ok(pool)
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
