//! CPU vs GPU fusion, per stage and end to end, for a Kinect-size frame (512x424 depth ->
//! 1920x1080 colour, `geometry::synth::kinect_preset`). GPU figures include upload and
//! read-back. Prints the adapter; without one only the CPU side runs.
//!
//! `cargo bench --bench fusion_gpu -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;
use std::sync::atomic::AtomicU32;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use fusion_gpu::{FramePlan, FusionContext, GpuPolicy, StageOptions};
use geometry::fusion::{
    backproject_cloud, depth_ray_table, project_cloud, register_depth, register_depth_parallel, zbuffer_from_samples,
    ColorProjection,
};
use geometry::synth;
use geometry::{DepthKind, Image};

/// Frames per streaming measurement: enough for the two slots to reach a steady state.
const STREAM_FRAMES: usize = 8;

/// The later stages' parameters used for the GPU "all stages" figures.
const STAGES: StageOptions =
    StageOptions { nearest_radius_px: 2.5, depth_jump: 0.05, hole_radius_px: 3.5, hole_grow_px: 2.0, occlusion_tolerance: Some(0.02) };

fn bench(c: &mut Criterion) {
    let setup = synth::kinect_preset(true);
    let frame = synth::render(&setup);
    let rig = &setup.rig;
    let depth = &frame.depth;
    let kind = DepthKind::Z;
    let rays = depth_ray_table(&rig.depth, kind);
    let proj = ColorProjection::from_rig(rig);
    let (cw, ch) = (rig.color.width, rig.color.height);

    // CPU per stage.
    let mut g = c.benchmark_group("cpu");
    g.bench_function("h1_backproject", |b| b.iter(|| black_box(backproject_cloud(depth, &rays))));
    let (cloud, _) = backproject_cloud(depth, &rays);
    g.bench_function("h2_project", |b| b.iter(|| black_box(project_cloud(&cloud.points, &proj))));
    let samples = project_cloud(&cloud.points, &proj);
    g.bench_function("h7_zbuffer", |b| b.iter(|| black_box(zbuffer_from_samples(&samples, cw as u32, ch as u32))));
    let mut zb = vec![0f32; cw * ch];
    g.bench_function("h1_h2_h7_fused_single_thread", |b| {
        b.iter(|| black_box(register_depth(depth.data(), &rays, &proj, &mut zb)))
    });
    let atomic: Vec<AtomicU32> = (0..cw * ch).map(|_| AtomicU32::new(0)).collect();
    g.bench_function("h1_h2_h7_fused_rayon", |b| {
        b.iter(|| black_box(register_depth_parallel(depth.data(), &rays, rig.depth.width, &proj, &atomic)))
    });
    g.finish();

    let mut ctx = match FusionContext::new(GpuPolicy::Required) {
        Ok(ctx) => ctx,
        Err(e) => {
            eprintln!("SKIP GPU benches: {e}");
            return;
        }
    };
    println!("GPU adapter: {}", ctx.adapter_summary());
    let all = FramePlan { stages: Some(STAGES), read_intermediates: false };
    let mut g = c.benchmark_group("gpu");
    g.bench_function("h1_h2_h7_with_upload_readback", |b| {
        b.iter(|| black_box(ctx.register(rig, depth, kind, false).expect("GPU frame")))
    });
    g.bench_function("h1_h2_h7_h3_h8mask_h6_with_upload_readback", |b| {
        b.iter(|| black_box(ctx.frame(rig, depth, kind, Some(&frame.color), all).expect("GPU frame")))
    });
    let full = ctx.frame(rig, depth, kind, Some(&frame.color), all).expect("GPU frame");
    let (nearest, holes) = (full.nearest.expect("nearest"), full.holes.expect("holes"));
    g.bench_function("h8_plane_fill_with_upload_readback", |b| {
        b.iter(|| black_box(ctx.fill_holes_with_plane(&rig.color, &nearest, &holes, [0.0, 0.0, 1.0], 3.0).expect("fill")))
    });
    g.finish();

    // Streaming throughput: STREAM_FRAMES frames through two slots vs one at a time.
    let depths: Vec<Image<f32>> = (0..STREAM_FRAMES).map(|k| depth.map(|&z| z * (1.0 + 0.01 * k as f32))).collect();
    let mut g = c.benchmark_group("gpu_stream");
    g.throughput(Throughput::Elements(STREAM_FRAMES as u64));
    g.bench_function("streamed_two_slots", |b| {
        b.iter(|| {
            ctx.stream(rig, kind, depths.iter().map(|d| (d, Some(&frame.color))), all, |_, f| {
                black_box(f);
            })
            .expect("stream")
        })
    });
    g.bench_function("sequential_frames", |b| {
        b.iter(|| {
            for d in &depths {
                black_box(ctx.frame(rig, d, kind, Some(&frame.color), all).expect("GPU frame"));
            }
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
