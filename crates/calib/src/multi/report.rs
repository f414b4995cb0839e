//! The report of a joint calibration (`kfuse calibrate --camera/--shots --report DIR`,
//! `report.json`) and its corner detections, which other tools read to calibrate the same
//! corners (`benches/peers/opencv_calibrate_multiview.py`).
//!
//! `report.json` (format [`REPORT_FORMAT`]): the board, the reference, the RMS over every
//! corner, per camera its intrinsics and σ of each, its `camera_from_reference` and σ
//! (rotation in degrees about the axes, translation and centre in mm), its centre in the
//! reference frame, its RMS and single-camera RMS, per view its RMS, the views left out and why,
//! the spanning tree, and `detections` ([`detections_json`]).

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde_json::{Value, json};

use super::{CameraViews, MultiCalibration};
use crate::Board;
use crate::mono::intrinsic_names;

/// The `format` of `report.json`.
pub const REPORT_FORMAT: &str = "kfuse-multi-calibration";
/// The `format` of the detections.
pub const DETECTIONS_FORMAT: &str = "kfuse-multi-detections";

/// Every camera's corners by view id: `{format, board: {cols, rows, square_m}, cameras: [{name,
/// role, sensor, width, height, views: [{view_id, file, corners: [[id, x, y], ...]}]}]}`,
/// pixels 0-based with integer pixel centres (OpenCV's convention), object point of corner
/// `id` at `(square·(id mod cols), square·(id div cols), 0)`. Views without a board are left out.
/// `files` gives each camera's image per view id (the `file` field; `null` where not given).
pub fn detections_json(
    board: &Board,
    cameras: &[CameraViews],
    files: &[BTreeMap<u64, PathBuf>],
) -> Value {
    let cams: Vec<Value> = cameras
        .iter()
        .enumerate()
        .map(|(ci, c)| {
            let views: Vec<Value> = c
                .views
                .iter()
                .filter(|(_, v)| !v.corners.is_empty())
                .map(|(id, v)| {
                    let file = files.get(ci).and_then(|f| f.get(id)).map(|p| p.display().to_string());
                    json!({
                        "view_id": id,
                        "file": file,
                        "corners": v.corners.iter().map(|k| json!([k.id, k.px.x, k.px.y])).collect::<Vec<_>>(),
                    })
                })
                .collect();
            json!({
                "name": c.name,
                "role": c.role.as_str(),
                "sensor": c.sensor,
                "width": c.width,
                "height": c.height,
                "views": views,
            })
        })
        .collect();
    json!({
        "format": DETECTIONS_FORMAT,
        "board": {"cols": board.cols, "rows": board.rows, "square_m": board.square_m},
        "cameras": cams,
    })
}

/// `report.json` of a joint calibration (module docs); `detections` is [`detections_json`]'s.
pub fn report_json(
    board: &Board,
    cal: &MultiCalibration,
    cameras: &[CameraViews],
    files: &[BTreeMap<u64, PathBuf>],
) -> Value {
    let names = intrinsic_names();
    let cams: Vec<Value> = cal
        .rig
        .cameras
        .iter()
        .zip(&cal.cameras)
        .zip(cameras)
        .zip(&cal.tree)
        .enumerate()
        .map(|(ci, (((rc, rep), input), tree))| {
            let k = rc.model.intrinsics;
            let d = rc.model.distortion;
            let values = [k.fx, k.fy, k.cx, k.cy, k.skew, d.k1, d.k2, d.p1, d.p2, d.k3];
            let std = rep.intrinsics_std.to_array();
            let intr: serde_json::Map<String, Value> =
                names.iter().zip(values).map(|(n, v)| (n.to_string(), json!(v))).collect();
            let intr_std: serde_json::Map<String, Value> =
                names.iter().zip(std).map(|(n, v)| (n.to_string(), json!(v))).collect();
            let pose = rc.camera_from_reference;
            let r = pose.rotation.matrix();
            let center = pose.inverse().translation;
            let file_of = |id: &u64| {
                files.get(ci).and_then(|f| f.get(id)).map(|p| p.display().to_string())
            };
            let views: Vec<Value> = rep
                .view_rms_px
                .iter()
                .map(|(id, rms)| json!({"view_id": id, "file": file_of(id), "rms_px": rms}))
                .collect();
            // The single-camera fit's own rejections (no board, outlier views).
            let single_rejected: Vec<Value> = input
                .views
                .keys()
                .zip(&rep.mono.views)
                .filter_map(|(id, v)| {
                    Some(json!({"view_id": id, "file": file_of(id), "reason": v.rejected.clone()?}))
                })
                .collect();
            json!({
                "name": rc.name,
                "role": rc.role.as_str(),
                "sensor": rc.sensor,
                "width": rc.model.width,
                "height": rc.model.height,
                "intrinsics": intr,
                "intrinsics_std_1sigma": intr_std,
                "camera_from_reference": {
                    "rotation": (0..3).map(|i| (0..3).map(|j| r[(i, j)]).collect::<Vec<_>>()).collect::<Vec<_>>(),
                    "translation_m": [pose.translation.x, pose.translation.y, pose.translation.z],
                },
                "rotation_std_1sigma_deg": rep.rotation_std_rad.iter().map(|v| v.to_degrees()).collect::<Vec<_>>(),
                "translation_std_1sigma_mm": rep.translation_std_m.iter().map(|v| v * 1e3).collect::<Vec<_>>(),
                "center_in_reference_m": [center.x, center.y, center.z],
                "center_std_1sigma_mm": rep.center_std_m.iter().map(|v| v * 1e3).collect::<Vec<_>>(),
                "rms_px": rep.rms_px,
                "single_camera_rms_px": rep.mono.rms_px,
                "views": views,
                "single_camera_rejected_views": single_rejected,
                "tree_parent": tree.as_ref().map(|t| t.0.clone()),
                "tree_shared_views": tree.as_ref().map(|t| t.1),
            })
        })
        .collect();
    let tree: Vec<Value> = cal
        .rig
        .cameras
        .iter()
        .zip(&cal.tree)
        .map(|(c, t)| {
            json!({
                "camera": c.name,
                "parent": t.as_ref().map(|t| t.0.clone()),
                "shared_views": t.as_ref().map(|t| t.1),
            })
        })
        .collect();
    json!({
        "format": REPORT_FORMAT,
        "board": {"cols": board.cols, "rows": board.rows, "square_m": board.square_m},
        "reference": cal.rig.reference,
        "rms_px": cal.rms_px,
        "cameras": cams,
        "rejected_views": cal.rejected_views.iter().map(|(v, why)| json!({"view_id": v, "reason": why})).collect::<Vec<_>>(),
        "rejected_corners": cal.rejected_corners,
        "spanning_tree": tree,
        "detections": detections_json(board, cameras, files),
    })
}
