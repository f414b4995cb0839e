//! Image sizes read from headers, checked against limits before anything is decoded, and the
//! completeness check of JPEG files (whose decoder fills a truncated file with grey silently).
//!
//! | limit | value | why |
//! | --- | --- | --- |
//! | [`MAX_IMAGE_SIDE`] | 16 384 px | the rig limit ([`geometry::rig::MAX_IMAGE_SIDE`]): no camera kfuse fuses is larger |
//! | [`MAX_IMAGE_PIXELS`] | 50 Mpx | 25 Kinect colour frames; above any camera kfuse calibrates (45 Mpx DSLRs) |
//! | [`MAX_IMAGE_FILE_BYTES`] | 512 MiB | a 50 Mpx 16-bit RGBA file stored raw is 400 MB |
//! | [`MAX_DECODE_BYTES`] | 512 MiB | what a decoder may allocate: a 50 Mpx RGBA16 buffer is 400 MB |

use std::io::{BufRead, Cursor, Seek};
use std::path::Path;

use geometry::GeometryError;

/// Largest width or height of an image read, pixels (the rig's own limit).
pub const MAX_IMAGE_SIDE: u32 = geometry::rig::MAX_IMAGE_SIDE as u32;
/// Most pixels of an image read.
pub const MAX_IMAGE_PIXELS: u64 = geometry::camera::MAX_CAMERA_PIXELS;
/// Largest image file read into memory, bytes.
pub const MAX_IMAGE_FILE_BYTES: u64 = 512 << 20;
/// Most memory an image decoder may allocate, bytes.
pub const MAX_DECODE_BYTES: u64 = 512 << 20;

fn format_err(path: &Path, message: impl Into<String>) -> GeometryError {
    // Decoder messages may end in a newline or hold control characters: one clean line.
    let message: String = message.into();
    let message = message.split(char::is_control).filter(|s| !s.trim().is_empty());
    let message = message.map(str::trim).collect::<Vec<_>>().join(" ");
    GeometryError::Format { path: path.to_path_buf(), message }
}

/// The container of an image file, recognised by its first bytes (never by its name).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Container {
    Png,
    Tiff,
    Exr,
    Jpeg,
    Bmp,
    Unknown,
}

/// Recognises a file by its first bytes.
pub(crate) fn sniff(bytes: &[u8]) -> Container {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        Container::Png
    } else if bytes.starts_with(b"II*\0") || bytes.starts_with(b"MM\0*") {
        Container::Tiff
    } else if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        Container::Exr
    } else if bytes.starts_with(&[0xff, 0xd8, 0xff]) {
        Container::Jpeg
    } else if bytes.starts_with(b"BM") {
        Container::Bmp
    } else {
        Container::Unknown
    }
}

/// The limits of the image crate's decoders: [`MAX_IMAGE_SIDE`] and [`MAX_DECODE_BYTES`].
pub(crate) fn decoder_limits() -> image::Limits {
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_IMAGE_SIDE);
    limits.max_alloc = Some(MAX_DECODE_BYTES);
    limits
}

/// Fails when a `w`×`h` image is over the limits.
pub fn check_image_size(path: &Path, w: u64, h: u64) -> Result<(), GeometryError> {
    let side = u64::from(MAX_IMAGE_SIDE);
    if w > side || h > side || w.saturating_mul(h) > MAX_IMAGE_PIXELS {
        return Err(format_err(
            path,
            format!(
                "is {w}x{h} pixels, over kfuse's limit ({MAX_IMAGE_SIDE} px per side, {} Mpx); no camera kfuse works with makes such images",
                MAX_IMAGE_PIXELS / 1_000_000
            ),
        ));
    }
    if w == 0 || h == 0 {
        return Err(format_err(path, format!("is an empty {w}x{h} image")));
    }
    Ok(())
}

/// Bytes looked at before an image file is read on: enough for every signature [`sniff`] knows.
const SNIFF_BYTES: u64 = 8;

/// Reads a whole image file into memory, at most [`MAX_IMAGE_FILE_BYTES`] whatever the file
/// is (a device or pipe states no size), through [`bounded_read`]. A file whose first bytes
/// are no image signature is returned as those bytes alone, for the caller's format error
/// (so `/dev/zero` or random bytes are refused after 8 bytes, not read on).
pub fn read_image_bytes(path: &Path) -> Result<Vec<u8>, GeometryError> {
    use std::io::Read;
    let io = |source| GeometryError::Io { path: path.to_path_buf(), source };
    let expected = bounded_read::Expected {
        what: "an image file",
        fix: "is this the right file? Give a PNG, JPEG, TIFF, BMP or OpenEXR file",
    };
    let mut file = bounded_read::open_bounded(path, MAX_IMAGE_FILE_BYTES, expected).map_err(io)?;
    let mut head = Vec::new();
    (&mut file).take(SNIFF_BYTES).read_to_end(&mut head).map_err(io)?;
    if sniff(&head) == Container::Unknown {
        // Not an image: the first bytes are enough for the caller's format error.
        return Ok(head);
    }
    bounded_read::read_bounded_from(Cursor::new(head).chain(file), MAX_IMAGE_FILE_BYTES, expected)
        .map_err(io)
}

/// The `(width, height)` an image's header declares, read without decoding any pixel.
pub(crate) fn header_size<R: BufRead + Seek>(
    path: &Path,
    container: Container,
    reader: R,
) -> Result<(u64, u64), GeometryError> {
    let format = match container {
        Container::Png => image::ImageFormat::Png,
        Container::Jpeg => image::ImageFormat::Jpeg,
        Container::Bmp => image::ImageFormat::Bmp,
        Container::Tiff => {
            let bad = |e: tiff::TiffError| format_err(path, format!("corrupt TIFF header: {e}"));
            let (w, h) =
                tiff::decoder::Decoder::new(reader).map_err(bad)?.dimensions().map_err(bad)?;
            return Ok((w.into(), h.into()));
        }
        Container::Exr => {
            let meta = exr::meta::MetaData::read_from_buffered(reader, false)
                .map_err(|e| format_err(path, format!("corrupt OpenEXR header: {e}")))?;
            let header = meta
                .headers
                .first()
                .ok_or_else(|| format_err(path, "OpenEXR file without a layer"))?;
            let size = header.layer_size;
            return Ok((size.width() as u64, size.height() as u64));
        }
        Container::Unknown => {
            return Err(format_err(path, "is not an image kfuse can read (unknown format)"));
        }
    };
    let (w, h) = image::ImageReader::with_format(reader, format)
        .into_dimensions()
        .map_err(|e| format_err(path, format!("corrupt {format:?} header: {e}")))?;
    Ok((w.into(), h.into()))
}

/// The size of the image in `path` from its header only (no pixel is decoded), checked
/// against the limits: call it to compare with a rig before reading a large file.
pub fn image_size(path: &Path) -> Result<(usize, usize), GeometryError> {
    let io = |source| GeometryError::Io { path: path.to_path_buf(), source };
    let file = bounded_read::open_without_blocking(path).map_err(io)?;
    let mut reader = std::io::BufReader::new(file);
    let container = sniff(reader.fill_buf().map_err(io)?);
    let (w, h) = header_size(path, container, reader)?;
    check_image_size(path, w, h)?;
    Ok((w as usize, h as usize))
}

/// Checks the header of in-memory image bytes: size within the limits.
pub(crate) fn check_header(path: &Path, bytes: &[u8]) -> Result<(), GeometryError> {
    let (w, h) = header_size(path, sniff(bytes), Cursor::new(bytes))?;
    check_image_size(path, w, h)
}

/// Fails when a JPEG stream ends before its end-of-image marker (a truncated file, which the
/// decoder would otherwise fill with grey). Walks the segment structure: marker segments are
/// skipped by their length (so an EXIF thumbnail's own end marker is not taken for the
/// file's), entropy-coded data up to the next marker; data after the end marker is allowed.
pub(crate) fn check_jpeg_complete(path: &Path, bytes: &[u8]) -> Result<(), GeometryError> {
    let truncated = |_| {
        format_err(
            path,
            format!(
                "is a truncated JPEG: its {} bytes end before the end-of-image marker (the file was cut short); copy or export it again",
                bytes.len()
            ),
        )
    };
    let mut pos = 2; // after SOI
    loop {
        // Find the next marker (0xFF followed by a non-0xFF byte; 0xFF fill bytes allowed).
        while pos < bytes.len() && bytes[pos] != 0xff {
            pos += 1;
        }
        while pos < bytes.len() && bytes[pos] == 0xff {
            pos += 1;
        }
        let Some(&marker) = bytes.get(pos) else { return Err(truncated(pos)) };
        pos += 1;
        match marker {
            0xd9 => return Ok(()),                 // EOI
            0x01 | 0xd0..=0xd7 | 0x00 => continue, // TEM, RSTn, stuffed byte: no length
            _ => {
                let len = match bytes.get(pos..pos + 2) {
                    Some(b) => usize::from(u16::from_be_bytes([b[0], b[1]])),
                    None => return Err(truncated(pos)),
                };
                if len < 2 || pos + len > bytes.len() {
                    return Err(truncated(pos));
                }
                pos += len;
                if marker == 0xda {
                    // Start of scan: entropy-coded data follows, in which 0xFF is followed
                    // by 0x00 (stuffing) or a restart marker; the loop above skips both.
                    while pos + 1 < bytes.len() {
                        if bytes[pos] == 0xff
                            && bytes[pos + 1] != 0x00
                            && !(0xd0..=0xd7).contains(&bytes[pos + 1])
                        {
                            break;
                        }
                        pos += 1;
                    }
                    if pos + 1 >= bytes.len() {
                        return Err(truncated(pos));
                    }
                }
            }
        }
    }
}
