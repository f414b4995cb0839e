//! Joint bilateral filter (protocol §9.5): the range weights of neighbour pairs, computed once
//! per pair and shared by both ends, and the 3 × 3 filter of each frequency's phasor with its
//! edge test.

use super::lanes::{V, ld, sp, st};
#[cfg(target_arch = "x86_64")]
use super::lanes8;
use super::{Ctx, DecoderParams, PAD, PPlane, Plane, Row1, RowE, W, fastmath};

/// Bilateral amplitude threshold τ on a² + b² (protocol §9.5).
#[inline]
pub(super) fn bilateral_tau(p: &DecoderParams) -> f32 {
    (p.joint_bilateral_ab_threshold * p.joint_bilateral_ab_threshold)
        / (p.ab_multiplier * p.ab_multiplier)
}

/// Range distance of two unit phasors (protocol §9.5): `((−(ua1·ua + ub1·ub)) + 1)·0.5`, written as
/// `(1 − (…))·0.5`, the same IEEE result; symmetric bit for bit since each product commutes.
#[inline(always)]
pub(super) fn range_dist(ua1: V, ub1: V, ua: V, ub: V) -> V {
    (sp(1.0) - (ua1 * ua + ub1 * ub)) * sp(0.5)
}

/// Forward range weights (see [`RowE`]) of row `r` with its lower neighbour row `n`, both the
/// weight and the distance set to 0 unless both ends pass the amplitude threshold (the only
/// case in which the bilateral filter reads them).
#[inline(always)]
pub(super) fn edge_weights<const L8: bool>(c: &Ctx, r: &Row1, n: &Row1, out: &mut RowE) {
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
pub(super) type UnitPlanes<'a> = (&'a PPlane, &'a PPlane, &'a PPlane);

/// One direction of [`edge_weights`]: pairs (x of `this`, x + `OFF` of `other`). `FAST`: the
/// weights with [`fastmath::exp_unclamped`]; else the exponent, −∞ where masked, for libm.
#[inline(always)]
pub(super) fn pair_row<const FAST: bool, const OFF: isize>(
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
pub(super) fn copy_unfiltered(r: &Row1, fa: &mut [Plane; 3], fb: &mut [Plane; 3], ok: &mut Plane) {
    for k in 0..3 {
        fa[k].copy_from_slice(&r.a[k][PAD..PAD + W]);
        fb[k].copy_from_slice(&r.b[k][PAD..PAD + W]);
    }
    *ok = [1.0; W];
}

/// Joint bilateral filter (protocol §9.5) of frequency `k` over one processing row (1 ≤ y ≤ 422):
/// writes the filtered phasor to `fa`, `fb` and ANDs this frequency's edge test into `ok`
/// (k = 0 starts it). Border columns are copied with `edge_ok` true.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn bilateral_k(
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
