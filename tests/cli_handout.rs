//! The lab handout's flow end to end through the built binary (issue 13, "Done when"), and the
//! bundled sample set in `data/`:
//! * on the simulated sensor: `capture calib --backend sim` (equal to `data/calib`) →
//!   `calibrate` (stereo; against the sensor's factory parameters) → `rig export` / `rig import`
//!   round trips → `capture scene --backend sim` (equal to `data/kinect`) → `undistort` (format
//!   kept) → `fuse --rectified` (against the scene's true depth); and the README's first
//!   command, `fuse` on the bundled `data/kinect`, against the same truth;
//! * on the course data (`../shared/data`, skipped visibly when absent): Bouguet's
//!   `Calib_Results_stereo.mat` → `rig import` (equal to `calib::bouguet`'s numbers) → export /
//!   import round trip; `KinectData.mat` → `rig import` (the same calibration); `fuse --mat
//!   KinectData.mat --color Colour_rect.tif --depth Depth_rect.tif` with a uint16 depth rendered
//!   for the file's own rig (the shared copy's `Depth` is a broken 8-bit picture).

mod common;

use std::path::{Path, PathBuf};

use common::{depth_mm, kfuse, read_exr, rig_diff, scratch, small_rig, summary, zbuffer_vs_truth};
use geometry::synth::{self, SynthFrame};
use geometry::testdata::shared_data_or_skip as shared;
use geometry::{Distortion, Image, Rig};
use kfuse_io::raster::{Raster, RasterFormat, read_raster, write_raster};
use serde_json::Value;

/// The bundled sample set (data/README.md says which command made each file).
fn bundled_data() -> PathBuf {
    common::repo_dir().join("data")
}
/// Shots of the bundled calibration set: the first four poses of the simulated calibration
/// scene (`kinect_usb::sim::calib_scene::BOARD_POSES`), enough for a stereo calibration within
/// a few tenths of a pixel (and small enough to bundle: ~0.57 MB a pair).
const CALIB_SHOTS: usize = 4;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn ok(args: &[&str]) -> String {
    let o = kfuse(args);
    let text =
        format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "kfuse {args:?} failed:\n{text}");
    text
}

fn read_rig(p: &Path) -> Rig {
    kfuse_io::rig::read_rig(p).unwrap().into_pair(p).unwrap()
}

// ---------------------------------------------------------------------------------------
// Regenerated files against the bundled ones

/// Largest difference of two images' values, per channel: 8-bit colour levels, 16-bit units
/// (millimetres for depth, decoder units for IR). Panics when the pixel types or sizes differ.
fn max_value_diff(a: &Raster, b: &Raster) -> u32 {
    fn diff<T: Copy>(a: &[T], b: &[T], f: impl Fn(T, T) -> u32) -> u32 {
        assert_eq!(a.len(), b.len());
        a.iter().zip(b).map(|(&x, &y)| f(x, y)).max().unwrap_or(0)
    }
    let d8 = |x: u8, y: u8| x.abs_diff(y) as u32;
    match (a, b) {
        (Raster::Gray8(a), Raster::Gray8(b)) => diff(a.data(), b.data(), d8),
        (Raster::Rgb8(a), Raster::Rgb8(b)) => diff(a.data(), b.data(), |x: [u8; 3], y: [u8; 3]| {
            (0..3).map(|i| d8(x[i], y[i])).max().unwrap()
        }),
        (Raster::Gray16(a), Raster::Gray16(b)) => {
            diff(a.data(), b.data(), |x: u16, y: u16| x.abs_diff(y) as u32)
        }
        _ => panic!("pixel types differ: {} vs {}", a.kind(), b.kind()),
    }
}

/// Tolerance of a regenerated file against the bundled one: colour within 1 level (the JPEG is
/// the simulator's own encoding of a noise-free render), depth within 1 mm and IR within 1 unit
/// (the depth decoder's SIMD paths agree to 0.003 mm, which can flip one rounding). Measured on
/// the machine that bundled them: every file byte-identical.
const REGENERATED_MAX_DIFF: u32 = 1;

/// Each bundled file of `bundled` (images and `kinect_params.json`) against the file of the
/// same name that this run wrote into `fresh`.
fn assert_regenerates(bundled: &Path, fresh: &Path, names: &[String]) {
    for name in names {
        let (b, f) = (bundled.join(name), fresh.join(name));
        if name.ends_with(".json") {
            let parse =
                |p: &Path| -> Value { serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap() };
            assert_eq!(parse(&b), parse(&f), "{name}: the sensor's parameters differ");
            continue;
        }
        let ((rb, fb), (rf, ff)) = (read_raster(&b).unwrap(), read_raster(&f).unwrap());
        assert_eq!(fb, ff, "{name}: format");
        assert_eq!(rb.size(), rf.size(), "{name}: size");
        let d = max_value_diff(&rb, &rf);
        assert!(d <= REGENERATED_MAX_DIFF, "{name}: regenerated values differ by up to {d}");
    }
}

/// The scene `kfuse capture scene --backend sim` shows, rendered here with the factory rig of
/// `rig_file` (the one `rig import kinect_params.json` fits; exact for the simulated sensor,
/// tested in cli_rig): the noise-free Kinect preset, colour camera and `color_from_depth`
/// replaced, as the simulator renders it (`kfuse_capture`'s sim source).
fn sim_scene_truth(rig_file: &Path) -> SynthFrame {
    let factory = read_rig(rig_file);
    let mut setup = synth::kinect_preset(false);
    setup.rig.color = factory.color;
    setup.rig.color.distortion = Distortion::NONE;
    setup.rig.color_from_depth = factory.color_from_depth;
    synth::render(&setup)
}

/// Fuses and returns the output folder (no figures: they are tested elsewhere).
fn fuse(out: &Path, args: &[&str]) -> PathBuf {
    let mut all = vec!["fuse"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--out", s(out), "--no-figures"]);
    ok(&all);
    out.to_path_buf()
}

// ---------------------------------------------------------------------------------------
// The simulated sensor

/// Floors of the calibration comparison where calibrate's σ is tiny (noise-free corners), as
/// in tests/sim_calibration.rs: intrinsics 0.5 px (anti-aliasing and JPEG move corners by
/// ~0.05 px), rotation 0.05°, translation 0.2 mm.
const FLOOR_PX: f64 = 0.5;
const FLOOR_ROT_DEG: f64 = 0.05;
const FLOOR_T_MM: f64 = 0.2;

/// Every parameter of the calibrated rig against the factory rig, within max(3σ of
/// calibrate's own report, the floor); returns the table it printed.
fn assert_calibration_recovers(calibrated: &Rig, factory: &Rig) -> String {
    let cal = calibrated.calibration.clone().expect("calibrate writes its uncertainties");
    let mut report = String::new();
    let mut failures = Vec::new();
    let mut check = |what: &str, got: f64, truth: f64, sigma: f64, floor: f64| {
        let tol = (3.0 * sigma).max(floor);
        report += &format!(
            "{what:>10}: calibrated {got:10.4}  factory {truth:10.4}  diff {:+.4}  tol {tol:.4}\n",
            got - truth
        );
        if !((got - truth).abs() <= tol) {
            failures.push(what.to_string());
        }
    };
    for (cam, got, truth, std) in [
        ("depth", calibrated.depth.intrinsics, factory.depth.intrinsics, &cal["depth_std_1sigma"]),
        ("colour", calibrated.color.intrinsics, factory.color.intrinsics, &cal["color_std_1sigma"]),
    ] {
        for (name, g, t) in [
            ("fx", got.fx, truth.fx),
            ("fy", got.fy, truth.fy),
            ("cx", got.cx, truth.cx),
            ("cy", got.cy, truth.cy),
        ] {
            let sigma = std[name].as_f64().unwrap_or(f64::INFINITY);
            check(&format!("{cam} {name}"), g, t, sigma, FLOOR_PX);
        }
    }
    let std_of = |key: &str| -> Vec<f64> {
        cal[key].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
    };
    let rsig = std_of("color_from_depth_rotation_std_rad").iter().map(|s| s * s).sum::<f64>();
    let relative =
        calibrated.color_from_depth.rotation.inverse() * factory.color_from_depth.rotation;
    check("R angle°", relative.angle().to_degrees(), 0.0, rsig.sqrt().to_degrees(), FLOOR_ROT_DEG);
    let tstd = std_of("color_from_depth_translation_std_m");
    let (t, tt) = (calibrated.color_from_depth.translation, factory.color_from_depth.translation);
    for (i, axis) in ["T.x mm", "T.y mm", "T.z mm"].into_iter().enumerate() {
        check(axis, t[i] * 1e3, tt[i] * 1e3, tstd[i] * 1e3, FLOOR_T_MM);
    }
    assert!(failures.is_empty(), "outside tolerance: {failures:?}\n{report}");
    report
}

/// Export to OpenCV YAML and to a ROS camera_info pair and import both back: every parameter
/// within 1e-9 (both exporters print f64 in full; see tests/cli_rig.rs).
fn assert_export_round_trips(rig_path: &Path, dir: &Path) {
    let rig = read_rig(rig_path);
    let p = |f: &str| dir.join(f);
    ok(&["rig", "export", s(rig_path), "--format", "opencv", "--out", s(&p("rig.yml"))]);
    ok(&["rig", "import", s(&p("rig.yml")), "--out", s(&p("back_cv.json"))]);
    let d = rig_diff(&rig, &read_rig(&p("back_cv.json")));
    assert!(d < 1e-9, "OpenCV round trip: {d}");
    ok(&["rig", "export", s(rig_path), "--format", "ros", "--out", s(&p("ros"))]);
    ok(&[
        "rig",
        "import",
        s(&p("ros/depth.yaml")),
        s(&p("ros/color.yaml")),
        "--out",
        s(&p("back_ros.json")),
    ]);
    let d2 = rig_diff(&rig, &read_rig(&p("back_ros.json")));
    assert!(d2 < 1e-9, "ROS round trip: {d2}");
    eprintln!("export → import: OpenCV max difference {d:.1e}, ROS {d2:.1e}");
}

#[test]
fn handout_flow_on_the_simulated_sensor_and_the_bundled_data() {
    let dir = scratch("handout-sim");
    let data = &bundled_data();

    // L1: the calibration shots, equal to the bundled data/calib.
    let caps = dir.join("caps");
    let count = CALIB_SHOTS.to_string();
    ok(&[
        "capture",
        "calib",
        "--backend",
        "sim",
        "--count",
        &count,
        "--interval",
        "0",
        "--out",
        s(&caps),
    ]);
    let mut names = vec!["kinect_params.json".to_string()];
    for k in 1..=CALIB_SHOTS {
        names.push(format!("color_{k:04}.jpg"));
        names.push(format!("ir_{k:04}.png"));
    }
    assert_regenerates(&data.join("calib"), &caps, &names);

    // L2: stereo calibration, against the factory parameters (`rig import kinect_params.json`).
    let rig_path = dir.join("rig.json");
    ok(&[
        "calibrate",
        "--ir",
        &format!("{}/ir_*.png", caps.display()),
        "--color",
        &format!("{}/color_*.jpg", caps.display()),
        "--out",
        s(&rig_path),
    ]);
    let factory_path = dir.join("factory.json");
    ok(&["rig", "import", s(&caps.join("kinect_params.json")), "--out", s(&factory_path)]);
    let calibrated = read_rig(&rig_path);
    let report = assert_calibration_recovers(&calibrated, &read_rig(&factory_path));
    eprintln!("calibrated from {CALIB_SHOTS} simulated pairs:\n{report}");
    // The bundled rig is that same factory fit.
    assert!(rig_diff(&read_rig(&factory_path), &read_rig(&data.join("kinect/rig.json"))) < 1e-12);

    // Round trips of the calibrated rig through the other tools' formats.
    assert_export_round_trips(&rig_path, &dir);

    // L3: the scene, equal to the bundled data/kinect.
    let scene = dir.join("scene");
    ok(&[
        "capture",
        "scene",
        "--backend",
        "sim",
        "--name",
        "desk",
        "--interval",
        "0",
        "--out",
        s(&scene),
    ]);
    let names: Vec<String> =
        ["desk_color.jpg", "desk_depth.png", "desk_ir.png", "kinect_params.json"]
            .map(String::from)
            .to_vec();
    assert_regenerates(&data.join("kinect"), &scene, &names);

    // Undistort with the calibrated rig: the format and pixel type are kept.
    // Both cameras into one folder, as the handout keeps Colour_rect.tif beside Depth_rect.tif.
    let rect = dir.join("rect");
    ok(&[
        "undistort",
        "--rig",
        s(&rig_path),
        "--camera",
        "color",
        s(&scene.join("desk_color.jpg")),
        "--out",
        s(&rect),
    ]);
    ok(&[
        "undistort",
        "--rig",
        s(&rig_path),
        "--camera",
        "depth",
        s(&scene.join("desk_depth.png")),
        "--out",
        s(&rect),
    ]);
    let (c, cf) = read_raster(&rect.join("desk_color_rect.jpg")).unwrap();
    assert_eq!((cf, c.kind(), c.size()), (RasterFormat::Jpeg, "8-bit RGB", (1920, 1080)));
    let (d, df) = read_raster(&rect.join("desk_depth_rect.png")).unwrap();
    assert_eq!((df, d.kind(), d.size()), (RasterFormat::Png, "16-bit grey", (512, 424)));

    // fuse --rectified with the calibrated rig, and the README's first command (the bundled
    // files with the bundled factory rig), against the scene's true colour-frame depth.
    let truth = sim_scene_truth(&data.join("kinect/rig.json"));
    let rectified = fuse(
        &dir.join("fused_rect"),
        &[
            "--rig",
            s(&rig_path),
            "--color",
            s(&rect.join("desk_color_rect.jpg")),
            "--depth",
            s(&rect.join("desk_depth_rect.png")),
            "--rectified",
        ],
    );
    let bundled = fuse(
        &dir.join("fused_bundled"),
        &[
            "--rig",
            s(&data.join("kinect/rig.json")),
            "--color",
            s(&data.join("kinect/desk_color.jpg")),
            "--depth",
            s(&data.join("kinect/desk_depth.png")),
        ],
    );
    for (what, out, max_median, min_within) in [
        // The calibrated rig from 4 views (colour fx +0.47 px, T.z +0.8 mm off the factory's:
        // ~0.4 px at the image edges) and nearest-neighbour undistortion of the depth (up to
        // half a depth pixel, 1.5 colour pixels, per sample) move the depth edges by a pixel
        // or two: measured median 1.57 mm, 91.6 % within 10 mm (the rest on the ~2 m jumps
        // at the objects' outlines).
        ("calibrated + undistorted + --rectified", &rectified, 0.0025, 0.88),
        // The factory rig the scene was rendered with; the mm rounding of the depth file.
        ("bundled data/kinect", &bundled, 0.001, 0.98),
    ] {
        let (median, within, n) = zbuffer_vs_truth(out, &truth);
        eprintln!(
            "{what}: z-buffer vs truth median {:.2} mm, {:.2} % within 10 mm of {n} px",
            median * 1e3,
            within * 1e2
        );
        assert!(
            median < max_median && within > min_within && n > 150_000,
            "{what}: {median} {within} {n}"
        );
        let sm = summary(out);
        assert_eq!(sm["summary"]["depth_kind"], "z", "{what}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

// ---------------------------------------------------------------------------------------
// The course data

fn lab(data: &Path, f: &str) -> PathBuf {
    data.join("kinect-lab").join(f)
}

#[test]
fn handout_flow_on_the_course_data() {
    let Some(data) = shared("handout_flow_on_the_course_data") else { return };
    let dir = scratch("handout-course");

    // Bouguet's stereo result → rig, equal to the numbers written in the file itself, read
    // by an independent MATLAB v5 reader (`tests/mat5_values.py`, Python's standard library):
    // fc, cc, kc of each camera exactly (Bouguet's pixels are 0-based centres like ours, kc is
    // OpenCV's order), R to 1e-12 (reading a rig file re-orthonormalises it) and T (mm → m)
    // to 1e-15 m; then the exports round trip.
    let stereo = lab(&data, "Calib_Results_stereo.mat");
    let bouguet = dir.join("bouguet.json");
    ok(&["rig", "import", s(&stereo), "--out", s(&bouguet)]);
    let got = read_rig(&bouguet);
    let names = ["fc_left", "cc_left", "kc_left", "fc_right", "cc_right", "kc_right", "R", "T"];
    let read = std::process::Command::new("/usr/bin/python3")
        .arg(common::repo_dir().join("tests/mat5_values.py"))
        .arg(&stereo)
        .args(names)
        .output()
        .expect("/usr/bin/python3 is needed for the independent .mat reader");
    assert!(read.status.success(), "{}", String::from_utf8_lossy(&read.stderr));
    let file: Value = serde_json::from_slice(&read.stdout).unwrap();
    let nums = |n: &str| -> Vec<f64> {
        file[n]["data"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect()
    };
    for (cam, side) in [(&got.depth, "left"), (&got.color, "right")] {
        let (fc, cc, kc) =
            (nums(&format!("fc_{side}")), nums(&format!("cc_{side}")), nums(&format!("kc_{side}")));
        let (k, d) = (&cam.intrinsics, &cam.distortion);
        assert_eq!([k.fx, k.fy, k.cx, k.cy], [fc[0], fc[1], cc[0], cc[1]], "{side} camera");
        assert_eq!([d.k1, d.k2, d.p1, d.p2, d.k3], [kc[0], kc[1], kc[2], kc[3], kc[4]], "{side}");
    }
    let (r, t) = (nums("R"), nums("T"));
    let pose = &got.color_from_depth;
    for row in 0..3 {
        for col in 0..3 {
            // MATLAB stores column-major.
            let (g, w) = (pose.rotation[(row, col)], r[col * 3 + row]);
            assert!((g - w).abs() < 1e-12, "R[{row}][{col}]: {g} vs the file's {w}");
        }
        let (g, w) = (pose.translation[row], t[row] * 1e-3);
        assert!((g - w).abs() < 1e-15, "T[{row}]: {g} m vs the file's {w} m");
    }
    assert_export_round_trips(&bouguet, &dir);

    // The lab's KinectData.mat holds the same calibration (Calibrate.m copies Bouguet's KK and
    // R, T), without distortion.
    let kd_mat = lab(&data, "KinectData.mat");
    let kd = dir.join("kinect_data.json");
    let text = ok(&["rig", "import", s(&kd_mat), "--out", s(&kd)]);
    // Its 'Depth' is a 424×512 uint8 picture: the size is the Kinect's, and the note says why.
    assert!(
        text.contains(
            "depth camera 512x424 (the Kinect v2's size: its 'Depth' is not depth measurements)"
        ),
        "{text}"
    );
    let kd_rig = read_rig(&kd);
    assert_eq!(kd_rig.depth.intrinsics.fx, got.depth.intrinsics.fx);
    assert_eq!(kd_rig.color.intrinsics.fy, got.color.intrinsics.fy);
    let dt = (kd_rig.color_from_depth.translation - got.color_from_depth.translation).norm();
    // T printed by MATLAB to the file at double precision: equal up to the mm → m rounding.
    assert!(dt < 1e-12, "KinectData.mat T differs from Bouguet's by {dt} m");

    // The handout's rectified images of a scene seen by that rig: the Kinect preset rendered
    // with the file's own (distortion-free) rig, saved as Colour_rect.tif (RGB) and
    // Depth_rect.tif (uint16 mm, z); `fuse --mat` takes the rig from the file and the images
    // from the flags.
    let mut setup = synth::kinect_preset(false);
    setup.rig = kd_rig.clone();
    let frame = synth::render(&setup);
    let colour = dir.join("Colour_rect.tif");
    write_raster(&colour, &Raster::Rgb8(frame.color.clone()), RasterFormat::Tiff).unwrap();
    let depth = dir.join("Depth_rect.tif");
    write_raster(&depth, &Raster::Gray16(depth_mm(&frame)), RasterFormat::Tiff).unwrap();
    let out = fuse(
        &dir.join("fused"),
        &["--mat", s(&kd_mat), "--color", s(&colour), "--depth", s(&depth)],
    );
    let (median, within, n) = zbuffer_vs_truth(&out, &frame);
    eprintln!(
        "KinectData.mat + Colour_rect.tif + Depth_rect.tif: z-buffer vs truth median {:.2} mm, {:.2} % within 10 mm of {n} px",
        median * 1e3,
        within * 1e2
    );
    // As for the synthetic KinectData.mat of tests/cli_lab.rs: the mm rounding (±0.5 mm) and the
    // nearest sample's offset on the tilted wall; the rest is at edges.
    assert!(median < 0.002 && within > 0.97 && n > 150_000, "{median} {within} {n}");
    // `kfuse view` reopens exactly what fuse used (the file's rig, the replacing images named
    // by summary.json): fused again, it gives fuse's z-buffer bit for bit.
    let (frame, _) = viewer::data::open_folder_with(&out, false).unwrap();
    let opts = geometry::fusion::FusionOptions::default();
    let again =
        geometry::fusion::run(&frame.rig, &frame.depth, frame.kind, &frame.color, &opts).unwrap();
    let written = read_exr(&out.join("depth_zbuffer.exr"));
    assert_eq!(written.len(), again.zbuffer.data().len());
    let differing = written
        .iter()
        .zip(again.zbuffer.data())
        .filter(|(a, b)| a.to_bits() != b.to_bits() && !(a.is_nan() && b.is_nan()))
        .count();
    assert_eq!(differing, 0, "the viewer's inputs are not fuse's");
    let _ = std::fs::remove_dir_all(&dir);
}

// ---------------------------------------------------------------------------------------
// undistort: OpenEXR depth

#[test]
fn undistort_keeps_openexr_depth_in_metres() {
    let dir = scratch("handout-exr");
    let (w, h) = (64, 48);
    let depth = Image::from_fn(w, h, |x, y| {
        if (x + y) % 11 == 0 { f32::NAN } else { 0.8 + 0.013 * x as f32 + 0.007 * y as f32 }
    });
    let input = dir.join("depth_m.exr");
    kfuse_io::images::write_depth_exr(&input, &depth).unwrap();
    let rig_with = |name: &str, dist: Distortion| {
        let mut rig = small_rig();
        rig.depth.distortion = dist;
        let path = dir.join(name);
        kfuse_io::rig::write_rig(&path, &rig).unwrap();
        path
    };
    // Without distortion the map is the identity: every value comes back bit for bit (NaN
    // stays NaN), as OpenEXR.
    let plain = rig_with("plain.json", Distortion::NONE);
    let out = dir.join("out");
    ok(&["undistort", "--rig", s(&plain), "--camera", "depth", s(&input), "--out", s(&out)]);
    let back = read_exr(&out.join("depth_m_rect.exr"));
    assert_eq!(back.len(), w * h);
    assert!(
        back.iter().zip(depth.data()).all(|(a, b)| a.to_bits() == b.to_bits()),
        "values changed"
    );
    // With distortion, nearest neighbour: every value is an input value or NaN (masked).
    let lens =
        rig_with("lens.json", Distortion { k1: -0.2, k2: 0.05, p1: 0.001, p2: 0.0, k3: 0.0 });
    let out2 = dir.join("out2");
    ok(&["undistort", "--rig", s(&lens), "--camera", "depth", s(&input), "--out", s(&out2)]);
    let back = read_exr(&out2.join("depth_m_rect.exr"));
    assert!(
        back.iter().all(|v| v.is_nan() || depth.data().iter().any(|x| x.to_bits() == v.to_bits()))
    );
    assert!(
        back.iter().zip(depth.data()).any(|(a, b)| a.to_bits() != b.to_bits()),
        "the lens changed nothing"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
