//! H2 (`project.wgsl`): `X_c = R·X_d + T` and the colour camera's projection with distortion.

use bytemuck::{Pod, Zeroable};
use geometry::fusion::ColorProjection;

use super::{PerSlot, Shader, Stage, dispatch, write_uniform};
use crate::frame::{FrameBuffers, TableRefs, Work};
use crate::gpu::Gpu;
use crate::shaders;

/// `proj`: [`Params`].
pub(crate) const PARAMS: u32 = 0;
/// `points`: H1's points.
pub(crate) const POINTS: u32 = 1;
/// `samples`: one `[u, v, z, valid]` per depth pixel (output).
pub(crate) const SAMPLES: u32 = 2;

/// The shader and its bindings.
pub(crate) const SHADER: Shader = Shader {
    file: "project.wgsl",
    source: shaders::PROJECT,
    entry_points: &["main"],
    bindings: &[("proj", PARAMS), ("points", POINTS), ("samples", SAMPLES)],
};

/// The WGSL's `Projection` uniform.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct Params {
    rows: [[f32; 4]; 3],
    k: [f32; 4],
    d0: [f32; 4],
    d1: [f32; 4],
    size: [u32; 4],
    /// Always zero (see `keep()` in the shaders).
    opaque: [u32; 4],
}

impl Params {
    /// The projection `proj` for `n` depth pixels dispatched with row stride `stride`.
    pub(crate) fn new(proj: &ColorProjection, n: u32, stride: u32) -> Self {
        let r = &proj.rotation;
        let t = &proj.translation;
        Self {
            rows: [[r[0], r[1], r[2], t[0]], [r[3], r[4], r[5], t[1]], [r[6], r[7], r[8], t[2]]],
            k: [proj.fx, proj.fy, proj.cx, proj.cy],
            d0: [proj.skew, proj.k1, proj.k2, proj.p1],
            d1: [proj.p2, proj.k3, 0.0, 0.0],
            size: [proj.width, proj.height, n, stride],
            opaque: [0; 4],
        }
    }
}

/// H2: its pipeline, uniform and a bind group per frame slot.
pub(crate) struct Project {
    pipeline: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    groups: PerSlot<wgpu::BindGroup>,
}

impl Project {
    pub(crate) fn boxed(gpu: &Gpu) -> Box<dyn Stage> {
        Box::new(Self {
            pipeline: super::pipeline(&gpu.device, &SHADER, "main"),
            params: gpu.uniform::<Params>("H2 params"),
            groups: PerSlot::default(),
        })
    }
}

impl Stage for Project {
    fn runs(&self, _: &Work<'_>) -> bool {
        true
    }

    fn bind(&mut self, gpu: &Gpu, slot: usize, frame: &FrameBuffers, _: &TableRefs<'_>) {
        let group = gpu.bind(
            &self.pipeline,
            &[(PARAMS, &self.params), (POINTS, &frame.points), (SAMPLES, &frame.samples)],
        );
        self.groups.set(slot, group);
    }

    fn encode(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass<'_>, slot: usize, work: &Work<'_>) {
        let grid = gpu.grid(work.depth_pixels);
        write_uniform(gpu, &self.params, &Params::new(work.proj, work.depth_pixels, grid.stride));
        dispatch(pass, &self.pipeline, self.groups.get(slot), grid);
    }
}
