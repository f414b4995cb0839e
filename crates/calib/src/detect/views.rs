//! Many views: the board's colouring taken from the complete detections, and the labelling of
//! a stereo pair made to agree.

use geometry::Image;
use nalgebra::{Vector2, Vector3};

use super::{Detection, DetectorParams, Refinement, detect, to_f32};
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
    let params = |img: &Image<u8>| DetectorParams {
        refinement,
        ..DetectorParams::for_image(img.width(), img.height())
    };
    use rayon::prelude::*;
    let first = |board: &Board| -> Vec<Option<Detection>> {
        images
            .par_iter()
            .map(|(_, img)| {
                let d = detect(&to_f32(img), board, &params(img));
                progress();
                d
            })
            .collect()
    };
    let run = |board: &Board| -> Vec<Option<Detection>> {
        images.par_iter().map(|(_, img)| detect(&to_f32(img), board, &params(img))).collect()
    };
    let mut dets = first(board);
    let mut board = *board;
    if board.top_left_black.is_none() {
        let complete: Vec<bool> =
            dets.iter().flatten().filter(|d| d.complete).map(|d| d.top_left_black).collect();
        if !complete.is_empty() {
            let black = 2 * complete.iter().filter(|&&b| b).count() >= complete.len();
            board.top_left_black = Some(black);
            if dets.iter().flatten().any(|d| d.top_left_black != black || !d.complete) {
                dets = run(&board);
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
        })
        .collect();
    (views, board)
}

/// Relabels a view by the board's 180° rotation (`(x, y) → (cols−1−x, rows−1−y)`).
pub fn rotate_180(view: &ViewCorners, board: &Board) -> ViewCorners {
    let mut out = view.clone();
    for c in &mut out.corners {
        let (x, y) = (c.id % board.cols, c.id / board.cols);
        c.id = (board.rows - 1 - y) * board.cols + (board.cols - 1 - x);
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

/// Makes the labelling of a colour view agree with its depth/IR partner: on a board whose
/// colouring is symmetric under 180° (odd × odd inner corners), the two cameras could pick
/// opposite origins for a board near 90°; the cameras are not rotated against each other by
/// more than a few degrees, so the x axes must point the same way.
pub fn align_pair(depth: &ViewCorners, color: &ViewCorners, board: &Board) -> ViewCorners {
    if !(board.cols + board.rows).is_multiple_of(2) {
        return color.clone();
    }
    match (x_axis(depth, board), x_axis(color, board)) {
        (Some(a), Some(b)) if a.dot(&b) < 0.0 => rotate_180(color, board),
        _ => color.clone(),
    }
}
