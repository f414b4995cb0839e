//! `kfuse fuse --rig RIG.json --sensor SERIAL=COLOR,DEPTH ...`: several Kinects of a rig of
//! N cameras fused into one coloured cloud in the rig's reference frame
//! ([`geometry::fusion::multi::fuse_multi`]), z-buffered into one camera of the rig, with the
//! rig's overlap consistency per pair of sensors.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use geometry::fusion::multi::{SensorImages, fuse_multi};
use geometry::{DepthKind, MultiRig};
use kfuse_io::atomic::{StagedDir, write_bytes_atomic};
use kfuse_io::{image_header, images, ply};
use serde::Serialize;

use super::{DepthKindArg, FuseArgs, options};

/// Every name this command writes into `--out`.
const OUTPUTS: [&str; 4] = ["rig.json", "cloud.ply", "depth_zbuffer.png", "summary.json"];

/// One `--sensor SERIAL=COLOR,DEPTH`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SensorArg {
    /// The sensor's name in the rig.
    pub serial: String,
    /// Its colour image.
    pub color: PathBuf,
    /// Its depth image.
    pub depth: PathBuf,
}

/// Parses `SERIAL=COLOR,DEPTH`.
pub fn parse_sensor(s: &str) -> Result<SensorArg, String> {
    let err = || format!("'{s}': --sensor takes SERIAL=COLOR,DEPTH (e.g. 0123=c.png,d.png)");
    let (serial, files) = s.split_once('=').ok_or_else(err)?;
    let (color, depth) = files.split_once(',').ok_or_else(err)?;
    if serial.is_empty() || color.is_empty() || depth.is_empty() {
        return Err(err());
    }
    Ok(SensorArg { serial: serial.into(), color: color.into(), depth: depth.into() })
}

#[derive(Serialize)]
struct Summary<'a> {
    rig: String,
    reference: &'a str,
    view: &'a str,
    sensors: Vec<SensorSummary>,
    points: usize,
    view_pixels: usize,
    consistency: &'a [geometry::fusion::multi::PairConsistency],
    consistency_gate_mm: f64,
    timings_ms: serde_json::Value,
    frames: &'static str,
}

#[derive(Serialize)]
struct SensorSummary {
    sensor: String,
    color: String,
    depth: String,
    samples: usize,
    points_in_cloud: usize,
}

fn check_size(
    what: &str,
    path: &Path,
    got: (usize, usize),
    want: (usize, usize),
    camera: &str,
) -> Result<()> {
    if got != want {
        bail!(
            "{what} {} is {}x{}, but camera {camera} of the rig is {}x{}: give that camera's image",
            path.display(),
            got.0,
            got.1,
            want.0,
            want.1
        );
    }
    Ok(())
}

/// Reads `--rig` as a rig of several cameras (version 2), its plausibility checked unless
/// `force` (then the problems are printed as warnings).
fn read_rig(path: &Path, force: bool) -> Result<MultiRig> {
    let Some(rig) = calib::rig_io::load_multi(path)? else {
        bail!(
            "{}: not a rig of several cameras (version 2): --sensor of several Kinects needs one (a two-camera rig fuses one Kinect: --color/--depth)",
            path.display()
        );
    };
    let problems = rig.plausibility_problems();
    if !problems.is_empty() {
        if !force {
            bail!(
                "{}: {} (pass --force if the rig really is meant this way)",
                path.display(),
                problems.join("; ")
            );
        }
        for w in &problems {
            eprintln!("warning: {}: {w}", path.display());
        }
    }
    Ok(rig)
}

/// Runs the fusion of several sensors; returns the output folder.
pub fn run(args: &FuseArgs) -> Result<PathBuf> {
    let started = std::time::Instant::now();
    let options = options(args)?;
    let Some(rig_path) = &args.rig else {
        bail!("--sensor needs --rig RIG.json (a rig of several cameras)")
    };
    if args.color.is_some() || args.depth.is_some() || args.mat.is_some() {
        bail!("--sensor gives every sensor's images: drop --color/--depth/--mat");
    }
    let mut rig = read_rig(rig_path, args.force)?;
    rig.rectified |= args.rectified;
    let sensors = rig.sensors();
    let names = || sensors.join(", ");
    for (i, s) in args.sensor.iter().enumerate() {
        if !sensors.contains(&s.serial.as_str()) {
            bail!(
                "--sensor {}: no sensor {} in {} (its sensors: {})",
                s.serial,
                s.serial,
                rig_path.display(),
                names()
            );
        }
        if args.sensor[..i].iter().any(|o| o.serial == s.serial) {
            bail!("--sensor {} is given twice", s.serial);
        }
    }
    if let Some(missing) = sensors.iter().find(|s| !args.sensor.iter().any(|a| a.serial == **s)) {
        bail!(
            "sensor {missing} of {} has no images: add --sensor {missing}=COLOR,DEPTH (or fuse with a rig without it)",
            rig_path.display()
        );
    }
    let view_name = match &args.view {
        Some(v) => v.clone(),
        None => {
            // The reference sensor's colour camera.
            let sensor = rig.camera(&rig.reference).and_then(|c| c.sensor.clone());
            let color = rig.cameras.iter().find(|c| {
                c.role == geometry::CameraRole::Color && c.sensor.is_some() && c.sensor == sensor
            });
            match color {
                Some(c) => c.name.clone(),
                None => bail!(
                    "the reference camera {} of {} belongs to no sensor with a colour camera: pass --view CAMERA",
                    rig.reference,
                    rig_path.display()
                ),
            }
        }
    };
    let Some(view) = rig.camera(&view_name) else {
        bail!(
            "--view {view_name}: no such camera in {} (its cameras: {})",
            rig_path.display(),
            rig.names().join(", ")
        );
    };
    let kind = match args.depth_kind {
        DepthKindArg::Z => DepthKind::Z,
        DepthKindArg::Range => DepthKind::Range,
    };
    let mut inputs = Vec::new();
    for s in &args.sensor {
        let (pair, _) = rig.sensor_rig(&s.serial)?;
        let (dname, cname) = (format!("{}.depth", s.serial), format!("{}.color", s.serial));
        let want_c = (pair.color.width, pair.color.height);
        let want_d = (pair.depth.width, pair.depth.height);
        check_size("colour image", &s.color, image_header::image_size(&s.color)?, want_c, &cname)?;
        check_size("depth image", &s.depth, image_header::image_size(&s.depth)?, want_d, &dname)?;
        let color = images::read_color(&s.color)?;
        let depth = images::read_depth(&s.depth, args.depth_scale)?;
        check_size("colour image", &s.color, color.size(), want_c, &cname)?;
        check_size("depth image", &s.depth, depth.size(), want_d, &dname)?;
        inputs.push(SensorImages { sensor: s.serial.clone(), depth, color });
    }
    let fused = fuse_multi(&rig, &inputs, kind, &options)
        .with_context(|| format!("fusing the sensors of {}", rig_path.display()))?;
    let zbuffer = fused.zbuffer_into(view);

    let staged = StagedDir::new(&args.out)?;
    staged.refuse_foreign(&OUTPUTS.map(String::from))?;
    kfuse_io::rig::write_multi_rig(&staged.join("rig.json"), &rig)?;
    ply::write_cloud_ply(&staged.join("cloud.ply"), &fused.cloud, "rig reference camera")?;
    images::write_depth_png16(&staged.join("depth_zbuffer.png"), &zbuffer)?;
    let per_sensor = fused.points_per_sensor();
    let summary = Summary {
        rig: rig_path.display().to_string(),
        reference: &rig.reference,
        view: &view_name,
        sensors: fused
            .sensors
            .iter()
            .zip(&per_sensor)
            .map(|(c, &n)| {
                let a = args.sensor.iter().find(|a| a.serial == c.sensor).expect("checked above");
                SensorSummary {
                    sensor: c.sensor.clone(),
                    color: a.color.display().to_string(),
                    depth: a.depth.display().to_string(),
                    samples: c.points.len(),
                    points_in_cloud: n,
                }
            })
            .collect(),
        points: fused.cloud.points.len(),
        view_pixels: zbuffer.data().iter().filter(|z| z.is_finite()).count(),
        consistency: &fused.consistency,
        consistency_gate_mm: geometry::fusion::multi::OVERLAP_GATE_M as f64 * 1e3,
        timings_ms: serde_json::json!({
            "sensors": fused.timings.sensors_ms,
            "merge": fused.timings.merge_ms,
            "consistency": fused.timings.consistency_ms,
            "total": started.elapsed().as_secs_f64() * 1e3,
        }),
        frames: "cloud.ply: the rig's reference camera; depth_zbuffer.png: --view camera, z in mm",
    };
    let json = serde_json::to_string_pretty(&summary).context("serialising summary.json")?;
    write_bytes_atomic(&staged.join("summary.json"), json.as_bytes())?;
    let out = staged.commit()?;
    println!(
        "fused {} sensors: {} points into {}",
        fused.sensors.len(),
        fused.cloud.points.len(),
        out.display()
    );
    for c in &fused.consistency {
        println!(
            "consistency {}-{}: {:.2} mm over {} tiles ({} pixels; per pixel {:.2} mm)",
            c.a, c.b, c.tile_median_mm, c.tiles, c.pixels, c.median_abs_mm
        );
    }
    Ok(out)
}
