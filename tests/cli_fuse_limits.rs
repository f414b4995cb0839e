//! `kfuse fuse` refuses, at once and in one line, the inputs that made its fusion stages hang
//! or abort (issue 12): a `--hole-radius` whose coverage disc is too large for the rig, and a
//! rig whose depth focal length is not in pixels. Inputs are written with `image` and
//! `Rig::to_json` only.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use geometry::{CameraModel, Distortion, Intrinsics, Rig, RigidTransform};
use nalgebra::{Rotation3, Vector3};

fn kfuse(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kfuse")).args(args).output().expect("run kfuse")
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kfuse-limits-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A 64x48 depth camera (focal length `depth_f`) and a 96x72 colour camera: with 60 px the
/// sample spacing is 1.5 colour px.
fn write_case(dir: &Path, depth_f: f64) -> [PathBuf; 3] {
    let depth =
        CameraModel::new(64, 48, Intrinsics::new(depth_f, depth_f, 31.5, 23.5), Distortion::NONE);
    let color = CameraModel::new(96, 72, Intrinsics::new(90.0, 90.0, 47.5, 35.5), Distortion::NONE);
    let rig = Rig::new(
        depth,
        color,
        RigidTransform::new(Rotation3::identity(), Vector3::new(-0.05, 0.0, 0.0)),
    );
    let rig_path = dir.join("rig.json");
    std::fs::write(&rig_path, rig.to_json()).unwrap();
    let color_path = dir.join("color.png");
    image::RgbImage::from_fn(96, 72, |x, y| image::Rgb([x as u8, y as u8, 100]))
        .save(&color_path)
        .unwrap();
    let depth_path = dir.join("depth.png");
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(64, 48, |x, _| {
        image::Luma([1500 + 10 * x as u16])
    })
    .save(&depth_path)
    .unwrap();
    [rig_path, color_path, depth_path]
}

fn fuse(files: &[PathBuf; 3], out: &Path, extra: &[&str]) -> Output {
    let [rig, color, depth] = files;
    let mut args = vec![
        "fuse",
        "--rig",
        rig.to_str().unwrap(),
        "--color",
        color.to_str().unwrap(),
        "--depth",
        depth.to_str().unwrap(),
        "--resample",
        "nearest",
        "--no-figures",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    kfuse(&args)
}

/// Failure, one `error:` line containing every one of `needles`, and no output folder.
fn assert_refused(o: &Output, out: &Path, needles: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "expected failure, got success: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    for n in needles {
        assert!(lines[0].contains(n), "error does not say '{n}': {err}");
    }
    assert!(!out.exists(), "output folder left behind");
}

#[test]
fn hole_radius_beyond_the_rig_limit_is_refused_and_the_limit_itself_fuses() {
    let dir = scratch("hole");
    let files = write_case(&dir, 60.0);
    let out = dir.join("out");
    for factor in ["30", "1e9"] {
        let o = fuse(&files, &out, &["--hole-radius", factor]);
        // 16 px: geometry::fusion::MAX_COVERAGE_RADIUS_PX; 10.67 = 16 / the rig's 1.5 px spacing.
        assert_refused(&o, &out, &["--hole-radius", "16 px", "at most 10.67"]);
    }
    // 16 px / 1.5 px: the largest factor this rig allows still fuses.
    let o = fuse(&files, &out, &["--hole-radius", "10.666666"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let r = summary["summary"]["coverage_radius_px"].as_f64().unwrap();
    // 10.666666 × 1.5 = 15.999999: 1e-4 covers the factor's 6 printed decimals.
    assert!((r - 16.0).abs() < 1e-4, "{r}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn depth_focal_length_not_in_pixels_is_refused_naming_the_rig() {
    let dir = scratch("focal");
    let out = dir.join("out");
    for f in [3.65, 0.00365] {
        let files = write_case(&dir, f);
        let o = fuse(&files, &out, &[]);
        assert_refused(&o, &out, &["rig.json", "in pixels"]);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
