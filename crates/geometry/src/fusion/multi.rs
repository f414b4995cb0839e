//! Fusion of several Kinects: every sensor's depth into one coloured cloud in the rig's
//! reference frame, z-buffered into any camera of the rig, with the rig's overlap
//! consistency per pair of sensors.
//!
//! Per sensor ([`fuse_multi_on`]): its depth image is corrected with the depth camera's
//! [`crate::DepthCorrection`] (where the rig has one), then the per-pixel stages of a
//! single-sensor `fusion::run` run on it, all sensors as one batch on the chosen engine
//! ([`PerPixel::per_pixel_batch`]: [`CpuPixels`], or the GPU's `fusion_gpu::FusionContext`):
//! H1 back-projection, coloured by its own colour camera with H6 (occlusions judged against
//! H3's nearest fill of its own z-buffer), and the samples moved into the reference frame. The merged cloud keeps, where two sensors see the same
//! surface (the other sensor's depth within [`OVERLAP_GATE_M`] of the point), the sample of
//! the sensor closer to it: the Kinect's noise grows with z², so the closer one measures it
//! better (the "best-seeing" rule of issue 32).
//!
//! [`MultiFusion::zbuffer_into`] z-buffers every sensor's samples into one camera with H2
//! and H7's rules ([`project_point`], [`zbuffer_index`], [`super::zbuffer_min`]: nearest
//! wins), the points projected from their own depth frame with the composed
//! `camera_from_depth` pose, so that one sensor into its own colour camera is bit-identical
//! to [`super::Registration`]; [`MultiFusion::zbuffer_into_on`] is the same on an engine
//! ([`PerPixel::zbuffer_views`]: on the GPU one atomic-min buffer across the sensors).
//!
//! **Per-sensor meshes** ([`MultiFusion::sensor_mesh`]): each sensor's depth grid meshed by
//! the single-sensor path's H4 ([`mesh_on_depth_grid`], texture coordinates into its own
//! colour image) and cleaned by H5 ([`remove_edge_faces`] with [`stretch_test`] of its own
//! pair), both in its colour camera's frame exactly as `fusion::run` does, then moved into
//! the reference frame: the same faces as a single-sensor fuse of that frame.
//!
//! **A virtual view** ([`MultiFusion::render_merged`], a pose from [`look_at`]): the merged
//! cloud's points z-buffered into any camera model at any pose, nearest wins, with the colour
//! of the winning point.
//!
//! **Consistency** of a pair (A, B): every sample of B is projected into A's depth camera;
//! where A has a sample at that pixel within [`OVERLAP_GATE_M`] the signed difference
//! `z_A − z_B` (A's frame) is kept. Each B sample is compared (no z-buffer: the minimum of
//! several noisy samples on one pixel is biased towards the camera). Reported: the median
//! `|z_A − z_B|` over the compared pixels (the noise of both sensors included: ~0.95·σ√2),
//! and the **tile consistency**, the median over [`CONSISTENCY_TILE_PX`]-pixel tiles of A's
//! image (with at least [`MIN_TILE_SAMPLES`] comparisons) of the absolute median difference
//! in the tile: the rig's misalignment with the per-pixel noise averaged out, the number a
//! user can trust or distrust.

use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use super::pixel::{
    ColorProjection, ZBUFFER_EMPTY, project_point, zbuffer_index, zbuffer_pixel, zbuffer_points,
};
use super::{
    CpuPixels, DepthView, FusionOptions, PerPixel, PerPixelOutput, PixelFrame, Request,
    StageTimings, cloud_colors, mesh_on_depth_grid, project_cloud, remove_edge_faces, stretch_test,
};
use crate::{
    CameraModel, DepthKind, GeometryError, Image, Mesh, MultiRig, PointCloud, Rig, RigCamera,
    RigidTransform,
};

/// Shortest distance, metres, between a virtual camera's centre and the point it looks at
/// (and the smallest `|up × view direction|` of unit vectors) for [`look_at`] to define a
/// pose: 1 µm (0.06° of direction for the cross product), far below any rig's scale and far
/// above f64 rounding of metre-sized coordinates.
pub const LOOK_AT_MIN: f64 = 1e-6;

/// Largest depth difference, metres, at which a sample of one sensor and a sample of another
/// on the same pixel are the same surface: 50 mm, over ten times the Kinect's noise at 2 m
/// (σ ≈ 6 mm for the difference of two sensors) and a 1 cm / 1° pose error at 1.5 m (~3 cm),
/// and below the gaps between the objects and what is behind them (≥ 10 cm in a room).
pub const OVERLAP_GATE_M: f32 = 0.05;

/// Side of the tiles of the tile consistency, depth pixels: 8 (64 pixels, ~3 cm at 1.5 m):
/// the median of up to 64 differences has an eighth of the per-pixel noise, and a pose error
/// changes the difference little across 3 cm.
pub const CONSISTENCY_TILE_PX: usize = 8;

/// Fewest comparisons in a tile for it to count: 16, a quarter of a tile (the tile's median
/// then still has a quarter of the per-pixel noise; tiles on the rim of an overlap have fewer).
pub const MIN_TILE_SAMPLES: usize = 16;

/// The images of one sensor.
#[derive(Debug, Clone)]
pub struct SensorImages {
    /// The sensor (a Kinect's serial number) of the rig.
    pub sensor: String,
    /// Depth image of the sensor's depth camera, metres (NaN or 0 for no sample).
    pub depth: Image<f32>,
    /// Colour image of its colour camera.
    pub color: Image<[u8; 3]>,
}

/// One sensor's samples.
#[derive(Debug, Clone)]
pub struct SensorCloud {
    /// The sensor.
    pub sensor: String,
    /// Its depth + colour pair (its depth camera's frame the reference), as fused
    /// (undistorted when the rig is rectified).
    pub rig: Rig,
    /// Its depth camera's pose: `X_depth = R · X_reference + T`.
    pub depth_from_reference: RigidTransform,
    /// Its depth image as fused: metres, after the depth correction.
    pub depth: Image<f32>,
    /// H1 points in its depth camera's frame, metres, row-major.
    pub points: Vec<[f32; 3]>,
    /// The depth pixel (row-major index) of every point.
    pub pixels: Vec<u32>,
    /// H6 colour of every point (black where its colour camera does not see it).
    pub colors: Vec<[u8; 3]>,
    /// `z` of every depth pixel's sample (depth camera frame, after the correction), NaN for
    /// none.
    pub z: Image<f32>,
    /// Per point: kept in the merged cloud (no other sensor sees its surface closer).
    pub kept: Vec<bool>,
    /// H6: its own colour image sampled on its depth grid.
    pub color_on_depth: Image<[u8; 3]>,
    /// Where H6 trusts that colour (the colour camera sees the depth sample).
    pub color_valid: Image<bool>,
}

/// The overlap of two sensors.
#[derive(Debug, Clone, Serialize)]
pub struct PairConsistency {
    /// The sensor whose depth camera the comparison is in.
    pub a: String,
    /// The sensor whose samples are projected into A.
    pub b: String,
    /// Samples of B compared with a sample of A (the overlap, in pixels of A).
    pub pixels: usize,
    /// Median `|z_A − z_B|` over them, millimetres (both sensors' noise included).
    pub median_abs_mm: f64,
    /// Tiles of A's image with at least [`MIN_TILE_SAMPLES`] comparisons.
    pub tiles: usize,
    /// Median over those tiles of the tile's absolute median difference, millimetres.
    pub tile_median_mm: f64,
    /// Samples compared by colour: both A's and B's colour cameras see the sample, and both
    /// sensors see its surface from the same side (not the two faces of a thin board).
    pub color_pixels: usize,
    /// Pearson correlation of the grey values (Rec. 601 luma) that A's and B's colour cameras
    /// see at the compared samples: near 1 where the rig puts B's samples on the surfaces A
    /// sees them on (the same texture, whatever the two cameras' exposure and white balance),
    /// near 0 where it does not (swapped sensors or poses, whose geometry can still agree on
    /// a floor or a symmetric scene). NaN with fewer than [`MIN_COLOR_SAMPLES`].
    pub color_correlation: f64,
}

/// Smallest colour correlation of a pair of sensors whose rig describes them: 0.5. On the
/// simulated ring (noisy depth, 1920 × 1080 colour) the true rig gives 0.96–0.98, a sensor moved
/// by 1 cm and 1° still 0.75–0.93 (its geometry is off by 36–42 mm, told by the tile
/// consistency), and a rig with two sensors' images or poses swapped −0.04–0.32, although its
/// tile consistency (0.6–20 mm) can look as good as the truth's in a symmetric scene.
pub const MIN_COLOR_CORRELATION: f64 = 0.5;

/// Fewest samples seen by both colour cameras for [`PairConsistency::color_correlation`]:
/// 500, where the correlation of unrelated textures is within ±0.1 of 0 (1/√500 ≈ 0.045).
pub const MIN_COLOR_SAMPLES: usize = 500;

/// Pearson correlation of paired values; NaN when fewer than [`MIN_COLOR_SAMPLES`] or one
/// side is constant.
fn correlation(pairs: &[(f64, f64)]) -> f64 {
    if pairs.len() < MIN_COLOR_SAMPLES {
        return f64::NAN;
    }
    let n = pairs.len() as f64;
    let (ma, mb) = pairs.iter().fold((0.0, 0.0), |(sa, sb), (a, b)| (sa + a, sb + b));
    let (ma, mb) = (ma / n, mb / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (a, b) in pairs {
        let (da, db) = (a - ma, b - mb);
        sab += da * db;
        saa += da * da;
        sbb += db * db;
    }
    if saa <= 0.0 || sbb <= 0.0 { f64::NAN } else { sab / (saa * sbb).sqrt() }
}

/// Rec. 601 luma of an RGB colour.
fn luma(c: [u8; 3]) -> f64 {
    0.299 * c[0] as f64 + 0.587 * c[1] as f64 + 0.114 * c[2] as f64
}

/// Wall-clock times of [`fuse_multi`]'s stages, milliseconds.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct MultiTimings {
    /// Correction, H1 and H6 of every sensor.
    pub sensors_ms: f64,
    /// The best-seeing rule and the merged cloud.
    pub merge_ms: f64,
    /// Consistency of every pair.
    pub consistency_ms: f64,
}

/// Everything [`fuse_multi`] makes.
#[derive(Debug, Clone)]
pub struct MultiFusion {
    /// Per sensor of the rig (in [`MultiRig::sensors`] order).
    pub sensors: Vec<SensorCloud>,
    /// The merged cloud in the reference frame, with colours.
    pub cloud: PointCloud,
    /// Per point of [`MultiFusion::cloud`]: index of its sensor in [`MultiFusion::sensors`].
    pub cloud_sensor: Vec<u16>,
    /// Every pair `a < b` of sensors (B's samples in A's camera).
    pub consistency: Vec<PairConsistency>,
    /// Stage times.
    pub timings: MultiTimings,
    rectified: bool,
    /// What the depth images hold (for [`MultiFusion::zbuffer_into_on`]).
    kind: DepthKind,
}

fn model_as_fused(model: &CameraModel, rectified: bool) -> CameraModel {
    if rectified { model.without_distortion() } else { *model }
}

/// The projection of `camera_from_depth` points into `camera` (H2's arithmetic).
fn projection(camera: &CameraModel, camera_from_depth: RigidTransform) -> ColorProjection {
    ColorProjection::from_rig(&Rig::new(*camera, *camera, camera_from_depth))
}

/// Fuses one depth + colour pair per sensor of `rig` (depth of kind `kind`, metres) on the
/// CPU: [`fuse_multi_on`] with [`CpuPixels`].
pub fn fuse_multi(
    rig: &MultiRig,
    inputs: &[SensorImages],
    kind: DepthKind,
    options: &FusionOptions,
) -> Result<MultiFusion, GeometryError> {
    fuse_multi_on(&mut CpuPixels::new(), rig, inputs, kind, options)
}

/// Fuses one depth + colour pair per sensor of `rig` (depth of kind `kind`, metres), with
/// every sensor's per-pixel stages (H1, its own H2 + H7, H3 nearest, H6) on `engine` as one
/// batch ([`PerPixel::per_pixel_batch`], the stages of a single-sensor `fusion::run`); see
/// the module docs. `options` gives H6's occlusion tolerance and H3's coverage radius and
/// depth jump. The output is the same on every engine.
///
/// Errors ([`GeometryError::InvalidInput`], before any work): a sensor of the rig without
/// images, images of a sensor the rig does not have or given twice, a rig sensor without a
/// depth or a colour camera; [`GeometryError::SizeMismatch`] for an image of another size
/// than its camera; the depth correction's errors; the engine's.
pub fn fuse_multi_on<E: PerPixel>(
    engine: &mut E,
    rig: &MultiRig,
    inputs: &[SensorImages],
    kind: DepthKind,
    options: &FusionOptions,
) -> Result<MultiFusion, E::Error> {
    rig.validate()?;
    let sensors = rig.sensors();
    for (i, input) in inputs.iter().enumerate() {
        if !sensors.contains(&input.sensor.as_str()) {
            return Err(GeometryError::InvalidInput(format!(
                "sensor \"{}\" is not in the rig (its sensors: {})",
                input.sensor,
                sensors.join(", ")
            ))
            .into());
        }
        if inputs[..i].iter().any(|o| o.sensor == input.sensor) {
            return Err(GeometryError::InvalidInput(format!(
                "sensor \"{}\" is given twice",
                input.sensor
            ))
            .into());
        }
    }
    let mut pairs = Vec::with_capacity(sensors.len());
    for s in &sensors {
        let input = inputs.iter().find(|i| i.sensor == *s).ok_or_else(|| {
            GeometryError::InvalidInput(format!(
                "sensor \"{s}\" of the rig has no depth and colour images"
            ))
        })?;
        let (mut pair, depth_from_reference) = rig.sensor_rig(s)?;
        pair.rectified |= rig.rectified;
        let request = Request::new(&pair, kind, FusionOptions { zbuffer: true, ..*options })?;
        let pair = request.rig();
        input.depth.expect_size(
            &format!("depth image of sensor {s}"),
            pair.depth.width,
            pair.depth.height,
        )?;
        input.color.expect_size(
            &format!("colour image of sensor {s}"),
            pair.color.width,
            pair.color.height,
        )?;
        pairs.push((input, request, depth_from_reference));
    }

    let t0 = Instant::now();
    let depths = pairs
        .par_iter()
        .map(|(input, request, _)| prepared_depth(input, request))
        .collect::<Result<Vec<_>, _>>()?;
    let frames: Vec<PixelFrame<'_>> = pairs
        .iter()
        .zip(&depths)
        .map(|((input, request, _), depth)| PixelFrame {
            rig: request.rig(),
            depth,
            color: &input.color,
            params: request.params(),
        })
        .collect();
    let outputs = engine.per_pixel_batch(&frames, kind, &mut StageTimings::default())?;
    let mut clouds: Vec<SensorCloud> = pairs
        .into_iter()
        .zip(depths)
        .zip(outputs)
        .map(|(((input, request, depth_from_reference), depth), out)| {
            sensor_cloud(&input.sensor, request.rig().clone(), depth_from_reference, depth, out)
        })
        .collect();
    let sensors_ms = t0.elapsed().as_secs_f64() * 1e3;

    let t1 = Instant::now();
    let kept: Vec<Vec<bool>> =
        (0..clouds.len()).into_par_iter().map(|b| best_seeing(&clouds, b)).collect();
    let mut cloud = PointCloud::default();
    let mut cloud_sensor = Vec::new();
    for (k, (c, kept)) in clouds.iter_mut().zip(kept).enumerate() {
        c.kept = kept;
        let m = c.depth_from_reference.inverse();
        let r = m.rotation.matrix();
        let t = m.translation;
        for ((p, col), _) in c.points.iter().zip(&c.colors).zip(&c.kept).filter(|(_, k)| **k) {
            let p = nalgebra::Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            let q = r * p + t;
            cloud.points.push([q.x as f32, q.y as f32, q.z as f32]);
            cloud.colors.push(*col);
            cloud_sensor.push(k as u16);
        }
    }
    let merge_ms = t1.elapsed().as_secs_f64() * 1e3;

    let t2 = Instant::now();
    let index_pairs: Vec<(usize, usize)> =
        (0..clouds.len()).flat_map(|a| (a + 1..clouds.len()).map(move |b| (a, b))).collect();
    let consistency =
        index_pairs.into_par_iter().map(|(a, b)| consistency(&clouds[a], &clouds[b])).collect();
    let consistency_ms = t2.elapsed().as_secs_f64() * 1e3;

    Ok(MultiFusion {
        sensors: clouds,
        cloud,
        cloud_sensor,
        consistency,
        timings: MultiTimings { sensors_ms, merge_ms, consistency_ms },
        rectified: rig.rectified,
        kind,
    })
}

/// Sensor `input`'s depth as its request prepares it ([`Request::prepare_depth`]), clipped to
/// the depth range (the depth its samples and later z-buffers come from).
fn prepared_depth(input: &SensorImages, request: &Request) -> Result<Image<f32>, GeometryError> {
    let mut depth = input.depth.clone();
    request.prepare_depth(&mut depth)?;
    let range = request.params().depth_range;
    Ok(if range.is_all() { depth } else { range.clip(&depth).into_owned() })
}

/// A sensor's samples from its per-pixel stages' output.
fn sensor_cloud(
    sensor: &str,
    rig: Rig,
    depth_from_reference: RigidTransform,
    depth: Image<f32>,
    out: PerPixelOutput,
) -> SensorCloud {
    let colors = cloud_colors(&out.cloud_pixels, &out.color_on_depth, &out.color_on_depth_valid);
    let (w, h) = depth.size();
    let mut z = Image::filled(w, h, f32::NAN);
    for (p, &i) in out.points.iter().zip(&out.cloud_pixels) {
        z.data_mut()[i as usize] = p[2];
    }
    let kept = vec![true; out.points.len()];
    SensorCloud {
        sensor: sensor.to_string(),
        rig,
        depth_from_reference,
        depth,
        points: out.points,
        pixels: out.cloud_pixels,
        colors,
        z,
        kept,
        color_on_depth: out.color_on_depth,
        color_valid: out.color_on_depth_valid,
    }
}

/// `a`'s depth camera seeing `b`'s points: the projection of b's depth frame into a's.
fn depth_into(a: &SensorCloud, b: &SensorCloud) -> ColorProjection {
    let a_from_b = a.depth_from_reference.compose(&b.depth_from_reference.inverse());
    projection(&a.rig.depth, a_from_b)
}

/// Per point of sensor `b`: no other sensor has a sample within the gate of it that is
/// closer to that sensor than the point is to `b`.
fn best_seeing(clouds: &[SensorCloud], b: usize) -> Vec<bool> {
    let cb = &clouds[b];
    let mut kept = vec![true; cb.points.len()];
    for (a, ca) in clouds.iter().enumerate() {
        if a == b {
            continue;
        }
        let proj = depth_into(ca, cb);
        let za = ca.z.data();
        for (p, k) in cb.points.iter().zip(kept.iter_mut()) {
            if !*k {
                continue;
            }
            if let Some([u, v, z]) = project_point(&proj, *p)
                && let Some(i) = zbuffer_index(u, v, proj.width, proj.height)
                && (za[i] - z).abs() <= OVERLAP_GATE_M
                && z < p[2]
            {
                *k = false;
            }
        }
    }
    kept
}

/// The pose of a camera at `from` looking at `at` (both in the rig's reference frame,
/// metres) with `up` (reference frame) pointing up in its image: `camera_from_reference`, the
/// camera's z axis towards `at`, its y axis (image down) in the plane of `−up` and the view
/// direction. Errors: `at` within [`LOOK_AT_MIN`] of `from`, `up` (nearly) along the view
/// direction, or a coordinate not finite.
pub fn look_at(
    from: nalgebra::Vector3<f64>,
    at: nalgebra::Vector3<f64>,
    up: nalgebra::Vector3<f64>,
) -> Result<RigidTransform, GeometryError> {
    let bad = |m: &str| GeometryError::InvalidInput(m.to_string());
    if !(from.iter().chain(at.iter()).chain(up.iter()).all(|c| c.is_finite())) {
        return Err(bad("the virtual camera's coordinates must be finite numbers"));
    }
    let view = at - from;
    if view.norm() < LOOK_AT_MIN {
        return Err(bad("the virtual camera looks at its own centre: give look-at away from from"));
    }
    let z = view.normalize();
    if up.norm() < LOOK_AT_MIN {
        return Err(bad("the virtual camera's up direction is zero"));
    }
    let x = (-up.normalize()).cross(&z);
    if x.norm() < LOOK_AT_MIN {
        return Err(bad("the virtual camera looks along its up direction: give another up=x,y,z"));
    }
    let x = x.normalize();
    let y = z.cross(&x);
    let world_from_camera = nalgebra::Matrix3::from_columns(&[x, y, z]);
    let r = nalgebra::Rotation3::from_matrix_unchecked(world_from_camera.transpose());
    Ok(RigidTransform::new(r, -(r * from)))
}

fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n % 2 == 1 { values[n / 2] } else { 0.5 * (values[n / 2 - 1] + values[n / 2]) }
}

/// Pixels between the neighbours whose points give a sample's surface normal in
/// [`SideTest`]: 2 on each side, so the normal spans 4 depth pixels (about 3 cm at 3 m), where
/// the time-of-flight noise of a few millimetres tilts it by a few degrees only.
const NORMAL_STEP_PX: usize = 2;

/// Which side of its surface a sample is seen from: a thin object (a calibration board, a
/// sheet, a door) seen from both sides by two sensors has its two faces within the overlap
/// gate of each other, and their colours are unrelated however good the rig is (the
/// simulated ring's board: printed front, plain back; correlation −0.02 on the true rig). The
/// colour comparison takes only samples that both sensors see from the same side.
struct SideTest {
    /// Index + 1 into A's points of every depth pixel of A, 0 for none.
    point_of_pixel: Vec<u32>,
    width: usize,
    height: usize,
    /// B's depth camera centre in A's depth frame.
    b_centre: [f64; 3],
}

impl SideTest {
    fn new(a: &SensorCloud, b: &SensorCloud) -> Self {
        let (width, height) = a.z.size();
        let mut point_of_pixel = vec![0u32; width * height];
        for (i, &px) in a.pixels.iter().enumerate() {
            if let Some(slot) = point_of_pixel.get_mut(px as usize) {
                *slot = i as u32 + 1;
            }
        }
        let a_from_b = a.depth_from_reference.compose(&b.depth_from_reference.inverse());
        let c = a_from_b.apply(&nalgebra::Vector3::zeros());
        Self { point_of_pixel, width, height, b_centre: [c.x, c.y, c.z] }
    }

    /// A's point at pixel (x, y), if A has a sample there.
    fn point(&self, a: &SensorCloud, x: usize, y: usize) -> Option<[f64; 3]> {
        if x >= self.width || y >= self.height {
            return None;
        }
        let k = self.point_of_pixel[y * self.width + x].checked_sub(1)?;
        let p = a.points[k as usize];
        Some([p[0] as f64, p[1] as f64, p[2] as f64])
    }

    /// Whether A (at its origin) and B see A's sample at pixel (x, y) from the same side of
    /// the surface through its neighbours; false where a neighbour is missing (an edge,
    /// where the side cannot be told).
    fn same_side(&self, a: &SensorCloud, x: usize, y: usize) -> bool {
        let s = NORMAL_STEP_PX;
        let (Some(p), Some(l), Some(r), Some(u), Some(d)) = (
            self.point(a, x, y),
            x.checked_sub(s).and_then(|xl| self.point(a, xl, y)),
            self.point(a, x + s, y),
            y.checked_sub(s).and_then(|yu| self.point(a, x, yu)),
            self.point(a, x, y + s),
        ) else {
            return false;
        };
        let sub = |p: [f64; 3], q: [f64; 3]| [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
        let (e1, e2) = (sub(r, l), sub(d, u));
        let n = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let dot = |v: [f64; 3]| n[0] * v[0] + n[1] * v[1] + n[2] * v[2];
        dot(sub([0.0; 3], p)) * dot(sub(self.b_centre, p)) > 0.0
    }
}

fn consistency(a: &SensorCloud, b: &SensorCloud) -> PairConsistency {
    let proj = depth_into(a, b);
    let sides = SideTest::new(a, b);
    let (w, h) = a.z.size();
    let za = a.z.data();
    let (tw, th) = (w.div_ceil(CONSISTENCY_TILE_PX), h.div_ceil(CONSISTENCY_TILE_PX));
    let mut tiles: Vec<Vec<f64>> = vec![Vec::new(); tw * th];
    let mut abs = Vec::new();
    let mut greys = Vec::new();
    for (i, p) in b.points.iter().enumerate() {
        let Some([u, v, z]) = project_point(&proj, *p) else { continue };
        let Some((x, y)) = zbuffer_pixel(u, v, proj.width, proj.height) else { continue };
        let d = za[y * w + x] - z;
        if d.abs() <= OVERLAP_GATE_M {
            abs.push(d.abs() as f64);
            tiles[(y / CONSISTENCY_TILE_PX) * tw + x / CONSISTENCY_TILE_PX].push(d as f64);
            let pixel = b.pixels[i] as usize;
            if a.color_valid.data()[y * w + x]
                && b.color_valid.data()[pixel]
                && sides.same_side(a, x, y)
            {
                let seen_by_b = b.color_on_depth.data()[pixel];
                greys.push((luma(a.color_on_depth.data()[y * w + x]), luma(seen_by_b)));
            }
        }
    }
    let mut tile_values: Vec<f64> =
        tiles.iter_mut().filter(|t| t.len() >= MIN_TILE_SAMPLES).map(|t| median(t).abs()).collect();
    let pixels = abs.len();
    PairConsistency {
        a: a.sensor.clone(),
        b: b.sensor.clone(),
        pixels,
        median_abs_mm: median(&mut abs) * 1e3,
        tiles: tile_values.len(),
        tile_median_mm: median(&mut tile_values) * 1e3,
        color_pixels: greys.len(),
        color_correlation: correlation(&greys),
    }
}

impl MultiFusion {
    /// Every sensor's samples z-buffered into `camera` (a camera of the rig the fusion was
    /// made with): per pixel the smallest `z` in that camera's frame, [`ZBUFFER_EMPTY`]
    /// where no sample lands (H2 + H7's rules, see the module docs).
    pub fn zbuffer_into(&self, camera: &RigCamera) -> Image<f32> {
        let all: Vec<usize> = (0..self.sensors.len()).collect();
        self.zbuffer_of_sensors(camera, &all)
    }

    /// [`MultiFusion::zbuffer_into`] with the samples of the sensors at `sensors` (indices
    /// into [`MultiFusion::sensors`]) only.
    pub fn zbuffer_of_sensors(&self, camera: &RigCamera, sensors: &[usize]) -> Image<f32> {
        let model = model_as_fused(&camera.model, self.rectified);
        let mut out = Image::filled(model.width, model.height, ZBUFFER_EMPTY);
        for s in sensors.iter().filter_map(|&k| self.sensors.get(k)) {
            let camera_from_depth =
                camera.camera_from_reference.compose(&s.depth_from_reference.inverse());
            zbuffer_points(&s.points, &projection(&model, camera_from_depth), out.data_mut());
        }
        out
    }

    /// [`MultiFusion::zbuffer_into`] on `engine` ([`PerPixel::zbuffer_views`] of every
    /// sensor's corrected depth): on the GPU one atomic-min z-buffer across the sensors. The
    /// same image as [`MultiFusion::zbuffer_into`] on every engine.
    pub fn zbuffer_into_on<E: PerPixel>(
        &self,
        engine: &mut E,
        camera: &RigCamera,
    ) -> Result<Image<f32>, E::Error> {
        let model = model_as_fused(&camera.model, self.rectified);
        let views: Vec<DepthView<'_>> = self
            .sensors
            .iter()
            .map(|s| DepthView {
                depth_camera: &s.rig.depth,
                depth: &s.depth,
                camera_from_depth: camera
                    .camera_from_reference
                    .compose(&s.depth_from_reference.inverse()),
            })
            .collect();
        engine.zbuffer_views(&model, &views, self.kind)
    }

    /// H4 + H5 of sensor `k` (index into [`MultiFusion::sensors`]; `None` past the end): its
    /// depth grid meshed and cleaned in its colour camera's frame as the single-sensor
    /// pipeline does (`fusion::run` with [`super::MeshSource::DepthGrid`]: the samples landing
    /// on its colour image, texture coordinates into it, H6 vertex colours, H5 with
    /// `options`' rule at its depth camera's scale), the vertices then moved into the rig's
    /// reference frame (metres). Returns the cleaned mesh and the face count before H5.
    pub fn sensor_mesh(&self, k: usize, options: &FusionOptions) -> Option<(Mesh, usize)> {
        let s = self.sensors.get(k)?;
        let proj = ColorProjection::from_rig(&s.rig);
        let samples = project_cloud(&s.points, &proj);
        let (mesh, _) = mesh_on_depth_grid(
            s.rig.depth.width,
            s.rig.depth.height,
            &s.points,
            &s.pixels,
            &samples,
            &s.rig.color_from_depth,
            (s.rig.color.width, s.rig.color.height),
            &s.color_on_depth,
            &s.color_valid,
        );
        let before = mesh.faces.len();
        let mut clean = remove_edge_faces(&mesh, &stretch_test(&s.rig, options));
        let reference_from_color =
            s.rig.color_from_depth.compose(&s.depth_from_reference).inverse();
        for v in &mut clean.vertices {
            let p = nalgebra::Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64);
            let q = reference_from_color.apply(&p);
            *v = [q.x as f32, q.y as f32, q.z as f32];
        }
        Some((clean, before))
    }

    /// The merged cloud z-buffered into a camera `model` at pose `camera_from_reference`
    /// (any pose: a virtual view): per pixel the smallest `z` in that camera's frame
    /// ([`ZBUFFER_EMPTY`] where no point lands) and the colour of that point (black where
    /// none). Points are projected from their own depth frame with the composed pose (H2's
    /// arithmetic, H7's pixel rule); of equal `z` the first in cloud order wins.
    pub fn render_merged(
        &self,
        model: &CameraModel,
        camera_from_reference: &RigidTransform,
    ) -> (Image<f32>, Image<[u8; 3]>) {
        let model = model_as_fused(model, self.rectified);
        let mut depth = Image::filled(model.width, model.height, ZBUFFER_EMPTY);
        let mut color = Image::filled(model.width, model.height, [0u8; 3]);
        for s in &self.sensors {
            let camera_from_depth =
                camera_from_reference.compose(&s.depth_from_reference.inverse());
            let proj = projection(&model, camera_from_depth);
            let kept = s.points.iter().zip(&s.colors).zip(&s.kept).filter(|(_, k)| **k);
            for ((p, c), _) in kept {
                if let Some([u, v, z]) = project_point(&proj, *p)
                    && let Some(i) = zbuffer_index(u, v, proj.width, proj.height)
                    && !(depth.data()[i] <= z)
                {
                    depth.data_mut()[i] = z;
                    color.data_mut()[i] = *c;
                }
            }
        }
        (depth, color)
    }

    /// Points of each sensor in the merged cloud.
    pub fn points_per_sensor(&self) -> Vec<usize> {
        self.sensors.iter().map(|s| s.kept.iter().filter(|k| **k).count()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::{Registration, depth_ray_table};
    use crate::synth::{KinectNoise, KinectRing, kinect_ring_preset, render_ring};

    /// The consistency bar of issue 32: 2 mm.
    const CONSISTENCY_BAR_MM: f64 = 2.0;

    fn inputs(ring: &KinectRing, frames: &[crate::synth::SynthFrame]) -> Vec<SensorImages> {
        ring.serials
            .iter()
            .zip(frames)
            .map(|(s, f)| SensorImages {
                sensor: s.clone(),
                depth: f.depth.clone(),
                color: f.color.clone(),
            })
            .collect()
    }

    /// Per point of sensor `k`: distance to the true surface point along its pixel's ray.
    fn errors(
        fusion: &MultiFusion,
        frames: &[crate::synth::SynthFrame],
        k: usize,
        only_kept: bool,
    ) -> Vec<f64> {
        let s = &fusion.sensors[k];
        let rays = depth_ray_table(&s.rig.depth, DepthKind::Z);
        let truth = frames[k].true_depth_z.data();
        s.points
            .iter()
            .zip(&s.pixels)
            .zip(&s.kept)
            .filter(|(_, kept)| !only_kept || **kept)
            .filter_map(|((p, &i), _)| {
                let t = truth[i as usize] as f64;
                let [x, y, _] = rays[i as usize];
                let norm = ((x * x + y * y + 1.0) as f64).sqrt();
                t.is_finite().then(|| (p[2] as f64 - t).abs() * norm)
            })
            .collect()
    }

    fn perturbed(ring: &KinectRing, serial: &str) -> MultiRig {
        // 1° about an oblique axis and 1 cm, applied to the whole sensor (both cameras).
        let delta = RigidTransform::from_axis_angle(
            nalgebra::Vector3::new(0.6, 0.8, 0.0) * 1f64.to_radians(),
            nalgebra::Vector3::new(0.006, -0.008, 0.0),
        );
        let mut rig = ring.rig.clone();
        let depth = rig.camera(&format!("{serial}.depth")).unwrap().camera_from_reference;
        // The depth camera moves about its own centre; the colour camera moves with it.
        let moved = delta.compose(&depth);
        for c in rig.cameras.iter_mut().filter(|c| c.sensor.as_deref() == Some(serial)) {
            let from_depth = c.camera_from_reference.compose(&depth.inverse());
            c.camera_from_reference = from_depth.compose(&moved);
        }
        rig
    }

    #[test]
    fn ring_merged_cloud_beats_every_sensor_and_the_true_rig_is_consistent() {
        let ring = kinect_ring_preset();
        let frames = render_ring(&ring, Some(&KinectNoise::default()));
        let fusion =
            fuse_multi(&ring.rig, &inputs(&ring, &frames), DepthKind::Z, &FusionOptions::default())
                .unwrap();
        let mut merged = Vec::new();
        let mut singles = Vec::new();
        for k in 0..ring.serials.len() {
            let mut all = errors(&fusion, &frames, k, false);
            singles.push(median(&mut all) * 1e3);
            merged.extend(errors(&fusion, &frames, k, true));
        }
        let merged = median(&mut merged) * 1e3;
        println!("median point error per sensor (mm): {singles:.3?}; merged: {merged:.3}");
        println!("points per sensor in the merged cloud: {:?}", fusion.points_per_sensor());
        for &s in &singles {
            assert!(merged <= s, "merged {merged:.3} mm > single sensor {s:.3} mm");
        }
        assert_eq!(fusion.consistency.len(), 3);
        for c in &fusion.consistency {
            println!(
                "true rig {}-{}: {} px, per-pixel median |dz| {:.3} mm, tile consistency {:.3} mm over {} tiles",
                c.a, c.b, c.pixels, c.median_abs_mm, c.tile_median_mm, c.tiles
            );
            println!("  colour {} px, correlation {:.3}", c.color_pixels, c.color_correlation);
            // The ring's sensors overlap on the floor and the objects' sides: thousands of pixels.
            assert!(c.pixels > 2000 && c.tiles > 30, "{c:?}");
            assert!(c.tile_median_mm <= CONSISTENCY_BAR_MM, "{c:?}");
            assert!(c.color_correlation >= MIN_COLOR_CORRELATION, "{c:?}");
        }

        let broken = perturbed(&ring, "RING2");
        let fusion =
            fuse_multi(&broken, &inputs(&ring, &frames), DepthKind::Z, &FusionOptions::default())
                .unwrap();
        for c in &fusion.consistency {
            println!(
                "RING2 moved 1 cm, 1°: {}-{}: {} px, per-pixel median |dz| {:.3} mm, tile consistency {:.3} mm over {} tiles",
                c.a, c.b, c.pixels, c.median_abs_mm, c.tile_median_mm, c.tiles
            );
            println!("  colour {} px, correlation {:.3}", c.color_pixels, c.color_correlation);
            if c.b == "RING2" {
                // Twice the bar: a pose error of this size is not mistaken for noise.
                assert!(c.tile_median_mm > 2.0 * CONSISTENCY_BAR_MM, "{c:?}");
            } else {
                assert!(c.tile_median_mm <= CONSISTENCY_BAR_MM, "{c:?}");
            }
        }
    }

    /// A rig that does not describe the sensors (two sensors' images swapped; two sensors'
    /// poses swapped) measured 10–20 mm and 0.6–0.8 mm tile consistency here (0.4 mm over a few
    /// tiles in the case): numbers that look as good as the truth's in this symmetric
    /// ring. The colour correlation tells them apart: under [`MIN_COLOR_CORRELATION`] for every
    /// pair with a swapped sensor, over it for the true rig (the test above).
    #[test]
    fn swapped_sensors_and_poses_are_told_by_their_colours() {
        let ring = kinect_ring_preset();
        let frames = render_ring(&ring, Some(&KinectNoise::default()));
        let mut swapped = inputs(&ring, &frames);
        let (a, b) = (swapped[0].sensor.clone(), swapped[1].sensor.clone());
        (swapped[0].sensor, swapped[1].sensor) = (b, a);
        let images =
            fuse_multi(&ring.rig, &swapped, DepthKind::Z, &FusionOptions::default()).unwrap();
        let mut poses = ring.rig.clone();
        let pose =
            |r: &MultiRig, s: &str| r.camera(&format!("{s}.depth")).unwrap().camera_from_reference;
        let (s1, s2) = (ring.serials[1].as_str(), ring.serials[2].as_str());
        let (p1, p2) = (pose(&ring.rig, s1), pose(&ring.rig, s2));
        for c in poses.cameras.iter_mut() {
            let (from, to) = match c.sensor.as_deref() {
                Some(s) if s == s1 => (p1, p2),
                Some(s) if s == s2 => (p2, p1),
                _ => continue,
            };
            c.camera_from_reference = c.camera_from_reference.compose(&from.inverse()).compose(&to);
        }
        let poses =
            fuse_multi(&poses, &inputs(&ring, &frames), DepthKind::Z, &FusionOptions::default())
                .unwrap();
        for (what, fusion) in [("images", &images), ("poses", &poses)] {
            assert_eq!(fusion.consistency.len(), 3);
            for c in &fusion.consistency {
                println!(
                    "swapped {what} {}-{}: {} px, tile {:.3} mm over {} tiles, colour {} px, correlation {:.3}",
                    c.a,
                    c.b,
                    c.pixels,
                    c.tile_median_mm,
                    c.tiles,
                    c.color_pixels,
                    c.color_correlation
                );
                assert!(c.color_pixels > 10_000, "{c:?}");
                assert!(c.color_correlation < MIN_COLOR_CORRELATION, "{what}: {c:?}");
            }
        }
    }

    /// One sensor's samples z-buffered into its own colour camera are bit-identical to
    /// `Registration`'s z-buffer of the same frame: the same f64 pose (the rig's
    /// `transform`), rounded to the same f32 projection, and H2/H7's rules.
    #[test]
    fn own_colour_camera_zbuffer_equals_registration() {
        let ring = kinect_ring_preset();
        let frames = render_ring(&ring, Some(&KinectNoise::default()));
        let fusion =
            fuse_multi(&ring.rig, &inputs(&ring, &frames), DepthKind::Z, &FusionOptions::default())
                .unwrap();
        for (k, serial) in ring.serials.iter().enumerate() {
            let (pair, _) = ring.rig.sensor_rig(serial).unwrap();
            let mut reg =
                Registration::new(&pair, DepthKind::Z, &FusionOptions::default()).unwrap();
            let landed = reg.register(&frames[k].depth).unwrap();
            assert!(landed > 50_000, "{landed}");
            let camera = ring.rig.camera(&format!("{serial}.color")).unwrap();
            let ours = fusion.zbuffer_of_sensors(camera, &[k]);
            let same = ours
                .data()
                .iter()
                .zip(reg.zbuffer())
                .filter(|(a, b)| a.to_bits() == b.to_bits())
                .count();
            assert_eq!(same, ours.data().len(), "sensor {serial}: pixels differ");
        }
        // All sensors into one camera: at least as many pixels as its own sensor alone.
        let camera = ring.rig.camera("RING0.color").unwrap();
        let filled = |img: &Image<f32>| img.data().iter().filter(|z| z.is_finite()).count();
        assert!(
            filled(&fusion.zbuffer_into(camera)) > filled(&fusion.zbuffer_of_sensors(camera, &[0]))
        );
    }

    /// Per sensor, the mesh of `sensor_mesh` is the single-sensor pipeline's H5-clean mesh of
    /// that frame (`fusion::run` with the sensor's own pair): the same faces, texture
    /// coordinates and vertex colours, and its vertices those of the single mesh moved into
    /// the reference frame by the rig's pose.
    #[test]
    fn sensor_meshes_are_the_single_sensor_meshes_in_the_reference_frame() {
        // f32 vertices of metre-sized coordinates moved by an f64 pose: a few ulps (1e-7 m);
        // the bar of the task, 1 µm, is well above that and far below a depth sample.
        const VERTEX_TOL_M: f64 = 1e-6;
        let ring = kinect_ring_preset();
        let frames = render_ring(&ring, Some(&KinectNoise::default()));
        let opts = FusionOptions::default();
        let fusion = fuse_multi(&ring.rig, &inputs(&ring, &frames), DepthKind::Z, &opts).unwrap();
        for (k, serial) in ring.serials.iter().enumerate() {
            let (pair, depth_from_ref) = ring.rig.sensor_rig(serial).unwrap();
            let single =
                crate::fusion::run(&pair, &frames[k].depth, DepthKind::Z, &frames[k].color, &opts)
                    .unwrap();
            let (ours, before) = fusion.sensor_mesh(k, &opts).unwrap();
            println!(
                "sensor {serial}: {} vertices, {before} faces -> {} after H5 (single-sensor fuse: {} -> {})",
                ours.vertices.len(),
                ours.faces.len(),
                single.mesh.faces.len(),
                single.mesh_clean.faces.len()
            );
            assert!(ours.faces.len() > 100_000, "{}", ours.faces.len());
            assert!(ours.faces.len() < before, "H5 removed nothing");
            assert_eq!(before, single.mesh.faces.len());
            assert_eq!(ours.faces, single.mesh_clean.faces);
            assert_eq!(ours.uvs, single.mesh_clean.uvs);
            assert_eq!(ours.colors, single.mesh_clean.colors);
            assert_eq!(ours.vertices.len(), single.mesh_clean.vertices.len());
            let ref_from_color = pair.color_from_depth.compose(&depth_from_ref).inverse();
            let worst = ours
                .vertices
                .iter()
                .zip(&single.mesh_clean.vertices)
                .map(|(a, b)| {
                    let b = ref_from_color.apply(&nalgebra::Vector3::new(
                        b[0] as f64,
                        b[1] as f64,
                        b[2] as f64,
                    ));
                    (nalgebra::Vector3::new(a[0] as f64, a[1] as f64, a[2] as f64) - b).norm()
                })
                .fold(0.0, f64::max);
            println!("sensor {serial}: largest vertex difference {worst:.2e} m");
            assert!(worst <= VERTEX_TOL_M, "{worst} m");
        }
        assert!(fusion.sensor_mesh(3, &opts).is_none());
    }

    /// The true `z` of every pixel of `model` at `camera_from_world` in the ring's world
    /// scene (NaN where the ray hits nothing), by the scene's own ray caster.
    pub(crate) fn true_view(
        ring: &KinectRing,
        model: &CameraModel,
        camera_from_world: &RigidTransform,
    ) -> Image<f32> {
        let world_from_camera = camera_from_world.inverse();
        let o = world_from_camera.translation;
        let fold = model.distortion.fold_radius();
        let mut out = Image::filled(model.width, model.height, f32::NAN);
        for y in 0..model.height {
            for x in 0..model.width {
                let d = model.intrinsics.from_pixel(x as f64, y as f64);
                let Some(n) = model.distortion.undistort_within(d.x, d.y, fold) else { continue };
                let dir = world_from_camera.rotation * nalgebra::Vector3::new(n.x, n.y, 1.0);
                if let Some(hit) = ring.world.cast(&o, &dir) {
                    out.data_mut()[y * model.width + x] =
                        camera_from_world.apply(&hit.point).z as f32;
                }
            }
        }
        out
    }

    /// A virtual camera above the ring between sensors 0 and 1, looking down at the objects:
    /// the merged cloud rendered there agrees with the scene's truth rendered at that pose.
    #[test]
    fn virtual_view_of_the_merged_cloud_matches_the_truth_at_that_pose() {
        // Median |z − z_true| bound, mm: the samples' noise (σ = 1.5 mm·z², ~1.6 mm median at
        // 1.3–2 m), the nearest-wins minimum of several samples per pixel (biased towards the
        // camera), and a point landing up to half a pixel from the centre the truth is cast
        // through (on the floor seen at 45°, ~1.5 mm).
        const MEDIAN_BOUND_MM: f64 = 4.0;
        // A pixel is right when within 2 cm of the truth (ten times the noise); wrong ones are
        // gaps between splatted points through which a farther surface shows.
        const RIGHT_MM: f64 = 20.0;
        const MIN_RIGHT_FRACTION: f64 = 0.9;
        // The view is covered: at least half of the pixels whose ray meets the scene.
        const MIN_COVERAGE: f64 = 0.5;
        let ring = kinect_ring_preset();
        let frames = render_ring(&ring, Some(&KinectNoise::default()));
        let opts = FusionOptions::default();
        let fusion = fuse_multi(&ring.rig, &inputs(&ring, &frames), DepthKind::Z, &opts).unwrap();
        let world_from_ref = ring.depth_from_world[0].inverse();
        let ref_from_world = ring.depth_from_world[0];
        let a = 60f64.to_radians();
        let from_w = nalgebra::Vector3::new(1.3 * a.sin(), -0.9, -1.3 * a.cos());
        let at_w = nalgebra::Vector3::new(0.0, 0.1, 0.0);
        let up_w = nalgebra::Vector3::new(0.0, -1.0, 0.0);
        let pose = look_at(
            ref_from_world.apply(&from_w),
            ref_from_world.apply(&at_w),
            ref_from_world.rotation * up_w,
        )
        .unwrap();
        let model = ring.rig.camera(&ring.rig.reference).unwrap().model;
        let (depth, color) = fusion.render_merged(&model, &pose);
        let truth = true_view(&ring, &model, &pose.compose(&ref_from_world));
        // The truth's own check: `world_from_ref` and back is the identity.
        assert!((world_from_ref.compose(&ref_from_world).translation).norm() < 1e-12);
        let mut diffs = Vec::new();
        let mut scene_pixels = 0usize;
        for ((z, t), _c) in depth.data().iter().zip(truth.data()).zip(color.data()) {
            if t.is_finite() {
                scene_pixels += 1;
            }
            if z.is_finite() && t.is_finite() {
                diffs.push(((z - t).abs() * 1e3) as f64);
            }
        }
        let covered = diffs.len() as f64 / scene_pixels as f64;
        let right = diffs.iter().filter(|d| **d <= RIGHT_MM).count() as f64 / diffs.len() as f64;
        let med = median(&mut diffs);
        println!(
            "virtual view: {} of {scene_pixels} scene pixels covered ({:.1} %), median |dz| {med:.3} mm, {:.1} % within {RIGHT_MM} mm",
            diffs.len(),
            100.0 * covered,
            100.0 * right
        );
        assert!(covered >= MIN_COVERAGE, "{covered}");
        assert!(med <= MEDIAN_BOUND_MM, "{med} mm");
        assert!(right >= MIN_RIGHT_FRACTION, "{right}");

        // Bad poses are one clear error each.
        let o = nalgebra::Vector3::zeros();
        let e = look_at(o, o, up_w).unwrap_err().to_string();
        assert!(e.contains("looks at its own centre"), "{e}");
        let e = look_at(o, up_w, up_w).unwrap_err().to_string();
        assert!(e.contains("along its up direction"), "{e}");
    }

    #[test]
    fn missing_unknown_and_wrongly_sized_inputs_are_refused() {
        let ring = kinect_ring_preset();
        let frames: Vec<_> = ring.setups.iter().map(crate::synth::render).collect();
        let mut inp = inputs(&ring, &frames);
        let opts = FusionOptions::default();
        inp.pop();
        let e = fuse_multi(&ring.rig, &inp, DepthKind::Z, &opts).unwrap_err().to_string();
        assert!(e.contains("RING2") && e.contains("no depth and colour images"), "{e}");
        let mut inp = inputs(&ring, &frames);
        inp[1].sensor = "NOPE".into();
        let e = fuse_multi(&ring.rig, &inp, DepthKind::Z, &opts).unwrap_err().to_string();
        assert!(e.contains("\"NOPE\" is not in the rig"), "{e}");
        let mut inp = inputs(&ring, &frames);
        inp[0].color = Image::filled(640, 480, [0; 3]);
        let e = fuse_multi(&ring.rig, &inp, DepthKind::Z, &opts).unwrap_err().to_string();
        assert!(e.contains("colour image of sensor RING0"), "{e}");
    }
}
