//! CPU depth decoder (protocol §9): raw 11-bit frame → depth (mm, f32) + IR amplitude (f32), both
//! 512 × 424 upright (row 0 = top).
//!
//! # Precision
//!
//! [`DecoderPrecision::Exact`] follows the reference order exactly (f32, with the f64
//! promotions of protocol §9, no fused multiply-add, libm `cosf/sinf/atan2f/expf/logf`) and
//! reproduces the oracle vectors bit for bit on Linux x86-64 (`tests/oracle.rs`).
//!
//! [`DecoderPrecision::Fast`] — **the default, also of `kfuse capture`** — is the same
//! algorithm in the same operation order, but computes `exp`, `ln` and `atan2` with this
//! crate's branch-free four-lane f32 functions ([`fastmath`], within 2.5 ulp of f64) and, in
//! stage 2, multiplies by f64 constants where the reference divides, so that every stage runs
//! in SIMD lanes. Against every oracle file it stays inside protocol §9.9's test policy (at
//! most 0.01 mm depth difference, no pixel changing validity, IR bit-identical; asserted per
//! file in `tests/oracle.rs`), far below the sensor's noise; it is the default because it lets
//! `kfuse capture` decode at the sensor's 30 Hz with time left for JPEG decoding and writing
//! (timings in BENCHMARKS.md). Use `Exact` (`kfuse capture --exact-decoder`) to reproduce
//! libfreenect2's CPU decoder bit for bit.
//!
//! # Stages
//!
//! | Stage | File | Protocol | In → out |
//! |---|---|---|---|
//! | Unpack + stage 1 | `stage1.rs` | §8, §9.3, §9.4 | 9 × 704 stored bytes → `(a, b)`, amplitude, unit phasor per frequency |
//! | Bilateral filter | `bilateral.rs` | §9.5 | stage-1 rows y − 1..y + 1 → filtered `(a, b)`, `edge_ok` |
//! | Stage 2 | `stage2.rs` | §9.6 steps 1–3 | filtered phasors → amplitude sum, gate, phases, confidence |
//! | Unwrap + depth | `unwrap.rs` | §9.6 steps 3–4 | phases, confidence, x/z tables → depth (mm) |
//! | IR | `stage1.rs` (`ir_row`) | §9.6 step 5 | stage-1 amplitudes → IR row |
//! | Edge-aware filter + flip | `edge.rs` | §9.7, §9.8 | depth and amplitude sums of rows y − 1..y + 1 → upright depth row |
//! | Lanes | `lanes.rs`, `lanes8.rs`, `fastmath.rs` | §9.9 | four-lane helpers, AVX2 kernels, `Fast`'s `exp`/`ln`/`atan2` |
//!
//! This file holds the public types, the working buffers and the driver (`band_with`) that
//! runs the stages row by row.
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

// The literal constants of protocol §9 (1.442695, 0.301030, 3.321928, …) must stay as written for
// bit-exactness; they are not the library constants they approximate.
#![allow(clippy::approx_constant)]

mod bilateral;
mod edge;
pub mod fastmath;
mod lanes;
#[cfg(target_arch = "x86_64")]
mod lanes8;
mod stage1;
mod stage2;
mod unwrap;

use rayon::prelude::*;

use crate::error::{KinectError, Result};
use crate::orientation::{Orientation, mirror_rows};
use crate::params::{P0Tables, XzTables};
use crate::raw::{HEIGHT, PIXELS, RAW_FRAME_BYTES, SATURATED, WIDTH, lut};
use bilateral::{bilateral_k, copy_unfiltered, edge_weights};
use edge::output_row;
pub use stage1::phase_step_coefficients;
use stage1::{TRIG_TABLE_MAX_SPAN, Trig, ir_row, stage1_row};
use stage2::stage2_row;

/// Decoder constants of protocol §9.1 (libfreenect2 defaults). Literal constants inside the
/// formulas are kept inline, as protocol §9.1 requires for bit-exactness.
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
    /// Joint bilateral filter of the phasors (protocol §9.5).
    pub bilateral: bool,
    /// Edge-aware filter of the depth (protocol §9.7; also clamps to [min_depth, max_depth]).
    pub edge_aware: bool,
    /// Process rows in parallel on the current rayon pool.
    pub parallel: bool,
    /// Which way left and right run in the depth and IR written: [`Orientation::Scene`]
    /// (kfuse's rule, the default) or [`Orientation::Sensor`] (the protocol's and its test
    /// vectors', mirrored). The two differ only in where a value is written.
    pub orientation: Orientation,
}

impl Default for DecoderConfig {
    fn default() -> Self {
        DecoderConfig {
            bilateral: true,
            edge_aware: true,
            parallel: true,
            orientation: Orientation::Scene,
        }
    }
}

/// How the decoder evaluates its transcendental functions (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DecoderPrecision {
    /// glibc `expf/logf/atan2f` per pixel, as the reference: bit-identical to the oracle.
    Exact,
    /// Four-lane f32 approximations (≤ 2.5 ulp): within protocol §9.9's tolerance, about twice as
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

/// Stage-1 results of one processing row (protocol §9.4) plus the bilateral filter's per-pixel
/// terms (protocol §9.5 step 1): per frequency k, `a`, `b`, amplitude `A`, the unit phasor
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

/// Per-frame-constant tables, by processing row.
struct Tables {
    /// The companding LUT (protocol §8) as f32.
    lut: [f32; 2048],
    /// Protocol §9.3's coefficients.
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
    /// Protocol §9.7's `d̃` (depth, 0 where the bilateral `edge_ok` is false) where it is > 0, else
    /// +∞: what the neighbour minimum of the edge-aware filter reads. Rows of stride [`SW`].
    depth_lo: Vec<f32>,
    /// The same with −∞ for the neighbour maximum. Rows of stride [`SW`].
    depth_hi: Vec<f32>,
    /// Stage-2 amplitude sum (protocol §9.6 step 2). Rows of stride [`SW`].
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

    /// Decodes one raw frame into upright `depth` (mm) and `ir` images of 512 × 424, in
    /// [`DecoderConfig::orientation`].
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
        let mirror = self.config.orientation == Orientation::Scene;
        let f = |(r, drow): (usize, &mut [f32])| {
            output_row(planes, H - 1 - r, drow, &self.params, self.config.edge_aware);
            if mirror {
                drow.reverse();
            }
        };
        if self.config.parallel {
            depth.par_chunks_mut(W).enumerate().for_each(f);
        } else {
            depth.chunks_mut(W).enumerate().for_each(f);
        }
        if mirror {
            mirror_rows(ir, W);
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
