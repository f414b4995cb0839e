//! `kfuse devices` / `kfuse capture --device` with several simulated Kinects (issue 32): a
//! ring of three, its true rig checked against the ring formula and against the images (the
//! board's corners projected with `true_rig.json` fall on the checkerboard the images show,
//! or on its plain back), a sensor lost mid-run, two sensors with the same serial, an unknown
//! serial, and recordings of each sensor.

mod common;

use std::path::Path;
use std::process::Command;

use kinect_usb::sim::calib_scene::{BOARD_INNER_CORNERS, BOARD_SQUARE_M, BoardPose};
use kinect_usb::sim::ring::{OWN_POSES, RING_RADIUS_M, SHARED_POSES, board_poses};
use serde_json::Value;

const SERIALS: [&str; 3] = ["000000000001", "000000000002", "000000000003"];

fn kfuse() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kfuse"))
}

fn json(p: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

/// One camera of a rig file version 2, read here without kfuse's reader.
struct Cam {
    size: [f64; 2],
    k: [f64; 4],
    dist: [f64; 5],
    r: [[f64; 3]; 3],
    t: [f64; 3],
}

impl Cam {
    fn of(v: &Value) -> Cam {
        let f = |k: &str| v[k].as_f64().unwrap();
        let pose = &v["camera_from_reference"];
        Cam {
            size: [f("width"), f("height")],
            k: [f("fx"), f("fy"), f("cx"), f("cy")],
            dist: [f("k1"), f("k2"), f("p1"), f("p2"), f("k3")],
            r: std::array::from_fn(|i| {
                std::array::from_fn(|j| pose["rotation"][i][j].as_f64().unwrap())
            }),
            t: std::array::from_fn(|i| pose["translation_m"][i].as_f64().unwrap()),
        }
    }

    fn to_cam(&self, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|i| (0..3).map(|k| self.r[i][k] * p[k]).sum::<f64>() + self.t[i])
    }

    /// The centre in the reference frame: −Rᵀ·T.
    fn centre(&self) -> [f64; 3] {
        std::array::from_fn(|i| -(0..3).map(|k| self.r[k][i] * self.t[k]).sum::<f64>())
    }

    /// OpenCV's pinhole + Brown–Conrady projection of a reference-frame point.
    fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        let q = self.to_cam(p);
        if q[2] <= 0.0 {
            return None;
        }
        let (x, y) = (q[0] / q[2], q[1] / q[2]);
        let [k1, k2, p1, p2, k3] = self.dist;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        Some([self.k[0] * xd + self.k[2], self.k[1] * yd + self.k[3]])
    }
}

/// A point of board pose `pose` (world frame) in the reference frame (the first sensor's
/// depth camera at `(0, 0, −ρ)` of the world, looking along +z: `X_ref = X_world + (0, 0, ρ)`).
fn board_point(pose: &BoardPose, bx: f64, by: f64) -> [f64; 3] {
    let p = pose.point(bx, by);
    [p[0], p[1], p[2] + RING_RADIUS_M]
}

/// Margin, pixels, a corner must keep from the image border to count as seen: the detector
/// needs the squares around each inner corner (half a square is ≥ 4 colour pixels here).
const SEEN_MARGIN_PX: f64 = 15.0;
/// Contrast between the board's white and black squares at the square centres, grey levels
/// (8-bit colour; IR: relative): the printed side is 235 vs 25 before noise and JPEG; its
/// plain back shows none.
const PATTERN_CONTRAST: f64 = 100.0;
const NO_PATTERN_SPREAD: f64 = 30.0;

/// Whether camera `cam` sees the printed side of `pose` with every inner corner inside its
/// image (the sensor's colour camera centre on the side the board faces).
fn sees(cam: &Cam, pose: &BoardPose) -> bool {
    front_faces(cam, pose)
        && (0..BOARD_INNER_CORNERS.1).all(|j| {
            (0..BOARD_INNER_CORNERS.0).all(|i| {
                let p = board_point(pose, i as f64 * BOARD_SQUARE_M, j as f64 * BOARD_SQUARE_M);
                cam.project(p).is_some_and(|[u, v]| {
                    u > SEEN_MARGIN_PX
                        && v > SEEN_MARGIN_PX
                        && u < cam.size[0] - 1.0 - SEEN_MARGIN_PX
                        && v < cam.size[1] - 1.0 - SEEN_MARGIN_PX
                })
            })
        })
}

/// Whether `cam`'s centre is on the side of the board its printed side faces (the board's
/// −z side: the simulator's poses face their camera with the board's z axis pointing away).
fn front_faces(cam: &Cam, pose: &BoardPose) -> bool {
    let c = cam.centre();
    let n = [pose.r[0][2], pose.r[1][2], pose.r[2][2]];
    let o = board_point(pose, 0.0, 0.0);
    (0..3).map(|i| n[i] * (o[i] - c[i])).sum::<f64>() > 0.0
}

/// The image's values at the centres of the board's inner squares, split into those of black
/// squares (`(i + j)` even, the simulator's colouring) and white ones; `None` where a centre
/// falls outside the image.
fn square_samples(cam: &Cam, pose: &BoardPose, img: &[f64], w: usize) -> Option<[Vec<f64>; 2]> {
    let h = img.len() / w;
    let mut out = [Vec::new(), Vec::new()];
    for j in 0..BOARD_INNER_CORNERS.1 - 1 {
        for i in 0..BOARD_INNER_CORNERS.0 - 1 {
            let s = BOARD_SQUARE_M;
            let [u, v] =
                cam.project(board_point(pose, (i as f64 + 0.5) * s, (j as f64 + 0.5) * s))?;
            let (u, v) = (u.round() as i64, v.round() as i64);
            if u < 0 || v < 0 || u >= w as i64 || v >= h as i64 {
                return None;
            }
            out[usize::from((i + j) % 2 == 1)].push(img[v as usize * w + u as usize]);
        }
    }
    Some(out)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// `--sim-sensors 3 capture calib --device all`: three folders with the same shots, the
/// timestamps paired, a true rig at the ring's poses that maps the board onto the images,
/// and shots seen by some sensors and not by others.
#[test]
fn three_kinect_ring_calibration_capture() {
    let st = kfuse().args(["devices", "--backend", "sim", "--sim-sensors", "3"]).output().unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let out = String::from_utf8_lossy(&st.stdout);
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 3, "{out}");
    for (l, s) in lines.iter().zip(SERIALS) {
        assert!(l.contains(&format!("serial {s}")) && l.contains("sim backend"), "{l}");
    }

    let n_poses = board_poses(3).len();
    assert_eq!(n_poses, 3 * OWN_POSES.len() + 3 * SHARED_POSES.len());
    // `kfuse capture calib --backend sim --sim-sensors 3 --device all --count n_poses`, made
    // once per build of the binary and shared with cli_calibrate_multi (the slowest step of
    // the suite): common::ring_calibration_capture.
    let out = common::ring_calibration_capture();
    let dir = tempfile::tempdir().unwrap();

    // The same shot numbers in every sensor's folder, each with its own parameters.
    let names: Vec<String> = (1..=n_poses).map(|k| format!("{k:04}")).collect();
    for s in SERIALS {
        for n in &names {
            for f in [format!("color_{n}.jpg"), format!("ir_{n}.png"), format!("depth_{n}.png")] {
                assert!(out.join(s).join(&f).exists(), "{s}/{f}");
            }
        }
        assert_eq!(json(&out.join(s).join("kinect_params.json"))["serial"], s);
    }
    // Paired: every shot has each sensor, at the same time since its first shot (the ring's
    // sensors have different clocks), one frame period (267 ticks) per shot.
    let index = json(&out.join("index.json"));
    assert_eq!(index["format"], "kfuse-multi-capture");
    let shots = index["shots"].as_array().unwrap();
    assert_eq!(shots.len(), n_poses);
    for (k, shot) in shots.iter().enumerate() {
        assert_eq!(shot["name"], names[k]);
        for s in SERIALS {
            let ms = shot["sensors"][s]["since_first_shot_ms"].as_f64().unwrap();
            assert!((ms - k as f64 * 267.0 * 0.125).abs() < 1e-9, "shot {k} {s}: {ms} ms");
        }
        assert_eq!(shot["spread_ms"].as_f64(), Some(0.0));
    }
    let origins: Vec<u64> = SERIALS
        .iter()
        .map(|s| shots[0]["sensors"][s]["depth_timestamp"].as_u64().unwrap())
        .collect();
    assert!(origins[0] != origins[1] && origins[1] != origins[2], "{origins:?}");

    // The true rig: the ring formula, written here: sensor i of 3 at
    // (−ρ·sin θ, 0, −ρ·cos θ) of the world (θ = 120°·i), its optical axis through the centre,
    // turned about y only; the reference frame is the first sensor's depth camera, so the
    // world's origin is at (0, 0, ρ) in it. Its colour camera 52 mm along its depth camera's
    // +x (the scene orientation's rule).
    let rig = json(&out.join("true_rig.json"));
    assert_eq!(rig["version"], 2);
    assert_eq!(rig["reference"], "000000000001.depth");
    let cams = rig["cameras"].as_array().unwrap();
    assert_eq!(cams.len(), 6);
    let cam =
        |name: String| Cam::of(cams.iter().find(|c| c["name"] == name.as_str()).expect(&name));
    for (i, s) in SERIALS.iter().enumerate() {
        let d = cam(format!("{s}.depth"));
        let theta = (120.0 * i as f64).to_radians();
        let want = [-RING_RADIUS_M * theta.sin(), 0.0, RING_RADIUS_M - RING_RADIUS_M * theta.cos()];
        let c = d.centre();
        for a in 0..3 {
            assert!((c[a] - want[a]).abs() < 1e-9, "{s} centre {c:?}, want {want:?}");
        }
        let axis = d.r[2];
        for a in 0..3 {
            let to_centre = ([0.0, 0.0, RING_RADIUS_M][a] - c[a]) / RING_RADIUS_M;
            assert!((axis[a] - to_centre).abs() < 1e-9, "{s} axis {axis:?}");
        }
        assert!((d.r[1][1] - 1.0).abs() < 1e-12, "{s}: not turned about y only");
        let col = cam(format!("{s}.color"));
        let cc = d.to_cam(col.centre());
        assert!((cc[0] - 0.052).abs() < 1e-3 && cc[1].abs() < 1e-9 && cc[2].abs() < 1e-9, "{cc:?}");
        // Each sensor's depth intrinsics are its kinect_params.json's (f32 as printed).
        let p = json(&out.join(s).join("kinect_params.json"));
        for (k, v) in ["fx", "fy", "cx", "cy"].iter().zip(d.k) {
            assert!((p["depth"][k].as_f64().unwrap() - v).abs() < 1e-4, "{s} {k}");
        }
    }
    let fx: Vec<f64> = SERIALS.iter().map(|s| cam(format!("{s}.depth")).k[0]).collect();
    assert!(fx[0] != fx[1] && fx[1] != fx[2] && fx[0] != fx[2], "{fx:?}");

    // Against the images: wherever the rig says a camera sees the board's printed side, its
    // image shows the checkerboard at the projected square centres; where it sees the back,
    // no pattern. Some shots are seen by one sensor and not another.
    let poses = board_poses(3);
    let mut seen_by_some_not_all = 0;
    let mut checked = 0;
    for (k, pose) in poses.iter().enumerate() {
        let mut seen = Vec::new();
        for s in SERIALS {
            let color = cam(format!("{s}.color"));
            let depth = cam(format!("{s}.depth"));
            let img = image::open(out.join(s).join(format!("color_{}.jpg", names[k]))).unwrap();
            let grey: Vec<f64> = img.to_luma8().into_raw().into_iter().map(f64::from).collect();
            let ir = image::open(out.join(s).join(format!("ir_{}.png", names[k]))).unwrap();
            let ir: Vec<f64> = ir.into_luma16().into_raw().into_iter().map(f64::from).collect();
            let is_seen = sees(&color, pose);
            if is_seen {
                let [b, w] = square_samples(&color, pose, &grey, 1920).unwrap();
                assert!(mean(&w) - mean(&b) > PATTERN_CONTRAST, "shot {k} {s}: no board");
                assert!(
                    b.iter().cloned().fold(0.0, f64::max) < w.iter().cloned().fold(255.0, f64::min),
                    "shot {k} {s}: a black square is brighter than a white one"
                );
                // The depth camera (with its distortion): the IR's white squares reflect
                // several times the black ones' light (albedo 0.85 vs 0.10).
                if let Some([b, w]) = square_samples(&depth, pose, &ir, 512) {
                    assert!(
                        mean(&w) > 3.0 * mean(&b),
                        "shot {k} {s}: IR {} {}",
                        mean(&w),
                        mean(&b)
                    );
                }
                checked += 1;
            } else if !front_faces(&color, pose)
                && let Some([b, w]) = square_samples(&color, pose, &grey, 1920)
            {
                let all: Vec<f64> = b.into_iter().chain(w).collect();
                let spread = all.iter().cloned().fold(0.0, f64::max)
                    - all.iter().cloned().fold(255.0, f64::min);
                assert!(spread < NO_PATTERN_SPREAD, "shot {k} {s}: pattern behind, {spread}");
                checked += 1;
            }
            seen.push(is_seen);
        }
        if seen.iter().any(|&v| v) && !seen.iter().all(|&v| v) {
            seen_by_some_not_all += 1;
        }
        // Own poses: seen by their sensor only; shared ones by both neighbours.
        let want: Vec<bool> = if k < 3 * OWN_POSES.len() {
            (0..3).map(|i| i == k % 3).collect()
        } else {
            let pair = (k - 3 * OWN_POSES.len()) / SHARED_POSES.len();
            (0..3).map(|i| i == pair || i == (pair + 1) % 3).collect()
        };
        assert_eq!(seen, want, "shot {k}");
    }
    eprintln!(
        "{checked} views checked against the images, {seen_by_some_not_all} of {n_poses} shots seen by a subset"
    );
    assert_eq!(seen_by_some_not_all, n_poses);

    // The detector and calibration, independent of the simulator: the second sensor's own
    // images calibrate to its own (perturbed) factory parameters within 3σ, and its detector
    // finds no board in shot 1 (facing the first sensor) but one in shot 2 (facing it).
    let fitted = dir.path().join("rig2.json");
    let s2 = out.join(SERIALS[1]);
    let st = kfuse()
        .args(["calibrate", "--allow-unpaired", "--ir"])
        .arg(s2.join("ir_*.png"))
        .arg("--color")
        .arg(s2.join("color_*.jpg"))
        .arg("--out")
        .arg(&fitted)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&st.stdout);
    assert!(st.status.success(), "{}{text}", String::from_utf8_lossy(&st.stderr));
    let row = |name: &str| text.lines().find(|l| l.trim_start().starts_with(name)).unwrap_or("");
    assert!(row("color_0001.jpg").contains("no board found"), "{text}");
    assert!(row("color_0002.jpg").contains(" ok"), "{text}");
    let fit = json(&fitted);
    let c = &fit["calibration"];
    for (which, sigma, truth) in [
        ("depth_camera", "depth_std_1sigma", cam(format!("{}.depth", SERIALS[1]))),
        ("color_camera", "color_std_1sigma", cam(format!("{}.color", SERIALS[1]))),
    ] {
        for (k, want) in ["fx", "fy", "cx", "cy"].iter().zip(truth.k) {
            let got = fit[which][k].as_f64().unwrap();
            let sd = c[sigma][k].as_f64().unwrap();
            eprintln!("{which} {k}: {got:.3} ± {sd:.3}, true {want:.3}");
            assert!((got - want).abs() <= 3.0 * sd, "{which} {k}: {got} ± {sd}, true {want}");
        }
    }
    // The perturbation (+1.2 % depth focal length) is resolved: far beyond 10σ.
    let sd = c["depth_std_1sigma"]["fx"].as_f64().unwrap();
    assert!((fit["depth_camera"]["fx"].as_f64().unwrap() - fx[0]).abs() > 10.0 * sd);
}

/// One sensor of three unplugged mid-run: named on stderr, the other two take every shot,
/// `index.json` says after which shot it was lost; exit 1.
#[test]
fn a_lost_sensor_is_named_and_the_others_go_on() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s");
    let st = kfuse()
        .args(["capture", "scene", "--backend", "sim", "--sim-sensors", "3", "--device", "all"])
        .args(["--sim-fault-sensor", SERIALS[1], "--sim-unplug-after", "3"])
        .args(["--count", "5", "--interval", "0", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&st.stderr);
    assert_eq!(st.status.code(), Some(1), "{err}");
    assert!(err.contains(&format!("sensor {} was lost after", SERIALS[1])), "{err}");
    assert!(err.contains("go on"), "{err}");
    let count = |s: &str| {
        (1..=5).filter(|k| out.join(s).join(format!("scene_{k:04}_depth.png")).exists()).count()
    };
    assert_eq!(count(SERIALS[0]), 5);
    assert_eq!(count(SERIALS[2]), 5);
    let lost = count(SERIALS[1]);
    // Unplugged after 3 frame periods: at least one shot before, never all five.
    assert!((1..5).contains(&lost), "{lost}");
    let index = json(&out.join("index.json"));
    let sensor = &index["sensors"][1];
    assert_eq!(sensor["serial"], SERIALS[1]);
    assert_eq!(sensor["lost_after_shot"].as_u64(), Some(lost as u64));
    assert_eq!(sensor["shots"].as_u64(), Some(lost as u64));
    assert!(index["shots"][4]["sensors"].get(SERIALS[1]).is_none());
}

/// Two sensors with the same serial, an unknown serial, a serial given twice: one line each,
/// nothing written.
#[test]
fn same_and_unknown_serials_are_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    let run = |extra: &[&str], out: &Path| {
        let st = kfuse()
            .args(["capture", "scene", "--backend", "sim", "--interval", "0"])
            .args(extra)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap();
        assert_eq!(st.status.code(), Some(1));
        assert!(!out.exists(), "{} written", out.display());
        let err = String::from_utf8_lossy(&st.stderr).into_owned();
        let lines: Vec<String> =
            err.lines().filter(|l| !l.trim().is_empty()).map(str::to_string).collect();
        assert_eq!(lines.len(), 1, "{err}");
        lines[0].clone()
    };
    let same =
        run(&["--sim-sensors", "2", "--sim-same-serial", "--device", "all"], &dir.path().join("a"));
    assert!(same.contains("two Kinects report the same serial number 000000000001"), "{same}");
    let unknown = run(&["--sim-sensors", "3", "--device", "0123"], &dir.path().join("b"));
    assert!(
        unknown.contains("--device 0123: no Kinect v2 with this serial number is connected (connected: 000000000001, 000000000002, 000000000003)"),
        "{unknown}"
    );
    let twice = run(
        &["--sim-sensors", "3", "--device", SERIALS[1], "--device", SERIALS[1]],
        &dir.path().join("c"),
    );
    assert!(twice.contains("given twice"), "{twice}");
}

/// `capture record --device all` writes `OUT/SERIAL.kfrec` per sensor; a recording replays
/// to exactly what that sensor alone captures.
#[test]
fn record_all_writes_one_recording_per_sensor() {
    let dir = tempfile::tempdir().unwrap();
    let recs = dir.path().join("recs");
    let st = kfuse()
        .args(["capture", "record", "--backend", "sim", "--sim-sensors", "2", "--device", "all"])
        .args(["--frames", "3", "--out"])
        .arg(&recs)
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    for s in &SERIALS[..2] {
        assert!(recs.join(format!("{s}.kfrec")).exists(), "{s}");
    }
    let replayed = dir.path().join("r");
    let st = kfuse()
        .args(["capture", "scene", "--interval", "0", "--replay"])
        .arg(recs.join(format!("{}.kfrec", SERIALS[1])))
        .arg("--out")
        .arg(&replayed)
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let direct = dir.path().join("d");
    let st = kfuse()
        .args([
            "capture",
            "scene",
            "--backend",
            "sim",
            "--sim-sensors",
            "2",
            "--device",
            SERIALS[1],
        ])
        .args(["--interval", "0", "--out"])
        .arg(&direct)
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    assert_eq!(json(&replayed.join("kinect_params.json"))["serial"], SERIALS[1]);
    assert_eq!(json(&direct.join("kinect_params.json"))["serial"], SERIALS[1]);
    for f in ["scene_depth.png", "scene_ir.png", "scene_color.jpg"] {
        assert_eq!(
            std::fs::read(replayed.join(f)).unwrap(),
            std::fs::read(direct.join(f)).unwrap(),
            "{f}"
        );
    }
}
