//! kfuse's joint calibration against OpenCV's `calibrateMultiview` on the same corners (issue
//! 52 item 8): a ring of three Kinect-like sensors (six cameras), whose corners this file
//! projects with the pinhole model and OpenCV's five-coefficient distortion written out below
//! (not with kfuse's camera model), plus Gaussian corner noise. kfuse fits them
//! ([`calib::multi::calibrate_multi`], the shipped defaults); OpenCV fits the same corners
//! through `benches/peers/opencv_calibrate_multiview.py` (the detections of
//! [`calib::multi::report::detections_json`], as `kfuse calibrate --report` writes them). Each
//! camera's centre and rotation are compared with the ring's truth: kfuse's error must be
//! below OpenCV's.
//!
//! The peer runs with the Python named by `KFUSE_PYTHON` (`.ci/run`: its venv, where it
//! installs `opencv-python-headless`), else `python3`. Without `cv2.calibrateMultiview`
//! (OpenCV ≥ 5) the test is a visible skip, or a failure where `KFUSE_REQUIRE_OPENCV=1`.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use calib::multi::{CameraViews, calibrate_multi, report::detections_json};
use calib::{Board, CalibFlags, Corner, ViewCorners};
use geometry::CameraRole;
use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const TEST: &str = "kfuse_beats_opencv_calibrate_multiview_on_the_same_corners";
/// The Python that runs the peer (else `python3`).
const PYTHON_ENV: &str = "KFUSE_PYTHON";
/// `1`: a Python without `cv2.calibrateMultiview` fails the test instead of skipping it.
const REQUIRE_ENV: &str = "KFUSE_REQUIRE_OPENCV";
/// Seed of the board poses and the corner noise.
const SEED: u64 = 52;
/// Corner noise per axis, px: the IR camera's (512×424, glare, low contrast) and the colour
/// camera's (1080p); twice as much in IR, as the simulated ring's rendered corners show.
const NOISE_IR_PX: f64 = 0.2;
/// See [`NOISE_IR_PX`].
const NOISE_COLOR_PX: f64 = 0.1;
/// Board poses facing one sensor (seen by its two cameras only).
const VIEWS_PER_SENSOR: usize = 5;
/// Board poses between two neighbouring sensors (seen by both): they carry the
/// sensor-to-sensor poses.
const VIEWS_PER_PAIR: usize = 12;
/// A view is kept for a camera when at least this share of the board's corners fall inside
/// its image (kfuse takes partial boards; OpenCV's peer leaves those out).
const MIN_CORNER_SHARE: f64 = 0.5;

/// A board seen more obliquely than acos(0.25) = 75.5° is left out (the detector's limit).
const MIN_FACING_COS: f64 = 0.25;

/// The board's extent from corner 0 to the last corner, metres.
fn board_size(board: &Board) -> Vector3<f64> {
    Vector3::new(
        board.square_m * (board.cols - 1) as f64,
        board.square_m * (board.rows - 1) as f64,
        0.0,
    )
}

/// One camera of the ring: image size, pinhole (fx, fy, cx, cy), distortion (k1, k2, p1, p2,
/// k3) and its pose `camera_from_world`.
struct Camera {
    name: String,
    role: CameraRole,
    width: usize,
    height: usize,
    k: [f64; 4],
    dist: [f64; 5],
    r: Matrix3<f64>,
    t: Vector3<f64>,
}

impl Camera {
    /// The pixel of a world point: pinhole projection, then OpenCV's radial-tangential
    /// distortion written out (x' = x·(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²),
    /// y' likewise with p1 and p2 swapped), then u = fx·x' + cx, v = fy·y' + cy. `None` behind
    /// the camera.
    fn project(&self, world: &Vector3<f64>) -> Option<Vector2<f64>> {
        let p = self.r * world + self.t;
        if p.z <= 0.0 {
            return None;
        }
        let (x, y) = (p.x / p.z, p.y / p.z);
        let [k1, k2, p1, p2, k3] = self.dist;
        let r2 = x * x + y * y;
        let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        let [fx, fy, cx, cy] = self.k;
        Some(Vector2::new(fx * xd + cx, fy * yd + cy))
    }

    /// The camera centre in the world: −Rᵀ·t.
    fn centre(&self) -> Vector3<f64> {
        -(self.r.transpose() * self.t)
    }
}

/// A camera at `centre` looking at `target`, image y down (world y up is the image's −y).
fn look_at(centre: Vector3<f64>, target: Vector3<f64>) -> (Matrix3<f64>, Vector3<f64>) {
    let z = (target - centre).normalize();
    let x = Vector3::new(0.0, 1.0, 0.0).cross(&z).normalize();
    let y = z.cross(&x);
    let r = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    (r, -(r * centre))
}

/// Three sensors on a 1.5 m circle, 120° apart, each looking at the centre: its IR camera
/// and its colour camera 52 mm to the side, slightly turned.
fn ring() -> Vec<Camera> {
    let mut out = Vec::new();
    for s in 0..3 {
        let fs = s as f64;
        let th = (120.0 * fs).to_radians();
        let c = 1.5 * Vector3::new(th.sin(), 0.0, -th.cos());
        let (r, t) = look_at(c, Vector3::new(0.0, 0.02 * fs, 0.0));
        out.push(Camera {
            name: format!("k{s}.ir"),
            role: CameraRole::Depth,
            width: 512,
            height: 424,
            k: [365.0 + 2.0 * fs, 365.5 + 2.0 * fs, 256.0 + fs, 212.0 - fs],
            dist: [0.09 + 0.005 * fs, -0.25, 0.0005, -0.0003, 0.08],
            r,
            t,
        });
        let rc = *Rotation3::from_euler_angles(0.002 * fs, -0.003, 0.001).matrix();
        let tc = Vector3::new(-0.052, 0.001 * fs, 0.0);
        out.push(Camera {
            name: format!("k{s}.color"),
            role: CameraRole::Color,
            width: 1920,
            height: 1080,
            k: [1060.0 - 3.0 * fs, 1061.0 - 3.0 * fs, 960.0 + 2.0 * fs, 540.0 + fs],
            dist: [0.02, -0.05, 0.0002, 0.0001, 0.01],
            r: rc * r,
            t: rc * t + tc,
        });
    }
    out
}

/// A standard normal sample (Box–Muller).
fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random_range(f64::EPSILON..1.0);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Board poses `(world_from_board rotation, translation)`: [`VIEWS_PER_SENSOR`] facing each
/// sensor, [`VIEWS_PER_PAIR`] halfway between each pair, tilted up to 30°, near the centre.
fn board_poses(rng: &mut ChaCha8Rng, board: &Board) -> Vec<(Matrix3<f64>, Vector3<f64>)> {
    let facing = (0..3)
        .flat_map(|s| std::iter::repeat_n(120.0 * s as f64, VIEWS_PER_SENSOR))
        .chain((0..3).flat_map(|s| std::iter::repeat_n(120.0 * s as f64 + 60.0, VIEWS_PER_PAIR)));
    let half = 0.5 * board_size(board);
    facing
        .collect::<Vec<_>>()
        .into_iter()
        .map(|f| {
            let th = (f + 8.0 * rng.random_range(-1.0..1.0)).to_radians();
            // Board z points away from the sensor(s) it faces.
            let z = -Vector3::new(th.sin(), 0.0, -th.cos());
            let x = Vector3::new(0.0, 1.0, 0.0).cross(&z).normalize();
            let y = z.cross(&x);
            let tilt = Rotation3::from_euler_angles(
                30f64.to_radians() * rng.random_range(-1.0..1.0),
                20f64.to_radians() * rng.random_range(-1.0..1.0),
                25f64.to_radians() * rng.random_range(-1.0..1.0),
            );
            let r = Matrix3::from_columns(&[x, y, z]) * tilt.matrix();
            let centre = Vector3::new(
                0.45 * rng.random_range(-1.0..1.0),
                0.3 * rng.random_range(-1.0..1.0),
                0.45 * rng.random_range(-1.0..1.0),
            );
            (r, centre - r * half)
        })
        .collect()
}

/// Every camera's corners per view id: the board's corners projected by
/// [`Camera::project`] with noise, those inside the image; a view where the board's front
/// faces away or fewer than [`MIN_CORNER_SHARE`] of its corners are in the image is left out.
fn views(ring: &[Camera], board: &Board) -> Vec<CameraViews> {
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let poses = board_poses(&mut rng, board);
    ring.iter()
        .map(|cam| {
            let noise = if cam.role == CameraRole::Depth { NOISE_IR_PX } else { NOISE_COLOR_PX };
            let mut vs = BTreeMap::new();
            for (vi, (rb, tb)) in poses.iter().enumerate() {
                // The board's normal (its z) must point away from the camera, at most
                // acos(MIN_FACING_COS) from the line of sight.
                let sight = (rb * (0.5 * board_size(board)) + tb - cam.centre()).normalize();
                if rb.column(2).dot(&sight) < MIN_FACING_COS {
                    continue;
                }
                let mut corners = Vec::new();
                for id in 0..board.len() {
                    let object = Vector3::new(
                        board.square_m * (id % board.cols) as f64,
                        board.square_m * (id / board.cols) as f64,
                        0.0,
                    );
                    let Some(px) = cam.project(&(rb * object + tb)) else { continue };
                    let inside = px.x >= 0.0
                        && px.y >= 0.0
                        && px.x <= (cam.width - 1) as f64
                        && px.y <= (cam.height - 1) as f64;
                    if inside {
                        let n = Vector2::new(gauss(&mut rng), gauss(&mut rng));
                        corners.push(Corner { id, px: px + noise * n });
                    }
                }
                if (corners.len() as f64) < MIN_CORNER_SHARE * board.len() as f64 {
                    continue;
                }
                vs.insert(
                    vi as u64,
                    ViewCorners {
                        name: format!("{}_{vi:02}", cam.name),
                        width: cam.width,
                        height: cam.height,
                        corners,
                        unusable: None,
                    },
                );
            }
            CameraViews {
                name: cam.name.clone(),
                role: cam.role,
                sensor: Some(cam.name.split('.').next().unwrap().to_string()),
                width: cam.width,
                height: cam.height,
                views: vs,
                flags: CalibFlags::default(),
            }
        })
        .collect()
}

/// The camera's true pose relative to the reference camera `reference`: (R, t) of
/// `camera_from_reference`.
fn true_pose(cam: &Camera, reference: &Camera) -> (Matrix3<f64>, Vector3<f64>) {
    let r = cam.r * reference.r.transpose();
    (r, cam.t - r * reference.t)
}

/// Centre error (mm) and rotation error (degrees) of a fitted `camera_from_reference`.
fn pose_error(
    fit: (Matrix3<f64>, Vector3<f64>),
    truth: (Matrix3<f64>, Vector3<f64>),
) -> (f64, f64) {
    let centre = |(r, t): (Matrix3<f64>, Vector3<f64>)| -(r.transpose() * t);
    let mm = (centre(fit) - centre(truth)).norm() * 1e3;
    let cos = (((fit.0 * truth.0.transpose()).trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
    (mm, cos.acos().to_degrees())
}

/// Whether `python` imports cv2 with `calibrateMultiview`; `Err` says what it found.
fn opencv_version(python: &str) -> Result<String, String> {
    let out = Command::new(python)
        .args(["-c", "import cv2; cv2.calibrateMultiview; print(cv2.__version__)"])
        .output()
        .map_err(|e| format!("cannot run {python}: {e}"))?;
    if out.status.success() {
        Ok(String::from_utf8_lossy(&out.stdout).trim().to_string())
    } else {
        let err = String::from_utf8_lossy(&out.stderr);
        Err(format!(
            "{python} has no cv2.calibrateMultiview (OpenCV >= 5; pip install opencv-python-headless): {}",
            err.trim().lines().last().unwrap_or_default()
        ))
    }
}

#[test]
fn kfuse_beats_opencv_calibrate_multiview_on_the_same_corners() {
    let python = std::env::var(PYTHON_ENV).unwrap_or_else(|_| "python3".to_string());
    let version = match opencv_version(&python) {
        Ok(v) => v,
        Err(why) if std::env::var(REQUIRE_ENV).as_deref() == Ok("1") => {
            panic!("{REQUIRE_ENV}=1: {why}")
        }
        Err(why) => {
            test_skip::skip(TEST, &why);
            return;
        }
    };
    let board = Board::new(9, 6, 0.08).unwrap();
    let ring = ring();
    let cams = views(&ring, &board);
    let per_cam: Vec<usize> = cams.iter().map(|c| c.views.len()).collect();
    println!("views per camera: {per_cam:?}");

    let kfuse = calibrate_multi(&board, &cams, None).expect("kfuse's joint calibration");
    assert_eq!(kfuse.rig.reference, "k0.ir");

    let dir = tempfile::tempdir().unwrap();
    let detections = dir.path().join("report.json");
    let report = serde_json::json!({
        "reference": kfuse.rig.reference,
        "detections": detections_json(&board, &cams, &[]),
    });
    std::fs::write(&detections, serde_json::to_vec(&report).unwrap()).unwrap();
    // The crate folder cargo names at run time (a test binary reused from a checkout at
    // another path would look there), else the one it was compiled in.
    let crate_dir = std::env::var_os("CARGO_MANIFEST_DIR")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).to_path_buf());
    let script = crate_dir.join("../../benches/peers/opencv_calibrate_multiview.py");
    let cv_out = dir.path().join("opencv.json");
    let st = Command::new(&python).arg(&script).arg(&detections).arg(&cv_out).output().unwrap();
    assert!(st.status.success(), "the OpenCV peer: {}", String::from_utf8_lossy(&st.stderr));
    let cv: serde_json::Value = serde_json::from_slice(&std::fs::read(&cv_out).unwrap()).unwrap();
    assert_eq!(cv["reference"], "k0.ir");
    println!(
        "OpenCV {version}: RMS {:.4} px, {} camera-views used, {} partial left out; kfuse RMS {:.4} px",
        cv["rms_px"], cv["views_used"], cv["views_left_out_partial"], kfuse.rms_px
    );

    let reference = &ring[0];
    let (mut sum_kfuse, mut sum_cv) = ((0.0, 0.0), (0.0, 0.0));
    println!("camera       kfuse mm   kfuse °   OpenCV mm  OpenCV °");
    for cam in ring.iter().skip(1) {
        let truth = true_pose(cam, reference);
        let fit = kfuse.rig.cameras.iter().find(|c| c.name == cam.name).unwrap();
        let k = pose_error(
            (*fit.camera_from_reference.rotation.matrix(), fit.camera_from_reference.translation),
            truth,
        );
        let c = cv["cameras"].as_array().unwrap().iter().find(|c| c["name"] == *cam.name).unwrap();
        let pose = &c["camera_from_reference"];
        let r = Matrix3::from_fn(|i, j| pose["rotation"][i][j].as_f64().unwrap());
        let t = Vector3::from_fn(|i, _| pose["translation_m"][i].as_f64().unwrap());
        let o = pose_error((r, t), truth);
        println!("{:<12} {:8.3} {:9.4} {:11.3} {:9.4}", cam.name, k.0, k.1, o.0, o.1);
        sum_kfuse = (sum_kfuse.0 + k.0 * k.0, sum_kfuse.1 + k.1 * k.1);
        sum_cv = (sum_cv.0 + o.0 * o.0, sum_cv.1 + o.1 * o.1);
    }
    let n = (ring.len() - 1) as f64;
    let rms = |s: (f64, f64)| ((s.0 / n).sqrt(), (s.1 / n).sqrt());
    let (k, o) = (rms(sum_kfuse), rms(sum_cv));
    println!(
        "RMS over the cameras: kfuse {:.3} mm {:.4}°, OpenCV {:.3} mm {:.4}°",
        k.0, k.1, o.0, o.1
    );
    assert!(k.0 < o.0, "centre error: kfuse {:.3} mm, OpenCV {:.3} mm", k.0, o.0);
    assert!(k.1 < o.1, "rotation error: kfuse {:.4}°, OpenCV {:.4}°", k.1, o.1);
}
