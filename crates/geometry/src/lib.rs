//! Camera geometry, rig calibration files and the CPU fusion pipeline of kfuse.
//!
//! * [`fusion`]: the eight depth → colour stages H1–H8 and their one-call entry point
//!   [`fusion::run`].
//! * `synth` (feature `synth`): analytic synthetic scenes rendered through a rig, with the
//!   ground truths the fusion tests are checked against.
//! * `testdata` (feature `testdata`): where every crate's tests find `../shared/data` (and when
//!   they skip).
//!
//! # Conventions (the same as `DESIGN.md`; every module of this crate follows them)
//!
//! * **Pixels** are 0-based and integer coordinates are pixel *centres* (OpenCV and Bouguet
//!   agree). Pixel `(u, v)` = (column, row); row 0 is the top of the image.
//! * **Camera frame**: x right, y down, z forward (optical axis). The depth camera's frame is
//!   the rig's reference frame.
//! * **Poses** are named `a_from_b`: `color_from_depth` maps a point of the depth camera's
//!   frame into the colour camera's frame, `X_color = R · X_depth + T` (Bouguet's stereo R, T).
//! * **Units**: metres; `f64` for calibration, `f32` per pixel. Kinect millimetres are
//!   converted by importers.
//! * **Depth kinds**: `z` (distance along the optical axis, Kinect) or `range` (distance to the
//!   optical centre). See [`DepthKind`].
//! * **Distortion**: Brown–Conrady `k1, k2, p1, p2, k3` in OpenCV's order and formula.
//! * **Invalid depth** is `0` (Kinect raw) or `NaN` (in memory, after import); both mean
//!   "no sample" and never produce a point at the origin.
#![deny(missing_docs)]

pub mod camera;
pub mod cloud;
pub mod depth_correction;
pub mod error;
pub mod fusion;
pub mod image;
pub mod multi_rig;
pub mod num_fmt;
pub mod pose;
pub mod rig;
#[cfg(any(test, feature = "synth"))]
pub mod synth;
#[cfg(any(test, feature = "testdata"))]
pub mod testdata;
pub mod timing;

pub use camera::{CameraModel, DepthKind, Distortion, Intrinsics};
pub use cloud::{Mesh, PointCloud};
pub use error::GeometryError;
pub use image::Image;
pub use multi_rig::{CameraRole, MultiRig, RigCamera};
pub use pose::RigidTransform;
pub use rig::Rig;
