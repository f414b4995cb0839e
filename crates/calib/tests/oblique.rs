//! Boards lying flat on a table seen at grazing angles (issue 29: a 1920x1080 webcam photo of a
//! 10x7 board on a table, which OpenCV's classic and SB detectors find, was missed). The tests'
//! own renderer (`common/render.rs`) draws the board on a textured, lamp-lit table top seen by a
//! 1080p pinhole camera with a mild barrel lens from `obliquity` degrees off the board's normal,
//! with blur and noise; the truth is the corners' exact projection.
//!
//! Before the fix, detection failed from 60–70° (depending on the board's turn on the table):
//! the seed cell's rule for telling a square's sides from its diagonals was a length rule,
//! which strong perspective defeats, so the grid grew along the diagonals (16x7 corners instead
//! of 10x7), and the seed's angle, side-ratio and nearest-neighbour limits found no cell at all
//! in the thin squares near 80°.

mod common;

use calib::Board;
use calib::detect::{Detection, DetectorParams, detect, to_f32};
use common::render::{Scene, Table, table_pose};
use geometry::{Distortion, Intrinsics};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A 1080p webcam: 1400 px focal length (69° across), a mild barrel lens.
const W: usize = 1920;
const H: usize = 1080;
const F: f64 = 1400.0;
const LENS: Distortion = Distortion { k1: -0.04, k2: 0.01, p1: 0.0, p2: 0.0, k3: 0.0 };
/// The board: 10x7 inner corners (11x8 squares, colour decides the labelling).
const COLS: usize = 10;
const ROWS: usize = 7;
/// Samples per pixel side of the renderer: with 2 an edge along a pixel row is placed in steps
/// of half a pixel, which moved the corners' truth by up to 0.25 px from the rendered image;
/// with 3 the rendered corners lie within ~0.05 px of it.
const SUPERSAMPLING: usize = 3;

/// The largest obliquity (degrees between the board's normal and the direction from the
/// camera to the board's centre) at which detection is claimed: every 10x7 board on the table
/// is found up to here, with the board filling 60–90 % of the frame and turned any way on the
/// table. At 80° the squares near the far corners are 7 times longer than wide and 20–25 px
/// across, and some views lose a corner or the whole board; at 85° the candidate stage misses
/// most far corners. Beyond this limit the detector may find nothing, never wrong corners.
const MAX_CLAIMED_OBLIQUITY_DEG: f64 = 75.0;
/// Every corner within this of its true position up to the claimed limit (the bar):
/// the detector's error on these renders is 0.01–0.04 px mean, up to ~0.15 px on the thinnest
/// far squares.
const CORNER_TOL_PX: f64 = 0.3;
/// Beyond the limit a reported corner must still carry its true id: within this of the true
/// corner with its id (the nearest other corner is at least ~8 px away on these renders).
const SAME_CORNER_PX: f64 = 1.5;
/// The scenes are as grazing as the photo: the near squares at least this many times
/// the far ones (√area).
const MIN_NEAR_FAR_RATIO: f64 = 2.0;

/// The board on the table at `obliquity_deg` (see [`table_pose`]), turned so that the camera
/// looks along `azimuth_deg` from the board's x axis, its outline spanning `fill` of the frame.
fn scene(obliquity_deg: f64, azimuth_deg: f64, fill: f64) -> Scene {
    let (r, t) = table_pose(COLS, ROWS, (W, H, F), obliquity_deg, azimuth_deg, fill);
    Scene {
        width: W,
        height: H,
        cols: COLS,
        rows: ROWS,
        top_left_black: true,
        k: Intrinsics::new(F, F, (W as f64 - 1.0) / 2.0, (H as f64 - 1.0) / 2.0),
        dist: LENS,
        r,
        t,
        blur: 0.8,
        noise: 2.0,
        background: 70.0,
    }
}

/// A wooden table top four board lengths wide, a lamp off to one side.
fn table() -> Table {
    Table {
        x: (-14.0, 24.0),
        y: (-12.0, 19.0),
        base: 120.0,
        grain: 22.0,
        speckle: 12.0,
        grain_angle: 0.35,
        lamp: (2.0, 8.0),
        lamp_radius: 14.0,
        falloff: 0.35,
        seed: 29,
    }
}

/// The largest and the smallest board square in the image (√area, px).
fn square_sizes(s: &Scene) -> (f64, f64) {
    let mut sizes = Vec::new();
    for y in -1..ROWS as i32 {
        for x in -1..COLS as i32 {
            let p = [(0, 0), (1, 0), (1, 1), (0, 1)]
                .map(|(dx, dy)| s.project((x + dx) as f64, (y + dy) as f64));
            let twice_area: f64 = (0..4).map(|k| p[k].perp(&p[(k + 1) % 4])).sum();
            sizes.push((0.5 * twice_area).abs().sqrt());
        }
    }
    let max = sizes.iter().copied().fold(0.0, f64::max);
    (max, sizes.iter().copied().fold(max, f64::min))
}

/// Renders the scene (seeded) and detects the board in it.
fn render_and_detect(s: &Scene, seed: u64) -> Option<Detection> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let img = s.render_on_table(&mut rng, &table(), SUPERSAMPLING);
    let board = Board::new(COLS, ROWS, 1.0).unwrap();
    detect(&to_f32(&img), &board, &DetectorParams::for_image(W, H))
}

/// Distance of each detected corner from the true corner with its id. The board's colouring
/// decides its labelling (10 + 7 is odd) and the top-left square is black, so corner 0 is the
/// rendered corner 0 in every view.
fn errors(s: &Scene, d: &Detection) -> Vec<f64> {
    d.corners.iter().map(|c| (c.px - s.corner(c.id)).norm()).collect()
}

/// Source of the expectations: the rendered corners' exact projections. Obliquities 60°, 70°
/// and 75° (the claimed limit), the camera looking nearly along the board's long axis (15°)
/// and nearly along its short one (80°; not exactly along either, where the renderer's
/// supersampling of edges along pixel rows would dominate the error), the board filling 90 %
/// of the frame; and at the limit, a board filling 60 % (smaller far squares). Every board is
/// found complete, every corner within [`CORNER_TOL_PX`].
#[test]
fn boards_on_a_table_are_found_up_to_the_claimed_obliquity() {
    let cases = [
        (60.0, 15.0, 0.9),
        (70.0, 15.0, 0.9),
        (MAX_CLAIMED_OBLIQUITY_DEG, 15.0, 0.9),
        (60.0, 80.0, 0.9),
        (70.0, 80.0, 0.9),
        (MAX_CLAIMED_OBLIQUITY_DEG, 80.0, 0.9),
        (MAX_CLAIMED_OBLIQUITY_DEG, 40.0, 0.6),
    ];
    let mut failures = Vec::new();
    for (k, &(obliquity, azimuth, fill)) in cases.iter().enumerate() {
        let s = scene(obliquity, azimuth, fill);
        let (near, far) = square_sizes(&s);
        assert!(
            near / far >= MIN_NEAR_FAR_RATIO,
            "{obliquity}°/{azimuth}°: squares {near:.0} to {far:.0} px, not a grazing view"
        );
        let case = format!("obliquity {obliquity}°, azimuth {azimuth}°, fill {fill}");
        let Some(d) = render_and_detect(&s, 2900 + k as u64) else {
            failures.push(format!("{case}: no board"));
            continue;
        };
        let e = errors(&s, &d);
        let mean = e.iter().sum::<f64>() / e.len() as f64;
        let max = e.iter().copied().fold(0.0, f64::max);
        println!(
            "{case}: squares {near:.0} to {far:.0} px; {} corners, error mean {mean:.3} px, max {max:.3} px",
            d.corners.len()
        );
        if !d.complete || d.corners.len() != COLS * ROWS {
            failures.push(format!("{case}: {} of {} corners", d.corners.len(), COLS * ROWS));
        } else if max > CORNER_TOL_PX {
            failures.push(format!("{case}: a corner {max:.3} px from the truth"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Corners the detector must still report in each 80° view, for the mislabelling check
/// beyond the limit to check something (a detector that found no board there would pass it
/// vacuously): measured 67 and 68 of the 70 (the board incomplete: the thinnest far squares
/// lost). 60 leaves room for a few more far corners lost to a detector change, while a missed
/// board or a fragment of it fails. Not a claim of detection beyond the limit for users (the
/// doc of [`MAX_CLAIMED_OBLIQUITY_DEG`]), a floor on what this test exercises.
const MIN_CORNERS_AT_80_DEG: usize = 60;

/// Source of the expectations: the rendered corners. Beyond [`MAX_CLAIMED_OBLIQUITY_DEG`]
/// (80° and 85°, both turns of the board) no complete board is claimed, but a board that is
/// reported carries the right ids: every corner within [`SAME_CORNER_PX`] of the true corner
/// with its id. So that this checks corners at all, each 80° view reports at least
/// [`MIN_CORNERS_AT_80_DEG`] of them; at 85° the detector finds nothing (measured), and those
/// two views check only that no board with wrong ids is reported.
#[test]
fn beyond_the_claimed_obliquity_no_corner_is_mislabelled() {
    for (k, &(obliquity, azimuth)) in
        [(80.0, 15.0), (80.0, 80.0), (85.0, 15.0), (85.0, 80.0)].iter().enumerate()
    {
        assert!(obliquity > MAX_CLAIMED_OBLIQUITY_DEG);
        let s = scene(obliquity, azimuth, 0.9);
        let detection = render_and_detect(&s, 2950 + k as u64);
        let found = detection.as_ref().map_or(0, |d| d.corners.len());
        if obliquity <= 80.0 {
            assert!(
                found >= MIN_CORNERS_AT_80_DEG,
                "{obliquity}°/{azimuth}°: {found} corners reported, at least {MIN_CORNERS_AT_80_DEG} expected"
            );
        }
        let Some(d) = detection else {
            println!("obliquity {obliquity}°, azimuth {azimuth}°: no board");
            continue;
        };
        let e = errors(&s, &d);
        let max = e.iter().copied().fold(0.0, f64::max);
        println!(
            "obliquity {obliquity}°, azimuth {azimuth}°: {} corners (complete: {}), worst {max:.3} px",
            d.corners.len(),
            d.complete
        );
        assert!(max < SAME_CORNER_PX, "{obliquity}°/{azimuth}°: a corner {max:.2} px off its id");
    }
}
