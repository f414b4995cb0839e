//! H8: disocclusion hole mask and hole filling from a robust plane fit.

use nalgebra::{Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::{CameraModel, Image};

/// H8's hole mask with reusable buffers (one per image size and radii).
///
/// The mask is computed on bit rows (64 pixels per word), without scanning a disc per pixel:
///
/// 1. `occupied` = the z-buffer's non-empty pixels;
/// 2. `covered` = `occupied` dilated by a Euclidean disc of radius `radius`: each row is
///    dilated horizontally by `0, 1, …, floor(radius)` pixels (shift-or), and
///    `covered(y) = OR over dy of dilate_h(occupied(y + dy), floor(sqrt(radius² - dy²)))`;
/// 3. `core` = pixels not covered but *inside the samples' footprint*: some covered pixel
///    lies to their left and to their right in their row, and above and below them in their
///    column;
/// 4. **holes** = `core` dilated by a disc of radius `grow` (same method), minus `occupied`.
///
/// Step 2 closes the gaps of the sample lattice but also shrinks a real hole by `radius` on
/// every side; step 4 gives that back. A hole's true edge lies about half a sample spacing
/// `s` beyond its last sample, so `grow = radius - s/2` restores it ([`run`] does this).
///
/// [`run`]: super::run
#[derive(Debug, Clone)]
pub struct HoleMasker {
    width: usize,
    height: usize,
    words: usize,
    radius: f32,
    grow: f32,
    levels: Vec<u64>,
    occupied: Vec<u64>,
    covered: Vec<u64>,
    core: Vec<u64>,
    holes: Vec<u64>,
    below: Vec<u64>,
    above: Vec<u64>,
}

/// `floor(sqrt(r² - dy²))` for `dy = 0..=floor(r)`.
fn half_widths(r: f32) -> Vec<usize> {
    let r = r.max(0.0);
    (0..=r.floor() as usize).map(|dy| (r * r - (dy * dy) as f32).max(0.0).sqrt().floor() as usize).collect()
}

/// `out = src` dilated by a Euclidean disc of radius `r` (bit rows of `words` words).
fn dilate_disc(src: &[u64], out: &mut [u64], levels: &mut Vec<u64>, width: usize, height: usize, words: usize, r: f32) {
    let hw = half_widths(r);
    let nlevels = hw[0] + 1;
    let plane = height * words;
    let tail_mask = if width % 64 == 0 { u64::MAX } else { (1u64 << (width % 64)) - 1 };
    levels.resize(nlevels * plane, 0);
    levels[..plane].copy_from_slice(src);
    for level in 1..nlevels {
        let (prev, next) = levels.split_at_mut(level * plane);
        let prev = &prev[(level - 1) * plane..];
        let next = &mut next[..plane];
        for y in 0..height {
            let p = &prev[y * words..(y + 1) * words];
            let n = &mut next[y * words..(y + 1) * words];
            for i in 0..words {
                let left_carry = if i > 0 { p[i - 1] >> 63 } else { 0 };
                let right_carry = if i + 1 < words { p[i + 1] << 63 } else { 0 };
                n[i] = p[i] | (p[i] << 1) | left_carry | (p[i] >> 1) | right_carry;
            }
            n[words - 1] &= tail_mask;
        }
    }
    let k = hw.len() as isize - 1;
    for y in 0..height {
        let c = &mut out[y * words..(y + 1) * words];
        c.fill(0);
        for dy in -k..=k {
            let sy = y as isize + dy;
            if sy < 0 || sy >= height as isize {
                continue;
            }
            let src = &levels[hw[dy.unsigned_abs()] * plane + sy as usize * words..][..words];
            for i in 0..words {
                c[i] |= src[i];
            }
        }
    }
}

impl HoleMasker {
    /// Buffers for a `width × height` z-buffer, a coverage radius and a growth radius in
    /// pixels (see the type's docs).
    pub fn new(width: usize, height: usize, radius_px: f32, grow_px: f32) -> Self {
        let words = width.div_ceil(64);
        let plane = height * words;
        Self {
            width,
            height,
            words,
            radius: radius_px.max(0.0),
            grow: grow_px.max(0.0),
            levels: Vec::with_capacity((radius_px.max(grow_px).max(0.0) as usize + 1) * plane),
            occupied: vec![0; plane],
            covered: vec![0; plane],
            core: vec![0; plane],
            holes: vec![0; plane],
            below: vec![0; plane],
            above: vec![0; words],
        }
    }

    /// The coverage radius in pixels.
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// Computes the hole mask of `zbuffer` (row-major, `NaN` = empty) into `mask`; returns the
    /// number of hole pixels. Both slices must be `width × height`.
    pub fn compute(&mut self, zbuffer: &[f32], mask: &mut [bool]) -> usize {
        let (w, h, words) = (self.width, self.height, self.words);
        // 1. occupancy.
        for y in 0..h {
            let row = &zbuffer[y * w..(y + 1) * w];
            let out = &mut self.occupied[y * words..(y + 1) * words];
            for (wi, chunk) in row.chunks(64).enumerate() {
                let mut bits = 0u64;
                for (b, &z) in chunk.iter().enumerate() {
                    bits |= ((z == z) as u64) << b;
                }
                out[wi] = bits;
            }
        }
        // 2. covered.
        dilate_disc(&self.occupied, &mut self.covered, &mut self.levels, w, h, words, self.radius);
        // 3. core: not covered, between covered pixels in the row and in the column.
        for i in 0..words {
            self.below[(h - 1) * words + i] = 0;
        }
        for y in (0..h.saturating_sub(1)).rev() {
            for i in 0..words {
                self.below[y * words + i] = self.below[(y + 1) * words + i] | self.covered[(y + 1) * words + i];
            }
        }
        self.above.fill(0);
        for y in 0..h {
            let c = &self.covered[y * words..(y + 1) * words];
            let core = &mut self.core[y * words..(y + 1) * words];
            core.fill(0);
            let first = c.iter().position(|&b| b != 0).map(|i| i * 64 + c[i].trailing_zeros() as usize);
            let last = c.iter().rposition(|&b| b != 0).map(|i| i * 64 + 63 - c[i].leading_zeros() as usize);
            if let (Some(first), Some(last)) = (first, last) {
                for i in 0..words {
                    // Bits strictly between `first` and `last`.
                    let lo = i * 64;
                    let span = if last <= lo || first >= lo + 63 {
                        0
                    } else {
                        let from = (first + 1).max(lo) - lo;
                        let to = (last.min(lo + 64)) - lo; // exclusive
                        if to <= from { 0 } else { (u64::MAX >> (64 - (to - from))) << from }
                    };
                    core[i] = !c[i] & span & self.above[i] & self.below[y * words + i];
                }
            }
            for i in 0..words {
                self.above[i] |= c[i];
            }
        }
        // 4. grow back, minus occupied pixels.
        dilate_disc(&self.core, &mut self.holes, &mut self.levels, w, h, words, self.grow);
        let mut count = 0;
        for y in 0..h {
            let out = &mut mask[y * w..(y + 1) * w];
            for (x, m) in out.iter_mut().enumerate() {
                let (i, b) = (y * words + x / 64, x % 64);
                let hole = (self.holes[i] & !self.occupied[i]) >> b & 1 == 1;
                *m = hole;
                count += hole as usize;
            }
        }
        count
    }
}

/// H8 mask with fresh buffers (see [`HoleMasker`]).
pub fn hole_mask(zbuffer: &Image<f32>, radius_px: f32, grow_px: f32) -> Image<bool> {
    let (w, h) = zbuffer.size();
    let mut mask = Image::filled(w, h, false);
    HoleMasker::new(w, h, radius_px, grow_px).compute(zbuffer.data(), mask.data_mut());
    mask
}

/// A plane `n · X = d` in the colour camera's frame (`n` unit length, `d > 0` for a plane in
/// front of the camera), with its RANSAC support.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PlaneFit {
    /// Unit normal.
    pub normal: [f64; 3],
    /// Offset, metres.
    pub offset: f64,
    /// Samples within the threshold of the refined plane.
    pub inliers: usize,
    /// Samples tried.
    pub samples: usize,
    /// RMS distance of the inliers to the plane, metres.
    pub rms_m: f64,
}

/// Options of [`fit_plane_ransac`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PlaneFitOptions {
    /// RANSAC hypotheses.
    pub iterations: usize,
    /// Point-to-plane distance of an inlier, metres.
    pub threshold_m: f64,
    /// Most samples used (drawn at random without bias from the valid pixels).
    pub max_samples: usize,
    /// Seed of the generator.
    pub seed: u64,
}

impl Default for PlaneFitOptions {
    fn default() -> Self {
        Self {
            // 200 hypotheses find a plane holding >= 30 % of the samples with probability
            // 1 - (1 - 0.3³)^200 > 0.996.
            iterations: 200,
            // 1 cm: above nearest-fill steps on tilted surfaces (~1 mm/px at 3 m), below
            // the size of the objects standing in front of a background.
            threshold_m: 0.01,
            // 20 000 samples pin a plane to ~1e-4 relative; more only costs time.
            max_samples: 20_000,
            seed: 0x6b66_7573_65,
        }
    }
}

/// Least-squares plane through `points` (centroid + smallest-eigenvalue normal).
fn refine_plane(points: &[Vector3<f64>]) -> Option<(Vector3<f64>, f64)> {
    if points.len() < 3 {
        return None;
    }
    let c = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
    let mut cov = Matrix3::zeros();
    for p in points {
        let d = p - c;
        cov += d * d.transpose();
    }
    let eig = cov.symmetric_eigen();
    let (i, _) = eig.eigenvalues.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1))?;
    let mut n: Vector3<f64> = eig.eigenvectors.column(i).into();
    let mut d = n.dot(&c);
    if d < 0.0 {
        n = -n;
        d = -d;
    }
    Some((n, d))
}

/// Robust plane fit (RANSAC + least-squares refinement) to the 3D points of the valid pixels
/// of `depth` (colour-frame `z`), back-projected through `camera` (distortion undone).
/// Deterministic for a given seed. `None` when fewer than 3 valid pixels or no plane.
pub fn fit_plane_ransac(depth: &Image<f32>, camera: &CameraModel, options: &PlaneFitOptions) -> Option<PlaneFit> {
    let (w, _) = depth.size();
    let valid: Vec<usize> = depth.data().iter().enumerate().filter(|(_, z)| **z > 0.0 && z.is_finite()).map(|(i, _)| i).collect();
    if valid.len() < 3 {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let n = options.max_samples.min(valid.len()).max(3);
    let fold = camera.distortion.fold_radius();
    let points: Vec<Vector3<f64>> = (0..n)
        .filter_map(|k| {
            let i = if n == valid.len() { valid[k] } else { valid[rng.random_range(0..valid.len())] };
            let (x, y) = (i % w, i / w);
            let d = camera.intrinsics.from_pixel(x as f64, y as f64);
            let r = camera.distortion.undistort_within(d.x, d.y, fold)?;
            let z = *depth.get(x, y) as f64;
            Some(Vector3::new(r.x * z, r.y * z, z))
        })
        .collect();
    if points.len() < 3 {
        return None;
    }
    let mut best: Option<(usize, Vector3<f64>, f64)> = None;
    for _ in 0..options.iterations {
        let a = points[rng.random_range(0..points.len())];
        let b = points[rng.random_range(0..points.len())];
        let c = points[rng.random_range(0..points.len())];
        let nrm = (b - a).cross(&(c - a));
        let len = nrm.norm();
        if !(len > 1e-12) {
            continue;
        }
        let nrm = nrm / len;
        let d = nrm.dot(&a);
        let count = points.iter().filter(|p| (nrm.dot(p) - d).abs() < options.threshold_m).count();
        if best.is_none_or(|(bc, _, _)| count > bc) {
            best = Some((count, nrm, d));
        }
    }
    let (_, nrm, d) = best?;
    let inliers: Vec<Vector3<f64>> = points.iter().copied().filter(|p| (nrm.dot(p) - d).abs() < options.threshold_m).collect();
    let (nrm, d) = refine_plane(&inliers)?;
    let final_inliers: Vec<f64> =
        points.iter().map(|p| nrm.dot(p) - d).filter(|r| r.abs() < options.threshold_m).collect();
    let rms = (final_inliers.iter().map(|r| r * r).sum::<f64>() / final_inliers.len().max(1) as f64).sqrt();
    Some(PlaneFit { normal: [nrm.x, nrm.y, nrm.z], offset: d, inliers: final_inliers.len(), samples: points.len(), rms_m: rms })
}

/// Depth `z` of a plane along the undistorted ray `(x, y, 1)`, in `f32` like the GPU:
/// `den = n0*x + n1*y + n2; z = d / den`, `None` unless `z > 0` and finite.
#[inline]
pub fn plane_depth_pixel(normal: [f32; 3], offset: f32, ray: [f32; 2]) -> Option<f32> {
    let den = normal[0] * ray[0] + normal[1] * ray[1] + normal[2];
    let z = offset / den;
    (z > 0.0 && z < f32::INFINITY).then_some(z)
}

/// H8 fill: a copy of `depth` whose `mask` pixels take the plane's depth along their
/// undistorted ray through `camera` ([`plane_depth_pixel`]). Returns the image and the
/// number of pixels filled.
pub fn fill_holes_with_plane(
    depth: &Image<f32>,
    mask: &Image<bool>,
    camera: &CameraModel,
    plane: &PlaneFit,
) -> (Image<f32>, usize) {
    let mut out = depth.clone();
    let (w, _) = depth.size();
    let n = plane.normal.map(|c| c as f32);
    let fold = camera.distortion.fold_radius();
    let mut filled = 0;
    for (i, _) in mask.data().iter().enumerate().filter(|(_, m)| **m) {
        let d = camera.intrinsics.from_pixel((i % w) as f64, (i / w) as f64);
        let Some(r) = camera.distortion.undistort_within(d.x, d.y, fold) else { continue };
        if let Some(z) = plane_depth_pixel(n, plane.offset as f32, [r.x as f32, r.y as f32]) {
            out.data_mut()[i] = z;
            filled += 1;
        }
    }
    (out, filled)
}
