//! A simulated Kinect v2 behind [`UsbBackend`] (protocol §14.1): enforces the protocol, answers
//! every command from a [`SimProfile`], streams depth frames built with the forward model from a
//! caller-supplied [`SimScene`] and colour packets from caller-supplied JPEGs, and injects
//! seeded faults.
//!
//! Size (~950 lines, one file): the simulated device is one state machine whose command
//! handlers, stream generator, replay source and fault injection all read and change the same
//! private state; split into modules, that state would have to become crate-visible. It is
//! compiled only with the `sim` feature. The calibration scene it can show (a checkerboard in
//! tilted poses, labs L1–L3) is [`calib_scene`]; several sensors in a ring around it are
//! [`ring`].

pub mod calib_scene;
pub mod depth_error;
pub mod ring;

use std::collections::VecDeque;
use std::time::Duration;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::backend::{
    ResetOutcome, StopReason, StreamEvent, StreamHandle, StreamSpec, UsbBackend, XferStatus,
};
use crate::decoder::DecoderParams;
use crate::error::UsbError;
use crate::forward::forward_frame;
use crate::params::{ColorParams, DepthParams, P0Tables, XzTables};
use crate::protocol::{
    self, ANALOG_GAIN_RANGE, COLOR_SETTING_ID, COLOR_SETTING_RESPONSE_LEN, ColorSettingCode,
    ColorSettingResponse, CommandMessage, EXPOSURE_COMPENSATION_RANGE, ExposureMode, LedSetting,
    MAX_EXPOSURE_MS, SET_MODE_ID, ep,
};
use crate::raw::PIXELS;
use crate::stream::{ColorMeta, build_color_packet, packetize_depth_frame};

/// Timestamp increment per frame (0.125 ms units, 30 Hz).
const TICKS_PER_FRAME: u32 = 267;

/// Status the simulated device puts in a 0x3E response (or an LED completion) when a value is
/// out of range. The real status codes are not documented (protocol §4.10); the sim's convention:
/// 0 = accepted, [`SIM_STATUS_INVALID_VALUE`], [`SIM_STATUS_UNKNOWN_CODE`],
/// [`SIM_STATUS_BAD_REQUEST`].
pub const SIM_STATUS_INVALID_VALUE: u32 = 1;
/// Status for a setting code the protocol document does not list.
pub const SIM_STATUS_UNKNOWN_CODE: u32 = 2;
/// Status for a malformed 0x3E request (setting count ≠ 1 or setting sequence id ≠ 0).
pub const SIM_STATUS_BAD_REQUEST: u32 = 3;
/// Exposure time (ms) the simulated auto-exposure settles on at compensation 0; the colour
/// footer reports `AUTO_EXPOSURE_MS × 2^compensation` in auto mode.
pub const SIM_AUTO_EXPOSURE_MS: f32 = 10.0;

/// The simulated colour camera's settings registers (protocol §4.10), keyed by SET code.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SimColorSettings {
    regs: std::collections::BTreeMap<u32, u32>,
}

impl Default for SimColorSettings {
    /// Power-on values: auto exposure, compensation 0, 10 ms, gains 1.
    fn default() -> Self {
        use ColorSettingCode::*;
        let mut regs = std::collections::BTreeMap::new();
        regs.insert(SetExposureMode.code(), ExposureMode::Auto.value());
        for (c, v) in [
            (SetIntegrationTime, SIM_AUTO_EXPOSURE_MS),
            (SetExposureTime, SIM_AUTO_EXPOSURE_MS),
            (SetAnalogGain, 1.0),
            (SetDigitalGain, 1.0),
            (SetRedGain, 1.0),
            (SetGreenGain, 1.0),
            (SetBlueGain, 1.0),
            (SetExposureCompensation, 0.0),
        ] {
            regs.insert(c.code(), v.to_bits());
        }
        SimColorSettings { regs }
    }
}

impl SimColorSettings {
    /// Stored value word of a SET code (a GET code reads its SET code's value).
    pub fn get(&self, code: ColorSettingCode) -> u32 {
        let set = code.set_of_get().unwrap_or(code);
        self.regs.get(&set.code()).copied().unwrap_or(0)
    }

    /// Stored value of an f32 setting.
    pub fn get_f32(&self, code: ColorSettingCode) -> f32 {
        f32::from_bits(self.get(code))
    }

    /// Current exposure mode.
    pub fn exposure_mode(&self) -> ExposureMode {
        ExposureMode::from_value(self.get(ColorSettingCode::SetExposureMode))
    }

    /// `(exposure ms, gain)` the colour footer reports for these settings.
    pub fn footer_exposure_gain(&self) -> (f32, f32) {
        use ColorSettingCode::*;
        match self.exposure_mode() {
            ExposureMode::Manual => (self.get_f32(SetIntegrationTime), self.get_f32(SetAnalogGain)),
            ExposureMode::SemiAuto => (self.get_f32(SetExposureTime), 1.0),
            _ => (SIM_AUTO_EXPOSURE_MS * self.get_f32(SetExposureCompensation).exp2(), 1.0),
        }
    }

    /// Applies one 0x3E request `[count, setting seq id, code, value]`, validating it as the
    /// sensor is assumed to: returns the response.
    fn apply(&mut self, params: &[u32]) -> ColorSettingResponse {
        let reply = |status: u32, data: u32| ColorSettingResponse {
            num_status: 1,
            command_list_status: 0,
            status,
            data,
        };
        let [count, sub_seq, code, value] = match params {
            &[a, b, c, d] => [a, b, c, d],
            _ => return reply(SIM_STATUS_BAD_REQUEST, 0),
        };
        if count != 1 || sub_seq != 0 {
            return reply(SIM_STATUS_BAD_REQUEST, 0);
        }
        let Some(c) = ColorSettingCode::from_code(code) else {
            return reply(SIM_STATUS_UNKNOWN_CODE, 0);
        };
        if c.is_get() {
            return reply(0, self.get(c));
        }
        use ColorSettingCode::*;
        let f = f32::from_bits(value);
        let in_range = |lo: f32, lo_incl: bool, hi: f32| {
            f.is_finite() && (if lo_incl { f >= lo } else { f > lo }) && f <= hi
        };
        let ok = match c {
            SetExposureMode => matches!(
                ExposureMode::from_value(value),
                ExposureMode::Auto | ExposureMode::SemiAuto | ExposureMode::Manual
            ),
            SetIntegrationTime | SetExposureTime => in_range(0.0, false, MAX_EXPOSURE_MS),
            SetAnalogGain => in_range(*ANALOG_GAIN_RANGE.start(), true, *ANALOG_GAIN_RANGE.end()),
            SetExposureCompensation => in_range(
                *EXPOSURE_COMPENSATION_RANGE.start(),
                true,
                *EXPOSURE_COMPENSATION_RANGE.end(),
            ),
            SetRedGain | SetGreenGain | SetBlueGain | SetDigitalGain => {
                in_range(0.0, false, protocol::MAX_CHANNEL_GAIN)
            }
            _ => true,
        };
        if !ok {
            return reply(SIM_STATUS_INVALID_VALUE, 0);
        }
        self.regs.insert(code, value);
        reply(0, 0)
    }
}

/// What the simulated device answers to commands.
#[derive(Debug, Clone)]
pub struct SimProfile {
    /// Firmware records (record 3 is shown to users).
    pub firmware: [(u16, u16, u32, u32); 7],
    /// 92 bytes of hardware info.
    pub hardware_info: Vec<u8>,
    /// Serial number.
    pub serial: String,
    /// Depth intrinsics.
    pub depth_params: DepthParams,
    /// P0 tables.
    pub p0: P0Tables,
    /// Colour parameters.
    pub color_params: ColorParams,
    /// Status words returned by successive polls (the last one repeats).
    pub status_words: Vec<u32>,
    /// `wBytesPerInterval` of endpoint 0x84.
    pub bytes_per_interval: u32,
}

impl SimProfile {
    /// A profile from the vectors' inputs (real factory intrinsics, synthetic P0 and colour
    /// parameters) with a real-looking firmware version and status sequence.
    pub fn from_vectors(dir: &std::path::Path) -> crate::Result<Self> {
        let read_bytes = |path: &std::path::Path| {
            std::fs::read(path)
                .map_err(|source| crate::KinectError::File { path: path.to_path_buf(), source })
        };
        let hw = read_bytes(&dir.join("real/protocol/hardware_info_response.bin"))?;
        Ok(SimProfile {
            firmware: [
                (1, 0, 0, 0),
                (2, 0, 0, 0),
                (3, 0, 0, 0),
                (4, 0, 3912, 0),
                (0, 0, 0, 0),
                (0, 0, 0, 0),
                (0, 0, 0, 0),
            ],
            hardware_info: hw,
            serial: "016293740947".into(),
            depth_params: DepthParams::from_response(&read_bytes(
                &dir.join("inputs/depth_camera_params_response.bin"),
            )?)?,
            p0: P0Tables::from_response(&read_bytes(&dir.join("inputs/p0_tables_response.bin"))?)?,
            color_params: ColorParams::from_response(&read_bytes(
                &dir.join("inputs/rgb_camera_params_response.bin"),
            )?)?,
            status_words: vec![1024, 9729, 9731],
            bytes_per_interval: protocol::MIN_BYTES_PER_INTERVAL,
        })
    }

    /// A self-contained profile for given depth intrinsics: smooth synthetic P0 tables and
    /// pinhole-like colour parameters (colour focal length `color_f`, principal point at the
    /// image centre, the real devices' `shift_d = 863`, `shift_m = 52`).
    pub fn synthetic(depth: DepthParams, color_f: f32) -> Self {
        let base = [11_418.0f64, 2_284.0, 17_128.0];
        let tables = std::array::from_fn(|k| {
            (0..PIXELS)
                .map(|i| {
                    let (x, y) = ((i % 512) as f64 / 511.0 - 0.5, (i / 512) as f64 / 423.0 - 0.5);
                    (base[k] + 900.0 * x - 600.0 * y + 1200.0 * (x * x + y * y)).round() as u16
                })
                .collect()
        });
        // Polynomial coefficients of a pinhole mapping (protocol §11.1 inverted for x, y linear).
        const QD: f32 = 0.01;
        const QC: f32 = 0.002199;
        let (shift_d, shift_m) = (863.0f32, 52.0f32);
        let mut mx = [0f32; 10];
        let mut my = [0f32; 10];
        mx[7] = color_f * QC / (QD * depth.fx);
        mx[9] = shift_m / shift_d * color_f * QC;
        my[8] = color_f * QC / (QD * depth.fy);
        SimProfile {
            firmware: [
                (1, 0, 0, 0),
                (2, 0, 0, 0),
                (3, 0, 0, 0),
                (4, 0, 3912, 0),
                (0, 0, 0, 0),
                (0, 0, 0, 0),
                (0, 0, 0, 0),
            ],
            hardware_info: vec![0u8; 92],
            serial: "000000000001".into(),
            depth_params: depth,
            p0: P0Tables { tables },
            color_params: ColorParams {
                f: color_f,
                cx: 959.5,
                cy: 539.5,
                shift_d,
                shift_m,
                mx,
                my,
            },
            status_words: vec![1024, 9729, 9731],
            bytes_per_interval: protocol::MIN_BYTES_PER_INTERVAL,
        }
    }

    fn firmware_bytes(&self) -> Vec<u8> {
        let mut v = vec![0u8; 0x200];
        for (i, &(maj, min, rev, build)) in self.firmware.iter().enumerate() {
            let r = &mut v[16 * i..16 * i + 16];
            r[0..4].copy_from_slice(&(((maj as u32) << 16) | min as u32).to_le_bytes());
            r[4..8].copy_from_slice(&rev.to_le_bytes());
            r[8..12].copy_from_slice(&build.to_le_bytes());
        }
        v
    }
}

/// What the simulated sensor sees. Frames cycle.
#[derive(Debug, Clone, Default)]
pub struct SimScene {
    /// Depth frames: (depth in mm, IR amplitude), each 512 × 424 upright.
    pub depth_frames: Vec<(Vec<f32>, Vec<f32>)>,
    /// Colour frames as JPEG bitstreams (any bytes starting FF D8 and ending FF D9).
    pub color_jpegs: Vec<Vec<u8>>,
}

/// Seeded fault injection.
#[derive(Debug, Clone, Default)]
pub struct SimFaults {
    /// Seed of every random decision.
    pub seed: u64,
    /// Claiming an interface fails with Busy.
    pub busy: bool,
    /// Command id whose OUT transfer stalls (once).
    pub stall_command: Option<u32>,
    /// Command id whose response read times out (once).
    pub timeout_command: Option<u32>,
    /// Command id answered with a premature completion (once).
    pub premature_completion: Option<u32>,
    /// Completions echo a wrong sequence number.
    pub wrong_completion_sequence: bool,
    /// Status never reports ready.
    pub status_never_ready: bool,
    /// Fraction of iso packets lost (error status, no data).
    pub iso_drop_rate: f64,
    /// Fraction of iso packets delivered short (truncated data).
    pub iso_short_rate: f64,
    /// Fraction of colour transfers that stall (error status).
    pub bulk_error_rate: f64,
    /// The device disappears after this many frame periods.
    pub unplug_after_frames: Option<u64>,
    /// Command id whose data phase is cut to half its length (once).
    pub short_response: Option<u32>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Data,
    Completion,
}

/// The simulated device.
pub struct SimDevice {
    profile: SimProfile,
    scene: SimScene,
    /// Faults to inject.
    pub faults: SimFaults,
    rng: ChaCha8Rng,
    /// Every operation, in order (for asserting exact start/stop/close sequences).
    pub transcript: Vec<String>,
    /// Protocol rules the host broke (must stay empty).
    pub violations: Vec<String>,
    config: u8,
    claimed: [bool; 2],
    alt1: u8,
    suspended: bool,
    streaming_on: bool,
    status_ready_seen: bool,
    status_polls: usize,
    expected_seq: u32,
    pending: Option<(CommandMessage, Vec<u8>, Phase, u32)>,
    /// The last 0x4B at sequence 0 could have been either the first sequenced command or the
    /// LED API (protocol §3.3 ambiguity at the session's start): accept either numbering next.
    led_ambiguous: bool,
    color: SimColorSettings,
    leds: [Option<LedSetting>; 2],
    led_api: Vec<LedSetting>,
    halted_out: bool,
    gone: bool,
    iso: Option<(StreamHandle, usize)>,
    bulk: Option<(StreamHandle, usize)>,
    next_handle: u32,
    queue: VecDeque<(StreamHandle, StreamEvent)>,
    raw_frames: Vec<Vec<u8>>,
    /// Frame periods generated so far.
    pub frame_index: u64,
    /// Sequence number of the next depth frame (wraps at 2^16).
    pub depth_sequence: u32,
    timestamp: u32,
    replay: Option<Box<dyn crate::recording::ReplaySource>>,
    /// Why a replay stopped early (a corrupt record), taken by [`SimDevice::take_replay_error`].
    replay_error: Option<crate::KinectError>,
}

/// Recorded events queued per simulated frame period during replay: about one depth frame's
/// worth of isochronous packets (9 per sub-packet × 10 plus empty ones) or more, while the
/// queue stays bounded by this many records (each ≤ `recording::MAX_RECORD`) whatever the
/// recording's size.
const REPLAY_EVENTS_PER_PERIOD: usize = 128;

impl SimDevice {
    /// A device that answers commands from a recording's metadata and streams its recorded
    /// events (the replay path: identical code from the backend up). The streams end with
    /// `Stopped { Requested }` when the recording is exhausted.
    pub fn replay(rec: crate::recording::Recording) -> crate::Result<Self> {
        Self::replay_from(&rec.meta, Box::new(rec.events.into_iter()))
    }

    /// [`SimDevice::replay`] streaming from `source` (e.g. a
    /// [`RecordingReader`](crate::recording::RecordingReader)): at most
    /// `REPLAY_EVENTS_PER_PERIOD` events are held at a time. A read error ends the streams with
    /// `Stopped { Stalled }` and is kept for [`SimDevice::take_replay_error`].
    pub fn replay_from(
        m: &crate::recording::RecordingMeta,
        source: Box<dyn crate::recording::ReplaySource>,
    ) -> crate::Result<Self> {
        let mut fw = [(0u16, 0u16, 0u32, 0u32); 7];
        let parts: Vec<u32> = m.firmware.split('.').filter_map(|p| p.parse().ok()).collect();
        if parts.len() >= 4 {
            fw[3] = (parts[0] as u16, parts[1] as u16, parts[2], parts[3]);
        }
        let mut hw = m.hardware_info.clone();
        hw.resize(92, 0);
        let profile = SimProfile {
            firmware: fw,
            hardware_info: hw,
            serial: m.serial.clone(),
            depth_params: DepthParams::from_response(&m.depth_params)?,
            p0: P0Tables::from_response(&m.p0)?,
            color_params: ColorParams::from_response(&m.color_params)?,
            status_words: vec![1],
            bytes_per_interval: protocol::MIN_BYTES_PER_INTERVAL,
        };
        let mut d = SimDevice::new(profile, SimScene::default(), SimFaults::default());
        d.replay = Some(source);
        Ok(d)
    }

    /// The error that ended a replay early, if any (taken: a second call returns `None`).
    pub fn take_replay_error(&mut self) -> Option<crate::KinectError> {
        self.replay_error.take()
    }

    /// What the replay source skipped or found cut so far.
    pub fn replay_report(&self) -> crate::recording::ReadReport {
        self.replay.as_ref().map(|r| r.report()).unwrap_or_default()
    }

    /// Events waiting in the device's queue (what a replay holds in memory besides the reader).
    pub fn queued_events(&self) -> usize {
        self.queue.len()
    }

    /// A device with the given profile, scene and faults.
    pub fn new(profile: SimProfile, scene: SimScene, faults: SimFaults) -> Self {
        let rng = ChaCha8Rng::seed_from_u64(faults.seed);
        SimDevice {
            profile,
            scene,
            faults,
            rng,
            transcript: Vec::new(),
            violations: Vec::new(),
            config: 0,
            claimed: [false; 2],
            alt1: 0,
            suspended: false,
            streaming_on: false,
            status_ready_seen: false,
            status_polls: 0,
            expected_seq: 0,
            pending: None,
            led_ambiguous: false,
            color: SimColorSettings::default(),
            leds: [None; 2],
            led_api: Vec::new(),
            halted_out: false,
            gone: false,
            iso: None,
            bulk: None,
            next_handle: 1,
            queue: VecDeque::new(),
            raw_frames: Vec::new(),
            frame_index: 0,
            depth_sequence: 0,
            timestamp: 1000,
            replay: None,
            replay_error: None,
        }
    }

    /// The raw depth frames the device streams (forward model of the scene), built on demand.
    pub fn raw_frames(&mut self) -> &[Vec<u8>] {
        if self.raw_frames.is_empty() {
            use rayon::prelude::*;
            let xz = XzTables::from_params(&self.profile.depth_params);
            let p = DecoderParams::default();
            // In parallel: the calibration scene's 17 frames were 15 % of its start-up, serial.
            self.raw_frames = self
                .scene
                .depth_frames
                .par_iter()
                .filter(|(d, i)| d.len() == PIXELS && i.len() == PIXELS)
                .map(|(d, i)| forward_frame(d, i, &xz, &self.profile.p0, &p))
                .collect();
            if !self.raw_frames.is_empty() {
                // Only the raw frames are streamed: the decoded images are not kept twice
                // (a ring of simulated sensors holds dozens of frames each).
                self.scene.depth_frames = Vec::new();
            }
        }
        &self.raw_frames
    }

    fn check(&mut self) -> Result<(), UsbError> {
        if self.gone { Err(UsbError::NoDevice) } else { Ok(()) }
    }

    fn respond(&mut self, m: &CommandMessage) -> Vec<u8> {
        let p = &self.profile;
        match (m.id, m.params.first().copied()) {
            (0x02, _) => p.firmware_bytes(),
            (0x14, _) => p.hardware_info.clone(),
            (0x22, Some(1)) => protocol::encode_serial(&p.serial),
            (0x22, Some(2)) => p.p0.to_response(),
            (0x22, Some(3)) => p.depth_params.to_response(),
            (0x22, Some(4)) => p.color_params.to_response(),
            (0x16, _) => {
                let w = if self.faults.status_never_ready {
                    0
                } else {
                    p.status_words
                        .get(self.status_polls)
                        .or(p.status_words.last())
                        .copied()
                        .unwrap_or(1)
                };
                self.status_polls += 1;
                if w & 1 == 1 {
                    self.status_ready_seen = true;
                }
                w.to_le_bytes().to_vec()
            }
            (COLOR_SETTING_ID, _) => self.color.apply(&m.params).to_bytes().to_vec(),
            _ => Vec::new(),
        }
    }

    /// Records an LED setting from 0x4B words; returns the completion status (non-zero when
    /// an LED API request is invalid). Start/stop "mode" words are recorded when they decode as
    /// LED settings (protocol §4.9) and never rejected.
    fn apply_led(&mut self, params: &[u32], api: bool) -> u32 {
        let words = match params {
            &[a, b, c, d] => [a, b, c, d],
            _ => return SIM_STATUS_BAD_REQUEST,
        };
        match LedSetting::from_words(words) {
            Ok(l) => {
                self.leds[l.id as usize & 1] = Some(l);
                if api {
                    self.led_api.push(l);
                }
                0
            }
            Err(_) if api => SIM_STATUS_INVALID_VALUE,
            Err(_) => 0,
        }
    }

    /// The colour camera's settings as the device holds them.
    pub fn color_settings(&self) -> &SimColorSettings {
        &self.color
    }

    /// Current state of LED `id` (from LED API and start/stop mode commands alike); `None`
    /// before any 0x4B addressed it.
    pub fn led(&self, id: u16) -> Option<LedSetting> {
        self.leds.get(id as usize).copied().flatten()
    }

    /// Every accepted LED API request (sequence 0), in order.
    pub fn led_api_log(&self) -> &[LedSetting] {
        &self.led_api
    }

    fn generate_frame_period(&mut self) {
        if let Some(it) = self.replay.as_mut() {
            use crate::device::StreamKind;
            let (iso, bulk) = (self.iso.map(|s| s.0), self.bulk.map(|s| s.0));
            let mut end = None;
            for _ in 0..REPLAY_EVENTS_PER_PERIOD {
                match it.next_event() {
                    Ok(Some(e)) => {
                        let h = if e.kind == StreamKind::Depth { iso } else { bulk };
                        if let Some(h) = h {
                            self.queue.push_back((h, e.into_event()));
                        }
                    }
                    Ok(None) => {
                        end = Some(StopReason::Requested);
                        break;
                    }
                    Err(e) => {
                        self.replay_error = Some(e);
                        end = Some(StopReason::Stalled);
                        break;
                    }
                }
            }
            if let Some(reason) = end {
                for h in [iso, bulk].into_iter().flatten() {
                    self.queue.push_back((h, StreamEvent::Stopped { reason }));
                }
            }
            return;
        }
        if let Some(n) = self.faults.unplug_after_frames
            && self.frame_index >= n
        {
            self.gone = true;
            for h in [self.iso.map(|s| s.0), self.bulk.map(|s| s.0)].into_iter().flatten() {
                self.queue
                    .push_back((h, StreamEvent::Stopped { reason: StopReason::Disconnected }));
            }
            return;
        }
        let mut depth_events = Vec::new();
        let iso_ok = self.alt1 == 1 && self.streaming_on && !self.suspended;
        if let Some((h, psize)) = self.iso
            && iso_ok
        {
            let nframes = self.raw_frames().len();
            if nframes > 0 {
                let idx = (self.frame_index % nframes as u64) as usize;
                let mut gaps = [0usize; 10];
                for g in gaps.iter_mut() {
                    *g = self.rng.random_range(1..=3);
                }
                let packets = packetize_depth_frame(
                    &self.raw_frames[idx],
                    self.depth_sequence,
                    self.timestamp,
                    psize,
                    gaps,
                );
                for mut pk in packets {
                    let r: f64 = self.rng.random();
                    let status = if r < self.faults.iso_drop_rate {
                        pk.clear();
                        XferStatus::Error
                    } else {
                        if r < self.faults.iso_drop_rate + self.faults.iso_short_rate
                            && pk.len() > 1
                        {
                            let keep = self.rng.random_range(0..pk.len());
                            pk.truncate(keep);
                        }
                        XferStatus::Completed
                    };
                    depth_events.push((h, StreamEvent::IsoPacket { status, data: pk }));
                }
            }
        }
        let mut color_events = Vec::new();
        if let Some((h, size)) = self.bulk
            && !self.scene.color_jpegs.is_empty()
        {
            let idx = (self.frame_index % self.scene.color_jpegs.len() as u64) as usize;
            let jpeg = &self.scene.color_jpegs[idx];
            let pad = (4 - jpeg.len() % 4) % 4;
            let filler = 4 * self.rng.random_range(0..64usize);
            let (exposure, gain) = self.color.footer_exposure_gain();
            let meta = ColorMeta {
                sequence: self.frame_index as u32,
                timestamp: self.timestamp,
                exposure,
                gain,
                gamma: 1.0,
            };
            let packet = build_color_packet(jpeg, &meta, pad, filler);
            for chunk in packet.chunks(size.max(1)) {
                let r: f64 = self.rng.random();
                let status = if r < self.faults.bulk_error_rate {
                    XferStatus::Error
                } else {
                    XferStatus::Completed
                };
                color_events.push((
                    h,
                    StreamEvent::Bulk {
                        status,
                        data: if status == XferStatus::Completed {
                            chunk.to_vec()
                        } else {
                            Vec::new()
                        },
                    },
                ));
            }
        }
        // Interleave the two streams over the frame period.
        let (nd, nc) = (depth_events.len(), color_events.len());
        let mut di = depth_events.into_iter();
        let mut ci = color_events.into_iter();
        let total = nd + nc;
        let (mut sent_d, mut sent_c) = (0usize, 0usize);
        for _ in 0..total {
            // Keep both streams proportionally advanced.
            let take_depth = nc == 0 || (nd > 0 && sent_d * nc <= sent_c * nd);
            if take_depth && let Some(e) = di.next() {
                self.queue.push_back(e);
                sent_d += 1;
                continue;
            }
            if let Some(e) = ci.next() {
                self.queue.push_back(e);
                sent_c += 1;
            } else if let Some(e) = di.next() {
                self.queue.push_back(e);
                sent_d += 1;
            }
        }
        self.frame_index += 1;
        self.depth_sequence = (self.depth_sequence + 1) % (1 << 16);
        self.timestamp = self.timestamp.wrapping_add(TICKS_PER_FRAME);
    }

    /// Sets the timestamp of the next frame period, 0.125 ms units (each sensor of a simulated
    /// ring has its own clock, as real Kinects do).
    pub fn set_timestamp(&mut self, ticks: u32) {
        self.timestamp = ticks;
    }

    /// Sets the next depth sequence number (to test wrap-around).
    pub fn set_depth_sequence(&mut self, s: u32) {
        self.depth_sequence = s % (1 << 16);
    }
}

impl UsbBackend for SimDevice {
    fn active_config(&mut self) -> Result<u8, UsbError> {
        self.check()?;
        Ok(self.config)
    }

    fn set_config(&mut self, cfg: u8) -> Result<(), UsbError> {
        self.check()?;
        self.transcript.push(format!("set_config {cfg}"));
        self.config = cfg;
        Ok(())
    }

    fn reset(&mut self) -> Result<ResetOutcome, UsbError> {
        self.check()?;
        self.transcript.push("reset".into());
        Ok(ResetOutcome::Ok)
    }

    fn claim(&mut self, iface: u8) -> Result<(), UsbError> {
        self.check()?;
        if self.faults.busy {
            return Err(UsbError::Busy);
        }
        self.transcript.push(format!("claim {iface}"));
        self.claimed[iface as usize & 1] = true;
        Ok(())
    }

    fn release(&mut self, iface: u8) -> Result<(), UsbError> {
        self.check()?;
        self.transcript.push(format!("release {iface}"));
        self.claimed[iface as usize & 1] = false;
        Ok(())
    }

    fn set_alt(&mut self, iface: u8, alt: u8) -> Result<(), UsbError> {
        self.check()?;
        self.transcript.push(format!("set_alt {iface} {alt}"));
        if iface == 1 {
            self.alt1 = alt;
        }
        Ok(())
    }

    fn control_out(
        &mut self,
        req_type: u8,
        req: u8,
        value: u16,
        index: u16,
        _data: &[u8],
        _t: Duration,
    ) -> Result<usize, UsbError> {
        self.check()?;
        self.transcript.push(format!("control {req_type:02x} {req:02x} {value} {index:#x}"));
        if req_type == 0x01 && req == 0x03 {
            self.suspended = (index >> 8) & 1 == 1;
        }
        Ok(0)
    }

    fn bulk_out(&mut self, ep_: u8, data: &[u8], _t: Duration) -> Result<usize, UsbError> {
        self.check()?;
        if ep_ != ep::COMMAND_OUT {
            return Err(UsbError::NotSupported);
        }
        if self.halted_out {
            return Err(UsbError::Stall);
        }
        if !self.claimed[0] {
            self.violations.push("command before claiming interface 0".into());
        }
        let m = match protocol::parse_command(data) {
            Ok(m) => m,
            Err(e) => {
                self.violations.push(e.to_string());
                self.halted_out = true;
                return Err(UsbError::Stall);
            }
        };
        self.transcript.push(format!("cmd {:#04x} seq {} {:?}", m.id, m.sequence, m.params));
        if self.faults.stall_command == Some(m.id) {
            self.faults.stall_command = None;
            self.halted_out = true;
            return Err(UsbError::Stall);
        }
        let mut completion_status = 0;
        match m.id {
            COLOR_SETTING_ID => {
                // Colour settings always carry sequence 0 and do not advance it (protocol §3.3).
                if m.sequence != 0 {
                    self.violations.push(format!(
                        "colour setting (0x3E) with sequence {}, must be 0",
                        m.sequence
                    ));
                }
                if m.max_response_len != COLOR_SETTING_RESPONSE_LEN as u32 {
                    self.violations.push(format!(
                        "colour setting (0x3E) max_response_len {}, must be 16",
                        m.max_response_len
                    ));
                }
            }
            SET_MODE_ID
                if m.sequence != self.expected_seq
                    && !(self.led_ambiguous && m.sequence == self.expected_seq.wrapping_add(1)) =>
            {
                // Out of the counter: the LED API (sequence 0, protocol §4.9).
                if m.sequence != 0 {
                    self.violations.push(format!(
                        "command 0x4b: sequence {} expected {} (or 0 for the LED API)",
                        m.sequence, self.expected_seq
                    ));
                }
                completion_status = self.apply_led(&m.params, true);
            }
            _ => {
                let ok = m.sequence == self.expected_seq
                    || (self.led_ambiguous && m.sequence == self.expected_seq.wrapping_add(1));
                if !ok {
                    self.violations.push(format!(
                        "command {:#x}: sequence {} expected {}",
                        m.id, m.sequence, self.expected_seq
                    ));
                }
                // A 0x4B at sequence 0 when the counter is also at 0: LED API or first command?
                let ambiguous = m.id == SET_MODE_ID && m.sequence == 0 && self.expected_seq == 0;
                if ambiguous {
                    self.led_ambiguous = true;
                    completion_status = self.apply_led(&m.params, true);
                } else {
                    self.led_ambiguous = false;
                    self.expected_seq = m.sequence.wrapping_add(1);
                    if m.id == SET_MODE_ID {
                        self.apply_led(&m.params, false);
                    }
                }
            }
        }
        if m.id == 0x09 && !self.status_ready_seen && !self.faults.status_never_ready {
            self.violations.push("InitStreams before the status poll reported ready".into());
        }
        if m.id == 0x2B {
            self.streaming_on = m.params.first() == Some(&1);
        }
        let resp = self.respond(&m);
        let phase = if m.max_response_len > 0 { Phase::Data } else { Phase::Completion };
        self.pending = Some((m, resp, phase, completion_status));
        Ok(data.len())
    }

    fn bulk_in(&mut self, ep_: u8, buf: &mut [u8], _t: Duration) -> Result<usize, UsbError> {
        self.check()?;
        if ep_ != ep::COMMAND_IN {
            return Err(UsbError::NotSupported);
        }
        let Some((m, mut resp, phase, cstatus)) = self.pending.take() else {
            return Err(UsbError::Timeout);
        };
        if self.faults.timeout_command == Some(m.id) {
            self.faults.timeout_command = None;
            return Err(UsbError::Timeout);
        }
        let seq = if self.faults.wrong_completion_sequence {
            m.sequence.wrapping_add(7)
        } else {
            m.sequence
        };
        match phase {
            Phase::Data if self.faults.premature_completion == Some(m.id) => {
                self.faults.premature_completion = None;
                let c = protocol::encode_completion(seq);
                let n = c.len().min(buf.len());
                buf[..n].copy_from_slice(&c[..n]);
                Ok(n)
            }
            Phase::Data => {
                if self.faults.short_response == Some(m.id) {
                    self.faults.short_response = None;
                    resp.truncate(resp.len() / 2);
                }
                if buf.len() > m.max_response_len as usize {
                    self.violations.push(format!(
                        "read of {} bytes exceeds max_response_len {}",
                        buf.len(),
                        m.max_response_len
                    ));
                }
                let n = resp.len().min(buf.len());
                buf[..n].copy_from_slice(&resp[..n]);
                self.pending = Some((m, Vec::new(), Phase::Completion, cstatus));
                Ok(n)
            }
            Phase::Completion => {
                let c = protocol::encode_completion_with_status(seq, cstatus);
                let n = c.len().min(buf.len());
                buf[..n].copy_from_slice(&c[..n]);
                Ok(n)
            }
        }
    }

    fn clear_halt(&mut self, ep_: u8) -> Result<(), UsbError> {
        self.check()?;
        self.transcript.push(format!("clear_halt {ep_:#04x}"));
        if ep_ == ep::COMMAND_OUT {
            self.halted_out = false;
        }
        self.pending = None;
        Ok(())
    }

    fn iso_bytes_per_interval(&mut self, _ep: u8, _alt: u8) -> Result<u32, UsbError> {
        self.check()?;
        Ok(self.profile.bytes_per_interval)
    }

    fn start_stream(&mut self, spec: StreamSpec) -> Result<StreamHandle, UsbError> {
        self.check()?;
        let h = StreamHandle(self.next_handle);
        self.next_handle += 1;
        match spec {
            StreamSpec::Iso { packet_size, .. } => {
                if self.alt1 != 1 || !self.streaming_on || self.suspended {
                    self.violations.push("iso stream started before alt 1 + streaming on".into());
                }
                self.transcript.push("start_stream iso".into());
                // Build the forward-modelled frames now, not inside a frame wait.
                self.raw_frames();
                self.iso = Some((h, packet_size));
            }
            StreamSpec::Bulk { size, .. } => {
                self.transcript.push("start_stream bulk".into());
                self.bulk = Some((h, size));
            }
        }
        Ok(h)
    }

    fn next_event(
        &mut self,
        _timeout: Duration,
    ) -> Result<Option<(StreamHandle, StreamEvent)>, UsbError> {
        if self.queue.is_empty() {
            self.check()?;
            if self.iso.is_none() && self.bulk.is_none() {
                return Ok(None);
            }
            self.generate_frame_period();
        }
        Ok(self.queue.pop_front())
    }

    fn stop_stream(&mut self, h: StreamHandle, _max_wait: Duration) -> Result<(), UsbError> {
        self.transcript.push("stop_stream".into());
        if self.iso.map(|s| s.0) == Some(h) {
            self.iso = None;
        }
        if self.bulk.map(|s| s.0) == Some(h) {
            self.bulk = None;
        }
        self.queue.retain(|(hh, _)| *hh != h);
        self.check()
    }
}
