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

use geometry::{DepthKind, Image, Rig};
use kinect_usb::decoder::{DecoderConfig, DecoderParams};
use kinect_usb::params::{P0Tables, XzTables};
use kinect_usb::raw::{HEIGHT, WIDTH};

use crate::context::{DepthInput, FusionContext};
use crate::error::GpuError;
use crate::gpu::Gpu;
use crate::plan::{FramePlan, GpuFrame};
use crate::stages::decode::{Decode, input};

pub use crate::stages::decode::METRES_PER_MM;

/// The GPU depth decoder of one [`FusionContext`]: its pipelines, the device tables and the
/// working buffers of one frame. Create it once per sensor (tables) and decode many frames.
pub struct GpuDecoder {
    gpu: Gpu,
    stage: Decode,
}

impl std::fmt::Debug for GpuDecoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuDecoder").field("adapter", &self.gpu.info.name).finish_non_exhaustive()
    }
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
        let gpu = ctx.gpu.clone();
        let stage = Decode::new(&gpu, params, config, xz, p0)?;
        Ok(Self { gpu, stage })
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
        self.stage.decode(&self.gpu, raw, depth, ir)
    }

    /// Whether this decoder was made on `ctx` (buffers of one device cannot be used on another).
    fn check_context(&self, ctx: &FusionContext) -> Result<(), GpuError> {
        if self.gpu.id == ctx.gpu.id {
            return Ok(());
        }
        Err(input(
            "the GpuDecoder was created on another FusionContext; create it on this one".into(),
        ))
    }
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
        self.stream_raw_in(decoder, rig, frames, plan, plan.depth_range(), sink)
    }

    /// [`FusionContext::stream_raw`] with H1 keeping the samples in `depth_range`.
    pub(crate) fn stream_raw_in<'a, I, F>(
        &mut self,
        decoder: &GpuDecoder,
        rig: &Rig,
        frames: I,
        plan: FramePlan,
        depth_range: geometry::fusion::DepthRange,
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
        let frames = frames
            .into_iter()
            .map(|(raw, color)| (DepthInput::Raw { decoder: &decoder.stage, raw }, color));
        self.stream_inputs(rig, DepthKind::Z, frames, plan, depth_range, sink)
    }
}
