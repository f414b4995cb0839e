//! Stage 3, grid: grows a seed cell of candidates into a grid of rows and columns, and trims a
//! grid larger than the board to a board-sized window.

use geometry::Image;
use nalgebra::Vector2;

use super::subpix::{bilinear, refine_corner};
use crate::zhang::homography;

use crate::Board;

/// A predicted neighbour is accepted within this fraction of the local grid step.
const GRID_TOLERANCE: f64 = 0.28;
/// Seeds tried, strongest candidates first: a board's corners are among the strongest
/// responses, so a seed cell is found long before this.
const MAX_SEEDS: usize = 60;
/// Nearest candidates a seed cell's sides are looked for among (its first side among the
/// nearest three). A square seen at a grazing angle is up to 7 times longer than wide (a
/// 10x7 board 80° from its normal): its long side's far corner comes after the 12 corners
/// within 6 short steps along the short one, and the 8 nearest held none of it.
const SEED_NEIGHBOURS: usize = 24;
/// Largest ratio of a seed cell's sides: the squares' aspect at 80° from the board's normal
/// (7.5 on a 10x7 board filling a 1080p frame) with some room.
const SEED_MAX_SIDE_RATIO: f64 = 8.0;
/// Largest |cos| of the angle between a seed cell's sides: 0.6 (53°) held boards up to ~65°
/// from their normal; at 75–80° the squares near the far corners meet at 35–40° (0.8), and
/// [`are_sides`], not the angle, tells a side from a diagonal.
const SEED_MAX_COS: f64 = 0.85;

/// Grid coordinates → index into the candidate list.
pub(super) type Grid = std::collections::HashMap<(i32, i32), usize>;

fn nearest(pts: &[(Vector2<f64>, f32)], used: &[bool], p: Vector2<f64>, tol: f64) -> Option<usize> {
    let mut best: Option<(usize, f64)> = None;
    for (i, c) in pts.iter().enumerate() {
        if used[i] {
            continue;
        }
        let d = (c.0 - p).norm();
        if d < tol && best.is_none_or(|b| d < b.1) {
            best = Some((i, d));
        }
    }
    best.map(|b| b.0)
}

/// A step of a seed cell runs along a board side when, at a quarter, half and three quarters
/// of it, the points a quarter of the cell to either side differ in grey level by at least
/// this fraction of the corner's contrast, with the same sign at all three: there they lie in
/// the two squares that the side separates, one dark, one light. Along a cell's diagonal the
/// middle pair lies in one square; along two sides in a row, the quarter pairs lie in squares
/// of opposite colourings; along a knight's move (two sides and one across) a quarter pair
/// lies in one square. Half the contrast lies midway between a side's difference (the full
/// contrast) and the others' (zero, or the full contrast with the other sign).
const SIDE_MIN_CONTRAST: f64 = 0.5;

/// True when `u` and `v`, steps from the corner at `p` to two of its neighbours, are the
/// sides of a board square (see [`SIDE_MIN_CONTRAST`]), not a side and a diagonal nor longer
/// lattice steps. Under strong perspective a cell's sides meet at 40° or 140°, or one is
/// several times the other, and a diagonal is then shorter than the longer side, so the
/// lengths alone do not tell them apart: a length rule ("no diagonal shorter than the longer
/// side") grew boards seen 60–75° from their normal along the diagonals (issue 29). Nor does
/// the colour of the four cells around `p`, which a knight's-move basis keeps.
fn are_sides(img: &Image<f32>, p: Vector2<f64>, u: Vector2<f64>, v: Vector2<f64>) -> bool {
    let area = (u.x * v.y - u.y * v.x).abs();
    if area <= 0.0 {
        return false;
    }
    // The corner's contrast: the range of the grey levels on a circle within a quarter of the
    // lines' spacing (it crosses the four squares at the corner, clear of the next edges).
    let r = 0.25 * (area / u.norm()).min(area / v.norm());
    let ring = (0..16).map(|n| {
        let (sin, cos) = (n as f64 * std::f64::consts::TAU / 16.0).sin_cos();
        bilinear(img, p.x + r * cos, p.y + r * sin)
    });
    let (lo, hi) = ring.fold((f64::MAX, f64::MIN), |a, g| (a.0.min(g), a.1.max(g)));
    let min_step = SIDE_MIN_CONTRAST * (hi - lo);
    // Differences across `w` at its quarter, half and three-quarter points, all at least
    // `min_step` and of one sign.
    let along = |w: Vector2<f64>, o: Vector2<f64>| {
        let d = [0.25, 0.5, 0.75].map(|t| {
            let (a, b) = (p + t * w + 0.25 * o, p + t * w - 0.25 * o);
            bilinear(img, a.x, a.y) - bilinear(img, b.x, b.y)
        });
        d.iter().all(|&x| x >= min_step) || d.iter().all(|&x| x <= -min_step)
    };
    hi > lo && along(u, v) && along(v, u)
}

/// The step after `s0`, `s` along a grid line: `s` turned and scaled as `s0` → `s` was (the
/// complex ratio `s / s0` applied again), the way perspective and a lens shrink and bend a
/// board's lines gradually. A constant step (`s` again) underestimates the shrinking: on
/// GoPro GOPR0053 (fisheye close-up, steps 177 → 133 → 94 px) it predicted the corner after
/// next closer than the next one. Where the two steps differ by more than a smooth line allows
/// ([`MAX_STEP_RATIO`], [`MAX_LINE_TURN_DEG`]) they say nothing about the next one: `s`.
fn next_step(s0: Vector2<f64>, s: Vector2<f64>) -> Vector2<f64> {
    let n0 = s0.norm_squared();
    if n0 <= 0.0 {
        return s;
    }
    // r = s / s0 as complex numbers.
    let (re, im) = ((s.x * s0.x + s.y * s0.y) / n0, (s.y * s0.x - s.x * s0.y) / n0);
    let ratio = re.hypot(im);
    let turn = im.atan2(re).abs().to_degrees();
    if !(1.0 / MAX_STEP_RATIO..=MAX_STEP_RATIO).contains(&ratio) || turn > MAX_LINE_TURN_DEG {
        return s;
    }
    Vector2::new(s.x * re - s.y * im, s.x * im + s.y * re)
}

/// Grows a grid from seed `s`; `None` if no seed cell exists there.
fn grow(img: &Image<f32>, pts: &[(Vector2<f64>, f32)], s: usize) -> Option<Grid> {
    let p = pts[s].0;
    let mut by_dist: Vec<(usize, f64)> = pts
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != s)
        .map(|(i, c)| (i, (c.0 - p).norm()))
        .collect();
    by_dist.sort_by(|a, b| a.1.total_cmp(&b.1));
    by_dist.truncate(SEED_NEIGHBOURS);
    let all_used = vec![false; pts.len()];
    for &(a, da) in by_dist.iter().take(3) {
        let u = pts[a].0 - p;
        let Some(a2) = nearest(pts, &all_used, p - u, GRID_TOLERANCE * da) else { continue };
        for &(b, db) in &by_dist {
            let v = pts[b].0 - p;
            let cos = u.dot(&v) / (da * db);
            if cos.abs() > SEED_MAX_COS
                || db > SEED_MAX_SIDE_RATIO * da
                || da > SEED_MAX_SIDE_RATIO * db
            {
                continue;
            }
            let Some(b2) = nearest(pts, &all_used, p - v, GRID_TOLERANCE * db) else { continue };
            // The image test last: most pairs fail the candidates' geometry first.
            if nearest(pts, &all_used, p + u + v, GRID_TOLERANCE * da.min(db)).is_none()
                || !are_sides(img, p, u, v)
            {
                continue;
            }
            let mut grid = Grid::new();
            let mut used = vec![false; pts.len()];
            for (k, i) in [((0, 0), s), ((1, 0), a), ((-1, 0), a2), ((0, 1), b), ((0, -1), b2)] {
                grid.insert(k, i);
                used[i] = true;
            }
            // Breadth-first, then again from every corner while a pass adds any: a neighbour
            // that could not be predicted when its corner was first visited (no previous
            // corner on its line yet, e.g. next to a missed candidate) can be once the grid
            // has grown around it (GoPro GOPR0067: three corners were left out so).
            let mut queue: std::collections::VecDeque<(i32, i32)> = grid.keys().copied().collect();
            let mut added = false;
            loop {
                let Some((i, j)) = queue.pop_front() else {
                    if !std::mem::take(&mut added) {
                        break;
                    }
                    queue.extend(grid.keys().copied());
                    continue;
                };
                for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                    let key = (i + di, j + dj);
                    if grid.contains_key(&key) {
                        continue;
                    }
                    let here = pts[grid[&(i, j)]].0;
                    // Predict from the previous corner on the same line, else from a parallel
                    // step of a neighbouring line.
                    let step = if let Some(&back) = grid.get(&(i - di, j - dj)) {
                        let s = here - pts[back].0;
                        let s0 =
                            grid.get(&(i - 2 * di, j - 2 * dj)).map(|&b| pts[back].0 - pts[b].0);
                        Some(s0.map_or(s, |s0| next_step(s0, s)))
                    } else {
                        [(dj, di), (-dj, -di)].iter().find_map(|&(oi, oj)| {
                            let q0 = grid.get(&(i + oi, j + oj))?;
                            let q1 = grid.get(&(i + oi + di, j + oj + dj))?;
                            Some(pts[*q1].0 - pts[*q0].0)
                        })
                    };
                    let Some(step) = step else { continue };
                    if let Some(n) = nearest(pts, &used, here + step, GRID_TOLERANCE * step.norm())
                    {
                        grid.insert(key, n);
                        used[n] = true;
                        queue.push_back(key);
                        added = true;
                    }
                }
            }
            return Some(grid);
        }
    }
    None
}

/// Grows grids from the strongest candidates (seeds not already in a grid) and keeps the
/// largest; stops early once one has `enough` corners.
pub(super) fn largest(
    img: &Image<f32>,
    pts: &[(Vector2<f64>, f32)],
    enough: usize,
) -> Option<Grid> {
    let mut best: Option<Grid> = None;
    let mut tried = vec![false; pts.len()];
    for s in 0..pts.len().min(MAX_SEEDS) {
        if tried[s] {
            continue;
        }
        if let Some(g) = grow(img, pts, s) {
            for &i in g.values() {
                tried[i] = true;
            }
            if best.as_ref().is_none_or(|b| g.len() > b.len()) {
                best = Some(g);
            }
            if best.as_ref().is_some_and(|b| b.len() >= enough) {
                break;
            }
        }
    }
    best
}

/// Largest turn between two successive steps along a grid line, degrees. A lens bends the
/// rows of a real board gradually (a few degrees per square even on the GoPro wide-angle set);
/// a corner grown into the wrong row or column turns the line by 30° or more.
const MAX_LINE_TURN_DEG: f64 = 20.0;
/// Largest ratio between two successive steps along a grid line (perspective and lens change
/// the square size gradually; a skipped corner doubles the step).
const MAX_STEP_RATIO: f64 = 1.6;

/// True when every line of the grid runs smoothly: successive steps turn by less than
/// [`MAX_LINE_TURN_DEG`] and change length by less than [`MAX_STEP_RATIO`].
pub(super) fn is_smooth(pts: &[(Vector2<f64>, f32)], grid: &Grid) -> bool {
    let cos_max = MAX_LINE_TURN_DEG.to_radians().cos();
    grid.keys().all(|&(i, j)| {
        [(1, 0), (0, 1)].iter().all(|&(di, dj)| {
            let (Some(&a), Some(&b), Some(&c)) =
                (grid.get(&(i - di, j - dj)), grid.get(&(i, j)), grid.get(&(i + di, j + dj)))
            else {
                return true;
            };
            let (u, v) = (pts[b].0 - pts[a].0, pts[c].0 - pts[b].0);
            let (lu, lv) = (u.norm(), v.norm());
            lu > 0.0
                && lv > 0.0
                && u.dot(&v) / (lu * lv) >= cos_max
                && lu.max(lv) / lu.min(lv) <= MAX_STEP_RATIO
        })
    })
}

/// True when `full` has a complete line of corners right beside the window `part` (a
/// sub-grid of it): a row or column just outside the window, spanning the window's length.
pub(super) fn full_line_beside(full: &Grid, part: &Grid) -> bool {
    let (Some(i0), Some(i1), Some(j0), Some(j1)) = (
        part.keys().map(|k| k.0).min(),
        part.keys().map(|k| k.0).max(),
        part.keys().map(|k| k.1).min(),
        part.keys().map(|k| k.1).max(),
    ) else {
        return false;
    };
    let column = |i: i32| (j0..=j1).all(|j| full.contains_key(&(i, j)));
    let row = |j: i32| (i0..=i1).all(|i| full.contains_key(&(i, j)));
    column(i0 - 1) || column(i1 + 1) || row(j0 - 1) || row(j1 + 1)
}

/// Half window of the `cornerSubPix` that fills a hole, as a fraction of the local grid step
/// (clear of the neighbouring corners, whose edges would pull it; the same fraction as the
/// final colour window in `refine.rs`).
const FILL_WINDOW_FRACTION: f64 = 0.4;
/// Smallest half window of that `cornerSubPix`, px (below 2 it sees too few gradients).
const FILL_MIN_HALF_WINDOW: usize = 2;

/// Largest distance of a filled corner from its prediction, as a fraction of the local grid
/// step: a little over a third of the growth's [`GRID_TOLERANCE`], as the prediction (a
/// homography of the grid corners around the hole) is exact under perspective and only the
/// lens's bend over two squares and the corners' noise move a real corner off it, while a
/// `cornerSubPix` that converged on another feature (a neighbouring edge) is off by more.
const FILL_MAX_OFFSET: f64 = 0.1;
/// Grid corners within this many steps (Chebyshev) of a hole predict it.
const FILL_LOCAL_RADIUS: i32 = 2;
/// Fewest such corners for the local homography (4 determine it; 6 leave redundancy).
const FILL_MIN_LOCAL: usize = 6;

/// The image position of grid position `at` predicted by the homography of the grid corners
/// within [`FILL_LOCAL_RADIUS`] of it (exact under perspective, and over two squares the lens
/// bends the board little); `None` with fewer than [`FILL_MIN_LOCAL`] of them.
fn local_prediction(
    pts: &[(Vector2<f64>, f32)],
    grid: &Grid,
    at: (i32, i32),
) -> Option<Vector2<f64>> {
    let near: Vec<(Vector2<f64>, Vector2<f64>)> = grid
        .iter()
        .filter(|(k, _)| (k.0 - at.0).abs().max((k.1 - at.1).abs()) <= FILL_LOCAL_RADIUS)
        .map(|(k, &n)| (Vector2::new((k.0 - at.0) as f64, (k.1 - at.1) as f64), pts[n].0))
        .collect();
    if near.len() < FILL_MIN_LOCAL {
        return None;
    }
    let (plane, pix): (Vec<_>, Vec<_>) = near.into_iter().unzip();
    let h = homography(&plane, &pix)?;
    let q = h * nalgebra::Vector3::new(0.0, 0.0, 1.0);
    (q.z.abs() > f64::EPSILON).then(|| Vector2::new(q.x / q.z, q.y / q.z))
}

/// Fills the holes of a board-sized grid: a grid position inside the grid's extent with no
/// candidate (the candidate stage misses corners of squares only ~10 px wide, GoPro GOPR0067)
/// where the local grid step is below the ChESS ring's diameter (`2 · ring_radius`) is
/// predicted by the homography of the grid corners around it, refined with `cornerSubPix`
/// there, and added to `pts` when the refinement stays within [`FILL_MAX_OFFSET`] of a step
/// of the prediction and the four quadrants around it alternate in colour (an X-junction, not
/// an edge or a blank). Repeats while a pass fills any hole. Every position inside the extent of a grid on a board is a
/// board corner, so no new corner can be grown off the board.
pub(super) fn fill_holes(
    img: &Image<f32>,
    pts: &mut Vec<(Vector2<f64>, f32)>,
    grid: &mut Grid,
    ring_radius: usize,
) {
    let (Some(i0), Some(i1), Some(j0), Some(j1)) = (
        grid.keys().map(|k| k.0).min(),
        grid.keys().map(|k| k.0).max(),
        grid.keys().map(|k| k.1).min(),
        grid.keys().map(|k| k.1).max(),
    ) else {
        return;
    };
    loop {
        let mut filled = false;
        for i in i0..=i1 {
            for j in j0..=j1 {
                if grid.contains_key(&(i, j)) {
                    continue;
                }
                let at = |di: i32, dj: i32| grid.get(&(i + di, j + dj)).map(|&n| pts[n].0);
                // (prediction, step along the line) from each axis, interpolation first.
                let mut guesses = Vec::new();
                let mut axes = Vec::new();
                for (di, dj) in [(1, 0), (0, 1)] {
                    if let (Some(a), Some(b)) = (at(-di, -dj), at(di, dj)) {
                        guesses.push((0.5 * (a + b), 0.5 * (b - a)));
                    }
                }
                for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                    if let (Some(a), Some(b)) = (at(-di, -dj), at(-2 * di, -2 * dj)) {
                        guesses.push((2.0 * a - b, a - b));
                    }
                }
                for (di, dj) in [(1, 0), (0, 1)] {
                    let d = match (at(di, dj), at(-di, -dj)) {
                        (Some(a), Some(b)) => Some(0.5 * (a - b)),
                        _ => None,
                    };
                    axes.push(d);
                }
                let Some(&(_, step)) = guesses.first() else { continue };
                let Some(pred) = local_prediction(pts, grid, (i, j)) else { continue };
                let len = step.norm();
                // The other axis' step: from the grid around, else the perpendicular.
                let other = guesses
                    .iter()
                    .map(|g| g.1)
                    .chain(axes.into_iter().flatten())
                    .find(|v| (v.dot(&step) / (v.norm() * len)).abs() < 0.5)
                    .unwrap_or_else(|| Vector2::new(-step.y, step.x));
                // The window sized by the shorter step, as it must stay clear of both axes'
                // neighbours.
                let short = len.min(other.norm());
                // Only where the candidate stage is blind: squares narrower than the ChESS
                // ring's diameter put the neighbouring corners' edges on the ring. Elsewhere a
                // corner without a candidate is not a clean junction (the Kinect's IR glare
                // separates the black squares: kinect-lab ir_11, where a filled corner ended
                // 2.9 px from the lab's), and it stays a hole.
                if short >= 2.0 * ring_radius as f64 {
                    continue;
                }
                let hw = ((FILL_WINDOW_FRACTION * short) as usize).max(FILL_MIN_HALF_WINDOW);
                let margin = hw as f64 + 2.0;
                if pred.x < margin
                    || pred.y < margin
                    || pred.x > img.width() as f64 - 1.0 - margin
                    || pred.y > img.height() as f64 - 1.0 - margin
                {
                    continue;
                }
                let Some(q) = refine_corner(img, pred, hw) else { continue };
                if (q - pred).norm() >= FILL_MAX_OFFSET * short {
                    continue;
                }
                if !alternates(img, q, step, other) {
                    continue;
                }
                pts.push((q, 0.0));
                grid.insert((i, j), pts.len() - 1);
                filled = true;
            }
        }
        if !filled {
            break;
        }
    }
}

/// True when the four cells around the junction `q` (grid steps `u`, `v`) alternate: both
/// diagonal cells of one pair darker than both of the other pair.
fn alternates(img: &Image<f32>, q: Vector2<f64>, u: Vector2<f64>, v: Vector2<f64>) -> bool {
    let s = |d: Vector2<f64>| bilinear(img, q.x + 0.25 * d.x, q.y + 0.25 * d.y);
    let (a, b) = ((s(u + v), s(-u - v)), (s(u - v), s(v - u)));
    a.0.min(a.1) > b.0.max(b.1) || b.0.min(b.1) > a.0.max(a.1)
}

/// Corners along the grid's two axes (`(ni, nj)`).
pub(super) fn extents(grid: &Grid) -> (i32, i32) {
    let span = |f: fn(&(i32, i32)) -> i32| {
        let (lo, hi) =
            grid.keys().map(f).fold((i32::MAX, i32::MIN), |a, v| (a.0.min(v), a.1.max(v)));
        if hi >= lo { hi - lo + 1 } else { 0 }
    };
    (span(|k| k.0), span(|k| k.1))
}

/// Most corners an outermost grid line may hold, as a fraction of the grid's extent along it,
/// and still be peeled off by [`peel_partial_lines`]: the spurious junctions along a board's
/// border are a few (1 to 4 of 9 on OpenCV's samples), while the last line of a board cut off
/// by the image edge usually keeps most of its corners and is left alone.
const MAX_PEELED_LINE_FRACTION: f64 = 0.5;

/// `grid` without its partial outermost lines: while an outermost row or column holds some but
/// at most [`MAX_PEELED_LINE_FRACTION`] of the grid's positions along it, the sparsest such
/// line is removed. A complete board's outer lines are complete, so this only removes
/// junctions where the board's border meets the background and that line up with the grid.
pub(super) fn peel_partial_lines(grid: &Grid) -> Grid {
    let mut grid = grid.clone();
    loop {
        let (imin, imax) = (
            grid.keys().map(|k| k.0).min().unwrap_or(0),
            grid.keys().map(|k| k.0).max().unwrap_or(0),
        );
        let (jmin, jmax) = (
            grid.keys().map(|k| k.1).min().unwrap_or(0),
            grid.keys().map(|k| k.1).max().unwrap_or(0),
        );
        if imax - imin < 2 || jmax - jmin < 2 {
            return grid;
        }
        // (axis 0 = a column of fixed i, 1 = a row of fixed j; the line's index; its corners;
        // the grid's extent along it).
        let lines = [
            (0, imin, jmax - jmin + 1),
            (0, imax, jmax - jmin + 1),
            (1, jmin, imax - imin + 1),
            (1, jmax, imax - imin + 1),
        ];
        let on = |axis: i32, at: i32, k: &(i32, i32)| if axis == 0 { k.0 == at } else { k.1 == at };
        let sparsest = lines
            .iter()
            .map(|&(axis, at, len)| {
                (axis, at, len, grid.keys().filter(|k| on(axis, at, k)).count())
            })
            .filter(|&(_, _, len, n)| {
                n < len as usize && n as f64 <= MAX_PEELED_LINE_FRACTION * len as f64
            })
            .min_by_key(|&(_, _, _, n)| n);
        let Some((axis, at, _, _)) = sparsest else { return grid };
        grid.retain(|k, _| !on(axis, at, k));
    }
}

/// A grid larger than the board (spurious junctions where the board's border meets the
/// background line up with the grid): keep the board-sized window, in either orientation,
/// with the most corners and then the strongest total response.
pub(super) fn trim(board: &Board, pts: &[(Vector2<f64>, f32)], grid: Grid) -> Grid {
    let (imin, imax) =
        (grid.keys().map(|k| k.0).min().unwrap_or(0), grid.keys().map(|k| k.0).max().unwrap_or(0));
    let (jmin, jmax) =
        (grid.keys().map(|k| k.1).min().unwrap_or(0), grid.keys().map(|k| k.1).max().unwrap_or(0));
    let (ni, nj) = (imax - imin + 1, jmax - jmin + 1);
    let (c, r) = (board.cols as i32, board.rows as i32);
    let fits = |a: i32, b: i32| (ni <= a && nj <= b) || (ni <= b && nj <= a);
    if fits(c, r) {
        return grid;
    }
    let mut best: Option<((usize, f32), Grid)> = None;
    for (wa, wb) in [(c, r), (r, c)] {
        for i0 in imin..=(imax - wa + 1).max(imin) {
            for j0 in jmin..=(jmax - wb + 1).max(jmin) {
                let sub: Grid = grid
                    .iter()
                    .filter(|(k, _)| k.0 >= i0 && k.0 < i0 + wa && k.1 >= j0 && k.1 < j0 + wb)
                    .map(|(k, v)| (*k, *v))
                    .collect();
                let score = (sub.len(), sub.values().map(|&n| pts[n].1).sum::<f32>());
                if best
                    .as_ref()
                    .is_none_or(|b| score.0 > b.0.0 || (score.0 == b.0.0 && score.1 > b.0.1))
                {
                    best = Some((score, sub));
                }
            }
        }
    }
    best.map(|b| b.1).unwrap_or(grid)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid with the keys `cells`, values arbitrary.
    fn keys(cells: impl IntoIterator<Item = (i32, i32)>) -> Grid {
        cells.into_iter().enumerate().map(|(n, k)| (k, n)).collect()
    }

    fn sorted(g: &Grid) -> Vec<(i32, i32)> {
        let mut k: Vec<(i32, i32)> = g.keys().copied().collect();
        k.sort();
        k
    }

    #[test]
    fn partial_outer_lines_are_peeled_and_a_cut_board_is_left_alone() {
        let board = || (0..9).flat_map(|i| (0..6).map(move |j| (i, j)));
        let whole = keys(board());
        // Unchanged: a complete grid.
        assert_eq!(sorted(&peel_partial_lines(&whole)), sorted(&whole));
        // 3 junctions above the board (row −1) and 2 beside it (column 9), as OpenCV's left
        // samples show: both lines go, the 9x6 board stays.
        let extra = keys(board().chain([(2, -1), (3, -1), (4, -1), (9, 1), (9, 4)]));
        assert_eq!(sorted(&peel_partial_lines(&extra)), sorted(&whole));
        // A board cut by the image edge: its last row keeps 6 of 9 corners, more than half, and
        // is not peeled into a smaller "complete" board.
        let cut = keys(board().filter(|&(i, j)| j < 5 || i < 6));
        assert_eq!(sorted(&peel_partial_lines(&cut)), sorted(&cut));
    }

    /// A board of `cols × rows` inner corners whose corner `(i, j)` is at `origin + i a + j b`
    /// (an affine view), its squares dark 40 / light 200 with a light margin of one square on
    /// a background of 120, rendered with 4×4 samples per pixel; and its corners.
    fn lattice(
        (w, h): (usize, usize),
        origin: Vector2<f64>,
        a: Vector2<f64>,
        b: Vector2<f64>,
        (cols, rows): (i32, i32),
    ) -> (Image<f32>, Vec<(Vector2<f64>, f32)>) {
        let inv = nalgebra::Matrix2::from_columns(&[a, b]).try_inverse().unwrap();
        let img = Image::from_fn(w, h, |x, y| {
            let mut sum = 0.0;
            for sy in 0..4 {
                for sx in 0..4 {
                    let q = Vector2::new(
                        x as f64 - 0.375 + 0.25 * sx as f64,
                        y as f64 - 0.375 + 0.25 * sy as f64,
                    );
                    let c = inv * (q - origin);
                    let (u, v) = (c.x.floor() as i32, c.y.floor() as i32);
                    sum += if u < -2 || v < -2 || u > cols || v > rows {
                        120.0
                    } else if u < -1 || v < -1 || u > cols - 1 || v > rows - 1 {
                        200.0
                    } else if (u + v).rem_euclid(2) == 0 {
                        40.0
                    } else {
                        200.0
                    };
                }
            }
            sum / 16.0
        });
        let pts = (0..rows)
            .flat_map(|j| (0..cols).map(move |i| (i, j)))
            .map(|(i, j)| (origin + a * i as f64 + b * j as f64, 1.0))
            .collect();
        (img, pts)
    }

    /// Source of the expectations: the rendered lattices' sides. Two 9x6 boards: the cell of
    /// OpenCV-set left12's seed (sides `a` 43 px and `b` 53 px at 82°; the diagonal `b − a`
    /// meets `a` at 124°, |cos| 0.56, inside the seed's angle test), and a cell as strong
    /// perspective shears it (sides 60 and 36 px at 124°, a diagonal of 50 px shorter than the
    /// longer side, so that the shortest lattice steps, the lattice's reduced basis, are a side
    /// and a diagonal). From every seed the grid is either none (a seed on the border has no
    /// cell around it along the sides) or the whole lattice stepping along the sides; on the
    /// first, seeds on the border used to pick the diagonal, on the second a length rule picks
    /// it from every seed.
    #[test]
    fn a_seed_needs_the_cells_sides_not_a_diagonal() {
        type Case = (Vector2<f64>, Vector2<f64>, Vector2<f64>, (usize, usize));
        let cases: [Case; 2] = [
            (
                Vector2::new(3.70, -42.76),
                Vector2::new(-51.73, -12.02),
                Vector2::new(420.0, 560.0),
                (600, 680),
            ),
            (
                Vector2::new(60.0, 0.0),
                Vector2::new(-20.0, 30.0),
                Vector2::new(300.0, 100.0),
                (960, 340),
            ),
        ];
        for (k, (a, b, origin, size)) in cases.into_iter().enumerate() {
            // The side and the diagonal that a length rule takes for a cell.
            let (side, diagonal) = if k == 0 { (a, b - a) } else { (b, a + b) };
            let cos = side.dot(&diagonal) / (side.norm() * diagonal.norm());
            let ratio = side.norm().max(diagonal.norm()) / side.norm().min(diagonal.norm());
            assert!(cos.abs() < 0.6 && ratio < 2.0, "the seed's angle and length tests pass it");
            if k == 1 {
                assert!((a + b).norm() < a.norm(), "a diagonal shorter than the longer side");
            }
            let (img, pts) = lattice(size, origin, a, b, (9, 6));
            let mut grown = 0;
            for s in 0..pts.len() {
                let Some(g) = grow(&img, &pts, s) else { continue };
                grown += 1;
                assert_eq!(g.len(), 54, "sides {a:?} {b:?}, seed {s}");
                for (&(i, j), &n) in &g {
                    for d in [(1, 0), (0, 1)] {
                        if let Some(&m) = g.get(&(i + d.0, j + d.1)) {
                            let step = pts[m].0 - pts[n].0;
                            let side = [a, -a, b, -b].iter().any(|s| (step - s).norm() < 1e-9);
                            assert!(side, "seed {s}: step {step:?} at ({i}, {j}) is no cell side");
                        }
                    }
                }
            }
            // The 7x4 interior corners all seed.
            assert!(grown >= 28, "sides {a:?} {b:?}: {grown} seeds grew");
        }
    }

    /// Source of the expectations: the rendered lattice's sides `a`, `b` (the perspective-sheared
    /// cell of `a_seed_needs_the_cells_sides_not_a_diagonal`). At an interior corner the sides
    /// pass [`are_sides`] in either order and sign; a side with a diagonal (`a + b`, `b − a`),
    /// with two sides in a row (`2b`, seen as a seed on every second row of a board 70° from its
    /// normal), with a knight's move (`2a + b`), and two diagonals do not.
    #[test]
    fn are_sides_tells_sides_from_other_lattice_steps() {
        let (a, b) = (Vector2::new(60.0, 0.0), Vector2::new(-20.0, 30.0));
        let (img, pts) = lattice((960, 340), Vector2::new(300.0, 100.0), a, b, (9, 6));
        // Corner (4, 2), with two corners on every side.
        let p = pts[2 * 9 + 4].0;
        for (u, v) in [(a, b), (b, a), (-a, b), (a, -b), (-b, -a)] {
            assert!(are_sides(&img, p, u, v), "sides {u:?} {v:?}");
        }
        let others = [
            (a, a + b),
            (b, a + b),
            (a, b - a),
            (a, 2.0 * b),
            (b, 2.0 * a),
            (b, 2.0 * a + b),
            (a + b, b - a),
        ];
        for (u, v) in others {
            assert!(!are_sides(&img, p, u, v) && !are_sides(&img, p, v, u), "steps {u:?} {v:?}");
        }
    }

    /// Source of the expectation: a line shrinking and turning at a constant rate (a
    /// geometric sequence of steps, as perspective makes) is predicted exactly; steps that no
    /// smooth line shows (ratio beyond [`MAX_STEP_RATIO`]) fall back to the last step.
    #[test]
    fn next_step_continues_a_shrinking_turning_line() {
        let turn = 4f64.to_radians();
        let rot = |v: Vector2<f64>, k: f64| {
            let (c, s) = ((k * turn).cos(), (k * turn).sin());
            Vector2::new(c * v.x - s * v.y, s * v.x + c * v.y)
        };
        let s0 = Vector2::new(177.0, 0.0);
        let (s1, s2) = (rot(s0, 1.0) * 0.75, rot(s0, 2.0) * 0.75 * 0.75);
        assert!((next_step(s0, s1) - s2).norm() < 1e-9);
        // A constant-step prediction would be 33 px off here (44 % of the next step).
        assert!((s1 - s2).norm() > 0.28 * s2.norm());
        let jump = Vector2::new(2.0 * 177.0, 0.0);
        assert_eq!(next_step(s0, jump), jump);
    }

    /// A checkerboard of 12 px squares, rendered with 4×4 supersampling (dark 40, light 200),
    /// and a flat grey patch (120) covering corner `blank`; corner `(i, j)` of the grid is at
    /// `(30.5 + 12 i, 30.5 + 12 j)`.
    fn board_image(blank: (i32, i32)) -> (Image<f32>, impl Fn(i32, i32) -> Vector2<f64>) {
        let at = |i: i32, j: i32| Vector2::new(30.5 + 12.0 * i as f64, 30.5 + 12.0 * j as f64);
        let b = at(blank.0, blank.1);
        let img = Image::from_fn(140, 120, |x, y| {
            if (x as f64 - b.x).abs() < 4.0 && (y as f64 - b.y).abs() < 4.0 {
                return 120.0;
            }
            let mut sum = 0.0;
            for sy in 0..4 {
                for sx in 0..4 {
                    let u = (x as f64 - 0.375 + 0.25 * sx as f64 - 30.5) / 12.0;
                    let v = (y as f64 - 0.375 + 0.25 * sy as f64 - 30.5) / 12.0;
                    let dark = (u.floor() as i64 + v.floor() as i64).rem_euclid(2) == 0;
                    sum += if dark { 40.0 } else { 200.0 };
                }
            }
            sum / 16.0
        });
        (img, at)
    }

    /// Source of the expectations: the rendered board's corner positions. Holes at real
    /// corners are filled within 0.1 px of the truth; the corner covered by a flat patch
    /// (no junction there) stays a hole; nothing is added outside the grid's extent.
    #[test]
    fn fill_holes_finds_missed_corners_and_nothing_else() {
        let blank = (5, 3);
        let (img, at) = board_image(blank);
        let holes = [(0, 0), (3, 2), (4, 2), (7, 4), blank];
        // The 8x6 grid's true corners, less the holes.
        let holed = || {
            let (mut pts, mut grid) = (Vec::new(), Grid::new());
            for i in 0..8 {
                for j in 0..6 {
                    if !holes.contains(&(i, j)) {
                        pts.push((at(i, j), 1.0));
                        grid.insert((i, j), pts.len() - 1);
                    }
                }
            }
            (pts, grid)
        };
        let (mut pts, mut grid) = holed();
        // Ring radius 7 (colour images): 14 px, above the 12 px squares.
        fill_holes(&img, &mut pts, &mut grid, 7);
        for &(i, j) in &holes[..4] {
            let &n = grid.get(&(i, j)).unwrap_or_else(|| panic!("hole ({i}, {j}) not filled"));
            let err = (pts[n].0 - at(i, j)).norm();
            assert!(err < 0.1, "({i}, {j}) filled {err:.3} px off");
        }
        assert!(!grid.contains_key(&blank), "a corner filled on the flat patch");
        assert_eq!(grid.len(), 8 * 6 - 1);
        // Ring radius 5 (IR images): 10 px, below the 12 px squares, where the candidate stage
        // sees corners; a hole there is not a clean junction and is left alone.
        let (mut pts5, mut grid5) = holed();
        fill_holes(&img, &mut pts5, &mut grid5, 5);
        assert_eq!(grid5.len(), 8 * 6 - holes.len(), "holes filled where the squares are wide");
    }
}
