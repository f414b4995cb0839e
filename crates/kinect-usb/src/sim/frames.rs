//! The simulated streams, one frame period at a time: the forward-modelled raw depth frames,
//! their isochronous packets and the colour bulk transfers (with the seeded packet faults and
//! the unplug), interleaved; or, during a replay, the next recorded events.

use rand::Rng;

use super::SimDevice;
use crate::UsbError;
use crate::backend::{StopReason, StreamEvent, XferStatus};
use crate::decoder::DecoderParams;
use crate::forward::forward_frame;
use crate::params::XzTables;
use crate::pool::resubmit_failed;
use crate::raw::PIXELS;
use crate::stream::{ColorMeta, build_color_packet, packetize_depth_frame};

/// Timestamp increment per frame (0.125 ms units, 30 Hz).
const TICKS_PER_FRAME: u32 = 267;

/// Recorded events queued per simulated frame period during replay: about one depth frame's
/// worth of isochronous packets (9 per sub-packet × 10 plus empty ones) or more, while the
/// queue stays bounded by this many records (each ≤ `recording::MAX_RECORD`) whatever the
/// recording's size.
const REPLAY_EVENTS_PER_PERIOD: usize = 128;

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
    pub(super) fn generate_frame_period(&mut self) {
        if let Some(it) = self.replay.as_mut() {
            use crate::device::StreamKind;
            let (iso, bulk) = (self.iso.map(|s| s.0), self.bulk.map(|s| s.0));
            let mut end = None;
            for _ in 0..REPLAY_EVENTS_PER_PERIOD {
                match it.next_event() {
                    Ok(Some(e)) => {
                        let h = if e.kind == StreamKind::Depth { iso } else { bulk };
                        if let Some(h) = h {
                            self.queue.push_back((h, e.into_event()));
                        }
                    }
                    Ok(None) => {
                        end = Some(StopReason::Requested);
                        break;
                    }
                    Err(e) => {
                        self.replay_error = Some(e);
                        end = Some(StopReason::Stalled);
                        break;
                    }
                }
            }
            if let Some(reason) = end {
                for h in [iso, bulk].into_iter().flatten() {
                    self.queue.push_back((h, StreamEvent::Stopped { reason }));
                }
            }
            return;
        }
        if let Some(n) = self.faults.unplug_after_frames
            && self.frame_index >= n
        {
            self.gone = true;
            for h in [self.iso.map(|s| s.0), self.bulk.map(|s| s.0)].into_iter().flatten() {
                self.queue
                    .push_back((h, StreamEvent::Stopped { reason: StopReason::Disconnected }));
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
                if self.iso_in_flight == 0 {
                    self.iso = None;
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
                self.queue.push_back(e);
                sent_d += 1;
                continue;
            }
            if let Some(e) = ci.next() {
                self.queue.push_back(e);
                sent_c += 1;
            } else if let Some(e) = di.next() {
                self.queue.push_back(e);
                sent_d += 1;
            }
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
