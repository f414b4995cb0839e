//! Stages 5 and 6, encode and write: a frame's outputs as files (16-bit PNG depth, 8-bit PNG
//! hole mask, RGB PNG colour on the depth grid, PLY cloud, the sensor's JPEG copied byte for
//! byte), named by the [`Layout`], and the sequence's `index.json`.
//!
//! PNG settings ([`PNG_COMPRESSION`], [`PNG_FILTER`]): measured on a registered Kinect v2
//! depth frame (1920 × 1080, 16 bit) by `benches/sequence.rs`; see BENCHMARKS.md
//! "Sequences (issue 15)".

use std::path::{Path, PathBuf};

use geometry::{Image, PointCloud};
use kfuse_io::atomic::write_bytes_atomic;
use serde::Serialize;

use crate::color::ColorJpeg;
use crate::matching::Missing;
use crate::rosbag2::{Bag, BagMessage, SensorImages};
use crate::source::TICKS_PER_SECOND;
use crate::{Result, SequenceError};

/// zlib level of every PNG written per frame: `Fastest` (fdeflate). Measured on a registered
/// depth frame of the simulated Kinect (1920 × 1080, 16 bit, ~9 % of the pixels set;
/// `benches/sequence.rs`, BENCHMARKS.md): `Fastest` and `Fast` give the same bytes here and
/// `Fastest` is the quicker; `Balanced` (zlib level 6) is 1.8x smaller but ~20x slower, which
/// would make encoding the pipeline's slowest stage.
pub const PNG_COMPRESSION: png::Compression = png::Compression::Fastest;

/// Row filter of every PNG written per frame: none. The registered depth is sparse (runs of
/// zeros between isolated samples), where a filter turns each sample into two non-zero
/// differences: `NoFilter` gave the smallest file (0.63 MB vs 0.97 `Sub`, 1.23 `Up`, 0.86
/// `Adaptive`) and the fastest encode (BENCHMARKS.md).
pub const PNG_FILTER: png::Filter = png::Filter::NoFilter;

/// Where the frames go and in which units.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Layout {
    /// kfuse's own: `depth/NNNNNN.png` (millimetres) by frame number, `index.json`.
    Kfuse,
    /// TUM RGB-D: `rgb/`, `depth/` named by timestamp (seconds), `rgb.txt`, `depth.txt`,
    /// `associations.txt`, depth at [`TUM_UNITS_PER_METRE`].
    Tum,
    /// A rosbag2 folder (`metadata.yaml`, `<name>_0.mcap`) of ROS 2 topics
    /// ([`crate::rosbag2`]), depth in millimetres; recordings only.
    Rosbag2,
}

/// Depth units per metre of the TUM RGB-D benchmark's PNGs (its `depth_scale` 5000: 0.2 mm
/// steps, up to 13.1 m), which Open3D's TUM reader and ORB-SLAM's TUM examples assume.
pub const TUM_UNITS_PER_METRE: f64 = 5000.0;

/// Depth units per metre of the kfuse layout: millimetres, as every 16-bit depth kfuse writes.
pub const KFUSE_UNITS_PER_METRE: f64 = 1000.0;

impl Layout {
    /// Units per metre of the depth PNGs.
    pub fn units_per_metre(self) -> f64 {
        match self {
            Layout::Kfuse | Layout::Rosbag2 => KFUSE_UNITS_PER_METRE,
            Layout::Tum => TUM_UNITS_PER_METRE,
        }
    }
}

/// A time in sensor ticks as seconds with six decimals, exactly (a tick is 125 µs).
pub fn seconds_text(ticks: u64) -> String {
    let us = ticks * (1_000_000 / TICKS_PER_SECOND);
    format!("{}.{:06}", us / 1_000_000, us % 1_000_000)
}

/// What the index says about one frame's colour partner.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ColorRef {
    /// The sensor's colour sequence number (recordings).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sequence: Option<u32>,
    /// Sensor time, seconds (recordings).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_s: Option<String>,
    /// Sensor time, ticks of 0.125 ms (recordings).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_ticks: Option<u64>,
}

/// Everything the writer needs to know about a frame besides its pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameMeta {
    /// Frame number: depth periods since the first frame (recordings) or the shot's position
    /// (folders).
    pub number: u64,
    /// The shot's name (folders).
    pub name: Option<String>,
    /// The depth sequence number (recordings).
    pub depth_sequence: Option<u32>,
    /// The depth frame's sensor time in ticks (recordings).
    pub depth_time: Option<u64>,
    /// The colour partner, if any.
    pub color: Option<ColorRef>,
}

/// One line of `index.json`'s `frames`.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct IndexEntry {
    /// Frame number.
    pub number: u64,
    /// Shot name (folders).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Depth sequence number (recordings).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth_sequence: Option<u32>,
    /// Depth time, seconds (recordings).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth_time_s: Option<String>,
    /// Depth time, ticks (recordings).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth_time_ticks: Option<u64>,
    /// The colour partner (`null`: none within the skew limit, or none in the shot).
    pub color: Option<ColorRef>,
    /// Depth samples that landed on the colour image.
    pub landed: usize,
    /// Files written, relative to the output folder.
    pub files: Vec<String>,
}

/// Which files to write per frame besides the registered depth.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FileSet {
    /// `holes/…png`.
    pub holes: bool,
    /// `color_on_depth/…png`.
    pub color_on_depth: bool,
    /// `cloud/…ply`.
    pub cloud: bool,
    /// The sensor's JPEG (`color/` in the kfuse layout; always `rgb/` in the TUM layout).
    pub color: bool,
}

/// A frame's files, encoded, not yet written.
pub struct Encoded {
    /// The frame.
    pub meta: FrameMeta,
    /// Samples landed (for the index).
    pub landed: usize,
    /// (relative path, bytes) of every file.
    pub files: Vec<(String, Vec<u8>)>,
    /// The frame's messages (the rosbag2 layout).
    pub messages: Vec<BagMessage>,
}

/// The per-frame outputs of one run.
#[derive(Debug)]
pub struct FrameWriter {
    root: PathBuf,
    layout: Layout,
    set: FileSet,
    color_size: (usize, usize),
    depth_size: (usize, usize),
    /// The bag of the rosbag2 layout.
    bag: Option<Bag>,
}

/// Encodes `data` (rows of `width` samples, 8-bit or big-endian 16-bit) as a PNG with
/// [`PNG_COMPRESSION`] and [`PNG_FILTER`].
pub fn encode_png(
    width: usize,
    height: usize,
    color: png::ColorType,
    depth: png::BitDepth,
    data: &[u8],
    compression: png::Compression,
    filter: png::Filter,
) -> std::result::Result<Vec<u8>, png::EncodingError> {
    let mut out = Vec::with_capacity(data.len() / 4);
    {
        let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
        enc.set_color(color);
        enc.set_depth(depth);
        enc.set_compression(compression);
        enc.set_filter(filter);
        let mut w = enc.write_header()?;
        w.write_image_data(data)?;
        w.finish()?;
    }
    Ok(out)
}

/// A 16-bit grey image as PNG bytes (big-endian samples, as PNG stores them).
pub fn encode_png16(width: usize, height: usize, values: &[u16]) -> Result<Vec<u8>, String> {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
    encode_png(
        width,
        height,
        png::ColorType::Grayscale,
        png::BitDepth::Sixteen,
        &bytes,
        PNG_COMPRESSION,
        PNG_FILTER,
    )
    .map_err(|e| e.to_string())
}

fn ply_bytes(cloud: &PointCloud) -> Vec<u8> {
    // Binary little-endian PLY: float x y z, and uchar rgb when the cloud is coloured.
    let color = cloud.colors.len() == cloud.points.len() && !cloud.points.is_empty();
    let mut head = format!(
        "ply\nformat binary_little_endian 1.0\ncomment kfuse sequence frame, metres, depth camera frame (x right, y down, z forward)\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n",
        cloud.points.len()
    );
    if color {
        head.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
    head.push_str("end_header\n");
    let mut out = head.into_bytes();
    for (i, p) in cloud.points.iter().enumerate() {
        for c in p {
            out.extend_from_slice(&c.to_le_bytes());
        }
        if color {
            out.extend_from_slice(&cloud.colors[i]);
        }
    }
    out
}

impl FrameWriter {
    /// Writes into `root` (the staging folder) in `layout`, the files of `set`, for a rig of
    /// these colour and depth sizes. Creates the layout's folders.
    pub fn new(
        root: &Path,
        layout: Layout,
        set: FileSet,
        color_size: (usize, usize),
        depth_size: (usize, usize),
    ) -> Result<Self> {
        let w = Self { root: root.to_path_buf(), layout, set, color_size, depth_size, bag: None };
        for dir in w.folders() {
            let p = root.join(dir);
            std::fs::create_dir_all(&p)
                .map_err(|e| SequenceError::input(&p, format!("cannot create the folder: {e}")))?;
        }
        Ok(w)
    }

    /// The layout.
    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// Writes the frames into `bag` (the rosbag2 layout).
    pub fn with_bag(mut self, bag: Bag) -> Self {
        self.bag = Some(bag);
        self
    }

    /// The bag of the rosbag2 layout.
    pub fn bag(&self) -> Option<&Bag> {
        self.bag.as_ref()
    }

    /// The folders this writer fills.
    pub fn folders(&self) -> Vec<&'static str> {
        if self.layout == Layout::Rosbag2 {
            return Vec::new();
        }
        let mut v = vec!["depth"];
        match self.layout {
            Layout::Tum => v.push("rgb"),
            Layout::Kfuse if self.set.color => v.push("color"),
            Layout::Kfuse | Layout::Rosbag2 => {}
        }
        for (on, dir) in [
            (self.set.holes, "holes"),
            (self.set.color_on_depth, "color_on_depth"),
            (self.set.cloud, "cloud"),
        ] {
            if on {
                v.push(dir);
            }
        }
        v
    }

    /// The file stem of a frame: its number (kfuse) or its depth time in seconds (TUM).
    fn stem(&self, meta: &FrameMeta) -> String {
        match (self.layout, meta.depth_time) {
            (Layout::Tum, Some(t)) => seconds_text(t),
            _ => format!("{:06}", meta.number),
        }
    }

    /// Whether [`FrameWriter::encode`] writes each frame's colour JPEG as the scene is
    /// ([`ColorJpeg::scene_jpeg`]: the TUM layout's `rgb/`, `--write color`, the rosbag2
    /// layout's compressed colour), so that a sensor's mirrored JPEG is flipped per frame.
    pub fn writes_scene_jpeg(&self) -> bool {
        matches!(self.layout, Layout::Tum | Layout::Rosbag2) || self.set.color
    }

    /// Encodes a frame's files, or its messages in the rosbag2 layout (nothing is written
    /// yet). `jpeg` is the frame's colour JPEG, written as the scene is
    /// ([`ColorJpeg::scene_jpeg`]); `sensor` the decoder's depth and IR (rosbag2 layout).
    pub fn encode(
        &self,
        meta: FrameMeta,
        r: &crate::process::Registered,
        jpeg: Option<&ColorJpeg>,
        sensor: Option<&SensorImages>,
    ) -> Result<Encoded> {
        if self.layout == Layout::Rosbag2 {
            let bag = self.bag.as_ref().ok_or_else(|| {
                SequenceError::Pipeline("the rosbag2 layout's writer has no bag".into())
            })?;
            return self.encode_messages(bag, meta, r, jpeg, sensor);
        }
        let stem = self.stem(&meta);
        let err = |name: &str, message: String| SequenceError::Encode {
            path: self.root.join(name),
            message,
        };
        let mut files = Vec::new();
        let (cw, ch) = self.color_size;
        let name = format!("depth/{stem}.png");
        let png = encode_png16(cw, ch, &r.depth_units).map_err(|m| err(&name, m))?;
        files.push((name, png));
        if let (true, Some(j)) = (self.writes_scene_jpeg(), jpeg) {
            let (dir, color_stem) =
                match (self.layout, meta.color.as_ref().and_then(|c| c.time_ticks)) {
                    (Layout::Tum, Some(t)) => ("rgb", seconds_text(t)),
                    (Layout::Tum, None) => ("rgb", stem.clone()),
                    (Layout::Kfuse | Layout::Rosbag2, _) => ("color", stem.clone()),
                };
            let name = format!("{dir}/{color_stem}.jpg");
            let source = PathBuf::from(format!("frame {}", meta.number));
            let bytes = j.scene_jpeg(&source)?.into_owned();
            files.push((name, bytes));
        }
        if let (true, Some(m)) = (self.set.holes, &r.holes) {
            let name = format!("holes/{stem}.png");
            let png = encode_png(
                cw,
                ch,
                png::ColorType::Grayscale,
                png::BitDepth::Eight,
                m,
                PNG_COMPRESSION,
                PNG_FILTER,
            )
            .map_err(|e| err(&name, e.to_string()))?;
            files.push((name, png));
        }
        if let (true, Some(c)) = (self.set.color_on_depth, &r.color_on_depth) {
            let name = format!("color_on_depth/{stem}.png");
            files.push((name.clone(), self.rgb_png(c).map_err(|e| err(&name, e))?));
        }
        if let (true, Some(cloud)) = (self.set.cloud, &r.cloud) {
            files.push((format!("cloud/{stem}.ply"), ply_bytes(cloud)));
        }
        Ok(Encoded { meta, landed: r.landed, files, messages: Vec::new() })
    }

    fn encode_messages(
        &self,
        bag: &Bag,
        meta: FrameMeta,
        r: &crate::process::Registered,
        jpeg: Option<&ColorJpeg>,
        sensor: Option<&SensorImages>,
    ) -> Result<Encoded> {
        let source = PathBuf::from(format!("frame {}", meta.number));
        let depth_ticks = meta.depth_time.ok_or_else(|| {
            SequenceError::input(
                &source,
                "has no sensor time, which the rosbag2 layout stamps messages with",
            )
        })?;
        let scene;
        let color = match (jpeg, meta.color.as_ref().and_then(|c| c.time_ticks)) {
            (Some(j), Some(t)) => {
                scene = j.scene_jpeg(&source)?;
                Some((scene.as_ref(), t, meta.color.as_ref().and_then(|c| c.sequence)))
            }
            _ => None,
        };
        let messages = bag.frame_messages(
            depth_ticks,
            sensor,
            self.depth_size,
            &r.depth_units,
            self.color_size,
            color,
            r.cloud.as_ref(),
        )?;
        Ok(Encoded { meta, landed: r.landed, files: Vec::new(), messages })
    }

    fn rgb_png(&self, c: &Image<[u8; 3]>) -> Result<Vec<u8>, String> {
        let (w, h) = self.depth_size;
        let bytes: Vec<u8> = c.data().iter().flatten().copied().collect();
        encode_png(
            w,
            h,
            png::ColorType::Rgb,
            png::BitDepth::Eight,
            &bytes,
            PNG_COMPRESSION,
            PNG_FILTER,
        )
        .map_err(|e| e.to_string())
    }

    /// Writes an encoded frame's files (each atomically) and returns its index entry.
    pub fn write(&self, e: Encoded) -> Result<IndexEntry> {
        if let Some(bag) = &self.bag {
            bag.write(e.messages)?;
        }
        let mut names = Vec::with_capacity(e.files.len());
        for (name, bytes) in e.files {
            write_bytes_atomic(&self.root.join(&name), &bytes)?;
            names.push(name);
        }
        let m = e.meta;
        Ok(IndexEntry {
            number: m.number,
            name: m.name,
            depth_sequence: m.depth_sequence,
            depth_time_s: m.depth_time.map(seconds_text),
            depth_time_ticks: m.depth_time,
            color: m.color,
            landed: e.landed,
            files: names,
        })
    }
}

/// A shot of a frame folder left out, and why.
#[derive(Debug, Clone, Serialize, PartialEq, Eq)]
pub struct SkippedShot {
    /// The shot's name.
    pub name: String,
    /// Why (its depth or colour file is missing).
    pub reason: String,
}

/// Time spent per stage, summed over frames (seconds of the threads that ran them). Read,
/// decode and register run one after another on one worker thread, encode and write on the
/// other (or on the same one with one thread): each thread's stages sum to at most the run's
/// wall time.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct StageSeconds {
    /// Reading the recording (records, CRCs, frame assembly, matching) or the folder's files.
    pub read: f64,
    /// Depth decoding (or reading depth PNGs) and colour JPEG decoding when needed: the sum
    /// of [`StageSeconds::decode_depth`] and [`StageSeconds::decode_color`].
    pub decode: f64,
    /// The depth part of `decode`: the raw frame decoded (or handed to the GPU), or the depth
    /// PNG read.
    pub decode_depth: f64,
    /// The colour part of `decode`: the JPEG decoded (when the outputs need its pixels).
    pub decode_color: f64,
    /// Registration and the extras (hole mask, colour on depth, cloud).
    pub register: f64,
    /// PNG encoding.
    pub encode: f64,
    /// Writing the files.
    pub write: f64,
}

impl StageSeconds {
    /// Takes worker B's stages (register, encode, write) from `b`.
    pub(crate) fn add_backend(&mut self, b: &StageSeconds) {
        self.register += b.register;
        // Worker A may have flipped some frames' colour JPEGs (`pipeline`'s shared flip).
        self.encode += b.encode;
        self.write += b.write;
    }

    /// The stages as a [`geometry::timing::Timings`] in milliseconds (for the `--timings`
    /// summary), in pipeline order; `setup_s` first.
    pub fn to_timings(&self, setup_s: f64) -> geometry::timing::Timings {
        let mut t = geometry::timing::Timings::new();
        for (stage, s) in [
            ("setup", setup_s),
            ("read", self.read),
            ("decode depth", self.decode_depth),
            ("decode colour", self.decode_color),
            ("register", self.register),
            ("encode", self.encode),
            ("write", self.write),
        ] {
            t.add(stage, s * 1e3);
        }
        t
    }
}

/// `index.json`: every frame written, every frame missing, and how the run went.
#[derive(Debug, Clone, Serialize)]
pub struct Index {
    /// `"kfuse-sequence-index"`.
    pub format: &'static str,
    /// Format version.
    pub version: u32,
    /// The recording or frame folder.
    pub source: String,
    /// The layout.
    pub layout: Layout,
    /// What the depth PNGs hold.
    pub depth_png: String,
    /// Depth units per metre in the depth PNGs.
    pub depth_units_per_metre: f64,
    /// Largest depth-to-colour time difference of a pair, milliseconds (recordings).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_skew_ms: Option<f64>,
    /// The run was stopped by Ctrl-C / SIGTERM: every frame listed is complete, the frames
    /// after the last one were not processed.
    pub interrupted: bool,
    /// Frames written, by frame number.
    pub frames: Vec<IndexEntry>,
    /// Depth frames of the recording that are not in the output, by frame number.
    pub missing: Vec<Missing>,
    /// Shots of a frame folder left out.
    pub skipped_shots: Vec<SkippedShot>,
    /// Colour frames without a depth partner (not written).
    pub unmatched_color_frames: u64,
    /// Records of the recording left out as corrupt (`--skip-corrupt`).
    pub corrupt_records_skipped: usize,
    /// The recording was truncated and its intact beginning used (`--allow-truncated`).
    pub truncated_recording_used: bool,
    /// Worker threads.
    pub threads: usize,
    /// Registration engine (`cpu` or the GPU adapter).
    pub engine: String,
    /// Seconds before the pipeline started: opening the input, the rig, setting up the
    /// decoder and registration (the GPU's adapter and pipelines on `--engine gpu`), the
    /// output folders.
    pub setup_s: f64,
    /// Wall-clock seconds of the run (reading to last write).
    pub wall_s: f64,
    /// Seconds per stage, summed over frames.
    pub stage_s: StageSeconds,
    /// The volume made from the frames (`kfuse fuse --recording --tsdf`): its files, voxel
    /// size, frames integrated, mesh size.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tsdf: Option<serde_json::Value>,
}

/// Writes `index` as `index.json` in `root`, atomically.
pub fn write_index(root: &Path, index: &Index) -> Result<()> {
    let path = root.join("index.json");
    let mut json = serde_json::to_string_pretty(index)
        .map_err(|e| SequenceError::Encode { path: path.clone(), message: e.to_string() })?;
    json.push('\n');
    write_bytes_atomic(&path, json.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_are_exact_at_six_decimals() {
        assert_eq!(seconds_text(0), "0.000000");
        assert_eq!(seconds_text(1), "0.000125");
        assert_eq!(seconds_text(8000), "1.000000");
        assert_eq!(seconds_text(8000 * 3600 + 267), "3600.033375");
    }

    #[test]
    fn png16_round_trips_through_the_image_crate() {
        let (w, h) = (37, 5);
        let values: Vec<u16> = (0..w * h).map(|i| (i as u16).wrapping_mul(977)).collect();
        let bytes = encode_png16(w, h, &values).unwrap();
        let img = image::load_from_memory(&bytes).unwrap().into_luma16();
        assert_eq!(img.into_raw(), values);
    }
}
