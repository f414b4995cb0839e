//! H7 (`zbuffer.wgsl`): `clear` fills the z-buffer with the empty value, `scatter` keeps the
//! smallest `z` per colour pixel (`atomicMin` on the f32 bits). Without the clear
//! ([`crate::frame::Work::accumulate_zbuffer`]) the scatter adds a frame's samples to the
//! z-buffer of the one before: the z-buffer across the sensors of a rig.

use super::{PerSlot, Shader, SizeParams, Stage, dispatch, write_uniform};
use crate::frame::{FrameBuffers, TableRefs, Work};
use crate::gpu::Gpu;
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

/// H7: `clear` then `scatter`, each with its uniform, bind groups per frame slot.
pub(crate) struct ZBuffer {
    clear: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
    clear_params: wgpu::Buffer,
    scatter_params: wgpu::Buffer,
    groups: PerSlot<[wgpu::BindGroup; 2]>,
}

impl ZBuffer {
    pub(crate) fn boxed(gpu: &Gpu) -> Box<dyn Stage> {
        Box::new(Self {
            clear: super::pipeline(&gpu.device, &SHADER, "clear"),
            scatter: super::pipeline(&gpu.device, &SHADER, "scatter"),
            clear_params: gpu.uniform::<Params>("H7 clear params"),
            scatter_params: gpu.uniform::<Params>("H7 scatter params"),
            groups: PerSlot::default(),
        })
    }
}

impl Stage for ZBuffer {
    fn runs(&self, _: &Work<'_>) -> bool {
        true
    }

    fn bind(&mut self, gpu: &Gpu, slot: usize, frame: &FrameBuffers, _: &TableRefs<'_>) {
        let clear =
            gpu.bind(&self.clear, &[(PARAMS, &self.clear_params), (ZBUFFER, &frame.zbuffer)]);
        let scatter = gpu.bind(
            &self.scatter,
            &[(PARAMS, &self.scatter_params), (SAMPLES, &frame.samples), (ZBUFFER, &frame.zbuffer)],
        );
        self.groups.set(slot, [clear, scatter]);
    }

    fn encode(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass<'_>, slot: usize, work: &Work<'_>) {
        let (cw, ch) = work.color_size;
        let (m, n) = (work.color_pixels(), work.depth_pixels);
        let (c, d) = (gpu.grid(m), gpu.grid(n));
        write_uniform(gpu, &self.clear_params, &Params { size: [cw, ch, m, c.stride] });
        write_uniform(gpu, &self.scatter_params, &Params { size: [cw, ch, n, d.stride] });
        let [clear, scatter] = self.groups.get(slot);
        if !work.accumulate_zbuffer {
            dispatch(pass, &self.clear, clear, c);
        }
        dispatch(pass, &self.scatter, scatter, d);
    }
}
