//! ROS 1 serialisation of the messages kfuse reads from ROS 1 bags (iai_kinect2's
//! kinect2_bridge recorded with `rosbag record`): little-endian, no alignment, strings and
//! sequences as a `uint32` count then the elements, fixed arrays without count, and a
//! `std_msgs/Header` with `uint32 seq` before the stamp (`time`: `uint32` seconds and
//! nanoseconds). Decoded into the ROS 2 structs of [`crate::msgs`] (the sequence number is
//! dropped: ROS 2's header has none). Every count is checked against the bytes left before
//! anything is allocated.

use crate::msgs::{
    CameraInfo, CompressedImage, Header, Image, Quaternion, RegionOfInterest, TFMessage, Time,
    Transform, TransformStamped, Vector3,
};

/// A message that does not decode: the field and why.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("ROS 1 message: {0}")]
pub struct Ros1Error(pub String);

/// The fewest bytes a `TransformStamped` takes: seq, stamp, two string counts, seven `float64`.
const MIN_TRANSFORM_STAMPED_BYTES: usize = 4 + 8 + 4 + 4 + 7 * 8;

/// A reader of one ROS 1 message body.
pub struct Ros1Reader<'a> {
    data: &'a [u8],
    at: usize,
}

impl<'a> Ros1Reader<'a> {
    /// A reader of `data`, the whole message.
    pub fn new(data: &'a [u8]) -> Self {
        Self { data, at: 0 }
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], Ros1Error> {
        let left = self.data.len() - self.at;
        if n > left {
            return Err(Ros1Error(format!(
                "{what} needs {n} byte(s) at offset {}, only {left} left (message cut short)",
                self.at
            )));
        }
        let s = &self.data[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }

    /// A `uint8`.
    pub fn u8(&mut self, what: &str) -> Result<u8, Ros1Error> {
        Ok(self.take(1, what)?[0])
    }

    /// A `uint32`.
    pub fn u32(&mut self, what: &str) -> Result<u32, Ros1Error> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    /// A `float64`.
    pub fn f64(&mut self, what: &str) -> Result<f64, Ros1Error> {
        let b = self.take(8, what)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(f64::from_le_bytes(a))
    }

    /// A sequence's count, checked: `count × min_element_bytes` must fit in the bytes left.
    pub fn count(&mut self, min_element_bytes: usize, what: &str) -> Result<usize, Ros1Error> {
        let n = self.u32(what)? as usize;
        let left = self.data.len() - self.at;
        if n.saturating_mul(min_element_bytes.max(1)) > left {
            return Err(Ros1Error(format!(
                "{what} claims {n} element(s) at offset {}, more than the {left} byte(s) left can hold",
                self.at
            )));
        }
        Ok(n)
    }

    /// A `string` (UTF-8).
    pub fn string(&mut self, what: &str) -> Result<String, Ros1Error> {
        let n = self.count(1, what)?;
        let b = self.take(n, what)?;
        String::from_utf8(b.to_vec()).map_err(|_| Ros1Error(format!("{what}: not UTF-8")))
    }

    /// A `uint8[]`.
    pub fn bytes(&mut self, what: &str) -> Result<Vec<u8>, Ros1Error> {
        let n = self.count(1, what)?;
        Ok(self.take(n, what)?.to_vec())
    }

    /// A `float64[N]`.
    pub fn f64_array<const N: usize>(&mut self, what: &str) -> Result<[f64; N], Ros1Error> {
        let mut a = [0.0; N];
        for v in &mut a {
            *v = self.f64(what)?;
        }
        Ok(a)
    }

    /// A `float64[]`.
    pub fn f64_seq(&mut self, what: &str) -> Result<Vec<f64>, Ros1Error> {
        let n = self.count(8, what)?;
        (0..n).map(|_| self.f64(what)).collect()
    }

    /// Checks that the message ended with its last field.
    pub fn finish(self, what: &str) -> Result<(), Ros1Error> {
        let extra = self.data.len() - self.at;
        if extra > 0 {
            return Err(Ros1Error(format!("{what}: {extra} byte(s) after the last field")));
        }
        Ok(())
    }
}

fn header(r: &mut Ros1Reader<'_>) -> Result<Header, Ros1Error> {
    let _seq = r.u32("Header.seq")?;
    let sec = r.u32("Header.stamp.secs")?;
    let nanosec = r.u32("Header.stamp.nsecs")?;
    // ROS 1's `time` is unsigned; ROS 2's seconds are int32 (the same range until 2038).
    let sec = i32::try_from(sec)
        .map_err(|_| Ros1Error(format!("Header.stamp: {sec} s does not fit an int32")))?;
    Ok(Header { stamp: Time { sec, nanosec }, frame_id: r.string("Header.frame_id")? })
}

/// `sensor_msgs/Image` of ROS 1.
pub fn image(data: &[u8]) -> Result<Image, Ros1Error> {
    let mut r = Ros1Reader::new(data);
    let m = Image {
        header: header(&mut r)?,
        height: r.u32("Image.height")?,
        width: r.u32("Image.width")?,
        encoding: r.string("Image.encoding")?,
        is_bigendian: r.u8("Image.is_bigendian")?,
        step: r.u32("Image.step")?,
        data: r.bytes("Image.data")?,
    };
    r.finish("sensor_msgs/Image")?;
    Ok(m)
}

/// `sensor_msgs/CompressedImage` of ROS 1.
pub fn compressed_image(data: &[u8]) -> Result<CompressedImage, Ros1Error> {
    let mut r = Ros1Reader::new(data);
    let m = CompressedImage {
        header: header(&mut r)?,
        format: r.string("CompressedImage.format")?,
        data: r.bytes("CompressedImage.data")?,
    };
    r.finish("sensor_msgs/CompressedImage")?;
    Ok(m)
}

/// `sensor_msgs/CameraInfo` of ROS 1 (`D`, `K`, `R`, `P` as ROS 2's `d`, `k`, `r`, `p`).
pub fn camera_info(data: &[u8]) -> Result<CameraInfo, Ros1Error> {
    let mut r = Ros1Reader::new(data);
    let m = CameraInfo {
        header: header(&mut r)?,
        height: r.u32("CameraInfo.height")?,
        width: r.u32("CameraInfo.width")?,
        distortion_model: r.string("CameraInfo.distortion_model")?,
        d: r.f64_seq("CameraInfo.D")?,
        k: r.f64_array("CameraInfo.K")?,
        r: r.f64_array("CameraInfo.R")?,
        p: r.f64_array("CameraInfo.P")?,
        binning_x: r.u32("CameraInfo.binning_x")?,
        binning_y: r.u32("CameraInfo.binning_y")?,
        roi: RegionOfInterest {
            x_offset: r.u32("RegionOfInterest.x_offset")?,
            y_offset: r.u32("RegionOfInterest.y_offset")?,
            height: r.u32("RegionOfInterest.height")?,
            width: r.u32("RegionOfInterest.width")?,
            do_rectify: r.u8("RegionOfInterest.do_rectify")? != 0,
        },
    };
    r.finish("sensor_msgs/CameraInfo")?;
    Ok(m)
}

/// `tf2_msgs/TFMessage` of ROS 1.
pub fn tf_message(data: &[u8]) -> Result<TFMessage, Ros1Error> {
    let mut r = Ros1Reader::new(data);
    let n = r.count(MIN_TRANSFORM_STAMPED_BYTES, "TFMessage.transforms")?;
    let mut transforms = Vec::with_capacity(n);
    for _ in 0..n {
        let header = header(&mut r)?;
        let child_frame_id = r.string("TransformStamped.child_frame_id")?;
        let [x, y, z] = r.f64_array("Transform.translation")?;
        let [qx, qy, qz, qw] = r.f64_array("Transform.rotation")?;
        transforms.push(TransformStamped {
            header,
            child_frame_id,
            transform: Transform {
                translation: Vector3 { x, y, z },
                rotation: Quaternion { x: qx, y: qy, z: qz, w: qw },
            },
        });
    }
    r.finish("tf2_msgs/TFMessage")?;
    Ok(TFMessage { transforms })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(b: &mut Vec<u8>, t: &str) {
        b.extend_from_slice(&(t.len() as u32).to_le_bytes());
        b.extend_from_slice(t.as_bytes());
    }

    fn image_bytes(data_len: u32, data: &[u8]) -> Vec<u8> {
        let mut b = Vec::new();
        for v in [7u32, 12, 500_000_000] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        s(&mut b, "ir");
        for v in [2u32, 3] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        s(&mut b, "16UC1");
        b.push(0);
        b.extend_from_slice(&6u32.to_le_bytes());
        b.extend_from_slice(&data_len.to_le_bytes());
        b.extend_from_slice(data);
        b
    }

    #[test]
    fn an_image_decodes_field_by_field_and_lengths_are_bounded() {
        let img = image(&image_bytes(12, &[1; 12])).unwrap();
        assert_eq!(img.header.stamp, Time { sec: 12, nanosec: 500_000_000 });
        assert_eq!(img.header.frame_id, "ir");
        assert_eq!((img.height, img.width, img.step), (2, 3, 6));
        assert_eq!(img.encoding, "16UC1");
        assert_eq!(img.data, vec![1; 12]);
        let e = image(&image_bytes(u32::MAX, &[1; 12])).unwrap_err();
        assert!(e.0.contains("Image.data claims 4294967295"), "{e}");
        let e = image(&image_bytes(12, &[1; 11])).unwrap_err();
        assert!(e.0.contains("claims 12"), "{e}");
        let e = image(&image_bytes(11, &[1; 12])).unwrap_err();
        assert!(e.0.contains("1 byte(s) after the last field"), "{e}");
    }
}
