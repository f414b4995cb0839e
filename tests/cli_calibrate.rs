//! End-to-end tests of `kfuse calibrate` and `kfuse undistort` on the shared data.

use geometry::testdata::shared_data_or_skip as shared;
use std::path::Path;
use std::process::Command;

fn kfuse(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_kfuse")).args(args).output().expect("kfuse runs");
    let text =
        format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    (out.status.success(), text)
}

#[test]
fn calibrates_the_real_ir_session_and_writes_the_report() {
    let Some(data) = shared("calibrates_the_real_ir_session_and_writes_the_report") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ir.json");
    let report = tmp.path().join("report");
    let pattern = format!("{}/kinect-lab/ir_*.bmp", data.display());
    let (ok, text) = kfuse(&[
        "calibrate",
        "--ir",
        &pattern,
        "--lab-settings",
        "--out",
        out.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
    // ir_23 has no board and is reported as such; the other 11 are used.
    assert!(text.contains("ir_23.bmp") && text.contains("REJECTED"), "{text}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let fx = v["camera"]["fx"].as_f64().unwrap();
    // The lab's fc(1) = 364.126 ± 2.62 (3σ).
    assert!((fx - 364.126).abs() < 2.62, "fx {fx}");
    for f in [
        "report.json",
        "per_image_error.png",
        "residuals_ir.png",
        "board_poses_ir.png",
        "corners_ir_1.png",
        "corners_ir_23.png",
    ] {
        assert!(report.join(f).is_file(), "{f} missing");
    }
}

#[test]
fn bad_inputs_fail_clearly_and_write_nothing() {
    let Some(data) = shared("bad_inputs_fail_clearly_and_write_nothing") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("rig.json");
    let o = out.to_str().unwrap();
    let lab = data.join("kinect-lab");
    let syn = data.join("synthetic-calib");
    // No board in any image.
    let (ok, text) =
        kfuse(&["calibrate", "--ir", lab.join("ir_23.bmp").to_str().unwrap(), "--out", o]);
    assert!(!ok && text.contains("no 7x5 checkerboard found"), "{text}");
    // Fewer than 3 usable views.
    let two = format!("{}/kinect-lab/ir_1?.bmp", data.display()); // ir_10, ir_11
    let (ok, text) = kfuse(&["calibrate", "--ir", &two, "--out", o]);
    assert!(!ok && text.contains("at least 3 are needed"), "{text}");
    // Mixed image sizes within one camera.
    let (ok, text) = kfuse(&[
        "calibrate",
        "--ir",
        lab.join("ir_1.bmp").to_str().unwrap(),
        "--ir",
        lab.join("ir_3.bmp").to_str().unwrap(),
        "--ir",
        syn.join("color/color_01.png").to_str().unwrap(),
        "--out",
        o,
    ]);
    assert!(!ok && text.contains("must have the same size"), "{text}");
    // A pair where only the colour image shows the board.
    let dir = tmp.path().join("pairs");
    std::fs::create_dir_all(&dir).unwrap();
    for i in 1..=4 {
        std::fs::copy(
            syn.join(format!("color/color_{i:02}.png")),
            dir.join(format!("color_{i}.png")),
        )
        .unwrap();
        let ir = if i == 4 { lab.join("ir_23.bmp") } else { syn.join(format!("ir/ir_{i:02}.png")) };
        std::fs::copy(ir, dir.join(format!("ir_{i}.{}", if i == 4 { "bmp" } else { "png" })))
            .unwrap();
    }
    let (ok, text) = kfuse(&[
        "calibrate",
        "--color",
        &format!("{}/color_*", dir.display()),
        "--ir",
        &format!("{}/ir_*", dir.display()),
        "--out",
        o,
    ]);
    assert!(!ok && text.contains("pair 4") && text.contains("--allow-unpaired"), "{text}");
    // A pattern matching nothing.
    let (ok, text) = kfuse(&["calibrate", "--ir", "/nonexistent/ir_*.png", "--out", o]);
    assert!(!ok && text.contains("no file matches"), "{text}");
    // Nothing was written by any failed run.
    assert!(!out.exists());
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 1, "only the pairs folder");
}

#[test]
fn undistort_writes_rect_images() {
    let Some(data) = shared("undistort_writes_rect_images") else { return };
    let tmp = tempfile::tempdir().unwrap();
    // A rig with the lab's Bouguet IR camera and a plain colour camera.
    let rig = tmp.path().join("rig.json");
    std::fs::write(
        &rig,
        r#"{"format":"kfuse-rig","version":1,
            "depth_camera":{"width":512,"height":424,"fx":364.126,"fy":365.126,"cx":255.5,"cy":211.5,"k1":0.099,"k2":-0.2206,"p1":0.0041,"p2":0.0016,"k3":0},
            "color_camera":{"width":1920,"height":1080,"fx":1060,"fy":1060,"cx":959.5,"cy":539.5,"k1":0.04,"k2":-0.04,"p1":0.003,"p2":-0.005,"k3":0},
            "color_from_depth":{"rotation":[[1,0,0],[0,1,0],[0,0,1]],"translation_m":[-0.052,0,0]}}"#,
    )
    .unwrap();
    let out = tmp.path().join("rect");
    let img = data.join("kinect-lab/ir_1.bmp");
    let (ok, text) = kfuse(&[
        "undistort",
        "--rig",
        rig.to_str().unwrap(),
        "--camera",
        "depth",
        img.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
    let rect = calib::io::read_gray(&out.join("ir_1_rect.png")).unwrap();
    let input = calib::io::read_gray(&img).unwrap();
    assert_eq!(rect.size(), (512, 424));
    // Next to the principal point the lens does not move pixels: the same value comes back.
    assert_eq!(rect.get(255, 211), input.get(255, 211));
    // Away from the centre it does (barrel-like k1 > 0 with k2 < 0): the image changed.
    let changed = rect.data().iter().zip(input.data()).filter(|(a, b)| a != b).count();
    assert!(changed > 10_000, "{changed} pixels changed");
}

/// A sharp pinhole rendering (3x3 supersampling) of the 7x5-corner, 40 mm board of DESIGN.md
/// (8x6 squares, top-left black, 30 mm white margin) on a grey background, 512x424, f = 365 px.
/// `rz` turns the board about the optical axis, `tilt` about the board's x axis (radians);
/// `t` is the board origin (first inner corner) in the camera frame, metres.
fn render_board(rz: f64, tilt: f64, t: [f64; 3]) -> image::GrayImage {
    let (w, h, f, cx, cy) = (512u32, 424u32, 365.0, 255.5, 211.5);
    let (cz, sz, ct, st) = (rz.cos(), rz.sin(), tilt.cos(), tilt.sin());
    // R = Rz(rz)·Rx(tilt): columns are the board's x, y and normal axes in the camera frame.
    let r = [[cz, -sz * ct, sz * st], [sz, cz * ct, -cz * st], [0.0, st, ct]];
    let col = |j: usize| [r[0][j], r[1][j], r[2][j]];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let (ex, ey, n) = (col(0), col(1), col(2));
    let sample = |u: f64, v: f64| -> f64 {
        let d = [(u - cx) / f, (v - cy) / f, 1.0];
        let s = dot(n, t) / dot(n, d);
        let x = [s * d[0] - t[0], s * d[1] - t[1], s * d[2] - t[2]];
        let (bx, by) = (dot(ex, x) * 1000.0, dot(ey, x) * 1000.0); // mm
        let (sx, sy) = (((bx + 40.0) / 40.0).floor(), ((by + 40.0) / 40.0).floor());
        if (0.0..8.0).contains(&sx) && (0.0..6.0).contains(&sy) {
            if (sx + sy) as i64 % 2 == 0 { 30.0 } else { 220.0 }
        } else if (-70.0..=310.0).contains(&bx) && (-70.0..=230.0).contains(&by) {
            220.0
        } else {
            90.0
        }
    };
    image::GrayImage::from_fn(w, h, |x, y| {
        let mut acc = 0.0;
        for i in 0..3 {
            for j in 0..3 {
                acc += sample(x as f64 + (i as f64 - 1.0) / 3.0, y as f64 + (j as f64 - 1.0) / 3.0);
            }
        }
        image::Luma([(acc / 9.0).round() as u8])
    })
}

#[test]
fn fronto_parallel_boards_are_refused_with_the_fix() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("imgs");
    std::fs::create_dir_all(&dir).unwrap();
    // Five boards turned only about the optical axis, at different places and distances:
    // every homography is a similarity, so the focal length is unobservable (Zhang).
    let poses = [
        (0.0, [-0.12, -0.08, 0.60]),
        (0.35, [-0.08, -0.12, 0.65]),
        (-0.3, [-0.16, -0.02, 0.70]),
        (0.15, [-0.14, -0.10, 0.55]),
        (-0.1, [-0.10, -0.06, 0.75]),
    ];
    for (i, (rz, t)) in poses.iter().enumerate() {
        render_board(*rz, 0.0, *t).save(dir.join(format!("ir_{}.png", i + 1))).unwrap();
    }
    let out = tmp.path().join("rig.json");
    let report = tmp.path().join("report");
    let pattern = format!("{}/ir_*.png", dir.display());
    let (ok, text) = kfuse(&[
        "calibrate",
        "--ir",
        &pattern,
        "--out",
        out.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    assert!(!ok, "fronto-parallel boards must fail:\n{text}");
    // The message names the degeneracy and the fix.
    assert!(text.contains("fronto-parallel") && text.contains("tilt the board 20–45°"), "{text}");
    // All five boards were found: the failure is the geometry, not the detection.
    assert!(!text.contains("REJECTED"), "{text}");
    // Nothing half-written: no rig file, no report folder, no staging folder.
    assert!(!out.exists() && !report.exists(), "{text}");
    let left: Vec<_> =
        std::fs::read_dir(tmp.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left, vec![std::ffi::OsString::from("imgs")], "{text}");
    // The same boards tilted by 30° about their x axis (alternating sign) calibrate: the
    // refusal above is the geometry's, not the renderer's.
    for (i, (rz, t)) in poses.iter().enumerate() {
        let tilt = if i % 2 == 0 { 0.52 } else { -0.52 };
        render_board(*rz, tilt, *t).save(dir.join(format!("ir_{}.png", i + 1))).unwrap();
    }
    let (ok, text) = kfuse(&["calibrate", "--ir", &pattern, "--out", out.to_str().unwrap()]);
    assert!(ok, "{text}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let fx = v["camera"]["fx"].as_f64().unwrap();
    // Sharp, noise-free pinhole images: the rendered f = 365 px within 0.5 %.
    assert!((fx - 365.0).abs() < 0.005 * 365.0, "fx {fx}\n{text}");
}

/// Mean distance (px) from every corner in `report.json`'s `detected_corners` to the nearest
/// of the lab's Bouguet corners of the same image, over the images both have.
fn mean_distance_to_bouguet(
    report: &Path,
    bouguet: &calib::bouguet::BouguetCamera,
) -> (f64, usize) {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.join("report.json")).unwrap())
            .unwrap();
    let (mut sum, mut n) = (0.0, 0usize);
    // A single-camera report is the camera file itself, with the report under `calibration`.
    for img in v["calibration"]["images"].as_array().expect("report lists images") {
        let name = Path::new(img["image"].as_str().unwrap_or_default())
            .file_name()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        // ir_N.bmp is the lab's view N.
        let Some(k) = name
            .strip_prefix("ir_")
            .and_then(|s| s.strip_suffix(".bmp"))
            .and_then(|s| s.parse::<usize>().ok())
        else {
            continue;
        };
        let Some(Some(lab)) = bouguet.views.get(k - 1) else { continue };
        for c in img["detected_corners"].as_array().into_iter().flatten() {
            let (x, y) = (c[1].as_f64().unwrap(), c[2].as_f64().unwrap());
            let d = lab
                .corners
                .iter()
                .map(|l| ((l.px.x - x).powi(2) + (l.px.y - y).powi(2)).sqrt())
                .fold(f64::INFINITY, f64::min);
            sum += d;
            n += 1;
        }
    }
    (sum / n.max(1) as f64, n)
}

#[test]
fn corners_flag_selects_the_estimator_and_subpix_matches_the_labs_toolbox() {
    let Some(data) =
        shared("corners_flag_selects_the_estimator_and_subpix_matches_the_labs_toolbox")
    else {
        return;
    };
    let bouguet =
        calib::bouguet::import_mono(&data.join("kinect-lab/Calib_Results_left.mat")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let pattern = format!("{}/kinect-lab/ir_*.bmp", data.display());
    let mut means = Vec::new();
    for mode in ["subpix", "junction"] {
        let out = tmp.path().join(format!("{mode}.json"));
        let report = tmp.path().join(format!("report-{mode}"));
        let (ok, text) = kfuse(&[
            "calibrate",
            "--ir",
            &pattern,
            "--lab-settings",
            "--corners",
            mode,
            "--out",
            out.to_str().unwrap(),
            "--report",
            report.to_str().unwrap(),
        ]);
        assert!(ok, "{mode}: {text}");
        let (mean, n) = mean_distance_to_bouguet(&report, &bouguet);
        eprintln!("--corners {mode}: mean {mean:.4} px from Bouguet's corners over {n} corners");
        // The 10 views the lab used hold 350 corners; partial boards may add or drop a few.
        assert!(n >= 300, "{mode}: only {n} corners compared");
        means.push(mean);
    }
    // Issue 3's bar for agreement with the lab's toolbox corners.
    assert!(means[0] <= 0.15, "subpix corners {:.4} px from Bouguet's (bar 0.15)", means[0]);
    // The flag reaches the detector: the junction fit moves corners by a measurable amount
    // (0.21 px mean from Bouguet's in the library test, against 0.13 px).
    assert!((means[1] - means[0]).abs() > 0.02, "both estimators gave {means:?}");
}
