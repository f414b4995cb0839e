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
    /// The real Kinect v2 at this USB bus and address (one of several, `kfuse capture
    /// --device SERIAL`).
    UsbAt {
        /// Bus number.
        bus: u8,
        /// Device address on the bus.
        address: u8,
    },
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
    /// With `calib_scene`: render only the first this many frames of the calibration scene
    /// (`kinect_usb::sim::calib_scene::calibration_scene_first`, `sim::ring`'s for a ring): the
    /// shots of a capture that takes one shot per frame (`kfuse capture calib --count N` without
    /// a pause between shots). Rendering is most of the start-up (a 1920x1080 supersampled
    /// colour render per pose and sensor), so the poses no shot reaches are not rendered. The
    /// frames are those of the whole scene; the sensor cycles through the ones it has, so frame
    /// `N` shows the first pose again. `None`: every pose of the scene.
    pub calib_frames: Option<usize>,
    /// A depth error the sensor makes on purpose (issue 16), applied to every depth frame of
    /// either scene; `None`: the depth is exact.
    pub depth_error: Option<kinect_usb::sim::depth_error::DepthError>,
    /// Give the default scene's depth the Kinect noise (`geometry::synth::apply_kinect_noise`:
    /// σ = 1.5 mm·z², flying pixels at depth edges), independent in each of
    /// [`SIM_NOISY_FRAMES`] frames that the sensor cycles through (`--sim-depth-noise`: a
    /// recording of one fixed sensor whose frames average out, issue 50). Not with the
    /// calibration scene (it has its own noise).
    pub depth_noise: bool,
    /// Which sensor of a simulated ring this is (`kinect_usb::sim::ring`); `None`: the single
    /// simulated sensor (as a ring of one).
    pub ring: Option<SimRing>,
    /// With a ring: the faults above only on the sensor of this serial (`None`: on every one).
    pub fault_sensor: Option<String>,
    /// With a ring: the second sensor reports the first one's serial (tests of two Kinects
    /// with the same serial number).
    pub same_serial: bool,
    /// Produce frames at the sensor's 30 Hz of host time whether anyone reads or not
    /// (`kinect_usb::sim::SimPacing::RealTime`: a slow reader loses frames, newest wins, as
    /// with a real sensor; `kfuse serve`). Off: one frame each time one is asked for
    /// (lockstep, deterministic; captures and tests).
    pub real_time: bool,
}

/// One sensor of a ring of simulated Kinects (`kfuse --backend sim --sim-sensors N`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SimRing {
    /// Sensors in the ring, 1..=`kinect_usb::sim::ring::MAX_SIM_SENSORS`.
    pub sensors: usize,
    /// This sensor, 0-based.
    pub index: usize,
    /// The serial number this sensor reports: its own (`ring::serial(index)`) unless a test
    /// gives it another sensor's (two sensors with the same serial).
    pub serial: String,
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
            SensorSource::Usb | SensorSource::UsbAt { .. } => "Kinect v2",
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
    sim_scene_frames(None)
}

/// Distinct noisy depth frames of `--sim-depth-noise`: 16 (the sensor cycles through them, so
/// a recording of up to 16 frames has independent noise in each; each costs 1.7 MB of depth
/// and IR).
pub const SIM_NOISY_FRAMES: usize = 16;

/// [`sim_scene`], with `noisy` frames of the Kinect noise (frame `k` seeded with
/// `KinectNoise::default().seed + k`) instead of the one noise-free frame.
pub fn sim_scene_frames(noisy: Option<usize>) -> (SimScene, SimProfile) {
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
    let depth_and_ir = |frame: &geometry::synth::SynthFrame| {
        let mut depth_mm: Vec<f32> = frame
            .depth
            .data()
            .iter()
            .map(|&m| if m.is_finite() && m > 0.0 { m * 1000.0 } else { 0.0 })
            .collect();
        let mut ir: Vec<f32> = frame.amplitude.data().iter().map(|&a| a * SIM_IR_SCALE).collect();
        // What the sensor streams: the scene mirrored.
        mirror_rows(&mut depth_mm, dw);
        mirror_rows(&mut ir, dw);
        (depth_mm, ir)
    };
    let depth_frames = match noisy {
        None => vec![depth_and_ir(&frame)],
        Some(n) => (0..n as u64)
            .map(|k| {
                let mut f = frame.clone();
                let base = geometry::synth::KinectNoise::default();
                let noise =
                    geometry::synth::KinectNoise { seed: base.seed.wrapping_add(k), ..base };
                geometry::synth::apply_kinect_noise(&mut f, &noise);
                depth_and_ir(&f)
            })
            .collect(),
    };
    let (cw, ch) = frame.color.size();
    let mut color = frame.color.data().to_vec();
    // What the sensor streams: the scene mirrored.
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
    let scene = SimScene { depth_frames, color_jpegs: if ok { vec![jpeg] } else { vec![] } };
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

/// Timestamp origin of sensor `index` of a simulated ring (0.125 ms units): each Kinect has its
/// own free-running clock, so the ring's sensors start at different times (sensor 0 as the
/// single sensor, at 1000; the others 1.234 s, 2.468 s, … later).
fn ring_clock_origin(index: usize) -> u32 {
    1000 + 9_872 * index as u32
}

/// The simulated device of [`SensorSource::Sim`] (fixed seed 1: runs are reproducible).
pub fn sim_device(options: &SimOptions) -> Result<SimDevice, CaptureError> {
    if let Some(r) = options.ring.as_ref().filter(|r| r.sensors > 1) {
        return ring_device(options, r);
    }
    // The calibration scene needs only the profile: the default scene is not rendered for it
    // (a 1920x1080 render and JPEG that start-up threw away).
    let (mut scene, profile) = if options.calib_scene {
        (SimScene::default(), sim_scene_profile())
    } else {
        sim_scene_frames(options.depth_noise.then_some(SIM_NOISY_FRAMES))
    };
    if options.calib_scene {
        let frames = options.calib_frames.unwrap_or(usize::MAX);
        scene = kinect_usb::sim::calib_scene::calibration_scene_first(&profile, frames)
            .ok_or_else(|| {
                CaptureError::Config(
                    "the simulated sensor's colour parameters are not a pinhole camera".into(),
                )
            })?;
    }
    add_depth_error(&mut scene, options);
    let mut dev = SimDevice::new(profile, scene, sim_faults(options));
    set_pacing(&mut dev, options);
    Ok(dev)
}

/// [`SimOptions::real_time`]'s pacing.
fn set_pacing(dev: &mut SimDevice, options: &SimOptions) {
    if options.real_time {
        dev.pacing = kinect_usb::sim::SimPacing::RealTime;
    }
}

/// The depth error `--sim-depth-error` injects, applied to every depth frame of `scene`.
fn add_depth_error(scene: &mut SimScene, options: &SimOptions) {
    if let Some(e) = &options.depth_error {
        for (depth_mm, _) in &mut scene.depth_frames {
            e.apply(depth_mm);
        }
    }
}

fn sim_faults(options: &SimOptions) -> SimFaults {
    SimFaults {
        seed: 1,
        busy: options.busy,
        iso_drop_rate: options.iso_drop,
        unplug_after_frames: options.unplug_after,
        ..SimFaults::default()
    }
}

/// Sensor `r.index` of a ring: its own profile and pose (`kinect_usb::sim::ring`), the
/// ring's calibration scene or room, its own clock.
fn ring_device(options: &SimOptions, r: &SimRing) -> Result<SimDevice, CaptureError> {
    use kinect_usb::sim::ring;
    if r.sensors > ring::MAX_SIM_SENSORS || r.index >= r.sensors {
        return Err(CaptureError::Config(format!(
            "simulated sensor {} of {}: a ring holds 1 to {} sensors",
            r.index + 1,
            r.sensors,
            ring::MAX_SIM_SENSORS
        )));
    }
    let mut profile = ring::sensor_profile(&sim_scene_profile(), r.index);
    let scene = if options.calib_scene {
        let frames = options.calib_frames.unwrap_or(usize::MAX);
        ring::calibration_scene_first(&profile, r.sensors, r.index, frames)
    } else {
        ring::view_scene(&profile, r.sensors, r.index)
    };
    let mut scene = scene.ok_or_else(|| {
        CaptureError::Config(
            "the simulated sensor's colour parameters are not a pinhole camera".into(),
        )
    })?;
    add_depth_error(&mut scene, options);
    profile.serial = r.serial.clone();
    let mut dev = SimDevice::new(profile, scene, sim_faults(options));
    dev.set_timestamp(ring_clock_origin(r.index));
    set_pacing(&mut dev, options);
    Ok(dev)
}

/// The true rig of a ring of `sensors` simulated Kinects, as the images a capture writes
/// (scene orientation): for each sensor its depth camera `SERIAL.depth` (the factory depth
/// intrinsics and distortion) and colour camera `SERIAL.color` (pinhole, `X_color = X_depth + t`,
/// `kinect_usb::sim::calib_scene::FactoryRig::of_scene`), posed by the ring
/// (`kinect_usb::sim::ring::depth_from_world`); the reference is the first sensor's depth
/// camera. One sensor gives its pair (written as a version-1 rig file).
pub fn sim_true_rig(sensors: usize) -> Result<geometry::multi_rig::MultiRig, CaptureError> {
    use geometry::multi_rig::{CameraRole, MultiRig, RigCamera};
    use geometry::{CameraModel, Distortion, Intrinsics, RigidTransform};
    use kinect_usb::sim::calib_scene::FactoryRig;
    use kinect_usb::sim::ring;
    let n = sensors.clamp(1, ring::MAX_SIM_SENSORS);
    let base = sim_scene_profile();
    let transform = |p: &ring::Pose| {
        let m = nalgebra::Matrix3::from_fn(|i, j| p.r[i][j]);
        RigidTransform::from_matrix(m, nalgebra::Vector3::from(p.t))
            .map_err(|e| CaptureError::Config(format!("a ring pose is not a rotation: {e}")))
    };
    let world_from_ref = transform(&ring::world_from_depth(n, 0))?;
    let mut cameras = Vec::new();
    for i in 0..n {
        let profile = ring::sensor_profile(&base, i);
        let f = FactoryRig::of_scene(&profile).ok_or_else(|| {
            CaptureError::Config(
                "the simulated sensor's colour parameters are not a pinhole camera".into(),
            )
        })?;
        let d = &f.depth;
        let depth_model = CameraModel::new(
            kinect_usb::raw::WIDTH,
            kinect_usb::raw::HEIGHT,
            Intrinsics::new(d.fx as f64, d.fy as f64, d.cx as f64, d.cy as f64),
            Distortion {
                k1: d.k1 as f64,
                k2: d.k2 as f64,
                p1: d.p1 as f64,
                p2: d.p2 as f64,
                k3: d.k3 as f64,
            },
        );
        let [fx, fy, cx, cy] = f.color;
        let color_model =
            CameraModel::new(1920, 1080, Intrinsics::new(fx, fy, cx, cy), Distortion::NONE);
        let depth_from_ref = transform(&ring::depth_from_world(n, i))?.compose(&world_from_ref);
        let color_from_depth = RigidTransform::from_axis_angle(
            nalgebra::Vector3::zeros(),
            nalgebra::Vector3::from(f.t_m),
        );
        let serial = ring::serial(i);
        cameras.push(RigCamera {
            name: format!("{serial}.depth"),
            role: CameraRole::Depth,
            sensor: Some(serial.clone()),
            model: depth_model,
            camera_from_reference: depth_from_ref,
            depth_correction: None,
        });
        cameras.push(RigCamera {
            name: format!("{serial}.color"),
            role: CameraRole::Color,
            sensor: Some(serial.clone()),
            model: color_model,
            camera_from_reference: color_from_depth.compose(&depth_from_ref),
            depth_correction: None,
        });
    }
    let rig = MultiRig {
        reference: cameras[0].name.clone(),
        cameras,
        calibration: None,
        rectified: false,
    };
    rig.validate()?;
    Ok(rig)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The calibration scene of `kfuse capture calib --count n --interval 0`: sensor `index`
    /// of a ring of `sensors` (`None`: the single sensor) with only `n` frames rendered.
    fn calib_device(ring: Option<(usize, usize)>, n: usize) -> SimDevice {
        let ring = ring.map(|(sensors, index)| SimRing {
            sensors,
            index,
            serial: kinect_usb::sim::ring::serial(index),
        });
        let options =
            SimOptions { calib_scene: true, calib_frames: Some(n), ring, ..SimOptions::default() };
        sim_device(&options).unwrap()
    }

    /// `--sim-sensors 3 --count 6`: every sensor of the ring holds exactly 6 depth and 6
    /// colour frames (the poses its 6 shots take), not the 90 of the whole ring scene.
    #[test]
    fn a_ring_capture_of_6_shots_renders_6_frames_per_sensor() {
        for index in 0..3 {
            let mut dev = calib_device(Some((3, index)), 6);
            assert_eq!(dev.color_frames(), 6, "sensor {index}: colour frames");
            assert_eq!(dev.raw_frames().len(), 6, "sensor {index}: depth frames");
        }
    }

    /// The single sensor with `--count 2`: 2 frames, not the scene's 17.
    #[test]
    fn a_single_sensor_capture_of_2_shots_renders_2_frames() {
        let mut dev = calib_device(None, 2);
        assert_eq!((dev.color_frames(), dev.raw_frames().len()), (2, 2));
    }
}
