//! `kfuse calibrate`: checkerboard images of the colour and/or IR camera → rig file (or a
//! single-camera file), optional OpenCV YAML, and a report folder of figures.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use calib::detect::{
    Refinement, align_pair, common_grid_size, detect_views_timed, detect_views_with,
};
use calib::files::{
    COLOR_RMS_LIMIT_PX, DEPTH_RMS_LIMIT_PX, add_detections, camera_json, opencv_yaml_camera,
    opencv_yaml_rig, stereo_rig, write_text,
};
use calib::io::ImageTiming;
use calib::{
    Board, CalibError, CalibFlags, StereoOptions, ViewCorners, calibrate_mono, calibrate_stereo,
};
use geometry::Image;
use geometry::timing::{Timings, ms_since};
use indicatif::{ProgressBar, ProgressStyle};
use kfuse_io::atomic::{StagedDir, StagedFiles};

use crate::calibrate_report::{Figures, print_held_out, print_mono, print_stereo};

mod depth;
mod depth_figures;
mod multi;

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

/// The board of `--board`, `--square`, `--top-left`, and whether its size is to be found from
/// the images (`--board auto`; the counts are then placeholders).
fn parse_board(board: &str, square: &str, top_left: Option<&str>) -> Result<(Board, bool)> {
    let auto = board.trim().eq_ignore_ascii_case("auto");
    let (c, r) = if auto {
        (2, 2)
    } else {
        board
            .split_once(['x', 'X'])
            .and_then(|(c, r)| {
                Some((c.trim().parse::<usize>().ok()?, r.trim().parse::<usize>().ok()?))
            })
            .with_context(|| {
                format!("--board '{board}': give inner corners as COLSxROWS, e.g. 7x5, or auto")
            })?
    };
    if c > MAX_BOARD_SIDE || r > MAX_BOARD_SIDE {
        bail!("--board '{board}': at most {MAX_BOARD_SIDE} inner corners per side");
    }
    let s = square.trim();
    let (num, scale) = if let Some(v) = s.strip_suffix("mm") {
        (v, 1e-3)
    } else if let Some(v) = s.strip_suffix("cm") {
        (v, 1e-2)
    } else if let Some(v) = s.strip_suffix('m') {
        (v, 1.0)
    } else {
        match s.parse::<f64>() {
            Ok(v) if v > 0.0 => {
                // The readings that give a square a printed board has (5-100 mm), first.
                let readings: Vec<String> = [("mm", 1e-3), ("cm", 1e-2), ("m", 1.0)]
                    .into_iter()
                    .filter(|(_, m)| (PRINTED_SQUARE_M.0..=PRINTED_SQUARE_M.1).contains(&(v * m)))
                    .map(|(unit, m)| match unit {
                        "mm" => format!("{v}mm"),
                        _ => format!("{v}{unit} ({} mm)", (v * m * 1e4).round() / 10.0),
                    })
                    .collect();
                if readings.is_empty() {
                    bail!(
                        "--square '{square}': give a unit: {v}mm, {}cm or {}m?",
                        v / 10.0,
                        v / 1000.0
                    )
                }
                bail!("--square '{square}': give a unit: {}?", readings.join(" or "))
            }
            _ => bail!(
                "--square '{square}': give the printed square's side with a unit, e.g. 40mm, 4cm or 0.04m"
            ),
        }
    };
    let v: f64 =
        num.trim().parse().with_context(|| format!("--square '{square}': not a number"))?;
    let side_m = v * scale;
    if !(MIN_SQUARE_M..=MAX_SQUARE_M).contains(&side_m) {
        bail!(
            "--square '{square}': a square side must be between {} mm and {MAX_SQUARE_M} m; give the printed square's side, e.g. 24mm",
            MIN_SQUARE_M * 1e3
        );
    }
    let mut b = Board::new(c, r, side_m)?;
    b.top_left_black = top_left.map(|t| t == "black");
    Ok((b, auto))
}

/// Square sides of printed calibration boards, metres: 5-100 mm (A4 boards have 20-40 mm
/// squares, large boards up to 100 mm). Only for the hint at a number given without a unit.
const PRINTED_SQUARE_M: (f64, f64) = (0.005, 0.1);

/// Largest inner-corner count per side accepted from `--board` (far above any printed board;
/// bounds the detector's work).
const MAX_BOARD_SIDE: usize = 100;

/// Largest square side accepted from `--square`: 1 m is far above any printed board (and a unit
/// mistake such as `40m` for 40 mm lands above it).
const MAX_SQUARE_M: f64 = 1.0;
/// Smallest square side accepted from `--square`: 0.1 mm, the squares of microscope
/// calibration slides; below it is a unit mistake (`0.024mm` for 24 mm).
const MIN_SQUARE_M: f64 = 1e-4;

/// Natural order: `ir_2` before `ir_10`.
fn natural_key(p: &Path) -> Vec<(String, u64)> {
    let s = p.to_string_lossy();
    let mut out = Vec::new();
    let mut text = String::new();
    let mut num = String::new();
    for ch in s.chars() {
        if ch.is_ascii_digit() {
            num.push(ch);
        } else {
            if !num.is_empty() {
                out.push((std::mem::take(&mut text), num.parse().unwrap_or(u64::MAX)));
                num.clear();
            }
            text.push(ch);
        }
    }
    out.push((text, num.parse().unwrap_or(0)));
    out
}

/// Expands the patterns in-process (the shell may not), naturally sorted. A pattern that names
/// an existing file is that file, taken literally: `shot[1].png` is the file of that name, not
/// the glob that matches `shot1.png`.
pub fn expand(patterns: &[String], what: &str) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for p in patterns {
        if Path::new(p).is_file() {
            files.push(PathBuf::from(p));
            continue;
        }
        let matches: Vec<PathBuf> = glob::glob(p)
            .with_context(|| format!("--{what} '{p}': invalid glob pattern"))?
            .filter_map(|e| e.ok())
            .filter(|p| p.is_file())
            .collect();
        if matches.is_empty() && Path::new(p).is_dir() {
            let example = Path::new(p).join("*.png");
            bail!(
                "--{what} '{p}' is a folder; give a pattern of its images, e.g. --{what} '{}'",
                example.display()
            );
        }
        if matches.is_empty() {
            bail!("--{what} '{p}': no file matches{}", no_match_hint(p));
        }
        files.extend(matches);
    }
    files.sort_by_key(|p| natural_key(p));
    files.dedup();
    Ok(files)
}

/// Why a pattern may match nothing: the files it matches when case is ignored (`IR_*.png`
/// for `ir_0001.png`), or a folder that does not exist.
fn no_match_hint(pattern: &str) -> String {
    let options = glob::MatchOptions { case_sensitive: false, ..Default::default() };
    let ignoring_case: Vec<PathBuf> = glob::glob_with(pattern, options)
        .map(|m| m.filter_map(|e| e.ok()).filter(|p| p.is_file()).collect())
        .unwrap_or_default();
    if let Some(first) = ignoring_case.first() {
        return format!(
            "; {} file(s) match when upper and lower case are not told apart (e.g. {}): check the case",
            ignoring_case.len(),
            first.display()
        );
    }
    let folder = parent_folder(Path::new(pattern));
    if !folder.is_dir() && !folder.to_string_lossy().contains(['*', '?', '[']) {
        return format!("; the folder {} does not exist", folder.display());
    }
    String::new()
}

pub(crate) fn bar(len: usize, msg: &str) -> ProgressBar {
    let pb = ProgressBar::new(len as u64);
    pb.set_style(
        ProgressStyle::with_template("{msg:>18} [{bar:30}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb.set_message(msg.to_string());
    pb
}

/// One camera's views, its images (`None` where unreadable), the board (its size found when
/// `--board auto`), the stages' times ([`calib::timing::read_stage`], `detect_stage`) and
/// every image's.
type Detected = (Vec<ViewCorners>, Vec<Option<Image<u8>>>, Board, Timings, Vec<ImageTiming>);

/// Reads and detects one camera's images. An image that cannot be read is kept as a view that
/// cannot be used, with the reason, so that the calibration table lists it and goes on.
///
/// With `auto`, the board's size is the complete board most images show. When the board is
/// found in fewer than the views a calibration needs and the images show another size, the
/// error says which.
fn load_and_detect(
    files: &[PathBuf],
    board: &Board,
    auto: bool,
    camera: &str,
    refinement: Refinement,
) -> Result<Detected> {
    let mut timings = Timings::new();
    let pb = bar(files.len(), &format!("reading {camera}"));
    let (images, read_ms): (Vec<Result<Image<u8>, String>>, Vec<f64>) =
        timings.time(&calib::timing::read_stage(camera), || {
            calib::io::read_gray_all(files, &|| pb.inc(1))
                .into_iter()
                .map(|(r, ms)| (r.map_err(|e| e.to_string()), ms))
                .unzip()
        });
    pb.finish();
    let file_name =
        |f: &PathBuf| f.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let names: Vec<(String, &Image<u8>)> = files
        .iter()
        .zip(&images)
        .filter_map(|(f, i)| Some((file_name(f), i.as_ref().ok()?)))
        .collect();
    println!("{camera}: detecting the board in {} image(s)", names.len());
    let mut board = *board;
    let detect_stage = calib::timing::detect_stage(camera);
    if auto {
        let t = Instant::now();
        let size = common_grid_size(&names);
        timings.add(&detect_stage, ms_since(t));
        let Some(((a, b), _)) = size else {
            bail!(
                "--board auto: no complete checkerboard found in the {} {camera} image(s); give --board COLSxROWS (inner corners)",
                names.len()
            );
        };
        (board.cols, board.rows) = (a, b);
    }
    let pb = bar(names.len(), &format!("detecting {camera}"));
    let (found, board, detect_ms) = timings
        .time(&detect_stage, || detect_views_timed(&names, &board, refinement, &|| pb.inc(1)));
    pb.finish();
    let with_board = found.iter().filter(|v| !v.corners.is_empty()).count();
    if auto {
        // The count of the views the board was then found in (the ones the calibration
        // uses), not of the images whose whole grid the size search saw.
        let (a, b) = (board.cols, board.rows);
        println!(
            "--board auto: {with_board} of {} {camera} images show a {a}x{b} grid; using {a}x{b}",
            names.len()
        );
    }
    if !auto && with_board < calib::mono::MIN_VIEWS {
        let asked = (board.cols.max(board.rows), board.cols.min(board.rows));
        if let Some(((a, b), _)) = common_grid_size(&names).filter(|s| s.0 != asked) {
            // The count of the images the board of that size is then found in (what
            // `--board AxB` would calibrate on), not of those whose whole grid the size search
            // saw: that search can miss boards the detector of a known size finds (partial
            // boards; before it peeled the border's spurious junctions off, OpenCV's 9x6 sample
            // gave 2 of 13 against 13 of 13).
            let suggested = Board { cols: a, rows: b, ..board };
            let (views, _) = detect_views_with(&names, &suggested, refinement, &|| {});
            let n = views.iter().filter(|v| !v.corners.is_empty()).count();
            bail!(
                "{camera}: these images show a {a}x{b} grid (found in {n} of {} images); you asked for {}x{} (found in {with_board}). Give --board {a}x{b} (inner corners) or --board auto",
                names.len(),
                board.cols,
                board.rows
            );
        }
    }
    let mut detect_ms = detect_ms.into_iter();
    let image_times = files
        .iter()
        .zip(&images)
        .zip(read_ms)
        .map(|((f, i), read_ms)| ImageTiming {
            camera: camera.to_string(),
            name: file_name(f),
            read_ms,
            detect_ms: i.as_ref().ok().and_then(|_| detect_ms.next()),
        })
        .collect();
    let mut found = found.into_iter();
    let views = files
        .iter()
        .zip(&images)
        .map(|(f, i)| match i {
            Ok(_) => found.next().expect("one view per readable image"),
            Err(e) => {
                // The reader's message starts with the path, which the line already names.
                let why = e.strip_prefix(&format!("{}: ", f.display())).unwrap_or(e);
                println!("  {}: cannot be read: {why}; left out", f.display());
                ViewCorners {
                    name: file_name(f),
                    width: 0,
                    height: 0,
                    corners: vec![],
                    unusable: Some(format!("unreadable: {why}")),
                }
            }
        })
        .collect();
    Ok((views, images.into_iter().map(Result::ok).collect(), board, timings, image_times))
}

fn flags(args: &CalibrateArgs) -> CalibFlags {
    let mut f = if args.lab_settings { CalibFlags::bouguet() } else { CalibFlags::default() };
    f.fix_principal_point |= args.fix_principal_point;
    f.fix_aspect_ratio |= args.fix_aspect_ratio;
    f.fix_k3 |= args.fix_k3;
    f.zero_tangential |= args.zero_tangential;
    f.reject_outliers = !args.no_outlier_rejection;
    f
}

/// The readable images of one camera with their files and detections, for the report.
fn with_images<'a>(
    files: &'a [PathBuf],
    images: &'a [Option<Image<u8>>],
    views: &'a [ViewCorners],
) -> Vec<(&'a Path, &'a Image<u8>, &'a ViewCorners)> {
    files
        .iter()
        .zip(images)
        .zip(views)
        .filter_map(|((f, i), v)| Some((f.as_path(), i.as_ref()?, v)))
        .collect()
}

/// Fails when the first `--ir` image has the Kinect v2's colour size and the first `--color`
/// image its IR size (read from the headers, before any work): the two options swapped, which
/// gave a rig whose depth camera is 1920x1080, exit 0.
fn check_not_swapped(ir: &[PathBuf], color: &[PathBuf]) -> Result<()> {
    let size =
        |files: &[PathBuf]| files.first().and_then(|f| kfuse_io::image_header::image_size(f).ok());
    use calib::rig_io::show::{KINECT_COLOR_SIZE as COLOR, KINECT_DEPTH_SIZE as IR};
    match (size(ir), size(color)) {
        (Some(i), Some(c)) if (i, c) == (COLOR, IR) => bail!(
            "the --ir images are 1920x1080 and the --color images 512x424: the Kinect v2's colour camera is the 1920x1080 one; are --ir and --color swapped?"
        ),
        // One camera: other cameras may have these sizes, so a warning only.
        (Some(i), None) if i == COLOR => println!(
            "WARNING: the --ir images are 1920x1080, the Kinect v2's colour size: meant as --color?"
        ),
        (None, Some(c)) if c == IR => println!(
            "WARNING: the --color images are 512x424, the Kinect v2's IR size: meant as --ir?"
        ),
        _ => {}
    }
    Ok(())
}

/// The rig's JSON, once it reads back as every other command reads rigs: a depth correction
/// outside what a sensor's error can be (`geometry::depth_correction`'s limits) was written with
/// exit 0 and then refused by `rig show` and `fuse`. The usual cause is a wrong `--square`,
/// which scales the boards' distances and with them the fitted depth scale (30mm for 40 mm
/// gave +33.9 %).
fn readable_rig_json(rig: &geometry::Rig, out: &Path) -> Result<String> {
    let text = rig.to_json();
    if let Err(e) = geometry::Rig::from_json(&text, out) {
        let e = e.to_string();
        let why = e.strip_prefix(&format!("{}: ", out.display())).unwrap_or(&e);
        let hint = if rig.depth_correction.is_some() {
            "; a wrong --square scales the boards' distances and so the depth scale: check the printed square's side"
        } else {
            ""
        };
        bail!(
            "the calibration gives a rig that kfuse cannot use ({why}){hint}; nothing was written"
        );
    }
    Ok(text)
}

/// Largest ratio of the stereo fit's RMS to the worse single-camera RMS for pairs of one
/// session: 5. One board pose seen by both cameras adds only the extrinsics, so the joint fit
/// (weighted, its RMS over both cameras' corners) stays at or below the worse camera's own RMS:
/// rendered set 0.024 vs 0.030 px, the bundled pairs 0.025 vs 0.031 px, the simulated
/// sensor's 16 pairs 0.067 vs 0.068 px (2026-12-02). IR and colour images of two sessions gave
/// 39 px against 0.055 px, with T = 5.9 m, written with exit 0.
const MAX_STEREO_RMS_RATIO: f64 = 5.0;
/// Stereo RMS (px) under which no pair is blamed, whatever the ratio: 1 px is within what a
/// blurred or distorted real image gives on its own.
const STEREO_RMS_FLOOR_PX: f64 = 1.0;

/// Fails when the stereo fit cannot be of pairs that show the same board poses: its RMS far
/// above each camera's own (the usual cause: images of two sessions, or pairs matched out of
/// order). A rig that passes but that `fuse` would refuse (baseline, distortion) gets a
/// warning: two far-apart cameras can be calibrated, and fused with `--force`.
fn check_stereo_consistent(s: &calib::StereoCalibration) -> Result<()> {
    let single = s.depth_mono.rms_px.max(s.color_mono.rms_px);
    if s.rms_px > STEREO_RMS_FLOOR_PX && s.rms_px > MAX_STEREO_RMS_RATIO * single {
        bail!(
            "the IR and colour images do not show the same board poses pair by pair: the stereo RMS {:.2} px is {:.0}x the single-camera fits' ({:.3} px IR, {:.3} px colour); give the IR and colour images of one session (pairs are matched in sorted file-name order); nothing was written",
            s.rms_px,
            s.rms_px / single,
            s.depth_mono.rms_px,
            s.color_mono.rms_px
        );
    }
    let rig = geometry::Rig::new(s.depth, s.color, s.color_from_depth);
    for problem in rig.plausibility_problems() {
        println!("  WARNING: {problem}; `kfuse fuse` refuses such a rig without --force");
    }
    Ok(())
}

/// The folder of an output path (`.` for a bare file name).
fn parent_folder(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Where an output path leads, for telling whether two outputs are one file: the path with
/// its links and `..` resolved, or (missing) its resolved folder and its name.
fn resolved_output(path: &Path) -> PathBuf {
    path.canonicalize().unwrap_or_else(|_| {
        let folder = parent_folder(path);
        let folder = folder.canonicalize().unwrap_or_else(|_| folder.to_path_buf());
        folder.join(path.file_name().unwrap_or_default())
    })
}

/// Checks the output paths before any work: each names a file in an existing folder (a
/// missing file, a regular file or a link to one: no folder, device or pipe), none is one of
/// the input images, no two outputs are the same path, and the report folder is not a file.
fn check_outputs<'a>(
    args: &CalibrateArgs,
    inputs: impl Iterator<Item = &'a PathBuf> + Clone,
) -> Result<()> {
    let same = |a: &Path, b: &Path| match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    let mut taken: Vec<(&str, PathBuf)> = Vec::new();
    for (flag, path) in std::iter::once(("--out", &args.out))
        .chain(args.opencv_yaml.iter().map(|y| ("--opencv-yaml", y)))
    {
        if path.is_dir() {
            bail!("{flag} {} is a folder; give a file name such as rig.json", path.display());
        }
        let parent = parent_folder(path);
        if !parent.is_dir() {
            bail!(
                "{flag} {}: folder {} does not exist; create it first",
                path.display(),
                parent.display()
            );
        }
        if let Err(e) = kfuse_io::atomic::writable_target(path) {
            bail!("{flag} {e}");
        }
        if let Some(input) = inputs.clone().find(|i| same(i, path)) {
            bail!(
                "{flag} {} is one of the input images ({}); give a new file name such as rig.json",
                path.display(),
                input.display()
            );
        }
        let here = resolved_output(path);
        if let Some((other, _)) = taken.iter().find(|(_, p)| *p == here) {
            bail!(
                "{flag} {} is the same file as {other}; give each output its own name",
                path.display()
            );
        }
        // `--rig R --depth … --out R` adds the correction to the rig it reads: replacing it is
        // the point (its cameras and extrinsics are carried over).
        let adds_to_input_rig =
            !args.depth.is_empty() && args.rig.as_deref().is_some_and(|r| same(r, path));
        if !args.overwrite
            && !adds_to_input_rig
            && let Some(what) = foreign_output(
                path,
                flag == "--opencv-yaml",
                writes_rig(args),
                !args.depth.is_empty(),
            )
        {
            bail!(
                "{flag} {}: exists and is {what}; give another file name, or pass --overwrite to replace it",
                path.display()
            );
        }
        taken.push((flag, here));
    }
    if let Some(dir) = &args.report {
        if dir.exists() && !dir.is_dir() {
            bail!("--report {} exists and is not a folder", dir.display());
        }
        let here = resolved_output(dir);
        if let Some((other, _)) = taken.iter().find(|(_, p)| *p == here) {
            bail!(
                "--report {} is the same path as {other}; give the report its own folder",
                dir.display()
            );
        }
    }
    Ok(())
}

/// Bytes of an existing output file read to recognise it as kfuse's: a rig JSON with its
/// report is 100-400 KB (per-corner residuals of 25 pairs); an OpenCV YAML under 2 KB.
const RECOGNISE_BYTES: u64 = 16 << 20;
/// The top-level keys of the OpenCV YAML files kfuse writes (`calib::files::opencv_yaml_rig`,
/// `opencv_yaml_camera`); OpenCV's own samples add others (`calibration_time`, `nr_of_frames`).
const KFUSE_YAML_KEYS: [&[&str]; 2] = [
    &[
        "D1",
        "D2",
        "M1",
        "M2",
        "R",
        "T",
        "T_units",
        "image_height_1",
        "image_height_2",
        "image_width_1",
        "image_width_2",
    ],
    &["camera_matrix", "distortion_coefficients", "image_height", "image_width"],
];

/// What an existing output file is when kfuse calibrate did not write it (`None`: missing, or
/// one of calibrate's own: a `kfuse-rig` / `kfuse-camera` JSON whose `calibration` is
/// calibrate's report, or an OpenCV YAML with exactly the keys kfuse writes). A rerun into
/// the same `rig.json` replaces it; anything else, a rig imported from another tool, a rig
/// whose depth correction this run would drop, a user's notes or OpenCV's own calibration, is
/// kept unless `--overwrite` says otherwise. `depth_run`: this run fits a depth correction.
fn foreign_output(path: &Path, yaml: bool, rig: bool, depth_run: bool) -> Option<String> {
    use std::io::Read;
    let file = std::fs::File::open(path).ok()?;
    if !file.metadata().is_ok_and(|m| m.is_file()) {
        return None;
    }
    let mut text = String::new();
    if file.take(RECOGNISE_BYTES).read_to_string(&mut text).is_err() {
        return Some("not a text file".into());
    }
    if yaml {
        let mut keys: Vec<&str> = text
            .lines()
            .filter(|l| l.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_'))
            .filter_map(|l| l.split_once(':').map(|(k, _)| k.trim()))
            .collect();
        keys.sort_unstable();
        let ours = text.starts_with("%YAML:1.0") && KFUSE_YAML_KEYS.contains(&keys.as_slice());
        return (!ours).then(|| "another YAML or text file".into());
    }
    let value = serde_json::from_str::<serde_json::Value>(&text).ok();
    let format =
        value.as_ref().and_then(|v| v.get("format").and_then(|f| f.as_str()).map(str::to_string));
    // Replaced by the same kind only: a single-camera run into a two-camera rig would lose
    // the other camera and the extrinsics (and the other way round a camera file).
    match (format.as_deref(), rig) {
        (Some(geometry::rig::RIG_FORMAT), true) | (Some(calib::rig_io::CAMERA_FORMAT), false) => {
            value.as_ref().and_then(|v| not_calibrates(v, depth_run))
        }
        (Some(geometry::rig::RIG_FORMAT), false) => {
            Some("a two-camera rig, and this run writes a single-camera file".into())
        }
        (Some(calib::rig_io::CAMERA_FORMAT), true) => {
            Some("a single-camera file, and this run writes a two-camera rig".into())
        }
        (Some(other), _) => Some(format!("a JSON file of format \"{other}\"")),
        (None, _) => Some("not a kfuse calibration file".into()),
    }
}

/// For a kfuse rig or camera file of the kind this run writes: why it is not calibrate's own
/// to replace (an import, or a depth correction this run would drop), `None` when it is.
fn not_calibrates(v: &serde_json::Value, depth_run: bool) -> Option<String> {
    /// Characters of a file's `calibration.source` shown in the message (a file name or a
    /// tool's name fits; a garbage value must not flood the terminal).
    const SOURCE_SHOWN_CHARS: usize = 80;
    // calibrate's report holds the board it was fitted on; an import names its source.
    let report = &v["calibration"];
    if report.get("board").is_none() {
        let source = match report.get("source").and_then(|s| s.as_str()) {
            Some(s) => format!(
                "imported from {}",
                s.chars().take(SOURCE_SHOWN_CHARS).collect::<String>().escape_debug()
            ),
            None => "its report names no calibration board".into(),
        };
        return Some(format!("a calibration kfuse calibrate did not make ({source})"));
    }
    if !depth_run && !v["depth_correction"].is_null() {
        return Some(
            "a rig with a depth correction (calibrate --depth), which this run would drop".into(),
        );
    }
    None
}

/// Whether this run writes a two-camera rig (IR and colour images, or `--rig` with
/// `--depth`) rather than a single-camera file.
fn writes_rig(args: &CalibrateArgs) -> bool {
    (!args.color.is_empty() && !args.ir.is_empty()) || args.rig.is_some()
}

/// What an interrupted `calibrate` says it did.
const STOPPED: &str = ": stopped; no rig file or report was written";

/// Runs `work` on a worker thread (`interrupt::run_until_interrupted`): its own stages go
/// into `timings`, the rest of the call's wall time (starting the thread, waiting for its
/// result) into [`calib::timing::WORKER`].
fn on_worker<T: Send + 'static>(
    timings: &mut Timings,
    work: impl FnOnce() -> (T, Timings) + Send + 'static,
) -> Result<T> {
    let t = Instant::now();
    let (value, inner) = crate::interrupt::run_until_interrupted(STOPPED, work)?;
    let call_ms = ms_since(t);
    timings.extend("", &inner);
    timings.add(calib::timing::WORKER, call_ms - inner.total_ms());
    Ok(value)
}

/// `work`'s result with its wall time as the one stage `stage`.
fn timed<T>(stage: &str, work: impl FnOnce() -> T) -> (T, Timings) {
    let mut t = Timings::new();
    let value = t.time(stage, work);
    (value, t)
}

/// The `--timings` lines: the stages, with ms per image for reading and detection, then per
/// camera the median and largest image's read and detection times.
fn timing_lines(wall_ms: f64, timings: &Timings, images: &[ImageTiming]) -> Vec<String> {
    let cameras: Vec<&str> =
        ["IR", "colour"].into_iter().filter(|c| images.iter().any(|i| i.camera == *c)).collect();
    let per_image: Vec<String> = cameras
        .iter()
        .flat_map(|c| [calib::timing::read_stage(c), calib::timing::detect_stage(c)])
        .collect();
    let per_image: Vec<&str> = per_image.iter().map(String::as_str).collect();
    let n = cameras.first().map_or(0, |c| images.iter().filter(|i| i.camera == *c).count());
    let mut lines = timings.summary(wall_ms, Some((n, "image", &per_image)));
    let stats = |mut v: Vec<f64>| -> (f64, f64) {
        v.sort_by(f64::total_cmp);
        (v.get(v.len() / 2).copied().unwrap_or(0.0), v.last().copied().unwrap_or(0.0))
    };
    for c in cameras {
        let of = |f: &dyn Fn(&ImageTiming) -> Option<f64>| -> Vec<f64> {
            images.iter().filter(|i| i.camera == c).filter_map(f).collect()
        };
        let (rm, rx) = stats(of(&|i| Some(i.read_ms)));
        let (dm, dx) = stats(of(&|i| i.detect_ms));
        lines.push(format!(
            "  per {c} image (own thread): read median {rm:.2} ms (max {rx:.2}), detect median {dm:.2} ms (max {dx:.2})"
        ));
    }
    lines
}

/// Runs the command.
pub fn run(args: CalibrateArgs) -> Result<()> {
    if !args.camera.is_empty() || args.shots.is_some() || args.reference.is_some() {
        return multi::run(&args);
    }
    let started = Instant::now();
    let mut timings = Timings::new();
    let mut image_times: Vec<ImageTiming> = Vec::new();
    let (board, auto) = parse_board(&args.board, &args.square, args.top_left.as_deref())?;
    if args.color.is_empty() && args.ir.is_empty() {
        bail!("give --color and/or --ir image patterns, e.g. --ir 'captures/ir_*.png'");
    }
    let color_files = if args.color.is_empty() { vec![] } else { expand(&args.color, "color")? };
    let ir_files = if args.ir.is_empty() { vec![] } else { expand(&args.ir, "ir")? };
    let depth_files = if args.depth.is_empty() { vec![] } else { expand(&args.depth, "depth")? };
    depth::check_args(&ir_files, &color_files, &depth_files, args.rig.as_deref())?;
    if args.force && depth_files.is_empty() {
        bail!(
            "--force only lets --depth write an implausible depth scale; without --depth there is nothing it applies to: leave it out"
        );
    }
    let base_rig = args.rig.as_deref().map(depth::read_rig).transpose()?;
    let both = !color_files.is_empty() && !ir_files.is_empty();
    check_not_swapped(&ir_files, &color_files)?;
    if both && color_files.len() != ir_files.len() {
        bail!(
            "{} colour images but {} IR images: stereo needs one image of each camera per board pose (pairs are matched in sorted order)",
            color_files.len(),
            ir_files.len()
        );
    }
    check_outputs(&args, color_files.iter().chain(&ir_files).chain(&depth_files))?;
    crate::interrupt::install()?;
    let flags = flags(&args);
    // Detection and the fits write nothing; they run on a worker thread so that Ctrl-C is
    // answered within a poll interval whatever stage they are in.
    let corners: Refinement = args.corners.into();
    let mut detect = |files: &[PathBuf], board: Board, auto: bool, camera: &'static str| {
        let files = files.to_vec();
        let (views, images, board, stages, per_image) = on_worker(&mut timings, move || {
            match load_and_detect(&files, &board, auto, camera, corners) {
                Ok(d) => {
                    let stages = d.3.clone();
                    (Ok(d), stages)
                }
                Err(e) => (Err(e), Timings::new()),
            }
        })??;
        drop(stages);
        image_times.extend(per_image);
        anyhow::Ok((views, images, board))
    };
    let (ir_views, ir_images, board) = if ir_files.is_empty() {
        (vec![], vec![], board)
    } else {
        detect(&ir_files, board, auto, "IR")?
    };
    let (mut color_views, color_images, board) = if color_files.is_empty() {
        (vec![], vec![], board)
    } else {
        // With --board auto and IR images, the IR images already fixed the size. The colouring
        // (where the board's own colours decide it) is found from the colour images too and
        // compared: one board shows the same colouring to both cameras.
        let ir_colouring = board.top_left_black;
        let color_board = Board {
            top_left_black: board.top_left_black.filter(|_| args.top_left.is_some()),
            ..board
        };
        let (views, images, color_board) =
            detect(&color_files, color_board, auto && ir_files.is_empty(), "colour")?;
        if let (Some(ir), Some(color)) = (ir_colouring, color_board.top_left_black)
            && ir != color
            && !ir_views.is_empty()
        {
            let name = |black: bool| if black { "black" } else { "white" };
            bail!(
                "the IR images show a {}x{} board whose top-left square is {}, the colour images one whose top-left square is {}: the two sets are not of the same board (images of two sessions?); give the IR and colour images of one session, or --top-left black|white if the board really is the same",
                board.cols,
                board.rows,
                name(ir),
                name(color)
            );
        }
        (views, images, if ir_colouring.is_some() { board } else { color_board })
    };

    // Output staging: nothing is written unless everything succeeds.
    let mut outputs: Vec<(PathBuf, String)> = Vec::new();
    let mut report;
    let mut figs = Figures { board: Some(board), ..Figures::default() };
    let mut depth_fit = None;
    let fit_depth = |timings: &mut Timings, camera: geometry::CameraModel| {
        let (views, ir, depth) = (ir_views.clone(), ir_files.clone(), depth_files.clone());
        let (reject, force) = (flags.reject_outliers, args.force);
        on_worker(timings, move || {
            timed(calib::timing::DEPTH, || {
                depth::fit(&camera, &board, &views, &ir, &depth, reject, force)
            })
        })
    };
    if both {
        for i in 0..ir_views.len() {
            let (d, c) = (!ir_views[i].corners.is_empty(), !color_views[i].corners.is_empty());
            if d != c && !args.allow_unpaired {
                let (found, fi, missing, mi) = if d {
                    ("IR", &ir_files[i], "colour", &color_files[i])
                } else {
                    ("colour", &color_files[i], "IR", &ir_files[i])
                };
                return Err(CalibError::UnpairedView {
                    pair: format!("{}", i + 1),
                    found: found.into(),
                    found_image: fi.display().to_string(),
                    missing: missing.into(),
                    missing_image: mi.display().to_string(),
                }
                .into());
            }
            if d && c {
                color_views[i] = align_pair(&ir_views[i], &color_views[i], &board);
            }
        }
        let options = StereoOptions {
            depth_flags: flags,
            color_flags: flags,
            fix_intrinsics: args.fix_intrinsics,
        };
        let (ir, color) = (ir_views.clone(), color_views.clone());
        let s = on_worker(&mut timings, move || {
            let t = Instant::now();
            let s = calibrate_stereo(&board, &ir, &color, &options, None, None);
            let mut stages = Timings::new();
            if let Ok(s) = &s {
                calib::timing::add_stereo(&mut stages, s, ms_since(t));
            }
            (s, stages)
        })??;
        let held_out = if args.report.is_some() {
            let (ir, color) = (ir_views.clone(), color_views.clone());
            Some(on_worker(&mut timings, move || {
                timed(calib::timing::HELD_OUT, || {
                    calib::holdout::held_out_stereo(&board, &ir, &color, &options)
                })
            })?)
        } else {
            None
        };
        print_stereo(&s, &ir_views);
        check_stereo_consistent(&s)?;
        let mut rig = stereo_rig(&s, &board);
        if let Some(cal) = rig.calibration.as_mut() {
            // Corners and image paths for `kfuse view` (the calibration page).
            add_detections(&mut cal["depth_single_camera"], &ir_views, &ir_files);
            add_detections(&mut cal["color_single_camera"], &color_views, &color_files);
        }
        report = rig.calibration.clone().unwrap_or_default();
        if let Some(h) = &held_out {
            report["held_out"] = print_held_out(h);
        }
        if !depth_files.is_empty() {
            let fit = fit_depth(&mut timings, rig.depth)??;
            depth::print_fit(&fit);
            rig.depth_correction = Some(Box::new(depth::correction_of(&fit)));
            report["depth_correction"] = fit.report_json();
            depth_fit = Some(fit);
        }
        outputs.push((args.out.clone(), readable_rig_json(&rig, &args.out)?));
        if let Some(y) = &args.opencv_yaml {
            outputs.push((y.clone(), opencv_yaml_rig(&rig)));
        }
        figs.cameras.push(("IR", s.depth, s.depth_mono.clone(), DEPTH_RMS_LIMIT_PX));
        figs.cameras.push(("colour", s.color, s.color_mono.clone(), COLOR_RMS_LIMIT_PX));
    } else if let Some(mut rig) = base_rig {
        // --depth with --rig: the rig's IR intrinsics, only the correction is new.
        let fit = fit_depth(&mut timings, rig.depth)??;
        depth::print_fit(&fit);
        rig.depth_correction = Some(Box::new(depth::correction_of(&fit)));
        report = serde_json::json!({ "depth_correction": fit.report_json() });
        outputs.push((args.out.clone(), readable_rig_json(&rig, &args.out)?));
        depth_fit = Some(fit);
    } else {
        let (name, views, files, limit) = if ir_files.is_empty() {
            ("colour", &color_views, &color_files, COLOR_RMS_LIMIT_PX)
        } else {
            ("IR", &ir_views, &ir_files, DEPTH_RMS_LIMIT_PX)
        };
        let views_owned = views.clone();
        let m = on_worker(&mut timings, move || {
            let t = Instant::now();
            let m = calibrate_mono(&format!("{name} camera"), &board, &views_owned, &flags, None);
            let mut stages = Timings::new();
            if let Ok(m) = &m {
                calib::timing::add_mono(&mut stages, name, m, ms_since(t));
            }
            (m, stages)
        })??;
        print_mono(&format!("{name} camera"), &m, limit);
        let held_out = if args.report.is_some() {
            let views_owned = views.clone();
            let h = on_worker(&mut timings, move || {
                timed(calib::timing::HELD_OUT, || {
                    calib::holdout::held_out_mono(name, &board, &views_owned, &flags, None)
                })
            })?;
            Some(print_held_out(&h))
        } else {
            None
        };
        let mut text = camera_json(&m, &board, if name == "IR" { "depth" } else { "color" });
        report = match serde_json::from_str::<serde_json::Value>(&text) {
            Ok(mut v) => {
                // Corners and image paths for `kfuse view` (the calibration page).
                add_detections(&mut v["calibration"], views, files);
                text = serde_json::to_string_pretty(&v)?;
                v
            }
            Err(_) => serde_json::Value::default(),
        };
        if let Some(h) = held_out {
            report["held_out"] = h;
        }
        outputs.push((args.out.clone(), text));
        if let Some(y) = &args.opencv_yaml {
            outputs.push((y.clone(), opencv_yaml_camera(&m.camera)));
        }
        figs.cameras.push((name, m.camera, m, limit));
    }

    // The rig file(s) are written to temporary names first and renamed only after the report
    // is published: a failure anywhere leaves neither.
    crate::interrupt::check(STOPPED)?;
    let mut files = StagedFiles::new();
    timings.time(STAGE_WRITE_RIG, || {
        outputs.iter().try_for_each(|(path, text)| files.add(path, text.as_bytes()))
    })?;
    if let Some(dir) = &args.report {
        let staged = StagedDir::new(dir)?;
        figs.ir_images = with_images(&ir_files, &ir_images, &ir_views);
        figs.color_images = with_images(&color_files, &color_images, &color_views);
        timings.time(STAGE_WRITE_FIGURES, || -> Result<()> {
            if !figs.cameras.is_empty() {
                figs.write(&staged)?;
            }
            if let Some(fit) = &depth_fit {
                depth_figures::write(&staged, fit)?;
            }
            Ok(())
        })?;
        // Last, so that its timings hold every stage before it.
        report["timings_ms"] =
            calib::timing::report_json(ms_since(started), &timings, &image_times);
        timings.time(STAGE_WRITE_REPORT, || {
            write_text(&staged.join("report.json"), &serde_json::to_string_pretty(&report)?)
                .map_err(anyhow::Error::from)
        })?;
        crate::interrupt::check(STOPPED)?;
        timings.time(STAGE_PUBLISH, || staged.commit())?;
        println!("\nreport: {}", dir.display());
    }
    timings.time(STAGE_PUBLISH, || files.commit())?;
    for (path, _) in &outputs {
        println!("wrote {}", path.display());
    }
    if args.timings {
        for line in timing_lines(ms_since(started), &timings, &image_times) {
            eprintln!("{line}");
        }
    }
    Ok(())
}

/// Stage: the rig (or camera) file and the OpenCV YAML written to their temporary names.
const STAGE_WRITE_RIG: &str = "write rig files";
/// Stage: the report's figures (`--report`).
const STAGE_WRITE_FIGURES: &str = "write report figures";
/// Stage: report.json (`--report`; after its own `timings_ms` were taken, so only in the
/// `--timings` lines).
const STAGE_WRITE_REPORT: &str = "write report.json";
/// Stage: the outputs renamed into place (only in the `--timings` lines).
const STAGE_PUBLISH: &str = "publish outputs";

#[cfg(test)]
mod tests {
    use super::*;

    /// `--square` mistakes from a user's trial, each with a message that says the fix.
    #[test]
    fn square_sizes_need_a_unit_and_a_printable_size() {
        let side = |sq: &str| parse_board("9x6", sq, None).map(|(b, _)| b.square_m);
        let err = |sq: &str| side(sq).unwrap_err().to_string();
        assert!((side("24mm").unwrap() - 0.024).abs() < 1e-15);
        assert!((side("2.4cm").unwrap() - 0.024).abs() < 1e-15);
        // The reading that gives a printed board's square is offered (5-100 mm); otherwise
        // all three.
        assert!(err("24").contains("give a unit: 24mm?"), "{}", err("24"));
        assert!(err("0.04").contains("give a unit: 0.04m (40 mm)?"), "{}", err("0.04"));
        assert!(err("4").contains("give a unit: 4cm (40 mm)?"), "{}", err("4"));
        assert!(err("8").contains("give a unit: 8mm or 8cm (80 mm)?"), "{}", err("8"));
        assert!(err("500").contains("500mm, 50cm or 0.5m?"), "{}", err("500"));
        for bad in ["0", "-1", "abc"] {
            assert!(err(bad).contains("with a unit, e.g. 40mm"), "{bad}: {}", err(bad));
        }
        for bad in ["-1mm", "0mm", "1e-30m", "0.05mm", "2m"] {
            assert!(err(bad).contains("between 0.1 mm and 1 m"), "{bad}: {}", err(bad));
        }
    }

    #[test]
    fn a_folder_given_as_a_pattern_gets_an_example() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().display().to_string();
        let err = expand(std::slice::from_ref(&d), "color").unwrap_err().to_string();
        assert!(err.contains("is a folder") && err.contains(&format!("{d}/*.png")), "{err}");
    }

    #[test]
    fn file_names_with_glob_characters_are_taken_literally() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["shot[1].png", "shot1.png", "shot2.png", "shot10.png"] {
            std::fs::write(dir.path().join(name), b"x").unwrap();
        }
        let d = dir.path().display();
        let names = |files: Vec<PathBuf>| -> Vec<String> {
            files.iter().map(|f| f.file_name().unwrap().to_string_lossy().into_owned()).collect()
        };
        // The literal file wins over the glob `shot[1].png` (which matches shot1.png).
        assert_eq!(names(expand(&[format!("{d}/shot[1].png")], "color").unwrap()), ["shot[1].png"]);
        // No such file: a glob, naturally sorted (shot2 before shot10).
        assert_eq!(
            names(expand(&[format!("{d}/shot[0-9]*.png")], "color").unwrap()),
            ["shot1.png", "shot2.png", "shot10.png"]
        );
        let err = expand(&[format!("{d}/none[1].png")], "ir").unwrap_err().to_string();
        assert!(err.contains("--ir") && err.contains("no file matches"), "{err}");
    }
}
