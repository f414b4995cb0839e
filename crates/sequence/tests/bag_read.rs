//! Reading bags (issue 48, item 3): a bag kfuse wrote with `--layout rosbag2` read back with
//! [`kfuse_sequence::bag::BagSource`], its rig rebuilt from its camera_infos and `/tf_static`,
//! and fused into the kfuse layout: the registered depth equals that of the `.kfrec` it came
//! from within the bag's millimetre rounding (see the test). Bad input: a truncated MCAP file, a
//! chunk whose CRC does not match, a record that claims 10 GB, a bag without camera_info, an
//! image whose step disagrees with its size: one error naming the file (and the topic), and
//! nothing in `--out`. The independent writer (`rosbags`) is python/tests/test_rosbag_read.py's.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use fusion_gpu::Engine;
use geometry::Rig;
use geometry::fusion::FusionOptions;
use kfuse_capture::{SensorSource, Session, SimOptions};
use kfuse_io::atomic::StagedDir;
use kfuse_ros_msgs::{Image, Message};
use kfuse_sequence::bag::{BagSource, TopicChoice};
use kfuse_sequence::command::{self, Observer, SequenceInput, SequenceOptions};
use kfuse_sequence::matching::DEFAULT_MAX_SKEW_TICKS;
use kfuse_sequence::pipeline::Kept;
use kfuse_sequence::source::TICKS_PER_SECOND;
use kfuse_sequence::write::{FileSet, IndexEntry, Layout};
use kinect_usb::recording::ReadOptions;

/// Depth frames recorded.
const FRAMES: u64 = 4;

// The registered depth of a bag cannot equal the recording's exactly: the bag's
// `sd/image_depth` holds the decoder's depth rounded to whole millimetres (16UC1), the
// recording's pipeline registers the unrounded depth. Moving a point by up to 0.5 mm in z
// moves its splat by a fraction of a colour pixel, so (measured on the simulated frames:
// 184 026 pixels with a sample in both, 184 004 equal, 20 off by more than 1 mm, 939 of the
// 2 073 600 pixels gaining or losing a sample):

/// Share of the pixels with a sample in both whose values must be equal.
const MIN_EQUAL_SHARE: f64 = 0.999;

/// A value may differ by this many millimetres (the rounding: 0.5 mm in the depth camera's z,
/// up to 1 mm after the colour camera's z is rounded again)…
const DEPTH_TOLERANCE_MM: u16 = 1;

/// …except at occlusion edges, where the shifted splat of a nearer surface covers or uncovers a
/// farther one: at most this share of the pixels with a sample in both.
const MAX_EDGE_SHARE: f64 = 0.0005;

/// Pixels that gain or lose a sample (a splat's edge crossing a pixel's), as a share of the
/// recording's pixels with a sample.
const MAX_COVERAGE_CHANGE: f64 = 0.01;

struct Quiet;

impl Observer for Quiet {
    fn note(&mut self, _: &str) {}
    fn frame(&mut self, _: &IndexEntry, _: u64) {}
    fn warn(&mut self, _: String) {}
    fn kept(&mut self, _: &StagedDir, _: &Kept) {}
}

fn options(layout: Layout) -> SequenceOptions {
    SequenceOptions {
        layout,
        files: FileSet::default(),
        keep_every: None,
        threads: 2,
        max_skew_ms: DEFAULT_MAX_SKEW_TICKS as f64 * 1e3 / TICKS_PER_SECOND as f64,
        engine: Engine::Cpu,
        fusion: FusionOptions::default(),
        kept_color: false,
        points: false,
    }
}

fn record(dir: &Path) -> (PathBuf, Rig) {
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
    (path, rig)
}

fn fuse(input: SequenceInput, rig: &Rig, out: &Path, layout: Layout) -> command::Finished {
    let o = options(layout);
    let opened = command::open(&input, out, &o).unwrap();
    command::run(opened, rig, &o, &mut Quiet, &|| false).unwrap()
}

/// The recording, its kfuse layout and its rosbag2 layout.
struct Fixture {
    _dir: tempfile::TempDir,
    dir: PathBuf,
    rig: Rig,
    kfuse: command::Finished,
    seq: PathBuf,
    bag: PathBuf,
}

fn fixture() -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let (rec, rig) = record(dir.path());
    let seq = dir.path().join("seq");
    let kfuse = fuse(
        SequenceInput::Recording(rec.clone(), ReadOptions::default()),
        &rig,
        &seq,
        Layout::Kfuse,
    );
    let bag = dir.path().join("bag");
    fuse(SequenceInput::Recording(rec, ReadOptions::default()), &rig, &bag, Layout::Rosbag2);
    Fixture { dir: dir.path().to_path_buf(), _dir: dir, rig, kfuse, seq, bag }
}

fn bag_input(path: &Path) -> SequenceInput {
    SequenceInput::Bag(path.to_path_buf(), TopicChoice::default())
}

fn png16(path: &Path) -> Vec<u16> {
    image::open(path).unwrap().into_luma16().into_raw()
}

#[test]
fn a_bag_kfuse_wrote_fuses_to_the_recordings_registered_depth() {
    let f = fixture();
    let source = BagSource::open(&f.bag, &TopicChoice::default()).unwrap();
    assert!(
        source.meta().depth_topic.ends_with("/sd/image_depth"),
        "{}",
        source.meta().depth_topic
    );
    assert!(source.meta().color_topic.ends_with("/hd/image_color/compressed"));
    // The rig of the camera_infos and /tf_static is the recording's.
    let rig = source.rig().unwrap();
    for (a, b) in [(&rig.depth, &f.rig.depth), (&rig.color, &f.rig.color)] {
        assert_eq!((a.width, a.height), (b.width, b.height));
        let (ia, ib) = (&a.intrinsics, &b.intrinsics);
        for (x, y) in [(ia.fx, ib.fx), (ia.fy, ib.fy), (ia.cx, ib.cx), (ia.cy, ib.cy)] {
            assert!((x - y).abs() < 1e-9, "{x} {y}");
        }
        assert_eq!(a.distortion.to_array(), b.distortion.to_array());
    }
    let t = rig.color_from_depth.translation - f.rig.color_from_depth.translation;
    assert!(t.norm() < 1e-12, "{t}");
    let r = rig.color_from_depth.rotation.matrix() - f.rig.color_from_depth.rotation.matrix();
    assert!(r.abs().max() < 1e-12, "{r}");
    drop(source);

    for layout in [Layout::Kfuse, Layout::Tum] {
        let out = f.dir.join(format!("from-bag-{layout:?}"));
        let read = fuse(bag_input(&f.bag), &rig, &out, layout);
        let frames = &f.kfuse.index.frames;
        assert_eq!(read.index.frames.len(), frames.len(), "{layout:?}");
        if layout == Layout::Tum {
            assert!(out.join("associations.txt").is_file());
            continue;
        }
        // The bag's stamps are host time: the recording's sensor times moved by one offset
        // (the bag's clock, `kfuse_sequence::host_time`), whole ticks after the reader's
        // rounding to ticks, the spacing kept exactly.
        let shift = |a: Option<u64>, b: Option<u64>| a.zip(b).map(|(a, b)| a as i128 - b as i128);
        let offset = shift(read.index.frames[0].depth_time_ticks, frames[0].depth_time_ticks);
        assert!(offset.unwrap() > 1_600_000_000 * TICKS_PER_SECOND as i128, "{offset:?}");
        for (a, b) in read.index.frames.iter().zip(frames) {
            // Same stamps up to the clock's offset, same colour partner.
            assert_eq!(shift(a.depth_time_ticks, b.depth_time_ticks), offset);
            let color = |e: &IndexEntry| e.color.as_ref().and_then(|c| c.time_ticks);
            if color(b).is_some() {
                assert_eq!(shift(color(a), color(b)), offset);
            } else {
                assert_eq!(color(a), None);
            }
            let (x, y) = (png16(&out.join(&a.files[0])), png16(&f.seq.join(&b.files[0])));
            assert_eq!(x.len(), y.len());
            let both: Vec<u16> = x
                .iter()
                .zip(&y)
                .filter(|(p, q)| **p > 0 && **q > 0)
                .map(|(p, q)| p.abs_diff(*q))
                .collect();
            let n = both.len() as f64;
            let equal = both.iter().filter(|&&d| d == 0).count() as f64;
            let edges = both.iter().filter(|&&d| d > DEPTH_TOLERANCE_MM).count() as f64;
            let name = &a.files[0];
            assert!(equal / n >= MIN_EQUAL_SHARE, "{name}: {equal} of {n} equal");
            assert!(edges / n <= MAX_EDGE_SHARE, "{name}: {edges} of {n} beyond 1 mm");
            let changed = x.iter().zip(&y).filter(|(p, q)| (**p > 0) != (**q > 0)).count();
            let samples = y.iter().filter(|&&q| q > 0).count();
            let share = changed as f64 / samples as f64;
            assert!(share <= MAX_COVERAGE_CHANGE, "{name}: {changed} of {samples}");
            assert!(both.len() > 100_000);
        }
    }
}

/// A copy of the bag's MCAP file at `dst`, each message passed through `edit` (topic, CDR
/// bytes → new bytes, or `None` to leave it out).
fn rewrite(src: &Path, dst: &Path, mut edit: impl FnMut(&str, Vec<u8>) -> Option<Vec<u8>>) {
    let bytes = std::fs::read(src).unwrap();
    let mut w =
        mcap::Writer::new(std::io::BufWriter::new(std::fs::File::create(dst).unwrap())).unwrap();
    let mut channels: BTreeMap<String, u16> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let topic = m.channel.topic.clone();
        let Some(data) = edit(&topic, m.data.into_owned()) else { continue };
        let id = *channels.entry(topic.clone()).or_insert_with(|| {
            let s = m.channel.schema.as_ref().unwrap();
            let sid = w.add_schema(&s.name, &s.encoding, &s.data).unwrap();
            w.add_channel(sid, &topic, &m.channel.message_encoding, &m.channel.metadata).unwrap()
        });
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: m.sequence,
            log_time: m.log_time,
            publish_time: m.publish_time,
        };
        w.write_to_known_channel(&header, &data).unwrap();
    }
    w.finish().unwrap();
}

fn mcap_of(bag: &Path) -> PathBuf {
    bag.join("bag_0.mcap")
}

/// Opens and runs `input` into `out` with the fixture's rig; the error's text.
fn fails(input: &Path, rig: &Rig, out: &Path) -> String {
    let o = options(Layout::Kfuse);
    let e = match command::open(&bag_input(input), out, &o) {
        Err(e) => e,
        Ok(opened) => command::run(opened, rig, &o, &mut Quiet, &|| false).expect_err("an error"),
    };
    assert!(!out.exists(), "{} was written", out.display());
    chain(&e)
}

/// An error and its sources, as the command line prints them (`{:#}`).
fn chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut next = e.source();
    while let Some(c) = next {
        s.push_str(": ");
        s.push_str(&c.to_string());
        next = c.source();
    }
    s
}

#[test]
fn damaged_mcap_files_are_one_error_naming_the_file() {
    let f = fixture();
    let src = mcap_of(&f.bag);
    let bytes = std::fs::read(&src).unwrap();
    let out = f.dir.join("out");

    let cut = f.dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let e = fails(&cut, &f.rig, &out);
    assert!(e.contains("cut.mcap") && e.contains("truncated"), "{e}");

    // The first chunk record (opcode 6) after the magic and the header record.
    let mut at = 8;
    while bytes[at] != 0x06 {
        at += 9 + u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
    }
    // Chunk body: start u64, end u64, uncompressed size u64, uncompressed CRC u32.
    let crc_at = at + 9 + 24;
    let mut bad_crc = bytes.clone();
    bad_crc[crc_at] ^= 0x01;
    let crc = f.dir.join("flipped.mcap");
    std::fs::write(&crc, &bad_crc).unwrap();
    let e = fails(&crc, &f.rig, &out);
    assert!(e.contains("flipped.mcap") && e.to_lowercase().contains("crc"), "{e}");

    let mut huge = bytes.clone();
    huge[at + 1..at + 9].copy_from_slice(&10_000_000_000u64.to_le_bytes());
    let big = f.dir.join("big.mcap");
    std::fs::write(&big, &huge).unwrap();
    let e = fails(&big, &f.rig, &out);
    assert!(e.contains("big.mcap") && e.contains("10000000000"), "{e}");
}

#[test]
fn a_bag_without_camera_info_needs_a_rig_and_a_bad_image_is_named() {
    let f = fixture();
    let src = mcap_of(&f.bag);
    let out = f.dir.join("out");

    let no_info = f.dir.join("no_info.mcap");
    rewrite(&src, &no_info, |t, d| (!t.ends_with("camera_info")).then_some(d));
    let o = options(Layout::Kfuse);
    let opened = command::open(&bag_input(&no_info), &out, &o).unwrap();
    let e = opened.bag_rig().unwrap().expect_err("no rig").to_string();
    assert!(
        e.contains("no_info.mcap") && e.contains("no camera_info") && e.contains("--rig"),
        "{e}"
    );
    assert!(e.contains("/sd/image_depth"), "{e}");
    // With a rig given, the bag fuses as the one with camera_info.
    let done = command::run(opened, &f.rig, &o, &mut Quiet, &|| false).unwrap();
    assert_eq!(done.index.frames.len(), f.kfuse.index.frames.len());

    let bad_step = f.dir.join("bad_step.mcap");
    let mut n = 0;
    rewrite(&src, &bad_step, |t, d| {
        if !t.ends_with("/sd/image_depth") {
            return Some(d);
        }
        n += 1;
        let mut img = Image::from_cdr(&d).unwrap();
        if n == 2 {
            img.step += 2;
        }
        Some(img.to_cdr().unwrap())
    });
    let e = fails(&bad_step, &f.rig, &f.dir.join("out2"));
    assert!(
        e.contains("bad_step.mcap") && e.contains("/sd/image_depth") && e.contains("step"),
        "{e}"
    );

    let bad_enc = f.dir.join("bad_enc.mcap");
    rewrite(&src, &bad_enc, |t, d| {
        if !t.ends_with("/sd/image_depth") {
            return Some(d);
        }
        let mut img = Image::from_cdr(&d).unwrap();
        img.encoding = "32FC1".into();
        Some(img.to_cdr().unwrap())
    });
    let e = fails(&bad_enc, &f.rig, &f.dir.join("out3"));
    assert!(
        e.contains("bad_enc.mcap") && e.contains("/sd/image_depth") && e.contains("32FC1"),
        "{e}"
    );
}
