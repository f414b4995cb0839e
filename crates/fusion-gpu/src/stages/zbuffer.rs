//! H7 (`zbuffer.wgsl`): `clear` fills the z-buffer with the empty value, `scatter` keeps the
//! smallest `z` per colour pixel (`atomicMin` on the f32 bits).

use super::{Shader, SizeParams};
use crate::shaders;

/// `params`: [`Params`].
pub(crate) const PARAMS: u32 = 0;
/// `samples`: H2's samples (`scatter` only).
pub(crate) const SAMPLES: u32 = 1;
/// `zbuffer`: the colour-sized z-buffer (output).
pub(crate) const ZBUFFER: u32 = 2;

/// The shader and its bindings.
pub(crate) const SHADER: Shader = Shader {
    file: "zbuffer.wgsl",
    source: shaders::ZBUFFER,
    entry_points: &["clear", "scatter"],
    bindings: &[("params", PARAMS), ("samples", SAMPLES), ("zbuffer", ZBUFFER)],
};

/// `size = [colour width, colour height, items, row stride]` (items: colour pixels for
/// `clear`, depth pixels for `scatter`).
pub(crate) type Params = SizeParams;

/// The stage's two pipelines.
pub(crate) struct Pipelines {
    pub clear: wgpu::ComputePipeline,
    pub scatter: wgpu::ComputePipeline,
}

impl Pipelines {
    pub(crate) fn new(device: &wgpu::Device) -> Self {
        Self {
            clear: super::pipeline(device, &SHADER, "clear"),
            scatter: super::pipeline(device, &SHADER, "scatter"),
        }
    }
}
