//! `kfuse serve`: one sensor on its own PC, published over Zenoh (`kfuse_live`). The sensor is
//! opened as `kfuse capture` opens it (`--backend usb|sim`, `--device SERIAL`, the simulated
//! ring's `--sim-sensors N`), its depth decoded here, and every frame published as it arrives:
//! depth (16UC1 mm) and IR as `sensor_msgs/Image`, the sensor's JPEG (mirrored into the scene
//! orientation without loss, the bytes `kfuse capture` writes) as `sensor_msgs/CompressedImage`,
//! both cameras' `CameraInfo` per depth frame, `/tf_static` at start and every second, and
//! kfuse's status (the sensor's timestamps, the frames not published). Newest wins: the device
//! keeps one frame per stream, so a publisher that falls behind loses frames (counted in the
//! status), and Zenoh drops what the network cannot take; nothing queues.
//!
//! The network side lives in `kfuse_live`; here: the flags, the sensor loop, the messages.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use geometry::Rig;
use kfuse_capture::{FramePump, Pumped, SensorSource};
use kfuse_live::publish::{SensorPublisher, compressed_jpeg, header, image_16uc1, unix_now_ns};
use kfuse_live::status::{STATUS_FORMAT, STATUS_VERSION, Status};
use kfuse_live::{Endpoints, LiveTopic};
use kfuse_ros_msgs::names::optical_frames;
use kfuse_ros_msgs::{CameraInfo, Quaternion, Transform, TransformStamped, Vector3};

use zenoh::Wait;

use crate::cmd_capture::CommonArgs;

/// How often `/tf_static` is published again (module docs of `kfuse_live`: late ROS
/// subscribers do not query).
pub const TF_STATIC_PERIOD: Duration = Duration::from_secs(1);

/// Longest wait for a frame before `serve` gives up on the sensor: 5 s (a sensor delivers every
/// 33 ms; `kfuse_capture::pump::FRAME_TIMEOUT` is 3 s for a first pair).
pub const SENSOR_SILENCE: Duration = Duration::from_secs(5);

/// The network flags of `kfuse serve` and `kfuse fuse --live`.
#[derive(Args, Debug, Clone, Default)]
pub struct NetArgs {
    /// A Zenoh endpoint to listen on, e.g. `tcp/0.0.0.0:7447` (repeat for several). Without
    /// it, a free TCP port on every interface (found by multicast scouting).
    #[arg(long, value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// A Zenoh endpoint of another kfuse (or a Zenoh router) to connect to, e.g.
    /// `tcp/192.168.1.20:7447` (repeat for several).
    #[arg(long, value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// Do not look for peers by UDP multicast (Zenoh's scouting on the LAN): only --connect.
    #[arg(long)]
    pub no_multicast: bool,
    /// The ROS 2 domain of the topics (the first chunk of every key; default: ROS_DOMAIN_ID,
    /// else 0).
    #[arg(long, value_name = "ID", value_parser = kfuse_live::keys::parse_domain)]
    pub domain_id: Option<u32>,
}

impl NetArgs {
    /// The session's endpoints.
    pub fn endpoints(&self) -> Endpoints {
        Endpoints {
            listen: self.listen.clone(),
            connect: self.connect.clone(),
            multicast: !self.no_multicast,
        }
    }

    /// `--domain-id`, else `ROS_DOMAIN_ID`, else 0.
    pub fn domain(&self) -> Result<u32> {
        match self.domain_id {
            Some(d) => Ok(d),
            None => kfuse_live::keys::domain_from_env().map_err(anyhow::Error::msg),
        }
    }
}

/// `kfuse serve`.
#[derive(Args, Debug)]
#[command(after_help = "\
Examples:
  kfuse serve --backend usb --listen tcp/0.0.0.0:7447 --rig rig.json      # on each sensor's PC
  kfuse serve --backend sim --sim-sensors 3 --device 000000000002 --listen tcp/127.0.0.1:17002 --no-multicast

Publishes, per sensor (SERIAL as in `kfuse devices`), the ROS 2 topics
  /kinect2/sn_SERIAL/sd/image_depth   sensor_msgs/Image 16UC1, millimetres
  /kinect2/sn_SERIAL/sd/image_ir      sensor_msgs/Image 16UC1 (not with --no-ir)
  /kinect2/sn_SERIAL/hd/image_color/compressed   sensor_msgs/CompressedImage, the sensor's JPEG
  /kinect2/sn_SERIAL/{sd,hd}/camera_info         sensor_msgs/CameraInfo (from --rig)
  /tf_static                          tf2_msgs/TFMessage
on rmw_zenoh's Zenoh keys (ROS domain --domain-id), and kfuse's status (drops, sensor times) on
DOMAIN/kinect2/sn_SERIAL/kfuse/status. Ctrl-C or SIGTERM stops it cleanly.")]
pub struct ServeArgs {
    #[command(flatten)]
    common: CommonArgs,
    /// The rig whose cameras the CameraInfo and /tf_static messages describe: a rig of several
    /// sensors (`kfuse calibrate --camera ...`) that names this sensor, or its two-camera rig.
    /// The simulator's default is the simulated ring's true rig; a real sensor needs one
    /// (`kfuse rig import kinect_params.json` makes one from its factory parameters).
    #[arg(long, value_name = "RIG.json")]
    rig: Option<PathBuf>,
    /// Stop after publishing this many depth frames (default: run until Ctrl-C/SIGTERM).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    frames: Option<u64>,
    /// Leave the IR images out (half the bytes of a frame without the JPEG).
    #[arg(long)]
    no_ir: bool,
    #[command(flatten)]
    net: NetArgs,
}

/// This sensor's pair and, in a rig of several sensors, its depth camera's pose in the rig's
/// reference frame and the reference sensor's serial.
struct SensorRig {
    pair: Rig,
    in_reference: Option<(geometry::RigidTransform, String)>,
}

/// The rig of `--rig` (or the simulated ring's) for sensor `serial`. Error: a rig that does not
/// name the sensor (refused by name: its frames would be fused with another sensor's pose).
fn sensor_rig(args: &ServeArgs, serial: &str, source: &SensorSource) -> Result<SensorRig> {
    let multi = match (&args.rig, source) {
        (Some(path), _) => match kfuse_io::rig::read_rig(path)? {
            kfuse_io::rig::AnyRig::Multi(m) => Some((m, path.display().to_string())),
            kfuse_io::rig::AnyRig::Single(c) => {
                let kfuse_io::rig_io::Calibration::Rig(pair) = *c else {
                    bail!(
                        "{}: a single camera; --rig takes a rig of the sensor's depth and colour cameras",
                        path.display()
                    );
                };
                return Ok(SensorRig { pair, in_reference: None });
            }
        },
        (None, SensorSource::Sim(o)) => {
            let n = o.ring.as_ref().map_or(1, |r| r.sensors);
            let rig = kfuse_capture::source::sim_true_rig(n)?;
            match rig.as_pair() {
                Some(pair) if n == 1 => return Ok(SensorRig { pair, in_reference: None }),
                _ => Some((rig, "the simulated ring's true rig".to_string())),
            }
        }
        (None, _) => bail!(
            "--rig RIG.json is needed for the CameraInfo and /tf_static of a real sensor (`kfuse rig import kinect_params.json` makes one from its factory parameters; `kfuse capture scene` writes that file)"
        ),
    };
    let (rig, name) = multi.context("a rig")?;
    if !rig.sensors().contains(&serial) {
        bail!(
            "{name} has no sensor {serial} (its sensors: {}): this is not the rig of this sensor; give the rig that names it",
            rig.sensors().join(", ")
        );
    }
    let (pair, depth_from_reference) = rig.sensor_rig(serial)?;
    let reference_sensor = rig
        .camera(&rig.reference)
        .and_then(|c| c.sensor.clone())
        .unwrap_or_else(|| rig.reference.clone());
    let in_reference =
        (reference_sensor != serial).then_some((depth_from_reference, reference_sensor));
    Ok(SensorRig { pair, in_reference })
}

fn camera_info(v: &kfuse_io::rig_io::ros::CameraInfoValues) -> Result<CameraInfo> {
    Ok(CameraInfo {
        height: u32::try_from(v.height).context("camera height")?,
        width: u32::try_from(v.width).context("camera width")?,
        distortion_model: "plumb_bob".into(),
        d: v.d.to_vec(),
        k: v.k,
        r: v.r,
        p: v.p,
        ..Default::default()
    })
}

fn transform(t: &geometry::RigidTransform) -> Transform {
    let q = nalgebra::UnitQuaternion::from_rotation_matrix(&t.rotation);
    let v = t.translation;
    Transform {
        translation: Vector3 { x: v.x, y: v.y, z: v.z },
        rotation: Quaternion { x: q.i, y: q.j, z: q.k, w: q.w },
    }
}

/// Both `CameraInfo`s and the static transforms of sensor `serial` (the rosbag2 layout's
/// rules: `kfuse_io::rig_io::ros::rig_camera_infos`, the IR optical frame's pose in the colour
/// optical frame; with a rig of several sensors also this depth camera's pose in the reference
/// sensor's IR optical frame).
fn latched(serial: &str, rig: &SensorRig, stamp_ns: u64) -> Result<kfuse_live::publish::Latched> {
    let (ir, rgb) = optical_frames(serial);
    let (d, c) = kfuse_io::rig_io::ros::rig_camera_infos(&rig.pair);
    let mut transforms = vec![TransformStamped {
        header: header(stamp_ns, &rgb)?,
        child_frame_id: ir.clone(),
        transform: transform(&rig.pair.color_from_depth),
    }];
    if let Some((depth_from_reference, reference)) = &rig.in_reference {
        transforms.push(TransformStamped {
            header: header(stamp_ns, &optical_frames(reference).0)?,
            child_frame_id: ir,
            transform: transform(&depth_from_reference.inverse()),
        });
    }
    Ok(kfuse_live::publish::Latched {
        depth_info: camera_info(&d)?,
        color_info: camera_info(&c)?,
        transforms,
    })
}

/// Host time (Unix ns) of an `Instant`, through one reading of both clocks at start.
struct Clock {
    instant: Instant,
    unix_ns: u64,
}

impl Clock {
    fn now() -> Self {
        Self { instant: Instant::now(), unix_ns: unix_now_ns() }
    }

    fn unix_ns(&self, t: Instant) -> u64 {
        match t.checked_duration_since(self.instant) {
            Some(d) => self.unix_ns + d.as_nanos() as u64,
            None => self.unix_ns.saturating_sub(self.instant.duration_since(t).as_nanos() as u64),
        }
    }
}

/// Runs `kfuse serve`.
pub fn run(args: ServeArgs) -> Result<()> {
    crate::interrupt::install()?;
    let domain = args.net.domain()?;
    let chosen = args.common.chosen()?;
    if let Some(c) = chosen.as_ref().filter(|c| c.len() > 1) {
        bail!(
            "--device chose {} sensors: `kfuse serve` publishes one; start one per sensor (`kfuse serve --device SERIAL`)",
            c.len()
        );
    }
    let common = args.common.with_chosen(chosen);
    let mut source = common.source();
    match &mut source {
        SensorSource::Sim(o) => o.real_time = true,
        SensorSource::Replay(_) => {
            bail!("`kfuse serve` streams a live sensor (--backend usb or sim), not a --replay")
        }
        _ => {}
    }
    // The network first: a taken port fails before the sensor starts.
    let zenoh = kfuse_live::net::open(&args.net.endpoints())?;
    let mut session = crate::cmd_capture::start_source(&common, source.clone())?;
    let serial = session.info().serial.clone();
    let rig = sensor_rig(&args, &serial, &source)?;
    let clock = Clock::now();
    let mut publisher =
        SensorPublisher::declare(&zenoh, domain, &serial, latched(&serial, &rig, clock.unix_ns)?)?;
    let mut pump = FramePump::new(session.decoder(&common.decoder())?);
    eprintln!(
        "serving sensor {serial} on ROS domain {domain} ({}): Zenoh id {}",
        kfuse_ros_msgs::names::namespace(&serial),
        zenoh.zid()
    );
    for l in &args.net.listen {
        eprintln!("listening on {l}");
    }
    let r = serve_loop(&args, &mut session, &mut pump, &mut publisher, &clock, &serial);
    let c = session.counters();
    session.close();
    crate::cmd_capture::write_sim_report(&common, &session)?;
    let frames = r?;
    eprintln!(
        "published {frames} depth frames ({:.1} MB); {} depth and {} colour frames replaced before they were published",
        publisher.bytes() as f64 / 1e6,
        c.depth_overwritten,
        c.color_overwritten
    );
    drop(publisher);
    let _ = zenoh.close().wait();
    if crate::interrupt::requested() {
        // The way a service is stopped (SIGTERM from its supervisor, Ctrl-C): a clean exit.
        eprintln!("stopped by a signal after {frames} frames");
    }
    Ok(())
}

/// The sensor loop: pumps frames and publishes them until `--frames`, a signal, or the sensor
/// goes silent. Returns the depth frames published.
fn serve_loop(
    args: &ServeArgs,
    session: &mut kfuse_capture::Session,
    pump: &mut FramePump,
    publisher: &mut SensorPublisher,
    clock: &Clock,
    serial: &str,
) -> Result<u64> {
    let (ir_frame, rgb_frame) = optical_frames(serial);
    let (w, h) = (kinect_usb::raw::WIDTH, kinect_usb::raw::HEIGHT);
    let mut published = 0u64;
    let mut last_tf: Option<Instant> = None;
    let mut last_frame = Instant::now();
    let mut color: Option<(u32, u64)> = None;
    while !crate::interrupt::requested() && args.frames.is_none_or(|n| published < n) {
        if last_tf.is_none_or(|t| t.elapsed() >= TF_STATIC_PERIOD) {
            publisher.put_tf_static()?;
            last_tf = Some(Instant::now());
        }
        let got = pump.pump(session, Duration::from_millis(100))?;
        match got {
            None => {
                if last_frame.elapsed() > SENSOR_SILENCE {
                    bail!("sensor {serial} sent no frame for {SENSOR_SILENCE:?}: stopped");
                }
            }
            Some(Pumped::Color) => {
                last_frame = Instant::now();
                let at = pump.color_arrived().map_or_else(unix_now_ns, |t| clock.unix_ns(t));
                let jpeg = kfuse_io::sensor_color::mirrored_jpeg(pump.color_jpeg())
                    .map_err(|m| anyhow::anyhow!("sensor {serial}: its colour frame: {m}"))?;
                publisher
                    .put(LiveTopic::Color, compressed_jpeg(header(at, &rgb_frame)?, &jpeg)?)?;
                color = Some((pump.color_timestamp().unwrap_or(0), at));
            }
            Some(Pumped::Depth { timestamp, .. }) => {
                last_frame = Instant::now();
                let at = pump.depth_arrived().map_or_else(unix_now_ns, |t| clock.unix_ns(t));
                let before = publisher.bytes();
                let depth = kfuse_sequence::rosbag2::depth_mm_u16(pump.depth_mm());
                let hd = header(at, &ir_frame)?;
                publisher.put(LiveTopic::Depth, image_16uc1(hd.clone(), (w, h), &depth)?)?;
                if !args.no_ir {
                    let ir = kfuse_sequence::rosbag2::ir_u16(pump.ir());
                    publisher.put(LiveTopic::Ir, image_16uc1(hd.clone(), (w, h), &ir)?)?;
                }
                publisher.put_camera_infos(hd, header(at, &rgb_frame)?)?;
                published += 1;
                let c = session.counters();
                let status = Status {
                    format: STATUS_FORMAT.into(),
                    version: STATUS_VERSION,
                    serial: serial.to_string(),
                    frames: published,
                    depth_time_ticks: timestamp,
                    depth_host_ns: at,
                    color_time_ticks: color.map(|c| c.0),
                    color_host_ns: color.map(|c| c.1),
                    depth_dropped: c.depth_overwritten,
                    color_dropped: c.color_overwritten,
                    frame_bytes: publisher.bytes() - before,
                };
                publisher.put(LiveTopic::Status, status.encode())?;
            }
        }
    }
    Ok(published)
}
