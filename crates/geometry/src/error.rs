//! The error type of the `geometry` crate.

use std::path::PathBuf;

/// Everything that can go wrong in `geometry`: invalid models, sizes that do not match,
/// unreadable or malformed files (always naming the file).
#[derive(Debug, thiserror::Error)]
pub enum GeometryError {
    /// A camera or rig parameter is not finite or not physically meaningful.
    #[error("invalid camera parameter: {0}")]
    InvalidParameter(String),
    /// Two images (or an image and a camera model) disagree about their size.
    #[error("size mismatch: {what} is {got_w}x{got_h}, expected {want_w}x{want_h}")]
    SizeMismatch {
        /// What was being checked, e.g. "depth image 'scene/depth.png'".
        what: String,
        /// Width found.
        got_w: usize,
        /// Height found.
        got_h: usize,
        /// Width expected.
        want_w: usize,
        /// Height expected.
        want_h: usize,
    },
    /// Input data that cannot be used (all-invalid depth, NaN where numbers are required...).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// A file was read but its content is not what was expected.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong and, where possible, how to fix it.
        message: String,
    },
}
