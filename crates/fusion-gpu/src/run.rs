//! [`FusionContext::run`]: the whole H1–H8 pipeline with the per-pixel stages on the GPU,
//! returning the CPU pipeline's [`FusionOutput`].

use std::time::Instant;

use geometry::fusion::{
    ColorSample, FusionOptions, FusionOutput, PixelStages, StageTimings, check_inputs,
    coverage_radius_px, finish, fit_plane_ransac, hole_grow_px, linear_resample, sample_spacing_px,
    zbuffer_index,
};
use geometry::{DepthKind, Image, PointCloud, Rig};

use crate::{FramePlan, FusionContext, GpuError, StageOptions};

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

impl FusionContext {
    /// Runs H1–H8 on one frame, like [`geometry::fusion::run`] and with the same inputs,
    /// errors and output.
    ///
    /// On the GPU (one submission): H1 back-projection, H2 projection, H7 z-buffer, H3
    /// nearest fill, H8 hole mask, H6 colour on depth; then, after the CPU RANSAC plane fit
    /// (kept on the CPU: a few hundred sequential hypotheses over ≤ 20 000 points), the H8
    /// plane fill. On the CPU: H3 Delaunay-linear (spade), H4 mesh and H5 face removal, which
    /// are not per-pixel kernels. Every GPU stage is bit-identical to its CPU twin, so the
    /// output equals the CPU pipeline's except for `summary.timings_ms`: there the GPU
    /// submission's wall time (upload + H1, H2, H7, H3 nearest, H8 mask, H6 + read-back) is
    /// reported as `h1_ms`, with `h2_ms`, `h7_ms`, `h3_nearest_ms` and `h6_ms` zero, and
    /// `h8_ms` covers the CPU plane fit plus the GPU fill.
    pub fn run(
        &mut self,
        rig: &Rig,
        depth: &Image<f32>,
        kind: DepthKind,
        color: &Image<[u8; 3]>,
        options: &FusionOptions,
    ) -> Result<FusionOutput, GpuError> {
        let valid_depth_pixels = check_inputs(rig, depth, color, options)?;
        let (cw, ch) = (rig.color.width, rig.color.height);
        let spacing = sample_spacing_px(rig);
        let radius = coverage_radius_px(rig, options);
        let stages = StageOptions {
            nearest_radius_px: radius,
            depth_jump: options.depth_jump,
            hole_radius_px: radius,
            hole_grow_px: hole_grow_px(rig, options),
            occlusion_tolerance: Some(options.color_occlusion_tolerance),
        };
        let mut timings = StageTimings::default();

        let t = Instant::now();
        let frame = self.frame(
            rig,
            depth,
            kind,
            Some(color),
            FramePlan { stages: Some(stages), read_intermediates: true },
        )?;
        timings.h1_ms = ms(t);
        let missing = |what: &str| GpuError::Device {
            adapter: self.adapter_name().to_string(),
            during: "reading back the frame",
            message: format!("{what} was not read back"),
        };
        let points = frame.points.ok_or_else(|| missing("H1 points"))?;
        let gpu_samples = frame.samples.ok_or_else(|| missing("H2 samples"))?;
        let nearest = frame.nearest.ok_or_else(|| missing("H3 nearest"))?;
        let mask = frame.holes.ok_or_else(|| missing("H8 mask"))?;
        let (color_img, color_valid) = frame.color_on_depth.ok_or_else(|| missing("H6 colour"))?;
        let zbuffer = frame.zbuffer;

        // H1 cloud and H2 sample list in the CPU's order (row-major pixels, then points).
        let mut cloud = PointCloud::default();
        let mut cloud_pixels = Vec::new();
        let mut samples = Vec::new();
        for (i, (p, s)) in points.iter().zip(&gpu_samples).enumerate() {
            if p[3] != 1.0 {
                continue;
            }
            let point = cloud.points.len() as u32;
            cloud.points.push([p[0], p[1], p[2]]);
            cloud_pixels.push(i as u32);
            if s[3] == 1.0 && zbuffer_index(s[0], s[1], cw as u32, ch as u32).is_some() {
                samples.push(ColorSample { u: s[0], v: s[1], z: s[2], point });
            }
        }
        cloud.colors = cloud_pixels
            .iter()
            .map(|&i| {
                if color_valid.data()[i as usize] {
                    color_img.data()[i as usize]
                } else {
                    [0, 0, 0]
                }
            })
            .collect();

        let t = Instant::now();
        let (linear, linear_stats) = if options.linear {
            let (img, stats) = linear_resample(
                &samples,
                &zbuffer,
                options.linear_max_edge_factor * spacing,
                options.depth_jump,
            )?;
            (Some(img), Some(stats))
        } else {
            (None, None)
        };
        timings.h3_linear_ms = ms(t);

        let t = Instant::now();
        let plane = if options.fill_holes {
            fit_plane_ransac(&nearest, &rig.color, &options.plane)
        } else {
            None
        };
        let (filled, filled_pixels) = match &plane {
            Some(p) => {
                let normal = p.normal.map(|c| c as f32);
                self.fill_holes_with_plane(&rig.color, &nearest, &mask, normal, p.offset as f32)?
            }
            None => (nearest.clone(), 0),
        };
        timings.h8_ms = ms(t);

        let stages = PixelStages {
            cloud,
            cloud_pixels,
            samples,
            zbuffer,
            nearest,
            linear,
            linear_stats,
            hole_mask: mask,
            filled,
            filled_pixels,
            plane,
            color_on_depth: color_img,
            color_on_depth_valid: color_valid,
        };
        Ok(finish(rig, kind, color, options, valid_depth_pixels, stages, timings))
    }
}

/// Which engine [`fuse`] used.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Engine {
    /// The GPU adapter of this name.
    Gpu {
        /// Adapter name, e.g. `llvmpipe (LLVM 15.0.6, 256 bits)`.
        adapter: String,
        /// True for a software adapter (lavapipe): correct but slower than the CPU path.
        software: bool,
    },
    /// The CPU pipeline, because [`GpuPolicy::Auto`] found no adapter; `reason` is the
    /// [`GpuError::NoAdapter`] message, for the CLI's warning.
    CpuFallback {
        /// Why the GPU was not used.
        reason: String,
    },
}

/// The CLI's `--gpu` / `--gpu auto` in one call: runs the frame on a new [`FusionContext`],
/// or, under [`GpuPolicy::Auto`] when there is no adapter, on the CPU
/// ([`geometry::fusion::run`]). Under [`GpuPolicy::Required`] no adapter is
/// [`GpuError::NoAdapter`]. For many frames keep a [`FusionContext`] instead.
pub fn fuse(
    policy: crate::GpuPolicy,
    rig: &Rig,
    depth: &Image<f32>,
    kind: DepthKind,
    color: &Image<[u8; 3]>,
    options: &FusionOptions,
) -> Result<(FusionOutput, Engine), GpuError> {
    match FusionContext::new(policy) {
        Ok(mut ctx) => {
            let engine = Engine::Gpu {
                adapter: ctx.adapter_name().to_string(),
                software: ctx.is_software(),
            };
            Ok((ctx.run(rig, depth, kind, color, options)?, engine))
        }
        Err(e @ GpuError::NoAdapter { .. }) if policy.falls_back_to_cpu() => {
            let out = geometry::fusion::run(rig, depth, kind, color, options)?;
            Ok((out, Engine::CpuFallback { reason: e.to_string() }))
        }
        Err(e) => Err(e),
    }
}
