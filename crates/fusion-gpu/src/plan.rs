//! The public description of a frame's work and its results: [`StageOptions`], [`FramePlan`]
//! and [`GpuFrame`] (re-exported at the crate root).

use geometry::Image;

use crate::error::GpuError;

/// The stages after H7 and their parameters (the same meaning as the CPU twins' arguments).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StageOptions {
    /// H3 nearest fill: disc radius in colour pixels (`geometry::fusion::nearest_fill`).
    pub nearest_radius_px: f32,
    /// H3 nearest fill: relative depth step that separates surfaces.
    pub depth_jump: f32,
    /// H8 hole mask: coverage radius in colour pixels (`geometry::fusion::HoleMasker`).
    pub hole_radius_px: f32,
    /// H8 hole mask: how far hole cores grow back, colour pixels (`HoleMasker`'s `grow`).
    pub hole_grow_px: f32,
    /// H6: a depth pixel's colour is dropped when its `z` exceeds the colour camera's H3 depth
    /// there by more than this fraction (`geometry::fusion::color_on_depth`); `None` samples
    /// every pixel without an occlusion test.
    pub occlusion_tolerance: Option<f32>,
}

impl StageOptions {
    /// Checks the three radii against `geometry::fusion::MAX_COVERAGE_RADIUS_PX` before their
    /// lookup tables are built (the disc table grows with the square of the radius).
    ///
    /// Error: [`GpuError::Input`] naming the radius and the limit.
    pub fn check(&self) -> Result<(), GpuError> {
        let limit = geometry::fusion::MAX_COVERAGE_RADIUS_PX;
        for (what, r) in [
            ("H3 nearest radius", self.nearest_radius_px),
            ("H8 coverage radius", self.hole_radius_px),
            ("H8 growth radius", self.hole_grow_px),
        ] {
            if !(0.0..=limit).contains(&r) {
                return Err(GpuError::Input(geometry::GeometryError::InvalidInput(format!(
                    "{what} {r} px is outside 0..={limit} px"
                ))));
            }
        }
        Ok(())
    }
}

/// What a frame runs: H1 + H2 + H7 always, the later stages when `stages` is given.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FramePlan {
    /// H3 nearest fill, H8 hole mask and (with a colour image) H6; `None`: H1 + H2 + H7 only.
    pub stages: Option<StageOptions>,
    /// Also copy back H1's points and H2's samples (for parity checks; costs read-back time).
    pub read_intermediates: bool,
}

/// One frame's results read back from the GPU.
#[derive(Debug, Clone, PartialEq)]
pub struct GpuFrame {
    /// H7: colour-sized z-buffer, smallest colour-frame `z` per pixel (metres), and
    /// [`geometry::fusion::ZBUFFER_EMPTY`] (a NaN with all bits set) where no sample landed.
    pub zbuffer: Image<f32>,
    /// H1 when asked for: one entry per depth pixel, `[X, Y, Z, 1]` (depth camera frame,
    /// metres) or all zero for no point.
    pub points: Option<Vec<[f32; 4]>>,
    /// H2 when asked for: one entry per depth pixel, `[u, v, z_color, 1]` when in front of
    /// the colour camera (the pixel may lie outside the colour image), all zero otherwise.
    pub samples: Option<Vec<[f32; 4]>>,
    /// H3 nearest fill of the colour grid (colour-frame `z`, `ZBUFFER_EMPTY` = none).
    pub nearest: Option<Image<f32>>,
    /// H8 disocclusion hole mask on the colour grid.
    pub holes: Option<Image<bool>>,
    /// H6 colour on the depth grid and its validity (black where invalid).
    pub color_on_depth: Option<(Image<[u8; 3]>, Image<bool>)>,
}
