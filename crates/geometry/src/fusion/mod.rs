//! The CPU depth → colour fusion pipeline, stages H1–H8 of the lab handout.
//!
//! | stage | function | result |
//! | --- | --- | --- |
//! | H1 | [`backproject_cloud`] | depth pixels → points in the depth camera frame |
//! | H2 | [`project_cloud`] | `X_c = R·X_d + T`, projected with the colour distortion |
//! | H7 | [`register_depth`], [`zbuffer_from_samples`] | nearest surface per colour pixel |
//!
//! # GPU parity rules
//!
//! The per-pixel arithmetic lives in [`pixel`] as small `#[inline]` `f32` functions
//! ([`backproject_pixel`], [`transform_point`], [`project_color_point`], [`zbuffer_index`],
//! [`zbuffer_min`]); `fusion-gpu`'s WGSL mirrors them line by line. See [`pixel`] for the
//! exact rules: evaluation order, validity test, the rounding rule
//! `(floor(u + 0.5), floor(v + 0.5))` and the z-buffer's empty value [`ZBUFFER_EMPTY`].

pub mod pixel;
mod register;

pub use pixel::{
    backproject_pixel, depth_ray_table, project_color_point, project_point, register_pixel, transform_point,
    zbuffer_index, zbuffer_min, ColorProjection, ZBUFFER_EMPTY,
};
pub use register::{
    atomic_zbuffer_to_image, backproject_cloud, project_cloud, register_depth, register_depth_parallel,
    zbuffer_from_samples, ColorSample,
};
