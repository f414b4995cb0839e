//! Numbers in messages and reports: read from files, they can be anything, and Rust's `{}` and
//! `{:.3}` write every digit of `1e300` (301 of them) or `1e-300`. Every message that prints a
//! value read from a file goes through [`num`] or [`fixed`].

/// Smallest |x| written positionally by [`num`]: 1e-4 (below, `0.0001234` reads worse than
/// `1.234e-4`).
pub const MIN_PLAIN: f64 = 1e-4;
/// Largest |x| written positionally by [`num`] and [`fixed`]: 1e9 (a 16384-px image side, a
/// focal length of 20 000 px and a millimetre value of a metre-scale rig are far below; above is
/// a unit or typing mistake, better read as `1.5e12`).
pub const MAX_PLAIN: f64 = 1e9;

/// `x` as Rust's shortest text that reads back to the same `f64` (`{}`), switching to
/// scientific notation (`1e300`, `-2.5e-7`) outside `MIN_PLAIN..MAX_PLAIN`; 0, NaN and
/// infinities as `{}` writes them.
pub fn num(x: f64) -> String {
    let a = x.abs();
    if !x.is_finite() || x == 0.0 || (MIN_PLAIN..MAX_PLAIN).contains(&a) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// `x` with `decimals` digits after the point (`{:.N}`), or in scientific notation with 3
/// decimals (`1.000e300`) when |x| ≥ [`MAX_PLAIN`]; NaN and infinities as `{}` writes them.
pub fn fixed(x: f64, decimals: usize) -> String {
    if x.is_finite() && x.abs() >= MAX_PLAIN {
        format!("{x:.3e}")
    } else {
        format!("{x:.decimals$}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The texts against hand-written expectations; `1e300` was 301 characters before.
    #[test]
    fn huge_and_tiny_numbers_are_short() {
        assert_eq!(num(1e300), "1e300");
        assert_eq!(num(-2.5e-300), "-2.5e-300");
        assert_eq!(num(365.25), "365.25");
        assert_eq!(num(0.052), "0.052");
        assert_eq!(num(0.0), "0");
        assert_eq!(num(f64::NAN), "NaN");
        assert_eq!(fixed(1e300, 3), "1.000e300");
        assert_eq!(fixed(1059.31234, 3), "1059.312");
        assert_eq!(fixed(-1e-300, 3), "-0.000");
        for x in [1e300, -1e300, 1e-300, f64::MAX, f64::MIN_POSITIVE] {
            assert!(
                num(x).len() <= 24 && fixed(x, 6).len() <= 24,
                "{x}: {} {}",
                num(x),
                fixed(x, 6)
            );
        }
    }
}
