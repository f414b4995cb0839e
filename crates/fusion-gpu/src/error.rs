//! The error type of `fusion-gpu`.

use geometry::GeometryError;

/// Everything that can go wrong on the GPU path: no adapter, a frame the adapter cannot hold,
/// bad input (the same checks as the CPU pipeline), or a device failure reported by wgpu.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No Vulkan adapter is present (no GPU and no software Vulkan driver).
    #[error(
        "no GPU adapter found; install mesa-vulkan-drivers for software Vulkan, or use --engine cpu \
         (backends tried: {backends})"
    )]
    NoAdapter {
        /// The wgpu backends that were searched, e.g. "VULKAN".
        backends: String,
    },
    /// The adapter exists but refused to create a device.
    #[error("GPU adapter '{adapter}' refused to create a device: {message}")]
    RequestDevice {
        /// Adapter name.
        adapter: String,
        /// wgpu's reason.
        message: String,
    },
    /// One buffer of the frame exceeds what the adapter can bind (lavapipe: 128 MiB per
    /// storage binding). Refused before anything is allocated.
    #[error(
        "frame too large for GPU adapter '{adapter}': the {buffer} buffer ({width}x{height}) needs \
         {bytes} bytes, the adapter allows {limit} per binding; use smaller images or the CPU path \
         (--engine cpu)"
    )]
    FrameTooLarge {
        /// Adapter name.
        adapter: String,
        /// Which buffer, e.g. "colour z-buffer".
        buffer: &'static str,
        /// Image width of that buffer.
        width: usize,
        /// Image height of that buffer.
        height: usize,
        /// Bytes the buffer would need.
        bytes: u64,
        /// The adapter's limit in bytes.
        limit: u64,
    },
    /// Input rejected by the same checks the CPU pipeline applies.
    #[error(transparent)]
    Input(#[from] GeometryError),
    /// wgpu reported a validation, out-of-memory or device-lost error while running a frame.
    #[error("GPU device error on adapter '{adapter}' during {during}: {message}")]
    Device {
        /// Adapter name.
        adapter: String,
        /// What was being done.
        during: &'static str,
        /// wgpu's message.
        message: String,
    },
}
