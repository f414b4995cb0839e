//! Bouguet's Camera Calibration Toolbox results as calibration data: the file reader is
//! [`kfuse_io::bouguet`] (where every rig format lives); this module labels its corners as
//! board corners ([`ViewCorners`]) and its errors as [`IntrinsicsStd`], for comparing kfuse's
//! calibration with the lab's.

use std::path::Path;

use geometry::{CameraModel, Rig, RigidTransform};
use nalgebra::{Vector2, Vector3};

use crate::{CalibError, Corner, IntrinsicsStd, ViewCorners};

/// One camera's Bouguet result.
#[derive(Debug, Clone)]
pub struct BouguetCamera {
    /// The camera (`fc`, `cc`, `alpha_c`, `kc`, `nx × ny`).
    pub camera: CameraModel,
    /// 1σ of the intrinsics (Bouguet's `*_error` / 3).
    pub std: IntrinsicsStd,
    /// Per image (1-based MATLAB index `i` at position `i − 1`): the extracted corners `x_i`
    /// labelled in Bouguet's order, `None` for inactive images.
    pub views: Vec<Option<ViewCorners>>,
    /// Per image: Bouguet's board points `X_i` (metres), parallel to `views`.
    pub board_points: Vec<Option<Vec<Vector3<f64>>>>,
    /// Bouguet's `camera_from_board` per image (`omc_i`, `Tc_i` in metres).
    pub poses: Vec<Option<RigidTransform>>,
    /// Bouguet's pixel error std `err_std` (x, y), px.
    pub err_std_px: Option<Vector2<f64>>,
}

/// Reads a mono result (`Calib_Results_left.mat`, `Calib_Results_right.mat`, or a plain
/// `Calib_Results.mat`) with [`kfuse_io::bouguet::import_mono`].
pub fn import_mono(path: &Path) -> Result<BouguetCamera, CalibError> {
    let b = kfuse_io::bouguet::import_mono(path)?;
    let (width, height) = (b.camera.width, b.camera.height);
    let views = b
        .views
        .into_iter()
        .enumerate()
        .map(|(k, v)| {
            v.map(|px| ViewCorners {
                name: format!("image {}", k + 1),
                width,
                height,
                corners: px.into_iter().enumerate().map(|(id, px)| Corner { id, px }).collect(),
                unusable: None,
            })
        })
        .collect();
    Ok(BouguetCamera {
        camera: b.camera,
        std: IntrinsicsStd::from_array(b.std),
        views,
        board_points: b.board_points,
        poses: b.poses,
        err_std_px: b.err_std_px,
    })
}

/// Reads a stereo result into a rig ([`kfuse_io::bouguet::import_stereo`]).
pub fn import_stereo(stereo: &Path, left: &Path, right: &Path) -> Result<Rig, CalibError> {
    Ok(kfuse_io::bouguet::import_stereo(stereo, left, right)?)
}
