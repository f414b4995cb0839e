//! Stage 3: pulling frames. [`FramePump`] owns the depth decoder and the newest decoded depth,
//! IR and colour JPEG; `kfuse capture` waits for a fresh pair per shot
//! ([`FramePump::fresh_pair`]), the viewer's capture thread shows every depth frame
//! ([`FramePump::pump`]).

use std::time::{Duration, Instant};

use kinect_usb::KinectError;
use kinect_usb::decoder::DepthDecoder;
use kinect_usb::device::Frame;
use kinect_usb::raw::PIXELS;

use crate::{CaptureError, Session};

/// How long to wait for one frame pair before giving up (a live sensor delivers every 33 ms;
/// a hundred periods covers a slow start of the colour stream).
pub const FRAME_TIMEOUT: Duration = Duration::from_secs(3);

/// What one [`FramePump::pump`] received.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pumped {
    /// A depth frame, now decoded in [`FramePump::depth_mm`] and [`FramePump::ir`].
    Depth {
        /// Depth frames decoded since the pump started (1 for the first).
        number: u64,
        /// Sensor timestamp of the frame, 0.125 ms units.
        timestamp: u32,
    },
    /// A colour frame, now in [`FramePump::color_jpeg`].
    Color,
}

/// The decoder and the newest frames.
pub struct FramePump {
    decoder: DepthDecoder,
    depth_mm: Vec<f32>,
    ir: Vec<f32>,
    color_jpeg: Vec<u8>,
    depth_at: Option<Instant>,
    color_at: Option<Instant>,
    depth_frames: u64,
    depth_timestamp: Option<u32>,
    color_timestamp: Option<u32>,
}

impl FramePump {
    /// A pump decoding with `decoder` (from [`Session::decoder`]).
    pub fn new(decoder: DepthDecoder) -> Self {
        Self {
            decoder,
            depth_mm: vec![0.0; PIXELS],
            ir: vec![0.0; PIXELS],
            color_jpeg: Vec::new(),
            depth_at: None,
            color_at: None,
            depth_frames: 0,
            depth_timestamp: None,
            color_timestamp: None,
        }
    }

    /// The decoder in use.
    pub fn decoder(&self) -> &DepthDecoder {
        &self.decoder
    }

    /// The newest decoded depth, millimetres, 512 × 424 row-major, 0 = invalid.
    pub fn depth_mm(&self) -> &[f32] {
        &self.depth_mm
    }

    /// The newest decoded IR amplitude, 512 × 424.
    pub fn ir(&self) -> &[f32] {
        &self.ir
    }

    /// The newest colour JPEG as the sensor sent it (empty before the first colour frame).
    pub fn color_jpeg(&self) -> &[u8] {
        &self.color_jpeg
    }

    /// The sensor timestamp of the newest decoded depth frame (0.125 ms units).
    pub fn depth_timestamp(&self) -> Option<u32> {
        self.depth_timestamp
    }

    /// The sensor timestamp of the newest colour frame (0.125 ms units).
    pub fn color_timestamp(&self) -> Option<u32> {
        self.color_timestamp
    }

    /// When the newest decoded depth frame arrived (its last packet completed, host time).
    pub fn depth_arrived(&self) -> Option<Instant> {
        self.depth_at
    }

    /// When the newest colour frame arrived (host time).
    pub fn color_arrived(&self) -> Option<Instant> {
        self.color_at
    }

    /// Depth frames decoded so far.
    pub fn depth_frames(&self) -> u64 {
        self.depth_frames
    }

    /// Waits at most `timeout` for one frame of `session` and takes it in: a depth frame is
    /// decoded, a colour JPEG kept. `Ok(None)` on timeout.
    pub fn pump(
        &mut self,
        session: &mut Session,
        timeout: Duration,
    ) -> Result<Option<Pumped>, CaptureError> {
        match session.next_frame_at(timeout, &mut |_, _| {})? {
            Some((Frame::Depth(f), arrived)) => {
                self.decoder
                    .decode(f.data, &mut self.depth_mm, &mut self.ir)
                    .map_err(CaptureError::Decode)?;
                self.depth_at = Some(arrived);
                self.depth_frames += 1;
                self.depth_timestamp = Some(f.timestamp);
                Ok(Some(Pumped::Depth { number: self.depth_frames, timestamp: f.timestamp }))
            }
            Some((Frame::Color(jpeg, meta), arrived)) => {
                self.color_timestamp = Some(meta.timestamp);
                self.color_jpeg.clear();
                self.color_jpeg.extend_from_slice(jpeg);
                self.color_at = Some(arrived);
                Ok(Some(Pumped::Color))
            }
            None => Ok(None),
        }
    }

    /// Whether both the held depth frame and the held colour frame arrived (their last packet
    /// completed, host time) at or after `since` (a caller that pumps frame by frame, e.g. to answer Ctrl-C between frames,
    /// asks this where [`FramePump::fresh_pair`] loops by itself).
    pub fn holds_pair_since(&self, since: Instant) -> bool {
        let fresh = |t: Option<Instant>| t.is_some_and(|t| t >= since);
        fresh(self.depth_at) && fresh(self.color_at)
    }

    /// Pumps until both a depth and a colour frame that arrived at or after `since` are held,
    /// at most [`FRAME_TIMEOUT`] (then a protocol error naming the timeout). Frames that
    /// arrived before `since` are passed over: after a pause this returns the sensor's present,
    /// not a frame from the start of the pause (the device keeps only the newest per stream).
    pub fn fresh_pair(
        &mut self,
        session: &mut Session,
        since: Instant,
    ) -> Result<(), CaptureError> {
        let deadline = Instant::now() + FRAME_TIMEOUT;
        loop {
            if self.holds_pair_since(since) {
                return Ok(());
            }
            if Instant::now() > deadline {
                return Err(CaptureError::Device(KinectError::Protocol {
                    what: "capture".into(),
                    detail: format!("no complete frame pair within {FRAME_TIMEOUT:?}"),
                }));
            }
            self.pump(session, FRAME_TIMEOUT)?;
        }
    }
}
