//! How the simulated device answers commands: the response of each command from the profile
//! (status polls, colour settings), the status convention of its answers and the LED state
//! that 0x4B sets.

use super::{SimColorSettings, SimDevice};
use crate::protocol::{self, COLOR_SETTING_ID, CommandMessage, LedSetting};

/// Status the simulated device puts in a 0x3E response (or an LED completion) when a value is
/// out of range. The real status codes are not documented (protocol §4.10); the sim's convention:
/// 0 = accepted, [`SIM_STATUS_INVALID_VALUE`], [`SIM_STATUS_UNKNOWN_CODE`],
/// [`SIM_STATUS_BAD_REQUEST`].
pub const SIM_STATUS_INVALID_VALUE: u32 = 1;
/// Status for a setting code the protocol document does not list.
pub const SIM_STATUS_UNKNOWN_CODE: u32 = 2;
/// Status for a malformed 0x3E request (setting count ≠ 1 or setting sequence id ≠ 0).
pub const SIM_STATUS_BAD_REQUEST: u32 = 3;

impl SimDevice {
    pub(super) fn respond(&mut self, m: &CommandMessage) -> Vec<u8> {
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
            (COLOR_SETTING_ID, _) => {
                let mut r = self.color.apply(&m.params);
                if r.status == 0
                    && let Some(s) = self.faults.accepted_status
                {
                    r.status = s;
                }
                r.to_bytes().to_vec()
            }
            _ => Vec::new(),
        }
    }

    /// Records an LED setting from 0x4B words; returns the completion status (non-zero when
    /// an LED API request is invalid). Start/stop "mode" words are recorded when they decode as
    /// LED settings (protocol §4.9) and never rejected.
    pub(super) fn apply_led(&mut self, params: &[u32], api: bool) -> u32 {
        let words = match params {
            &[a, b, c, d] => [a, b, c, d],
            _ => return SIM_STATUS_BAD_REQUEST,
        };
        match LedSetting::from_words(words) {
            Ok(l) => {
                self.leds[l.id as usize & 1] = Some(l);
                if api {
                    self.led_api.push(l);
                    return self.faults.accepted_status.unwrap_or(0);
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
}
