//! The GPU stages, one module each: its WGSL ([`crate::shaders`]), entry points, named binding
//! numbers (checked against the WGSL's `@binding(n)` declarations by naga reflection in this
//! module's test), parameter struct (the WGSL's uniform, field for field) and pipelines.
//!
//! | stage | module | shader | entry points |
//! | --- | --- | --- | --- |
//! | H1 back-projection | [`backproject`] | `backproject.wgsl` | `main` |
//! | H2 projection | [`project`] | `project.wgsl` | `main` |
//! | H7 z-buffer | [`zbuffer`] | `zbuffer.wgsl` | `clear`, `scatter` |
//! | H3 nearest fill | [`nearest`] | `nearest_fill.wgsl` | `main` |
//! | H8 hole mask | [`holes`] | `hole_mask.wgsl` | `extents`, `coverage`, `core_mask`, `grow` |
//! | H6 colour on depth | [`color`] | `color_on_depth.wgsl` | `main` |
//! | H8 plane fill | [`plane`] | `plane_fill.wgsl` | `main` |
//! | Kinect v2 depth decoding (stage 1, filter + stage 2, edge filter) | [`decode`] | `decode_stage1.wgsl`, `decode_filter.wgsl`, `decode_edge.wgsl` | `main` each |
//!
//! `FusionContext::submit` chains them for one frame, naming every binding by its constant.

pub(crate) mod backproject;
pub(crate) mod color;
pub(crate) mod decode;
pub(crate) mod holes;
pub(crate) mod nearest;
pub(crate) mod plane;
pub(crate) mod project;
pub(crate) mod zbuffer;

use bytemuck::{Pod, Zeroable};

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

/// Every stage's shader (for the binding test).
#[cfg(test)]
pub(crate) const ALL: [&Shader; 10] = [
    &backproject::SHADER,
    &project::SHADER,
    &zbuffer::SHADER,
    &nearest::SHADER,
    &holes::SHADER,
    &color::SHADER,
    &plane::SHADER,
    &decode::STAGE1,
    &decode::FILTER,
    &decode::EDGE,
];

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
        for shader in ALL {
            let declared = wgsl_bindings(shader);
            let ours: BTreeMap<String, u32> =
                shader.bindings.iter().map(|&(n, b)| (n.to_string(), b)).collect();
            assert_eq!(ours.len(), shader.bindings.len(), "{}: a name twice", shader.file);
            assert_eq!(ours, declared, "{}: binding constants differ from the WGSL", shader.file);
        }
    }

    #[test]
    fn entry_points_exist_and_every_shader_file_has_a_stage() {
        for shader in ALL {
            let module = naga::front::wgsl::parse_str(shader.source).expect("parses");
            let names: Vec<&str> = module.entry_points.iter().map(|e| e.name.as_str()).collect();
            for entry in shader.entry_points {
                assert!(names.contains(entry), "{}: no entry point {entry}", shader.file);
            }
        }
        let mut ours: Vec<&str> = ALL.iter().map(|s| s.file).collect();
        let mut files: Vec<&str> = crate::shaders::ALL.iter().map(|(f, _)| *f).collect();
        ours.sort();
        files.sort();
        assert_eq!(ours, files);
    }
}
