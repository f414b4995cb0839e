//! Stage 4a: shot files. A shot is the colour JPEG, the IR and the depth of one moment; the
//! three are written into a staging folder inside the output folder and then moved into place
//! (same filesystem, so each move is a rename): a failed write leaves none of them, and a
//! signal (which only sets a flag, checked between shots) cannot separate them.

use std::path::{Path, PathBuf};

use kfuse_io::atomic::write_atomic;
use kfuse_io::images::png16_value;
use kinect_usb::device::DeviceInfo;
use kinect_usb::orientation::Orientation;
use kinect_usb::raw::{HEIGHT, WIDTH};

use crate::CaptureError;

/// Name prefix of the staging folder inside the output folder (followed by the process id, so
/// that a leftover of a killed capture can be recognised and removed).
pub const STAGING_PREFIX: &str = ".kfuse-shot-staging-";

/// Colour image size of the Kinect v2, pixels (`kinect_params.json`).
const COLOR_SIZE: (u32, u32) = (1920, 1080);

/// The two kinds of shot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShotKind {
    /// A checkerboard pair for `kfuse calibrate`: `color_NNNN.jpg`, `ir_NNNN.png`, `depth_NNNN.png`.
    Calib,
    /// A scene: `NAME_color.jpg`, `NAME_ir.png`, `NAME_depth.png`.
    Scene,
}

/// The colour, IR and depth files of shot `name` in `out` (crate docs).
pub fn shot_files(out: &Path, name: &str, kind: ShotKind) -> [PathBuf; 3] {
    let (stem, suffix) = match kind {
        ShotKind::Scene => (format!("{name}_"), String::new()),
        ShotKind::Calib => (String::new(), format!("_{name}")),
    };
    [
        out.join(format!("{stem}color{suffix}.jpg")),
        out.join(format!("{stem}ir{suffix}.png")),
        out.join(format!("{stem}depth{suffix}.png")),
    ]
}

/// The version of `kinect_params.json` written: 2 holds the parameters of images in the
/// scene orientation (`image_orientation`); version 1 files (kfuse before the orientation
/// rule) hold the sensor's own, of mirrored images.
pub const PARAMS_VERSION: u64 = 2;

/// Writes `out/kinect_params.json`: the factory intrinsics of both cameras, of the images
/// kfuse writes (`kinect_usb::orientation::Orientation::Scene`: the device's parameters
/// mirrored, [`kinect_usb::params::DepthParams::mirrored`] and
/// [`kinect_usb::params::ColorParams::mirrored`]).
pub fn write_params_json(out: &Path, info: &DeviceInfo) -> Result<(), CaptureError> {
    let d = &info.depth_params.mirrored();
    let c = &info.color_params.mirrored();
    let v = serde_json::json!({
        "format": "kfuse-kinect-params",
        "version": PARAMS_VERSION,
        "image_orientation": Orientation::Scene.name(),
        "serial": info.serial,
        "firmware": info.firmware,
        "units": "pixels; shift_d and shift_m in millimetres",
        "depth": { "width": WIDTH, "height": HEIGHT, "fx": d.fx, "fy": d.fy, "cx": d.cx, "cy": d.cy,
                   "k1": d.k1, "k2": d.k2, "k3": d.k3, "p1": d.p1, "p2": d.p2 },
        "color": { "width": COLOR_SIZE.0, "height": COLOR_SIZE.1, "fx": c.f, "fy": c.f, "cx": c.cx, "cy": c.cy,
                   "shift_d": c.shift_d, "shift_m": c.shift_m, "mx": c.mx, "my": c.my },
    });
    let path = out.join("kinect_params.json");
    write_atomic(&path, |w| {
        serde_json::to_writer_pretty(&mut *w, &v)?;
        w.write_all(b"\n")
    })
    .map_err(|e| CaptureError::write(&path, e))
}

/// Writes `values` (a `width × height` row-major image: depth in mm, or IR) as a 16-bit PNG,
/// atomically, with `kfuse_io::images::png16_value`'s rule: rounded, clamped to `1..=65535`;
/// non-finite and non-positive values become 0 (invalid).
pub fn write_png16(
    path: &Path,
    values: &[f32],
    width: usize,
    height: usize,
) -> Result<(), CaptureError> {
    let px = values.iter().map(|&v| png16_value(f64::from(v))).collect();
    kfuse_io::images::write_png16(path, width, height, px).map_err(|e| CaptureError::write(path, e))
}

/// Removes staging folders left in `out` by killed captures (their process no longer runs).
pub fn remove_stale_staging(out: &Path) {
    let Ok(entries) = std::fs::read_dir(out) else { return };
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(pid) = name.to_str().and_then(|n| n.strip_prefix(STAGING_PREFIX)) else {
            continue;
        };
        let alive = pid.parse::<u32>().is_ok_and(|p| Path::new(&format!("/proc/{p}")).exists());
        if !alive && e.path().is_dir() {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

/// Writes shots into one output folder, each through the staging folder (module docs).
#[derive(Debug)]
pub struct ShotWriter {
    out: PathBuf,
    stage: PathBuf,
}

impl ShotWriter {
    /// A writer into `out` (created if missing; staging folders of killed captures in it are
    /// removed).
    pub fn new(out: &Path) -> Result<Self, CaptureError> {
        std::fs::create_dir_all(out).map_err(|e| CaptureError::write(out, e))?;
        remove_stale_staging(out);
        let stage = out.join(format!("{STAGING_PREFIX}{}", std::process::id()));
        Ok(Self { out: out.to_path_buf(), stage })
    }

    /// The output folder.
    pub fn out(&self) -> &Path {
        &self.out
    }

    /// Writes one shot: `files` (from [`shot_files`], inside the output folder) receive the
    /// sensor's colour JPEG mirrored into the scene orientation
    /// without loss (`kfuse_io::sensor_color::mirrored_jpeg`: the IR and depth, from the decoder, are in it
    /// already) and the IR and depth (mm) as 16-bit PNGs. All three appear together or none
    /// does. Error: the colour frame does not decode, or a write failed (the staging folder is
    /// removed).
    pub fn write(
        &self,
        files: &[PathBuf; 3],
        color_jpeg: &[u8],
        ir: &[f32],
        depth_mm: &[f32],
    ) -> Result<(), CaptureError> {
        let stage = &self.stage;
        let staged = files.clone().map(|f| stage.join(f.file_name().unwrap_or_default()));
        let color = kfuse_io::sensor_color::mirrored_jpeg(color_jpeg).map_err(|m| {
            CaptureError::write(&files[0], format!("{m} (a damaged frame from the sensor)"))
        })?;
        let r = std::fs::create_dir_all(stage)
            .map_err(|e| CaptureError::write(stage, e))
            .and_then(|()| {
                write_atomic(&staged[0], |w| w.write_all(&color))
                    .map_err(|e| CaptureError::write(&files[0], e))
            })
            .and_then(|()| write_png16(&staged[1], ir, WIDTH, HEIGHT))
            .and_then(|()| write_png16(&staged[2], depth_mm, WIDTH, HEIGHT))
            .and_then(|()| {
                staged.iter().zip(files).try_for_each(|(from, to)| {
                    std::fs::rename(from, to).map_err(|e| {
                        CaptureError::write(to, format!("moving it from {}: {e}", from.display()))
                    })
                })
            });
        let _ = std::fs::remove_dir_all(stage);
        r
    }
}

impl Drop for ShotWriter {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.stage);
    }
}
