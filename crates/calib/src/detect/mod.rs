//! Checkerboard detection with sub-pixel corners, built for the Kinect's IR images (low
//! resolution, saturated centre, dark edges) as well as 1080p colour.
//!
//! # Stages
//!
//! | # | stage | file | in → out |
//! |---|-------|------|----------|
//! | 1 | candidates | [`candidates`](candidates()) (`candidates.rs`) | image → ChESS response → local maxima |
//! | 2 | sub-pixel | [`refine_corner`] (`subpix.rs`) | each maximum → `cornerSubPix` position |
//! | 3 | grid | `grid.rs` | candidates → seed cell (sides checked on the image) → grid of rows and columns, trimmed to the board |
//! | 4 | labelling | `label.rs` | grid → board corner ids (or dropped when not certain) |
//! | 5 | final fit | `refine.rs`, [`fit_junction`] (`junction.rs`) | labelled corners → final positions |
//! | – | many views | `views.rs` | per-image detections → one colouring, stereo pairs aligned |
//!
//! 1. **Candidates**: the ChESS X-junction response on a ring of 16 samples (radius
//!    [`DetectorParams::ring_radius`]). It compares opposite and adjacent ring sectors, so it
//!    depends only on local contrast, not on the absolute brightness that the IR glare ruins;
//!    local maxima above a small fraction of the strongest response are kept. On images wider
//!    than 800 px it runs on the 2×2 box mean ([`DetectorParams::response_decimation`]), a
//!    quarter of the pixels; the maxima are refined on the full image. Smaller images try the
//!    box mean first and compute the full-resolution response only when that finds no
//!    complete board ([`DetectorParams::coarse_first`]).
//! 2. **Sub-pixel**: OpenCV's `cornerSubPix` normal equations (gradient ⟂ (corner − pixel),
//!    Gaussian-weighted window), iterated to 1e-4 px; the same estimator that Bouguet's
//!    toolbox uses.
//! 3. **Grid**: a seed cell (a corner, one of its nearest neighbours, the opposite one and a
//!    non-collinear pair) whose two steps the image shows to be a square's sides (the grey
//!    levels on either side of each step differ, with one sign all along it; under strong
//!    perspective a diagonal can be shorter than a side, so lengths do not tell them apart)
//!    grows breadth-first by predicting each neighbour from the previous
//!    corners of its row or column (the last step, turned and scaled as the one before it),
//!    repeated while a pass adds a corner; holes (a glare-washed corner) are allowed. Holes
//!    where the squares are narrower than the ChESS ring are filled by `cornerSubPix` at the
//!    predicted point.
//! 4. **Labelling**: the grid's extents are matched to the board's `cols × rows`, never
//!    mirrored; the colour of the squares fixes the offsets of a partial board and, where it
//!    can, the orientation; the rest follows the ordering rule below. A board whose labelling
//!    is not certain (a partial board whose offsets the colours do not fix) is dropped, never
//!    guessed.
//! 5. **Final sub-pixel fit** ([`Refinement::JunctionFit`], the default): the maximum-likelihood
//!    fit of a blurred X-junction model to every pixel within 0.45 grid steps
//!    ([`fit_junction`]), started from step 2 with the edge directions of the labelled grid.
//!    [`Refinement::CornerSubPix`] instead refines each corner again with `cornerSubPix` and a
//!    window sized to its local grid step (more pixels, less noise) and reproduces Bouguet's
//!    corners; it is also the junction fit's fallback.
//!
//! # Corner ordering rule
//!
//! Corner `k` is `(k mod cols, k div cols)` on the board (see [`Board`]): corner 0 is the inner
//! corner diagonal to the board's top-left square, the x axis runs along the `cols` corners, and
//! a labelling is never mirrored. A physical board can be labelled so in 2 ways, turned 180°
//! against each other (4 on a square board, in quarter turns). Which one is reported:
//!
//! * **Colour decides** where the turn changes the colour of the top-left square: boards with
//!   one even and one odd square count (`cols + rows` odd: OpenCV's 9x6 = 10x7 squares, 7x6,
//!   6x9, 10x7) and the quarter turns of a square board with an odd count (5x5). The top-left
//!   square is black ([`Board::top_left_black`] `Some(false)` asks for white): corner 0 is at
//!   the board's black corner square, the same physical corner in every view and in both
//!   cameras of a stereo pair, whatever the pose. (OpenCV's `findChessboardCornersSB` has no
//!   fixed rule here; compare its corners after turning them to this rule.)
//! * **Orientation decides** where the turn keeps the colouring (`cols + rows` even: 7x5 =
//!   8x6 squares, 8x6, 9x7; and the quarter turns of a square board with an even count): the
//!   images cannot tell the placements apart, so the detector reports the one whose x axis
//!   points most to the right in the image (measured at the grid's first corner). Two cameras
//!   could decide a board near the tie (x axis near vertical) differently; [`align_pair`]
//!   turns the colour view of a stereo pair to agree with the depth view.
//!
//! With the colouring unknown (`top_left_black: None`), [`detect_views`] takes it from the
//! complete detections (majority) and labels the partial ones again with it.

mod candidates;
mod grid;
mod junction;
mod label;
mod refine;
mod subpix;
mod views;

use std::time::{Duration, Instant};

use geometry::Image;

pub use candidates::{candidates, chess_response};
pub use junction::{fit_junction, fit_junction_with_std};
pub use subpix::refine_corner;
pub use views::{
    align_pair, common_grid_size, detect_views, detect_views_timed, detect_views_with,
    detect_views_with_progress, rotate_180,
};

use crate::{Board, Corner};

/// Tunables of [`detect`]. [`DetectorParams::for_image`] picks them from the image size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectorParams {
    /// ChESS ring radius, px. 5 is the ChESS paper's value for squares ≥ 15 px.
    pub ring_radius: usize,
    /// Half window of the sub-pixel refinement, px (OpenCV's `winSize`).
    pub subpix_half_window: usize,
    /// Candidates below this fraction of the strongest response are dropped.
    pub min_response_fraction: f32,
    /// The final sub-pixel estimator of the labelled corners.
    pub refinement: Refinement,
    /// 2: the ChESS response and its peaks are computed on the image's 2×2 box mean (with a
    /// ring of half the radius, rounded up), a quarter of the pixels; the peaks are then
    /// refined on the full image. 1: on the full image.
    pub response_decimation: usize,
    /// With `response_decimation` 1: look for the board first with the response on the 2×2
    /// box mean (as `response_decimation` 2 does), and compute the full-resolution response
    /// only when that finds no complete board (of two partial results, the one with more
    /// corners; on a tie the full-resolution one). Every corner is still refined on the full
    /// image, so a board found either way gets the same corners, up to where the junction
    /// fit's end point depends on its start (kinect-lab: mean ≤ 1e-3 px, worst 0.03 px).
    pub coarse_first: bool,
}

/// The final sub-pixel estimator of a labelled corner.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Refinement {
    /// [`fit_junction`]: the maximum-likelihood fit of a blurred X-junction (default). On the
    /// rendered set it has a third of `cornerSubPix`'s error (IR 0.023 px vs 0.061 px, colour
    /// 0.008 vs 0.025 px), and on the real kinect-lab IR views it lowers the calibration RMS
    /// from 0.249 px to 0.172 px; it is 0.21 px from Bouguet's corners there, which carry the
    /// toolbox estimator's own noise.
    #[default]
    JunctionFit,
    /// `cornerSubPix` / Bouguet's `cornerfinder` estimator with a window sized to the local
    /// grid step: reproduces the toolbox's corners (0.126 px from the lab's on kinect-lab),
    /// for comparisons with results computed by those tools.
    CornerSubPix,
}

impl DetectorParams {
    /// IR-sized images (≤ 800 px wide) use a 9×9 refinement window (OpenCV's (4,4), which
    /// reproduces the lab's Bouguet corners); larger images 11×11 with a wider ring.
    pub fn for_image(width: usize, _height: usize) -> Self {
        if width <= SMALL_IMAGE_WIDTH {
            Self {
                ring_radius: 5,
                subpix_half_window: 4,
                min_response_fraction: 0.04,
                refinement: Refinement::default(),
                response_decimation: 1,
                // The response and its peaks are two fifths of an IR image's detection (0.45 +
                // 0.14 of 1.69 ms, rendered IR bench image); on the box mean they take 0.20 ms.
                // At the Kinect's usual 0.5–1.5 m a 40 mm square spans 10–30 IR pixels, 5–15 at
                // half size, where the ring of radius 3 still fits. Smaller squares and
                // cut-off boards fall back to the full response (kinect-lab's three partial
                // views take both passes; on the box mean alone one of them lost a corner).
                coarse_first: true,
            }
        } else {
            Self {
                ring_radius: 7,
                subpix_half_window: 5,
                min_response_fraction: 0.04,
                refinement: Refinement::default(),
                // Squares of large images span ≥ 20 px (the ring of radius 7 needs them), so
                // they still span ≥ 10 px at half size: the response at a quarter of the cost.
                response_decimation: 2,
                coarse_first: false,
            }
        }
    }
}

/// Images up to this width are treated as IR-sized (Kinect IR: 512).
const SMALL_IMAGE_WIDTH: usize = 800;

/// A detected board: the labelled corners (a subset for partial boards).
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Labelled corners, sorted by id.
    pub corners: Vec<Corner>,
    /// True when every corner of the board was found.
    pub complete: bool,
    /// The board colouring this labelling assumed (see [`Board::top_left_black`]).
    pub top_left_black: bool,
}

/// Detects the board in a grey image (0–255 values).
pub fn detect(img: &Image<f32>, board: &Board, params: &DetectorParams) -> Option<Detection> {
    detect_timed(img, board, params).0
}

/// Wall-clock time spent in each stage of one [`detect`] call (for the benchmarks and the
/// `detect_stages` example; a stage not reached is zero).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimes {
    /// Stage 1a: the ChESS response over the whole image (decimated where
    /// [`DetectorParams::response_decimation`] says so).
    pub response: Duration,
    /// Stage 1b: local maxima of the response (threshold, non-maximum suppression, sorting).
    pub peaks: Duration,
    /// Stage 2: `cornerSubPix` of every peak, duplicates merged.
    pub subpix: Duration,
    /// Stage 3: grid growing, the larger-board checks, trimming and the smoothness check.
    pub grid: Duration,
    /// Stage 4: labelling.
    pub label: Duration,
    /// Stage 5: the final sub-pixel fit of the labelled corners.
    pub refine: Duration,
}

impl StageTimes {
    /// Sum of the stages.
    pub fn total(&self) -> Duration {
        self.response + self.peaks + self.subpix + self.grid + self.label + self.refine
    }
}

impl std::ops::AddAssign for StageTimes {
    /// Stage by stage (a detection that ran twice, see [`DetectorParams::coarse_first`]).
    fn add_assign(&mut self, o: Self) {
        self.response += o.response;
        self.peaks += o.peaks;
        self.subpix += o.subpix;
        self.grid += o.grid;
        self.label += o.label;
        self.refine += o.refine;
    }
}

/// [`detect`], also returning the time spent in each stage (summed over both passes where
/// [`DetectorParams::coarse_first`] needed the second).
pub fn detect_timed(
    img: &Image<f32>,
    board: &Board,
    params: &DetectorParams,
) -> (Option<Detection>, StageTimes) {
    // Called from outside rayon's pool (one image, not `detect_views`): the detection moves
    // onto a pool thread (`rayon::scope` runs its closure there), so that its stages' parallel
    // loops split their work in the pool instead of each handing it over from this thread and
    // sleeping until it is done (three or four hand-offs per image). IR bench image, one
    // thread, minimum of 500 runs: 0.98–0.99 → 0.89–0.92 ms, the same corners (2026-12-02).
    if rayon::current_thread_index().is_none() {
        return rayon::scope(|_| detect_timed(img, board, params));
    }
    if !(params.coarse_first && params.response_decimation == 1) {
        return detect_pass(img, board, params);
    }
    let coarse = DetectorParams { response_decimation: 2, coarse_first: false, ..*params };
    let (first, mut t) = detect_pass(img, board, &coarse);
    if first.as_ref().is_some_and(|d| d.complete) {
        return (first, t);
    }
    let full = DetectorParams { coarse_first: false, ..*params };
    let (second, t2) = detect_pass(img, board, &full);
    t += t2;
    // The full pass is the reference; the coarse one only where it found more corners.
    let corners = |d: &Option<Detection>| d.as_ref().map_or(0, |d| d.corners.len());
    (if corners(&first) > corners(&second) { first } else { second }, t)
}

/// One detection with the response at `params.response_decimation`'s scale.
fn detect_pass(
    img: &Image<f32>,
    board: &Board,
    params: &DetectorParams,
) -> (Option<Detection>, StageTimes) {
    let mut t = StageTimes::default();
    let mut clock = Instant::now();
    let mut lap = |d: &mut Duration| {
        let now = Instant::now();
        *d = now - clock;
        clock = now;
    };
    let resp = candidates::response(img, params);
    lap(&mut t.response);
    let peaks = candidates::peaks(&resp, params);
    candidates::recycle(resp);
    lap(&mut t.peaks);
    let mut pts = candidates::refine_peaks(img, &peaks, params);
    lap(&mut t.subpix);
    if pts.len() < 4 {
        return (None, t);
    }
    let grid = grid_for_board(img, board, &mut pts, params);
    lap(&mut t.grid);
    let Some(grid) = grid else { return (None, t) };
    let labelled = label::label(img, board, &pts, &grid);
    lap(&mut t.label);
    let Some(labelled) = labelled else { return (None, t) };
    let corners = refine::refine(img, &labelled, params);
    lap(&mut t.refine);
    let complete = corners.len() == board.len();
    (Some(Detection { corners, complete, top_left_black: labelled.top_left_black }), t)
}

/// Stage 3: the board-sized grid of the candidates, or `None` when there is none or the image
/// shows a larger board. Corners found in the grid's holes are appended to `pts`.
fn grid_for_board(
    img: &Image<f32>,
    board: &Board,
    pts: &mut Vec<(nalgebra::Vector2<f64>, f32)>,
    params: &DetectorParams,
) -> Option<grid::Grid> {
    let found = grid::largest(img, pts, board.len())?;
    if shows_larger_board(img, board, pts, &found) {
        return None;
    }
    let grid = grid::trim(board, pts, found.clone());
    // Trimming drops junctions where the board's border meets the background or clutter next
    // to it; a whole line of corners next to the board-sized window, as long as the window,
    // is a larger board, and its sub-grid is never reported.
    if grid::full_line_beside(&found, &grid) {
        return None;
    }
    let mut grid = grid;
    grid::fill_holes(img, pts, &mut grid, params.ring_radius);
    // A corner grown into the wrong row or column (a strong lens bends the grid past the
    // growth's prediction) would be labelled wrongly: such a grid is dropped, never guessed.
    if !grid::is_smooth(pts, &grid) {
        return None;
    }
    Some(grid)
}

/// True when `grid` is a complete checkerboard (every corner present, colours checked) with
/// more corners along an axis than `board` allows: the image shows a larger board, and
/// labelling a board-sized window of it would calibrate on a sub-grid.
fn shows_larger_board(
    img: &Image<f32>,
    board: &Board,
    pts: &[(nalgebra::Vector2<f64>, f32)],
    grid: &grid::Grid,
) -> bool {
    let (ni, nj) = grid::extents(grid);
    let (a, b) = (ni.max(nj) as usize, ni.min(nj) as usize);
    let fits = a <= board.cols.max(board.rows) && b <= board.cols.min(board.rows);
    !fits && complete_board(img, pts, grid).is_some()
}

/// The inner-corner counts `(larger, smaller)` of `grid` when it is a complete checkerboard:
/// no corner missing and the squares' colours those of a board of its size.
fn complete_board(
    img: &Image<f32>,
    pts: &[(nalgebra::Vector2<f64>, f32)],
    grid: &grid::Grid,
) -> Option<(usize, usize)> {
    let (ni, nj) = grid::extents(grid);
    if ni < 2 || nj < 2 || grid.len() != (ni * nj) as usize {
        return None;
    }
    let (a, b) = (ni.max(nj) as usize, ni.min(nj) as usize);
    let whole = Board::new(a, b, 1.0).ok()?;
    label::label(img, &whole, pts, grid).map(|_| (a, b))
}

/// The inner-corner counts `(larger, smaller)` of the largest complete checkerboard in the
/// image, whatever its size (for `--board auto` and for saying what the images show when the
/// board given does not match); `None` when there is none.
pub fn grid_size(img: &Image<f32>, params: &DetectorParams) -> Option<(usize, usize)> {
    let mut pts = candidates(img, params);
    if pts.len() < 4 {
        return None;
    }
    let grid = grid::largest(img, &pts, usize::MAX)?;
    // Junctions where the board's border meets the background line up with the grid as a
    // partial extra line (11 of OpenCV's 13 left samples): without them the board is complete.
    // Holes are filled as detection with a known size fills them (one GoPro view).
    let peeled = grid::peel_partial_lines(&grid);
    for mut g in [grid, peeled] {
        grid::fill_holes(img, &mut pts, &mut g, params.ring_radius);
        if let Some(size) = complete_board(img, &pts, &g) {
            return Some(size);
        }
    }
    None
}

/// Converts an 8-bit grey image to the detector's input.
pub fn to_f32(img: &Image<u8>) -> Image<f32> {
    img.map(|&v| v as f32)
}
