//! Depth → colour registration with the device's factory parameters (protocol §11).
//!
//! Depth pixels are upright (row 0 = top); colour pixels are 1920 × 1080, index `col + 1920·row`.
//! All arithmetic in f32 in the reference order, so outputs match the registration vectors
//! exactly.

use crate::params::{ColorParams, DepthParams};
use crate::raw::{HEIGHT, PIXELS, WIDTH};

/// Colour image width.
pub const COLOR_WIDTH: usize = 1920;
/// Colour image height.
pub const COLOR_HEIGHT: usize = 1080;
/// Rows of the bigdepth (filter map) image: colour rows plus one padding row above and below.
pub const BIGDEPTH_HEIGHT: usize = COLOR_HEIGHT + 2;
/// Depth quantum of the polynomial mapping (reference constant).
const DEPTH_Q: f32 = 0.01;
/// Colour quantum of the polynomial mapping (reference constant).
const COLOR_Q: f32 = 0.002199;
/// Occlusion filter window half-width (colour columns).
const FILTER_HALF_W: isize = 2;
/// Occlusion filter window half-height (colour rows).
const FILTER_HALF_H: isize = 1;
/// Relative depth difference above which a colour pixel counts as occluded (1 %).
const FILTER_TOLERANCE: f32 = 0.01;

/// Precomputed registration maps.
pub struct Registration {
    color: ColorParams,
    /// Per undistorted depth pixel: index of the distorted source pixel, or −1.
    distort_src: Vec<i32>,
    /// Per undistorted depth pixel: colour x at infinity (`rx`).
    map_x: Vec<f32>,
    /// Per undistorted depth pixel: colour y (`ry`).
    map_y: Vec<f32>,
    /// `trunc(ry + 0.5)`.
    map_yi: Vec<i32>,
}

/// Outputs of [`Registration::apply`].
pub struct Registered {
    /// Depth resampled onto the undistorted depth grid (mm).
    pub undistorted: Vec<f32>,
    /// Colour index per undistorted depth pixel, −1 if none.
    pub color_index: Vec<i32>,
    /// Registered colour (one u32 per depth pixel, same packing as the input), 0 = none.
    pub registered: Vec<u32>,
    /// 1920 × 1082 minimum-depth map (rows 0 and 1081 padding), +∞ where nothing maps.
    pub bigdepth: Vec<f32>,
}

impl Registration {
    /// Precomputes the maps from the depth and colour factory parameters.
    pub fn new(d: &DepthParams, color: &ColorParams) -> Self {
        let mut distort_src = vec![-1i32; PIXELS];
        let mut map_x = vec![0f32; PIXELS];
        let mut map_y = vec![0f32; PIXELS];
        let mut map_yi = vec![0i32; PIXELS];
        for y in 0..HEIGHT {
            for x in 0..WIDTH {
                let i = y * WIDTH + x;
                let (dx_, dy_) = distort(d, x as f32, y as f32);
                let ix = (dx_ + 0.5) as i32;
                let iy = (dy_ + 0.5) as i32;
                // `as` truncates toward zero: (−1, 0) becomes 0 (reference quirk, protocol §11.1).
                distort_src[i] =
                    if ix >= 0 && (ix as usize) < WIDTH && iy >= 0 && (iy as usize) < HEIGHT {
                        iy * WIDTH as i32 + ix
                    } else {
                        -1
                    };
                let (rx, ry) = depth_to_color(d, color, x as f32, y as f32);
                map_x[i] = rx;
                map_y[i] = ry;
                map_yi[i] = (ry + 0.5) as i32;
            }
        }
        Registration { color: *color, distort_src, map_x, map_y, map_yi }
    }

    /// Colour pixel (float) of undistorted depth pixel `(x, y)` at depth `z_mm` (protocol §11.2).
    pub fn map_point(&self, x: usize, y: usize, z_mm: f32) -> (f32, f32) {
        let i = y * WIDTH + x;
        let c = &self.color;
        ((self.map_x[i] + c.shift_m / z_mm) * c.f + c.cx, self.map_y[i])
    }

    /// Full-frame registration (protocol §11.3) of an upright depth image (mm) and a 1920 × 1080
    /// colour image (one u32 per pixel). With `filter` the occlusion filter is applied.
    pub fn apply(&self, depth: &[f32], color: &[u32], filter: bool, out: &mut Registered) {
        let c = &self.color;
        out.bigdepth.fill(f32::INFINITY);
        let big_len = out.bigdepth.len() as isize;
        for i in 0..PIXELS {
            let src = self.distort_src[i];
            if src < 0 {
                out.undistorted[i] = 0.0;
                out.color_index[i] = -1;
                continue;
            }
            let z = depth[src as usize];
            out.undistorted[i] = z;
            if z <= 0.0 {
                out.color_index[i] = -1;
                continue;
            }
            let cu = ((self.map_x[i] + c.shift_m / z) * c.f + (c.cx + 0.5)) as i32;
            let cv = self.map_yi[i];
            let off = cu as i64 + COLOR_WIDTH as i64 * cv as i64;
            if off < 0 || off >= (COLOR_WIDTH * COLOR_HEIGHT) as i64 {
                out.color_index[i] = -1;
                continue;
            }
            out.color_index[i] = off as i32;
            if filter {
                for row in (cv as isize - FILTER_HALF_H)..=(cv as isize + FILTER_HALF_H) {
                    for col in (cu as isize - FILTER_HALF_W)..=(cu as isize + FILTER_HALF_W) {
                        // Columns are not bounds-checked (reference behaviour: a window at the
                        // left/right edge spills into the neighbouring row); only the buffer is.
                        let idx = (row + 1) * COLOR_WIDTH as isize + col;
                        if (0..big_len).contains(&idx) {
                            let b = &mut out.bigdepth[idx as usize];
                            if z < *b {
                                *b = z;
                            }
                        }
                    }
                }
            }
        }
        for i in 0..PIXELS {
            let off = out.color_index[i];
            out.registered[i] = if off < 0 {
                0
            } else if filter {
                let z = out.undistorted[i];
                let b = out.bigdepth[off as usize + COLOR_WIDTH];
                if (z - b) / z > FILTER_TOLERANCE { 0 } else { color[off as usize] }
            } else {
                color[off as usize]
            };
        }
    }
}

impl Registered {
    /// Allocates output buffers.
    pub fn new() -> Self {
        Registered {
            undistorted: vec![0.0; PIXELS],
            color_index: vec![-1; PIXELS],
            registered: vec![0; PIXELS],
            bigdepth: vec![f32::INFINITY; COLOR_WIDTH * BIGDEPTH_HEIGHT],
        }
    }
}

impl Default for Registered {
    fn default() -> Self {
        Self::new()
    }
}

fn distort(d: &DepthParams, mx: f32, my: f32) -> (f32, f32) {
    let dx = (mx - d.cx) / d.fx;
    let dy = (my - d.cy) / d.fy;
    let dx2 = dx * dx;
    let dy2 = dy * dy;
    let r2 = dx2 + dy2;
    let dxdy2 = 2.0f32 * dx * dy;
    let kr = 1.0f32 + ((d.k3 * r2 + d.k2) * r2 + d.k1) * r2;
    let x = d.fx * (dx * kr + d.p2 * (r2 + 2.0f32 * dx2) + d.p1 * dxdy2) + d.cx;
    let y = d.fy * (dy * kr + d.p1 * (r2 + 2.0f32 * dy2) + d.p2 * dxdy2) + d.cy;
    (x, y)
}

fn depth_to_color(d: &DepthParams, c: &ColorParams, x: f32, y: f32) -> (f32, f32) {
    let mx = (x - d.cx) * DEPTH_Q;
    let my = (y - d.cy) * DEPTH_Q;
    let poly = |k: &[f32; 10]| {
        (mx * mx * mx * k[0])
            + (my * my * my * k[1])
            + (mx * mx * my * k[2])
            + (my * my * mx * k[3])
            + (mx * mx * k[4])
            + (my * my * k[5])
            + (mx * my * k[6])
            + (mx * k[7])
            + (my * k[8])
            + k[9]
    };
    let wx = poly(&c.mx);
    let wy = poly(&c.my);
    let rx = (wx / (c.f * COLOR_Q)) - (c.shift_m / c.shift_d);
    let ry = (wy / COLOR_Q) + c.cy;
    (rx, ry)
}
