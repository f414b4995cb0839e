//! A checkerboard renderer for the tests, independent of the detector: a board of
//! `(cols + 1) × (rows + 1)` squares with a white margin of one square, seen by a pinhole
//! camera (optionally with lens distortion) at a given pose, area-sampled, blurred and noised.
//!
//! Board frame as `calib::Board` in square units: inner corner `(x, y)` at `(x, y, 0)`; the
//! square between corners `(x−1, y−1)` and `(x, y)` is square `(x, y)`, dark iff `x + y` is
//! even and the top-left square is black (or odd and it is white).
#![allow(dead_code)]

use geometry::{Distortion, Image, Intrinsics};
use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};
use rand::Rng;

/// Grey level of the dark squares.
pub const DARK: f64 = 30.0;
/// Grey level of the white squares and margin.
pub const LIGHT: f64 = 220.0;

/// A rendered board and where its corners are.
pub struct Scene {
    /// Image size.
    pub width: usize,
    pub height: usize,
    /// Inner corners per row and per column.
    pub cols: usize,
    pub rows: usize,
    /// Colour of the top-left square.
    pub top_left_black: bool,
    pub k: Intrinsics,
    pub dist: Distortion,
    /// Camera from board (square units): `X_cam = R·X_board + t`.
    pub r: Matrix3<f64>,
    pub t: Vector3<f64>,
    /// Gaussian blur σ (px) and noise σ (grey levels).
    pub blur: f64,
    pub noise: f64,
    /// Background grey level.
    pub background: f64,
}

impl Scene {
    /// Pinhole image (no distortion) of board point `(x, y, 0)`.
    pub fn pinhole(&self, x: f64, y: f64) -> Vector2<f64> {
        let c = self.r * Vector3::new(x, y, 0.0) + self.t;
        self.k.to_pixel(c.x / c.z, c.y / c.z)
    }

    /// Image (with the scene's distortion) of board point `(x, y, 0)`.
    pub fn project(&self, x: f64, y: f64) -> Vector2<f64> {
        let c = self.r * Vector3::new(x, y, 0.0) + self.t;
        let d = self.dist.distort(c.x / c.z, c.y / c.z);
        self.k.to_pixel(d.x, d.y)
    }

    /// True position of inner corner `id` (`x = id mod cols`).
    pub fn corner(&self, id: usize) -> Vector2<f64> {
        self.project((id % self.cols) as f64, (id / self.cols) as f64)
    }

    /// Grey level at board-plane point `(x, y)` (corner units).
    fn albedo(&self, x: f64, y: f64) -> f64 {
        let (c, r) = (self.cols as f64, self.rows as f64);
        if x < -2.0 || y < -2.0 || x > c + 1.0 || y > r + 1.0 {
            return self.background;
        }
        if x < -1.0 || y < -1.0 || x > c || y > r {
            return LIGHT;
        }
        let (sx, sy) = (x.floor() as i64 + 1, y.floor() as i64 + 1);
        let dark = ((sx + sy).rem_euclid(2) == 0) == self.top_left_black;
        if dark { DARK } else { LIGHT }
    }

    /// Renders the scene: 2×2 samples per pixel (pixel centres at integers), then a separable
    /// Gaussian blur and Gaussian noise, rounded to 8 bits.
    pub fn render(&self, rng: &mut impl Rng) -> Image<u8> {
        const SS: usize = 2;
        let (w, h) = (self.width, self.height);
        // Plane → camera ray: the inverse of [r1 r2 t].
        let m = Matrix3::from_columns(&[self.r.column(0).into(), self.r.column(1).into(), self.t]);
        let inv = m.try_inverse().expect("board plane not through the camera centre");
        let plane = |u: f64, v: f64| -> Option<(f64, f64)> {
            let n = self.k.from_pixel(u, v);
            let n = if self.dist.is_zero() { n } else { self.dist.undistort(n.x, n.y)? };
            let q = inv * Vector3::new(n.x, n.y, 1.0);
            (q.z > 0.0).then(|| (q.x / q.z, q.y / q.z))
        };
        let mut img: Vec<f64> = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for j in 0..SS {
                    for i in 0..SS {
                        let u = x as f64 - 0.5 + (i as f64 + 0.5) / SS as f64;
                        let v = y as f64 - 0.5 + (j as f64 + 0.5) / SS as f64;
                        acc += plane(u, v).map_or(self.background, |(bx, by)| self.albedo(bx, by));
                    }
                }
                img[y * w + x] = acc / (SS * SS) as f64;
            }
        }
        let img = blur(&img, w, h, self.blur);
        let normal = |rng: &mut dyn rand::RngCore| -> f64 {
            // Box–Muller.
            let (a, b): (f64, f64) = (rng.random::<f64>().max(1e-12), rng.random());
            (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        };
        let data = img
            .iter()
            .map(|&v| (v + self.noise * normal(rng)).round().clamp(0.0, 255.0) as u8)
            .collect();
        Image::from_vec(w, h, data).unwrap()
    }
}

/// Separable Gaussian blur (σ in px, kernel ±3σ, clamped borders).
pub fn blur(img: &[f64], w: usize, h: usize, sigma: f64) -> Vec<f64> {
    if sigma <= 0.0 {
        return img.to_vec();
    }
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f64> = (-r..=r).map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp()).collect();
    let s: f64 = k.iter().sum();
    let k: Vec<f64> = k.iter().map(|v| v / s).collect();
    let pass = |src: &[f64], horizontal: bool| -> Vec<f64> {
        let mut out = vec![0.0; w * h];
        for y in 0..h as isize {
            for x in 0..w as isize {
                let mut acc = 0.0;
                for (n, kv) in k.iter().enumerate() {
                    let d = n as isize - r;
                    let (xx, yy) = if horizontal {
                        ((x + d).clamp(0, w as isize - 1), y)
                    } else {
                        (x, (y + d).clamp(0, h as isize - 1))
                    };
                    acc += kv * src[yy as usize * w + xx as usize];
                }
                out[y as usize * w + x as usize] = acc;
            }
        }
        out
    };
    pass(&pass(img, true), false)
}

/// A random pose that shows the whole board (margin included) in a `w × h` image seen with
/// focal length `f` (`camera = (w, h, f)`): in-plane rotation uniform over 360°, tilt up to `max_tilt_deg` about
/// both in-plane axes, the board's diagonal filling `fill` of the shorter image side.
pub fn random_pose(
    rng: &mut impl Rng,
    cols: usize,
    rows: usize,
    (w, h, f): (usize, usize, f64),
    max_tilt_deg: f64,
    fill: f64,
) -> (Matrix3<f64>, Vector3<f64>) {
    let roll = rng.random_range(0.0..std::f64::consts::TAU);
    let tilt = max_tilt_deg.to_radians();
    let (ax, ay) = (rng.random_range(-tilt..tilt), rng.random_range(-tilt..tilt));
    let r = *(Rotation3::from_euler_angles(ax, ay, 0.0)
        * Rotation3::from_euler_angles(0.0, 0.0, roll))
    .matrix();
    // Board centre (corner units) at the optical axis, distance from the wanted size.
    let (c, ro) = (cols as f64 + 3.0, rows as f64 + 3.0);
    let diag = (c * c + ro * ro).sqrt();
    let z = f * diag / (fill * w.min(h) as f64);
    let centre = Vector3::new((cols as f64 - 1.0) / 2.0, (rows as f64 - 1.0) / 2.0, 0.0);
    let shift = Vector3::new(
        rng.random_range(-0.05..0.05) * z * w as f64 / f,
        rng.random_range(-0.05..0.05) * z * h as f64 / f,
        z,
    );
    let t = shift - r * centre;
    (r, t)
}
