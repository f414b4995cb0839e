//! The joint calibration of N cameras as one library call (`kfuse calibrate --camera/--shots`,
//! issue 32): each camera's images read and detected as a one- or two-camera run does
//! ([`super::detect`]), one board colouring over every camera, the labels aligned
//! ([`crate::multi::input::align_labels`]), [`crate::multi::calibrate_multi`], and the
//! report ([`crate::multi::report::report_json`]) with the rig that keeps its summary. It
//! prints nothing and writes nothing: progress and events go to an [`Observer`].

use std::collections::BTreeMap;
use std::path::PathBuf;

use geometry::CameraRole;
use geometry::multi_rig::MultiRig;
use geometry::timing::Timings;
use serde_json::Value;

use super::{CameraImages, Observer};
use crate::detect::Refinement;
use crate::multi::input::{CameraFiles, align_labels};
use crate::multi::report::report_json;
use crate::multi::{CameraViews, MultiCalibration, calibrate_multi};
use crate::{Board, CalibError, CalibFlags};
use kfuse_io::rig_io::show::{KINECT_COLOR_SIZE, KINECT_DEPTH_SIZE};

/// What a joint calibration runs on.
#[derive(Debug, Clone)]
pub struct JointRequest {
    /// The cameras, each with its images by view id.
    pub cameras: Vec<CameraFiles>,
    /// The board; with `auto_board` its size is found from the first camera's images.
    pub board: Board,
    /// `--board auto`.
    pub auto_board: bool,
    /// The user gave the board's colouring (`--top-left`): cameras that disagree with it are
    /// not an error.
    pub top_left_given: bool,
    /// Every camera's single-camera flags.
    pub flags: CalibFlags,
    /// The sub-pixel corner estimator.
    pub refinement: Refinement,
    /// The reference camera (its frame is the rig's); `None`: the first depth camera.
    pub reference: Option<String>,
}

/// The result of a joint calibration.
#[derive(Debug, Clone)]
pub struct JointOutcome {
    /// The fit.
    pub calibration: MultiCalibration,
    /// Every camera's detected views (what the fit ran on), in the request's order.
    pub inputs: Vec<CameraViews>,
    /// The board (its size as found with `auto_board`).
    pub board: Board,
    /// `report.json`: the fit, σ, per-view errors and every camera's corners.
    pub report: Value,
    /// The rig to write: the fit's rig with the report (without the corners) as its
    /// `calibration`; validated.
    pub rig: MultiRig,
    /// The stages' times (read and detect per camera, the joint fit).
    pub timings: Timings,
}

/// The stage name of the joint fit in [`JointOutcome::timings`].
pub const JOINT_FIT_STAGE: &str = "joint calibration";

/// Runs a joint calibration (module docs).
pub fn run_joint(req: &JointRequest, obs: &dyn Observer) -> Result<JointOutcome, CalibError> {
    let mut board = req.board;
    let mut timings = Timings::new();
    let mut inputs = Vec::with_capacity(req.cameras.len());
    let mut colouring = super::detect::Colouring::default();
    for cam in &req.cameras {
        check_image_sizes(cam)?;
    }
    for (i, cam) in req.cameras.iter().enumerate() {
        let asked =
            Board { top_left_black: board.top_left_black.filter(|_| req.top_left_given), ..board };
        let files: Vec<PathBuf> = cam.files.values().cloned().collect();
        let d = super::detect::load_and_detect(
            &CameraImages::files(files),
            &asked,
            req.auto_board && i == 0,
            &cam.name,
            req.refinement,
            obs,
        )?;
        timings.extend("", &d.timings);
        (board.cols, board.rows) = (d.board.cols, d.board.rows);
        // One board shows one colouring to every camera that decides it.
        if !req.top_left_given {
            colouring.agree(&cam.name, d.board.top_left_black, &board)?;
        }
        let views: BTreeMap<u64, _> = cam.files.keys().copied().zip(d.views).collect();
        let Some(size) = views.values().find(|v| v.width > 0) else {
            return Err(CalibError::Input(format!(
                "camera {}: none of its {} image(s) can be read",
                cam.name,
                views.len()
            )));
        };
        let (width, height) = (size.width, size.height);
        inputs.push(CameraViews {
            name: cam.name.clone(),
            role: cam.role,
            sensor: cam.sensor.clone(),
            width,
            height,
            views,
            flags: req.flags,
        });
    }
    align_labels(&board, &mut inputs);
    let calibration = timings
        .time(JOINT_FIT_STAGE, || calibrate_multi(&board, &inputs, req.reference.as_deref()))?;
    let files: Vec<BTreeMap<u64, PathBuf>> = req.cameras.iter().map(|c| c.files.clone()).collect();
    let report = report_json(&board, &calibration, &inputs, &files);
    let mut rig = calibration.rig.clone();
    // The rig keeps the report without the corners (those are in report.json).
    let mut summary = report.clone();
    if let Some(m) = summary.as_object_mut() {
        m.remove("detections");
    }
    rig.calibration = Some(summary);
    rig.validate().map_err(|e| {
        CalibError::Input(format!(
            "the calibration gives a rig that kfuse cannot use ({e}); nothing was written"
        ))
    })?;
    check_plausible(&rig)?;
    Ok(JointOutcome { calibration, inputs, board, report, rig, timings })
}

/// Fails, before any image is decoded, when one of `cam`'s images (read from its header) is
/// not the size of its first readable one: the fit then took the first image's size for the
/// camera and fitted the others' corners into it (1920x1080 colour shots in a 512x424 IR
/// camera gave a Kinect whose two cameras were 2.8 m and 120° apart, exit 0). Unreadable
/// headers are left to the reader, which lists them.
fn check_image_sizes(cam: &CameraFiles) -> Result<(), CalibError> {
    let mut first: Option<(&PathBuf, (usize, usize))> = None;
    for path in cam.files.values() {
        let Ok(size) = kfuse_io::image_header::image_size(path) else { continue };
        let Some((first_path, first_size)) = first else {
            first = Some((path, size));
            continue;
        };
        if size == first_size {
            continue;
        }
        let kinect = match (cam.role, size) {
            (CameraRole::Depth, KINECT_COLOR_SIZE) => {
                " (the Kinect v2's colour size: a colour image among the IR ones?)"
            }
            (CameraRole::Color, KINECT_DEPTH_SIZE) => {
                " (the Kinect v2's IR size: an IR image among the colour ones?)"
            }
            _ => "",
        };
        return Err(CalibError::Input(format!(
            "camera {}: {} is {}x{}{kinect}, its first image {} is {}x{}: one camera's images are all of that camera; give each camera only its own images (SERIAL.depth the ir_* files, SERIAL.color the color_* files); nothing was written",
            cam.name,
            path.display(),
            size.0,
            size.1,
            first_path.display(),
            first_size.0,
            first_size.1
        )));
    }
    Ok(())
}

/// The plausibility check every reader and writer of rigs runs
/// ([`MultiRig::plausibility_problems`]: `kfuse rig import`, `rig show`, `fuse`), as a refusal:
/// a joint calibration has no `--force`, and a rig that `fuse` refuses is not a result.
fn check_plausible(rig: &MultiRig) -> Result<(), CalibError> {
    let problems = rig.plausibility_problems();
    if problems.is_empty() {
        return Ok(());
    }
    Err(CalibError::Input(format!(
        "the calibration gives a rig that `kfuse fuse` would refuse: {}; check that each camera's images are its own and that one shot number is one board pose in every camera (SERIAL.depth the ir_* files, SERIAL.color the color_* files); nothing was written",
        problems.join("; ")
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A Kinect whose colour camera sits 2.8 m from its IR camera (the rig) is
    /// refused, naming the sensor and the baseline; the Kinect's own 52 mm passes.
    #[test]
    fn an_implausible_joint_rig_is_refused() {
        let mut pair = geometry::synth::kinect_rig();
        let good = MultiRig::from_pair(&pair, Some("0001"));
        assert!(check_plausible(&good).is_ok());
        pair.color_from_depth.translation = nalgebra::Vector3::new(-2.8, 0.0, 0.0);
        let e = check_plausible(&MultiRig::from_pair(&pair, Some("0001"))).unwrap_err();
        let e = e.to_string();
        assert!(
            e.contains("sensor \"0001\"")
                && e.contains("|T| = 2.8 m is over 0.5 m")
                && !e.contains('\n'),
            "{e}"
        );
    }
}
