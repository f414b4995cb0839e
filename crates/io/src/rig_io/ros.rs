//! ROS `camera_info` YAML (the layout of `camera_calibration_parsers`: `image_width`,
//! `image_height`, `camera_name`, `camera_matrix` K, `distortion_model` + `distortion_coefficients`
//! D, `rectification_matrix` R, `projection_matrix` P), one file per camera.
//!
//! # The pair's extrinsics
//!
//! ROS stores a stereo pair's geometry in the rectified frames: `R_i` rotates camera `i`'s
//! frame into its rectified frame and `P_i = K'_i [I | t_i]` projects points of the *first*
//! camera's rectified frame, `t_i = K'_i⁻¹ P_i[:, 3]` (`t_1 = 0`; for the second camera
//! `P[0][3] = Tx = −fx'·B`). So `X_2 = R_2ᵀ (R_1 X_1 − t_1 + t_2)`:
//! `color_from_depth = (R_2ᵀ R_1, R_2ᵀ (t_2 − t_1))`, lengths in metres (ROS uses SI units).
//!
//! Export writes a pair that gives the rig back: the rectified frame's x axis along the
//! baseline (`e1 = ±C/|C|`, `C` the colour camera's centre in the depth frame, the sign
//! keeping x pointing right), `e2 = ẑ × e1` normalised, `e3 = e1 × e2`; `R_1 = [e1 e2 e3]ᵀ`,
//! `R_2 = R_1 Rᵀ`, `K'_i = K_i` (each camera keeps its own intrinsics and size, so the images
//! are not resampled to a common rectified camera) and `t_2 = (∓|C|, 0, 0)`.
//! Distortion model `plumb_bob` (k1, k2, p1, p2, k3: OpenCV's order, as kfuse's).

use std::fmt::Write as _;
use std::path::Path;

use geometry::GeometryError;
use geometry::{CameraModel, Rig, RigidTransform};
use nalgebra::{Matrix3, Vector3};
use serde_json::json;

use super::opencv::camera_from_values;
use super::yaml::{Doc, fmt_err};
use super::{Calibration, ImportOptions, Imported, Role};

/// Below this baseline (metres) the export uses the identity rectification (no direction).
const MIN_BASELINE_M: f64 = 1e-12;
/// |P[2][3]| and |t| below this count as zero when telling a pair from two mono files.
const ZERO_TRANSLATION: f64 = 1e-12;

/// True when a YAML document looks like a ROS `camera_info` file.
pub fn is_camera_info(doc: &Doc) -> bool {
    ["distortion_model", "projection_matrix", "rectification_matrix", "camera_name"]
        .iter()
        .any(|k| doc.has(k))
}

struct Info {
    camera: CameraModel,
    rect: Matrix3<f64>,
    /// `t_i = K'⁻¹ P[:, 3]`.
    t: Vector3<f64>,
}

/// The camera a ROS `camera_name` names: kfuse's own (`depth`, `color`) and the usual driver
/// names (`ir`, `rgb`, `colour`, as a whole word of the name); `None` for anything else.
fn named_role(name: &str) -> Option<Role> {
    let words: Vec<String> =
        name.split(|c: char| !c.is_ascii_alphanumeric()).map(str::to_ascii_lowercase).collect();
    let has = |w: &[&str]| words.iter().any(|x| w.contains(&x.as_str()));
    match (has(&["depth", "ir"]), has(&["color", "colour", "rgb"])) {
        (true, false) => Some(Role::Depth),
        (false, true) => Some(Role::Color),
        _ => None,
    }
}

fn read_info(doc: &Doc, what: &str) -> Result<Info, GeometryError> {
    let w = doc.size("image_width")?;
    let h = doc.size("image_height")?;
    let (Some(w), Some(h)) = (w, h) else {
        return Err(fmt_err(doc.path(), "no 'image_width' / 'image_height'"));
    };
    // The model first: a file of another model is named as such, whatever else it lacks.
    let distortion_model = doc.string("distortion_model");
    check_model(distortion_model.as_deref(), doc.path())?;
    let k = doc.values("camera_matrix", 9)?;
    let d = doc.matrix("distortion_coefficients")?.map(|m| m.2).unwrap_or_default();
    let rect = match doc.matrix("rectification_matrix")? {
        None => None,
        Some((_, _, r)) if r.len() == 9 => Some(r),
        Some((r, c, _)) => {
            return Err(fmt_err(
                doc.path(),
                format!("'rectification_matrix' is {r}×{c}, expected 3×3"),
            ));
        }
    };
    let p = match doc.matrix("projection_matrix")? {
        None => None,
        Some((3, 4, p)) => Some(p),
        Some((r, c, _)) => {
            return Err(fmt_err(
                doc.path(),
                format!("'projection_matrix' is {r}×{c}, expected 3×4"),
            ));
        }
    };
    let fields = CameraInfoFields { width: w, height: h, distortion_model, k, d, r: rect, p };
    info_of(&fields, doc.path(), what)
}

/// The fields of one `camera_info` (a YAML file's or a `sensor_msgs/CameraInfo` message's),
/// before they are checked: `r` and `p` absent (`None`) read as the identity and `K [I | 0]`.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfoFields {
    /// Image columns.
    pub width: usize,
    /// Image rows.
    pub height: usize,
    /// `distortion_model`, if given.
    pub distortion_model: Option<String>,
    /// K, row-major (9 values).
    pub k: Vec<f64>,
    /// D.
    pub d: Vec<f64>,
    /// R, row-major (9 values).
    pub r: Option<Vec<f64>>,
    /// P, row-major (12 values).
    pub p: Option<Vec<f64>>,
}

/// The camera, rectification and `t_i` of one `camera_info`'s fields (module docs); `path`
/// and `what` are named in errors.
fn check_model(model: Option<&str>, path: &Path) -> Result<(), GeometryError> {
    if let Some(model) = model
        && !matches!(model, "plumb_bob" | "rational_polynomial")
    {
        return Err(fmt_err(
            path,
            format!(
                "distortion_model '{model}' is not supported (kfuse uses plumb_bob: k1, k2, p1, p2, k3)"
            ),
        ));
    }
    Ok(())
}

fn info_of(f: &CameraInfoFields, path: &Path, what: &str) -> Result<Info, GeometryError> {
    check_model(f.distortion_model.as_deref(), path)?;
    let camera = camera_from_values(&f.k, &f.d, (f.width, f.height), path, what)?;
    let rect = match &f.r {
        None => Matrix3::identity(),
        Some(r) if r.len() == 9 => Matrix3::from_row_slice(r),
        Some(r) => return Err(fmt_err(path, format!("R has {} values, expected 9", r.len()))),
    };
    RigidTransform::from_matrix(rect, Vector3::zeros())
        .map_err(|e| fmt_err(path, format!("{what}: rectification matrix R: {e}")))?;
    let t = match &f.p {
        None => Vector3::zeros(),
        Some(p) if p.len() == 12 => {
            let kp = Matrix3::new(p[0], p[1], p[2], p[4], p[5], p[6], p[8], p[9], p[10]);
            let inv = kp.try_inverse().ok_or_else(|| {
                fmt_err(path, format!("{what}: projection matrix P: its left 3×3 part is singular"))
            })?;
            inv * Vector3::new(p[3], p[7], p[11])
        }
        Some(p) => return Err(fmt_err(path, format!("P has {} values, expected 12", p.len()))),
    };
    Ok(Info { camera, rect, t })
}

/// The cameras of a depth and a colour `camera_info` (a bag's `sensor_msgs/CameraInfo`
/// messages; `path` and `what_*` are named in errors) and the pair's `color_from_depth` as
/// their R and P carry it (module docs), `None` when they carry none (R = I and no Tx, Ty: two
/// single cameras, whose extrinsics must come from elsewhere, a bag's `/tf_static`). The same
/// math as the YAML import.
pub fn cameras_from_infos(
    depth: &CameraInfoFields,
    color: &CameraInfoFields,
    path: &Path,
    (what_depth, what_color): (&str, &str),
) -> Result<(CameraModel, CameraModel, Option<RigidTransform>), GeometryError> {
    let a = info_of(depth, path, what_depth)?;
    let b = info_of(color, path, what_color)?;
    let cfd = pair_extrinsics(&a, &b, path)?;
    Ok((a.camera, b.camera, cfd))
}

/// `color_from_depth` of a pair (module docs); `None` when R = I and t = 0 in both.
fn pair_extrinsics(
    a: &Info,
    b: &Info,
    path: &Path,
) -> Result<Option<RigidTransform>, GeometryError> {
    let rot = b.rect.transpose() * a.rect;
    let t = b.rect.transpose() * (b.t - a.t);
    if (rot - Matrix3::identity()).abs().max() < ZERO_TRANSLATION && t.norm() < ZERO_TRANSLATION {
        return Ok(None);
    }
    RigidTransform::from_matrix(rot, t)
        .map(Some)
        .map_err(|e| fmt_err(path, format!("extrinsics: {e}")))
}

/// Imports one `camera_info` file (one camera; `opts.role` says which) or a pair
/// (depth first, colour second).
pub fn import(docs: &[Doc], opts: &ImportOptions) -> Result<Imported, GeometryError> {
    match docs {
        [one] => {
            let info = read_info(one, "camera")?;
            let role = opts.role.ok_or_else(|| {
                fmt_err(
                    one.path(),
                    "holds one camera; say which with --camera depth or --camera color, or give the depth and colour files together",
                )
            })?;
            Ok(Imported {
                calibration: Calibration::Camera {
                    camera: info.camera,
                    role: Some(role),
                    report: Some(
                        json!({"source": "ROS camera_info", "file": one.path().display().to_string()}),
                    ),
                },
                source: "ROS camera_info".into(),
                notes: vec![],
            })
        }
        [d, c] => {
            // Files that name their camera (as `kfuse rig export --format ros` and most
            // drivers do) must come depth first: in the other order the rig's cameras were
            // exchanged, exit 0.
            let role_of = |doc: &Doc| doc.string("camera_name").as_deref().and_then(named_role);
            if role_of(d) == Some(Role::Color) || role_of(c) == Some(Role::Depth) {
                return Err(fmt_err(
                    d.path(),
                    format!(
                        "names the {} camera (camera_name), but the first file must be the depth camera's: give {} {}",
                        role_of(d).map_or("other", Role::name),
                        c.path().display(),
                        d.path().display()
                    ),
                ));
            }
            let a = read_info(d, "depth camera")?;
            let b = read_info(c, "colour camera")?;
            let Some(cfd) = pair_extrinsics(&a, &b, c.path())? else {
                return Err(fmt_err(
                    c.path(),
                    "the two camera_info files carry no extrinsics (R = I and no Tx, Ty in either projection_matrix): they are two single cameras, not a calibrated pair",
                ));
            };
            let mut rig = Rig::new(a.camera, b.camera, cfd);
            rig.calibration = Some(json!({"source": "ROS camera_info pair",
                "files": [d.path().display().to_string(), c.path().display().to_string()]}));
            Ok(Imported {
                calibration: Calibration::Rig(rig),
                source: "ROS camera_info pair".into(),
                notes: vec![
                    "first file = depth camera, second = colour camera; translations in metres (ROS SI units)".into(),
                ],
            })
        }
        _ => Err(fmt_err(
            docs[0].path(),
            format!("give one camera_info file or a pair (depth, colour), not {}", docs.len()),
        )),
    }
}

fn mat_yaml(out: &mut String, name: &str, rows: usize, cols: usize, data: &[f64]) {
    // `{:?}` is Rust's shortest representation that reads back to the same f64.
    let values: Vec<String> = data.iter().map(|v| format!("{v:?}")).collect();
    let _ =
        writeln!(out, "{name}:\n  rows: {rows}\n  cols: {cols}\n  data: [{}]", values.join(", "));
}

/// One camera's `camera_info` values: the calibrated image's size, `K`, `D` (plumb_bob: k1,
/// k2, p1, p2, k3), `R` and `P`, row-major, as the YAML file and `sensor_msgs/CameraInfo`
/// hold them.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfoValues {
    /// Image columns.
    pub width: usize,
    /// Image rows.
    pub height: usize,
    /// Intrinsic matrix.
    pub k: [f64; 9],
    /// Distortion, plumb_bob.
    pub d: [f64; 5],
    /// Rectification rotation.
    pub r: [f64; 9],
    /// Projection matrix, 3 × 4: `K [I | t]`.
    pub p: [f64; 12],
}

/// The `camera_info` values of camera `c` with rectification `rect` and translation `t`
/// (module docs).
pub fn camera_info_values(
    c: &CameraModel,
    rect: &Matrix3<f64>,
    t: &Vector3<f64>,
) -> CameraInfoValues {
    let k = c.intrinsics.matrix();
    let kt = k * t;
    let row = |m: &Matrix3<f64>| std::array::from_fn(|n| m[(n / 3, n % 3)]);
    let p = std::array::from_fn(|n| {
        let (i, j) = (n / 4, n % 4);
        if j == 3 { kt[i] } else { k[(i, j)] }
    });
    CameraInfoValues {
        width: c.width,
        height: c.height,
        k: row(&k),
        d: c.distortion.to_array(),
        r: row(rect),
        p,
    }
}

/// One `camera_info` file.
pub fn camera_info_yaml(
    name: &str,
    c: &CameraModel,
    rect: &Matrix3<f64>,
    t: &Vector3<f64>,
) -> String {
    let v = camera_info_values(c, rect, t);
    let mut s = String::new();
    let _ =
        writeln!(s, "image_width: {}\nimage_height: {}\ncamera_name: {name}", v.width, v.height);
    mat_yaml(&mut s, "camera_matrix", 3, 3, &v.k);
    let _ = writeln!(s, "distortion_model: plumb_bob");
    mat_yaml(&mut s, "distortion_coefficients", 1, 5, &v.d);
    mat_yaml(&mut s, "rectification_matrix", 3, 3, &v.r);
    mat_yaml(&mut s, "projection_matrix", 3, 4, &v.p);
    s
}

/// The rectification of a rig's pair (module docs): `(R_1, R_2, t_2)`, `t_1 = 0`.
fn rig_rectification(rig: &Rig) -> (Matrix3<f64>, Matrix3<f64>, Vector3<f64>) {
    let cfd = &rig.color_from_depth;
    let r = *cfd.rotation.matrix();
    let centre = -(r.transpose() * cfd.translation);
    let b = centre.norm();
    let (r1, t2) = if b < MIN_BASELINE_M {
        (Matrix3::identity(), Vector3::zeros())
    } else {
        let sign = if centre.x < 0.0 { -1.0 } else { 1.0 };
        let e1 = centre * (sign / b);
        // A baseline along the optical axis has no ẑ × e1; any perpendicular axis will do.
        let e2 = Vector3::z().cross(&e1).try_normalize(MIN_BASELINE_M).unwrap_or(Vector3::y());
        let e3 = e1.cross(&e2);
        (
            Matrix3::from_rows(&[e1.transpose(), e2.transpose(), e3.transpose()]),
            Vector3::new(-sign * b, 0.0, 0.0),
        )
    };
    (r1, r1 * r.transpose(), t2)
}

/// The `camera_info` values of a rig's pair: `(depth, colour)` (module docs); what
/// [`rig_yaml`] writes and what a rosbag2 export publishes as `sd/` and `hd/camera_info`.
pub fn rig_camera_infos(rig: &Rig) -> (CameraInfoValues, CameraInfoValues) {
    let (r1, r2, t2) = rig_rectification(rig);
    (
        camera_info_values(&rig.depth, &r1, &Vector3::zeros()),
        camera_info_values(&rig.color, &r2, &t2),
    )
}

/// The `camera_info` pair of a rig: `(depth file text, colour file text)` (module docs).
pub fn rig_yaml(rig: &Rig) -> (String, String) {
    let (r1, r2, t2) = rig_rectification(rig);
    (
        camera_info_yaml("depth", &rig.depth, &r1, &Vector3::zeros()),
        camera_info_yaml("color", &rig.color, &r2, &t2),
    )
}

/// The poses of a rig of several cameras for ROS: one entry per camera other than the
/// reference, in tf's convention (the child camera's pose in the parent = reference frame,
/// metres and a unit quaternion x, y, z, w, the arguments of `static_transform_publisher`).
pub fn rig_static_transforms(rig: &geometry::MultiRig) -> String {
    let mut s = String::from(
        "# kfuse rig export --format ros: the cameras' poses as tf static transforms.\n# Each entry is the camera's pose in the reference camera's frame (parent), metres and a\n# unit quaternion (x, y, z, w); publish one with\n#   ros2 run tf2_ros static_transform_publisher X Y Z QX QY QZ QW PARENT CHILD\n",
    );
    let _ = writeln!(s, "reference: \"{}\"\ntransforms:", rig.reference.escape_default());
    for c in rig.cameras.iter().filter(|c| c.name != rig.reference) {
        let pose = c.camera_from_reference.inverse();
        let q = nalgebra::UnitQuaternion::from_rotation_matrix(&pose.rotation);
        let t = pose.translation;
        let _ = writeln!(
            s,
            "  - parent: \"{}\"\n    child: \"{}\"\n    translation: [{:?}, {:?}, {:?}]\n    rotation_xyzw: [{:?}, {:?}, {:?}, {:?}]",
            rig.reference.escape_default(),
            c.name.escape_default(),
            t.x,
            t.y,
            t.z,
            q.i,
            q.j,
            q.k,
            q.w
        );
    }
    s
}
