//! The noisy Kinect preset: depth noise that grows with the square of the distance and
//! flying pixels at depth edges, the two things that make H4/H5 on real Kinect depth differ
//! from the smooth synthetic scenes.
//!
//! * **Noise**: Gaussian, `σ(z) = σ₁ · z²` (z in metres, `σ₁` ≈ 1.5 mm at 1 m; the model
//!   issue 13 gives for the Kinect v2).
//! * **Flying pixels**: a valid depth pixel whose true depth differs from a 4-neighbour's by
//!   more than [`FLYING_EDGE_JUMP`] (relative) sits on a depth edge; with probability
//!   [`FLYING_PIXEL_FRACTION`] it reports a mix of the two surfaces, `z + w·(z_n − z)` with
//!   `w` uniform in `[FLYING_MIX_MIN, 1 − FLYING_MIX_MIN]` (a time-of-flight pixel whose
//!   footprint covers both), plus the noise at that depth.
//!
//! Random choices come from a ChaCha8 generator seeded per row from [`KinectNoise::seed`]:
//! the same frame on any thread count.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::{SynthFrame, SynthSetup, kinect_preset, render, standard_normal};
use crate::Image;

/// Relative true-depth difference to a 4-neighbour that puts a pixel on a depth edge: 5 %,
/// far above the noise (0.6 % at 4 m) and below the preset's object/background gaps (≥ 20 %).
pub const FLYING_EDGE_JUMP: f64 = 0.05;
/// Fraction of depth-edge pixels that fly: about half, as on Kinect v2 frames without the
/// driver's edge filter.
pub const FLYING_PIXEL_FRACTION: f64 = 0.5;
/// Smallest share of the other surface in a flying pixel's depth (and of its own): 0.15, so a
/// flying pixel lies at least 15 % of the gap away from both surfaces (a mix closer than that
/// is indistinguishable from the surface's own noise and is not called flying).
pub const FLYING_MIX_MIN: f64 = 0.15;

/// The noise model of [`render_noisy`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KinectNoise {
    /// Depth noise σ at 1 m, metres (grows with z²).
    pub sigma_1m_m: f64,
    /// Fraction of depth-edge pixels that fly ([`FLYING_PIXEL_FRACTION`]).
    pub flying_fraction: f64,
    /// Seed of every random choice.
    pub seed: u64,
}

impl Default for KinectNoise {
    fn default() -> Self {
        Self {
            sigma_1m_m: crate::fusion::KINECT_NOISE_1M_M as f64,
            flying_fraction: FLYING_PIXEL_FRACTION,
            seed: 0x006e_6f69_7379,
        }
    }
}

/// A rendered frame with its flying pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct NoisyFrame {
    /// The frame; its `depth` carries the noise and the flying pixels, its truths are
    /// noise-free.
    pub frame: SynthFrame,
    /// Per depth pixel: reports a mix of two surfaces.
    pub flying: Image<bool>,
}

/// The noisy Kinect preset: the scene and rig of [`kinect_preset`] (objects at 1.0–1.7 m
/// before a wall at 2.2–4.5 m, dropouts, range limit) rendered without its constant noise,
/// and the [`KinectNoise`] that [`render_noisy`] adds.
pub fn kinect_noisy_preset() -> (SynthSetup, KinectNoise) {
    (kinect_preset(false), KinectNoise::default())
}

/// Renders `setup` and adds `noise` ([`apply_kinect_noise`]).
pub fn render_noisy(setup: &SynthSetup, noise: &KinectNoise) -> NoisyFrame {
    let mut frame = render(setup);
    let flying = apply_kinect_noise(&mut frame, noise);
    NoisyFrame { frame, flying }
}

/// Adds `noise` to the valid pixels of `frame.depth` (z or range: the value is scaled with
/// the new z) and returns the flying-pixel mask (see the module docs). Pixels without a
/// sample stay without one.
pub fn apply_kinect_noise(frame: &mut SynthFrame, noise: &KinectNoise) -> Image<bool> {
    let (w, h) = frame.depth.size();
    let truth = frame.true_depth_z.clone();
    let t = truth.data();
    let results: Vec<(f32, bool)> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let mut rng = ChaCha8Rng::seed_from_u64(
                noise.seed ^ (y as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            );
            let depth = &frame.depth;
            (0..w)
                .map(|x| {
                    let i = y * w + x;
                    let d = *depth.get(x, y);
                    let z = t[i] as f64;
                    if !(d.is_finite() && d > 0.0 && z > 0.0) {
                        return (d, false);
                    }
                    // The neighbour across the largest edge, if any.
                    let mut across: Option<f64> = None;
                    for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
                        let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                        if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                            continue;
                        }
                        let zn = t[ny as usize * w + nx as usize] as f64;
                        if zn > 0.0
                            && (zn - z).abs() > FLYING_EDGE_JUMP * z.min(zn)
                            && across.is_none_or(|a| (zn - z).abs() > (a - z).abs())
                        {
                            across = Some(zn);
                        }
                    }
                    // Draw every random number whether used or not: the stream per row then
                    // does not depend on which pixels are edges.
                    let fly_draw: f64 = rng.random();
                    let mix = FLYING_MIX_MIN + (1.0 - 2.0 * FLYING_MIX_MIN) * rng.random::<f64>();
                    let n = standard_normal(&mut rng);
                    let (z_new, flying) = match across {
                        Some(zn) if fly_draw < noise.flying_fraction => (z + mix * (zn - z), true),
                        _ => (z, false),
                    };
                    let z_new = z_new + noise.sigma_1m_m * z_new * z_new * n;
                    // d / z is 1 for z depth and the ray's length factor for range depth.
                    ((z_new * d as f64 / z) as f32, flying)
                })
                .collect::<Vec<_>>()
        })
        .collect();
    frame.depth = Image::from_fn(w, h, |x, y| results[y * w + x].0);
    Image::from_fn(w, h, |x, y| results[y * w + x].1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_grows_with_z_squared_and_flying_pixels_are_seeded() {
        let (setup, noise) = kinect_noisy_preset();
        let clean = render(&setup);
        let noisy = render_noisy(&setup, &noise);
        let (d0, d1, t) = (clean.depth.data(), noisy.frame.depth.data(), clean.true_depth_z.data());
        // Same pixels valid; residuals / z² are N(0, σ₁) off the flying pixels.
        let mut scaled = Vec::new();
        let mut flying = 0;
        for i in 0..d0.len() {
            assert_eq!(d0[i].is_finite(), d1[i].is_finite());
            if !d0[i].is_finite() {
                continue;
            }
            if noisy.flying.data()[i] {
                flying += 1;
                continue;
            }
            let z = t[i] as f64;
            scaled.push((d1[i] as f64 - d0[i] as f64) / (z * z));
        }
        let n = scaled.len() as f64;
        let mean = scaled.iter().sum::<f64>() / n;
        let sd = (scaled.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / n).sqrt();
        eprintln!(
            "noise σ₁ {:.4} mm (mean {:.4} mm), {flying} flying pixels",
            sd * 1e3,
            mean * 1e3
        );
        // 190k samples: the estimate of σ₁ is within 1 % of 1.5 mm at > 5 standard errors.
        assert!((sd - noise.sigma_1m_m).abs() < 0.01 * noise.sigma_1m_m, "{sd}");
        assert!(mean.abs() < 0.02 * noise.sigma_1m_m, "{mean}");
        // Edge pixels, recounted from the truth: every flying pixel is one, and about
        // FLYING_PIXEL_FRACTION of them fly (binomial, within 5 standard deviations).
        let (w, h) = clean.depth.size();
        let mut edges = 0;
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let edge = d0[i].is_finite()
                    && [(0i64, -1i64), (0, 1), (-1, 0), (1, 0)].iter().any(|&(dx, dy)| {
                        let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                        nx >= 0 && ny >= 0 && nx < w as i64 && ny < h as i64 && {
                            let (z, zn) = (t[i] as f64, t[ny as usize * w + nx as usize] as f64);
                            zn > 0.0 && (zn - z).abs() > FLYING_EDGE_JUMP * z.min(zn)
                        }
                    });
                edges += edge as usize;
                assert!(edge || !noisy.flying.data()[i], "pixel {x},{y} flies off an edge");
            }
        }
        let p = FLYING_PIXEL_FRACTION;
        let sd = (p * (1.0 - p) / edges as f64).sqrt();
        let frac = flying as f64 / edges as f64;
        eprintln!("{flying} of {edges} edge pixels fly");
        assert!(edges > 1000 && (frac - p).abs() < 5.0 * sd, "{frac}");
        // Seeded: the same frame again.
        let bits = |d: &[f32]| d.iter().map(|z| z.to_bits()).collect::<Vec<_>>();
        assert!(bits(render_noisy(&setup, &noise).frame.depth.data()) == bits(d1));
    }
}
