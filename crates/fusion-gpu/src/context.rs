//! [`FusionContext`]: the wgpu device, queue, compute pipelines and per-frame buffers, reused
//! across frames. (About 700 lines: the context's state, its buffers and the streaming loop
//! that owns them, over depth images or raw frames decoded on the GPU; the stages are in
//! [`crate::stages`], a frame's wiring in `submit.rs`, the decoder in `decode.rs`.)

use std::collections::VecDeque;
use std::sync::mpsc;
use std::sync::{Arc, Mutex};

use bytemuck::Pod;
use geometry::fusion::{ColorProjection, depth_ray_table};
use geometry::{CameraModel, DepthKind, Image, Rig};

use geometry::fusion::disc_offsets;

use crate::stages::{backproject, color, holes, nearest, plane, project, zbuffer};
use crate::submit::write_padded;
use crate::tables::hole_half_widths;
use crate::{GpuDecoder, GpuError};

/// Invocations per workgroup of every kernel (the `@workgroup_size` in the shaders): 256 is a
/// multiple of every vendor's SIMD width and within WebGPU's default limit.
const WORKGROUP_SIZE: u32 = 256;

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

/// The compiled pipelines of every stage (see [`crate::stages`]).
pub(crate) struct Kernels {
    pub(crate) backproject: wgpu::ComputePipeline,
    pub(crate) project: wgpu::ComputePipeline,
    pub(crate) zbuffer: zbuffer::Pipelines,
    pub(crate) nearest: wgpu::ComputePipeline,
    pub(crate) holes: holes::Pipelines,
    pub(crate) color: wgpu::ComputePipeline,
    pub(crate) plane_fill: wgpu::ComputePipeline,
}

/// A device buffer built from host data, with the key it was built from.
pub(crate) struct Cached<K> {
    pub(crate) key: K,
    pub(crate) buffer: wgpu::Buffer,
    pub(crate) len: u32,
}

/// Everything one in-flight frame needs: inputs, intermediates, outputs, read-back buffers.
pub(crate) struct FrameSlot {
    pub(crate) depth_size: (usize, usize),
    pub(crate) color_size: (usize, usize),
    pub(crate) uniforms: Vec<wgpu::Buffer>,
    pub(crate) depth: wgpu::Buffer,
    pub(crate) points: wgpu::Buffer,
    pub(crate) samples: wgpu::Buffer,
    pub(crate) zbuffer: wgpu::Buffer,
    pub(crate) nearest: wgpu::Buffer,
    pub(crate) covered: wgpu::Buffer,
    pub(crate) row_extent: wgpu::Buffer,
    pub(crate) col_extent: wgpu::Buffer,
    pub(crate) core: wgpu::Buffer,
    pub(crate) holes: wgpu::Buffer,
    pub(crate) color: wgpu::Buffer,
    pub(crate) rgba: wgpu::Buffer,
    pub(crate) filled: wgpu::Buffer,
    pub(crate) read_z: wgpu::Buffer,
    pub(crate) read_points: wgpu::Buffer,
    pub(crate) read_samples: wgpu::Buffer,
    pub(crate) read_nearest: wgpu::Buffer,
    pub(crate) read_holes: wgpu::Buffer,
    pub(crate) read_rgba: wgpu::Buffer,
}

/// Uniform buffer indices of a slot.
pub(crate) const U_BACKPROJECT: usize = 0;
pub(crate) const U_PROJECT: usize = 1;
pub(crate) const U_ZCLEAR: usize = 2;
pub(crate) const U_ZSCATTER: usize = 3;
pub(crate) const U_NEAREST: usize = 4;
pub(crate) const U_HOLE_CLEAR: usize = 5;
pub(crate) const U_HOLE: usize = 6;
pub(crate) const U_COLOR: usize = 7;
pub(crate) const U_PLANE: usize = 8;
pub(crate) const UNIFORM_COUNT: usize = 9;
/// Bytes of every uniform buffer: the largest parameter struct (H2's projection).
pub(crate) const UNIFORM_BYTES: u64 = size_of::<project::Params>() as u64;

/// What a submitted frame will read back.
#[derive(Clone, Copy)]
pub(crate) struct Reads {
    pub(crate) intermediates: bool,
    pub(crate) stages: bool,
    pub(crate) color: bool,
}

/// A submitted frame whose results are not read yet.
pub(crate) struct Pending {
    pub(crate) slot: usize,
    pub(crate) frame: usize,
    pub(crate) submission: wgpu::SubmissionIndex,
    pub(crate) reads: Reads,
    pub(crate) mapped: mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
    pub(crate) maps: usize,
}

/// Source of the per-context ids that tie a [`crate::GpuDecoder`] to its context.
static NEXT_CONTEXT_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// Where a frame's depth comes from.
pub(crate) enum DepthInput<'a> {
    /// A depth image in metres, uploaded.
    Metres(&'a Image<f32>),
    /// A raw Kinect v2 frame, uploaded and decoded on the GPU into the depth buffer.
    Raw { decoder: &'a GpuDecoder, raw: &'a [u8] },
}

/// The GPU fusion engine: device, queue, compiled pipelines and buffers reused from frame to
/// frame (re-allocated only when the image sizes change). Create once, run many frames.
pub struct FusionContext {
    /// Unique per context (a decoder's buffers belong to one device).
    pub(crate) id: u64,
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    pub(crate) info: wgpu::AdapterInfo,
    pub(crate) limits: wgpu::Limits,
    pub(crate) kernels: Kernels,
    pub(crate) depth_rays: Option<Cached<(CameraModel, DepthKind)>>,
    pub(crate) color_rays: Option<(Cached<CameraModel>, Vec<[f32; 2]>)>,
    pub(crate) offsets: Option<Cached<u32>>,
    pub(crate) half_widths: Option<Cached<u32>>,
    pub(crate) grow_half_widths: Option<Cached<u32>>,
    pub(crate) slots: Vec<FrameSlot>,
    pub(crate) errors: Arc<Mutex<Vec<String>>>,
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
        // Listing the adapters makes libwayland print a line on headless machines.
        let adapter = crate::quiet::without_wayland_noise(|| {
            let instance = wgpu::Instance::new(desc);
            pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                force_fallback_adapter: false,
                compatible_surface: None,
                apply_limit_buckets: false,
            }))
        })
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
            backproject: backproject::pipeline(&device),
            project: project::pipeline(&device),
            zbuffer: zbuffer::Pipelines::new(&device),
            nearest: nearest::pipeline(&device),
            holes: holes::Pipelines::new(&device),
            color: color::pipeline(&device),
            plane_fill: plane::pipeline(&device),
        };
        let ctx = Self {
            id: NEXT_CONTEXT_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
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
    /// `read_intermediates`). Bit-identical to [`geometry::fusion::Registration`].
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
        sink: F,
    ) -> Result<usize, GpuError>
    where
        I: IntoIterator<Item = (&'a Image<f32>, Option<&'a Image<[u8; 3]>>)>,
        F: FnMut(usize, GpuFrame),
    {
        let frames = frames.into_iter().map(|(d, c)| (DepthInput::Metres(d), c));
        self.stream_inputs(rig, kind, frames, plan, sink)
    }

    /// [`FusionContext::stream`] on any [`DepthInput`].
    pub(crate) fn stream_inputs<'a, I, F>(
        &mut self,
        rig: &Rig,
        kind: DepthKind,
        frames: I,
        plan: FramePlan,
        mut sink: F,
    ) -> Result<usize, GpuError>
    where
        I: IntoIterator<Item = (DepthInput<'a>, Option<&'a Image<[u8; 3]>>)>,
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
            let sizes = match &depth {
                DepthInput::Metres(d) => {
                    d.expect_size("depth image", depth_size.0, depth_size.1).map_err(GpuError::from)
                }
                DepthInput::Raw { raw, .. } => GpuDecoder::check_raw(raw),
            }
            .and_then(|()| {
                color.map_or(Ok(()), |c| {
                    c.expect_size("colour image", color_size.0, color_size.1).map_err(Into::into)
                })
            });
            if let Err(e) = sizes {
                // Let the frames in flight complete so their read-back buffers are unmapped
                // and the context stays usable; their results are dropped with the error.
                while let Some(p) = pending.pop_front() {
                    let _ = self.finish(p);
                }
                return Err(e);
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

    pub(crate) fn device_error(&self, during: &'static str, message: String) -> GpuError {
        GpuError::Device { adapter: self.info.name.clone(), during, message }
    }

    pub(crate) fn check_errors(&self, during: &'static str) -> Result<(), GpuError> {
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

    pub(crate) fn upload<T: Pod>(&self, label: &str, data: &[T]) -> wgpu::Buffer {
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

    pub(crate) fn ensure_color_rays(&mut self, camera: &CameraModel) {
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

    pub(crate) fn ensure_slot(
        &mut self,
        slot: usize,
        depth_size: (usize, usize),
        color_size: (usize, usize),
    ) {
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
                .map(|_| buf("params", UNIFORM_BYTES, U::UNIFORM | U::COPY_DST))
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
    pub(crate) fn grid(&self, n: u32) -> (u32, u32, u32) {
        self.grid_sized(n, WORKGROUP_SIZE)
    }

    pub(crate) fn grid_sized(&self, n: u32, workgroup: u32) -> (u32, u32, u32) {
        let groups = n.div_ceil(workgroup).max(1);
        let max_x = self.limits.max_compute_workgroups_per_dimension.max(1);
        let x = groups.min(max_x);
        let y = groups.div_ceil(x);
        (x, y, x * workgroup)
    }

    pub(crate) fn bind(
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

    pub(crate) fn wait(
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

    pub(crate) fn read_mapped<T: Pod>(
        &self,
        buffer: &wgpu::Buffer,
        bytes: u64,
    ) -> Result<Vec<T>, GpuError> {
        let v = {
            let view = buffer
                .get_mapped_range(0..bytes)
                .map_err(|e| self.device_error("reading back", e.to_string()))?;
            bytemuck::pod_collect_to_vec(&view)
        };
        buffer.unmap();
        Ok(v)
    }

    pub(crate) fn finish(&mut self, p: Pending) -> Result<(usize, GpuFrame), GpuError> {
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
