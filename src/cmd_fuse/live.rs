//! `kfuse fuse --live --rig RIG.json --out DIR [--sets N]`: the sensors of a rig of several
//! Kinects, each published by `kfuse serve` on its own PC, received over Zenoh
//! (`kfuse_live::receive`), matched one frame per sensor (`kfuse_live::matching`), and each
//! matched set fused by the fusion of several Kinects that `--sensor` images go through
//! ([`super::multi::run`], called with the set's frames as its `--sensor` files).
//!
//! # Output
//!
//! - `DIR/frames/NNNNNN/`: what arrived for set `NNNNNN`: `SERIAL_depth.png` (16-bit mm, the
//!   values of `sd/image_depth`) and `SERIAL_color.jpg` (the JPEG as received) per sensor,
//!   `set.json` (each frame's stamps, the spread), and `rig.json` when a sensor was missing
//!   (the rig of the sensors present; see below). Committed whole (a staged folder).
//! - `DIR/sets/NNNNNN/`: the outputs of `kfuse fuse --rig RIG --sensor SERIAL=COLOR,DEPTH …`
//!   of those files, byte for byte (their `summary.json` names the files and times the run).
//! - `DIR/live.json`: every set (its sensors, spread, latency from the newest frame's arrival
//!   to the fused output, fusion time), each sensor's counters (frames, garbage refused with
//!   the last reason, messages lost, frames replaced, the publisher's drops) and its stops;
//!   rewritten after each set and at the end.
//!
//! # Sensors that stop
//!
//! A sensor whose last depth frame is older than `--stale-after` ([`STALE_AFTER`]) is reported
//! once and left out:
//! the sets go on with the others (fused with the rig of the sensors present; when the
//! reference sensor is the one missing, the first sensor present becomes the reference, so those
//! sets are in its frame). When it sends again it is reported and taken back. Until the first
//! set every sensor of the rig is waited for, at most [`FIRST_SET_WAIT`].

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use geometry::MultiRig;
use kfuse_io::atomic::{StagedDir, write_bytes_atomic};
use kfuse_live::matching::{MATCH_TOLERANCE_NS, SensorFrames, newest_set, spread_ns};
use kfuse_live::publish::unix_now_ns;
use kfuse_live::receive::{ColorFrame, DepthFrame, Receiver, SensorCounters, SensorHold};
use serde::Serialize;

use super::FuseArgs;
use super::multi::{SensorArg, check_serial_for_files, load_multi_rig_for_fuse};

/// Default of `--stale-after`: a sensor whose newest depth frame arrived longer ago than this is
/// reported as stopped and left out of the sets: 1 s (30 frame periods; a `serve` whose network
/// stalls a moment is not dropped at once).
pub const STALE_AFTER: Duration = Duration::from_secs(1);

/// Largest `--stale-after`: 600 s.
pub const MAX_STALE_S: f64 = 600.0;

/// Fewest sensors of a set: 2 (the fusion of several Kinects; with fewer sensors of the rig
/// sending, the run waits).
pub const MIN_SET_SENSORS: usize = 2;

/// Parses `--stale-after`: seconds in (0, [`MAX_STALE_S`]].
pub fn parse_stale_s(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("`{s}` is not a number of seconds"))?;
    if !(v > 0.0 && v <= MAX_STALE_S) {
        return Err(format!("{} s is outside (0, {MAX_STALE_S}] s", geometry::num_fmt::num(v)));
    }
    Ok(v)
}

/// How long the first set waits for every sensor of the rig before the ones that sent nothing
/// are reported as stopped: 10 s (a `serve` starting its sensor takes a few seconds).
pub const FIRST_SET_WAIT: Duration = Duration::from_secs(10);

/// Default of `--wait`: 30 s without a fused set ends the run with an error.
pub const DEFAULT_WAIT_S: f64 = 30.0;

/// Largest `--tolerance-ms`: 1000 ms (a set of frames a second apart is no set).
pub const MAX_TOLERANCE_MS: f64 = 1000.0;

/// Parses `--tolerance-ms`: a finite number of milliseconds in (0, [`MAX_TOLERANCE_MS`]].
pub fn parse_tolerance_ms(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("`{s}` is not a number of milliseconds"))?;
    if !(v > 0.0 && v <= MAX_TOLERANCE_MS) {
        return Err(format!(
            "{} ms is outside (0, {MAX_TOLERANCE_MS}] ms",
            geometry::num_fmt::num(v)
        ));
    }
    Ok(v)
}

/// One sensor's frame of a set, in `set.json` and `live.json`.
#[derive(Debug, Clone, Serialize)]
struct SetFrame {
    sensor: String,
    depth_stamp_ns: u64,
    color_stamp_ns: u64,
    /// The sensor's own timestamp of the depth frame (from its status), when known.
    depth_time_ticks: Option<u32>,
}

/// One fused set in `live.json`.
#[derive(Debug, Clone, Serialize)]
struct SetRecord {
    set: u64,
    frames: Vec<SetFrame>,
    missing: Vec<String>,
    spread_ms: f64,
    /// From the newest frame's arrival on its sensor's PC to the fused set's commit.
    latency_ms: f64,
    fuse_ms: f64,
    out: String,
}

#[derive(Debug, Clone, Serialize)]
struct SensorRecord {
    sensor: String,
    counters: SensorCounters,
    stopped: Vec<StopRecord>,
}

#[derive(Debug, Clone, Serialize)]
struct StopRecord {
    /// Seconds since the start of the run.
    at_s: f64,
    /// Seconds after which it was back, if it came back.
    back_at_s: Option<f64>,
}

#[derive(Serialize)]
struct LiveSummary<'a> {
    format: &'static str,
    version: u32,
    rig: String,
    tolerance_ms: f64,
    /// Seconds from the start of the run to this summary.
    elapsed_s: f64,
    sets: &'a [SetRecord],
    sensors: Vec<SensorRecord>,
}

/// The flags --live takes and refuses.
fn check_flags(args: &FuseArgs) -> Result<()> {
    if args.sequence.recording.is_some() || args.sequence.frames.is_some() {
        bail!("--live fuses the sensors as they publish: drop --recording/--frames");
    }
    Ok(())
}

/// A rig of the sensors `present` of `rig` (their cameras only). When the reference camera's
/// sensor is not among them, the first present sensor's depth camera becomes the reference.
fn sub_rig(rig: &MultiRig, present: &[String]) -> Result<MultiRig> {
    let keep =
        |c: &geometry::multi_rig::RigCamera| c.sensor.as_ref().is_some_and(|s| present.contains(s));
    let reference = match rig.camera(&rig.reference).filter(|c| keep(c)) {
        Some(c) => c.clone(),
        None => rig
            .cameras
            .iter()
            .find(|c| keep(c) && c.role == geometry::CameraRole::Depth)
            .cloned()
            .context("no depth camera of a present sensor")?,
    };
    let cameras = rig
        .cameras
        .iter()
        .filter(|c| keep(c))
        .map(|c| {
            let mut c = c.clone();
            c.camera_from_reference = rig.transform(&reference, &c);
            c
        })
        .collect();
    let sub = MultiRig {
        reference: reference.name.clone(),
        cameras,
        calibration: None,
        rectified: rig.rectified,
    };
    sub.validate()?;
    Ok(sub)
}

/// Writes what arrived for set `k` into `out/frames/NNNNNN/` (module docs) and returns the
/// `--sensor` arguments of its fusion and the rig to fuse it with.
fn write_frames(
    out: &Path,
    k: u64,
    rig: &MultiRig,
    rig_path: &Path,
    set: &[(String, Arc<DepthFrame>, Arc<ColorFrame>)],
    record: &[SetFrame],
) -> Result<(Vec<SensorArg>, PathBuf)> {
    let dir = out.join("frames").join(format!("{k:06}"));
    let staged = StagedDir::new(&dir)?;
    for (serial, depth, color) in set {
        kfuse_io::images::write_png16(
            &staged.join(format!("{serial}_depth.png")),
            depth.width,
            depth.height,
            depth.mm.clone(),
        )?;
        write_bytes_atomic(&staged.join(format!("{serial}_color.jpg")), &color.jpeg)?;
    }
    let present: Vec<String> = set.iter().map(|(s, _, _)| s.clone()).collect();
    let all = rig.sensors().len() == present.len();
    if !all {
        kfuse_io::rig::write_multi_rig(&staged.join("rig.json"), &sub_rig(rig, &present)?)?;
    }
    let json = serde_json::to_string_pretty(&serde_json::json!({ "set": k, "frames": record }))?;
    write_bytes_atomic(&staged.join("set.json"), json.as_bytes())?;
    let dir = staged.commit()?;
    let args = present
        .iter()
        .map(|s| SensorArg {
            serial: s.clone(),
            color: dir.join(format!("{s}_color.jpg")),
            depth: dir.join(format!("{s}_depth.png")),
        })
        .collect();
    let rig_for_set = if all { rig_path.to_path_buf() } else { dir.join("rig.json") };
    Ok((args, rig_for_set))
}

/// Which sensors take part now; reports each change on stderr and in `stops`.
struct Liveness {
    active: Vec<bool>,
    stops: Vec<Vec<StopRecord>>,
    started: Instant,
    stale_after: Duration,
}

impl Liveness {
    fn update(&mut self, holds: &[SensorHold], first_set_done: bool) {
        let waiting = !first_set_done && self.started.elapsed() < FIRST_SET_WAIT;
        for (k, h) in holds.iter().enumerate() {
            let fresh = h.last_depth_at.is_some_and(|t| t.elapsed() < self.stale_after);
            let now = fresh || (waiting && h.last_depth_at.is_none());
            let at = self.started.elapsed().as_secs_f64();
            if self.active[k] && !now {
                let n = self.active.iter().filter(|a| **a).count() - 1;
                eprintln!(
                    "sensor {} stopped: no depth frame for {:.1} s; fusing the other {n}",
                    h.serial,
                    self.stale_after.as_secs_f64()
                );
                self.stops[k].push(StopRecord { at_s: at, back_at_s: None });
            } else if !self.active[k] && now {
                eprintln!("sensor {} is back: fusing it again", h.serial);
                if let Some(s) = self.stops[k].last_mut() {
                    s.back_at_s = Some(at);
                }
            }
            self.active[k] = now;
        }
    }
}

/// Runs `kfuse fuse --live`.
pub fn run(args: &FuseArgs) -> Result<()> {
    crate::interrupt::install()?;
    check_flags(args)?;
    let rig_path = args.rig.as_deref().context("--live needs --rig")?;
    let rig = load_multi_rig_for_fuse(rig_path, args.force)?;
    let sensors: Vec<String> = rig.sensors().into_iter().map(String::from).collect();
    if sensors.is_empty() {
        bail!("{}: no camera belongs to a sensor: nothing to receive", rig_path.display());
    }
    for s in &sensors {
        check_serial_for_files(s, rig_path)?;
    }
    let out = &args.out;
    if out.exists() && (!out.is_dir() || std::fs::read_dir(out)?.next().is_some()) {
        bail!(
            "--out {}: exists and is not an empty folder; --live writes a new folder of sets: give a new one",
            out.display()
        );
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let tolerance_ns = args.tolerance_ms.map_or(MATCH_TOLERANCE_NS, |ms| (ms * 1e6) as u64);
    let wait = Duration::from_secs_f64(args.wait.unwrap_or(DEFAULT_WAIT_S));
    let domain = args.net.domain()?;
    let zenoh = kfuse_live::net::open(&args.net.endpoints())?;
    let receiver = Receiver::subscribe(&zenoh, domain, &sensors)?;
    eprintln!(
        "waiting for sensors {} (ROS domain {domain}; sets within {:.1} ms)",
        sensors.join(", "),
        tolerance_ns as f64 / 1e6
    );
    let mut live = Liveness {
        active: vec![true; sensors.len()],
        stops: vec![Vec::new(); sensors.len()],
        started: Instant::now(),
        stale_after: args.stale_after.map_or(STALE_AFTER, Duration::from_secs_f64),
    };
    let mut records: Vec<SetRecord> = Vec::new();
    let mut last_used: Vec<Option<u64>> = vec![None; sensors.len()];
    let mut last_set = Instant::now();
    let summary = |records: &[SetRecord], holds: &[SensorHold], live: &Liveness| -> Result<()> {
        let s = LiveSummary {
            format: "kfuse-live-fusion",
            version: 1,
            rig: rig_path.display().to_string(),
            tolerance_ms: tolerance_ns as f64 / 1e6,
            elapsed_s: live.started.elapsed().as_secs_f64(),
            sets: records,
            sensors: holds
                .iter()
                .zip(&live.stops)
                .map(|(h, s)| SensorRecord {
                    sensor: h.serial.clone(),
                    counters: h.counters.clone(),
                    stopped: s.clone(),
                })
                .collect(),
        };
        let json = serde_json::to_string_pretty(&s)?;
        write_bytes_atomic(&out.join("live.json"), json.as_bytes())?;
        Ok(())
    };
    let result = loop {
        if args.sets.is_some_and(|n| records.len() as u64 >= n) {
            break Ok(());
        }
        if crate::interrupt::requested() {
            break Ok(());
        }
        receiver.wait(Duration::from_millis(50));
        let holds = receiver.snapshot();
        live.update(&holds, !records.is_empty());
        if last_set.elapsed() > wait {
            let seen: Vec<String> = holds
                .iter()
                .map(|h| {
                    format!(
                        "{}: {} depth frames, {} refused",
                        h.serial, h.counters.depth, h.counters.garbage
                    )
                })
                .collect();
            break Err(anyhow::anyhow!(
                "no set of frames could be fused for {:.0} s ({}); is every `kfuse serve` running and reachable (--connect), on ROS domain {domain}?",
                wait.as_secs_f64(),
                seen.join("; ")
            ));
        }
        let waiting_for_all = records.is_empty() && live.started.elapsed() < FIRST_SET_WAIT;
        let chosen: Vec<usize> = (0..sensors.len())
            .filter(|&k| live.active[k] && (!waiting_for_all || holds[k].last_depth_at.is_some()))
            .collect();
        if chosen.len() < MIN_SET_SENSORS.min(sensors.len())
            || (waiting_for_all && chosen.len() < sensors.len())
        {
            continue;
        }
        let frames: Vec<SensorFrames> = chosen
            .iter()
            .map(|&k| SensorFrames {
                depth: holds[k].depth.iter().map(|f| f.stamp_ns).collect(),
                color: holds[k].color.iter().map(|f| f.stamp_ns).collect(),
            })
            .collect();
        let after: Vec<Option<u64>> = chosen.iter().map(|&k| last_used[k]).collect();
        let Some(set) = newest_set(&frames, &after, tolerance_ns) else { continue };
        let k = records.len() as u64 + 1;
        let mut parts = Vec::new();
        let mut record = Vec::new();
        for (&s, c) in chosen.iter().zip(&set) {
            let h = &holds[s];
            let depth = h.depth[c.depth].clone();
            let ticks = h.status.as_ref().filter(|st| st.depth_host_ns == c.depth_ns);
            record.push(SetFrame {
                sensor: h.serial.clone(),
                depth_stamp_ns: c.depth_ns,
                color_stamp_ns: c.color_ns,
                depth_time_ticks: ticks.map(|st| st.depth_time_ticks),
            });
            parts.push((h.serial.clone(), depth, h.color[c.color].clone()));
            last_used[s] = Some(c.depth_ns);
        }
        let missing: Vec<String> =
            sensors.iter().filter(|s| !parts.iter().any(|p| &p.0 == *s)).cloned().collect();
        let t0 = Instant::now();
        let set_out = out.join("sets").join(format!("{k:06}"));
        if !args.live_match_only {
            let (sensor_args, rig_for_set) = write_frames(out, k, &rig, rig_path, &parts, &record)?;
            let fuse_args = FuseArgs {
                live: false,
                sets: None,
                rig: Some(rig_for_set),
                sensor: sensor_args,
                out: set_out.clone(),
                ..args.clone()
            };
            super::multi::run(&fuse_args).with_context(|| format!("fusing set {k}"))?;
        }
        let newest = set.iter().map(|c| c.depth_ns).max().unwrap_or(0);
        let rec = SetRecord {
            set: k,
            frames: record,
            missing,
            spread_ms: spread_ns(&set) as f64 / 1e6,
            latency_ms: unix_now_ns().saturating_sub(newest) as f64 / 1e6,
            fuse_ms: t0.elapsed().as_secs_f64() * 1e3,
            out: if args.live_match_only { String::new() } else { set_out.display().to_string() },
        };
        if args.live_match_only {
            records.push(rec);
            last_set = Instant::now();
            continue;
        }
        eprintln!(
            "set {k}: {} sensors{}, spread {:.1} ms, latency {:.0} ms -> {}",
            rec.frames.len(),
            if rec.missing.is_empty() {
                String::new()
            } else {
                format!(" ({} missing)", rec.missing.join(", "))
            },
            rec.spread_ms,
            rec.latency_ms,
            set_out.display()
        );
        records.push(rec);
        last_set = Instant::now();
        summary(&records, &receiver.snapshot(), &live)?;
    };
    let holds = receiver.snapshot();
    summary(&records, &holds, &live)?;
    if args.live_match_only {
        println!("matched {} set(s) (not fused: --live-match-only)", records.len());
    }
    for h in &holds {
        let c = &h.counters;
        if c.garbage > 0 {
            eprintln!(
                "sensor {}: {} message(s) refused (last: {})",
                h.serial,
                c.garbage,
                c.last_garbage.as_deref().unwrap_or("")
            );
        }
        if c.lost + c.publisher_dropped > 0 {
            eprintln!(
                "sensor {}: {} message(s) lost on the way, {} frame(s) not published by its serve",
                h.serial, c.lost, c.publisher_dropped
            );
        }
    }
    drop(receiver);
    let _ = zenoh::Wait::wait(zenoh.close());
    result?;
    if !args.live_match_only {
        println!("fused {} set(s) into {}", records.len(), out.join("sets").display());
    }
    if crate::interrupt::requested() {
        crate::interrupt::check(&format!(
            ": {} set(s) fused into {}",
            records.len(),
            out.display()
        ))?;
    }
    Ok(())
}
