//! H3: the irregular `(u, v, z)` samples resampled onto the colour pixel grid.

use rayon::prelude::*;
use spade::{DelaunayTriangulation, HasPosition, Point2, Triangulation};

use super::pixel::{ZBUFFER_EMPTY, zbuffer_index};
use super::register::ColorSample;
use crate::{GeometryError, Image};

/// The pixel offsets `(dx, dy)` with `dx² + dy² <= radius²`, sorted by `dx² + dy²`, then `dy`,
/// then `dx` (the order in which [`nearest_fill`] looks; a WGSL twin uses the same table).
pub fn disc_offsets(radius_px: f32) -> Vec<(i32, i32, i32)> {
    let r = radius_px.max(0.0);
    let k = r.floor() as i32;
    let r2 = r * r;
    let mut offsets = Vec::new();
    for dy in -k..=k {
        for dx in -k..=k {
            let d2 = dx * dx + dy * dy;
            if d2 as f32 <= r2 {
                offsets.push((dx, dy, d2));
            }
        }
    }
    offsets.sort_by_key(|&(dx, dy, d2)| (d2, dy, dx));
    offsets
}

/// H3, nearest neighbour, on the z-buffer (H7) image: every colour pixel takes the value of
/// the nearest z-buffered pixel within `radius_px`, *among those on the nearest surface*.
///
/// Per pixel, in two passes over the [`disc_offsets`] of `radius_px`:
/// 1. `zmin` = the smallest non-empty z-buffer value in the disc (none: the pixel stays
///    empty, [`ZBUFFER_EMPTY`]);
/// 2. the result is the value of the first offset in disc order whose value is
///    `<= zmin * (1 + depth_jump)`.
///
/// Emptiness is tested on the bits (`is_nan` here; `bits == 0xFFFF_FFFF` in WGSL, where NaN
/// comparisons are not reliable).
///
/// Pass 1 keeps hidden background samples that fell between the samples of a nearer
/// surface (the colour camera cannot see them) from winning; pass 2 keeps the edge of the
/// nearer surface where it is (no dilation beyond half the sample spacing).
pub fn nearest_fill(zbuffer: &Image<f32>, radius_px: f32, depth_jump: f32) -> Image<f32> {
    let (w, h) = zbuffer.size();
    let fill = NearestFill::new(zbuffer, radius_px, depth_jump);
    let mut out = Image::filled(w, h, ZBUFFER_EMPTY);
    out.data_mut().par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            *o = fill.at_xy(x, y);
        }
    });
    out
}

/// [`nearest_fill`] one pixel at a time, for a caller that reads it at few pixels: H6's
/// occlusion test reads it only where the depth samples land (at most one per depth pixel,
/// ~200 000 of a 1920 × 1080 colour grid), so filling the whole grid first spent ten times
/// the work (the colour-on-depth stage of a recording took ~200 ms a frame). [`NearestFill::at`]
/// equals `nearest_fill(..)`'s value at that pixel, bit for bit: [`nearest_fill`] is made of it.
pub struct NearestFill<'a> {
    src: &'a [f32],
    width: usize,
    height: usize,
    offsets: Vec<(i32, i32, i32)>,
    linear: Vec<isize>,
    reach: usize,
    depth_jump: f32,
}

impl<'a> NearestFill<'a> {
    /// The fill of `zbuffer` with `radius_px` and `depth_jump` (see [`nearest_fill`]).
    pub fn new(zbuffer: &'a Image<f32>, radius_px: f32, depth_jump: f32) -> Self {
        let (width, height) = zbuffer.size();
        let offsets = disc_offsets(radius_px);
        let reach = offsets.iter().map(|o| o.0.abs().max(o.1.abs())).max().unwrap_or(0) as usize;
        let linear =
            offsets.iter().map(|&(dx, dy, _)| dy as isize * width as isize + dx as isize).collect();
        Self { src: zbuffer.data(), width, height, offsets, linear, reach, depth_jump }
    }

    /// The fill at pixel `(x, y)`, which must be inside the image.
    #[inline]
    pub fn at_xy(&self, x: usize, y: usize) -> f32 {
        let (w, h, k) = (self.width, self.height, self.reach);
        if y >= k && y + k < h && x >= k && x + k < w {
            nearest_fill_interior(self.src, y * w + x, &self.linear, self.depth_jump)
        } else {
            nearest_fill_pixel(self.src, w, h, x as i32, y as i32, &self.offsets, self.depth_jump)
        }
    }

    /// The fill at row-major pixel index `j`, which must be inside the image.
    #[inline]
    pub fn at(&self, j: usize) -> f32 {
        self.at_xy(j % self.width, j / self.width)
    }
}

/// [`nearest_fill_pixel`] for a pixel whose whole disc is inside the image (no bounds
/// tests; `linear` = the disc offsets as row-major index offsets). Same result.
#[inline]
fn nearest_fill_interior(src: &[f32], centre: usize, linear: &[isize], depth_jump: f32) -> f32 {
    let mut zmin = ZBUFFER_EMPTY;
    for &d in linear {
        let z = src[centre.wrapping_add_signed(d)];
        if !(zmin <= z) && !z.is_nan() {
            zmin = z;
        }
    }
    if zmin.is_nan() {
        return ZBUFFER_EMPTY;
    }
    let limit = zmin * (1.0 + depth_jump);
    for &d in linear {
        let z = src[centre.wrapping_add_signed(d)];
        if z <= limit {
            return z;
        }
    }
    ZBUFFER_EMPTY
}

/// One pixel of [`nearest_fill`].
#[inline]
pub fn nearest_fill_pixel(
    src: &[f32],
    w: usize,
    h: usize,
    x: i32,
    y: i32,
    offsets: &[(i32, i32, i32)],
    depth_jump: f32,
) -> f32 {
    let mut zmin = ZBUFFER_EMPTY;
    for &(dx, dy, _) in offsets {
        let (sx, sy) = (x + dx, y + dy);
        if sx >= 0 && sy >= 0 && (sx as usize) < w && (sy as usize) < h {
            let z = src[sy as usize * w + sx as usize];
            if !(zmin <= z) && !z.is_nan() {
                zmin = z;
            }
        }
    }
    if zmin.is_nan() {
        return ZBUFFER_EMPTY;
    }
    let limit = zmin * (1.0 + depth_jump);
    for &(dx, dy, _) in offsets {
        let (sx, sy) = (x + dx, y + dy);
        if sx >= 0 && sy >= 0 && (sx as usize) < w && (sy as usize) < h {
            let z = src[sy as usize * w + sx as usize];
            if z <= limit {
                return z;
            }
        }
    }
    ZBUFFER_EMPTY
}

/// A Delaunay vertex: sub-pixel colour position and depth.
struct Vertex {
    p: Point2<f64>,
    z: f32,
}

impl HasPosition for Vertex {
    type Scalar = f64;
    fn position(&self) -> Point2<f64> {
        self.p
    }
}

/// Counts of the linear resampling.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct LinearStats {
    /// Samples triangulated (the z-buffer winners).
    pub vertices: usize,
    /// Delaunay triangles.
    pub triangles: usize,
    /// Triangles rasterised (not too long, not across a depth jump).
    pub triangles_used: usize,
    /// Pixels that received a value.
    pub pixels: usize,
}

/// H3, Delaunay-linear: the samples that won the z-buffer (`zbuffer` = H7 of `samples`) are
/// triangulated in the colour image plane (spade) and each triangle is rasterised with
/// linear interpolation of `z` at the pixel centres inside it (edges included).
///
/// No value is invented outside the samples' convex hull (only triangles are filled), nor
/// across holes or depth edges: triangles with an edge longer than `max_edge_px` or whose
/// depths differ by more than `depth_jump` (relative to the smallest) are skipped.
pub fn linear_resample(
    samples: &[ColorSample],
    zbuffer: &Image<f32>,
    max_edge_px: f32,
    depth_jump: f32,
) -> Result<(Image<f32>, LinearStats), GeometryError> {
    let (w, h) = zbuffer.size();
    let zb = zbuffer.data();
    let vertices: Vec<Vertex> = samples
        .iter()
        .filter(|s| zbuffer_index(s.u, s.v, w as u32, h as u32).is_some_and(|i| zb[i] == s.z))
        .map(|s| Vertex { p: Point2::new(s.u as f64, s.v as f64), z: s.z })
        .collect();
    let mut stats = LinearStats { vertices: vertices.len(), ..LinearStats::default() };
    let mut out = Image::filled(w, h, ZBUFFER_EMPTY);
    if vertices.len() < 3 {
        return Ok((out, stats));
    }
    let tri = DelaunayTriangulation::<Vertex>::bulk_load(vertices).map_err(|e| {
        GeometryError::InvalidInput(format!(
            "Delaunay triangulation of the colour-frame samples failed: {e:?}"
        ))
    })?;
    stats.triangles = tri.num_inner_faces();
    let max_edge2 = (max_edge_px as f64) * (max_edge_px as f64);
    let data = out.data_mut();
    for face in tri.inner_faces() {
        let [a, b, c] = face.vertices();
        let (pa, pb, pc) = (a.position(), b.position(), c.position());
        let (za, zb_, zc) = (a.data().z, b.data().z, c.data().z);
        let d2 = |p: Point2<f64>, q: Point2<f64>| (p.x - q.x).powi(2) + (p.y - q.y).powi(2);
        if d2(pa, pb) > max_edge2 || d2(pb, pc) > max_edge2 || d2(pc, pa) > max_edge2 {
            continue;
        }
        let zlo = za.min(zb_).min(zc);
        let zhi = za.max(zb_).max(zc);
        if zhi > zlo * (1.0 + depth_jump) {
            continue;
        }
        stats.triangles_used += 1;
        let den = (pb.y - pc.y) * (pa.x - pc.x) + (pc.x - pb.x) * (pa.y - pc.y);
        if den == 0.0 {
            continue;
        }
        let x0 = pa.x.min(pb.x).min(pc.x).ceil().max(0.0) as usize;
        let x1 = pa.x.max(pb.x).max(pc.x).floor().min(w as f64 - 1.0);
        let y0 = pa.y.min(pb.y).min(pc.y).ceil().max(0.0) as usize;
        let y1 = pa.y.max(pb.y).max(pc.y).floor().min(h as f64 - 1.0);
        if x1 < 0.0 || y1 < 0.0 {
            continue;
        }
        // Barycentric tolerance: pixel centres on a shared edge belong to both triangles.
        const EDGE_EPS: f64 = 1e-9;
        for y in y0..=y1 as usize {
            for x in x0..=x1 as usize {
                let (px, py) = (x as f64, y as f64);
                let l1 = ((pb.y - pc.y) * (px - pc.x) + (pc.x - pb.x) * (py - pc.y)) / den;
                let l2 = ((pc.y - pa.y) * (px - pc.x) + (pa.x - pc.x) * (py - pc.y)) / den;
                let l3 = 1.0 - l1 - l2;
                if l1 >= -EDGE_EPS && l2 >= -EDGE_EPS && l3 >= -EDGE_EPS {
                    let z = l1 * za as f64 + l2 * zb_ as f64 + l3 * zc as f64;
                    let slot = &mut data[y * w + x];
                    if slot.is_nan() {
                        stats.pixels += 1;
                    }
                    *slot = z as f32;
                }
            }
        }
    }
    Ok((out, stats))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fill of one pixel from its definition alone (no offsets table, no interior path):
    /// the disc's smallest non-empty z, then the first value within the depth jump of it in
    /// order of distance², then dy, then dx.
    fn reference(src: &Image<f32>, x: i32, y: i32, radius: f32, jump: f32) -> f32 {
        let (w, h) = src.size();
        let k = radius.floor() as i32;
        let mut disc: Vec<(i32, i32, i32)> = Vec::new();
        for dy in -k..=k {
            for dx in -k..=k {
                let d2 = dx * dx + dy * dy;
                let (sx, sy) = (x + dx, y + dy);
                if d2 as f32 <= radius * radius
                    && (0..w as i32).contains(&sx)
                    && (0..h as i32).contains(&sy)
                {
                    disc.push((d2, dy, dx));
                }
            }
        }
        disc.sort();
        let value =
            |&(_, dy, dx): &(i32, i32, i32)| src.data()[((y + dy) * w as i32 + x + dx) as usize];
        let Some(zmin) = disc.iter().map(value).filter(|z| !z.is_nan()).reduce(f32::min) else {
            return ZBUFFER_EMPTY;
        };
        disc.iter().map(value).find(|&z| z <= zmin * (1.0 + jump)).unwrap_or(ZBUFFER_EMPTY)
    }

    /// `NearestFill::at` (what H6 reads) equals the whole-grid `nearest_fill` and the
    /// definition at every pixel of a z-buffer with sparse samples of two surfaces (a near
    /// square over a far slope), holes and the image's borders, bit for bit.
    #[test]
    fn nearest_fill_at_a_pixel_is_the_whole_fill_and_the_definition() {
        let (w, h) = (61usize, 37usize);
        let z = Image::from_fn(w, h, |x, y| {
            // Samples on every other pixel of a lattice, a few holes.
            if (x * 7 + y * 3) % 3 == 0 || (x + 2 * y) % 11 == 0 {
                return ZBUFFER_EMPTY;
            }
            if (20..40).contains(&x) && (10..25).contains(&y) {
                1.0 + 0.001 * x as f32
            } else {
                2.0 + 0.01 * y as f32
            }
        });
        for (radius, jump) in [(0.0, 0.05), (1.5, 0.05), (2.9, 0.02), (4.0, 0.3)] {
            let whole = nearest_fill(&z, radius, jump);
            let at = NearestFill::new(&z, radius, jump);
            for y in 0..h {
                for x in 0..w {
                    let j = y * w + x;
                    let want = reference(&z, x as i32, y as i32, radius, jump);
                    assert_eq!(at.at(j).to_bits(), want.to_bits(), "({x}, {y}) r {radius}");
                    assert_eq!(whole.data()[j].to_bits(), want.to_bits(), "({x}, {y}) r {radius}");
                }
            }
        }
    }
}
