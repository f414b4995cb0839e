//! CPU cost of streaming (issue 45): one second of a Kinect v2's traffic, packets in and frames
//! assembled, nothing decoded. The simulated sensor produces 30 frame periods (30 depth frames
//! as isochronous packets cut at its `wBytesPerInterval`, with empty packets between
//! sub-packets, and 30 colour frames of 200 kB as 16 kB bulk transfers: about 95 MB, the
//! sensor's rate); the bench then does what the libusb completion thread does with them: copy
//! each packet out of its transfer buffer (as `transfer.rs` does), hand it to the frame sink
//! (`latest::FrameSink::deliver`), which runs the depth and colour parsers and keeps the
//! newest frame per stream. One iteration is one second of streaming on one thread, so its
//! time is the CPU seconds the driver spends per second of streaming on one core.
//!
//! With `STREAM_CPU_PROBE=N` it also prints the least thread CPU time of N iterations (on a
//! loaded machine criterion's wall-clock figure includes time spent waiting for a core).

use std::sync::{Arc, Mutex};
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use kinect_usb::backend::{StreamEvent, XferStatus};
use kinect_usb::device::{KinectDevice, StreamKind};
use kinect_usb::latest::FrameSink;
use kinect_usb::raw::PIXELS;
use kinect_usb::sim::{SIM_FRAME_RATE, SimDevice, SimFaults, SimScene};

#[path = "../tests/common/mod.rs"]
mod common;
#[path = "../../../benches/support/thread_cpu.rs"]
mod thread_cpu;
use thread_cpu::thread_cpu_ns;

/// Bytes of a colour frame: a 1920 × 1080 baseline JPEG of an ordinary indoor scene is
/// 150–250 kB.
const JPEG_BYTES: usize = 200_000;

type Packet = (StreamKind, XferStatus, Vec<u8>);

/// One second of the simulated sensor's stream events, as its transfers complete.
fn one_second() -> Vec<Packet> {
    let mut jpeg = vec![0xFF, 0xD8];
    jpeg.extend((0..JPEG_BYTES - 4).map(|i| (i as u8).wrapping_mul(31) & 0x7F));
    jpeg.extend([0xFF, 0xD9]);
    let scene = SimScene {
        depth_frames: vec![(vec![1500.0; PIXELS], vec![2000.0; PIXELS])],
        color_jpegs: vec![jpeg],
    };
    let faults = SimFaults { seed: 1, ..SimFaults::default() };
    let sim = Arc::new(Mutex::new(SimDevice::new(common::synthetic_profile(), scene, faults)));
    let mut dev = KinectDevice::open(sim).expect("open the simulated sensor");
    dev.start(true, true).expect("start it");
    dev.set_raw_tap(true);
    let mut events = Vec::new();
    let mut depth = 0;
    while depth < SIM_FRAME_RATE as usize {
        let mut tap = |k: StreamKind, e: &StreamEvent| match e {
            StreamEvent::IsoPacket { status, data } | StreamEvent::Bulk { status, data } => {
                events.push((k, *status, data.clone()))
            }
            _ => {}
        };
        if let Some(kinect_usb::device::Frame::Depth(_)) =
            dev.next_frame(Duration::from_secs(1), &mut tap).expect("stream")
        {
            depth += 1;
        }
    }
    events
}

/// Delivers one second of traffic to `sink` as the completion thread does.
fn stream(sink: &FrameSink, events: &[Packet]) {
    for (kind, status, data) in events {
        let data = data.to_vec();
        let ev = match kind {
            StreamKind::Depth => StreamEvent::IsoPacket { status: *status, data },
            StreamKind::Color => StreamEvent::Bulk { status: *status, data },
        };
        sink.deliver(*kind, ev);
    }
}

fn bench(c: &mut Criterion) {
    let events = one_second();
    let bytes: usize = events.iter().map(|e| e.2.len()).sum();
    let sink = FrameSink::new();
    stream(&sink, &events);
    let st = sink.stats();
    eprintln!(
        "one second of streaming: {} events, {:.1} MB, {} depth and {} colour frames assembled",
        events.len(),
        bytes as f64 / 1e6,
        st.depth.frames,
        st.color.frames
    );
    assert!(st.depth.frames >= SIM_FRAME_RATE as u64 - 1 && st.color.frames > 0);
    if let Some(n) = std::env::var("STREAM_CPU_PROBE").ok().and_then(|v| v.parse::<usize>().ok()) {
        let mut best = u64::MAX;
        for _ in 0..n {
            let (Some(t0), (), Some(t1)) =
                (thread_cpu_ns(), stream(&sink, &events), thread_cpu_ns())
            else {
                break;
            };
            best = best.min(t1 - t0);
        }
        eprintln!(
            "cpu probe: {:.1} ms thread CPU time per second of streaming ({:.2} % of one core), \
             least of {n}",
            best as f64 / 1e6,
            best as f64 / 1e7
        );
    }
    let mut g = c.benchmark_group("streaming");
    g.throughput(Throughput::Bytes(bytes as u64));
    g.bench_function("one_second_packets_to_frames", |b| b.iter(|| stream(&sink, &events)));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
