//! Kinect v2 depth decoding (`decode_stage1.wgsl`, `decode_filter.wgsl`, `decode_edge.wgsl`):
//! the three passes of the CPU decoder `kinect_usb::decoder` with `DecoderPrecision::Fast`, and
//! their shared uniform [`Params`]. The driver is [`crate::GpuDecoder`].

use bytemuck::{Pod, Zeroable};
use kinect_usb::decoder::{DecoderConfig, DecoderParams};

use super::Shader;
use crate::shaders;

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
