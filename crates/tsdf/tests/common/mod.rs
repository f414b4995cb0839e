//! Helpers of the truth tests: depth rendered by ray casting an analytic scene
//! (`geometry::synth::Scene::cast`), the true distance to a scene's surfaces computed from the
//! shapes' own distance functions, and a grid of points for nearest-neighbour queries. None of
//! it uses the TSDF code.
#![allow(dead_code)]

use std::collections::HashMap;

use geometry::synth::{Scene, Shape};
use geometry::{CameraModel, Image, RigidTransform};
use nalgebra::Vector3;
use rayon::prelude::*;

/// The z-depth image a camera at pose `camera_from_world` sees of `world` (NaN: no hit).
pub fn render_z(
    camera: &CameraModel,
    camera_from_world: &RigidTransform,
    world: &Scene,
) -> Image<f32> {
    let scene = world.transformed(camera_from_world);
    let (w, h) = (camera.width, camera.height);
    let data: Vec<f32> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let Some(n) = camera.unproject((i % w) as f64, (i / w) as f64) else {
                return f32::NAN;
            };
            // The ray (x, y, 1): its parameter at the hit is the hit's z.
            match scene.cast(&Vector3::zeros(), &Vector3::new(n.x, n.y, 1.0)) {
                Some(hit) => hit.point.z as f32,
                None => f32::NAN,
            }
        })
        .collect();
    Image::from_vec(w, h, data).unwrap()
}

/// A camera at `eye` looking at `target`, image y along the world's +y (down).
pub fn look_at(eye: Vector3<f64>, target: Vector3<f64>) -> RigidTransform {
    geometry::fusion::multi::look_at(eye, target, -Vector3::y()).unwrap()
}

/// Signed distance from `p` to one shape (negative inside a solid); exact for planes,
/// spheres and boxes (the shapes of the scenes these tests build and of the simulated ring).
pub fn shape_sdf(shape: &Shape, p: &Vector3<f64>) -> f64 {
    match shape {
        Shape::Plane { point, normal } => normal.normalize().dot(&(p - point)),
        Shape::Sphere { center, radius } => (p - center).norm() - radius,
        Shape::Box { center, half_extents, rotation } => {
            let l = rotation.inverse() * (p - center);
            let q = l.abs() - half_extents;
            let outside = q.map(|v| v.max(0.0)).norm();
            let inside = q.x.max(q.y).max(q.z).min(0.0);
            outside + inside
        }
        Shape::Cone { .. } => panic!("the truth tests' scenes have no cones"),
    }
}

/// Distance from `p` to the surface of the union of the scene's solids: `|min_i sdf_i(p)|`.
pub fn scene_distance(scene: &Scene, p: &Vector3<f64>) -> f64 {
    scene.objects.iter().map(|o| shape_sdf(&o.shape, p)).fold(f64::INFINITY, f64::min).abs()
}

/// Points binned in cubes of `cell` metres, to ask whether one lies within `cell` of a point.
pub struct PointGrid {
    cell: f64,
    bins: HashMap<[i64; 3], Vec<Vector3<f64>>>,
}

impl PointGrid {
    pub fn new(points: impl IntoIterator<Item = Vector3<f64>>, cell: f64) -> Self {
        let mut bins: HashMap<[i64; 3], Vec<Vector3<f64>>> = HashMap::new();
        for p in points {
            bins.entry(Self::key(&p, cell)).or_default().push(p);
        }
        Self { cell, bins }
    }

    fn key(p: &Vector3<f64>, cell: f64) -> [i64; 3] {
        [(p.x / cell).floor() as i64, (p.y / cell).floor() as i64, (p.z / cell).floor() as i64]
    }

    /// Distance to the nearest point if it is within `cell`.
    pub fn nearest_within_cell(&self, p: &Vector3<f64>) -> Option<f64> {
        let k = Self::key(p, self.cell);
        let mut best = f64::INFINITY;
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    if let Some(b) = self.bins.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                        for q in b {
                            best = best.min((q - p).norm());
                        }
                    }
                }
            }
        }
        (best <= self.cell).then_some(best)
    }
}

/// The value at quantile `q` (0–1) of `values` (sorted in place; nearest rank).
pub fn quantile(values: &mut [f64], q: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    let i = ((values.len() as f64 - 1.0) * q).round() as usize;
    values[i]
}

pub fn v3(p: [f32; 3]) -> Vector3<f64> {
    Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}
