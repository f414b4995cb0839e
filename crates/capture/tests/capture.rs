//! The capture library on the simulated sensor and on files: the 16-bit PNG rule, staged shots,
//! the session and pump, recording and replay.

use std::path::Path;
use std::time::{Duration, Instant};

use kfuse_capture::record::record;
use kfuse_capture::shots::STAGING_PREFIX;
use kfuse_capture::source::sim_scene;
use kfuse_capture::{
    CaptureError, DecoderOptions, FramePump, Pumped, ReplayOptions, SensorSource, Session,
    ShotKind, ShotWriter, SimOptions, shot_files, write_png16,
};

fn read_png16(p: &Path) -> (u32, u32, Vec<u16>) {
    let img = image::open(p).unwrap().into_luma16();
    (img.width(), img.height(), img.into_raw())
}

/// The entries of `dir`, sorted (staging folders included).
fn names(dir: &Path) -> std::collections::BTreeSet<String> {
    let entries = std::fs::read_dir(dir).unwrap();
    entries.map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect()
}

/// The one 16-bit rule: 0 means "no value", so a valid value below 0.5 becomes 1 (not 0),
/// halves round away from zero, values above the range saturate, and NaN, ±∞, 0 and negative
/// values are 0. Expected values worked out by hand from that rule.
#[test]
fn png16_rounds_clamps_to_1_65535_and_zeroes_invalid_values() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("v.png");
    let values =
        [0.0, 0.3, 0.5, 1234.5, 1234.49, 70_000.0, f32::NAN, -5.0, f32::INFINITY, 65_535.4];
    write_png16(&p, &values, 5, 2).unwrap();
    let (w, h, px) = read_png16(&p);
    assert_eq!((w, h), (5, 2));
    assert_eq!(px, vec![0, 1, 1, 1235, 1234, 65535, 0, 0, 0, 65535]);
    // The depth writer of kfuse-io follows the same rule (metres → mm): 0.3 mm stays valid.
    let depth = geometry::Image::from_vec(3, 1, vec![0.0003f32, 1.5, f32::NAN]).unwrap();
    assert_eq!(kfuse_io::images::depth_to_mm(&depth), vec![1, 1500, 0]);
    // A size that does not match the values is refused and writes nothing.
    let bad = dir.path().join("bad.png");
    let e = write_png16(&bad, &values, 4, 2).unwrap_err().to_string();
    assert!(e.contains("10 values do not make a 4x2 image"), "{e}");
    assert!(!bad.exists());
}

/// A shot's three files appear together: a good shot leaves exactly them (no staging folder),
/// a failing one (IR of the wrong size) leaves none of its files; a staging folder of a dead
/// process is removed when a writer opens the folder.
#[test]
fn shots_are_staged_and_appear_together() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("shots");
    std::fs::create_dir_all(out.join(format!("{STAGING_PREFIX}4294967295"))).unwrap();
    let w = ShotWriter::new(&out).unwrap();
    assert!(names(&out).is_empty(), "stale staging kept: {:?}", names(&out));
    let n = 512 * 424;
    let depth: Vec<f32> = (0..n).map(|i| (i % 5000) as f32).collect();
    let ir = vec![100.0f32; n];
    // A sensor colour frame: left half red, right half blue, as the sensor streams it
    // (mirrored); the shot holds it as the scene is: blue on the left.
    let (cw, ch) = (32u32, 16u32);
    let rgb: Vec<u8> = (0..cw * ch)
        .flat_map(|i| if i % cw < cw / 2 { [230u8, 20, 20] } else { [20, 20, 230] })
        .collect();
    let mut jpeg = Vec::new();
    image::ImageEncoder::write_image(
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90),
        &rgb,
        cw,
        ch,
        image::ExtendedColorType::Rgb8,
    )
    .unwrap();
    let files = shot_files(&out, "0001", ShotKind::Calib);
    w.write(&files, &jpeg, &ir, &depth).unwrap();
    let shot_names = ["color_0001.jpg", "depth_0001.png", "ir_0001.png"].map(String::from);
    assert_eq!(names(&out), shot_names.clone().into());
    assert_eq!(read_png16(&files[2]).2[4999], 4999);
    let saved = image::open(&files[0]).unwrap().into_rgb8();
    assert_eq!(saved.dimensions(), (cw, ch));
    // JPEG chroma subsampling blurs the middle columns only: 4 px in from each side is pure.
    let (left, right) = (saved.get_pixel(4, 8).0, saved.get_pixel(cw - 5, 8).0);
    assert!(left[2] > 180 && left[0] < 60 && right[0] > 180 && right[2] < 60, "{left:?} {right:?}");
    // A frame that does not decode is refused and leaves nothing.
    let broken = shot_files(&out, "0002", ShotKind::Calib);
    let e = w.write(&broken, &[0xFF, 0xD8, 0xFF, 0xD9], &ir, &depth).unwrap_err();
    assert!(e.to_string().contains("the sensor's colour frame"), "{e}");
    assert_eq!(names(&out), shot_names.clone().into());
    let scene = shot_files(&out, "desk", ShotKind::Scene);
    let e = w.write(&scene, &jpeg, &ir[..10], &depth).unwrap_err();
    assert!(matches!(e, CaptureError::Write { .. }), "{e}");
    assert_eq!(names(&out), shot_names.into());
}

/// Largest |decoded − scene| depth, mm, of the simulator's forward model (scene → phases →
/// raw frame) decoded with the filters off: the bound `kinect-usb/tests/sim.rs` asserts for
/// the same round trip (protocol §14.3; the vectors' manifest `forward_model_round_trip`
/// measured 6.0 mm max on its scene). Quantisation of the phases, not noise: the sim adds none.
const FORWARD_MODEL_MAX_MM: f32 = 8.0;

/// The session on the simulated sensor: a fresh pair's depth equals the scene within the
/// decoder's forward-model bound ([`FORWARD_MODEL_MAX_MM`]); a recording of it
/// replays through the same session type with as many depth frames, then ends.
#[test]
fn sim_session_pumps_the_scene_and_a_recording_replays() {
    let source = SensorSource::Sim(SimOptions::default());
    let mut s = Session::open(&source).unwrap();
    // The factory parameters the session reads back over the simulated USB protocol are the
    // ones the simulator was built from: `geometry::synth`'s Kinect preset depth camera, of
    // the sensor's mirrored images, stored as f32 on the device (so equal exactly).
    let depth_cam = geometry::synth::kinect_preset(false).rig.depth.mirrored();
    let p = s.info().depth_params;
    let got = [p.fx, p.fy, p.cx, p.cy, p.k1, p.k2, p.k3];
    let i = &depth_cam.intrinsics;
    let k = &depth_cam.distortion;
    let want = [i.fx, i.fy, i.cx, i.cy, k.k1, k.k2, k.k3].map(|v| v as f32);
    assert_eq!(got, want, "depth factory parameters (fx fy cx cy k1 k2 k3)");
    let opts = DecoderOptions { no_filters: true, ..DecoderOptions::default() };
    let mut pump = FramePump::new(s.decoder(&opts).unwrap());
    pump.fresh_pair(&mut s, Instant::now()).unwrap();
    assert_eq!(&pump.color_jpeg()[..2], &[0xFF, 0xD8]);
    let (scene, _) = sim_scene();
    // The sim streams the scene mirrored (kinect_usb::orientation); the pump writes it back.
    let mut truth = scene.depth_frames[0].0.clone();
    kinect_usb::orientation::mirror_rows(&mut truth, 512);
    let truth = &truth;
    let (mut n, mut max) = (0usize, 0f32);
    for (i, (&t, &d)) in truth.iter().zip(pump.depth_mm()).enumerate() {
        let c = i % 512;
        if t > 0.0 && d > 0.0 && c > 0 && c < 511 {
            n += 1;
            max = max.max((t - d).abs());
        }
    }
    // Measured 7.56 mm max on this scene, 210 964 pixels compared.
    assert!(n > 150_000 && max <= FORWARD_MODEL_MAX_MM, "{n} pixels, max |err| {max} mm");

    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("s.kfrec");
    let mut seen = Vec::new();
    let r = record(&mut s, &file, 3, &|| false, &mut |k| seen.push(k)).unwrap();
    assert_eq!((r.frames, r.interrupted, r.stopped_by.is_none()), (3, false, true));
    assert!(r.written);
    assert_eq!(seen, [1, 2, 3]);
    // A stop request before the first depth frame (Ctrl-C while the sensor started, issue 29):
    // nothing is written, the recording already at the path is kept byte for byte (it was
    // replaced by a recording of no frame), and no temporary is left.
    let old = std::fs::read(&file).unwrap();
    let r = record(&mut s, &file, 3, &|| true, &mut |_| {}).unwrap();
    assert_eq!((r.frames, r.interrupted, r.written), (0, true, false));
    assert_eq!(std::fs::read(&file).unwrap(), old, "the old recording was replaced");
    assert_eq!(names(dir.path()).into_iter().collect::<Vec<_>>(), ["s.kfrec"]);
    s.close();

    let replay = SensorSource::Replay(ReplayOptions {
        path: file,
        allow_truncated: false,
        skip_corrupt: false,
    });
    let mut s = Session::open(&replay).unwrap();
    let mut pump = FramePump::new(s.decoder(&opts).unwrap());
    let mut depth_frames = 0;
    let end = loop {
        match pump.pump(&mut s, Duration::from_secs(3)) {
            Ok(Some(Pumped::Depth { number, .. })) => depth_frames = number,
            Ok(_) => {}
            Err(e) => break e,
        }
    };
    assert!(end.is_end_of_stream(), "{end}");
    assert_eq!(depth_frames, 3);
    let outcome = s.replay_outcome().unwrap();
    assert!(outcome.error.is_none() && outcome.report.skipped.is_empty());
}

/// No sensor and bad configuration are plain errors that say what to do.
/// Sensor timestamp step per frame period: 30 Hz in 0.125 ms units (1/30 s = 266.7 ticks, the
/// simulator steps 267).
const TICKS_PER_PERIOD: u32 = 267;

/// Issue 45 item 1: a shot after a 10 s pause is the present. The simulated sensor produces
/// 300 frame periods with nobody reading; the session holds one frame per stream (under three
/// raw depth frames), every frame not taken is counted, and `fresh_pair` then returns the
/// newest depth frame (the old unbounded queue returned the frame from the pause's start).
#[test]
fn fresh_pair_after_an_idle_pause_is_current() {
    let mut s = Session::open(&SensorSource::Sim(SimOptions::default())).unwrap();
    let opts = DecoderOptions { no_filters: true, ..DecoderOptions::default() };
    let mut pump = FramePump::new(s.decoder(&opts).unwrap());
    pump.fresh_pair(&mut s, Instant::now()).unwrap();
    let ts0 = pump.depth_timestamp().unwrap();
    let c0 = s.counters();
    let n0 = c0.depth_taken + c0.depth_overwritten;
    assert!(s.advance_sim(300));
    let held = s.buffered_bytes();
    assert!(held < 3 * kinect_usb::raw::RAW_FRAME_BYTES, "{held} bytes held");
    pump.fresh_pair(&mut s, Instant::now()).unwrap();
    let c = s.counters();
    let n1 = c.depth_taken + c.depth_overwritten;
    // 300 periods and at least one more after the call; all but the frames taken overwritten.
    assert!(n1 > n0 + 300, "{c:?}");
    assert!(c.depth_overwritten >= c0.depth_overwritten + 299, "{c:?}");
    // The frame the pump holds is frame n1: the newest assembled (none waits behind it
    // but at most the one of the next period).
    assert!(c.depth_frames - n1 <= 1, "{c:?}");
    let ts1 = pump.depth_timestamp().unwrap();
    assert_eq!(ts1.wrapping_sub(ts0), TICKS_PER_PERIOD * (n1 - n0) as u32, "{c:?}");
}

#[test]
fn absent_sensor_and_bad_drop_rate_are_refused() {
    let e = Session::open(&SensorSource::Absent).err().unwrap();
    assert!(matches!(e, CaptureError::NoSensor { .. }), "{e}");
    assert!(e.to_string().contains("no Kinect v2 found"), "{e}");
    let bad = SensorSource::Sim(SimOptions { iso_drop: 1.5, ..SimOptions::default() });
    let e = Session::open(&bad).err().unwrap();
    assert!(e.to_string().contains("1.5 is outside [0, 1]"), "{e}");
}
