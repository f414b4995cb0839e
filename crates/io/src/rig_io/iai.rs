//! iai_kinect2's calibration (`kinect2_calibration` writes it, `kinect2_bridge` reads it from
//! `kinect2_bridge/data/<serial>/`): four OpenCV FileStorage YAML files in one folder.
//!
//! | file | keys | meaning |
//! | --- | --- | --- |
//! | `calib_color.yaml` | `cameraMatrix` 3×3, `distortionCoefficients` 1×5 (1×8 with `rational`), `rotation` 3×3 = I, `projection` 4×4 = [K 0; 0 1] | the colour camera |
//! | `calib_ir.yaml` | the same | the IR (= depth) camera |
//! | `calib_pose.yaml` | `rotation` 3×3, `translation` 3×1, `essential`, `fundamental` | `cv::stereoCalibrate(…, pointsIr, pointsColor, …)`: `X_color = R·X_ir + T`, metres (the board size is given in metres: `chess5x7x0.03`) |
//! | `calib_depth.yaml` | `depthShift` (a number) | millimetres added to every depth value (optional: `kinect2_bridge` uses 0 without it) |
//!
//! Facts from the public iai_kinect2 source (code-iai/iai_kinect2 at 0e2c5f6):
//! `kinect2_definitions.h` (file and key names), `kinect2_calibration.cpp`
//! (`storeCalibration`, `calibrateExtrinsics`, `DepthCalibration::compareDists`) and
//! `kinect2_bridge.cpp` (`initCalibration`, `loadCalibration*File`, the depth shift's use).
//!
//! * **No image sizes** are stored: `kinect2_bridge` hard-codes the Kinect v2's 1920×1080
//!   colour and 512×424 IR images, and so does this importer (or `--color-size`,
//!   `--depth-size`), saying so.
//! * **Orientation**: `kinect2_bridge` flips libfreenect2's images left–right before
//!   publishing them (`cv::flip(…, 1)`), so iai's calibration is of unmirrored images, with
//!   the colour camera at about +52 mm of the IR camera (as the Kinect SDK and MATLAB). It is
//!   imported as it is.
//! * **`depthShift`, sign**: `kinect2_calibration` stores `depthShift = 1000 · mean(z_board −
//!   z_measured)` (the board plane's z from the IR pose minus the measured z, metres → mm), and
//!   `kinect2_bridge` publishes `depth_mm + depthShift` (`depth.convertTo(…, CV_16U, 1,
//!   depthShift)`). kfuse's model is `z_measured = z_true + offset`
//!   ([`geometry::depth_correction`]), so `offset_m = −depthShift / 1000`.
//! * Only `cameraMatrix` and `distortionCoefficients` of a camera file are read, as
//!   `kinect2_bridge` does; `rotation` and `projection` are written on export (identity and
//!   `[K 0; 0 1]`, as `kinect2_calibration` writes them). A pose file's `essential` is checked
//!   against `[T]×·R` when present (a file edited by hand, or mixed from two calibrations).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use geometry::GeometryError;
use geometry::depth_correction::{DepthCorrection, DepthTerm, DepthTermKind};
use geometry::num_fmt::{fixed, num};
use geometry::{CameraModel, Rig, RigidTransform};
use nalgebra::{Matrix3, Vector3};
use serde_json::json;

use super::opencv::camera_from;
use super::show::{KINECT_COLOR_SIZE, KINECT_DEPTH_SIZE};
use super::yaml::{Doc, fmt_err};
use super::{Calibration, ImportOptions, Imported, Role};

/// The colour camera's file (`K2_CALIB_COLOR`).
pub const COLOR_FILE: &str = "calib_color.yaml";
/// The IR (depth) camera's file (`K2_CALIB_IR`).
pub const IR_FILE: &str = "calib_ir.yaml";
/// The IR → colour pose (`K2_CALIB_POSE`).
pub const POSE_FILE: &str = "calib_pose.yaml";
/// The depth shift (`K2_CALIB_DEPTH`).
pub const DEPTH_FILE: &str = "calib_depth.yaml";
/// The four files in the order `kinect2_calibration`'s README lists them for copying.
pub const FILES: [&str; 4] = [COLOR_FILE, DEPTH_FILE, IR_FILE, POSE_FILE];

/// Largest `max |E − [T]×·R|` accepted in `calib_pose.yaml`, relative to `|T|`: 1e-6.
/// OpenCV computes `E = [T]×·R` in double precision and writes 17 digits, so a file of one
/// calibration agrees to ~1e-15; a hand-edited T or R leaves a difference of its edit's size.
const ESSENTIAL_TOLERANCE: f64 = 1e-6;
/// Smallest |F[2][2]| by which OpenCV normalises the fundamental matrix (its
/// `stereoCalibrate` divides by F(2,2) when it is above DBL_EPSILON); below it F is written
/// unnormalised.
const FUNDAMENTAL_NORM_MIN: f64 = f64::EPSILON;

/// What one YAML document of iai's calibration is, from its keys.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Camera,
    Pose,
    Depth,
}

/// What a file of an iai calibration is: a pose needs only `rotation` and `translation`
/// (all `kinect2_bridge` reads of it).
fn kind_of(doc: &Doc) -> Option<Kind> {
    if doc.has("cameraMatrix") {
        Some(Kind::Camera)
    } else if doc.has("rotation") && doc.has("translation") {
        Some(Kind::Pose)
    } else if doc.has("depthShift") {
        Some(Kind::Depth)
    } else {
        None
    }
}

/// True when `doc` is one of iai_kinect2's calibration files, by keys no other format this
/// importer reads has: `cameraMatrix` with `distortionCoefficients` or `projection`;
/// `rotation`, `translation` with `essential` or `fundamental`; `depthShift`.
pub fn is_iai(doc: &Doc) -> bool {
    (doc.has("cameraMatrix") && (doc.has("distortionCoefficients") || doc.has("projection")))
        || (doc.has("rotation")
            && doc.has("translation")
            && (doc.has("essential") || doc.has("fundamental")))
        || doc.has("depthShift")
}

/// True when `dir` holds any of iai's four files.
pub fn is_iai_dir(dir: &Path) -> bool {
    FILES.iter().any(|f| dir.join(f).is_file())
}

/// Imports iai's calibration folder: `calib_color.yaml`, `calib_ir.yaml`, `calib_pose.yaml`
/// (required) and `calib_depth.yaml` (optional).
pub fn import_dir(dir: &Path, opts: &ImportOptions) -> Result<Imported, GeometryError> {
    let mut docs = Vec::new();
    for name in [COLOR_FILE, IR_FILE, POSE_FILE] {
        let p = dir.join(name);
        if !p.is_file() {
            return Err(fmt_err(
                &p,
                format!(
                    "not found; iai_kinect2's calibration folder holds {COLOR_FILE}, {IR_FILE}, {POSE_FILE} (and optionally {DEPTH_FILE}): copy {name} from kinect2_calibration's folder into {}",
                    dir.display()
                ),
            ));
        }
        docs.push(Doc::read(&p)?);
    }
    let depth = dir.join(DEPTH_FILE);
    if depth.is_file() {
        docs.push(Doc::read(&depth)?);
    }
    import_docs(docs, opts)
}

fn file_name(doc: &Doc) -> String {
    doc.path().file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
}

/// A camera file's camera at `size`.
fn read_camera(doc: &Doc, size: (usize, usize), what: &str) -> Result<CameraModel, GeometryError> {
    let k = doc.values("cameraMatrix", 9)?;
    let Some((_, _, d)) = doc.matrix("distortionCoefficients")? else {
        return Err(fmt_err(
            doc.path(),
            "no 'distortionCoefficients' (kinect2_calibration writes them beside cameraMatrix; a camera without them would be taken as distortion-free)",
        ));
    };
    camera_from(&k, &d, size, doc, what)
}

/// Which camera each of the (one or two) camera files is: by iai's file name when it has one,
/// else (two files) the larger focal length is the colour camera (Kinect v2: ~1060 px against
/// ~365 px). A file named as one camera holding the other's focal length is refused.
fn camera_roles(cams: &[&Doc], opts: &ImportOptions) -> Result<Vec<Role>, GeometryError> {
    let named = |d: &Doc| match file_name(d).as_str() {
        COLOR_FILE => Some(Role::Color),
        IR_FILE => Some(Role::Depth),
        _ => None,
    };
    let fx = |d: &Doc| d.values("cameraMatrix", 9).map(|k| k[0]);
    match cams {
        [one] => {
            let role = opts.role.or(named(one)).ok_or_else(|| {
                fmt_err(
                    one.path(),
                    format!(
                        "is one iai_kinect2 camera file; say which camera with --camera depth or --camera color, or give the folder (or {COLOR_FILE}, {IR_FILE} and {POSE_FILE} together)"
                    ),
                )
            })?;
            Ok(vec![role])
        }
        [a, b] => {
            let (fa, fb) = (fx(a)?, fx(b)?);
            let by_focal =
                if fa > fb { [Role::Color, Role::Depth] } else { [Role::Depth, Role::Color] };
            let roles = match (named(a), named(b)) {
                (Some(ra), Some(rb)) if ra != rb => [ra, rb],
                _ => by_focal,
            };
            for (doc, f) in [(a, fa), (b, fb)] {
                if !(geometry::rig::MIN_FOCAL_PX..=geometry::rig::MAX_FOCAL_PX).contains(&f) {
                    return Err(fmt_err(
                        doc.path(),
                        format!(
                            "its fx {} px is no camera's (plausible: {}-{} px; the Kinect v2's colour camera has ~1060 px, its IR camera ~365 px): correct the file",
                            geometry::num_fmt::fixed(f, 1),
                            geometry::rig::MIN_FOCAL_PX,
                            geometry::rig::MAX_FOCAL_PX
                        ),
                    ));
                }
            }
            for (doc, role, f, other) in [(a, roles[0], fa, fb), (b, roles[1], fb, fa)] {
                let expected_larger = role == Role::Color;
                if (f > other) != expected_larger {
                    return Err(fmt_err(
                        doc.path(),
                        format!(
                            "is named as the {} camera's file but its fx {f:.1} px is {} the other camera's {other:.1} px (the Kinect v2's colour camera has ~1060 px, its IR camera ~365 px): are {COLOR_FILE} and {IR_FILE} exchanged?",
                            if role == Role::Color { "colour" } else { "IR" },
                            if expected_larger { "below" } else { "above" }
                        ),
                    ));
                }
            }
            Ok(roles.to_vec())
        }
        _ => Err(fmt_err(
            cams[0].path(),
            format!(
                "{} camera files given; iai_kinect2 has two ({COLOR_FILE}, {IR_FILE})",
                cams.len()
            ),
        )),
    }
}

/// The principal point must lie inside the image the camera is taken at: a colour camera's
/// matrix at the IR camera's 512×424 (or the reverse) would otherwise import silently.
fn check_inside(camera: &CameraModel, doc: &Doc, role: Role) -> Result<(), GeometryError> {
    let k = &camera.intrinsics;
    if !(0.0..camera.width as f64).contains(&k.cx) || !(0.0..camera.height as f64).contains(&k.cy) {
        return Err(fmt_err(
            doc.path(),
            format!(
                "as the {} camera at {}x{} its principal point ({:.1}, {:.1}) px lies outside the image: is it the other camera's file, or of another image size (pass --{}-size WxH)?",
                if role == Role::Color { "colour" } else { "IR" },
                camera.width,
                camera.height,
                k.cx,
                k.cy,
                if role == Role::Color { "color" } else { "depth" }
            ),
        ));
    }
    Ok(())
}

fn cross_matrix(t: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0)
}

fn read_pose(doc: &Doc) -> Result<RigidTransform, GeometryError> {
    let r = Matrix3::from_row_slice(&doc.values("rotation", 9)?);
    let t = doc.values("translation", 3)?;
    let t = Vector3::new(t[0], t[1], t[2]);
    if let Some((_, _, e)) = doc.matrix("essential")? {
        if e.len() != 9 {
            return Err(fmt_err(
                doc.path(),
                format!("'essential' has {} values, expected 9", e.len()),
            ));
        }
        let diff = (Matrix3::from_row_slice(&e) - cross_matrix(&t) * r).abs().max();
        if diff > ESSENTIAL_TOLERANCE * t.norm().max(f64::MIN_POSITIVE) {
            return Err(fmt_err(
                doc.path(),
                format!(
                    "'essential' is not [T]×·R of its 'rotation' and 'translation' (differs by {}): the file was edited or mixes two calibrations; run kinect2_calibration's 'calibrate sync' again",
                    geometry::num_fmt::num(diff)
                ),
            ));
        }
    }
    RigidTransform::from_matrix(r, t)
        .map_err(|e| fmt_err(doc.path(), format!("'rotation', 'translation': {e}")))
}

/// `calib_depth.yaml`'s `depthShift` (mm) as kfuse's depth correction of a `(w, h)` depth
/// camera (module docs: `offset_m = −depthShift / 1000`); `None` for a shift of 0.
fn read_depth(doc: &Doc, (w, h): (usize, usize)) -> Result<Option<DepthCorrection>, GeometryError> {
    let shift_mm =
        doc.number("depthShift")?.ok_or_else(|| fmt_err(doc.path(), "no 'depthShift'"))?;
    if shift_mm == 0.0 {
        return Ok(None);
    }
    let c = DepthCorrection {
        width: w,
        height: h,
        terms: vec![DepthTerm { kind: DepthTermKind::Offset, value: -shift_mm * 1e-3, std: 0.0 }],
        fit: Some(json!({
            "source": "iai_kinect2 calib_depth.yaml",
            "file": doc.path().display().to_string(),
            "depthShift_mm": shift_mm,
            "note": "kinect2_bridge publishes depth_mm + depthShift: offset = -depthShift / 1000 m",
        })),
    };
    c.validate().map_err(|e| {
        fmt_err(
            doc.path(),
            format!("'depthShift' {} mm: {e}; depthShift is in millimetres", num(shift_mm)),
        )
    })?;
    Ok(Some(c))
}

/// Imports iai's files given one by one (any order; recognised by their keys): the colour and
/// IR camera files and the pose give a rig, a depth file adds the depth correction; one camera
/// file alone gives a single camera.
pub fn import_docs(docs: Vec<Doc>, opts: &ImportOptions) -> Result<Imported, GeometryError> {
    let (mut cams, mut pose, mut depth) = (Vec::new(), None, None);
    for doc in &docs {
        match kind_of(doc) {
            Some(Kind::Camera) => cams.push(doc),
            Some(k) => {
                let slot = if k == Kind::Pose { &mut pose } else { &mut depth };
                if let Some(first) = slot.replace(doc) {
                    return Err(fmt_err(
                        doc.path(),
                        format!(
                            "is a second {} file (the first is {}); give one calibration's files",
                            if k == Kind::Pose { POSE_FILE } else { DEPTH_FILE },
                            first.path().display()
                        ),
                    ));
                }
            }
            None => {
                return Err(fmt_err(
                    doc.path(),
                    format!(
                        "is not one of iai_kinect2's calibration files ({COLOR_FILE}, {IR_FILE}: cameraMatrix, distortionCoefficients; {POSE_FILE}: rotation, translation, essential; {DEPTH_FILE}: depthShift)"
                    ),
                ));
            }
        }
    }
    if cams.is_empty() {
        return Err(fmt_err(
            docs[0].path(),
            format!("no camera file among the files given; add {COLOR_FILE} and {IR_FILE}"),
        ));
    }
    let roles = camera_roles(&cams, opts)?;
    let size_of = |role: Role| match role {
        Role::Color => opts.color_size.unwrap_or(KINECT_COLOR_SIZE),
        Role::Depth => opts.depth_size.unwrap_or(KINECT_DEPTH_SIZE),
    };
    let files: Vec<String> = docs.iter().map(|d| d.path().display().to_string()).collect();
    let size_note = |role: Role| {
        let (w, h) = size_of(role);
        let given = match role {
            Role::Color => opts.color_size.is_some(),
            Role::Depth => opts.depth_size.is_some(),
        };
        let (name, flag) =
            if role == Role::Color { ("colour", "--color-size") } else { ("IR", "--depth-size") };
        if given {
            format!("{name} camera {w}x{h} ({flag})")
        } else {
            format!(
                "{name} camera {w}x{h}: iai_kinect2's files store no image size, the Kinect v2's (kinect2_bridge's) is used"
            )
        }
    };
    let mut cameras = Vec::new();
    for (doc, &role) in cams.iter().zip(&roles) {
        let what = if role == Role::Color { "colour camera" } else { "IR camera" };
        let camera = read_camera(doc, size_of(role), what)?;
        check_inside(&camera, doc, role)?;
        cameras.push((role, camera));
    }
    if let [(role, camera)] = cameras[..] {
        if let Some(p) = pose.or(depth) {
            return Err(fmt_err(
                p.path(),
                format!(
                    "needs both cameras; add the other camera's file ({})",
                    if role == Role::Color { IR_FILE } else { COLOR_FILE }
                ),
            ));
        }
        return Ok(Imported {
            calibration: Calibration::Camera {
                camera,
                role: Some(role),
                report: Some(json!({"source": "iai_kinect2", "files": files})),
            },
            source: "iai_kinect2 camera file".into(),
            notes: vec![size_note(role)],
        });
    }
    let camera = |r: Role| cameras.iter().find(|c| c.0 == r).map(|c| c.1);
    let (Some(ir), Some(color)) = (camera(Role::Depth), camera(Role::Color)) else {
        return Err(fmt_err(cams[1].path(), "two files of the same camera"));
    };
    let Some(pose) = pose else {
        return Err(fmt_err(
            cams[0].path(),
            format!(
                "the cameras' pose is missing: add {POSE_FILE} (rotation, translation; kinect2_calibration's 'calibrate sync' writes it)"
            ),
        ));
    };
    let mut rig = Rig::new(ir, color, read_pose(pose)?);
    let mut notes = vec![
        "calib_pose.yaml: X_color = R·X_ir + T, T in metres (cv::stereoCalibrate of IR then colour points; the board size is in metres)".to_string(),
        size_note(Role::Depth),
        size_note(Role::Color),
    ];
    match depth {
        None => notes.push(format!(
            "no {DEPTH_FILE}: no depth correction (kinect2_bridge uses depthShift 0 then)"
        )),
        Some(d) => {
            let c = read_depth(d, (ir.width, ir.height))?;
            notes.push(match &c {
                Some(c) => format!(
                    "{DEPTH_FILE}: depthShift {} mm (added to the depth) = a depth offset of {} mm (z_measured = z_true + offset)",
                    geometry::num_fmt::num(-c.value(DepthTermKind::Offset) * 1e3),
                    geometry::num_fmt::num(c.value(DepthTermKind::Offset) * 1e3)
                ),
                None => format!("{DEPTH_FILE}: depthShift 0 mm: no depth correction"),
            });
            rig.depth_correction = c.map(Box::new);
        }
    }
    rig.calibration = Some(json!({"source": "iai_kinect2 (kinect2_calibration)", "files": files}));
    Ok(Imported {
        calibration: Calibration::Rig(rig),
        source: "iai_kinect2 calibration".into(),
        notes,
    })
}

/// Options of [`export`].
#[derive(Debug, Clone, Copy, Default)]
pub struct ExportOptions {
    /// Write only the offset of a depth correction that has other terms too (scale, spatial),
    /// which `depthShift` cannot hold; without it such a rig is refused.
    pub depth_offset_only: bool,
}

fn matrix_rows(m: &Matrix3<f64>) -> Vec<f64> {
    (0..3).flat_map(|i| (0..3).map(move |j| m[(i, j)])).collect()
}

fn camera_text(c: &CameraModel) -> String {
    let k = c.intrinsics.matrix();
    let mut s = String::from("%YAML:1.0\n---\n");
    super::opencv::yaml_matrix(&mut s, "cameraMatrix", 3, 3, &matrix_rows(&k));
    super::opencv::yaml_matrix(&mut s, "distortionCoefficients", 1, 5, &c.distortion.to_array());
    super::opencv::yaml_matrix(&mut s, "rotation", 3, 3, &matrix_rows(&Matrix3::identity()));
    let mut p = [0.0; 16];
    for i in 0..3 {
        for j in 0..3 {
            p[4 * i + j] = k[(i, j)];
        }
    }
    p[15] = 1.0;
    super::opencv::yaml_matrix(&mut s, "projection", 4, 4, &p);
    s
}

/// iai's four files of `rig`, `(file name, text)` in [`FILES`]' order: the cameras as they
/// are (iai stores no image size: a rig of other sizes is refused), the pose with OpenCV's
/// `essential = [T]×·R` and `fundamental = K_colorᵀ⁻¹·E·K_ir⁻¹` normalised to F[2][2] = 1, and
/// `depthShift = −1000 · offset` (0 without a depth correction). A depth correction with
/// other terms than the offset is refused, naming them, unless `opts.depth_offset_only`.
pub fn export(
    rig: &Rig,
    opts: ExportOptions,
    source: &Path,
) -> Result<Vec<(&'static str, String)>, GeometryError> {
    let sizes = ((rig.depth.width, rig.depth.height), (rig.color.width, rig.color.height));
    if sizes != (KINECT_DEPTH_SIZE, KINECT_COLOR_SIZE) {
        return Err(fmt_err(
            source,
            format!(
                "the cameras are {}x{} (depth) and {}x{} (colour); iai_kinect2's files store no image size and kinect2_bridge assumes the Kinect v2's 512x424 and 1920x1080",
                sizes.0.0, sizes.0.1, sizes.1.0, sizes.1.1
            ),
        ));
    }
    // kinect2_bridge publishes the images as the scene is: a rig of mirrored images would be
    // written with its colour camera on the wrong side (104 mm off) without a word.
    if let Some((true, _)) = super::show::kinect_orientation(rig) {
        return Err(fmt_err(
            source,
            format!(
                "is a rig of images mirrored left-right (its colour camera at x = {} mm of the IR camera; kinect2_bridge's images put it at about +52 mm): convert it first with `kfuse rig import {} --mirror --out RIG.json`, then export RIG.json",
                fixed(rig.color_centre_in_depth().x * 1000.0, 1),
                source.display()
            ),
        ));
    }
    if rig.rectified {
        return Err(fmt_err(
            source,
            "is a rig of undistorted images (rectified); kinect2_bridge undistorts the sensor's raw images itself: export the rig of the raw images",
        ));
    }
    let shift_mm = match rig.depth_correction.as_deref() {
        None => 0.0,
        Some(c) => {
            let others: Vec<&str> = c
                .terms
                .iter()
                .filter(|t| t.kind != DepthTermKind::Offset && t.value != 0.0)
                .map(|t| t.kind.name())
                .collect();
            if !others.is_empty() && !opts.depth_offset_only {
                return Err(fmt_err(
                    source,
                    format!(
                        "its depth correction has terms ({}) besides the offset, which {DEPTH_FILE}'s depthShift (one offset in mm) cannot hold; pass --depth-offset-only to write the offset alone (kinect2_bridge then corrects only the offset)",
                        others.join(", ")
                    ),
                ));
            }
            -c.value(DepthTermKind::Offset) * 1e3
        }
    };
    let cfd = &rig.color_from_depth;
    let r = *cfd.rotation.matrix();
    let t = cfd.translation;
    let e = cross_matrix(&t) * r;
    let inv = |c: &CameraModel| {
        c.intrinsics
            .matrix()
            .try_inverse()
            .ok_or_else(|| fmt_err(source, "a camera matrix is singular (zero focal length?)"))
    };
    let mut f = inv(&rig.color)?.transpose() * e * inv(&rig.depth)?;
    if f[(2, 2)].abs() > FUNDAMENTAL_NORM_MIN {
        f /= f[(2, 2)];
    }
    let mut pose = String::from("%YAML:1.0\n---\n");
    super::opencv::yaml_matrix(&mut pose, "rotation", 3, 3, &matrix_rows(&r));
    super::opencv::yaml_matrix(&mut pose, "translation", 3, 1, &[t.x, t.y, t.z]);
    super::opencv::yaml_matrix(&mut pose, "essential", 3, 3, &matrix_rows(&e));
    super::opencv::yaml_matrix(&mut pose, "fundamental", 3, 3, &matrix_rows(&f));
    let mut depth = String::from("%YAML:1.0\n---\n");
    let _ = writeln!(depth, "depthShift: {shift_mm:.17e}");
    Ok(vec![
        (COLOR_FILE, camera_text(&rig.color)),
        (DEPTH_FILE, depth),
        (IR_FILE, camera_text(&rig.depth)),
        (POSE_FILE, pose),
    ])
}

/// The paths [`export`]'s files get in `dir`.
pub fn export_paths(dir: &Path) -> Vec<PathBuf> {
    FILES.iter().map(|f| dir.join(f)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    // A hand-written calibration folder in the layout of kinect2_calibration's files (OpenCV
    // 2.4's FileStorage: `%YAML:1.0` without `---`, `0.` for zero, lists wrapped over lines).
    // Its own numbers, asserted after import.
    const IR: &str = "%YAML:1.0\ncameraMatrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 3.6512340000000000e+02, 0., 2.5731250000000000e+02, 0.,\n       3.6498760000000000e+02, 2.0615620000000000e+02, 0., 0., 1. ]\ndistortionCoefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [ 9.1234000000000000e-02, -2.7012300000000000e-01,\n       1.2300000000000000e-04, -4.5600000000000000e-04,\n       9.8760000000000000e-02 ]\nrotation: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]\nprojection: !!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: d\n   data: [ 3.6512340000000000e+02, 0., 2.5731250000000000e+02, 0., 0.,\n       3.6498760000000000e+02, 2.0615620000000000e+02, 0., 0., 0., 1.,\n       0., 0., 0., 0., 1. ]\n";
    const COLOR: &str = "%YAML:1.0\ncameraMatrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1.0581230000000000e+03, 0., 9.5412300000000000e+02, 0.,\n       1.0574560000000000e+03, 5.3187600000000000e+02, 0., 0., 1. ]\ndistortionCoefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [ 4.5600000000000000e-02, -6.1230000000000000e-02,\n       1.1100000000000000e-03, -1.4400000000000000e-03,\n       2.0100000000000000e-02 ]\nrotation: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]\nprojection: !!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: d\n   data: [ 1.0581230000000000e+03, 0., 9.5412300000000000e+02, 0., 0.,\n       1.0574560000000000e+03, 5.3187600000000000e+02, 0., 0., 0., 1.,\n       0., 0., 0., 0., 1. ]\n";
    // R: 0.01 rad about y; T = (-52.1, 0.3, 1.2) mm; essential = [T]×·R (computed in double
    // precision when the file was written).
    const POSE: &str = "%YAML:1.0\nrotation: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 9.9995000041666526e-01, 0., 9.9998333341666645e-03, 0., 1., 0.,\n       -9.9998333341666645e-03, 0., 9.9995000041666526e-01 ]\ntranslation: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ -5.2100000000000000e-02, 3.0000000000000000e-04,\n       1.2000000000000000e-03 ]\nessential: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ -2.9999500002499992e-06, -1.1999999999999999e-03,\n       2.9998500012499957e-04, 6.7894868378991506e-04, 0.,\n       5.2109394821709260e-02, -2.9998500012499957e-04,\n       -5.2100000000000000e-02, -2.9999500002499992e-06 ]\nfundamental: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1.2e-08, 3.1e-06, -1.1e-03, -1.8e-06, 0., 5.3e-02,\n       4.4e-04, -5.0e-02, 1. ]\n";
    const DEPTH: &str = "%YAML:1.0\ndepthShift: -1.3250000000000000e+01\n";

    fn folder(files: &[(&str, &str)]) -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        for (name, text) in files {
            std::fs::write(dir.path().join(name), text).unwrap();
        }
        dir
    }

    fn all() -> Vec<(&'static str, &'static str)> {
        vec![(COLOR_FILE, COLOR), (IR_FILE, IR), (POSE_FILE, POSE), (DEPTH_FILE, DEPTH)]
    }

    fn rig_of(i: Imported) -> Rig {
        match i.calibration {
            Calibration::Rig(r) => r,
            c => panic!("not a rig: {c:?}"),
        }
    }

    /// The numbers written in the files come back: intrinsics and T exactly (decimal text →
    /// f64 once), R to 1e-15 (re-orthonormalised), the Kinect's image sizes, and
    /// depthShift −13.25 mm (added to the depth) as an offset of +13.25 mm.
    #[test]
    fn hand_written_iai_folder_imports_with_its_numbers() {
        let dir = folder(&all());
        let imported = import_dir(dir.path(), &ImportOptions::default()).unwrap();
        let notes = imported.notes.join("\n");
        assert!(notes.contains("store no image size"), "{notes}");
        let rig = rig_of(imported);
        let (d, c) = (&rig.depth, &rig.color);
        assert_eq!((d.width, d.height, c.width, c.height), (512, 424, 1920, 1080));
        assert_eq!(
            [d.intrinsics.fx, d.intrinsics.fy, d.intrinsics.cx, d.intrinsics.cy],
            [365.1234, 364.9876, 257.3125, 206.1562]
        );
        assert_eq!(d.distortion.to_array(), [0.091234, -0.270123, 0.000123, -0.000456, 0.09876]);
        assert_eq!(
            [c.intrinsics.fx, c.intrinsics.fy, c.intrinsics.cx, c.intrinsics.cy],
            [1058.123, 1057.456, 954.123, 531.876]
        );
        assert_eq!(c.distortion.to_array(), [0.0456, -0.06123, 0.00111, -0.00144, 0.0201]);
        assert_eq!(rig.color_from_depth.translation, Vector3::new(-0.0521, 0.0003, 0.0012));
        let r = rig.color_from_depth.rotation.matrix();
        let (cos, sin) = (0.01f64.cos(), 0.01f64.sin());
        let want = Matrix3::new(cos, 0.0, sin, 0.0, 1.0, 0.0, -sin, 0.0, cos);
        assert!((r - want).abs().max() < 1e-15, "{r}");
        let dc = rig.depth_correction.as_deref().expect("calib_depth.yaml gives a correction");
        assert_eq!((dc.width, dc.height), (512, 424));
        assert!((dc.value(DepthTermKind::Offset) - 0.01325).abs() < 1e-15);
        assert_eq!(dc.terms.len(), 1);
        // A measured 1.01325 m is 1 m true: kinect2_bridge's depth + depthShift.
        assert!((dc.correct(100.0, 100.0, 1.01325) - 1.0).abs() < 1e-12);
        // +52 mm = the rule (unmirrored images, as kinect2_bridge publishes them).
        assert!(rig.color_centre_in_depth().x > 0.05, "{}", rig.color_centre_in_depth());
    }

    /// The files given one by one, in any order, are the folder; one camera file alone is a
    /// single camera (a pose beside it asks for the other camera's file); the folder without
    /// calib_depth.yaml has no depth correction and says so.
    #[test]
    fn files_in_any_order_and_the_optional_depth_file() {
        let dir = folder(&all());
        let p = |n: &str| dir.path().join(n);
        let from_dir = rig_of(import_dir(dir.path(), &ImportOptions::default()).unwrap());
        let docs = [POSE_FILE, DEPTH_FILE, COLOR_FILE, IR_FILE].map(|n| Doc::read(&p(n)).unwrap());
        let from_files = rig_of(import_docs(docs.to_vec(), &ImportOptions::default()).unwrap());
        assert_eq!(from_dir.depth, from_files.depth);
        assert_eq!(from_dir.color, from_files.color);
        assert_eq!(from_dir.depth_correction, from_files.depth_correction);
        // One camera file alone is that camera (by iai's name, or --camera), at its Kinect size.
        let one = import_docs(vec![Doc::read(&p(IR_FILE)).unwrap()], &ImportOptions::default());
        match one.unwrap().calibration {
            Calibration::Camera { camera, role, .. } => {
                assert_eq!(role, Some(Role::Depth));
                assert_eq!(
                    (camera.width, camera.height, camera.intrinsics.fx),
                    (512, 424, 365.1234)
                );
            }
            c => panic!("not one camera: {c:?}"),
        }
        let with_pose = vec![Doc::read(&p(COLOR_FILE)).unwrap(), Doc::read(&p(POSE_FILE)).unwrap()];
        let e = import_docs(with_pose, &ImportOptions::default()).unwrap_err().to_string();
        assert!(e.contains(POSE_FILE) && e.contains(IR_FILE), "{e}");
        std::fs::remove_file(p(DEPTH_FILE)).unwrap();
        let i = import_dir(dir.path(), &ImportOptions::default()).unwrap();
        assert!(i.notes.iter().any(|n| n.contains("no calib_depth.yaml")), "{:?}", i.notes);
        assert!(rig_of(i).depth_correction.is_none());
    }

    /// A required file missing: one line naming it. The colour and IR files exchanged, and a
    /// pose whose essential matrix is not [T]×·R: refused naming the file.
    #[test]
    fn missing_exchanged_and_inconsistent_files_are_refused() {
        for missing in [COLOR_FILE, IR_FILE, POSE_FILE] {
            let files: Vec<_> = all().into_iter().filter(|(n, _)| *n != missing).collect();
            let dir = folder(&files);
            let e = import_dir(dir.path(), &ImportOptions::default()).unwrap_err().to_string();
            let want = format!("{}: not found", dir.path().join(missing).display());
            assert!(e.starts_with(&want) && !e.contains('\n'), "{e}");
        }
        let dir = folder(&[(COLOR_FILE, IR), (IR_FILE, COLOR), (POSE_FILE, POSE)]);
        let e = import_dir(dir.path(), &ImportOptions::default()).unwrap_err().to_string();
        assert!(e.contains(COLOR_FILE) && e.contains("exchanged"), "{e}");
        // T's x edited from -52.1 to -51.1 mm, essential left as it was: 1 mm off.
        let edited = POSE.replace("-5.2100000000000000e-02, 3.0", "-5.1100000000000000e-02, 3.0");
        let dir = folder(&[(COLOR_FILE, COLOR), (IR_FILE, IR), (POSE_FILE, &edited)]);
        let e = import_dir(dir.path(), &ImportOptions::default()).unwrap_err().to_string();
        assert!(e.contains(POSE_FILE) && e.contains("'essential' is not [T]×·R"), "{e}");
        // A camera file without its distortion (was read as distortion-free).
        // An implausible focal length is named as such, in short notation (it was called two
        // files exchanged, with a 300-digit number).
        let huge = IR.replacen("3.6512340000000000e+02", "3.6e+302", 1);
        let dir = folder(&[(COLOR_FILE, COLOR), (IR_FILE, &huge), (POSE_FILE, POSE)]);
        let e = import_dir(dir.path(), &ImportOptions::default()).unwrap_err().to_string();
        assert!(
            e.contains(IR_FILE) && e.contains("no camera's") && !e.contains("exchanged"),
            "{e}"
        );
        assert!(e.len() < 400, "{e}");
        let no_dist = IR.replace("distortionCoefficients:", "distortion:");
        let dir = folder(&[(COLOR_FILE, COLOR), (IR_FILE, &no_dist), (POSE_FILE, POSE)]);
        let e = import_dir(dir.path(), &ImportOptions::default()).unwrap_err().to_string();
        assert!(e.contains(IR_FILE) && e.contains("no 'distortionCoefficients'"), "{e}");
        // depthShift in metres by mistake would still be within range; in micrometres it is not.
        let dir = folder(&[
            (COLOR_FILE, COLOR),
            (IR_FILE, IR),
            (POSE_FILE, POSE),
            (DEPTH_FILE, "%YAML:1.0\ndepthShift: -13250.\n"),
        ]);
        let e = import_dir(dir.path(), &ImportOptions::default()).unwrap_err().to_string();
        assert!(e.contains(DEPTH_FILE) && e.contains("millimetres"), "{e}");
    }

    /// export → import gives the rig back: every camera parameter and T to 1e-12 (17
    /// significant digits written), R to 1e-12, the offset to 1e-15; the essential matrix
    /// written passes the import's check and the fundamental matrix satisfies x_cᵀ·F·x_ir = 0
    /// for a point seen by both cameras (1e-9, normalised F).
    #[test]
    fn export_then_import_gives_the_rig_back() {
        let mut rig = geometry::synth::kinect_rig();
        rig.depth_correction = Some(Box::new(DepthCorrection {
            width: 512,
            height: 424,
            terms: vec![DepthTerm { kind: DepthTermKind::Offset, value: -0.0187, std: 0.0 }],
            fit: None,
        }));
        let files = export(&rig, ExportOptions::default(), Path::new("rig.json")).unwrap();
        let dir = folder(&files.iter().map(|(n, t)| (*n, t.as_str())).collect::<Vec<_>>());
        let depth_text = std::fs::read_to_string(dir.path().join(DEPTH_FILE)).unwrap();
        assert!(depth_text.contains("depthShift: 1.87"), "{depth_text}");
        let back = rig_of(import_dir(dir.path(), &ImportOptions::default()).unwrap());
        let values = |c: &CameraModel| {
            let k = c.intrinsics;
            let mut v = vec![k.fx, k.fy, k.cx, k.cy, k.skew];
            v.extend(c.distortion.to_array());
            v
        };
        for (a, b) in [(&rig.depth, &back.depth), (&rig.color, &back.color)] {
            assert_eq!((a.width, a.height), (b.width, b.height));
            for (x, y) in values(a).iter().zip(values(b)) {
                assert!((x - y).abs() < 1e-12, "{x} {y}");
            }
        }
        let dr = (rig.color_from_depth.rotation.matrix() - back.color_from_depth.rotation.matrix())
            .abs()
            .max();
        let dt = (rig.color_from_depth.translation - back.color_from_depth.translation).abs().max();
        assert!(dr < 1e-12 && dt < 1e-12, "{dr} {dt}");
        let off = back.depth_correction.as_deref().unwrap().value(DepthTermKind::Offset);
        assert!((off + 0.0187).abs() < 1e-15, "{off}");
        // The fundamental matrix: a point 1.5 m away, projected (without distortion) into
        // both cameras, satisfies the epipolar constraint.
        let pose = Doc::read(&dir.path().join(POSE_FILE)).unwrap();
        let f = Matrix3::from_row_slice(&pose.values("fundamental", 9).unwrap());
        let p = Vector3::new(0.1, -0.05, 1.5);
        let pc = rig.color_from_depth.apply(&p);
        let xi = rig.depth.intrinsics.matrix() * (p / p.z);
        let xc = rig.color.intrinsics.matrix() * (pc / pc.z);
        assert!((xc.transpose() * f * xi)[0].abs() < 1e-9, "{}", (xc.transpose() * f * xi)[0]);
        assert!((f[(2, 2)] - 1.0).abs() < 1e-15);
    }

    /// A depth correction beyond an offset: refused naming its terms; with
    /// `depth_offset_only` the offset alone is written. Other image sizes are refused.
    #[test]
    fn export_refuses_what_iai_cannot_hold() {
        let mut rig = geometry::synth::kinect_rig();
        let t = |kind, value| DepthTerm { kind, value, std: 0.0 };
        rig.depth_correction = Some(Box::new(DepthCorrection {
            width: 512,
            height: 424,
            terms: vec![
                t(DepthTermKind::Offset, 0.024),
                t(DepthTermKind::Scale, 0.004),
                t(DepthTermKind::Radial2, 0.0),
            ],
            fit: None,
        }));
        let e = export(&rig, ExportOptions::default(), Path::new("r.json")).unwrap_err();
        let e = e.to_string();
        assert!(
            e.contains("r.json") && e.contains("(scale)") && e.contains("--depth-offset-only"),
            "{e}"
        );
        let files =
            export(&rig, ExportOptions { depth_offset_only: true }, Path::new("r.json")).unwrap();
        let depth = &files.iter().find(|f| f.0 == DEPTH_FILE).unwrap().1;
        let doc = Doc::parse(depth, Path::new(DEPTH_FILE)).unwrap();
        assert!((doc.number("depthShift").unwrap().unwrap() + 24.0).abs() < 1e-12);
        let mut small = rig.clone();
        small.depth_correction = None;
        small.depth.width = 640;
        let e = export(&small, ExportOptions::default(), Path::new("r.json")).unwrap_err();
        assert!(e.to_string().contains("640x424"), "{e}");
    }
}
