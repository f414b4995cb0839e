//! The rosbag2 layout end to end on the simulated sensor's recording (issue 48): the MCAP file
//! read back with the `mcap` crate's reader (summary, chunk index, every message) and every
//! message decoded with `kfuse-ros-msgs`; the registered depth equals the kfuse layout's PNG of
//! the same frame, the stamps equal the index's times; a stopped run leaves a complete bag; the
//! options the layout cannot take are refused before anything is written. The independent
//! readers (`rosbags`, `mcap-ros2-support`) are python/tests/test_rosbag2.py's.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use fusion_gpu::Engine;
use geometry::Rig;
use geometry::fusion::FusionOptions;
use kfuse_capture::{SensorSource, Session, SimOptions};
use kfuse_io::atomic::StagedDir;
use kfuse_ros_msgs::{CameraInfo, CompressedImage, Image, Message, TFMessage};
use kfuse_sequence::command::{self, Observer, SequenceInput, SequenceOptions};
use kfuse_sequence::matching::DEFAULT_MAX_SKEW_TICKS;
use kfuse_sequence::pipeline::Kept;
use kfuse_sequence::rosbag2::{NANOS_PER_TICK, namespace};
use kfuse_sequence::source::TICKS_PER_SECOND;
use kfuse_sequence::write::{FileSet, IndexEntry, Layout};
use kinect_usb::recording::ReadOptions;

/// Depth frames recorded.
const FRAMES: u64 = 4;

fn record(dir: &Path) -> (PathBuf, Rig, String) {
    let path = dir.join("sim.kfrec");
    let mut session = Session::open(&SensorSource::Sim(SimOptions::default())).unwrap();
    kfuse_capture::record::record(&mut session, &path, FRAMES, &|| false, &mut |_| {}).unwrap();
    kfuse_capture::write_params_json(dir, session.info()).unwrap();
    let params = [dir.join("kinect_params.json")];
    let opts = kfuse_io::rig_io::ImportOptions::default();
    let rig = match kfuse_io::rig_io::import(&params, &opts).unwrap().calibration {
        kfuse_io::rig_io::Calibration::Rig(r) => r,
        _ => panic!("kinect_params.json is a rig"),
    };
    (path, rig, session.info().serial.clone())
}

struct Quiet;

impl Observer for Quiet {
    fn note(&mut self, _: &str) {}
    fn frame(&mut self, _: &IndexEntry, _: u64) {}
    fn warn(&mut self, _: String) {}
    fn kept(&mut self, _: &StagedDir, _: &Kept) {}
}

fn options(layout: Layout, files: FileSet) -> SequenceOptions {
    SequenceOptions {
        layout,
        files,
        keep_every: None,
        threads: 2,
        max_skew_ms: DEFAULT_MAX_SKEW_TICKS as f64 * 1e3 / TICKS_PER_SECOND as f64,
        engine: Engine::Cpu,
        fusion: FusionOptions::default(),
        kept_color: false,
    }
}

fn input(rec: &Path) -> SequenceInput {
    SequenceInput::Recording(rec.to_path_buf(), ReadOptions::default())
}

fn fuse(
    rec: &Path,
    rig: &Rig,
    out: &Path,
    layout: Layout,
    stop: &(dyn Fn() -> bool + Sync),
) -> command::Finished {
    let o = options(layout, FileSet::default());
    let opened = command::open(&input(rec), out, &o).unwrap();
    command::run(opened, rig, &o, &mut Quiet, stop).unwrap()
}

/// A message read back: (topic, log time, publish time, bytes).
type Read = (String, u64, u64, Vec<u8>);

/// Every message of an MCAP file and its summary.
fn read_mcap(path: &Path) -> (Vec<Read>, mcap::Summary) {
    let bytes = std::fs::read(path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("the file has a summary");
    let messages = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            (m.channel.topic.clone(), m.log_time, m.publish_time, m.data.into_owned())
        })
        .collect();
    (messages, summary)
}

#[test]
fn every_message_decodes_and_matches_the_kfuse_layout() {
    let dir = tempfile::tempdir().unwrap();
    let (rec, rig, serial) = record(dir.path());
    let bag = dir.path().join("bag");
    let finished = fuse(&rec, &rig, &bag, Layout::Rosbag2, &|| false);
    let seq = dir.path().join("seq");
    let kfuse = fuse(&rec, &rig, &seq, Layout::Kfuse, &|| false);
    let frames = &kfuse.index.frames;
    assert!(frames.len() >= FRAMES as usize - 1, "{} frames", frames.len());
    assert_eq!(finished.index.frames.len(), frames.len());
    assert_eq!(finished.index.layout, Layout::Rosbag2);
    assert!(
        finished.index.depth_png.contains("hd/image_depth_rect"),
        "{}",
        finished.index.depth_png
    );

    let (messages, summary) = read_mcap(&bag.join("bag_0.mcap"));
    assert!(!summary.chunk_indexes.is_empty(), "no chunk index: readers cannot seek");
    assert!(summary.chunk_indexes.iter().all(|c| c.compression == "zstd"));
    assert_eq!(summary.stats.as_ref().unwrap().message_count, messages.len() as u64);
    assert_eq!(summary.channels.len(), 7);
    for ch in summary.channels.values() {
        assert_eq!(ch.message_encoding, "cdr");
        assert!(ch.metadata.contains_key("offered_qos_profiles"), "{}", ch.topic);
        assert_eq!(ch.schema.as_ref().unwrap().encoding, "ros2msg");
    }

    let ns = namespace(&serial);
    let mut by_topic: BTreeMap<String, Vec<(u64, Vec<u8>)>> = BTreeMap::new();
    for (topic, log, publish, data) in messages {
        assert_eq!(log, publish);
        by_topic.entry(topic).or_default().push((log, data));
    }
    let depth_ns: Vec<u64> =
        frames.iter().map(|f| f.depth_time_ticks.unwrap() * NANOS_PER_TICK).collect();
    let topic = |rel: &str| format!("{ns}/{rel}");
    for rel in ["sd/image_depth", "sd/image_ir", "hd/image_depth_rect"] {
        let msgs = &by_topic[&topic(rel)];
        assert_eq!(msgs.iter().map(|m| m.0).collect::<Vec<_>>(), depth_ns, "{rel}");
        for (t, data) in msgs {
            let img = Image::from_cdr(data).unwrap();
            let stamp =
                img.header.stamp.sec as u64 * 1_000_000_000 + u64::from(img.header.stamp.nanosec);
            assert_eq!(stamp, *t);
            assert_eq!(img.encoding, "16UC1");
            assert_eq!(img.data.len(), img.step as usize * img.height as usize);
        }
    }
    // Registered depth: the kfuse layout's PNG, value for value.
    for ((_, data), f) in by_topic[&topic("hd/image_depth_rect")].iter().zip(frames) {
        let img = Image::from_cdr(data).unwrap();
        let png = image::open(seq.join(&f.files[0])).unwrap().into_luma16();
        assert_eq!((img.width, img.height), png.dimensions());
        let values: Vec<u16> =
            img.data.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
        assert_eq!(values, png.into_raw(), "{}", f.files[0]);
        assert!(values.iter().filter(|&&v| v > 0).count() > 100_000);
    }
    for rel in ["sd/camera_info", "hd/camera_info"] {
        let msgs = &by_topic[&topic(rel)];
        assert_eq!(msgs.len(), frames.len());
        let ci = CameraInfo::from_cdr(&msgs[0].1).unwrap();
        let cam = if rel.starts_with("sd") { &rig.depth } else { &rig.color };
        assert_eq!((ci.width as usize, ci.height as usize), (cam.width, cam.height));
        assert_eq!(ci.k[0], cam.intrinsics.fx);
    }
    let colors = &by_topic[&topic("hd/image_color/compressed")];
    assert!(!colors.is_empty());
    for (_, data) in colors {
        let c = CompressedImage::from_cdr(data).unwrap();
        assert_eq!(c.format, "jpeg");
        assert_eq!(&c.data[..2], &[0xFF, 0xD8]);
    }
    let tf = &by_topic["/tf_static"];
    assert_eq!(tf.len(), 1);
    assert_eq!(tf[0].0, depth_ns[0]);
    let t = TFMessage::from_cdr(&tf[0].1).unwrap();
    let v = t.transforms[0].transform.translation;
    let want = rig.color_from_depth.translation;
    assert_eq!([v.x, v.y, v.z], [want.x, want.y, want.z]);

    let meta = std::fs::read_to_string(bag.join("metadata.yaml")).unwrap();
    assert!(meta.contains("  version: 5\n"), "{meta}");
    let total: usize = by_topic.values().map(Vec::len).sum();
    assert!(meta.contains(&format!("  message_count: {total}\n")), "{meta}");
}

#[test]
fn a_stopped_run_leaves_a_complete_bag() {
    let dir = tempfile::tempdir().unwrap();
    let (rec, rig, serial) = record(dir.path());
    let bag = dir.path().join("bag");
    // Stop after the second frame is read.
    let polls = AtomicUsize::new(0);
    let stop = || polls.fetch_add(1, Ordering::SeqCst) >= 2;
    let finished = fuse(&rec, &rig, &bag, Layout::Rosbag2, &stop);
    assert!(finished.outcome.interrupted);
    let n = finished.index.frames.len();
    assert!((1..FRAMES as usize).contains(&n), "{n} frames");
    let (messages, summary) = read_mcap(&bag.join("bag_0.mcap"));
    assert_eq!(summary.stats.unwrap().message_count, messages.len() as u64);
    let rect = format!("{}/hd/image_depth_rect", namespace(&serial));
    assert_eq!(messages.iter().filter(|m| m.0 == rect).count(), n);
    assert!(std::fs::read_to_string(bag.join("metadata.yaml")).unwrap().contains(&rect));
}

#[test]
fn options_the_layout_cannot_take_are_refused_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let with_color = options(Layout::Rosbag2, FileSet { color: true, ..FileSet::default() });
    let e = command::open(&input(&dir.path().join("x.kfrec")), &out, &with_color)
        .err()
        .expect("--write with the rosbag2 layout is refused");
    assert!(e.to_string().contains("drop --write"), "{e}");
    let frames = SequenceInput::Frames(dir.path().to_path_buf());
    let e = options(Layout::Rosbag2, FileSet::default()).check(&frames).unwrap_err();
    assert!(e.to_string().contains("rosbag2"), "{e}");
    assert!(!out.exists());
}
