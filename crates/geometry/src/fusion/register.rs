//! H1 back-projection and H2 projection into the colour camera as a point cloud and a sample
//! list (the stages' reference form, and what the z-buffer-off switch needs); H7 itself is
//! [`super::Registration`] (the `bench-variants` feature adds the older z-buffer variants in
//! `variants.rs`).

use super::pixel::{
    ColorProjection, ZBUFFER_EMPTY, backproject_pixel, project_point, zbuffer_index,
};
use crate::{Image, PointCloud};

/// One depth sample seen by the colour camera (H2): where it lands and how far it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColorSample {
    /// Colour pixel column (sub-pixel, distortion applied).
    pub u: f32,
    /// Colour pixel row.
    pub v: f32,
    /// Depth along the colour camera's optical axis, metres.
    pub z: f32,
    /// Index of the point in the H1 cloud.
    pub point: u32,
}

/// H1: every valid depth pixel as a 3D point in the depth camera's frame (row-major order),
/// and the row-major index of the pixel each point came from. Pixels without a sample
/// (`NaN`, `0`, negative, infinite) or without a ray (lens fold) give no point.
pub fn backproject_cloud(depth: &Image<f32>, rays: &[[f32; 3]]) -> (PointCloud, Vec<u32>) {
    let mut cloud = PointCloud::default();
    let mut pixels = Vec::new();
    for (i, (&value, &ray)) in depth.data().iter().zip(rays).enumerate() {
        if let Some(p) = backproject_pixel(ray, value)
            && p.iter().all(|c| c.is_finite())
        {
            cloud.points.push(p);
            pixels.push(i as u32);
        }
    }
    (cloud, pixels)
}

/// H2: the points that land on the colour image (by the rounding rule of
/// [`zbuffer_index`]) and lie in front of the colour camera.
pub fn project_cloud(points: &[[f32; 3]], proj: &ColorProjection) -> Vec<ColorSample> {
    points
        .iter()
        .enumerate()
        .filter_map(|(i, &p)| {
            let [u, v, z] = project_point(proj, p)?;
            zbuffer_index(u, v, proj.width, proj.height)?;
            Some(ColorSample { u, v, z, point: i as u32 })
        })
        .collect()
}

/// H7 without the depth test (the viewer's z-buffer-off switch): in sample order, the first
/// sample on a colour pixel stays. Empty pixels hold [`ZBUFFER_EMPTY`], like the z-buffer.
/// Where a foreground object and the background hidden behind it (seen by the depth camera,
/// not by the colour camera) land on one colour pixel, the background can win. (Keeping the
/// *last* sample instead would hide the effect on a Kinect: with the colour camera at −x,
/// row-major order is occlusion-compatible and reproduces the z-buffer exactly.)
pub fn first_write_wins(samples: &[ColorSample], width: usize, height: usize) -> Image<f32> {
    let mut img = Image::filled(width, height, ZBUFFER_EMPTY);
    let data = img.data_mut();
    for s in samples {
        if let Some(i) = zbuffer_index(s.u, s.v, width as u32, height as u32)
            && data[i].to_bits() == ZBUFFER_EMPTY.to_bits()
        {
            data[i] = s.z;
        }
    }
    img
}
