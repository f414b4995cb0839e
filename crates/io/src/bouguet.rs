//! Import of Bouguet's Camera Calibration Toolbox results (`Calib_Results_left.mat`,
//! `_right.mat`, `_stereo.mat`).
//!
//! Bouguet's pixel coordinates are 0-based with integer pixel centres (its default principal
//! point is `((nx−1)/2, (ny−1)/2)`), the same as ours, so corners and `cc` are taken as they
//! are. `alpha_c` is a skew *ratio* (skew in pixels = `alpha_c · fc(1)`); `kc` is in OpenCV's
//! order `k1, k2, p1, p2, k3`; translations are in the board's unit (mm here) and converted
//! to metres; its `*_error` values are 3σ and are divided by 3.

use std::path::Path;

use crate::mat::MatFile;
use geometry::{CameraModel, Distortion, Intrinsics, Rig, RigidTransform};
use nalgebra::{Matrix3, Vector2, Vector3};

use geometry::GeometryError;

/// Bouguet's board unit: the lab's files use millimetres (`dX = 40`).
const MM: f64 = 1e-3;
/// Most images of one Bouguet calibration read (`n_ima`): 10 000. The toolbox's users
/// calibrate with tens of images (the lab's: 12); each image is looked up by name, so a
/// corrupt `n_ima = 1e18` would loop for ever.
pub const MAX_BOUGUET_IMAGES: usize = 10_000;

/// A whole-number count variable of `m`, in `1..=max` (image sides, the image count): NaN,
/// fractions, zero and huge values are refused naming the variable.
fn count(m: &MatFile, name: &str, max: usize, what: &str) -> Result<usize, GeometryError> {
    let v = m.scalar(name)?;
    if !((1.0..=max as f64).contains(&v) && v.fract() == 0.0) {
        return Err(fmt(
            m.path(),
            format!(
                "'{name}' ({what}) is {}, expected a whole number in 1..={max}",
                geometry::num_fmt::num(v)
            ),
        ));
    }
    Ok(v as usize)
}

/// One camera's Bouguet result.
#[derive(Debug, Clone)]
pub struct BouguetCamera {
    /// The camera (`fc`, `cc`, `alpha_c`, `kc`, `nx × ny`).
    pub camera: CameraModel,
    /// 1σ of the intrinsics (Bouguet's `*_error` / 3) in the order `fx, fy, cx, cy, skew,
    /// k1, k2, p1, p2, k3` (`calib::IntrinsicsStd::from_array`'s); Bouguet states no skew
    /// error, so that one is 0.
    pub std: [f64; 10],
    /// Per image (1-based MATLAB index `i` at position `i − 1`): the extracted corners `x_i`
    /// in Bouguet's order (corner `k` at position `k`), pixels; `None` for inactive images.
    /// `calib::bouguet` labels them as board corners for the calibration's comparisons.
    pub views: Vec<Option<Vec<Vector2<f64>>>>,
    /// Per image: Bouguet's board points `X_i` (metres), parallel to `views`.
    pub board_points: Vec<Option<Vec<Vector3<f64>>>>,
    /// Bouguet's `camera_from_board` per image (`omc_i`, `Tc_i` in metres).
    pub poses: Vec<Option<RigidTransform>>,
    /// Bouguet's pixel error std `err_std` (x, y), px.
    pub err_std_px: Option<Vector2<f64>>,
}

fn fmt(path: &Path, message: String) -> GeometryError {
    GeometryError::Format { path: path.to_path_buf(), message }
}

fn vec_of(m: &MatFile, name: &str, n: usize) -> Result<Vec<f64>, GeometryError> {
    let mm = m.matrix(name)?;
    if mm.data.len() != n {
        return Err(fmt(m.path(), format!("'{name}' has {} values, expected {n}", mm.data.len())));
    }
    Ok(mm.data)
}

fn camera_from(
    m: &MatFile,
    suffix: &str,
    width: usize,
    height: usize,
) -> Result<(CameraModel, [f64; 10]), GeometryError> {
    let fc = vec_of(m, &format!("fc{suffix}"), 2)?;
    let cc = vec_of(m, &format!("cc{suffix}"), 2)?;
    let kc = vec_of(m, &format!("kc{suffix}"), 5)?;
    let alpha = m.scalar(&format!("alpha_c{suffix}")).unwrap_or(0.0);
    let mut k = Intrinsics::new(fc[0], fc[1], cc[0], cc[1]);
    k.skew = alpha * fc[0];
    let cam = CameraModel::new(
        width,
        height,
        k,
        Distortion::from_array([kc[0], kc[1], kc[2], kc[3], kc[4]]),
    );
    cam.validate().map_err(|e| fmt(m.path(), e.to_string()))?;
    let e = |name: &str, n: usize| vec_of(m, &format!("{name}{suffix}_error"), n).ok();
    let fe = e("fc", 2).unwrap_or(vec![0.0; 2]);
    let ce = e("cc", 2).unwrap_or(vec![0.0; 2]);
    let ke = e("kc", 5).unwrap_or(vec![0.0; 5]);
    let std = [
        fe[0] / 3.0,
        fe[1] / 3.0,
        ce[0] / 3.0,
        ce[1] / 3.0,
        0.0,
        ke[0] / 3.0,
        ke[1] / 3.0,
        ke[2] / 3.0,
        ke[3] / 3.0,
        ke[4] / 3.0,
    ];
    Ok((cam, std))
}

/// Reads a mono result (`Calib_Results_left.mat`, `Calib_Results_right.mat`, or a plain
/// `Calib_Results.mat`).
pub fn import_mono(path: &Path) -> Result<BouguetCamera, GeometryError> {
    let m = MatFile::read(path)?;
    if m.get("nx").is_none() {
        return Err(fmt(
            path,
            "no 'nx': not a Bouguet Calib_Results file (save it with the toolbox's 'Save')".into(),
        ));
    }
    let side = geometry::rig::MAX_IMAGE_SIDE;
    let nx = count(&m, "nx", side, "the image width in pixels")?;
    let ny = count(&m, "ny", side, "the image height in pixels")?;
    let (camera, std) = camera_from(&m, "", nx, ny)?;
    let n_ima = count(&m, "n_ima", MAX_BOUGUET_IMAGES, "the number of images")?;
    let active = m.matrix("active_images").map(|a| a.data).unwrap_or_else(|_| vec![1.0; n_ima]);
    let mut views = Vec::with_capacity(n_ima);
    let mut board_points = Vec::with_capacity(n_ima);
    let mut poses = Vec::with_capacity(n_ima);
    for i in 1..=n_ima {
        let on = active.get(i - 1).copied().unwrap_or(0.0) != 0.0;
        let x = m
            .matrix(&format!("x_{i}"))
            .ok()
            .filter(|x| on && x.rows == 2 && x.cols >= 4 && x.data.iter().all(|v| v.is_finite()));
        let big_x = m.matrix(&format!("X_{i}")).ok().filter(|x| x.rows == 3);
        match (x, big_x) {
            (Some(x), Some(bx)) if bx.cols == x.cols => {
                views.push(Some(
                    (0..x.cols).map(|c| Vector2::new(x.at(0, c), x.at(1, c))).collect(),
                ));
                board_points.push(Some(
                    (0..bx.cols)
                        .map(|c| Vector3::new(bx.at(0, c), bx.at(1, c), bx.at(2, c)) * MM)
                        .collect(),
                ));
            }
            _ => {
                views.push(None);
                board_points.push(None);
            }
        }
        let pose = (|| {
            let om = vec_of(&m, &format!("omc_{i}"), 3).ok()?;
            let t = vec_of(&m, &format!("Tc_{i}"), 3).ok()?;
            (on && om.iter().chain(&t).all(|v| v.is_finite())).then(|| {
                RigidTransform::from_axis_angle(
                    Vector3::new(om[0], om[1], om[2]),
                    Vector3::new(t[0], t[1], t[2]) * MM,
                )
            })
        })();
        poses.push(pose);
    }
    let err_std_px = m
        .matrix("err_std")
        .ok()
        .filter(|e| e.data.len() == 2)
        .map(|e| Vector2::new(e.data[0], e.data[1]));
    Ok(BouguetCamera { camera, std, views, board_points, poses, err_std_px })
}

/// Largest relative difference between a mono result's focal length and the stereo file's
/// for the same camera. Bouguet's stereo refinement moves each focal length by hundredths of a
/// percent (kinect-lab: IR fc 364.13 px alone, 364.21 px in the stereo file; colour 1062.33 →
/// 1062.45 px); the Kinect's two cameras differ by a factor of three, so 10 % tells them apart
/// with margin either way.
const MONO_STEREO_FOCAL_TOLERANCE: f64 = 0.1;

/// Reads a stereo result into a rig: left = depth/IR camera, right = colour camera,
/// `color_from_depth` = Bouguet's `R, T` (`X_right = R·X_left + T`, mm → m), with the stereo
/// file's re-optimised intrinsics. Image sizes come from the mono files (the stereo file
/// stores only one `nx, ny`).
pub fn import_stereo(stereo: &Path, left: &Path, right: &Path) -> Result<Rig, GeometryError> {
    let l = import_mono(left)?;
    let r = import_mono(right)?;
    let m = MatFile::read(stereo)?;
    let (depth, _) = camera_from(&m, "_left", l.camera.width, l.camera.height)?;
    let (color, _) = camera_from(&m, "_right", r.camera.width, r.camera.height)?;
    // The mono files give only the image sizes: check that each is the camera it is given as
    // (a swapped or repeated file gave a rig with the Kinect's two sizes exchanged, exit 0).
    let off = |mono: &CameraModel, stereo: &CameraModel| {
        (mono.intrinsics.fx - stereo.intrinsics.fx).abs() / stereo.intrinsics.fx.abs().max(1e-9)
    };
    for (file, mono, side, stereo, other) in
        [(left, &l.camera, "left", &depth, &color), (right, &r.camera, "right", &color, &depth)]
    {
        if off(mono, stereo) > MONO_STEREO_FOCAL_TOLERANCE {
            let hint = if off(mono, other) <= MONO_STEREO_FOCAL_TOLERANCE {
                "it is the other camera's result: give them in the order stereo.mat left.mat right.mat"
            } else {
                "it is not a result of this stereo calibration's cameras"
            };
            return Err(fmt(
                file,
                format!(
                    "given as the {side} camera, but its fc {:.1} px is not the stereo file's fc_{side} {:.1} px: {hint}",
                    mono.intrinsics.fx, stereo.intrinsics.fx
                ),
            ));
        }
    }
    let rm = m.matrix_of_size("R", 3, 3)?;
    let t = vec_of(&m, "T", 3)?;
    let rot = Matrix3::from_row_slice(&rm.data);
    let color_from_depth = RigidTransform::from_matrix(rot, Vector3::new(t[0], t[1], t[2]) * MM)
        .map_err(|e| fmt(stereo, format!("'R', 'T': {e}")))?;
    let mut rig = Rig::new(depth, color, color_from_depth);
    rig.calibration = Some(serde_json::json!({
        "source": "Bouguet Camera Calibration Toolbox",
        "files": [stereo.display().to_string(), left.display().to_string(), right.display().to_string()],
        "sigma_x_px": m.scalar("sigma_x").ok(),
    }));
    Ok(rig)
}
