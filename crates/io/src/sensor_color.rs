//! The Kinect v2's colour JPEG, which the sensor streams mirrored left–right, brought into kfuse's
//! image orientation (as the scene is; `kinect_usb::orientation`). The depth and IR are
//! mirrored by the decoder; the colour frame is a JPEG, so it is decoded, mirrored and, where
//! a file is written, encoded again.
//!
//! Where a JPEG is written ([`mirrored_jpeg`]: TUM's `rgb/`, capture shots), the frame is mirrored
//! without loss in the DCT domain, exactly as `jpegtran -flip horizontal` does (libjpeg-turbo's
//! transform, through the `turbojpeg` crate; byte for byte the same file, tested against Debian's
//! `jpegtran`): no pixel is decoded or quantised again, and it costs a fraction of a decode and
//! an encode. No maintained pure-Rust crate transforms JPEGs in the DCT domain, and writing the
//! entropy decoder, the coefficient flip and libjpeg's encoder again only to match its bytes
//! would be a second JPEG codec to keep; libjpeg-turbo is the reference implementation users
//! already run (the crate builds it from its bundled source with CMake and NASM, so there is no
//! system library to match). Only a frame whose width is not a multiple of its MCU width (not
//! the Kinect's 1920 pixels) cannot be flipped exactly this way: it is decoded, mirrored and
//! encoded anew at [`MIRRORED_JPEG_QUALITY`].

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

/// The sensor's colour JPEG as a JPEG in the scene orientation: [`flip_jpeg_lossless`] where the
/// frame's width allows it (every Kinect frame), else [`decode_mirrored`] then [`encode_jpeg`].
/// A damaged or cut-short JPEG is refused either way, with one line naming "the sensor's colour
/// frame".
pub fn mirrored_jpeg(jpeg: &[u8]) -> Result<Vec<u8>, String> {
    match flip_jpeg_lossless(jpeg)? {
        Some(flipped) => Ok(flipped),
        None => encode_jpeg(&decode_mirrored(jpeg)?),
    }
}

/// The JPEG mirrored left–right in the DCT domain, without decoding a pixel: the bytes
/// `jpegtran -flip horizontal` writes (same libjpeg transform; markers other than JFIF's are
/// copied, the entropy coding is the standard tables' as jpegtran's is). `Ok(None)` when the
/// image's width is not a whole number of MCUs, where the flip would not be exact (libjpeg's
/// "perfect" option refuses it; `jpegtran` would leave the right edge unflipped). Error: the
/// bytes are not a complete JPEG (checked first, as every reader does), or its data is damaged.
pub fn flip_jpeg_lossless(jpeg: &[u8]) -> Result<Option<Vec<u8>>, String> {
    let name = std::path::Path::new("the sensor's colour frame");
    crate::images::check_picture(name, jpeg).map_err(|e| e.to_string())?;
    let header = turbojpeg::read_header(jpeg)
        .map_err(|e| format!("{}: is not a JPEG libjpeg can read: {e}", name.display()))?;
    if header.width % mcu_width(header.subsamp) != 0 {
        return Ok(None);
    }
    let mut transform = turbojpeg::Transform::op(turbojpeg::TransformOp::Hflip);
    transform.perfect = true;
    turbojpeg::transform(&transform, jpeg)
        .map(|buf| Some(buf.to_vec()))
        .map_err(|e| format!("{}: a damaged JPEG ({e})", name.display()))
}

/// The width in pixels of one MCU (minimum coded unit) for a chroma subsampling: 8 pixels
/// without horizontal subsampling, 16 with 2× (4:2:2, 4:2:0), 32 with 4× (4:1:1).
fn mcu_width(subsamp: turbojpeg::Subsamp) -> usize {
    use turbojpeg::Subsamp;
    match subsamp {
        Subsamp::None | Subsamp::Gray | Subsamp::Sub1x2 | Subsamp::Sub1x4 => 8,
        Subsamp::Sub2x1 | Subsamp::Sub2x2 => 16,
        Subsamp::Sub4x1 => 32,
        // Not a standard sampling: no flip is exact by this rule; re-encode.
        _ => usize::MAX,
    }
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

    /// A 1920×1080 frame of the Kinect's size: left–right asymmetric, with texture in every
    /// block (gradients, a checker, a diagonal) so that each DCT coefficient's sign matters.
    fn kinect_sized_rgb() -> Vec<u8> {
        let (w, h) = (1920usize, 1080usize);
        let mut raw = Vec::with_capacity(w * h * 3);
        for y in 0..h {
            for x in 0..w {
                let checker = ((x / 7 + y / 5) % 2) as u8 * 60;
                let diag = if (x + 2 * y) % 97 < 9 { 120 } else { 0 };
                raw.extend([(x * 255 / w) as u8 ^ checker, (y % 256) as u8, diag + (x % 31) as u8]);
            }
        }
        raw
    }

    fn encode_image_crate(raw: &[u8], w: u32, h: u32, quality: u8) -> Vec<u8> {
        let mut jpeg = Vec::new();
        let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, quality);
        image::ImageEncoder::write_image(enc, raw, w, h, image::ExtendedColorType::Rgb8).unwrap();
        jpeg
    }

    /// The JPEG without its Huffman tables (DHT segments), as a motion-JPEG stream such as the
    /// Kinect v2's sends it: decoders take ITU-T T.81 Annex K's standard tables then.
    fn strip_dht(jpeg: &[u8]) -> Vec<u8> {
        let mut out = jpeg[..2].to_vec();
        let mut i = 2;
        while jpeg[i + 1] != 0xDA {
            let len = 2 + usize::from(u16::from_be_bytes([jpeg[i + 2], jpeg[i + 3]]));
            if jpeg[i + 1] != 0xC4 {
                out.extend_from_slice(&jpeg[i..i + len]);
            }
            i += len;
        }
        out.extend_from_slice(&jpeg[i..]);
        assert!(out.len() < jpeg.len(), "the test JPEG must have had DHT segments");
        out
    }

    /// The JPEGs of the lossless-flip tests: the image crate's without its Huffman tables, the image crate's encoder (4:2:2, what the
    /// simulator streams) at the sensor's quality, and libjpeg-turbo's at 4:2:0 and 4:4:4.
    fn kinect_sized_jpegs() -> Vec<(&'static str, Vec<u8>)> {
        let raw = kinect_sized_rgb();
        let tj = |subsamp| {
            let img = turbojpeg::Image {
                pixels: raw.as_slice(),
                width: 1920,
                pitch: 1920 * 3,
                height: 1080,
                format: turbojpeg::PixelFormat::RGB,
            };
            turbojpeg::compress(img, 90, subsamp).unwrap().to_vec()
        };
        let image_crate = encode_image_crate(&raw, 1920, 1080, 90);
        vec![
            (
                "image crate 4:2:2 q90, no DHT (motion-JPEG, as the Kinect streams)",
                strip_dht(&image_crate),
            ),
            ("image crate 4:2:2 q90", image_crate),
            ("libjpeg-turbo 4:2:0 q90", tj(turbojpeg::Subsamp::Sub2x2)),
            ("libjpeg-turbo 4:4:4 q90", tj(turbojpeg::Subsamp::None)),
        ]
    }

    /// `jpegtran -flip horizontal` (Debian's libjpeg-turbo-progs, a separate build of another
    /// libjpeg-turbo release) is the independent reference: the flip must give its file byte
    /// for byte. `.ci/run` installs it and sets `KFUSE_REQUIRE_JPEGTRAN`, so CI cannot skip.
    #[test]
    fn lossless_flip_equals_jpegtran_byte_for_byte() {
        let dir = std::env::temp_dir().join(format!("kfuse-jpegtran-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let probe = std::process::Command::new("jpegtran").arg("-version").output();
        if probe.is_err() {
            assert!(
                std::env::var_os("KFUSE_REQUIRE_JPEGTRAN").is_none(),
                "KFUSE_REQUIRE_JPEGTRAN is set but jpegtran does not run (apt-get install libjpeg-turbo-progs)"
            );
            test_skip::skip(
                "lossless_flip_equals_jpegtran_byte_for_byte",
                "jpegtran not installed (apt-get install libjpeg-turbo-progs)",
            );
            return;
        }
        for (what, jpeg) in kinect_sized_jpegs() {
            let input = dir.join("in.jpg");
            std::fs::write(&input, &jpeg).unwrap();
            let out = std::process::Command::new("jpegtran")
                .args(["-flip", "horizontal"])
                .arg(&input)
                .output()
                .unwrap();
            assert!(out.status.success(), "{what}: jpegtran failed: {:?}", out);
            let ours = flip_jpeg_lossless(&jpeg).unwrap().expect("1920 is a whole number of MCUs");
            assert!(ours != jpeg, "{what}: the flip must change the file");
            assert_eq!(ours.len(), out.stdout.len(), "{what}: length differs from jpegtran's");
            assert!(ours == out.stdout, "{what}: bytes differ from jpegtran -flip horizontal");
            assert_eq!(mirrored_jpeg(&jpeg).unwrap(), ours, "{what}: mirrored_jpeg takes the flip");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn decode_rgb(jpeg: &[u8]) -> (usize, Vec<u8>) {
        let img = image::load_from_memory(jpeg).unwrap().into_rgb8();
        (img.width() as usize, img.into_raw())
    }

    /// Decoding the flipped file (with the image crate's decoder, not libjpeg) gives the
    /// mirrored pixels of the original's decode within JPEG's rounding: the coefficients are
    /// the same up to sign, but the integer IDCT and the chroma upsampling round towards one
    /// side, so a level or two may differ (measured: at most 2 levels, mean 0.0001 levels on
    /// these frames; the bars 4 and 0.25). A missing flip is ~80 levels off on average.
    #[test]
    fn lossless_flip_decodes_to_the_mirrored_pixels() {
        // The image crate's decoder (used here as the reference) has no default Huffman
        // tables: the DHT-less frame is checked byte for byte against jpegtran, and its
        // decoding in `a_motion_jpeg_frame_without_huffman_tables_decodes`.
        for (what, jpeg) in kinect_sized_jpegs().into_iter().filter(|(w, _)| !w.contains("no DHT"))
        {
            let (w, original) = decode_rgb(&jpeg);
            let (w2, flipped) = decode_rgb(&flip_jpeg_lossless(&jpeg).unwrap().unwrap());
            assert_eq!(w, w2);
            let mut mirrored = original.clone();
            for row in mirrored.chunks_exact_mut(w * 3) {
                let mut px: Vec<[u8; 3]> =
                    row.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
                px.reverse();
                row.copy_from_slice(&px.concat());
            }
            let diff = |a: &[u8], b: &[u8]| {
                let max = a.iter().zip(b).map(|(&x, &y)| x.abs_diff(y)).max().unwrap();
                let mean = a.iter().zip(b).map(|(&x, &y)| f64::from(x.abs_diff(y))).sum::<f64>()
                    / a.len() as f64;
                (max, mean)
            };
            let (max, mean) = diff(&flipped, &mirrored);
            eprintln!("{what}: mirrored decode vs decode of the flip: max {max}, mean {mean:.4}");
            assert!(max <= 4 && mean < 0.25, "{what}: max {max}, mean {mean}");
            let (_, unflipped_mean) = diff(&flipped, &original);
            assert!(
                unflipped_mean > 20.0,
                "{what}: the frame must be asymmetric ({unflipped_mean})"
            );
        }
    }

    /// A width that is not a whole number of MCUs (100 pixels at 4:2:2, MCU 16) cannot be
    /// flipped exactly in the DCT domain: no lossless result, and `mirrored_jpeg` re-encodes,
    /// still the mirror of the frame. A damaged middle is refused, not passed on.
    #[test]
    fn partial_mcu_widths_are_reencoded_and_damage_is_refused() {
        let (scene, jpeg) = sensor_frame(100, 64);
        assert_eq!(flip_jpeg_lossless(&jpeg).unwrap(), None);
        let again = mirrored_jpeg(&jpeg).unwrap();
        let (w, px) = decode_rgb(&again);
        let px = px.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        assert!(rms(&Image::from_vec(w, 64, px).unwrap(), &scene) < 4.0);
        let e = flip_jpeg_lossless(&jpeg[..jpeg.len() / 2]).unwrap_err();
        assert!(e.contains("the sensor's colour frame"), "{e}");
        assert!(flip_jpeg_lossless(b"not a jpeg").is_err());
    }

    /// Largest difference, levels, between libjpeg-turbo's and the image crate's decodes of one
    /// frame: their integer IDCTs round differently (measured 3 on this frame); a wrong table
    /// or a lost block is tens of levels off.
    const MOTION_JPEG_MAX_LEVELS: u8 = 4;
    /// Mean difference, levels (measured 0.013).
    const MOTION_JPEG_MEAN_LEVELS: f64 = 0.1;

    /// A motion-JPEG frame (no DHT segment, as a Kinect may stream it) decodes through kfuse's
    /// one reader (`decode_mirrored` → `images::decode_color_noting`): the image crate's
    /// decoder refuses it (no default tables), libjpeg-turbo decodes it with T.81's standard
    /// tables. Compared with the image crate's decode of the same frame with its tables: the
    /// coefficients are identical, only the two decoders' integer IDCTs round differently
    /// (measured: at most 3 levels, mean 0.013). Without the fallback the frame is an
    /// error ("corrupt or unsupported Jpeg image").
    #[test]
    fn a_motion_jpeg_frame_without_huffman_tables_decodes() {
        let raw = kinect_sized_rgb();
        let jpeg = encode_image_crate(&raw, 1920, 1080, 90);
        let motion = strip_dht(&jpeg);
        assert!(image::load_from_memory(&motion).is_err(), "the image crate decodes it now");
        let reference = decode_mirrored(&jpeg).unwrap();
        let decoded = decode_mirrored(&motion).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(decoded.size(), (1920, 1080));
        let (a, b) = (reference.data(), decoded.data());
        let pairs = a.iter().zip(b).flat_map(|(p, q)| p.iter().zip(q));
        let (mut max, mut sum, mut n) = (0u8, 0u64, 0u64);
        for (&x, &y) in pairs {
            max = max.max(x.abs_diff(y));
            sum += u64::from(x.abs_diff(y));
            n += 1;
        }
        let mean = sum as f64 / n as f64;
        eprintln!("motion-JPEG decode vs the decode with tables: max {max}, mean {mean:.4}");
        assert!(
            max <= MOTION_JPEG_MAX_LEVELS && mean < MOTION_JPEG_MEAN_LEVELS,
            "max {max}, mean {mean}"
        );
    }
}
