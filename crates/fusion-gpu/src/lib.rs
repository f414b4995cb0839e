//! The kfuse depth → colour fusion stages as WGSL compute shaders on wgpu (Vulkan only).
//!
//! Every stage has a CPU twin in [`geometry::fusion`] whose `f32` arithmetic the shader
//! mirrors operation by operation (same order, no `dot()`, validity decided on bit patterns,
//! products that feed a sum pinned with `keep()` so no compiler contracts them into a fused
//! multiply-add), so on an adapter with IEEE division (lavapipe) every stage is
//! **bit-identical** to the CPU:
//!
//! | stage | shader | CPU twin |
//! | --- | --- | --- |
//! | H1 back-projection (z or range, ray table) | `shaders/backproject.wgsl` | [`geometry::fusion::backproject_pixel`] |
//! | H2 `X_c = R·X_d + T`, projection with distortion | `shaders/project.wgsl` | [`geometry::fusion::project_point`] |
//! | H7 z-buffer, `atomicMin` on the f32 bits | `shaders/zbuffer.wgsl` | [`geometry::fusion::Registration`] |
//! | H3 nearest fill (disc, nearest surface) | `shaders/nearest_fill.wgsl` | [`geometry::fusion::nearest_fill_pixel`] |
//! | H8 hole mask (coverage, core, grow) | `shaders/hole_mask.wgsl` | [`geometry::fusion::HoleMasker`] |
//! | H8 plane fill (plane from the CPU RANSAC) | `shaders/plane_fill.wgsl` | [`geometry::fusion::plane_depth_pixel`] |
//! | H6 colour onto the depth grid (bilinear) | `shaders/color_on_depth.wgsl` | [`geometry::fusion::bilinear_rgb`] |
//!
//! Kinect v2 depth decoding ([`GpuDecoder`], module `decode`): the CPU decoder's three passes
//! (`kinect_usb::decoder`, `DecoderPrecision::Fast`) as `shaders/decode_stage1.wgsl`,
//! `decode_filter.wgsl` and `decode_edge.wgsl`, within protocol §9.9's 0.01 mm with no
//! validity flips on every oracle frame (`tests/decode.rs`).
//! [`FusionContext::decode_and_register`] and [`FusionContext::stream_raw`] decode raw frames
//! straight into the registration's depth buffer.
//!
//! Not on the GPU: the RANSAC plane fit (a few hundred sequential hypotheses over ≤ 20 000
//! points), H3 Delaunay-linear (spade), H4 meshing and H5 face removal; [`FusionContext::run`]
//! runs them on the CPU between and after the GPU passes. Hardware GPUs may round division
//! differently (Vulkan allows 2.5 ulp), so there parity is to the ulp, not the bit.
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
//! ```no_run
//! # fn demo(rig: &geometry::Rig, depth: &geometry::Image<f32>, color: &geometry::Image<[u8; 3]>) -> Result<(), fusion_gpu::GpuError> {
//! use fusion_gpu::FusionContext;
//! let mut ctx = FusionContext::new()?; // GpuError::NoAdapter without Vulkan
//! eprintln!("GPU: {}", ctx.adapter_name());
//! let options = geometry::fusion::FusionOptions::default();
//! let out = ctx.run(rig, depth, geometry::DepthKind::Z, color, &options)?; // a FusionOutput
//! # Ok(()) }
//! ```
//!
//! [`FusionContext::new`] opens the adapter and compiles the pipelines once; buffers are
//! reused across frames. [`FusionContext::stream`] overlaps upload, compute and read-back of
//! consecutive frames with two frame slots. Frames whose buffers exceed the adapter's binding
//! limit (lavapipe: 128 MiB) are refused up front with [`GpuError::FrameTooLarge`].
#![deny(missing_docs)]

mod context;
mod decode;
mod engine;
mod error;
mod frame;
mod gpu;
mod plan;
mod quiet;
mod run;
pub mod shaders;
mod stages;
mod tables;

pub use context::FusionContext;
pub use decode::{GpuDecoder, METRES_PER_MM};
pub use engine::Engine;
pub use error::GpuError;
pub use plan::{FramePlan, GpuFrame};
pub use run::{EngineUsed, PixelEngine, RawStreamFrame, fuse, fuse_multi, fuse_request};
