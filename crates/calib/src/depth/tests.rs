//! Tests of the depth fit on rendered planes with a known error.
use super::*;
use geometry::{Distortion, Intrinsics};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn camera() -> CameraModel {
    CameraModel::new(
        512,
        424,
        Intrinsics::new(365.0, 365.0, 257.0, 206.0),
        Distortion { k1: 0.09, k2: -0.27, p1: 0.0, p2: 0.0, k3: 0.1 },
    )
}

/// A board at `z` tilted by `(ax, ay)` rad, its centre at `(cx, cy)·z`.
fn pose(z: f64, ax: f64, ay: f64, (cx, cy): (f64, f64), board: &Board) -> RigidTransform {
    let r = nalgebra::Rotation3::from_euler_angles(ax, ay, 0.0);
    let mid = Vector3::new(
        (board.cols - 1) as f64 * board.square_m / 2.0,
        (board.rows - 1) as f64 * board.square_m / 2.0,
        0.0,
    );
    RigidTransform::new(r, Vector3::new(cx * z, cy * z, z) - r * mid)
}

/// Renders the depth of `pose`'s plane (everywhere: the fit only looks at the board) with
/// `truth`'s error, 1 mm quantisation and, for `moved`, the plane 30 mm further.
fn view(cam: &CameraModel, p: RigidTransform, truth: &DepthCorrection, moved: bool) -> DepthView {
    let n: Vector3<f64> = p.rotation.matrix().column(2).into();
    let d0 = n.dot(&p.translation) + if moved { 0.03 * n.z } else { 0.0 };
    static RAYS: std::sync::OnceLock<Vec<[f32; 2]>> = std::sync::OnceLock::new();
    let rays = RAYS.get_or_init(|| cam.ray_table());
    let depth = Image::from_fn(512, 424, |u, v| {
        let [x, y] = rays[v * 512 + u];
        let z = d0 / n.dot(&Vector3::new(f64::from(x), f64::from(y), 1.0));
        ((truth.distort(u as f64, v as f64, z) * 1000.0).round() / 1000.0) as f32
    });
    DepthView { name: "v".into(), camera_from_board: p, depth, ir: None }
}

fn truth() -> DepthCorrection {
    let t = |kind, value| DepthTerm { kind, value, std: 0.0 };
    DepthCorrection {
        width: 512,
        height: 424,
        terms: vec![
            t(DepthTermKind::Offset, 0.024),
            t(DepthTermKind::Scale, 0.005),
            t(DepthTermKind::Radial2, 0.010),
        ],
        fit: None,
    }
}

/// Offset, scale and radial come back within 3σ (and σ below 1 mm / 0.1 %) from planes
/// at 0.7–3 m; x, y, radial4 are not chosen; the moved view is rejected.
#[test]
fn the_fit_recovers_an_injected_error_and_rejects_a_moved_board() {
    let cam = camera();
    let board = Board::new(7, 5, 0.04).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let truth = truth();
    let mut views: Vec<DepthView> = (0..9)
        .map(|k| {
            let z = 0.7 + 0.29 * k as f64;
            let (ax, ay) = (rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5));
            let c = (rng.random_range(-0.3..0.3), rng.random_range(-0.2..0.2));
            view(&cam, pose(z, ax, ay, c, &board), &truth, false)
        })
        .collect();
    views.push(view(&cam, pose(1.3, 0.3, -0.2, (0.1, 0.0), &board), &truth, true));
    let fit = fit_depth_correction(&cam, &board, &views).unwrap();
    let kinds: Vec<_> = fit.correction.terms.iter().map(|t| t.kind).collect();
    assert_eq!(
        kinds,
        [DepthTermKind::Offset, DepthTermKind::Scale, DepthTermKind::Radial2],
        "{:?}",
        fit.order_steps
    );
    for t in &fit.correction.terms {
        let want = truth.value(t.kind);
        assert!(
            (t.value - want).abs() <= 3.0 * t.std.max(1e-6),
            "{}: {} vs {want} ± {}",
            t.kind.name(),
            t.value,
            t.std
        );
    }
    assert!(fit.views[9].rejected.is_some(), "{:?}", fit.views[9]);
    assert!(fit.views[..9].iter().all(|v| v.rejected.is_none()));
    // 1 mm quantisation: 0.29 mm RMS left.
    assert!(
        fit.rms_after_m < 4e-4 && fit.rms_before_m > 0.02,
        "{} {}",
        fit.rms_after_m,
        fit.rms_before_m
    );
}

/// Too few views, or views at one distance, are refused with what is needed.
#[test]
fn insufficient_data_says_what_is_needed() {
    let cam = camera();
    let board = Board::new(7, 5, 0.04).unwrap();
    let views: Vec<DepthView> = (0..5)
        .map(|k| {
            view(&cam, pose(1.0 + 0.05 * k as f64, 0.3, 0.2, (0.0, 0.0), &board), &truth(), false)
        })
        .collect();
    let err = fit_depth_correction(&cam, &board, &views).unwrap_err().to_string();
    assert!(err.contains("0.50 m") && err.contains("5 view"), "{err}");
    let err = fit_depth_correction(&cam, &board, &views[..2]).unwrap_err().to_string();
    assert!(err.contains("at least 4"), "{err}");
}
