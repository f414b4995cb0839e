//! Kinect v2 frames over the network (issue 49): what `kfuse serve` publishes on each sensor's
//! PC and what `kfuse fuse --live` subscribes to on the fusion PC, on **Zenoh**, with the
//! payloads in ROS 2's CDR from [`kfuse_ros_msgs`] (the encoder the rosbag2 layout uses) on
//! the key expressions of ROS 2's `rmw_zenoh`.
//!
//! # Why Zenoh
//!
//! A Kinect v2 needs a USB 3 controller of its own, so a rig of several runs one PC per sensor
//! and sends frames to a fusion PC. Decoding depth on the sensor's PC makes a frame small
//! enough for gigabit Ethernet; measured on the simulated sensor (`benches/live.sh`,
//! BENCHMARKS.md "Live fusion over Zenoh"), one frame on the wire is:
//!
//! | message | bytes |
//! | --- | --- |
//! | `sd/image_depth` (16UC1, 512 × 424) | 434 260 |
//! | `sd/image_ir` (16UC1) | 434 260 |
//! | `hd/image_color/compressed` (the sensor's JPEG, 1920 × 1080) | the JPEG + ~70 (the simulator's: ~0.24 MB) |
//! | `sd/camera_info`, `hd/camera_info` | ~390 each |
//! | `kfuse/status` (JSON) | ~330 |
//!
//! 1.08–1.11 MB a frame measured for the simulated sensor, 266 Mbit/s at 30 Hz (3 sensors per
//! gigabit link); without IR (`kfuse serve --no-ir`) 162 Mbit/s (6 per link).
//! Depth alone is 104 Mbit/s at 30 Hz; raw packets would be 0.72 Gbit/s per sensor.
//! Zenoh carries this without a broker (peers connect directly; a router only where a site
//! needs one), fragments messages of any size (up to the bound set here,
//! [`net::MAX_TRANSPORT_MESSAGE_BYTES`]), drops rather than queues when a link is slow
//! (`CongestionControl::Drop`), and is the transport of ROS 2's `rmw_zenoh` (a Tier 1
//! middleware in REP 2000 from ROS 2 Kilted): a ROS 2 node on `rmw_zenoh` subscribes to these
//! topics as ordinary topics. The `zenoh` crate is pure Rust; with its default features off
//! and only the TCP transport on (QUIC, TLS, WebSocket, UDP, shared memory left out) it adds
//! 167 crates to the workspace's lock file and ~12 CPU-minutes to a first debug build (22 min
//! of wall time on the 2-core machine shared with other builds). The
//! alternatives named in the issue were weighed: LiveScan3D's own TCP protocol and
//! VolumetricCapture's RabbitMQ broker reach no ROS node; DDS (the other ROS 2 transport)
//! has no pure-Rust implementation of its own discovery that ROS 2 interoperates with.
//!
//! # Key expressions
//!
//! `rmw_zenoh` maps a ROS 2 topic to the key `<domain>/<topic name without its leading
//! slash>/<type>/<type hash>`, where the type is `pkg::msg::dds_::Type_` and the hash the
//! type's RIHS01 hash (REP 2011) — established from `rmw_zenoh`'s sources (its design notes
//! and `liveliness_utils.cpp`'s `TopicInfo`; [`keys::topic_key`]), not against a running ROS
//! 2 system, which cannot be installed here. Each sensor publishes, in ROS domain `<d>`
//! (`--domain-id`, else `ROS_DOMAIN_ID`, else 0), under iai_kinect2's names in the namespace
//! `/kinect2/sn_<serial>` of the rosbag2 layout ([`kfuse_ros_msgs::names`]):
//!
//! | ROS topic | type | Zenoh key |
//! | --- | --- | --- |
//! | `/kinect2/sn_<s>/sd/image_depth` | `sensor_msgs/Image` 16UC1 mm | `<d>/kinect2/sn_<s>/sd/image_depth/sensor_msgs::msg::dds_::Image_/RIHS01_d31d…7d47` |
//! | `/kinect2/sn_<s>/sd/image_ir` | `sensor_msgs/Image` 16UC1 | `<d>/kinect2/sn_<s>/sd/image_ir/sensor_msgs::msg::dds_::Image_/RIHS01_d31d…7d47` |
//! | `/kinect2/sn_<s>/hd/image_color/compressed` | `sensor_msgs/CompressedImage` `jpeg` | `<d>/kinect2/sn_<s>/hd/image_color/compressed/sensor_msgs::msg::dds_::CompressedImage_/RIHS01_1564…371a` |
//! | `/kinect2/sn_<s>/sd/camera_info`, `…/hd/camera_info` | `sensor_msgs/CameraInfo` | `<d>/kinect2/sn_<s>/{sd,hd}/camera_info/sensor_msgs::msg::dds_::CameraInfo_/RIHS01_b3df…e275` |
//! | `/tf_static` | `tf2_msgs/TFMessage` | `<d>/tf_static/tf2_msgs::msg::dds_::TFMessage_/RIHS01_e369…f087` |
//! | (kfuse's own) | JSON, [`status::Status`] | `<d>/kinect2/sn_<s>/kfuse/status` |
//!
//! Every message carries `rmw_zenoh`'s attachment ([`attachment`]: sequence number, source
//! time, GID). Not done: `rmw_zenoh`'s liveliness tokens (`@ros2_lv/…`), which its graph
//! cache reads for `ros2 topic list`: a ROS 2 node receives the topics (`ros2 topic echo
//! /kinect2/sn_<s>/sd/camera_info sensor_msgs/msg/CameraInfo`, type given), but the graph
//! does not list them. `/tf_static` is republished every second rather than kept for late
//! joiners by `rmw_zenoh`'s transient-local cache; the latched messages are also answered to a
//! Zenoh query on their keys ([`publish::SensorPublisher`]).
//!
//! # Times
//!
//! Header stamps are the host time (Unix, ns) at which the frame arrived on the sensor's PC
//! (its last USB packet); the sensor's own timestamp (0.125 ms ticks, its own clock) is in
//! the status message. Kinect v2s have no sync port: hosts keep their clocks together with
//! chrony or PTP, and [`matching`] matches frames across sensors by these stamps.
#![deny(missing_docs)]

pub mod attachment;
pub mod keys;
pub mod matching;
pub mod net;
pub mod publish;
pub mod receive;
pub mod status;

pub use keys::LiveTopic;
pub use net::Endpoints;

/// What can go wrong on the network side.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LiveError {
    /// Zenoh refused an operation (opening, declaring, publishing).
    #[error("{0}")]
    Zenoh(String),
    /// A configuration value is wrong.
    #[error("{0}")]
    Config(String),
    /// A message to send could not be encoded.
    #[error("encoding a message: {0}")]
    Encode(String),
    /// A received message was refused.
    #[error("{what}: {why}")]
    Garbage {
        /// What the message should have been.
        what: &'static str,
        /// Why it was refused.
        why: String,
    },
}
