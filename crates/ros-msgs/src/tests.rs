//! Byte layouts derived by hand from the CDR rules of [`crate::cdr`], round trips, schema
//! texts, and bad input.

use super::*;
use crate::cdr::{CdrReader, CdrWriter, ENCAPSULATION_CDR_LE};

fn header(sec: i32, nanosec: u32, frame: &str) -> Header {
    Header { stamp: Time { sec, nanosec }, frame_id: frame.into() }
}

fn camera_info() -> CameraInfo {
    CameraInfo {
        header: header(12, 345_678_901, "kinect2_rgb_optical_frame"),
        height: 1080,
        width: 1920,
        distortion_model: "plumb_bob".into(),
        d: vec![0.01, -0.02, 0.001, -0.0005, 0.003],
        k: [1060.5, 0.0, 959.5, 0.0, 1061.25, 539.5, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [1060.5, 0.0, 959.5, -55.1, 0.0, 1061.25, 539.5, 0.0, 0.0, 0.0, 1.0, 0.0],
        binning_x: 0,
        binning_y: 0,
        roi: RegionOfInterest { x_offset: 1, y_offset: 2, height: 3, width: 4, do_rectify: true },
    }
}

fn tf() -> TFMessage {
    TFMessage {
        transforms: vec![TransformStamped {
            header: header(0, 0, "a"),
            child_frame_id: "b".into(),
            transform: Transform {
                translation: Vector3 { x: 1.0, y: 2.0, z: 3.0 },
                rotation: Quaternion::default(),
            },
        }],
    }
}

fn cloud() -> PointCloud2 {
    let field =
        |name: &str, offset, datatype| PointField { name: name.into(), offset, datatype, count: 1 };
    PointCloud2 {
        header: header(7, 8, "depth"),
        height: 1,
        width: 2,
        fields: vec![
            field("x", 0, POINT_FIELD_FLOAT32),
            field("y", 4, POINT_FIELD_FLOAT32),
            field("z", 8, POINT_FIELD_FLOAT32),
            field("rgb", 12, POINT_FIELD_UINT32),
        ],
        is_bigendian: false,
        point_step: 16,
        row_step: 32,
        data: (0..32).collect(),
        is_dense: true,
    }
}

/// Header { stamp 1 700 000 000 s + 5 ns, frame_id "ir" }. Body offsets: `sec` int32 at 0
/// (1 700 000 000 = 0x6553F100, little endian `00 F1 53 65`), `nanosec` uint32 at 4, the
/// string's length at 8 (3: "ir" and its NUL), its bytes at 12..15; nothing after the last
/// field, so 4 + 15 = 19 bytes.
#[test]
fn header_bytes_follow_the_cdr_rules() {
    let bytes = header(1_700_000_000, 5, "ir").to_cdr().unwrap();
    let expected: &[u8] = &[
        0x00, 0x01, 0x00, 0x00, // encapsulation: CDR_LE, options 0
        0x00, 0xF1, 0x53, 0x65, // sec
        0x05, 0x00, 0x00, 0x00, // nanosec
        0x03, 0x00, 0x00, 0x00, // frame_id length, NUL counted
        b'i', b'r', 0x00, // frame_id
    ];
    assert_eq!(bytes, expected);
    assert_eq!(Header::from_cdr(&bytes).unwrap(), header(1_700_000_000, 5, "ir"));
}

/// Image { header (0 s, 0 ns, "ab"), 2 × 1, "16UC1", little endian, step 2, data 1 2 3 4 }.
/// Body offsets: sec 0, nanosec 4, frame_id length 8 (3), "ab\0" 12..15, one pad byte to 16
/// (uint32 alignment), height 16, width 20, encoding length 24 (6), "16UC1\0" 28..34,
/// is_bigendian 34, one pad byte to 36, step 36, data count 40, data 44..48.
#[test]
fn image_bytes_pad_uint32_fields_to_four() {
    let img = Image {
        header: header(0, 0, "ab"),
        height: 2,
        width: 1,
        encoding: "16UC1".into(),
        is_bigendian: 0,
        step: 2,
        data: vec![1, 2, 3, 4],
    };
    let bytes = img.to_cdr().unwrap();
    let mut expected = ENCAPSULATION_CDR_LE.to_vec();
    expected.extend([0, 0, 0, 0, 0, 0, 0, 0]); // sec, nanosec
    expected.extend([3, 0, 0, 0, b'a', b'b', 0]); // frame_id
    expected.push(0); // pad to 16
    expected.extend([2, 0, 0, 0, 1, 0, 0, 0]); // height, width
    expected.extend([6, 0, 0, 0, b'1', b'6', b'U', b'C', b'1', 0]); // encoding
    expected.push(0); // is_bigendian
    expected.push(0); // pad to 36
    expected.extend([2, 0, 0, 0]); // step
    expected.extend([4, 0, 0, 0, 1, 2, 3, 4]); // data
    assert_eq!(bytes, expected);
    assert_eq!(bytes.len(), 4 + 48);
    assert_eq!(Image::from_cdr(&bytes).unwrap(), img);
}

/// TFMessage with one transform (frames "a" → "b", t = (1, 2, 3), identity rotation). Body
/// offsets: count 0 (1), sec 4, nanosec 8, frame_id length 12 (2), "a\0" 16..18, two pad bytes
/// to 20, child length 20 (2), "b\0" 24..26, six pad bytes to 32 (float64 alignment, counted
/// from after the encapsulation header), seven float64 at 32..88.
#[test]
fn transform_bytes_pad_float64_to_eight_after_the_header() {
    let bytes = tf().to_cdr().unwrap();
    let mut expected = ENCAPSULATION_CDR_LE.to_vec();
    expected.extend([1, 0, 0, 0]); // one transform
    expected.extend([0; 8]); // stamp
    expected.extend([2, 0, 0, 0, b'a', 0, 0, 0]); // frame_id, 2 pad
    expected.extend([2, 0, 0, 0, b'b', 0]); // child_frame_id
    expected.extend([0; 6]); // pad to 32
    for v in [1.0f64, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0] {
        expected.extend(v.to_le_bytes());
    }
    assert_eq!(bytes, expected);
    assert_eq!(bytes.len(), 4 + 88);
    // 1.0 as IEEE 754 binary64, little endian.
    assert_eq!(&bytes[4 + 32..4 + 40], &[0, 0, 0, 0, 0, 0, 0xF0, 0x3F]);
    assert_eq!(TFMessage::from_cdr(&bytes).unwrap(), tf());
}

/// CameraInfo with frame "kinect2_rgb_optical_frame" (25 characters + NUL = 26): body offsets
/// sec 0, nanosec 4, length 8, text 12..38, pad to 40, height 40, width 44, model length 48
/// (10), "plumb_bob\0" 52..62, pad to 64, d count 64 (5), pad to 72, d 72..112, k 112..184,
/// r 184..256, p 256..352, binning 352..360, roi 360..376, do_rectify 376: 377 bytes.
#[test]
fn camera_info_layout_and_round_trip() {
    let ci = camera_info();
    let bytes = ci.to_cdr().unwrap();
    assert_eq!(bytes.len(), 4 + 377);
    let at = |o: usize| &bytes[4 + o..];
    assert_eq!(&at(64)[..4], &5u32.to_le_bytes());
    assert_eq!(&at(68)[..4], &[0, 0, 0, 0]);
    assert_eq!(&at(72)[..8], &0.01f64.to_le_bytes());
    assert_eq!(&at(112)[..8], &1060.5f64.to_le_bytes());
    assert_eq!(&at(256 + 3 * 8)[..8], &(-55.1f64).to_le_bytes());
    assert_eq!(at(376), &[1]);
    assert_eq!(CameraInfo::from_cdr(&bytes).unwrap(), ci);
}

#[test]
fn every_type_round_trips() {
    let c = CompressedImage {
        header: header(3, 4, "rgb"),
        format: "jpeg".into(),
        data: vec![0xFF, 0xD8, 0xFF, 0xD9],
    };
    assert_eq!(CompressedImage::from_cdr(&c.to_cdr().unwrap()).unwrap(), c);
    assert_eq!(PointCloud2::from_cdr(&cloud().to_cdr().unwrap()).unwrap(), cloud());
    let t = Time { sec: -3, nanosec: 999_999_999 };
    assert_eq!(Time::from_cdr(&t.to_cdr().unwrap()).unwrap(), t);
    let empty = TFMessage::default();
    assert_eq!(empty.to_cdr().unwrap(), [0, 1, 0, 0, 0, 0, 0, 0]);
    assert_eq!(TFMessage::from_cdr(&empty.to_cdr().unwrap()).unwrap(), empty);
}

#[test]
fn time_from_nanoseconds_splits_exactly_and_refuses_2038() {
    assert_eq!(Time::from_nanos(1_500_000_125).unwrap(), Time { sec: 1, nanosec: 500_000_125 });
    let ns = (i32::MAX as u64 + 1) * 1_000_000_000;
    assert_eq!(Time::from_nanos(ns), Err(CdrError::TimeRange { ns }));
    assert!(Time::from_nanos(ns - 1).is_ok());
}

/// The schema texts, written out by hand from the ROS 2 `.msg` files in rosbag2's order
/// (python/tests/test_rosbag2.py compares all of them with `rosbags`' `generate_msgdef`).
#[test]
fn schema_texts_list_dependencies_depth_first_once() {
    let sep = schema::SEPARATOR;
    assert_eq!(sep.len(), 80);
    assert_eq!(
        Header::schema(),
        format!(
            "builtin_interfaces/Time stamp\nstring frame_id\n{sep}\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
        )
    );
    let tf = TFMessage::schema();
    let names: Vec<&str> = tf.lines().filter_map(|l| l.strip_prefix("MSG: ")).collect();
    assert_eq!(
        names,
        [
            "geometry_msgs/TransformStamped",
            "std_msgs/Header",
            "builtin_interfaces/Time",
            "geometry_msgs/Transform",
            "geometry_msgs/Vector3",
            "geometry_msgs/Quaternion"
        ]
    );
    let ci = CameraInfo::schema();
    let names: Vec<&str> = ci.lines().filter_map(|l| l.strip_prefix("MSG: ")).collect();
    assert_eq!(
        names,
        ["std_msgs/Header", "builtin_interfaces/Time", "sensor_msgs/RegionOfInterest"]
    );
    assert!(ci.starts_with("std_msgs/Header header\nuint32 height\n"));
    assert_eq!(Image::TYPE, "sensor_msgs/msg/Image");
}

/// Every strict prefix of a message fails with an error (no panic, no partial message).
#[test]
fn truncated_messages_are_refused_at_every_length() {
    // A message's bytes and whether its decoder refuses a given prefix.
    type Refuses = fn(&[u8]) -> bool;
    let messages: Vec<(Vec<u8>, Refuses)> = vec![
        (camera_info().to_cdr().unwrap(), |b| CameraInfo::from_cdr(b).is_err()),
        (tf().to_cdr().unwrap(), |b| TFMessage::from_cdr(b).is_err()),
        (cloud().to_cdr().unwrap(), |b| PointCloud2::from_cdr(b).is_err()),
    ];
    for (bytes, fails) in messages {
        for n in 0..bytes.len() {
            assert!(
                fails(&bytes[..n]),
                "a {n}-byte prefix of a {}-byte message decoded",
                bytes.len()
            );
        }
    }
    let img = Image {
        header: header(1, 2, "x"),
        height: 1,
        width: 4,
        encoding: "mono8".into(),
        step: 4,
        data: vec![9; 4],
        ..Default::default()
    };
    let bytes = img.to_cdr().unwrap();
    // Cut inside the data: its count (4) is more than the 3 bytes left.
    let err = Image::from_cdr(&bytes[..bytes.len() - 1]).unwrap_err();
    assert!(
        matches!(err, CdrError::LengthTooLarge { what: "Image.data", claimed: 4, left: 3, .. }),
        "{err}"
    );
    // Cut inside the step field (body offset 36..40 of this message): a field cut short.
    let err = Image::from_cdr(&bytes[..4 + 38]).unwrap_err();
    assert!(
        matches!(err, CdrError::Truncated { what: "Image.step", need: 4, left: 2, .. }),
        "{err}"
    );
    assert!(!err.to_string().contains('\n'));
}

/// Counts patched to gigabytes: refused from the count, before anything is allocated (the
/// test would abort on a 4 GiB or 34 GB allocation otherwise).
#[test]
fn huge_claimed_lengths_are_refused_before_allocating() {
    let img = Image {
        header: header(1, 2, "x"),
        encoding: "mono8".into(),
        data: vec![7; 8],
        ..Default::default()
    };
    let mut bytes = img.to_cdr().unwrap();
    let n = bytes.len();
    // data's count is the 4 bytes before its 8 bytes.
    bytes[n - 12..n - 8].copy_from_slice(&u32::MAX.to_le_bytes());
    let err = Image::from_cdr(&bytes).unwrap_err();
    assert!(
        matches!(err, CdrError::LengthTooLarge { what: "Image.data", claimed, left: 8, .. } if claimed == u32::MAX as usize),
        "{err}"
    );
    assert!(err.to_string().contains("4294967295"), "{err}");

    // CameraInfo.d: 2^32 - 1 float64s claimed (34 GB).
    let mut ci = camera_info().to_cdr().unwrap();
    ci[4 + 64..4 + 68].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(
        CameraInfo::from_cdr(&ci),
        Err(CdrError::LengthTooLarge { what: "CameraInfo.d", .. })
    ));

    // TFMessage: 2^32 - 1 transforms of at least 74 bytes each claimed (318 GB).
    let mut t = tf().to_cdr().unwrap();
    t[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(
        TFMessage::from_cdr(&t),
        Err(CdrError::LengthTooLarge { what: "TFMessage.transforms", .. })
    ));

    // A string's length of 1 GB.
    let mut h = header(0, 0, "ir").to_cdr().unwrap();
    h[12..16].copy_from_slice(&1_000_000_000u32.to_le_bytes());
    assert!(matches!(
        Header::from_cdr(&h),
        Err(CdrError::LengthTooLarge { what: "Header.frame_id", .. })
    ));
}

#[test]
fn malformed_fields_are_refused_with_the_field_named() {
    // Big-endian CDR (00 00) is not what kfuse reads.
    let mut h = header(0, 0, "ir").to_cdr().unwrap();
    h[1] = 0x00;
    assert_eq!(Header::from_cdr(&h), Err(CdrError::Encapsulation([0, 0, 0, 0])));
    // A string whose last byte is not NUL.
    let mut h = header(0, 0, "ir").to_cdr().unwrap();
    *h.last_mut().unwrap() = b'!';
    assert!(matches!(Header::from_cdr(&h), Err(CdrError::String { what: "Header.frame_id", .. })));
    // A string of length 0 (not even its NUL).
    let mut h = header(0, 0, "").to_cdr().unwrap();
    h[12..16].copy_from_slice(&0u32.to_le_bytes());
    h.pop();
    assert!(matches!(Header::from_cdr(&h), Err(CdrError::String { .. })));
    // A bool of 2.
    let mut c = cloud().to_cdr().unwrap();
    *c.last_mut().unwrap() = 2;
    assert_eq!(
        PointCloud2::from_cdr(&c),
        Err(CdrError::Bool { what: "PointCloud2.is_dense", value: 2 })
    );
    // Trailing bytes: up to three zeros of padding are accepted, more are refused.
    let mut h = header(0, 0, "ir").to_cdr().unwrap();
    h.push(0);
    assert!(Header::from_cdr(&h).is_ok());
    h.extend([0, 0, 0]);
    assert_eq!(
        Header::from_cdr(&h),
        Err(CdrError::Trailing { what: "std_msgs/msg/Header", extra: 4 })
    );
    // Encoding refuses what CDR cannot carry.
    assert_eq!(
        header(0, 0, "a\0b").to_cdr(),
        Err(CdrError::NulInString { what: "Header.frame_id" })
    );
}

#[test]
fn the_writer_aligns_relative_to_the_body_not_the_buffer() {
    let mut w = CdrWriter::new();
    w.u8(1);
    w.f64(2.0);
    let bytes = w.into_bytes();
    // The header's 4 bytes do not count: the float64 is at body offset 8, buffer offset 12.
    assert_eq!(bytes.len(), 4 + 16);
    assert_eq!(&bytes[4..12], &[1, 0, 0, 0, 0, 0, 0, 0]);
    let mut r = CdrReader::new(&bytes).unwrap();
    assert_eq!(r.u8("a").unwrap(), 1);
    assert_eq!(r.f64("b").unwrap(), 2.0);
    assert_eq!(r.remaining(), 0);
}
