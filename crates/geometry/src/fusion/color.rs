//! H6: the colour image sampled onto the depth grid.

use rayon::prelude::*;

use super::pixel::{ColorProjection, register_pixel, zbuffer_index};
use super::resample::NearestFill;
use crate::Image;

/// The depth the colour camera sees at a colour pixel (row-major index), for H6's occlusion
/// test: a dense colour-frame depth image, or H3's nearest fill computed only where it is read
/// ([`NearestFill`]).
pub trait SeenDepth: Sync {
    /// The depth at pixel `j` (NaN or <= 0: nothing seen there).
    fn seen(&self, j: usize) -> f32;
}

impl SeenDepth for Image<f32> {
    #[inline]
    fn seen(&self, j: usize) -> f32 {
        self.data()[j]
    }
}

impl SeenDepth for NearestFill<'_> {
    #[inline]
    fn seen(&self, j: usize) -> f32 {
        self.at(j)
    }
}

/// Bilinear sample of `color` at sub-pixel `(u, v)` (pixel centres at integers), `None` unless
/// `0 <= u <= width - 1` and `0 <= v <= height - 1`. Per channel, in `f32`:
/// `top = c00 + (c10 - c00) * fx`, `bottom = c01 + (c11 - c01) * fx`,
/// `value = top + (bottom - top) * fy`, rounded as `floor(value + 0.5)`.
#[inline]
pub fn bilinear_rgb(color: &[[u8; 3]], width: u32, height: u32, u: f32, v: f32) -> Option<[u8; 3]> {
    let (wf, hf) = ((width - 1) as f32, (height - 1) as f32);
    if !(u >= 0.0 && v >= 0.0 && u <= wf && v <= hf) {
        return None;
    }
    let x0 = u.floor();
    let y0 = v.floor();
    let fx = u - x0;
    let fy = v - y0;
    let (x0, y0) = (x0 as usize, y0 as usize);
    let x1 = (x0 + 1).min(width as usize - 1);
    let y1 = (y0 + 1).min(height as usize - 1);
    let w = width as usize;
    let (c00, c10, c01, c11) =
        (color[y0 * w + x0], color[y0 * w + x1], color[y1 * w + x0], color[y1 * w + x1]);
    let mut out = [0u8; 3];
    for k in 0..3 {
        let top = c00[k] as f32 + (c10[k] as f32 - c00[k] as f32) * fx;
        let bottom = c01[k] as f32 + (c11[k] as f32 - c01[k] as f32) * fx;
        let value = top + (bottom - top) * fy;
        out[k] = (value + 0.5).floor() as u8;
    }
    Some(out)
}

/// H6: for every depth pixel with a sample, the colour seen where its point lands in the
/// colour image (bilinear), and whether that colour is trustworthy.
///
/// A pixel is valid when its point projects inside the colour image and, if
/// `color_depth` (a dense colour-frame depth such as H3's nearest fill) is given, the point
/// is not behind the surface the colour camera sees there: `z <= z_seen · (1 + occlusion_tolerance)`
/// at the pixel `zbuffer_index(u, v)`. Invalid pixels are black.
pub fn color_on_depth<S: SeenDepth>(
    depth: &Image<f32>,
    rays: &[[f32; 3]],
    proj: &ColorProjection,
    color: &Image<[u8; 3]>,
    color_depth: Option<&S>,
    occlusion_tolerance: f32,
) -> (Image<[u8; 3]>, Image<bool>) {
    let (w, h) = depth.size();
    let mut out = Image::filled(w, h, [0u8; 3]);
    let mut valid = Image::filled(w, h, false);
    let cdata = color.data();
    out.data_mut().par_chunks_mut(w).zip(valid.data_mut().par_chunks_mut(w)).enumerate().for_each(
        |(y, (orow, vrow))| {
            for x in 0..w {
                let i = y * w + x;
                let Some([u, v, z]) = register_pixel(proj, rays[i], depth.data()[i]) else {
                    continue;
                };
                let Some(c) = bilinear_rgb(cdata, proj.width, proj.height, u, v) else { continue };
                if let Some(cd) = color_depth
                    && let Some(j) = zbuffer_index(u, v, proj.width, proj.height)
                {
                    let seen = cd.seen(j);
                    if seen > 0.0 && z > seen * (1.0 + occlusion_tolerance) {
                        continue;
                    }
                }
                orow[x] = c;
                vrow[x] = true;
            }
        },
    );
    (out, valid)
}
