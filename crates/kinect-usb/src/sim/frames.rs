//! The simulated streams, one frame period at a time: the forward-modelled raw depth frames,
//! their isochronous packets and the colour bulk transfers (with the seeded packet faults and
//! the unplug), interleaved; or, during a replay, the next recorded events.

use rand::Rng;

use super::SimDevice;
use crate::UsbError;
use crate::backend::{StopReason, StreamEvent, StreamHandle, XferStatus};
use crate::decoder::DecoderParams;
use crate::forward::forward_frame;
use crate::params::XzTables;
use crate::pool::resubmit_failed;
use crate::raw::PIXELS;
use crate::stream::{ColorMeta, build_color_packet, packetize_depth_frame};

/// Timestamp increment per frame (0.125 ms units, 30 Hz).
const TICKS_PER_FRAME: u32 = 267;

impl SimDevice {
    /// The raw depth frames the device streams (forward model of the scene), built on demand.
    pub fn raw_frames(&mut self) -> &[Vec<u8>] {
        if self.raw_frames.is_empty() {
            use rayon::prelude::*;
            let xz = XzTables::from_params(&self.profile.depth_params);
            let p = DecoderParams::default();
            // In parallel: the calibration scene's 17 frames were 15 % of its start-up, serial.
            self.raw_frames = self
                .scene
                .depth_frames
                .par_iter()
                .filter(|(d, i)| d.len() == PIXELS && i.len() == PIXELS)
                .map(|(d, i)| forward_frame(d, i, &xz, &self.profile.p0, &p))
                .collect();
            if !self.raw_frames.is_empty() {
                // Only the raw frames are streamed: the decoded images are not kept twice
                // (a ring of simulated sensors holds dozens of frames each).
                self.scene.depth_frames = Vec::new();
            }
        }
        &self.raw_frames
    }
    /// Delivers `ev` of stream `h` to that stream's sink (the completion path).
    fn emit(&self, h: StreamHandle, ev: StreamEvent) {
        let sink = if self.iso.map(|s| s.0) == Some(h) {
            self.iso_sink.as_ref()
        } else if self.bulk.map(|s| s.0) == Some(h) {
            self.bulk_sink.as_ref()
        } else {
            None
        };
        if let Some(sink) = sink {
            self.emitted.set(self.emitted.get() + 1);
            sink.deliver(ev);
        }
    }

    /// During a replay: reads and delivers the next recorded event, or ends the streams
    /// (`Requested` at the end of the recording, `Stalled` on a read error).
    pub(super) fn replay_next(&mut self) {
        let Some(it) = self.replay.as_mut() else { return };
        use crate::device::StreamKind;
        let (iso, bulk) = (self.iso.map(|s| s.0), self.bulk.map(|s| s.0));
        let next = it.next_event();
        let end = match next {
            Ok(Some(e)) => {
                let h = if e.kind == StreamKind::Depth { iso } else { bulk };
                if let Some(h) = h {
                    self.emit(h, e.into_event());
                }
                return;
            }
            Ok(None) => StopReason::Requested,
            Err(e) => {
                self.replay_error = Some(e);
                StopReason::Stalled
            }
        };
        for h in [iso, bulk].into_iter().flatten() {
            self.emit(h, StreamEvent::Stopped { reason: end });
        }
        self.iso = None;
        self.bulk = None;
    }

    /// Produces `periods` frame periods at once, delivered through the streams' sinks as a
    /// sensor's transfers complete, whether anyone reads them or not (a test's simulated
    /// time; [`SimPacing`](super::SimPacing) is not consulted).
    pub fn advance(&mut self, periods: u64) {
        for _ in 0..periods {
            self.generate_frame_period();
        }
    }

    pub(super) fn generate_frame_period(&mut self) {
        if self.gone || (self.iso.is_none() && self.bulk.is_none()) {
            return;
        }
        if let Some(n) = self.faults.unplug_after_frames
            && self.frame_index >= n
        {
            self.gone = true;
            for h in [self.iso.map(|s| s.0), self.bulk.map(|s| s.0)].into_iter().flatten() {
                self.emit(h, StreamEvent::Stopped { reason: StopReason::Disconnected });
            }
            return;
        }
        let mut depth_events = Vec::new();
        let iso_ok = self.alt1 == 1 && self.streaming_on && !self.suspended;
        if let Some((h, psize)) = self.iso
            && iso_ok
        {
            let nframes = self.raw_frames().len();
            if nframes > 0 {
                let idx = (self.frame_index % nframes as u64) as usize;
                let mut gaps = [0usize; 10];
                for g in gaps.iter_mut() {
                    *g = self.rng.random_range(1..=3);
                }
                // The device fills packets up to its own wBytesPerInterval; a host buffer
                // slot smaller than that overflows (libusb: LIBUSB_TRANSFER_OVERFLOW, no data).
                let device_packet = self.profile.bytes_per_interval as usize;
                let packets = packetize_depth_frame(
                    &self.raw_frames[idx],
                    self.depth_sequence,
                    self.timestamp,
                    device_packet,
                    gaps,
                );
                for mut pk in packets {
                    let r: f64 = self.rng.random();
                    // Overflowing the host's slot, or lost at the injected rate.
                    let status = if pk.len() > psize || r < self.faults.iso_drop_rate {
                        pk.clear();
                        XferStatus::Error
                    } else {
                        if r < self.faults.iso_drop_rate + self.faults.iso_short_rate
                            && pk.len() > 1
                        {
                            let keep = self.rng.random_range(0..pk.len());
                            pk.truncate(keep);
                        }
                        XferStatus::Completed
                    };
                    depth_events.push((h, StreamEvent::IsoPacket { status, data: pk }));
                }
            }
            if self.faults.depth_resubmit_failures > 0 && self.iso_in_flight > 0 {
                // One transfer's resubmission fails: the shared pool policy retires it.
                self.faults.depth_resubmit_failures -= 1;
                self.iso_in_flight -= 1;
                for ev in resubmit_failed(UsbError::Io, self.iso_in_flight) {
                    depth_events.push((h, ev));
                }
            }
        }
        let mut color_events = Vec::new();
        if let Some((h, size)) = self.bulk
            && !self.scene.color_jpegs.is_empty()
        {
            let idx = (self.frame_index % self.scene.color_jpegs.len() as u64) as usize;
            let jpeg = &self.scene.color_jpegs[idx];
            let pad = (4 - jpeg.len() % 4) % 4;
            let filler = 4 * self.rng.random_range(0..64usize);
            let (exposure, gain) = self.color.footer_exposure_gain();
            let meta = ColorMeta {
                sequence: self.frame_index as u32,
                timestamp: self.timestamp,
                exposure,
                gain,
                gamma: 1.0,
            };
            let mut packet = build_color_packet(jpeg, &meta, pad, filler);
            if let Some(magic) = self.faults.color_header_magic {
                packet[4..8].copy_from_slice(&magic.to_le_bytes());
            }
            for chunk in packet.chunks(size.max(1)) {
                let r: f64 = self.rng.random();
                let status = if r < self.faults.bulk_error_rate {
                    XferStatus::Error
                } else {
                    XferStatus::Completed
                };
                color_events.push((
                    h,
                    StreamEvent::Bulk {
                        status,
                        data: if status == XferStatus::Completed {
                            chunk.to_vec()
                        } else {
                            Vec::new()
                        },
                    },
                ));
            }
        }
        // Interleave the two streams over the frame period.
        let (nd, nc) = (depth_events.len(), color_events.len());
        let mut di = depth_events.into_iter();
        let mut ci = color_events.into_iter();
        let total = nd + nc;
        let (mut sent_d, mut sent_c) = (0usize, 0usize);
        for _ in 0..total {
            // Keep both streams proportionally advanced.
            let take_depth = nc == 0 || (nd > 0 && sent_d * nc <= sent_c * nd);
            if take_depth && let Some(e) = di.next() {
                self.emit(e.0, e.1);
                sent_d += 1;
                continue;
            }
            if let Some(e) = ci.next() {
                self.emit(e.0, e.1);
                sent_c += 1;
            } else if let Some(e) = di.next() {
                self.emit(e.0, e.1);
                sent_d += 1;
            }
        }
        if self.iso_in_flight == 0 && self.iso.is_some() && self.replay.is_none() {
            // Every depth transfer retired: the stream ended (after its last events went out).
            self.iso = None;
            self.iso_sink = None;
        }
        self.frame_index += 1;
        self.depth_sequence = (self.depth_sequence + 1) % (1 << 16);
        self.timestamp = self.timestamp.wrapping_add(TICKS_PER_FRAME);
    }

    /// Sets the timestamp of the next frame period, 0.125 ms units (each sensor of a simulated
    /// ring has its own clock, as real Kinects do).
    pub fn set_timestamp(&mut self, ticks: u32) {
        self.timestamp = ticks;
    }

    /// Sets the next depth sequence number (to test wrap-around).
    pub fn set_depth_sequence(&mut self, s: u32) {
        self.depth_sequence = s % (1 << 16);
    }
}
