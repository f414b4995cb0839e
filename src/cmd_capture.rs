//! `kfuse devices` and `kfuse capture {calib,scene,record}`: thin CLI over `kinect-usb`.

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand, ValueEnum};
use geometry::io::atomic::write_atomic;
use indicatif::{ProgressBar, ProgressStyle};
use kinect_usb::backend::UsbBackend;
use kinect_usb::decoder::DepthDecoder;
use kinect_usb::device::{DeviceInfo, Frame, KinectDevice, StreamKind};
use kinect_usb::raw::{HEIGHT, PIXELS, WIDTH};
use kinect_usb::recording::{RecordingMeta, RecordingWriter, read_recording_file};
use kinect_usb::sim::{SimDevice, SimFaults};
use kinect_usb::{KinectError, usb};
use viewer::capture::{self, ShotKind};

/// How long to wait for one frame before giving up (a live sensor delivers every 33 ms).
const FRAME_TIMEOUT: Duration = Duration::from_secs(3);

/// Which transport to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Backend {
    /// A real Kinect v2 over libusb.
    Usb,
    /// The simulated Kinect v2 (synthetic scene from `geometry::synth`).
    Sim,
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
    /// Decode depth without the bilateral and edge-aware filters (raw per-pixel depth).
    #[arg(long)]
    no_filters: bool,
    #[arg(long, value_enum, default_value_t = Backend::Usb, hide = true)]
    backend: Backend,
    /// Simulated device: disappear after this many frame periods.
    #[arg(long, hide = true)]
    sim_unplug_after: Option<u64>,
    /// Simulated device: report busy.
    #[arg(long, hide = true)]
    sim_busy: bool,
    /// Simulated device: fraction of isochronous packets lost.
    #[arg(long, hide = true, default_value_t = 0.0)]
    sim_iso_drop: f64,
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
    #[command(after_help = "Examples:\n  kfuse capture calib --out calib_shots --count 20            # press Enter for each shot\n  \
        kfuse capture calib --out calib_shots --count 20 --interval 2   # a shot every 2 s\n  \
        kfuse capture calib --replay session.kfrec --out shots --interval 0\n\n\
        Writes color_NNNN.jpg, ir_NNNN.png (16-bit), depth_NNNN.png (16-bit, mm, 0 = invalid)\n\
        and kinect_params.json (factory intrinsics of both cameras). Move the board between shots.")]
    Calib {
        /// Output folder.
        #[arg(long, default_value = "calib_capture")]
        out: PathBuf,
        /// Number of shots.
        #[arg(long, default_value_t = 20)]
        count: usize,
        /// Seconds between automatic shots; without it, each line on stdin (Enter) takes a shot.
        #[arg(long)]
        interval: Option<f64>,
        /// Replace existing files in the output folder.
        #[arg(long)]
        overwrite: bool,
        #[command(flatten)]
        common: CommonArgs,
    },
    /// Save the colour, IR and depth of a scene when you press Enter.
    #[command(after_help = "Examples:\n  kfuse capture scene --out lab --name desk         # press Enter to save\n  \
        kfuse capture scene --out lab --name desk --interval 0   # save immediately\n\n\
        Writes NAME_color.jpg, NAME_ir.png, NAME_depth.png (mm) and kinect_params.json.")]
    Scene {
        /// Output folder.
        #[arg(long, default_value = "scene_capture")]
        out: PathBuf,
        /// File name prefix.
        #[arg(long, default_value = "scene")]
        name: String,
        /// Number of scenes to save (numbered when more than one).
        #[arg(long, default_value_t = 1)]
        count: usize,
        /// Seconds before each automatic save; without it, press Enter.
        #[arg(long)]
        interval: Option<f64>,
        /// Replace existing files.
        #[arg(long)]
        overwrite: bool,
        #[command(flatten)]
        common: CommonArgs,
    },
    /// Record raw USB stream packets and the device metadata for later replay.
    #[command(after_help = "Examples:\n  kfuse capture record --output session.kfrec --frames 300\n  \
        kfuse capture calib --replay session.kfrec --interval 0 --count 5 --out shots\n\n\
        The recording holds every isochronous and bulk packet, so replay runs the same parsers and decoder.")]
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
    if args.backend == Backend::Sim {
        println!("simulated Kinect v2  serial 000000000001  (sim backend)");
        return Ok(());
    }
    let list = usb::list_devices().map_err(not_found_hint)?;
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
        KinectError::NoUsb(_) | KinectError::NotFound => anyhow::anyhow!("{}\n{}", e, KinectError::NotFound),
        KinectError::Busy => anyhow::anyhow!("{e}"),
        e => anyhow::Error::new(e),
    }
}

/// Runs `kfuse capture …`.
pub fn run_capture(args: CaptureArgs) -> Result<()> {
    match args.mode {
        CaptureMode::Calib { out, count, interval, overwrite, common } => {
            let names = (1..=count).map(|i| format!("{i:04}")).collect::<Vec<_>>();
            shots(&out, &names, "", interval, overwrite, &common)
        }
        CaptureMode::Scene { out, name, count, interval, overwrite, common } => {
            let names: Vec<String> =
                if count == 1 { vec![name.clone()] } else { (1..=count).map(|i| format!("{name}_{i:04}")).collect() };
            shots(&out, &names, "scene", interval, overwrite, &common)
        }
        CaptureMode::Record { output, frames, overwrite, common } => record(&output, frames, overwrite, &common),
    }
}

type Device = KinectDevice<Box<dyn UsbBackend>>;

fn open(common: &CommonArgs) -> Result<Device> {
    let backend: Box<dyn UsbBackend> = if let Some(path) = &common.replay {
        let rec = read_recording_file(path, common.allow_truncated)?;
        if !rec.complete {
            eprintln!("warning: {} is truncated; replaying its {} intact packets", path.display(), rec.events.len());
        }
        Box::new(SimDevice::replay(rec)?)
    } else {
        match common.backend {
            Backend::Sim => Box::new(sim_device(common)),
            Backend::Usb => Box::new(usb::open_first().map_err(not_found_hint)?),
        }
    };
    KinectDevice::open(backend).map_err(|e| match e {
        KinectError::Busy => anyhow::anyhow!("{e}\nhint: run `kfuse devices` to see which sensors are free"),
        e => not_found_hint(e),
    })
}

/// The simulated device used by `--backend sim`: `geometry::synth`'s Kinect preset scene.
pub fn sim_device(common: &CommonArgs) -> SimDevice {
    let (scene, profile) = capture::sim_scene();
    let faults = SimFaults {
        seed: 1,
        busy: common.sim_busy,
        iso_drop_rate: common.sim_iso_drop,
        unplug_after_frames: common.sim_unplug_after,
        ..SimFaults::default()
    };
    SimDevice::new(profile, scene, faults)
}

fn decoder_for(info: &DeviceInfo, no_filters: bool) -> Result<DepthDecoder> {
    Ok(capture::decoder_for(info, no_filters)?)
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
            Some(s) => Trigger::Interval(Duration::from_secs_f64(s.max(0.0))),
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
fn fresh_pair(dev: &mut Device, dec: &mut DepthDecoder, latest: &mut Latest, since: Instant) -> kinect_usb::Result<()> {
    let deadline = Instant::now() + FRAME_TIMEOUT;
    loop {
        let fresh = |t: Option<Instant>| t.is_some_and(|t| t >= since);
        if fresh(latest.depth_at) && fresh(latest.color_at) {
            return Ok(());
        }
        if Instant::now() > deadline {
            return Err(KinectError::Protocol { what: "capture".into(), detail: format!("no complete frame pair within {FRAME_TIMEOUT:?}") });
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

fn shots(out: &Path, names: &[String], kind: &str, interval: Option<f64>, overwrite: bool, common: &CommonArgs) -> Result<()> {
    let kind = if kind == "scene" { ShotKind::Scene } else { ShotKind::Calib };
    let files = |n: &str| capture::shot_files(out, n, kind);
    if !overwrite {
        if let Some(p) = names.iter().flat_map(|n| files(n)).find(|p| p.exists()) {
            bail!("{} already exists; pass --overwrite to replace, or choose another --out", p.display());
        }
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mut dev = open(common)?;
    let info = dev.start(true, true)?.clone();
    write_params_json(out, &info)?;
    let mut dec = decoder_for(&info, common.no_filters)?;
    let trigger = Trigger::new(interval);
    if matches!(trigger, Trigger::Lines(_)) {
        eprintln!("Press Enter to take each of {} shots (Ctrl-D to stop early).", names.len());
    }
    let bar = ProgressBar::new(names.len() as u64);
    bar.set_style(ProgressStyle::with_template("{bar:30} {pos}/{len} shots {msg}").unwrap_or_else(|_| ProgressStyle::default_bar()));
    let mut latest = Latest { depth: vec![0.0; PIXELS], ir: vec![0.0; PIXELS], color: Vec::new(), depth_at: None, color_at: None };
    let mut saved = 0usize;
    let mut outcome: Result<()> = Ok(());
    for n in names {
        match &trigger {
            Trigger::Interval(d) => {
                // Keep draining the stream while waiting so the shot is current.
                let until = Instant::now() + *d;
                while Instant::now() < until {
                    if let Err(e) = dev.next_frame(Duration::from_millis(50), &mut |_, _| {}) {
                        outcome = Err(e.into());
                        break;
                    }
                }
            }
            Trigger::Lines(rx) => {
                if rx.recv().is_err() {
                    eprintln!("stdin closed: stopping after {saved} shots");
                    break;
                }
            }
        }
        if outcome.is_err() {
            break;
        }
        if let Err(e) = fresh_pair(&mut dev, &mut dec, &mut latest, Instant::now()) {
            outcome = Err(e.into());
            break;
        }
        let [c, i, d] = files(n);
        write_atomic(&c, |w| w.write_all(&latest.color))?;
        write_png16(&i, &latest.ir, WIDTH, HEIGHT)?;
        write_png16(&d, &latest.depth, WIDTH, HEIGHT)?;
        saved += 1;
        bar.inc(1);
    }
    bar.finish_and_clear();
    report_counters(&dev);
    let _ = dev.close();
    match outcome {
        Ok(()) => {
            eprintln!("saved {saved} shot(s) in {}", out.display());
            Ok(())
        }
        Err(e) => {
            let disconnected = matches!(e.downcast_ref::<KinectError>(), Some(KinectError::Disconnected { .. }));
            if disconnected {
                bail!("{e}\ncapture stopped: {saved} complete shot(s) were saved in {} and are intact; reconnect the sensor (USB 3 port, power) and run again", out.display());
            }
            if matches!(e.downcast_ref::<KinectError>(), Some(KinectError::EndOfStream)) {
                bail!("the recording ended after {saved} shot(s) (saved in {})", out.display());
            }
            Err(e)
        }
    }
}

fn report_counters(dev: &Device) {
    let c = dev.counters();
    if c.depth_dropped + c.depth_incomplete + c.color_dropped > 0 || c.iso_errors > 0 {
        eprintln!(
            "stream: {} depth frames, {} dropped (incomplete {}), {} iso packet errors; {} colour frames, {} dropped",
            c.depth_frames, c.depth_dropped, c.depth_incomplete, c.iso_errors, c.color_frames, c.color_dropped
        );
    }
}

fn record(output: &Path, frames: u64, overwrite: bool, common: &CommonArgs) -> Result<()> {
    if output.exists() && !overwrite {
        bail!("{} already exists; pass --overwrite to replace it", output.display());
    }
    let mut dev = open(common)?;
    let info = dev.start(true, true)?.clone();
    let meta = RecordingMeta::from_info(&info);
    let bar = ProgressBar::new(frames);
    bar.set_style(ProgressStyle::with_template("{bar:30} {pos}/{len} depth frames").unwrap_or_else(|_| ProgressStyle::default_bar()));
    let mut stop: Option<KinectError> = None;
    let mut got = 0u64;
    write_atomic(output, |w| {
        let mut rw = RecordingWriter::new(w, &meta)?;
        let mut io_err = None;
        while got < frames {
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
    match stop {
        None => {
            eprintln!("recorded {got} depth frames to {}", output.display());
            Ok(())
        }
        Some(e @ KinectError::Disconnected { .. }) => {
            bail!("{e}\nrecording stopped: {got} complete depth frames were saved in {} (a valid, replayable file)", output.display())
        }
        Some(KinectError::EndOfStream) => {
            eprintln!("source recording ended: {got} depth frames written to {}", output.display());
            Ok(())
        }
        Some(e) => Err(e.into()),
    }
}
