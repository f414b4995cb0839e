//! Stage 5, junction fit: the maximum-likelihood fit of a blurred X-junction model, the
//! default final sub-pixel estimator of the labelled corners.
//!
//! Longer than 600 lines for a measured reason: the per-evaluation kernel (`V`, `kernel`,
//! `eval_lanes`) was moved to its own module once, and LLVM then generated slower code for it
//! (fit stage of the rendered 1080p image, minimum of 150 runs: 3.1 → 4.1 ms on the baseline
//! target, 1.8 → 2.2 ms in the AVX2 clone), so it stays next to the fit that calls it.
//! Tried again on 2026-12-02, after the vectoriser fix in `kernel`, into `junction/kernel.rs`:
//! the corners were the same to the bit and the AVX2 clone as fast, but the baseline copy
//! (timed by calling it directly) was again slower, IR bench image 1.01–1.13 → 1.29–1.41 ms,
//! rendered 1080p 3.0 → 3.9–4.0 ms (fit stage, one thread, minimum of 200 runs).

use geometry::Image;
use multiversion::multiversion;
use multiversion::target::target_cfg_f;
use nalgebra::Vector2;

/// Pixels at or above this value are treated as saturated (censored) by [`fit_junction`]: the
/// IR camera's glare clips white paper at 255, and a clipped pixel only says "at least 255".
const SATURATED: f64 = 254.5;
/// Iterations and convergence threshold (px) of [`fit_junction`]'s Levenberg–Marquardt: a
/// step that moves the corner by less than this ends the fit (after an accepted step, without
/// evaluating the model there). 1e-4 px is a hundredth of the rendered set's corner error.
/// On 2026-12-02 every corpus, rendered-set and kinect-lab figure was the same to the printed
/// digits with 1e-5 and 1e-4 px, and the IR bench image's fit stage took 0.49 instead of
/// 0.54 ms (one thread, minimum of 300 runs); 1e-3 px moved robot-arm's and Udacity's RMS in
/// the fourth decimal for 3 % more. (An earlier detector lost a partial GoPro view with
/// 1e-4 px, its RMS 0.516 → 0.519 px; the current one keeps all 35 views and 0.5229 px.)
const FIT_MAX_ITERATIONS: usize = 40;
const FIT_EPS: f64 = 1e-4;
/// Wider junction-fit windows first converge on the pixels within this radius (px), then
/// take at most [`FIT_FINAL_ITERATIONS`] steps on the whole window, a fraction of the cost on
/// 1080p boards. On sharp real images (σ ≈ 0.35 px) the last steps converge slowly, so this is
/// close to, not at, the whole window's minimum: 10 final steps instead of 3 move the corpus
/// RMS by ≤ 0.002 px (robot-arm 0.2120 → 0.2103, GoPro 0.5230 → 0.5227, 2026-12-02); 1 or 2
/// steps (with one more unchecked step) raised robot-arm to 0.216–0.222 and GoPro above
/// OpenCV's 0.5233, so 3 stays.
const FIT_COARSE_RADIUS: f64 = 8.0;
const FIT_FINAL_ITERATIONS: usize = 3;
/// Convergence threshold (px) of the coarse stage: the final steps on the whole window move
/// the corner by 1e-3 to 5e-2 px anyway (traced on GoPro views of the corpus), so converging
/// the coarse fit to [`FIT_EPS`] (up to twice the iterations) was wasted. The rendered set's
/// corner errors and calibration figures are unchanged to the printed digits.
const FIT_COARSE_EPS: f64 = 1e-3;
/// Smallest σ (px) of an accepted fit: a sharper edge than that is below what the model
/// (blur without the pixel's own 1 px box, σ ≈ 0.29) can tell, and the corner is refined by
/// `cornerSubPix` instead.
const FIT_MIN_SIGMA: f64 = 0.1;
/// Fewest unsaturated pixels for a junction fit (9 parameters; 30 gives a well-posed fit).
const FIT_MIN_PIXELS: usize = 30;
/// The coarse stage runs only when its circle holds less than this share of the window's
/// pixels. IR windows (radius ≈ 9 px) hold ~250 pixels, ~200 of them within 8 px: the coarse
/// stage saved little per evaluation there and cost a whole-window evaluation more at its end
/// (rendered IR bench image, 2026-12-02; figures unchanged to the printed digits).
///
/// Measured and not taken (2026-12-02): a start of mean, contrast and σ from a least-squares
/// fit of the sharp model, and dividing zig-zagging steps by 1 − r (r the ratio of a step to
/// the one before). Together they cut the evaluations per fit by a quarter to two fifths
/// (IR bench 8.3 → 5.5, GoPro 18.2 → 10.8) and lowered the colour corpus RMS by up to
/// 0.001 px, but raised the real kinect-lab IR calibration's RMS from 0.2168 to 0.2243 px
/// (7 of its 9 views worse; each change alone 0.2214 and 0.2220).
const FIT_COARSE_MAX_SHARE: f64 = 0.6;
/// A rejected trial whose cost rose by at most this fraction, after a step of less than
/// [`FIT_FLOOR_MOVE`] px, ends the fit: the cost is at the f32 sums' rounding floor (~1e-7
/// relative) and further damped steps of ~1e-5 px were all rejected the same way (up to four
/// wasted evaluations, traced on the IR bench image).
const FIT_COST_FLOOR: f64 = 1e-6;
const FIT_FLOOR_MOVE: f64 = 1e-3;

/// Pixels per lane group of the junction-fit kernel. The kernel is plain loops over
/// `[f32; LANES]` arrays, which LLVM vectorises itself: two SSE2 registers per operation on the
/// baseline target, one AVX2 register in the AVX2+FMA clone ([`eval_kernel`]). (`wide`'s types
/// pick SSE2 at compile time and would stay SSE2 inside the clone.)
const LANES: usize = 8;
type Lane = [f32; LANES];
/// Lane groups per block of [`kernel`]: its model pass writes a block's Jacobian rows and
/// residuals (10 × 16 × 8 f32 = 5 KiB, in L1), then its product pass runs over them with one
/// accumulator at a time in registers, so each of the 55 accumulators is loaded and stored once
/// per block. (Updating all 55 for every group of eight pixels needs 110 SSE registers of
/// x86-64's 16: they were spilled and reloaded every group, ~82 cycles per pixel.)
const BLOCK: usize = 16;
/// Columns of the product pass at once in the AVX2+FMA clone: eight accumulators (of 16 YMM
/// registers) cover a fused multiply-add's latency (4 cycles) on its two ports, where four
/// waited on their own adds. Each accumulator still sums its pixels in group order, so the
/// sums are the same to the bit; fit stage of the IR bench image 0.98–1.00 → 0.95–0.97 ms
/// (one thread, loaded machine, 2026-12-02).
const WIDE: usize = 8;
/// Rows per pixel of the product pass: the 9 Jacobian entries, then the residual. The upper
/// triangle of their outer product holds JᵀJ (45 entries), Jᵀr (9) and the squared residual.
const ROWS: usize = 10;
const PRODUCTS: usize = ROWS * (ROWS + 1) / 2;

/// Eight f32 lanes with element-wise arithmetic written as plain loops over the array (each
/// operation a fixed-length loop that LLVM's vectoriser turns into SIMD instructions of the
/// target it compiles for: the baseline or the AVX2+FMA clone).
#[derive(Clone, Copy)]
struct V<const W: usize>([f32; W]);

impl<const W: usize> V<W> {
    #[inline(always)]
    fn splat(x: f32) -> Self {
        Self([x; W])
    }
    #[inline(always)]
    fn map(self, f: impl Fn(f32) -> f32) -> Self {
        Self(std::array::from_fn(|l| f(self.0[l])))
    }
    #[inline(always)]
    fn zip(self, o: Self, f: impl Fn(f32, f32) -> f32) -> Self {
        Self(std::array::from_fn(|l| f(self.0[l], o.0[l])))
    }
}

impl<const W: usize> std::ops::Add for V<W> {
    type Output = Self;
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        self.zip(o, |a, b| a + b)
    }
}

impl<const W: usize> std::ops::Sub for V<W> {
    type Output = Self;
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        self.zip(o, |a, b| a - b)
    }
}

impl<const W: usize> std::ops::Mul for V<W> {
    type Output = Self;
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        self.zip(o, |a, b| a * b)
    }
}

impl<const W: usize> std::ops::Div for V<W> {
    type Output = Self;
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        self.zip(o, |a, b| a / b)
    }
}

impl<const W: usize> std::ops::Neg for V<W> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        self.map(|a| -a)
    }
}

/// `a·b + c`: fused (one rounding) in the FMA clone, a multiply and an add elsewhere (a fused
/// `mul_add` without the FMA instruction is a slow library call).
#[inline(always)]
fn mul_add<const FMA: bool, const W: usize>(a: V<W>, b: V<W>, c: V<W>) -> V<W> {
    V(std::array::from_fn(|l| {
        if FMA { a.0[l].mul_add(b.0[l], c.0[l]) } else { a.0[l] * b.0[l] + c.0[l] }
    }))
}

/// `erf(x)` given `q = exp(−x²)` (which the fit needs anyway for the derivative):
/// Abramowitz & Stegun 7.1.26, absolute error ≤ 1.5e-7 — 2e-5 grey levels at a contrast of
/// 255, far below the images' noise — at a third of the cost of a full-precision `erf`.
/// (Evaluated in f32: the rounding adds ≤ 3e-7.)
#[inline(always)]
fn erf_with_gauss<const FMA: bool, const W: usize>(x: V<W>, q: V<W>) -> V<W> {
    const P: f32 = 0.327_591_1;
    const A: [f32; 5] = [0.254_829_6, -0.284_496_74, 1.421_413_7, -1.453_152_1, 1.061_405_4];
    let one = V::splat(1.0);
    let t = one / mul_add::<FMA, W>(V::splat(P), x.map(f32::abs), one);
    let mut poly = V::splat(A[4]);
    for c in A[..4].iter().rev() {
        poly = mul_add::<FMA, W>(poly, t, V::splat(*c));
    }
    let y = one - t * poly * q;
    // erf is odd: give y the sign of x.
    y.zip(x, |y, x| f32::from_bits(y.to_bits() ^ (x.to_bits() & 0x8000_0000)))
}

/// `exp(x)` for `x ≤ 0`, inlined (a library `exp` was a function call, 45 % of the fit's
/// time): Cody–Waite reduction to `r ∈ [−ln 2 / 2, ln 2 / 2]` and Cephes' degree-7 polynomial
/// for `expf` (≤ 2 ulp); arguments below −87 give `exp(−87)` ≈ 1.6e-38 instead of a smaller
/// number, which the fit cannot tell from 0.
#[inline(always)]
fn exp_nonpositive<const FMA: bool, const W: usize>(x: V<W>) -> V<W> {
    const LOG2_E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    const P: [f32; 6] = [
        1.987_569_1e-4,
        1.398_199_9e-3,
        8.333_452e-3,
        4.166_579_6e-2,
        1.666_666_5e-1,
        0.5, // Cephes: 5.0000001e-1, which rounds to 0.5 in f32
    ];
    // 1.5·2²³: adding it to a value of magnitude below 2²² rounds that value to the nearest
    // integer n, which then sits in the sum's low mantissa bits (no float→int conversion).
    const ROUND: f32 = 12_582_912.0;
    let x = x.map(|x| if x < -87.0 { -87.0 } else { x });
    let t = mul_add::<FMA, W>(x, V::splat(LOG2_E), V::splat(ROUND));
    let n = t - V::splat(ROUND);
    // n·LN2_HI is exact (LN2_HI has 11 significant bits, |n| ≤ 126).
    let r = mul_add::<FMA, W>(n, V::splat(-LN2_LO), mul_add::<FMA, W>(n, V::splat(-LN2_HI), x));
    let mut p = V::splat(P[0]);
    for c in &P[1..] {
        p = mul_add::<FMA, W>(p, r, V::splat(*c));
    }
    let e = mul_add::<FMA, W>(r * r, p, r) + V::splat(1.0);
    // 2ⁿ: the sum's bits are 0x4B40_0000 + n; shifted left by 23 only n + 127 (in 1..=127
    // after the clamp) stays, in the exponent field.
    e * t.map(|t| f32::from_bits(t.to_bits().wrapping_add(127) << 23))
}

/// A fit window's pixels in lanes of eight (structure of arrays, the last lane padded with
/// weight 0): offsets from the fit's start point and observed values. f32 is exact for the
/// 8-bit values and keeps offsets below 1e-5 px of rounding within the ≤ 20 px window.
struct Lanes {
    /// `x − start.x`, `y − start.y`, observed value, 1 for a pixel and 0 for padding.
    u: Vec<Lane>,
    v: Vec<Lane>,
    obs: Vec<Lane>,
    valid: Vec<Lane>,
}

impl Lanes {
    fn new(pix: &[(f64, f64, f64)], start: Vector2<f64>) -> Self {
        let n = pix.len().div_ceil(LANES);
        let mut lanes = Self {
            u: vec![[0.0; LANES]; n],
            v: vec![[0.0; LANES]; n],
            obs: vec![[0.0; LANES]; n],
            valid: vec![[0.0; LANES]; n],
        };
        for (i, q) in pix.iter().enumerate() {
            let (g, l) = (i / LANES, i % LANES);
            lanes.u[g][l] = (q.0 - start.x) as f32;
            lanes.v[g][l] = (q.1 - start.y) as f32;
            lanes.obs[g][l] = q.2 as f32;
            lanes.valid[g][l] = 1.0;
        }
        lanes
    }
}

/// The junction model's parameters (see [`fit_junction`]) as the kernel uses them, in f32:
/// edge-angle sines and cosines, mean, contrast, gradient, the corner's offset from the
/// window's start point, `1/(√2σ)`, `√(2/π)/σ` and `1/σ`.
#[derive(Clone, Copy)]
struct Model {
    s1: f32,
    c1: f32,
    s2: f32,
    c2: f32,
    m: f32,
    a: f32,
    gx: f32,
    gy: f32,
    du: f32,
    dv: f32,
    k: f32,
    g: f32,
    inv_sg: f32,
}

impl Model {
    fn new(p: &nalgebra::SVector<f64, 9>, start: Vector2<f64>) -> Self {
        Self {
            s1: p[2].sin() as f32,
            c1: p[2].cos() as f32,
            s2: p[3].sin() as f32,
            c2: p[3].cos() as f32,
            m: p[4] as f32,
            a: p[5] as f32,
            gx: p[7] as f32,
            gy: p[8] as f32,
            du: (p[0] - start.x) as f32,
            dv: (p[1] - start.y) as f32,
            k: (1.0 / (std::f64::consts::SQRT_2 * p[6])) as f32,
            g: ((2.0 / std::f64::consts::PI).sqrt() / p[6]) as f32,
            inv_sg: (1.0 / p[6]) as f32,
        }
    }

    /// Eight pixels' Jacobian rows (∂f/∂p for the 9 parameters) and residuals `f − obs`,
    /// zero for padding and for a censored pixel.
    #[inline(always)]
    fn pixels<const FMA: bool, const W: usize>(
        &self,
        u0: V<W>,
        v0: V<W>,
        obs: V<W>,
        valid: V<W>,
    ) -> [V<W>; ROWS] {
        let [s1, c1, s2, c2, m, a, gx, gy, du, dv, k, g, inv_sg] = [
            self.s1,
            self.c1,
            self.s2,
            self.c2,
            self.m,
            self.a,
            self.gx,
            self.gy,
            self.du,
            self.dv,
            self.k,
            self.g,
            self.inv_sg,
        ]
        .map(V::splat);
        let (u, v) = (u0 - du, v0 - dv);
        let (d1, d2) = (c1 * v - s1 * u, c2 * v - s2 * u);
        let (x1, x2) = (d1 * k, d2 * k);
        let (q1, q2) =
            (exp_nonpositive::<FMA, W>(-(x1 * x1)), exp_nonpositive::<FMA, W>(-(x2 * x2)));
        let (e1, e2) = (erf_with_gauss::<FMA, W>(x1, q1), erf_with_gauss::<FMA, W>(x2, q2));
        let ee = e1 * e2;
        let pp = mul_add::<FMA, W>(a, ee, m);
        let l = mul_add::<FMA, W>(gy, v0, mul_add::<FMA, W>(gx, u0, V::splat(1.0)));
        let f = pp * l;
        // A saturated pixel only says "at least 255": no residual where the model is above it.
        let keep = V(std::array::from_fn(|i| {
            let censored = obs.0[i] >= SATURATED as f32 && f.0[i] >= obs.0[i];
            if censored { 0.0 } else { valid.0[i] }
        }));
        let res = (f - obs) * keep;
        // ∂E(dᵢ)/∂dᵢ times the other edge's E.
        let (h1, h2) = (g * q1 * e2, e1 * g * q2);
        let lk = l * keep;
        let nal = -(a * lk);
        let ppk = pp * keep;
        [
            -nal * mul_add::<FMA, W>(h1, s1, h2 * s2),
            nal * mul_add::<FMA, W>(h1, c1, h2 * c2),
            nal * h1 * mul_add::<FMA, W>(c1, u, s1 * v),
            nal * h2 * mul_add::<FMA, W>(c2, u, s2 * v),
            lk,
            ee * lk,
            nal * inv_sg * mul_add::<FMA, W>(d1, h1, d2 * h2),
            ppk * u0,
            ppk * v0,
            res,
        ]
    }
}

/// The upper triangle of Σ [J r]ᵀ[J r] over `px` (row-major, `ROWS` = 10: JᵀJ, then Jᵀr in
/// each row's last entry, the cost last), per lane: each lane sums its pixels in window
/// order. Written for LLVM's vectoriser (the lane loops); `FMA` selects fused multiply-adds.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // lane loops by index: fixed-length loops LLVM vectorises
fn kernel<const FMA: bool>(px: &Lanes, md: &Model) -> [Lane; PRODUCTS] {
    let mut acc = [[0.0f32; LANES]; PRODUCTS];
    let mut rows = [[[0.0f32; LANES]; BLOCK]; ROWS];
    let groups = px.u.len();
    for first in (0..groups).step_by(BLOCK) {
        let nb = BLOCK.min(groups - first);
        for b in 0..nb {
            // `black_box` keeps LLVM's loop vectoriser off this loop. Without it, it vectorised
            // the loop across lane groups (each vector lane a different group, every `[f32; 8]`
            // transposed in and out: 3 667 instructions in the AVX2 clone, 280 of them
            // `vshufps`) instead of the lane loops within a group (678 instructions). The IR
            // bench image's fit stage: 0.68–0.72 → 0.60 ms (one thread, minimum of 300 runs),
            // corners identical to the bit (2026-12-02).
            let i = std::hint::black_box(first + b);
            let j = md.pixels::<FMA, LANES>(V(px.u[i]), V(px.v[i]), V(px.obs[i]), V(px.valid[i]));
            for r in 0..ROWS {
                rows[r][b] = j[r].0;
            }
        }
        // Row r against up to four columns at once: four independent accumulators (eight
        // SSE registers) keep the adders busy where one accumulator waited on its own add.
        // The FMA clone takes up to [`WIDE`] at once.
        let mut n = 0;
        for r in 0..ROWS {
            let mut c = r;
            while c < ROWS {
                let k = (ROWS - c).min(if FMA { WIDE } else { 4 });
                let acc = &mut acc[n..n + k];
                match k {
                    8 => products::<8, FMA>(&rows, r, c, nb, acc),
                    7 => products::<7, FMA>(&rows, r, c, nb, acc),
                    6 => products::<6, FMA>(&rows, r, c, nb, acc),
                    5 => products::<5, FMA>(&rows, r, c, nb, acc),
                    4 => products::<4, FMA>(&rows, r, c, nb, acc),
                    3 => products::<3, FMA>(&rows, r, c, nb, acc),
                    2 => products::<2, FMA>(&rows, r, c, nb, acc),
                    _ => products::<1, FMA>(&rows, r, c, nb, acc),
                }
                c += k;
                n += k;
            }
        }
    }
    acc
}

/// Adds `Σ rows[r]·rows[c + i]` over a block's first `nb` lane groups to `acc[i]`,
/// `i < K`, per lane and in group order.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // lane loops by index: fixed-length loops LLVM vectorises
fn products<const K: usize, const FMA: bool>(
    rows: &[[Lane; BLOCK]; ROWS],
    r: usize,
    c: usize,
    nb: usize,
    acc: &mut [Lane],
) {
    let mut sums: [V<LANES>; K] = std::array::from_fn(|i| V(acc[i]));
    for b in 0..nb {
        let row = V(rows[r][b]);
        for i in 0..K {
            sums[i] = mul_add::<FMA, LANES>(row, V(rows[c + i][b]), sums[i]);
        }
    }
    for (a, s) in acc.iter_mut().zip(sums) {
        *a = s.0;
    }
}

/// [`kernel`], compiled for the baseline target (SSE2 on x86-64) and for AVX2+FMA, the clone
/// picked at run time (a cached CPU-feature check): the same loops in 256-bit registers with
/// fused multiply-adds run in about half the time.
#[multiversion(targets("x86_64+avx2+fma"))]
fn eval_kernel(px: &Lanes, md: &Model) -> [Lane; PRODUCTS] {
    kernel::<{ target_cfg_f!(target_feature = "fma") }>(px, md)
}

/// Cost, JᵀJ and Jᵀr of the junction model with parameters `p` (see [`fit_junction`]) over
/// `px`, whose offsets are from `start`: [`eval_kernel`]'s f32 sums, each lane's reduced to
/// f64, and JᵀJ mirrored from its upper triangle.
fn eval_lanes(
    px: &Lanes,
    p: &nalgebra::SVector<f64, 9>,
    start: Vector2<f64>,
) -> (f64, nalgebra::SMatrix<f64, 9, 9>, nalgebra::SVector<f64, 9>) {
    sums_to_normal_equations(&eval_kernel(px, &Model::new(p, start)))
}

/// Cost, JᵀJ and Jᵀr from [`kernel`]'s per-lane sums.
fn sums_to_normal_equations(
    acc: &[Lane; PRODUCTS],
) -> (f64, nalgebra::SMatrix<f64, 9, 9>, nalgebra::SVector<f64, 9>) {
    // Each product's lanes summed in f64 in lane order, from −0.0 as `Iterator::sum`; with
    // the products in the inner loop LLVM adds several products' lanes at once.
    let mut sums = [-0.0f64; PRODUCTS];
    for l in 0..LANES {
        for (s, lanes) in sums.iter_mut().zip(acc) {
            *s += lanes[l] as f64;
        }
    }
    let mut jtj = nalgebra::SMatrix::<f64, 9, 9>::zeros();
    let mut jtr = nalgebra::SVector::<f64, 9>::zeros();
    let mut cost = 0.0;
    let mut n = 0;
    for r in 0..ROWS {
        for c in r..ROWS {
            let s = sums[n];
            n += 1;
            match (r, c) {
                (9, 9) => cost = s,
                (r, 9) => jtr[r] = s,
                (r, c) => {
                    jtj[(r, c)] = s;
                    jtj[(c, r)] = s;
                }
            }
        }
    }
    (cost, jtj, jtr)
}

/// Maximum-likelihood sub-pixel X-junction: fits the model of a blurred checker corner,
/// `I(x) = (m + a·E(d₁)·E(d₂))·(1 + g·(x − x₀))`, `E(d) = erf(d / (√2·σ))`, `dᵢ` the signed
/// distance to edge line `i` through the corner, to the pixels within `radius` of `start` by
/// Levenberg–Marquardt (9 parameters: corner, two edge angles, mean, contrast, blur, and a
/// linear brightness gradient for vignetting and glare). Saturated pixels are censored.
///
/// Unlike `cornerSubPix`'s gradient-orthogonality normal equations, whose flat-area pixels add
/// gradient noise with a lever arm, every pixel here is weighted by how much it says about
/// the corner, so a wide window keeps lowering the noise (the rendered set's corner error
/// halves). The blur of two non-orthogonal edges is not exactly a product of `erf`s, but the
/// mismatch is point-symmetric about the corner and does not move it. `dirs` are the image
/// directions of the two grid lines (any sign). `None` when the fit fails or leaves the
/// window's centre by more than 1 px.
pub fn fit_junction(
    img: &Image<f32>,
    start: Vector2<f64>,
    dirs: [Vector2<f64>; 2],
    radius: f64,
) -> Option<Vector2<f64>> {
    fit(img, start, dirs, radius).map(|f| f.0)
}

/// [`fit_junction`] with the corner's 1σ (px, the larger axis of its covariance), from the
/// fit's Jacobian and residual variance.
pub fn fit_junction_with_std(
    img: &Image<f32>,
    start: Vector2<f64>,
    dirs: [Vector2<f64>; 2],
    radius: f64,
) -> Option<(Vector2<f64>, f64)> {
    let (c, cost, jtj, n) = fit(img, start, dirs, radius)?;
    let dof = (n as f64 - 9.0).max(1.0);
    let cov = jtj.try_inverse()? * (cost / dof);
    let sub = cov.fixed_view::<2, 2>(0, 0).into_owned();
    let std = sub.symmetric_eigenvalues().max().max(0.0).sqrt();
    Some((c, std))
}

/// [`fit_junction`] with the final cost, JᵀJ and pixel count (for the corner's σ).
fn fit(
    img: &Image<f32>,
    start: Vector2<f64>,
    dirs: [Vector2<f64>; 2],
    radius: f64,
) -> Option<(Vector2<f64>, f64, nalgebra::SMatrix<f64, 9, 9>, usize)> {
    use nalgebra::{SMatrix, SVector};
    let (w, h) = (img.width() as isize, img.height() as isize);
    let r = radius.floor() as isize;
    let (ox, oy) = (start.x.round() as isize, start.y.round() as isize);
    // The window's pixels in row order, with the counts that choose the stages.
    let mut pix: Vec<(f64, f64, f64)> = Vec::with_capacity(((2 * r + 1) * (2 * r + 1)) as usize);
    let (mut unsaturated, mut coarse_all, mut coarse_unsaturated) = (0, 0, 0);
    let (data, row_len) = (img.data(), img.width());
    // Within the coarse stage's circle (for the counts here and the coarse window below).
    let in_coarse = |x: f64, y: f64| {
        (x - start.x).powi(2) + (y - start.y).powi(2) <= FIT_COARSE_RADIUS * FIT_COARSE_RADIUS
    };
    for y in (oy - r).max(0)..=(oy + r).min(h - 1) {
        let row = &data[y as usize * row_len..(y as usize + 1) * row_len];
        for x in (ox - r).max(0)..=(ox + r).min(w - 1) {
            let (u, v) = (x as f64 - start.x, y as f64 - start.y);
            if u * u + v * v <= radius * radius {
                let value = row[x as usize] as f64;
                pix.push((x as f64, y as f64, value));
                let clear = value < SATURATED;
                unsaturated += usize::from(clear);
                if in_coarse(x as f64, y as f64) {
                    coarse_all += 1;
                    coarse_unsaturated += usize::from(clear);
                }
            }
        }
    }
    if unsaturated < FIT_MIN_PIXELS {
        return None;
    }
    let th = |d: Vector2<f64>| d.y.atan2(d.x);
    let (t1, t2) = (th(dirs[0]), th(dirs[1]));
    let two_stage = radius > FIT_COARSE_RADIUS
        && coarse_unsaturated >= FIT_MIN_PIXELS
        && (coarse_all as f64) < FIT_COARSE_MAX_SHARE * pix.len() as f64;
    let m0 = pix.iter().map(|p| p.2).sum::<f64>() / pix.len() as f64;
    let side = |t: f64| {
        let (s, c) = (t.sin(), t.cos());
        move |x: f64, y: f64| {
            if -s * (x - start.x) + c * (y - start.y) >= 0.0 { 1.0 } else { -1.0 }
        }
    };
    let (side1, side2) = (side(t1), side(t2));
    let a0 = pix.iter().map(|p| (p.2 - m0) * side1(p.0, p.1) * side2(p.0, p.1)).sum::<f64>()
        / pix.len() as f64;
    // p = [cx, cy, θ1, θ2, m, a, σ, gx, gy]
    let p =
        SVector::<f64, 9>::from_column_slice(&[start.x, start.y, t1, t2, m0, a0, 1.0, 0.0, 0.0]);
    // Cost, JᵀJ and Jᵀr at `p`, eight pixels at a time in f32 (`Lanes`); sums are reduced to
    // f64 once per evaluation.
    let eval = |px: &Lanes, p: &SVector<f64, 9>| eval_lanes(px, p, start);
    // Levenberg–Marquardt; every trial point is evaluated with its Jacobian, which an accepted
    // step (the common case) then uses without a second pass over the pixels.
    let lm = |pix: &Lanes,
              mut p: SVector<f64, 9>,
              iterations: usize,
              eps: f64|
     -> Option<(SVector<f64, 9>, f64, SMatrix<f64, 9, 9>)> {
        let mut lambda = 1e-3;
        let (mut cost, mut jtj, mut jtr) = eval(pix, &p);
        let mut last_accepted = false;
        for _ in 0..iterations {
            let mut a = jtj;
            for i in 0..9 {
                a[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&(-jtr))) else {
                lambda *= 10.0;
                if lambda > 1e8 {
                    return None;
                }
                continue;
            };
            // A step below `eps` right after an accepted one ends the fit; it is taken without
            // evaluating the model there (that evaluation would only confirm it: its cost,
            // JᵀJ and Jᵀr differ from the current ones in the last digits), so the returned
            // cost and JᵀJ are those of the point one tiny step before. Not after a rejected
            // step or before the first accepted one: a damped or first step can be small in
            // position and still wrong in the other parameters, and needs its evaluation.
            let moved = step.fixed_rows::<2>(0).norm();
            if moved < eps && last_accepted {
                p += step;
                break;
            }
            let next = p + step;
            let trial = eval(pix, &next);
            if trial.0 < cost {
                p = next;
                lambda = (lambda * 0.3).max(1e-9);
                (cost, jtj, jtr) = trial;
                last_accepted = true;
                if moved < eps {
                    break;
                }
            } else {
                last_accepted = false;
                lambda *= 10.0;
                let at_floor = trial.0 - cost <= FIT_COST_FLOOR * cost && moved < FIT_FLOOR_MOVE;
                if lambda > 1e8 || at_floor {
                    break;
                }
            }
        }
        Some((p, cost, jtj))
    };
    let all = Lanes::new(&pix, start);
    let (p, cost, jtj) = if two_stage {
        let coarse: Vec<(f64, f64, f64)> =
            pix.iter().copied().filter(|q| in_coarse(q.0, q.1)).collect();
        let (p1, _, _) = lm(&Lanes::new(&coarse, start), p, FIT_MAX_ITERATIONS, FIT_COARSE_EPS)?;
        lm(&all, p1, FIT_FINAL_ITERATIONS, FIT_EPS)?
    } else {
        lm(&all, p, FIT_MAX_ITERATIONS, FIT_EPS)?
    };
    let c = Vector2::new(p[0], p[1]);
    let ok = p.iter().all(|v| v.is_finite())
        && (c - start).norm() <= 1.0
        // The model depends on σ only through E(d₁)·E(d₂), which is even in σ: a fit that
        // crossed to −σ is the same junction. (Rejecting those sent 733 of the corpus's
        // 3728 fits, a fifth, to the cornerSubPix fallback; accepting them lowers the
        // robot-arm and GoPro RMS and worst corner distances.)
        && p[6].abs() > FIT_MIN_SIGMA
        && p[6].abs() < radius
        && p[5].abs() > 0.0
        // A singular fit (no information on some parameter) is no corner estimate.
        && jtj.try_inverse().is_some();
    if !ok {
        return None;
    }
    Some((c, cost, jtj, pix.len()))
}

#[cfg(test)]
mod tests {
    use super::super::subpix::px;
    use super::*;

    #[test]
    fn fast_erf_matches_tabulated_values() {
        // erf to 16 digits (Abramowitz & Stegun table 7.1 / any CAS); the approximation's
        // documented bound is 1.5e-7, f32 evaluation adds a few 1e-7.
        for (x, erf) in [
            (0.0, 0.0),
            (0.1, 0.112_462_916_018_284_9),
            (0.5, 0.520_499_877_813_046_5),
            (1.0, 0.842_700_792_949_714_9),
            (2.0, 0.995_322_265_018_952_7),
            (3.5, 0.999_999_256_901_627_7),
        ] {
            for (x, erf) in [(x, erf), (-x, -erf)] {
                let xs = V::splat(x as f32);
                let q = V::splat((-(x as f32).powi(2)).exp());
                // The bound plus f32 rounding (x itself rounds by up to 6e-8 · x).
                for g in [erf_with_gauss::<false, 8>(xs, q).0, erf_with_gauss::<true, 8>(xs, q).0] {
                    let g = g[3];
                    assert!((g as f64 - erf).abs() < 5e-7, "erf({x}) = {g}, expected {erf}");
                }
            }
        }
    }

    #[test]
    fn fast_exp_matches_std() {
        // Relative error against f64 `exp`: Cephes' expf bound is 2 ulp (≈ 2.4e-7); below
        // −87 the documented clamp.
        for exp in [exp_nonpositive::<false, 8>, exp_nonpositive::<true, 8>] {
            let mut x = 0.0f32;
            while x > -87.0 {
                let got = exp(V::splat(x)).0[5] as f64;
                let want = (x as f64).exp();
                assert!(((got - want) / want).abs() < 3e-7, "exp({x}) = {got}, expected {want}");
                x -= 0.013_7;
            }
            let clamped = exp(V::splat(-200.0)).0[0] as f64;
            assert!((clamped - (-87.0f64).exp()).abs() < 1e-43);
        }
    }

    /// A blurred X-junction rendered analytically (8x8 supersampling of the sharp pattern,
    /// then a 3x3 binomial blur) with its corner at a known sub-pixel position.
    fn junction(cx: f64, cy: f64, angle: f64, skew: f64) -> Image<f32> {
        let (a1, a2) = (angle, angle + std::f64::consts::FRAC_PI_2 + skew);
        let sharp = Image::from_fn(64, 64, |x, y| {
            let mut acc = 0.0;
            for i in 0..8 {
                for j in 0..8 {
                    let (u, v) = (
                        x as f64 + (i as f64 + 0.5) / 8.0 - 0.5 - cx,
                        y as f64 + (j as f64 + 0.5) / 8.0 - 0.5 - cy,
                    );
                    let s = (-a1.sin() * u + a1.cos() * v).signum()
                        * (-a2.sin() * u + a2.cos() * v).signum();
                    acc += if s > 0.0 { 200.0 } else { 40.0 };
                }
            }
            (acc / 64.0) as f32
        });
        let k = [1.0, 2.0, 1.0];
        Image::from_fn(64, 64, |x, y| {
            let mut acc = 0.0;
            for (dj, kj) in k.iter().enumerate() {
                for (di, ki) in k.iter().enumerate() {
                    acc += kj
                        * ki
                        * px(&sharp, x as isize + di as isize - 1, y as isize + dj as isize - 1);
                }
            }
            acc / 16.0
        })
    }

    #[test]
    fn junction_fit_recovers_a_known_corner() {
        // Noise-free, tilted and sheared junctions: the pattern is exact up to the 1/8 px
        // supersampling, so the fit must land within 0.01 px (cornerSubPix's own error on
        // such images is several times that; the fit starts 0.4 px away).
        for (cx, cy, angle, skew) in
            [(31.3, 30.7, 0.2, 0.0), (32.45, 31.1, -0.5, 0.3), (30.8, 32.25, 1.0, -0.4)]
        {
            let img = junction(cx, cy, angle, skew);
            let dirs = [
                Vector2::new(angle.cos(), angle.sin()),
                Vector2::new(
                    (angle + std::f64::consts::FRAC_PI_2 + skew).cos(),
                    (angle + std::f64::consts::FRAC_PI_2 + skew).sin(),
                ),
            ];
            let start = Vector2::new(cx + 0.3, cy - 0.25);
            let (p, std) = fit_junction_with_std(&img, start, dirs, 12.0).expect("fits");
            let err = (p - Vector2::new(cx, cy)).norm();
            assert!(err < 0.01, "({cx}, {cy}): error {err} px");
            assert!(std < 0.01, "σ {std}");
        }
    }

    /// erf to ~1e-15 for the kernel test's reference: e^(−x²)·2/√π·Σ 2ⁿx^(2n+1)/(1·3···(2n+1))
    /// (positive terms, no cancellation); ±1 beyond |x| = 6, where erf is ±1 to 1e-17.
    fn erf_reference(x: f64) -> f64 {
        if x.abs() > 6.0 {
            return x.signum();
        }
        let (mut term, mut sum, mut n) = (x, x, 0.0);
        while term.abs() > 1e-17 * sum.abs() {
            n += 1.0;
            term *= 2.0 * x * x / (2.0 * n + 1.0);
            sum += term;
        }
        2.0 / std::f64::consts::PI.sqrt() * (-x * x).exp() * sum
    }

    /// The junction model of [`fit_junction`]'s documentation, plainly in f64 at pixel (x, y);
    /// the gradient is relative to the window's start point, as in the fit.
    fn model_reference(p: &[f64; 9], start: Vector2<f64>, x: f64, y: f64) -> f64 {
        let (u, v) = (x - p[0], y - p[1]);
        let e = |t: f64| erf_reference((-t.sin() * u + t.cos() * v) / (2f64.sqrt() * p[6]));
        (p[4] + p[5] * e(p[2]) * e(p[3])) * (1.0 + p[7] * (x - start.x) + p[8] * (y - start.y))
    }

    #[test]
    fn erf_reference_matches_tabulated_values() {
        for (x, erf) in [(0.1, 0.112_462_916_018_284_9), (1.0, 0.842_700_792_949_714_9)] {
            assert!((erf_reference(x) - erf).abs() < 1e-14);
            assert!((erf_reference(-x) + erf).abs() < 1e-14);
        }
        assert!((erf_reference(3.5) - 0.999_999_256_901_627_7).abs() < 1e-14);
    }

    #[test]
    fn kernel_matches_a_plain_f64_evaluation() {
        // Random windows (partly saturated: censored pixels) and parameters; the reference
        // sums per pixel in f64 with central-difference derivatives (step 1e-5 of the
        // parameter: truncation and rounding errors ~1e-8 of the entries). Tolerance: each
        // entry within 1e-4 of its Cauchy–Schwarz scale √(JᵀJᵢᵢ·JᵀJⱼⱼ) (Jᵀr: √(JᵀJᵢᵢ·cost)),
        // the cost within 1e-4 relative — f32 sums of a few hundred pixels and the erf
        // approximation's 1.5e-7 are ~1e-6 of that.
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(14);
        let mut censored_pixels = 0;
        for _ in 0..12 {
            let start = Vector2::new(rng.random_range(20.0..40.0), rng.random_range(20.0..40.0));
            let radius: f64 = rng.random_range(5.0..13.0);
            let t1: f64 = rng.random_range(-3.0..3.0);
            let mut truth = [
                start.x + rng.random_range(-0.6..0.6),
                start.y + rng.random_range(-0.6..0.6),
                t1,
                t1 + std::f64::consts::FRAC_PI_2 + rng.random_range(-0.5..0.5),
                rng.random_range(90.0..170.0),
                rng.random_range(40.0..110.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 },
                rng.random_range(0.4..2.0),
                rng.random_range(-0.02..0.02),
                rng.random_range(-0.02..0.02),
            ];
            let mut pix = Vec::new();
            let r = radius.floor() as isize;
            let (ox, oy) = (start.x.round() as isize, start.y.round() as isize);
            for y in oy - r..=oy + r {
                for x in ox - r..=ox + r {
                    let (x, y) = (x as f64, y as f64);
                    if (x - start.x).powi(2) + (y - start.y).powi(2) <= radius * radius {
                        let noisy =
                            model_reference(&truth, start, x, y) + rng.random_range(-4.0f64..4.0);
                        pix.push((x, y, noisy.round().clamp(0.0, 255.0)));
                    }
                }
            }
            // Evaluate away from the truth, as the fit's iterations do.
            for (i, d) in [0.3, -0.2, 0.05, -0.04, 5.0, 8.0, 0.2, 0.004, -0.003].iter().enumerate()
            {
                truth[i] += d * rng.random_range(-1.0..1.0);
            }
            let p = truth;
            let (mut cost, mut jtj, mut jtr) = (0.0, [[0.0f64; 9]; 9], [0.0f64; 9]);
            for &(x, y, obs) in &pix {
                let f = model_reference(&p, start, x, y);
                if obs >= SATURATED && f >= obs {
                    censored_pixels += 1;
                    continue;
                }
                let j: [f64; 9] = std::array::from_fn(|i| {
                    let h = 1e-5 * p[i].abs().max(1.0);
                    let (mut hi, mut lo) = (p, p);
                    hi[i] += h;
                    lo[i] -= h;
                    (model_reference(&hi, start, x, y) - model_reference(&lo, start, x, y))
                        / (2.0 * h)
                });
                cost += (f - obs) * (f - obs);
                for r in 0..9 {
                    jtr[r] += j[r] * (f - obs);
                    for c in 0..9 {
                        jtj[r][c] += j[r] * j[c];
                    }
                }
            }
            let lanes = Lanes::new(&pix, start);
            let pv = nalgebra::SVector::<f64, 9>::from(p);
            let md = Model::new(&pv, start);
            for (name, (got_cost, got_jtj, got_jtr)) in [
                ("baseline", sums_to_normal_equations(&kernel::<false>(&lanes, &md))),
                ("fma", sums_to_normal_equations(&kernel::<true>(&lanes, &md))),
                ("dispatched", eval_lanes(&lanes, &pv, start)),
            ] {
                assert!(
                    (got_cost - cost).abs() <= 1e-4 * cost,
                    "{name}: cost {got_cost} vs {cost}"
                );
                for r in 0..9 {
                    let scale = (jtj[r][r] * cost).sqrt();
                    assert!(
                        (got_jtr[r] - jtr[r]).abs() <= 1e-4 * scale,
                        "{name}: Jᵀr[{r}] {} vs {}",
                        got_jtr[r],
                        jtr[r]
                    );
                    for c in 0..9 {
                        let scale = (jtj[r][r] * jtj[c][c]).sqrt();
                        assert!(
                            (got_jtj[(r, c)] - jtj[r][c]).abs() <= 1e-4 * scale,
                            "{name}: JᵀJ[{r},{c}] {} vs {}",
                            got_jtj[(r, c)],
                            jtj[r][c]
                        );
                    }
                }
            }
        }
        // Censored pixels were exercised.
        assert!(censored_pixels > 0);
    }
}
