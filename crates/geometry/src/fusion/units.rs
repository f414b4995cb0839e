//! Depth in the wrong unit, told before any fusion work: one rule for `kfuse fuse`, the
//! Python package's `fuse`/`Registration` and every other caller of the fusion. A whole frame
//! whose median depth lies outside [`MIN_MEDIAN_DEPTH_M`]..[`MAX_MEDIAN_DEPTH_M`] is a unit
//! mistake, not a scene: it would otherwise fuse at 65 m (a 65 535 fill), or land nowhere
//! (metres read as millimetres), with no word.
//!
//! The median, not the extremes: one flying pixel does not hide a whole frame in the wrong
//! unit (the Python package's earlier test of the largest sample did).

use crate::Image;

/// Shortest plausible median depth, metres: 0.2. The Kinect v2 measures from 0.5 m, the
/// closest depth cameras from about 0.1-0.2 m; a whole frame whose median is nearer is metres
/// read as millimetres (or kilometres), or micrometre-scaled millimetres.
pub const MIN_MEDIAN_DEPTH_M: f64 = 0.2;
/// Longest plausible median depth, metres: 15. The Kinect v2 ends at 4.5 m (8 m at most),
/// ToF and stereo depth cameras at about 10 m; millimetres read as metres give medians of
/// hundreds to thousands of "metres", and a frame of 65 535 (a 16-bit fill) 65.5.
pub const MAX_MEDIAN_DEPTH_M: f64 = 15.0;

/// The median of every `stride`-th pixel's valid (finite, positive) sample, metres; `None`
/// when there is none. `stride` 1 is the exact median; a stream of frames may look at a
/// sample (the Python `Registration` takes every 7th pixel: about 31 000 of a Kinect frame).
pub fn median_depth(depth: &Image<f32>, stride: usize) -> Option<f64> {
    let mut v: Vec<f32> = depth
        .data()
        .iter()
        .step_by(stride.max(1))
        .copied()
        .filter(|d| d.is_finite() && *d > 0.0)
        .collect();
    if v.is_empty() {
        return None;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f32::total_cmp);
    Some(*m as f64)
}

/// Whether [`median_depth`] (the same sample, the same element) is under `under` and over
/// `over` metres, found by counting in one pass, without collecting or sorting the sample: a
/// stream of frames checks each frame's unit for a few microseconds, and computes the median
/// itself only for a frame outside the band (to say what it is). `None` when there is no
/// valid sample.
///
/// The median is element `n / 2` of the `n` valid samples sorted, so it is under `under`
/// exactly when more than `n / 2` samples are, and over `over` exactly when at least
/// `n - n / 2` samples are.
pub fn median_outside(
    depth: &Image<f32>,
    stride: usize,
    under: f64,
    over: f64,
) -> Option<(bool, bool)> {
    let (mut n, mut below, mut above) = (0usize, 0usize, 0usize);
    for &d in depth.data().iter().step_by(stride.max(1)) {
        if d.is_finite() && d > 0.0 {
            n += 1;
            below += usize::from(f64::from(d) < under);
            above += usize::from(f64::from(d) > over);
        }
    }
    (n > 0).then(|| (below > n / 2, above >= n - n / 2))
}

/// Nearest depth the Kinect v2 measures, metres: 0.5 (its specification; its depth images
/// hold no sample nearer). A Kinect frame whose median is nearer is most likely depth in
/// centimetres read as millimetres (a 1.5 m wall reads 0.15 m; 2.9 m reads 0.29 m, which
/// [`MIN_MEDIAN_DEPTH_M`] lets through). Only warned about: a hand in front of the sensor
/// makes such a frame too.
pub const KINECT_MIN_DEPTH_M: f64 = 0.5;

/// A frame's depth in a unit the fusion does not read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DepthUnitProblem {
    /// The median depth (metres) is over [`MAX_MEDIAN_DEPTH_M`].
    TooFar(f64),
    /// The median depth (metres) is under [`MIN_MEDIAN_DEPTH_M`].
    TooNear(f64),
}

impl DepthUnitProblem {
    /// The median depth, metres.
    pub fn median_m(self) -> f64 {
        match self {
            DepthUnitProblem::TooFar(m) | DepthUnitProblem::TooNear(m) => m,
        }
    }
}

impl std::fmt::Display for DepthUnitProblem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // The median is one of the frame's f32 samples: written as that f32's shortest text
        // (65.535, not 65.53499984741211), in scientific notation outside num_fmt's range.
        let m32 = self.median_m() as f32;
        let plain =
            (crate::num_fmt::MIN_PLAIN..crate::num_fmt::MAX_PLAIN).contains(&f64::from(m32.abs()));
        let m = if plain { format!("{m32}") } else { format!("{m32:e}") };
        match self {
            DepthUnitProblem::TooFar(_) => {
                write!(f, "median depth {m} m is over {MAX_MEDIAN_DEPTH_M} m")
            }
            DepthUnitProblem::TooNear(_) => {
                write!(f, "median depth {m} m is under {MIN_MEDIAN_DEPTH_M} m")
            }
        }
    }
}

/// The unit problem of a depth frame in metres (median of every `stride`-th pixel, see
/// [`median_depth`]), `None` when plausible or empty (an empty frame is not a unit mistake).
pub fn depth_unit_problem(depth: &Image<f32>, stride: usize) -> Option<DepthUnitProblem> {
    unit_problem_of_median(median_depth(depth, stride)?)
}

/// The unit problem of a frame whose median depth is `median` metres.
pub fn unit_problem_of_median(median: f64) -> Option<DepthUnitProblem> {
    if median > MAX_MEDIAN_DEPTH_M {
        Some(DepthUnitProblem::TooFar(median))
    } else if median < MIN_MEDIAN_DEPTH_M {
        Some(DepthUnitProblem::TooNear(median))
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 512×424 frame of `value` metres with every 50th pixel set to `flying` and a third
    /// of the pixels empty.
    fn frame(value: f32, flying: f32) -> Image<f32> {
        let mut data = vec![value; 512 * 424];
        for (i, d) in data.iter_mut().enumerate() {
            if i % 50 == 0 {
                *d = flying;
            } else if i % 3 == 0 {
                *d = if i % 2 == 0 { 0.0 } else { f32::NAN };
            }
        }
        Image::from_vec(512, 424, data).unwrap()
    }

    #[test]
    fn median_outside_agrees_with_the_sorted_median() {
        // Frames whose sample sizes are odd and even and whose medians sit exactly on, just
        // under and just over the limits: the counted answer equals comparing the median
        // that median_depth sorts out.
        let limits = [0.2, 0.5, 15.0, 1.0];
        for n in [1usize, 2, 3, 4, 7, 10, 101] {
            for centre in [0.1f32, 0.2, 0.5, 0.7, 15.0, 15.5, 1.0] {
                let frame = Image::from_fn(n, 3, |x, y| match (x + y) % 5 {
                    0 => f32::NAN,
                    1 => centre,
                    2 => centre * 0.5,
                    3 => centre * 2.0,
                    _ => 0.0,
                });
                for stride in [1, 2, 3] {
                    let Some(m) = median_depth(&frame, stride) else {
                        assert_eq!(median_outside(&frame, stride, 0.2, 15.0), None);
                        continue;
                    };
                    for &under in &limits {
                        for &over in &limits {
                            assert_eq!(
                                median_outside(&frame, stride, under, over),
                                Some((m < under, m > over)),
                                "n {n} centre {centre} stride {stride} median {m}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn the_median_tells_the_unit_whatever_a_few_pixels_say() {
        // 1.5 m in millimetres read as metres, in metres read as millimetres, a 65 535 fill.
        assert_eq!(
            depth_unit_problem(&frame(1500.0, 0.8), 1),
            Some(DepthUnitProblem::TooFar(1500.0))
        );
        assert_eq!(
            depth_unit_problem(&frame(0.0015, 25.0), 1),
            Some(DepthUnitProblem::TooNear(0.0015f32 as f64))
        );
        assert_eq!(
            depth_unit_problem(&frame(65.535, 1.0), 7),
            Some(DepthUnitProblem::TooFar(65.535f32 as f64))
        );
        // Plausible scenes, with flying pixels at either end; strided the same.
        for stride in [1, 7] {
            assert_eq!(depth_unit_problem(&frame(1.5, 60.0), stride), None);
            assert_eq!(depth_unit_problem(&frame(0.6, 0.001), stride), None);
            assert_eq!(depth_unit_problem(&frame(14.0, 0.001), stride), None);
        }
        // The band's ends are plausible; an empty frame has no unit.
        assert_eq!(depth_unit_problem(&frame(MIN_MEDIAN_DEPTH_M as f32, 1.0), 1), None);
        assert_eq!(depth_unit_problem(&frame(MAX_MEDIAN_DEPTH_M as f32, 1.0), 1), None);
        assert_eq!(depth_unit_problem(&Image::filled(8, 8, f32::NAN), 1), None);
        let shown = DepthUnitProblem::TooFar(65.535f32 as f64).to_string();
        assert_eq!(shown, "median depth 65.535 m is over 15 m");
        let shown = DepthUnitProblem::TooNear(0.0013f32 as f64).to_string();
        assert_eq!(shown, "median depth 0.0013 m is under 0.2 m");
        let shown = DepthUnitProblem::TooFar(3e30).to_string();
        assert_eq!(shown, "median depth 3e30 m is over 15 m");
    }
}
