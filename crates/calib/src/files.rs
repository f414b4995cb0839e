//! Calibration files: the rig JSON (`geometry::Rig` with its `calibration` report), a
//! single-camera JSON, and OpenCV FileStorage YAML export (the writers are
//! `kfuse_io::rig_io::opencv`'s, re-exported here). Writing goes through
//! `kfuse_io::atomic` (temporary file + rename), so a failed run leaves nothing half-written.

use std::path::Path;

use geometry::Rig;
use kfuse_io::atomic::write_bytes_atomic;
use serde_json::{Value, json};

use crate::mono::{IntrinsicsStd, MonoCalibration};
use crate::{Board, CalibError, StereoCalibration, ViewCorners};

/// The OpenCV FileStorage writers live with the OpenCV reader in `kfuse_io::rig_io::opencv`.
pub use kfuse_io::rig_io::opencv::{opencv_yaml_camera, opencv_yaml_rig, opencv_yaml_rig_camera};

/// The report's RMS limits are defined with the rig files that carry the report.
pub use kfuse_io::rig::{COLOR_RMS_LIMIT_PX, DEPTH_RMS_LIMIT_PX};

fn std_json(s: &IntrinsicsStd) -> Value {
    json!({"fx": s.fx, "fy": s.fy, "cx": s.cx, "cy": s.cy, "skew": s.skew,
           "k1": s.k1, "k2": s.k2, "p1": s.p1, "p2": s.p2, "k3": s.k3})
}

/// One corner's row of a report, `[id, values…]`, the corner index written as an integer
/// (`12`, not `12.0`: it is an index into the board's corners, and readers that parse rows
/// by type, as Python's `json` does, get an `int` they can index with).
fn corner_row(id: usize, values: &[f64]) -> Value {
    let mut row = Vec::with_capacity(values.len() + 1);
    row.push(json!(id));
    row.extend(values.iter().map(|v| json!(v)));
    Value::Array(row)
}

/// Stereo residual rows (`[id, x, y, ex, ey]`, the id stored as f64 in memory) with integer ids.
fn residual_rows(rows: &[[f64; 5]]) -> Value {
    Value::Array(rows.iter().map(|r| corner_row(r[0] as usize, &r[1..])).collect())
}

/// The report of one camera's calibration (JSON). Per image: name, RMS, corners used, tilt,
/// rejection reason, and (for the viewer's calibration page) `camera_from_board` (metres,
/// `null` for a rejected view) and `residuals_px`: `[id, x, y, ex, ey]` per used corner, the
/// observed position and the error vector observed − projected, px.
pub fn mono_report(m: &MonoCalibration) -> Value {
    let residuals = |view: usize| -> Value {
        Value::Array(
            m.residuals
                .iter()
                .filter(|r| r.0 == view)
                .map(|(_, id, p, e)| corner_row(*id, &[p.x, p.y, e.x, e.y]))
                .collect(),
        )
    };
    json!({
        "rms_px": m.rms_px,
        "sigma_px": m.sigma_px,
        "std_1sigma": std_json(&m.std),
        "flags": m.flags,
        "fold_radius_normalised": m.camera.distortion.fold_radius(),
        "images": m.views.iter().enumerate().map(|(i, v)| json!({
            "name": v.name, "rms_px": if v.rms_px.is_finite() { json!(v.rms_px) } else { Value::Null },
            "corners": v.n_corners, "tilt_deg": if v.tilt_deg.is_finite() { json!(v.tilt_deg) } else { Value::Null },
            "rejected": v.rejected,
            "camera_from_board": v.camera_from_board.filter(|_| v.rejected.is_none()),
            "residuals_px": residuals(i),
        })).collect::<Vec<_>>(),
        "rejected_corners": m.rejected_corners,
        "fixed_parameter_checks": {
            "what": "per constraint flag: the same views fitted without it; 'moved' lists the other parameters that moved by more than max_sigmas_allowed σ of that free fit (fixed_fit − free_fit)",
            "max_sigmas_allowed": crate::mono::FIX_SHIFT_SIGMAS,
            "checks": m.fix_checks,
        },
    })
}

fn board_json(board: &Board) -> Value {
    json!({"inner_corners_cols": board.cols, "inner_corners_rows": board.rows, "square_m": board.square_m,
           "top_left_black": board.top_left_black})
}

/// The rig of a stereo calibration, with the full report in its `calibration` field.
pub fn stereo_rig(s: &StereoCalibration, board: &Board) -> Rig {
    let mut rig = Rig::new(s.depth, s.color, s.color_from_depth);
    let r = s.rotation_std_rad;
    let t = s.translation_std_m;
    rig.calibration = Some(json!({
        "tool": concat!("kfuse calibrate ", env!("CARGO_PKG_VERSION")),
        "units": "px for errors and intrinsics σ, metres for translations, radians for rotations; σ are 1σ",
        "board": board_json(board),
        "rms_px": s.rms_px,
        "depth_rms_px": s.depth_rms_px,
        "color_rms_px": s.color_rms_px,
        "depth_std_1sigma": std_json(&s.depth_std),
        "color_std_1sigma": std_json(&s.color_std),
        "color_from_depth_rotation_std_rad": [r.x, r.y, r.z],
        "color_from_depth_translation_std_m": [t.x, t.y, t.z],
        "pairs_used": s.pairs_used,
        "per_pair_rms_px": s.view_rms_px.iter().map(|(d, c)| json!({
            "depth": if d.is_finite() { json!(d) } else { Value::Null },
            "color": if c.is_finite() { json!(c) } else { Value::Null },
        })).collect::<Vec<_>>(),
        "per_pair_weight": s.view_weights.iter().map(|(d, c)| json!({
            "depth": if d.is_finite() { json!(d) } else { Value::Null },
            "color": if c.is_finite() { json!(c) } else { Value::Null },
        })).collect::<Vec<_>>(),
        "per_pair_joint_residuals_px": s.joint_residuals_px.iter().map(|(d, c)| json!({"depth": residual_rows(d), "color": residual_rows(c)})).collect::<Vec<_>>(),
        "rejected_views": s.rejected_views.iter().map(|(i, why)| json!({"pair": i, "reason": why})).collect::<Vec<_>>(),
        "rejected_corners": s.rejected_corners,
        "depth_camera": s.depth,
        "color_camera": s.color,
        "color_from_depth": s.color_from_depth,
        "depth_from_board": s.depth_from_board,
        "depth_single_camera": mono_report(&s.depth_mono),
        "color_single_camera": mono_report(&s.color_mono),
    }));
    rig
}

/// Adds what the detector found to a camera's report (the `images` array of
/// [`mono_report`], in the same order as `views`): per image `detected_corners`
/// (`[id, x, y]`, px, every corner found, outliers included) and `image`, the file the
/// corners were found in (`files[i]`, made absolute when it exists so that the report can be
/// opened from any folder). Views beyond `files` get no path.
pub fn add_detections(report: &mut Value, views: &[ViewCorners], files: &[std::path::PathBuf]) {
    let Some(images) = report.get_mut("images").and_then(Value::as_array_mut) else { return };
    for (i, (entry, v)) in images.iter_mut().zip(views).enumerate() {
        entry["detected_corners"] =
            Value::Array(v.corners.iter().map(|c| corner_row(c.id, &[c.px.x, c.px.y])).collect());
        entry["image_size"] = json!([v.width, v.height]);
        if let Some(f) = files.get(i) {
            let f = std::fs::canonicalize(f).unwrap_or_else(|_| f.clone());
            entry["image"] = json!(f.to_string_lossy());
        }
    }
}

/// A single-camera calibration file (`format: kfuse-camera`).
pub fn camera_json(m: &MonoCalibration, board: &Board, role: &str) -> String {
    let mut report = mono_report(m);
    report["board"] = board_json(board);
    let v = json!({
        "format": "kfuse-camera", "version": 1, "role": role,
        "units": "intrinsics in pixels",
        "camera": m.camera,
        "calibration": report,
    });
    serde_json::to_string_pretty(&v).unwrap_or_default()
}

/// Writes text atomically.
pub fn write_text(path: &Path, text: &str) -> Result<(), CalibError> {
    write_bytes_atomic(path, text.as_bytes())?;
    Ok(())
}
