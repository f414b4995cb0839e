//! Issue 45 item 1: streaming that is bounded and current. The simulated sensors produce their
//! frame periods through the same completion path as the libusb event thread (the streams'
//! sinks) while nobody reads: what is held stays at one frame per stream, the frames not taken
//! are counted exactly, and the next frame asked for after the pause is the sensor's current
//! one. Needs no shared data (synthetic profile and scene).

mod common;

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use kinect_usb::backend::UsbBackend;
use kinect_usb::device::{Frame, KinectDevice, StreamCounters};
use kinect_usb::raw::{PIXELS, RAW_FRAME_BYTES};
use kinect_usb::sim::{SIM_FRAME_RATE, SimDevice, SimFaults, SimPacing, SimProfile, SimScene};

const T: Duration = Duration::from_secs(1);
/// Simulated seconds of streaming with nobody reading.
const IDLE_SECONDS: u64 = 10;
/// What the queues may hold per sensor: the newest depth frame, one recycled depth buffer and
/// the newest colour JPEG (a few kB here) — under three raw depth frames, whatever the pause.
const HELD_BOUND: usize = 3 * RAW_FRAME_BYTES;
/// Resident memory the pause may add to the process (the bar).
const RSS_GROWTH_BOUND: usize = 20 << 20;

/// The tests of this file measure the process's resident memory: one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

fn profile() -> SimProfile {
    common::synthetic_profile()
}

fn fake_jpeg(n: usize, tag: u8) -> Vec<u8> {
    let mut j = vec![0xFF, 0xD8];
    j.extend((0..n).map(|i| (i as u8).wrapping_mul(31).wrapping_add(tag) & 0x7F));
    j.extend([0xFF, 0xD9]);
    j
}

/// A flat wall and a 30 kB colour frame.
fn scene() -> SimScene {
    SimScene {
        depth_frames: vec![(vec![1500.0; PIXELS], vec![2000.0; PIXELS])],
        color_jpegs: vec![fake_jpeg(30_000, 1)],
    }
}

/// Resident set size of this process, bytes (`VmRSS` of /proc/self/status).
fn rss_bytes() -> usize {
    let s = std::fs::read_to_string("/proc/self/status").unwrap();
    let line = s.lines().find(|l| l.starts_with("VmRSS:")).unwrap();
    let kb: usize = line.split_whitespace().nth(1).unwrap().parse().unwrap();
    kb * 1024
}

type Shared = Arc<Mutex<SimDevice>>;

fn open(pacing: SimPacing, seed: u64) -> (Shared, KinectDevice<Shared>) {
    let mut s = SimDevice::new(profile(), scene(), SimFaults { seed, ..SimFaults::default() });
    s.pacing = pacing;
    let sim = Arc::new(Mutex::new(s));
    let mut dev = KinectDevice::open(Arc::clone(&sim)).unwrap();
    dev.start(true, true).unwrap();
    (sim, dev)
}

/// Takes frames until one depth frame that arrived at or after `since`; returns its sequence
/// number (colour frames and older depth frames are taken and passed over).
fn fresh_depth<B: UsbBackend>(dev: &mut KinectDevice<B>, since: Instant) -> u32 {
    for _ in 0..8 {
        match dev.next_frame_at(T, &mut |_, _| {}).unwrap() {
            Some((Frame::Depth(f), at)) if at >= since => return f.sequence,
            Some(_) => {}
            None => panic!("timeout"),
        }
    }
    panic!("no fresh depth frame in 8 frames");
}

fn current_sequence(sim: &Shared) -> u32 {
    // The sequence of the last frame period produced.
    let s = sim.lock().unwrap();
    (s.depth_sequence + (1 << 16) - 1) % (1 << 16)
}

/// Three sensors stream 10 simulated seconds (300 frame periods each, pushed through the
/// completion path) with nobody reading. Each holds one depth and one colour frame; the drop
/// counters equal frames produced − taken − the one waiting; the frame taken next is each
/// sensor's current one, not one from 10 s ago; the process's resident memory grows by less
/// than 20 MB (the old unbounded queue held 300 × 2.98 MB = 895 MB per sensor).
#[test]
fn three_idle_sensors_stay_bounded_and_current() {
    let _one = SERIAL.lock().unwrap_or_else(|p| p.into_inner());
    let mut sensors: Vec<_> = (0..3).map(|i| open(SimPacing::Lockstep, i)).collect();
    // Warm up: the first depth and colour frame of each, so every buffer exists.
    for (_, dev) in &mut sensors {
        let since = Instant::now();
        fresh_depth(dev, since);
        while !matches!(dev.next_frame(T, &mut |_, _| {}).unwrap(), Some(Frame::Color(..))) {}
    }
    let before: Vec<(u64, StreamCounters)> = sensors
        .iter()
        .map(|(sim, dev)| (sim.lock().unwrap().frame_index, dev.counters()))
        .collect();
    let rss0 = rss_bytes();
    let periods = IDLE_SECONDS * SIM_FRAME_RATE as u64;
    for (sim, _) in &sensors {
        sim.lock().unwrap().advance(periods);
    }
    let rss1 = rss_bytes();
    let grown = rss1.saturating_sub(rss0);
    println!("resident memory {rss0} -> {rss1} bytes (+{grown}) over {periods} periods × 3");
    assert!(grown < RSS_GROWTH_BOUND, "resident memory grew by {grown} bytes");
    for (i, (sim, dev)) in sensors.iter_mut().enumerate() {
        let held = dev.buffered_bytes();
        println!("sensor {i}: {held} bytes held");
        assert!(held < HELD_BOUND, "sensor {i} holds {held} bytes");
        let c = dev.counters();
        let (p0, c0) = before[i];
        let produced = sim.lock().unwrap().frame_index;
        assert_eq!(produced, p0 + periods, "sensor {i}");
        assert_eq!((c.depth_frames, c.color_frames), (produced, produced), "sensor {i}");
        // Nothing taken during the pause; the newest of each stream is waiting.
        assert_eq!((c.depth_taken, c.color_taken), (c0.depth_taken, c0.color_taken));
        assert_eq!(c.depth_overwritten, produced - c.depth_taken - 1, "sensor {i}");
        assert_eq!(c.color_overwritten, produced - c.color_taken - 1, "sensor {i}");
        assert!(c.depth_overwritten >= periods - 1, "sensor {i}: {c:?}");
        // Nothing was lost on the wire: every drop is the reader's.
        assert_eq!((c.depth_dropped, c.depth_incomplete, c.iso_errors), (0, 0, 0));

        // The frame waiting is the current one; asking for one that arrives after now gives
        // the next period, the device's current sequence.
        let waiting = current_sequence(sim);
        assert_eq!(waiting as u64, produced - 1, "sensor {i}");
        let since = Instant::now();
        let seq = fresh_depth(dev, since);
        assert_eq!(seq, current_sequence(sim), "sensor {i}");
        assert_eq!(seq, waiting + 1, "sensor {i}");
        let c: StreamCounters = dev.counters();
        assert_eq!(c.depth_overwritten, c.depth_frames - c.depth_taken, "sensor {i}: {c:?}");
    }
}

/// Paced by the host clock at 30 Hz, the simulated sensor goes on producing while nobody
/// reads for a second; the frame asked for afterwards is the last one produced, and every
/// frame produced is either taken or counted as overwritten.
#[test]
fn real_time_sensor_produces_whether_read_or_not() {
    let _one = SERIAL.lock().unwrap_or_else(|p| p.into_inner());
    let (sim, mut dev) = open(SimPacing::RealTime, 7);
    // The periods due since the streams started (the start itself takes a while).
    let first = fresh_depth(&mut dev, Instant::now());
    assert_eq!(first as u64, sim.lock().unwrap().frame_index - 1);
    std::thread::sleep(Duration::from_secs(1));
    let since = Instant::now();
    let seq = fresh_depth(&mut dev, since);
    let produced = sim.lock().unwrap().frame_index;
    // A second at 30 Hz: at least 30 more periods (more on a slow machine).
    assert!(produced > 30, "{produced} periods");
    assert_eq!(seq, current_sequence(&sim));
    assert_eq!(seq as u64, produced - 1);
    let c = dev.counters();
    println!("real time: {produced} periods, {c:?}");
    assert_eq!(c.depth_frames, produced);
    assert_eq!(c.depth_overwritten, c.depth_frames - c.depth_taken, "{c:?}");
    assert!(dev.buffered_bytes() < HELD_BOUND);
}
