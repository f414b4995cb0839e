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
/// Both dilations stream: the horizontally dilated rows live in a ring of `2·floor(r) + 1`
/// rows (a few kB), so one pass top-down (step 2, noting for every row what lies above it)
/// and one bottom-up (steps 3 and 4, the core rows fed to the second dilation as they are
/// made) touch nothing bigger than the bit planes and the output.
///
/// [`run`]: super::run
#[derive(Debug, Clone)]
pub struct HoleMasker {
    width: usize,
    height: usize,
    words: usize,
    radius: f32,
    grow: f32,
    radius_widths: Vec<usize>,
    grow_widths: Vec<usize>,
    ring: Vec<u64>,
    row: Vec<u64>,
    occupied: Vec<u64>,
    covered: Vec<u64>,
    /// Row `y`: OR of the covered rows above `y`.
    above: Vec<u64>,
    /// OR of the covered rows below the row being made (bottom-up pass).
    below: Vec<u64>,
    holes: Vec<u64>,
}

/// `floor(sqrt(r² - dy²))` for `dy = 0..=floor(r)`.
fn half_widths(r: f32) -> Vec<usize> {
    let r = r.max(0.0);
    (0..=r.floor() as usize)
        .map(|dy| (r * r - (dy * dy) as f32).max(0.0).sqrt().floor() as usize)
        .collect()
}

/// `dst` = `src` dilated horizontally by one pixel. Both rows carry one zero word on each
/// side (`words + 2` words), so the carries between words need no branch and the loop
/// vectorises; bits beyond the width are cleared with `tail_mask`.
#[inline]
fn dilate_row_once(src: &[u64], dst: &mut [u64], tail_mask: u64) {
    let n = src.len() - 2;
    let (l, m, r) = (&src[..n], &src[1..n + 1], &src[2..n + 2]);
    let d = &mut dst[1..n + 1];
    for i in 0..n {
        d[i] = m[i] | (m[i] << 1) | (l[i] >> 63) | (m[i] >> 1) | (r[i] << 63);
    }
    d[n - 1] &= tail_mask;
}

/// Streaming disc dilation (see [`HoleMasker`]): `source(y, row)` writes source row `y`
/// (called once per row, in order: top-down, or bottom-up when `reverse`), and
/// `emit(y, row)` receives dilated row `y` (in the same order, `floor(r)` rows behind).
/// `hw` = [`half_widths`] of the radius.
#[allow(clippy::too_many_arguments)]
fn dilate_stream(
    height: usize,
    words: usize,
    width: usize,
    hw: &[usize],
    ring: &mut Vec<u64>,
    out: &mut Vec<u64>,
    reverse: bool,
    mut source: impl FnMut(usize, &mut [u64]),
    mut emit: impl FnMut(usize, &[u64]),
) {
    let k = hw.len() - 1;
    let levels = hw[0] + 1;
    let slots = 2 * k + 1;
    let padded = words + 2;
    let stride = levels * padded;
    let tail_mask = if width.is_multiple_of(64) { u64::MAX } else { (1u64 << (width % 64)) - 1 };
    // Every row's pad words are zero and are never written.
    ring.clear();
    ring.resize(slots * stride, 0);
    out.resize(words, 0);
    let row_at = |step: usize| if reverse { height - 1 - step } else { step };
    for step in 0..height + k {
        if step < height {
            let s = row_at(step);
            let slot = &mut ring[(s % slots) * stride..][..stride];
            source(s, &mut slot[1..words + 1]);
            for level in 1..levels {
                let (prev, next) = slot.split_at_mut(level * padded);
                dilate_row_once(&prev[(level - 1) * padded..], &mut next[..padded], tail_mask);
            }
        }
        if step >= k {
            let y = row_at(step - k);
            out.fill(0);
            for sy in y.saturating_sub(k)..=(y + k).min(height - 1) {
                let level = hw[sy.abs_diff(y)];
                let src = &ring[(sy % slots) * stride + level * padded + 1..][..words];
                for (o, s) in out.iter_mut().zip(src) {
                    *o |= s;
                }
            }
            emit(y, out);
        }
    }
}

/// Writes one bit row (bit `x % 64` of word `x / 64`) into `out` as `bool`s; returns the
/// number of bits set. Compiled for x86-64's baseline and for AVX2, picked at run time by the
/// CPU (`multiversion`): AVX2's per-lane shifts vectorise `bits >> b`, which SSE2 cannot
/// (it shifts every lane by the same amount). Integer operations: the same result on both.
#[multiversion::multiversion(targets("x86_64+avx2"))]
pub(crate) fn unpack_bits_row(bits: &[u64], out: &mut [bool]) -> usize {
    let mut count = 0;
    for (chunk, &bits) in out.chunks_mut(64).zip(bits) {
        if bits == 0 {
            chunk.fill(false);
            continue;
        }
        count += bits.count_ones() as usize;
        for (b, m) in chunk.iter_mut().enumerate() {
            *m = bits >> b & 1 == 1;
        }
    }
    count
}

/// Bits of word `i` (pixels `64 i .. 64 i + 63`) strictly between pixels `first` and `last`.
#[inline]
fn span_bits(i: usize, first: usize, last: usize) -> u64 {
    let lo = i * 64;
    if last <= lo || first >= lo + 63 {
        return 0;
    }
    let from = (first + 1).max(lo) - lo;
    let to = last.min(lo + 64) - lo; // exclusive
    if to <= from { 0 } else { (u64::MAX >> (64 - (to - from))) << from }
}

impl HoleMasker {
    /// Buffers for a `width × height` z-buffer, a coverage radius and a growth radius in
    /// pixels (see the type's docs).
    pub fn new(width: usize, height: usize, radius_px: f32, grow_px: f32) -> Self {
        let words = width.div_ceil(64).max(1);
        let plane = height * words;
        let (radius, grow) = (radius_px.max(0.0), grow_px.max(0.0));
        Self {
            width,
            height,
            words,
            radius,
            grow,
            radius_widths: half_widths(radius),
            grow_widths: half_widths(grow),
            ring: Vec::new(),
            row: vec![0; words],
            occupied: vec![0; plane],
            covered: vec![0; plane],
            above: vec![0; plane],
            below: vec![0; words],
            holes: vec![0; plane],
        }
    }

    /// The coverage radius in pixels.
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// The growth radius in pixels.
    pub fn grow(&self) -> f32 {
        self.grow
    }

    /// 64-bit words per bit row.
    pub fn words_per_row(&self) -> usize {
        self.words
    }

    /// The occupancy bit image [`HoleMasker::compute_from_occupancy`] reads (bit `x % 64` of
    /// word `y * words_per_row + x / 64`), e.g. for [`super::Registration::register`].
    pub fn occupancy_mut(&mut self) -> &mut [u64] {
        &mut self.occupied
    }

    /// The hole mask of the last computation as bits (bit `x % 64` of word
    /// `y * words_per_row + x / 64`; bits beyond the width are clear).
    pub fn hole_bits(&self) -> &[u64] {
        &self.holes
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
                    bits |= (!z.is_nan() as u64) << b;
                }
                out[wi] = bits;
            }
        }
        self.compute_from_occupancy(mask)
    }

    /// Steps 2–4 on the occupancy already in [`HoleMasker::occupancy_mut`], into `mask`
    /// (`width × height`, row-major); returns the number of hole pixels.
    pub fn compute_from_occupancy(&mut self, mask: &mut [bool]) -> usize {
        let w = self.width;
        let mut count = 0;
        self.compute_bits(|y, bits| count += unpack_bits_row(bits, &mut mask[y * w..(y + 1) * w]));
        count
    }

    /// Steps 2–4 on the occupancy already in [`HoleMasker::occupancy_mut`], into
    /// [`HoleMasker::hole_bits`] only (no `bool` image); returns the number of hole pixels.
    pub fn compute_bits_from_occupancy(&mut self) -> usize {
        let mut count = 0;
        self.compute_bits(|_, bits| {
            count += bits.iter().map(|b| b.count_ones() as usize).sum::<usize>()
        });
        count
    }

    /// Steps 2–4; `row(y, bits)` receives every hole row (bottom-up) as it is made.
    fn compute_bits(&mut self, mut row: impl FnMut(usize, &[u64])) {
        let (w, h, words) = (self.width, self.height, self.words);
        if h == 0 || w == 0 {
            return;
        }
        let Self {
            radius_widths,
            grow_widths,
            ring,
            row: out,
            occupied,
            covered,
            above,
            below,
            holes,
            ..
        } = self;
        // 2. covered, top-down; `above` of every row on the way.
        below.fill(0); // the running OR of the rows above, for now
        dilate_stream(
            h,
            words,
            w,
            radius_widths,
            ring,
            out,
            false,
            |s, dst| dst.copy_from_slice(&occupied[s * words..(s + 1) * words]),
            |y, c| {
                covered[y * words..(y + 1) * words].copy_from_slice(c);
                above[y * words..(y + 1) * words].copy_from_slice(below);
                for (a, c) in below.iter_mut().zip(c) {
                    *a |= c;
                }
            },
        );
        // 3. + 4. bottom-up: core rows (between covered pixels in the row and in the column)
        // feed the growth dilation, whose rows minus the occupied pixels are the holes.
        below.fill(0);
        dilate_stream(
            h,
            words,
            w,
            grow_widths,
            ring,
            out,
            true,
            |y, core| {
                let c = &covered[y * words..(y + 1) * words];
                let a = &above[y * words..(y + 1) * words];
                let first =
                    c.iter().position(|&b| b != 0).map(|i| i * 64 + c[i].trailing_zeros() as usize);
                let last = c
                    .iter()
                    .rposition(|&b| b != 0)
                    .map(|i| i * 64 + 63 - c[i].leading_zeros() as usize);
                match (first, last) {
                    (Some(first), Some(last)) => {
                        for (((k, c), a), b) in core.iter_mut().zip(c).zip(a).zip(below.iter()) {
                            *k = !c & a & b;
                        }
                        // Only between the row's first and last covered pixel.
                        let (fw, lw) = (first / 64, last / 64);
                        core[..fw].fill(0);
                        core[lw + 1..].fill(0);
                        core[fw] &= span_bits(fw, first, last);
                        core[lw] &= span_bits(lw, first, last);
                    }
                    _ => core.fill(0),
                }
                for (b, c) in below.iter_mut().zip(c) {
                    *b |= c;
                }
            },
            |y, grown| {
                let o = &occupied[y * words..(y + 1) * words];
                let hrow = &mut holes[y * words..(y + 1) * words];
                for ((hb, g), o) in hrow.iter_mut().zip(grown).zip(o) {
                    *hb = g & !o;
                }
                row(y, hrow);
            },
        );
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
            seed: 0x006b_6675_7365,
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
pub fn fit_plane_ransac(
    depth: &Image<f32>,
    camera: &CameraModel,
    options: &PlaneFitOptions,
) -> Option<PlaneFit> {
    let (w, _) = depth.size();
    let valid: Vec<usize> = depth
        .data()
        .iter()
        .enumerate()
        .filter(|(_, z)| **z > 0.0 && z.is_finite())
        .map(|(i, _)| i)
        .collect();
    if valid.len() < 3 {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let n = options.max_samples.min(valid.len()).max(3);
    let fold = camera.distortion.fold_radius();
    let points: Vec<Vector3<f64>> = (0..n)
        .filter_map(|k| {
            let i =
                if n == valid.len() { valid[k] } else { valid[rng.random_range(0..valid.len())] };
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
    let inliers: Vec<Vector3<f64>> =
        points.iter().copied().filter(|p| (nrm.dot(p) - d).abs() < options.threshold_m).collect();
    let (nrm, d) = refine_plane(&inliers)?;
    let final_inliers: Vec<f64> =
        points.iter().map(|p| nrm.dot(p) - d).filter(|r| r.abs() < options.threshold_m).collect();
    let rms = (final_inliers.iter().map(|r| r * r).sum::<f64>()
        / final_inliers.len().max(1) as f64)
        .sqrt();
    Some(PlaneFit {
        normal: [nrm.x, nrm.y, nrm.z],
        offset: d,
        inliers: final_inliers.len(),
        samples: points.len(),
        rms_m: rms,
    })
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
