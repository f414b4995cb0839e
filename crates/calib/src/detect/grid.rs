//! Stage 3, grid: grows a seed cell of candidates into a grid of rows and columns, and trims a
//! grid larger than the board to a board-sized window.

use nalgebra::Vector2;

use crate::Board;

/// A predicted neighbour is accepted within this fraction of the local grid step.
const GRID_TOLERANCE: f64 = 0.28;
/// Seeds tried, strongest candidates first: a board's corners are among the strongest
/// responses, so a seed cell is found long before this.
const MAX_SEEDS: usize = 60;

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

/// True when `(u, v)` is a reduced (Lagrange–Gauss) basis of the lattice it spans: neither
/// `u + v` nor `u − v` is shorter than the longer of the two. A cell's two sides are; a side
/// and a diagonal of the cell are not (the other diagonal is shorter), although under
/// perspective they can meet at 55° or more and pass the angle test. A seed on such a sheared
/// basis grows the whole board into a grid whose rows run along the cells' diagonals (OpenCV
/// sample left06 and left12, seeds at the board's border where the side's far neighbour is
/// missing).
fn reduced(u: Vector2<f64>, v: Vector2<f64>) -> bool {
    let longer = u.norm_squared().max(v.norm_squared());
    (u + v).norm_squared() >= longer && (u - v).norm_squared() >= longer
}

/// Grows a grid from seed `s`; `None` if no seed cell exists there.
fn grow(pts: &[(Vector2<f64>, f32)], s: usize) -> Option<Grid> {
    let p = pts[s].0;
    let mut by_dist: Vec<(usize, f64)> = pts
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != s)
        .map(|(i, c)| (i, (c.0 - p).norm()))
        .collect();
    by_dist.sort_by(|a, b| a.1.total_cmp(&b.1));
    by_dist.truncate(8);
    let all_used = vec![false; pts.len()];
    for &(a, da) in by_dist.iter().take(3) {
        let u = pts[a].0 - p;
        let Some(a2) = nearest(pts, &all_used, p - u, GRID_TOLERANCE * da) else { continue };
        for &(b, db) in &by_dist {
            let v = pts[b].0 - p;
            let cos = u.dot(&v) / (da * db);
            if cos.abs() > 0.6 || db > 2.0 * da || da > 2.0 * db || !reduced(u, v) {
                continue;
            }
            let Some(b2) = nearest(pts, &all_used, p - v, GRID_TOLERANCE * db) else { continue };
            if nearest(pts, &all_used, p + u + v, GRID_TOLERANCE * da.min(db)).is_none() {
                continue;
            }
            let mut grid = Grid::new();
            let mut used = vec![false; pts.len()];
            for (k, i) in [((0, 0), s), ((1, 0), a), ((-1, 0), a2), ((0, 1), b), ((0, -1), b2)] {
                grid.insert(k, i);
                used[i] = true;
            }
            let mut queue: std::collections::VecDeque<(i32, i32)> = grid.keys().copied().collect();
            while let Some((i, j)) = queue.pop_front() {
                for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                    let key = (i + di, j + dj);
                    if grid.contains_key(&key) {
                        continue;
                    }
                    let here = pts[grid[&(i, j)]].0;
                    // Predict from the previous corner on the same line, else from a parallel
                    // step of a neighbouring line.
                    let step = if let Some(&back) = grid.get(&(i - di, j - dj)) {
                        Some(here - pts[back].0)
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
pub(super) fn largest(pts: &[(Vector2<f64>, f32)], enough: usize) -> Option<Grid> {
    let mut best: Option<Grid> = None;
    let mut tried = vec![false; pts.len()];
    for s in 0..pts.len().min(MAX_SEEDS) {
        if tried[s] {
            continue;
        }
        if let Some(g) = grow(pts, s) {
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

/// Corners along the grid's two axes (`(ni, nj)`).
pub(super) fn extents(grid: &Grid) -> (i32, i32) {
    let span = |f: fn(&(i32, i32)) -> i32| {
        let (lo, hi) =
            grid.keys().map(f).fold((i32::MAX, i32::MIN), |a, v| (a.0.min(v), a.1.max(v)));
        if hi >= lo { hi - lo + 1 } else { 0 }
    };
    (span(|k| k.0), span(|k| k.1))
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

    /// The cell of OpenCV-set left12's seed: sides `a` (43 px) and `b` (53 px) at 82°; the
    /// diagonal `b − a` meets `a` at 124° (|cos| 0.56, inside the seed's angle test). Sides are a reduced basis, a side and a diagonal are not; the
    /// grid grown from the candidates' lattice must run along the sides.
    #[test]
    fn a_seed_needs_the_cells_sides_not_a_diagonal() {
        let a = Vector2::new(3.70, -42.76);
        let b = Vector2::new(-51.73, -12.02);
        assert!(reduced(a, b) && reduced(b, a));
        assert!(!reduced(a, b - a) && !reduced(b - a, a) && !reduced(a, a + b));
        let cos = a.dot(&(b - a)) / (a.norm() * (b - a).norm());
        assert!(cos.abs() < 0.6, "the angle test alone would accept it: cos {cos}");
        // A 9x6 lattice of corners with those sides. From every seed, the grid is either
        // none (a seed on the border has no cell around it along the sides) or the whole
        // lattice stepping along the sides; seeds on the border used to pick the diagonal.
        let origin = Vector2::new(400.0, 400.0);
        let pts: Vec<(Vector2<f64>, f32)> = (0..6)
            .flat_map(|j| (0..9).map(move |i| (i, j)))
            .map(|(i, j)| (origin + a * i as f64 + b * j as f64, 1.0))
            .collect();
        let mut grown = 0;
        for s in 0..pts.len() {
            let Some(g) = grow(&pts, s) else { continue };
            grown += 1;
            assert_eq!(g.len(), 54, "seed {s}");
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
        assert!(grown >= 28, "{grown} seeds grew");
    }
}
