//! The kfuse depth → colour fusion stages as WGSL compute shaders on wgpu (Vulkan only).
//!
//! Every stage has a CPU twin in [`geometry::fusion`] whose `f32` arithmetic the shader
//! mirrors operation by operation (same order, no fused multiply-add, no `dot()`, validity
//! decided on bit patterns), so on an adapter that neither fuses nor approximates (lavapipe
//! does neither) the results are bit-identical:
//!
//! | stage | shader | CPU twin |
//! | --- | --- | --- |
//! | H1 back-projection (z or range, ray table) | `shaders/backproject.wgsl` | [`geometry::fusion::backproject_pixel`] |
//! | H2 `X_c = R·X_d + T`, projection with distortion | `shaders/project.wgsl` | [`geometry::fusion::project_point`] |
//! | H7 z-buffer, `atomicMin` on the f32 bits | `shaders/zbuffer.wgsl` | [`geometry::fusion::register_depth`] |
//!
//! # Conventions (as in `DESIGN.md`)
//!
//! * Pixels are 0-based, integer coordinates are pixel centres; a sample lands on colour pixel
//!   `(floor(u + 0.5), floor(v + 0.5))`.
//! * Camera frames: x right, y down, z forward; the depth camera is the rig's reference and
//!   `color_from_depth` maps `X_color = R · X_depth + T`. Units: metres, `f32` per pixel.
//! * Invalid depth is `0` or `NaN`; neither produces a point. An empty z-buffer pixel holds
//!   [`geometry::fusion::ZBUFFER_EMPTY`] (all bits set), the identity of `atomicMin`.
//!
//! # Use
//!
//! [`FusionContext::new`] opens the adapter (it names it: [`FusionContext::adapter_name`]) and
//! compiles the pipelines once; [`FusionContext::register`] runs one frame,
//! [`FusionContext::stream`] overlaps upload, compute and read-back of consecutive frames with
//! two frame slots. Frames whose buffers exceed the adapter's binding limit are refused
//! up front with [`GpuError::FrameTooLarge`]; no adapter gives [`GpuError::NoAdapter`].
#![deny(missing_docs)]

mod context;
mod error;
mod run;
pub mod shaders;
mod tables;

pub use context::{FramePlan, FusionContext, GpuFrame, GpuPolicy, StageOptions};
pub use error::GpuError;
