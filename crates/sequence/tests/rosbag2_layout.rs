//! The rosbag2 layout end to end on the simulated sensor's recording (issue 48): the MCAP file
//! read back with the `mcap` crate's reader (summary, chunk index, every message) and every
//! message decoded with `kfuse-ros-msgs`; the registered depth equals the kfuse layout's PNG of
//! the same frame, the stamps are the index's sensor times mapped to host time (the recording's
//! last frame at its file's modification time) and agree with the host times at which the
//! recorder counted each frame (within [`ANCHOR_TOLERANCE_NS`] and the simulator's bursts); `sd/points` equals the kfuse layout's PLY
//! cloud of the same frame; a stopped run leaves a complete bag; the options the layout cannot
//! take are refused before anything is written. The independent readers (`rosbags`,
//! `mcap-ros2-support`) are python/tests/test_rosbag2.py's.

use std::collections::BTreeMap;
use std::error::Error as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use fusion_gpu::Engine;
use geometry::Rig;
use geometry::fusion::FusionOptions;
use kfuse_capture::{SensorSource, Session, SimOptions};
use kfuse_io::atomic::StagedDir;
use kfuse_ros_msgs::{CameraInfo, CompressedImage, Image, Message, PointCloud2, TFMessage};
use kfuse_sequence::command::{self, Observer, SequenceInput, SequenceOptions};
use kfuse_sequence::matching::DEFAULT_MAX_SKEW_TICKS;
use kfuse_sequence::pipeline::Kept;
use kfuse_sequence::rosbag2::{NANOS_PER_TICK, namespace};
use kfuse_sequence::source::TICKS_PER_SECOND;
use kfuse_sequence::write::{FileSet, IndexEntry, Layout};
use kinect_usb::recording::ReadOptions;

/// Depth frames recorded.
const FRAMES: u64 = 4;

/// Largest distance between the last frame's bag stamp (the anchor: the recording file's
/// modification time) and the host time at which the recorder counted that frame: 50 ms. The
/// file time is the kernel's coarse clock (late by up to one scheduler tick, 4 ms at 250 Hz;
/// measured 2.6 and 5.4 ms), and the end record is written after the recorder counted the
/// frame (a preempted thread on a loaded machine adds its wait).
const ANCHOR_TOLERANCE_NS: i128 = 50_000_000;

/// A sensor frame period of the simulated sensor, ns: 267 ticks.
const SIM_PERIOD_NS: i128 = 267 * 125_000;

fn unix_ns(t: std::time::SystemTime) -> u64 {
    t.duration_since(std::time::UNIX_EPOCH).unwrap().as_nanos() as u64
}

/// The recording, its rig, the sensor's serial, and the host time (Unix ns) at which the
/// recorder counted each depth frame.
fn record(dir: &Path) -> (PathBuf, Rig, String) {
    let (path, rig, serial, _) = record_timed(dir);
    (path, rig, serial)
}

fn record_timed(dir: &Path) -> (PathBuf, Rig, String, Vec<u64>) {
    let path = dir.join("sim.kfrec");
    let mut session = Session::open(&SensorSource::Sim(SimOptions::default())).unwrap();
    let mut host = Vec::new();
    let mut counted = |n: u64| {
        let now = unix_ns(std::time::SystemTime::now());
        host.resize(n as usize, now);
    };
    kfuse_capture::record::record(&mut session, &path, FRAMES, &|| false, &mut counted).unwrap();
    kfuse_capture::write_params_json(dir, session.info()).unwrap();
    let params = [dir.join("kinect_params.json")];
    let opts = kfuse_io::rig_io::ImportOptions::default();
    let rig = match kfuse_io::rig_io::import(&params, &opts).unwrap().calibration {
        kfuse_io::rig_io::Calibration::Rig(r) => r,
        _ => panic!("kinect_params.json is a rig"),
    };
    (path, rig, session.info().serial.clone(), host)
}

/// The host time of sensor time `ticks` by the layout's rule, computed here from the file's
/// modification time and the last frame's sensor time in the kfuse layout's index.
fn host_ns(rec: &Path, frames: &[IndexEntry], ticks: u64) -> u64 {
    let mtime = unix_ns(std::fs::metadata(rec).unwrap().modified().unwrap());
    let last = frames.last().unwrap().depth_time_ticks.unwrap();
    (mtime as i128 + (ticks as i128 - last as i128) * NANOS_PER_TICK as i128) as u64
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
        points: false,
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
    fuse_with(rec, rig, out, options(layout, FileSet::default()), stop)
}

fn fuse_with(
    rec: &Path,
    rig: &Rig,
    out: &Path,
    o: SequenceOptions,
    stop: &(dyn Fn() -> bool + Sync),
) -> command::Finished {
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
        frames.iter().map(|f| host_ns(&rec, frames, f.depth_time_ticks.unwrap())).collect();
    // Unix time of this century, not the sensor's clock.
    assert!(depth_ns[0] > 1_600_000_000_000_000_000, "{}", depth_ns[0]);
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
    let color_ns: Vec<u64> = frames
        .iter()
        .filter_map(|f| f.color.as_ref().and_then(|c| c.time_ticks))
        .map(|t| host_ns(&rec, frames, t))
        .collect();
    for (t, data) in colors {
        assert!(color_ns.contains(t), "colour stamp {t} is no frame's colour time");
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
fn stamps_are_the_host_times_the_recorder_received_the_frames_at() {
    let dir = tempfile::tempdir().unwrap();
    let (rec, rig, serial, host) = record_timed(dir.path());
    assert_eq!(host.len(), FRAMES as usize);
    let bag = dir.path().join("bag");
    let finished = fuse(&rec, &rig, &bag, Layout::Rosbag2, &|| false);
    let frames = &finished.index.frames;
    let rect = format!("{}/hd/image_depth_rect", namespace(&serial));
    let (messages, _) = read_mcap(&bag.join("bag_0.mcap"));
    let stamps: Vec<u64> = messages.iter().filter(|m| m.0 == rect).map(|m| m.1).collect();
    assert_eq!(stamps.len(), frames.len());
    // The last frame at the file's modification time, the others by the sensor's spacing.
    let mtime = unix_ns(std::fs::metadata(&rec).unwrap().modified().unwrap());
    assert_eq!(*stamps.last().unwrap(), mtime);
    for (w, f) in stamps.windows(2).zip(frames.windows(2)) {
        let ticks = f[1].depth_time_ticks.unwrap() - f[0].depth_time_ticks.unwrap();
        assert_eq!(w[1] - w[0], ticks * NANOS_PER_TICK);
    }
    // Frame j from the end: received (host time) no earlier than its stamp less the anchor's
    // tolerance, and no later than j frame periods after it plus that tolerance: the simulated
    // sensor produces the periods a late host missed in one burst (`SimPacing::RealTime`; the
    // recorder starts after the streams did), so earlier frames can arrive bunched with the
    // last one, but never before their own sensor time. A bag in the sensor's clock is
    // decades off.
    let mut lags = Vec::new();
    for (j, (&s, &h)) in stamps.iter().rev().zip(host.iter().rev()).enumerate() {
        let lag = i128::from(h) - i128::from(s);
        let most = j as i128 * SIM_PERIOD_NS + ANCHOR_TOLERANCE_NS;
        assert!(
            (-ANCHOR_TOLERANCE_NS..=most).contains(&lag),
            "frame {j} from the end: received {lag} ns after its stamp, outside -{ANCHOR_TOLERANCE_NS}..={most}"
        );
        lags.push(lag as f64 / 1e6);
    }
    eprintln!("host time - bag stamp, last frame first (ms): {lags:.1?}");
}

#[test]
fn points_equal_the_kfuse_layouts_ply_clouds() {
    let dir = tempfile::tempdir().unwrap();
    let (rec, rig, serial) = record(dir.path());
    let bag = dir.path().join("bag");
    let finished = fuse_with(
        &rec,
        &rig,
        &bag,
        SequenceOptions { points: true, ..options(Layout::Rosbag2, FileSet::default()) },
        &|| false,
    );
    let seq = dir.path().join("seq");
    let cloud_files = FileSet { cloud: true, ..FileSet::default() };
    let kfuse = fuse_with(&rec, &rig, &seq, options(Layout::Kfuse, cloud_files), &|| false);
    let frames = &kfuse.index.frames;
    assert_eq!(finished.index.frames.len(), frames.len());
    let topic = format!("{}/sd/points", namespace(&serial));
    let (messages, summary) = read_mcap(&bag.join("bag_0.mcap"));
    assert_eq!(summary.channels.len(), 8);
    let clouds: Vec<PointCloud2> = messages
        .iter()
        .filter(|m| m.0 == topic)
        .map(|m| PointCloud2::from_cdr(&m.3).unwrap())
        .collect();
    assert_eq!(clouds.len(), frames.len());
    let mut colored = 0;
    for (c, f) in clouds.iter().zip(frames) {
        let ply =
            std::fs::read(seq.join(f.files.iter().find(|n| n.starts_with("cloud/")).unwrap()))
                .unwrap();
        let end = b"end_header
";
        let at = ply.windows(end.len()).position(|w| w == end).unwrap() + end.len();
        let head = std::str::from_utf8(&ply[..at]).unwrap();
        let n: usize =
            head.lines().find_map(|l| l.strip_prefix("element vertex ")).unwrap().parse().unwrap();
        let rgb = head.contains("property uchar red");
        let stride = if rgb { 15 } else { 12 };
        assert_eq!((c.height, c.width as usize), (1, n));
        assert!(n > 100_000, "{n} points");
        assert_eq!((c.point_step, c.row_step as usize, c.data.len()), (16, 16 * n, 16 * n));
        let names: Vec<_> =
            c.fields.iter().map(|f| (f.name.as_str(), f.offset, f.datatype, f.count)).collect();
        assert_eq!(names, [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("rgb", 12, 7, 1)]);
        assert!(c.is_dense && !c.is_bigendian);
        assert!(c.header.frame_id.ends_with("_ir_optical_frame"));
        for (p, v) in c.data.chunks_exact(16).zip(ply[at..].chunks_exact(stride)) {
            // x, y, z: the PLY's float32s, bit for bit.
            assert_eq!(&p[..12], &v[..12]);
            let packed = u32::from_le_bytes([p[12], p[13], p[14], p[15]]);
            let want = if rgb {
                (u32::from(v[12]) << 16) | (u32::from(v[13]) << 8) | u32::from(v[14])
            } else {
                0
            };
            assert_eq!(packed, want);
            colored += usize::from(packed != 0);
        }
    }
    assert!(colored > 100_000, "{colored} coloured points");
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
fn a_recording_dated_before_1970_is_one_clear_error_and_writes_nothing() {
    use std::time::{Duration, UNIX_EPOCH};
    let dir = tempfile::tempdir().unwrap();
    let (rec, rig, _) = record(dir.path());
    let date =
        |t| std::fs::File::options().write(true).open(&rec).unwrap().set_modified(t).unwrap();
    let out = dir.path().join("bag");
    let o = options(Layout::Rosbag2, FileSet::default());
    // Its last frame 10 ms after the epoch: the first ones would be stamped before it.
    date(UNIX_EPOCH + Duration::from_millis(10));
    let opened = command::open(&input(&rec), &out, &o).unwrap();
    let e = command::run(opened, &rig, &o, &mut Quiet, &|| false).unwrap_err();
    // The whole chain, as the command line prints it on one line.
    let mut e: (String, Option<&dyn std::error::Error>) = (e.to_string(), e.source());
    while let Some(s) = e.1 {
        e = (format!("{}: {s}", e.0), s.source());
    }
    let e = e.0;
    assert!(e.contains("before 1970") && e.contains("bag_0.mcap"), "{e}");
    assert!(e.contains("/hd/image_depth_rect") && !e.contains('\n'), "{e}");
    assert!(!out.exists());
    // A file time before the epoch: refused when opened.
    date(UNIX_EPOCH - Duration::from_secs(86_400));
    let e = command::open(&input(&rec), &out, &o).err().expect("refused").to_string();
    assert!(e.contains("sim.kfrec") && e.contains("before 1970") && e.contains("touch -d"), "{e}");
    assert!(!out.exists());
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
    let points = SequenceOptions { points: true, ..options(Layout::Kfuse, FileSet::default()) };
    let e = points.check(&input(&dir.path().join("x.kfrec"))).unwrap_err();
    assert!(e.to_string().contains("--layout rosbag2"), "{e}");
    assert!(!out.exists());
}
