//! H6 (`color_on_depth.wgsl`): the colour image sampled (bilinear) at every depth pixel's
//! projection, with the occlusion test against H3's nearest fill.

use bytemuck::{Pod, Zeroable};

use super::{PerSlot, Shader, Stage, dispatch, write_uniform};
use crate::frame::{FrameBuffers, TableRefs, Work};
use crate::gpu::Gpu;
use crate::shaders;

/// `params`: [`Params`].
pub(crate) const PARAMS: u32 = 0;
/// `samples`: H2's samples.
pub(crate) const SAMPLES: u32 = 1;
/// `color`: the colour image, packed RGB bytes.
pub(crate) const COLOR: u32 = 2;
/// `dense`: H3's nearest fill (occlusion test).
pub(crate) const DENSE: u32 = 3;
/// `rgba`: colour and validity per depth pixel (output).
pub(crate) const RGBA: u32 = 4;

/// The shader and its bindings.
pub(crate) const SHADER: Shader = Shader {
    file: "color_on_depth.wgsl",
    source: shaders::COLOR_ON_DEPTH,
    entry_points: &["main"],
    bindings: &[
        ("params", PARAMS),
        ("samples", SAMPLES),
        ("color", COLOR),
        ("dense", DENSE),
        ("rgba", RGBA),
    ],
};

/// The WGSL's `Params`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct Params {
    /// `[colour width, colour height, depth pixels, row stride]`.
    pub size: [u32; 4],
    /// `[tolerance, 1 = test on / 0 = off, 0, 0]`.
    pub occlusion: [f32; 4],
    /// Always zero (see `keep()` in the shaders).
    pub opaque: [u32; 4],
}

/// H6: its pipeline, uniform and a bind group per frame slot.
pub(crate) struct ColorOnDepth {
    pipeline: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    groups: PerSlot<wgpu::BindGroup>,
}

impl ColorOnDepth {
    pub(crate) fn boxed(gpu: &Gpu) -> Box<dyn Stage> {
        Box::new(Self {
            pipeline: super::pipeline(&gpu.device, &SHADER, "main"),
            params: gpu.uniform::<Params>("H6 params"),
            groups: PerSlot::default(),
        })
    }
}

impl Stage for ColorOnDepth {
    fn runs(&self, work: &Work<'_>) -> bool {
        work.stages.is_some() && work.color
    }

    fn bind(&mut self, gpu: &Gpu, slot: usize, frame: &FrameBuffers, _: &TableRefs<'_>) {
        let group = gpu.bind(
            &self.pipeline,
            &[
                (PARAMS, &self.params),
                (SAMPLES, &frame.samples),
                (COLOR, &frame.color),
                (DENSE, &frame.nearest),
                (RGBA, &frame.rgba),
            ],
        );
        self.groups.set(slot, group);
    }

    fn encode(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass<'_>, slot: usize, work: &Work<'_>) {
        let tolerance = work.stages.and_then(|s| s.occlusion_tolerance);
        let (tol, on) = tolerance.map_or((0.0, 0.0), |t| (t, 1.0));
        let (cw, ch) = work.color_size;
        let grid = gpu.grid(work.depth_pixels);
        let params = Params {
            size: [cw, ch, work.depth_pixels, grid.stride],
            occlusion: [tol, on, 0.0, 0.0],
            opaque: [0; 4],
        };
        write_uniform(gpu, &self.params, &params);
        dispatch(pass, &self.pipeline, self.groups.get(slot), grid);
    }
}
