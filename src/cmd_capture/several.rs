//! `kfuse capture calib|scene|record` with several `--device`s: the flags' checks, the trigger
//! and the messages over `kfuse_capture::multi` (which opens the sensors, pairs their frames,
//! writes `OUT/SERIAL/`, `OUT/index.json` and the recordings, and drops a lost sensor).

use std::path::Path;
use std::sync::mpsc;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use kfuse_capture::multi::{self, Connected, MultiShots, ShotReport};
use kfuse_capture::{ShotKind, shot_files};

use super::{CommonArgs, Trigger, Waited, report_counters};

fn serials(sensors: &[Connected]) -> String {
    sensors.iter().map(Connected::serial_text).collect::<Vec<_>>().join(", ")
}

fn print_lost(report: &ShotReport, shot: usize, live: usize) {
    for (serial, why) in &report.lost {
        eprintln!(
            "sensor {serial} was lost after {shot} shot(s): {why}; the other {live} sensor(s) go on"
        );
    }
}

/// What every command of several sensors refuses before it starts: `--sim-report` (one
/// sensor's report) and an `--out` that is a file (`what` says where the files go).
fn check_options(common: &CommonArgs, out: &Path, what: &str) -> Result<()> {
    if common.sim_report.is_some() {
        bail!("--sim-report writes one sensor's report: give one --device with it");
    }
    if out.exists() && !out.is_dir() {
        bail!(
            "--out {}: exists and is not a folder; several sensors' {what}: give a folder name",
            out.display()
        );
    }
    Ok(())
}

/// `capture calib|scene` from every sensor of `sensors` into `out/SERIAL/`.
pub(super) fn shots(
    out: &Path,
    names: &[String],
    kind: ShotKind,
    interval: Option<f64>,
    overwrite: bool,
    common: &CommonArgs,
    sensors: &[Connected],
) -> Result<()> {
    check_options(common, out, "shots go into OUT/SERIAL/ folders")?;
    if !overwrite {
        for s in sensors {
            let folder = out.join(s.serial_text());
            if let Some(p) =
                names.iter().flat_map(|n| shot_files(&folder, n, kind)).find(|p| p.exists())
            {
                bail!(
                    "{} already exists; pass --overwrite to replace, or choose another --out",
                    p.display()
                );
            }
        }
    }
    eprintln!("starting {} Kinects ({})…", sensors.len(), serials(sensors));
    let (chosen, settings) = (sensors.to_vec(), common.settings());
    let opened = crate::interrupt::run_until_interrupted(
        ": stopped while the sensors were starting; nothing was written",
        move || multi::open_all(&chosen, &settings),
    )??;
    let mut sessions = Vec::new();
    for (session, lines) in opened {
        for l in lines {
            eprintln!("{}: {l}", session.info().serial);
        }
        sessions.push(session);
    }
    let mut shots = MultiShots::new(out, kind, sessions, &common.decoder())?;
    let trigger = Trigger::new(interval);
    if matches!(trigger, Trigger::Lines(_)) {
        eprintln!("Press Enter to take each of {} shots (Ctrl-D to stop early).", names.len());
    }
    let mut lost = Vec::new();
    let mut saved = 0usize;
    let mut stopped = None;
    for n in names {
        let report = match &trigger {
            Trigger::Interval(d) => shots.drain(*d, &crate::interrupt::requested),
            Trigger::Lines(rx) => match wait_line(rx) {
                Waited::Shoot => ShotReport::default(),
                w => {
                    stopped = Some(w);
                    break;
                }
            },
        };
        print_lost(&report, saved, shots.live());
        lost.extend(report.lost);
        if crate::interrupt::requested() {
            stopped = Some(Waited::Interrupted);
            break;
        }
        if shots.live() == 0 {
            break;
        }
        let report = shots.shoot(n)?;
        print_lost(&report, saved, shots.live());
        lost.extend(report.lost);
        if report.written == 0 {
            break;
        }
        saved += 1;
    }
    let live = shots.live();
    for (_, session) in shots.close() {
        report_counters(&session);
    }
    match stopped {
        Some(Waited::StdinClosed) if saved == 0 => bail!(
            "stdin was closed before the first shot, so nothing was captured: press Enter for each shot, or give --interval SECONDS for automatic shots"
        ),
        Some(Waited::StdinClosed) => eprintln!("stdin closed: stopping after {saved} shot(s)"),
        Some(Waited::Interrupted) => crate::interrupt::check(&format!(
            ": {saved} complete shot(s) of each sensor are in {}",
            out.display()
        ))?,
        _ => {}
    }
    if !lost.is_empty() {
        let names: Vec<String> = lost.iter().map(|(s, _)| s.clone()).collect();
        bail!(
            "lost during the capture: {}; the {live} other sensor(s) took all {saved} shot(s), and every shot saved is complete, in {} (index.json lists which sensor has which)",
            names.join(", "),
            out.display()
        );
    }
    eprintln!("saved {saved} shot(s) from each of {live} sensors in {}", out.display());
    Ok(())
}

/// Waits for one line on stdin (a shot), stdin's end, or an interrupt.
fn wait_line(rx: &mpsc::Receiver<()>) -> Waited {
    loop {
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(()) => return Waited::Shoot,
            Err(mpsc::RecvTimeoutError::Timeout) if !crate::interrupt::requested() => {}
            Err(mpsc::RecvTimeoutError::Timeout) => return Waited::Interrupted,
            Err(mpsc::RecvTimeoutError::Disconnected) => return Waited::StdinClosed,
        }
    }
}

/// `capture record` of every sensor of `sensors` into `out/SERIAL.kfrec`.
pub(super) fn record(
    out: &Path,
    frames: u64,
    overwrite: bool,
    common: &CommonArgs,
    sensors: &[Connected],
) -> Result<()> {
    check_options(common, out, "recordings are OUT/SERIAL.kfrec")?;
    if !overwrite {
        for s in sensors {
            let p = out.join(format!("{}.kfrec", s.serial_text()));
            if p.exists() {
                bail!("{} already exists; pass --overwrite to replace it", p.display());
            }
        }
    }
    std::fs::create_dir_all(out).with_context(|| format!("--out {}", out.display()))?;
    eprintln!("recording {} Kinects ({})…", sensors.len(), serials(sensors));
    let stop = crate::interrupt::requested;
    let results = multi::record_all(sensors, out, frames, &common.settings(), &stop);
    let mut failed = Vec::new();
    for r in &results {
        match &r.result {
            Ok(rec) if rec.stopped_by.is_none() && !rec.interrupted => {
                eprintln!(
                    "{}: recorded {} depth frames to {}",
                    r.serial,
                    rec.frames,
                    r.path.display()
                );
            }
            Ok(rec) => {
                let why = rec
                    .stopped_by
                    .as_ref()
                    .map_or_else(|| "interrupted".to_string(), |e| e.to_string());
                eprintln!(
                    "sensor {} was lost after {} depth frames: {why}; its recording {} is complete up to there, the other sensors went on",
                    r.serial,
                    rec.frames,
                    r.path.display()
                );
                failed.push(r.serial.clone());
            }
            Err(e) => {
                eprintln!("sensor {}: {e}", r.serial);
                failed.push(r.serial.clone());
            }
        }
    }
    crate::interrupt::check(&format!(
        ": the recordings in {} are complete and replayable",
        out.display()
    ))?;
    if !failed.is_empty() {
        bail!(
            "not every sensor recorded {frames} frames: {}; the others' recordings are complete in {}",
            failed.join(", "),
            out.display()
        );
    }
    Ok(())
}
