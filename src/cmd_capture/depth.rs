//! The depth-calibration parts of `kfuse capture` (issue 16): `--sim-depth-error` and
//! `capture scene --rig`'s corrected depth beside the raw one.

use std::path::Path;

use anyhow::{Result, bail};
use geometry::depth_correction::DepthCorrection;
use kinect_usb::raw::{HEIGHT, WIDTH};
use kinect_usb::sim::depth_error::DepthError;

/// Largest injected offset or radial term, mm, and scale accepted by `--sim-depth-error`: a
/// metre of error or a scale of 50 % is a typing mistake, not a sensor.
pub const MAX_SIM_DEPTH_ERROR_MM: f64 = 1000.0;
pub const MAX_SIM_DEPTH_SCALE: f64 = 0.5;

/// Parses `--sim-depth-error`: `OFFSET_MM,SCALE,RADIAL_MM` or `kinect`.
pub fn parse_depth_error(s: &str) -> std::result::Result<DepthError, String> {
    if s.trim() == "kinect" {
        return Ok(kinect_usb::sim::depth_error::KINECT_LIKE);
    }
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|_| format!("`{p}` is not a number")))
        .collect::<std::result::Result<_, _>>()?;
    let [offset_mm, scale, radial_mm] = v[..] else {
        return Err(format!(
            "give OFFSET_MM,SCALE,RADIAL_MM (3 numbers, e.g. 24,0.005,10) or kinect, not `{s}`"
        ));
    };
    if !(offset_mm.abs() <= MAX_SIM_DEPTH_ERROR_MM && radial_mm.abs() <= MAX_SIM_DEPTH_ERROR_MM) {
        return Err(format!("offset and radial must be within ±{MAX_SIM_DEPTH_ERROR_MM} mm"));
    }
    if !(scale.abs() <= MAX_SIM_DEPTH_SCALE) {
        return Err(format!(
            "the scale is a fraction (0.005 = 0.5 %) within ±{MAX_SIM_DEPTH_SCALE}"
        ));
    }
    Ok(DepthError { offset_mm, scale, radial_mm })
}

/// `capture scene --rig`: the rig's depth correction (a rig without one is refused: the
/// corrected file would be the raw one again).
pub fn scene_depth_correction(path: &Path) -> Result<DepthCorrection> {
    let rig = kfuse_io::rig::read_rig(path)
        .and_then(|r| r.into_pair(path))
        .map_err(|e| anyhow::anyhow!("--rig {e}"))?;
    match rig.depth_correction {
        Some(c) => Ok(*c),
        None => bail!(
            "--rig {}: the rig has no depth_correction; add one with `kfuse calibrate --rig {} --ir 'ir_*.png' --depth 'depth_*.png'`",
            path.display(),
            path.display()
        ),
    }
}

/// Writes `NAME_depth_corrected.png` beside a scene shot's raw depth (16-bit mm).
pub fn write_corrected(raw_depth: &Path, depth_mm: &[f32], c: &DepthCorrection) -> Result<()> {
    let name = raw_depth.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let path = raw_depth.with_file_name(name.replace("_depth.png", "_depth_corrected.png"));
    let mut img = geometry::Image::from_vec(WIDTH, HEIGHT, depth_mm.to_vec())?;
    c.correct_image(&mut img, 1e-3)?;
    kfuse_capture::shots::write_png16(&path, img.data(), WIDTH, HEIGHT)?;
    Ok(())
}
