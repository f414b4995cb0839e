//! The whole run of `kfuse fuse --recording/--frames`: check the options, open the input and
//! the staged output folder ([`open`]), then read → match → decode → register → encode →
//! write every frame through [`crate::pipeline::run`] and write `index.json` (and the TUM
//! lists) ([`run`]). The command line adds what is not the sequence's own: the rig (its
//! checks against the sensor's factory parameters), a progress bar and the figures of kept
//! frames ([`Observer`]), and the printed summary.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use fusion_gpu::{Engine, EngineUsed};
use geometry::Rig;
use geometry::fusion::FusionOptions;
use kfuse_io::atomic::StagedDir;
use kfuse_ros_msgs::Message as _;
use kinect_usb::decoder::DepthDecoder;
use kinect_usb::device::DeviceInfo;
use kinect_usb::recording::ReadOptions;

use crate::bag::{BagSource, TopicChoice};
use crate::host_time::{self, HostClock};
use crate::pipeline::{self, Config, Input, Kept, Outcome, Report};
use crate::process::{self, Extras, Processor};
use crate::rosbag2::{self, Bag};
use crate::source::{FolderSource, RecordingSource, TICKS_PER_SECOND};
use crate::write::{self, FileSet, FrameWriter, Index, IndexEntry, Layout};
use crate::{Result, SequenceError, tum};

/// Most worker threads: the stages form two groups (read…register, encode+write), so a
/// third thread would have nothing of its own to do.
pub const MAX_THREADS: usize = 2;

/// Largest skew between a depth frame and its colour partner, milliseconds: a whole second
/// pairs frames 30 periods apart, far beyond any use.
pub const MAX_SKEW_LIMIT_MS: f64 = 1000.0;

/// The name of the sensor's factory parameters beside a capture's frames (and written into
/// a recording's output folder).
pub const FACTORY_PARAMS: &str = "kinect_params.json";

/// The `format` of `index.json`.
pub const INDEX_FORMAT: &str = "kfuse-sequence-index";

/// What a run reads.
#[derive(Debug, Clone)]
pub enum SequenceInput {
    /// A `.kfrec` recording and how to read a damaged one.
    Recording(PathBuf, ReadOptions),
    /// A folder of `kfuse capture` shots, or a glob of their files.
    Frames(PathBuf),
    /// A ROS 2 bag (rosbag2 folder or `.mcap` file) and its depth and colour topics.
    Bag(PathBuf, TopicChoice),
}

impl SequenceInput {
    /// The recording, folder or pattern as given.
    pub fn path(&self) -> &Path {
        match self {
            SequenceInput::Recording(p, _)
            | SequenceInput::Frames(p)
            | SequenceInput::Bag(p, _) => p,
        }
    }
}

/// How a run processes and writes.
#[derive(Debug, Clone)]
pub struct SequenceOptions {
    /// The output layout.
    pub layout: Layout,
    /// Files per frame besides the registered depth.
    pub files: FileSet,
    /// Hand every n-th frame to [`Observer::kept`] (the command line's figures).
    pub keep_every: Option<u64>,
    /// Worker threads, 1 or [`MAX_THREADS`].
    pub threads: usize,
    /// Largest depth–colour skew, milliseconds.
    pub max_skew_ms: f64,
    /// Where the per-pixel stages run.
    pub engine: Engine,
    /// The fusion options of every frame (`kfuse fuse`'s `--hole-radius` and the rest): the
    /// per-pixel stages run with them, as the single-frame `kfuse fuse` does.
    pub fusion: FusionOptions,
    /// The frames handed to [`Observer::kept`] carry H6's colour on the depth grid
    /// ([`crate::pipeline::Kept::color_on_depth`]; `kfuse fuse --recording --tsdf`).
    pub kept_color: bool,
    /// The rosbag2 layout's `sd/points` topic: each frame's coloured cloud as a
    /// `sensor_msgs/PointCloud2` (`--points`).
    pub points: bool,
}

impl SequenceOptions {
    /// The options' own errors, before anything is opened.
    pub fn check(&self, input: &SequenceInput) -> Result<()> {
        let bad = |m: String| Err(SequenceError::Options(m));
        if !(1..=MAX_THREADS).contains(&self.threads) {
            return bad(format!("--threads must be 1 or {MAX_THREADS}, got {}", self.threads));
        }
        let skew = self.max_skew_ms;
        if !(skew.is_finite() && skew > 0.0 && skew <= MAX_SKEW_LIMIT_MS) {
            return bad(format!("--max-skew-ms must be in (0, {MAX_SKEW_LIMIT_MS}], got {skew}"));
        }
        if self.points && self.layout != Layout::Rosbag2 {
            return bad(
                "--points adds the rosbag2 layout's sd/points topic; give --layout rosbag2, or \
                 write the clouds as files with --write cloud"
                    .into(),
            );
        }
        if self.layout == Layout::Rosbag2 {
            if matches!(input, SequenceInput::Frames(_)) {
                return Err(SequenceError::input(
                    input.path(),
                    "a frame folder has no sensor timestamps or serial, which the rosbag2 layout \
                     stamps and names its topics with; export a recording (`kfuse capture record`) \
                     with --layout rosbag2, or use --layout kfuse",
                ));
            }
            if matches!(input, SequenceInput::Bag(..)) {
                return Err(SequenceError::input(
                    input.path(),
                    "is a bag already: the rosbag2 layout writes the decoder's depth and IR of a                      recording, which a bag does not hold; use --layout kfuse or tum",
                ));
            }
            if self.files != FileSet::default() {
                return bad(
                    "--write: the rosbag2 layout writes topics, not per-frame files (its colour \
                     JPEGs are on hd/image_color/compressed); drop --write"
                        .into(),
                );
            }
        }
        if self.layout == Layout::Tum && matches!(input, SequenceInput::Frames(_)) {
            return Err(SequenceError::input(
                input.path(),
                "a frame folder has no sensor timestamps, which the TUM layout is named by; \
                 export a recording (`kfuse capture record`) with --layout tum, or use --layout kfuse",
            ));
        }
        Ok(())
    }

    fn extras(&self) -> Extras {
        Extras {
            holes: self.files.holes,
            color_on_depth: self.files.color_on_depth
                || self.files.cloud
                || self.points
                || self.kept_color,
            cloud: self.files.cloud || self.points,
            color_valid: self.kept_color,
        }
    }
}

/// Every name a sequence run into `out` may write there.
pub fn output_names_for(out: &Path) -> Vec<String> {
    let mut names = output_names();
    names.push("metadata.yaml".into());
    names.push(rosbag2::mcap_name(out));
    names
}

/// Every name a sequence run may write into its output folder, besides the rosbag2 layout's
/// ([`output_names_for`]).
pub fn output_names() -> Vec<String> {
    [
        "index.json",
        FACTORY_PARAMS,
        "depth",
        "rgb",
        "color",
        "holes",
        "color_on_depth",
        "cloud",
        "figures",
        "rgb.txt",
        "depth.txt",
        "associations.txt",
        "README.txt",
        // `kfuse fuse --recording … --tsdf`: the volume's mesh and surface points.
        "tsdf_mesh.ply",
        "tsdf_cloud.ply",
        "tsdf_mesh.obj",
        "tsdf_mesh.mtl",
    ]
    .map(String::from)
    .into()
}

/// How far a run has come.
#[derive(Debug, Clone)]
pub enum Progress {
    /// Bytes of the recording read (shared with its reader), of its size.
    Bytes(Arc<AtomicU64>, u64),
    /// Shots of a folder.
    Shots(u64),
}

impl Progress {
    /// How far, in the progress's unit (bytes read, or shots done of `shots_done`).
    pub fn position(&self, shots_done: u64) -> u64 {
        match self {
            Progress::Bytes(count, _) => count.load(Ordering::Relaxed),
            Progress::Shots(_) => shots_done,
        }
    }
}

/// An opened input with its staged output folder (nothing is in `--out` until [`run`]
/// commits it).
pub struct Opened {
    input: Input,
    decoder: Option<DepthDecoder>,
    info: Option<DeviceInfo>,
    progress: Progress,
    staged: StagedDir,
    source: PathBuf,
    started: Instant,
    /// A bag's own rig (its camera_infos and `/tf_static`), or why there is none.
    bag_rig: Option<Result<Rig>>,
    /// The recording's host clock (the rosbag2 layout's stamps, [`crate::host_time`]).
    clock: Option<HostClock>,
}

impl Opened {
    /// A bag's rig, built from its camera_infos and `/tf_static` ([`crate::bag::rig_from_meta`]),
    /// or why it cannot be (no camera_info: the caller's `--rig` is needed); `None` for a
    /// recording or a frame folder.
    pub fn bag_rig(&self) -> Option<std::result::Result<&Rig, &SequenceError>> {
        self.bag_rig.as_ref().map(|r| r.as_ref())
    }

    /// Whether the input is a bag.
    pub fn is_bag(&self) -> bool {
        self.bag_rig.is_some()
    }

    /// The staged output folder (files written there appear in `--out` with the run).
    pub fn staged(&self) -> &StagedDir {
        &self.staged
    }

    /// A recording's sensor (its serial, firmware and factory parameters); `None` for a folder.
    pub fn device_info(&self) -> Option<&DeviceInfo> {
        self.info.as_ref()
    }

    /// Whether the input is a recording.
    pub fn is_recording(&self) -> bool {
        self.info.is_some()
    }

    /// The sensor's factory parameters: beside a folder's frames (the file may not exist), or
    /// in the output folder for a recording (once the caller wrote them there).
    pub fn factory_params(&self) -> PathBuf {
        if self.is_recording() {
            return self.staged.join(FACTORY_PARAMS);
        }
        let dir = if self.source.is_dir() { self.source.clone() } else { glob_dir(&self.source) };
        dir.join(FACTORY_PARAMS)
    }

    /// The recording, folder or pattern as given.
    pub fn source(&self) -> &Path {
        &self.source
    }

    /// The progress measure of the run.
    pub fn progress(&self) -> &Progress {
        &self.progress
    }
}

/// Checks `options`, opens `input` and stages the output folder `out` (refusing one that
/// holds files kfuse would not write there).
pub fn open(input: &SequenceInput, out: &Path, options: &SequenceOptions) -> Result<Opened> {
    let started = Instant::now();
    options.check(input)?;
    let staged = StagedDir::new(out)?;
    staged.refuse_foreign(&output_names_for(out))?;
    let mut bag_rig = None;
    let mut clock = None;
    let (input_, decoder, info, progress) = match input {
        SequenceInput::Recording(path, read) => {
            if options.layout == Layout::Rosbag2 {
                clock = Some(host_time::recording_clock(path, *read)?);
            }
            let src = RecordingSource::open(path, *read)?;
            let info = src.info().clone();
            let decoder = process::recording_decoder(&info)?;
            let (count, len) = src.progress();
            let max_skew = (options.max_skew_ms * TICKS_PER_SECOND as f64 / 1e3).round() as u64;
            let progress = Progress::Bytes(count, len);
            (Input::Recording(Box::new(src), max_skew), Some(decoder), Some(info), progress)
        }
        SequenceInput::Frames(frames) => {
            let folder = FolderSource::open(frames)?;
            let progress = Progress::Shots(folder.shots.len() as u64);
            (Input::Folder(folder), None, None, progress)
        }
        SequenceInput::Bag(path, topics) => {
            let src = BagSource::open(path, topics)?;
            let m = src.meta();
            let raw_color = m
                .channels
                .values()
                .any(|c| c.topic == m.color_topic && c.msg_type == kfuse_ros_msgs::Image::TYPE);
            if raw_color && (options.files.color || options.layout == Layout::Tum) {
                // Those outputs are the colour JPEGs as recorded; a raw Image has none (the
                // bag source hands its pixels on as a PNG).
                return Err(SequenceError::input(
                    path,
                    format!(
                        "topic {}: a raw sensor_msgs/Image, no JPEG to copy into color/ or the TUM layout's rgb/; use --layout kfuse without --write color",
                        m.color_topic
                    ),
                ));
            }
            bag_rig = Some(src.rig());
            let (count, len) = src.progress();
            let max_skew = (options.max_skew_ms * TICKS_PER_SECOND as f64 / 1e3).round() as u64;
            (Input::Bag(Box::new(src), max_skew), None, None, Progress::Bytes(count, len))
        }
    };
    Ok(Opened {
        input: input_,
        decoder,
        info,
        progress,
        staged,
        source: input.path().to_path_buf(),
        started,
        bag_rig,
        clock,
    })
}

/// What the caller sees of a run while it goes (on the calling thread, in frame order).
pub trait Observer {
    /// A line for the user (the engine chosen, GPU decoding).
    fn note(&mut self, line: &str);
    /// A frame was written; `entry` is its index entry, `shots_done` the frames written and
    /// the shots left out so far.
    fn frame(&mut self, entry: &IndexEntry, shots_done: u64);
    /// A frame or shot the user should hear about (no colour, missing, left out).
    fn warn(&mut self, line: String);
    /// A frame handed over by [`SequenceOptions::keep_every`] (figures), with the output folder.
    fn kept(&mut self, staged: &StagedDir, kept: &Kept);
    /// The last frame is through, before `index.json` is written and the folder committed:
    /// outputs made from all frames (`kfuse fuse --tsdf`'s volume) go into `staged` here, and
    /// what they are (a JSON object) into `index.json`'s `tsdf`. An error (one line) stops the
    /// run and nothing is committed. Not called on an interrupted run.
    fn finish(
        &mut self,
        staged: &StagedDir,
    ) -> std::result::Result<Option<serde_json::Value>, String> {
        let _ = staged;
        Ok(None)
    }
}

/// A finished run.
#[derive(Debug)]
pub struct Finished {
    /// The output folder (committed).
    pub out: PathBuf,
    /// What was written into its `index.json`.
    pub index: Index,
    /// The pipeline's outcome (wall time, stage times, interrupted).
    pub outcome: Outcome,
    /// Seconds from [`open`] to the first frame (setup: rig, decoder tables, GPU).
    pub setup_s: f64,
    /// The run was stopped early into a folder that held an earlier output: its frames were
    /// discarded and the earlier output kept as it was (`out` is that folder), because a
    /// partial run must not replace a complete one.
    pub discarded: bool,
}

/// Runs the opened input through the pipeline with `rig`, writes `index.json` (and the TUM
/// lists) and commits the output folder. `stop` is polled before each frame: a stopped run
/// keeps its complete frames and a valid index (`Finished::outcome.interrupted`), unless the
/// output folder held an earlier output: that one is then kept as it was and this run's frames
/// are discarded (`Finished::discarded`).
///
/// Errors: a stage's first error; a run that fused no frame (nothing is written).
pub fn run(
    opened: Opened,
    rig: &Rig,
    options: &SequenceOptions,
    observer: &mut dyn Observer,
    stop: &(dyn Fn() -> bool + Sync),
) -> Result<Finished> {
    let Opened { input, decoder, info, progress: _, staged, source, started, bag_rig, clock } =
        opened;
    // Frames with sensor times: a recording's, or a bag's header stamps.
    let recording = info.is_some() || bag_rig.is_some();
    let engine = options.engine.open()?;
    if let EngineUsed::CpuFallback { reason } = &engine.1 {
        observer.note(&format!("no GPU, registering on the CPU: {reason}"));
    }
    let gpu = matches!(engine.1, EngineUsed::Gpu { .. });
    let units = options.layout.units_per_metre();
    let mut processor =
        Processor::new(rig, decoder, options.extras(), units, &options.fusion, engine.0)
            .map_err(|e| e.context(format!("setting up registration for {}", source.display())))?;
    // The rosbag2 layout publishes the decoder's depth and IR (`sd/` topics): decoded on the
    // CPU, kept per frame.
    if options.layout == Layout::Rosbag2 {
        processor.decoding.keep_sensor_images();
    }
    // On the GPU, a recording's depth is decoded there too (the frame never leaves the GPU)
    // unless the depth is needed on the CPU: figures, the cloud, a depth correction, the
    // rosbag2 layout's sd/ topics.
    if let (Some(info), None) = (&info, options.keep_every)
        && processor
            .decode_on_gpu(info)
            .map_err(|e| e.context("setting up depth decoding on the GPU"))?
    {
        observer.note("depth decoding: on the GPU");
    }
    let engine = processor.adapter().unwrap_or_else(|| "cpu".into());
    if gpu {
        observer.note(&format!("GPU adapter: {engine}"));
    }
    let mut writer = FrameWriter::new(
        staged.path(),
        options.layout,
        options.files,
        (rig.color.width, rig.color.height),
        (rig.depth.width, rig.depth.height),
    )?;
    if options.layout == Layout::Rosbag2 {
        let info = info.as_ref().ok_or_else(|| {
            SequenceError::input(
                &source,
                "the rosbag2 layout needs a recording (its sensor's serial and times)",
            )
        })?;
        let file = rosbag2::mcap_name(staged.destination());
        let clock = clock.ok_or_else(|| {
            SequenceError::Pipeline("the rosbag2 layout's recording has no host clock".into())
        })?;
        writer = writer.with_bag(Bag::create(
            staged.path(),
            &file,
            &info.serial,
            rig,
            clock,
            options.points,
        )?);
    }
    let (mut frames, mut missing, mut skipped) = (Vec::new(), Vec::new(), Vec::new());
    let mut on_report = |r: Report| -> Result<()> {
        match r {
            Report::Frame(entry, kept) => {
                if entry.color.is_none() {
                    // A folder's shots have no timestamps: a missing colour file, not a skew.
                    let why = if recording {
                        format!("no colour frame within {} ms", options.max_skew_ms)
                    } else {
                        "no colour image of this shot".to_string()
                    };
                    let name = entry.name.clone().unwrap_or_else(|| entry.number.to_string());
                    observer
                        .warn(format!("frame {name}: {why}; its depth is written without colour"));
                }
                if let Some(k) = kept {
                    observer.kept(&staged, &k);
                }
                observer.frame(&entry, (frames.len() + 1 + skipped.len()) as u64);
                frames.push(entry);
            }
            Report::Missing(m) => {
                observer.warn(format!(
                    "frame {} (depth sequence {}): {}",
                    m.number,
                    m.depth_sequence,
                    m.reason.text()
                ));
                missing.push(m);
            }
            Report::Skipped(s) => {
                observer.warn(format!("shot {}: left out: {}", s.name, s.reason));
                skipped.push(s);
            }
        }
        Ok(())
    };
    let config = Config { threads: options.threads, keep_every: options.keep_every };
    let setup_s = started.elapsed().as_secs_f64();
    let outcome = pipeline::run(input, processor, &writer, config, stop, &mut on_report)
        .map_err(|e| e.context(format!("processing {}", source.display())))?;
    if frames.is_empty() && !outcome.interrupted {
        // Nothing fused: an error, not a folder with an empty index and exit 0 (a user's
        // `--frames` of calibration shots without depth, and a recording cut before its first
        // frame).
        let why = skipped
            .first()
            .map(|s| format!("shot {}: {}", s.name, s.reason))
            .or_else(|| missing.first().map(|m| format!("frame {}: {}", m.number, m.reason.text())))
            .unwrap_or_else(|| "it holds no frame".into());
        return Err(SequenceError::input(
            &source,
            format!(
                "no frame could be fused ({} shot(s) left out, {} depth frame(s) missing; first: {why}); nothing was written",
                skipped.len(),
                missing.len()
            ),
        ));
    }
    let tsdf = if outcome.interrupted {
        None
    } else {
        observer.finish(&staged).map_err(|m| SequenceError::input(&source, m))?
    };
    let source_text = source.display().to_string();
    let index = Index {
        format: INDEX_FORMAT,
        version: 1,
        source: source_text.clone(),
        layout: options.layout,
        depth_png: match options.layout {
            // No PNGs: the registered depth is the bag's hd/image_depth_rect topic.
            Layout::Rosbag2 => format!(
                "none: the registered depth (colour camera z on the colour grid, {units} units per metre, 0 = no sample) is the bag's hd/image_depth_rect topic"
            ),
            Layout::Kfuse | Layout::Tum => format!(
                "16-bit, registered on the colour grid (colour camera z), {units} units per metre, 0 = no sample"
            ),
        },
        depth_units_per_metre: units,
        max_skew_ms: recording.then_some(options.max_skew_ms),
        interrupted: outcome.interrupted,
        frames,
        missing,
        skipped_shots: skipped,
        unmatched_color_frames: outcome.unmatched_colors,
        corrupt_records_skipped: usize::try_from(outcome.read_report.skipped_records)
            .unwrap_or(usize::MAX),
        truncated_recording_used: outcome.read_report.truncated,
        threads: options.threads,
        engine,
        setup_s,
        wall_s: outcome.wall_s,
        stage_s: outcome.stage_s,
        tsdf,
    };
    if let Some(bag) = writer.bag() {
        bag.finish()?;
    }
    write::write_index(staged.path(), &index)?;
    if options.layout == Layout::Tum {
        tum::write_lists(staged.path(), &index.frames, &source_text, options.max_skew_ms)?;
    }
    if outcome.interrupted && staged.replaces_existing() {
        // Dropped, the staging folder is deleted: the earlier output stays untouched.
        let out = staged.destination().to_path_buf();
        drop(staged);
        return Ok(Finished { out, index, outcome, setup_s, discarded: true });
    }
    let out = staged.commit()?;
    Ok(Finished { out, index, outcome, setup_s, discarded: false })
}

/// The folder of a glob pattern: its components before the first one with a wildcard.
pub fn glob_dir(pattern: &Path) -> PathBuf {
    let mut dir = PathBuf::new();
    for c in pattern.components() {
        let s = c.as_os_str().to_string_lossy();
        if s.contains(['*', '?', '[']) {
            break;
        }
        dir.push(c);
    }
    if dir == pattern { pattern.parent().map(Path::to_path_buf).unwrap_or_default() } else { dir }
}
