//! Colour-camera settings (command 0x3E, protocol §4.10): the setting codes, their value
//! kinds and ranges, the 16-byte response, and the exposure presets built from them.

use super::{Command, is_completion, u32_at};
use crate::error::{KinectError, Result};

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
