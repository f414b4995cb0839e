//! Rig and camera files of other tools: import into kfuse's rig JSON, export to OpenCV and
//! ROS, and a readable description with sanity checks (`kfuse rig import|export|show`).
//!
//! | source | module | gives |
//! | --- | --- | --- |
//! | Bouguet `Calib_Results_stereo.mat` (+ `_left`, `_right`) | [`crate::bouguet`] | rig |
//! | Bouguet `Calib_Results_left.mat` / `_right.mat` / `Calib_Results.mat` | [`crate::bouguet`] | one camera |
//! | the lab's `KinectData.mat`, the course's `synthdata.mat` | `kfuse_io::course` | rig |
//! | OpenCV FileStorage YAML (`stereoCalibrate` names, `kfuse calibrate --opencv-yaml`) | [`opencv`] | rig or one camera |
//! | ROS `camera_info` YAML (one file per camera) | [`ros`] | rig (pair) or one camera |
//! | iai_kinect2's folder (`calib_color.yaml`, `calib_ir.yaml`, `calib_pose.yaml`, `calib_depth.yaml`), or its files | [`iai`] | rig (with its depth shift), or one camera |
//! | `kinect_params.json` (`kfuse capture`: the sensor's factory parameters) | [`kinect`] | rig (fitted, see there) |
//! | kfuse rig JSON (two cameras or several), kfuse single-camera JSON | [`crate::rig::read_rig`] | rig or one camera |
//!
//! The format is recognised from the content (MATLAB header, JSON `format` field, YAML keys),
//! not from the file name (a folder is read as iai_kinect2's, whose file names are fixed by
//! `kinect2_bridge`). JSON with a key repeated in one object is refused
//! ([`geometry::rig::duplicate_key`]), as one with an unknown key.

pub mod iai;
pub mod kinect;
pub mod opencv;
pub mod ros;
pub mod show;
pub mod yaml;

use std::path::{Path, PathBuf};

use crate::mat::MatFile;
use geometry::GeometryError;
use geometry::{CameraModel, Rig};
use serde_json::{Value, json};

use yaml::{fmt_err, read_text};

/// The value of the `format` field of a single-camera file (`kfuse calibrate --ir … --out`).
pub const CAMERA_FORMAT: &str = "kfuse-camera";
/// The value of the `format` field of `kinect_params.json`.
pub const KINECT_PARAMS_FORMAT: &str = "kfuse-kinect-params";

/// Which camera of the rig a single camera is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// The depth (IR) camera, the rig's reference.
    Depth,
    /// The colour camera.
    Color,
}

impl Role {
    /// The name used in files and on the command line (`depth`, `color`).
    pub fn name(self) -> &'static str {
        match self {
            Role::Depth => "depth",
            Role::Color => "color",
        }
    }

    /// Parses `depth`/`ir` or `color`/`colour`.
    pub fn parse(s: &str) -> Option<Role> {
        match s.to_ascii_lowercase().as_str() {
            "depth" | "ir" => Some(Role::Depth),
            "color" | "colour" | "rgb" => Some(Role::Color),
            _ => None,
        }
    }
}

/// What a calibration file holds: a rig, or one camera.
// A rig (two cameras, a transform, its report and depth correction) is larger than one
// camera; a file holds one value read once per command, so boxing it would only add noise to
// every match.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Calibration {
    /// Both cameras and `color_from_depth`.
    Rig(Rig),
    /// One camera; `role` says which, where the file says it.
    Camera {
        /// The camera.
        camera: CameraModel,
        /// Which camera it is.
        role: Option<Role>,
        /// Report or provenance kept verbatim (`calibration` field).
        report: Option<Value>,
    },
}

impl Calibration {
    /// The camera `role` of a rig, or the single camera (an error names `source` when the
    /// file's camera is the other one).
    pub fn camera(&self, role: Role, source: &Path) -> Result<CameraModel, GeometryError> {
        match self {
            Calibration::Rig(rig) => Ok(if role == Role::Depth { rig.depth } else { rig.color }),
            Calibration::Camera { camera, role: Some(r), .. } if *r != role => Err(fmt_err(
                source,
                format!(
                    "this single-camera file holds the {} camera, not the {} camera; pass --camera {}",
                    r.name(),
                    role.name(),
                    r.name()
                ),
            )),
            Calibration::Camera { camera, .. } => Ok(*camera),
        }
    }

    /// What makes the file's cameras (and baseline) implausible for a real camera, each naming
    /// the likely unit mistake ([`Rig::plausibility_problems`]); empty when plausible.
    pub fn plausibility_problems(&self) -> Vec<String> {
        match self {
            Calibration::Rig(rig) => rig.plausibility_problems(),
            Calibration::Camera { camera, role, .. } => {
                geometry::rig::camera_plausibility_problems(
                    role.map(Role::name).unwrap_or("single"),
                    camera,
                )
            }
        }
    }

    /// The file text in kfuse's format (rig JSON or single-camera JSON).
    pub fn to_json(&self) -> String {
        match self {
            Calibration::Rig(rig) => rig.to_json(),
            Calibration::Camera { camera, role, report } => camera_file_json(camera, *role, report),
        }
    }
}

/// A single-camera file (`format: kfuse-camera`, the layout `kfuse calibrate` writes).
pub fn camera_file_json(
    camera: &CameraModel,
    role: Option<Role>,
    report: &Option<Value>,
) -> String {
    let mut v = json!({
        "format": CAMERA_FORMAT, "version": 1,
        "units": "intrinsics in pixels",
        "camera": camera,
    });
    if let Some(r) = role {
        v["role"] = json!(r.name());
    }
    if let Some(rep) = report {
        v["calibration"] = rep.clone();
    }
    serde_json::to_string_pretty(&v).unwrap_or_default()
}

/// A kfuse rig file of any kind, told apart by its content: what [`crate::rig::read_rig`], the
/// one reader of kfuse's rig and camera files, gives.
#[derive(Debug, Clone)]
pub enum AnyRig {
    /// A rig of several cameras (version 2).
    Multi(geometry::MultiRig),
    /// A two-camera rig or a camera file.
    Single(Box<Calibration>),
}

impl AnyRig {
    /// The depth + colour pair; a single-camera file or a rig of several cameras is refused,
    /// naming `path` and how to get a pair.
    pub fn into_pair(self, path: &Path) -> Result<Rig, GeometryError> {
        match self.into_calibration(path)? {
            Calibration::Rig(rig) => Ok(rig),
            Calibration::Camera { role, .. } => {
                let which = role.map(|r| format!(" (the {} camera)", r.name())).unwrap_or_default();
                Err(fmt_err(
                    path,
                    format!(
                        "this is a single-camera file{which}; this needs both cameras and color_from_depth: \
                         calibrate the pair with `kfuse calibrate --ir 'ir_*.png' --color 'color_*.png' --out rig.json`, \
                         or make a rig from the lab's files with `kfuse rig import Calib_Results_stereo.mat --out rig.json`"
                    ),
                ))
            }
        }
    }

    /// A two-camera rig or one camera; a rig of several cameras is refused, naming `path` and
    /// how to pick one sensor's pair.
    pub fn into_calibration(self, path: &Path) -> Result<Calibration, GeometryError> {
        match self {
            AnyRig::Single(c) => Ok(*c),
            AnyRig::Multi(multi) => {
                Err(fmt_err(path, geometry::multi_rig::not_a_pair_message(multi.cameras.len())))
            }
        }
    }

    /// The rig of several cameras, or `None` for a pair or a camera file.
    pub fn into_multi(self) -> Option<geometry::MultiRig> {
        match self {
            AnyRig::Multi(multi) => Some(multi),
            AnyRig::Single(_) => None,
        }
    }
}

/// Parses the text of a kfuse rig file of either kind (see [`crate::rig::read_rig`]).
pub(crate) fn any_from_text(text: &str, path: &Path) -> Result<AnyRig, GeometryError> {
    match multi_from_text(text, path)? {
        Some(multi) => Ok(AnyRig::Multi(multi)),
        None => Ok(AnyRig::Single(Box::new(from_kfuse_json(text, path)?))),
    }
}

fn multi_from_text(text: &str, path: &Path) -> Result<Option<geometry::MultiRig>, GeometryError> {
    let Ok(v) = serde_json::from_str::<Value>(text) else { return Ok(None) };
    if !geometry::multi_rig::is_multi_rig_json(&v) {
        return Ok(None);
    }
    Ok(Some(geometry::MultiRig::from_json(text, path)?))
}

fn from_kfuse_json(text: &str, path: &Path) -> Result<Calibration, GeometryError> {
    let v: Value = serde_json::from_str(text).map_err(|e| {
        fmt_err(
            path,
            format!(
                "not a kfuse rig or camera file ({e}); create one with `kfuse calibrate` or `kfuse rig import`"
            ),
        )
    })?;
    if let Some(repeated) = geometry::rig::duplicate_key(text) {
        return Err(fmt_err(path, repeated));
    }
    match v.get("format").and_then(Value::as_str) {
        Some(CAMERA_FORMAT) => {
            if v.get("version").and_then(Value::as_u64).unwrap_or(0) > 1 {
                return Err(fmt_err(
                    path,
                    "camera file version is newer than this kfuse; upgrade kfuse",
                ));
            }
            if let Some(unknown) =
                geometry::rig::unknown_keys(&v["camera"], "camera", &geometry::rig::CAMERA_KEYS)
                    .first()
            {
                return Err(fmt_err(path, unknown.clone()));
            }
            let camera: CameraModel = serde_json::from_value(v["camera"].clone())
                .map_err(|e| fmt_err(path, format!("'camera': {e}")))?;
            camera.validate().map_err(|e| fmt_err(path, e.to_string()))?;
            let role = match v.get("role").and_then(Value::as_str) {
                None => None,
                Some(r) => Some(Role::parse(r).ok_or_else(|| {
                    fmt_err(path, format!("'role' is '{r}', expected 'depth' or 'color'"))
                })?),
            };
            Ok(Calibration::Camera { camera, role, report: v.get("calibration").cloned() })
        }
        Some(KINECT_PARAMS_FORMAT) => Err(fmt_err(
            path,
            "this is the sensor's factory parameters, not a rig; turn it into one with `kfuse rig import`",
        )),
        _ => Ok(Calibration::Rig(Rig::from_json(text, path)?)),
    }
}

/// A length unit for translations read from files that do not state theirs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LengthUnit {
    /// Metres.
    Metres,
    /// Millimetres.
    Millimetres,
}

impl LengthUnit {
    /// Metres per unit.
    pub fn to_metres(self) -> f64 {
        match self {
            LengthUnit::Metres => 1.0,
            LengthUnit::Millimetres => 1e-3,
        }
    }

    /// Parses `m` or `mm`.
    pub fn parse(s: &str) -> Option<LengthUnit> {
        match s.trim() {
            "m" | "metres" | "meters" => Some(LengthUnit::Metres),
            "mm" | "millimetres" | "millimeters" => Some(LengthUnit::Millimetres),
            _ => None,
        }
    }
}

/// Options of [`import`] for what a file may not say.
#[derive(Debug, Clone, Default)]
pub struct ImportOptions {
    /// Unit of `T` in OpenCV files without `T_units`.
    pub t_units: Option<LengthUnit>,
    /// Depth camera image size for files that do not store it.
    pub depth_size: Option<(usize, usize)>,
    /// Colour camera image size for files that do not store it.
    pub color_size: Option<(usize, usize)>,
    /// Which camera a single-camera source is.
    pub role: Option<Role>,
}

/// The result of [`import`].
#[derive(Debug, Clone)]
pub struct Imported {
    /// The rig or camera.
    pub calibration: Calibration,
    /// What the source was, in words ("Bouguet stereo calibration").
    pub source: String,
    /// Facts the user should know (approximations made, values assumed), one line each.
    pub notes: Vec<String>,
}

fn imported(calibration: Calibration, source: &str, notes: Vec<String>) -> Imported {
    Imported { calibration, source: source.into(), notes }
}

/// Imports a rig or camera from `sources` (see the module table). Several files are needed
/// for a Bouguet stereo result (`stereo.mat [left.mat right.mat]`; left and right default to
/// the files beside it), a ROS pair (`depth.yaml color.yaml`, in that order), an OpenCV
/// calibration split over files (`intrinsics.yml extrinsics.yml`) and iai_kinect2's files
/// given one by one (any order); a folder is iai_kinect2's calibration folder.
pub fn import(sources: &[PathBuf], opts: &ImportOptions) -> Result<Imported, GeometryError> {
    let first = sources
        .first()
        .ok_or_else(|| GeometryError::InvalidInput("no calibration file given to import".into()))?;
    if first.is_dir() {
        expect_count(sources, 1, "a calibration folder")?;
        if !iai::is_iai_dir(first) {
            return Err(fmt_err(
                first,
                format!(
                    "is a folder without a calibration kfuse reads: a folder is read as iai_kinect2's ({}), and none of those files is in it; give the calibration file itself",
                    iai::FILES.join(", ")
                ),
            ));
        }
        return iai::import_dir(first, opts);
    }
    // A pipe or a FIFO gives its bytes once: read it whole (a text format; a MATLAB file is
    // binary and refused by read_text) instead of sniffing its head and opening it again.
    let piped = std::fs::metadata(first).is_ok_and(|m| !m.is_file());
    let text_once = if piped { Some(read_text(first)?) } else { None };
    let head = match &text_once {
        Some(text) => text.as_bytes()[..text.len().min(128)].to_vec(),
        None => {
            use std::io::Read;
            let mut buf = [0u8; 128];
            let n = bounded_read::open_without_blocking(first)
                .and_then(|mut f| f.read(&mut buf))
                .map_err(|source| GeometryError::Io { path: first.clone(), source })?;
            buf[..n].to_vec()
        }
    };
    if head.starts_with(b"MATLAB") {
        return import_mat(sources, opts);
    }
    let text = match text_once {
        Some(text) => text,
        None => read_text(first)?,
    };
    let trimmed = text.trim_start_matches('\u{feff}').trim_start();
    // Bouguet's toolbox saves its results twice: Calib_Results*.mat (read here) and a MATLAB
    // script of the same name, .m, whose lines start with '%' comments and `fc = [ … ];`.
    if first.extension().is_some_and(|e| e == "m") && trimmed.starts_with('%') {
        let mat = first.with_extension("mat");
        return Err(fmt_err(
            first,
            format!(
                "is the Bouguet toolbox's MATLAB script, which kfuse does not run; give the .mat file it saved beside it ({})",
                mat.display()
            ),
        ));
    }
    if trimmed.starts_with('{') {
        expect_count(sources, 1, "a JSON file")?;
        return import_json(&text, first);
    }
    if trimmed.starts_with("<?xml") || trimmed.starts_with("<opencv_storage") {
        return Err(fmt_err(
            first,
            "OpenCV XML FileStorage is not supported; save the calibration as .yml (cv::FileStorage writes YAML for that name)",
        ));
    }
    let docs = sources.iter().map(|p| yaml::Doc::read(p)).collect::<Result<Vec<_>, _>>()?;
    if docs.iter().any(iai::is_iai) {
        return iai::import_docs(docs, opts);
    }
    if ros::is_camera_info(&docs[0]) {
        return ros::import(&docs, opts);
    }
    opencv::import(docs, opts)
}

fn expect_count(sources: &[PathBuf], max: usize, what: &str) -> Result<(), GeometryError> {
    if sources.len() > max {
        return Err(fmt_err(
            &sources[max],
            format!(
                "{} is {what}; give it alone (found {} files)",
                sources[0].display(),
                sources.len()
            ),
        ));
    }
    Ok(())
}

fn import_json(text: &str, path: &Path) -> Result<Imported, GeometryError> {
    let v: Value =
        serde_json::from_str(text).map_err(|e| fmt_err(path, format!("not valid JSON ({e})")))?;
    if let Some(repeated) = geometry::rig::duplicate_key(text) {
        return Err(fmt_err(path, repeated));
    }
    if v.get("format").and_then(Value::as_str) == Some(KINECT_PARAMS_FORMAT) {
        let params = kinect::FactoryParams::from_json(&v, path)?;
        let fit = params.to_rig()?;
        let mut notes = vec![fit.summary()];
        if !params.scene_orientation {
            notes.push(
                "these are the parameters of mirrored images (kinect_params.json version 1: \
                 `kfuse capture` before it wrote images as the scene is), and so is the rig: \
                 it fits that capture's images; `--mirror` gives the rig of images as the scene is"
                    .into(),
            );
        }
        let mut rig = fit.rig;
        rig.calibration = Some(fit.report);
        return Ok(imported(Calibration::Rig(rig), "Kinect v2 factory parameters", notes));
    }
    let c = from_kfuse_json(text, path)?;
    Ok(imported(c, "kfuse calibration file", vec![]))
}

fn import_mat(sources: &[PathBuf], opts: &ImportOptions) -> Result<Imported, GeometryError> {
    let path = &sources[0];
    let m = MatFile::read(path)?;
    let has = |n: &str| m.get(n).is_some();
    if has("Dparam") && has("Cparam") {
        expect_count(sources, 1, "a course file")?;
        // synthdata.mat's Dparam has fx too (beside fp): fp decides.
        if crate::kinect_data::is_kinect_data(&m) {
            let kd = crate::course::read_kinect_data(path)?;
            let (w, h) = (kd.rig.depth.width, kd.rig.depth.height);
            // The depth camera's size is its 'Depth' image's when that holds millimetres; a
            // broken 8-bit one is not trusted and the Kinect v2's size is used instead.
            let size_from = match kd.depth {
                crate::kinect_data::KinectDepth::Millimetres(_) => "the size of its 'Depth'",
                crate::kinect_data::KinectDepth::Unusable(_) => {
                    "the Kinect v2's size: its 'Depth' is not depth measurements"
                }
            };
            return Ok(imported(
                Calibration::Rig(kd.rig),
                "the lab's KinectData.mat",
                vec![
                    format!(
                        "KinectData.mat stores no distortion (its colour image is rectified): both cameras have none; depth camera {w}x{h} ({size_from})"
                    ),
                    "R, T read as Bouguet's X_color = R·X_depth + T with T in millimetres".into(),
                ],
            ));
        }
        let cd = crate::course::read_course(path)?;
        return Ok(imported(
            Calibration::Rig(cd.rig),
            "the course's synthdata.mat",
            vec!["synthdata.mat conventions: 1-based cx, cy; R, T the colour camera's pose in the depth frame (kfuse_io::course)".into()],
        ));
    }
    if has("fc_left") && has("fc_right") {
        expect_count(sources, 3, "a Bouguet stereo result (stereo.mat [left.mat right.mat])")?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let (left, right) = match sources {
            [_, l, r] => (l.clone(), r.clone()),
            [_] => (dir.join("Calib_Results_left.mat"), dir.join("Calib_Results_right.mat")),
            _ => {
                return Err(fmt_err(
                    path,
                    "give both mono results after the stereo file (stereo.mat left.mat right.mat), or neither",
                ));
            }
        };
        for f in [&left, &right] {
            if !f.is_file() {
                return Err(fmt_err(
                    f,
                    format!(
                        "not found; Bouguet's stereo file stores one image size, so the mono results (Calib_Results_left.mat, Calib_Results_right.mat) are read for both sizes: put them beside {} or name them after it",
                        path.display()
                    ),
                ));
            }
        }
        let rig = crate::bouguet::import_stereo(path, &left, &right)?;
        return Ok(imported(
            Calibration::Rig(rig),
            "Bouguet stereo calibration",
            vec![
                "left = depth/IR camera, right = colour camera; T converted from millimetres"
                    .into(),
            ],
        ));
    }
    if has("fc") && has("nx") {
        expect_count(sources, 1, "a Bouguet single-camera result")?;
        let cam = crate::bouguet::import_mono(path)?;
        let role = opts.role.ok_or_else(|| {
            fmt_err(path, "holds one camera; say which with --camera depth or --camera color")
        })?;
        let report = json!({"source": "Bouguet Camera Calibration Toolbox", "file": path.display().to_string(),
                            "err_std_px": cam.err_std_px.map(|e| [e.x, e.y])});
        return Ok(imported(
            Calibration::Camera { camera: cam.camera, role: Some(role), report: Some(report) },
            "Bouguet single-camera calibration",
            vec![],
        ));
    }
    Err(fmt_err(
        path,
        "not a calibration MATLAB file this importer knows (expected Bouguet's Calib_Results*.mat with fc/kc, or the lab's KinectData.mat with Dparam/Cparam)",
    ))
}
