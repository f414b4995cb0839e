//! Stage 1: where frames come from. One type, [`SensorSource`], for `kfuse capture`, `kfuse
//! devices` and the viewer's live page.

use std::path::PathBuf;

use crate::CaptureError;
use kinect_usb::orientation::mirror_rows;
use kinect_usb::params::DepthParams;
use kinect_usb::sim::{SimDevice, SimFaults, SimProfile, SimScene};

/// Scale from the synthetic scene's amplitude (albedo·cos/r², ≈0.05–0.6) to decoder IR units
/// (≈1 000–12 000, well above the decoder's amplitude gates).
pub const SIM_IR_SCALE: f32 = 20_000.0;

/// Quality of the simulated colour camera's JPEG: the sensor's own stream is of this order,
/// and it keeps the checkerboard's edges sharp for the calibration tests.
const SIM_JPEG_QUALITY: u8 = 90;

/// Which sensor to stream from.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorSource {
    /// A real Kinect v2 over libusb (the first one found).
    Usb,
    /// The simulated Kinect v2: `geometry::synth`'s Kinect preset scene over the same USB
    /// protocol, with optional faults.
    Sim(SimOptions),
    /// A raw recording made with `kfuse capture record`, replayed through the same parsers and
    /// decoder as a live sensor.
    Replay(ReplayOptions),
    /// A USB bus with no Kinect on it: what every command does without a sensor, whatever is
    /// plugged into the machine running the tests.
    Absent,
}

/// Faults of the simulated sensor.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SimOptions {
    /// Disappear (unplug) after this many frame periods.
    pub unplug_after: Option<u64>,
    /// Report busy when opened.
    pub busy: bool,
    /// Fraction of isochronous packets lost, `0..=1`.
    pub iso_drop: f64,
    /// Show the calibration scene (`kinect_usb::sim::calib_scene`: a 7x5-corner board of
    /// 40 mm squares in 17 tilted poses at 0.6–2.5 m, one per frame) instead of the Kinect preset.
    pub calib_scene: bool,
    /// A depth error the sensor makes on purpose (issue 16), applied to every depth frame of
    /// either scene; `None`: the depth is exact.
    pub depth_error: Option<kinect_usb::sim::depth_error::DepthError>,
}

/// How to read a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayOptions {
    /// The `.kfrec` file.
    pub path: PathBuf,
    /// Accept a truncated recording and use its intact beginning.
    pub allow_truncated: bool,
    /// Leave out records whose checksum does not match instead of stopping at the first.
    pub skip_corrupt: bool,
}

impl SensorSource {
    /// The sensor's name for titles and messages.
    pub fn name(&self) -> &'static str {
        match self {
            SensorSource::Usb => "Kinect v2",
            SensorSource::Sim(_) => "simulated Kinect v2",
            SensorSource::Replay(_) => "recorded Kinect v2",
            SensorSource::Absent => "no Kinect v2",
        }
    }

    /// Whether a consumer showing frames live should pace them to the sensor's 30 Hz: the
    /// simulator and a replay deliver frames as fast as they are asked for.
    pub fn needs_pacing(&self) -> bool {
        matches!(self, SensorSource::Sim(_) | SensorSource::Replay(_))
    }
}

/// The simulated scene (depth in mm, IR) and device profile of [`SensorSource::Sim`]:
/// `geometry::synth`'s Kinect preset without noise, colour as a JPEG.
///
/// Like a real Kinect v2 the simulator streams **mirrored** images with the factory
/// parameters of those (`kinect_usb::orientation`): the scene is rendered as it is, with the
/// rig that is the mirror of the profile's factory rig (colour camera at x ≈ +52 mm), and each
/// image is then mirrored left–right. A capture (which mirrors back) shows the rendered scene
/// exactly, and its `kinect_params.json` describes the rendering rig.
pub fn sim_scene() -> (SimScene, SimProfile) {
    let mut setup = geometry::synth::kinect_preset(false);
    let sensor_depth = setup.rig.depth.mirrored();
    let profile = sim_scene_profile();
    // Rendered with the mirror of the rig the profile's factory parameters describe
    // (`FactoryRig::of_profile`: pinhole colour camera, `color_from_depth` = +52 mm along x in
    // the sensor's mirrored images, protocol §4.7, §11.2), so that `kinect_params.json` maps
    // every point where the images show it.
    if let Some(f) = kinect_usb::sim::calib_scene::FactoryRig::of_profile(&profile) {
        let [fx, fy, cx, cy] = f.color;
        let (w, h) = (setup.rig.color.width, setup.rig.color.height);
        let mut sensor_rig = setup.rig.clone();
        sensor_rig.depth = sensor_depth;
        sensor_rig.color = geometry::CameraModel::new(
            w,
            h,
            geometry::Intrinsics::new(fx, fy, cx, cy),
            geometry::Distortion::NONE,
        );
        sensor_rig.color_from_depth = geometry::RigidTransform::from_axis_angle(
            nalgebra::Vector3::zeros(),
            nalgebra::Vector3::from(f.t_m),
        );
        setup.rig = sensor_rig.mirrored();
    }
    let frame = geometry::synth::render(&setup);
    let (dw, _) = frame.depth.size();
    let mut depth_mm: Vec<f32> = frame
        .depth
        .data()
        .iter()
        .map(|&m| if m.is_finite() && m > 0.0 { m * 1000.0 } else { 0.0 })
        .collect();
    let mut ir: Vec<f32> = frame.amplitude.data().iter().map(|&a| a * SIM_IR_SCALE).collect();
    let (cw, ch) = frame.color.size();
    let mut color = frame.color.data().to_vec();
    // What the sensor streams: the scene mirrored.
    mirror_rows(&mut depth_mm, dw);
    mirror_rows(&mut ir, dw);
    mirror_rows(&mut color, cw);
    let rgb: Vec<u8> = color.iter().flat_map(|p| p.iter().copied()).collect();
    let mut jpeg = Vec::new();
    let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, SIM_JPEG_QUALITY);
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

/// The simulated sensor's profile ([`sim_scene`]'s): the factory parameters of the mirrored
/// stream of `geometry::synth`'s Kinect preset.
fn sim_scene_profile() -> SimProfile {
    let rig = geometry::synth::kinect_preset(false).rig;
    sim_profile(&rig.depth.mirrored(), rig.color.intrinsics.fx)
}

/// The simulated sensor's profile for depth camera `d` (of the sensor's mirrored images) and
/// colour focal length `color_fx`.
fn sim_profile(d: &geometry::CameraModel, color_fx: f64) -> SimProfile {
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
    SimProfile::synthetic(params, color_fx as f32)
}

/// The simulated device of [`SensorSource::Sim`] (fixed seed 1: runs are reproducible).
pub fn sim_device(options: &SimOptions) -> Result<SimDevice, CaptureError> {
    // The calibration scene needs only the profile: the default scene is not rendered for it
    // (a 1920x1080 render and JPEG that start-up threw away).
    let (mut scene, profile) =
        if options.calib_scene { (SimScene::default(), sim_scene_profile()) } else { sim_scene() };
    if options.calib_scene {
        scene = kinect_usb::sim::calib_scene::calibration_scene(&profile).ok_or_else(|| {
            CaptureError::Config(
                "the simulated sensor's colour parameters are not a pinhole camera".into(),
            )
        })?;
    }
    if let Some(e) = &options.depth_error {
        for (depth_mm, _) in &mut scene.depth_frames {
            e.apply(depth_mm);
        }
    }
    let faults = SimFaults {
        seed: 1,
        busy: options.busy,
        iso_drop_rate: options.iso_drop,
        unplug_after_frames: options.unplug_after,
        ..SimFaults::default()
    };
    Ok(SimDevice::new(profile, scene, faults))
}
