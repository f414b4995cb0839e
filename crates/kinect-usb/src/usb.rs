//! The libusb backend: enumeration, configuration, control and bulk through `rusb` (safe), the
//! two streams through [`crate::transfer`]. A `rusb::Context` is always created explicitly; its
//! failure (no `/dev/bus/usb`, e.g. in a container) means "no USB available".

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use rusb::UsbContext;

use crate::backend::{EventSink, ResetOutcome, Serviced, StreamHandle, StreamSpec, UsbBackend};
use crate::error::{KinectError, Result, UsbError};
use crate::protocol::{PRODUCT_IDS, VENDOR_ID};
use crate::transfer::TransferPool;

/// Open attempts right after enumeration (protocol §5.1).
const OPEN_ATTEMPTS: usize = 10;
/// Pause between open attempts.
const OPEN_RETRY: Duration = Duration::from_millis(100);
/// Event-thread poll interval (protocol §5.5).
const EVENT_POLL: Duration = Duration::from_millis(100);
/// Streaming transfer timeout.
const STREAM_TIMEOUT: Duration = Duration::from_millis(1000);
/// SuperSpeed endpoint companion descriptor type.
const SS_ENDPOINT_COMPANION: u8 = 0x30;

fn map_err(e: rusb::Error) -> UsbError {
    match e {
        rusb::Error::Timeout => UsbError::Timeout,
        rusb::Error::Pipe => UsbError::Stall,
        rusb::Error::Busy => UsbError::Busy,
        rusb::Error::NoDevice | rusb::Error::NotFound => UsbError::NoDevice,
        rusb::Error::Overflow => UsbError::Overflow,
        rusb::Error::Access => UsbError::Access,
        rusb::Error::NotSupported => UsbError::NotSupported,
        rusb::Error::NoMem => UsbError::NoMem,
        _ => UsbError::Io,
    }
}

/// A Kinect v2 seen on the bus.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceSummary {
    /// Bus number.
    pub bus: u8,
    /// Device address.
    pub address: u8,
    /// Product id (0x02D8 release, 0x02C4 preview).
    pub product_id: u16,
    /// Serial from the string descriptor; `None` if the device could not be opened (busy or
    /// no permission).
    pub serial: Option<String>,
}

fn context() -> Result<rusb::Context> {
    rusb::Context::new().map_err(|e| KinectError::NoUsb(e.to_string()))
}

fn kinects(ctx: &rusb::Context) -> Result<Vec<(rusb::Device<rusb::Context>, u16)>> {
    let list = ctx.devices().map_err(|e| KinectError::usb("listing USB devices", map_err(e)))?;
    Ok(list
        .iter()
        .filter_map(|d| {
            let desc = d.device_descriptor().ok()?;
            (desc.vendor_id() == VENDOR_ID && PRODUCT_IDS.contains(&desc.product_id()))
                .then_some((d, desc.product_id()))
        })
        .collect())
}

/// Lists connected Kinect v2 sensors (protocol §1 enumeration recipe).
pub fn list_devices() -> Result<Vec<DeviceSummary>> {
    let ctx = context()?;
    Ok(kinects(&ctx)?
        .into_iter()
        .map(|(d, pid)| {
            let serial = d.open().ok().and_then(|h| {
                let desc = d.device_descriptor().ok()?;
                h.read_serial_number_string_ascii(&desc).ok()
            });
            DeviceSummary { bus: d.bus_number(), address: d.address(), product_id: pid, serial }
        })
        .collect())
}

/// Opens the first Kinect v2 (retrying 10 × 100 ms while it is busy).
pub fn open_first() -> Result<RusbBackend> {
    let ctx = context()?;
    let (dev, _) = kinects(&ctx)?.into_iter().next().ok_or(KinectError::NotFound)?;
    open_device(ctx, dev)
}

/// Opens the Kinect v2 at `bus` / `address` ([`DeviceSummary`]'s), retrying as
/// [`open_first`]: one of several sensors (two may even report the same serial).
pub fn open_at(bus: u8, address: u8) -> Result<RusbBackend> {
    let ctx = context()?;
    let (dev, _) = kinects(&ctx)?
        .into_iter()
        .find(|(d, _)| d.bus_number() == bus && d.address() == address)
        .ok_or(KinectError::NotFound)?;
    open_device(ctx, dev)
}

fn open_device(ctx: rusb::Context, dev: rusb::Device<rusb::Context>) -> Result<RusbBackend> {
    let mut last = UsbError::Io;
    for _ in 0..OPEN_ATTEMPTS {
        match dev.open() {
            Ok(handle) => return Ok(RusbBackend::new(ctx, dev, handle)),
            Err(e) => last = map_err(e),
        }
        std::thread::sleep(OPEN_RETRY);
    }
    Err(KinectError::usb("opening the Kinect v2", last))
}

fn serial_of(
    dev: &rusb::Device<rusb::Context>,
    handle: &rusb::DeviceHandle<rusb::Context>,
) -> Option<String> {
    let desc = dev.device_descriptor().ok()?;
    handle.read_serial_number_string_ascii(&desc).ok()
}

/// Where a sensor is plugged in (bus and hub port path): unlike the address, it survives a
/// re-enumeration. Used to find a sensor again when its serial could not be read.
fn port_path(dev: &rusb::Device<rusb::Context>) -> (u8, Vec<u8>) {
    (dev.bus_number(), dev.port_numbers().unwrap_or_default())
}

/// [`UsbBackend`] over libusb.
pub struct RusbBackend {
    ctx: rusb::Context,
    device: rusb::Device<rusb::Context>,
    /// `None` between closing a re-enumerated handle and reopening the sensor.
    handle: Option<rusb::DeviceHandle<rusb::Context>>,
    /// The sensor's serial, read at open, to find it again after a re-enumeration.
    serial: Option<String>,
    pools: HashMap<StreamHandle, TransferPool>,
    next_handle: u32,
    events: Option<(Arc<AtomicBool>, JoinHandle<()>)>,
}

impl RusbBackend {
    fn new(
        ctx: rusb::Context,
        device: rusb::Device<rusb::Context>,
        handle: rusb::DeviceHandle<rusb::Context>,
    ) -> Self {
        let serial = serial_of(&device, &handle);
        RusbBackend {
            ctx,
            device,
            handle: Some(handle),
            serial,
            pools: HashMap::new(),
            next_handle: 1,
            events: None,
        }
    }

    fn h(&mut self) -> std::result::Result<&mut rusb::DeviceHandle<rusb::Context>, UsbError> {
        self.handle.as_mut().ok_or(UsbError::NoDevice)
    }

    /// The same sensor on the bus now: same serial, or same port path when the serial was
    /// unreadable. Candidates that cannot be opened (busy, still enumerating) are skipped.
    fn find_again(
        &self,
        port: &(u8, Vec<u8>),
    ) -> Option<(rusb::Device<rusb::Context>, rusb::DeviceHandle<rusb::Context>)> {
        let list = kinects(&self.ctx).ok()?;
        list.into_iter().find_map(|(d, _)| {
            if self.serial.is_none() && port_path(&d) != *port {
                return None;
            }
            let h = d.open().ok()?;
            match &self.serial {
                Some(s) if serial_of(&d, &h).as_deref() != Some(s.as_str()) => None,
                _ => Some((d, h)),
            }
        })
    }

    fn ensure_event_thread(&mut self) {
        if self.events.is_some() {
            return;
        }
        let run = Arc::new(AtomicBool::new(true));
        let (r, ctx) = (run.clone(), self.ctx.clone());
        let th = std::thread::spawn(move || {
            while r.load(Ordering::SeqCst) {
                let _ = ctx.handle_events(Some(EVENT_POLL));
            }
        });
        self.events = Some((run, th));
    }
}

impl Drop for RusbBackend {
    fn drop(&mut self) {
        // Pools first (they need the event thread to collect cancellations), then the thread.
        self.pools.clear();
        if let Some((run, th)) = self.events.take() {
            run.store(false, Ordering::SeqCst);
            let _ = th.join();
        }
    }
}

impl UsbBackend for RusbBackend {
    fn active_config(&mut self) -> std::result::Result<u8, UsbError> {
        self.h()?.active_configuration().map_err(map_err)
    }
    fn set_config(&mut self, cfg: u8) -> std::result::Result<(), UsbError> {
        self.h()?.set_active_configuration(cfg).map_err(map_err)
    }
    fn reset(&mut self) -> std::result::Result<ResetOutcome, UsbError> {
        match self.h()?.reset() {
            Ok(()) => Ok(ResetOutcome::Ok),
            Err(rusb::Error::NotFound) => Ok(ResetOutcome::Reenumerated),
            Err(e) => Err(map_err(e)),
        }
    }
    fn reopen(&mut self, wait: Duration) -> std::result::Result<(), UsbError> {
        let port = port_path(&self.device);
        self.pools.clear();
        self.handle = None; // closes the dead handle
        std::thread::sleep(wait);
        for _ in 0..OPEN_ATTEMPTS {
            if let Some((d, h)) = self.find_again(&port) {
                self.device = d;
                self.handle = Some(h);
                return Ok(());
            }
            std::thread::sleep(OPEN_RETRY);
        }
        Err(UsbError::NoDevice)
    }
    fn claim(&mut self, iface: u8) -> std::result::Result<(), UsbError> {
        self.h()?.claim_interface(iface).map_err(map_err)
    }
    fn release(&mut self, iface: u8) -> std::result::Result<(), UsbError> {
        self.h()?.release_interface(iface).map_err(map_err)
    }
    fn set_alt(&mut self, iface: u8, alt: u8) -> std::result::Result<(), UsbError> {
        self.h()?.set_alternate_setting(iface, alt).map_err(map_err)
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
        self.h()?.write_control(req_type, req, value, index, data, timeout).map_err(map_err)
    }
    fn bulk_out(
        &mut self,
        ep: u8,
        data: &[u8],
        timeout: Duration,
    ) -> std::result::Result<usize, UsbError> {
        self.h()?.write_bulk(ep, data, timeout).map_err(map_err)
    }
    fn bulk_in(
        &mut self,
        ep: u8,
        buf: &mut [u8],
        timeout: Duration,
    ) -> std::result::Result<usize, UsbError> {
        self.h()?.read_bulk(ep, buf, timeout).map_err(map_err)
    }
    fn clear_halt(&mut self, ep: u8) -> std::result::Result<(), UsbError> {
        self.h()?.clear_halt(ep).map_err(map_err)
    }
    fn iso_bytes_per_interval(&mut self, ep: u8, alt: u8) -> std::result::Result<u32, UsbError> {
        let cfg = self.device.config_descriptor(0).map_err(map_err)?;
        for iface in cfg.interfaces() {
            for d in iface.descriptors().filter(|d| d.setting_number() == alt) {
                for e in d.endpoint_descriptors().filter(|e| e.address() == ep) {
                    let extra = e.extra().unwrap_or(&[]);
                    let mut i = 0;
                    while i + 1 < extra.len() {
                        let len = extra[i] as usize;
                        if len == 0 {
                            break;
                        }
                        if extra[i + 1] == SS_ENDPOINT_COMPANION && len >= 6 && i + 6 <= extra.len()
                        {
                            return Ok(u16::from_le_bytes([extra[i + 4], extra[i + 5]]) as u32);
                        }
                        i += len;
                    }
                }
            }
        }
        Err(UsbError::NotSupported)
    }
    fn start_stream(
        &mut self,
        spec: StreamSpec,
        sink: Arc<dyn EventSink>,
    ) -> std::result::Result<StreamHandle, UsbError> {
        let raw = self.h()?.as_raw();
        self.ensure_event_thread();
        let h = StreamHandle(self.next_handle);
        self.next_handle += 1;
        let pool = match spec {
            StreamSpec::Iso { ep, transfers, packets, packet_size } => TransferPool::start(
                raw,
                ep,
                transfers,
                packets.max(1),
                packet_size,
                sink,
                STREAM_TIMEOUT,
            )?,
            StreamSpec::Bulk { ep, transfers, size } => {
                TransferPool::start(raw, ep, transfers, 0, size, sink, STREAM_TIMEOUT)?
            }
        };
        self.pools.insert(h, pool);
        Ok(h)
    }
    fn service(&mut self, _timeout: Duration) -> std::result::Result<Serviced, UsbError> {
        // The event thread completes the transfers and assembles frames in the sink.
        Ok(Serviced::Background)
    }
    fn stop_stream(
        &mut self,
        h: StreamHandle,
        max_wait: Duration,
    ) -> std::result::Result<(), UsbError> {
        if let Some(mut pool) = self.pools.remove(&h) {
            let done = pool.stop(max_wait);
            drop(pool);
            if !done {
                return Err(UsbError::Timeout);
            }
        }
        Ok(())
    }
}
