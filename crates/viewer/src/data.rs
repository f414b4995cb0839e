//! Loading what the viewer shows: a `kfuse fuse` output folder, a capture folder or the
//! bundled synthetic scene.
//!
//! Folder kinds (decided by the files present):
//! * **fuse output** (`summary.json`): its `inputs` name the rig, colour and depth files (or a
//!   `synthdata.mat` or `KinectData.mat`, with the colour and depth files of `fuse --mat …
//!   --color … --depth …` that replaced its images); relative paths are tried against the current directory, then the
//!   folder's parent, then the folder itself by file name.
//!
//! A rig with `"rectified": true` (or a fuse output whose `inputs` say `"rectified": true`,
//! `kfuse fuse --rectified`) is used without its distortion, as `kfuse fuse` does.
//! * **capture** (`rig.json` with `color.png`): `rig.json`, `color.png`, `depth.png` (16-bit
//!   millimetres, z), optional `ir.png` (16-bit amplitude), as `kfuse demo` writes.
//! * **`kfuse capture`** (`kinect_params.json`): the shot shown is the one asked for by name
//!   ([`open_folder_shot`], `kfuse view --shot NAME`), else the last scene shot by name
//!   (`NAME_color.jpg`, `NAME_depth.png` (16-bit millimetres, z), optional `NAME_ir.png`),
//!   else the last calibration shot (`color_NNNN.jpg`, `depth_NNNN.png`, `ir_NNNN.png`); the
//!   rig is `rig.json` if the folder has one, else the one fitted to the sensor's factory
//!   parameters (`kfuse_io::rig_io::kinect`, as `kfuse rig import kinect_params.json`).

use std::path::{Path, PathBuf};

use geometry::{DepthKind, GeometryError, Image, Rig, synth};
use kfuse_io::kinect_data::{self, KinectDepth};
use kfuse_io::mat::MatFile;
use kfuse_io::{course, images, rig as rigio};

use crate::ViewerError;

/// The raw inputs of one frame: what the fusion pipeline is re-run on.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Where it came from (shown in the title bar).
    pub name: String,
    /// Both cameras and `color_from_depth`.
    pub rig: Rig,
    /// Depth image (depth camera), metres, NaN or 0 = no sample.
    pub depth: Image<f32>,
    /// What `depth` measures.
    pub kind: DepthKind,
    /// Colour image (colour camera).
    pub color: Image<[u8; 3]>,
    /// IR amplitude (depth camera), arbitrary units, if the source has one.
    pub ir: Option<Image<f32>>,
}

/// The bundled synthetic Kinect v2 scene (`geometry::synth::kinect_preset` with noise):
/// the IR pane shows its simulated amplitude.
pub fn demo_frame() -> Frame {
    let setup = synth::kinect_preset(true);
    let frame = synth::render(&setup);
    Frame {
        name: "synthetic Kinect v2 scene".into(),
        rig: setup.rig,
        depth: frame.depth,
        kind: frame.depth_kind,
        color: frame.color,
        ir: Some(frame.amplitude),
    }
}

/// Opens a `kfuse fuse` output folder or a capture folder (see the module docs); a rig that
/// fails the plausibility check is refused, as by `kfuse fuse` ([`open_folder_with`]).
pub fn open_folder(dir: &Path) -> Result<Frame, ViewerError> {
    open_folder_with(dir, false).map(|(frame, _)| frame)
}

/// [`open_folder`], with the rig plausibility check of `kfuse fuse` ([`Rig::check_plausible`]:
/// focal lengths in pixels, image sides, baseline). Without `force` an implausible rig file is
/// refused (the error names it and `--force`); with `force` it is used and its problems come
/// back as warnings, one line each. A `synthdata.mat` (course data) is not checked, as in
/// `kfuse fuse --mat`: its importer converts the course's units itself.
pub fn open_folder_with(dir: &Path, force: bool) -> Result<(Frame, Vec<String>), ViewerError> {
    open_folder_shot(dir, force, None)
}

/// [`open_folder_with`]; `shot` picks the shot of a `kfuse capture` folder by name: a scene's
/// `NAME` (`NAME_color.jpg`, `NAME_depth.png`) or a calibration shot's number `NNNN`
/// (`color_NNNN.jpg`, `depth_NNNN.png`). A name the folder does not hold, or a shot asked of
/// another kind of folder, is an error that lists the shots there are.
pub fn open_folder_shot(
    dir: &Path,
    force: bool,
    shot: Option<&str>,
) -> Result<(Frame, Vec<String>), ViewerError> {
    if !dir.is_dir() {
        return Err(ViewerError::NotAFolder { path: dir.to_path_buf() });
    }
    let is_capture = dir.join("kinect_params.json").exists();
    if let (Some(shot), false) = (shot, is_capture) {
        return Err(ViewerError::UnknownShot {
            path: dir.to_path_buf(),
            shot: shot.to_string(),
            shots: "none: shots are picked in a `kfuse capture` folder (kinect_params.json)".into(),
        });
    }
    let summary = dir.join("summary.json");
    if summary.is_file() {
        return open_fuse_output(dir, &summary, force);
    }
    if is_capture {
        return open_kfuse_capture(dir, force, shot);
    }
    if dir.join("rig.json").exists() {
        return open_capture(dir, force);
    }
    Err(ViewerError::UnknownFolder { path: dir.to_path_buf() })
}

/// Reads a rig file and applies [`Rig::check_plausible`], or with `force` returns its problems
/// as warnings.
fn load_rig_for_view(path: &Path, force: bool) -> Result<(Rig, Vec<String>), ViewerError> {
    let rig = rigio::read_rig(path).and_then(|r| r.into_pair(path)).map_err(|e| bad(path, e))?;
    check_rig(rig, path, force)
}

/// [`Rig::check_plausible`] on a rig read from `path`, or with `force` its problems as warnings.
fn check_rig(rig: Rig, path: &Path, force: bool) -> Result<(Rig, Vec<String>), ViewerError> {
    if force {
        let warnings = rig
            .plausibility_problems()
            .into_iter()
            .map(|p| format!("{}: {p} (--force)", path.display()))
            .collect();
        return Ok((rig, warnings));
    }
    rig.check_plausible().map_err(|e| ViewerError::BadFile {
        path: path.to_path_buf(),
        message: format!(
            "{e}; fix the rig, or pass --force (kfuse view --force DIR) if it really is meant this way"
        ),
    })?;
    Ok((rig, Vec::new()))
}

fn bad(path: &Path, e: GeometryError) -> ViewerError {
    ViewerError::BadFile { path: path.to_path_buf(), message: e.to_string() }
}

fn require(path: PathBuf, hint: &str) -> Result<PathBuf, ViewerError> {
    if path.is_file() {
        Ok(path)
    } else {
        Err(ViewerError::MissingFile { path, hint: hint.into() })
    }
}

fn check_size(
    path: &Path,
    camera: &'static str,
    got: (usize, usize),
    want: (usize, usize),
) -> Result<(), ViewerError> {
    if got == want {
        return Ok(());
    }
    Err(ViewerError::SizeMismatch {
        path: path.to_path_buf(),
        camera,
        got_w: got.0,
        got_h: got.1,
        want_w: want.0,
        want_h: want.1,
    })
}

/// The frame of a rig (read by [`load_rig_for_view`], with its warnings) and its image files.
fn load(
    name: String,
    (mut rig, warnings): (Rig, Vec<String>),
    color_path: &Path,
    depth_path: &Path,
    scale: f64,
    kind: DepthKind,
    ir_path: Option<&Path>,
) -> Result<(Frame, Vec<String>), ViewerError> {
    if rig.rectified {
        // Already undistorted images: fused as by `kfuse fuse --rectified`.
        rig = rig.as_rectified();
    }
    let color = images::read_color(color_path).map_err(|e| bad(color_path, e))?;
    check_size(color_path, "colour", color.size(), (rig.color.width, rig.color.height))?;
    // As read: the rig's depth correction is the fusion request's depth preparation
    // (`geometry::fusion::Request`, applied by the pipeline as `kfuse fuse` applies it).
    let depth = images::read_depth(depth_path, scale).map_err(|e| bad(depth_path, e))?;
    check_size(depth_path, "depth", depth.size(), (rig.depth.width, rig.depth.height))?;
    let ir = match ir_path {
        Some(p) => {
            let ir = images::read_depth(p, 1.0).map_err(|e| bad(p, e))?;
            check_size(p, "depth (IR)", ir.size(), (rig.depth.width, rig.depth.height))?;
            Some(ir)
        }
        None => None,
    };
    Ok((Frame { name, rig, depth, kind, color, ir }, warnings))
}

fn open_capture(dir: &Path, force: bool) -> Result<(Frame, Vec<String>), ViewerError> {
    const HINT: &str = "a capture folder holds rig.json, color.png and depth.png (16-bit mm), as `kfuse demo` writes into input/";
    let rig = require(dir.join("rig.json"), HINT)?;
    let color = require(dir.join("color.png"), HINT)?;
    let depth = require(dir.join("depth.png"), HINT)?;
    let ir = dir.join("ir.png");
    let ir = ir.is_file().then_some(ir);
    load(
        dir.display().to_string(),
        load_rig_for_view(&rig, force)?,
        &color,
        &depth,
        images::MILLIMETRES,
        DepthKind::Z,
        ir.as_deref(),
    )
}

/// At most this many folder entries are looked at for shots: far more than a capture session
/// writes (3 files a shot), and a bound on a folder that is not one.
const MAX_FOLDER_ENTRIES: usize = 1_000_000;

/// One complete shot of a capture folder: its name, whether it is a scene shot (else a
/// calibration shot), and its colour, depth and IR files.
type Shot = (String, bool, [PathBuf; 3]);

/// Every complete shot of a capture folder, sorted by name within each kind: scenes first,
/// then calibration shots (names as `kfuse_capture::shot_files`).
fn shots_in(dir: &Path) -> Result<Vec<Shot>, ViewerError> {
    use kfuse_capture::{ShotKind, shot_files};
    let entries = std::fs::read_dir(dir)
        .map_err(|e| ViewerError::BadFile { path: dir.into(), message: e.to_string() })?;
    let names: Vec<String> = entries
        .take(MAX_FOLDER_ENTRIES)
        .flatten()
        .filter_map(|e| e.file_name().into_string().ok())
        .collect();
    let complete = |name: &str, kind: ShotKind| {
        let [color, ir, depth] = shot_files(dir, name, kind);
        let scene = kind == ShotKind::Scene;
        (color.is_file() && depth.is_file()).then(|| (name.to_string(), scene, [color, depth, ir]))
    };
    let of_kind = |kind: ShotKind, shot_name: fn(&str) -> Option<&str>| {
        let mut shots: Vec<&str> = names.iter().filter_map(|n| shot_name(n)).collect();
        shots.sort_unstable();
        shots.into_iter().filter_map(|n| complete(n, kind)).collect::<Vec<_>>()
    };
    let mut all =
        of_kind(ShotKind::Scene, |n| n.strip_suffix("_depth.png").filter(|s| !s.is_empty()));
    all.extend(of_kind(ShotKind::Calib, |n| {
        n.strip_prefix("depth_").and_then(|s| s.strip_suffix(".png"))
    }));
    Ok(all)
}

/// The shot [`open_kfuse_capture`] shows: `wanted` by name, else the last scene shot by name,
/// else the last calibration shot.
fn pick_shot(dir: &Path, wanted: Option<&str>) -> Result<Option<Shot>, ViewerError> {
    let shots = shots_in(dir)?;
    let Some(wanted) = wanted else {
        let last_scene = shots.iter().rfind(|s| s.1).cloned();
        return Ok(last_scene.or_else(|| shots.last().cloned()));
    };
    if let Some(found) = shots.iter().find(|s| s.0 == wanted) {
        return Ok(Some(found.clone()));
    }
    /// At most this many shot names are listed in the error.
    const LISTED: usize = 20;
    let mut list: Vec<&str> = shots.iter().map(|s| s.0.as_str()).take(LISTED).collect();
    if shots.len() > LISTED {
        list.push("…");
    }
    Err(ViewerError::UnknownShot {
        path: dir.to_path_buf(),
        shot: wanted.to_string(),
        shots: if list.is_empty() { "none".into() } else { list.join(", ") },
    })
}

/// A `kfuse capture` folder (module docs).
fn open_kfuse_capture(
    dir: &Path,
    force: bool,
    wanted: Option<&str>,
) -> Result<(Frame, Vec<String>), ViewerError> {
    let Some((shot, _, [color, depth, ir])) = pick_shot(dir, wanted)? else {
        return Err(ViewerError::NoShot { path: dir.to_path_buf() });
    };
    let rig_path = dir.join("rig.json");
    let rig = if rig_path.is_file() {
        load_rig_for_view(&rig_path, force)?
    } else {
        let params = dir.join("kinect_params.json");
        check_rig(factory_rig(&params)?, &params, force)?
    };
    let ir = ir.is_file().then_some(ir);
    load(
        format!("{} ({shot})", dir.display()),
        rig,
        &color,
        &depth,
        images::MILLIMETRES,
        DepthKind::Z,
        ir.as_deref(),
    )
}

/// The rig fitted to the factory parameters in `kinect_params.json`.
fn factory_rig(path: &Path) -> Result<Rig, ViewerError> {
    use kfuse_io::rig_io::{kinect::FactoryParams, yaml::read_text};
    let file_err = |e: GeometryError| match e {
        GeometryError::Format { path, message } => ViewerError::BadFile { path, message },
        e => ViewerError::BadFile { path: path.to_path_buf(), message: e.to_string() },
    };
    let text = read_text(path).map_err(file_err)?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| ViewerError::BadFile {
        path: path.into(),
        message: format!("not valid JSON ({e}); it is written by `kfuse capture`"),
    })?;
    let fit = FactoryParams::from_json(&v, path).and_then(|p| p.to_rig()).map_err(file_err)?;
    Ok(fit.rig)
}

/// Resolves an input path recorded in summary.json (see the module docs).
fn resolve(dir: &Path, recorded: &str, summary: &Path) -> Result<PathBuf, ViewerError> {
    let p = PathBuf::from(recorded);
    let mut tries = vec![p.clone()];
    if p.is_relative()
        && let Some(parent) = dir.parent()
    {
        tries.push(parent.join(&p));
    }
    if let Some(name) = p.file_name() {
        tries.push(dir.join(name));
    }
    tries.into_iter().find(|t| t.is_file()).ok_or_else(|| ViewerError::MissingFile {
        path: p,
        hint: format!(
            "{} names it as an input of the fusion; restore it or re-run `kfuse fuse`",
            summary.display()
        ),
    })
}

fn open_fuse_output(
    dir: &Path,
    summary: &Path,
    force: bool,
) -> Result<(Frame, Vec<String>), ViewerError> {
    let text = std::fs::read_to_string(summary)
        .map_err(|e| ViewerError::BadFile { path: summary.into(), message: e.to_string() })?;
    let json: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| ViewerError::BadFile {
            path: summary.into(),
            message: format!("not valid JSON ({e}); re-run `kfuse fuse`"),
        })?;
    let inputs = json.get("inputs").ok_or_else(|| ViewerError::BadFile {
        path: summary.into(),
        message: "no \"inputs\" entry; it was not written by `kfuse fuse`".into(),
    })?;
    let field = |k: &str| inputs.get(k).and_then(|v| v.as_str());
    let name = dir.display().to_string();
    let scale = inputs
        .get("depth_scale_m_per_unit")
        .and_then(|v| v.as_f64())
        .unwrap_or(images::MILLIMETRES);
    let rectified = inputs.get("rectified").and_then(|v| v.as_bool()) == Some(true);
    if let Some(mat) = field("mat") {
        let mat = resolve(dir, mat, summary)?;
        // `--color` / `--depth` of `kfuse fuse --mat` replaced the file's images.
        let color = field("color").map(|p| resolve(dir, p, summary)).transpose()?;
        let depth = field("depth").map(|p| resolve(dir, p, summary)).transpose()?;
        let overrides = MatOverrides { color: color.as_deref(), depth: depth.as_deref(), scale };
        let (mut frame, warnings) = open_mat(name, &mat, overrides, force)?;
        if rectified {
            frame.rig = frame.rig.as_rectified();
        }
        return Ok((frame, warnings));
    }
    let (Some(rig), Some(color), Some(depth)) = (field("rig"), field("color"), field("depth"))
    else {
        return Err(ViewerError::BadFile {
            path: summary.into(),
            message: "\"inputs\" lacks rig, color or depth; re-run `kfuse fuse`".into(),
        });
    };
    let kind = match field("depth_kind") {
        Some("range") => DepthKind::Range,
        _ => DepthKind::Z,
    };
    let (rig, color, depth) =
        (resolve(dir, rig, summary)?, resolve(dir, color, summary)?, resolve(dir, depth, summary)?);
    let (mut rig, warnings) = load_rig_for_view(&rig, force)?;
    // `kfuse fuse --rectified` records it among the inputs.
    rig.rectified |= rectified;
    load(name, (rig, warnings), &color, &depth, scale, kind, None)
}

/// The images of `kfuse fuse --mat FILE --color C --depth D` that replaced the file's own,
/// as its summary.json records them, and the depth file's metres per unit.
struct MatOverrides<'a> {
    color: Option<&'a Path>,
    depth: Option<&'a Path>,
    scale: f64,
}

/// The frame `kfuse fuse --mat` fused: the course's `synthdata.mat` or the lab's
/// `KinectData.mat` (told apart as `fuse` does, `kinect_data::is_kinect_data`), with the
/// colour and depth files that replaced the file's images. A `KinectData.mat` rig gets the
/// plausibility check of a rig file (as in `fuse`); its 8-bit `Depth` (not measurements) is
/// refused unless a depth file replaced it.
fn open_mat(
    name: String,
    mat: &Path,
    overrides: MatOverrides<'_>,
    force: bool,
) -> Result<(Frame, Vec<String>), ViewerError> {
    let file = MatFile::read(mat).map_err(|e| bad(mat, e))?;
    let (rig, color, file_depth, kind, warnings) = if kinect_data::is_kinect_data(&file) {
        let kd = kinect_data::kinect_data_from_mat(&file).map_err(|e| bad(mat, e))?;
        let (rig, warnings) = check_rig(kd.rig, mat, force)?;
        let depth = match kd.depth {
            KinectDepth::Millimetres(d) => Ok(d),
            KinectDepth::Unusable(why) => Err(why),
        };
        (rig, kd.color, depth, DepthKind::Z, warnings)
    } else {
        let data = course::course_from_mat(&file, course::CourseConvention::SYNTHDATA)
            .map_err(|e| bad(mat, e))?;
        (data.rig, data.color, Ok(data.depth), data.depth_kind, Vec::new())
    };
    let color = match overrides.color {
        Some(p) => {
            let c = images::read_color(p).map_err(|e| bad(p, e))?;
            check_size(p, "colour", c.size(), (rig.color.width, rig.color.height))?;
            c
        }
        None => color,
    };
    let depth = match (overrides.depth, file_depth) {
        (Some(p), _) => {
            let d = images::read_depth(p, overrides.scale).map_err(|e| bad(p, e))?;
            check_size(p, "depth", d.size(), (rig.depth.width, rig.depth.height))?;
            d
        }
        (None, Ok(d)) => d,
        (None, Err(why)) => {
            return Err(ViewerError::BadFile {
                path: mat.to_path_buf(),
                message: format!(
                    "{why}; `kfuse fuse` needs --depth for it, and this output's summary.json names no depth file: re-run `kfuse fuse --mat … --depth FILE`"
                ),
            });
        }
    };
    Ok((Frame { name, rig, depth, kind, color, ir: None }, warnings))
}
