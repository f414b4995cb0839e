//! The simulated 3-Kinect ring: 6 cameras, a board near the centre.

use std::collections::BTreeMap;

use geometry::{CameraModel, CameraRole, Distortion, Intrinsics, RigidTransform};
use nalgebra::{Rotation3, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{CameraViews, calibrate_multi};
use crate::{Board, CalibError, CalibFlags, Corner, ViewCorners};

/// Camera centre error bound of issue 32, metres.
const MAX_CENTER_ERROR_M: f64 = 1e-3;
/// Rotation error bound of issue 32, degrees.
const MAX_ROTATION_ERROR_DEG: f64 = 0.05;
/// A truth within 3σ (per axis of the centre).
const MAX_SIGMAS: f64 = 3.0;
/// A camera whose view ids are shuffled must be visibly wrong: 5 mm or an RMS above 2 px
/// (ten times the IR corner noise).
const BROKEN_MIN_ERROR_M: f64 = 5e-3;
/// See [`BROKEN_MIN_ERROR_M`].
const BROKEN_MIN_RMS_PX: f64 = 2.0;

/// A standard normal sample (Box–Muller).
fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random_range(f64::EPSILON..1.0);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Board poses facing one sensor (seen by its pair only).
const VIEWS_PER_SENSOR: usize = 6;
/// Board poses between two sensors (seen by both pairs): they carry the sensor-to-sensor
/// poses, so there are more of them.
const VIEWS_PER_PAIR: usize = 26;
/// Views between k0 and k1 kept in the smaller ring of the shuffled-ids test: all of them
/// (the k0–k1 pose rests on them alone; its fit takes under a second).
const SMALL_RING_PAIR_VIEWS: u64 = 26;
/// Rotation bar of that smaller ring with its true ids, degrees: twice the full ring's
/// [`MAX_ROTATION_ERROR_DEG`] (one pair's views carry the k0–k1 pose; measured 0.051°); a view
/// id naming another board pose puts a camera tens of degrees off.
const SMALL_RING_MAX_ROTATION_DEG: f64 = 0.1;

struct Truth {
    models: Vec<CameraModel>,
    /// world → camera.
    cam_from_world: Vec<RigidTransform>,
    names: Vec<String>,
}

fn look_at(center: Vector3<f64>, target: Vector3<f64>) -> RigidTransform {
    let z = (target - center).normalize();
    let y0 = Vector3::new(0.0, 1.0, 0.0);
    let x = y0.cross(&z).normalize();
    let y = z.cross(&x);
    let world_from_cam =
        Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[x, y, z]));
    let r = world_from_cam.inverse();
    RigidTransform::new(r, -(r * center))
}

fn ring() -> Truth {
    let mut models = Vec::new();
    let mut poses = Vec::new();
    let mut names = Vec::new();
    for s in 0..3 {
        let th = (s as f64) * 120f64.to_radians();
        let c = 1.5 * Vector3::new(th.sin(), 0.0, -th.cos());
        let depth = look_at(c, Vector3::new(0.0, 0.02 * s as f64, 0.0));
        let fs = s as f64;
        models.push(CameraModel::new(
            512,
            424,
            Intrinsics::new(365.0 + 2.0 * fs, 365.0 + 2.0 * fs, 256.0 + fs, 212.0 - fs),
            Distortion { k1: 0.09 + 0.005 * fs, k2: -0.25, ..Default::default() },
        ));
        poses.push(depth);
        names.push(format!("k{s}.ir"));
        let color_from_depth = RigidTransform::new(
            Rotation3::from_euler_angles(0.002 * fs, -0.003, 0.001),
            Vector3::new(-0.052, 0.001 * fs, 0.0),
        );
        models.push(CameraModel::new(
            1920,
            1080,
            Intrinsics::new(1060.0 - 3.0 * fs, 1060.0 - 3.0 * fs, 960.0 + 2.0 * fs, 540.0 + fs),
            Distortion { k1: 0.02, k2: -0.05, ..Default::default() },
        ));
        poses.push(color_from_depth.compose(&depth));
        names.push(format!("k{s}.color"));
    }
    Truth { models, cam_from_world: poses, names }
}

/// Board poses (world_from_board): 4 facing each sensor, 3 between each pair of sensors.
fn board_poses(rng: &mut ChaCha8Rng, board: &Board) -> Vec<RigidTransform> {
    let mut out = Vec::new();
    let mut facing = Vec::new();
    for s in 0..3 {
        for _ in 0..VIEWS_PER_SENSOR {
            facing.push(s as f64 * 120.0);
        }
    }
    for s in 0..3 {
        for _ in 0..VIEWS_PER_PAIR {
            facing.push(s as f64 * 120.0 + 60.0);
        }
    }
    let half = Vector3::new(
        0.5 * board.square_m * (board.cols - 1) as f64,
        0.5 * board.square_m * (board.rows - 1) as f64,
        0.0,
    );
    for f in facing {
        let th = (f + 8.0 * rng.random_range(-1.0..1.0)).to_radians();
        let dir = Vector3::new(th.sin(), 0.0, -th.cos()); // towards the sensor(s)
        // Board z points away from the camera(s) it faces.
        let z = -dir;
        let x = Vector3::new(0.0, 1.0, 0.0).cross(&z).normalize();
        let y = z.cross(&x);
        let base = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[x, y, z]));
        let tilt = Rotation3::from_euler_angles(
            30f64.to_radians() * rng.random_range(-1.0..1.0),
            20f64.to_radians() * rng.random_range(-1.0..1.0),
            25f64.to_radians() * rng.random_range(-1.0..1.0),
        );
        let r = base * tilt;
        let center = Vector3::new(
            0.45 * rng.random_range(-1.0..1.0),
            0.3 * rng.random_range(-1.0..1.0),
            0.45 * rng.random_range(-1.0..1.0),
        );
        out.push(RigidTransform::new(r, center - r * half));
    }
    out
}

fn views(truth: &Truth, board: &Board, seed: u64) -> Vec<CameraViews> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let poses = board_poses(&mut rng, board);
    let mut out = Vec::new();
    for (ci, model) in truth.models.iter().enumerate() {
        let sigma = if model.width == 512 { 0.2 } else { 0.1 };
        let mut vs = BTreeMap::new();
        for (vi, wb) in poses.iter().enumerate() {
            let cb = truth.cam_from_world[ci].compose(wb);
            // The camera centre in the board frame: the front side is z < 0.
            let cam_in_board = cb.inverse().translation;
            let normal_cos = -cam_in_board.z / cam_in_board.norm();
            if normal_cos < 0.25 {
                continue;
            }
            let mut corners = Vec::new();
            for id in 0..board.len() {
                let x = cb.apply(&board.object_point(id));
                if x.z <= 0.0 {
                    continue;
                }
                let d = model.distortion.distort(x.x / x.z, x.y / x.z);
                let px = model.intrinsics.to_pixel(d.x, d.y);
                if px.x < 0.0
                    || px.y < 0.0
                    || px.x > (model.width - 1) as f64
                    || px.y > (model.height - 1) as f64
                {
                    continue;
                }
                corners.push(Corner {
                    id,
                    px: px + sigma * Vector2::new(gauss(&mut rng), gauss(&mut rng)),
                });
            }
            if corners.len() < board.len() / 2 {
                continue;
            }
            vs.insert(
                vi as u64,
                ViewCorners {
                    name: format!("{}_{vi:02}.png", truth.names[ci]),
                    width: model.width,
                    height: model.height,
                    corners,
                    unusable: None,
                },
            );
        }
        out.push(CameraViews {
            name: truth.names[ci].clone(),
            role: if model.width == 512 { CameraRole::Depth } else { CameraRole::Color },
            sensor: Some(truth.names[ci].split('.').next().unwrap_or_default().to_string()),
            width: model.width,
            height: model.height,
            views: vs,
            flags: CalibFlags::default(),
        });
    }
    out
}

fn board() -> Board {
    Board::new(11, 8, 0.08).expect("valid board")
}

/// Per camera: (centre error m, centre σ norm m, rotation error °, worst centre error in σ).
fn errors(truth: &Truth, r: &super::MultiCalibration) -> Vec<(String, f64, f64, f64, f64)> {
    let ref_from_world = truth.cam_from_world[0];
    r.rig
        .cameras
        .iter()
        .zip(&r.cameras)
        .enumerate()
        .map(|(ci, (c, rep))| {
            let t = truth.cam_from_world[ci].compose(&ref_from_world.inverse());
            let est = c.camera_from_reference;
            let ct = t.inverse().translation;
            let ce = est.inverse().translation;
            let e = ce - ct;
            let rot = (t.rotation.inverse() * est.rotation).angle().to_degrees();
            let sig = rep.center_std_m;
            let in_sigma = if c.name == r.rig.reference {
                0.0
            } else {
                assert!(sig.iter().all(|s| *s > 0.0), "{}: centre σ {sig:?}", c.name);
                (0..3).map(|k| e[k].abs() / sig[k]).fold(0.0, f64::max)
            };
            (c.name.clone(), e.norm(), sig.norm(), rot, in_sigma)
        })
        .collect()
}

/// Per non-reference camera: its pose's six errors (fit − truth) over their σ: the rotation's
/// left perturbation δ (R_fit = exp(δ)·R_true, the solver's parameters) over
/// `rotation_std_rad`, then the centre in the reference frame over `center_std_m`.
fn pose_z(truth: &Truth, r: &super::MultiCalibration) -> Vec<(String, [f64; 6])> {
    let ref_from_world = truth.cam_from_world[0];
    r.rig
        .cameras
        .iter()
        .zip(&r.cameras)
        .enumerate()
        .filter(|(_, (c, _))| c.name != r.rig.reference)
        .map(|(ci, (c, rep))| {
            let (rs, cs) = (rep.rotation_std_rad, rep.center_std_m);
            assert!(rs.iter().chain(cs.iter()).all(|s| *s > 0.0), "{}: σ {rs:?} {cs:?}", c.name);
            let t = truth.cam_from_world[ci].compose(&ref_from_world.inverse());
            let est = c.camera_from_reference;
            let delta = (est.rotation * t.rotation.inverse()).scaled_axis();
            let dc = est.inverse().translation - t.inverse().translation;
            let z =
                std::array::from_fn(
                    |k| if k < 3 { delta[k] / rs[k] } else { dc[k - 3] / cs[k - 3] },
                );
            (c.name.clone(), z)
        })
        .collect()
}

/// Seeds of the σ check: six independent rings of noise and board poses.
const SIGMA_SEEDS: std::ops::RangeInclusive<u64> = 1..=6;
/// Independent values per seed among the 15 rotation errors over σ (5 cameras × 3), and
/// likewise among the 15 centre errors: a sensor's colour camera moves with its IR camera
/// (their centres differ by the fixed baseline), so the 15 carry about 9 (k0.color's 3, k1's
/// 3, k2's 3), and the two sensors' poses are correlated through the shared board poses: 4
/// is a conservative count.
const SIGMA_EFFECTIVE_PER_SEED: f64 = 4.0;
/// The normal quantile of the band's two tails (0.5 % each).
const SIGMA_BAND_Z: f64 = 2.576;

/// The (0.5 %, 99.5 %) quantiles of sqrt(χ²_k / k), the RMS of k independent standard normal
/// values, by the Wilson–Hilferty approximation (χ²_k/k ≈ (1 − 2/(9k) + z·sqrt(2/(9k)))³,
/// within 0.3 % of the exact quantile for k ≥ 30).
fn rms_band(k: f64) -> (f64, f64) {
    let a = 2.0 / (9.0 * k);
    let q = |z: f64| (1.0 - a + z * a.sqrt()).powi(3).sqrt();
    (q(-SIGMA_BAND_Z), q(SIGMA_BAND_Z))
}

/// σ is honest from both sides: over [`SIGMA_SEEDS`] rings, the errors of every camera's
/// rotation against the truth divided by their σ, and those of its centre, each have an RMS
/// within the 99 % band of [`rms_band`] for the effective count of values. An inflated σ (×3:
/// RMS 0.32) or a deflated one fails, and so does σ = 0 (asserted in `pose_z`). The centres'
/// σ with the sign of ∂C/∂δ flipped (the bug this caught) gave 0.576, below the band's 0.640.
#[test]
fn multi_ring_sigma_matches_the_errors() {
    let truth = ring();
    let b = board();
    let (mut rot, mut centre) = (Vec::new(), Vec::new());
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    for seed in SIGMA_SEEDS {
        let r = calibrate_multi(&b, &views(&truth, &b, seed), None).expect("joint calibration");
        let z = pose_z(&truth, &r);
        let (r0, c0) = (rot.len(), centre.len());
        for (_, v) in &z {
            rot.extend_from_slice(&v[..3]);
            centre.extend_from_slice(&v[3..]);
        }
        println!(
            "seed {seed}: RMS of error/σ, rotations {:.3}, centres {:.3}",
            rms(&rot[r0..]),
            rms(&centre[c0..])
        );
    }
    let k = SIGMA_EFFECTIVE_PER_SEED * SIGMA_SEEDS.count() as f64;
    let (lo, hi) = rms_band(k);
    for (what, v) in [("rotations", &rot), ("centres", &centre)] {
        let x = rms(v);
        println!(
            "{what}: RMS of error/σ {x:.3} over {} values; band {lo:.3}..{hi:.3} ({k} effective)",
            v.len()
        );
        assert!((lo..=hi).contains(&x), "{what}: RMS of error/σ {x:.3} outside {lo:.3}..{hi:.3}");
    }
}

#[test]
fn multi_ring_of_three_kinects() {
    let truth = ring();
    let b = board();
    let cams = views(&truth, &b, 32);
    let per_cam: Vec<usize> = cams.iter().map(|c| c.views.len()).collect();
    println!("views per camera: {per_cam:?}");
    let r = calibrate_multi(&b, &cams, None).expect("joint calibration");
    assert_eq!(r.rig.reference, "k0.ir");
    println!("RMS {:.3} px, tree {:?}", r.rms_px, r.tree);
    println!(
        "{:<10} {:>10} {:>8} {:>8} {:>9} {:>8}",
        "camera", "pos err mm", "σ mm", "err/σ", "rot err °", "RMS px"
    );
    let errs = errors(&truth, &r);
    for ((name, e, s, rot, ns), rep) in errs.iter().zip(&r.cameras) {
        println!(
            "{name:<10} {:>10.4} {:>8.4} {ns:>8.2} {rot:>9.4} {:>8.3}",
            e * 1e3,
            s * 1e3,
            rep.rms_px
        );
    }
    for (name, e, _, rot, ns) in &errs {
        assert!(*e < MAX_CENTER_ERROR_M, "{name}: centre error {:.3} mm", e * 1e3);
        assert!(*ns < MAX_SIGMAS, "{name}: centre error {ns:.2} σ");
        assert!(*rot < MAX_ROTATION_ERROR_DEG, "{name}: rotation error {rot:.4}°");
    }
    // Two sensors' pairs share views and sensor-only views exist.
    assert!(r.cameras.iter().all(|c| c.rms_px < 0.5), "RMS near the corner noise");
}

#[test]
fn multi_shuffled_view_ids_are_visible() {
    let truth = ring();
    let b = board();
    let mut cams = views(&truth, &b, 32);
    // One joint fit, without the outlier rounds: each round reruns the dense LM (~670
    // unknowns), and with wrong ids every round finds new outliers, so the rounds took over
    // 300 s in the debug profile. What is proved stays: wrong ids are not fitted away
    // silently (the RMS or the poses show them).
    for c in &mut cams {
        c.flags.reject_outliers = false;
    }
    // Camera k1.ir: its view ids rotated among its own views.
    let c = &mut cams[2];
    let keys: Vec<u64> = c.views.keys().copied().collect();
    let vals: Vec<ViewCorners> = c.views.values().cloned().collect();
    c.views = keys.iter().copied().zip(vals.into_iter().cycle().skip(1)).collect();
    match calibrate_multi(&b, &cams, None) {
        Ok(r) => {
            let errs = errors(&truth, &r);
            let worst = errs.iter().map(|e| e.1).fold(0.0, f64::max);
            let worst_rms = r.cameras.iter().map(|c| c.rms_px).fold(0.0, f64::max);
            println!(
                "shuffled: worst centre error {:.2} mm, worst RMS {worst_rms:.2} px, {} views rejected",
                worst * 1e3,
                r.rejected_views.len()
            );
            assert!(
                worst > BROKEN_MIN_ERROR_M
                    || worst_rms > BROKEN_MIN_RMS_PX
                    || r.rejected_views.len() >= 3,
                "shuffled ids went unnoticed: {:.3} mm, {worst_rms:.3} px",
                worst * 1e3
            );
        }
        Err(e) => {
            // The refusal must be the one that names the camera whose ids are wrong.
            let msg = e.to_string();
            println!("shuffled: refused: {msg}");
            assert!(matches!(e, CalibError::ViewsDisagree { .. }), "{msg}");
            assert!(msg.contains("k1.ir") && msg.contains("shot number"), "{msg}");
        }
    }
}

/// The shipped settings (`CalibFlags::default()`: outlier rejection on) on a smaller ring:
/// sensors k0 and k1 only (four cameras), their own views and the first
/// [`SMALL_RING_PAIR_VIEWS`] of the views between them. With camera k1.ir's view ids rotated
/// among its own views, the outcome is the refusal `ViewsDisagree` naming k1.ir: the spanning
/// tree's edge to or from k1.ir has at least `EDGE_CHECK_MIN_VIEWS` shared views, and with
/// every id naming another board pose fewer than half of them agree with the edge's medoid,
/// so the check refuses before any joint fit (and its outlier rounds) runs. The same small
/// ring with its true ids calibrates (every camera within 3σ and 5 mm), so the refusal is the
/// shuffle's.
#[test]
fn multi_shuffled_view_ids_refused_with_the_shipped_settings() {
    let truth = ring();
    let b = board();
    let mut cams = views(&truth, &b, 32);
    cams.truncate(4);
    // View ids: VIEWS_PER_SENSOR per sensor (k0's, k1's, k2's), then VIEWS_PER_PAIR per pair
    // (k0–k1 first).
    let pair01 = 3 * VIEWS_PER_SENSOR as u64;
    for c in &mut cams {
        assert!(c.flags.reject_outliers, "the shipped settings");
        c.views.retain(|&id, _| {
            id < 2 * VIEWS_PER_SENSOR as u64
                || (pair01..pair01 + SMALL_RING_PAIR_VIEWS).contains(&id)
        });
    }
    let r = calibrate_multi(&b, &cams, None).expect("the small ring with its true ids");
    // The fit's cameras are the ring's first four, in order (`errors` pairs them by index).
    // Two sensors only: the k0–k1 pose rests on one pair's views (1.35 mm and 0.051° off,
    // 1.3σ), not within the full ring's 1 mm and 0.05°; far below the shuffled case's
    // visibly-wrong bar.
    for (name, e, _, rot, ns) in &errors(&truth, &r) {
        println!(
            "true ids: {name}: centre error {:.3} mm ({ns:.2} σ), rotation {rot:.4}°",
            e * 1e3
        );
        assert!(*e < BROKEN_MIN_ERROR_M, "{name}: centre error {:.3} mm", e * 1e3);
        assert!(*ns < MAX_SIGMAS, "{name}: centre error {ns:.2} σ");
        assert!(*rot < SMALL_RING_MAX_ROTATION_DEG, "{name}: rotation error {rot:.4}°");
    }
    // Camera k1.ir: its view ids rotated among its own views.
    let c = &mut cams[2];
    assert_eq!(c.name, "k1.ir");
    let keys: Vec<u64> = c.views.keys().copied().collect();
    let vals: Vec<ViewCorners> = c.views.values().cloned().collect();
    c.views = keys.iter().copied().zip(vals.into_iter().cycle().skip(1)).collect();
    let e = match calibrate_multi(&b, &cams, None) {
        Ok(r) => panic!(
            "shuffled ids not refused: RMS {:.2} px, {} corners rejected",
            r.rms_px, r.rejected_corners
        ),
        Err(e) => e,
    };
    let msg = e.to_string();
    println!("shuffled, shipped settings: {msg}");
    match &e {
        CalibError::ViewsDisagree { camera, parent, shared, agreeing } => {
            assert!(camera == "k1.ir" || parent == "k1.ir", "{msg}");
            assert!(2 * agreeing < *shared, "{msg}");
        }
        _ => panic!("not ViewsDisagree: {msg}"),
    }
    assert!(msg.contains("k1.ir") && msg.contains("shot number"), "{msg}");
}

#[test]
fn multi_disconnected_graph_names_the_groups() {
    let truth = ring();
    let b = board();
    let mut cams = views(&truth, &b, 32);
    // Sensor k2 keeps only the views no other sensor saw.
    let others: std::collections::BTreeSet<u64> =
        cams[..4].iter().flat_map(|c| c.views.keys().copied()).collect();
    for c in &mut cams[4..] {
        c.views.retain(|k, _| !others.contains(k));
    }
    let e = calibrate_multi(&b, &cams, None).expect_err("not connected");
    let msg = e.to_string();
    println!("{msg}");
    assert!(matches!(e, CalibError::NotConnected { .. }));
    assert!(msg.contains("{k0.ir, k0.color, k1.ir, k1.color} and {k2.ir, k2.color}"), "{msg}");
    assert!(msg.contains("need a view of the board in common"), "{msg}");
}

#[test]
fn multi_camera_without_views_is_named() {
    let truth = ring();
    let b = board();
    let mut cams = views(&truth, &b, 32);
    cams[3].views.clear();
    let e = calibrate_multi(&b, &cams, None).expect_err("no views");
    let msg = e.to_string();
    println!("{msg}");
    assert!(matches!(e, CalibError::NoBoard { .. }), "{msg}");
    assert!(msg.contains("k1.color"), "{msg}");
}
