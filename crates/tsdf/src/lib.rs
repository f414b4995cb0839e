//! Volumetric fusion: several depth images (several Kinects of a rig, or many frames of one)
//! into one truncated signed distance field (TSDF), and one coloured mesh out of it.
//!
//! * [`TsdfVolume`]: a sparse volume of hashed voxel blocks ([`BLOCK_SIDE`]³ voxels each,
//!   allocated only where a depth image's truncation band passes, so memory grows with the
//!   surface, not the room), bounded by [`TsdfOptions::max_memory_bytes`].
//! * [`TsdfVolume::integrate`]: projective integration of one z-depth image, with its
//!   registered colour ([`RegisteredColor`], `geometry::fusion`'s H6), on every core (rayon).
//! * [`TsdfVolume::extract_mesh`]: marching cubes ([`marching`]) with per-vertex colours and
//!   normals; [`TsdfMesh::to_point_cloud`]: the surface point cloud.
//! * [`integrate_multi`]: every sensor of a `geometry::fusion::multi::MultiFusion` into one
//!   volume in the rig's reference frame.
//!
//! # Conventions (those of `geometry`)
//!
//! * **Units**: metres. Voxel size, truncation and depth are metres; weights are relative to a
//!   sample at 1 m.
//! * **Frames**: cameras look along +z, x right, y down. A frame's pose is
//!   `camera_from_volume` (`X_camera = R · X_volume + T`); the volume's frame is whatever
//!   frame the poses are relative to (for a rig, its reference camera's frame).
//! * **Depth kind**: the input is `z` (distance along the optical axis, what a Kinect
//!   delivers). A voxel's signed distance compares its camera-frame `z` with the measured `z`
//!   at the pixel its centre projects to (through the lens distortion), and scales the
//!   difference to the distance along the ray: `sdf = (z_meas − z_voxel)·√(1 + x² + y²)`.
//!   Comparing `z` with the voxel's Euclidean distance (range) bends every off-axis plane.
//! * **Sign**: positive in front of the surface (towards the camera), negative behind it;
//!   stored divided by the truncation μ (−1…1). Only voxels within μ of a sample along its ray
//!   are updated, in front or behind: nothing is carved far behind a surface, so a thin object
//!   seen from both sides keeps both faces.
//! * **Weights**: inverse variance of the Kinect depth noise, `σ(z) = σ₁·z²`
//!   ([`depth_sigma_m`], σ₁ = 1.5 mm): a sample at 2 m weighs 1/16 of one at 1 m
//!   ([`depth_weight`]).
//! * **Voxels**: voxel `g` (integer coordinates) has its centre at `(g + ½)·voxel_size`.
#![deny(missing_docs)]

mod error;
pub mod marching;
mod options;
mod volume;

pub use error::TsdfError;
pub use marching::{TsdfMesh, UNSEEN_GREY};
pub use options::{
    DEFAULT_MAX_MEMORY_BYTES, DEFAULT_TRUNCATION_M, DEFAULT_TRUNCATION_VOXELS,
    DEFAULT_VOXEL_SIZE_M, KINECT_MAX_DEPTH_M, KINECT_MIN_DEPTH_M, MAX_DEPTH_OPTION_M,
    MAX_TRUNCATION_M, MAX_VOXEL_SIZE_M, MIN_TRUNCATION_VOXELS, MIN_VOXEL_SIZE_M, TsdfOptions,
};
pub use volume::{
    BLOCK_BYTES, BLOCK_OVERHEAD_BYTES, BLOCK_SIDE, BLOCK_VOXELS, DepthFrame,
    INTERPOLATION_MAX_STEP, IntegrationStats, MAX_CAMERA_DISTANCE_M, RegisteredColor, TsdfVolume,
    Voxel, depth_sigma_m, depth_weight,
};

use geometry::fusion::multi::MultiFusion;

/// Integrates every sensor of `fusion` (its depth after the depth correction, as `z`, and its
/// H6 colour) into `volume`, each with its depth camera's pose in the rig's reference frame;
/// `progress` is called after each sensor with the number done. Returns the statistics per
/// sensor, in the order of `fusion.sensors`.
pub fn integrate_multi(
    volume: &mut TsdfVolume,
    fusion: &MultiFusion,
    mut progress: impl FnMut(usize),
) -> Result<Vec<IntegrationStats>, TsdfError> {
    let mut stats = Vec::with_capacity(fusion.sensors.len());
    for (k, s) in fusion.sensors.iter().enumerate() {
        stats.push(volume.integrate(&DepthFrame {
            camera: &s.rig.depth,
            camera_from_volume: s.depth_from_reference,
            z: &s.z,
            color: Some(RegisteredColor { rgb: &s.color_on_depth, valid: &s.color_valid }),
        })?);
        progress(k + 1);
    }
    Ok(stats)
}
