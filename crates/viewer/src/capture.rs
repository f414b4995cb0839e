//! What `kfuse capture` and the viewer's live page share: the simulated sensor's scene, the
//! depth decoder set-up, and the shot writers with their file naming (so a shot saved with a
//! key press in `kfuse view --backend sim` is the same files `kfuse capture` writes).
//!
//! Files of one shot (see [`shot_files`]): a calibration shot `NNNN` is `color_NNNN.jpg` (the
//! sensor's JPEG, unchanged), `ir_NNNN.png` (16-bit amplitude) and `depth_NNNN.png` (16-bit,
//! millimetres, 0 = invalid); a scene `NAME` is `NAME_color.jpg`, `NAME_ir.png`,
//! `NAME_depth.png`. `kinect_params.json` holds the factory intrinsics of both cameras.

use std::path::{Path, PathBuf};

use kfuse_io::atomic::write_atomic;
use kinect_usb::decoder::{DecoderConfig, DecoderParams, DepthDecoder};
use kinect_usb::device::DeviceInfo;
use kinect_usb::params::{DepthParams, XzTables};
use kinect_usb::raw::{HEIGHT, WIDTH};
use kinect_usb::sim::{SimProfile, SimScene};

use crate::ViewerError;

/// Scale from the synthetic scene's amplitude (albedo·cos/r², ≈0.05–0.6) to decoder IR units
/// (≈1 000–12 000, well above the decoder's amplitude gates).
pub const SIM_IR_SCALE: f32 = 20_000.0;

/// The two kinds of shot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShotKind {
    /// A checkerboard pair for `kfuse calibrate`: `color_NNNN.jpg`, `ir_NNNN.png`, `depth_NNNN.png`.
    Calib,
    /// A scene: `NAME_color.jpg`, `NAME_ir.png`, `NAME_depth.png`.
    Scene,
}

/// The colour, IR and depth files of shot `name` in `out` (module docs).
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

/// The simulated scene (depth in mm, IR) and device profile of `--backend sim`:
/// `geometry::synth`'s Kinect preset without noise, colour as a quality-90 JPEG, rendered with
/// the rig the profile's factory parameters describe (`FactoryRig::of_profile`: pinhole colour
/// camera, `color_from_depth` = +52 mm along x as on real devices, protocol §4.7, §11.2), so
/// that `kinect_params.json` maps every point where the images show it.
pub fn sim_scene() -> (SimScene, SimProfile) {
    let mut setup = geometry::synth::kinect_preset(false);
    let profile = sim_profile(&setup.rig);
    if let Some(f) = kinect_usb::sim::calib_scene::FactoryRig::of_profile(&profile) {
        let [fx, fy, cx, cy] = f.color;
        let (w, h) = (setup.rig.color.width, setup.rig.color.height);
        setup.rig.color = geometry::CameraModel::new(
            w,
            h,
            geometry::Intrinsics::new(fx, fy, cx, cy),
            geometry::Distortion::NONE,
        );
        setup.rig.color_from_depth = geometry::RigidTransform::from_axis_angle(
            nalgebra::Vector3::zeros(),
            nalgebra::Vector3::from(f.t_m),
        );
    }
    let frame = geometry::synth::render(&setup);
    let depth_mm: Vec<f32> = frame
        .depth
        .data()
        .iter()
        .map(|&m| if m.is_finite() && m > 0.0 { m * 1000.0 } else { 0.0 })
        .collect();
    let ir: Vec<f32> = frame.amplitude.data().iter().map(|&a| a * SIM_IR_SCALE).collect();
    let (cw, ch) = frame.color.size();
    let rgb: Vec<u8> = frame.color.data().iter().flat_map(|p| p.iter().copied()).collect();
    let mut jpeg = Vec::new();
    let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90);
    let ok = image::ImageEncoder::write_image(
        enc,
        &rgb,
        cw as u32,
        ch as u32,
        image::ExtendedColorType::Rgb8,
    )
    .is_ok();
    let scene = SimScene {
        depth_frames: vec![(depth_mm, ir)],
        color_jpegs: if ok { vec![jpeg] } else { vec![] },
    };
    (scene, profile)
}

/// The simulated sensor's profile for `rig`'s depth camera and colour focal length.
fn sim_profile(rig: &geometry::Rig) -> SimProfile {
    let d = &rig.depth;
    let params = DepthParams {
        fx: d.intrinsics.fx as f32,
        fy: d.intrinsics.fy as f32,
        cx: d.intrinsics.cx as f32,
        cy: d.intrinsics.cy as f32,
        k1: d.distortion.k1 as f32,
        k2: d.distortion.k2 as f32,
        k3: d.distortion.k3 as f32,
        p1: d.distortion.p1 as f32,
        p2: d.distortion.p2 as f32,
    };
    SimProfile::synthetic(params, rig.color.intrinsics.fx as f32)
}

/// The depth decoder for a started device (`no_filters`: without the bilateral and
/// edge-aware filters).
pub fn decoder_for(info: &DeviceInfo, no_filters: bool) -> kinect_usb::Result<DepthDecoder> {
    let xz = XzTables::from_params(&info.depth_params);
    let cfg = DecoderConfig { bilateral: !no_filters, edge_aware: !no_filters, parallel: true };
    DepthDecoder::new(DecoderParams::default(), cfg, &xz, &info.p0)
}

fn write_err(path: &Path, e: impl std::fmt::Display) -> ViewerError {
    ViewerError::Write { path: path.to_path_buf(), message: e.to_string() }
}

/// Writes `out/kinect_params.json`: the factory intrinsics of both cameras.
pub fn write_params_json(out: &Path, info: &DeviceInfo) -> Result<(), ViewerError> {
    let d = &info.depth_params;
    let c = &info.color_params;
    let v = serde_json::json!({
        "format": "kfuse-kinect-params",
        "version": 1,
        "serial": info.serial,
        "firmware": info.firmware,
        "units": "pixels; shift_d and shift_m in millimetres",
        "depth": { "width": WIDTH, "height": HEIGHT, "fx": d.fx, "fy": d.fy, "cx": d.cx, "cy": d.cy,
                   "k1": d.k1, "k2": d.k2, "k3": d.k3, "p1": d.p1, "p2": d.p2 },
        "color": { "width": 1920, "height": 1080, "fx": c.f, "fy": c.f, "cx": c.cx, "cy": c.cy,
                   "shift_d": c.shift_d, "shift_m": c.shift_m, "mx": c.mx, "my": c.my },
    });
    let path = out.join("kinect_params.json");
    write_atomic(&path, |w| {
        serde_json::to_writer_pretty(&mut *w, &v)?;
        w.write_all(b"\n")
    })
    .map_err(|e| write_err(&path, e))
}

/// Writes `values` (a `width × height` row-major image) as a 16-bit PNG: rounded, clamped to
/// 65535; non-finite and non-positive values become 0 (invalid).
pub fn write_png16(
    path: &Path,
    values: &[f32],
    width: usize,
    height: usize,
) -> Result<(), ViewerError> {
    let px: Vec<u16> = values
        .iter()
        .map(|&v| if v.is_finite() && v > 0.0 { v.round().min(65535.0) as u16 } else { 0 })
        .collect();
    let img =
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(width as u32, height as u32, px)
            .ok_or_else(|| {
                write_err(
                    path,
                    format!("{} values do not make a {width}x{height} image", values.len()),
                )
            })?;
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Png).map_err(|e| write_err(path, e))?;
    write_atomic(path, |w| w.write_all(bytes.get_ref())).map_err(|e| write_err(path, e))
}

/// Writes one shot: the sensor's colour JPEG unchanged, IR and depth (mm) as 16-bit PNGs.
pub fn write_shot(
    files: &[PathBuf; 3],
    color_jpeg: &[u8],
    ir: &[f32],
    depth_mm: &[f32],
) -> Result<(), ViewerError> {
    let [c, i, d] = files;
    write_atomic(c, |w| w.write_all(color_jpeg)).map_err(|e| write_err(c, e))?;
    write_png16(i, ir, WIDTH, HEIGHT)?;
    write_png16(d, depth_mm, WIDTH, HEIGHT)
}
