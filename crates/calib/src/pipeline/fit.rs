//! The fits of a run: the stereo pair (pairs checked and aligned, joint fit, held-out check,
//! the consistency check, the rig), one camera alone, or only the depth correction of a given
//! rig; each with the text of its output file and its `report.json`.

use std::time::Instant;

use geometry::Rig;
use geometry::timing::{Timings, ms_since};
use serde_json::Value;

use super::{CameraRun, Event, Fit, Observer, Options};
use crate::depth::DepthFit;
use crate::detect::align_pair;
use crate::files::{
    COLOR_RMS_LIMIT_PX, DEPTH_RMS_LIMIT_PX, add_detections, camera_json, stereo_rig,
};
use crate::holdout::HoldOut;
use crate::{
    Board, CalibError, StereoCalibration, StereoOptions, calibrate_mono, calibrate_stereo,
};

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

/// What a fit gives: the fit, the rig (none for one camera), the output file's text, the
/// report, the held-out check and the depth fit where they were made.
pub(super) struct Fitted {
    pub fit: Fit,
    pub rig: Option<Rig>,
    pub text: String,
    pub report: Value,
    pub held_out: Option<Result<HoldOut, CalibError>>,
    pub depth_fit: Option<DepthFit>,
}

/// The depth correction's part of a run: the depth files and what the fit needs.
pub(super) struct DepthInput<'a> {
    pub files: &'a [std::path::PathBuf],
    pub ir: &'a CameraRun,
    pub force: bool,
}

impl DepthInput<'_> {
    /// Fits the correction for `rig`'s IR camera and adds it (with the report's entry).
    fn add_to(
        &self,
        rig: &mut Rig,
        board: &Board,
        options: &Options,
        timings: &mut Timings,
        obs: &dyn Observer,
    ) -> Result<DepthFit, CalibError> {
        let fit = timings.time(crate::timing::DEPTH, || {
            super::depth::fit(
                &rig.depth,
                board,
                &self.ir.views,
                &self.ir.files,
                self.files,
                options.flags.reject_outliers,
                self.force,
                obs,
            )
        })?;
        rig.depth_correction = Some(Box::new(super::depth::correction_of(&fit)));
        Ok(fit)
    }
}

/// The held-out check's `report.json` entry; a check that could not be made (too few views)
/// says why.
pub fn held_out_json(h: &Result<HoldOut, CalibError>) -> Value {
    match h {
        Ok(h) => h.report_json(),
        Err(e) => serde_json::json!({ "not_done": e.to_string() }),
    }
}

/// Fails when the stereo fit cannot be of pairs that show the same board poses: its RMS far
/// above each camera's own (the usual cause: images of two sessions, or pairs matched out of
/// order). A rig that passes but that `fuse` would refuse (baseline, distortion) gets a
/// warning ([`Event::RigWarning`]): two far-apart cameras can be calibrated, and fused with
/// `--force`.
fn check_stereo_consistent(s: &StereoCalibration, obs: &dyn Observer) -> Result<(), CalibError> {
    let single = s.depth_mono.rms_px.max(s.color_mono.rms_px);
    if s.rms_px > STEREO_RMS_FLOOR_PX && s.rms_px > MAX_STEREO_RMS_RATIO * single {
        return Err(CalibError::Input(format!(
            "the IR and colour images do not show the same board poses pair by pair: the stereo RMS {:.2} px is {:.0}x the single-camera fits' ({:.3} px IR, {:.3} px colour); give the IR and colour images of one session (pairs are matched in sorted file-name order); nothing was written",
            s.rms_px,
            s.rms_px / single,
            s.depth_mono.rms_px,
            s.color_mono.rms_px
        )));
    }
    let rig = Rig::new(s.depth, s.color, s.color_from_depth);
    for problem in rig.plausibility_problems() {
        obs.event(Event::RigWarning(&problem));
    }
    Ok(())
}

/// The rig's JSON, once it reads back as every other command reads rigs: a depth correction
/// outside what a sensor's error can be (`geometry::depth_correction`'s limits) was written with
/// exit 0 and then refused by `rig show` and `fuse`. The usual cause is a wrong `--square`,
/// which scales the boards' distances and with them the fitted depth scale (30mm for 40 mm
/// gave +33.9 %).
pub(super) fn readable_rig_json(rig: &Rig) -> Result<String, CalibError> {
    let text = rig.to_json();
    if let Err(e) = Rig::from_json(&text, std::path::Path::new("rig.json")) {
        // The reader's message starts with the path it was given, which is not the output's.
        let why = match e {
            geometry::GeometryError::Format { message, .. } => message,
            other => other.to_string(),
        };
        let hint = if rig.depth_correction.is_some() {
            "; a wrong --square scales the boards' distances and so the depth scale: check the printed square's side"
        } else {
            ""
        };
        return Err(CalibError::Input(format!(
            "the calibration gives a rig that kfuse cannot use ({why}){hint}; nothing was written"
        )));
    }
    Ok(text)
}

/// The files of a camera's views for the report's `image` entries (none for images given in
/// memory: their names are no files).
fn report_files(c: &CameraRun) -> &[std::path::PathBuf] {
    if c.in_memory { &[] } else { &c.files }
}

/// Pairs checked (the board in both images unless `allow_unpaired`), the colour corners
/// aligned with the IR ones, the joint fit; then the held-out check (with `options.held_out`),
/// the consistency check, the rig with its detections and the depth correction.
pub(super) fn stereo(
    board: &Board,
    ir: &CameraRun,
    color: &mut CameraRun,
    depth: Option<DepthInput<'_>>,
    options: &Options,
    timings: &mut Timings,
    obs: &dyn Observer,
) -> Result<Fitted, CalibError> {
    for i in 0..ir.views.len() {
        let (d, c) = (!ir.views[i].corners.is_empty(), !color.views[i].corners.is_empty());
        if d != c && !options.allow_unpaired {
            let (found, fi, missing, mi) = if d {
                ("IR", &ir.files[i], "colour", &color.files[i])
            } else {
                ("colour", &color.files[i], "IR", &ir.files[i])
            };
            return Err(CalibError::UnpairedView {
                pair: format!("{}", i + 1),
                found: found.into(),
                found_image: fi.display().to_string(),
                missing: missing.into(),
                missing_image: mi.display().to_string(),
            });
        }
        if d && c {
            color.views[i] = align_pair(&ir.views[i], &color.views[i], board);
        }
    }
    let stereo_options = StereoOptions {
        depth_flags: options.flags,
        color_flags: options.flags,
        fix_intrinsics: options.fix_intrinsics,
    };
    let t = Instant::now();
    let s = calibrate_stereo(board, &ir.views, &color.views, &stereo_options, None, None)?;
    crate::timing::add_stereo(timings, &s, ms_since(t));
    let held_out = options.held_out.then(|| {
        timings.time(crate::timing::HELD_OUT, || {
            crate::holdout::held_out_stereo(board, &ir.views, &color.views, &stereo_options)
        })
    });
    obs.event(Event::Stereo { fit: &s, ir_views: &ir.views });
    check_stereo_consistent(&s, obs)?;
    let mut rig = stereo_rig(&s, board);
    if let Some(cal) = rig.calibration.as_mut() {
        // Corners and image paths for `kfuse view` (the calibration page).
        add_detections(&mut cal["depth_single_camera"], &ir.views, report_files(ir));
        add_detections(&mut cal["color_single_camera"], &color.views, report_files(color));
    }
    let mut report = rig.calibration.clone().unwrap_or_default();
    if let Some(h) = &held_out {
        obs.event(Event::HeldOut(h));
        report["held_out"] = held_out_json(h);
    }
    let depth_fit = match depth {
        Some(d) => {
            let fit = d.add_to(&mut rig, board, options, timings, obs)?;
            report["depth_correction"] = fit.report_json();
            Some(fit)
        }
        None => None,
    };
    let text = readable_rig_json(&rig)?;
    Ok(Fitted { fit: Fit::Stereo(Box::new(s)), rig: Some(rig), text, report, held_out, depth_fit })
}

/// `--depth` with `--rig`: the rig's IR intrinsics, only the correction is new.
pub(super) fn depth_only(
    mut rig: Rig,
    board: &Board,
    depth: DepthInput<'_>,
    options: &Options,
    timings: &mut Timings,
    obs: &dyn Observer,
) -> Result<Fitted, CalibError> {
    let fit = depth.add_to(&mut rig, board, options, timings, obs)?;
    let report = serde_json::json!({ "depth_correction": fit.report_json() });
    let text = readable_rig_json(&rig)?;
    Ok(Fitted {
        fit: Fit::DepthOnly,
        rig: Some(rig),
        text,
        report,
        held_out: None,
        depth_fit: Some(fit),
    })
}

/// One camera alone (the IR camera when it has images, else the colour camera): the fit, the
/// held-out check (with `options.held_out`), its single-camera file with the detections.
pub(super) fn mono(
    board: &Board,
    ir: &CameraRun,
    color: &CameraRun,
    options: &Options,
    timings: &mut Timings,
    obs: &dyn Observer,
) -> Result<Fitted, CalibError> {
    let (name, run, limit) = if ir.files.is_empty() {
        ("colour", color, COLOR_RMS_LIMIT_PX)
    } else {
        ("IR", ir, DEPTH_RMS_LIMIT_PX)
    };
    let flags = options.flags;
    let camera = format!("{name} camera");
    let t = Instant::now();
    let m = calibrate_mono(&camera, board, &run.views, &flags, None)?;
    crate::timing::add_mono(timings, name, &m, ms_since(t));
    obs.event(Event::Mono { camera: &camera, fit: &m, limit_px: limit });
    let held_out = options.held_out.then(|| {
        timings.time(crate::timing::HELD_OUT, || {
            crate::holdout::held_out_mono(name, board, &run.views, &flags, None)
        })
    });
    if let Some(h) = &held_out {
        obs.event(Event::HeldOut(h));
    }
    let mut text = camera_json(&m, board, if name == "IR" { "depth" } else { "color" });
    let mut report = match serde_json::from_str::<Value>(&text) {
        Ok(mut v) => {
            // Corners and image paths for `kfuse view` (the calibration page).
            add_detections(&mut v["calibration"], &run.views, report_files(run));
            text = serde_json::to_string_pretty(&v)
                .map_err(|e| CalibError::Input(format!("the camera file: {e}")))?;
            v
        }
        Err(_) => Value::default(),
    };
    if let Some(h) = &held_out {
        report["held_out"] = held_out_json(h);
    }
    let fit = Fit::Mono { camera: name, fit: Box::new(m) };
    Ok(Fitted { fit, rig: None, text, report, held_out, depth_fit: None })
}
