//! The `.msg` schema texts of MCAP's `ros2msg` schema encoding, as rosbag2's MCAP storage
//! plugin (and `rosbags`' `generate_msgdef`) write them: the type's own definition, then for
//! every type it uses, depth first in the order of first use and each once, a line of 80 `=`,
//! `MSG: pkg/Type` and that type's definition. The definitions are the fields of the ROS 2
//! `.msg` files without their comments (constants kept: `PointField`'s datatypes).

/// The line between two definitions of a schema text.
pub const SEPARATOR: &str =
    "================================================================================";

/// A message type's definition: its name as in a `MSG:` line, its own text, the types it uses.
#[derive(Debug)]
pub struct MsgDef {
    /// `pkg/Type`.
    pub name: &'static str,
    /// The fields (and constants), one per line, each line ending in `\n`.
    pub text: &'static str,
    /// The message types its fields use, in field order.
    pub deps: &'static [&'static MsgDef],
}

impl MsgDef {
    /// The whole schema text (module docs).
    pub fn schema(&self) -> String {
        let mut seen: Vec<&'static str> = Vec::new();
        let mut order: Vec<&MsgDef> = Vec::new();
        fn visit<'a>(d: &'a MsgDef, seen: &mut Vec<&'static str>, order: &mut Vec<&'a MsgDef>) {
            for dep in d.deps {
                if !seen.contains(&dep.name) {
                    seen.push(dep.name);
                    order.push(dep);
                    visit(dep, seen, order);
                }
            }
        }
        visit(self, &mut seen, &mut order);
        let mut s = self.text.to_string();
        for d in order {
            s.push_str(SEPARATOR);
            s.push_str("\nMSG: ");
            s.push_str(d.name);
            s.push('\n');
            s.push_str(d.text);
        }
        s
    }
}

/// `builtin_interfaces/Time`.
pub const TIME: MsgDef =
    MsgDef { name: "builtin_interfaces/Time", text: "int32 sec\nuint32 nanosec\n", deps: &[] };

/// `std_msgs/Header`.
pub const HEADER: MsgDef = MsgDef {
    name: "std_msgs/Header",
    text: "builtin_interfaces/Time stamp\nstring frame_id\n",
    deps: &[&TIME],
};

/// `sensor_msgs/Image`.
pub const IMAGE: MsgDef = MsgDef {
    name: "sensor_msgs/Image",
    text: "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n",
    deps: &[&HEADER],
};

/// `sensor_msgs/CompressedImage`.
pub const COMPRESSED_IMAGE: MsgDef = MsgDef {
    name: "sensor_msgs/CompressedImage",
    text: "std_msgs/Header header\nstring format\nuint8[] data\n",
    deps: &[&HEADER],
};

/// `sensor_msgs/RegionOfInterest`.
pub const REGION_OF_INTEREST: MsgDef = MsgDef {
    name: "sensor_msgs/RegionOfInterest",
    text: "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n",
    deps: &[],
};

/// `sensor_msgs/CameraInfo`.
pub const CAMERA_INFO: MsgDef = MsgDef {
    name: "sensor_msgs/CameraInfo",
    text: "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\nsensor_msgs/RegionOfInterest roi\n",
    deps: &[&HEADER, &REGION_OF_INTEREST],
};

/// `sensor_msgs/PointField`.
pub const POINT_FIELD: MsgDef = MsgDef {
    name: "sensor_msgs/PointField",
    text: "uint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\nuint8 INT32=5\nuint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\nstring name\nuint32 offset\nuint8 datatype\nuint32 count\n",
    deps: &[],
};

/// `sensor_msgs/PointCloud2`.
pub const POINT_CLOUD2: MsgDef = MsgDef {
    name: "sensor_msgs/PointCloud2",
    text: "std_msgs/Header header\nuint32 height\nuint32 width\nsensor_msgs/PointField[] fields\nbool is_bigendian\nuint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n",
    deps: &[&HEADER, &POINT_FIELD],
};

/// `geometry_msgs/Vector3`.
pub const VECTOR3: MsgDef =
    MsgDef { name: "geometry_msgs/Vector3", text: "float64 x\nfloat64 y\nfloat64 z\n", deps: &[] };

/// `geometry_msgs/Quaternion` (the `.msg` file's defaults, `w 1`, are not part of the text
/// rosbag2's readers compare).
pub const QUATERNION: MsgDef = MsgDef {
    name: "geometry_msgs/Quaternion",
    text: "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
    deps: &[],
};

/// `geometry_msgs/Transform`.
pub const TRANSFORM: MsgDef = MsgDef {
    name: "geometry_msgs/Transform",
    text: "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
    deps: &[&VECTOR3, &QUATERNION],
};

/// `geometry_msgs/TransformStamped`.
pub const TRANSFORM_STAMPED: MsgDef = MsgDef {
    name: "geometry_msgs/TransformStamped",
    text: "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n",
    deps: &[&HEADER, &TRANSFORM],
};

/// `tf2_msgs/TFMessage`.
pub const TF_MESSAGE: MsgDef = MsgDef {
    name: "tf2_msgs/TFMessage",
    text: "geometry_msgs/TransformStamped[] transforms\n",
    deps: &[&TRANSFORM_STAMPED],
};
