//! Kinect v2 (Kinect for Xbox One) driver core of kfuse: USB protocol, simulated device, stream
//! parsers, CPU depth decoder, registration and raw recordings.
//!
//! Implements the protocol described in this repository's `docs/kinect-v2-protocol.md`;
//! comments cite its sections by number, e.g. "protocol §9.6" (`tests/protocol_doc.rs` checks
//! that every cited section exists).
//!
//! # Conventions
//!
//! * Depth/IR images are 512 × 424 `f32`, row-major, **upright** (row 0 = top) and, by default,
//!   **as the scene is** (not mirrored as the sensor streams them: [`orientation`]); pixel
//!   `(c, r)` = (column, row), integer coordinates are pixel centres.
//! * Depth is in **millimetres** along the optical axis (z); `0` (or −0.0) means invalid.
//!   IR is decoder amplitude in `[0, 65535]`.
//! * Colour frames are 1920 × 1080 baseline JPEG as sent by the sensor (mirrored: the consumer
//!   that decodes them mirrors the pixels, [`orientation::mirror_rows`]).
//! * All protocol fields are little-endian. Timestamps are in units of 0.125 ms.
//! * Internally the decoder works in *processing* rows `y = 423 − r` (protocol §9.8).
//! * Colour-camera settings (0x3E) and the LED API (0x4B) go out with sequence 0 and leave the
//!   per-device counter alone (protocol §3.3); every other command post-increments it. Their value
//!   ranges are the named constants of [`protocol`] (e.g. [`protocol::ANALOG_GAIN_RANGE`]).
//!
//! # Features
//!
//! * `sim` — the simulated device (module `sim`) and its `rand` dependencies: for the CLI's
//!   `--backend sim`, the viewer's live mode without a sensor, and tests. Off by default so that
//!   the driver does not ship it.
//! * `testdata` — locating and reading the shared test vectors (module `testdata`): for tests and
//!   benches only (this crate's own tests enable both through a dev-dependency on itself).
//!
//! This crate depends on nothing else of kfuse. `unsafe` is confined to the private
//! `transfer` module (libusb isochronous/bulk transfers) and to the one call by which the
//! depth decoder enters its AVX2 kernels after checking that the CPU has AVX2.
#![deny(missing_docs)]
#![deny(unsafe_code)]

pub mod backend;
pub mod decoder;
pub mod device;
pub mod error;
pub mod forward;
pub mod latest;
pub mod orientation;
pub mod params;
mod pool;
pub mod protocol;
pub mod raw;
pub mod recording;
pub mod registration;
#[cfg(feature = "sim")]
pub mod sim;
pub mod stream;
#[cfg(any(test, feature = "testdata"))]
pub mod testdata;
pub mod trace;
mod transfer;
pub mod usb;

pub use error::{KinectError, Result, UsbError};
