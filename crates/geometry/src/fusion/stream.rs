//! H1 + H2 + H7 + H8's mask for a stream of frames: [`Registration`] keeps every buffer and
//! every per-pixel constant between frames. (About 700 lines with its tests: the loop variants
//! and the argument that they are equivalent belong in one place.)
//!
//! The per-pixel arithmetic is [`super::pixel`]'s, unchanged (so the z-buffer is
//! bit-identical to the `bench-variants` z-buffers `register_depth` and `zbuffer_from_samples` and to the GPU);
//! what differs is the loop around it:
//!
//! * the ray table is stored as three planes (`x`, `y`, `s`), so the projection of a block of
//!   pixels vectorises without shuffles;
//! * the rounding and bounds test of [`super::zbuffer_pixel`] is evaluated branch-free in the
//!   same vector pass, in the equivalent form `0 <= u + 0.5 < width` (for an integer `width`,
//!   `floor(t) < width ⇔ t < width` and `floor(t) >= 0 ⇔ t >= 0`), leaving the scatter loop
//!   nothing but the z-test;
//! * the colour-sized z-buffer (8 MB at 1920×1080) is not cleared up front: a depth frame's
//!   rows land on the colour image roughly top to bottom, so each colour row is cleared just
//!   before the first sample that lands in it (rows are cleared in order, each once, and a
//!   row is never written before it is cleared), and the rows no sample reached are cleared at
//!   the end. The clear then warms the cache lines the scatter is about to hit instead of
//!   pushing 8 MB through the cache a second time. The order only affects speed: any input
//!   (random samples included) gives the same result.
//! * "clear" resets only what the previous frame wrote: the workspace keeps the invariant
//!   "a z-buffer pixel is non-empty only where its occupancy bit is set" (the occupancy bits
//!   are the hole mask's input anyway), so a row is cleared by resetting the 64-pixel runs
//!   whose occupancy word is non-zero, then the word. A z-buffer the caller lends
//!   ([`Registration::register_into`], [`Registration::register_parallel_into`]: a NumPy
//!   array, say) holds anything, so there every row is cleared whole (still row by row, just
//!   before its first sample): 8 MB written once instead of a copy's 8 MB read and written.
//! * the projection loop is compiled for x86-64's baseline and for AVX2 and picked at run
//!   time (`project_any`): the same operations in the same order, 8 lanes instead of 4;
//! * [`Registration::register_parallel`] splits the *colour* image into horizontal bands,
//!   one per task, so that no two tasks write the same pixel: no atomics, and the minimum is
//!   order-independent, so the result is bit-identical to one thread.

use rayon::prelude::*;

use super::holes::{HoleMasker, unpack_bits_row};
use super::pixel::{ColorProjection, ZBUFFER_EMPTY, distort_to_pixel, transform_point};
use super::{
    FusionOptions, MAX_COVERAGE_RADIUS_PX, checked_coverage_radius_px, depth_ray_table,
    hole_grow_px,
};
use crate::{DepthKind, GeometryError, Image, Rig};

/// Pixels per block of the two-pass loop: 256 × 3 words stay in L1.
const BLOCK: usize = 256;

/// Marks "no pixel" in the column plane of a projected block.
const NO_PIXEL: u32 = u32::MAX;

/// Depth rows per task of the parallel projection pass: 8 rows (4k pixels at 512 columns)
/// amortise rayon's per-task cost (~1 µs) over ~40 µs of work.
const ROWS_PER_TASK: usize = 8;

/// Where every depth pixel lands: pixel index (or [`NO_PIXEL`]), occupancy bit, colour-frame `z`.
#[derive(Clone)]
struct Projected {
    index: Vec<u32>,
    bit: Vec<u32>,
    z: Vec<f32>,
}

/// Exact z-buffered registration (H1 + H2 + H7) and the H8 hole mask of one depth frame after
/// another, with no allocation per frame.
///
/// ```
/// # use geometry::{fusion::{FusionOptions, Registration}, synth};
/// let setup = synth::kinect_preset(false);
/// let frame = synth::render(&setup);
/// let mut reg = Registration::new(&setup.rig, frame.depth_kind, &FusionOptions::default())?;
/// let mut mask = vec![false; reg.zbuffer().len()];
/// // per frame:
/// let landed = reg.register(&frame.depth).unwrap();
/// let holes = reg.hole_mask(&mut mask);
/// assert!(landed > 150_000 && holes > 0);
/// # Ok::<(), geometry::GeometryError>(())
/// ```
#[derive(Debug, Clone)]
pub struct Registration {
    proj: ColorProjection,
    depth_width: usize,
    depth_height: usize,
    ray_x: Vec<f32>,
    ray_y: Vec<f32>,
    ray_s: Vec<f32>,
    zbuffer: Vec<f32>,
    masker: HoleMasker,
    /// Depth-sized projection planes of [`Registration::register_parallel`] (empty until used).
    projected: Option<Projected>,
    /// Per task of the parallel projection: smallest and largest colour row landed on.
    task_rows: Vec<(u32, u32)>,
    /// Whether [`project_block`] may form the indices in `f32` ([`fits_float_index`]).
    float_index: bool,
    /// Whether the occupancy rows are exactly `width` bits (`width % 64 == 0`), so that a
    /// pixel's bit index is its pixel index and needs no plane of its own.
    same_stride: bool,
    /// Whether the last frame went into a caller's z-buffer, so that the occupancy bits no
    /// longer say where `zbuffer` is non-empty (its next frame clears every row whole).
    own_zbuffer_stale: bool,
}

impl std::fmt::Debug for Projected {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Projected({} pixels)", self.z.len())
    }
}

/// Projects one block (≤ [`BLOCK`] pixels): for every pixel the row-major index of its
/// colour pixel (`row * width + column`, [`NO_PIXEL`] where [`super::register_pixel`] gives
/// `None` or [`super::zbuffer_pixel`] rejects the pixel), its bit in an occupancy image of
/// `bits_per_row` bits per row (`row * bits_per_row + column`, meaningless for
/// [`NO_PIXEL`]) and its `z`. Same arithmetic as [`super::register_pixel`] operation for
/// operation.
///
/// With `FLOAT_INDEX` the two indices are formed in `f32` (`floor(v) * width + floor(u)`,
/// exact integers) and converted by [`float_to_u32`], which saves the emulated 32-bit integer
/// multiply of x86-64's baseline SSE2; only valid when `width * height` and
/// `bits_per_row * height` are at most 2^23 ([`fits_float_index`]).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn project_block<const FLOAT_INDEX: bool, const SAME_STRIDE: bool>(
    p: &ColorProjection,
    depth: &[f32],
    rx: &[f32],
    ry: &[f32],
    rs: &[f32],
    bits_per_row: u32,
    pj: &mut [u32],
    po: &mut [u32],
    pz: &mut [f32],
) {
    let n = depth.len();
    let (rx, ry, rs) = (&rx[..n], &ry[..n], &rs[..n]);
    let (pj, po, pz) = (&mut pj[..n], &mut po[..n], &mut pz[..n]);
    let (wf, hf) = (p.width as f32, p.height as f32);
    let w = p.width;
    let bprf = bits_per_row as f32;
    for i in 0..n {
        let value = depth[i];
        let valid = super::pixel::is_sample(value);
        // backproject_pixel
        let zd = value * rs[i];
        let xd = [rx[i] * zd, ry[i] * zd, zd];
        // project_point
        let xc = transform_point(p, xd);
        let zc = xc[2];
        let [u, v] = distort_to_pixel(p, xc);
        // zbuffer_pixel, branch-free (see the module docs for the equivalence).
        let tu = u + 0.5;
        let tv = v + 0.5;
        let ok = valid & (zc > 0.0) & (tu >= 0.0) & (tu < wf) & (tv >= 0.0) & (tv < hf);
        if FLOAT_INDEX {
            // Garbage in the lanes that are not `ok`; they become NO_PIXEL.
            let (fu, fv) = (floor_small(tu), floor_small(tv));
            let j = float_to_u32(fv * wf + fu);
            pj[i] = if ok { j } else { NO_PIXEL };
            if !SAME_STRIDE {
                po[i] = float_to_u32(fv * bprf + fu);
            }
        } else {
            let cu = floor_to_u32(if ok { tu } else { 0.0 });
            let cv = floor_to_u32(if ok { tv } else { 0.0 });
            pj[i] = if ok { cv.wrapping_mul(w).wrapping_add(cu) } else { NO_PIXEL };
            if !SAME_STRIDE {
                po[i] = cv.wrapping_mul(bits_per_row).wrapping_add(cu);
            }
        }
        pz[i] = zc;
    }
}

/// 2^23: from there on every `f32` is an integer, and `t + 2^23` rounds `t` to an integer.
const TWO_POW_23: f32 = 8_388_608.0;

/// `floor(t)` as an integer for `0 <= t < 2^23`, in float operations only (a saturating
/// `as` cast keeps the loop from vectorising on x86-64's SSE2 baseline): `(t + 2^23) - 2^23`
/// rounds `t` to the nearest integer exactly, one less if that overshot, and the bits of
/// `n + 2^23` minus those of `2^23` are the integer `n`.
#[inline(always)]
pub(crate) fn floor_to_u32(t: f32) -> u32 {
    float_to_u32(floor_small(t))
}

/// `floor(t)` for `0 <= t < 2^23` (see [`floor_to_u32`]); anything for other `t`.
#[inline(always)]
fn floor_small(t: f32) -> f32 {
    let r = (t + TWO_POW_23) - TWO_POW_23;
    if r > t { r - 1.0 } else { r }
}

/// The integer `n` for an integer-valued `0 <= n < 2^23` (see [`floor_to_u32`]); anything
/// (no panic) for other values.
#[inline(always)]
fn float_to_u32(n: f32) -> u32 {
    (n + TWO_POW_23).to_bits().wrapping_sub(TWO_POW_23.to_bits())
}

/// Whether [`project_block`]'s `FLOAT_INDEX` form is exact for this colour image: every pixel
/// index and occupancy bit index below 2^23.
fn fits_float_index(width: usize, height: usize, bits_per_row: usize) -> bool {
    const LIMIT: usize = 1 << 23;
    width.saturating_mul(height) <= LIMIT && bits_per_row.saturating_mul(height) <= LIMIT
}

/// The scatter half of the loop for one projected block: the z-test into `zbuffer`
/// (`width` columns), marking `occupancy` (`words` 64-bit words per row). Both hold a band of
/// rows starting at colour row `row0` (0 and the whole image on one thread); samples outside
/// the band are skipped. Rows `cleared..` of the band are cleared on first use (see the
/// module docs). Returns the number of samples z-tested.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn scatter_block<const SAME_STRIDE: bool>(
    pj: &[u32],
    po: &[u32],
    pz: &[f32],
    zbuffer: &mut [f32],
    occupancy: &mut [u64],
    width: usize,
    words: usize,
    row0: usize,
    cleared: &mut usize,
    full: bool,
) -> usize {
    let rows = occupancy.len() / words.max(1);
    let (j0, w0) = ((row0 * width) as u32, row0 * words);
    let len = zbuffer.len();
    // Samples below this index are in rows already cleared.
    let mut limit = *cleared * width;
    let mut landed = 0;
    // The occupancy word being marked, kept in a register: consecutive samples mostly share
    // a word, and an OR into memory per sample would chain them through store forwarding.
    let (mut word, mut bits) = (usize::MAX, 0u64);
    let n = pj.len();
    let (po, pz) = (&po[..if SAME_STRIDE { 0 } else { n }], &pz[..n]);
    for i in 0..n {
        let (jj, z) = (pj[i], pz[i]);
        let o = if SAME_STRIDE { jj } else { po[i] };
        // NO_PIXEL and samples of other bands wrap to >= len.
        let j = jj.wrapping_sub(j0) as usize;
        if j >= len {
            continue;
        }
        if j >= limit {
            let y = j / width;
            clear_rows(zbuffer, occupancy, width, words, *cleared, y + 1, full);
            *cleared = y + 1;
            limit = *cleared * width;
        }
        let slot = &mut zbuffer[j];
        // zbuffer_min
        if !(*slot <= z) {
            *slot = z;
        }
        let w = (o / 64) as usize - w0;
        if w != word {
            if word != usize::MAX {
                occupancy[word] |= bits;
            }
            (word, bits) = (w, 0);
        }
        bits |= 1u64 << (o % 64);
        landed += 1;
    }
    if word != usize::MAX {
        occupancy[word] |= bits;
    }
    debug_assert!(*cleared <= rows);
    landed
}

/// [`project_block`] in the form `float_index` / `same_stride` allow, compiled twice: for
/// x86-64's SSE2 baseline and for AVX2, picked once at run time by the CPU (`multiversion`).
/// AVX2 runs the loop 8 lanes wide instead of 4 (its two divisions per pixel dominate). The
/// operations and their order are the same in both copies and IEEE `+ - * /` round the same
/// at any width (no FMA: Rust never contracts `a * b + c`), so the planes are bit-identical.
#[multiversion::multiversion(targets("x86_64+avx2"))]
#[allow(clippy::too_many_arguments)]
fn project_any(
    float_index: bool,
    same_stride: bool,
    p: &ColorProjection,
    depth: &[f32],
    rx: &[f32],
    ry: &[f32],
    rs: &[f32],
    bits_per_row: u32,
    pj: &mut [u32],
    po: &mut [u32],
    pz: &mut [f32],
) {
    match (float_index, same_stride) {
        (true, true) => project_block::<true, true>(p, depth, rx, ry, rs, bits_per_row, pj, po, pz),
        (true, false) => {
            project_block::<true, false>(p, depth, rx, ry, rs, bits_per_row, pj, po, pz)
        }
        (false, true) => {
            project_block::<false, true>(p, depth, rx, ry, rs, bits_per_row, pj, po, pz)
        }
        (false, false) => {
            project_block::<false, false>(p, depth, rx, ry, rs, bits_per_row, pj, po, pz)
        }
    }
}

/// [`scatter_block`] reading the bit index from the pixel index when `same_stride`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn scatter_any(
    same_stride: bool,
    pj: &[u32],
    po: &[u32],
    pz: &[f32],
    zbuffer: &mut [f32],
    occupancy: &mut [u64],
    width: usize,
    words: usize,
    row0: usize,
    cleared: &mut usize,
    full: bool,
) -> usize {
    if same_stride {
        scatter_block::<true>(pj, po, pz, zbuffer, occupancy, width, words, row0, cleared, full)
    } else {
        scatter_block::<false>(pj, po, pz, zbuffer, occupancy, width, words, row0, cleared, full)
    }
}

/// Clears rows `from..to` of the z-buffer and the occupancy bits. Relies on the invariant
/// that [`Registration`] keeps between frames: a z-buffer pixel is not empty only where its
/// occupancy bit is set. So only the 64-pixel runs with a bit set are reset (about a third
/// of the image for a Kinect frame: two colour rows in three receive no sample at all).
/// `full`: every run is reset (a z-buffer the invariant does not hold for: a caller's).
#[cold]
#[inline(never)]
fn clear_rows(
    zbuffer: &mut [f32],
    occupancy: &mut [u64],
    width: usize,
    words: usize,
    from: usize,
    to: usize,
    full: bool,
) {
    for y in from..to {
        let zrow = &mut zbuffer[y * width..(y + 1) * width];
        for (run, bits) in zrow.chunks_mut(64).zip(&mut occupancy[y * words..(y + 1) * words]) {
            if full || *bits != 0 {
                run.fill(ZBUFFER_EMPTY);
                *bits = 0;
            }
        }
    }
}

impl Registration {
    /// Buffers and per-pixel constants for `rig`, depth images of kind `kind`, and H8's radii
    /// from `options` ([`checked_coverage_radius_px`], [`hole_grow_px`]).
    ///
    /// Errors: [`GeometryError::InvalidParameter`] for an invalid rig,
    /// [`checked_coverage_radius_px`]'s for a radius out of bounds.
    pub fn new(rig: &Rig, kind: DepthKind, options: &FusionOptions) -> Result<Self, GeometryError> {
        rig.validate()?;
        let radius = checked_coverage_radius_px(rig, options)?;
        let rays = depth_ray_table(&rig.depth, kind);
        Self::from_parts(
            ColorProjection::from_rig(rig),
            &rays,
            rig.depth.width,
            radius,
            hole_grow_px(rig, options),
        )
    }

    /// The same from a projection, a depth ray table ([`depth_ray_table`], row-major,
    /// `depth_width` columns) and the two radii of [`HoleMasker::new`] in colour pixels.
    ///
    /// Error: [`GeometryError::InvalidInput`] when a radius is not in
    /// `0..=`[`MAX_COVERAGE_RADIUS_PX`] (the hole mask's tables grow with it).
    pub fn from_parts(
        proj: ColorProjection,
        rays: &[[f32; 3]],
        depth_width: usize,
        radius_px: f32,
        grow_px: f32,
    ) -> Result<Self, GeometryError> {
        for (what, r) in [("coverage radius", radius_px), ("hole growth radius", grow_px)] {
            if !(0.0..=MAX_COVERAGE_RADIUS_PX).contains(&r) {
                return Err(GeometryError::InvalidInput(format!(
                    "{what} {r} px is outside 0..={MAX_COVERAGE_RADIUS_PX} px"
                )));
            }
        }
        let (cw, ch) = (proj.width as usize, proj.height as usize);
        let depth_width = depth_width.max(1);
        Ok(Self {
            proj,
            depth_width,
            depth_height: rays.len() / depth_width,
            ray_x: rays.iter().map(|r| r[0]).collect(),
            ray_y: rays.iter().map(|r| r[1]).collect(),
            ray_s: rays.iter().map(|r| r[2]).collect(),
            zbuffer: vec![ZBUFFER_EMPTY; cw * ch],
            masker: HoleMasker::new(cw, ch, radius_px, grow_px),
            projected: None,
            task_rows: Vec::new(),
            float_index: fits_float_index(cw, ch, cw.div_ceil(64).max(1) * 64),
            same_stride: cw % 64 == 0,
            own_zbuffer_stale: false,
        })
    }

    /// The colour projection in use.
    pub fn projection(&self) -> &ColorProjection {
        &self.proj
    }

    fn check(&self, depth: &Image<f32>) -> Result<(), GeometryError> {
        depth.expect_size("depth image", self.depth_width, self.depth_height)
    }

    /// Registers one depth frame (depth-camera-sized, the kind given to
    /// [`Registration::new`]) on one thread: afterwards [`Registration::zbuffer`] holds the
    /// smallest colour-frame `z` per colour pixel ([`ZBUFFER_EMPTY`] elsewhere), bit-identical
    /// to the `bench-variants` `register_depth`. Returns the number of samples that landed on the colour
    /// image. Error: [`GeometryError::SizeMismatch`] for a depth image of another size.
    pub fn register(&mut self, depth: &Image<f32>) -> Result<usize, GeometryError> {
        self.check(depth)?;
        let mut zbuffer = std::mem::take(&mut self.zbuffer);
        let landed = self.register_to(depth, &mut zbuffer, self.own_zbuffer_stale);
        (self.zbuffer, self.own_zbuffer_stale) = (zbuffer, false);
        Ok(landed)
    }

    /// [`Registration::register`] straight into the caller's `zbuffer` (colour-sized,
    /// row-major; any content: every row is cleared whole), leaving the workspace's own
    /// z-buffer ([`Registration::zbuffer`]) as it was; [`Registration::hole_mask`] then gives
    /// this frame's mask. No copy: a stream of frames into one array writes each z-buffer
    /// once. Errors: [`GeometryError::SizeMismatch`] for a depth image of another size,
    /// [`GeometryError::InvalidInput`] for a `zbuffer` of another length.
    pub fn register_into(
        &mut self,
        depth: &Image<f32>,
        zbuffer: &mut [f32],
    ) -> Result<usize, GeometryError> {
        self.check_into(depth, zbuffer)?;
        self.own_zbuffer_stale = true;
        Ok(self.register_to(depth, zbuffer, true))
    }

    /// [`Registration::register_parallel`] straight into the caller's `zbuffer`, as
    /// [`Registration::register_into`]; bit-identical to both.
    pub fn register_parallel_into(
        &mut self,
        depth: &Image<f32>,
        zbuffer: &mut [f32],
    ) -> Result<usize, GeometryError> {
        self.check_into(depth, zbuffer)?;
        self.own_zbuffer_stale = true;
        Ok(self.register_parallel_to(depth, zbuffer, true))
    }

    fn check_into(&self, depth: &Image<f32>, zbuffer: &[f32]) -> Result<(), GeometryError> {
        self.check(depth)?;
        let (cw, ch) = (self.proj.width as usize, self.proj.height as usize);
        if zbuffer.len() != cw * ch {
            return Err(GeometryError::InvalidInput(format!(
                "z-buffer of {} pixels for a {cw}x{ch} colour image ({} pixels)",
                zbuffer.len(),
                cw * ch
            )));
        }
        Ok(())
    }

    /// One thread into `zbuffer` (checked); `full`: clear every row whole.
    fn register_to(&mut self, depth: &Image<f32>, zbuffer: &mut [f32], full: bool) -> usize {
        let (cw, ch) = (self.proj.width as usize, self.proj.height as usize);
        let words = self.masker.words_per_row();
        let occupancy = self.masker.occupancy_mut();
        let mut cleared = 0;
        let mut landed = 0;
        let bits_per_row = (words * 64) as u32;
        let (mut bj, mut bo, mut bz) = ([0u32; BLOCK], [0u32; BLOCK], [0f32; BLOCK]);
        let chunks = depth
            .data()
            .chunks(BLOCK)
            .zip(self.ray_x.chunks(BLOCK))
            .zip(self.ray_y.chunks(BLOCK))
            .zip(self.ray_s.chunks(BLOCK));
        for (((d, rx), ry), rs) in chunks {
            project_any(
                self.float_index,
                self.same_stride,
                &self.proj,
                d,
                rx,
                ry,
                rs,
                bits_per_row,
                &mut bj,
                &mut bo,
                &mut bz,
            );
            let n = d.len();
            landed += scatter_any(
                self.same_stride,
                &bj[..n],
                &bo[..n],
                &bz[..n],
                zbuffer,
                occupancy,
                cw,
                words,
                0,
                &mut cleared,
                full,
            );
        }
        if cleared < ch {
            clear_rows(zbuffer, occupancy, cw, words, cleared, ch, full);
        }
        landed
    }

    /// [`Registration::register`] on all rayon threads, bit-identical to it. Pass 1 projects
    /// blocks of depth rows in parallel into depth-sized planes and notes the colour rows each
    /// block reaches; pass 2 gives every task a band of colour rows and z-buffers the blocks
    /// that reach it, so that every pixel has one writer.
    pub fn register_parallel(&mut self, depth: &Image<f32>) -> Result<usize, GeometryError> {
        self.check(depth)?;
        let mut zbuffer = std::mem::take(&mut self.zbuffer);
        let landed = self.register_parallel_to(depth, &mut zbuffer, self.own_zbuffer_stale);
        (self.zbuffer, self.own_zbuffer_stale) = (zbuffer, false);
        Ok(landed)
    }

    /// All rayon threads into `zbuffer` (checked); `full`: clear every row whole.
    fn register_parallel_to(
        &mut self,
        depth: &Image<f32>,
        zbuffer: &mut [f32],
        full: bool,
    ) -> usize {
        let (cw, ch) = (self.proj.width as usize, self.proj.height as usize);
        let n = depth.data().len();
        let projected = self.projected.get_or_insert_with(|| Projected {
            index: vec![0; n],
            bit: vec![0; n],
            z: vec![0.0; n],
        });
        let chunk = self.depth_width * ROWS_PER_TASK;
        let tasks = n.div_ceil(chunk);
        self.task_rows.resize(tasks, (0, 0));
        let proj = &self.proj;
        let words = self.masker.words_per_row();
        let bits_per_row = (words * 64) as u32;
        let (float_index, same_stride) = (self.float_index, self.same_stride);
        // Pass 1: projection.
        projected
            .index
            .par_chunks_mut(chunk)
            .zip(projected.bit.par_chunks_mut(chunk))
            .zip(projected.z.par_chunks_mut(chunk))
            .zip(depth.data().par_chunks(chunk))
            .zip(
                self.ray_x
                    .par_chunks(chunk)
                    .zip(self.ray_y.par_chunks(chunk))
                    .zip(self.ray_s.par_chunks(chunk)),
            )
            .zip(self.task_rows.par_iter_mut())
            .for_each(|(((((pj, po), pz), d), ((rx, ry), rs)), rows)| {
                // Smallest and largest pixel index: their rows bound the rows reached.
                let (mut lo, mut hi) = (u32::MAX, 0);
                for start in (0..d.len()).step_by(BLOCK) {
                    let end = (start + BLOCK).min(d.len());
                    let (bj, bo) = (&mut pj[start..end], &mut po[start..end]);
                    let (d, rx, ry, rs, bz) = (
                        &d[start..end],
                        &rx[start..end],
                        &ry[start..end],
                        &rs[start..end],
                        &mut pz[start..end],
                    );
                    project_any(
                        float_index,
                        same_stride,
                        proj,
                        d,
                        rx,
                        ry,
                        rs,
                        bits_per_row,
                        bj,
                        bo,
                        bz,
                    );
                    for &j in bj.iter() {
                        if j != NO_PIXEL {
                            lo = lo.min(j);
                            hi = hi.max(j);
                        }
                    }
                }
                *rows = if lo > hi { (1, 0) } else { (lo / cw as u32, hi / cw as u32) };
            });
        // Pass 2: bands of colour rows, one writer per pixel.
        let bands = rayon::current_num_threads().max(1);
        let band_rows = ch.div_ceil(bands).max(1);
        let projected = &*projected;
        let task_rows = &self.task_rows;
        zbuffer
            .par_chunks_mut(band_rows * cw)
            .zip(self.masker.occupancy_mut().par_chunks_mut(band_rows * words))
            .enumerate()
            .map(|(b, (zb, occ))| {
                let row0 = b * band_rows;
                let rows = occ.len() / words.max(1);
                let (row0_u, row1) = (row0 as u32, (row0 + rows) as u32);
                let mut cleared = 0;
                let mut landed = 0;
                for (t, &(lo, hi)) in task_rows.iter().enumerate() {
                    if lo > hi || hi < row0_u || lo >= row1 {
                        continue;
                    }
                    let r = t * chunk..((t + 1) * chunk).min(n);
                    let (pj, po, pz) =
                        (&projected.index[r.clone()], &projected.bit[r.clone()], &projected.z[r]);
                    landed += scatter_any(
                        same_stride,
                        pj,
                        po,
                        pz,
                        zb,
                        occ,
                        cw,
                        words,
                        row0,
                        &mut cleared,
                        full,
                    );
                }
                if cleared < rows {
                    clear_rows(zb, occ, cw, words, cleared, rows, full);
                }
                landed
            })
            .sum()
    }

    /// The z-buffer of the last frame registered into the workspace's own buffer
    /// ([`Registration::register`], [`Registration::register_parallel`]; colour-sized,
    /// row-major, [`ZBUFFER_EMPTY`] where no sample landed).
    pub fn zbuffer(&self) -> &[f32] {
        &self.zbuffer
    }

    /// The z-buffer of the last registered frame, taking the workspace apart (row-major,
    /// colour-sized, no copy).
    pub fn into_zbuffer(self) -> Vec<f32> {
        self.zbuffer
    }

    /// The z-buffer as an image.
    pub fn zbuffer_image(&self) -> Image<f32> {
        let w = self.proj.width as usize;
        Image::from_fn(w, self.proj.height as usize, |x, y| self.zbuffer[y * w + x])
    }

    /// H8's hole mask of the last registered frame into `mask` (colour-sized, row-major; the
    /// same as [`HoleMasker::compute`] on [`Registration::zbuffer`]); returns the number of
    /// hole pixels. Reads the occupancy bits the registration marked instead of scanning the
    /// z-buffer.
    pub fn hole_mask(&mut self, mask: &mut [bool]) -> usize {
        self.masker.compute_from_occupancy(mask)
    }

    /// [`Registration::hole_mask`] with the `bool` image written on all rayon threads (the
    /// bit mask itself is made on one: its two passes run down and up the whole image).
    pub fn hole_mask_parallel(&mut self, mask: &mut [bool]) -> usize {
        /// Rows per task: 32 rows of 1920 `bool`s = 60 kB each.
        const ROWS: usize = 32;
        let (w, words) = (self.proj.width as usize, self.masker.words_per_row());
        let (n, bits) = self.hole_bits();
        mask.par_chunks_mut(w * ROWS).zip(bits.par_chunks(words * ROWS)).for_each(|(m, b)| {
            for (m, b) in m.chunks_mut(w).zip(b.chunks(words)) {
                unpack_bits_row(b, m);
            }
        });
        n
    }

    /// [`Registration::hole_mask`] as bits only, without writing a `bool` image: returns the
    /// number of hole pixels and the mask (bit `x % 64` of word `y * words + x / 64`, with
    /// `words = ceil(width / 64)`; [`HoleMasker::hole_bits`]).
    pub fn hole_bits(&mut self) -> (usize, &[u64]) {
        let n = self.masker.compute_bits_from_occupancy();
        (n, self.masker.hole_bits())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::floor_f32;

    #[test]
    fn float_floor_equals_floor_on_the_whole_range_the_rounding_uses() {
        // Every f32 in [0, 2^12) near an integer or a half (the values where a rounding
        // error would show), and a sweep of the rest up to 2^23: the trick must equal
        // floor_f32 exactly (it replaces it inside the bounds test).
        let mut checked = 0;
        for k in 0..4096u32 {
            for base in [k as f32, k as f32 + 0.5] {
                let mut x = base;
                let mut y = base;
                for _ in 0..8 {
                    for t in [x, y] {
                        if (0.0..TWO_POW_23).contains(&t) {
                            assert_eq!(floor_to_u32(t) as f32, floor_f32(t), "floor({t:e})");
                            checked += 1;
                        }
                    }
                    x = x.next_up();
                    y = y.next_down();
                }
            }
        }
        let mut t = 0.0f32;
        while t < TWO_POW_23 {
            assert_eq!(floor_to_u32(t) as f32, floor_f32(t), "floor({t:e})");
            assert_eq!(
                floor_to_u32(t.next_down().max(0.0)) as f32,
                floor_f32(t.next_down().max(0.0))
            );
            t = t * 1.001 + 1e-3;
            checked += 2;
        }
        // Count guard: the first loop checks 4096 × 2 bases × 8 steps × 2 directions ≈ 131 000
        // values (a handful below 0 skipped), the sweep ~2 × 16 000 more.
        assert!(checked > 100_000);
    }

    #[test]
    fn all_index_forms_agree() {
        // The Kinect preset (noisy) and a second frame through the same workspace: the f32
        // index form must give the same z-buffer and occupancy bits as the integer form, and
        // the shared pixel/bit index (1920 = 30 * 64) the same as a separate bit index.
        let setup = crate::synth::kinect_preset(true);
        let frame = crate::synth::render(&setup);
        let mut a =
            Registration::new(&setup.rig, frame.depth_kind, &FusionOptions::default()).unwrap();
        assert!(a.float_index, "1920x1080 fits the f32 index form");
        let mut b = a.clone();
        b.float_index = false;
        let mut c = a.clone();
        c.same_stride = false;
        let scaled = frame.depth.map(|z| z * 0.7);
        for depth in [&frame.depth, &scaled] {
            for parallel in [false, true] {
                let run = |r: &mut Registration| {
                    if parallel { r.register_parallel(depth) } else { r.register(depth) }.unwrap()
                };
                let (na, nb, nc) = (run(&mut a), run(&mut b), run(&mut c));
                assert_eq!((na, na), (nb, nc));
                // Guard: the Kinect preset's 217 088 depth pixels are mostly valid and land
                // in the colour view (synth::kinect_preset); 100 000 fails when registration
                // lands almost nothing.
                assert!(na > 100_000);
                for other in [&mut b, &mut c] {
                    assert!(
                        a.zbuffer
                            .iter()
                            .zip(&other.zbuffer)
                            .all(|(x, y)| x.to_bits() == y.to_bits())
                    );
                    assert!(a.masker.occupancy_mut() == other.masker.occupancy_mut());
                }
            }
        }
        // Hand calculation: 3841 × 2185 = 8 392 585 and 3904 bits × 2185 rows = 8 530 240
        // exceed 2^23 = 8 388 608; 3840 × 2160 = 8 294 400 fits.
        assert!(!fits_float_index(3841, 2185, 3904), "2^23 limit");
        assert!(fits_float_index(3840, 2160, 3840));
    }
}
