//! Volumetric fusion on the CPU: integration of one Kinect-size depth frame (512×424) and
//! marching cubes, on all cores (rayon).
//!
//! Frame: the noisy Kinect preset (`geometry::synth::kinect_noisy_preset`: the factory lens
//! distortion, objects at 1.0–1.7 m before a wall at 2.2–4.5 m, σ = 1.5 mm·z² and flying
//! pixels), z depth; default truncation (30 mm, or 3 voxels).
//!
//! * `integrate/first_{5,10}mm`: the frame into an empty volume (every block of its band
//!   allocated: what the first frame of a sensor costs, and what Open3D's
//!   `VoxelBlockGrid.integrate` does on a fresh grid).
//! * `integrate/again_{5,10}mm`: the frame into a volume that already holds it (the blocks
//!   exist: each further frame of a fixed sensor).
//! * `extract_mesh/{5,10}mm`: marching cubes of that volume, with colours and normals.
//! * `ring/again_{5,10}mm`: one sensor of the simulated 3-Kinect ring
//!   (`geometry::synth::kinect_ring_preset`, noisy: a box and a sphere on a floor at
//!   1.3–2.5 m, nothing behind), the frame into a volume that holds it.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use geometry::RigidTransform;
use geometry::synth::{
    KinectNoise, kinect_noisy_preset, kinect_ring_preset, render_noisy, render_ring,
};
use kfuse_tsdf::{DepthFrame, TsdfOptions, TsdfVolume};

fn benches(c: &mut Criterion) {
    let (setup, noise) = kinect_noisy_preset();
    let frame = render_noisy(&setup, &noise).frame;
    let camera = setup.rig.depth;
    let valid = frame.depth.data().iter().filter(|z| z.is_finite() && **z > 0.0).count();
    eprintln!("frame: {}x{}, {valid} depth samples", camera.width, camera.height);
    let depth = DepthFrame {
        camera: &camera,
        camera_from_volume: RigidTransform::identity(),
        z: &frame.depth,
        color: None,
    };
    let mut group = c.benchmark_group("integrate");
    group.sample_size(20);
    for (voxel, name) in [(0.005, "5mm"), (0.01, "10mm")] {
        let empty = TsdfVolume::new(TsdfOptions::with_voxel_size(voxel)).unwrap();
        group.bench_function(format!("first_{name}"), |b| {
            b.iter_batched(
                || empty.clone(),
                |mut v| {
                    v.integrate(black_box(&depth)).unwrap();
                    v
                },
                criterion::BatchSize::LargeInput,
            )
        });
        let mut full = empty.clone();
        let stats = full.integrate(&depth).unwrap();
        eprintln!(
            "{name}: {} blocks ({:.0} MB), {} voxels updated per frame",
            full.block_count(),
            full.memory_bytes() as f64 / 1e6,
            stats.voxels_updated
        );
        group.bench_function(format!("again_{name}"), |b| {
            b.iter(|| full.integrate(black_box(&depth)).unwrap())
        });
    }
    group.finish();
    let ring = kinect_ring_preset();
    let ring_frames = render_ring(&ring, Some(&KinectNoise::default()));
    let ring_camera = ring.setups[0].rig.depth;
    let ring_depth = DepthFrame {
        camera: &ring_camera,
        camera_from_volume: RigidTransform::identity(),
        z: &ring_frames[0].depth,
        color: None,
    };
    let valid = ring_frames[0].depth.data().iter().filter(|z| z.is_finite() && **z > 0.0).count();
    eprintln!("ring frame: {valid} depth samples");
    let mut group = c.benchmark_group("ring");
    group.sample_size(20);
    for (voxel, name) in [(0.005, "5mm"), (0.01, "10mm")] {
        let mut full = TsdfVolume::new(TsdfOptions::with_voxel_size(voxel)).unwrap();
        full.integrate(&ring_depth).unwrap();
        eprintln!("ring {name}: {} blocks", full.block_count());
        group.bench_function(format!("again_{name}"), |b| {
            b.iter(|| full.integrate(black_box(&ring_depth)).unwrap())
        });
    }
    group.finish();
    let mut group = c.benchmark_group("extract_mesh");
    group.sample_size(10);
    for (voxel, name) in [(0.005, "5mm"), (0.01, "10mm")] {
        let mut v = TsdfVolume::new(TsdfOptions::with_voxel_size(voxel)).unwrap();
        v.integrate(&depth).unwrap();
        let faces = v.extract_mesh().faces.len();
        eprintln!("{name}: mesh of {faces} faces");
        group.bench_function(name, |b| b.iter(|| black_box(v.extract_mesh())));
    }
    group.finish();
}

criterion_group!(tsdf, benches);
criterion_main!(tsdf);
