//! The simulated colour camera's settings registers (command 0x3E, protocol §4.10): their
//! power-on values, the validation of a request and the exposure/gain the colour footer reports.

use super::{SIM_STATUS_BAD_REQUEST, SIM_STATUS_INVALID_VALUE, SIM_STATUS_UNKNOWN_CODE};
use crate::protocol::{
    self, ANALOG_GAIN_RANGE, ColorSettingCode, ColorSettingResponse, EXPOSURE_COMPENSATION_RANGE,
    ExposureMode, MAX_EXPOSURE_MS,
};

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
    pub(super) fn apply(&mut self, params: &[u32]) -> ColorSettingResponse {
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
