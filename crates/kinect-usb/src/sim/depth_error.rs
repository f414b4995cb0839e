//! A depth error the simulated sensor applies on purpose (issue 16): the time-of-flight
//! camera's measured z is `(1 + scale)·z + offset + radial·ρ²` with `ρ² = ((u−uc)² + (v−vc)²)
//! / (uc² + vc²)`, `uc = (W−1)/2`, `vc = (H−1)/2` (1 at the image's corner pixels, 0 at its
//! centre). These are the definitions of kfuse's depth-correction model (`geometry::
//! depth_correction`, terms `offset`, `scale`, `radial2`), written here again because this crate
//! depends on nothing of kfuse's: `kfuse calibrate --depth` must find these three numbers.

use crate::raw::{HEIGHT, WIDTH};

/// The error of the Kinect v2's depth libfreenect2's users measured (issue 144: "always 24 mm
/// further away than it should be", growing towards the corners), with a 0.5 % scale; what
/// `--sim-depth-error default` injects.
pub const KINECT_LIKE: DepthError = DepthError { offset_mm: 24.0, scale: 0.005, radial_mm: 10.0 };

/// The injected error (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DepthError {
    /// Constant offset, millimetres (positive: the sensor reads too far).
    pub offset_mm: f64,
    /// Relative scale of the true z (0.005 = 0.5 %).
    pub scale: f64,
    /// Extra offset at the image's corners, growing with ρ², millimetres.
    pub radial_mm: f64,
}

impl DepthError {
    /// The measured z (mm) of true z `z_mm` at depth pixel `(u, v)` of a 512 × 424 image.
    pub fn measured(&self, u: f64, v: f64, z_mm: f64) -> f64 {
        let (uc, vc) = ((WIDTH as f64 - 1.0) / 2.0, (HEIGHT as f64 - 1.0) / 2.0);
        let rho2 = ((u - uc).powi(2) + (v - vc).powi(2)) / (uc * uc + vc * vc);
        (1.0 + self.scale) * z_mm + self.offset_mm + self.radial_mm * rho2
    }

    /// Applies the error to a 512 × 424 depth frame in millimetres (row-major); invalid
    /// samples (0 or not finite) stay invalid.
    pub fn apply(&self, depth_mm: &mut [f32]) {
        for (i, z) in depth_mm.iter_mut().enumerate().take(WIDTH * HEIGHT) {
            if *z > 0.0 && z.is_finite() {
                let (u, v) = ((i % WIDTH) as f64, (i / WIDTH) as f64);
                *z = self.measured(u, v, f64::from(*z)) as f32;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// At the image centre only offset and scale act; at a corner pixel the radial term adds
    /// its full value; zeros stay zeros.
    #[test]
    fn the_error_has_its_stated_values() {
        let e = KINECT_LIKE;
        assert!((e.measured(255.5, 211.5, 1000.0) - 1029.0).abs() < 1e-9);
        assert!((e.measured(0.0, 423.0, 2000.0) - (2010.0 + 24.0 + 10.0)).abs() < 1e-9);
        let mut d = vec![1000.0f32; WIDTH * HEIGHT];
        d[5] = 0.0;
        e.apply(&mut d);
        assert_eq!(d[5], 0.0);
        assert!((d[0] - 1039.0).abs() < 1e-3, "{}", d[0]);
    }
}
