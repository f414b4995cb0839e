//! Pinhole camera with Brown–Conrady distortion (OpenCV's model and parameter order).
//!
//! A 3D point `X = (X, Y, Z)` in the camera frame (x right, y down, z forward, metres) maps to
//! a pixel in three steps:
//!
//! 1. normalise: `x = X/Z`, `y = Y/Z`;
//! 2. distort: with `r² = x² + y²`,
//!    `x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²)`,
//!    `y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2 y²) + 2 p2 x y`;
//! 3. to pixels: `u = fx x_d + skew y_d + cx`, `v = fy y_d + cy` (0-based, integer = centre).
//!
//! `skew` is in pixels (OpenCV's `K[0][1]`; Bouguet's `alpha_c` times `fx`).
//! Undistortion inverts step 2 by Newton's method; it fails (returns `None`) where the model
//! folds over, i.e. beyond [`Distortion::fold_radius`].

use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::GeometryError;

/// Newton iterations allowed when undistorting one point. Kinect-like distortion converges
/// in 4-6; 30 leaves room for strong distortion near the fold.
const UNDISTORT_MAX_ITERATIONS: usize = 30;

/// Most pixels of any camera kfuse works with: 50 Mpx (25 Kinect colour frames, above the 45 Mpx
/// DSLRs kfuse calibrates). No image larger can be read (`kfuse_io::image_header` refuses it),
/// and the per-pixel tables of a larger colour camera run to several GiB before any image is
/// looked at: a 16 384² camera (each side within [`crate::rig::MAX_IMAGE_SIDE`]) aborted the
/// Python interpreter on allocation. A hard limit of [`CameraModel::validate`]: `force` does not
/// lift it.
pub const MAX_CAMERA_PIXELS: u64 = 50_000_000;
/// Convergence threshold on the distorted-coordinate residual (normalised units). 1e-14 is
/// ~1e-11 px at f = 1000 px, far below the 1e-6 px round-trip budget.
const UNDISTORT_TOLERANCE: f64 = 1e-14;
/// Step of the scan for the fold radius, in normalised units (~0.4 px at f = 365 px).
const FOLD_SCAN_STEP: f64 = 1e-3;
/// Largest undistorted radius scanned for a fold: tan(78.7°), beyond any Kinect lens.
const FOLD_SCAN_MAX_RADIUS: f64 = 5.0;

/// Linear intrinsics: focal lengths and principal point in pixels, skew in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x (0-based, pixel centres at integers).
    pub cx: f64,
    /// Principal point y (0-based, pixel centres at integers).
    pub cy: f64,
    /// Skew, pixels: `u = fx x + skew y + cx`. Zero for every modern sensor.
    #[serde(default)]
    pub skew: f64,
}

impl Intrinsics {
    /// Intrinsics without skew.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Self { fx, fy, cx, cy, skew: 0.0 }
    }

    /// The 3x3 camera matrix `K`.
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, self.skew, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// Distorted normalised coordinates → pixel.
    #[inline]
    pub fn to_pixel(&self, xd: f64, yd: f64) -> Vector2<f64> {
        Vector2::new(self.fx * xd + self.skew * yd + self.cx, self.fy * yd + self.cy)
    }

    /// Pixel → distorted normalised coordinates (inverse of [`Intrinsics::to_pixel`]).
    #[inline]
    pub fn from_pixel(&self, u: f64, v: f64) -> Vector2<f64> {
        let yd = (v - self.cy) / self.fy;
        let xd = (u - self.cx - self.skew * yd) / self.fx;
        Vector2::new(xd, yd)
    }
}

/// Brown–Conrady lens distortion, OpenCV's coefficient order `k1, k2, p1, p2, k3`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Distortion {
    /// Radial r² coefficient.
    pub k1: f64,
    /// Radial r⁴ coefficient.
    pub k2: f64,
    /// Tangential coefficient p1.
    pub p1: f64,
    /// Tangential coefficient p2.
    pub p2: f64,
    /// Radial r⁶ coefficient.
    #[serde(default)]
    pub k3: f64,
}

impl Distortion {
    /// No distortion.
    pub const NONE: Distortion = Distortion { k1: 0.0, k2: 0.0, p1: 0.0, p2: 0.0, k3: 0.0 };

    /// Coefficients in OpenCV order `[k1, k2, p1, p2, k3]`.
    pub fn to_array(&self) -> [f64; 5] {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
    }

    /// From OpenCV order `[k1, k2, p1, p2, k3]`.
    pub fn from_array(c: [f64; 5]) -> Self {
        Self { k1: c[0], k2: c[1], p1: c[2], p2: c[3], k3: c[4] }
    }

    /// True when every coefficient is exactly zero.
    pub fn is_zero(&self) -> bool {
        self.to_array().iter().all(|&c| c == 0.0)
    }

    /// Undistorted normalised `(x, y)` → distorted normalised `(x_d, y_d)`.
    #[inline]
    pub fn distort(&self, x: f64, y: f64) -> Vector2<f64> {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xy = x * y;
        Vector2::new(
            x * radial + 2.0 * self.p1 * xy + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * xy,
        )
    }

    /// [`Distortion::distort`] and its 2x2 Jacobian `∂(x_d, y_d)/∂(x, y)`.
    #[inline]
    pub fn distort_with_jacobian(&self, x: f64, y: f64) -> (Vector2<f64>, Matrix2<f64>) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        // d(radial)/d(r2)
        let dradial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let xy = x * y;
        let d = Vector2::new(
            x * radial + 2.0 * self.p1 * xy + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * xy,
        );
        let dxdx = radial + 2.0 * x * x * dradial + 2.0 * self.p1 * y + 6.0 * self.p2 * x;
        let dxdy = 2.0 * x * y * dradial + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        let dydx = 2.0 * x * y * dradial + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        let dydy = radial + 2.0 * y * y * dradial + 6.0 * self.p1 * y + 2.0 * self.p2 * x;
        (d, Matrix2::new(dxdx, dxdy, dydx, dydy))
    }

    /// Distorted normalised `(x_d, y_d)` → undistorted `(x, y)` by Newton's method.
    ///
    /// Returns `None` where the iteration does not converge or converges to a point beyond
    /// the fold radius (there the model is not invertible and the pixel sees no single ray).
    pub fn undistort(&self, xd: f64, yd: f64) -> Option<Vector2<f64>> {
        if !(xd.is_finite() && yd.is_finite()) {
            return None;
        }
        if self.is_zero() {
            return Some(Vector2::new(xd, yd));
        }
        self.undistort_within(xd, yd, self.fold_radius())
    }

    /// [`Distortion::undistort`] with the fold radius already known (`fold` must be
    /// [`Distortion::fold_radius`]): computing it once per camera instead of once per pixel
    /// makes whole-image ray tables cheap.
    pub fn undistort_within(&self, xd: f64, yd: f64, fold: Option<f64>) -> Option<Vector2<f64>> {
        if !(xd.is_finite() && yd.is_finite()) {
            return None;
        }
        if self.is_zero() {
            return Some(Vector2::new(xd, yd));
        }
        let target = Vector2::new(xd, yd);
        let mut p = target;
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            let (d, j) = self.distort_with_jacobian(p.x, p.y);
            let residual = d - target;
            if residual.norm() < UNDISTORT_TOLERANCE {
                return Self::inside_fold(p, fold);
            }
            let step = j.try_inverse()? * residual;
            p -= step;
            if !(p.x.is_finite() && p.y.is_finite()) {
                return None;
            }
        }
        let residual = self.distort(p.x, p.y) - target;
        if residual.norm() < 1e3 * UNDISTORT_TOLERANCE { Self::inside_fold(p, fold) } else { None }
    }

    fn inside_fold(p: Vector2<f64>, fold: Option<f64>) -> Option<Vector2<f64>> {
        match fold {
            Some(r) if p.norm() >= r => None,
            _ => Some(p),
        }
    }

    /// The smallest undistorted radius `r` at which the radial map `r · (1 + k1 r² + k2 r⁴ +
    /// k3 r⁶)` stops increasing, or `None` if it increases up to `r = 5` (78.7° off-axis).
    ///
    /// Beyond this radius two different rays land on the same pixel: the model "folds" and
    /// undistortion is meaningless there (the lab's IR k1/k2 fold near the image corners).
    pub fn fold_radius(&self) -> Option<f64> {
        let slope = |r: f64| {
            let r2 = r * r;
            1.0 + r2 * (3.0 * self.k1 + r2 * (5.0 * self.k2 + r2 * 7.0 * self.k3))
        };
        if self.k1 == 0.0 && self.k2 == 0.0 && self.k3 == 0.0 {
            return None;
        }
        let mut r = 0.0;
        while r < FOLD_SCAN_MAX_RADIUS {
            let next = r + FOLD_SCAN_STEP;
            if slope(next) <= 0.0 {
                // Bisect between r (slope > 0) and next (slope <= 0).
                let (mut lo, mut hi) = (r, next);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if slope(mid) > 0.0 {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                return Some(lo);
            }
            r = next;
        }
        None
    }
}

/// How a depth image measures distance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum DepthKind {
    /// Distance along the optical axis (what the Kinect delivers).
    #[default]
    Z,
    /// Euclidean distance to the optical centre (the course's synthetic data).
    Range,
}

impl DepthKind {
    /// Converts one sample to `z` given the pixel's undistorted normalised coordinates
    /// `(x, y)`: `z = range / sqrt(1 + x² + y²)`, i.e. `m·f / sqrt(f² + X² + Y²)` with
    /// `(X, Y)` the undistorted pixel offset from the principal point.
    #[inline]
    pub fn to_z(self, value: f64, x: f64, y: f64) -> f64 {
        match self {
            DepthKind::Z => value,
            DepthKind::Range => value / (1.0 + x * x + y * y).sqrt(),
        }
    }
}

impl std::str::FromStr for DepthKind {
    type Err = GeometryError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "z" => Ok(DepthKind::Z),
            "range" => Ok(DepthKind::Range),
            other => Err(GeometryError::InvalidParameter(format!(
                "depth kind '{other}': use 'z' (distance along the optical axis, Kinect) or \
                 'range' (distance to the optical centre)"
            ))),
        }
    }
}

impl std::fmt::Display for DepthKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            DepthKind::Z => "z",
            DepthKind::Range => "range",
        })
    }
}

/// A calibrated camera: image size, intrinsics and distortion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraModel {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Linear intrinsics.
    #[serde(flatten)]
    pub intrinsics: Intrinsics,
    /// Lens distortion.
    #[serde(flatten)]
    pub distortion: Distortion,
}

impl CameraModel {
    /// A camera from its parts.
    pub fn new(
        width: usize,
        height: usize,
        intrinsics: Intrinsics,
        distortion: Distortion,
    ) -> Self {
        Self { width, height, intrinsics, distortion }
    }

    /// Checks that every parameter is finite and meaningful (positive size and focal lengths).
    pub fn validate(&self) -> Result<(), GeometryError> {
        let k = &self.intrinsics;
        let d = &self.distortion;
        let named = [
            ("fx", k.fx),
            ("fy", k.fy),
            ("cx", k.cx),
            ("cy", k.cy),
            ("skew", k.skew),
            ("k1", d.k1),
            ("k2", d.k2),
            ("p1", d.p1),
            ("p2", d.p2),
            ("k3", d.k3),
        ];
        let bad: Vec<String> = named
            .iter()
            .filter(|(_, v)| !v.is_finite())
            .map(|(n, v)| format!("{n} = {v}"))
            .collect();
        if !bad.is_empty() {
            return Err(GeometryError::InvalidParameter(format!(
                "camera parameters must be finite numbers, got {}",
                bad.join(", ")
            )));
        }
        if self.width == 0 || self.height == 0 {
            return Err(GeometryError::InvalidParameter(format!(
                "image size {}x{} is empty",
                self.width, self.height
            )));
        }
        let side = crate::rig::MAX_IMAGE_SIDE;
        let pixels = (self.width as u64).saturating_mul(self.height as u64);
        if self.width > side || self.height > side || pixels > MAX_CAMERA_PIXELS {
            return Err(GeometryError::InvalidParameter(format!(
                "image size {}x{} is over kfuse's camera limit ({side} px per side, {} Mpx): no image that large can be read; is this the camera's size in pixels?",
                self.width,
                self.height,
                MAX_CAMERA_PIXELS / 1_000_000
            )));
        }
        if k.fx <= 0.0 || k.fy <= 0.0 {
            return Err(GeometryError::InvalidParameter(format!(
                "focal lengths must be positive, got fx={} fy={}",
                crate::num_fmt::num(k.fx),
                crate::num_fmt::num(k.fy)
            )));
        }
        Ok(())
    }

    /// Projects a point of the camera frame to a pixel (distortion applied). `None` when the
    /// point is not in front of the camera. The pixel may lie outside the image: check with
    /// [`CameraModel::contains`].
    #[inline]
    pub fn project(&self, p: &Vector3<f64>) -> Option<Vector2<f64>> {
        if !(p.z > 0.0) {
            return None;
        }
        let d = self.distortion.distort(p.x / p.z, p.y / p.z);
        Some(self.intrinsics.to_pixel(d.x, d.y))
    }

    /// Pixel → undistorted normalised coordinates `(x, y)`: the ray through the pixel is
    /// `(x, y, 1)`. `None` where the distortion model folds or cannot be inverted.
    #[inline]
    pub fn unproject(&self, u: f64, v: f64) -> Option<Vector2<f64>> {
        let d = self.intrinsics.from_pixel(u, v);
        self.distortion.undistort(d.x, d.y)
    }

    /// The 3D point at depth `value` (of kind `kind`) seen through pixel `(u, v)`.
    pub fn backproject(&self, u: f64, v: f64, value: f64, kind: DepthKind) -> Option<Vector3<f64>> {
        if !(value.is_finite() && value > 0.0) {
            return None;
        }
        let n = self.unproject(u, v)?;
        let z = kind.to_z(value, n.x, n.y);
        Some(Vector3::new(n.x * z, n.y * z, z))
    }

    /// True when `(u, v)` falls on the image: `-0.5 <= u < width - 0.5` and likewise for `v`
    /// (pixel centres at integers, so pixel 0 covers [-0.5, 0.5)).
    #[inline]
    pub fn contains(&self, u: f64, v: f64) -> bool {
        u >= -0.5 && v >= -0.5 && u < self.width as f64 - 0.5 && v < self.height as f64 - 0.5
    }

    /// Undistorted normalised ray `(x, y)` of every pixel centre, row-major, `NaN` where the
    /// pixel has no ray (distortion folds). Precompute once per camera: back-projection is
    /// then one multiply per coordinate.
    pub fn ray_table(&self) -> Vec<[f32; 2]> {
        let mut table = Vec::with_capacity(self.width * self.height);
        let fold = self.distortion.fold_radius();
        for v in 0..self.height {
            for u in 0..self.width {
                let d = self.intrinsics.from_pixel(u as f64, v as f64);
                match self.distortion.undistort_within(d.x, d.y, fold) {
                    Some(n) => table.push([n.x as f32, n.y as f32]),
                    None => table.push([f32::NAN, f32::NAN]),
                }
            }
        }
        table
    }

    /// The same camera without distortion (what an undistorted image is seen through).
    pub fn without_distortion(&self) -> CameraModel {
        CameraModel { distortion: Distortion::NONE, ..*self }
    }

    /// The camera that sees this camera's images mirrored left–right (pixel column `u` becomes
    /// `width − 1 − u`), in the camera frame mirrored the same way (`x → −x`): `cx → width − 1
    /// − cx`, the skew and the tangential `p2` change sign, everything else stays. A point's
    /// projection through the result is the mirror of its mirror image's projection here.
    pub fn mirrored(&self) -> CameraModel {
        let k = self.intrinsics;
        let intrinsics = Intrinsics { cx: self.width as f64 - 1.0 - k.cx, skew: -k.skew, ..k };
        let distortion = Distortion { p2: -self.distortion.p2, ..self.distortion };
        CameraModel { intrinsics, distortion, ..*self }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// The factory depth-camera parameters of a real Kinect v2 (libfreenect2 issue #41,
    /// also in `kinect-v2-vectors/manifest.json`).
    fn kinect_depth() -> CameraModel {
        CameraModel::new(
            512,
            424,
            Intrinsics::new(368.096588, 368.096588, 261.696594, 202.522202),
            Distortion { k1: 0.084061, k2: -0.271582, p1: 0.0, p2: 0.0, k3: 0.101907 },
        )
    }

    #[test]
    fn project_unproject_round_trip_below_1e6_px_over_whole_kinect_image() {
        // Add tangential terms so every branch of the model is exercised.
        let mut cam = kinect_depth();
        cam.distortion.p1 = 0.0021;
        cam.distortion.p2 = -0.0013;
        cam.intrinsics.skew = 0.3;
        let mut worst: f64 = 0.0;
        for v in 0..cam.height {
            for u in 0..cam.width {
                let n = cam.unproject(u as f64, v as f64).expect("Kinect lens does not fold");
                let p = cam.project(&Vector3::new(n.x * 2.0, n.y * 2.0, 2.0)).unwrap();
                worst = worst.max((p - Vector2::new(u as f64, v as f64)).norm());
            }
        }
        // UNDISTORT_TOLERANCE (1e-14 normalised ≈ 4e-12 px at f = 368) bounds the Newton
        // solve; 1e-6 px is the design's round-trip budget, far above that and far below any
        // model error.
        assert!(worst < 1e-6, "worst round-trip error {worst} px");
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let d = Distortion { k1: 0.1, k2: -0.25, p1: 0.003, p2: -0.002, k3: 0.09 };
        let (x, y) = (0.31, -0.22);
        let (_, j) = d.distort_with_jacobian(x, y);
        let h = 1e-7;
        let dx = (d.distort(x + h, y) - d.distort(x - h, y)) / (2.0 * h);
        let dy = (d.distort(x, y + h) - d.distort(x, y - h)) / (2.0 * h);
        // Central differences with h = 1e-7: truncation O(h²) ≈ 1e-14, rounding ≈ ε/h ≈ 2e-9 on
        // O(1) values; 1e-7 is ~50× that, and a wrong Jacobian term is off by O(0.01).
        assert_relative_eq!(j[(0, 0)], dx.x, epsilon = 1e-7);
        assert_relative_eq!(j[(1, 0)], dx.y, epsilon = 1e-7);
        assert_relative_eq!(j[(0, 1)], dy.x, epsilon = 1e-7);
        assert_relative_eq!(j[(1, 1)], dy.y, epsilon = 1e-7);
    }

    #[test]
    fn fold_radius_of_the_synthetic_ir_lens_matches_its_readme() {
        // shared/data/synthetic-calib/README.md: k1 = 0.098, k2 = -0.22 folds at r = 1.047.
        let d = Distortion { k1: 0.098, k2: -0.22, p1: 0.004, p2: 0.0016, k3: 0.0 };
        let r = d.fold_radius().unwrap();
        // The README states the fold radius to 3 decimals.
        assert!((r - 1.047).abs() < 1e-3, "fold radius {r}");
        // Distorted radii past the fold's maximum have no preimage: undistortion refuses them,
        // and just inside the fold it still inverts exactly.
        let max = d.distort(r, 0.0);
        assert!(d.undistort(1.01 * max.x, 1.01 * max.y).is_none());
        let inside = d.distort(0.95 * r, 0.0);
        let back = d.undistort(inside.x, inside.y).unwrap();
        // The Newton solve converges to UNDISTORT_TOLERANCE (1e-14); 1e-9 leaves margin for the
        // weaker conditioning near the fold (slope of the radial map → 0 there).
        assert!((back.x - 0.95 * r).abs() < 1e-9 && back.y.abs() < 1e-9, "{back}");
        assert!(Distortion::NONE.fold_radius().is_none());
    }

    #[test]
    fn range_to_z_matches_the_design_formula() {
        // z = m f / sqrt(f² + X² + Y²) with pixel offsets X, Y.
        let (f, px, py, m) = (525.0, 120.0, -80.0, 2.5);
        let z = DepthKind::Range.to_z(m, px / f, py / f);
        let expected = m * f / (f * f + px * px + py * py).sqrt();
        assert_relative_eq!(z, expected, epsilon = 1e-12);
        assert_eq!(DepthKind::Z.to_z(m, 3.0, 4.0), m);
    }

    #[test]
    fn invalid_depth_never_becomes_a_point() {
        let cam = kinect_depth();
        assert!(cam.backproject(10.0, 10.0, 0.0, DepthKind::Z).is_none());
        assert!(cam.backproject(10.0, 10.0, f64::NAN, DepthKind::Z).is_none());
        assert!(cam.project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn validate_rejects_nan_and_nonpositive_focal() {
        let mut cam = kinect_depth();
        assert!(cam.validate().is_ok());
        for fx in [f64::NAN, -1.0] {
            cam.intrinsics.fx = fx;
            let e = cam.validate().unwrap_err();
            assert!(matches!(e, GeometryError::InvalidParameter(_)), "{fx}: {e:?}");
        }
    }
}
