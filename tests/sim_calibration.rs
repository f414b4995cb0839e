//! The simulated sensor for labs L1–L2, end to end through the binary: `kfuse capture calib
//! --backend sim` (the checkerboard scene) → `kfuse calibrate --ir … --color …` → the rig
//! must be the sensor's own factory parameters (`kinect_params.json`), each within
//! max(3σ reported by calibrate, a stated floor).

mod common;

use common::{kfuse, scratch};
use kinect_usb::params::{ColorParams, DepthParams};
use kinect_usb::registration::Registration;
use serde_json::Value;

/// Shots: one per pose of the scene (`kinect_usb::sim::calib_scene::BOARD_POSES`).
const SHOTS: usize = 12;
/// Floors of the comparison where calibrate's σ is tiny (noise-free corners): intrinsics
/// 0.5 px (the renders' anti-aliasing, 3×3 / 2×2 samples per pixel, and JPEG bias corner
/// positions by up to ~0.05 px, which over 12 views moves focal lengths and principal points
/// by a few tenths), rotation 0.05°, translation 0.2 mm.
const FLOOR_PX: f64 = 0.5;
const FLOOR_ROT_DEG: f64 = 0.05;
const FLOOR_T_MM: f64 = 0.2;

/// The pinhole colour camera and translation the factory registration describes, measured
/// from kinect-usb's `Registration::map_point` (the libfreenect2-exact reference, not the
/// simulator's own derivation): `[fx, fy, cx, cy]` of the colour camera and `T.x` (m).
fn factory_truth(d: &DepthParams, c: &ColorParams) -> ([f64; 4], f64) {
    let reg = Registration::new(d, c);
    const FAR_MM: f32 = 1e9;
    let (x0, y0, dx) = (256usize, 212usize, 150usize);
    let at = |x: usize, y: usize, z: f32| {
        let (u, v) = reg.map_point(x, y, z);
        (u as f64, v as f64)
    };
    let (fxd, fyd, cxd, cyd) = (d.fx as f64, d.fy as f64, d.cx as f64, d.cy as f64);
    let fx = (at(x0 + dx, y0, FAR_MM).0 - at(x0 - dx, y0, FAR_MM).0) / (2.0 * dx as f64 / fxd);
    let fy = (at(x0, y0 + dx, FAR_MM).1 - at(x0, y0 - dx, FAR_MM).1) / (2.0 * dx as f64 / fyd);
    let (u0, v0) = at(x0, y0, FAR_MM);
    let cx = u0 - fx * (x0 as f64 - cxd) / fxd;
    let cy = v0 - fy * (y0 as f64 - cyd) / fyd;
    let z = 1000.0f32;
    let tx = (at(x0, y0, z).0 - u0) * (z as f64 * 1e-3) / fx;
    ([fx, fy, cx, cy], tx)
}

#[test]
fn calibrating_the_simulated_sensor_recovers_its_factory_parameters() {
    let dir = scratch("sim-calibration");
    let caps = dir.join("caps");
    let n = SHOTS.to_string();
    let o = kfuse(&[
        "capture",
        "calib",
        "--backend",
        "sim",
        "--count",
        &n,
        "--interval",
        "0",
        "--out",
        caps.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let params: Value =
        serde_json::from_slice(&std::fs::read(caps.join("kinect_params.json")).unwrap()).unwrap();
    let (d, c) = common::kinect_params_of(&params);
    // Every shot shows a different pose (the scene is not one frame repeated).
    let first = std::fs::read(caps.join("ir_0001.png")).unwrap();
    assert!(
        (2..=SHOTS).all(|k| std::fs::read(caps.join(format!("ir_{k:04}.png"))).unwrap() != first)
    );

    let rig_path = dir.join("rig.json");
    let ir = format!("{}/ir_*.png", caps.display());
    let color = format!("{}/color_*.jpg", caps.display());
    let o =
        kfuse(&["calibrate", "--ir", &ir, "--color", &color, "--out", rig_path.to_str().unwrap()]);
    let text =
        format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "{text}");
    let rig =
        geometry::Rig::from_json(&std::fs::read_to_string(&rig_path).unwrap(), &rig_path).unwrap();
    let cal = rig.calibration.clone().unwrap();
    let pairs = cal["pairs_used"].as_array().map_or(0, Vec::len);
    assert!(pairs >= SHOTS - 1, "only {pairs} of {SHOTS} pairs used\n{text}");

    let (color_truth, tx_truth) = factory_truth(&d, &c);
    let depth_truth = [d.fx as f64, d.fy as f64, d.cx as f64, d.cy as f64];
    let mut report = String::new();
    let mut failures = Vec::new();
    let mut check = |what: &str, got: f64, truth: f64, sigma: f64, floor: f64| {
        let tol = (3.0 * sigma).max(floor);
        report += &format!(
            "{what:>10}: recovered {got:10.4}  factory {truth:10.4}  diff {:+.4}  σ {sigma:.4}  tol {tol:.4}\n",
            got - truth
        );
        if !((got - truth).abs() <= tol) {
            failures.push(what.to_string());
        }
    };
    for (cam, k, truth, std) in [
        ("depth", rig.depth.intrinsics, depth_truth, &cal["depth_std_1sigma"]),
        ("colour", rig.color.intrinsics, color_truth, &cal["color_std_1sigma"]),
    ] {
        for (i, (name, got)) in
            [("fx", k.fx), ("fy", k.fy), ("cx", k.cx), ("cy", k.cy)].into_iter().enumerate()
        {
            let s = std[name].as_f64().unwrap_or(f64::INFINITY);
            check(&format!("{cam} {name}"), got, truth[i], s, FLOOR_PX);
        }
    }
    // The factory rig has no rotation (its polynomial is affine and diagonal).
    let rstd: Vec<f64> = cal["color_from_depth_rotation_std_rad"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap().to_degrees())
        .collect();
    let rsig = rstd.iter().map(|s| s * s).sum::<f64>().sqrt();
    check("R angle°", rig.color_from_depth.angle_deg(), 0.0, rsig, FLOOR_ROT_DEG);
    let tstd: Vec<f64> = cal["color_from_depth_translation_std_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let t = rig.color_from_depth.translation;
    check("T.x mm", t.x * 1e3, tx_truth * 1e3, tstd[0] * 1e3, FLOOR_T_MM);
    check("T.y mm", t.y * 1e3, 0.0, tstd[1] * 1e3, FLOOR_T_MM);
    check("T.z mm", t.z * 1e3, 0.0, tstd[2] * 1e3, FLOOR_T_MM);
    eprintln!("sim calibration ({pairs} pairs):\n{report}");
    assert!(failures.is_empty(), "outside tolerance: {failures:?}\n{report}\n{text}");

    // Issue 13 item 6 / the sign of T: every board corner the IR image shows, at the depth
    // the depth image gives there, is mapped by the reported factory parameters to where the
    // colour image shows a corner.
    let (rms, max, n) = factory_mapping_error(&cal, &params, &caps);
    eprintln!(
        "IR corner + depth → factory mapping vs colour corner: RMS {rms:.3} px, max {max:.3} px, {n} corners"
    );
    assert!(n >= 20 * SHOTS, "{n} corners");
    assert!(rms <= MAPPING_RMS_PX && max <= MAPPING_MAX_PX, "RMS {rms} px, max {max} px");
}

/// Bounds of the factory mapping check: colour corners are located to ~0.1 px, IR corners to
/// ~0.1 px (×2.9, the colour/IR scale), the depth plane fit to ~2 mm (0.1 px of parallax at
/// 1 m); a wrong-signed baseline is off by 2·f·T/z ≈ 110 px at 1 m.
const MAPPING_RMS_PX: f64 = 0.6;
const MAPPING_MAX_PX: f64 = 1.5;
/// Half-size of the depth window a plane is fitted to around an IR corner, pixels.
const PLANE_HALF: i64 = 3;

fn corners_of(images: &Value) -> Vec<(String, Vec<[f64; 2]>)> {
    images
        .as_array()
        .unwrap()
        .iter()
        .map(|im| {
            let name = std::path::Path::new(im["image"].as_str().unwrap())
                .file_name()
                .unwrap()
                .to_string_lossy()
                .into_owned();
            let c = im["detected_corners"]
                .as_array()
                .unwrap()
                .iter()
                .map(|c| [c[1].as_f64().unwrap(), c[2].as_f64().unwrap()])
                .collect();
            (name, c)
        })
        .collect()
}

/// The colour pixel of undistorted depth pixel `(x, y)` at `z_mm` by protocol §11.1–11.2 in
/// f64 (written from the document, not from the simulator's code).
fn factory_map(p: &Value, x: f64, y: f64, z_mm: f64) -> [f64; 2] {
    let g = |o: &str, k: &str| p[o][k].as_f64().unwrap();
    let poly = |k: &str, mx: f64, my: f64| {
        let c: Vec<f64> =
            p["color"][k].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let m = [
            mx * mx * mx,
            my * my * my,
            mx * mx * my,
            my * my * mx,
            mx * mx,
            my * my,
            mx * my,
            mx,
            my,
            1.0,
        ];
        c.iter().zip(m).map(|(c, m)| c * m).sum::<f64>()
    };
    let (qd, qc) = (0.01, 0.002199);
    let (mx, my) = ((x - g("depth", "cx")) * qd, (y - g("depth", "cy")) * qd);
    let (f, sm, sd) = (g("color", "fx"), g("color", "shift_m"), g("color", "shift_d"));
    let rx = poly("mx", mx, my) / (f * qc) - sm / sd;
    let ry = poly("my", mx, my) / qc + g("color", "cy");
    [(rx + sm / z_mm) * f + g("color", "cx"), ry]
}

/// Undistorted pixel of distorted depth pixel `(u, v)` (Brown–Conrady inverted by fixed-point
/// iteration, 30 steps: the Kinect lens converges to < 1e-9 px).
fn undistort(p: &Value, u: f64, v: f64) -> [f64; 2] {
    let g = |k: &str| p["depth"][k].as_f64().unwrap();
    let (fx, fy, cx, cy) = (g("fx"), g("fy"), g("cx"), g("cy"));
    let (xd, yd) = ((u - cx) / fx, (v - cy) / fy);
    let (mut x, mut y) = (xd, yd);
    for _ in 0..30 {
        let r2 = x * x + y * y;
        let k = 1.0 + ((g("k3") * r2 + g("k2")) * r2 + g("k1")) * r2;
        let tx = g("p2") * (r2 + 2.0 * x * x) + g("p1") * 2.0 * x * y;
        let ty = g("p1") * (r2 + 2.0 * y * y) + g("p2") * 2.0 * x * y;
        x = (xd - tx) / k;
        y = (yd - ty) / k;
    }
    [fx * x + cx, fy * y + cy]
}

/// Depth (mm) at sub-pixel `(u, v)` of a 512-wide depth image: a least-squares plane through
/// the valid pixels of the surrounding window.
fn depth_at(depth: &[u16], u: f64, v: f64) -> Option<f64> {
    let (cu, cv) = (u.round() as i64, v.round() as i64);
    let mut a = nalgebra::Matrix3::<f64>::zeros();
    let mut b = nalgebra::Vector3::<f64>::zeros();
    for dv in -PLANE_HALF..=PLANE_HALF {
        for du in -PLANE_HALF..=PLANE_HALF {
            let (x, y) = (cu + du, cv + dv);
            if !(0..512).contains(&x) || !(0..424).contains(&y) {
                continue;
            }
            let z = depth[(y * 512 + x) as usize];
            if z == 0 {
                continue;
            }
            let r = nalgebra::Vector3::new(1.0, x as f64 - u, y as f64 - v);
            a += r * r.transpose();
            b += r * z as f64;
        }
    }
    a.cholesky().map(|c| c.solve(&b)[0])
}

fn factory_mapping_error(cal: &Value, params: &Value, caps: &std::path::Path) -> (f64, f64, usize) {
    let ir = corners_of(&cal["depth_single_camera"]["images"]);
    let color = corners_of(&cal["color_single_camera"]["images"]);
    let (mut sum, mut max, mut n) = (0.0, 0.0f64, 0usize);
    for (name, corners) in &ir {
        let shot = name.trim_start_matches("ir_").trim_end_matches(".png");
        let Some((_, cc)) = color.iter().find(|(c, _)| c == &format!("color_{shot}.jpg")) else {
            continue;
        };
        let depth =
            image::open(caps.join(format!("depth_{shot}.png"))).unwrap().into_luma16().into_raw();
        for &[u, v] in corners {
            let Some(z) = depth_at(&depth, u, v) else { continue };
            let [x, y] = undistort(params, u, v);
            let [pu, pv] = factory_map(params, x, y, z);
            let e = cc
                .iter()
                .map(|c| ((c[0] - pu).powi(2) + (c[1] - pv).powi(2)).sqrt())
                .fold(f64::INFINITY, f64::min);
            sum += e * e;
            max = max.max(e);
            n += 1;
        }
    }
    ((sum / n.max(1) as f64).sqrt(), max, n)
}
