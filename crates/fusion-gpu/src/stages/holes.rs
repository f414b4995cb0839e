//! H8 hole mask (`hole_mask.wgsl`), `geometry::fusion::HoleMasker` in four kernels: `coverage`
//! (occupied pixels dilated by the coverage disc), `extents` (per row and column, the span of
//! covered pixels), `core_mask` (uncovered pixels inside both spans) and `grow` (cores dilated
//! by the growth disc, minus occupied pixels).

use bytemuck::{Pod, Zeroable};

use super::{PerSlot, Shader, Stage, dispatch, write_uniform};
use crate::frame::{FrameBuffers, TableRefs, Work};
use crate::gpu::Gpu;
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

/// H8's mask: four pipelines, two uniforms (the per-line `extents` pass and the per-pixel
/// passes), and per frame slot the buffers only this stage uses and the four bind groups.
pub(crate) struct HoleMask {
    extents: wgpu::ComputePipeline,
    coverage: wgpu::ComputePipeline,
    core: wgpu::ComputePipeline,
    grow: wgpu::ComputePipeline,
    line_params: wgpu::Buffer,
    pixel_params: wgpu::Buffer,
    slots: PerSlot<Bound>,
}

/// A slot's own buffers (kept alive with the bind groups that name them) and bind groups in
/// dispatch order: coverage, extents, core, grow.
struct Bound {
    _buffers: [wgpu::Buffer; 4],
    groups: [wgpu::BindGroup; 4],
}

impl HoleMask {
    pub(crate) fn boxed(gpu: &Gpu) -> Box<dyn Stage> {
        let pipeline = |entry| super::pipeline(&gpu.device, &SHADER, entry);
        Box::new(Self {
            extents: pipeline("extents"),
            coverage: pipeline("coverage"),
            core: pipeline("core_mask"),
            grow: pipeline("grow"),
            line_params: gpu.uniform::<Params>("H8 extents params"),
            pixel_params: gpu.uniform::<Params>("H8 mask params"),
            slots: PerSlot::default(),
        })
    }
}

impl Stage for HoleMask {
    fn runs(&self, work: &Work<'_>) -> bool {
        work.stages.is_some()
    }

    fn bind(&mut self, gpu: &Gpu, slot: usize, frame: &FrameBuffers, tables: &TableRefs<'_>) {
        let (cw, ch) = (frame.color_size.0 as u64, frame.color_size.1 as u64);
        let m = cw * ch;
        let covered = gpu.storage("covered", m * 4);
        let row_extent = gpu.storage("row extents", ch * 8);
        let col_extent = gpu.storage("column extents", cw * 8);
        let core = gpu.storage("hole cores", m * 4);
        let pixel = &self.pixel_params;
        let groups = [
            gpu.bind(
                &self.coverage,
                &[
                    (PARAMS, pixel),
                    (ZBUFFER, &frame.zbuffer),
                    (HALF_WIDTH, &tables.half_widths.buffer),
                    (COVERED, &covered),
                ],
            ),
            gpu.bind(
                &self.extents,
                &[
                    (PARAMS, &self.line_params),
                    (COVERED, &covered),
                    (ROW_EXTENT, &row_extent),
                    (COL_EXTENT, &col_extent),
                ],
            ),
            gpu.bind(
                &self.core,
                &[
                    (PARAMS, pixel),
                    (COVERED, &covered),
                    (ROW_EXTENT, &row_extent),
                    (COL_EXTENT, &col_extent),
                    (CORE, &core),
                ],
            ),
            gpu.bind(
                &self.grow,
                &[
                    (PARAMS, pixel),
                    (ZBUFFER, &frame.zbuffer),
                    (CORE, &core),
                    (GROW_HALF_WIDTH, &tables.grow_half_widths.buffer),
                    (HOLES, &frame.holes),
                ],
            ),
        ];
        self.slots.set(slot, Bound { _buffers: [covered, row_extent, col_extent, core], groups });
    }

    fn encode(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass<'_>, slot: usize, work: &Work<'_>) {
        let (cw, ch) = work.color_size;
        let m = work.color_pixels();
        let t = &work.tables;
        let radius =
            [t.half_widths.len.saturating_sub(1), t.grow_half_widths.len.saturating_sub(1), 0, 0];
        let (px, line) = (gpu.grid(m), gpu.grid_sized(cw + ch, EXTENT_WORKGROUP_SIZE));
        write_uniform(
            gpu,
            &self.line_params,
            &Params { size: [cw, ch, cw + ch, line.stride], radius },
        );
        write_uniform(gpu, &self.pixel_params, &Params { size: [cw, ch, m, px.stride], radius });
        let [coverage, extents, core, grow] = &self.slots.get(slot).groups;
        dispatch(pass, &self.coverage, coverage, px);
        dispatch(pass, &self.extents, extents, line);
        dispatch(pass, &self.core, core, px);
        dispatch(pass, &self.grow, grow, px);
    }
}
