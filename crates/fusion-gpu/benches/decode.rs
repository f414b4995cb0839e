//! Kinect v2 depth decoding on the GPU (issue 15 item 4): one raw frame decoded and read back
//! (`GpuDecoder::decode`), decoded + registered without the depth leaving the GPU
//! (`FusionContext::decode_and_register`, z-buffer read back), and the same streamed with two
//! frames in flight (`FusionContext::stream_raw`), decoding without the two filters (their
//! cost), against the CPU `Fast` decoder on the same
//! frame for scale. Needs the shared vectors (`../shared/data/kinect-v2-vectors`) and a Vulkan
//! adapter; prints what it skips otherwise.
//!
//! `cargo bench -p fusion-gpu --bench decode -- --warm-up-time 1 --measurement-time 5`

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use fusion_gpu::{FramePlan, FusionContext, GpuDecoder};
use kinect_usb::decoder::{DecoderConfig, DecoderParams, DepthDecoder};
use kinect_usb::params::{P0Tables, XzTables};
use kinect_usb::raw::PIXELS;
use kinect_usb::testdata::{read_bytes, read_f32, vectors_dir};

/// Frames per streaming measurement: enough for the two slots to reach a steady state.
const STREAM_FRAMES: usize = 8;

fn bench(c: &mut Criterion) {
    let Some(dir) = vectors_dir() else {
        eprintln!("SKIP decode bench: shared data not found (set KFUSE_SHARED_DATA)");
        return;
    };
    let mut ctx = match FusionContext::new() {
        Ok(ctx) => ctx,
        Err(e) => {
            eprintln!("SKIP decode bench: {e}");
            return;
        }
    };
    eprintln!("adapter: {}", ctx.adapter_summary());
    let p0 =
        P0Tables::from_response(&read_bytes(&dir.join("inputs/p0_tables_response.bin")).unwrap())
            .unwrap();
    let xz = XzTables::from_vecs(
        read_f32(&dir.join("tables/xtable.f32")).unwrap(),
        read_f32(&dir.join("tables/ztable.f32")).unwrap(),
    )
    .unwrap();
    let raw = read_bytes(&dir.join("frames/scene.raw")).unwrap();
    let cfg = DecoderConfig::default();
    let mut gpu = GpuDecoder::new(&ctx, DecoderParams::default(), cfg, &xz, &p0).unwrap();
    let mut cpu = DepthDecoder::new(DecoderParams::default(), cfg, &xz, &p0).unwrap();
    let rig = geometry::synth::kinect_rig();
    let (mut depth, mut ir) = (vec![0f32; PIXELS], vec![0f32; PIXELS]);

    let mut g = c.benchmark_group("decode");
    g.throughput(Throughput::Elements(1));
    g.bench_function("cpu_fast_frame", |b| {
        b.iter(|| cpu.decode(black_box(&raw), &mut depth, &mut ir).unwrap())
    });
    g.bench_function("gpu_frame", |b| {
        b.iter(|| gpu.decode(black_box(&raw), &mut depth, &mut ir).unwrap())
    });
    // The same without the bilateral and edge-aware filters: what the filters cost.
    let bare = DecoderConfig {
        bilateral: false,
        edge_aware: false,
        parallel: true,
        ..DecoderConfig::default()
    };
    let mut gpu_bare = GpuDecoder::new(&ctx, DecoderParams::default(), bare, &xz, &p0).unwrap();
    g.bench_function("gpu_frame_without_filters", |b| {
        b.iter(|| gpu_bare.decode(black_box(&raw), &mut depth, &mut ir).unwrap())
    });
    g.bench_function("gpu_decode_register_frame", |b| {
        b.iter(|| black_box(ctx.decode_and_register(&gpu, &raw, &rig, false).unwrap()))
    });
    g.throughput(Throughput::Elements(STREAM_FRAMES as u64));
    let plan = FramePlan::default();
    g.bench_function("gpu_decode_register_stream", |b| {
        b.iter(|| {
            let frames = (0..STREAM_FRAMES).map(|_| (&raw[..], None));
            ctx.stream_raw(&gpu, &rig, frames, plan, |_, f| {
                black_box(f);
            })
            .unwrap()
        })
    });
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
