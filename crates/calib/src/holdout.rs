//! Held-out check: calibrate on half the views, predict the other half.
//!
//! An in-sample RMS says how well the model bends to the corners it was fitted to; the error
//! on views the fit never saw says how well it predicts. The split is deterministic: the
//! usable views (or pairs: both cameras show a board) in input order, the 1st, 3rd, 5th, …
//! calibrate, the 2nd, 4th, … are held out ([`split`]).
//!
//! Prediction of a held-out view:
//! * **one camera** ([`predict_mono`]): the board pose from the view's own corners with the
//!   trained intrinsics held (six numbers fitted to 2·N corner coordinates, so the error is a
//!   little below what a known pose would give), then every corner's distance to its
//!   projection;
//! * **the colour camera through the rig** ([`predict_through_rig`]): the board pose from the
//!   held-out view's IR corners alone (trained IR intrinsics held), carried into the colour
//!   camera by the trained `color_from_depth` and projected with the trained colour
//!   intrinsics; no colour corner of the view is used, so the error measures the whole rig.
//!
//! Each set of errors is summarised by its median and 95th percentile (nearest rank) beside
//! the training fit's in-sample RMS of that camera.

use geometry::{CameraModel, RigidTransform};
use serde::{Deserialize, Serialize};

use crate::mono::{CalibFlags, MIN_CORNERS_PER_VIEW, MIN_VIEWS, calibrate_mono_unchecked};
use crate::{Board, CalibError, StereoOptions, ViewCorners, calibrate_stereo};

/// Fewest usable views (pairs) for a held-out check: 6, so that both halves have the
/// [`MIN_VIEWS`] a calibration (and the held-out poses' tilt check) needs.
pub const MIN_HOLDOUT_VIEWS: usize = 2 * MIN_VIEWS;

/// The held-out errors of one prediction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeldOutErrors {
    /// What was predicted ("IR", "colour", "colour through the rig").
    pub what: String,
    /// Corners predicted.
    pub corners: usize,
    /// Median distance of a held-out corner to its prediction, px.
    pub median_px: f64,
    /// 95th percentile (nearest rank) of that distance, px.
    pub p95_px: f64,
    /// The training fit's RMS for this camera (in-sample), px.
    pub in_sample_rms_px: f64,
}

/// The held-out check of a calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HoldOut {
    /// The views the check calibrated on (names of the first camera's images).
    pub train: Vec<String>,
    /// The views it predicted.
    pub held_out: Vec<String>,
    /// One entry per prediction.
    pub errors: Vec<HeldOutErrors>,
}

impl HoldOut {
    /// The check as JSON for `report.json`.
    pub fn report_json(&self) -> serde_json::Value {
        serde_json::json!({
            "split": "usable views (pairs: both cameras show the board) in input order; the 1st, 3rd, 5th, ... calibrate, the 2nd, 4th, ... are predicted",
            "prediction": "one camera: board pose from the held-out view's own corners with the trained intrinsics held; colour through the rig: board pose from the held-out IR corners only, carried by the trained color_from_depth into the trained colour camera",
            "statistic": "distance of each held-out corner to its prediction, px: median and 95th percentile (nearest rank); in_sample_rms_px is the training fit's RMS",
            "train": self.train,
            "held_out": self.held_out,
            "errors": self.errors,
        })
    }
}

/// Median and 95th percentile (nearest rank) of `errors`; NaN for none.
pub fn median_p95(errors: &[f64]) -> (f64, f64) {
    if errors.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let mut e = errors.to_vec();
    e.sort_by(f64::total_cmp);
    let n = e.len();
    let median = if n % 2 == 1 { e[n / 2] } else { 0.5 * (e[n / 2 - 1] + e[n / 2]) };
    let rank = (0.95 * n as f64).ceil() as usize;
    (median, e[rank.clamp(1, n) - 1])
}

/// The split of the module docs over the indices `usable`: (train, held out).
pub fn split(usable: &[usize]) -> (Vec<usize>, Vec<usize>) {
    let train = usable.iter().step_by(2).copied().collect();
    let held = usable.iter().skip(1).step_by(2).copied().collect();
    (train, held)
}

fn has_board(v: &ViewCorners) -> bool {
    v.unusable.is_none() && v.corners.len() >= MIN_CORNERS_PER_VIEW
}

fn too_few(camera: &str, usable: usize) -> CalibError {
    CalibError::TooFewViews {
        camera: format!("{camera} (held-out check: half the views calibrate, half are predicted)"),
        usable,
        needed: MIN_HOLDOUT_VIEWS,
        left_out: String::new(),
    }
}

/// The board poses of `views` seen by `camera` with its intrinsics held (no outlier
/// rejection: a held-out view is predicted as it is).
fn poses(
    camera: &CameraModel,
    board: &Board,
    views: &[ViewCorners],
) -> Result<Vec<Option<RigidTransform>>, CalibError> {
    let flags = CalibFlags {
        use_intrinsic_guess: true,
        fix_intrinsics: true,
        reject_outliers: false,
        ..CalibFlags::default()
    };
    let m = calibrate_mono_unchecked("held-out views", board, views, &flags, Some(camera))?;
    Ok(m.views.iter().map(|v| v.camera_from_board.filter(|_| v.rejected.is_none())).collect())
}

/// Distances (px) of `views`' corners to their projection through `camera`, each view's pose
/// fitted to its own corners with the intrinsics held (module docs).
pub fn predict_mono(
    camera: &CameraModel,
    board: &Board,
    views: &[ViewCorners],
) -> Result<Vec<f64>, CalibError> {
    let poses = poses(camera, board, views)?;
    Ok(errors(camera, board, views, &poses, &RigidTransform::identity()))
}

/// Distances (px) of the colour corners `color_views[i]` to their prediction from the IR
/// corners `depth_views[i]` through `color_from_depth` (module docs).
pub fn predict_through_rig(
    board: &Board,
    depth: &CameraModel,
    color: &CameraModel,
    color_from_depth: &RigidTransform,
    depth_views: &[ViewCorners],
    color_views: &[ViewCorners],
) -> Result<Vec<f64>, CalibError> {
    let poses = poses(depth, board, depth_views)?;
    Ok(errors(color, board, color_views, &poses, color_from_depth))
}

fn errors(
    camera: &CameraModel,
    board: &Board,
    views: &[ViewCorners],
    poses: &[Option<RigidTransform>],
    camera_from_pose_frame: &RigidTransform,
) -> Vec<f64> {
    let mut out = Vec::new();
    for (v, pose) in views.iter().zip(poses) {
        let Some(pose) = pose else { continue };
        let camera_from_board = camera_from_pose_frame.compose(pose);
        for c in &v.corners {
            if let Some(p) = camera.project(&camera_from_board.apply(&board.object_point(c.id))) {
                out.push((c.px - p).norm());
            }
        }
    }
    out
}

fn summary(what: &str, errors: &[f64], in_sample_rms_px: f64) -> HeldOutErrors {
    let (median_px, p95_px) = median_p95(errors);
    HeldOutErrors { what: what.into(), corners: errors.len(), median_px, p95_px, in_sample_rms_px }
}

fn pick(views: &[ViewCorners], idx: &[usize]) -> Vec<ViewCorners> {
    idx.iter().map(|&i| views[i].clone()).collect()
}

/// The held-out check of a single-camera calibration with `flags` (module docs).
pub fn held_out_mono(
    camera: &str,
    board: &Board,
    views: &[ViewCorners],
    flags: &CalibFlags,
    guess: Option<&CameraModel>,
) -> Result<HoldOut, CalibError> {
    let usable: Vec<usize> = (0..views.len()).filter(|&i| has_board(&views[i])).collect();
    if usable.len() < MIN_HOLDOUT_VIEWS {
        return Err(too_few(camera, usable.len()));
    }
    let (train, held) = split(&usable);
    let m = calibrate_mono_unchecked(camera, board, &pick(views, &train), flags, guess)?;
    let e = predict_mono(&m.camera, board, &pick(views, &held))?;
    Ok(HoldOut {
        train: train.iter().map(|&i| views[i].name.clone()).collect(),
        held_out: held.iter().map(|&i| views[i].name.clone()).collect(),
        errors: vec![summary(camera, &e, m.rms_px)],
    })
}

/// The held-out check of a stereo calibration with `options` (module docs): IR and colour
/// each from their own corners, and the colour camera through the rig.
pub fn held_out_stereo(
    board: &Board,
    depth_views: &[ViewCorners],
    color_views: &[ViewCorners],
    options: &StereoOptions,
) -> Result<HoldOut, CalibError> {
    let usable: Vec<usize> = (0..depth_views.len().min(color_views.len()))
        .filter(|&i| has_board(&depth_views[i]) && has_board(&color_views[i]))
        .collect();
    if usable.len() < MIN_HOLDOUT_VIEWS {
        return Err(too_few("stereo pairs", usable.len()));
    }
    let (train, held) = split(&usable);
    let s = calibrate_stereo(
        board,
        &pick(depth_views, &train),
        &pick(color_views, &train),
        options,
        None,
        None,
    )?;
    let (hd, hc) = (pick(depth_views, &held), pick(color_views, &held));
    let ir = predict_mono(&s.depth, board, &hd)?;
    let colour = predict_mono(&s.color, board, &hc)?;
    let rig = predict_through_rig(board, &s.depth, &s.color, &s.color_from_depth, &hd, &hc)?;
    Ok(HoldOut {
        train: train.iter().map(|&i| depth_views[i].name.clone()).collect(),
        held_out: held.iter().map(|&i| depth_views[i].name.clone()).collect(),
        errors: vec![
            summary("IR", &ir, s.depth_rms_px),
            summary("colour", &colour, s.color_rms_px),
            summary("colour through the rig", &rig, s.color_rms_px),
        ],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_and_split_are_the_documented_ones() {
        let e: Vec<f64> = (1..=20).map(f64::from).collect();
        // Median of 1..=20: 10.5; 95th nearest rank: the 19th value.
        assert_eq!(median_p95(&e), (10.5, 19.0));
        assert_eq!(median_p95(&[3.0]), (3.0, 3.0));
        assert_eq!(split(&[0, 2, 3, 5, 8]), (vec![0, 3, 8], vec![2, 5]));
    }
}
