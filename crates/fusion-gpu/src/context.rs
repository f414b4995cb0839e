//! [`FusionContext`]: the wgpu device, queue, compute pipelines and per-frame buffers, reused
//! across frames.

use std::collections::VecDeque;
use std::sync::mpsc;
use std::sync::{Arc, Mutex};

use bytemuck::{Pod, Zeroable};
use geometry::fusion::{depth_ray_table, ColorProjection};
use geometry::{CameraModel, DepthKind, Image, Rig};

use crate::{shaders, GpuError};

/// Invocations per workgroup of every kernel (the `@workgroup_size` in the shaders): 256 is a
/// multiple of every vendor's SIMD width and within WebGPU's default limit.
const WORKGROUP_SIZE: u32 = 256;

/// Frame slots of the streaming mode: two, so one frame computes while the previous one is
/// read back and the next one uploads.
const STREAM_SLOTS: usize = 2;

/// What to do when no adapter is found. The library never falls back by itself: both
/// policies make [`FusionContext::new`] return [`GpuError::NoAdapter`]; the policy tells the
/// caller (the CLI's `--gpu` / `--gpu auto`) whether it may fall back to the CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GpuPolicy {
    /// The GPU was asked for explicitly: no adapter is an error.
    #[default]
    Required,
    /// Use a GPU when there is one, otherwise the caller runs the CPU pipeline (with a warning).
    Auto,
}

impl GpuPolicy {
    /// True when the caller may run the CPU pipeline instead after [`GpuError::NoAdapter`].
    pub fn falls_back_to_cpu(self) -> bool {
        matches!(self, GpuPolicy::Auto)
    }
}

/// One frame's results read back from the GPU.
#[derive(Debug, Clone, PartialEq)]
pub struct GpuFrame {
    /// H7: colour-sized z-buffer, smallest colour-frame `z` per pixel (metres), and
    /// [`geometry::fusion::ZBUFFER_EMPTY`] (a NaN with all bits set) where no sample landed.
    pub zbuffer: Image<f32>,
    /// H1, when [`ReadBack::points`] was asked for: one entry per depth pixel,
    /// `[X, Y, Z, 1]` (depth camera frame, metres) or all zero for no point.
    pub points: Option<Vec<[f32; 4]>>,
    /// H2, when [`ReadBack::samples`] was asked for: one entry per depth pixel,
    /// `[u, v, z_color, 1]` when in front of the colour camera (the pixel may lie outside the
    /// colour image), all zero otherwise.
    pub samples: Option<Vec<[f32; 4]>>,
}

/// Which intermediate results to copy back besides the z-buffer (each costs read-back time).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ReadBack {
    /// H1's per-pixel points.
    pub points: bool,
    /// H2's per-pixel colour samples.
    pub samples: bool,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct CountParams {
    count: u32,
    row_stride: u32,
    _pad: [u32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ProjectParams {
    rows: [[f32; 4]; 3],
    k: [f32; 4],
    d0: [f32; 4],
    d1: [f32; 4],
    size: [u32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct SizeParams {
    size: [u32; 4],
}

struct Kernels {
    backproject: wgpu::ComputePipeline,
    project: wgpu::ComputePipeline,
    zclear: wgpu::ComputePipeline,
    zscatter: wgpu::ComputePipeline,
}

/// The ray table on the device for one depth camera and depth kind.
struct Rays {
    camera: CameraModel,
    kind: DepthKind,
    buffer: wgpu::Buffer,
}

/// Everything one in-flight frame needs: its own inputs, intermediates, outputs, read-back
/// buffers and bind groups.
struct FrameSlot {
    depth_size: (usize, usize),
    color_size: (usize, usize),
    depth: wgpu::Buffer,
    points: wgpu::Buffer,
    samples: wgpu::Buffer,
    zbuffer: wgpu::Buffer,
    u_backproject: wgpu::Buffer,
    u_project: wgpu::Buffer,
    u_zclear: wgpu::Buffer,
    u_zscatter: wgpu::Buffer,
    read_z: wgpu::Buffer,
    read_points: wgpu::Buffer,
    read_samples: wgpu::Buffer,
    /// Bind groups, rebuilt when the ray buffer changes.
    groups: Option<SlotGroups>,
}

struct SlotGroups {
    rays_id: u64,
    backproject: wgpu::BindGroup,
    project: wgpu::BindGroup,
    zclear: wgpu::BindGroup,
    zscatter: wgpu::BindGroup,
}

/// A submitted frame whose results are not read yet.
struct Pending {
    slot: usize,
    frame: usize,
    submission: wgpu::SubmissionIndex,
    read: ReadBack,
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
    rays: Option<Rays>,
    rays_id: u64,
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
    /// Fails with [`GpuError::NoAdapter`] when there is none, whatever the `policy`; see
    /// [`GpuPolicy`] for what the caller does then.
    pub fn new(policy: GpuPolicy) -> Result<Self, GpuError> {
        let _ = policy;
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        // Only the Vulkan backend is compiled in; asking for others would find nothing.
        desc.backends &= wgpu::Backends::VULKAN;
        if desc.backends.is_empty() {
            desc.backends = wgpu::Backends::VULKAN;
        }
        let backends = format!("{:?}", desc.backends);
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
        .map_err(|e| GpuError::RequestDevice { adapter: info.name.clone(), message: e.to_string() })?;

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
        };
        let ctx = Self { device, queue, info, limits, kernels, rays: None, rays_id: 0, slots: Vec::new(), errors };
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
            self.info.name, self.info.device_type, self.info.backend, self.info.driver, self.info.driver_info
        )
    }

    /// True for a software adapter (lavapipe / llvmpipe): correct, but slower than the CPU path.
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// The largest storage-buffer binding of this adapter, bytes (lavapipe: 128 MiB).
    pub fn max_binding_bytes(&self) -> u64 {
        (self.limits.max_storage_buffer_binding_size as u64).min(self.limits.max_buffer_size)
    }

    /// Checks that frames of these sizes fit the adapter, without allocating anything.
    pub fn check_frame_size(&self, depth: (usize, usize), color: (usize, usize)) -> Result<(), GpuError> {
        let limit = self.max_binding_bytes();
        let needs: [(&'static str, (usize, usize), u64); 3] = [
            ("depth image", depth, 4),
            ("per-pixel point", depth, 16),
            ("colour z-buffer", color, 4),
        ];
        for (buffer, (w, h), bytes_per_pixel) in needs {
            let bytes = (w as u64).saturating_mul(h as u64).saturating_mul(bytes_per_pixel);
            if bytes > limit || w.saturating_mul(h) > u32::MAX as usize / 4 {
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

    /// H1 + H2 + H7 for one depth frame: the colour-sized z-buffer, and the intermediates
    /// asked for in `read`. Bit-identical to [`geometry::fusion::register_depth`].
    pub fn register(&mut self, rig: &Rig, depth: &Image<f32>, kind: DepthKind, read: ReadBack) -> Result<GpuFrame, GpuError> {
        let mut out = None;
        self.stream(rig, kind, std::iter::once(depth), read, |_, frame| out = Some(frame))?;
        out.ok_or_else(|| GpuError::Device {
            adapter: self.info.name.clone(),
            during: "reading back the frame",
            message: "no result was produced".into(),
        })
    }

    /// Streaming mode: registers every depth frame of `frames` (all the size of
    /// `rig.depth`), handing each result to `sink(frame_index, frame)` in order. Two frame
    /// slots alternate so that frame `k + 1` uploads and computes while frame `k` is read
    /// back (`map_async`).
    pub fn stream<'a, I, F>(&mut self, rig: &Rig, kind: DepthKind, frames: I, read: ReadBack, mut sink: F) -> Result<usize, GpuError>
    where
        I: IntoIterator<Item = &'a Image<f32>>,
        F: FnMut(usize, GpuFrame),
    {
        rig.validate()?;
        let depth_size = (rig.depth.width, rig.depth.height);
        let color_size = (rig.color.width, rig.color.height);
        self.check_frame_size(depth_size, color_size)?;
        self.ensure_rays(&rig.depth, kind);
        let proj = ColorProjection::from_rig(rig);
        let mut pending: VecDeque<Pending> = VecDeque::new();
        let mut count = 0;
        for (k, depth) in frames.into_iter().enumerate() {
            depth.expect_size("depth image", depth_size.0, depth_size.1)?;
            let slot = k % STREAM_SLOTS;
            if let Some(pos) = pending.iter().position(|p| p.slot == slot) {
                // Frames complete in order: finish everything up to this slot's last frame.
                for _ in 0..=pos {
                    let p = pending.pop_front().expect("position() found it");
                    let (frame, result) = self.finish(p)?;
                    sink(frame, result);
                }
            }
            self.ensure_slot(slot, depth_size, color_size);
            let p = self.submit(slot, k, depth, &proj, read)?;
            pending.push_back(p);
            count += 1;
        }
        while let Some(p) = pending.pop_front() {
            let (frame, result) = self.finish(p)?;
            sink(frame, result);
        }
        Ok(count)
    }

    fn check_errors(&self, during: &'static str) -> Result<(), GpuError> {
        let mut errors = self.errors.lock().map_err(|_| GpuError::Device {
            adapter: self.info.name.clone(),
            during,
            message: "error handler poisoned".into(),
        })?;
        if errors.is_empty() {
            return Ok(());
        }
        let message = errors.join("; ");
        errors.clear();
        Err(GpuError::Device { adapter: self.info.name.clone(), during, message })
    }

    fn ensure_rays(&mut self, camera: &CameraModel, kind: DepthKind) {
        if let Some(r) = &self.rays {
            if r.camera == *camera && r.kind == kind {
                return;
            }
        }
        let table = depth_ray_table(camera, kind);
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("depth ray table"),
            size: (table.len() * 12).max(16) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.queue.write_buffer(&buffer, 0, bytemuck::cast_slice(&table));
        self.rays = Some(Rays { camera: *camera, kind, buffer });
        self.rays_id += 1;
    }

    fn ensure_slot(&mut self, slot: usize, depth_size: (usize, usize), color_size: (usize, usize)) {
        if self.slots.get(slot).is_some_and(|s| s.depth_size == depth_size && s.color_size == color_size) {
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
        let buf = |label: &str, size: u64, usage: U| {
            self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(16),
                usage,
                mapped_at_creation: false,
            })
        };
        FrameSlot {
            depth_size,
            color_size,
            depth: buf("depth", n * 4, U::STORAGE | U::COPY_DST),
            points: buf("points", n * 16, U::STORAGE | U::COPY_SRC),
            samples: buf("samples", n * 16, U::STORAGE | U::COPY_SRC),
            zbuffer: buf("zbuffer", m * 4, U::STORAGE | U::COPY_SRC),
            u_backproject: buf("backproject params", 16, U::UNIFORM | U::COPY_DST),
            u_project: buf("project params", size_of::<ProjectParams>() as u64, U::UNIFORM | U::COPY_DST),
            u_zclear: buf("zclear params", 16, U::UNIFORM | U::COPY_DST),
            u_zscatter: buf("zscatter params", 16, U::UNIFORM | U::COPY_DST),
            read_z: buf("zbuffer read-back", m * 4, U::MAP_READ | U::COPY_DST),
            read_points: buf("points read-back", n * 16, U::MAP_READ | U::COPY_DST),
            read_samples: buf("samples read-back", n * 16, U::MAP_READ | U::COPY_DST),
            groups: None,
        }
    }

    /// Workgroups along x and y, and invocations per row, for `n` items.
    fn grid(&self, n: u32) -> (u32, u32, u32) {
        let groups = n.div_ceil(WORKGROUP_SIZE).max(1);
        let max_x = self.limits.max_compute_workgroups_per_dimension.max(1);
        let x = groups.min(max_x);
        let y = groups.div_ceil(x);
        (x, y, x * WORKGROUP_SIZE)
    }

    fn submit(&mut self, slot: usize, frame: usize, depth: &Image<f32>, proj: &ColorProjection, read: ReadBack) -> Result<Pending, GpuError> {
        let rays = self.rays.as_ref().expect("ensure_rays ran before submit");
        let n = depth.data().len() as u32;
        let m = proj.width * proj.height;
        let (dx, dy, depth_stride) = self.grid(n);
        let (cx, cy, color_stride) = self.grid(m);
        let s = &mut self.slots[slot];
        if s.groups.as_ref().is_none_or(|g| g.rays_id != self.rays_id) {
            let bind = |pipe: &wgpu::ComputePipeline, entries: &[(u32, &wgpu::Buffer)]| {
                let entries: Vec<wgpu::BindGroupEntry> = entries
                    .iter()
                    .map(|(binding, b)| wgpu::BindGroupEntry { binding: *binding, resource: b.as_entire_binding() })
                    .collect();
                self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: None,
                    layout: &pipe.get_bind_group_layout(0),
                    entries: &entries,
                })
            };
            let k = &self.kernels;
            s.groups = Some(SlotGroups {
                rays_id: self.rays_id,
                backproject: bind(&k.backproject, &[(0, &s.u_backproject), (1, &s.depth), (2, &rays.buffer), (3, &s.points)]),
                project: bind(&k.project, &[(0, &s.u_project), (1, &s.points), (2, &s.samples)]),
                zclear: bind(&k.zclear, &[(0, &s.u_zclear), (2, &s.zbuffer)]),
                zscatter: bind(&k.zscatter, &[(0, &s.u_zscatter), (1, &s.samples), (2, &s.zbuffer)]),
            });
        }
        let g = s.groups.as_ref().expect("just built");
        let q = &self.queue;
        q.write_buffer(&s.u_backproject, 0, bytemuck::bytes_of(&CountParams { count: n, row_stride: depth_stride, _pad: [0; 2] }));
        let r = &proj.rotation;
        let t = &proj.translation;
        let pp = ProjectParams {
            rows: [[r[0], r[1], r[2], t[0]], [r[3], r[4], r[5], t[1]], [r[6], r[7], r[8], t[2]]],
            k: [proj.fx, proj.fy, proj.cx, proj.cy],
            d0: [proj.skew, proj.k1, proj.k2, proj.p1],
            d1: [proj.p2, proj.k3, 0.0, 0.0],
            size: [proj.width, proj.height, n, depth_stride],
        };
        q.write_buffer(&s.u_project, 0, bytemuck::bytes_of(&pp));
        q.write_buffer(&s.u_zclear, 0, bytemuck::bytes_of(&SizeParams { size: [proj.width, proj.height, m, color_stride] }));
        q.write_buffer(&s.u_zscatter, 0, bytemuck::bytes_of(&SizeParams { size: [proj.width, proj.height, n, depth_stride] }));
        q.write_buffer(&s.depth, 0, bytemuck::cast_slice(depth.data()));

        let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("fusion frame") });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("H1 H2 H7"), timestamp_writes: None });
            let k = &self.kernels;
            pass.set_pipeline(&k.zclear);
            pass.set_bind_group(0, &g.zclear, &[]);
            pass.dispatch_workgroups(cx, cy, 1);
            pass.set_pipeline(&k.backproject);
            pass.set_bind_group(0, &g.backproject, &[]);
            pass.dispatch_workgroups(dx, dy, 1);
            pass.set_pipeline(&k.project);
            pass.set_bind_group(0, &g.project, &[]);
            pass.dispatch_workgroups(dx, dy, 1);
            pass.set_pipeline(&k.zscatter);
            pass.set_bind_group(0, &g.zscatter, &[]);
            pass.dispatch_workgroups(dx, dy, 1);
        }
        let zbytes = m as u64 * 4;
        let dbytes = n as u64 * 16;
        enc.copy_buffer_to_buffer(&s.zbuffer, 0, &s.read_z, 0, zbytes);
        if read.points {
            enc.copy_buffer_to_buffer(&s.points, 0, &s.read_points, 0, dbytes);
        }
        if read.samples {
            enc.copy_buffer_to_buffer(&s.samples, 0, &s.read_samples, 0, dbytes);
        }
        let submission = q.submit([enc.finish()]);
        let (tx, rx) = mpsc::channel();
        let mut maps = 0;
        for (wanted, buffer, bytes) in [(true, &s.read_z, zbytes), (read.points, &s.read_points, dbytes), (read.samples, &s.read_samples, dbytes)] {
            if wanted {
                let tx = tx.clone();
                buffer.map_async(wgpu::MapMode::Read, 0..bytes, move |r| {
                    let _ = tx.send(r);
                });
                maps += 1;
            }
        }
        self.check_errors("submitting a frame")?;
        Ok(Pending { slot, frame, submission, read, mapped: rx, maps })
    }

    fn finish(&mut self, p: Pending) -> Result<(usize, GpuFrame), GpuError> {
        let adapter = self.info.name.clone();
        let device_err = |during: &'static str, message: String| GpuError::Device { adapter: adapter.clone(), during, message };
        self.device
            .poll(wgpu::PollType::Wait { submission_index: Some(p.submission), timeout: None })
            .map_err(|e| device_err("waiting for a frame", e.to_string()))?;
        for _ in 0..p.maps {
            match p.mapped.recv() {
                Ok(Ok(())) => {}
                Ok(Err(e)) => return Err(device_err("mapping the read-back buffers", e.to_string())),
                Err(e) => return Err(device_err("mapping the read-back buffers", e.to_string())),
            }
        }
        self.check_errors("running a frame")?;
        let s = &self.slots[p.slot];
        let (cw, ch) = s.color_size;
        let n = s.depth_size.0 * s.depth_size.1;
        let read_vec = |buffer: &wgpu::Buffer, bytes: u64| -> Result<Vec<u8>, GpuError> {
            let v = {
                let view = buffer
                    .get_mapped_range(0..bytes)
                    .map_err(|e| device_err("reading back", e.to_string()))?;
                view.to_vec()
            };
            buffer.unmap();
            Ok(v)
        };
        let z: Vec<f32> = bytemuck::pod_collect_to_vec(&read_vec(&s.read_z, (cw * ch * 4) as u64)?);
        let zbuffer = Image::from_vec(cw, ch, z)?;
        let points = if p.read.points {
            Some(bytemuck::pod_collect_to_vec(&read_vec(&s.read_points, (n * 16) as u64)?))
        } else {
            None
        };
        let samples = if p.read.samples {
            Some(bytemuck::pod_collect_to_vec(&read_vec(&s.read_samples, (n * 16) as u64)?))
        } else {
            None
        };
        Ok((p.frame, GpuFrame { zbuffer, points, samples }))
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
