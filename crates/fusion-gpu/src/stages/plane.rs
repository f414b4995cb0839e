//! H8 plane fill (`plane_fill.wgsl`): hole pixels take the depth of the CPU-fitted plane along
//! their undistorted ray.

use std::sync::mpsc;

use bytemuck::{Pod, Zeroable};
use geometry::{CameraModel, Image};

use super::Shader;
use crate::context::{FusionContext, U_PLANE};
use crate::{GpuError, shaders};

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

/// The stage's pipeline.
pub(crate) fn pipeline(device: &wgpu::Device) -> wgpu::ComputePipeline {
    super::pipeline(device, &SHADER, "main")
}

impl FusionContext {
    /// H8 fill on the GPU: `nearest` (H3, colour-sized) with every `holes` pixel replaced by the
    /// depth of the plane `normal · X = offset` (colour frame, metres) along the pixel's
    /// undistorted ray. Bit-identical to `geometry::fusion::fill_holes_with_plane` with the
    /// plane rounded to `f32`, including the count of pixels filled. The plane itself comes
    /// from the CPU RANSAC fit (`geometry::fusion::fit_plane_ransac`).
    pub fn fill_holes_with_plane(
        &mut self,
        color_camera: &CameraModel,
        nearest: &Image<f32>,
        holes: &Image<bool>,
        normal: [f32; 3],
        offset: f32,
    ) -> Result<(Image<f32>, usize), GpuError> {
        color_camera.validate()?;
        let (w, h) = (color_camera.width, color_camera.height);
        nearest.expect_size("nearest-filled colour depth", w, h)?;
        holes.expect_size("hole mask", w, h)?;
        // The depth side is irrelevant here; reuse slot 0 with whatever depth size it has.
        self.check_frame_size((1, 1), (w, h))?;
        let depth_size = self.slots.first().map_or((1, 1), |s| s.depth_size);
        self.ensure_slot(0, depth_size, (w, h));
        self.ensure_color_rays(color_camera);
        let m = (w * h) as u32;
        let (gx, gy, stride) = self.grid(m);
        let s = &self.slots[0];
        let q = &self.queue;
        q.write_buffer(&s.nearest, 0, bytemuck::cast_slice(nearest.data()));
        let mask: Vec<u32> = holes.data().iter().map(|&b| b as u32).collect();
        q.write_buffer(&s.holes, 0, bytemuck::cast_slice(&mask));
        let params = Params {
            size: [w as u32, h as u32, m, stride],
            plane: [normal[0], normal[1], normal[2], offset],
            opaque: [0; 4],
        };
        q.write_buffer(&s.uniforms[U_PLANE], 0, bytemuck::bytes_of(&params));
        let (rays, host_rays) = match &self.color_rays {
            Some((c, host)) => (&c.buffer, host),
            None => {
                return Err(self.device_error("filling holes", "colour ray table missing".into()));
            }
        };
        // The count the CPU twin reports: hole pixels whose ray meets the plane in front.
        let filled = holes
            .data()
            .iter()
            .zip(host_rays)
            .filter(|(m, ray)| {
                **m && geometry::fusion::plane_depth_pixel(normal, offset, **ray).is_some()
            })
            .count();
        let group = self.bind(
            &self.kernels.plane_fill,
            &[
                (PARAMS, &s.uniforms[U_PLANE]),
                (DENSE, &s.nearest),
                (HOLES, &s.holes),
                (RAYS, rays),
                (FILLED, &s.filled),
            ],
        );
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("H8 fill") });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("H8 fill"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.kernels.plane_fill);
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(gx, gy, 1);
        }
        let bytes = m as u64 * 4;
        enc.copy_buffer_to_buffer(&s.filled, 0, &s.read_nearest, 0, bytes);
        let submission = q.submit([enc.finish()]);
        let (tx, rx) = mpsc::channel();
        s.read_nearest.map_async(wgpu::MapMode::Read, 0..bytes, move |r| {
            let _ = tx.send(r);
        });
        self.wait(submission, &rx, 1)?;
        let data: Vec<f32> = self.read_mapped(&self.slots[0].read_nearest, bytes)?;
        Ok((Image::from_vec(w, h, data)?, filled))
    }
}
