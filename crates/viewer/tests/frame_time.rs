//! Frame time of the 3D view on the Kinect-size textured mesh (printed for BENCHMARKS.md; no
//! wall-clock assert). Also checks that the mesh covers most of the initial view.

mod common;

use std::time::Instant;

use egui_kittest::wgpu::{create_render_state, default_wgpu_setup};
use viewer::camera3d::OrbitCamera;
use viewer::render3d::{DrawParams, OFFSCREEN_FORMAT, SceneGpu};
use viewer::{Engine, ViewerApp};

/// Viewport of the measurement, pixels (a typical laptop window's 3D pane).
const W: u32 = 1280;
const H: u32 = 720;
const FRAMES: u32 = 10;

#[test]
fn frame_time_kinect_textured_mesh() {
    if !common::gpu_available("frame_time_kinect_textured_mesh") {
        return;
    }
    let app = ViewerApp::with_frame(common::synth_frame().0.clone(), Engine::Cpu);
    let geometry = app.geometry().unwrap().clone();
    let state = create_render_state(default_wgpu_setup(), egui_wgpu::RendererOptions::PREDICTABLE);
    let (device, queue) = (&state.device, &state.queue);
    let mut scene = SceneGpu::new(device, OFFSCREEN_FORMAT);
    let t = Instant::now();
    scene.upload(device, queue, &geometry);
    let upload_ms = t.elapsed().as_secs_f64() * 1e3;
    let mut cam = OrbitCamera::fit(geometry.vertices.iter().map(|v| v.pos)).unwrap();
    let mut frame = |cam: &OrbitCamera| {
        let params = DrawParams {
            view_proj: cam.view_proj(W as f32 / H as f32).into(),
            points: false,
            mesh: true,
        };
        let mut enc = device.create_command_encoder(&Default::default());
        scene.draw(device, queue, &mut enc, &params, [W, H]);
        let i = queue.submit([enc.finish()]);
        device.poll(wgpu::PollType::Wait { submission_index: Some(i), timeout: None }).unwrap();
    };
    frame(&cam);
    let t = Instant::now();
    for _ in 0..FRAMES {
        cam.orbit(3.0, 0.0);
        frame(&cam);
    }
    let ms = t.elapsed().as_secs_f64() * 1e3 / FRAMES as f64;
    let (_, tris) = scene.uploaded_counts();
    println!(
        "3D view frame time: {ms:.2} ms/frame ({tris} textured triangles, {} vertices, {W}x{H}, adapter {}); upload {upload_ms:.1} ms",
        geometry.vertices.len(),
        state.adapter.get_info().name
    );
    assert_eq!(tris as usize, app.drawn_triangles());

    // Read the last frame back: the scene fills most of the view from the camera's viewpoint.
    let tex = scene.offscreen().unwrap();
    let buf = device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: (W * H * 4) as u64,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut enc = device.create_command_encoder(&Default::default());
    enc.copy_texture_to_buffer(
        tex.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &buf,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(W * 4),
                rows_per_image: Some(H),
            },
        },
        wgpu::Extent3d { width: W, height: H, depth_or_array_layers: 1 },
    );
    let i = queue.submit([enc.finish()]);
    buf.slice(..).map_async(wgpu::MapMode::Read, |_| {});
    device.poll(wgpu::PollType::Wait { submission_index: Some(i), timeout: None }).unwrap();
    let data = buf.slice(..).get_mapped_range().expect("mapped above");
    let bg = viewer::render3d::BACKGROUND.map(|c| (c * 255.0).round() as u8);
    let covered = data
        .chunks(4)
        // ±2 per channel: the clear colour BACKGROUND (e.g. 0.08 · 255 = 20.4) is stored by the
        // Rgba8Unorm target with its own rounding; a mesh pixel differs far more than that.
        .filter(|p| {
            (p[0] as i32 - bg[0] as i32).abs() > 2
                || (p[1] as i32 - bg[1] as i32).abs() > 2
                || (p[2] as i32 - bg[2] as i32).abs() > 2
        })
        .count();
    let frac = covered as f64 / (W * H) as f64;
    println!("mesh covers {:.1} % of the view", frac * 100.0);
    // The scene's wall spans the whole colour view; orbiting 30 points (~6°) keeps most of it.
    // 10 orbits of 3 points × ORBIT_RAD_PER_POINT (0.0035) = 0.105 rad ≈ 6°; 0.5: "most".
    assert!(frac > 0.5, "mesh covers only {frac:.3} of the view");
}
