//! kfuse's status message (`<domain>/kinect2/sn_<serial>/kfuse/status`): a small JSON object
//! `kfuse serve` publishes after each depth frame, with the sensor's own timestamps beside the
//! host times of the image headers and the counters of frames not published. Not a ROS type
//! (ROS has none for this; a ROS node can read it as bytes).

use serde::{Deserialize, Serialize};

use crate::LiveError;
use crate::keys::MAX_STATUS_BYTES;

/// `format` of a status message.
pub const STATUS_FORMAT: &str = "kfuse-live-status";
/// `version` of the status message this kfuse writes and reads.
pub const STATUS_VERSION: u32 = 1;

/// One status message.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Status {
    /// [`STATUS_FORMAT`].
    pub format: String,
    /// [`STATUS_VERSION`].
    pub version: u32,
    /// The sensor's serial number.
    pub serial: String,
    /// Depth frames published so far (this one included).
    pub frames: u64,
    /// The depth frame's sensor timestamp (0.125 ms ticks of the sensor's own clock).
    pub depth_time_ticks: u32,
    /// The depth frame's host arrival time (ns since the Unix epoch): the stamp of its
    /// `sd/image_depth`, `sd/image_ir` and `sd/camera_info` headers.
    pub depth_host_ns: u64,
    /// The newest colour frame's sensor timestamp, if any yet.
    pub color_time_ticks: Option<u32>,
    /// The newest colour frame's host arrival time (its `hd/` headers' stamp), if any yet.
    pub color_host_ns: Option<u64>,
    /// Depth frames the sensor delivered that were not published (a newer one replaced them
    /// before the publisher took them: newest wins).
    pub depth_dropped: u64,
    /// Colour frames not published, likewise.
    pub color_dropped: u64,
    /// Bytes of this depth frame's messages (depth, IR, both camera infos; the colour is
    /// published on its own when it arrives).
    pub frame_bytes: u64,
}

impl Status {
    /// The message's bytes (JSON).
    pub fn encode(&self) -> Vec<u8> {
        serde_json::to_vec(self).unwrap_or_default()
    }

    /// A status message's bytes. Error: over [`MAX_STATUS_BYTES`], not this JSON object, or
    /// another format or version.
    pub fn decode(bytes: &[u8]) -> Result<Self, LiveError> {
        let bad = |why: String| LiveError::Garbage { what: "a kfuse status message", why };
        if bytes.len() > MAX_STATUS_BYTES {
            return Err(bad(format!(
                "{} bytes, over its {MAX_STATUS_BYTES}-byte limit",
                bytes.len()
            )));
        }
        let s: Status = serde_json::from_slice(bytes).map_err(|e| bad(format!("{e}")))?;
        if s.format != STATUS_FORMAT || s.version != STATUS_VERSION {
            return Err(bad(format!(
                "format {:?} version {}, expected {STATUS_FORMAT:?} version {STATUS_VERSION}",
                s.format, s.version
            )));
        }
        Ok(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status() -> Status {
        Status {
            format: STATUS_FORMAT.into(),
            version: STATUS_VERSION,
            serial: "1".into(),
            frames: 3,
            depth_time_ticks: 9,
            depth_host_ns: 1_700_000_000_000_000_000,
            color_time_ticks: None,
            color_host_ns: Some(4),
            depth_dropped: 1,
            color_dropped: 0,
            frame_bytes: 900_000,
        }
    }

    #[test]
    fn round_trip() {
        assert_eq!(Status::decode(&status().encode()).unwrap(), status());
    }

    #[test]
    fn garbage_is_refused() {
        assert!(Status::decode(b"").is_err());
        assert!(Status::decode(&[0xff; 100]).is_err());
        assert!(Status::decode(&vec![b' '; MAX_STATUS_BYTES + 1]).is_err());
        let mut s = status();
        s.version = 2;
        assert!(Status::decode(&s.encode()).is_err());
    }
}
