//! Stream parsers: depth frame assembly from isochronous packets (protocol §7) and colour JPEG
//! framing from bulk transfers (protocol §6). Both are allocation-free per packet after
//! construction and never panic on any input.

use crate::raw::{RAW_FRAME_BYTES, SUB_IMAGE_BYTES, SUB_IMAGES};

/// Bytes of the footer that ends every depth sub-packet.
pub const DEPTH_FOOTER_BYTES: usize = 152;
/// Bytes of a depth sub-packet on the wire (data + footer).
pub const DEPTH_SUBPACKET_BYTES: usize = SUB_IMAGE_BYTES + DEPTH_FOOTER_BYTES;
/// Mask of a complete frame (all 10 sub-images received).
const COMPLETE_MASK: u16 = 0x3FF;
/// Depth sequence numbers wrap at 2^16 (protocol §7, observed).
const DEPTH_SEQ_MODULUS: u32 = 1 << 16;
/// Colour header bytes (sequence + magic).
pub const COLOR_HEADER_BYTES: usize = 8;
/// Colour footer bytes.
pub const COLOR_FOOTER_BYTES: usize = 56;
/// Colour header magic "BBBB".
pub const COLOR_MAGIC: u32 = 0x4242_4242;
/// Colour footer magic "9999".
pub const COLOR_FOOTER_MAGIC: u32 = 0x3939_3939;
/// Colour assembly buffer capacity (reference: 2 MiB).
pub const COLOR_BUFFER_CAPACITY: usize = 2 << 20;

fn u32_at(b: &[u8], off: usize) -> u32 {
    u32::from_le_bytes([b[off], b[off + 1], b[off + 2], b[off + 3]])
}

/// Footer of a depth sub-packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DepthFooter {
    /// Timestamp (0.125 ms units).
    pub timestamp: u32,
    /// Frame sequence number.
    pub sequence: u32,
    /// Sub-image index 0..9.
    pub subsequence: u32,
    /// Data length (298 496).
    pub length: u32,
}

impl DepthFooter {
    /// Parses the 152-byte footer.
    pub fn parse(b: &[u8]) -> Option<Self> {
        if b.len() < DEPTH_FOOTER_BYTES {
            return None;
        }
        Some(DepthFooter {
            timestamp: u32_at(b, 8),
            sequence: u32_at(b, 12),
            subsequence: u32_at(b, 16),
            length: u32_at(b, 20),
        })
    }

    /// Serialises the footer (magic words and the 32 unknown fields zero).
    pub fn to_bytes(&self) -> [u8; DEPTH_FOOTER_BYTES] {
        let mut f = [0u8; DEPTH_FOOTER_BYTES];
        f[8..12].copy_from_slice(&self.timestamp.to_le_bytes());
        f[12..16].copy_from_slice(&self.sequence.to_le_bytes());
        f[16..20].copy_from_slice(&self.subsequence.to_le_bytes());
        f[20..24].copy_from_slice(&self.length.to_le_bytes());
        f
    }
}

/// Counters of the depth stream.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DepthStats {
    /// Complete frames emitted.
    pub frames: u64,
    /// Frames started but never completed (a sub-image was lost).
    pub incomplete_frames: u64,
    /// Frames of which not one sub-packet arrived (gaps in the sequence numbers of the
    /// sub-packets seen). `frames + incomplete_frames + skipped_frames` accounts for every
    /// frame the sensor sent, but the one still in assembly.
    pub skipped_frames: u64,
    /// Sub-packets dropped (wrong length or overflow).
    pub dropped_subpackets: u64,
}

/// Assembles raw depth frames from isochronous packets.
pub struct DepthAssembler {
    work: Vec<u8>,
    frame: Vec<u8>,
    mask: u16,
    current_seq: Option<u32>,
    first_timestamp: u32,
    last_seen_seq: Option<u32>,
    last: Option<(u32, u32)>,
    /// Stream counters.
    pub stats: DepthStats,
}

/// A complete raw depth frame, borrowed from the assembler.
#[derive(Debug)]
pub struct RawDepthFrame<'a> {
    /// Frame sequence number.
    pub sequence: u32,
    /// Timestamp of the frame's sub-packet 0 (kfuse deviation from the reference, protocol §7).
    pub timestamp: u32,
    /// 2 984 960 bytes.
    pub data: &'a [u8],
}

impl Default for DepthAssembler {
    fn default() -> Self {
        Self::new()
    }
}

impl DepthAssembler {
    /// New assembler with its buffers allocated.
    pub fn new() -> Self {
        DepthAssembler {
            work: Vec::with_capacity(DEPTH_SUBPACKET_BYTES),
            frame: vec![0u8; RAW_FRAME_BYTES],
            mask: 0,
            current_seq: None,
            first_timestamp: 0,
            last_seen_seq: None,
            last: None,
            stats: DepthStats::default(),
        }
    }

    /// Feeds one completed isochronous packet (`data` = its `actual_length` bytes). Returns a
    /// frame when this packet completed one.
    pub fn push(&mut self, data: &[u8]) -> Option<RawDepthFrame<'_>> {
        self.last = None;
        if data.is_empty() {
            self.work.clear();
            return None;
        }
        let total = self.work.len() + data.len();
        if total > DEPTH_SUBPACKET_BYTES {
            self.work.clear();
            self.stats.dropped_subpackets += 1;
            return None;
        }
        self.work.extend_from_slice(data);
        if total == DEPTH_SUBPACKET_BYTES {
            // The sub-packet ends here: its last 152 bytes are the footer (which may straddle
            // the previous packet when the last packet is short).
            let footer = DepthFooter::parse(&self.work[SUB_IMAGE_BYTES..])?;
            self.work.truncate(SUB_IMAGE_BYTES);
            return self.on_subpacket(footer);
        }
        None
    }

    fn on_subpacket(&mut self, f: DepthFooter) -> Option<RawDepthFrame<'_>> {
        let len = self.work.len();
        if f.length as usize != len
            || f.subsequence as usize >= SUB_IMAGES
            || len != SUB_IMAGE_BYTES
        {
            self.work.clear();
            self.stats.dropped_subpackets += 1;
            return None;
        }
        if self.current_seq != Some(f.sequence) {
            if self.current_seq.is_some() && self.mask != 0 {
                self.stats.incomplete_frames += 1;
            }
            self.note_sequence(f.sequence);
            self.current_seq = Some(f.sequence);
            self.mask = 0;
        }
        if f.subsequence == 0 {
            self.first_timestamp = f.timestamp;
        }
        let s = f.subsequence as usize;
        self.frame[s * SUB_IMAGE_BYTES..][..SUB_IMAGE_BYTES].copy_from_slice(&self.work);
        self.mask |= 1 << s;
        self.work.clear();
        if self.mask == COMPLETE_MASK {
            self.mask = 0;
            self.current_seq = None;
            self.stats.frames += 1;
            self.last = Some((f.sequence, self.first_timestamp));
            return Some(RawDepthFrame {
                sequence: f.sequence,
                timestamp: self.first_timestamp,
                data: &self.frame,
            });
        }
        None
    }

    /// Counts the frames skipped between the last sequence seen and `sequence` (modulo 2¹⁶,
    /// so the wrap is not a loss). A sequence behind the last one (a late sub-packet of an
    /// older frame) is neither a loss nor the new reference.
    fn note_sequence(&mut self, sequence: u32) {
        let forward = match self.last_seen_seq {
            None => true,
            Some(prev) => {
                let gap = sequence.wrapping_sub(prev) % DEPTH_SEQ_MODULUS;
                if gap > 1 && gap < DEPTH_SEQ_MODULUS / 2 {
                    self.stats.skipped_frames += (gap - 1) as u64;
                }
                gap != 0 && gap < DEPTH_SEQ_MODULUS / 2
            }
        };
        if forward {
            self.last_seen_seq = Some(sequence);
        }
    }

    /// The frame completed by the latest [`Self::push`], if that push completed one.
    pub fn last_frame(&self) -> Option<RawDepthFrame<'_>> {
        self.last.map(|(sequence, timestamp)| RawDepthFrame {
            sequence,
            timestamp,
            data: &self.frame,
        })
    }
}

/// Metadata of a colour frame (from the footer).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColorMeta {
    /// Sequence number.
    pub sequence: u32,
    /// Timestamp (0.125 ms units).
    pub timestamp: u32,
    /// Exposure (pseudo-ms).
    pub exposure: f32,
    /// Gain.
    pub gain: f32,
    /// Gamma.
    pub gamma: f32,
}

/// Counters of the colour stream.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ColorStats {
    /// Frames emitted.
    pub frames: u64,
    /// Packets rejected (size, sequence, end marker) or overflowing the buffer.
    pub dropped: u64,
    /// Frames whose header magic was not 'BBBB' (protocol §6). libfreenect2 never checks it,
    /// so kfuse counts it and keeps the frame, unless [`ColorAssembler::strict_header`] is set
    /// (then the frame is also counted in `dropped`).
    pub bad_header_magic: u64,
}

/// Assembles colour JPEG frames from bulk transfers.
pub struct ColorAssembler {
    buf: Vec<u8>,
    pending_clear: bool,
    last: Option<(usize, ColorMeta)>,
    /// Stream counters.
    pub stats: ColorStats,
    /// Drop frames whose header magic is not 'BBBB' (default: count and keep them, as
    /// libfreenect2 does not check it).
    pub strict_header: bool,
}

impl Default for ColorAssembler {
    fn default() -> Self {
        Self::new()
    }
}

impl ColorAssembler {
    /// New assembler with a 2 MiB buffer.
    pub fn new() -> Self {
        ColorAssembler {
            buf: Vec::with_capacity(COLOR_BUFFER_CAPACITY),
            pending_clear: false,
            last: None,
            stats: ColorStats::default(),
            strict_header: false,
        }
    }

    /// Feeds one completed bulk transfer. Returns `(jpeg, meta)` when a packet completed.
    pub fn push(&mut self, data: &[u8]) -> Option<(&[u8], ColorMeta)> {
        self.last = None;
        if self.pending_clear {
            self.buf.clear();
            self.pending_clear = false;
        }
        if self.buf.len() + data.len() > COLOR_BUFFER_CAPACITY {
            self.buf.clear();
            self.stats.dropped += 1;
            return None;
        }
        self.buf.extend_from_slice(data);
        let n = self.buf.len();
        if n <= COLOR_HEADER_BYTES + COLOR_FOOTER_BYTES {
            return None;
        }
        let f = &self.buf[n - COLOR_FOOTER_BYTES..];
        if u32_at(f, 0) != COLOR_FOOTER_MAGIC || u32_at(f, 32) != COLOR_MAGIC {
            return None;
        }
        let seq = u32_at(&self.buf, 0);
        let footer_seq = u32_at(f, 4);
        let filler = u32_at(f, 8) as usize;
        let packet_size = u32_at(f, 36) as usize;
        let meta = ColorMeta {
            sequence: seq,
            timestamp: u32_at(f, 20),
            exposure: f32::from_bits(u32_at(f, 24)),
            gain: f32::from_bits(u32_at(f, 28)),
            gamma: f32::from_bits(u32_at(f, 40)),
        };
        let header_ok = u32_at(&self.buf, 4) == COLOR_MAGIC;
        if packet_size != n
            || seq != footer_seq
            || n - COLOR_HEADER_BYTES - COLOR_FOOTER_BYTES < filler
        {
            self.buf.clear();
            self.stats.dropped += 1;
            return None;
        }
        let l = n - COLOR_HEADER_BYTES - COLOR_FOOTER_BYTES - filler;
        let body = &self.buf[COLOR_HEADER_BYTES..COLOR_HEADER_BYTES + l];
        let mut jpeg_len = None;
        for pad in 0..=3usize {
            if l >= pad + 2 && body[l - pad - 2] == 0xFF && body[l - pad - 1] == 0xD9 {
                jpeg_len = Some(l - pad);
                break;
            }
        }
        let Some(jl) = jpeg_len else {
            self.buf.clear();
            self.stats.dropped += 1;
            return None;
        };
        if !header_ok {
            // Only once the packet is otherwise valid, so one bad frame counts once.
            self.stats.bad_header_magic += 1;
            if self.strict_header {
                self.buf.clear();
                self.stats.dropped += 1;
                return None;
            }
        }
        self.stats.frames += 1;
        // Cleared on the next push (the frame borrows the buffer until then).
        let out = &self.buf[COLOR_HEADER_BYTES..COLOR_HEADER_BYTES + jl];
        self.pending_clear = true;
        self.last = Some((jl, meta));
        Some((out, meta))
    }

    /// The JPEG completed by the latest [`Self::push`], if that push completed one.
    pub fn last_frame(&self) -> Option<(&[u8], ColorMeta)> {
        self.last.map(|(jl, m)| (&self.buf[COLOR_HEADER_BYTES..COLOR_HEADER_BYTES + jl], m))
    }
}

/// Builds a colour packet (header + JPEG + `pad` × 0xA5 + filler + footer), as the device sends
/// it. Used by the simulated device and tests.
pub fn build_color_packet(jpeg: &[u8], meta: &ColorMeta, pad: usize, filler: usize) -> Vec<u8> {
    let n = COLOR_HEADER_BYTES + jpeg.len() + pad + filler + COLOR_FOOTER_BYTES;
    let mut p = Vec::with_capacity(n);
    p.extend_from_slice(&meta.sequence.to_le_bytes());
    p.extend_from_slice(&COLOR_MAGIC.to_le_bytes());
    p.extend_from_slice(jpeg);
    p.extend(std::iter::repeat_n(0xA5u8, pad));
    p.extend(std::iter::repeat_n(b'Z', filler));
    let mut f = [0u8; COLOR_FOOTER_BYTES];
    f[0..4].copy_from_slice(&COLOR_FOOTER_MAGIC.to_le_bytes());
    f[4..8].copy_from_slice(&meta.sequence.to_le_bytes());
    f[8..12].copy_from_slice(&(filler as u32).to_le_bytes());
    f[20..24].copy_from_slice(&meta.timestamp.to_le_bytes());
    f[24..28].copy_from_slice(&meta.exposure.to_le_bytes());
    f[28..32].copy_from_slice(&meta.gain.to_le_bytes());
    f[32..36].copy_from_slice(&COLOR_MAGIC.to_le_bytes());
    f[36..40].copy_from_slice(&(n as u32).to_le_bytes());
    f[40..44].copy_from_slice(&meta.gamma.to_le_bytes());
    p.extend_from_slice(&f);
    p
}

/// Splits a raw frame into isochronous packets the way the device does: per sub-packet
/// (data + footer) packets of `max_packet` bytes, the last one shorter, followed by
/// `gaps[s]` zero-length packets.
pub fn packetize_depth_frame(
    raw: &[u8],
    sequence: u32,
    timestamp: u32,
    max_packet: usize,
    gaps: [usize; SUB_IMAGES],
) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    for s in 0..SUB_IMAGES {
        let mut sub = Vec::with_capacity(DEPTH_SUBPACKET_BYTES);
        sub.extend_from_slice(&raw[s * SUB_IMAGE_BYTES..][..SUB_IMAGE_BYTES]);
        let f = DepthFooter {
            timestamp,
            sequence,
            subsequence: s as u32,
            length: SUB_IMAGE_BYTES as u32,
        };
        sub.extend_from_slice(&f.to_bytes());
        for chunk in sub.chunks(max_packet.max(1)) {
            out.push(chunk.to_vec());
        }
        for _ in 0..gaps[s] {
            out.push(Vec::new());
        }
    }
    out
}
