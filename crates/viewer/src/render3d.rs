//! The 3D view: point cloud and textured mesh drawn with wgpu.
//!
//! [`SceneGpu`] owns the pipelines and buffers. It draws into its own colour + depth target
//! (so the 3D view has a depth buffer whatever egui's render pass has) and
//! [`View3dCallback`], an `egui_wgpu::CallbackTrait`, copies that target into egui's pass
//! with a full-screen triangle. [`SceneGpu`] is stored in egui-wgpu's callback resources
//! (see [`install`]); it is also usable without egui (the frame-time test does).
//!
//! Colours: images hold sRGB-encoded bytes; the offscreen target is `Rgba8Unorm` and egui's
//! target is not sRGB either, so bytes pass through unchanged (as in egui's own images).

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use geometry::{Image, Mesh, PointCloud, RigidTransform};
use nalgebra::Vector3;
use wgpu::util::DeviceExt;

/// Offscreen colour format.
pub const OFFSCREEN_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Background of the 3D view (dark grey, linear 0..1 of the stored bytes).
pub const BACKGROUND: [f64; 4] = [0.08, 0.08, 0.1, 1.0];

/// A point of the cloud: position (colour frame, metres) and RGBA colour.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct PointVertex {
    /// Position.
    pub pos: [f32; 3],
    /// Colour, sRGB bytes.
    pub color: [u8; 4],
}

/// A mesh vertex: position (colour frame, metres) and texture coordinate (top-left origin).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct MeshVertex {
    /// Position.
    pub pos: [f32; 3],
    /// Texture coordinate, `[0, 1]²`, origin at the texture's top-left (wgpu convention).
    pub uv: [f32; 2],
}

/// What the 3D view draws, ready for upload. Immutable once built; `generation` changes
/// whenever the content does, so [`SceneGpu`] uploads only then.
#[derive(Debug)]
pub struct Geometry3d {
    /// Identifies the content.
    pub generation: u64,
    /// Cloud points in the colour frame.
    pub points: Vec<PointVertex>,
    /// Mesh vertices.
    pub vertices: Vec<MeshVertex>,
    /// Triangle indices, three per face.
    pub indices: Vec<u32>,
    /// The mesh's texture (the colour image).
    pub texture: Arc<Image<[u8; 3]>>,
}

impl Geometry3d {
    /// The H1 cloud (depth frame, moved into the colour frame with `color_from_depth`) and
    /// a mesh in the colour frame textured by `texture`.
    pub fn new(
        generation: u64,
        cloud: &PointCloud,
        color_from_depth: &RigidTransform,
        mesh: &Mesh,
        texture: Arc<Image<[u8; 3]>>,
    ) -> Self {
        let points = cloud
            .points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let q =
                    color_from_depth.apply(&Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64));
                let c = cloud.colors.get(i).copied().unwrap_or([200, 200, 200]);
                PointVertex {
                    pos: [q.x as f32, q.y as f32, q.z as f32],
                    color: [c[0], c[1], c[2], 255],
                }
            })
            .collect();
        let vertices = mesh
            .vertices
            .iter()
            .enumerate()
            .map(|(i, v)| {
                // Mesh uvs are OBJ's (bottom-left origin): flip t.
                let uv = mesh.uvs.get(i).map(|t| [t[0], 1.0 - t[1]]).unwrap_or([0.0, 0.0]);
                MeshVertex { pos: *v, uv }
            })
            .collect();
        let indices = mesh.faces.iter().flatten().copied().collect();
        Self { generation, points, vertices, indices, texture }
    }
}

/// What to draw this frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DrawParams {
    /// Projection × view, column-major.
    pub view_proj: [[f32; 4]; 4],
    /// Draw the point cloud.
    pub points: bool,
    /// Draw the textured mesh.
    pub mesh: bool,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Uniforms {
    view_proj: [[f32; 4]; 4],
}

const SHADER: &str = r#"
struct U { view_proj: mat4x4<f32> };
@group(0) @binding(0) var<uniform> u: U;
@group(1) @binding(0) var tex: texture_2d<f32>;
@group(1) @binding(1) var samp: sampler;

struct PointOut { @builtin(position) pos: vec4<f32>, @location(0) color: vec4<f32> };
@vertex fn vs_point(@location(0) p: vec3<f32>, @location(1) c: vec4<f32>) -> PointOut {
    var o: PointOut;
    o.pos = u.view_proj * vec4<f32>(p, 1.0);
    o.color = c;
    return o;
}
@fragment fn fs_point(i: PointOut) -> @location(0) vec4<f32> { return i.color; }

struct MeshOut { @builtin(position) pos: vec4<f32>, @location(0) uv: vec2<f32> };
@vertex fn vs_mesh(@location(0) p: vec3<f32>, @location(1) uv: vec2<f32>) -> MeshOut {
    var o: MeshOut;
    o.pos = u.view_proj * vec4<f32>(p, 1.0);
    o.uv = uv;
    return o;
}
@fragment fn fs_mesh(i: MeshOut) -> @location(0) vec4<f32> { return textureSample(tex, samp, i.uv); }

struct BlitOut { @builtin(position) pos: vec4<f32>, @location(0) uv: vec2<f32> };
@vertex fn vs_blit(@builtin(vertex_index) i: u32) -> BlitOut {
    let x = f32((i << 1u) & 2u);
    let y = f32(i & 2u);
    var o: BlitOut;
    o.pos = vec4<f32>(x * 2.0 - 1.0, 1.0 - y * 2.0, 0.0, 1.0);
    o.uv = vec2<f32>(x, y);
    return o;
}
@fragment fn fs_blit(i: BlitOut) -> @location(0) vec4<f32> { return textureSample(tex, samp, i.uv); }
"#;

struct Target {
    size: [u32; 2],
    color: wgpu::Texture,
    color_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    blit_group: wgpu::BindGroup,
}

struct Uploaded {
    generation: u64,
    points: wgpu::Buffer,
    point_count: u32,
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    index_count: u32,
    texture_group: wgpu::BindGroup,
}

/// Pipelines, buffers and the offscreen target of the 3D view.
pub struct SceneGpu {
    point_pipeline: wgpu::RenderPipeline,
    mesh_pipeline: wgpu::RenderPipeline,
    blit_pipeline: wgpu::RenderPipeline,
    uniforms: wgpu::Buffer,
    uniform_group: wgpu::BindGroup,
    texture_layout: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
    target: Option<Target>,
    uploaded: Option<Uploaded>,
}

impl SceneGpu {
    /// Compiles the pipelines; `target_format` is the format of the pass the view is
    /// copied into (egui's).
    pub fn new(device: &wgpu::Device, target_format: wgpu::TextureFormat) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("viewer 3d"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let uniform_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("viewer uniforms"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let texture_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("viewer texture"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let layout3d = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("viewer 3d"),
            bind_group_layouts: &[Some(&uniform_layout), Some(&texture_layout)],
            immediate_size: 0,
        });
        let blit_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("viewer blit"),
            bind_group_layouts: &[Some(&uniform_layout), Some(&texture_layout)],
            immediate_size: 0,
        });
        let depth = Some(wgpu::DepthStencilState {
            format: DEPTH_FORMAT,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: Default::default(),
            bias: Default::default(),
        });
        let point_attrs = wgpu::vertex_attr_array![0 => Float32x3, 1 => Unorm8x4];
        let mesh_attrs = wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x2];
        let pipeline = |label: &str,
                        layout: &wgpu::PipelineLayout,
                        vs: &str,
                        fs: &str,
                        buffers: &[Option<wgpu::VertexBufferLayout>],
                        topology,
                        depth: Option<wgpu::DepthStencilState>,
                        format| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some(vs),
                    compilation_options: Default::default(),
                    buffers,
                },
                primitive: wgpu::PrimitiveState { topology, ..Default::default() },
                depth_stencil: depth,
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(fs),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let point_pipeline = pipeline(
            "viewer points",
            &layout3d,
            "vs_point",
            "fs_point",
            &[Some(wgpu::VertexBufferLayout {
                array_stride: size_of::<PointVertex>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &point_attrs,
            })],
            wgpu::PrimitiveTopology::PointList,
            depth.clone(),
            OFFSCREEN_FORMAT,
        );
        let mesh_pipeline = pipeline(
            "viewer mesh",
            &layout3d,
            "vs_mesh",
            "fs_mesh",
            &[Some(wgpu::VertexBufferLayout {
                array_stride: size_of::<MeshVertex>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &mesh_attrs,
            })],
            wgpu::PrimitiveTopology::TriangleList,
            depth,
            OFFSCREEN_FORMAT,
        );
        let blit_pipeline = pipeline(
            "viewer blit",
            &blit_layout,
            "vs_blit",
            "fs_blit",
            &[],
            wgpu::PrimitiveTopology::TriangleList,
            None,
            target_format,
        );
        let uniforms = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("viewer uniforms"),
            contents: bytemuck::bytes_of(&Uniforms { view_proj: [[0.0; 4]; 4] }),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        });
        let uniform_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("viewer uniforms"),
            layout: &uniform_layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: uniforms.as_entire_binding() }],
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("viewer sampler"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        Self {
            point_pipeline,
            mesh_pipeline,
            blit_pipeline,
            uniforms,
            uniform_group,
            texture_layout,
            sampler,
            target: None,
            uploaded: None,
        }
    }

    /// Number of points and triangles uploaded (0, 0 before the first upload).
    pub fn uploaded_counts(&self) -> (u32, u32) {
        self.uploaded.as_ref().map_or((0, 0), |u| (u.point_count, u.index_count / 3))
    }

    /// Uploads `geometry` unless that generation is already on the GPU.
    pub fn upload(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, geometry: &Geometry3d) {
        if self.uploaded.as_ref().is_some_and(|u| u.generation == geometry.generation) {
            return;
        }
        let usage_v = wgpu::BufferUsages::VERTEX;
        // Empty buffers are not allowed to be bound: keep one dummy element.
        let points: &[u8] = if geometry.points.is_empty() {
            &[0; 16]
        } else {
            bytemuck::cast_slice(&geometry.points)
        };
        let vertices: &[u8] = if geometry.vertices.is_empty() {
            &[0; 20]
        } else {
            bytemuck::cast_slice(&geometry.vertices)
        };
        let indices: &[u8] = if geometry.indices.is_empty() {
            &[0; 12]
        } else {
            bytemuck::cast_slice(&geometry.indices)
        };
        let points = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("viewer points"),
            contents: points,
            usage: usage_v,
        });
        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("viewer vertices"),
            contents: vertices,
            usage: usage_v,
        });
        let indices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("viewer indices"),
            contents: indices,
            usage: wgpu::BufferUsages::INDEX,
        });
        let (w, h) = geometry.texture.size();
        let rgba: Vec<u8> =
            geometry.texture.data().iter().flat_map(|c| [c[0], c[1], c[2], 255]).collect();
        let size = wgpu::Extent3d {
            width: w.max(1) as u32,
            height: h.max(1) as u32,
            depth_or_array_layers: 1,
        };
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("viewer mesh texture"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8Unorm,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        if !rgba.is_empty() {
            queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                &rgba,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(4 * w as u32),
                    rows_per_image: Some(h as u32),
                },
                size,
            );
        }
        let view = texture.create_view(&Default::default());
        let texture_group = self.texture_group(device, &view);
        self.uploaded = Some(Uploaded {
            generation: geometry.generation,
            points,
            point_count: geometry.points.len() as u32,
            vertices,
            indices,
            index_count: geometry.indices.len() as u32,
            texture_group,
        });
    }

    fn texture_group(&self, device: &wgpu::Device, view: &wgpu::TextureView) -> wgpu::BindGroup {
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("viewer texture"),
            layout: &self.texture_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(view),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::Sampler(&self.sampler),
                },
            ],
        })
    }

    fn ensure_target(&mut self, device: &wgpu::Device, size: [u32; 2]) {
        let size = [size[0].max(1), size[1].max(1)];
        if self.target.as_ref().is_some_and(|t| t.size == size) {
            return;
        }
        let extent = wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 };
        let make = |format, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some("viewer offscreen"),
                size: extent,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let color = make(
            OFFSCREEN_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
        );
        let depth = make(DEPTH_FORMAT, wgpu::TextureUsages::RENDER_ATTACHMENT);
        let color_view = color.create_view(&Default::default());
        let blit_group = self.texture_group(device, &color_view);
        self.target = Some(Target {
            size,
            color,
            color_view,
            depth_view: depth.create_view(&Default::default()),
            blit_group,
        });
    }

    /// The offscreen colour texture (after [`SceneGpu::draw`]).
    pub fn offscreen(&self) -> Option<&wgpu::Texture> {
        self.target.as_ref().map(|t| &t.color)
    }

    /// Records the 3D pass into `encoder`: clears the offscreen target of `size` pixels and
    /// draws the uploaded mesh and/or cloud.
    pub fn draw(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        params: &DrawParams,
        size: [u32; 2],
    ) {
        self.ensure_target(device, size);
        queue.write_buffer(
            &self.uniforms,
            0,
            bytemuck::bytes_of(&Uniforms { view_proj: params.view_proj }),
        );
        let Some(target) = &self.target else { return };
        let [r, g, b, a] = BACKGROUND;
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("viewer 3d"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &target.color_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color { r, g, b, a }),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &target.depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        let Some(up) = &self.uploaded else { return };
        pass.set_bind_group(0, &self.uniform_group, &[]);
        pass.set_bind_group(1, &up.texture_group, &[]);
        if params.mesh && up.index_count > 0 {
            pass.set_pipeline(&self.mesh_pipeline);
            pass.set_vertex_buffer(0, up.vertices.slice(..));
            pass.set_index_buffer(up.indices.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..up.index_count, 0, 0..1);
        }
        if params.points && up.point_count > 0 {
            pass.set_pipeline(&self.point_pipeline);
            pass.set_vertex_buffer(0, up.points.slice(..));
            pass.draw(0..up.point_count, 0..1);
        }
    }

    /// Copies the offscreen target into `pass` (the viewport egui set for the callback).
    pub fn blit(&self, pass: &mut wgpu::RenderPass<'static>) {
        let Some(target) = &self.target else { return };
        pass.set_pipeline(&self.blit_pipeline);
        pass.set_bind_group(0, &self.uniform_group, &[]);
        pass.set_bind_group(1, &target.blit_group, &[]);
        pass.draw(0..3, 0..1);
    }
}

/// Puts a [`SceneGpu`] for `render_state`'s device into its callback resources (call once,
/// from eframe's creation context or a test's render state).
pub fn install(render_state: &egui_wgpu::RenderState) {
    let scene = SceneGpu::new(&render_state.device, render_state.target_format);
    render_state.renderer.write().callback_resources.insert(scene);
}

/// The paint callback of the 3D view.
pub struct View3dCallback {
    /// What to draw.
    pub geometry: Arc<Geometry3d>,
    /// How.
    pub params: DrawParams,
    /// Size of the view, points.
    pub size_points: [f32; 2],
}

impl egui_wgpu::CallbackTrait for View3dCallback {
    fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        screen: &egui_wgpu::ScreenDescriptor,
        encoder: &mut wgpu::CommandEncoder,
        resources: &mut egui_wgpu::CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        let Some(scene) = resources.get_mut::<SceneGpu>() else { return Vec::new() };
        scene.upload(device, queue, &self.geometry);
        let ppp = screen.pixels_per_point;
        let size = [
            (self.size_points[0] * ppp).round() as u32,
            (self.size_points[1] * ppp).round() as u32,
        ];
        scene.draw(device, queue, encoder, &self.params, size);
        Vec::new()
    }

    fn paint(
        &self,
        _info: egui::PaintCallbackInfo,
        pass: &mut wgpu::RenderPass<'static>,
        resources: &egui_wgpu::CallbackResources,
    ) {
        if let Some(scene) = resources.get::<SceneGpu>() {
            scene.blit(pass);
        }
    }
}
