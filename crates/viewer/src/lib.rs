//! kfuse's viewer: the fusion of one Kinect v2 frame, in 2D panes and a 3D view, with the
//! pipeline's switches re-running the fusion live; a `kfuse calibrate` report
//! ([`calibration`], [`calib_page`]); and a live sensor or the simulated one ([`live`]), saving
//! shots with the files of `kfuse capture` (both use the `kfuse-capture` library).
//! The 3D view's mesh is by default `kfuse fuse`'s default mesh (H4 on the depth grid,
//! [`pipeline::MeshGrid::Depth`]), the handout's H3-grid mesh a switch away.
//!
//! Library-first: [`ViewerApp`] holds all state and draws into any `egui::Ui`, so the
//! headless tests (`egui_kittest`) drive exactly what `kfuse view` shows. The pure parts
//! (loading [`data`], the pipeline with its [`pipeline::Toggles`], the pane images
//! [`panes`], zoom/pan [`view2d`], the orbit camera [`camera3d`], the report model
//! [`calibration`], the live session [`live::LivePage`]) are tested without a window.
//!
//! Threads: only live mode has one, the capture thread, which owns the device and sends
//! decoded frames through a bounded channel (capacity 1, newest frame wins); dropping the app
//! stops and joins it.
//!
//! # Conventions
//!
//! Those of `geometry`: pixels 0-based with centres at integers; frames x right, y down,
//! z forward; the depth camera is the rig's reference; metres (the UI prints millimetres for
//! depth). The 3D view shows everything in the **colour camera's frame** (the cloud is moved
//! there with `color_from_depth`), seen initially from the colour camera. The calibration
//! page's 3D view is in the **depth camera's frame** (the rig's reference). Live depth is in
//! millimetres as the sensor sends it (the `kinect-usb` convention); saved depth PNGs are
//! 16-bit millimetres, 0 = invalid.
#![deny(missing_docs)]

mod app;
pub mod calib_page;
pub mod calibration;
pub mod camera3d;
pub mod canvas3d;
pub mod data;
mod error;
pub mod live;
pub mod panes;
pub mod pipeline;
pub mod render3d;
pub mod rig_page;
pub mod view2d;

pub use app::{Page, ViewerApp};
pub use error::ViewerError;
pub use fusion_gpu::Engine;
