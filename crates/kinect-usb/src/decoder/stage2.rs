//! Stage 2 (protocol §9.6 steps 1–2 and the confidence of step 3): amplitudes, the amplitude
//! gate, phases and the de-aliasing confidence of one row; the unwrapping and depth of step 3–4
//! are in [`super::unwrap`].

use super::lanes::{V, fmax, fmin, ld, sp, st};
use super::unwrap::unwrap_depth;
use super::{Ctx, DecoderParams, Plane, W, Workspace, fastmath};

/// The argument of the de-aliasing confidence's `exp` (protocol §9.6 step 3) from `ln A*`.
#[inline(always)]
pub(super) fn conf_arg(p: &DecoderParams, ln_astar: f32) -> f32 {
    (ln_astar * p.ab_confidence_slope * 0.301030f32 + p.ab_confidence_offset) * 3.321928f32
}

/// Stage 2 (protocol §9.6) of processing row `y` from the filtered phasors in `ws.fa/fb` and
/// `ws.ok`: writes the depth, its `lo`/`hi` forms for the edge-aware filter (see
/// [`DepthDecoder`](super::DepthDecoder)'s fields) and the amplitude sum, in three passes over the row: amplitudes,
/// phases and confidence (libm only past the gate for Exact), unwrapping and depth.
#[inline(always)]
pub(super) fn stage2_row(
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
