//! The names kfuse gives its ROS topics and frames, one rule for every sink (the rosbag2 layout
//! of `kfuse fuse --layout rosbag2` and the live topics of `kfuse serve`): iai_kinect2's topic
//! names under a per-sensor namespace `/kinect2/sn_<serial>` (a ROS name token may not start
//! with a digit, and a Kinect's serial does), its optical frame names.

/// The sensor's namespace: `/kinect2/sn_<serial>`, every character of the serial that is not
/// `[A-Za-z0-9_]` replaced by `_` (ROS names allow no other).
pub fn namespace(serial: &str) -> String {
    format!("/kinect2/sn_{}", name_token(serial))
}

/// `serial` as a ROS name token: every character that is not `[A-Za-z0-9_]` replaced by `_`.
pub fn name_token(serial: &str) -> String {
    serial.chars().map(|c| if c.is_ascii_alphanumeric() || c == '_' { c } else { '_' }).collect()
}

/// The sensor's optical frames: `(IR/depth, colour)`, `kinect2_<serial>_{ir,rgb}_optical_frame`.
pub fn optical_frames(serial: &str) -> (String, String) {
    let s = name_token(serial);
    (format!("kinect2_{s}_ir_optical_frame"), format!("kinect2_{s}_rgb_optical_frame"))
}

/// The topics of one sensor, relative to its [`namespace`] (`/tf_static` is global).
pub mod topic {
    /// Depth, 16UC1 millimetres, 512 × 424.
    pub const DEPTH: &str = "sd/image_depth";
    /// IR amplitude, 16UC1.
    pub const IR: &str = "sd/image_ir";
    /// Depth registered on the colour grid.
    pub const DEPTH_RECT: &str = "hd/image_depth_rect";
    /// The sensor's JPEG.
    pub const COLOR: &str = "hd/image_color/compressed";
    /// The depth camera's `CameraInfo`.
    pub const DEPTH_INFO: &str = "sd/camera_info";
    /// The colour camera's `CameraInfo`.
    pub const COLOR_INFO: &str = "hd/camera_info";
    /// The cloud on the depth grid (`sensor_msgs/PointCloud2`, IR optical frame): iai_kinect2's
    /// `sd/points`, which its launch file makes with depth_image_proc from the `sd/` images.
    pub const POINTS: &str = "sd/points";
    /// The static transforms (global, not under the namespace).
    pub const TF_STATIC: &str = "/tf_static";
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_follow_ros_rules_and_iai_kinect2() {
        assert_eq!(namespace("003415165047"), "/kinect2/sn_003415165047");
        assert_eq!(namespace("A-1.2"), "/kinect2/sn_A_1_2");
        assert_eq!(
            optical_frames("1"),
            ("kinect2_1_ir_optical_frame".into(), "kinect2_1_rgb_optical_frame".into())
        );
    }
}
