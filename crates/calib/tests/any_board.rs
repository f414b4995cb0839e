//! Any board: every inner-corner count from 3x3 to 16x12, both parities, landscape and
//! portrait, rendered by the tests' own renderer (`common/render.rs`) at random poses (any
//! in-plane rotation, tilt up to 35°), blur and noise, is found without being told the board's
//! colouring, and every corner carries the id that the documented ordering rule gives it
//! (`calib::detect` module docs): zero mislabelled corners.
//!
//! `KFUSE_ANY_BOARD_POSES=N` renders N poses per size instead of 1 (the default keeps the test
//! at a few seconds).

mod common;

use calib::Board;
use calib::detect::{DetectorParams, detect, to_f32};
use common::render::{Scene, random_pose};
use geometry::{Distortion, Intrinsics};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A detected corner counts as carrying the right id when it lies within this distance of
/// that id's true position: the detector's corner error on such renders is ~0.05 px and the
/// nearest other corner is at least ~10 px away, so 1.5 px cannot confuse two corners.
const SAME_CORNER_PX: f64 = 1.5;
/// Where the board's x axis is within this (as the x component of its unit image direction)
/// of the direction of another labelling's x axis, the rule's choice is a tie that the
/// detector's finite grid can decide either way; both are accepted there (and counted).
const TIE: f64 = 0.3;
/// Square size (px, fronto-parallel) the image size is chosen for: 16x12 boards (17x13
/// squares and the margin) fill a 640x480 image at it; tilt shortens squares by up to
/// cos 35° (to ~14 px), still above the ChESS ring's needs.
const PX_PER_SQUARE: f64 = 17.0;
/// Fraction of the image's shorter side that the board's diagonal (margin included) spans.
const FILL: f64 = 0.85;
/// Largest tilt of the board about either in-plane axis, degrees.
const MAX_TILT_DEG: f64 = 35.0;

/// The labellings that the ordering rule allows for a board of `cols × rows` inner corners
/// whose top-left square has colour `black`: the board's rotations that map its corner grid onto
/// itself (180° always, 90° when square), each with the top-left colour it implies; black
/// preferred; then the x axis pointing most to the right, ties within [`TIE`] all accepted.
/// Each labelling is a map from the rendered board's corner id to the expected id.
fn expected_labellings(s: &Scene) -> Vec<Vec<usize>> {
    let (c, r) = (s.cols, s.rows);
    let n = c * r;
    // Rotation k·90° as an id permutation and whether it flips the top-left colour.
    let mut rots: Vec<(Vec<usize>, bool)> = vec![((0..n).collect(), false)];
    rots.push((
        (0..n).map(|id| (r - 1 - id / c) * c + (c - 1 - id % c)).collect(),
        (c + r) % 2 == 1,
    ));
    if c == r {
        // (x, y) → (c−1−y, x) and its inverse; the top-left square moves to a corner square
        // whose colour differs iff the side has an odd number of inner corners.
        rots.push(((0..n).map(|id| (id % c) * c + (c - 1 - id / c)).collect(), c % 2 == 1));
        rots.push(((0..n).map(|id| (c - 1 - id % c) * c + id / c).collect(), c % 2 == 1));
    }
    let black: Vec<bool> = rots.iter().map(|(_, flip)| s.top_left_black != *flip).collect();
    let any_black = black.iter().any(|&b| b);
    let mut cand: Vec<(Vec<usize>, f64)> = rots
        .into_iter()
        .zip(black)
        .filter(|(_, b)| *b == any_black)
        .map(|((perm, _), _)| {
            // Image direction of the new x axis at the board centre: new corner (x, y) is the old
            // corner perm⁻¹; step from the new centre to its +x neighbour.
            let inv = |new: usize| perm.iter().position(|&p| p == new).unwrap();
            let (cx, cy) = (c / 2, r / 2);
            let a = s.corner(inv(cy * c + cx.min(c - 2)));
            let b = s.corner(inv(cy * c + cx.min(c - 2) + 1));
            ((perm.clone()), (b - a).normalize().x)
        })
        .collect();
    cand.sort_by(|a, b| b.1.total_cmp(&a.1));
    let best = cand[0].1;
    cand.into_iter().filter(|c| c.1 >= best - TIE).map(|c| c.0).collect()
}

struct Outcome {
    found: bool,
    mislabelled: usize,
    tie: bool,
}

/// A `cols × rows` board at a random pose, blur and noise (seeded), in an image sized to it,
/// with the scene that rendered it.
fn render_case(cols: usize, rows: usize, seed: u64) -> (Scene, geometry::Image<u8>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    // The image just large enough for squares of about PX_PER_SQUARE px (a 4:3 frame, at most
    // 640x480): small boards in small images keep the test at a few seconds.
    let diag = (((cols + 3) * (cols + 3) + (rows + 3) * (rows + 3)) as f64).sqrt();
    let h = ((diag * PX_PER_SQUARE / FILL).round() as usize).clamp(160, 480);
    let w = h * 4 / 3;
    let f = 1.1 * w as f64;
    let (r, t) = random_pose(&mut rng, cols, rows, (w, h, f), MAX_TILT_DEG, FILL);
    let scene = Scene {
        width: w,
        height: h,
        cols,
        rows,
        top_left_black: rng.random_bool(0.5),
        k: Intrinsics::new(f, f, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0),
        dist: Distortion::from_array([0.0; 5]),
        r,
        t,
        blur: rng.random_range(0.4..1.2),
        noise: rng.random_range(0.0..4.0),
        background: rng.random_range(60.0..160.0),
    };
    let img = scene.render(&mut rng);
    (scene, img)
}

fn run_case(cols: usize, rows: usize, seed: u64) -> Outcome {
    let (scene, img) = render_case(cols, rows, seed);
    let (w, h) = (img.width(), img.height());
    let board = Board::new(cols, rows, 1.0).unwrap();
    let Some(d) = detect(&to_f32(&img), &board, &DetectorParams::for_image(w, h)) else {
        return Outcome { found: false, mislabelled: 0, tie: false };
    };
    let allowed = expected_labellings(&scene);
    // Under labelling `perm`, expected id e = perm[true id]; so true id = perm⁻¹[e].
    let wrong = |perm: &Vec<usize>| {
        d.corners
            .iter()
            .filter(|c| {
                let truth = perm.iter().position(|&p| p == c.id).unwrap();
                (c.px - scene.corner(truth)).norm() > SAME_CORNER_PX
            })
            .count()
    };
    let mislabelled = allowed.iter().map(wrong).min().unwrap();
    let complete = d.complete && d.corners.len() == cols * rows;
    Outcome { found: complete, mislabelled, tie: allowed.len() > 1 }
}

#[test]
fn every_board_size_and_parity_is_labelled_by_the_rule() {
    let poses: u64 = std::env::var("KFUSE_ANY_BOARD_POSES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1)
        .clamp(1, 1000);
    let mut sizes = Vec::new();
    for a in 3..=16usize {
        for b in 3..=12usize {
            sizes.push((a, b));
            if a > 12 {
                sizes.push((b, a)); // portrait beyond the landscape range
            }
        }
    }
    let cases: Vec<(usize, usize, u64)> = sizes
        .iter()
        .flat_map(|&(c, r)| (0..poses).map(move |p| (c, r, (c * 1000 + r) as u64 * 7919 + p)))
        .collect();
    use rayon::prelude::*;
    let out: Vec<((usize, usize, u64), Outcome)> =
        cases.par_iter().map(|&(c, r, s)| ((c, r, s), run_case(c, r, s))).collect();
    let missed: Vec<_> = out.iter().filter(|o| !o.1.found).map(|o| o.0).collect();
    let wrong: Vec<_> =
        out.iter().filter(|o| o.1.mislabelled > 0).map(|o| (o.0, o.1.mislabelled)).collect();
    let ties = out.iter().filter(|o| o.1.tie).count();
    let (odd, even) = out.iter().fold((0, 0), |acc, o| {
        if (o.0.0 + o.0.1) % 2 == 1 { (acc.0 + 1, acc.1) } else { (acc.0, acc.1 + 1) }
    });
    println!(
        "{} cases ({} sizes x {poses} poses; {odd} colour-decided, {even} 180°-symmetric): \
         {} not found, {} with mislabelled corners, {ties} orientation ties",
        out.len(),
        sizes.len(),
        missed.len(),
        wrong.len()
    );
    assert!(wrong.is_empty(), "mislabelled corners (cols, rows, seed), count: {wrong:?}");
    assert!(missed.is_empty(), "boards not found completely (cols, rows, seed): {missed:?}");
}

/// A board with an even and an odd square count (OpenCV's 9x6) rendered once with a black and
/// once with a white top-left square, same pose: detected without a colour given, corner 0 is
/// at the black corner square both times — the origin of the first rendering and the far end
/// (rendered corner 53) of the second.
#[test]
fn colour_decided_boards_start_at_the_black_corner_square() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let (r, t) = random_pose(&mut rng, 9, 6, (640, 480, 700.0), 20.0, 0.8);
    let mk = |black: bool| Scene {
        width: 640,
        height: 480,
        cols: 9,
        rows: 6,
        top_left_black: black,
        k: Intrinsics::new(700.0, 700.0, 319.5, 239.5),
        dist: Distortion::from_array([0.0; 5]),
        r,
        t,
        blur: 0.7,
        noise: 1.0,
        background: 100.0,
    };
    let board = Board::new(9, 6, 1.0).unwrap();
    for (black, truth_of_0) in [(true, 0), (false, 53)] {
        let s = mk(black);
        let d = detect(&to_f32(&s.render(&mut rng)), &board, &DetectorParams::for_image(640, 480))
            .expect("found");
        assert!(d.complete && d.top_left_black);
        let c0 = d.corners.iter().find(|c| c.id == 0).unwrap().px;
        let err = (c0 - s.corner(truth_of_0)).norm();
        assert!(err < SAME_CORNER_PX, "top-left black {black}: corner 0 {err} px from truth");
    }
}

/// Tolerance: none. A detection gives the same corners to the bit whether it is called from
/// outside rayon's pool (it then moves onto a pool thread) or inside one, and after detections
/// of larger and smaller images on the same threads, whose buffers it reuses.
#[test]
fn detection_is_the_same_from_any_thread_and_after_other_images() {
    let cases = [(9, 6, 11), (16, 12, 12), (3, 3, 13)];
    let images: Vec<_> = cases.iter().map(|&(c, r, seed)| render_case(c, r, seed).1).collect();
    let detect_case = |k: usize| {
        let (c, r, _) = cases[k];
        let img = &images[k];
        let board = Board::new(c, r, 1.0).unwrap();
        let d = detect(&to_f32(img), &board, &DetectorParams::for_image(img.width(), img.height()))
            .unwrap_or_else(|| panic!("{c}x{r}: no board"));
        d.corners.iter().map(|c| (c.id, c.px.x.to_bits(), c.px.y.to_bits())).collect::<Vec<_>>()
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
    let first = detect_case(0);
    assert_eq!(first.len(), 54);
    assert_eq!(pool.install(|| detect_case(0)), first, "inside a pool");
    for k in [1, 2] {
        detect_case(k);
        pool.install(|| detect_case(k));
    }
    assert_eq!(detect_case(0), first, "after other images");
    assert_eq!(pool.install(|| detect_case(0)), first, "inside a pool, after other images");
}
