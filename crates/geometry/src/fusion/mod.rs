//! The CPU depth → colour fusion pipeline, stages H1–H8 of the lab handout.
//!
//! | stage | function | result |
//! | --- | --- | --- |
//! | H1 | [`backproject_cloud`] | depth pixels → points in the depth camera frame (z or range input) |
//! | H2 | [`project_cloud`] | `X_c = R·X_d + T`, projected with the colour camera's distortion |
//! | H3 | [`nearest_fill`], [`linear_resample`] | samples → colour pixel grid (nearest; Delaunay-linear) |
//! | H4 | [`mesh_on_depth_grid`], [`mesh_from_depth`] | textured triangle mesh on the depth samples (default) or on a colour-frame depth image |
//! | H5 | [`remove_edge_faces`] ([`StretchTest`]) | faces at depth discontinuities dropped (sample-scale depth-step test, or the handout's face normal) |
//! | H6 | [`color_on_depth`] | colour sampled onto the depth grid (bilinear) |
//! | H7 | [`Registration`] | nearest surface per colour pixel (exact min z) |
//! | H8 | [`hole_mask`], [`fit_plane_ransac`], [`fill_holes_with_plane`] | disocclusion holes, plane fill |
//!
//! [`run_on`] chains them for one frame, with the per-pixel stages on an engine ([`CpuPixels`]
//! or `fusion-gpu`'s context; [`run`] is the CPU one); the CLI, `fusion-gpu` and the viewer
//! all call it. For a stream
//! of frames, [`Registration`] does H1 + H2 + H7 and H8's mask with buffers and per-pixel
//! constants kept between frames (bit-identical to the stages above; the fast path of the
//! `register+holes` benchmark).
//!
//! # Conventions
//!
//! Those of the crate (pixel centres at integers, `color_from_depth`, metres). Depth images
//! in the colour frame hold the colour camera's `z`; an empty pixel is NaN (H7 and H3 use the
//! NaN with bits `0xFFFF_FFFF`, [`ZBUFFER_EMPTY`]).
//!
//! **Sample spacing** `s`: the distance in colour pixels between the projections of two
//! neighbouring depth pixels at equal depth, `s = sqrt((fx_c/fx_d)·(fy_c/fy_d))` (Kinect v2:
//! ~2.9 px). The **coverage radius** of H3's nearest fill and H8's mask is
//! `max(hole_radius_factor · s, MIN_COVERAGE_RADIUS_PX)`: a colour pixel with no z-buffered
//! sample within it is empty, and a hole if it also lies inside the samples' footprint
//! (see [`HoleMasker`]).
//!
//! # GPU parity rules
//!
//! The per-pixel arithmetic lives in [`pixel`] as small `#[inline]` `f32` functions
//! ([`backproject_pixel`], [`transform_point`], [`project_color_point`], [`zbuffer_index`],
//! [`zbuffer_min`]), plus [`nearest_fill_pixel`] (with [`disc_offsets`]),
//! [`plane_depth_pixel`] and [`bilinear_rgb`]; `fusion-gpu`'s WGSL mirrors them line by line.
//! See [`pixel`] for the exact rules: evaluation order, validity test, the rounding rule
//! `(floor(u + 0.5), floor(v + 0.5))` and the z-buffer's empty value.

mod color;
mod holes;
mod mesh;
pub mod multi;
mod pipeline;
pub mod pixel;
mod range;
mod register;
mod request;
mod resample;
mod stream;
pub mod units;
#[cfg(feature = "bench-variants")]
mod variants;

use serde::Serialize;

pub use color::{SeenDepth, bilinear_rgb, color_on_depth};
pub use holes::{
    HoleMasker, PlaneFit, PlaneFitOptions, fill_holes_with_plane, fit_plane_ransac, hole_mask,
    plane_depth_pixel,
};
pub use mesh::{
    EdgeFaceRule, HIDDEN_VERTEX_GREY, KINECT_NOISE_1M_M, NOISE_ALLOWANCE_SIGMAS, StretchTest,
    face_normal, is_stretched, mesh_from_depth, mesh_on_depth_grid, remove_edge_faces,
    remove_stretched_faces,
};
#[cfg(feature = "fault-injection")]
pub use pipeline::fault;
pub use pipeline::{
    CpuPixels, DepthView, PerPixel, PerPixelOutput, PixelFrame, PixelParams, StreamFrame,
    StreamPlan, StreamResult, cloud_colors, register_on, run, run_on, stream_on, stretch_test,
};
pub use pixel::{
    ColorProjection, ZBUFFER_EMPTY, backproject_pixel, depth_ray_table, floor_f32, is_sample,
    is_sample_in, project_color_point, project_point, register_pixel, transform_point,
    zbuffer_index, zbuffer_min, zbuffer_pixel, zbuffer_points,
};
pub use range::{DepthRange, MAX_RANGE_M};
pub use register::{ColorSample, backproject_cloud, first_write_wins, project_cloud};
pub use request::{DEPTH_CORRECTION_NEEDS_Z, Request};
pub use resample::{
    LinearStats, NearestFill, disc_offsets, linear_resample, nearest_fill, nearest_fill_pixel,
};
pub use stream::Registration;
/// The z-buffer variants that benchmarks and comparison tests measure [`Registration`] against
/// (feature `bench-variants`; bit-identical to it). Not part of the library's API: the one CPU
/// z-buffer is [`Registration`], the other is `fusion-gpu`'s shader.
#[cfg(feature = "bench-variants")]
pub use variants::{
    atomic_zbuffer_to_image, register_depth, register_depth_marking, register_depth_parallel,
    zbuffer_from_samples,
};

use crate::{DepthKind, GeometryError, Image, Mesh, PointCloud, Rig};

/// Smallest coverage radius, pixels: below 1.5 px a colour camera no sharper than the depth
/// camera would call the diagonal gaps of a square sample lattice holes.
pub const MIN_COVERAGE_RADIUS_PX: f32 = 1.5;

/// Largest coverage radius, colour pixels, that H3 nearest and H8 accept. The nearest fill
/// reads up to twice the `π r²` pixels of its disc per colour pixel, so its work grows with
/// the square of the radius: 16 px (≈ 800 offsets, ~22× the Kinect default of 3.5 px) keeps a
/// 1920×1080 frame to about a second on one core, and a coverage disc 32 px wide already
/// closes every disocclusion a Kinect-like baseline makes, so H8 would find no hole at all.
/// A `--hole-radius` of 30 (87 px on a Kinect) or 1e9 is refused with this limit instead of
/// hanging or aborting on the disc table.
pub const MAX_COVERAGE_RADIUS_PX: f32 = 16.0;

/// Largest sample spacing, colour pixels between neighbouring depth samples, that a rig may
/// give (Kinect v2: 2.9). At 8 a depth sample stands for 64 colour pixels: a colour camera
/// more than 8× sharper than its depth camera is not a fusion rig, but a depth focal length
/// in millimetres or metres instead of pixels is (3.65 gives ~296, 0.00365 ~300 000), and
/// would size the coverage disc, the hole mask and the linear resampling's edge test by it.
pub const MAX_SAMPLE_SPACING_PX: f32 = 8.0;

/// What H4 meshes: the depth samples themselves (default) or a colour-frame depth image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshSource {
    /// One vertex per depth sample that lands on the colour image, faces on the depth pixel
    /// grid, texture coordinates from H2's projection ([`mesh_on_depth_grid`]): no
    /// staircase, every vertex a measurement. Disocclusion holes stay open (H5 removes the
    /// faces across them); [`FusionOptions::mesh_step`] does not apply.
    #[default]
    #[serde(rename = "depth_grid")]
    DepthGrid,
    /// H3 nearest fill.
    Nearest,
    /// H3 Delaunay-linear (falls back to nearest when linear is off).
    Linear,
    /// Nearest fill with H8's plane-filled holes.
    Filled,
    /// H3 Delaunay-linear with H8's plane-filled holes (the viewer's Delaunay + hole filling;
    /// falls back to [`MeshSource::Linear`] without a plane and to nearest without linear).
    #[serde(rename = "linear_filled")]
    LinearFilled,
}

/// Every knob of [`run`]. `Default` is what the lab handout does, tuned for a Kinect v2.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FusionOptions {
    /// Coverage radius of H3 nearest and H8 holes, in sample spacings (see the module docs).
    /// 1.2: covers the diagonal gap of a square lattice (0.71 s) on surfaces tilted up to
    /// ~55° (stretch 1.7), and is small enough to keep a 52 mm-baseline Kinect's
    /// disocclusions (≥ 5 px at 1 m depth difference) open.
    pub hole_radius_factor: f32,
    /// Relative depth difference that separates two surfaces (H3 nearest's "nearest
    /// surface", H3 linear's edge test). 5 %: ten times the Kinect's depth noise, well below
    /// object/background gaps.
    pub depth_jump: f32,
    /// Compute H3's Delaunay-linear resampling (the slowest stage: a Delaunay triangulation of
    /// ~190k samples per Kinect frame).
    pub linear: bool,
    /// Longest triangle edge H3 linear fills, in sample spacings: 3 bridges stretched
    /// samples on slanted surfaces but not disocclusion holes wider than ~3 samples.
    pub linear_max_edge_factor: f32,
    /// Which depth H4 meshes.
    pub mesh_source: MeshSource,
    /// H4 grid step in colour pixels for the colour-grid sources: 2 gives ~1 vertex per
    /// depth sample at Kinect scale.
    pub mesh_step: usize,
    /// H5 rule ([`EdgeFaceRule`]): the sample-scale depth-step test (default) or the
    /// handout's literal face-normal test.
    pub edge_rule: EdgeFaceRule,
    /// H5 tilt limit, `tan(angle)`: with [`EdgeFaceRule::Normal`] a face goes when
    /// `|n_xy| > stretch_ratio · |n_z|`; with [`EdgeFaceRule::SampleScale`] an edge is
    /// stretched when its depth step exceeds `stretch_ratio` times its lateral extent plus
    /// the noise allowance. 1.0 is the handout's "in-plane component larger than the depth
    /// component" (45°).
    pub stretch_ratio: f32,
    /// H5 [`EdgeFaceRule::SampleScale`]: the depth noise σ at 1 m, metres, growing with z²
    /// ([`KINECT_NOISE_1M_M`] for a Kinect; 0 for noise-free data).
    pub depth_noise_1m_m: f32,
    /// H6: a depth pixel's colour is rejected as occluded when its point is farther than the
    /// surface the colour camera sees there by more than this fraction. 2 %: above nearest
    /// fill's depth steps on slanted surfaces, below object/background gaps.
    pub color_occlusion_tolerance: f32,
    /// H8 plane fit.
    pub plane: PlaneFitOptions,
    /// Fill H8's holes from the plane (otherwise `filled` = `nearest`).
    pub fill_holes: bool,
    /// Record wall-clock time per stage in the summary.
    pub record_timings: bool,
    /// H7 z-buffer. Off (a teaching switch of the viewer): the first sample on a colour pixel
    /// stays ([`first_write_wins`]), H6 has no occlusion test, and the per-pixel stages run on
    /// the CPU whatever the engine. Written to summary.json only when off.
    #[serde(skip_serializing_if = "is_true")]
    pub zbuffer: bool,
    /// H1: depth values outside this range are not samples (`--depth-range`). Written to
    /// summary.json only when it clips.
    #[serde(skip_serializing_if = "DepthRange::is_all")]
    pub depth_range: DepthRange,
}

fn is_true(b: &bool) -> bool {
    *b
}

impl Default for FusionOptions {
    fn default() -> Self {
        Self {
            hole_radius_factor: 1.2,
            depth_jump: 0.05,
            linear: true,
            linear_max_edge_factor: 3.0,
            mesh_source: MeshSource::DepthGrid,
            mesh_step: 2,
            edge_rule: EdgeFaceRule::SampleScale,
            stretch_ratio: 1.0,
            depth_noise_1m_m: KINECT_NOISE_1M_M,
            color_occlusion_tolerance: 0.02,
            plane: PlaneFitOptions::default(),
            fill_holes: true,
            record_timings: false,
            zbuffer: true,
            depth_range: DepthRange::ALL,
        }
    }
}

/// Milliseconds per stage.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct StageTimings {
    /// H1 back-projection.
    pub h1_ms: f64,
    /// H2 projection.
    pub h2_ms: f64,
    /// H7 z-buffer.
    pub h7_ms: f64,
    /// H3 nearest fill.
    pub h3_nearest_ms: f64,
    /// H3 Delaunay-linear.
    pub h3_linear_ms: f64,
    /// H8 mask, plane fit and fill.
    pub h8_ms: f64,
    /// H6 colour on depth.
    pub h6_ms: f64,
    /// H4 mesh.
    pub h4_ms: f64,
    /// H5 stretched-face removal.
    pub h5_ms: f64,
}

impl StageTimings {
    /// Adds `other`'s time of every stage to this one's.
    pub fn add(&mut self, other: &StageTimings) {
        self.h1_ms += other.h1_ms;
        self.h2_ms += other.h2_ms;
        self.h7_ms += other.h7_ms;
        self.h3_nearest_ms += other.h3_nearest_ms;
        self.h3_linear_ms += other.h3_linear_ms;
        self.h8_ms += other.h8_ms;
        self.h6_ms += other.h6_ms;
        self.h4_ms += other.h4_ms;
        self.h5_ms += other.h5_ms;
    }

    /// The stages as a [`crate::timing::Timings`] (for the `--timings` summary), in pipeline
    /// order.
    pub fn to_timings(&self) -> crate::timing::Timings {
        let mut t = crate::timing::Timings::new();
        for (stage, ms) in [
            ("H1 back-projection", self.h1_ms),
            ("H2 projection", self.h2_ms),
            ("H7 z-buffer", self.h7_ms),
            ("H3 nearest", self.h3_nearest_ms),
            ("H3 linear", self.h3_linear_ms),
            ("H8 holes", self.h8_ms),
            ("H6 colour on depth", self.h6_ms),
            ("H4 mesh", self.h4_ms),
            ("H5 stretched faces", self.h5_ms),
        ] {
            t.add(stage, ms);
        }
        t
    }
}

/// Counts of every stage of one [`run`] (serialisable as the CLI's JSON report).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FusionSummary {
    /// Depth image size.
    pub depth_size: [usize; 2],
    /// Colour image size.
    pub color_size: [usize; 2],
    /// Depth kind of the input.
    pub depth_kind: DepthKind,
    /// Depth pixels with a sample.
    pub valid_depth_pixels: usize,
    /// H1 points.
    pub points: usize,
    /// H2 samples landing on the colour image in front of the camera.
    pub samples_in_view: usize,
    /// H7 colour pixels holding a sample.
    pub zbuffer_pixels: usize,
    /// Sample spacing in colour pixels.
    pub sample_spacing_px: f32,
    /// Coverage radius of H3 nearest / H8, pixels.
    pub coverage_radius_px: f32,
    /// H3 nearest: colour pixels with a value.
    pub nearest_pixels: usize,
    /// H3 linear statistics (when computed).
    pub linear: Option<LinearStats>,
    /// H4 vertices.
    pub mesh_vertices: usize,
    /// H4 faces (before H5).
    pub faces_before: usize,
    /// Faces kept by H5.
    pub faces_after: usize,
    /// Fraction of H4's faces H5 removed (0 for an empty mesh).
    pub faces_removed_fraction: f64,
    /// H6 depth pixels with a trusted colour.
    pub color_on_depth_pixels: usize,
    /// H8 hole pixels.
    pub hole_pixels: usize,
    /// H8 pixels filled from the plane.
    pub filled_pixels: usize,
    /// H8 plane (colour frame), when one was found.
    pub plane: Option<PlaneFit>,
    /// Per-stage timings, when requested.
    pub timings_ms: Option<StageTimings>,
}

/// Everything [`run`] computes. Colour-frame depth images are colour-sized, NaN = empty.
#[derive(Debug, Clone)]
pub struct FusionOutput {
    /// H1 points (depth camera frame) with H6 colours (black where the colour is not
    /// trusted, see [`FusionOutput::color_on_depth_valid`]).
    pub cloud: PointCloud,
    /// Row-major depth pixel index of every cloud point.
    pub cloud_pixels: Vec<u32>,
    /// H2 samples in the colour image (`point` indexes `cloud`).
    pub samples: Vec<ColorSample>,
    /// H7 z-buffer (sparse: one sample per pixel at most).
    pub zbuffer: Image<f32>,
    /// H3 nearest fill of the z-buffer.
    pub nearest: Image<f32>,
    /// H3 Delaunay-linear (when [`FusionOptions::linear`]).
    pub linear: Option<Image<f32>>,
    /// H8 hole mask (colour-sized).
    pub hole_mask: Image<bool>,
    /// H3 nearest with H8's holes filled from the plane.
    pub filled: Image<f32>,
    /// H3 linear with H8's holes filled from the plane (only for
    /// [`MeshSource::LinearFilled`] when a plane was found).
    pub linear_filled: Option<Image<f32>>,
    /// Pixels the plane filled in the depth that H4 meshed ([`FusionOutput::meshed_depth`]).
    pub mesh_filled_pixels: usize,
    /// H6 colour on the depth grid.
    pub color_on_depth: Image<[u8; 3]>,
    /// H6 validity per depth pixel.
    pub color_on_depth_valid: Image<bool>,
    /// H4 mesh (colour camera frame).
    pub mesh: Mesh,
    /// H5: `mesh` without stretched faces.
    pub mesh_clean: Mesh,
    /// Counts and timings.
    pub summary: FusionSummary,
}

impl FusionOutput {
    /// The colour-frame depth H4 meshed for `source` (the [`FusionOptions::mesh_source`] of
    /// the run), with the same fallbacks as the run; for [`MeshSource::DepthGrid`] (which
    /// meshes the samples, not an image) the nearest fill, the depth it is closest to.
    pub fn meshed_depth(&self, source: MeshSource) -> &Image<f32> {
        match (source, &self.linear_filled) {
            (MeshSource::Nearest | MeshSource::DepthGrid, _) => &self.nearest,
            (MeshSource::Filled, _) => &self.filled,
            (MeshSource::LinearFilled, Some(d)) => d,
            (MeshSource::Linear | MeshSource::LinearFilled, _) => {
                self.linear.as_ref().unwrap_or(&self.nearest)
            }
        }
    }
}

/// The sample spacing of a rig in colour pixels (see the module docs).
pub fn sample_spacing_px(rig: &Rig) -> f32 {
    let sx = rig.color.intrinsics.fx / rig.depth.intrinsics.fx;
    let sy = rig.color.intrinsics.fy / rig.depth.intrinsics.fy;
    (sx * sy).sqrt() as f32
}

/// The coverage radius for `rig` and `options` (see the module docs).
pub fn coverage_radius_px(rig: &Rig, options: &FusionOptions) -> f32 {
    (options.hole_radius_factor * sample_spacing_px(rig)).max(MIN_COVERAGE_RADIUS_PX)
}

/// The coverage radius of [`coverage_radius_px`] once the rig's sample spacing and the radius
/// are checked against [`MAX_SAMPLE_SPACING_PX`] and [`MAX_COVERAGE_RADIUS_PX`]: every run
/// (CPU and GPU) calls this before any table is built or any pixel visited.
///
/// Errors, each naming the value, the limit and the fix: [`GeometryError::InvalidParameter`]
/// for a rig whose focal lengths give a spacing above [`MAX_SAMPLE_SPACING_PX`],
/// [`GeometryError::InvalidInput`] for a hole radius factor that is not positive or gives a
/// radius above [`MAX_COVERAGE_RADIUS_PX`].
pub fn checked_coverage_radius_px(
    rig: &Rig,
    options: &FusionOptions,
) -> Result<f32, GeometryError> {
    let spacing = sample_spacing_px(rig);
    if !(spacing <= MAX_SAMPLE_SPACING_PX) {
        return Err(GeometryError::InvalidParameter(format!(
            "the rig's cameras give {spacing} colour pixels between neighbouring depth samples \
             (colour fx, fy = {}, {}; depth fx, fy = {}, {}), more than the {MAX_SAMPLE_SPACING_PX} \
             a fusion rig can have; focal lengths must be in pixels (a Kinect v2 depth camera has \
             fx ≈ 365), check the rig file",
            rig.color.intrinsics.fx,
            rig.color.intrinsics.fy,
            rig.depth.intrinsics.fx,
            rig.depth.intrinsics.fy
        )));
    }
    let factor = options.hole_radius_factor;
    if !(factor.is_finite() && factor > 0.0) {
        return Err(GeometryError::InvalidInput(format!(
            "the hole radius factor must be a positive number, got {factor}"
        )));
    }
    let radius = coverage_radius_px(rig, options);
    if !(radius <= MAX_COVERAGE_RADIUS_PX) {
        return Err(GeometryError::InvalidInput(format!(
            "hole radius {factor} × sample spacing {spacing:.2} px = a coverage radius of \
             {radius:.1} px, above the limit of {MAX_COVERAGE_RADIUS_PX} px; use a hole radius \
             of at most {:.2} with this rig",
            MAX_COVERAGE_RADIUS_PX / spacing
        )));
    }
    Ok(radius)
}

/// How far H8 grows the hole cores back: `coverage radius - spacing / 2` (see [`HoleMasker`]).
pub fn hole_grow_px(rig: &Rig, options: &FusionOptions) -> f32 {
    (coverage_radius_px(rig, options) - 0.5 * sample_spacing_px(rig)).max(0.0)
}

/// Checks a frame against its rig before any stage runs (the CPU pipeline and `fusion-gpu`
/// share it) and returns the number of valid depth samples (within
/// [`FusionOptions::depth_range`]).
///
/// Errors: [`GeometryError::InvalidParameter`] for an invalid rig or a coverage radius out of
/// bounds ([`checked_coverage_radius_px`]), [`GeometryError::SizeMismatch`] when an image does
/// not match its camera, [`GeometryError::InvalidInput`] when no depth pixel has a sample.
pub fn check_inputs(
    rig: &Rig,
    depth: &Image<f32>,
    color: &Image<[u8; 3]>,
    options: &FusionOptions,
) -> Result<usize, GeometryError> {
    rig.validate()?;
    checked_coverage_radius_px(rig, options)?;
    depth.expect_size("depth image", rig.depth.width, rig.depth.height)?;
    color.expect_size("colour image", rig.color.width, rig.color.height)?;
    let range = options.depth_range;
    let valid_depth_pixels = depth.data().iter().filter(|&&z| range.contains(z)).count();
    if valid_depth_pixels == 0 && !range.is_all() {
        return Err(GeometryError::InvalidInput(format!(
            "the {}x{} depth image has no sample within the depth range {range}; widen the range",
            depth.width(),
            depth.height()
        )));
    }
    if valid_depth_pixels == 0 {
        return Err(GeometryError::InvalidInput(format!(
            "the {}x{} depth image has no valid sample (all NaN, zero, negative or infinite); \
             check the depth file and its units",
            depth.width(),
            depth.height()
        )));
    }
    Ok(valid_depth_pixels)
}
