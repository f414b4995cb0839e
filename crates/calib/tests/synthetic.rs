//! The rendered set `synthetic-calib/`: detection and calibration against exact ground truth,
//! and against OpenCV's results on the same images (`opencv_reference.json`).

mod common;

use std::path::Path;
use std::sync::OnceLock;

use calib::detect::{align_pair, detect_views, rotate_180};
use calib::{StereoOptions, ViewCorners, calibrate_stereo};
use common::*;
use geometry::Image;
use nalgebra::Vector2;

fn load_gray(path: &Path) -> Image<u8> {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_luma8();
    Image::from_vec(img.width() as usize, img.height() as usize, img.into_raw()).unwrap()
}

/// (IR views, colour views aligned to their IR partner), detected once per test binary: the
/// 15 colour PNGs are 1920x1080 and decoding them dominates the test time.
fn views(data: &Path) -> &'static (Vec<ViewCorners>, Vec<ViewCorners>) {
    static V: OnceLock<(Vec<ViewCorners>, Vec<ViewCorners>)> = OnceLock::new();
    V.get_or_init(|| {
        let run = |cam: &str| {
            let imgs: Vec<(String, Image<u8>)> = (1..=15)
                .map(|i| {
                    let name = format!("{cam}/{cam}_{i:02}.png");
                    let img = load_gray(&data.join("synthetic-calib").join(&name));
                    (name, img)
                })
                .collect();
            let refs: Vec<(String, &Image<u8>)> =
                imgs.iter().map(|(n, i)| (n.clone(), i)).collect();
            detect_views(&refs, &board()).0
        };
        let ir = run("ir");
        let color = run("color");
        let color = ir.iter().zip(&color).map(|(d, c)| align_pair(d, c, &board())).collect();
        (ir, color)
    })
}

/// Mean corner error against the truth, allowing the board's 180° symmetry per view.
fn corner_error(views: &[ViewCorners], gt: &serde_json::Value, cam: &str) -> (f64, f64, usize) {
    let (mut sum, mut max, mut n) = (0.0, 0.0f64, 0);
    for (i, v) in views.iter().enumerate() {
        let truth = corners_from(&gt["views"][i][cam]["corners_px"], "", 0, 0);
        let err = |v: &ViewCorners| {
            v.corners.iter().map(|c| (c.px - truth.get(c.id).unwrap()).norm()).collect::<Vec<_>>()
        };
        let a = err(v);
        let b = err(&rotate_180(v, &board()));
        let e = if a.iter().sum::<f64>() <= b.iter().sum::<f64>() { a } else { b };
        sum += e.iter().sum::<f64>();
        max = e.iter().copied().fold(max, f64::max);
        n += e.len();
    }
    (sum / n as f64, max, n)
}

#[test]
fn rendered_corners_are_as_accurate_as_opencvs() {
    let Some(data) = shared_data("rendered_corners_are_as_accurate_as_opencvs") else { return };
    let gt = json(data.join("synthetic-calib/ground_truth.json"));
    let cv = json(data.join("synthetic-calib/opencv_reference.json"));
    let (ir, color) = views(&data);
    for (cam, views, key) in [("ir", ir, "classic_ir"), ("color", color, "classic_color")] {
        assert!(
            views.iter().all(|v| v.corners.len() == 35),
            "{cam}: {:?}",
            views.iter().map(|v| v.corners.len()).collect::<Vec<_>>()
        );
        let (mean, max, n) = corner_error(views, &gt, cam);
        let theirs = f(&cv["detection_summary"][key]["mean_err_px"]);
        eprintln!(
            "{cam}: {n} corners, mean error {mean:.4} px (OpenCV classic {theirs:.4}), max {max:.3}"
        );
        // The bar of synthetic-calib/README.md: OpenCV's classic corners' mean error.
        assert!(mean <= theirs, "{cam}: {mean} vs {theirs}");
    }
}

#[test]
fn rendered_pair_labels_agree_between_cameras() {
    let Some(data) = shared_data("rendered_pair_labels_agree_between_cameras") else { return };
    let gt = json(data.join("synthetic-calib/ground_truth.json"));
    let (ir, color) = views(&data);
    // Each camera's labelling, corner by corner against the rendered truth: either every
    // corner k sits on the truth's corner k, or (the 7x5 board is 180° symmetric) every corner
    // sits on the truth's corner 34 − k. A view matching neither is mislabelled; a pair whose
    // cameras match different twins would pair corner k with corner 34 − k in the stereo fit.
    // 1 px: the worst rendered corner error is 0.2 px (rendered_corners_are_as_accurate_as_opencvs),
    // a wrong label is at least one 40 mm square (> 25 px in both cameras) away.
    #[derive(Debug, PartialEq)]
    enum Labels {
        AsTruth,
        Rotated180,
    }
    let labels = |v: &ViewCorners, i: usize, cam: &str| -> Labels {
        let t = corners_from(&gt["views"][i][cam]["corners_px"], "", 0, 0);
        let worst = |v: &ViewCorners| {
            v.corners.iter().map(|c| (c.px - t.get(c.id).unwrap()).norm()).fold(0.0, f64::max)
        };
        let (direct, twin) = (worst(v), worst(&rotate_180(v, &board())));
        assert_eq!(v.corners.len(), 35, "view {} {cam}: all corners found", i + 1);
        if direct < 1.0 {
            Labels::AsTruth
        } else if twin < 1.0 {
            Labels::Rotated180
        } else {
            panic!(
                "view {} {cam}: labels match neither the truth ({direct:.2} px) nor its 180° twin ({twin:.2} px)",
                i + 1
            )
        }
    };
    for i in 0..15 {
        assert_eq!(labels(&ir[i], i, "ir"), labels(&color[i], i, "color"), "view {}", i + 1);
    }
}

#[test]
fn rendered_stereo_beats_the_bars_and_opencv() {
    let Some(data) = shared_data("rendered_stereo_beats_the_bars_and_opencv") else { return };
    let gt = json(data.join("synthetic-calib/ground_truth.json"));
    let cv = json(data.join("synthetic-calib/opencv_reference.json"));
    let (ir, color) = views(&data);
    let r = calibrate_stereo(&board(), ir, color, &StereoOptions::default(), None, None).unwrap();
    let truth_cfd = gt_color_from_depth(&gt);
    let dt = (r.color_from_depth.translation - truth_cfd.translation).norm() * 1000.0;
    let dr = rotation_error_deg(&r.color_from_depth, &truth_cfd);
    let joint = &cv["calibration_from_classic_corners"]["stereo"]["joint_standard5"];
    let (cv_dt, cv_dr) = (f(&joint["T_error_norm_mm"]), f(&joint["rotation_error_deg"]));
    eprintln!(
        "stereo |dT| {dt:.4} mm (OpenCV {cv_dt:.4}), rotation {dr:.4}° (OpenCV {cv_dr:.4}), rms {:.4} / {:.4} px",
        r.depth_rms_px, r.color_rms_px
    );
    for (cam, model, key, std) in
        [("ir", r.depth, "cam1", r.depth_std), ("color", r.color, "cam2", r.color_std)]
    {
        let truth = gt_camera(&gt, cam);
        let k = model.intrinsics;
        let t = truth.intrinsics;
        let c = &joint[key];
        let efx = (k.fx / t.fx - 1.0).abs();
        let efy = (k.fy / t.fy - 1.0).abs();
        let epp = Vector2::new(k.cx - t.cx, k.cy - t.cy);
        let cv_fx = (f(&c["fx"]) / t.fx - 1.0).abs();
        let cv_fy = (f(&c["fy"]) / t.fy - 1.0).abs();
        let cv_pp = Vector2::new(f(&c["cx"]) - t.cx, f(&c["cy"]) - t.cy);
        eprintln!(
            "{cam}: fx err {:.4}% (OpenCV {:.4}%), fy {:.4}% ({:.4}%), pp err ({:.4}, {:.4}) px (OpenCV ({:.4}, {:.4}))",
            100.0 * efx,
            100.0 * cv_fx,
            100.0 * efy,
            100.0 * cv_fy,
            epp.x,
            epp.y,
            cv_pp.x,
            cv_pp.y
        );
        // Honest uncertainty on the rendered images: the truth within ±3σ.
        for (e, s) in [
            (k.fx - t.fx, std.fx),
            (k.fy - t.fy, std.fy),
            (k.cx - t.cx, std.cx),
            (k.cy - t.cy, std.cy),
        ] {
            assert!(e.abs() < 3.0 * s, "{cam}: error {e} vs σ {s}");
        }
        // Acceptance bars: 0.1 % on f, 0.5 px on the principal point.
        // Issue 3's acceptance bars; measured (issue 4's report, weighted joint fit): IR fx/fy
        // 0.0012/0.0019 %, colour 0.0017/0.0016 %, principal points 0.027 px and 0.038 px.
        assert!(efx < 1e-3 && efy < 1e-3, "{cam}");
        assert!(epp.norm() < 0.5, "{cam}");
        // No larger than OpenCV's joint stereoCalibrate on the same images: each focal length,
        // and the principal point as a point (its distance to the truth).
        eprintln!(
            "{cam}: |pp err| {:.4} px (OpenCV {:.4}); fx err {:.4} px = {:.2}σ",
            epp.norm(),
            cv_pp.norm(),
            k.fx - t.fx,
            (k.fx - t.fx) / std.fx
        );
        assert!(efx <= cv_fx, "{cam} fx: {efx} vs OpenCV {cv_fx}");
        assert!(efy <= cv_fy, "{cam} fy: {efy} vs OpenCV {cv_fy}");
        assert!(epp.norm() <= cv_pp.norm(), "{cam} principal point: {epp} vs OpenCV {cv_pp}");
    }
    // The joint fit's heteroscedastic weights: the views whose IR residuals show the
    // renderer's edge quantisation (boards within ~4° of the pixel axes) are down-weighted,
    // every used view has a weight in (0, 1], and at least one camera-average view keeps 1.
    for (i, &(wd, wc)) in r.view_weights.iter().enumerate() {
        for w in [wd, wc] {
            assert!(w > 0.0 && w <= 1.0, "view {i}: weight {w}");
        }
    }
    // 0.8: the down-weighted IR views sit far below it (issue 4's report shows `w 0.38` beside
    // such a view in the viewer); a fit that weights nothing has every w = 1.
    assert!(r.view_weights.iter().any(|w| w.0 == 1.0) && r.view_weights.iter().any(|w| w.0 < 0.8));
    // The joint residual rows reproduce the per-pair RMS (to rounding) and list every corner.
    for (i, ((d, c), (rd, rc))) in r.joint_residuals_px.iter().zip(&r.view_rms_px).enumerate() {
        for (rows, rms) in [(d, rd), (c, rc)] {
            assert_eq!(rows.len(), 35, "pair {i}");
            let got = (rows.iter().map(|e| e[3] * e[3] + e[4] * e[4]).sum::<f64>()
                / rows.len() as f64)
                .sqrt();
            assert!((got - rms).abs() < 1e-12, "pair {i}: {got} vs {rms}");
        }
    }
    let st = r.translation_std_m * 1000.0;
    let et = (r.color_from_depth.translation - truth_cfd.translation) * 1000.0;
    for j in 0..3 {
        assert!(et[j].abs() < 3.0 * st[j], "T[{j}] error {} mm vs σ {} mm", et[j], st[j]);
    }
    // Acceptance bars: 0.5 mm and 0.05°, and no worse than OpenCV's joint stereoCalibrate.
    // Measured |ΔT| 0.0072 mm, rotation 0.0034° (issue 4's report); OpenCV 0.0465 mm, 0.0333°.
    assert!(dt < 0.5 && dr < 0.05);
    assert!(dt <= cv_dt && dr <= cv_dr, "OpenCV: {cv_dt} mm, {cv_dr}°");
    // synthetic-calib/README.md: 15 board poses, each seen by both cameras.
    assert_eq!(r.pairs_used.len(), 15);
}

/// The report's per-image fields for the viewer: the residual vectors reproduce each image's
/// RMS, every detected corner is listed, and the joint fit's board poses match the truth.
#[test]
fn report_holds_residuals_detections_and_board_poses() {
    let Some(data) = shared_data("report_holds_residuals_detections_and_board_poses") else {
        return;
    };
    let gt = json(data.join("synthetic-calib/ground_truth.json"));
    let (ir, color) = views(&data);
    let r = calibrate_stereo(&board(), ir, color, &StereoOptions::default(), None, None).unwrap();
    let mut rig = calib::files::stereo_rig(&r, &board());
    let files: Vec<std::path::PathBuf> =
        (1..=15).map(|i| data.join(format!("synthetic-calib/ir/ir_{i:02}.png"))).collect();
    let report = rig.calibration.as_mut().unwrap();
    for pair in report["per_pair_joint_residuals_px"].as_array().unwrap() {
        for rows in [&pair["depth"], &pair["color"]] {
            assert!(rows.as_array().unwrap().iter().all(|e| e[0].is_u64()), "{rows}");
        }
    }
    calib::files::add_detections(&mut report["depth_single_camera"], ir, &files);
    for (key, views) in [("depth_single_camera", ir), ("color_single_camera", color)] {
        let images = report[key]["images"].as_array().unwrap();
        assert_eq!(images.len(), 15);
        for (im, v) in images.iter().zip(views.iter()) {
            let res = im["residuals_px"].as_array().unwrap();
            assert_eq!(res.len() as u64, im["corners"].as_u64().unwrap());
            assert!(res.iter().all(|e| e[0].is_u64()), "{key} {}: ids are integers", v.name);
            // RMS from the listed error vectors: the same sums in another order, 1e-12 px.
            let rms = (res.iter().map(|e| f(&e[3]).powi(2) + f(&e[4]).powi(2)).sum::<f64>()
                / res.len() as f64)
                .sqrt();
            assert!(
                (rms - f(&im["rms_px"])).abs() < 1e-12,
                "{key} {}: {rms} vs {}",
                v.name,
                im["rms_px"]
            );
            if key == "depth_single_camera" {
                let detected = im["detected_corners"].as_array().unwrap();
                assert_eq!(detected.len(), v.corners.len());
                // Corner indices are JSON integers (`12`, not `12.0`), equal to the detector's.
                for (row, c) in detected.iter().zip(&v.corners) {
                    assert_eq!(row[0].as_u64(), Some(c.id as u64), "{}: {row}", v.name);
                }
                assert!(std::path::Path::new(im["image"].as_str().unwrap()).is_file());
            }
            assert!(im["camera_from_board"].is_object());
        }
    }
    let poses = report["depth_from_board"].as_array().unwrap();
    assert_eq!(poses.len(), 15);
    for (i, p) in poses.iter().enumerate() {
        let p: geometry::RigidTransform = serde_json::from_value(p.clone()).unwrap();
        // The board's first inner corner where the truth puts it, allowing the board's 180°
        // symmetry (the detector may label from the opposite corner): within 2 mm at 0.45–0.9 m.
        let truth = gt_pose(&gt, i, "ir");
        let far = board().object_point(board().len() - 1);
        let d = (p.translation - truth.translation)
            .norm()
            .min((p.translation - truth.apply(&far)).norm());
        // No recorded measurement: 2 mm is ~0.2–0.4 % of the 0.45–0.9 m board distance, a margin
        // over the calibration's 0.1 % focal bar (which scales distance); a mislabelled or flipped
        // board is off by ≥ 40 mm (one square).
        assert!(d < 2e-3, "pair {i}: board origin {d} m from the truth");
    }
}

/// The held-out check on the rendered set: calibrated on the 1st, 3rd, … pairs (8), the other 7
/// predicted. Each camera's held-out median is within 2× its in-sample RMS (for Gaussian
/// corner noise the median distance is 0.83× the RMS; a pose fitted to the view's own corners
/// takes a little off, a model that only fits its own views adds), and the colour corners
/// predicted from the IR pose through the rig within 5× the colour RMS (the IR pose's own
/// error, from corners 3× coarser, is carried into the colour image). A rig whose T is 1 mm
/// off (the predictions of a broken rig) gives a median at least 5× the true rig's.
#[test]
fn the_held_out_check_predicts_the_rendered_views_and_catches_a_broken_rig() {
    let Some(data) = shared_data("the_held_out_check_predicts_the_rendered_views") else {
        return;
    };
    let gt = json(data.join("synthetic-calib/ground_truth.json"));
    let (ir, color) = views(&data);
    let h =
        calib::holdout::held_out_stereo(&board(), ir, color, &StereoOptions::default()).unwrap();
    let names = |range: std::iter::StepBy<std::ops::RangeInclusive<usize>>| -> Vec<String> {
        range.map(|i| format!("ir/ir_{i:02}.png")).collect()
    };
    assert_eq!(h.train, names((1..=15).step_by(2)));
    assert_eq!(h.held_out, names((2..=14).step_by(2)));
    for e in &h.errors {
        eprintln!(
            "held out {}: median {:.4} px, 95 % {:.4} px over {} corners (in-sample RMS {:.4} px)",
            e.what, e.median_px, e.p95_px, e.corners, e.in_sample_rms_px
        );
        assert_eq!(e.corners, 7 * 35, "{}", e.what);
        let factor = if e.what.contains("rig") { 5.0 } else { 2.0 };
        assert!(e.median_px <= factor * e.in_sample_rms_px, "{e:?}");
        assert!(e.p95_px >= e.median_px);
    }
    // The broken variant: the true rig (from the ground truth) and one with T 1 mm off, both
    // predicting the held-out colour corners from the IR corners.
    let held: Vec<usize> = (1..15).step_by(2).collect();
    let pick = |v: &[calib::ViewCorners]| held.iter().map(|&i| v[i].clone()).collect::<Vec<_>>();
    let (hd, hc) = (pick(ir), pick(color));
    let (ird, colour) = (gt_camera(&gt, "ir"), gt_camera(&gt, "color"));
    let cfd = gt_color_from_depth(&gt);
    let mut broken = cfd;
    broken.translation.x += 0.001;
    let predict = |rig: &geometry::RigidTransform| {
        let e =
            calib::holdout::predict_through_rig(&board(), &ird, &colour, rig, &hd, &hc).unwrap();
        calib::holdout::median_p95(&e).0
    };
    let (good, bad) = (predict(&cfd), predict(&broken));
    eprintln!("through the true rig: median {good:.4} px; with T 1 mm off: {bad:.4} px");
    let fitted = h.errors.iter().find(|e| e.what.contains("rig")).unwrap().median_px;
    assert!(bad >= 5.0 * good && bad >= 5.0 * fitted, "{good} {bad} {fitted}");
}
