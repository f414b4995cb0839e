//! Helpers shared by the end-to-end tests of the `kfuse` binary: running it, scratch folders,
//! and a small rig with matching input images.
#![allow(dead_code)] // each test binary uses a different subset

use std::path::PathBuf;
use std::process::{Command, Output};

use geometry::{CameraModel, Distortion, Image, Intrinsics, Rig, RigidTransform};
use kfuse_io::{images, rig as rigio};
use nalgebra::Vector3;

/// Runs the built binary with `args` and waits for it.
pub fn kfuse(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kfuse")).args(args).output().expect("run kfuse")
}

/// A fresh, empty folder under the temp dir, unique per test name and process.
pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kfuse-e2e-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A small rig: 64x48 depth camera, 96x72 colour camera 5 cm to the side.
pub fn small_rig() -> Rig {
    let depth = CameraModel::new(64, 48, Intrinsics::new(60.0, 60.0, 31.5, 23.5), Distortion::NONE);
    let color = CameraModel::new(96, 72, Intrinsics::new(90.0, 90.0, 47.5, 35.5), Distortion::NONE);
    Rig::new(
        depth,
        color,
        RigidTransform::new(nalgebra::Rotation3::identity(), Vector3::new(-0.05, 0.0, 0.0)),
    )
}

/// The files of [`small_case`]: the rig and one colour and depth image in `dir`.
pub struct Case {
    pub dir: PathBuf,
    pub rig: PathBuf,
    pub color: PathBuf,
    pub depth: PathBuf,
}

/// Writes [`small_rig`] with a colour gradient and a tilted depth ramp (1.5 m + 1 cm per column)
/// into a fresh scratch folder.
pub fn small_case(name: &str) -> Case {
    let dir = scratch(name);
    let rig = dir.join("rig.json");
    rigio::write_rig(&rig, &small_rig()).unwrap();
    let color = dir.join("color.png");
    images::write_color_png(&color, &Image::from_fn(96, 72, |x, y| [x as u8, y as u8, 100]))
        .unwrap();
    let depth = dir.join("depth.png");
    images::write_depth_png16(&depth, &Image::from_fn(64, 48, |x, _| 1.5 + 0.01 * x as f32))
        .unwrap();
    Case { dir, rig, color, depth }
}

/// The sensor's factory parameters from a `kinect_params.json` (what `kfuse capture` writes
/// beside its shots), read field by field with serde_json: independent of the simulator's and
/// of `rig import`'s own readers, so tests can hold those against it.
pub fn kinect_params_of(
    v: &serde_json::Value,
) -> (kinect_usb::params::DepthParams, kinect_usb::params::ColorParams) {
    let f = |o: &str, k: &str| v[o][k].as_f64().unwrap() as f32;
    let arr = |k: &str| -> [f32; 10] {
        std::array::from_fn(|i| v["color"][k][i].as_f64().unwrap() as f32)
    };
    (
        kinect_usb::params::DepthParams {
            fx: f("depth", "fx"),
            fy: f("depth", "fy"),
            cx: f("depth", "cx"),
            cy: f("depth", "cy"),
            k1: f("depth", "k1"),
            k2: f("depth", "k2"),
            k3: f("depth", "k3"),
            p1: f("depth", "p1"),
            p2: f("depth", "p2"),
        },
        kinect_usb::params::ColorParams {
            f: f("color", "fx"),
            cx: f("color", "cx"),
            cy: f("color", "cy"),
            shift_d: f("color", "shift_d"),
            shift_m: f("color", "shift_m"),
            mx: arr("mx"),
            my: arr("my"),
        },
    )
}
