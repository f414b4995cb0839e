//! The attachment `rmw_zenoh` puts on every message (its `attachment_helpers.cpp` of Jazzy and
//! later): the publisher's sequence number, the source timestamp and the publisher's GID, in
//! the Zenoh serialization format (zenoh-ext): `int64` little endian, `int64` little endian,
//! then the 16-byte GID as a sequence (LEB128 length 16, the bytes). 33 bytes. A ROS 2
//! subscriber on `rmw_zenoh` reads it from every sample; kfuse's fuser reads the sequence
//! number to count the messages lost between a sensor and itself.

use crate::LiveError;

/// Bytes of a GID (`RMW_GID_STORAGE_SIZE` of ROS 2 Jazzy and later).
pub const GID_BYTES: usize = 16;

/// Bytes of an encoded attachment.
pub const ATTACHMENT_BYTES: usize = 8 + 8 + 1 + GID_BYTES;

/// One message's attachment.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    /// The publisher's count of its messages, from 1.
    pub sequence_number: i64,
    /// When the message was published: nanoseconds since the Unix epoch.
    pub source_timestamp: i64,
    /// The publisher's GID.
    pub source_gid: [u8; GID_BYTES],
}

impl Attachment {
    /// The attachment's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(ATTACHMENT_BYTES);
        b.extend_from_slice(&self.sequence_number.to_le_bytes());
        b.extend_from_slice(&self.source_timestamp.to_le_bytes());
        b.push(GID_BYTES as u8); // LEB128 of 16: one byte.
        b.extend_from_slice(&self.source_gid);
        b
    }

    /// An attachment's bytes. Error: any other length or a GID length other than 16.
    pub fn decode(bytes: &[u8]) -> Result<Self, LiveError> {
        let bad = |why: String| LiveError::Garbage { what: "the rmw_zenoh attachment", why };
        if bytes.len() != ATTACHMENT_BYTES {
            return Err(bad(format!("{} bytes, expected {ATTACHMENT_BYTES}", bytes.len())));
        }
        if bytes[16] != GID_BYTES as u8 {
            return Err(bad(format!("GID of {} bytes, expected {GID_BYTES}", bytes[16])));
        }
        let i64_at = |k: usize| {
            let mut a = [0u8; 8];
            a.copy_from_slice(&bytes[k..k + 8]);
            i64::from_le_bytes(a)
        };
        let mut source_gid = [0u8; GID_BYTES];
        source_gid.copy_from_slice(&bytes[17..]);
        Ok(Self { sequence_number: i64_at(0), source_timestamp: i64_at(8), source_gid })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_layout() {
        let a = Attachment { sequence_number: 5, source_timestamp: -2, source_gid: [7; 16] };
        let b = a.encode();
        assert_eq!(b.len(), 33);
        assert_eq!(&b[..8], &[5, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(&b[8..16], &[0xfe, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff]);
        assert_eq!(b[16], 16);
        assert_eq!(Attachment::decode(&b).unwrap(), a);
    }

    #[test]
    fn other_shapes_are_refused() {
        assert!(Attachment::decode(&[]).is_err());
        assert!(Attachment::decode(&[0; 34]).is_err());
        let mut b =
            Attachment { sequence_number: 1, source_timestamp: 1, source_gid: [0; 16] }.encode();
        b[16] = 15;
        assert!(Attachment::decode(&b).is_err());
    }
}
