//! `--depth-range` (issue 46): depth values outside the range are not samples, on the CPU and
//! on the GPU alike. The Kinect preset's frame with a range cut through its depths: the kept
//! samples are counted here from the depth image itself, and the cloud of the clipped run is
//! the unclipped run's cloud restricted to the pixels whose depth is inside. The GPU (a whole
//! frame, and a stream that asks H1 + H2 + H7 only, so the range reaches H1 without the later
//! stages' parameters) gives the CPU's bits.

mod common;

use common::{context_or_skip, kinect};
use fusion_gpu::PixelEngine;
use geometry::fusion::{
    self, CpuPixels, DepthRange, FusionOptions, Request, StreamFrame, StreamPlan, run,
};
use geometry::{DepthKind, Image};

/// The range: from the 30th to the 70th percentile of the frame's samples, so that both ends
/// cut through the scene.
fn range_of(depth: &Image<f32>) -> DepthRange {
    let mut v: Vec<f32> =
        depth.data().iter().copied().filter(|z| z.is_finite() && *z > 0.0).collect();
    v.sort_by(f32::total_cmp);
    DepthRange::new(v[v.len() * 3 / 10], v[v.len() * 7 / 10]).unwrap()
}

fn bits(z: &[f32]) -> Vec<u32> {
    z.iter().map(|v| v.to_bits()).collect()
}

/// The z-buffer of a stream of one frame on `engine`, H1 + H2 + H7 only.
fn streamed(engine: &mut PixelEngine, request: &Request, depth: &Image<f32>) -> Vec<u32> {
    let mut out = Vec::new();
    let frames = [StreamFrame { depth, color: None }];
    fusion::stream_on(engine, request, &frames, StreamPlan::default(), &mut |_, r| {
        out = bits(r.zbuffer)
    })
    .expect("stream");
    out
}

#[test]
fn samples_outside_the_range_are_not_samples_on_cpu_and_gpu() {
    let (setup, frame) = kinect();
    let (rig, depth) = (&setup.rig, &frame.depth);
    assert_eq!(frame.depth_kind, DepthKind::Z);
    let range = range_of(depth);
    let is_sample = |z: f32| z.is_finite() && z > 0.0;
    let all = depth.data().iter().filter(|&&z| is_sample(z)).count();
    let inside = depth
        .data()
        .iter()
        .filter(|&&z| is_sample(z) && z >= range.min_m && z <= range.max_m)
        .count();
    eprintln!("range {range}: {inside} of {all} samples inside");
    assert!(inside > all / 3 && inside < all * 2 / 3, "{inside} of {all}");

    let options = FusionOptions { depth_range: range, linear: false, ..FusionOptions::default() };
    let whole = run(
        rig,
        depth,
        DepthKind::Z,
        &frame.color,
        &FusionOptions { linear: false, ..FusionOptions::default() },
    )
    .unwrap();
    let cpu = run(rig, depth, DepthKind::Z, &frame.color, &options).unwrap();
    assert_eq!(cpu.summary.valid_depth_pixels, inside);
    assert_eq!(whole.summary.valid_depth_pixels, all);
    // The clipped cloud is the whole cloud's points at the pixels inside, bit for bit.
    let kept: Vec<(u32, [u32; 3])> = whole
        .cloud_pixels
        .iter()
        .zip(&whole.cloud.points)
        .filter(|(i, _)| {
            let z = depth.data()[**i as usize];
            z >= range.min_m && z <= range.max_m
        })
        .map(|(i, p)| (*i, p.map(f32::to_bits)))
        .collect();
    let clipped: Vec<(u32, [u32; 3])> = cpu
        .cloud_pixels
        .iter()
        .zip(&cpu.cloud.points)
        .map(|(i, p)| (*i, p.map(f32::to_bits)))
        .collect();
    assert_eq!(clipped.len(), kept.len());
    assert!(clipped == kept, "the clipped cloud is not the whole cloud's points inside");
    assert!(cpu.summary.zbuffer_pixels < whole.summary.zbuffer_pixels);

    // A stream on the CPU gives the single frame's z-buffer.
    let request = Request::new(rig, DepthKind::Z, options).unwrap();
    let mut cpu_engine = PixelEngine::Cpu(CpuPixels::new());
    let cpu_stream = streamed(&mut cpu_engine, &request, depth);
    assert!(cpu_stream == bits(cpu.zbuffer.data()), "CPU stream and frame differ");

    let Some(mut ctx) = context_or_skip("depth_range") else { return };
    let gpu = ctx.run(rig, depth, DepthKind::Z, &frame.color, &options).unwrap();
    assert_eq!(gpu.summary.valid_depth_pixels, inside);
    assert!(gpu.cloud_pixels == cpu.cloud_pixels, "GPU H1 pixels differ");
    assert!(bits(gpu.zbuffer.data()) == bits(cpu.zbuffer.data()), "GPU z-buffer differs");
    assert!(gpu.hole_mask.data() == cpu.hole_mask.data(), "GPU hole mask differs");
    assert!(gpu.color_on_depth.data() == cpu.color_on_depth.data(), "GPU H6 differs");
    let mut gpu_engine = PixelEngine::Gpu(Box::new(ctx));
    let gpu_stream = streamed(&mut gpu_engine, &request, depth);
    assert!(gpu_stream == cpu_stream, "GPU stream (H1 + H2 + H7 only) differs from the CPU's");
}
