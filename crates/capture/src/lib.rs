//! Headless Kinect v2 capture: what `kfuse capture` and the viewer's live page (`kfuse view
//! --backend …`) share, without a command line or a window. Configuration is plain structs
//! ([`SensorSource`], [`ColorSettings`], [`DecoderOptions`]); errors are [`CaptureError`].
//!
//! # Stages
//!
//! | stage | module | what it does |
//! | --- | --- | --- |
//! | 1 source | [`source`] | [`SensorSource`]: `usb` (libusb), `sim` (the simulated sensor showing `geometry::synth`'s Kinect scene), `replay` (a `.kfrec` recording), `absent` (a bus without a Kinect, for tests) |
//! | 2 session | [`session`], [`settings`] | [`Session::open`] opens and starts the device, applies [`ColorSettings`] (exposure, LED; their text forms in [`settings`]) and reads them back, builds the depth decoder, closes; reports of the simulator and of a replay |
//! | 3 pump | [`pump`] | [`FramePump`] pulls frames: decodes each depth frame into depth (mm) and IR, keeps the newest colour JPEG; [`FramePump::fresh_pair`] waits for a pair newer than an instant |
//! | 4a shots | [`shots`] | [`ShotWriter`]: a shot's colour JPEG, IR and depth PNGs are staged inside the output folder and moved into place together; [`shot_files`] names them; [`write_params_json`] the factory intrinsics |
//! | 4b recording | [`record`] | [`record::record`]: every raw USB packet and the device metadata into a `.kfrec` file, published atomically |
//! | several | [`multi`] | several sensors: [`multi::connected`] lists what a source offers (a ring of simulated sensors, `kinect_usb::sim::ring`), [`multi::select`] takes `--device SERIAL\|all`, [`multi::MultiShots`] takes each shot from every sensor at one trigger, paired by sensor timestamps, into `OUT/SERIAL/` with `OUT/index.json` (a lost sensor is dropped, the others go on), [`multi::record_all`] records each to `OUT/SERIAL.kfrec`; [`source::sim_true_rig`] is the simulated ring's rig (`true_rig.json`) |
//! | PNG | [`shots::write_png16`] | the 16-bit PNG of IR and depth (rule: `kfuse_io::images::png16_value`) |
//!
//! # Files of one shot
//!
//! A calibration shot `NNNN` is `color_NNNN.jpg` (the sensor's colour frame mirrored into the
//! scene orientation without loss, in the DCT domain: `kfuse_io::sensor_color::mirrored_jpeg`),
//! `ir_NNNN.png` (16-bit amplitude) and `depth_NNNN.png` (16-bit, millimetres, 0 = invalid); a
//! scene `NAME` is `NAME_color.jpg`, `NAME_ir.png`, `NAME_depth.png`. `kinect_params.json`
//! holds the factory intrinsics of both cameras, adjusted to the scene orientation
//! ([`write_params_json`]).
//!
//! # Image orientation
//!
//! Every image kfuse writes is **as the scene is** (`kinect_usb::orientation`): the sensor
//! streams mirrored images, the decoder writes depth and IR unmirrored, the shot writer mirrors
//! the colour JPEG, and `kinect_params.json` (version 2, `"image_orientation": "scene"`) holds
//! the factory parameters of the mirrored images, so its rig has the colour camera at
//! x ≈ +52 mm, as the Kinect SDK's, iai_kinect2's and the lab's Bouguet calibrations do. A
//! `.kfrec` recording keeps the raw packets, so one made before this rule replays in it too.
//!
//! # Conventions
//!
//! Those of `kinect-usb`: depth in millimetres as the sensor sends it (0 = invalid), images
//! 512 × 424 row-major, upright, as the scene is; sensor timestamps in 0.125 ms units. Nothing here prints:
//! what a caller may want to show is returned (setting read-backs, replay reports).
#![deny(missing_docs)]

pub mod error;
pub mod multi;
pub mod pump;
pub mod record;
pub mod session;
pub mod settings;
pub mod shots;
pub mod source;

pub use error::CaptureError;
pub use pump::{FramePump, Pumped};
pub use session::{DecoderOptions, ReplayOutcome, Session};
pub use settings::ColorSettings;
pub use shots::{ShotKind, ShotWriter, shot_files, write_params_json, write_png16};
pub use source::{ReplayOptions, SensorSource, SimOptions, SimRing};
