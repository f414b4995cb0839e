//! [`FusionContext`]: the wgpu device, queue, compute pipelines and per-frame buffers, reused
//! across frames.

use std::collections::VecDeque;
use std::sync::mpsc;
use std::sync::{Arc, Mutex};

use bytemuck::{Pod, Zeroable};
use geometry::fusion::{ColorProjection, depth_ray_table};
use geometry::{CameraModel, DepthKind, Image, Rig};

use geometry::fusion::disc_offsets;

use crate::tables::hole_half_widths;
use crate::{GpuError, shaders};

/// Invocations per workgroup of every kernel (the `@workgroup_size` in the shaders): 256 is a
/// multiple of every vendor's SIMD width and within WebGPU's default limit.
const WORKGROUP_SIZE: u32 = 256;

/// Workgroup size of the hole mask's per-row / per-column `extents` kernel: only
/// `width + height` invocations, each a long loop, so small groups spread them over more cores.
const EXTENT_WORKGROUP_SIZE: u32 = 64;

/// Frame slots of the streaming mode: two, so one frame computes while the previous one is
/// read back and the next one uploads.
const STREAM_SLOTS: usize = 2;

/// The stages after H7 and their parameters (the same meaning as the CPU twins' arguments).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StageOptions {
    /// H3 nearest fill: disc radius in colour pixels (`geometry::fusion::nearest_fill`).
    pub nearest_radius_px: f32,
    /// H3 nearest fill: relative depth step that separates surfaces.
    pub depth_jump: f32,
    /// H8 hole mask: coverage radius in colour pixels (`geometry::fusion::HoleMasker`).
    pub hole_radius_px: f32,
    /// H8 hole mask: how far hole cores grow back, colour pixels (`HoleMasker`'s `grow`).
    pub hole_grow_px: f32,
    /// H6: a depth pixel's colour is dropped when its `z` exceeds the colour camera's H3 depth
    /// there by more than this fraction (`geometry::fusion::color_on_depth`); `None` samples
    /// every pixel without an occlusion test.
    pub occlusion_tolerance: Option<f32>,
}

impl StageOptions {
    /// Checks the three radii against `geometry::fusion::MAX_COVERAGE_RADIUS_PX` before their
    /// lookup tables are built (the disc table grows with the square of the radius).
    ///
    /// Error: [`GpuError::Input`] naming the radius and the limit.
    pub fn check(&self) -> Result<(), GpuError> {
        let limit = geometry::fusion::MAX_COVERAGE_RADIUS_PX;
        for (what, r) in [
            ("H3 nearest radius", self.nearest_radius_px),
            ("H8 coverage radius", self.hole_radius_px),
            ("H8 growth radius", self.hole_grow_px),
        ] {
            if !(0.0..=limit).contains(&r) {
                return Err(GpuError::Input(geometry::GeometryError::InvalidInput(format!(
                    "{what} {r} px is outside 0..={limit} px"
                ))));
            }
        }
        Ok(())
    }
}

/// What a frame runs: H1 + H2 + H7 always, the later stages when `stages` is given.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FramePlan {
    /// H3 nearest fill, H8 hole mask and (with a colour image) H6; `None`: H1 + H2 + H7 only.
    pub stages: Option<StageOptions>,
    /// Also copy back H1's points and H2's samples (for parity checks; costs read-back time).
    pub read_intermediates: bool,
}

/// One frame's results read back from the GPU.
#[derive(Debug, Clone, PartialEq)]
pub struct GpuFrame {
    /// H7: colour-sized z-buffer, smallest colour-frame `z` per pixel (metres), and
    /// [`geometry::fusion::ZBUFFER_EMPTY`] (a NaN with all bits set) where no sample landed.
    pub zbuffer: Image<f32>,
    /// H1 when asked for: one entry per depth pixel, `[X, Y, Z, 1]` (depth camera frame,
    /// metres) or all zero for no point.
    pub points: Option<Vec<[f32; 4]>>,
    /// H2 when asked for: one entry per depth pixel, `[u, v, z_color, 1]` when in front of
    /// the colour camera (the pixel may lie outside the colour image), all zero otherwise.
    pub samples: Option<Vec<[f32; 4]>>,
    /// H3 nearest fill of the colour grid (colour-frame `z`, `ZBUFFER_EMPTY` = none).
    pub nearest: Option<Image<f32>>,
    /// H8 disocclusion hole mask on the colour grid.
    pub holes: Option<Image<bool>>,
    /// H6 colour on the depth grid and its validity (black where invalid).
    pub color_on_depth: Option<(Image<[u8; 3]>, Image<bool>)>,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct SizeParams {
    size: [u32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ProjectParams {
    rows: [[f32; 4]; 3],
    k: [f32; 4],
    d0: [f32; 4],
    d1: [f32; 4],
    size: [u32; 4],
    /// Always zero (see `keep()` in the shaders).
    opaque: [u32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct NearestParams {
    size: [u32; 4],
    offsets: [u32; 4],
    jump: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct HoleParams {
    size: [u32; 4],
    radius: [u32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ColorParams {
    size: [u32; 4],
    occlusion: [f32; 4],
    /// Always zero (see `keep()` in the shaders).
    opaque: [u32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PlaneParams {
    size: [u32; 4],
    plane: [f32; 4],
    /// Always zero (see `keep()` in the shaders).
    opaque: [u32; 4],
}

struct Kernels {
    backproject: wgpu::ComputePipeline,
    project: wgpu::ComputePipeline,
    zclear: wgpu::ComputePipeline,
    zscatter: wgpu::ComputePipeline,
    nearest: wgpu::ComputePipeline,
    hole_extents: wgpu::ComputePipeline,
    hole_cover: wgpu::ComputePipeline,
    hole_core: wgpu::ComputePipeline,
    hole_grow: wgpu::ComputePipeline,
    color: wgpu::ComputePipeline,
    plane_fill: wgpu::ComputePipeline,
}

/// A device buffer built from host data, with the key it was built from.
struct Cached<K> {
    key: K,
    buffer: wgpu::Buffer,
    len: u32,
}

/// Everything one in-flight frame needs: inputs, intermediates, outputs, read-back buffers.
struct FrameSlot {
    depth_size: (usize, usize),
    color_size: (usize, usize),
    uniforms: Vec<wgpu::Buffer>,
    depth: wgpu::Buffer,
    points: wgpu::Buffer,
    samples: wgpu::Buffer,
    zbuffer: wgpu::Buffer,
    nearest: wgpu::Buffer,
    covered: wgpu::Buffer,
    row_extent: wgpu::Buffer,
    col_extent: wgpu::Buffer,
    core: wgpu::Buffer,
    holes: wgpu::Buffer,
    color: wgpu::Buffer,
    rgba: wgpu::Buffer,
    filled: wgpu::Buffer,
    read_z: wgpu::Buffer,
    read_points: wgpu::Buffer,
    read_samples: wgpu::Buffer,
    read_nearest: wgpu::Buffer,
    read_holes: wgpu::Buffer,
    read_rgba: wgpu::Buffer,
}

/// Uniform buffer indices of a slot.
const U_BACKPROJECT: usize = 0;
const U_PROJECT: usize = 1;
const U_ZCLEAR: usize = 2;
const U_ZSCATTER: usize = 3;
const U_NEAREST: usize = 4;
const U_HOLE_CLEAR: usize = 5;
const U_HOLE: usize = 6;
const U_COLOR: usize = 7;
const U_PLANE: usize = 8;
const UNIFORM_COUNT: usize = 9;

/// What a submitted frame will read back.
#[derive(Clone, Copy)]
struct Reads {
    intermediates: bool,
    stages: bool,
    color: bool,
}

/// A submitted frame whose results are not read yet.
struct Pending {
    slot: usize,
    frame: usize,
    submission: wgpu::SubmissionIndex,
    reads: Reads,
    mapped: mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
    maps: usize,
}

/// The GPU fusion engine: device, queue, compiled pipelines and buffers reused from frame to
/// frame (re-allocated only when the image sizes change). Create once, run many frames.
pub struct FusionContext {
    device: wgpu::Device,
    queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    kernels: Kernels,
    depth_rays: Option<Cached<(CameraModel, DepthKind)>>,
    color_rays: Option<(Cached<CameraModel>, Vec<[f32; 2]>)>,
    offsets: Option<Cached<u32>>,
    half_widths: Option<Cached<u32>>,
    grow_half_widths: Option<Cached<u32>>,
    slots: Vec<FrameSlot>,
    errors: Arc<Mutex<Vec<String>>>,
}

impl std::fmt::Debug for FusionContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FusionContext").field("adapter", &self.info.name).finish_non_exhaustive()
    }
}

impl FusionContext {
    /// Opens the first Vulkan adapter (a real GPU is preferred over a software one such as
    /// lavapipe) and compiles every stage. Honours `WGPU_BACKEND` / `VK_DRIVER_FILES`.
    ///
    /// Fails with [`GpuError::NoAdapter`] when there is none; the library never falls back
    /// by itself ([`crate::fuse`] does under [`crate::Engine::Auto`]).
    pub fn new() -> Result<Self, GpuError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        // Only the Vulkan backend is compiled in; asking for others would find nothing.
        desc.backends &= wgpu::Backends::VULKAN;
        if desc.backends.is_empty() {
            desc.backends = wgpu::Backends::VULKAN;
        }
        let backends = "Vulkan".to_string();
        let instance = wgpu::Instance::new(desc);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        }))
        .map_err(|_| GpuError::NoAdapter { backends })?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("kfuse fusion"),
            required_features: wgpu::Features::empty(),
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::RequestDevice {
            adapter: info.name.clone(),
            message: e.to_string(),
        })?;

        // Validation and out-of-memory errors would panic in wgpu's default handler; collect
        // them instead and turn them into GpuError::Device after the frame.
        let errors = Arc::new(Mutex::new(Vec::new()));
        let sink = Arc::clone(&errors);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut v) = sink.lock() {
                v.push(e.to_string());
            }
        }));

        let kernels = Kernels {
            backproject: pipeline(&device, "backproject.wgsl", shaders::BACKPROJECT, "main"),
            project: pipeline(&device, "project.wgsl", shaders::PROJECT, "main"),
            zclear: pipeline(&device, "zbuffer.wgsl", shaders::ZBUFFER, "clear"),
            zscatter: pipeline(&device, "zbuffer.wgsl", shaders::ZBUFFER, "scatter"),
            nearest: pipeline(&device, "nearest_fill.wgsl", shaders::NEAREST_FILL, "main"),
            hole_extents: pipeline(&device, "hole_mask.wgsl", shaders::HOLE_MASK, "extents"),
            hole_cover: pipeline(&device, "hole_mask.wgsl", shaders::HOLE_MASK, "coverage"),
            hole_core: pipeline(&device, "hole_mask.wgsl", shaders::HOLE_MASK, "core_mask"),
            hole_grow: pipeline(&device, "hole_mask.wgsl", shaders::HOLE_MASK, "grow"),
            color: pipeline(&device, "color_on_depth.wgsl", shaders::COLOR_ON_DEPTH, "main"),
            plane_fill: pipeline(&device, "plane_fill.wgsl", shaders::PLANE_FILL, "main"),
        };
        let ctx = Self {
            device,
            queue,
            info,
            limits,
            kernels,
            depth_rays: None,
            color_rays: None,
            offsets: None,
            half_widths: None,
            grow_half_widths: None,
            slots: Vec::new(),
            errors,
        };
        ctx.check_errors("compiling the shaders")?;
        Ok(ctx)
    }

    /// The adapter's name, e.g. `llvmpipe (LLVM 15.0.6, 256 bits)` for lavapipe.
    pub fn adapter_name(&self) -> &str {
        &self.info.name
    }

    /// A one-line description: name, device type, backend, driver.
    pub fn adapter_summary(&self) -> String {
        format!(
            "{} ({:?}, {:?}, driver {} {})",
            self.info.name,
            self.info.device_type,
            self.info.backend,
            self.info.driver,
            self.info.driver_info
        )
    }

    /// True for a software adapter (lavapipe / llvmpipe): correct, but slower than the CPU path.
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// The largest storage-buffer binding of this adapter, bytes (lavapipe: 128 MiB).
    pub fn max_binding_bytes(&self) -> u64 {
        self.limits.max_storage_buffer_binding_size.min(self.limits.max_buffer_size)
    }

    /// Checks that frames of these sizes fit the adapter, without allocating anything.
    /// The largest bindings are the per-depth-pixel points (16 bytes a pixel) and the colour
    /// ray table (8 bytes a colour pixel).
    pub fn check_frame_size(
        &self,
        depth: (usize, usize),
        color: (usize, usize),
    ) -> Result<(), GpuError> {
        let limit = self.max_binding_bytes();
        let needs: [(&'static str, (usize, usize), u64); 2] =
            [("per-depth-pixel point", depth, 16), ("colour ray table", color, 8)];
        for (buffer, (w, h), bytes_per_pixel) in needs {
            let bytes = (w as u64).saturating_mul(h as u64).saturating_mul(bytes_per_pixel);
            // Indices are u32 in the shaders (3 per pixel in the ray table).
            if bytes > limit || w.saturating_mul(h) > (u32::MAX / 4) as usize {
                return Err(GpuError::FrameTooLarge {
                    adapter: self.info.name.clone(),
                    buffer,
                    width: w,
                    height: h,
                    bytes,
                    limit,
                });
            }
        }
        Ok(())
    }

    /// H1 + H2 + H7 for one depth frame: the colour-sized z-buffer (and H1/H2 per pixel when
    /// `read_intermediates`). Bit-identical to [`geometry::fusion::register_depth`].
    pub fn register(
        &mut self,
        rig: &Rig,
        depth: &Image<f32>,
        kind: DepthKind,
        read_intermediates: bool,
    ) -> Result<GpuFrame, GpuError> {
        let plan = FramePlan { stages: None, read_intermediates };
        self.single(rig, depth, kind, None, plan)
    }

    /// One frame through the stages of `plan`; `color` (the colour image, `rig.color`'s
    /// size) is needed for H6 and ignored otherwise.
    pub fn frame(
        &mut self,
        rig: &Rig,
        depth: &Image<f32>,
        kind: DepthKind,
        color: Option<&Image<[u8; 3]>>,
        plan: FramePlan,
    ) -> Result<GpuFrame, GpuError> {
        self.single(rig, depth, kind, color, plan)
    }

    fn single(
        &mut self,
        rig: &Rig,
        depth: &Image<f32>,
        kind: DepthKind,
        color: Option<&Image<[u8; 3]>>,
        plan: FramePlan,
    ) -> Result<GpuFrame, GpuError> {
        let mut out = None;
        let frames = std::iter::once((depth, color));
        self.stream(rig, kind, frames, plan, |_, frame| out = Some(frame))?;
        out.ok_or_else(|| {
            self.device_error("reading back the frame", "no result was produced".into())
        })
    }

    /// Streaming mode: runs `plan` on every `(depth, colour)` frame of `frames` (all of the
    /// rig's sizes), handing each result to `sink(frame_index, frame)` in order. Two frame
    /// slots alternate so that frame `k + 1` uploads and computes while frame `k` is read back
    /// (`map_async`). Returns the number of frames.
    pub fn stream<'a, I, F>(
        &mut self,
        rig: &Rig,
        kind: DepthKind,
        frames: I,
        plan: FramePlan,
        mut sink: F,
    ) -> Result<usize, GpuError>
    where
        I: IntoIterator<Item = (&'a Image<f32>, Option<&'a Image<[u8; 3]>>)>,
        F: FnMut(usize, GpuFrame),
    {
        rig.validate()?;
        if let Some(s) = &plan.stages {
            s.check()?;
        }
        let depth_size = (rig.depth.width, rig.depth.height);
        let color_size = (rig.color.width, rig.color.height);
        self.check_frame_size(depth_size, color_size)?;
        self.ensure_tables(rig, kind, plan.stages.as_ref());
        let proj = ColorProjection::from_rig(rig);
        let mut pending: VecDeque<Pending> = VecDeque::new();
        let mut count = 0;
        for (k, (depth, color)) in frames.into_iter().enumerate() {
            let sizes =
                depth.expect_size("depth image", depth_size.0, depth_size.1).and_then(|()| {
                    color.map_or(Ok(()), |c| {
                        c.expect_size("colour image", color_size.0, color_size.1)
                    })
                });
            if let Err(e) = sizes {
                // Let the frames in flight complete so their read-back buffers are unmapped
                // and the context stays usable; their results are dropped with the error.
                while let Some(p) = pending.pop_front() {
                    let _ = self.finish(p);
                }
                return Err(e.into());
            }
            let slot = k % STREAM_SLOTS;
            if let Some(pos) = pending.iter().position(|p| p.slot == slot) {
                // Frames complete in order: finish everything up to this slot's last frame.
                for _ in 0..=pos {
                    if let Some(p) = pending.pop_front() {
                        let (frame, result) = self.finish(p)?;
                        sink(frame, result);
                    }
                }
            }
            self.ensure_slot(slot, depth_size, color_size);
            let p = self.submit(slot, k, depth, color, &proj, &plan)?;
            pending.push_back(p);
            count += 1;
        }
        while let Some(p) = pending.pop_front() {
            let (frame, result) = self.finish(p)?;
            sink(frame, result);
        }
        Ok(count)
    }

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
        let params = PlaneParams {
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
            &[(0, &s.uniforms[U_PLANE]), (1, &s.nearest), (2, &s.holes), (3, rays), (4, &s.filled)],
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

    fn device_error(&self, during: &'static str, message: String) -> GpuError {
        GpuError::Device { adapter: self.info.name.clone(), during, message }
    }

    fn check_errors(&self, during: &'static str) -> Result<(), GpuError> {
        let mut errors = self
            .errors
            .lock()
            .map_err(|_| self.device_error(during, "error handler poisoned".into()))?;
        if errors.is_empty() {
            return Ok(());
        }
        let message = errors.join("; ");
        errors.clear();
        Err(GpuError::Device { adapter: self.info.name.clone(), during, message })
    }

    fn upload<T: Pod>(&self, label: &str, data: &[T]) -> wgpu::Buffer {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: (bytes.len() as u64).next_multiple_of(4).max(16),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        write_padded(&self.queue, &buffer, bytes);
        buffer
    }

    fn ensure_color_rays(&mut self, camera: &CameraModel) {
        if self.color_rays.as_ref().is_none_or(|(c, _)| c.key != *camera) {
            let table = camera.ray_table();
            let buffer = self.upload("colour ray table", &table);
            self.color_rays =
                Some((Cached { key: *camera, buffer, len: table.len() as u32 }, table));
        }
    }

    fn ensure_tables(&mut self, rig: &Rig, kind: DepthKind, stages: Option<&StageOptions>) {
        let key = (rig.depth, kind);
        if self.depth_rays.as_ref().is_none_or(|c| c.key != key) {
            let table = depth_ray_table(&rig.depth, kind);
            let buffer = self.upload("depth ray table", &table);
            self.depth_rays = Some(Cached { key, buffer, len: table.len() as u32 });
        }
        let (nearest_r, hole_r, grow_r) = stages
            .map_or((0.0, 0.0, 0.0), |s| (s.nearest_radius_px, s.hole_radius_px, s.hole_grow_px));
        if self.offsets.as_ref().is_none_or(|c| c.key != nearest_r.to_bits()) {
            let table: Vec<[i32; 2]> =
                disc_offsets(nearest_r).into_iter().map(|(dx, dy, _)| [dx, dy]).collect();
            let buffer = self.upload("disc offsets", &table);
            self.offsets =
                Some(Cached { key: nearest_r.to_bits(), buffer, len: table.len() as u32 });
        }
        if self.half_widths.as_ref().is_none_or(|c| c.key != hole_r.to_bits()) {
            let table = hole_half_widths(hole_r);
            let buffer = self.upload("hole half widths", &table);
            self.half_widths =
                Some(Cached { key: hole_r.to_bits(), buffer, len: table.len() as u32 });
        }
        if self.grow_half_widths.as_ref().is_none_or(|c| c.key != grow_r.to_bits()) {
            let table = hole_half_widths(grow_r);
            let buffer = self.upload("hole grow half widths", &table);
            self.grow_half_widths =
                Some(Cached { key: grow_r.to_bits(), buffer, len: table.len() as u32 });
        }
    }

    fn ensure_slot(&mut self, slot: usize, depth_size: (usize, usize), color_size: (usize, usize)) {
        if self
            .slots
            .get(slot)
            .is_some_and(|s| s.depth_size == depth_size && s.color_size == color_size)
        {
            return;
        }
        let s = self.new_slot(depth_size, color_size);
        if slot < self.slots.len() {
            self.slots[slot] = s;
        } else {
            self.slots.push(s);
        }
    }

    fn new_slot(&self, depth_size: (usize, usize), color_size: (usize, usize)) -> FrameSlot {
        use wgpu::BufferUsages as U;
        let n = (depth_size.0 * depth_size.1) as u64;
        let m = (color_size.0 * color_size.1) as u64;
        let (cw, ch) = (color_size.0 as u64, color_size.1 as u64);
        let buf = |label: &str, size: u64, usage: U| {
            self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.next_multiple_of(4).max(16),
                usage,
                mapped_at_creation: false,
            })
        };
        let storage = U::STORAGE | U::COPY_SRC | U::COPY_DST;
        let read = U::MAP_READ | U::COPY_DST;
        FrameSlot {
            depth_size,
            color_size,
            uniforms: (0..UNIFORM_COUNT)
                .map(|_| buf("params", size_of::<ProjectParams>() as u64, U::UNIFORM | U::COPY_DST))
                .collect(),
            depth: buf("depth", n * 4, storage),
            points: buf("points", n * 16, storage),
            samples: buf("samples", n * 16, storage),
            zbuffer: buf("zbuffer", m * 4, storage),
            nearest: buf("nearest fill", m * 4, storage),
            covered: buf("covered", m * 4, storage),
            row_extent: buf("row extents", ch * 8, storage),
            col_extent: buf("column extents", cw * 8, storage),
            core: buf("hole cores", m * 4, storage),
            holes: buf("holes", m * 4, storage),
            color: buf("colour image", m * 3, storage),
            rgba: buf("colour on depth", n * 4, storage),
            filled: buf("plane fill", m * 4, storage),
            read_z: buf("zbuffer read-back", m * 4, read),
            read_points: buf("points read-back", n * 16, read),
            read_samples: buf("samples read-back", n * 16, read),
            read_nearest: buf("nearest read-back", m * 4, read),
            read_holes: buf("holes read-back", m * 4, read),
            read_rgba: buf("colour on depth read-back", n * 4, read),
        }
    }

    /// Workgroups along x and y, and invocations per row, for `n` items.
    fn grid(&self, n: u32) -> (u32, u32, u32) {
        self.grid_sized(n, WORKGROUP_SIZE)
    }

    fn grid_sized(&self, n: u32, workgroup: u32) -> (u32, u32, u32) {
        let groups = n.div_ceil(workgroup).max(1);
        let max_x = self.limits.max_compute_workgroups_per_dimension.max(1);
        let x = groups.min(max_x);
        let y = groups.div_ceil(x);
        (x, y, x * workgroup)
    }

    fn bind(
        &self,
        pipe: &wgpu::ComputePipeline,
        entries: &[(u32, &wgpu::Buffer)],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = entries
            .iter()
            .map(|(binding, b)| wgpu::BindGroupEntry {
                binding: *binding,
                resource: b.as_entire_binding(),
            })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipe.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    fn submit(
        &self,
        slot: usize,
        frame: usize,
        depth: &Image<f32>,
        color: Option<&Image<[u8; 3]>>,
        proj: &ColorProjection,
        plan: &FramePlan,
    ) -> Result<Pending, GpuError> {
        let missing =
            || self.device_error("preparing a frame", "lookup tables were not uploaded".into());
        let rays = self.depth_rays.as_ref().ok_or_else(missing)?;
        let offsets = self.offsets.as_ref().ok_or_else(missing)?;
        let half_widths = self.half_widths.as_ref().ok_or_else(missing)?;
        let grow_half_widths = self.grow_half_widths.as_ref().ok_or_else(missing)?;
        let s = &self.slots[slot];
        let n = depth.data().len() as u32;
        let (cw, ch) = (proj.width, proj.height);
        let m = cw * ch;
        let (dx, dy, dstride) = self.grid(n);
        let (cx, cy, cstride) = self.grid(m);
        let (ex, ey, estride) = self.grid_sized(cw + ch, EXTENT_WORKGROUP_SIZE);
        let k = &self.kernels;
        let q = &self.queue;
        let u = &s.uniforms;

        q.write_buffer(
            &u[U_BACKPROJECT],
            0,
            bytemuck::bytes_of(&SizeParams { size: [n, dstride, 0, 0] }),
        );
        let r = &proj.rotation;
        let t = &proj.translation;
        let pp = ProjectParams {
            rows: [[r[0], r[1], r[2], t[0]], [r[3], r[4], r[5], t[1]], [r[6], r[7], r[8], t[2]]],
            k: [proj.fx, proj.fy, proj.cx, proj.cy],
            d0: [proj.skew, proj.k1, proj.k2, proj.p1],
            d1: [proj.p2, proj.k3, 0.0, 0.0],
            size: [cw, ch, n, dstride],
            opaque: [0; 4],
        };
        q.write_buffer(&u[U_PROJECT], 0, bytemuck::bytes_of(&pp));
        q.write_buffer(
            &u[U_ZCLEAR],
            0,
            bytemuck::bytes_of(&SizeParams { size: [cw, ch, m, cstride] }),
        );
        q.write_buffer(
            &u[U_ZSCATTER],
            0,
            bytemuck::bytes_of(&SizeParams { size: [cw, ch, n, dstride] }),
        );
        q.write_buffer(&s.depth, 0, bytemuck::cast_slice(depth.data()));

        let mut groups = vec![
            (&k.zclear, self.bind(&k.zclear, &[(0, &u[U_ZCLEAR]), (2, &s.zbuffer)]), (cx, cy)),
            (
                &k.backproject,
                self.bind(
                    &k.backproject,
                    &[(0, &u[U_BACKPROJECT]), (1, &s.depth), (2, &rays.buffer), (3, &s.points)],
                ),
                (dx, dy),
            ),
            (
                &k.project,
                self.bind(&k.project, &[(0, &u[U_PROJECT]), (1, &s.points), (2, &s.samples)]),
                (dx, dy),
            ),
            (
                &k.zscatter,
                self.bind(&k.zscatter, &[(0, &u[U_ZSCATTER]), (1, &s.samples), (2, &s.zbuffer)]),
                (dx, dy),
            ),
        ];
        let mut reads =
            Reads { intermediates: plan.read_intermediates, stages: false, color: false };
        if let Some(st) = &plan.stages {
            reads.stages = true;
            let np = NearestParams {
                size: [cw, ch, m, cstride],
                offsets: [offsets.len, 0, 0, 0],
                jump: [st.depth_jump, 0.0, 0.0, 0.0],
            };
            q.write_buffer(&u[U_NEAREST], 0, bytemuck::bytes_of(&np));
            let radius =
                [half_widths.len.saturating_sub(1), grow_half_widths.len.saturating_sub(1), 0, 0];
            let hc = HoleParams { size: [cw, ch, cw + ch, estride], radius };
            q.write_buffer(&u[U_HOLE_CLEAR], 0, bytemuck::bytes_of(&hc));
            let hp = HoleParams { size: [cw, ch, m, cstride], radius };
            q.write_buffer(&u[U_HOLE], 0, bytemuck::bytes_of(&hp));
            groups.push((
                &k.nearest,
                self.bind(
                    &k.nearest,
                    &[(0, &u[U_NEAREST]), (1, &s.zbuffer), (2, &offsets.buffer), (3, &s.nearest)],
                ),
                (cx, cy),
            ));
            groups.push((
                &k.hole_cover,
                self.bind(
                    &k.hole_cover,
                    &[(0, &u[U_HOLE]), (1, &s.zbuffer), (2, &half_widths.buffer), (3, &s.covered)],
                ),
                (cx, cy),
            ));
            groups.push((
                &k.hole_extents,
                self.bind(
                    &k.hole_extents,
                    &[
                        (0, &u[U_HOLE_CLEAR]),
                        (3, &s.covered),
                        (4, &s.row_extent),
                        (5, &s.col_extent),
                    ],
                ),
                (ex, ey),
            ));
            groups.push((
                &k.hole_core,
                self.bind(
                    &k.hole_core,
                    &[
                        (0, &u[U_HOLE]),
                        (3, &s.covered),
                        (4, &s.row_extent),
                        (5, &s.col_extent),
                        (6, &s.core),
                    ],
                ),
                (cx, cy),
            ));
            groups.push((
                &k.hole_grow,
                self.bind(
                    &k.hole_grow,
                    &[
                        (0, &u[U_HOLE]),
                        (1, &s.zbuffer),
                        (6, &s.core),
                        (7, &grow_half_widths.buffer),
                        (8, &s.holes),
                    ],
                ),
                (cx, cy),
            ));
            if let Some(c) = color {
                reads.color = true;
                write_padded(q, &s.color, bytemuck::cast_slice(c.data()));
                let (tol, on) = st.occlusion_tolerance.map_or((0.0, 0.0), |t| (t, 1.0));
                let cp = ColorParams {
                    size: [cw, ch, n, dstride],
                    occlusion: [tol, on, 0.0, 0.0],
                    opaque: [0; 4],
                };
                q.write_buffer(&u[U_COLOR], 0, bytemuck::bytes_of(&cp));
                groups.push((
                    &k.color,
                    self.bind(
                        &k.color,
                        &[
                            (0, &u[U_COLOR]),
                            (1, &s.samples),
                            (2, &s.color),
                            (3, &s.nearest),
                            (4, &s.rgba),
                        ],
                    ),
                    (dx, dy),
                ));
            }
        }

        let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("fusion frame"),
        });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("fusion"),
                timestamp_writes: None,
            });
            for (pipe, group, (gx, gy)) in &groups {
                pass.set_pipeline(pipe);
                pass.set_bind_group(0, group, &[]);
                pass.dispatch_workgroups(*gx, *gy, 1);
            }
        }
        let zbytes = m as u64 * 4;
        let dbytes = n as u64 * 16;
        let mut copies: Vec<(&wgpu::Buffer, &wgpu::Buffer, u64)> =
            vec![(&s.zbuffer, &s.read_z, zbytes)];
        if reads.intermediates {
            copies.push((&s.points, &s.read_points, dbytes));
            copies.push((&s.samples, &s.read_samples, dbytes));
        }
        if reads.stages {
            copies.push((&s.nearest, &s.read_nearest, zbytes));
            copies.push((&s.holes, &s.read_holes, zbytes));
        }
        if reads.color {
            copies.push((&s.rgba, &s.read_rgba, n as u64 * 4));
        }
        for (src, dst, bytes) in &copies {
            enc.copy_buffer_to_buffer(src, 0, dst, 0, *bytes);
        }
        let submission = q.submit([enc.finish()]);
        let (tx, rx) = mpsc::channel();
        for (_, dst, bytes) in &copies {
            let tx = tx.clone();
            dst.map_async(wgpu::MapMode::Read, 0..*bytes, move |r| {
                let _ = tx.send(r);
            });
        }
        self.check_errors("submitting a frame")?;
        Ok(Pending { slot, frame, submission, reads, mapped: rx, maps: copies.len() })
    }

    fn wait(
        &self,
        submission: wgpu::SubmissionIndex,
        mapped: &mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
        maps: usize,
    ) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::Wait { submission_index: Some(submission), timeout: None })
            .map_err(|e| self.device_error("waiting for a frame", e.to_string()))?;
        for _ in 0..maps {
            match mapped.recv() {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    return Err(self.device_error("mapping the read-back buffers", e.to_string()));
                }
                Err(e) => {
                    return Err(self.device_error("mapping the read-back buffers", e.to_string()));
                }
            }
        }
        self.check_errors("running a frame")
    }

    fn read_mapped<T: Pod>(&self, buffer: &wgpu::Buffer, bytes: u64) -> Result<Vec<T>, GpuError> {
        let v = {
            let view = buffer
                .get_mapped_range(0..bytes)
                .map_err(|e| self.device_error("reading back", e.to_string()))?;
            bytemuck::pod_collect_to_vec(&view)
        };
        buffer.unmap();
        Ok(v)
    }

    fn finish(&mut self, p: Pending) -> Result<(usize, GpuFrame), GpuError> {
        self.wait(p.submission, &p.mapped, p.maps)?;
        let s = &self.slots[p.slot];
        let (cw, ch) = s.color_size;
        let (dw, dh) = s.depth_size;
        let (m, n) = ((cw * ch) as u64, (dw * dh) as u64);
        let zbuffer = Image::from_vec(cw, ch, self.read_mapped(&s.read_z, m * 4)?)?;
        let (mut points, mut samples, mut nearest, mut holes, mut color_on_depth) =
            (None, None, None, None, None);
        if p.reads.intermediates {
            points = Some(self.read_mapped(&s.read_points, n * 16)?);
            samples = Some(self.read_mapped(&s.read_samples, n * 16)?);
        }
        if p.reads.stages {
            nearest = Some(Image::from_vec(cw, ch, self.read_mapped(&s.read_nearest, m * 4)?)?);
            let h: Vec<u32> = self.read_mapped(&s.read_holes, m * 4)?;
            holes = Some(Image::from_vec(cw, ch, h.into_iter().map(|b| b == 1).collect())?);
        }
        if p.reads.color {
            let rgba: Vec<u32> = self.read_mapped(&s.read_rgba, n * 4)?;
            let rgb = rgba.iter().map(|&c| [c as u8, (c >> 8) as u8, (c >> 16) as u8]).collect();
            let valid = rgba.iter().map(|&c| c >> 24 == 0xff).collect();
            color_on_depth = Some((Image::from_vec(dw, dh, rgb)?, Image::from_vec(dw, dh, valid)?));
        }
        Ok((p.frame, GpuFrame { zbuffer, points, samples, nearest, holes, color_on_depth }))
    }
}

/// Writes `bytes` to the start of `buffer`; wgpu copies whole 4-byte words, so a tail of 1-3
/// bytes (an RGB image with an odd pixel count) is padded with zeros.
fn write_padded(queue: &wgpu::Queue, buffer: &wgpu::Buffer, bytes: &[u8]) {
    let aligned = bytes.len() / 4 * 4;
    if aligned > 0 {
        queue.write_buffer(buffer, 0, &bytes[..aligned]);
    }
    if aligned < bytes.len() {
        let mut tail = [0u8; 4];
        tail[..bytes.len() - aligned].copy_from_slice(&bytes[aligned..]);
        queue.write_buffer(buffer, aligned as u64, &tail);
    }
}

fn pipeline(device: &wgpu::Device, file: &str, source: &str, entry: &str) -> wgpu::ComputePipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(file),
        source: wgpu::ShaderSource::Wgsl(source.into()),
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
