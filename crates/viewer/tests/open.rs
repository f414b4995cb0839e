//! Opening folders: capture and `kfuse fuse` output folders load; missing or corrupt files
//! give an error naming the file (never a panic).

use std::path::Path;

use geometry::synth;
use kfuse_io::{images, rig as rigio};
use viewer::data::{open_folder, open_folder_with};
use viewer::{Engine, ViewerApp, ViewerError};

/// Writes the course-size synthetic scene (640×480, fast) as a capture folder. Its rig has
/// the course data's 1.02 m baseline, over the plausibility limit: the tests open it with
/// `force` (the check itself is tested in `implausible_rig_is_refused_unless_forced`).
fn write_capture(dir: &Path) -> synth::SynthFrame {
    let setup = synth::course_preset();
    let frame = synth::render(&setup);
    images::write_color_png(&dir.join("color.png"), &frame.color).unwrap();
    // The course preset measures range; a capture folder holds z, as a Kinect does.
    images::write_depth_png16(&dir.join("depth.png"), &frame.true_depth_z).unwrap();
    rigio::write_rig(&dir.join("rig.json"), &setup.rig).unwrap();
    frame
}

#[test]
fn capture_folder_opens_and_fuses() {
    let tmp = tempfile::tempdir().unwrap();
    let truth = write_capture(tmp.path());
    let (frame, warnings) = open_folder_with(tmp.path(), true).unwrap();
    // One warning: synth::course_rig's 1.02 m baseline (over the 0.5 m limit) on purpose.
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    // 640 × 480: synth::course_rig's depth camera, written above.
    assert_eq!(frame.depth.size(), (640, 480));
    // 16-bit millimetres: every value within half a millimetre of the truth.
    let worst = frame
        .depth
        .data()
        .iter()
        .zip(truth.true_depth_z.data())
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    // 0.5 mm: rounding to whole millimetres; 1e-6 m: f32 rounding of metre values below 20 m.
    assert!(worst <= 0.0005 + 1e-6, "depth round trip error {worst} m");
    let app = ViewerApp::open_with(tmp.path(), Engine::Cpu, true);
    assert!(app.error.is_none(), "{:?}", app.error);
    // Guard: a 640 × 480 grid has up to 2 · 639 · 479 ≈ 612 000 faces and the course scene's plane
    // fills the view (synth::course_preset); 10 000 fails only for an (almost) empty mesh.
    assert!(app.drawn_triangles() > 10_000);
}

#[test]
fn fuse_output_folder_resolves_its_inputs() {
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("input");
    std::fs::create_dir(&input).unwrap();
    write_capture(&input);
    let fused = tmp.path().join("fused");
    std::fs::create_dir(&fused).unwrap();
    // As `kfuse fuse` records them: paths relative to where it ran (here: tmp's parent
    // is not the cwd, so the viewer must find them relative to the folder's parent).
    let summary = serde_json::json!({"format": "kfuse-fuse-summary", "inputs": {
        "rig": "input/rig.json", "color": "input/color.png", "depth": "input/depth.png",
        "depth_kind": "z", "depth_scale_m_per_unit": 0.001}});
    std::fs::write(fused.join("summary.json"), summary.to_string()).unwrap();
    let (frame, _) = open_folder_with(&fused, true).unwrap();
    // 640 × 480: synth::course_rig's colour camera, written by write_capture.
    assert_eq!(frame.color.size(), (640, 480));
}

fn expect_error_naming(dir: &Path, file: &str) -> ViewerError {
    let err = open_folder_with(dir, true).expect_err("must fail");
    let msg = err.to_string();
    assert!(msg.contains(file), "error {msg:?} does not name {file}");
    // The app shows it instead of panicking.
    let app = ViewerApp::open_with(dir, Engine::Cpu, true);
    assert!(app.error.as_ref().is_some_and(|e| e.to_string().contains(file)));
    assert!(app.fused.is_none());
    err
}

#[test]
fn missing_colour_image_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    write_capture(tmp.path());
    std::fs::remove_file(tmp.path().join("color.png")).unwrap();
    assert!(matches!(
        expect_error_naming(tmp.path(), "color.png"),
        ViewerError::MissingFile { .. }
    ));
}

#[test]
fn corrupt_depth_image_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    write_capture(tmp.path());
    std::fs::write(tmp.path().join("depth.png"), b"\x89PNG\r\n\x1a\n this is not a png").unwrap();
    assert!(matches!(expect_error_naming(tmp.path(), "depth.png"), ViewerError::BadFile { .. }));
}

#[test]
fn corrupt_rig_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    write_capture(tmp.path());
    std::fs::write(tmp.path().join("rig.json"), "{ \"depth\": 3 ").unwrap();
    expect_error_naming(tmp.path(), "rig.json");
}

#[test]
fn wrong_size_colour_image_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    write_capture(tmp.path());
    images::write_color_png(
        &tmp.path().join("color.png"),
        &geometry::Image::filled(320, 240, [9u8; 3]),
    )
    .unwrap();
    assert!(matches!(
        expect_error_naming(tmp.path(), "color.png"),
        ViewerError::SizeMismatch { got_w: 320, .. }
    ));
}

#[test]
fn corrupt_summary_and_missing_inputs_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("summary.json"), "not json").unwrap();
    expect_error_naming(tmp.path(), "summary.json");
    std::fs::write(
        tmp.path().join("summary.json"),
        r#"{"inputs": {"rig": "/nowhere/rig.json", "color": "c.png", "depth": "d.png"}}"#,
    )
    .unwrap();
    assert!(matches!(
        expect_error_naming(tmp.path(), "/nowhere/rig.json"),
        ViewerError::MissingFile { .. }
    ));
}

#[test]
fn not_a_folder_and_unknown_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("nope");
    expect_error_naming(&missing, "nope");
    expect_error_naming(tmp.path(), "summary.json");
}

/// The viewer applies `kfuse fuse`'s rig check (`Rig::check_plausible`): a rig in the wrong
/// units is refused with one message naming rig.json, the problem and `--force`, for a
/// capture folder and a `kfuse fuse` output alike; with `force` it opens, the problems as
/// warnings.
#[test]
fn implausible_rig_is_refused_unless_forced() {
    let tmp = tempfile::tempdir().unwrap();
    let setup = synth::course_preset();
    write_capture(tmp.path());
    // The course preset's 1.02 m baseline alone.
    let err = open_folder(tmp.path()).expect_err("1.02 m baseline").to_string();
    assert!(
        err.contains("rig.json") && err.contains("baseline") && err.contains("--force"),
        "{err}"
    );
    let app = ViewerApp::open(tmp.path(), Engine::Cpu);
    assert!(app.error.is_some() && app.fused.is_none());
    // A plausible baseline opens without a warning; focal lengths in metres do not.
    let mut rig = setup.rig.clone();
    rig.color_from_depth.translation *= 0.05 / rig.color_from_depth.translation.norm();
    rigio::write_rig(&tmp.path().join("rig.json"), &rig).unwrap();
    let (_, warnings) = open_folder_with(tmp.path(), false).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    rig.depth.intrinsics.fx /= 1e5;
    rigio::write_rig(&tmp.path().join("rig.json"), &rig).unwrap();
    let err = open_folder(tmp.path()).expect_err("fx in metres").to_string();
    assert!(err.contains("rig.json") && err.contains("fx") && err.contains("not metres"), "{err}");
    // The course rig again (1.02 m), through a `kfuse fuse` output folder.
    rigio::write_rig(&tmp.path().join("rig.json"), &setup.rig).unwrap();
    let fused = tmp.path().join("fused");
    std::fs::create_dir(&fused).unwrap();
    let summary = serde_json::json!({"inputs": {"rig": tmp.path().join("rig.json"),
        "color": tmp.path().join("color.png"), "depth": tmp.path().join("depth.png")}});
    std::fs::write(fused.join("summary.json"), summary.to_string()).unwrap();
    let err = open_folder(&fused).expect_err("through summary.json").to_string();
    assert!(err.contains("rig.json") && err.contains("--force"), "{err}");
    // --force: opened, one warning naming the file and the problem.
    let (frame, warnings) = open_folder_with(&fused, true).unwrap();
    assert_eq!(frame.depth.size(), (640, 480));
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(warnings[0].contains("rig.json") && warnings[0].contains("baseline"), "{warnings:?}");
    let app = ViewerApp::open_with(&fused, Engine::Cpu, true);
    assert!(app.error.is_none() && app.warnings == warnings, "{:?}", app.error);
}
