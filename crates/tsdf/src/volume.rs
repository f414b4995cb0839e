//! The sparse volume and the projective integration of depth images.

use std::collections::HashMap;

use geometry::{CameraModel, Image, RigidTransform};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use wide::f32x8;

use crate::{TsdfError, TsdfOptions};

/// Voxels along each edge of a block: 8 (a block is 8³ = 512 voxels, 4 cm at 5 mm voxels:
/// large enough that the hash map holds few keys, small enough that the band of a surface,
/// about 6 cm thick, fills a good share of every block it touches).
pub const BLOCK_SIDE: usize = 8;
/// Voxels of a block.
pub const BLOCK_VOXELS: usize = BLOCK_SIDE * BLOCK_SIDE * BLOCK_SIDE;
/// Bytes of bookkeeping per block besides its voxels, as the memory bound counts them: 64
/// (its key in the block list, 12; the hash map's key, value and control byte at its worst
/// load factor, ~20; the voxel array's pointer and length, 16; the rest for the map's growth).
pub const BLOCK_OVERHEAD_BYTES: u64 = 64;
/// Bytes of one block as [`TsdfOptions::max_memory_bytes`] counts them.
pub const BLOCK_BYTES: u64 =
    (std::mem::size_of::<Voxel>() * BLOCK_VOXELS) as u64 + BLOCK_OVERHEAD_BYTES;

/// Largest depth step between the four pixels around a voxel's projection, as a fraction of
/// the depth, at which the depth is interpolated bilinearly (otherwise the nearest pixel is
/// read): 3 %. A surface at 75° to the ray steps ~1 % of z per Kinect pixel, and the noise of
/// the difference of two pixels is ~1 % of z at 4.5 m (σ(z)·√2); the project calls a step of
/// 5 % a depth edge (`geometry::synth::FLYING_EDGE_JUMP`), across which interpolating would
/// invent a surface between the two.
pub const INTERPOLATION_MAX_STEP: f64 = 0.03;

/// Image rows whose blocks are gathered (in parallel) before they are merged into the frame's
/// list and checked against the memory bound: 32, enough rows for every core, few enough
/// that one band's keys stay small next to the bound (32 rows of a 512-pixel-wide image).
const ROWS_PER_MERGE: usize = 32;

/// Block keys each row's gathering remembers to skip repeats: 8, two or three pixels'
/// segments (a band of 2μ = 6 cm crosses 2–4 blocks of 4 cm); the sort and dedup after the
/// row stay exact, this only shortens the list they work on.
const RECENT_KEYS: usize = 8;

/// Cameras whose undistorted ray tables a volume keeps between frames: 16, more than the
/// sensors of any rig kfuse fuses (a table of a 512×424 camera is 1.7 MB).
const MAX_CACHED_CAMERAS: usize = 16;

/// The Kinect depth noise σ(z) at depth `z` (metres): `σ₁ · z²` with σ₁ =
/// [`geometry::fusion::KINECT_NOISE_1M_M`] (1.5 mm at 1 m; Khoshelham & Elberink 2012, the
/// model issue 13 states for the Kinect v2 and the simulator draws its noise from).
pub fn depth_sigma_m(z: f64) -> f64 {
    geometry::fusion::KINECT_NOISE_1M_M as f64 * z * z
}

/// The weight of one sample at depth `z` (metres): its inverse variance relative to a sample
/// at 1 m, `(σ(1 m) / σ(z))² = 1 / z⁴`. The fused TSDF of a voxel is the inverse-variance
/// weighted mean of the samples' signed distances, the least-squares estimate of the surface.
pub fn depth_weight(z: f64) -> f64 {
    let s = depth_sigma_m(z) / depth_sigma_m(1.0);
    1.0 / (s * s)
}

/// Farthest a camera may be from the volume's origin, metres: 100 km. Far beyond any scene a
/// depth camera sees (a rig's poses are metres from its reference camera), and it keeps the
/// block coordinates of the finest voxels (8 mm blocks) out to the farthest depth range
/// (100 m) a hundred times inside `i32` (a pose 1e300 m away overflowed the block walk).
pub const MAX_CAMERA_DISTANCE_M: f64 = 1.0e5;

/// One voxel: the truncated signed distance (in units of the truncation, −1…1, positive in
/// front of the surface, towards the cameras), its weight (0: never observed), and the
/// weighted mean colour with its own weight (0: no colour seen).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Voxel {
    /// Signed distance divided by the truncation.
    pub tsdf: f32,
    /// Sum of the samples' weights ([`depth_weight`]).
    pub weight: f32,
    /// Mean colour, 0–255 per channel.
    pub color: [f32; 3],
    /// Sum of the weights of the samples that had a colour.
    pub color_weight: f32,
}

/// The colour registered onto a depth image: `rgb` at every depth pixel, trusted where
/// `valid` (the colour camera sees that depth sample): `geometry::fusion`'s H6
/// (`SensorCloud::color_on_depth` and `color_valid`).
#[derive(Debug, Clone, Copy)]
pub struct RegisteredColor<'a> {
    /// Colour per depth pixel.
    pub rgb: &'a Image<[u8; 3]>,
    /// Where the colour is trusted.
    pub valid: &'a Image<bool>,
}

/// One depth image to integrate.
#[derive(Debug, Clone, Copy)]
pub struct DepthFrame<'a> {
    /// The depth camera (with its distortion; voxel centres are projected through it).
    pub camera: &'a CameraModel,
    /// The depth camera's pose: `X_camera = R · X_volume + T`.
    pub camera_from_volume: RigidTransform,
    /// z depth (along the optical axis), metres; NaN or 0 for no sample. Convert range depth
    /// with [`geometry::DepthKind::to_z`] first.
    pub z: &'a Image<f32>,
    /// Optional colour per depth pixel.
    pub color: Option<RegisteredColor<'a>>,
}

/// What one [`TsdfVolume::integrate`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct IntegrationStats {
    /// Depth pixels within the depth range.
    pub pixels: usize,
    /// Blocks the frame's band touched.
    pub blocks_touched: usize,
    /// Blocks newly allocated.
    pub blocks_allocated: usize,
    /// Voxels updated.
    pub voxels_updated: usize,
}

/// A sparse TSDF volume: blocks of [`BLOCK_VOXELS`] voxels allocated where a depth image's
/// truncation band passes, found through a hash map of block coordinates. Coordinates are
/// those of the volume's frame (a rig's reference frame, metres); voxel `g` (integer
/// coordinates) has its centre at `(g + ½) · voxel_size`, block `b` holds voxels
/// `8·b … 8·b + 7`.
#[derive(Debug, Clone)]
pub struct TsdfVolume {
    options: TsdfOptions,
    keys: Vec<[i32; 3]>,
    blocks: Vec<Box<[Voxel]>>,
    index: HashMap<[i32; 3], u32>,
    rays: Vec<(CameraModel, Vec<[f32; 2]>)>,
    frames: usize,
}

impl TsdfVolume {
    /// An empty volume; the options are validated.
    pub fn new(options: TsdfOptions) -> Result<Self, TsdfError> {
        options.validate()?;
        Ok(Self {
            options,
            keys: Vec::new(),
            blocks: Vec::new(),
            index: HashMap::new(),
            rays: Vec::new(),
            frames: 0,
        })
    }

    /// The volume's options.
    pub fn options(&self) -> &TsdfOptions {
        &self.options
    }

    /// Allocated blocks.
    pub fn block_count(&self) -> usize {
        self.blocks.len()
    }

    /// Bytes the blocks take as the memory bound counts them.
    pub fn memory_bytes(&self) -> u64 {
        self.blocks.len() as u64 * BLOCK_BYTES
    }

    /// Frames integrated.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// The voxel with integer coordinates `g`, if its block is allocated.
    pub fn voxel(&self, g: [i64; 3]) -> Option<&Voxel> {
        let (key, local) = split_voxel(g)?;
        let b = *self.index.get(&key)?;
        Some(&self.blocks[b as usize][local])
    }

    /// The integer coordinates of the voxel whose cell holds point `p` (volume frame).
    pub fn voxel_of(&self, p: &Vector3<f64>) -> [i64; 3] {
        let v = self.options.voxel_size_m;
        [(p.x / v).floor() as i64, (p.y / v).floor() as i64, (p.z / v).floor() as i64]
    }

    /// Sets voxel `g`, allocating its block (the marching-cubes tests fill analytic fields).
    #[cfg(test)]
    pub(crate) fn set_voxel(&mut self, g: [i64; 3], voxel: Voxel) {
        let (key, local) = split_voxel(g).unwrap();
        let b = *self.index.entry(key).or_insert_with(|| {
            self.keys.push(key);
            self.blocks.push(vec![Voxel::default(); BLOCK_VOXELS].into_boxed_slice());
            (self.blocks.len() - 1) as u32
        });
        self.blocks[b as usize][local] = voxel;
    }

    /// Block keys and voxels, for the mesh extraction.
    pub(crate) fn parts(&self) -> Parts<'_> {
        Parts { keys: &self.keys, blocks: &self.blocks, index: &self.index }
    }

    fn ray_table(&mut self, camera: &CameraModel) -> usize {
        if let Some(i) = self.rays.iter().position(|(c, _)| c == camera) {
            return i;
        }
        if self.rays.len() >= MAX_CACHED_CAMERAS {
            self.rays.remove(0);
        }
        self.rays.push((*camera, camera.ray_table()));
        self.rays.len() - 1
    }

    /// Integrates one depth image (and its registered colour): every voxel whose centre
    /// projects (through the camera's distortion) onto a pixel with a sample, and lies within
    /// the truncation μ of that sample along the pixel's ray, in front or behind, takes the
    /// sample's signed distance with the weight [`depth_weight`]. The signed distance compares
    /// the voxel's camera-frame `z` with the measured `z` and scales the difference to the
    /// distance along the ray: `sdf = (z_measured − z_voxel) · √(1 + x² + y²)` with
    /// `(x, y) = (X/Z, Y/Z)` of the voxel. Voxels farther than μ behind a sample are never
    /// touched (a thin object seen from its other side keeps its back face), nor voxels
    /// farther than μ in front.
    ///
    /// Errors, before anything changes: a NaN or infinite pose, a camera model that does not
    /// validate, a depth (or colour) image of another size than the camera, and
    /// [`TsdfError::MemoryBound`] when the blocks the frame needs would exceed the bound.
    pub fn integrate(&mut self, frame: &DepthFrame<'_>) -> Result<IntegrationStats, TsdfError> {
        let camera = frame.camera;
        camera.validate()?;
        let (w, h) = (camera.width, camera.height);
        frame.z.expect_size("depth image", w, h)?;
        if let Some(c) = &frame.color {
            c.rgb.expect_size("registered colour image", w, h)?;
            c.valid.expect_size("registered colour mask", w, h)?;
        }
        let pose = &frame.camera_from_volume;
        let r = *pose.rotation.matrix();
        if !(r.iter().all(|v| v.is_finite()) && pose.translation.iter().all(|v| v.is_finite())) {
            return Err(TsdfError::InvalidFrame(format!(
                "camera pose must be finite, got rotation {:?} translation {:?}",
                r.as_slice(),
                pose.translation.as_slice()
            )));
        }
        let volume_from_camera = pose.inverse();
        let distance = volume_from_camera.translation.norm();
        if !(distance <= MAX_CAMERA_DISTANCE_M) {
            return Err(TsdfError::InvalidFrame(format!(
                "the camera is {distance:.3e} m from the volume's origin, farther than {MAX_CAMERA_DISTANCE_M} m: is the pose camera_from_volume in metres?"
            )));
        }
        let table = self.ray_table(camera);
        let rays = &self.rays[table].1;
        let o = self.options;
        let block_m = o.voxel_size_m * BLOCK_SIDE as f64;
        let depth = frame.z.data();

        // 1. The blocks the band of every sample passes through, gathered in bands of rows
        //    and merged after each, so that the key list never holds more than the blocks
        //    the memory bound allows plus one band's: a frame past the bound is refused
        //    before the list outgrows it.
        let limit_blocks = (o.max_memory_bytes / BLOCK_BYTES) as usize;
        // The camera's centre and rotation in the volume's frame: a pixel's band runs from
        // `c + R·dir·t0` to `c + R·dir·t1`.
        let centre = volume_from_camera.translation;
        let rot = *volume_from_camera.rotation.matrix();
        let row_keys = |y: usize| {
            let mut keys = Vec::new();
            let mut segment = Vec::new();
            // The previous pixel's blocks: neighbouring pixels' bands mostly pass through the
            // same ones, and a repeated list is not pushed again, which keeps the row's list
            // (and its sort) short; the sort and dedup after the row stay exact.
            let mut previous: Vec<[i32; 3]> = Vec::new();
            // And the keys pushed last, for the pixels whose list differs from the previous
            // one in a block or two.
            let mut recent = [[i32::MIN; 3]; RECENT_KEYS];
            let mut next = 0;
            let mut pixels = 0;
            for x in 0..w {
                let i = y * w + x;
                let z = depth[i] as f64;
                if !(z >= o.min_depth_m && z <= o.max_depth_m) {
                    continue;
                }
                let [rx, ry] = rays[i];
                if !(rx.is_finite() && ry.is_finite()) {
                    continue;
                }
                pixels += 1;
                let dir = Vector3::new(rx as f64, ry as f64, 1.0);
                let len = dir.norm();
                let range = z * len;
                let t0 = (range - o.truncation_m).max(0.0) / len;
                let t1 = (range + o.truncation_m) / len;
                let d = rot * dir;
                let a = centre + d * t0;
                let b = centre + d * t1;
                segment.clear();
                blocks_on_segment(&a, &b, block_m, &mut segment);
                if segment != previous {
                    for k in &segment {
                        if !recent.contains(k) {
                            recent[next] = *k;
                            next = (next + 1) % RECENT_KEYS;
                            keys.push(*k);
                        }
                    }
                    std::mem::swap(&mut segment, &mut previous);
                }
            }
            keys.sort_unstable();
            keys.dedup();
            (pixels, keys)
        };
        let mut pixels = 0;
        let mut needed: Vec<[i32; 3]> = Vec::new();
        // Set once the bound is passed: the rest of the frame is still counted (not
        // allocated), so the error states the frame's whole need, not the part counted
        // before the bound (which made 1 mm voxels report less memory than 2 mm ones).
        let mut over = false;
        let over_bound = |blocks: usize| TsdfError::MemoryBound {
            blocks,
            needed_bytes: blocks as u64 * BLOCK_BYTES,
            limit_bytes: o.max_memory_bytes,
        };
        for start in (0..h).step_by(ROWS_PER_MERGE) {
            let band: Vec<(usize, Vec<[i32; 3]>)> =
                (start..h.min(start + ROWS_PER_MERGE)).into_par_iter().map(row_keys).collect();
            for (p, keys) in band {
                pixels += p;
                needed.extend(keys);
            }
            needed.par_sort_unstable();
            needed.dedup();
            // The new blocks are at most all of them; count them exactly only when that
            // bound is over the limit.
            if !over && self.blocks.len() + needed.len() > limit_blocks {
                let new = needed.iter().filter(|k| !self.index.contains_key(*k)).count();
                over = self.blocks.len() + new > limit_blocks;
            }
        }
        if over {
            let new = needed.iter().filter(|k| !self.index.contains_key(*k)).count();
            return Err(over_bound(self.blocks.len() + new));
        }
        let new: Vec<[i32; 3]> =
            needed.iter().copied().filter(|k| !self.index.contains_key(k)).collect();
        for k in &new {
            self.index.insert(*k, self.blocks.len() as u32);
            self.keys.push(*k);
            self.blocks.push(vec![Voxel::default(); BLOCK_VOXELS].into_boxed_slice());
        }
        let mut touched = vec![false; self.blocks.len()];
        for k in &needed {
            touched[self.index[k] as usize] = true;
        }

        // 2. Every voxel of those blocks against the sample its centre projects onto.
        let ctx = UpdateContext {
            camera,
            r,
            t: pose.translation,
            depth,
            color: frame.color.as_ref().filter(|_| o.color),
            options: o,
        };
        let voxels_updated = self
            .blocks
            .par_iter_mut()
            .zip(self.keys.par_iter())
            .zip(touched.par_iter())
            .filter(|(_, t)| **t)
            .map(|((block, key), _)| ctx.update_block(key, block))
            .sum();
        self.frames += 1;
        Ok(IntegrationStats {
            pixels,
            blocks_touched: needed.len(),
            blocks_allocated: new.len(),
            voxels_updated,
        })
    }
}

/// The blocks of a volume as the mesh extraction reads them.
pub(crate) struct Parts<'a> {
    /// Block coordinates, one per block.
    pub keys: &'a [[i32; 3]],
    /// The voxels of each block.
    pub blocks: &'a [Box<[Voxel]>],
    /// Block coordinates → index into `blocks`.
    pub index: &'a HashMap<[i32; 3], u32>,
}

/// Block key and index within the block of voxel `g`; `None` outside the `i32` block range.
pub(crate) fn split_voxel(g: [i64; 3]) -> Option<([i32; 3], usize)> {
    let s = BLOCK_SIDE as i64;
    let mut key = [0i32; 3];
    let mut local = [0usize; 3];
    for a in 0..3 {
        key[a] = i32::try_from(g[a].div_euclid(s)).ok()?;
        local[a] = g[a].rem_euclid(s) as usize;
    }
    Some((key, local_index(local[0], local[1], local[2])))
}

/// Index of voxel `(x, y, z)` within its block (x fastest).
#[inline]
pub(crate) fn local_index(x: usize, y: usize, z: usize) -> usize {
    (z * BLOCK_SIDE + y) * BLOCK_SIDE + x
}

/// Appends the keys of the blocks (edge `block_m`) that the segment `a`–`b` passes through,
/// by a 3D digital differential analyser (Amanatides & Woo 1987): exact, every block once.
fn blocks_on_segment(a: &Vector3<f64>, b: &Vector3<f64>, block_m: f64, out: &mut Vec<[i32; 3]>) {
    let pa = a / block_m;
    let pb = b / block_m;
    let cell_of = |p: &Vector3<f64>| [floor_i64(p.x), floor_i64(p.y), floor_i64(p.z)];
    let mut cell = cell_of(&pa);
    let end = cell_of(&pb);
    let d = pb - pa;
    let mut step = [0i64; 3];
    let mut t_max = [f64::INFINITY; 3];
    let mut t_delta = [f64::INFINITY; 3];
    for i in 0..3 {
        if d[i] > 0.0 {
            step[i] = 1;
            t_max[i] = ((cell[i] + 1) as f64 - pa[i]) / d[i];
            t_delta[i] = 1.0 / d[i];
        } else if d[i] < 0.0 {
            step[i] = -1;
            t_max[i] = (cell[i] as f64 - pa[i]) / d[i];
            t_delta[i] = -1.0 / d[i];
        }
    }
    // The segment crosses at most this many cell faces; the bound also stops the walk if
    // rounding makes it miss `end`.
    let max_steps: i64 = (0..3).map(|i| (end[i] - cell[i]).abs()).sum::<i64>() + 3;
    for _ in 0..=max_steps {
        if let (Ok(x), Ok(y), Ok(z)) =
            (i32::try_from(cell[0]), i32::try_from(cell[1]), i32::try_from(cell[2]))
        {
            out.push([x, y, z]);
        }
        if cell == end {
            break;
        }
        let axis = if t_max[0] <= t_max[1] && t_max[0] <= t_max[2] {
            0
        } else if t_max[1] <= t_max[2] {
            1
        } else {
            2
        };
        if t_max[axis] > 1.0 {
            break;
        }
        cell[axis] += step[axis];
        t_max[axis] += t_delta[axis];
    }
}

/// `x.floor() as i64` without the call to libm's `floor` (the x86-64 baseline has no SSE4.1
/// rounding instruction, and the band walk floors six coordinates per pixel): the cast
/// truncates towards zero (saturating), one less for a negative non-integer.
#[inline]
fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x { t - 1 } else { t }
}

/// What the per-block update reads.
struct UpdateContext<'a> {
    camera: &'a CameraModel,
    r: Matrix3<f64>,
    t: Vector3<f64>,
    depth: &'a [f32],
    color: Option<&'a RegisteredColor<'a>>,
    options: TsdfOptions,
}

impl UpdateContext<'_> {
    /// Updates the voxels of one block; returns how many were updated.
    ///
    /// Eight voxels at a time, a row of the block along x (`wide::f32x8`): position, projection
    /// (a plain pinhole when the camera has no distortion, Open3D's comparison frames; the
    /// Brown–Conrady polynomial otherwise), the along-ray factor, the signed distance, the
    /// band test and the weighted mean are vector operations; the depth lookup
    /// ([`sample_depth`]) and the colour are per voxel. `f32` throughout: a voxel's
    /// camera-frame position is within ~0.5 µm at 5 m, a thousandth of the depth's millimetre
    /// steps; the block's origin is computed in `f64` and its voxels stepped from it, so the
    /// error does not grow with the distance from the volume's origin.
    fn update_block(&self, key: &[i32; 3], block: &mut [Voxel]) -> usize {
        let o = &self.options;
        let v = o.voxel_size_m;
        let mu = o.truncation_m as f32;
        let inv_mu = 1.0 / mu;
        let (w, h) = (self.camera.width, self.camera.height);
        let (min_z, max_z) = (o.min_depth_m as f32, o.max_depth_m as f32);
        let k = &self.camera.intrinsics;
        let s = f32x8::splat;
        let (fx, fy, cx, cy, skew) =
            (s(k.fx as f32), s(k.fy as f32), s(k.cx as f32), s(k.cy as f32), s(k.skew as f32));
        let d = self.camera.distortion;
        let pinhole = d == geometry::Distortion::NONE;
        let (k1, k2, k3, p1, p2) =
            (s(d.k1 as f32), s(d.k2 as f32), s(d.k3 as f32), s(d.p1 as f32), s(d.p2 as f32));
        let (zero, one, two) = (s(0.0), s(1.0), s(2.0));
        let mut updated = 0;
        // Voxel centres in the camera frame, stepped from the block's first voxel: the
        // rotation's columns times the voxel size are the steps along x, y and z.
        let side = BLOCK_SIDE as f64;
        let first = Vector3::new(
            (key[0] as f64 * side + 0.5) * v,
            (key[1] as f64 * side + 0.5) * v,
            (key[2] as f64 * side + 0.5) * v,
        );
        let origin = (self.r * first + self.t).cast::<f32>();
        let sx = (self.r.column(0) * v).into_owned().cast::<f32>();
        let sy = (self.r.column(1) * v).into_owned().cast::<f32>();
        let sz = (self.r.column(2) * v).into_owned().cast::<f32>();
        let lane = f32x8::from([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]);
        let (rx, ry, rz) = (lane * sx.x, lane * sx.y, lane * sx.z);
        for z in 0..BLOCK_SIDE {
            for y in 0..BLOCK_SIDE {
                let row = origin + sz * z as f32 + sy * y as f32;
                let (px, py, pz) = (s(row.x) + rx, s(row.y) + ry, s(row.z) + rz);
                let front = pz.simd_gt(zero).to_bitmask();
                if front == 0 {
                    continue;
                }
                let inv_z = one / pz;
                let (nx, ny) = (px * inv_z, py * inv_z);
                let r2 = nx * nx + ny * ny;
                let (xd, yd) = if pinhole {
                    (nx, ny)
                } else {
                    let radial = one + r2 * (k1 + r2 * (k2 + r2 * k3));
                    let xy = nx * ny;
                    (
                        nx * radial + two * p1 * xy + p2 * (r2 + two * nx * nx),
                        ny * radial + p1 * (r2 + two * ny * ny) + two * p2 * xy,
                    )
                };
                let (u, vv) = (fx * xd + skew * yd + cx, fy * yd + cy);
                let Some((zmv, pixel)) =
                    sample_depth8(self.depth, w, h, pz.simd_gt(zero), u, vv, min_z, max_z)
                else {
                    continue;
                };
                let sdf = (zmv - pz) * (one + r2).sqrt();
                // NaN (no sample) compares false: those voxels are not updated.
                let band = sdf.abs().simd_le(s(mu)).to_bitmask();
                if band == 0 {
                    continue;
                }
                // depth_weight(zm) = 1 / zm⁴.
                let z2 = zmv * zmv;
                let weight = one / (z2 * z2);
                let base = local_index(0, y, z);
                let voxels = &mut block[base..base + BLOCK_SIDE];
                let (mut t_old, mut w_old) = ([0.0f32; BLOCK_SIDE], [0.0f32; BLOCK_SIDE]);
                for (l, vox) in voxels.iter().enumerate() {
                    t_old[l] = vox.tsdf;
                    w_old[l] = vox.weight;
                }
                let (t_old, w_old) = (f32x8::from(t_old), f32x8::from(w_old));
                let wsum = w_old + weight;
                let t_new = ((t_old * w_old + sdf * s(inv_mu) * weight) / wsum).to_array();
                let (wsum, weight) = (wsum.to_array(), weight.to_array());
                for (l, vox) in voxels.iter_mut().enumerate() {
                    if band >> l & 1 == 0 {
                        continue;
                    }
                    vox.tsdf = t_new[l];
                    vox.weight = wsum[l];
                    if let Some(c) = self.color
                        && c.valid.data()[pixel[l]]
                    {
                        let rgb = c.rgb.data()[pixel[l]];
                        let cw = vox.color_weight + weight[l];
                        for (k, channel) in vox.color.iter_mut().enumerate() {
                            *channel =
                                (*channel * vox.color_weight + rgb[k] as f32 * weight[l]) / cw;
                        }
                        vox.color_weight = cw;
                    }
                }
                updated += band.count_ones() as usize;
            }
        }
        updated
    }
}

/// [`sample_depth`] of eight image positions `(u, v)` where `front` (the voxels in front of
/// the camera): the image test and the interpolation are vector operations, the five reads per
/// position (the nearest pixel and the four around it) scalar. Returns the depths (NaN: no
/// sample, outside the image or behind the camera) and the nearest pixels' indices; `None`
/// when no position is inside the image.
#[allow(clippy::too_many_arguments)]
#[inline]
fn sample_depth8(
    depth: &[f32],
    w: usize,
    h: usize,
    front: f32x8,
    u: f32x8,
    vv: f32x8,
    min_z: f32,
    max_z: f32,
) -> Option<(f32x8, [usize; BLOCK_SIDE])> {
    let s = f32x8::splat;
    let zero = s(0.0);
    let inside = (front
        & u.simd_ge(zero)
        & vv.simd_ge(zero)
        & u.simd_le(s((w - 1) as f32))
        & vv.simd_le(s((h - 1) as f32)))
    .to_bitmask();
    if inside == 0 {
        return None;
    }
    let (ua, va) = (u.to_array(), vv.to_array());
    let nan = [f32::NAN; BLOCK_SIDE];
    let (mut zn, mut q0, mut q1, mut q2, mut q3) = (nan, nan, nan, nan, nan);
    let (mut fu, mut fv) = ([0.0f32; BLOCK_SIDE], [0.0f32; BLOCK_SIDE]);
    let mut pixel = [0usize; BLOCK_SIDE];
    for l in 0..BLOCK_SIDE {
        if inside >> l & 1 == 0 {
            continue;
        }
        // u, v ≥ 0 here: the casts are floors.
        pixel[l] = (va[l] + 0.5) as usize * w + (ua[l] + 0.5) as usize;
        zn[l] = depth[pixel[l]];
        // The pixel up and left of the position (the last but one on the far
        // edges).
        let (u0, v0) = ((ua[l] as usize).min(w - 2), (va[l] as usize).min(h - 2));
        let i = v0 * w + u0;
        q0[l] = depth[i];
        q1[l] = depth[i + 1];
        q2[l] = depth[i + w];
        q3[l] = depth[i + w + 1];
        fu[l] = ua[l] - u0 as f32;
        fv[l] = va[l] - v0 as f32;
    }
    let ok = |z: f32x8| z.simd_ge(s(min_z)) & z.simd_le(s(max_z));
    let zn = f32x8::from(zn);
    let (q0, q1, q2, q3) = (f32x8::from(q0), f32x8::from(q1), f32x8::from(q2), f32x8::from(q3));
    let lo = q0.min(q1).min(q2.min(q3));
    let hi = q0.max(q1).max(q2.max(q3));
    let smooth = ok(q0)
        & ok(q1)
        & ok(q2)
        & ok(q3)
        & (hi - lo).simd_le(s(INTERPOLATION_MAX_STEP as f32) * zn);
    let (fu, fv) = (f32x8::from(fu), f32x8::from(fv));
    let top = q0 + (q1 - q0) * fu;
    let bottom = q2 + (q3 - q2) * fu;
    let bilinear = top + (bottom - top) * fv;
    // No sample at the nearest pixel: NaN, which fails the band test below.
    let zmv = ok(zn).bitselect(smooth.bitselect(bilinear, zn), s(f32::NAN));
    Some((zmv, pixel))
}

/// The measured z at image position `(u, v)` and the nearest pixel's index: bilinear between
/// the four pixels around it where all four have a sample and they differ by at most
/// [`INTERPOLATION_MAX_STEP`] of the depth, the nearest pixel's sample otherwise (pixel
/// centres at integers, the nearest is `floor(u + ½)`). `None` without a sample within the
/// depth range, and outside `0 ≤ u ≤ width − 1`, `0 ≤ v ≤ height − 1`: in the outer half
/// pixel of the image no four pixels surround the position, and the nearest pixel's depth
/// there errs by half a pixel's depth step (4 mm on a 40° plane at 4 m).
#[cfg(test)]
fn sample_depth(
    depth: &[f32],
    w: usize,
    h: usize,
    u: f32,
    v: f32,
    min: f32,
    max: f32,
) -> Option<(f32, usize)> {
    if w < 2 || h < 2 || !(u >= 0.0 && v >= 0.0 && u <= (w - 1) as f32 && v <= (h - 1) as f32) {
        return None;
    }
    // u, v ≥ 0 here: the casts are floors.
    let nearest = (v + 0.5) as usize * w + (u + 0.5) as usize;
    let zn = depth[nearest];
    let ok = |z: f32| z >= min && z <= max;
    if !ok(zn) {
        return None;
    }
    // The pixel up and left of the position (the last but one on the far edges).
    let (u0, v0) = ((u as usize).min(w - 2), (v as usize).min(h - 2));
    let i = v0 * w + u0;
    let q = [depth[i], depth[i + 1], depth[i + w], depth[i + w + 1]];
    if q.iter().all(|&z| ok(z)) {
        let lo = q[0].min(q[1]).min(q[2].min(q[3]));
        let hi = q[0].max(q[1]).max(q[2].max(q[3]));
        if hi - lo <= INTERPOLATION_MAX_STEP as f32 * zn {
            let (fu, fv) = (u - u0 as f32, v - v0 as f32);
            let top = q[0] + (q[1] - q[0]) * fu;
            let bottom = q[2] + (q[3] - q[2]) * fu;
            return Some((top + (bottom - top) * fv, nearest));
        }
    }
    Some((zn, nearest))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segment_walk_visits_every_block_once_in_order() {
        let mut out = Vec::new();
        let a = Vector3::new(0.01, 0.01, 0.01);
        let b = Vector3::new(0.13, 0.05, -0.03);
        blocks_on_segment(&a, &b, 0.04, &mut out);
        assert_eq!(out.first(), Some(&[0, 0, 0]));
        assert_eq!(out.last(), Some(&[3, 1, -1]));
        // Face-adjacent steps only, no repeats.
        for p in out.windows(2) {
            let d: i32 = (0..3).map(|i| (p[1][i] - p[0][i]).abs()).sum();
            assert_eq!(d, 1, "{out:?}");
        }
        // Dense sampling of the segment finds no block the walk missed.
        for s in 0..=10_000 {
            let p = a + (b - a) * (s as f64 / 10_000.0);
            let k = [
                (p.x / 0.04).floor() as i32,
                (p.y / 0.04).floor() as i32,
                (p.z / 0.04).floor() as i32,
            ];
            assert!(out.contains(&k), "{k:?} missing");
        }
    }

    /// The eight-lane sampling of the voxel loop equals the scalar reference, at positions
    /// on and off the image, between samples, across depth edges and holes.
    #[test]
    fn sample_depth8_matches_the_scalar_reference() {
        let (w, h) = (23usize, 17usize);
        // Smooth ramps, a 20 % step at x = 11, holes (NaN and 0) and out-of-range depth.
        let depth: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                match (x * 7 + y * 3) % 29 {
                    0 => f32::NAN,
                    1 => 0.0,
                    2 => 9.0,
                    _ => 1.5 + 0.004 * x as f32 + 0.003 * y as f32 + if x > 11 { 0.3 } else { 0.0 },
                }
            })
            .collect();
        let (min, max) = (0.5, 4.5);
        let mut state = 12345u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let mut compared = 0;
        for round in 0..2000 {
            let mut u = [0.0f32; BLOCK_SIDE];
            let mut v = [0.0f32; BLOCK_SIDE];
            let mut f = [0.0f32; BLOCK_SIDE];
            for l in 0..BLOCK_SIDE {
                u[l] = next() * (w as f32 + 2.0) - 1.0;
                v[l] = next() * (h as f32 + 2.0) - 1.0;
                // Every 7th lane behind the camera; every 50th round on exact pixel centres.
                f[l] = if (round + l) % 7 == 0 { 0.0 } else { f32::from_bits(u32::MAX) };
                if round % 50 == 0 {
                    u[l] = u[l].round();
                    v[l] = v[l].round();
                }
            }
            let front = f32x8::from(f);
            let got = sample_depth8(&depth, w, h, front, f32x8::from(u), f32x8::from(v), min, max);
            let front_bits = front.to_bitmask();
            for l in 0..BLOCK_SIDE {
                let want = if front_bits >> l & 1 == 1 {
                    sample_depth(&depth, w, h, u[l], v[l], min, max)
                } else {
                    None
                };
                let have = got.and_then(|(z, p)| {
                    let z = z.to_array()[l];
                    z.is_finite().then_some((z, p[l]))
                });
                assert_eq!(have, want, "u {} v {} front {}", u[l], v[l], front_bits >> l & 1);
                compared += usize::from(want.is_some());
            }
        }
        assert!(compared > 5000, "{compared}");
    }

    #[test]
    fn floor_i64_is_floor() {
        for x in [0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 2.999, -2.999, 1e12 + 0.5, -1e12 - 0.5, 7.0] {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
    }

    #[test]
    fn weight_is_inverse_variance() {
        assert!((depth_weight(1.0) - 1.0).abs() < 1e-12);
        assert!((depth_weight(2.0) - 1.0 / 16.0).abs() < 1e-12);
        assert!((depth_sigma_m(2.0) - 0.006).abs() < 1e-9);
    }

    #[test]
    fn voxel_split_round_trips() {
        for g in [[0i64, 0, 0], [-1, 7, 8], [-9, -8, 15]] {
            let (key, local) = split_voxel(g).unwrap();
            let back: Vec<i64> = (0..3)
                .map(|a| {
                    let l = [local % 8, (local / 8) % 8, local / 64][a] as i64;
                    key[a] as i64 * 8 + l
                })
                .collect();
            assert_eq!(back, g.to_vec());
        }
    }
}
