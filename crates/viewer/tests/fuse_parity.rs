//! The 3D view's default mesh is `kfuse fuse`'s default mesh: the viewer's drawn geometry
//! against `geometry::fusion::run` with `FusionOptions::default()` (what `fuse` runs without
//! flags), on the synthetic Kinect scene and on the bundled `data/kinect` capture.

mod common;

use std::path::PathBuf;

use geometry::fusion::{self, FusionOptions};
use geometry::{DepthKind, Image, Mesh, Rig};
use viewer::pipeline::{MeshGrid, Toggles};
use viewer::{Engine, ViewerApp};

/// Largest vertex position difference tolerated, metres: both sides run the same f32
/// arithmetic on the same samples, so they should agree to the bit; 1e-6 m (a micrometre,
/// ~10 f32 ulps at 5 m) only absorbs a different summation order, while the H3-grid mesh or
/// a shifted grid differs by millimetres.
const POSITION_TOLERANCE_M: f32 = 1e-6;

/// The reference: the `fuse` pipeline's default run on the same inputs.
fn fuse_default(
    rig: &Rig,
    depth: &Image<f32>,
    kind: DepthKind,
    color: &Image<[u8; 3]>,
) -> (Mesh, Mesh) {
    let out = fusion::run(rig, depth, kind, color, &FusionOptions::default()).expect("fusion runs");
    (out.mesh, out.mesh_clean)
}

/// Asserts that the viewer draws `reference` (same faces, positions within the tolerance);
/// returns the largest position difference.
fn assert_draws(app: &ViewerApp, reference: &Mesh, what: &str) -> f32 {
    let g = app.geometry().expect("the viewer fused the frame");
    assert_eq!(g.vertices.len(), reference.vertices.len(), "{what}: vertex count");
    assert_eq!(g.indices.len(), 3 * reference.faces.len(), "{what}: face count");
    let faces: Vec<u32> = reference.faces.iter().flatten().copied().collect();
    assert!(g.indices == faces, "{what}: the faces differ");
    let mut worst = 0.0f32;
    for (v, r) in g.vertices.iter().zip(&reference.vertices) {
        for (a, b) in v.pos.iter().zip(r) {
            worst = worst.max((a - b).abs());
        }
    }
    assert!(worst <= POSITION_TOLERANCE_M, "{what}: vertices differ by up to {worst} m");
    worst
}

fn check(
    app: &mut ViewerApp,
    rig: &Rig,
    depth: &Image<f32>,
    kind: DepthKind,
    color: &Image<[u8; 3]>,
    scene: &str,
) {
    assert_eq!(app.toggles.mesh_grid, MeshGrid::Depth, "the depth grid is the default");
    let (mesh, clean) = fuse_default(rig, depth, kind, color);
    // Guard against comparing two empty meshes: both scenes fill most of the 512 × 424 view
    // (a full grid has 2 · 511 · 423 = 432 306 faces).
    assert!(clean.faces.len() > 100_000, "{scene}: {} faces", clean.faces.len());
    let worst = assert_draws(app, &clean, &format!("{scene}, H5 mesh"));
    eprintln!(
        "{scene}: viewer = fuse: {} vertices, {} faces, worst position difference {worst} m",
        clean.vertices.len(),
        clean.faces.len()
    );
    // Edge-face removal off: H4's mesh of the same run.
    app.set_toggles(Toggles { remove_edges: false, ..app.toggles });
    assert_draws(app, &mesh, &format!("{scene}, H4 mesh"));
    // The H3-grid mesh is a different mesh (the choice is real).
    app.set_toggles(Toggles { remove_edges: true, mesh_grid: MeshGrid::Color, ..app.toggles });
    let g = app.geometry().unwrap();
    assert_ne!(g.vertices.len(), clean.vertices.len(), "{scene}: H3-grid mesh");
}

#[test]
fn default_mesh_is_fuses_mesh_on_the_synthetic_scene() {
    let (frame, _) = common::synth_frame();
    let mut app = ViewerApp::with_frame(frame.clone(), Engine::Cpu);
    check(&mut app, &frame.rig, &frame.depth, frame.kind, &frame.color, "synthetic scene");
}

fn bundled_kinect() -> PathBuf {
    manifest_dir().join("../../data/kinect")
}

#[test]
fn default_mesh_is_fuses_mesh_on_the_bundled_capture() {
    let dir = bundled_kinect();
    // The inputs read here as `kfuse fuse --rig rig.json --color desk_color.jpg --depth
    // desk_depth.png` reads them (z, 16-bit millimetres), independently of the viewer's loader.
    let rig = kfuse_io::rig::read_pair(&dir.join("rig.json")).unwrap();
    let color = kfuse_io::images::read_color(&dir.join("desk_color.jpg")).unwrap();
    let depth =
        kfuse_io::images::read_depth(&dir.join("desk_depth.png"), kfuse_io::images::MILLIMETRES)
            .unwrap();
    let mut app = ViewerApp::open(&dir, Engine::Cpu);
    assert!(app.fused.is_some(), "the viewer opens {}: {:?}", dir.display(), app.error);
    check(&mut app, &rig, &depth, DepthKind::Z, &color, "data/kinect");
}

/// This package's folder from the `CARGO_MANIFEST_DIR` cargo sets when it runs the test, not
/// the path compiled in: a test binary reused from a checkout at another path (a shared target
/// directory) must read this checkout's files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map(std::path::PathBuf::from).expect("run by cargo test")
}
