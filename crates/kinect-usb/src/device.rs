//! The session state machine (protocol §5): open, start streaming, frames, stop, close — over any
//! [`UsbBackend`].
//!
//! Size (~670 lines): the session state machine of protocol §5 and the commands that are only
//! valid in its states (colour settings, LED); its steps share the device's private state.

use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::backend::{
    ResetOutcome, Serviced, StopReason, StreamEvent, StreamHandle, StreamSpec, UsbBackend,
};
use crate::error::{KinectError, Result, USBFS_MEMORY_FIX, UsbError};
use crate::latest::{FrameSink, TakenFrame};
use crate::params::{ColorParams, DepthParams, P0Tables};
use crate::protocol::{
    self, ColorSettingCode, ColorSettingResponse, Command, Exposure, ExposureMode, LedSetting,
    MIN_BYTES_PER_INTERVAL, MODE_OFF, MODE_ON, MODE_ON_100, STATUS_REGISTER, ValueKind, ep,
};
use crate::stream::{ColorMeta, RawDepthFrame};

/// Timeout of every control and command transfer (protocol §2.1, §3.2).
pub const COMMAND_TIMEOUT: Duration = Duration::from_millis(1000);
/// Status polls before giving up waiting for readiness (protocol §5.2 step 10).
pub const STATUS_POLLS: usize = 50;
/// Sleep between not-ready status polls.
pub const STATUS_POLL_INTERVAL: Duration = Duration::from_millis(100);
/// Bound on waiting for cancelled transfers at stop (the reference waits forever).
pub const STOP_WAIT: Duration = Duration::from_secs(2);
/// Colour transfers in flight × size (Linux default, protocol §5.5).
pub const COLOR_STREAM: StreamSpec =
    StreamSpec::Bulk { ep: ep::COLOR_IN, transfers: 20, size: 16_384 };
/// Depth transfers in flight (Linux default, protocol §5.5).
pub const DEPTH_TRANSFERS: usize = 60;
/// Isochronous packets per depth transfer (Linux default, protocol §5.5).
pub const DEPTH_PACKETS_PER_TRANSFER: usize = 8;
/// Largest `wBytesPerInterval` accepted from endpoint 0x84's companion descriptor: a
/// SuperSpeed isochronous endpoint moves at most (Mult + 1 ≤ 3) × (bMaxBurst + 1 ≤ 16) packets
/// of 1024 bytes per service interval (USB 3.2 specification, section 9.6.7), so anything
/// larger is a corrupt descriptor, not bandwidth. Real sensors report 33 792 (protocol §2.2).
pub const MAX_BYTES_PER_INTERVAL: u32 = 3 * 16 * 1024;

/// The depth stream: [`DEPTH_TRANSFERS`] × [`DEPTH_PACKETS_PER_TRANSFER`] packets of
/// `packet_size` bytes, the endpoint's `wBytesPerInterval` (as libfreenect2 sizes them,
/// protocol §5.5).
pub fn depth_stream(packet_size: usize) -> StreamSpec {
    StreamSpec::Iso {
        ep: ep::DEPTH_IN,
        transfers: DEPTH_TRANSFERS,
        packets: DEPTH_PACKETS_PER_TRANSFER,
        packet_size,
    }
}

/// Wait between closing a handle whose port reset re-enumerated the sensor and looking for it
/// again: libfreenect2's value (`libfreenect2.cpp:1219-1249`, a workaround for host controllers
/// that re-enumerate on reset), enough for the host to enumerate the device anew.
pub const REENUMERATION_WAIT: Duration = Duration::from_secs(1);

/// Options of [`KinectDevice::open_with`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OpenOptions {
    /// Wait after a re-enumerating reset before looking for the sensor again
    /// ([`REENUMERATION_WAIT`] by default; tests make it short).
    pub reenumeration_wait: Duration,
}

impl Default for OpenOptions {
    fn default() -> Self {
        OpenOptions { reenumeration_wait: REENUMERATION_WAIT }
    }
}

/// Session state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// Opened and configured, not streaming.
    Open,
    /// Streaming.
    Streaming,
    /// Closed.
    Closed,
}

/// Everything read from the device at start.
#[derive(Debug, Clone)]
pub struct DeviceInfo {
    /// Firmware version (record 3), e.g. `4.0.3912.0`.
    pub firmware: String,
    /// Serial number.
    pub serial: String,
    /// Raw 92-byte hardware info.
    pub hardware_info: Vec<u8>,
    /// Depth camera intrinsics.
    pub depth_params: DepthParams,
    /// P0 tables.
    pub p0: P0Tables,
    /// Colour camera parameters.
    pub color_params: ColorParams,
    /// The raw responses (depth params, P0, colour params), kept for recordings.
    pub raw_depth_params: Vec<u8>,
    /// Raw P0 response.
    pub raw_p0: Vec<u8>,
    /// Raw colour parameter response.
    pub raw_color_params: Vec<u8>,
}

/// Which stream an event belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StreamKind {
    /// Depth (isochronous).
    Depth,
    /// Colour (bulk).
    Color,
}

/// A frame produced by [`KinectDevice::next_frame`], borrowing the device's buffers.
#[derive(Debug)]
pub enum Frame<'a> {
    /// A complete raw depth frame.
    Depth(RawDepthFrame<'a>),
    /// A colour JPEG and its metadata.
    Color(&'a [u8], ColorMeta),
}

/// Stream counters reported to users.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StreamCounters {
    /// Complete depth frames.
    pub depth_frames: u64,
    /// Depth frames lost (sequence gaps).
    pub depth_dropped: u64,
    /// Depth frames started but incomplete.
    pub depth_incomplete: u64,
    /// Iso packets with an error status.
    pub iso_errors: u64,
    /// Colour frames.
    pub color_frames: u64,
    /// Colour packets dropped.
    pub color_dropped: u64,
    /// Colour frames whose header magic was not 'BBBB' (kept unless
    /// [`KinectDevice::strict_checks`]; libfreenect2 does not check it).
    pub color_bad_header_magic: u64,
    /// 0x3E colour-setting responses with a non-zero status word (accepted unless
    /// [`KinectDevice::strict_checks`]; libfreenect2 ignores it).
    pub color_setting_nonzero_status: u64,
    /// LED API completions with a non-zero status word (accepted unless
    /// [`KinectDevice::strict_checks`]; libfreenect2 ignores it).
    pub led_nonzero_status: u64,
    /// Transfers retired because their submission or resubmission failed (the stream goes on
    /// with the others, as libfreenect2's; it ends when none is left).
    pub transfers_retired: u64,
    /// Depth frames assembled but replaced by a newer one before the application took them
    /// (it read slower than the sensor's 30 Hz; libfreenect2's "packets were lost"). With
    /// the frame still waiting, `depth_frames = depth_taken + depth_overwritten (+ 1)`.
    pub depth_overwritten: u64,
    /// Colour frames replaced before the application took them.
    pub color_overwritten: u64,
    /// Depth frames the application took ([`KinectDevice::next_frame`]).
    pub depth_taken: u64,
    /// Colour frames the application took.
    pub color_taken: u64,
    /// Raw events a recorder did not get because it fell behind by more than
    /// [`crate::latest::TAP_QUEUE_BYTES`].
    pub tap_dropped: u64,
}

/// An opened Kinect v2 session over a backend.
pub struct KinectDevice<B: UsbBackend> {
    backend: B,
    seq: u32,
    state: State,
    info: Option<DeviceInfo>,
    /// Frame assembly on the completion side and the newest-wins slots.
    sink: Arc<FrameSink>,
    /// The frame last handed out (borrowed by [`Frame`] until the next call).
    held: Option<TakenFrame>,
    depth_h: Option<StreamHandle>,
    color_h: Option<StreamHandle>,
    depth_packet_size: usize,
    color_setting_nonzero_status: u64,
    led_nonzero_status: u64,
    transfers_retired: u64,
    /// Non-fatal protocol warnings (sequence mismatches, status never ready…).
    pub warnings: Vec<String>,
    /// Treat a completion sequence mismatch as an error.
    pub strict_sequence: bool,
    /// Enforce the three values the sensor is not known to promise and libfreenect2 ignores:
    /// a non-zero 0x3E status or LED completion status becomes [`KinectError::Rejected`], and
    /// a colour frame whose header magic is not 'BBBB' is dropped. Off by default: each is
    /// counted ([`StreamCounters`]) and, for the status words, noted in [`Self::warnings`].
    pub strict_checks: bool,
}

impl<B: UsbBackend> KinectDevice<B> {
    /// Opens the device (protocol §5.1 steps 2–9) on an already-opened backend handle, with
    /// the default [`OpenOptions`].
    pub fn open(backend: B) -> Result<Self> {
        Self::open_with(backend, OpenOptions::default())
    }

    /// Opens the device (protocol §5.1 steps 2–9). When the port reset re-enumerates the
    /// sensor, the handle is closed and the same sensor (serial) is opened again after
    /// `options.reenumeration_wait`, once and without another reset, as libfreenect2 does;
    /// [`KinectError::NotBackAfterReset`] when it does not come back.
    pub fn open_with(mut backend: B, options: OpenOptions) -> Result<Self> {
        let b = &mut backend;
        match b.reset().map_err(|e| KinectError::usb("port reset", e))? {
            ResetOutcome::Ok => {}
            ResetOutcome::Reenumerated => {
                let wait = options.reenumeration_wait;
                b.reopen(wait).map_err(|e| match e {
                    UsbError::NoDevice => {
                        KinectError::NotBackAfterReset { waited_ms: wait.as_millis() as u64 }
                    }
                    e => KinectError::usb("reopening after a re-enumerating reset", e),
                })?;
            }
        }
        if b.active_config().map_err(|e| KinectError::usb("reading configuration", e))? != 1 {
            b.set_config(1).map_err(|e| KinectError::usb("set configuration 1", e))?;
        }
        for iface in [0, 1] {
            b.claim(iface).map_err(|e| KinectError::usb(format!("claim interface {iface}"), e))?;
        }
        let t = COMMAND_TIMEOUT;
        b.control_out(0x00, 0x31, 40, 0, &[], t)
            .map_err(|e| KinectError::usb("SET_ISOCH_DELAY", e))?;
        b.set_alt(1, 0).map_err(|e| KinectError::usb("interface 1 alt 0", e))?;
        b.control_out(0x00, 0x03, 48, 0, &[], t).map_err(|e| KinectError::usb("U1_ENABLE", e))?;
        b.control_out(0x00, 0x03, 49, 0, &[], t).map_err(|e| KinectError::usb("U2_ENABLE", e))?;
        b.control_out(0x01, 0x03, 0, 3 << 8, &[], t)
            .map_err(|e| KinectError::usb("function suspend", e))?;
        let bpi = b
            .iso_bytes_per_interval(ep::DEPTH_IN, 1)
            .map_err(|e| KinectError::usb("reading endpoint 0x84 descriptor", e))?;
        if bpi < MIN_BYTES_PER_INTERVAL {
            let _ = b.release(0);
            let _ = b.release(1);
            return Err(KinectError::InsufficientBandwidth {
                got: bpi,
                need: MIN_BYTES_PER_INTERVAL,
            });
        }
        if bpi > MAX_BYTES_PER_INTERVAL {
            let _ = b.release(0);
            let _ = b.release(1);
            return Err(KinectError::Protocol {
                what: "endpoint 0x84 descriptor".into(),
                detail: format!(
                    "wBytesPerInterval {bpi} is more than a SuperSpeed isochronous endpoint can \
                     move ({MAX_BYTES_PER_INTERVAL} = 3 × 16 × 1024 bytes): corrupt descriptor; \
                     replug the sensor or try another USB 3 port"
                ),
            });
        }
        Ok(KinectDevice {
            backend,
            seq: 0,
            state: State::Open,
            info: None,
            sink: Arc::new(FrameSink::new()),
            held: None,
            depth_h: None,
            color_h: None,
            depth_packet_size: bpi as usize,
            color_setting_nonzero_status: 0,
            led_nonzero_status: 0,
            transfers_retired: 0,
            warnings: Vec::new(),
            strict_sequence: false,
            strict_checks: false,
        })
    }

    /// Bytes per depth isochronous packet: the `wBytesPerInterval` read at open (bounded by
    /// [`MIN_BYTES_PER_INTERVAL`] and [`MAX_BYTES_PER_INTERVAL`]).
    pub fn depth_packet_size(&self) -> usize {
        self.depth_packet_size
    }

    /// Current state.
    pub fn state(&self) -> State {
        self.state
    }

    /// Device information (available after [`Self::start`]).
    pub fn info(&self) -> Option<&DeviceInfo> {
        self.info.as_ref()
    }

    /// The backend (e.g. to inspect a simulated device's transcript).
    pub fn backend(&self) -> &B {
        &self.backend
    }

    /// Sequence number the next sequenced command will carry (protocol §3.3). Colour settings and
    /// LED commands neither use nor advance it.
    pub fn sequence(&self) -> u32 {
        self.seq
    }

    /// Sends one command and returns its data phase (protocol §3.2).
    pub fn command(&mut self, cmd: Command) -> Result<Vec<u8>> {
        self.transact(cmd).map(|(data, _)| data)
    }

    /// One transaction; returns the data phase and the completion's status word.
    /// Colour settings and the LED API go out with sequence 0 and leave the counter alone
    /// (protocol §3.3); every other command takes the counter and post-increments it.
    fn transact(&mut self, cmd: Command) -> Result<(Vec<u8>, u32)> {
        let seq = if cmd.is_unsequenced() {
            0
        } else {
            let s = self.seq;
            self.seq = self.seq.wrapping_add(1);
            s
        };
        let name = cmd.name();
        let msg = cmd.encode(seq);
        let n = self
            .usb(ep::COMMAND_OUT, &name, |b| b.bulk_out(ep::COMMAND_OUT, &msg, COMMAND_TIMEOUT))?;
        if n != msg.len() {
            return Err(KinectError::Protocol {
                what: name,
                detail: format!("short write {n} of {}", msg.len()),
            });
        }
        let mut data = Vec::new();
        if cmd.max_response_len() > 0 {
            data = vec![0u8; cmd.max_response_len() as usize];
            let got = self.usb(ep::COMMAND_IN, &name, |b| {
                b.bulk_in(ep::COMMAND_IN, &mut data, COMMAND_TIMEOUT)
            })?;
            data.truncate(got);
            if protocol::is_completion(&data) {
                return Err(KinectError::Protocol {
                    what: name,
                    detail: "premature completion (device ended the command without data)".into(),
                });
            }
            if got < cmd.min_response_len() {
                return Err(KinectError::Protocol {
                    what: name,
                    detail: format!("short response: {got} bytes, need {}", cmd.min_response_len()),
                });
            }
        }
        let mut c = [0u8; 16];
        let got = self
            .usb(ep::COMMAND_IN, &name, |b| b.bulk_in(ep::COMMAND_IN, &mut c, COMMAND_TIMEOUT))?;
        let (cseq, status) = protocol::parse_completion_status(&c[..got], &name)?;
        if cseq != seq {
            let msg = format!("{name}: completion sequence {cseq}, expected {seq}");
            if self.strict_sequence {
                return Err(KinectError::Protocol { what: name, detail: msg });
            }
            self.warnings.push(msg);
        }
        Ok((data, status))
    }

    fn require_open(&self, op: &str) -> Result<()> {
        if self.state == State::Closed {
            return Err(KinectError::State { op: op.into(), state: format!("{:?}", self.state) });
        }
        Ok(())
    }

    /// Sends one 0x3E colour-camera setting (protocol §4.10) and returns its parsed response.
    /// A non-zero `status` in the response is counted
    /// ([`StreamCounters::color_setting_nonzero_status`]) and noted in [`Self::warnings`]; with
    /// [`Self::strict_checks`] it is returned as [`KinectError::Rejected`].
    /// Prefer the typed methods ([`Self::set_exposure`], [`Self::integration_time_ms`], …).
    pub fn color_setting(
        &mut self,
        code: ColorSettingCode,
        value: u32,
    ) -> Result<ColorSettingResponse> {
        self.require_open("colour setting")?;
        if let ColorSettingCode::SetMeteringZoneWeight(z) = code
            && z >= protocol::METERING_ZONES
        {
            return Err(KinectError::Invalid(format!(
                "metering zone {z} (zones are 0..{})",
                protocol::METERING_ZONES - 1
            )));
        }
        let cmd = Command::ColorSetting { code: code.code(), value };
        let name = cmd.name();
        let data = self.command(cmd)?;
        let r = protocol::parse_color_setting_response(&data)
            .map_err(|e| KinectError::Protocol { what: name.clone(), detail: e.to_string() })?;
        if r.status != 0 {
            self.color_setting_nonzero_status += 1;
            if self.strict_checks {
                return Err(KinectError::Rejected {
                    what: name,
                    status: r.status,
                    detail: format!("response {r:?}"),
                });
            }
            self.warnings.push(format!(
                "{name}: response status {:#x} (ignored, as libfreenect2 does; strict_checks \
                 rejects it)",
                r.status
            ));
        }
        Ok(r)
    }

    /// Sets an f32-valued colour setting (validated only for finiteness; use the typed
    /// setters for range checks).
    pub fn set_color_f32(&mut self, code: ColorSettingCode, v: f32) -> Result<()> {
        if code.is_get() || code.value_kind() != ValueKind::F32 || !v.is_finite() {
            return Err(KinectError::Invalid(format!("{code:?} takes no finite f32 value ({v})")));
        }
        self.color_setting(code, v.to_bits()).map(|_| ())
    }

    /// Sets a u32-valued colour setting.
    pub fn set_color_u32(&mut self, code: ColorSettingCode, v: u32) -> Result<()> {
        if code.is_get() || code.value_kind() != ValueKind::U32 {
            return Err(KinectError::Invalid(format!("{code:?} takes no u32 value")));
        }
        self.color_setting(code, v).map(|_| ())
    }

    /// Reads a GET code's value word.
    pub fn get_color_raw(&mut self, code: ColorSettingCode) -> Result<u32> {
        if !code.is_get() {
            return Err(KinectError::Invalid(format!("{code:?} is not a GET code")));
        }
        Ok(self.color_setting(code, 0)?.data)
    }

    fn get_color_f32(&mut self, code: ColorSettingCode) -> Result<f32> {
        let v = f32::from_bits(self.get_color_raw(code)?);
        if !v.is_finite() {
            return Err(KinectError::Protocol {
                what: format!("colour setting {code:?}"),
                detail: format!("device returned a non-finite value {v}"),
            });
        }
        Ok(v)
    }

    /// Applies an exposure preset (protocol §4.10), after validating its values. The commands are
    /// sent in the preset's order; the first failure stops and is returned.
    pub fn set_exposure(&mut self, e: Exposure) -> Result<()> {
        self.require_open("set exposure")?;
        for (code, value) in e.settings()? {
            self.color_setting(code, value)?;
        }
        Ok(())
    }

    /// Sets the white-balance mode (code 10). Protocol §4.10 does not document the values
    /// \[UNSURE\]; libfreenect2 clients use 1 = auto and 3 = manual.
    pub fn set_white_balance_mode(&mut self, mode: u32) -> Result<()> {
        self.set_color_u32(ColorSettingCode::SetWhiteBalanceMode, mode)
    }

    /// Sets the red, green and blue channel gains (codes 11–13), each `(0, MAX_CHANNEL_GAIN]`.
    pub fn set_rgb_gains(&mut self, red: f32, green: f32, blue: f32) -> Result<()> {
        for (w, g) in [("red gain", red), ("green gain", green), ("blue gain", blue)] {
            protocol::validate_channel_gain(w, g)?;
        }
        use ColorSettingCode::*;
        for (c, g) in [(SetRedGain, red), (SetGreenGain, green), (SetBlueGain, blue)] {
            self.set_color_f32(c, g)?;
        }
        Ok(())
    }

    /// Sets the digital gain (code 19), `(0, MAX_CHANNEL_GAIN]`.
    pub fn set_digital_gain(&mut self, g: f32) -> Result<()> {
        protocol::validate_channel_gain("digital gain", g)?;
        self.set_color_f32(ColorSettingCode::SetDigitalGain, g)
    }

    /// Current exposure mode (code 80).
    pub fn exposure_mode(&mut self) -> Result<ExposureMode> {
        Ok(ExposureMode::from_value(self.get_color_raw(ColorSettingCode::GetExposureMode)?))
    }

    /// Integration time in ms (code 2).
    pub fn integration_time_ms(&mut self) -> Result<f32> {
        self.get_color_f32(ColorSettingCode::GetIntegrationTime)
    }

    /// Analog gain (code 22).
    pub fn analog_gain(&mut self) -> Result<f32> {
        self.get_color_f32(ColorSettingCode::GetAnalogGain)
    }

    /// Semi-auto pseudo exposure time in ms (code 18).
    pub fn exposure_time_ms(&mut self) -> Result<f32> {
        self.get_color_f32(ColorSettingCode::GetExposureTime)
    }

    /// Exposure compensation in EV (code 24).
    pub fn exposure_compensation(&mut self) -> Result<f32> {
        self.get_color_f32(ColorSettingCode::GetExposureCompensation)
    }

    /// Digital gain (code 20).
    pub fn digital_gain(&mut self) -> Result<f32> {
        self.get_color_f32(ColorSettingCode::GetDigitalGain)
    }

    /// Red, green and blue channel gains (codes 14–16).
    pub fn rgb_gains(&mut self) -> Result<[f32; 3]> {
        use ColorSettingCode::*;
        Ok([
            self.get_color_f32(GetRedGain)?,
            self.get_color_f32(GetGreenGain)?,
            self.get_color_f32(GetBlueGain)?,
        ])
    }

    /// White-balance mode (code 81), raw value.
    pub fn white_balance_mode(&mut self) -> Result<u32> {
        self.get_color_raw(ColorSettingCode::GetWhiteBalanceMode)
    }

    /// Frame-rate setting (code 83), raw value (encoding not documented, protocol §4.10).
    pub fn frame_rate_raw(&mut self) -> Result<u32> {
        self.get_color_raw(ColorSettingCode::GetFrameRate)
    }

    /// Sets an LED (protocol §4.9) after validating the setting. Sent with sequence 0 without
    /// advancing the counter; a non-zero completion status is counted
    /// ([`StreamCounters::led_nonzero_status`]) and noted in [`Self::warnings`], or, with
    /// [`Self::strict_checks`], returned as [`KinectError::Rejected`].
    pub fn set_led(&mut self, led: LedSetting) -> Result<()> {
        self.require_open("set LED")?;
        led.validate()?;
        let cmd = Command::Led(led);
        let name = cmd.name();
        let (_, status) = self.transact(cmd)?;
        if status != 0 {
            self.led_nonzero_status += 1;
            if self.strict_checks {
                return Err(KinectError::Rejected {
                    what: name,
                    status,
                    detail: "completion status".into(),
                });
            }
            self.warnings.push(format!(
                "{name}: completion status {status:#x} (ignored, as libfreenect2 does; \
                 strict_checks rejects it)"
            ));
        }
        Ok(())
    }

    fn usb<T>(
        &mut self,
        endpoint: u8,
        what: &str,
        f: impl FnOnce(&mut B) -> std::result::Result<T, UsbError>,
    ) -> Result<T> {
        match f(&mut self.backend) {
            Ok(v) => Ok(v),
            Err(UsbError::Stall) => {
                // Clear the halt so the next command can proceed (protocol §3.2).
                let _ = self.backend.clear_halt(endpoint);
                Err(KinectError::usb(what, UsbError::Stall))
            }
            Err(e) => Err(KinectError::usb(what, e)),
        }
    }

    /// Starts streaming (protocol §5.2). On failure, rolls back best-effort and stays Open.
    pub fn start(&mut self, color: bool, depth: bool) -> Result<&DeviceInfo> {
        if self.state != State::Open {
            return Err(KinectError::State {
                op: "start".into(),
                state: format!("{:?}", self.state),
            });
        }
        match self.start_inner(color, depth) {
            Ok(()) => {
                self.state = State::Streaming;
                self.info.as_ref().ok_or_else(|| KinectError::Invalid("no device info".into()))
            }
            Err(e) => {
                self.state = State::Streaming;
                let _ = self.stop();
                Err(e)
            }
        }
    }

    fn start_inner(&mut self, color: bool, depth: bool) -> Result<()> {
        let t = COMMAND_TIMEOUT;
        self.usb(0, "function resume", |b| b.control_out(0x01, 0x03, 0, 0, &[], t))?;
        let fw = protocol::parse_firmware(&self.command(Command::ReadFirmwareVersions)?)?;
        let hardware_info = self.command(Command::ReadHardwareInfo)?;
        let serial = protocol::parse_serial(&self.command(Command::ReadDataPage(1))?);
        let raw_depth_params = self.command(Command::ReadDataPage(3))?;
        let depth_params = DepthParams::from_response(&raw_depth_params)?;
        let raw_p0 = self.command(Command::ReadDataPage(2))?;
        let p0 = P0Tables::from_response(&raw_p0)?;
        let raw_color_params = self.command(Command::ReadDataPage(4))?;
        let color_params = ColorParams::from_response(&raw_color_params)?;
        self.command(Command::SetMode(MODE_ON_100))?;
        self.command(Command::SetMode(MODE_OFF))?;
        let mut ready = false;
        for _ in 0..STATUS_POLLS {
            let s = protocol::parse_status(&self.command(Command::ReadStatus(STATUS_REGISTER))?)?;
            if s & 1 == 1 {
                ready = true;
                break;
            }
            std::thread::sleep(STATUS_POLL_INTERVAL);
        }
        if !ready {
            self.warnings.push(format!(
                "sensor never reported ready after {STATUS_POLLS} status polls; continuing"
            ));
        }
        self.command(Command::InitStreams)?;
        self.usb(0, "interface 1 alt 1", |b| b.set_alt(1, 1))?;
        self.command(Command::ReadStatus(STATUS_REGISTER))?;
        self.command(Command::SetStreaming(true))?;
        self.info = Some(DeviceInfo {
            firmware: protocol::user_firmware_version(&fw)
                .map(|v| v.to_string())
                .unwrap_or_else(|| "unknown".into()),
            serial,
            hardware_info,
            depth_params,
            p0,
            color_params,
            raw_depth_params,
            raw_p0,
            raw_color_params,
        });
        self.sink.set_strict_header(self.strict_checks);
        if color {
            let sink = self.sink.stream(StreamKind::Color);
            self.color_h = Some(self.usb(ep::COLOR_IN, "start colour stream", |b| {
                b.start_stream(COLOR_STREAM, sink)
            })?);
        }
        if depth {
            let spec = depth_stream(self.depth_packet_size);
            let sink = self.sink.stream(StreamKind::Depth);
            self.depth_h =
                Some(self.usb(ep::DEPTH_IN, "start depth stream", |b| b.start_stream(spec, sink))?);
        }
        Ok(())
    }

    /// Waits at most `timeout` for a frame not handed out yet: the earliest-arrived of the
    /// newest depth and the newest colour frame (each stream keeps only its newest, protocol
    /// §5.5: frames the application did not take in time are counted in
    /// [`StreamCounters::depth_overwritten`] / [`StreamCounters::color_overwritten`]). `tap`
    /// sees the raw stream events queued since the last call while [`Self::set_raw_tap`] is on
    /// (for recordings). Returns `Ok(None)` on timeout; `Err(Disconnected)` when the device
    /// went away.
    pub fn next_frame(
        &mut self,
        timeout: Duration,
        tap: &mut dyn FnMut(StreamKind, &StreamEvent),
    ) -> Result<Option<Frame<'_>>> {
        Ok(self.next_frame_at(timeout, tap)?.map(|(f, _)| f))
    }

    /// [`Self::next_frame`] with the host time at which the frame's last packet completed
    /// (to tell frames that arrived after a moment from older ones).
    pub fn next_frame_at(
        &mut self,
        timeout: Duration,
        tap: &mut dyn FnMut(StreamKind, &StreamEvent),
    ) -> Result<Option<(Frame<'_>, Instant)>> {
        if self.state != State::Streaming {
            return Err(KinectError::State {
                op: "next_frame".into(),
                state: format!("{:?}", self.state),
            });
        }
        if let Some(TakenFrame::Depth(d)) = self.held.take() {
            self.sink.recycle_depth(d.data);
        }
        self.sink.set_strict_header(self.strict_checks);
        let deadline = Instant::now() + timeout;
        loop {
            let taken = self.sink.take();
            for (kind, ev) in &taken.tap {
                tap(*kind, ev);
            }
            for (kind, ev) in taken.control {
                match ev {
                    StreamEvent::Retired { error, in_flight } => {
                        self.transfers_retired += 1;
                        let mut w = format!(
                            "{kind:?} stream: a transfer was retired ({error}); {in_flight} still \
                             in flight"
                        );
                        if error == UsbError::NoMem {
                            w.push_str(". ");
                            w.push_str(USBFS_MEMORY_FIX);
                        }
                        self.warnings.push(w);
                    }
                    StreamEvent::Stopped { reason: StopReason::Disconnected } => {
                        return Err(KinectError::Disconnected { what: "streaming".into() });
                    }
                    StreamEvent::Stopped { reason: StopReason::Requested } => {
                        return Err(KinectError::EndOfStream);
                    }
                    StreamEvent::Stopped { reason } => {
                        return Err(KinectError::Protocol {
                            what: format!("{kind:?} stream"),
                            detail: format!("stream stopped: {reason:?}"),
                        });
                    }
                    StreamEvent::IsoPacket { .. } | StreamEvent::Bulk { .. } => {}
                }
            }
            if let Some(f) = taken.frame {
                let at = f.arrived();
                self.held = Some(f);
                return Ok(self.held_frame().map(|f| (f, at)));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            match self.backend.service(left) {
                Ok(Serviced::Delivered) => {}
                Ok(Serviced::Idle) => {
                    if !self.sink.has_pending() {
                        return Ok(None);
                    }
                }
                Ok(Serviced::Background) => self.sink.wait(left),
                Err(UsbError::NoDevice) => {
                    return Err(KinectError::Disconnected { what: "streaming".into() });
                }
                Err(e) => return Err(KinectError::usb("streaming", e)),
            }
        }
    }

    fn held_frame(&self) -> Option<Frame<'_>> {
        Some(match self.held.as_ref()? {
            TakenFrame::Depth(d) => Frame::Depth(RawDepthFrame {
                sequence: d.sequence,
                timestamp: d.timestamp,
                data: &d.data,
            }),
            TakenFrame::Color(c) => Frame::Color(&c.jpeg, c.meta),
        })
    }

    /// Queues every raw stream event for [`Self::next_frame`]'s `tap` (a recorder) while on,
    /// at most [`crate::latest::TAP_QUEUE_BYTES`] between two calls; off by default, so that
    /// an application that reads slowly holds no packets.
    pub fn set_raw_tap(&mut self, on: bool) {
        self.sink.set_tap(on);
    }

    /// Bytes held for the application between the completion side and [`Self::next_frame`]:
    /// at most one depth frame and one colour JPEG in their slots, one recycled depth buffer,
    /// and the recorder's queue when [`Self::set_raw_tap`] is on. It does not grow with time.
    pub fn buffered_bytes(&self) -> usize {
        self.sink.buffered_bytes()
    }

    /// Stream counters so far.
    pub fn counters(&self) -> StreamCounters {
        let st = self.sink.stats();
        StreamCounters {
            depth_frames: st.depth.frames,
            depth_dropped: st.depth.skipped_frames,
            depth_incomplete: st.depth.incomplete_frames,
            iso_errors: st.iso_errors,
            color_frames: st.color.frames,
            color_dropped: st.color.dropped,
            color_bad_header_magic: st.color.bad_header_magic,
            color_setting_nonzero_status: self.color_setting_nonzero_status,
            led_nonzero_status: self.led_nonzero_status,
            transfers_retired: self.transfers_retired,
            depth_overwritten: st.depth_overwritten,
            color_overwritten: st.color_overwritten,
            depth_taken: st.depth_taken,
            color_taken: st.color_taken,
            tap_dropped: st.tap_dropped,
        }
    }

    /// Stops streaming (protocol §5.3), best effort: every step runs, errors are aggregated.
    pub fn stop(&mut self) -> Result<()> {
        if self.state != State::Streaming {
            return Ok(());
        }
        let mut errors = Vec::new();
        for h in [self.color_h.take(), self.depth_h.take()].into_iter().flatten() {
            if let Err(e) = self.backend.stop_stream(h, STOP_WAIT) {
                errors.push(format!("cancel stream: {e}"));
            }
        }
        if let Err(e) = self.backend.set_alt(1, 0) {
            errors.push(format!("interface 1 alt 0: {e}"));
        }
        let cmds = [
            Command::SetMode(MODE_ON_100),
            Command::SetMode(MODE_OFF),
            Command::Stop,
            Command::SetStreaming(false),
            Command::SetMode(MODE_ON),
            Command::SetMode(MODE_OFF),
            Command::SetMode(MODE_ON),
            Command::SetMode(MODE_OFF),
        ];
        for c in cmds {
            if let Err(e) = self.command(c) {
                errors.push(e.to_string());
                if matches!(e, KinectError::Disconnected { .. }) {
                    break;
                }
            }
        }
        if let Err(e) = self.backend.control_out(0x01, 0x03, 0, 3 << 8, &[], COMMAND_TIMEOUT) {
            errors.push(format!("function suspend: {e}"));
        }
        self.state = State::Open;
        if errors.is_empty() {
            Ok(())
        } else {
            Err(KinectError::Protocol { what: "stop".into(), detail: errors.join("; ") })
        }
    }

    /// Closes the session (protocol §5.4), best effort.
    pub fn close(&mut self) -> Result<()> {
        if self.state == State::Closed {
            return Ok(());
        }
        let r = self.stop();
        if !self.is_gone(&r) {
            let _ = self.command(Command::SetMode(MODE_ON_100));
            let _ = self.command(Command::SetMode(MODE_OFF));
        }
        let _ = self.backend.release(0);
        let _ = self.backend.release(1);
        self.state = State::Closed;
        r
    }

    fn is_gone(&self, r: &Result<()>) -> bool {
        matches!(r, Err(KinectError::Protocol { detail, .. }) if detail.contains("disappeared"))
    }
}

impl<B: UsbBackend> Drop for KinectDevice<B> {
    fn drop(&mut self) {
        let _ = self.close();
    }
}
