//! Which kfuse command wrote an image, stored in the image itself, so that it travels with the
//! file (copied, moved, renamed) where a folder's manifest or a name suffix does not: `kfuse
//! undistort` marks its outputs and refuses to undistort them a second time wherever they are.
//!
//! | format | where the mark is | |
//! | --- | --- | --- |
//! | PNG | a `tEXt` chunk with keyword `Software`, right after `IHDR` | [`mark_png`] |
//! | JPEG | a comment segment (`COM`, `FF FE`), right after the start of image | [`mark_jpeg`] |
//! | TIFF | the `Software` tag (305) | written by `raster::write_raster_marked` |
//! | OpenEXR | the `software` attribute of the layer | written by `images::write_depth_exr_marked` |
//! | BMP | nowhere (the format has no text field): not recognised by its content | |
//!
//! The mark is a line starting with [`UNDISTORT_MARK`]. An image re-saved by another program
//! usually loses it, and is then no longer kfuse's output.

use std::path::Path;

use geometry::GeometryError;

use crate::image_header::{Container, read_image_bytes, sniff};

/// The start of the mark `kfuse undistort` writes into each output image (followed by the
/// camera: `kfuse undistort (color camera)`).
pub const UNDISTORT_MARK: &str = "kfuse undistort";

/// PNG's keyword of the text chunk that names the program that wrote the file.
const PNG_SOFTWARE: &[u8] = b"Software";

/// Length of the PNG signature, bytes.
const PNG_SIGNATURE: usize = 8;

/// `png` with a `tEXt` chunk `Software: text` inserted after its `IHDR` chunk. Bytes that are
/// not a PNG with an `IHDR` first are returned as they are.
pub fn mark_png(png: Vec<u8>, text: &str) -> Vec<u8> {
    let Some((b"IHDR", _, end)) = png_chunk(&png, PNG_SIGNATURE) else { return png };
    let mut data = PNG_SOFTWARE.to_vec();
    data.push(0);
    data.extend(text.bytes().filter(|b| (0x20..0x7f).contains(b)));
    let mut chunk = Vec::with_capacity(data.len() + 12);
    chunk.extend((data.len() as u32).to_be_bytes());
    let mut crc = crc32fast::Hasher::new();
    crc.update(b"tEXt");
    crc.update(&data);
    chunk.extend(b"tEXt");
    chunk.extend(&data);
    chunk.extend(crc.finalize().to_be_bytes());
    let mut out = png;
    out.splice(end..end, chunk);
    out
}

/// `jpeg` with a comment segment holding `text` right after its start-of-image marker. Bytes
/// that are not a JPEG are returned as they are.
pub fn mark_jpeg(jpeg: Vec<u8>, text: &str) -> Vec<u8> {
    if sniff(&jpeg) != Container::Jpeg {
        return jpeg;
    }
    let text: Vec<u8> = text.bytes().take(usize::from(u16::MAX) - 2).collect();
    let mut segment = vec![0xff, 0xfe];
    segment.extend(((text.len() + 2) as u16).to_be_bytes());
    segment.extend(text);
    let mut out = jpeg;
    out.splice(2..2, segment);
    out
}

/// The chunk of a PNG at `pos`: its type, data and the position after it (`None` past the end
/// or for a chunk cut short).
fn png_chunk(png: &[u8], pos: usize) -> Option<(&[u8], &[u8], usize)> {
    let len = u32::from_be_bytes(png.get(pos..pos + 4)?.try_into().ok()?) as usize;
    let kind = png.get(pos + 4..pos + 8)?;
    let data = png.get(pos + 8..pos.checked_add(8 + len)?)?;
    Some((kind, data, pos + 12 + len))
}

/// The `Software` text of a PNG (chunks before the image data), if any.
fn png_software(png: &[u8]) -> Option<String> {
    let mut pos = PNG_SIGNATURE;
    while let Some((kind, data, next)) = png_chunk(png, pos) {
        match kind {
            b"IDAT" | b"IEND" => return None,
            b"tEXt" => {
                if let Some(text) =
                    data.strip_prefix(PNG_SOFTWARE).and_then(|d| d.strip_prefix(&[0]))
                {
                    return Some(String::from_utf8_lossy(text).into_owned());
                }
            }
            _ => {}
        }
        pos = next;
    }
    None
}

/// The comments of a JPEG (segments before the scan data), joined by new lines.
fn jpeg_comments(jpeg: &[u8]) -> Option<String> {
    let mut comments = Vec::new();
    let mut pos = 2;
    while jpeg.get(pos) == Some(&0xff) {
        let marker = *jpeg.get(pos + 1)?;
        if marker == 0xda || marker == 0xd9 {
            break;
        }
        let len = usize::from(u16::from_be_bytes(jpeg.get(pos + 2..pos + 4)?.try_into().ok()?));
        let data = jpeg.get(pos + 4..pos + 2 + len.max(2))?;
        if marker == 0xfe {
            comments.push(String::from_utf8_lossy(data).into_owned());
        }
        pos += 2 + len;
    }
    (!comments.is_empty()).then(|| comments.join("\n"))
}

/// The `Software` tag of a TIFF's first image, if any.
fn tiff_software(tiff: &[u8]) -> Option<String> {
    let mut decoder = tiff::decoder::Decoder::new(std::io::Cursor::new(tiff)).ok()?;
    decoder.get_tag_ascii_string(tiff::tags::Tag::Software).ok()
}

/// The `software` attribute of an OpenEXR's first layer, if any.
fn exr_software(exr: &[u8]) -> Option<String> {
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(exr), false).ok()?;
    let header = meta.headers.first()?;
    header.own_attributes.software_name.as_ref().map(|t| t.to_string())
}

/// The program text stored in an image's bytes (PNG `Software`, JPEG comments, TIFF
/// `Software`, OpenEXR `software`), if any.
pub fn software_of(bytes: &[u8]) -> Option<String> {
    match sniff(bytes) {
        Container::Png => png_software(bytes),
        Container::Jpeg => jpeg_comments(bytes),
        Container::Tiff => tiff_software(bytes),
        Container::Exr => exr_software(bytes),
        Container::Bmp | Container::Unknown => None,
    }
}

/// Whether the image at `path` was written by `kfuse undistort` (its mark, see the module
/// docs). Error: the file cannot be read.
pub fn written_by_undistort(path: &Path) -> Result<bool, GeometryError> {
    let bytes = read_image_bytes(path)?;
    Ok(software_of(&bytes).is_some_and(|s| s.lines().any(|l| l.starts_with(UNDISTORT_MARK))))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png() -> Vec<u8> {
        let mut out = std::io::Cursor::new(Vec::new());
        image::DynamicImage::ImageLuma8(image::GrayImage::from_pixel(4, 3, image::Luma([7])))
            .write_to(&mut out, image::ImageFormat::Png)
            .unwrap();
        out.into_inner()
    }

    fn jpeg() -> Vec<u8> {
        let mut out = std::io::Cursor::new(Vec::new());
        image::DynamicImage::ImageRgb8(image::RgbImage::from_pixel(8, 8, image::Rgb([9, 8, 7])))
            .write_to(&mut out, image::ImageFormat::Jpeg)
            .unwrap();
        out.into_inner()
    }

    /// A marked PNG and JPEG carry the mark, still decode to the same pixels, and an unmarked
    /// one has none.
    #[test]
    fn marks_are_found_and_leave_the_pixels_alone() {
        for (plain, marked) in [
            (png(), mark_png(png(), "kfuse undistort (color camera)")),
            (jpeg(), mark_jpeg(jpeg(), "kfuse undistort (color camera)")),
        ] {
            assert_eq!(software_of(&plain), None);
            assert_eq!(software_of(&marked).as_deref(), Some("kfuse undistort (color camera)"));
            let a = image::load_from_memory(&plain).unwrap().into_rgb8();
            let b = image::load_from_memory(&marked).unwrap().into_rgb8();
            assert_eq!(a, b);
        }
        // Not an image of that format: unchanged.
        assert_eq!(mark_png(b"abc".to_vec(), "x"), b"abc");
        assert_eq!(mark_jpeg(b"abc".to_vec(), "x"), b"abc");
    }
}
