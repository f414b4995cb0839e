//! CPU vs GPU fusion, per stage and end to end, for a Kinect-size frame (512x424 depth ->
//! 1920x1080 colour, `geometry::synth::kinect_preset`). GPU figures include upload and
//! read-back. Prints the adapter; without one only the CPU side runs.
//!
//! `cargo bench --bench fusion_gpu -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;
use std::sync::atomic::AtomicU32;

use criterion::{Criterion, SamplingMode, Throughput, criterion_group, criterion_main};
use fusion_gpu::{FramePlan, FusionContext};
use geometry::fusion::{
    ColorProjection, FusionOptions, PixelParams, PlaneFit, backproject_cloud, color_on_depth,
    coverage_radius_px, depth_ray_table, fill_holes_with_plane, hole_grow_px, hole_mask,
    nearest_fill, project_cloud, register_depth, register_depth_parallel, run,
    zbuffer_from_samples,
};
use geometry::synth;
use geometry::{DepthKind, Image};

/// Frames per streaming measurement: enough for the two slots to reach a steady state.
const STREAM_FRAMES: usize = 4;

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
    g.bench_function("h7_zbuffer", |b| {
        b.iter(|| black_box(zbuffer_from_samples(&samples, cw as u32, ch as u32)))
    });
    let mut zb = vec![0f32; cw * ch];
    g.bench_function("h1_h2_h7_fused_single_thread", |b| {
        b.iter(|| black_box(register_depth(depth.data(), &rays, &proj, &mut zb)))
    });
    let atomic: Vec<AtomicU32> = (0..cw * ch).map(|_| AtomicU32::new(0)).collect();
    g.bench_function("h1_h2_h7_fused_rayon", |b| {
        b.iter(|| {
            black_box(register_depth_parallel(depth.data(), &rays, rig.depth.width, &proj, &atomic))
        })
    });
    let zbuffer = zbuffer_from_samples(&samples, cw as u32, ch as u32);
    let radius = coverage_radius_px(rig, &FusionOptions::default());
    let grow = hole_grow_px(rig, &FusionOptions::default());
    g.bench_function("h3_nearest_fill", |b| {
        b.iter(|| black_box(nearest_fill(&zbuffer, radius, 0.05)))
    });
    let nearest_cpu = nearest_fill(&zbuffer, radius, 0.05);
    g.bench_function("h8_hole_mask", |b| b.iter(|| black_box(hole_mask(&zbuffer, radius, grow))));
    let mask_cpu = hole_mask(&zbuffer, radius, grow);
    let plane =
        PlaneFit { normal: [0.0, 0.0, 1.0], offset: 3.0, inliers: 0, samples: 0, rms_m: 0.0 };
    g.bench_function("h8_plane_fill", |b| {
        b.iter(|| black_box(fill_holes_with_plane(&nearest_cpu, &mask_cpu, &rig.color, &plane)))
    });
    g.bench_function("h6_color_on_depth", |b| {
        b.iter(|| {
            black_box(color_on_depth(depth, &rays, &proj, &frame.color, Some(&nearest_cpu), 0.02))
        })
    });
    g.finish();

    // End to end, H1-H8 (H3 linear off: it is the same CPU code on both paths).
    let options = FusionOptions { linear: false, ..FusionOptions::default() };
    let mut g = c.benchmark_group("end_to_end");
    // Frames of 10-200 ms: 10 samples keep the run within minutes on lavapipe.
    g.sample_size(10);
    // Flat: every sample runs the same number of iterations (10 calls of ~0.1–1 s here, not
    // the 55 of linear sampling), so `benches/run_all.sh` stays minutes long.
    g.sampling_mode(SamplingMode::Flat);
    g.bench_function("cpu_run", |b| {
        b.iter(|| black_box(run(rig, depth, kind, &frame.color, &options).expect("CPU run")))
    });
    let gpu_ctx = FusionContext::new();
    if let Ok(mut ctx) = gpu_ctx {
        g.bench_function("gpu_run", |b| {
            b.iter(|| {
                black_box(ctx.run(rig, depth, kind, &frame.color, &options).expect("GPU run"))
            })
        });
    }
    g.finish();

    let mut ctx = match FusionContext::new() {
        Ok(ctx) => ctx,
        Err(e) => {
            eprintln!("SKIP GPU benches: {e}");
            return;
        }
    };
    println!("GPU adapter: {}", ctx.adapter_summary());
    // The later stages with the parameters geometry::fusion::run derives for this rig.
    let stages = PixelParams {
        radius_px: radius,
        grow_px: grow,
        depth_jump: 0.05,
        occlusion_tolerance: Some(0.02),
        zbuffer: true,
        depth_range: geometry::fusion::DepthRange::ALL,
    };
    let all = FramePlan { stages: Some(stages), read_intermediates: false };
    let mut g = c.benchmark_group("gpu");
    g.sample_size(10);
    // Flat sampling, as above.
    g.sampling_mode(SamplingMode::Flat);
    g.bench_function("h1_h2_h7_with_upload_readback", |b| {
        b.iter(|| black_box(ctx.register(rig, depth, kind, false).expect("GPU frame")))
    });
    g.bench_function("h1_h2_h7_h3_h8mask_h6_with_upload_readback", |b| {
        b.iter(|| {
            black_box(ctx.frame(rig, depth, kind, Some(&frame.color), all).expect("GPU frame"))
        })
    });
    let full = ctx.frame(rig, depth, kind, Some(&frame.color), all).expect("GPU frame");
    let (nearest, holes) = (full.nearest.expect("nearest"), full.holes.expect("holes"));
    g.bench_function("h8_plane_fill_with_upload_readback", |b| {
        b.iter(|| {
            black_box(
                ctx.fill_holes_with_plane(&rig.color, &nearest, &holes, [0.0, 0.0, 1.0], 3.0)
                    .expect("fill"),
            )
        })
    });
    g.finish();

    // Streaming throughput: STREAM_FRAMES frames through two slots vs one at a time.
    let depths: Vec<Image<f32>> =
        (0..STREAM_FRAMES).map(|k| depth.map(|&z| z * (1.0 + 0.01 * k as f32))).collect();
    let mut g = c.benchmark_group("gpu_stream");
    g.sample_size(10);
    // Flat sampling, as above.
    g.sampling_mode(SamplingMode::Flat);
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
