//! `kfuse calibrate --shots DIR` / `--camera NAME=GLOB`: the joint calibration of a simulated
//! ring of three Kinects (six cameras, issue 32) from the folder `kfuse capture calib --device
//! all` writes, against the ring's true rig (`true_rig.json`, written by the simulator from
//! its own poses and factory parameters, not by the calibration); and the inputs a joint
//! calibration refuses, each with one line and nothing written.

mod common;

use std::path::Path;
use std::process::Command;

use kinect_usb::sim::ring::OWN_POSES;
use serde_json::Value;

const SERIALS: [&str; 3] = ["000000000001", "000000000002", "000000000003"];

/// Bound on each camera centre's error, in σ of the calibration's own first-order σ (per
/// axis): 3σ, the usual bar for an honest uncertainty.
const MAX_SIGMAS: f64 = 3.0;
/// Bound on each camera centre's error, mm: issue 32's 1 mm. The ring shares twenty board
/// poses per neighbouring pair (`SHARED_POSES`: sideways, near and far, tilted), 10–65° off
/// each camera's axis at 1.6–2.6 m; the fit's own σ of a centre between sensors is 1.0–2.1 mm
/// per axis (three shared poses left 3–5 mm and 1.99 mm errors). Measured on this capture: at
/// most 0.76 mm (0.45 σ of the centre σ before issue 52 fixed its sign error, which made σ
/// 2.5× too large; the test prints the table). A wrong pose graph is off by decimetres.
const MAX_CENTER_ERROR_MM: f64 = 1.0;
/// Band of the RMS of the centres' errors over their σ (15 values: 5 free cameras × 3 axes),
/// 99 % of a χ² with 6 degrees of freedom, sqrt(0.676/6)..sqrt(18.55/6): a sensor's colour
/// camera moves with its depth camera, so the two free sensors give about 6 independent values,
/// not 15. Measured on this capture: 0.48 (0.19 with the σ that issue 52 found 2.5× too large).
/// The calibration crate's `multi_ring_sigma_matches_the_errors` checks the same over six
/// seeded rings (0.97).
const MIN_RMS_SIGMAS: f64 = 0.336;
/// Upper end of that band.
const MAX_RMS_SIGMAS: f64 = 1.758;
/// Bound on each camera rotation's error, degrees: issue 32's 0.05°; measured at most
/// 0.037°.
const MAX_ROTATION_ERROR_DEG: f64 = 0.05;
/// Bound on the overlap consistency of the scene fused with the *calibrated* rig, mm: issue
/// 32's 2 mm (tests/cli_fuse_multi.rs holds the true rig to the same bar; it gives at most
/// 0.50 mm); measured 0.54 mm for the worst pair (2.03–2.38 mm with three shared poses).
const CALIBRATED_CONSISTENCY_BAR_MM: f64 = 2.0;

fn kfuse() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kfuse"))
}

fn json(p: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

/// One camera's pose in a version-2 rig file, read here without kfuse's reader.
struct Pose {
    r: [[f64; 3]; 3],
    t: [f64; 3],
}

impl Pose {
    fn of(rig: &Value, name: &str) -> Pose {
        let cam = rig["cameras"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["name"] == name)
            .unwrap_or_else(|| panic!("camera {name} in the rig"));
        let p = &cam["camera_from_reference"];
        Pose {
            r: std::array::from_fn(|i| {
                std::array::from_fn(|j| p["rotation"][i][j].as_f64().unwrap())
            }),
            t: std::array::from_fn(|i| p["translation_m"][i].as_f64().unwrap()),
        }
    }

    /// The centre in the reference frame: −Rᵀ·T.
    fn centre(&self) -> [f64; 3] {
        std::array::from_fn(|i| -(0..3).map(|k| self.r[k][i] * self.t[k]).sum::<f64>())
    }

    /// The angle of R_a·R_bᵀ, degrees.
    fn angle_to(&self, b: &Pose) -> f64 {
        let trace: f64 =
            (0..3).map(|i| (0..3).map(|k| self.r[i][k] * b.r[i][k]).sum::<f64>()).sum();
        ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
    }
}

/// The simulated ring's calibration capture, shared with `cli_capture_multi` (made once per
/// build of the binary: `common::ring_calibration_capture`).
fn ring_capture() -> &'static Path {
    common::ring_calibration_capture()
}

/// `--shots DIR`: every camera within 3σ of the truth and within the bars above, the rig a
/// version-2 rig `kfuse fuse --rig` reads, report.json with every camera's σ and corners.
#[test]
fn joint_calibration_of_a_three_kinect_ring_against_its_true_rig() {
    let ring = ring_capture();
    let dir = tempfile::tempdir().unwrap();
    let (rig_path, report) = (dir.path().join("rig.json"), dir.path().join("report"));
    let st = kfuse()
        .args(["calibrate", "--shots"])
        .arg(ring)
        .arg("--out")
        .arg(&rig_path)
        .arg("--report")
        .arg(&report)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&st.stdout);
    assert!(st.status.success(), "{}{text}", String::from_utf8_lossy(&st.stderr));
    assert!(text.contains("joint calibration: reference 000000000001.depth"), "{text}");

    let truth = json(&ring.join("true_rig.json"));
    let fitted = json(&rig_path);
    assert_eq!(fitted["version"], 2);
    assert_eq!(fitted["reference"], truth["reference"]);
    let rep = json(&report.join("report.json"));
    assert_eq!(rep["format"], "kfuse-multi-calibration");
    let cams = rep["cameras"].as_array().unwrap();
    assert_eq!(cams.len(), 6);
    let mut worst = (0.0f64, 0.0f64, 0.0f64);
    // Every non-reference centre error over its σ, per axis: their RMS must be near 1.
    let mut normalised = Vec::new();
    for s in SERIALS {
        for role in ["depth", "color"] {
            let name = format!("{s}.{role}");
            let (got, want) = (Pose::of(&fitted, &name), Pose::of(&truth, &name));
            let (g, w) = (got.centre(), want.centre());
            let entry = cams.iter().find(|c| c["name"] == name.as_str()).unwrap();
            let sd: Vec<f64> =
                (0..3).map(|a| entry["center_std_1sigma_mm"][a].as_f64().unwrap()).collect();
            let err_mm: Vec<f64> = (0..3).map(|a| (g[a] - w[a]) * 1e3).collect();
            let norm = err_mm.iter().map(|e| e * e).sum::<f64>().sqrt();
            // σ = 0 only for the reference (fixed at the identity); elsewhere it would make
            // every error "infinitely many σ" or, skipped, hide a broken uncertainty.
            let sigmas = if name == "000000000001.depth" {
                0.0
            } else {
                assert!(sd.iter().all(|s| *s > 0.0), "{name}: centre σ {sd:?} mm");
                normalised.extend((0..3).map(|a| err_mm[a] / sd[a]));
                (0..3).map(|a| err_mm[a].abs() / sd[a]).fold(0.0, f64::max)
            };
            let rot = got.angle_to(&want);
            eprintln!(
                "{name:<20} centre error {norm:6.2} mm ({:.2}, {:.2}, {:.2}; σ {:.2}, {:.2}, {:.2}; {sigmas:.2} σ), rotation {rot:.3}°",
                err_mm[0], err_mm[1], err_mm[2], sd[0], sd[1], sd[2]
            );
            if name == "000000000001.depth" {
                assert!(norm < 1e-9 && rot < 1e-9, "the reference is the identity");
                continue;
            }
            assert!(sigmas <= MAX_SIGMAS, "{name}: centre error {sigmas:.2} σ");
            assert!(norm <= MAX_CENTER_ERROR_MM, "{name}: centre error {norm:.2} mm");
            assert!(rot <= MAX_ROTATION_ERROR_DEG, "{name}: rotation error {rot:.3}°");
            worst = (worst.0.max(norm), worst.1.max(sigmas), worst.2.max(rot));
        }
    }
    // σ from both sides (issue 52): an inflated σ (2.5× before issue 52's sign fix: RMS 0.19)
    // fails the lower bound, a too small one the upper.
    let rms_sigmas =
        (normalised.iter().map(|v| v * v).sum::<f64>() / normalised.len() as f64).sqrt();
    eprintln!("centre errors over their σ: RMS {rms_sigmas:.2} over {} values", normalised.len());
    assert_eq!(normalised.len(), 15, "five free cameras, three axes each");
    assert!(
        (MIN_RMS_SIGMAS..=MAX_RMS_SIGMAS).contains(&rms_sigmas),
        "centre errors over their σ: RMS {rms_sigmas:.2}, outside [{MIN_RMS_SIGMAS}, {MAX_RMS_SIGMAS}]"
    );
    eprintln!(
        "worst: {:.2} mm, {:.2} σ, {:.3}°; joint RMS {:.3} px",
        worst.0,
        worst.1,
        worst.2,
        rep["rms_px"].as_f64().unwrap()
    );
    // Every camera's corners are in the report, keyed by view id, for other tools.
    let det = &rep["detections"];
    assert_eq!(det["format"], "kfuse-multi-detections");
    // The rig is what fuse reads for several Kinects (version 2, with the calibration kept).
    assert!(fitted["calibration"]["rms_px"].is_number());

    // The README's flow goes on: a scene captured by the same ring and fused with the
    // calibrated rig (not the true one): every overlapping pair of sensors within
    // CALIBRATED_CONSISTENCY_BAR_MM.
    let scene = dir.path().join("scene");
    let st = kfuse()
        .args(["capture", "scene", "--backend", "sim", "--sim-sensors", "3", "--device", "all"])
        .args(["--interval", "0", "--out"])
        .arg(&scene)
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let fused = dir.path().join("fused");
    let st = kfuse()
        .args(["fuse", "--rig"])
        .arg(&rig_path)
        .arg("--frames")
        .arg(&scene)
        .arg("--out")
        .arg(&fused)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&st.stdout);
    assert!(st.status.success(), "{}{text}", String::from_utf8_lossy(&st.stderr));
    let summary = json(&fused.join("summary.json"));
    let pairs = summary["consistency"].as_array().unwrap();
    assert_eq!(pairs.len(), 3);
    for p in pairs {
        eprintln!("with the calibrated rig: consistency {p}");
    }
    let mut overlapping = 0;
    for p in pairs {
        if p["tiles"].as_u64().unwrap() > 0 {
            let mm = p["tile_median_mm"].as_f64().unwrap();
            assert!(mm <= CALIBRATED_CONSISTENCY_BAR_MM, "{p}");
            overlapping += 1;
        }
    }
    assert!(overlapping >= 2, "the ring's sensors overlap: {pairs:?}");
}

/// One camera's own shots only (no board pose shared with the other camera): the covisibility
/// graph is not connected, the error names both groups, and no rig is written.
#[test]
fn cameras_without_a_shared_view_are_one_line_and_nothing_is_written() {
    let ring = ring_capture();
    let dir = tempfile::tempdir().unwrap();
    // Sensor i's own poses are shots k = i, i + 3, ... (0-based) of the first 3·OWN_POSES.
    let mut args = Vec::new();
    for (i, s) in SERIALS.iter().take(2).enumerate() {
        let folder = dir.path().join(s);
        std::fs::create_dir(&folder).unwrap();
        for k in (i..3 * OWN_POSES.len()).step_by(3) {
            let name = format!("ir_{:04}.png", k + 1);
            std::fs::copy(ring.join(s).join(&name), folder.join(&name)).unwrap();
        }
        args.push("--camera".to_string());
        args.push(format!("{s}.depth={}", folder.join("ir_*.png").display()));
    }
    let out = dir.path().join("rig.json");
    let st = kfuse().arg("calibrate").args(&args).arg("--out").arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(!st.status.success());
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("{000000000001.depth} and {000000000002.depth}"), "{err}");
    assert!(!out.exists(), "nothing written");
}

/// The options of a two-camera run, a camera whose name repeats, and an unknown reference:
/// one line each, naming what to do, before any image is read.
#[test]
fn joint_calibration_arguments_are_checked_first() {
    let ring = ring_capture();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rig.json");
    let glob = |s: &str| format!("{}", ring.join(s).join("ir_*.png").display());
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec!["--shots".into(), ring.display().to_string(), "--ir".into(), glob(SERIALS[0])],
            "--ir is an option of the one- and two-camera calibration",
        ),
        (
            vec![
                "--camera".into(),
                format!("a.depth={}", glob(SERIALS[0])),
                "--camera".into(),
                format!("a.depth={}", glob(SERIALS[1])),
            ],
            "a.depth",
        ),
        (
            vec!["--shots".into(), ring.display().to_string(), "--reference".into(), "x".into()],
            "--reference x: not one of the cameras",
        ),
    ];
    for (args, want) in cases {
        let st = kfuse().arg("calibrate").args(&args).arg("--out").arg(&out).output().unwrap();
        let err = String::from_utf8_lossy(&st.stderr);
        assert!(!st.status.success(), "{args:?}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?}: nothing written");
    }
}
