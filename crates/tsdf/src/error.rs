//! The error type of `kfuse-tsdf`.

use geometry::GeometryError;

/// Everything that can go wrong in volumetric fusion. Every message is one line that names
/// the value and the accepted range.
#[derive(Debug, thiserror::Error)]
pub enum TsdfError {
    /// An option is out of its range (voxel size, truncation, memory bound, depth range).
    #[error("invalid TSDF option: {0}")]
    InvalidOption(String),
    /// Integrating a frame would allocate more voxel blocks than the memory bound allows.
    #[error(
        "the TSDF volume would need at least {needed_bytes} bytes ({blocks} voxel blocks), more \
         than the memory bound of {limit_bytes} bytes: use a larger voxel size or raise the bound"
    )]
    MemoryBound {
        /// Blocks the volume would hold after the frame (at least: the frame is refused as
        /// soon as its blocks seen so far exceed the bound).
        blocks: usize,
        /// Bytes those blocks take.
        needed_bytes: u64,
        /// The bound ([`crate::TsdfOptions::max_memory_bytes`]).
        limit_bytes: u64,
    },
    /// A frame that cannot be integrated (NaN pose, image of another size than its camera).
    #[error("invalid frame: {0}")]
    InvalidFrame(String),
    /// A camera model or image error from `geometry`.
    #[error(transparent)]
    Geometry(#[from] GeometryError),
}
