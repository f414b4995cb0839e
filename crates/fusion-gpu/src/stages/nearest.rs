//! H3 nearest fill (`nearest_fill.wgsl`): every colour pixel takes the nearest z-buffered
//! sample on the nearest surface within the disc of `geometry::fusion::disc_offsets`.

use bytemuck::{Pod, Zeroable};

use super::Shader;
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

/// The stage's pipeline.
pub(crate) fn pipeline(device: &wgpu::Device) -> wgpu::ComputePipeline {
    super::pipeline(device, &SHADER, "main")
}
