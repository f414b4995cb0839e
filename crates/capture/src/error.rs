//! The crate's one error type.

use std::path::PathBuf;

use kinect_usb::KinectError;

/// What can go wrong while capturing.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// No Kinect v2 on the bus (or no USB at all); the message says what to check.
    #[error("{}", no_sensor_message(cause))]
    NoSensor {
        /// What the driver reported.
        cause: KinectError,
    },
    /// The sensor is claimed by another program.
    #[error("{0}\nhint: run `kfuse devices` to see which sensors are free")]
    Busy(KinectError),
    /// The device or the stream failed (unplugged, protocol, recording).
    #[error(transparent)]
    Device(#[from] KinectError),
    /// A colour-camera or LED setting was refused by the sensor.
    #[error("applying {what}: {source}")]
    Setting {
        /// The setting, e.g. `--exposure manual:20,2`.
        what: String,
        /// The sensor's refusal.
        source: KinectError,
    },
    /// A depth frame did not decode.
    #[error("depth decoding failed: {0}")]
    Decode(KinectError),
    /// A file could not be written (nothing half-written is left under its name).
    #[error("cannot write {}: {message}", path.display())]
    Write {
        /// The file or folder.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// A file format error from `kfuse-io` (atomic writes, PNG encoding).
    #[error(transparent)]
    File(#[from] geometry::GeometryError),
    /// An invalid configuration value (e.g. a drop rate outside `[0, 1]`).
    #[error("invalid capture configuration: {0}")]
    Config(String),
}

/// The driver's message, followed by what to check (power, USB 3 port, udev rule) unless the
/// message is already that.
fn no_sensor_message(cause: &KinectError) -> String {
    match cause {
        KinectError::NotFound => cause.to_string(),
        _ => format!("{cause}\n{}", KinectError::NotFound),
    }
}

impl CaptureError {
    /// The driver's error behind this one, if any (to tell an unplug or the end of a
    /// recording from other failures).
    pub fn kinect(&self) -> Option<&KinectError> {
        match self {
            CaptureError::NoSensor { cause: e }
            | CaptureError::Busy(e)
            | CaptureError::Device(e)
            | CaptureError::Setting { source: e, .. }
            | CaptureError::Decode(e) => Some(e),
            _ => None,
        }
    }

    /// True when the sensor went away (unplugged, lost power).
    pub fn is_disconnected(&self) -> bool {
        matches!(self.kinect(), Some(KinectError::Disconnected { .. }))
    }

    /// True when a replayed recording ran out of frames.
    pub fn is_end_of_stream(&self) -> bool {
        matches!(self.kinect(), Some(KinectError::EndOfStream))
    }

    pub(crate) fn write(path: &std::path::Path, e: impl std::fmt::Display) -> Self {
        CaptureError::Write { path: path.to_path_buf(), message: e.to_string() }
    }
}
