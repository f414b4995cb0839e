//! H3 nearest fill (`nearest_fill.wgsl`): every colour pixel takes the nearest z-buffered
//! sample on the nearest surface within the disc of `geometry::fusion::disc_offsets`.

use bytemuck::{Pod, Zeroable};

use super::{PerSlot, Shader, Stage, dispatch, write_uniform};
use crate::frame::{FrameBuffers, TableRefs, Work};
use crate::gpu::Gpu;
use crate::shaders;

/// `params`: [`Params`].
pub(crate) const PARAMS: u32 = 0;
/// `zbuffer`: H7's z-buffer.
pub(crate) const ZBUFFER: u32 = 1;
/// `offsets`: the disc offsets, in search order.
pub(crate) const OFFSETS: u32 = 2;
/// `dense`: the filled colour-frame depth (output).
pub(crate) const DENSE: u32 = 3;

/// The shader and its bindings.
pub(crate) const SHADER: Shader = Shader {
    file: "nearest_fill.wgsl",
    source: shaders::NEAREST_FILL,
    entry_points: &["main"],
    bindings: &[("params", PARAMS), ("zbuffer", ZBUFFER), ("offsets", OFFSETS), ("dense", DENSE)],
};

/// The WGSL's `Params`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct Params {
    /// `[colour width, colour height, colour pixels, row stride]`.
    pub size: [u32; 4],
    /// `[number of disc offsets, 0, 0, 0]`.
    pub offsets: [u32; 4],
    /// `[depth jump, 0, 0, 0]`.
    pub jump: [f32; 4],
}

/// H3 nearest: its pipeline, uniform and a bind group per frame slot.
pub(crate) struct Nearest {
    pipeline: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    groups: PerSlot<wgpu::BindGroup>,
}

impl Nearest {
    pub(crate) fn boxed(gpu: &Gpu) -> Box<dyn Stage> {
        Box::new(Self {
            pipeline: super::pipeline(&gpu.device, &SHADER, "main"),
            params: gpu.uniform::<Params>("H3 params"),
            groups: PerSlot::default(),
        })
    }
}

impl Stage for Nearest {
    fn runs(&self, work: &Work<'_>) -> bool {
        work.stages.is_some()
    }

    fn bind(&mut self, gpu: &Gpu, slot: usize, frame: &FrameBuffers, tables: &TableRefs<'_>) {
        let group = gpu.bind(
            &self.pipeline,
            &[
                (PARAMS, &self.params),
                (ZBUFFER, &frame.zbuffer),
                (OFFSETS, &tables.offsets.buffer),
                (DENSE, &frame.nearest),
            ],
        );
        self.groups.set(slot, group);
    }

    fn encode(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass<'_>, slot: usize, work: &Work<'_>) {
        let jump = work.stages.map_or(0.0, |s| s.depth_jump);
        let (cw, ch) = work.color_size;
        let m = work.color_pixels();
        let grid = gpu.grid(m);
        let params = Params {
            size: [cw, ch, m, grid.stride],
            offsets: [work.tables.offsets.len, 0, 0, 0],
            jump: [jump, 0.0, 0.0, 0.0],
        };
        write_uniform(gpu, &self.params, &params);
        dispatch(pass, &self.pipeline, self.groups.get(slot), grid);
    }
}
