//! The joint calibration of N cameras as one library call (`kfuse calibrate --camera/--shots`,
//! issue 32): each camera's images read and detected as a one- or two-camera run does
//! ([`super::detect`]), one board colouring over every camera, the labels aligned
//! ([`crate::multi::input::align_labels`]), [`crate::multi::calibrate_multi`], and the
//! report ([`crate::multi::report::report_json`]) with the rig that keeps its summary. It
//! prints nothing and writes nothing: progress and events go to an [`Observer`].

use std::collections::BTreeMap;
use std::path::PathBuf;

use geometry::multi_rig::MultiRig;
use geometry::timing::Timings;
use serde_json::Value;

use super::{CameraImages, Observer};
use crate::detect::Refinement;
use crate::multi::input::{CameraFiles, align_labels};
use crate::multi::report::report_json;
use crate::multi::{CameraViews, MultiCalibration, calibrate_multi};
use crate::{Board, CalibError, CalibFlags};

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
    Ok(JointOutcome { calibration, inputs, board, report, rig, timings })
}
