//! Streaming mode: consecutive frames through two in-flight slots give exactly the results of
//! single-frame runs, in order.

mod common;

use common::{context_or_skip, kinect, with_small_color};
use fusion_gpu::FramePlan;
use geometry::fusion::PixelParams;
use geometry::{DepthKind, Image};

#[test]
fn streamed_frames_equal_single_frames_in_order() {
    let test = "streamed_frames_equal_single_frames_in_order";
    let Some(mut ctx) = context_or_skip(test) else { return };
    let (setup, frame) = kinect();
    // A 480x270 colour camera keeps the test fast; the slot logic does not depend on size.
    let rig = with_small_color(&setup.rig, 480);
    let color = Image::from_fn(rig.color.width, rig.color.height, |x, y| {
        [(x % 256) as u8, (y % 256) as u8, ((x + y) % 256) as u8]
    });
    // Four different frames: the preset's depth scaled by 1 + 2% k (so every z-buffer differs).
    let depths: Vec<Image<f32>> =
        (0..4).map(|k| frame.depth.map(|&z| z * (1.0 + 0.02 * k as f32))).collect();
    let plan = FramePlan {
        stages: Some(PixelParams {
            radius_px: 1.5,
            grow_px: 1.0,
            depth_jump: 0.05,
            occlusion_tolerance: Some(0.02),
            zbuffer: true,
            depth_range: geometry::fusion::DepthRange::ALL,
        }),
        read_intermediates: false,
    };
    let mut streamed = Vec::new();
    let n = ctx
        .stream(&rig, DepthKind::Z, depths.iter().map(|d| (d, Some(&color))), plan, |k, f| {
            streamed.push((k, f))
        })
        .expect("stream");
    // Four frames were built above (k = 0..4), handed back in submission order.
    assert_eq!(n, 4);
    assert_eq!(streamed.iter().map(|(k, _)| *k).collect::<Vec<_>>(), vec![0, 1, 2, 3]);
    for (k, got) in &streamed {
        let want =
            ctx.frame(&rig, &depths[*k], DepthKind::Z, Some(&color), plan).expect("single frame");
        // Bit-level comparison (NaN == NaN by bits).
        let bits = |i: &Image<f32>| i.data().iter().map(|z| z.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&got.zbuffer), bits(&want.zbuffer), "frame {k}: z-buffer");
        assert_eq!(
            bits(got.nearest.as_ref().unwrap()),
            bits(want.nearest.as_ref().unwrap()),
            "frame {k}: nearest"
        );
        assert_eq!(got.holes, want.holes, "frame {k}: holes");
        assert_eq!(got.color_on_depth, want.color_on_depth, "frame {k}: colour");
    }
    // The frames really differ (the slots did not hand back a stale buffer).
    assert_ne!(
        streamed[0].1.zbuffer.data()[..].iter().map(|z| z.to_bits()).collect::<Vec<_>>(),
        streamed[3].1.zbuffer.data()[..].iter().map(|z| z.to_bits()).collect::<Vec<_>>()
    );
}

#[test]
fn a_bad_frame_mid_stream_is_an_error_and_the_context_stays_usable() {
    let test = "a_bad_frame_mid_stream_is_an_error_and_the_context_stays_usable";
    let Some(mut ctx) = context_or_skip(test) else { return };
    let (setup, frame) = kinect();
    let bad = Image::filled(10, 10, 1.0f32);
    let frames = [&frame.depth, &bad, &frame.depth];
    let mut seen = 0;
    let err = ctx
        .stream(
            &setup.rig,
            DepthKind::Z,
            frames.iter().map(|d| (*d, None)),
            FramePlan::default(),
            |_, _| seen += 1,
        )
        .expect_err("a 10x10 depth frame was accepted");
    assert!(err.to_string().contains("10x10"), "{err}");
    assert_eq!(seen, 0, "results of a failed stream are not handed out");
    let after = ctx
        .register(&setup.rig, &frame.depth, DepthKind::Z, false)
        .expect("context unusable after the error");
    assert!(after.zbuffer.data().iter().any(|z| !z.is_nan()));
}
