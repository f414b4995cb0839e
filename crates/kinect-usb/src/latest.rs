//! Bounded, current streaming (protocol §5.5, §17): frames are assembled where the transfers
//! complete — the libusb event thread, or the simulator's completion path — stamped with their
//! host arrival time and kept in one newest-wins slot per stream. A consumer that is slow or
//! idle makes frames drop (counted, as libfreenect2's "packets were lost"), never memory grow.
//!
//! [`FrameSink`] is the shared state; a backend's stream delivers into it through a
//! [`StreamSink`] (one per stream, which names the stream's kind); the device takes frames
//! out ([`crate::device::KinectDevice::next_frame`]). Every queue here is bounded by a named
//! constant.

use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::backend::{EventSink, StreamEvent, XferStatus};
use crate::device::StreamKind;
use crate::stream::{ColorAssembler, ColorMeta, ColorStats, DepthAssembler, DepthStats};

/// Stream-end and retirement events held for the consumer: a depth pool of 60 transfers and a
/// colour pool of 20 can each retire every transfer once and then stop, 82 events; anything
/// beyond that is a repeat and is counted in [`SinkStats::control_dropped`] instead.
pub const CONTROL_EVENTS: usize = 128;

/// Raw events held for a recorder ([`FrameSink::set_tap`]), in bytes: about a third of a
/// second of both streams (≈ 95 MB/s), enough to ride out a disk write that stalls for that
/// long; a recorder slower than the sensor loses events (counted in
/// [`SinkStats::tap_dropped`]) instead of the queue growing.
pub const TAP_QUEUE_BYTES: usize = 32 << 20;

/// A depth frame in its slot.
#[derive(Debug)]
pub struct DepthSlot {
    /// Frame sequence number.
    pub sequence: u32,
    /// Sensor timestamp of sub-packet 0 (0.125 ms units).
    pub timestamp: u32,
    /// The raw frame (2 984 960 bytes).
    pub data: Vec<u8>,
    /// Host time at which its last packet completed.
    pub arrived: Instant,
    order: u64,
}

/// A colour frame in its slot.
#[derive(Debug)]
pub struct ColorSlot {
    /// The JPEG bitstream.
    pub jpeg: Vec<u8>,
    /// Footer metadata.
    pub meta: ColorMeta,
    /// Host time at which its last transfer completed.
    pub arrived: Instant,
    order: u64,
}

/// A frame taken out of the sink.
#[derive(Debug)]
pub enum TakenFrame {
    /// Depth.
    Depth(DepthSlot),
    /// Colour.
    Color(ColorSlot),
}

impl TakenFrame {
    /// Host arrival time.
    pub fn arrived(&self) -> Instant {
        match self {
            TakenFrame::Depth(d) => d.arrived,
            TakenFrame::Color(c) => c.arrived,
        }
    }
}

/// Counters of the sink.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SinkStats {
    /// The depth assembler's counters (frames assembled, incomplete, skipped, dropped
    /// sub-packets).
    pub depth: DepthStats,
    /// The colour assembler's counters.
    pub color: ColorStats,
    /// Isochronous packets completed with an error status.
    pub iso_errors: u64,
    /// Depth frames assembled and replaced in the slot by a newer one before the consumer took
    /// them (the consumer was slower than the sensor).
    pub depth_overwritten: u64,
    /// Colour frames replaced in the slot before the consumer took them.
    pub color_overwritten: u64,
    /// Depth frames taken by the consumer.
    pub depth_taken: u64,
    /// Colour frames taken by the consumer.
    pub color_taken: u64,
    /// Raw events not queued for the recorder because [`TAP_QUEUE_BYTES`] were held.
    pub tap_dropped: u64,
    /// Retirement events not queued because [`CONTROL_EVENTS`] were held.
    pub control_dropped: u64,
}

struct State {
    depth: DepthAssembler,
    color: ColorAssembler,
    depth_slot: Option<DepthSlot>,
    color_slot: Option<ColorSlot>,
    /// One recycled depth buffer (the consumer's previous frame), so that steady streaming
    /// does not allocate.
    spare_depth: Option<Vec<u8>>,
    order: u64,
    control: VecDeque<(StreamKind, StreamEvent)>,
    tap: Option<VecDeque<(StreamKind, StreamEvent)>>,
    tap_bytes: usize,
    stats: SinkStats,
}

/// The completion side's frame assembly and the newest-wins slots (module docs).
pub struct FrameSink {
    state: Mutex<State>,
    ready: Condvar,
}

impl Default for FrameSink {
    fn default() -> Self {
        Self::new()
    }
}

/// What [`FrameSink::take`] hands the consumer.
#[derive(Debug, Default)]
pub struct Taken {
    /// Raw events for the recorder, in arrival order (empty unless the tap is on).
    pub tap: Vec<(StreamKind, StreamEvent)>,
    /// Retirements, and a stream end once no frame is waiting, in arrival order.
    pub control: Vec<(StreamKind, StreamEvent)>,
    /// The earliest-arrived untaken frame.
    pub frame: Option<TakenFrame>,
}

fn event_bytes(ev: &StreamEvent) -> usize {
    match ev {
        StreamEvent::Bulk { data, .. } | StreamEvent::IsoPacket { data, .. } => data.len(),
        _ => 0,
    }
}

impl FrameSink {
    /// An empty sink with its assemblers allocated.
    pub fn new() -> Self {
        FrameSink {
            state: Mutex::new(State {
                depth: DepthAssembler::new(),
                color: ColorAssembler::new(),
                depth_slot: None,
                color_slot: None,
                spare_depth: None,
                order: 0,
                control: VecDeque::new(),
                tap: None,
                tap_bytes: 0,
                stats: SinkStats::default(),
            }),
            ready: Condvar::new(),
        }
    }

    /// The sink as the [`EventSink`] of one stream of kind `kind`.
    pub fn stream(self: &Arc<Self>, kind: StreamKind) -> Arc<dyn EventSink> {
        Arc::new(StreamSink { sink: Arc::clone(self), kind })
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic while holding the lock leaves at worst a half-assembled frame, which the
        // assemblers discard on the next packet.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Drop colour frames whose header magic is not 'BBBB' (protocol §6).
    pub fn set_strict_header(&self, strict: bool) {
        self.lock().color.strict_header = strict;
    }

    /// Queues every raw event for a recorder (bounded by [`TAP_QUEUE_BYTES`]) while on; off
    /// drops what is queued.
    pub fn set_tap(&self, on: bool) {
        let mut s = self.lock();
        if on {
            s.tap.get_or_insert_with(VecDeque::new);
        } else {
            s.tap = None;
            s.tap_bytes = 0;
        }
    }

    /// Whether the recorder tap is on.
    pub fn tap_on(&self) -> bool {
        self.lock().tap.is_some()
    }

    /// The completion side: one event of stream `kind`, assembled at once.
    pub fn deliver(&self, kind: StreamKind, ev: StreamEvent) {
        let mut guard = self.lock();
        let s = &mut *guard;
        if let Some(tap) = s.tap.as_mut() {
            let n = event_bytes(&ev);
            if s.tap_bytes + n > TAP_QUEUE_BYTES {
                s.stats.tap_dropped += 1;
            } else {
                s.tap_bytes += n;
                tap.push_back((kind, ev.clone()));
            }
        }
        let now = Instant::now();
        match ev {
            StreamEvent::IsoPacket { status, data } => {
                if status != XferStatus::Completed {
                    s.stats.iso_errors += 1;
                    return;
                }
                if let Some(f) = s.depth.push(&data) {
                    let (sequence, timestamp) = (f.sequence, f.timestamp);
                    let mut buf = match s.depth_slot.take() {
                        Some(old) => {
                            s.stats.depth_overwritten += 1;
                            old.data
                        }
                        None => s.spare_depth.take().unwrap_or_default(),
                    };
                    buf.clear();
                    buf.extend_from_slice(f.data);
                    s.order += 1;
                    s.depth_slot = Some(DepthSlot {
                        sequence,
                        timestamp,
                        data: buf,
                        arrived: now,
                        order: s.order,
                    });
                } else {
                    return;
                }
            }
            StreamEvent::Bulk { status, data } => {
                if status != XferStatus::Completed {
                    return;
                }
                if let Some((jpeg, meta)) = s.color.push(&data) {
                    let mut buf = match s.color_slot.take() {
                        Some(old) => {
                            s.stats.color_overwritten += 1;
                            old.jpeg
                        }
                        None => Vec::new(),
                    };
                    buf.clear();
                    buf.extend_from_slice(jpeg);
                    s.order += 1;
                    s.color_slot =
                        Some(ColorSlot { jpeg: buf, meta, arrived: now, order: s.order });
                } else {
                    return;
                }
            }
            ev @ StreamEvent::Retired { .. } if s.control.len() >= CONTROL_EVENTS => {
                let _ = ev;
                s.stats.control_dropped += 1;
                return;
            }
            ev => s.control.push_back((kind, ev)),
        }
        drop(guard);
        self.ready.notify_all();
    }

    /// Takes what is waiting: the tap's events, the retirements, the earliest untaken frame,
    /// and a stream end only when no frame is waiting (frames that completed before the end
    /// are handed out first).
    pub fn take(&self) -> Taken {
        let mut s = self.lock();
        let mut out = Taken::default();
        if let Some(tap) = s.tap.as_mut() {
            out.tap = tap.drain(..).collect();
            s.tap_bytes = 0;
        }
        let depth_first = match (&s.depth_slot, &s.color_slot) {
            (Some(d), Some(c)) => d.order < c.order,
            (Some(_), None) => true,
            _ => false,
        };
        out.frame = if depth_first {
            s.stats.depth_taken += 1;
            s.depth_slot.take().map(TakenFrame::Depth)
        } else if let Some(c) = s.color_slot.take() {
            s.stats.color_taken += 1;
            Some(TakenFrame::Color(c))
        } else {
            None
        };
        let frame_waiting = out.frame.is_some();
        while let Some((_, ev)) = s.control.front() {
            if frame_waiting && matches!(ev, StreamEvent::Stopped { .. }) {
                break;
            }
            out.control.extend(s.control.pop_front());
        }
        out
    }

    /// Gives a taken depth frame's buffer back for reuse.
    pub fn recycle_depth(&self, buf: Vec<u8>) {
        self.lock().spare_depth = Some(buf);
    }

    /// Whether a frame or a control event is waiting.
    pub fn has_pending(&self) -> bool {
        let s = self.lock();
        s.depth_slot.is_some() || s.color_slot.is_some() || !s.control.is_empty()
    }

    /// Waits at most `timeout` for a frame or a control event.
    pub fn wait(&self, timeout: Duration) {
        let s = self.lock();
        let _ = self.ready.wait_timeout_while(s, timeout, |s| {
            s.depth_slot.is_none() && s.color_slot.is_none() && s.control.is_empty()
        });
    }

    /// Bytes held for the consumer: the frames in the slots, the recycled depth buffer and the
    /// recorder's queue (the assemblers' own fixed buffers, one depth frame and 2 MiB, are
    /// not counted: they never grow).
    pub fn buffered_bytes(&self) -> usize {
        let s = self.lock();
        s.depth_slot.as_ref().map_or(0, |d| d.data.capacity())
            + s.color_slot.as_ref().map_or(0, |c| c.jpeg.capacity())
            + s.spare_depth.as_ref().map_or(0, Vec::capacity)
            + s.tap_bytes
    }

    /// Counters so far.
    pub fn stats(&self) -> SinkStats {
        let s = self.lock();
        SinkStats { depth: s.depth.stats, color: s.color.stats, ..s.stats }
    }
}

/// One stream's view of a [`FrameSink`].
struct StreamSink {
    sink: Arc<FrameSink>,
    kind: StreamKind,
}

impl EventSink for StreamSink {
    fn deliver(&self, ev: StreamEvent) {
        self.sink.deliver(self.kind, ev);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raw::RAW_FRAME_BYTES;
    use crate::stream::packetize_depth_frame;

    fn feed_depth(sink: &FrameSink, seq: u32) {
        let raw = vec![seq as u8; RAW_FRAME_BYTES];
        for p in packetize_depth_frame(&raw, seq, 1000 + seq, 33_792, [1; 10]) {
            sink.deliver(
                StreamKind::Depth,
                StreamEvent::IsoPacket { status: XferStatus::Completed, data: p },
            );
        }
    }

    #[test]
    fn newest_wins_and_counts_what_it_replaced() {
        let sink = FrameSink::new();
        for seq in 0..5 {
            feed_depth(&sink, seq);
        }
        let st = sink.stats();
        assert_eq!((st.depth.frames, st.depth_overwritten, st.depth_taken), (5, 4, 0));
        assert_eq!(sink.buffered_bytes(), RAW_FRAME_BYTES);
        let t = sink.take();
        let Some(TakenFrame::Depth(d)) = t.frame else { panic!("no depth frame") };
        assert_eq!((d.sequence, d.data[0]), (4, 4));
        assert_eq!(sink.buffered_bytes(), 0);
        sink.recycle_depth(d.data);
        feed_depth(&sink, 5);
        // The recycled buffer became the slot's: still one frame held.
        assert_eq!(sink.buffered_bytes(), RAW_FRAME_BYTES);
        assert_eq!(sink.stats().depth_taken, 1);
    }

    #[test]
    fn stream_end_waits_behind_frames_and_retirements_are_bounded() {
        use crate::backend::StopReason;
        let sink = FrameSink::new();
        feed_depth(&sink, 0);
        sink.deliver(StreamKind::Depth, StreamEvent::Stopped { reason: StopReason::Stalled });
        for _ in 0..CONTROL_EVENTS + 3 {
            sink.deliver(
                StreamKind::Color,
                StreamEvent::Retired { error: crate::UsbError::Io, in_flight: 1 },
            );
        }
        assert_eq!(sink.stats().control_dropped, 4);
        let t = sink.take();
        assert!(matches!(t.frame, Some(TakenFrame::Depth(_))));
        assert!(t.control.is_empty(), "the end stays behind the frame");
        let t = sink.take();
        assert!(t.frame.is_none());
        assert_eq!(t.control.len(), CONTROL_EVENTS);
        assert!(matches!(t.control[0].1, StreamEvent::Stopped { reason: StopReason::Stalled }));
    }

    #[test]
    fn tap_is_bounded_by_bytes() {
        let sink = FrameSink::new();
        sink.set_tap(true);
        let big = vec![0u8; 1 << 20];
        for _ in 0..40 {
            sink.deliver(
                StreamKind::Color,
                StreamEvent::Bulk { status: XferStatus::Error, data: big.clone() },
            );
        }
        assert_eq!(sink.stats().tap_dropped, 40 - (TAP_QUEUE_BYTES >> 20) as u64);
        assert_eq!(sink.buffered_bytes(), TAP_QUEUE_BYTES);
        assert_eq!(sink.take().tap.len(), TAP_QUEUE_BYTES >> 20);
        assert_eq!(sink.buffered_bytes(), 0);
    }
}
