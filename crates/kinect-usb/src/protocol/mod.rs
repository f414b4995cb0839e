//! Command messages, completions and response parsers (protocol §3–§4). Pure byte-level code
//! that the sim and the device share.
//!
//! One submodule per part of the wire format: this file holds the message framing (commands,
//! completions, the firmware/serial/status parsers, protocol §3–§4.8), [`color`] the
//! colour-camera settings of 0x3E with their exposure presets (§4.10), [`led`] the LED API of
//! 0x4B (§4.9). Everything is re-exported here, so `protocol::X` names every item.

mod color;
mod led;

pub use color::*;
pub use led::*;

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

#[cfg(test)]
mod tests;
