//! The one error type of this crate.

use std::path::PathBuf;

/// What can go wrong while reading, processing or writing a sequence. Every variant names the
/// file it is about where there is one.
#[derive(Debug, thiserror::Error)]
pub enum SequenceError {
    /// The recording could not be read or is damaged (the reader's message says how to go on).
    #[error(transparent)]
    Recording(#[from] kinect_usb::KinectError),
    /// A frame folder or glob that gives no usable frame, or a file in it that is not one.
    #[error("{path}: {message}")]
    Input {
        /// The folder, pattern or file.
        path: PathBuf,
        /// What is wrong and what to do.
        message: String,
    },
    /// Registration or image work refused its input (a rig that does not fit the frames).
    #[error(transparent)]
    Geometry(#[from] geometry::GeometryError),
    /// The GPU path failed.
    #[error(transparent)]
    Gpu(#[from] fusion_gpu::GpuError),
    /// Encoding an output image.
    #[error("{path}: cannot encode: {message}")]
    Encode {
        /// The output file.
        path: PathBuf,
        /// The encoder's message.
        message: String,
    },
    /// A pipeline thread could not be started or stopped unexpectedly.
    #[error("pipeline: {0}")]
    Pipeline(String),
    /// An option of the run that cannot work (`--threads 3`), before anything is opened.
    #[error("{0}")]
    Options(String),
    /// What the run was doing when `source` happened (`processing REC.kfrec`).
    #[error("{what}")]
    Context {
        /// What was being done.
        what: String,
        /// What went wrong.
        #[source]
        source: Box<SequenceError>,
    },
}

impl SequenceError {
    /// An [`SequenceError::Input`] for `path`.
    pub fn input(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        SequenceError::Input { path: path.into(), message: message.into() }
    }

    /// This error with what was being done when it happened.
    pub fn context(self, what: impl Into<String>) -> Self {
        SequenceError::Context { what: what.into(), source: Box::new(self) }
    }
}

/// This crate's result type.
pub type Result<T, E = SequenceError> = std::result::Result<T, E>;
