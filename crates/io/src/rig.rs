//! Rig files on disk: the versioned JSON of [`Rig::to_json`] / [`Rig::from_json`].

use std::path::Path;

use crate::atomic::write_bytes_atomic;
use geometry::{GeometryError, MultiRig, Rig};

/// Handout thresholds (lab L2) on the reprojection RMS in a rig file's calibration report
/// (`kfuse calibrate` writes it, `kfuse rig show` and the viewer check it): colour RMS must
/// stay below 0.2 px, IR below 0.4 px.
pub const COLOR_RMS_LIMIT_PX: f64 = 0.2;
/// See [`COLOR_RMS_LIMIT_PX`].
pub const DEPTH_RMS_LIMIT_PX: f64 = 0.4;

/// Reads and validates a rig file, and checks that it can be a rig of real cameras
/// ([`Rig::check_plausible`]: focal lengths, image sizes, baseline); the error names the file
/// and the likely unit mistake. Every command and the viewer read rigs through this.
pub fn read_rig(path: &Path) -> Result<Rig, GeometryError> {
    let rig = read_rig_unchecked(path)?;
    rig.check_plausible().map_err(|e| GeometryError::Format {
        path: path.to_path_buf(),
        message: format!("{e} (pass --force if the rig really is meant this way)"),
    })?;
    Ok(rig)
}

/// Reads and validates a rig file without the plausibility check (`--force`): the caller
/// reports [`Rig::plausibility_problems`] as warnings.
pub fn read_rig_unchecked(path: &Path) -> Result<Rig, GeometryError> {
    let bytes = read_rig_bytes(path)?;
    let text = String::from_utf8(bytes).map_err(|_| GeometryError::Format {
        path: path.to_path_buf(),
        message: "not a kfuse rig file (binary, not JSON text); create one with `kfuse calibrate`"
            .into(),
    })?;
    let rig = Rig::from_json(&text, path)?;
    rig.validate()
        .map_err(|e| GeometryError::Format { path: path.to_path_buf(), message: e.to_string() })?;
    Ok(rig)
}

/// Largest rig file read, bytes: 4 MiB. A depth + colour rig is about 3 KB and one of the
/// most cameras a rig may have (64, [`geometry::multi_rig::MAX_RIG_CAMERAS`]) about 100 KB;
/// the limit bounds what a wrong file, a device or a pipe can make kfuse read.
pub const MAX_RIG_FILE_BYTES: u64 = 4 << 20;

/// The bytes of a rig file, at most [`MAX_RIG_FILE_BYTES`] whatever the file is (a device or
/// a pipe states no size; see [`bounded_read`]).
pub fn read_rig_bytes(path: &Path) -> Result<Vec<u8>, GeometryError> {
    let expected = bounded_read::Expected {
        what: "a rig file",
        fix: "give the rig JSON that `kfuse calibrate` or `kfuse rig import` wrote",
    };
    bounded_read::read_bounded(path, MAX_RIG_FILE_BYTES, expected)
        .map_err(|source| GeometryError::Io { path: path.to_path_buf(), source })
}

/// Writes a rig file atomically.
pub fn write_rig(path: &Path, rig: &Rig) -> Result<(), GeometryError> {
    write_bytes_atomic(path, rig.to_json().as_bytes())
}

/// Writes a rig file of any number of cameras atomically (a depth + colour pair as version 1).
pub fn write_multi_rig(path: &Path, rig: &MultiRig) -> Result<(), GeometryError> {
    rig.validate()
        .map_err(|e| GeometryError::Format { path: path.to_path_buf(), message: e.to_string() })?;
    write_bytes_atomic(path, rig.to_json().as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use geometry::{CameraModel, Distortion, Intrinsics, RigidTransform};
    use nalgebra::Vector3;

    #[test]
    fn rig_file_round_trip_and_errors() {
        let dir = std::env::temp_dir().join(format!("kfuse-rigio-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let depth = CameraModel::new(
            512,
            424,
            Intrinsics::new(368.1, 368.1, 261.7, 202.5),
            Distortion { k1: 0.084, k2: -0.27, p1: 0.0, p2: 0.0, k3: 0.10 },
        );
        let color = CameraModel::new(
            1920,
            1080,
            Intrinsics::new(1062.5, 1066.5, 959.5, 539.5),
            Distortion::NONE,
        );
        let rig = Rig::new(
            depth,
            color,
            RigidTransform::from_axis_angle(
                Vector3::new(0.0, 0.01, 0.0),
                Vector3::new(-0.052, 0.0, 0.0),
            ),
        );
        let path = dir.join("rig.json");
        write_rig(&path, &rig).unwrap();
        let back = read_rig(&path).unwrap();
        assert_eq!(back.depth, rig.depth);
        assert!(
            (back.color_from_depth.translation - rig.color_from_depth.translation).norm() < 1e-15
        );
        let mut mm = rig.clone();
        mm.color_from_depth.translation *= 1000.0;
        write_rig(&dir.join("mm.json"), &mm).unwrap();
        let err = read_rig(&dir.join("mm.json")).unwrap_err().to_string();
        assert!(
            err.contains("mm.json") && err.contains("T looks like millimetres: 52 → 0.052 m?"),
            "{err}"
        );
        assert_eq!(read_rig_unchecked(&dir.join("mm.json")).unwrap().depth, rig.depth);
        let err = read_rig(&dir.join("nope.json")).unwrap_err().to_string();
        assert!(err.contains("nope.json"), "{err}");
        std::fs::write(dir.join("bad.json"), "{\"format\": 3}").unwrap();
        let err = read_rig(&dir.join("bad.json")).unwrap_err().to_string();
        assert!(err.contains("bad.json") && err.contains("not a kfuse rig file"), "{err}");
        std::fs::write(dir.join("image.png"), b"\x89PNG\r\n\x1a\n\xff\xfe").unwrap();
        let err = read_rig(&dir.join("image.png")).unwrap_err().to_string();
        assert!(err.contains("image.png") && err.contains("not a kfuse rig file"), "{err}");
    }
}
