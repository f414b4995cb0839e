//! `kfuse calibrate`: checkerboard images of the colour and/or IR camera → rig file (or a
//! single-camera file), optional OpenCV YAML, and a report folder of figures.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use calib::detect::{Refinement, align_pair, common_grid_size, detect_views_with};
use calib::files::{
    COLOR_RMS_LIMIT_PX, DEPTH_RMS_LIMIT_PX, add_detections, camera_json, opencv_yaml_camera,
    opencv_yaml_rig, stereo_rig, write_text,
};
use calib::{
    Board, CalibError, CalibFlags, MonoCalibration, StereoOptions, ViewCorners, calibrate_mono,
    calibrate_stereo,
};
use geometry::{CameraModel, Image};
use indicatif::{ProgressBar, ProgressStyle};
use kfuse_io::atomic::{StagedDir, StagedFiles};
use kfuse_io::images::write_color_png;
use nalgebra::Vector2;
use plotters::prelude::*;

/// Arguments of `kfuse calibrate`.
#[derive(clap::Args, Debug)]
#[command(after_help = "EXAMPLES:
  Stereo (pairs matched by sorted file name; quote the patterns):
    kfuse calibrate --color 'caps/color_*.png' --ir 'caps/ir_*.png' --board 7x5 --square 40mm \\
        --out rig.json --report caps/report
  One camera, the lab's Bouguet settings (principal point at the centre, k3 = 0):
    kfuse calibrate --ir 'kinect-lab/ir_*.bmp' --lab-settings --out ir.json

The handout's bars: RMS below 0.2 px (colour) and 0.4 px (IR); a warning is printed above them.
Views and corners rejected as outliers are always listed. The stereo joint fit weights each
view by its own noise (never above its camera's level): the table's weight column shows which
views counted less. Outputs are written atomically: a run that fails leaves no file behind.")]
pub struct CalibrateArgs {
    /// Colour-camera images: a glob pattern (quote it) or a file; repeatable.
    #[arg(long, value_name = "GLOB")]
    color: Vec<String>,
    /// IR (depth-camera) images: a glob pattern (quote it) or a file; repeatable.
    #[arg(long, value_name = "GLOB")]
    ir: Vec<String>,
    /// Inner corners per row x per column, e.g. 7x5 for a board of 8x6 squares (OpenCV's
    /// sample board is 9x6), or `auto`: the size of the complete board most images show.
    #[arg(long, default_value = "7x5")]
    board: String,
    /// Square side with unit: 40mm, 4cm, 0.04m.
    #[arg(long, default_value = "40mm")]
    square: String,
    /// Colour of the board's top-left square (next to the first inner corner); auto-detected
    /// from the images when not given.
    #[arg(long, value_parser = ["black", "white"])]
    top_left: Option<String>,
    /// Output file: the rig JSON (both cameras) or a single-camera JSON.
    #[arg(long, default_value = "rig.json")]
    out: PathBuf,
    /// Also export OpenCV FileStorage YAML here (M1/D1 = IR, M2/D2 = colour, R, T in metres).
    #[arg(long)]
    opencv_yaml: Option<PathBuf>,
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
        bail!("--square '{square}': give a unit, e.g. 40mm, 4cm or 0.04m")
    };
    let v: f64 =
        num.trim().parse().with_context(|| format!("--square '{square}': not a number"))?;
    let side_m = v * scale;
    if !(side_m > 0.0 && side_m <= MAX_SQUARE_M) {
        bail!(
            "--square '{square}': a square side must be above 0 and at most {MAX_SQUARE_M} m; give the printed square's side, e.g. 24mm"
        );
    }
    let mut b = Board::new(c, r, side_m)?;
    b.top_left_black = top_left.map(|t| t == "black");
    Ok((b, auto))
}

/// Largest inner-corner count per side accepted from `--board` (far above any printed board;
/// bounds the detector's work).
const MAX_BOARD_SIDE: usize = 100;

/// Largest square side accepted from `--square`: 1 m is far above any printed board (and a unit
/// mistake such as `40m` for 40 mm lands above it).
const MAX_SQUARE_M: f64 = 1.0;

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

/// Expands the patterns in-process (the shell may not), naturally sorted.
pub fn expand(patterns: &[String], what: &str) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for p in patterns {
        let matches: Vec<PathBuf> = glob::glob(p)
            .with_context(|| format!("--{what} '{p}': invalid glob pattern"))?
            .filter_map(|e| e.ok())
            .filter(|p| p.is_file())
            .collect();
        if matches.is_empty() {
            bail!("--{what} '{p}': no file matches (quote the pattern so that kfuse expands it)");
        }
        files.extend(matches);
    }
    files.sort_by_key(|p| natural_key(p));
    files.dedup();
    Ok(files)
}

fn bar(len: usize, msg: &str) -> ProgressBar {
    let pb = ProgressBar::new(len as u64);
    pb.set_style(
        ProgressStyle::with_template("{msg:>18} [{bar:30}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb.set_message(msg.to_string());
    pb
}

/// One camera's views, its images (`None` where unreadable) and the board (its size found when
/// `--board auto`).
type Detected = (Vec<ViewCorners>, Vec<Option<Image<u8>>>, Board);

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
    use rayon::prelude::*;
    let pb = bar(files.len(), &format!("reading {camera}"));
    let images: Vec<Result<Image<u8>, String>> = files
        .par_iter()
        .map(|f| {
            let r = calib::io::read_gray(f).map_err(|e| e.to_string());
            pb.inc(1);
            r
        })
        .collect();
    pb.finish();
    let file_name =
        |f: &PathBuf| f.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let names: Vec<(String, &Image<u8>)> = files
        .iter()
        .zip(&images)
        .filter_map(|(f, i)| Some((file_name(f), i.as_ref().ok()?)))
        .collect();
    let mut board = *board;
    if auto {
        let Some(((a, b), _)) = common_grid_size(&names) else {
            bail!(
                "--board auto: no complete checkerboard found in the {} {camera} image(s); give --board COLSxROWS (inner corners)",
                names.len()
            );
        };
        (board.cols, board.rows) = (a, b);
    }
    let pb = bar(names.len(), &format!("detecting {camera}"));
    let (found, board) = detect_views_with(&names, &board, refinement, &|| pb.inc(1));
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
        if let Some(((a, b), n)) = common_grid_size(&names).filter(|s| s.0 != asked) {
            bail!(
                "{camera}: these images show a {a}x{b} grid ({n} of {} images); you asked for {}x{} (the board is found in {with_board}). Give --board {a}x{b} (inner corners) or --board auto",
                names.len(),
                board.cols,
                board.rows
            );
        }
    }
    let mut found = found.into_iter();
    let views = files
        .iter()
        .zip(&images)
        .map(|(f, i)| match i {
            Ok(_) => found.next().expect("one view per readable image"),
            Err(e) => {
                println!("  {}: cannot be read ({e}); left out", f.display());
                ViewCorners {
                    name: file_name(f),
                    width: 0,
                    height: 0,
                    corners: vec![],
                    unusable: Some(format!("unreadable: {e}")),
                }
            }
        })
        .collect();
    Ok((views, images.into_iter().map(Result::ok).collect(), board))
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

fn print_mono(camera: &str, m: &MonoCalibration, limit: f64) {
    let k = m.camera.intrinsics;
    let d = m.camera.distortion;
    let s = m.std;
    println!(
        "\n{camera}: {}x{}, RMS {:.4} px (σ per axis {:.4} px)",
        m.camera.width, m.camera.height, m.rms_px, m.sigma_px
    );
    println!(
        "  fx {:.3} ± {:.3}  fy {:.3} ± {:.3}  cx {:.3} ± {:.3}  cy {:.3} ± {:.3}   (1σ)",
        k.fx, s.fx, k.fy, s.fy, k.cx, s.cx, k.cy, s.cy
    );
    println!(
        "  k1 {:.5} ± {:.5}  k2 {:.5} ± {:.5}  p1 {:.6} ± {:.6}  p2 {:.6} ± {:.6}  k3 {:.5} ± {:.5}",
        d.k1, s.k1, d.k2, s.k2, d.p1, s.p1, d.p2, s.p2, d.k3, s.k3
    );
    if let Some((r, fraction)) = calib::undistort::fold_inside_image(&m.camera) {
        println!(
            "  note: the distortion model folds inside the image (undistorted radius {r:.3}): {:.2} % of the pixels, near the corners, see no valid ray; undistortion masks them",
            100.0 * fraction
        );
    }
    println!("  {:<28} {:>8} {:>8} {:>8}  status", "image", "corners", "RMS px", "tilt°");
    for v in &m.views {
        let status = match &v.rejected {
            Some(why) => format!("REJECTED: {why}"),
            None if v.rms_px > limit => format!("WARNING: above the handout's {limit} px"),
            None => "ok".into(),
        };
        println!(
            "  {:<28} {:>8} {:>8.4} {:>8.1}  {status}",
            v.name, v.n_corners, v.rms_px, v.tilt_deg
        );
    }
    for c in &m.rejected_corners {
        println!(
            "  rejected corner {} of {}: error {:.2} px > {:.2} px",
            c.id, c.view, c.error_px, c.threshold_px
        );
    }
    if m.rms_px > limit {
        println!("  WARNING: {camera} RMS {:.3} px is above the handout's {limit} px", m.rms_px);
    }
}

/// Checks the output paths before any work: each names a file in an existing folder, none is
/// a folder, none is one of the input images, and the report folder is not a file.
fn check_outputs<'a>(
    args: &CalibrateArgs,
    inputs: impl Iterator<Item = &'a PathBuf> + Clone,
) -> Result<()> {
    let same = |a: &Path, b: &Path| match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    for (flag, path) in std::iter::once(("--out", &args.out))
        .chain(args.opencv_yaml.iter().map(|y| ("--opencv-yaml", y)))
    {
        if path.is_dir() {
            bail!("{flag} {} is a folder; give a file name such as rig.json", path.display());
        }
        let parent = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        if !parent.is_dir() {
            bail!(
                "{flag} {}: folder {} does not exist; create it first",
                path.display(),
                parent.display()
            );
        }
        if let Some(input) = inputs.clone().find(|i| same(i, path)) {
            bail!(
                "{flag} {} is one of the input images ({}); give a new file name such as rig.json",
                path.display(),
                input.display()
            );
        }
    }
    if let Some(dir) = args.report.as_ref().filter(|d| d.exists() && !d.is_dir()) {
        bail!("--report {} exists and is not a folder", dir.display());
    }
    Ok(())
}

/// Runs the command.
pub fn run(args: CalibrateArgs) -> Result<()> {
    let (board, auto) = parse_board(&args.board, &args.square, args.top_left.as_deref())?;
    if args.color.is_empty() && args.ir.is_empty() {
        bail!("give --color and/or --ir image patterns, e.g. --ir 'captures/ir_*.png'");
    }
    let color_files = if args.color.is_empty() { vec![] } else { expand(&args.color, "color")? };
    let ir_files = if args.ir.is_empty() { vec![] } else { expand(&args.ir, "ir")? };
    let both = !color_files.is_empty() && !ir_files.is_empty();
    if both && color_files.len() != ir_files.len() {
        bail!(
            "{} colour images but {} IR images: stereo needs one image of each camera per board pose (pairs are matched in sorted order)",
            color_files.len(),
            ir_files.len()
        );
    }
    check_outputs(&args, color_files.iter().chain(&ir_files))?;
    crate::interrupt::install()?;
    let flags = flags(&args);
    let (ir_views, ir_images, board) = if ir_files.is_empty() {
        (vec![], vec![], board)
    } else {
        load_and_detect(&ir_files, &board, auto, "IR", args.corners.into())?
    };
    let (mut color_views, color_images, board) = if color_files.is_empty() {
        (vec![], vec![], board)
    } else {
        // With --board auto and IR images, the IR images already fixed the size.
        load_and_detect(
            &color_files,
            &board,
            auto && ir_files.is_empty(),
            "colour",
            args.corners.into(),
        )?
    };

    // Output staging: nothing is written unless everything succeeds.
    let mut outputs: Vec<(PathBuf, String)> = Vec::new();
    let report;
    let mut figs = Figures { board: Some(board), ..Figures::default() };
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
        let s = calibrate_stereo(&board, &ir_views, &color_views, &options, None, None)?;
        print_mono("IR camera (alone)", &s.depth_mono, DEPTH_RMS_LIMIT_PX);
        print_mono("colour camera (alone)", &s.color_mono, COLOR_RMS_LIMIT_PX);
        let t = s.color_from_depth.translation * 1000.0;
        let ts = s.translation_std_m * 1000.0;
        let rs = s.rotation_std_rad.map(f64::to_degrees);
        println!(
            "\nstereo (joint refinement over {} pairs): RMS {:.4} px — IR {:.4} px, colour {:.4} px",
            s.pairs_used.len(),
            s.rms_px,
            s.depth_rms_px,
            s.color_rms_px
        );
        println!(
            "  color_from_depth T = ({:.3}, {:.3}, {:.3}) mm ± ({:.3}, {:.3}, {:.3}) mm (1σ)",
            t.x, t.y, t.z, ts.x, ts.y, ts.z
        );
        println!(
            "  rotation {:.4}° (axis-angle {:?}) ± ({:.4}, {:.4}, {:.4})°",
            s.color_from_depth.angle_deg(),
            s.color_from_depth.axis_angle().as_slice(),
            rs.x,
            rs.y,
            rs.z
        );
        println!(
            "  {:<28} {:>10} {:>10} {:>10} {:>10}",
            "pair", "IR RMS", "colour RMS", "IR weight", "col weight"
        );
        for (i, ((d, c), (wd, wc))) in s.view_rms_px.iter().zip(&s.view_weights).enumerate() {
            println!(
                "  {:<28} {:>10.4} {:>10.4} {:>10.2} {:>10.2}",
                ir_views[i].name, d, c, wd, wc
            );
        }
        println!(
            "  (weights: 1 = the camera's own noise level; a noisier view counts less in the joint fit)"
        );
        for (i, why) in &s.rejected_views {
            println!("  REJECTED pair {}: {why}", ir_views[*i].name);
        }
        for c in &s.rejected_corners {
            println!(
                "  rejected corner {} of {}: error {:.2} px > {:.2} px",
                c.id, c.view, c.error_px, c.threshold_px
            );
        }
        if s.depth_rms_px > DEPTH_RMS_LIMIT_PX {
            println!(
                "  WARNING: IR RMS after stereo {:.3} px is above the handout's {DEPTH_RMS_LIMIT_PX} px",
                s.depth_rms_px
            );
        }
        if s.color_rms_px > COLOR_RMS_LIMIT_PX {
            println!(
                "  WARNING: colour RMS after stereo {:.3} px is above the handout's {COLOR_RMS_LIMIT_PX} px",
                s.color_rms_px
            );
        }
        let mut rig = stereo_rig(&s, &board);
        if let Some(cal) = rig.calibration.as_mut() {
            // Corners and image paths for `kfuse view` (the calibration page).
            add_detections(&mut cal["depth_single_camera"], &ir_views, &ir_files);
            add_detections(&mut cal["color_single_camera"], &color_views, &color_files);
        }
        report = rig.calibration.clone().unwrap_or_default();
        outputs.push((args.out.clone(), rig.to_json()));
        if let Some(y) = &args.opencv_yaml {
            outputs.push((y.clone(), opencv_yaml_rig(&rig)));
        }
        figs.cameras.push(("IR", s.depth, s.depth_mono.clone(), DEPTH_RMS_LIMIT_PX));
        figs.cameras.push(("colour", s.color, s.color_mono.clone(), COLOR_RMS_LIMIT_PX));
    } else {
        let (name, views, files, limit) = if ir_files.is_empty() {
            ("colour", &color_views, &color_files, COLOR_RMS_LIMIT_PX)
        } else {
            ("IR", &ir_views, &ir_files, DEPTH_RMS_LIMIT_PX)
        };
        let m = calibrate_mono(&format!("{name} camera"), &board, views, &flags, None)?;
        print_mono(&format!("{name} camera"), &m, limit);
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
        outputs.push((args.out.clone(), text));
        if let Some(y) = &args.opencv_yaml {
            outputs.push((y.clone(), opencv_yaml_camera(&m.camera)));
        }
        figs.cameras.push((name, m.camera, m, limit));
    }

    // The rig file(s) are written to temporary names first and renamed only after the report
    // is published: a failure anywhere leaves neither.
    const STOPPED: &str = ": stopped; no rig file or report was written";
    crate::interrupt::check(STOPPED)?;
    let mut files = StagedFiles::new();
    for (path, text) in &outputs {
        files.add(path, text.as_bytes())?;
    }
    if let Some(dir) = &args.report {
        let staged = StagedDir::new(dir)?;
        figs.ir_images =
            ir_images.iter().zip(&ir_views).filter_map(|(i, v)| Some((i.as_ref()?, v))).collect();
        figs.color_images = color_images
            .iter()
            .zip(&color_views)
            .filter_map(|(i, v)| Some((i.as_ref()?, v)))
            .collect();
        figs.write(&staged, &report)?;
        crate::interrupt::check(STOPPED)?;
        staged.commit()?;
        println!("\nreport: {}", dir.display());
    }
    files.commit()?;
    for (path, _) in &outputs {
        println!("wrote {}", path.display());
    }
    Ok(())
}

#[derive(Default)]
struct Figures<'a> {
    board: Option<Board>,
    /// (name, final camera, single-camera result with per-view data, RMS limit).
    cameras: Vec<(&'static str, CameraModel, MonoCalibration, f64)>,
    ir_images: Vec<(&'a Image<u8>, &'a ViewCorners)>,
    color_images: Vec<(&'a Image<u8>, &'a ViewCorners)>,
}

// The one copy of the bundled font, shared with `kfuse fuse`'s figures.
use kfuse_figures::{FONT_NAME, register_font};

fn save_rgb(path: &Path, buf: Vec<u8>, w: usize, h: usize) -> Result<()> {
    let px = buf.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    write_color_png(path, &Image::from_vec(w, h, px)?)?;
    Ok(())
}

impl Figures<'_> {
    fn write(&self, dir: &StagedDir, report: &serde_json::Value) -> Result<()> {
        register_font();
        write_text(&dir.join("report.json"), &serde_json::to_string_pretty(report)?)?;
        let pb = bar(self.ir_images.len() + self.color_images.len(), "report figures");
        for (img, v) in self.ir_images.iter().chain(&self.color_images) {
            corners_figure(&dir.join(format!("corners_{}.png", stem(&v.name))), img, v)?;
            pb.inc(1);
        }
        pb.finish();
        errors_figure(&dir.join("per_image_error.png"), &self.cameras)?;
        for (name, cam, m, _) in &self.cameras {
            residuals_figure(
                &dir.join(format!("residuals_{}.png", name.to_lowercase())),
                name,
                cam,
                m,
            )?;
            poses_figure(
                &dir.join(format!("board_poses_{}.png", name.to_lowercase())),
                name,
                m,
                self.board.as_ref(),
            )?;
        }
        Ok(())
    }
}

fn stem(name: &str) -> String {
    Path::new(name)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| name.to_string())
}

/// The image with its detected corners: a circle per corner, corner 0 and the x axis marked.
fn corners_figure(path: &Path, img: &Image<u8>, v: &ViewCorners) -> Result<()> {
    let (w, h) = img.size();
    let mut buf: Vec<u8> = img.data().iter().flat_map(|&g| [g, g, g]).collect();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
        let r = ((w.max(h) as f64) / 160.0).max(3.0) as i32;
        let font = (FONT_NAME, (w.max(h) / 40).max(12) as u32).into_font().color(&YELLOW);
        let pt = |p: Vector2<f64>| (p.x.round() as i32, p.y.round() as i32);
        for c in &v.corners {
            let colour = if c.id == 0 { RED } else { GREEN };
            root.draw(&Circle::new(pt(c.px), r, colour.stroke_width(2)))?;
        }
        if let (Some(a), Some(b)) = (v.get(0), v.get(1)) {
            root.draw(&PathElement::new(vec![pt(a), pt(b)], RED.stroke_width(3)))?;
        }
        let status = if v.corners.is_empty() {
            "no board found".to_string()
        } else {
            format!("{} corners (red: corner 0 → x axis)", v.corners.len())
        };
        root.draw(&Text::new(format!("{}: {status}", v.name), (10, 10), font))?;
        root.present()?;
    }
    save_rgb(path, buf, w, h)
}

fn errors_figure(
    path: &Path,
    cams: &[(&'static str, CameraModel, MonoCalibration, f64)],
) -> Result<()> {
    let (w, h) = (1000usize, 300 * cams.len().max(1) + 40);
    let mut buf = vec![255u8; w * h * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
        let (title, body) = root.split_vertically(40);
        title.draw(&Text::new(
            "Per-image reprojection error (RMS, px)",
            (10, 8),
            (FONT_NAME, 22).into_font(),
        ))?;
        let areas = body.split_evenly((cams.len().max(1), 1));
        for ((name, _, m, limit), area) in cams.iter().zip(areas) {
            let vals: Vec<(usize, f64, bool)> = m
                .views
                .iter()
                .enumerate()
                .filter(|(_, v)| v.rms_px.is_finite())
                .map(|(i, v)| (i, v.rms_px, v.rejected.is_some()))
                .collect();
            let ymax = vals.iter().map(|v| v.1).fold(*limit, f64::max) * 1.15;
            let mut chart = ChartBuilder::on(&area)
                .caption(
                    format!("{name} camera (line: handout limit {limit} px; grey: rejected)"),
                    (FONT_NAME, 16),
                )
                .margin(8)
                .x_label_area_size(30)
                .y_label_area_size(50)
                .build_cartesian_2d(0f64..m.views.len() as f64, 0f64..ymax)?;
            chart
                .configure_mesh()
                .disable_x_mesh()
                .x_desc("image index")
                .y_desc("RMS px")
                .label_style((FONT_NAME, 12))
                .draw()?;
            chart.draw_series(vals.iter().map(|&(i, e, rej)| {
                let colour = if rej {
                    RGBColor(160, 160, 160)
                } else if e > *limit {
                    RED
                } else {
                    BLUE
                };
                Rectangle::new([(i as f64 + 0.15, 0.0), (i as f64 + 0.85, e)], colour.filled())
            }))?;
            chart.draw_series(LineSeries::new(
                [(0.0, *limit), (m.views.len() as f64, *limit)],
                RED.stroke_width(2),
            ))?;
        }
        root.present()?;
    }
    save_rgb(path, buf, w, h)
}

/// Residual vectors at the corners' image positions, magnified.
fn residuals_figure(path: &Path, name: &str, cam: &CameraModel, m: &MonoCalibration) -> Result<()> {
    let (w, h) = (1000usize, (1000.0 * cam.height as f64 / cam.width as f64) as usize + 60);
    let mut buf = vec![255u8; w * h * 3];
    let max = m.residuals.iter().map(|r| r.3.norm()).fold(1e-9, f64::max);
    let gain = 0.04 * cam.width as f64 / max;
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!(
                    "{name}: residual vectors ×{gain:.0} (largest {max:.3} px), RMS {:.3} px",
                    m.rms_px
                ),
                (FONT_NAME, 18),
            )
            .margin(10)
            .x_label_area_size(25)
            .y_label_area_size(45)
            .build_cartesian_2d(0f64..cam.width as f64, cam.height as f64..0f64)?;
        chart.configure_mesh().disable_mesh().label_style((FONT_NAME, 12)).draw()?;
        chart.draw_series(m.residuals.iter().map(|(_, _, p, e)| {
            PathElement::new(
                vec![(p.x, p.y), (p.x + gain * e.x, p.y + gain * e.y)],
                BLUE.stroke_width(2),
            )
        }))?;
        chart.draw_series(
            m.residuals.iter().map(|(_, _, p, _)| Circle::new((p.x, p.y), 2, BLACK.filled())),
        )?;
        root.present()?;
    }
    save_rgb(path, buf, w, h)
}

/// Board positions seen from above (x–z plane of the camera frame, metres).
fn poses_figure(path: &Path, name: &str, m: &MonoCalibration, board: Option<&Board>) -> Result<()> {
    let (bw, bh) = board
        .map(|b| (b.square_m * (b.cols - 1) as f64, b.square_m * (b.rows - 1) as f64))
        .unwrap_or((0.24, 0.16));
    let (w, h) = (900usize, 700usize);
    let mut buf = vec![255u8; w * h * 3];
    let poses: Vec<_> =
        m.views.iter().filter_map(|v| v.camera_from_board.map(|p| (v.name.clone(), p))).collect();
    let pts: Vec<Vec<(f64, f64)>> = poses
        .iter()
        .map(|(_, p)| {
            [(0.0, 0.0), (bw, 0.0), (bw, bh), (0.0, bh), (0.0, 0.0)]
                .iter()
                .map(|&(x, y)| {
                    let q = p.apply(&nalgebra::Vector3::new(x, y, 0.0));
                    (q.x, q.z)
                })
                .collect()
        })
        .collect();
    let xs = pts.iter().flatten().map(|p| p.0);
    let (xmin, xmax) = xs.fold((0.0f64, 0.0f64), |a, x| (a.0.min(x), a.1.max(x)));
    let zmax = pts.iter().flatten().map(|p| p.1).fold(0.1f64, f64::max);
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("{name}: board poses seen from above (camera at the origin)"),
                (FONT_NAME, 18),
            )
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(50)
            .build_cartesian_2d((xmin - 0.1)..(xmax + 0.1), 0f64..(zmax * 1.1))?;
        chart
            .configure_mesh()
            .x_desc("x (m)")
            .y_desc("z (m)")
            .label_style((FONT_NAME, 12))
            .draw()?;
        for (i, outline) in pts.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            chart.draw_series(LineSeries::new(outline.clone(), colour.stroke_width(2)))?;
        }
        chart.draw_series([TriangleMarker::new((0.0, 0.0), 10, RED.filled())])?;
        root.present()?;
    }
    save_rgb(path, buf, w, h)
}
