//! Stage 5, final sub-pixel fit of the labelled corners: the junction fit
//! ([`Refinement::JunctionFit`], default) or `cornerSubPix` with a window sized to the local
//! grid step ([`Refinement::CornerSubPix`]).

use std::collections::HashMap;

use geometry::Image;
use nalgebra::Vector2;

use super::junction::fit_junction;
use super::label::{LabelledGrid, map};
use super::subpix::refine_corner;
use super::{DetectorParams, Refinement, SMALL_IMAGE_WIDTH};
use crate::Corner;

/// Final refinement window, half size as a fraction of the distance to the nearest grid
/// neighbour. Colour: 0.4 gives the lowest corner error on the rendered set (0.025 px vs
/// 0.042 px with OpenCV's fixed 11x11 window). IR: 0.2 keeps the real corners within
/// 0.13 px of the lab's Bouguet corners (9x9 window) while lowering the real-data RMS.
const FINAL_WINDOW_FRACTION_LARGE: f64 = 0.4;
const FINAL_WINDOW_FRACTION_SMALL: f64 = 0.2;
/// Junction-fit radius as a fraction of the distance to the nearest grid neighbour: the
/// circle stays clear of the neighbouring corners' edges (0.5 would touch them under blur).
const JUNCTION_FIT_FRACTION: f64 = 0.45;
/// Cap of the junction-fit radius, px (cost grows with its square).
const JUNCTION_FIT_MAX_RADIUS: f64 = 20.0;
/// Cap of the final window's half size, px.
const FINAL_WINDOW_MAX: usize = 20;

/// The labelled corners refined to their final positions, sorted by id.
pub(super) fn refine(img: &Image<f32>, l: &LabelledGrid, params: &DetectorParams) -> Vec<Corner> {
    let min_window = params.subpix_half_window;
    let pos: HashMap<(i32, i32), Vector2<f64>> = l.corners.iter().map(|c| (c.0, c.1)).collect();
    let hgrid = &l.hgrid;
    // A window fitted to the local grid step: more pixels average out more noise, and the
    // window stays clear of the neighbouring corners.
    let factor = if img.width() > SMALL_IMAGE_WIDTH {
        FINAL_WINDOW_FRACTION_LARGE
    } else {
        FINAL_WINDOW_FRACTION_SMALL
    };
    use rayon::prelude::*;
    let mut corners: Vec<Corner> = l
        .corners
        .par_iter()
        .map(|&((i, j), p, id)| {
            let step = [(1, 0), (-1, 0), (0, 1), (0, -1)]
                .iter()
                .filter_map(|(di, dj)| pos.get(&(i + di, j + dj)).map(|q| (q - p).norm()))
                .fold(f64::INFINITY, f64::min);
            let hw =
                (factor * step).floor().clamp(min_window as f64, FINAL_WINDOW_MAX as f64) as usize;
            let subpix = || {
                if hw > min_window {
                    refine_corner(img, p, hw).filter(|q| (q - p).norm() < 1.0).unwrap_or(p)
                } else {
                    p
                }
            };
            let dirs = [
                map(hgrid, i as f64 + 1.0, j as f64) - map(hgrid, i as f64, j as f64),
                map(hgrid, i as f64, j as f64 + 1.0) - map(hgrid, i as f64, j as f64),
            ];
            let radius = (JUNCTION_FIT_FRACTION * step).min(JUNCTION_FIT_MAX_RADIUS);
            let px = match params.refinement {
                // The fit converges from the first cornerSubPix estimate; the wide-window one
                // is only the fallback.
                Refinement::JunctionFit => {
                    fit_junction(img, p, dirs, radius).unwrap_or_else(subpix)
                }
                Refinement::CornerSubPix => subpix(),
            };
            Corner { id, px }
        })
        .collect();
    corners.sort_by_key(|c| c.id);
    corners
}
