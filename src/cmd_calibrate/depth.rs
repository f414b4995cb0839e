//! `kfuse calibrate --depth`: the depth images of the IR shots → `calib::depth`'s fit → the
//! rig's `depth_correction`, the table and the report figures (`depth_figures`).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use calib::depth::{
    DepthFit, DepthView, MIN_DEPTH_VIEWS, MIN_DISTANCE_SPAN_M, fit_depth_correction,
};
use calib::rig_io::{self, Calibration};
use calib::{Board, CalibFlags, ViewCorners, calibrate_mono};
use geometry::{CameraModel, Image, Rig};

/// Checks the depth flags against the others before any work.
pub fn check_args(
    ir_files: &[PathBuf],
    color_files: &[PathBuf],
    depth_files: &[PathBuf],
    rig: Option<&Path>,
) -> Result<()> {
    if depth_files.is_empty() {
        if rig.is_some() {
            bail!(
                "--rig is the rig --depth adds its correction to; give --depth 'shots/depth_*.png' too"
            );
        }
        return Ok(());
    }
    if ir_files.is_empty() {
        bail!(
            "--depth needs the IR images of the same shots (--ir 'shots/ir_*.png'): the board pose seen in IR gives the true distance of every depth pixel"
        );
    }
    if ir_files.len() != depth_files.len() {
        bail!(
            "{} IR images but {} depth images: give the depth image of every IR shot (pairs are matched in sorted order)",
            ir_files.len(),
            depth_files.len()
        );
    }
    if color_files.is_empty() && rig.is_none() {
        bail!(
            "--depth writes its correction into a rig: give --color images too (stereo calibration), or --rig rig.json (a rig with the IR camera's intrinsics, e.g. from `kfuse rig import kinect_params.json`)"
        );
    }
    if !color_files.is_empty() && rig.is_some() {
        bail!(
            "give either --color (a new stereo calibration) or --rig (an existing rig) with --depth, not both"
        );
    }
    Ok(())
}

/// Reads `--rig` (a kfuse rig).
pub fn read_rig(path: &Path) -> Result<Rig> {
    match rig_io::load(path)? {
        Calibration::Rig(rig) => Ok(rig),
        Calibration::Camera { .. } => bail!(
            "{}: a single-camera file; --rig needs a rig (both cameras), e.g. `kfuse rig import kinect_params.json --out rig.json`",
            path.display()
        ),
    }
}

/// Fits the correction: board poses from the IR corners with `camera`'s intrinsics held
/// fixed (the depth pixels are that camera's), the depth files read as millimetres.
pub fn fit(
    camera: &CameraModel,
    board: &Board,
    ir_views: &[ViewCorners],
    ir_files: &[PathBuf],
    depth_files: &[PathBuf],
    reject_outliers: bool,
) -> Result<DepthFit> {
    let flags = CalibFlags {
        use_intrinsic_guess: true,
        fix_intrinsics: true,
        reject_outliers,
        ..CalibFlags::default()
    };
    let m = calibrate_mono("IR camera (poses for --depth)", board, ir_views, &flags, Some(camera))
        .context("depth calibration: board poses from the IR images")?;
    let mut views = Vec::new();
    for ((corners, ir_path), depth_path) in ir_views.iter().zip(ir_files).zip(depth_files) {
        let Some(pose) = m
            .views
            .iter()
            .find(|v| v.name == corners.name && v.rejected.is_none())
            .and_then(|v| v.camera_from_board)
        else {
            println!("  {}: no board pose from {}; left out", depth_path.display(), corners.name);
            continue;
        };
        let depth = kfuse_io::images::read_depth(depth_path, 1e-3)
            .with_context(|| format!("--depth {}", depth_path.display()))?;
        let ir = image::open(ir_path).ok().map(|i| {
            let g = i.into_luma16();
            let (w, h) = (g.width() as usize, g.height() as usize);
            Image::from_vec(w, h, g.into_raw()).unwrap_or_else(|_| Image::filled(1, 1, 0))
        });
        let ir = ir.filter(|i| i.size() == depth.size());
        let name = depth_path
            .file_name()
            .map_or_else(|| depth_path.display().to_string(), |n| n.to_string_lossy().into_owned());
        views.push(DepthView { name, camera_from_board: pose, depth, ir });
    }
    Ok(fit_depth_correction(camera, board, &views)?)
}

/// The rig's correction with the fit's report.
pub fn correction_of(fit: &DepthFit) -> geometry::depth_correction::DepthCorrection {
    let mut c = fit.correction.clone();
    c.fit = Some(fit.report_json());
    c
}

/// Prints the table: per view pixels, distance, RMS before/after, rejections; the terms.
pub fn print_fit(fit: &DepthFit) {
    println!("\ndepth calibration: measured z against the IR board plane");
    println!(
        "  {:<24} {:>7} {:>7} {:>11} {:>11}",
        "view", "pixels", "z (m)", "RMS before", "RMS after"
    );
    for v in &fit.views {
        println!(
            "  {:<24} {:>7} {:>7.3} {:>8.2} mm {:>8.2} mm{}",
            v.name,
            v.pixels,
            v.median_z_m,
            1e3 * v.rms_before_m,
            1e3 * v.rms_after_m,
            v.rejected.as_ref().map(|r| format!("  rejected: {r}")).unwrap_or_default()
        );
    }
    println!("  model order (from the data):");
    for o in &fit.order_steps {
        println!(
            "    {:<16} RMS {:.3} mm, leave-one-view-out {:.3} mm  {}",
            o.terms,
            1e3 * o.rms_m,
            1e3 * o.cv_rms_m,
            if o.kept { "kept" } else { "not kept" }
        );
    }
    let (lo, hi) = fit.distance_range_m;
    println!(
        "  {} views at {lo:.2}–{hi:.2} m; RMS {:.2} mm before, {:.2} mm after",
        fit.views.iter().filter(|v| v.rejected.is_none()).count(),
        1e3 * fit.rms_before_m,
        1e3 * fit.rms_after_m
    );
    for line in fit.correction.describe() {
        println!("  {line}");
    }
    if hi - lo < 2.0 * MIN_DISTANCE_SPAN_M {
        println!(
            "  note: boards span {:.2} m; views over at least {:.1} m (and ≥ {MIN_DEPTH_VIEWS} of them) pin offset and scale down better",
            hi - lo,
            2.0 * MIN_DISTANCE_SPAN_M
        );
    }
}
