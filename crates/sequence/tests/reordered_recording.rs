//! A recording whose depth records go backwards (a duplicated USB block, a reordered pair of
//! frames) is read as what it is (issue 51): each out-of-order frame is one entry of the
//! missing list, never a 16-bit wrap-around of 65 534 frames lost; frame numbers (the output
//! file names) are unique and increasing, and so are the timestamps (the TUM lists).
//! The recording is the simulated sensor's, its depth records regrouped per frame and written
//! again in another order with the recording writer.

use kfuse_capture::{SensorSource, Session, SimOptions};
use kfuse_sequence::matching::{DEFAULT_MAX_SKEW_TICKS, Matched, Matcher, MissingReason};
use kfuse_sequence::source::RecordingSource;
use kinect_usb::backend::XferStatus;
use kinect_usb::device::StreamKind;
use kinect_usb::recording::{ReadOptions, RecordedEvent, RecordingWriter, read_recording_file};
use kinect_usb::stream::DepthAssembler;

/// Depth frames recorded.
const FRAMES: u64 = 6;

/// The depth records of each complete depth frame, in order, with its sequence number.
fn depth_frames(events: &[RecordedEvent]) -> Vec<(u32, Vec<RecordedEvent>)> {
    let mut asm = DepthAssembler::new();
    let (mut frames, mut group) = (Vec::new(), Vec::new());
    for e in events.iter().filter(|e| e.kind == StreamKind::Depth) {
        group.push(e.clone());
        if e.status != XferStatus::Completed {
            continue;
        }
        if let Some(f) = asm.push(&e.data) {
            frames.push((f.sequence, std::mem::take(&mut group)));
        }
    }
    frames
}

#[test]
fn duplicated_and_reordered_depth_frames_are_left_out_one_entry_each() {
    let dir = tempfile::tempdir().unwrap();
    let recorded = dir.path().join("sim.kfrec");
    let mut session = Session::open(&SensorSource::Sim(SimOptions::default())).unwrap();
    kfuse_capture::record::record(&mut session, &recorded, FRAMES, &|| false, &mut |_| {}).unwrap();
    let rec = read_recording_file(&recorded, false).unwrap();
    let frames = depth_frames(&rec.events);
    assert!(frames.len() >= 6, "{} depth frames recorded", frames.len());
    let s0 = frames[0].0;
    let seqs: Vec<u32> = frames.iter().map(|f| f.0).collect();
    assert_eq!(seqs[..6], (s0..s0 + 6).collect::<Vec<_>>(), "the simulator drops no frame");

    // Frames 0 1 2, frame 1's block again, 3, then 5 before 4.
    let order = [0usize, 1, 2, 1, 3, 5, 4];
    let damaged = dir.path().join("reordered.kfrec");
    let mut w = RecordingWriter::new(std::fs::File::create(&damaged).unwrap(), &rec.meta).unwrap();
    for &k in &order {
        for e in &frames[k].1 {
            w.write_event(e.kind, &e.to_event()).unwrap();
        }
    }
    w.finish().unwrap();

    let mut src = RecordingSource::open(&damaged, ReadOptions::default()).unwrap();
    let mut m = Matcher::new(DEFAULT_MAX_SKEW_TICKS);
    let mut out = Vec::new();
    while let Some(ev) = src.next_event().unwrap() {
        m.push(ev);
        while let Some(r) = m.pop() {
            out.push(r);
        }
    }
    m.finish();
    while let Some(r) = m.pop() {
        out.push(r);
    }
    let mut written = Vec::new();
    let mut missing = Vec::new();
    for r in &out {
        match r {
            Matched::Frame(p) => written.push((p.number, p.depth.sequence, p.depth.timestamp)),
            Matched::Missing(x) => missing.push((x.number, x.depth_sequence, x.reason)),
        }
    }
    let numbered: Vec<(u64, u32)> = written.iter().map(|w| (w.0, w.1)).collect();
    assert_eq!(numbered, vec![(0, s0), (1, s0 + 1), (2, s0 + 2), (3, s0 + 3), (5, s0 + 5)]);
    assert_eq!(
        missing,
        vec![
            (2, s0 + 1, MissingReason::OutOfOrder),
            (4, s0 + 4, MissingReason::Dropped),
            (5, s0 + 4, MissingReason::OutOfOrder),
        ]
    );
    // Output files are named by frame number: one per number; TUM times go forward.
    assert!(written.windows(2).all(|w| w[0].0 < w[1].0 && w[0].2 < w[1].2), "{written:?}");
}
