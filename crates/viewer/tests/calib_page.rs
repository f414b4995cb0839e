//! The calibration page on real `kfuse calibrate` reports: the stereo report of the shared
//! synthetic-calib set (detected with the same library calls as the CLI) and the kinect-lab IR
//! session (one view without a board, rejected). State tests compare the page's numbers with
//! the report file; the snapshot tests (wgpu on lavapipe) render each sub-view.

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use calib::detect::{align_pair, detect_views};
use calib::files::{add_detections, camera_json, stereo_rig};
use calib::{Board, CalibFlags, StereoOptions, calibrate_mono, calibrate_stereo};
use egui_kittest::kittest::Queryable;
use egui_kittest::wgpu::{WgpuTestRenderer, create_render_state, default_wgpu_setup};
use egui_kittest::{Harness, SnapshotOptions};
use geometry::testdata::shared_data_or_skip as shared;
use serde_json::Value;
use viewer::calib_page::CalibView;
use viewer::{Engine, Page, ViewerApp, ViewerError};

const SIZE: egui::Vec2 = egui::Vec2::new(1000.0, 620.0);
/// As in ui.rs: colour distance 2 absorbs lavapipe vs GPU rasterisation differences.
const PIXEL_THRESHOLD: f32 = 2.0;
/// Differing pixels tolerated: every calibration view (error bars, corners, residual arrows,
/// the board-pose wireframe and the parameter table) is drawn by egui's 2D painter, no 3D
/// mesh. Measured 0 of 620 000 against the committed PNGs on lavapipe (the renderer that wrote
/// them and that CI uses); 8 leaves room for a few anti-aliased edge pixels, while one changed
/// digit in a label differs in ≥ 20 pixels.
const FAILED_PIXELS: usize = 8;

fn images(dir: &Path, prefix: &str) -> (Vec<PathBuf>, Vec<(String, geometry::Image<u8>)>) {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().starts_with(prefix))
        .collect();
    files.sort();
    let imgs = files
        .iter()
        .map(|f| {
            (
                f.file_name().unwrap().to_string_lossy().into_owned(),
                calib::io::read_gray(f).unwrap(),
            )
        })
        .collect();
    (files, imgs)
}

/// The stereo report of synthetic-calib, written as `kfuse calibrate --report` writes
/// report.json, in a fixed folder (the page shows its path, so the snapshot needs it stable).
fn stereo_report(test: &str) -> Option<&'static Path> {
    let data = shared(test)?;
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    Some(DIR.get_or_init(|| {
        let set = data.join("synthetic-calib");
        let (ir_files, ir) = images(&set.join("ir"), "ir_");
        let (color_files, color) = images(&set.join("color"), "color_");
        let board = Board::new(7, 5, 0.04).unwrap();
        let (ir_views, board) = detect_views(&as_refs(&ir), &board);
        let (color_views, board) = detect_views(&as_refs(&color), &board);
        let color_views: Vec<_> =
            ir_views.iter().zip(&color_views).map(|(d, c)| align_pair(d, c, &board)).collect();
        let s = calibrate_stereo(
            &board,
            &ir_views,
            &color_views,
            &StereoOptions::default(),
            None,
            None,
        )
        .unwrap();
        let mut rig = stereo_rig(&s, &board);
        let cal = rig.calibration.as_mut().unwrap();
        add_detections(&mut cal["depth_single_camera"], &ir_views, &ir_files);
        add_detections(&mut cal["color_single_camera"], &color_views, &color_files);
        let dir = std::env::temp_dir().join("kfuse-viewer-test-calib-report");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("report.json"), serde_json::to_string_pretty(cal).unwrap())
            .unwrap();
        // The rig file `kfuse calibrate --out` writes, in a folder of its own.
        std::fs::create_dir_all(dir.join("rig")).unwrap();
        std::fs::write(dir.join("rig/rig.json"), rig.to_json()).unwrap();
        dir
    }))
}

fn as_refs(v: &[(String, geometry::Image<u8>)]) -> Vec<(String, &geometry::Image<u8>)> {
    v.iter().map(|(n, i)| (n.clone(), i)).collect()
}

fn read_json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn page_lists_the_reports_per_image_rms_and_corners() {
    let Some(dir) = stereo_report("page_lists_the_reports_per_image_rms_and_corners") else {
        return;
    };
    let app = ViewerApp::open(dir, Engine::Cpu);
    assert!(app.error.is_none(), "{:?}", app.error);
    assert_eq!(app.page, Page::Calibration);
    assert_eq!(app.pages(), vec![Page::Calibration]);
    let page = app.calib.as_ref().unwrap();
    let json = read_json(&dir.join("report.json"));
    let bars = page.error_bars();
    // A stereo report has two cameras (depth_single_camera, color_single_camera).
    assert_eq!(bars.len(), 2);
    for ((label, bars), key) in bars.iter().zip(["depth_single_camera", "color_single_camera"]) {
        let images = json[key]["images"].as_array().unwrap();
        assert_eq!(bars.len(), images.len(), "{label}");
        for (b, im) in bars.iter().zip(images) {
            // Tolerance 0: the page shows the file's numbers, it does not recompute them.
            assert_eq!(b.rms_px, im["rms_px"].as_f64(), "{label} {}", b.name);
            assert_eq!(b.name, im["name"].as_str().unwrap());
            assert_eq!(b.rejected, !im["rejected"].is_null());
            let detected = &page.report.cameras[if *label == "IR" { 0 } else { 1 }]
                .images
                .iter()
                .find(|i| i.name == b.name)
                .unwrap()
                .detected;
            assert_eq!(detected.len(), im["detected_corners"].as_array().unwrap().len());
        }
    }
    // Every synthetic view shows the whole 7x5 board in both cameras.
    assert!(page.report.cameras.iter().all(|c| c.images.iter().all(|i| i.detected.len() == 35)));
    // The ±3σ column is three times the report's 1σ, exactly.
    let rows = page.report.parameter_rows();
    let fx = &rows[0].1[0];
    assert_eq!(fx.0, "fx");
    assert_eq!(fx.2, Some(3.0 * json["depth_std_1sigma"]["fx"].as_f64().unwrap()));
    // Tx in mm against the synthetic truth T = -52 mm: the CLI's accuracy (0.05 mm bar in the
    // data README) with a margin for the detector, 0.2 mm.
    let tx = rows[2].1.iter().find(|r| r.0 == "Tx").unwrap();
    assert!((tx.1 + 52.0).abs() < 0.2, "Tx {} mm", tx.1);
    // The boards of the joint fit: one per pair, all used.
    assert_eq!(page.board_poses().len(), json["pairs_used"].as_array().unwrap().len());
    // The joint fit's per-view weights, as written (tolerance 0), and some views below 1.
    let weights = json["per_pair_weight"].as_array().unwrap();
    for (cam, key) in page.report.cameras.iter().zip(["depth", "color"]) {
        for (im, w) in cam.images.iter().zip(weights) {
            assert_eq!(im.joint_weight, w[key].as_f64(), "{} {}", cam.label, im.name);
        }
    }
    assert!(page.report.cameras[0].images.iter().any(|i| i.joint_weight.is_some_and(|w| w < 1.0)));
    // The joint fit's residual rows reproduce its per-pair RMS (JSON round trip: 1e-12 px).
    let rms = json["per_pair_rms_px"].as_array().unwrap();
    for (cam, key) in page.report.cameras.iter().zip(["depth", "color"]) {
        for (im, r) in cam.images.iter().zip(rms) {
            let rows = &im.joint_residuals;
            let got = (rows.iter().map(|e| e[3] * e[3] + e[4] * e[4]).sum::<f64>()
                / rows.len() as f64)
                .sqrt();
            assert!((got - r[key].as_f64().unwrap()).abs() < 1e-12, "{} {}", cam.label, im.name);
        }
    }
}

#[test]
fn rejected_view_is_marked_on_the_kinect_lab_session() {
    let Some(data) = shared("rejected_view_is_marked_on_the_kinect_lab_session") else { return };
    let lab = data.join("kinect-lab");
    let (files, imgs) = images(&lab, "ir_");
    let board = Board::new(7, 5, 0.04).unwrap();
    let refs: Vec<_> = imgs.iter().map(|(n, i)| (n.clone(), i)).collect();
    let (views, board) = detect_views(&refs, &board);
    let m = calibrate_mono("IR camera", &board, &views, &CalibFlags::bouguet(), None).unwrap();
    let mut v: Value = serde_json::from_str(&camera_json(&m, &board, "depth")).unwrap();
    add_detections(&mut v["calibration"], &views, &files);
    // A fixed folder: the page shows the path, and the snapshot below must not depend on it.
    let dir = std::env::temp_dir().join("kfuse-viewer-test-calib-lab");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("ir.json");
    std::fs::write(&file, v.to_string()).unwrap();
    let app = ViewerApp::open(&file, Engine::Cpu);
    assert!(app.error.is_none(), "{:?}", app.error);
    let page = app.calib.as_ref().unwrap();
    let bars = page.error_bars()[0].1.clone();
    let rejected: Vec<&str> = bars.iter().filter(|b| b.rejected).map(|b| b.name.as_str()).collect();
    // ir_23 shows no board (the CLI test says the same); the other views are used.
    assert_eq!(rejected, vec!["ir_23.bmp"]);
    assert_eq!(
        bars.iter().filter(|b| !b.rejected).count(),
        m.views.iter().filter(|v| v.rejected.is_none()).count()
    );
    // Single camera: the boards are in the camera's frame, one per used view.
    assert_eq!(page.board_poses().len(), bars.len() - 1);
    let Some(mut h) = harness("rejected_view_is_marked_on_the_kinect_lab_session", app) else {
        return;
    };
    h.get_by_label_contains("X ir_23.bmp");
    h.snapshot_options("calib_errors_rejected", &options());
    h.get_by_label(CalibView::Poses.label()).click();
    h.run();
    assert_eq!(h.state().calib.as_ref().unwrap().boards_drawn, bars.len() - 1);
}

#[test]
fn corrupt_or_incomplete_report_names_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("report.json"), "{ \"board\": ").unwrap();
    let app = ViewerApp::open(tmp.path(), Engine::Cpu);
    let e = app.error.as_ref().expect("corrupt JSON is an error");
    assert!(matches!(e, ViewerError::BadFile { .. }));
    assert!(
        e.to_string().contains("report.json") && e.to_string().contains("not valid JSON"),
        "{e}"
    );
    assert!(app.calib.is_none());
    // Valid JSON without the report's entries: named too, with the missing entry.
    std::fs::write(tmp.path().join("report.json"), r#"{"board": {"inner_corners_cols": 7, "inner_corners_rows": 5, "square_m": 0.04}, "depth_single_camera": {}}"#).unwrap();
    let app = ViewerApp::open(tmp.path(), Engine::Cpu);
    let e = app.error.as_ref().expect("incomplete report is an error").to_string();
    assert!(e.contains("report.json") && e.contains("depth_camera"), "{e}");
    // A rig file passed directly, truncated.
    let rig = tmp.path().join("rig.json");
    std::fs::write(&rig, "{\"format\": \"kfuse-rig\", \"calibration\": {").unwrap();
    let app = ViewerApp::open(&rig, Engine::Cpu);
    assert!(app.error.as_ref().is_some_and(|e| e.to_string().contains("rig.json")));
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

fn options() -> SnapshotOptions {
    SnapshotOptions::new().threshold(PIXEL_THRESHOLD).max_failed_pixels(FAILED_PIXELS)
}

#[test]
fn calibration_page_snapshots() {
    let Some(dir) = stereo_report("calibration_page_snapshots") else { return };
    let Some(mut h) = harness("calibration_page_snapshots", ViewerApp::open(dir, Engine::Cpu))
    else {
        return;
    };
    h.snapshot_options("calib_errors", &options());

    // Image 3 of the colour camera: its 35 corners are drawn.
    h.get_by_label("colour camera").click();
    h.run();
    h.get_by_label_contains("color_03.png").click();
    h.get_by_label(CalibView::Corners.label()).click();
    h.run();
    h.run();
    let page = h.state().calib.as_ref().unwrap();
    assert_eq!((page.camera, page.image), (1, 2));
    assert_eq!(page.markers_drawn, page.report.cameras[1].images[2].detected.len());
    // synthetic-calib/README.md: 7x5 inner corners, all visible in every view.
    assert_eq!(page.markers_drawn, 35);
    h.snapshot_options("calib_corners", &options());

    h.get_by_label(CalibView::Residuals.label()).click();
    h.run();
    // A stereo report opens on the joint fit's residuals; the toggle shows the single-camera
    // fit's. Every used corner gets one arrow either way.
    let page = h.state().calib.as_ref().unwrap();
    let joint: usize = page.report.cameras[1].images.iter().map(|i| i.joint_residuals.len()).sum();
    // synthetic-calib/README.md: 15 board poses × 35 corners, all used by the joint fit.
    assert_eq!((page.arrows_drawn, joint), (15 * 35, 15 * 35));
    h.get_by_label_contains("stereo joint fit: residual vectors");
    h.snapshot_options("calib_residuals", &options());
    h.get_by_label("single-camera fit").click();
    h.run();
    let page = h.state().calib.as_ref().unwrap();
    let used: usize = page.report.cameras[1].images.iter().map(|i| i.residuals.len()).sum();
    assert_eq!(page.arrows_drawn, used);
    h.get_by_label_contains("single-camera fit: residual vectors");
    h.get_by_label("stereo joint fit").click();
    h.run();

    h.get_by_label(CalibView::Poses.label()).click();
    h.run();
    // synthetic-calib/README.md: 15 board poses, one board per pair used.
    assert_eq!(h.state().calib.as_ref().unwrap().boards_drawn, 15);
    h.snapshot_options("calib_poses", &options());
    // Dragging orbits; Reset view goes back.
    let home = h.state().calib.as_ref().unwrap().orbit;
    let centre = egui::Pos2::new(SIZE.x * 0.65, SIZE.y * 0.5);
    h.drag_at(centre);
    h.run();
    h.hover_at(centre + egui::vec2(100.0, 30.0));
    h.run();
    h.drop_at(centre + egui::vec2(100.0, 30.0));
    h.run();
    assert_ne!(h.state().calib.as_ref().unwrap().orbit, home);
    h.get_by_label("Reset view").click();
    h.run();
    assert_eq!(h.state().calib.as_ref().unwrap().orbit, home);

    h.get_by_label(CalibView::Parameters.label()).click();
    h.run();
    h.get_by_label_contains("color_from_depth");
    h.snapshot_options("calib_params", &options());
}

#[test]
fn corrupt_report_shows_the_error_panel() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("report.json"), "not json at all").unwrap();
    let Some(h) =
        harness("corrupt_report_shows_the_error_panel", ViewerApp::open(tmp.path(), Engine::Cpu))
    else {
        return;
    };
    h.get_by_label("Error");
    h.get_by_label_contains("report.json: not valid JSON");
}

#[test]
fn rig_file_folder_opens_with_the_rigs_cameras() {
    let Some(dir) = stereo_report("rig_file_folder_opens_with_the_rigs_cameras") else { return };
    let from_rig = ViewerApp::open(&dir.join("rig"), Engine::Cpu);
    assert!(from_rig.error.is_none(), "{:?}", from_rig.error);
    let from_report = ViewerApp::open(dir, Engine::Cpu);
    let (a, b) =
        (&from_rig.calib.as_ref().unwrap().report, &from_report.calib.as_ref().unwrap().report);
    // Both files carry the same numbers (the rig's cameras are the report's, exactly).
    assert_eq!(a.cameras, b.cameras);
    assert_eq!(a.stereo, b.stereo);
    assert_eq!(a.depth_from_board, b.depth_from_board);
    let rig = kfuse_io::rig::read_pair(&dir.join("rig/rig.json")).unwrap();
    assert_eq!(a.cameras[0].model, rig.depth);
    assert_eq!(a.cameras[1].model, rig.color);
}

#[test]
fn missing_image_is_named_in_the_corner_view() {
    let Some(dir) = stereo_report("missing_image_is_named_in_the_corner_view") else { return };
    let mut json = read_json(&dir.join("report.json"));
    json["depth_single_camera"]["images"][0]["image"] = Value::from("/nonexistent/ir_01.png");
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("report.json"), json.to_string()).unwrap();
    let Some(mut h) = harness(
        "missing_image_is_named_in_the_corner_view",
        ViewerApp::open(tmp.path(), Engine::Cpu),
    ) else {
        return;
    };
    h.get_by_label(CalibView::Corners.label()).click();
    h.run();
    h.run();
    h.get_by_label_contains("image not shown: /nonexistent/ir_01.png");
    // The corners are still drawn, on a blank canvas.
    assert_eq!(h.state().calib.as_ref().unwrap().markers_drawn, 35);
}
