//! Branch-free four-lane f32 `exp`, `ln` and `atan2` for [`DecoderPrecision::Fast`](super::DecoderPrecision).
//!
//! Written on `wide::f32x4` (SSE2 on baseline x86-64) with arithmetic, comparisons and selects
//! only: no calls, no table lookups, no branches.
//! Accuracy against f64 references is asserted in this module's tests:
//!
//! | function | domain where the bound holds | max error |
//! | --- | --- | --- |
//! | [`exp`], [`exp_unclamped`] | −87 ≤ x ≤ 88 (`exp` clamps outside; NaN → NaN) | 2 ulp ([`EXP_MAX_ULP`]) |
//! | [`ln`] | positive normal x (NaN → NaN) | 2 ulp ([`LN_MAX_ULP`]) |
//! | [`atan2`] | finite (y, x) ≠ (0, 0) (NaN → NaN) | 2.5 ulp ([`ATAN2_MAX_ULP`]) |
//!
//! glibc's `expf/logf/atan2f` are within about 0.5–1 ulp, so the Fast decoder differs from the
//! oracle by a few ulps in intermediate values (see `tests/oracle.rs` for the effect on depth).

/// Bound of [`exp`] in ulps of the f32 result (test `exp_within_bound_of_f64`).
pub const EXP_MAX_ULP: f64 = 2.0;
/// Bound of [`ln`] in ulps of the f32 result (test `ln_within_bound_of_f64`).
pub const LN_MAX_ULP: f64 = 2.0;
/// Bound of [`atan2`] in ulps of the f32 result (test `atan2_within_bound_of_f64`; 2.14 measured,
/// from the rounding of the final `π/4 + atan u` style sums).
pub const ATAN2_MAX_ULP: f64 = 2.5;

use wide::{f32x4, i32x4};

/// 1.5 · 2²³: adding and subtracting it rounds an f32 of magnitude < 2²² to the nearest integer
/// (ties to even) without a rounding instruction (SSE2 has none).
const ROUND_MAGIC: f32 = 12_582_912.0;
/// ln 2 split for Cody–Waite reduction: the high part has 12 significant bits so that `n · LN2_HI`
/// is exact for |n| ≤ 2¹¹.
const LN2_HI: f32 = 0.693_359_4;
/// ln 2 − [`LN2_HI`].
const LN2_LO: f32 = -2.121_944_4e-4;

#[inline(always)]
fn sp(v: f32) -> f32x4 {
    f32x4::splat(v)
}

/// Coefficients of e^r ≈ Σ cᵢ rⁱ on |r| ≤ ln 2 / 2: a weighted least-squares (Lawson iteration)
/// fit made for this module, relative error 1.9·10⁻⁹ in exact arithmetic (degree 6).
const EXP_P: [f32; 7] =
    [1.0, 1.0, 0.499_999_9, 0.166_664_2, 0.041_668_225, 0.008_374_816, 0.001_383_684_6];

/// e^x, four lanes, clamping x to [−87, 88] first (NaN propagates). See [`exp_unclamped`].
#[inline(always)]
pub fn exp(x: f32x4) -> f32x4 {
    // Comparisons with NaN are false: NaN passes both clamps.
    let x = x.simd_lt(sp(-87.0)).select(sp(-87.0), x);
    let x = x.simd_gt(sp(88.0)).select(sp(88.0), x);
    exp_unclamped(x)
}

/// e^x, four lanes, for x in [−87, 88] (NaN → NaN; other inputs give unspecified values).
/// Reduction x = n·ln 2 + r with |r| ≤ ln 2 / 2, e^r by a degree-6 polynomial, scaled by 2ⁿ
/// built in the exponent bits. The bilateral filter's arguments lie in [−7.3, 0].
#[inline(always)]
pub fn exp_unclamped(x: f32x4) -> f32x4 {
    let n = (x * sp(std::f32::consts::LOG2_E) + sp(ROUND_MAGIC)) - sp(ROUND_MAGIC);
    let r = (x - n * sp(LN2_HI)) - n * sp(LN2_LO);
    let mut p = sp(EXP_P[6]);
    for c in [EXP_P[5], EXP_P[4], EXP_P[3], EXP_P[2], EXP_P[1], EXP_P[0]] {
        p = p * r + sp(c);
    }
    // n ∈ [−126, 127] here (a NaN lane gives some scale, harmless: p is NaN).
    let e: i32x4 = (n.fast_trunc_int() + i32x4::splat(127)) << 23u32;
    p * f32x4::from_bits(wide::bytemuck::cast(e))
}

/// √2, the upper end of the mantissa range [√½, √2) used by [`ln`].
const SQRT_2: f32 = std::f32::consts::SQRT_2;

/// ln x, four lanes, for positive normal x. x = 2ᵉ·m with m ∈ [√½, √2); ln m = 2·atanh(s),
/// s = (m − 1)/(m + 1), |s| ≤ 0.172, by its series to s⁹ (truncation < 3·10⁻⁹ relative).
#[inline(always)]
pub fn ln(x: f32x4) -> f32x4 {
    let bits: i32x4 = wide::bytemuck::cast(x);
    let e = ((bits >> 23u32) & i32x4::splat(0xff)) - i32x4::splat(127);
    let m: f32x4 =
        wide::bytemuck::cast((bits & i32x4::splat(0x007f_ffff)) | i32x4::splat(0x3f80_0000));
    let big = m.simd_gt(sp(SQRT_2));
    let m = big.select(m * sp(0.5), m);
    let e = f32x4::from_i32x4(e) + (big & sp(1.0));
    let s = (m - sp(1.0)) / (m + sp(1.0));
    let z = s * s;
    let mut q = sp(1.0 / 9.0);
    for c in [1.0 / 7.0, 1.0 / 5.0, 1.0 / 3.0] {
        q = q * z + sp(c);
    }
    let s2 = sp(2.0) * s;
    let lnm = s2 + s2 * (z * q);
    let r = e * sp(LN2_HI) + (lnm + e * sp(LN2_LO));
    x.is_nan().select(x, r)
}

/// tan(π/8): above it, atan(t) = π/4 + atan((t − 1)/(t + 1)).
const TAN_PI_8: f32 = 0.414_213_57;
/// Coefficients of atan(u) ≈ u + u³·P(u²) on |u| ≤ tan(π/8): a weighted least-squares (Lawson
/// iteration) fit made for this module, relative error 7·10⁻¹⁰ in exact arithmetic.
const ATAN_P: [f32; 5] = [-0.333_333_16, 0.199_984_71, -0.142_435_33, 0.105_938_13, -0.060_782_19];

/// π/4 rounded to f32.
const PIO4_HI: f32 = std::f32::consts::FRAC_PI_4;
/// π/4 − [`PIO4_HI`].
const PIO4_LO: f32 = (std::f64::consts::FRAC_PI_4 - PIO4_HI as f64) as f32;
/// π/2 rounded to f32.
const PIO2_HI: f32 = std::f32::consts::FRAC_PI_2;
/// π/2 − [`PIO2_HI`].
const PIO2_LO: f32 = (std::f64::consts::FRAC_PI_2 - PIO2_HI as f64) as f32;
/// π rounded to f32.
const PI_HI: f32 = std::f32::consts::PI;
/// π − [`PI_HI`].
const PI_LO: f32 = (std::f64::consts::PI - PI_HI as f64) as f32;

/// atan2(y, x), four lanes, in (−π, π], for finite (y, x) ≠ (0, 0); NaN in either gives NaN
/// (so does (0, 0), where libm gives ±0 or ±π — the decoder never needs it there: the amplitude
/// gate of protocol §9.6 discards those pixels).
#[inline(always)]
pub fn atan2(y: f32x4, x: f32x4) -> f32x4 {
    let (ax, ay) = (x.abs(), y.abs());
    let swap = ay.simd_gt(ax);
    let num = swap.select(ax, ay);
    let den = swap.select(ay, ax);
    // t = num/den ∈ [0, 1]; above tan(π/8), atan t = π/4 + atan((num − den)/(num + den)),
    // formed from num and den directly (one rounding instead of two).
    let big = num.simd_gt(sp(TAN_PI_8) * den);
    let u = big.select(num - den, num) / big.select(num + den, den);
    let z = u * u;
    let mut p = sp(ATAN_P[4]);
    for c in [ATAN_P[3], ATAN_P[2], ATAN_P[1], ATAN_P[0]] {
        p = p * z + sp(c);
    }
    let a = u + u * (z * p);
    // Adding multiples of π/4 with their rounding error carried separately.
    let a = big.select(sp(PIO4_HI) + (a + sp(PIO4_LO)), a);
    let a = swap.select(sp(PIO2_HI) - (a - sp(PIO2_LO)), a);
    // x = −0 behaves like +0 (angle ±π/2), as in libm for y ≠ 0.
    let a = x.simd_lt(sp(0.0)).select(sp(PI_HI) - (a - sp(PI_LO)), a);
    a.copysign(y)
}

/// One-lane versions of the functions above, operation for operation (same constants, same
/// order, same results bit for bit): loops over them vectorise to any lane width, which is
/// how the decoder's eight-lane kernels use them.
pub mod scalar {
    use super::{
        ATAN_P, EXP_P, LN2_HI, LN2_LO, PI_HI, PI_LO, PIO2_HI, PIO2_LO, PIO4_HI, PIO4_LO,
        ROUND_MAGIC, SQRT_2, TAN_PI_8,
    };

    /// [`super::exp`] of one value.
    #[inline(always)]
    pub fn exp(x: f32) -> f32 {
        let x = if x < -87.0 { -87.0 } else { x };
        let x = if x > 88.0 { 88.0 } else { x };
        exp_unclamped(x)
    }

    /// [`super::exp_unclamped`] of one value. The integer `n` is read from the low mantissa
    /// bits of `x·log2 e + 1.5·2²³` (exact for |n| < 2²²) instead of converting the float,
    /// which vectorises where Rust's saturating `as i32` would not; for the finite inputs of
    /// the domain it equals the four-lane truncation.
    #[inline(always)]
    pub fn exp_unclamped(x: f32) -> f32 {
        let t = x * std::f32::consts::LOG2_E + ROUND_MAGIC;
        let n = t - ROUND_MAGIC;
        let r = (x - n * LN2_HI) - n * LN2_LO;
        let mut p = EXP_P[6];
        for c in [EXP_P[5], EXP_P[4], EXP_P[3], EXP_P[2], EXP_P[1], EXP_P[0]] {
            p = p * r + c;
        }
        let ni = (t.to_bits() as i32).wrapping_sub(ROUND_MAGIC.to_bits() as i32);
        p * f32::from_bits((ni.wrapping_add(127) << 23) as u32)
    }

    /// [`super::ln`] of one value.
    #[inline(always)]
    pub fn ln(x: f32) -> f32 {
        let bits = x.to_bits() as i32;
        let e = ((bits >> 23) & 0xff) - 127;
        let m = f32::from_bits(((bits & 0x007f_ffff) | 0x3f80_0000) as u32);
        let big = m > SQRT_2;
        let m = if big { m * 0.5 } else { m };
        let e = e as f32 + if big { 1.0 } else { 0.0 };
        let s = (m - 1.0) / (m + 1.0);
        let z = s * s;
        let mut q = 1.0f32 / 9.0;
        for c in [1.0f32 / 7.0, 1.0f32 / 5.0, 1.0f32 / 3.0] {
            q = q * z + c;
        }
        let s2 = 2.0 * s;
        let lnm = s2 + s2 * (z * q);
        let r = e * LN2_HI + (lnm + e * LN2_LO);
        if x.is_nan() { x } else { r }
    }

    /// [`super::atan2`] of one pair.
    #[inline(always)]
    pub fn atan2(y: f32, x: f32) -> f32 {
        let (ax, ay) = (x.abs(), y.abs());
        let swap = ay > ax;
        let num = if swap { ax } else { ay };
        let den = if swap { ay } else { ax };
        let big = num > TAN_PI_8 * den;
        let u = (if big { num - den } else { num }) / (if big { num + den } else { den });
        let z = u * u;
        let mut p = ATAN_P[4];
        for c in [ATAN_P[3], ATAN_P[2], ATAN_P[1], ATAN_P[0]] {
            p = p * z + c;
        }
        let a = u + u * (z * p);
        let a = if big { PIO4_HI + (a + PIO4_LO) } else { a };
        let a = if swap { PIO2_HI - (a - PIO2_LO) } else { a };
        let a = if x < 0.0 { PI_HI - (a - PI_LO) } else { a };
        a.copysign(y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tolerance: none. The one-lane functions must return the four-lane functions' bits for
    /// every input the decoder can produce (and NaN for NaN): a sweep over f32 bit patterns.
    #[test]
    fn scalar_versions_equal_the_four_lane_versions_bit_for_bit() {
        let lane = |f: &dyn Fn(f32x4) -> f32x4, x: f32| f(f32x4::splat(x)).to_array()[0];
        let same = |a: f32, b: f32| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
        for bits in (0..u32::MAX).step_by(9_973) {
            let x = f32::from_bits(bits);
            assert!(same(scalar::exp(x), lane(&exp, x)), "exp({x:e})");
            assert!(same(scalar::ln(x), lane(&ln, x)), "ln({x:e})");
            if (-87.0..=88.0).contains(&x) {
                assert!(
                    same(scalar::exp_unclamped(x), lane(&exp_unclamped, x)),
                    "exp_unclamped({x:e})"
                );
            }
            let y = f32::from_bits(bits.rotate_left(7));
            let want = atan2(f32x4::splat(y), f32x4::splat(x)).to_array()[0];
            assert!(same(scalar::atan2(y, x), want), "atan2({y:e}, {x:e})");
        }
    }

    fn atan2_1(y: f32, x: f32) -> f32 {
        atan2(f32x4::splat(y), f32x4::splat(x)).to_array()[0]
    }

    /// Lane 0 of a function of four lanes, the value broadcast.
    fn one(f: impl Fn(f32x4) -> f32x4, x: f32) -> f32 {
        f(f32x4::splat(x)).to_array()[0]
    }

    /// Error of `got` against the f64 reference in ulps of the f32 nearest to the reference.
    fn ulps(got: f32, want: f64) -> f64 {
        let w = want as f32;
        let ulp = (f32::from_bits(w.abs().to_bits() + 1) - w.abs()) as f64;
        (got as f64 - want).abs() / ulp
    }

    /// Every 256th f32 in [−87, 88] (≈ 8.7 M values) and every 23rd f32 in the bilateral
    /// filter's argument range [−7.3, −2⁻²⁰] (≈ 8 M values).
    #[test]
    fn exp_within_bound_of_f64() {
        let mut worst = (0.0f64, 0.0f32);
        let mut check = |x: f32| {
            let e = ulps(one(exp, x), (x as f64).exp())
                .max(ulps(one(exp_unclamped, x), (x as f64).exp()));
            if e > worst.0 {
                worst = (e, x);
            }
        };
        for bits in ((-0.0f32).to_bits()..=(-87.0f32).to_bits())
            .step_by(256)
            .chain((0..=88.0f32.to_bits()).step_by(256))
        {
            check(f32::from_bits(bits));
        }
        for bits in ((2.0f32.powi(-20)).to_bits()..=7.3f32.to_bits()).step_by(23) {
            check(-f32::from_bits(bits));
        }
        assert!(worst.0 <= EXP_MAX_ULP, "exp({:e}) off by {:.3} ulp", worst.1, worst.0);
        assert!(one(exp, f32::NAN).is_nan() && one(exp_unclamped, f32::NAN).is_nan());
        assert_eq!(one(exp, -1000.0), one(exp, -87.0));
        assert_eq!(one(exp, 0.0), 1.0);
        assert_eq!(one(exp, -0.0), 1.0);
        // Lanes are independent.
        assert_eq!(exp(f32x4::new([0.0, 1.0, f32::NAN, -1.0])).to_array()[3], one(exp, -1.0));
    }

    /// Every 61st positive normal f32 (≈ 35 M values, every exponent and mantissa region).
    #[test]
    fn ln_within_bound_of_f64() {
        let mut worst = (0.0f64, 0.0f32);
        for bits in (f32::MIN_POSITIVE.to_bits()..f32::INFINITY.to_bits()).step_by(61) {
            let x = f32::from_bits(bits);
            let e = ulps(one(ln, x), (x as f64).ln());
            if e > worst.0 {
                worst = (e, x);
            }
        }
        assert!(worst.0 <= LN_MAX_ULP, "ln({:e}) off by {:.3} ulp", worst.1, worst.0);
        assert!(one(ln, f32::NAN).is_nan());
        assert_eq!(one(ln, 1.0), 0.0);
    }

    /// Angles on a fine grid over the full circle (including the axes and the octant borders)
    /// at radii from 10⁻³ to 10⁶, plus the signed axes.
    #[test]
    fn atan2_within_bound_of_f64() {
        let mut worst = (0.0f64, 0.0f32, 0.0f32);
        let n = 200_003;
        for i in 0..n {
            let th = -std::f64::consts::PI + 2.0 * std::f64::consts::PI * (i as f64) / (n as f64);
            for r in [1e-3f64, 0.7, 3.0, 1234.5, 1e6] {
                let (y, x) = ((r * th.sin()) as f32, (r * th.cos()) as f32);
                let e = ulps(atan2_1(y, x), (y as f64).atan2(x as f64));
                if e > worst.0 {
                    worst = (e, y, x);
                }
            }
        }
        for (y, x) in [
            (1.0f32, 0.0f32),
            (-1.0, 0.0),
            (1.0, -0.0),
            (0.0, 1.0),
            (-0.0, 1.0),
            (0.0, -1.0),
            (-0.0, -1.0),
            (1.0, 1.0),
            (-1.0, -1.0),
        ] {
            let (got, want) = (atan2_1(y, x), y.atan2(x));
            assert_eq!(got.is_sign_negative(), want.is_sign_negative(), "sign of atan2({y}, {x})");
            let e = ulps(got, (y as f64).atan2(x as f64));
            if e > worst.0 {
                worst = (e, y, x);
            }
        }
        assert!(
            worst.0 <= ATAN2_MAX_ULP,
            "atan2({:e}, {:e}) off by {:.3} ulp",
            worst.1,
            worst.2,
            worst.0
        );
        assert!(atan2_1(f32::NAN, 1.0).is_nan() && atan2_1(1.0, f32::NAN).is_nan());
    }
}
