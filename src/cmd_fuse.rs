//! `kfuse fuse`: depth + colour + rig → coloured cloud, registered depth, meshes, holes and
//! the lab's figures, written into one output folder that appears only when complete.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use fusion_gpu::{Engine, EngineUsed};
use geometry::fusion::{self, FusionOptions, FusionOutput, MeshSource};
use indicatif::{ProgressBar, ProgressStyle};
use kfuse_io::atomic::StagedDir;
use kfuse_io::{fused, images};

use crate::figures;

mod checks;
mod inputs;
pub mod live;
pub mod multi;
pub mod sequence;

pub use inputs::{Inputs, load_inputs};

/// Fuse one depth frame with one colour frame.
#[derive(Args, Debug, Clone)]
#[command(after_help = "\
Examples:
  kfuse fuse --rig rig.json --color color.png --depth depth.png --out fused
  kfuse fuse --rig rig.json --color c.jpg --depth d.exr --depth-kind range --out fused
  kfuse fuse --mat ../shared/data/course/synthdata.mat --out course-fused
  kfuse fuse --mat KinectData.mat --color Colour_rect.tif --depth Depth_rect.tif --out lab
  kfuse fuse --rig rig.json --color rect/Colour_rect.tif --depth rect/Depth_rect.tif --rectified --out f
  kfuse fuse --rig rig.json --color c.png --depth d.png --resample nearest --no-figures --out quick
  kfuse fuse --mat synthdata.mat --engine gpu --out gpu-fused  (GPU required; prints the adapter)
  kfuse fuse --mat synthdata.mat --engine auto --out fused     (GPU if any, else CPU with a warning)
  kfuse fuse --recording session.kfrec --out seq               (every frame: depth/NNNNNN.png, index.json)
  kfuse fuse --recording session.kfrec --layout tum --out tum  (TUM RGB-D: rgb/, depth/, associations.txt)
  kfuse fuse --recording session.kfrec --layout rosbag2 --out bag  (ROS 2 bag: ros2 bag play bag, Foxglove)
  kfuse fuse --recording session.kfrec --layout rosbag2 --points --out bag  (and the coloured cloud, sd/points)
  kfuse fuse --rig rig.json --frames shots --write holes,color-on-depth --out seq
  kfuse fuse --rig rig3.json --sensor A=a_color.jpg,a_depth.png --sensor B=b_color.jpg,b_depth.png \
             --sensor C=c_color.jpg,c_depth.png --out merged   (a rig of several Kinects)
  kfuse fuse --rig ring_scene/true_rig.json --frames ring_scene --out merged
             (a capture of several sensors: DIR/index.json; --shot NAME|K when it holds several)
  kfuse fuse --rig ring_scene/true_rig.json --frames ring_scene --tsdf --voxel-size 0.005 --out vol
             (volumetric fusion: tsdf_mesh.ply, tsdf_cloud.ply beside the merged cloud)
  kfuse fuse --rig rig3.json --frames room --virtual-view 'from=0.5,-0.8,0.4;look-at=0,0.2,1.6' --out v
             (also virtual_depth.png, virtual_color.png: the merged cloud seen from that pose)

Inputs are the raw (distorted) camera images; the rig's distortion is applied exactly.
Images from `kfuse undistort` are rectified: pass --rectified, or they are distorted twice.
Unit mistakes fail before any work (median depth outside 0.2-15 m, under 1 % of the depth
samples landing in the colour image, implausible rig); --force fuses anyway.
Depth: 16-bit PNG/TIFF in millimetres (see --depth-scale) or 32-bit float TIFF/EXR in metres;
0 or NaN means no sample.

Outputs (in --out; the folder appears only when everything was written):
  cloud.ply                      H1 points, depth camera frame, H6 colours
  depth_zbuffer / depth_nearest / depth_linear / depth_filled  .png (16-bit mm) + .exr (m),
                                 colour camera frame and pixel grid
  hole_mask.png                  H8 disocclusion holes (255 = hole)
  color_on_depth.png             H6 colour sampled on the depth grid
  mesh.ply, mesh.obj/.mtl/_texture.png           H4 textured mesh (colour camera frame)
  mesh_clean.ply, mesh_clean.obj/.mtl/_texture.png   H5 without stretched faces
  summary.json                   counts, plane, timings, inputs and units
  task1.png ... task8.png        the lab's figures

Outputs of several Kinects (--sensor or --frames of a capture of several sensors):
  rig.json, cloud.ply            the rig; the merged cloud (reference frame, own-colour H6)
  depth_zbuffer.png              merged samples z-buffered into --view (16-bit mm)
  mesh_SERIAL.ply, mesh_SERIAL.obj/.mtl/_texture.png   per sensor: H4 on its depth grid, H5,
                                 in the reference frame, textured by its own colour image
  virtual_depth.png, virtual_color.png   with --virtual-view (16-bit mm z; RGB)
  tsdf_mesh.ply, tsdf_cloud.ply  with --tsdf: the volumetric fusion's mesh (vertex colours,
                                 normals; also tsdf_mesh.obj + .mtl) and its surface points
                                 (reference frame)
  summary.json                   points per sensor, mesh faces, consistency per pair")]
pub struct FuseArgs {
    /// Rig file (JSON from `kfuse calibrate` or `kfuse rig import`) describing both cameras
    /// and color_from_depth. A single-camera file is not enough.
    /// With --recording or --frames: optional (the sensor's factory parameters).
    #[arg(long, value_name = "RIG.json", required_unless_present_any = ["mat", "recording", "frames"])]
    pub rig: Option<PathBuf>,
    /// Colour image (PNG, JPEG, TIFF or BMP), as captured (distorted) or rectified (then
    /// --rectified). With --mat it replaces the file's image.
    #[arg(long, value_name = "C.png", required_unless_present_any = ["mat", "recording", "frames", "sensor", "live"])]
    pub color: Option<PathBuf>,
    /// Depth image of the depth camera, as captured or rectified. With --mat it replaces the
    /// file's depth (e.g. the handout's Depth_rect.tif).
    #[arg(long, value_name = "D.png", required_unless_present_any = ["mat", "recording", "frames", "sensor", "live"])]
    pub depth: Option<PathBuf>,
    /// What the depth values measure: z (along the optical axis, Kinect) or range (distance to
    /// the optical centre).
    #[arg(long, value_enum, default_value_t = DepthKindArg::Z)]
    pub depth_kind: DepthKindArg,
    /// Metres per unit of 16-bit depth images (0.001 = millimetres; at most 0.01, centimetres,
    /// without --force). Float images are metres.
    #[arg(long, default_value_t = images::MILLIMETRES, value_name = "M_PER_UNIT", allow_hyphen_values = true)]
    pub depth_scale: f64,
    /// The lab course's MATLAB file instead of --rig: synthdata.mat, or the lab's
    /// KinectData.mat (uint16 Depth in mm; --color/--depth replace its images).
    #[arg(long, value_name = "FILE.mat", conflicts_with = "rig")]
    pub mat: Option<PathBuf>,
    /// The images are already undistorted (`kfuse undistort`, the handout's *_rect files):
    /// fuse them without the rig's distortion. A rig file can say the same ("rectified": true).
    #[arg(long)]
    pub rectified: bool,
    /// Output folder (created; same-named files in it are replaced).
    #[arg(long, short, value_name = "DIR")]
    pub out: PathBuf,
    /// H3 resampling: both nearest and Delaunay-linear, or nearest only (faster).
    #[arg(long, value_enum, default_value_t = ResampleArg::Both)]
    pub resample: ResampleArg,
    /// What H4 meshes: the depth samples (depth-grid, default) or a colour-frame depth.
    #[arg(long, value_enum, default_value_t = MeshFromArg::DepthGrid)]
    pub mesh_from: MeshFromArg,
    /// H5 rule: sample-scale (depth step per edge against one depth sample of a tilted
    /// surface plus 3σ of Kinect noise, σ = 1.5 mm·z²) or normal (the handout's literal
    /// face-normal test, which noise and staircases defeat on real depth).
    #[arg(long, value_enum, default_value_t = H5Arg::SampleScale)]
    pub h5: H5Arg,
    /// H5 tilt limit: a face tilted more than atan(RATIO) from facing the camera is removed
    /// (1.0 = 45°; larger keeps more slanted faces).
    #[arg(long, value_name = "RATIO", default_value_t = FusionOptions::default().stretch_ratio, allow_negative_numbers = true)]
    pub stretch_ratio: f32,
    /// Coverage radius of H3 nearest fill and H8 holes, in depth-sample spacings. Times the
    /// rig's spacing it may be at most 16 colour pixels (a factor of 5.5 on a Kinect v2):
    /// the nearest fill's work grows with the square of the radius.
    #[arg(long, value_name = "FACTOR", default_value_t = FusionOptions::default().hole_radius_factor, allow_negative_numbers = true)]
    pub hole_radius: f32,
    /// Depth samples outside MIN..MAX are not samples (H1's rule, on every engine; one frame,
    /// several Kinects and sequences alike): metres or millimetres with the unit written,
    /// e.g. 0.5m..2.5m, 500mm..2500mm or 0.5..2.5m.
    #[arg(long, value_name = "MIN..MAX", value_parser = parse_depth_range)]
    pub depth_range: Option<fusion::DepthRange>,
    /// Do not draw the Task 1-8 figures.
    #[arg(long)]
    pub no_figures: bool,
    /// Where the per-pixel stages (H1, H2, H7, H3 nearest, H8 mask and fill, H6) run: cpu,
    /// gpu (wgpu, Vulkan; fails without an adapter) or auto (the GPU if there is one, else the
    /// CPU with a warning). Results are identical on every engine.
    #[arg(long, value_name = "ENGINE", default_value_t = Engine::Cpu, value_parser = parse_engine, conflicts_with = "gpu")]
    pub engine: Engine,
    /// Old spelling of `--engine gpu` (`--gpu`) and `--engine auto` (`--gpu auto`).
    #[arg(long, num_args = 0..=1, default_missing_value = "gpu", value_name = "auto", value_parser = parse_gpu_alias, hide = true)]
    pub gpu: Option<Engine>,
    /// Fuse despite a failed plausibility check, with a warning: the rig's (focal lengths
    /// 50-20000 px, image sides up to 16384 px, baseline up to 0.5 m), the depth's (median
    /// 0.2-15 m after --depth-scale, steps of at most 1 cm) or the overlap's (at least 1 % of the depth samples land
    /// in the colour image); see README "Limits".
    #[arg(long)]
    pub force: bool,
    /// Print where the time went on stderr: milliseconds of each stage (one frame: H1-H8
    /// as in summary.json's timings_ms; a sequence: setup, read, decode (depth, colour),
    /// register, encode, write as in index.json), as `kfuse calibrate --timings` does.
    #[arg(long)]
    pub timings: bool,
    /// With a rig of several Kinects (a version-2 rig file): one sensor's colour and depth
    /// image, SERIAL=COLOR,DEPTH; once per sensor of the rig. Writes rig.json, cloud.ply
    /// (merged, reference frame), depth_zbuffer.png (--view) and summary.json (consistency
    /// per sensor pair) instead of the one-frame outputs.
    #[arg(long, value_name = "SERIAL=C.png,D.png", value_parser = multi::parse_sensor, conflicts_with_all = ["color", "depth", "mat"])]
    pub sensor: Vec<multi::SensorArg>,
    /// With several Kinects (--sensor, or --frames of a capture of several sensors): the
    /// camera of the rig the merged samples are z-buffered into (default: the reference
    /// sensor's colour camera).
    #[arg(long, value_name = "CAMERA")]
    pub view: Option<String>,
    /// With --frames of a capture of several sensors (DIR/index.json): the shot to fuse, by
    /// its name or 0-based index in index.json (needed when the capture holds several).
    #[arg(long, value_name = "NAME|K")]
    pub shot: Option<String>,
    /// With several Kinects: also z-buffer the merged cloud into a virtual camera with the
    /// reference depth camera's intrinsics at this pose, written as virtual_depth.png (z, mm)
    /// and virtual_color.png: 'from=X,Y,Z;look-at=X,Y,Z' with an optional ';up=X,Y,Z'
    /// (metres, the rig's reference frame: x right, y down, z forward of the reference
    /// camera; up defaults to 0,-1,0).
    #[arg(long, value_name = "from=X,Y,Z;look-at=X,Y,Z", allow_hyphen_values = true)]
    pub virtual_view: Option<String>,
    /// Volumetric fusion (`kfuse-tsdf`): integrate depth into one truncated signed distance
    /// field and write its marching-cubes mesh as tsdf_mesh.ply (vertex colours and normals;
    /// the same as tsdf_mesh.obj + .mtl) and its surface points as tsdf_cloud.ply. With several Kinects: every sensor's depth, in
    /// the rig's reference frame. With --recording (one fixed sensor): every frame's depth (or
    /// the first --frames-max N), in its depth camera's frame, coloured by the frames' colour
    /// images; index.json's `tsdf` lists the files and the volume.
    #[arg(long)]
    pub tsdf: bool,
    /// With --tsdf: the voxel size, metres (default 0.005; 0.001–0.5).
    #[arg(long, value_name = "M", allow_hyphen_values = true)]
    pub voxel_size: Option<f64>,
    /// With --tsdf: the truncation distance, metres (default 0.03, or 3 voxels when that is
    /// more; at least 2 voxels, at most 1 m).
    #[arg(long, value_name = "M", allow_hyphen_values = true)]
    pub truncation: Option<f64>,
    /// A whole recording or frame folder instead of one frame.
    #[command(flatten)]
    pub sequence: sequence::SequenceArgs,
    /// Fuse live: subscribe to the sensors of --rig (a rig of several sensors), each published
    /// by `kfuse serve` on its own PC over Zenoh, match one frame per sensor in time and fuse
    /// each matched set as `--sensor` images are fused, into OUT/sets/NNNNNN/ (what arrived:
    /// OUT/frames/NNNNNN/; OUT/live.json: every set, its spread and latency, each sensor's
    /// counters). A sensor that stops is reported and the others go on.
    #[arg(long, requires = "rig", conflicts_with_all = ["color", "depth", "mat", "sensor", "shot"])]
    pub live: bool,
    /// With --live: stop after this many fused sets (default: until Ctrl-C or SIGTERM).
    #[arg(long, value_name = "N", requires = "live", value_parser = clap::value_parser!(u64).range(1..))]
    pub sets: Option<u64>,
    /// With --live: the largest spread of a set's frames (newest minus oldest arrival on the
    /// sensors' PCs), milliseconds (default 25: free-running sensors at 30 Hz are always
    /// within 25 ms for up to 4 sensors).
    #[arg(long, value_name = "MS", requires = "live", value_parser = live::parse_tolerance_ms)]
    pub tolerance_ms: Option<f64>,
    /// With --live: a sensor whose newest frame is older than this many seconds is reported
    /// as stopped and left out of the sets until it sends again (default 1).
    #[arg(long, value_name = "S", requires = "live", value_parser = live::parse_stale_s)]
    pub stale_after: Option<f64>,
    /// With --live: give up when no set could be fused for this many seconds (default 30).
    #[arg(long, value_name = "S", requires = "live", value_parser = crate::cmd_capture::parse_interval)]
    pub wait: Option<f64>,
    /// With --live: match sets and record them in live.json without writing or fusing them
    /// (the transport's and the matching's own rate, for `benches/live.sh`).
    #[arg(long, requires = "live", hide = true)]
    pub live_match_only: bool,
    /// The network of --live (Zenoh endpoints, ROS domain).
    #[command(flatten)]
    pub net: crate::cmd_serve::NetArgs,
}

/// `--engine cpu|gpu|auto` (the CLI of `fuse` and `view`).
pub fn parse_engine(s: &str) -> Result<Engine, String> {
    s.parse()
}

/// `--depth-range MIN..MAX` ([`fusion::DepthRange::parse`]).
fn parse_depth_range(s: &str) -> Result<fusion::DepthRange, String> {
    fusion::DepthRange::parse(s).map_err(|e| match e {
        geometry::GeometryError::InvalidInput(m) => m,
        e => e.to_string(),
    })
}

/// The old `--gpu [auto]`: bare `--gpu` is `gpu`, `--gpu auto` is `auto`.
fn parse_gpu_alias(s: &str) -> Result<Engine, String> {
    match s {
        "gpu" | "on" => Ok(Engine::Gpu),
        "auto" => Ok(Engine::Auto),
        _ => Err(format!("'{s}': --gpu takes no value or 'auto' (or use --engine cpu|gpu|auto)")),
    }
}

impl FuseArgs {
    /// The engine asked for, by `--engine` or the old `--gpu [auto]`.
    pub fn engine(&self) -> Engine {
        self.gpu.unwrap_or(self.engine)
    }
}

/// `--depth-kind`.
#[derive(ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthKindArg {
    /// Distance along the optical axis.
    Z,
    /// Distance to the optical centre.
    Range,
}

/// `--resample`.
#[derive(ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum ResampleArg {
    /// Nearest fill and Delaunay-linear.
    Both,
    /// Nearest fill only.
    Nearest,
}

/// `--h5`.
#[derive(ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum H5Arg {
    /// Per edge, at the scale of the depth samples, with a noise allowance.
    SampleScale,
    /// The handout's face-normal test.
    Normal,
}

/// `--mesh-from`.
#[derive(ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFromArg {
    /// The depth samples themselves (texture coordinates from their projection).
    DepthGrid,
    /// Nearest fill with plane-filled holes.
    Filled,
    /// Nearest fill.
    Nearest,
    /// Delaunay-linear.
    Linear,
}

/// What an interrupted `fuse` says it did.
const STOPPED: &str = ": stopped; the staging folder was removed and --out left as it was";

/// The fusion options `args` ask for; every option's value is checked here.
pub fn options(args: &FuseArgs) -> Result<FusionOptions> {
    checks::check_depth_scale(args.depth_scale)?;
    if !(args.stretch_ratio.is_finite() && args.stretch_ratio > 0.0) {
        bail!("--stretch-ratio must be a positive number, got {}", args.stretch_ratio);
    }
    if !(args.hole_radius.is_finite() && args.hole_radius > 0.0) {
        bail!("--hole-radius must be a positive number, got {}", args.hole_radius);
    }
    let mesh_source = match args.mesh_from {
        MeshFromArg::DepthGrid => MeshSource::DepthGrid,
        MeshFromArg::Filled => MeshSource::Filled,
        MeshFromArg::Nearest => MeshSource::Nearest,
        MeshFromArg::Linear => MeshSource::Linear,
    };
    if mesh_source == MeshSource::Linear && args.resample == ResampleArg::Nearest {
        bail!("--mesh-from linear needs the linear resampling: drop --resample nearest");
    }
    Ok(FusionOptions {
        linear: args.resample == ResampleArg::Both,
        mesh_source,
        edge_rule: match args.h5 {
            H5Arg::SampleScale => fusion::EdgeFaceRule::SampleScale,
            H5Arg::Normal => fusion::EdgeFaceRule::Normal,
        },
        stretch_ratio: args.stretch_ratio,
        hole_radius_factor: args.hole_radius,
        depth_range: args.depth_range.unwrap_or_default(),
        record_timings: true,
        ..FusionOptions::default()
    })
}

/// What [`run`] produced.
pub struct FuseResult {
    /// The committed output folder.
    pub out: PathBuf,
    /// The fusion's counts.
    pub summary: fusion::FusionSummary,
    /// Whether the lab's figures were drawn (not with `--no-figures`).
    pub figures: bool,
}

fn progress(steps: u64) -> ProgressBar {
    let bar = ProgressBar::new(steps);
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.enable_steady_tick(Duration::from_millis(120));
    bar
}

/// Runs `kfuse fuse`.
pub fn run(args: &FuseArgs) -> Result<FuseResult> {
    let started = std::time::Instant::now();
    let bar = progress(6);
    bar.set_message("reading inputs");
    let options = options(args)?;
    // --out is checked (and its staging folder made) before any work, including entries of
    // the user's that carry an output's name.
    let staged = StagedDir::new(&args.out)?;
    staged.refuse_foreign(&output_names())?;
    crate::interrupt::install()?;
    let (inputs, request) = load_inputs(args, &options)?;
    // Before any work: the coverage radius this rig and --hole-radius give, and the rig's
    // sample spacing, within the stages' limits (the stages check again; this names the files).
    fusion::checked_coverage_radius_px(&inputs.rig, &options).with_context(|| {
        format!("the rig {} with --hole-radius {}", rig_name(args), args.hole_radius)
    })?;
    bar.inc(1);
    crate::interrupt::check(STOPPED)?;
    bar.set_message("fusing (H1-H8)");
    let engine = args.engine();
    let on = if engine == Engine::Cpu { "" } else { " on the GPU" };
    let (output, used) = fusion_gpu::fuse_request(engine, &request, &inputs.depth, &inputs.color)
        .with_context(|| format!("fusing {}{on}", input_names(args)))?;
    if let Some(note) = engine_note(&used) {
        // Printed beside the progress bar (which is hidden when stderr is not a terminal).
        bar.suspend(|| eprintln!("{note}"));
    }
    bar.inc(1);
    crate::interrupt::check(STOPPED)?;
    let mut files = Vec::new();
    bar.set_message("writing cloud and depth images");
    fused::write_data(&staged, &output, &mut files)?;
    crate::interrupt::pause_point("fuse-data");
    bar.inc(1);
    crate::interrupt::check(STOPPED)?;
    bar.set_message("writing meshes");
    fused::write_meshes(&staged, &inputs.color, &output, &mut files)?;
    bar.inc(1);
    crate::interrupt::check(STOPPED)?;
    if !args.no_figures {
        bar.set_message("drawing figures");
        write_figures(&staged, &inputs, &output, &options, &mut files)?;
    }
    bar.inc(1);
    crate::interrupt::check(STOPPED)?;
    fused::write_summary(&staged, &inputs.description, &options, &output.summary, files)?;
    crate::interrupt::pause_point("fuse-staged");
    bar.set_message("committing");
    crate::interrupt::check(STOPPED)?;
    let out = staged.commit()?;
    bar.inc(1);
    bar.finish_and_clear();
    if args.timings
        && let Some(t) = &output.summary.timings_ms
    {
        for line in t.to_timings().summary(geometry::timing::ms_since(started), None) {
            eprintln!("{line}");
        }
    }
    Ok(FuseResult { out, summary: output.summary, figures: !args.no_figures })
}

/// The line `--engine` prints on stderr about where the stages ran: the GPU adapter, or the
/// warning of a fallback to the CPU; nothing on the CPU as asked.
pub fn engine_note(used: &EngineUsed) -> Option<String> {
    match used {
        EngineUsed::Cpu => None,
        EngineUsed::Gpu { adapter, software } => {
            let note = if *software {
                " (software Vulkan: exact, but slower than the CPU path)"
            } else {
                ""
            };
            Some(format!("GPU adapter: {adapter}{note}"))
        }
        EngineUsed::CpuFallback { reason } => Some(format!("warning: {reason}; fusing on the CPU")),
    }
}

fn rig_name(args: &FuseArgs) -> String {
    match (&args.mat, &args.rig) {
        (Some(m), _) => m.display().to_string(),
        (_, Some(r)) => r.display().to_string(),
        _ => "the rig".into(),
    }
}

fn input_names(args: &FuseArgs) -> String {
    match (&args.mat, &args.depth, &args.color) {
        (Some(m), _, _) => m.display().to_string(),
        (_, Some(d), Some(c)) => format!("{} with {}", d.display(), c.display()),
        _ => "the inputs".into(),
    }
}

/// Every name `fuse` may write into `--out` (a run writes a subset: `depth_linear.*` only with
/// `--linear`, figures unless `--no-figures`); checked against real runs by a test.
fn output_names() -> Vec<String> {
    let mut names = fused::output_names();
    names.extend((1..=figures::LAB_FIGURES).map(|n| format!("task{n}.png")));
    names
}

fn write_figures(
    staged: &StagedDir,
    inputs: &Inputs,
    out: &FusionOutput,
    options: &FusionOptions,
    files: &mut Vec<String>,
) -> Result<()> {
    let lab = figures::LabInputs {
        rig: &inputs.rig,
        color: &inputs.color,
        depth: &inputs.depth,
        depth_kind: inputs.kind,
        options,
        output: out,
    };
    figures::save_lab_figures(|name| staged.join(name), &lab, files)
}

/// Prints where the results are.
pub fn report(result: &FuseResult) {
    let s = &result.summary;
    println!("fused {} depth samples into {} points", s.valid_depth_pixels, s.points);
    println!(
        "  colour view: {} samples, z-buffer {} px, holes {} px (filled {}), mesh {} -> {} faces after H5 ({:.1} % removed)",
        s.samples_in_view,
        s.zbuffer_pixels,
        s.hole_pixels,
        s.filled_pixels,
        s.faces_before,
        s.faces_after,
        100.0 * s.faces_removed_fraction
    );
    let out = result.out.display();
    println!("results in {out}/");
    println!("  point cloud   {out}/cloud.ply       (MeshLab, CloudCompare, Blender)");
    println!("  meshes        {out}/mesh.obj, {out}/mesh_clean.obj (+ .ply)");
    println!("  depth         {out}/depth_filled.png (16-bit mm), .exr (m)");
    if result.figures {
        println!("  figures       {out}/task1.png ... task8.png   summary: {out}/summary.json");
    } else {
        // `--no-figures`: none drawn, none listed.
        println!("  summary       {out}/summary.json");
    }
}
