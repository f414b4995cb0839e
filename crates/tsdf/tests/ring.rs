//! Accuracy against truth on the simulated ring of three Kinects (`geometry::synth::ring`):
//! the TSDF mesh of one matched set of depth images, at 5 mm and 10 mm voxels, noise-free and
//! with the Kinect's noise (σ = 1.5 mm·z² and flying pixels), against the scene's true
//! surfaces; and against the merged point cloud of the same noisy depth.
//!
//! * **Error** of a vertex: its distance to the true surface, from the shapes' own distance
//!   functions (`common::scene_distance`), not from the TSDF.
//! * **Completeness**: the share of true surface samples within two voxels of a mesh vertex.
//!   The samples are the true surface points (the simulator's ray-cast `true_depth_z`) that the
//!   sensors measure (a valid depth sample in the noise-free render), every second pixel of
//!   every sensor.

mod common;

use std::sync::OnceLock;

use common::{PointGrid, quantile, scene_distance, shape_sdf, v3};
use geometry::DepthKind;
use geometry::fusion::FusionOptions;
use geometry::fusion::multi::{MultiFusion, SensorImages, fuse_multi};
use geometry::synth::{
    KinectNoise, KinectRing, SynthFrame, apply_kinect_noise, kinect_ring_preset, render_ring,
};
use kfuse_tsdf::{DepthFrame, TsdfMesh, TsdfOptions, TsdfVolume, integrate_multi};
use nalgebra::Vector3;

/// Bar on the noise-free median vertex error, millimetres: 0.1 (measured 0.01 at 5 mm and 0.02
/// at 10 mm voxels). Marching cubes interpolates the along-ray distance, which is linear
/// across a plane's voxels, so the floor's and the box's faces come out exact; the sphere's
/// curvature and the edges are a minority of the vertices. A z/range mix-up, a pose applied
/// the wrong way or a half-voxel offset of the grid costs millimetres.
const CLEAN_MEDIAN_MM: f64 = 0.1;
/// Bar on the noise-free 95th percentile, millimetres: 1.0 (measured 0.46 at both sizes): the
/// box's edges and the sphere's contact with the floor, where the band of one surface reaches
/// the next, a fifth of a 5 mm voxel.
const CLEAN_P95_MM: f64 = 1.0;
/// Bar on the noisy median, millimetres: 0.6 (measured 0.41 at 5 mm, 0.39 at 10 mm); the
/// merged cloud of the same depth has 0.77, and the test also requires the TSDF's median to
/// be below the cloud's.
const NOISY_MEDIAN_MM: f64 = 0.6;
/// Bar on the noisy 95th percentile, millimetres: 3.0 (measured 2.02 at 5 mm, 1.63 at 10 mm;
/// the merged cloud 2.53): the flying pixels at the objects' silhouettes that one sensor alone
/// sees leave fragments within the truncation of the edge.
const NOISY_P95_MM: f64 = 3.0;
/// Bar on completeness: 0.98 (measured 1.000 in every case). One sensor alone reaches 0.88
/// (checked below), so the bar tells a sensor's missing view.
const MIN_COMPLETENESS: f64 = 0.98;
/// Bar on the median colour error, largest channel difference 0–255: 6 (measured 1.0). The
/// textures' stripes and plaid change within a voxel at their edges; a colour taken from the
/// wrong pixel or the wrong camera is off by tens.
const COLOR_MEDIAN_MAX: f64 = 6.0;

/// Matched sets of the several-sets test: 4 (each set is three noisy frames, fused and
/// integrated; 4 keep the debug-build test within seconds). `KFUSE_TSDF_RING_SETS=N` (1–100)
/// runs N instead, for the figure of issue 50's 30 sets.
const SETS: usize = 4;
/// Largest `KFUSE_TSDF_RING_SETS`.
const MAX_SETS: usize = 100;

struct Ring {
    ring: KinectRing,
    clean: Vec<SynthFrame>,
    noisy: Vec<SynthFrame>,
    /// True surface samples, world frame.
    truth: Vec<Vector3<f64>>,
}

fn ring() -> &'static Ring {
    static RING: OnceLock<Ring> = OnceLock::new();
    RING.get_or_init(|| {
        let ring = kinect_ring_preset();
        let clean = render_ring(&ring, None);
        let noisy = render_ring(&ring, Some(&KinectNoise::default()));
        let mut truth = Vec::new();
        for (k, f) in clean.iter().enumerate() {
            let camera = &ring.setups[k].rig.depth;
            let world_from_depth = ring.depth_from_world[k].inverse();
            for v in (0..camera.height).step_by(2) {
                for u in (0..camera.width).step_by(2) {
                    let measured = f.depth.get(u, v).is_finite() && *f.depth.get(u, v) > 0.0;
                    let z = *f.true_depth_z.get(u, v) as f64;
                    if let (true, Some(p)) =
                        (measured, camera.backproject(u as f64, v as f64, z, DepthKind::Z))
                    {
                        truth.push(world_from_depth.apply(&p));
                    }
                }
            }
        }
        Ring { ring, clean, noisy, truth }
    })
}

fn fuse(r: &Ring, frames: &[SynthFrame]) -> MultiFusion {
    let inputs: Vec<SensorImages> = r
        .ring
        .serials
        .iter()
        .zip(frames)
        .map(|(s, f)| SensorImages {
            sensor: s.clone(),
            depth: f.depth.clone(),
            color: f.color.clone(),
        })
        .collect();
    fuse_multi(&r.ring.rig, &inputs, DepthKind::Z, &FusionOptions::default()).unwrap()
}

struct Accuracy {
    median_mm: f64,
    p95_mm: f64,
    completeness: f64,
    vertices: usize,
}

/// Errors of `points` (the rig's reference frame) against the true scene, and the share of
/// the true samples within `2 · voxel` of one of them.
fn accuracy(r: &Ring, points: &[[f32; 3]], voxel: f64) -> Accuracy {
    let world_from_ref = r.ring.depth_from_world[0].inverse();
    let world: Vec<Vector3<f64>> = points.iter().map(|&p| world_from_ref.apply(&v3(p))).collect();
    let mut errors: Vec<f64> = world.iter().map(|p| scene_distance(&r.ring.world, p)).collect();
    let grid = PointGrid::new(world.iter().copied(), 2.0 * voxel);
    let covered = r.truth.iter().filter(|p| grid.nearest_within_cell(p).is_some()).count();
    Accuracy {
        median_mm: quantile(&mut errors, 0.5) * 1e3,
        p95_mm: quantile(&mut errors, 0.95) * 1e3,
        completeness: covered as f64 / r.truth.len() as f64,
        vertices: points.len(),
    }
}

fn tsdf_mesh(fusion: &MultiFusion, voxel: f64) -> TsdfMesh {
    let mut volume = TsdfVolume::new(TsdfOptions::with_voxel_size(voxel)).unwrap();
    integrate_multi(&mut volume, fusion, |_| {}).unwrap();
    volume.extract_mesh()
}

/// Median over the vertices of the largest channel difference, 0–255, between the vertex's
/// colour and the true texture of the surface nearest to it.
fn color_error(r: &Ring, mesh: &TsdfMesh) -> f64 {
    let world_from_ref = r.ring.depth_from_world[0].inverse();
    let mut errors: Vec<f64> = mesh
        .vertices
        .iter()
        .zip(&mesh.colors)
        .map(|(&p, c)| {
            let p = world_from_ref.apply(&v3(p));
            let o = r
                .ring
                .world
                .objects
                .iter()
                .min_by(|a, b| {
                    shape_sdf(&a.shape, &p).abs().total_cmp(&shape_sdf(&b.shape, &p).abs())
                })
                .unwrap();
            let t = o.texture.color_u8(&p);
            (0..3).map(|k| (t[k] as f64 - c[k] as f64).abs()).fold(0.0, f64::max)
        })
        .collect();
    quantile(&mut errors, 0.5)
}

fn tsdf_accuracy(r: &Ring, fusion: &MultiFusion, voxel: f64, label: &str) -> Accuracy {
    let mesh = tsdf_mesh(fusion, voxel);
    let a = accuracy(r, &mesh.vertices, voxel);
    eprintln!(
        "{label}: {} vertices, {} faces, median {:.2} mm, p95 {:.2} mm, completeness {:.3}",
        a.vertices,
        mesh.faces.len(),
        a.median_mm,
        a.p95_mm,
        a.completeness
    );
    a
}

#[test]
fn ring_noise_free() {
    let r = ring();
    let fusion = fuse(r, &r.clean);
    for (voxel, label) in [(0.005, "noise-free, 5 mm"), (0.01, "noise-free, 10 mm")] {
        let a = tsdf_accuracy(r, &fusion, voxel, label);
        assert!(a.median_mm < CLEAN_MEDIAN_MM, "{label}: median {:.3} mm", a.median_mm);
        assert!(a.p95_mm < CLEAN_P95_MM, "{label}: p95 {:.3} mm", a.p95_mm);
        assert!(a.completeness >= MIN_COMPLETENESS, "{label}: {:.3}", a.completeness);
    }
    let mesh = tsdf_mesh(&fusion, 0.01);
    let ce = color_error(r, &mesh);
    eprintln!("colour error (median of the largest channel difference): {ce:.1}");
    assert!(ce <= COLOR_MEDIAN_MAX, "{ce}");
    // One sensor alone sees a part of the scene: completeness must say so.
    let s = &fusion.sensors[0];
    let mut one = TsdfVolume::new(TsdfOptions::with_voxel_size(0.01)).unwrap();
    one.integrate(&DepthFrame {
        camera: &s.rig.depth,
        camera_from_volume: s.depth_from_reference,
        z: &s.z,
        color: None,
    })
    .unwrap();
    let a = accuracy(r, &one.extract_mesh().vertices, 0.01);
    eprintln!("one sensor, 10 mm: completeness {:.3}", a.completeness);
    assert!(a.completeness < MIN_COMPLETENESS, "{}", a.completeness);
}

#[test]
fn ring_noisy_against_the_merged_cloud() {
    let r = ring();
    let fusion = fuse(r, &r.noisy);
    let c = accuracy(r, &fusion.cloud.points, 0.005);
    eprintln!("merged cloud (noisy): median {:.2} mm, p95 {:.2} mm", c.median_mm, c.p95_mm);
    for (voxel, label) in [(0.005, "noisy, 5 mm"), (0.01, "noisy, 10 mm")] {
        let a = tsdf_accuracy(r, &fusion, voxel, label);
        assert!(a.median_mm < NOISY_MEDIAN_MM, "{label}: median {:.3} mm", a.median_mm);
        assert!(
            a.median_mm < c.median_mm,
            "{label}: median {:.3} mm, merged cloud {:.3} mm",
            a.median_mm,
            c.median_mm
        );
        assert!(a.p95_mm < NOISY_P95_MM, "{label}: p95 {:.3} mm", a.p95_mm);
        assert!(a.completeness >= MIN_COMPLETENESS, "{label}: {:.3}", a.completeness);
    }
}

/// Several matched sets of the ring (the same scene, independent noise) integrated into one
/// volume: the noise averages out, so the median and the 95th percentile fall below one set's.
#[test]
fn ring_several_sets_beat_one() {
    let r = ring();
    let sets = std::env::var("KFUSE_TSDF_RING_SETS")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        .filter(|n| (1..=MAX_SETS).contains(n))
        .unwrap_or(SETS);
    let voxel = 0.01;
    let mut volume = TsdfVolume::new(TsdfOptions::with_voxel_size(voxel)).unwrap();
    let mut one = None;
    for set in 0..sets {
        let frames: Vec<SynthFrame> = r
            .clean
            .iter()
            .enumerate()
            .map(|(k, f)| {
                let mut f = f.clone();
                let seed = KinectNoise::default().seed
                    ^ (set as u64 + 1).wrapping_mul(0x9E37_79B9)
                    ^ (k as u64 + 1).wrapping_mul(0x2545_F491);
                apply_kinect_noise(&mut f, &KinectNoise { seed, ..KinectNoise::default() });
                f
            })
            .collect();
        integrate_multi(&mut volume, &fuse(r, &frames), |_| {}).unwrap();
        if set == 0 {
            one = Some(accuracy(r, &volume.extract_mesh().vertices, voxel));
        }
    }
    let one = one.unwrap();
    let all = accuracy(r, &volume.extract_mesh().vertices, voxel);
    eprintln!(
        "10 mm, 1 set: median {:.3} mm, p95 {:.3} mm; {sets} sets: median {:.3} mm, p95 {:.3} mm, completeness {:.3}",
        one.median_mm, one.p95_mm, all.median_mm, all.p95_mm, all.completeness
    );
    if sets > 1 {
        assert!(all.median_mm < one.median_mm, "{} vs {}", all.median_mm, one.median_mm);
        assert!(all.p95_mm < one.p95_mm, "{} vs {}", all.p95_mm, one.p95_mm);
    }
    assert!(all.completeness >= MIN_COMPLETENESS, "{}", all.completeness);
}
