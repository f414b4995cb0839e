//! Camera calibration for kfuse: checkerboard detection, Zhang initialisation,
//! Levenberg–Marquardt refinement of one or two cameras, parameter uncertainty, outlier
//! rejection, and calibration files.
//!
//! # Conventions (as `DESIGN.md` and the `geometry` crate)
//!
//! * **Pixels** are 0-based, integer coordinates are pixel centres (OpenCV, Bouguet).
//!   Bouguet's MATLAB files are converted by the importer.
//! * **Camera frame**: x right, y down, z forward. The depth/IR camera is the rig reference.
//! * **Poses** are named `a_from_b`: `camera_from_board`, `color_from_depth`
//!   (`X_color = R·X_depth + T`, Bouguet's stereo R, T).
//! * **Units**: metres for lengths (board squares, translations); pixels for intrinsics.
//! * **Distortion**: OpenCV's 5-coefficient Brown–Conrady model `k1, k2, p1, p2, k3`,
//!   evaluated by `geometry::Distortion` (never re-implemented here).
//! * **Board frame**: origin at the first inner corner, corner `k` at
//!   `(s·(k mod cols), s·(k div cols), 0)`; see [`Board`].
//! * **Uncertainty**: 1σ, `sqrt(diag((JᵀJ)⁻¹)·σ²)`, `σ² = Σ|e|²/(2·N_corners − N_params)`
//!   (OpenCV's `calibrateCameraExtended`; Bouguet's `*_error` are 3σ).
#![deny(missing_docs)]

mod board;
pub mod bouguet;
mod bundle;
pub mod depth;
pub mod detect;
mod error;
pub mod files;
pub mod holdout;
pub mod io;
pub mod mono;
pub mod multi;
pub mod pipeline;
pub mod stereo;
pub mod timing;
pub mod undistort;
pub mod zhang;

pub use board::{Board, Corner, ViewCorners};
pub use error::CalibError;
pub use mono::{CalibFlags, IntrinsicsStd, MonoCalibration, calibrate_mono};
pub use stereo::{StereoCalibration, StereoOptions, calibrate_stereo};
