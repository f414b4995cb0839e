//! Several Kinects on the GPU (issue 32): `fuse_multi_on` with the per-pixel stages of every
//! sensor on a `FusionContext` against `fuse_multi` on the CPU, and the z-buffer across the
//! sensors (one atomic-min buffer, cleared before the first sensor only) against the CPU's,
//! into every camera of the simulated 3-Kinect ring.
//!
//! Tolerance: none (see `parity_run.rs`: every GPU stage mirrors its CPU twin, lavapipe fuses
//! no multiply-adds), so every image, cloud and consistency figure must be bit-identical.

mod common;

use common::context_or_skip;
use geometry::fusion::multi::{MultiFusion, SensorImages, fuse_multi, fuse_multi_on};
use geometry::fusion::{CpuPixels, DepthView, FusionOptions, PerPixel};
use geometry::synth::{KinectNoise, KinectRing, kinect_ring_preset, render_ring};
use geometry::{DepthKind, Image};

fn bits(img: &Image<f32>) -> Vec<u32> {
    img.data().iter().map(|z| z.to_bits()).collect()
}

fn ring() -> (KinectRing, Vec<SensorImages>) {
    let ring = kinect_ring_preset();
    let frames = render_ring(&ring, Some(&KinectNoise::default()));
    let inputs = ring
        .serials
        .iter()
        .zip(frames)
        .map(|(s, f)| SensorImages { sensor: s.clone(), depth: f.depth, color: f.color })
        .collect();
    (ring, inputs)
}

fn assert_same_fusion(cpu: &MultiFusion, gpu: &MultiFusion) {
    assert_eq!(cpu.sensors.len(), gpu.sensors.len());
    for (c, g) in cpu.sensors.iter().zip(&gpu.sensors) {
        let point_bits = |s: &[[f32; 3]]| s.iter().flat_map(|p| p.map(f32::to_bits)).collect();
        let (pc, pg): (Vec<u32>, Vec<u32>) = (point_bits(&c.points), point_bits(&g.points));
        assert_eq!(pc, pg, "{}: H1 points", c.sensor);
        assert_eq!(c.pixels, g.pixels, "{}: H1 pixels", c.sensor);
        assert_eq!(c.colors, g.colors, "{}: H6 colours of the points", c.sensor);
        assert_eq!(c.color_valid.data(), g.color_valid.data(), "{}: H6 valid", c.sensor);
        assert_eq!(c.kept, g.kept, "{}: best-seeing rule", c.sensor);
        // Thousands of coloured points per sensor: the comparison is not of empty clouds.
        let coloured = c.color_valid.data().iter().filter(|v| **v).count();
        assert!(c.points.len() > 50_000 && coloured > 20_000, "{}: {coloured}", c.sensor);
    }
    assert_eq!(cpu.cloud, gpu.cloud, "merged cloud");
    assert_eq!(cpu.cloud_sensor, gpu.cloud_sensor);
    for (c, g) in cpu.consistency.iter().zip(&gpu.consistency) {
        assert_eq!(c.pixels, g.pixels, "{c:?} {g:?}");
        assert_eq!(c.tile_median_mm.to_bits(), g.tile_median_mm.to_bits(), "{c:?} {g:?}");
    }
}

#[test]
fn several_kinects_fuse_and_zbuffer_bit_identically_on_the_gpu() {
    let Some(mut ctx) =
        context_or_skip("several_kinects_fuse_and_zbuffer_bit_identically_on_the_gpu")
    else {
        return;
    };
    let (ring, inputs) = ring();
    let options = FusionOptions::default();
    let cpu = fuse_multi(&ring.rig, &inputs, DepthKind::Z, &options).unwrap();
    let gpu = fuse_multi_on(&mut ctx, &ring.rig, &inputs, DepthKind::Z, &options).unwrap();
    assert_same_fusion(&cpu, &gpu);

    let last = cpu.sensors.len() - 1;
    for camera in &ring.rig.cameras {
        let want = cpu.zbuffer_into(camera);
        let got = cpu.zbuffer_into_on(&mut ctx, camera).unwrap();
        let differing = bits(&want).iter().zip(bits(&got)).filter(|(a, b)| **a != *b).count();
        let landed = want.data().iter().filter(|z| z.is_finite()).count();
        println!("{}: {landed} pixels z-buffered, {differing} differ", camera.name);
        assert_eq!(differing, 0, "{}", camera.name);
        // The CPU engine's own zbuffer_views is the same image.
        assert_eq!(bits(&cpu.zbuffer_into_on(&mut CpuPixels::new(), camera).unwrap()), bits(&want));
        // Across the sensors, not only the last one submitted (a clear before every sensor
        // would leave the last sensor's samples alone): more pixels than the last sensor's,
        // by thousands where the camera is another sensor's (the last sensor's own cameras
        // gain only the few hundred pixels the others see past its silhouettes).
        let last_only = cpu.zbuffer_of_sensors(camera, &[last]);
        let last_landed = last_only.data().iter().filter(|z| z.is_finite()).count();
        let margin = if camera.sensor.as_deref() == Some(cpu.sensors[last].sensor.as_str()) {
            1
        } else {
            10_000
        };
        assert!(landed >= last_landed + margin, "{}: {landed} vs {last_landed}", camera.name);
    }
}

#[test]
fn views_of_another_size_and_no_views_are_handled() {
    let Some(mut ctx) = context_or_skip("views_of_another_size_and_no_views_are_handled") else {
        return;
    };
    let (ring, inputs) = ring();
    let (pair, _) = ring.rig.sensor_rig(&ring.serials[0]).unwrap();
    // No views: the empty z-buffer of the camera's size, as on the CPU.
    let none = ctx.zbuffer_views(&pair.color, &[], DepthKind::Z).unwrap();
    assert_eq!(none.size(), (pair.color.width, pair.color.height));
    assert_eq!(
        bits(&none),
        bits(&CpuPixels::new().zbuffer_views(&pair.color, &[], DepthKind::Z).unwrap())
    );
    // A depth image of the wrong size is an error naming it, on both engines.
    let small = Image::filled(10, 10, 1.0f32);
    let view = DepthView {
        depth_camera: &pair.depth,
        depth: &small,
        camera_from_depth: pair.color_from_depth,
    };
    let gpu = ctx.zbuffer_views(&pair.color, &[view], DepthKind::Z).unwrap_err().to_string();
    let cpu =
        CpuPixels::new().zbuffer_views(&pair.color, &[view], DepthKind::Z).unwrap_err().to_string();
    assert!(gpu.contains("depth image") && gpu.contains("10x10"), "{gpu}");
    assert!(cpu.contains("depth image") && cpu.contains("10x10"), "{cpu}");
    // The context stays usable: one sensor into its own colour camera is its registration.
    let view = DepthView {
        depth_camera: &pair.depth,
        depth: &inputs[0].depth,
        camera_from_depth: pair.color_from_depth,
    };
    let one = ctx.zbuffer_views(&pair.color, &[view], DepthKind::Z).unwrap();
    let reg = ctx.register(&pair, &inputs[0].depth, DepthKind::Z, false).unwrap();
    assert_eq!(bits(&one), bits(&reg.zbuffer));
}
