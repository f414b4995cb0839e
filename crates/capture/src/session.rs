//! Stage 2: an open, streaming sensor. [`Session::open`] opens and starts the device of a
//! [`SensorSource`]; the session applies the colour camera's and LED's settings, builds the
//! depth decoder for the device's calibration tables, hands out raw frames, and closes.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use kfuse_io::atomic::write_atomic;
use kinect_usb::backend::{StreamEvent, UsbBackend};
use kinect_usb::decoder::{DecoderConfig, DecoderParams, DecoderPrecision, DepthDecoder, Kernels};
use kinect_usb::device::{DeviceInfo, Frame, KinectDevice, StreamCounters, StreamKind};
use kinect_usb::params::XzTables;
use kinect_usb::protocol::{self, ExposureMode, LedMode, LedSetting};
use kinect_usb::recording::{ReadOptions, ReadReport, RecordingReader};
use kinect_usb::sim::SimDevice;
use kinect_usb::trace::{TraceHandle, TracingBackend};
use kinect_usb::{KinectError, usb};

use crate::CaptureError;
use crate::settings::{ColorSettings, exposure_text};
use crate::source::{SensorSource, sim_device};

/// The device type every source opens as.
pub type Device = KinectDevice<Box<dyn UsbBackend>>;
type SimHandle = Arc<Mutex<SimDevice>>;

/// How depth frames are decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DecoderOptions {
    /// Without the bilateral and edge-aware filters (raw per-pixel depth).
    pub no_filters: bool,
    /// `Exact`: bit-identical to libfreenect2's CPU decoder (~2× slower); `Fast`: within
    /// 0.01 mm of it.
    pub precision: DecoderPrecision,
}

impl Default for DecoderOptions {
    fn default() -> Self {
        Self { no_filters: false, precision: DecoderPrecision::Fast }
    }
}

/// What a replay skipped or kept, and the error that ended it early.
#[derive(Debug)]
pub struct ReplayOutcome {
    /// Records left out and whether a truncated prefix was used.
    pub report: ReadReport,
    /// The error that ended the replay before the recording's end (a corrupt record); a
    /// caller must fail on it.
    pub error: Option<KinectError>,
}

/// An open, started sensor. Dropping it closes the device (`KinectDevice`'s drop).
pub struct Session {
    dev: Device,
    sim: Option<SimHandle>,
    info: DeviceInfo,
    source: SensorSource,
}

fn no_sensor(e: KinectError) -> CaptureError {
    match e {
        KinectError::NoUsb(_) | KinectError::NotFound => CaptureError::NoSensor { cause: e },
        e => CaptureError::Device(e),
    }
}

/// The Kinect v2 sensors `source` offers, one line each (bus, address, product id, serial;
/// the simulator one line per simulated sensor, a recording none). Error:
/// [`CaptureError::NoSensor`] when there is none.
pub fn list_devices(source: &SensorSource) -> Result<Vec<String>, CaptureError> {
    Ok(crate::multi::connected(source)?.into_iter().map(|c| c.line).collect())
}

pub(crate) fn usb_sensors() -> Result<Vec<crate::multi::Connected>, CaptureError> {
    let list = usb::list_devices().map_err(no_sensor)?;
    if list.is_empty() {
        return Err(no_sensor(KinectError::NotFound));
    }
    Ok(list
        .iter()
        .map(|d| crate::multi::Connected {
            serial: d.serial.clone(),
            line: format!(
                "Kinect v2  bus {:03} address {:03}  pid {:04x}  serial {}",
                d.bus,
                d.address,
                d.product_id,
                d.serial.as_deref().unwrap_or("(unreadable: device busy or no permission)")
            ),
            source: SensorSource::UsbAt { bus: d.bus, address: d.address },
        })
        .collect())
}

pub(crate) fn no_sensor_error() -> CaptureError {
    no_sensor(KinectError::NotFound)
}

impl Session {
    /// Opens the sensor of `source` and starts its colour and depth streams.
    ///
    /// Errors: [`CaptureError::NoSensor`] without a Kinect, [`CaptureError::Busy`] when another
    /// program holds it, [`CaptureError::Config`] for a drop rate outside `[0, 1]`,
    /// [`CaptureError::Device`] for a recording that does not open or a failed start.
    pub fn open(source: &SensorSource) -> Result<Self, CaptureError> {
        Self::open_traced(source, None)
    }

    /// [`Session::open`] with every USB call and stream event of the session recorded in
    /// `trace` (`kfuse capture record --usb-trace`; the caller finishes the trace once the
    /// session is closed, or after a failed open: that trace is the one a bug report needs).
    pub fn open_traced(
        source: &SensorSource,
        trace: Option<&TraceHandle>,
    ) -> Result<Self, CaptureError> {
        let mut sim = None;
        let backend: Box<dyn UsbBackend> = match source {
            SensorSource::Replay(r) => {
                // Streamed: the reader holds one record at a time, whatever the file's size.
                let opts =
                    ReadOptions { keep_prefix: r.allow_truncated, skip_corrupt: r.skip_corrupt };
                let reader = RecordingReader::open(&r.path, opts)?;
                let meta = reader.meta().clone();
                let h = Arc::new(Mutex::new(SimDevice::replay_from(&meta, Box::new(reader))?));
                sim = Some(h.clone());
                Box::new(h)
            }
            SensorSource::Sim(o) => {
                if !(0.0..=1.0).contains(&o.iso_drop) {
                    return Err(CaptureError::Config(format!(
                        "iso packet drop rate {} is outside [0, 1]",
                        o.iso_drop
                    )));
                }
                let h = Arc::new(Mutex::new(sim_device(o)?));
                sim = Some(h.clone());
                Box::new(h)
            }
            SensorSource::Usb => Box::new(usb::open_first().map_err(no_sensor)?),
            SensorSource::UsbAt { bus, address } => {
                Box::new(usb::open_at(*bus, *address).map_err(no_sensor)?)
            }
            SensorSource::Absent => return Err(no_sensor(KinectError::NotFound)),
        };
        let backend: Box<dyn UsbBackend> = match trace {
            Some(t) => Box::new(TracingBackend::new(backend, t.clone())),
            None => backend,
        };
        let mut dev = KinectDevice::open(backend).map_err(|e| match e {
            KinectError::Busy => CaptureError::Busy(e),
            e => no_sensor(e),
        })?;
        let info = dev.start(true, true)?.clone();
        Ok(Self { dev, sim, info, source: source.clone() })
    }

    /// What the device reported when it started (serial, firmware, calibration tables).
    pub fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// The source this session streams from.
    pub fn source(&self) -> &SensorSource {
        &self.source
    }

    /// Applies `settings` and reads them back. Returns one line per setting saying what the
    /// sensor now uses (a read-back that fails is reported in its line as a warning, since the
    /// setting itself was accepted). Error: [`CaptureError::Setting`] when the sensor refuses.
    pub fn apply_settings(
        &mut self,
        settings: &ColorSettings,
    ) -> Result<Vec<String>, CaptureError> {
        let mut lines = Vec::new();
        if let Some(e) = settings.exposure {
            self.dev.set_exposure(e).map_err(|source| CaptureError::Setting {
                what: format!("--exposure {}", exposure_text(&e)),
                source,
            })?;
            lines.push(match self.read_exposure() {
                Ok(t) => format!("colour exposure: {t} (read back from the sensor)"),
                Err(err) => {
                    format!("warning: --exposure was applied but reading it back failed: {err}")
                }
            });
        }
        if let Some(l) = settings.led {
            self.dev.set_led(l).map_err(|source| CaptureError::Setting {
                what: format!("--led (LED {})", l.id),
                source,
            })?;
            let what = match l.mode {
                LedMode::Constant if l.start_level == 0 => "off".to_string(),
                LedMode::Constant => {
                    format!("on at level {}/{}", l.start_level, protocol::LED_MAX_LEVEL)
                }
                LedMode::Blink => format!("blinking every {} ms", l.interval_ms),
            };
            lines.push(format!("LED {}: {what}", l.id));
        }
        Ok(lines)
    }

    fn read_exposure(&mut self) -> kinect_usb::Result<String> {
        let d = &mut self.dev;
        Ok(match d.exposure_mode()? {
            ExposureMode::Manual => format!(
                "manual, integration time {} ms, analog gain {}",
                d.integration_time_ms()?,
                d.analog_gain()?
            ),
            ExposureMode::SemiAuto => {
                format!("semi-auto, exposure time {} ms", d.exposure_time_ms()?)
            }
            ExposureMode::Auto => format!("auto, compensation {}", d.exposure_compensation()?),
            ExposureMode::Other(v) => format!("mode {v}"),
        })
    }

    /// The depth decoder for this device's calibration tables.
    pub fn decoder(&self, options: &DecoderOptions) -> Result<DepthDecoder, CaptureError> {
        let xz = XzTables::from_params(&self.info.depth_params);
        let filters = !options.no_filters;
        let cfg = DecoderConfig {
            bilateral: filters,
            edge_aware: filters,
            parallel: true,
            ..DecoderConfig::default()
        };
        let dec = DepthDecoder::new(DecoderParams::default(), cfg, &xz, &self.info.p0)?;
        Ok(dec.with_precision(options.precision))
    }

    /// Waits for the next complete frame, at most `timeout` (`Ok(None)` on timeout); `tap`
    /// sees every raw stream event (for recordings).
    pub fn next_frame(
        &mut self,
        timeout: Duration,
        tap: &mut dyn FnMut(StreamKind, &StreamEvent),
    ) -> Result<Option<Frame<'_>>, CaptureError> {
        Ok(self.dev.next_frame(timeout, tap)?)
    }

    /// [`Session::next_frame`] with the host time at which the frame arrived (its last
    /// packet completed): each stream keeps only its newest frame, so a frame taken after a
    /// pause is at most one period old, and this tells whether it came after a moment.
    pub fn next_frame_at(
        &mut self,
        timeout: Duration,
        tap: &mut dyn FnMut(StreamKind, &StreamEvent),
    ) -> Result<Option<(Frame<'_>, Instant)>, CaptureError> {
        Ok(self.dev.next_frame_at(timeout, tap)?)
    }

    pub(crate) fn device_mut(&mut self) -> &mut Device {
        &mut self.dev
    }

    /// A simulated sensor produces `periods` frame periods (depth and colour) at once, through
    /// its transfer-completion path, with nobody reading (tests of idle consumers: what is
    /// held stays bounded, a fresh pair after it is current). Returns false, doing nothing,
    /// for a real sensor or a replay.
    pub fn advance_sim(&self, periods: u64) -> bool {
        match (&self.source, &self.sim) {
            (SensorSource::Sim(_), Some(sim)) => {
                sim.lock().unwrap_or_else(|p| p.into_inner()).advance(periods);
                true
            }
            _ => false,
        }
    }

    /// Bytes the device holds between its transfer-completion side and the next frame taken
    /// (bounded: one frame per stream, `KinectDevice::buffered_bytes`).
    pub fn buffered_bytes(&self) -> usize {
        self.dev.buffered_bytes()
    }

    /// Frames received, dropped and incomplete so far.
    pub fn counters(&self) -> StreamCounters {
        self.dev.counters()
    }

    /// Stops the streams and releases the device (errors while closing are ignored: the
    /// device may already be gone).
    pub fn close(&mut self) {
        let _ = self.dev.close();
    }

    /// After a replay: what was skipped or kept, and the error that ended it early. `None`
    /// for a live or simulated sensor.
    pub fn replay_outcome(&self) -> Option<ReplayOutcome> {
        let (SensorSource::Replay(_), Some(sim)) = (&self.source, &self.sim) else { return None };
        let mut s = sim.lock().unwrap_or_else(|p| p.into_inner());
        Some(ReplayOutcome { report: s.replay_report(), error: s.take_replay_error() })
    }

    /// Writes the simulated device's colour settings, LED commands and protocol violations as
    /// JSON to `path` (for tests of the settings path); does nothing for a real sensor.
    pub fn write_sim_report(&self, path: &Path) -> Result<(), CaptureError> {
        let Some(sim) = &self.sim else { return Ok(()) };
        let s = sim.lock().unwrap_or_else(|p| p.into_inner());
        use kinect_usb::protocol::ColorSettingCode as C;
        let c = s.color_settings();
        let led = |l: &LedSetting| {
            serde_json::json!({ "id": l.id, "blink": l.mode == LedMode::Blink, "start_level": l.start_level,
                                "stop_level": l.stop_level, "interval_ms": l.interval_ms })
        };
        let v = serde_json::json!({
            "exposure_mode": c.get(C::SetExposureMode),
            "integration_time_ms": c.get_f32(C::SetIntegrationTime),
            "analog_gain": c.get_f32(C::SetAnalogGain),
            "exposure_time_ms": c.get_f32(C::SetExposureTime),
            "exposure_compensation": c.get_f32(C::SetExposureCompensation),
            "led_api": s.led_api_log().iter().map(led).collect::<Vec<_>>(),
            "violations": s.violations,
            "commands": s.transcript.iter().filter(|l| l.starts_with("cmd")).collect::<Vec<_>>(),
        });
        write_atomic(path, |w| {
            serde_json::to_writer_pretty(&mut *w, &v)?;
            w.write_all(b"\n")
        })?;
        Ok(())
    }
}

/// One line naming the decoder in use (precision and this CPU's kernels).
pub fn decoder_summary(options: &DecoderOptions, decoder: &DepthDecoder) -> &'static str {
    match (options.precision, decoder.kernels()) {
        (DecoderPrecision::Exact, _) => "exact (bit-identical to libfreenect2's CPU decoder)",
        (DecoderPrecision::Fast, Kernels::Avx2) => "fast (eight-lane AVX2 kernels)",
        (DecoderPrecision::Fast, Kernels::Portable) => {
            "fast (four-lane kernels: this CPU has no AVX2)"
        }
    }
}
