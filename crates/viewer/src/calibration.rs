//! The calibration page's model: a `kfuse calibrate` report read back from its JSON (pure
//! data, tested without a window).
//!
//! Accepted inputs (see [`open_calibration`]):
//! * a report folder (`kfuse calibrate --report DIR`) holding `report.json`;
//! * a stereo rig file (`rig.json`, its `calibration` field is the report) or a folder holding
//!   one together with no capture images;
//! * a single-camera file (`format: kfuse-camera`).
//!
//! The numbers are taken as written: per-image RMS, residual vectors and board poses come
//! from the report (the calibration is never recomputed here). Per image the report holds
//! `detected_corners` (`[id, x, y]` px), `residuals_px` (`[id, x, y, ex, ey]`, error =
//! observed − projected), `camera_from_board` and the `image` path (see `calib::files`, which writes it).
//! Board poses in the 3D view are in the **depth camera's frame** for a stereo report (the
//! joint fit's `depth_from_board`) and in the camera's own frame for a single camera.

use std::path::{Path, PathBuf};

use geometry::{CameraModel, RigidTransform};
use serde_json::Value;

use crate::ViewerError;

/// Names of the ten intrinsic parameters in the report's σ order.
pub const PARAM_NAMES: [&str; 10] = ["fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3"];

/// One image of one camera.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibImage {
    /// File name.
    pub name: String,
    /// RMS reprojection error, px (`None` when the view had no usable board).
    pub rms_px: Option<f64>,
    /// Why the view was left out, if it was.
    pub rejected: Option<String>,
    /// Corners the detector found: `[id, x, y]`, px.
    pub detected: Vec<[f64; 3]>,
    /// Used corners: `[id, x, y, ex, ey]`, px (error = observed − projected).
    pub residuals: Vec<[f64; 5]>,
    /// `camera_from_board`, metres (`None` for a rejected view).
    pub camera_from_board: Option<RigidTransform>,
    /// The image file the corners were found in, if the report names it.
    pub image: Option<PathBuf>,
    /// The same rows after the stereo joint fit (empty for a single-camera report, an unused
    /// pair or a report written before they were added).
    pub joint_residuals: Vec<[f64; 5]>,
    /// Relative weight of this view's corners in the stereo joint fit (1 = the camera's own
    /// noise level, less for a noisier view; `None` for a single-camera report or an unused
    /// pair).
    pub joint_weight: Option<f64>,
}

impl CalibImage {
    /// The joint fit's residual rows when `joint`, else the single-camera fit's.
    pub fn residual_rows(&self, joint: bool) -> &[[f64; 5]] {
        if joint { &self.joint_residuals } else { &self.residuals }
    }
}

impl CalibCamera {
    /// Whether the report carries the stereo joint fit's residuals for this camera.
    pub fn has_joint_residuals(&self) -> bool {
        self.images.iter().any(|i| !i.joint_residuals.is_empty())
    }
}

/// One calibrated camera.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibCamera {
    /// "IR" or "colour".
    pub label: &'static str,
    /// The calibrated camera (final values: after the joint fit for a stereo rig).
    pub model: CameraModel,
    /// 1σ of `fx, fy, cx, cy, skew, k1, k2, p1, p2, k3` (0 = fixed).
    pub std_1sigma: [f64; 10],
    /// Overall RMS, px.
    pub rms_px: f64,
    /// The handout's RMS bar for this camera, px.
    pub limit_px: f64,
    /// Every image in input order.
    pub images: Vec<CalibImage>,
}

/// `color_from_depth` with its uncertainty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoExtrinsics {
    /// `X_color = R·X_depth + T`, metres.
    pub color_from_depth: RigidTransform,
    /// 1σ of the small-angle rotation about x, y, z, radians.
    pub rotation_std_rad: [f64; 3],
    /// 1σ of T, metres.
    pub translation_std_m: [f64; 3],
    /// Joint RMS over both cameras, px.
    pub rms_px: f64,
}

/// A calibration report as the page shows it.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibReport {
    /// The JSON file it was read from.
    pub source: PathBuf,
    /// Depth/IR first, then colour (one of them for a single-camera report).
    pub cameras: Vec<CalibCamera>,
    /// Stereo extrinsics, for a rig report.
    pub stereo: Option<StereoExtrinsics>,
    /// Per pair: the board in the depth camera's frame (stereo reports).
    pub depth_from_board: Vec<Option<RigidTransform>>,
    /// Inner corners per row and column, square side in metres.
    pub board: (usize, usize, f64),
}

/// One table row: name, value, ±3σ (`None` = fixed), unit.
pub type ParamRow = (String, f64, Option<f64>, &'static str);

impl CalibReport {
    /// The board rectangle's size through the outer inner corners, metres.
    pub fn board_size_m(&self) -> (f64, f64) {
        let (c, r, s) = self.board;
        (s * c.saturating_sub(1) as f64, s * r.saturating_sub(1) as f64)
    }

    /// The parameter table with ±3σ (3 × the report's 1σ; σ = 0 means the parameter was
    /// fixed and shows no interval).
    pub fn parameter_rows(&self) -> Vec<(String, Vec<ParamRow>)> {
        let mut out = Vec::new();
        for cam in &self.cameras {
            let k = cam.model.intrinsics;
            let d = cam.model.distortion;
            let values = [k.fx, k.fy, k.cx, k.cy, k.skew, d.k1, d.k2, d.p1, d.p2, d.k3];
            let rows = PARAM_NAMES
                .iter()
                .zip(values)
                .zip(cam.std_1sigma)
                .enumerate()
                .map(|(i, ((n, v), s))| {
                    (n.to_string(), v, (s > 0.0).then_some(3.0 * s), if i < 5 { "px" } else { "" })
                })
                .collect();
            out.push((
                format!(
                    "{} camera ({}x{}), RMS {:.4} px",
                    cam.label, cam.model.width, cam.model.height, cam.rms_px
                ),
                rows,
            ));
        }
        if let Some(s) = &self.stereo {
            let om = s.color_from_depth.axis_angle();
            let t = s.color_from_depth.translation;
            let mut rows: Vec<ParamRow> = Vec::new();
            for (i, axis) in ["x", "y", "z"].iter().enumerate() {
                rows.push((
                    format!("rotation {axis} (axis-angle)"),
                    om[i].to_degrees(),
                    Some(3.0 * s.rotation_std_rad[i].to_degrees()),
                    "°",
                ));
            }
            for (i, axis) in ["x", "y", "z"].iter().enumerate() {
                rows.push((
                    format!("T{axis}"),
                    t[i] * 1000.0,
                    Some(3.0 * s.translation_std_m[i] * 1000.0),
                    "mm",
                ));
            }
            out.push((
                format!("color_from_depth (X_color = R·X_depth + T), joint RMS {:.4} px", s.rms_px),
                rows,
            ));
        }
        out
    }
}

fn bad(path: &Path, message: impl Into<String>) -> ViewerError {
    ViewerError::BadFile { path: path.to_path_buf(), message: message.into() }
}

/// True when `dir` looks like a `kfuse calibrate` output: it holds `report.json`, or a
/// `rig.json` with a `calibration` report and no capture images. A `kfuse capture` folder
/// (`kinect_params.json`) is a frame even with a calibrated `rig.json` beside its shots (the
/// bundled `data/kinect`).
pub fn is_calibration_folder(dir: &Path) -> bool {
    if dir.join("report.json").is_file() {
        return true;
    }
    let rig = dir.join("rig.json");
    let frame_files = ["color.png", "depth.png", "kinect_params.json"];
    if !rig.is_file() || frame_files.iter().any(|f| dir.join(f).exists()) {
        return false;
    }
    std::fs::read_to_string(&rig)
        .ok()
        .and_then(|t| serde_json::from_str::<Value>(&t).ok())
        .is_some_and(|v| v.get("calibration").is_some_and(|c| c.is_object()))
}

/// Opens a `kfuse calibrate` output: a report folder, a rig file or a single-camera file
/// (see the module docs). Every problem names the file.
pub fn open_calibration(path: &Path) -> Result<CalibReport, ViewerError> {
    let file = if path.is_dir() {
        let report = path.join("report.json");
        let rig = path.join("rig.json");
        if report.is_file() {
            report
        } else if rig.is_file() {
            rig
        } else {
            return Err(ViewerError::MissingFile {
                path: report,
                hint: "a calibration report folder holds report.json, as `kfuse calibrate --report DIR` writes it".into(),
            });
        }
    } else if path.is_file() {
        path.to_path_buf()
    } else {
        return Err(ViewerError::MissingFile {
            path: path.to_path_buf(),
            hint: "give a `kfuse calibrate` report folder or rig file".into(),
        });
    };
    let text = std::fs::read_to_string(&file).map_err(|e| bad(&file, e.to_string()))?;
    let json: Value = serde_json::from_str(&text).map_err(|e| {
        bad(&file, format!("not valid JSON ({e}); re-run `kfuse calibrate --report DIR`"))
    })?;
    parse_report(&file, &json)
}

/// Reads a report from parsed JSON; `file` is named in errors.
pub fn parse_report(file: &Path, json: &Value) -> Result<CalibReport, ViewerError> {
    // A rig or camera file carries the report in `calibration`; report.json is the report itself
    // (stereo) or the whole camera file (single camera).
    let (report, single_camera) =
        if json.get("format").and_then(Value::as_str) == Some("kfuse-camera") {
            (
                json.get("calibration")
                    .ok_or_else(|| bad(file, "no \"calibration\" report in this camera file"))?,
                json.get("camera"),
            )
        } else if let Some(c) = json.get("calibration").filter(|c| c.is_object()) {
            (c, None)
        } else {
            (json, None)
        };
    let board = report
        .get("board")
        .ok_or_else(|| bad(file, "no \"board\" entry; it was not written by `kfuse calibrate`"))?;
    let num = |v: &Value, k: &str| {
        v.get(k)
            .and_then(Value::as_f64)
            .ok_or_else(|| bad(file, format!("missing or non-numeric \"{k}\"")))
    };
    let board = (
        num(board, "inner_corners_cols")? as usize,
        num(board, "inner_corners_rows")? as usize,
        num(board, "square_m")?,
    );

    let camera_of = |v: Option<&Value>, what: &str| -> Result<CameraModel, ViewerError> {
        let v = v.ok_or_else(|| bad(file, format!("no \"{what}\" camera; re-run `kfuse calibrate` (this report predates the viewer)")))?;
        serde_json::from_value(v.clone()).map_err(|e| bad(file, format!("\"{what}\": {e}")))
    };
    let mut cameras = Vec::new();
    let mut stereo = None;
    let mut depth_from_board = Vec::new();
    if let Some(depth_mono) = report.get("depth_single_camera") {
        // Stereo: final cameras from the joint fit (in the rig file or in the report).
        let (depth, color) = match json.get("calibration") {
            Some(_) => (
                camera_of(json.get("depth_camera"), "depth_camera")?,
                camera_of(json.get("color_camera"), "color_camera")?,
            ),
            None => (
                camera_of(report.get("depth_camera"), "depth_camera")?,
                camera_of(report.get("color_camera"), "color_camera")?,
            ),
        };
        let color_mono = report
            .get("color_single_camera")
            .ok_or_else(|| bad(file, "no \"color_single_camera\" report"))?;
        cameras.push(camera(
            file,
            "IR",
            depth,
            report.get("depth_std_1sigma"),
            num(report, "depth_rms_px")?,
            depth_mono,
            kfuse_io::rig::DEPTH_RMS_LIMIT_PX,
        )?);
        cameras.push(camera(
            file,
            "colour",
            color,
            report.get("color_std_1sigma"),
            num(report, "color_rms_px")?,
            color_mono,
            kfuse_io::rig::COLOR_RMS_LIMIT_PX,
        )?);
        // Per pair (image order): the joint fit's weights (reports before they existed: none).
        if let Some(weights) = report.get("per_pair_weight").and_then(Value::as_array) {
            for (cam, key) in cameras.iter_mut().zip(["depth", "color"]) {
                for (im, w) in cam.images.iter_mut().zip(weights) {
                    im.joint_weight = w.get(key).and_then(Value::as_f64);
                }
            }
        }
        if let Some(pairs) = report.get("per_pair_joint_residuals_px").and_then(Value::as_array) {
            for (cam, key) in cameras.iter_mut().zip(["depth", "color"]) {
                for (im, pair) in cam.images.iter_mut().zip(pairs) {
                    im.joint_residuals =
                        rows::<5>(file, pair.get(key), &format!("{}: joint residuals", im.name))?;
                }
            }
        }
        let cfd = match json.get("calibration") {
            Some(_) => json.get("color_from_depth"),
            None => report.get("color_from_depth"),
        };
        let cfd: RigidTransform = cfd
            .ok_or_else(|| bad(file, "no \"color_from_depth\"; re-run `kfuse calibrate`"))
            .and_then(|v| {
                serde_json::from_value(v.clone())
                    .map_err(|e| bad(file, format!("\"color_from_depth\": {e}")))
            })?;
        stereo = Some(StereoExtrinsics {
            color_from_depth: cfd,
            rotation_std_rad: triple(file, report, "color_from_depth_rotation_std_rad")?,
            translation_std_m: triple(file, report, "color_from_depth_translation_std_m")?,
            rms_px: num(report, "rms_px")?,
        });
        if let Some(list) = report.get("depth_from_board").and_then(Value::as_array) {
            depth_from_board =
                list.iter().map(|p| serde_json::from_value(p.clone()).ok()).collect();
        }
    } else {
        let model = camera_of(single_camera, "camera")?;
        let role = json.get("role").and_then(Value::as_str).unwrap_or("depth");
        let (label, limit) = if role == "color" {
            ("colour", kfuse_io::rig::COLOR_RMS_LIMIT_PX)
        } else {
            ("IR", kfuse_io::rig::DEPTH_RMS_LIMIT_PX)
        };
        cameras.push(camera(
            file,
            label,
            model,
            report.get("std_1sigma"),
            num(report, "rms_px")?,
            report,
            limit,
        )?);
    }
    Ok(CalibReport { source: file.to_path_buf(), cameras, stereo, depth_from_board, board })
}

fn triple(file: &Path, v: &Value, key: &str) -> Result<[f64; 3], ViewerError> {
    let a = v
        .get(key)
        .and_then(Value::as_array)
        .ok_or_else(|| bad(file, format!("missing \"{key}\"")))?;
    match a.as_slice() {
        [x, y, z] => match (x.as_f64(), y.as_f64(), z.as_f64()) {
            (Some(x), Some(y), Some(z)) => Ok([x, y, z]),
            _ => Err(bad(file, format!("\"{key}\" must hold three numbers"))),
        },
        _ => Err(bad(file, format!("\"{key}\" must hold three numbers"))),
    }
}

fn rows<const N: usize>(
    file: &Path,
    v: Option<&Value>,
    what: &str,
) -> Result<Vec<[f64; N]>, ViewerError> {
    let Some(list) = v else { return Ok(Vec::new()) };
    let list = list.as_array().ok_or_else(|| bad(file, format!("\"{what}\" is not a list")))?;
    list.iter()
        .map(|row| {
            let r = row
                .as_array()
                .filter(|r| r.len() == N)
                .ok_or_else(|| bad(file, format!("\"{what}\": each entry needs {N} numbers")))?;
            let mut out = [0.0; N];
            for (o, x) in out.iter_mut().zip(r) {
                *o = x
                    .as_f64()
                    .ok_or_else(|| bad(file, format!("\"{what}\": non-numeric entry")))?;
            }
            Ok(out)
        })
        .collect()
}

fn camera(
    file: &Path,
    label: &'static str,
    model: CameraModel,
    std: Option<&Value>,
    rms_px: f64,
    mono: &Value,
    limit_px: f64,
) -> Result<CalibCamera, ViewerError> {
    let std = std.ok_or_else(|| bad(file, format!("no 1σ entry for the {label} camera")))?;
    let mut std_1sigma = [0.0; 10];
    for (s, name) in std_1sigma.iter_mut().zip(PARAM_NAMES) {
        *s = std
            .get(name)
            .and_then(Value::as_f64)
            .ok_or_else(|| bad(file, format!("{label} camera σ: missing \"{name}\"")))?;
    }
    let images = mono.get("images").and_then(Value::as_array).ok_or_else(|| {
        bad(file, format!("no per-image list (\"images\") for the {label} camera"))
    })?;
    let images = images
        .iter()
        .map(|im| {
            let name = im
                .get("name")
                .and_then(Value::as_str)
                .ok_or_else(|| bad(file, format!("{label} image without a \"name\"")))?;
            Ok(CalibImage {
                name: name.to_string(),
                rms_px: im.get("rms_px").and_then(Value::as_f64),
                rejected: im.get("rejected").and_then(Value::as_str).map(str::to_string),
                detected: rows::<3>(
                    file,
                    im.get("detected_corners"),
                    &format!("{name}: detected_corners"),
                )?,
                residuals: rows::<5>(
                    file,
                    im.get("residuals_px"),
                    &format!("{name}: residuals_px"),
                )?,
                camera_from_board: im
                    .get("camera_from_board")
                    .filter(|p| !p.is_null())
                    .and_then(|p| serde_json::from_value(p.clone()).ok()),
                image: im.get("image").and_then(Value::as_str).map(PathBuf::from),
                joint_weight: None,
                joint_residuals: Vec::new(),
            })
        })
        .collect::<Result<Vec<_>, ViewerError>>()?;
    Ok(CalibCamera { label, model, std_1sigma, rms_px, limit_px, images })
}

/// The magnification of the residual arrows: the largest residual is drawn
/// [`RESIDUAL_ARROW_FRACTION`] of the image width long (1 when there are no residuals).
pub fn residual_gain(cam: &CalibCamera, joint: bool) -> f64 {
    let max = cam
        .images
        .iter()
        .flat_map(|i| i.residual_rows(joint))
        .map(|r| r[3].hypot(r[4]))
        .fold(0.0, f64::max);
    if max > 0.0 { RESIDUAL_ARROW_FRACTION * cam.model.width as f64 / max } else { 1.0 }
}

/// Length of the largest residual arrow as a fraction of the image width: 5 % is long enough
/// to read directions and short enough that neighbouring corners' arrows rarely cross.
pub const RESIDUAL_ARROW_FRACTION: f64 = 0.05;
