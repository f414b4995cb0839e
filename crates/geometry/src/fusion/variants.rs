//! The z-buffer variants the benchmarks and comparison tests measure `Registration` against
//! (only with the `bench-variants` feature): H7 from H2's sample list, and H1 + H2 + H7 fused
//! on one thread, with an occupancy image, and on all threads with an atomic minimum. Each is
//! bit-identical to [`super::Registration`] (the library's one CPU z-buffer) and to the
//! shader; `crates/geometry/tests/fusion_units.rs` checks it.

use std::sync::atomic::{AtomicU32, Ordering};

use rayon::prelude::*;

use super::ColorSample;
use super::pixel::{
    ColorProjection, ZBUFFER_EMPTY, distort_to_pixel, transform_point, zbuffer_index, zbuffer_min,
    zbuffer_pixel,
};
use crate::Image;

/// H7 from H2's samples: the smallest `z` per colour pixel, [`ZBUFFER_EMPTY`] elsewhere.
pub fn zbuffer_from_samples(samples: &[ColorSample], width: u32, height: u32) -> Image<f32> {
    let mut img = Image::filled(width as usize, height as usize, ZBUFFER_EMPTY);
    let data = img.data_mut();
    for s in samples {
        if let Some(i) = zbuffer_index(s.u, s.v, width, height) {
            zbuffer_min(&mut data[i], s.z);
        }
    }
    img
}

/// Pixels per block of the two-pass hot loop: 256 × 3 `f32` stay in L1.
const BLOCK: usize = 256;

/// Pass 1 of the hot loop over one block: `[u, v, z]` of every pixel, NaN `u` where
/// [`register_pixel`] gives `None`. Branch-free and the same arithmetic as
/// [`register_pixel`] (so bit-identical), which lets the compiler vectorise it.
#[inline]
fn project_block(
    p: &ColorProjection,
    depth: &[f32],
    rays: &[[f32; 3]],
    u: &mut [f32; BLOCK],
    v: &mut [f32; BLOCK],
    z: &mut [f32; BLOCK],
) {
    for i in 0..depth.len().min(BLOCK) {
        let value = depth[i];
        let ray = rays[i];
        let valid = super::pixel::is_sample(value);
        let zd = value * ray[2];
        let xc = transform_point(p, [ray[0] * zd, ray[1] * zd, zd]);
        let zc = xc[2];
        let [uu, vv] = distort_to_pixel(p, xc);
        let ok = valid && zc > 0.0;
        u[i] = if ok { uu } else { f32::NAN };
        v[i] = vv;
        z[i] = zc;
    }
}

/// H1 + H2 + H7 fused, single thread, no allocation: clears `zbuffer` (colour-sized,
/// row-major) to [`ZBUFFER_EMPTY`] and z-buffers every depth pixel into it.
/// `depth` and `rays` are depth-sized and row-major. Returns the number of samples that
/// landed on the colour image.
pub fn register_depth(
    depth: &[f32],
    rays: &[[f32; 3]],
    proj: &ColorProjection,
    zbuffer: &mut [f32],
) -> usize {
    zbuffer.fill(ZBUFFER_EMPTY);
    let mut landed = 0;
    let (mut bu, mut bv, mut bz) = ([0f32; BLOCK], [0f32; BLOCK], [0f32; BLOCK]);
    for (d, r) in depth.chunks(BLOCK).zip(rays.chunks(BLOCK)) {
        project_block(proj, d, r, &mut bu, &mut bv, &mut bz);
        for i in 0..d.len() {
            if let Some(j) = zbuffer_index(bu[i], bv[i], proj.width, proj.height) {
                zbuffer_min(&mut zbuffer[j], bz[i]);
                landed += 1;
            }
        }
    }
    landed
}

/// [`register_depth`] that also marks the landing pixels in an occupancy bit image
/// (`words_per_row` 64-bit words per colour row, bit `x % 64` of word `x / 64`), which it
/// clears first: exactly the non-empty pixels of the z-buffer, without scanning it again.
/// Feed it to [`super::HoleMasker::compute_from_occupancy`].
pub fn register_depth_marking(
    depth: &[f32],
    rays: &[[f32; 3]],
    proj: &ColorProjection,
    zbuffer: &mut [f32],
    occupancy: &mut [u64],
    words_per_row: usize,
) -> usize {
    zbuffer.fill(ZBUFFER_EMPTY);
    occupancy.fill(0);
    let w = proj.width as usize;
    let mut landed = 0;
    let (mut bu, mut bv, mut bz) = ([0f32; BLOCK], [0f32; BLOCK], [0f32; BLOCK]);
    for (d, r) in depth.chunks(BLOCK).zip(rays.chunks(BLOCK)) {
        project_block(proj, d, r, &mut bu, &mut bv, &mut bz);
        for i in 0..d.len() {
            if let Some((x, y)) = zbuffer_pixel(bu[i], bv[i], proj.width, proj.height) {
                zbuffer_min(&mut zbuffer[y * w + x], bz[i]);
                occupancy[y * words_per_row + x / 64] |= 1u64 << (x % 64);
                landed += 1;
            }
        }
    }
    landed
}

/// [`register_depth`] on all rayon threads: blocks of depth rows in parallel, an atomic
/// minimum on the `f32` bit patterns (exactly what the GPU does), so the result is
/// bit-identical to the single-thread version. `zbuffer` holds the bit patterns
/// (colour-sized, row-major); read it with [`atomic_zbuffer_to_image`].
pub fn register_depth_parallel(
    depth: &[f32],
    rays: &[[f32; 3]],
    depth_width: usize,
    proj: &ColorProjection,
    zbuffer: &[AtomicU32],
) -> usize {
    /// Depth rows per rayon task: 8 rows (~4k pixels) amortise the task overhead.
    const ROWS_PER_TASK: usize = 8;
    zbuffer
        .par_chunks(1 << 16)
        .for_each(|c| c.iter().for_each(|a| a.store(u32::MAX, Ordering::Relaxed)));
    let chunk = depth_width.max(1) * ROWS_PER_TASK;
    depth
        .par_chunks(chunk)
        .zip(rays.par_chunks(chunk))
        .map(|(d, r)| {
            let mut n = 0;
            let (mut bu, mut bv, mut bz) = ([0f32; BLOCK], [0f32; BLOCK], [0f32; BLOCK]);
            for (d, r) in d.chunks(BLOCK).zip(r.chunks(BLOCK)) {
                project_block(proj, d, r, &mut bu, &mut bv, &mut bz);
                for i in 0..d.len() {
                    if let Some(j) = zbuffer_index(bu[i], bv[i], proj.width, proj.height) {
                        zbuffer[j].fetch_min(bz[i].to_bits(), Ordering::Relaxed);
                        n += 1;
                    }
                }
            }
            n
        })
        .sum()
}

/// Copies an atomic z-buffer (bit patterns) into an image of `f32`.
pub fn atomic_zbuffer_to_image(zbuffer: &[AtomicU32], out: &mut [f32]) {
    out.par_chunks_mut(1 << 16).zip(zbuffer.par_chunks(1 << 16)).for_each(|(o, b)| {
        o.iter_mut().zip(b).for_each(|(o, a)| *o = f32::from_bits(a.load(Ordering::Relaxed)))
    });
}
