//! Undistortion against truth: a board rendered through a known distorting lens
//! (`common/render.rs` undistorts each pixel's ray exactly, independently of
//! `calib::undistort`) is undistorted by [`UndistortMap`]; the corners found in the result must
//! land on the board's pinhole projection and its rows and columns must be straight. A map
//! built with the wrong sign of k1 must fail the same checks.

mod common;

use calib::Board;
use calib::detect::{DetectorParams, detect, to_f32};
use calib::undistort::UndistortMap;
use common::render::Scene;
use geometry::{CameraModel, Distortion, Image, Intrinsics};
use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Corners in the undistorted image within this of the pinhole projection: the detector's
/// error on sharp renders is ~0.03 px, bilinear resampling adds a few hundredths.
pub const CORNER_TOL_PX: f64 = 0.15;
/// Largest distance of a corner from the straight line fitted to its row or column.
pub const STRAIGHT_TOL_PX: f64 = 0.1;

/// A barrel lens as strong as a wide-angle webcam's (the corners move by ~14 px).
fn camera(k1: f64) -> CameraModel {
    CameraModel::new(
        640,
        480,
        Intrinsics::new(520.0, 520.0, 319.5, 239.5),
        Distortion { k1, k2: 0.06, p1: 0.0008, p2: -0.0005, k3: 0.0 },
    )
}

const K1: f64 = -0.28;

fn scene(cam: &CameraModel) -> Scene {
    // A 9x6 board, tilted 15° and turned 10°, filling most of the frame.
    let r = *(Rotation3::from_euler_angles(0.26, -0.1, 0.17)).matrix();
    let centre = Vector3::new(4.0, 2.5, 0.0);
    Scene {
        width: cam.width,
        height: cam.height,
        cols: 9,
        rows: 6,
        top_left_black: true,
        k: cam.intrinsics,
        dist: cam.distortion,
        r: Matrix3::from(r),
        t: Vector3::new(0.0, 0.0, 14.0) - r * centre,
        blur: 0.6,
        noise: 0.5,
        background: 90.0,
    }
}

/// Largest distance (px) of a point from the total-least-squares line through all of them.
pub fn line_residual(pts: &[Vector2<f64>]) -> f64 {
    let n = pts.len() as f64;
    let m = pts.iter().sum::<Vector2<f64>>() / n;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in pts {
        let d = p - m;
        sxx += d.x * d.x;
        sxy += d.x * d.y;
        syy += d.y * d.y;
    }
    // Normal = eigenvector of the smaller eigenvalue of the scatter matrix.
    let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let normal = Vector2::new(-theta.sin(), theta.cos());
    pts.iter().map(|p| (p - m).dot(&normal).abs()).fold(0.0, f64::max)
}

/// (worst corner distance to the pinhole projection, worst row/column line residual) of the
/// board found in `img`; `None` when the whole board is not found.
fn measure(img: &Image<u8>, s: &Scene) -> Option<(f64, f64)> {
    let board = Board::new(9, 6, 1.0).unwrap();
    let d = detect(&to_f32(img), &board, &DetectorParams::for_image(img.width(), img.height()))?;
    if !d.complete {
        return None;
    }
    let at = |id: usize| d.corners.iter().find(|c| c.id == id).unwrap().px;
    let corner = d
        .corners
        .iter()
        .map(|c| (c.px - s.pinhole((c.id % 9) as f64, (c.id / 9) as f64)).norm())
        .fold(0.0, f64::max);
    let rows = (0..6).map(|y| line_residual(&(0..9).map(|x| at(y * 9 + x)).collect::<Vec<_>>()));
    let cols = (0..9).map(|x| line_residual(&(0..6).map(|y| at(y * 9 + x)).collect::<Vec<_>>()));
    Some((corner, rows.chain(cols).fold(0.0, f64::max)))
}

fn gray(img: &Image<[u8; 1]>) -> Image<u8> {
    img.map(|p| p[0])
}

#[test]
fn undistorted_corners_land_on_the_pinhole_projection_and_lines_are_straight() {
    let cam = camera(K1);
    let s = scene(&cam);
    let input = s.render(&mut ChaCha8Rng::seed_from_u64(1));
    // The input is visibly distorted: its rows bend by pixels.
    let (corner_in, straight_in) = measure(&input, &s).expect("board found in the input");
    println!(
        "distorted input: corners {corner_in:.3} px from pinhole, lines bend {straight_in:.3} px"
    );
    // Measured (audit18, 2026-12-01, on top of 04fbb28): input corners 6.386 px from the pinhole
    // projection, lines bend 1.354 px.
    assert!(corner_in > 3.0 && straight_in > 1.0, "{corner_in} {straight_in}");

    let map = UndistortMap::new(&cam);
    let (out, _) = map.remap_bilinear(&input.map(|&v| [v]));
    let (corner, straight) = measure(&gray(&out), &s).expect("board found undistorted");
    println!("undistorted: corners {corner:.4} px from pinhole, lines within {straight:.4} px");
    // Measured (same run): 0.0451 px and 0.0360 px, so CORNER_TOL_PX (0.15) and STRAIGHT_TOL_PX
    // (0.1) are ~3× the measured values; the wrong-sign control below measured 11.83 px / 2.41 px.
    assert!(corner < CORNER_TOL_PX, "corner {corner} px from the pinhole projection");
    assert!(straight < STRAIGHT_TOL_PX, "lines bend {straight} px");

    // Control: the wrong sign of k1 must fail both checks.
    let wrong = UndistortMap::new(&camera(-K1));
    let (bad, _) = wrong.remap_bilinear(&input.map(|&v| [v]));
    let control = measure(&gray(&bad), &s);
    println!("wrong sign of k1: {control:?} (corner px, line bend px)");
    assert!(
        control.is_none_or(|(c, l)| c > 10.0 * CORNER_TOL_PX && l > 10.0 * STRAIGHT_TOL_PX),
        "{control:?}"
    );
}
