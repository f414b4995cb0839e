//! Issue 45 items 2–4 through the simulated device's fault knobs: depth packets sized from the
//! descriptor, a port reset that re-enumerates, partial transfer failures. Needs no shared data
//! (synthetic profile and scene).

mod common;

use std::time::Duration;

use kinect_usb::device::{Frame, KinectDevice, MAX_BYTES_PER_INTERVAL, OpenOptions, State};
use kinect_usb::raw::PIXELS;
use kinect_usb::sim::{SimDevice, SimFaults, SimProfile, SimScene};
use kinect_usb::{KinectError, UsbError};

const T: Duration = Duration::from_secs(1);

fn profile() -> SimProfile {
    common::synthetic_profile()
}

/// One flat wall at 1.5 m.
fn depth_scene() -> SimScene {
    SimScene {
        depth_frames: vec![(vec![1500.0; PIXELS], vec![2000.0; PIXELS])],
        color_jpegs: vec![],
    }
}

/// Pulls `n` depth frames and returns their sequence numbers.
fn depth_sequences<B: kinect_usb::backend::UsbBackend>(
    dev: &mut KinectDevice<B>,
    n: usize,
) -> Vec<u32> {
    (0..n)
        .map(|_| match dev.next_frame(T, &mut |_, _| {}) {
            Ok(Some(Frame::Depth(f))) => f.sequence,
            other => panic!("expected a depth frame, got {other:?}"),
        })
        .collect()
}

/// The device's companion descriptor says 36 864 bytes per interval (36 × 1024, not the
/// 33 792 real sensors report) and it fills its packets up to that: the host sizes its
/// packet slots from the descriptor, so no packet overflows and every frame completes (with
/// the old constant 33 792 every full packet overflowed and no frame ever completed).
#[test]
fn depth_packets_are_sized_from_the_descriptor() {
    let mut p = profile();
    p.bytes_per_interval = 36_864;
    let mut dev =
        KinectDevice::open(SimDevice::new(p, depth_scene(), SimFaults::default())).unwrap();
    assert_eq!(dev.depth_packet_size(), 36_864);
    dev.start(false, true).unwrap();
    assert_eq!(depth_sequences(&mut dev, 3), [0, 1, 2]);
    let c = dev.counters();
    assert_eq!((c.depth_frames, c.iso_errors, c.depth_incomplete, c.depth_dropped), (3, 0, 0, 0));
}

/// The largest descriptor value a SuperSpeed endpoint can have (3 × 16 × 1024) is used as is;
/// one byte more, or 0, is refused at open with an error that says why.
#[test]
fn bytes_per_interval_is_bounded_at_open() {
    let mut p = profile();
    p.bytes_per_interval = MAX_BYTES_PER_INTERVAL;
    let mut dev =
        KinectDevice::open(SimDevice::new(p.clone(), depth_scene(), SimFaults::default())).unwrap();
    assert_eq!(dev.depth_packet_size(), 49_152);
    dev.start(false, true).unwrap();
    assert_eq!(depth_sequences(&mut dev, 2), [0, 1]);

    p.bytes_per_interval = MAX_BYTES_PER_INTERVAL + 1;
    let e = KinectDevice::open(SimDevice::new(p.clone(), depth_scene(), SimFaults::default()))
        .err()
        .unwrap();
    assert!(
        matches!(&e, KinectError::Protocol { detail, .. }
            if detail.contains("wBytesPerInterval 49153") && detail.contains("corrupt descriptor")),
        "{e}"
    );
    p.bytes_per_interval = 0;
    let e =
        KinectDevice::open(SimDevice::new(p, depth_scene(), SimFaults::default())).err().unwrap();
    assert!(matches!(e, KinectError::InsufficientBandwidth { got: 0, need: 33_792 }), "{e}");
}

/// The port reset re-enumerates the sensor: open closes the dead handle, waits, finds the same
/// serial again and opens it once without another reset, then configures it as usual (with
/// the old behaviour open went on with the dead handle and failed "disappeared … while
/// reading configuration").
#[test]
fn reset_that_reenumerates_reopens_the_same_serial() {
    let faults = SimFaults { reset_reenumerates: true, ..SimFaults::default() };
    let wait = Duration::from_millis(30);
    let t0 = std::time::Instant::now();
    let mut dev = KinectDevice::open_with(
        SimDevice::new(profile(), depth_scene(), faults),
        OpenOptions { reenumeration_wait: wait },
    )
    .unwrap();
    assert!(t0.elapsed() >= wait, "waited {:?}", t0.elapsed());
    let tr = &dev.backend().transcript;
    assert_eq!(
        tr[..6],
        ["reset", "close", "reopen serial 000000000001", "set_config 1", "claim 0", "claim 1"]
    );
    assert_eq!(tr.iter().filter(|l| *l == "reset").count(), 1, "{tr:?}");
    dev.start(false, true).unwrap();
    assert_eq!(depth_sequences(&mut dev, 2), [0, 1]);
    assert!(dev.backend().violations.is_empty(), "{:?}", dev.backend().violations);
    // libfreenect2's wait is the default.
    assert_eq!(OpenOptions::default().reenumeration_wait, Duration::from_secs(1));
}

/// The sensor does not come back after the re-enumeration: open fails with an error that says
/// so and names the wait, not with the dead handle's "disappeared".
#[test]
fn reset_that_reenumerates_and_never_returns_is_a_clear_error() {
    let faults = SimFaults {
        reset_reenumerates: true,
        lost_after_reenumeration: true,
        ..SimFaults::default()
    };
    let e = KinectDevice::open_with(
        SimDevice::new(profile(), depth_scene(), faults),
        OpenOptions { reenumeration_wait: Duration::from_millis(20) },
    )
    .err()
    .unwrap();
    assert!(matches!(e, KinectError::NotBackAfterReset { waited_ms: 20 }), "{e}");
    let msg = e.to_string();
    assert!(msg.contains("re-enumerated") && msg.contains("same serial"), "{msg}");
}

/// 20 of the 60 depth transfers cannot be submitted (usbfs out of memory): the stream starts
/// with the other 40, as libfreenect2's, reports the 20 retired transfers and says what to do
/// (with the old behaviour one failed submission failed the start).
#[test]
fn partial_submission_starts_and_names_the_usbfs_fix() {
    let faults =
        SimFaults { depth_submit_failures: Some((20, UsbError::NoMem)), ..SimFaults::default() };
    let mut dev = KinectDevice::open(SimDevice::new(profile(), depth_scene(), faults)).unwrap();
    dev.start(false, true).unwrap();
    assert_eq!(depth_sequences(&mut dev, 3), [0, 1, 2]);
    let c = dev.counters();
    assert_eq!((c.transfers_retired, c.depth_frames), (20, 3));
    let retired: Vec<&String> =
        dev.warnings.iter().filter(|w| w.contains("transfer was retired")).collect();
    assert_eq!(retired.len(), 20);
    assert!(
        retired.iter().all(|w| w.contains("40 still in flight")
            && w.contains("echo 0 | sudo tee /sys/module/usbcore/parameters/usbfs_memory_mb")),
        "{retired:?}"
    );
}

/// No depth transfer can be submitted for lack of memory: start fails with an error that says
/// so and names both fixes, and the session rolls back to Open.
#[test]
fn no_transfer_submitted_for_lack_of_memory_is_a_usbfs_error() {
    let faults =
        SimFaults { depth_submit_failures: Some((60, UsbError::NoMem)), ..SimFaults::default() };
    let mut dev = KinectDevice::open(SimDevice::new(profile(), depth_scene(), faults)).unwrap();
    let e = dev.start(false, true).unwrap_err();
    assert!(matches!(&e, KinectError::UsbMemory { what } if what == "start depth stream"), "{e}");
    let msg = e.to_string();
    for needle in [
        "usbfs_memory_mb",
        "echo 0 | sudo tee /sys/module/usbcore/parameters/usbfs_memory_mb",
        "usbcore.usbfs_memory_mb=",
    ] {
        assert!(msg.contains(needle), "{needle} missing: {msg}");
    }
    assert_eq!(dev.state(), State::Open);
}

/// Transfers whose resubmission fails are retired one by one while the stream goes on; it
/// ends (`Stalled`) only when the last one is retired. 57 of 60 fail to submit (I/O), then the
/// 3 left fail their resubmission at the end of frame periods 0, 1 and 2: frames 0, 1 and 2
/// arrive, then the stream stops (with the old behaviour the first failed resubmission ended
/// it).
#[test]
fn failed_resubmissions_retire_transfers_until_none_remain() {
    let faults = SimFaults {
        depth_submit_failures: Some((57, UsbError::Io)),
        depth_resubmit_failures: 3,
        ..SimFaults::default()
    };
    let mut dev = KinectDevice::open(SimDevice::new(profile(), depth_scene(), faults)).unwrap();
    dev.start(false, true).unwrap();
    assert_eq!(depth_sequences(&mut dev, 3), [0, 1, 2]);
    let e = dev.next_frame(T, &mut |_, _| {}).unwrap_err();
    assert!(e.to_string().contains("Stalled"), "{e}");
    let c = dev.counters();
    assert_eq!((c.transfers_retired, c.depth_frames, c.iso_errors), (60, 3, 0));
    assert!(dev.warnings.iter().any(|w| w.contains("(USB I/O error); 0 still in flight")));
}

/// A few failed resubmissions in a full pool do not interrupt the stream at all.
#[test]
fn a_failed_resubmission_does_not_end_the_stream() {
    let faults = SimFaults { depth_resubmit_failures: 5, ..SimFaults::default() };
    let mut dev = KinectDevice::open(SimDevice::new(profile(), depth_scene(), faults)).unwrap();
    dev.start(false, true).unwrap();
    assert_eq!(depth_sequences(&mut dev, 8), [0, 1, 2, 3, 4, 5, 6, 7]);
    assert_eq!(dev.counters().transfers_retired, 5);
    assert!(dev.warnings.iter().any(|w| w.contains("55 still in flight")), "{:?}", dev.warnings);
}
