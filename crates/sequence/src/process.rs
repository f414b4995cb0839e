//! Stages 3 and 4, decode and register: a frame's depth (raw sensor data through the
//! `kinect_usb` decoder, or a 16-bit millimetre PNG of a frame folder) in metres, then the
//! per-pixel stages of the one fusion pipeline on the opened engine
//! ([`geometry::fusion::stream_on`] on a [`PixelEngine`], the engine `kfuse fuse` runs a single
//! frame on): the registration on the colour grid and what the caller asked for besides, the
//! H8 hole mask and H6 colour on the depth grid; then the coloured H1 cloud. On the GPU a
//! recording's raw frames can be decoded there too
//! ([`fusion_gpu::FusionContext::per_pixel_stream_raw`], the same stages behind the GPU decoder).
//!
//! Every output is what `kfuse fuse` computes for one frame with the same rig and options.

use std::path::Path;

use crate::color::ColorJpeg;
use fusion_gpu::{GpuDecoder, PixelEngine};
use geometry::fusion::{
    self, FusionOptions, PixelParams, Request, StreamFrame, StreamPlan, StreamResult,
    backproject_cloud, depth_ray_table, stream_on,
};
use geometry::{DepthKind, Image, PointCloud, Rig};
use kfuse_io::images::png16_values;
use kinect_usb::decoder::{DecoderConfig, DecoderParams, DecoderPrecision, DepthDecoder};
use kinect_usb::device::DeviceInfo;
use kinect_usb::params::XzTables;
use kinect_usb::raw::{HEIGHT, PIXELS, WIDTH};

use crate::{Result, SequenceError};

/// Frames registered per call of `FusionContext::stream` on the GPU path: the context keeps
/// two frames in flight, so four per call keep it busy while bounding the decoded frames
/// held (4 × 0.9 MB of depth, plus their colour images when H6 is asked for).
pub const GPU_BATCH: usize = 4;

/// Which per-frame results to compute besides the registered depth.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Extras {
    /// H8 disocclusion hole mask on the colour grid.
    pub holes: bool,
    /// H6 colour on the depth grid (needs the colour JPEG decoded).
    pub color_on_depth: bool,
    /// H1 cloud in the depth camera frame, coloured by H6 where the frame has colour.
    pub cloud: bool,
    /// Keep H6's validity mask beside its colour ([`Registered::color_valid`]): the frames
    /// handed to the caller carry both (`kfuse fuse --recording --tsdf` colours its volume).
    pub color_valid: bool,
}

/// A frame's depth in metres (0 = no sample) and, when an output needs it, its decoded colour.
pub struct Decoded {
    /// Depth, metres, the depth camera's size; empty (0 × 0) when the frame is decoded on the
    /// GPU ([`Processor::decodes_on_gpu`]), which then reads `raw` instead.
    pub depth: Image<f32>,
    /// The raw depth frame, kept only when it is decoded on the GPU.
    pub raw: Option<Vec<u8>>,
    /// The colour image, decoded only when H6 or the cloud needs it and the frame has colour.
    pub color: Option<Image<[u8; 3]>>,
    /// The decoder's own depth and IR, kept for the rosbag2 layout
    /// ([`FrameDecoder::keep_sensor_images`]).
    pub sensor: Option<crate::rosbag2::SensorImages>,
}

/// What registration produced for one frame.
pub struct Registered {
    /// Registered depth on the colour grid, in the writer's units (`png16_value` of
    /// `z · units_per_metre`; 0 = no sample), row-major.
    pub depth_units: Vec<u16>,
    /// Colour pixels that received a depth sample (the z-buffer's non-empty pixels; the same
    /// count on every engine).
    pub landed: usize,
    /// H8 hole mask (255 = hole), colour grid, row-major.
    pub holes: Option<Vec<u8>>,
    /// H6 colour on the depth grid (black where invalid).
    pub color_on_depth: Option<Image<[u8; 3]>>,
    /// Where H6 trusts that colour ([`Extras::color_valid`]).
    pub color_valid: Option<Image<bool>>,
    /// H1 cloud, depth camera frame, metres.
    pub cloud: Option<PointCloud>,
}

/// The two halves of a frame's processing, which the pipeline runs on its two workers
/// ([`crate::pipeline`]): [`FrameDecoder`] (depth decoding, colour decoding; worker A, after
/// reading) and [`FrameRegistrar`] (the per-pixel stages and the extras; worker B, before
/// encoding), so that with two threads each core carries about half of a frame's work.
pub struct Processor {
    /// Decoding: raw depth (or a depth PNG) into metres, the colour JPEG when needed.
    pub decoding: FrameDecoder,
    /// Registration and the extras on the engine.
    pub registering: FrameRegistrar,
}

/// Worker A's half of [`Processor`]: the depth decoder (recordings only) and its buffers.
pub struct FrameDecoder {
    decoder: Option<DepthDecoder>,
    depth_mm: Vec<f32>,
    ir: Vec<f32>,
    rig: Rig,
    /// The fusion request: its depth preparation is applied to every decoded frame.
    request: Request,
    needs_color: bool,
    /// Raw frames go to the registrar undecoded ([`Processor::decode_on_gpu`]).
    raw_to_gpu: bool,
    /// Keep the decoder's depth and IR of each frame ([`FrameDecoder::sensor_images`]).
    keep_sensor: bool,
}

/// Worker B's half of [`Processor`]: the engine of the per-pixel stages and the constants of
/// the extras.
pub struct FrameRegistrar {
    /// The depth decoder on the GPU (`--engine gpu` on a recording): raw frames are decoded
    /// and registered without the depth leaving the GPU.
    gpu_decoder: Option<GpuDecoder>,
    engine: PixelEngine,
    rig: Rig,
    rays: Vec<[f32; 3]>,
    extras: Extras,
    units_per_metre: f64,
    request: Request,
    params: PixelParams,
}

/// The depth decoder for a recording's calibration tables, with both filters, one thread
/// (the pipeline runs its stages on their own threads) and the `Fast` precision (within
/// 0.01 mm of libfreenect2's CPU decoder, protocol §9.9).
pub fn recording_decoder(info: &DeviceInfo) -> Result<DepthDecoder> {
    let xz = XzTables::from_params(&info.depth_params);
    let cfg = DecoderConfig {
        bilateral: true,
        edge_aware: true,
        parallel: false,
        ..DecoderConfig::default()
    };
    Ok(DepthDecoder::new(DecoderParams::default(), cfg, &xz, &info.p0)?
        .with_precision(DecoderPrecision::Fast))
}

impl Processor {
    /// A processor for frames of `rig` (a Kinect v2's depth camera: 512 × 424, z depth),
    /// decoding raw frames with `decoder` when given, writing depth at `units_per_metre`,
    /// running the per-pixel stages with `options` (those of `kfuse fuse`: the hole radius of
    /// H8 and the rest) on `engine` (opened by [`fusion_gpu::Engine::open`]).
    ///
    /// Errors: [`SequenceError::Geometry`] for a rig that is invalid, not of a Kinect v2's
    /// depth size, or whose coverage radius is out of bounds; [`SequenceError::Gpu`] for
    /// frames too large for the GPU.
    pub fn new(
        rig: &Rig,
        decoder: Option<DepthDecoder>,
        extras: Extras,
        units_per_metre: f64,
        options: &FusionOptions,
        mut engine: PixelEngine,
    ) -> Result<Self> {
        if decoder.is_some() && (rig.depth.width, rig.depth.height) != (WIDTH, HEIGHT) {
            return Err(SequenceError::Geometry(geometry::GeometryError::InvalidInput(format!(
                "the rig's depth camera is {}x{}, a Kinect v2 recording's depth is {WIDTH}x{HEIGHT}; \
                 give the rig of the sensor that made the recording",
                rig.depth.width, rig.depth.height
            ))));
        }
        rig.validate()?;
        fusion::checked_coverage_radius_px(rig, options)?;
        let request = Request::new(rig, DepthKind::Z, *options)?;
        if let Some(ctx) = engine.gpu() {
            ctx.check_frame_size(
                (rig.depth.width, rig.depth.height),
                (rig.color.width, rig.color.height),
            )?;
        }
        Ok(Self {
            decoding: FrameDecoder {
                decoder,
                depth_mm: vec![0.0; PIXELS],
                ir: vec![0.0; PIXELS],
                rig: rig.clone(),
                request: request.clone(),
                needs_color: extras.color_on_depth || extras.cloud,
                raw_to_gpu: false,
                keep_sensor: false,
            },
            registering: FrameRegistrar {
                gpu_decoder: None,
                engine,
                rig: request.rig().clone(),
                rays: depth_ray_table(&rig.depth, DepthKind::Z),
                extras,
                units_per_metre,
                params: request.params(),
                request,
            },
        })
    }

    /// The GPU adapter in use (name, type, backend, driver), `None` on the CPU path.
    pub fn adapter(&self) -> Option<String> {
        match &self.registering.engine {
            PixelEngine::Gpu(ctx) => Some(ctx.adapter_summary()),
            PixelEngine::Cpu(_) => None,
        }
    }

    /// Moves depth decoding onto the GPU for a recording made by the sensor `info` describes
    /// (the GPU path only). Decoding stays on the CPU, and this returns `false`, when the depth
    /// is needed on the CPU: a rig with a `depth_correction` (applied to decoded depth), the
    /// cloud, or no decoder (a frame folder). On the GPU the frame's depth equals the CPU
    /// `Fast` decoder's (fusion-gpu's parity test: bit-identical on lavapipe).
    pub fn decode_on_gpu(&mut self, info: &DeviceInfo) -> Result<bool> {
        let r = &mut self.registering;
        let PixelEngine::Gpu(ctx) = &r.engine else { return Ok(false) };
        if self.decoding.decoder.is_none()
            || self.decoding.keep_sensor
            || r.request.prepares_depth()
            || r.extras.cloud
        {
            return Ok(false);
        }
        let xz = XzTables::from_params(&info.depth_params);
        let cfg = DecoderConfig {
            bilateral: true,
            edge_aware: true,
            parallel: false,
            ..DecoderConfig::default()
        };
        r.gpu_decoder = Some(GpuDecoder::new(ctx, DecoderParams::default(), cfg, &xz, &info.p0)?);
        self.decoding.raw_to_gpu = true;
        Ok(true)
    }
}

impl FrameDecoder {
    /// Whether raw frames go to [`FrameRegistrar::register`] undecoded (see
    /// [`Processor::decode_on_gpu`]).
    pub fn decodes_on_gpu(&self) -> bool {
        self.raw_to_gpu
    }

    /// Keeps each frame's decoder depth and IR (the rosbag2 layout's `sd/` topics): frames are
    /// then decoded on the CPU.
    pub fn keep_sensor_images(&mut self) {
        self.keep_sensor = true;
    }

    /// The decoder's depth (millimetres) and IR of the frame [`FrameDecoder::decode_raw`] decoded
    /// last, as 16-bit images, when [`FrameDecoder::keep_sensor_images`] asked for them.
    pub fn sensor_images(&self) -> Option<crate::rosbag2::SensorImages> {
        self.keep_sensor.then(|| crate::rosbag2::SensorImages {
            depth_mm: crate::rosbag2::depth_mm_u16(&self.depth_mm),
            ir: crate::rosbag2::ir_u16(&self.ir),
        })
    }

    /// Whether a frame's colour must be decoded for the extras asked for.
    pub fn needs_color(&self) -> bool {
        self.needs_color
    }

    /// Decodes a raw depth frame into metres. Error: no decoder (a frame folder's processor)
    /// or a frame of the wrong size.
    pub fn decode_raw(&mut self, raw: &[u8]) -> Result<Image<f32>> {
        let decoder = self.decoder.as_mut().ok_or_else(|| {
            SequenceError::Pipeline("a raw depth frame reached a processor without decoder".into())
        })?;
        decoder.decode(raw, &mut self.depth_mm, &mut self.ir)?;
        let mut depth = depth_in_metres(&self.depth_mm, WIDTH, HEIGHT)?;
        self.correct(&mut depth)?;
        Ok(depth)
    }

    /// A depth frame decoded already (a bag's: metres as little-endian `f32`, `w × h`, 0 = no
    /// sample), checked against the rig's depth size, with the rig's depth correction applied
    /// as to a decoded frame.
    pub fn take_decoded(&self, metres: &[u8], w: usize, h: usize) -> Result<Image<f32>> {
        let (rw, rh) = (self.rig.depth.width, self.rig.depth.height);
        if (w, h) != (rw, rh) {
            return Err(SequenceError::Pipeline(format!(
                "the bag's depth images are {w}x{h}, the rig's depth camera is {rw}x{rh}; give the rig of the camera that took them"
            )));
        }
        let data: Vec<f32> =
            metres.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        let mut depth = Image::from_vec(w, h, data)?;
        self.correct(&mut depth)?;
        Ok(depth)
    }

    /// The request's depth preparation (the rig's `depth_correction`, `kfuse calibrate
    /// --depth`) applied to a frame's depth in metres, as `kfuse fuse` applies it to one frame
    /// ([`Request::prepare_depth`]).
    fn correct(&self, depth: &mut Image<f32>) -> Result<()> {
        self.request.prepare_depth(depth)?;
        Ok(())
    }

    /// Reads a frame folder's depth PNG (16-bit millimetres) into metres, checked against the
    /// rig's depth size.
    pub fn read_depth_png(&self, path: &Path) -> Result<Image<f32>> {
        let depth = kfuse_io::images::read_depth(path, kfuse_io::images::MILLIMETRES)?;
        let (w, h) = (self.rig.depth.width, self.rig.depth.height);
        if depth.size() != (w, h) {
            return Err(SequenceError::input(
                path,
                format!(
                    "is {}x{}, the rig's depth camera is {w}x{h}; give the rig of the sensor that took it",
                    depth.width(),
                    depth.height()
                ),
            ));
        }
        // NaN (no sample) as 0, the decoder's convention.
        let data = depth.into_vec().into_iter().map(|v| if v > 0.0 { v } else { 0.0 }).collect();
        let mut depth = Image::from_vec(w, h, data)?;
        self.correct(&mut depth)?;
        Ok(depth)
    }

    /// Decodes a colour JPEG as the scene is ([`ColorJpeg::decode`]) when the extras need it,
    /// checked against the rig's colour size; otherwise only checked (it is copied). The reader
    /// and its checks are `kfuse_io::images`', the same as single-frame `kfuse fuse`'s: a JPEG
    /// cut short, or an image too large by its header, is refused rather than decoded with
    /// grey filling.
    pub fn decode_color(&self, jpeg: &ColorJpeg, name: &Path) -> Result<Option<Image<[u8; 3]>>> {
        if !self.needs_color() {
            kfuse_io::images::check_picture(name, &jpeg.bytes)?;
            return Ok(None);
        }
        let img = jpeg.decode(name)?;
        let (w, h) = img.size();
        if (w, h) != (self.rig.color.width, self.rig.color.height) {
            return Err(SequenceError::input(
                name,
                format!(
                    "colour image is {w}x{h}, the rig's colour camera is {}x{}",
                    self.rig.color.width, self.rig.color.height
                ),
            ));
        }
        Ok(Some(img))
    }
}

impl FrameRegistrar {
    /// Whether registration runs on the GPU (frames are then registered in batches of
    /// [`GPU_BATCH`]).
    pub fn on_gpu(&self) -> bool {
        matches!(self.engine, PixelEngine::Gpu(_))
    }

    /// Registers `frames` (one on the CPU path; up to [`GPU_BATCH`] on the GPU path, streamed
    /// with two in flight) through the pipeline's per-pixel stages and computes the extras;
    /// results in order.
    pub fn register(&mut self, frames: &[Decoded]) -> Result<Vec<Registered>> {
        let needs_color = self.extras.color_on_depth || self.extras.cloud;
        let plan = StreamPlan { holes: self.extras.holes, color_on_depth: needs_color };
        let units = self.units_per_metre;
        let keep_valid = self.extras.color_valid;
        let mut out = Vec::with_capacity(frames.len());
        let mut sink = |_: usize, r: StreamResult<'_>| {
            let (depth_units, landed) = to_units_counted(r.zbuffer, units);
            out.push(Registered {
                depth_units,
                landed,
                holes: r.hole_mask.map(|m| m.iter().map(|&h| u8::from(h) * 255).collect()),
                color_on_depth: r.color_on_depth.map(|(c, _)| c.clone()),
                color_valid: r.color_on_depth.filter(|_| keep_valid).map(|(_, v)| v.clone()),
                cloud: None,
            })
        };
        match (&self.gpu_decoder, self.engine.gpu()) {
            (Some(decoder), Some(ctx)) => {
                let raws = frames
                    .iter()
                    .map(|f| f.raw.as_deref().map(|r| (r, f.color.as_ref())))
                    .collect::<Option<Vec<_>>>()
                    .ok_or_else(|| {
                        SequenceError::Pipeline(
                            "a decoded frame reached the GPU decoder without its raw data".into(),
                        )
                    })?;
                ctx.per_pixel_stream_raw(decoder, &self.rig, &raws, &self.params, plan, &mut sink)?;
            }
            _ => {
                let inputs: Vec<StreamFrame<'_>> = frames
                    .iter()
                    .map(|f| StreamFrame { depth: &f.depth, color: f.color.as_ref() })
                    .collect();
                stream_on(&mut self.engine, &self.request, &inputs, plan, &mut sink)?;
            }
        }
        if self.extras.cloud {
            for (f, r) in frames.iter().zip(&mut out) {
                let depth = self.params.depth_range.clip(&f.depth);
                let (mut cloud, pixels) = backproject_cloud(&depth, &self.rays);
                if let Some(c) = &r.color_on_depth {
                    cloud.colors = pixels.iter().map(|&i| c.data()[i as usize]).collect();
                }
                r.cloud = Some(cloud);
            }
        }
        Ok(out)
    }
}

/// The decoder's depth (millimetres, 0 = invalid) in metres: the one place where a frame's
/// depth enters the metric pipeline, and so where a per-frame depth correction (a rig's
/// fitted depth model) belongs, between decoding and registration.
/// Error: `mm` is not `width × height`.
pub fn depth_in_metres(mm: &[f32], width: usize, height: usize) -> Result<Image<f32>> {
    let data = mm.iter().map(|&v| mm_to_metres(v)).collect();
    Ok(Image::from_vec(width, height, data)?)
}

/// [`depth_in_metres`] into `out` (reused from frame to frame; `mm` must have its size).
/// Error: `mm` is not `out`'s size.
pub fn depth_in_metres_into(mm: &[f32], out: &mut Image<f32>) -> Result<()> {
    let (w, h) = out.size();
    if mm.len() != w * h {
        return Err(geometry::GeometryError::InvalidInput(format!(
            "{} depth values for a {w}x{h} depth image",
            mm.len()
        ))
        .into());
    }
    for (o, &v) in out.data_mut().iter_mut().zip(mm) {
        *o = mm_to_metres(v);
    }
    Ok(())
}

/// One decoder depth value (mm, 0 = invalid) in metres.
#[inline]
fn mm_to_metres(v: f32) -> f32 {
    if v > 0.0 { v * 1e-3 } else { 0.0 }
}

/// A z-buffer (metres, NaN = empty) in 16-bit units by `png16_value`'s rule.
pub fn to_units(zbuffer: &[f32], units_per_metre: f64) -> Vec<u16> {
    to_units_counted(zbuffer, units_per_metre).0
}

/// [`to_units`] and the number of non-empty (non-NaN) z-buffer pixels, in one pass over the
/// 8 MB z-buffer of a 1920×1080 frame instead of two.
pub fn to_units_counted(zbuffer: &[f32], units_per_metre: f64) -> (Vec<u16>, usize) {
    let mut units = vec![0; zbuffer.len()];
    let landed = png16_values(zbuffer, units_per_metre, &mut units);
    (units, landed)
}
