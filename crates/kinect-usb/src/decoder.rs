//! CPU depth decoder (spec §9): raw 11-bit frame → depth (mm, f32) + IR amplitude (f32), both
//! 512 × 424 upright (row 0 = top).
//!
//! # Precision
//!
//! [`DecoderPrecision::Exact`] follows the reference order exactly (f32, with the f64
//! promotions of the spec, no fused multiply-add, libm `cosf/sinf/atan2f/expf/logf`) and
//! reproduces the oracle vectors bit for bit on Linux x86-64 (`tests/oracle.rs`).
//!
//! [`DecoderPrecision::Fast`] — **the default, also of `kfuse capture`** — is the same
//! algorithm in the same operation order, but computes `exp`, `ln` and `atan2` with this
//! crate's branch-free four-lane f32 functions ([`fastmath`], within 2.5 ulp of f64) and, in
//! stage 2, multiplies by f64 constants where the reference divides, so that every stage runs
//! in SIMD lanes. Against every oracle file it stays far inside spec §9.9's test policy: at
//! most 0.003 mm depth difference (bar 0.01 mm), no pixel changing validity, 97–99.9 % of the
//! pixels bit-identical, IR bit-identical (asserted per file in `tests/oracle.rs`). Its
//! four-lane path needs about 134 M instructions per frame with both filters instead of 299 M
//! (Exact) and 610 M (the previous decoder); with the AVX2 kernels below a frame takes about
//! 8 ms of one core instead of 19 ms (Exact; see BENCHMARKS.md). That
//! is what lets `kfuse capture` decode at the sensor's 30 Hz (33 ms per frame) with time left
//! for JPEG decoding and writing files, which is why it is the default; the differences are
//! far below the sensor's noise. Use `Exact` (`kfuse capture --exact-decoder`) to reproduce
//! libfreenect2's CPU decoder bit for bit.
//!
//! # Structure
//!
//! Internally everything runs in *processing* coordinates: processing row `y = 423 − r` of
//! output row `r`. The frame is cut into bands of rows; each band streams its rows through a
//! ring of three stage-1 rows kept as structure-of-arrays planes (`[f32; 512]` per quantity and
//! frequency), computes the bilateral filter's shared range weights (one `exp` per neighbour
//! pair), the bilateral filter and stage 2 row by row, and writes the pre-edge-filter depth.
//! A second pass applies the edge-aware filter and flips rows to the upright output. Loops run
//! over whole rows with selects instead of branches, which LLVM vectorises; per-pixel floating
//! point sums keep the reference order (vectorising across pixels reorders nothing within a
//! pixel). With [`DecoderConfig::parallel`] the bands run on the caller's current rayon pool.
//!
//! # Kernels
//!
//! On a CPU with AVX2 (checked once at run time, [`Kernels::detect`]) `Fast` runs its two
//! heaviest parts — the bilateral pair weights and stage 2 — as eight-lane loops compiled for
//! AVX2 (module `lanes8`); elsewhere, and for `Exact`, the four-lane `wide` code runs. Both do
//! the same IEEE operations in the same order, so the output is **bit-identical** either way
//! (`tests/oracle.rs` compares them on every vector file); [`DepthDecoder::with_kernels`]
//! forces the portable path. The default build needs no `-C target-cpu`.
//!
//! All working buffers live in [`DepthDecoder`]; [`DepthDecoder::decode`] allocates nothing.

// The spec's literal constants (1.442695, 0.301030, 3.321928, …) must stay as written for
// bit-exactness; they are not the library constants they approximate.
#![allow(clippy::approx_constant)]

pub mod fastmath;
#[cfg(target_arch = "x86_64")]
mod lanes8;

use rayon::prelude::*;
use wide::{f32x4, f64x2};

use crate::error::{KinectError, Result};
use crate::params::{P0Tables, XzTables};
use crate::raw::{
    HEIGHT, PIXELS, RAW_FRAME_BYTES, ROW_BYTES, SATURATED, SUB_IMAGE_BYTES, WIDTH, lut,
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

/// How the decoder evaluates its transcendental functions (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DecoderPrecision {
    /// glibc `expf/logf/atan2f` per pixel, as the reference: bit-identical to the oracle.
    Exact,
    /// Four-lane f32 approximations (≤ 2.5 ulp): within spec §9.9's tolerance, about twice as
    /// fast as `Exact`.
    #[default]
    Fast,
}

/// Vector width of the [`DecoderPrecision::Fast`] kernels. Both give the same bits (the
/// eight-lane kernels do the same IEEE operations in the same order); only speed differs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kernels {
    /// Four lanes (SSE2 on x86-64, `wide`'s portable lanes elsewhere): every CPU.
    Portable,
    /// Eight lanes (AVX2) for the hottest loops of `Fast`; chosen by [`DepthDecoder::new`]
    /// when the CPU has AVX2 (Intel since 2013, AMD since 2015). `Exact` never uses them.
    Avx2,
}

impl Kernels {
    /// The widest kernels this CPU runs.
    pub fn detect() -> Kernels {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Kernels::Avx2;
        }
        Kernels::Portable
    }
}

const W: usize = WIDTH;
const H: usize = HEIGHT;
/// Row bands of a frame. 8 keeps both cores of the CI machine (and up to 8) busy while the
/// redundant halo work (one extra stage-1 row on each side of a band) stays under 4 %.
const BANDS: usize = 8;
/// Processing rows per band.
const BAND_ROWS: usize = H / BANDS;
const _: () = assert!(BAND_ROWS * BANDS == H);
/// The saturation marker as the f32 the stage-1 arithmetic sees.
const SAT: f32 = SATURATED as f32;
/// Padding on each side of a [`PPlane`], so that the lanes of a neighbour at x ± 1 can be loaded
/// for every group of four pixels.
const PAD: usize = 4;

/// Row stride of the frame planes read with neighbours (`W` plus [`PAD`] on each side).
const SW: usize = W + 2 * PAD;

/// One row of one quantity, indexed by image column.
type Plane = [f32; W];
/// One row of one quantity with [`PAD`] unused elements on each side: column x at `x + PAD`.
type PPlane = [f32; W + 2 * PAD];

/// Four lanes.
type V = f32x4;

#[inline(always)]
fn sp(v: f32) -> V {
    V::splat(v)
}
/// Lanes `p[i..i + 4]`.
#[inline(always)]
fn ld(p: &[f32], i: usize) -> V {
    let mut a = [0f32; 4];
    a.copy_from_slice(&p[i..i + 4]);
    V::new(a)
}
/// Stores lanes at `p[i..i + 4]`.
#[inline(always)]
fn st(p: &mut [f32], i: usize, v: V) {
    p[i..i + 4].copy_from_slice(&v.to_array());
}
/// Widens to f64 (two pairs of lanes).
#[inline(always)]
fn wide64(v: V) -> [f64x2; 2] {
    let a = v.to_array();
    [f64x2::new([a[0] as f64, a[1] as f64]), f64x2::new([a[2] as f64, a[3] as f64])]
}
/// Rounds two pairs of f64 lanes to f32.
#[inline(always)]
fn narrow(v: [f64x2; 2]) -> V {
    let (l, h) = (v[0].to_array(), v[1].to_array());
    V::new([l[0] as f32, l[1] as f32, h[0] as f32, h[1] as f32])
}
/// f64 arithmetic on the lanes, rounded back to f32.
#[inline(always)]
fn map64(v: V, f: impl Fn(f64x2) -> f64x2) -> V {
    let [l, h] = wide64(v);
    narrow([f(l), f(h)])
}

/// Stage-1 results of one processing row (spec §9.4) plus the bilateral filter's per-pixel
/// terms (spec §9.5 step 1): per frequency k, `a`, `b`, amplitude `A`, the unit phasor
/// `(a·g, b·g)` with `g = 1/√(a² + b²)` (NaN → +∞) and `n² = a² + b²`.
struct Row1 {
    a: [PPlane; 3],
    b: [PPlane; 3],
    amp: [Plane; 3],
    ua: [PPlane; 3],
    ub: [PPlane; 3],
    n2: [PPlane; 3],
}

/// Bilateral range weights `exp((−1.442695·e)·dist)` of the four "forward" neighbour pairs of
/// each pixel of a row, `e[k][dir]` with dir = right, down-left, down, down-right, and the
/// distances `dist` themselves, both 0 unless both ends pass the amplitude threshold. `dist` is
/// symmetric bit for bit (each product commutes), so one value serves both ends, which then use
/// the same exponent `e`.
struct RowE {
    e: [[PPlane; 4]; 3],
    /// The range distances `dist` of the same pairs.
    d: [[PPlane; 4]; 3],
}

/// Working rows of one band (about 200 KB).
struct Workspace {
    prev: Box<Row1>,
    cur: Box<Row1>,
    next: Box<Row1>,
    e_prev: Box<RowE>,
    e_cur: Box<RowE>,
    /// LUT values of the nine phase sub-images of the row being unpacked, by image column.
    m: [Plane; 9],
    /// Filtered (or copied) phasors.
    fa: [Plane; 3],
    fb: [Plane; 3],
    /// Bilateral `edge_ok` as 1.0 / 0.0.
    ok: Plane,
    /// Stage-2 scratch: A* of the confidence, the amplitude gate (1.0 / 0.0), phases, confidence.
    astar: Plane,
    gate: Plane,
    phi: [Plane; 3],
    conf: Plane,
}

impl Row1 {
    fn boxed() -> Box<Self> {
        let z = [[0f32; W + 2 * PAD]; 3];
        Box::new(Row1 { a: z, b: z, amp: [[0f32; W]; 3], ua: z, ub: z, n2: z })
    }
}

impl RowE {
    fn boxed() -> Box<Self> {
        let z = [[[0f32; W + 2 * PAD]; 4]; 3];
        Box::new(RowE { e: z, d: z })
    }
}

impl Workspace {
    fn boxed() -> Box<Self> {
        let z3 = [[0f32; W]; 3];
        Box::new(Workspace {
            prev: Row1::boxed(),
            cur: Row1::boxed(),
            next: Row1::boxed(),
            e_prev: RowE::boxed(),
            e_cur: RowE::boxed(),
            m: [[0f32; W]; 9],
            fa: z3,
            fb: z3,
            ok: [0f32; W],
            astar: [0f32; W],
            gate: [0f32; W],
            phi: z3,
            conf: [0f32; W],
        })
    }
}

/// Largest span of P0 values (per frequency) stored as a table indexed by value rather than
/// as per-pixel planes: 16 384 entries of 32 bytes (512 KB per frequency) still sit in the L2
/// cache, while the per-pixel planes stream 15.6 MB per frame (the vectors' tables span
/// about 3 000 values).
const TRIG_TABLE_MAX_SPAN: usize = 16_384;

/// The phase-step coefficients of spec §9.3, `cos ψ_kj` and `sin(−ψ_kj)`, which depend on the
/// pixel only through its P0 value.
enum Trig {
    /// Per processing row, 18 planes: for k = 0..3, `cos ψ_k0..2` then `sin(−ψ_k0..2)`.
    Planes(Vec<[Plane; 18]>),
    /// Per frequency k, entry `P − min P` = `[cos ψ_k0..2, 0, sin(−ψ_k0..2), 0]`; per processing
    /// row and frequency, each pixel's entry.
    Table { table: [Vec<[f32; 8]>; 3], index: Vec<[[u16; W]; 3]> },
}

impl Trig {
    /// A table if every frequency's P0 values span less than `max_span` values, else planes.
    #[allow(clippy::needless_range_loop)] // x indexes the P0 table and 18 planes.
    fn new(params: &DecoderParams, p0: &P0Tables, max_span: usize) -> Self {
        // Spec §9.3, in this precision.
        let coefficients = |p: u16| -> [f32; 8] {
            let theta = (-(p as f64) * 0.000031 * std::f64::consts::PI) as f32;
            let mut e = [0f32; 8];
            for j in 0..3 {
                let psi = theta + params.phase_in_rad[j];
                e[j] = psi.cos();
                e[4 + j] = (-psi).sin();
            }
            e
        };
        let range = |t: &[u16]| {
            (t.iter().copied().min().unwrap_or(0), t.iter().copied().max().unwrap_or(0))
        };
        let spans = p0.tables.each_ref().map(|t| range(t));
        // P0 row 423 − y is processing row y (spec §9.3).
        let p0_at = |k: usize, y: usize, x: usize| p0.tables[k][(H - 1 - y) * W + x];
        if spans.iter().all(|&(lo, hi)| ((hi - lo) as usize) < max_span) {
            let base = spans.map(|(lo, _)| lo);
            let table = [0, 1, 2].map(|k| (spans[k].0..=spans[k].1).map(coefficients).collect());
            let index = (0..H)
                .map(|y| [0, 1, 2].map(|k| std::array::from_fn(|x| p0_at(k, y, x) - base[k])))
                .collect();
            Trig::Table { table, index }
        } else {
            let mut planes = vec![[[0f32; W]; 18]; H];
            for (y, pl) in planes.iter_mut().enumerate() {
                for x in 0..W {
                    for k in 0..3 {
                        let e = coefficients(p0_at(k, y, x));
                        for j in 0..3 {
                            pl[6 * k + j][x] = e[j];
                            pl[6 * k + 3 + j][x] = e[4 + j];
                        }
                    }
                }
            }
            Trig::Planes(planes)
        }
    }

    /// Lanes x..x + 4 of `[cos ψ_k0, cos ψ_k1, cos ψ_k2, sin(−ψ_k0), sin(−ψ_k1), sin(−ψ_k2)]` of
    /// processing row y.
    #[inline(always)]
    fn lanes(&self, y: usize, k: usize, x: usize) -> [V; 6] {
        match self {
            Trig::Planes(planes) => {
                let pl = &planes[y];
                [0, 1, 2, 3, 4, 5].map(|j| ld(&pl[6 * k + j], x))
            }
            Trig::Table { table, index } => {
                let (t, ix) = (&table[k], &index[y][k]);
                let entries = [0, 1, 2, 3].map(|l| &t[ix[x + l] as usize]);
                let [c0, c1, c2, _] = V::transpose(entries.map(|e| ld(e, 0)));
                let [s0, s1, s2, _] = V::transpose(entries.map(|e| ld(e, 4)));
                [c0, c1, c2, s0, s1, s2]
            }
        }
    }
}

/// Per-frame-constant tables, by processing row.
struct Tables {
    /// The companding LUT (spec §8) as f32.
    lut: [f32; 2048],
    /// Spec §9.3's coefficients.
    trig: Trig,
    x: Vec<Plane>,
    z: Vec<Plane>,
}

/// The CPU depth decoder with its precomputed tables and working buffers.
pub struct DepthDecoder {
    params: DecoderParams,
    /// Configuration used by [`DepthDecoder::decode`].
    pub config: DecoderConfig,
    /// Transcendental functions used by [`DepthDecoder::decode`] (default [`DecoderPrecision::Fast`]).
    pub precision: DecoderPrecision,
    /// Vector width; only [`DepthDecoder::with_kernels`] changes it, so `Avx2` implies the
    /// CPU has AVX2.
    kernels: Kernels,
    tables: Tables,
    work: Vec<Box<Workspace>>,
    /// Stage-2 depth before the edge-aware filter, by processing pixel.
    depth_pre: Vec<f32>,
    /// Spec §9.7's `d̃` (depth, 0 where the bilateral `edge_ok` is false) where it is > 0, else
    /// +∞: what the neighbour minimum of the edge-aware filter reads. Rows of stride [`SW`].
    depth_lo: Vec<f32>,
    /// The same with −∞ for the neighbour maximum. Rows of stride [`SW`].
    depth_hi: Vec<f32>,
    /// Stage-2 amplitude sum (spec §9.6 step 2). Rows of stride [`SW`].
    ir_sum: Vec<f32>,
}

impl DepthDecoder {
    /// Builds a decoder from x/z tables (processing-row indexed) and the P0 tables, with
    /// [`DecoderPrecision::Fast`].
    pub fn new(
        params: DecoderParams,
        config: DecoderConfig,
        xz: &XzTables,
        p0: &P0Tables,
    ) -> Result<Self> {
        if xz.x.len() != PIXELS || xz.z.len() != PIXELS {
            return Err(KinectError::Size {
                what: "x/z tables".into(),
                expected: PIXELS,
                got: xz.x.len().min(xz.z.len()),
            });
        }
        for t in &p0.tables {
            if t.len() != PIXELS {
                return Err(KinectError::Size {
                    what: "P0 table".into(),
                    expected: PIXELS,
                    got: t.len(),
                });
            }
        }
        let trig = Trig::new(&params, p0, TRIG_TABLE_MAX_SPAN);
        let rows = |v: &[f32]| -> Vec<Plane> {
            v.chunks_exact(W)
                .map(|c| {
                    let mut r = [0f32; W];
                    r.copy_from_slice(c);
                    r
                })
                .collect()
        };
        Ok(DepthDecoder {
            params,
            config,
            precision: DecoderPrecision::default(),
            kernels: Kernels::detect(),
            tables: Tables { lut: lut().map(f32::from), trig, x: rows(&xz.x), z: rows(&xz.z) },
            work: (0..BANDS).map(|_| Workspace::boxed()).collect(),
            depth_pre: vec![0f32; PIXELS],
            depth_lo: vec![0f32; H * SW],
            depth_hi: vec![0f32; H * SW],
            ir_sum: vec![0f32; H * SW],
        })
    }

    /// The same decoder with another [`DecoderPrecision`].
    pub fn with_precision(mut self, precision: DecoderPrecision) -> Self {
        self.precision = precision;
        self
    }

    /// The same decoder with other [`Kernels`]; `Avx2` on a CPU without AVX2 falls back to
    /// `Portable` (see [`DepthDecoder::kernels`]).
    pub fn with_kernels(mut self, kernels: Kernels) -> Self {
        self.kernels = if kernels == Kernels::Avx2 { Kernels::detect() } else { kernels };
        self
    }

    /// The kernels [`DepthDecoder::decode`] uses for [`DecoderPrecision::Fast`].
    pub fn kernels(&self) -> Kernels {
        self.kernels
    }

    /// The decoder constants.
    pub fn params(&self) -> &DecoderParams {
        &self.params
    }

    /// Decodes one raw frame into upright `depth` (mm) and `ir` images of 512 × 424.
    pub fn decode(&mut self, raw: &[u8], depth: &mut [f32], ir: &mut [f32]) -> Result<()> {
        if raw.len() != RAW_FRAME_BYTES {
            return Err(KinectError::Size {
                what: "raw depth frame".into(),
                expected: RAW_FRAME_BYTES,
                got: raw.len(),
            });
        }
        if depth.len() != PIXELS || ir.len() != PIXELS {
            return Err(KinectError::Size {
                what: "depth/IR output".into(),
                expected: PIXELS,
                got: depth.len().min(ir.len()),
            });
        }
        let ctx = Ctx {
            raw,
            t: &self.tables,
            p: &self.params,
            cfg: self.config,
            fast: self.precision == DecoderPrecision::Fast,
            lanes8: self.precision == DecoderPrecision::Fast && self.kernels == Kernels::Avx2,
        };
        // Pass 1: stage 1, bilateral, stage 2 per band; IR written directly (output rows of a
        // band are the band's processing rows flipped, hence the reversed output chunks).
        let chunk = BAND_ROWS * W;
        if self.config.parallel {
            self.work
                .par_iter_mut()
                .zip(self.depth_pre.par_chunks_mut(chunk))
                .zip(self.depth_lo.par_chunks_mut(BAND_ROWS * SW))
                .zip(self.depth_hi.par_chunks_mut(BAND_ROWS * SW))
                .zip(self.ir_sum.par_chunks_mut(BAND_ROWS * SW))
                .zip(ir.par_chunks_mut(chunk).rev())
                .enumerate()
                .for_each(|(i, (((((ws, dp), lo), hi), is), irc))| {
                    let out = BandOut { dp, lo, hi, is, ir: irc };
                    band(&ctx, ws, i * BAND_ROWS, (i + 1) * BAND_ROWS, out)
                });
        } else {
            let out = BandOut {
                dp: &mut self.depth_pre,
                lo: &mut self.depth_lo,
                hi: &mut self.depth_hi,
                is: &mut self.ir_sum,
                ir,
            };
            band(&ctx, &mut self.work[0], 0, H, out);
        }
        // Pass 2: edge-aware filter (optional) and flip to upright output.
        let planes =
            (&self.depth_pre[..], &self.depth_lo[..], &self.depth_hi[..], &self.ir_sum[..]);
        let f = |(r, drow): (usize, &mut [f32])| {
            output_row(planes, H - 1 - r, drow, &self.params, self.config.edge_aware)
        };
        if self.config.parallel {
            depth.par_chunks_mut(W).enumerate().for_each(f);
        } else {
            depth.chunks_mut(W).enumerate().for_each(f);
        }
        Ok(())
    }
}

/// What every row function reads.
struct Ctx<'a> {
    raw: &'a [u8],
    t: &'a Tables,
    p: &'a DecoderParams,
    cfg: DecoderConfig,
    fast: bool,
    /// Run the eight-lane kernels (Fast on an AVX2 CPU, see [`Kernels`]).
    lanes8: bool,
}

/// Pass-1 outputs of a band of processing rows `y0..y1`: `dp` (stride [`W`]), `lo`, `hi`, `is`
/// (stride [`SW`]) hold those rows; `ir` holds the upright output rows `H − y1 .. H − y0`.
struct BandOut<'a> {
    dp: &'a mut [f32],
    lo: &'a mut [f32],
    hi: &'a mut [f32],
    is: &'a mut [f32],
    ir: &'a mut [f32],
}

/// Pass 1 over processing rows `y0..y1`, with the eight-lane kernels when `c.lanes8`.
fn band(c: &Ctx, ws: &mut Workspace, y0: usize, y1: usize, out: BandOut) {
    #[cfg(target_arch = "x86_64")]
    if c.lanes8 {
        // SAFETY: `lanes8` is only set for `Kernels::Avx2`, which `DepthDecoder` holds only
        // after `is_x86_feature_detected!("avx2")` returned true on this CPU.
        #[allow(unsafe_code)]
        unsafe {
            band_avx2(c, ws, y0, y1, out)
        };
        return;
    }
    band_with::<false>(c, ws, y0, y1, out)
}

/// [`band_with`] compiled for AVX2, so that the eight-lane kernels it inlines vectorise to
/// 256-bit registers.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn band_avx2(c: &Ctx, ws: &mut Workspace, y0: usize, y1: usize, out: BandOut) {
    band_with::<true>(c, ws, y0, y1, out)
}

/// Pass 1 over processing rows `y0..y1`; `L8` selects the eight-lane kernels of [`lanes8`].
#[inline(always)]
fn band_with<const L8: bool>(c: &Ctx, ws: &mut Workspace, y0: usize, y1: usize, out: BandOut) {
    let BandOut { dp, lo, hi, is, ir } = out;
    let bil = c.cfg.bilateral;
    if bil {
        if y0 > 0 {
            stage1_row(c, y0 - 1, &mut ws.m, &mut ws.prev, true);
        }
        stage1_row(c, y0, &mut ws.m, &mut ws.cur, true);
        if y0 > 0 {
            edge_weights::<L8>(c, &ws.prev, &ws.cur, &mut ws.e_prev);
        }
    }
    for y in y0..y1 {
        let o = (y - y0) * W;
        if bil {
            if y + 1 < H {
                stage1_row(c, y + 1, &mut ws.m, &mut ws.next, true);
                edge_weights::<L8>(c, &ws.cur, &ws.next, &mut ws.e_cur);
            }
            if y == 0 || y == H - 1 {
                copy_unfiltered(&ws.cur, &mut ws.fa, &mut ws.fb, &mut ws.ok);
            } else {
                for k in 0..3 {
                    bilateral_k(
                        c.p,
                        k,
                        &ws.prev,
                        &ws.cur,
                        &ws.next,
                        &ws.e_prev,
                        &ws.e_cur,
                        &mut ws.fa[k],
                        &mut ws.fb[k],
                        &mut ws.ok,
                    );
                }
            }
        } else {
            stage1_row(c, y, &mut ws.m, &mut ws.cur, false);
            copy_unfiltered(&ws.cur, &mut ws.fa, &mut ws.fb, &mut ws.ok);
        }
        ir_row(&ws.cur, c.p, &mut ir[(y1 - 1 - y) * W..][..W]);
        let os = (y - y0) * SW + PAD;
        let (dpr, lor, hir, isr) =
            (&mut dp[o..o + W], &mut lo[os..os + W], &mut hi[os..os + W], &mut is[os..os + W]);
        #[cfg(target_arch = "x86_64")]
        if L8 {
            let scratch = lanes8::Stage2Scratch {
                astar: &mut ws.astar,
                gate: &mut ws.gate,
                phi: &mut ws.phi,
                conf: &mut ws.conf,
            };
            lanes8::stage2_row(
                c.p, &ws.fa, &ws.fb, &ws.ok, &c.t.x[y], &c.t.z[y], scratch, dpr, lor, hir, isr,
            );
        } else {
            stage2_row(c, y, ws, dpr, lor, hir, isr);
        }
        #[cfg(not(target_arch = "x86_64"))]
        stage2_row(c, y, ws, dpr, lor, hir, isr);
        if bil {
            // Rotate the ring: prev ← cur ← next, e_prev ← e_cur.
            std::mem::swap(&mut ws.prev, &mut ws.cur);
            std::mem::swap(&mut ws.cur, &mut ws.next);
            std::mem::swap(&mut ws.e_prev, &mut ws.e_cur);
        }
    }
}

/// Unpacks the 512 11-bit codes of one 704-byte stored row through the LUT into image-column
/// order (spec §8). Slots `8g .. 8g + 8` occupy the 11 bytes from `11g`; slot `q` holds column
/// `4·(q mod 128) + q div 128`. Columns 0 and 511 are never read by the decoder: 0.
#[inline(always)]
fn unpack_row(row: &[u8], lut: &[f32; 2048], out: &mut Plane) {
    for g in 0..64 {
        let o = 11 * g;
        let (mut lo, mut hi) = ([0u8; 8], [0u8; 8]);
        lo.copy_from_slice(&row[o..o + 8]);
        hi.copy_from_slice(&row[o + 3..o + 11]);
        let (lo, hi) = (u64::from_le_bytes(lo), u64::from_le_bytes(hi));
        // Code i of the group starts at bit 11·i; codes 5..7 are read from the second load,
        // which starts 24 bits later.
        let codes = [lo, lo >> 11, lo >> 22, lo >> 33, lo >> 44, hi >> 31, hi >> 42, hi >> 53];
        let base = 32 * (g % 16) + g / 16;
        for (i, code) in codes.into_iter().enumerate() {
            out[base + 4 * i] = lut[(code & 0x7ff) as usize];
        }
    }
    out[0] = 0.0;
    out[W - 1] = 0.0;
}

/// Stage 1 (spec §9.4) of processing row `y`, plus the bilateral per-pixel terms if `unit`.
#[inline(always)]
fn stage1_row(c: &Ctx, y: usize, m: &mut [Plane; 9], out: &mut Row1, unit: bool) {
    let stored = stored_row_of_processing_row(y);
    for (s, ms) in m.iter_mut().enumerate() {
        let off = s * SUB_IMAGE_BYTES + stored * ROW_BYTES;
        unpack_row(&c.raw[off..off + ROW_BYTES], &c.t.lut, ms);
    }
    let z = &c.t.z[y];
    let p = c.p;
    let (zero, abm, sat) = (sp(0.0), sp(p.ab_multiplier), sp(SAT));
    for k in 0..3 {
        let (m0, m1, m2) = (&m[3 * k], &m[3 * k + 1], &m[3 * k + 2]);
        let mk = sp(p.ab_multiplier_per_frq[k]);
        let Row1 { a: oa, b: ob, amp: oamp, ua, ub, n2 } = out;
        let (oa, ob, oamp, ua, ub, n2) =
            (&mut oa[k], &mut ob[k], &mut oamp[k], &mut ua[k], &mut ub[k], &mut n2[k]);
        for x in (0..W / 4).map(|g| 4 * g) {
            let (v0, v1, v2) = (ld(m0, x), ld(m1, x), ld(m2, x));
            let [c0, c1, c2, s0, s1, s2] = c.t.trig.lanes(y, k, x);
            let a = (c0 * v0 + c1 * v1 + c2 * v2) * mk;
            let b = (s0 * v0 + s1 * v1 + s2 * v2) * mk;
            let amp = (a * a + b * b).sqrt() * abm;
            let is_sat = v0.simd_eq(sat) | v1.simd_eq(sat) | v2.simd_eq(sat);
            // ztable ≤ 0: invalid pixel (0, 0, 0); else saturated: (0, 0, 65535).
            let invalid = ld(z, x).simd_le(zero);
            let zero_ab = invalid | is_sat;
            let (a, b) = (zero_ab.select(zero, a), zero_ab.select(zero, b));
            st(oa, x + PAD, a);
            st(ob, x + PAD, b);
            st(oamp, x, invalid.select(zero, is_sat.select(sp(65535.0), amp)));
            if unit {
                let n = a * a + b * b;
                let g = sp(1.0) / n.sqrt();
                let g = g.is_nan().select(sp(f32::INFINITY), g);
                st(ua, x + PAD, a * g);
                st(ub, x + PAD, b * g);
                st(n2, x + PAD, n);
            }
        }
    }
}

/// IR output (spec §9.6 step 5) of one row from the stage-1 amplitudes.
#[inline(always)]
fn ir_row(r: &Row1, p: &DecoderParams, out: &mut [f32]) {
    let (third, mult, max) = (sp(0.3333333), sp(p.ab_output_multiplier), sp(65535.0));
    for x in (0..W / 4).map(|g| 4 * g) {
        let v = (ld(&r.amp[0], x) + ld(&r.amp[1], x) + ld(&r.amp[2], x)) * third * mult;
        st(out, x, v.simd_gt(max).select(max, v));
    }
}

/// Bilateral amplitude threshold τ on a² + b² (spec §9.5).
#[inline]
fn bilateral_tau(p: &DecoderParams) -> f32 {
    (p.joint_bilateral_ab_threshold * p.joint_bilateral_ab_threshold)
        / (p.ab_multiplier * p.ab_multiplier)
}

/// Range distance of two unit phasors (spec §9.5): `((−(ua1·ua + ub1·ub)) + 1)·0.5`, written as
/// `(1 − (…))·0.5`, the same IEEE result; symmetric bit for bit since each product commutes.
#[inline(always)]
fn range_dist(ua1: V, ub1: V, ua: V, ub: V) -> V {
    (sp(1.0) - (ua1 * ua + ub1 * ub)) * sp(0.5)
}

/// Forward range weights (see [`RowE`]) of row `r` with its lower neighbour row `n`, both the
/// weight and the distance set to 0 unless both ends pass the amplitude threshold (the only
/// case in which the bilateral filter reads them).
#[inline(always)]
fn edge_weights<const L8: bool>(c: &Ctx, r: &Row1, n: &Row1, out: &mut RowE) {
    for k in 0..3 {
        let this = (&r.ua[k], &r.ub[k], &r.n2[k]);
        let below = (&n.ua[k], &n.ub[k], &n.n2[k]);
        let [er, edl, ed, edr] = &mut out.e[k];
        let [dr, ddl, dd, ddr] = &mut out.d[k];
        // Other end: (row, column offset) = (this, +1), (below, −1), (below, 0), (below, +1).
        #[cfg(target_arch = "x86_64")]
        if L8 {
            let (ce, tau0) = (-1.442695f32 * c.p.joint_bilateral_exp, bilateral_tau(c.p));
            lanes8::pair_row::<1>(ce, tau0, this, this, er, dr);
            lanes8::pair_row::<-1>(ce, tau0, this, below, edl, ddl);
            lanes8::pair_row::<0>(ce, tau0, this, below, ed, dd);
            lanes8::pair_row::<1>(ce, tau0, this, below, edr, ddr);
            continue;
        }
        if c.fast {
            pair_row::<true, 1>(c.p, this, this, er, dr);
            pair_row::<true, -1>(c.p, this, below, edl, ddl);
            pair_row::<true, 0>(c.p, this, below, ed, dd);
            pair_row::<true, 1>(c.p, this, below, edr, ddr);
        } else {
            pair_row::<false, 1>(c.p, this, this, er, dr);
            pair_row::<false, -1>(c.p, this, below, edl, ddl);
            pair_row::<false, 0>(c.p, this, below, ed, dd);
            pair_row::<false, 1>(c.p, this, below, edr, ddr);
            for e in [er, edl, ed, edr] {
                for v in e[PAD..PAD + W].iter_mut() {
                    *v = if *v == f32::NEG_INFINITY { 0.0 } else { v.exp() };
                }
            }
        }
    }
}

/// Planes (ua, ub, n²) of one frequency of a [`Row1`].
type UnitPlanes<'a> = (&'a PPlane, &'a PPlane, &'a PPlane);

/// One direction of [`edge_weights`]: pairs (x of `this`, x + `OFF` of `other`). `FAST`: the
/// weights with [`fastmath::exp_unclamped`]; else the exponent, −∞ where masked, for libm.
#[inline(always)]
fn pair_row<const FAST: bool, const OFF: isize>(
    p: &DecoderParams,
    this: UnitPlanes,
    other: UnitPlanes,
    e: &mut PPlane,
    d: &mut PPlane,
) {
    let ce = sp(-1.442695f32 * p.joint_bilateral_exp);
    let tau0 = sp(bilateral_tau(p));
    let ((ua, ub, n2), (oa, ob, on2)) = (this, other);
    for x in (0..W / 4).map(|g| 4 * g) {
        let i = x + PAD;
        let j = (i as isize + OFF) as usize;
        let dist = range_dist(ld(oa, j), ld(ob, j), ld(ua, i), ld(ub, i));
        let both = ld(n2, i).simd_ge(tau0) & ld(on2, j).simd_ge(tau0);
        st(d, i, dist & both);
        if FAST {
            st(e, i, fastmath::exp_unclamped(ce * dist) & both);
        } else {
            // expf(−∞) = 0 exactly.
            st(e, i, both.select(ce * dist, sp(f32::NEG_INFINITY)));
        }
    }
}

/// Border rows, and all pixels without the bilateral filter: unfiltered phasors, `edge_ok` true.
#[inline(always)]
fn copy_unfiltered(r: &Row1, fa: &mut [Plane; 3], fb: &mut [Plane; 3], ok: &mut Plane) {
    for k in 0..3 {
        fa[k].copy_from_slice(&r.a[k][PAD..PAD + W]);
        fb[k].copy_from_slice(&r.b[k][PAD..PAD + W]);
    }
    *ok = [1.0; W];
}

/// Joint bilateral filter (spec §9.5) of frequency `k` over one processing row (1 ≤ y ≤ 422):
/// writes the filtered phasor to `fa`, `fb` and ANDs this frequency's edge test into `ok`
/// (k = 0 starts it). Border columns are copied with `edge_ok` true.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn bilateral_k(
    p: &DecoderParams,
    k: usize,
    up: &Row1,
    mid: &Row1,
    dn: &Row1,
    e_up: &RowE,
    e_mid: &RowE,
    fa: &mut Plane,
    fb: &mut Plane,
    ok: &mut Plane,
) {
    let gk = &p.gaussian_kernel;
    let (zero, one) = (sp(0.0), sp(1.0));
    let tau0 = sp(bilateral_tau(p));
    let max_edge = sp(p.joint_bilateral_max_edge);
    let (n2, a, b) = (&mid.n2[k], &mid.a[k], &mid.b[k]);
    let [_, eu_dl, eu_d, eu_dr] = &e_up.e[k];
    let [em_r, em_dl, em_d, em_dr] = &e_mid.e[k];
    let [_, du_dl, du_d, du_dr] = &e_up.d[k];
    let [dm_r, dm_dl, dm_d, dm_dr] = &e_mid.d[k];
    let (ua, ub) = (&mid.ua[k], &mid.ub[k]);
    for x in (0..W / 4).map(|g| 4 * g) {
        let i = x + PAD;
        let cn2 = ld(n2, i);
        // Centre ≥ τ ("shared"): a neighbour passes iff it is ≥ τ too, exactly where the stored
        // weight and distance are non-zero, so the masked values serve directly (a failing
        // neighbour adds w·0 = +0 to the sums, which changes no value). Centre below τ: τ = e
        // = 0, every neighbour with n² ≥ 0 passes, and exp(−0·dist) is 1 for a finite dist and
        // NaN otherwise, i.e. (dist − dist) + 1; the distance is recomputed (bit-identical by
        // symmetry) because the stored one is masked.
        let shared = cn2.simd_ge(tau0);
        let (mut w_acc, mut sa, mut sb, mut d_acc) = (zero, zero, zero, zero);
        if shared.all() {
            macro_rules! nb {
                ($w:expr, $row:expr, $j:expr, $e:expr, $d:expr) => {{
                    let (r, j): (&Row1, usize) = ($row, $j);
                    let (a1, b1) = (ld(&r.a[k], j), ld(&r.b[k], j));
                    let weight = sp($w) * $e;
                    d_acc += $d;
                    sa += weight * a1;
                    sb += weight * b1;
                    w_acc += weight;
                }};
            }
            nb!(gk[0], up, i - 1, ld(eu_dr, i - 1), ld(du_dr, i - 1));
            nb!(gk[1], up, i, ld(eu_d, i), ld(du_d, i));
            nb!(gk[2], up, i + 1, ld(eu_dl, i + 1), ld(du_dl, i + 1));
            nb!(gk[3], mid, i - 1, ld(em_r, i - 1), ld(dm_r, i - 1));
            let w = sp(gk[4]);
            w_acc += w;
            sa += w * ld(a, i);
            sb += w * ld(b, i);
            nb!(gk[5], mid, i + 1, ld(em_r, i), ld(dm_r, i));
            nb!(gk[6], dn, i - 1, ld(em_dl, i), ld(dm_dl, i));
            nb!(gk[7], dn, i, ld(em_d, i), ld(dm_d, i));
            nb!(gk[8], dn, i + 1, ld(em_dr, i), ld(dm_dr, i));
        } else {
            let tau = cn2.simd_lt(tau0).select(zero, tau0);
            let (cua, cub) = (ld(ua, i), ld(ub, i));
            macro_rules! nb {
                ($w:expr, $row:expr, $j:expr, $e:expr) => {{
                    let (r, j): (&Row1, usize) = ($row, $j);
                    let (a1, b1, n12) = (ld(&r.a[k], j), ld(&r.b[k], j), ld(&r.n2[k], j));
                    let dist = range_dist(ld(&r.ua[k], j), ld(&r.ub[k], j), cua, cub);
                    let pass = n12.simd_ge(tau);
                    let ex = shared.select($e, (dist - dist) + one);
                    // `pass ? x : 0` as a bit mask; adding +0 instead of skipping the addition
                    // changes nothing (d_acc only feeds a comparison).
                    let weight = (sp($w) * ex) & pass;
                    d_acc += (dist & pass);
                    sa += weight * a1;
                    sb += weight * b1;
                    w_acc += weight;
                }};
            }
            nb!(gk[0], up, i - 1, ld(eu_dr, i - 1));
            nb!(gk[1], up, i, ld(eu_d, i));
            nb!(gk[2], up, i + 1, ld(eu_dl, i + 1));
            nb!(gk[3], mid, i - 1, ld(em_r, i - 1));
            let w = sp(gk[4]);
            w_acc += w;
            sa += w * ld(a, i);
            sb += w * ld(b, i);
            nb!(gk[5], mid, i + 1, ld(em_r, i));
            nb!(gk[6], dn, i - 1, ld(em_dl, i));
            nb!(gk[7], dn, i, ld(em_d, i));
            nb!(gk[8], dn, i + 1, ld(em_dr, i));
        }
        let edge = d_acc.simd_lt(max_edge);
        let prev_ok = if k == 0 { one } else { ld(ok, x) };
        st(ok, x, edge & prev_ok);
        let pos = w_acc.simd_gt(zero);
        st(fa, x, (sa / w_acc) & pos);
        st(fb, x, (sb / w_acc) & pos);
    }
    for x in [0, W - 1] {
        fa[x] = a[x + PAD];
        fb[x] = b[x + PAD];
        ok[x] = 1.0;
    }
}

/// `floorf` of four lanes without a rounding instruction (SSE2 has none): exact for every
/// input — values with |x| ≥ 2²³, infinities and NaN are returned unchanged like `floorf`, and
/// the sign is restored so that −0.0 stays −0.0.
#[inline(always)]
fn floor4(x: V) -> V {
    let small = x.abs().simd_lt(sp(8_388_608.0));
    let t = V::from_i32x4(x.fast_trunc_int());
    let f = t - (t.simd_gt(x) & sp(1.0));
    small.select(f.copysign(x), x)
}

/// `if b < a { b } else { a }` per lane (the reference's NaN behaviour). On x86 that is
/// exactly `minps(b, a)`.
#[inline(always)]
fn fmin(a: V, b: V) -> V {
    #[cfg(target_arch = "x86_64")]
    return b.fast_min(a);
    #[cfg(not(target_arch = "x86_64"))]
    return b.simd_lt(a).select(b, a);
}
/// `if a < b { b } else { a }` per lane; on x86 exactly `maxps(b, a)`.
#[inline(always)]
fn fmax(a: V, b: V) -> V {
    #[cfg(target_arch = "x86_64")]
    return b.fast_max(a);
    #[cfg(not(target_arch = "x86_64"))]
    return a.simd_lt(b).select(b, a);
}

/// The argument of the de-aliasing confidence's `exp` (spec §9.6 step 3) from `ln A*`.
#[inline(always)]
fn conf_arg(p: &DecoderParams, ln_astar: f32) -> f32 {
    (ln_astar * p.ab_confidence_slope * 0.301030f32 + p.ab_confidence_offset) * 3.321928f32
}

/// Stage 2 (spec §9.6) of processing row `y` from the filtered phasors in `ws.fa/fb` and
/// `ws.ok`: writes the depth, its `lo`/`hi` forms for the edge-aware filter (see
/// [`DepthDecoder`]'s fields) and the amplitude sum, in three passes over the row: amplitudes,
/// phases and confidence (libm only past the gate for Exact), unwrapping and depth.
#[inline(always)]
fn stage2_row(
    c: &Ctx,
    y: usize,
    ws: &mut Workspace,
    dp: &mut [f32],
    lo: &mut [f32],
    hi: &mut [f32],
    is: &mut [f32],
) {
    let p = c.p;
    let zero = sp(0.0);
    let (xt, zt) = (&c.t.x[y], &c.t.z[y]);
    // Amplitudes (step 1–2): (sum, A* of the confidence, gate mask).
    let amplitudes = |fa: &[Plane; 3], fb: &[Plane; 3], x: usize| -> (V, V, V) {
        let mut al = [zero; 3];
        for (k, alk) in al.iter_mut().enumerate() {
            let (a, b) = (ld(&fa[k], x), ld(&fb[k], x));
            *alk = (a * a + b * b).sqrt() * sp(p.ab_multiplier);
        }
        let s = al[0] + al[1] + al[2];
        let amin = fmin(fmin(al[0], al[1]), al[2]);
        let amax = fmax(fmax(al[0], al[1]), al[2]);
        let astar = if p.ab_confidence_slope > 0.0 { amin } else { amax };
        let gate = !(amin.simd_lt(sp(p.individual_ab_threshold)) | s.simd_lt(sp(p.ab_threshold)));
        (s, astar, gate)
    };
    for x in (0..W / 4).map(|g| 4 * g) {
        let (s, astar, gate) = amplitudes(&ws.fa, &ws.fb, x);
        st(is, x, s);
        st(&mut ws.astar, x, astar);
        st(&mut ws.gate, x, gate & sp(1.0));
    }
    if c.fast {
        // Four lanes everywhere (values outside the gate are discarded in `unwrap_depth`).
        for x in (0..W / 4).map(|g| 4 * g) {
            for k in 0..3 {
                let ph = fastmath::atan2(ld(&ws.fb[k], x), ld(&ws.fa[k], x));
                st(&mut ws.phi[k], x, ph);
            }
            let l = fastmath::ln(ld(&ws.astar, x));
            let arg = (l * sp(p.ab_confidence_slope) * sp(0.301030) + sp(p.ab_confidence_offset))
                * sp(3.321928);
            st(&mut ws.conf, x, fastmath::exp(arg));
        }
    } else {
        // libm only past the gate, as the reference.
        for x in 0..W {
            if ws.gate[x] != 0.0 {
                for k in 0..3 {
                    ws.phi[k][x] = ws.fb[k][x].atan2(ws.fa[k][x]);
                }
                ws.conf[x] = conf_arg(p, ws.astar[x].ln()).exp();
            }
        }
    }
    for x in (0..W / 4).map(|g| 4 * g) {
        let phi = [0, 1, 2].map(|k| ld(&ws.phi[k], x));
        let (gate, ok) = (ld(&ws.gate, x).simd_gt(zero), ld(&ws.ok, x).simd_gt(zero));
        let (d, l, h) = unwrap_depth(c, phi, ld(&ws.conf, x), gate, ok, ld(xt, x), ld(zt, x));
        st(dp, x, d);
        st(lo, x, l);
        st(hi, x, h);
    }
}

/// Stage 2 from the phases `phi` (atan2 as returned), the de-aliasing confidence before
/// clamping, the amplitude gate and `edge_ok` masks and the x/z table values: the unwrapping
/// (step 3) and depth (step 4) of four pixels, returned as (depth, lo, hi) (see
/// [`DepthDecoder`]'s fields).
#[inline(always)]
fn unwrap_depth(c: &Ctx, phi: [V; 3], conf: V, gate: V, ok: V, xt: V, zt: V) -> (V, V, V) {
    let p = c.p;
    let two_pi = 2.0 * std::f64::consts::PI;
    let (zero, one) = (sp(0.0), sp(1.0));
    let f64s = f64x2::splat;
    let mut ph = [zero; 3];
    for (k, phk) in ph.iter_mut().enumerate() {
        let f = phi[k];
        let f = f.simd_lt(zero).select(map64(f, |d| d + f64s(two_pi)), f);
        *phk = f & f.simd_eq(f);
    }
    // Fast: one f64 product instead of a division and a product (the f64 results differ in
    // the last bits, which the rounding to f32 almost always hides).
    let (t0, t1, t2) = if c.fast {
        (
            map64(ph[0], |d| d * f64s(3.0 / two_pi)),
            map64(ph[1], |d| d * f64s(15.0 / two_pi)),
            map64(ph[2], |d| d * f64s(2.0 / two_pi)),
        )
    } else {
        (
            map64(ph[0], |d| d / f64s(two_pi) * f64s(3.0)),
            map64(ph[1], |d| d / f64s(two_pi) * f64s(15.0)),
            map64(ph[2], |d| d / f64s(two_pi) * f64s(2.0)),
        )
    };
    // `−a + b` of the spec is written `b − a` (the same IEEE result).
    let t5 = floor4((t1 - t0) * sp(0.333333) + sp(0.5)) * sp(3.0) + t0;
    let t3 = t5 - t2;
    let t4 = t3 * sp(2.0);
    let pos = t4.simd_ge(zero - t4);
    let t3 = t3 * pos.select(sp(0.5), sp(-0.5));
    let t3 = (t3 - floor4(t3)) * pos.select(sp(2.0), sp(-2.0));
    let at3 = t3.abs();
    let wrap = sp(0.5).simd_lt(at3) & at3.simd_lt(sp(1.5));
    let t6 = wrap.select(t5 + sp(15.0), t5);
    let t7 = wrap.select(t1 + sp(15.0), t1);
    let t8 = (floor4((t6 - t2) * sp(0.5) + sp(0.5)) * sp(2.0) + t2) * sp(0.5);
    let t6 = t6 * sp(0.333333);
    let t7 = t7 * sp(0.066667);
    let t9 = t8 + t6 + t7;
    let t10 = t9 * sp(0.333333);
    let t6 = map64(t6, |d| d * f64s(two_pi));
    let t7 = map64(t7, |d| d * f64s(two_pi));
    let t8 = map64(t8, |d| d * f64s(two_pi));
    let e8 = t7 * sp(0.826977) - t8 * sp(0.110264);
    let e6 = t8 * sp(0.551318) - t6 * sp(0.826977);
    let e7 = t6 * sp(0.110264) - t7 * sp(0.551318);
    let nu = e8 * e8 + e6 * e6 + e7 * e7;
    // Multiplied, not selected: a negative t10 becomes −0.0 (spec §9.9).
    let t10 = t10 * (t9.simd_ge(zero) & one);
    let cf = conf;
    let (cmin, cmax) = (sp(p.min_dealias_confidence), sp(p.max_dealias_confidence));
    let cf = cf.simd_lt(cmin).select(cmin, cf);
    let cf = cf.simd_gt(cmax).select(cmax, cf);
    let cf = cf * cf;
    let phase = t10 * (cf.simd_ge(nu) & one);
    let phase = phase & gate;
    // Depth (step 4).
    let ph = phase.simd_gt(zero).select(phase + sp(p.phase_offset), phase);
    let zl = zt * ph;
    let dmax = ph * sp(p.unambiguous_dist) * sp(2.0);
    let xm = if c.fast {
        // Fast: in f32 (≤ 1.5 ulp from the f64 quotient; xm is a correction of a few %).
        (xt * sp(90.0)) / (dmax * dmax * sp(8192.0))
    } else {
        let [x0, x1] = wide64(xt * sp(90.0));
        let [d0, d1] = wide64(dmax * dmax);
        narrow([x0 / (d0 * f64s(8192.0)), x1 / (d1 * f64s(8192.0))])
    };
    // `−zl·xm + 1` of the spec is written `1 − zl·xm` (the same IEEE result).
    let zf = zl / (one - zl * xm);
    let zf = zf.simd_lt(zero).select(zero, zf);
    let d = (zl.simd_gt(zero) & dmax.simd_gt(zero)).select(zf, zl);
    let valid = ok & d.simd_gt(zero);
    (d, valid.select(d, sp(f32::INFINITY)), valid.select(d, sp(f32::NEG_INFINITY)))
}

/// Rows y − 1, y, y + 1 of a plane of stride [`SW`].
fn rows3(v: &[f32], y: usize) -> [&[f32]; 3] {
    [y - 1, y, y + 1].map(|r| &v[r * SW..(r + 1) * SW])
}

/// Pass 2 of processing row `y` (written to output row `423 − y`): edge-aware filter (spec
/// §9.7) or a plain copy. `planes` = (depth, lo, hi, ir_sum), see [`DepthDecoder`]'s fields.
fn output_row(
    planes: (&[f32], &[f32], &[f32], &[f32]),
    y: usize,
    drow: &mut [f32],
    p: &DecoderParams,
    edge_on: bool,
) {
    let (dp, dlo, dhi, is) = planes;
    let d = &dp[y * W..(y + 1) * W];
    if !edge_on {
        drow.copy_from_slice(d);
        return;
    }
    let in_range = |v: f32| v >= p.min_depth && v <= p.max_depth;
    if y == 0 || y == H - 1 {
        for (o, &v) in drow.iter_mut().zip(d) {
            *o = if in_range(v) { v } else { 0.0 };
        }
        return;
    }
    // Rows y − 1, y, y + 1 of a stride-SW plane; column x at `x + PAD` of each.
    let (s, l, h) = (rows3(is, y), rows3(dlo, y), rows3(dhi, y));
    let zero = sp(0.0);
    let (dmin, dmax) = (sp(p.min_depth), sp(p.max_depth));
    for x in (0..W / 4).map(|g| 4 * g) {
        let i = x + PAD;
        let dc = ld(d, x);
        let sc = ld(s[1], i);
        let mut sum = sc;
        let mut sq = sc * sc;
        let (mut lo, mut hi) = (dc, dc);
        // Neighbours in raster order. lo/hi hold ±∞ where d̃ ≤ 0, which `fmin`/`fmax` ignore
        // exactly like the reference's `if d̃ > 0` test.
        for (r, j) in
            [(0, i - 1), (0, i), (0, i + 1), (1, i - 1), (1, i + 1), (2, i - 1), (2, i), (2, i + 1)]
        {
            let sv = ld(s[r], j);
            sum += sv;
            sq += sv * sv;
            lo = fmin(lo, ld(l[r], j));
            hi = fmax(hi, ld(h[r], j));
        }
        let nine = sp(9.0);
        let sigma =
            (sq * nine - sum * sum).sqrt() / nine / fmax(sum / nine, sp(p.edge_ab_avg_min_value));
        let dlo = (dc - lo).abs();
        let dhi = (dc - hi).abs();
        let avg = (dlo + dhi) * sp(0.5);
        let mx = fmax(dlo, dhi);
        let reject = dc.simd_gt(zero)
            & sigma.simd_ge(sp(p.edge_ab_std_dev_threshold))
            & dlo.simd_gt(sp(p.edge_close_delta_threshold))
            & dhi.simd_gt(sp(p.edge_far_delta_threshold))
            & mx.simd_gt(sp(p.edge_max_delta_threshold))
            & avg.simd_gt(sp(p.edge_avg_delta_threshold));
        // In range (so d > 0): keep d unless rejected or not edge_ok (hi = −∞ there).
        let keep = (dc.simd_ge(dmin) & dc.simd_le(dmax)) & ld(h[1], i).simd_gt(zero) & !reject;
        st(drow, x, dc & keep);
    }
    for x in [0, W - 1] {
        drow[x] = if in_range(d[x]) { d[x] } else { 0.0 };
    }
}

#[cfg(test)]
mod tests {
    use super::{DecoderParams, H, Trig, V, W, floor4};
    use crate::params::P0Tables;
    use rand::{Rng, SeedableRng};

    /// The value-indexed table and the per-pixel planes must give the same coefficient lanes,
    /// bit for bit (zero tolerance: both are the same f32 values, stored differently), for
    /// random P0 tables whose values span 3 000 (like the vectors'), at every pixel.
    #[test]
    fn trig_table_equals_trig_planes() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let p0 = P0Tables {
            tables: [11_000u16, 2_000, 17_000]
                .map(|lo| (0..W * H).map(|_| rng.random_range(lo..lo + 3_000)).collect()),
        };
        let params = DecoderParams::default();
        let (table, planes) = (Trig::new(&params, &p0, 16_384), Trig::new(&params, &p0, 0));
        assert!(matches!(table, Trig::Table { .. }) && matches!(planes, Trig::Planes(_)));
        for y in 0..H {
            for k in 0..3 {
                for x in (0..W).step_by(4) {
                    let (t, p) = (table.lanes(y, k, x), planes.lanes(y, k, x));
                    for j in 0..6 {
                        let (t, p) = (t[j].to_array(), p[j].to_array());
                        assert!(
                            t.iter().zip(&p).all(|(a, b)| a.to_bits() == b.to_bits()),
                            "y {y} k {k} x {x} j {j}: {t:?} vs {p:?}"
                        );
                    }
                }
            }
        }
    }

    /// The branch-free floor must equal `f32::floor` bit for bit (zero tolerance: the Exact
    /// decoder is bit-exact). Checked on every 257th bit pattern (≈ 16.7 M values, both signs,
    /// all exponents, NaN and infinities) plus the signed zeros and values next to integers,
    /// four different values at a time.
    #[test]
    fn floor_matches_libm_bit_for_bit() {
        let check = |x: [f32; 4]| {
            let got = floor4(V::new(x)).to_array();
            for (g, x) in got.into_iter().zip(x) {
                let want = x.floor();
                assert!(
                    g.to_bits() == want.to_bits() || (g.is_nan() && want.is_nan()),
                    "floor({x:e}) = {g:e}, libm {want:e}"
                );
            }
        };
        let mut quad = [0f32; 4];
        for (n, bits) in (0..=u32::MAX).step_by(257).enumerate() {
            quad[n % 4] = f32::from_bits(bits);
            if n % 4 == 3 {
                check(quad);
            }
        }
        for x in [
            0.0f32,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            8_388_607.5,
            -8_388_607.5,
            8_388_608.0,
            -8_388_609.0,
        ] {
            check([
                x,
                f32::from_bits(x.to_bits() + 1),
                f32::from_bits(x.to_bits().saturating_sub(1)),
                -x,
            ]);
        }
    }
}
