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
    let mut patch = vec![0.0f64; (n + 2) * (n + 2)];
    let mut raw = vec![0.0f64; (n + 3) * (n + 3)];
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
        for (i, row) in patch.chunks_mut(n + 2).enumerate() {
            let (top, bottom) = (&raw[i * (n + 3)..], &raw[(i + 1) * (n + 3)..]);
            for (j, v) in row.iter_mut().enumerate() {
                let (a, b, c, d) = (top[j], top[j + 1], bottom[j], bottom[j + 1]);
                *v = (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy;
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
