//! Stage 1, candidates: the ChESS X-junction response and its local maxima, each refined to
//! sub-pixel by [`refine_corner`].

use geometry::Image;
use nalgebra::Vector2;

use super::DetectorParams;
use super::subpix::refine_corner;

/// Most candidates kept per image (strongest first); a 7x5 board needs 35.
const MAX_CANDIDATES: usize = 600;
/// Images of at least this many pixels get their ChESS response rows in parallel. An IR
/// image (512x424, 217 k pixels) is above it: on the idle bench machine its response took
/// 0.69 ms on one core (`detect_stages`, SSE2 kernel), and the criterion IR detection took
/// 2.43 ms with the response on one thread against 2.08 ms with its rows in parallel
/// (`run_all.sh`, 2026-12-02 02:56 and 03:15 UTC). The IR image's coarse-first pass computes
/// the response of its 2×2 box mean (256x212, 54 k pixels): in parallel it took 30 µs less of
/// the detection's stages outside the junction fit (two threads, minimum of 300 runs: 262–267
/// → 231–235 µs, 2026-12-02). Below ~50 k pixels (a 256x192 image) the response is a few
/// hundredths of a millisecond, where rayon's hand-offs would cost about what they save.
const PARALLEL_RESPONSE_PIXELS: usize = 50_000;

/// Most response-sized buffers kept per thread for the next detection ([`zeroed_buffer`]):
/// one detection pass needs two at once (the 2×2 box mean and its response).
const SPARE_BUFFERS: usize = 2;
/// Largest buffer kept (values): a 1920x1080 frame's. A buffer taken fresh from the allocator
/// is mapped page by page as the kernels first write it, and glibc hands freed buffers of
/// this size back to the kernel: on the IR bench image the box mean and its response cost
/// ~100 page faults per detection, 10 % of a one-thread detection's profile (perf,
/// 2026-12-02). Larger images allocate anew; two buffers per thread of at most 8.3 MB stay
/// held.
const SPARE_BUFFER_MAX_LEN: usize = 1920 * 1080;

thread_local! {
    /// Buffers of earlier detections on this thread, reused by [`zeroed_buffer`].
    static SPARE: std::cell::RefCell<Vec<Vec<f32>>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// `len` zeros, in a buffer of an earlier detection on this thread where one was kept.
fn zeroed_buffer(len: usize) -> Vec<f32> {
    let mut buf = SPARE.with(|s| s.borrow_mut().pop()).unwrap_or_default();
    buf.clear();
    buf.resize(len, 0.0);
    buf
}

/// Keeps `img`'s buffer for a later [`zeroed_buffer`] on this thread (response images and
/// box means, once their peaks are found).
pub(super) fn recycle(img: Image<f32>) {
    let buf = img.into_vec();
    if buf.capacity() <= SPARE_BUFFER_MAX_LEN {
        SPARE.with(|s| {
            let mut spare = s.borrow_mut();
            if spare.len() < SPARE_BUFFERS {
                spare.push(buf);
            }
        });
    }
}

/// Pixels per step of the response kernel (and of the peak search's threshold skip): two
/// AVX2 registers of `f32`, four SSE2 ones. Sixteen rather than eight gives each step
/// independent chains of the 16-term ring sum to overlap (detect_stages, one thread, loaded
/// machine, alternated: IR response 0.55–0.65 ms with 8, 0.36–0.38 ms with 16; peaks 0.16–0.22
/// against 0.10 ms).
const LANES: usize = 16;

/// The arithmetic [`pixel_response`] needs: `f32`, and [`Lanes`] ([`LANES`] pixels at once).
trait Lane:
    Copy
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::ops::Div<Output = Self>
{
    fn splat(v: f32) -> Self;
    fn abs_(self) -> Self;
}

impl Lane for f32 {
    fn splat(v: f32) -> Self {
        v
    }
    fn abs_(self) -> Self {
        self.abs()
    }
}

/// [`LANES`] pixels' values, each operation applied lane by lane in plain loops that LLVM
/// turns into SIMD instructions of whatever width the calling function is compiled for (the
/// SSE2 baseline, or AVX2 in [`row_response`]'s dispatched copy): the same IEEE operations as
/// on `f32`, so every lane equals the scalar formula bit for bit.
#[derive(Clone, Copy)]
struct Lanes([f32; LANES]);

macro_rules! lanewise {
    ($tr:ident, $f:ident, $op:tt) => {
        impl std::ops::$tr for Lanes {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: Self) -> Self {
                Lanes(std::array::from_fn(|k| self.0[k] $op o.0[k]))
            }
        }
    };
}
lanewise!(Add, add, +);
lanewise!(Sub, sub, -);
lanewise!(Mul, mul, *);
lanewise!(Div, div, /);

impl Lane for Lanes {
    #[inline(always)]
    fn splat(v: f32) -> Self {
        Lanes([v; LANES])
    }
    #[inline(always)]
    fn abs_(self) -> Self {
        Lanes(self.0.map(f32::abs))
    }
}

/// ChESS response at every pixel (0 near the border).
///
/// Row by row: each of the 16 ring samples of the pixels of a row is a contiguous slice of
/// the image (the row shifted by the ring offset), so [`row_response`] computes the pixels of
/// a row [`LANES`] at a time; the operations and their order per pixel are the textbook
/// formula's.
pub fn chess_response(img: &Image<f32>, radius: usize) -> Image<f32> {
    chess_response_with(img, radius, row_response)
}

/// The kernel computing one row's responses (see [`row_response`]).
type RowFn = fn(&[&[f32]; 16], &[&[f32]; 5], &mut [f32]);

/// [`chess_response`] with the row kernel given (the tests pass the baseline copy).
fn chess_response_with(img: &Image<f32>, radius: usize, row_fn: RowFn) -> Image<f32> {
    let (w, h) = img.size();
    let r = radius as f64;
    let offsets: [(isize, isize); 16] = std::array::from_fn(|n| {
        let a = n as f64 * std::f64::consts::TAU / 16.0;
        ((r * a.cos()).round() as isize, (r * a.sin()).round() as isize)
    });
    if w <= 2 * radius || h <= 2 * radius {
        return Image::from_fn(w, h, |_, _| 0.0);
    }
    let mut out = zeroed_buffer(w * h);
    let data = img.data();
    let len = w - 2 * radius;
    let row = |y: usize, row: &mut [f32]| {
        if y < radius || y + radius >= h {
            return;
        }
        // Slice n holds ring sample n of the pixels x = radius .. w − radius.
        let at = |dx: isize, dy: isize| {
            let start = (y as isize + dy) as usize * w + (radius as isize + dx) as usize;
            &data[start..start + len]
        };
        let ring: [&[f32]; 16] = offsets.map(|(dx, dy)| at(dx, dy));
        let local = [at(0, 0), at(-1, 0), at(1, 0), at(0, -1), at(0, 1)];
        row_fn(&ring, &local, &mut row[radius..radius + len]);
    };
    // Rows in parallel only where the image is large enough to repay rayon's hand-offs (see
    // PARALLEL_RESPONSE_PIXELS).
    if w * h >= PARALLEL_RESPONSE_PIXELS {
        use rayon::prelude::*;
        out.par_chunks_mut(w).enumerate().for_each(|(y, r)| row(y, r));
    } else {
        out.chunks_mut(w).enumerate().for_each(|(y, r)| row(y, r));
    }
    Image::from_vec(w, h, out).expect("w × h values")
}

/// The response of one row's pixels into `out` from their 16 ring-sample slices and their
/// centre, left, right, up and down slices (all `out.len()` long). Compiled twice, for the
/// SSE2 baseline and for AVX2, picked at run time by the CPU (`multiversion`); both evaluate
/// [`pixel_response`]'s operations in its order, without fused multiply-adds, so they give
/// the same bits.
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn row_response(ring: &[&[f32]; 16], local: &[&[f32]; 5], out: &mut [f32]) {
    row_kernel(ring, local, out);
}

/// [`row_response`]'s body, inlined into each of its compiled copies (and called directly by
/// the tests to get the baseline copy whatever the CPU).
#[inline(always)]
fn row_kernel(ring: &[&[f32]; 16], local: &[&[f32]; 5], out: &mut [f32]) {
    let len = out.len();
    if len < LANES {
        // Too short a row for one step: pixel by pixel.
        for (k, o) in out.iter_mut().enumerate() {
            *o = pixel_response(&ring.map(|s| s[k]), local.map(|s| s[k]));
        }
        return;
    }
    let mut s = [Lanes([0.0; LANES]); 16];
    let mut l = [Lanes([0.0; LANES]); 5];
    let mut i = 0;
    while i < len {
        // The last step ends at the row's end, overlapping its predecessor (those pixels get
        // the same values again).
        let at = i.min(len - LANES);
        // Plain copies (no closures through `array::from_fn`, which stayed calls).
        for (v, src) in s.iter_mut().zip(ring) {
            v.0.copy_from_slice(&src[at..at + LANES]);
        }
        for (v, src) in l.iter_mut().zip(local) {
            v.0.copy_from_slice(&src[at..at + LANES]);
        }
        let v = pixel_response(&s, l);
        out[at..at + LANES].copy_from_slice(&v.0);
        i = at + LANES;
    }
}

/// The ChESS response of one pixel (or [`LANES`], as [`Lanes`]) from its 16 ring samples and
/// its centre, left, right, up and down neighbours: sum response − diff response − mean
/// response, in the textbook formula's order of operations.
#[inline(always)]
fn pixel_response<T: Lane>(s: &[T; 16], local: [T; 5]) -> T {
    let zero = T::splat(0.0);
    let mut sum = zero;
    for n in 0..4 {
        sum = sum + ((s[n] + s[n + 8]) - (s[n + 4] + s[n + 12])).abs_();
    }
    let mut diff = zero;
    for n in 0..8 {
        diff = diff + (s[n] - s[n + 8]).abs_();
    }
    let mut ring = zero;
    for v in s {
        ring = ring + *v;
    }
    let ring_mean = ring / T::splat(16.0);
    let [c, l, r, u, d] = local;
    let local = (c + l + r + u + d) / T::splat(5.0);
    sum - diff - T::splat(16.0) * (ring_mean - local).abs_()
}

/// Candidate X-junctions: local maxima of the ChESS response, refined to sub-pixel.
pub fn candidates(img: &Image<f32>, params: &DetectorParams) -> Vec<(Vector2<f64>, f32)> {
    let resp = response(img, params);
    let found = peaks(&resp, params);
    recycle(resp);
    refine_peaks(img, &found, params)
}

/// Ring radius of the response at [`DetectorParams::response_decimation`]'s scale.
fn response_radius(params: &DetectorParams) -> usize {
    params.ring_radius.div_ceil(params.response_decimation.max(1)).max(3)
}

/// The ChESS response at [`DetectorParams::response_decimation`]'s scale: on the image, or
/// on its 2×2 box mean (a box mean, not every second pixel: a sharp corner's response is
/// only 1–2 px wide, and sampling every second pixel missed strong corners).
pub(super) fn response(img: &Image<f32>, params: &DetectorParams) -> Image<f32> {
    if params.response_decimation == 2 {
        let half = halve(img);
        let resp = chess_response(&half, response_radius(params));
        recycle(half);
        resp
    } else {
        chess_response(img, params.ring_radius)
    }
}

/// The 2×2 box mean of `img` (an odd last row or column is dropped): pixel `(x, y)` is the
/// mean of full-size pixels `2x, 2x + 1` × `2y, 2y + 1`, centred at `(2x + 0.5, 2y + 0.5)`.
pub(super) fn halve(img: &Image<f32>) -> Image<f32> {
    let (w, h) = img.size();
    let (hw, hh) = (w / 2, h / 2);
    let data = img.data();
    let mut out = zeroed_buffer(hw * hh);
    for (y, row) in out.chunks_mut(hw.max(1)).enumerate().take(hh) {
        halve_row(
            &data[2 * y * w..2 * y * w + 2 * hw],
            &data[(2 * y + 1) * w..(2 * y + 1) * w + 2 * hw],
            row,
        );
    }
    Image::from_vec(hw, hh, out).expect("hw × hh values")
}

/// One row of [`halve`]: `out[x]` is the mean of `a[2x], a[2x + 1], b[2x], b[2x + 1]`
/// (rows `2y` and `2y + 1`). Compiled for SSE2 and AVX2, picked at run time; the same
/// operations in the same order in both.
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn halve_row(a: &[f32], b: &[f32], out: &mut [f32]) {
    for ((o, a), b) in out.iter_mut().zip(a.chunks_exact(2)).zip(b.chunks_exact(2)) {
        *o = ((a[0] + a[1]) + (b[0] + b[1])) * 0.25;
    }
}

/// Local maxima of the response above [`DetectorParams::min_response_fraction`] of its
/// largest value, strongest first, at most [`MAX_CANDIDATES`].
pub(super) fn peaks(resp: &Image<f32>, params: &DetectorParams) -> Vec<(usize, usize, f32)> {
    let (w, h) = resp.size();
    let data = resp.data();
    let max = max_of(data);
    if max <= 0.0 {
        return Vec::new();
    }
    let thr = max * params.min_response_fraction;
    let nms = response_radius(params);
    // Pixel (xx, yy) beats (x, y) with value v: larger, or equal and earlier in raster order
    // (so of a plateau exactly one pixel is kept).
    let beats = |xx: usize, yy: usize, x: usize, y: usize, v: f32| {
        let o = data[yy * w + xx];
        o > v || (o == v && (yy, xx) < (y, x))
    };
    // Whether a pixel of the window of half size `r` around (x, y), clipped to the image,
    // beats it.
    let beaten_within = |x: usize, y: usize, v: f32, r: usize| {
        let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
        (y.saturating_sub(r)..=(y + r).min(h - 1))
            .any(|yy| (x0..=x1).any(|xx| (xx, yy) != (x, y) && beats(xx, yy, x, y, v)))
    };
    let mut peaks = Vec::new();
    for (y, row) in data.chunks_exact(w).enumerate() {
        // Most pixels are at most the threshold: runs of LANES of them are skipped with one
        // branch-free test each.
        for (c, chunk) in row.chunks(LANES).enumerate() {
            if !chunk.iter().fold(false, |any, &v| any | (v > thr)) {
                continue;
            }
            for (k, &v) in chunk.iter().enumerate() {
                let x = c * LANES + k;
                // The 3x3 neighbourhood first (a subset of the window, same rule): most
                // pixels above the threshold lie on edges and fail it at once.
                if v <= thr || beaten_within(x, y, v, 1) || beaten_within(x, y, v, nms) {
                    continue;
                }
                peaks.push((x, y, v));
            }
        }
    }
    peaks.sort_by(|a, b| b.2.total_cmp(&a.2));
    peaks.truncate(MAX_CANDIDATES);
    peaks
}

/// The largest of 0 and `data`'s values (`f32::max` over them, ignoring NaN), [`LANES`]
/// running maxima at once: the maximum does not depend on the order of comparison.
fn max_of(data: &[f32]) -> f32 {
    let mut lanes = [0.0f32; LANES];
    let mut chunks = data.chunks_exact(LANES);
    for chunk in &mut chunks {
        for (m, &v) in lanes.iter_mut().zip(chunk) {
            *m = m.max(v);
        }
    }
    chunks.remainder().iter().chain(&lanes).copied().fold(0.0f32, f32::max)
}

/// Each peak (at the response's scale) refined on the full image by [`refine_corner`]; of two
/// peaks refining onto one corner the stronger is kept.
pub(super) fn refine_peaks(
    img: &Image<f32>,
    peaks: &[(usize, usize, f32)],
    params: &DetectorParams,
) -> Vec<(Vector2<f64>, f32)> {
    use rayon::prelude::*;
    let scale = params.response_decimation.max(1) as f64;
    let offset = (scale - 1.0) / 2.0;
    let mut refined: Vec<(Vector2<f64>, f32)> = peaks
        .par_iter()
        .filter_map(|&(x, y, v)| {
            let at = Vector2::new(x as f64 * scale + offset, y as f64 * scale + offset);
            refine_corner(img, at, params.subpix_half_window).map(|p| (p, v))
        })
        .collect();
    // Two peaks refining onto one corner: keep the stronger.
    let mut keep: Vec<(Vector2<f64>, f32)> = Vec::with_capacity(refined.len());
    refined.sort_by(|a, b| b.1.total_cmp(&a.1));
    for c in refined {
        if keep.iter().all(|k| (k.0 - c.0).norm() > 2.0) {
            keep.push(c);
        }
    }
    keep
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tolerance: none. The peak search equals its definition evaluated pixel by pixel (every
    /// pixel of the clipped window compared, no 3x3 pre-test): above the threshold, no pixel
    /// of the window larger, none equal and earlier in raster order. The response has
    /// plateaus (ties) and peaks at the borders.
    #[test]
    fn peaks_equal_the_definition() {
        let (w, h) = (83, 57);
        let resp = Image::from_fn(w, h, |x, y| ((x * 7 + y * 13) % 17 + (x * y) % 5) as f32);
        let params = DetectorParams::for_image(w, h);
        let got = peaks(&resp, &params);
        let max = resp.data().iter().copied().fold(0.0f32, f32::max);
        let thr = max * params.min_response_fraction;
        let r = response_radius(&params) as isize;
        let mut want = Vec::new();
        for y in 0..h as isize {
            for x in 0..w as isize {
                let v = *resp.get(x as usize, y as usize);
                let beaten = (-r..=r).any(|dy| {
                    (-r..=r).any(|dx| {
                        let (xx, yy) = (x + dx, y + dy);
                        (dx, dy) != (0, 0)
                            && (0..w as isize).contains(&xx)
                            && (0..h as isize).contains(&yy)
                            && {
                                let o = *resp.get(xx as usize, yy as usize);
                                o > v || (o == v && (dy, dx) < (0, 0))
                            }
                    })
                });
                if v > thr && !beaten {
                    want.push((x as usize, y as usize, v));
                }
            }
        }
        want.sort_by(|a, b| b.2.total_cmp(&a.2));
        assert!(want.len() > 10, "the image has peaks ({})", want.len());
        assert_eq!(got, want);
    }

    /// Tolerance: none. The row-slice ChESS response equals the per-pixel textbook formula
    /// (16 ring samples gathered per pixel) bit for bit, on non-square images with structure
    /// everywhere, for both ring radii, borders included: with the kernel copy the CPU picks
    /// (AVX2 where present, as on the test machine) and with the SSE2 baseline copy, on rows
    /// whose length is a multiple of [`LANES`], is not (the last step overlaps), and is
    /// shorter than one step.
    #[test]
    fn chess_response_equals_the_per_pixel_formula() {
        let kernels: [(&str, RowFn); 2] = [("dispatched", row_response), ("baseline", row_kernel)];
        for ((w, h), radius, (name, kernel)) in [(97, 61), (30, 23), (15, 17)]
            .into_iter()
            .flat_map(|s| [5usize, 7].into_iter().map(move |r| (s, r)))
            .flat_map(|(s, r)| kernels.into_iter().map(move |k| (s, r, k)))
        {
            if w <= 2 * radius {
                continue;
            }
            let img = Image::from_fn(w, h, |x, y| {
                let checker = if ((x / 9) + (y / 7)) % 2 == 0 { 200.0 } else { 30.0 };
                checker + ((x * 37 + y * 91) % 23) as f32 * 0.7
            });
            let got = chess_response_with(&img, radius, kernel);
            let ring: Vec<(isize, isize)> = (0..16)
                .map(|n| {
                    let a = n as f64 * std::f64::consts::TAU / 16.0;
                    (
                        (radius as f64 * a.cos()).round() as isize,
                        (radius as f64 * a.sin()).round() as isize,
                    )
                })
                .collect();
            let at = |x: usize, y: usize, dx: isize, dy: isize| {
                *img.get((x as isize + dx) as usize, (y as isize + dy) as usize)
            };
            for y in 0..h {
                for x in 0..w {
                    let want = if x < radius || y < radius || x + radius >= w || y + radius >= h {
                        0.0
                    } else {
                        let s: Vec<f32> = ring.iter().map(|&(dx, dy)| at(x, y, dx, dy)).collect();
                        let mut sum = 0.0;
                        for n in 0..4 {
                            sum += ((s[n] + s[n + 8]) - (s[n + 4] + s[n + 12])).abs();
                        }
                        let mut diff = 0.0;
                        for n in 0..8 {
                            diff += (s[n] - s[n + 8]).abs();
                        }
                        let mean = s.iter().sum::<f32>() / 16.0;
                        let local = (at(x, y, 0, 0)
                            + at(x, y, -1, 0)
                            + at(x, y, 1, 0)
                            + at(x, y, 0, -1)
                            + at(x, y, 0, 1))
                            / 5.0;
                        sum - diff - 16.0 * (mean - local).abs()
                    };
                    assert_eq!(
                        got.get(x, y).to_bits(),
                        want.to_bits(),
                        "{name} kernel, {w}x{h}, radius {radius}, ({x}, {y})"
                    );
                }
            }
        }
    }

    /// Tolerance: none. The 2×2 box mean equals its definition pixel by pixel (the same sum
    /// order), on odd sizes (the last row and column dropped) with fractional values.
    #[test]
    fn halve_equals_the_box_mean() {
        let (w, h) = (71, 33);
        let img = Image::from_fn(w, h, |x, y| ((x * 29 + y * 53) % 97) as f32 * 1.3 + 0.1);
        let got = halve(&img);
        assert_eq!(got.size(), (35, 16));
        for y in 0..16 {
            for x in 0..35 {
                let p = |dx: usize, dy: usize| *img.get(2 * x + dx, 2 * y + dy);
                let want = ((p(0, 0) + p(1, 0)) + (p(0, 1) + p(1, 1))) * 0.25;
                assert_eq!(got.get(x, y).to_bits(), want.to_bits(), "({x}, {y})");
            }
        }
    }

    /// Tolerance: none. The lane-wise maximum equals the sequential `f32::max` fold from 0,
    /// for lengths with and without a remainder, all-negative data, and the maximum in the
    /// remainder.
    #[test]
    fn max_of_equals_the_fold() {
        for n in [0usize, 5, 8, 37, 64] {
            let data: Vec<f32> = (0..n).map(|i| ((i * 37) % 11) as f32 - 7.5).collect();
            let want = data.iter().copied().fold(0.0f32, f32::max);
            assert_eq!(max_of(&data).to_bits(), want.to_bits(), "n = {n}");
            let neg: Vec<f32> = data.iter().map(|v| -v.abs() - 1.0).collect();
            assert_eq!(max_of(&neg), 0.0, "n = {n}, all negative");
            let mut last = data.clone();
            if let Some(v) = last.last_mut() {
                *v = 1e6;
                assert_eq!(max_of(&last), 1e6, "n = {n}, maximum last");
            }
        }
    }

    /// Tolerance: none. The response and the box mean computed in buffers that earlier,
    /// larger images left behind full of other values (NaN) equal those computed in fresh
    /// buffers, the response's zero border included.
    #[test]
    fn reused_buffers_give_the_fresh_results() {
        let img = Image::from_fn(61, 47, |x, y| ((x * 29 + y * 53) % 97) as f32 * 1.3 + 0.1);
        SPARE.with(|s| s.borrow_mut().clear());
        let fresh_response = chess_response(&img, 5);
        SPARE.with(|s| s.borrow_mut().clear());
        let fresh_half = halve(&img);
        for _ in 0..SPARE_BUFFERS {
            recycle(Image::from_fn(90, 70, |_, _| f32::NAN));
        }
        let response = chess_response(&img, 5);
        for _ in 0..SPARE_BUFFERS {
            recycle(Image::from_fn(90, 70, |_, _| f32::NAN));
        }
        let half = halve(&img);
        for (got, want) in [(&response, &fresh_response), (&half, &fresh_half)] {
            assert_eq!(got.size(), want.size());
            for (i, (g, w)) in got.data().iter().zip(want.data()).enumerate() {
                assert_eq!(g.to_bits(), w.to_bits(), "value {i}");
            }
        }
        // The border the response leaves at 0 was written over with NaN before.
        assert_eq!(*response.get(0, 0), 0.0);
    }
}
