//! The transport abstraction (protocol §14.1). The protocol layer, the parsers and the decoder see
//! only this trait and byte slices.
//!
//! Streaming events are *pushed* where the transfers complete: each stream delivers into the
//! [`EventSink`] given to [`UsbBackend::start_stream`] (the device's
//! [`FrameSink`](crate::latest::FrameSink), which assembles frames there and keeps the newest,
//! protocol §5.5). The libusb backend delivers from its event thread; the simulated device,
//! which has no thread of its own, completes its due transfers when
//! [`UsbBackend::service`] (or [`crate::sim::SimDevice::advance`]) runs, through the same sink.

use std::sync::Arc;
use std::time::Duration;

use crate::error::UsbError;

/// Result of a port reset.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ResetOutcome {
    /// The device is still there.
    Ok,
    /// The device re-enumerated (libusb `NOT_FOUND`): reopen it.
    Reenumerated,
}

/// What to stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StreamSpec {
    /// Bulk IN stream (colour).
    Bulk {
        /// Endpoint.
        ep: u8,
        /// Transfers in flight.
        transfers: usize,
        /// Bytes per transfer.
        size: usize,
    },
    /// Isochronous IN stream (depth).
    Iso {
        /// Endpoint.
        ep: u8,
        /// Transfers in flight.
        transfers: usize,
        /// Packets per transfer.
        packets: usize,
        /// Bytes per packet.
        packet_size: usize,
    },
}

/// Completion status of one transfer or iso packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum XferStatus {
    /// Completed (data valid).
    Completed,
    /// Error (data invalid).
    Error,
    /// Timed out.
    TimedOut,
    /// Cancelled.
    Cancelled,
}

/// Why a stream stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// Stopped on request.
    Requested,
    /// The device disappeared.
    Disconnected,
    /// The stream could not go on: every transfer of its pool was retired (their
    /// resubmissions failed for a reason other than a disconnection), or a replayed recording
    /// was corrupt.
    Stalled,
}

/// Identifies a running stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct StreamHandle(pub u32);

/// One streaming event.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StreamEvent {
    /// One completed bulk transfer.
    Bulk {
        /// Status.
        status: XferStatus,
        /// `actual_length` bytes.
        data: Vec<u8>,
    },
    /// One isochronous packet descriptor (in order).
    IsoPacket {
        /// Status.
        status: XferStatus,
        /// `actual_length` bytes.
        data: Vec<u8>,
    },
    /// One transfer of the stream's pool was retired: its first submission or a resubmission
    /// failed with `error` (not a disconnection). The stream goes on with `in_flight`
    /// transfers; when that is 0, a [`StreamEvent::Stopped`] follows (protocol §5.5).
    Retired {
        /// Why it could not be submitted ([`UsbError::NoMem`]: Linux's usbfs memory limit).
        error: UsbError,
        /// Transfers of the pool still in flight.
        in_flight: usize,
    },
    /// The stream ended.
    Stopped {
        /// Why.
        reason: StopReason,
    },
}

/// What [`UsbBackend::service`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Serviced {
    /// It delivered events to the streams' sinks.
    Delivered,
    /// Nothing was due within the timeout (or nothing is streaming).
    Idle,
    /// Transfers complete on the backend's own thread: wait on the sink.
    Background,
}

/// Where a stream's completed transfers go, called on the completion side (the libusb event
/// thread) for every event of that stream, in order.
pub trait EventSink: Send + Sync {
    /// One event of the stream.
    fn deliver(&self, ev: StreamEvent);
}

/// A USB transport to one opened Kinect v2.
pub trait UsbBackend: Send {
    /// Active configuration value.
    fn active_config(&mut self) -> Result<u8, UsbError>;
    /// Sets the configuration.
    fn set_config(&mut self, cfg: u8) -> Result<(), UsbError>;
    /// USB port reset.
    fn reset(&mut self) -> Result<ResetOutcome, UsbError>;
    /// After a reset that re-enumerated the device ([`ResetOutcome::Reenumerated`]): closes
    /// this handle, waits `wait`, finds the same sensor again (same serial) and opens it,
    /// without another reset (libfreenect2's workaround, protocol §5.1). `Err(NoDevice)` when
    /// no sensor with that serial came back.
    fn reopen(&mut self, wait: Duration) -> Result<(), UsbError>;
    /// Claims an interface.
    fn claim(&mut self, iface: u8) -> Result<(), UsbError>;
    /// Releases an interface.
    fn release(&mut self, iface: u8) -> Result<(), UsbError>;
    /// Selects an alternate setting.
    fn set_alt(&mut self, iface: u8, alt: u8) -> Result<(), UsbError>;
    /// Standard/host-to-device control request.
    fn control_out(
        &mut self,
        req_type: u8,
        req: u8,
        value: u16,
        index: u16,
        data: &[u8],
        timeout: Duration,
    ) -> Result<usize, UsbError>;
    /// Bulk OUT.
    fn bulk_out(&mut self, ep: u8, data: &[u8], timeout: Duration) -> Result<usize, UsbError>;
    /// Bulk IN.
    fn bulk_in(&mut self, ep: u8, buf: &mut [u8], timeout: Duration) -> Result<usize, UsbError>;
    /// Clears a halt (STALL) on an endpoint.
    fn clear_halt(&mut self, ep: u8) -> Result<(), UsbError>;
    /// `wBytesPerInterval` of the SuperSpeed companion descriptor of `ep` in alt setting `alt`.
    fn iso_bytes_per_interval(&mut self, ep: u8, alt: u8) -> Result<u32, UsbError>;
    /// Starts continuous streaming: every event of the stream goes to `sink`, from the
    /// completion side.
    fn start_stream(
        &mut self,
        spec: StreamSpec,
        sink: Arc<dyn EventSink>,
    ) -> Result<StreamHandle, UsbError>;
    /// Lets a backend without a completion thread of its own (the simulator) complete the
    /// transfers that are due, waiting at most `timeout` for one. A backend whose transfers
    /// complete on their own thread (libusb) returns [`Serviced::Background`] at once and the
    /// caller waits on its sink.
    fn service(&mut self, timeout: Duration) -> Result<Serviced, UsbError>;
    /// Cancels a stream and waits at most `max_wait` for its transfers.
    fn stop_stream(&mut self, h: StreamHandle, max_wait: Duration) -> Result<(), UsbError>;
}

impl<T: UsbBackend + ?Sized> UsbBackend for Box<T> {
    fn active_config(&mut self) -> Result<u8, UsbError> {
        (**self).active_config()
    }
    fn set_config(&mut self, cfg: u8) -> Result<(), UsbError> {
        (**self).set_config(cfg)
    }
    fn reset(&mut self) -> Result<ResetOutcome, UsbError> {
        (**self).reset()
    }
    fn reopen(&mut self, wait: Duration) -> Result<(), UsbError> {
        (**self).reopen(wait)
    }
    fn claim(&mut self, iface: u8) -> Result<(), UsbError> {
        (**self).claim(iface)
    }
    fn release(&mut self, iface: u8) -> Result<(), UsbError> {
        (**self).release(iface)
    }
    fn set_alt(&mut self, iface: u8, alt: u8) -> Result<(), UsbError> {
        (**self).set_alt(iface, alt)
    }
    fn control_out(
        &mut self,
        req_type: u8,
        req: u8,
        value: u16,
        index: u16,
        data: &[u8],
        timeout: Duration,
    ) -> Result<usize, UsbError> {
        (**self).control_out(req_type, req, value, index, data, timeout)
    }
    fn bulk_out(&mut self, ep: u8, data: &[u8], timeout: Duration) -> Result<usize, UsbError> {
        (**self).bulk_out(ep, data, timeout)
    }
    fn bulk_in(&mut self, ep: u8, buf: &mut [u8], timeout: Duration) -> Result<usize, UsbError> {
        (**self).bulk_in(ep, buf, timeout)
    }
    fn clear_halt(&mut self, ep: u8) -> Result<(), UsbError> {
        (**self).clear_halt(ep)
    }
    fn iso_bytes_per_interval(&mut self, ep: u8, alt: u8) -> Result<u32, UsbError> {
        (**self).iso_bytes_per_interval(ep, alt)
    }
    fn start_stream(
        &mut self,
        spec: StreamSpec,
        sink: Arc<dyn EventSink>,
    ) -> Result<StreamHandle, UsbError> {
        (**self).start_stream(spec, sink)
    }
    fn service(&mut self, timeout: Duration) -> Result<Serviced, UsbError> {
        (**self).service(timeout)
    }
    fn stop_stream(&mut self, h: StreamHandle, max_wait: Duration) -> Result<(), UsbError> {
        (**self).stop_stream(h, max_wait)
    }
}

/// A backend shared with an observer (e.g. a test or the CLI inspecting a simulated device
/// while a [`crate::device::KinectDevice`] owns it). A poisoned lock is used as is: the
/// backends keep no invariants that a panic half-way could break.
impl<T: UsbBackend> UsbBackend for std::sync::Arc<std::sync::Mutex<T>> {
    fn active_config(&mut self) -> Result<u8, UsbError> {
        lock(self).active_config()
    }
    fn set_config(&mut self, cfg: u8) -> Result<(), UsbError> {
        lock(self).set_config(cfg)
    }
    fn reset(&mut self) -> Result<ResetOutcome, UsbError> {
        lock(self).reset()
    }
    fn reopen(&mut self, wait: Duration) -> Result<(), UsbError> {
        lock(self).reopen(wait)
    }
    fn claim(&mut self, iface: u8) -> Result<(), UsbError> {
        lock(self).claim(iface)
    }
    fn release(&mut self, iface: u8) -> Result<(), UsbError> {
        lock(self).release(iface)
    }
    fn set_alt(&mut self, iface: u8, alt: u8) -> Result<(), UsbError> {
        lock(self).set_alt(iface, alt)
    }
    fn control_out(
        &mut self,
        req_type: u8,
        req: u8,
        value: u16,
        index: u16,
        data: &[u8],
        timeout: Duration,
    ) -> Result<usize, UsbError> {
        lock(self).control_out(req_type, req, value, index, data, timeout)
    }
    fn bulk_out(&mut self, ep: u8, data: &[u8], timeout: Duration) -> Result<usize, UsbError> {
        lock(self).bulk_out(ep, data, timeout)
    }
    fn bulk_in(&mut self, ep: u8, buf: &mut [u8], timeout: Duration) -> Result<usize, UsbError> {
        lock(self).bulk_in(ep, buf, timeout)
    }
    fn clear_halt(&mut self, ep: u8) -> Result<(), UsbError> {
        lock(self).clear_halt(ep)
    }
    fn iso_bytes_per_interval(&mut self, ep: u8, alt: u8) -> Result<u32, UsbError> {
        lock(self).iso_bytes_per_interval(ep, alt)
    }
    fn start_stream(
        &mut self,
        spec: StreamSpec,
        sink: Arc<dyn EventSink>,
    ) -> Result<StreamHandle, UsbError> {
        lock(self).start_stream(spec, sink)
    }
    fn service(&mut self, timeout: Duration) -> Result<Serviced, UsbError> {
        lock(self).service(timeout)
    }
    fn stop_stream(&mut self, h: StreamHandle, max_wait: Duration) -> Result<(), UsbError> {
        lock(self).stop_stream(h, max_wait)
    }
}

fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}
