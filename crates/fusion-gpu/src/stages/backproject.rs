//! H1 back-projection (`backproject.wgsl`): depth pixels → points in the depth camera frame.

use super::{PerSlot, Shader, SizeParams, Stage, dispatch, write_uniform};
use crate::frame::{FrameBuffers, TableRefs, Work};
use crate::gpu::Gpu;
use crate::shaders;

/// `params`: [`Params`].
pub(crate) const PARAMS: u32 = 0;
/// `depth`: the depth image, metres.
pub(crate) const DEPTH: u32 = 1;
/// `rays`: the depth ray table.
pub(crate) const RAYS: u32 = 2;
/// `points`: one `[X, Y, Z, valid]` per depth pixel (output).
pub(crate) const POINTS: u32 = 3;

/// The shader and its bindings.
pub(crate) const SHADER: Shader = Shader {
    file: "backproject.wgsl",
    source: shaders::BACKPROJECT,
    entry_points: &["main"],
    bindings: &[("params", PARAMS), ("depth", DEPTH), ("rays", RAYS), ("points", POINTS)],
};

/// `size = [depth pixels, row stride, near end bits, far end bits]` (the depth range's `f32`
/// ends as bits, [`geometry::fusion::DepthRange`]).
pub(crate) type Params = SizeParams;

/// H1: its pipeline, uniform and a bind group per frame slot.
pub(crate) struct Backproject {
    pipeline: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    groups: PerSlot<wgpu::BindGroup>,
}

impl Backproject {
    pub(crate) fn boxed(gpu: &Gpu) -> Box<dyn Stage> {
        Box::new(Self {
            pipeline: super::pipeline(&gpu.device, &SHADER, "main"),
            params: gpu.uniform::<Params>("H1 params"),
            groups: PerSlot::default(),
        })
    }
}

impl Stage for Backproject {
    fn runs(&self, _: &Work<'_>) -> bool {
        true
    }

    fn bind(&mut self, gpu: &Gpu, slot: usize, frame: &FrameBuffers, tables: &TableRefs<'_>) {
        let group = gpu.bind(
            &self.pipeline,
            &[
                (PARAMS, &self.params),
                (DEPTH, &frame.depth),
                (RAYS, &tables.depth_rays.buffer),
                (POINTS, &frame.points),
            ],
        );
        self.groups.set(slot, group);
    }

    fn encode(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass<'_>, slot: usize, work: &Work<'_>) {
        let grid = gpu.grid(work.depth_pixels);
        let r = work.depth_range;
        let size = [work.depth_pixels, grid.stride, r.min_m.to_bits(), r.max_m.to_bits()];
        write_uniform(gpu, &self.params, &Params { size });
        dispatch(pass, &self.pipeline, self.groups.get(slot), grid);
    }
}
