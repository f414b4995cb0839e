//! The LED API (command 0x4B with the LED words, protocol §4.9): validated LED settings and
//! their four parameter words.

use crate::error::{KinectError, Result};

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
