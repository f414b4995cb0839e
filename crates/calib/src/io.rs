//! Image reading for the calibration tools (the only module of this crate that opens files).

use std::path::Path;

use geometry::Image;

use crate::CalibError;

/// Reads any 8/16-bit image file as 8-bit grey (16-bit is scaled down by 256).
pub fn read_gray(path: &Path) -> Result<Image<u8>, CalibError> {
    let img = image::open(path).map_err(|e| match e {
        image::ImageError::IoError(source) => CalibError::Io { path: path.to_path_buf(), source },
        other => CalibError::Format {
            path: path.to_path_buf(),
            message: format!("cannot decode image: {other}"),
        },
    })?;
    let g = img.to_luma8();
    Ok(Image::from_vec(g.width() as usize, g.height() as usize, g.into_raw())?)
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
