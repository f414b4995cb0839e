//! Eight-lane (AVX2) kernels of [`DecoderPrecision::Fast`](super::DecoderPrecision::Fast).
//!
//! Each kernel is the per-pixel arithmetic of the four-lane `wide` code in the parent module,
//! in the same operation order, written as a plain loop over the pixels of a row. The parent
//! calls them only from inside its `#[target_feature(enable = "avx2")]` band function, where
//! LLVM vectorises these loops to eight lanes. Rust never contracts `a * b + c` into a fused
//! multiply-add and every lane operation is the same IEEE operation as in the four-lane code,
//! so the two paths give **bit-identical** results (`tests/oracle.rs` compares them on every
//! vector file); only the width changes.

use super::fastmath::scalar;
use super::{DecoderParams, PAD, PPlane, Plane, W};

/// Range distance of two unit phasors, as the parent's `range_dist`.
#[inline(always)]
fn range_dist(ua1: f32, ub1: f32, ua: f32, ub: f32) -> f32 {
    (1.0 - (ua1 * ua + ub1 * ub)) * 0.5
}

/// The parent's `pair_row::<true, OFF>`: bilateral range weights `exp(ce · dist)` and distances
/// of the pairs (x of `this`, x + `OFF` of `other`), 0 unless both ends reach `tau0`.
#[inline(always)]
pub(super) fn pair_row<const OFF: isize>(
    ce: f32,
    tau0: f32,
    this: (&PPlane, &PPlane, &PPlane),
    other: (&PPlane, &PPlane, &PPlane),
    e: &mut PPlane,
    d: &mut PPlane,
) {
    let ((ua, ub, n2), (oa, ob, on2)) = (this, other);
    let j0 = (PAD as isize + OFF) as usize;
    let (ua, ub, n2) = (&ua[PAD..PAD + W], &ub[PAD..PAD + W], &n2[PAD..PAD + W]);
    let (oa, ob, on2) = (&oa[j0..j0 + W], &ob[j0..j0 + W], &on2[j0..j0 + W]);
    let (e, d) = (&mut e[PAD..PAD + W], &mut d[PAD..PAD + W]);
    for x in 0..W {
        let dist = range_dist(oa[x], ob[x], ua[x], ub[x]);
        // `&`, not `&&`: both loads happen, so the loop stays branch-free.
        let both = (n2[x] >= tau0) & (on2[x] >= tau0);
        d[x] = if both { dist } else { 0.0 };
        let w = scalar::exp_unclamped(ce * dist);
        e[x] = if both { w } else { 0.0 };
    }
}

/// Scratch planes of [`stage2_row`]: A* of the confidence, the amplitude gate (1.0 / 0.0),
/// the three phases and the confidence.
pub(super) struct Stage2Scratch<'a> {
    pub astar: &'a mut Plane,
    pub gate: &'a mut Plane,
    pub phi: &'a mut [Plane; 3],
    pub conf: &'a mut Plane,
}

/// The parent's `stage2_row` for `Fast` (protocol §9.6), in the same loops: amplitudes and gate,
/// phases, confidence, then `unwrap_depth`; writes the depth `dp`, its `lo`/`hi` forms and the
/// amplitude sum `is` of one processing row. `fa`, `fb`: filtered phasors; `ok`: the
/// bilateral `edge_ok` (1.0 / 0.0); `xt`, `zt`: the row's x/z tables.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn stage2_row(
    p: &DecoderParams,
    fa: &[Plane; 3],
    fb: &[Plane; 3],
    ok: &Plane,
    xt: &Plane,
    zt: &Plane,
    scratch: Stage2Scratch,
    dp: &mut [f32],
    lo: &mut [f32],
    hi: &mut [f32],
    is: &mut [f32],
) {
    let Stage2Scratch { astar, gate, phi, conf } = scratch;
    let (dp, lo, hi, is) = (&mut dp[..W], &mut lo[..W], &mut hi[..W], &mut is[..W]);
    // Amplitudes (steps 1–2).
    for x in 0..W {
        let amp = |k: usize| (fa[k][x] * fa[k][x] + fb[k][x] * fb[k][x]).sqrt() * p.ab_multiplier;
        let (a0, a1, a2) = (amp(0), amp(1), amp(2));
        let s = a0 + a1 + a2;
        let amin = fmin(fmin(a0, a1), a2);
        let amax = fmax(fmax(a0, a1), a2);
        astar[x] = if p.ab_confidence_slope > 0.0 { amin } else { amax };
        let pass = !((amin < p.individual_ab_threshold) | (s < p.ab_threshold));
        gate[x] = if pass { 1.0 } else { 0.0 };
        is[x] = s;
    }
    for k in 0..3 {
        for x in 0..W {
            phi[k][x] = scalar::atan2(fb[k][x], fa[k][x]);
        }
    }
    for x in 0..W {
        let l = scalar::ln(astar[x]);
        conf[x] =
            scalar::exp((l * p.ab_confidence_slope * 0.301030 + p.ab_confidence_offset) * 3.321928);
    }
    for x in 0..W {
        let (d, l, h) = unwrap_depth(
            p,
            [phi[0][x], phi[1][x], phi[2][x]],
            conf[x],
            gate[x] > 0.0,
            ok[x] > 0.0,
            xt[x],
            zt[x],
        );
        dp[x] = d;
        lo[x] = l;
        hi[x] = h;
    }
}

/// The parent's `unwrap_depth` for `Fast`, one pixel.
#[inline(always)]
fn unwrap_depth(
    p: &DecoderParams,
    phi: [f32; 3],
    conf: f32,
    gate: bool,
    ok: bool,
    xt: f32,
    zt: f32,
) -> (f32, f32, f32) {
    let two_pi = 2.0 * std::f64::consts::PI;
    // Unwrapping (step 3).
    let wrap_phase = |f: f32| {
        let f = if f < 0.0 { ((f as f64) + two_pi) as f32 } else { f };
        if f.is_nan() { 0.0 } else { f }
    };
    let ph = [wrap_phase(phi[0]), wrap_phase(phi[1]), wrap_phase(phi[2])];
    let t0 = ((ph[0] as f64) * (3.0 / two_pi)) as f32;
    let t1 = ((ph[1] as f64) * (15.0 / two_pi)) as f32;
    let t2 = ((ph[2] as f64) * (2.0 / two_pi)) as f32;
    let t5 = ((t1 - t0) * 0.333333 + 0.5).floor() * 3.0 + t0;
    let t3 = t5 - t2;
    let t4 = t3 * 2.0;
    let pos = t4 >= 0.0 - t4;
    let t3 = t3 * if pos { 0.5 } else { -0.5 };
    let t3 = (t3 - t3.floor()) * if pos { 2.0 } else { -2.0 };
    let at3 = t3.abs();
    let wrap = (0.5 < at3) & (at3 < 1.5);
    let t6 = if wrap { t5 + 15.0 } else { t5 };
    let t7 = if wrap { t1 + 15.0 } else { t1 };
    let t8 = (((t6 - t2) * 0.5 + 0.5).floor() * 2.0 + t2) * 0.5;
    let t6 = t6 * 0.333333;
    let t7 = t7 * 0.066667;
    let t9 = t8 + t6 + t7;
    let t10 = t9 * 0.333333;
    let t6 = ((t6 as f64) * two_pi) as f32;
    let t7 = ((t7 as f64) * two_pi) as f32;
    let t8 = ((t8 as f64) * two_pi) as f32;
    let e8 = t7 * 0.826977 - t8 * 0.110264;
    let e6 = t8 * 0.551318 - t6 * 0.826977;
    let e7 = t6 * 0.110264 - t7 * 0.551318;
    let nu = e8 * e8 + e6 * e6 + e7 * e7;
    let t10 = t10 * if t9 >= 0.0 { 1.0 } else { 0.0 };
    let cf = if conf < p.min_dealias_confidence { p.min_dealias_confidence } else { conf };
    let cf = if cf > p.max_dealias_confidence { p.max_dealias_confidence } else { cf };
    let cf = cf * cf;
    let phase = t10 * if cf >= nu { 1.0 } else { 0.0 };
    let phase = if gate { phase } else { 0.0 };
    // Depth (step 4).
    let ph = if phase > 0.0 { phase + p.phase_offset } else { phase };
    let zl = zt * ph;
    let dmax = ph * p.unambiguous_dist * 2.0;
    let xm = (xt * 90.0) / (dmax * dmax * 8192.0);
    let zf = zl / (1.0 - zl * xm);
    let zf = if zf < 0.0 { 0.0 } else { zf };
    let d = if (zl > 0.0) & (dmax > 0.0) { zf } else { zl };
    let valid = ok & (d > 0.0);
    (d, if valid { d } else { f32::INFINITY }, if valid { d } else { f32::NEG_INFINITY })
}

/// `if b < a { b } else { a }`: the parent's `fmin` (x86 `minps(b, a)`, NaN behaviour included).
#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if b < a { b } else { a }
}

/// `if a < b { b } else { a }`: the parent's `fmax`.
#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a < b { b } else { a }
}
