//! End-to-end tests of `kfuse calibrate` and `kfuse undistort` on the shared data.
//!
//! Size (~640 lines, one file): the calibrate and undistort flows share the shared-data sets,
//! the binary runner above and the board renderer below; each test reads as one user session.

use geometry::testdata::shared_data_or_skip as shared;
use std::path::Path;
use std::process::Command;

fn kfuse(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_kfuse")).args(args).output().expect("kfuse runs");
    let text =
        format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    (out.status.success(), text)
}

/// `kfuse calibrate --color PATTERN --board BOARD [EXTRA…] --out OUT`, which must succeed;
/// its output.
fn calibrate_color(pattern: &str, board: &str, extra: &[&str], out: &Path) -> String {
    let args = [&["calibrate", "--color", pattern, "--board", board][..], extra];
    let (ok, text) = kfuse(&[&args.concat()[..], &["--out", out.to_str().unwrap()]].concat());
    assert!(ok, "{text}");
    text
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
    // The held-out check: 11 views with a board, the 1st, 3rd, … (6) calibrate, 5 predicted;
    // printed and in report.json. Real IR corners are heavy-tailed (up to ~1.2 px), so the
    // held-out median is asserted within 3× the in-sample RMS and the 95th percentile above
    // the median.
    assert!(text.contains("held-out check: calibrated on 6 views"), "{text}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.join("report.json")).unwrap())
            .unwrap();
    let h = &r["held_out"];
    assert_eq!(h["train"].as_array().map(Vec::len), Some(6), "{h}");
    assert_eq!(h["held_out"].as_array().map(Vec::len), Some(5), "{h}");
    let e = &h["errors"][0];
    let (median, p95, rms) = (
        e["median_px"].as_f64().unwrap(),
        e["p95_px"].as_f64().unwrap(),
        e["in_sample_rms_px"].as_f64().unwrap(),
    );
    eprintln!(
        "kinect-lab IR held out: median {median:.4} px, 95 % {p95:.4} px, in-sample RMS {rms:.4} px"
    );
    assert!(median > 0.0 && median <= 3.0 * rms && p95 >= median, "{e}");
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
    // The odd-sized image is left out with its size named; two views are too few.
    assert!(
        !ok && text.contains("at least 3 are needed") && text.contains("color_01.png (image is"),
        "{text}"
    );
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
    // IR images of one session paired with colour images of another whose 7x5 board is
    // coloured the other way round (the lab's top-left square is white, the rendered set's
    // black): named as two sets, not as three colour images without a board (a user's trial).
    let (ok, text) = kfuse(&[
        "calibrate",
        "--ir",
        &format!("{}/ir_1*.bmp", lab.display()),
        "--color",
        &format!("{}/color/color_1[0-2].png", syn.display()),
        "--out",
        o,
    ]);
    assert!(
        !ok && text.contains("top-left square is white")
            && text.contains("top-left square is black")
            && text.contains("not of the same board")
            && !text.contains("not in the colour image"),
        "{text}"
    );
    // Colour images of the bundled session paired with IR images of the rendered set (the
    // same 7x5 board, other poses): each camera alone fits, the stereo fit cannot (a user's
    // trial: RMS 39 px, T = 5.9 m, written with exit 0).
    let bundled = manifest_dir().join("data/calib");
    let (ok, text) = kfuse(&[
        "calibrate",
        "--color",
        &format!("{}/color_*.jpg", bundled.display()),
        "--ir",
        &format!("{}/ir/ir_0[1-4].png", syn.display()),
        "--out",
        o,
    ]);
    assert!(
        !ok && text.contains("do not show the same board poses")
            && text.contains("x the single-camera fits'"),
        "{text}"
    );
    // --ir and --color swapped (Kinect sizes): refused before detection.
    let (ok, text) = kfuse(&[
        "calibrate",
        "--color",
        &format!("{}/ir_*.png", bundled.display()),
        "--ir",
        &format!("{}/color_*.jpg", bundled.display()),
        "--out",
        o,
    ]);
    assert!(
        !ok && text.contains("are --ir and --color swapped?") && !text.contains("detecting"),
        "{text}"
    );
    // A pattern matching nothing: in a folder that does not exist, or with the wrong case.
    let (ok, text) = kfuse(&["calibrate", "--ir", "/nonexistent/ir_*.png", "--out", o]);
    assert!(
        !ok && text.contains("no file matches; the folder /nonexistent does not exist"),
        "{text}"
    );
    let upper = format!("{}/IR_*.png", bundled.display());
    let (ok, text) = kfuse(&["calibrate", "--ir", &upper, "--out", o]);
    assert!(!ok && text.contains("4 file(s) match when upper and lower case"), "{text}");
    // An unquoted pattern, expanded by the shell into one option's several values, is used
    // (it was "unexpected argument 'ir_0002.png'").
    let files: Vec<String> =
        (1..=4).map(|i| format!("{}/ir_{i:04}.png", bundled.display())).collect();
    let args = [&["calibrate", "--ir"][..], &files.iter().map(String::as_str).collect::<Vec<_>>()]
        .concat();
    let fresh = tmp.path().join("four.json");
    let (ok, text) = kfuse(&[&args[..], &["--out", fresh.to_str().unwrap()]].concat());
    assert!(ok && text.contains("detecting the board in 4 image(s)"), "{text}");
    std::fs::remove_file(&fresh).unwrap();
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
    let rect = calib::io::read_gray(&out.join("ir_1_rect.bmp")).unwrap();
    let input = calib::io::read_gray(&img).unwrap();
    assert_eq!(rect.size(), (512, 424));
    // Next to the principal point the lens does not move pixels: the same value comes back.
    assert_eq!(rect.get(255, 211), input.get(255, 211));
    // Away from the centre it does (barrel-like k1 > 0 with k2 < 0): the image changed.
    let changed = rect.data().iter().zip(input.data()).filter(|(a, b)| a != b).count();
    assert!(changed > 10_000, "{changed} pixels changed");
    // And by the right amount in the right direction: every board corner found in the output
    // sits where the lens model's inverse (geometry's iterative `undistort`, not the map) puts
    // the corner found in the input. The lab's lens moves these corners by up to a few px;
    // the wrong sign of k1 would double that, applying distortion would too.
    let corners = |img: &geometry::Image<u8>| {
        use calib::detect::{DetectorParams, detect, to_f32};
        let board = calib::Board::new(7, 5, 0.04).unwrap();
        let d = detect(&to_f32(img), &board, &DetectorParams::for_image(512, 424)).unwrap();
        assert!(d.complete);
        d.corners
    };
    let k = geometry::Intrinsics::new(364.126, 365.126, 255.5, 211.5);
    let dist = geometry::Distortion { k1: 0.099, k2: -0.2206, p1: 0.0041, p2: 0.0016, k3: 0.0 };
    let (before, after) = (corners(&input), corners(&rect));
    let (mut worst, mut moved) = (0.0f64, 0.0f64);
    for (b, a) in before.iter().zip(&after) {
        let n = k.from_pixel(b.px.x, b.px.y);
        let u = dist.undistort(n.x, n.y).unwrap();
        let want = k.to_pixel(u.x, u.y);
        worst = worst.max((a.px - want).norm());
        moved = moved.max((want - b.px).norm());
    }
    eprintln!(
        "lab ir_1: corners move up to {moved:.3} px; output within {worst:.3} px of the model"
    );
    // Real corners carry ~0.1 px of detection noise in each image.
    // Derivation: two independent detections of ~0.1 px each differ by ≈ √2 · 0.1 = 0.14 px;
    // 0.3 px is ~2× that. 1 px: the lab lens moves these corners by a few px (see above).
    assert!(moved > 1.0 && worst < 0.3, "moved {moved} px, off by {worst} px");
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
    // The bar stated when this test was added (issue 2's closing report: "tilted ±30° calibrate
    // within 0.5 % of the true focal length"); no tighter measurement is recorded.
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

/// The corpus set with OpenCV's own sample images (`samples/data/left*.jpg`, 9x6 board).
fn opencv_samples(test: &str) -> Option<std::path::PathBuf> {
    Some(shared(test)?.join("calib-corpus/opencv-stereo-640x480-9x6/images"))
}

/// RMS (px) of a single-camera file written by `kfuse calibrate`.
fn rms_of(out: &Path) -> f64 {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out).unwrap()).unwrap();
    v["calibration"]["rms_px"].as_f64().unwrap_or_else(|| panic!("no rms_px in {v}"))
}

#[test]
fn opencv_sample_images_calibrate_with_the_board_size_only_or_auto() {
    let Some(dir) =
        opencv_samples("opencv_sample_images_calibrate_with_the_board_size_only_or_auto")
    else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let pattern = format!("{}/left*.jpg", dir.display());
    for board in ["9x6", "auto"] {
        let out = tmp.path().join(format!("left-{board}.json"));
        let (ok, text) = kfuse(&[
            "calibrate",
            "--color",
            &pattern,
            "--board",
            board,
            "--square",
            "24mm",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "--board {board}: {text}");
        if board == "auto" {
            // The count names the images the board was found in, i.e. the table's rows with
            // corners (it once counted the size search's whole grids: "2 of 13", then 11 used).
            let line = text
                .lines()
                .find(|l| l.contains("--board auto:"))
                .unwrap_or_else(|| panic!("no --board auto line:\n{text}"));
            assert!(line.contains("show a 9x6 grid; using 9x6"), "{line}");
            let said: usize = line
                .split_whitespace()
                .nth(2)
                .and_then(|n| n.parse().ok())
                .unwrap_or_else(|| panic!("{line}"));
            let with_corners = text
                .lines()
                .filter(|l| l.trim_start().starts_with("left") && l.contains(".jpg"))
                .filter(|l| {
                    l.split_whitespace().nth(1).and_then(|n| n.parse::<usize>().ok()) > Some(0)
                })
                .count();
            assert_eq!(said, with_corners, "{text}");
            assert!(said >= 11, "{line}");
        }
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        // OpenCV 5 on the same images (reference.json, classic): fx 536.07, fy 536.02; the
        // 1σ of fx there is ~2 px.
        let fx = v["camera"]["fx"].as_f64().unwrap();
        assert!((fx - 536.07).abs() < 6.0, "--board {board}: fx {fx}\n{text}");
        // OpenCV's best RMS on this camera (cornerSubPix 5x5) is 0.195 px.
        let rms = rms_of(&out);
        assert!(rms < 0.195, "--board {board}: RMS {rms}\n{text}");
        // 13 views tilted 15-41°: fx ± 0.07 %, far from the weak-constraint warning.
        assert!(!text.contains("constrain it weakly"), "{text}");
    }
}

#[test]
fn a_wrong_board_size_says_what_the_images_show() {
    let Some(dir) = opencv_samples("a_wrong_board_size_says_what_the_images_show") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("left.json");
    let pattern = format!("{}/left*.jpg", dir.display());
    // A smaller board than the images show: never calibrated on a sub-grid.
    let (ok, text) = kfuse(&[
        "calibrate",
        "--color",
        &pattern,
        "--board",
        "7x5",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        !ok && text.contains("these images show a 9x6 grid") && text.contains("you asked for 7x5"),
        "{text}"
    );
    // The count is of the images `--board 9x6` then finds the board in: all 13 (as the test
    // above calibrates on), not the images whose whole grid the size search alone sees (2 of 13
    // before it peeled the border's spurious junctions off; 13 now, `corpus.rs`).
    assert!(text.contains("(found in 13 of 13 images)"), "{text}");
    assert!(!out.exists());
}

#[test]
fn an_image_of_another_size_is_left_out_and_the_rest_calibrate() {
    let Some(data) = shared("an_image_of_another_size_is_left_out_and_the_rest_calibrate") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cam.json");
    // 20 board images, two of them 1281x721 among 1280x720 (the corpus README).
    let pattern = format!(
        "{}/calib-corpus/udacity-camera-cal-1280x720-9x6/images/calibration*.jpg",
        data.display()
    );
    let text = calibrate_color(&pattern, "9x6", &[], &out);
    for odd in ["calibration7.jpg", "calibration15.jpg"] {
        let line = text
            .lines()
            .find(|l| l.contains(odd))
            .unwrap_or_else(|| panic!("{odd} not listed:\n{text}"));
        assert!(line.contains("1281x721") && line.contains("REJECTED"), "{line}");
        // A view that was not used has no error or tilt: `-`, not NaN.
        assert!(!line.contains("NaN") && line.split_whitespace().nth(2) == Some("-"), "{line}");
    }
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(v["camera"]["width"].as_u64(), Some(1280), "{text}");
    // The handout's 0.2 px bar is the Kinect colour camera's: this 1280x720 camera calibrates
    // to ~0.86 px (OpenCV: 0.853 px), and one note says the bar is not applied instead of a
    // warning on every view.
    assert!(v["calibration"]["rms_px"].as_f64().is_some_and(|r| r > 0.2), "{text}");
    assert!(!text.contains("WARNING"), "{text}");
    assert!(text.contains("bar is for the Kinect's images; these are 1280x720"), "{text}");
}

/// A 9x6 board (10x7 squares, top-left black, one-square white margin) seen through a lens
/// `dist` with intrinsics `k`, rendered by undistorting each of 3x3 sub-pixel samples' rays
/// (geometry's iterative inverse, independent of the undistortion map), then a 3x3 binomial
/// blur. Returns the image and the board's pinhole projection (corner `id` → pixel).
fn render_distorted(
    k: geometry::Intrinsics,
    dist: geometry::Distortion,
    (w, h): (usize, usize),
) -> (image::GrayImage, impl Fn(usize) -> nalgebra::Vector2<f64>) {
    use nalgebra::{Rotation3, Vector3};
    let r = *Rotation3::from_euler_angles(0.25, -0.12, 0.15).matrix();
    let t = Vector3::new(0.0, 0.0, 14.0) - r * Vector3::new(4.0, 2.5, 0.0);
    let m = nalgebra::Matrix3::from_columns(&[r.column(0).into(), r.column(1).into(), t]);
    let inv = m.try_inverse().unwrap();
    let albedo = |u: f64, v: f64| -> f64 {
        let n = k.from_pixel(u, v);
        let Some(n) = dist.undistort(n.x, n.y) else { return 90.0 };
        let q = inv * Vector3::new(n.x, n.y, 1.0);
        let (x, y) = (q.x / q.z, q.y / q.z);
        if !(-2.0..=10.0).contains(&x) || !(-2.0..=7.0).contains(&y) {
            90.0
        } else if x < -1.0 || y < -1.0 || x > 9.0 || y > 6.0 {
            220.0
        } else if ((x.floor() + y.floor()) as i64).rem_euclid(2) == 0 {
            30.0
        } else {
            220.0
        }
    };
    let sharp: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            let mut acc = 0.0;
            for a in [-1.0, 0.0, 1.0] {
                for b in [-1.0, 0.0, 1.0] {
                    acc += albedo(x + a / 3.0, y + b / 3.0);
                }
            }
            acc / 9.0
        })
        .collect();
    let at = |x: i64, y: i64| {
        sharp[(y.clamp(0, h as i64 - 1) as usize) * w + x.clamp(0, w as i64 - 1) as usize]
    };
    let img = image::GrayImage::from_fn(w as u32, h as u32, |x, y| {
        let (x, y) = (x as i64, y as i64);
        let mut acc = 0.0;
        for (dy, ky) in [(-1, 1.0), (0, 2.0), (1, 1.0)] {
            for (dx, kx) in [(-1, 1.0), (0, 2.0), (1, 1.0)] {
                acc += kx * ky * at(x + dx, y + dy);
            }
        }
        image::Luma([(acc / 16.0).round() as u8])
    });
    let pinhole = move |id: usize| {
        let c = r * Vector3::new((id % 9) as f64, (id / 9) as f64, 0.0) + t;
        k.to_pixel(c.x / c.z, c.y / c.z)
    };
    (img, pinhole)
}

/// Largest distance (px) of a point from the total-least-squares line through all of them.
fn line_residual(pts: &[nalgebra::Vector2<f64>]) -> f64 {
    let m = pts.iter().sum::<nalgebra::Vector2<f64>>() / pts.len() as f64;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in pts {
        let d = p - m;
        (sxx, sxy, syy) = (sxx + d.x * d.x, sxy + d.x * d.y, syy + d.y * d.y);
    }
    let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let normal = nalgebra::Vector2::new(-theta.sin(), theta.cos());
    pts.iter().map(|p| (p - m).dot(&normal).abs()).fold(0.0, f64::max)
}

/// (worst corner distance to `truth`, worst row/column line residual) of the 9x6 board found
/// in `img`, `None` when it is not found whole.
fn corners_vs_truth(
    img: &image::GrayImage,
    truth: &dyn Fn(usize) -> nalgebra::Vector2<f64>,
) -> Option<(f64, f64)> {
    use calib::detect::{DetectorParams, detect, to_f32};
    let g = geometry::Image::from_vec(
        img.width() as usize,
        img.height() as usize,
        img.as_raw().clone(),
    )
    .unwrap();
    let board = calib::Board::new(9, 6, 1.0).unwrap();
    let d = detect(&to_f32(&g), &board, &DetectorParams::for_image(g.width(), g.height()))?;
    if !d.complete {
        return None;
    }
    let at = |id: usize| d.corners[id].px;
    let worst = d.corners.iter().map(|c| (c.px - truth(c.id)).norm()).fold(0.0, f64::max);
    let rows = (0..6).map(|y| line_residual(&(0..9).map(|x| at(y * 9 + x)).collect::<Vec<_>>()));
    let cols = (0..9).map(|x| line_residual(&(0..6).map(|y| at(y * 9 + x)).collect::<Vec<_>>()));
    Some((worst, rows.chain(cols).fold(0.0, f64::max)))
}

/// `kfuse undistort` against truth: a board rendered through a known barrel lens comes out with
/// its corners on the pinhole projection (within 0.15 px: detector error ~0.03 px plus the
/// bilinear resampling) and its rows and columns straight (within 0.1 px); the same run with
/// the wrong sign of k1 in the rig misses both by far.
#[test]
fn undistort_puts_corners_on_the_pinhole_projection() {
    let tmp = tempfile::tempdir().unwrap();
    let (w, h) = (512usize, 424usize);
    let k = geometry::Intrinsics::new(365.0, 365.0, 255.5, 211.5);
    let dist = geometry::Distortion { k1: -0.3, k2: 0.08, p1: 0.001, p2: -0.0006, k3: 0.0 };
    let (img, truth) = render_distorted(k, dist, (w, h));
    let input = tmp.path().join("ir_1.png");
    img.save(&input).unwrap();
    let (corner_in, bend_in) = corners_vs_truth(&img, &truth).expect("board in the input");
    assert!(corner_in > 3.0 && bend_in > 1.0, "the input is distorted: {corner_in} {bend_in}");
    let mut results = Vec::new();
    for k1 in [dist.k1, -dist.k1] {
        let rig = tmp.path().join("rig.json");
        let cam = format!(
            r#"{{"width":{w},"height":{h},"fx":365,"fy":365,"cx":255.5,"cy":211.5,"k1":{k1},"k2":{},"p1":{},"p2":{},"k3":0}}"#,
            dist.k2, dist.p1, dist.p2
        );
        std::fs::write(
            &rig,
            format!(
                r#"{{"format":"kfuse-rig","version":1,"depth_camera":{cam},"color_camera":{cam},
                "color_from_depth":{{"rotation":[[1,0,0],[0,1,0],[0,0,1]],"translation_m":[-0.052,0,0]}}}}"#
            ),
        )
        .unwrap();
        let out = tmp.path().join(format!("rect{k1}"));
        let (ok, text) = kfuse(&[
            "undistort",
            "--rig",
            rig.to_str().unwrap(),
            "--camera",
            "depth",
            input.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "{text}");
        let rect = image::open(out.join("ir_1_rect.png")).unwrap().to_luma8();
        results.push(corners_vs_truth(&rect, &truth));
    }
    eprintln!(
        "input: corners {corner_in:.3} px, bend {bend_in:.3} px; undistorted: {:?}; wrong sign: {:?}",
        results[0], results[1]
    );
    let (corner, bend) = results[0].expect("board found after undistortion");
    assert!(corner < 0.15 && bend < 0.1, "corner {corner} px, bend {bend} px");
    assert!(
        results[1].is_none_or(|(c, b)| c > 1.5 && b > 1.0),
        "wrong k1 sign passed: {:?}",
        results[1]
    );
}

/// The per-image table row of `name` in `kfuse calibrate`'s output.
fn table_row<'a>(text: &'a str, name: &str) -> &'a str {
    text.lines()
        .find(|l| l.trim_start().starts_with(name))
        .unwrap_or_else(|| panic!("{name} not listed:\n{text}"))
}

/// Files from a user's trial: a JPEG cut short is listed as such and left out (it was decoded
/// with its missing part grey, and reported as "no board found"), and a 16-bit PNG holding
/// 8-bit values calibrates exactly as the 8-bit image (it was divided by 257 to two grey
/// levels: view RMS 0.32 instead of 0.17 px).
#[test]
fn a_cut_jpeg_is_named_and_a_16_bit_copy_gives_the_same_corners() {
    let Some(dir) = opencv_samples("a_cut_jpeg_is_named_and_a_16_bit_copy_gives_the_same_corners")
    else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (plain, cut, wide) =
        (tmp.path().join("plain"), tmp.path().join("cut"), tmp.path().join("wide"));
    for d in [&plain, &cut, &wide] {
        std::fs::create_dir(d).unwrap();
        for i in 1..=14 {
            let name = format!("left{i:02}.jpg");
            if dir.join(&name).is_file() {
                std::fs::copy(dir.join(&name), d.join(&name)).unwrap();
            }
        }
    }
    let bytes = std::fs::read(dir.join("left09.jpg")).unwrap();
    std::fs::write(cut.join("left09.jpg"), &bytes[..bytes.len() * 3 / 4]).unwrap();
    let grey = image::open(dir.join("left09.jpg")).unwrap().to_luma8();
    let (w, h) = (grey.width() as usize, grey.height() as usize);
    let values: Vec<u16> = grey.into_raw().into_iter().map(u16::from).collect();
    std::fs::remove_file(wide.join("left09.jpg")).unwrap();
    kfuse_io::images::write_u16_png(
        &wide.join("left09.png"),
        &geometry::Image::from_vec(w, h, values).unwrap(),
    )
    .unwrap();
    let run = |d: &Path| {
        calibrate_color(&format!("{}/left*", d.display()), "9x6", &[], &d.join("cam.json"))
    };
    let (plain, cut, wide) = (run(&plain), run(&cut), run(&wide));
    let row = table_row(&cut, "left09.jpg");
    assert!(row.contains("REJECTED") && row.contains("truncated JPEG"), "{row}");
    // The file is named once per line (the reader's message named it again).
    assert_eq!(row.matches("left09.jpg").count(), 1, "{row}");
    // The same grey values, so the same corners: the same row to the printed digits.
    let cells = |row: &str| row.split_whitespace().skip(1).collect::<Vec<_>>().join(" ");
    assert_eq!(cells(table_row(&wide, "left09.png")), cells(table_row(&plain, "left09.jpg")));
}

/// The corpus's robot-arm set: 5 views tilted 15–25° leave the focal length at ± 3.5 % (1σ)
/// and cy at ± 3.3 % (OpenCV's classic and SB calibrations of it: fx ± 80 and ± 76 px,
/// reference.json's std_intrinsics):
/// the command says so and what views to add, instead of only printing the ± figures.
#[test]
fn few_similar_views_are_warned_about() {
    let Some(data) = shared("few_similar_views_are_warned_about") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("arm.json");
    let pattern =
        format!("{}/calib-corpus/color-1920x1080-9x6-robotarm/images/*.png", data.display());
    let text = calibrate_color(&pattern, "9x6", &["--square", "24mm"], &out);
    let line = text
        .lines()
        .find(|l| l.contains("constrain it weakly"))
        .unwrap_or_else(|| panic!("no weak-constraint warning:\n{text}"));
    assert!(line.contains("WARNING") && line.contains("these 5 views"), "{line}");
    assert!(line.contains("fx ± ") && line.contains("cy ± ") && line.contains("tilted"), "{line}");
}

/// The rendered IR images (principal point at the image centre) `n` of them, each padded with
/// `pad` columns on the left (the edge column repeated), into `dir`: padding moves the image
/// centre by pad/2 but the principal point by pad, so fixing it at the centre becomes wrong.
fn padded_rendered_ir(data: &Path, dir: &Path, pad: u32) {
    std::fs::create_dir_all(dir).unwrap();
    for i in 1..=15 {
        let src = image::open(data.join(format!("synthetic-calib/ir/ir_{i:02}.png"))).unwrap();
        let g = src.to_luma8();
        let out = image::GrayImage::from_fn(g.width() + pad, g.height(), |x, y| {
            *g.get_pixel(x.saturating_sub(pad), y)
        });
        out.save(dir.join(format!("ir_{i:02}.png"))).unwrap();
    }
}

/// `--fix-principal-point` on the rendered IR set (principal point at the centre): no warning.
/// The same images with 48 columns added on the left (principal point 24 px off the new
/// centre): one warning line naming the focal lengths' moves and σ, and the check in the
/// camera file's report.
#[test]
fn fixing_the_principal_point_is_warned_about_only_where_it_is_wrong() {
    let Some(data) = shared("fixing_the_principal_point_is_warned_about_only_where_it_is_wrong")
    else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let run = |pattern: &str, out: &Path| {
        let args = ["calibrate", "--ir", pattern, "--fix-principal-point", "--out"];
        let (ok, text) = kfuse(&[&args[..], &[out.to_str().unwrap()]].concat());
        assert!(ok, "{text}");
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out).unwrap()).unwrap();
        (text, v["calibration"]["fixed_parameter_checks"]["checks"][0].clone())
    };
    let (text, check) = run(
        &format!("{}/synthetic-calib/ir/ir_*.png", data.display()),
        &tmp.path().join("centred.json"),
    );
    assert!(!text.contains("--fix-principal-point (or --lab-settings) moves"), "{text}");
    assert_eq!(check["moved"].as_array().map(Vec::len), Some(0), "{check}");
    let padded = tmp.path().join("padded");
    padded_rendered_ir(&data, &padded, 48);
    let (text, check) =
        run(&format!("{}/ir_*.png", padded.display()), &tmp.path().join("padded.json"));
    let warnings: Vec<&str> = text
        .lines()
        .filter(|l| l.contains("--fix-principal-point (or --lab-settings) moves"))
        .collect();
    assert_eq!(warnings.len(), 1, "{text}");
    let line = warnings[0];
    eprintln!("{line}");
    assert!(
        line.contains("WARNING: IR camera") && line.contains("fx by +") && line.contains("σ (σ "),
        "{line}"
    );
    let moved = check["moved"].as_array().unwrap();
    let fx = moved.iter().find(|m| m["parameter"] == "fx").expect("fx moved");
    let sigmas = (fx["fixed_fit"].as_f64().unwrap() - fx["free_fit"].as_f64().unwrap()).abs()
        / fx["free_std"].as_f64().unwrap();
    assert!(sigmas > calib::mono::FIX_SHIFT_SIGMAS, "{fx}");
    // The free fit finds the principal point where the padding put it: 255.5 + 48.
    let cx = check["freed"].as_array().unwrap().iter().find(|m| m["parameter"] == "cx").unwrap();
    assert!((cx["free_fit"].as_f64().unwrap() - 303.5).abs() < 0.5, "{cx}");
}

/// Fewer than three images with a board: the error names each image left out and why (no
/// board found, another image size); nothing is written.
#[test]
fn too_few_boards_name_the_images_without_one_and_why() {
    let Some(data) = shared("too_few_boards_name_the_images_without_one_and_why") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let blank = tmp.path().join("blank.png");
    image::GrayImage::from_pixel(512, 424, image::Luma([128u8])).save(&blank).unwrap();
    let small = tmp.path().join("small.png");
    image::GrayImage::from_pixel(640, 480, image::Luma([128u8])).save(&small).unwrap();
    let syn = data.join("synthetic-calib/ir");
    let out = tmp.path().join("ir.json");
    let (ok, text) = kfuse(&[
        "calibrate",
        "--ir",
        syn.join("ir_01.png").to_str().unwrap(),
        syn.join("ir_02.png").to_str().unwrap(),
        blank.to_str().unwrap(),
        small.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!ok, "{text}");
    for want in [
        "only 2 usable view(s)",
        "blank.png (no board found)",
        "small.png (image is 640x480, the camera's other images are 512x424)",
    ] {
        assert!(text.contains(want), "{want}: {text}");
    }
    assert!(!out.exists());
}

/// `calibrate --report` on the rendered stereo set prints the held-out check and writes it to
/// report.json: IR, colour and the colour camera through the rig, 7 held-out pairs of 35
/// corners; each camera's median within 2× its in-sample RMS, through the rig within 5× the
/// colour RMS (the bars of `calib`'s rendered-set test, `crates/calib/tests/synthetic.rs`).
#[test]
fn the_stereo_report_holds_the_held_out_check_through_the_rig() {
    let Some(data) = shared("the_stereo_report_holds_the_held_out_check_through_the_rig") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let syn = data.join("synthetic-calib");
    let report = tmp.path().join("report");
    let (ok, text) = kfuse(&[
        "calibrate",
        "--ir",
        &format!("{}/ir/ir_*.png", syn.display()),
        "--color",
        &format!("{}/color/color_*.png", syn.display()),
        "--out",
        tmp.path().join("rig.json").to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
    assert!(text.contains("held-out check: calibrated on 8 views"), "{text}");
    assert!(text.lines().any(|l| l.trim_start().starts_with("colour through the rig")), "{text}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.join("report.json")).unwrap())
            .unwrap();
    let errors = r["held_out"]["errors"].as_array().unwrap();
    let whats: Vec<&str> = errors.iter().map(|e| e["what"].as_str().unwrap()).collect();
    assert_eq!(whats, ["IR", "colour", "colour through the rig"]);
    for e in errors {
        let (median, rms) =
            (e["median_px"].as_f64().unwrap(), e["in_sample_rms_px"].as_f64().unwrap());
        let factor = if e["what"] == "colour through the rig" { 5.0 } else { 2.0 };
        assert_eq!(e["corners"].as_u64(), Some(7 * 35), "{e}");
        assert!(median > 0.0 && median <= factor * rms, "{e}");
    }
}

/// Slack for comparing sums of stage times with the wall time they are part of, ms: the values
/// are sums of f64 milliseconds, exact to far below this.
const TIMING_EPSILON_MS: f64 = 1e-6;

/// Checks `report.json`'s `timings_ms` and the `--timings` lines of a run: every stage of
/// `stages` present (and no other), each finite and ≥ 0, their sum at most the wall time; one
/// per-image entry per image of each camera (`(camera, file names)`), each within its
/// camera's read and detect stage; `text` holds the summary lines.
fn check_timings(
    r: &serde_json::Value,
    stages: &[&str],
    images: &[(&str, Vec<String>)],
    text: &str,
) {
    let t = &r["timings_ms"];
    let wall = t["wall_ms"].as_f64().unwrap_or_else(|| panic!("no wall_ms: {t}"));
    assert!(wall.is_finite() && wall > 0.0, "{t}");
    let listed: Vec<(&str, f64)> = t["stages"]
        .as_array()
        .unwrap_or_else(|| panic!("no stages: {t}"))
        .iter()
        .map(|s| (s["stage"].as_str().unwrap(), s["ms"].as_f64().unwrap()))
        .collect();
    let mut names: Vec<&str> = listed.iter().map(|s| s.0).collect();
    names.sort_unstable();
    let mut want = stages.to_vec();
    want.sort_unstable();
    assert_eq!(names, want, "{t}");
    for (name, ms) in &listed {
        assert!(ms.is_finite() && *ms >= 0.0, "{name}: {ms}");
    }
    let sum: f64 = listed.iter().map(|s| s.1).sum();
    assert!(sum <= wall + TIMING_EPSILON_MS, "stages {sum} ms > wall {wall} ms: {t}");
    let stage = |name: &str| listed.iter().find(|s| s.0 == name).map(|s| s.1).unwrap();
    let per_image = t["per_image"].as_array().unwrap_or_else(|| panic!("no per_image: {t}"));
    assert_eq!(per_image.len(), images.iter().map(|(_, f)| f.len()).sum::<usize>(), "{t}");
    for (camera, files) in images {
        let of: Vec<&serde_json::Value> =
            per_image.iter().filter(|i| i["camera"] == *camera).collect();
        let got: Vec<&str> = of.iter().map(|i| i["name"].as_str().unwrap()).collect();
        assert_eq!(got, files.iter().map(String::as_str).collect::<Vec<_>>(), "{camera}");
        let (read, detect) = (stage(&format!("read {camera}")), stage(&format!("detect {camera}")));
        for i in of {
            let (r, d) = (i["read_ms"].as_f64().unwrap(), i["detect_ms"].as_f64().unwrap());
            assert!(r.is_finite() && r >= 0.0 && r <= read + TIMING_EPSILON_MS, "{i} {read}");
            assert!(d.is_finite() && d >= 0.0 && d <= detect + TIMING_EPSILON_MS, "{i} {detect}");
        }
        assert!(text.contains(&format!("per {camera} image (own thread): read median")), "{text}");
    }
    assert!(text.lines().any(|l| l.starts_with("timings: ") && l.ends_with(" ms wall")), "{text}");
    for name in stages.iter().chain(&["write report.json", "publish outputs", "(not in a stage)"]) {
        assert!(
            text.lines().any(|l| l.trim_start().starts_with(name) && l.contains(" ms ")),
            "no --timings line for {name}: {text}"
        );
    }
}

/// The file names of a pattern's matches, sorted as `calibrate` sorts them (these sets are
/// numbered with leading zeros, or as ir_1 … ir_12, which the natural sort orders).
fn names_of(dir: &Path, prefix: &str, ext: &str) -> Vec<String> {
    let mut v: Vec<(u32, String)> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter_map(|n| {
            let num = n.strip_prefix(prefix)?.strip_suffix(ext)?.parse().ok()?;
            Some((num, n))
        })
        .collect();
    v.sort();
    v.into_iter().map(|(_, n)| n).collect()
}

/// A stereo run with `--report --timings` (6 rendered pairs, enough for the held-out check)
/// times every stage of the pipeline and every image of both cameras.
#[test]
fn the_stereo_report_times_every_stage_and_image() {
    let Some(data) = shared("the_stereo_report_times_every_stage_and_image") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let syn = data.join("synthetic-calib");
    let report = tmp.path().join("report");
    let (ok, text) = kfuse(&[
        "calibrate",
        "--ir",
        &format!("{}/ir/ir_0[1-6].png", syn.display()),
        "--color",
        &format!("{}/color/color_0[1-6].png", syn.display()),
        "--out",
        tmp.path().join("rig.json").to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
        "--timings",
    ]);
    assert!(ok, "{text}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.join("report.json")).unwrap())
            .unwrap();
    let first6 = |mut v: Vec<String>| {
        v.truncate(6);
        v
    };
    let images = [
        ("IR", first6(names_of(&syn.join("ir"), "ir_", ".png"))),
        ("colour", first6(names_of(&syn.join("color"), "color_", ".png"))),
    ];
    let stages = [
        "read IR",
        "detect IR",
        "read colour",
        "detect colour",
        "fit mono IR",
        "fit mono colour",
        "fit stereo",
        "σ (uncertainty)",
        "held-out check",
        "worker threads",
        "write rig files",
        "write report figures",
    ];
    check_timings(&r, &stages, &images, &text);
    // The rig file stays what it was: no timings in it (a rerun gives the same rig).
    let rig = std::fs::read_to_string(tmp.path().join("rig.json")).unwrap();
    assert!(!rig.contains("timings"), "timings leaked into the rig file");
}

/// `--timings` on the real IR session: with --report, report.json's split holds the
/// constraint checks of --lab-settings and all 12 images; without --report the summary is
/// printed all the same; without --timings it is not.
#[test]
fn timings_of_a_single_camera_run_are_in_the_report_and_on_stderr() {
    let Some(data) = shared("timings_of_a_single_camera_run_are_in_the_report_and_on_stderr")
    else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let lab = data.join("kinect-lab");
    let pattern = format!("{}/ir_*.bmp", lab.display());
    let out = tmp.path().join("ir.json");
    let report = tmp.path().join("report");
    let base = ["calibrate", "--ir", &pattern, "--lab-settings", "--out", out.to_str().unwrap()];
    let (ok, text) =
        kfuse(&[&base[..], &["--report", report.to_str().unwrap(), "--timings"]].concat());
    assert!(ok, "{text}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.join("report.json")).unwrap())
            .unwrap();
    let names = names_of(&lab, "ir_", ".bmp");
    assert_eq!(names.len(), 12);
    let stages = [
        "read IR",
        "detect IR",
        "fit mono IR",
        "σ (uncertainty)",
        "constraint checks",
        "held-out check",
        "worker threads",
        "write rig files",
        "write report figures",
    ];
    check_timings(&r, &stages, &[("IR", names)], &text);

    let (ok, text) = kfuse(&[&base[..], &["--timings"]].concat());
    assert!(ok, "{text}");
    for line in ["timings: ", "  read IR ", "  detect IR ", "  fit mono IR ", "  publish outputs "]
    {
        assert!(text.lines().any(|l| l.starts_with(line)), "{line}: {text}");
    }
    assert!(!text.contains("held-out check "), "no held-out check without --report: {text}");
    let (ok, text) = kfuse(&base);
    assert!(ok, "{text}");
    assert!(!text.lines().any(|l| l.starts_with("timings: ")), "{text}");
}

/// The bundled calibration set (`data/calib`: four IR + colour shots of the simulated Kinect).
fn bundled_calib() -> std::path::PathBuf {
    manifest_dir().join("data/calib")
}

/// Joint calibration (issue 51): a 1920x1080 colour shot among a camera's 512x424 IR images is
/// refused before any detection, in one line naming the camera, the file, both sizes and the
/// fix, and no rig is written. Before, its corners were fitted into the 512x424 camera and a
/// rig was written with exit 0 (checked by reverting the size check in
/// `calib::pipeline::joint`).
#[test]
fn joint_calibration_refuses_an_image_of_another_size() {
    let data = bundled_calib();
    let tmp = tempfile::tempdir().unwrap();
    let mixed = tmp.path().join("mixed");
    std::fs::create_dir(&mixed).unwrap();
    for i in 1..=3 {
        let f = format!("ir_000{i}.png");
        std::fs::copy(data.join(&f), mixed.join(&f)).unwrap();
    }
    std::fs::copy(data.join("color_0004.jpg"), mixed.join("color_0004.jpg")).unwrap();
    let out = tmp.path().join("rig.json");
    let out_s = out.to_str().unwrap();
    let depth = format!("0001.depth={}/*", mixed.display());
    let color = format!("0001.color={}/color_*.jpg", data.display());
    let out_run = Command::new(env!("CARGO_BIN_EXE_kfuse"))
        .args(["calibrate", "--camera", &depth, "--camera", &color, "--out", out_s])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out_run.stderr);
    assert!(!out_run.status.success(), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("camera 0001.depth")
            && err.contains("color_0004.jpg is 1920x1080")
            && err.contains("a colour image among the IR ones")
            && err.contains("ir_0001.png is 512x424")
            && err.contains("give each camera only its own images"),
        "{err}"
    );
    assert!(!out.exists());
}

/// Joint calibration (issue 51) runs the plausibility check of `rig import`, `rig show` and
/// `fuse` (`MultiRig::plausibility_problems`): the same IR images given as a Kinect's depth and
/// colour cameras calibrate to two cameras at one place (baseline 0 against the 5 mm minimum),
/// which is refused in one line naming the sensor, the baseline and the fix, with no rig
/// written. Before, the rig was written with exit 0 (checked by reverting the check).
#[test]
fn joint_calibration_refuses_a_rig_that_fuse_would_refuse() {
    let data = bundled_calib();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("rig.json");
    let ir = format!("{}/ir_*.png", data.display());
    let (depth, color) = (format!("0001.depth={ir}"), format!("0001.color={ir}"));
    let out_run = Command::new(env!("CARGO_BIN_EXE_kfuse"))
        .args(["calibrate", "--camera", &depth, "--camera", &color])
        .args(["--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out_run.stderr);
    assert!(!out_run.status.success(), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("sensor \"0001\": the baseline |T|")
            && err.contains("is under 5 mm")
            && err.contains("each camera's images are its own")
            && err.contains("nothing was written"),
        "{err}"
    );
    assert!(!out.exists());
}

/// This package's folder from the `CARGO_MANIFEST_DIR` cargo sets when it runs the test, not
/// the path compiled in: a test binary reused from a checkout at another path (a shared target
/// directory) must read this checkout's files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map(std::path::PathBuf::from).expect("run by cargo test")
}
