//! What `kfuse calibrate` prints (the per-camera and stereo tables) and draws (the report
//! folder's figures: detected corners, per-image errors, residual vectors, board poses).

use std::path::Path;

use anyhow::Result;
use calib::files::{COLOR_RMS_LIMIT_PX, DEPTH_RMS_LIMIT_PX};
use calib::{Board, MonoCalibration, StereoCalibration, ViewCorners};
use geometry::{CameraModel, Image};
use kfuse_io::atomic::StagedDir;
use kfuse_io::images::write_color_png;
use nalgebra::Vector2;
use plotters::prelude::*;

use indicatif::{ProgressBar, ProgressStyle};
// The one copy of the bundled font, shared with `kfuse fuse`'s figures.
use kfuse_figures::{FONT_NAME, register_font};

/// Whether the handout's RMS bars (for the Kinect's colour and IR cameras) apply to a camera
/// with `m`'s image size: they do for the Kinect's two image sizes only. Another camera (a
/// phone, a GoPro, OpenCV's 640x480 samples) has its own pixels, lens and compression: on the
/// calibration corpus, cameras calibrated as well as OpenCV does have RMS 0.15–0.86 px, and a
/// warning on every view would be noise.
fn handout_bar_applies(m: &MonoCalibration) -> bool {
    use kfuse_io::rig_io::show::{KINECT_COLOR_SIZE, KINECT_DEPTH_SIZE};
    let size = (m.camera.width, m.camera.height);
    size == KINECT_COLOR_SIZE || size == KINECT_DEPTH_SIZE
}

/// A focal length or principal-point coordinate whose 1σ exceeds this fraction (of the focal
/// length; of the image width or height) is warned about as weakly constrained. Views that
/// constrain the camera give 0.07–0.3 % (the corpus's OpenCV, Udacity and GoPro sets,
/// kinect-lab, the bundled 4-pair sample); the robot-arm set's 5 views, tilted 15–25°, give
/// fx ± 3.5 % and cy ± 3.3 % (2026-12-02).
const WEAK_PARAMETER_FRACTION: f64 = 0.01;

/// The intrinsics of `m` that its views leave weakly constrained (see
/// [`WEAK_PARAMETER_FRACTION`]), as "fx ± 68.7 px (3.5 %)"; fixed ones (σ 0) never are.
fn weakly_constrained(m: &MonoCalibration) -> Vec<String> {
    let (k, s) = (m.camera.intrinsics, m.std);
    let (w, h) = (m.camera.width as f64, m.camera.height as f64);
    [("fx", s.fx, k.fx), ("fy", s.fy, k.fy), ("cx", s.cx, w), ("cy", s.cy, h)]
        .into_iter()
        .filter(|&(_, sd, scale)| sd > WEAK_PARAMETER_FRACTION * scale)
        .map(|(name, sd, scale)| format!("{name} ± {sd:.1} px ({:.1} %)", 100.0 * sd / scale))
        .collect()
}

/// One warning line per constraint flag that moved other parameters beyond
/// `calib::mono::FIX_SHIFT_SIGMAS` σ of the free fit (`MonoCalibration::fix_checks`): the
/// parameters, their moves and σ, and where the free fit puts what the flag fixed.
fn fix_warnings(camera: &str, m: &MonoCalibration) -> Vec<String> {
    let value = |name: &str, v: f64| {
        if matches!(name, "fx" | "fy" | "cx" | "cy" | "skew") {
            format!("{v:+.2} px")
        } else {
            format!("{v:+.5}")
        }
    };
    m.fix_checks
        .iter()
        .filter(|c| !c.moved.is_empty())
        .map(|c| {
            let moves: Vec<String> = c
                .moved
                .iter()
                .map(|p| {
                    let d = p.fixed_fit - p.free_fit;
                    let rel = if p.free_fit.abs() > 1.0 {
                        format!(" ({:+.1} %)", 100.0 * d / p.free_fit)
                    } else {
                        String::new()
                    };
                    format!(
                        "{} by {}{rel} = {:.0}σ (σ {})",
                        p.parameter,
                        value(&p.parameter, d),
                        p.sigmas(),
                        value(&p.parameter, p.free_std).trim_start_matches('+')
                    )
                })
                .collect();
            let freed: Vec<String> = c
                .freed
                .iter()
                .map(|p| format!("{} {:.3} ± {:.3}", p.parameter, p.free_fit, p.free_std))
                .collect();
            // --lab-settings sets two of the flags.
            let lab = if matches!(c.flag.as_str(), "fix_principal_point" | "fix_k3") {
                " (or --lab-settings)"
            } else {
                ""
            };
            format!(
                "WARNING: {camera}: --{}{lab} moves {} against the free fit, which gives {}: the constraint does not fit these images",
                c.flag.replace('_', "-"),
                moves.join(", "),
                freed.join(", ")
            )
        })
        .collect()
}

/// Prints one camera's result: parameters with 1σ, the per-image table, rejected corners.
/// Views and cameras above the handout's `limit` get a warning, on Kinect-sized images only.
pub(crate) fn print_mono(camera: &str, m: &MonoCalibration, limit: f64) {
    let bar = handout_bar_applies(m);
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
            "  note: the distortion model folds inside the image (undistorted radius {r:.3}): {:.2} % of the pixels, near the corners, lie beyond the largest radius the model reaches: no ray maps onto them, so undistorted images leave them out",
            100.0 * fraction
        );
    }
    println!("  {:<28} {:>8} {:>8} {:>8}  status", "image", "corners", "RMS px", "tilt°");
    for v in &m.views {
        let status = match &v.rejected {
            Some(why) => format!("REJECTED: {why}"),
            None if bar && v.rms_px > limit => format!("WARNING: above the handout's {limit} px"),
            None => "ok".into(),
        };
        println!(
            "  {:<28} {:>8} {:>8} {:>8}  {status}",
            v.name,
            v.n_corners,
            cell(v.rms_px, 4),
            cell(v.tilt_deg, 1)
        );
    }
    for c in &m.rejected_corners {
        println!(
            "  rejected corner {} of {}: error {:.2} px > {:.2} px",
            c.id, c.view, c.error_px, c.threshold_px
        );
    }
    for line in fix_warnings(camera, m) {
        println!("  {line}");
    }
    let weak = weakly_constrained(m);
    if !weak.is_empty() {
        let tilts: Vec<f64> = m
            .views
            .iter()
            .filter(|v| v.rejected.is_none() && v.tilt_deg.is_finite())
            .map(|v| v.tilt_deg)
            .collect();
        let (lo, hi) =
            tilts.iter().fold((f64::INFINITY, 0.0f64), |(a, b), &t| (a.min(t), b.max(t)));
        println!(
            "  WARNING: {camera}: these {} views constrain it weakly: {} (1σ); add views with the board tilted 30-45° in different directions and reaching the image's corners (these are tilted {lo:.0}-{hi:.0}°)",
            tilts.len(),
            weak.join(", ")
        );
    }
    if m.rms_px > limit {
        if bar {
            println!(
                "  WARNING: {camera} RMS {:.3} px is above the handout's {limit} px",
                m.rms_px
            );
        } else {
            println!(
                "  note: the handout's {limit} px bar is for the Kinect's images; these are {}x{}, so no view is warned about",
                m.camera.width, m.camera.height
            );
        }
    }
}

/// Prints the stereo result: each camera alone, the joint fit, the per-pair table.
pub(crate) fn print_stereo(s: &StereoCalibration, ir_views: &[ViewCorners]) {
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
        "  rotation {:.4}° (axis-angle [{}] rad) ± ({:.4}, {:.4}, {:.4})°",
        s.color_from_depth.angle_deg(),
        s.color_from_depth
            .axis_angle()
            .iter()
            .map(|v| format!("{v:.6}"))
            .collect::<Vec<_>>()
            .join(", "),
        rs.x,
        rs.y,
        rs.z
    );
    println!(
        "  {:<28} {:>10} {:>10} {:>10} {:>10}",
        "pair", "IR RMS", "colour RMS", "IR weight", "col weight"
    );
    // A pair without the board in one camera (`--allow-unpaired`) or left out of the joint fit
    // has no value there: "-", not NaN.
    let cell = |v: f64, digits: usize| {
        if v.is_finite() { format!("{v:.digits$}") } else { "-".to_string() }
    };
    for (i, ((d, c), (wd, wc))) in s.view_rms_px.iter().zip(&s.view_weights).enumerate() {
        println!(
            "  {:<28} {:>10} {:>10} {:>10} {:>10}",
            ir_views[i].name,
            cell(*d, 4),
            cell(*c, 4),
            cell(*wd, 2),
            cell(*wc, 2)
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
}

/// Prints the held-out check (`calib::holdout`); a check that could not be made (too few
/// views) is said so (`calib::pipeline::fit::held_out_json` is its `report.json` entry).
pub(crate) fn print_held_out(h: &std::result::Result<calib::holdout::HoldOut, calib::CalibError>) {
    match h {
        Ok(h) => {
            println!(
                "\nheld-out check: calibrated on {} views (the 1st, 3rd, ...), predicted the other {}:",
                h.train.len(),
                h.held_out.len()
            );
            for e in &h.errors {
                println!(
                    "  {:<24} median {:.3} px, 95 % {:.3} px over {} corners (in-sample RMS {:.3} px)",
                    e.what, e.median_px, e.p95_px, e.corners, e.in_sample_rms_px
                );
            }
            if h.errors.iter().any(|e| e.what.contains("rig")) {
                println!(
                    "  (colour through the rig: the board pose from the held-out IR corners only, carried by the rig)"
                );
            }
        }
        Err(e) => println!("\nheld-out check: not done: {e}"),
    }
}

/// A progress bar of `len` steps labelled `msg` (on stderr).
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

/// What the report folder shows.
#[derive(Default)]
pub(crate) struct Figures<'a> {
    /// The board (its size found when `--board auto`).
    pub board: Option<Board>,
    /// (name, final camera, single-camera result with per-view data, RMS limit).
    pub cameras: Vec<(&'static str, CameraModel, MonoCalibration, f64)>,
    /// IR images (file, pixels, detection).
    pub ir_images: Vec<(&'a Path, &'a Image<u8>, &'a ViewCorners)>,
    /// Colour images (file, pixels, detection).
    pub color_images: Vec<(&'a Path, &'a Image<u8>, &'a ViewCorners)>,
}

fn save_rgb(path: &Path, buf: Vec<u8>, w: usize, h: usize) -> Result<()> {
    let px = buf.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    write_color_png(path, &Image::from_vec(w, h, px)?)?;
    Ok(())
}

impl Figures<'_> {
    /// Writes every figure into the staged report folder (report.json is the caller's: it
    /// is written last, with the time these took).
    pub(crate) fn write(&self, dir: &StagedDir) -> Result<()> {
        register_font();
        let pb = bar(self.ir_images.len() + self.color_images.len(), "report figures");
        let all: Vec<_> = self.ir_images.iter().chain(&self.color_images).collect();
        let names = figure_stems(&all.iter().map(|(p, _, _)| *p).collect::<Vec<_>>());
        // One figure per image, independent of the others: on rayon's pool (a serial loop
        // was 1.47 s of a 2.1 s `--report` run on the 15 rendered pairs, 49 ms per figure,
        // mostly the 1080p PNG encoding).
        use rayon::prelude::*;
        all.par_iter().zip(names).try_for_each(|((_, img, v), name)| -> Result<()> {
            corners_figure(&dir.join(format!("corners_{name}.png")), img, v)?;
            pb.inc(1);
            Ok(())
        })?;
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

/// One figure name per image, all different: the file stem (`left01`), or where two images
/// share a stem (`a/left01.png`, `b/left01.png`; an IR and a colour image of the same name)
/// their folder's name before it (`a_left01`, `b_left01`), and a counter if that still
/// collides — so that no figure overwrites another's.
fn figure_stems(paths: &[&Path]) -> Vec<String> {
    let text = |s: Option<&std::ffi::OsStr>| s.map(|s| s.to_string_lossy().into_owned());
    let stems: Vec<String> =
        paths.iter().map(|p| text(p.file_stem()).unwrap_or_else(|| "image".into())).collect();
    let count = |s: &String| stems.iter().filter(|t| *t == s).count();
    let mut names: Vec<String> = paths
        .iter()
        .zip(&stems)
        .map(|(p, s)| {
            if count(s) == 1 {
                return s.clone();
            }
            match text(p.parent().and_then(Path::file_name)) {
                Some(folder) => format!("{folder}_{s}"),
                None => s.clone(),
            }
        })
        .collect();
    let mut seen = std::collections::HashSet::new();
    for name in &mut names {
        let base = name.clone();
        let mut i = 2;
        while !seen.insert(name.clone()) {
            *name = format!("{base}_{i}");
            i += 1;
        }
    }
    names
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
    let (w, h) = (1000usize, 370 * cams.len().max(1) + 40);
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
            // One bar per image, named on the axis (rotated: up to ~40 names share 1000 px).
            // A view without an RMS (no board, unreadable) gets a light full-height bar, so
            // that every image of the table has its place here.
            let n = m.views.len().max(1);
            let names: Vec<String> = m.views.iter().map(|v| v.name.clone()).collect();
            let ymax =
                m.views.iter().map(|v| v.rms_px).filter(|e| e.is_finite()).fold(*limit, f64::max)
                    * 1.15;
            let mut chart = ChartBuilder::on(&area)
                .caption(
                    format!(
                        "{name} camera (line: handout limit {limit} px; grey: rejected, light grey: no RMS)"
                    ),
                    (FONT_NAME, 16),
                )
                .margin(8)
                .x_label_area_size(100)
                .y_label_area_size(50)
                // `a..b` segmented has a segment for every value of a..=b: one per view.
                .build_cartesian_2d((0..n - 1).into_segmented(), 0f64..ymax)?;
            chart
                .configure_mesh()
                .disable_x_mesh()
                .x_labels(n)
                // plotters centres a rotated label on its tick, so half of it would sit above
                // the axis and be cut off: leading spaces (narrower than letters) move the
                // name below.
                .x_label_formatter(&|v| match v {
                    SegmentValue::CenterOf(i) => names
                        .get(*i)
                        .map(|n| format!("{}{n}", " ".repeat(n.chars().count() * 2)))
                        .unwrap_or_default(),
                    _ => String::new(),
                })
                .y_desc("RMS px")
                // Both axes first; then the x labels rotated (this order: label_style sets both).
                .label_style((FONT_NAME, 12))
                .x_label_style(
                    (FONT_NAME, 11).into_font().transform(FontTransform::Rotate90).color(&BLACK),
                )
                .draw()?;
            chart.draw_series(m.views.iter().enumerate().map(|(i, v)| {
                let (top, colour) = if !v.rms_px.is_finite() {
                    (ymax, RGBColor(225, 225, 225))
                } else if v.rejected.is_some() {
                    (v.rms_px, RGBColor(160, 160, 160))
                } else if v.rms_px > *limit {
                    (v.rms_px, RED)
                } else {
                    (v.rms_px, BLUE)
                };
                let mut bar = Rectangle::new(
                    [(SegmentValue::Exact(i), 0.0), (SegmentValue::Exact(i + 1), top)],
                    colour.filled(),
                );
                bar.set_margin(0, 0, 3, 3);
                bar
            }))?;
            chart.draw_series(LineSeries::new(
                [(SegmentValue::Exact(0), *limit), (SegmentValue::Exact(n), *limit)],
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

/// A number of the per-view table with `decimals` places, or `-` for a view that was not used
/// (the fit gives it no error or tilt: NaN, which a reader would take for a failure).
fn cell(value: f64, decimals: usize) -> String {
    if value.is_finite() { format!("{value:.decimals$}") } else { "-".into() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figure_names_never_collide() {
        let p = |s: &'static str| Path::new(s);
        assert_eq!(
            figure_stems(&[p("a/left01.png"), p("b/left01.png"), p("a/left02.png")]),
            ["a_left01", "b_left01", "left02"]
        );
        // The same folder name twice, and an IR and a colour image named alike.
        assert_eq!(
            figure_stems(&[p("x/a/0001.png"), p("y/a/0001.png"), p("0001.bmp")]),
            ["a_0001", "a_0001_2", "0001"]
        );
        assert_eq!(
            figure_stems(&[p("ir/0001.png"), p("color/0001.png")]),
            ["ir_0001", "color_0001"]
        );
    }
}
