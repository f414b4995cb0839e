//! Images read and written in their own pixel type and file format, for tools that change
//! pixel positions but not values (`kfuse undistort`): grey stays grey, 16-bit stays 16-bit,
//! float stays float, TIFF stays TIFF.
//!
//! | pixel type | read from | written to |
//! | --- | --- | --- |
//! | 8-bit grey, RGB, RGBA | PNG, TIFF, BMP, JPEG | the same format (JPEG at quality [`JPEG_QUALITY`]) |
//! | 16-bit grey (depth in mm, 16-bit IR) | PNG, TIFF | the same format |
//! | 32-bit float grey (depth in m) | TIFF | TIFF |
//!
//! Other types (16-bit colour, grey + alpha, float colour) are refused with one line naming
//! the file.

use std::io::Cursor;
use std::path::Path;

use crate::atomic::write_bytes_atomic;
use crate::image_header::{
    Container, check_header, check_jpeg_complete, decoder_limits, read_image_bytes, sniff,
};
use geometry::{GeometryError, Image};

/// JPEG quality of rewritten JPEG files: 95, visually lossless; JPEG cannot keep the pixel
/// values exactly in any case (use PNG or TIFF for that).
pub const JPEG_QUALITY: u8 = 95;

/// What [`read_raster`] accepts, for messages.
pub const RASTER_TYPES: &str = "8-bit grey/RGB/RGBA (PNG, TIFF, BMP, JPEG; grey + alpha PNG as RGBA), 16-bit grey (PNG, TIFF) or 32-bit float grey (TIFF)";

/// An image in its file's pixel type.
#[derive(Debug, Clone, PartialEq)]
pub enum Raster {
    /// 8-bit grey.
    Gray8(Image<u8>),
    /// 8-bit RGB.
    Rgb8(Image<[u8; 3]>),
    /// 8-bit RGBA.
    Rgba8(Image<[u8; 4]>),
    /// 16-bit grey (Kinect depth in millimetres, 0 = none; 16-bit IR).
    Gray16(Image<u16>),
    /// 32-bit float grey (depth in metres, NaN = none).
    GrayF32(Image<f32>),
}

impl Raster {
    /// Width and height.
    pub fn size(&self) -> (usize, usize) {
        match self {
            Raster::Gray8(i) => i.size(),
            Raster::Rgb8(i) => i.size(),
            Raster::Rgba8(i) => i.size(),
            Raster::Gray16(i) => i.size(),
            Raster::GrayF32(i) => i.size(),
        }
    }

    /// The pixel type in words ("8-bit grey", …).
    pub fn kind(&self) -> &'static str {
        match self {
            Raster::Gray8(_) => "8-bit grey",
            Raster::Rgb8(_) => "8-bit RGB",
            Raster::Rgba8(_) => "8-bit RGBA",
            Raster::Gray16(_) => "16-bit grey",
            Raster::GrayF32(_) => "32-bit float grey",
        }
    }
}

/// The file formats a [`Raster`] is written in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RasterFormat {
    /// PNG.
    Png,
    /// TIFF (uncompressed).
    Tiff,
    /// BMP.
    Bmp,
    /// JPEG.
    Jpeg,
}

impl RasterFormat {
    /// The usual file extension.
    pub fn extension(self) -> &'static str {
        match self {
            RasterFormat::Png => "png",
            RasterFormat::Tiff => "tif",
            RasterFormat::Bmp => "bmp",
            RasterFormat::Jpeg => "jpg",
        }
    }
}

fn err(path: &Path, message: impl Into<String>) -> GeometryError {
    GeometryError::Format { path: path.to_path_buf(), message: message.into() }
}

fn image_of<T: Clone>(
    path: &Path,
    w: u32,
    h: u32,
    data: Vec<T>,
) -> Result<Image<T>, GeometryError> {
    Image::from_vec(w as usize, h as usize, data).map_err(|e| err(path, e.to_string()))
}

fn chunks<const C: usize, T: Copy + Default>(raw: Vec<T>) -> Vec<[T; C]> {
    raw.chunks_exact(C).map(|c| std::array::from_fn(|i| c[i])).collect()
}

/// Reads an image in its own pixel type and says its format (see the module docs).
pub fn read_raster(path: &Path) -> Result<(Raster, RasterFormat), GeometryError> {
    let bytes = read_image_bytes(path)?;
    let format = match sniff(&bytes) {
        Container::Png => RasterFormat::Png,
        Container::Tiff => RasterFormat::Tiff,
        Container::Bmp => RasterFormat::Bmp,
        Container::Jpeg => RasterFormat::Jpeg,
        Container::Exr | Container::Unknown => {
            return Err(err(
                path,
                format!("is not an image this command reads; use {RASTER_TYPES}"),
            ));
        }
    };
    check_header(path, &bytes)?;
    if format == RasterFormat::Jpeg {
        check_jpeg_complete(path, &bytes)?;
    }
    let raster = if format == RasterFormat::Tiff {
        read_tiff(path, &bytes)?
    } else {
        read_other(path, &bytes, format)?
    };
    Ok((raster, format))
}

fn read_tiff(path: &Path, bytes: &[u8]) -> Result<Raster, GeometryError> {
    use tiff::ColorType as C;
    use tiff::decoder::DecodingResult as R;
    let tiff_err = |e: tiff::TiffError| err(path, format!("corrupt or unsupported TIFF: {e}"));
    let mut dec = tiff::decoder::Decoder::new(Cursor::new(bytes)).map_err(tiff_err)?;
    let (w, h) = dec.dimensions().map_err(tiff_err)?;
    let colour = dec.colortype().map_err(tiff_err)?;
    Ok(match (colour, dec.read_image().map_err(tiff_err)?) {
        (C::Gray(8), R::U8(v)) => Raster::Gray8(image_of(path, w, h, v)?),
        (C::RGB(8), R::U8(v)) => Raster::Rgb8(image_of(path, w, h, chunks::<3, u8>(v))?),
        (C::RGBA(8), R::U8(v)) => Raster::Rgba8(image_of(path, w, h, chunks::<4, u8>(v))?),
        (C::Gray(16), R::U16(v)) => Raster::Gray16(image_of(path, w, h, v)?),
        (C::Gray(32), R::F32(v)) => Raster::GrayF32(image_of(path, w, h, v)?),
        (c, _) => {
            return Err(err(path, format!("is a {c:?} TIFF; this command reads {RASTER_TYPES}")));
        }
    })
}

fn read_other(path: &Path, bytes: &[u8], format: RasterFormat) -> Result<Raster, GeometryError> {
    let f = match format {
        RasterFormat::Png => image::ImageFormat::Png,
        RasterFormat::Bmp => image::ImageFormat::Bmp,
        RasterFormat::Jpeg | RasterFormat::Tiff => image::ImageFormat::Jpeg,
    };
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), f);
    reader.limits(decoder_limits());
    let img = reader
        .decode()
        .map_err(|e| err(path, format!("corrupt or unsupported {f:?} image: {e}")))?;
    let (w, h) = (img.width(), img.height());
    Ok(match img {
        image::DynamicImage::ImageLuma8(b) => Raster::Gray8(image_of(path, w, h, b.into_raw())?),
        image::DynamicImage::ImageRgb8(b) => {
            let rgb = chunks::<3, u8>(b.into_raw());
            // An 8-bit BMP is stored with a palette, which the decoder expands to RGB; a grey
            // palette (the Kinect IR frames of the lab) is a grey image and stays one.
            if format == RasterFormat::Bmp && rgb.iter().all(|p| p[0] == p[1] && p[1] == p[2]) {
                Raster::Gray8(image_of(path, w, h, rgb.iter().map(|p| p[0]).collect())?)
            } else {
                Raster::Rgb8(image_of(path, w, h, rgb)?)
            }
        }
        image::DynamicImage::ImageRgba8(b) => {
            Raster::Rgba8(image_of(path, w, h, chunks::<4, u8>(b.into_raw()))?)
        }
        // Grey + alpha (a PNG that `calibrate` reads as grey) becomes RGBA with the grey in
        // all three colours: the alpha is kept, and RGBA is a type every writer here holds.
        image::DynamicImage::ImageLumaA8(b) => {
            let rgba =
                chunks::<2, u8>(b.into_raw()).into_iter().map(|[g, a]| [g, g, g, a]).collect();
            Raster::Rgba8(image_of(path, w, h, rgba)?)
        }
        image::DynamicImage::ImageLuma16(b) => Raster::Gray16(image_of(path, w, h, b.into_raw())?),
        other => {
            return Err(err(
                path,
                format!("is a {:?} {f:?} image; this command reads {RASTER_TYPES}", other.color()),
            ));
        }
    })
}

/// Writes `raster` as `format`, keeping its pixel type; fails (naming the file) where the
/// format cannot hold the type (16-bit or float in BMP/JPEG, float in PNG).
pub fn write_raster(
    path: &Path,
    raster: &Raster,
    format: RasterFormat,
) -> Result<(), GeometryError> {
    write_raster_with(path, raster, format, None)
}

/// [`write_raster`] with `mark` stored in the file as the program that wrote it
/// ([`crate::provenance`]: PNG `Software` text, JPEG comment, TIFF `Software` tag; BMP has no
/// place for it).
pub fn write_raster_marked(
    path: &Path,
    raster: &Raster,
    format: RasterFormat,
    mark: &str,
) -> Result<(), GeometryError> {
    write_raster_with(path, raster, format, Some(mark))
}

fn write_raster_with(
    path: &Path,
    raster: &Raster,
    format: RasterFormat,
    mark: Option<&str>,
) -> Result<(), GeometryError> {
    let (w, h) = raster.size();
    let (w, h) = match (u32::try_from(w), u32::try_from(h)) {
        (Ok(w), Ok(h)) if w > 0 && h > 0 => (w, h),
        _ => return Err(err(path, format!("cannot write a {w}x{h} image"))),
    };
    let bytes = match format {
        RasterFormat::Tiff => encode_tiff(path, raster, w, h, mark)?,
        _ => encode_other(path, raster, format, w, h)?,
    };
    let bytes = match (mark, format) {
        (Some(m), RasterFormat::Png) => crate::provenance::mark_png(bytes, m),
        (Some(m), RasterFormat::Jpeg) => crate::provenance::mark_jpeg(bytes, m),
        _ => bytes,
    };
    write_bytes_atomic(path, &bytes)
}

/// One TIFF image of pixel type `C`, with `mark` as its `Software` tag.
fn tiff_image<C: tiff::encoder::colortype::ColorType>(
    enc: &mut tiff::encoder::TiffEncoder<&mut Cursor<Vec<u8>>>,
    w: u32,
    h: u32,
    data: &[C::Inner],
    mark: Option<&str>,
) -> tiff::TiffResult<()>
where
    [C::Inner]: tiff::encoder::TiffValue,
{
    let mut image = enc.new_image::<C>(w, h)?;
    if let Some(m) = mark {
        image.encoder().write_tag(tiff::tags::Tag::Software, m)?;
    }
    image.write_data(data)
}

fn encode_tiff(
    path: &Path,
    raster: &Raster,
    w: u32,
    h: u32,
    mark: Option<&str>,
) -> Result<Vec<u8>, GeometryError> {
    use tiff::encoder::{TiffEncoder, colortype};
    let enc_err = |e: tiff::TiffError| err(path, format!("cannot encode TIFF: {e}"));
    let mut out = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut out).map_err(enc_err)?;
    let flat = |d: &[[u8; 3]]| d.iter().flatten().copied().collect::<Vec<u8>>();
    match raster {
        Raster::Gray8(i) => tiff_image::<colortype::Gray8>(&mut enc, w, h, i.data(), mark),
        Raster::Rgb8(i) => tiff_image::<colortype::RGB8>(&mut enc, w, h, &flat(i.data()), mark),
        Raster::Rgba8(i) => {
            let raw: Vec<u8> = i.data().iter().flatten().copied().collect();
            tiff_image::<colortype::RGBA8>(&mut enc, w, h, &raw, mark)
        }
        Raster::Gray16(i) => tiff_image::<colortype::Gray16>(&mut enc, w, h, i.data(), mark),
        Raster::GrayF32(i) => tiff_image::<colortype::Gray32Float>(&mut enc, w, h, i.data(), mark),
    }
    .map_err(enc_err)?;
    Ok(out.into_inner())
}

fn encode_other(
    path: &Path,
    raster: &Raster,
    format: RasterFormat,
    w: u32,
    h: u32,
) -> Result<Vec<u8>, GeometryError> {
    use image::DynamicImage as D;
    let internal = || err(path, "internal: buffer size");
    let img = match raster {
        Raster::Gray8(i) => {
            D::ImageLuma8(image::GrayImage::from_raw(w, h, i.data().to_vec()).ok_or_else(internal)?)
        }
        Raster::Rgb8(i) => D::ImageRgb8(
            image::RgbImage::from_raw(w, h, i.data().iter().flatten().copied().collect())
                .ok_or_else(internal)?,
        ),
        Raster::Rgba8(i) => D::ImageRgba8(
            image::RgbaImage::from_raw(w, h, i.data().iter().flatten().copied().collect())
                .ok_or_else(internal)?,
        ),
        Raster::Gray16(i) if format == RasterFormat::Png => D::ImageLuma16(
            image::ImageBuffer::from_raw(w, h, i.data().to_vec()).ok_or_else(internal)?,
        ),
        other => {
            return Err(err(
                path,
                format!("a {} image cannot be saved as {format:?}; use PNG or TIFF", other.kind()),
            ));
        }
    };
    let mut out = Cursor::new(Vec::new());
    let result = match format {
        RasterFormat::Jpeg => {
            let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, JPEG_QUALITY);
            img.write_with_encoder(enc)
        }
        RasterFormat::Bmp => img.write_to(&mut out, image::ImageFormat::Bmp),
        _ => img.write_to(&mut out, image::ImageFormat::Png),
    };
    result.map_err(|e| err(path, format!("cannot encode {format:?}: {e}")))?;
    Ok(out.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_type_round_trips_exactly_in_its_format() {
        let dir = tempfile::tempdir().unwrap();
        let g8 = Image::from_fn(5, 3, |x, y| (x * 40 + y) as u8);
        let rgb = Image::from_fn(5, 3, |x, y| [x as u8, y as u8, 200]);
        let rgba = Image::from_fn(5, 3, |x, y| [x as u8, y as u8, 7, 128]);
        let g16 = Image::from_fn(5, 3, |x, y| (x * 13_000 + y) as u16);
        let f32i =
            Image::from_fn(5, 3, |x, y| if x == 0 { f32::NAN } else { 0.123 * (x + y) as f32 });
        let cases = [
            (Raster::Gray8(g8.clone()), RasterFormat::Png),
            (Raster::Gray8(g8), RasterFormat::Tiff),
            (Raster::Rgb8(rgb.clone()), RasterFormat::Bmp),
            (Raster::Rgb8(rgb), RasterFormat::Tiff),
            (Raster::Rgba8(rgba.clone()), RasterFormat::Png),
            (Raster::Rgba8(rgba), RasterFormat::Tiff),
            (Raster::Gray16(g16.clone()), RasterFormat::Png),
            (Raster::Gray16(g16), RasterFormat::Tiff),
        ];
        for (i, (r, f)) in cases.iter().enumerate() {
            let p = dir.path().join(format!("{i}.{}", f.extension()));
            write_raster(&p, r, *f).unwrap();
            let (back, bf) = read_raster(&p).unwrap();
            assert_eq!((&back, bf), (r, *f), "{} as {f:?}", r.kind());
        }
        let p = dir.path().join("f.tif");
        write_raster(&p, &Raster::GrayF32(f32i.clone()), RasterFormat::Tiff).unwrap();
        let (Raster::GrayF32(back), RasterFormat::Tiff) = read_raster(&p).unwrap() else {
            panic!("float TIFF not read as float")
        };
        for (a, b) in back.data().iter().zip(f32i.data()) {
            assert!(a.to_bits() == b.to_bits(), "{a} vs {b}");
        }
        let e = write_raster(&dir.path().join("x.jpg"), &Raster::GrayF32(f32i), RasterFormat::Jpeg);
        assert!(e.unwrap_err().to_string().contains("use PNG or TIFF"));
    }

    #[test]
    fn grey_with_alpha_is_read_as_rgba_with_the_grey_in_each_colour() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("la.png");
        let la = image::GrayAlphaImage::from_fn(4, 2, |x, y| {
            image::LumaA([x as u8 * 60, 255 - y as u8])
        });
        la.save(&p).unwrap();
        let (Raster::Rgba8(back), RasterFormat::Png) = read_raster(&p).unwrap() else {
            panic!("grey + alpha PNG not read as RGBA")
        };
        assert_eq!(back.size(), (4, 2));
        for y in 0..2 {
            for x in 0..4 {
                let g = x as u8 * 60;
                assert_eq!(*back.get(x, y), [g, g, g, 255 - y as u8], "({x}, {y})");
            }
        }
    }
}
