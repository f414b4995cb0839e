//! Image reading for the calibration tools.
//!
//! The modules of this crate that open files (everything else takes values in memory):
//!
//! * `io` (this module): the images to detect in (`kfuse_io::images::read_gray`,
//!   `image::open` for the bit depth).
//! * `bouguet`: Bouguet's `Calib_Results*.mat` through `kfuse_io::bouguet` (rig and camera
//!   files of every format are read in `kfuse_io::rig_io`).
//! * `files`: writes calibration files (`write_text`, atomically through `kfuse_io::atomic`).
//! * `pipeline`: a run's images through this module, `pipeline::inputs` the first image's
//!   header (`kfuse_io::image_header`) and the patterns' matches (`glob`), `pipeline::depth`
//!   the depth images (`kfuse_io::images::read_depth`, `image::open` for the 16-bit IR) and
//!   `--rig` (`kfuse_io::rig::read_rig`).

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

/// One image's share of a calibration run's time, for `report.json`'s `timings_ms`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ImageTiming {
    /// The camera ("IR", "colour").
    pub camera: String,
    /// The image's file name.
    pub name: String,
    /// Reading and decoding the file to 8-bit grey ([`read_gray`]), ms.
    pub read_ms: f64,
    /// Detecting the board (`crate::detect::detect_views_timed`), ms; `None` for an image
    /// that could not be read.
    pub detect_ms: Option<f64>,
}

/// [`read_gray`] of every file on rayon's pool, calling `progress` after each, with each
/// file's read-and-decode time in ms (its pool thread's wall time: the files are read in
/// parallel, so the sum can exceed the call's wall time).
pub fn read_gray_all(
    files: &[std::path::PathBuf],
    progress: &(dyn Fn() + Sync),
) -> Vec<(Result<Image<u8>, CalibError>, f64)> {
    use rayon::prelude::*;
    files
        .par_iter()
        .map(|f| {
            let t = std::time::Instant::now();
            let r = read_gray(f);
            let ms = geometry::timing::ms_since(t);
            progress();
            (r, ms)
        })
        .collect()
}
