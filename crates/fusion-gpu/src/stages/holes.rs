//! H8 hole mask (`hole_mask.wgsl`), `geometry::fusion::HoleMasker` in four kernels: `coverage`
//! (occupied pixels dilated by the coverage disc), `extents` (per row and column, the span of
//! covered pixels), `core_mask` (uncovered pixels inside both spans) and `grow` (cores dilated
//! by the growth disc, minus occupied pixels).

use bytemuck::{Pod, Zeroable};

use super::Shader;
use crate::shaders;

/// `params`: [`Params`].
pub(crate) const PARAMS: u32 = 0;
/// `zbuffer`: H7's z-buffer.
pub(crate) const ZBUFFER: u32 = 1;
/// `half_width`: half widths of the coverage disc per row offset.
pub(crate) const HALF_WIDTH: u32 = 2;
/// `covered`: coverage per colour pixel.
pub(crate) const COVERED: u32 = 3;
/// `row_extent`: first and last covered column per row.
pub(crate) const ROW_EXTENT: u32 = 4;
/// `col_extent`: first and last covered row per column.
pub(crate) const COL_EXTENT: u32 = 5;
/// `core`: hole cores.
pub(crate) const CORE: u32 = 6;
/// `grow_half_width`: half widths of the growth disc.
pub(crate) const GROW_HALF_WIDTH: u32 = 7;
/// `holes`: the hole mask (output).
pub(crate) const HOLES: u32 = 8;

/// The shader and its bindings.
pub(crate) const SHADER: Shader = Shader {
    file: "hole_mask.wgsl",
    source: shaders::HOLE_MASK,
    entry_points: &["extents", "coverage", "core_mask", "grow"],
    bindings: &[
        ("params", PARAMS),
        ("zbuffer", ZBUFFER),
        ("half_width", HALF_WIDTH),
        ("covered", COVERED),
        ("row_extent", ROW_EXTENT),
        ("col_extent", COL_EXTENT),
        ("core", CORE),
        ("grow_half_width", GROW_HALF_WIDTH),
        ("holes", HOLES),
    ],
};

/// Workgroup size of the per-row / per-column `extents` kernel (its `@workgroup_size`): only
/// `width + height` invocations, each a long loop, so small groups spread them over more cores.
pub(crate) const EXTENT_WORKGROUP_SIZE: u32 = 64;

/// The WGSL's `Params`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct Params {
    /// `[colour width, colour height, items, row stride]` (items: `width + height` for
    /// `extents`, colour pixels for the others).
    pub size: [u32; 4],
    /// `[coverage radius, growth radius, 0, 0]` in whole pixels (last half-width index).
    pub radius: [u32; 4],
}

/// The stage's four pipelines.
pub(crate) struct Pipelines {
    pub extents: wgpu::ComputePipeline,
    pub coverage: wgpu::ComputePipeline,
    pub core: wgpu::ComputePipeline,
    pub grow: wgpu::ComputePipeline,
}

impl Pipelines {
    pub(crate) fn new(device: &wgpu::Device) -> Self {
        Self {
            extents: super::pipeline(device, &SHADER, "extents"),
            coverage: super::pipeline(device, &SHADER, "coverage"),
            core: super::pipeline(device, &SHADER, "core_mask"),
            grow: super::pipeline(device, &SHADER, "grow"),
        }
    }
}
