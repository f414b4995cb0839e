//! The rig page on a rig of several cameras: three Kinects on a ring of radius 1.5 m around a
//! point 1.5 m in front of the reference sensor, all facing it, with a merged cloud (a
//! coloured sphere at the centre). The page's camera centres are checked against the ring's
//! formula (written here, independent of the rig code), the folder and file openings and their
//! errors, and a snapshot (wgpu on lavapipe) of what `kfuse view` shows.

mod common;

use std::path::{Path, PathBuf};

use egui_kittest::wgpu::{WgpuTestRenderer, create_render_state, default_wgpu_setup};
use egui_kittest::{Harness, SnapshotOptions};
use geometry::{MultiRig, PointCloud, RigidTransform};
use nalgebra::{Rotation3, Vector3};
use viewer::{Engine, Page, ViewerApp};

const SIZE: egui::Vec2 = egui::Vec2::new(1000.0, 620.0);
/// As in ui.rs: colour distance 2 absorbs lavapipe vs GPU rasterisation differences.
const PIXEL_THRESHOLD: f32 = 2.0;
/// Differing pixels tolerated: the page is egui's 2D painter only (lines, squares, text), as
/// the calibration page, whose snapshots measured 0 of 620 000 on lavapipe; 8 leaves room
/// for anti-aliased edge pixels while one changed digit of a label differs in ≥ 20.
const FAILED_PIXELS: usize = 8;

/// Ring radius and the centre's distance in front of the reference sensor, metres.
const RING_RADIUS_M: f64 = 1.5;

/// Sensor k's depth-camera centre in the reference (sensor 0's depth) frame: the ring's centre
/// is at (0, 0, R); sensor k sits at angle 120°·k around the y axis through it.
fn ring_centre(k: usize) -> Vector3<f64> {
    let a = (k as f64) * 2.0 * std::f64::consts::PI / 3.0;
    Vector3::new(-RING_RADIUS_M * a.sin(), 0.0, RING_RADIUS_M * (1.0 - a.cos()))
}

fn ring_rig() -> MultiRig {
    let pair = geometry::synth::kinect_rig();
    let mut cameras = Vec::new();
    for (k, serial) in ["S0", "S1", "S2"].iter().enumerate() {
        let a = (k as f64) * 2.0 * std::f64::consts::PI / 3.0;
        // reference_from_sensor: turned by a about y, so its z axis (sin a, 0, cos a) points
        // from ring_centre(k) at the centre (0, 0, R).
        let r = Rotation3::from_axis_angle(&Vector3::y_axis(), a);
        let reference_from_sensor = RigidTransform::new(r, ring_centre(k));
        let sensor_from_reference = reference_from_sensor.inverse();
        for mut c in MultiRig::from_pair(&pair, Some(serial)).cameras {
            c.camera_from_reference = c.camera_from_reference.compose(&sensor_from_reference);
            cameras.push(c);
        }
    }
    MultiRig { reference: "S0.depth".into(), cameras, calibration: None, rectified: false }
}

/// A sphere of radius 0.3 m at the ring's centre, coloured by direction.
fn sphere_cloud() -> PointCloud {
    let mut cloud = PointCloud::default();
    for i in 0..60 {
        for j in 0..120 {
            let th = std::f64::consts::PI * (i as f64 + 0.5) / 60.0;
            let ph = 2.0 * std::f64::consts::PI * j as f64 / 120.0;
            let d = Vector3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin());
            let p = Vector3::new(0.0, 0.0, RING_RADIUS_M) + d * 0.3;
            cloud.points.push([p.x as f32, p.y as f32, p.z as f32]);
            let c = |x: f64| (127.5 + 127.0 * x) as u8;
            cloud.colors.push([c(d.x), c(d.y), c(d.z)]);
        }
    }
    cloud
}

/// A fixed folder (the page shows the rig's path, so the snapshot needs it stable), written
/// once per test process: the tests of this file run in parallel and read it at the same time,
/// and a second writer removing it under a reader made the cloud comparison fail at random.
fn rig_folder() -> PathBuf {
    static FOLDER: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    FOLDER
        .get_or_init(|| {
            let dir = std::env::temp_dir().join("kfuse-viewer-test-rig-page");
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).unwrap();
            kfuse_io::rig::write_multi_rig(&dir.join("rig.json"), &ring_rig()).unwrap();
            let cloud = dir.join("cloud.ply");
            kfuse_io::ply::write_cloud_ply(&cloud, &sphere_cloud(), "S0.depth").unwrap();
            dir
        })
        .clone()
}

#[test]
fn rig_page_shows_every_camera_at_its_ring_position() {
    let dir = rig_folder();
    let app = ViewerApp::open(&dir, Engine::Cpu);
    assert!(app.error.is_none(), "{:?}", app.error.as_ref().map(|e| e.to_string()));
    assert_eq!(app.page, Page::Rig);
    assert_eq!(app.pages(), vec![Page::Rig]);
    let page = app.rig.as_ref().unwrap();
    let frusta = page.frusta();
    assert_eq!(frusta.len(), 6);
    for (k, serial) in ["S0", "S1", "S2"].iter().enumerate() {
        let (_, _, centre, _) =
            frusta.iter().find(|f| f.0 == format!("{serial}.depth")).expect("depth camera drawn");
        // Two compositions of f64 poses: far under a micrometre.
        assert!((centre - ring_centre(k)).norm() < 1e-9, "{serial}: {centre:?}");
    }
    // Each depth frustum points at the ring's centre: the mean of its corners lies on the
    // line from its centre to (0, 0, R), within 1 mm per metre (the principal point is off
    // the image centre by a few pixels, 1.7 % of the focal length at most).
    for (name, _, centre, corners) in frusta.iter().filter(|f| f.0.ends_with("depth")) {
        let mid = corners.iter().fold(Vector3::zeros(), |a, c| a + c) / 4.0;
        let to_centre = (Vector3::new(0.0, 0.0, RING_RADIUS_M) - centre).normalize();
        let dir = (mid - centre).normalize();
        assert!(to_centre.dot(&dir) > 0.999, "{name} looks along {dir:?}, not {to_centre:?}");
    }
    // Every point of the 7 200 fits under MAX_DRAWN_POINTS: all are kept, in file order.
    assert_eq!(page.cloud, sphere_cloud());
    // The same page from the rig file alone, without the cloud.
    let app = ViewerApp::open(&dir.join("rig.json"), Engine::Cpu);
    assert_eq!(app.page, Page::Rig);
    assert!(app.rig.as_ref().unwrap().cloud.is_empty());
}

/// `kfuse fuse --tsdf`'s surface beside the merged cloud: read, drawn instead of the cloud by
/// default, the checkbox's state switching back; a broken one is an error naming it.
#[test]
fn tsdf_surface_is_shown_instead_of_the_cloud() {
    let dir = std::env::temp_dir().join(format!("kfuse-viewer-rig-tsdf-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    kfuse_io::rig::write_multi_rig(&dir.join("rig.json"), &ring_rig()).unwrap();
    kfuse_io::ply::write_cloud_ply(&dir.join("cloud.ply"), &sphere_cloud(), "S0.depth").unwrap();
    // The surface: every other point of the sphere, drawn grey (a different cloud).
    let mut surface = sphere_cloud();
    surface.points = surface.points.into_iter().step_by(2).collect();
    surface.colors = vec![[128, 128, 128]; surface.points.len()];
    kfuse_io::ply::write_cloud_ply(&dir.join("tsdf_cloud.ply"), &surface, "S0.depth").unwrap();
    let mut app = ViewerApp::open(&dir, Engine::Cpu);
    assert!(app.error.is_none(), "{:?}", app.error.as_ref().map(|e| e.to_string()));
    let page = app.rig.as_mut().unwrap();
    assert_eq!(page.surface, surface);
    assert_eq!(page.cloud, sphere_cloud());
    assert!(page.show_surface);
    assert_eq!(page.drawn_points(), &surface);
    page.show_surface = false;
    assert_eq!(page.drawn_points(), &sphere_cloud());
    let bytes = std::fs::read(dir.join("tsdf_cloud.ply")).unwrap();
    std::fs::write(dir.join("tsdf_cloud.ply"), &bytes[..bytes.len() / 2]).unwrap();
    let app = ViewerApp::open(&dir, Engine::Cpu);
    let e = app.error.as_ref().map(|e| e.to_string()).unwrap_or_default();
    assert!(e.contains("tsdf_cloud.ply") && e.contains("cut short"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn broken_cloud_is_an_error_naming_it() {
    let dir = std::env::temp_dir().join(format!("kfuse-viewer-rig-broken-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    kfuse_io::rig::write_multi_rig(&dir.join("rig.json"), &ring_rig()).unwrap();
    kfuse_io::ply::write_cloud_ply(&dir.join("cloud.ply"), &sphere_cloud(), "S0.depth").unwrap();
    let bytes = std::fs::read(dir.join("cloud.ply")).unwrap();
    std::fs::write(dir.join("cloud.ply"), &bytes[..bytes.len() / 2]).unwrap();
    let app = ViewerApp::open(&dir, Engine::Cpu);
    let e = app.error.as_ref().map(|e| e.to_string()).unwrap_or_default();
    assert!(e.contains("cloud.ply") && e.contains("cut short"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

fn harness(test: &str, app: ViewerApp) -> Option<Harness<'static, ViewerApp>> {
    if !common::gpu_available(test) {
        return None;
    }
    let state = create_render_state(default_wgpu_setup(), egui_wgpu::RendererOptions::PREDICTABLE);
    let mut h = Harness::builder()
        .with_size(SIZE)
        .renderer(WgpuTestRenderer::from_render_state(state))
        .build_ui_state(|ui, app: &mut ViewerApp| app.ui(ui), app);
    h.run();
    Some(h)
}

#[test]
fn rig_page_snapshot() {
    let dir: &Path = &rig_folder();
    let Some(mut h) = harness("rig_page_snapshot", ViewerApp::open(dir, Engine::Cpu)) else {
        return;
    };
    h.snapshot_options(
        "rig_page",
        &SnapshotOptions::new().threshold(PIXEL_THRESHOLD).max_failed_pixels(FAILED_PIXELS),
    );
}
