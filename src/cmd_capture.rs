//! `kfuse devices` and `kfuse capture {calib,scene,record}`: thin CLI over `kinect-usb`.

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, mpsc};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use kfuse_io::atomic::write_atomic;
use kinect_usb::backend::UsbBackend;
use kinect_usb::decoder::{DecoderPrecision, DepthDecoder, Kernels};
use kinect_usb::device::{DeviceInfo, Frame, KinectDevice, StreamKind};
use kinect_usb::protocol::{self, Exposure, ExposureMode, LedMode, LedSetting};
use kinect_usb::raw::{HEIGHT, PIXELS, WIDTH};
use kinect_usb::recording::{ReadOptions, RecordingMeta, RecordingReader, RecordingWriter};
use kinect_usb::sim::{SimDevice, SimFaults};
use kinect_usb::{KinectError, usb};
use viewer::capture::{self, ShotKind};

/// How long to wait for one frame before giving up (a live sensor delivers every 33 ms).
const FRAME_TIMEOUT: Duration = Duration::from_secs(3);

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

/// Which transport to use.
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

/// `kfuse devices`.
#[derive(Args, Debug)]
#[command(after_help = "Examples:\n  kfuse devices\n\nExits non-zero when no Kinect v2 is found.")]
pub struct DevicesArgs {
    #[arg(long, value_enum, default_value_t = Backend::Usb, hide = true)]
    backend: Backend,
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
    /// checkerboard of 40 mm squares in 12 tilted poses at 0.6–1.5 m (one pose per frame:
    /// `--count 12 --interval 0` takes each once; `kfuse calibrate` then recovers the factory
    /// parameters), `capture scene` the synthetic Kinect preset (objects before a wall).
    #[arg(long, value_enum, default_value_t = Backend::Usb)]
    backend: Backend,
    /// Set by `capture calib`: the simulated sensor shows its calibration scene.
    #[arg(skip)]
    sim_calib_scene: bool,
    /// Simulated device: disappear after this many frame periods.
    #[arg(long, hide = true)]
    sim_unplug_after: Option<u64>,
    /// Simulated device: report busy.
    #[arg(long, hide = true)]
    sim_busy: bool,
    /// Simulated device: fraction of isochronous packets lost, 0..1.
    #[arg(long, hide = true, default_value_t = 0.0, value_parser = parse_fraction)]
    sim_iso_drop: f64,
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
    led: Option<LedArg>,
    /// Which LED `--led` drives (the sensor has LEDs 0 and 1).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u16).range(0..2), requires = "led")]
    led_id: u16,
}

/// `--led` value before the LED id is known.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LedArg {
    /// Off.
    Off,
    /// Constant at a level 0..=1000.
    On(u16),
    /// Blinking with an interval in ms.
    Blink(u32),
}

impl LedArg {
    fn setting(self, id: u16) -> LedSetting {
        match self {
            LedArg::Off => LedSetting::off(id),
            LedArg::On(level) => LedSetting::on(id, level),
            LedArg::Blink(ms) => LedSetting::blink(id, ms),
        }
    }
}

fn parse_f32(s: &str, what: &str) -> std::result::Result<f32, String> {
    s.trim().parse::<f32>().map_err(|_| format!("{what} `{s}` is not a number"))
}

/// Parses `--exposure`: `auto`, `auto:COMP`, `semi:MS`, `manual:MS,GAIN`; values are checked
/// against the ranges of `kinect_usb::protocol`.
pub fn parse_exposure(s: &str) -> std::result::Result<Exposure, String> {
    const FORMS: &str = "expected auto, auto:COMP, semi:MS or manual:MS,GAIN (e.g. manual:20,2)";
    let (mode, rest) = match s.split_once(':') {
        Some((m, r)) => (m, Some(r)),
        None => (s, None),
    };
    let e = match (mode.trim().to_ascii_lowercase().as_str(), rest) {
        ("auto", None) => Exposure::Auto { compensation: 0.0 },
        ("auto", Some(c)) => Exposure::Auto { compensation: parse_f32(c, "compensation")? },
        ("semi" | "semi-auto", Some(ms)) => {
            Exposure::SemiAuto { exposure_ms: parse_f32(ms, "exposure time")? }
        }
        ("manual", Some(r)) => {
            let (ms, gain) =
                r.split_once(',').ok_or_else(|| format!("manual needs MS,GAIN; {FORMS}"))?;
            Exposure::Manual {
                integration_ms: parse_f32(ms, "integration time")?,
                analog_gain: parse_f32(gain, "analog gain")?,
            }
        }
        _ => return Err(format!("`{s}`: {FORMS}")),
    };
    e.validate().map_err(|err| err.to_string())?;
    Ok(e)
}

/// Longest `--interval`: one day. Longer waits are certainly a typo (and `inf` or 1e30 would
/// overflow the `Duration` of the wait).
pub const MAX_INTERVAL_S: f64 = 86_400.0;

/// Parses `--interval`: a finite number of seconds in `[0, MAX_INTERVAL_S]`.
pub fn parse_interval(s: &str) -> std::result::Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("`{s}` is not a number of seconds"))?;
    if !(0.0..=MAX_INTERVAL_S).contains(&v) {
        return Err(format!("{v} s is outside [0, {MAX_INTERVAL_S}] seconds"));
    }
    Ok(v)
}

/// Parses a fraction in `[0, 1]` (`--sim-iso-drop`).
pub fn parse_fraction(s: &str) -> std::result::Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("`{s}` is not a number"))?;
    if !(0.0..=1.0).contains(&v) {
        return Err(format!("{v} is outside [0, 1]"));
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

/// Parses `--led`: `off`, `on`, `on:LEVEL`, `blink:MS`.
pub fn parse_led(s: &str) -> std::result::Result<LedArg, String> {
    const FORMS: &str = "expected off, on, on:LEVEL (0..1000) or blink:MS";
    let (mode, rest) = match s.split_once(':') {
        Some((m, r)) => (m, Some(r.trim())),
        None => (s, None),
    };
    let arg =
        match (mode.trim().to_ascii_lowercase().as_str(), rest) {
            ("off", None) => LedArg::Off,
            ("on", None) => LedArg::On(protocol::LED_MAX_LEVEL),
            ("on", Some(l)) => LedArg::On(
                l.parse().map_err(|_| format!("LED level `{l}` is not a whole number; {FORMS}"))?,
            ),
            ("blink", Some(ms)) => LedArg::Blink(ms.parse().map_err(|_| {
                format!("blink interval `{ms}` is not a whole number of ms; {FORMS}")
            })?),
            _ => return Err(format!("`{s}`: {FORMS}")),
        };
    arg.setting(0).validate().map_err(|e| e.to_string())?;
    Ok(arg)
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
        /// Number of shots.
        #[arg(long, default_value_t = 20)]
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
        /// Number of scenes to save (numbered when more than one).
        #[arg(long, default_value_t = 1)]
        count: usize,
        /// Seconds before each automatic save (0..86400); without it, press Enter.
        #[arg(long, value_parser = parse_interval)]
        interval: Option<f64>,
        /// Replace existing files.
        #[arg(long)]
        overwrite: bool,
        #[command(flatten)]
        common: CommonArgs,
    },
    /// Record raw USB stream packets and the device metadata for later replay.
    #[command(after_help = concat!("Examples:\n  kfuse capture record --output session.kfrec --frames 300\n  \
        kfuse capture calib --replay session.kfrec --interval 0 --count 5 --out shots\n\n\
        The recording holds every isochronous and bulk packet, so replay runs the same parsers and decoder.", settings_help!()))]
    Record {
        /// Recording file.
        #[arg(long, default_value = "capture.kfrec")]
        output: PathBuf,
        /// Depth frames to record.
        #[arg(long, default_value_t = 150)]
        frames: u64,
        /// Replace an existing file.
        #[arg(long)]
        overwrite: bool,
        #[command(flatten)]
        common: CommonArgs,
    },
}

/// Runs `kfuse devices`.
pub fn run_devices(args: DevicesArgs) -> Result<()> {
    let list = match args.backend {
        Backend::Usb => usb::list_devices().map_err(not_found_hint)?,
        Backend::Sim => {
            println!("simulated Kinect v2  serial 000000000001  (sim backend)");
            return Ok(());
        }
        Backend::Absent => Vec::new(),
    };
    if list.is_empty() {
        return Err(not_found_hint(KinectError::NotFound));
    }
    for d in &list {
        println!(
            "Kinect v2  bus {:03} address {:03}  pid {:04x}  serial {}",
            d.bus,
            d.address,
            d.product_id,
            d.serial.as_deref().unwrap_or("(unreadable: device busy or no permission)")
        );
    }
    Ok(())
}

fn not_found_hint(e: KinectError) -> anyhow::Error {
    match e {
        KinectError::NoUsb(_) | KinectError::NotFound => {
            anyhow::anyhow!("{}\n{}", e, KinectError::NotFound)
        }
        KinectError::Busy => anyhow::anyhow!("{e}"),
        e => anyhow::Error::new(e),
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
            let common = CommonArgs { sim_calib_scene: true, ..common };
            let names = (1..=count).map(|i| format!("{i:04}")).collect::<Vec<_>>();
            shots(&out, &names, "", interval, overwrite, &common)
        }
        CaptureMode::Scene { out, name, count, interval, overwrite, common } => {
            let names: Vec<String> = if count == 1 {
                vec![name.clone()]
            } else {
                (1..=count).map(|i| format!("{name}_{i:04}")).collect()
            };
            shots(&out, &names, "scene", interval, overwrite, &common)
        }
        CaptureMode::Record { output, frames, overwrite, common } => {
            record(&output, frames, overwrite, &common)
        }
    }
}

type Device = KinectDevice<Box<dyn UsbBackend>>;
type SimHandle = Arc<Mutex<SimDevice>>;

fn open(common: &CommonArgs) -> Result<(Device, Option<SimHandle>)> {
    let mut sim = None;
    let backend: Box<dyn UsbBackend> = if let Some(path) = &common.replay {
        // Streamed: the reader holds one record at a time, whatever the file's size.
        let opts =
            ReadOptions { keep_prefix: common.allow_truncated, skip_corrupt: common.skip_corrupt };
        let reader = RecordingReader::open(path, opts)?;
        let meta = reader.meta().clone();
        let h = Arc::new(Mutex::new(SimDevice::replay_from(&meta, Box::new(reader))?));
        sim = Some(h.clone());
        Box::new(h)
    } else {
        match common.backend {
            Backend::Sim => {
                let h = Arc::new(Mutex::new(sim_device(common)?));
                sim = Some(h.clone());
                Box::new(h)
            }
            Backend::Usb => Box::new(usb::open_first().map_err(not_found_hint)?),
            Backend::Absent => return Err(not_found_hint(KinectError::NotFound)),
        }
    };
    let dev = KinectDevice::open(backend).map_err(|e| match e {
        KinectError::Busy => {
            anyhow::anyhow!("{e}\nhint: run `kfuse devices` to see which sensors are free")
        }
        e => not_found_hint(e),
    })?;
    Ok((dev, sim))
}

fn exposure_text(e: &Exposure) -> String {
    match *e {
        Exposure::Auto { compensation } => format!("auto:{compensation}"),
        Exposure::SemiAuto { exposure_ms } => format!("semi:{exposure_ms}"),
        Exposure::Manual { integration_ms, analog_gain } => {
            format!("manual:{integration_ms},{analog_gain}")
        }
    }
}

/// Applies `--exposure` and `--led` on a started device and reports what the sensor reads
/// back. A refused setting is an error (the user asked for it); a failed read-back only warns.
fn apply_settings(dev: &mut Device, common: &CommonArgs) -> Result<()> {
    if let Some(e) = &common.exposure {
        dev.set_exposure(*e)
            .with_context(|| format!("applying --exposure {}", exposure_text(e)))?;
        let readback = (|| -> kinect_usb::Result<String> {
            Ok(match dev.exposure_mode()? {
                ExposureMode::Manual => {
                    format!(
                        "manual, integration time {} ms, analog gain {}",
                        dev.integration_time_ms()?,
                        dev.analog_gain()?
                    )
                }
                ExposureMode::SemiAuto => {
                    format!("semi-auto, exposure time {} ms", dev.exposure_time_ms()?)
                }
                ExposureMode::Auto => {
                    format!("auto, compensation {}", dev.exposure_compensation()?)
                }
                ExposureMode::Other(v) => format!("mode {v}"),
            })
        })();
        match readback {
            Ok(t) => eprintln!("colour exposure: {t} (read back from the sensor)"),
            Err(err) => {
                eprintln!("warning: --exposure was applied but reading it back failed: {err}")
            }
        }
    }
    if let Some(l) = common.led {
        let setting = l.setting(common.led_id);
        dev.set_led(setting).with_context(|| format!("applying --led (LED {})", common.led_id))?;
        let what = match setting.mode {
            LedMode::Constant if setting.start_level == 0 => "off".to_string(),
            LedMode::Constant => {
                format!("on at level {}/{}", setting.start_level, protocol::LED_MAX_LEVEL)
            }
            LedMode::Blink => format!("blinking every {} ms", setting.interval_ms),
        };
        eprintln!("LED {}: {what}", common.led_id);
    }
    Ok(())
}

/// Writes `--sim-report`: the simulated device's colour settings, LEDs and protocol violations.
fn write_sim_report(common: &CommonArgs, sim: &Option<SimHandle>) -> Result<()> {
    let (Some(path), Some(sim)) = (&common.sim_report, sim) else { return Ok(()) };
    let s = sim.lock().unwrap_or_else(|p| p.into_inner());
    use kinect_usb::protocol::ColorSettingCode as C;
    let c = s.color_settings();
    let led = |l: &LedSetting| {
        serde_json::json!({ "id": l.id, "blink": l.mode == LedMode::Blink, "start_level": l.start_level,
                            "stop_level": l.stop_level, "interval_ms": l.interval_ms })
    };
    let v = serde_json::json!({
        "exposure_mode": c.get(C::SetExposureMode),
        "integration_time_ms": c.get_f32(C::SetIntegrationTime),
        "analog_gain": c.get_f32(C::SetAnalogGain),
        "exposure_time_ms": c.get_f32(C::SetExposureTime),
        "exposure_compensation": c.get_f32(C::SetExposureCompensation),
        "led_api": s.led_api_log().iter().map(led).collect::<Vec<_>>(),
        "violations": s.violations,
        "commands": s.transcript.iter().filter(|l| l.starts_with("cmd")).collect::<Vec<_>>(),
    });
    write_atomic(path, |w| {
        serde_json::to_writer_pretty(&mut *w, &v)?;
        w.write_all(b"\n")
    })?;
    Ok(())
}

/// The simulated device used by `--backend sim`: `geometry::synth`'s Kinect preset scene, or
/// for `capture calib` the checkerboard of `kinect_usb::sim::calib_scene`.
pub fn sim_device(common: &CommonArgs) -> Result<SimDevice> {
    let (mut scene, profile) = capture::sim_scene();
    if common.sim_calib_scene {
        scene = kinect_usb::sim::calib_scene::calibration_scene(&profile)
            .context("the simulated sensor's colour parameters are not a pinhole camera")?;
    }
    let faults = SimFaults {
        seed: 1,
        busy: common.sim_busy,
        iso_drop_rate: common.sim_iso_drop,
        unplug_after_frames: common.sim_unplug_after,
        ..SimFaults::default()
    };
    Ok(SimDevice::new(profile, scene, faults))
}

fn decoder_for(info: &DeviceInfo, no_filters: bool, exact: bool) -> Result<DepthDecoder> {
    let precision = if exact { DecoderPrecision::Exact } else { DecoderPrecision::Fast };
    let dec = capture::decoder_for(info, no_filters)?.with_precision(precision);
    let what = match (precision, dec.kernels()) {
        (DecoderPrecision::Exact, _) => "exact (bit-identical to libfreenect2's CPU decoder)",
        (DecoderPrecision::Fast, Kernels::Avx2) => "fast (eight-lane AVX2 kernels)",
        (DecoderPrecision::Fast, Kernels::Portable) => {
            "fast (four-lane kernels: this CPU has no AVX2)"
        }
    };
    eprintln!("depth decoder: {what}");
    Ok(dec)
}

fn write_params_json(out: &Path, info: &DeviceInfo) -> Result<()> {
    Ok(capture::write_params_json(out, info)?)
}

fn write_png16(path: &Path, values: &[f32], width: usize, height: usize) -> Result<()> {
    Ok(capture::write_png16(path, values, width, height)?)
}

/// Waits for the trigger of the next shot: `interval` seconds, or one line on stdin.
enum Trigger {
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

struct Latest {
    depth: Vec<f32>,
    ir: Vec<f32>,
    color: Vec<u8>,
    depth_at: Option<Instant>,
    color_at: Option<Instant>,
}

/// Pulls frames until both a depth and a colour frame newer than `since` are in `latest`.
fn fresh_pair(
    dev: &mut Device,
    dec: &mut DepthDecoder,
    latest: &mut Latest,
    since: Instant,
) -> kinect_usb::Result<()> {
    let deadline = Instant::now() + FRAME_TIMEOUT;
    loop {
        let fresh = |t: Option<Instant>| t.is_some_and(|t| t >= since);
        if fresh(latest.depth_at) && fresh(latest.color_at) {
            return Ok(());
        }
        if Instant::now() > deadline {
            return Err(KinectError::Protocol {
                what: "capture".into(),
                detail: format!("no complete frame pair within {FRAME_TIMEOUT:?}"),
            });
        }
        match dev.next_frame(FRAME_TIMEOUT, &mut |_, _| {})? {
            Some(Frame::Depth(f)) => {
                dec.decode(f.data, &mut latest.depth, &mut latest.ir)?;
                latest.depth_at = Some(Instant::now());
            }
            Some(Frame::Color(j, _)) => {
                latest.color.clear();
                latest.color.extend_from_slice(j);
                latest.color_at = Some(Instant::now());
            }
            None => {}
        }
    }
}

/// Name prefix of the folder inside `--out` where a shot's files are written before they are
/// moved into place together (same filesystem, so each move is a rename).
const STAGING_PREFIX: &str = ".kfuse-shot-staging-";

/// Writes one shot's colour, IR and depth into `stage`, then moves all three to `files`: a
/// failed write leaves none of them in `--out`, and a signal (which only sets a flag, checked
/// between shots) cannot separate them.
fn write_shot(stage: &Path, files: &[PathBuf; 3], latest: &Latest) -> Result<()> {
    std::fs::create_dir_all(stage).with_context(|| format!("creating {}", stage.display()))?;
    let staged = files.clone().map(|f| stage.join(f.file_name().unwrap_or_default()));
    write_atomic(&staged[0], |w| w.write_all(&latest.color))?;
    write_png16(&staged[1], &latest.ir, WIDTH, HEIGHT)?;
    write_png16(&staged[2], &latest.depth, WIDTH, HEIGHT)?;
    for (from, to) in staged.iter().zip(files) {
        std::fs::rename(from, to)
            .with_context(|| format!("moving {} to {}", from.display(), to.display()))?;
    }
    Ok(())
}

/// Removes staging folders left in `out` by killed captures (their process no longer runs).
fn remove_stale_staging(out: &Path) {
    let Ok(entries) = std::fs::read_dir(out) else { return };
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(pid) = name.to_str().and_then(|n| n.strip_prefix(STAGING_PREFIX)) else {
            continue;
        };
        let alive = pid.parse::<u32>().is_ok_and(|p| Path::new(&format!("/proc/{p}")).exists());
        if !alive && e.path().is_dir() {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

fn shots(
    out: &Path,
    names: &[String],
    kind: &str,
    interval: Option<f64>,
    overwrite: bool,
    common: &CommonArgs,
) -> Result<()> {
    let kind = if kind == "scene" { ShotKind::Scene } else { ShotKind::Calib };
    let files = |n: &str| capture::shot_files(out, n, kind);
    if !overwrite && let Some(p) = names.iter().flat_map(|n| files(n)).find(|p| p.exists()) {
        bail!(
            "{} already exists; pass --overwrite to replace, or choose another --out",
            p.display()
        );
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    remove_stale_staging(out);
    let stage = out.join(format!("{STAGING_PREFIX}{}", std::process::id()));
    let (mut dev, sim) = open(common)?;
    let info = dev.start(true, true)?.clone();
    if let Err(e) = apply_settings(&mut dev, common) {
        let _ = dev.close();
        write_sim_report(common, &sim)?;
        return Err(e);
    }
    write_params_json(out, &info)?;
    let mut dec = decoder_for(&info, common.no_filters, common.exact_decoder)?;
    let trigger = Trigger::new(interval);
    if matches!(trigger, Trigger::Lines(_)) {
        eprintln!("Press Enter to take each of {} shots (Ctrl-D to stop early).", names.len());
    }
    let bar = ProgressBar::new(names.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} shots {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut latest = Latest {
        depth: vec![0.0; PIXELS],
        ir: vec![0.0; PIXELS],
        color: Vec::new(),
        depth_at: None,
        color_at: None,
    };
    let mut saved = 0usize;
    let mut outcome: Result<()> = Ok(());
    let mut interrupted = false;
    'shots: for n in names {
        match &trigger {
            Trigger::Interval(d) => {
                // Keep draining the stream while waiting so the shot is current.
                let until = Instant::now() + *d;
                while Instant::now() < until && !crate::interrupt::requested() {
                    if let Err(e) = dev.next_frame(Duration::from_millis(50), &mut |_, _| {}) {
                        outcome = Err(e.into());
                        break;
                    }
                }
            }
            Trigger::Lines(rx) => loop {
                match rx.recv_timeout(Duration::from_millis(100)) {
                    Ok(()) => break,
                    Err(mpsc::RecvTimeoutError::Timeout) if !crate::interrupt::requested() => {}
                    Err(mpsc::RecvTimeoutError::Timeout) => break,
                    Err(mpsc::RecvTimeoutError::Disconnected) => {
                        eprintln!("stdin closed: stopping after {saved} shots");
                        break 'shots;
                    }
                }
            },
        }
        if crate::interrupt::requested() {
            interrupted = true;
            break;
        }
        if outcome.is_err() {
            break;
        }
        if let Err(e) = fresh_pair(&mut dev, &mut dec, &mut latest, Instant::now()) {
            outcome = Err(e.into());
            break;
        }
        if let Err(e) = write_shot(&stage, &files(n), &latest) {
            let _ = std::fs::remove_dir_all(&stage);
            return Err(e);
        }
        saved += 1;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let _ = std::fs::remove_dir_all(&stage);
    report_counters(&dev);
    let _ = dev.close();
    write_sim_report(common, &sim)?;
    if let Some(e) = replay_outcome(common, &sim) {
        bail!(
            "{e}\nreplay stopped: {saved} shot(s) taken before it are intact in {}",
            out.display()
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
        Err(e) => {
            let disconnected =
                matches!(e.downcast_ref::<KinectError>(), Some(KinectError::Disconnected { .. }));
            if disconnected {
                bail!(
                    "{e}\ncapture stopped: {saved} complete shot(s) were saved in {} and are intact; reconnect the sensor (USB 3 port, power) and run again",
                    out.display()
                );
            }
            if matches!(e.downcast_ref::<KinectError>(), Some(KinectError::EndOfStream)) {
                bail!("the recording ended after {saved} shot(s) (saved in {})", out.display());
            }
            Err(e)
        }
    }
}

/// After a replay: reports skipped records and a kept truncated prefix, and returns the error
/// that ended the replay early (a corrupt record), which must fail the command.
fn replay_outcome(common: &CommonArgs, sim: &Option<SimHandle>) -> Option<KinectError> {
    let (Some(path), Some(sim)) = (&common.replay, sim) else { return None };
    let mut s = sim.lock().unwrap_or_else(|p| p.into_inner());
    let report = s.replay_report();
    for (index, offset) in &report.skipped {
        eprintln!(
            "warning: {}: record {index} at byte {offset} is corrupt (checksum mismatch) and was left out",
            path.display()
        );
    }
    if report.truncated {
        eprintln!(
            "warning: {} is truncated; its intact beginning was replayed (--allow-truncated)",
            path.display()
        );
    }
    s.take_replay_error()
}

fn report_counters(dev: &Device) {
    let c = dev.counters();
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
}

fn record(output: &Path, frames: u64, overwrite: bool, common: &CommonArgs) -> Result<()> {
    if output.exists() && !overwrite {
        bail!("{} already exists; pass --overwrite to replace it", output.display());
    }
    let (mut dev, sim) = open(common)?;
    let info = dev.start(true, true)?.clone();
    if let Err(e) = apply_settings(&mut dev, common) {
        let _ = dev.close();
        write_sim_report(common, &sim)?;
        return Err(e);
    }
    let meta = RecordingMeta::from_info(&info);
    let bar = ProgressBar::new(frames);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} depth frames")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut stop: Option<KinectError> = None;
    let (mut got, mut interrupted) = (0u64, false);
    write_atomic(output, |w| {
        let mut rw = RecordingWriter::new(w, &meta)?;
        let mut io_err = None;
        while got < frames {
            if crate::interrupt::requested() {
                interrupted = true;
                break;
            }
            let mut tap = |k: StreamKind, e: &_| {
                if let Err(err) = rw.write_event(k, e) {
                    io_err.get_or_insert(err);
                }
            };
            match dev.next_frame(FRAME_TIMEOUT, &mut tap) {
                Ok(Some(Frame::Depth(_))) => {
                    got += 1;
                    bar.inc(1);
                }
                Ok(_) => {}
                Err(e) => {
                    stop = Some(e);
                    break;
                }
            }
            if let Some(e) = io_err.take() {
                return Err(e);
            }
        }
        rw.finish().map(|_| ())
    })?;
    bar.finish_and_clear();
    report_counters(&dev);
    let _ = dev.close();
    write_sim_report(common, &sim)?;
    if let Some(e) = replay_outcome(common, &sim) {
        bail!(
            "{e}\nreplay stopped: the {got} depth frames before it were written to {}",
            output.display()
        );
    }
    if interrupted {
        crate::interrupt::check(&format!(
            ": the {got} depth frames captured before it were saved in {} (a complete recording \
             that replays without extra flags)",
            output.display()
        ))?;
    }
    match stop {
        None => {
            eprintln!("recorded {got} depth frames to {}", output.display());
            Ok(())
        }
        Some(e @ KinectError::Disconnected { .. }) => {
            bail!(
                "{e}\nrecording stopped: {got} complete depth frames were saved in {} (a valid, replayable file)",
                output.display()
            )
        }
        Some(KinectError::EndOfStream) => {
            eprintln!("source recording ended: {got} depth frames written to {}", output.display());
            Ok(())
        }
        Some(e) => Err(e.into()),
    }
}
