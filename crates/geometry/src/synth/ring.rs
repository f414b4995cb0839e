//! A ring of Kinects around one object: the simulated scene of several sensors.
//!
//! [`kinect_ring_preset`] places [`RING_SENSORS`] Kinect v2-like sensors 120° apart on a
//! ring of radius [`RING_RADIUS_M`], 0.7 m above a floor slab, all facing a box and a sphere
//! standing at the ring's centre. Each sensor has slightly different intrinsics (as factory
//! calibrations differ). The scene is defined in a world frame (y down, the floor's top at
//! `y = 0.25 m`) and moved into every sensor's depth frame with [`Scene::transformed`], so
//! that [`render_ring`] renders each sensor with the one-rig ray caster; the true
//! [`MultiRig`] has cameras `SERIAL.depth` / `SERIAL.color`, sensor `SERIAL`, the first depth
//! camera the reference.

use nalgebra::{Matrix3, Rotation3, Vector3};

use super::{
    KINECT_DROPOUT_FRACTION, KINECT_MAX_RANGE_M, KINECT_MIN_AMPLITUDE, KinectNoise, Scene,
    SceneObject, SensorOptions, Shape, SynthFrame, SynthSetup, Texture, apply_kinect_noise,
    kinect_rig, render,
};
use crate::{CameraRole, DepthKind, MultiRig, RigCamera, RigidTransform};

/// Sensors of the ring preset: 3, the smallest ring that sees an object from all sides.
pub const RING_SENSORS: usize = 3;
/// Ring radius, metres: 1.5, where a Kinect v2 sees a 0.5 m object whole with its 70° × 60°
/// depth field of view and within its best range (0.5–4.5 m).
pub const RING_RADIUS_M: f64 = 1.5;
/// Height of the sensors above the floor's top, metres (a tripod).
const RING_HEIGHT_M: f64 = 0.7;
/// World `y` of the floor's top (y points down).
const FLOOR_Y_M: f64 = 0.25;

/// The ring preset: the true rig, the sensors' serial numbers, and one single-Kinect setup
/// per sensor (its own rig, the scene in its depth frame, its own seed).
#[derive(Debug, Clone, PartialEq)]
pub struct KinectRing {
    /// The true rig of all `2 · RING_SENSORS` cameras.
    pub rig: MultiRig,
    /// Serial numbers, one per sensor, in the rig's order.
    pub serials: Vec<String>,
    /// Per sensor: what [`render`] needs.
    pub setups: Vec<SynthSetup>,
    /// Per sensor: its depth camera's pose in the world frame of the scene
    /// (`X_depth = R · X_world + T`).
    pub depth_from_world: Vec<RigidTransform>,
    /// The scene in the world frame.
    pub world: Scene,
}

/// A camera at `eye` looking at `target`, image y along the world's y (down):
/// `camera_from_world`.
fn look_at(eye: Vector3<f64>, target: Vector3<f64>) -> RigidTransform {
    let z = (target - eye).normalize();
    let x = Vector3::y().cross(&z).normalize();
    let y = z.cross(&x);
    let world_from_camera = Matrix3::from_columns(&[x, y, z]);
    let r = Rotation3::from_matrix_unchecked(world_from_camera.transpose());
    RigidTransform::new(r, -(r * eye))
}

/// The object at the ring's centre on a floor slab (world frame, y down).
fn ring_world() -> Scene {
    Scene {
        objects: vec![
            SceneObject {
                shape: Shape::Box {
                    center: Vector3::new(0.0, FLOOR_Y_M + 0.02, 0.0),
                    half_extents: Vector3::new(0.8, 0.02, 0.8),
                    rotation: Rotation3::identity(),
                },
                texture: Texture::Plaid { period_m: 0.35, base: [130, 125, 120], amplitude: 80.0 },
                ir_albedo: 0.8,
            },
            SceneObject {
                shape: Shape::Box {
                    center: Vector3::new(-0.08, FLOOR_Y_M - 0.13, 0.04),
                    half_extents: Vector3::new(0.09, 0.13, 0.09),
                    rotation: Rotation3::from_axis_angle(&Vector3::y_axis(), 25f64.to_radians()),
                },
                texture: Texture::Stripes {
                    period_m: 0.12,
                    direction: Vector3::new(1.0, 0.5, 0.3),
                    a: [200, 50, 40],
                    b: [250, 220, 90],
                },
                ir_albedo: 0.7,
            },
            SceneObject {
                shape: Shape::Sphere {
                    center: Vector3::new(0.15, FLOOR_Y_M - 0.11, -0.08),
                    radius: 0.11,
                },
                texture: Texture::Plaid { period_m: 0.2, base: [90, 160, 110], amplitude: 60.0 },
                ir_albedo: 0.7,
            },
        ],
    }
}

/// The 3-Kinect ring (see the module docs): serials `RING0`, `RING1`, `RING2`; sensor `k`
/// at azimuth `k · 120°`, its depth focal lengths scaled by `1 + 0.004·(k − 1)`, its
/// principal points shifted by `1.5·k` px, its colour focal lengths by `1 − 0.003·(k − 1)`,
/// the Kinect preset's sensor model (range limit, low-amplitude cut, dropouts, no constant
/// noise: [`render_ring`] adds [`KinectNoise`]).
pub fn kinect_ring_preset() -> KinectRing {
    let world = ring_world();
    let target = Vector3::new(0.0, FLOOR_Y_M - 0.15, 0.0);
    let mut cameras = Vec::new();
    let mut setups = Vec::new();
    let mut depth_from_world = Vec::new();
    let mut serials = Vec::new();
    let mut ref_from_world: Option<RigidTransform> = None;
    for k in 0..RING_SENSORS {
        let serial = format!("RING{k}");
        let a = (k as f64) * std::f64::consts::TAU / RING_SENSORS as f64;
        let eye = Vector3::new(
            RING_RADIUS_M * a.sin(),
            FLOOR_Y_M - RING_HEIGHT_M,
            -RING_RADIUS_M * a.cos(),
        );
        let d_from_w = look_at(eye, target);
        let world_from_ref = *ref_from_world.get_or_insert(d_from_w);
        let depth_from_ref = d_from_w.compose(&world_from_ref.inverse());
        let mut rig = kinect_rig();
        let s = k as f64 - 1.0;
        rig.depth.intrinsics.fx *= 1.0 + 0.004 * s;
        rig.depth.intrinsics.fy *= 1.0 + 0.004 * s;
        rig.depth.intrinsics.cx += 1.5 * k as f64;
        rig.depth.intrinsics.cy -= 1.5 * k as f64;
        rig.color.intrinsics.fx *= 1.0 - 0.003 * s;
        rig.color.intrinsics.fy *= 1.0 - 0.003 * s;
        rig.color.intrinsics.cx += 2.0 * k as f64;
        cameras.push(RigCamera {
            name: format!("{serial}.depth"),
            role: CameraRole::Depth,
            sensor: Some(serial.clone()),
            model: rig.depth,
            camera_from_reference: depth_from_ref,
            depth_correction: None,
        });
        cameras.push(RigCamera {
            name: format!("{serial}.color"),
            role: CameraRole::Color,
            sensor: Some(serial.clone()),
            model: rig.color,
            camera_from_reference: rig.color_from_depth.compose(&depth_from_ref),
            depth_correction: None,
        });
        let sensor = SensorOptions {
            depth_kind: DepthKind::Z,
            max_range_m: KINECT_MAX_RANGE_M,
            min_amplitude: KINECT_MIN_AMPLITUDE,
            dropout_fraction: KINECT_DROPOUT_FRACTION,
            noise_sigma_m: 0.0,
            seed: SensorOptions::default().seed ^ (k as u64 + 1).wrapping_mul(0x5851_F42D),
        };
        setups.push(SynthSetup { rig, scene: world.transformed(&d_from_w), sensor });
        depth_from_world.push(d_from_w);
        serials.push(serial);
    }
    let rig = MultiRig {
        reference: format!("{}.depth", serials[0]),
        cameras,
        calibration: None,
        rectified: false,
    };
    KinectRing { rig, serials, setups, depth_from_world, world }
}

/// Renders every sensor of `ring`; with `noise`, [`apply_kinect_noise`] adds the Kinect's
/// z²-noise and flying pixels, seeded differently per sensor.
pub fn render_ring(ring: &KinectRing, noise: Option<&KinectNoise>) -> Vec<SynthFrame> {
    ring.setups
        .iter()
        .enumerate()
        .map(|(k, setup)| {
            let mut frame = render(setup);
            if let Some(n) = noise {
                let n =
                    KinectNoise { seed: n.seed ^ (k as u64 + 1).wrapping_mul(0x2545_F491), ..*n };
                apply_kinect_noise(&mut frame, &n);
            }
            frame
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The world point each sensor's depth camera sees at its centre pixel is the same point
    /// of the world scene: the transformed scene and the rig's poses agree.
    #[test]
    fn ring_rig_and_transformed_scenes_agree() {
        let ring = kinect_ring_preset();
        ring.rig.validate().unwrap();
        assert_eq!(ring.rig.sensors(), vec!["RING0", "RING1", "RING2"]);
        for (k, setup) in ring.setups.iter().enumerate() {
            let dir = Vector3::new(0.05, 0.1, 1.0);
            let hit = setup.scene.cast(&Vector3::zeros(), &dir).expect("sensor sees the scene");
            // The same ray cast in the world frame.
            let w_from_d = ring.depth_from_world[k].inverse();
            let o = w_from_d.translation;
            let d = w_from_d.rotation * dir;
            let world_hit = ring.world.cast(&o, &d).unwrap();
            // 1e-9 m: f64 rounding of two transforms of metre-sized numbers.
            assert!((w_from_d.apply(&hit.point) - world_hit.point).norm() < 1e-9);
            assert_eq!(hit.object, world_hit.object);
            // Colours are attached to the surfaces.
            let c0 = setup.scene.objects[hit.object].texture.color_at(&hit.point);
            let c1 = ring.world.objects[hit.object].texture.color_at(&world_hit.point);
            for c in 0..3 {
                assert!((c0[c] - c1[c]).abs() < 1e-6);
            }
            // The rig's pose of the depth camera is depth_from_world relative to sensor 0.
            let (_, depth_from_ref) = ring.rig.sensor_rig(&ring.serials[k]).unwrap();
            let expect = ring.depth_from_world[k].compose(&ring.depth_from_world[0].inverse());
            assert!((depth_from_ref.translation - expect.translation).norm() < 1e-12);
        }
    }
}
