//! The known traps of volumetric fusion, each against a truth computed without the TSDF code
//! (analytic scenes, depth by ray casting): z against range, carving behind a thin wall, the
//! weighting of a biased sensor; plus the bad inputs.

mod common;

use common::{look_at, render_z, v3};
use geometry::synth::{Scene, SceneObject, Shape, Texture, kinect_rig};
use geometry::{CameraModel, Image, RigidTransform};
use kfuse_tsdf::{DepthFrame, TsdfError, TsdfOptions, TsdfVolume, depth_weight};
use nalgebra::{Rotation3, Vector3};

fn solid(shape: Shape) -> SceneObject {
    SceneObject { shape, texture: Texture::Solid([200, 200, 200]), ir_albedo: 0.8 }
}

/// A Kinect v2 depth camera with its factory lens distortion.
fn kinect_depth() -> CameraModel {
    kinect_rig().depth
}

fn integrate(volume: &mut TsdfVolume, camera: &CameraModel, pose: RigidTransform, z: &Image<f32>) {
    volume.integrate(&DepthFrame { camera, camera_from_volume: pose, z, color: None }).unwrap();
}

/// Largest distance, metres, of a mesh vertex from a plane the camera sees without noise:
/// 0.25 mm (measured: 0.02 mm). The along-ray distance is exact for z depth, the depth is
/// interpolated bilinearly between pixels (a plane's z is smooth), marching cubes interpolates
/// a linear function along voxel edges; what remains is the curvature of `z(u, v)` within a
/// pixel and f32 rounding. Reading the nearest pixel instead errs by half a pixel's depth step
/// (~1 mm at 2 m on this plane); comparing z with the voxel's range instead errs by
/// `z·(√(1 + x² + y²) − 1)`, centimetres off-axis.
const PLANE_TOLERANCE_M: f64 = 0.00025;

/// A plane at 1.5 m tilted 35° to the optical axis fills the image (0.9–2.9 m, within the
/// depth range, whose limits are edges of the data): every vertex of the mesh lies on it. The same depth read as range (the trap) misses it by centimetres.
#[test]
fn off_axis_plane_is_flat_at_its_true_distance() {
    let camera = kinect_depth();
    let normal = Rotation3::from_axis_angle(&Vector3::y_axis(), 35f64.to_radians())
        * Vector3::new(0.0, 0.0, -1.0);
    let point = Vector3::new(0.0, 0.1, 1.5);
    let world = Scene { objects: vec![solid(Shape::Plane { point, normal })] };
    let pose = RigidTransform::identity();
    let z = render_z(&camera, &pose, &world);
    let mut volume = TsdfVolume::new(TsdfOptions::default()).unwrap();
    integrate(&mut volume, &camera, pose, &z);
    let mesh = volume.extract_mesh();
    assert!(mesh.vertices.len() > 20_000, "{} vertices", mesh.vertices.len());
    let worst =
        mesh.vertices.iter().map(|&v| normal.dot(&(v3(v) - point)).abs()).fold(0.0, f64::max);
    eprintln!("off-axis plane: worst vertex {:.3} mm off", worst * 1e3);
    assert!(worst < PLANE_TOLERANCE_M, "worst vertex {:.2} mm off the plane", worst * 1e3);
    // The vertices span the image's width, off-axis included (x/z up to ±0.6).
    let xs: Vec<f64> = mesh.vertices.iter().map(|v| v[0] as f64 / v[2] as f64).collect();
    assert!(xs.iter().copied().fold(f64::INFINITY, f64::min) < -0.5);
    assert!(xs.iter().copied().fold(f64::NEG_INFINITY, f64::max) > 0.5);

    // The trap, as a check that this test sees it: the range of each pixel given as z.
    let rays = camera.ray_table();
    let range = Image::from_fn(camera.width, camera.height, |x, y| {
        let [rx, ry] = rays[y * camera.width + x];
        z.get(x, y) * (1.0 + rx * rx + ry * ry).sqrt()
    });
    let mut wrong = TsdfVolume::new(TsdfOptions::default()).unwrap();
    integrate(&mut wrong, &camera, pose, &range);
    let worst_wrong = wrong
        .extract_mesh()
        .vertices
        .iter()
        .map(|&v| normal.dot(&(v3(v) - point)).abs())
        .fold(0.0, f64::max);
    eprintln!("the same depth as range: worst vertex {:.1} mm off", worst_wrong * 1e3);
    assert!(worst_wrong > 10.0 * PLANE_TOLERANCE_M, "{worst_wrong}");
}

/// Voxel size and truncation of the thin-wall test: 5 mm and 15 mm (three voxels), the wall
/// 25 mm thick, thicker than the band behind each face (15 mm) by two voxels, so that each
/// camera's band ends inside the wall. Had a camera updated voxels farther behind its surface
/// than the truncation (set them to −1, "carving"), the air in front of the other face would
/// turn negative and that face would vanish or move by up to the wall's thickness.
const WALL_VOXEL_M: f64 = 0.005;
const WALL_TRUNCATION_M: f64 = 0.015;
const WALL_THICKNESS_M: f64 = 0.025;
/// Largest distance of a vertex from its face, metres: 1.5 mm (noise-free depth, see
/// [`PLANE_TOLERANCE_M`]; the margin is for the wall's rim cells, where the two cameras'
/// bands meet at the faces' edges). A carved face moves by up to the wall's 25 mm.
const WALL_TOLERANCE_M: f64 = 0.0015;
/// Share of the central patch's 1 cm cells where each face must have a vertex: 99 % (every
/// cell should; the margin is for cells on the patch's rim).
const WALL_MIN_COVERAGE: f64 = 0.99;

#[test]
fn thin_wall_seen_from_both_sides_keeps_both_faces() {
    let camera = kinect_depth();
    let half = WALL_THICKNESS_M / 2.0;
    let world = Scene {
        objects: vec![solid(Shape::Box {
            center: Vector3::zeros(),
            half_extents: Vector3::new(0.8, 0.8, half),
            rotation: Rotation3::identity(),
        })],
    };
    let a = look_at(Vector3::new(0.1, -0.05, -1.2), Vector3::zeros());
    let b = look_at(Vector3::new(-0.08, 0.06, 1.3), Vector3::zeros());
    let options = TsdfOptions {
        voxel_size_m: WALL_VOXEL_M,
        truncation_m: WALL_TRUNCATION_M,
        ..TsdfOptions::default()
    };
    let mut volume = TsdfVolume::new(options).unwrap();
    for pose in [a, b] {
        let z = render_z(&camera, &pose, &world);
        integrate(&mut volume, &camera, pose, &z);
    }
    let mesh = volume.extract_mesh();
    let patch = 0.2;
    let cells = (2.0 * patch / 0.01) as usize;
    let mut front = vec![false; cells * cells];
    let mut back = vec![false; cells * cells];
    for &v in &mesh.vertices {
        let p = v3(v);
        if p.x.abs() >= patch || p.y.abs() >= patch {
            continue;
        }
        let (df, db) = ((p.z + half).abs(), (p.z - half).abs());
        assert!(
            df.min(db) < WALL_TOLERANCE_M,
            "vertex {p:?} is {:.1} mm from the nearest face",
            df.min(db) * 1e3
        );
        let cell = ((p.y + patch) / 0.01) as usize * cells + ((p.x + patch) / 0.01) as usize;
        if df < db {
            front[cell] = true;
        } else {
            back[cell] = true;
        }
    }
    let share = |f: &[bool]| f.iter().filter(|&&c| c).count() as f64 / f.len() as f64;
    assert!(share(&front) >= WALL_MIN_COVERAGE, "front face: {:.3}", share(&front));
    assert!(share(&back) >= WALL_MIN_COVERAGE, "back face: {:.3}", share(&back));
}

/// The biased sensor's offset, metres: 2 cm (a time-of-flight sensor's bias before its depth
/// correction).
const OFFSET_M: f64 = 0.02;
/// Tolerance on the fused surface's shift, metres: 0.3 mm. The alternatives it must tell
/// apart are 0 or 20 mm (the last frame wins), 10 mm (equal weights) and the 3.2 mm of the
/// inverse-variance weights; what remains is the rays' slant in the patch (< 1 % of the
/// shift) and f32 rounding.
const OFFSET_TOLERANCE_M: f64 = 0.0003;

/// Two sensors see a wall head-on, one at 1.0 m, one at 1.5 m whose depth reads 2 cm long:
/// the fused surface lies where the inverse-variance weights put it, whatever the order.
#[test]
fn biased_sensor_moves_the_surface_by_its_weight() {
    let camera = kinect_depth();
    let world = Scene {
        objects: vec![solid(Shape::Box {
            center: Vector3::new(0.0, 0.0, 0.1),
            half_extents: Vector3::new(1.5, 1.5, 0.1),
            rotation: Rotation3::identity(),
        })],
    };
    let (za, zb) = (1.0, 1.5);
    let a = look_at(Vector3::new(-0.05, 0.0, -za), Vector3::new(-0.05, 0.0, 0.0));
    let b = look_at(Vector3::new(0.05, 0.0, -zb), Vector3::new(0.05, 0.0, 0.0));
    let depth_a = render_z(&camera, &a, &world);
    let depth_b = render_z(&camera, &b, &world).map(|z| z + OFFSET_M as f32);
    // The inverse-variance weights of the two samples (σ(z) ∝ z²), from the model stated in
    // the crate docs, and the weighted mean of their surfaces.
    let (wa, wb) = (1.0 / za.powi(4), 1.0 / (zb + OFFSET_M).powi(4));
    let expected = OFFSET_M * wb / (wa + wb);
    assert!((wb - depth_weight(zb + OFFSET_M)).abs() < 1e-12);
    let mut shifts = Vec::new();
    for order in [[(a, &depth_a), (b, &depth_b)], [(b, &depth_b), (a, &depth_a)]] {
        let mut volume = TsdfVolume::new(TsdfOptions::default()).unwrap();
        for (pose, z) in order {
            integrate(&mut volume, &camera, pose, z);
        }
        let mut zs: Vec<f64> = volume
            .extract_mesh()
            .vertices
            .iter()
            .filter(|v| v[0].abs() < 0.1 && v[1].abs() < 0.1)
            .map(|v| v[2] as f64)
            .collect();
        assert!(zs.len() > 500, "{} vertices in the patch", zs.len());
        let shift = common::quantile(&mut zs, 0.5);
        assert!(
            (shift - expected).abs() < OFFSET_TOLERANCE_M,
            "surface moved by {:.2} mm, expected {:.2} mm",
            shift * 1e3,
            expected * 1e3
        );
        eprintln!("biased sensor: shift {:.3} mm, expected {:.3} mm", shift * 1e3, expected * 1e3);
        shifts.push(shift);
    }
    assert!((shifts[0] - shifts[1]).abs() < 1e-5, "{shifts:?}");
}

#[test]
fn memory_bound_and_nan_pose_are_clear_errors() {
    let camera = kinect_depth();
    let world = Scene {
        objects: vec![solid(Shape::Plane {
            point: Vector3::new(0.0, 0.0, 1.5),
            normal: Vector3::new(0.0, 0.0, -1.0),
        })],
    };
    let pose = RigidTransform::identity();
    let z = render_z(&camera, &pose, &world);
    // Room for 100 blocks; a plane filling the image at 1.5 m needs thousands.
    let options =
        TsdfOptions { max_memory_bytes: 100 * kfuse_tsdf::BLOCK_BYTES, ..TsdfOptions::default() };
    let mut volume = TsdfVolume::new(options).unwrap();
    let e = volume
        .integrate(&DepthFrame { camera: &camera, camera_from_volume: pose, z: &z, color: None })
        .unwrap_err();
    let TsdfError::MemoryBound { blocks, .. } = e else { panic!("{e}") };
    let msg = e.to_string();
    assert!(msg.contains("memory bound") && !msg.contains('\n'), "{msg}");
    // Nothing was allocated by the refused frame.
    assert_eq!(volume.block_count(), 0);
    // The need reported is the frame's whole need: the blocks the same frame allocates in a
    // volume without that bound (it once stopped counting at the bound).
    let mut unbounded = TsdfVolume::new(TsdfOptions::default()).unwrap();
    unbounded
        .integrate(&DepthFrame { camera: &camera, camera_from_volume: pose, z: &z, color: None })
        .unwrap();
    assert!(unbounded.block_count() > 1000, "{}", unbounded.block_count());
    assert_eq!(blocks, unbounded.block_count());

    let mut bad = pose;
    bad.translation.x = f64::NAN;
    let mut volume = TsdfVolume::new(TsdfOptions::default()).unwrap();
    let e = volume
        .integrate(&DepthFrame { camera: &camera, camera_from_volume: bad, z: &z, color: None })
        .unwrap_err()
        .to_string();
    assert!(e.contains("pose must be finite") && !e.contains('\n'), "{e}");

    // A camera past MAX_CAMERA_DISTANCE_M (1e300 m overflowed the block walk: a panic in a
    // debug build, a walk of 2^63 steps in a release one) is refused; one just inside is not.
    for (x, refused) in [
        (1e300, true),
        (-1e300, true),
        (2.0 * kfuse_tsdf::MAX_CAMERA_DISTANCE_M, true),
        (1.0e4, false),
    ] {
        let mut far = pose;
        far.translation.x = x;
        let mut volume = TsdfVolume::new(TsdfOptions::default()).unwrap();
        let r = volume.integrate(&DepthFrame {
            camera: &camera,
            camera_from_volume: far,
            z: &z,
            color: None,
        });
        if refused {
            let e = r.unwrap_err().to_string();
            assert!(e.contains("farther than") && !e.contains('\n'), "{e}");
            assert_eq!((volume.block_count(), volume.frames()), (0, 0));
        } else {
            assert!(r.unwrap().blocks_allocated > 1000);
        }
    }

    let small = Image::filled(10, 10, 1.0f32);
    let e = volume
        .integrate(&DepthFrame {
            camera: &camera,
            camera_from_volume: pose,
            z: &small,
            color: None,
        })
        .unwrap_err()
        .to_string();
    assert!(e.contains("10x10"), "{e}");
}
