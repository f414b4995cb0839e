//! [`FusionContext::run`]: the whole H1–H8 pipeline ([`geometry::fusion::run_on`]) with the
//! per-pixel stages on the GPU ([`PerPixel`] for [`FusionContext`]); [`PixelEngine`], an
//! opened [`Engine`] (the CPU or a GPU context as one [`PerPixel`], [`Engine::open`]), which
//! single frames, several Kinects and sequences run on; and [`fuse`] and [`fuse_multi`]
//! (several Kinects), the [`Engine`] selector in one call.

use std::time::Instant;

use geometry::fusion::multi::{MultiFusion, SensorImages, fuse_multi_on};
use geometry::fusion::{
    ColorSample, CpuPixels, DepthView, FusionOptions, FusionOutput, PerPixel, PerPixelOutput,
    PixelFrame, PixelParams, PlaneFit, Request, StageTimings, StreamFrame, StreamPlan,
    StreamResult, run_on, zbuffer_index,
};
use geometry::{CameraModel, DepthKind, Image, MultiRig, Rig, RigCamera};

use crate::{Engine, FramePlan, FusionContext, GpuDecoder, GpuError, GpuFrame};

impl PerPixel for FusionContext {
    type Error = GpuError;

    /// One GPU submission: upload, H1, H2, H7, H3 nearest, H8 mask, H6, read-back. Its wall
    /// time is reported as `h1_ms` (`h2_ms`, `h7_ms`, `h3_nearest_ms` and `h6_ms` stay zero).
    fn per_pixel(
        &mut self,
        rig: &Rig,
        depth: &Image<f32>,
        kind: DepthKind,
        color: &Image<[u8; 3]>,
        params: &PixelParams,
        timings: &mut StageTimings,
    ) -> Result<PerPixelOutput, GpuError> {
        let (cw, ch) = (rig.color.width, rig.color.height);
        let stages = *params;
        let t = Instant::now();
        let frame = self.frame(
            rig,
            depth,
            kind,
            Some(color),
            FramePlan { stages: Some(stages), read_intermediates: true },
        )?;
        timings.h1_ms += t.elapsed().as_secs_f64() * 1e3;
        let missing = |what: &str| GpuError::Device {
            adapter: self.adapter_name().to_string(),
            during: "reading back the frame",
            message: format!("{what} was not read back"),
        };
        let gpu_points = frame.points.ok_or_else(|| missing("H1 points"))?;
        let gpu_samples = frame.samples.ok_or_else(|| missing("H2 samples"))?;
        let nearest = frame.nearest.ok_or_else(|| missing("H3 nearest"))?;
        let hole_mask = frame.holes.ok_or_else(|| missing("H8 mask"))?;
        let (color_on_depth, color_on_depth_valid) =
            frame.color_on_depth.ok_or_else(|| missing("H6 colour"))?;

        // H1 cloud and H2 sample list in the CPU's order (row-major pixels, then points).
        let mut points = Vec::new();
        let mut cloud_pixels = Vec::new();
        let mut samples = Vec::new();
        for (i, (p, s)) in gpu_points.iter().zip(&gpu_samples).enumerate() {
            if p[3] != 1.0 {
                continue;
            }
            let point = points.len() as u32;
            points.push([p[0], p[1], p[2]]);
            cloud_pixels.push(i as u32);
            if s[3] == 1.0 && zbuffer_index(s[0], s[1], cw as u32, ch as u32).is_some() {
                samples.push(ColorSample { u: s[0], v: s[1], z: s[2], point });
            }
        }
        Ok(PerPixelOutput {
            points,
            cloud_pixels,
            samples,
            zbuffer: frame.zbuffer,
            nearest,
            hole_mask,
            color_on_depth,
            color_on_depth_valid,
        })
    }

    fn fill_holes(
        &mut self,
        camera: &CameraModel,
        depth: &Image<f32>,
        mask: &Image<bool>,
        plane: &PlaneFit,
    ) -> Result<(Image<f32>, usize), GpuError> {
        let normal = plane.normal.map(|c| c as f32);
        self.fill_holes_with_plane(camera, depth, mask, normal, plane.offset as f32)
    }

    /// [`FusionContext::zbuffer_views`]: one atomic-min z-buffer across the views.
    fn zbuffer_views(
        &mut self,
        camera: &CameraModel,
        views: &[DepthView<'_>],
        kind: DepthKind,
    ) -> Result<Image<f32>, GpuError> {
        FusionContext::zbuffer_views(self, camera, views, kind)
    }

    /// [`FusionContext::stream`]: two frames in flight, only what `plan` asks read back.
    fn per_pixel_stream(
        &mut self,
        rig: &Rig,
        kind: DepthKind,
        frames: &[StreamFrame<'_>],
        params: &PixelParams,
        plan: StreamPlan,
        sink: &mut dyn FnMut(usize, StreamResult<'_>),
    ) -> Result<(), GpuError> {
        let gpu_plan = FramePlan {
            stages: (plan.holes || plan.color_on_depth).then_some(*params),
            read_intermediates: false,
        };
        let inputs = frames.iter().map(|f| {
            (crate::context::DepthInput::Metres(f.depth), f.color.filter(|_| plan.color_on_depth))
        });
        let range = params.depth_range;
        self.stream_inputs(rig, kind, inputs, gpu_plan, range, |i, r| lend(i, &r, plan, sink))?;
        Ok(())
    }
}

/// One raw frame of [`FusionContext::per_pixel_stream_raw`]: the Kinect v2's raw depth data
/// and, for H6, the frame's colour image.
pub type RawStreamFrame<'a> = (&'a [u8], Option<&'a Image<[u8; 3]>>);

/// A GPU frame's results lent to a stream's sink, as `plan` asked for them.
fn lend(i: usize, r: &GpuFrame, plan: StreamPlan, sink: &mut dyn FnMut(usize, StreamResult<'_>)) {
    sink(
        i,
        StreamResult {
            zbuffer: r.zbuffer.data(),
            hole_mask: r.holes.as_ref().filter(|_| plan.holes).map(|m| m.data()),
            color_on_depth: r.color_on_depth.as_ref().map(|(c, v)| (c, v)),
        },
    );
}

/// An opened [`Engine`]: the per-pixel stages on the CPU ([`CpuPixels`]) or on a GPU
/// context, as one [`PerPixel`] whose errors are [`GpuError`]s (a CPU error is
/// [`GpuError::Input`]). What `kfuse fuse` (one frame, several Kinects) and `kfuse fuse
/// --recording` run on.
#[derive(Debug)]
pub enum PixelEngine {
    /// The CPU.
    Cpu(CpuPixels),
    /// A GPU context.
    Gpu(Box<FusionContext>),
}

impl PixelEngine {
    /// The GPU context, `None` on the CPU.
    pub fn gpu(&mut self) -> Option<&mut FusionContext> {
        match self {
            PixelEngine::Gpu(ctx) => Some(ctx),
            PixelEngine::Cpu(_) => None,
        }
    }
}

impl Engine {
    /// Opens the engine: [`Engine::Cpu`] the CPU; [`Engine::Gpu`] a new [`FusionContext`]
    /// (no adapter: [`GpuError::NoAdapter`]); [`Engine::Auto`] a context when an adapter
    /// exists, else the CPU with the reason in [`EngineUsed::CpuFallback`].
    pub fn open(self) -> Result<(PixelEngine, EngineUsed), GpuError> {
        if !self.wants_gpu() {
            return Ok((PixelEngine::Cpu(CpuPixels::new()), EngineUsed::Cpu));
        }
        match FusionContext::new() {
            Ok(ctx) => {
                let used = EngineUsed::Gpu {
                    adapter: ctx.adapter_name().to_string(),
                    software: ctx.is_software(),
                };
                Ok((PixelEngine::Gpu(Box::new(ctx)), used))
            }
            Err(e @ GpuError::NoAdapter { .. }) if self.falls_back_to_cpu() => Ok((
                PixelEngine::Cpu(CpuPixels::new()),
                EngineUsed::CpuFallback { reason: e.to_string() },
            )),
            Err(e) => Err(e),
        }
    }
}

impl PerPixel for PixelEngine {
    type Error = GpuError;

    fn per_pixel(
        &mut self,
        rig: &Rig,
        depth: &Image<f32>,
        kind: DepthKind,
        color: &Image<[u8; 3]>,
        params: &PixelParams,
        timings: &mut StageTimings,
    ) -> Result<PerPixelOutput, GpuError> {
        match self {
            PixelEngine::Cpu(c) => Ok(c.per_pixel(rig, depth, kind, color, params, timings)?),
            PixelEngine::Gpu(g) => g.per_pixel(rig, depth, kind, color, params, timings),
        }
    }

    fn fill_holes(
        &mut self,
        camera: &CameraModel,
        depth: &Image<f32>,
        mask: &Image<bool>,
        plane: &PlaneFit,
    ) -> Result<(Image<f32>, usize), GpuError> {
        match self {
            PixelEngine::Cpu(c) => Ok(c.fill_holes(camera, depth, mask, plane)?),
            PixelEngine::Gpu(g) => g.fill_holes(camera, depth, mask, plane),
        }
    }

    fn per_pixel_batch(
        &mut self,
        frames: &[PixelFrame<'_>],
        kind: DepthKind,
        timings: &mut StageTimings,
    ) -> Result<Vec<PerPixelOutput>, GpuError> {
        match self {
            PixelEngine::Cpu(c) => Ok(c.per_pixel_batch(frames, kind, timings)?),
            PixelEngine::Gpu(g) => g.per_pixel_batch(frames, kind, timings),
        }
    }

    fn zbuffer_views(
        &mut self,
        camera: &CameraModel,
        views: &[DepthView<'_>],
        kind: DepthKind,
    ) -> Result<Image<f32>, GpuError> {
        match self {
            PixelEngine::Cpu(c) => Ok(c.zbuffer_views(camera, views, kind)?),
            PixelEngine::Gpu(g) => PerPixel::zbuffer_views(g.as_mut(), camera, views, kind),
        }
    }

    fn per_pixel_stream(
        &mut self,
        rig: &Rig,
        kind: DepthKind,
        frames: &[StreamFrame<'_>],
        params: &PixelParams,
        plan: StreamPlan,
        sink: &mut dyn FnMut(usize, StreamResult<'_>),
    ) -> Result<(), GpuError> {
        match self {
            PixelEngine::Cpu(c) => Ok(c.per_pixel_stream(rig, kind, frames, params, plan, sink)?),
            PixelEngine::Gpu(g) => g.per_pixel_stream(rig, kind, frames, params, plan, sink),
        }
    }

    fn per_pixel_into(
        &mut self,
        rig: &Rig,
        kind: DepthKind,
        depth: &Image<f32>,
        params: &PixelParams,
        zbuffer: &mut [f32],
        hole_mask: Option<&mut [bool]>,
    ) -> Result<(), GpuError> {
        match self {
            PixelEngine::Cpu(c) => {
                Ok(c.per_pixel_into(rig, kind, depth, params, zbuffer, hole_mask)?)
            }
            PixelEngine::Gpu(g) => g.per_pixel_into(rig, kind, depth, params, zbuffer, hole_mask),
        }
    }
}

impl FusionContext {
    /// Runs H1–H8 on one frame, like [`geometry::fusion::run`] and with the same inputs,
    /// errors and output: [`geometry::fusion::run_on`] with the per-pixel stages on this GPU.
    ///
    /// On the GPU (one submission): H1 back-projection, H2 projection, H7 z-buffer, H3
    /// nearest fill, H8 hole mask, H6 colour on depth; then, after the CPU RANSAC plane fit
    /// (kept on the CPU: a few hundred sequential hypotheses over ≤ 20 000 points), the H8
    /// plane fill. On the CPU: H3 Delaunay-linear (spade), H4 mesh and H5 face removal, which
    /// are not per-pixel kernels. Every GPU stage is bit-identical to its CPU twin, so the
    /// output equals the CPU pipeline's except for `summary.timings_ms`: there the GPU
    /// submission's wall time (upload + H1, H2, H7, H3 nearest, H8 mask, H6 + read-back) is
    /// reported as `h1_ms`, with `h2_ms`, `h7_ms`, `h3_nearest_ms` and `h6_ms` zero, and
    /// `h8_ms` covers the CPU plane fit plus the GPU fill. `depth` is prepared for `rig`
    /// here ([`Request::prepare_depth`]).
    pub fn run(
        &mut self,
        rig: &Rig,
        depth: &Image<f32>,
        kind: DepthKind,
        color: &Image<[u8; 3]>,
        options: &FusionOptions,
    ) -> Result<FusionOutput, GpuError> {
        let request = Request::new(rig, kind, *options)?;
        let depth = request.prepared(depth)?;
        run_on(self, &request, &depth, color)
    }

    /// [`PerPixel::per_pixel_stream`] on raw Kinect v2 depth frames that `decoder` decodes
    /// on this GPU in front of the same stages ([`FusionContext::stream_raw`]: the depth
    /// never leaves the GPU), each with its colour image for H6. `params` as
    /// [`PixelParams::new`] gives them, with the z-buffer on.
    ///
    /// Errors: those of [`FusionContext::stream_raw`].
    pub fn per_pixel_stream_raw(
        &mut self,
        decoder: &GpuDecoder,
        rig: &Rig,
        frames: &[RawStreamFrame<'_>],
        params: &PixelParams,
        plan: StreamPlan,
        sink: &mut dyn FnMut(usize, StreamResult<'_>),
    ) -> Result<(), GpuError> {
        let gpu_plan = FramePlan {
            stages: (plan.holes || plan.color_on_depth).then_some(*params),
            read_intermediates: false,
        };
        let inputs = frames.iter().map(|&(raw, c)| (raw, c.filter(|_| plan.color_on_depth)));
        let range = params.depth_range;
        self.stream_raw_in(decoder, rig, inputs, gpu_plan, range, |i, r| lend(i, &r, plan, sink))?;
        Ok(())
    }
}

/// Which engine [`fuse`] ran the frame on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum EngineUsed {
    /// The CPU pipeline, as asked ([`Engine::Cpu`]).
    Cpu,
    /// The GPU adapter of this name.
    Gpu {
        /// Adapter name, e.g. `llvmpipe (LLVM 15.0.6, 256 bits)`.
        adapter: String,
        /// True for a software adapter (lavapipe): correct but slower than the CPU path.
        software: bool,
    },
    /// The CPU pipeline, because [`Engine::Auto`] found no adapter; `reason` is the
    /// [`GpuError::NoAdapter`] message, for the CLI's warning.
    CpuFallback {
        /// Why the GPU was not used.
        reason: String,
    },
}

/// The CLI's `--engine` in one call: [`run_on`] of `request` on the engine [`Engine::open`]
/// gives (the CPU for [`Engine::Cpu`], else a new [`FusionContext`], or, under
/// [`Engine::Auto`] when there is no adapter, the CPU). `depth` is prepared
/// ([`Request::prepare_depth`]). Under [`Engine::Gpu`] no adapter is [`GpuError::NoAdapter`].
/// For many frames keep the opened engine instead.
pub fn fuse_request(
    engine: Engine,
    request: &Request,
    depth: &Image<f32>,
    color: &Image<[u8; 3]>,
) -> Result<(FusionOutput, EngineUsed), GpuError> {
    let (mut pixels, used) = engine.open()?;
    Ok((run_on(&mut pixels, request, depth, color)?, used))
}

/// [`fuse_request`] of the [`Request`] of `rig`, `kind` and `options`, on `depth` as it
/// prepares it.
pub fn fuse(
    engine: Engine,
    rig: &Rig,
    depth: &Image<f32>,
    kind: DepthKind,
    color: &Image<[u8; 3]>,
    options: &FusionOptions,
) -> Result<(FusionOutput, EngineUsed), GpuError> {
    let request = Request::new(rig, kind, *options)?;
    let depth = request.prepared(depth)?;
    fuse_request(engine, &request, &depth, color)
}

/// [`fuse`] for several Kinects: [`geometry::fusion::multi::fuse_multi_on`] and the z-buffer
/// of every sensor into `view` (a camera of `rig`, [`MultiFusion::zbuffer_into_on`]) on the
/// engine `engine` selects, a new [`FusionContext`] for the GPU, the CPU under
/// [`Engine::Auto`] without an adapter. The same fusion and z-buffer on every engine.
pub fn fuse_multi(
    engine: Engine,
    rig: &MultiRig,
    inputs: &[SensorImages],
    kind: DepthKind,
    options: &FusionOptions,
    view: &RigCamera,
) -> Result<(MultiFusion, Image<f32>, EngineUsed), GpuError> {
    let (mut pixels, used) = engine.open()?;
    let fused = fuse_multi_on(&mut pixels, rig, inputs, kind, options)?;
    let zbuffer = fused.zbuffer_into_on(&mut pixels, view)?;
    Ok((fused, zbuffer, used))
}
