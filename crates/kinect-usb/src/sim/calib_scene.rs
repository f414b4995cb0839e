//! The simulated sensor's calibration scene (labs L1–L3): a checkerboard of
//! [`BOARD_INNER_CORNERS`] inner corners and [`BOARD_SQUARE_M`] squares (with a white margin)
//! in front of a grey wall, moving through [`BOARD_POSES`] tilted poses, rendered in IR
//! (amplitude ∝ albedo·cos/r², with noise), depth (z, mm) and colour with the rig of the
//! profile's own factory parameters in the scene orientation ([`FactoryRig::of_scene`]), then
//! mirrored as the sensor streams it. Frame `k` of the scene (depth and colour alike) shows
//! pose `k mod N`, so `kfuse capture calib --backend sim --count N --interval 0` takes one shot
//! per pose and `kfuse calibrate` should recover [`FactoryRig::of_scene`].
//!
//! Pixel convention: integer coordinates are pixel centres (as the factory registration maps,
//! protocol §11.1, no `+0.5`); frames: x right, y down, z forward; `X_color = X_depth + t`.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::{SimProfile, SimScene};
use crate::orientation::mirror_rows;
use crate::params::DepthParams;
use crate::raw::{HEIGHT, WIDTH};

/// The colour image's size, pixels.
pub(crate) const COLOR_SIZE: (usize, usize) = (1920, 1080);

/// Inner corners per row × per column (`kfuse calibrate --board 7x5`, its default).
pub const BOARD_INNER_CORNERS: (usize, usize) = (7, 5);
/// Side of one square, metres (`--square 40mm`, calibrate's default).
pub const BOARD_SQUARE_M: f64 = 0.04;
/// White margin around the squares, metres (a detector needs a quiet zone around the board).
pub const BOARD_MARGIN_M: f64 = 0.03;
/// IR albedo of the white squares and margin, of the black squares, of the wall and of the
/// board's plain back: a printed board's black absorbs most of the 860 nm light, its paper
/// reflects most of it; the back is grey foam board (printed on one side only, as real boards
/// are, so a sensor behind the board sees no pattern: [`crate::sim::ring`]).
const ALBEDO: [f64; 4] = [0.85, 0.10, 0.5, 0.6];
/// Colour of the white squares, black squares, wall and the board's back (RGB).
const COLOR_RGB: [[f64; 3]; 4] =
    [[235.0, 235.0, 228.0], [25.0, 25.0, 28.0], [120.0, 110.0, 95.0], [190.0, 188.0, 182.0]];
/// Material index of the wall (or the ring's round room) and of the board's back.
const WALL: usize = 2;
const BACK: usize = 3;
/// The wall behind the board: a plane z = this many metres (inside the Kinect's 4.5 m range,
/// 5 cm behind the farthest pose's corners).
const WALL_Z_M: f64 = 2.6;
/// Scale from amplitude (albedo·cos/r², r in metres) to decoder IR units: the same as the
/// default scene's (`SIM_IR_SCALE` of the capture code), white at 1 m ≈ 17 000.
const IR_SCALE: f64 = 20_000.0;
/// Relative IR noise (1σ; the Kinect's IR shows a few per cent of shot noise).
const IR_NOISE: f64 = 0.02;
/// Colour noise, grey levels (1σ, before JPEG).
const COLOR_NOISE: f64 = 2.0;
/// Supersampling per axis of the IR (3×3) and colour (2×2) pixels: anti-aliased edges, so
/// corners are located to a small fraction of a pixel as on a real board.
const IR_SAMPLES: usize = 3;
const COLOR_SAMPLES: usize = 2;
/// JPEG quality of the colour frames (the sensor's own JPEGs are of similar quality).
pub(crate) const JPEG_QUALITY: u8 = 92;
/// Fixed-point iterations undistorting a depth pixel (the depth lens's distortion is mild:
/// converges to < 1e-9 in ~10).
const UNDISTORT_ITERATIONS: usize = 20;

/// Board poses: centre `(x/z, y/z, z in m)` in the depth camera, then rotations about the
/// board's x, y and z axes in degrees (tilt from facing the camera 10–40°, distances
/// 0.6–2.5 m, centres spread over the image). The first 12 (0.6–1.5 m) are the intrinsic
/// calibration's; the last 5 (1.7–2.5 m, four of them towards the image corners) give the
/// depth calibration (issue 16) the range that separates offset from scale and the corners
/// where a radial error shows. Beyond ~2.5 m the 40 mm squares are under 6 IR pixels and the
/// board is no longer detected (measured: poses at 2.7 and 3.0 m gave no board).
pub const BOARD_POSES: [[f64; 6]; 17] = [
    [0.00, 0.00, 0.70, 15.0, -20.0, 5.0],
    [-0.25, -0.12, 0.90, -20.0, 25.0, -8.0],
    [0.25, -0.12, 0.90, 20.0, -25.0, 10.0],
    [-0.25, 0.12, 1.00, -10.0, 30.0, 3.0],
    [0.25, 0.12, 1.00, 25.0, 15.0, -12.0],
    [0.00, -0.15, 1.20, -30.0, 0.0, 15.0],
    [0.00, 0.15, 1.20, 30.0, 10.0, -5.0],
    [-0.30, 0.00, 1.40, 5.0, 35.0, 8.0],
    [0.30, 0.00, 1.40, -5.0, -35.0, -8.0],
    [0.10, 0.05, 0.60, 8.0, 12.0, 20.0],
    [-0.15, -0.05, 1.50, -25.0, -25.0, 0.0],
    [0.18, 0.12, 1.10, 12.0, -8.0, 25.0],
    [0.45, 0.32, 1.70, 15.0, -15.0, 5.0],
    [-0.45, 0.32, 1.90, -12.0, 18.0, -6.0],
    [0.45, -0.32, 2.10, 18.0, 10.0, 8.0],
    [-0.45, -0.32, 2.30, -10.0, -15.0, 0.0],
    [0.00, 0.00, 2.50, 12.0, 12.0, 4.0],
];

/// The pinhole rig the factory parameters describe when their colour polynomial is affine
/// (the simulated profile's, [`SimProfile::synthetic`]): derived from protocol §11.1–11.2,
/// `u = (rx + shift_m/z)·f + cx`, `rx = wx/(f·qc) − shift_m/shift_d`, `v = wy/qc + cy`, with
/// `wx = mx[7]·(x − cx_d)·qd + mx[9]`, `wy = my[8]·(y − cy_d)·qd + my[9]` and
/// `x − cx_d = fx_d·X/Z`. The parallax `f·shift_m/z` is the colour camera's translation:
/// `t = (f·shift_m/fx, 0, 0)` mm, `R = I` — positive on real devices (`shift_m = 52`).
#[derive(Debug, Clone, PartialEq)]
pub struct FactoryRig {
    /// The depth camera (Brown–Conrady, integer pixel centres).
    pub depth: DepthParams,
    /// Colour focal lengths and principal point, pixels.
    pub color: [f64; 4],
    /// `X_color = X_depth + t`, metres.
    pub t_m: [f64; 3],
}

/// Depth and colour quanta of the factory polynomial (protocol §11.1).
const QD: f64 = 0.01;
const QC: f64 = 0.002199;

impl FactoryRig {
    /// The rig of `p`, or `None` where its colour polynomial is not affine and diagonal (a
    /// real device's cubic is no pinhole camera).
    pub fn of_profile(p: &SimProfile) -> Option<Self> {
        let c = &p.color_params;
        let affine = |m: &[f32; 10], keep: usize| {
            m.iter().enumerate().all(|(i, &v)| i == keep || i == 9 || v == 0.0)
        };
        if !affine(&c.mx, 7) || !affine(&c.my, 8) || c.shift_d == 0.0 {
            return None;
        }
        let d = &p.depth_params;
        let (f, sm, sd) = (c.f as f64, c.shift_m as f64, c.shift_d as f64);
        let fx = c.mx[7] as f64 * QD * d.fx as f64 / QC;
        let fy = c.my[8] as f64 * QD * d.fy as f64 / QC;
        let cx = c.mx[9] as f64 / QC - f * sm / sd + c.cx as f64;
        let cy = c.my[9] as f64 / QC + c.cy as f64;
        Some(FactoryRig { depth: *d, color: [fx, fy, cx, cy], t_m: [f * sm / fx * 1e-3, 0.0, 0.0] })
    }

    /// The rig of the same cameras in left–right mirrored images (`crate::orientation`): the
    /// depth camera [`DepthParams::mirrored`], the colour principal point `cx → 1919 − cx` and
    /// the translation's x negated.
    pub fn mirrored(&self) -> Self {
        let [fx, fy, cx, cy] = self.color;
        FactoryRig {
            depth: self.depth.mirrored(),
            color: [fx, fy, (COLOR_SIZE.0 - 1) as f64 - cx, cy],
            t_m: [-self.t_m[0], self.t_m[1], self.t_m[2]],
        }
    }

    /// The rig of the images a capture of `p` writes (as the scene is, kfuse's rule): the
    /// mirror of [`FactoryRig::of_profile`], whose parameters are of the sensor's mirrored
    /// stream. The calibration scene is rendered with it ([`calibration_scene`]).
    pub fn of_scene(p: &SimProfile) -> Option<Self> {
        Self::of_profile(p).map(|r| r.mirrored())
    }

    /// Undistorted normalised coordinates of distorted depth pixel `(u, v)`.
    pub fn depth_ray(&self, u: f64, v: f64) -> [f64; 2] {
        let d = &self.depth;
        let (xd, yd) = ((u - d.cx as f64) / d.fx as f64, (v - d.cy as f64) / d.fy as f64);
        let (k1, k2, k3, p1, p2) =
            (d.k1 as f64, d.k2 as f64, d.k3 as f64, d.p1 as f64, d.p2 as f64);
        let (mut x, mut y) = (xd, yd);
        for _ in 0..UNDISTORT_ITERATIONS {
            let r2 = x * x + y * y;
            let kappa = 1.0 + ((k3 * r2 + k2) * r2 + k1) * r2;
            let tx = p2 * (r2 + 2.0 * x * x) + p1 * 2.0 * x * y;
            let ty = p1 * (r2 + 2.0 * y * y) + p2 * 2.0 * x * y;
            x = (xd - tx) / kappa;
            y = (yd - ty) / kappa;
        }
        [x, y]
    }

    /// Distorted depth pixel of the depth-frame point `p` (protocol §11.1's distortion).
    pub fn project_depth(&self, p: [f64; 3]) -> [f64; 2] {
        let d = &self.depth;
        let (x, y) = (p[0] / p[2], p[1] / p[2]);
        let (k1, k2, k3, p1, p2) =
            (d.k1 as f64, d.k2 as f64, d.k3 as f64, d.p1 as f64, d.p2 as f64);
        let r2 = x * x + y * y;
        let kappa = 1.0 + ((k3 * r2 + k2) * r2 + k1) * r2;
        let xd = x * kappa + p2 * (r2 + 2.0 * x * x) + p1 * 2.0 * x * y;
        let yd = y * kappa + p1 * (r2 + 2.0 * y * y) + p2 * 2.0 * x * y;
        [d.fx as f64 * xd + d.cx as f64, d.fy as f64 * yd + d.cy as f64]
    }

    /// Colour pixel of the depth-frame point `p`.
    pub fn project_color(&self, p: [f64; 3]) -> [f64; 2] {
        let q = [p[0] + self.t_m[0], p[1] + self.t_m[1], p[2] + self.t_m[2]];
        let [fx, fy, cx, cy] = self.color;
        [fx * q[0] / q[2] + cx, fy * q[1] / q[2] + cy]
    }
}

/// One board pose: `X_depth = R·X_board + t`; board points `(i·s, j·s, 0)` are the inner
/// corners (row-major, `i` along the row).
#[derive(Debug, Clone, Copy)]
pub struct BoardPose {
    /// Rotation, row-major.
    pub r: [[f64; 3]; 3],
    /// Translation, metres.
    pub t: [f64; 3],
}

fn mat_mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

impl BoardPose {
    /// Pose `k` of [`BOARD_POSES`].
    pub fn of_index(k: usize) -> Self {
        Self::from_row(BOARD_POSES[k % BOARD_POSES.len()])
    }

    /// The pose a row of [`BOARD_POSES`] describes: board centre `(x/z, y/z, z in m)`, then
    /// rotations about the board's x, y and z axes in degrees.
    pub fn from_row(row: [f64; 6]) -> Self {
        let [fx, fy, z, ax, ay, az] = row;
        let (sx, cx) = ax.to_radians().sin_cos();
        let (sy, cy) = ay.to_radians().sin_cos();
        let (sz, cz) = az.to_radians().sin_cos();
        let rx = [[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]];
        let ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
        let rz = [[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]];
        let r = mat_mul(&mat_mul(&rz, &ry), &rx);
        let (w, h) = (BOARD_INNER_CORNERS.0 - 1, BOARD_INNER_CORNERS.1 - 1);
        let mid = [w as f64 * BOARD_SQUARE_M / 2.0, h as f64 * BOARD_SQUARE_M / 2.0];
        let centre = [fx * z, fy * z, z];
        let t = std::array::from_fn(|i| centre[i] - r[i][0] * mid[0] - r[i][1] * mid[1]);
        BoardPose { r, t }
    }

    /// The depth-frame position of board point `(bx, by)` (metres on the board).
    pub fn point(&self, bx: f64, by: f64) -> [f64; 3] {
        std::array::from_fn(|i| self.r[i][0] * bx + self.r[i][1] * by + self.t[i])
    }

    /// The tilt from facing the camera along its axis, degrees.
    pub fn tilt_deg(&self) -> f64 {
        self.r[2][2].abs().acos().to_degrees()
    }

    /// Left-multiplies the pose by `X_to = r·X_from + t`: the same board in another frame.
    pub fn transformed(&self, r: &[[f64; 3]; 3], t: &[f64; 3]) -> Self {
        let rr = mat_mul(r, &self.r);
        let tt = std::array::from_fn(|i| (0..3).map(|k| r[i][k] * self.t[k]).sum::<f64>() + t[i]);
        BoardPose { r: rr, t: tt }
    }

    /// Whether a camera at `o` (same frame as the pose) sees the printed side: it lies on
    /// the side the board's −z axis points to (the side every pose of [`BOARD_POSES`] faces).
    pub fn front_faces(&self, o: [f64; 3]) -> bool {
        let n = [self.r[0][2], self.r[1][2], self.r[2][2]];
        (0..3).map(|i| n[i] * (self.t[i] - o[i])).sum::<f64>() > 0.0
    }

    /// What a ray `o + s·d` (depth frame) hits: (material index into [`ALBEDO`], the point,
    /// the surface normal), the board (printed side or back) or else `backdrop`.
    fn hit(&self, o: [f64; 3], d: [f64; 3], backdrop: &Backdrop) -> (usize, [f64; 3], [f64; 3]) {
        let n = [self.r[0][2], self.r[1][2], self.r[2][2]];
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let nd = dot(n, d);
        if nd.abs() > 1e-9 {
            let s = dot(n, [self.t[0] - o[0], self.t[1] - o[1], self.t[2] - o[2]]) / nd;
            let p = [o[0] + s * d[0], o[1] + s * d[1], o[2] + s * d[2]];
            if s > 0.0 {
                let q = [p[0] - self.t[0], p[1] - self.t[1], p[2] - self.t[2]];
                let (bx, by) = (
                    self.r[0][0] * q[0] + self.r[1][0] * q[1] + self.r[2][0] * q[2],
                    self.r[0][1] * q[0] + self.r[1][1] * q[1] + self.r[2][1] * q[2],
                );
                let sq = BOARD_SQUARE_M;
                let (w, h) = (BOARD_INNER_CORNERS.0 as f64 * sq, BOARD_INNER_CORNERS.1 as f64 * sq);
                let m = BOARD_MARGIN_M;
                if bx >= -sq - m && bx <= w + m && by >= -sq - m && by <= h + m {
                    // A ray reaching the plane along −n comes from behind: the plain back.
                    if nd < 0.0 {
                        return (BACK, p, n);
                    }
                    let inside = bx >= -sq && bx < w && by >= -sq && by < h;
                    let (i, j) = ((bx / sq).floor() as i64, (by / sq).floor() as i64);
                    let black = inside && (i + j).rem_euclid(2) == 0;
                    return (usize::from(black), p, n);
                }
            }
        }
        backdrop.hit(o, d)
    }
}

/// What lies behind the board.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Backdrop {
    /// The single sensor's wall: the plane z = [`WALL_Z_M`] of its depth frame.
    Wall,
    /// A round room: the vertical cylinder of `radius` metres about the world's y axis, seen
    /// by a camera with `world_from_camera` (`X_world = r·X_camera + t`).
    Cylinder {
        /// Rotation, row-major.
        r: [[f64; 3]; 3],
        /// Translation, metres.
        t: [f64; 3],
        /// Radius, metres.
        radius: f64,
    },
}

impl Backdrop {
    /// (material, point, normal) of the backdrop along `o + s·d`.
    fn hit(&self, o: [f64; 3], d: [f64; 3]) -> (usize, [f64; 3], [f64; 3]) {
        match *self {
            Backdrop::Wall => {
                let s = (WALL_Z_M - o[2]) / d[2];
                (WALL, [o[0] + s * d[0], o[1] + s * d[1], WALL_Z_M], [0.0, 0.0, 1.0])
            }
            Backdrop::Cylinder { r, t, radius } => {
                let rot = |v: [f64; 3]| -> [f64; 3] {
                    std::array::from_fn(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2])
                };
                let (ow, dw) = (rot(o), rot(d));
                let ow = [ow[0] + t[0], ow[1] + t[1], ow[2] + t[2]];
                let a = dw[0] * dw[0] + dw[2] * dw[2];
                let b = 2.0 * (ow[0] * dw[0] + ow[2] * dw[2]);
                let c = ow[0] * ow[0] + ow[2] * ow[2] - radius * radius;
                // Inside the room (c < 0) the far root is the wall; a vertical ray (outside
                // any Kinect's field of view) ends 4 m away.
                let s = if a > 1e-12 {
                    (-b + (b * b - 4.0 * a * c).max(0.0).sqrt()) / (2.0 * a)
                } else {
                    4.0
                };
                let p = [o[0] + s * d[0], o[1] + s * d[1], o[2] + s * d[2]];
                let pw = [ow[0] + s * dw[0], ow[2] + s * dw[2]];
                let nw = [pw[0] / radius, 0.0, pw[1] / radius];
                // Normal in the camera frame: rᵀ·n_world.
                let n =
                    std::array::from_fn(|i| r[0][i] * nw[0] + r[1][i] * nw[1] + r[2][i] * nw[2]);
                (WALL, p, n)
            }
        }
    }
}

/// IR amplitude (decoder units, no noise) and z (mm) seen along undistorted depth ray `(x, y)`.
fn ir_sample(pose: &BoardPose, backdrop: &Backdrop, x: f64, y: f64) -> (f64, f64) {
    let d = [x, y, 1.0];
    let (m, p, n) = pose.hit([0.0; 3], d, backdrop);
    let r2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
    let cos = (n[0] * p[0] + n[1] * p[1] + n[2] * p[2]).abs() / r2.sqrt();
    (ALBEDO[m] * cos / r2 * IR_SCALE, p[2] * 1000.0)
}

/// Rays per depth pixel: the [`IR_SAMPLES`]² supersamples, then the pixel centre.
const RAYS_PER_PIXEL: usize = IR_SAMPLES * IR_SAMPLES + 1;

/// The undistorted rays of every depth pixel's samples (row-major, [`RAYS_PER_PIXEL`] each):
/// computed once for all poses (the fixed-point undistortion is the costly part).
pub(crate) fn depth_rays(rig: &FactoryRig) -> Vec<[f64; 2]> {
    let n = IR_SAMPLES as f64;
    let mut rays = vec![[0.0; 2]; WIDTH * HEIGHT * RAYS_PER_PIXEL];
    rays.par_chunks_mut(WIDTH * RAYS_PER_PIXEL).enumerate().for_each(|(v, row)| {
        for (u, px) in row.chunks_mut(RAYS_PER_PIXEL).enumerate() {
            for (s, ray) in px.iter_mut().enumerate() {
                let (du, dv) = if s + 1 == RAYS_PER_PIXEL {
                    (0.0, 0.0)
                } else {
                    let (a, b) = (s / IR_SAMPLES, s % IR_SAMPLES);
                    ((b as f64 + 0.5) / n - 0.5, (a as f64 + 0.5) / n - 0.5)
                };
                *ray = rig.depth_ray(u as f64 + du, v as f64 + dv);
            }
        }
    });
    rays
}

/// Renders pose `k`: depth (z, mm) and IR, each 512 × 424, and the colour image (RGB8,
/// 1920 × 1080).
pub fn render_pose(rig: &FactoryRig, k: usize) -> (Vec<f32>, Vec<f32>, Vec<u8>) {
    render_pose_with(rig, &depth_rays(rig), k)
}

fn render_pose_with(
    rig: &FactoryRig,
    rays: &[[f64; 2]],
    k: usize,
) -> (Vec<f32>, Vec<f32>, Vec<u8>) {
    render_view(rig, rays, &BoardPose::of_index(k), &Backdrop::Wall, 0x5EED_0000 + k as u64)
}

/// Renders the board at `pose` (in the depth camera's frame) before `backdrop` with the rig
/// `rig` (depth rays `rays` of [`depth_rays`]); noise seeded with `seed`.
pub(crate) fn render_view(
    rig: &FactoryRig,
    rays: &[[f64; 2]],
    pose: &BoardPose,
    backdrop: &Backdrop,
    seed: u64,
) -> (Vec<f32>, Vec<f32>, Vec<u8>) {
    let pose = *pose;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut depth = vec![0f32; WIDTH * HEIGHT];
    let mut ir = vec![0f32; WIDTH * HEIGHT];
    let n = IR_SAMPLES as f64;
    depth.par_chunks_mut(WIDTH).zip(ir.par_chunks_mut(WIDTH)).enumerate().for_each(
        |(v, (drow, irow))| {
            for u in 0..WIDTH {
                let px = &rays[(v * WIDTH + u) * RAYS_PER_PIXEL..][..RAYS_PER_PIXEL];
                let sum: f64 = px[..RAYS_PER_PIXEL - 1]
                    .iter()
                    .map(|&[x, y]| ir_sample(&pose, backdrop, x, y).0)
                    .sum();
                let [x, y] = px[RAYS_PER_PIXEL - 1];
                drow[u] = ir_sample(&pose, backdrop, x, y).1 as f32;
                irow[u] = (sum / (n * n)) as f32;
            }
        },
    );
    for a in ir.iter_mut() {
        let g: f64 = gaussian(&mut rng);
        *a = (*a as f64 * (1.0 + IR_NOISE * g)).max(1.0) as f32;
    }
    let (cw, ch) = COLOR_SIZE;
    let [fx, fy, cx, cy] = rig.color;
    let o = [-rig.t_m[0], -rig.t_m[1], -rig.t_m[2]];
    // The board's bounding box in the colour image (+2 px): only there are pixels
    // supersampled; the smooth wall elsewhere takes one sample (a tenth of the cost).
    let (sq, mg) = (BOARD_SQUARE_M, BOARD_MARGIN_M);
    let (bw, bh) = (BOARD_INNER_CORNERS.0 as f64 * sq + mg, BOARD_INNER_CORNERS.1 as f64 * sq + mg);
    let outline = [(-sq - mg, -sq - mg), (bw, -sq - mg), (-sq - mg, bh), (bw, bh)]
        .map(|(x, y)| rig.project_color(pose.point(x, y)));
    let lo = |i: usize| outline.iter().map(|p| p[i]).fold(f64::INFINITY, f64::min) - 2.0;
    let hi = |i: usize| outline.iter().map(|p| p[i]).fold(f64::NEG_INFINITY, f64::max) + 2.0;
    let (umin, umax, vmin, vmax) = (lo(0), hi(0), lo(1), hi(1));
    let mut rgb = vec![0u8; cw * ch * 3];
    rgb.par_chunks_mut(cw * 3).enumerate().for_each(|(v, row)| {
        for u in 0..cw {
            let near = (umin..=umax).contains(&(u as f64)) && (vmin..=vmax).contains(&(v as f64));
            let ns = if near { COLOR_SAMPLES } else { 1 };
            let m = ns as f64;
            let mut acc = [0.0f64; 3];
            for a in 0..ns {
                for b in 0..ns {
                    let (du, dv) = ((b as f64 + 0.5) / m - 0.5, (a as f64 + 0.5) / m - 0.5);
                    let d = [(u as f64 + du - cx) / fx, (v as f64 + dv - cy) / fy, 1.0];
                    let (mat, p, _) = pose.hit(o, d, backdrop);
                    // Wall: a soft vertical gradient, so it is not a flat field.
                    let shade = if mat == WALL { 1.0 + 0.15 * p[1] } else { 1.0 };
                    for (c, a) in acc.iter_mut().enumerate() {
                        *a += COLOR_RGB[mat][c] * shade;
                    }
                }
            }
            for c in 0..3 {
                row[3 * u + c] = (acc[c] / (m * m)).round().clamp(0.0, 255.0) as u8;
            }
        }
    });
    for px in rgb.iter_mut() {
        let g: f64 = gaussian(&mut rng);
        *px = (*px as f64 + COLOR_NOISE * g).round().clamp(0.0, 255.0) as u8;
    }
    (depth, ir, rgb)
}

/// A standard normal sample (Box–Muller).
fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-12);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// The calibration scene for `profile`: one depth and one colour frame (quality-92 JPEG) per
/// pose of [`BOARD_POSES`]. `None` where the profile's colour mapping is not a pinhole camera
/// ([`FactoryRig::of_profile`]).
///
/// The boards are rendered as the scene is, with [`FactoryRig::of_scene`], and every image is
/// then mirrored left–right: what a real sensor streams (`crate::orientation`), so a capture,
/// which mirrors back, shows [`render_pose`] of that rig exactly.
pub fn calibration_scene(profile: &SimProfile) -> Option<SimScene> {
    calibration_scene_first(profile, BOARD_POSES.len())
}

/// The first `poses` frames of [`calibration_scene`] (`poses` clamped to
/// 1..=[`BOARD_POSES`]`.len()`), byte for byte the same (each pose keeps its own noise seed):
/// what a capture of `poses` shots takes at one shot per frame, without rendering the poses
/// it never reaches (each pose is a 1920 × 1080 supersampled render and JPEG). The sensor
/// cycles through the frames it has, so shots past the last one show pose 0 again.
pub fn calibration_scene_first(profile: &SimProfile, poses: usize) -> Option<SimScene> {
    let rig = FactoryRig::of_scene(profile)?;
    let rays = depth_rays(&rig);
    let frames: Vec<Option<_>> = (0..poses.clamp(1, BOARD_POSES.len()))
        .into_par_iter()
        .map(|k| {
            let (depth, ir, rgb) = render_pose_with(&rig, &rays, k);
            as_streamed(depth, ir, rgb)
        })
        .collect();
    scene_of_frames(frames)
}

/// A view as the sensor streams it: `((depth, IR), colour JPEG)`, mirrored left–right.
pub(crate) type StreamedView = ((Vec<f32>, Vec<f32>), Vec<u8>);

/// One rendered view as the sensor streams it: depth, IR and colour mirrored left–right
/// (`crate::orientation`), the colour as a quality-[`JPEG_QUALITY`] JPEG. `None` when the
/// encoder fails.
pub(crate) fn as_streamed(
    mut depth: Vec<f32>,
    mut ir: Vec<f32>,
    rgb: Vec<u8>,
) -> Option<StreamedView> {
    mirror_rows(&mut depth, WIDTH);
    mirror_rows(&mut ir, WIDTH);
    let mut px: Vec<[u8; 3]> = rgb.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    mirror_rows(&mut px, COLOR_SIZE.0);
    let rgb: Vec<u8> = px.concat();
    let mut jpeg = Vec::new();
    let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, JPEG_QUALITY);
    image::ImageEncoder::write_image(
        enc,
        &rgb,
        COLOR_SIZE.0 as u32,
        COLOR_SIZE.1 as u32,
        image::ExtendedColorType::Rgb8,
    )
    .ok()?;
    Some(((depth, ir), jpeg))
}

/// The scene of streamed views in order; `None` when any failed.
pub(crate) fn scene_of_frames(frames: Vec<Option<StreamedView>>) -> Option<SimScene> {
    let mut scene = SimScene::default();
    for f in frames {
        let (d, jpeg) = f?;
        scene.depth_frames.push(d);
        scene.color_jpegs.push(jpeg);
    }
    Some(scene)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn profile() -> SimProfile {
        let d = DepthParams {
            fx: 368.1,
            fy: 368.1,
            cx: 261.7,
            cy: 202.5,
            k1: 0.084,
            k2: -0.27,
            k3: 0.10,
            p1: 0.0,
            p2: 0.0,
        };
        SimProfile::synthetic(d, 1060.7)
    }

    /// The synthetic profile is a pinhole colour camera at `f`, the image centre, 52 mm along
    /// +x (protocol §4.7's `shift_m = 52`), to f32 rounding (1e-3 px, 1e-6 m).
    #[test]
    fn the_synthetic_profile_is_its_stated_pinhole_rig() {
        let rig = FactoryRig::of_profile(&profile()).unwrap();
        let [fx, fy, cx, cy] = rig.color;
        assert!((fx - 1060.7).abs() < 1e-3 && (fy - 1060.7).abs() < 1e-3, "{rig:?}");
        assert!((cx - 959.5).abs() < 1e-3 && (cy - 539.5).abs() < 1e-3, "{rig:?}");
        assert!((rig.t_m[0] - 0.052).abs() < 1e-6 && rig.t_m[1] == 0.0, "{rig:?}");
        let mut cubic = profile();
        cubic.color_params.mx[0] = 1e-3;
        assert!(FactoryRig::of_profile(&cubic).is_none());
    }

    /// Undistorting inverts the distortion to 1e-6 px over the whole depth image.
    #[test]
    fn depth_rays_invert_the_projection() {
        let rig = FactoryRig::of_profile(&profile()).unwrap();
        for (u, v) in [(0.0, 0.0), (511.0, 423.0), (261.7, 202.5), (100.0, 380.0)] {
            let [x, y] = rig.depth_ray(u, v);
            let [pu, pv] = rig.project_depth([x * 2.0, y * 2.0, 2.0]);
            assert!((pu - u).abs() < 1e-6 && (pv - v).abs() < 1e-6, "{u} {v} -> {pu} {pv}");
        }
    }

    /// A scene of the first 2 poses holds 2 frames, byte-identical to the full scene's first
    /// 2 (depth, IR and the colour JPEG); a request for 0 poses renders 1.
    #[test]
    fn the_first_poses_are_the_full_scenes_frames() {
        let full = calibration_scene(&profile()).unwrap();
        assert_eq!(full.depth_frames.len(), BOARD_POSES.len());
        let first = calibration_scene_first(&profile(), 2).unwrap();
        assert_eq!((first.depth_frames.len(), first.color_jpegs.len()), (2, 2));
        for k in 0..2 {
            assert!(first.depth_frames[k] == full.depth_frames[k], "pose {k}: depth or IR differ");
            assert!(first.color_jpegs[k] == full.color_jpegs[k], "pose {k}: colour JPEG differs");
        }
        assert_eq!(calibration_scene_first(&profile(), 0).unwrap().depth_frames.len(), 1);
    }

    /// Every pose is tilted 10–40°, at 0.6–2.6 m, with every inner corner at least 15 px
    /// inside both images (the whole board is detectable).
    #[test]
    fn every_pose_shows_the_whole_board_tilted() {
        let rig = FactoryRig::of_profile(&profile()).unwrap();
        for k in 0..BOARD_POSES.len() {
            let pose = BoardPose::of_index(k);
            let tilt = pose.tilt_deg();
            assert!((10.0..=40.0).contains(&tilt), "pose {k}: tilt {tilt}°");
            for j in 0..BOARD_INNER_CORNERS.1 {
                for i in 0..BOARD_INNER_CORNERS.0 {
                    let p = pose.point(i as f64 * BOARD_SQUARE_M, j as f64 * BOARD_SQUARE_M);
                    assert!((0.5..2.7).contains(&p[2]), "pose {k}: z {}", p[2]);
                    let [u, v] = rig.project_depth(p);
                    assert!(u > 15.0 && u < 496.0 && v > 15.0 && v < 408.0, "pose {k} ir {u} {v}");
                    let [u, v] = rig.project_color(p);
                    assert!(
                        u > 15.0 && u < 1904.0 && v > 15.0 && v < 1064.0,
                        "pose {k} colour {u} {v}"
                    );
                }
            }
        }
    }
}
