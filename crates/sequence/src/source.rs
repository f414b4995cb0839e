//! Stage 1, read: where frames come from. A `.kfrec` recording ([`RecordingSource`]: every raw
//! USB packet, assembled into depth frames and colour JPEGs by `kinect_usb::stream`, one
//! record in memory at a time) or a folder of frames written by `kfuse capture`
//! ([`FolderSource`]: `NAME_depth.png` + `NAME_color.jpg`, or `depth_NNNN.png` +
//! `color_NNNN.jpg`).

use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use kinect_usb::backend::XferStatus;
use kinect_usb::device::{DeviceInfo, StreamKind};
use kinect_usb::params::{ColorParams, DepthParams, P0Tables};
use kinect_usb::recording::{ReadOptions, ReadReport, RecordingReader};
use kinect_usb::stream::{ColorAssembler, DepthAssembler};

use crate::{Result, SequenceError};

/// Sensor timestamps count units of 0.125 ms (protocol §7): 8000 per second.
pub const TICKS_PER_SECOND: u64 = 8000;

/// A complete raw depth frame as the sensor sent it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawDepth {
    /// The sensor's frame sequence number (wraps at 2^16).
    pub sequence: u32,
    /// Sensor timestamp, [`TICKS_PER_SECOND`] units, unwrapped from the sensor's 32 bits.
    pub timestamp: u64,
    /// The 2 984 960 bytes of the frame.
    pub data: Vec<u8>,
}

/// A colour frame: the sensor's JPEG, unchanged.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ColorFrame {
    /// The sensor's colour sequence number.
    pub sequence: u32,
    /// Sensor timestamp, [`TICKS_PER_SECOND`] units, unwrapped.
    pub timestamp: u64,
    /// The JPEG bytes.
    pub jpeg: Vec<u8>,
}

/// What a recording yields, in the order the packets arrived.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SourceEvent {
    /// A complete depth frame, and how many depth frames the assembler abandoned as
    /// incomplete (a sub-image lost) since the previous complete one.
    Depth {
        /// The frame.
        frame: RawDepth,
        /// Frames abandoned as incomplete since the previous complete frame.
        incomplete_before: u64,
    },
    /// A complete colour frame.
    Color(ColorFrame),
}

/// Unwraps the sensor's 32-bit timestamps into a monotonic 64-bit count (a 32-bit count of
/// 0.125 ms wraps after 149 hours).
#[derive(Debug, Default, Clone, Copy)]
struct Unwrap {
    last: Option<u32>,
    value: u64,
}

impl Unwrap {
    fn next(&mut self, raw: u32) -> u64 {
        match self.last {
            None => self.value = u64::from(raw),
            // A step backwards (out-of-order packets) is taken as such, not as a wrap.
            Some(last) => {
                let step = raw.wrapping_sub(last) as i32;
                self.value = self.value.saturating_add_signed(i64::from(step));
            }
        }
        self.last = Some(raw);
        self.value
    }
}

/// A file that counts the bytes read from it (for the progress bar).
pub(crate) struct Counting {
    pub(crate) file: std::fs::File,
    pub(crate) count: Arc<AtomicU64>,
}

impl Read for Counting {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.file.read(buf)?;
        self.count.fetch_add(n as u64, Ordering::Relaxed);
        Ok(n)
    }
}

/// Read buffer of the recording: 1 MiB, as `RecordingReader::open`.
const READ_BUFFER: usize = 1 << 20;

/// A `.kfrec` recording, streamed: the reader holds one record, the assemblers one depth
/// frame and one colour frame.
pub struct RecordingSource {
    path: PathBuf,
    reader: RecordingReader<BufReader<Counting>>,
    bytes_read: Arc<AtomicU64>,
    file_len: u64,
    info: DeviceInfo,
    depth: DepthAssembler,
    color: ColorAssembler,
    depth_clock: Unwrap,
    color_clock: Unwrap,
    incomplete_seen: u64,
    iso_errors: u64,
}

impl RecordingSource {
    /// Opens `path` and parses its device metadata (calibration tables included). `options`
    /// as `kfuse capture --replay`: keep a truncated file's intact prefix, skip corrupt records.
    ///
    /// Errors: [`SequenceError::Recording`] for a file that is not a recording, is damaged
    /// (the message says which flag goes on) or whose calibration tables do not parse.
    pub fn open(path: &Path, options: ReadOptions) -> Result<Self> {
        // `open` checks the end record (unless a truncated prefix is accepted); the events are
        // then read through a second handle that counts bytes for the progress bar.
        crate::bag::require_rereadable(
            path,
            "a recording is read twice (checked to its end record, then frame by frame)",
        )?;
        if path.is_dir() {
            return Err(SequenceError::input(
                path,
                "is a folder: --recording takes a .kfrec file, a rosbag2 folder (with metadata.yaml and an .mcap file), an .mcap or a ROS 1 .bag; a folder of shots is read with --frames",
            ));
        }
        let m = RecordingReader::open(path, options)?.meta().clone();
        let io = |source| kinect_usb::KinectError::File { path: path.to_path_buf(), source };
        let file = bounded_read::open_without_blocking(path).map_err(io)?;
        let file_len = file.metadata().map_err(io)?.len();
        let bytes_read = Arc::new(AtomicU64::new(0));
        let counting = Counting { file, count: bytes_read.clone() };
        let reader =
            RecordingReader::new(BufReader::with_capacity(READ_BUFFER, counting), path, options)?;
        let info = DeviceInfo {
            firmware: m.firmware.clone(),
            serial: m.serial.clone(),
            hardware_info: m.hardware_info.clone(),
            depth_params: DepthParams::from_response(&m.depth_params)?,
            p0: P0Tables::from_response(&m.p0)?,
            color_params: ColorParams::from_response(&m.color_params)?,
            raw_depth_params: m.depth_params,
            raw_p0: m.p0,
            raw_color_params: m.color_params,
        };
        Ok(Self {
            path: path.to_path_buf(),
            reader,
            bytes_read,
            file_len,
            info,
            depth: DepthAssembler::new(),
            color: ColorAssembler::new(),
            depth_clock: Unwrap::default(),
            color_clock: Unwrap::default(),
            incomplete_seen: 0,
            iso_errors: 0,
        })
    }

    /// The recording file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// A shared counter of the bytes read so far, and the file's size (for progress).
    pub fn progress(&self) -> (Arc<AtomicU64>, u64) {
        (self.bytes_read.clone(), self.file_len)
    }

    /// What the sensor reported when the recording started (calibration tables included).
    pub fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// Records skipped as corrupt and whether a truncated prefix was used, so far.
    pub fn report(&self) -> ReadReport {
        kinect_usb::recording::ReplaySource::report(&self.reader)
    }

    /// Depth packets the sensor flagged with an error status (left out), so far.
    pub fn iso_errors(&self) -> u64 {
        self.iso_errors
    }

    /// Colour packets the assembler rejected (size, sequence, markers), so far.
    pub fn color_dropped(&self) -> u64 {
        self.color.stats.dropped
    }

    /// The next complete frame, `Ok(None)` at the end of the recording.
    pub fn next_event(&mut self) -> Result<Option<SourceEvent>> {
        while let Some(ev) = self.reader.next_event()? {
            if ev.status != XferStatus::Completed {
                if ev.kind == StreamKind::Depth {
                    self.iso_errors += 1;
                }
                continue;
            }
            match ev.kind {
                StreamKind::Depth => {
                    if let Some(f) = self.depth.push(&ev.data) {
                        let (sequence, raw_ts, data) = (f.sequence, f.timestamp, f.data.to_vec());
                        let incomplete = self.depth.stats.incomplete_frames;
                        let incomplete_before = incomplete - self.incomplete_seen;
                        self.incomplete_seen = incomplete;
                        let timestamp = self.depth_clock.next(raw_ts);
                        let frame = RawDepth { sequence, timestamp, data };
                        return Ok(Some(SourceEvent::Depth { frame, incomplete_before }));
                    }
                }
                StreamKind::Color => {
                    if let Some((jpeg, meta)) = self.color.push(&ev.data) {
                        let jpeg = jpeg.to_vec();
                        let timestamp = self.color_clock.next(meta.timestamp);
                        let sequence = meta.sequence;
                        return Ok(Some(SourceEvent::Color(ColorFrame {
                            sequence,
                            timestamp,
                            jpeg,
                        })));
                    }
                }
            }
        }
        Ok(None)
    }
}

/// One shot of a frame folder: its name and files.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Shot {
    /// The shot's name (`NAME` of `NAME_depth.png`, `NNNN` of `depth_NNNN.png`).
    pub name: String,
    /// The depth PNG (16-bit millimetres, 0 = invalid).
    pub depth: Option<PathBuf>,
    /// The colour JPEG.
    pub color: Option<PathBuf>,
}

/// Largest number of shots a folder or pattern may give: ten hours at 30 Hz; guards the
/// listing against a pattern that matches a whole disk.
pub const MAX_SHOTS: usize = 30 * 3600 * 10;

/// The shots of a `kfuse capture` folder or a glob pattern of depth or colour files, sorted
/// by name; a shot with only one of its two files is kept (and listed as incomplete later).
#[derive(Debug, Clone)]
pub struct FolderSource {
    /// The folder or pattern given.
    pub input: PathBuf,
    /// The shots, sorted by name.
    pub shots: Vec<Shot>,
}

/// The shot name, role (`true` = depth) and partner's file name of a `kfuse capture` file
/// name (`kfuse_capture::shot_files`).
fn shot_of(file: &str) -> Option<(String, bool, String)> {
    let scene = |suffix: &str| file.strip_suffix(suffix).filter(|n| !n.is_empty());
    if let Some(n) = scene("_depth.png") {
        return Some((n.to_string(), true, format!("{n}_color.jpg")));
    }
    if let Some(n) = scene("_color.jpg") {
        return Some((n.to_string(), false, format!("{n}_depth.png")));
    }
    let calib = |prefix: &str, ext: &str| {
        file.strip_prefix(prefix)
            .and_then(|r| r.strip_suffix(ext))
            .filter(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
    };
    if let Some(n) = calib("depth_", ".png") {
        return Some((n.to_string(), true, format!("color_{n}.jpg")));
    }
    calib("color_", ".jpg").map(|n| (n.to_string(), false, format!("depth_{n}.png")))
}

impl FolderSource {
    /// The shots of folder `input` (every `kfuse capture` shot in it) or of the glob pattern
    /// `input` (its matches; each file's partner is looked up beside it).
    ///
    /// Errors: [`SequenceError::Input`] for a bad pattern, an unreadable folder, no shot at
    /// all, or more than [`MAX_SHOTS`].
    pub fn open(input: &Path) -> Result<Self> {
        let mut files: Vec<PathBuf> = Vec::new();
        let push = |files: &mut Vec<PathBuf>, p: PathBuf| -> Result<()> {
            if files.len() >= 2 * MAX_SHOTS {
                return Err(SequenceError::input(
                    input,
                    format!("more than {MAX_SHOTS} shots; split the sequence"),
                ));
            }
            files.push(p);
            Ok(())
        };
        if input.is_dir() {
            let rd = std::fs::read_dir(input)
                .map_err(|e| SequenceError::input(input, format!("cannot list the folder: {e}")))?;
            for entry in rd.flatten() {
                push(&mut files, entry.path())?;
            }
        } else {
            let pattern = input.to_string_lossy();
            let paths = glob::glob(&pattern).map_err(|e| {
                SequenceError::input(input, format!("not a folder, and not a valid pattern: {e}"))
            })?;
            for p in paths.flatten() {
                let partner = p.file_name().and_then(|f| f.to_str()).and_then(shot_of).map(|s| s.2);
                if let (Some(partner), Some(dir)) = (partner, p.parent()) {
                    let q = dir.join(partner);
                    if q.exists() {
                        push(&mut files, q)?;
                    }
                }
                push(&mut files, p)?;
            }
        }
        let mut shots: std::collections::BTreeMap<String, Shot> = Default::default();
        for f in files {
            let Some(file) = f.file_name().and_then(|n| n.to_str()) else { continue };
            let Some((name, is_depth, partner)) = shot_of(file) else { continue };
            // Keyed by the depth file's name: a scene "0001" and a calibration shot 0001 in
            // one folder stay apart.
            let key = if is_depth { file.to_string() } else { partner };
            let shot = shots.entry(key).or_insert(Shot { name, depth: None, color: None });
            if is_depth { shot.depth = Some(f) } else { shot.color = Some(f) }
        }
        if shots.is_empty() {
            return Err(SequenceError::input(
                input,
                "no frame found: expected the files `kfuse capture` writes (NAME_depth.png + \
                 NAME_color.jpg, or depth_NNNN.png + color_NNNN.jpg)",
            ));
        }
        Ok(Self { input: input.to_path_buf(), shots: shots.into_values().collect() })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timestamps_unwrap_across_the_32_bit_wrap_and_keep_backward_steps() {
        let mut u = Unwrap::default();
        assert_eq!(u.next(u32::MAX - 10), u64::from(u32::MAX - 10));
        assert_eq!(u.next(5), u64::from(u32::MAX) + 6);
        assert_eq!(u.next(3), u64::from(u32::MAX) + 4);
    }

    #[test]
    fn shot_names_follow_kfuse_capture() {
        let s = |n: &str, d: bool, p: &str| Some((n.to_string(), d, p.to_string()));
        assert_eq!(shot_of("desk_depth.png"), s("desk", true, "desk_color.jpg"));
        assert_eq!(shot_of("desk_color.jpg"), s("desk", false, "desk_depth.png"));
        assert_eq!(shot_of("0001_depth.png"), s("0001", true, "0001_color.jpg"));
        assert_eq!(shot_of("depth_0007.png"), s("0007", true, "color_0007.jpg"));
        assert_eq!(shot_of("color_0007.jpg"), s("0007", false, "depth_0007.png"));
        assert_eq!(shot_of("ir_0007.png"), None);
        assert_eq!(shot_of("_depth.png"), None);
        assert_eq!(shot_of("depth_x1.png"), None);
    }
}
