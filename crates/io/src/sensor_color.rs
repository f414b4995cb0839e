//! The Kinect v2's colour JPEG, which the sensor streams mirrored left–right, brought into kfuse's
//! image orientation (as the scene is; `kinect_usb::orientation`). The depth and IR are
//! mirrored by the decoder; the colour frame is a JPEG, so it is decoded, mirrored and, where
//! a file is written, encoded again.
//!
//! A baseline JPEG can be mirrored without loss only in the DCT domain (libjpeg's `jpegtran
//! -flip horizontal`); no maintained pure-Rust crate does that, and a C library would put a
//! system dependency on every build, so the mirrored frame is encoded anew at
//! [`MIRRORED_JPEG_QUALITY`].

use geometry::Image;

/// JPEG quality of a mirrored colour frame. The sensor's own frames are of quality ~90
/// (protocol §5; the simulator uses 90–92); re-encoding at 95 adds about one grey level of RMS
/// error (measured in `mirrored_jpeg_is_the_mirror_of_the_sensor_frame`), far below the
/// sensor's noise, at ~1.6× the sensor frame's size.
pub const MIRRORED_JPEG_QUALITY: u8 = 95;

/// The sensor's colour JPEG decoded into RGB, mirrored into the scene orientation, through
/// [`crate::images::decode_color_noting`] (the one reader, which refuses a JPEG cut short
/// rather than filling it with grey). The error is one line naming "the sensor's colour frame".
pub fn decode_mirrored(jpeg: &[u8]) -> Result<Image<[u8; 3]>, String> {
    let name = std::path::Path::new("the sensor's colour frame");
    let (mut img, _) = crate::images::decode_color_noting(name, jpeg).map_err(|e| e.to_string())?;
    let (w, _) = img.size();
    for row in img.data_mut().chunks_exact_mut(w.max(1)) {
        row.reverse();
    }
    Ok(img)
}

/// An RGB image encoded as a baseline JPEG at [`MIRRORED_JPEG_QUALITY`].
pub fn encode_jpeg(rgb: &Image<[u8; 3]>) -> Result<Vec<u8>, String> {
    let (w, h) = rgb.size();
    let raw: Vec<u8> = rgb.data().iter().flat_map(|p| p.iter().copied()).collect();
    let mut out = Vec::with_capacity(raw.len() / 8);
    let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, MIRRORED_JPEG_QUALITY);
    image::ImageEncoder::write_image(enc, &raw, w as u32, h as u32, image::ExtendedColorType::Rgb8)
        .map_err(|e| format!("the colour JPEG does not encode: {e}"))?;
    Ok(out)
}

/// The sensor's colour JPEG as a JPEG in the scene orientation ([`decode_mirrored`] then
/// [`encode_jpeg`]).
pub fn mirrored_jpeg(jpeg: &[u8]) -> Result<Vec<u8>, String> {
    encode_jpeg(&decode_mirrored(jpeg)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A left–right asymmetric test frame (a gradient and a block on the left) as the sensor
    /// would send it, mirrored, at the sensor's quality.
    fn sensor_frame(w: usize, h: usize) -> (Image<[u8; 3]>, Vec<u8>) {
        let scene = Image::from_fn(w, h, |x, y| {
            let block = x < w / 4 && y > h / 3 && y < 2 * h / 3;
            let g = (x * 255 / w) as u8;
            if block { [250, 20, 20] } else { [g, (y * 255 / h) as u8, 128] }
        });
        let mut sensor = scene.clone();
        let (sw, _) = sensor.size();
        for row in sensor.data_mut().chunks_exact_mut(sw) {
            row.reverse();
        }
        let mut jpeg = Vec::new();
        let raw: Vec<u8> = sensor.data().iter().flat_map(|p| p.iter().copied()).collect();
        let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90);
        image::ImageEncoder::write_image(
            enc,
            &raw,
            w as u32,
            h as u32,
            image::ExtendedColorType::Rgb8,
        )
        .unwrap();
        (scene, jpeg)
    }

    fn rms(a: &Image<[u8; 3]>, b: &Image<[u8; 3]>) -> f64 {
        let n = a.data().len() as f64 * 3.0;
        let s: f64 = a
            .data()
            .iter()
            .zip(b.data())
            .flat_map(|(p, q)| p.iter().zip(q).map(|(&x, &y)| (x as f64 - y as f64).powi(2)))
            .sum();
        (s / n).sqrt()
    }

    /// Tolerances: the sensor frame's own JPEG error (quality 90) is ~1–2 grey levels RMS on
    /// this frame; the mirrored one may add at most 1.5 more. The unmirrored decode is ~70
    /// levels off, so a missing or doubled mirror fails by far.
    #[test]
    fn mirrored_jpeg_is_the_mirror_of_the_sensor_frame() {
        let (scene, jpeg) = sensor_frame(320, 192);
        let decoded = decode_mirrored(&jpeg).unwrap();
        let direct = rms(&decoded, &scene);
        assert!(direct < 3.0, "decoded and mirrored: RMS {direct}");
        let plain = image::load_from_memory(&jpeg).unwrap().into_rgb8();
        let px = plain.into_raw().chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let unmirrored = Image::from_vec(320, 192, px).unwrap();
        assert!(rms(&unmirrored, &scene) > 30.0, "the test frame must be asymmetric");
        let again = mirrored_jpeg(&jpeg).unwrap();
        let reread = image::load_from_memory(&again).unwrap().into_rgb8();
        let px = reread.into_raw().chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let reread = Image::from_vec(320, 192, px).unwrap();
        let re = rms(&reread, &scene);
        assert!(re < direct + 1.5, "re-encoded: RMS {re} against {direct} before");
        let e = decode_mirrored(b"not a jpeg").unwrap_err();
        assert!(e.contains("the sensor's colour frame"), "{e}");
        // Cut short: refused, not filled with grey.
        let e = decode_mirrored(&jpeg[..jpeg.len() / 2]).unwrap_err();
        assert!(e.contains("the sensor's colour frame"), "{e}");
    }
}
