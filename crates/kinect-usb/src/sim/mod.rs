//! A simulated Kinect v2 behind [`UsbBackend`](crate::backend::UsbBackend) (protocol §14.1):
//! enforces the protocol, answers every command from a [`SimProfile`], streams depth frames
//! built with the forward model from a caller-supplied [`SimScene`] and colour packets from
//! caller-supplied JPEGs, and injects seeded faults.
//!
//! The simulated device is one state machine whose command handlers, stream generator, replay
//! source and fault injection all read and change the same private state: that state
//! ([`SimDevice`]'s fields) is declared here, so that the submodules, one per part of the
//! machine, share it without it becoming crate-visible. This file also holds what a caller
//! configures ([`SimScene`], [`SimFaults`]) and [`SimDevice::new`]; `profile` holds
//! [`SimProfile`], `color` the colour camera's settings registers ([`SimColorSettings`]),
//! `commands` the answers to commands and the LED state, `frames` the streamed frame periods,
//! `replay` the device built from a recording, `backend` the
//! [`UsbBackend`](crate::backend::UsbBackend) implementation (protocol checks, command phases,
//! streams). Everything public is re-exported here, so `sim::X` names every item.
//!
//! It is compiled only with the `sim` feature. The calibration scene it can show (a
//! checkerboard in tilted poses, labs L1–L3) is [`calib_scene`]; several sensors in a ring
//! around it are [`ring`]; the depth error it can inject is [`depth_error`].

pub mod calib_scene;
pub mod depth_error;
pub mod ring;

mod backend;
mod color;
mod commands;
mod frames;
mod profile;
mod replay;

pub use color::{SIM_AUTO_EXPOSURE_MS, SimColorSettings};
pub use commands::{SIM_STATUS_BAD_REQUEST, SIM_STATUS_INVALID_VALUE, SIM_STATUS_UNKNOWN_CODE};
pub use profile::SimProfile;

use std::sync::Arc;
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::backend::{EventSink, StreamHandle};
use crate::protocol::{CommandMessage, LedSetting};

/// What the simulated sensor sees. Frames cycle.
#[derive(Debug, Clone, Default)]
pub struct SimScene {
    /// Depth frames: (depth in mm, IR amplitude), each 512 × 424 upright.
    pub depth_frames: Vec<(Vec<f32>, Vec<f32>)>,
    /// Colour frames as JPEG bitstreams (any bytes starting FF D8 and ending FF D9).
    pub color_jpegs: Vec<Vec<u8>>,
}

/// Seeded fault injection.
#[derive(Debug, Clone, Default)]
pub struct SimFaults {
    /// Seed of every random decision.
    pub seed: u64,
    /// Claiming an interface fails with Busy.
    pub busy: bool,
    /// Command id whose OUT transfer stalls (once).
    pub stall_command: Option<u32>,
    /// Command id whose response read times out (once).
    pub timeout_command: Option<u32>,
    /// Command id answered with a premature completion (once).
    pub premature_completion: Option<u32>,
    /// Completions echo a wrong sequence number.
    pub wrong_completion_sequence: bool,
    /// Status never reports ready.
    pub status_never_ready: bool,
    /// Fraction of iso packets lost (error status, no data).
    pub iso_drop_rate: f64,
    /// Fraction of iso packets delivered short (truncated data).
    pub iso_short_rate: f64,
    /// Fraction of colour transfers that stall (error status).
    pub bulk_error_rate: f64,
    /// The device disappears after this many frame periods.
    pub unplug_after_frames: Option<u64>,
    /// Command id whose data phase is cut to half its length (once).
    pub short_response: Option<u32>,
    /// The colour packets' header magic (offset 4) is this word instead of 'BBBB' (a firmware
    /// that writes something else there; libfreenect2 never reads it).
    pub color_header_magic: Option<u32>,
    /// Every accepted 0x3E response and LED API completion carries this status word instead
    /// of 0 (the setting still takes effect): the meaning of the word is undocumented.
    pub accepted_status: Option<u32>,
    /// The next port reset re-enumerates the device (libusb `NOT_FOUND`): the handle is dead
    /// until [`UsbBackend::reopen`](crate::backend::UsbBackend::reopen) finds it again.
    pub reset_reenumerates: bool,
    /// After a re-enumeration the sensor does not come back (a reopen finds no such serial).
    pub lost_after_reenumeration: bool,
    /// The last `n` transfers of the depth pool fail their first submission with this error
    /// ([`UsbError::NoMem`](crate::UsbError::NoMem): Linux's `usbfs_memory_mb` exhausted).
    pub depth_submit_failures: Option<(usize, crate::UsbError)>,
    /// This many depth transfers fail their resubmission (I/O error), one at the end of each
    /// frame period from the first. The simulated stream itself does not thin out with fewer
    /// transfers in flight; it ends when none is left.
    pub depth_resubmit_failures: usize,
}

/// When the simulated sensor produces its frame periods (each: one depth frame's isochronous
/// packets and one colour frame's bulk transfers, through the streams' sinks, i.e. the same
/// completion code as the libusb backend's event thread).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum SimPacing {
    /// One period each time the host services the device with nothing waiting for it
    /// (deterministic: every frame reaches a reader, whatever its speed; for tests).
    #[default]
    Lockstep,
    /// At the sensor's 30 Hz of host time since the streams started, whether anyone reads or
    /// not: the periods due are produced when the device is next serviced, a slow reader
    /// loses frames (newest wins) as with a real sensor.
    RealTime,
}

/// Frame periods per second of the sensor (depth and colour at 30 Hz, protocol §7).
pub const SIM_FRAME_RATE: u32 = 30;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Data,
    Completion,
}

/// The simulated device.
pub struct SimDevice {
    profile: SimProfile,
    scene: SimScene,
    /// Faults to inject.
    pub faults: SimFaults,
    rng: ChaCha8Rng,
    /// Every operation, in order (for asserting exact start/stop/close sequences).
    pub transcript: Vec<String>,
    /// Protocol rules the host broke (must stay empty).
    pub violations: Vec<String>,
    config: u8,
    claimed: [bool; 2],
    alt1: u8,
    suspended: bool,
    streaming_on: bool,
    status_ready_seen: bool,
    status_polls: usize,
    expected_seq: u32,
    pending: Option<(CommandMessage, Vec<u8>, Phase, u32)>,
    /// The last 0x4B at sequence 0 could have been either the first sequenced command or the
    /// LED API (protocol §3.3 ambiguity at the session's start): accept either numbering next.
    led_ambiguous: bool,
    color: SimColorSettings,
    leds: [Option<LedSetting>; 2],
    led_api: Vec<LedSetting>,
    halted_out: bool,
    gone: bool,
    /// The handle died in a re-enumerating reset and was not reopened yet.
    stale_handle: bool,
    iso: Option<(StreamHandle, usize)>,
    /// Depth transfers in flight (the pool's size less the retired ones).
    iso_in_flight: usize,
    bulk: Option<(StreamHandle, usize)>,
    /// Events delivered to the sinks so far.
    emitted: std::cell::Cell<u64>,
    /// Where the depth stream's events go (given at its start).
    iso_sink: Option<Arc<dyn EventSink>>,
    /// Where the colour stream's events go.
    bulk_sink: Option<Arc<dyn EventSink>>,
    /// When frame periods are produced.
    pub pacing: SimPacing,
    /// [`SimPacing::RealTime`]: when the first stream started, and the periods produced on that
    /// clock since.
    paced_since: Option<(Instant, u64)>,
    next_handle: u32,
    raw_frames: Vec<Vec<u8>>,
    /// Frame periods generated so far.
    pub frame_index: u64,
    /// Sequence number of the next depth frame (wraps at 2^16).
    pub depth_sequence: u32,
    timestamp: u32,
    replay: Option<Box<dyn crate::recording::ReplaySource>>,
    /// Why a replay stopped early (a corrupt record), taken by [`SimDevice::take_replay_error`].
    replay_error: Option<crate::KinectError>,
}

impl SimDevice {
    /// A device with the given profile, scene and faults.
    pub fn new(profile: SimProfile, scene: SimScene, faults: SimFaults) -> Self {
        let rng = ChaCha8Rng::seed_from_u64(faults.seed);
        SimDevice {
            profile,
            scene,
            faults,
            rng,
            transcript: Vec::new(),
            violations: Vec::new(),
            config: 0,
            claimed: [false; 2],
            alt1: 0,
            suspended: false,
            streaming_on: false,
            status_ready_seen: false,
            status_polls: 0,
            expected_seq: 0,
            pending: None,
            led_ambiguous: false,
            color: SimColorSettings::default(),
            leds: [None; 2],
            led_api: Vec::new(),
            halted_out: false,
            gone: false,
            stale_handle: false,
            iso: None,
            iso_in_flight: 0,
            bulk: None,
            emitted: std::cell::Cell::new(0),
            iso_sink: None,
            bulk_sink: None,
            pacing: SimPacing::Lockstep,
            paced_since: None,
            next_handle: 1,
            raw_frames: Vec::new(),
            frame_index: 0,
            depth_sequence: 0,
            timestamp: 1000,
            replay: None,
            replay_error: None,
        }
    }

    /// Colour frames of the scene: the device cycles through them, one per frame period.
    pub fn color_frames(&self) -> usize {
        self.scene.color_jpegs.len()
    }
}
