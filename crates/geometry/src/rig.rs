//! The rig calibration: both cameras and `color_from_depth`, and its versioned JSON form.
//!
//! ```json
//! {
//!   "format": "kfuse-rig", "version": 1,
//!   "units": "lengths in metres, intrinsics in pixels, rotations as row-major matrices",
//!   "depth_camera": { "width": 512, "height": 424, "fx": ..., "fy": ..., "cx": ..., "cy": ...,
//!                     "skew": 0, "k1": ..., "k2": ..., "p1": ..., "p2": ..., "k3": ... },
//!   "color_camera": { ... same fields ... },
//!   "color_from_depth": { "rotation": [[...],[...],[...]], "translation_m": [x, y, z] },
//!   "calibration": { ... optional report written by `kfuse calibrate` ... }
//! }
//! ```
//! `color_from_depth` maps depth-camera points into the colour camera: `X_c = R·X_d + T`.

use serde::{Deserialize, Serialize};

use crate::{CameraModel, GeometryError, RigidTransform};

/// The value of the `format` field.
pub const RIG_FORMAT: &str = "kfuse-rig";
/// The newest rig file version this build writes and reads.
pub const RIG_VERSION: u32 = 1;
const RIG_UNITS: &str = "lengths in metres, intrinsics in pixels, rotations as row-major matrices";

/// A calibrated depth + colour camera pair.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    /// The depth (IR / time-of-flight) camera; its frame is the rig's reference.
    pub depth: CameraModel,
    /// The colour camera.
    pub color: CameraModel,
    /// `X_color = R · X_depth + T`, metres.
    pub color_from_depth: RigidTransform,
    /// The calibration report (errors, standard deviations, board, per-image RMS) as written
    /// by `kfuse calibrate`, kept verbatim; `None` for rigs from other sources.
    pub calibration: Option<serde_json::Value>,
}

#[derive(Serialize, Deserialize)]
struct RigFile {
    format: String,
    version: u32,
    #[serde(default)]
    units: String,
    depth_camera: CameraModel,
    color_camera: CameraModel,
    color_from_depth: RigidTransform,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    calibration: Option<serde_json::Value>,
}

impl Rig {
    /// A rig without a calibration report.
    pub fn new(depth: CameraModel, color: CameraModel, color_from_depth: RigidTransform) -> Self {
        Self { depth, color, color_from_depth, calibration: None }
    }

    /// Checks both cameras.
    pub fn validate(&self) -> Result<(), GeometryError> {
        self.depth.validate()?;
        self.color.validate()
    }

    /// The rig as pretty-printed JSON (the rig file format above).
    pub fn to_json(&self) -> String {
        let file = RigFile {
            format: RIG_FORMAT.into(),
            version: RIG_VERSION,
            units: RIG_UNITS.into(),
            depth_camera: self.depth,
            color_camera: self.color,
            color_from_depth: self.color_from_depth,
            calibration: self.calibration.clone(),
        };
        // Serialising plain numbers and strings cannot fail.
        serde_json::to_string_pretty(&file).unwrap_or_default()
    }

    /// Parses a rig file's text. `source` names the file in error messages.
    pub fn from_json(text: &str, source: &std::path::Path) -> Result<Self, GeometryError> {
        let format_err =
            |message: String| GeometryError::Format { path: source.to_path_buf(), message };
        let file: RigFile = serde_json::from_str(text).map_err(|e| {
            format_err(format!("not a kfuse rig file ({e}); create one with `kfuse calibrate`"))
        })?;
        if file.format != RIG_FORMAT {
            return Err(format_err(format!(
                "format is '{}', expected '{RIG_FORMAT}'",
                file.format
            )));
        }
        if file.version > RIG_VERSION {
            return Err(format_err(format!(
                "rig file version {} is newer than this kfuse understands ({RIG_VERSION}); upgrade kfuse",
                file.version
            )));
        }
        let rig = Rig {
            depth: file.depth_camera,
            color: file.color_camera,
            color_from_depth: file.color_from_depth,
            calibration: file.calibration,
        };
        rig.validate().map_err(|e| format_err(e.to_string()))?;
        Ok(rig)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Distortion, Intrinsics};
    use nalgebra::Vector3;
    use std::path::Path;

    #[test]
    fn json_round_trip_keeps_every_parameter() {
        let depth = CameraModel::new(
            512,
            424,
            Intrinsics::new(365.0, 365.0, 255.5, 211.5),
            Distortion { k1: 0.098, k2: -0.22, p1: 0.004, p2: 0.0016, k3: 0.0 },
        );
        let color = CameraModel::new(
            1920,
            1080,
            Intrinsics::new(1060.0, 1060.0, 959.5, 539.5),
            Distortion::NONE,
        );
        let t = RigidTransform::from_axis_angle(
            Vector3::new(-0.001, 0.025, 0.007),
            Vector3::new(-0.052, -0.0003, 0.0006),
        );
        let mut rig = Rig::new(depth, color, t);
        rig.calibration = Some(serde_json::json!({"rms_px": 0.1}));
        let back = Rig::from_json(&rig.to_json(), Path::new("rig.json")).unwrap();
        assert_eq!(back.depth, rig.depth);
        assert_eq!(back.color, rig.color);
        assert!((back.color_from_depth.matrix() - t.matrix()).abs().max() < 1e-15);
        assert_eq!(back.calibration, rig.calibration);
    }

    #[test]
    fn wrong_format_and_future_version_are_named() {
        let err = Rig::from_json("{}", Path::new("x/rig.json")).unwrap_err().to_string();
        assert!(err.contains("x/rig.json"), "{err}");
        let depth = CameraModel::new(4, 4, Intrinsics::new(1.0, 1.0, 1.5, 1.5), Distortion::NONE);
        let text = Rig::new(depth, depth, RigidTransform::identity())
            .to_json()
            .replace("\"version\": 1", "\"version\": 99");
        let err = Rig::from_json(&text, Path::new("rig.json")).unwrap_err().to_string();
        assert!(err.contains("upgrade"), "{err}");
    }
}
