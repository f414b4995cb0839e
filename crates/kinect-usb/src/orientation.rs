//! Image orientation: which way left and right run in the images a consumer gets.
//!
//! The sensor's stream (depth, IR and colour alike, as libfreenect2 and its Protonect show
//! them) is **mirrored** left–right relative to the scene: a point on the scene's left shows on
//! the image's right. kfuse's rule is [`Orientation::Scene`], images as the scene is, as the
//! Kinect SDK, iai_kinect2 (which flips libfreenect2's images) and MATLAB give them; in it the
//! colour camera's centre lies at x ≈ +52 mm in the depth camera's frame. The decoder writes
//! this orientation by default ([`crate::decoder::DecoderConfig::orientation`]); the protocol's
//! test vectors and the factory registration of protocol §11 are in [`Orientation::Sensor`].
//!
//! Mirroring maps column `c` of a `w`-wide image to `w − 1 − c` (pixel centres at integer
//! coordinates), so a principal point `cx` becomes `w − 1 − cx`; rows are unchanged.

/// Which way left and right run in an image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Orientation {
    /// As the scene is (the Kinect SDK's, iai_kinect2's and MATLAB's images): kfuse's rule.
    #[default]
    Scene,
    /// As the sensor streams it: mirrored left–right (libfreenect2's raw output, protocol §9.8
    /// and §11, and `kfuse capture` before it mirrored its images).
    Sensor,
}

impl Orientation {
    /// The name written in files (`kinect_params.json`'s `image_orientation`).
    pub fn name(self) -> &'static str {
        match self {
            Orientation::Scene => "scene",
            Orientation::Sensor => "sensor",
        }
    }

    /// Parses [`Orientation::name`].
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "scene" => Some(Orientation::Scene),
            "sensor" => Some(Orientation::Sensor),
            _ => None,
        }
    }
}

/// Mirrors a row-major image of `width` columns left–right in place (each row reversed). A
/// trailing partial row (a length that is not a multiple of `width`) is left as it is.
pub fn mirror_rows<T>(pixels: &mut [T], width: usize) {
    if width == 0 {
        return;
    }
    for row in pixels.chunks_exact_mut(width) {
        row.reverse();
    }
}

/// The principal-point coordinate `c` of an image `size` pixels wide after mirroring.
pub fn mirror_coordinate(c: f32, size: usize) -> f32 {
    (size as f32 - 1.0) - c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mirroring_reverses_each_row_and_twice_is_identity() {
        let mut v: Vec<u32> = (0..12).collect();
        mirror_rows(&mut v, 4);
        assert_eq!(v, [3, 2, 1, 0, 7, 6, 5, 4, 11, 10, 9, 8]);
        mirror_rows(&mut v, 4);
        assert_eq!(v, (0..12).collect::<Vec<_>>());
        assert_eq!(mirror_coordinate(0.0, 512), 511.0);
        assert_eq!(mirror_coordinate(255.5, 512), 255.5);
        for o in [Orientation::Scene, Orientation::Sensor] {
            assert_eq!(Orientation::parse(o.name()), Some(o));
        }
    }
}
