//! H4 textured mesh, H5 removal of stretched faces.
//!
//! | function | what |
//! | --- | --- |
//! | [`mesh_on_depth_grid`] | H4 where the data is: one vertex per depth sample, faces from the depth pixel grid, texture coordinates from H2's projection (the default, [`super::MeshSource::DepthGrid`]) |
//! | [`mesh_from_depth`] | H4 on a grid of colour pixels of a resampled colour-frame depth (H3 nearest / linear / filled) |
//! | [`StretchTest`], [`remove_edge_faces`] | H5 with either rule of [`EdgeFaceRule`] |
//! | [`is_stretched`], [`remove_stretched_faces`] | H5, the handout's literal face-normal rule |
//!
//! Why two H4s: a colour-grid mesh of nearest-filled depth is a staircase (each depth sample
//! covers a plateau of ~3×3 colour pixels), and on real depth its risers and the sensor's
//! noise make the handout's normal test remove most of a surface (62 % of a Kinect frame of a
//! person before a wall). On the depth grid every vertex is a measurement and neighbours are
//! one sample apart, so H5 can judge a depth step against what one sample of a tilted,
//! noisy surface can give.

use serde::Serialize;

use super::register::ColorSample;
use crate::{CameraModel, Image, Mesh, RigidTransform};

/// H4: a triangle mesh on a grid of every `step`-th colour pixel of `depth` (colour-frame
/// `z`, NaN = none). Vertices are the 3D points (colour camera frame, metres) of the valid
/// grid pixels, back-projected through `camera` (distortion undone); texture coordinates
/// point into `color` (OBJ convention, see [`Mesh::uvs`]) and vertex colours are copied
/// from it. Each grid cell whose corners are valid gives two triangles `(a, c, b)` and
/// `(b, c, d)` (`a` top-left, `b` top-right, `c` bottom-left, `d` bottom-right),
/// counter-clockwise seen from the camera; a cell with three valid corners gives one.
pub fn mesh_from_depth(
    depth: &Image<f32>,
    camera: &CameraModel,
    color: &Image<[u8; 3]>,
    step: usize,
) -> Mesh {
    let step = step.max(1);
    let (w, h) = depth.size();
    let gw = w.div_ceil(step);
    let gh = h.div_ceil(step);
    let fold = camera.distortion.fold_radius();
    let mut index = vec![u32::MAX; gw * gh];
    let mut mesh = Mesh::default();
    for gy in 0..gh {
        for gx in 0..gw {
            let (x, y) = (gx * step, gy * step);
            let z = *depth.get(x, y);
            if !super::pixel::is_sample(z) {
                continue;
            }
            let d = camera.intrinsics.from_pixel(x as f64, y as f64);
            let Some(n) = camera.distortion.undistort_within(d.x, d.y, fold) else { continue };
            index[gy * gw + gx] = mesh.vertices.len() as u32;
            mesh.vertices.push([n.x as f32 * z, n.y as f32 * z, z]);
            let (cw, ch) = color.size();
            mesh.uvs.push([(x as f32 + 0.5) / cw as f32, 1.0 - (y as f32 + 0.5) / ch as f32]);
            mesh.colors.push(*color.get(x.min(cw - 1), y.min(ch - 1)));
        }
    }
    grid_faces(&index, gw, gh, &mesh.vertices, false, &mut mesh.faces);
    mesh
}

/// The triangles of a vertex grid (`index[y * gw + x]`, `u32::MAX` = no vertex): a cell with
/// four vertices gives two, split along `a–d` or `b–c` (`a` top-left, `b` top-right, `c`
/// bottom-left, `d` bottom-right); a cell with three gives one; all counter-clockwise seen
/// from the camera. `adaptive`: split along the diagonal whose ends differ less in depth (a
/// cell across a depth edge then keeps one triangle on the near surface instead of two
/// slivers across it); otherwise always `(a, c, b)`, `(b, c, d)`.
fn grid_faces(
    index: &[u32],
    gw: usize,
    gh: usize,
    vertices: &[[f32; 3]],
    adaptive: bool,
    faces: &mut Vec<[u32; 3]>,
) {
    let valid = |i: u32| i != u32::MAX;
    let dz = |i: u32, j: u32| (vertices[i as usize][2] - vertices[j as usize][2]).abs();
    for gy in 0..gh.saturating_sub(1) {
        for gx in 0..gw.saturating_sub(1) {
            let a = index[gy * gw + gx];
            let b = index[gy * gw + gx + 1];
            let c = index[(gy + 1) * gw + gx];
            let d = index[(gy + 1) * gw + gx + 1];
            match (valid(a), valid(b), valid(c), valid(d)) {
                (true, true, true, true) => {
                    if adaptive && dz(a, d) < dz(b, c) {
                        faces.push([a, c, d]);
                        faces.push([a, d, b]);
                    } else {
                        faces.push([a, c, b]);
                        faces.push([b, c, d]);
                    }
                }
                (true, true, true, false) => faces.push([a, c, b]),
                (false, true, true, true) => faces.push([b, c, d]),
                (true, false, true, true) => faces.push([a, c, d]),
                (true, true, false, true) => faces.push([a, d, b]),
                _ => {}
            }
        }
    }
}

/// Vertex colour of a depth-grid mesh vertex the colour camera does not see (H6 found it
/// hidden behind a nearer surface): neutral grey, so the occluder's colour is not painted
/// onto it.
pub const HIDDEN_VERTEX_GREY: [u8; 3] = [128, 128, 128];

/// H4 where the data is: one vertex per H2 sample (a depth pixel whose point lands on the
/// colour image), faces between neighbouring depth pixels, texture coordinates from the
/// sample's projection `(u, v)` into the `color_size` colour image (OBJ convention, see
/// [`Mesh::uvs`]). Vertices are the H1 `points` moved into the colour camera's frame by
/// `color_from_depth` (metres), like [`mesh_from_depth`]'s. Vertex colours are H6's
/// (`color_on_depth` where `color_valid`, depth-grid images), [`HIDDEN_VERTEX_GREY`] where H6
/// does not trust the colour (the point is hidden from the colour camera).
///
/// `samples[k].point` indexes `points` and `cloud_pixels` (the row-major depth pixel of each
/// point, `depth_width × depth_height` grid). Cells split along their flatter diagonal (see
/// the private `grid_faces`). Returns the mesh and the depth pixel of every vertex.
#[allow(clippy::too_many_arguments)]
pub fn mesh_on_depth_grid(
    depth_width: usize,
    depth_height: usize,
    points: &[[f32; 3]],
    cloud_pixels: &[u32],
    samples: &[ColorSample],
    color_from_depth: &RigidTransform,
    color_size: (usize, usize),
    color_on_depth: &Image<[u8; 3]>,
    color_valid: &Image<bool>,
) -> (Mesh, Vec<u32>) {
    let n = depth_width * depth_height;
    let mut index = vec![u32::MAX; n];
    // One sample per depth pixel at most; samples come in any order (engines differ), the
    // vertex order is the depth pixels' row-major order so the mesh is the same on all.
    let mut sample_of = vec![u32::MAX; n];
    for (k, s) in samples.iter().enumerate() {
        if let Some(&p) = cloud_pixels.get(s.point as usize)
            && (p as usize) < n
        {
            sample_of[p as usize] = k as u32;
        }
    }
    let (cw, ch) = color_size;
    let mut mesh = Mesh::default();
    let mut vertex_pixels = Vec::new();
    for (pixel, &k) in sample_of.iter().enumerate() {
        if k == u32::MAX {
            continue;
        }
        let s = samples[k as usize];
        let p = points[s.point as usize];
        let q =
            color_from_depth.apply(&nalgebra::Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64));
        if !(q.z > 0.0) {
            continue;
        }
        index[pixel] = mesh.vertices.len() as u32;
        vertex_pixels.push(pixel as u32);
        mesh.vertices.push([q.x as f32, q.y as f32, q.z as f32]);
        mesh.uvs.push([(s.u + 0.5) / cw as f32, 1.0 - (s.v + 0.5) / ch as f32]);
        let seen = color_valid.data().get(pixel).copied().unwrap_or(false);
        mesh.colors.push(match color_on_depth.data().get(pixel) {
            Some(c) if seen => *c,
            _ => HIDDEN_VERTEX_GREY,
        });
    }
    grid_faces(&index, depth_width, depth_height, &mesh.vertices, true, &mut mesh.faces);
    (mesh, vertex_pixels)
}

/// The face normal `(p1 - p0) × (p2 - p0)` (not normalised).
#[inline]
pub fn face_normal(p0: [f32; 3], p1: [f32; 3], p2: [f32; 3]) -> [f32; 3] {
    let a = [p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]];
    let b = [p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]];
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// H5's test for one face: stretched when the in-plane (x, y) component of its normal is
/// larger than `ratio` times its depth (z) component, i.e. the face is tilted more than
/// `atan(ratio)` away from facing the camera. `ratio = 1` is the handout's "in-plane
/// component larger than the depth component" (45°).
#[inline]
pub fn is_stretched(p0: [f32; 3], p1: [f32; 3], p2: [f32; 3], ratio: f32) -> bool {
    let n = face_normal(p0, p1, p2);
    let inplane2 = n[0] * n[0] + n[1] * n[1];
    let depth2 = n[2] * n[2] * ratio * ratio;
    inplane2 > depth2
}

/// H5: a copy of `mesh` without its stretched faces ([`is_stretched`]); vertices are kept.
pub fn remove_stretched_faces(mesh: &Mesh, ratio: f32) -> Mesh {
    remove_edge_faces(
        mesh,
        &StretchTest { rule: EdgeFaceRule::Normal, ratio, depth_focal_px: 1.0, noise_1m_m: 0.0 },
    )
}

/// Depth noise σ of a Kinect at 1 m, metres: ≈ 1.5 mm, growing with the square of the
/// distance (the structured-light/ToF noise model of Khoshelham & Elberink 2012 that issue 13
/// states for the Kinect v2: σ(z) = σ₁·z²). H5's default noise allowance.
pub const KINECT_NOISE_1M_M: f32 = 0.0015;

/// How many standard deviations of the depth *difference* of two neighbouring samples
/// (`√2·σ(z)`) H5's sample-scale rule forgives: 3 → a face on a surface that faces the camera
/// is removed by noise alone with probability < 3 × 0.27 % (three edges), while a jump of a
/// few centimetres at 2 m still exceeds it.
pub const NOISE_ALLOWANCE_SIGMAS: f32 = 3.0;

/// Which test H5 applies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum EdgeFaceRule {
    /// Per edge, at the scale of the depth samples, with a noise allowance (the default):
    /// an edge is stretched when its ends differ in depth by more than `ratio` times its
    /// lateral extent (at least one depth sample, `z / f_depth`) plus
    /// [`NOISE_ALLOWANCE_SIGMAS`]`·√2·σ(z)` with `σ(z) = σ₁·z²`; a face with a stretched
    /// edge goes. Without noise (`σ₁ = 0`) and on a flat face this is the handout's tilt
    /// limit `atan(ratio)`; unlike the normal it tolerates one sample's step (nearest-fill
    /// staircases) and the sensor's noise, and still catches a flying pixel between two
    /// surfaces (its edges to both are long in depth).
    #[default]
    SampleScale,
    /// The handout's literal rule: the face normal's in-plane part exceeds `ratio` times its
    /// depth part ([`is_stretched`]).
    Normal,
}

/// One H5 test with its scale (see [`EdgeFaceRule`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StretchTest {
    /// The rule.
    pub rule: EdgeFaceRule,
    /// Tilt limit as `tan(angle)`: 1 = 45° (the handout's).
    pub ratio: f32,
    /// Focal length of the depth camera, pixels: one depth sample spans `z / depth_focal_px`
    /// metres at depth `z`.
    pub depth_focal_px: f32,
    /// σ₁, the depth noise at 1 m, metres ([`KINECT_NOISE_1M_M`]; 0 for noise-free data).
    pub noise_1m_m: f32,
}

impl StretchTest {
    /// Whether the face `p0, p1, p2` (camera frame, metres, z > 0) is stretched.
    #[inline]
    pub fn is_stretched(&self, p0: [f32; 3], p1: [f32; 3], p2: [f32; 3]) -> bool {
        match self.rule {
            EdgeFaceRule::Normal => is_stretched(p0, p1, p2, self.ratio),
            EdgeFaceRule::SampleScale => {
                self.edge_stretched(p0, p1)
                    || self.edge_stretched(p1, p2)
                    || self.edge_stretched(p2, p0)
            }
        }
    }

    /// The sample-scale test of one edge (see [`EdgeFaceRule::SampleScale`]).
    #[inline]
    pub fn edge_stretched(&self, p: [f32; 3], q: [f32; 3]) -> bool {
        let z = 0.5 * (p[2] + q[2]);
        // Lateral extent: the angle between the two rays times the mean depth.
        let (dx, dy) = (p[0] / p[2] - q[0] / q[2], p[1] / p[2] - q[1] / q[2]);
        let lateral = z * (dx * dx + dy * dy).sqrt();
        let sample = z / self.depth_focal_px;
        let sigma = self.noise_1m_m * z * z;
        let allowed = self.ratio * lateral.max(sample)
            + NOISE_ALLOWANCE_SIGMAS * std::f32::consts::SQRT_2 * sigma;
        // NaN (a vertex at z = 0) is stretched.
        !((p[2] - q[2]).abs() <= allowed)
    }
}

/// H5: a copy of `mesh` without the faces `test` finds stretched; vertices are kept.
pub fn remove_edge_faces(mesh: &Mesh, test: &StretchTest) -> Mesh {
    let v = &mesh.vertices;
    let faces = mesh
        .faces
        .iter()
        .copied()
        .filter(|f| !test.is_stretched(v[f[0] as usize], v[f[1] as usize], v[f[2] as usize]))
        .collect();
    Mesh { faces, ..mesh.clone() }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test(rule: EdgeFaceRule, noise: f32) -> StretchTest {
        StretchTest { rule, ratio: 1.0, depth_focal_px: 365.0, noise_1m_m: noise }
    }

    #[test]
    fn sample_scale_rule_forgives_one_sample_steps_and_noise_but_not_jumps() {
        let t = test(EdgeFaceRule::SampleScale, KINECT_NOISE_1M_M);
        // Two neighbouring depth samples at 2 m: 5.5 mm apart laterally.
        let s = 2.0 / 365.0;
        let p = [0.0, 0.0, 2.0];
        // Allowed: 1 · 5.48 mm + 3 · √2 · 1.5 mm · 4 = 30.9 mm.
        assert!(!t.edge_stretched(p, [s, 0.0, 2.030]));
        assert!(t.edge_stretched(p, [s, 0.0, 2.032]));
        // A jump to the wall 1 m behind is stretched by either rule.
        assert!(t.edge_stretched(p, [s, 0.0, 3.0]));
        assert!(is_stretched(p, [s, 0.0, 3.0], [0.0, s, 2.0], 1.0));
        // One sample's step on a colour grid 1 colour pixel wide (a nearest-fill riser):
        // lateral 1/1060 of z, floored to one depth sample, so a 45° surface's step stays.
        let c = 2.0 / 1060.0;
        let step = [c, 0.0, 2.0 + s];
        assert!(!t.edge_stretched(p, step));
        // The handout's normal test on that riser (with the next grid vertex beside it):
        // tilted ~70°, removed.
        assert!(is_stretched(p, step, [0.0, c, 2.0], 1.0));
        // Without noise allowance the 10 mm step of the first case is a 61° edge: stretched.
        let quiet = test(EdgeFaceRule::SampleScale, 0.0);
        assert!(quiet.edge_stretched(p, [s, 0.0, 2.010]));
        assert!(!quiet.edge_stretched(p, [s, 0.0, 2.005]));
    }

    #[test]
    fn depth_grid_mesh_has_one_vertex_per_sample_and_uvs_from_the_projection() {
        // A 3×2 depth grid, one pixel without a sample (index 4).
        let points: Vec<[f32; 3]> = vec![
            [0.0, 0.0, 1.0],
            [0.01, 0.0, 1.0],
            [0.02, 0.0, 1.0],
            [0.0, 0.01, 1.0],
            [0.02, 0.01, 1.0],
        ];
        let cloud_pixels = vec![0, 1, 2, 3, 5];
        // Samples in reverse order (an engine may order them differently).
        let samples: Vec<ColorSample> = (0..5u32)
            .rev()
            .map(|k| ColorSample { u: 10.0 + k as f32, v: 5.0, z: 1.0, point: k })
            .collect();
        let h6 = Image::from_fn(3, 2, |x, y| [x as u8 * 50, y as u8, 7]);
        let valid = Image::from_fn(3, 2, |x, _| x != 2);
        let (mesh, pixels) = mesh_on_depth_grid(
            3,
            2,
            &points,
            &cloud_pixels,
            &samples,
            &RigidTransform::identity(),
            (40, 20),
            &h6,
            &valid,
        );
        assert_eq!(pixels, vec![0, 1, 2, 3, 5]);
        assert_eq!(mesh.vertices[4], [0.02, 0.01, 1.0]);
        // Vertex 1 came from the sample with u = 11: uv = (11.5 / 40, 1 - 5.5 / 20).
        assert_eq!(mesh.uvs[1], [11.5 / 40.0, 1.0 - 5.5 / 20.0]);
        assert_eq!(mesh.colors[1], [50, 0, 7]);
        // Depth pixel 2 is hidden from the colour camera (H6 invalid): grey.
        assert_eq!(mesh.colors[2], HIDDEN_VERTEX_GREY);
        // Both cells miss depth pixel 4: one triangle each.
        assert_eq!(mesh.faces, vec![[0, 3, 1], [1, 4, 2]]);
    }
}
