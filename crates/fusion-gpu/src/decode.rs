//! [`GpuDecoder`]: Kinect v2 depth decoding on the GPU (protocol §8–§9), the three passes of
//! `kinect_usb::decoder::DepthDecoder` with `DecoderPrecision::Fast` as WGSL compute shaders
//! (`shaders/decode_stage1.wgsl`, `decode_filter.wgsl`, `decode_edge.wgsl`, see
//! [`crate::stages::decode`]), and the [`FusionContext`] entry points that decode and register
//! a raw frame without it leaving the GPU ([`FusionContext::decode_and_register`],
//! [`FusionContext::stream_raw`]).
//!
//! # Parity
//!
//! The shaders mirror the CPU `Fast` decoder operation by operation: its own `exp`, `ln` and
//! `atan2` (`kinect_usb::decoder::fastmath`) constant for constant, the same f32 order, and
//! the CPU's few f64 steps as exact f32 double-word products and sums rounded once (see
//! `decode_filter.wgsl`). On lavapipe (IEEE division, no fused multiply-add) the output is
//! therefore the CPU's to the bit except where an f64 step's exact value lies within about
//! 2⁻⁴⁸ of an f32 rounding boundary; `tests/decode.rs` holds it to protocol §9.9's bar
//! (0.01 mm, no pixel changing validity) on every oracle frame.
//!
//! The decoder's tables (the LUT, the phase-step coefficients by P0 value, the x/z tables)
//! are uploaded once by [`GpuDecoder::new`]; each frame uploads only its 2 984 960 raw bytes.

use std::sync::mpsc;
use std::sync::{Arc, Mutex};

use geometry::{DepthKind, Image, Rig};
use kinect_usb::decoder::{DecoderConfig, DecoderParams, phase_step_coefficients};
use kinect_usb::params::{P0Tables, XzTables};
use kinect_usb::raw::{HEIGHT, PIXELS, RAW_FRAME_BYTES, WIDTH, lut};

use crate::context::DepthInput;
use crate::stages::decode::{self as stage, Params, Pipelines};
use crate::{FramePlan, FusionContext, GpuError, GpuFrame};

/// Metres per millimetre of the depth the registration stages receive from the decoder:
/// `depth_m = depth_mm * METRES_PER_MM`, one f32 product per pixel (the CPU equivalent of
/// [`FusionContext::decode_and_register`] is the CPU decoder's depth times this, then
/// [`FusionContext::register`] with [`DepthKind::Z`]).
pub const METRES_PER_MM: f32 = 0.001;

/// The GPU depth decoder of one [`FusionContext`]: its pipelines, the device tables and the
/// working buffers of one frame. Create it once per sensor (tables) and decode many frames.
pub struct GpuDecoder {
    ctx_id: u64,
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: String,
    errors: Arc<Mutex<Vec<String>>>,
    pipelines: Pipelines,
    grid: (u32, u32),
    raw: wgpu::Buffer,
    depth_mm: wgpu::Buffer,
    ir: wgpu::Buffer,
    uniform: wgpu::Buffer,
    pre: wgpu::Buffer,
    stage1_group: wgpu::BindGroup,
    filter_group: wgpu::BindGroup,
    /// The edge pass writing its metres into the decoder's own buffer (for [`GpuDecoder::decode`]).
    edge_group: wgpu::BindGroup,
    read_depth: wgpu::Buffer,
    read_ir: wgpu::Buffer,
}

impl std::fmt::Debug for GpuDecoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuDecoder").field("adapter", &self.adapter).finish_non_exhaustive()
    }
}

/// A storage buffer of `bytes` (at least 16).
fn storage(
    device: &wgpu::Device,
    label: &str,
    bytes: u64,
    extra: wgpu::BufferUsages,
) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: bytes.next_multiple_of(4).max(16),
        usage: wgpu::BufferUsages::STORAGE | extra,
        mapped_at_creation: false,
    })
}

/// The phase-step coefficient table of protocol §9.3 by P0 value and each processing pixel's
/// entries in it: per frequency, two vec4 per P0 value from the frequency's smallest to its
/// largest (`[cos ψ_0..2, 0]`, `[sin(−ψ_0..2), 0]`), the three frequencies one after the
/// other; per pixel `[entry_0, entry_1, entry_2, 0]` (P0 row `423 − y` is processing row `y`).
fn trig_tables(params: &DecoderParams, p0: &P0Tables) -> (Vec<[f32; 4]>, Vec<[u32; 4]>) {
    let mut table = Vec::new();
    let mut base = [0u32; 3];
    let mut lo = [0u16; 3];
    for (k, t) in p0.tables.iter().enumerate() {
        let (min, max) =
            (t.iter().copied().min().unwrap_or(0), t.iter().copied().max().unwrap_or(0));
        base[k] = (table.len() / 2) as u32;
        lo[k] = min;
        for p in min..=max {
            let e = phase_step_coefficients(params, p);
            table.push([e[0], e[1], e[2], 0.0]);
            table.push([e[4], e[5], e[6], 0.0]);
        }
    }
    let index = (0..PIXELS)
        .map(|i| {
            let (y, x) = (i / WIDTH, i % WIDTH);
            let at =
                |k: usize| base[k] + (p0.tables[k][(HEIGHT - 1 - y) * WIDTH + x] - lo[k]) as u32;
            [at(0), at(1), at(2), 0]
        })
        .collect();
    (table, index)
}

impl GpuDecoder {
    /// A decoder on `ctx`'s device with the CPU decoder's inputs (`DepthDecoder::new`'s):
    /// constants, filter switches (`config.parallel` has no meaning here), the x/z tables
    /// (processing-row order) and the P0 tables. Uploads every table once.
    ///
    /// Errors: [`GpuError::Input`] for tables of the wrong size; [`GpuError::Device`] when the
    /// device fails.
    pub fn new(
        ctx: &FusionContext,
        params: DecoderParams,
        config: DecoderConfig,
        xz: &XzTables,
        p0: &P0Tables,
    ) -> Result<Self, GpuError> {
        if xz.x.len() != PIXELS
            || xz.z.len() != PIXELS
            || p0.tables.iter().any(|t| t.len() != PIXELS)
        {
            return Err(input(format!(
                "decoder tables must hold {PIXELS} values each (x {}, z {}, P0 {:?})",
                xz.x.len(),
                xz.z.len(),
                p0.tables.each_ref().map(|t| t.len())
            )));
        }
        let device = ctx.device.clone();
        let (gx, gy, stride) = ctx.grid(PIXELS as u32);
        let uniform_data = Params::new(&params, &config, PIXELS as u32, stride, METRES_PER_MM);
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("decoder params"),
            size: size_of::<Params>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ctx.queue.write_buffer(&uniform, 0, bytemuck::bytes_of(&uniform_data));
        let lut: Vec<f32> = lut().map(f32::from).to_vec();
        let (trig, trig_index) = trig_tables(&params, p0);
        let lut = ctx.upload("decoder LUT", &lut);
        let trig = ctx.upload("decoder phase-step coefficients", &trig);
        let trig_index = ctx.upload("decoder coefficient index", &trig_index);
        let xtab = ctx.upload("decoder x table", &xz.x[..]);
        let ztab = ctx.upload("decoder z table", &xz.z[..]);
        use wgpu::BufferUsages as U;
        let n = PIXELS as u64;
        let raw = storage(&device, "raw depth frame", RAW_FRAME_BYTES as u64, U::COPY_DST);
        let s1 = storage(&device, "decoder stage 1", n * 48, U::empty());
        let n2 = storage(&device, "decoder stage 1 n2", n * 16, U::empty());
        let ir = storage(&device, "decoded IR", n * 4, U::COPY_SRC);
        let pre = storage(&device, "decoder stage 2", n * 16, U::empty());
        let depth_mm = storage(&device, "decoded depth", n * 4, U::COPY_SRC);
        let depth_m = storage(&device, "decoded depth (metres)", n * 4, U::empty());
        let read = |label| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: n * 4,
                usage: U::MAP_READ | U::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let (read_depth, read_ir) = (read("decoded depth read-back"), read("IR read-back"));
        let pipelines = Pipelines::new(&device);
        let stage1_group = ctx.bind(
            &pipelines.stage1,
            &[
                (stage::PARAMS, &uniform),
                (stage::S1_RAW, &raw),
                (stage::S1_LUT, &lut),
                (stage::S1_TRIG, &trig),
                (stage::S1_TRIG_INDEX, &trig_index),
                (stage::S1_ZTAB, &ztab),
                (stage::S1_OUT, &s1),
                (stage::S1_N2, &n2),
                (stage::S1_IR, &ir),
            ],
        );
        let filter_group = ctx.bind(
            &pipelines.filter,
            &[
                (stage::PARAMS, &uniform),
                (stage::F_S1, &s1),
                (stage::F_N2, &n2),
                (stage::F_XTAB, &xtab),
                (stage::F_ZTAB, &ztab),
                (stage::F_PRE, &pre),
            ],
        );
        let edge_group =
            edge_bind_group(&device, &pipelines, [&uniform, &pre, &depth_mm, &depth_m]);
        let dec = GpuDecoder {
            ctx_id: ctx.id,
            device,
            queue: ctx.queue.clone(),
            adapter: ctx.info.name.clone(),
            errors: Arc::clone(&ctx.errors),
            edge_group,
            pipelines,
            grid: (gx, gy),
            raw,
            depth_mm,
            ir,
            uniform,
            pre,
            stage1_group,
            filter_group,
            read_depth,
            read_ir,
        };
        ctx.check_errors("creating the depth decoder")?;
        Ok(dec)
    }

    /// The edge pass's bind group writing the metres into `depth_m`.
    pub(crate) fn edge_bind_group(&self, depth_m: &wgpu::Buffer) -> wgpu::BindGroup {
        edge_bind_group(
            &self.device,
            &self.pipelines,
            [&self.uniform, &self.pre, &self.depth_mm, depth_m],
        )
    }

    /// Whether this decoder was made on `ctx` (buffers of one device cannot be used on another).
    pub(crate) fn check_context(&self, ctx: &FusionContext) -> Result<(), GpuError> {
        if self.ctx_id == ctx.id {
            return Ok(());
        }
        Err(input(
            "the GpuDecoder was created on another FusionContext; create it on this one".into(),
        ))
    }

    /// Checks the size of a raw frame.
    pub(crate) fn check_raw(raw: &[u8]) -> Result<(), GpuError> {
        if raw.len() == RAW_FRAME_BYTES {
            return Ok(());
        }
        Err(input(format!(
            "a raw Kinect v2 depth frame has {RAW_FRAME_BYTES} bytes, got {}",
            raw.len()
        )))
    }

    /// Queues the upload of a raw frame (checked by [`GpuDecoder::check_raw`]).
    pub(crate) fn write_raw(&self, raw: &[u8]) {
        self.queue.write_buffer(&self.raw, 0, raw);
    }

    /// Records the three decode passes into `pass`, the edge pass with `edge_group`.
    pub(crate) fn record(&self, pass: &mut wgpu::ComputePass<'_>, edge_group: &wgpu::BindGroup) {
        let (gx, gy) = self.grid;
        for (pipe, group) in [
            (&self.pipelines.stage1, &self.stage1_group),
            (&self.pipelines.filter, &self.filter_group),
            (&self.pipelines.edge, edge_group),
        ] {
            pass.set_pipeline(pipe);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(gx, gy, 1);
        }
    }

    /// Decodes one raw frame (2 984 960 bytes) into upright `depth` (mm) and `ir` images of
    /// 512 × 424, as `kinect_usb::decoder::DepthDecoder::decode` does, and reads both back.
    ///
    /// Errors: [`GpuError::Input`] for a frame or output of the wrong size,
    /// [`GpuError::Device`] when the device fails.
    pub fn decode(
        &mut self,
        raw: &[u8],
        depth: &mut [f32],
        ir: &mut [f32],
    ) -> Result<(), GpuError> {
        Self::check_raw(raw)?;
        if depth.len() != PIXELS || ir.len() != PIXELS {
            return Err(input(format!(
                "depth and IR outputs must hold {PIXELS} pixels, got {} and {}",
                depth.len(),
                ir.len()
            )));
        }
        self.write_raw(raw);
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("decode") });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("decode"),
                timestamp_writes: None,
            });
            self.record(&mut pass, &self.edge_group);
        }
        let bytes = PIXELS as u64 * 4;
        enc.copy_buffer_to_buffer(&self.depth_mm, 0, &self.read_depth, 0, bytes);
        enc.copy_buffer_to_buffer(&self.ir, 0, &self.read_ir, 0, bytes);
        let submission = self.queue.submit([enc.finish()]);
        let (tx, rx) = mpsc::channel();
        for b in [&self.read_depth, &self.read_ir] {
            let tx = tx.clone();
            b.map_async(wgpu::MapMode::Read, 0..bytes, move |r| {
                let _ = tx.send(r);
            });
        }
        self.device
            .poll(wgpu::PollType::Wait { submission_index: Some(submission), timeout: None })
            .map_err(|e| self.error("waiting for the decoder", e.to_string()))?;
        for _ in 0..2 {
            match rx.recv() {
                Ok(Ok(())) => {}
                Ok(Err(e)) => return Err(self.error("mapping the decoder output", e.to_string())),
                Err(e) => return Err(self.error("mapping the decoder output", e.to_string())),
            }
        }
        self.check_errors()?;
        for (buffer, out) in [(&self.read_depth, depth), (&self.read_ir, ir)] {
            {
                let view = buffer
                    .get_mapped_range(0..bytes)
                    .map_err(|e| self.error("reading the decoder output", e.to_string()))?;
                for (o, b) in out.iter_mut().zip(view.chunks_exact(4)) {
                    *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                }
            }
            buffer.unmap();
        }
        Ok(())
    }

    fn error(&self, during: &'static str, message: String) -> GpuError {
        GpuError::Device { adapter: self.adapter.clone(), during, message }
    }

    fn check_errors(&self) -> Result<(), GpuError> {
        let mut errors = self
            .errors
            .lock()
            .map_err(|_| self.error("decoding", "error handler poisoned".into()))?;
        if errors.is_empty() {
            return Ok(());
        }
        let message = errors.join("; ");
        errors.clear();
        Err(self.error("decoding", message))
    }
}

/// The edge pass's bind group: `[params, pre, depth_mm, depth_m]`.
fn edge_bind_group(
    device: &wgpu::Device,
    pipelines: &Pipelines,
    buffers: [&wgpu::Buffer; 4],
) -> wgpu::BindGroup {
    let [params, pre, mm, m] = buffers;
    let entries = [
        (stage::PARAMS, params),
        (stage::E_PRE, pre),
        (stage::E_DEPTH_MM, mm),
        (stage::E_DEPTH_M, m),
    ]
    .map(|(binding, b)| wgpu::BindGroupEntry { binding, resource: b.as_entire_binding() });
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("decoder edge pass"),
        layout: &pipelines.edge.get_bind_group_layout(0),
        entries: &entries,
    })
}

fn input(message: String) -> GpuError {
    GpuError::Input(geometry::GeometryError::InvalidInput(message))
}

impl FusionContext {
    /// Decodes a raw Kinect v2 depth frame with `decoder` and runs H1 + H2 + H7 on the result
    /// without the frame leaving the GPU: the decoder's edge pass writes the depth in metres
    /// (`mm * METRES_PER_MM`, z along the optical axis) straight into the registration's
    /// depth buffer. `rig.depth` must be the 512 × 424 depth camera. Equals the CPU decoder
    /// (`Fast`) followed by [`FusionContext::register`] with [`DepthKind::Z`] (see the module
    /// docs for the decoder's parity).
    pub fn decode_and_register(
        &mut self,
        decoder: &GpuDecoder,
        raw: &[u8],
        rig: &Rig,
        read_intermediates: bool,
    ) -> Result<GpuFrame, GpuError> {
        let plan = FramePlan { stages: None, read_intermediates };
        let mut out = None;
        self.stream_raw(decoder, rig, std::iter::once((raw, None)), plan, |_, f| out = Some(f))?;
        out.ok_or_else(|| {
            self.device_error("reading back the frame", "no result was produced".into())
        })
    }

    /// [`FusionContext::stream`] on raw Kinect v2 depth frames: each frame is decoded on the
    /// GPU by `decoder` (made on this context) and registered in the same command buffer;
    /// `(raw frame, colour image)` pairs in, `sink(frame_index, frame)` in order, two frames
    /// in flight. `rig.depth` must be 512 × 424; depth is [`DepthKind::Z`].
    pub fn stream_raw<'a, I, F>(
        &mut self,
        decoder: &GpuDecoder,
        rig: &Rig,
        frames: I,
        plan: FramePlan,
        sink: F,
    ) -> Result<usize, GpuError>
    where
        I: IntoIterator<Item = (&'a [u8], Option<&'a Image<[u8; 3]>>)>,
        F: FnMut(usize, GpuFrame),
    {
        decoder.check_context(self)?;
        if (rig.depth.width, rig.depth.height) != (WIDTH, HEIGHT) {
            return Err(input(format!(
                "decoding on the GPU needs the rig's depth camera at {WIDTH}x{HEIGHT}, it is {}x{}",
                rig.depth.width, rig.depth.height
            )));
        }
        let frames =
            frames.into_iter().map(|(raw, color)| (DepthInput::Raw { decoder, raw }, color));
        self.stream_inputs(rig, DepthKind::Z, frames, plan, sink)
    }
}
