//! The lab's `KinectData.mat`: what `Calibrate.m` and the capture script save.
//!
//! | variable | holds | here |
//! | --- | --- | --- |
//! | `Dparam`, `Cparam` | structs with Bouguet's `fx`, `fy`, `cx`, `cy` (pixels, 0-based) of the depth and colour camera | [`CameraModel`]s without distortion |
//! | `R`, `T` | Bouguet's stereo extrinsics, `X_color = R·X_depth + T`, `T` in millimetres | `color_from_depth`, metres |
//! | `Image` | the colour image, H×W×3 uint8 (or float 0..1) | 8-bit RGB |
//! | `Depth` | the depth frame, H×W, millimetres along the optical axis (z), 0 = no sample | metres, `NaN` = none ([`KinectDepth::Millimetres`]) |
//!
//! The file stores no distortion: the lab rectifies the images before saving them. A `Depth`
//! of class uint8 / int8 / logical is a picture of depth (the copy in
//! `../shared/data/kinect-lab` holds such a one, 97 % zeros), not measurements: it is
//! reported as [`KinectDepth::Unusable`] with that reason, and the rig and the colour image
//! are still read (for `kfuse rig import`, or `kfuse fuse --mat … --depth`).

use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use crate::course::color_image;
use crate::mat::{MatFile, NumericData, column_to_row_major};
use geometry::{CameraModel, Distortion, GeometryError, Image, Intrinsics, Rig, RigidTransform};

/// Kinect v2 depth image size, used for the depth camera when the file's `Depth` is unusable
/// (then its size says nothing).
pub const KINECT_DEPTH_SIZE: (usize, usize) = (512, 424);

/// Metres per unit of the file's `Depth` (the Kinect's millimetres).
pub const DEPTH_M_PER_UNIT: f64 = 1e-3;

/// The file's `Depth`.
#[derive(Debug, Clone)]
pub enum KinectDepth {
    /// Real depth: z in metres (converted from the file's millimetres), `NaN` = no sample.
    Millimetres(Image<f32>),
    /// Not depth measurements; the reason names the variable, its class and what it holds.
    Unusable(String),
}

/// The content of `KinectData.mat`: the lab's rig, its rectified colour image and its depth.
#[derive(Debug, Clone)]
pub struct KinectLabData {
    /// Depth camera (the size of a usable `Depth`, else 512×424) and colour camera (the size
    /// of `Image`), no distortion, metres.
    pub rig: Rig,
    /// The rectified colour image.
    pub color: Image<[u8; 3]>,
    /// The depth frame, or why it cannot be used.
    pub depth: KinectDepth,
}

/// True when a parsed `.mat` file looks like `KinectData.mat` (`Dparam` with `fx` and no
/// `fp`), not like the course's `synthdata.mat` (`Dparam` with `fp`, the focal length in
/// pixels, beside `f` in metres and sometimes `fx`).
pub fn is_kinect_data(file: &MatFile) -> bool {
    let dparam = file.get("Dparam");
    dparam.and_then(|d| d.field("fx")).is_some() && dparam.and_then(|d| d.field("fp")).is_none()
}

/// Reads `KinectData.mat` (see the module docs).
pub fn read_kinect_data(path: &Path) -> Result<KinectLabData, GeometryError> {
    kinect_data_from_mat(&MatFile::read(path)?)
}

/// [`read_kinect_data`] on a parsed file.
pub fn kinect_data_from_mat(file: &MatFile) -> Result<KinectLabData, GeometryError> {
    let color = color_image(file, "Image")?;
    let depth = depth_of(file)?;
    let depth_size = match &depth {
        KinectDepth::Millimetres(d) => d.size(),
        KinectDepth::Unusable(_) => KINECT_DEPTH_SIZE,
    };
    let camera = |name: &str, (w, h): (usize, usize)| -> Result<CameraModel, GeometryError> {
        let k = Intrinsics::new(
            file.scalar(&format!("{name}.fx"))?,
            file.scalar(&format!("{name}.fy"))?,
            file.scalar(&format!("{name}.cx"))?,
            file.scalar(&format!("{name}.cy"))?,
        );
        let cam = CameraModel::new(w, h, k, Distortion::NONE);
        cam.validate().map_err(|e| file.error(format!("'{name}': {e}")))?;
        Ok(cam)
    };
    let depth_cam = camera("Dparam", depth_size)?;
    let color_cam = camera("Cparam", color.size())?;
    let r = file.matrix_of_size("R", 3, 3)?;
    let t = file.matrix("T")?;
    if t.data.len() != 3 {
        return Err(file.error(format!("variable 'T' is {}×{}, expected 3×1", t.rows, t.cols)));
    }
    // Bouguet's stereo T is in millimetres.
    let t = Vector3::from_column_slice(&t.data) * 1e-3;
    let color_from_depth = RigidTransform::from_matrix(Matrix3::from_row_slice(&r.data), t)
        .map_err(|e| file.error(format!("'R', 'T': {e}")))?;
    Ok(KinectLabData { rig: Rig::new(depth_cam, color_cam, color_from_depth), color, depth })
}

/// The file's `Depth`: an H×W real array of millimetres (uint16 as the capture saves it;
/// other integer and float classes wider than 8 bits are read the same way).
fn depth_of(file: &MatFile) -> Result<KinectDepth, GeometryError> {
    let arr = file.numeric("Depth")?;
    let dims = arr.dims.iter().map(|d| d.to_string()).collect::<Vec<_>>().join("×");
    if arr.dims.len() != 2 || arr.is_complex() || arr.is_empty() {
        return Err(file.error(format!(
            "variable 'Depth' must be a real H×W matrix of millimetres, it is {dims} {}",
            arr.class().name()
        )));
    }
    if let NumericData::UInt8(_) | NumericData::Int8(_) | NumericData::Logical(_) = arr.real {
        let values = arr.real.to_f64();
        let zeros = values.iter().filter(|&&v| v == 0.0).count();
        return Ok(KinectDepth::Unusable(format!(
            "its 'Depth' is {dims} {} ({:.0} % zeros): an 8-bit picture of depth, not millimetres; \
             Kinect depth needs 16 bits (uint16, mm)",
            arr.class().name(),
            100.0 * zeros as f64 / values.len().max(1) as f64
        )));
    }
    let (h, w) = (arr.dims[0], arr.dims[1]);
    let mm = column_to_row_major(&arr.real.to_f64(), &arr.dims);
    let metres = mm
        .into_iter()
        .map(|v| {
            let m = (v * DEPTH_M_PER_UNIT) as f32;
            if m.is_finite() && m > 0.0 { m } else { f32::NAN }
        })
        .collect();
    let depth = Image::from_vec(w, h, metres)?;
    if depth.data().iter().all(|d| d.is_nan()) {
        return Ok(KinectDepth::Unusable(format!(
            "its 'Depth' ({dims} {}) has no valid (positive) sample",
            arr.class().name()
        )));
    }
    Ok(KinectDepth::Millimetres(depth))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mat::{MatValue, NumericArray, row_to_column_major, write_mat};

    fn lab_file(depth: MatValue) -> Vec<(&'static str, MatValue)> {
        let cam = |fx, cx, cy| {
            MatValue::structure(vec![
                ("fx", MatValue::scalar(fx)),
                ("fy", MatValue::scalar(fx + 1.0)),
                ("cx", MatValue::scalar(cx)),
                ("cy", MatValue::scalar(cy)),
            ])
        };
        let image = MatValue::Numeric(NumericArray {
            dims: vec![3, 4, 3],
            real: NumericData::UInt8((0..36).collect()),
            imag: None,
        });
        vec![
            ("Depth", depth),
            ("Image", image),
            ("Dparam", cam(365.0, 1.5, 1.0)),
            ("Cparam", cam(1060.0, 1.5, 1.0)),
            ("R", MatValue::double_matrix(3, 3, &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])),
            ("T", MatValue::double_matrix(3, 1, &[-52.0, 0.5, 1.0])),
        ]
    }

    #[test]
    fn uint16_depth_is_read_as_millimetres_and_uint8_refused() {
        let dir = tempfile::tempdir().unwrap();
        // 2×3 depth, row-major: 1000 1500 0 / 2000 65535 7.
        let row_major: [u16; 6] = [1000, 1500, 0, 2000, 65535, 7];
        let depth = MatValue::Numeric(NumericArray {
            dims: vec![2, 3],
            real: NumericData::UInt16(row_to_column_major(&row_major, &[2, 3])),
            imag: None,
        });
        let path = dir.path().join("KinectData.mat");
        write_mat(&path, &lab_file(depth)).unwrap();
        let kd = read_kinect_data(&path).unwrap();
        let KinectDepth::Millimetres(d) = &kd.depth else { panic!("{:?}", kd.depth) };
        assert_eq!(d.size(), (3, 2));
        assert_eq!((kd.rig.depth.width, kd.rig.depth.height), (3, 2));
        assert_eq!((kd.rig.color.width, kd.rig.color.height), (4, 3));
        assert_eq!(*d.get(0, 0), 1.0);
        assert_eq!(*d.get(1, 0), 1.5);
        assert!(d.get(2, 0).is_nan());
        assert_eq!(*d.get(1, 1), 65.535);
        assert!((d.get(2, 1) - 0.007).abs() < 1e-9);
        let t = kd.rig.color_from_depth.translation;
        assert!((t - Vector3::new(-0.052, 0.0005, 0.001)).norm() < 1e-15, "T {t} (mm → m)");
        assert_eq!(kd.rig.depth.intrinsics.fy, 366.0);

        let picture = MatValue::Numeric(NumericArray {
            dims: vec![2, 3],
            real: NumericData::UInt8(vec![0, 0, 0, 9, 0, 0]),
            imag: None,
        });
        write_mat(&path, &lab_file(picture)).unwrap();
        let kd = read_kinect_data(&path).unwrap();
        let KinectDepth::Unusable(why) = &kd.depth else { panic!("uint8 accepted") };
        assert!(why.contains("uint8") && why.contains("83 % zeros"), "{why}");
        assert_eq!((kd.rig.depth.width, kd.rig.depth.height), KINECT_DEPTH_SIZE);
    }
}
