//! Rig files on disk: the versioned JSON of [`Rig::to_json`] / [`Rig::from_json`] (and of
//! [`MultiRig`] and single cameras), read by [`read_rig`] alone.

use std::path::Path;

use crate::atomic::write_bytes_atomic;
pub use crate::rig_io::{AnyRig, Calibration};
use geometry::{GeometryError, MultiRig, Rig};

/// Handout thresholds (lab L2) on the reprojection RMS in a rig file's calibration report
/// (`kfuse calibrate` writes it, `kfuse rig show` and the viewer check it): colour RMS must
/// stay below 0.2 px, IR below 0.4 px.
pub const COLOR_RMS_LIMIT_PX: f64 = 0.2;
/// See [`COLOR_RMS_LIMIT_PX`].
pub const DEPTH_RMS_LIMIT_PX: f64 = 0.4;

/// The one reader of kfuse's rig and camera files: reads `path` once (at most
/// [`MAX_RIG_FILE_BYTES`], so a pipe or a FIFO works as a regular file does and a device
/// cannot make it read for ever) and tells apart by content a rig of several cameras (version
/// 2), a depth + colour rig (version 1) and a single-camera file, each validated. Every
/// command, the viewer and Python read rig files through this; [`read_pair`] adds the
/// plausibility check a depth + colour rig gets before fusion. Other tools' formats are
/// imported by [`crate::rig_io::import`].
pub fn read_rig(path: &Path) -> Result<AnyRig, GeometryError> {
    let text = read_rig_text(path)?;
    crate::rig_io::any_from_text(&text, path)
}

/// [`read_rig`]'s depth + colour rig ([`AnyRig::into_pair`]) checked to be a rig of real
/// cameras ([`Rig::check_plausible`]: focal lengths, image sizes, baseline); the error names
/// the file and the likely unit mistake. Without the check (`--force`), `read_rig(path)?
/// .into_pair(path)` and report [`Rig::plausibility_problems`] as warnings.
pub fn read_pair(path: &Path) -> Result<Rig, GeometryError> {
    let rig = read_rig(path)?.into_pair(path)?;
    rig.check_plausible().map_err(|e| GeometryError::Format {
        path: path.to_path_buf(),
        message: format!("{e} (pass --force if the rig really is meant this way)"),
    })?;
    Ok(rig)
}

/// Largest rig file read, bytes: 4 MiB. A depth + colour rig is about 3 KB and one of the
/// most cameras a rig may have (64, [`geometry::multi_rig::MAX_RIG_CAMERAS`]) about 100 KB;
/// the limit bounds what a wrong file, a device or a pipe can make kfuse read.
pub const MAX_RIG_FILE_BYTES: u64 = 4 << 20;

/// The text of a rig file, at most [`MAX_RIG_FILE_BYTES`] whatever the file is (a device or
/// a pipe states no size; see [`bounded_read`]); binary data and an empty file are refused.
fn read_rig_text(path: &Path) -> Result<String, GeometryError> {
    let format = |message: String| GeometryError::Format { path: path.to_path_buf(), message };
    let expected = bounded_read::Expected {
        what: "a rig file",
        fix: "give the rig JSON that `kfuse calibrate` or `kfuse rig import` wrote",
    };
    let bytes = bounded_read::read_bounded(path, MAX_RIG_FILE_BYTES, expected)
        .map_err(|source| GeometryError::Io { path: path.to_path_buf(), source })?;
    let len = bytes.len();
    let text = String::from_utf8(bytes).map_err(|_| {
        format(
            "not a kfuse rig file (binary, not JSON text); create one with `kfuse calibrate` or `kfuse rig import`"
                .into(),
        )
    })?;
    if text.trim_start_matches('\u{feff}').trim().is_empty() {
        return Err(format(format!(
            "is empty ({len} bytes{}): no rig in it; was it saved completely? Save or export the rig again",
            if len > 0 { ", all blank" } else { "" }
        )));
    }
    Ok(text)
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
        let back = read_pair(&path).unwrap();
        assert_eq!(back.depth, rig.depth);
        assert!(
            (back.color_from_depth.translation - rig.color_from_depth.translation).norm() < 1e-15
        );
        let mut mm = rig.clone();
        mm.color_from_depth.translation *= 1000.0;
        write_rig(&dir.join("mm.json"), &mm).unwrap();
        let err = read_pair(&dir.join("mm.json")).unwrap_err().to_string();
        assert!(
            err.contains("mm.json") && err.contains("T looks like millimetres: 52 → 0.052 m?"),
            "{err}"
        );
        let mm_path = dir.join("mm.json");
        assert_eq!(read_rig(&mm_path).unwrap().into_pair(&mm_path).unwrap().depth, rig.depth);
        let err = read_pair(&dir.join("nope.json")).unwrap_err().to_string();
        assert!(err.contains("nope.json"), "{err}");
        std::fs::write(dir.join("bad.json"), "{\"format\": 3}").unwrap();
        let err = read_pair(&dir.join("bad.json")).unwrap_err().to_string();
        assert!(err.contains("bad.json") && err.contains("not a kfuse rig file"), "{err}");
        std::fs::write(dir.join("image.png"), b"\x89PNG\r\n\x1a\n\xff\xfe").unwrap();
        let err = read_pair(&dir.join("image.png")).unwrap_err().to_string();
        assert!(err.contains("image.png") && err.contains("not a kfuse rig file"), "{err}");
    }

    /// [`read_rig`] tells the three kinds of file apart by content, and each conversion
    /// refuses the other kinds naming the file and what to do.
    #[test]
    fn read_rig_gives_each_kind_and_refuses_the_wrong_one() {
        let dir = std::env::temp_dir().join(format!("kfuse-rigkinds-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        // The simulator's Kinect pair (geometry's `synth` feature, a dev-dependency here).
        let rig = geometry::synth::kinect_rig();
        let camera = rig.depth;
        let pair_path = dir.join("pair.json");
        write_rig(&pair_path, &rig).unwrap();
        let mut multi = MultiRig::from_pair(&rig, Some("A"));
        let mut b = MultiRig::from_pair(&rig, Some("B")).cameras;
        for c in &mut b {
            c.camera_from_reference.translation.x += 1.0;
        }
        multi.cameras.extend(b);
        let multi_path = dir.join("multi.json");
        write_multi_rig(&multi_path, &multi).unwrap();
        let camera_path = dir.join("ir.json");
        std::fs::write(
            &camera_path,
            crate::rig_io::camera_file_json(&camera, Some(crate::rig_io::Role::Depth), &None),
        )
        .unwrap();

        let pair = read_rig(&pair_path).unwrap().into_pair(&pair_path).unwrap();
        assert_eq!(pair.depth, rig.depth);
        assert_eq!(pair.color, rig.color);
        assert!(read_rig(&pair_path).unwrap().into_multi().is_none());
        let back = read_rig(&multi_path).unwrap().into_multi().expect("a rig of four cameras");
        assert_eq!(back.cameras.len(), 4);
        assert_eq!(back.cameras[3].model, rig.color);
        let e = read_rig(&multi_path).unwrap().into_pair(&multi_path).unwrap_err().to_string();
        assert!(e.contains("multi.json") && e.contains("a rig of 4 cameras"), "{e}");
        assert!(e.contains("--sensor SERIAL"), "{e}");
        let e = read_rig(&camera_path).unwrap().into_pair(&camera_path).unwrap_err().to_string();
        assert!(
            e.contains("ir.json") && e.contains("single-camera file (the depth camera)"),
            "{e}"
        );
        match read_rig(&camera_path).unwrap().into_calibration(&camera_path).unwrap() {
            Calibration::Camera { camera: c, .. } => assert_eq!(c, camera),
            other => panic!("a camera file read as {other:?}"),
        }
        std::fs::write(dir.join("empty.json"), "  \n").unwrap();
        let e = read_rig(&dir.join("empty.json")).unwrap_err().to_string();
        assert!(e.contains("empty.json") && e.contains("is empty (3 bytes, all blank)"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
