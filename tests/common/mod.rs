//! Helpers shared by the end-to-end tests of the `kfuse` binary: running it, scratch folders,
//! and a small rig with matching input images.
#![allow(dead_code)] // each test binary uses a different subset

use std::path::PathBuf;
use std::process::{Command, Output};

use geometry::{CameraModel, Distortion, Image, Intrinsics, Rig, RigidTransform};
use kfuse_io::{images, rig as rigio};
use nalgebra::Vector3;

/// The repository (the `kfuse` package's folder) from the `CARGO_MANIFEST_DIR` cargo sets when it
/// runs the test, not the path compiled in: a test binary reused from a checkout at another path
/// (a shared target directory) must read this checkout's files.
pub fn repo_dir() -> PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map(PathBuf::from).expect("run by cargo test")
}

/// Runs the built binary with `args` and waits for it.
pub fn kfuse(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kfuse")).args(args).output().expect("run kfuse")
}

/// The built binary as a `Command`, for tests that set more than its arguments.
pub fn kfuse_command() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kfuse"))
}

/// Asserts that a run succeeded and returns its stderr (where kfuse reports).
pub fn stderr_of_success(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    err
}

/// A fresh, empty folder under the temp dir, unique per test name and process. A run keeps its
/// folders (to look at after a failure); the first call of a later run removes those of test
/// processes that have ended ([`clear_finished_runs`]).
pub fn scratch(name: &str) -> PathBuf {
    clear_finished_runs();
    let dir = std::env::temp_dir().join(format!("{SCRATCH_PREFIX}{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The start of every [`scratch`] folder's name; the process id ends it.
const SCRATCH_PREFIX: &str = "kfuse-e2e-";

/// Removes, once per process, the [`scratch`] folders whose process has ended (on Linux, where
/// `/proc/PID` says whether a process runs). Without it every run left its folders behind: 634
/// of them, 18 GB, had piled up in /tmp on the development machine (a live test's recordings
/// are 0.7 GB each).
fn clear_finished_runs() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        if !std::path::Path::new("/proc/self").exists() {
            return;
        }
        let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else { return };
        for entry in entries.flatten() {
            let name = entry.file_name();
            let Some(rest) = name.to_str().and_then(|n| n.strip_prefix(SCRATCH_PREFIX)) else {
                continue;
            };
            let Some(pid) = rest.rsplit('-').next().and_then(|p| p.parse::<u32>().ok()) else {
                continue;
            };
            if pid != std::process::id() && !std::path::Path::new(&format!("/proc/{pid}")).exists()
            {
                let _ = std::fs::remove_dir_all(entry.path());
            }
        }
    });
}

/// A small rig: 64x48 depth camera, 96x72 colour camera 5 cm to the side.
pub fn small_rig() -> Rig {
    let depth = CameraModel::new(64, 48, Intrinsics::new(60.0, 60.0, 31.5, 23.5), Distortion::NONE);
    let color = CameraModel::new(96, 72, Intrinsics::new(90.0, 90.0, 47.5, 35.5), Distortion::NONE);
    Rig::new(
        depth,
        color,
        RigidTransform::new(nalgebra::Rotation3::identity(), Vector3::new(-0.05, 0.0, 0.0)),
    )
}

/// The files of [`small_case`]: the rig and one colour and depth image in `dir`.
pub struct Case {
    pub dir: PathBuf,
    pub rig: PathBuf,
    pub color: PathBuf,
    pub depth: PathBuf,
}

/// Writes [`small_rig`] with a colour gradient and a tilted depth ramp (1.5 m + 1 cm per column)
/// into a fresh scratch folder.
pub fn small_case(name: &str) -> Case {
    let dir = scratch(name);
    let rig = dir.join("rig.json");
    rigio::write_rig(&rig, &small_rig()).unwrap();
    let color = dir.join("color.png");
    images::write_color_png(&color, &Image::from_fn(96, 72, |x, y| [x as u8, y as u8, 100]))
        .unwrap();
    let depth = dir.join("depth.png");
    images::write_depth_png16(&depth, &Image::from_fn(64, 48, |x, _| 1.5 + 0.01 * x as f32))
        .unwrap();
    Case { dir, rig, color, depth }
}

/// The sensor's factory parameters from a `kinect_params.json` (what `kfuse capture` writes
/// beside its shots), read field by field with serde_json: independent of the simulator's and
/// of `rig import`'s own readers, so tests can hold those against it.
pub fn kinect_params_of(
    v: &serde_json::Value,
) -> (kinect_usb::params::DepthParams, kinect_usb::params::ColorParams) {
    let f = |o: &str, k: &str| v[o][k].as_f64().unwrap() as f32;
    let arr = |k: &str| -> [f32; 10] {
        std::array::from_fn(|i| v["color"][k][i].as_f64().unwrap() as f32)
    };
    (
        kinect_usb::params::DepthParams {
            fx: f("depth", "fx"),
            fy: f("depth", "fy"),
            cx: f("depth", "cx"),
            cy: f("depth", "cy"),
            k1: f("depth", "k1"),
            k2: f("depth", "k2"),
            k3: f("depth", "k3"),
            p1: f("depth", "p1"),
            p2: f("depth", "p2"),
        },
        kinect_usb::params::ColorParams {
            f: f("color", "fx"),
            cx: f("color", "cx"),
            cy: f("color", "cy"),
            shift_d: f("color", "shift_d"),
            shift_m: f("color", "shift_m"),
            mx: arr("mx"),
            my: arr("my"),
        },
    )
}

/// The `summary.json` a `kfuse fuse` run wrote into `dir`.
pub fn summary(dir: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
}

/// The first channel of an OpenEXR file (`kfuse fuse`'s `depth_*.exr`: metres, NaN = none).
pub fn read_exr(path: &std::path::Path) -> Vec<f32> {
    let img = exr::prelude::read_first_flat_layer_from_file(path).unwrap();
    let ch = &img.layer_data.channel_data.list[0];
    (0..ch.sample_data.len()).map(|i| ch.sample_data.value_by_flat_index(i).to_f32()).collect()
}

/// A synthetic frame's depth as the 16-bit millimetres of a depth file.
pub fn depth_mm(frame: &geometry::synth::SynthFrame) -> Image<u16> {
    let (w, h) = frame.depth.size();
    Image::from_vec(w, h, images::depth_to_mm(&frame.depth)).unwrap()
}

/// The fused z-buffer (`depth_zbuffer.exr` in `out`) against the scene's true colour-frame
/// depth: (median |error|, fraction of compared pixels within 10 mm, compared pixels).
pub fn zbuffer_vs_truth(
    out: &std::path::Path,
    frame: &geometry::synth::SynthFrame,
) -> (f64, f64, usize) {
    let z = read_exr(&out.join("depth_zbuffer.exr"));
    let mut errors: Vec<f64> = z
        .iter()
        .zip(frame.true_color_depth.data())
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(a, b)| (a - b).abs() as f64)
        .collect();
    errors.sort_by(f64::total_cmp);
    let n = errors.len();
    let within = errors.iter().filter(|&&e| e <= 0.010).count();
    (errors[n / 2], within as f64 / n as f64, n)
}

/// Every parameter of a camera: size, intrinsics (pixels), distortion coefficients.
pub fn cam_values(c: &CameraModel) -> Vec<f64> {
    let k = c.intrinsics;
    let mut v = vec![c.width as f64, c.height as f64, k.fx, k.fy, k.cx, k.cy, k.skew];
    v.extend(c.distortion.to_array());
    v
}

/// Largest absolute difference over every parameter of two rigs (pixels, unitless
/// coefficients, rotation matrix entries, metres).
pub fn rig_diff(a: &Rig, b: &Rig) -> f64 {
    let mut d = 0f64;
    for (x, y) in cam_values(&a.depth).iter().zip(cam_values(&b.depth)) {
        d = d.max((x - y).abs());
    }
    for (x, y) in cam_values(&a.color).iter().zip(cam_values(&b.color)) {
        d = d.max((x - y).abs());
    }
    let r =
        (a.color_from_depth.rotation.matrix() - b.color_from_depth.rotation.matrix()).abs().max();
    let t = (a.color_from_depth.translation - b.color_from_depth.translation).abs().max();
    d.max(r).max(t)
}

/// Sensors of the simulated ring that [`ring_calibration_capture`] captures.
pub const RING_SENSORS: usize = 3;

/// Prefix of the shared ring captures' folders in cargo's `CARGO_TARGET_TMPDIR`.
const RING_CAPTURE_PREFIX: &str = "ring-calibration-capture-";

/// The folder `kfuse capture calib --backend sim --sim-sensors 3 --device all --count COUNT
/// --interval 0` wrote, for every board pose of the simulated ring (`COUNT` =
/// `kinect_usb::sim::ring::board_poses(3).len()`), made once per build of the binary and shared
/// by the test files that read it (`cli_capture_multi` checks the capture, `cli_calibrate_multi`
/// calibrates from it): rendering and capturing its 270 frames is the slowest step of the
/// suite (80 s on 2 cores), and was done once by each of them.
///
/// It lives in cargo's `CARGO_TARGET_TMPDIR`, in a folder named after the binary's size and
/// modification time, so a rebuilt binary captures anew (older captures are removed then). The
/// capture is written into a staging folder and renamed when it succeeded, so a test never reads
/// a half-written one; a process that loses the rename to another uses the other's. Panics with
/// the binary's stderr when the capture fails.
pub fn ring_calibration_capture() -> &'static std::path::Path {
    static DIR: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        let bin = std::path::Path::new(env!("CARGO_BIN_EXE_kfuse"));
        let meta = std::fs::metadata(bin).expect("the kfuse binary");
        let modified = meta
            .modified()
            .ok()
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .map_or(0, |d| d.as_nanos());
        let name = format!("{RING_CAPTURE_PREFIX}{}-{modified}", meta.len());
        let root = PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
        let done = root.join(&name);
        if done.join("index.json").is_file() {
            return done;
        }
        std::fs::create_dir_all(&root).unwrap();
        // Captures of earlier builds: no test reads them again.
        for entry in std::fs::read_dir(&root).unwrap().flatten() {
            let n = entry.file_name().to_string_lossy().into_owned();
            if n.starts_with(RING_CAPTURE_PREFIX) && !n.starts_with(&name) {
                let _ = std::fs::remove_dir_all(entry.path());
            }
        }
        let staging = root.join(format!("{name}.staging-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&staging);
        let count = kinect_usb::sim::ring::board_poses(RING_SENSORS).len();
        let out = kfuse_command()
            .args(["capture", "calib", "--backend", "sim", "--sim-sensors"])
            .arg(RING_SENSORS.to_string())
            .args(["--device", "all", "--count", &count.to_string(), "--interval", "0", "--out"])
            .arg(&staging)
            .output()
            .expect("run kfuse capture");
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        if std::fs::rename(&staging, &done).is_err() {
            // Another process finished first: its capture is the same binary's.
            let _ = std::fs::remove_dir_all(&staging);
            assert!(done.join("index.json").is_file(), "no ring capture at {}", done.display());
        }
        done
    })
}
