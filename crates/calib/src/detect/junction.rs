//! Stage 5, junction fit: the maximum-likelihood fit of a blurred X-junction model, the
//! default final sub-pixel estimator of the labelled corners.

use geometry::Image;
use nalgebra::Vector2;

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
/// Convergence threshold (px) of the coarse stage: the final steps on the whole window move
/// the corner by 1e-3 to 5e-2 px anyway (traced on GoPro views of the corpus), so converging
/// the coarse fit to [`FIT_EPS`] (up to twice the iterations) was wasted. The rendered set's
/// corner errors and calibration figures are unchanged to the printed digits.
const FIT_COARSE_EPS: f64 = 1e-3;
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
    let sqrt_2_pi = (2.0 / std::f64::consts::PI).sqrt();
    // Cost, JᵀJ and Jᵀr at `p`. JᵀJ is accumulated as its upper triangle (45 products per
    // pixel instead of 81) and mirrored once at the end.
    let eval = |pix: &[(f64, f64, f64)],
                p: &SVector<f64, 9>|
     -> (f64, SMatrix<f64, 9, 9>, SVector<f64, 9>) {
        let (s1, c1, s2, c2) = (p[2].sin(), p[2].cos(), p[3].sin(), p[3].cos());
        let (m, a, sg, gx, gy) = (p[4], p[5], p[6], p[7], p[8]);
        let k = 1.0 / (std::f64::consts::SQRT_2 * sg);
        let mut cost = 0.0;
        let mut upper = [0.0f64; 45];
        let mut jtr = [0.0f64; 9];
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
            let g1 = sqrt_2_pi / sg * q1;
            let g2 = sqrt_2_pi / sg * q2;
            let al = a * l;
            let j = [
                al * (g1 * s1 * e2 + e1 * g2 * s2),
                al * (-g1 * c1 * e2 - e1 * g2 * c2),
                al * g1 * (-c1 * u - s1 * v) * e2,
                al * e1 * g2 * (-c2 * u - s2 * v),
                l,
                e1 * e2 * l,
                al * (-(d1 / sg) * g1 * e2 - e1 * (d2 / sg) * g2),
                pp * (x - start.x),
                pp * (y - start.y),
            ];
            let mut n = 0;
            for r in 0..9 {
                for c in r..9 {
                    upper[n] += j[r] * j[c];
                    n += 1;
                }
                jtr[r] += res * j[r];
            }
        }
        let mut jtj = SMatrix::<f64, 9, 9>::zeros();
        let mut n = 0;
        for r in 0..9 {
            for c in r..9 {
                jtj[(r, c)] = upper[n];
                jtj[(c, r)] = upper[n];
                n += 1;
            }
        }
        (cost, jtj, SVector::<f64, 9>::from_column_slice(&jtr))
    };
    // Levenberg–Marquardt; every trial point is evaluated with its Jacobian, which an accepted
    // step (the common case) then uses without a second pass over the pixels.
    let lm = |pix: &[(f64, f64, f64)],
              mut p: SVector<f64, 9>,
              iterations: usize,
              eps: f64|
     -> Option<(SVector<f64, 9>, f64, SMatrix<f64, 9, 9>)> {
        let mut lambda = 1e-3;
        let (mut cost, mut jtj, mut jtr) = eval(pix, &p);
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
            let trial = eval(pix, &next);
            if trial.0 < cost {
                p = next;
                lambda = (lambda * 0.3).max(1e-9);
                let moved = step.fixed_rows::<2>(0).norm();
                (cost, jtj, jtr) = trial;
                if moved < eps {
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
        let (p1, _, _) = lm(&coarse, p, FIT_MAX_ITERATIONS, FIT_COARSE_EPS)?;
        lm(&pix, p1, FIT_FINAL_ITERATIONS, FIT_EPS)?
    } else {
        lm(&pix, p, FIT_MAX_ITERATIONS, FIT_EPS)?
    };
    let c = Vector2::new(p[0], p[1]);
    let ok = p.iter().all(|v| v.is_finite())
        && (c - start).norm() <= 1.0
        && p[6] > 0.1
        && p[6] < radius
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
