//! `kfuse capture record --usb-trace` and `kfuse replay-trace` on the simulated Kinect v2
//! (issue 45): the trace replays to the frames of the recording made in the same session
//! (read independently, from the recording's full packets); an unplug finalises both files and
//! says how many frames were kept; a failed start still leaves a trace that replays to the same
//! error; a damaged trace is refused with one line.

use std::path::Path;
use std::process::{Command, Output};

use kinect_usb::device::StreamKind;
use kinect_usb::recording::read_recording_file;
use kinect_usb::stream::DepthAssembler;

fn kfuse() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kfuse"))
}

fn record(dir: &Path, extra: &[&str]) -> Output {
    kfuse()
        .args(["capture", "record", "--backend", "sim", "--out"])
        .arg(dir.join("r.kfrec"))
        .arg("--usb-trace")
        .arg(dir.join("t.kftrace"))
        .args(extra)
        .output()
        .unwrap()
}

fn replay_trace(dir: &Path) -> Output {
    kfuse().arg("replay-trace").arg(dir.join("t.kftrace")).arg("--frames").output().unwrap()
}

/// Depth sequence numbers the replayed trace lists (`depth SEQ TS` lines).
fn traced_depth(out: &Output) -> Vec<u32> {
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.strip_prefix("depth "))
        .filter_map(|l| l.split(' ').next()?.parse().ok())
        .collect()
}

/// Depth sequence numbers in a recording, assembled from its full packets.
fn recorded_depth(path: &Path) -> Vec<u32> {
    let rec = read_recording_file(path, false).unwrap();
    let mut asm = DepthAssembler::new();
    rec.events
        .iter()
        .filter(|e| e.kind == StreamKind::Depth)
        .filter_map(|e| asm.push(&e.data).map(|f| f.sequence))
        .collect()
}

fn no_partial_files(dir: &Path) {
    for e in std::fs::read_dir(dir).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!name.contains("partial"), "left behind: {name}");
    }
}

#[test]
fn a_traced_recording_replays_to_the_recordings_frames() {
    let dir = tempfile::tempdir().unwrap();
    let st = record(dir.path(), &["--frames", "5"]);
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(st.status.success(), "{err}");
    assert!(err.contains("USB trace:") && err.contains("t.kftrace"), "{err}");
    no_partial_files(dir.path());
    let r = replay_trace(dir.path());
    let out = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(out.contains("headers only") && out.contains("serial"), "{out}");
    let recorded = recorded_depth(&dir.path().join("r.kfrec"));
    assert_eq!(recorded.len(), 5);
    let traced = traced_depth(&r);
    // The recorder stops after its 5th frame; the trace may hold one more period.
    assert!(traced.len() >= recorded.len() && traced.len() <= recorded.len() + 1, "{out}");
    assert_eq!(traced[..recorded.len()], recorded[..]);
    // Without image payloads the trace is a small fraction of the recording.
    let t = std::fs::metadata(dir.path().join("t.kftrace")).unwrap().len();
    let k = std::fs::metadata(dir.path().join("r.kfrec")).unwrap().len();
    assert!(t * 5 < k, "trace {t} bytes, recording {k}");
}

#[test]
fn an_unplug_finalises_the_recording_and_the_trace() {
    let dir = tempfile::tempdir().unwrap();
    let st = record(dir.path(), &["--frames", "10", "--sim-unplug-after", "3"]);
    let err = String::from_utf8_lossy(&st.stderr);
    assert_eq!(st.status.code(), Some(1), "{err}");
    let errors: Vec<_> = err.lines().filter(|l| l.starts_with("error: ")).collect();
    assert_eq!(errors.len(), 1, "{err}");
    assert!(err.contains("disappeared") && err.contains("3 complete depth frames"), "{err}");
    assert_eq!(recorded_depth(&dir.path().join("r.kfrec")).len(), 3);
    let r = replay_trace(dir.path());
    let out = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(out.contains("the sensor disappeared"), "{out}");
    assert_eq!(traced_depth(&r).len(), 3, "{out}");
    no_partial_files(dir.path());
}

#[test]
fn a_failed_start_leaves_a_trace_that_fails_the_same_way() {
    let dir = tempfile::tempdir().unwrap();
    let st = record(dir.path(), &["--frames", "2", "--sim-busy"]);
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(!st.status.success());
    assert!(err.contains("device busy"), "{err}");
    assert!(!dir.path().join("r.kfrec").exists());
    let r = replay_trace(dir.path());
    let rerr = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{rerr}");
    assert!(rerr.contains("device busy") && rerr.contains("fails the same way"), "{rerr}");
    assert_eq!(rerr.lines().count(), 1, "{rerr}");
    assert!(r.stdout.is_empty());
}

#[test]
fn a_damaged_trace_is_refused_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    assert!(record(dir.path(), &["--frames", "1"]).status.success());
    let p = dir.path().join("t.kftrace");
    let b = std::fs::read(&p).unwrap();
    std::fs::write(&p, &b[..b.len() - 3]).unwrap();
    let r = replay_trace(dir.path());
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("t.kftrace") && err.contains("truncated"), "{err}");
    assert!(r.stdout.is_empty());
}

#[test]
fn an_existing_trace_needs_overwrite() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("t.kftrace"), b"keep").unwrap();
    let st = record(dir.path(), &["--frames", "1"]);
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(!st.status.success());
    assert!(err.contains("--overwrite"), "{err}");
    assert_eq!(std::fs::read(dir.path().join("t.kftrace")).unwrap(), b"keep");
}

/// The counters of a `stream: N depth frames, D dropped (incomplete I), E iso packet errors;
/// C colour frames, CD dropped` line (`kfuse capture record`) or of replay-trace's `depth:` and
/// `colour:` lines, as (depth frames, depth lost, incomplete, iso errors, colour frames).
fn numbers(line: &str) -> Vec<u64> {
    line.split(|c: char| !c.is_ascii_digit()).filter_map(|w| w.parse().ok()).collect()
}

/// A lossy capture long enough that the trace holds more stream events than the replay's
/// bound on events between two start calls (4096; the depth stream, started last, is
/// followed by every event of the capture): replay-trace counts what the live parsers
/// counted, number for number, and lists the recording's depth frames.
#[test]
fn a_lossy_capture_replays_to_the_live_counters() {
    let dir = tempfile::tempdir().unwrap();
    // 0.2 % of iso packets lost: a depth frame spans ~100 packets, so ~1 frame in 5 is
    // incomplete; 35 frames take ~42 periods of ~130 events each (~5 500 events).
    let st = record(dir.path(), &["--frames", "35", "--sim-iso-drop", "0.002"]);
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(st.status.success(), "{err}");
    let live_line = err.lines().find(|l| l.starts_with("stream: ") && l.contains("iso packet"));
    let live = numbers(live_line.unwrap_or_else(|| panic!("no counters line: {err}")));
    // depth frames, dropped, incomplete, iso errors, colour frames, colour dropped
    assert_eq!(live.len(), 6, "{live_line:?}");
    assert!(live[2] > 0 && live[3] > 0, "the drop knob lost nothing: {live_line:?}");
    let r = replay_trace(dir.path());
    let out = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let line = |p: &str| numbers(out.lines().find(|l| l.starts_with(p)).unwrap());
    let events = numbers(out.lines().find(|l| l.starts_with("replayed ")).unwrap());
    assert!(events[1] > 4096, "only {} events: too short to test the bound", events[1]);
    // "depth: F frames assembled, L lost, I incomplete, E packets with an error status"
    let depth = line("depth: ");
    assert_eq!(depth, [live[0], live[1], live[2], live[3]], "{out}\nlive: {live_line:?}");
    // "colour: F frames assembled, D packets dropped, M with another header magic"
    let colour = line("colour: ");
    assert_eq!((colour[0], colour[1], colour[2]), (live[4], live[5], 0), "{out}");
    let recorded = recorded_depth(&dir.path().join("r.kfrec"));
    assert_eq!(recorded.len(), 35);
    assert_eq!(traced_depth(&r), recorded, "{out}");
}
