//! The depth-range clip (`kfuse fuse --depth-range MIN..MAX`, Python's `depth_range=`, the
//! viewer's slider): depth values outside `MIN..=MAX` metres are not samples. Part of H1's
//! sample rule ([`super::pixel::is_sample_in`]), so it holds on every engine: the CPU engine
//! clips a frame's depth before H1 ([`DepthRange::clip`]), the GPU's back-projection shader
//! tests the same rule per pixel.

use std::borrow::Cow;

use serde::Serialize;

use super::pixel::is_sample_in;
use crate::{GeometryError, Image};

/// Largest depth a range may name, metres: 1000. No depth camera measures a kilometre; an end
/// above it is a unit mistake (millimetres written as metres).
pub const MAX_RANGE_M: f32 = 1000.0;

/// The depth values that count as samples: `min_m <= value <= max_m`, metres (on top of the
/// rule that a sample is positive and finite). [`DepthRange::ALL`] keeps every sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DepthRange {
    /// Nearest kept depth, metres (0: no near limit).
    pub min_m: f32,
    /// Farthest kept depth, metres (`f32::MAX`: no far limit; a finite number, so that a GPU
    /// uniform never holds an infinity).
    pub max_m: f32,
}

impl Default for DepthRange {
    fn default() -> Self {
        Self::ALL
    }
}

impl DepthRange {
    /// No clip: every positive finite value is a sample.
    pub const ALL: DepthRange = DepthRange { min_m: 0.0, max_m: f32::MAX };

    /// The range `min_m..=max_m` metres.
    ///
    /// Error ([`GeometryError::InvalidInput`]): an end that is not a finite number in
    /// `0..=`[`MAX_RANGE_M`], or `min_m > max_m`.
    pub fn new(min_m: f32, max_m: f32) -> Result<Self, GeometryError> {
        for (what, v) in [("near end", min_m), ("far end", max_m)] {
            if !(0.0..=MAX_RANGE_M).contains(&v) {
                return Err(GeometryError::InvalidInput(format!(
                    "depth range {what} {v} m is outside 0..{MAX_RANGE_M} m"
                )));
            }
        }
        if min_m > max_m {
            return Err(GeometryError::InvalidInput(format!(
                "depth range {min_m}..{max_m} m: the near end is beyond the far end; give MIN..MAX"
            )));
        }
        Ok(Self { min_m, max_m })
    }

    /// Whether this range keeps every sample.
    pub fn is_all(&self) -> bool {
        *self == Self::ALL
    }

    /// Whether `value` (metres) is a sample under this range.
    #[inline]
    pub fn contains(&self, value: f32) -> bool {
        is_sample_in(value, *self)
    }

    /// `depth` with every value this range does not keep set to NaN (no sample); borrowed
    /// unchanged for [`DepthRange::ALL`].
    pub fn clip<'a>(&self, depth: &'a Image<f32>) -> Cow<'a, Image<f32>> {
        if self.is_all() {
            return Cow::Borrowed(depth);
        }
        let mut out = depth.clone();
        for v in out.data_mut() {
            if !self.contains(*v) {
                *v = f32::NAN;
            }
        }
        Cow::Owned(out)
    }

    /// [`DepthRange::clip`] into `out` (reused, resized to `depth`'s size): no allocation
    /// once `out` has that size.
    pub fn clip_into(&self, depth: &Image<f32>, out: &mut Image<f32>) {
        let (w, h) = depth.size();
        if out.size() != (w, h) {
            *out = Image::filled(w, h, f32::NAN);
        }
        for (o, &v) in out.data_mut().iter_mut().zip(depth.data()) {
            *o = if self.contains(v) { v } else { f32::NAN };
        }
    }

    /// Parses `MIN..MAX` with a unit, `m` or `mm`, on each end or once at the end for both:
    /// `0.5m..2m`, `500mm..2000mm`, `0.5..2m`.
    ///
    /// Error: the text, what is wrong, and an example.
    pub fn parse(text: &str) -> Result<Self, GeometryError> {
        let bad = |why: String| {
            GeometryError::InvalidInput(format!(
                "depth range '{text}': {why}; give MIN..MAX with a unit, e.g. 0.5m..2m or 500mm..2000mm"
            ))
        };
        let Some((a, b)) = text.trim().split_once("..") else {
            return Err(bad("no '..' between the two ends".into()));
        };
        let (b_val, b_unit) = split_unit(b.trim());
        let (a_val, a_unit) = split_unit(a.trim());
        let Some(unit) = b_unit.or(a_unit) else {
            return Err(bad("no unit (m or mm)".into()));
        };
        let a_unit = a_unit.unwrap_or(unit);
        let number =
            |s: &str| s.trim().parse::<f64>().map_err(|_| bad(format!("'{s}' is not a number")));
        let (min, max) = (number(a_val)? * a_unit, number(b_val)? * unit);
        Self::new(min as f32, max as f32).map_err(|e| bad(e.to_string()))
    }
}

/// A number and its unit's metres (`m`: 1, `mm`: 0.001), `None` without a unit.
fn split_unit(s: &str) -> (&str, Option<f64>) {
    if let Some(v) = s.strip_suffix("mm") {
        (v, Some(1e-3))
    } else if let Some(v) = s.strip_suffix('m') {
        (v, Some(1.0))
    } else {
        (s, None)
    }
}

impl std::fmt::Display for DepthRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}..{} m", self.min_m, self.max_m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_metres_and_millimetres() {
        assert_eq!(DepthRange::parse("0.5m..2m").unwrap(), DepthRange::new(0.5, 2.0).unwrap());
        assert_eq!(DepthRange::parse("0.5..2m").unwrap(), DepthRange::new(0.5, 2.0).unwrap());
        let mm = DepthRange::parse("500mm..2500mm").unwrap();
        assert_eq!((mm.min_m, mm.max_m), (0.5, 2.5));
        assert_eq!(DepthRange::parse(" 500..2500mm ").unwrap(), mm);
        for bad in ["0.5..2", "2m..0.5m", "0.5m-2m", "a..2m", "0..5000m", "-1m..2m"] {
            assert!(DepthRange::parse(bad).is_err(), "{bad}");
        }
        let e = DepthRange::parse("0.5..2").unwrap_err().to_string();
        assert!(e.contains("no unit") && e.contains("0.5m..2m"), "{e}");
    }

    #[test]
    fn clip_keeps_the_ends_and_drops_the_rest() {
        let r = DepthRange::new(1.0, 2.0).unwrap();
        let d = Image::from_vec(6, 1, vec![0.999, 1.0, 1.5, 2.0, 2.001, 0.0]).unwrap();
        let c = r.clip(&d);
        let kept: Vec<bool> = c.data().iter().map(|v| !v.is_nan()).collect();
        assert_eq!(kept, [false, true, true, true, false, false]);
        assert!(matches!(DepthRange::ALL.clip(&d), Cow::Borrowed(_)));
    }
}
