//! Four-lane helpers shared by every stage: loads, stores, f64 widening, and the branch-free
//! `floor`, `min` and `max` whose NaN and signed-zero behaviour matches the reference's scalar
//! code bit for bit.

use wide::{f32x4, f64x2};

/// Four lanes.
pub(super) type V = f32x4;

#[inline(always)]
pub(super) fn sp(v: f32) -> V {
    V::splat(v)
}
/// Lanes `p[i..i + 4]`.
#[inline(always)]
pub(super) fn ld(p: &[f32], i: usize) -> V {
    let mut a = [0f32; 4];
    a.copy_from_slice(&p[i..i + 4]);
    V::new(a)
}
/// Stores lanes at `p[i..i + 4]`.
#[inline(always)]
pub(super) fn st(p: &mut [f32], i: usize, v: V) {
    p[i..i + 4].copy_from_slice(&v.to_array());
}
/// Widens to f64 (two pairs of lanes).
#[inline(always)]
pub(super) fn wide64(v: V) -> [f64x2; 2] {
    let a = v.to_array();
    [f64x2::new([a[0] as f64, a[1] as f64]), f64x2::new([a[2] as f64, a[3] as f64])]
}
/// Rounds two pairs of f64 lanes to f32.
#[inline(always)]
pub(super) fn narrow(v: [f64x2; 2]) -> V {
    let (l, h) = (v[0].to_array(), v[1].to_array());
    V::new([l[0] as f32, l[1] as f32, h[0] as f32, h[1] as f32])
}
/// f64 arithmetic on the lanes, rounded back to f32.
#[inline(always)]
pub(super) fn map64(v: V, f: impl Fn(f64x2) -> f64x2) -> V {
    let [l, h] = wide64(v);
    narrow([f(l), f(h)])
}

/// `floorf` of four lanes without a rounding instruction (SSE2 has none): exact for every
/// input — values with |x| ≥ 2²³, infinities and NaN are returned unchanged like `floorf`, and
/// the sign is restored so that −0.0 stays −0.0.
#[inline(always)]
pub(super) fn floor4(x: V) -> V {
    let small = x.abs().simd_lt(sp(8_388_608.0));
    let t = V::from_i32x4(x.fast_trunc_int());
    let f = t - (t.simd_gt(x) & sp(1.0));
    small.select(f.copysign(x), x)
}

/// `if b < a { b } else { a }` per lane (the reference's NaN behaviour). On x86 that is
/// exactly `minps(b, a)`.
#[inline(always)]
pub(super) fn fmin(a: V, b: V) -> V {
    #[cfg(target_arch = "x86_64")]
    return b.fast_min(a);
    #[cfg(not(target_arch = "x86_64"))]
    return b.simd_lt(a).select(b, a);
}
/// `if a < b { b } else { a }` per lane; on x86 exactly `maxps(b, a)`.
#[inline(always)]
pub(super) fn fmax(a: V, b: V) -> V {
    #[cfg(target_arch = "x86_64")]
    return b.fast_max(a);
    #[cfg(not(target_arch = "x86_64"))]
    return a.simd_lt(b).select(b, a);
}

#[cfg(test)]
mod tests {
    use super::{V, floor4};

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
