//! A `kfuse fuse --mat KinectData.mat --color Colour_rect.tif --depth Depth_rect.tif` output
//! reopens in the viewer with exactly what `fuse` used: the rig of the lab's `KinectData.mat`
//! (read as `fuse` reads it, not with the course reader, which refuses the file) and the
//! colour and depth files that replaced the file's images, as its summary.json names them.
//! (`tests/cli_handout.rs` checks the same against the real `kfuse fuse` binary's output.)

use std::path::Path;

use geometry::fusion::{self, FusionOptions};
use geometry::synth;
use geometry::testdata::shared_data_or_skip;
use geometry::{DepthKind, Image};
use kfuse_io::kinect_data::{KinectDepth, read_kinect_data};
use kfuse_io::raster::{Raster, RasterFormat, write_raster};
use viewer::data::open_folder_with;
use viewer::{Engine, ViewerApp, ViewerError};

/// Depth as the handout's Depth_rect.tif holds it: uint16 millimetres of z, 0 = no sample
/// (`images::depth_to_mm`, what tests/cli_handout.rs writes).
fn depth_mm(z: &Image<f32>) -> Image<u16> {
    let (w, h) = z.size();
    Image::from_vec(w, h, kfuse_io::images::depth_to_mm(z)).unwrap()
}

/// A fuse output folder whose summary.json records `inputs` as `kfuse fuse --mat` writes them.
fn fused_with(dir: &Path, inputs: serde_json::Value) -> std::path::PathBuf {
    let fused = dir.join("fused");
    std::fs::create_dir_all(&fused).unwrap();
    let summary = serde_json::json!({"format": "kfuse-fuse-summary", "inputs": inputs});
    std::fs::write(fused.join("summary.json"), summary.to_string()).unwrap();
    fused
}

#[test]
fn kinect_data_mat_output_reopens_with_the_images_that_replaced_the_files() {
    let test = "kinect_data_mat_output_reopens_with_the_images_that_replaced_the_files";
    let Some(data) = shared_data_or_skip(test) else { return };
    let mat = data.join("kinect-lab").join("KinectData.mat");
    let kd = read_kinect_data(&mat).unwrap();
    // The shared copy's 'Depth' is an 8-bit picture, not measurements: only the replacing
    // depth file can be what fuse used.
    assert!(matches!(kd.depth, KinectDepth::Unusable(_)), "the file's own Depth is usable");
    // The handout's rectified images: the Kinect preset rendered with the file's own rig (as in
    // tests/cli_handout.rs).
    let mut setup = synth::kinect_preset(false);
    setup.rig = kd.rig.clone();
    let truth = synth::render(&setup);
    let tmp = tempfile::tempdir().unwrap();
    let colour = tmp.path().join("Colour_rect.tif");
    write_raster(&colour, &Raster::Rgb8(truth.color.clone()), RasterFormat::Tiff).unwrap();
    let depth = tmp.path().join("Depth_rect.tif");
    let mm = depth_mm(&truth.depth);
    write_raster(&depth, &Raster::Gray16(mm.clone()), RasterFormat::Tiff).unwrap();
    let fused = fused_with(
        tmp.path(),
        serde_json::json!({"mat": mat, "color": colour, "depth": depth,
            "depth_scale_m_per_unit": 0.001, "depth_kind": "z", "rectified": false}),
    );

    let (frame, warnings) = open_folder_with(&fused, false).expect("the output reopens");
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(frame.kind, DepthKind::Z);
    // The file's rig, unchanged.
    assert_eq!(frame.rig.depth.intrinsics, kd.rig.depth.intrinsics);
    assert_eq!(frame.rig.color.intrinsics, kd.rig.color.intrinsics);
    assert_eq!(frame.rig.color_from_depth.translation, kd.rig.color_from_depth.translation);
    // The replacing colour (1920 × 1080, lossless TIFF): every pixel.
    assert_eq!(frame.color.size(), truth.color.size());
    assert!(frame.color.data() == truth.color.data(), "colour is not Colour_rect.tif");
    // The replacing depth: every sample is the file's millimetres in metres (f32 of mm/1000,
    // the reader's conversion), 0 / NaN where the file has 0.
    assert_eq!(frame.depth.size(), mm.size());
    let mut valid = 0;
    for (got, &want) in frame.depth.data().iter().zip(mm.data()) {
        if want == 0 {
            assert!(!(*got > 0.0), "a sample where Depth_rect.tif has none: {got}");
        } else {
            valid += 1;
            let want_m = (f64::from(want) * 1e-3) as f32;
            assert!((got - want_m).abs() <= 1e-6, "{got} m for {want} mm");
        }
    }
    // Guard: the preset's wall fills the view (512 × 424 = 217 088 pixels).
    assert!(valid > 150_000, "{valid}");

    // The 3D view draws the mesh `fuse` makes of those inputs (its default mesh).
    let reference =
        fusion::run(&kd.rig, &frame.depth, DepthKind::Z, &truth.color, &FusionOptions::default())
            .unwrap();
    let app = ViewerApp::open_with(&fused, Engine::Cpu, false);
    assert!(app.error.is_none(), "{:?}", app.error);
    let g = app.geometry().expect("the viewer fused the frame");
    assert_eq!(g.vertices.len(), reference.mesh.vertices.len());
    assert!(g.vertices.len() > 100_000, "{}", g.vertices.len());

    // Without the replacing depth (an output of `fuse --mat` alone could not exist for this
    // file; a hand-edited summary): the error names the .mat and says what is missing.
    let bare = fused_with(
        &tmp.path().join("bare"),
        serde_json::json!({"mat": mat, "color": colour, "depth_kind": "z"}),
    );
    let err = open_folder_with(&bare, false).expect_err("no depth to show");
    assert!(matches!(&err, ViewerError::BadFile { path, .. } if path == &mat), "{err:?}");
    assert!(err.to_string().contains("--depth"), "{err}");
}
