//! Command messages, completions and response parsers (protocol §3–§4). Pure byte-level code.
//!
//! Size (~870 lines of code, ~160 of tests): every message and response layout of protocol
//! §3–§4 — commands, completions, firmware/serial/status parsers, the colour-setting codes and
//! presets, LED settings — each a few lines of byte handling that the sim and the device share;
//! kept together so that one file shows the whole wire format.

use crate::error::{KinectError, Result};

/// Command message magic.
pub const COMMAND_MAGIC: u32 = 0x0602_2009;
/// Completion magic.
pub const COMPLETION_MAGIC: u32 = 0x0A6F_E000;
/// Completion length.
pub const COMPLETION_LEN: usize = 16;
/// Status register polled for readiness.
pub const STATUS_REGISTER: u32 = 0x09_0000;
/// Minimum isochronous bytes per interval of endpoint 0x84 (protocol §2.2).
pub const MIN_BYTES_PER_INTERVAL: u32 = 0x8400;

/// Vendor id (Microsoft).
pub const VENDOR_ID: u16 = 0x045E;
/// Product ids opened by kfuse: release sensor and developer preview.
pub const PRODUCT_IDS: [u16; 2] = [0x02D8, 0x02C4];

/// Endpoints (protocol §2).
pub mod ep {
    /// Command OUT (bulk).
    pub const COMMAND_OUT: u8 = 0x02;
    /// Response IN (bulk).
    pub const COMMAND_IN: u8 = 0x81;
    /// Colour stream IN (bulk).
    pub const COLOR_IN: u8 = 0x83;
    /// Depth stream IN (isochronous).
    pub const DEPTH_IN: u8 = 0x84;
}

/// Command ids and parameters (protocol §4.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// 0x02.
    ReadFirmwareVersions,
    /// 0x14.
    ReadHardwareInfo,
    /// 0x22 with page 1 (serial), 2 (P0), 3 (depth params), 4 (colour params).
    ReadDataPage(u32),
    /// 0x16 with a register.
    ReadStatus(u32),
    /// 0x09.
    InitStreams,
    /// 0x2B.
    SetStreaming(bool),
    /// 0x4B with four parameter words.
    SetMode([u32; 4]),
    /// 0x0A.
    Stop,
    /// 0x3E: one colour-camera setting (§4.10). Parameters `[1, 0, code, value]`; sent with
    /// sequence 0 without advancing the counter (protocol §3.3); 16-byte response.
    ColorSetting {
        /// Setting code ([`ColorSettingCode::code`]).
        code: u32,
        /// Value: a u32, or the bit pattern of an f32 (see [`ColorSettingCode::value_kind`]).
        value: u32,
    },
    /// 0x4B used as the public LED API (protocol §4.9): sequence 0, counter not advanced. Build it
    /// from a validated [`LedSetting`].
    Led(LedSetting),
}

/// ModeOff parameters.
pub const MODE_OFF: [u32; 4] = [0, 0, 0, 0];
/// ModeOn parameters.
pub const MODE_ON: [u32; 4] = [1, 0, 0, 0];
/// ModeOn100 parameters.
pub const MODE_ON_100: [u32; 4] = [1, 0x0064_0064, 0, 0];

impl Command {
    /// Command id.
    pub fn id(&self) -> u32 {
        match self {
            Command::ReadFirmwareVersions => 0x02,
            Command::ReadHardwareInfo => 0x14,
            Command::ReadDataPage(_) => 0x22,
            Command::ReadStatus(_) => 0x16,
            Command::InitStreams => 0x09,
            Command::SetStreaming(_) => 0x2B,
            Command::SetMode(_) => 0x4B,
            Command::Stop => 0x0A,
            Command::ColorSetting { .. } => COLOR_SETTING_ID,
            Command::Led(_) => SET_MODE_ID,
        }
    }

    /// Parameter words.
    pub fn params(&self) -> Vec<u32> {
        match *self {
            Command::ReadDataPage(p) => vec![p],
            Command::ReadStatus(r) => vec![r],
            Command::SetStreaming(on) => vec![on as u32],
            Command::SetMode(w) => w.to_vec(),
            Command::ColorSetting { code, value } => vec![1, 0, code, value],
            Command::Led(l) => l.words().to_vec(),
            _ => vec![],
        }
    }

    /// `max_response_len` of the data phase (0 = none).
    pub fn max_response_len(&self) -> u32 {
        match self {
            Command::ReadFirmwareVersions => 0x200,
            Command::ReadHardwareInfo => 0x5C,
            Command::ReadDataPage(1) => 0x80,
            Command::ReadDataPage(_) => 0x1C_0000,
            Command::ReadStatus(_) => 4,
            Command::ColorSetting { .. } => COLOR_SETTING_RESPONSE_LEN as u32,
            _ => 0,
        }
    }

    /// True for the commands sent with sequence 0 that do not advance the per-device counter
    /// (colour settings and the LED API, protocol §3.3).
    pub fn is_unsequenced(&self) -> bool {
        matches!(self, Command::ColorSetting { .. } | Command::Led(_))
    }

    /// Minimum accepted response length.
    pub fn min_response_len(&self) -> usize {
        match self {
            Command::ReadFirmwareVersions => 0x200,
            Command::ReadHardwareInfo => 92,
            Command::ReadDataPage(1) => 0x80,
            Command::ReadDataPage(2) => 1_302_572,
            Command::ReadDataPage(3) => 92,
            Command::ReadDataPage(4) => 12_981,
            Command::ReadDataPage(_) => 0,
            Command::ReadStatus(_) => 4,
            Command::ColorSetting { .. } => COLOR_SETTING_RESPONSE_LEN,
            _ => 0,
        }
    }

    /// Human-readable name for errors.
    pub fn name(&self) -> String {
        match *self {
            Command::ColorSetting { code, value } => match ColorSettingCode::from_code(code) {
                Some(c) if c.is_get() => format!("colour setting {c:?} (0x3E code {code})"),
                Some(c) => format!(
                    "colour setting {c:?} = {} (0x3E code {code})",
                    c.value_kind().show(value)
                ),
                None => format!("colour setting code {code} = {value:#x} (0x3E)"),
            },
            _ => format!("{self:?} (0x{:02X})", self.id()),
        }
    }

    /// A 0x3E command setting `code` to the f32 `v` (bit pattern).
    pub fn set_f32(code: ColorSettingCode, v: f32) -> Self {
        Command::ColorSetting { code: code.code(), value: v.to_bits() }
    }

    /// A 0x3E command setting `code` to the u32 `v`.
    pub fn set_u32(code: ColorSettingCode, v: u32) -> Self {
        Command::ColorSetting { code: code.code(), value: v }
    }

    /// A 0x3E GET command (value word 0).
    pub fn get(code: ColorSettingCode) -> Self {
        Command::ColorSetting { code: code.code(), value: 0 }
    }

    /// Encodes the command message with sequence `seq`.
    pub fn encode(&self, seq: u32) -> Vec<u8> {
        let mut m = Vec::with_capacity(36);
        for w in [COMMAND_MAGIC, seq, self.max_response_len(), self.id(), 0] {
            m.extend_from_slice(&w.to_le_bytes());
        }
        for w in self.params() {
            m.extend_from_slice(&w.to_le_bytes());
        }
        m
    }
}

fn u32_at(b: &[u8], off: usize) -> u32 {
    u32::from_le_bytes([b[off], b[off + 1], b[off + 2], b[off + 3]])
}

/// A decoded command message (as the device sees it).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandMessage {
    /// Sequence number.
    pub sequence: u32,
    /// Max response length.
    pub max_response_len: u32,
    /// Command id.
    pub id: u32,
    /// Parameter words.
    pub params: Vec<u32>,
}

/// Parses a command message (20, 24 or 36 bytes).
pub fn parse_command(b: &[u8]) -> Result<CommandMessage> {
    if !matches!(b.len(), 20 | 24 | 36) {
        return Err(KinectError::Protocol {
            what: "command".into(),
            detail: format!("length {} not 20, 24 or 36", b.len()),
        });
    }
    if u32_at(b, 0) != COMMAND_MAGIC {
        return Err(KinectError::Protocol {
            what: "command".into(),
            detail: format!("bad magic 0x{:08X}", u32_at(b, 0)),
        });
    }
    Ok(CommandMessage {
        sequence: u32_at(b, 4),
        max_response_len: u32_at(b, 8),
        id: u32_at(b, 12),
        params: b[20..]
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
    })
}

/// Encodes a completion (status word 0).
pub fn encode_completion(seq: u32) -> [u8; COMPLETION_LEN] {
    encode_completion_with_status(seq, 0)
}

/// Encodes a completion with a status word (offset 8, protocol §3.2).
pub fn encode_completion_with_status(seq: u32, status: u32) -> [u8; COMPLETION_LEN] {
    let mut c = [0u8; COMPLETION_LEN];
    c[0..4].copy_from_slice(&COMPLETION_MAGIC.to_le_bytes());
    c[4..8].copy_from_slice(&seq.to_le_bytes());
    c[8..12].copy_from_slice(&status.to_le_bytes());
    c
}

/// True if `b` is a 16-byte completion (used to detect premature completion).
pub fn is_completion(b: &[u8]) -> bool {
    b.len() == COMPLETION_LEN && u32_at(b, 0) == COMPLETION_MAGIC
}

/// Parses a completion and returns its sequence.
pub fn parse_completion(b: &[u8], what: &str) -> Result<u32> {
    if !is_completion(b) {
        return Err(KinectError::Protocol {
            what: what.into(),
            detail: format!("missing completion ({} bytes)", b.len()),
        });
    }
    Ok(u32_at(b, 4))
}

/// Parses a completion and returns `(sequence, status word)`. The status word's meaning is
/// unsure (protocol §3.2: the reference driver ignores it); kfuse only checks it for the LED API.
pub fn parse_completion_status(b: &[u8], what: &str) -> Result<(u32, u32)> {
    let seq = parse_completion(b, what)?;
    Ok((seq, u32_at(b, 8)))
}

/// One firmware version record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FirmwareVersion {
    /// Major.
    pub major: u16,
    /// Minor.
    pub minor: u16,
    /// Revision.
    pub revision: u32,
    /// Build.
    pub build: u32,
}

impl std::fmt::Display for FirmwareVersion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}.{}.{}.{}", self.major, self.minor, self.revision, self.build)
    }
}

/// Parses the firmware response (up to 7 records) and returns the records.
pub fn parse_firmware(b: &[u8]) -> Result<Vec<FirmwareVersion>> {
    if b.len() < 16 {
        return Err(KinectError::Size {
            what: "firmware response".into(),
            expected: 0x200,
            got: b.len(),
        });
    }
    Ok(b.chunks_exact(16)
        .take(7)
        .map(|r| {
            let mm = u32_at(r, 0);
            FirmwareVersion {
                major: (mm >> 16) as u16,
                minor: (mm & 0xFFFF) as u16,
                revision: u32_at(r, 4),
                build: u32_at(r, 8),
            }
        })
        .collect())
}

/// The version shown to users: record index 3 (protocol §4.2).
pub fn user_firmware_version(records: &[FirmwareVersion]) -> Option<FirmwareVersion> {
    records.get(3).copied()
}

/// Decodes the UTF-16LE serial (every other byte until a zero byte).
pub fn parse_serial(b: &[u8]) -> String {
    b.iter().step_by(2).take_while(|&&c| c != 0).map(|&c| c as char).collect()
}

/// Encodes a serial as the 0x80-byte UTF-16LE page.
pub fn encode_serial(s: &str) -> Vec<u8> {
    let mut v = vec![0u8; 0x80];
    for (i, c) in s.bytes().take(0x3F).enumerate() {
        v[2 * i] = c;
    }
    v
}

/// Parses the status word.
pub fn parse_status(b: &[u8]) -> Result<u32> {
    if b.len() < 4 {
        return Err(KinectError::Size {
            what: "status response".into(),
            expected: 4,
            got: b.len(),
        });
    }
    Ok(u32_at(b, 0))
}

// ---------------------------------------------------------------------------------------------
// Colour camera settings (0x3E, protocol §4.10) and the LED API (0x4B, protocol §4.9).
// ---------------------------------------------------------------------------------------------

/// Command id of the colour-camera setting command (protocol §4.10).
pub const COLOR_SETTING_ID: u32 = 0x3E;
/// Command id of "set mode" / LED (protocol §4.9).
pub const SET_MODE_ID: u32 = 0x4B;
/// Length of a 0x3E response: `num_status, command_list_status, status, data` (protocol §4.10).
pub const COLOR_SETTING_RESPONSE_LEN: usize = 16;

/// Analog gain accepted by the colour sensor (protocol §4.10: "f32, 1..4").
pub const ANALOG_GAIN_RANGE: std::ops::RangeInclusive<f32> = 1.0..=4.0;
/// Exposure compensation of the auto-exposure preset, in EV (protocol §4.10: "f32, −2..2").
pub const EXPOSURE_COMPENSATION_RANGE: std::ops::RangeInclusive<f32> = -2.0..=2.0;
/// Longest manual integration time / semi-auto pseudo exposure time in ms: two 30 Hz frame
/// periods, the range libfreenect2 documents for these presets (the protocol document gives none).
pub const MAX_EXPOSURE_MS: f32 = 66.0;
/// Largest red/green/blue or digital gain kfuse sends. §4.10 gives no range; kfuse uses the
/// analog gain's upper bound so that a typo cannot push an absurd value into the firmware.
pub const MAX_CHANNEL_GAIN: f32 = 4.0;
/// Number of metering zones (codes 29–76 set the weight of zone 0..47, protocol §4.10).
pub const METERING_ZONES: u8 = 48;

/// Representation of a 0x3E value word.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValueKind {
    /// A plain u32.
    U32,
    /// The bit pattern of an f32.
    F32,
}

impl ValueKind {
    /// Human-readable value for messages.
    pub fn show(self, v: u32) -> String {
        match self {
            ValueKind::U32 => v.to_string(),
            ValueKind::F32 => format!("{}", f32::from_bits(v)),
        }
    }
}

/// The codes of the 0x3E colour-setting command (protocol §4.10 table).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[allow(missing_docs)] // Each variant is §4.10's name of its code; `code()` gives the number.
pub enum ColorSettingCode {
    SetExposureMode,
    SetIntegrationTime,
    GetIntegrationTime,
    SetWhiteBalanceMode,
    SetRedGain,
    SetGreenGain,
    SetBlueGain,
    GetRedGain,
    GetGreenGain,
    GetBlueGain,
    SetExposureTime,
    GetExposureTime,
    SetDigitalGain,
    GetDigitalGain,
    SetAnalogGain,
    GetAnalogGain,
    SetExposureCompensation,
    GetExposureCompensation,
    SetAcs,
    GetAcs,
    SetMeteringMode,
    SetMeteringZones,
    /// Weight of metering zone `0..48` (codes 29–76).
    SetMeteringZoneWeight(u8),
    SetMaxAnalogGainCap,
    SetMaxDigitalGainCap,
    SetFlickerFreeFrequency,
    GetExposureMode,
    GetWhiteBalanceMode,
    SetFrameRate,
    GetFrameRate,
}

impl ColorSettingCode {
    /// The numeric code sent in parameter word 2.
    pub fn code(self) -> u32 {
        use ColorSettingCode::*;
        match self {
            SetExposureMode => 0,
            SetIntegrationTime => 1,
            GetIntegrationTime => 2,
            SetWhiteBalanceMode => 10,
            SetRedGain => 11,
            SetGreenGain => 12,
            SetBlueGain => 13,
            GetRedGain => 14,
            GetGreenGain => 15,
            GetBlueGain => 16,
            SetExposureTime => 17,
            GetExposureTime => 18,
            SetDigitalGain => 19,
            GetDigitalGain => 20,
            SetAnalogGain => 21,
            GetAnalogGain => 22,
            SetExposureCompensation => 23,
            GetExposureCompensation => 24,
            SetAcs => 25,
            GetAcs => 26,
            SetMeteringMode => 27,
            SetMeteringZones => 28,
            SetMeteringZoneWeight(z) => 29 + z.min(METERING_ZONES - 1) as u32,
            SetMaxAnalogGainCap => 77,
            SetMaxDigitalGainCap => 78,
            SetFlickerFreeFrequency => 79,
            GetExposureMode => 80,
            GetWhiteBalanceMode => 81,
            SetFrameRate => 82,
            GetFrameRate => 83,
        }
    }

    /// The setting of a numeric code, `None` for codes protocol §4.10 does not list (3–9, > 83).
    pub fn from_code(code: u32) -> Option<Self> {
        use ColorSettingCode::*;
        Some(match code {
            0 => SetExposureMode,
            1 => SetIntegrationTime,
            2 => GetIntegrationTime,
            10 => SetWhiteBalanceMode,
            11 => SetRedGain,
            12 => SetGreenGain,
            13 => SetBlueGain,
            14 => GetRedGain,
            15 => GetGreenGain,
            16 => GetBlueGain,
            17 => SetExposureTime,
            18 => GetExposureTime,
            19 => SetDigitalGain,
            20 => GetDigitalGain,
            21 => SetAnalogGain,
            22 => GetAnalogGain,
            23 => SetExposureCompensation,
            24 => GetExposureCompensation,
            25 => SetAcs,
            26 => GetAcs,
            27 => SetMeteringMode,
            28 => SetMeteringZones,
            29..=76 => SetMeteringZoneWeight((code - 29) as u8),
            77 => SetMaxAnalogGainCap,
            78 => SetMaxDigitalGainCap,
            79 => SetFlickerFreeFrequency,
            80 => GetExposureMode,
            81 => GetWhiteBalanceMode,
            82 => SetFrameRate,
            83 => GetFrameRate,
            _ => return None,
        })
    }

    /// True for GET codes (their response `data` holds the value).
    pub fn is_get(self) -> bool {
        self.set_of_get().is_some()
    }

    /// For a GET code, the SET code whose value it reads.
    pub fn set_of_get(self) -> Option<Self> {
        use ColorSettingCode::*;
        Some(match self {
            GetIntegrationTime => SetIntegrationTime,
            GetRedGain => SetRedGain,
            GetGreenGain => SetGreenGain,
            GetBlueGain => SetBlueGain,
            GetExposureTime => SetExposureTime,
            GetDigitalGain => SetDigitalGain,
            GetAnalogGain => SetAnalogGain,
            GetExposureCompensation => SetExposureCompensation,
            GetAcs => SetAcs,
            GetExposureMode => SetExposureMode,
            GetWhiteBalanceMode => SetWhiteBalanceMode,
            GetFrameRate => SetFrameRate,
            _ => return None,
        })
    }

    /// How the value word is represented: f32 for the times and gains (protocol §4.10 names
    /// integration time, exposure time, analog gain and compensation as f32; the channel and
    /// digital gains and caps are treated alike \[UNSURE\]), u32 for modes and the rest.
    pub fn value_kind(self) -> ValueKind {
        use ColorSettingCode::*;
        let set = self.set_of_get().unwrap_or(self);
        match set {
            SetIntegrationTime
            | SetRedGain
            | SetGreenGain
            | SetBlueGain
            | SetExposureTime
            | SetDigitalGain
            | SetAnalogGain
            | SetExposureCompensation
            | SetMaxAnalogGainCap
            | SetMaxDigitalGainCap => ValueKind::F32,
            _ => ValueKind::U32,
        }
    }
}

/// The 16-byte response of a 0x3E command (protocol §4.10).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ColorSettingResponse {
    /// Number of status entries.
    pub num_status: u32,
    /// Command-list status.
    pub command_list_status: u32,
    /// Status of the setting; kfuse treats non-zero as "rejected by the device".
    pub status: u32,
    /// The value for GET codes.
    pub data: u32,
}

impl ColorSettingResponse {
    /// `data` read as an f32 bit pattern.
    pub fn data_f32(&self) -> f32 {
        f32::from_bits(self.data)
    }

    /// The 16 response bytes (used by the simulated device).
    pub fn to_bytes(&self) -> [u8; COLOR_SETTING_RESPONSE_LEN] {
        let mut b = [0u8; COLOR_SETTING_RESPONSE_LEN];
        for (i, w) in [self.num_status, self.command_list_status, self.status, self.data]
            .into_iter()
            .enumerate()
        {
            b[4 * i..4 * i + 4].copy_from_slice(&w.to_le_bytes());
        }
        b
    }
}

/// Parses a 0x3E response: exactly 16 bytes, four little-endian u32 words.
pub fn parse_color_setting_response(b: &[u8]) -> Result<ColorSettingResponse> {
    if b.len() != COLOR_SETTING_RESPONSE_LEN {
        return Err(KinectError::Size {
            what: "colour setting (0x3E) response".into(),
            expected: COLOR_SETTING_RESPONSE_LEN,
            got: b.len(),
        });
    }
    if is_completion(b) {
        return Err(KinectError::Protocol {
            what: "colour setting (0x3E) response".into(),
            detail: "a completion instead of the 16-byte response (premature completion)".into(),
        });
    }
    Ok(ColorSettingResponse {
        num_status: u32_at(b, 0),
        command_list_status: u32_at(b, 4),
        status: u32_at(b, 8),
        data: u32_at(b, 12),
    })
}

/// Colour exposure mode as read with code 80 and set with code 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExposureMode {
    /// 0: fully automatic.
    Auto,
    /// 3: semi-automatic (pseudo exposure time, automatic gain).
    SemiAuto,
    /// 4: manual (integration time and analog gain).
    Manual,
    /// A value the protocol document does not name.
    Other(u32),
}

impl ExposureMode {
    /// The value word.
    pub fn value(self) -> u32 {
        match self {
            ExposureMode::Auto => 0,
            ExposureMode::SemiAuto => 3,
            ExposureMode::Manual => 4,
            ExposureMode::Other(v) => v,
        }
    }

    /// Decodes a value word.
    pub fn from_value(v: u32) -> Self {
        match v {
            0 => ExposureMode::Auto,
            3 => ExposureMode::SemiAuto,
            4 => ExposureMode::Manual,
            v => ExposureMode::Other(v),
        }
    }
}

/// An exposure setting of the colour camera (the presets of protocol §4.10).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Exposure {
    /// Automatic exposure with a compensation in EV ([`EXPOSURE_COMPENSATION_RANGE`]).
    Auto {
        /// Exposure compensation.
        compensation: f32,
    },
    /// Semi-automatic: a pseudo exposure time in ms, `(0, MAX_EXPOSURE_MS]`.
    SemiAuto {
        /// Pseudo exposure time (ms).
        exposure_ms: f32,
    },
    /// Manual: integration time in ms `(0, MAX_EXPOSURE_MS]` and analog gain
    /// ([`ANALOG_GAIN_RANGE`]).
    Manual {
        /// Integration time (ms).
        integration_ms: f32,
        /// Analog gain.
        analog_gain: f32,
    },
}

fn check_range(what: &str, v: f32, lo: f32, lo_inclusive: bool, hi: f32) -> Result<()> {
    let ok = v.is_finite() && (if lo_inclusive { v >= lo } else { v > lo }) && v <= hi;
    if ok {
        Ok(())
    } else {
        let open = if lo_inclusive { "[" } else { "(" };
        Err(KinectError::Invalid(format!("{what} {v} is outside {open}{lo}, {hi}]")))
    }
}

impl Exposure {
    /// Checks the values against the named ranges.
    pub fn validate(&self) -> Result<()> {
        match *self {
            Exposure::Auto { compensation } => check_range(
                "exposure compensation",
                compensation,
                *EXPOSURE_COMPENSATION_RANGE.start(),
                true,
                *EXPOSURE_COMPENSATION_RANGE.end(),
            ),
            Exposure::SemiAuto { exposure_ms } => check_range(
                "semi-auto exposure time (ms)",
                exposure_ms,
                0.0,
                false,
                MAX_EXPOSURE_MS,
            ),
            Exposure::Manual { integration_ms, analog_gain } => {
                check_range("integration time (ms)", integration_ms, 0.0, false, MAX_EXPOSURE_MS)?;
                check_range(
                    "analog gain",
                    analog_gain,
                    *ANALOG_GAIN_RANGE.start(),
                    true,
                    *ANALOG_GAIN_RANGE.end(),
                )
            }
        }
    }

    /// The preset's `(code, value)` settings, in order (protocol §4.10): *auto* = (25←0, 0←0,
    /// 23←comp); *semi-auto* = (25←0, 0←3, 17←ms); *manual* = (25←0, 0←4, 1←ms, 21←gain).
    pub fn settings(&self) -> Result<Vec<(ColorSettingCode, u32)>> {
        self.validate()?;
        use ColorSettingCode::*;
        let acs = (SetAcs, 0);
        Ok(match *self {
            Exposure::Auto { compensation } => {
                vec![
                    acs,
                    (SetExposureMode, ExposureMode::Auto.value()),
                    (SetExposureCompensation, compensation.to_bits()),
                ]
            }
            Exposure::SemiAuto { exposure_ms } => {
                vec![
                    acs,
                    (SetExposureMode, ExposureMode::SemiAuto.value()),
                    (SetExposureTime, exposure_ms.to_bits()),
                ]
            }
            Exposure::Manual { integration_ms, analog_gain } => vec![
                acs,
                (SetExposureMode, ExposureMode::Manual.value()),
                (SetIntegrationTime, integration_ms.to_bits()),
                (SetAnalogGain, analog_gain.to_bits()),
            ],
        })
    }

    /// The preset as 0x3E commands, in order.
    pub fn commands(&self) -> Result<Vec<Command>> {
        Ok(self
            .settings()?
            .into_iter()
            .map(|(c, v)| Command::ColorSetting { code: c.code(), value: v })
            .collect())
    }
}

/// The *auto* preset's commands (validated).
pub fn auto_exposure(compensation: f32) -> Result<Vec<Command>> {
    Exposure::Auto { compensation }.commands()
}

/// The *semi-auto* preset's commands (validated).
pub fn semi_auto_exposure(exposure_ms: f32) -> Result<Vec<Command>> {
    Exposure::SemiAuto { exposure_ms }.commands()
}

/// The *manual* preset's commands (validated).
pub fn manual_exposure(integration_ms: f32, analog_gain: f32) -> Result<Vec<Command>> {
    Exposure::Manual { integration_ms, analog_gain }.commands()
}

/// Checks a red/green/blue or digital gain: finite, `(0, MAX_CHANNEL_GAIN]`.
pub fn validate_channel_gain(what: &str, g: f32) -> Result<()> {
    check_range(what, g, 0.0, false, MAX_CHANNEL_GAIN)
}

/// Highest LED brightness level (protocol §4.9: levels 0..1000).
pub const LED_MAX_LEVEL: u16 = 1000;
/// Number of LEDs addressable by the LED API (ids 0 and 1, protocol §4.9).
pub const LED_COUNT: u16 = 2;

/// LED mode (protocol §4.9).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LedMode {
    /// 0: constant at `start_level`.
    Constant,
    /// 1: blink between `start_level` and `stop_level` every `interval_ms`.
    Blink,
}

/// One LED setting (§4.9): `u16 id, u16 mode | u16 start, u16 stop | u32 interval | u32 0`,
/// packed little-endian into the four parameter words.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LedSetting {
    /// LED 0 or 1.
    pub id: u16,
    /// Constant or blinking.
    pub mode: LedMode,
    /// Level 0..=1000 (constant level, or first blink level).
    pub start_level: u16,
    /// Level 0..=1000 (second blink level).
    pub stop_level: u16,
    /// Blink interval in ms (> 0 when blinking; sent as is when constant).
    pub interval_ms: u32,
}

impl LedSetting {
    /// LED `id` off (constant, level 0).
    pub fn off(id: u16) -> Self {
        LedSetting { id, mode: LedMode::Constant, start_level: 0, stop_level: 0, interval_ms: 0 }
    }

    /// LED `id` constantly on at `level`.
    pub fn on(id: u16, level: u16) -> Self {
        LedSetting {
            id,
            mode: LedMode::Constant,
            start_level: level,
            stop_level: level,
            interval_ms: 0,
        }
    }

    /// LED `id` blinking between full and off every `interval_ms`.
    pub fn blink(id: u16, interval_ms: u32) -> Self {
        LedSetting {
            id,
            mode: LedMode::Blink,
            start_level: LED_MAX_LEVEL,
            stop_level: 0,
            interval_ms,
        }
    }

    /// Checks id, levels and the blink interval.
    pub fn validate(&self) -> Result<()> {
        if self.id >= LED_COUNT {
            return Err(KinectError::Invalid(format!(
                "LED id {} (the sensor has LEDs 0 and 1)",
                self.id
            )));
        }
        for (what, l) in [("start level", self.start_level), ("stop level", self.stop_level)] {
            if l > LED_MAX_LEVEL {
                return Err(KinectError::Invalid(format!(
                    "LED {what} {l} is above {LED_MAX_LEVEL}"
                )));
            }
        }
        if self.mode == LedMode::Blink && self.interval_ms == 0 {
            return Err(KinectError::Invalid("LED blink interval must be at least 1 ms".into()));
        }
        Ok(())
    }

    /// The four parameter words.
    pub fn words(&self) -> [u32; 4] {
        let mode = match self.mode {
            LedMode::Constant => 0u32,
            LedMode::Blink => 1,
        };
        [
            self.id as u32 | mode << 16,
            self.start_level as u32 | (self.stop_level as u32) << 16,
            self.interval_ms,
            0,
        ]
    }

    /// Decodes (and validates) four parameter words; the reserved word must be 0.
    pub fn from_words(w: [u32; 4]) -> Result<Self> {
        let mode = match w[0] >> 16 {
            0 => LedMode::Constant,
            1 => LedMode::Blink,
            m => {
                return Err(KinectError::Invalid(format!(
                    "LED mode {m} (0 = constant, 1 = blink)"
                )));
            }
        };
        if w[3] != 0 {
            return Err(KinectError::Invalid(format!("LED reserved word {:#x} is not 0", w[3])));
        }
        let l = LedSetting {
            id: (w[0] & 0xFFFF) as u16,
            mode,
            start_level: (w[1] & 0xFFFF) as u16,
            stop_level: (w[1] >> 16) as u16,
            interval_ms: w[2],
        };
        l.validate()?;
        Ok(l)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_roundtrip_and_lengths() {
        let c = Command::SetMode(MODE_ON_100);
        let m = c.encode(6);
        // Protocol §3.1: a 20-byte header (magic, sequence, max response length, id, 0) plus
        // 4 bytes per parameter word: 36 for 0x4B's four words, 24 for a data page, 20 for none.
        assert_eq!(m.len(), 36);
        let p = parse_command(&m).unwrap();
        assert_eq!((p.sequence, p.id, p.params.clone()), (6, 0x4B, MODE_ON_100.to_vec()));
        assert_eq!(Command::ReadDataPage(2).encode(4).len(), 24);
        assert_eq!(Command::InitStreams.encode(0).len(), 20);
        assert!(parse_command(&m[..30]).is_err());
        let s = encode_serial("016293740947");
        assert_eq!(parse_serial(&s), "016293740947");
        assert_eq!(parse_completion(&encode_completion(9), "x").unwrap(), 9);
    }

    /// The 20-byte header of a command message with sequence 0, as spelled out in protocol §3.1.
    fn header(max_len: u8, id: u8) -> Vec<u8> {
        vec![0x09, 0x20, 0x02, 0x06, 0, 0, 0, 0, max_len, 0, 0, 0, id, 0, 0, 0, 0, 0, 0, 0]
    }

    /// One 0x3E message `[1, 0, code, value]` with the value given as its 4 little-endian bytes.
    fn color_msg(code: u8, value: [u8; 4]) -> Vec<u8> {
        let mut m = header(16, 0x3E);
        m.extend_from_slice(&[1, 0, 0, 0, 0, 0, 0, 0, code, 0, 0, 0]);
        m.extend_from_slice(&value);
        m
    }

    /// Every preset of protocol §4.10 encodes to the exact bytes: count 1, setting sequence id 0,
    /// the code, the value (u32 or the f32 bit pattern, hand-written below: 20.0 = 0x41A00000,
    /// 2.0 = 0x40000000, −1.5 = 0xBFC00000, 33.0 = 0x42040000), sequence 0 in the header.
    #[test]
    fn exposure_presets_encode_byte_for_byte() {
        let enc = |cmds: Vec<Command>| cmds.iter().map(|c| c.encode(0)).collect::<Vec<_>>();
        let acs = color_msg(25, [0, 0, 0, 0]);
        assert_eq!(
            enc(manual_exposure(20.0, 2.0).unwrap()),
            vec![
                acs.clone(),
                color_msg(0, [4, 0, 0, 0]),
                color_msg(1, [0, 0, 0xA0, 0x41]),
                color_msg(21, [0, 0, 0, 0x40])
            ]
        );
        assert_eq!(
            enc(auto_exposure(-1.5).unwrap()),
            vec![acs.clone(), color_msg(0, [0, 0, 0, 0]), color_msg(23, [0, 0, 0xC0, 0xBF])]
        );
        assert_eq!(
            enc(semi_auto_exposure(33.0).unwrap()),
            vec![acs, color_msg(0, [3, 0, 0, 0]), color_msg(17, [0, 0, 0x04, 0x42])]
        );
        for m in enc(manual_exposure(20.0, 2.0).unwrap()) {
            assert_eq!(m.len(), 36);
        }
        // A GET: value word 0, response length 16.
        assert_eq!(Command::get(ColorSettingCode::GetAnalogGain).encode(0), color_msg(22, [0; 4]));
        assert!(Command::get(ColorSettingCode::GetAnalogGain).is_unsequenced());
        assert!(!Command::SetMode(MODE_OFF).is_unsequenced());
    }

    #[test]
    fn exposure_validation_names_the_range() {
        // Out by a little on each side of protocol §4.10's ranges (analog gain 1..4, compensation
        // −2..2) and of (0, MAX_EXPOSURE_MS] for times, plus NaN and infinity.
        for bad in [
            Exposure::Manual { integration_ms: 20.0, analog_gain: 0.5 },
            Exposure::Manual { integration_ms: 20.0, analog_gain: 4.01 },
            Exposure::Manual { integration_ms: 0.0, analog_gain: 2.0 },
            Exposure::Manual { integration_ms: 66.5, analog_gain: 2.0 },
            Exposure::Manual { integration_ms: f32::NAN, analog_gain: 2.0 },
            Exposure::Auto { compensation: 2.5 },
            Exposure::Auto { compensation: -2.01 },
            Exposure::SemiAuto { exposure_ms: -1.0 },
            Exposure::SemiAuto { exposure_ms: f32::INFINITY },
        ] {
            let e = bad.commands().unwrap_err().to_string();
            assert!(e.contains("outside"), "{bad:?}: {e}");
        }
        // Edges of the ranges are accepted.
        assert!(manual_exposure(MAX_EXPOSURE_MS, 4.0).is_ok());
        assert!(manual_exposure(0.1, 1.0).is_ok());
        assert!(auto_exposure(-2.0).is_ok() && auto_exposure(2.0).is_ok());
    }

    #[test]
    fn color_codes_round_trip_and_pair_get_with_set() {
        let mut n = 0;
        for code in 0..=100u32 {
            if let Some(c) = ColorSettingCode::from_code(code) {
                assert_eq!(c.code(), code);
                n += 1;
            }
        }
        // Protocol §4.10 lists codes 0, 1, 2, 10..=83: 3 + 74.
        assert_eq!(n, 77);
        assert_eq!(
            ColorSettingCode::GetAnalogGain.set_of_get(),
            Some(ColorSettingCode::SetAnalogGain)
        );
        assert_eq!(
            ColorSettingCode::GetExposureMode.set_of_get(),
            Some(ColorSettingCode::SetExposureMode)
        );
        assert_eq!(ColorSettingCode::GetAnalogGain.value_kind(), ValueKind::F32);
        assert_eq!(ColorSettingCode::GetExposureMode.value_kind(), ValueKind::U32);
        assert_eq!(ColorSettingCode::SetMeteringZoneWeight(47).code(), 76);
    }

    /// A sample response: num_status 1, command-list status 0, status 0, data = 2.0f32.
    #[test]
    fn color_setting_response_parses_and_rejects_bad_lengths() {
        let b = [1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x40];
        let r = parse_color_setting_response(&b).unwrap();
        assert_eq!(
            r,
            ColorSettingResponse {
                num_status: 1,
                command_list_status: 0,
                status: 0,
                data: 0x4000_0000
            }
        );
        assert_eq!(r.data_f32(), 2.0);
        assert_eq!(r.to_bytes(), b);
        for n in [0, 4, 15, 17] {
            let e = parse_color_setting_response(&vec![0u8; n]).unwrap_err().to_string();
            assert!(e.contains("expected 16 bytes"), "{e}");
        }
        let e = parse_color_setting_response(&encode_completion(0)).unwrap_err().to_string();
        assert!(e.contains("premature completion"), "{e}");
    }

    /// LED words per protocol §4.9; the start/stop mode words of its table decode as the
    /// LED settings it names.
    #[test]
    fn led_setting_encodes_per_spec() {
        let blink = LedSetting::blink(1, 500);
        // Protocol §4.9: led 1 | blink (1) << 16; start 1000 (0x3E8) | stop 0 << 16; 500 ms; 0.
        // The bad ones break §4.9's ranges: led id 0 or 1, levels 0..1000, blink interval > 0.
        assert_eq!(blink.words(), [0x0001_0001, 0x0000_03E8, 500, 0]);
        let mut m = header(0, 0x4B);
        m.extend_from_slice(&[1, 0, 1, 0, 0xE8, 0x03, 0, 0, 0xF4, 0x01, 0, 0, 0, 0, 0, 0]);
        assert_eq!(Command::Led(blink).encode(0), m);
        assert_eq!(LedSetting::on(1, 100).words(), MODE_ON_100);
        assert_eq!(LedSetting::off(0).words(), MODE_OFF);
        assert_eq!(LedSetting::on(1, 0).words(), MODE_ON);
        assert_eq!(LedSetting::from_words(MODE_ON_100).unwrap(), LedSetting::on(1, 100));
        assert_eq!(LedSetting::from_words(blink.words()).unwrap(), blink);
        for bad in [
            LedSetting::on(2, 100),
            LedSetting::on(0, 1001),
            LedSetting { stop_level: 5000, ..LedSetting::blink(0, 100) },
            LedSetting::blink(0, 0),
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
            assert!(LedSetting::from_words(bad.words()).is_err(), "{bad:?}");
        }
        assert!(LedSetting::from_words([0x0002_0000, 0, 0, 0]).is_err());
        assert!(LedSetting::from_words([0, 0, 0, 7]).is_err());
    }
}
