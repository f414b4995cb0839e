//! Stage 5, junction fit: the maximum-likelihood fit of a blurred X-junction model, the
//! default final sub-pixel estimator of the labelled corners.

use geometry::Image;
use nalgebra::Vector2;
use wide::f32x8;

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

/// `erf(x)` given `q = exp(−x²)` (which the fit needs anyway for the derivative), eight
/// lanes at once: Abramowitz & Stegun 7.1.26, absolute error ≤ 1.5e-7 — 2e-5 grey levels at a
/// contrast of 255, far below the images' noise — at a third of the cost of a full-precision
/// `erf`. (Evaluated in f32: the rounding adds ≤ 3e-7.)
#[inline]
fn erf_with_gauss(x: f32x8, q: f32x8) -> f32x8 {
    const P: f32 = 0.327_591_1;
    const A: [f32; 5] = [0.254_829_6, -0.284_496_74, 1.421_413_7, -1.453_152_1, 1.061_405_4];
    let t = f32x8::ONE / f32x8::splat(P).mul_add(x.abs(), f32x8::ONE);
    let poly = f32x8::splat(A[4]).mul_add(t, f32x8::splat(A[3]));
    let poly = poly.mul_add(t, f32x8::splat(A[2]));
    let poly = poly.mul_add(t, f32x8::splat(A[1]));
    let poly = poly.mul_add(t, f32x8::splat(A[0]));
    let y = f32x8::ONE - t * poly * q;
    // erf is odd: give y the sign of x.
    y ^ (x & f32x8::splat(-0.0))
}

/// `exp(x)` for `x ≤ 0`, eight lanes at once, inlined (wide's `exp` handles every input and
/// was a function call, 45 % of the fit's time): Cody–Waite reduction to `r ∈ [−ln 2 / 2,
/// ln 2 / 2]` and Cephes' degree-7 polynomial for `expf` (≤ 2 ulp); arguments below −87 give
/// `exp(−87)` ≈ 1.6e-38 instead of a smaller number, which the fit cannot tell from 0.
#[inline(always)]
fn exp_nonpositive(x: f32x8) -> f32x8 {
    const LOG2_E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    const P: [f32; 6] = [
        1.987_569_1e-4,
        1.398_199_9e-3,
        8.333_452e-3,
        4.166_579_6e-2,
        1.666_666_5e-1,
        0.5, // Cephes: 5.0000001e-1, which rounds to 0.5 in f32
    ];
    let x = x.fast_max(f32x8::splat(-87.0));
    // Round to nearest: for y ≤ 0, round(y) = trunc(y − 0.5).
    let n = (x * f32x8::splat(LOG2_E) - f32x8::splat(0.5)).fast_trunc_int();
    let nf = f32x8::from_i32x8(n);
    let r = x - nf * f32x8::splat(LN2_HI) - nf * f32x8::splat(LN2_LO);
    let mut p = f32x8::splat(P[0]);
    for c in &P[1..] {
        p = p.mul_add(r, f32x8::splat(*c));
    }
    let e = (r * r).mul_add(p, r) + f32x8::ONE;
    let scale: f32x8 = wide::bytemuck::cast((n + wide::i32x8::splat(127)) << 23);
    e * scale
}

/// A fit window's pixels in lanes of eight (structure of arrays, the last lane padded with
/// weight 0): offsets from the fit's start point and observed values. f32 is exact for the
/// 8-bit values and keeps offsets below 1e-5 px of rounding within the ≤ 20 px window.
struct Lanes {
    /// `x − start.x`, `y − start.y`, observed value, 1 for a pixel and 0 for padding.
    u: Vec<f32x8>,
    v: Vec<f32x8>,
    obs: Vec<f32x8>,
    valid: Vec<f32x8>,
}

impl Lanes {
    fn new(pix: &[(f64, f64, f64)], start: Vector2<f64>) -> Self {
        let n = pix.len().div_ceil(8);
        let mut lanes = Self {
            u: Vec::with_capacity(n),
            v: Vec::with_capacity(n),
            obs: Vec::with_capacity(n),
            valid: Vec::with_capacity(n),
        };
        for chunk in pix.chunks(8) {
            let lane = |f: &dyn Fn(&(f64, f64, f64)) -> f32| {
                f32x8::new(std::array::from_fn(|i| chunk.get(i).map_or(0.0, f)))
            };
            lanes.u.push(lane(&|q| (q.0 - start.x) as f32));
            lanes.v.push(lane(&|q| (q.1 - start.y) as f32));
            lanes.obs.push(lane(&|q| q.2 as f32));
            lanes.valid.push(lane(&|_| 1.0));
        }
        lanes
    }
}

/// Cost, JᵀJ and Jᵀr of the junction model with parameters `p` (see [`fit_junction`]) over
/// `px`, whose offsets are from `start`. JᵀJ is accumulated as its upper triangle (45 products
/// per pixel instead of 81) and mirrored once at the end.
fn eval_lanes(
    px: &Lanes,
    p: &nalgebra::SVector<f64, 9>,
    start: Vector2<f64>,
) -> (f64, nalgebra::SMatrix<f64, 9, 9>, nalgebra::SVector<f64, 9>) {
    let s = |v: f64| f32x8::splat(v as f32);
    let (s1, c1, s2, c2) = (s(p[2].sin()), s(p[2].cos()), s(p[3].sin()), s(p[3].cos()));
    let (m, a, gx, gy) = (s(p[4]), s(p[5]), s(p[7]), s(p[8]));
    let (du, dv) = (s(p[0] - start.x), s(p[1] - start.y));
    let k = s(1.0 / (std::f64::consts::SQRT_2 * p[6]));
    let g = s((2.0 / std::f64::consts::PI).sqrt() / p[6]);
    let inv_sg = s(1.0 / p[6]);
    let saturated = f32x8::splat(SATURATED as f32);
    let mut cost = f32x8::ZERO;
    let mut upper = [f32x8::ZERO; 45];
    let mut jtr = [f32x8::ZERO; 9];
    for i in 0..px.u.len() {
        let (u0, v0, obs) = (px.u[i], px.v[i], px.obs[i]);
        let (u, v) = (u0 - du, v0 - dv);
        let (d1, d2) = (c1 * v - s1 * u, c2 * v - s2 * u);
        let (x1, x2) = (d1 * k, d2 * k);
        let (q1, q2) = (exp_nonpositive(-(x1 * x1)), exp_nonpositive(-(x2 * x2)));
        let (e1, e2) = (erf_with_gauss(x1, q1), erf_with_gauss(x2, q2));
        let pp = m + a * e1 * e2;
        let l = f32x8::ONE + gx * u0 + gy * v0;
        let f = pp * l;
        // A saturated pixel only says "at least 255": no residual where the model is above it.
        let censored = obs.simd_ge(saturated) & f.simd_ge(obs);
        let keep = px.valid[i].simd_gt(f32x8::ZERO) & !censored;
        let keep = keep & f32x8::ONE;
        let res = (f - obs) * keep;
        cost += res * res;
        let (g1, g2) = (g * q1, g * q2);
        let al = a * l * keep;
        let j = [
            al * (g1 * s1 * e2 + e1 * g2 * s2),
            -al * (g1 * c1 * e2 + e1 * g2 * c2),
            -al * g1 * (c1 * u + s1 * v) * e2,
            -al * e1 * g2 * (c2 * u + s2 * v),
            l * keep,
            e1 * e2 * l * keep,
            -al * (d1 * inv_sg * g1 * e2 + e1 * d2 * inv_sg * g2),
            pp * u0 * keep,
            pp * v0 * keep,
        ];
        let mut n = 0;
        for r in 0..9 {
            for c in r..9 {
                upper[n] = j[r].mul_add(j[c], upper[n]);
                n += 1;
            }
            jtr[r] = res.mul_add(j[r], jtr[r]);
        }
    }
    let sum = |v: f32x8| v.to_array().iter().map(|&x| x as f64).sum::<f64>();
    let mut jtj = nalgebra::SMatrix::<f64, 9, 9>::zeros();
    let mut n = 0;
    for r in 0..9 {
        for c in r..9 {
            jtj[(r, c)] = sum(upper[n]);
            jtj[(c, r)] = jtj[(r, c)];
            n += 1;
        }
    }
    (sum(cost), jtj, nalgebra::SVector::<f64, 9>::from_fn(|r, _| sum(jtr[r])))
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

    #[test]
    fn fast_erf_matches_tabulated_values() {
        // erf to 16 digits (Abramowitz & Stegun table 7.1 / any CAS); the approximation's
        // documented bound is 1.5e-7, f32 evaluation adds a few 1e-7.
        for (x, erf) in [
            (0.0, 0.0),
            (0.1, 0.112_462_916_018_284_9),
            (0.5, 0.520_499_877_813_046_5),
            (1.0, 0.842_700_792_949_714_9),
            (2.0, 0.995_322_265_018_952_7),
            (3.5, 0.999_999_256_901_627_7),
        ] {
            for (x, erf) in [(x, erf), (-x, -erf)] {
                let xs = f32x8::splat(x as f32);
                let got = erf_with_gauss(xs, (-(xs * xs)).exp()).to_array();
                // The bound plus f32 rounding (x itself rounds by up to 6e-8 · x).
                for g in got {
                    assert!((g as f64 - erf).abs() < 5e-7, "erf({x}) = {g}, expected {erf}");
                }
            }
        }
    }

    #[test]
    fn fast_exp_matches_std() {
        // Relative error against f64 `exp`: Cephes' expf bound is 2 ulp (≈ 2.4e-7); below
        // −87 the documented clamp.
        let mut x = 0.0f32;
        while x > -87.0 {
            let got = exp_nonpositive(f32x8::splat(x)).to_array()[0] as f64;
            let want = (x as f64).exp();
            assert!(((got - want) / want).abs() < 3e-7, "exp({x}) = {got}, expected {want}");
            x -= 0.013_7;
        }
        let clamped = exp_nonpositive(f32x8::splat(-200.0)).to_array()[0] as f64;
        assert!((clamped - (-87.0f64).exp()).abs() < 1e-43);
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
