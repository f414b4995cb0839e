//! Several sensors at once (issue 32): which Kinects a source offers ([`connected`]), the
//! choice of `--device SERIAL|all` ([`select`]), shots from every chosen sensor taken at one
//! trigger and paired by their sensor timestamps ([`MultiShots`]), and recordings of all of
//! them ([`record_all`]).
//!
//! # Files
//!
//! Shots of several sensors go into one folder per sensor, `OUT/SERIAL/`, each with the file
//! names of a single sensor's capture (`color_NNNN.jpg`, `ir_NNNN.png`, `depth_NNNN.png`,
//! `kinect_params.json`; scenes `NAME_*`), and `OUT/index.json` ([`INDEX_FORMAT`]) lists every
//! shot with each sensor's depth and colour timestamps; a simulated ring also gets
//! `OUT/true_rig.json`, the rig the simulator renders with ([`crate::source::sim_true_rig`]).
//! Recordings are `OUT/SERIAL.kfrec`.
//!
//! # Pairing
//!
//! Kinect v2s have no sync input: each runs its own 30 Hz clock. At each trigger every sensor
//! delivers a fresh depth + colour pair; its colour frame is then taken within half a frame
//! period of its depth frame ([`HALF_PERIOD_TICKS`]), and a sensor whose depth frame is more
//! than half a period behind the latest one (timestamps counted from each sensor's first
//! shot) is pumped on until it catches up, at most [`MAX_ALIGN_FRAMES`] frames. Shot `k` of
//! every sensor thus shows the same moment to within one frame (33 ms); `index.json` holds the
//! timestamps and the spread.
//!
//! # A sensor lost mid-run
//!
//! A sensor whose stream fails (unplugged, a stalled stream) is dropped from the run with the
//! reason ([`ShotReport::lost`]); the others go on, and `index.json` says after which shot it
//! was lost. Its shots before that are complete.

use std::path::{Path, PathBuf};
use std::time::Instant;

use kfuse_io::atomic::write_atomic;

use crate::pump::FRAME_TIMEOUT;
use crate::record::{Recorded, record};
use crate::source::{SimRing, sim_true_rig};
use crate::{
    CaptureError, ColorSettings, DecoderOptions, FramePump, SensorSource, Session, ShotKind,
    ShotWriter, shot_files, write_params_json,
};

/// Half a frame period at 30 Hz in sensor ticks (0.125 ms): 133 (a frame is 266–267 ticks,
/// protocol §13). Frames closer than this are the same moment.
pub const HALF_PERIOD_TICKS: i64 = 133;

/// Most extra frames one sensor is pumped to pair its colour with its depth or to catch up
/// with the others at one shot: 90 (3 s of stream). Sensors more than 3 s apart are not one
/// moment; the shot is taken as it is and `index.json`'s spread says so.
pub const MAX_ALIGN_FRAMES: usize = 90;

/// The `format` of `index.json`.
pub const INDEX_FORMAT: &str = "kfuse-multi-capture";

/// One Kinect a source offers.
#[derive(Debug, Clone, PartialEq)]
pub struct Connected {
    /// Its serial number (`None`: a real sensor that could not be asked: busy, permissions).
    pub serial: Option<String>,
    /// Its line in `kfuse devices`.
    pub line: String,
    /// The source that opens exactly this sensor.
    pub source: SensorSource,
}

impl Connected {
    /// The serial, or `?` when it could not be read.
    pub fn serial_text(&self) -> &str {
        self.serial.as_deref().unwrap_or("?")
    }
}

/// Every Kinect `source` offers: the sensors on the USB bus, the sensors of a simulated ring
/// (`SimOptions::ring`; its faults only on `SimOptions::fault_sensor` when one is named), or
/// the one sensor of a recording or the single simulator. Error: [`CaptureError::NoSensor`]
/// when there is none.
pub fn connected(source: &SensorSource) -> Result<Vec<Connected>, CaptureError> {
    match source {
        SensorSource::Usb | SensorSource::UsbAt { .. } => crate::session::usb_sensors(),
        SensorSource::Sim(o) => {
            let n = o.ring.as_ref().map_or(1, |r| r.sensors).max(1);
            let max = kinect_usb::sim::ring::MAX_SIM_SENSORS;
            if n > max {
                return Err(CaptureError::Config(format!(
                    "--sim-sensors {n}: the simulated ring holds 1 to {max} sensors"
                )));
            }
            Ok((0..n)
                .map(|i| {
                    let own = kinect_usb::sim::ring::serial(i);
                    let serial = if o.same_serial && i == 1 {
                        kinect_usb::sim::ring::serial(0)
                    } else {
                        own.clone()
                    };
                    let mut opts = o.clone();
                    if o.fault_sensor.as_ref().is_some_and(|f| *f != own) {
                        opts.unplug_after = None;
                        opts.busy = false;
                        opts.iso_drop = 0.0;
                    }
                    opts.ring =
                        (n > 1).then(|| SimRing { sensors: n, index: i, serial: serial.clone() });
                    Connected {
                        line: format!("simulated Kinect v2  serial {serial}  (sim backend)"),
                        serial: Some(serial),
                        source: SensorSource::Sim(opts),
                    }
                })
                .collect())
        }
        SensorSource::Replay(_) | SensorSource::Absent => Err(crate::session::no_sensor_error()),
    }
}

/// The sensors `devices` names among `sensors` (from [`connected`]): `all`, or serial numbers
/// (each once). Errors, one line each: a serial not connected (the connected ones listed), a
/// serial given twice, two chosen sensors reporting the same serial.
pub fn select(sensors: &[Connected], devices: &[String]) -> Result<Vec<Connected>, CaptureError> {
    let listed = || sensors.iter().map(Connected::serial_text).collect::<Vec<_>>().join(", ");
    let chosen: Vec<Connected> = if devices.iter().any(|d| d == "all") {
        if devices.len() > 1 {
            return Err(CaptureError::Config(
                "--device all already takes every sensor: give it alone, or serial numbers".into(),
            ));
        }
        sensors.to_vec()
    } else {
        let mut out = Vec::new();
        for (i, d) in devices.iter().enumerate() {
            if devices[..i].contains(d) {
                return Err(CaptureError::Config(format!("--device {d} is given twice")));
            }
            let matching: Vec<&Connected> =
                sensors.iter().filter(|s| s.serial.as_deref() == Some(d.as_str())).collect();
            if matching.is_empty() {
                return Err(CaptureError::Config(format!(
                    "--device {d}: no Kinect v2 with this serial number is connected (connected: {}); see `kfuse devices`",
                    listed()
                )));
            }
            out.extend(matching.into_iter().cloned());
        }
        out
    };
    check_distinct(chosen.iter().map(|c| c.serial_text()))?;
    Ok(chosen)
}

/// Error when two of `serials` are the same: each sensor's folder and cameras are named by it.
fn check_distinct<'a>(serials: impl Iterator<Item = &'a str>) -> Result<(), CaptureError> {
    let serials: Vec<&str> = serials.collect();
    for (i, s) in serials.iter().enumerate() {
        if serials[..i].contains(s) {
            return Err(CaptureError::Config(format!(
                "two Kinects report the same serial number {s}: kfuse names each sensor's folder and cameras by its serial, so it cannot tell them apart; capture them one at a time (--device with a bus's single sensor) or unplug one"
            )));
        }
    }
    Ok(())
}

/// Opens every sensor of `sensors` and applies `settings` to each; returns the sessions and,
/// per sensor, the lines its settings' read-backs gave. Stops at the first sensor that does
/// not open (the message names it). Error also when two sensors report the same serial.
pub fn open_all(
    sensors: &[Connected],
    settings: &ColorSettings,
) -> Result<Vec<(Session, Vec<String>)>, CaptureError> {
    let mut out = Vec::new();
    for c in sensors {
        let named =
            |e: CaptureError| CaptureError::Config(format!("sensor {}: {e}", c.serial_text()));
        let mut s = Session::open(&c.source).map_err(named)?;
        let lines = s.apply_settings(settings).map_err(named)?;
        out.push((s, lines));
    }
    check_distinct(out.iter().map(|(s, _)| s.info().serial.as_str()))?;
    Ok(out)
}

/// What one shot of several sensors did.
#[derive(Debug, Default)]
pub struct ShotReport {
    /// Sensors that wrote this shot.
    pub written: usize,
    /// Sensors lost at this shot: (serial, why). They take no further shots.
    pub lost: Vec<(String, String)>,
}

/// One sensor's timestamps of one shot.
#[derive(Debug, Clone, Copy)]
struct Stamp {
    depth: u32,
    color: u32,
    relative_ticks: i64,
}

struct Member {
    serial: String,
    session: Session,
    pump: FramePump,
    writer: ShotWriter,
    lost: Option<(usize, String)>,
    first: Option<u32>,
    stamps: Vec<Option<Stamp>>,
}

/// Signed difference `a − b` of two wrapping u32 timestamps.
fn ticks_between(a: u32, b: u32) -> i64 {
    a.wrapping_sub(b) as i32 as i64
}

impl Member {
    fn relative(&self) -> i64 {
        match (self.pump.depth_timestamp(), self.first) {
            (Some(t), Some(f)) => ticks_between(t, f),
            _ => 0,
        }
    }

    /// Pumps until `done` holds, at most [`MAX_ALIGN_FRAMES`] frames; `Ok(false)` if it never
    /// did.
    fn pump_until(&mut self, done: impl Fn(&FramePump) -> bool) -> Result<bool, CaptureError> {
        for _ in 0..2 * MAX_ALIGN_FRAMES {
            if done(&self.pump) {
                return Ok(true);
            }
            if self.pump.pump(&mut self.session, FRAME_TIMEOUT)?.is_none() {
                return Err(CaptureError::Device(kinect_usb::KinectError::Protocol {
                    what: "capture".into(),
                    detail: format!("no frame within {FRAME_TIMEOUT:?}"),
                }));
            }
        }
        Ok(done(&self.pump))
    }

    /// Pumps until the colour frame is within half a period of the depth frame.
    fn pair_colour(&mut self) -> Result<(), CaptureError> {
        self.pump_until(|p| match (p.depth_timestamp(), p.color_timestamp()) {
            (Some(d), Some(c)) => ticks_between(c, d).abs() <= HALF_PERIOD_TICKS,
            _ => false,
        })
        .map(|_| ())
    }
}

/// Shots from several open sensors into `OUT/SERIAL/` (module docs).
pub struct MultiShots {
    out: PathBuf,
    kind: ShotKind,
    members: Vec<Member>,
    names: Vec<String>,
}

impl MultiShots {
    /// Sets up the sensor folders `out/SERIAL/` with each sensor's `kinect_params.json`, and
    /// for a simulated ring `out/true_rig.json`; decoders per `decoder`.
    pub fn new(
        out: &Path,
        kind: ShotKind,
        sessions: Vec<Session>,
        decoder: &DecoderOptions,
    ) -> Result<Self, CaptureError> {
        std::fs::create_dir_all(out).map_err(|e| CaptureError::write(out, e))?;
        let mut members = Vec::new();
        for session in sessions {
            let serial = session.info().serial.clone();
            let folder = out.join(&serial);
            let writer = ShotWriter::new(&folder)?;
            write_params_json(&folder, session.info())?;
            let pump = FramePump::new(session.decoder(decoder)?);
            members.push(Member {
                serial,
                session,
                pump,
                writer,
                lost: None,
                first: None,
                stamps: Vec::new(),
            });
        }
        let rings: Vec<&SimRing> = members
            .iter()
            .filter_map(|m| match m.session.source() {
                SensorSource::Sim(o) => o.ring.as_ref(),
                _ => None,
            })
            .collect();
        if !rings.is_empty() && rings.len() == members.len() {
            let rig = sim_true_rig(rings[0].sensors)?;
            let serials: Vec<&str> = members.iter().map(|m| m.serial.as_str()).collect();
            let rig = sub_rig(&rig, &serials)?;
            kfuse_io::rig::write_multi_rig(&out.join("true_rig.json"), &rig)?;
        }
        Ok(Self { out: out.to_path_buf(), kind, members, names: Vec::new() })
    }

    /// The serial numbers, in order.
    pub fn serials(&self) -> Vec<&str> {
        self.members.iter().map(|m| m.serial.as_str()).collect()
    }

    /// The folder of sensor `serial`.
    pub fn folder(&self, serial: &str) -> PathBuf {
        self.out.join(serial)
    }

    /// Sensors still running.
    pub fn live(&self) -> usize {
        self.members.iter().filter(|m| m.lost.is_none()).count()
    }

    /// The sessions still running (to keep their streams drained while waiting for a trigger).
    pub fn sessions_mut(&mut self) -> impl Iterator<Item = &mut Session> {
        self.members.iter_mut().filter(|m| m.lost.is_none()).map(|m| &mut m.session)
    }

    /// Drains every running sensor's stream for about `for_ms` milliseconds (an interval
    /// between shots: the shot then shows the present, not a queue of old frames). A sensor
    /// whose stream fails is lost.
    pub fn drain(&mut self, wait: std::time::Duration, stop: &dyn Fn() -> bool) -> ShotReport {
        let mut report = ShotReport::default();
        let until = Instant::now() + wait;
        let shot = self.names.len();
        while Instant::now() < until && !stop() {
            for m in self.members.iter_mut().filter(|m| m.lost.is_none()) {
                if let Err(e) =
                    m.session.next_frame(std::time::Duration::from_millis(10), &mut |_, _| {})
                {
                    m.lost = Some((shot, e.to_string()));
                    report.lost.push((m.serial.clone(), e.to_string()));
                }
            }
            if self.live() == 0 {
                break;
            }
        }
        report
    }

    /// Takes shot `name` from every running sensor (module docs: pairing) and writes it into
    /// each sensor's folder. Error only for a file that cannot be written; a sensor whose
    /// stream fails is lost (in the report) and the others go on.
    pub fn shoot(&mut self, name: &str) -> Result<ShotReport, CaptureError> {
        let mut report = ShotReport::default();
        let shot = self.names.len();
        let since = Instant::now();
        let lose = |m: &mut Member, e: CaptureError, report: &mut ShotReport| {
            let why = e.to_string();
            m.lost = Some((shot, why.clone()));
            report.lost.push((m.serial.clone(), why));
        };
        for m in self.members.iter_mut().filter(|m| m.lost.is_none()) {
            let r = m.pump.fresh_pair(&mut m.session, since).and_then(|()| m.pair_colour());
            match r {
                Ok(()) => {
                    if m.first.is_none() {
                        m.first = m.pump.depth_timestamp();
                    }
                }
                Err(e) => lose(m, e, &mut report),
            }
        }
        // Catch up with the latest sensor (timestamps from each sensor's first shot).
        let latest = self.members.iter().filter(|m| m.lost.is_none()).map(Member::relative).max();
        if let Some(latest) = latest {
            for m in self.members.iter_mut().filter(|m| m.lost.is_none()) {
                let first = m.first;
                let r = m
                    .pump_until(|p| match (p.depth_timestamp(), first) {
                        (Some(t), Some(f)) => ticks_between(t, f) >= latest - HALF_PERIOD_TICKS,
                        _ => false,
                    })
                    .and_then(|_| m.pair_colour());
                if let Err(e) = r {
                    lose(m, e, &mut report);
                }
            }
        }
        let kind = self.kind;
        for m in self.members.iter_mut() {
            if m.lost.is_some() {
                m.stamps.push(None);
                continue;
            }
            let files = shot_files(m.writer.out(), name, kind);
            m.writer.write(&files, m.pump.color_jpeg(), m.pump.ir(), m.pump.depth_mm())?;
            m.stamps.push(Some(Stamp {
                depth: m.pump.depth_timestamp().unwrap_or(0),
                color: m.pump.color_timestamp().unwrap_or(0),
                relative_ticks: m.relative(),
            }));
            report.written += 1;
        }
        self.names.push(name.to_string());
        self.write_index()?;
        Ok(report)
    }

    /// The depth frame of the newest shot of sensor `serial` (mm), for callers that write
    /// more per shot (a corrected depth).
    pub fn depth_mm(&self, serial: &str) -> Option<&[f32]> {
        self.members
            .iter()
            .find(|m| m.serial == serial && m.lost.is_none())
            .map(|m| m.pump.depth_mm())
    }

    /// Writes `OUT/index.json` (after every shot, so an interrupted run has it too).
    fn write_index(&self) -> Result<(), CaptureError> {
        let sensors: Vec<serde_json::Value> = self
            .members
            .iter()
            .map(|m| {
                serde_json::json!({
                    "serial": m.serial,
                    "folder": m.serial,
                    "shots": m.stamps.iter().flatten().count(),
                    "lost_after_shot": m.lost.as_ref().map(|(k, _)| k),
                    "lost": m.lost.as_ref().map(|(_, why)| why),
                })
            })
            .collect();
        let shots: Vec<serde_json::Value> = self
            .names
            .iter()
            .enumerate()
            .map(|(k, name)| {
                let mut per = serde_json::Map::new();
                let mut rel = Vec::new();
                for m in &self.members {
                    if let Some(Some(s)) = m.stamps.get(k) {
                        rel.push(s.relative_ticks);
                        per.insert(
                            m.serial.clone(),
                            serde_json::json!({
                                "depth_timestamp": s.depth,
                                "color_timestamp": s.color,
                                "since_first_shot_ms": s.relative_ticks as f64 * 0.125,
                            }),
                        );
                    }
                }
                let spread = rel.iter().max().zip(rel.iter().min()).map_or(0, |(a, b)| a - b);
                serde_json::json!({
                    "name": name,
                    "sensors": per,
                    "spread_ms": spread as f64 * 0.125,
                })
            })
            .collect();
        let v = serde_json::json!({
            "format": INDEX_FORMAT,
            "version": 1,
            "kind": match self.kind { ShotKind::Calib => "calib", ShotKind::Scene => "scene" },
            "units": "timestamps in sensor ticks of 0.125 ms, each sensor its own clock; since_first_shot_ms from that sensor's first shot",
            "sensors": sensors,
            "shots": shots,
        });
        let path = self.out.join("index.json");
        write_atomic(&path, |w| {
            serde_json::to_writer_pretty(&mut *w, &v)?;
            w.write_all(b"\n")
        })
        .map_err(|e| CaptureError::write(&path, e))
    }

    /// Closes every session; returns each sensor's serial and session (for stream counters
    /// and simulator reports) in order.
    pub fn close(mut self) -> Vec<(String, Session)> {
        let members = std::mem::take(&mut self.members);
        members
            .into_iter()
            .map(|mut m| {
                m.session.close();
                (m.serial, m.session)
            })
            .collect()
    }
}

/// The cameras of `serials` (in that order) of `rig`, re-based on the first one's depth
/// camera.
fn sub_rig(
    rig: &geometry::multi_rig::MultiRig,
    serials: &[&str],
) -> Result<geometry::multi_rig::MultiRig, CaptureError> {
    let mut cameras = Vec::new();
    for s in serials {
        cameras.extend(rig.cameras.iter().filter(|c| c.sensor.as_deref() == Some(*s)).cloned());
    }
    let reference = format!("{}.depth", serials.first().copied().unwrap_or_default());
    let ref_from_old = rig
        .camera(&reference)
        .map(|c| c.camera_from_reference.inverse())
        .ok_or_else(|| CaptureError::Config(format!("the true rig has no camera {reference}")))?;
    for c in &mut cameras {
        c.camera_from_reference = c.camera_from_reference.compose(&ref_from_old);
    }
    let out =
        geometry::multi_rig::MultiRig { reference, cameras, calibration: None, rectified: false };
    out.validate()?;
    Ok(out)
}

/// How one sensor's recording went.
#[derive(Debug)]
pub struct SensorRecording {
    /// The sensor's serial number.
    pub serial: String,
    /// The file.
    pub path: PathBuf,
    /// What [`record`] returned (an error: the sensor did not open, or a write failed).
    pub result: Result<Recorded, CaptureError>,
}

/// Records `frames` depth frames of every sensor of `sensors` at once, each into
/// `out/SERIAL.kfrec`, each on its own thread (a sensor that fails or is lost ends its own
/// recording; the others go on). `settings` are applied to each sensor after it opens;
/// `stop` is polled between frames.
pub fn record_all(
    sensors: &[Connected],
    out: &Path,
    frames: u64,
    settings: &ColorSettings,
    stop: &(dyn Fn() -> bool + Sync),
) -> Vec<SensorRecording> {
    std::thread::scope(|scope| {
        let handles: Vec<_> = sensors
            .iter()
            .map(|c| {
                let path = out.join(format!("{}.kfrec", c.serial_text()));
                let serial = c.serial_text().to_string();
                let h = scope.spawn({
                    let path = path.clone();
                    move || {
                        let mut session = Session::open(&c.source)?;
                        session.apply_settings(settings)?;
                        let r = record(&mut session, &path, frames, stop, &mut |_| {});
                        session.close();
                        r
                    }
                });
                (serial, path, h)
            })
            .collect();
        handles
            .into_iter()
            .map(|(serial, path, h)| SensorRecording {
                serial,
                path,
                result: h.join().unwrap_or_else(|_| {
                    Err(CaptureError::Config("the recording thread panicked".into()))
                }),
            })
            .collect()
    })
}
