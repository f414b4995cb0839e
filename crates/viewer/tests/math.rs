//! Zoom/pan, the orbit camera and the value under the cursor.

mod common;

use egui::{Pos2, Rect, Vec2};
use nalgebra::{Vector3, Vector4};
use viewer::camera3d::OrbitCamera;
use viewer::panes::{self, Pane};
use viewer::view2d::View2d;
use viewer::{Engine, ViewerApp};

const RECT: Rect = Rect { min: Pos2::new(100.0, 50.0), max: Pos2::new(900.0, 650.0) };

#[test]
fn fitted_view_maps_corners_to_pixel_edges() {
    let v = View2d::default();
    let size = [1920, 1080];
    let r = v.image_rect(RECT, size);
    // Fitted by width: 800 / 1920 points per pixel, centred vertically.
    // 800 = RECT's width (900 − 100); 1e-3: f32 rounding of ~1e3 point coordinates.
    assert!((r.width() - 800.0).abs() < 1e-3 && (r.center().y - RECT.center().y).abs() < 1e-3);
    let [x, y] = v.screen_to_pixel(RECT, size, r.min);
    assert!(
        (x + 0.5).abs() < 1e-3 && (y + 0.5).abs() < 1e-3,
        "top-left edge is pixel (-0.5, -0.5), got ({x}, {y})"
    );
}

#[test]
fn zoom_keeps_the_point_under_the_cursor_and_pan_moves_it() {
    let mut v = View2d::default();
    let size = [512, 424];
    let cursor = Pos2::new(300.0, 200.0);
    let before = v.screen_to_pixel(RECT, size, cursor);
    v.zoom_at(RECT, size, cursor, 4.0);
    let after = v.screen_to_pixel(RECT, size, cursor);
    // f32 rounding of ~1e3 point coordinates: 1e-3 px.
    assert!((before[0] - after[0]).abs() < 1e-3 && (before[1] - after[1]).abs() < 1e-3);
    // The factor passed to zoom_at above, from the default zoom 1 (exact in f32).
    assert_eq!(v.zoom, 4.0);
    let scale = v.scale(RECT, size);
    v.pan(RECT, size, Vec2::new(scale * 10.0, 0.0));
    let panned = v.screen_to_pixel(RECT, size, cursor);
    assert!(
        (panned[0] - (after[0] - 10.0)).abs() < 1e-3,
        "dragging right by 10 px shows pixels 10 to the left"
    );
}

fn project(cam: &OrbitCamera, p: [f32; 3]) -> [f32; 3] {
    let c = cam.view_proj(1.0) * Vector4::new(p[0], p[1], p[2], 1.0);
    [c.x / c.w, c.y / c.w, c.z / c.w]
}

#[test]
fn orbit_camera_starts_at_the_colour_camera_and_projects_like_it() {
    let cam = OrbitCamera::fit([[-1.0, -0.5, 2.0], [1.0, 0.5, 4.0]].into_iter()).unwrap();
    assert_eq!(cam.eye(), [0.0, 0.0, 0.0]);
    // The target is at the view's centre, inside the depth range.
    let t = project(&cam, cam.target);
    // 1e-6: f32 rounding of an NDC coordinate that is exactly 0 for the target; (0, 1): the
    // depth range of wgpu's clip space.
    assert!(t[0].abs() < 1e-6 && t[1].abs() < 1e-6 && t[2] > 0.0 && t[2] < 1.0);
    // x right stays right; y down (camera frame) is down on screen (NDC y up).
    let r = project(&cam, [0.5, 0.0, 3.0]);
    let d = project(&cam, [0.0, 0.5, 3.0]);
    assert!(r[0] > 0.0 && d[1] < 0.0, "right {r:?}, down {d:?}");
    // Nearer points get smaller depth values.
    assert!(project(&cam, [0.0, 0.0, 2.0])[2] < project(&cam, [0.0, 0.0, 3.5])[2]);
}

#[test]
fn orbit_keeps_distance_zoom_changes_it_pan_moves_target() {
    let mut cam = OrbitCamera::fit([[0.0, 0.0, 3.0]].into_iter()).unwrap();
    cam.orbit(200.0, -100.0);
    let e = Vector3::from(cam.eye());
    // 3.0: the fitted point's distance; 1e-5 m ≈ 30 f32 ulps at 3 m (trig and a norm).
    assert!(((e - Vector3::from(cam.target)).norm() - 3.0).abs() < 1e-5);
    // 200 points × ORBIT_RAD_PER_POINT (0.0035) = 0.7 rad of yaw: the eye moves ≈ 3 · sin 0.7 ≈
    // 1.9 m sideways; 0.1 m only asks for a visible move.
    assert!(e.x.abs() > 0.1, "orbiting moved the eye sideways: {e:?}");
    cam.zoom(100.0);
    assert!(cam.distance < 3.0);
    let t0 = cam.target;
    cam.pan(50.0, 0.0, 600.0);
    assert_ne!(cam.target, t0);
    // Panning moves perpendicular to the view direction: distance unchanged.
    let d = cam.distance;
    // 1e-4 m: f32 rounding of a < 3 m distance after a pan (a few ops, ~1e-6 each), with margin.
    assert!(((Vector3::from(cam.eye()) - Vector3::from(cam.target)).norm() - d).abs() < 1e-4);
}

#[test]
fn probe_reports_depth_and_a_point_that_projects_back() {
    let (frame, _) = common::synth_frame();
    let app = ViewerApp::with_frame(frame.clone(), Engine::Cpu);
    let fused = app.fused.as_ref().unwrap();
    // Depth grid: the input depth itself.
    let (u, v) = (256usize, 212usize);
    let z = *frame.depth.get(u, v);
    assert!(z.is_finite());
    let p = panes::probe(Pane::Depth, frame, fused, u as f32 + 0.3, v as f32 - 0.2).unwrap();
    assert_eq!(p.pixel, [u, v]);
    // mm printed from f32 metres: 1e-3 mm.
    assert!((p.depth_mm.unwrap() - z * 1000.0).abs() < 1e-3);
    let q = p.point.unwrap();
    let back = frame.rig.depth.project(&Vector3::new(q[0], q[1], q[2])).unwrap();
    // Back-projection then projection through the distortion model: 1e-6 px.
    assert!((back.x - u as f64).abs() < 1e-6 && (back.y - v as f64).abs() < 1e-6);
    // Colour grid: the registered depth, the point in the colour frame.
    let (cu, cv) = (960usize, 540usize);
    let p = panes::probe(Pane::Blend, frame, fused, cu as f32, cv as f32).unwrap();
    let zc = *fused.shown_depth.get(cu, cv);
    assert!((p.depth_mm.unwrap() - zc * 1000.0).abs() < 1e-3);
    let q = p.point.unwrap();
    // The point's z is the registered depth itself (f32 → f64): 1e-6 m covers the f32 value.
    assert!((q[2] - zc as f64).abs() < 1e-6);
    let back = frame.rig.color.project(&Vector3::new(q[0], q[1], q[2])).unwrap();
    assert!((back.x - cu as f64).abs() < 1e-6 && (back.y - cv as f64).abs() < 1e-6);
    // Outside the image: nothing.
    assert!(panes::probe(Pane::Color, frame, fused, -3.0, 10.0).is_none());
}

#[test]
fn overlays_mix_both_images() {
    let (frame, _) = common::synth_frame();
    let app = ViewerApp::with_frame(frame.clone(), Engine::Cpu);
    let fused = app.fused.as_ref().unwrap();
    let (checker, range) = panes::render(Pane::Checker, frame, fused);
    let range = range.unwrap();
    let depth = panes::depth_colors(&fused.shown_depth, range);
    // Square (0, 0) is colour, square (1, 0) is depth.
    assert_eq!(checker.get(10, 10), frame.color.get(10, 10));
    let x = panes::CHECKER_PX + 10;
    assert_eq!(checker.get(x, 10), depth.get(x, 10));
    let (blend, _) = panes::render(Pane::Blend, frame, fused);
    let (u, v) = (960, 540);
    let c = frame.color.get(u, v);
    let d = depth.get(u, v);
    for k in 0..3 {
        let want = (0.5 * c[k] as f32 + 0.5 * d[k] as f32).round() as i32;
        // 1: one u8 rounding step (the pane mixes with BLEND_ALPHA in its own order of terms).
        assert!((blend.get(u, v)[k] as i32 - want).abs() <= 1);
    }
    let (holes, _) = panes::render(Pane::Holes, frame, fused);
    // [255, 40, 40]: the Holes pane's hole colour (panes::render, Pane::Holes).
    let red = holes.data().iter().filter(|p| **p == [255, 40, 40]).count();
    assert_eq!(red, fused.output.hole_mask.data().iter().filter(|&&m| m).count());
}
