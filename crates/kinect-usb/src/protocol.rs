//! Command messages, completions and response parsers (spec §3–§4). Pure byte-level code.

use crate::error::{KinectError, Result};

/// Command message magic.
pub const COMMAND_MAGIC: u32 = 0x0602_2009;
/// Completion magic.
pub const COMPLETION_MAGIC: u32 = 0x0A6F_E000;
/// Completion length.
pub const COMPLETION_LEN: usize = 16;
/// Status register polled for readiness.
pub const STATUS_REGISTER: u32 = 0x09_0000;
/// Minimum isochronous bytes per interval of endpoint 0x84 (spec §2.2).
pub const MIN_BYTES_PER_INTERVAL: u32 = 0x8400;

/// Vendor id (Microsoft).
pub const VENDOR_ID: u16 = 0x045E;
/// Product ids opened by kfuse: release sensor and developer preview.
pub const PRODUCT_IDS: [u16; 2] = [0x02D8, 0x02C4];

/// Endpoints (spec §2).
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

/// Command ids and parameters (spec §4.1).
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
        }
    }

    /// Parameter words.
    pub fn params(&self) -> Vec<u32> {
        match *self {
            Command::ReadDataPage(p) => vec![p],
            Command::ReadStatus(r) => vec![r],
            Command::SetStreaming(on) => vec![on as u32],
            Command::SetMode(w) => w.to_vec(),
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
            _ => 0,
        }
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
            _ => 0,
        }
    }

    /// Human-readable name for errors.
    pub fn name(&self) -> String {
        format!("{self:?} (0x{:02X})", self.id())
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
        return Err(KinectError::Protocol { what: "command".into(), detail: format!("length {} not 20, 24 or 36", b.len()) });
    }
    if u32_at(b, 0) != COMMAND_MAGIC {
        return Err(KinectError::Protocol { what: "command".into(), detail: format!("bad magic 0x{:08X}", u32_at(b, 0)) });
    }
    Ok(CommandMessage {
        sequence: u32_at(b, 4),
        max_response_len: u32_at(b, 8),
        id: u32_at(b, 12),
        params: b[20..].chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect(),
    })
}

/// Encodes a completion.
pub fn encode_completion(seq: u32) -> [u8; COMPLETION_LEN] {
    let mut c = [0u8; COMPLETION_LEN];
    c[0..4].copy_from_slice(&COMPLETION_MAGIC.to_le_bytes());
    c[4..8].copy_from_slice(&seq.to_le_bytes());
    c
}

/// True if `b` is a 16-byte completion (used to detect premature completion).
pub fn is_completion(b: &[u8]) -> bool {
    b.len() == COMPLETION_LEN && u32_at(b, 0) == COMPLETION_MAGIC
}

/// Parses a completion and returns its sequence.
pub fn parse_completion(b: &[u8], what: &str) -> Result<u32> {
    if !is_completion(b) {
        return Err(KinectError::Protocol { what: what.into(), detail: format!("missing completion ({} bytes)", b.len()) });
    }
    Ok(u32_at(b, 4))
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
        return Err(KinectError::Size { what: "firmware response".into(), expected: 0x200, got: b.len() });
    }
    Ok(b.chunks_exact(16)
        .take(7)
        .map(|r| {
            let mm = u32_at(r, 0);
            FirmwareVersion { major: (mm >> 16) as u16, minor: (mm & 0xFFFF) as u16, revision: u32_at(r, 4), build: u32_at(r, 8) }
        })
        .collect())
}

/// The version shown to users: record index 3 (spec §4.2).
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
        return Err(KinectError::Size { what: "status response".into(), expected: 4, got: b.len() });
    }
    Ok(u32_at(b, 0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_roundtrip_and_lengths() {
        let c = Command::SetMode(MODE_ON_100);
        let m = c.encode(6);
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
}
