//! Stage 5, junction fit: the maximum-likelihood fit of a blurred X-junction model, the
//! default final sub-pixel estimator of the labelled corners.

use geometry::Image;
use nalgebra::Vector2;

mod kernel;
use kernel::{Lanes, eval_lanes};

/// Pixels at or above this value are treated as saturated (censored) by [`fit_junction`]: the
/// IR camera's glare clips white paper at 255, and a clipped pixel only says "at least 255".
const SATURATED: f64 = 254.5;
/// Iterations and convergence threshold (px) of [`fit_junction`]'s Levenberg–Marquardt: a
/// step that moves the corner by less than this ends the fit (after an accepted step, without
/// evaluating the model there). The rendered set's figures are the same to the printed digits
/// with 1e-5, 1e-4 and 3e-4 px, but 1e-4 px lost a partial GoPro view of the corpus and
/// raised its RMS from 0.516 to 0.519 px.
const FIT_MAX_ITERATIONS: usize = 40;
const FIT_EPS: f64 = 1e-5;
/// Wider junction-fit windows first converge on the pixels within this radius (px), then
/// take at most [`FIT_FINAL_ITERATIONS`] steps on the whole window: same result (the full
/// window's minimum), a fraction of the cost on 1080p boards.
const FIT_COARSE_RADIUS: f64 = 8.0;
const FIT_FINAL_ITERATIONS: usize = 3;
/// Convergence threshold (px) of the coarse stage: the final steps on the whole window move
/// the corner by 1e-3 to 5e-2 px anyway (traced on GoPro views of the corpus), so converging
/// the coarse fit to [`FIT_EPS`] (up to twice the iterations) was wasted. The rendered set's
/// corner errors and calibration figures are unchanged to the printed digits.
const FIT_COARSE_EPS: f64 = 1e-3;
/// Smallest σ (px) of an accepted fit: a sharper edge than that is below what the model
/// (blur without the pixel's own 1 px box, σ ≈ 0.29) can tell, and the corner is refined by
/// `cornerSubPix` instead.
const FIT_MIN_SIGMA: f64 = 0.1;
/// Fewest unsaturated pixels for a junction fit (9 parameters; 30 gives a well-posed fit).
const FIT_MIN_PIXELS: usize = 30;

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
    fit(img, start, dirs, radius).map(|f| f.0)
}

/// [`fit_junction`] with the corner's 1σ (px, the larger axis of its covariance), from the
/// fit's Jacobian and residual variance.
pub fn fit_junction_with_std(
    img: &Image<f32>,
    start: Vector2<f64>,
    dirs: [Vector2<f64>; 2],
    radius: f64,
) -> Option<(Vector2<f64>, f64)> {
    let (c, cost, jtj, n) = fit(img, start, dirs, radius)?;
    let dof = (n as f64 - 9.0).max(1.0);
    let cov = jtj.try_inverse()? * (cost / dof);
    let sub = cov.fixed_view::<2, 2>(0, 0).into_owned();
    let std = sub.symmetric_eigenvalues().max().max(0.0).sqrt();
    Some((c, std))
}

/// [`fit_junction`] with the final cost, JᵀJ and pixel count (for the corner's σ).
fn fit(
    img: &Image<f32>,
    start: Vector2<f64>,
    dirs: [Vector2<f64>; 2],
    radius: f64,
) -> Option<(Vector2<f64>, f64, nalgebra::SMatrix<f64, 9, 9>, usize)> {
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
    // Cost, JᵀJ and Jᵀr at `p`, eight pixels at a time in f32 (`Lanes`); sums are reduced to
    // f64 once per evaluation.
    let eval = |px: &Lanes, p: &SVector<f64, 9>| eval_lanes(px, p, start);
    // Levenberg–Marquardt; every trial point is evaluated with its Jacobian, which an accepted
    // step (the common case) then uses without a second pass over the pixels.
    let lm = |pix: &Lanes,
              mut p: SVector<f64, 9>,
              iterations: usize,
              eps: f64|
     -> Option<(SVector<f64, 9>, f64, SMatrix<f64, 9, 9>)> {
        let mut lambda = 1e-3;
        let (mut cost, mut jtj, mut jtr) = eval(pix, &p);
        let mut last_accepted = false;
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
            // A step below `eps` right after an accepted one ends the fit; it is taken without
            // evaluating the model there (that evaluation would only confirm it: its cost,
            // JᵀJ and Jᵀr differ from the current ones in the last digits), so the returned
            // cost and JᵀJ are those of the point one tiny step before. Not after a rejected
            // step or before the first accepted one: a damped or first step can be small in
            // position and still wrong in the other parameters, and needs its evaluation.
            let moved = step.fixed_rows::<2>(0).norm();
            if moved < eps && last_accepted {
                p += step;
                break;
            }
            let next = p + step;
            let trial = eval(pix, &next);
            if trial.0 < cost {
                p = next;
                lambda = (lambda * 0.3).max(1e-9);
                (cost, jtj, jtr) = trial;
                last_accepted = true;
                if moved < eps {
                    break;
                }
            } else {
                last_accepted = false;
                lambda *= 10.0;
                if lambda > 1e8 {
                    break;
                }
            }
        }
        Some((p, cost, jtj))
    };
    let within = |q: &(f64, f64, f64)| {
        (q.0 - start.x).powi(2) + (q.1 - start.y).powi(2) <= FIT_COARSE_RADIUS * FIT_COARSE_RADIUS
    };
    let all = Lanes::new(&pix, start);
    let coarse_unsaturated = pix.iter().filter(|q| within(q) && q.2 < SATURATED).count();
    let (p, cost, jtj) = if radius > FIT_COARSE_RADIUS && coarse_unsaturated >= FIT_MIN_PIXELS {
        let coarse: Vec<(f64, f64, f64)> = pix.iter().copied().filter(within).collect();
        let (p1, _, _) = lm(&Lanes::new(&coarse, start), p, FIT_MAX_ITERATIONS, FIT_COARSE_EPS)?;
        lm(&all, p1, FIT_FINAL_ITERATIONS, FIT_EPS)?
    } else {
        lm(&all, p, FIT_MAX_ITERATIONS, FIT_EPS)?
    };
    let c = Vector2::new(p[0], p[1]);
    let ok = p.iter().all(|v| v.is_finite())
        && (c - start).norm() <= 1.0
        // The model depends on σ only through E(d₁)·E(d₂), which is even in σ: a fit that
        // crossed to −σ is the same junction. (Rejecting those sent 733 of the corpus's
        // 3728 fits, a fifth, to the cornerSubPix fallback; accepting them lowers the
        // robot-arm and GoPro RMS and worst corner distances.)
        && p[6].abs() > FIT_MIN_SIGMA
        && p[6].abs() < radius
        && p[5].abs() > 0.0
        // A singular fit (no information on some parameter) is no corner estimate.
        && jtj.try_inverse().is_some();
    if !ok {
        return None;
    }
    Some((c, cost, jtj, pix.len()))
}

#[cfg(test)]
mod tests {
    use super::super::subpix::px;
    use super::*;

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
