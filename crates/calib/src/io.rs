//! Image reading for the calibration tools (the only module of this crate that opens files).

use std::path::Path;

use geometry::Image;

use crate::CalibError;

/// Reads any 8/16-bit image file as 8-bit grey (16-bit is scaled down by 256).
pub fn read_gray(path: &Path) -> Result<Image<u8>, CalibError> {
    let img = image::open(path).map_err(|e| match e {
        image::ImageError::IoError(source) => CalibError::Io { path: path.to_path_buf(), source },
        other => CalibError::Format { path: path.to_path_buf(), message: format!("cannot decode image: {other}") },
    })?;
    let g = img.to_luma8();
    Ok(Image::from_vec(g.width() as usize, g.height() as usize, g.into_raw())?)
}
