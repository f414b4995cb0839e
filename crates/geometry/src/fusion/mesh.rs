//! H4 textured mesh from a colour-frame depth image, H5 removal of stretched faces.

use crate::{CameraModel, Image, Mesh};

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
            if !(z > 0.0 && z < f32::INFINITY) {
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
    for gy in 0..gh.saturating_sub(1) {
        for gx in 0..gw.saturating_sub(1) {
            let a = index[gy * gw + gx];
            let b = index[gy * gw + gx + 1];
            let c = index[(gy + 1) * gw + gx];
            let d = index[(gy + 1) * gw + gx + 1];
            let valid = |i: u32| i != u32::MAX;
            match (valid(a), valid(b), valid(c), valid(d)) {
                (true, true, true, true) => {
                    mesh.faces.push([a, c, b]);
                    mesh.faces.push([b, c, d]);
                }
                (true, true, true, false) => mesh.faces.push([a, c, b]),
                (false, true, true, true) => mesh.faces.push([b, c, d]),
                (true, false, true, true) => mesh.faces.push([a, c, d]),
                (true, true, false, true) => mesh.faces.push([a, d, b]),
                _ => {}
            }
        }
    }
    mesh
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
    let v = &mesh.vertices;
    let faces = mesh
        .faces
        .iter()
        .copied()
        .filter(|f| !is_stretched(v[f[0] as usize], v[f[1] as usize], v[f[2] as usize], ratio))
        .collect();
    Mesh { faces, ..mesh.clone() }
}
