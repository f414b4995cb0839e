//! Issue 45: USB traces (`.kftrace`). A capture from the simulated sensor is traced at the
//! backend boundary, then replayed through the same protocol code and stream parsers: the
//! device information, every frame (sequence, timestamp) and the parsers' counters match the
//! live run's; the trace holds no image; damaged traces are refused with one line naming the
//! file. Needs no shared data (synthetic profile and scene).

mod common;

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use kinect_usb::KinectError;
use kinect_usb::device::{Frame, KinectDevice, StreamCounters, StreamKind};
use kinect_usb::raw::PIXELS;
use kinect_usb::sim::{SimDevice, SimFaults, SimScene};
use kinect_usb::trace::{
    ReplayedFrame, TRACE_BULK_HEAD, TRACE_BULK_TAIL, TRACE_ISO_TAIL, TraceEnd, TraceHandle,
    TraceRecord, TracedEvent, TracingBackend, read_trace, replay_trace,
};

const T: Duration = Duration::from_secs(1);
/// Frames the live capture takes.
const FRAMES: usize = 24;

fn fake_jpeg(n: usize) -> Vec<u8> {
    let mut j = vec![0xFF, 0xD8];
    j.extend((0..n).map(|i| (i as u8).wrapping_mul(29) & 0x7F));
    j.extend([0xFF, 0xD9]);
    j
}

fn scene() -> SimScene {
    SimScene {
        depth_frames: vec![(vec![1500.0; PIXELS], vec![2000.0; PIXELS])],
        color_jpegs: vec![fake_jpeg(20_000), fake_jpeg(33_333)],
    }
}

struct Live {
    frames: Vec<ReplayedFrame>,
    counters: StreamCounters,
    serial: String,
    raw: (Vec<u8>, Vec<u8>, Vec<u8>),
    disconnected: bool,
}

/// Captures up to `FRAMES` frames from a simulated sensor with `faults`, traced to `path`.
fn capture(path: &Path, faults: SimFaults, payload: bool) -> Live {
    capture_n(path, faults, payload, FRAMES)
}

/// [`capture`] of up to `n` frames.
fn capture_n(path: &Path, faults: SimFaults, payload: bool, n: usize) -> Live {
    let sim = Arc::new(Mutex::new(SimDevice::new(common::synthetic_profile(), scene(), faults)));
    let trace = TraceHandle::create(path, payload).unwrap();
    let mut dev = KinectDevice::open(TracingBackend::new(sim, trace.clone())).unwrap();
    let info = dev.start(true, true).unwrap().clone();
    let mut frames = Vec::new();
    let mut disconnected = false;
    while frames.len() < n {
        match dev.next_frame(T, &mut |_, _| {}) {
            Ok(Some(Frame::Depth(f))) => frames.push(ReplayedFrame {
                kind: StreamKind::Depth,
                sequence: f.sequence,
                timestamp: f.timestamp,
            }),
            Ok(Some(Frame::Color(_, m))) => frames.push(ReplayedFrame {
                kind: StreamKind::Color,
                sequence: m.sequence,
                timestamp: m.timestamp,
            }),
            Err(KinectError::Disconnected { .. }) => {
                disconnected = true;
                break;
            }
            other => panic!("live capture: {other:?}"),
        }
    }
    let counters = dev.counters();
    let _ = dev.close();
    drop(dev);
    let summary = trace.finish().unwrap();
    assert_eq!(summary.omitted, 0);
    assert_eq!(summary.bytes, std::fs::metadata(path).unwrap().len());
    Live {
        frames,
        counters,
        serial: info.serial,
        raw: (info.raw_depth_params, info.raw_p0, info.raw_color_params),
        disconnected,
    }
}

/// The replay assembles every frame the live run assembled: the ones the live run took, in
/// the same order, then those still waiting when it stopped; counters of the parsers equal.
fn assert_same(live: &Live, path: &Path) -> kinect_usb::trace::TraceReplayReport {
    let r = replay_trace(path).unwrap();
    assert_eq!(r.info.serial, live.serial);
    assert_eq!(
        (&r.info.raw_depth_params, &r.info.raw_p0, &r.info.raw_color_params),
        (&live.raw.0, &live.raw.1, &live.raw.2)
    );
    assert!(
        r.frames.len() >= live.frames.len(),
        "{} < {} frames",
        r.frames.len(),
        live.frames.len()
    );
    assert_eq!(r.frames[..live.frames.len()], live.frames[..]);
    let (a, b) = (&r.counters, &live.counters);
    assert_eq!(
        (a.depth_frames, a.depth_dropped, a.depth_incomplete, a.iso_errors),
        (b.depth_frames, b.depth_dropped, b.depth_incomplete, b.iso_errors)
    );
    assert_eq!((a.color_frames, a.color_dropped), (b.color_frames, b.color_dropped));
    // Every frame assembled is taken during the replay (one event per service call).
    assert_eq!(r.frames.len() as u64, a.depth_frames + a.color_frames);
    r
}

#[test]
fn a_trace_replays_to_the_same_parsed_results_and_holds_no_image() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let path = dir.join("capture.kftrace");
    let faults = SimFaults { seed: 7, iso_drop_rate: 0.01, ..SimFaults::default() };
    let live = capture(&path, faults, false);
    assert!(live.counters.iso_errors > 0, "the drop knob lost no packet: {:?}", live.counters);
    let r = assert_same(&live, &path);
    assert_eq!(r.end, TraceEnd::EndOfTrace);
    assert!(!r.payload);
    assert!(r.calls > 30, "only {} calls replayed", r.calls);
    // No image: an event keeps at most its framing bytes, far less than the payload moved.
    let (mut traced, mut moved) = (0usize, 0u64);
    for rec in read_trace(&path).unwrap() {
        if let TraceRecord::Event { event, .. } = rec {
            match event {
                TracedEvent::Iso { length, head, tail, .. } => {
                    assert!(head.is_empty() && tail.len() <= TRACE_ISO_TAIL);
                    (traced, moved) = (traced + tail.len(), moved + length as u64);
                }
                TracedEvent::Bulk { length, head, tail, .. } => {
                    assert!(head.len() <= TRACE_BULK_HEAD && tail.len() <= TRACE_BULK_TAIL);
                    (traced, moved) = (traced + head.len() + tail.len(), moved + length as u64);
                }
                _ => {}
            }
        }
    }
    let file = std::fs::metadata(&path).unwrap().len();
    // Depth dominates: 152 of ~33 kB per packet (0.5 %); the P0 reply (1.3 MB) is in the file.
    assert!((traced as f64) < 0.01 * moved as f64, "{traced} of {moved} bytes traced");
    assert!(file < 2_000_000 + moved / 50, "{file} bytes of trace for {moved} streamed");
}

/// A capture longer than the replay's bound on events held between two calls of the start
/// sequence (4096, `MAX_PENDING_EVENTS` in `trace/replay.rs`): the depth stream, started last,
/// is followed by every event of the capture until the stop sequence, and the replay must not
/// take them for damage (it did: `kfuse capture record --frames 60 --usb-trace` wrote a trace
/// that `kfuse replay-trace` refused with "more than 4096 stream events between two calls").
#[test]
fn a_long_trace_replays_past_the_start_sequence_bound() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("long.kftrace");
    // 60 periods of both streams: 120 frames.
    let live = capture_n(&path, SimFaults { seed: 11, ..SimFaults::default() }, false, 120);
    let events = read_trace(&path)
        .unwrap()
        .iter()
        .filter(|r| matches!(r, TraceRecord::Event { .. }))
        .count();
    // The regression needs more events than the bound of 4096.
    assert!(events > 4096, "only {events} events: the capture is too short to test the bound");
    let r = assert_same(&live, &path);
    assert_eq!(r.end, TraceEnd::EndOfTrace);
    assert_eq!(r.counters.depth_frames, live.counters.depth_frames);
    assert!(live.counters.depth_frames >= 60, "{:?}", live.counters);
}

#[test]
fn a_payload_trace_replays_the_same() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let path = dir.join("p.kftrace");
    let faults = SimFaults { seed: 3, ..SimFaults::default() };
    let live = capture(&path, faults, true);
    let r = assert_same(&live, &path);
    assert!(r.payload);
}

#[test]
fn an_unplugged_sensor_ends_its_trace_as_disconnected() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let path = dir.join("u.kftrace");
    let faults = SimFaults { seed: 5, unplug_after_frames: Some(4), ..SimFaults::default() };
    let live = capture(&path, faults, false);
    assert!(live.disconnected);
    assert_eq!(live.counters.depth_frames, 4);
    let r = assert_same(&live, &path);
    assert_eq!(r.end, TraceEnd::Disconnected);
}

fn one_line_trace_error(path: &Path) -> String {
    match replay_trace(path) {
        Err(e @ KinectError::Trace { .. }) => {
            let m = e.to_string();
            assert!(!m.contains('\n'), "{m}");
            assert!(m.contains(&path.display().to_string()), "{m}");
            m
        }
        other => panic!("a damaged trace was not refused: {:?}", other.map(|r| r.frames.len())),
    }
}

#[test]
fn damaged_traces_are_refused_with_one_line() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let good = dir.join("good.kftrace");
    let faults = SimFaults { seed: 9, ..SimFaults::default() };
    capture(&good, faults, false);
    let bytes = std::fs::read(&good).unwrap();
    let write = |name: &str, b: &[u8]| {
        let p = dir.join(name);
        std::fs::write(&p, b).unwrap();
        p
    };
    let m = one_line_trace_error(&write("cut.kftrace", &bytes[..bytes.len() - 10]));
    assert!(m.contains("truncated"), "{m}");
    let mut flipped = bytes.clone();
    let mid = bytes.len() / 2;
    flipped[mid] ^= 0x40;
    let m = one_line_trace_error(&write("flipped.kftrace", &flipped));
    assert!(m.contains("checksum"), "{m}");
    let mut magic = bytes.clone();
    magic[0] = b'X';
    let m = one_line_trace_error(&write("magic.kftrace", &magic));
    assert!(m.contains("not a kfuse USB trace"), "{m}");
    let mut version = bytes.clone();
    version[8] = 9;
    let m = one_line_trace_error(&write("version.kftrace", &version));
    assert!(m.contains("version 9"), "{m}");
    // The first record's length made huge: refused before anything is allocated.
    let mut long = bytes.clone();
    long[28 + 1..28 + 5].copy_from_slice(&u32::MAX.to_le_bytes());
    let m = one_line_trace_error(&write("long.kftrace", &long));
    assert!(m.contains("damaged"), "{m}");
    let m = one_line_trace_error(&write("empty.kftrace", &[]));
    assert!(m.contains("truncated header"), "{m}");
}
