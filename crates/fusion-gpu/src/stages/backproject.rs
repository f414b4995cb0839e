//! H1 back-projection (`backproject.wgsl`): depth pixels → points in the depth camera frame.

use super::{Shader, SizeParams};
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

/// `size = [depth pixels, row stride, 0, 0]`.
pub(crate) type Params = SizeParams;

/// The stage's pipeline.
pub(crate) fn pipeline(device: &wgpu::Device) -> wgpu::ComputePipeline {
    super::pipeline(device, &SHADER, "main")
}
