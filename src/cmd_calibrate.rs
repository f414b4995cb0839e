//! `kfuse calibrate`: checkerboard images of the colour and/or IR camera → rig file (or a
//! single-camera file), optional OpenCV YAML, and a report folder of figures. The run itself
//! is `calib::pipeline`; this is its arguments, the output checks and writing (`outputs`), and
//! what it prints (`print`).

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::Result;
use calib::CalibFlags;
use calib::detect::Refinement;
use calib::pipeline::{CameraImages, Options, Request, expand_all, parse_board};
use geometry::timing::{Timings, ms_since};

mod depth;
mod depth_figures;
mod multi;
mod outputs;
mod print;

/// Arguments of `kfuse calibrate`.
#[derive(clap::Args, Debug)]
#[command(after_help = "EXAMPLES:
  Stereo (pairs matched by sorted file name; quote the patterns):
    kfuse calibrate --color 'caps/color_*.png' --ir 'caps/ir_*.png' --board 7x5 --square 40mm \\
        --out rig.json --report caps/report
  One camera, the lab's Bouguet settings (principal point at the centre, k3 = 0):
    kfuse calibrate --ir 'kinect-lab/ir_*.bmp' --lab-settings --out ir.json

The handout's bars: RMS below 0.2 px (colour) and 0.4 px (IR); a warning is printed above them.
Depth calibration (the time-of-flight depth's offset, scale and spatial error, issue 16): add
the depth images of the IR shots; the correction goes into the rig (\"depth_correction\"):
    kfuse calibrate --ir 'caps/ir_*.png' --color 'caps/color_*.jpg' --depth 'caps/depth_*.png' \\
        --out rig.json --report caps/report
    kfuse calibrate --rig rig.json --ir 'caps/ir_*.png' --depth 'caps/depth_*.png' --out rig2.json
It needs at least 4 boards whose distances span at least 0.5 m (e.g. 0.8, 1.2, 1.8, 2.5 m),
tilted 10-40 degrees and spread over the image, without glare on the board.
A depth correction belongs with the IR intrinsics it was fitted with: the board distances come
from them and from --square, so another calibration's focal length gives another offset and
scale (printed per +1 % of f and of the square beside each term's σ). Keep the two together,
as the rig file does; a scale beyond ±5 % is refused unless --force.

Views and corners rejected as outliers are always listed. The stereo joint fit weights each
view by its own noise (never above its camera's level): the table's weight column shows which
views counted less. Outputs are written atomically: a run that fails leaves no file behind.")]
pub struct CalibrateArgs {
    /// Colour-camera images: glob patterns (quoted, kfuse expands them) or files (an unquoted
    /// pattern that the shell expands works too); repeatable.
    #[arg(long, value_name = "GLOB", num_args = 1..)]
    color: Vec<String>,
    /// IR (depth-camera) images: glob patterns or files, as --color. 8-bit, or
    /// 16-bit raw IR (scaled by each image's range; 65535 counts as clipped).
    #[arg(long, value_name = "GLOB", num_args = 1..)]
    ir: Vec<String>,
    /// Depth images (16-bit PNG, mm) of the IR shots, matched with --ir in sorted order:
    /// fits the depth correction (offset, scale, spatial terms) into the rig. The correction
    /// belongs with the IR intrinsics it was fitted with (the board distances come from them
    /// and from --square; the rig keeps the two together): its offset and scale move with the
    /// focal length and the square, which the printed table and report.json quantify.
    #[arg(long, value_name = "GLOB", num_args = 1..)]
    depth: Vec<String>,
    /// With --depth and --ir only: the rig (IR intrinsics) the correction is added to; the
    /// output is this rig with its depth_correction.
    #[arg(long, value_name = "RIG.json")]
    rig: Option<PathBuf>,
    /// Inner corners per row x per column, e.g. 7x5 for a board of 8x6 squares (OpenCV's
    /// sample board is 9x6), or `auto`: the size of the complete board most images show.
    #[arg(long, default_value = "7x5")]
    board: String,
    /// Square side with unit: 40mm, 4cm, 0.04m.
    #[arg(long, default_value = "40mm", allow_hyphen_values = true)]
    square: String,
    /// Colour of the board's top-left square (next to the first inner corner); auto-detected
    /// from the images when not given.
    #[arg(long, value_parser = ["black", "white"])]
    top_left: Option<String>,
    /// Output file: the rig JSON (both cameras) or a single-camera JSON. An existing file is
    /// replaced when kfuse wrote it (a rerun); any other file only with --overwrite.
    #[arg(long, default_value = "rig.json")]
    out: PathBuf,
    /// Also export OpenCV FileStorage YAML here (M1/D1 = IR, M2/D2 = colour, R, T in metres).
    #[arg(long)]
    opencv_yaml: Option<PathBuf>,
    /// Replace an existing --out or --opencv-yaml file that kfuse did not write.
    #[arg(long)]
    overwrite: bool,
    /// With --depth: write a depth correction whose scale is beyond what a Kinect v2
    /// plausibly has (±5 %; usually a wrong --square or intrinsics of another calibration),
    /// with a warning instead of refusing it.
    #[arg(long)]
    force: bool,
    /// Folder for the report figures (corners on every image, per-image errors, residual
    /// vectors, board poses) and report.json.
    #[arg(long)]
    report: Option<PathBuf>,
    /// The lab's Bouguet settings: principal point fixed at the image centre, k3 = 0.
    #[arg(long)]
    lab_settings: bool,
    /// Keep the principal point at the image centre.
    #[arg(long)]
    fix_principal_point: bool,
    /// Keep fy/fx = 1.
    #[arg(long)]
    fix_aspect_ratio: bool,
    /// Keep k3 = 0.
    #[arg(long)]
    fix_k3: bool,
    /// p1 = p2 = 0.
    #[arg(long)]
    zero_tangential: bool,
    /// Stereo: keep each camera's single-camera intrinsics, refine only R, T and the poses.
    #[arg(long)]
    fix_intrinsics: bool,
    /// Keep every corner and view (no outlier rejection), like OpenCV.
    #[arg(long)]
    no_outlier_rejection: bool,
    /// Use pairs where only one image shows the board for that camera's intrinsics instead of
    /// failing.
    #[arg(long)]
    allow_unpaired: bool,
    /// Final sub-pixel corner estimator: `junction` fits a blurred X-junction model (most
    /// accurate: a third of cornerSubPix's error on rendered boards, lower RMS on real IR);
    /// `subpix` is OpenCV's cornerSubPix / Bouguet's cornerfinder, for corners that match
    /// those tools (0.13 px from the lab's Bouguet corners on real IR).
    #[arg(long, value_enum, default_value = "junction")]
    corners: CornerEstimator,
    /// Print where the time went on stderr: milliseconds of each stage (reading and
    /// decoding, detection, each fit, σ, the held-out check, the depth fit, writing), per
    /// image for reading and detection. With --report, report.json holds the same split
    /// (`timings_ms`) with every image's times.
    #[arg(long)]
    timings: bool,
    /// Joint calibration of N cameras (issue 32): one camera's images as NAME=GLOB, e.g.
    /// 0001.depth='shots/000000000001/ir_*.png'; repeatable. The view id of an image is the
    /// shot number in its name (the last run of digits); one id in two cameras is one board
    /// pose. SERIAL.depth / SERIAL.color name a Kinect's IR and colour cameras. Writes a rig of
    /// every camera (--out) and, with --report, report.json with every camera's corners.
    #[arg(long = "camera", value_name = "NAME=GLOB")]
    camera: Vec<String>,
    /// Joint calibration of a multi-sensor capture folder (`kfuse capture calib --device all
    /// --out DIR`): every DIR/SERIAL/ir_* as camera SERIAL.depth, DIR/SERIAL/color_* as
    /// SERIAL.color (the names of its true_rig.json); --camera adds cameras.
    #[arg(long, value_name = "DIR")]
    shots: Option<PathBuf>,
    /// The reference camera of a joint calibration (its frame is the rig's); default: the
    /// first depth camera.
    #[arg(long, value_name = "NAME")]
    reference: Option<String>,
}

/// `--corners`: the final sub-pixel estimator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum CornerEstimator {
    /// Maximum-likelihood X-junction fit (default).
    Junction,
    /// cornerSubPix / Bouguet cornerfinder.
    Subpix,
}

impl From<CornerEstimator> for Refinement {
    fn from(c: CornerEstimator) -> Self {
        match c {
            CornerEstimator::Junction => Refinement::JunctionFit,
            CornerEstimator::Subpix => Refinement::CornerSubPix,
        }
    }
}

/// The fits' flags of `args` (`--lab-settings`, the `--fix-*` flags, `--no-outlier-rejection`).
fn flags(args: &CalibrateArgs) -> CalibFlags {
    let mut flags = if args.lab_settings { CalibFlags::bouguet() } else { CalibFlags::default() };
    flags.fix_principal_point |= args.fix_principal_point;
    flags.fix_aspect_ratio |= args.fix_aspect_ratio;
    flags.fix_k3 |= args.fix_k3;
    flags.zero_tangential |= args.zero_tangential;
    flags.reject_outliers = !args.no_outlier_rejection;
    flags
}

/// The pipeline's request of `args`: the board, the images (patterns expanded), the flags.
fn request(args: &CalibrateArgs) -> Result<Request> {
    let (board, auto_board) = parse_board(&args.board, &args.square, args.top_left.as_deref())?;
    let (ir, color, depth) = expand_all(&args.ir, &args.color, &args.depth)?;
    let options = Options {
        flags: flags(args),
        fix_intrinsics: args.fix_intrinsics,
        allow_unpaired: args.allow_unpaired,
        refinement: args.corners.into(),
        force: args.force,
        held_out: args.report.is_some(),
    };
    Ok(Request {
        ir: CameraImages::files(ir),
        color: CameraImages::files(color),
        depth,
        rig: args.rig.clone(),
        board,
        auto_board,
        options,
    })
}

/// What an interrupted `calibrate` says it did.
const STOPPED: &str = ": stopped; no rig file or report was written";

/// Runs the command: the inputs checked, the outputs checked before any work, the pipeline
/// on a worker thread (`interrupt::run_until_interrupted`: detection and the fits write
/// nothing, and Ctrl-C is answered within a poll interval whatever stage they are in), then
/// the outputs written all or nothing.
pub fn run(args: CalibrateArgs) -> Result<()> {
    if !args.camera.is_empty() || args.shots.is_some() || args.reference.is_some() {
        return multi::run(&args);
    }
    let started = Instant::now();
    let printer = Arc::new(print::Printer::default());
    let prepared = calib::pipeline::prepare(request(&args)?, &*printer)?;
    outputs::check(&args, prepared.inputs())?;
    crate::interrupt::install()?;
    let worker = Instant::now();
    let observer = printer.clone();
    let outcome =
        crate::interrupt::run_until_interrupted(STOPPED, move || prepared.run(&*observer))??;
    // The pipeline's own stages, and the rest of the worker's wall time (starting the thread,
    // waiting for its result) as `calib::timing::WORKER`.
    let mut timings = Timings::new();
    timings.extend("", &outcome.timings);
    timings.add(calib::timing::WORKER, ms_since(worker) - outcome.timings.total_ms());
    outputs::write(&args, &outcome, timings, started)
}
