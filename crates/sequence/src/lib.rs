//! Whole recordings, not single frames: a `.kfrec` recording (or a folder of frames written by
//! `kfuse capture`) through decode and registration, frame by frame, in a bounded streamed
//! pipeline, written in kfuse's layout or the TUM RGB-D layout. `kfuse fuse --recording` /
//! `--frames` is the command line over this crate.
//!
//! # Stages
//!
//! | stage | module | what it does |
//! | --- | --- | --- |
//! | 1 read | [`source`] | [`source::RecordingSource`]: the recording's packets assembled into depth frames and colour JPEGs (`kinect_usb::stream`), one record in memory at a time; [`source::FolderSource`]: the shots of a capture folder or glob |
//! | 1 read (bags) | [`bag`] | [`bag::BagSource`]: a ROS 2 bag's (rosbag2 folder or `.mcap`) depth `Image`s, already in metres, and colour pictures, stamped by their headers; its camera_infos and `/tf_static` as a rig |
//! | 2 match | [`matching`] | depth and colour paired by the sensor's timestamps, frame numbers from the depth sequence numbers, every lost depth frame listed |
//! | 3–4 decode, register | [`process`] | the `Fast` depth decoder, `geometry::fusion::Registration` (or `fusion_gpu::FusionContext::stream`), the hole mask, colour on the depth grid, the cloud |
//! | 5–6 encode, write | [`write`] | PNG (fdeflate's fastest level, no row filter), the colour JPEG as the scene is ([`color`]: a capture's copied unchanged, a recording's flipped without loss in the DCT domain), `index.json` |
//! | export | [`tum`] | `rgb.txt`, `depth.txt`, `associations.txt`, README of the TUM layout |
//! | export | [`rosbag2`] | the rosbag2 layout: ROS 2 topics (depth, IR, registered depth, the sensor's JPEG, camera_info, `/tf_static`, optionally the cloud as `PointCloud2`) in one MCAP file + `metadata.yaml`, stamped in host time ([`host_time`]: the recording's sensor clock anchored at its file's modification time) |
//! | pipeline | [`pipeline`] | the stages on one or two worker threads joined by bounded queues; Ctrl-C finishes the frames in flight |
//! | the run | [`command`] | the whole `kfuse fuse --recording/--frames`: options checked, input and staged output opened ([`command::open`]), the pipeline, `index.json` and the TUM lists, the folder committed ([`command::run`]); the caller sees progress through [`command::Observer`] |
//!
//! # Conventions
//!
//! Images as the scene is (`kinect_usb::orientation`): the decoder writes depth unmirrored, and a
//! recording's colour JPEG, mirrored as the sensor streams it, is mirrored where it is used
//! ([`color::ColorJpeg`]). Sensor timestamps in ticks of 0.125 ms ([`source::TICKS_PER_SECOND`]), written as seconds
//! with six decimals (exact). Registered depth is the colour camera's `z` on the colour pixel
//! grid (H7's z-buffer: the nearest sample per colour pixel), 0 = no sample, in millimetres
//! (kfuse and rosbag2 layouts) or 1/5000 m (TUM layout). Frame numbers count depth frame periods from the
//! first frame of the recording, so a lost frame leaves a gap in the numbers.
#![deny(missing_docs)]

pub mod bag;
pub mod bag1;
pub mod color;
pub mod command;
pub mod error;
pub mod host_time;
pub mod matching;
pub mod pipeline;
pub mod process;
pub mod rosbag2;
pub mod source;
pub mod tum;
pub mod write;

pub use error::{Result, SequenceError};
