//! The one H1–H8 pipeline: [`run_on`] runs the per-pixel stages on an engine ([`PerPixel`]:
//! [`CpuPixels`] here, `fusion_gpu::FusionContext` on the GPU) and everything else once.
//!
//! | step | where |
//! | --- | --- |
//! | input checks, limits ([`super::check_inputs`]) | here |
//! | H1, H2, H7, H3 nearest, H8 mask, H6 | the engine ([`PerPixel::per_pixel`]) |
//! | H3 Delaunay-linear, H8 plane fit | here (CPU) |
//! | H8 plane fill | the engine ([`PerPixel::fill_holes`]) |
//! | cloud colours, H4 mesh, H5 face removal, summary | here |
//!
//! A sequence (`kfuse fuse --recording/--frames`) runs the same per-pixel stages on the same
//! engine through [`stream_on`]: per frame H1, H2, H7 and, as its [`StreamPlan`] asks, the H8
//! mask and H3 nearest + H6 ([`PerPixel::per_pixel_stream`]), with the engine's state kept
//! between frames.
//!
//! The switches of the viewer are options of the same run: [`FusionOptions::zbuffer`] off
//! (first write wins, H6 without its occlusion test; a teaching switch that always runs on
//! [`CpuPixels`]), [`FusionOptions::linear`] and [`MeshSource`] (which depth is meshed, with
//! or without the plane fill), [`FusionOptions::edge_rule`] and
//! [`FusionOptions::stretch_ratio`] (H5).

use std::time::Instant;

use rayon::prelude::*;

use super::{
    ColorProjection, ColorSample, FusionOptions, FusionOutput, FusionSummary, MeshSource,
    NearestFill, PlaneFit, Registration, SeenDepth, StageTimings, StretchTest, backproject_cloud,
    check_inputs, color_on_depth, coverage_radius_px, depth_ray_table, fill_holes_with_plane,
    first_write_wins, fit_plane_ransac, hole_grow_px, hole_mask, linear_resample, mesh_from_depth,
    mesh_on_depth_grid, nearest_fill, project_cloud, remove_edge_faces, sample_spacing_px,
    zbuffer_points,
};
use super::{DepthRange, Request};
use crate::fusion::ZBUFFER_EMPTY;
use crate::{CameraModel, DepthKind, GeometryError, Image, PointCloud, Rig, RigidTransform};

/// The parameters of the per-pixel stages, in colour pixels (from [`FusionOptions`] and the
/// rig; see [`PixelParams::new`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelParams {
    /// H3 nearest and H8 coverage radius ([`super::checked_coverage_radius_px`]).
    pub radius_px: f32,
    /// H8 growth radius ([`super::hole_grow_px`]).
    pub grow_px: f32,
    /// H3 nearest's surface separation ([`FusionOptions::depth_jump`]).
    pub depth_jump: f32,
    /// H6 occlusion tolerance; `None` without the test (z-buffer off).
    pub occlusion_tolerance: Option<f32>,
    /// H7 z-buffer (`false`: first write wins, [`first_write_wins`]).
    pub zbuffer: bool,
    /// H1's sample rule: depth values outside this range are not samples
    /// ([`FusionOptions::depth_range`]; [`DepthRange::ALL`] keeps every sample).
    pub depth_range: DepthRange,
}

impl PixelParams {
    /// Checks the two radii against [`super::MAX_COVERAGE_RADIUS_PX`] before an engine builds
    /// their lookup tables (the disc table grows with the square of the radius).
    ///
    /// Error: [`GeometryError::InvalidInput`] naming the radius and the limit.
    pub fn check(&self) -> Result<(), GeometryError> {
        let limit = super::MAX_COVERAGE_RADIUS_PX;
        for (what, r) in [
            ("H3 nearest / H8 coverage radius", self.radius_px),
            ("H8 growth radius", self.grow_px),
        ] {
            if !(0.0..=limit).contains(&r) {
                return Err(GeometryError::InvalidInput(format!(
                    "{what} {r} px is outside 0..={limit} px"
                )));
            }
        }
        Ok(())
    }

    /// The parameters `options` give for `rig` (radii not checked: [`run_on`] checks them
    /// first).
    pub fn new(rig: &Rig, options: &FusionOptions) -> Self {
        let grow_px = hole_grow_px(rig, options);
        #[cfg(feature = "fault-injection")]
        let grow_px = if fault::hole_growth_broken() { 0.0 } else { grow_px };
        Self {
            radius_px: coverage_radius_px(rig, options),
            grow_px,
            depth_jump: options.depth_jump,
            occlusion_tolerance: options.zbuffer.then_some(options.color_occlusion_tolerance),
            zbuffer: options.zbuffer,
            depth_range: options.depth_range,
        }
    }
}

/// Faults in the pipeline's wiring for tests (feature `fault-injection`): while set,
/// [`PixelParams::new`] gives H8 no growth radius, so every path that takes its parameters from
/// it (a single frame, several Kinects, a sequence; on every engine) computes another hole
/// mask; [`super::Request::prepare_depth`] makes every sample 2 % farther, so every door that
/// prepares its depth through the request fuses another depth. Off unless a test sets them;
/// process-wide switches, so a test that sets one runs alone in its test binary.
#[cfg(feature = "fault-injection")]
pub mod fault {
    use std::sync::atomic::{AtomicBool, Ordering};

    static HOLE_GROWTH_BROKEN: AtomicBool = AtomicBool::new(false);
    static DEPTH_PREPARATION_BROKEN: AtomicBool = AtomicBool::new(false);

    /// Breaks (`true`) or mends (`false`) the depth preparation of
    /// [`super::super::Request::prepare_depth`].
    pub fn break_depth_preparation(broken: bool) {
        DEPTH_PREPARATION_BROKEN.store(broken, Ordering::SeqCst);
    }

    pub(in crate::fusion) fn depth_preparation_broken() -> bool {
        DEPTH_PREPARATION_BROKEN.load(Ordering::SeqCst)
    }

    /// Breaks (`true`) or mends (`false`) H8's growth radius in [`super::PixelParams::new`].
    pub fn break_hole_growth(broken: bool) {
        HOLE_GROWTH_BROKEN.store(broken, Ordering::SeqCst);
    }

    pub(super) fn hole_growth_broken() -> bool {
        HOLE_GROWTH_BROKEN.load(Ordering::SeqCst)
    }
}

/// What the per-pixel stages produce.
#[derive(Debug, Clone)]
pub struct PerPixelOutput {
    /// H1 points (depth camera frame), row-major pixel order.
    pub points: Vec<[f32; 3]>,
    /// Depth pixel index of every point.
    pub cloud_pixels: Vec<u32>,
    /// H2 samples inside the colour image (`point` indexes `points`).
    pub samples: Vec<ColorSample>,
    /// H7 z-buffer.
    pub zbuffer: Image<f32>,
    /// H3 nearest fill.
    pub nearest: Image<f32>,
    /// H8 hole mask.
    pub hole_mask: Image<bool>,
    /// H6 colour on the depth grid.
    pub color_on_depth: Image<[u8; 3]>,
    /// Where H6 colour is trustworthy.
    pub color_on_depth_valid: Image<bool>,
}

/// One frame of [`PerPixel::per_pixel_batch`]: each frame of a batch has its own rig (the
/// sensors of a multi-Kinect rig) and parameters.
#[derive(Debug, Clone, Copy)]
pub struct PixelFrame<'a> {
    /// The frame's depth + colour pair.
    pub rig: &'a Rig,
    /// Depth image of `rig.depth`'s size, metres (checked by the caller).
    pub depth: &'a Image<f32>,
    /// Colour image of `rig.color`'s size.
    pub color: &'a Image<[u8; 3]>,
    /// The per-pixel stages' parameters for `rig` ([`PixelParams::new`]).
    pub params: PixelParams,
}

/// One depth image seen by another camera, for [`PerPixel::zbuffer_views`]: the depth
/// camera's model, its depth image (metres, that model's size) and the pose of the seeing
/// camera, `X_camera = R · X_depth + T`.
#[derive(Debug, Clone, Copy)]
pub struct DepthView<'a> {
    /// The depth camera (as fused: undistorted when the rig is rectified).
    pub depth_camera: &'a CameraModel,
    /// Its depth image, metres (NaN or 0 for no sample).
    pub depth: &'a Image<f32>,
    /// The seeing camera's pose in the depth camera's frame.
    pub camera_from_depth: RigidTransform,
}

/// What [`stream_on`] computes for each frame besides H1, H2 and H7's z-buffer: the
/// per-frame outputs of `kfuse fuse --recording`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StreamPlan {
    /// H8's hole mask.
    pub holes: bool,
    /// H3 nearest + H6 colour on the depth grid, for the frames that bring a colour image.
    pub color_on_depth: bool,
}

/// One frame of a stream ([`stream_on`]): its depth (metres, 0 or NaN for no sample, the
/// rig's depth size) and its colour image (the rig's colour size), which only H6 reads.
#[derive(Debug, Clone, Copy)]
pub struct StreamFrame<'a> {
    /// Depth, metres.
    pub depth: &'a Image<f32>,
    /// Colour, when the frame has one decoded.
    pub color: Option<&'a Image<[u8; 3]>>,
}

/// One streamed frame's results, lent to the sink of [`PerPixel::per_pixel_stream`] (the
/// engine reuses the buffers for the next frame).
#[derive(Debug, Clone, Copy)]
pub struct StreamResult<'a> {
    /// H7 z-buffer on the colour grid, row-major, [`ZBUFFER_EMPTY`] where no sample landed.
    pub zbuffer: &'a [f32],
    /// H8 hole mask on the colour grid, row-major, with [`StreamPlan::holes`].
    pub hole_mask: Option<&'a [bool]>,
    /// H6 colour on the depth grid and where it is trustworthy, with
    /// [`StreamPlan::color_on_depth`] for a frame with colour.
    pub color_on_depth: Option<(&'a Image<[u8; 3]>, &'a Image<bool>)>,
}

/// An engine for the per-pixel stages. Every engine's output is bit-identical to
/// [`CpuPixels`]'s (the GPU's on an adapter with IEEE division, see `fusion-gpu`).
pub trait PerPixel {
    /// The engine's error (every [`GeometryError`] converts into it).
    type Error: From<GeometryError>;

    /// H1, H2, H7, H3 nearest, H8 mask and H6 on one checked frame; adds its stage times to
    /// `timings`.
    fn per_pixel(
        &mut self,
        rig: &Rig,
        depth: &Image<f32>,
        kind: DepthKind,
        color: &Image<[u8; 3]>,
        params: &PixelParams,
        timings: &mut StageTimings,
    ) -> Result<PerPixelOutput, Self::Error>;

    /// H8 fill: `depth` with its `mask` pixels taken from `plane` ([`fill_holes_with_plane`]).
    fn fill_holes(
        &mut self,
        camera: &CameraModel,
        depth: &Image<f32>,
        mask: &Image<bool>,
        plane: &PlaneFit,
    ) -> Result<(Image<f32>, usize), Self::Error>;

    /// The batch form of [`PerPixel::per_pixel`]: every frame of `frames` (checked), outputs
    /// in order, each frame's stage times added to `timings`. One after another unless the
    /// engine does better ([`CpuPixels`]: the frames in parallel).
    fn per_pixel_batch(
        &mut self,
        frames: &[PixelFrame<'_>],
        kind: DepthKind,
        timings: &mut StageTimings,
    ) -> Result<Vec<PerPixelOutput>, Self::Error> {
        frames
            .iter()
            .map(|f| self.per_pixel(f.rig, f.depth, kind, f.color, &f.params, timings))
            .collect()
    }

    /// H1 + H2 + H7 of several depth images into one `camera`: per pixel of `camera`'s image
    /// the smallest `z` (its frame, metres) of any view's samples, [`super::ZBUFFER_EMPTY`]
    /// where none lands; the z-buffer across the sensors of a rig. Each view is H1 of its
    /// depth camera, H2 with the composed pose, and H7's min, so one view into its own
    /// colour camera is bit-identical to [`Registration`].
    fn zbuffer_views(
        &mut self,
        camera: &CameraModel,
        views: &[DepthView<'_>],
        kind: DepthKind,
    ) -> Result<Image<f32>, Self::Error>;

    /// The streaming form for sequences ([`stream_on`], which checks the frames first): H1,
    /// H2 and H7 of every frame of `frames` (all of `rig`), with H8's mask and H3 nearest +
    /// H6 as `plan` asks and with the H7 z-buffer of [`PixelParams::zbuffer`] on; each frame's
    /// results lent to `sink` in order. The engine keeps its state between calls for the
    /// same rig ([`CpuPixels`]: its [`Registration`]'s buffers and tables; the GPU: two
    /// frames in flight). Every result equals [`PerPixel::per_pixel`]'s on the frame.
    fn per_pixel_stream(
        &mut self,
        rig: &Rig,
        kind: DepthKind,
        frames: &[StreamFrame<'_>],
        params: &PixelParams,
        plan: StreamPlan,
        sink: &mut dyn FnMut(usize, StreamResult<'_>),
    ) -> Result<(), Self::Error>;

    /// One frame of a stream ([`register_on`], which checks it first) with its results
    /// written into the caller's buffers: H1 + H2 + H7 into `zbuffer` (colour-sized) and, when
    /// given, H8's mask into `hole_mask`. Equal to [`PerPixel::per_pixel_stream`] on the frame
    /// (this default runs it and copies what it lends; [`CpuPixels`] registers straight into
    /// `zbuffer`, with no copy).
    fn per_pixel_into(
        &mut self,
        rig: &Rig,
        kind: DepthKind,
        depth: &Image<f32>,
        params: &PixelParams,
        zbuffer: &mut [f32],
        hole_mask: Option<&mut [bool]>,
    ) -> Result<(), Self::Error> {
        per_pixel_into_by_copy(self, rig, kind, depth, params, zbuffer, hole_mask)
    }
}

/// [`PerPixel::per_pixel_into`] through [`PerPixel::per_pixel_stream`]: the frame streamed with
/// [`StreamPlan::holes`] as `hole_mask` asks, and what the engine lends copied into the
/// caller's buffers.
fn per_pixel_into_by_copy<E: PerPixel + ?Sized>(
    engine: &mut E,
    rig: &Rig,
    kind: DepthKind,
    depth: &Image<f32>,
    params: &PixelParams,
    zbuffer: &mut [f32],
    mut hole_mask: Option<&mut [bool]>,
) -> Result<(), E::Error> {
    let plan = StreamPlan { holes: hole_mask.is_some(), color_on_depth: false };
    let frames = [StreamFrame { depth, color: None }];
    engine.per_pixel_stream(rig, kind, &frames, params, plan, &mut |_, r| {
        zbuffer.copy_from_slice(r.zbuffer);
        if let (Some(out), Some(mask)) = (hole_mask.as_deref_mut(), r.hole_mask) {
            out.copy_from_slice(mask);
        }
    })
}

/// The CPU engine. H7 and H8's mask run on [`Registration`] (the fast path of the
/// `register+holes` benchmark: on all rayon threads for a frame, on one thread per frame of
/// a stream, whose caller runs its own stages beside it), H1/H2 keep the cloud and the samples
/// the outputs need, H3 nearest and H6 are the stage functions. It keeps the stream's
/// [`Registration`] between [`PerPixel::per_pixel_stream`] calls for the same rig.
#[derive(Debug, Default, Clone)]
pub struct CpuPixels {
    stream: Option<Box<CpuStream>>,
}

/// What [`CpuPixels`] keeps for a stream: the rig, kind and radii it was built for, and
/// the buffers.
#[derive(Debug, Clone)]
struct CpuStream {
    rig: Rig,
    kind: DepthKind,
    radii: (f32, f32),
    reg: Registration,
    rays: Vec<[f32; 3]>,
    proj: ColorProjection,
    mask: Vec<bool>,
    /// The frame clipped to the depth range ([`CpuPixels::per_pixel_into`]), reused.
    clipped: Image<f32>,
}

impl CpuPixels {
    /// A CPU engine (no stream state yet).
    pub fn new() -> Self {
        Self::default()
    }

    /// The stream state for `rig`, `kind` and `params`' radii, built on first use and when
    /// any of them changes.
    fn stream_state(
        &mut self,
        rig: &Rig,
        kind: DepthKind,
        params: &PixelParams,
    ) -> Result<&mut CpuStream, GeometryError> {
        let radii = (params.radius_px, params.grow_px);
        let fresh = self
            .stream
            .as_ref()
            .is_some_and(|s| s.kind == kind && s.radii == radii && s.rig == *rig);
        if !fresh {
            let rays = depth_ray_table(&rig.depth, kind);
            let proj = ColorProjection::from_rig(rig);
            let reg = Registration::from_parts(proj, &rays, rig.depth.width, radii.0, radii.1)?;
            let mask = vec![false; rig.color.width * rig.color.height];
            let clipped = Image::filled(0, 0, f32::NAN);
            self.stream = Some(Box::new(CpuStream {
                rig: rig.clone(),
                kind,
                radii,
                reg,
                rays,
                proj,
                mask,
                clipped,
            }));
        }
        Ok(self.stream.as_mut().expect("built above"))
    }

    /// H8's hole mask of the last frame of [`PerPixel::per_pixel_into`] (or of the last
    /// streamed frame) into `mask` (colour-sized), on all rayon threads; the number of hole
    /// pixels, `None` before any frame or for a `mask` of another length.
    pub fn last_hole_mask(&mut self, mask: &mut [bool]) -> Option<usize> {
        let s = self.stream.as_mut()?;
        (mask.len() == s.mask.len()).then(|| s.reg.hole_mask_parallel(mask))
    }
}

/// H6 of one frame as every CPU path runs it: with the occlusion test against `nearest`
/// (H3) when `params` has a tolerance, without it otherwise.
fn h6(
    depth: &Image<f32>,
    rays: &[[f32; 3]],
    proj: &ColorProjection,
    color: &Image<[u8; 3]>,
    nearest: &impl SeenDepth,
    params: &PixelParams,
) -> (Image<[u8; 3]>, Image<bool>) {
    match params.occlusion_tolerance {
        Some(tol) => color_on_depth(depth, rays, proj, color, Some(nearest), tol),
        None => color_on_depth(depth, rays, proj, color, None::<&Image<f32>>, 0.0),
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

impl PerPixel for CpuPixels {
    type Error = GeometryError;

    fn per_pixel(
        &mut self,
        rig: &Rig,
        depth: &Image<f32>,
        kind: DepthKind,
        color: &Image<[u8; 3]>,
        params: &PixelParams,
        timings: &mut StageTimings,
    ) -> Result<PerPixelOutput, GeometryError> {
        let depth = &*params.depth_range.clip(depth);
        let proj = ColorProjection::from_rig(rig);
        let (cw, ch) = (rig.color.width, rig.color.height);

        let t = Instant::now();
        let rays = depth_ray_table(&rig.depth, kind);
        let (cloud, cloud_pixels) = backproject_cloud(depth, &rays);
        timings.h1_ms += ms(t);

        let t = Instant::now();
        let samples = project_cloud(&cloud.points, &proj);
        timings.h2_ms += ms(t);

        let (zbuffer, mask) = if params.zbuffer {
            let t = Instant::now();
            let mut reg = Registration::from_parts(
                proj,
                &rays,
                rig.depth.width,
                params.radius_px,
                params.grow_px,
            )?;
            reg.register_parallel(depth)?;
            timings.h7_ms += ms(t);
            let t = Instant::now();
            let mut mask = Image::filled(cw, ch, false);
            reg.hole_mask_parallel(mask.data_mut());
            timings.h8_ms += ms(t);
            (Image::from_vec(cw, ch, reg.into_zbuffer())?, mask)
        } else {
            let t = Instant::now();
            let zbuffer = first_write_wins(&samples, cw, ch);
            timings.h7_ms += ms(t);
            let t = Instant::now();
            let mask = hole_mask(&zbuffer, params.radius_px, params.grow_px);
            timings.h8_ms += ms(t);
            (zbuffer, mask)
        };

        let t = Instant::now();
        let nearest = nearest_fill(&zbuffer, params.radius_px, params.depth_jump);
        timings.h3_nearest_ms += ms(t);

        let t = Instant::now();
        let (color_img, color_valid) = h6(depth, &rays, &proj, color, &nearest, params);
        timings.h6_ms += ms(t);

        Ok(PerPixelOutput {
            points: cloud.points,
            cloud_pixels,
            samples,
            zbuffer,
            nearest,
            hole_mask: mask,
            color_on_depth: color_img,
            color_on_depth_valid: color_valid,
        })
    }

    fn fill_holes(
        &mut self,
        camera: &CameraModel,
        depth: &Image<f32>,
        mask: &Image<bool>,
        plane: &PlaneFit,
    ) -> Result<(Image<f32>, usize), GeometryError> {
        Ok(fill_holes_with_plane(depth, mask, camera, plane))
    }

    /// The frames on all rayon threads, each on its own [`CpuPixels`]; `timings` gets the sum
    /// of the frames' stage times (CPU time, above the batch's wall time).
    fn per_pixel_batch(
        &mut self,
        frames: &[PixelFrame<'_>],
        kind: DepthKind,
        timings: &mut StageTimings,
    ) -> Result<Vec<PerPixelOutput>, GeometryError> {
        let outputs: Vec<(PerPixelOutput, StageTimings)> = frames
            .par_iter()
            .map(|f| {
                let mut t = StageTimings::default();
                let out =
                    CpuPixels::new().per_pixel(f.rig, f.depth, kind, f.color, &f.params, &mut t)?;
                Ok((out, t))
            })
            .collect::<Result<_, GeometryError>>()?;
        Ok(outputs
            .into_iter()
            .map(|(out, t)| {
                timings.add(&t);
                out
            })
            .collect())
    }

    fn zbuffer_views(
        &mut self,
        camera: &CameraModel,
        views: &[DepthView<'_>],
        kind: DepthKind,
    ) -> Result<Image<f32>, GeometryError> {
        camera.validate()?;
        let mut out = Image::filled(camera.width, camera.height, ZBUFFER_EMPTY);
        for v in views {
            v.depth_camera.validate()?;
            v.depth.expect_size("depth image", v.depth_camera.width, v.depth_camera.height)?;
            let (cloud, _) = backproject_cloud(v.depth, &depth_ray_table(v.depth_camera, kind));
            let proj =
                ColorProjection::from_rig(&Rig::new(*v.depth_camera, *camera, v.camera_from_depth));
            zbuffer_points(&cloud.points, &proj, out.data_mut());
        }
        Ok(out)
    }

    /// One thread per frame on the kept [`Registration`]; with [`PixelParams::zbuffer`] off
    /// (first write wins), [`PerPixel::per_pixel`] per frame.
    fn per_pixel_stream(
        &mut self,
        rig: &Rig,
        kind: DepthKind,
        frames: &[StreamFrame<'_>],
        params: &PixelParams,
        plan: StreamPlan,
        sink: &mut dyn FnMut(usize, StreamResult<'_>),
    ) -> Result<(), GeometryError> {
        if !params.zbuffer {
            let black = Image::filled(rig.color.width, rig.color.height, [0u8; 3]);
            for (i, f) in frames.iter().enumerate() {
                let color = f.color.unwrap_or(&black);
                let mut t = StageTimings::default();
                let out = self.per_pixel(rig, f.depth, kind, color, params, &mut t)?;
                sink(
                    i,
                    StreamResult {
                        zbuffer: out.zbuffer.data(),
                        hole_mask: plan.holes.then_some(out.hole_mask.data()),
                        color_on_depth: (plan.color_on_depth && f.color.is_some())
                            .then_some((&out.color_on_depth, &out.color_on_depth_valid)),
                    },
                );
            }
            return Ok(());
        }
        let s = self.stream_state(rig, kind, params)?;
        for (i, f) in frames.iter().enumerate() {
            let depth = &*params.depth_range.clip(f.depth);
            s.reg.register(depth)?;
            if plan.holes {
                s.reg.hole_mask(&mut s.mask);
            }
            let colored = match f.color {
                Some(color) if plan.color_on_depth => {
                    // H3's nearest fill only where H6 reads it (`NearestFill`): the same values.
                    let zbuffer = s.reg.zbuffer_image();
                    let nearest = NearestFill::new(&zbuffer, params.radius_px, params.depth_jump);
                    Some(h6(depth, &s.rays, &s.proj, color, &nearest, params))
                }
                _ => None,
            };
            sink(
                i,
                StreamResult {
                    zbuffer: s.reg.zbuffer(),
                    hole_mask: plan.holes.then_some(&s.mask[..]),
                    color_on_depth: colored.as_ref().map(|(c, v)| (c, v)),
                },
            );
        }
        Ok(())
    }

    /// On the kept [`Registration`] on all rayon threads (one frame: no caller stages run
    /// beside it), straight into `zbuffer` ([`Registration::register_parallel_into`]); the
    /// depth range clipped into a kept buffer. With [`PixelParams::zbuffer`] off, the
    /// default (via [`PerPixel::per_pixel_stream`]).
    fn per_pixel_into(
        &mut self,
        rig: &Rig,
        kind: DepthKind,
        depth: &Image<f32>,
        params: &PixelParams,
        zbuffer: &mut [f32],
        hole_mask: Option<&mut [bool]>,
    ) -> Result<(), GeometryError> {
        if !params.zbuffer {
            return per_pixel_into_by_copy(self, rig, kind, depth, params, zbuffer, hole_mask);
        }
        let s = self.stream_state(rig, kind, params)?;
        if params.depth_range.is_all() {
            s.reg.register_parallel_into(depth, zbuffer)?;
        } else {
            params.depth_range.clip_into(depth, &mut s.clipped);
            s.reg.register_parallel_into(&s.clipped, zbuffer)?;
        }
        if let Some(mask) = hole_mask {
            s.reg.hole_mask_parallel(mask);
        }
        Ok(())
    }
}

/// The colours of the cloud: H6's colour of each point's depth pixel, black where H6 does
/// not trust it.
pub fn cloud_colors(
    cloud_pixels: &[u32],
    color_on_depth: &Image<[u8; 3]>,
    valid: &Image<bool>,
) -> Vec<[u8; 3]> {
    let (colors, valid) = (color_on_depth.data(), valid.data());
    cloud_pixels
        .iter()
        .map(|&i| if valid[i as usize] { colors[i as usize] } else { [0, 0, 0] })
        .collect()
}

/// H5's test for `rig` and `options`: the rule, tilt limit and noise of `options`, at the
/// scale of the rig's depth samples (the depth camera's mean focal length).
pub fn stretch_test(rig: &Rig, options: &FusionOptions) -> StretchTest {
    let k = rig.depth.intrinsics;
    StretchTest {
        rule: options.edge_rule,
        ratio: options.stretch_ratio,
        depth_focal_px: (k.fx * k.fy).sqrt() as f32,
        noise_1m_m: options.depth_noise_1m_m,
    }
}

/// Runs H1–H8 on one frame of `request` with the per-pixel stages on `engine` (see the
/// module docs). `depth` is prepared ([`Request::prepare_depth`]). With
/// [`FusionOptions::zbuffer`] off the per-pixel stages run on [`CpuPixels`] whatever the
/// engine.
///
/// Errors: those of [`check_inputs`] (before any work), and the engine's.
pub fn run_on<E: PerPixel>(
    engine: &mut E,
    request: &Request,
    depth: &Image<f32>,
    color: &Image<[u8; 3]>,
) -> Result<FusionOutput, E::Error> {
    let (rig, kind, options) = (request.rig(), request.kind(), request.options());
    let valid_depth_pixels = check_inputs(rig, depth, color, options)?;
    let mut timings = StageTimings::default();
    let params = request.params();
    let px = if options.zbuffer {
        engine.per_pixel(rig, depth, kind, color, &params, &mut timings)?
    } else {
        CpuPixels::new().per_pixel(rig, depth, kind, color, &params, &mut timings)?
    };

    let t = Instant::now();
    let spacing = sample_spacing_px(rig);
    let (linear, linear_stats) = if options.linear {
        let (img, stats) = linear_resample(
            &px.samples,
            &px.zbuffer,
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
        fit_plane_ransac(&px.nearest, &rig.color, &options.plane)
    } else {
        None
    };
    let mut fill = |d: &Image<f32>| -> Result<(Image<f32>, usize), E::Error> {
        match &plane {
            Some(p) if options.zbuffer => engine.fill_holes(&rig.color, d, &px.hole_mask, p),
            Some(p) => Ok(CpuPixels::new().fill_holes(&rig.color, d, &px.hole_mask, p)?),
            None => Ok((d.clone(), 0)),
        }
    };
    let (filled, filled_pixels) = fill(&px.nearest)?;
    let linear_filled = match (options.mesh_source, &linear) {
        (MeshSource::LinearFilled, Some(l)) if plane.is_some() => Some(fill(l)?),
        _ => None,
    };
    timings.h8_ms += ms(t);

    let t = Instant::now();
    let (mesh, mesh_filled_pixels) = if options.mesh_source == MeshSource::DepthGrid {
        let (mesh, _) = mesh_on_depth_grid(
            rig.depth.width,
            rig.depth.height,
            &px.points,
            &px.cloud_pixels,
            &px.samples,
            &rig.color_from_depth,
            color.size(),
            &px.color_on_depth,
            &px.color_on_depth_valid,
        );
        (mesh, 0)
    } else {
        let (mesh_depth, filled) = match (options.mesh_source, &linear_filled) {
            (MeshSource::Nearest | MeshSource::DepthGrid, _) => (&px.nearest, 0),
            (MeshSource::Filled, _) => (&filled, filled_pixels),
            (MeshSource::LinearFilled, Some((d, n))) => (d, *n),
            (MeshSource::Linear | MeshSource::LinearFilled, _) => {
                (linear.as_ref().unwrap_or(&px.nearest), 0)
            }
        };
        (mesh_from_depth(mesh_depth, &rig.color, color, options.mesh_step), filled)
    };
    timings.h4_ms = ms(t);
    let t = Instant::now();
    let mesh_clean = remove_edge_faces(&mesh, &stretch_test(rig, options));
    timings.h5_ms = ms(t);

    let mut cloud = PointCloud { points: px.points, ..PointCloud::default() };
    cloud.colors = cloud_colors(&px.cloud_pixels, &px.color_on_depth, &px.color_on_depth_valid);

    let count = |img: &Image<f32>| img.data().iter().filter(|z| z.is_finite()).count();
    let summary = FusionSummary {
        depth_size: [rig.depth.width, rig.depth.height],
        color_size: [rig.color.width, rig.color.height],
        depth_kind: kind,
        valid_depth_pixels,
        points: cloud.len(),
        samples_in_view: px.samples.len(),
        zbuffer_pixels: count(&px.zbuffer),
        sample_spacing_px: spacing,
        coverage_radius_px: params.radius_px,
        nearest_pixels: count(&px.nearest),
        linear: linear_stats,
        mesh_vertices: mesh.vertices.len(),
        faces_before: mesh.faces.len(),
        faces_after: mesh_clean.faces.len(),
        faces_removed_fraction: if mesh.faces.is_empty() {
            0.0
        } else {
            1.0 - mesh_clean.faces.len() as f64 / mesh.faces.len() as f64
        },
        color_on_depth_pixels: px.color_on_depth_valid.data().iter().filter(|&&v| v).count(),
        hole_pixels: px.hole_mask.data().iter().filter(|&&m| m).count(),
        filled_pixels,
        plane,
        timings_ms: options.record_timings.then_some(timings),
    };
    let mesh_depth = linear_filled.map(|(d, _)| d);
    Ok(FusionOutput {
        cloud,
        cloud_pixels: px.cloud_pixels,
        samples: px.samples,
        zbuffer: px.zbuffer,
        nearest: px.nearest,
        linear,
        hole_mask: px.hole_mask,
        filled,
        linear_filled: mesh_depth,
        mesh_filled_pixels,
        color_on_depth: px.color_on_depth,
        color_on_depth_valid: px.color_on_depth_valid,
        mesh,
        mesh_clean,
        summary,
    })
}

/// The per-pixel stages of [`run_on`] on a stream of frames of `request` (their depth
/// prepared, [`Request::prepare_depth`]), on `engine`: what `kfuse fuse --recording/--frames`
/// runs per frame ([`PerPixel::per_pixel_stream`]; each frame's results lent to `sink` in
/// order). With [`FusionOptions::zbuffer`] off the stages run on [`CpuPixels`] whatever the
/// engine, as in [`run_on`].
///
/// Errors, before any work: an invalid rig, a coverage radius out of bounds
/// ([`super::checked_coverage_radius_px`]), a frame whose depth or colour image is not of its
/// camera's size; then the engine's. A frame without any depth sample is not an error here
/// (a stream goes on; [`run_on`] refuses such a frame).
pub fn stream_on<E: PerPixel>(
    engine: &mut E,
    request: &Request,
    frames: &[StreamFrame<'_>],
    plan: StreamPlan,
    sink: &mut dyn FnMut(usize, StreamResult<'_>),
) -> Result<(), E::Error> {
    let (rig, kind, options) = (request.rig(), request.kind(), request.options());
    rig.validate()?;
    super::checked_coverage_radius_px(rig, options)?;
    for f in frames {
        f.depth.expect_size("depth image", rig.depth.width, rig.depth.height)?;
        if let Some(c) = f.color {
            c.expect_size("colour image", rig.color.width, rig.color.height)?;
        }
    }
    let params = request.params();
    if options.zbuffer {
        engine.per_pixel_stream(rig, kind, frames, &params, plan, sink)
    } else {
        Ok(CpuPixels::new().per_pixel_stream(rig, kind, frames, &params, plan, sink)?)
    }
}

/// One frame of a stream of `request` (its depth prepared, [`Request::prepare_depth`]) on
/// `engine`, its results written into the caller's buffers: the H7 z-buffer into `zbuffer`
/// and, when given, H8's hole mask into `hole_mask` (both colour-sized, row-major); what
/// [`stream_on`] lends for the frame with [`StreamPlan::holes`] as `hole_mask` asks
/// ([`PerPixel::per_pixel_into`]: on [`CpuPixels`] with no copy). With
/// [`FusionOptions::zbuffer`] off the stages run on [`CpuPixels`] whatever the engine.
///
/// Errors, before any work: those of [`stream_on`], and a buffer of another length than the
/// colour image's ([`GeometryError::InvalidInput`]); then the engine's.
pub fn register_on<E: PerPixel>(
    engine: &mut E,
    request: &Request,
    depth: &Image<f32>,
    zbuffer: &mut [f32],
    hole_mask: Option<&mut [bool]>,
) -> Result<(), E::Error> {
    let (rig, kind, options) = (request.rig(), request.kind(), request.options());
    rig.validate()?;
    super::checked_coverage_radius_px(rig, options)?;
    depth.expect_size("depth image", rig.depth.width, rig.depth.height)?;
    let pixels = rig.color.width * rig.color.height;
    let lengths = [Some(zbuffer.len()), hole_mask.as_ref().map(|m| m.len())];
    if let Some(n) = lengths.into_iter().flatten().find(|&n| n != pixels) {
        return Err(GeometryError::InvalidInput(format!(
            "an output buffer of {n} pixels for the {}x{} colour image ({pixels} pixels)",
            rig.color.width, rig.color.height
        ))
        .into());
    }
    let params = request.params();
    if options.zbuffer {
        engine.per_pixel_into(rig, kind, depth, &params, zbuffer, hole_mask)
    } else {
        Ok(CpuPixels::new().per_pixel_into(rig, kind, depth, &params, zbuffer, hole_mask)?)
    }
}

/// Runs H1–H8 on one frame on the CPU: the [`Request`] of `rig`, `kind` and `options`, its
/// depth preparation on a copy of `depth`, and [`run_on`] with [`CpuPixels`]. `depth` is
/// depth-camera-sized (metres, kind `kind`, NaN / 0 = no sample), `color` colour-camera-sized.
///
/// Errors: [`GeometryError::SizeMismatch`] when an image does not match its camera in
/// `rig`, [`GeometryError::InvalidParameter`] for an invalid rig,
/// [`GeometryError::InvalidInput`] when no depth pixel has a sample or the coverage radius is
/// out of bounds.
pub fn run(
    rig: &Rig,
    depth: &Image<f32>,
    kind: DepthKind,
    color: &Image<[u8; 3]>,
    options: &FusionOptions,
) -> Result<FusionOutput, GeometryError> {
    let request = Request::new(rig, kind, *options)?;
    let depth = request.prepared(depth)?;
    run_on(&mut CpuPixels::new(), &request, &depth, color)
}
