//! Pass 2: the edge-aware filter (protocol §9.7), which rejects depth at flying-pixel edges
//! and clamps to `[min_depth, max_depth]`, and the flip of processing row `y` to output row
//! `423 − y` (§9.8).

use super::lanes::{fmax, fmin, ld, sp, st};
use super::{DecoderParams, H, PAD, SW, W};

/// Rows y − 1, y, y + 1 of a plane of stride [`SW`].
pub(super) fn rows3(v: &[f32], y: usize) -> [&[f32]; 3] {
    [y - 1, y, y + 1].map(|r| &v[r * SW..(r + 1) * SW])
}

/// Pass 2 of processing row `y` (written to output row `423 − y`): edge-aware filter (protocol
/// §9.7) or a plain copy. `planes` = (depth, lo, hi, ir_sum), see [`DepthDecoder`](super::DepthDecoder)'s fields.
pub(super) fn output_row(
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
