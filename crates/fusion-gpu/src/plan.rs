//! The public description of a frame's work and its results: [`FramePlan`] (whose later
//! stages take the CPU pipeline's own parameters, `geometry::fusion::PixelParams`) and
//! [`GpuFrame`] (re-exported at the crate root).

use geometry::Image;
use geometry::fusion::PixelParams;

/// What a frame runs: H1 + H2 + H7 always, the later stages when `stages` is given.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FramePlan {
    /// H3 nearest fill, H8 hole mask and (with a colour image) H6 with these parameters (those
    /// of the CPU stages, `PixelParams::new`; its `zbuffer` switch is the CPU's alone, the GPU
    /// always z-buffers); `None`: H1 + H2 + H7 only.
    pub stages: Option<PixelParams>,
    /// Also copy back H1's points and H2's samples (for parity checks; costs read-back time).
    pub read_intermediates: bool,
}

impl FramePlan {
    /// H1's depth range: that of `stages`, every sample without them (the per-pixel engine,
    /// `PerPixel for FusionContext`, always passes its request's own).
    pub fn depth_range(&self) -> geometry::fusion::DepthRange {
        self.stages.map_or(geometry::fusion::DepthRange::ALL, |p| p.depth_range)
    }
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
