//! Image reading for the calibration tools (the only module of this crate that opens files).

use std::path::Path;

use geometry::Image;

use crate::CalibError;

/// Reads an image file as 8-bit grey for detection: `kfuse_io::images::read_gray`, the one
/// reader the command line uses too (size limits, a JPEG cut short refused, colour as luma,
/// 16-bit scaled by the image's range).
pub fn read_gray(path: &Path) -> Result<Image<u8>, CalibError> {
    Ok(kfuse_io::images::read_gray(path)?)
}

/// True when the file holds 8-bit samples (grey or colour); false for 16-bit or float
/// images (depth).
pub fn is_8bit(path: &Path) -> Result<bool, CalibError> {
    let img = image::open(path).map_err(|e| CalibError::Format {
        path: path.to_path_buf(),
        message: format!("cannot decode image: {e}"),
    })?;
    Ok(matches!(
        img.color(),
        image::ColorType::L8
            | image::ColorType::La8
            | image::ColorType::Rgb8
            | image::ColorType::Rgba8
    ))
}
