//! Stage 1, read, of a ROS 2 bag: a rosbag2 folder (`metadata.yaml` + one `.mcap` file) or a
//! bare `.mcap` file whose depth is a `sensor_msgs/Image` (16UC1 millimetres or 32FC1 metres)
//! and whose colour is a `sensor_msgs/CompressedImage` (JPEG, PNG) or an `Image` (rgb8, bgr8),
//! with a `sensor_msgs/CameraInfo` per camera and `/tf_static` for the pair's pose
//! ([`BagSource`]). The depth is already decoded: the pipeline's decode stage passes it on
//! (`Job::predecoded`), and matching pairs depth and colour by header stamp as it pairs a
//! recording's frames ([`crate::matching`]).
//!
//! The file is read twice, streamed, through the `mcap` crate's `LinearReader`: once
//! ([`BagSource::open`]) for the channels, the camera_infos and `/tf_static` (every image
//! message is skipped undecoded), then frame by frame. Every chunk's CRC is checked before a
//! message of it is used, every record length is bounded by [`MAX_RECORD_BYTES`] before it is
//! read, and every image's `step` × `height` against its data and `width` × bytes per pixel
//! ([`depth_metres`], [`color_picture`]): a damaged bag is one line naming the file (and the
//! topic), and since the first pass reads the whole file, nothing is written for it.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicU64;

use geometry::{Rig, RigidTransform};
use kfuse_io::rig_io::ros::{CameraInfoFields, cameras_from_infos};
use kfuse_ros_msgs::{
    CameraInfo, CompressedImage, Image, Message, TFMessage, TransformStamped, ros1,
};
use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use nalgebra::{Isometry3, Matrix3, Quaternion, Translation3, UnitQuaternion};

use crate::rosbag2::NANOS_PER_TICK;
use crate::source::{ColorFrame, Counting, RawDepth, SourceEvent};
use crate::{Result, SequenceError};

/// Largest MCAP record (and compressed or decompressed chunk) read: 256 MiB. A Kinect v2
/// frame's largest message, a 1920 × 1080 32FC1 or rgb8 image, is 8.3 MB, and rosbag2 writes
/// chunks of about 1 MiB; a length beyond this is a damaged file, refused before anything is
/// allocated for it.
pub const MAX_RECORD_BYTES: usize = 256 << 20;

/// Largest image side accepted (pixels): four times the Kinect v2's 1920-pixel colour width;
/// a bag's image may be another camera's, but a larger side is a damaged message.
pub const MAX_IMAGE_SIDE: u32 = 8192;

/// Largest number of `/tf_static` transforms kept: a robot's whole static tree has tens; more
/// is a damaged or foreign bag, and the pose search stays bounded.
pub const MAX_TRANSFORMS: usize = 4096;

/// Read buffer of the MCAP file: 1 MiB, as the recording reader's.
const READ_BUFFER: usize = 1 << 20;

/// ROS 2's `/tf_static` topic.
pub const TF_STATIC: &str = "/tf_static";

/// The depth topic's and colour topic's names, when the caller chooses them.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct TopicChoice {
    /// `--depth-topic`.
    pub depth: Option<String>,
    /// `--color-topic`.
    pub color: Option<String>,
}

/// A channel of the bag: topic and message type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelInfo {
    /// The topic.
    pub topic: String,
    /// `pkg/msg/Type`.
    pub msg_type: String,
    /// Messages of it in the bag.
    pub count: u64,
}

/// What the first pass found: the topics and the calibration messages.
#[derive(Debug, Clone, Default)]
pub struct BagMeta {
    /// Every channel by id.
    pub channels: BTreeMap<u16, ChannelInfo>,
    /// The depth topic used.
    pub depth_topic: String,
    /// The colour topic used.
    pub color_topic: String,
    /// The depth camera's `camera_info` topic and its first message.
    pub depth_info: Option<(String, CameraInfo)>,
    /// The colour camera's `camera_info` topic and its first message.
    pub color_info: Option<(String, CameraInfo)>,
    /// `/tf_static`'s transforms.
    pub transforms: Vec<TransformStamped>,
}

/// The MCAP file of `input`: the file itself, or the one `.mcap` file of a rosbag2 folder.
///
/// Errors: a folder without `.mcap` file or with several (split bags are not read yet), or
/// a SQLite (`.db3`) bag.
pub fn mcap_file(input: &Path) -> Result<PathBuf> {
    if !input.is_dir() {
        return Ok(input.to_path_buf());
    }
    let rd = std::fs::read_dir(input)
        .map_err(|e| SequenceError::input(input, format!("cannot list the bag folder: {e}")))?;
    let (mut mcaps, mut db3) = (Vec::new(), false);
    for entry in rd.flatten() {
        let p = entry.path();
        match p.extension().and_then(|e| e.to_str()) {
            Some("mcap") => mcaps.push(p),
            Some("db3") => db3 = true,
            _ => {}
        }
    }
    mcaps.sort();
    match mcaps.as_slice() {
        [one] => Ok(one.clone()),
        [] if db3 => Err(SequenceError::input(
            input,
            "a rosbag2 folder with SQLite storage (.db3): only MCAP storage is read; convert it with \
             `ros2 bag convert` (storage_id: mcap)",
        )),
        [] => Err(SequenceError::input(input, "a folder without .mcap file: not a rosbag2 bag")),
        many => Err(SequenceError::input(
            input,
            format!(
                "a rosbag2 bag split into {} .mcap files: only single-file bags are read; give one file",
                many.len()
            ),
        )),
    }
}

/// Whether `path` looks like a bag: a ROS 2 bag (a folder with `metadata.yaml`, a `.mcap`
/// file or a file that starts with MCAP's magic) or a ROS 1 bag (a file that starts with
/// `#ROSBAG V2.0`).
pub fn is_bag(path: &Path) -> bool {
    is_ros2_bag(path) || crate::bag1::is_ros1_bag(path)
}

/// Whether `path` looks like a ROS 2 bag (see [`is_bag`]).
pub fn is_ros2_bag(path: &Path) -> bool {
    if path.is_dir() {
        // rosbag2 writes metadata.yaml beside its storage file; a folder that lost it (or was
        // assembled by hand) is still read from its one .mcap file ([`mcap_file`]), and a
        // folder of SQLite storage is a bag too, refused with the conversion command.
        return path.join("metadata.yaml").is_file() || folder_has_bag_storage(path);
    }
    if path.extension().and_then(|e| e.to_str()) == Some("mcap") {
        return true;
    }
    crate::bag1::file_starts_with(path, mcap::MAGIC)
}

/// Whether folder `dir` holds a `.mcap` or `.db3` file (at most [`MAX_FOLDER_ENTRIES_SNIFFED`]
/// entries are looked at).
fn folder_has_bag_storage(dir: &Path) -> bool {
    std::fs::read_dir(dir).is_ok_and(|rd| {
        rd.flatten()
            .take(MAX_FOLDER_ENTRIES_SNIFFED)
            .any(|e| matches!(e.path().extension().and_then(|x| x.to_str()), Some("mcap" | "db3")))
    })
}

/// Entries of a folder looked at to tell whether it is a bag without `metadata.yaml`: a
/// rosbag2 folder holds 2–3 files; a frame folder of 10 000 shots is not listed whole twice.
const MAX_FOLDER_ENTRIES_SNIFFED: usize = 64;

/// Refuses `path` when it is a pipe, a FIFO or a device: a bag is read twice (its
/// camera_infos and `/tf_static` first, then its frames), which a stream cannot give.
pub(crate) fn require_rereadable(path: &Path, what: &str) -> Result<()> {
    use std::os::unix::fs::FileTypeExt;
    let Ok(meta) = std::fs::metadata(path) else { return Ok(()) };
    let t = meta.file_type();
    if t.is_fifo() || t.is_char_device() || t.is_socket() {
        return Err(SequenceError::input(
            path,
            format!(
                "is a pipe or a device, not a file: {what}, which a stream cannot give; save it to a file first (`cat … > FILE`) and give that"
            ),
        ));
    }
    Ok(())
}

/// How a channel's messages are serialised.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Wire {
    /// ROS 2's CDR (an MCAP channel with message encoding `cdr`).
    Cdr,
    /// ROS 1's serialisation (a ROS 1 bag).
    Ros1,
    /// Anything else (refused when a topic kfuse reads has it).
    Other(String),
}

/// One record of a bag's stream, owned.
enum Rec {
    Schema {
        id: u16,
        name: String,
    },
    /// A channel; `msg_type` given directly by a ROS 1 connection, else its schema's name.
    Channel {
        id: u16,
        schema_id: u16,
        topic: String,
        msg_type: Option<String>,
        wire: Wire,
    },
    Message {
        channel: u16,
        data: Vec<u8>,
    },
}

/// The MCAP file streamed record by record (chunks decompressed, their CRCs checked first).
struct McapStream {
    path: PathBuf,
    file: BufReader<Counting>,
    reader: LinearReader,
}

impl McapStream {
    fn open(path: &Path, count: Arc<AtomicU64>) -> Result<(Self, u64)> {
        let io = |e: std::io::Error| SequenceError::input(path, format!("cannot read: {e}"));
        let file = bounded_read::open_without_blocking(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        if len == 0 {
            return Err(SequenceError::input(
                path,
                "is empty (0 bytes): no bag in it; was the recording saved completely? Record or copy it again",
            ));
        }
        let options = LinearReaderOptions::default()
            .with_prevalidate_chunk_crcs(true)
            .with_validate_summary_section_crc(true)
            .with_record_length_limit(MAX_RECORD_BYTES);
        let reader = LinearReader::new_with_options(options);
        let file = BufReader::with_capacity(READ_BUFFER, Counting { file, count });
        Ok((Self { path: path.to_path_buf(), file, reader }, len))
    }

    fn bad(&self, e: impl std::fmt::Display) -> SequenceError {
        SequenceError::input(&self.path, format!("not a readable MCAP file: {e}"))
    }

    /// The next schema, channel or message; `None` at the end.
    fn next(&mut self) -> Result<Option<Rec>> {
        loop {
            let Some(event) = self.reader.next_event() else { return Ok(None) };
            let event = match event {
                Ok(e) => e,
                Err(mcap::McapError::UnexpectedEof) => {
                    return Err(self.bad("it ends inside a record (a truncated file)"));
                }
                Err(mcap::McapError::BadMagic) => {
                    return Err(SequenceError::input(
                        &self.path,
                        "not an MCAP file (it does not start or end with MCAP's magic bytes): give a rosbag2 folder, an .mcap file (`ros2 bag record -s mcap`, `kfuse fuse --layout rosbag2`) or a ROS 1 .bag",
                    ));
                }
                Err(e) => {
                    let m = e.to_string();
                    return Err(SequenceError::input(
                        &self.path,
                        format!("not a readable MCAP file: {m}"),
                    ));
                }
            };
            match event {
                LinearReadEvent::ReadRequest(need) => {
                    let buf = self.reader.insert(need);
                    let n = self.file.read(buf).map_err(|e| {
                        SequenceError::input(&self.path, format!("cannot read: {e}"))
                    })?;
                    self.reader.notify_read(n);
                }
                LinearReadEvent::Record { opcode, data } => {
                    let rec = match mcap::parse_record(opcode, data) {
                        Ok(r) => r,
                        Err(e) => {
                            let m = e.to_string();
                            return Err(SequenceError::input(
                                &self.path,
                                format!("not a readable MCAP file: {m}"),
                            ));
                        }
                    };
                    match rec {
                        Record::Schema { header, .. } => {
                            return Ok(Some(Rec::Schema { id: header.id, name: header.name }));
                        }
                        Record::Channel(c) => {
                            let wire = match c.message_encoding.as_str() {
                                "cdr" => Wire::Cdr,
                                other => Wire::Other(other.to_string()),
                            };
                            return Ok(Some(Rec::Channel {
                                id: c.id,
                                schema_id: c.schema_id,
                                topic: c.topic,
                                msg_type: None,
                                wire,
                            }));
                        }
                        Record::Message { header, data } => {
                            return Ok(Some(Rec::Message {
                                channel: header.channel_id,
                                data: data.into_owned(),
                            }));
                        }
                        _ => {}
                    }
                }
            }
        }
    }
}

/// A ROS 2 bag, read frame by frame: depth frames (already in metres) and colour pictures,
/// as [`SourceEvent`]s stamped by their header stamps in sensor ticks (0.125 ms).
pub struct BagSource {
    input: PathBuf,
    stream: Stream,
    meta: BagMeta,
    wires: HashMap<u16, Wire>,
    depth_channels: Vec<u16>,
    color_channels: Vec<u16>,
    channel_topics: HashMap<u16, String>,
    bytes_read: Arc<AtomicU64>,
    file_len: u64,
    depth_count: u32,
    color_count: u32,
    depth_size: Option<(usize, usize)>,
    pending: VecDeque<SourceEvent>,
}

/// A bag's records: an MCAP file's, or a ROS 1 bag's ([`crate::bag1`]).
enum Stream {
    Mcap(McapStream),
    Ros1(crate::bag1::Ros1Stream),
}

impl Stream {
    fn open(path: &Path, count: Arc<AtomicU64>) -> Result<(Self, u64)> {
        if crate::bag1::is_ros1_bag(path) {
            let (s, len) = crate::bag1::Ros1Stream::open(path, count)?;
            return Ok((Stream::Ros1(s), len));
        }
        let (s, len) = McapStream::open(path, count)?;
        Ok((Stream::Mcap(s), len))
    }

    fn path(&self) -> &Path {
        match self {
            Stream::Mcap(s) => &s.path,
            Stream::Ros1(s) => s.path(),
        }
    }

    fn next(&mut self) -> Result<Option<Rec>> {
        match self {
            Stream::Mcap(s) => s.next(),
            Stream::Ros1(s) => Ok(s.next_record()?.map(|r| match r {
                crate::bag1::Ros1Rec::Connection { id, topic, msg_type } => Rec::Channel {
                    id,
                    schema_id: 0,
                    topic,
                    msg_type: Some(msg_type),
                    wire: Wire::Ros1,
                },
                crate::bag1::Ros1Rec::Message { conn, data } => {
                    Rec::Message { channel: conn, data }
                }
            })),
        }
    }
}

/// A message of a channel kfuse reads, decoded from its wire format.
fn decode<T>(
    path: &Path,
    topic: &str,
    wire: Option<&Wire>,
    data: &[u8],
    ros1: fn(&[u8]) -> std::result::Result<T, kfuse_ros_msgs::ros1::Ros1Error>,
) -> Result<T>
where
    T: Message,
{
    let r = match wire {
        Some(Wire::Cdr) => T::from_cdr(data).map_err(|e| e.to_string()),
        Some(Wire::Ros1) => ros1(data).map_err(|e| e.to_string()),
        Some(Wire::Other(e)) => {
            return Err(topic_err(
                path,
                topic,
                format!("message encoding '{e}': only ROS 2's cdr and ROS 1 bags are read"),
            ));
        }
        None => return Err(topic_err(path, topic, "no channel record declares it")),
    };
    r.map_err(|e| topic_err(path, topic, format!("a message does not decode: {e}")))
}

/// The `camera_info` topic beside an image topic: `<ns>/camera_info` of `<ns>/image_x`
/// (`<ns>/image_x/compressed` for a CompressedImage), as image_transport and iai_kinect2 name
/// them.
pub fn camera_info_topic(image_topic: &str) -> String {
    let base = image_topic.strip_suffix("/compressed").unwrap_or(image_topic);
    match base.rsplit_once('/') {
        Some((ns, _)) => format!("{ns}/camera_info"),
        None => "camera_info".into(),
    }
}

/// The depth and colour topics a bag offers, by type and name (see [`BagSource::open`]).
fn candidates(channels: &BTreeMap<u16, ChannelInfo>) -> (Vec<&ChannelInfo>, Vec<&ChannelInfo>) {
    let images = |want: &dyn Fn(&ChannelInfo) -> bool| -> Vec<&ChannelInfo> {
        channels.values().filter(|c| c.count > 0 && want(c)).collect()
    };
    let seg = |c: &ChannelInfo| last_segment(&c.topic).to_ascii_lowercase();
    let is_depth = |c: &ChannelInfo| c.msg_type == Image::TYPE && seg(c).contains("depth");
    let depth_candidates = unrect(images(&is_depth));
    let color_named = |c: &ChannelInfo| {
        let s = seg(c);
        s.contains("color") || s.contains("colour") || s.contains("rgb")
    };
    let is_picture =
        |c: &ChannelInfo| c.msg_type == CompressedImage::TYPE || c.msg_type == Image::TYPE;
    // Colour-named pictures; else any CompressedImage that is no depth (`compressedDepth`)
    // or IR image.
    let mut color_candidates = unrect(images(&|c| is_picture(c) && color_named(c)));
    if color_candidates.is_empty() {
        color_candidates = images(&|c| {
            let s = seg(c);
            c.msg_type == CompressedImage::TYPE && !s.contains("depth") && !s.contains("ir")
        });
    }
    (depth_candidates, color_candidates)
}

/// The sensor's images over rectified or registered ones (`*_rect`), where both are there.
fn unrect(v: Vec<&ChannelInfo>) -> Vec<&ChannelInfo> {
    let rect = |c: &ChannelInfo| last_segment(&c.topic).to_ascii_lowercase().contains("rect");
    let plain: Vec<_> = v.iter().copied().filter(|c| !rect(c)).collect();
    if plain.is_empty() { v } else { plain }
}

fn last_segment(topic: &str) -> &str {
    let base = topic.strip_suffix("/compressed").unwrap_or(topic);
    base.rsplit('/').next().unwrap_or(base)
}

/// Chooses the topic of a role: the caller's, or the one candidate by type and name.
fn choose(
    input: &Path,
    role: &str,
    flag: &str,
    given: Option<&str>,
    channels: &BTreeMap<u16, ChannelInfo>,
    candidates: &[&ChannelInfo],
    types: &[&str],
) -> Result<String> {
    if let Some(t) = given {
        let found = channels.values().find(|c| c.topic == t);
        return match found {
            Some(c) if types.contains(&c.msg_type.as_str()) => Ok(t.to_string()),
            Some(c) => Err(SequenceError::input(
                input,
                format!("{flag} {t}: the topic is {}, expected {}", c.msg_type, types.join(" or ")),
            )),
            None => Err(SequenceError::input(
                input,
                format!("{flag} {t}: no such topic in the bag ({})", list(channels.values())),
            )),
        };
    }
    match candidates {
        [one] => Ok(one.topic.clone()),
        [] => Err(SequenceError::input(
            input,
            format!("no {role} topic found by type ({}); topics: {}", types.join(" or "), {
                list(channels.values())
            }),
        )),
        many => Err(SequenceError::input(
            input,
            format!(
                "{} candidate {role} topics: {}; choose one with {flag}",
                many.len(),
                list(many.iter().copied())
            ),
        )),
    }
}

fn list<'a>(channels: impl Iterator<Item = &'a ChannelInfo>) -> String {
    let v: Vec<String> = channels.map(|c| format!("{} ({})", c.topic, c.msg_type)).collect();
    if v.is_empty() { "none".into() } else { v.join(", ") }
}

impl BagSource {
    /// Opens the bag `input` (a rosbag2 folder or a `.mcap` file), chooses the depth and colour
    /// topics (`topics`, or by type: an `Image` topic whose name holds `depth` — not a
    /// `*_rect` one where another is there — and a `CompressedImage` or colour-named `Image`
    /// topic; one of each) and reads their camera_infos and `/tf_static`.
    ///
    /// Errors: not a bag, a damaged MCAP file (truncated, a chunk whose CRC does not match, a
    /// record longer than [`MAX_RECORD_BYTES`]), a message that does not decode, no or several
    /// candidate topics.
    pub fn open(input: &Path, topics: &TopicChoice) -> Result<Self> {
        let file = mcap_file(input)?;
        require_rereadable(
            &file,
            "a bag is read twice (its camera_infos and /tf_static first, then its frames)",
        )?;
        let bytes_read = Arc::new(AtomicU64::new(0));
        let (mut scan, _) = Stream::open(&file, Arc::new(AtomicU64::new(0)))?;
        let mut schemas: HashMap<u16, String> = HashMap::new();
        let mut channels: BTreeMap<u16, ChannelInfo> = BTreeMap::new();
        let mut wires: HashMap<u16, Wire> = HashMap::new();
        let mut infos: HashMap<String, CameraInfo> = HashMap::new();
        let mut transforms: Vec<TransformStamped> = Vec::new();
        while let Some(rec) = scan.next()? {
            match rec {
                Rec::Schema { id, name } => {
                    schemas.insert(id, name);
                }
                Rec::Channel { id, schema_id, topic, msg_type, wire } => {
                    // ROS 2 names `ros2msg` and `ros2idl` schemas `pkg/msg/Type`.
                    let msg_type = msg_type
                        .unwrap_or_else(|| schemas.get(&schema_id).cloned().unwrap_or_default());
                    channels.entry(id).or_insert(ChannelInfo { topic, msg_type, count: 0 });
                    wires.entry(id).or_insert(wire);
                }
                Rec::Message { channel, data } => {
                    let Some(ch) = channels.get_mut(&channel) else {
                        return Err(SequenceError::input(
                            &file,
                            format!(
                                "a message on channel {channel}, which no channel record declares"
                            ),
                        ));
                    };
                    ch.count += 1;
                    let wire = wires.get(&channel);
                    let path = scan.path();
                    if ch.msg_type == CameraInfo::TYPE && !infos.contains_key(&ch.topic) {
                        let info: CameraInfo =
                            decode(path, &ch.topic, wire, &data, ros1::camera_info)?;
                        infos.insert(ch.topic.clone(), info);
                    } else if ch.msg_type == TFMessage::TYPE && ch.topic == TF_STATIC {
                        let tf: TFMessage = decode(path, &ch.topic, wire, &data, ros1::tf_message)?;
                        if transforms.len() + tf.transforms.len() > MAX_TRANSFORMS {
                            return Err(SequenceError::input(
                                path,
                                format!("topic {TF_STATIC}: more than {MAX_TRANSFORMS} transforms"),
                            ));
                        }
                        transforms.extend(tf.transforms);
                    }
                }
            }
        }
        let (depth_candidates, color_candidates) = candidates(&channels);
        let depth_topic = choose(
            &file,
            "depth",
            "--depth-topic",
            topics.depth.as_deref(),
            &channels,
            &depth_candidates,
            &[Image::TYPE],
        )?;
        let color_topic = choose(
            &file,
            "colour",
            "--color-topic",
            topics.color.as_deref(),
            &channels,
            &color_candidates,
            &[CompressedImage::TYPE, Image::TYPE],
        )?;
        for (id, c) in &channels {
            if (c.topic == depth_topic || c.topic == color_topic)
                && let Some(Wire::Other(e)) = wires.get(id)
            {
                return Err(topic_err(
                    &file,
                    &c.topic,
                    format!("message encoding '{e}': only ROS 2's cdr and ROS 1 bags are read"),
                ));
            }
        }
        let info_of = |topic: &str| {
            let t = camera_info_topic(topic);
            infos.get(&t).cloned().map(|i| (t, i))
        };
        let meta = BagMeta {
            depth_info: info_of(&depth_topic),
            color_info: info_of(&color_topic),
            channels,
            depth_topic,
            color_topic,
            transforms,
        };
        let ids = |topic: &str| -> Vec<u16> {
            meta.channels.iter().filter(|(_, c)| c.topic == topic).map(|(id, _)| *id).collect()
        };
        let depth_channels = ids(&meta.depth_topic);
        let color_channels = ids(&meta.color_topic);
        let channel_topics = meta.channels.iter().map(|(id, c)| (*id, c.topic.clone())).collect();
        let (stream, file_len) = Stream::open(&file, bytes_read.clone())?;
        Ok(Self {
            input: input.to_path_buf(),
            stream,
            meta,
            wires,
            depth_channels,
            color_channels,
            channel_topics,
            bytes_read,
            file_len,
            depth_count: 0,
            color_count: 0,
            depth_size: None,
            pending: VecDeque::new(),
        })
    }

    /// The bag as given.
    pub fn path(&self) -> &Path {
        &self.input
    }

    /// What the first pass found.
    pub fn meta(&self) -> &BagMeta {
        &self.meta
    }

    /// A shared counter of the bytes read so far, and the file's size (for progress).
    pub fn progress(&self) -> (Arc<AtomicU64>, u64) {
        (self.bytes_read.clone(), self.file_len)
    }

    /// The size of the depth frames read so far (the first one's).
    pub fn depth_size(&self) -> Option<(usize, usize)> {
        self.depth_size
    }

    /// The rig of the bag's camera_infos and `/tf_static` ([`rig_from_meta`]).
    pub fn rig(&self) -> Result<Rig> {
        rig_from_meta(self.stream.path(), &self.meta)
    }

    /// The next depth frame (its `data`: the depth in metres as little-endian `f32`, row-major,
    /// [`BagSource::depth_size`]) or colour picture, `Ok(None)` at the end. Sequence numbers
    /// count the topic's messages (a ROS 2 header has none).
    pub fn next_event(&mut self) -> Result<Option<SourceEvent>> {
        if let Some(e) = self.pending.pop_front() {
            return Ok(Some(e));
        }
        while let Some(rec) = self.stream.next()? {
            let Rec::Message { channel, data } = rec else { continue };
            let path = self.stream.path();
            let wire = self.wires.get(&channel);
            if self.depth_channels.contains(&channel) {
                let topic = &self.channel_topics[&channel];
                let img: Image = decode(path, topic, wire, &data, ros1::image)?;
                let timestamp = stamp_ticks(path, topic, &img.header)?;
                let (w, h, metres) = depth_metres(&img).map_err(|m| topic_err(path, topic, m))?;
                match self.depth_size {
                    None => self.depth_size = Some((w, h)),
                    Some(s) if s != (w, h) => {
                        return Err(topic_err(
                            path,
                            topic,
                            format!("a {w}x{h} image after {}x{} ones", s.0, s.1),
                        ));
                    }
                    Some(_) => {}
                }
                let data = metres.iter().flat_map(|v| v.to_le_bytes()).collect();
                let sequence = self.depth_count;
                self.depth_count = self.depth_count.wrapping_add(1);
                let frame = RawDepth { sequence, timestamp, data };
                return Ok(Some(SourceEvent::Depth { frame, incomplete_before: 0 }));
            }
            if self.color_channels.contains(&channel) {
                let topic = &self.channel_topics[&channel];
                let (header, picture) = if self.meta.channels[&channel].msg_type == Image::TYPE {
                    let img: Image = decode(path, topic, wire, &data, ros1::image)?;
                    let png = color_picture(&img).map_err(|m| topic_err(path, topic, m))?;
                    (img.header, png)
                } else {
                    let c: CompressedImage =
                        decode(path, topic, wire, &data, ros1::compressed_image)?;
                    let f = c.format.to_ascii_lowercase();
                    if !(f.contains("jpeg") || f.contains("jpg") || f.contains("png")) {
                        return Err(topic_err(
                            path,
                            topic,
                            format!(
                                "CompressedImage format '{}': only jpeg and png are read",
                                c.format
                            ),
                        ));
                    }
                    (c.header, c.data)
                };
                let timestamp = stamp_ticks(path, topic, &header)?;
                let sequence = self.color_count;
                self.color_count = self.color_count.wrapping_add(1);
                return Ok(Some(SourceEvent::Color(ColorFrame {
                    sequence,
                    timestamp,
                    jpeg: picture,
                })));
            }
        }
        Ok(None)
    }
}

fn topic_err(path: &Path, topic: &str, m: impl std::fmt::Display) -> SequenceError {
    SequenceError::input(path, format!("topic {topic}: {m}"))
}

/// A header stamp in sensor ticks (0.125 ms, rounded to the nearest). Error: a negative time.
fn stamp_ticks(path: &Path, topic: &str, h: &kfuse_ros_msgs::Header) -> Result<u64> {
    let sec = u64::try_from(h.stamp.sec).map_err(|_| {
        topic_err(path, topic, format!("negative header stamp ({} s)", h.stamp.sec))
    })?;
    let ns = sec * 1_000_000_000 + u64::from(h.stamp.nanosec);
    Ok((ns + NANOS_PER_TICK / 2) / NANOS_PER_TICK)
}

/// Checks an image's size fields against its data: `width` and `height` in
/// `1..=`[`MAX_IMAGE_SIDE`], `step` ≥ `width` × `bytes_per_pixel`, `step` × `height` equal to
/// the data's length. Returns `(width, height, step)`.
fn checked_size(
    img: &Image,
    bytes_per_pixel: usize,
) -> std::result::Result<(usize, usize, usize), String> {
    let (w, h) = (img.width, img.height);
    if w == 0 || h == 0 || w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
        return Err(format!("image {w}x{h}: each side must be 1 to {MAX_IMAGE_SIDE}"));
    }
    let (w, h, step) = (w as usize, h as usize, img.step as usize);
    let row = w * bytes_per_pixel;
    if step < row {
        return Err(format!(
            "image step {step} is less than width {w} × {bytes_per_pixel} bytes ({}) of its encoding {}",
            row, img.encoding
        ));
    }
    if step.checked_mul(h) != Some(img.data.len()) {
        return Err(format!(
            "image data is {} bytes, step {step} × height {h} = {} ({} {w}x{h})",
            img.data.len(),
            step.saturating_mul(h),
            img.encoding
        ));
    }
    Ok((w, h, step))
}

/// A depth image in metres (0 = no sample): 16UC1 / mono16 millimetres (`v × 1e-3` in `f32`,
/// as the recording decoder's millimetres become metres) or 32FC1 metres (NaN, ±inf and
/// values ≤ 0 as 0). Error (a line for the user): another encoding, or sizes that disagree.
pub fn depth_metres(img: &Image) -> std::result::Result<(usize, usize, Vec<f32>), String> {
    let bpp = match img.encoding.as_str() {
        "16UC1" | "mono16" => 2,
        "32FC1" => 4,
        e => {
            return Err(format!(
                "depth encoding '{e}': expected 16UC1 (millimetres) or 32FC1 (metres)"
            ));
        }
    };
    let (w, h, step) = checked_size(img, bpp)?;
    let big = img.is_bigendian != 0;
    let mut out = Vec::with_capacity(w * h);
    for row in img.data.chunks_exact(step).take(h) {
        for px in row[..w * bpp].chunks_exact(bpp) {
            let v = if bpp == 2 {
                let b = [px[0], px[1]];
                let mm = if big { u16::from_be_bytes(b) } else { u16::from_le_bytes(b) };
                if mm > 0 { f32::from(mm) * 1e-3 } else { 0.0 }
            } else {
                let b = [px[0], px[1], px[2], px[3]];
                let m = if big { f32::from_be_bytes(b) } else { f32::from_le_bytes(b) };
                if m.is_finite() && m > 0.0 { m } else { 0.0 }
            };
            out.push(v);
        }
    }
    Ok((w, h, out))
}

/// An rgb8 / bgr8 colour `Image` as a PNG (lossless; the pipeline's colour reader decodes
/// pictures). Error: another encoding, or sizes that disagree.
pub fn color_picture(img: &Image) -> std::result::Result<Vec<u8>, String> {
    let bgr = match img.encoding.as_str() {
        "rgb8" => false,
        "bgr8" => true,
        e => {
            return Err(format!(
                "colour encoding '{e}': expected rgb8 or bgr8 (or a CompressedImage)"
            ));
        }
    };
    let (w, h, step) = checked_size(img, 3)?;
    let mut rgb = Vec::with_capacity(w * h * 3);
    for row in img.data.chunks_exact(step).take(h) {
        for px in row[..w * 3].chunks_exact(3) {
            if bgr {
                rgb.extend_from_slice(&[px[2], px[1], px[0]])
            } else {
                rgb.extend_from_slice(px)
            }
        }
    }
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w as u32, h as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::Fast);
        let mut writer = enc.write_header().map_err(|e| format!("cannot encode: {e}"))?;
        writer.write_image_data(&rgb).map_err(|e| format!("cannot encode: {e}"))?;
    }
    Ok(out)
}

fn fields(i: &CameraInfo) -> CameraInfoFields {
    // An all-zero R or P is "not given" (ROS drivers of uncalibrated cameras send zeros).
    let given = |v: &[f64]| v.iter().any(|&x| x != 0.0).then(|| v.to_vec());
    CameraInfoFields {
        width: i.width as usize,
        height: i.height as usize,
        distortion_model: Some(i.distortion_model.clone()).filter(|m| !m.is_empty()),
        k: i.k.to_vec(),
        d: i.d.clone(),
        r: given(&i.r),
        p: given(&i.p),
    }
}

fn isometry(t: &TransformStamped) -> Isometry3<f64> {
    let q = t.transform.rotation;
    let v = t.transform.translation;
    Isometry3::from_parts(
        Translation3::new(v.x, v.y, v.z),
        UnitQuaternion::from_quaternion(Quaternion::new(q.w, q.x, q.y, q.z)),
    )
}

/// The pose of frame `to` relative to frame `from` through the `/tf_static` tree
/// (`X_to = M X_from`), `None` when they are not connected.
pub fn tf_between(transforms: &[TransformStamped], from: &str, to: &str) -> Option<Isometry3<f64>> {
    // Breadth-first from `from`: M of each frame reached. An edge parent → child holds
    // X_parent = T X_child.
    let mut seen: HashMap<&str, Isometry3<f64>> = HashMap::new();
    seen.insert(from, Isometry3::identity());
    let mut queue = VecDeque::from([from]);
    while let Some(f) = queue.pop_front() {
        let m = seen[f];
        if f == to {
            return Some(m);
        }
        for t in transforms {
            let (parent, child) = (t.header.frame_id.as_str(), t.child_frame_id.as_str());
            let next = if child == f {
                (parent, isometry(t) * m)
            } else if parent == f {
                (child, isometry(t).inverse() * m)
            } else {
                continue;
            };
            if !seen.contains_key(next.0) {
                seen.insert(next.0, next.1);
                queue.push_back(next.0);
            }
        }
    }
    None
}

/// The rig of a bag: the depth and colour cameras of their camera_infos (K, D; the YAML
/// import's math, [`cameras_from_infos`]), `color_from_depth` from `/tf_static` (the colour
/// camera_info's frame to the depth camera_info's, through the static tree), else from the
/// camera_infos' R and P when they carry a pair (kfuse's bags carry both; they agree).
///
/// Errors (naming the file and topic): no camera_info for a camera (pass `--rig`), cameras
/// that do not validate, no pose between them.
pub fn rig_from_meta(path: &Path, meta: &BagMeta) -> Result<Rig> {
    let need = |info: &Option<(String, CameraInfo)>, topic: &str| {
        info.clone().ok_or_else(|| {
            topic_err(
                path,
                topic,
                format!(
                    "no camera_info for it ({} has no message); pass --rig RIG.json",
                    camera_info_topic(topic)
                ),
            )
        })
    };
    let (dt, d) = need(&meta.depth_info, &meta.depth_topic)?;
    let (ct, c) = need(&meta.color_info, &meta.color_topic)?;
    let what = (format!("topic {dt}"), format!("topic {ct}"));
    let (depth, color, pair) =
        cameras_from_infos(&fields(&d), &fields(&c), path, (&what.0, &what.1))
            .map_err(|e| SequenceError::input(path, e.to_string()))?;
    let tf = tf_between(&meta.transforms, &d.header.frame_id, &c.header.frame_id);
    let cfd = match (tf, pair) {
        (Some(m), _) => {
            let r: Matrix3<f64> = *m.rotation.to_rotation_matrix().matrix();
            RigidTransform::from_matrix(r, m.translation.vector).map_err(|e| {
                SequenceError::input(path, format!("topic {TF_STATIC}: the pose: {e}"))
            })?
        }
        (None, Some(p)) => p,
        (None, None) => {
            return Err(SequenceError::input(
                path,
                format!(
                    "no pose between the cameras: {TF_STATIC} connects no '{}' and '{}' (the camera_infos' frames), and their R and P carry no pair; pass --rig RIG.json",
                    d.header.frame_id, c.header.frame_id
                ),
            ));
        }
    };
    let mut rig = Rig::new(depth, color, cfd);
    rig.validate().map_err(|e| SequenceError::input(path, format!("the bag's rig: {e}")))?;
    rig.calibration = Some(serde_json::json!({
        "source": "ROS bag camera_info + /tf_static",
        "file": path.display().to_string(),
        "topics": [dt, ct],
    }));
    Ok(rig)
}

/// The rig of the bag `input` without reading its frames (`kfuse rig import BAG`): the first
/// pass of [`BagSource::open`] and [`rig_from_meta`].
pub fn rig_from_bag(input: &Path, topics: &TopicChoice) -> Result<Rig> {
    BagSource::open(input, topics)?.rig()
}

#[cfg(test)]
mod tests {
    use super::*;
    use kfuse_ros_msgs::{Header, Quaternion as Q, Transform, Vector3};

    #[test]
    fn camera_info_topics_follow_image_transport() {
        assert_eq!(
            camera_info_topic("/kinect2/hd/image_color/compressed"),
            "/kinect2/hd/camera_info"
        );
        assert_eq!(camera_info_topic("/kinect2/sd/image_depth"), "/kinect2/sd/camera_info");
        assert_eq!(camera_info_topic("/a/b/sd/image_depth"), "/a/b/sd/camera_info");
    }

    fn topics(list: &[(&str, &str)]) -> BTreeMap<u16, ChannelInfo> {
        list.iter()
            .enumerate()
            .map(|(i, (t, ty))| {
                let c = ChannelInfo { topic: t.to_string(), msg_type: ty.to_string(), count: 3 };
                (i as u16, c)
            })
            .collect()
    }

    fn names(v: Vec<&ChannelInfo>) -> Vec<&str> {
        v.into_iter().map(|c| c.topic.as_str()).collect()
    }

    #[test]
    fn topics_are_found_by_type_and_name() {
        let (img, comp) = (Image::TYPE, CompressedImage::TYPE);
        // kfuse's rosbag2 layout: one of each.
        let k = topics(&[
            ("/kinect2/sn_1/sd/image_depth", img),
            ("/kinect2/sn_1/sd/image_ir", img),
            ("/kinect2/sn_1/hd/image_depth_rect", img),
            ("/kinect2/sn_1/hd/image_color/compressed", comp),
            ("/kinect2/sn_1/sd/camera_info", CameraInfo::TYPE),
        ]);
        let (d, c) = candidates(&k);
        assert_eq!(names(d), ["/kinect2/sn_1/sd/image_depth"]);
        assert_eq!(names(c), ["/kinect2/sn_1/hd/image_color/compressed"]);
        // iai_kinect2's: the sensor's depth; colour in two resolutions (the caller chooses), no
        // compressed depth or IR among the colour candidates.
        let iai = topics(&[
            ("/kinect2/sd/image_depth", img),
            ("/kinect2/sd/image_depth_rect", img),
            ("/kinect2/qhd/image_depth_rect", img),
            ("/kinect2/sd/image_depth_rect/compressedDepth", comp),
            ("/kinect2/sd/image_ir/compressed", comp),
            ("/kinect2/hd/image_color/compressed", comp),
            ("/kinect2/hd/image_color_rect/compressed", comp),
            ("/kinect2/qhd/image_color/compressed", comp),
        ]);
        let (d, c) = candidates(&iai);
        assert_eq!(names(d), ["/kinect2/sd/image_depth"]);
        assert_eq!(
            names(c),
            ["/kinect2/hd/image_color/compressed", "/kinect2/qhd/image_color/compressed"]
        );
        // Only rectified depth: taken.
        let only = topics(&[("/cam/image_depth_rect", img)]);
        assert_eq!(names(candidates(&only).0), ["/cam/image_depth_rect"]);
    }

    fn image(encoding: &str, w: u32, h: u32, step: u32, len: usize) -> Image {
        Image {
            height: h,
            width: w,
            encoding: encoding.into(),
            step,
            data: vec![0; len],
            ..Default::default()
        }
    }

    #[test]
    fn image_sizes_are_checked_against_step_and_encoding() {
        assert!(depth_metres(&image("16UC1", 4, 2, 8, 16)).is_ok());
        // padded rows are fine
        assert!(depth_metres(&image("16UC1", 4, 2, 10, 20)).is_ok());
        let e = depth_metres(&image("16UC1", 4, 2, 6, 12)).unwrap_err();
        assert!(e.contains("step 6 is less than width 4"), "{e}");
        let e = depth_metres(&image("32FC1", 4, 2, 16, 16)).unwrap_err();
        assert!(e.contains("data is 16 bytes"), "{e}");
        let e = depth_metres(&image("rgb8", 4, 2, 12, 24)).unwrap_err();
        assert!(e.contains("depth encoding 'rgb8'"), "{e}");
        let e = depth_metres(&image("16UC1", 100_000, 1, 200_000, 0)).unwrap_err();
        assert!(e.contains("each side"), "{e}");
        let e = color_picture(&image("bgr8", 4, 2, 12, 23)).unwrap_err();
        assert!(e.contains("data is 23 bytes"), "{e}");
    }

    #[test]
    fn depth_values_become_metres() {
        let mut img = image("16UC1", 2, 1, 4, 4);
        img.data = [1500u16.to_le_bytes(), 0u16.to_le_bytes()].concat();
        assert_eq!(depth_metres(&img).unwrap().2, vec![1500.0f32 * 1e-3, 0.0]);
        img.is_bigendian = 1;
        img.data = [1500u16.to_be_bytes(), 7u16.to_be_bytes()].concat();
        assert_eq!(depth_metres(&img).unwrap().2, vec![1500.0f32 * 1e-3, 7.0f32 * 1e-3]);
        let mut img = image("32FC1", 3, 1, 12, 12);
        img.data = [1.25f32, f32::NAN, -1.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        assert_eq!(depth_metres(&img).unwrap().2, vec![1.25, 0.0, 0.0]);
    }

    fn ts(parent: &str, child: &str, x: f64, q: Q) -> TransformStamped {
        TransformStamped {
            header: Header { frame_id: parent.into(), ..Default::default() },
            child_frame_id: child.into(),
            transform: Transform { translation: Vector3 { x, y: 0.0, z: 0.0 }, rotation: q },
        }
    }

    #[test]
    fn poses_chain_through_the_static_tree() {
        let id = Q { x: 0.0, y: 0.0, z: 0.0, w: 1.0 };
        // 90° about z
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let rz = Q { x: 0.0, y: 0.0, z: s, w: s };
        let tfs =
            vec![ts("link", "rgb", 0.0, id), ts("rgb", "ir", -0.05, rz), ts("x", "y", 1.0, id)];
        // X_rgb = T(rgb<-ir) X_ir
        let m = tf_between(&tfs, "ir", "rgb").unwrap();
        let p = m * nalgebra::Point3::new(1.0, 0.0, 0.0);
        assert!((p - nalgebra::Point3::new(-0.05, 1.0, 0.0)).norm() < 1e-12, "{p}");
        let back = tf_between(&tfs, "rgb", "ir").unwrap();
        assert!(((back * m).translation.vector).norm() < 1e-12);
        assert!(tf_between(&tfs, "ir", "link").is_some());
        assert!(tf_between(&tfs, "ir", "y").is_none());
    }
}
