//! Factory parameters read from the device (protocol §4.5–§4.7) and the x/z tables derived from
//! them (protocol §9.2).

use crate::error::{KinectError, Result};
use crate::orientation::mirror_coordinate;
use crate::raw::{HEIGHT, PIXELS, WIDTH};
use crate::registration::COLOR_WIDTH;

/// Minimum size of the depth-camera parameter response (23 f32).
pub const DEPTH_PARAMS_MIN_LEN: usize = 92;
/// Size of the P0-table response.
pub const P0_RESPONSE_LEN: usize = 1_302_572;
/// Byte offsets of the three P0 tables within the response.
pub const P0_TABLE_OFFSETS: [usize; 3] = [34, 434_214, 868_394];
/// Size of the colour-camera parameter response.
pub const COLOR_PARAMS_LEN: usize = 12_981;
/// Newton iterations allowed for undistortion (protocol §9.2).
const MAX_NEWTON_ITERS: usize = 100;

fn f32_at(b: &[u8], off: usize) -> f32 {
    f32::from_le_bytes([b[off], b[off + 1], b[off + 2], b[off + 3]])
}

/// Depth (IR) camera intrinsics as stored in the device (pixels; Brown–Conrady distortion).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthParams {
    /// Focal length x, pixels.
    pub fx: f32,
    /// Focal length y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
    /// Radial k1.
    pub k1: f32,
    /// Radial k2.
    pub k2: f32,
    /// Radial k3.
    pub k3: f32,
    /// Tangential p1.
    pub p1: f32,
    /// Tangential p2.
    pub p2: f32,
}

impl DepthParams {
    /// Parses the response to command 0x22 page 3 (23 f32: fx, fy, 0, cx, cy, k1, k2, p1, p2, k3, …).
    pub fn from_response(b: &[u8]) -> Result<Self> {
        if b.len() < DEPTH_PARAMS_MIN_LEN {
            return Err(KinectError::Size {
                what: "depth camera parameter response".into(),
                expected: DEPTH_PARAMS_MIN_LEN,
                got: b.len(),
            });
        }
        Ok(DepthParams {
            fx: f32_at(b, 0),
            fy: f32_at(b, 4),
            cx: f32_at(b, 12),
            cy: f32_at(b, 16),
            k1: f32_at(b, 20),
            k2: f32_at(b, 24),
            p1: f32_at(b, 28),
            p2: f32_at(b, 32),
            k3: f32_at(b, 36),
        })
    }

    /// The parameters of the same camera in left–right mirrored images
    /// ([`crate::orientation`]): `cx → 511 − cx`, and `p2` negated (the tangential term that is
    /// even in x); everything else is unchanged. Mirroring twice gives the parameters back
    /// exactly.
    pub fn mirrored(&self) -> Self {
        DepthParams { cx: mirror_coordinate(self.cx, WIDTH), p2: -self.p2, ..*self }
    }

    /// Serialises to the 92-byte response layout (used by the simulated device).
    pub fn to_response(&self) -> Vec<u8> {
        let mut v = [0f32; 23];
        v[0] = self.fx;
        v[1] = self.fy;
        v[3] = self.cx;
        v[4] = self.cy;
        v[5] = self.k1;
        v[6] = self.k2;
        v[7] = self.p1;
        v[8] = self.p2;
        v[9] = self.k3;
        v.iter().flat_map(|f| f.to_le_bytes()).collect()
    }
}

/// The three per-pixel phase-offset tables (upright orientation, 424 × 512 u16 each).
#[derive(Debug, Clone, PartialEq)]
pub struct P0Tables {
    /// `tables[k][r*512 + c]` for modulation frequency k.
    pub tables: [Vec<u16>; 3],
}

impl P0Tables {
    /// Parses the response to command 0x22 page 2 (extra bytes are ignored).
    pub fn from_response(b: &[u8]) -> Result<Self> {
        if b.len() < P0_RESPONSE_LEN {
            return Err(KinectError::Size {
                what: "P0 table response".into(),
                expected: P0_RESPONSE_LEN,
                got: b.len(),
            });
        }
        let t = |k: usize| -> Vec<u16> {
            b[P0_TABLE_OFFSETS[k]..][..2 * PIXELS]
                .chunks_exact(2)
                .map(|c| u16::from_le_bytes([c[0], c[1]]))
                .collect()
        };
        Ok(P0Tables { tables: [t(0), t(1), t(2)] })
    }

    /// Serialises to the response layout (header and guard words zero except the header's
    /// first and fourth word, as in the vectors).
    pub fn to_response(&self) -> Vec<u8> {
        let mut out = vec![0u8; P0_RESPONSE_LEN];
        out[0..4].copy_from_slice(&32u32.to_le_bytes());
        out[12..16].copy_from_slice(&434_176u32.to_le_bytes());
        for k in 0..3 {
            for (i, v) in self.tables[k].iter().enumerate() {
                out[P0_TABLE_OFFSETS[k] + 2 * i..][..2].copy_from_slice(&v.to_le_bytes());
            }
        }
        out
    }
}

/// Colour camera parameters (protocol §4.7).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColorParams {
    /// Focal length (fx = fy), pixels.
    pub f: f32,
    /// Principal point x.
    pub cx: f32,
    /// Principal point y.
    pub cy: f32,
    /// Depth (mm) at which the reference offset is calibrated.
    pub shift_d: f32,
    /// Baseline-like parallax constant (mm).
    pub shift_m: f32,
    /// x-mapping coefficients of x³, y³, x²y, xy², x², y², xy, x, y, 1.
    pub mx: [f32; 10],
    /// y-mapping coefficients, same monomials.
    pub my: [f32; 10],
}

/// Sign of each `mx` coefficient under mirroring: `wx'(a, b) = −wx(−a, b)`, so the monomial
/// `a^i·b^j` (order x³, y³, x²y, xy², x², y², xy, x, y, 1; `i` = its power of x) keeps its
/// coefficient times `(−1)^(i+1)`.
const MIRROR_SIGN_MX: [f32; 10] = [1.0, -1.0, -1.0, 1.0, -1.0, -1.0, 1.0, 1.0, -1.0, -1.0];
/// Sign of each `my` coefficient under mirroring: `wy'(a, b) = wy(−a, b)`, `(−1)^i`.
const MIRROR_SIGN_MY: [f32; 10] = [-1.0, 1.0, 1.0, -1.0, 1.0, 1.0, -1.0, -1.0, 1.0, 1.0];

impl ColorParams {
    /// The factory registration of left–right mirrored depth and colour images
    /// ([`crate::orientation`]), given the depth camera's [`DepthParams::mirrored`]: a depth
    /// pixel `(511 − x, y)` at depth `z` then maps to colour pixel `(1919 − u, v)` where `(x, y)`
    /// mapped to `(u, v)` (protocol §11.2: `u = (rx + shift_m/z)·f + cx`, so `cx → 1919 − cx`,
    /// `shift_m → −shift_m` and `rx → −rx`, whose polynomial in the mirrored `(x − cx)` changes
    /// the signs of [`MIRROR_SIGN_MX`]; `ry` is unchanged, [`MIRROR_SIGN_MY`]). Exact up to f32
    /// rounding of `1919 − cx`; mirroring twice gives the parameters back exactly.
    pub fn mirrored(&self) -> Self {
        let mut mx = self.mx;
        let mut my = self.my;
        for i in 0..10 {
            mx[i] *= MIRROR_SIGN_MX[i];
            my[i] *= MIRROR_SIGN_MY[i];
        }
        ColorParams {
            cx: mirror_coordinate(self.cx, COLOR_WIDTH),
            shift_m: -self.shift_m,
            mx,
            my,
            ..*self
        }
    }

    /// Parses the response to command 0x22 page 4.
    pub fn from_response(b: &[u8]) -> Result<Self> {
        if b.len() < COLOR_PARAMS_LEN {
            return Err(KinectError::Size {
                what: "colour camera parameter response".into(),
                expected: COLOR_PARAMS_LEN,
                got: b.len(),
            });
        }
        let mut mx = [0f32; 10];
        let mut my = [0f32; 10];
        for i in 0..10 {
            mx[i] = f32_at(b, 21 + 4 * i);
            my[i] = f32_at(b, 61 + 4 * i);
        }
        Ok(ColorParams {
            f: f32_at(b, 1),
            cx: f32_at(b, 5),
            cy: f32_at(b, 9),
            shift_d: f32_at(b, 13),
            shift_m: f32_at(b, 17),
            mx,
            my,
        })
    }

    /// Serialises to the 12 981-byte response layout (trailing tables zero).
    pub fn to_response(&self) -> Vec<u8> {
        let mut out = vec![0u8; COLOR_PARAMS_LEN];
        out[0] = 1;
        let head = [self.f, self.cx, self.cy, self.shift_d, self.shift_m];
        for (i, v) in head.iter().chain(self.mx.iter()).chain(self.my.iter()).enumerate() {
            out[1 + 4 * i..][..4].copy_from_slice(&v.to_le_bytes());
        }
        out
    }
}

/// x/z tables indexed by table row (= the CPU decoder's processing row) × 512 + column.
#[derive(Debug, Clone, PartialEq)]
pub struct XzTables {
    /// `8192 · x_undistorted` per pixel.
    pub x: Vec<f32>,
    /// `(6250/3) / sqrt(xu² + yu² + 1)` per pixel; `≤ 0` marks an invalid pixel.
    pub z: Vec<f32>,
    /// Pixels whose undistortion did not converge within 100 Newton steps.
    pub nonconverged: usize,
}

impl XzTables {
    /// Computes the tables from the depth intrinsics (protocol §9.2, f64 Newton undistortion).
    pub fn from_params(p: &DepthParams) -> Self {
        let (fx, fy, cx, cy) = (p.fx as f64, p.fy as f64, p.cx as f64, p.cy as f64);
        let (k1, k2, k3, p1, p2) =
            (p.k1 as f64, p.k2 as f64, p.k3 as f64, p.p1 as f64, p.p2 as f64);
        let mut x = vec![0f32; PIXELS];
        let mut z = vec![0f32; PIXELS];
        let mut nonconverged = 0;
        let eps = 16.0 * f64::EPSILON;
        for v in 0..HEIGHT {
            for u in 0..WIDTH {
                let xd = (u as f64 + 0.5 - cx) / fx;
                let yd = (v as f64 + 0.5 - cy) / fy;
                let (mut px, mut py) = (xd, yd);
                let mut converged = false;
                for _ in 0..MAX_NEWTON_ITERS {
                    let r2 = px * px + py * py;
                    let kappa = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
                    let dk = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r2 * r2;
                    let dxv = px * kappa + p2 * (r2 + 2.0 * px * px) + 2.0 * p1 * px * py - xd;
                    let dyv = py * kappa + p1 * (r2 + 2.0 * py * py) + 2.0 * p2 * px * py - yd;
                    let j11 = kappa + 2.0 * px * px * dk + 6.0 * p2 * px + 2.0 * p1 * py;
                    let j12 = 2.0 * px * py * dk + 2.0 * p1 * px + 2.0 * p2 * py;
                    let j22 = kappa + 2.0 * py * py * dk + 2.0 * p2 * px + 6.0 * p1 * py;
                    let det = j11 * j22 - j12 * j12;
                    let ddx = (j22 * dxv - j12 * dyv) / det;
                    let ddy = (j11 * dyv - j12 * dxv) / det;
                    px -= ddx;
                    py -= ddy;
                    if ddx.abs() <= eps && ddy.abs() <= eps {
                        converged = true;
                        break;
                    }
                }
                if !converged {
                    nonconverged += 1;
                }
                let n = v * WIDTH + u;
                x[n] = (8192.0 * px) as f32;
                z[n] = ((6250.0 / 3.0) / (px * px + py * py + 1.0).sqrt()) as f32;
            }
        }
        XzTables { x, z, nonconverged }
    }

    /// Wraps tables read from files (each 424 × 512 f32).
    pub fn from_vecs(x: Vec<f32>, z: Vec<f32>) -> Result<Self> {
        for (name, t) in [("x table", &x), ("z table", &z)] {
            if t.len() != PIXELS {
                return Err(KinectError::Size {
                    what: name.into(),
                    expected: PIXELS,
                    got: t.len(),
                });
            }
        }
        Ok(XzTables { x, z, nonconverged: 0 })
    }
}
