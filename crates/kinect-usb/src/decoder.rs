//! CPU depth decoder (spec §9): raw 11-bit frame → depth (mm, f32) + IR amplitude (f32), both
//! 512 × 424 upright (row 0 = top).
//!
//! The arithmetic follows the reference order exactly (f32, with the f64 promotions of the spec,
//! no fused multiply-add, libm `cosf/sinf/atan2f/expf/logf`) so that it reproduces the oracle
//! vectors bit for bit on Linux x86-64. Internally everything runs in *processing*
//! coordinates: processing row `y = 423 − r` of output row `r`.
//!
//! All working buffers live in [`DepthDecoder`]; [`DepthDecoder::decode`] allocates nothing.
//! Rows are processed with rayon when [`DecoderConfig::parallel`] is set (in the caller's
//! current rayon pool).

use rayon::prelude::*;

use crate::error::{KinectError, Result};
use crate::params::{P0Tables, XzTables};
use crate::raw::{
    PIXELS, RAW_FRAME_BYTES, ROW_BYTES, SATURATED, SUB_IMAGE_BYTES, WIDTH, HEIGHT, lut,
    stored_row_of_processing_row,
};

/// Decoder constants of spec §9.1 (libfreenect2 defaults). Literal constants inside the
/// formulas are kept inline, as the spec requires for bit-exactness.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DecoderParams {
    /// Amplitude scale.
    pub ab_multiplier: f32,
    /// Per-frequency gain.
    pub ab_multiplier_per_frq: [f32; 3],
    /// IR output scale.
    pub ab_output_multiplier: f32,
    /// Phase steps in radians (0°, 120°, 240°).
    pub phase_in_rad: [f32; 3],
    /// Bilateral amplitude threshold.
    pub joint_bilateral_ab_threshold: f32,
    /// Bilateral edge test on the summed distance.
    pub joint_bilateral_max_edge: f32,
    /// Bilateral exponent.
    pub joint_bilateral_exp: f32,
    /// 3 × 3 Gaussian kernel, row-major.
    pub gaussian_kernel: [f32; 9],
    /// Added to positive phases.
    pub phase_offset: f32,
    /// Unambiguous distance unit (mm).
    pub unambiguous_dist: f32,
    /// Per-frequency amplitude gate.
    pub individual_ab_threshold: f32,
    /// Summed amplitude gate.
    pub ab_threshold: f32,
    /// De-aliasing confidence slope.
    pub ab_confidence_slope: f32,
    /// De-aliasing confidence offset.
    pub ab_confidence_offset: f32,
    /// Lower confidence clamp.
    pub min_dealias_confidence: f32,
    /// Upper confidence clamp.
    pub max_dealias_confidence: f32,
    /// Edge filter: minimum mean amplitude for the relative std-dev.
    pub edge_ab_avg_min_value: f32,
    /// Edge filter: std-dev threshold.
    pub edge_ab_std_dev_threshold: f32,
    /// Edge filter: close delta (mm).
    pub edge_close_delta_threshold: f32,
    /// Edge filter: far delta (mm).
    pub edge_far_delta_threshold: f32,
    /// Edge filter: max delta (mm).
    pub edge_max_delta_threshold: f32,
    /// Edge filter: average delta (mm).
    pub edge_avg_delta_threshold: f32,
    /// Minimum valid depth (mm) when the edge filter is on.
    pub min_depth: f32,
    /// Maximum valid depth (mm) when the edge filter is on.
    pub max_depth: f32,
}

impl Default for DecoderParams {
    fn default() -> Self {
        DecoderParams {
            ab_multiplier: 0.6666667,
            ab_multiplier_per_frq: [1.322581, 1.0, 1.612903],
            ab_output_multiplier: 16.0,
            phase_in_rad: [0.0, 2.094395, 4.18879],
            joint_bilateral_ab_threshold: 3.0,
            joint_bilateral_max_edge: 2.5,
            joint_bilateral_exp: 5.0,
            gaussian_kernel: [
                0.1069973, 0.1131098, 0.1069973, 0.1131098, 0.1195716, 0.1131098, 0.1069973,
                0.1131098, 0.1069973,
            ],
            phase_offset: 0.0,
            unambiguous_dist: 2083.333,
            individual_ab_threshold: 3.0,
            ab_threshold: 10.0,
            ab_confidence_slope: -0.5330578,
            ab_confidence_offset: 0.7694894,
            min_dealias_confidence: 0.3490659,
            max_dealias_confidence: 0.6108653,
            edge_ab_avg_min_value: 50.0,
            edge_ab_std_dev_threshold: 0.05,
            edge_close_delta_threshold: 50.0,
            edge_far_delta_threshold: 30.0,
            edge_max_delta_threshold: 100.0,
            edge_avg_delta_threshold: 0.0,
            min_depth: 0.5f32 * 1000.0f32,
            max_depth: 4.5f32 * 1000.0f32,
        }
    }
}

/// Switches of the decoder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DecoderConfig {
    /// Joint bilateral filter of the phasors (spec §9.5).
    pub bilateral: bool,
    /// Edge-aware filter of the depth (spec §9.7; also clamps to [min_depth, max_depth]).
    pub edge_aware: bool,
    /// Process rows in parallel on the current rayon pool.
    pub parallel: bool,
}

impl Default for DecoderConfig {
    fn default() -> Self {
        DecoderConfig { bilateral: true, edge_aware: true, parallel: true }
    }
}

/// Stage-1 result per pixel: (a, b, A) for each of the three frequencies.
type Stage1 = [f32; 9];

/// Per-pixel bilateral terms: (a·g, b·g, a² + b²) for each of the three frequencies.
type Unit = [f32; 9];

/// Bilateral range weights `expf(−1.442695·e·dist)` of the four "forward" neighbours of a pixel
/// (right, down-left, down, down-right), index `4·k + direction`. `dist` is symmetric bit for
/// bit (products commute in IEEE arithmetic), so one value serves both ends of the pair; it is
/// only filled (and only read) when both ends pass the amplitude threshold, where both use the
/// same exponent `e`.
type EdgeExp = [f32; 12];

/// The CPU depth decoder with its precomputed tables and working buffers.
pub struct DepthDecoder {
    params: DecoderParams,
    /// Configuration used by [`DepthDecoder::decode`].
    pub config: DecoderConfig,
    lut: [i16; 2048],
    /// Per processing pixel: cos ψ_kj and sin(−ψ_kj), laid out k-major: [C0 C1 C2 S0 S1 S2] × 3.
    trig: Vec<[f32; 18]>,
    xtable: Vec<f32>,
    ztable: Vec<f32>,
    stage1: Vec<Stage1>,
    /// Per pixel and frequency, the bilateral-filter terms that only depend on that pixel:
    /// [a·g, b·g, a² + b²] with g = 1/√(a² + b²) (spec §9.5), computed once per frame.
    unit: Vec<Unit>,
    edge_exp: Vec<EdgeExp>,
    depth_pre: Vec<f32>,
    ir_sum: Vec<f32>,
    edge_ok: Vec<bool>,
}

impl DepthDecoder {
    /// Builds a decoder from x/z tables (processing-row indexed) and the P0 tables.
    pub fn new(params: DecoderParams, config: DecoderConfig, xz: &XzTables, p0: &P0Tables) -> Result<Self> {
        if xz.x.len() != PIXELS || xz.z.len() != PIXELS {
            return Err(KinectError::Size { what: "x/z tables".into(), expected: PIXELS, got: xz.x.len().min(xz.z.len()) });
        }
        for t in &p0.tables {
            if t.len() != PIXELS {
                return Err(KinectError::Size { what: "P0 table".into(), expected: PIXELS, got: t.len() });
            }
        }
        let mut trig = vec![[0f32; 18]; PIXELS];
        for y in 0..HEIGHT {
            for x in 0..WIDTH {
                let e = &mut trig[y * WIDTH + x];
                for k in 0..3 {
                    let p = p0.tables[k][(HEIGHT - 1 - y) * WIDTH + x];
                    let theta = (-(p as f64) * 0.000031 * std::f64::consts::PI) as f32;
                    for j in 0..3 {
                        let psi = theta + params.phase_in_rad[j];
                        e[6 * k + j] = psi.cos();
                        e[6 * k + 3 + j] = (-psi).sin();
                    }
                }
            }
        }
        Ok(DepthDecoder {
            params,
            config,
            lut: lut(),
            trig,
            xtable: xz.x.clone(),
            ztable: xz.z.clone(),
            stage1: vec![[0f32; 9]; PIXELS],
            unit: vec![[0f32; 9]; PIXELS],
            edge_exp: vec![[0f32; 12]; PIXELS],
            depth_pre: vec![0f32; PIXELS],
            ir_sum: vec![0f32; PIXELS],
            edge_ok: vec![true; PIXELS],
        })
    }

    /// The decoder constants.
    pub fn params(&self) -> &DecoderParams {
        &self.params
    }

    /// Decodes one raw frame into upright `depth` (mm) and `ir` images of 512 × 424.
    pub fn decode(&mut self, raw: &[u8], depth: &mut [f32], ir: &mut [f32]) -> Result<()> {
        if raw.len() != RAW_FRAME_BYTES {
            return Err(KinectError::Size { what: "raw depth frame".into(), expected: RAW_FRAME_BYTES, got: raw.len() });
        }
        if depth.len() != PIXELS || ir.len() != PIXELS {
            return Err(KinectError::Size { what: "depth/IR output".into(), expected: PIXELS, got: depth.len().min(ir.len()) });
        }
        let cfg = self.config;
        let p = self.params;
        let lut = &self.lut;
        let trig = &self.trig;
        let ztable = &self.ztable;
        let xtable = &self.xtable;

        // Pass 1: stage 1 per processing row.
        {
            let f = |(y, (row, urow)): (usize, (&mut [Stage1], &mut [Unit]))| {
                stage1_row(raw, y, row, lut, trig, ztable, &p);
                if cfg.bilateral {
                    unit_row(row, urow);
                }
            };
            if cfg.parallel {
                self.stage1.par_chunks_mut(WIDTH).zip(self.unit.par_chunks_mut(WIDTH)).enumerate().for_each(f);
            } else {
                self.stage1.chunks_mut(WIDTH).zip(self.unit.chunks_mut(WIDTH)).enumerate().for_each(f);
            }
        }
        // Pass 1b: shared bilateral range weights (only with the bilateral filter).
        if cfg.bilateral {
            let un = &self.unit;
            let f = |(y, row): (usize, &mut [EdgeExp])| edge_exp_row(un, y, row, &p);
            if cfg.parallel {
                self.edge_exp.par_chunks_mut(WIDTH).enumerate().for_each(f);
            } else {
                self.edge_exp.chunks_mut(WIDTH).enumerate().for_each(f);
            }
        }
        // Pass 2: bilateral (optional) + stage 2 per processing row.
        {
            let s1 = &self.stage1;
            let un = &self.unit;
            let ee = &self.edge_exp;
            let f = |(y, ((d, s), e)): (usize, ((&mut [f32], &mut [f32]), &mut [bool]))| {
                stage2_row(s1, un, ee, y, d, s, e, xtable, ztable, &p, cfg.bilateral)
            };
            if cfg.parallel {
                self.depth_pre
                    .par_chunks_mut(WIDTH)
                    .zip(self.ir_sum.par_chunks_mut(WIDTH))
                    .zip(self.edge_ok.par_chunks_mut(WIDTH))
                    .enumerate()
                    .for_each(f);
            } else {
                self.depth_pre
                    .chunks_mut(WIDTH)
                    .zip(self.ir_sum.chunks_mut(WIDTH))
                    .zip(self.edge_ok.chunks_mut(WIDTH))
                    .enumerate()
                    .for_each(f);
            }
        }
        // Pass 3: edge-aware filter (optional), IR, flip to upright output.
        {
            let (s1, dp, is, eo) = (&self.stage1, &self.depth_pre, &self.ir_sum, &self.edge_ok);
            let f = |(r, (drow, irow)): (usize, (&mut [f32], &mut [f32]))| {
                let y = HEIGHT - 1 - r;
                output_row(s1, dp, is, eo, y, drow, irow, &p, cfg.edge_aware)
            };
            if cfg.parallel {
                depth.par_chunks_mut(WIDTH).zip(ir.par_chunks_mut(WIDTH)).enumerate().for_each(f);
            } else {
                depth.chunks_mut(WIDTH).zip(ir.chunks_mut(WIDTH)).enumerate().for_each(f);
            }
        }
        Ok(())
    }
}

/// Stage 1 (spec §9.4) of processing row `y`.
fn stage1_row(
    raw: &[u8],
    y: usize,
    out: &mut [Stage1],
    lut: &[i16; 2048],
    trig: &[[f32; 18]],
    ztable: &[f32],
    p: &DecoderParams,
) {
    let stored = stored_row_of_processing_row(y);
    // m[s][x]: LUT value of sub-image s at column x (columns 0 and 511 are never read: 0).
    let mut m = [[0i16; WIDTH]; 9];
    // The stored row, zero-padded so that every 11-bit code can be read with one 4-byte load
    // (the same bits as `raw::read_code`, which reads bytes past the row as 0).
    let mut padded = [0u8; ROW_BYTES + 4];
    for (s, ms) in m.iter_mut().enumerate() {
        padded[..ROW_BYTES].copy_from_slice(&raw[s * SUB_IMAGE_BYTES + stored * ROW_BYTES..][..ROW_BYTES]);
        // Slot q holds column 4·(q mod 128) + q / 128 (`raw::column_of_slot`): for each of the
        // four column phases, walk its 128 slots in order.
        for (phase, q0) in (0..4).map(|ph| (ph, ph * 128)) {
            for i in 0..128 {
                let x = 4 * i + phase;
                if x == 0 || x == WIDTH - 1 {
                    continue;
                }
                let bit = 11 * (q0 + i);
                let byte = bit >> 3;
                let w = u32::from_le_bytes([padded[byte], padded[byte + 1], padded[byte + 2], padded[byte + 3]]);
                ms[x] = lut[((w >> (bit & 7)) & 0x7FF) as usize];
            }
        }
    }
    for x in 0..WIDTH {
        let n = y * WIDTH + x;
        let t = &trig[n];
        let o = &mut out[x];
        if ztable[n] <= 0.0 {
            *o = [0.0; 9];
            continue;
        }
        for k in 0..3 {
            let (m0, m1, m2) = (m[3 * k][x], m[3 * k + 1][x], m[3 * k + 2][x]);
            if m0 == SATURATED || m1 == SATURATED || m2 == SATURATED {
                o[3 * k] = 0.0;
                o[3 * k + 1] = 0.0;
                o[3 * k + 2] = 65535.0;
                continue;
            }
            let (m0, m1, m2) = (m0 as f32, m1 as f32, m2 as f32);
            let c = &t[6 * k..6 * k + 6];
            let mut a = c[0] * m0 + c[1] * m1 + c[2] * m2;
            let mut b = c[3] * m0 + c[4] * m1 + c[5] * m2;
            a *= p.ab_multiplier_per_frq[k];
            b *= p.ab_multiplier_per_frq[k];
            let amp = (a * a + b * b).sqrt() * p.ab_multiplier;
            o[3 * k] = a;
            o[3 * k + 1] = b;
            o[3 * k + 2] = amp;
        }
    }
}

/// Per-pixel bilateral terms of one row (see [`Unit`]).
fn unit_row(s1: &[Stage1], out: &mut [Unit]) {
    for (o, st) in out.iter_mut().zip(s1) {
        for k in 0..3 {
            let (a, b) = (st[3 * k], st[3 * k + 1]);
            let n2 = a * a + b * b;
            let g = inv_norm(n2);
            o[3 * k] = a * g;
            o[3 * k + 1] = b * g;
            o[3 * k + 2] = n2;
        }
    }
}

/// Bilateral amplitude threshold τ on a² + b² (spec §9.5).
#[inline]
fn bilateral_tau(p: &DecoderParams) -> f32 {
    (p.joint_bilateral_ab_threshold * p.joint_bilateral_ab_threshold) / (p.ab_multiplier * p.ab_multiplier)
}

/// Range distance of two unit phasors (spec §9.5), in the reference's operation order with the
/// neighbour's factor first; symmetric bit for bit since each product commutes.
#[inline(always)]
fn range_dist(ua1: f32, ub1: f32, ua: f32, ub: f32) -> f32 {
    ((-(ua1 * ua + ub1 * ub)) + 1.0f32) * 0.5f32
}

/// Forward range weights of processing row `y` (see [`EdgeExp`]).
fn edge_exp_row(un: &[Unit], y: usize, out: &mut [EdgeExp], p: &DecoderParams) {
    let tau = bilateral_tau(p);
    let ce = -1.442695f32 * p.joint_bilateral_exp;
    let row = &un[y * WIDTH..(y + 1) * WIDTH];
    let next = if y + 1 < HEIGHT { Some(&un[(y + 1) * WIDTH..(y + 2) * WIDTH]) } else { None };
    for (x, o) in out.iter_mut().enumerate() {
        let c = &row[x];
        for k in 0..3 {
            let (ua, ub, n2) = (c[3 * k], c[3 * k + 1], c[3 * k + 2]);
            if !(n2 >= tau) {
                continue;
            }
            let mut w = |d: usize, q: &Unit| {
                if q[3 * k + 2] >= tau {
                    o[4 * k + d] = (ce * range_dist(q[3 * k], q[3 * k + 1], ua, ub)).exp();
                }
            };
            if x + 1 < WIDTH {
                w(0, &row[x + 1]);
            }
            if let Some(nx) = next {
                if x >= 1 {
                    w(1, &nx[x - 1]);
                }
                w(2, &nx[x]);
                if x + 1 < WIDTH {
                    w(3, &nx[x + 1]);
                }
            }
        }
    }
}

#[inline]
fn inv_norm(n2: f32) -> f32 {
    let g = 1.0f32 / n2.sqrt();
    if g.is_nan() { f32::INFINITY } else { g }
}

/// Joint bilateral filter (spec §9.5) of pixel (x, y) (not on the border). Returns the six
/// filtered phasor components and `edge_ok`.
#[inline]
fn bilateral(s1: &[Stage1], un: &[Unit], ee: &[EdgeExp], x: usize, y: usize, p: &DecoderParams) -> ([f32; 6], bool) {
    let mut out = [0f32; 6];
    let mut edge_ok = true;
    let n = y * WIDTH + x;
    let centre = &s1[n];
    let cu = &un[n];
    // Neighbour indices in kernel order (centre skipped), all in bounds: not on the border.
    let up = &s1[n - WIDTH - 1..n - WIDTH + 2];
    let mid = &s1[n - 1..n + 2];
    let dn = &s1[n + WIDTH - 1..n + WIDTH + 2];
    let uup = &un[n - WIDTH - 1..n - WIDTH + 2];
    let umid = &un[n - 1..n + 2];
    let udn = &un[n + WIDTH - 1..n + WIDTH + 2];
    let gk = &p.gaussian_kernel;
    let tau0 = bilateral_tau(p);
    // Shared weights: the pixel's own forward edges and the backward edges of the row above
    // and the left neighbour.
    let (e_ul, e_u, e_ur, e_l, e_c) = (&ee[n - WIDTH - 1], &ee[n - WIDTH], &ee[n - WIDTH + 1], &ee[n - 1], &ee[n]);
    for k in 0..3 {
        let (a, b) = (centre[3 * k], centre[3 * k + 1]);
        let (ua, ub, n2) = (cu[3 * k], cu[3 * k + 1], cu[3 * k + 2]);
        let mut tau = tau0;
        let mut e = p.joint_bilateral_exp;
        if n2 < tau {
            tau = 0.0;
            e = 0.0;
        }
        let ce = -1.442695f32 * e;
        // Both ends above τ: the weight was computed once in `edge_exp_row` (same `e`, same
        // argument bits).
        let shared = n2 >= tau0;
        let (mut w_acc, mut sa, mut sb, mut d_acc) = (0f32, 0f32, 0f32, 0f32);
        // One neighbour, in the reference's operation order.
        macro_rules! nb {
            ($w:expr, $o:expr, $u:expr, $e:expr) => {{
                let (o, u): (&Stage1, &Unit) = ($o, $u);
                let (a1, b1) = (o[3 * k], o[3 * k + 1]);
                let (ua1, ub1, n12) = (u[3 * k], u[3 * k + 1], u[3 * k + 2]);
                let dist = range_dist(ua1, ub1, ua, ub);
                let mut weight = 0.0f32;
                if n12 >= tau {
                    weight = $w * if shared { $e } else { (ce * dist).exp() };
                    d_acc += dist;
                }
                sa += weight * a1;
                sb += weight * b1;
                w_acc += weight;
            }};
        }
        nb!(gk[0], &up[0], &uup[0], e_ul[4 * k + 3]);
        nb!(gk[1], &up[1], &uup[1], e_u[4 * k + 2]);
        nb!(gk[2], &up[2], &uup[2], e_ur[4 * k + 1]);
        nb!(gk[3], &mid[0], &umid[0], e_l[4 * k]);
        {
            let w = gk[4];
            w_acc += w;
            sa += w * a;
            sb += w * b;
        }
        nb!(gk[5], &mid[2], &umid[2], e_c[4 * k]);
        nb!(gk[6], &dn[0], &udn[0], e_c[4 * k + 1]);
        nb!(gk[7], &dn[1], &udn[1], e_c[4 * k + 2]);
        nb!(gk[8], &dn[2], &udn[2], e_c[4 * k + 3]);
        edge_ok = edge_ok && d_acc < p.joint_bilateral_max_edge;
        if w_acc > 0.0 {
            out[2 * k] = sa / w_acc;
            out[2 * k + 1] = sb / w_acc;
        }
    }
    (out, edge_ok)
}

/// Stage 2 (spec §9.6) of one pixel: returns (depth, ir_sum).
#[inline]
fn stage2_pixel(ab: &[f32; 6], xt: f32, zt: f32, p: &DecoderParams) -> (f32, f32) {
    use std::f64::consts::PI;
    let two_pi = 2.0 * PI;
    let mut alpha = [0f32; 3];
    for k in 0..3 {
        let (a, b) = (ab[2 * k], ab[2 * k + 1]);
        alpha[k] = (a * a + b * b).sqrt() * p.ab_multiplier;
    }
    let s = alpha[0] + alpha[1] + alpha[2];
    let amin = fmin(fmin(alpha[0], alpha[1]), alpha[2]);
    let amax = fmax(fmax(alpha[0], alpha[1]), alpha[2]);
    let mut phase = 0.0f32;
    if !(amin < p.individual_ab_threshold || s < p.ab_threshold) {
        // The phases are only needed past the amplitude gate (same values as computing them
        // for every pixel: atan2f has no side effects).
        let mut phi = [0f32; 3];
        for k in 0..3 {
            let (a, b) = (ab[2 * k], ab[2 * k + 1]);
            let mut f = b.atan2(a);
            if f < 0.0 {
                f = ((f as f64) + two_pi) as f32;
            }
            if f.is_nan() {
                f = 0.0;
            }
            phi[k] = f;
        }
        let t0 = ((phi[0] as f64) / two_pi * 3.0) as f32;
        let t1 = ((phi[1] as f64) / two_pi * 15.0) as f32;
        let t2 = ((phi[2] as f64) / two_pi * 2.0) as f32;
        let t5 = floor((t1 - t0) * 0.333333f32 + 0.5f32) * 3.0f32 + t0;
        let mut t3 = -t2 + t5;
        let t4 = t3 * 2.0f32;
        let pos = t4 >= -t4;
        t3 *= if pos { 0.5f32 } else { -0.5f32 };
        t3 = (t3 - floor(t3)) * if pos { 2.0f32 } else { -2.0f32 };
        let wrap = 0.5f32 < t3.abs() && t3.abs() < 1.5f32;
        let mut t6 = if wrap { t5 + 15.0f32 } else { t5 };
        let mut t7 = if wrap { t1 + 15.0f32 } else { t1 };
        let mut t8 = (floor((-t2 + t6) * 0.5f32 + 0.5f32) * 2.0f32 + t2) * 0.5f32;
        t6 *= 0.333333f32;
        t7 *= 0.066667f32;
        let t9 = t8 + t6 + t7;
        let mut t10 = t9 * 0.333333f32;
        t6 = ((t6 as f64) * two_pi) as f32;
        t7 = ((t7 as f64) * two_pi) as f32;
        t8 = ((t8 as f64) * two_pi) as f32;
        let e8 = t7 * 0.826977f32 - t8 * 0.110264f32;
        let e6 = t8 * 0.551318f32 - t6 * 0.826977f32;
        let e7 = t6 * 0.110264f32 - t7 * 0.551318f32;
        let nu = e8 * e8 + e6 * e6 + e7 * e7;
        t10 *= if t9 >= 0.0 { 1.0f32 } else { 0.0f32 };
        let astar = if p.ab_confidence_slope > 0.0 { amin } else { amax };
        let mut c = ((astar.ln() * p.ab_confidence_slope * 0.301030f32 + p.ab_confidence_offset) * 3.321928f32).exp();
        c = if c < p.min_dealias_confidence { p.min_dealias_confidence } else { c };
        c = if c > p.max_dealias_confidence { p.max_dealias_confidence } else { c };
        c *= c;
        phase = t10 * if c >= nu { 1.0f32 } else { 0.0f32 };
    }
    let ph = if phase > 0.0 { phase + p.phase_offset } else { phase };
    let zl = zt * ph;
    let dmax = ph * p.unambiguous_dist * 2.0f32;
    let xm = (((xt * 90.0f32) as f64) / (((dmax * dmax) as f64) * 8192.0)) as f32;
    let mut zf = zl / (-zl * xm + 1.0f32);
    zf = if zf < 0.0 { 0.0 } else { zf };
    let d = if zl > 0.0 && dmax > 0.0 { zf } else { zl };
    (d, s)
}

/// `floorf` without a library call (the baseline x86-64 target has no `roundss`): exact for
/// every input — values with |x| ≥ 2²³, infinities and NaN are returned unchanged like
/// `floorf`, and the sign is restored so that −0.0 stays −0.0.
#[inline(always)]
fn floor(x: f32) -> f32 {
    if !(x.abs() < 8_388_608.0f32) {
        return x;
    }
    let t = (x as i32) as f32;
    // Branch-free (the comparison is data dependent): t − 1 or t − 0 (t − 0 = t exactly).
    let f = t - ((t > x) as i32 as f32);
    f.copysign(x)
}

#[inline]
fn fmin(a: f32, b: f32) -> f32 {
    if b < a { b } else { a }
}
#[inline]
fn fmax(a: f32, b: f32) -> f32 {
    if a < b { b } else { a }
}

/// Pass 2 of processing row `y`: bilateral + stage 2.
#[allow(clippy::too_many_arguments)]
fn stage2_row(
    s1: &[Stage1],
    un: &[Unit],
    ee: &[EdgeExp],
    y: usize,
    depth: &mut [f32],
    ir_sum: &mut [f32],
    edge_ok: &mut [bool],
    xtable: &[f32],
    ztable: &[f32],
    p: &DecoderParams,
    bilateral_on: bool,
) {
    for x in 0..WIDTH {
        let n = y * WIDTH + x;
        let c = &s1[n];
        let border = x == 0 || x == WIDTH - 1 || y == 0 || y == HEIGHT - 1;
        let (ab, ok) = if bilateral_on && !border {
            bilateral(s1, un, ee, x, y, p)
        } else {
            ([c[0], c[1], c[3], c[4], c[6], c[7]], true)
        };
        let (d, s) = stage2_pixel(&ab, xtable[n], ztable[n], p);
        depth[x] = d;
        ir_sum[x] = s;
        edge_ok[x] = ok;
    }
}

/// Pass 3 of processing row `y` (written to output row `423 − y`): edge-aware filter and IR.
#[allow(clippy::too_many_arguments)]
fn output_row(
    s1: &[Stage1],
    dp: &[f32],
    is: &[f32],
    eo: &[bool],
    y: usize,
    drow: &mut [f32],
    irow: &mut [f32],
    p: &DecoderParams,
    edge_on: bool,
) {
    for x in 0..WIDTH {
        let n = y * WIDTH + x;
        let st = &s1[n];
        let ir = (st[2] + st[5] + st[8]) * 0.3333333f32 * p.ab_output_multiplier;
        irow[x] = if ir > 65535.0 { 65535.0 } else { ir };
        let d = dp[n];
        if !edge_on {
            drow[x] = d;
            continue;
        }
        if !(d >= p.min_depth && d <= p.max_depth) {
            drow[x] = 0.0;
            continue;
        }
        if x < 1 || y < 1 || x > WIDTH - 2 || y > HEIGHT - 2 {
            drow[x] = d;
            continue;
        }
        let mut sum = is[n];
        let mut sq = is[n] * is[n];
        let (mut lo, mut hi) = (d, d);
        for dy in [-1isize, 0, 1] {
            let yy = (y as isize + dy) as usize;
            for dx in [-1isize, 0, 1] {
                if dy == 0 && dx == 0 {
                    continue;
                }
                let m = yy * WIDTH + (x as isize + dx) as usize;
                let s1v = is[m];
                sum += s1v;
                sq += s1v * s1v;
                let dn = if eo[m] { dp[m] } else { 0.0 };
                if dn > 0.0 {
                    lo = fmin(lo, dn);
                    hi = fmax(hi, dn);
                }
            }
        }
        let sigma = (sq * 9.0f32 - sum * sum).sqrt() / 9.0f32 / fmax(sum / 9.0f32, p.edge_ab_avg_min_value);
        let dlo = (d - lo).abs();
        let dhi = (d - hi).abs();
        let avg = (dlo + dhi) * 0.5f32;
        let mx = fmax(dlo, dhi);
        let reject = d > 0.0
            && sigma >= p.edge_ab_std_dev_threshold
            && dlo > p.edge_close_delta_threshold
            && dhi > p.edge_far_delta_threshold
            && mx > p.edge_max_delta_threshold
            && avg > p.edge_avg_delta_threshold;
        drow[x] = if reject || !eo[n] { 0.0 } else { d };
    }
}

#[cfg(test)]
mod tests {
    use super::floor;

    /// The hand-written floor must equal `f32::floor` bit for bit (zero tolerance: the decoder
    /// is bit-exact). Checked on every 257th bit pattern (≈ 16.7 M values, both signs, all
    /// exponents, NaN and infinities) plus the signed zeros and values next to integers.
    #[test]
    fn floor_matches_libm_bit_for_bit() {
        let check = |x: f32| {
            let (got, want) = (floor(x), x.floor());
            assert!(
                got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                "floor({x:e}) = {got:e}, libm {want:e}"
            );
        };
        for bits in (0..=u32::MAX).step_by(257) {
            check(f32::from_bits(bits));
        }
        for x in [0.0f32, -0.0, 0.5, -0.5, 1.0, -1.0, 8_388_607.5, -8_388_607.5, 8_388_608.0, -8_388_609.0] {
            check(x);
            check(f32::from_bits(x.to_bits() + 1));
            check(f32::from_bits(x.to_bits().saturating_sub(1)));
        }
    }
}
