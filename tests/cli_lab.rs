//! End-to-end tests of the lab's own workflow (issue 13) through the built binary: `fuse`
//! refuses a single-camera file and says how to get a rig; unit and emptiness mistakes fail
//! before any work, naming the mistake (`--force` overrides); `fuse --mat KinectData.mat` with
//! real uint16 depth against the scene's truth and against the same scene as separate files;
//! `--color`/`--depth` replacing the file's images; `--rectified`; `undistort` keeping the
//! format and pixel type of every input.
//!
//! Size (~640 lines, one file): the tests follow the handout's flow in order and share the
//! output readers, the KinectData.mat builder and the rectified scene defined beside them.

mod common;

use std::f64::consts::FRAC_PI_2;
use std::path::{Path, PathBuf};
use std::process::Output;

use common::{
    depth_mm, kfuse, read_exr, scratch, small_case, small_rig, summary, zbuffer_vs_truth,
};
use geometry::synth::{self, SynthFrame};
use geometry::testdata::shared_data_or_skip as shared_data;
use geometry::{Distortion, Image, Rig, RigidTransform};
use kfuse_io::mat::{MatValue, NumericArray, NumericData, row_to_column_major, write_mat};
use kfuse_io::raster::{Raster, RasterFormat, read_raster, write_raster};
use kfuse_io::rig_io::{Role, camera_file_json};
use kfuse_io::{images, rig as rigio};
use nalgebra::Vector3;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A clean failure (exit 1) with exactly one `error:` line, which it returns.
fn one_error_line(o: &Output) -> String {
    let err = stderr(o);
    assert_eq!(o.status.code(), Some(1), "expected a clean failure (exit 1): {err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "expected one error line: {err}");
    assert!(!err.contains("panicked"), "{err}");
    lines[0].to_string()
}

#[test]
fn fuse_refuses_a_single_camera_file_and_says_how_to_get_a_rig() {
    let case = small_case("lab-single");
    let ir = case.dir.join("ir.json");
    std::fs::write(&ir, camera_file_json(&small_rig().depth, Some(Role::Depth), &None)).unwrap();
    let out = case.dir.join("out");
    let o = kfuse(&[
        "fuse",
        "--rig",
        s(&ir),
        "--color",
        s(&case.color),
        "--depth",
        s(&case.depth),
        "--out",
        s(&out),
    ]);
    let line = one_error_line(&o);
    for want in [
        "ir.json",
        "single-camera file",
        "needs both cameras",
        "kfuse calibrate --ir",
        "kfuse rig import",
    ] {
        assert!(line.contains(want), "'{want}' missing: {line}");
    }
    assert!(!out.exists());
    let _ = std::fs::remove_dir_all(&case.dir);
}

#[test]
fn bad_depth_scales_give_one_line() {
    let case = small_case("lab-scale");
    let out = case.dir.join("out");
    for v in ["NaN", "inf", "-inf", "0", "-1", "1e40", "2"] {
        let o = kfuse(&[
            "fuse",
            "--rig",
            s(&case.rig),
            "--color",
            s(&case.color),
            "--depth",
            s(&case.depth),
            "--out",
            s(&out),
            "--depth-scale",
            v,
        ]);
        let line = one_error_line(&o);
        assert!(
            line.contains("--depth-scale") && line.contains("0.001 for millimetres"),
            "{v}: {line}"
        );
        assert!(!out.exists());
    }
    let _ = std::fs::remove_dir_all(&case.dir);
}

/// `fuse` on the small case with `depth` and extra arguments.
fn fuse_small(case: &common::Case, rig: &Path, depth: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "fuse",
        "--rig",
        s(rig),
        "--color",
        s(&case.color),
        "--depth",
        s(depth),
        "--out",
        s(out),
    ];
    args.extend_from_slice(extra);
    args.push("--no-figures");
    kfuse(&args)
}

#[test]
fn unit_and_emptiness_mistakes_fail_naming_the_mistake_and_force_overrides() {
    // The small case: depth 1.50-2.13 m in millimetres, colour camera 5 cm to the side.
    let case = small_case("lab-units");
    let out = case.dir.join("out");
    let good = fuse_small(&case, &case.rig, &case.depth, &out, &[]);
    assert!(good.status.success(), "{}", stderr(&good));
    std::fs::remove_dir_all(&out).unwrap();

    // --depth-scale 1 on millimetre depth: a median of ~1 800 "m".
    let o = fuse_small(&case, &case.rig, &case.depth, &out, &["--depth-scale", "1"]);
    let line = one_error_line(&o);
    assert!(line.contains("depth.png") && line.contains("median depth 1 8"), "{line}");
    assert!(line.contains("is --depth-scale 1 on millimetre depth? use 0.001"), "{line}");
    assert!(!out.exists());

    // Micrometres: a median of ~2 mm.
    let o = fuse_small(&case, &case.rig, &case.depth, &out, &["--depth-scale", "0.000001"]);
    let line = one_error_line(&o);
    assert!(line.contains("under 0.2 m") && line.contains("use 0.001"), "{line}");
    assert!(!out.exists());

    // A float TIFF holding millimetres (float depth must be metres).
    let mm_tif = case.dir.join("depth_mm.tif");
    images::write_depth_tiff(&mm_tif, &Image::from_fn(64, 48, |x, _| 1500.0 + 10.0 * x as f32))
        .unwrap();
    let o = fuse_small(&case, &case.rig, &mm_tif, &out, &[]);
    let line = one_error_line(&o);
    assert!(line.contains("depth_mm.tif") && line.contains("looks like millimetres"), "{line}");
    assert!(!out.exists());

    // Depth saved in whole metres (1 or 2) and read with --depth-scale 1: a plausible median,
    // two depth levels.
    let metres = case.dir.join("depth_m.png");
    images::write_u16_png(&metres, &Image::from_fn(64, 48, |x, _| 1 + (x / 32) as u16)).unwrap();
    let o = fuse_small(&case, &case.rig, &metres, &out, &["--depth-scale", "1"]);
    let line = one_error_line(&o);
    assert!(
        line.contains("depth_m.png")
            && line.contains("depth steps of 1.000 m")
            && line.contains("only 2 distinct depth value(s)")
            && line.contains("whole metres"),
        "{line}"
    );
    assert!(!out.exists());
    // Centimetres (the same ramp, 1.50-2.13 m) fuse as millimetres do.
    let cm = case.dir.join("depth_cm.png");
    images::write_u16_png(&cm, &Image::from_fn(64, 48, |x, _| 150 + x as u16)).unwrap();
    let o = fuse_small(&case, &case.rig, &cm, &out, &["--depth-scale", "0.01"]);
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::remove_dir_all(&out).unwrap();

    // A 16-bit grey image (millimetre depth at the colour camera's size) as --color.
    let grey16 = case.dir.join("color16.png");
    images::write_u16_png(&grey16, &Image::from_fn(96, 72, |x, _| 1500 + x as u16)).unwrap();
    let mut args = vec!["fuse", "--rig", s(&case.rig), "--color", s(&grey16)];
    args.extend(["--depth", s(&case.depth), "--out", s(&out), "--no-figures"]);
    let line = one_error_line(&kfuse(&args));
    assert!(
        line.contains("color16.png")
            && line.contains("is a 16-bit grey image, not a colour picture")
            && line.contains("--force"),
        "{line}"
    );
    assert!(!out.exists());

    // A rig whose colour camera looks 90° away: nothing lands in the colour image.
    let mut away = small_rig();
    away.color_from_depth = RigidTransform::from_axis_angle(
        Vector3::new(0.0, FRAC_PI_2, 0.0),
        away.color_from_depth.translation,
    );
    let away_path = case.dir.join("rig_away.json");
    rigio::write_rig(&away_path, &away).unwrap();
    let o = fuse_small(&case, &away_path, &case.depth, &out, &[]);
    let line = one_error_line(&o);
    assert!(
        line.contains("rig_away.json")
            && line.contains("only 0.00 % of the 3072 depth samples land in the colour image"),
        "{line}"
    );
    assert!(!out.exists());
    // --force fuses anyway, with the reason as a warning; the fusion's own count agrees
    // with the check: no sample in view.
    let o = fuse_small(&case, &away_path, &case.depth, &out, &["--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("warning") && stderr(&o).contains("(--force)"), "{}", stderr(&o));
    assert_eq!(summary(&out)["summary"]["samples_in_view"], 0);
    std::fs::remove_dir_all(&out).unwrap();
    // A rig with T in millimetres passed with --force: the overlap check names the mistake
    // too (read as millimetres, 97 % land: the 5 cm baseline shifts the rest out of view).
    let mut mm = small_rig();
    mm.color_from_depth.translation *= 1000.0;
    let mm_path = case.dir.join("rig_mm.json");
    rigio::write_rig(&mm_path, &mm).unwrap();
    let o = fuse_small(&case, &mm_path, &case.depth, &out, &["--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("land in the colour image")
            && stderr(&o).contains(
                "T looks like millimetres: 50 → 0.05 m? (read as millimetres, 97 % would land)"
            ),
        "{}",
        stderr(&o)
    );
    std::fs::remove_dir_all(&out).unwrap();
    let o = fuse_small(&case, &case.rig, &case.depth, &out, &["--depth-scale", "1", "--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("median depth"), "{}", stderr(&o));
    let _ = std::fs::remove_dir_all(&case.dir);
}

// ---------------------------------------------------------------------------------------
// KinectData.mat

/// The Kinect preset without noise and with both cameras distortion-free (the lab saves
/// rectified images, and KinectData.mat stores no distortion), rendered.
fn rectified_kinect_scene() -> (Rig, SynthFrame) {
    let mut setup = synth::kinect_preset(false);
    setup.rig.depth.distortion = Distortion::NONE;
    setup.rig.color.distortion = Distortion::NONE;
    let frame = synth::render(&setup);
    (setup.rig, frame)
}

fn numeric(dims: Vec<usize>, real: NumericData) -> MatValue {
    MatValue::Numeric(NumericArray { dims, real, imag: None })
}

fn camera_struct(k: &geometry::Intrinsics) -> MatValue {
    MatValue::structure(vec![
        ("fx", MatValue::scalar(k.fx)),
        ("fy", MatValue::scalar(k.fy)),
        ("cx", MatValue::scalar(k.cx)),
        ("cy", MatValue::scalar(k.cy)),
    ])
}

/// Writes a KinectData.mat as the lab's Calibrate.m + capture save it: `Depth` H×W (uint16 mm
/// z, or the given 8-bit picture), `Image` H×W×3 uint8, `Dparam`/`Cparam` fx fy cx cy
/// (0-based), `R`, `T` (mm).
fn write_kinect_data(path: &Path, rig: &Rig, frame: &SynthFrame, depth: MatValue) {
    let (cw, ch) = frame.color.size();
    let rgb: Vec<u8> = frame.color.data().iter().flatten().copied().collect();
    let image =
        numeric(vec![ch, cw, 3], NumericData::UInt8(row_to_column_major(&rgb, &[ch, cw, 3])));
    let r = rig.color_from_depth.rotation.matrix();
    let r_rows: Vec<f64> = (0..3).flat_map(|i| (0..3).map(move |j| r[(i, j)])).collect();
    let t_mm = rig.color_from_depth.translation * 1000.0;
    write_mat(
        path,
        &[
            ("Depth", depth),
            ("Image", image),
            ("Dparam", camera_struct(&rig.depth.intrinsics)),
            ("Cparam", camera_struct(&rig.color.intrinsics)),
            ("R", MatValue::double_matrix(3, 3, &r_rows)),
            ("T", MatValue::double_matrix(3, 1, t_mm.as_slice())),
        ],
    )
    .unwrap();
}

fn uint16_depth(frame: &SynthFrame) -> MatValue {
    let (w, h) = frame.depth.size();
    let mm = depth_mm(frame);
    numeric(vec![h, w], NumericData::UInt16(row_to_column_major(mm.data(), &[h, w])))
}

fn fuse_args(out: &Path, args: &[&str]) -> Output {
    let mut all = vec!["fuse"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--out", s(out), "--no-figures"]);
    kfuse(&all)
}

#[test]
fn fuse_mat_kinect_data_with_real_depth_matches_truth_and_the_separate_files() {
    let dir = scratch("lab-kinectdata");
    let (rig, frame) = rectified_kinect_scene();
    let mat = dir.join("KinectData.mat");
    write_kinect_data(&mat, &rig, &frame, uint16_depth(&frame));

    // `rig import` takes the depth camera's size from the real Depth and says so.
    let o = kfuse(&["rig", "import", s(&mat), "--out", s(&dir.join("kd_rig.json"))]);
    assert!(o.status.success(), "{}", stderr(&o));
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("depth camera 512x424 (the size of its 'Depth')"), "{said}");

    let from_mat = dir.join("from_mat");
    let o = fuse_args(&from_mat, &["--mat", s(&mat)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let sm = summary(&from_mat);
    assert_eq!(sm["summary"]["depth_kind"], "z");
    let valid = frame.depth.data().iter().filter(|d| d.is_finite()).count();
    assert_eq!(sm["summary"]["points"], valid as u64, "one point per valid depth pixel");
    // Against truth: the mm rounding (±0.5 mm) and the nearest sample's offset on the tilted
    // wall (~1.2 mm per colour pixel) give a median under 2 mm; the rest is at edges.
    let (median, within, n) = zbuffer_vs_truth(&from_mat, &frame);
    eprintln!(
        "KinectData.mat: z-buffer vs truth median {:.2} mm, {:.2} % within 10 mm of {n}",
        median * 1e3,
        within * 1e2
    );
    // Measured: median 0.33 mm, 99.0 % within 10 mm, 188 157 pixels (one per depth sample
    // in view, the rest of the 1080p grid is between samples).
    assert!(median < 0.002 && within > 0.97 && n > 150_000, "{median} {within} {n}");

    // The same scene as the separate files of `fuse --rig`: a rig with T = T_mm · 1e-3 (the
    // importer's arithmetic), a colour PNG and a 16-bit mm depth PNG.
    let mut file_rig = rig.clone();
    file_rig.color_from_depth.translation = (rig.color_from_depth.translation * 1000.0) * 1e-3;
    let rig_path = dir.join("rig.json");
    rigio::write_rig(&rig_path, &file_rig).unwrap();
    let color = dir.join("color.png");
    images::write_color_png(&color, &frame.color).unwrap();
    let depth = dir.join("depth.png");
    images::write_u16_png(&depth, &depth_mm(&frame)).unwrap();
    let from_files = dir.join("from_files");
    let o = fuse_args(
        &from_files,
        &["--rig", s(&rig_path), "--color", s(&color), "--depth", s(&depth)],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let sf = summary(&from_files);
    for key in ["points", "samples_in_view", "zbuffer_pixels", "hole_pixels", "faces_after"] {
        assert_eq!(sm["summary"][key], sf["summary"][key], "{key}");
    }
    for name in ["depth_zbuffer.exr", "depth_filled.exr"] {
        let (a, b) = (read_exr(&from_mat.join(name)), read_exr(&from_files.join(name)));
        assert!(
            a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
            "{name} differs between --mat and the separate files"
        );
    }

    // A KinectData.mat with the broken 8-bit Depth of the shared copy: refused with the
    // reason; with the handout's Colour_rect.tif / Depth_rect.tif it fuses like the real one.
    let (w, h) = frame.depth.size();
    let picture: Vec<u8> = frame
        .depth
        .data()
        .iter()
        .map(|d| if d.is_finite() { (d * 50.0).min(255.0) as u8 } else { 0 })
        .collect();
    let broken = dir.join("KinectData_8bit.mat");
    write_kinect_data(
        &broken,
        &rig,
        &frame,
        numeric(vec![h, w], NumericData::UInt8(row_to_column_major(&picture, &[h, w]))),
    );
    let out = dir.join("broken");
    let line = one_error_line(&fuse_args(&out, &["--mat", s(&broken)]));
    assert!(
        line.contains("KinectData_8bit.mat") && line.contains("uint8") && line.contains("--depth"),
        "{line}"
    );
    assert!(!out.exists());
    let colour_tif = dir.join("Colour_rect.tif");
    write_raster(&colour_tif, &Raster::Rgb8(frame.color.clone()), RasterFormat::Tiff).unwrap();
    let depth_tif = dir.join("Depth_rect.tif");
    write_raster(&depth_tif, &Raster::Gray16(depth_mm(&frame)), RasterFormat::Tiff).unwrap();
    let o = fuse_args(
        &out,
        &["--mat", s(&broken), "--color", s(&colour_tif), "--depth", s(&depth_tif)],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    for name in ["depth_zbuffer.exr", "depth_filled.exr"] {
        let (a, b) = (read_exr(&from_mat.join(name)), read_exr(&out.join(name)));
        assert!(
            a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
            "{name}: --color/--depth did not replace the file's images"
        );
    }
    // An override of the wrong size names the file and the size.
    let small = dir.join("small.png");
    images::write_u16_png(&small, &Image::filled(64, 48, 1500u16)).unwrap();
    let out2 = dir.join("wrong");
    let line = one_error_line(&fuse_args(&out2, &["--mat", s(&mat), "--depth", s(&small)]));
    assert!(line.contains("small.png") && line.contains("512x424"), "{line}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_shared_lab_files_are_told_apart_and_the_8_bit_depth_refused() {
    let Some(data) = shared_data("the_shared_lab_files_are_told_apart_and_the_8_bit_depth_refused")
    else {
        return;
    };
    let dir = scratch("lab-shared-kd");
    let out = dir.join("out");
    let mat = data.join("kinect-lab/KinectData.mat");
    let line = one_error_line(&fuse_args(&out, &["--mat", s(&mat)]));
    assert!(
        line.contains("KinectData.mat") && line.contains("uint8") && line.contains("8-bit picture"),
        "{line}"
    );
    assert!(!out.exists());
    // synthdata.mat's Dparam has fx (in metres) beside fp: it is still read as the course
    // file, by `fuse --mat` and by `rig import` (focal length fp = f / pixelsize = 426.7 px).
    let course = data.join("course/synthdata.mat");
    let o = fuse_args(&dir.join("course"), &["--mat", s(&course)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rig = dir.join("course_rig.json");
    // (--force: the course's synthetic rig has a 1 m baseline by design.)
    let o = kfuse(&["rig", "import", s(&course), "--out", s(&rig), "--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rig = rigio::read_rig(&rig).unwrap().into_pair(&rig).unwrap();
    assert!(
        (rig.depth.intrinsics.fx - 0.024 / 5.625e-5).abs() < 1e-9,
        "{}",
        rig.depth.intrinsics.fx
    );
    let _ = std::fs::remove_dir_all(&dir);
}

// ---------------------------------------------------------------------------------------
// --rectified

fn plane_rms(out: &Path) -> f64 {
    summary(out)["summary"]["plane"]["rms_m"].as_f64().expect("a plane was fitted")
}

#[test]
fn rectified_images_fuse_like_the_raw_ones_only_with_rectified() {
    let dir = scratch("lab-rectified");
    let demo = dir.join("demo");
    let o = kfuse(&["demo", "--out", s(&demo), "--no-figures"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let input = demo.join("input");
    let rig = input.join("rig.json");
    let raw = plane_rms(&demo.join("fused"));
    for (camera, image, rect) in
        [("color", "color.png", "rect_c"), ("depth", "depth.png", "rect_d")]
    {
        let o = kfuse(&[
            "undistort",
            "--rig",
            s(&rig),
            "--camera",
            camera,
            s(&input.join(image)),
            "--out",
            s(&dir.join(rect)),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let color = dir.join("rect_c/color_rect.png");
    let depth = dir.join("rect_d/depth_rect.png");
    let fuse = |rig: &Path, out: &str, extra: &[&str]| {
        let out = dir.join(out);
        let mut args = vec!["--rig", s(rig), "--color", s(&color), "--depth", s(&depth)];
        args.extend_from_slice(extra);
        let o = fuse_args(&out, &args);
        assert!(o.status.success(), "{}", stderr(&o));
        plane_rms(&out)
    };
    let rectified = fuse(&rig, "rectified", &["--rectified"]);
    // Without --rectified, undistort's outputs are refused (they would be undistorted twice);
    // --force fuses them anyway, for the comparison below.
    let args = ["--rig", s(&rig), "--color", s(&color), "--depth", s(&depth)];
    let o = fuse_args(&dir.join("refused"), &args);
    let line = one_error_line(&o);
    assert!(
        line.contains("color_rect.png: was written by kfuse undistort")
            && line.contains("--rectified"),
        "{line}"
    );
    let twice = fuse(&rig, "twice", &["--force"]);
    // The rig file's field says the same as the flag.
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&rig).unwrap()).unwrap();
    v["rectified"] = serde_json::json!(true);
    let rect_rig = dir.join("rig_rect.json");
    std::fs::write(&rect_rig, v.to_string()).unwrap();
    let by_field = fuse(&rect_rig, "field", &[]);
    eprintln!(
        "wall plane RMS: raw {:.3} mm, undistort + --rectified {:.3} mm, rectified images distorted again {:.3} mm",
        raw * 1e3,
        rectified * 1e3,
        twice * 1e3
    );
    assert_eq!(rectified, by_field, "the rig's 'rectified' field differs from --rectified");
    // Undistorting the depth by nearest neighbour moves each sample by up to half a pixel
    // (σ = 1/√12 px = 2.4 mm at 3 m); on the wall, tilted by 0.43 in depth per unit across,
    // that adds ~1 mm RMS in quadrature to the raw 1.73 mm: √(1.73² + 1.0²) = 2.0 mm
    // (measured 1.95). So the rectified fusion may be up to 25 % rougher, never better by
    // more than the fit's noise.
    assert!(rectified > 0.95 * raw && rectified < 1.25 * raw, "raw {raw}, rectified {rectified}");
    // Distorted a second time the wall bends: the bug this flag fixes (measured 1.73 → 3.06 mm
    // on the raw-vs-twice pair, 1.57× the rectified fusion's error).
    assert!(twice > 1.35 * rectified, "twice {twice}, rectified {rectified}");
    let _ = std::fs::remove_dir_all(&dir);
}

// ---------------------------------------------------------------------------------------
// undistort keeps the format

/// A rig with the small case's sizes and the given distortion on both cameras.
fn undistort_rig(dir: &Path, name: &str, dist: Distortion) -> PathBuf {
    let mut rig = small_rig();
    rig.depth.distortion = dist;
    rig.color.distortion = dist;
    let path = dir.join(name);
    rigio::write_rig(&path, &rig).unwrap();
    path
}

fn undistort(rig: &Path, camera: &str, images: &[&str], out: &Path) -> Output {
    let mut args = vec!["undistort", "--rig", s(rig), "--camera", camera];
    args.extend_from_slice(images);
    args.extend_from_slice(&["--out", s(out)]);
    kfuse(&args)
}

#[test]
fn undistort_keeps_format_pixel_type_and_values() {
    let dir = scratch("lab-undistort");
    let inputs = dir.join("in");
    std::fs::create_dir_all(&inputs).unwrap();
    let (w, h) = (64, 48);
    let depth_cases = [
        (
            "Ir.png",
            Raster::Gray8(Image::from_fn(w, h, |x, y| (x * 3 + y) as u8)),
            RasterFormat::Png,
        ),
        (
            "Ir.bmp",
            Raster::Gray8(Image::from_fn(w, h, |x, y| (x + 2 * y) as u8)),
            RasterFormat::Bmp,
        ),
        ("Ir8.tif", Raster::Gray8(Image::from_fn(w, h, |x, y| (x * y) as u8)), RasterFormat::Tiff),
        (
            "Depth.png",
            Raster::Gray16(Image::from_fn(w, h, |x, y| 1000 + (x * 97 + y) as u16)),
            RasterFormat::Png,
        ),
        (
            "Depth.tif",
            Raster::Gray16(Image::from_fn(w, h, |x, y| {
                if x == 3 { 0 } else { 60_000 - (x * 7 + y) as u16 }
            })),
            RasterFormat::Tiff,
        ),
        (
            "Depth_m.tif",
            Raster::GrayF32(Image::from_fn(w, h, |x, y| {
                if y == 5 { f32::NAN } else { 1.25 + 0.001 * (x + y) as f32 }
            })),
            RasterFormat::Tiff,
        ),
    ];
    let (cw, ch) = (96, 72);
    let color_cases = [
        (
            "Colour.tif",
            Raster::Rgb8(Image::from_fn(cw, ch, |x, y| [x as u8, y as u8, 7])),
            RasterFormat::Tiff,
        ),
        (
            "Colour.png",
            Raster::Rgba8(Image::from_fn(cw, ch, |x, y| [x as u8, y as u8, 7, 200])),
            RasterFormat::Png,
        ),
    ];
    for (name, r, f) in depth_cases.iter().chain(&color_cases) {
        write_raster(&inputs.join(name), r, *f).unwrap();
    }
    // Without distortion the map is the identity: every pixel comes back with its value and
    // type, in its format, named like the handout (Colour.tif → Colour_rect.tif). The depth
    // images go in as a quoted glob (expanded by kfuse), the colour ones expanded by the shell.
    let plain = undistort_rig(&dir, "plain.json", Distortion::NONE);
    let out_d = dir.join("out_d");
    let pattern = format!("{}/[ID]*", inputs.display());
    let o = undistort(&plain, "depth", &[&pattern], &out_d);
    assert!(o.status.success(), "{}", stderr(&o));
    let out_c = dir.join("out_c");
    let colour: Vec<String> =
        color_cases.iter().map(|(n, _, _)| inputs.join(n).display().to_string()).collect();
    let colour: Vec<&str> = colour.iter().map(String::as_str).collect();
    let o = undistort(&plain, "color", &colour, &out_c);
    assert!(o.status.success(), "{}", stderr(&o));
    let rect_name = |n: &str| {
        let (stem, ext) = n.rsplit_once('.').unwrap();
        format!("{stem}_rect.{ext}")
    };
    for (name, r, f) in &depth_cases {
        let (back, bf) = read_raster(&out_d.join(rect_name(name))).unwrap();
        assert_eq!(bf, *f, "{name}: format");
        match (r, &back) {
            (Raster::GrayF32(a), Raster::GrayF32(b)) => assert!(
                a.data().iter().zip(b.data()).all(|(x, y)| x.to_bits() == y.to_bits()),
                "{name}: float values changed"
            ),
            _ => assert_eq!(&back, r, "{name}: pixel type or values changed"),
        }
    }
    for (name, r, f) in &color_cases {
        let (back, bf) = read_raster(&out_c.join(rect_name(name))).unwrap();
        assert_eq!((&back, bf), (r, *f), "{name}");
    }

    // With distortion, 16-bit and float depth are resampled by nearest neighbour: every
    // output value is an input value (or the masked 0 / NaN), never a blend.
    let lens = undistort_rig(
        &dir,
        "lens.json",
        Distortion { k1: -0.2, k2: 0.05, p1: 0.001, p2: 0.0, k3: 0.0 },
    );
    let out_l = dir.join("out_l");
    let o = undistort(&lens, "depth", &[&format!("{}/Depth*", inputs.display())], &out_l);
    assert!(o.status.success(), "{}", stderr(&o));
    for (name, r, _) in depth_cases.iter().filter(|c| c.0.starts_with("Depth")) {
        let (back, _) = read_raster(&out_l.join(rect_name(name))).unwrap();
        match (r, &back) {
            (Raster::Gray16(a), Raster::Gray16(b)) => {
                assert!(b.data().iter().all(|v| *v == 0 || a.data().contains(v)), "{name}");
                assert!(b.data() != a.data(), "{name}: the lens changed nothing");
            }
            (Raster::GrayF32(a), Raster::GrayF32(b)) => assert!(
                b.data()
                    .iter()
                    .all(|v| v.is_nan() || a.data().iter().any(|x| x.to_bits() == v.to_bits())),
                "{name}"
            ),
            _ => panic!("{name}: type changed to {}", back.kind()),
        }
    }

    // A pattern that matches nothing is one clear line.
    let none = format!("{}/nothing_*.png", inputs.display());
    let line = one_error_line(&undistort(&plain, "depth", &[&none], &dir.join("out_n")));
    assert!(line.contains("nothing_*.png") && line.contains("no file matches"), "{line}");
    let _ = std::fs::remove_dir_all(&dir);
}
