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

/// Writes what `kfuse capture scene --backend sim` writes for one shot named `name`: the
/// simulated sensor's colour JPEG and depth (mm) through `kfuse_capture`'s own writer and
/// names, and `kinect_params.json` in `kfuse_capture::write_params_json`'s layout, from the
/// simulator's factory parameters.
fn write_kfuse_capture(dir: &Path, name: &str) {
    let (scene, profile) = kfuse_capture::source::sim_scene();
    let writer = kfuse_capture::ShotWriter::new(dir).unwrap();
    let files = kfuse_capture::shot_files(dir, name, kfuse_capture::ShotKind::Scene);
    // The simulator streams mirrored frames, as a sensor does; the capture mirrors them back
    // (the decoder for depth and IR, the writer for colour) and writes the mirrored factory
    // parameters (kinect_usb::orientation).
    let (mut depth_mm, mut ir) = scene.depth_frames[0].clone();
    kinect_usb::orientation::mirror_rows(&mut depth_mm, 512);
    kinect_usb::orientation::mirror_rows(&mut ir, 512);
    writer.write(&files, &scene.color_jpegs[0], &ir, &depth_mm).unwrap();
    let (d, c) = (&profile.depth_params.mirrored(), &profile.color_params.mirrored());
    let v = serde_json::json!({
        "format": "kfuse-kinect-params", "version": 2, "image_orientation": "scene",
        "serial": profile.serial,
        "units": "pixels; shift_d and shift_m in millimetres",
        "depth": { "width": 512, "height": 424, "fx": d.fx, "fy": d.fy, "cx": d.cx, "cy": d.cy,
                   "k1": d.k1, "k2": d.k2, "k3": d.k3, "p1": d.p1, "p2": d.p2 },
        "color": { "width": 1920, "height": 1080, "fx": c.f, "fy": c.f, "cx": c.cx, "cy": c.cy,
                   "shift_d": c.shift_d, "shift_m": c.shift_m, "mx": c.mx, "my": c.my },
    });
    std::fs::write(dir.join("kinect_params.json"), v.to_string()).unwrap();
}

/// A `kfuse capture` folder (kinect_params.json, NAME_color.jpg, NAME_depth.png, no rig.json)
/// opens: the newest scene shot by name, depth as written, the rig fitted to the factory
/// parameters as `kfuse rig import` fits it.
#[test]
fn kfuse_capture_folder_opens_its_newest_shot() {
    let tmp = tempfile::tempdir().unwrap();
    write_kfuse_capture(tmp.path(), "scene_0002");
    // An older shot whose depth is all invalid: opening it instead would fail the check below.
    let old = kfuse_capture::shot_files(tmp.path(), "scene_0001", kfuse_capture::ShotKind::Scene);
    std::fs::copy(tmp.path().join("scene_0002_color.jpg"), &old[0]).unwrap();
    images::write_depth_png16(&old[2], &geometry::Image::filled(512, 424, 0.0)).unwrap();
    let (frame, warnings) = open_folder_with(tmp.path(), false).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    assert!(frame.name.contains("scene_0002"), "{}", frame.name);
    assert_eq!(frame.kind, geometry::DepthKind::Z);
    // Truth: the simulator's scene (geometry::synth's Kinect preset without noise), z in metres.
    let truth = synth::render(&synth::kinect_preset(false));
    assert_eq!(frame.depth.size(), truth.true_depth_z.size());
    let (mut worst, mut n) = (0.0f32, 0usize);
    for (a, b) in frame.depth.data().iter().zip(truth.true_depth_z.data()) {
        // The simulated sensor drops what it cannot see (no surface, out of range): 0 = no sample.
        if *a > 0.0 {
            assert!(b.is_finite() && *b > 0.0, "a sample where the truth has no surface");
            worst = worst.max((a - b).abs());
            n += 1;
        }
    }
    eprintln!("kfuse capture folder: depth error max {worst:.2e} m over {n} pixels");
    // The scene fills most of the 512 × 424 view (synth::kinect_preset).
    assert!(n > 100_000, "{n} valid pixels");
    // 0.5 mm: rounding to whole millimetres; 1e-6 m: f32 rounding of metre values below 20 m.
    assert!(worst <= 0.0005 + 1e-6, "depth error {worst} m over {n} pixels");
    // The rig: the factory fit of the same kinect_params.json, done here independently.
    let params = tmp.path().join("kinect_params.json");
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&params).unwrap()).unwrap();
    let fit =
        kfuse_io::rig_io::kinect::FactoryParams::from_json(&v, &params).unwrap().to_rig().unwrap();
    assert_eq!(frame.rig, fit.rig);
    // The sim's colour camera is 1920 × 1080, the JPEG decoded at that size.
    assert_eq!(frame.color.size(), (1920, 1080));
    // A rig.json next to it wins over the factory parameters.
    let mut rig = fit.rig.clone();
    rig.color_from_depth.translation.x += 0.01;
    rigio::write_rig(&tmp.path().join("rig.json"), &rig).unwrap();
    let (frame, _) = open_folder_with(tmp.path(), false).unwrap();
    // 1e-15 m: the rig file's decimal text (serde_json reads floats to within an ulp or two).
    let moved = frame.rig.color_from_depth.translation - rig.color_from_depth.translation;
    assert!(moved.amax() < 1e-15, "{moved}");
}

/// A `kfuse capture` folder without a complete shot: one line naming the folder and the files
/// expected.
#[test]
fn kfuse_capture_folder_without_a_shot_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    write_kfuse_capture(tmp.path(), "scene_0001");
    std::fs::remove_file(tmp.path().join("scene_0001_depth.png")).unwrap();
    let err = expect_error_naming(tmp.path(), &tmp.path().display().to_string());
    assert!(matches!(err, ViewerError::NoShot { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(
        !msg.contains('\n') && msg.contains("NAME_depth.png") && msg.contains("depth_NNNN.png")
    );
    for f in std::fs::read_dir(tmp.path()).unwrap() {
        let f = f.unwrap().path();
        if f.file_name().is_some_and(|n| n != "kinect_params.json") {
            std::fs::remove_file(f).unwrap();
        }
    }
    assert!(matches!(open_folder_with(tmp.path(), true), Err(ViewerError::NoShot { .. })));
}

/// `kfuse view --shot NAME`: a named scene shot or calibration shot of a `kfuse capture`
/// folder instead of the newest; an unknown name (or a shot asked of another kind of folder)
/// is one line listing the shots there are.
#[test]
fn kfuse_capture_folder_opens_the_shot_asked_for() {
    use viewer::data::open_folder_shot;
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_kfuse_capture(dir, "scene_0002");
    // "desk" (sorted before scene_0002, so never the default): a flat 1.5 m depth.
    let desk = kfuse_capture::shot_files(dir, "desk", kfuse_capture::ShotKind::Scene);
    std::fs::copy(dir.join("scene_0002_color.jpg"), &desk[0]).unwrap();
    images::write_depth_png16(&desk[2], &geometry::Image::filled(512, 424, 1.5)).unwrap();
    // Calibration shot 0003: a flat 0.9 m depth.
    let calib = kfuse_capture::shot_files(dir, "0003", kfuse_capture::ShotKind::Calib);
    std::fs::copy(dir.join("scene_0002_color.jpg"), &calib[0]).unwrap();
    images::write_depth_png16(&calib[2], &geometry::Image::filled(512, 424, 0.9)).unwrap();

    let flat = |shot: Option<&str>| {
        let (frame, _) = open_folder_shot(dir, false, shot).unwrap();
        let d = frame.depth.data();
        (frame.name.clone(), d.iter().all(|&z| z == d[0]).then_some(d[0]))
    };
    let (name, constant) = flat(None);
    assert!(name.contains("scene_0002") && constant.is_none(), "{name}");
    let (name, constant) = flat(Some("desk"));
    assert!(name.contains("(desk)") && constant == Some(1.5), "{name} {constant:?}");
    let (name, constant) = flat(Some("0003"));
    assert!(name.contains("(0003)") && constant == Some(0.9), "{name} {constant:?}");

    let err = open_folder_shot(dir, false, Some("nope")).unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, ViewerError::UnknownShot { .. }), "{err:?}");
    assert!(
        !msg.contains('\n') && msg.contains("'nope'") && msg.contains("desk, scene_0002, 0003"),
        "{msg}"
    );
    // A capture folder of `kfuse demo` (rig.json, no kinect_params.json) has no named shots.
    let demo = tempfile::tempdir().unwrap();
    write_capture(demo.path());
    let err = open_folder_shot(demo.path(), false, Some("desk")).unwrap_err();
    assert!(err.to_string().contains("kfuse capture"), "{err}");
}

/// A rectified rig (`"rectified": true`, or a fuse output of `kfuse fuse --rectified`) is used
/// without its distortion, as `kfuse fuse` uses it; otherwise the distortion is kept.
#[test]
fn rectified_rigs_are_used_without_distortion() {
    let lens = geometry::Distortion { k1: -0.1, k2: 0.02, p1: 0.0, p2: 0.0, k3: 0.0 };
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("input");
    std::fs::create_dir(&input).unwrap();
    write_capture(&input);
    let rig_path = input.join("rig.json");
    let mut rig = rigio::read_rig(&rig_path).unwrap().into_pair(&rig_path).unwrap();
    rig.depth.distortion = lens;
    rig.color.distortion = lens;
    rigio::write_rig(&input.join("rig.json"), &rig).unwrap();
    let (frame, _) = open_folder_with(&input, true).unwrap();
    assert_eq!((frame.rig.depth.distortion, frame.rig.color.distortion), (lens, lens));

    // The fuse output of the same rig, fused with --rectified.
    let fused = tmp.path().join("fused");
    std::fs::create_dir(&fused).unwrap();
    let summary = |rectified: bool| {
        serde_json::json!({"format": "kfuse-fuse-summary", "inputs": {
            "rig": "input/rig.json", "color": "input/color.png", "depth": "input/depth.png",
            "depth_kind": "z", "depth_scale_m_per_unit": 0.001, "rectified": rectified}})
        .to_string()
    };
    std::fs::write(fused.join("summary.json"), summary(true)).unwrap();
    let (frame, _) = open_folder_with(&fused, true).unwrap();
    let none = geometry::Distortion::NONE;
    assert_eq!((frame.rig.depth.distortion, frame.rig.color.distortion), (none, none));
    std::fs::write(fused.join("summary.json"), summary(false)).unwrap();
    let (frame, _) = open_folder_with(&fused, true).unwrap();
    assert_eq!(frame.rig.color.distortion, lens);

    // The rig's own field.
    rig.rectified = true;
    rigio::write_rig(&input.join("rig.json"), &rig).unwrap();
    let (frame, _) = open_folder_with(&input, true).unwrap();
    assert_eq!((frame.rig.depth.distortion, frame.rig.color.distortion), (none, none));
}
