//! Colour, depth and mask images on disk.
//!
//! * **Colour**: PNG, JPEG, TIFF or BMP, 8- or 16-bit, grey / RGB / RGBA → `Image<[u8; 3]>`
//!   (16-bit channels are scaled to 8 bits, alpha dropped, grey replicated).
//! * **Grey for detection** ([`read_gray`]): the same files → `Image<u8>`, luma of colour;
//!   16-bit grey scaled by its largest value.
//! * **Depth**, read into metres with `NaN` for "no sample":
//!   - 16-bit grey PNG or TIFF, integer units (Kinect: millimetres, `metres_per_unit = 0.001`);
//!     `0` means no sample;
//!   - 32-bit float grey TIFF or single-channel OpenEXR (`Y`, `Z`, `R` or `depth` channel, or
//!     the only channel) in metres; `NaN`, `±∞` and values ≤ 0 mean no sample.
//!
//!   8-bit images are refused: they are pictures of depth, not measurements.
//! * **Depth written** as 16-bit PNG in millimetres (`NaN` → 0, rounded to the nearest mm,
//!   clamped to 1..=65 535 mm so a valid sample never becomes "no sample") and as float
//!   OpenEXR in metres (one channel `Y`, so OpenCV's `imread(..., IMREAD_ANYDEPTH)` and image
//!   viewers show it as grey; `NaN` kept). Float TIFF in metres for tests and exchange.
//! * **Masks** are written as 8-bit grey PNG (0 / 255), colour as 8-bit RGB PNG.
//!
//! Every write goes through [`crate::atomic`]: a file appears complete or not at all.

use std::io::Cursor;
use std::path::Path;

use crate::atomic::write_bytes_atomic;
use crate::image_header::{
    Container, check_header, check_jpeg_complete, decoder_limits, read_image_bytes, sniff,
};
use geometry::{GeometryError, Image};

/// The colour formats accepted, for error messages and `--help`.
pub const COLOR_FORMATS: &str = "PNG, JPEG, TIFF or BMP (8/16-bit grey, RGB or RGBA)";
/// The depth formats accepted, for error messages and `--help`.
pub const DEPTH_FORMATS: &str = "16-bit grey PNG/TIFF in integer units (millimetres by default), or 32-bit float grey TIFF / OpenEXR in metres";
/// Metres per unit of Kinect 16-bit depth images (millimetres).
pub const MILLIMETRES: f64 = 1e-3;
/// Largest depth a 16-bit millimetre PNG can hold, metres.
pub const PNG16_MAX_M: f32 = 65.535;

fn format_err(path: &Path, message: impl Into<String>) -> GeometryError {
    // Decoder messages may end in a newline or hold control characters: one clean line.
    let message: String = message.into();
    let message = message.split(char::is_control).filter(|s| !s.trim().is_empty());
    let message = message.map(str::trim).collect::<Vec<_>>().join(" ");
    GeometryError::Format { path: path.to_path_buf(), message }
}

/// Decodes a colour or grey image (the formats of [`COLOR_FORMATS`]) with the checks every
/// reader makes first ([`check_picture`]).
fn decode_picture(path: &Path) -> Result<image::DynamicImage, GeometryError> {
    decode_picture_bytes(path, &read_image_bytes(path)?)
}

/// The checks every colour reader makes before decoding, on an image's bytes: a format of
/// [`COLOR_FORMATS`] (by content, not name), the header's size within the limits, a JPEG not
/// cut short (the decoder would fill the missing part with grey). `path` names the image in
/// the error. For bytes passed on without decoding (a frame folder's JPEG copied into a
/// sequence's output); every decode runs it too.
pub fn check_picture(path: &Path, bytes: &[u8]) -> Result<(), GeometryError> {
    picture_format(path, bytes).map(|_| ())
}

/// [`check_picture`], returning the format to decode with.
fn picture_format(path: &Path, bytes: &[u8]) -> Result<image::ImageFormat, GeometryError> {
    let format = match sniff(bytes) {
        Container::Png => image::ImageFormat::Png,
        Container::Tiff => image::ImageFormat::Tiff,
        Container::Jpeg => image::ImageFormat::Jpeg,
        Container::Bmp => image::ImageFormat::Bmp,
        Container::Exr => {
            return Err(format_err(
                path,
                format!("is an OpenEXR (float) image; colour images must be {COLOR_FORMATS}"),
            ));
        }
        Container::Unknown => {
            return Err(format_err(
                path,
                format!("is not an image kfuse can read (unknown format); use {COLOR_FORMATS}"),
            ));
        }
    };
    if format == image::ImageFormat::Jpeg {
        check_jpeg_complete(path, bytes)?;
    }
    check_header(path, bytes)?;
    Ok(format)
}

/// Decodes image bytes after [`check_picture`].
fn decode_picture_bytes(path: &Path, bytes: &[u8]) -> Result<image::DynamicImage, GeometryError> {
    let format = picture_format(path, bytes)?;
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), format);
    reader.limits(decoder_limits());
    let img = match reader.decode() {
        Ok(img) => img,
        // The image crate's JPEG decoder has no default Huffman tables; a motion-JPEG frame
        // (no DHT segment: decoders take ITU-T T.81 Annex K's standard tables, as libjpeg and
        // libfreenect2 do) is decoded by libjpeg-turbo instead.
        Err(_) if format == image::ImageFormat::Jpeg && !jpeg_has_huffman_tables(bytes) => {
            decode_motion_jpeg(path, bytes)?
        }
        Err(e) => {
            return Err(format_err(
                path,
                format!("corrupt or unsupported {format:?} image: {e}; use {COLOR_FORMATS}"),
            ));
        }
    };
    if matches!(img, image::DynamicImage::ImageRgb32F(_) | image::DynamicImage::ImageRgba32F(_)) {
        return Err(format_err(
            path,
            format!("is a floating-point image; colour images must be {COLOR_FORMATS}"),
        ));
    }
    Ok(img)
}

/// True when a JPEG defines a Huffman table (a DHT segment, marker `FF C4`) before its first
/// scan. The segments are walked by their lengths from SOI up to SOS; a stream that ends or
/// breaks the marker syntax first counts as having tables (the decoder's own error is the
/// one to report then).
fn jpeg_has_huffman_tables(bytes: &[u8]) -> bool {
    const DHT: u8 = 0xC4;
    const SOS: u8 = 0xDA;
    let mut i = 2; // after SOI (FF D8), checked by the caller's sniffing
    while i + 4 <= bytes.len() {
        if bytes[i] != 0xFF {
            return true;
        }
        match bytes[i + 1] {
            DHT => return true,
            SOS => return false,
            // Fill bytes before a marker.
            0xFF => i += 1,
            _ => i += 2 + usize::from(u16::from_be_bytes([bytes[i + 2], bytes[i + 3]])),
        }
    }
    true
}

/// A JPEG without Huffman tables decoded by libjpeg-turbo (which falls back on the standard
/// tables), after its declared size is checked against the image limits.
fn decode_motion_jpeg(path: &Path, bytes: &[u8]) -> Result<image::DynamicImage, GeometryError> {
    let broken = |e: turbojpeg::Error| {
        format_err(path, format!("corrupt JPEG without Huffman tables (motion-JPEG): {e}"))
    };
    let header = turbojpeg::read_header(bytes).map_err(broken)?;
    crate::image_header::check_image_size(path, header.width as u64, header.height as u64)?;
    let rgb = turbojpeg::decompress(bytes, turbojpeg::PixelFormat::RGB).map_err(broken)?;
    let (w, h) = (rgb.width as u32, rgb.height as u32);
    let buffer = image::RgbImage::from_raw(w, h, rgb.pixels).ok_or_else(|| {
        format_err(path, "libjpeg-turbo returned fewer pixels than the JPEG declares")
    })?;
    Ok(image::DynamicImage::ImageRgb8(buffer))
}

/// An image's pixel type in words, for messages ("an 8-bit grey", not the decoder's `L8`).
fn pixel_type_in_words(color: image::ColorType) -> String {
    use image::ColorType as C;
    match color {
        C::L8 => "an 8-bit grey".into(),
        C::La8 => "an 8-bit grey + alpha".into(),
        C::Rgb8 => "an 8-bit RGB".into(),
        C::Rgba8 => "an 8-bit RGBA".into(),
        C::L16 => "a 16-bit grey".into(),
        C::La16 => "a 16-bit grey + alpha".into(),
        C::Rgb16 => "a 16-bit RGB".into(),
        C::Rgba16 => "a 16-bit RGBA".into(),
        C::Rgb32F => "a float RGB".into(),
        C::Rgba32F => "a float RGBA".into(),
        other => format!("a {other:?}"),
    }
}

/// Reads a colour image (see the module docs for the formats).
pub fn read_color(path: &Path) -> Result<Image<[u8; 3]>, GeometryError> {
    Ok(read_color_noting(path)?.0)
}

/// [`read_color`], with a note when the file is not a colour picture but was converted to one:
/// a 16-bit grey image (depth or IR saved at the colour camera's size) becomes RGB divided by
/// 257, near black for millimetre depth. The caller decides whether that is an error.
pub fn read_color_noting(path: &Path) -> Result<(Image<[u8; 3]>, Option<String>), GeometryError> {
    decode_color_noting(path, &read_image_bytes(path)?)
}

/// [`read_color_noting`] of an image already in memory (a frame of a recording or of a frame
/// folder), with the same checks ([`check_picture`]) and conversion; `path` names it in errors.
/// One reader for single images and sequences: a JPEG cut short is refused by both.
pub fn decode_color_noting(
    path: &Path,
    bytes: &[u8],
) -> Result<(Image<[u8; 3]>, Option<String>), GeometryError> {
    let img = decode_picture_bytes(path, bytes)?;
    let note = matches!(img.color(), image::ColorType::L16 | image::ColorType::La16).then(|| {
        format!(
            "{}: is {} image, not a colour picture (depth or IR at the colour camera's size?); give the colour camera's 8-bit image",
            path.display(),
            pixel_type_in_words(img.color())
        )
    });
    let rgb = img.into_rgb8();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let pixels = rgb.into_raw().chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    Ok((Image::from_vec(w, h, pixels)?, note))
}

/// Reads an image as 8-bit grey for checkerboard detection (`kfuse calibrate`), with the
/// checks of [`read_color`] (size limits, a JPEG cut short is refused, not decoded as grey).
/// Colour becomes luma. 16-bit values (Kinect IR, raw) are scaled by their image's range:
///
/// * all within 0..=255 (8-bit data in a 16-bit file): kept as they are;
/// * up to 65 535, the sensor's clipping value: × 255 / 65 535, so clipped pixels become 255,
///   which the detector treats as saturated (censored);
/// * otherwise × 254 / the largest value: the whole 8-bit range, no pixel marked clipped.
///
/// A fixed division by 257 leaves a low-range image a few grey levels: a 16-bit copy of an
/// OpenCV sample view with values 0..=255 became 0/1 and its corners were 2× noisier.
pub fn read_gray(path: &Path) -> Result<Image<u8>, GeometryError> {
    let img = decode_picture(path)?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    let pixels = match img {
        image::DynamicImage::ImageLuma16(_)
        | image::DynamicImage::ImageLumaA16(_)
        | image::DynamicImage::ImageRgb16(_)
        | image::DynamicImage::ImageRgba16(_) => {
            let grey = img.into_luma16().into_raw();
            let max = grey.iter().copied().max().unwrap_or(0);
            let scale = match max {
                0..=255 => 1.0,
                u16::MAX => 255.0 / 65535.0,
                _ => 254.0 / f32::from(max),
            };
            grey.iter().map(|&v| (f32::from(v) * scale).round() as u8).collect()
        }
        other => other.into_luma8().into_raw(),
    };
    Image::from_vec(w, h, pixels)
}

/// How a depth file stores its values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthEncoding {
    /// 16-bit integers, scaled by the caller's metres per unit.
    Integer,
    /// 32-bit (or 16-bit half) floats, metres.
    FloatMetres,
}

/// Reads a depth image into metres (`NaN` = no sample). `metres_per_unit` scales 16-bit
/// integer images ([`MILLIMETRES`] for Kinect files); float images are already metres.
/// Fails when the image holds no valid sample at all.
pub fn read_depth(path: &Path, metres_per_unit: f64) -> Result<Image<f32>, GeometryError> {
    Ok(read_depth_encoded(path, metres_per_unit)?.0)
}

/// [`read_depth`], also saying how the file stored the values (for messages about units).
pub fn read_depth_encoded(
    path: &Path,
    metres_per_unit: f64,
) -> Result<(Image<f32>, DepthEncoding), GeometryError> {
    if !(metres_per_unit.is_finite() && metres_per_unit > 0.0) {
        return Err(GeometryError::InvalidParameter(format!(
            "depth scale must be a positive number of metres per unit, got {metres_per_unit}"
        )));
    }
    let bytes = read_image_bytes(path)?;
    if matches!(sniff(&bytes), Container::Png | Container::Tiff | Container::Exr) {
        check_header(path, &bytes)?;
    }
    let (img, encoding) = match sniff(&bytes) {
        Container::Png => (read_depth_png(path, &bytes, metres_per_unit)?, DepthEncoding::Integer),
        Container::Tiff => read_depth_tiff(path, &bytes, metres_per_unit)?,
        Container::Exr => (read_depth_exr(path, &bytes)?, DepthEncoding::FloatMetres),
        Container::Jpeg | Container::Bmp => {
            return Err(format_err(
                path,
                format!(
                    "is an 8-bit JPEG/BMP picture, not depth measurements; depth must be {DEPTH_FORMATS}"
                ),
            ));
        }
        Container::Unknown => {
            return Err(format_err(
                path,
                format!(
                    "is not an image kfuse can read (unknown format); depth must be {DEPTH_FORMATS}"
                ),
            ));
        }
    };
    if !img.data().iter().any(|d| d.is_finite()) {
        return Err(format_err(
            path,
            "has no valid depth sample (every pixel is 0 or NaN); check that this is the depth image and not an empty frame",
        ));
    }
    Ok((img, encoding))
}

/// Depth in metres (`NaN` = no sample) from a `w x h` row-major image of 16-bit integers
/// (`0` = no sample) scaled by `metres_per_unit` ([`MILLIMETRES`] for Kinect depth): how
/// [`read_depth`] reads a 16-bit PNG or TIFF, for depth that comes as integers from elsewhere
/// (the Python package's NumPy arrays).
pub fn depth_from_units(
    w: usize,
    h: usize,
    units: &[u16],
    metres_per_unit: f64,
) -> Result<Image<f32>, GeometryError> {
    let data = units.iter().map(|&u| unit_to_metres(u, metres_per_unit)).collect();
    Image::from_vec(w, h, data)
}

/// [`depth_from_units`] into `out` (the same length as `units`): a stream of frames reuses
/// one image. Error: [`GeometryError::InvalidInput`] for lengths that differ.
pub fn depth_from_units_into(
    units: &[u16],
    metres_per_unit: f64,
    out: &mut [f32],
) -> Result<(), GeometryError> {
    if units.len() != out.len() {
        return Err(GeometryError::InvalidInput(format!(
            "{} depth units for a depth image of {} pixels",
            units.len(),
            out.len()
        )));
    }
    for (o, &u) in out.iter_mut().zip(units) {
        *o = unit_to_metres(u, metres_per_unit);
    }
    Ok(())
}

/// One 16-bit depth value in metres, `0` = no sample (`NaN`).
#[inline]
fn unit_to_metres(u: u16, metres_per_unit: f64) -> f32 {
    if u == 0 { f32::NAN } else { (u as f64 * metres_per_unit) as f32 }
}

fn from_metres(w: usize, h: usize, metres: Vec<f32>) -> Result<Image<f32>, GeometryError> {
    let data =
        metres.into_iter().map(|d| if d.is_finite() && d > 0.0 { d } else { f32::NAN }).collect();
    Image::from_vec(w, h, data)
}

fn read_depth_png(
    path: &Path,
    bytes: &[u8],
    metres_per_unit: f64,
) -> Result<Image<f32>, GeometryError> {
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), image::ImageFormat::Png);
    reader.limits(decoder_limits());
    let img = reader.decode().map_err(|e| format_err(path, format!("corrupt PNG: {e}")))?;
    match img {
        image::DynamicImage::ImageLuma16(buf) => {
            let (w, h) = (buf.width() as usize, buf.height() as usize);
            depth_from_units(w, h, &buf.into_raw(), metres_per_unit)
        }
        other => Err(format_err(
            path,
            format!("is {} PNG; depth must be {DEPTH_FORMATS}", pixel_type_in_words(other.color())),
        )),
    }
}

fn read_depth_tiff(
    path: &Path,
    bytes: &[u8],
    metres_per_unit: f64,
) -> Result<(Image<f32>, DepthEncoding), GeometryError> {
    let tiff_err = |e: tiff::TiffError| {
        format_err(path, format!("corrupt or unsupported TIFF: {e}; depth must be {DEPTH_FORMATS}"))
    };
    let mut dec = tiff::decoder::Decoder::new(Cursor::new(bytes)).map_err(tiff_err)?;
    let (w, h) = dec.dimensions().map_err(tiff_err)?;
    let colour = dec.colortype().map_err(tiff_err)?;
    let (w, h) = (w as usize, h as usize);
    match (colour, dec.read_image().map_err(tiff_err)?) {
        (tiff::ColorType::Gray(16), tiff::decoder::DecodingResult::U16(v)) => {
            Ok((depth_from_units(w, h, &v, metres_per_unit)?, DepthEncoding::Integer))
        }
        (tiff::ColorType::Gray(32), tiff::decoder::DecodingResult::F32(v)) => {
            Ok((from_metres(w, h, v)?, DepthEncoding::FloatMetres))
        }
        (c, _) => Err(format_err(path, format!("is a {c:?} TIFF; depth must be {DEPTH_FORMATS}"))),
    }
}

/// EXR channel names taken as depth, in order of preference (case-insensitive, compared with
/// the last dot-separated part of the name).
const EXR_DEPTH_CHANNELS: [&str; 4] = ["z", "depth", "y", "r"];

fn read_depth_exr(path: &Path, bytes: &[u8]) -> Result<Image<f32>, GeometryError> {
    use exr::prelude::*;
    let img = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| format_err(path, format!("corrupt or unsupported OpenEXR: {e}")))?;
    let layer = &img.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    let channels = &layer.channel_data.list;
    let short = |c: &AnyChannel<FlatSamples>| {
        c.name.to_string().rsplit('.').next().unwrap_or_default().to_lowercase()
    };
    let channel = if channels.len() == 1 {
        &channels[0]
    } else {
        EXR_DEPTH_CHANNELS
            .iter()
            .find_map(|want| channels.iter().find(|c| short(c) == *want))
            .ok_or_else(|| {
                let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
                format_err(path, format!("has channels {}; expected one channel or one named Z, depth, Y or R (metres)", names.join(", ")))
            })?
    };
    let values: Vec<f32> = match &channel.sample_data {
        FlatSamples::F32(v) => v.clone(),
        FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
        FlatSamples::U32(_) => {
            return Err(format_err(
                path,
                format!(
                    "channel '{}' holds integers; EXR depth must be float metres",
                    channel.name
                ),
            ));
        }
    };
    from_metres(w, h, values)
}

/// One value of a 16-bit image where 0 means "no value" (depth in millimetres, IR amplitude):
/// non-finite and non-positive values → 0; others rounded to the nearest integer (halves away
/// from zero) and clamped to `1..=65535`, so that a valid value below 0.5 stays valid instead of
/// turning into the "no value" 0, and a value above the range saturates. The one rule of every
/// 16-bit PNG kfuse writes ([`write_png16`]).
///
/// `f64::round` is a call into libm on x86-64's baseline (there is no rounding instruction
/// before SSE4.1), which made this rule half of a sequence frame's registration stage (a
/// 1920×1080 frame converts 2 million values). Below 65535 the truncating conversion is exact
/// and `v - trunc(v)` is exact (Sterbenz), so `trunc(v) + (fraction >= 0.5)` is `round(v)`
/// bit for bit, halves away from zero included (tested against `f64::round`).
#[inline]
pub fn png16_value(v: f64) -> u16 {
    if !(v > 0.0 && v < f64::INFINITY) {
        return 0; // NaN, ±∞ and v <= 0: no value.
    }
    if v >= 65535.0 {
        return 65535;
    }
    let t = v as u32; // truncation: 0..=65534
    let r = t + u32::from(v - f64::from(t) >= 0.5);
    r.max(1) as u16
}

/// [`png16_value`] of every `src[i] · scale` into `dst` (same length), bit for bit, and the
/// number of `src` values that are not NaN: the conversion of a sequence frame's z-buffer
/// (2 million values at 1920×1080). Written without branches and without a float → integer
/// conversion (both keep a loop from vectorising), with the same steps as [`png16_value`]:
/// the clamp to `0..=65535` first, `floor` from a round-to-nearest by adding and subtracting
/// 2^52, halves away from zero, then the clamp to 1. Compiled for x86-64's baseline and for
/// AVX2 and picked at run time (`multiversion`); IEEE operations without contraction, so both
/// give the same bits (tested against [`png16_value`]).
///
/// # Panics
/// When `dst` and `src` differ in length (a caller's bug).
#[multiversion::multiversion(targets("x86_64+avx2"))]
pub fn png16_values(src: &[f32], scale: f64, dst: &mut [u16]) -> usize {
    /// 2^52: adding it to a double in [0, 2^31) rounds it to an integer (to nearest, ties to
    /// even) and leaves that integer in the low bits of the sum's representation.
    const INTEGER_BITS: f64 = 4_503_599_627_370_496.0;
    assert_eq!(src.len(), dst.len(), "png16_values: source and destination lengths differ");
    let mut present = 0usize;
    for (d, s) in dst.chunks_mut(256).zip(src.chunks(256)) {
        let mut count = 0u32;
        for (d, &z) in d.iter_mut().zip(s) {
            let v = f64::from(z) * scale;
            let valid = v > 0.0 && v < f64::INFINITY;
            // NaN and v <= 0 → 0 (masked out by `valid` below); +∞ → 65535 (masked too).
            let c = if v > 0.0 { v.min(65535.0) } else { 0.0 };
            // floor(c) = round-to-nearest(c), minus one where that rounded up.
            let nearest = (c + INTEGER_BITS) - INTEGER_BITS;
            let floor = nearest - if nearest > c { 1.0 } else { 0.0 };
            // Halves away from zero, then the 1..=65535 clamp of png16_value.
            let r = (floor + if c - floor >= 0.5 { 1.0 } else { 0.0 }).max(1.0);
            let bits = (r + INTEGER_BITS).to_bits() as u16;
            *d = if valid { bits } else { 0 };
            count += u32::from(!z.is_nan());
        }
        present += count as usize;
    }
    present
}

/// Depth in metres → 16-bit millimetres by [`png16_value`]: `NaN` (or ≤ 0) → 0; valid values
/// rounded to the nearest millimetre and clamped to `1..=65535`.
pub fn depth_to_mm(depth: &Image<f32>) -> Vec<u16> {
    depth.data().iter().map(|&d| png16_value(d as f64 * 1e3)).collect()
}

fn encode_png(img: image::DynamicImage, path: &Path) -> Result<Vec<u8>, GeometryError> {
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| format_err(path, format!("cannot encode PNG: {e}")))?;
    Ok(out.into_inner())
}

fn size_u32(path: &Path, w: usize, h: usize) -> Result<(u32, u32), GeometryError> {
    match (u32::try_from(w), u32::try_from(h)) {
        (Ok(w), Ok(h)) if w > 0 && h > 0 => Ok((w, h)),
        _ => Err(format_err(path, format!("cannot write a {w}x{h} image"))),
    }
}

/// Writes depth (metres) as a 16-bit grey PNG in millimetres (see [`depth_to_mm`]).
pub fn write_depth_png16(path: &Path, depth: &Image<f32>) -> Result<(), GeometryError> {
    write_png16(path, depth.width(), depth.height(), depth_to_mm(depth))
}

/// Writes a `width × height` row-major 16-bit grey PNG, atomically: the one 16-bit PNG encoder
/// (depth here, the capture's depth and IR in `kfuse-capture`; values made by [`png16_value`]).
/// Error: a size of 0 or above `u32`, or `values` not of that size.
pub fn write_png16(
    path: &Path,
    width: usize,
    height: usize,
    values: Vec<u16>,
) -> Result<(), GeometryError> {
    let (w, h) = size_u32(path, width, height)?;
    let n = values.len();
    let buf = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, values)
        .filter(|_| width.checked_mul(height) == Some(n))
        .ok_or_else(|| {
            format_err(path, format!("{n} values do not make a {width}x{height} image"))
        })?;
    write_bytes_atomic(path, &encode_png(image::DynamicImage::ImageLuma16(buf), path)?)
}

/// Writes depth (metres, `NaN` kept) as a single-channel (`Y`) 32-bit float OpenEXR file.
pub fn write_depth_exr(path: &Path, depth: &Image<f32>) -> Result<(), GeometryError> {
    write_depth_exr_with(path, depth, None)
}

/// [`write_depth_exr`] with `mark` as the layer's `software` attribute
/// ([`crate::provenance`]).
pub fn write_depth_exr_marked(
    path: &Path,
    depth: &Image<f32>,
    mark: &str,
) -> Result<(), GeometryError> {
    write_depth_exr_with(path, depth, Some(mark))
}

fn write_depth_exr_with(
    path: &Path,
    depth: &Image<f32>,
    mark: Option<&str>,
) -> Result<(), GeometryError> {
    use exr::prelude::*;
    size_u32(path, depth.width(), depth.height())?;
    let channel = AnyChannel::new("Y", FlatSamples::F32(depth.data().to_vec()));
    let mut list = SmallVec::new();
    list.push(channel);
    let layer = Layer::new(
        (depth.width(), depth.height()),
        LayerAttributes {
            software_name: mark.map(Text::from),
            ..LayerAttributes::named("depth_m")
        },
        // Tiles in increasing order, not in the order the parallel compressor finishes them:
        // the same depth gives the same bytes (the CLI's and Python's outputs are compared
        // byte for byte).
        Encoding { line_order: LineOrder::Increasing, ..Encoding::FAST_LOSSLESS },
        AnyChannels::sort(list),
    );
    let mut out = Cursor::new(Vec::new());
    exr::prelude::Image::from_layer(layer)
        .write()
        .to_buffered(&mut out)
        .map_err(|e| format_err(path, format!("cannot encode OpenEXR: {e}")))?;
    write_bytes_atomic(path, &out.into_inner())
}

/// Writes depth (metres, `NaN` kept) as a 32-bit float grey TIFF.
pub fn write_depth_tiff(path: &Path, depth: &Image<f32>) -> Result<(), GeometryError> {
    let (w, h) = size_u32(path, depth.width(), depth.height())?;
    let mut out = Cursor::new(Vec::new());
    let mut enc = tiff::encoder::TiffEncoder::new(&mut out)
        .map_err(|e| format_err(path, format!("cannot encode TIFF: {e}")))?;
    enc.write_image::<tiff::encoder::colortype::Gray32Float>(w, h, depth.data())
        .map_err(|e| format_err(path, format!("cannot encode TIFF: {e}")))?;
    write_bytes_atomic(path, &out.into_inner())
}

/// Writes 16-bit integer depth units as a grey PNG (e.g. raw Kinect millimetres).
pub fn write_u16_png(path: &Path, image: &Image<u16>) -> Result<(), GeometryError> {
    let (w, h) = size_u32(path, image.width(), image.height())?;
    let buf = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, image.data().to_vec())
        .ok_or_else(|| format_err(path, "internal: buffer size"))?;
    write_bytes_atomic(path, &encode_png(image::DynamicImage::ImageLuma16(buf), path)?)
}

/// Writes an RGB image as an 8-bit PNG.
pub fn write_color_png(path: &Path, image: &Image<[u8; 3]>) -> Result<(), GeometryError> {
    let (w, h) = size_u32(path, image.width(), image.height())?;
    let raw: Vec<u8> = image.data().iter().flatten().copied().collect();
    let buf = image::RgbImage::from_raw(w, h, raw)
        .ok_or_else(|| format_err(path, "internal: buffer size"))?;
    write_bytes_atomic(path, &encode_png(image::DynamicImage::ImageRgb8(buf), path)?)
}

/// Writes an 8-bit grey image as PNG.
pub fn write_gray_png(path: &Path, image: &Image<u8>) -> Result<(), GeometryError> {
    let (w, h) = size_u32(path, image.width(), image.height())?;
    let buf = image::GrayImage::from_raw(w, h, image.data().to_vec())
        .ok_or_else(|| format_err(path, "internal: buffer size"))?;
    write_bytes_atomic(path, &encode_png(image::DynamicImage::ImageLuma8(buf), path)?)
}

/// Writes a mask as an 8-bit grey PNG: `true` → 255, `false` → 0.
pub fn write_mask_png(path: &Path, mask: &Image<bool>) -> Result<(), GeometryError> {
    write_gray_png(path, &mask.map(|&m| if m { 255 } else { 0 }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("kfuse-images-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn ramp() -> Image<f32> {
        Image::from_fn(7, 5, |x, y| {
            if (x + y) % 4 == 0 { f32::NAN } else { 0.5 + 0.0371 * x as f32 + 0.913 * y as f32 }
        })
    }

    /// The rule as written first, with `f64::round`: the reference the fast form must equal.
    fn png16_reference(v: f64) -> u16 {
        if v.is_finite() && v > 0.0 { v.round().clamp(1.0, 65535.0) as u16 } else { 0 }
    }

    #[test]
    fn png16_value_equals_rounding_with_f64_round() {
        // Every half and its two neighbours up to the top of the range (the values where a
        // rounding shortcut goes wrong), the specials, and f32 depths times the writers'
        // units (1000 mm, TUM's 5000) as the sequences convert them.
        let mut checked = 0u32;
        let mut check = |v: f64| {
            assert_eq!(png16_value(v), png16_reference(v), "png16_value({v:e})");
            checked += 1;
        };
        for k in 0..=65_536u32 {
            let half = f64::from(k) + 0.5;
            for v in
                [half, half.next_up(), half.next_down(), f64::from(k), f64::from(k).next_down()]
            {
                check(v);
            }
        }
        for v in [
            0.0,
            -0.0,
            -1.0,
            f64::MIN_POSITIVE,
            0.49999999999999994,
            65534.5,
            65535.0,
            65535.4,
            65535.5,
            1e300,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ] {
            check(v);
        }
        let mut z = 0.01f32;
        while z < 80.0 {
            for units in [1000.0, 5000.0] {
                check(f64::from(z) * units);
            }
            z = (z * 1.000_03).next_up();
        }
        // 65 537 × 5 halves and neighbours, 13 specials, ~2 × 300 000 depths.
        assert!(checked > 900_000, "{checked}");
    }

    #[test]
    fn png16_values_equals_png16_value_on_every_kind_of_sample() {
        // Depths of every decade from 0.1 mm to 100 m, halves of the units, NaN, ±∞, 0, −0
        // and negatives, converted at kfuse's 1000 and TUM's 5000 units per metre: the batch
        // form must give png16_value's result for each and count the non-NaN ones.
        let mut src = vec![f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 0.0, -0.0, -1.0];
        let mut z = 1e-4f32;
        while z < 100.0 {
            src.extend([z, z.next_up(), -z]);
            z *= 1.0007;
        }
        src.extend((0..70_000).map(|k| (k as f32 + 0.5) * 1e-3));
        for scale in [1000.0, 5000.0] {
            let mut dst = vec![7u16; src.len()];
            let present = png16_values(&src, scale, &mut dst);
            for (&z, &d) in src.iter().zip(&dst) {
                assert_eq!(d, png16_value(f64::from(z) * scale), "z = {z:e}, scale {scale}");
            }
            assert_eq!(present, src.iter().filter(|z| !z.is_nan()).count());
            // Guard: in range (1 < d < 65535) are, at 5000 units per metre, the ~13 000
            // halves below 13.1 m and ~2 × 16 000 swept depths from 0.2 mm to 13.1 m; more
            // at 1000.
            assert!(dst.iter().filter(|&&d| d > 1 && d < 65535).count() > 30_000);
        }
    }

    #[test]
    fn depth_png16_round_trip_in_millimetres() {
        let dir = scratch("png16");
        let path = dir.join("d.png");
        let mut depth = ramp();
        *depth.get_mut(1, 0) = 70.0; // beyond 65.535 m: clamps
        *depth.get_mut(2, 0) = 0.0002; // rounds to 0 mm but is valid: clamps to 1 mm
        write_depth_png16(&path, &depth).unwrap();
        // Independent reader: the image crate sees 16-bit grey with the millimetre values.
        let raw = image::open(&path).unwrap();
        let raw = raw.as_luma16().unwrap();
        assert_eq!(raw.get_pixel(0, 0).0[0], 0, "NaN must be 0");
        assert_eq!(raw.get_pixel(1, 0).0[0], 65535);
        assert_eq!(raw.get_pixel(2, 0).0[0], 1);
        assert_eq!(
            raw.get_pixel(3, 2).0[0],
            (1000.0 * (0.5f32 + 0.0371 * 3.0 + 0.913 * 2.0) as f64).round() as u16
        );
        let back = read_depth(&path, MILLIMETRES).unwrap();
        for (a, b) in depth.data().iter().zip(back.data()).skip(3) {
            // Millimetre quantisation: |error| ≤ 0.5 mm (+ f32 rounding).
            assert!(a.is_nan() && b.is_nan() || (a - b).abs() <= 0.5e-3 + 1e-6, "{a} vs {b}");
        }
    }

    #[test]
    fn float_exr_and_tiff_round_trip_exactly() {
        let dir = scratch("float");
        let depth = ramp();
        for name in ["d.exr", "d.tif"] {
            let path = dir.join(name);
            if name.ends_with("exr") {
                write_depth_exr(&path, &depth).unwrap();
            } else {
                write_depth_tiff(&path, &depth).unwrap();
            }
            let back = read_depth(&path, MILLIMETRES).unwrap();
            assert_eq!(back.size(), depth.size());
            for (a, b) in depth.data().iter().zip(back.data()) {
                assert!(a.is_nan() && b.is_nan() || a == b, "{name}: {a} vs {b}");
            }
        }
        // Independent reader of the EXR: the exr crate's own RGBA path sees a grey image
        // whose luminance channel carries the metres.
        let img = exr::prelude::read_first_flat_layer_from_file(dir.join("d.exr")).unwrap();
        assert_eq!(img.layer_data.channel_data.list[0].name.to_string(), "Y");
        assert_eq!(
            img.layer_data.channel_data.list[0].sample_data.value_by_flat_index(1).to_f32(),
            depth.data()[1]
        );
    }

    #[test]
    fn colour_png_round_trip_and_formats() {
        let dir = scratch("colour");
        let img = Image::from_fn(4, 3, |x, y| [x as u8 * 60, y as u8 * 100, 7]);
        let path = dir.join("c.png");
        write_color_png(&path, &img).unwrap();
        assert_eq!(read_color(&path).unwrap(), img);
        // BMP written by the image crate reads back the same.
        let bmp = dir.join("c.bmp");
        image::RgbImage::from_raw(4, 3, img.data().iter().flatten().copied().collect())
            .unwrap()
            .save(&bmp)
            .unwrap();
        assert_eq!(read_color(&bmp).unwrap(), img);
        let mask = Image::from_fn(4, 3, |x, _| x > 1);
        write_mask_png(&dir.join("m.png"), &mask).unwrap();
        let m = image::open(dir.join("m.png")).unwrap().into_luma8();
        assert_eq!((m.get_pixel(0, 0).0[0], m.get_pixel(3, 2).0[0]), (0, 255));
    }

    #[test]
    fn bad_inputs_give_clear_errors() {
        let dir = scratch("bad");
        let missing = dir.join("missing.png");
        let err = read_depth(&missing, MILLIMETRES).unwrap_err().to_string();
        assert!(err.contains("missing.png"), "{err}");
        let corrupt = dir.join("corrupt.png");
        let mut bytes = b"\x89PNG\r\n\x1a\n".to_vec();
        bytes.extend_from_slice(&[0u8; 40]);
        std::fs::write(&corrupt, &bytes).unwrap();
        let err = read_color(&corrupt).unwrap_err().to_string();
        assert!(err.contains("corrupt.png") && err.contains("corrupt"), "{err}");
        let text = dir.join("notes.png");
        std::fs::write(&text, "hello").unwrap();
        let err = read_color(&text).unwrap_err().to_string();
        assert!(err.contains("notes.png") && err.contains("PNG, JPEG, TIFF or BMP"), "{err}");
        // An 8-bit grey PNG is not depth.
        let gray = dir.join("gray8.png");
        write_gray_png(&gray, &Image::filled(3, 3, 9u8)).unwrap();
        let err = read_depth(&gray, MILLIMETRES).unwrap_err().to_string();
        assert!(err.contains("gray8.png") && err.contains("16-bit"), "{err}");
        // All-zero and all-NaN depth.
        let zero = dir.join("zero.png");
        write_depth_png16(&zero, &Image::filled(3, 3, f32::NAN)).unwrap();
        let err = read_depth(&zero, MILLIMETRES).unwrap_err().to_string();
        assert!(err.contains("zero.png") && err.contains("no valid depth"), "{err}");
        let nan = dir.join("nan.tif");
        write_depth_tiff(&nan, &Image::filled(3, 3, f32::NAN)).unwrap();
        let err = read_depth(&nan, MILLIMETRES).unwrap_err().to_string();
        assert!(err.contains("nan.tif") && err.contains("no valid depth"), "{err}");
    }

    /// Grey for detection: a 16-bit image whose values stay within 0..=255 keeps them
    /// exactly; one with a larger range is scaled by 254 / its maximum (1000 → 254, 500 →
    /// 127, 3 → 0.762 → 1), one reaching 65 535 by 255 / 65 535 (65 535 → 255, 1 285 → 5);
    /// 8-bit grey is read as it is; a JPEG cut short is refused.
    #[test]
    fn grey_for_detection_scales_16_bit_by_its_range() {
        let dir = scratch("grey");
        let low: Vec<u16> = (0..12).map(|i| i * 23).collect(); // 0..=253
        let path = dir.join("low16.png");
        write_u16_png(&path, &Image::from_vec(4, 3, low.clone()).unwrap()).unwrap();
        let g = read_gray(&path).unwrap();
        assert_eq!(g.data(), low.iter().map(|&v| v as u8).collect::<Vec<_>>().as_slice());
        let path = dir.join("wide16.png");
        write_u16_png(&path, &Image::from_vec(3, 1, vec![1000u16, 500, 3]).unwrap()).unwrap();
        assert_eq!(read_gray(&path).unwrap().data(), [254, 127, 1]);
        write_u16_png(&path, &Image::from_vec(2, 1, vec![65535u16, 1285]).unwrap()).unwrap();
        assert_eq!(read_gray(&path).unwrap().data(), [255, 5]);
        let path = dir.join("grey8.png");
        let grey8 = Image::from_vec(3, 1, vec![7u8, 130, 255]).unwrap();
        write_gray_png(&path, &grey8).unwrap();
        assert_eq!(read_gray(&path).unwrap().data(), grey8.data());
        // As depth it is refused in words (it said "is a L8 PNG", the decoder's name).
        let err = read_depth(&path, MILLIMETRES).unwrap_err().to_string();
        assert!(err.contains("is an 8-bit grey PNG; depth must be"), "{err}");
        let jpg = dir.join("cut.jpg");
        image::GrayImage::from_fn(64, 64, |x, y| image::Luma([((x * 4) ^ (y * 4)) as u8]))
            .save(&jpg)
            .unwrap();
        let bytes = std::fs::read(&jpg).unwrap();
        std::fs::write(&jpg, &bytes[..bytes.len() * 2 / 3]).unwrap();
        let err = read_gray(&jpg).unwrap_err().to_string();
        assert!(err.contains("cut.jpg") && err.contains("truncated JPEG"), "{err}");
    }

    #[test]
    fn jpeg_colour_and_tiff16_depth_from_other_writers() {
        let dir = scratch("others");
        // JPEG written by the image crate: lossy, so compare within the codec's error on a
        // flat colour (quality 95 keeps flat areas within a few levels).
        let jpg = dir.join("c.jpg");
        image::RgbImage::from_pixel(16, 8, image::Rgb([200, 120, 40])).save(&jpg).unwrap();
        let c = read_color(&jpg).unwrap();
        assert_eq!(c.size(), (16, 8));
        let p = c.get(5, 5);
        assert!(
            // Note: `save` encodes with JpegEncoder::new, the image crate's default quality
            // 75 (image 0.25.10 io/free_functions.rs), not 95. On a flat image only each
            // block's DC term and the YCbCr round trip lose precision (≈ 1–2 levels); ±4 is a
            // margin over that, not a measurement.
            (p[0] as i32 - 200).abs() <= 4
                && (p[1] as i32 - 120).abs() <= 4
                && (p[2] as i32 - 40).abs() <= 4,
            "{p:?}"
        );
        // 16-bit grey TIFF written by the tiff crate, in millimetres and with a custom scale.
        let tif = dir.join("d16.tif");
        let mut bytes = Cursor::new(Vec::new());
        let units: Vec<u16> = (0..12).map(|i| i * 250).collect();
        tiff::encoder::TiffEncoder::new(&mut bytes)
            .unwrap()
            .write_image::<tiff::encoder::colortype::Gray16>(4, 3, &units)
            .unwrap();
        std::fs::write(&tif, bytes.into_inner()).unwrap();
        let d = read_depth(&tif, MILLIMETRES).unwrap();
        assert!(d.get(0, 0).is_nan());
        // 250 and 2750 mm × 1e-3 in f32: ~1 ulp (1.5e-8 at 0.25, 2.4e-7 at 2.75), with margin.
        assert!((d.get(1, 0) - 0.25).abs() < 1e-7 && (d.get(3, 2) - 2.75).abs() < 1e-6);
        let d = read_depth(&tif, 1e-4).unwrap(); // 0.1 mm units
        assert!((d.get(3, 2) - 0.275).abs() < 1e-7);
        let e = read_depth(&tif, 0.0).unwrap_err();
        assert!(matches!(e, GeometryError::InvalidParameter(_)), "{e:?}");
        // A multi-channel EXR: the Z channel is taken, whatever else is there.
        use exr::prelude::*;
        let exr_path = dir.join("multi.exr");
        let mut list = SmallVec::new();
        list.push(AnyChannel::new("R", FlatSamples::F32(vec![9.0; 6])));
        list.push(AnyChannel::new("Z", FlatSamples::F32(vec![1.5, 2.0, f32::NAN, 0.0, -1.0, 3.0])));
        let layer = Layer::new(
            (3, 2),
            LayerAttributes::named("x"),
            Encoding::UNCOMPRESSED,
            AnyChannels::sort(list),
        );
        exr::prelude::Image::from_layer(layer).write().to_file(&exr_path).unwrap();
        let d = read_depth(&exr_path, MILLIMETRES).unwrap();
        let v: Vec<f32> = d.data().to_vec();
        assert_eq!((v[0], v[1], v[5]), (1.5, 2.0, 3.0));
        assert!(
            v[2].is_nan() && v[3].is_nan() && v[4].is_nan(),
            "NaN, 0 and negative are no sample: {v:?}"
        );
    }
}
