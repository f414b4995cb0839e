//! `kfuse fuse --rig RIG.json --sensor SERIAL=COLOR,DEPTH ...` or `--frames DIR` (a capture of
//! several sensors, `DIR/index.json`): several Kinects of a rig of N cameras fused into one
//! coloured cloud in the rig's reference frame, z-buffered into one camera of the rig
//! ([`fusion_gpu::fuse_multi`]: the per-pixel stages and the z-buffer across the sensors on
//! `--engine`) and optionally into a virtual camera, meshed per sensor with H5's edge rule,
//! with the rig's overlap consistency per pair of sensors. With `--tsdf`, every sensor's depth
//! is also integrated into one truncated signed distance field (`kfuse_tsdf`), meshed by
//! marching cubes into [`TSDF_OUTPUTS`].

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use fusion_gpu::{Engine, EngineUsed};
use geometry::fusion::FusionOptions;
use geometry::fusion::multi::{MultiFusion, SensorImages, look_at};
use geometry::{DepthKind, MultiRig, RigidTransform};
use kfuse_io::atomic::{StagedDir, write_bytes_atomic};
use kfuse_io::{image_header, images, obj, ply};
use nalgebra::Vector3;
use serde::Serialize;

use super::{DepthKindArg, FuseArgs, options};

/// The names this command always writes into `--out`; beside them `mesh_SERIAL.*` per
/// sensor ([`mesh_names`]) and, with `--virtual-view`, [`VIRTUAL_OUTPUTS`].
const OUTPUTS: [&str; 4] = ["rig.json", "cloud.ply", "depth_zbuffer.png", "summary.json"];

/// What `--tsdf` writes: the mesh (vertex colours and normals) and the surface points.
const TSDF_OUTPUTS: [&str; 4] = kfuse_io::fused::TSDF_FILES;

/// Bytes in a GiB, for the memory bound's message.
const GIB: f64 = (1u64 << 30) as f64;

/// What `--virtual-view` writes.
const VIRTUAL_OUTPUTS: [&str; 2] = ["virtual_depth.png", "virtual_color.png"];

/// Largest `index.json` of a capture folder read: 16 MiB (a capture of four sensors writes
/// ~0.5 kB per shot: over 30 000 shots).
const MAX_INDEX_BYTES: u64 = 16 << 20;

/// The `format` of a capture of several sensors' `index.json` (`kfuse_capture::multi`).
const INDEX_FORMAT: &str = "kfuse-multi-capture";

/// Longest sensor name that names output files (`mesh_SERIAL.obj`): 64 characters (Kinect
/// serials have 12).
const MAX_SERIAL_CHARS: usize = 64;

/// Whether `dir` is a capture folder of several sensors (it holds an `index.json`).
pub fn is_multi_capture(dir: &Path) -> bool {
    dir.join("index.json").is_file()
}

/// Whether `kfuse fuse` fuses several Kinects: `--sensor`, `--frames` of a capture of several
/// sensors, or one of the flags only that fusion takes (which [`run`] then checks).
pub fn is_multi(args: &FuseArgs) -> bool {
    !args.sensor.is_empty()
        || args.sequence.frames.as_deref().is_some_and(is_multi_capture)
        || args.shot.is_some()
        || args.virtual_view.is_some()
        || args.view.is_some()
        // --tsdf of a recording (one fixed sensor) is the sequence path's.
        || ((args.tsdf || args.voxel_size.is_some() || args.truncation.is_some())
            && args.sequence.recording.is_none())
}

/// The volume `--tsdf`, `--voxel-size` and `--truncation` ask for, checked before any work;
/// `None` without `--tsdf`. Errors, one line each: a value out of its range (naming the flag,
/// the value and the range), `--voxel-size`/`--truncation` without `--tsdf`.
pub(super) fn tsdf_options(args: &FuseArgs) -> Result<Option<kfuse_tsdf::TsdfOptions>> {
    if !args.tsdf {
        if args.voxel_size.is_some() || args.truncation.is_some() {
            bail!("--voxel-size and --truncation size the volume of --tsdf: add --tsdf");
        }
        return Ok(None);
    }
    let mut o = match args.voxel_size {
        Some(v) => kfuse_tsdf::TsdfOptions::with_voxel_size(v),
        None => kfuse_tsdf::TsdfOptions::default(),
    };
    if let Some(t) = args.truncation {
        o.truncation_m = t;
    }
    o.validate().map_err(|e| {
        let flag =
            if e.to_string().contains("truncation") { "--truncation" } else { "--voxel-size" };
        anyhow::anyhow!("{flag}: {e}")
    })?;
    Ok(Some(o))
}

/// The per-sensor mesh files of sensor `serial`: the H5-clean mesh as PLY and OBJ (with its
/// material and texture), as single `fuse` writes `mesh_clean.*`.
fn mesh_names(serial: &str) -> [String; 4] {
    [".ply", ".obj", ".mtl", "_texture.png"].map(|ext| format!("mesh_{serial}{ext}"))
}

/// Refuses a sensor name that cannot name a file.
pub(super) fn check_serial_for_files(serial: &str, rig: &Path) -> Result<()> {
    let ok = !serial.is_empty()
        && serial.chars().count() <= MAX_SERIAL_CHARS
        && !serial.starts_with('.')
        && serial.chars().all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c));
    if !ok {
        bail!(
            "{}: sensor \"{}\" cannot name its mesh file (mesh_SERIAL.obj): rename it to at most {MAX_SERIAL_CHARS} letters, digits, '-', '_' or '.'",
            rig.display(),
            serial.escape_debug().take(MAX_SERIAL_CHARS).collect::<String>()
        );
    }
    Ok(())
}

/// Reads `--rig` as a rig of several cameras (version 2), its plausibility checked unless
/// `force` (then the problems are printed as warnings).
pub(super) fn load_multi_rig_for_fuse(path: &Path, force: bool) -> Result<MultiRig> {
    let Some(rig) = kfuse_io::rig::read_rig(path)?.into_multi() else {
        bail!(
            "{}: not a rig of several cameras (version 2): --sensor/--frames of several Kinects need one; make it with `kfuse calibrate --camera NAME=GLOB ...` (a two-camera rig fuses one Kinect: --color/--depth)",
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

/// One shot of a capture folder chosen by `--frames DIR [--shot K]`.
#[derive(Debug, Clone, Serialize)]
struct ShotChoice {
    folder: String,
    shot: String,
    index: usize,
}

/// Every sensor's colour and depth file of one shot of the capture folder `dir`
/// (`index.json`): the shot `shot` names (its name, or its 0-based index), or the only one.
/// Errors, one line each: no or a broken index, two sensors with one serial, an unknown shot,
/// several shots without `--shot`.
fn frames_inputs(dir: &Path, shot: Option<&str>) -> Result<(Vec<SensorArg>, ShotChoice)> {
    let path = dir.join("index.json");
    let expected = bounded_read::Expected {
        what: "the index.json of a capture",
        fix: "is it one? Give the folder `kfuse capture --device ...` wrote",
    };
    let bytes = bounded_read::read_bounded(&path, MAX_INDEX_BYTES, expected)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let text = String::from_utf8(bytes)
        .map_err(|_| anyhow::anyhow!("{}: binary data, not JSON text", path.display()))?;
    let bad = |m: String| {
        anyhow::anyhow!(
            "{}: {m} (the index.json of `kfuse capture --device ...` of several sensors)",
            path.display()
        )
    };
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| bad(format!("not JSON ({e})")))?;
    if v.get("format").and_then(|f| f.as_str()) != Some(INDEX_FORMAT) {
        return Err(bad(format!(
            "not a capture of several sensors (no \"format\": \"{INDEX_FORMAT}\")"
        )));
    }
    if v.get("version").and_then(|f| f.as_u64()) != Some(1) {
        return Err(bad("an index version this kfuse does not read (1): upgrade kfuse".into()));
    }
    let scene = match v.get("kind").and_then(|k| k.as_str()) {
        Some("scene") => true,
        Some("calib") => false,
        _ => return Err(bad("\"kind\" must be \"scene\" or \"calib\"".into())),
    };
    let sensors = v
        .get("sensors")
        .and_then(|s| s.as_array())
        .ok_or_else(|| bad("no \"sensors\" list".into()))?;
    let max = geometry::multi_rig::MAX_RIG_CAMERAS;
    if sensors.len() > max {
        return Err(bad(format!(
            "{} sensors, over the {max} cameras a rig may hold",
            sensors.len()
        )));
    }
    let mut folders: Vec<(String, String)> = Vec::new();
    for s in sensors {
        let serial = s
            .get("serial")
            .and_then(|x| x.as_str())
            .ok_or_else(|| bad("a sensor without \"serial\"".into()))?;
        let folder = s.get("folder").and_then(|x| x.as_str()).unwrap_or(serial);
        let mut parts = Path::new(folder).components();
        let plain =
            matches!(parts.next(), Some(std::path::Component::Normal(_))) && parts.next().is_none();
        if !plain {
            return Err(bad(format!(
                "sensor {serial}'s folder \"{}\" is not a folder inside {}",
                folder.escape_debug(),
                dir.display()
            )));
        }
        if folders.iter().any(|(o, _)| o == serial) {
            return Err(bad(format!(
                "two sensors with the same serial {serial}: their frames cannot be told apart; capture them again with distinct sensors"
            )));
        }
        folders.push((serial.to_string(), folder.to_string()));
    }
    let shots =
        v.get("shots").and_then(|s| s.as_array()).ok_or_else(|| bad("no \"shots\" list".into()))?;
    let name_of =
        |s: &serde_json::Value| s.get("name").and_then(|n| n.as_str()).map(str::to_string);
    let index = match shot {
        Some(want) => match shots.iter().position(|s| name_of(s).as_deref() == Some(want)) {
            Some(k) => k,
            None => match want.parse::<usize>() {
                Ok(k) if k < shots.len() => k,
                _ => bail!(
                    "--shot {want}: {} has no shot of that name, and {} shots (indices 0-{})",
                    path.display(),
                    shots.len(),
                    shots.len().saturating_sub(1)
                ),
            },
        },
        None if shots.len() == 1 => 0,
        None if shots.is_empty() => {
            bail!("{}: no shots were taken into {}", path.display(), dir.display())
        }
        None => bail!(
            "{} holds {} shots: choose one with --shot NAME or --shot K (0-{})",
            dir.display(),
            shots.len(),
            shots.len() - 1
        ),
    };
    let chosen = &shots[index];
    let name = name_of(chosen).ok_or_else(|| bad(format!("shot {index} has no \"name\"")))?;
    let taken = chosen.get("sensors").and_then(|s| s.as_object());
    let mut out = Vec::new();
    for (serial, folder) in &folders {
        if !taken.is_some_and(|t| t.contains_key(serial)) {
            // A sensor lost before this shot (index.json's "lost_after_shot").
            continue;
        }
        let base = dir.join(folder);
        let (color, depth) = if scene {
            (base.join(format!("{name}_color.jpg")), base.join(format!("{name}_depth.png")))
        } else {
            (base.join(format!("color_{name}.jpg")), base.join(format!("depth_{name}.png")))
        };
        out.push(SensorArg { serial: serial.clone(), color, depth });
    }
    let choice = ShotChoice { folder: dir.display().to_string(), shot: name, index };
    Ok((out, choice))
}

/// Parses `--virtual-view 'from=X,Y,Z;look-at=X,Y,Z[;up=X,Y,Z]'` (reference frame, metres;
/// `up` by default the reference camera's up, −y) into the camera's `camera_from_reference`.
pub fn parse_virtual_view(s: &str) -> Result<RigidTransform, String> {
    let usage = "--virtual-view takes 'from=X,Y,Z;look-at=X,Y,Z[;up=X,Y,Z]' (metres, in the rig's reference frame)";
    let mut from = None;
    let mut at = None;
    let mut up = Vector3::new(0.0, -1.0, 0.0);
    for part in s.split(';').map(str::trim).filter(|p| !p.is_empty()) {
        let (key, value) = part.split_once('=').ok_or_else(|| format!("'{part}': {usage}"))?;
        let c: Vec<f64> = value
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| format!("'{part}': three numbers X,Y,Z expected; {usage}"))?;
        let [x, y, z] = c[..] else {
            return Err(format!("'{part}': three numbers X,Y,Z expected; {usage}"));
        };
        let v = Vector3::new(x, y, z);
        match key.trim() {
            "from" => from = Some(v),
            "look-at" | "at" => at = Some(v),
            "up" => up = v,
            other => return Err(format!("'{other}': unknown key; {usage}")),
        }
    }
    let (Some(from), Some(at)) = (from, at) else {
        return Err(format!("'{s}': both from= and look-at= are needed; {usage}"));
    };
    look_at(from, at, up).map_err(|e| format!("--virtual-view '{s}': {e}"))
}

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
    #[serde(skip_serializing_if = "Option::is_none")]
    shot: Option<ShotChoice>,
    #[serde(skip_serializing_if = "Option::is_none")]
    virtual_view: Option<VirtualSummary>,
    #[serde(skip_serializing_if = "Option::is_none")]
    tsdf: Option<TsdfSummary>,
    consistency: &'a [geometry::fusion::multi::PairConsistency],
    consistency_gate_mm: f64,
    engine: String,
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
    mesh: String,
    mesh_faces_before_h5: usize,
    mesh_faces: usize,
    mesh_vertices: usize,
}

/// summary.json's `tsdf`.
#[derive(Serialize)]
struct TsdfSummary {
    voxel_size_m: f64,
    truncation_m: f64,
    blocks: usize,
    memory_bytes: u64,
    memory_bound_bytes: u64,
    /// Per sensor, in the order of `sensors`: voxels updated.
    voxels_updated: Vec<usize>,
    mesh_vertices: usize,
    mesh_faces: usize,
    integrate_ms: f64,
    mesh_ms: f64,
}

#[derive(Serialize)]
struct VirtualSummary {
    spec: String,
    camera_model_of: String,
    camera_from_reference: [[f64; 4]; 3],
    pixels: usize,
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

/// The flags of a fusion of several sensors agree; returns `--frames` when it is a capture
/// folder of several sensors.
fn check_flags(args: &FuseArgs) -> Result<Option<&Path>> {
    let frames_dir = args.sequence.frames.as_deref().filter(|d| is_multi_capture(d));
    if args.sensor.is_empty() && frames_dir.is_none() {
        match &args.sequence.frames {
            Some(f) => bail!(
                "{}: no index.json, so not a capture of several sensors: --view/--shot/--virtual-view/--tsdf fuse several Kinects (give `kfuse capture --device ...`'s folder, or --sensor SERIAL=COLOR,DEPTH per sensor)",
                f.display()
            ),
            None => bail!(
                "--view/--shot/--virtual-view/--tsdf fuse several Kinects: give --sensor SERIAL=COLOR,DEPTH per sensor or --frames DIR of a capture of several sensors"
            ),
        }
    }
    if !args.sensor.is_empty() && args.sequence.frames.is_some() {
        bail!(
            "--sensor gives every sensor's images and --frames a capture folder: give one of them"
        );
    }
    if args.sequence.recording.is_some() {
        bail!(
            "--recording is one sensor's recording: fuse several Kinects from --sensor images or a --frames capture folder"
        );
    }
    if args.shot.is_some() && frames_dir.is_none() {
        bail!(
            "--shot chooses a shot of --frames DIR (a capture of several sensors): drop it with --sensor"
        );
    }
    if args.color.is_some() || args.depth.is_some() || args.mat.is_some() {
        bail!("--sensor/--frames give every sensor's images: drop --color/--depth/--mat");
    }
    Ok(frames_dir)
}

/// Every sensor of `rig` has exactly one pair of images in `sensor_args`, and every pair
/// belongs to a sensor of the rig.
fn check_sensors(
    rig: &MultiRig,
    rig_path: &Path,
    sensor_args: &[SensorArg],
    shot: Option<&ShotChoice>,
) -> Result<()> {
    let given = if shot.is_some() { "the capture" } else { "--sensor" };
    let sensors = rig.sensors();
    if sensors.is_empty() {
        bail!(
            "{}: no camera belongs to a sensor (\"sensor\": SERIAL): nothing to fuse",
            rig_path.display()
        );
    }
    for s in &sensors {
        check_serial_for_files(s, rig_path)?;
    }
    for (i, s) in sensor_args.iter().enumerate() {
        if !sensors.contains(&s.serial.as_str()) {
            bail!(
                "{given} {}: no sensor {} in {} (its sensors: {})",
                s.serial,
                s.serial,
                rig_path.display(),
                sensors.join(", ")
            );
        }
        if sensor_args[..i].iter().any(|o| o.serial == s.serial) {
            bail!("--sensor {} is given twice", s.serial);
        }
    }
    if let Some(missing) = sensors.iter().find(|s| !sensor_args.iter().any(|a| a.serial == **s)) {
        match shot {
            Some(c) => bail!(
                "sensor {missing} of {} has no frames in shot {} of {} (lost or not captured): fuse with a rig without it",
                rig_path.display(),
                c.shot,
                c.folder
            ),
            None => bail!(
                "sensor {missing} of {} has no images: add --sensor {missing}=COLOR,DEPTH (or fuse with a rig without it)",
                rig_path.display()
            ),
        }
    }
    Ok(())
}

/// The camera the merged cloud is z-buffered into: `--view`, or the reference sensor's colour
/// camera.
fn view_name(args: &FuseArgs, rig: &MultiRig, rig_path: &Path) -> Result<String> {
    let name = match &args.view {
        Some(v) => v.clone(),
        None => {
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
    if rig.camera(&name).is_none() {
        bail!(
            "--view {name}: no such camera in {} (its cameras: {})",
            rig_path.display(),
            rig.names().join(", ")
        );
    }
    Ok(name)
}

/// Every sensor's colour and depth image, each checked against its camera's size in `rig`
/// (from the file's header before decoding, then the decoded image).
fn read_inputs(
    rig: &MultiRig,
    sensor_args: &[SensorArg],
    depth_scale: f64,
) -> Result<Vec<SensorImages>> {
    let mut inputs = Vec::new();
    for s in sensor_args {
        let (pair, _) = rig.sensor_rig(&s.serial)?;
        let (dname, cname) = (format!("{}.depth", s.serial), format!("{}.color", s.serial));
        let want_c = (pair.color.width, pair.color.height);
        let want_d = (pair.depth.width, pair.depth.height);
        check_size("colour image", &s.color, image_header::image_size(&s.color)?, want_c, &cname)?;
        check_size("depth image", &s.depth, image_header::image_size(&s.depth)?, want_d, &dname)?;
        let color = images::read_color(&s.color)?;
        let depth = images::read_depth(&s.depth, depth_scale)?;
        check_size("colour image", &s.color, color.size(), want_c, &cname)?;
        check_size("depth image", &s.depth, depth.size(), want_d, &dname)?;
        inputs.push(SensorImages { sensor: s.serial.clone(), depth, color });
    }
    Ok(inputs)
}

/// One sensor's mesh as written: its OBJ's name and the faces before and after H5's rule.
struct MeshWritten {
    obj: String,
    faces_before_h5: usize,
    faces: usize,
    vertices: usize,
}

/// Every sensor's mesh (H5's edge rule) as `mesh_SERIAL.ply` and a textured `mesh_SERIAL.obj`.
fn write_meshes(
    staged: &StagedDir,
    fused: &MultiFusion,
    inputs: &[SensorImages],
    options: &FusionOptions,
) -> Result<Vec<MeshWritten>> {
    let mut meshes = Vec::new();
    for (k, c) in fused.sensors.iter().enumerate() {
        let (mesh, before) = fused.sensor_mesh(k, options).context("a sensor of the fusion")?;
        let [ply_name, obj_name, _, texture] = mesh_names(&c.sensor);
        ply::write_mesh_ply(
            &staged.join(&ply_name),
            &mesh,
            "rig reference camera",
            Some(&texture),
        )?;
        let color = &inputs.iter().find(|i| i.sensor == c.sensor).context("a fused sensor")?.color;
        obj::write_textured_obj(&staged.join(&obj_name), &mesh, Some(color))?;
        meshes.push(MeshWritten {
            obj: obj_name,
            faces_before_h5: before,
            faces: mesh.faces.len(),
            vertices: mesh.vertices.len(),
        });
    }
    Ok(meshes)
}

/// `--virtual-view`: the merged cloud rendered into a camera of the reference camera's model at
/// `pose`, written as [`VIRTUAL_OUTPUTS`].
fn write_virtual(
    staged: &StagedDir,
    rig: &MultiRig,
    fused: &MultiFusion,
    spec: &str,
    pose: &RigidTransform,
) -> Result<VirtualSummary> {
    let reference = rig.camera(&rig.reference).context("the rig's reference camera")?;
    let (depth, color) = fused.render_merged(&reference.model, pose);
    images::write_depth_png16(&staged.join(VIRTUAL_OUTPUTS[0]), &depth)?;
    images::write_color_png(&staged.join(VIRTUAL_OUTPUTS[1]), &color)?;
    let m = pose.matrix();
    Ok(VirtualSummary {
        spec: spec.to_string(),
        camera_model_of: rig.reference.clone(),
        camera_from_reference: std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)])),
        pixels: depth.data().iter().filter(|z| z.is_finite()).count(),
    })
}

/// `--tsdf`: every sensor integrated into one volume (a progress bar per sensor and for the
/// mesh), the mesh and its surface points written as [`TSDF_OUTPUTS`].
fn write_tsdf(
    staged: &StagedDir,
    fused: &MultiFusion,
    options: kfuse_tsdf::TsdfOptions,
) -> Result<TsdfSummary> {
    let bar = super::progress(fused.sensors.len() as u64 + 1);
    bar.set_message("TSDF: integrating");
    let t0 = std::time::Instant::now();
    let mut volume = kfuse_tsdf::TsdfVolume::new(options)?;
    let stats = kfuse_tsdf::integrate_multi(&mut volume, fused, |k| bar.set_position(k as u64));
    let stats = match stats {
        Ok(s) => s,
        Err(e @ kfuse_tsdf::TsdfError::MemoryBound { .. }) => {
            bar.finish_and_clear();
            bail!("{}", memory_bound_line(&e, &options));
        }
        Err(e) => {
            bar.finish_and_clear();
            return Err(e).context("--tsdf");
        }
    };
    let integrate_ms = t0.elapsed().as_secs_f64() * 1e3;
    bar.set_message("TSDF: marching cubes");
    let t1 = std::time::Instant::now();
    let mesh = volume.extract_mesh();
    let mesh_ms = t1.elapsed().as_secs_f64() * 1e3;
    bar.finish_and_clear();
    kfuse_io::fused::write_tsdf_files(
        staged.path(),
        &mesh.to_mesh(),
        &mesh.normals,
        "rig reference camera",
    )?;
    Ok(TsdfSummary {
        voxel_size_m: options.voxel_size_m,
        truncation_m: options.truncation_m,
        blocks: volume.block_count(),
        memory_bytes: volume.memory_bytes(),
        memory_bound_bytes: options.max_memory_bytes,
        voxels_updated: stats.iter().map(|s| s.voxels_updated).collect(),
        mesh_vertices: mesh.vertices.len(),
        mesh_faces: mesh.faces.len(),
        integrate_ms,
        mesh_ms,
    })
}

/// The one line of a volume over its memory bound, naming `--voxel-size`; `e`'s own text for
/// any other error.
pub(super) fn memory_bound_line(
    e: &kfuse_tsdf::TsdfError,
    options: &kfuse_tsdf::TsdfOptions,
) -> String {
    match e {
        kfuse_tsdf::TsdfError::MemoryBound { blocks, needed_bytes, limit_bytes } => format!(
            "--voxel-size {}: the TSDF volume would need at least {:.2} GiB ({blocks} voxel blocks), over its {:.2} GiB bound: use a larger --voxel-size (memory grows with 1/size²)",
            options.voxel_size_m,
            *needed_bytes as f64 / GIB,
            *limit_bytes as f64 / GIB
        ),
        e => format!("--tsdf: {e}"),
    }
}

/// Each sensor's line of summary.json.
fn sensor_summaries(
    fused: &MultiFusion,
    sensor_args: &[SensorArg],
    meshes: &[MeshWritten],
) -> Vec<SensorSummary> {
    let per_sensor = fused.points_per_sensor();
    fused
        .sensors
        .iter()
        .zip(&per_sensor)
        .zip(meshes)
        .map(|((c, &n), m)| {
            let a = sensor_args.iter().find(|a| a.serial == c.sensor).expect("checked above");
            SensorSummary {
                sensor: c.sensor.clone(),
                color: a.color.display().to_string(),
                depth: a.depth.display().to_string(),
                samples: c.points.len(),
                points_in_cloud: n,
                mesh: m.obj.clone(),
                mesh_faces_before_h5: m.faces_before_h5,
                mesh_faces: m.faces,
                mesh_vertices: m.vertices,
            }
        })
        .collect()
}

/// What a run prints: the points, the shot, each mesh and each pair's consistency.
fn print_result(
    out: &Path,
    fused: &MultiFusion,
    shot: Option<&ShotChoice>,
    meshes: &[MeshWritten],
) {
    println!(
        "fused {} sensors: {} points into {}",
        fused.sensors.len(),
        fused.cloud.points.len(),
        out.display()
    );
    if let Some(c) = shot {
        println!("  shot {} ({}) of {}", c.index, c.shot, c.folder);
    }
    for (c, m) in fused.sensors.iter().zip(meshes) {
        println!(
            "  mesh {}: {} -> {} faces after H5 ({})",
            c.sensor, m.faces_before_h5, m.faces, m.obj
        );
    }
    for c in &fused.consistency {
        let colour = if c.color_correlation.is_nan() {
            format!("colour not compared: {} pixels seen by both", c.color_pixels)
        } else {
            format!("colour correlation {:.2}", c.color_correlation)
        };
        println!(
            "consistency {}-{}: {:.2} mm over {} tiles ({} pixels; per pixel {:.2} mm; {colour})",
            c.a, c.b, c.tile_median_mm, c.tiles, c.pixels, c.median_abs_mm
        );
    }
    for line in consistency_warnings(&fused.consistency) {
        eprintln!("warning: {line}");
    }
}

/// Fewest tiles for a pair's consistency to mean something: 10 (640 compared pixels, a patch
/// of ~25 × 25 cm at 1.5 m). A wrong rig can put a few samples of one sensor on another's by
/// chance; 0.4 mm "over 2 tiles" looked better than the true rig's 0.5 mm over 60.
const MIN_CONSISTENCY_TILES: usize = 10;

/// The warnings of a fusion's pair consistencies: a pair whose colours disagree (the rig does
/// not put one sensor's samples on the surfaces the other sees them on: swapped sensors or
/// poses), or whose overlap is too small to measure.
fn consistency_warnings(pairs: &[geometry::fusion::multi::PairConsistency]) -> Vec<String> {
    use geometry::fusion::multi::MIN_COLOR_CORRELATION;
    let mut lines = Vec::new();
    for c in pairs {
        if c.color_correlation < MIN_COLOR_CORRELATION {
            lines.push(format!(
                "sensors {} and {}: the colours they see on their common surfaces do not match (correlation {:.2}, under {MIN_COLOR_CORRELATION}): the rig does not describe these frames; are two sensors' serials or poses swapped? (kfuse rig show RIG.json lists them)",
                c.a, c.b, c.color_correlation
            ));
        } else if c.tiles < MIN_CONSISTENCY_TILES {
            lines.push(format!(
                "sensors {} and {}: their depth agrees over {} tile(s) only (under {MIN_CONSISTENCY_TILES}): too small an overlap to judge the rig by its {:.2} mm",
                c.a, c.b, c.tiles, c.tile_median_mm
            ));
        }
    }
    lines
}

/// How summary.json names the engine that ran.
fn engine_name(used: &EngineUsed) -> String {
    match used {
        EngineUsed::Cpu => "cpu".to_string(),
        EngineUsed::Gpu { adapter, .. } => format!("gpu: {adapter}"),
        EngineUsed::CpuFallback { .. } => "cpu (no GPU adapter)".to_string(),
    }
}

/// Runs the fusion of several sensors; returns the output folder.
pub fn run(args: &FuseArgs) -> Result<PathBuf> {
    let started = std::time::Instant::now();
    let options = options(args)?;
    let frames_dir = check_flags(args)?;
    let tsdf = tsdf_options(args)?;
    if args.sequence.frames_max.is_some() {
        // It was accepted and ignored (new-user trial): several Kinects fuse one shot.
        bail!(
            "--frames-max limits the frames of a recording (--recording) that --tsdf integrates; several Kinects fuse one shot each (pick it with --shot): drop --frames-max"
        );
    }
    let Some(rig_path) = &args.rig else {
        bail!(
            "several Kinects need --rig RIG.json (a rig of several cameras; a simulated capture writes true_rig.json beside its frames)"
        )
    };
    let mut rig = load_multi_rig_for_fuse(rig_path, args.force)?;
    rig.rectified |= args.rectified;
    let (sensor_args, shot) = match frames_dir {
        Some(dir) => frames_inputs(dir, args.shot.as_deref()).map(|(a, c)| (a, Some(c)))?,
        None => (args.sensor.clone(), None),
    };
    check_sensors(&rig, rig_path, &sensor_args, shot.as_ref())?;
    let view_name = view_name(args, &rig, rig_path)?;
    let view = rig.camera(&view_name).context("the --view camera")?;
    let virtual_pose = match &args.virtual_view {
        Some(spec) => Some((spec.clone(), parse_virtual_view(spec).map_err(anyhow::Error::msg)?)),
        None => None,
    };
    let kind = match args.depth_kind {
        DepthKindArg::Z => DepthKind::Z,
        DepthKindArg::Range => DepthKind::Range,
    };
    let mut outputs: Vec<String> = OUTPUTS.map(String::from).to_vec();
    outputs.extend(rig.sensors().into_iter().flat_map(mesh_names));
    if virtual_pose.is_some() {
        outputs.extend(VIRTUAL_OUTPUTS.map(String::from));
    }
    if tsdf.is_some() {
        outputs.extend(TSDF_OUTPUTS.map(String::from));
    }
    let staged = StagedDir::new(&args.out)?;
    staged.refuse_foreign(&outputs)?;

    let inputs = read_inputs(&rig, &sensor_args, args.depth_scale)?;
    let engine = args.engine();
    let on = if engine == Engine::Cpu { "" } else { " on the GPU" };
    let (fused, zbuffer, used) =
        fusion_gpu::fuse_multi(engine, &rig, &inputs, kind, &options, view)
            .with_context(|| format!("fusing the sensors of {}{on}", rig_path.display()))?;
    if let Some(note) = super::engine_note(&used) {
        eprintln!("{note}");
    }
    kfuse_io::rig::write_multi_rig(&staged.join("rig.json"), &rig)?;
    ply::write_cloud_ply(&staged.join("cloud.ply"), &fused.cloud, "rig reference camera")?;
    images::write_depth_png16(&staged.join("depth_zbuffer.png"), &zbuffer)?;
    let t_mesh = std::time::Instant::now();
    let meshes = write_meshes(&staged, &fused, &inputs, &options)?;
    let mesh_ms = t_mesh.elapsed().as_secs_f64() * 1e3;
    let virtual_view = match &virtual_pose {
        Some((spec, pose)) => Some(write_virtual(&staged, &rig, &fused, spec, pose)?),
        None => None,
    };
    let tsdf = match tsdf {
        Some(o) => Some(write_tsdf(&staged, &fused, o)?),
        None => None,
    };
    let summary = Summary {
        rig: rig_path.display().to_string(),
        reference: &rig.reference,
        view: &view_name,
        sensors: sensor_summaries(&fused, &sensor_args, &meshes),
        points: fused.cloud.points.len(),
        view_pixels: zbuffer.data().iter().filter(|z| z.is_finite()).count(),
        shot: shot.clone(),
        virtual_view,
        tsdf,
        consistency: &fused.consistency,
        consistency_gate_mm: geometry::fusion::multi::OVERLAP_GATE_M as f64 * 1e3,
        engine: engine_name(&used),
        timings_ms: serde_json::json!({
            "sensors": fused.timings.sensors_ms,
            "merge": fused.timings.merge_ms,
            "consistency": fused.timings.consistency_ms,
            "meshes": mesh_ms,
            "total": started.elapsed().as_secs_f64() * 1e3,
        }),
        frames: "cloud.ply, mesh_SERIAL.*: the rig's reference camera; depth_zbuffer.png: --view camera, z in mm; virtual_depth.png: the --virtual-view camera, z in mm; tsdf_mesh.ply, tsdf_cloud.ply: the rig's reference camera",
    };
    let json = serde_json::to_string_pretty(&summary).context("serialising summary.json")?;
    write_bytes_atomic(&staged.join("summary.json"), json.as_bytes())?;
    let out = staged.commit()?;
    print_result(&out, &fused, shot.as_ref(), &meshes);
    if let Some(t) = &summary.tsdf {
        println!(
            "tsdf: {} vertices, {} faces at {} mm voxels ({}; {} blocks, {:.0} MB)",
            t.mesh_vertices,
            t.mesh_faces,
            t.voxel_size_m * 1e3,
            TSDF_OUTPUTS[0],
            t.blocks,
            t.memory_bytes as f64 / 1e6
        );
    }
    Ok(out)
}
