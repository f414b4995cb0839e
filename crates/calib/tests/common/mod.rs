//! Shared helpers of the calib integration tests: locating the shared data and reading its
//! JSON references.
#![allow(dead_code, unused_imports)]

use std::path::PathBuf;

use calib::{Board, Corner, ViewCorners};
pub use geometry::testdata::shared_data_or_skip as shared_data;
use geometry::{CameraModel, Distortion, Intrinsics, RigidTransform};
use nalgebra::{Vector2, Vector3};
use serde_json::Value;

pub fn json(path: PathBuf) -> Value {
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

pub fn board() -> Board {
    Board::new(7, 5, 0.04).unwrap()
}

/// A list of `[x, y]` pairs as corners labelled 0, 1, 2, ... in list order.
pub fn corners_from(list: &Value, name: &str, w: usize, h: usize) -> ViewCorners {
    let corners = list
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
        .map(|(id, p)| Corner {
            id,
            px: Vector2::new(p[0].as_f64().unwrap(), p[1].as_f64().unwrap()),
        })
        .collect();
    ViewCorners { name: name.into(), width: w, height: h, corners, unusable: None }
}

pub fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

/// A ground-truth camera of `synthetic-calib/ground_truth.json` ("ir" or "color").
pub fn gt_camera(gt: &Value, cam: &str) -> CameraModel {
    let c = &gt["cameras"][cam];
    let d: Vec<f64> = c["dist_k1_k2_p1_p2_k3"].as_array().unwrap().iter().map(f).collect();
    CameraModel::new(
        c["image_size_wh"][0].as_u64().unwrap() as usize,
        c["image_size_wh"][1].as_u64().unwrap() as usize,
        Intrinsics::new(f(&c["fx"]), f(&c["fy"]), f(&c["cx"]), f(&c["cy"])),
        Distortion::from_array([d[0], d[1], d[2], d[3], d[4]]),
    )
}

/// Ground-truth `camera_from_board` of view `i` (metres).
pub fn gt_pose(gt: &Value, i: usize, cam: &str) -> RigidTransform {
    let v = &gt["views"][i][cam];
    let r = Vector3::new(
        f(&v["rvec_board_to_cam"][0]),
        f(&v["rvec_board_to_cam"][1]),
        f(&v["rvec_board_to_cam"][2]),
    );
    let t = Vector3::new(
        f(&v["tvec_board_to_cam_mm"][0]),
        f(&v["tvec_board_to_cam_mm"][1]),
        f(&v["tvec_board_to_cam_mm"][2]),
    );
    RigidTransform::from_axis_angle(r, t / 1000.0)
}

/// Ground-truth `color_from_depth` (metres).
pub fn gt_color_from_depth(gt: &Value) -> RigidTransform {
    let s = &gt["stereo"];
    let r =
        Vector3::new(f(&s["om_rodrigues"][0]), f(&s["om_rodrigues"][1]), f(&s["om_rodrigues"][2]));
    let t = Vector3::new(f(&s["T_mm"][0]), f(&s["T_mm"][1]), f(&s["T_mm"][2]));
    RigidTransform::from_axis_angle(r, t / 1000.0)
}

/// Rotation angle between two rotations, degrees.
pub fn rotation_error_deg(a: &RigidTransform, b: &RigidTransform) -> f64 {
    (a.rotation.inverse() * b.rotation).angle().to_degrees()
}
pub mod render;
