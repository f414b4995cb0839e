//! Synthetic RGB-D ground truth: an analytic ray caster for a depth + colour camera rig.
//!
//! A [`Scene`] of planes, oriented boxes, spheres and cones (coordinates in the **depth
//! camera's frame**, metres) is rendered through a [`Rig`] (both cameras with their
//! distortion, `color_from_depth`) by [`render`] into a [`SynthFrame`]: what the sensors
//! deliver (colour, depth as `z` or `range`, an IR-like amplitude) and the truths the fusion
//! stages are tested against.
//!
//! Every pixel is sampled once, at its centre, along the exact (f64) undistorted ray; no
//! anti-aliasing, so a pixel's value is the value of one surface point.
//!
//! # Definitions used by the truths
//!
//! * A surface point `P` is **inside the depth camera's view** when it is in front of the
//!   depth camera (`P.z > 0`) and projects, with the depth camera's distortion, onto the
//!   depth image: `-0.5 <= u < width - 0.5` and likewise for `v`
//!   ([`crate::CameraModel::contains`]).
//! * `P` is **hidden from** a camera when the ray from that camera's centre to `P` first hits
//!   the scene at a distance shorter than `(1 - HIDDEN_TOLERANCE)` times the distance to `P`.
//! * The **true disocclusion mask** (per colour pixel) holds where the colour pixel sees a
//!   surface point that is inside the depth camera's view but hidden from it. Pixels whose
//!   point is visible to the depth camera but got no valid measurement (range, IR, dropout)
//!   are *not* disocclusions. `fusion`'s H8 hole mask approximates "inside the depth view"
//!   by "between covered colour pixels along the row and the column", see
//!   [`crate::fusion::hole_mask`].
//!
//! Random choices (dropouts, noise) come from a ChaCha8 generator seeded per row from
//! [`SensorOptions::seed`], so renders are identical on any thread count.
//!
//! [`kinect_noisy_preset`] and [`render_noisy`] (module `noisy`) add the real sensor's
//! depth-dependent noise and flying pixels at depth edges, with the flying pixels as truth.
//!
//! Size (~780 lines): the ray caster, its scene types and the presets every test and the demo
//! render; the noisy sensor model lives in `synth/noisy.rs`.

use nalgebra::{Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::{CameraModel, DepthKind, Distortion, Image, Intrinsics, Rig, RigidTransform};

mod noisy;
mod ring;
pub use noisy::{
    FLYING_EDGE_JUMP, FLYING_MIX_MIN, FLYING_PIXEL_FRACTION, KinectNoise, NoisyFrame,
    apply_kinect_noise, kinect_noisy_preset, render_noisy,
};
pub use ring::{KinectRing, RING_RADIUS_M, RING_SENSORS, kinect_ring_preset, render_ring};

/// Relative tolerance of the "hidden" test: the first hit must be closer than
/// `(1 - 1e-6)` times the distance to the point; f64 intersections are exact to ~1e-12, so
/// this only absorbs rounding, never a real occluder (the thinnest gap in the presets is cm).
pub const HIDDEN_TOLERANCE: f64 = 1e-6;
/// Smallest ray parameter accepted as a hit, to step off the surface a ray starts on.
const RAY_EPSILON: f64 = 1e-9;

/// An analytic surface. Directions need not be unit length; they are normalised on use.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// Infinite plane through `point` with normal `normal`.
    Plane {
        /// A point of the plane.
        point: Vector3<f64>,
        /// Normal (any length).
        normal: Vector3<f64>,
    },
    /// A box with centre, half extents along its own axes, and orientation
    /// (`world = rotation · local + center`).
    Box {
        /// Centre, metres.
        center: Vector3<f64>,
        /// Half side lengths along the box's local x, y, z, metres.
        half_extents: Vector3<f64>,
        /// Orientation of the box's axes in the scene.
        rotation: Rotation3<f64>,
    },
    /// A sphere.
    Sphere {
        /// Centre, metres.
        center: Vector3<f64>,
        /// Radius, metres.
        radius: f64,
    },
    /// A solid right circular cone: apex, axis from the apex towards the base, half opening
    /// angle, height; closed by its base disc.
    Cone {
        /// Apex, metres.
        apex: Vector3<f64>,
        /// Axis direction from the apex to the base centre (any length).
        axis: Vector3<f64>,
        /// Half opening angle, radians.
        half_angle: f64,
        /// Apex-to-base distance, metres.
        height: f64,
    },
}

/// A procedural colour pattern, evaluated at the 3D surface point.
#[derive(Debug, Clone, PartialEq)]
pub enum Texture {
    /// One colour.
    Solid([u8; 3]),
    /// A 3D checkerboard of cubes of side `square_m` (hard edges: good to look at, bad for
    /// colour tolerances at the edges).
    Checker {
        /// Cube side, metres.
        square_m: f64,
        /// First colour.
        a: [u8; 3],
        /// Second colour.
        b: [u8; 3],
    },
    /// Smooth sinusoidal stripes across `direction`, blending `a` and `b` with period
    /// `period_m`; smooth, so bilinear resampling is accurate everywhere.
    Stripes {
        /// Period, metres.
        period_m: f64,
        /// Direction across the stripes (any length).
        direction: Vector3<f64>,
        /// Colour at phase 0.
        a: [u8; 3],
        /// Colour at phase π.
        b: [u8; 3],
    },
    /// Smooth plaid: each channel a sinusoid along a different axis (R along x, G along y,
    /// B along z) with period `period_m`, around `base` with amplitude `amplitude`.
    Plaid {
        /// Period, metres.
        period_m: f64,
        /// Mean colour.
        base: [u8; 3],
        /// Amplitude of every channel (keep `base ± amplitude` within 0..=255).
        amplitude: f64,
    },
    /// Another texture evaluated in another frame: the colour at `p` is `texture`'s colour
    /// at `texture_from_scene · p` ([`Scene::transformed`] keeps a surface's colours where
    /// they were when it moves the geometry into a sensor's frame).
    Placed {
        /// The pattern, in its own frame.
        texture: Box<Texture>,
        /// Scene point → the pattern's frame.
        texture_from_scene: RigidTransform,
    },
}

impl Texture {
    /// The colour at surface point `p` as floats in 0..=255 (before rounding).
    pub fn color_at(&self, p: &Vector3<f64>) -> [f64; 3] {
        let f = |c: [u8; 3]| [c[0] as f64, c[1] as f64, c[2] as f64];
        let mix = |a: [u8; 3], b: [u8; 3], t: f64| {
            let (a, b) = (f(a), f(b));
            [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t]
        };
        match self {
            Texture::Solid(c) => f(*c),
            Texture::Checker { square_m, a, b } => {
                let s = (p / *square_m).map(f64::floor);
                let parity = (s.x + s.y + s.z).rem_euclid(2.0);
                if parity < 0.5 { f(*a) } else { f(*b) }
            }
            Texture::Stripes { period_m, direction, a, b } => {
                let phase = p.dot(&direction.normalize()) / period_m * std::f64::consts::TAU;
                mix(*a, *b, 0.5 - 0.5 * phase.cos())
            }
            Texture::Plaid { period_m, base, amplitude } => {
                let w = std::f64::consts::TAU / period_m;
                let b = f(*base);
                [
                    b[0] + amplitude * (w * p.x).sin(),
                    b[1] + amplitude * (w * p.y).sin(),
                    b[2] + amplitude * (w * p.z).sin(),
                ]
            }
            Texture::Placed { texture, texture_from_scene } => {
                texture.color_at(&texture_from_scene.apply(p))
            }
        }
    }

    /// The colour at `p` rounded to 8 bits.
    pub fn color_u8(&self, p: &Vector3<f64>) -> [u8; 3] {
        self.color_at(p).map(|c| c.round().clamp(0.0, 255.0) as u8)
    }
}

/// A shape with its colour texture and IR albedo (0..1, for the amplitude image).
#[derive(Debug, Clone, PartialEq)]
pub struct SceneObject {
    /// Geometry.
    pub shape: Shape,
    /// Colour pattern.
    pub texture: Texture,
    /// Reflectivity in the IR image, 0..1.
    pub ir_albedo: f64,
}

/// A ray hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter: `point = origin + t · direction`.
    pub t: f64,
    /// The surface point, metres, depth-camera frame.
    pub point: Vector3<f64>,
    /// Unit surface normal facing the ray's origin side.
    pub normal: Vector3<f64>,
    /// Index of the object hit.
    pub object: usize,
}

/// A set of objects in the depth camera's frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Scene {
    /// The objects.
    pub objects: Vec<SceneObject>,
}

impl Scene {
    /// The same scene with every surface moved by `to_from_scene` (`X_to = R·X + T`): the
    /// scene as seen from another frame, e.g. a sensor's depth camera
    /// (`depth_from_world`). Textures stay attached to the surfaces
    /// ([`Texture::Placed`]), so every sensor sees the same colours on the same point.
    pub fn transformed(&self, to_from_scene: &RigidTransform) -> Scene {
        let r = to_from_scene.rotation;
        let back = to_from_scene.inverse();
        let objects = self
            .objects
            .iter()
            .map(|o| {
                let shape = match &o.shape {
                    Shape::Plane { point, normal } => {
                        Shape::Plane { point: to_from_scene.apply(point), normal: r * normal }
                    }
                    Shape::Box { center, half_extents, rotation } => Shape::Box {
                        center: to_from_scene.apply(center),
                        half_extents: *half_extents,
                        rotation: r * rotation,
                    },
                    Shape::Sphere { center, radius } => {
                        Shape::Sphere { center: to_from_scene.apply(center), radius: *radius }
                    }
                    Shape::Cone { apex, axis, half_angle, height } => Shape::Cone {
                        apex: to_from_scene.apply(apex),
                        axis: r * axis,
                        half_angle: *half_angle,
                        height: *height,
                    },
                };
                let texture = match &o.texture {
                    Texture::Solid(c) => Texture::Solid(*c),
                    Texture::Placed { texture, texture_from_scene } => Texture::Placed {
                        texture: texture.clone(),
                        texture_from_scene: texture_from_scene.compose(&back),
                    },
                    other => Texture::Placed {
                        texture: Box::new(other.clone()),
                        texture_from_scene: back,
                    },
                };
                SceneObject { shape, texture, ir_albedo: o.ir_albedo }
            })
            .collect();
        Scene { objects }
    }

    /// The first hit along `origin + t · dir`, `t > 0`.
    pub fn cast(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        let mut best: Option<(f64, Vector3<f64>, usize)> = None;
        for (i, o) in self.objects.iter().enumerate() {
            if let Some((t, n)) = intersect(&o.shape, origin, dir)
                && best.is_none_or(|(bt, _, _)| t < bt)
            {
                best = Some((t, n, i));
            }
        }
        let (t, n, object) = best?;
        let n = n.normalize();
        let normal = if n.dot(dir) > 0.0 { -n } else { n };
        Some(Hit { t, point: origin + dir * t, normal, object })
    }
}

fn smallest_positive(a: f64, b: f64, c: f64) -> [Option<f64>; 2] {
    let disc = b * b - 4.0 * a * c;
    if !(disc >= 0.0) || a == 0.0 {
        return [None, None];
    }
    let s = disc.sqrt();
    let (t0, t1) = ((-b - s) / (2.0 * a), (-b + s) / (2.0 * a));
    let (t0, t1) = if t0 <= t1 { (t0, t1) } else { (t1, t0) };
    [(t0 > RAY_EPSILON).then_some(t0), (t1 > RAY_EPSILON).then_some(t1)]
}

/// Ray–shape intersection: smallest `t > 0` and the (unnormalised) outward normal there.
fn intersect(shape: &Shape, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<(f64, Vector3<f64>)> {
    match shape {
        Shape::Plane { point, normal } => {
            let den = d.dot(normal);
            if den == 0.0 {
                return None;
            }
            let t = (point - o).dot(normal) / den;
            (t > RAY_EPSILON).then_some((t, *normal))
        }
        Shape::Sphere { center, radius } => {
            let oc = o - center;
            let [t0, t1] =
                smallest_positive(d.dot(d), 2.0 * oc.dot(d), oc.dot(&oc) - radius * radius);
            let t = t0.or(t1)?;
            Some((t, o + d * t - center))
        }
        Shape::Box { center, half_extents, rotation } => {
            let inv = rotation.inverse();
            let lo = inv * (o - center);
            let ld = inv * d;
            let (mut tmin, mut tmax) = (f64::NEG_INFINITY, f64::INFINITY);
            let (mut axis_min, mut axis_max) = (0usize, 0usize);
            for k in 0..3 {
                if ld[k] == 0.0 {
                    if lo[k].abs() > half_extents[k] {
                        return None;
                    }
                    continue;
                }
                let (a, b) =
                    ((-half_extents[k] - lo[k]) / ld[k], (half_extents[k] - lo[k]) / ld[k]);
                let (a, b) = if a <= b { (a, b) } else { (b, a) };
                if a > tmin {
                    tmin = a;
                    axis_min = k;
                }
                if b < tmax {
                    tmax = b;
                    axis_max = k;
                }
            }
            if tmin > tmax {
                return None;
            }
            let (t, k) = if tmin > RAY_EPSILON {
                (tmin, axis_min)
            } else if tmax > RAY_EPSILON {
                (tmax, axis_max)
            } else {
                return None;
            };
            let mut n = Vector3::zeros();
            n[k] = (lo[k] + ld[k] * t).signum();
            Some((t, rotation * n))
        }
        Shape::Cone { apex, axis, half_angle, height } => {
            let a = axis.normalize();
            let c2 = half_angle.cos().powi(2);
            let co = o - apex;
            let (dv, cv) = (d.dot(&a), co.dot(&a));
            let qa = dv * dv - c2 * d.dot(d);
            let qb = 2.0 * (dv * cv - c2 * d.dot(&co));
            let qc = cv * cv - c2 * co.dot(&co);
            let mut best: Option<(f64, Vector3<f64>)> = None;
            for t in smallest_positive(qa, qb, qc).into_iter().flatten() {
                let w = co + d * t;
                let h = w.dot(&a);
                if (0.0..=*height).contains(&h) {
                    best = Some((t, w * c2 - a * h));
                    break;
                }
            }
            // Base disc.
            if dv != 0.0 {
                let t = (height - cv) / dv;
                let w = co + d * t;
                let r = height * half_angle.tan();
                if t > RAY_EPSILON
                    && (w - a * *height).norm_squared() <= r * r
                    && best.is_none_or(|(bt, _)| t < bt)
                {
                    best = Some((t, a));
                }
            }
            best
        }
    }
}

/// How the simulated depth sensor measures (and fails to).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorOptions {
    /// What the depth image stores.
    pub depth_kind: DepthKind,
    /// Points with `z` beyond this give no sample (Kinect v2: 4.5 m). `INFINITY` for none.
    pub max_range_m: f64,
    /// Pixels whose amplitude (`albedo · cos / r²`) is below this give no sample. `0` for none.
    pub min_amplitude: f64,
    /// Fraction of valid pixels randomly dropped (flying-pixel filters, multipath).
    pub dropout_fraction: f64,
    /// Standard deviation of Gaussian depth noise, metres. `0` turns noise off (default).
    pub noise_sigma_m: f64,
    /// Seed of every random choice.
    pub seed: u64,
}

impl Default for SensorOptions {
    fn default() -> Self {
        Self {
            depth_kind: DepthKind::Z,
            max_range_m: f64::INFINITY,
            min_amplitude: 0.0,
            dropout_fraction: 0.0,
            noise_sigma_m: 0.0,
            seed: 0x006b_6675_7365,
        }
    }
}

/// A rig, a scene and a sensor model: everything [`render`] needs.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthSetup {
    /// The cameras and `color_from_depth`.
    pub rig: Rig,
    /// The scene, in the depth camera's frame.
    pub scene: Scene,
    /// The depth sensor's behaviour.
    pub sensor: SensorOptions,
}

/// A rendered frame: sensor images and ground truths.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthFrame {
    /// Colour image (colour camera).
    pub color: Image<[u8; 3]>,
    /// Measured depth (depth camera), metres, of kind [`SynthFrame::depth_kind`]; NaN = no
    /// sample (beyond range, low amplitude, dropout, nothing hit).
    pub depth: Image<f32>,
    /// The kind of [`SynthFrame::depth`].
    pub depth_kind: DepthKind,
    /// IR-like amplitude `albedo · cos(incidence) / range²` (depth camera), 0 where nothing hit.
    pub amplitude: Image<f32>,
    /// True `z` (depth-camera frame) of every depth pixel, noise- and failure-free; NaN where
    /// nothing is hit.
    pub true_depth_z: Image<f32>,
    /// True `z` in the colour camera's frame of the surface each colour pixel sees; NaN where
    /// nothing is hit.
    pub true_color_depth: Image<f32>,
    /// True colour of the surface point each depth pixel sees.
    pub true_color_on_depth: Image<[u8; 3]>,
    /// Per depth pixel: its surface point is visible to the colour camera and lands on the
    /// colour image.
    pub true_seen_by_color: Image<bool>,
    /// Per colour pixel: its surface point is inside the depth camera's view, visible to it,
    /// and the depth pixel it falls on (rounded) holds a valid measurement.
    pub true_seen_by_depth: Image<bool>,
    /// Per colour pixel: the true disocclusion mask (inside the depth view, hidden from it).
    pub true_disocclusion: Image<bool>,
    /// Per colour pixel: index of the object seen (`u16::MAX` for none).
    pub true_color_object: Image<u16>,
    /// Per colour pixel: unit surface normal in the colour camera's frame, facing the
    /// camera (NaN where nothing is hit).
    pub true_color_normal: Image<[f32; 3]>,
    /// Per depth pixel: index of the object seen (`u16::MAX` for none).
    pub true_depth_object: Image<u16>,
}

/// Undistorted normalised rays of every pixel in f64 (NaN where the lens folds).
fn rays_f64(cam: &CameraModel) -> Vec<Option<Vector3<f64>>> {
    let fold = cam.distortion.fold_radius();
    (0..cam.height)
        .into_par_iter()
        .flat_map_iter(|v| {
            (0..cam.width).map(move |u| {
                let d = cam.intrinsics.from_pixel(u as f64, v as f64);
                cam.distortion.undistort_within(d.x, d.y, fold).map(|n| Vector3::new(n.x, n.y, 1.0))
            })
        })
        .collect()
}

/// Box–Muller standard normal from two uniforms.
fn standard_normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(f64::MIN_POSITIVE);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Renders `setup` (see the module docs for what each image means).
pub fn render(setup: &SynthSetup) -> SynthFrame {
    let rig = &setup.rig;
    let scene = &setup.scene;
    let sensor = setup.sensor;
    let (dw, dh) = (rig.depth.width, rig.depth.height);
    let (cw, ch) = (rig.color.width, rig.color.height);
    let depth_from_color = rig.color_from_depth.inverse();
    let color_origin = depth_from_color.translation;
    let zero = Vector3::zeros();

    // Depth camera.
    let depth_rays = rays_f64(&rig.depth);
    struct DepthPx {
        depth: f32,
        amplitude: f32,
        true_z: f32,
        color: [u8; 3],
        seen: bool,
        object: u16,
    }
    let depth_px: Vec<DepthPx> = (0..dh)
        .into_par_iter()
        .flat_map_iter(|v| {
            let mut rng = ChaCha8Rng::seed_from_u64(
                sensor.seed ^ (v as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            );
            let rays = &depth_rays[v * dw..(v + 1) * dw];
            rays.iter()
                .map(|ray| {
                    let none = DepthPx {
                        depth: f32::NAN,
                        amplitude: 0.0,
                        true_z: f32::NAN,
                        color: [0; 3],
                        seen: false,
                        object: u16::MAX,
                    };
                    let Some(ray) = ray else { return none };
                    let Some(hit) = scene.cast(&zero, ray) else { return none };
                    let obj = &scene.objects[hit.object];
                    let p = hit.point;
                    let range = p.norm();
                    let cos = hit.normal.dot(&(-p / range)).max(0.0);
                    let amplitude = obj.ir_albedo * cos / (range * range);
                    // Colour-camera visibility of this point.
                    let to_p = p - color_origin;
                    let pc = rig.color_from_depth.apply(&p);
                    let seen =
                        rig.color.project(&pc).is_some_and(|px| rig.color.contains(px.x, px.y))
                            && scene
                                .cast(&color_origin, &to_p)
                                .is_some_and(|h| h.t >= 1.0 - HIDDEN_TOLERANCE);
                    let dropped = sensor.dropout_fraction > 0.0
                        && rng.random::<f64>() < sensor.dropout_fraction;
                    let noise = if sensor.noise_sigma_m > 0.0 {
                        sensor.noise_sigma_m * standard_normal(&mut rng)
                    } else {
                        0.0
                    };
                    let z = p.z + noise;
                    let valid = !dropped
                        && z <= sensor.max_range_m
                        && amplitude >= sensor.min_amplitude
                        && z > 0.0;
                    let value = match sensor.depth_kind {
                        DepthKind::Z => z,
                        DepthKind::Range => z * (ray.norm()),
                    };
                    DepthPx {
                        depth: if valid { value as f32 } else { f32::NAN },
                        amplitude: amplitude as f32,
                        true_z: p.z as f32,
                        color: obj.texture.color_u8(&p),
                        seen,
                        object: hit.object as u16,
                    }
                })
                .collect::<Vec<_>>()
        })
        .collect();

    // Colour camera.
    let color_rays = rays_f64(&rig.color);
    let rot_dc = depth_from_color.rotation;
    struct ColorPx {
        color: [u8; 3],
        z: f32,
        seen_by_depth: bool,
        disoccluded: bool,
        object: u16,
        normal: [f32; 3],
    }
    let color_px: Vec<ColorPx> = color_rays
        .par_iter()
        .map(|ray| {
            let none = ColorPx {
                color: [0; 3],
                z: f32::NAN,
                seen_by_depth: false,
                disoccluded: false,
                object: u16::MAX,
                normal: [f32::NAN; 3],
            };
            let Some(ray) = ray else { return none };
            let dir = rot_dc * ray;
            let Some(hit) = scene.cast(&color_origin, &dir) else { return none };
            let obj = &scene.objects[hit.object];
            let p = hit.point;
            let z = rig.color_from_depth.apply(&p).z;
            let depth_px_at = rig.depth.project(&p).filter(|px| rig.depth.contains(px.x, px.y));
            let in_view = depth_px_at.is_some();
            let visible = scene.cast(&zero, &p).is_some_and(|h| h.t >= 1.0 - HIDDEN_TOLERANCE);
            let measured = depth_px_at.is_some_and(|px| {
                let (x, y) = ((px.x + 0.5).floor() as usize, (px.y + 0.5).floor() as usize);
                depth_px[y * dw + x].depth.is_finite()
            });
            ColorPx {
                color: obj.texture.color_u8(&p),
                z: z as f32,
                seen_by_depth: in_view && visible && measured,
                disoccluded: in_view && !visible,
                object: hit.object as u16,
                normal: {
                    let n = rig.color_from_depth.rotation * hit.normal;
                    [n.x as f32, n.y as f32, n.z as f32]
                },
            }
        })
        .collect();

    SynthFrame {
        depth: Image::from_fn(dw, dh, |x, y| depth_px[y * dw + x].depth),
        depth_kind: sensor.depth_kind,
        amplitude: Image::from_fn(dw, dh, |x, y| depth_px[y * dw + x].amplitude),
        true_depth_z: Image::from_fn(dw, dh, |x, y| depth_px[y * dw + x].true_z),
        true_color_on_depth: Image::from_fn(dw, dh, |x, y| depth_px[y * dw + x].color),
        true_seen_by_color: Image::from_fn(dw, dh, |x, y| depth_px[y * dw + x].seen),
        color: Image::from_fn(cw, ch, |x, y| color_px[y * cw + x].color),
        true_color_depth: Image::from_fn(cw, ch, |x, y| color_px[y * cw + x].z),
        true_seen_by_depth: Image::from_fn(cw, ch, |x, y| color_px[y * cw + x].seen_by_depth),
        true_disocclusion: Image::from_fn(cw, ch, |x, y| color_px[y * cw + x].disoccluded),
        true_color_object: Image::from_fn(cw, ch, |x, y| color_px[y * cw + x].object),
        true_color_normal: Image::from_fn(cw, ch, |x, y| color_px[y * cw + x].normal),
        true_depth_object: Image::from_fn(dw, dh, |x, y| depth_px[y * dw + x].object),
    }
}

/// The course's camera pair: both 640×480, depth focal 426.67 px (24 mm / 56.25 µm), colour
/// focal 622.22 px (35 mm / 56.25 µm), principal points at the image centre, no distortion;
/// `color_from_depth` = a 5° rotation about y and `T = (0.2, -1.0, 0)` m (the numbers of
/// `course/synthdata.mat`). Depth is delivered as **range**.
pub fn course_rig() -> Rig {
    let depth = CameraModel::new(
        640,
        480,
        Intrinsics::new(426.666_666_666_666_7, 426.666_666_666_666_7, 319.5, 239.5),
        Distortion::NONE,
    );
    let color = CameraModel::new(
        640,
        480,
        Intrinsics::new(622.222_222_222_222_3, 622.222_222_222_222_3, 319.5, 239.5),
        Distortion::NONE,
    );
    let r = Rotation3::from_axis_angle(&Vector3::y_axis(), -5f64.to_radians());
    Rig::new(depth, color, RigidTransform::new(r, Vector3::new(0.2, -1.0, 0.0)))
}

/// The course preset: [`course_rig`], a textured background plane at 18–20 m, a box, a
/// sphere and a cone at 10–14 m; range depth, no noise, no invalid pixels.
pub fn course_preset() -> SynthSetup {
    let scene = Scene {
        objects: vec![
            SceneObject {
                shape: Shape::Plane {
                    point: Vector3::new(0.0, 0.0, 19.0),
                    normal: Vector3::new(0.05, -0.03, -1.0),
                },
                texture: Texture::Checker { square_m: 1.5, a: [200, 200, 190], b: [60, 80, 120] },
                ir_albedo: 0.8,
            },
            SceneObject {
                shape: Shape::Box {
                    center: Vector3::new(-2.8, 0.8, 12.0),
                    half_extents: Vector3::new(1.1, 1.3, 1.1),
                    rotation: Rotation3::from_euler_angles(0.2, 0.6, 0.05),
                },
                texture: Texture::Stripes {
                    period_m: 0.8,
                    direction: Vector3::new(1.0, 1.0, 0.0),
                    a: [220, 60, 40],
                    b: [250, 210, 80],
                },
                ir_albedo: 0.6,
            },
            SceneObject {
                shape: Shape::Sphere { center: Vector3::new(2.6, -0.6, 11.0), radius: 1.6 },
                texture: Texture::Stripes {
                    period_m: 0.6,
                    direction: Vector3::new(0.0, 1.0, 0.2),
                    a: [40, 160, 60],
                    b: [210, 240, 200],
                },
                ir_albedo: 0.7,
            },
            SceneObject {
                shape: Shape::Cone {
                    apex: Vector3::new(0.2, -2.6, 14.0),
                    axis: Vector3::new(0.0, 1.0, 0.0),
                    half_angle: 22f64.to_radians(),
                    height: 3.2,
                },
                texture: Texture::Stripes {
                    period_m: 0.5,
                    direction: Vector3::new(0.0, 1.0, 0.0),
                    a: [90, 60, 160],
                    b: [230, 200, 250],
                },
                ir_albedo: 0.5,
            },
        ],
    };
    SynthSetup {
        rig: course_rig(),
        scene,
        sensor: SensorOptions { depth_kind: DepthKind::Range, ..SensorOptions::default() },
    }
}

/// Kinect v2 depth range limit, metres (beyond it the sensor reports 0).
pub const KINECT_MAX_RANGE_M: f64 = 4.5;
/// Amplitude below which the simulated Kinect reports no depth: with albedo 0.7 it cuts
/// surfaces seen at more than ~85° incidence at 2 m (the grazing limbs the real sensor drops).
pub const KINECT_MIN_AMPLITUDE: f64 = 0.015;
/// Fraction of randomly dropped depth pixels in the Kinect preset (isolated dropouts).
pub const KINECT_DROPOUT_FRACTION: f64 = 0.002;
/// Depth noise of the Kinect preset when noise is switched on, metres (Kinect v2 ~1.5 mm
/// at 2–3 m).
pub const KINECT_NOISE_SIGMA_M: f64 = 0.0015;

/// A Kinect v2-like rig: the factory depth intrinsics and distortion of
/// `kinect-v2-vectors/manifest.json` (`depth_params`), a 1920×1080 colour camera with a
/// ~1060 px focal length and mild distortion, 52 mm baseline along x and a tiny rotation.
pub fn kinect_rig() -> Rig {
    let depth = CameraModel::new(
        512,
        424,
        Intrinsics::new(368.096588, 368.096588, 261.696594, 202.522202),
        Distortion { k1: 0.084061, k2: -0.271582, p1: 0.0, p2: 0.0, k3: 0.101907 },
    );
    let color = CameraModel::new(
        1920,
        1080,
        Intrinsics::new(1060.7, 1059.3, 956.2, 537.9),
        Distortion { k1: 0.021, k2: -0.034, p1: 0.0006, p2: -0.0004, k3: 0.0 },
    );
    let t = RigidTransform::from_axis_angle(
        Vector3::new(0.0021, -0.0034, 0.0012),
        Vector3::new(-0.0519, 0.0004, 0.0011),
    );
    Rig::new(depth, color, t)
}

/// The Kinect preset: [`kinect_rig`], a tilted background plane at 2.2–4.8 m (its far corner
/// beyond the 4.5 m range), a box, a sphere and a cone at 1.0–1.7 m, smooth colour
/// patterns; z depth with realistic invalid pixels (beyond range, low amplitude, 0.2 %
/// dropouts). `noise` adds [`KINECT_NOISE_SIGMA_M`] Gaussian depth noise.
pub fn kinect_preset(noise: bool) -> SynthSetup {
    let scene = Scene {
        objects: vec![
            SceneObject {
                shape: Shape::Plane {
                    point: Vector3::new(0.0, 0.0, 3.0),
                    normal: Vector3::new(0.25, 0.35, 1.0),
                },
                texture: Texture::Plaid { period_m: 0.45, base: [130, 125, 120], amplitude: 90.0 },
                ir_albedo: 0.8,
            },
            SceneObject {
                shape: Shape::Box {
                    center: Vector3::new(-0.29, 0.08, 1.1),
                    half_extents: Vector3::new(0.11, 0.15, 0.1),
                    rotation: Rotation3::from_euler_angles(0.15, 0.5, 0.05),
                },
                texture: Texture::Stripes {
                    period_m: 0.2,
                    direction: Vector3::new(1.0, 0.5, 0.3),
                    a: [200, 50, 40],
                    b: [250, 220, 90],
                },
                ir_albedo: 0.7,
            },
            SceneObject {
                shape: Shape::Sphere { center: Vector3::new(0.27, -0.06, 1.25), radius: 0.14 },
                texture: Texture::Plaid { period_m: 0.3, base: [90, 160, 110], amplitude: 60.0 },
                ir_albedo: 0.7,
            },
            SceneObject {
                shape: Shape::Cone {
                    apex: Vector3::new(0.0, -0.2, 1.45),
                    axis: Vector3::new(0.0, 1.0, 0.1),
                    half_angle: 20f64.to_radians(),
                    height: 0.32,
                },
                texture: Texture::Stripes {
                    period_m: 0.15,
                    direction: Vector3::new(0.0, 1.0, 0.0),
                    a: [70, 50, 170],
                    b: [220, 200, 250],
                },
                ir_albedo: 0.6,
            },
        ],
    };
    let sensor = SensorOptions {
        depth_kind: DepthKind::Z,
        max_range_m: KINECT_MAX_RANGE_M,
        min_amplitude: KINECT_MIN_AMPLITUDE,
        dropout_fraction: KINECT_DROPOUT_FRACTION,
        noise_sigma_m: if noise { KINECT_NOISE_SIGMA_M } else { 0.0 },
        ..SensorOptions::default()
    };
    SynthSetup { rig: kinect_rig(), scene, sensor }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn analytic_intersections_hit_where_expected() {
        let o = Vector3::zeros();
        let d = Vector3::new(0.0, 0.0, 1.0);
        let sphere = Shape::Sphere { center: Vector3::new(0.0, 0.0, 5.0), radius: 1.0 };
        // Hand calculations: sphere at z 5, radius 1 → t = 4; box face at 3 − 0.5 = 2.5; cone apex
        // at 2; plane at 7. 1e-12 (1e-9 for the cone's quadratic, which cancels near the apex): f64
        // round-off of closed-form roots.
        assert!((intersect(&sphere, &o, &d).unwrap().0 - 4.0).abs() < 1e-12);
        let b = Shape::Box {
            center: Vector3::new(0.0, 0.0, 3.0),
            half_extents: Vector3::new(1.0, 1.0, 0.5),
            rotation: Rotation3::identity(),
        };
        let (t, n) = intersect(&b, &o, &d).unwrap();
        assert!((t - 2.5).abs() < 1e-12 && (n - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
        // Cone with apex towards the camera: the ray along its axis hits the apex.
        let c = Shape::Cone {
            apex: Vector3::new(0.0, 0.0, 2.0),
            axis: d,
            half_angle: 0.3,
            height: 1.0,
        };
        assert!((intersect(&c, &o, &d).unwrap().0 - 2.0).abs() < 1e-9);
        // A ray 0.1 off the axis hits the mantle at h = 0.1 / tan(0.3).
        let t = intersect(&c, &Vector3::new(0.1, 0.0, 0.0), &d).unwrap().0;
        assert!((t - (2.0 + 0.1 / 0.3f64.tan())).abs() < 1e-9, "{t}");
        let plane = Shape::Plane {
            point: Vector3::new(0.0, 0.0, 7.0),
            normal: Vector3::new(0.0, 0.0, -2.0),
        };
        assert!((intersect(&plane, &o, &d).unwrap().0 - 7.0).abs() < 1e-12);
    }
}
