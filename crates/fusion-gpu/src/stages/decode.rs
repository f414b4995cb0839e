//! Kinect v2 depth decoding (`decode_stage1.wgsl`, `decode_filter.wgsl`, `decode_edge.wgsl`):
//! the three passes of the CPU decoder `kinect_usb::decoder` with `DecoderPrecision::Fast`, and
//! their shared uniform [`Params`]. The driver is [`crate::GpuDecoder`].

use std::sync::mpsc;

use bytemuck::{Pod, Zeroable};
use kinect_usb::decoder::{DecoderConfig, DecoderParams, phase_step_coefficients};
use kinect_usb::params::{P0Tables, XzTables};
use kinect_usb::raw::{HEIGHT, PIXELS, RAW_FRAME_BYTES, WIDTH, lut};

use super::Shader;
use crate::error::GpuError;
use crate::gpu::Gpu;
use crate::shaders;

/// Metres per millimetre of the depth the registration stages receive from the decoder:
/// `depth_m = depth_mm * METRES_PER_MM`, one f32 product per pixel (the CPU equivalent of
/// `FusionContext::decode_and_register` is the CPU decoder's depth times this, then
/// `FusionContext::register` with `DepthKind::Z`).
pub const METRES_PER_MM: f32 = 0.001;

/// `params`: [`Params`] (the same binding in all three shaders).
pub(crate) const PARAMS: u32 = 0;

/// Stage 1 bindings: `raw` (the frame as u32 words).
pub(crate) const S1_RAW: u32 = 1;
/// `lut`: the 11-bit companding table as f32.
pub(crate) const S1_LUT: u32 = 2;
/// `trig`: phase-step coefficients by P0 value.
pub(crate) const S1_TRIG: u32 = 3;
/// `trig_index`: each pixel's entries in `trig`.
pub(crate) const S1_TRIG_INDEX: u32 = 4;
/// `ztab`: the z table.
pub(crate) const S1_ZTAB: u32 = 5;
/// `s1`: per pixel and frequency `(a, b, ua, ub)` (output).
pub(crate) const S1_OUT: u32 = 6;
/// `n2`: per pixel the three `a² + b²` (output).
pub(crate) const S1_N2: u32 = 7;
/// `ir`: the upright IR image (output).
pub(crate) const S1_IR: u32 = 8;

/// The stage-1 shader.
pub(crate) const STAGE1: Shader = Shader {
    file: "decode_stage1.wgsl",
    source: shaders::DECODE_STAGE1,
    entry_points: &["main"],
    bindings: &[
        ("params", PARAMS),
        ("raw", S1_RAW),
        ("lut", S1_LUT),
        ("trig", S1_TRIG),
        ("trig_index", S1_TRIG_INDEX),
        ("ztab", S1_ZTAB),
        ("s1", S1_OUT),
        ("n2", S1_N2),
        ("ir", S1_IR),
    ],
};

/// Filter bindings: `s1` (stage 1's output).
pub(crate) const F_S1: u32 = 1;
/// `n2` (stage 1's output).
pub(crate) const F_N2: u32 = 2;
/// `xtab`: the x table.
pub(crate) const F_XTAB: u32 = 3;
/// `ztab`: the z table.
pub(crate) const F_ZTAB: u32 = 4;
/// `pre`: depth before the edge filter, amplitude sum, validity (output).
pub(crate) const F_PRE: u32 = 5;

/// The bilateral filter + stage 2 + unwrapping shader.
pub(crate) const FILTER: Shader = Shader {
    file: "decode_filter.wgsl",
    source: shaders::DECODE_FILTER,
    entry_points: &["main"],
    bindings: &[
        ("params", PARAMS),
        ("s1", F_S1),
        ("n2", F_N2),
        ("xtab", F_XTAB),
        ("ztab", F_ZTAB),
        ("pre", F_PRE),
    ],
};

/// Edge-filter bindings: `pre` (the filter pass's output).
pub(crate) const E_PRE: u32 = 1;
/// `depth_mm`: upright depth in millimetres (output).
pub(crate) const E_DEPTH_MM: u32 = 2;
/// `depth_m`: upright depth in metres for the registration stages (output).
pub(crate) const E_DEPTH_M: u32 = 3;

/// The edge-aware filter + flip shader.
pub(crate) const EDGE: Shader = Shader {
    file: "decode_edge.wgsl",
    source: shaders::DECODE_EDGE,
    entry_points: &["main"],
    bindings: &[
        ("params", PARAMS),
        ("pre", E_PRE),
        ("depth_mm", E_DEPTH_MM),
        ("depth_m", E_DEPTH_M),
    ],
};

/// The uniform of the three decode shaders, field for field their WGSL `Params`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Debug, PartialEq)]
pub(crate) struct Params {
    /// `[pixels, row stride, opaque 0, mirror]`: mirror = 1 writes the scene orientation
    /// (`kinect_usb::orientation`), 0 the sensor's.
    pub size: [u32; 4],
    /// `[bilateral, edge-aware, A* is the minimum, 0]` as 1 / 0.
    pub flags: [u32; 4],
    pub ab: [f32; 4],
    pub bil: [f32; 4],
    pub gauss0: [f32; 4],
    pub gauss1: [f32; 4],
    pub gauss2: [f32; 4],
    pub conf: [f32; 4],
    pub edge0: [f32; 4],
    pub edge1: [f32; 4],
    pub edge2: [f32; 4],
    pub two_pi_add: [f32; 4],
    pub mul_t0: [f32; 4],
    pub mul_t1: [f32; 4],
    pub mul_t2: [f32; 4],
    pub mul_two_pi: [f32; 4],
}

/// An f64 constant `c` as the f32 parts the shaders' `mul64` / `add64` take:
/// `[hi, lo, hi_upper, hi_lower]` with `hi` = `c` rounded to f32, `lo` = `c − hi` rounded to f32
/// (exact in f64 first), and `hi` cut after its 12 leading significant bits into
/// `hi_upper + hi_lower` (both exact), the split Dekker's product needs.
pub(crate) fn split_f64(c: f64) -> [f32; 4] {
    let hi = c as f32;
    let lo = (c - hi as f64) as f32;
    let upper = f32::from_bits(hi.to_bits() & 0xffff_f000);
    [hi, lo, upper, hi - upper]
}

impl Params {
    /// The uniform for `params` / `config`, `pixels` invocations with `row_stride` per
    /// dispatch row, and `metres_per_mm` for the registration's depth.
    pub(crate) fn new(
        p: &DecoderParams,
        config: &DecoderConfig,
        pixels: u32,
        row_stride: u32,
        metres_per_mm: f32,
    ) -> Self {
        let g = p.gaussian_kernel;
        // The bilateral threshold on a² + b² (kinect_usb's `bilateral_tau`, protocol §9.5).
        let tau = (p.joint_bilateral_ab_threshold * p.joint_bilateral_ab_threshold)
            / (p.ab_multiplier * p.ab_multiplier);
        let two_pi = 2.0 * std::f64::consts::PI;
        Params {
            size: [
                pixels,
                row_stride,
                0,
                (config.orientation == kinect_usb::orientation::Orientation::Scene) as u32,
            ],
            flags: [
                config.bilateral as u32,
                config.edge_aware as u32,
                (p.ab_confidence_slope > 0.0) as u32,
                0,
            ],
            ab: [
                p.ab_multiplier_per_frq[0],
                p.ab_multiplier_per_frq[1],
                p.ab_multiplier_per_frq[2],
                p.ab_multiplier,
            ],
            bil: [
                p.ab_output_multiplier,
                tau,
                // The CPU's literal −1.442695 (protocol §9.5), not the library's log₂ e.
                #[allow(clippy::approx_constant)]
                {
                    -1.442695f32 * p.joint_bilateral_exp
                },
                p.joint_bilateral_max_edge,
            ],
            gauss0: [g[0], g[1], g[2], g[3]],
            gauss1: [g[4], g[5], g[6], g[7]],
            gauss2: [g[8], p.individual_ab_threshold, p.ab_threshold, p.ab_confidence_slope],
            conf: [
                p.ab_confidence_offset,
                p.min_dealias_confidence,
                p.max_dealias_confidence,
                p.phase_offset,
            ],
            edge0: [
                p.unambiguous_dist,
                p.edge_ab_avg_min_value,
                p.edge_ab_std_dev_threshold,
                p.edge_close_delta_threshold,
            ],
            edge1: [
                p.edge_far_delta_threshold,
                p.edge_max_delta_threshold,
                p.edge_avg_delta_threshold,
                p.min_depth,
            ],
            edge2: [p.max_depth, metres_per_mm, 0.0, 0.0],
            two_pi_add: split_f64(two_pi),
            mul_t0: split_f64(3.0 / two_pi),
            mul_t1: split_f64(15.0 / two_pi),
            mul_t2: split_f64(2.0 / two_pi),
            mul_two_pi: split_f64(two_pi),
        }
    }
}

/// The three decode pipelines.
pub(crate) struct Pipelines {
    pub stage1: wgpu::ComputePipeline,
    pub filter: wgpu::ComputePipeline,
    pub edge: wgpu::ComputePipeline,
}

impl Pipelines {
    pub(crate) fn new(device: &wgpu::Device) -> Self {
        Self {
            stage1: super::pipeline(device, &STAGE1, "main"),
            filter: super::pipeline(device, &FILTER, "main"),
            edge: super::pipeline(device, &EDGE, "main"),
        }
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

/// The decoder's GPU state: its three pipelines, the device tables and the working buffers of
/// one frame, created from the device (the public wrapper is [`crate::GpuDecoder`]).
pub(crate) struct Decode {
    pipelines: Pipelines,
    grid: (u32, u32),
    raw: wgpu::Buffer,
    depth_mm: wgpu::Buffer,
    ir: wgpu::Buffer,
    uniform: wgpu::Buffer,
    pre: wgpu::Buffer,
    stage1_group: wgpu::BindGroup,
    filter_group: wgpu::BindGroup,
    /// The edge pass writing its metres into the decoder's own buffer (for [`Decode::decode`]).
    edge_group: wgpu::BindGroup,
    read_depth: wgpu::Buffer,
    read_ir: wgpu::Buffer,
}

impl Decode {
    /// A decoder on `ctx`'s device with the CPU decoder's inputs (`DepthDecoder::new`'s):
    /// constants, filter switches (`config.parallel` has no meaning here), the x/z tables
    /// (processing-row order) and the P0 tables. Uploads every table once.
    ///
    /// Errors: [`GpuError::Input`] for tables of the wrong size; [`GpuError::Device`] when the
    /// device fails.
    pub(crate) fn new(
        gpu: &Gpu,
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
        let device = gpu.device.clone();
        let (gx, gy, stride) = {
            let g = gpu.grid(PIXELS as u32);
            (g.x, g.y, g.stride)
        };
        let uniform_data = Params::new(&params, &config, PIXELS as u32, stride, METRES_PER_MM);
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("decoder params"),
            size: size_of::<Params>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        gpu.queue.write_buffer(&uniform, 0, bytemuck::bytes_of(&uniform_data));
        let lut: Vec<f32> = lut().map(f32::from).to_vec();
        let (trig, trig_index) = trig_tables(&params, p0);
        let lut = gpu.upload("decoder LUT", &lut);
        let trig = gpu.upload("decoder phase-step coefficients", &trig);
        let trig_index = gpu.upload("decoder coefficient index", &trig_index);
        let xtab = gpu.upload("decoder x table", &xz.x[..]);
        let ztab = gpu.upload("decoder z table", &xz.z[..]);
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
        let stage1_group = gpu.bind(
            &pipelines.stage1,
            &[
                (PARAMS, &uniform),
                (S1_RAW, &raw),
                (S1_LUT, &lut),
                (S1_TRIG, &trig),
                (S1_TRIG_INDEX, &trig_index),
                (S1_ZTAB, &ztab),
                (S1_OUT, &s1),
                (S1_N2, &n2),
                (S1_IR, &ir),
            ],
        );
        let filter_group = gpu.bind(
            &pipelines.filter,
            &[
                (PARAMS, &uniform),
                (F_S1, &s1),
                (F_N2, &n2),
                (F_XTAB, &xtab),
                (F_ZTAB, &ztab),
                (F_PRE, &pre),
            ],
        );
        let edge_group =
            edge_bind_group(&device, &pipelines, [&uniform, &pre, &depth_mm, &depth_m]);
        let dec = Decode {
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
        gpu.check_errors("creating the depth decoder")?;
        Ok(dec)
    }

    /// The edge pass's bind group writing the metres into `depth_m`.
    pub(crate) fn edge_bind_group(&self, gpu: &Gpu, depth_m: &wgpu::Buffer) -> wgpu::BindGroup {
        edge_bind_group(
            &gpu.device,
            &self.pipelines,
            [&self.uniform, &self.pre, &self.depth_mm, depth_m],
        )
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
    pub(crate) fn write_raw(&self, gpu: &Gpu, raw: &[u8]) {
        gpu.queue.write_buffer(&self.raw, 0, raw);
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
    pub(crate) fn decode(
        &self,
        gpu: &Gpu,
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
        self.write_raw(gpu, raw);
        let mut enc = gpu
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
        let submission = gpu.queue.submit([enc.finish()]);
        let (tx, rx) = mpsc::channel();
        for b in [&self.read_depth, &self.read_ir] {
            let tx = tx.clone();
            b.map_async(wgpu::MapMode::Read, 0..bytes, move |r| {
                let _ = tx.send(r);
            });
        }
        gpu.device
            .poll(wgpu::PollType::Wait { submission_index: Some(submission), timeout: None })
            .map_err(|e| gpu.device_error("waiting for the decoder", e.to_string()))?;
        for _ in 0..2 {
            match rx.recv() {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    return Err(gpu.device_error("mapping the decoder output", e.to_string()));
                }
                Err(e) => return Err(gpu.device_error("mapping the decoder output", e.to_string())),
            }
        }
        gpu.check_errors("decoding")?;
        for (buffer, out) in [(&self.read_depth, depth), (&self.read_ir, ir)] {
            {
                let view = buffer
                    .get_mapped_range(0..bytes)
                    .map_err(|e| gpu.device_error("reading the decoder output", e.to_string()))?;
                for (o, b) in out.iter_mut().zip(view.chunks_exact(4)) {
                    *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                }
            }
            buffer.unmap();
        }
        Ok(())
    }
}

/// The edge pass's bind group: `[params, pre, depth_mm, depth_m]`.
fn edge_bind_group(
    device: &wgpu::Device,
    pipelines: &Pipelines,
    buffers: [&wgpu::Buffer; 4],
) -> wgpu::BindGroup {
    let [params, pre, mm, m] = buffers;
    let entries = [(PARAMS, params), (E_PRE, pre), (E_DEPTH_MM, mm), (E_DEPTH_M, m)]
        .map(|(binding, b)| wgpu::BindGroupEntry { binding, resource: b.as_entire_binding() });
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("decoder edge pass"),
        layout: &pipelines.edge.get_bind_group_layout(0),
        entries: &entries,
    })
}

pub(crate) fn input(message: String) -> GpuError {
    GpuError::Input(geometry::GeometryError::InvalidInput(message))
}

#[cfg(test)]
mod tests {
    use super::split_f64;

    /// The parts must represent the constant to within f32·f32 precision (|c − hi − lo| below
    /// 2⁻⁴⁸·|c|, what `lo`'s own rounding leaves) and the upper / lower split must be exact
    /// with at most 12 significant bits in the upper part (so that Dekker's partial products
    /// are exact in f32).
    #[test]
    fn f64_constants_split_exactly() {
        let two_pi = 2.0 * std::f64::consts::PI;
        for c in [two_pi, 3.0 / two_pi, 15.0 / two_pi, 2.0 / two_pi] {
            let [hi, lo, up, low] = split_f64(c);
            let rest = (c - hi as f64 - lo as f64).abs();
            assert!(rest <= c * 2f64.powi(-48), "{c}: rest {rest:e}");
            assert_eq!(up as f64 + low as f64, hi as f64, "{c}");
            assert_eq!(up.to_bits() & 0xfff, 0, "{c}: upper part has more than 12 bits");
            assert!((low as f64).abs() < (hi as f64).abs() * 2f64.powi(-11), "{c}");
        }
    }
}
