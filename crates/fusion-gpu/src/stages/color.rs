//! H6 (`color_on_depth.wgsl`): the colour image sampled (bilinear) at every depth pixel's
//! projection, with the occlusion test against H3's nearest fill.

use bytemuck::{Pod, Zeroable};

use super::Shader;
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

/// The stage's pipeline.
pub(crate) fn pipeline(device: &wgpu::Device) -> wgpu::ComputePipeline {
    super::pipeline(device, &SHADER, "main")
}
