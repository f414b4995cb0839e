//! Tests of the depth fit on rendered planes with a known error.
use super::*;
use crate::{CalibFlags, calibrate_mono};
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

/// The board's corners of `pose` projected through `cam` (exact: no noise).
fn corners(cam: &CameraModel, p: &RigidTransform, board: &Board, name: &str) -> ViewCorners {
    ViewCorners {
        name: name.into(),
        width: cam.width,
        height: cam.height,
        corners: (0..board.len())
            .map(|id| crate::Corner {
                id,
                px: cam.project(&p.apply(&board.object_point(id))).unwrap(),
            })
            .collect(),
        unusable: None,
    }
}

/// Eight shots at 0.7–2.8 m with `truth`'s error plus `extra(u, v)` metres.
fn shots(
    cam: &CameraModel,
    board: &Board,
    truth: &DepthCorrection,
    extra: &dyn Fn(usize, usize) -> f64,
) -> Vec<DepthShot> {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    (0..8)
        .map(|k| {
            let z = 0.7 + 0.3 * k as f64;
            let (ax, ay) = (rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5));
            let c = (rng.random_range(-0.25..0.25), rng.random_range(-0.2..0.2));
            let p = pose(z, ax, ay, c, board);
            let mut v = view(cam, p, truth, false);
            let (w, h) = v.depth.size();
            v.depth = Image::from_fn(w, h, |u, r| {
                (f64::from(*v.depth.get(u, r)) + (extra(u, r) * 1000.0).round() / 1000.0) as f32
            });
            let name = format!("depth_{k}");
            DepthShot { corners: corners(cam, &p, board, &name), name, depth: v.depth, ir: None }
        })
        .collect()
}

/// The sensitivity against its truths on exact corners: for the square, the analytic one
/// (every pose, and so every plane z, scales with the square: the scale becomes
/// `(1+s)/(1+ε) − 1`, the offset and the spatial terms do not move); for the focal length,
/// a finite difference computed here independently of the fit's normal equations (poses from
/// `calibrate_mono` with the focal length ±1 %, `board_samples`, the same terms by SVD).
#[test]
fn the_sensitivity_matches_the_analytic_and_finite_difference_truths() {
    let cam = camera();
    let board = Board::new(7, 5, 0.04).unwrap();
    let truth = truth();
    let shots = shots(&cam, &board, &truth, &|_, _| 0.0);
    let fit = fit_depth_from_corners(&cam, &board, &shots, true).unwrap();
    let sens = fit.sensitivity.clone().unwrap();
    let s = fit.correction.value(DepthTermKind::Scale);
    // Central difference of (1+s)/(1+ε) at ε = ±1 %, per 1 %.
    let analytic = ((1.0 + s) / 1.01 - (1.0 + s) / 0.99) / 2.0;
    let sq = sens.of(DepthTermKind::Scale).unwrap().per_percent_square;
    eprintln!("d scale / d square: {sq:.6} per 1 % (analytic {analytic:.6})");
    assert!((sq - analytic).abs() < 1e-5, "{sq} vs {analytic}");
    for t in &sens.terms {
        if t.kind != DepthTermKind::Scale {
            // Metres per 1 %: 1 µm is the quantised depth's leverage on a re-fit.
            assert!(
                t.per_percent_square.abs() < 1e-6,
                "{}: {}",
                t.kind.name(),
                t.per_percent_square
            );
        }
    }
    // The focal length: poses from `calibrate_mono` with f ± 1 %, the board samples along
    // that camera's rays, and the nominal fit's terms solved here by SVD of the design matrix.
    let kinds: Vec<DepthTermKind> = fit.correction.terms.iter().map(|t| t.kind).collect();
    let coords = ImageCoords::new(cam.width, cam.height);
    let fd: Vec<DVector<f64>> = [1.01, 0.99]
        .iter()
        .map(|&k| {
            let mut c = cam;
            c.intrinsics.fx *= k;
            c.intrinsics.fy *= k;
            let flags = CalibFlags {
                use_intrinsic_guess: true,
                fix_intrinsics: true,
                ..CalibFlags::default()
            };
            let views: Vec<ViewCorners> = shots.iter().map(|s| s.corners.clone()).collect();
            let m = calibrate_mono("ir", &board, &views, &flags, Some(&c)).unwrap();
            let rays = c.ray_table();
            let samples: Vec<Sample> = shots
                .iter()
                .zip(&m.views)
                .flat_map(|(s, r)| {
                    let v = DepthView {
                        name: s.name.clone(),
                        camera_from_board: r.camera_from_board.unwrap(),
                        depth: s.depth.clone(),
                        ir: None,
                    };
                    board_samples(&c, &rays, &board, &v)
                })
                .collect();
            let a = DMatrix::from_fn(samples.len(), kinds.len(), |i, j| {
                let s = &samples[i];
                match kinds[j] {
                    DepthTermKind::Scale => s.z_plane,
                    k => coords.term(k, f64::from(s.u), f64::from(s.v)),
                }
            });
            let y =
                DVector::from_fn(samples.len(), |i, _| samples[i].z_measured - samples[i].z_plane);
            a.svd(true, true).solve(&y, 1e-12).unwrap()
        })
        .collect();
    for (j, t) in sens.terms.iter().enumerate() {
        let want = (fd[0][j] - fd[1][j]) / 2.0;
        eprintln!(
            "d {} / d f: {:+.6} per 1 % (finite difference {want:+.6})",
            t.kind.name(),
            t.per_percent_focal
        );
        // 1 % of the derivative, or 1 µm (metres) / 1e-6 (scale) for one near zero: the two
        // solvers agree to rounding, the rest is the normal equations' conditioning.
        assert!(
            (t.per_percent_focal - want).abs() <= 0.01 * want.abs() + 1e-6,
            "{}: {} vs {want}",
            t.kind.name(),
            t.per_percent_focal
        );
    }
    // The focal length moves the scale by about −1 % per 1 % (distances scale with f) and
    // visibly more than its σ: the dependence is worth reporting.
    let ds = sens.of(DepthTermKind::Scale).unwrap().per_percent_focal;
    assert!(ds < -0.005 && ds.abs() > 10.0 * fit.correction.terms[1].std, "{ds}");
}

/// A scale beyond MAX_PLAUSIBLE_SCALE is refused with the scale, the bound and what moves it;
/// the injected 0.5 % passes.
#[test]
fn an_implausible_scale_is_refused_naming_what_moves_it() {
    let cam = camera();
    let board = Board::new(7, 5, 0.04).unwrap();
    let ok =
        fit_depth_from_corners(&cam, &board, &shots(&cam, &board, &truth(), &|_, _| 0.0), true)
            .unwrap();
    assert!(check_plausible(&ok).is_ok());
    let mut big = truth();
    big.terms[1].value = 0.08;
    let fit = fit_depth_from_corners(&cam, &board, &shots(&cam, &board, &big, &|_, _| 0.0), true)
        .unwrap();
    assert!((fit.correction.value(DepthTermKind::Scale) - 0.08).abs() < 1e-3);
    let err = check_plausible(&fit).unwrap_err().to_string();
    assert!(
        err.contains("+8.00 %")
            && err.contains("±5 %")
            && err.contains("each +1 % of the square moves it by -1.08 %")
            && err.contains("--force"),
        "{err}"
    );
}

/// An error outside the model (±5 mm alternating per pixel, as a fixed-pattern error) cannot
/// be fitted: the fit reports it as a residual of 5 mm RMS (the pattern's own RMS, with the
/// 0.29 mm of the 1 mm quantisation), in every view, not a success; the modelled terms are
/// still recovered within 3σ.
#[test]
fn an_error_outside_the_model_is_reported_as_residual() {
    let cam = camera();
    let board = Board::new(7, 5, 0.04).unwrap();
    let truth = truth();
    let pattern = |u: usize, v: usize| if (u + v).is_multiple_of(2) { 0.005 } else { -0.005 };
    let fit =
        fit_depth_from_corners(&cam, &board, &shots(&cam, &board, &truth, &pattern), true).unwrap();
    eprintln!("per-pixel ±5 mm pattern: RMS after the fit {:.3} mm", 1e3 * fit.rms_after_m);
    assert!((fit.rms_after_m - 0.005).abs() < 3e-4, "{}", fit.rms_after_m);
    assert!(
        fit.views.iter().all(|v| v.rejected.is_none() && v.rms_after_m > 0.0045),
        "{:?}",
        fit.views
    );
    for k in [DepthTermKind::Offset, DepthTermKind::Scale] {
        let t = fit.correction.terms.iter().find(|t| t.kind == k).unwrap();
        assert!((t.value - truth.value(k)).abs() <= 3.0 * t.std.max(1e-6), "{k:?}: {t:?}");
    }
}
