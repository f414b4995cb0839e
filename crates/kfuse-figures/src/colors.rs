//! Depth, masks and overlays as colour images: one colour map ([`colormap`], viridis) and one
//! robust range ([`robust_range`]) for the CLI's figures and the viewer's panes.

use geometry::Image;

/// Colour map for depth (a perceptually ordered blue → green → yellow ramp, viridis-like):
/// `t` in 0..1.
pub fn colormap(t: f32) -> [u8; 3] {
    // Viridis anchors at t = 0, .25, .5, .75, 1.
    const STOPS: [[f32; 3]; 5] = [
        [68.0, 1.0, 84.0],
        [59.0, 82.0, 139.0],
        [33.0, 145.0, 140.0],
        [94.0, 201.0, 98.0],
        [253.0, 231.0, 37.0],
    ];
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    let x = t * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f32;
    let a = STOPS[i];
    let b = STOPS[i + 1];
    [0, 1, 2].map(|k| (a[k] + (b[k] - a[k]) * f).round() as u8)
}

/// Lower percentile of [`robust_range`]: the 2 % nearest samples (noise, flying pixels at
/// object edges) do not stretch the colour scale.
pub const RANGE_LOW_PERCENT: usize = 2;
/// Upper percentile of [`robust_range`] (2 % farthest samples clipped, as for the low end).
pub const RANGE_HIGH_PERCENT: usize = 98;

/// The [`RANGE_LOW_PERCENT`] and [`RANGE_HIGH_PERCENT`] percentiles of the finite positive
/// values (a depth of 0 or below is no sample), or `None` when there are none. A range of
/// one value is widened to 1 mm.
pub fn robust_range(values: impl Iterator<Item = f32>) -> Option<(f32, f32)> {
    let mut v: Vec<f32> = values.filter(|d| d.is_finite() && *d > 0.0).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f32::total_cmp);
    let lo = v[v.len() * RANGE_LOW_PERCENT / 100];
    let hi = v[(v.len() * RANGE_HIGH_PERCENT / 100).min(v.len() - 1)];
    Some(if hi > lo { (lo, hi) } else { (lo, lo + 1e-3) })
}

/// Depth (metres) as colours over `range` (the image's [`robust_range`] when `None`): near =
/// dark blue, far = yellow; no sample (NaN, 0 or below) = black.
pub fn depth_colors(depth: &Image<f32>, range: Option<(f32, f32)>) -> Image<[u8; 3]> {
    let (lo, hi) =
        range.or_else(|| robust_range(depth.data().iter().copied())).unwrap_or((0.0, 1.0));
    depth
        .map(|&d| if d.is_finite() && d > 0.0 { colormap((d - lo) / (hi - lo)) } else { [0, 0, 0] })
}

/// Depth reduced by `factor` in each direction keeping the nearest valid sample of each
/// block: sparse depth (a z-buffer) stays visible when a figure shrinks it.
pub fn downsample_depth_min(depth: &Image<f32>, factor: usize) -> Image<f32> {
    let f = factor.max(1);
    let (w, h) = depth.size();
    Image::from_fn(w.div_ceil(f), h.div_ceil(f), |x, y| {
        let mut best = f32::NAN;
        for yy in y * f..((y + 1) * f).min(h) {
            for xx in x * f..((x + 1) * f).min(w) {
                let d = *depth.get(xx, yy);
                if d.is_finite() && (best.is_nan() || d < best) {
                    best = d;
                }
            }
        }
        best
    })
}

/// A mask as an image: `true` = red over dark grey.
pub fn mask_colors(mask: &Image<bool>) -> Image<[u8; 3]> {
    mask.map(|&m| if m { [230, 40, 40] } else { [40, 40, 40] })
}

/// Depth blended over colour (`alpha` = weight of the depth colours where depth is valid).
pub fn depth_overlay(color: &Image<[u8; 3]>, depth: &Image<f32>, alpha: f32) -> Image<[u8; 3]> {
    let dc = depth_colors(depth, None);
    let (w, h) = color.size();
    Image::from_fn(w, h, |x, y| {
        let c = color.get(x, y);
        // Depth grids may differ in size from the colour image: sample the nearest pixel.
        let dx = (x * depth.width() / w).min(depth.width().saturating_sub(1));
        let dy = (y * depth.height() / h).min(depth.height().saturating_sub(1));
        if depth.get(dx, dy).is_finite() {
            let d = dc.get(dx, dy);
            [0, 1, 2].map(|k| (c[k] as f32 * (1.0 - alpha) + d[k] as f32 * alpha).round() as u8)
        } else {
            *c
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colormap_hits_the_viridis_anchors_and_clamps() {
        // matplotlib's viridis table × 255: t = 0 (0.267, 0.0049, 0.329) → (68, 1, 84); 0.5 (0.128,
        // 0.567, 0.551) → (33, 145, 140); 1 (0.993, 0.906, 0.144) → (253, 231, 37).
        assert_eq!(colormap(0.0), [68, 1, 84]);
        assert_eq!(colormap(0.5), [33, 145, 140]);
        assert_eq!(colormap(1.0), [253, 231, 37]);
        assert_eq!(colormap(-3.0), colormap(0.0));
        assert_eq!(colormap(7.0), colormap(1.0));
        assert_eq!(colormap(f32::NAN), colormap(0.0));
        // Half way between the first two anchors.
        // Hand calculation: ((68 + 59)/2, (1 + 82)/2, (84 + 139)/2) = (63.5, 41.5, 111.5), rounded
        // half away from zero.
        assert_eq!(colormap(0.125), [64, 42, 112]);
    }

    #[test]
    fn robust_range_is_the_2nd_and_98th_percentile_of_the_samples() {
        // 1..=100 m plus non-samples that must not count: 2 % → 3 m, 98 % → 99 m.
        let values = (1..=100).map(|i| i as f32).chain([f32::NAN, 0.0, -5.0, f32::INFINITY]);
        // Hand calculation: 100 samples sorted, indices 100 · 2 / 100 = 2 → 3 m and
        // 100 · 98 / 100 = 98 → 99 m; one repeated value is widened by the documented 1 mm.
        assert_eq!(robust_range(values), Some((3.0, 99.0)));
        assert_eq!(robust_range([2.0f32; 10].into_iter()), Some((2.0, 2.001)));
        assert_eq!(robust_range([f32::NAN, 0.0].into_iter()), None);
    }

    #[test]
    fn depth_colors_black_out_non_samples() {
        let depth = Image::from_vec(4, 1, vec![1.0, 2.0, f32::NAN, 0.0]).unwrap();
        let c = depth_colors(&depth, Some((1.0, 2.0)));
        assert_eq!(c.data(), &[colormap(0.0), colormap(1.0), [0, 0, 0], [0, 0, 0]]);
    }
}
