//! The depth correction of a run (`kfuse calibrate --depth`): the depth images of the IR shots
//! read as millimetres, [`crate::depth::fit_depth_from_corners`] on the IR corners, the
//! plausibility check, and the rig's `depth_correction`.

use std::path::{Path, PathBuf};

use geometry::{CameraModel, Image, Rig};

use super::{Event, Observer};
use crate::depth::{DepthFit, DepthShot, check_plausible, fit_depth_from_corners};
use crate::{Board, CalibError, ViewCorners};
use kfuse_io::rig_io::Calibration;

fn input(message: &str) -> Result<(), CalibError> {
    Err(CalibError::Input(message.into()))
}

/// Checks the depth inputs against the others before any work: `depth` (the depth images) and
/// `rig` (`--rig`, the rig the correction is added to) with `ir` and `color`, the image
/// counts of each camera.
pub fn check_args(
    ir: usize,
    color: usize,
    depth: usize,
    rig: Option<&Path>,
) -> Result<(), CalibError> {
    if depth == 0 {
        if rig.is_some() {
            return input(
                "--rig is the rig --depth adds its correction to; give --depth 'shots/depth_*.png' too",
            );
        }
        return Ok(());
    }
    if ir == 0 {
        return input(
            "--depth needs the IR images of the same shots (--ir 'shots/ir_*.png'): the board pose seen in IR gives the true distance of every depth pixel",
        );
    }
    if ir != depth {
        return Err(CalibError::Input(format!(
            "{ir} IR images but {depth} depth images: give the depth image of every IR shot (pairs are matched in sorted order)"
        )));
    }
    if color == 0 && rig.is_none() {
        return input(
            "--depth writes its correction into a rig: give --color images too (stereo calibration), or --rig rig.json (a rig with the IR camera's intrinsics, e.g. from `kfuse rig import kinect_params.json`)",
        );
    }
    if color != 0 && rig.is_some() {
        return input(
            "give either --color (a new stereo calibration) or --rig (an existing rig) with --depth, not both",
        );
    }
    Ok(())
}

/// Reads `--rig` (a kfuse rig).
pub fn load_base_rig(path: &Path) -> Result<Rig, CalibError> {
    match kfuse_io::rig::read_rig(path)?.into_calibration(path)? {
        Calibration::Rig(rig) => Ok(rig),
        Calibration::Camera { .. } => Err(CalibError::Input(format!(
            "{}: a single-camera file; --rig needs a rig (both cameras), e.g. `kfuse rig import kinect_params.json --out rig.json`",
            path.display()
        ))),
    }
}

/// Fits the correction (`crate::depth::fit_depth_from_corners`): board poses from the IR
/// corners with `camera`'s intrinsics held fixed (the depth pixels are that camera's), the
/// depth files read as millimetres; then, unless `force`, refuses an implausible scale. The
/// views without a pose ([`Event::DepthNoPose`]), a scale written anyway
/// ([`Event::DepthForced`]) and the fit ([`Event::DepthFit`], also before a refusal) go to
/// `obs`.
#[allow(clippy::too_many_arguments)]
pub(super) fn fit(
    camera: &CameraModel,
    board: &Board,
    ir_views: &[ViewCorners],
    ir_files: &[PathBuf],
    depth_files: &[PathBuf],
    reject_outliers: bool,
    force: bool,
    obs: &dyn Observer,
) -> Result<DepthFit, CalibError> {
    let mut shots = Vec::new();
    for ((corners, ir_path), depth_path) in ir_views.iter().zip(ir_files).zip(depth_files) {
        let depth =
            kfuse_io::images::read_depth(depth_path, 1e-3).map_err(|e| CalibError::Context {
                context: format!("--depth {}", depth_path.display()),
                source: Box::new(e),
            })?;
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
    let fit = fit_depth_from_corners(camera, board, &shots, reject_outliers).map_err(|e| {
        CalibError::Context {
            context: "depth calibration: board poses from the IR images".into(),
            source: Box::new(e),
        }
    })?;
    for (name, why) in &fit.no_pose {
        obs.event(Event::DepthNoPose { name, why });
    }
    match check_plausible(&fit) {
        Ok(()) => {}
        Err(e) if force => {
            // The refusal's own advice (pass --force, nothing was written) is not what happens.
            let text = e.to_string();
            let text = text.split(", or pass --force").next().unwrap_or(&text);
            obs.event(Event::DepthForced(text));
        }
        Err(e) => {
            obs.event(Event::DepthFit(&fit));
            return Err(e);
        }
    }
    obs.event(Event::DepthFit(&fit));
    Ok(fit)
}

/// The rig's correction with the fit's report.
pub fn correction_of(fit: &DepthFit) -> geometry::depth_correction::DepthCorrection {
    let mut c = fit.correction.clone();
    c.fit = Some(fit.report_json());
    c
}
