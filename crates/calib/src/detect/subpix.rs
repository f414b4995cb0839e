//! Stage 2, sub-pixel: OpenCV's `cornerSubPix` estimator, and the clamped pixel reads the
//! other stages share.

use geometry::Image;
use nalgebra::Vector2;

/// Iterations and convergence threshold (px) of the sub-pixel refinement.
const SUBPIX_MAX_ITERATIONS: usize = 40;
const SUBPIX_EPS: f64 = 1e-4;

#[inline]
pub(super) fn px(img: &Image<f32>, x: isize, y: isize) -> f32 {
    let x = x.clamp(0, img.width() as isize - 1) as usize;
    let y = y.clamp(0, img.height() as isize - 1) as usize;
    *img.get(x, y)
}

/// Bilinear sample with clamping at the borders.
#[inline]
pub(super) fn bilinear(img: &Image<f32>, x: f64, y: f64) -> f64 {
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

/// OpenCV's `cornerSubPix` estimator around `start`. `None` when it leaves the window or the
/// image, or the gradient matrix is singular (no corner there).
pub fn refine_corner(
    img: &Image<f32>,
    start: Vector2<f64>,
    half_window: usize,
) -> Option<Vector2<f64>> {
    let hw = half_window as isize;
    let mut c = start;
    let (w, h) = (img.width(), img.height());
    let n = 2 * half_window + 1;
    let mask: Vec<f64> = (0..n)
        .map(|i| {
            let t = (i as f64 - half_window as f64) / half_window as f64;
            (-t * t).exp()
        })
        .collect();
    // The window's weights, `mask[i] * mask[j]`, once for all iterations.
    let weights: Vec<f64> = mask.iter().flat_map(|mi| mask.iter().map(move |mj| mi * mj)).collect();
    let mut patch = vec![0.0f64; (n + 2) * (n + 2)];
    let mut raw = vec![0.0f64; (n + 3) * (n + 3)];
    // `raw` blended along x: row i, column j is `raw[i][j] (1 − fx) + raw[i][j + 1] fx`.
    let mut across = vec![0.0f64; (n + 3) * (n + 2)];
    let data = img.data();
    let stride = img.width();
    for _ in 0..SUBPIX_MAX_ITERATIONS {
        // The window's samples sit at integer offsets from `c`, so they share one pair of
        // bilinear weights: read the (n + 3)² pixels under the window once (clamped at the
        // borders) and blend them, instead of four clamped reads per sample.
        let (x0, y0) = (c.x.floor(), c.y.floor());
        let (fx, fy) = (c.x - x0, c.y - y0);
        let (xs, ys) = (x0 as isize - hw - 1, y0 as isize - hw - 1);
        let m = (n + 3) as isize;
        if xs >= 0 && ys >= 0 && xs + m <= w as isize && ys + m <= h as isize {
            for (i, row) in raw.chunks_mut(n + 3).enumerate() {
                let start = (ys as usize + i) * stride + xs as usize;
                for (r, &v) in row.iter_mut().zip(&data[start..start + n + 3]) {
                    *r = v as f64;
                }
            }
        } else {
            for (i, row) in raw.chunks_mut(n + 3).enumerate() {
                for (j, r) in row.iter_mut().enumerate() {
                    *r = px(img, xs + j as isize, ys + i as isize) as f64;
                }
            }
        }
        // The bilinear blend `(a (1 − fx) + b fx) (1 − fy) + (c (1 − fx) + d fx) fy`, its
        // two x blends computed once per raw row instead of once per patch row using it
        // (the same operations on the same values: the same bits).
        for (src, dst) in raw.chunks_exact(n + 3).zip(across.chunks_exact_mut(n + 2)) {
            for (v, pair) in dst.iter_mut().zip(src.windows(2)) {
                *v = pair[0] * (1.0 - fx) + pair[1] * fx;
            }
        }
        for (i, row) in patch.chunks_exact_mut(n + 2).enumerate() {
            let (top, bottom) = (&across[i * (n + 2)..], &across[(i + 1) * (n + 2)..]);
            for ((v, t), b) in row.iter_mut().zip(top).zip(bottom) {
                *v = t * (1.0 - fy) + b * fy;
            }
        }
        let (mut a, mut b, mut cc, mut bb1, mut bb2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..n {
            let (above, here, below) = (
                &patch[i * (n + 2)..(i + 1) * (n + 2)],
                &patch[(i + 1) * (n + 2)..(i + 2) * (n + 2)],
                &patch[(i + 2) * (n + 2)..(i + 3) * (n + 2)],
            );
            let py = (i as isize - hw) as f64;
            for (j, &m) in weights[i * n..(i + 1) * n].iter().enumerate() {
                let gx = here[j + 2] - here[j];
                let gy = below[j + 1] - above[j + 1];
                let (gxx, gxy, gyy) = (gx * gx * m, gx * gy * m, gy * gy * m);
                let px = (j as isize - hw) as f64;
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
        if !(c.x >= 0.0 && c.y >= 0.0 && c.x <= w as f64 - 1.0 && c.y <= h as f64 - 1.0) {
            return None;
        }
        // Left the window: no corner here (most peaks that are not corners drift away; this
        // spares their remaining iterations).
        if (c - start).norm() > half_window as f64 {
            return None;
        }
        if step < SUBPIX_EPS {
            break;
        }
    }
    ((c - start).norm() <= half_window as f64).then_some(c)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `cornerSubPix` as first written: every patch sample blended from its four clamped
    /// pixels, the weight `mask[i] * mask[j]` formed per sample.
    fn reference(
        img: &Image<f32>,
        start: Vector2<f64>,
        half_window: usize,
    ) -> Option<Vector2<f64>> {
        let hw = half_window as isize;
        let n = 2 * half_window + 1;
        let mask: Vec<f64> = (0..n)
            .map(|i| {
                let t = (i as f64 - half_window as f64) / half_window as f64;
                (-t * t).exp()
            })
            .collect();
        let (w, h) = (img.width() as f64, img.height() as f64);
        let mut c = start;
        for _ in 0..SUBPIX_MAX_ITERATIONS {
            let (x0, y0) = (c.x.floor(), c.y.floor());
            let (fx, fy) = (c.x - x0, c.y - y0);
            // Patch sample (i, j) sits at offset (j − hw − 1, i − hw − 1) from the pixel
            // (x0, y0).
            let p = |i: usize, j: usize| {
                let (x, y) = (x0 as isize + j as isize - hw - 1, y0 as isize + i as isize - hw - 1);
                let (a, b) = (px(img, x, y) as f64, px(img, x + 1, y) as f64);
                let (cl, d) = (px(img, x, y + 1) as f64, px(img, x + 1, y + 1) as f64);
                (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (cl * (1.0 - fx) + d * fx) * fy
            };
            let (mut a, mut b, mut cc, mut bb1, mut bb2) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for i in 0..n {
                for j in 0..n {
                    let m = mask[i] * mask[j];
                    let gx = p(i + 1, j + 2) - p(i + 1, j);
                    let gy = p(i + 2, j + 1) - p(i, j + 1);
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
            let next =
                Vector2::new(c.x + (cc * bb1 - b * bb2) / det, c.y + (a * bb2 - b * bb1) / det);
            let step = (next - c).norm();
            c = next;
            if !(c.x >= 0.0 && c.y >= 0.0 && c.x <= w - 1.0 && c.y <= h - 1.0) {
                return None;
            }
            if (c - start).norm() > half_window as f64 {
                return None;
            }
            if step < SUBPIX_EPS {
                break;
            }
        }
        ((c - start).norm() <= half_window as f64).then_some(c)
    }

    /// Tolerance: none. The refinement equals the per-sample reference bit for bit, from
    /// starts on a grid over a smooth rotated X-junction image (corners near the middle and
    /// near the border, where the window's reads are clamped), for both window sizes; some
    /// starts converge, some leave the window.
    #[test]
    fn refine_corner_equals_the_per_sample_reference() {
        let (w, h) = (61, 47);
        let (cx, cy, (s, co)) = (30.37, 22.81, 0.3f64.sin_cos());
        let img = Image::from_fn(w, h, |x, y| {
            let (dx, dy) = (x as f64 - cx, y as f64 - cy);
            let (u, v) = (co * dx + s * dy, -s * dx + co * dy);
            (128.0 + 100.0 * (u / 1.5).tanh() * (v / 1.5).tanh() + ((x * y) % 7) as f64) as f32
        });
        let (mut found, mut lost) = (0, 0);
        for half_window in [4usize, 5] {
            for sy in (1..h).step_by(3) {
                for sx in (1..w).step_by(3) {
                    let start = Vector2::new(sx as f64 + 0.25, sy as f64 - 0.4);
                    let got = refine_corner(&img, start, half_window);
                    let want = reference(&img, start, half_window);
                    assert_eq!(
                        got.map(|p| (p.x.to_bits(), p.y.to_bits())),
                        want.map(|p| (p.x.to_bits(), p.y.to_bits())),
                        "half window {half_window}, start {start:?}"
                    );
                    match got {
                        Some(p) if (p - Vector2::new(cx, cy)).norm() < 0.1 => found += 1,
                        None => lost += 1,
                        Some(_) => {}
                    }
                }
            }
        }
        assert!(found > 5 && lost > 5, "{found} starts found the corner, {lost} were lost");
    }
}
