//! The colour camera's and LED's settings and their text forms, as `kfuse capture --exposure`
//! and `--led` spell them: `auto[:COMP]`, `semi:MS`, `manual:MS,GAIN`; `off`, `on[:LEVEL]`,
//! `blink:MS`. Values are checked against the ranges of `kinect_usb::protocol`.

use kinect_usb::protocol::{self, Exposure, LedSetting};

/// Colour camera and LED settings applied right after start-up (not with a replay).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ColorSettings {
    /// Exposure mode and values (`None`: the sensor's automatic default).
    pub exposure: Option<Exposure>,
    /// LED state (`None`: left as it is).
    pub led: Option<LedSetting>,
}

/// An LED state before the LED id is known (`--led`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LedState {
    /// Off.
    Off,
    /// Constant at a level 0..=1000.
    On(u16),
    /// Blinking with an interval in ms.
    Blink(u32),
}

impl LedState {
    /// The setting for LED `id` (0 or 1).
    pub fn setting(self, id: u16) -> LedSetting {
        match self {
            LedState::Off => LedSetting::off(id),
            LedState::On(level) => LedSetting::on(id, level),
            LedState::Blink(ms) => LedSetting::blink(id, ms),
        }
    }
}

fn parse_f32(s: &str, what: &str) -> Result<f32, String> {
    s.trim().parse::<f32>().map_err(|_| format!("{what} `{s}` is not a number"))
}

/// Parses `--exposure`: `auto`, `auto:COMP`, `semi:MS`, `manual:MS,GAIN`; values are checked
/// against the ranges of `kinect_usb::protocol`.
pub fn parse_exposure(s: &str) -> Result<Exposure, String> {
    const FORMS: &str = "expected auto, auto:COMP, semi:MS or manual:MS,GAIN (e.g. manual:20,2)";
    let (mode, rest) = match s.split_once(':') {
        Some((m, r)) => (m, Some(r)),
        None => (s, None),
    };
    let e = match (mode.trim().to_ascii_lowercase().as_str(), rest) {
        ("auto", None) => Exposure::Auto { compensation: 0.0 },
        ("auto", Some(c)) => Exposure::Auto { compensation: parse_f32(c, "compensation")? },
        ("semi" | "semi-auto", Some(ms)) => {
            Exposure::SemiAuto { exposure_ms: parse_f32(ms, "exposure time")? }
        }
        ("manual", Some(r)) => {
            let (ms, gain) =
                r.split_once(',').ok_or_else(|| format!("manual needs MS,GAIN; {FORMS}"))?;
            Exposure::Manual {
                integration_ms: parse_f32(ms, "integration time")?,
                analog_gain: parse_f32(gain, "analog gain")?,
            }
        }
        _ => return Err(format!("`{s}`: {FORMS}")),
    };
    e.validate().map_err(|err| err.to_string())?;
    Ok(e)
}

/// Parses `--led`: `off`, `on`, `on:LEVEL`, `blink:MS`.
pub fn parse_led(s: &str) -> Result<LedState, String> {
    const FORMS: &str = "expected off, on, on:LEVEL (0..1000) or blink:MS";
    let (mode, rest) = match s.split_once(':') {
        Some((m, r)) => (m, Some(r.trim())),
        None => (s, None),
    };
    let arg =
        match (mode.trim().to_ascii_lowercase().as_str(), rest) {
            ("off", None) => LedState::Off,
            ("on", None) => LedState::On(protocol::LED_MAX_LEVEL),
            ("on", Some(l)) => LedState::On(
                l.parse().map_err(|_| format!("LED level `{l}` is not a whole number; {FORMS}"))?,
            ),
            ("blink", Some(ms)) => LedState::Blink(ms.parse().map_err(|_| {
                format!("blink interval `{ms}` is not a whole number of ms; {FORMS}")
            })?),
            _ => return Err(format!("`{s}`: {FORMS}")),
        };
    arg.setting(0).validate().map_err(|e| e.to_string())?;
    Ok(arg)
}

/// An exposure in the form [`parse_exposure`] reads (`auto:COMP`, `semi:MS`, `manual:MS,GAIN`).
pub fn exposure_text(e: &Exposure) -> String {
    match *e {
        Exposure::Auto { compensation } => format!("auto:{compensation}"),
        Exposure::SemiAuto { exposure_ms } => format!("semi:{exposure_ms}"),
        Exposure::Manual { integration_ms, analog_gain } => {
            format!("manual:{integration_ms},{analog_gain}")
        }
    }
}
