//! Checkerboard detection with sub-pixel corners, built for the Kinect's IR images (low
//! resolution, saturated centre, dark edges) as well as 1080p colour.
//!
//! 1. **Candidates**: the ChESS X-junction response on a ring of 16 samples (radius
//!    [`DetectorParams::ring_radius`]). It compares opposite and adjacent ring sectors, so it
//!    depends only on local contrast, not on the absolute brightness that the IR glare ruins;
//!    local maxima above a small fraction of the strongest response are kept.
//! 2. **Sub-pixel**: OpenCV's `cornerSubPix` normal equations (gradient ⟂ (corner − pixel),
//!    Gaussian-weighted window), iterated to 1e-4 px; the same estimator that Bouguet's
//!    toolbox uses. With [`Refinement::CornerSubPix`] each corner is refined again, once the
//!    grid is known, with a window sized to its local grid step (more pixels, less noise; see
//!    `FINAL_WINDOW_FRACTION_*`); with the default junction fit that is only its fallback.
//! 5. **Final sub-pixel fit** ([`Refinement::JunctionFit`], the default): the maximum-likelihood
//!    fit of a blurred X-junction model to every pixel within 0.45 grid steps
//!    ([`fit_junction`]), started from step 2 with the edge directions of the labelled grid.
//!    [`Refinement::CornerSubPix`] stops after step 2 and reproduces Bouguet's corners.
//! 3. **Grid**: a seed cell (a corner, its nearest neighbour, the opposite one and a
//!    non-collinear pair) grows breadth-first by predicting each neighbour from the two
//!    previous corners of its row or column; holes (a glare-washed corner) are allowed.
//! 4. **Labelling**: the grid's extents are matched to the board's `cols × rows`, never
//!    mirrored; the colour of the squares (the board's top-left square is black) fixes the
//!    offsets of a partial board; the remaining 180° ambiguity of an even×even-square board is
//!    resolved by keeping the board's x axis pointing right in the image (and between the two
//!    cameras of a pair by [`align_pair`]). A partial board whose offsets are not certain is
//!    dropped, never guessed.

use geometry::Image;
use nalgebra::{Matrix3, Vector2, Vector3};

use crate::zhang::homography;
use crate::{Board, Corner, ViewCorners};

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
            }
        } else {
            Self {
                ring_radius: 7,
                subpix_half_window: 5,
                min_response_fraction: 0.04,
                refinement: Refinement::default(),
            }
        }
    }
}

/// Most candidates kept per image (strongest first); a 7x5 board needs 35.
const MAX_CANDIDATES: usize = 600;
/// A predicted neighbour is accepted within this fraction of the local grid step.
const GRID_TOLERANCE: f64 = 0.28;
/// Iterations and convergence threshold (px) of the sub-pixel refinement.
const SUBPIX_MAX_ITERATIONS: usize = 40;
const SUBPIX_EPS: f64 = 1e-4;
/// Images up to this width are treated as IR-sized (Kinect IR: 512).
const SMALL_IMAGE_WIDTH: usize = 800;
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
/// Fewest corners for a partial board to be reported (a homography needs 4; 6 gives slack).
const MIN_PARTIAL_CORNERS: usize = 6;
/// Fraction of cells whose colour must agree with the checker pattern.
const MIN_CHECKER_AGREEMENT: f64 = 0.8;

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

#[inline]
fn px(img: &Image<f32>, x: isize, y: isize) -> f32 {
    let x = x.clamp(0, img.width() as isize - 1) as usize;
    let y = y.clamp(0, img.height() as isize - 1) as usize;
    *img.get(x, y)
}

/// Bilinear sample with clamping at the borders.
#[inline]
fn bilinear(img: &Image<f32>, x: f64, y: f64) -> f64 {
    let x0 = x.floor();
    let y0 = y.floor();
    let (fx, fy) = (x - x0, y - y0);
    let (xi, yi) = (x0 as isize, y0 as isize);
    let a = px(img, xi, yi) as f64;
    let b = px(img, xi + 1, yi) as f64;
    let c = px(img, xi, yi + 1) as f64;
    let d = px(img, xi + 1, yi + 1) as f64;
    (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy
}

/// ChESS response at every pixel (0 near the border).
///
/// Row by row: each of the 16 ring samples of the pixels of a row is a contiguous slice of
/// the image (the row shifted by the ring offset), so the per-pixel arithmetic runs over
/// slices and vectorises; the operations and their order per pixel are the textbook formula's.
pub fn chess_response(img: &Image<f32>, radius: usize) -> Image<f32> {
    let (w, h) = img.size();
    let r = radius as f64;
    let offsets: [(isize, isize); 16] = std::array::from_fn(|n| {
        let a = n as f64 * std::f64::consts::TAU / 16.0;
        ((r * a.cos()).round() as isize, (r * a.sin()).round() as isize)
    });
    let mut out = vec![0.0f32; w * h];
    if w <= 2 * radius || h <= 2 * radius {
        return Image::from_fn(w, h, |_, _| 0.0);
    }
    let data = img.data();
    let len = w - 2 * radius;
    use rayon::prelude::*;
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        if y < radius || y + radius >= h {
            return;
        }
        // Slice n holds ring sample n of the pixels x = radius .. w − radius.
        let at = |dx: isize, dy: isize| {
            let start = (y as isize + dy) as usize * w + (radius as isize + dx) as usize;
            &data[start..start + len]
        };
        let ring: [&[f32]; 16] = offsets.map(|(dx, dy)| at(dx, dy));
        let (centre, left, right, up, down) = (at(0, 0), at(-1, 0), at(1, 0), at(0, -1), at(0, 1));
        for (i, o) in row[radius..radius + len].iter_mut().enumerate() {
            let s: [f32; 16] = std::array::from_fn(|n| ring[n][i]);
            let mut sum = 0.0;
            for n in 0..4 {
                sum += ((s[n] + s[n + 8]) - (s[n + 4] + s[n + 12])).abs();
            }
            let mut diff = 0.0;
            for n in 0..8 {
                diff += (s[n] - s[n + 8]).abs();
            }
            let ring_mean = s.iter().sum::<f32>() / 16.0;
            let local = (centre[i] + left[i] + right[i] + up[i] + down[i]) / 5.0;
            *o = sum - diff - 16.0 * (ring_mean - local).abs();
        }
    });
    Image::from_vec(w, h, out).expect("w × h values")
}

/// OpenCV's `cornerSubPix` estimator around `start`. `None` when it leaves the window or the
/// image, or the gradient matrix is singular (no corner there).
pub fn refine_corner(
    img: &Image<f32>,
    start: Vector2<f64>,
    half_window: usize,
) -> Option<Vector2<f64>> {
    let hw = half_window as isize;
    let mut c = start;
    let (w, h) = (img.width() as f64, img.height() as f64);
    let n = 2 * half_window + 1;
    let mask: Vec<f64> = (0..n)
        .map(|i| {
            let t = (i as f64 - half_window as f64) / half_window as f64;
            (-t * t).exp()
        })
        .collect();
    let mut patch = vec![0.0f64; (n + 2) * (n + 2)];
    for _ in 0..SUBPIX_MAX_ITERATIONS {
        for (i, row) in patch.chunks_mut(n + 2).enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = bilinear(
                    img,
                    c.x + (j as isize - hw - 1) as f64,
                    c.y + (i as isize - hw - 1) as f64,
                );
            }
        }
        let (mut a, mut b, mut cc, mut bb1, mut bb2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..n {
            for j in 0..n {
                let m = mask[i] * mask[j];
                let gx = patch[(i + 1) * (n + 2) + j + 2] - patch[(i + 1) * (n + 2) + j];
                let gy = patch[(i + 2) * (n + 2) + j + 1] - patch[i * (n + 2) + j + 1];
                let (gxx, gxy, gyy) = (gx * gx * m, gx * gy * m, gy * gy * m);
                let (px, py) = ((j as isize - hw) as f64, (i as isize - hw) as f64);
                a += gxx;
                b += gxy;
                cc += gyy;
                bb1 += gxx * px + gxy * py;
                bb2 += gxy * px + gyy * py;
            }
        }
        let det = a * cc - b * b;
        if det.abs() <= f64::EPSILON * (a * cc).abs().max(1e-300) {
            return None;
        }
        let next = Vector2::new(c.x + (cc * bb1 - b * bb2) / det, c.y + (a * bb2 - b * bb1) / det);
        let step = (next - c).norm();
        c = next;
        if !(c.x >= 0.0 && c.y >= 0.0 && c.x <= w - 1.0 && c.y <= h - 1.0) {
            return None;
        }
        if step < SUBPIX_EPS {
            break;
        }
    }
    ((c - start).norm() <= half_window as f64).then_some(c)
}

/// Pixels at or above this value are treated as saturated (censored) by [`fit_junction`]: the
/// IR camera's glare clips white paper at 255, and a clipped pixel only says "at least 255".
const SATURATED: f64 = 254.5;
/// Iterations and convergence threshold (px) of [`fit_junction`]'s Levenberg–Marquardt.
const FIT_MAX_ITERATIONS: usize = 40;
const FIT_EPS: f64 = 1e-5;
/// Wider junction-fit windows first converge on the pixels within this radius (px), then
/// take at most [`FIT_FINAL_ITERATIONS`] steps on the whole window: same result (the full
/// window's minimum), a fraction of the cost on 1080p boards.
const FIT_COARSE_RADIUS: f64 = 8.0;
const FIT_FINAL_ITERATIONS: usize = 3;
/// Fewest unsaturated pixels for a junction fit (9 parameters; 30 gives a well-posed fit).
const FIT_MIN_PIXELS: usize = 30;

/// `erf(x)` given `q = exp(−x²)` (which the fit needs anyway for the derivative):
/// Abramowitz & Stegun 7.1.26, absolute error ≤ 1.5e-7 — 2e-5 grey levels at a contrast of
/// 255, far below the images' noise — at a third of the cost of a full-precision `erf`.
#[inline]
fn erf_with_gauss(x: f64, q: f64) -> f64 {
    const P: f64 = 0.327_591_1;
    const A: [f64; 5] =
        [0.254_829_592, -0.284_496_736, 1.421_413_741, -1.453_152_027, 1.061_405_429];
    let t = 1.0 / (1.0 + P * x.abs());
    let y = 1.0 - t * (A[0] + t * (A[1] + t * (A[2] + t * (A[3] + t * A[4])))) * q;
    if x < 0.0 { -y } else { y }
}

/// Maximum-likelihood sub-pixel X-junction: fits the model of a blurred checker corner,
/// `I(x) = (m + a·E(d₁)·E(d₂))·(1 + g·(x − x₀))`, `E(d) = erf(d / (√2·σ))`, `dᵢ` the signed
/// distance to edge line `i` through the corner, to the pixels within `radius` of `start` by
/// Levenberg–Marquardt (9 parameters: corner, two edge angles, mean, contrast, blur, and a
/// linear brightness gradient for vignetting and glare). Saturated pixels are censored.
///
/// Unlike `cornerSubPix`'s gradient-orthogonality normal equations, whose flat-area pixels add
/// gradient noise with a lever arm, every pixel here is weighted by how much it says about
/// the corner, so a wide window keeps lowering the noise (the rendered set's corner error
/// halves). The blur of two non-orthogonal edges is not exactly a product of `erf`s, but the
/// mismatch is point-symmetric about the corner and does not move it. `dirs` are the image
/// directions of the two grid lines (any sign). `None` when the fit fails or leaves the
/// window's centre by more than 1 px.
pub fn fit_junction(
    img: &Image<f32>,
    start: Vector2<f64>,
    dirs: [Vector2<f64>; 2],
    radius: f64,
) -> Option<Vector2<f64>> {
    fit_junction_with_std(img, start, dirs, radius).map(|f| f.0)
}

/// [`fit_junction`] with the corner's 1σ (px, the larger axis of its covariance), from the
/// fit's Jacobian and residual variance.
pub fn fit_junction_with_std(
    img: &Image<f32>,
    start: Vector2<f64>,
    dirs: [Vector2<f64>; 2],
    radius: f64,
) -> Option<(Vector2<f64>, f64)> {
    use nalgebra::{SMatrix, SVector};
    let (w, h) = (img.width() as isize, img.height() as isize);
    let r = radius.floor() as isize;
    let (ox, oy) = (start.x.round() as isize, start.y.round() as isize);
    let mut pix: Vec<(f64, f64, f64)> = Vec::with_capacity(((2 * r + 1) * (2 * r + 1)) as usize);
    for y in (oy - r).max(0)..=(oy + r).min(h - 1) {
        for x in (ox - r).max(0)..=(ox + r).min(w - 1) {
            let (u, v) = (x as f64 - start.x, y as f64 - start.y);
            if u * u + v * v <= radius * radius {
                pix.push((x as f64, y as f64, *img.get(x as usize, y as usize) as f64));
            }
        }
    }
    if pix.iter().filter(|p| p.2 < SATURATED).count() < FIT_MIN_PIXELS {
        return None;
    }
    let th = |d: Vector2<f64>| d.y.atan2(d.x);
    let m0 = pix.iter().map(|p| p.2).sum::<f64>() / pix.len() as f64;
    let sign = |t: f64, x: f64, y: f64| {
        let d = -t.sin() * (x - start.x) + t.cos() * (y - start.y);
        if d >= 0.0 { 1.0 } else { -1.0 }
    };
    let (t1, t2) = (th(dirs[0]), th(dirs[1]));
    let a0 = pix.iter().map(|p| (p.2 - m0) * sign(t1, p.0, p.1) * sign(t2, p.0, p.1)).sum::<f64>()
        / pix.len() as f64;
    // p = [cx, cy, θ1, θ2, m, a, σ, gx, gy]
    let p =
        SVector::<f64, 9>::from_column_slice(&[start.x, start.y, t1, t2, m0, a0, 1.0, 0.0, 0.0]);
    let sqrt_2_pi = (2.0 / std::f64::consts::PI).sqrt();
    let eval = |pix: &[(f64, f64, f64)],
                p: &SVector<f64, 9>,
                jac: bool|
     -> (f64, SMatrix<f64, 9, 9>, SVector<f64, 9>) {
        let (s1, c1, s2, c2) = (p[2].sin(), p[2].cos(), p[3].sin(), p[3].cos());
        let (m, a, sg, gx, gy) = (p[4], p[5], p[6], p[7], p[8]);
        let k = 1.0 / (std::f64::consts::SQRT_2 * sg);
        let mut cost = 0.0;
        let mut jtj = SMatrix::<f64, 9, 9>::zeros();
        let mut jtr = SVector::<f64, 9>::zeros();
        for &(x, y, obs) in pix {
            let (u, v) = (x - p[0], y - p[1]);
            let (d1, d2) = (-s1 * u + c1 * v, -s2 * u + c2 * v);
            let (x1, x2) = (d1 * k, d2 * k);
            let (q1, q2) = ((-x1 * x1).exp(), (-x2 * x2).exp());
            let (e1, e2) = (erf_with_gauss(x1, q1), erf_with_gauss(x2, q2));
            let pp = m + a * e1 * e2;
            let l = 1.0 + gx * (x - start.x) + gy * (y - start.y);
            let f = pp * l;
            if obs >= SATURATED && f >= obs {
                continue;
            }
            let res = f - obs;
            cost += res * res;
            if !jac {
                continue;
            }
            let g1 = sqrt_2_pi / sg * q1;
            let g2 = sqrt_2_pi / sg * q2;
            let al = a * l;
            let j = SVector::<f64, 9>::from_column_slice(&[
                al * (g1 * s1 * e2 + e1 * g2 * s2),
                al * (-g1 * c1 * e2 - e1 * g2 * c2),
                al * g1 * (-c1 * u - s1 * v) * e2,
                al * e1 * g2 * (-c2 * u - s2 * v),
                l,
                e1 * e2 * l,
                al * (-(d1 / sg) * g1 * e2 - e1 * (d2 / sg) * g2),
                pp * (x - start.x),
                pp * (y - start.y),
            ]);
            jtj.ger(1.0, &j, &j, 1.0);
            jtr.axpy(res, &j, 1.0);
        }
        (cost, jtj, jtr)
    };
    let lm = |pix: &[(f64, f64, f64)],
              mut p: SVector<f64, 9>,
              iterations: usize|
     -> Option<(SVector<f64, 9>, f64, SMatrix<f64, 9, 9>)> {
        let mut lambda = 1e-3;
        let (mut cost, mut jtj, mut jtr) = eval(pix, &p, true);
        for _ in 0..iterations {
            let mut a = jtj;
            for i in 0..9 {
                a[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&(-jtr))) else {
                lambda *= 10.0;
                if lambda > 1e8 {
                    return None;
                }
                continue;
            };
            let next = p + step;
            let (c2, _, _) = eval(pix, &next, false);
            if c2 < cost {
                p = next;
                lambda = (lambda * 0.3).max(1e-9);
                let moved = step.fixed_rows::<2>(0).norm();
                (cost, jtj, jtr) = eval(pix, &p, true);
                if moved < FIT_EPS {
                    break;
                }
            } else {
                lambda *= 10.0;
                if lambda > 1e8 {
                    break;
                }
            }
        }
        Some((p, cost, jtj))
    };
    let coarse: Vec<(f64, f64, f64)> = pix
        .iter()
        .copied()
        .filter(|q| {
            (q.0 - start.x).powi(2) + (q.1 - start.y).powi(2)
                <= FIT_COARSE_RADIUS * FIT_COARSE_RADIUS
        })
        .collect();
    let (p, cost, jtj) = if radius > FIT_COARSE_RADIUS
        && coarse.iter().filter(|q| q.2 < SATURATED).count() >= FIT_MIN_PIXELS
    {
        let (p1, _, _) = lm(&coarse, p, FIT_MAX_ITERATIONS)?;
        lm(&pix, p1, FIT_FINAL_ITERATIONS)?
    } else {
        lm(&pix, p, FIT_MAX_ITERATIONS)?
    };
    let c = Vector2::new(p[0], p[1]);
    let ok = p.iter().all(|v| v.is_finite())
        && (c - start).norm() <= 1.0
        && p[6] > 0.1
        && p[6] < radius
        && p[5].abs() > 0.0;
    if !ok {
        return None;
    }
    let dof = (pix.len() as f64 - 9.0).max(1.0);
    let cov = jtj.try_inverse()? * (cost / dof);
    let sub = cov.fixed_view::<2, 2>(0, 0).into_owned();
    let std = sub.symmetric_eigenvalues().max().max(0.0).sqrt();
    Some((c, std))
}

/// Candidate X-junctions: local maxima of the ChESS response, refined to sub-pixel.
pub fn candidates(img: &Image<f32>, params: &DetectorParams) -> Vec<(Vector2<f64>, f32)> {
    let resp = chess_response(img, params.ring_radius);
    let (w, h) = resp.size();
    let max = resp.data().iter().copied().fold(0.0f32, f32::max);
    if max <= 0.0 {
        return Vec::new();
    }
    let thr = max * params.min_response_fraction;
    let nms = params.ring_radius as isize;
    let mut peaks = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let v = *resp.get(x, y);
            if v <= thr {
                continue;
            }
            let mut is_max = true;
            'outer: for dy in -nms..=nms {
                for dx in -nms..=nms {
                    let (xx, yy) = (x as isize + dx, y as isize + dy);
                    if (dx, dy) == (0, 0)
                        || xx < 0
                        || yy < 0
                        || xx >= w as isize
                        || yy >= h as isize
                    {
                        continue;
                    }
                    let o = *resp.get(xx as usize, yy as usize);
                    if o > v || (o == v && (dy, dx) < (0, 0)) {
                        is_max = false;
                        break 'outer;
                    }
                }
            }
            if is_max {
                peaks.push((x, y, v));
            }
        }
    }
    peaks.sort_by(|a, b| b.2.total_cmp(&a.2));
    peaks.truncate(MAX_CANDIDATES);
    use rayon::prelude::*;
    let mut refined: Vec<(Vector2<f64>, f32)> = peaks
        .par_iter()
        .filter_map(|&(x, y, v)| {
            refine_corner(img, Vector2::new(x as f64, y as f64), params.subpix_half_window)
                .map(|p| (p, v))
        })
        .collect();
    // Two peaks refining onto one corner: keep the stronger.
    let mut keep: Vec<(Vector2<f64>, f32)> = Vec::with_capacity(refined.len());
    refined.sort_by(|a, b| b.1.total_cmp(&a.1));
    for c in refined {
        if keep.iter().all(|k| (k.0 - c.0).norm() > 2.0) {
            keep.push(c);
        }
    }
    keep
}

type Grid = std::collections::HashMap<(i32, i32), usize>;

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
            if cos.abs() > 0.6 || db > 2.0 * da || da > 2.0 * db {
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

/// Detects the board in a grey image (0–255 values).
pub fn detect(img: &Image<f32>, board: &Board, params: &DetectorParams) -> Option<Detection> {
    let pts = candidates(img, params);
    if pts.len() < 4 {
        return None;
    }
    // Grow from the strongest candidates; keep the largest grid.
    let mut best: Option<Grid> = None;
    let mut tried = vec![false; pts.len()];
    for s in 0..pts.len().min(60) {
        if tried[s] {
            continue;
        }
        if let Some(g) = grow(&pts, s) {
            for &i in g.values() {
                tried[i] = true;
            }
            if best.as_ref().is_none_or(|b| g.len() > b.len()) {
                best = Some(g);
            }
            if best.as_ref().is_some_and(|b| b.len() >= board.len()) {
                break;
            }
        }
    }
    let grid = trim(board, &pts, best?);
    label(img, board, &pts, &grid, params)
}

/// A grid larger than the board (spurious junctions where the board's border meets the
/// background line up with the grid): keep the board-sized window, in either orientation,
/// with the most corners and then the strongest total response.
fn trim(board: &Board, pts: &[(Vector2<f64>, f32)], grid: Grid) -> Grid {
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

/// Maps grid coordinates to board ids (see the module docs); `None` when not certain.
fn label(
    img: &Image<f32>,
    board: &Board,
    pts: &[(Vector2<f64>, f32)],
    grid: &Grid,
    params: &DetectorParams,
) -> Option<Detection> {
    let min_window = params.subpix_half_window;
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
    let map = |h: &Matrix3<f64>, x: f64, y: f64| {
        let q = h * Vector3::new(x, y, 1.0);
        Vector2::new(q.x / q.z, q.y / q.z)
    };
    let pos: std::collections::HashMap<(i32, i32), Vector2<f64>> = g.iter().copied().collect();
    // Cell colours: +1 bright, -1 dark, relative to the mean of the cell's corner neighbourhood.
    let mut cells = Vec::new();
    for i in -1..ni {
        for j in -1..nj {
            let corners = [(i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1)];
            let known: Vec<Vector2<f64>> =
                corners.iter().filter_map(|k| pos.get(k).copied()).collect();
            let centre = if known.len() == 4 {
                known.iter().sum::<Vector2<f64>>() / 4.0
            } else if i >= 0 && j >= 0 && i + 1 < ni && j + 1 < nj {
                map(&hgrid, i as f64 + 0.5, j as f64 + 0.5)
            } else if !known.is_empty() {
                // Outer cells (the board's border squares): use the grid homography.
                map(&hgrid, i as f64 + 0.5, j as f64 + 0.5)
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
    let cell_map: std::collections::HashMap<(i32, i32), f64> = cells.iter().copied().collect();
    let mut even_dark = 0.0f64;
    let mut n = 0.0f64;
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
        let dark = v < nb.iter().sum::<f64>() / nb.len() as f64;
        let even = (i + j).rem_euclid(2) == 0;
        even_dark += if even == dark { 1.0 } else { 0.0 };
        n += 1.0;
    }
    if n < 1.0 {
        return None;
    }
    let agreement = (even_dark / n).max(1.0 - even_dark / n);
    if agreement < MIN_CHECKER_AGREEMENT {
        return None;
    }
    // In grid coordinates, cell (i, j) (upper-left corner (i, j)) is dark iff parity matches.
    let dark_parity = if even_dark / n >= 0.5 { 0 } else { 1 };

    // Candidate labellings: axis assignment and signs, never mirrored.
    let (cols, rows) = (board.cols as i32, board.rows as i32);
    let p0 = map(&hgrid, 0.0, 0.0);
    let px_ = map(&hgrid, 1.0, 0.0) - p0;
    let py_ = map(&hgrid, 0.0, 1.0) - p0;
    let grid_handed = px_.x * py_.y - px_.y * py_.x > 0.0;
    struct Cand {
        black: bool,
        swap: bool,
        si: i32,
        sj: i32,
        ox: i32,
        oy: i32,
    }
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
    let to_board = |c: &Cand, i: i32, j: i32| -> (i32, i32) {
        let (a, b) = if c.swap { (j, i) } else { (i, j) };
        let (ea, eb) = if c.swap { (nj, ni) } else { (ni, nj) };
        let bx = if c.si > 0 { a } else { ea - 1 - a };
        let by = if c.sj > 0 { b } else { eb - 1 - b };
        (bx + c.ox, by + c.oy)
    };
    // Colour: board square up-left of inner corner (bx, by) is square (bx, by), dark iff
    // bx + by even. The grid cell with upper-left corner (i, j) spans board corners whose
    // up-left square is the board square at the cell's minimum board corner + 1 offsets...
    // Simplest exact test: the cell's centre maps to board square coordinates.
    let cell_dark_board = |c: &Cand, i: i32, j: i32| -> bool {
        // Board coordinates of the cell's centre, in corner units: corners (i,j) and (i+1,j+1).
        let (b0x, b0y) = to_board(c, i, j);
        let (b1x, b1y) = to_board(c, i + 1, j + 1);
        // The square between inner corners (x, y) and (x+1, y+1) is square (x+1, y+1).
        let sx = b0x.min(b1x) + 1;
        let sy = b0y.min(b1y) + 1;
        ((sx + sy).rem_euclid(2) == 0) == c.black
    };
    let cands: Vec<Cand> = cands
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
    // Among the survivors, the 180° twins differ only by orientation: keep the one whose
    // board x axis points most to the right in the image.
    let dir_x = |c: &Cand| -> f64 {
        let a = if c.swap { py_ } else { px_ };
        (a * c.si as f64).normalize().x
    };
    let mut ok = ok;
    ok.sort_by(|a, b| dir_x(b).total_cmp(&dir_x(a)));
    let chosen = ok.first()?;
    // Certain only if every other survivor is the 180° twin of the chosen one.
    let twin_ok = |c: &Cand| {
        c.black == chosen.black && c.swap == chosen.swap && c.si == -chosen.si && c.sj == -chosen.sj
    };
    let same = |c: &Cand| {
        c.black == chosen.black
            && c.swap == chosen.swap
            && c.si == chosen.si
            && c.sj == chosen.sj
            && c.ox == chosen.ox
            && c.oy == chosen.oy
    };
    if ok.iter().any(|c| !(same(c) || twin_ok(c))) {
        return None;
    }
    // Final refinement with a window fitted to the local grid step: more pixels average out
    // more noise, and the window stays clear of the neighbouring corners.
    let factor = if img.width() > SMALL_IMAGE_WIDTH {
        FINAL_WINDOW_FRACTION_LARGE
    } else {
        FINAL_WINDOW_FRACTION_SMALL
    };
    let mut corners: Vec<Corner> = g
        .iter()
        .map(|&((i, j), p)| {
            let (bx, by) = to_board(chosen, i, j);
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
                map(&hgrid, i as f64 + 1.0, j as f64) - map(&hgrid, i as f64, j as f64),
                map(&hgrid, i as f64, j as f64 + 1.0) - map(&hgrid, i as f64, j as f64),
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
            Corner { id: (by * cols + bx) as usize, px }
        })
        .collect();
    corners.sort_by_key(|c| c.id);
    let complete = corners.len() == board.len();
    Some(Detection { corners, complete, top_left_black: chosen.black })
}

/// Converts an 8-bit grey image to the detector's input.
pub fn to_f32(img: &Image<u8>) -> Image<f32> {
    img.map(|&v| v as f32)
}

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

#[cfg(test)]
mod tests {
    use super::*;

    /// Tolerance: none. The row-slice ChESS response equals the per-pixel textbook formula
    /// (16 ring samples gathered per pixel) bit for bit, on a non-square image with structure
    /// everywhere, for both ring radii, borders included.
    #[test]
    fn chess_response_equals_the_per_pixel_formula() {
        let (w, h) = (97, 61);
        let img = Image::from_fn(w, h, |x, y| {
            let checker = if ((x / 9) + (y / 7)) % 2 == 0 { 200.0 } else { 30.0 };
            checker + ((x * 37 + y * 91) % 23) as f32 * 0.7
        });
        for radius in [5usize, 7] {
            let got = chess_response(&img, radius);
            let ring: Vec<(isize, isize)> = (0..16)
                .map(|n| {
                    let a = n as f64 * std::f64::consts::TAU / 16.0;
                    (
                        (radius as f64 * a.cos()).round() as isize,
                        (radius as f64 * a.sin()).round() as isize,
                    )
                })
                .collect();
            let at = |x: usize, y: usize, dx: isize, dy: isize| {
                *img.get((x as isize + dx) as usize, (y as isize + dy) as usize)
            };
            for y in 0..h {
                for x in 0..w {
                    let want = if x < radius || y < radius || x + radius >= w || y + radius >= h {
                        0.0
                    } else {
                        let s: Vec<f32> = ring.iter().map(|&(dx, dy)| at(x, y, dx, dy)).collect();
                        let mut sum = 0.0;
                        for n in 0..4 {
                            sum += ((s[n] + s[n + 8]) - (s[n + 4] + s[n + 12])).abs();
                        }
                        let mut diff = 0.0;
                        for n in 0..8 {
                            diff += (s[n] - s[n + 8]).abs();
                        }
                        let mean = s.iter().sum::<f32>() / 16.0;
                        let local = (at(x, y, 0, 0)
                            + at(x, y, -1, 0)
                            + at(x, y, 1, 0)
                            + at(x, y, 0, -1)
                            + at(x, y, 0, 1))
                            / 5.0;
                        sum - diff - 16.0 * (mean - local).abs()
                    };
                    assert_eq!(
                        got.get(x, y).to_bits(),
                        want.to_bits(),
                        "radius {radius}, ({x}, {y})"
                    );
                }
            }
        }
    }

    #[test]
    fn fast_erf_matches_tabulated_values() {
        // erf to 16 digits (Abramowitz & Stegun table 7.1 / any CAS); the approximation's
        // documented bound is 1.5e-7.
        for (x, erf) in [
            (0.0, 0.0),
            (0.1, 0.112_462_916_018_284_9),
            (0.5, 0.520_499_877_813_046_5),
            (1.0, 0.842_700_792_949_714_9),
            (2.0, 0.995_322_265_018_952_7),
            (3.5, 0.999_999_256_901_627_7),
        ] {
            for (x, erf) in [(x, erf), (-x, -erf)] {
                let got = erf_with_gauss(x, (-x * x).exp());
                assert!((got - erf).abs() < 1.5e-7, "erf({x}) = {got}, expected {erf}");
            }
        }
    }

    /// A blurred X-junction rendered analytically (8x8 supersampling of the sharp pattern,
    /// then a 3x3 binomial blur) with its corner at a known sub-pixel position.
    fn junction(cx: f64, cy: f64, angle: f64, skew: f64) -> Image<f32> {
        let (a1, a2) = (angle, angle + std::f64::consts::FRAC_PI_2 + skew);
        let sharp = Image::from_fn(64, 64, |x, y| {
            let mut acc = 0.0;
            for i in 0..8 {
                for j in 0..8 {
                    let (u, v) = (
                        x as f64 + (i as f64 + 0.5) / 8.0 - 0.5 - cx,
                        y as f64 + (j as f64 + 0.5) / 8.0 - 0.5 - cy,
                    );
                    let s = (-a1.sin() * u + a1.cos() * v).signum()
                        * (-a2.sin() * u + a2.cos() * v).signum();
                    acc += if s > 0.0 { 200.0 } else { 40.0 };
                }
            }
            (acc / 64.0) as f32
        });
        let k = [1.0, 2.0, 1.0];
        Image::from_fn(64, 64, |x, y| {
            let mut acc = 0.0;
            for (dj, kj) in k.iter().enumerate() {
                for (di, ki) in k.iter().enumerate() {
                    acc += kj
                        * ki
                        * px(&sharp, x as isize + di as isize - 1, y as isize + dj as isize - 1);
                }
            }
            acc / 16.0
        })
    }

    #[test]
    fn junction_fit_recovers_a_known_corner() {
        // Noise-free, tilted and sheared junctions: the pattern is exact up to the 1/8 px
        // supersampling, so the fit must land within 0.01 px (cornerSubPix's own error on
        // such images is several times that; the fit starts 0.4 px away).
        for (cx, cy, angle, skew) in
            [(31.3, 30.7, 0.2, 0.0), (32.45, 31.1, -0.5, 0.3), (30.8, 32.25, 1.0, -0.4)]
        {
            let img = junction(cx, cy, angle, skew);
            let dirs = [
                Vector2::new(angle.cos(), angle.sin()),
                Vector2::new(
                    (angle + std::f64::consts::FRAC_PI_2 + skew).cos(),
                    (angle + std::f64::consts::FRAC_PI_2 + skew).sin(),
                ),
            ];
            let start = Vector2::new(cx + 0.3, cy - 0.25);
            let (p, std) = fit_junction_with_std(&img, start, dirs, 12.0).expect("fits");
            let err = (p - Vector2::new(cx, cy)).norm();
            assert!(err < 0.01, "({cx}, {cy}): error {err} px");
            assert!(std < 0.01, "σ {std}");
        }
    }
}
