//! Shared helpers of the GPU tests: the adapter policy and test rigs.
#![allow(dead_code)]

use fusion_gpu::{FusionContext, GpuError, GpuPolicy};

/// A context on the default adapter, or `None` (after printing `SKIP <test>: no GPU adapter`)
/// when there is none. With `KFUSE_REQUIRE_GPU=1` (CI) a missing adapter fails the test.
pub fn context_or_skip(test: &str) -> Option<FusionContext> {
    match FusionContext::new(GpuPolicy::Required) {
        Ok(ctx) => {
            eprintln!("{test}: adapter {}", ctx.adapter_summary());
            Some(ctx)
        }
        Err(e @ GpuError::NoAdapter { .. }) => {
            if std::env::var("KFUSE_REQUIRE_GPU").is_ok_and(|v| v == "1") {
                panic!("{test}: KFUSE_REQUIRE_GPU=1 but {e}");
            }
            eprintln!("SKIP {test}: no GPU adapter ({e})");
            None
        }
        Err(e) => panic!("{test}: {e}"),
    }
}

use geometry::{CameraModel, DepthKind, Distortion, Image, Intrinsics, Rig, RigidTransform};
use nalgebra::Vector3;

/// A Kinect-like rig: the factory depth intrinsics of a real Kinect v2 and a distorted
/// colour camera of `color_w × color_h` (focal length scaled with the width).
pub fn kinect_rig(color_w: usize, color_h: usize) -> Rig {
    let depth = CameraModel::new(
        512,
        424,
        Intrinsics::new(368.096588, 368.096588, 261.696594, 202.522202),
        Distortion { k1: 0.084061, k2: -0.271582, p1: 0.0, p2: 0.0, k3: 0.101907 },
    );
    let s = color_w as f64 / 1920.0;
    let color = CameraModel::new(
        color_w,
        color_h,
        Intrinsics::new(1060.0 * s, 1058.0 * s, (color_w as f64 - 1.0) / 2.0, (color_h as f64 - 1.0) / 2.0),
        Distortion { k1: 0.02, k2: -0.01, p1: 0.0005, p2: -0.0003, k3: 0.0 },
    );
    let t = RigidTransform::from_axis_angle(Vector3::new(0.002, -0.003, 0.001), Vector3::new(0.052, 0.001, -0.002));
    Rig::new(depth, color, t)
}

/// An analytic scene seen by the depth camera: a back wall at 3 m tilted about y, a sphere of
/// radius 0.4 m at (0.2, 0, 1.5) in front of it (so the colour camera, 5 cm to the side, sees
/// disocclusions), every 37th pixel invalid (alternately 0 and NaN). Values are `z` or
/// `range` per `kind`, computed in f64 from the camera's own rays.
pub fn scene_depth(rig: &Rig, kind: DepthKind) -> Image<f32> {
    let cam = &rig.depth;
    let centre = Vector3::new(0.2, 0.0, 1.5);
    let radius: f64 = 0.4;
    Image::from_fn(cam.width, cam.height, |u, v| {
        let i = v * cam.width + u;
        if i % 37 == 0 {
            return if (i / 37) % 2 == 0 { 0.0 } else { f32::NAN };
        }
        let Some(n) = cam.unproject(u as f64, v as f64) else { return f32::NAN };
        let dir = Vector3::new(n.x, n.y, 1.0); // z = 1 along the ray
        // Wall: z = 3 + 0.3 x.
        let mut t = 3.0 / (1.0 - 0.3 * dir.x);
        // Sphere: |t dir - c|² = r².
        let b = dir.dot(&centre);
        let a = dir.dot(&dir);
        let disc = b * b - a * (centre.dot(&centre) - radius * radius);
        if disc >= 0.0 {
            let ts = (b - disc.sqrt()) / a;
            if ts > 0.0 && ts < t {
                t = ts;
            }
        }
        let p = dir * t;
        match kind {
            DepthKind::Z => p.z as f32,
            DepthKind::Range => p.norm() as f32,
        }
    })
}
