//! The rosbag2 layout (`--layout rosbag2`): a rosbag2 folder, `metadata.yaml` and one MCAP
//! file `<folder name>_0.mcap`, that `ros2 bag play`, Foxglove, RViz2 (through a player) and
//! `rosbags` open. MCAP profile `ros2`, schemas `ros2msg` (the `.msg` texts of
//! [`kfuse_ros_msgs::schema`]), messages `cdr` ([`kfuse_ros_msgs`]' encoder), per channel the
//! `offered_qos_profiles` metadata; chunks compressed with zstd ([`ZSTD_LEVEL`]), with message
//! indexes, chunk indexes and a summary
//! (statistics, schemas, channels) so that readers can seek. `metadata.yaml` is rosbag2's
//! version [`METADATA_VERSION`].
//!
//! # Topics
//!
//! In iai_kinect2's naming under the sensor's namespace [`namespace`] (`/kinect2/sn_<serial>`:
//! a ROS name token may not start with a digit, and the Kinect's serial does):
//!
//! | topic | type | what | stamp, frame |
//! | --- | --- | --- | --- |
//! | `sd/image_depth` | `sensor_msgs/Image` 16UC1 | the decoder's depth, millimetres (round half up), 0 = none, 512 × 424, as the scene is; before a rig's depth correction | depth time, IR optical frame |
//! | `sd/image_ir` | `sensor_msgs/Image` 16UC1 | the decoder's IR amplitude (round half up, clamped to 65535) | depth time, IR optical frame |
//! | `hd/image_depth_rect` | `sensor_msgs/Image` 16UC1 | depth registered on the colour grid (the kfuse layout's `depth/NNNNNN.png`, same values), millimetres | depth time, colour optical frame |
//! | `hd/image_color/compressed` | `sensor_msgs/CompressedImage` `jpeg` | the sensor's JPEG as the kfuse layout writes it (`color/NNNNNN.jpg`: flipped without loss), not re-encoded; once per colour frame | colour time, colour optical frame |
//! | `sd/camera_info`, `hd/camera_info` | `sensor_msgs/CameraInfo` | the rig's depth and colour cameras as `kfuse rig export --format ros` writes them ([`kfuse_io::rig_io::ros::rig_camera_infos`]) | depth time |
//! | `/tf_static` | `tf2_msgs/TFMessage`, transient local | the rig's `color_from_depth`: the IR optical frame's pose in the colour optical frame | first depth time |
//! | `sd/points` (only with `--points`) | `sensor_msgs/PointCloud2` | the frame's cloud as `--write cloud` writes it (`cloud/NNNNNN.ply`: the depth samples within the depth range back-projected, metres, in the depth camera's frame, coloured by the colour on the depth grid), unordered (height 1), fields `x`, `y`, `z` float32 and `rgb`, a float32 whose bits are `0x00RRGGBB` as PCL and iai_kinect2 pack it ([`POINTS_FIELDS`]), 16 bytes a point, dense; `rgb` 0 (black) for a frame without a colour partner | depth time, IR optical frame |
//!
//! # Times
//!
//! Header stamps and MCAP's log and publish times are host time, nanoseconds since the Unix
//! epoch, as ROS stamps are: the sensor's timestamps (0.125 ms ticks of its own clock, as
//! `index.json`'s `depth_time_ticks`) mapped by the recording's [`HostClock`]
//! ([`crate::host_time`]): the last complete depth frame lands on the recording file's
//! modification time, the host time at which `kfuse capture record` received it, and every
//! other message keeps the sensor's spacing to it (ticks × 125 µs, exact).
//!
//! Writing happens in the staged output folder; [`Bag::finish`] closes the MCAP file (summary,
//! footer) and writes `metadata.yaml`, and only then is the folder committed: an error or
//! Ctrl-C leaves nothing half-written in `--out`.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use geometry::Rig;
use kfuse_io::atomic::write_bytes_atomic;
use kfuse_io::rig_io::ros::{CameraInfoValues, rig_camera_infos};
use kfuse_ros_msgs::{
    CameraInfo, CompressedImage, Header, Image, Message, POINT_FIELD_FLOAT32, PointCloud2,
    PointField, Quaternion, TFMessage, Time, Transform, TransformStamped, Vector3,
};

use crate::host_time::HostClock;
use crate::source::TICKS_PER_SECOND;
use crate::{Result, SequenceError};

/// The rosbag2 metadata version of `metadata.yaml`: 5, what ROS 2 Humble's rosbag2 writes;
/// later rosbag2 releases (Jazzy's writes 9) read it, and its QoS profiles are the integer
/// form that every release reads.
pub const METADATA_VERSION: u32 = 5;

/// MCAP profile of rosbag2 files.
pub const PROFILE: &str = "ros2";
/// MCAP schema encoding of `.msg` texts.
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// MCAP message encoding of ROS 2 messages.
pub const MESSAGE_ENCODING: &str = "cdr";

/// Nanoseconds per sensor tick (0.125 ms).
pub const NANOS_PER_TICK: u64 = 1_000_000_000 / TICKS_PER_SECOND;

/// zstd level of the MCAP chunks. Level 1 measured against 3 on a 30-frame bag of the simulated
/// sensor (workspace Cargo.toml, the `mcap` entry): 16 % against 15 % of the bytes left, 6.9
/// against 8.1 ms a frame on one thread; the pipeline's writer thread is the one that pays.
pub const ZSTD_LEVEL: u32 = 1;

/// `sensor_msgs/Image` encoding of the depth and IR images (REP 118: 16-bit depth in mm).
pub const ENCODING_16UC1: &str = "16UC1";

/// Queue depth offered by the image and camera_info topics: rclcpp's default QoS (keep last
/// 10), what iai_kinect2's publishers offer.
pub const SENSOR_QOS_DEPTH: u32 = 10;

/// Queue depth of `/tf_static`: tf2_ros's static broadcaster offers keep last 1, transient
/// local (late subscribers get the last message).
pub const TF_STATIC_QOS_DEPTH: u32 = 1;

/// A topic of the layout (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Topic {
    /// `sd/image_depth`.
    Depth,
    /// `sd/image_ir`.
    Ir,
    /// `hd/image_depth_rect`.
    DepthRect,
    /// `hd/image_color/compressed`.
    Color,
    /// `sd/camera_info`.
    DepthInfo,
    /// `hd/camera_info`.
    ColorInfo,
    /// `/tf_static`.
    TfStatic,
    /// `sd/points` (optional: [`Bag::create`]'s `points`).
    Points,
}

/// Every topic, in channel order.
pub const TOPICS: [Topic; 8] = [
    Topic::Depth,
    Topic::Ir,
    Topic::DepthRect,
    Topic::Color,
    Topic::DepthInfo,
    Topic::ColorInfo,
    Topic::TfStatic,
    Topic::Points,
];

/// The fields of a `sd/points` point: `x`, `y`, `z` (metres) and `rgb` (`0x00RRGGBB` in a
/// float32's bits, PCL's `PointXYZRGB` packing, which RViz2's and Foxglove's `RGB8` colour
/// modes read), each a float32, at these byte offsets.
pub const POINTS_FIELDS: [(&str, u32); 4] = [("x", 0), ("y", 4), ("z", 8), ("rgb", 12)];

/// Bytes of a `sd/points` point: the four float32s of [`POINTS_FIELDS`], no padding.
pub const POINT_STEP: u32 = 16;

impl Topic {
    fn index(self) -> usize {
        self as usize
    }

    /// The topic's name under the sensor's namespace `ns` ([`namespace`]).
    pub fn name(self, ns: &str) -> String {
        use kfuse_ros_msgs::names::topic;
        let rel = match self {
            Topic::Depth => topic::DEPTH,
            Topic::Ir => topic::IR,
            Topic::DepthRect => topic::DEPTH_RECT,
            Topic::Color => topic::COLOR,
            Topic::DepthInfo => topic::DEPTH_INFO,
            Topic::ColorInfo => topic::COLOR_INFO,
            Topic::TfStatic => return topic::TF_STATIC.into(),
            Topic::Points => topic::POINTS,
        };
        format!("{ns}/{rel}")
    }

    /// The message type, `pkg/msg/Type`.
    pub fn msg_type(self) -> &'static str {
        match self {
            Topic::Depth | Topic::Ir | Topic::DepthRect => Image::TYPE,
            Topic::Color => CompressedImage::TYPE,
            Topic::DepthInfo | Topic::ColorInfo => CameraInfo::TYPE,
            Topic::TfStatic => TFMessage::TYPE,
            Topic::Points => PointCloud2::TYPE,
        }
    }

    fn schema(self) -> String {
        match self {
            Topic::Depth | Topic::Ir | Topic::DepthRect => Image::schema(),
            Topic::Color => CompressedImage::schema(),
            Topic::DepthInfo | Topic::ColorInfo => CameraInfo::schema(),
            Topic::TfStatic => TFMessage::schema(),
            Topic::Points => PointCloud2::schema(),
        }
    }

    /// The offered QoS profile as rosbag2 stores it (a YAML list of one profile, integer
    /// policies as `rmw_qos_*_policy_t`): keep last, reliable, volatile (transient local for
    /// `/tf_static`), automatic liveliness, infinite deadline, lifespan and lease.
    pub fn qos_yaml(self) -> String {
        // rmw's enums: history KEEP_LAST = 1; reliability RELIABLE = 1; durability
        // TRANSIENT_LOCAL = 1, VOLATILE = 2; liveliness AUTOMATIC = 1. RMW_DURATION_INFINITE
        // is i64::MAX ns, which rosbag2 writes as 9223372036 s + 854775807 ns.
        let (depth, durability) = match self {
            Topic::TfStatic => (TF_STATIC_QOS_DEPTH, 1),
            _ => (SENSOR_QOS_DEPTH, 2),
        };
        let inf = "\n    sec: 9223372036\n    nsec: 854775807";
        format!(
            "- history: 1\n  depth: {depth}\n  reliability: 1\n  durability: {durability}\n  deadline:{inf}\n  lifespan:{inf}\n  liveliness: 1\n  liveliness_lease_duration:{inf}\n  avoid_ros_namespace_conventions: false"
        )
    }
}

pub use kfuse_ros_msgs::names::{namespace, optical_frames};

/// The bag's MCAP file name for an output folder `out`: `<folder name>_0.mcap`, as
/// `ros2 bag record -o NAME` names its first file.
pub fn mcap_name(out: &Path) -> String {
    let stem = out
        .file_name()
        .and_then(|n| n.to_str())
        .filter(|n| kfuse_io::atomic::is_plain_name(n))
        .unwrap_or("rosbag2");
    format!("{stem}_0.mcap")
}

/// A sensor time in ticks as nanoseconds of the sensor's clock (not host time: [`HostClock`]).
pub fn ticks_to_nanos(ticks: u64) -> u64 {
    ticks.saturating_mul(NANOS_PER_TICK)
}

/// A message ready for the bag.
#[derive(Debug, Clone, PartialEq)]
pub struct BagMessage {
    /// Its topic.
    pub topic: Topic,
    /// Log and publish time, nanoseconds (the header's stamp).
    pub time_ns: u64,
    /// The colour frame's sequence number (colour messages: written once per colour frame).
    pub color_sequence: Option<u32>,
    /// CDR bytes.
    pub data: Vec<u8>,
}

/// A frame's images for the bag, besides its registered depth.
pub struct SensorImages {
    /// Decoder depth, millimetres (module docs), 512 × 424.
    pub depth_mm: Vec<u16>,
    /// Decoder IR amplitude, 512 × 424.
    pub ir: Vec<u16>,
}

/// The decoder's depth (f32 millimetres, 0 or less = none) as 16UC1: round half up, at least 1
/// for a sample, clamped to 65535.
pub fn depth_mm_u16(mm: &[f32]) -> Vec<u16> {
    mm.iter()
        .map(|&v| if v > 0.0 { (f64::from(v) + 0.5).floor().clamp(1.0, 65535.0) as u16 } else { 0 })
        .collect()
}

/// The decoder's IR amplitude (f32) as 16UC1: round half up, clamped to 0..=65535 (NaN: 0).
pub fn ir_u16(ir: &[f32]) -> Vec<u16> {
    ir.iter()
        .map(|&v| if v > 0.0 { (f64::from(v) + 0.5).floor().min(65535.0) as u16 } else { 0 })
        .collect()
}

struct Open {
    mcap: mcap::Writer<BufWriter<File>>,
    channels: [u16; TOPICS.len()],
    counts: [u64; TOPICS.len()],
    sequence: u32,
    bounds: Option<(u64, u64)>,
    tf_written: bool,
    last_color: Option<u32>,
}

/// The bag being written (module docs): the MCAP writer behind a lock, the sensor's names and
/// the rig's messages.
pub struct Bag {
    dir: PathBuf,
    file: String,
    ns: String,
    frames: (String, String),
    infos: (CameraInfoValues, CameraInfoValues),
    tf: Transform,
    clock: HostClock,
    topics: Vec<Topic>,
    open: Mutex<Option<Open>>,
}

impl std::fmt::Debug for Bag {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bag").field("file", &self.dir.join(&self.file)).finish_non_exhaustive()
    }
}

/// What a finished bag holds.
#[derive(Debug, Clone, PartialEq)]
pub struct BagSummary {
    /// The MCAP file's name in the folder.
    pub file: String,
    /// Messages per topic name.
    pub counts: Vec<(String, u64)>,
}

fn cdr_err(path: &Path, topic: &str, e: kfuse_ros_msgs::CdrError) -> SequenceError {
    SequenceError::Encode { path: path.to_path_buf(), message: format!("topic {topic}: {e}") }
}

fn mcap_err(path: &Path, what: &str, e: mcap::McapError) -> SequenceError {
    SequenceError::Encode { path: path.to_path_buf(), message: format!("{what}: {e}") }
}

impl Bag {
    /// Creates `<dir>/<file>` (`file` from [`mcap_name`]) for the sensor `serial` and `rig`:
    /// the MCAP header, the schemas and the channels (`sd/points` only with `points`). Sensor
    /// times are stamped through `clock` (module docs, Times).
    pub fn create(
        dir: &Path,
        file: &str,
        serial: &str,
        rig: &Rig,
        clock: HostClock,
        points: bool,
    ) -> Result<Self> {
        let path = dir.join(file);
        let f = File::create(&path)
            .map_err(|e| SequenceError::input(&path, format!("cannot create the bag file: {e}")))?;
        let options = mcap::WriteOptions::new()
            .profile(PROFILE)
            .library(format!("kfuse {}", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Zstd))
            .compression_level(ZSTD_LEVEL)
            // Compressed on the pipeline's writer thread: the two workers already fill the
            // cores zstd's own threads would compete for.
            .compression_threads(0);
        let mut mcap = options
            .create(BufWriter::new(f))
            .map_err(|e| mcap_err(&path, "writing the MCAP header", e))?;
        let ns = namespace(serial);
        let mut channels = [0u16; TOPICS.len()];
        let topics: Vec<Topic> =
            TOPICS.into_iter().filter(|&t| points || t != Topic::Points).collect();
        for &t in &topics {
            let schema = mcap
                .add_schema(t.msg_type(), SCHEMA_ENCODING, t.schema().as_bytes())
                .map_err(|e| mcap_err(&path, "writing a schema", e))?;
            let metadata = BTreeMap::from([("offered_qos_profiles".to_string(), t.qos_yaml())]);
            channels[t.index()] = mcap
                .add_channel(schema, &t.name(&ns), MESSAGE_ENCODING, &metadata)
                .map_err(|e| mcap_err(&path, "writing a channel", e))?;
        }
        let cfd = &rig.color_from_depth;
        let q = nalgebra::UnitQuaternion::from_rotation_matrix(&cfd.rotation);
        let t = cfd.translation;
        let tf = Transform {
            translation: Vector3 { x: t.x, y: t.y, z: t.z },
            rotation: Quaternion { x: q.i, y: q.j, z: q.k, w: q.w },
        };
        Ok(Self {
            dir: dir.to_path_buf(),
            file: file.to_string(),
            frames: optical_frames(serial),
            ns,
            infos: rig_camera_infos(rig),
            tf,
            clock,
            topics,
            open: Mutex::new(Some(Open {
                mcap,
                channels,
                counts: [0; TOPICS.len()],
                sequence: 0,
                bounds: None,
                tf_written: false,
                last_color: None,
            })),
        })
    }

    fn path(&self) -> PathBuf {
        self.dir.join(&self.file)
    }

    /// The host time of sensor time `ticks` (module docs, Times).
    fn stamp(&self, topic: Topic, ticks: u64) -> Result<u64> {
        self.clock.unix_ns(ticks).ok_or_else(|| {
            cdr_err_text(
                &self.path(),
                &topic.name(&self.ns),
                format!(
                    "sensor time {ticks} ticks is {:.3} s from the recording's last frame ({} ticks, at the file's modification time), before 1970 in host time: date the recording (touch -d) when it was made",
                    (ticks as f64 - self.clock.anchor_ticks as f64) / TICKS_PER_SECOND as f64,
                    self.clock.anchor_ticks
                ),
            )
        })
    }

    fn header(&self, time_ns: u64, frame: &str) -> Result<Header> {
        let stamp = Time::from_nanos(time_ns).map_err(|e| cdr_err(&self.path(), "header", e))?;
        Ok(Header { stamp, frame_id: frame.to_string() })
    }

    fn encode<M: Message>(&self, topic: Topic, m: &M) -> Result<Vec<u8>> {
        m.to_cdr().map_err(|e| cdr_err(&self.path(), &topic.name(&self.ns), e))
    }

    fn image(
        &self,
        topic: Topic,
        header: Header,
        (width, height): (usize, usize),
        values: &[u16],
    ) -> Result<Vec<u8>> {
        let bad = |m: String| cdr_err_text(&self.path(), &topic.name(&self.ns), m);
        if values.len() != width * height {
            return Err(bad(format!("{} samples for a {width}x{height} image", values.len())));
        }
        let dim = |v: usize| u32::try_from(v).map_err(|_| bad(format!("{v} pixels is too large")));
        let data: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let msg = Image {
            header,
            height: dim(height)?,
            width: dim(width)?,
            encoding: ENCODING_16UC1.into(),
            is_bigendian: 0,
            step: dim(width * 2)?,
            data,
        };
        self.encode(topic, &msg)
    }

    fn camera_info(&self, topic: Topic, header: Header, v: &CameraInfoValues) -> Result<Vec<u8>> {
        let bad = |m: String| cdr_err_text(&self.path(), &topic.name(&self.ns), m);
        let dim = |x: usize| u32::try_from(x).map_err(|_| bad(format!("{x} pixels is too large")));
        let msg = CameraInfo {
            header,
            height: dim(v.height)?,
            width: dim(v.width)?,
            distortion_model: "plumb_bob".into(),
            d: v.d.to_vec(),
            k: v.k,
            r: v.r,
            p: v.p,
            ..Default::default()
        };
        self.encode(topic, &msg)
    }

    /// Whether the bag has the `sd/points` topic.
    pub fn has_points(&self) -> bool {
        self.topics.contains(&Topic::Points)
    }

    /// A frame's cloud as a `sensor_msgs/PointCloud2` (module docs): unordered, fields
    /// [`POINTS_FIELDS`], `rgb` from the cloud's colours (0 where it has none).
    pub fn points_message(&self, header: Header, cloud: &geometry::PointCloud) -> Result<Vec<u8>> {
        let topic = Topic::Points;
        let bad = |m: String| cdr_err_text(&self.path(), &topic.name(&self.ns), m);
        let n = cloud.points.len();
        let colored = cloud.colors.len() == n;
        let width = u32::try_from(n).map_err(|_| bad(format!("{n} points is too many")))?;
        let row_step = width
            .checked_mul(POINT_STEP)
            .ok_or_else(|| bad(format!("{n} points is too many for one message")))?;
        let mut data = Vec::with_capacity(row_step as usize);
        for (i, p) in cloud.points.iter().enumerate() {
            for c in p {
                data.extend_from_slice(&c.to_le_bytes());
            }
            let rgb = if colored { packed_rgb(cloud.colors[i]) } else { 0.0 };
            data.extend_from_slice(&rgb.to_le_bytes());
        }
        let fields = POINTS_FIELDS
            .iter()
            .map(|&(name, offset)| PointField {
                name: name.into(),
                offset,
                datatype: POINT_FIELD_FLOAT32,
                count: 1,
            })
            .collect();
        let msg = PointCloud2 {
            header,
            height: 1,
            width,
            fields,
            is_bigendian: false,
            point_step: POINT_STEP,
            row_step,
            data,
            // Only valid samples are back-projected: no NaN point.
            is_dense: true,
        };
        self.encode(topic, &msg)
    }

    /// A frame's messages: depth, IR, camera_info at the depth time `depth_ticks`, registered
    /// depth `depth_rect` (colour grid, `color_size`), the colour JPEG `jpeg` at
    /// `color_ticks` (its sequence `color_sequence`), the cloud `cloud` when the bag has
    /// `sd/points`.
    #[allow(clippy::too_many_arguments)]
    pub fn frame_messages(
        &self,
        depth_ticks: u64,
        sensor: Option<&SensorImages>,
        depth_size: (usize, usize),
        depth_rect: &[u16],
        color_size: (usize, usize),
        jpeg: Option<(&[u8], u64, Option<u32>)>,
        cloud: Option<&geometry::PointCloud>,
    ) -> Result<Vec<BagMessage>> {
        let t = self.stamp(Topic::DepthRect, depth_ticks)?;
        let (ir_frame, rgb_frame) = (&self.frames.0, &self.frames.1);
        let msg = |topic, data| BagMessage { topic, time_ns: t, color_sequence: None, data };
        let mut out = Vec::with_capacity(TOPICS.len());
        if let Some(s) = sensor {
            let h = self.header(t, ir_frame)?;
            out.push(msg(
                Topic::Depth,
                self.image(Topic::Depth, h.clone(), depth_size, &s.depth_mm)?,
            ));
            out.push(msg(Topic::Ir, self.image(Topic::Ir, h, depth_size, &s.ir)?));
        }
        let h = self.header(t, rgb_frame)?;
        out.push(msg(Topic::DepthRect, self.image(Topic::DepthRect, h, color_size, depth_rect)?));
        if let Some((bytes, color_ticks, sequence)) = jpeg {
            let tc = self.stamp(Topic::Color, color_ticks)?;
            let m = CompressedImage {
                header: self.header(tc, rgb_frame)?,
                format: "jpeg".into(),
                data: bytes.to_vec(),
            };
            out.push(BagMessage {
                topic: Topic::Color,
                time_ns: tc,
                color_sequence: sequence,
                data: self.encode(Topic::Color, &m)?,
            });
        }
        let h = self.header(t, ir_frame)?;
        out.push(msg(Topic::DepthInfo, self.camera_info(Topic::DepthInfo, h, &self.infos.0)?));
        let h = self.header(t, rgb_frame)?;
        out.push(msg(Topic::ColorInfo, self.camera_info(Topic::ColorInfo, h, &self.infos.1)?));
        if self.has_points() {
            let cloud = cloud.ok_or_else(|| {
                SequenceError::Pipeline(format!(
                    "{}: a frame reached the bag without the cloud its sd/points topic needs",
                    self.path().display()
                ))
            })?;
            let h = self.header(t, ir_frame)?;
            out.push(msg(Topic::Points, self.points_message(h, cloud)?));
        }
        Ok(out)
    }

    /// Appends a frame's messages (in frame order; `/tf_static` before the first). A colour
    /// frame already written (the partner of two depth frames) is not written again.
    pub fn write(&self, messages: Vec<BagMessage>) -> Result<()> {
        let path = self.path();
        let mut guard = self.open.lock().map_err(|_| {
            SequenceError::Pipeline("the bag writer's lock was poisoned by a panic".into())
        })?;
        let open = guard.as_mut().ok_or_else(|| {
            SequenceError::Pipeline(format!("{}: written after it was finished", path.display()))
        })?;
        if !open.tf_written
            && let Some(first) = messages.iter().map(|m| m.time_ns).min()
        {
            let tf = TFMessage {
                transforms: vec![TransformStamped {
                    header: self.header(first, &self.frames.1)?,
                    child_frame_id: self.frames.0.clone(),
                    transform: self.tf,
                }],
            };
            let data = self.encode(Topic::TfStatic, &tf)?;
            open.put(&path, Topic::TfStatic, first, &data)?;
            open.tf_written = true;
        }
        for m in messages {
            if m.topic == Topic::Color {
                if m.color_sequence.is_some() && m.color_sequence == open.last_color {
                    continue;
                }
                open.last_color = m.color_sequence;
            }
            open.put(&path, m.topic, m.time_ns, &m.data)?;
        }
        Ok(())
    }

    /// Closes the MCAP file (a `rosbag2` metadata record with the bag's metadata, as rosbag2
    /// writes one; the summary and footer) and writes `metadata.yaml`.
    pub fn finish(&self) -> Result<BagSummary> {
        let path = self.path();
        let open = self
            .open
            .lock()
            .map_err(|_| {
                SequenceError::Pipeline("the bag writer's lock was poisoned by a panic".into())
            })?
            .take()
            .ok_or_else(|| {
                SequenceError::Pipeline(format!("{}: finished twice", path.display()))
            })?;
        let Open { mut mcap, counts, bounds, .. } = open;
        let yaml = self.metadata_yaml(&counts, bounds);
        let inner = yaml
            .strip_prefix("rosbag2_bagfile_information:\n")
            .map(|body| {
                body.lines()
                    .map(|l| l.strip_prefix("  ").unwrap_or(l))
                    .collect::<Vec<_>>()
                    .join("\n")
            })
            .unwrap_or_default();
        mcap.write_metadata(&mcap::records::Metadata {
            name: "rosbag2".into(),
            metadata: BTreeMap::from([("serialized_metadata".to_string(), inner)]),
        })
        .map_err(|e| mcap_err(&path, "writing the rosbag2 metadata record", e))?;
        mcap.finish().map_err(|e| mcap_err(&path, "writing the summary", e))?;
        let mut buf = mcap.into_inner();
        std::io::Write::flush(&mut buf)
            .map_err(|e| SequenceError::input(&path, format!("cannot write the bag file: {e}")))?;
        let file = buf.into_inner().map_err(|e| {
            SequenceError::input(&path, format!("cannot write the bag file: {}", e.error()))
        })?;
        file.sync_all()
            .map_err(|e| SequenceError::input(&path, format!("cannot write the bag file: {e}")))?;
        write_bytes_atomic(&self.dir.join("metadata.yaml"), yaml.as_bytes())?;
        Ok(BagSummary {
            file: self.file.clone(),
            counts: self.topics.iter().map(|t| (t.name(&self.ns), counts[t.index()])).collect(),
        })
    }

    /// `metadata.yaml` (rosbag2 version [`METADATA_VERSION`]).
    fn metadata_yaml(&self, counts: &[u64; TOPICS.len()], bounds: Option<(u64, u64)>) -> String {
        let (start, end) = bounds.unwrap_or((0, 0));
        let duration = end - start;
        let total: u64 = counts.iter().sum();
        let mut s = String::from("rosbag2_bagfile_information:\n");
        let _ = writeln!(s, "  version: {METADATA_VERSION}");
        let _ = writeln!(s, "  storage_identifier: mcap");
        let _ = writeln!(s, "  duration:\n    nanoseconds: {duration}");
        let _ = writeln!(s, "  starting_time:\n    nanoseconds_since_epoch: {start}");
        let _ = writeln!(s, "  message_count: {total}");
        let _ = writeln!(s, "  topics_with_message_count:");
        for &t in &self.topics {
            let _ = writeln!(s, "    - topic_metadata:");
            let _ = writeln!(s, "        name: {}", t.name(&self.ns));
            let _ = writeln!(s, "        type: {}", t.msg_type());
            let _ = writeln!(s, "        serialization_format: {MESSAGE_ENCODING}");
            let _ = writeln!(s, "        offered_qos_profiles: {}", yaml_quoted(&t.qos_yaml()));
            let _ = writeln!(s, "      message_count: {}", counts[t.index()]);
        }
        let _ = writeln!(s, "  compression_format: \"\"");
        let _ = writeln!(s, "  compression_mode: \"\"");
        let _ = writeln!(s, "  relative_file_paths:\n    - {}", self.file);
        let _ = writeln!(s, "  files:\n    - path: {}", self.file);
        let _ = writeln!(s, "      starting_time:\n        nanoseconds_since_epoch: {start}");
        let _ = writeln!(s, "      duration:\n        nanoseconds: {duration}");
        let _ = writeln!(s, "      message_count: {total}");
        s
    }
}

/// An RGB colour packed as PCL packs `PointXYZRGB`'s `rgb`: the bits `0x00RRGGBB` read as a
/// float32.
pub fn packed_rgb([r, g, b]: [u8; 3]) -> f32 {
    f32::from_bits((u32::from(r) << 16) | (u32::from(g) << 8) | u32::from(b))
}

fn cdr_err_text(path: &Path, topic: &str, message: String) -> SequenceError {
    SequenceError::Encode { path: path.to_path_buf(), message: format!("topic {topic}: {message}") }
}

/// `text` as a YAML double-quoted scalar (`\`, `"` and newlines escaped).
fn yaml_quoted(text: &str) -> String {
    let mut s = String::with_capacity(text.len() + 2);
    s.push('"');
    for c in text.chars() {
        match c {
            '\\' => s.push_str("\\\\"),
            '"' => s.push_str("\\\""),
            '\n' => s.push_str("\\n"),
            c => s.push(c),
        }
    }
    s.push('"');
    s
}

impl Open {
    fn put(&mut self, path: &Path, topic: Topic, time_ns: u64, data: &[u8]) -> Result<()> {
        let header = mcap::records::MessageHeader {
            channel_id: self.channels[topic.index()],
            sequence: self.sequence,
            log_time: time_ns,
            publish_time: time_ns,
        };
        self.mcap
            .write_to_known_channel(&header, data)
            .map_err(|e| mcap_err(path, "writing a message", e))?;
        self.sequence = self.sequence.wrapping_add(1);
        self.counts[topic.index()] += 1;
        self.bounds = Some(match self.bounds {
            None => (time_ns, time_ns),
            Some((a, b)) => (a.min(time_ns), b.max(time_ns)),
        });
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_follow_ros_rules_and_iai_kinect2() {
        assert_eq!(namespace("003415165047"), "/kinect2/sn_003415165047");
        assert_eq!(namespace("A-1.2"), "/kinect2/sn_A_1_2");
        assert_eq!(Topic::Color.name("/kinect2/sn_1"), "/kinect2/sn_1/hd/image_color/compressed");
        assert_eq!(Topic::TfStatic.name("/kinect2/sn_1"), "/tf_static");
        assert_eq!(optical_frames("7").1, "kinect2_7_rgb_optical_frame");
        assert_eq!(mcap_name(Path::new("/tmp/out/bag")), "bag_0.mcap");
    }

    #[test]
    fn ticks_are_exact_nanoseconds() {
        assert_eq!(ticks_to_nanos(1), 125_000);
        assert_eq!(ticks_to_nanos(8000 * 3600 + 267), 3_600_033_375_000);
    }

    #[test]
    fn sensor_images_round_half_up_and_keep_zero_as_none() {
        assert_eq!(
            depth_mm_u16(&[0.0, -1.0, 0.2, 1233.5, 1233.49, 70000.0]),
            [0, 0, 1, 1234, 1233, 65535]
        );
        assert_eq!(ir_u16(&[f32::NAN, 0.4, 0.5, 65535.7, 1e9]), [0, 0, 1, 65535, 65535]);
    }

    #[test]
    fn rgb_packs_as_pcl_does() {
        assert_eq!(packed_rgb([0x12, 0x34, 0x56]).to_bits(), 0x0012_3456);
        assert_eq!(packed_rgb([255, 0, 0]).to_bits(), 0x00FF_0000);
        assert_eq!(packed_rgb([0, 0, 0]), 0.0);
    }

    #[test]
    fn qos_text_is_quoted_as_one_yaml_line() {
        let q = yaml_quoted(&Topic::TfStatic.qos_yaml());
        assert!(!q.contains('\n'));
        assert!(q.contains("durability: 1\\n"));
        assert!(Topic::Depth.qos_yaml().contains("durability: 2\n"));
    }
}
