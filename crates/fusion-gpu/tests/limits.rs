//! Bad input and frames beyond the adapter's limits: clear errors, never a driver crash.

mod common;

use common::{context_or_skip, kinect};
use fusion_gpu::{Engine, FramePlan, GpuError};
use geometry::{CameraModel, DepthKind, Image};

#[test]
fn oversize_colour_frame_is_refused_before_allocating() {
    let test = "oversize_colour_frame_is_refused_before_allocating";
    let Some(mut ctx) = context_or_skip(test) else { return };
    let (setup, frame) = kinect();
    let limit = ctx.max_binding_bytes();
    // A colour camera whose ray table (8 bytes a pixel) is 2x the binding limit (lavapipe's
    // 128 MiB: 33.6 Mpx). Past geometry's 50 Mpx camera limit (a GPU with a 2 GiB binding
    // limit) no camera can reach the GPU's limit: the rig is refused before, as tested below.
    let mut rig = setup.rig.clone();
    let pixels = (2 * limit / 8) as usize;
    if pixels as u64 > geometry::camera::MAX_CAMERA_PIXELS {
        rig.color = CameraModel::new(8192, 8192, rig.color.intrinsics, rig.color.distortion);
        let err = ctx.register(&rig, &frame.depth, DepthKind::Z, false).expect_err("67 Mpx");
        assert!(err.to_string().contains("camera limit"), "{err}");
        return;
    }
    let width = 16_384;
    let height = pixels / width + 1;
    rig.color = CameraModel::new(width, height, rig.color.intrinsics, rig.color.distortion);
    let err =
        ctx.register(&rig, &frame.depth, DepthKind::Z, false).expect_err("oversize frame accepted");
    match &err {
        GpuError::FrameTooLarge { buffer, bytes, limit: l, width: w, .. } => {
            assert_eq!(*buffer, "colour ray table");
            assert!(*bytes > *l && *l == limit && *w == width, "{err}");
        }
        other => panic!("{test}: expected FrameTooLarge, got {other}"),
    }
    let msg = err.to_string();
    assert!(msg.contains("--engine cpu") && msg.contains(&limit.to_string()), "{msg}");
    // The context is still usable afterwards.
    let ok = ctx
        .register(&setup.rig, &frame.depth, DepthKind::Z, false)
        .expect("normal frame after refusal");
    assert!(ok.zbuffer.data().iter().any(|z| !z.is_nan()));
}

#[test]
fn oversize_depth_frame_is_refused() {
    let test = "oversize_depth_frame_is_refused";
    let Some(mut ctx) = context_or_skip(test) else { return };
    let (setup, _) = kinect();
    let mut rig = setup.rig.clone();
    // 16 bytes of point per depth pixel: 2x the binding limit. The image is never built:
    // the size check runs on the rig before any pixel is read.
    let pixels = (2 * ctx.max_binding_bytes() / 16) as usize;
    rig.depth =
        CameraModel::new(8192, pixels / 8192 + 1, rig.depth.intrinsics, rig.depth.distortion);
    let depth = Image::filled(1, 1, 1.0f32);
    let err = ctx.register(&rig, &depth, DepthKind::Z, false).expect_err("oversize depth accepted");
    assert!(
        matches!(err, GpuError::FrameTooLarge { buffer: "per-depth-pixel point", .. }),
        "{err}"
    );
}

#[test]
fn bad_input_is_rejected_like_on_the_cpu() {
    let test = "bad_input_is_rejected_like_on_the_cpu";
    let Some(mut ctx) = context_or_skip(test) else { return };
    let (setup, frame) = kinect();
    // Depth image of the wrong size.
    let small = Image::filled(100, 100, 1.0f32);
    let err =
        ctx.register(&setup.rig, &small, DepthKind::Z, false).expect_err("wrong size accepted");
    // 100x100: the frame built above; 512x424: the Kinect preset's depth camera (DESIGN.md).
    assert!(err.to_string().contains("100x100") && err.to_string().contains("512x424"), "{err}");
    // Colour image of the wrong size.
    let color = Image::filled(10, 10, [0u8; 3]);
    let err = ctx
        .frame(&setup.rig, &frame.depth, DepthKind::Z, Some(&color), FramePlan::default())
        .expect_err("wrong colour size accepted");
    assert!(matches!(err, GpuError::Input(_)), "{err}");
    // A rig with a NaN focal length.
    let mut rig = setup.rig.clone();
    rig.color.intrinsics.fx = f64::NAN;
    assert!(matches!(
        ctx.register(&rig, &frame.depth, DepthKind::Z, false),
        Err(GpuError::Input(_))
    ));
    // All-invalid depth is not an error: an empty z-buffer, like the CPU.
    let empty = Image::filled(512, 424, f32::NAN);
    let out = ctx.register(&setup.rig, &empty, DepthKind::Z, false).expect("empty frame");
    // An empty z-buffer pixel holds the all-ones bit pattern (a NaN, the atomicMin identity).
    assert!(out.zbuffer.data().iter().all(|z| z.to_bits() == u32::MAX));
}

#[test]
fn no_adapter_message_says_what_to_do() {
    // The message the CLI prints for `--gpu` without an adapter (no GPU needed for this).
    let err = GpuError::NoAdapter { backends: "VULKAN".into() };
    let msg = err.to_string();
    assert!(msg.starts_with("no GPU adapter found; install mesa-vulkan-drivers for software Vulkan, or use --engine cpu"), "{msg}");
    assert!(Engine::Auto.falls_back_to_cpu() && !Engine::Gpu.falls_back_to_cpu());
}
