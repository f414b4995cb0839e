//! The GPU stages, one module each: its WGSL ([`crate::shaders`]), entry points, named binding
//! numbers (checked against the WGSL's `@binding(n)` declarations by naga reflection in this
//! module's test), parameter struct (the WGSL's uniform, field for field) and the stage type.
//!
//! Each stage type owns its pipelines, its uniform buffers, its bind groups (one per frame
//! slot) and the buffers only it uses, created from the device ([`Gpu`]), and implements
//! [`Stage`]: `bind` (a slot's shared buffers and the lookup tables of [`crate::frame`]) and
//! `encode` (writes its uniforms, records its dispatches). A frame is the [`FRAME`] list in
//! dispatch order, so adding a stage touches its file here, its WGSL (and that file's line in
//! [`crate::shaders`]) and its entry in [`FRAME`]. The H8 plane fill ([`plane::PlaneFill`],
//! after the CPU's plane fit) and the Kinect v2 decoder ([`decode::Decode`], before H1 on raw
//! frames) are called on their own.
//!
//! Dependencies point down only: the stages use `crate::gpu`, `crate::frame`, `crate::plan`,
//! `crate::shaders` and `crate::error`, never the context (`tests/module_cycles.rs` fails on
//! an import cycle between the crate's modules).

pub(crate) mod backproject;
pub(crate) mod color;
pub(crate) mod decode;
pub(crate) mod holes;
pub(crate) mod nearest;
pub(crate) mod plane;
pub(crate) mod project;
pub(crate) mod zbuffer;

use bytemuck::{Pod, Zeroable};

use crate::frame::{FrameBuffers, TableRefs, Work};
use crate::gpu::{Gpu, Grid};

/// A stage of a frame (see the module docs).
pub(crate) trait Stage: Send + Sync {
    /// Whether the stage runs on a frame of `work` (H3, H8 and H6 only with stages, H6 only
    /// with a colour image).
    fn runs(&self, work: &Work<'_>) -> bool;
    /// (Re)creates the stage's bind groups, and buffers of its own, for frame slot `slot`;
    /// called when the slot's buffers or the tables are new, before any `encode` on it.
    fn bind(&mut self, gpu: &Gpu, slot: usize, frame: &FrameBuffers, tables: &TableRefs<'_>);
    /// Writes the stage's uniforms for `work` and records its dispatches on slot `slot`.
    fn encode(&self, gpu: &Gpu, pass: &mut wgpu::ComputePass<'_>, slot: usize, work: &Work<'_>);
}

/// A stage of [`FRAME`]: its shader (checked against the WGSL without a device) and its
/// constructor.
pub(crate) struct Entry {
    /// Read by the tests below.
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) shader: &'static Shader,
    pub(crate) new: fn(&Gpu) -> Box<dyn Stage>,
}

/// The stages of a frame in dispatch order: the one list a new stage joins.
pub(crate) const FRAME: [Entry; 6] = [
    Entry { shader: &backproject::SHADER, new: backproject::Backproject::boxed },
    Entry { shader: &project::SHADER, new: project::Project::boxed },
    Entry { shader: &zbuffer::SHADER, new: zbuffer::ZBuffer::boxed },
    Entry { shader: &nearest::SHADER, new: nearest::Nearest::boxed },
    Entry { shader: &holes::SHADER, new: holes::HoleMask::boxed },
    Entry { shader: &color::SHADER, new: color::ColorOnDepth::boxed },
];

/// Every shader: those of [`FRAME`], the plane fill's and the decoder's three.
#[cfg(test)]
fn all() -> impl Iterator<Item = &'static Shader> {
    FRAME.iter().map(|e| e.shader).chain([
        &plane::SHADER,
        &decode::STAGE1,
        &decode::FILTER,
        &decode::EDGE,
    ])
}

/// Per-slot state of a stage, set by [`Stage::bind`].
pub(crate) struct PerSlot<T>(Vec<Option<T>>);

impl<T> Default for PerSlot<T> {
    fn default() -> Self {
        Self(Vec::new())
    }
}

impl<T> PerSlot<T> {
    /// Sets slot `slot`'s state.
    pub(crate) fn set(&mut self, slot: usize, value: T) {
        if self.0.len() <= slot {
            self.0.resize_with(slot + 1, || None);
        }
        self.0[slot] = Some(value);
    }

    /// Slot `slot`'s state. The context binds a slot before it encodes a frame on it, so a
    /// missing one is a bug of this crate, not of its input.
    pub(crate) fn get(&self, slot: usize) -> &T {
        match self.0.get(slot) {
            Some(Some(v)) => v,
            _ => panic!("fusion-gpu: a stage encoded on frame slot {slot} before it was bound"),
        }
    }
}

/// Records one dispatch of `pipe` with `group` over `grid`.
pub(crate) fn dispatch(
    pass: &mut wgpu::ComputePass<'_>,
    pipe: &wgpu::ComputePipeline,
    group: &wgpu::BindGroup,
    grid: Grid,
) {
    pass.set_pipeline(pipe);
    pass.set_bind_group(0, group, &[]);
    pass.dispatch_workgroups(grid.x, grid.y, 1);
}

/// Writes a stage's uniform.
pub(crate) fn write_uniform<T: Pod>(gpu: &Gpu, buffer: &wgpu::Buffer, value: &T) {
    gpu.queue.write_buffer(buffer, 0, bytemuck::bytes_of(value));
}

/// A stage's shader: file name, WGSL source, entry points and its bindings by name (the WGSL
/// variable name and the constant of the stage module that holds the number).
pub(crate) struct Shader {
    pub file: &'static str,
    pub source: &'static str,
    /// Read by the tests below (checked against the WGSL) and by [`pipeline`] in debug builds.
    #[cfg_attr(not(test), allow(dead_code))]
    pub entry_points: &'static [&'static str],
    /// Read by the tests below: every `(WGSL name, constant)` must match the declaration.
    #[cfg_attr(not(test), allow(dead_code))]
    pub bindings: &'static [(&'static str, u32)],
}

/// The uniform of the stages that only need sizes: `size = [a, b, count, row stride]` (see
/// each shader's `Params`).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct SizeParams {
    pub size: [u32; 4],
}

/// The compute pipeline of `entry` in `shader` (bind group layout derived from the WGSL).
pub(crate) fn pipeline(
    device: &wgpu::Device,
    shader: &Shader,
    entry: &str,
) -> wgpu::ComputePipeline {
    debug_assert!(shader.entry_points.contains(&entry), "{}: {entry}", shader.file);
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(shader.file),
        source: wgpu::ShaderSource::Wgsl(shader.source.into()),
    });
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout: None,
        module: &module,
        entry_point: Some(entry),
        compilation_options: Default::default(),
        cache: None,
    })
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;

    /// `name → binding` of every `@group(0)` resource the WGSL declares (naga reflection).
    fn wgsl_bindings(shader: &Shader) -> BTreeMap<String, u32> {
        let module = naga::front::wgsl::parse_str(shader.source)
            .unwrap_or_else(|e| panic!("{}: {}", shader.file, e.emit_to_string(shader.source)));
        module
            .global_variables
            .iter()
            .filter_map(|(_, v)| {
                let b = v.binding.as_ref()?;
                assert_eq!(b.group, 0, "{}: only group 0 is bound", shader.file);
                Some((v.name.clone().expect("bound globals are named"), b.binding))
            })
            .collect()
    }

    #[test]
    fn binding_constants_match_the_wgsl_declarations() {
        for shader in all() {
            let declared = wgsl_bindings(shader);
            let ours: BTreeMap<String, u32> =
                shader.bindings.iter().map(|&(n, b)| (n.to_string(), b)).collect();
            assert_eq!(ours.len(), shader.bindings.len(), "{}: a name twice", shader.file);
            assert_eq!(ours, declared, "{}: binding constants differ from the WGSL", shader.file);
        }
    }

    #[test]
    fn entry_points_exist_and_every_shader_file_has_a_stage() {
        for shader in all() {
            let module = naga::front::wgsl::parse_str(shader.source).expect("parses");
            let names: Vec<&str> = module.entry_points.iter().map(|e| e.name.as_str()).collect();
            for entry in shader.entry_points {
                assert!(names.contains(entry), "{}: no entry point {entry}", shader.file);
            }
        }
        let mut ours: Vec<&str> = all().map(|s| s.file).collect();
        let mut files: Vec<&str> = crate::shaders::ALL.iter().map(|(f, _)| *f).collect();
        ours.sort();
        files.sort();
        assert_eq!(ours, files);
    }
}
