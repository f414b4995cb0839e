//! H8 plane fill (`plane_fill.wgsl`): hole pixels take the depth of the CPU-fitted plane along
//! their undistorted ray.

use std::sync::mpsc;

use bytemuck::{Pod, Zeroable};
use geometry::{CameraModel, Image};

use super::{Shader, dispatch, write_uniform};
use crate::error::GpuError;
use crate::gpu::Gpu;
use crate::shaders;

/// `params`: [`Params`].
pub(crate) const PARAMS: u32 = 0;
/// `dense`: the depth to fill (H3 nearest).
pub(crate) const DENSE: u32 = 1;
/// `holes`: the hole mask.
pub(crate) const HOLES: u32 = 2;
/// `rays`: the colour camera's undistorted ray per pixel.
pub(crate) const RAYS: u32 = 3;
/// `filled`: the filled depth (output).
pub(crate) const FILLED: u32 = 4;

/// The shader and its bindings.
pub(crate) const SHADER: Shader = Shader {
    file: "plane_fill.wgsl",
    source: shaders::PLANE_FILL,
    entry_points: &["main"],
    bindings: &[
        ("params", PARAMS),
        ("dense", DENSE),
        ("holes", HOLES),
        ("rays", RAYS),
        ("filled", FILLED),
    ],
};

/// The WGSL's `Params`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct Params {
    /// `[colour width, colour height, colour pixels, row stride]`.
    pub size: [u32; 4],
    /// `[n_x, n_y, n_z, d]` of the plane `n · X = d`.
    pub plane: [f32; 4],
    /// Always zero (see `keep()` in the shaders).
    pub opaque: [u32; 4],
}

/// H8's fill: its pipeline and uniform, and, for the last colour camera, its ray table (on the
/// device and on the host, for the count of pixels filled), its buffers and bind group.
pub(crate) struct PlaneFill {
    pipeline: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    bound: Option<Bound>,
}

struct Bound {
    camera: CameraModel,
    host_rays: Vec<[f32; 2]>,
    dense: wgpu::Buffer,
    holes: wgpu::Buffer,
    filled: wgpu::Buffer,
    read: wgpu::Buffer,
    group: wgpu::BindGroup,
    _rays: wgpu::Buffer,
}

impl PlaneFill {
    pub(crate) fn new(gpu: &Gpu) -> Self {
        Self {
            pipeline: super::pipeline(&gpu.device, &SHADER, "main"),
            params: gpu.uniform::<Params>("H8 fill params"),
            bound: None,
        }
    }

    /// `nearest` (checked to be `camera`'s size) with every `holes` pixel replaced by the
    /// depth of the plane `normal · X = offset` along the pixel's undistorted ray, and the
    /// count of pixels filled (hole pixels whose ray meets the plane in front, as the CPU
    /// twin counts them).
    pub(crate) fn fill(
        &mut self,
        gpu: &Gpu,
        camera: &CameraModel,
        nearest: &Image<f32>,
        holes: &Image<bool>,
        normal: [f32; 3],
        offset: f32,
    ) -> Result<(Image<f32>, usize), GpuError> {
        let (w, h) = (camera.width, camera.height);
        let m = (w * h) as u32;
        if self.bound.as_ref().is_none_or(|b| b.camera != *camera) {
            let host_rays = camera.ray_table();
            let rays = gpu.upload("colour ray table", &host_rays);
            let bytes = m as u64 * 4;
            let (dense, holes, filled) = (
                gpu.storage("plane fill input", bytes),
                gpu.storage("plane fill mask", bytes),
                gpu.storage("plane fill", bytes),
            );
            let read = gpu.read_back("plane fill read-back", bytes);
            let group = gpu.bind(
                &self.pipeline,
                &[
                    (PARAMS, &self.params),
                    (DENSE, &dense),
                    (HOLES, &holes),
                    (RAYS, &rays),
                    (FILLED, &filled),
                ],
            );
            self.bound = Some(Bound {
                camera: *camera,
                host_rays,
                dense,
                holes,
                filled,
                read,
                group,
                _rays: rays,
            });
        }
        let Some(b) = &self.bound else {
            return Err(gpu.device_error("filling holes", "colour ray table missing".into()));
        };
        let grid = gpu.grid(m);
        let q = &gpu.queue;
        q.write_buffer(&b.dense, 0, bytemuck::cast_slice(nearest.data()));
        let mask: Vec<u32> = holes.data().iter().map(|&v| v as u32).collect();
        q.write_buffer(&b.holes, 0, bytemuck::cast_slice(&mask));
        let params = Params {
            size: [w as u32, h as u32, m, grid.stride],
            plane: [normal[0], normal[1], normal[2], offset],
            opaque: [0; 4],
        };
        write_uniform(gpu, &self.params, &params);
        let filled = holes
            .data()
            .iter()
            .zip(&b.host_rays)
            .filter(|(m, ray)| {
                **m && geometry::fusion::plane_depth_pixel(normal, offset, **ray).is_some()
            })
            .count();
        let mut enc = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("H8 fill") });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("H8 fill"),
                timestamp_writes: None,
            });
            dispatch(&mut pass, &self.pipeline, &b.group, grid);
        }
        let bytes = m as u64 * 4;
        enc.copy_buffer_to_buffer(&b.filled, 0, &b.read, 0, bytes);
        let submission = q.submit([enc.finish()]);
        let (tx, rx) = mpsc::channel();
        b.read.map_async(wgpu::MapMode::Read, 0..bytes, move |r| {
            let _ = tx.send(r);
        });
        gpu.wait(submission, &rx, 1)?;
        let data: Vec<f32> = gpu.read_mapped(&b.read, bytes)?;
        Ok((Image::from_vec(w, h, data)?, filled))
    }
}
