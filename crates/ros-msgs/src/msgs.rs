//! The messages, field for field as their `.msg` files in ROS 2 (`builtin_interfaces`,
//! `std_msgs`, `sensor_msgs`, `geometry_msgs`, `tf2_msgs`; the same in Humble and Jazzy), and
//! their CDR layout ([`crate::cdr`]).

use crate::cdr::{CdrReader, CdrWriter};
use crate::schema::MsgDef;
use crate::{CdrError, schema};

/// A ROS 2 message type kfuse reads and writes.
pub trait Message: Sized {
    /// The type as rosbag2 and MCAP name it: `pkg/msg/Type`.
    const TYPE: &'static str;
    /// The type's `.msg` definition and its dependencies.
    const DEF: &'static MsgDef;

    /// Writes the fields (the body of a message, or this struct inside another).
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError>;

    /// Reads the fields.
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError>;

    /// The whole message: encapsulation header and body.
    fn to_cdr(&self) -> Result<Vec<u8>, CdrError> {
        let mut w = CdrWriter::new();
        self.write(&mut w)?;
        Ok(w.into_bytes())
    }

    /// A whole message. Error: a bad header, a field that runs past the end, a length larger
    /// than the bytes left, or bytes after the last field (beyond a padding of zeros).
    fn from_cdr(message: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(message)?;
        let m = Self::read(&mut r)?;
        r.finish(Self::TYPE)?;
        Ok(m)
    }

    /// The schema text of rosbag2's MCAP files (`ros2msg`): [`MsgDef::schema`].
    fn schema() -> String {
        Self::DEF.schema()
    }
}

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Time {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds, 0 ..= 999 999 999.
    pub nanosec: u32,
}

impl Time {
    /// A time of `ns` nanoseconds. Error: seconds beyond `i32` (year 2038 of Unix time).
    pub fn from_nanos(ns: u64) -> Result<Self, CdrError> {
        let sec = i32::try_from(ns / 1_000_000_000).map_err(|_| CdrError::TimeRange { ns })?;
        Ok(Self { sec, nanosec: (ns % 1_000_000_000) as u32 })
    }
}

impl Message for Time {
    const TYPE: &'static str = "builtin_interfaces/msg/Time";
    const DEF: &'static MsgDef = &schema::TIME;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        w.i32(self.sec);
        w.u32(self.nanosec);
        Ok(())
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Self { sec: r.i32("Time.sec")?, nanosec: r.u32("Time.nanosec")? })
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Header {
    /// Acquisition time.
    pub stamp: Time,
    /// The coordinate frame of the data.
    pub frame_id: String,
}

impl Message for Header {
    const TYPE: &'static str = "std_msgs/msg/Header";
    const DEF: &'static MsgDef = &schema::HEADER;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.stamp.write(w)?;
        w.string(&self.frame_id, "Header.frame_id")
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Self { stamp: Time::read(r)?, frame_id: r.string("Header.frame_id")? })
    }
}

/// `sensor_msgs/Image`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Image {
    /// Header.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`16UC1`, `rgb8`, …).
    pub encoding: String,
    /// 1 when multi-byte samples are big-endian.
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// `step × height` bytes.
    pub data: Vec<u8>,
}

impl Message for Image {
    const TYPE: &'static str = "sensor_msgs/msg/Image";
    const DEF: &'static MsgDef = &schema::IMAGE;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.header.write(w)?;
        w.u32(self.height);
        w.u32(self.width);
        w.string(&self.encoding, "Image.encoding")?;
        w.u8(self.is_bigendian);
        w.u32(self.step);
        w.bytes(&self.data, "Image.data")
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::read(r)?,
            height: r.u32("Image.height")?,
            width: r.u32("Image.width")?,
            encoding: r.string("Image.encoding")?,
            is_bigendian: r.u8("Image.is_bigendian")?,
            step: r.u32("Image.step")?,
            data: r.bytes("Image.data")?,
        })
    }
}

/// `sensor_msgs/CompressedImage`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct CompressedImage {
    /// Header.
    pub header: Header,
    /// `jpeg` or `png` (image_transport's compressed format).
    pub format: String,
    /// The compressed image's bytes.
    pub data: Vec<u8>,
}

impl Message for CompressedImage {
    const TYPE: &'static str = "sensor_msgs/msg/CompressedImage";
    const DEF: &'static MsgDef = &schema::COMPRESSED_IMAGE;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.header.write(w)?;
        w.string(&self.format, "CompressedImage.format")?;
        w.bytes(&self.data, "CompressedImage.data")
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::read(r)?,
            format: r.string("CompressedImage.format")?,
            data: r.bytes("CompressedImage.data")?,
        })
    }
}

/// `sensor_msgs/RegionOfInterest`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RegionOfInterest {
    /// Leftmost column.
    pub x_offset: u32,
    /// Topmost row.
    pub y_offset: u32,
    /// Rows (0: the full image).
    pub height: u32,
    /// Columns (0: the full image).
    pub width: u32,
    /// Whether the region is to be rectified.
    pub do_rectify: bool,
}

impl Message for RegionOfInterest {
    const TYPE: &'static str = "sensor_msgs/msg/RegionOfInterest";
    const DEF: &'static MsgDef = &schema::REGION_OF_INTEREST;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        w.u32(self.x_offset);
        w.u32(self.y_offset);
        w.u32(self.height);
        w.u32(self.width);
        w.bool(self.do_rectify);
        Ok(())
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Self {
            x_offset: r.u32("RegionOfInterest.x_offset")?,
            y_offset: r.u32("RegionOfInterest.y_offset")?,
            height: r.u32("RegionOfInterest.height")?,
            width: r.u32("RegionOfInterest.width")?,
            do_rectify: r.bool("RegionOfInterest.do_rectify")?,
        })
    }
}

/// `sensor_msgs/CameraInfo`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CameraInfo {
    /// Header (`frame_id`: the camera's optical frame).
    pub header: Header,
    /// Rows of the calibrated image.
    pub height: u32,
    /// Columns of the calibrated image.
    pub width: u32,
    /// `plumb_bob`, `rational_polynomial`, …
    pub distortion_model: String,
    /// Distortion coefficients (plumb_bob: k1, k2, t1, t2, k3).
    pub d: Vec<f64>,
    /// Intrinsic matrix, row-major.
    pub k: [f64; 9],
    /// Rectification rotation, row-major.
    pub r: [f64; 9],
    /// Projection matrix (3 × 4), row-major.
    pub p: [f64; 12],
    /// Horizontal binning.
    pub binning_x: u32,
    /// Vertical binning.
    pub binning_y: u32,
    /// Region of interest.
    pub roi: RegionOfInterest,
}

impl Message for CameraInfo {
    const TYPE: &'static str = "sensor_msgs/msg/CameraInfo";
    const DEF: &'static MsgDef = &schema::CAMERA_INFO;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.header.write(w)?;
        w.u32(self.height);
        w.u32(self.width);
        w.string(&self.distortion_model, "CameraInfo.distortion_model")?;
        w.count(self.d.len(), "CameraInfo.d")?;
        w.f64s(&self.d);
        w.f64s(&self.k);
        w.f64s(&self.r);
        w.f64s(&self.p);
        w.u32(self.binning_x);
        w.u32(self.binning_y);
        self.roi.write(w)
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::read(r)?,
            height: r.u32("CameraInfo.height")?,
            width: r.u32("CameraInfo.width")?,
            distortion_model: r.string("CameraInfo.distortion_model")?,
            d: r.f64_seq("CameraInfo.d")?,
            k: r.f64_array("CameraInfo.k")?,
            r: r.f64_array("CameraInfo.r")?,
            p: r.f64_array("CameraInfo.p")?,
            binning_x: r.u32("CameraInfo.binning_x")?,
            binning_y: r.u32("CameraInfo.binning_y")?,
            roi: RegionOfInterest::read(r)?,
        })
    }
}

/// `sensor_msgs/PointField`'s `datatype` of a `float32`.
pub const POINT_FIELD_FLOAT32: u8 = 7;
/// `sensor_msgs/PointField`'s `datatype` of a `uint32`.
pub const POINT_FIELD_UINT32: u8 = 6;

/// `sensor_msgs/PointField`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct PointField {
    /// Field name (`x`, `rgb`, …).
    pub name: String,
    /// Byte offset in the point.
    pub offset: u32,
    /// Type of the elements ([`POINT_FIELD_FLOAT32`], …).
    pub datatype: u8,
    /// Elements in the field.
    pub count: u32,
}

/// The fewest bytes a `PointField` takes in CDR: the name's length and NUL, the datatype, and
/// two `uint32`s (alignment padding aside).
const MIN_POINT_FIELD_BYTES: usize = 4 + 1 + 4 + 1 + 4;

impl Message for PointField {
    const TYPE: &'static str = "sensor_msgs/msg/PointField";
    const DEF: &'static MsgDef = &schema::POINT_FIELD;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        w.string(&self.name, "PointField.name")?;
        w.u32(self.offset);
        w.u8(self.datatype);
        w.u32(self.count);
        Ok(())
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Self {
            name: r.string("PointField.name")?,
            offset: r.u32("PointField.offset")?,
            datatype: r.u8("PointField.datatype")?,
            count: r.u32("PointField.count")?,
        })
    }
}

/// `sensor_msgs/PointCloud2`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct PointCloud2 {
    /// Header.
    pub header: Header,
    /// Rows (1 for an unordered cloud).
    pub height: u32,
    /// Points per row.
    pub width: u32,
    /// The fields of a point.
    pub fields: Vec<PointField>,
    /// Whether multi-byte fields are big-endian.
    pub is_bigendian: bool,
    /// Bytes per point.
    pub point_step: u32,
    /// Bytes per row.
    pub row_step: u32,
    /// `row_step × height` bytes.
    pub data: Vec<u8>,
    /// No invalid points.
    pub is_dense: bool,
}

impl Message for PointCloud2 {
    const TYPE: &'static str = "sensor_msgs/msg/PointCloud2";
    const DEF: &'static MsgDef = &schema::POINT_CLOUD2;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.header.write(w)?;
        w.u32(self.height);
        w.u32(self.width);
        w.count(self.fields.len(), "PointCloud2.fields")?;
        for f in &self.fields {
            f.write(w)?;
        }
        w.bool(self.is_bigendian);
        w.u32(self.point_step);
        w.u32(self.row_step);
        w.bytes(&self.data, "PointCloud2.data")?;
        w.bool(self.is_dense);
        Ok(())
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        let header = Header::read(r)?;
        let height = r.u32("PointCloud2.height")?;
        let width = r.u32("PointCloud2.width")?;
        let n = r.count(MIN_POINT_FIELD_BYTES, "PointCloud2.fields")?;
        let fields = (0..n).map(|_| PointField::read(r)).collect::<Result<_, _>>()?;
        Ok(Self {
            header,
            height,
            width,
            fields,
            is_bigendian: r.bool("PointCloud2.is_bigendian")?,
            point_step: r.u32("PointCloud2.point_step")?,
            row_step: r.u32("PointCloud2.row_step")?,
            data: r.bytes("PointCloud2.data")?,
            is_dense: r.bool("PointCloud2.is_dense")?,
        })
    }
}

/// `geometry_msgs/Vector3`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

impl Message for Vector3 {
    const TYPE: &'static str = "geometry_msgs/msg/Vector3";
    const DEF: &'static MsgDef = &schema::VECTOR3;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        w.f64s(&[self.x, self.y, self.z]);
        Ok(())
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        let [x, y, z] = r.f64_array("Vector3")?;
        Ok(Self { x, y, z })
    }
}

/// `geometry_msgs/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

impl Default for Quaternion {
    /// The identity, as the `.msg` file's default (`float64 w 1`).
    fn default() -> Self {
        Self { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }
    }
}

impl Message for Quaternion {
    const TYPE: &'static str = "geometry_msgs/msg/Quaternion";
    const DEF: &'static MsgDef = &schema::QUATERNION;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        w.f64s(&[self.x, self.y, self.z, self.w]);
        Ok(())
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        let [x, y, z, w] = r.f64_array("Quaternion")?;
        Ok(Self { x, y, z, w })
    }
}

/// `geometry_msgs/Transform`: the child frame's pose in the parent frame (`X_parent = R
/// X_child + t`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Transform {
    /// t, metres.
    pub translation: Vector3,
    /// R as a unit quaternion.
    pub rotation: Quaternion,
}

impl Message for Transform {
    const TYPE: &'static str = "geometry_msgs/msg/Transform";
    const DEF: &'static MsgDef = &schema::TRANSFORM;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.translation.write(w)?;
        self.rotation.write(w)
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Self { translation: Vector3::read(r)?, rotation: Quaternion::read(r)? })
    }
}

/// `geometry_msgs/TransformStamped`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TransformStamped {
    /// Header (`frame_id`: the parent frame).
    pub header: Header,
    /// The child frame.
    pub child_frame_id: String,
    /// The child's pose in the parent.
    pub transform: Transform,
}

/// The fewest bytes a `TransformStamped` takes in CDR: the header's time and frame length,
/// its NUL, the child frame's length and NUL, seven `float64`s (alignment padding aside).
const MIN_TRANSFORM_STAMPED_BYTES: usize = 8 + 4 + 1 + 4 + 1 + 7 * 8;

impl Message for TransformStamped {
    const TYPE: &'static str = "geometry_msgs/msg/TransformStamped";
    const DEF: &'static MsgDef = &schema::TRANSFORM_STAMPED;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        self.header.write(w)?;
        w.string(&self.child_frame_id, "TransformStamped.child_frame_id")?;
        self.transform.write(w)
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::read(r)?,
            child_frame_id: r.string("TransformStamped.child_frame_id")?,
            transform: Transform::read(r)?,
        })
    }
}

/// `tf2_msgs/TFMessage` (`/tf`, `/tf_static`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TFMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}

impl Message for TFMessage {
    const TYPE: &'static str = "tf2_msgs/msg/TFMessage";
    const DEF: &'static MsgDef = &schema::TF_MESSAGE;
    fn write(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        w.count(self.transforms.len(), "TFMessage.transforms")?;
        for t in &self.transforms {
            t.write(w)?;
        }
        Ok(())
    }
    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        let n = r.count(MIN_TRANSFORM_STAMPED_BYTES, "TFMessage.transforms")?;
        let transforms = (0..n).map(|_| TransformStamped::read(r)).collect::<Result<_, _>>()?;
        Ok(Self { transforms })
    }
}
