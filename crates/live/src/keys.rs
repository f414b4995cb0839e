//! Key expressions: one sensor's ROS 2 topics as `rmw_zenoh` names them (crate docs, "Key
//! expressions"), kfuse's own status key, and the parsing of a received key back into a sensor
//! and a topic.

use kfuse_ros_msgs::names::{self, topic};

use kfuse_ros_msgs::{CameraInfo, CompressedImage, Image, Message, TFMessage};

/// The ROS domain when neither `--domain-id` nor `ROS_DOMAIN_ID` gives one: 0, ROS 2's default.
pub const DEFAULT_DOMAIN_ID: u32 = 0;

/// Highest ROS domain id: 232 (ROS 2's limit for DDS port arithmetic; `rmw_zenoh` takes the
/// same range).
pub const MAX_DOMAIN_ID: u32 = 232;

/// The topic of kfuse's own status message under a sensor's namespace (not a ROS type: JSON,
/// [`crate::status::Status`]).
pub const STATUS_TOPIC: &str = "kfuse/status";

/// The RIHS01 type hashes (REP 2011) of the message types kfuse publishes, as ROS 2 Jazzy (and
/// Humble's type descriptions; the definitions are the same) computes them: the last chunk of
/// `rmw_zenoh`'s topic keys. Checked against `rosbags`' `hash_rihs01` by the Python test
/// (`python/tests/test_live.py`).
pub const TYPE_HASHES: [(&str, &str); 4] = [
    (Image::TYPE, "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"),
    (
        CompressedImage::TYPE,
        "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a",
    ),
    (CameraInfo::TYPE, "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275"),
    (TFMessage::TYPE, "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"),
];

/// A topic `kfuse serve` publishes for one sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LiveTopic {
    /// `sd/image_depth`: `sensor_msgs/Image` 16UC1, millimetres.
    Depth,
    /// `sd/image_ir`: `sensor_msgs/Image` 16UC1.
    Ir,
    /// `hd/image_color/compressed`: `sensor_msgs/CompressedImage`, the sensor's JPEG.
    Color,
    /// `sd/camera_info`.
    DepthInfo,
    /// `hd/camera_info`.
    ColorInfo,
    /// `/tf_static` (global).
    TfStatic,
    /// `kfuse/status`: kfuse's JSON status (frame counters, drops, times).
    Status,
}

/// Every topic, in the order [`LiveTopic::index`] numbers them.
pub const LIVE_TOPICS: [LiveTopic; 7] = [
    LiveTopic::Depth,
    LiveTopic::Ir,
    LiveTopic::Color,
    LiveTopic::DepthInfo,
    LiveTopic::ColorInfo,
    LiveTopic::TfStatic,
    LiveTopic::Status,
];

/// Largest depth or IR message accepted: 9 MiB (a 512 × 424 16-bit image is 434 kB; a
/// 1920 × 1080 one, depth registered to the colour grid, 4.1 MB; a 32-bit one 8.3 MB).
pub const MAX_IMAGE_BYTES: usize = 9 << 20;
/// Largest colour message accepted: 8 MiB (the Kinect's JPEG of 1920 × 1080 is 0.2–1 MB).
pub const MAX_JPEG_BYTES: usize = 8 << 20;
/// Largest `CameraInfo` or `TFMessage` accepted: 64 kB (they are ~0.4–1 kB).
pub const MAX_SMALL_BYTES: usize = 64 << 10;
/// Largest status message accepted: 16 kB (it is ~0.5 kB).
pub const MAX_STATUS_BYTES: usize = 16 << 10;

impl LiveTopic {
    /// Position in [`LIVE_TOPICS`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// The ROS topic name for the sensor `serial` (`/kinect2/sn_<serial>/…`, `/tf_static`).
    pub fn ros_name(self, serial: &str) -> String {
        let ns = names::namespace(serial);
        let rel = match self {
            LiveTopic::Depth => topic::DEPTH,
            LiveTopic::Ir => topic::IR,
            LiveTopic::Color => topic::COLOR,
            LiveTopic::DepthInfo => topic::DEPTH_INFO,
            LiveTopic::ColorInfo => topic::COLOR_INFO,
            LiveTopic::TfStatic => return topic::TF_STATIC.into(),
            LiveTopic::Status => STATUS_TOPIC,
        };
        format!("{ns}/{rel}")
    }

    /// The ROS message type (`pkg/msg/Type`); `None` for kfuse's status.
    pub fn ros_type(self) -> Option<&'static str> {
        match self {
            LiveTopic::Depth | LiveTopic::Ir => Some(Image::TYPE),
            LiveTopic::Color => Some(CompressedImage::TYPE),
            LiveTopic::DepthInfo | LiveTopic::ColorInfo => Some(CameraInfo::TYPE),
            LiveTopic::TfStatic => Some(TFMessage::TYPE),
            LiveTopic::Status => None,
        }
    }

    /// The key expression of this topic of sensor `serial` in ROS domain `domain`
    /// ([`topic_key`]; the status: `<domain>/kinect2/sn_<serial>/kfuse/status`).
    pub fn key(self, domain: u32, serial: &str) -> String {
        let name = self.ros_name(serial);
        match self.ros_type() {
            Some(t) => topic_key(domain, &name, t),
            None => format!("{domain}/{}", strip_slashes(&name)),
        }
    }

    /// Largest payload accepted on this topic (checked before any decoding).
    pub fn max_bytes(self) -> usize {
        match self {
            LiveTopic::Depth | LiveTopic::Ir => MAX_IMAGE_BYTES,
            LiveTopic::Color => MAX_JPEG_BYTES,
            LiveTopic::DepthInfo | LiveTopic::ColorInfo | LiveTopic::TfStatic => MAX_SMALL_BYTES,
            LiveTopic::Status => MAX_STATUS_BYTES,
        }
    }
}

/// `rmw_zenoh`'s type name of a ROS type: `sensor_msgs/msg/Image` →
/// `sensor_msgs::msg::dds_::Image_` (its `type_support_common.cpp`).
pub fn dds_type_name(ros_type: &str) -> String {
    let mut parts: Vec<&str> = ros_type.split('/').collect();
    let name = parts.pop().unwrap_or_default();
    format!("{}::dds_::{name}_", parts.join("::"))
}

/// The RIHS01 hash of one of kfuse's message types ([`TYPE_HASHES`]).
pub fn type_hash(ros_type: &str) -> Option<&'static str> {
    TYPE_HASHES.iter().find(|(t, _)| *t == ros_type).map(|(_, h)| *h)
}

/// `rmw_zenoh`'s key expression of a topic: `<domain>/<name without its leading and trailing
/// slash>/<dds type name>/<type hash>` (its `liveliness_utils.cpp`, `TopicInfo`); a type
/// without a known hash gets `TypeHashNotSupported`, what `rmw_zenoh` writes on ROS 2 Humble.
pub fn topic_key(domain: u32, ros_name: &str, ros_type: &str) -> String {
    let hash = type_hash(ros_type).unwrap_or("TypeHashNotSupported");
    format!("{domain}/{}/{}/{hash}", strip_slashes(ros_name), dds_type_name(ros_type))
}

fn strip_slashes(name: &str) -> &str {
    let name = name.strip_prefix('/').unwrap_or(name);
    name.strip_suffix('/').unwrap_or(name)
}

/// The key expression matching every topic of sensor `serial` (its namespace), `<domain>/kinect2/sn_<serial>/**`.
pub fn sensor_keys(domain: u32, serial: &str) -> String {
    format!("{domain}/{}/**", strip_slashes(&names::namespace(serial)))
}

/// Which topic a received key is, for sensor `serial`: `None` for any key that is not exactly
/// one of kfuse's keys of that sensor (another publisher's topic, another type or type hash).
pub fn parse_sensor_key(domain: u32, serial: &str, key: &str) -> Option<LiveTopic> {
    LIVE_TOPICS
        .into_iter()
        .filter(|t| *t != LiveTopic::TfStatic)
        .find(|t| t.key(domain, serial) == key)
}

/// The ROS domain: `ROS_DOMAIN_ID` when set to a number in 0..=[`MAX_DOMAIN_ID`], else
/// [`DEFAULT_DOMAIN_ID`]. Error: a value that is set but no such number.
pub fn domain_from_env() -> Result<u32, String> {
    match std::env::var("ROS_DOMAIN_ID") {
        Ok(v) if v.trim().is_empty() => Ok(DEFAULT_DOMAIN_ID),
        Ok(v) => parse_domain(v.trim()).map_err(|e| format!("ROS_DOMAIN_ID={v}: {e}")),
        Err(_) => Ok(DEFAULT_DOMAIN_ID),
    }
}

/// Parses a ROS domain id (0..=[`MAX_DOMAIN_ID`]).
pub fn parse_domain(s: &str) -> Result<u32, String> {
    match s.parse::<u32>() {
        Ok(d) if d <= MAX_DOMAIN_ID => Ok(d),
        _ => Err(format!("`{s}` is not a ROS domain id (0-{MAX_DOMAIN_ID})")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_rmw_zenoh_topic_keys() {
        assert_eq!(dds_type_name("sensor_msgs/msg/Image"), "sensor_msgs::msg::dds_::Image_");
        assert_eq!(
            LiveTopic::Depth.key(0, "000000000001"),
            "0/kinect2/sn_000000000001/sd/image_depth/sensor_msgs::msg::dds_::Image_/RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"
        );
        assert_eq!(
            LiveTopic::TfStatic.key(3, "x"),
            "3/tf_static/tf2_msgs::msg::dds_::TFMessage_/RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
        );
        assert_eq!(LiveTopic::Status.key(0, "A-1"), "0/kinect2/sn_A_1/kfuse/status");
        assert_eq!(sensor_keys(7, "A-1"), "7/kinect2/sn_A_1/**");
    }

    #[test]
    fn every_key_parses_back_and_others_do_not() {
        for t in LIVE_TOPICS.into_iter().filter(|t| *t != LiveTopic::TfStatic) {
            assert_eq!(parse_sensor_key(0, "S1", &t.key(0, "S1")), Some(t), "{t:?}");
            assert_eq!(parse_sensor_key(1, "S1", &t.key(0, "S1")), None, "{t:?} other domain");
            assert_eq!(parse_sensor_key(0, "S2", &t.key(0, "S1")), None, "{t:?} other sensor");
        }
        let wrong_hash = "0/kinect2/sn_S1/sd/image_depth/sensor_msgs::msg::dds_::Image_/RIHS01_00";
        assert_eq!(parse_sensor_key(0, "S1", wrong_hash), None);
        assert_eq!(parse_sensor_key(0, "S1", "0/kinect2/sn_S1/points"), None);
    }

    #[test]
    fn domain_ids_are_bounded() {
        assert_eq!(parse_domain("0"), Ok(0));
        assert_eq!(parse_domain("232"), Ok(232));
        assert!(parse_domain("233").is_err());
        assert!(parse_domain("-1").is_err());
    }
}
