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
        self.board_albedo(x, y).unwrap_or(self.background)
    }

    /// Grey level of the board (squares and margin) at board-plane point `(x, y)`, `None`
    /// beyond the margin.
    fn board_albedo(&self, x: f64, y: f64) -> Option<f64> {
        let (c, r) = (self.cols as f64, self.rows as f64);
        if x < -2.0 || y < -2.0 || x > c + 1.0 || y > r + 1.0 {
            return None;
        }
        if x < -1.0 || y < -1.0 || x > c || y > r {
            return Some(LIGHT);
        }
        let (sx, sy) = (x.floor() as i64 + 1, y.floor() as i64 + 1);
        let dark = ((sx + sy).rem_euclid(2) == 0) == self.top_left_black;
        Some(if dark { DARK } else { LIGHT })
    }

    /// Renders the scene: 2×2 samples per pixel (pixel centres at integers), then a separable
    /// Gaussian blur and Gaussian noise, rounded to 8 bits.
    pub fn render(&self, rng: &mut impl Rng) -> Image<u8> {
        self.render_with(rng, 2, &|x, y| self.albedo(x, y))
    }

    /// Renders the board lying on `table` (which also lights the board): the board-plane
    /// points beyond the board's margin show the table top, rays that miss it (past its edge,
    /// above the horizon) see the scene's `background`. `ss × ss` samples per pixel.
    pub fn render_on_table(&self, rng: &mut impl Rng, table: &Table, ss: usize) -> Image<u8> {
        self.render_with(rng, ss, &|x, y| {
            let surface = self.board_albedo(x, y).or_else(|| table.albedo(x, y));
            surface.map_or(self.background, |a| a * table.light(x, y))
        })
    }

    /// Renders with `shade` giving the grey level seen at board-plane point `(x, y)` (rays
    /// missing the plane see `background`): `ss × ss` samples per pixel, rows in parallel,
    /// then the blur and the noise (drawn serially from `rng`, so the image depends only on
    /// its seed).
    fn render_with(
        &self,
        rng: &mut impl Rng,
        ss: usize,
        shade: &(dyn Fn(f64, f64) -> f64 + Sync),
    ) -> Image<u8> {
        use rayon::prelude::*;
        let (w, h) = (self.width, self.height);
        // Plane → camera ray: the inverse of [r1 r2 t].
        let m = Matrix3::from_columns(&[self.r.column(0).into(), self.r.column(1).into(), self.t]);
        let inv = m.try_inverse().expect("board plane not through the camera centre");
        let fold = self.dist.fold_radius();
        let plane = |u: f64, v: f64| -> Option<(f64, f64)> {
            let n = self.k.from_pixel(u, v);
            let n =
                if self.dist.is_zero() { n } else { self.dist.undistort_within(n.x, n.y, fold)? };
            let q = inv * Vector3::new(n.x, n.y, 1.0);
            (q.z > 0.0).then(|| (q.x / q.z, q.y / q.z))
        };
        let mut img: Vec<f64> = vec![0.0; w * h];
        img.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, out) in row.iter_mut().enumerate() {
                let mut acc = 0.0;
                for j in 0..ss {
                    for i in 0..ss {
                        let u = x as f64 - 0.5 + (i as f64 + 0.5) / ss as f64;
                        let v = y as f64 - 0.5 + (j as f64 + 0.5) / ss as f64;
                        acc += plane(u, v).map_or(self.background, |(bx, by)| shade(bx, by));
                    }
                }
                *out = acc / (ss * ss) as f64;
            }
        });
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

/// A textured table top in the board's plane (board units: one square = 1), lit by one lamp:
/// wood-like grain (bands warped by smooth noise) with fine speckle, on a rectangle around the
/// board. Deterministic in `seed`; nothing in it is shaped after the detector.
pub struct Table {
    /// The table top's extent on the board plane: `x0..x1` × `y0..y1` (board units).
    pub x: (f64, f64),
    pub y: (f64, f64),
    /// Mean grey level of the wood and the grain's and the speckle's amplitudes.
    pub base: f64,
    pub grain: f64,
    pub speckle: f64,
    /// Direction of the grain on the plane, radians from the board's x axis.
    pub grain_angle: f64,
    /// The lamp's spot centre on the plane and its radius (board units); the light falls from
    /// 1 at the centre towards `1 − falloff` far from it.
    pub lamp: (f64, f64),
    pub lamp_radius: f64,
    pub falloff: f64,
    pub seed: u64,
}

impl Table {
    /// Albedo of the table top at board-plane point `(x, y)`, `None` off the table.
    pub fn albedo(&self, x: f64, y: f64) -> Option<f64> {
        if x < self.x.0 || x > self.x.1 || y < self.y.0 || y > self.y.1 {
            return None;
        }
        let (s, c) = self.grain_angle.sin_cos();
        // Along and across the grain.
        let (u, v) = (c * x + s * y, -s * x + c * y);
        let warp = 1.5 * value_noise(0.12 * u, 0.5 * v, self.seed);
        let bands = (std::f64::consts::TAU * (1.3 * v + warp)).sin();
        let fine = value_noise(5.0 * u, 5.0 * v, self.seed.wrapping_add(1)) - 0.5;
        Some(self.base + self.grain * bands + 2.0 * self.speckle * fine)
    }

    /// The lamp's light at board-plane point `(x, y)`, in `(1 − falloff, 1]`.
    pub fn light(&self, x: f64, y: f64) -> f64 {
        let d2 = (x - self.lamp.0).powi(2) + (y - self.lamp.1).powi(2);
        1.0 - self.falloff * (1.0 - (-d2 / (2.0 * self.lamp_radius.powi(2))).exp())
    }
}

/// Smooth value noise in [0, 1]: hashed values on the integer lattice, blended with the
/// smoothstep.
fn value_noise(x: f64, y: f64, seed: u64) -> f64 {
    let hash = |i: i64, j: i64| -> f64 {
        let mut z = seed
            ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        // splitmix64's finaliser.
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    };
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let smooth = |t: f64| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (smooth(fx), smooth(fy));
    let (i, j) = (x0 as i64, y0 as i64);
    let top = hash(i, j) * (1.0 - sx) + hash(i + 1, j) * sx;
    let bottom = hash(i, j + 1) * (1.0 - sx) + hash(i + 1, j + 1) * sx;
    top * (1.0 - sy) + bottom * sy
}

/// The pose of a camera looking at the centre of a `cols × rows` board lying on a table, from
/// `obliquity_deg` away from the board's normal (0 = straight down; 90 = along the table), the
/// camera's direction on the table at `azimuth_deg` from the board's x axis (0: the x axis,
/// the board's long side for cols > rows, runs away from the camera), no roll (the horizon
/// level), seen from the board's front (its x axis to the right of its y axis, so the image is
/// not mirrored). The distance makes the board's outline, margin included, span `fill` of the
/// image's width or height, whichever it reaches first, for a camera `(w, h, f)`; distortion
/// is not considered. Returns `(R, t)` with `X_cam = R·X_board + t` (board units).
pub fn table_pose(
    cols: usize,
    rows: usize,
    (w, h, f): (usize, usize, f64),
    obliquity_deg: f64,
    azimuth_deg: f64,
    fill: f64,
) -> (Matrix3<f64>, Vector3<f64>) {
    let (th, psi) = (obliquity_deg.to_radians(), azimuth_deg.to_radians());
    let centre = Vector3::new((cols as f64 - 1.0) / 2.0, (rows as f64 - 1.0) / 2.0, 0.0);
    // The board's front faces −z (as `calib`'s board frame: x right, y down, z away from the
    // camera), so "up" from the table is −z.
    let up = Vector3::new(0.0, 0.0, -1.0);
    // Towards the camera along the table: the x axis at azimuth 0, so the x axis runs away.
    let towards = -Vector3::new(psi.cos(), psi.sin(), 0.0);
    let view = -(th.sin() * towards + th.cos() * up); // camera → board centre
    let pose = |d: f64| {
        let cam = centre - d * view;
        let z = view;
        // Image down: the table's "down" without its component along the view.
        let down = -up - z * (-up).dot(&z);
        let y = if down.norm() > 1e-9 {
            down.normalize()
        } else {
            // Straight down onto the board: the board's y axis down the image.
            Vector3::new(0.0, 1.0, 0.0)
        };
        let x = y.cross(&z);
        let r = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
        (r, -r * cam)
    };
    // The outline (margin included) in the image, relative to the image's size.
    let (c, r) = (cols as f64, rows as f64);
    let span = |d: f64| {
        let (rot, t) = pose(d);
        let pts: Vec<Vector2<f64>> =
            [(-2.0, -2.0), (c + 1.0, -2.0), (-2.0, r + 1.0), (c + 1.0, r + 1.0)]
                .iter()
                .map(|&(x, y)| {
                    let p = rot * Vector3::new(x, y, 0.0) + t;
                    Vector2::new(f * p.x / p.z, f * p.y / p.z)
                })
                .collect();
        let ext = |g: fn(&Vector2<f64>) -> f64| {
            let (lo, hi) =
                pts.iter().map(g).fold((f64::MAX, f64::MIN), |a, v| (a.0.min(v), a.1.max(v)));
            hi - lo
        };
        (ext(|p| p.x) / w as f64).max(ext(|p| p.y) / h as f64)
    };
    // The span shrinks with the distance: bisect for `fill`, from the distance that puts the
    // whole outline (within its half diagonal of the centre) just in front of the camera.
    let (mut near, mut far) = (0.5 * (c + 3.0).hypot(r + 3.0) + 0.5, 1e4);
    for _ in 0..100 {
        let mid = 0.5 * (near + far);
        if span(mid) > fill { near = mid } else { far = mid }
    }
    pose(far)
}
