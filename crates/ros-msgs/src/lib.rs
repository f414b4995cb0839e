//! The ROS 2 standard messages kfuse writes into rosbag2/MCAP recordings (and later onto the
//! network), without ROS: their CDR encoding ([`cdr`]: XCDR1, little endian, behind the
//! `00 01 00 00` encapsulation header) and their `.msg` schema texts in the `ros2msg` form of
//! rosbag2's MCAP files ([`schema`]).
//!
//! | message | type |
//! | --- | --- |
//! | `builtin_interfaces/Time` | [`Time`] |
//! | `std_msgs/Header` | [`Header`] |
//! | `sensor_msgs/Image` | [`Image`] |
//! | `sensor_msgs/CompressedImage` | [`CompressedImage`] |
//! | `sensor_msgs/CameraInfo` (`RegionOfInterest`) | [`CameraInfo`] ([`RegionOfInterest`]) |
//! | `sensor_msgs/PointCloud2` (`PointField`) | [`PointCloud2`] ([`PointField`]) |
//! | `geometry_msgs/{TransformStamped, Transform, Vector3, Quaternion}` | [`TransformStamped`], [`Transform`], [`Vector3`], [`Quaternion`] |
//! | `tf2_msgs/TFMessage` | [`TFMessage`] |
//!
//! Topic and frame names, one rule for the rosbag2 layout and the live topics: [`names`].
//!
//! Every type implements [`Message`]: `to_cdr`, `from_cdr`, `schema`, and its rosbag2 type name.
//! Decoding checks every length against the bytes left before allocating: a message claiming
//! gigabytes fails with [`CdrError::LengthTooLarge`], one cut short with
//! [`CdrError::Truncated`].
#![deny(missing_docs)]

pub mod cdr;
mod msgs;
pub mod names;
pub mod ros1;
pub mod schema;

pub use msgs::*;

/// What can be wrong with a message being encoded or decoded; each names the field.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CdrError {
    /// The message ends before a field does.
    #[error(
        "CDR: {what} needs {need} byte(s) at offset {offset} of the body, only {left} left (message cut short)"
    )]
    Truncated {
        /// The field.
        what: &'static str,
        /// Offset in the body (after the encapsulation header).
        offset: usize,
        /// Bytes the field needs.
        need: usize,
        /// Bytes left.
        left: usize,
    },
    /// A string or sequence claims more elements than the bytes left could hold.
    #[error(
        "CDR: {what} claims {claimed} element(s) at offset {offset} of the body, more than the {left} byte(s) left can hold"
    )]
    LengthTooLarge {
        /// The field.
        what: &'static str,
        /// Offset in the body just after the count.
        offset: usize,
        /// The count the message states.
        claimed: usize,
        /// Bytes left.
        left: usize,
    },
    /// An encapsulation header other than little-endian plain CDR.
    #[error(
        "CDR: encapsulation header {0:02x?}, expected [00, 01, 00, 00] (little-endian XCDR1, what ROS 2 writes)"
    )]
    Encapsulation([u8; 4]),
    /// A string without its NUL or not UTF-8.
    #[error("CDR: {what}: {why}")]
    String {
        /// The field.
        what: &'static str,
        /// What is wrong.
        why: &'static str,
    },
    /// A `bool` byte other than 0 or 1.
    #[error("CDR: {what}: bool byte {value}, expected 0 or 1")]
    Bool {
        /// The field.
        what: &'static str,
        /// The byte.
        value: u8,
    },
    /// Bytes after the message's last field (more than a padding of zeros).
    #[error("CDR: {what}: {extra} byte(s) after the last field")]
    Trailing {
        /// The message type.
        what: &'static str,
        /// How many.
        extra: usize,
    },
    /// A string or sequence longer than CDR's `uint32` count can state.
    #[error("CDR: {what}: {len} elements, more than a CDR count (uint32) can state")]
    TooLong {
        /// The field.
        what: &'static str,
        /// Its length.
        len: usize,
    },
    /// A string to encode holds a NUL (readers would cut it there).
    #[error("CDR: {what}: the text holds a NUL byte")]
    NulInString {
        /// The field.
        what: &'static str,
    },
    /// A time whose seconds do not fit `builtin_interfaces/Time`'s `int32`.
    #[error("time {ns} ns: its seconds do not fit builtin_interfaces/Time's int32")]
    TimeRange {
        /// The time.
        ns: u64,
    },
}

#[cfg(test)]
mod tests;
