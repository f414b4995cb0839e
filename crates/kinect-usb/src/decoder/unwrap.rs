//! Phase unwrapping and depth (protocol §9.6 steps 3–4) of four pixels: the three wrapped
//! phases are combined into one unambiguous phase, gated by the de-aliasing confidence, and
//! turned into depth along the optical axis with the x/z tables (§9.2).

use wide::f64x2;

use super::Ctx;
use super::lanes::{V, floor4, map64, narrow, sp, wide64};

/// Stage 2 from the phases `phi` (atan2 as returned), the de-aliasing confidence before
/// clamping, the amplitude gate and `edge_ok` masks and the x/z table values: the unwrapping
/// (step 3) and depth (step 4) of four pixels, returned as (depth, lo, hi) (see
/// [`DepthDecoder`](super::DepthDecoder)'s fields).
#[inline(always)]
pub(super) fn unwrap_depth(
    c: &Ctx,
    phi: [V; 3],
    conf: V,
    gate: V,
    ok: V,
    xt: V,
    zt: V,
) -> (V, V, V) {
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
    // `−a + b` of the reference formula is written `b − a` (the same IEEE result).
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
    // Multiplied, not selected: a negative t10 becomes −0.0 (protocol §9.9).
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
    // `−zl·xm + 1` of the reference formula is written `1 − zl·xm` (the same IEEE result).
    let zf = zl / (one - zl * xm);
    let zf = zf.simd_lt(zero).select(zero, zf);
    let d = (zl.simd_gt(zero) & dmax.simd_gt(zero)).select(zf, zl);
    let valid = ok & d.simd_gt(zero);
    (d, valid.select(d, sp(f32::INFINITY)), valid.select(d, sp(f32::NEG_INFINITY)))
}
