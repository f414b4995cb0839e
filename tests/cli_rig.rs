//! End-to-end tests of `kfuse rig import|export|show` (and `undistort` with a single-camera
//! file), through the binary, against independent references: the Bouguet library import,
//! the MATLAB files' own numbers, kinect-usb's registration (the f32 reference that
//! reproduces libfreenect2's vectors) and the simulated sensor's known parameters.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{cam_values, rig_diff};
use geometry::Rig;
use geometry::testdata::shared_data_or_skip as shared;
use kinect_usb::params::{ColorParams, DepthParams};
use kinect_usb::registration::Registration;

fn kfuse(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_kfuse")).args(args).output().expect("kfuse runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn ok(args: &[&str]) -> String {
    let (ok, out, err) = kfuse(args);
    assert!(ok, "kfuse {args:?} failed:\n{out}\n{err}");
    out
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn read_rig(p: &Path) -> Rig {
    kfuse_io::rig::read_pair(p).unwrap()
}

fn lab(data: &Path, f: &str) -> PathBuf {
    data.join("kinect-lab").join(f)
}

/// Bouguet → rig equals `calib::bouguet::import_stereo`: intrinsics and T exactly (JSON keeps
/// f64 exactly), the rotation to 1e-15 (reading a rig file re-orthonormalises R; measured
/// 1.3e-16). Its numbers are the file's own (`KK_left`, `T` in mm).
#[test]
fn bouguet_stereo_import_equals_the_library_import() {
    let Some(data) = shared("bouguet_stereo_import_equals_the_library_import") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("rig.json");
    let stereo = lab(&data, "Calib_Results_stereo.mat");
    let text = ok(&["rig", "import", s(&stereo), "--out", s(&out)]);
    assert!(text.contains("Bouguet stereo"), "{text}");
    let got = read_rig(&out);
    let lib = calib::bouguet::import_stereo(
        &stereo,
        &lab(&data, "Calib_Results_left.mat"),
        &lab(&data, "Calib_Results_right.mat"),
    )
    .unwrap();
    assert!(rig_diff(&got, &lib) < 1e-15, "{}", rig_diff(&got, &lib));
    assert_eq!(got.depth, lib.depth);
    assert_eq!(got.color, lib.color);
    assert_eq!(got.color_from_depth.translation, lib.color_from_depth.translation);
    // Independent: the stereo file's matrices, read with the MATLAB reader.
    let m = kfuse_io::mat::MatFile::read(&stereo).unwrap();
    let kk = m.matrix("KK_left").unwrap();
    assert_eq!(got.depth.intrinsics.fx, kk.at(0, 0));
    assert_eq!(got.depth.intrinsics.cx, kk.at(0, 2));
    let t = m.matrix("T").unwrap().data;
    for (got_t, file_t) in got.color_from_depth.translation.iter().zip(&t) {
        // mm → m of values below 0.06 m: one f64 rounding (ulp ≈ 7e-18), 1e-15 with margin.
        assert!((got_t - file_t * 1e-3).abs() < 1e-15);
    }
    // The Kinect v2 depth image (DESIGN.md), the toolbox's nx, ny in Calib_Results_left.mat.
    assert_eq!((got.depth.width, got.depth.height), (512, 424));
    // Explicit mono files give the same rig.
    let out2 = tmp.path().join("rig2.json");
    ok(&[
        "rig",
        "import",
        s(&stereo),
        s(&lab(&data, "Calib_Results_left.mat")),
        s(&lab(&data, "Calib_Results_right.mat")),
        "--out",
        s(&out2),
    ]);
    assert!(rig_diff(&read_rig(&out2), &lib) < 1e-15);
}

/// rig → OpenCV YAML → rig and rig → ROS camera_info pair → rig keep every parameter
/// within 1e-9 (pixels, metres, rotation entries).
/// Mistakes from a user's trial, each refused with one line before anything is written: a
/// Bouguet stereo file's mono results in the wrong order or repeated (the rig's two image
/// sizes were exchanged, exit 0), a ROS pair in the wrong order (the cameras exchanged), and
/// an existing file as `--out` of import or export (replaced without a word); `--overwrite`
/// replaces it.
#[test]
fn swapped_inputs_and_existing_outputs_are_refused() {
    let Some(data) = shared("swapped_inputs_and_existing_outputs_are_refused") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let p = |f: &str| tmp.path().join(f);
    let (stereo, left, right) = (
        lab(&data, "Calib_Results_stereo.mat"),
        lab(&data, "Calib_Results_left.mat"),
        lab(&data, "Calib_Results_right.mat"),
    );
    for (l, r, says) in [
        (&right, &left, "the other camera's result"),
        (&right, &right, "the other camera's result"),
        (&left, &left, "the other camera's result"),
    ] {
        let (good, _, err) =
            kfuse(&["rig", "import", s(&stereo), s(l), s(r), "--out", s(&p("r.json"))]);
        assert!(
            !good && err.contains(says) && err.contains("stereo.mat left.mat right.mat"),
            "{err}"
        );
        assert!(!p("r.json").exists());
    }
    ok(&["rig", "import", s(&stereo), s(&left), s(&right), "--out", s(&p("rig.json"))]);
    ok(&["rig", "export", s(&p("rig.json")), "--format", "ros", "--out", s(&p("ros"))]);
    let (good, _, err) = kfuse(&[
        "rig",
        "import",
        s(&p("ros/color.yaml")),
        s(&p("ros/depth.yaml")),
        "--out",
        s(&p("back.json")),
    ]);
    assert!(
        !good && err.contains("names the color camera") && err.contains("depth camera's"),
        "{err}"
    );
    assert!(!p("back.json").exists());
    // Existing outputs: kept unless --overwrite.
    std::fs::write(p("notes.yml"), "mine").unwrap();
    // `rig export rig.json --format opencv --out OUT [EXTRA…]`.
    let rig_json = p("rig.json");
    let export_opencv = |out: &Path, extra: &[&str]| {
        let args = ["rig", "export", s(&rig_json), "--format", "opencv", "--out", s(out)];
        kfuse(&[&args[..], extra].concat())
    };
    let (good, _, err) = export_opencv(&p("notes.yml"), &[]);
    assert!(!good && err.contains("notes.yml") && err.contains("--overwrite"), "{err}");
    assert_eq!(std::fs::read_to_string(p("notes.yml")).unwrap(), "mine");
    let (good, _, err) = kfuse(&["rig", "import", s(&stereo), "--out", s(&p("notes.yml"))]);
    assert!(!good && err.contains("--overwrite"), "{err}");
    let (good, _, err) =
        kfuse(&["rig", "export", s(&p("rig.json")), "--format", "ros", "--out", s(&p("ros"))]);
    assert!(!good && err.contains("depth.yaml") && err.contains("--overwrite"), "{err}");
    ok(&["rig", "import", s(&stereo), "--out", s(&p("notes.yml")), "--overwrite"]);
    assert!(read_rig(&p("notes.yml")).depth.width == 512);
    // An input as --out, even with --overwrite: refused, the input kept (the toolbox's
    // files were replaced by JSON of their name, and every later import failed). The left
    // result beside a copied stereo file is read implicitly; it is a MATLAB file.
    let bq = p("bq");
    std::fs::create_dir_all(&bq).unwrap();
    for f in [&stereo, &left, &right] {
        std::fs::copy(f, bq.join(f.file_name().unwrap())).unwrap();
    }
    let (bq_stereo, bq_left) =
        (bq.join("Calib_Results_stereo.mat"), bq.join("Calib_Results_left.mat"));
    let before = std::fs::read(&bq_left).unwrap();
    for (out, says) in [(&bq_stereo, "is one of the input files"), (&bq_left, "is a MATLAB file")] {
        let (good, _, err) =
            kfuse(&["rig", "import", s(&bq_stereo), "--out", s(out), "--overwrite"]);
        assert!(!good && err.contains(says), "{err}");
    }
    assert_eq!(std::fs::read(&bq_left).unwrap(), before);
    ok(&["rig", "import", s(&bq_stereo), "--out", s(&p("again.json"))]);
    let (good, _, err) = export_opencv(&p("rig.json"), &["--overwrite"]);
    assert!(!good && err.contains("is one of the input files"), "{err}");
    assert!(read_rig(&p("rig.json")).depth.width == 512);
}

#[test]
fn opencv_and_ros_exports_import_back() {
    let Some(data) = shared("opencv_and_ros_exports_import_back") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let p = |f: &str| tmp.path().join(f);
    ok(&["rig", "import", s(&lab(&data, "Calib_Results_stereo.mat")), "--out", s(&p("rig.json"))]);
    let rig = read_rig(&p("rig.json"));
    ok(&["rig", "export", s(&p("rig.json")), "--format", "opencv", "--out", s(&p("rig.yml"))]);
    let yml = std::fs::read_to_string(p("rig.yml")).unwrap();
    assert!(yml.starts_with("%YAML:1.0") && yml.contains("!!opencv-matrix"), "{yml}");
    ok(&["rig", "import", s(&p("rig.yml")), "--out", s(&p("back_cv.json"))]);
    let d = rig_diff(&rig, &read_rig(&p("back_cv.json")));
    eprintln!("OpenCV round trip: max parameter difference {d:.2e}");
    // Loose, not measured: both exporters print f64 in full (files.rs `{:.17e}`, ros.rs `{:?}`),
    // so only the re-orthonormalisation of R and the T/P algebra (f64, ~1e-15) differ; 1e-9 is
    // far above that and far below any unit or transposition mistake (≥ 1e-3).
    assert!(d < 1e-9, "{d}");

    ok(&["rig", "export", s(&p("rig.json")), "--format", "ros", "--out", s(&p("ros"))]);
    let color_info = std::fs::read_to_string(p("ros/color.yaml")).unwrap();
    assert!(color_info.contains("distortion_model: plumb_bob"), "{color_info}");
    ok(&[
        "rig",
        "import",
        s(&p("ros/depth.yaml")),
        s(&p("ros/color.yaml")),
        "--out",
        s(&p("back_ros.json")),
    ]);
    let d = rig_diff(&rig, &read_rig(&p("back_ros.json")));
    eprintln!("ROS round trip: max parameter difference {d:.2e}");
    // As above (ROS camera_info pair).
    assert!(d < 1e-9, "{d}");
    // The colour camera's ROS projection matrix carries Tx = −fx'·B with B the baseline.
    let doc: serde_yaml_ng::Value = serde_yaml_ng::from_str(&color_info).unwrap();
    let pm = doc["projection_matrix"]["data"].as_sequence().unwrap();
    let (fx, tx) = (pm[0].as_f64().unwrap(), pm[3].as_f64().unwrap());
    let baseline = rig.color_from_depth.translation.norm();
    // f64 round-off of Tx / fx (~1e-16 relative on a 0.05 m baseline), with margin.
    assert!((tx.abs() / fx - baseline).abs() < 1e-12, "Tx {tx}, fx {fx}, B {baseline}");
}

/// An OpenCV `stereo_calib` style pair of files (intrinsics.yml + extrinsics.yml, T in
/// millimetres, no image sizes) with OpenCV's `%YAML:1.0` header and `!!opencv-matrix` tags.
#[test]
fn opencv_stereo_calibrate_files_are_read_with_their_units() {
    let tmp = tempfile::tempdir().unwrap();
    let p = |f: &str| tmp.path().join(f);
    let m = |name: &str, r: usize, c: usize, d: &str| {
        format!("{name}: !!opencv-matrix\n   rows: {r}\n   cols: {c}\n   dt: d\n   data: [ {d} ]\n")
    };
    let intr = format!(
        "%YAML:1.0\n---\n{}{}{}{}",
        m("M1", 3, 3, "3.6409e+02, 0., 2.5550e+02, 0., 3.6463e+02,\n       2.1150e+02, 0., 0., 1."),
        m("D1", 1, 5, "9.05e-02, -2.69e-01, 0., 0., 0."),
        m("M2", 3, 3, "1.0617e+03, 0., 9.595e+02, 0., 1.0633e+03, 5.395e+02, 0., 0., 1."),
        m("D2", 1, 8, "2.1e-02, -3.4e-02, 6.e-04, -4.e-04, 0., 0., 0., 0."),
    );
    // R: 1° about y, written to 17 digits as OpenCV does.
    let a = 1f64.to_radians();
    let (c, sn) = (a.cos(), a.sin());
    let extr = format!(
        "%YAML:1.0\n---\n{}{}",
        m("R", 3, 3, &format!("{c:.17e}, 0., {sn:.17e}, 0., 1., 0., {:.17e}, 0., {c:.17e}", -sn)),
        m("T", 3, 1, "-5.2195e+01, -2.62e-01, 6.25e-01"),
    );
    std::fs::write(p("intrinsics.yml"), intr).unwrap();
    std::fs::write(p("extrinsics.yml"), extr).unwrap();
    let out = p("rig.json");
    // Without image sizes, then without a unit, the import stops, names the file and says
    // what to pass.
    let (intr_path, extr_path) = (p("intrinsics.yml"), p("extrinsics.yml"));
    let two = [s(&intr_path), s(&extr_path)];
    let (good, _, err) = kfuse(&["rig", "import", two[0], two[1], "--out", s(&out)]);
    assert!(!good && err.contains("intrinsics.yml") && err.contains("--depth-size"), "{err}");
    let sizes = ["--depth-size", "512x424", "--color-size", "1920x1080"];
    let (good, _, err) =
        kfuse(&[&["rig", "import", two[0], two[1], "--out", s(&out)][..], &sizes[..]].concat());
    assert!(!good && err.contains("has no unit") && err.contains("--t-units mm"), "{err}");
    assert!(!out.exists());
    let text = ok(&[
        "rig",
        "import",
        s(&p("intrinsics.yml")),
        s(&p("extrinsics.yml")),
        "--t-units",
        "mm",
        "--depth-size",
        "512x424",
        "--color-size",
        "1920x1080",
        "--out",
        s(&out),
    ]);
    assert!(text.contains("OpenCV"), "{text}");
    let rig = read_rig(&out);
    // The numbers written into intrinsics.yml / extrinsics.yml above: M1 fx 3.6409e+02, D2 p1
    // 6.e-04, T.x −52.195 mm → −0.052195 m (f64 rounding 1e-15), R = 1° about y (printed to 17
    // digits, so the angle survives to f64 round-off of acos, 1e-12 deg).
    assert_eq!(rig.depth.intrinsics.fx, 364.09);
    assert_eq!(rig.color.distortion.p1, 6e-4);
    assert_eq!((rig.color.width, rig.color.height), (1920, 1080));
    assert!((rig.color_from_depth.translation.x + 0.052195).abs() < 1e-15);
    assert!((rig.color_from_depth.angle_deg() - 1.0).abs() < 1e-12);
    // A rational-model coefficient is refused by name.
    let bad = std::fs::read_to_string(p("intrinsics.yml"))
        .unwrap()
        .replace("0., 0., 0., 0. ]", "0., 0.3, 0., 0. ]");
    std::fs::write(p("rational.yml"), bad).unwrap();
    let (good, _, err) = kfuse(&[
        "rig",
        "import",
        s(&p("rational.yml")),
        s(&p("extrinsics.yml")),
        "--t-units",
        "mm",
        "--depth-size",
        "512x424",
        "--color-size",
        "1920x1080",
        "--out",
        s(&p("rational.json")),
    ]);
    assert!(!good && err.contains("rational.yml") && err.contains("beyond k3"), "{err}");
}

/// The lab's KinectData.mat → rig with the stereo file's numbers (the same calibration).
#[test]
fn kinect_data_mat_import() {
    let Some(data) = shared("kinect_data_mat_import") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("rig.json");
    ok(&["rig", "import", s(&lab(&data, "KinectData.mat")), "--out", s(&out)]);
    let rig = read_rig(&out);
    let st = kfuse_io::mat::MatFile::read(&lab(&data, "Calib_Results_stereo.mat")).unwrap();
    let kl = st.matrix("KK_left").unwrap();
    let kr = st.matrix("KK_right").unwrap();
    assert_eq!(rig.depth.intrinsics.fx, kl.at(0, 0));
    assert_eq!(rig.depth.intrinsics.cy, kl.at(1, 2));
    assert_eq!(rig.color.intrinsics.fy, kr.at(1, 1));
    assert_eq!((rig.color.width, rig.color.height), (1920, 1080));
    // The lab README: T = (-52.195, -0.262, 0.625) mm.
    let t = rig.color_from_depth.translation * 1e3;
    assert!(
        // The README states T to 3 decimals in mm.
        (t.x + 52.195).abs() < 1e-3 && (t.y + 0.262).abs() < 1e-3 && (t.z - 0.625).abs() < 1e-3,
        "{t}"
    );
}

/// Colour-pixel error of a rig against kinect-usb's registration (the f32 reference) on
/// every undistorted depth pixel whose sample exists, at the depths `zs` (mm): (RMS, max, n).
fn error_vs_registration(
    rig: &Rig,
    d: &DepthParams,
    c: &ColorParams,
    zs: &[f32],
) -> (f64, f64, usize) {
    let reg = Registration::new(d, c);
    let (mut sum, mut max, mut n) = (0f64, 0f64, 0usize);
    for y in 0..424 {
        for x in 0..512 {
            let k = rig.depth.intrinsics;
            let ray =
                nalgebra::Vector3::new((x as f64 - k.cx) / k.fx, (y as f64 - k.cy) / k.fy, 1.0);
            let Some(q) = rig.depth.project(&ray) else { continue };
            if !rig.depth.contains(q.x, q.y) {
                continue;
            }
            for &z in zs {
                let (u, v) = reg.map_point(x, y, z);
                if !rig.color.contains(u as f64, v as f64) {
                    continue;
                }
                let p = rig
                    .color
                    .project(&rig.color_from_depth.apply(&(ray * (z as f64 * 1e-3))))
                    .unwrap();
                let e = ((p.x - u as f64).powi(2) + (p.y - v as f64).powi(2)).sqrt();
                sum += e * e;
                max = max.max(e);
                n += 1;
            }
        }
    }
    ((sum / n as f64).sqrt(), max, n)
}

const DEPTHS_MM: [f32; 6] = [500.0, 800.0, 1200.0, 2000.0, 3000.0, 4500.0];

/// `kfuse capture scene --backend sim` → kinect_params.json → rig. The sim's colour
/// polynomial is affine (a pinhole colour camera), so the rig is exact: it reproduces
/// kinect-usb's registration to f32 rounding (< 0.01 px) and has the sim profile's numbers.
#[test]
fn kinect_params_of_the_simulated_sensor_become_an_exact_rig() {
    let tmp = tempfile::tempdir().unwrap();
    let cap = tmp.path().join("cap");
    ok(&["capture", "scene", "--backend", "sim", "--interval", "0", "--out", s(&cap)]);
    let params = cap.join("kinect_params.json");
    let out = tmp.path().join("rig.json");
    let text = ok(&["rig", "import", s(&params), "--out", s(&out)]);
    assert!(text.contains("RMS"), "{text}");
    let rig = read_rig(&out);
    let (d, c) = common::kinect_params_of(
        &serde_json::from_str(&std::fs::read_to_string(&params).unwrap()).unwrap(),
    );
    let (rms, max, n) = error_vs_registration(&rig, &d, &c, &DEPTHS_MM);
    eprintln!(
        "sim kinect_params → rig vs registration: RMS {rms:.2e} px, max {max:.2e} px, {n} samples"
    );
    // n: 512 × 424 pixels × 6 depths = 1 302 528 samples at most, those landing in the colour
    // image; 0.01 px: the sim's polynomial and parameters are f32 (relative 6e-8, ≈ 1e-4 px on
    // 1920 px), with margin.
    assert!(n > 500_000 && max < 0.01, "RMS {rms}, max {max}, n {n}");
    // Independent: the sim profile's construction (SimProfile::synthetic): depth = the
    // synthetic rig's depth camera in f32, colour f = its fx, principal point at the image
    // centre, parallax 52 mm along x, no rotation.
    let truth = geometry::synth::kinect_rig();
    assert_eq!(rig.depth.intrinsics.fx, truth.depth.intrinsics.fx as f32 as f64);
    assert_eq!(rig.depth.distortion.k3, truth.depth.distortion.k3 as f32 as f64);
    let f = truth.color.intrinsics.fx as f32 as f64;
    let k = rig.color.intrinsics;
    // Fitted from f32 polynomial coefficients: relative f32 rounding (6e-8 × 1060 ≈ 6e-5 px)
    // with margin; 959.5, 539.5: the 1920 × 1080 image centre of SimProfile::synthetic.
    assert!((k.fx - f).abs() < 1e-3 && (k.fy - f).abs() < 1e-3, "{k:?}");
    assert!((k.cx - 959.5).abs() < 1e-3 && (k.cy - 539.5).abs() < 1e-3, "{k:?}");
    assert!(rig.color.distortion.k1.abs() < 1e-6 && rig.color.distortion.k2.abs() < 1e-6);
    assert!(rig.color_from_depth.angle_deg() < 1e-4);
    let t = rig.color_from_depth.translation;
    // SimProfile::synthetic's 52 mm parallax (shift_m) of the sensor's mirrored stream, in
    // kinect_params.json's scene orientation: t = −52 mm, the colour camera's centre at +52 mm;
    // 1e-6 m: f32 rounding of shift_m/shift_d.
    assert!((t.x + 0.052).abs() < 1e-6 && t.y.abs() < 1e-6 && t.z.abs() < 1e-6, "{t}");
}

/// The factory parameters of the registration vectors: real depth intrinsics and a colour
/// polynomial with cubic terms. No pinhole rig reproduces a cubic exactly; the fitted rig's
/// error against kinect-usb's registration is measured and bounded.
#[test]
fn kinect_params_with_a_cubic_mapping_fit_within_the_stated_error() {
    let Some(data) = shared("kinect_params_with_a_cubic_mapping_fit_within_the_stated_error")
    else {
        return;
    };
    let inputs = data.join("kinect-v2-vectors/inputs");
    let d = DepthParams::from_response(
        &std::fs::read(inputs.join("depth_camera_params_response.bin")).unwrap(),
    )
    .unwrap();
    let c = ColorParams::from_response(
        &std::fs::read(inputs.join("rgb_camera_params_response.bin")).unwrap(),
    )
    .unwrap();
    assert!(c.mx[0] != 0.0, "the vectors' polynomial has cubic terms");
    // The layout `kfuse capture` writes (kfuse_capture::write_params_json).
    let v = serde_json::json!({
        "format": "kfuse-kinect-params", "version": 1, "serial": "vectors",
        "units": "pixels; shift_d and shift_m in millimetres",
        "depth": { "width": 512, "height": 424, "fx": d.fx, "fy": d.fy, "cx": d.cx, "cy": d.cy,
                   "k1": d.k1, "k2": d.k2, "k3": d.k3, "p1": d.p1, "p2": d.p2 },
        "color": { "width": 1920, "height": 1080, "fx": c.f, "fy": c.f, "cx": c.cx, "cy": c.cy,
                   "shift_d": c.shift_d, "shift_m": c.shift_m, "mx": c.mx, "my": c.my },
    });
    let tmp = tempfile::tempdir().unwrap();
    let params = tmp.path().join("kinect_params.json");
    std::fs::write(&params, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    let out = tmp.path().join("rig.json");
    let text = ok(&["rig", "import", s(&params), "--out", s(&out)]);
    let rig = read_rig(&out);
    for z in DEPTHS_MM {
        let (rms, max, _) = error_vs_registration(&rig, &d, &c, &[z]);
        eprintln!("  at {z} mm: RMS {rms:.3} px, max {max:.3} px");
    }
    let (rms, max, n) = error_vs_registration(&rig, &d, &c, &DEPTHS_MM);
    eprintln!(
        "vectors kinect_params → rig vs registration: RMS {rms:.4} px, max {max:.4} px, {n} samples\n{text}"
    );
    // Measured (every depth pixel, 6 depths): RMS 1.64 px, max 10.6 px in the colour image;
    // per depth RMS 2.9 px at 0.5 m, 0.8 px at 1.2 m, 1.5 px at 4.5 m. The error is the
    // models' disagreement, not the fit's: the factory applies its cubic (a radial
    // distortion about the depth ray) before the parallax shift, so its distortion centre
    // moves across the colour image with depth, while a rig's distortion is centred on a
    // fixed principal point. Bounds: the measured values + 20 % (measured in e5a3f99,
    // 2026-12-01).
    // At most 512 × 424 × 6 = 1 302 528 samples (those landing in the colour image).
    assert!(n > 500_000, "{n}");
    assert!(rms < 2.0 && max < 12.8, "RMS {rms}, max {max}");
    // The depth camera is taken exactly.
    assert_eq!(rig.depth.intrinsics.cx, d.cx as f64);
    assert_eq!(rig.depth.distortion.k2, d.k2 as f64);
}

/// `rig show` prints every quantity with its unit and the checks; single-camera files from
/// `kfuse calibrate --ir … --out ir.json` are accepted by show, export and undistort.
#[test]
fn show_prints_units_and_single_camera_files_are_accepted() {
    let Some(data) = shared("show_prints_units_and_single_camera_files_are_accepted") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let p = |f: &str| tmp.path().join(f);
    ok(&["rig", "import", s(&lab(&data, "Calib_Results_stereo.mat")), "--out", s(&p("rig.json"))]);
    let text = ok(&["rig", "show", s(&p("rig.json"))]);
    eprintln!("{text}");
    for needle in [
        "depth camera: 512 x 424 px",
        "colour camera: 1920 x 1080 px",
        "fx 364.",
        " px, fy ",
        "field of view",
        "° x ",
        "translation T    (-52.195, -0.262, 0.625) mm",
        "baseline         52.200 mm",
        "rotation ",
        "checks:",
    ] {
        assert!(text.contains(needle), "missing '{needle}' in\n{text}");
    }
    // The lab's IR distortion folds inside the image: show says so.
    assert!(text.contains("WARN  depth: distortion folds"), "{text}");

    let ir = p("ir.json");
    let pattern = format!("{}/kinect-lab/ir_*.bmp", data.display());
    ok(&["calibrate", "--ir", &pattern, "--lab-settings", "--out", s(&ir)]);
    let text = ok(&["rig", "show", s(&ir)]);
    assert!(
        text.contains("single-camera") && text.contains("depth camera: 512 x 424 px"),
        "{text}"
    );
    ok(&["rig", "export", s(&ir), "--format", "ros", "--out", s(&p("ros"))]);
    let info = std::fs::read_to_string(p("ros/depth.yaml")).unwrap();
    assert!(info.contains("image_width: 512"), "{info}");
    // The exported camera imports back (as the depth camera) to the same numbers.
    ok(&[
        "rig",
        "import",
        s(&p("ros/depth.yaml")),
        "--camera",
        "depth",
        "--out",
        s(&p("ir_back.json")),
    ]);
    let a = kfuse_io::rig::read_rig(&ir)
        .unwrap()
        .into_calibration(&ir)
        .unwrap()
        .camera(kfuse_io::rig_io::Role::Depth, &ir)
        .unwrap();
    let back = p("ir_back.json");
    let b = kfuse_io::rig::read_rig(&back)
        .unwrap()
        .into_calibration(&back)
        .unwrap()
        .camera(kfuse_io::rig_io::Role::Depth, &back)
        .unwrap();
    let diff =
        cam_values(&a).iter().zip(cam_values(&b)).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    // As for the OpenCV/ROS round trips above: f64 printed in full, 1e-9 is a loose ceiling.
    assert!(diff < 1e-9, "{diff}");
    // undistort takes the single-camera file; the wrong camera is named.
    let img = lab(&data, "ir_1.bmp");
    ok(&["undistort", "--rig", s(&ir), "--camera", "depth", s(&img), "--out", s(&p("rect"))]);
    assert!(p("rect/ir_1_rect.bmp").is_file(), "a BMP stays a BMP");
    let (good, _, err) = kfuse(&[
        "undistort",
        "--rig",
        s(&ir),
        "--camera",
        "color",
        s(&img),
        "--out",
        s(&p("rect2")),
    ]);
    assert!(!good && err.contains("ir.json") && err.contains("--camera depth"), "{err}");
}

/// Bad files: one line on stderr naming the file, non-zero exit, no output written.
#[test]
fn bad_files_fail_with_one_line_naming_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let p = |f: &str| tmp.path().join(f);
    let out = p("rig.json");
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("fake.mat", b"MATLAB 5.0 MAT-file, but truncated".to_vec(), "fake.mat"),
        ("notes.txt", b"just some words".to_vec(), "notes.txt"),
        ("empty.yml", b"%YAML:1.0\n---\nfoo: 1\n".to_vec(), "no camera matrix"),
        ("params.json", br#"{"format": "kfuse-kinect-params", "depth": {"width": 512}}"#.to_vec(), "depth.height"),
        ("image.png", b"\x89PNG\r\n\x1a\n\xff\xfe\x00\x01".to_vec(), "image.png"),
        ("ros.yaml", b"image_width: 512\nimage_height: 424\ncamera_name: depth\ndistortion_model: equidistant\n".to_vec(), "equidistant"),
        // Bouguet's script of its results (was "not valid YAML").
        ("Calib_Results_left.m", b"% Intrinsic and Extrinsic Camera Parameters\n%\nfc = [ 364.1 ; 365.1 ];\n".to_vec(), "give the .mat file it saved beside it"),
    ];
    for (name, bytes, needle) in cases {
        std::fs::write(p(name), bytes).unwrap();
        let (good, stdout, err) = kfuse(&["rig", "import", s(&p(name)), "--out", s(&out)]);
        assert!(!good, "{name}: {stdout}");
        // The brief's rule: bad input gets one line naming the file.
        assert_eq!(err.trim_end().lines().count(), 1, "{name}: {err}");
        assert!(err.contains(name) && err.contains(needle), "{name}: {err}");
        assert!(!out.exists(), "{name}: output written");
    }
    // A Bouguet stereo file without its mono files beside it.
    if let Some(data) = shared("bad_files_fail_with_one_line_naming_the_file") {
        let alone = p("Calib_Results_stereo.mat");
        std::fs::copy(lab(&data, "Calib_Results_stereo.mat"), &alone).unwrap();
        let (good, _, err) = kfuse(&["rig", "import", s(&alone), "--out", s(&out)]);
        assert!(
            !good && err.contains("Calib_Results_left.mat") && err.contains("not found"),
            "{err}"
        );
        assert!(!out.exists());
    }
    // show and export on a file that is not a rig.
    let (good, _, err) = kfuse(&["rig", "show", s(&p("notes.txt"))]);
    assert!(!good && err.contains("notes.txt") && err.contains("kfuse rig import"), "{err}");
    let (good, _, err) = kfuse(&["rig", "show", s(&p("missing.json"))]);
    assert!(!good && err.contains("missing.json"), "{err}");
}

/// The one file in `dir` whose name ends with `suffix`.
fn only_file(dir: &Path, suffix: &str) -> PathBuf {
    let found: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().ends_with(suffix))
        .collect();
    assert_eq!(found.len(), 1, "{suffix} in {}: {found:?}", dir.display());
    found[0].clone()
}

/// kfuse's orientation rule (images as the scene is): a capture's factory rig has the colour
/// camera at +52 mm, as the lab's Bouguet rig (+52.2 mm), which fuses a capture as it is. A
/// rig calibrated on images mirrored left-right (the colour camera on the other side of the
/// depth camera than the sensor's factory parameters say: raw libfreenect2, old captures) is
/// refused by `fuse` beside a capture's kinect_params.json, for one frame and for a folder of
/// frames, with the fix; `rig import --mirror` converts it, and mirroring twice gives the rig
/// back.
#[test]
fn a_rig_of_mirrored_images_is_refused_beside_a_capture_and_converted() {
    let tmp = tempfile::tempdir().unwrap();
    let cap = tmp.path().join("cap");
    ok(&["capture", "scene", "--backend", "sim", "--interval", "0", "--out", s(&cap)]);
    let factory = tmp.path().join("factory.json");
    ok(&["rig", "import", s(&cap.join("kinect_params.json")), "--out", s(&factory)]);
    let mirrored = tmp.path().join("mirrored.json");
    let text = ok(&["rig", "import", s(&factory), "--mirror", "--out", s(&mirrored)]);
    assert!(text.contains("mirrored left-right"), "{text}");
    // The factory rig already is of images as the scene is: the note says --mirror undid it.
    assert!(text.contains("--mirror turned a rig of images as the scene is"), "{text}");
    // The factory rig: colour camera 52 mm along +x (SimProfile::synthetic's shift_m of the
    // sensor's mirrored stream, mirrored back; 1e-6 m of f32 rounding); mirrored, along −x.
    let x = |p: &Path| read_rig(p).color_centre_in_depth().x;
    assert!((x(&factory) - 0.052).abs() < 1e-6 && (x(&mirrored) + 0.052).abs() < 1e-6);
    let (color, depth) = (only_file(&cap, "_color.jpg"), only_file(&cap, "_depth.png"));
    let fuse = |rig: &Path, out: &Path, extra: &[&str]| {
        let args = ["fuse", "--rig", s(rig), "--color", s(&color), "--depth", s(&depth)];
        kfuse(&[&args[..], &["--out", s(out), "--no-figures"], extra].concat())
    };
    let out = tmp.path().join("fused");
    let (good, _, err) = fuse(&mirrored, &out, &[]);
    assert!(!good && !out.exists(), "{err}");
    assert!(
        err.contains("mirrored.json puts the colour camera at x = -52.0 mm")
            && err.contains("kinect_params.json at +52.0 mm")
            && err.contains("the rig was calibrated on images mirrored left-right")
            && err.contains("--mirror --out RIG.json"),
        "{err}"
    );
    let (good, _, err) = fuse(&mirrored, &out, &["--force"]);
    assert!(good && err.contains("warning") && err.contains("mirrored left-right"), "{err}");
    let (good, _, err) = fuse(&factory, &tmp.path().join("fused2"), &[]);
    assert!(good && !err.contains("mirrored"), "{err}");
    // The same images away from their kinect_params.json: the mirrored rig cannot be checked
    // against the sensor's, so it fuses, with a warning naming the conversion.
    let away = tmp.path().join("away");
    std::fs::create_dir(&away).unwrap();
    let (color_away, depth_away) = (away.join("c.jpg"), away.join("d.png"));
    std::fs::copy(&color, &color_away).unwrap();
    std::fs::copy(&depth, &depth_away).unwrap();
    let args =
        ["fuse", "--rig", s(&mirrored), "--color", s(&color_away), "--depth", s(&depth_away)];
    let out_away = tmp.path().join("fused_away");
    let (good, _, err) = kfuse(&[&args[..], &["--out", s(&out_away), "--no-figures"]].concat());
    assert!(
        good && err.contains("warning: ")
            && err.contains("a calibration of images mirrored")
            && err.contains("--mirror --out RIG.json"),
        "{err}"
    );
    // A rig calibrated with squares 10x too small (T = 5.2 mm), and the capture's IR image
    // given as its depth: refused beside the capture. Depth in centimetres read as
    // millimetres (a Kinect frame at 0.1 of its distance): a warning.
    let mut small = read_rig(&factory);
    small.color_from_depth.translation *= 0.1;
    let small_path = tmp.path().join("small.json");
    kfuse_io::rig::write_rig(&small_path, &small).unwrap();
    let (good, _, err) = fuse(&small_path, &tmp.path().join("f3"), &[]);
    assert!(
        !good
            && err.contains("baseline of 5.2 mm")
            && err.contains("52.0 mm")
            && err.contains("--square too small"),
        "{err}"
    );
    let ir = only_file(&cap, "_ir.png");
    let args = ["fuse", "--rig", s(&factory), "--color", s(&color), "--depth", s(&ir)];
    let (good, _, err) = kfuse(&[&args[..], &["--out", s(&tmp.path().join("f4"))]].concat());
    assert!(
        !good && err.contains("is named as kfuse capture names the IR (brightness) image"),
        "{err}"
    );
    assert!(err.contains("scene_depth.png"), "{err}");
    let mm = kfuse_io::images::read_depth(&depth, 0.001).unwrap();
    let cm = geometry::Image::from_fn(mm.width(), mm.height(), |x, y| *mm.get(x, y) * 0.1);
    let cm_path = tmp.path().join("depth_cm.png");
    kfuse_io::images::write_depth_png16(&cm_path, &cm).unwrap();
    let args = ["fuse", "--rig", s(&factory), "--color", s(&color), "--depth", s(&cm_path)];
    let (good, _, err) =
        kfuse(&[&args[..], &["--out", s(&tmp.path().join("f5")), "--no-figures"]].concat());
    assert!(
        good && err.contains("nearer than the Kinect v2 measures")
            && err.contains("--depth-scale 0.01)"),
        "{err}"
    );
    // A folder of frames with the mirrored rig: refused the same way.
    let seq = tmp.path().join("seq");
    let (good, _, err) =
        kfuse(&["fuse", "--rig", s(&mirrored), "--frames", s(&cap), "--out", s(&seq)]);
    assert!(!good && err.contains("mirrored left-right") && !seq.exists(), "{err}");
    // Twice mirrored: the factory rig (a rig file's rotation is re-orthonormalised on reading:
    // 1e-15).
    let back = tmp.path().join("back.json");
    ok(&["rig", "import", s(&mirrored), "--mirror", "--out", s(&back)]);
    assert!(rig_diff(&read_rig(&back), &read_rig(&factory)) < 1e-12);

    // The lab's Bouguet rig: of images as the scene is, as kfuse's, so no note on import, and
    // it fuses a capture without --mirror; --mirror puts its colour camera at −52.2 mm, named.
    let Some(data) = shared("a_rig_of_mirrored_images_is_refused_beside_a_capture_and_converted")
    else {
        return;
    };
    let stereo = lab(&data, "Calib_Results_stereo.mat");
    let lab_rig = tmp.path().join("lab.json");
    let text = ok(&["rig", "import", s(&stereo), "--out", s(&lab_rig)]);
    assert!(!text.contains("mirrored"), "{text}");
    let shown = ok(&["rig", "show", s(&lab_rig)]);
    assert!(
        shown.contains("ok    orientation: the colour camera sits at x = +52.2 mm")
            && shown.contains("images as the scene is"),
        "{shown}"
    );
    let (good, _, err) = fuse(&lab_rig, &tmp.path().join("fused_lab"), &[]);
    assert!(good && !err.contains("mirrored"), "{err}");
    let lab_mirrored = tmp.path().join("lab_mirrored.json");
    let text = ok(&["rig", "import", s(&stereo), "--mirror", "--out", s(&lab_mirrored)]);
    assert!(text.contains("--mirror turned a rig of images as the scene is"), "{text}");
    let shown = ok(&["rig", "show", s(&lab_mirrored)]);
    assert!(
        shown.contains("WARN  orientation: the colour camera sits at x = -52.2 mm of the depth camera, a calibration of images mirrored"),
        "{shown}"
    );
    let (lab_r, m) = (read_rig(&lab_rig), read_rig(&lab_mirrored));
    // Bouguet's T = (−52.195, −0.262, 0.625) mm, R within 1.5° of identity: the centre is
    // −Rᵀ·T ≈ +52.2 mm along x; mirrored −52.2 mm, cx → 511 − cx.
    assert!((lab_r.color_centre_in_depth().x * 1000.0 - 52.2).abs() < 0.1);
    assert!((m.color_centre_in_depth().x * 1000.0 + 52.2).abs() < 0.1);
    assert_eq!(m.depth.intrinsics.cx, 511.0 - lab_r.depth.intrinsics.cx);
    // The lab's KinectData.mat (the same rig) with a capture's images in place of its own:
    // the same orientation, accepted.
    let kd = lab(&data, "KinectData.mat");
    let args = ["fuse", "--mat", s(&kd), "--color", s(&color), "--depth", s(&depth)];
    let out = tmp.path().join("fused_kd");
    let (good, _, err) = kfuse(&[&args[..], &["--out", s(&out), "--no-figures"]].concat());
    assert!(good && !err.contains("mirrored"), "{err}");
    // A capture folder of the old rule (kinect_params.json version 1: the sensor's own
    // parameters of mirrored images) beside the lab's rig: refused, the other way round.
    let old = tmp.path().join("old");
    std::fs::create_dir(&old).unwrap();
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(cap.join("kinect_params.json")).unwrap())
            .unwrap();
    v["version"] = 1.into();
    v.as_object_mut().unwrap().remove("image_orientation");
    let mirror_x = |v: &mut serde_json::Value, cam: &str, w: f64| {
        v[cam]["cx"] = (w - 1.0 - v[cam]["cx"].as_f64().unwrap()).into();
    };
    mirror_x(&mut v, "depth", 512.0);
    mirror_x(&mut v, "color", 1920.0);
    v["depth"]["p2"] = (-v["depth"]["p2"].as_f64().unwrap()).into();
    v["color"]["shift_m"] = (-v["color"]["shift_m"].as_f64().unwrap()).into();
    for (key, signs) in [
        ("mx", [1.0, -1.0, -1.0, 1.0, -1.0, -1.0, 1.0, 1.0, -1.0, -1.0]),
        ("my", [-1.0, 1.0, 1.0, -1.0, 1.0, 1.0, -1.0, -1.0, 1.0, 1.0]),
    ] {
        for (c, sign) in v["color"][key].as_array_mut().unwrap().iter_mut().zip(signs) {
            *c = (c.as_f64().unwrap() * sign).into();
        }
    }
    std::fs::write(old.join("kinect_params.json"), v.to_string()).unwrap();
    let old_depth = old.join("scene_depth.png");
    std::fs::copy(&depth, &old_depth).unwrap();
    let old_factory = tmp.path().join("old_factory.json");
    let text = ok(&["rig", "import", s(&old.join("kinect_params.json")), "--out", s(&old_factory)]);
    assert!(text.contains("parameters of mirrored images (kinect_params.json version 1"), "{text}");
    assert!((x(&old_factory) + 0.052).abs() < 1e-6, "{}", x(&old_factory));
    let args = ["fuse", "--rig", s(&lab_rig), "--color", s(&color), "--depth", s(&old_depth)];
    let out = tmp.path().join("fused_old");
    let (good, _, err) = kfuse(&[&args[..], &["--out", s(&out), "--no-figures"]].concat());
    assert!(
        !good
            && err.contains("x = +52.2 mm")
            && err.contains("these images are mirrored left-right")
            && err.contains("--mirror"),
        "{err}"
    );
    assert!(!out.exists());
}

// ---------------------------------------------------------------------------------------
// iai_kinect2

/// One OpenCV FileStorage matrix as kinect2_calibration's OpenCV writes it (`%.16e`, `dt: d`);
/// the test's own writer, independent of kfuse's exporter.
fn cv_matrix(name: &str, rows: usize, cols: usize, data: &[f64]) -> String {
    let values: Vec<String> = data.iter().map(|v| format!("{v:.16e}")).collect();
    format!(
        "{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {} ]\n",
        values.join(", ")
    )
}

/// The four files of iai_kinect2's calibration folder for `rig` and a depth shift (mm added
/// to the measured depth), in `dir`.
fn write_iai_folder(dir: &Path, rig: &Rig, depth_shift_mm: f64) {
    std::fs::create_dir_all(dir).unwrap();
    let rows = |m: &nalgebra::Matrix3<f64>| -> Vec<f64> {
        (0..3).flat_map(|i| (0..3).map(move |j| m[(i, j)])).collect()
    };
    let eye = nalgebra::Matrix3::<f64>::identity();
    let camera = |c: &geometry::CameraModel| {
        let k = c.intrinsics.matrix();
        let mut p = vec![0.0; 16];
        for i in 0..3 {
            for j in 0..3 {
                p[4 * i + j] = k[(i, j)];
            }
        }
        p[15] = 1.0;
        format!(
            "%YAML:1.0\n{}{}{}{}",
            cv_matrix("cameraMatrix", 3, 3, &rows(&k)),
            cv_matrix("distortionCoefficients", 1, 5, &c.distortion.to_array()),
            cv_matrix("rotation", 3, 3, &rows(&eye)),
            cv_matrix("projection", 4, 4, &p)
        )
    };
    let r = *rig.color_from_depth.rotation.matrix();
    let t = rig.color_from_depth.translation;
    let tx = nalgebra::Matrix3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0);
    let pose = format!(
        "%YAML:1.0\n{}{}{}",
        cv_matrix("rotation", 3, 3, &rows(&r)),
        cv_matrix("translation", 3, 1, t.as_slice()),
        cv_matrix("essential", 3, 3, &rows(&(tx * r)))
    );
    std::fs::write(dir.join("calib_color.yaml"), camera(&rig.color)).unwrap();
    std::fs::write(dir.join("calib_ir.yaml"), camera(&rig.depth)).unwrap();
    std::fs::write(dir.join("calib_pose.yaml"), pose).unwrap();
    std::fs::write(
        dir.join("calib_depth.yaml"),
        format!("%YAML:1.0\ndepthShift: {depth_shift_mm:.16e}\n"),
    )
    .unwrap();
}

/// Measured depth offset of the scene below (the Kinect v2's static offset, ~20 mm in
/// iai_kinect2's README), metres; iai writes its correction as depthShift = −20 mm.
const SENSOR_DEPTH_OFFSET_M: f32 = 0.020;

/// A scene rendered with `geometry::synth::kinect_rig` (unmirrored: colour camera at
/// +51.9 mm, iai's orientation) whose depth reads 20 mm too far, and its calibration written
/// in iai_kinect2's files with iai's conventions (X_color = R·X_ir + T in metres, depthShift
/// in mm added to the depth): `rig import DIR` → `fuse` puts the fused z-buffer on the truth
/// (median error < 2 mm, > 97 % within 10 mm: the nearest-sample error on the tilted wall
/// plus the mm rounding, as for KinectData.mat in cli_lab.rs). Without the depth shift the
/// median would be ~20 mm; with its sign reversed ~40 mm; a mirrored rig misplaces the edges.
/// Then `rig export --format iai-kinect2` of the imported rig and `rig import` of those files
/// give it back (1e-12), and a folder without calib_pose.yaml is one line naming it.
#[test]
fn iai_kinect2_folder_imports_and_fuses_onto_the_truth() {
    let tmp = tempfile::tempdir().unwrap();
    let p = |f: &str| tmp.path().join(f);
    let setup = geometry::synth::kinect_preset(false);
    let frame = geometry::synth::render(&setup);
    let (w, h) = frame.depth.size();
    let measured =
        geometry::Image::from_fn(w, h, |x, y| frame.depth.get(x, y) + SENSOR_DEPTH_OFFSET_M);
    kfuse_io::images::write_depth_png16(&p("depth.png"), &measured).unwrap();
    kfuse_io::images::write_color_png(&p("color.png"), &frame.color).unwrap();
    let iai = p("012526541941");
    write_iai_folder(&iai, &setup.rig, -1000.0 * f64::from(SENSOR_DEPTH_OFFSET_M));

    let said = ok(&["rig", "import", s(&iai), "--out", s(&p("rig.json"))]);
    assert!(said.contains("iai_kinect2") && said.contains("store no image size"), "{said}");
    let rig = read_rig(&p("rig.json"));
    assert!(rig_diff(&rig, &setup.rig) < 1e-12, "{}", rig_diff(&rig, &setup.rig));
    let out = p("fused");
    ok(&[
        "fuse",
        "--rig",
        s(&p("rig.json")),
        "--color",
        s(&p("color.png")),
        "--depth",
        s(&p("depth.png")),
        "--out",
        s(&out),
        "--no-figures",
    ]);
    let (median, within, n) = common::zbuffer_vs_truth(&out, &frame);
    eprintln!(
        "iai_kinect2 folder: z-buffer vs truth median {:.2} mm, {:.2} % within 10 mm of {n} px",
        median * 1e3,
        within * 1e2
    );
    assert!(median < 0.002 && within > 0.97 && n > 150_000, "{median} {within} {n}");

    ok(&["rig", "export", s(&p("rig.json")), "--format", "iai-kinect2", "--out", s(&p("back"))]);
    ok(&["rig", "import", s(&p("back")), "--out", s(&p("back.json"))]);
    let back = read_rig(&p("back.json"));
    assert!(rig_diff(&back, &rig) < 1e-12, "{}", rig_diff(&back, &rig));
    let offset = |r: &Rig| {
        r.depth_correction
            .as_deref()
            .unwrap()
            .value(geometry::depth_correction::DepthTermKind::Offset)
    };
    assert!((offset(&back) - f64::from(SENSOR_DEPTH_OFFSET_M)).abs() < 1e-9, "{}", offset(&back));

    std::fs::remove_file(iai.join("calib_pose.yaml")).unwrap();
    let (good, _, err) = kfuse(&["rig", "import", s(&iai), "--out", s(&p("none.json"))]);
    assert!(!good && err.trim_end().lines().count() == 1, "{err}");
    assert!(err.contains("calib_pose.yaml: not found"), "{err}");
    assert!(!p("none.json").exists());
}

/// The red-team's bad rig inputs, each refused with one line naming the file and what is
/// wrong, nothing written: an empty .json and .mat (were "not a mapping"), a Bouguet .mat
/// with a NaN focal length (printed a Rust debug struct) and with `n_ima = 1e18` (would loop
/// for ever), 400 kB of nested brackets (kept `rig import` busy past 60 s), and a rig JSON
/// with a key twice (the last was taken).
#[test]
fn red_team_rig_inputs_fail_with_one_line() {
    use kfuse_io::mat::{MatValue, write_mat};
    let tmp = tempfile::tempdir().unwrap();
    let p = |f: &str| tmp.path().join(f);
    let out = p("rig.json");
    std::fs::write(p("empty.json"), b"").unwrap();
    std::fs::write(p("empty.mat"), b"").unwrap();
    std::fs::write(p("deep.yaml"), format!("M1: {}", "[".repeat(400_000))).unwrap();
    let bouguet = |path: &Path, fc0: f64, n_ima: f64| {
        write_mat(
            path,
            &[
                ("fc", MatValue::double_matrix(2, 1, &[fc0, 365.0])),
                ("cc", MatValue::double_matrix(2, 1, &[255.5, 211.5])),
                ("kc", MatValue::double_matrix(5, 1, &[0.09, -0.27, 0.0, 0.0, 0.0])),
                ("alpha_c", MatValue::scalar(0.0)),
                ("nx", MatValue::scalar(512.0)),
                ("ny", MatValue::scalar(424.0)),
                ("n_ima", MatValue::scalar(n_ima)),
            ],
        )
        .unwrap()
    };
    bouguet(&p("Calib_Results_left.mat"), f64::NAN, 1.0);
    bouguet(&p("Calib_Results.mat"), 365.0, 1e18);
    let rig_text = geometry::synth::kinect_rig().to_json();
    std::fs::write(p("twice.json"), rig_text.replacen("\"fx\":", "\"fx\": 36.5, \"fx\":", 1))
        .unwrap();
    let cases = [
        ("empty.json", "is empty (0 bytes)"),
        ("empty.mat", "is empty (0 bytes)"),
        ("Calib_Results_left.mat", "got fx = NaN"),
        ("Calib_Results.mat", "'n_ima' (the number of images) is 1e18"),
        ("deep.yaml", "nested more than 16 levels"),
        ("twice.json", "key \"fx\" appears twice in depth_camera"),
    ];
    for (name, needle) in cases {
        let (good, stdout, err) =
            kfuse(&["rig", "import", s(&p(name)), "--camera", "depth", "--out", s(&out)]);
        assert!(!good, "{name}: {stdout}");
        assert_eq!(err.trim_end().lines().count(), 1, "{name}: {err}");
        assert!(err.contains(name) && err.contains(needle), "{name}: {err}");
        assert!(!err.contains("mapping") && !err.contains("CameraModel {"), "{name}: {err}");
        assert!(!out.exists(), "{name}: output written");
    }
    // Every command reads rigs through the same check.
    let (good, _, err) = kfuse(&["rig", "show", s(&p("twice.json"))]);
    assert!(!good && err.contains("twice.json") && err.contains("appears twice"), "{err}");
}

/// Huge and tiny values are printed in scientific notation by `rig show` and in messages (a
/// focal length of 1e300 px was printed with 301 digits, k1 = 1e-300 with 300).
#[test]
fn huge_and_tiny_numbers_are_printed_in_scientific_notation() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("odd.json");
    let mut rig = geometry::synth::kinect_rig();
    rig.depth.intrinsics.fx = 1e300;
    rig.color.distortion.k1 = 1e-300;
    kfuse_io::rig::write_rig(&path, &rig).unwrap();
    let shown = ok(&["rig", "show", s(&path)]);
    assert!(shown.contains("fx 1.000e300 px"), "{shown}");
    // No run of digits longer than f64's 17 significant ones (fx alone was 301 digits).
    let longest_digits = |t: &str| t.split(|c: char| !c.is_ascii_digit()).map(str::len).max();
    assert!(longest_digits(&shown).unwrap() <= 17, "{shown}");
    let (good, _, err) =
        kfuse(&["rig", "import", s(&path), "--out", s(&tmp.path().join("r.json"))]);
    assert!(!good && err.contains("fx = 1e300 px is over"), "{err}");
    assert!(longest_digits(&err).unwrap() <= 17, "{err}");
}

/// The simulated ring's own rig (`true_rig.json` of `capture scene --backend sim
/// --sim-sensors 3 --device all`): `rig show` printed "ok    sensor 000000000003: rotation
/// between the cameras NaN°" (issue 51): that pair's R, composed from the ring's poses, has
/// cos θ one ulp above 1, and nalgebra's `acos` gives NaN. Checked failing on the code before
/// `geometry::pose::rotation_angle` (the NaN line above). The sim's depth and colour cameras
/// are parallel: every pair is now 0.000°, and the angle itself under 1e-6° (f64 round-off
/// of composing poses 3.2 m away is ~1e-14 rad).
#[test]
fn show_of_the_simulated_rings_rig_prints_its_rotations() {
    let tmp = tempfile::tempdir().unwrap();
    let cap = tmp.path().join("ring");
    let args = ["capture", "scene", "--backend", "sim", "--sim-sensors", "3", "--device", "all"];
    ok(&[&args[..], &["--interval", "0", "--out", s(&cap)]].concat());
    let rig_path = cap.join("true_rig.json");
    let shown = ok(&["rig", "show", s(&rig_path)]);
    assert!(!shown.contains("NaN"), "{shown}");
    let rig =
        geometry::MultiRig::from_json(&std::fs::read_to_string(&rig_path).unwrap(), &rig_path)
            .unwrap();
    for serial in ["000000000001", "000000000002", "000000000003"] {
        let line = format!("ok    sensor {serial}: rotation between the cameras 0.000°");
        assert!(shown.contains(&line), "{line}\n{shown}");
        let angle = rig.sensor_rig(serial).unwrap().0.color_from_depth.angle_deg();
        assert!(angle.abs() < 1e-6, "{serial}: {angle}");
    }
}

/// `rig export --format iai-kinect2` of a rig of mirrored images (colour camera at −52 mm,
/// where kinect2_bridge's images have it at +52 mm) is refused in one line with the
/// conversion, and nothing is written; the rig it converts to exports (issue 51; checked
/// failing by removing the orientation check in `kfuse_io::rig_io::iai::export`).
#[test]
fn iai_kinect2_export_of_a_mirrored_rig_is_refused_with_the_conversion() {
    let tmp = tempfile::tempdir().unwrap();
    let rig = common::repo_dir().join("data/kinect/rig.json");
    let mirrored = tmp.path().join("mirrored.json");
    ok(&["rig", "import", s(&rig), "--mirror", "--out", s(&mirrored)]);
    let out = tmp.path().join("iai");
    let (good, _, err) =
        kfuse(&["rig", "export", s(&mirrored), "--format", "iai-kinect2", "--out", s(&out)]);
    assert!(!good, "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("mirrored.json")
            && err.contains("mirrored left-right")
            && err.contains("x = -52.0 mm")
            && err.contains("--mirror --out RIG.json"),
        "{err}"
    );
    assert!(!out.exists());
    let back = tmp.path().join("back.json");
    ok(&["rig", "import", s(&mirrored), "--mirror", "--out", s(&back)]);
    ok(&["rig", "export", s(&back), "--format", "iai-kinect2", "--out", s(&out)]);
    assert!(out.join("calib_pose.yaml").is_file());
}

/// Numbers a user or a file gives are echoed bounded (issue 51): `--interval 1e300` and an
/// iai_kinect2 depthShift of 1e308 mm were printed with 301 and 309 digits; now as 1e300 and
/// 1e308 (checked failing by reverting the `num` calls).
#[test]
fn huge_interval_and_depth_shift_are_echoed_in_scientific_notation() {
    let tmp = tempfile::tempdir().unwrap();
    let longest_digits =
        |t: &str| t.split(|c: char| !c.is_ascii_digit()).map(str::len).max().unwrap_or(0);
    let out = tmp.path().join("cap");
    let (good, _, err) =
        kfuse(&["capture", "calib", "--backend", "sim", "--interval", "1e300", "--out", s(&out)]);
    assert!(!good && err.contains("1e300 s is outside [0, 86400] seconds"), "{err}");
    assert!(longest_digits(&err) <= 17, "{err}");
    assert!(!out.exists());
    let dir = tmp.path().join("iai");
    write_iai_folder(&dir, &geometry::synth::kinect_rig(), 1e308);
    let rig = tmp.path().join("rig.json");
    let (good, _, err) = kfuse(&["rig", "import", s(&dir), "--out", s(&rig)]);
    assert!(!good && err.contains("'depthShift' 1e308 mm"), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(longest_digits(&err) <= 17, "{err}");
    assert!(!rig.exists());
}

/// `rig export --format iai-kinect2` writes its four files together or not at all (issue 51: a
/// full disk left 1 of the 4). A write that fails midway is made with a file-size limit
/// (`ulimit -f`, SIGXFSZ ignored, so write(2) fails with EFBIG as on a full disk) between the
/// smallest and the largest file's size: no file of the set appears in a new folder (nor the
/// folder), and an earlier complete set in an existing folder stays byte for byte.
#[test]
fn iai_export_writes_its_four_files_together_or_none() {
    let tmp = tempfile::tempdir().unwrap();
    let rig = common::repo_dir().join("data/kinect/rig.json");
    let good = tmp.path().join("good");
    ok(&["rig", "export", s(&rig), "--format", "iai-kinect2", "--out", s(&good)]);
    let mut sizes: Vec<(String, u64)> = std::fs::read_dir(&good)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (e.file_name().to_string_lossy().into_owned(), e.metadata().unwrap().len())
        })
        .collect();
    sizes.sort_by_key(|(_, n)| *n);
    assert_eq!(sizes.len(), 4, "{sizes:?}");
    // bash's ulimit -f counts 1024-byte blocks: a limit the smallest file fits under and the
    // largest does not.
    let blocks = sizes[0].1.div_ceil(1024);
    assert!(blocks * 1024 < sizes[3].1, "no limit between the file sizes {sizes:?}");
    let limited = |out: &Path, overwrite: bool| {
        let mut args = vec!["rig", "export", s(&rig), "--format", "iai-kinect2", "--out", s(out)];
        if overwrite {
            args.push("--overwrite");
        }
        let script = format!("ulimit -f {blocks}; trap '' XFSZ; exec \"$0\" \"$@\"");
        let r = Command::new("bash")
            .args(["-c", &script, env!("CARGO_BIN_EXE_kfuse")])
            .args(&args)
            .output()
            .unwrap();
        assert!(!r.status.success(), "the limited export succeeded");
        let err = String::from_utf8_lossy(&r.stderr).into_owned();
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        err
    };
    let fresh = tmp.path().join("fresh");
    let err = limited(&fresh, false);
    assert!(err.contains("too large") || err.contains("File too large"), "{err}");
    assert!(!fresh.exists(), "the failed export left {}", fresh.display());
    // Into the folder of the earlier set: nothing changes, and no temporary is left.
    let before: Vec<Vec<u8>> =
        sizes.iter().map(|(n, _)| std::fs::read(good.join(n)).unwrap()).collect();
    limited(&good, true);
    let after: Vec<Vec<u8>> =
        sizes.iter().map(|(n, _)| std::fs::read(good.join(n)).unwrap()).collect();
    assert_eq!(before, after);
    assert_eq!(std::fs::read_dir(&good).unwrap().count(), 4, "a temporary was left");
}
