//! The viewer's error type.

use std::path::PathBuf;

/// Everything that can go wrong while opening or fusing a folder. Each variant names the
/// file (or folder) and says how to fix it; the app shows it in an error panel.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    /// The folder does not exist or is not a folder.
    #[error(
        "{path}: not a folder; pass the output folder of `kfuse fuse`, or a capture folder with rig.json, color.png and depth.png"
    )]
    NotAFolder {
        /// The path given.
        path: PathBuf,
    },
    /// The folder holds neither `summary.json`, `rig.json` nor `kinect_params.json`.
    #[error(
        "{path}: neither summary.json (a `kfuse fuse` output) nor rig.json or kinect_params.json (a capture folder) is in this folder"
    )]
    UnknownFolder {
        /// The folder.
        path: PathBuf,
    },
    /// A `kfuse capture` folder (`kinect_params.json`) without a complete shot.
    #[error(
        "{path}: no shot to show; expected NAME_color.jpg + NAME_depth.png (`kfuse capture scene`) or color_NNNN.jpg + depth_NNNN.png (`kfuse capture calib`) next to kinect_params.json"
    )]
    NoShot {
        /// The folder.
        path: PathBuf,
    },
    /// `kfuse view --shot NAME`: no such shot in the folder.
    #[error("{path}: no shot '{shot}' (--shot); shots there: {shots}")]
    UnknownShot {
        /// The folder.
        path: PathBuf,
        /// The name asked for.
        shot: String,
        /// The shots the folder has (or why there are none).
        shots: String,
    },
    /// A file the folder needs is missing.
    #[error("{path}: missing; {hint}")]
    MissingFile {
        /// The file that was looked for.
        path: PathBuf,
        /// What it is and where it should come from.
        hint: String,
    },
    /// A rig of several cameras or its merged cloud could not be read (the message names the
    /// file).
    #[error("{0}")]
    Rig(String),
    /// A file exists but could not be read or parsed.
    #[error("{path}: {message}")]
    BadFile {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// An image does not match its camera in the rig.
    #[error(
        "{path} is {got_w}x{got_h}, but the rig says the {camera} camera is {want_w}x{want_h}; use the rig this image was captured with"
    )]
    SizeMismatch {
        /// The image file.
        path: PathBuf,
        /// Which camera.
        camera: &'static str,
        /// Image width.
        got_w: usize,
        /// Image height.
        got_h: usize,
        /// Rig width.
        want_w: usize,
        /// Rig height.
        want_h: usize,
    },
    /// The fusion pipeline refused the inputs.
    #[error("fusion failed on {source_name}: {message}")]
    Fusion {
        /// Which data set.
        source_name: String,
        /// The pipeline's message.
        message: String,
    },
    /// A shot or parameter file could not be written.
    #[error("{path}: cannot write ({message}); check that the output folder is writable (--out)")]
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// The sensor could not be opened or streamed.
    #[error("{message}")]
    Device {
        /// The driver's message (names the problem and the fix).
        message: String,
    },
}

impl From<kfuse_capture::CaptureError> for ViewerError {
    fn from(e: kfuse_capture::CaptureError) -> Self {
        match e {
            kfuse_capture::CaptureError::Write { path, message } => {
                ViewerError::Write { path, message }
            }
            e => ViewerError::Device { message: e.to_string() },
        }
    }
}
