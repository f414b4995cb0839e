//! `kfuse devices` and `kfuse capture {calib,scene,record}`: the clap layer over the
//! `kfuse-capture` library (sensor source, session, frame pump, shot writer, recording), which
//! the viewer's live page uses too. Here: the flags and their parsers, the shot trigger
//! (interval or Enter), the progress bar and the messages.

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand, ValueEnum};
use geometry::depth_correction::DepthCorrection;
use indicatif::{ProgressBar, ProgressStyle};
use kfuse_capture::multi::{self, Connected};
use kfuse_capture::session::{decoder_summary, list_devices};
use kfuse_capture::settings::{LedState, parse_exposure, parse_led};
use kfuse_capture::{
    CaptureError, ColorSettings, DecoderOptions, FramePump, ReplayOptions, SensorSource, Session,
    ShotKind, ShotWriter, SimOptions, SimRing, shot_files, write_params_json,
};
use kinect_usb::KinectError;
use kinect_usb::decoder::DecoderPrecision;
use kinect_usb::protocol::Exposure;
use kinect_usb::sim::depth_error::DepthError;
use kinect_usb::trace::TraceHandle;

mod depth;
mod rosbag2;
mod several;
mod usb_trace;
use depth::{parse_depth_error, scene_depth_correction, write_corrected};

/// The colour-camera and LED options' help, shared by every capture mode.
macro_rules! settings_help {
    () => {
        "\n\nColour camera and LED (applied right after start-up; not with --replay):\n  \
         --exposure auto              automatic exposure (default of the sensor)\n  \
         --exposure auto:-1           automatic, one stop darker (compensation -2..2)\n  \
         --exposure semi:20           semi-automatic, 20 ms pseudo exposure time (0..66 ms)\n  \
         --exposure manual:20,2       manual: 20 ms integration time, analog gain 2 (gain 1..4)\n  \
         --led on:500                 LED 0 at level 500 of 1000 (--led-id 1 for LED 1)\n  \
         --led blink:250              LED 0 blinking every 250 ms; --led off / --led on\n  \
         kfuse capture calib --out shots --interval 2 --exposure manual:20,2 --led blink:500\n\
         A fixed manual exposure keeps colour brightness constant between calibration shots."
    };
}

/// Which live sensor to use (`--backend` of `devices`, `capture` and `view`); with
/// `--replay` a recording instead. The command line's spelling of
/// `kfuse_capture::SensorSource`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Backend {
    /// A real Kinect v2 over libusb.
    Usb,
    /// The simulated Kinect v2 (synthetic scene from `geometry::synth`).
    Sim,
    /// A USB bus with no Kinect on it (tests: what every command does without a sensor,
    /// whatever is plugged into the machine running them).
    #[value(hide = true)]
    Absent,
}

impl Backend {
    /// The library's sensor source for this backend, with the simulator's faults.
    pub fn source(self, sim: SimOptions) -> SensorSource {
        match self {
            Backend::Usb => SensorSource::Usb,
            Backend::Sim => SensorSource::Sim(sim),
            Backend::Absent => SensorSource::Absent,
        }
    }
}

/// `kfuse devices`.
#[derive(Args, Debug)]
#[command(after_help = "Examples:\n  kfuse devices\n\nExits non-zero when no Kinect v2 is found.")]
pub struct DevicesArgs {
    /// The sensor: `usb`, a Kinect v2, or `sim`, the simulated Kinect v2 (no hardware needed;
    /// it reports its own factory parameters). With `sim`, `capture calib` shows a 7x5-corner
    /// checkerboard of 40 mm squares in 17 tilted poses at 0.6–2.5 m (one pose per frame:
    /// `--count 17 --interval 0` takes each once; `kfuse calibrate --allow-unpaired` then
    /// recovers the factory parameters: in the farthest poses the board is too small for the
    /// IR image, so those pairs serve the colour camera only), `capture scene` the synthetic
    /// Kinect preset (objects before a wall).
    #[arg(long, value_enum, default_value_t = Backend::Usb)]
    backend: Backend,
    /// With `--backend sim`: how many simulated Kinects (1–4), in a ring around the scene
    /// (`kinect_usb::sim::ring`), each with its own serial and factory parameters.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=4))]
    sim_sensors: u8,
}

/// Options shared by every capture mode.
#[derive(Args, Debug, Clone)]
pub struct CommonArgs {
    /// Replay a raw recording (made with `kfuse capture record`) instead of a live sensor.
    #[arg(long, value_name = "FILE")]
    replay: Option<PathBuf>,
    /// Accept a truncated recording and use its intact beginning.
    #[arg(long, requires = "replay")]
    allow_truncated: bool,
    /// Leave out records of the recording whose checksum does not match (each is reported)
    /// instead of stopping at the first.
    #[arg(long, requires = "replay")]
    skip_corrupt: bool,
    /// Decode depth without the bilateral and edge-aware filters (raw per-pixel depth).
    #[arg(long)]
    no_filters: bool,
    /// Decode with glibc's exp/atan2 exactly as libfreenect2's CPU decoder (bit-identical,
    /// ~2× slower) instead of the default fast decoder (within 0.01 mm of it).
    #[arg(long)]
    exact_decoder: bool,
    /// The sensor: `usb`, a Kinect v2, or `sim`, the simulated Kinect v2 (no hardware needed;
    /// it reports its own factory parameters). With `sim`, `capture calib` shows a 7x5-corner
    /// checkerboard of 40 mm squares in 17 tilted poses at 0.6–2.5 m (one pose per frame:
    /// `--count 17 --interval 0` takes each once; `kfuse calibrate --allow-unpaired` then
    /// recovers the factory parameters: in the farthest poses the board is too small for the
    /// IR image, so those pairs serve the colour camera only), `capture scene` the synthetic
    /// Kinect preset (objects before a wall).
    #[arg(long, value_enum, default_value_t = Backend::Usb)]
    backend: Backend,
    /// The Kinect to capture from, by serial number (`kfuse devices` lists them); repeat it for
    /// several, or `all`. With more than one, each sensor's files go into `OUT/SERIAL/` (the
    /// same names as for one), `OUT/index.json` lists each shot's sensor timestamps and a
    /// recording is `OUT/SERIAL.kfrec`. Without it: the first Kinect, files in `OUT`.
    #[arg(long = "device", value_name = "SERIAL|all", conflicts_with = "replay")]
    devices: Vec<String>,
    /// With `--backend sim`: how many simulated Kinects (1–4), in a ring 1.6 m from the centre
    /// facing it, 360°/N apart (two face each other), each with its own serial number
    /// (000000000001…) and factory parameters; `capture calib --device all` writes the true
    /// rig of the chosen sensors as `OUT/true_rig.json`.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=4))]
    sim_sensors: u8,
    /// Simulated ring: the `--sim-*` faults only on the sensor of this serial.
    #[arg(long, hide = true, value_name = "SERIAL")]
    sim_fault_sensor: Option<String>,
    /// Simulated ring: the second sensor reports the first one's serial number.
    #[arg(long, hide = true)]
    sim_same_serial: bool,
    /// Set by `capture calib`: the simulated sensor shows its calibration scene.
    #[arg(skip)]
    sim_calib_scene: bool,
    /// Set by `capture calib`: the frames of the calibration scene its shots reach
    /// (`SimOptions::calib_frames`; `None`: every one).
    #[arg(skip)]
    sim_calib_frames: Option<usize>,
    /// The one sensor `--device SERIAL` chose (its source opens exactly it).
    #[arg(skip)]
    chosen_source: Option<SensorSource>,
    /// Simulated device: disappear after this many frame periods.
    #[arg(long, hide = true)]
    sim_unplug_after: Option<u64>,
    /// Simulated device: report busy.
    #[arg(long, hide = true)]
    sim_busy: bool,
    /// Simulated device: fraction of isochronous packets lost, 0..1.
    #[arg(long, hide = true, default_value_t = 0.0, value_parser = parse_fraction)]
    sim_iso_drop: f64,
    /// Simulated device: make this depth error on purpose (issue 16), `OFFSET_MM,SCALE,RADIAL_MM`
    /// (measured z = (1 + SCALE)·z + OFFSET + RADIAL·ρ², ρ = 1 at the image corners), or
    /// `kinect` for 24,0.005,10 (libfreenect2 issue 144's 24 mm, 0.5 %, 10 mm at the corners).
    /// `kfuse calibrate --depth` measures it back.
    #[arg(long, value_name = "OFFSET_MM,SCALE,RADIAL_MM", value_parser = parse_depth_error)]
    sim_depth_error: Option<DepthError>,
    /// Simulated device: give the depth the Kinect noise (σ = 1.5 mm·z², flying pixels),
    /// independent in each of 16 frames it cycles through.
    #[arg(long, hide = true)]
    sim_depth_noise: bool,
    /// Simulated device: write its colour settings, LED state and protocol violations as JSON
    /// to this file when the capture ends.
    #[arg(long, hide = true, value_name = "FILE")]
    sim_report: Option<PathBuf>,
    /// Colour exposure: `auto[:COMP]` (COMP in -2..2), `semi:MS` (0..66 ms) or
    /// `manual:MS,GAIN` (0..66 ms, gain 1..4).
    #[arg(long, value_name = "MODE", value_parser = parse_exposure, conflicts_with = "replay")]
    exposure: Option<Exposure>,
    /// LED: `off`, `on`, `on:LEVEL` (0..1000) or `blink:MS` (blink interval in ms).
    #[arg(long, value_name = "STATE", value_parser = parse_led, conflicts_with = "replay")]
    led: Option<LedState>,
    /// Which LED `--led` drives (the sensor has LEDs 0 and 1).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u16).range(0..2), requires = "led")]
    led_id: u16,
}

/// Longest `--interval`: one day. Longer waits are certainly a typo (and `inf` or 1e30 would
/// overflow the `Duration` of the wait).
pub const MAX_INTERVAL_S: f64 = 86_400.0;

/// Parses `--interval`: a finite number of seconds in `[0, MAX_INTERVAL_S]`.
pub fn parse_interval(s: &str) -> std::result::Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("`{s}` is not a number of seconds"))?;
    if !(0.0..=MAX_INTERVAL_S).contains(&v) {
        return Err(format!(
            "{} s is outside [0, {MAX_INTERVAL_S}] seconds",
            geometry::num_fmt::num(v)
        ));
    }
    Ok(v)
}

/// Parses a fraction in `[0, 1]` (`--sim-iso-drop`).
pub fn parse_fraction(s: &str) -> std::result::Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("`{s}` is not a number"))?;
    if !(0.0..=1.0).contains(&v) {
        return Err(format!("{} is outside [0, 1]", geometry::num_fmt::num(v)));
    }
    Ok(v)
}

/// Parses `--name`: a plain file name, so that every file lands inside `--out` (no separators,
/// no `.` or `..`, not empty, no absolute path).
pub fn parse_plain_name(s: &str) -> std::result::Result<String, String> {
    let plain = !s.is_empty()
        && s != "."
        && s != ".."
        && !s.contains(['/', '\\'])
        && Path::new(s).file_name() == Some(std::ffi::OsStr::new(s));
    if !plain {
        return Err(format!(
            "`{s}` is not a plain file name (no folders or `..`); put the folder in --out"
        ));
    }
    Ok(s.to_string())
}

/// `kfuse capture`.
#[derive(Args, Debug)]
pub struct CaptureArgs {
    #[command(subcommand)]
    mode: CaptureMode,
}

#[derive(Subcommand, Debug)]
enum CaptureMode {
    /// Capture checkerboard image pairs for calibration (colour JPEG + IR + depth per shot).
    #[command(after_help = concat!("Examples:\n  kfuse capture calib --out calib_shots --count 20            # press Enter for each shot\n  \
        kfuse capture calib --out calib_shots --count 20 --interval 2   # a shot every 2 s\n  \
        kfuse capture calib --replay session.kfrec --out shots --interval 0\n\n\
        Writes color_NNNN.jpg, ir_NNNN.png (16-bit), depth_NNNN.png (16-bit, mm, 0 = invalid)\n\
        and kinect_params.json (factory intrinsics of both cameras). Move the board between shots.", settings_help!()))]
    Calib {
        /// Output folder.
        #[arg(long, default_value = "calib_capture")]
        out: PathBuf,
        /// Number of shots (at least 1).
        #[arg(long, default_value_t = 20, value_parser = clap::builder::RangedI64ValueParser::<usize>::new().range(1..))]
        count: usize,
        /// Seconds between automatic shots (0..86400); without it, each line on stdin (Enter)
        /// takes a shot.
        #[arg(long, value_parser = parse_interval)]
        interval: Option<f64>,
        /// Replace existing files in the output folder.
        #[arg(long)]
        overwrite: bool,
        #[command(flatten)]
        common: CommonArgs,
    },
    /// Save the colour, IR and depth of a scene when you press Enter.
    #[command(after_help = concat!("Examples:\n  kfuse capture scene --out lab --name desk         # press Enter to save\n  \
        kfuse capture scene --out lab --name desk --interval 0   # save immediately\n\n\
        Writes NAME_color.jpg, NAME_ir.png, NAME_depth.png (mm) and kinect_params.json.", settings_help!()))]
    Scene {
        /// Output folder.
        #[arg(long, default_value = "scene_capture")]
        out: PathBuf,
        /// File name prefix: a plain file name (no folders, no `..`); files go into --out.
        #[arg(long, default_value = "scene", value_parser = parse_plain_name)]
        name: String,
        /// Number of scenes to save (numbered when more than one; at least 1).
        #[arg(long, default_value_t = 1, value_parser = clap::builder::RangedI64ValueParser::<usize>::new().range(1..))]
        count: usize,
        /// Seconds before each automatic save (0..86400); without it, press Enter.
        #[arg(long, value_parser = parse_interval)]
        interval: Option<f64>,
        /// Replace existing files.
        #[arg(long)]
        overwrite: bool,
        /// A rig with a depth correction (`kfuse calibrate --depth`): each shot also gets
        /// NAME_depth_corrected.png (16-bit mm, corrected z) beside its raw NAME_depth.png.
        #[arg(long, value_name = "RIG.json")]
        rig: Option<PathBuf>,
        #[command(flatten)]
        common: CommonArgs,
    },
    /// Record raw USB stream packets and the device metadata for later replay.
    #[command(after_help = concat!("Examples:\n  kfuse capture record --out session.kfrec --frames 300\n  \
        kfuse capture calib --replay session.kfrec --interval 0 --count 5 --out shots\n  \
        kfuse capture record --out bug.kfrec --frames 30 --usb-trace bug.kftrace   # for a bug report\n\n\
        The recording holds every isochronous and bulk packet, so replay runs the same parsers and decoder.\n\
        --usb-trace also writes the session's USB calls and transfer headers (no images, about 1 MB/s);\n\
        `kfuse replay-trace bug.kftrace` shows what it holds. Attach the trace to a bug report.", settings_help!()))]
    Record {
        /// Recording file (`--out`, as every other command names its output; `--output`, the
        /// first spelling, still works).
        #[arg(
            long = "out",
            visible_alias = "output",
            value_name = "FILE.kfrec",
            default_value = "capture.kfrec"
        )]
        output: PathBuf,
        /// Depth frames to record (at least 1).
        #[arg(long, default_value_t = 150, value_parser = clap::value_parser!(u64).range(1..))]
        frames: u64,
        /// Replace an existing file.
        #[arg(long)]
        overwrite: bool,
        /// Also write a USB trace to this file for a bug report: every USB call of the session
        /// with its bytes, and each transfer's time, length, status and framing bytes (no
        /// images); `kfuse replay-trace FILE` replays it. Finished even when the sensor fails.
        #[arg(long, value_name = "FILE.kftrace", conflicts_with = "replay")]
        usb_trace: Option<PathBuf>,
        /// With `--usb-trace`: keep every transfer's whole payload, images included (about
        /// 95 MB per second of streaming, capped at 64 MiB of events).
        #[arg(long, requires = "usb_trace")]
        usb_trace_payload: bool,
        /// kfrec (raw packets, replayable) or rosbag2 (a ROS 2 bag folder with the topics of
        /// `kfuse fuse --layout rosbag2`; recorded to a staged .kfrec, then converted).
        #[arg(long, value_enum, default_value_t = RecordFormat::Kfrec)]
        format: RecordFormat,
        /// With --format rosbag2: add each frame's coloured cloud as sd/points (PointCloud2).
        #[arg(long)]
        points: bool,
        #[command(flatten)]
        common: CommonArgs,
    },
}

/// `kfuse capture record --format`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum RecordFormat {
    /// A `.kfrec` file of raw USB packets.
    Kfrec,
    /// A rosbag2 folder (metadata.yaml + OUT_0.mcap) that `ros2 bag play` and Foxglove open.
    Rosbag2,
}

/// Runs `kfuse devices`.
pub fn run_devices(args: DevicesArgs) -> Result<()> {
    let sim = SimOptions { ring: ring(args.sim_sensors), ..SimOptions::default() };
    for line in list_devices(&args.backend.source(sim))? {
        println!("{line}");
    }
    Ok(())
}

/// The ring of `--sim-sensors N` (`None` for one: the single simulated sensor).
fn ring(sensors: u8) -> Option<SimRing> {
    (sensors > 1).then(|| SimRing {
        sensors: sensors as usize,
        index: 0,
        serial: kinect_usb::sim::ring::serial(0),
    })
}

impl CommonArgs {
    /// The sensors `--device` chooses; `None` without `--device` and a ring (the one sensor
    /// of today's capture).
    pub(crate) fn chosen(&self) -> Result<Option<Vec<Connected>>> {
        if self.devices.is_empty() {
            return Ok(None);
        }
        let chosen = multi::select(&multi::connected(&self.source())?, &self.devices)?;
        Ok(Some(chosen))
    }

    /// `self` capturing from the one sensor of `chosen` (from [`CommonArgs::chosen`]), if any.
    pub(crate) fn with_chosen(&self, chosen: Option<Vec<Connected>>) -> CommonArgs {
        let chosen_source = chosen.and_then(|c| c.into_iter().next()).map(|c| c.source);
        CommonArgs { chosen_source, ..self.clone() }
    }

    pub(crate) fn source(&self) -> SensorSource {
        if let Some(s) = &self.chosen_source {
            return s.clone();
        }
        match &self.replay {
            Some(path) => SensorSource::Replay(ReplayOptions {
                path: path.clone(),
                allow_truncated: self.allow_truncated,
                skip_corrupt: self.skip_corrupt,
            }),
            None => self.backend.source(SimOptions {
                unplug_after: self.sim_unplug_after,
                busy: self.sim_busy,
                iso_drop: self.sim_iso_drop,
                calib_scene: self.sim_calib_scene,
                calib_frames: self.sim_calib_frames,
                depth_error: self.sim_depth_error,
                depth_noise: self.sim_depth_noise,
                ring: ring(self.sim_sensors),
                fault_sensor: self.sim_fault_sensor.clone(),
                same_serial: self.sim_same_serial,
                real_time: false,
            }),
        }
    }

    pub(crate) fn settings(&self) -> ColorSettings {
        ColorSettings { exposure: self.exposure, led: self.led.map(|l| l.setting(self.led_id)) }
    }

    pub(crate) fn decoder(&self) -> DecoderOptions {
        let precision =
            if self.exact_decoder { DecoderPrecision::Exact } else { DecoderPrecision::Fast };
        DecoderOptions { no_filters: self.no_filters, precision }
    }
}

/// Environment variable: when set, `kfuse capture` prints its peak resident memory (VmHWM of
/// /proc/self/status) on stderr at the end, for the memory tests.
const PEAK_RSS_ENV: &str = "KFUSE_REPORT_PEAK_RSS";

/// Runs `kfuse capture …`.
pub fn run_capture(args: CaptureArgs) -> Result<()> {
    let r = run_capture_mode(args);
    if std::env::var_os(PEAK_RSS_ENV).is_some()
        && let Ok(s) = std::fs::read_to_string("/proc/self/status")
        && let Some(l) = s.lines().find(|l| l.starts_with("VmHWM:"))
    {
        eprintln!("peak RSS {}", l.trim_start_matches("VmHWM:").trim());
    }
    r
}

fn run_capture_mode(args: CaptureArgs) -> Result<()> {
    // Ctrl-C / SIGTERM set a flag that the capture loops poll: a recording is finished (end
    // record written, file published), a shot is never split.
    crate::interrupt::install()?;
    match args.mode {
        CaptureMode::Calib { out, count, interval, overwrite, common } => {
            // Without a pause (`--interval 0`, or Enter against the simulator, which makes a
            // frame only when one is asked for) shot k is frame k: only the first `count`
            // frames are rendered. An interval streams on between shots, so a shot may show any
            // frame: every pose is rendered, as before.
            let one_frame_per_shot = interval.is_none_or(|s| s == 0.0);
            let frames = one_frame_per_shot.then_some(count);
            let common = CommonArgs { sim_calib_scene: true, sim_calib_frames: frames, ..common };
            let names = (1..=count).map(|i| format!("{i:04}")).collect::<Vec<_>>();
            match common.chosen()? {
                Some(s) if s.len() > 1 => {
                    several::shots(&out, &names, ShotKind::Calib, interval, overwrite, &common, &s)
                }
                s => {
                    let common = common.with_chosen(s);
                    shots(&out, &names, ShotKind::Calib, interval, overwrite, &common, None)
                }
            }
        }
        CaptureMode::Scene { out, name, count, interval, overwrite, rig, common } => {
            let correction = rig.as_deref().map(scene_depth_correction).transpose()?;
            let names: Vec<String> = if count == 1 {
                vec![name.clone()]
            } else {
                (1..=count).map(|i| format!("{name}_{i:04}")).collect()
            };
            match common.chosen()? {
                Some(s) if s.len() > 1 => {
                    if rig.is_some() {
                        bail!(
                            "--rig applies one sensor's depth correction: with several --device, capture each sensor's scene with its own rig, or drop --rig"
                        );
                    }
                    several::shots(&out, &names, ShotKind::Scene, interval, overwrite, &common, &s)
                }
                s => {
                    let common = common.with_chosen(s);
                    let c = correction.as_ref();
                    shots(&out, &names, ShotKind::Scene, interval, overwrite, &common, c)
                }
            }
        }
        CaptureMode::Record {
            output,
            frames,
            overwrite,
            usb_trace,
            usb_trace_payload,
            format,
            points,
            common,
        } => {
            let trace = usb_trace::TraceRequest::new(usb_trace, usb_trace_payload, overwrite);
            match (format, common.chosen()?) {
                (_, Some(s)) if s.len() > 1 && trace.requested() => bail!(
                    "--usb-trace traces one sensor: choose it with --device SERIAL (`kfuse devices` lists them)"
                ),
                (RecordFormat::Rosbag2, Some(s)) if s.len() > 1 => bail!(
                    "--format rosbag2 records one sensor: give one --device (or record .kfrec files and convert each with kfuse fuse --recording FILE --layout rosbag2)"
                ),
                (RecordFormat::Rosbag2, s) => rosbag2::record(
                    &output,
                    frames,
                    overwrite,
                    points,
                    &common.with_chosen(s),
                    trace,
                ),
                (RecordFormat::Kfrec, _) if points => {
                    bail!("--points adds a topic of --format rosbag2; add --format rosbag2")
                }
                (RecordFormat::Kfrec, Some(s)) if s.len() > 1 => {
                    several::record(&output, frames, overwrite, &common, &s)
                }
                (RecordFormat::Kfrec, s) => {
                    record(&output, frames, overwrite, &common.with_chosen(s), trace)
                }
            }
        }
    }
}

/// Opens the sensor and applies `--exposure` / `--led`, printing what the sensor reads back. A
/// refused setting is an error (the user asked for it); the simulator's report is still written.
pub(crate) fn start(common: &CommonArgs) -> Result<Session> {
    start_source(common, common.source())
}

/// [`start`] of `source` (the one `common` gives, changed by the caller: `kfuse serve` runs
/// the simulator in real time).
pub(crate) fn start_source(common: &CommonArgs, source: SensorSource) -> Result<Session> {
    start_traced(common, source, None)
}

/// [`start_source`] with the session's USB traffic recorded in `trace` (`capture record
/// --usb-trace`).
fn start_traced(
    common: &CommonArgs,
    source: SensorSource,
    trace: Option<&TraceHandle>,
) -> Result<Session> {
    let trace = trace.cloned();
    eprintln!("starting the {}…", source.name());
    // Opening renders the simulator's scene (seconds for the calibration scene's 17 poses) or
    // starts a real sensor: on a worker thread, so that Ctrl-C is answered within
    // `interrupt::run_until_interrupted`'s poll (nothing is written before the sensor runs).
    let mut session = crate::interrupt::run_until_interrupted(
        ": stopped while the sensor was starting; nothing was written",
        move || Session::open_traced(&source, trace.as_ref()),
    )??;
    match session.apply_settings(&common.settings()) {
        Ok(lines) => lines.iter().for_each(|l| eprintln!("{l}")),
        Err(e) => {
            session.close();
            write_sim_report(common, &session)?;
            return Err(e.into());
        }
    }
    Ok(session)
}

/// Writes `--sim-report` (the simulated device's colour settings, LEDs and protocol violations).
pub(crate) fn write_sim_report(common: &CommonArgs, session: &Session) -> Result<()> {
    if let Some(path) = &common.sim_report {
        session.write_sim_report(path)?;
    }
    Ok(())
}

/// Waits for the trigger of the next shot: `interval` seconds, or one line on stdin.
pub(crate) enum Trigger {
    Interval(Duration),
    Lines(mpsc::Receiver<()>),
}

impl Trigger {
    fn new(interval: Option<f64>) -> Self {
        match interval {
            // `parse_interval` bounds it to [0, MAX_INTERVAL_S]; the clamp keeps library callers
            // from the `Duration` panic as well.
            Some(s) => Trigger::Interval(Duration::from_secs_f64(if s.is_finite() {
                s.clamp(0.0, MAX_INTERVAL_S)
            } else {
                0.0
            })),
            None => {
                let (tx, rx) = mpsc::channel();
                std::thread::spawn(move || {
                    for line in std::io::stdin().lock().lines() {
                        if line.is_err() || tx.send(()).is_err() {
                            break;
                        }
                    }
                });
                Trigger::Lines(rx)
            }
        }
    }
}

/// What ended the wait for a shot's trigger.
pub(crate) enum Waited {
    Shoot,
    StdinClosed,
    Interrupted,
}

/// Waits for the trigger; with an interval it keeps draining the stream so the shot is current.
fn wait(trigger: &Trigger, session: &mut Session) -> Result<Waited, CaptureError> {
    match trigger {
        Trigger::Interval(d) => {
            let until = Instant::now() + *d;
            while Instant::now() < until && !crate::interrupt::requested() {
                session.next_frame(Duration::from_millis(50), &mut |_, _| {})?;
            }
        }
        Trigger::Lines(rx) => loop {
            match rx.recv_timeout(Duration::from_millis(100)) {
                Ok(()) => break,
                Err(mpsc::RecvTimeoutError::Timeout) if !crate::interrupt::requested() => {}
                Err(mpsc::RecvTimeoutError::Timeout) => break,
                Err(mpsc::RecvTimeoutError::Disconnected) => return Ok(Waited::StdinClosed),
            }
        },
    }
    Ok(if crate::interrupt::requested() { Waited::Interrupted } else { Waited::Shoot })
}

fn shots(
    out: &Path,
    names: &[String],
    kind: ShotKind,
    interval: Option<f64>,
    overwrite: bool,
    common: &CommonArgs,
    correction: Option<&DepthCorrection>,
) -> Result<()> {
    if out.exists() && !out.is_dir() {
        bail!(
            "--out {}: exists and is not a folder; shots are saved into a folder: give a folder name such as {}",
            out.display(),
            if kind == ShotKind::Calib { "calib_shots" } else { "scenes" }
        );
    }
    let files = |n: &str| shot_files(out, n, kind);
    if !overwrite && let Some(p) = names.iter().flat_map(|n| files(n)).find(|p| p.exists()) {
        bail!(
            "{} already exists; pass --overwrite to replace, or choose another --out",
            p.display()
        );
    }
    let created = !out.exists();
    let writer = ShotWriter::new(out)?;
    let mut session = match start(common) {
        Ok(session) => session,
        Err(e) => {
            // The folder made for the shots is removed again when it is still empty.
            drop(writer);
            if created {
                let _ = std::fs::remove_dir(out);
            }
            return Err(e);
        }
    };
    write_params_json(out, session.info())?;
    let opts = common.decoder();
    let mut pump = FramePump::new(session.decoder(&opts)?);
    eprintln!("depth decoder: {}", decoder_summary(&opts, pump.decoder()));
    let trigger = Trigger::new(interval);
    if matches!(trigger, Trigger::Lines(_)) {
        eprintln!("Press Enter to take each of {} shots (Ctrl-D to stop early).", names.len());
    }
    let bar = ProgressBar::new(names.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} shots {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut saved = 0usize;
    let mut outcome: Result<(), CaptureError> = Ok(());
    let mut interrupted = false;
    let mut stdin_closed = false;
    for n in names {
        match wait(&trigger, &mut session) {
            Ok(Waited::Shoot) => {}
            Ok(Waited::StdinClosed) => {
                eprintln!("stdin closed: stopping after {saved} shot(s)");
                stdin_closed = true;
                break;
            }
            Ok(Waited::Interrupted) => {
                interrupted = true;
                break;
            }
            Err(e) => {
                outcome = Err(e);
                break;
            }
        }
        if let Err(e) = pump.fresh_pair(&mut session, Instant::now()) {
            outcome = Err(e);
            break;
        }
        writer.write(&files(n), pump.color_jpeg(), pump.ir(), pump.depth_mm())?;
        if let Some(c) = correction {
            write_corrected(&files(n)[2], pump.depth_mm(), c)?;
        }
        saved += 1;
        bar.inc(1);
    }
    bar.finish_and_clear();
    drop(writer);
    report_counters(&session);
    session.close();
    write_sim_report(common, &session)?;
    if let Some(e) = replay_outcome(common, &session) {
        bail!(
            "{e}\nreplay stopped: {saved} shot(s) taken before it are intact in {}",
            out.display()
        );
    }
    if stdin_closed && saved == 0 {
        // Run from a script or with its input redirected: no shot was triggered, which is not
        // a capture (it exited 0 with an empty folder in a user's trial).
        bail!(
            "stdin was closed before the first shot, so nothing was captured: press Enter for each shot, or give --interval SECONDS for automatic shots"
        );
    }
    if interrupted {
        crate::interrupt::check(&format!(
            ": {saved} complete shot(s) (each with its colour, IR and depth) are in {}",
            out.display()
        ))?;
    }
    match outcome {
        Ok(()) => {
            eprintln!("saved {saved} shot(s) in {}", out.display());
            Ok(())
        }
        Err(e) if e.is_disconnected() => bail!(
            "{e}\ncapture stopped: {saved} complete shot(s) were saved in {} and are intact; reconnect the sensor (USB 3 port, power) and run again",
            out.display()
        ),
        Err(e) if e.is_end_of_stream() => {
            bail!("the recording ended after {saved} shot(s) (saved in {})", out.display())
        }
        Err(e) => Err(e.into()),
    }
}

/// After a replay: reports skipped records and a kept truncated prefix, and returns the error
/// that ended the replay early (a corrupt record), which must fail the command.
fn replay_outcome(common: &CommonArgs, session: &Session) -> Option<KinectError> {
    let path = common.replay.as_ref()?;
    let outcome = session.replay_outcome()?;
    let report = &outcome.report;
    for run in &report.skipped {
        let (i, at, n) = (run.first_index, run.offset, run.bytes);
        if run.records == 1 {
            eprintln!(
                "warning: {}: record {i} at byte {at} is corrupt (checksum mismatch) and was left out",
                path.display()
            );
        } else {
            eprintln!(
                "warning: {}: {} records from record {i} at byte {at} ({n} bytes) are corrupt (checksum mismatch) and were left out",
                path.display(),
                run.records
            );
        }
    }
    if report.unlisted_runs > 0 {
        eprintln!(
            "warning: {}: {} more damaged places not listed; in all {} records ({} bytes) were left out",
            path.display(),
            report.unlisted_runs,
            report.skipped_records,
            report.skipped_bytes
        );
    }
    if outcome.report.truncated {
        eprintln!(
            "warning: {} is truncated; its intact beginning was replayed (--allow-truncated)",
            path.display()
        );
    }
    outcome.error
}

pub(crate) fn report_counters(session: &Session) {
    let c = session.counters();
    if c.depth_dropped + c.depth_incomplete + c.color_dropped > 0 || c.iso_errors > 0 {
        eprintln!(
            "stream: {} depth frames, {} dropped (incomplete {}), {} iso packet errors; {} colour frames, {} dropped",
            c.depth_frames,
            c.depth_dropped,
            c.depth_incomplete,
            c.iso_errors,
            c.color_frames,
            c.color_dropped
        );
    }
    if c.depth_overwritten + c.color_overwritten + c.tap_dropped > 0 {
        // Frames nobody took in time (newest wins, issue 45): reported, not an error.
        eprintln!(
            "stream: {} depth and {} colour frames arrived while nothing was reading and were \
             replaced by newer ones{}",
            c.depth_overwritten,
            c.color_overwritten,
            if c.tap_dropped > 0 {
                format!("; the recorder fell behind and lost {} raw packets", c.tap_dropped)
            } else {
                String::new()
            }
        );
    }
}

fn record(
    output: &Path,
    frames: u64,
    overwrite: bool,
    common: &CommonArgs,
    trace: usb_trace::TraceRequest,
) -> Result<()> {
    if output.is_dir() {
        bail!(
            "--out {}: is a folder; a recording is one file: give a file name such as session.kfrec",
            output.display()
        );
    }
    if output.as_os_str().to_string_lossy().ends_with('/') {
        bail!(
            "--out {}: names a folder; a recording is one file: give a file name such as {}session.kfrec",
            output.display(),
            output.display()
        );
    }
    if output.exists() && !overwrite {
        bail!("{} already exists; pass --overwrite to replace it", output.display());
    }
    // The folder of the recording is created, as the other commands create theirs.
    if let Some(parent) = output.parent().filter(|p| !p.as_os_str().is_empty()) {
        if parent.exists() && !parent.is_dir() {
            bail!("--out {}: {} is not a folder", output.display(), parent.display());
        }
        std::fs::create_dir_all(parent).with_context(|| {
            format!("--out {}: creating {}", output.display(), parent.display())
        })?;
    }
    trace.check_path(output)?;
    let handle = trace.create()?;
    let mut session = match start_traced(common, common.source(), handle.as_ref()) {
        Ok(s) => s,
        Err(e) => {
            usb_trace::finish_after_error(handle.as_ref(), &trace);
            return Err(e);
        }
    };
    let bar = ProgressBar::new(frames);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} depth frames")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let stop = crate::interrupt::requested;
    let recorded = kfuse_capture::record::record(&mut session, output, frames, &stop, &mut |n| {
        bar.set_position(n)
    });
    bar.finish_and_clear();
    report_counters(&session);
    session.close();
    let traced = usb_trace::finish(handle.as_ref(), &trace);
    write_sim_report(common, &session)?;
    let recorded = recorded?;
    traced?;
    let got = recorded.frames;
    if let Some(e) = replay_outcome(common, &session) {
        bail!(
            "{e}\nreplay stopped: the {got} depth frames before it were written to {}",
            output.display()
        );
    }
    if !recorded.written {
        let kept = if output.exists() { "was left as it was" } else { "was not written" };
        crate::interrupt::check(&format!(
            ": stopped before the first depth frame; nothing was recorded and {} {kept}",
            output.display()
        ))?;
    }
    if recorded.interrupted {
        crate::interrupt::check(&format!(
            ": the {got} depth frames captured before it were saved in {} (a complete recording \
             that replays without extra flags)",
            output.display()
        ))?;
    }
    match recorded.stopped_by {
        None => {
            eprintln!("recorded {got} depth frames to {}", output.display());
            Ok(())
        }
        Some(e @ KinectError::Disconnected { .. }) => {
            bail!("{}", kfuse_capture::record::unplugged_message(&e, got, output))
        }
        Some(KinectError::EndOfStream) => {
            eprintln!("source recording ended: {got} depth frames written to {}", output.display());
            Ok(())
        }
        Some(e) => Err(e.into()),
    }
}
