//! [`FusionContext`]: the device, the frame's stages ([`crate::stages::FRAME`]), the lookup
//! tables and two frame slots, reused across frames, and the streaming loop that owns them,
//! over depth images or raw frames decoded on the GPU (`decode.rs`). A frame's submission is
//! the list of its stages' `encode` calls ([`FusionContext::submit`]); every stage owns its
//! pipelines, uniforms and bind groups.

use std::collections::VecDeque;
use std::sync::mpsc;

use geometry::fusion::{ColorProjection, DepthRange, DepthView, ZBUFFER_EMPTY};
use geometry::{CameraModel, DepthKind, Image, Rig};

use crate::error::GpuError;
use crate::frame::{FrameBuffers, Reads, Tables, Work};
use crate::gpu::{Gpu, write_padded};
use crate::plan::{FramePlan, GpuFrame};
use crate::stages::decode::Decode;
use crate::stages::plane::PlaneFill;
use crate::stages::{FRAME, Stage};

/// Frame slots of the streaming mode: two, so one frame computes while the previous one is
/// read back and the next one uploads.
const STREAM_SLOTS: usize = 2;

/// A frame slot: the buffers its stages share, and the tables generation its stages were
/// bound to (`None`: not yet).
struct FrameSlot {
    buffers: FrameBuffers,
    bound: Option<u64>,
}

/// A submitted frame whose results are not read yet.
pub(crate) struct Pending {
    slot: usize,
    frame: usize,
    submission: wgpu::SubmissionIndex,
    reads: Reads,
    mapped: mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
    maps: usize,
}

/// Where a frame's depth comes from.
pub(crate) enum DepthInput<'a> {
    /// A depth image in metres, uploaded.
    Metres(&'a Image<f32>),
    /// A raw Kinect v2 frame, uploaded and decoded on the GPU into the depth buffer.
    Raw { decoder: &'a Decode, raw: &'a [u8] },
}

/// The GPU fusion engine: device, queue, compiled stages and buffers reused from frame to
/// frame (re-allocated only when the image sizes change). Create once, run many frames.
pub struct FusionContext {
    pub(crate) gpu: Gpu,
    stages: Vec<Box<dyn Stage>>,
    plane: PlaneFill,
    tables: Tables,
    slots: Vec<FrameSlot>,
}

impl std::fmt::Debug for FusionContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FusionContext")
            .field("adapter", &self.gpu.info.name)
            .finish_non_exhaustive()
    }
}

impl FusionContext {
    /// Opens the first Vulkan adapter (a real GPU is preferred over a software one such as
    /// lavapipe) and compiles every stage. Honours `WGPU_BACKEND` / `VK_DRIVER_FILES`.
    ///
    /// Fails with [`GpuError::NoAdapter`] when there is none; the library never falls back
    /// by itself ([`crate::fuse`] does under [`crate::Engine::Auto`]).
    pub fn new() -> Result<Self, GpuError> {
        let gpu = Gpu::open()?;
        let stages = FRAME.iter().map(|e| (e.new)(&gpu)).collect();
        let plane = PlaneFill::new(&gpu);
        gpu.check_errors("compiling the shaders")?;
        Ok(Self { gpu, stages, plane, tables: Tables::default(), slots: Vec::new() })
    }

    /// The adapter's name, e.g. `llvmpipe (LLVM 15.0.6, 256 bits)` for lavapipe.
    pub fn adapter_name(&self) -> &str {
        &self.gpu.info.name
    }

    /// A one-line description: name, device type, backend, driver.
    pub fn adapter_summary(&self) -> String {
        format!(
            "{} ({:?}, {:?}, driver {} {})",
            self.gpu.info.name,
            self.gpu.info.device_type,
            self.gpu.info.backend,
            self.gpu.info.driver,
            self.gpu.info.driver_info
        )
    }

    /// True for a software adapter (lavapipe / llvmpipe): correct, but slower than the CPU path.
    pub fn is_software(&self) -> bool {
        self.gpu.info.device_type == wgpu::DeviceType::Cpu
    }

    /// The largest storage-buffer binding of this adapter, bytes (lavapipe: 128 MiB).
    pub fn max_binding_bytes(&self) -> u64 {
        self.gpu.limits.max_storage_buffer_binding_size.min(self.gpu.limits.max_buffer_size)
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
                    adapter: self.gpu.info.name.clone(),
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
            self.gpu.device_error("reading back the frame", "no result was produced".into())
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
        self.stream_inputs(rig, kind, frames, plan, plan.depth_range(), sink)
    }

    /// [`FusionContext::stream`] on any [`DepthInput`], H1 keeping the samples in
    /// `depth_range` (the request's, [`geometry::fusion::PixelParams::depth_range`]).
    pub(crate) fn stream_inputs<'a, I, F>(
        &mut self,
        rig: &Rig,
        kind: DepthKind,
        frames: I,
        plan: FramePlan,
        depth_range: DepthRange,
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
        self.tables.ensure(&self.gpu, rig, kind, plan.stages.as_ref());
        let proj = ColorProjection::from_rig(rig);
        let mut pending: VecDeque<Pending> = VecDeque::new();
        let mut count = 0;
        for (k, (depth, color)) in frames.into_iter().enumerate() {
            let sizes = match &depth {
                DepthInput::Metres(d) => {
                    d.expect_size("depth image", depth_size.0, depth_size.1).map_err(GpuError::from)
                }
                DepthInput::Raw { raw, .. } => Decode::check_raw(raw),
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
            self.ensure_slot(slot, depth_size, color_size)?;
            let p = self.submit(slot, k, depth, color, &proj, &plan, depth_range, false)?;
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
        self.gpu.device_error(during, message)
    }

    /// Slot `slot` with buffers of these sizes, its stages bound to them and to the tables.
    fn ensure_slot(
        &mut self,
        slot: usize,
        depth_size: (usize, usize),
        color_size: (usize, usize),
    ) -> Result<(), GpuError> {
        let fits = self.slots.get(slot).is_some_and(|s| {
            s.buffers.depth_size == depth_size && s.buffers.color_size == color_size
        });
        if !fits {
            let s = FrameSlot {
                buffers: FrameBuffers::new(&self.gpu, depth_size, color_size),
                bound: None,
            };
            if slot < self.slots.len() {
                self.slots[slot] = s;
            } else {
                self.slots.push(s);
            }
        }
        let generation = self.tables.generation();
        if self.slots[slot].bound != Some(generation) {
            let tables = self.tables.get().ok_or_else(|| {
                self.gpu.device_error("preparing a frame", "lookup tables were not uploaded".into())
            })?;
            let buffers = &self.slots[slot].buffers;
            for stage in &mut self.stages {
                stage.bind(&self.gpu, slot, buffers, &tables);
            }
            self.slots[slot].bound = Some(generation);
        }
        Ok(())
    }

    /// One frame on slot `slot` (ensured and bound): inputs uploaded, the stages that run on
    /// it encoded in [`FRAME`] order into one compute pass, the asked-for outputs copied to
    /// the read-back buffers. With `accumulate_zbuffer` H7 adds to the slot's z-buffer.
    #[allow(clippy::too_many_arguments)]
    fn submit(
        &self,
        slot: usize,
        frame: usize,
        depth: DepthInput<'_>,
        color: Option<&Image<[u8; 3]>>,
        proj: &ColorProjection,
        plan: &FramePlan,
        depth_range: DepthRange,
        accumulate_zbuffer: bool,
    ) -> Result<Pending, GpuError> {
        let gpu = &self.gpu;
        let tables = self.tables.get().ok_or_else(|| {
            gpu.device_error("preparing a frame", "lookup tables were not uploaded".into())
        })?;
        let s = &self.slots[slot].buffers;
        let upload_color = plan.stages.is_some() && color.is_some();
        if let (true, Some(c)) = (upload_color, color) {
            write_padded(&gpu.queue, &s.color, bytemuck::cast_slice(c.data()));
        }
        let work = Work {
            depth_pixels: (s.depth_size.0 * s.depth_size.1) as u32,
            color_size: (proj.width, proj.height),
            proj,
            stages: plan.stages,
            depth_range,
            color: upload_color,
            tables,
            accumulate_zbuffer,
        };
        // A raw frame is decoded in this command buffer, the depth in metres written straight
        // into the slot's depth buffer.
        let decode = match depth {
            DepthInput::Metres(d) => {
                gpu.queue.write_buffer(&s.depth, 0, bytemuck::cast_slice(d.data()));
                None
            }
            DepthInput::Raw { decoder, raw } => {
                decoder.write_raw(gpu, raw);
                Some((decoder, decoder.edge_bind_group(gpu, &s.depth)))
            }
        };
        let mut enc = gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("fusion frame"),
        });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("fusion"),
                timestamp_writes: None,
            });
            if let Some((decoder, edge_group)) = &decode {
                decoder.record(&mut pass, edge_group);
            }
            for stage in self.stages.iter().filter(|st| st.runs(&work)) {
                stage.encode(gpu, &mut pass, slot, &work);
            }
        }
        let reads = Reads {
            intermediates: plan.read_intermediates,
            stages: plan.stages.is_some(),
            color: upload_color,
        };
        let copies = s.copies(reads);
        for (src, dst, bytes) in &copies {
            enc.copy_buffer_to_buffer(src, 0, dst, 0, *bytes);
        }
        let submission = gpu.queue.submit([enc.finish()]);
        let (tx, rx) = mpsc::channel();
        for (_, dst, bytes) in &copies {
            let tx = tx.clone();
            dst.map_async(wgpu::MapMode::Read, 0..*bytes, move |r| {
                let _ = tx.send(r);
            });
        }
        gpu.check_errors("submitting a frame")?;
        Ok(Pending { slot, frame, submission, reads, mapped: rx, maps: copies.len() })
    }

    fn finish(&mut self, p: Pending) -> Result<(usize, GpuFrame), GpuError> {
        let gpu = &self.gpu;
        gpu.wait(p.submission, &p.mapped, p.maps)?;
        let s = &self.slots[p.slot].buffers;
        let (cw, ch) = s.color_size;
        let (dw, dh) = s.depth_size;
        let (m, n) = ((cw * ch) as u64, (dw * dh) as u64);
        let zbuffer = Image::from_vec(cw, ch, gpu.read_mapped(&s.read_z, m * 4)?)?;
        let (mut points, mut samples, mut nearest, mut holes, mut color_on_depth) =
            (None, None, None, None, None);
        if p.reads.intermediates {
            points = Some(gpu.read_mapped(&s.read_points, n * 16)?);
            samples = Some(gpu.read_mapped(&s.read_samples, n * 16)?);
        }
        if p.reads.stages {
            nearest = Some(Image::from_vec(cw, ch, gpu.read_mapped(&s.read_nearest, m * 4)?)?);
            let h: Vec<u32> = gpu.read_mapped(&s.read_holes, m * 4)?;
            holes = Some(Image::from_vec(cw, ch, h.into_iter().map(|b| b == 1).collect())?);
        }
        if p.reads.color {
            let rgba: Vec<u32> = gpu.read_mapped(&s.read_rgba, n * 4)?;
            let rgb = rgba.iter().map(|&c| [c as u8, (c >> 8) as u8, (c >> 16) as u8]).collect();
            let valid = rgba.iter().map(|&c| c >> 24 == 0xff).collect();
            color_on_depth = Some((Image::from_vec(dw, dh, rgb)?, Image::from_vec(dw, dh, valid)?));
        }
        Ok((p.frame, GpuFrame { zbuffer, points, samples, nearest, holes, color_on_depth }))
    }

    /// H1 + H2 + H7 of several depth images into one `camera`, one atomic-min z-buffer on
    /// the GPU across all of them (cleared before the first view only): per pixel the
    /// smallest `z` of any view's samples. Bit-identical to
    /// [`geometry::fusion::CpuPixels`]' [`PerPixel::zbuffer_views`](geometry::fusion::PerPixel)
    /// (a minimum does not depend on the order of its samples). Views may have different
    /// depth cameras; each is its own submission on frame slot 0 (their lookup tables
    /// differ), read back once after the last.
    pub fn zbuffer_views(
        &mut self,
        camera: &CameraModel,
        views: &[DepthView<'_>],
        kind: DepthKind,
    ) -> Result<Image<f32>, GpuError> {
        camera.validate()?;
        if views.is_empty() {
            return Ok(Image::filled(camera.width, camera.height, ZBUFFER_EMPTY));
        }
        let color_size = (camera.width, camera.height);
        let plan = FramePlan::default();
        let mut last = None;
        for (k, v) in views.iter().enumerate() {
            let rig = Rig::new(*v.depth_camera, *camera, v.camera_from_depth);
            rig.validate()?;
            let depth_size = (rig.depth.width, rig.depth.height);
            v.depth.expect_size("depth image", depth_size.0, depth_size.1)?;
            self.check_frame_size(depth_size, color_size)?;
            self.tables.ensure(&self.gpu, &rig, kind, None);
            self.ensure_slot(0, depth_size, color_size)?;
            let proj = ColorProjection::from_rig(&rig);
            let all = DepthRange::ALL;
            let p =
                self.submit(0, k, DepthInput::Metres(v.depth), None, &proj, &plan, all, k > 0)?;
            // One read-back buffer per slot: each submission is read before the next maps it.
            last = Some(self.finish(p)?.1.zbuffer);
        }
        last.ok_or_else(|| self.gpu.device_error("reading back the frame", "no result".into()))
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
        self.check_frame_size((1, 1), (w, h))?;
        self.plane.fill(&self.gpu, color_camera, nearest, holes, normal, offset)
    }
}
