//! Many views: the board's colouring taken from the complete detections, and the labelling of
//! a stereo pair made to agree.

use geometry::Image;
use geometry::timing::ms_since;
use nalgebra::{Vector2, Vector3};

use super::label::{rotate, rotations};
use super::{Detection, DetectorParams, Refinement, detect, grid_size, to_f32};
use crate::zhang::homography;
use crate::{Board, ViewCorners};

/// Detects the board in one camera's images and packs the results as [`ViewCorners`] (no
/// corners where the board is not found). When the board's colouring is unknown, it is taken
/// from the complete detections (majority) and the images are labelled again with it, so that
/// partial boards cannot pick the other colouring.
pub fn detect_views(images: &[(String, &Image<u8>)], board: &Board) -> (Vec<ViewCorners>, Board) {
    detect_views_with(images, board, Refinement::default(), &|| {})
}

/// [`detect_views`] calling `progress` once per image of the first pass (for progress bars).
pub fn detect_views_with_progress(
    images: &[(String, &Image<u8>)],
    board: &Board,
    progress: &(dyn Fn() + Sync),
) -> (Vec<ViewCorners>, Board) {
    detect_views_with(images, board, Refinement::default(), progress)
}

/// [`detect_views_with_progress`] with a chosen final sub-pixel estimator.
pub fn detect_views_with(
    images: &[(String, &Image<u8>)],
    board: &Board,
    refinement: Refinement,
    progress: &(dyn Fn() + Sync),
) -> (Vec<ViewCorners>, Board) {
    let (views, board, _) = detect_views_timed(images, board, refinement, progress);
    (views, board)
}

/// [`detect_views_with`] with each image's detection time, ms (its pool thread's wall time,
/// both passes when the colouring made a second one necessary; images run in parallel, so the
/// sum can exceed the call's wall time).
pub fn detect_views_timed(
    images: &[(String, &Image<u8>)],
    board: &Board,
    refinement: Refinement,
    progress: &(dyn Fn() + Sync),
) -> (Vec<ViewCorners>, Board, Vec<f64>) {
    let params = |img: &Image<u8>| DetectorParams {
        refinement,
        ..DetectorParams::for_image(img.width(), img.height())
    };
    use rayon::prelude::*;
    let timed = |img: &Image<u8>, board: &Board| {
        let t = std::time::Instant::now();
        let d = detect(&to_f32(img), board, &params(img));
        (d, ms_since(t))
    };
    let first = |board: &Board| -> Vec<(Option<Detection>, f64)> {
        images
            .par_iter()
            .map(|(_, img)| {
                let d = timed(img, board);
                progress();
                d
            })
            .collect()
    };
    // The second pass: only the images whose detection the colouring can change.
    let run = |board: &Board, again: &[usize]| -> Vec<(Option<Detection>, f64)> {
        again.par_iter().map(|&i| timed(images[i].1, board)).collect()
    };
    let (mut dets, mut ms): (Vec<Option<Detection>>, Vec<f64>) = first(board).into_iter().unzip();
    let mut board = *board;
    if board.top_left_black.is_none() {
        let complete: Vec<bool> =
            dets.iter().flatten().filter(|d| d.complete).map(|d| d.top_left_black).collect();
        if !complete.is_empty() {
            let black = 2 * complete.iter().filter(|&&b| b).count() >= complete.len();
            board.top_left_black = Some(black);
            // A complete detection of this colouring is labelled alike with the colouring
            // known (the labelling only drops the other colouring's placements, and its
            // choice was among the rest), so only the others are detected again: on the
            // lab's 12 IR images (4 partial or without a board) that was all 12 before.
            let again: Vec<usize> = (0..dets.len())
                .filter(|&i| {
                    !dets[i].as_ref().is_some_and(|d| d.complete && d.top_left_black == black)
                })
                .collect();
            if !again.is_empty() {
                for (&i, (d, t)) in again.iter().zip(run(&board, &again)) {
                    dets[i] = d;
                    ms[i] += t;
                }
            }
        }
    }
    let views = images
        .iter()
        .zip(dets)
        .map(|((name, img), d)| ViewCorners {
            name: name.clone(),
            width: img.width(),
            height: img.height(),
            corners: d.map(|d| d.corners).unwrap_or_default(),
            unusable: None,
        })
        .collect();
    (views, board, ms)
}

/// The inner-corner counts `(larger, smaller)` of the complete board that most images show
/// (the larger size on a tie), with how many images show it; `None` when no image shows a
/// complete board. For `--board auto`, and to say what the images show when the board given
/// is not found.
pub fn common_grid_size(images: &[(String, &Image<u8>)]) -> Option<((usize, usize), usize)> {
    use rayon::prelude::*;
    let sizes: Vec<(usize, usize)> = images
        .par_iter()
        .filter_map(|(_, img)| {
            grid_size(&to_f32(img), &DetectorParams::for_image(img.width(), img.height()))
        })
        .collect();
    let mut counts: Vec<((usize, usize), usize)> = Vec::new();
    for s in sizes {
        match counts.iter_mut().find(|c| c.0 == s) {
            Some(c) => c.1 += 1,
            None => counts.push((s, 1)),
        }
    }
    counts.into_iter().max_by_key(|&((a, b), n)| (n, a * b))
}

/// Relabels a view by the board's 180° rotation (`(x, y) → (cols−1−x, rows−1−y)`).
pub fn rotate_180(view: &ViewCorners, board: &Board) -> ViewCorners {
    rotate_view(view, board, 2)
}

/// Relabels a view by `k` quarter turns of the board (`k` odd only for square boards).
fn rotate_view(view: &ViewCorners, board: &Board, k: u8) -> ViewCorners {
    let (c, r) = (board.cols as i32, board.rows as i32);
    let mut out = view.clone();
    for corner in &mut out.corners {
        let (x, y) = ((corner.id % board.cols) as i32, (corner.id / board.cols) as i32);
        let (x, y) = rotate(k, c, r, (x, y));
        corner.id = (y * c + x) as usize;
    }
    out.corners.sort_by_key(|c| c.id);
    out
}

/// Direction of the board's x axis in the image (unit vector), from the corners.
fn x_axis(view: &ViewCorners, board: &Board) -> Option<Vector2<f64>> {
    let plane: Vec<Vector2<f64>> =
        view.corners.iter().map(|c| board.object_point(c.id).xy()).collect();
    let pix: Vec<Vector2<f64>> = view.corners.iter().map(|c| c.px).collect();
    let h = homography(&plane, &pix)?;
    let c = h * Vector3::new(
        0.5 * board.square_m * board.cols as f64,
        0.5 * board.square_m * board.rows as f64,
        1.0,
    );
    let d = h * Vector3::new(
        0.5 * board.square_m * board.cols as f64 + board.square_m,
        0.5 * board.square_m * board.rows as f64,
        1.0,
    );
    let v = Vector2::new(d.x / d.z - c.x / c.z, d.y / d.z - c.y / c.z);
    Some(v.normalize())
}

/// Makes the labelling of a colour view agree with its depth/IR partner. Where the board's
/// colouring is unchanged by a turn (180° when `cols + rows` is even, e.g. 7x5; 90° too on a
/// square board with an even count), each camera picks its placement by orientation and the
/// two could differ for a board near the tie; the cameras are not rotated against each other
/// by more than a few degrees, so the colour view is turned (by such a turn only) to make its
/// x axis point the depth view's way. Boards whose colour decides (one even and one odd
/// square count, e.g. 9x6) are labelled alike by both cameras already and left as they are.
pub fn align_pair(depth: &ViewCorners, color: &ViewCorners, board: &Board) -> ViewCorners {
    let Some(a) = x_axis(depth, board) else { return color.clone() };
    let (c, r) = (board.cols as i32, board.rows as i32);
    let mut best = (f64::NEG_INFINITY, color.clone());
    for (k, flips) in rotations(c, r) {
        if flips {
            continue;
        }
        let turned = rotate_view(color, board, k);
        if let Some(b) = x_axis(&turned, board) {
            let score = a.dot(&b);
            if score > best.0 {
                best = (score, turned);
            }
        }
    }
    best.1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Corner;

    /// A view of `board` whose corner `(x, y)` is at pixel `(100 + 20·x', 80 + 20·y')` with
    /// `(x', y')` the corner turned by `k` quarter turns: the camera sees the board upright,
    /// the labelling differs from the upright one by the turn.
    fn view(board: &Board, k: u8) -> ViewCorners {
        let (c, r) = (board.cols as i32, board.rows as i32);
        let corners = (0..board.len())
            .map(|id| {
                let (x, y) = rotate(k, c, r, ((id % board.cols) as i32, (id / board.cols) as i32));
                Corner { id, px: Vector2::new(100.0 + 20.0 * x as f64, 80.0 + 20.0 * y as f64) }
            })
            .collect();
        ViewCorners { name: "v".into(), width: 640, height: 480, corners, unusable: None }
    }

    /// Source of the expectations: the ordering rule in the module docs. A colour-symmetric
    /// board (7x5) labelled 180° apart in the two cameras is turned to agree; a colour-decided
    /// board (9x6) is never turned (colour already fixed the same physical corner in both
    /// cameras, whatever the orientation); an even square board (4x4) is turned by the quarter
    /// turn that makes the x axes agree; an odd square board (5x5) by 180° (a quarter turn would
    /// change its colour).
    #[test]
    fn align_pair_turns_only_where_colour_cannot_decide() {
        let same = |a: &ViewCorners, b: &ViewCorners| {
            a.corners.iter().zip(&b.corners).all(|(p, q)| p.id == q.id && p.px == q.px)
        };
        let b75 = Board::new(7, 5, 1.0).unwrap();
        let depth = view(&b75, 0);
        assert!(same(&align_pair(&depth, &view(&b75, 2), &b75), &depth));
        let b96 = Board::new(9, 6, 1.0).unwrap();
        let turned = view(&b96, 2);
        assert!(same(&align_pair(&view(&b96, 0), &turned, &b96), &turned));
        let b44 = Board::new(4, 4, 1.0).unwrap();
        let depth = view(&b44, 0);
        for k in 1..4 {
            assert!(same(&align_pair(&depth, &view(&b44, k), &b44), &depth), "4x4, {k} turns");
        }
        let b55 = Board::new(5, 5, 1.0).unwrap();
        let depth = view(&b55, 0);
        assert!(same(&align_pair(&depth, &view(&b55, 2), &b55), &depth));
    }
}
