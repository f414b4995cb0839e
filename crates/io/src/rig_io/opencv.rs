//! OpenCV FileStorage YAML → rig or camera. Export uses [`opencv_yaml_rig`] and
//! [`opencv_yaml_camera`] (the files `kfuse calibrate --opencv-yaml` writes).
//!
//! Names accepted (OpenCV has no fixed schema; these are the ones its samples and
//! `stereoCalibrate` users write):
//!
//! * camera 1 = depth/IR, camera 2 = colour: `M1`/`K1`/`cameraMatrix1`/`camera_matrix_1`,
//!   `D1`/`distCoeffs1`/`dist_coeffs_1`, likewise with `2`; `R`, `T` with `X_2 = R·X_1 + T`;
//!   image sizes `image_width_1`, `image_height_1`, `image_width_2`, `image_height_2`, or
//!   `--depth-size`/`--color-size`.
//! * one camera: `camera_matrix`/`cameraMatrix`/`K`, `distortion_coefficients`/`distCoeffs`/`D`,
//!   `image_width`, `image_height`.
//!
//! `T` is in whatever unit the board's square size was given in: `T_units: m` or `mm` in the
//! file (kfuse writes it) or `--t-units` says which; without either the import stops and asks.
//! Distortion vectors of 4, 5, 8, 12 or 14 coefficients are read in OpenCV's order; the
//! coefficients beyond `k3` (rational, thin-prism, tilt) must be zero, since kfuse's model has
//! five.

use std::fmt::Write as _;

use geometry::GeometryError;
use geometry::num_fmt::{fixed, num};
use geometry::{CameraModel, Distortion, Intrinsics, Rig, RigidTransform};
use nalgebra::{Matrix3, Vector3};
use serde_json::json;

use super::yaml::{Doc, fmt_err};
use super::{Calibration, ImportOptions, Imported, LengthUnit};

const K1_NAMES: &[&str] = &["M1", "K1", "cameraMatrix1", "camera_matrix_1", "cameraMatrixL"];
const D1_NAMES: &[&str] = &["D1", "distCoeffs1", "dist_coeffs_1", "distCoeffsL"];
const K2_NAMES: &[&str] = &["M2", "K2", "cameraMatrix2", "camera_matrix_2", "cameraMatrixR"];
const D2_NAMES: &[&str] = &["D2", "distCoeffs2", "dist_coeffs_2", "distCoeffsR"];
const K_NAMES: &[&str] = &["camera_matrix", "cameraMatrix", "K"];
const D_NAMES: &[&str] = &["distortion_coefficients", "distCoeffs", "D"];
/// Largest |K[2][0..2]| and |K[2][2] − 1| accepted in a camera matrix (files store ~17
/// digits; anything larger means the matrix is not a camera matrix).
const K_ROW_TOLERANCE: f64 = 1e-9;

/// Values of a file for a message, each as [`geometry::num_fmt::num`] writes it.
fn nums(v: &[f64]) -> String {
    v.iter().map(|&x| num(x)).collect::<Vec<_>>().join(", ")
}

/// A camera from a row-major 3×3 `K`, a distortion vector and a size.
pub fn camera_from(
    k: &[f64],
    d: &[f64],
    size: (usize, usize),
    doc: &Doc,
    what: &str,
) -> Result<CameraModel, GeometryError> {
    camera_from_values(k, d, size, doc.path(), what)
}

/// [`camera_from`] of values that come from `path` (a file that is no YAML document: a bag).
pub fn camera_from_values(
    k: &[f64],
    d: &[f64],
    (w, h): (usize, usize),
    path: &std::path::Path,
    what: &str,
) -> Result<CameraModel, GeometryError> {
    let err = |m: String| fmt_err(path, format!("{what}: {m}"));
    if k.len() != 9 {
        return Err(err(format!("camera matrix has {} values, expected 9", k.len())));
    }
    if k[3].abs() > K_ROW_TOLERANCE
        || k[6].abs() > K_ROW_TOLERANCE
        || k[7].abs() > K_ROW_TOLERANCE
        || (k[8] - 1.0).abs() > K_ROW_TOLERANCE
    {
        return Err(err(format!(
            "not a camera matrix (expected [fx s cx; 0 fy cy; 0 0 1], got [{}])",
            nums(k)
        )));
    }
    let mut c = [0.0; 5];
    match d.len() {
        0 => {}
        4 | 5 => c[..d.len()].copy_from_slice(d),
        8 | 12 | 14 if d[5..].iter().all(|&v| v == 0.0) => c.copy_from_slice(&d[..5]),
        8 | 12 | 14 => {
            return Err(err(format!(
                "distortion coefficients beyond k3 are not zero ({}): the rational / thin-prism / tilted models are not supported, recalibrate with OpenCV's 5-coefficient model",
                nums(&d[5..])
            )));
        }
        n => return Err(err(format!("{n} distortion coefficients, expected 4, 5, 8, 12 or 14"))),
    }
    let mut intr = Intrinsics::new(k[0], k[4], k[2], k[5]);
    intr.skew = k[1];
    let cam = CameraModel::new(w, h, intr, Distortion::from_array(c));
    cam.validate().map_err(|e| err(e.to_string()))?;
    Ok(cam)
}

fn matrix_of(doc: &Doc, names: &[&str]) -> Result<Option<(String, Vec<f64>)>, GeometryError> {
    for n in names {
        if let Some((_, _, d)) = doc.matrix(n)? {
            return Ok(Some((n.to_string(), d)));
        }
    }
    Ok(None)
}

fn size_of(
    doc: &Doc,
    w: &str,
    h: &str,
    given: Option<(usize, usize)>,
    flag: &str,
) -> Result<(usize, usize), GeometryError> {
    match (doc.size(w)?, doc.size(h)?, given) {
        (_, _, Some(s)) => Ok(s),
        (Some(w), Some(h), None) => Ok((w, h)),
        _ => Err(fmt_err(
            doc.path(),
            format!(
                "no image size ('{w}', '{h}'); pass {flag} WxH (e.g. 512x424 for the Kinect's depth camera, 1920x1080 for its colour camera)"
            ),
        )),
    }
}

/// Imports OpenCV YAML (one file, or several of one calibration merged).
pub fn import(docs: Vec<Doc>, opts: &ImportOptions) -> Result<Imported, GeometryError> {
    let mut docs = docs.into_iter();
    let Some(mut doc) = docs.next() else {
        return Err(GeometryError::InvalidInput("no OpenCV file given".into()));
    };
    let files: Vec<String> = std::iter::once(doc.path().display().to_string()).collect();
    let mut files = files;
    for other in docs {
        files.push(other.path().display().to_string());
        doc.merge(other)?;
    }
    if let Some((kname, k1)) = matrix_of(&doc, K1_NAMES)? {
        let Some((_, k2)) = matrix_of(&doc, K2_NAMES)? else {
            return Err(fmt_err(
                doc.path(),
                format!("has '{kname}' but no second camera matrix (M2, K2, cameraMatrix2)"),
            ));
        };
        let d1 = matrix_of(&doc, D1_NAMES)?.map(|d| d.1).unwrap_or_default();
        let d2 = matrix_of(&doc, D2_NAMES)?.map(|d| d.1).unwrap_or_default();
        let s1 = size_of(&doc, "image_width_1", "image_height_1", opts.depth_size, "--depth-size")?;
        let s2 = size_of(&doc, "image_width_2", "image_height_2", opts.color_size, "--color-size")?;
        let depth = camera_from(&k1, &d1, s1, &doc, "camera 1 (depth)")?;
        let color = camera_from(&k2, &d2, s2, &doc, "camera 2 (colour)")?;
        if !(doc.has("R") && doc.has("T")) {
            return Err(fmt_err(
                doc.path(),
                "has both cameras but no 'R' and 'T' (stereoCalibrate's extrinsics); add the extrinsics file (e.g. extrinsics.yml) after it",
            ));
        }
        let r = doc.values("R", 9).or_else(|_| doc.values("R", 3).map(rodrigues_to_matrix))?;
        let t = doc.values("T", 3)?;
        let (unit, unit_note) = t_unit(&doc, &t, opts)?;
        let s = unit.to_metres();
        let cfd = RigidTransform::from_matrix(
            Matrix3::from_row_slice(&r),
            Vector3::new(t[0] * s, t[1] * s, t[2] * s),
        )
        .map_err(|e| fmt_err(doc.path(), format!("'R', 'T': {e}")))?;
        let mut rig = Rig::new(depth, color, cfd);
        rig.calibration = Some(json!({"source": "OpenCV FileStorage YAML", "files": files}));
        return Ok(Imported {
            calibration: Calibration::Rig(rig),
            source: "OpenCV stereo calibration (YAML)".into(),
            notes: vec![
                "camera 1 = depth/IR, camera 2 = colour, X_2 = R·X_1 + T".into(),
                unit_note,
            ],
        });
    }
    if let Some((_, k)) = matrix_of(&doc, K_NAMES)? {
        let d = matrix_of(&doc, D_NAMES)?.map(|d| d.1).unwrap_or_default();
        let role = opts.role.ok_or_else(|| {
            fmt_err(doc.path(), "holds one camera; say which with --camera depth or --camera color")
        })?;
        let given = if role == super::Role::Depth { opts.depth_size } else { opts.color_size };
        let flag = if role == super::Role::Depth { "--depth-size" } else { "--color-size" };
        let size = size_of(&doc, "image_width", "image_height", given, flag)?;
        let camera = camera_from(&k, &d, size, &doc, "camera")?;
        return Ok(Imported {
            calibration: Calibration::Camera {
                camera,
                role: Some(role),
                report: Some(json!({"source": "OpenCV FileStorage YAML", "files": files})),
            },
            source: "OpenCV single-camera calibration (YAML)".into(),
            notes: vec![],
        });
    }
    Err(fmt_err(
        doc.path(),
        "no camera matrix found (expected M1/M2/R/T as stereoCalibrate writes, or camera_matrix/distortion_coefficients)",
    ))
}

fn rodrigues_to_matrix(r: Vec<f64>) -> Vec<f64> {
    let m = nalgebra::Rotation3::new(Vector3::new(r[0], r[1], r[2]));
    (0..3).flat_map(|i| (0..3).map(move |j| m[(i, j)])).collect()
}

fn t_unit(
    doc: &Doc,
    t: &[f64],
    opts: &ImportOptions,
) -> Result<(LengthUnit, String), GeometryError> {
    let norm = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
    if let Some(u) = doc.string("T_units") {
        let unit = LengthUnit::parse(&u).ok_or_else(|| {
            fmt_err(doc.path(), format!("'T_units' is '{u}', expected 'm' or 'mm'"))
        })?;
        if let Some(flag) = opts.t_units
            && flag != unit
        {
            return Err(fmt_err(
                doc.path(),
                format!("the file says T is in '{u}', --t-units says otherwise; drop --t-units"),
            ));
        }
        return Ok((unit, format!("T in {u} (the file's T_units)")));
    }
    match opts.t_units {
        Some(u) => Ok((
            u,
            format!("T in {} (--t-units)", if u == LengthUnit::Metres { "m" } else { "mm" }),
        )),
        None => Err(fmt_err(
            doc.path(),
            format!(
                "T = ({}, {}, {}) has no unit (OpenCV's T is in the unit of the board's square size; |T| = {}); pass --t-units mm or --t-units m",
                fixed(t[0], 6),
                fixed(t[1], 6),
                fixed(t[2], 6),
                fixed(norm, 4)
            ),
        )),
    }
}

/// One matrix in OpenCV FileStorage's `!!opencv-matrix` form (`rows`, `cols`, `dt: d`, `data`).
pub fn yaml_matrix(out: &mut String, name: &str, rows: usize, cols: usize, data: &[f64]) {
    let values: Vec<String> = data.iter().map(|v| format!("{v:.17e}")).collect();
    let _ = writeln!(
        out,
        "{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {} ]",
        values.join(", ")
    );
}

fn k_of(c: &CameraModel) -> [f64; 9] {
    let k = c.intrinsics;
    [k.fx, k.skew, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0]
}

/// OpenCV FileStorage YAML of one camera (`cv::FileStorage` reads it: `camera_matrix`,
/// `distortion_coefficients`, `image_width`, `image_height`).
pub fn opencv_yaml_camera(c: &CameraModel) -> String {
    let mut s = String::from("%YAML:1.0\n---\n");
    let _ = writeln!(s, "image_width: {}\nimage_height: {}", c.width, c.height);
    yaml_matrix(&mut s, "camera_matrix", 3, 3, &k_of(c));
    yaml_matrix(&mut s, "distortion_coefficients", 1, 5, &c.distortion.to_array());
    s
}

/// OpenCV FileStorage YAML of a rig in `stereoCalibrate`'s naming: camera 1 = depth/IR
/// (`M1`, `D1`), camera 2 = colour (`M2`, `D2`), `R`, `T` with `X_2 = R·X_1 + T`. `T` is in
/// metres (`T_units: m`); multiply by 1000 for a board measured in millimetres.
pub fn opencv_yaml_rig(rig: &Rig) -> String {
    let mut s = String::from("%YAML:1.0\n---\n");
    let _ = writeln!(s, "image_width_1: {}\nimage_height_1: {}", rig.depth.width, rig.depth.height);
    let _ = writeln!(s, "image_width_2: {}\nimage_height_2: {}", rig.color.width, rig.color.height);
    yaml_matrix(&mut s, "M1", 3, 3, &k_of(&rig.depth));
    yaml_matrix(&mut s, "D1", 1, 5, &rig.depth.distortion.to_array());
    yaml_matrix(&mut s, "M2", 3, 3, &k_of(&rig.color));
    yaml_matrix(&mut s, "D2", 1, 5, &rig.color.distortion.to_array());
    let cfd: &RigidTransform = &rig.color_from_depth;
    let r = cfd.rotation.matrix();
    let rd: Vec<f64> = (0..3).flat_map(|i| (0..3).map(move |j| r[(i, j)])).collect();
    yaml_matrix(&mut s, "R", 3, 3, &rd);
    yaml_matrix(&mut s, "T", 3, 1, &[cfd.translation.x, cfd.translation.y, cfd.translation.z]);
    let _ = writeln!(s, "T_units: m");
    s
}

/// OpenCV FileStorage YAML of one camera of a rig of several cameras: [`opencv_yaml_camera`]'s
/// keys, then its pose `R`, `T` (`X_camera = R·X_reference + T`, metres, `T_units: m`) and the
/// reference camera's name (`reference`), so that `cv::FileStorage` reads every camera of the
/// rig into one frame.
pub fn opencv_yaml_rig_camera(c: &geometry::RigCamera, reference: &str) -> String {
    let mut s = opencv_yaml_camera(&c.model);
    let _ = writeln!(s, "camera_name: \"{}\"\nreference: \"{reference}\"", c.name.escape_default());
    let pose = &c.camera_from_reference;
    let r = pose.rotation.matrix();
    let rd: Vec<f64> = (0..3).flat_map(|i| (0..3).map(move |j| r[(i, j)])).collect();
    yaml_matrix(&mut s, "R", 3, 3, &rd);
    yaml_matrix(&mut s, "T", 3, 1, &[pose.translation.x, pose.translation.y, pose.translation.z]);
    let _ = writeln!(s, "T_units: m");
    s
}
