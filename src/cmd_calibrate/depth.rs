//! `kfuse calibrate --depth`: the depth images of the IR shots → `calib::depth`'s fit → the
//! rig's `depth_correction`, the table and the report figures (`depth_figures`).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use calib::depth::{
    DepthFit, DepthShot, MIN_DEPTH_VIEWS, MIN_DISTANCE_SPAN_M, check_plausible,
    fit_depth_from_corners,
};
use calib::rig_io::{self, Calibration};
use calib::{Board, ViewCorners};
use geometry::depth_correction::DepthTermKind;
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

/// Fits the correction (`calib::depth::fit_depth_from_corners`): board poses from the IR
/// corners with `camera`'s intrinsics held fixed (the depth pixels are that camera's), the
/// depth files read as millimetres; then, unless `force`, refuses an implausible scale.
pub fn fit(
    camera: &CameraModel,
    board: &Board,
    ir_views: &[ViewCorners],
    ir_files: &[PathBuf],
    depth_files: &[PathBuf],
    reject_outliers: bool,
    force: bool,
) -> Result<DepthFit> {
    let mut shots = Vec::new();
    for ((corners, ir_path), depth_path) in ir_views.iter().zip(ir_files).zip(depth_files) {
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
        shots.push(DepthShot { name, corners: corners.clone(), depth, ir });
    }
    let fit = fit_depth_from_corners(camera, board, &shots, reject_outliers)
        .context("depth calibration: board poses from the IR images")?;
    for (name, why) in &fit.no_pose {
        println!("  {name}: {why}; left out");
    }
    match check_plausible(&fit) {
        Ok(()) => {}
        Err(e) if force => {
            // The refusal's own advice (pass --force, nothing was written) is not what happens.
            let text = e.to_string();
            let text = text.split(", or pass --force").next().unwrap_or(&text);
            println!("  WARNING (--force): {text}; written anyway (--force)");
        }
        Err(e) => {
            print_fit(&fit);
            return Err(e.into());
        }
    }
    Ok(fit)
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
    if let Some(sens) = &fit.sensitivity {
        // Beside each term's σ: how far it moves with what the board poses were computed
        // with (a correction belongs with the intrinsics and square it was fitted with).
        println!(
            "  what it depends on (re-fitted with the IR focal length and the square ±{:.0} %):",
            100.0 * sens.step
        );
        println!(
            "    {:<8} {:>12} {:>10} {:>16} {:>18}",
            "term", "value", "1σ", "per +1 % of f", "per +1 % of square"
        );
        for (t, d) in fit.correction.terms.iter().zip(&sens.terms) {
            // The scale in per cent, the other terms in millimetres.
            let (k, unit) =
                if t.kind == DepthTermKind::Scale { (100.0, " %") } else { (1e3, " mm") };
            println!(
                "    {:<8} {:>12} {:>10} {:>16} {:>18}",
                t.kind.name(),
                format!("{:+.3}{unit}", k * t.value),
                format!("{:.3}{unit}", k * t.std),
                format!("{:+.3}{unit}", k * d.per_percent_focal),
                format!("{:+.3}{unit}", k * d.per_percent_square)
            );
        }
        println!(
            "    (the correction holds with the IR intrinsics and square it was fitted with; the rig keeps them together)"
        );
    }
    if hi - lo < 2.0 * MIN_DISTANCE_SPAN_M {
        println!(
            "  note: boards span {:.2} m; views over at least {:.1} m (and ≥ {MIN_DEPTH_VIEWS} of them) pin offset and scale down better",
            hi - lo,
            2.0 * MIN_DISTANCE_SPAN_M
        );
    }
}
