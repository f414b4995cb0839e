//! Stage 4, labelling: maps the grid's coordinates to board corner ids. The grid's extents are
//! matched to the board's `cols × rows`, never mirrored; the colour of the squares fixes the
//! offsets of a partial board and, where it can, the orientation (the ordering rule is in the
//! module docs).

use std::collections::HashMap;

use geometry::Image;
use nalgebra::{Matrix3, Vector2, Vector3};

use super::grid::Grid;
use super::subpix::bilinear;
use crate::Board;
use crate::zhang::homography;

/// Fewest corners for a partial board to be reported (a homography needs 4; 6 gives slack).
const MIN_PARTIAL_CORNERS: usize = 6;
/// Fraction of cells whose colour must agree with the checker pattern.
const MIN_CHECKER_AGREEMENT: f64 = 0.8;
/// Least mean grey-level difference (0–255) between a grid's inner cells and their neighbours
/// for the cells to be a board's squares. The other checks are relative to the image's own
/// contrast, so in a smooth background JPEG's blocking (1–3 levels at quality 90) lines up
/// into a small "grid" whose cells alternate by chance: measured 1.5–2.7 levels on such false
/// grids of the simulated ring's colour shots, where one of them was labelled as six corners
/// of a board and broke the joint calibration. Real boards measured (the same metric, every
/// detection): ≥ 93 levels in the four calib-corpus sets, ≥ 213 in the lab's IR frames, ≥ 50
/// for a partial board in the simulator's IR. 10 levels is ~4× above the noise and 5× under
/// the weakest board.
const MIN_SQUARE_CONTRAST: f64 = 10.0;

/// A grid whose corners have board ids.
pub(super) struct LabelledGrid {
    /// Every corner: grid coordinates (0-based), pixel position, board id.
    pub corners: Vec<((i32, i32), Vector2<f64>, usize)>,
    /// Homography grid coordinates → image.
    pub hgrid: Matrix3<f64>,
    /// The board colouring the labelling assumed.
    pub top_left_black: bool,
}

/// Image point of grid (or board) coordinates `(x, y)` under homography `h`.
pub(super) fn map(h: &Matrix3<f64>, x: f64, y: f64) -> Vector2<f64> {
    let q = h * Vector3::new(x, y, 1.0);
    Vector2::new(q.x / q.z, q.y / q.z)
}

/// Mean intensity around a point (3x3 bilinear samples, 1 px apart).
fn sample_mean(img: &Image<f32>, p: Vector2<f64>) -> f64 {
    let mut s = 0.0;
    for dy in -1..=1 {
        for dx in -1..=1 {
            s += bilinear(img, p.x + dx as f64, p.y + dy as f64);
        }
    }
    s / 9.0
}

/// One way to put the grid on the board: axis assignment, signs, offsets and colouring.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Cand {
    black: bool,
    swap: bool,
    si: i32,
    sj: i32,
    ox: i32,
    oy: i32,
}

impl Cand {
    /// Board corner coordinates of grid corner `(i, j)` on a grid of `ni × nj` corners.
    fn board_corner(&self, ni: i32, nj: i32, i: i32, j: i32) -> (i32, i32) {
        let (a, b) = if self.swap { (j, i) } else { (i, j) };
        let (ea, eb) = if self.swap { (nj, ni) } else { (ni, nj) };
        let bx = if self.si > 0 { a } else { ea - 1 - a };
        let by = if self.sj > 0 { b } else { eb - 1 - b };
        (bx + self.ox, by + self.oy)
    }
}

/// The parity of the dark grid cells (cell `(i, j)` with upper-left corner `(i, j)` is dark iff
/// `(i + j) mod 2` equals it), or `None` when the cells do not look like a checkerboard: fewer
/// than [`MIN_CHECKER_AGREEMENT`] of them alternate, or they differ from their neighbours by
/// less than [`MIN_SQUARE_CONTRAST`] grey levels on average.
fn dark_parity(
    img: &Image<f32>,
    pos: &HashMap<(i32, i32), Vector2<f64>>,
    hgrid: &Matrix3<f64>,
    ni: i32,
    nj: i32,
) -> Option<i32> {
    // Cell colours: the mean of the cell's centre neighbourhood.
    let mut cells = Vec::new();
    for i in -1..ni {
        for j in -1..nj {
            let corners = [(i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1)];
            let known: Vec<Vector2<f64>> =
                corners.iter().filter_map(|k| pos.get(k).copied()).collect();
            let centre = if known.len() == 4 {
                known.iter().sum::<Vector2<f64>>() / 4.0
            } else if i >= 0 && j >= 0 && i + 1 < ni && j + 1 < nj {
                map(hgrid, i as f64 + 0.5, j as f64 + 0.5)
            } else if !known.is_empty() {
                // Outer cells (the board's border squares): use the grid homography.
                map(hgrid, i as f64 + 0.5, j as f64 + 0.5)
            } else {
                continue;
            };
            if centre.x < 1.0
                || centre.y < 1.0
                || centre.x > img.width() as f64 - 2.0
                || centre.y > img.height() as f64 - 2.0
            {
                continue;
            }
            cells.push(((i, j), sample_mean(img, centre)));
        }
    }
    if cells.len() < 4 {
        return None;
    }
    // Parity of dark cells: each inner cell is compared with the mean of its neighbouring
    // cells (local contrast, immune to the IR glare and vignetting).
    let cell_map: HashMap<(i32, i32), f64> = cells.iter().copied().collect();
    let mut even_dark = 0.0f64;
    let mut n = 0.0f64;
    let mut contrast_sum = 0.0f64;
    for (&(i, j), &v) in &cell_map {
        if !(i >= 0 && j >= 0 && i + 1 < ni && j + 1 < nj) {
            continue;
        }
        let nb: Vec<f64> = [(i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)]
            .iter()
            .filter_map(|k| cell_map.get(k).copied())
            .collect();
        if nb.is_empty() {
            continue;
        }
        let nb_mean = nb.iter().sum::<f64>() / nb.len() as f64;
        let dark = v < nb_mean;
        contrast_sum += (v - nb_mean).abs();
        let even = (i + j).rem_euclid(2) == 0;
        even_dark += if even == dark { 1.0 } else { 0.0 };
        n += 1.0;
    }
    if n < 1.0 {
        return None;
    }
    let agreement = (even_dark / n).max(1.0 - even_dark / n);
    if agreement < MIN_CHECKER_AGREEMENT || contrast_sum / n < MIN_SQUARE_CONTRAST {
        return None;
    }
    Some(if even_dark / n >= 0.5 { 0 } else { 1 })
}

/// Every unmirrored placement of an `ni × nj` grid on the board, with either colouring unless
/// the board's is known.
fn placements(board: &Board, ni: i32, nj: i32, grid_handed: bool) -> Vec<Cand> {
    let (cols, rows) = (board.cols as i32, board.rows as i32);
    let mut cands = Vec::new();
    for swap in [false, true] {
        for si in [1, -1] {
            for sj in [1, -1] {
                // Board axes from grid axes: bx = si * (swap ? j : i), by = sj * (swap ? i : j).
                // Handedness: mirrored iff the map has negative determinant relative to the
                // grid's own handedness.
                let det = if swap { -(si * sj) } else { si * sj };
                if (det > 0) != grid_handed {
                    continue;
                }
                let (ex, ey) = if swap { (nj, ni) } else { (ni, nj) };
                if ex > cols || ey > rows {
                    continue;
                }
                for ox in 0..=(cols - ex) {
                    for oy in 0..=(rows - ey) {
                        for black in [true, false] {
                            if board.top_left_black.is_none_or(|b| b == black) {
                                cands.push(Cand { black, swap, si, sj, ox, oy });
                            }
                        }
                    }
                }
            }
        }
    }
    cands
}

/// The rotations of a `cols × rows` corner grid onto itself, as quarter turns `k` (0, 2, and
/// 1, 3 when square), each with whether it changes the colour of the top-left square: the
/// square at the origin moves to the far corner square `(cols, rows)` under 180° (parity
/// `cols + rows`) and to `(n, 0)` under 90° (parity `n`).
pub(super) fn rotations(cols: i32, rows: i32) -> Vec<(u8, bool)> {
    let mut r = vec![(0, false), (2, (cols + rows) % 2 == 1)];
    if cols == rows {
        r.extend([(1, cols % 2 == 1), (3, cols % 2 == 1)]);
    }
    r
}

/// Board corner `(x, y)` turned by `k` quarter turns (`k` odd only for square boards).
pub(super) fn rotate(k: u8, cols: i32, rows: i32, (x, y): (i32, i32)) -> (i32, i32) {
    match k % 4 {
        0 => (x, y),
        1 => (cols - 1 - y, x),
        2 => (cols - 1 - x, rows - 1 - y),
        _ => (y, rows - 1 - x),
    }
}

/// Grid coordinates of board corner `(bx, by)` under placement `c` (the inverse of
/// [`Cand::board_corner`], also beyond the grid).
fn grid_of(c: &Cand, ni: i32, nj: i32, bx: i32, by: i32) -> (i32, i32) {
    let (ea, eb) = if c.swap { (nj, ni) } else { (ni, nj) };
    let (a, b) = (bx - c.ox, by - c.oy);
    let a = if c.si > 0 { a } else { ea - 1 - a };
    let b = if c.sj > 0 { b } else { eb - 1 - b };
    if c.swap { (b, a) } else { (a, b) }
}

/// A partial board's offsets are only certain where the image shows the board end: along each
/// board axis the grid does not span, one of the board's outermost corner lines must be in the
/// grid with the line beyond it (where a further line of corners would be) inside the image
/// (`inside` of grid coordinates). Otherwise the offsets rest on extrapolating the grid's
/// homography past the image, which a strong lens bends (a close-up of a board larger than
/// the frame has no end in view at all).
fn board_end_seen(
    c: &Cand,
    board: &Board,
    ni: i32,
    nj: i32,
    inside: &dyn Fn(f64, f64) -> bool,
) -> bool {
    let (cols, rows) = (board.cols as i32, board.rows as i32);
    let (ex, ey) = if c.swap { (nj, ni) } else { (ni, nj) };
    // The line beyond board column `bx` (for every grid row) is inside the image.
    let column_beyond = |bx: i32| {
        (c.oy..c.oy + ey).all(|by| {
            let (gi, gj) = grid_of(c, ni, nj, bx, by);
            inside(gi as f64, gj as f64)
        })
    };
    let row_beyond = |by: i32| {
        (c.ox..c.ox + ex).all(|bx| {
            let (gi, gj) = grid_of(c, ni, nj, bx, by);
            inside(gi as f64, gj as f64)
        })
    };
    let x_ok = ex == cols
        || (c.ox == 0 && column_beyond(-1))
        || (c.ox + ex == cols && column_beyond(cols));
    let y_ok =
        ey == rows || (c.oy == 0 && row_beyond(-1)) || (c.oy + ey == rows && row_beyond(rows));
    x_ok && y_ok
}

/// Maps grid coordinates to board ids (see the module docs); `None` when not certain.
pub(super) fn label(
    img: &Image<f32>,
    board: &Board,
    pts: &[(Vector2<f64>, f32)],
    grid: &Grid,
) -> Option<LabelledGrid> {
    if grid.len() < MIN_PARTIAL_CORNERS {
        return None;
    }
    let imin = grid.keys().map(|k| k.0).min()?;
    let jmin = grid.keys().map(|k| k.1).min()?;
    let g: Vec<((i32, i32), Vector2<f64>)> =
        grid.iter().map(|(&(i, j), &n)| ((i - imin, j - jmin), pts[n].0)).collect();
    let ni = g.iter().map(|k| k.0.0).max()? + 1;
    let nj = g.iter().map(|k| k.0.1).max()? + 1;
    // Homography grid → image for predictions (cell centres, missing corners).
    let plane: Vec<Vector2<f64>> =
        g.iter().map(|k| Vector2::new(k.0.0 as f64, k.0.1 as f64)).collect();
    let pix: Vec<Vector2<f64>> = g.iter().map(|k| k.1).collect();
    let hgrid = homography(&plane, &pix)?;
    let pos: HashMap<(i32, i32), Vector2<f64>> = g.iter().copied().collect();
    let dark_parity = dark_parity(img, &pos, &hgrid, ni, nj)?;

    // Candidate labellings: axis assignment and signs, never mirrored.
    let (cols, rows) = (board.cols as i32, board.rows as i32);
    let p0 = map(&hgrid, 0.0, 0.0);
    let px_ = map(&hgrid, 1.0, 0.0) - p0;
    let py_ = map(&hgrid, 0.0, 1.0) - p0;
    let grid_handed = px_.x * py_.y - px_.y * py_.x > 0.0;
    let to_board = |c: &Cand, i: i32, j: i32| c.board_corner(ni, nj, i, j);
    // Colour: the square between inner corners (x, y) and (x+1, y+1) is board square
    // (x+1, y+1), dark iff its coordinates' sum is even (top-left black) or odd.
    let cell_dark_board = |c: &Cand, i: i32, j: i32| -> bool {
        let (b0x, b0y) = to_board(c, i, j);
        let (b1x, b1y) = to_board(c, i + 1, j + 1);
        let sx = b0x.min(b1x) + 1;
        let sy = b0y.min(b1y) + 1;
        ((sx + sy).rem_euclid(2) == 0) == c.black
    };
    let cands: Vec<Cand> = placements(board, ni, nj, grid_handed)
        .into_iter()
        .filter(|c| {
            let grid_dark = |i: i32, j: i32| (i + j).rem_euclid(2) == dark_parity;
            grid_dark(0, 0) == cell_dark_board(c, 0, 0)
        })
        .collect();
    // Missing board corners must lie outside the image (or at its edge): otherwise the
    // labelling would claim a visible corner that is not there.
    let edge_margin = 0.5 * px_.norm().min(py_.norm());
    let conflicts = |c: &Cand| -> usize {
        let mut bad = 0;
        for bi in 0..cols {
            for bj in 0..rows {
                // Inverse map board → grid coordinates.
                let (a, b) = (bi - c.ox, bj - c.oy);
                let (ea, eb) = if c.swap { (nj, ni) } else { (ni, nj) };
                if a >= 0 && b >= 0 && a < ea && b < eb {
                    continue;
                }
                let a = if c.si > 0 { a } else { ea - 1 - a };
                let b = if c.sj > 0 { b } else { eb - 1 - b };
                let (gi, gj) = if c.swap { (b, a) } else { (a, b) };
                let q = map(&hgrid, gi as f64, gj as f64);
                let inside = q.x > edge_margin
                    && q.y > edge_margin
                    && q.x < img.width() as f64 - 1.0 - edge_margin
                    && q.y < img.height() as f64 - 1.0 - edge_margin;
                if inside {
                    bad += 1;
                }
            }
        }
        bad
    };
    let ok: Vec<&Cand> = cands.iter().filter(|c| conflicts(c) == 0).collect();
    // The ordering rule (module docs): among the survivors, a black top-left square if any
    // survivor has one, then the board x axis pointing most to the right in the image.
    let dir_x = |c: &Cand| -> f64 {
        let a = if c.swap { py_ } else { px_ };
        (a * c.si as f64).normalize().x
    };
    let any_black = ok.iter().any(|c| c.black);
    let mut pool: Vec<&Cand> = ok.iter().copied().filter(|c| c.black == any_black).collect();
    pool.sort_by(|a, b| dir_x(b).total_cmp(&dir_x(a)));
    let chosen = *pool.first()?;
    // Certain only if every survivor is the chosen placement turned by one of the board's
    // rotations (with the top-left colour that turn implies): then they all name the same
    // physical corners and the rule only picked a representative.
    let at = |c: &Cand, i: i32, j: i32| c.board_corner(ni, nj, i, j);
    let equivalent = |c: &Cand| {
        rotations(cols, rows).iter().any(|&(k, flips)| {
            c.black == (chosen.black != flips)
                && [(0, 0), (1, 0), (0, 1)]
                    .iter()
                    .all(|&(i, j)| at(c, i, j) == rotate(k, cols, rows, at(chosen, i, j)))
        })
    };
    if !ok.iter().all(|c| equivalent(c)) {
        return None;
    }
    if !board_end_seen(chosen, board, ni, nj, &|gi, gj| {
        let q = map(&hgrid, gi, gj);
        q.x > edge_margin
            && q.y > edge_margin
            && q.x < img.width() as f64 - 1.0 - edge_margin
            && q.y < img.height() as f64 - 1.0 - edge_margin
    }) {
        return None;
    }
    let corners = g
        .iter()
        .map(|&((i, j), p)| {
            let (bx, by) = to_board(chosen, i, j);
            ((i, j), p, (by * cols + bx) as usize)
        })
        .collect();
    Some(LabelledGrid { corners, hgrid, top_left_black: chosen.black })
}
