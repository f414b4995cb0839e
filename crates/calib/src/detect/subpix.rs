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
