//! The per-pixel arithmetic of the hot stages (H1, H2, H7, nearest fill, plane fill), in
//! `f32`, written so that a WGSL shader can mirror it line by line.
//!
//! Rules every function here follows (and every GPU twin must follow):
//!
//! * Only `+ - * /`, `floor` and comparisons; no `mul_add`, no `sqrt` (range→z is a
//!   precomputed per-pixel factor), no `dot()`; expressions are evaluated exactly in the order
//!   written, left to right (`a * b + c * d + e` is `((a*b) + (c*d)) + e`).
//! * A depth value is a sample when `value > 0` and `value < +inf` (so NaN and 0 are not).
//! * The pixel a point lands on is `(floor(u + 0.5), floor(v + 0.5))`, kept only when
//!   `0 <= px < width` and `0 <= py < height` ([`zbuffer_index`]).
//! * The z-buffer keeps the smallest colour-frame `z`. Its "empty" value is the NaN whose bit
//!   pattern is `0xFFFF_FFFF` ([`ZBUFFER_EMPTY`]): for positive floats the `u32` bit patterns
//!   order like the values, so a GPU `atomicMin` on the bits and the CPU's
//!   `if !(old <= z) { old = z }` give bit-identical images.

/// The "no sample" value of a z-buffer: a NaN with all bits set, i.e. `u32::MAX` as bits, the
/// identity of `atomicMin` on `u32`.
pub const ZBUFFER_EMPTY: f32 = f32::from_bits(u32::MAX);

/// The colour camera and `color_from_depth` in `f32`, ready for [`project_point`].
///
/// Upload this struct as-is (row-major rotation) to a GPU uniform buffer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColorProjection {
    /// `color_from_depth` rotation, row-major.
    pub rotation: [f32; 9],
    /// `color_from_depth` translation, metres.
    pub translation: [f32; 3],
    /// Focal length x, pixels.
    pub fx: f32,
    /// Focal length y, pixels.
    pub fy: f32,
    /// Principal point x.
    pub cx: f32,
    /// Principal point y.
    pub cy: f32,
    /// Skew, pixels.
    pub skew: f32,
    /// Radial r².
    pub k1: f32,
    /// Radial r⁴.
    pub k2: f32,
    /// Tangential p1.
    pub p1: f32,
    /// Tangential p2.
    pub p2: f32,
    /// Radial r⁶.
    pub k3: f32,
    /// Colour image width.
    pub width: u32,
    /// Colour image height.
    pub height: u32,
}

impl ColorProjection {
    /// The colour side of `rig` rounded to `f32`.
    pub fn from_rig(rig: &crate::Rig) -> Self {
        let m = rig.color_from_depth.rotation.matrix();
        let t = rig.color_from_depth.translation;
        let k = rig.color.intrinsics;
        let d = rig.color.distortion;
        let mut rotation = [0f32; 9];
        for i in 0..3 {
            for j in 0..3 {
                rotation[3 * i + j] = m[(i, j)] as f32;
            }
        }
        Self {
            rotation,
            translation: [t.x as f32, t.y as f32, t.z as f32],
            fx: k.fx as f32,
            fy: k.fy as f32,
            cx: k.cx as f32,
            cy: k.cy as f32,
            skew: k.skew as f32,
            k1: d.k1 as f32,
            k2: d.k2 as f32,
            p1: d.p1 as f32,
            p2: d.p2 as f32,
            k3: d.k3 as f32,
            width: rig.color.width as u32,
            height: rig.color.height as u32,
        }
    }
}

/// Per-pixel rays of the depth camera for one [`crate::DepthKind`]: `[x, y, s]` with `(x, y)`
/// the undistorted normalised ray (from [`crate::CameraModel::ray_table`]) and `s` the factor
/// that turns the stored depth value into `z` (`1` for z input, `1/sqrt(1 + x² + y²)`
/// computed in `f64` for range input). `x = y = NaN` where the lens folds.
pub fn depth_ray_table(camera: &crate::CameraModel, kind: crate::DepthKind) -> Vec<[f32; 3]> {
    camera
        .ray_table()
        .into_iter()
        .map(|[x, y]| {
            let s = kind.to_z(1.0, x as f64, y as f64) as f32;
            [x, y, s]
        })
        .collect()
}

/// The one "is this a depth sample" rule: `value > 0` and `value < +inf` (so NaN, 0, negative
/// and infinite values are not). Every CPU stage that reads a depth value asks this;
/// `backproject.wgsl`'s `is_sample` is its GPU twin.
#[inline(always)]
pub fn is_sample(value: f32) -> bool {
    value > 0.0 && value < f32::INFINITY
}

/// [`is_sample`] within a depth range ([`super::DepthRange`]): also `min_m <= value <= max_m`.
#[inline(always)]
pub fn is_sample_in(value: f32, range: super::DepthRange) -> bool {
    is_sample(value) && value >= range.min_m && value <= range.max_m
}

/// H1 for one pixel: the depth-camera point of depth `value` seen along `ray` (an entry of
/// [`depth_ray_table`]). `None` when `value` is not a sample.
///
/// `z = value * s; X = x * z; Y = y * z`. A NaN ray yields a NaN point, which
/// [`project_point`] rejects.
#[inline]
pub fn backproject_pixel(ray: [f32; 3], value: f32) -> Option<[f32; 3]> {
    if !is_sample(value) {
        return None;
    }
    let z = value * ray[2];
    Some([ray[0] * z, ray[1] * z, z])
}

/// H2 for one point: `X_c = R · X_d + T` (each row `((r0*x + r1*y) + r2*z) + t`).
#[inline]
pub fn transform_point(p: &ColorProjection, x: [f32; 3]) -> [f32; 3] {
    let r = &p.rotation;
    let t = &p.translation;
    [
        r[0] * x[0] + r[1] * x[1] + r[2] * x[2] + t[0],
        r[3] * x[0] + r[4] * x[1] + r[5] * x[2] + t[1],
        r[6] * x[0] + r[7] * x[1] + r[8] * x[2] + t[2],
    ]
}

/// H2 for one colour-frame point: its colour pixel `(u, v)` (distortion applied, OpenCV's
/// formula) and its colour-frame `z`, as `[u, v, z]`. `None` unless `z > 0` (NaN fails too).
/// The pixel may lie outside the image.
#[inline]
pub fn project_color_point(p: &ColorProjection, xc: [f32; 3]) -> Option<[f32; 3]> {
    let z = xc[2];
    if !(z > 0.0) {
        return None;
    }
    let [u, v] = distort_to_pixel(p, xc);
    Some([u, v, z])
}

/// The colour pixel `[u, v]` of a colour-frame point, without the `z > 0` test (a point
/// behind the camera gives a meaningless pixel; callers mask it). The one copy of H2's
/// arithmetic: the scalar path, the vectorised loops of `fusion::stream` and
/// `fusion::register`, and the WGSL shader all evaluate exactly this.
#[inline(always)]
pub fn distort_to_pixel(p: &ColorProjection, xc: [f32; 3]) -> [f32; 2] {
    let xn = xc[0] / xc[2];
    let yn = xc[1] / xc[2];
    let r2 = xn * xn + yn * yn;
    let radial = 1.0 + r2 * (p.k1 + r2 * (p.k2 + r2 * p.k3));
    let xy = xn * yn;
    let xd = xn * radial + 2.0 * p.p1 * xy + p.p2 * (r2 + 2.0 * xn * xn);
    let yd = yn * radial + p.p1 * (r2 + 2.0 * yn * yn) + 2.0 * p.p2 * xy;
    [p.fx * xd + p.skew * yd + p.cx, p.fy * yd + p.cy]
}

/// H2 for one depth-camera point: [`transform_point`] then [`project_color_point`].
#[inline]
pub fn project_point(p: &ColorProjection, x: [f32; 3]) -> Option<[f32; 3]> {
    project_color_point(p, transform_point(p, x))
}

/// The row-major index of the pixel `(floor(u + 0.5), floor(v + 0.5))`, or `None` when it is
/// outside a `width × height` image (or `u`, `v` are NaN).
#[inline]
pub fn zbuffer_index(u: f32, v: f32, width: u32, height: u32) -> Option<usize> {
    let (px, py) = zbuffer_pixel(u, v, width, height)?;
    Some(py * width as usize + px)
}

/// The pixel `(floor(u + 0.5), floor(v + 0.5))` as `(column, row)`, or `None` outside the
/// image (see [`zbuffer_index`]).
#[inline]
pub fn zbuffer_pixel(u: f32, v: f32, width: u32, height: u32) -> Option<(usize, usize)> {
    let px = floor_f32(u + 0.5);
    let py = floor_f32(v + 0.5);
    if !(px >= 0.0 && py >= 0.0 && px < width as f32 && py < height as f32) {
        return None;
    }
    Some((px as usize, py as usize))
}

/// `x.floor()` without a libm call (x86-64's baseline has no rounding instruction): exact for
/// every `|x| < 2^31`; NaN and larger magnitudes come out as some value outside any image,
/// which is all [`zbuffer_index`] needs.
#[inline]
pub fn floor_f32(x: f32) -> f32 {
    if !(x.abs() < 2_147_483_520.0) {
        return x; // NaN, infinities and integers beyond 2^31 are their own floor.
    }
    let t = x as i32 as f32;
    if t > x { t - 1.0 } else { t }
}

/// H7 for one sample: keeps the smaller `z` in `slot` (an empty slot holds NaN).
#[inline]
pub fn zbuffer_min(slot: &mut f32, z: f32) {
    if !(*slot <= z) {
        *slot = z;
    }
}

/// H2 + H7 of `points` (the frame `proj` projects from) into `zbuffer`, a buffer of `proj`'s
/// size: per pixel the smallest `z` ([`zbuffer_min`]), pixels outside the image dropped.
pub fn zbuffer_points(points: &[[f32; 3]], proj: &ColorProjection, zbuffer: &mut [f32]) {
    for &p in points {
        if let Some([u, v, z]) = project_point(proj, p)
            && let Some(i) = zbuffer_index(u, v, proj.width, proj.height)
        {
            zbuffer_min(&mut zbuffer[i], z);
        }
    }
}

/// H1 + H2 for one depth pixel: `[u, v, z_color]`, or `None` when the pixel has no sample or
/// the point is not in front of the colour camera.
#[inline]
pub fn register_pixel(p: &ColorProjection, ray: [f32; 3], value: f32) -> Option<[f32; 3]> {
    project_point(p, backproject_pixel(ray, value)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{DepthKind, Rig};

    /// The Kinect preset's rig (factory depth distortion, mild colour distortion).
    fn rig() -> Rig {
        crate::synth::kinect_rig()
    }

    #[test]
    fn f32_pixel_path_matches_the_f64_camera_model() {
        // The f32 path must agree with CameraModel's f64 backproject/project to well under
        // the 0.5-px rounding of H7: 1e-2 px allows f32 rounding of ~2000-px coordinates
        // (ulp 1.2e-4) through ~10 operations with margin.
        let rig = rig();
        let p = ColorProjection::from_rig(&rig);
        for kind in [DepthKind::Z, DepthKind::Range] {
            let rays = depth_ray_table(&rig.depth, kind);
            let mut worst: f64 = 0.0;
            for v in (0..424).step_by(7) {
                for u in (0..512).step_by(5) {
                    let value = 0.8 + 0.01 * ((u + v) % 300) as f32;
                    let got = register_pixel(&p, rays[v * 512 + u], value).unwrap();
                    let xd = rig.depth.backproject(u as f64, v as f64, value as f64, kind).unwrap();
                    let xc = rig.color_from_depth.apply(&xd);
                    let want = rig.color.project(&xc).unwrap();
                    worst = worst
                        .max((got[0] as f64 - want.x).abs())
                        .max((got[1] as f64 - want.y).abs());
                    assert!((got[2] as f64 - xc.z).abs() < 1e-5 * xc.z, "z {} vs {}", got[2], xc.z);
                }
            }
            assert!(worst < 1e-2, "{kind}: worst pixel difference {worst}");
        }
    }

    #[test]
    fn invalid_values_and_rounding_rule() {
        let ray = [0.1, -0.2, 1.0];
        assert!(backproject_pixel(ray, 0.0).is_none());
        assert!(backproject_pixel(ray, f32::NAN).is_none());
        assert!(backproject_pixel(ray, f32::INFINITY).is_none());
        assert!(backproject_pixel(ray, -1.0).is_none());
        // floor(u + 0.5): 1.49 → 1, 1.5 → 2, -0.5 → 0, -0.51 → outside.
        assert_eq!(zbuffer_index(1.49, 0.0, 4, 2), Some(1));
        assert_eq!(zbuffer_index(1.5, 0.0, 4, 2), Some(2));
        assert_eq!(zbuffer_index(-0.5, 1.2, 4, 2), Some(4));
        assert_eq!(zbuffer_index(-0.51, 0.0, 4, 2), None);
        assert_eq!(zbuffer_index(3.5, 0.0, 4, 2), None);
        assert_eq!(zbuffer_index(f32::NAN, 0.0, 4, 2), None);
        for x in [
            -3.5f32,
            -3.0,
            -0.2,
            -0.0,
            0.0,
            0.49,
            0.5,
            1.0,
            2.999,
            1e7 + 0.5,
            -1e9,
            3e9,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ] {
            assert_eq!(floor_f32(x), x.floor(), "floor({x})");
        }
        assert!(floor_f32(f32::NAN).is_nan());
        let mut slot = ZBUFFER_EMPTY;
        zbuffer_min(&mut slot, 2.0);
        zbuffer_min(&mut slot, 3.0);
        zbuffer_min(&mut slot, 1.5);
        assert_eq!(slot, 1.5);
        assert_eq!(ZBUFFER_EMPTY.to_bits(), u32::MAX);
    }
}
