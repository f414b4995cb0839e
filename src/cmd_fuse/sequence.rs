//! `kfuse fuse --recording` / `--frames`: a whole recording or frame folder through the
//! streamed pipeline of `kfuse-sequence`, into one output folder that appears when the run
//! ends (Ctrl-C included: the complete frames and a valid index are kept).

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use geometry::{DepthKind, Rig};
use indicatif::{ProgressBar, ProgressStyle};
use kfuse_io::atomic::StagedDir;
use kfuse_io::rig_io::{self, Calibration};
use kfuse_sequence::bag::TopicChoice;
use kfuse_sequence::command::{
    self, Finished, Observer, Opened, Progress, SequenceInput, SequenceOptions,
};
use kfuse_sequence::matching::DEFAULT_MAX_SKEW_TICKS;
use kfuse_sequence::pipeline::Kept;
use kfuse_sequence::source::TICKS_PER_SECOND;
use kfuse_sequence::write::{FileSet, IndexEntry, Layout};
use kinect_usb::recording::ReadOptions;

use super::{FuseArgs, inputs};

/// Missing or colourless frames named one by one on stderr; the rest are counted (all are in
/// index.json).
const MAX_LISTED: usize = 20;

/// The sequence flags of `kfuse fuse`.
#[derive(Args, Debug, Clone, Default)]
#[command(next_help_heading = "Sequences (a recording or a frame folder)")]
pub struct SequenceArgs {
    /// A raw recording (`kfuse capture record`): every depth frame is decoded, matched with
    /// the colour frame nearest in time, registered and written. Without --rig, the rig is
    /// fitted to the sensor's factory parameters stored in the recording. Also a ROS 2 bag (a
    /// rosbag2 folder with metadata.yaml, or an .mcap file): its depth Image (16UC1 mm or
    /// 32FC1 m) and colour (CompressedImage, or Image rgb8/bgr8) matched by header stamp;
    /// without --rig, the rig of its camera_infos and /tf_static.
    #[arg(long, value_name = "SESSION.kfrec|BAG", conflicts_with_all = ["color", "depth", "mat", "frames"])]
    pub recording: Option<PathBuf>,
    /// A bag's depth topic (sensor_msgs/Image); by default the one Image topic named *depth*
    /// (not *rect* where another is there).
    #[arg(long, value_name = "TOPIC", requires = "recording")]
    pub depth_topic: Option<String>,
    /// A bag's colour topic (sensor_msgs/CompressedImage or Image); by default the one such
    /// topic (a CompressedImage, or an Image named *color*/*rgb*).
    #[arg(long, value_name = "TOPIC", requires = "recording")]
    pub color_topic: Option<String>,
    /// A folder of `kfuse capture` shots (NAME_depth.png with NAME_color.jpg, or
    /// depth_NNNN.png with color_NNNN.jpg), or a quoted glob of their files. Without --rig,
    /// the folder's kinect_params.json.
    #[arg(long, value_name = "DIR|GLOB", conflicts_with_all = ["color", "depth", "mat"])]
    pub frames: Option<PathBuf>,
    /// Output layout: kfuse (depth/NNNNNN.png in mm, by frame number), tum (TUM RGB-D:
    /// rgb/, depth/ at 5000 per metre, rgb.txt, depth.txt, associations.txt; recordings only)
    /// or rosbag2 (a ROS 2 bag: metadata.yaml + OUT_0.mcap, topics /kinect2/sn_SERIAL/...;
    /// recordings only).
    #[arg(long, value_enum, default_value_t = LayoutArg::Kfuse)]
    pub layout: LayoutArg,
    /// Per-frame outputs besides the registered depth, comma-separated: holes (H8 mask),
    /// color-on-depth (H6), cloud (PLY, depth camera frame), color (the sensor's JPEG).
    #[arg(long, value_enum, value_delimiter = ',', value_name = "WHAT")]
    pub write: Vec<WriteArg>,
    /// With --layout rosbag2: add each frame's coloured cloud (the points --write cloud writes)
    /// as the topic /kinect2/sn_SERIAL/sd/points (sensor_msgs/PointCloud2: x, y, z float32
    /// metres in the IR optical frame, rgb float32 packed 0x00RRGGBB).
    #[arg(long)]
    pub points: bool,
    /// The lab's eight figures for every N-th frame (`every:N`), in figures/NNNNNN/; none by
    /// default (each costs a full single-frame fusion, ~1-3 s).
    #[arg(long, value_name = "every:N", value_parser = parse_every)]
    pub figures: Option<u64>,
    /// Worker threads: 1 (every stage on one) or 2 (read/decode/register | encode/write).
    #[arg(long, default_value_t = 2, value_name = "1|2")]
    pub threads: usize,
    /// Largest time between a depth frame and its colour partner, milliseconds (default:
    /// half the 30 Hz frame period).
    #[arg(long, value_name = "MS", default_value_t = DEFAULT_MAX_SKEW_TICKS as f64 * 1e3 / TICKS_PER_SECOND as f64, allow_negative_numbers = true)]
    pub max_skew_ms: f64,
    /// Accept a truncated recording and use its intact beginning.
    #[arg(long)]
    pub allow_truncated: bool,
    /// Leave out records of the recording whose checksum does not match.
    #[arg(long)]
    pub skip_corrupt: bool,
    /// With --recording and --tsdf: integrate only the first N frames (default: every frame;
    /// the later frames are still decoded and written as frames).
    #[arg(long, value_name = "N")]
    pub frames_max: Option<u64>,
}

/// `--layout`.
#[derive(ValueEnum, Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LayoutArg {
    /// depth/NNNNNN.png (millimetres) by frame number, index.json.
    #[default]
    Kfuse,
    /// The TUM RGB-D benchmark's layout.
    Tum,
    /// A rosbag2 folder (MCAP) that `ros2 bag play` and Foxglove open.
    Rosbag2,
}

/// `--write`.
#[derive(ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum WriteArg {
    /// holes/…png: H8 disocclusion mask on the colour grid (255 = hole).
    Holes,
    /// color_on_depth/…png: H6 colour on the depth grid.
    ColorOnDepth,
    /// cloud/…ply: H1 points in the depth camera frame, coloured by H6.
    Cloud,
    /// color/…jpg: the sensor's JPEG, unchanged (always written in the TUM layout as rgb/).
    Color,
}

fn parse_every(s: &str) -> Result<u64, String> {
    s.strip_prefix("every:")
        .and_then(|n| n.parse::<u64>().ok())
        .filter(|&n| n >= 1)
        .ok_or_else(|| format!("'{s}': expected every:N with N >= 1 (e.g. every:30)"))
}

impl FuseArgs {
    /// Whether this is a sequence run (`--recording` or `--frames`).
    pub fn is_sequence(&self) -> bool {
        self.sequence.recording.is_some() || self.sequence.frames.is_some()
    }
}

/// [`inputs::factory_problem`] of `rig` (read from `rig_path`) against the factory parameters
/// in `params` (`source` names where they came from): an error, or a warning with `--force`.
fn check_against_factory(
    rig: &Rig,
    rig_path: &Path,
    params: &Path,
    source: &str,
    force: bool,
) -> Result<()> {
    if let Some(problem) = inputs::factory_problem(rig, rig_path, params, source) {
        if !force {
            bail!("{problem}; pass --force if this really is meant");
        }
        eprintln!("warning: {problem} (--force)");
    }
    Ok(())
}

/// Reads a rig file: a kfuse rig, or the sensor's kinect_params.json (the rig fitted to its
/// factory parameters, as `kfuse rig import` does).
fn load_rig(path: &Path, force: bool) -> Result<Rig> {
    let imported = rig_io::import(&[path.to_path_buf()], &rig_io::ImportOptions::default())?;
    let rig = match imported.calibration {
        Calibration::Rig(rig) => rig,
        Calibration::Camera { .. } => bail!(
            "{}: this is a single-camera file; a sequence needs both cameras and color_from_depth \
             (the sensor's kinect_params.json, or a rig from `kfuse calibrate`)",
            path.display()
        ),
    };
    if force {
        for problem in rig.plausibility_problems() {
            eprintln!("warning: {}: {problem} (--force)", path.display());
        }
    } else if let Err(e) = rig.check_plausible() {
        bail!("{}: {e}; pass --force if the rig really is meant this way", path.display());
    }
    Ok(rig)
}

/// The rig of a sequence: `--rig` (checked against the sensor's factory parameters where
/// they are known), or the rig fitted to those parameters. A recording's parameters are first
/// written into the output folder.
fn sequence_rig(args: &FuseArgs, opened: &Opened) -> Result<Rig> {
    if let Some(bag_rig) = opened.bag_rig() {
        return match (&args.rig, bag_rig) {
            (Some(r), _) => load_rig(r, args.force),
            (None, Ok(rig)) => {
                eprintln!(
                    "rig: the camera_infos and /tf_static of {} (pass --rig for another)",
                    opened.source().display()
                );
                Ok(rig.clone())
            }
            (None, Err(e)) => bail!("{e}"),
        };
    }
    if let Some(info) = opened.device_info() {
        kfuse_capture::write_params_json(opened.staged().path(), info)?;
    }
    let params = opened.factory_params();
    let source = opened.source();
    // A recording's parameters are in the output folder; name the recording.
    let params_source =
        if opened.is_recording() { source.display() } else { params.display() }.to_string();
    match &args.rig {
        Some(r) => {
            let rig = load_rig(r, args.force)?;
            if params.is_file() {
                check_against_factory(&rig, r, &params, &params_source, args.force)?;
            }
            Ok(rig)
        }
        None if !params.exists() => bail!(
            "{}: no kinect_params.json beside the frames; pass --rig RIG.json",
            source.display()
        ),
        None => {
            let rig = if opened.is_recording() {
                load_rig(&params, args.force).with_context(|| {
                    format!(
                        "fitting a rig to the factory parameters stored in {}",
                        source.display()
                    )
                })?
            } else {
                load_rig(&params, args.force)?
            };
            eprintln!(
                "rig: fitted to the sensor's factory parameters in {params_source} (pass --rig for a calibrated one)"
            );
            Ok(rig)
        }
    }
}

/// Why `--depth-kind range` cannot apply to a sequence.
const REFUSE_DEPTH_KIND: &str = "--depth-kind range: a sequence's depth is the Kinect's z depth \
     (a recording's decoder, a capture folder's PNGs); drop --depth-kind";
/// Why `--depth-scale` cannot apply to a sequence.
const REFUSE_DEPTH_SCALE: &str = "--depth-scale: a sequence's depth is the sensor's millimetres \
     (a recording's decoder, a capture folder's 16-bit PNGs); drop --depth-scale";
/// Why `--rectified` cannot apply to a sequence.
const REFUSE_RECTIFIED: &str = "--rectified: a sequence's frames are the sensor's raw \
     (distorted) images; drop --rectified, or fuse undistorted images one at a time with --color/--depth";
/// Why `--no-figures` and `--figures every:N` cannot go together.
const REFUSE_NO_FIGURES: &str =
    "--no-figures contradicts --figures every:N; drop one (a sequence draws no figures by default)";

/// The flags of single-frame `kfuse fuse` that cannot apply to a sequence: the first one
/// given, as one line naming it and the fix. `--no-figures` alone is accepted (a sequence
/// draws figures only with `--figures`); the options of several Kinects (`--sensor`, `--view`,
/// `--shot`, `--virtual-view`, `--tsdf`) are refused by that fusion (`multi::run`).
fn refuse_single_frame_flags(args: &FuseArgs) -> Result<()> {
    if args.depth_kind != super::DepthKindArg::Z {
        bail!("{REFUSE_DEPTH_KIND}");
    }
    if args.depth_scale != kfuse_io::images::MILLIMETRES {
        bail!("{REFUSE_DEPTH_SCALE}");
    }
    if args.rectified {
        bail!("{REFUSE_RECTIFIED}");
    }
    if args.no_figures && args.sequence.figures.is_some() {
        bail!("{REFUSE_NO_FIGURES}");
    }
    Ok(())
}

/// The sequence options of the command line, with the fusion options of `kfuse fuse`
/// (`--hole-radius`, `--resample`, `--mesh-from`, `--h5`, `--stretch-ratio`, checked as for one
/// frame): every frame is fused with them, as `kfuse fuse` fuses one frame.
fn options(args: &FuseArgs) -> Result<SequenceOptions> {
    refuse_single_frame_flags(args)?;
    let fusion = geometry::fusion::FusionOptions {
        // Per-stage timings of a single-frame fusion (the figures') are not reported.
        record_timings: false,
        ..super::options(args)?
    };
    let seq = &args.sequence;
    let has = |w: WriteArg| seq.write.contains(&w);
    Ok(SequenceOptions {
        layout: match seq.layout {
            LayoutArg::Kfuse => Layout::Kfuse,
            LayoutArg::Tum => Layout::Tum,
            LayoutArg::Rosbag2 => Layout::Rosbag2,
        },
        files: FileSet {
            holes: has(WriteArg::Holes),
            color_on_depth: has(WriteArg::ColorOnDepth),
            cloud: has(WriteArg::Cloud),
            color: has(WriteArg::Color),
        },
        keep_every: seq.figures,
        threads: seq.threads,
        max_skew_ms: seq.max_skew_ms,
        engine: args.engine(),
        fusion,
        kept_color: false,
        points: seq.points,
    })
}

fn bar_for(len: u64, unit: &str) -> ProgressBar {
    let bar = ProgressBar::new(len.max(1));
    let template = format!(
        "{{spinner}} [{{elapsed_precise}}] {{bar:30}} {{percent:>3}}% {unit} {{msg}} ETA {{eta}}"
    );
    bar.set_style(
        ProgressStyle::with_template(&template).unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.enable_steady_tick(Duration::from_millis(120));
    bar
}

/// Runs `kfuse fuse` on a recording or a frame folder.
pub fn run(args: &FuseArgs) -> Result<()> {
    let seq = &args.sequence;
    let input = match (&seq.recording, &seq.frames) {
        (Some(path), _) if kfuse_sequence::bag::is_bag(path) => SequenceInput::Bag(
            path.clone(),
            TopicChoice { depth: seq.depth_topic.clone(), color: seq.color_topic.clone() },
        ),
        (Some(_), _) if seq.depth_topic.is_some() || seq.color_topic.is_some() => {
            bail!(
                "--depth-topic / --color-topic: the input is not a bag (a rosbag2 folder or .mcap file)"
            )
        }
        (Some(path), _) => SequenceInput::Recording(
            path.clone(),
            ReadOptions { keep_prefix: seq.allow_truncated, skip_corrupt: seq.skip_corrupt },
        ),
        (None, Some(frames)) => SequenceInput::Frames(frames.clone()),
        (None, None) => bail!("give --recording SESSION.kfrec or --frames DIR"),
    };
    let mut options = options(args)?;
    let tsdf = tsdf_request(args)?;
    if tsdf.is_some() {
        // Every frame's decoded depth and its colour on the depth grid (H6) handed over
        // (`Observer::kept`) to be integrated.
        options.keep_every = Some(1);
        options.kept_color = true;
    }
    options.check(&input)?;
    crate::interrupt::install()?;
    let opened = command::open(&input, &args.out, &options)?;
    let rig = sequence_rig(args, &opened)?;
    let shown = Shown::new(opened.progress().clone(), &rig, options.fusion);
    let Some((tsdf_options, frames_max)) = tsdf else {
        let mut shown = shown;
        let finished =
            command::run(opened, &rig, &options, &mut shown, &crate::interrupt::requested)?;
        shown.finish();
        return print_summary(&finished, seq.threads, args.timings);
    };
    let mut fused = TsdfShown {
        shown,
        volume: kfuse_tsdf::TsdfVolume::new(tsdf_options)?,
        options: tsdf_options,
        camera: rig.depth,
        frames_max,
        integrated: 0,
        colored: 0,
        integrate_s: 0.0,
        error: None,
        written: None,
    };
    let finished = command::run(opened, &rig, &options, &mut fused, &crate::interrupt::requested)?;
    fused.shown.finish();
    print_summary(&finished, seq.threads, args.timings)?;
    if let Some((vertices, faces, mesh_s)) = fused.written {
        let out = finished.out.display();
        println!(
            "  TSDF: {} frames integrated ({:.1} ms per frame), {} voxel blocks of {} m voxels; mesh {vertices} vertices, {faces} faces ({:.0} ms)",
            fused.integrated,
            fused.integrate_s * 1e3 / fused.integrated.max(1) as f64,
            fused.volume.block_count(),
            tsdf_options.voxel_size_m,
            mesh_s * 1e3
        );
        println!("  TSDF mesh     {out}/tsdf_mesh.ply, surface points {out}/tsdf_cloud.ply");
    }
    Ok(())
}

/// `--tsdf` (with `--voxel-size`, `--truncation`, `--frames-max`) of a recording: the volume's
/// options and the frame limit, checked before any work; `None` without `--tsdf`. One line
/// each: `--frames-max` without `--tsdf` or of 0, `--figures` with `--tsdf`, a value of the
/// volume out of its range.
fn tsdf_request(args: &FuseArgs) -> Result<Option<(kfuse_tsdf::TsdfOptions, u64)>> {
    let seq = &args.sequence;
    let Some(options) = super::multi::tsdf_options(args)? else {
        if seq.frames_max.is_some() {
            bail!("--frames-max limits the frames of --tsdf: add --tsdf");
        }
        return Ok(None);
    };
    if seq.figures.is_some() {
        bail!("--figures every:N draws single-frame figures; drop it with --tsdf");
    }
    let frames_max = match seq.frames_max {
        Some(0) => {
            bail!("--frames-max 0: integrate at least 1 frame (or drop --frames-max for all)")
        }
        Some(n) => n,
        None => u64::MAX,
    };
    Ok(Some((options, frames_max)))
}

/// [`Shown`] that also integrates every frame's depth into one TSDF volume (`--tsdf` of a
/// recording of one fixed sensor: the volume is the depth camera's frame) and writes its
/// mesh and surface points before the folder is committed.
struct TsdfShown<'a> {
    shown: Shown<'a>,
    volume: kfuse_tsdf::TsdfVolume,
    options: kfuse_tsdf::TsdfOptions,
    camera: geometry::CameraModel,
    frames_max: u64,
    integrated: u64,
    /// Frames integrated with their colour.
    colored: u64,
    integrate_s: f64,
    /// The first integration error (the run stops at its end with it).
    error: Option<String>,
    /// Vertices, faces and marching-cubes seconds of the written mesh.
    written: Option<(usize, usize, f64)>,
}

impl Observer for TsdfShown<'_> {
    fn note(&mut self, line: &str) {
        self.shown.note(line);
    }

    fn frame(&mut self, entry: &IndexEntry, shots_done: u64) {
        self.shown.frame(entry, shots_done);
    }

    fn warn(&mut self, line: String) {
        self.shown.warn(line);
    }

    fn kept(&mut self, _staged: &StagedDir, k: &Kept) {
        if self.error.is_some() || self.integrated >= self.frames_max {
            return;
        }
        let t = std::time::Instant::now();
        // The volume is the depth camera's frame; the decoded depth is z, 0 = no sample
        // (below the volume's minimum depth, so ignored).
        let frame = kfuse_tsdf::DepthFrame {
            camera: &self.camera,
            camera_from_volume: geometry::RigidTransform::identity(),
            z: &k.depth,
            // H6's colour of the frame (none for a depth frame without its colour partner:
            // the volume's colour is then the frames' that have one).
            color: k
                .color_on_depth
                .as_ref()
                .map(|(rgb, valid)| kfuse_tsdf::RegisteredColor { rgb, valid }),
        };
        match self.volume.integrate(&frame) {
            Ok(_) => {
                self.integrated += 1;
                self.colored += u64::from(k.color_on_depth.is_some());
            }
            Err(e) => {
                self.error = Some(format!(
                    "frame {}: {}",
                    k.number,
                    super::multi::memory_bound_line(&e, &self.options)
                ))
            }
        }
        self.integrate_s += t.elapsed().as_secs_f64();
    }

    fn finish(
        &mut self,
        staged: &StagedDir,
    ) -> std::result::Result<Option<serde_json::Value>, String> {
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        self.shown.bar.set_message("TSDF: marching cubes");
        let t = std::time::Instant::now();
        let mesh = self.volume.extract_mesh();
        let mesh_s = t.elapsed().as_secs_f64();
        if mesh.faces.is_empty() {
            return Err(format!(
                "--tsdf: the {} integrated frame(s) left no surface in the volume (no depth within {}–{} m?)",
                self.integrated, self.options.min_depth_m, self.options.max_depth_m
            ));
        }
        kfuse_io::fused::write_tsdf_files(
            staged.path(),
            &mesh.to_mesh(),
            &mesh.normals,
            "depth camera",
        )
        .map_err(|e| e.to_string())?;
        self.written = Some((mesh.vertices.len(), mesh.faces.len(), mesh_s));
        Ok(Some(serde_json::json!({
            "mesh": "tsdf_mesh.ply",
            "mesh_obj": "tsdf_mesh.obj",
            "cloud": "tsdf_cloud.ply",
            "frame": "the depth camera's (metres)",
            "voxel_size_m": self.options.voxel_size_m,
            "truncation_m": self.options.truncation_m,
            "frames_integrated": self.integrated,
            "frames_with_colour": self.colored,
            "blocks": self.volume.block_count(),
            "mesh_vertices": mesh.vertices.len(),
            "mesh_faces": mesh.faces.len(),
            "integrate_s": self.integrate_s,
            "mesh_s": mesh_s,
        })))
    }
}

/// The progress bar, the lines about frames (the first [`MAX_LISTED`], then a count) and the
/// figures of kept frames.
struct Shown<'a> {
    bar: ProgressBar,
    progress: Progress,
    rig: &'a Rig,
    fusion_options: geometry::fusion::FusionOptions,
    started: std::time::Instant,
    frames: u64,
    listed: usize,
}

impl<'a> Shown<'a> {
    fn new(
        progress: Progress,
        rig: &'a Rig,
        fusion_options: geometry::fusion::FusionOptions,
    ) -> Self {
        let bar = match &progress {
            Progress::Bytes(_, len) => bar_for(*len, "of the recording"),
            Progress::Shots(n) => bar_for(*n, "of the shots"),
        };
        let started = std::time::Instant::now();
        Self { bar, progress, rig, fusion_options, started, frames: 0, listed: 0 }
    }

    fn finish(&self) {
        self.bar.finish_and_clear();
        if self.listed > MAX_LISTED {
            eprintln!(
                "... and {} more such lines (all are in index.json)",
                self.listed - MAX_LISTED
            );
        }
    }
}

impl Observer for Shown<'_> {
    fn note(&mut self, line: &str) {
        self.bar.suspend(|| eprintln!("{line}"));
    }

    fn frame(&mut self, _entry: &IndexEntry, shots_done: u64) {
        self.frames += 1;
        let fps = self.frames as f64 / self.started.elapsed().as_secs_f64().max(1e-9);
        self.bar.set_message(format!("{} frames, {fps:.1} frames/s", self.frames));
        self.bar.set_position(self.progress.position(shots_done));
    }

    fn warn(&mut self, line: String) {
        self.listed += 1;
        if self.listed <= MAX_LISTED {
            self.bar.suspend(|| eprintln!("{line}"));
        }
    }

    fn kept(&mut self, staged: &StagedDir, k: &Kept) {
        // Figure errors are reported, not fatal: the frames matter more.
        if let Err(e) = draw_figures(staged, self.rig, k, &self.fusion_options) {
            self.bar.suspend(|| eprintln!("warning: figures of frame {}: {e:#}", k.number));
        }
    }
}

/// The lines printed after a run (and its Ctrl-C error).
fn print_summary(finished: &Finished, threads: usize, timings: bool) -> Result<()> {
    let Finished { out, index, outcome, setup_s, discarded } = finished;
    let n = index.frames.len();
    let fps = n as f64 / outcome.wall_s.max(1e-9);
    if *discarded {
        return Err(crate::interrupt::Interrupted(format!(
            ": {} holds an earlier output, kept as it was; the {n} frames of this stopped run were discarded (run it to the end to replace it, or into a new --out to keep a partial run)",
            out.display()
        ))
        .into());
    }
    if outcome.interrupted {
        return Err(crate::interrupt::Interrupted(format!(
            ": the {n} complete frames and their index were kept in {}",
            out.display()
        ))
        .into());
    }
    println!(
        "wrote {n} frames to {} ({fps:.1} frames/s, {threads} thread(s), {})",
        out.display(),
        index.engine
    );
    if !index.missing.is_empty() || !index.skipped_shots.is_empty() {
        println!(
            "  {} depth frames missing, {} shots left out: listed in {}/index.json",
            index.missing.len(),
            index.skipped_shots.len(),
            out.display()
        );
    }
    let s = &index.stage_s;
    println!(
        "  stages (s, summed over frames): read {:.2}, decode {:.2}, register {:.2}, encode {:.2}, write {:.2}",
        s.read, s.decode, s.register, s.encode, s.write
    );
    if timings {
        // Setup and the pipeline's wall time: with two threads, read…register and
        // encode+write each sum to at most the pipeline's part.
        let wall_ms = (setup_s + outcome.wall_s) * 1e3;
        let per: &[&str] =
            &["read", "decode depth", "decode colour", "register", "encode", "write"];
        for line in s.to_timings(*setup_s).summary(wall_ms, Some((n, "frame", per))) {
            eprintln!("{line}");
        }
        if threads > 1 {
            eprintln!(
                "  (2 threads: read, decode and register on one, encode and write on the other; each thread's stages are within the wall time)"
            );
        }
    }
    Ok(())
}

/// The lab's figures of one frame into figures/NNNNNN/ (a full single-frame fusion).
fn draw_figures(
    staged: &StagedDir,
    rig: &Rig,
    k: &Kept,
    options: &geometry::fusion::FusionOptions,
) -> Result<()> {
    let Some(jpeg) = &k.jpeg else { bail!("the frame has no colour") };
    let color = jpeg.decode(Path::new(&format!("frame {}", k.number)))?;
    // The frame's depth is prepared already (the sequence's decoder applies the request's
    // preparation): run the request on it as it is.
    let request = geometry::fusion::Request::new(rig, DepthKind::Z, *options)?;
    let output = geometry::fusion::run_on(
        &mut geometry::fusion::CpuPixels::new(),
        &request,
        &k.depth,
        &color,
    )?;
    let dir = staged.join(format!("figures/{:06}", k.number));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let lab = crate::figures::LabInputs {
        rig,
        color: &color,
        depth: &k.depth,
        depth_kind: DepthKind::Z,
        options,
        output: &output,
    };
    let mut files = Vec::new();
    crate::figures::save_lab_figures(|name| dir.join(name), &lab, &mut files)
}
