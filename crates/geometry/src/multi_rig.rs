//! Rigs of any number of cameras (several Kinects, extra plain cameras): each camera's model,
//! role, sensor and pose in one reference frame, and the rig file's version 2.
//!
//! Convention, written once: every camera's pose is `camera_from_reference`,
//! `X_camera = R · X_reference + T` (metres), the same direction as the two-camera rig's
//! `color_from_depth`. The reference is one named camera of the rig (its pose is the
//! identity); by default the first depth camera.
//!
//! A rig that is one depth + colour pair is written as the two-camera file of [`crate::rig`]
//! (version 1), unchanged, so every existing file and command keeps working; any other rig is
//! written as version 2:
//!
//! ```json
//! {
//!   "format": "kfuse-rig", "version": 2,
//!   "units": "lengths in metres, intrinsics in pixels, rotations as row-major matrices",
//!   "reference": "A.depth",
//!   "cameras": [
//!     { "name": "A.depth", "role": "depth", "sensor": "A",
//!       "width": 512, "height": 424, "fx": ..., ... "k3": ...,
//!       "camera_from_reference": { "rotation": [[...],[...],[...]], "translation_m": [x, y, z] },
//!       "depth_correction": { ... }   (optional, depth cameras only) },
//!     ...
//!   ],
//!   "calibration": { ... optional report ... },
//!   "rectified": false   (optional)
//! }
//! ```

use serde::{Deserialize, Serialize};

use crate::depth_correction::{DepthCorrection, DepthCorrectionFile};
use crate::rig::{
    CAMERA_KEYS, RIG_FORMAT, camera_plausibility_problems, duplicate_key, unknown_keys,
};
use crate::{CameraModel, GeometryError, Rig, RigidTransform};

/// The rig file version that holds N cameras.
pub const MULTI_RIG_VERSION: u32 = 2;

/// Most cameras one rig file may hold: 64. The largest rigs in the field (LiveScan3D rooms,
/// light stages of Kinects) have 8–16 sensors of two cameras each; a larger count read from a
/// file is a mistake, and each camera costs the fusion a full image.
pub const MAX_RIG_CAMERAS: usize = 64;

/// Longest name of a camera or sensor, characters: 64 (a serial number is 12 digits; a name
/// is shown in tables and used in folder names).
pub const MAX_NAME_CHARS: usize = 64;

/// Largest distance of a camera from the reference, metres: 50. A room-sized rig spans under
/// 20 m; a translation in millimetres reads as kilometres.
pub const MAX_RIG_EXTENT_M: f64 = 50.0;

/// How far the reference camera's stored pose may be from the identity (rotation entries,
/// metres): 1e-9, a few ulps of the text round trip; more means the file's poses are in
/// another frame than the one it names.
const REFERENCE_IDENTITY_TOLERANCE: f64 = 1e-9;

const UNITS: &str = "lengths in metres, intrinsics in pixels, rotations as row-major matrices";
const MULTI_KEYS: [&str; 7] =
    ["format", "version", "units", "reference", "cameras", "calibration", "rectified"];
const CAMERA_ENTRY_EXTRA_KEYS: [&str; 5] =
    ["name", "role", "sensor", "camera_from_reference", "depth_correction"];

/// True when a parsed JSON file says it is a kfuse rig file of version 2 (several cameras):
/// the one test [`MultiRig::from_json`], [`Rig::from_json`] and the readers use to tell the
/// two versions apart.
pub fn is_multi_rig_json(value: &serde_json::Value) -> bool {
    value.get("format").and_then(|f| f.as_str()) == Some(RIG_FORMAT)
        && value.get("version").and_then(|v| v.as_u64()) == Some(MULTI_RIG_VERSION.into())
}

/// Why a rig of `n` cameras (version 2) is refused where one depth + colour pair is needed,
/// and how to pick one sensor's pair.
pub fn not_a_pair_message(n: usize) -> String {
    format!(
        "a rig of {n} cameras (version {MULTI_RIG_VERSION}); this needs one depth + colour pair: pick one sensor's pair with `kfuse rig export --sensor SERIAL`, or use a command that takes several sensors"
    )
}

/// What a camera of a rig is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraRole {
    /// A Kinect's depth (IR / time-of-flight) camera; its images are depth and IR.
    Depth,
    /// A Kinect's colour camera.
    Color,
    /// Any other camera (an extra colour camera of the rig).
    Camera,
}

impl CameraRole {
    /// The word used in files and tables.
    pub fn as_str(self) -> &'static str {
        match self {
            CameraRole::Depth => "depth",
            CameraRole::Color => "color",
            CameraRole::Camera => "camera",
        }
    }
}

/// One camera of a [`MultiRig`].
#[derive(Debug, Clone, PartialEq)]
pub struct RigCamera {
    /// Unique within the rig (`"A.depth"`, `"left"`).
    pub name: String,
    /// What it is.
    pub role: CameraRole,
    /// The sensor it belongs to (a Kinect's serial number); the depth and colour camera of
    /// one Kinect share it. `None` for a camera of no sensor.
    pub sensor: Option<String>,
    /// Size, intrinsics and distortion.
    pub model: CameraModel,
    /// `X_camera = R · X_reference + T`, metres.
    pub camera_from_reference: RigidTransform,
    /// The measured-depth correction of a depth camera (`kfuse calibrate --depth`).
    pub depth_correction: Option<Box<DepthCorrection>>,
}

/// A rig of any number of cameras in one reference frame.
#[derive(Debug, Clone, PartialEq)]
pub struct MultiRig {
    /// The name of the camera whose frame is the reference.
    pub reference: String,
    /// Every camera, in file order.
    pub cameras: Vec<RigCamera>,
    /// The calibration report, kept verbatim.
    pub calibration: Option<serde_json::Value>,
    /// True when the images are already undistorted.
    pub rectified: bool,
}

#[derive(Serialize, Deserialize)]
struct CameraEntry {
    name: String,
    role: CameraRole,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    sensor: Option<String>,
    #[serde(flatten)]
    model: CameraModel,
    camera_from_reference: Option<RigidTransform>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    depth_correction: Option<DepthCorrectionFile>,
}

#[derive(Serialize, Deserialize)]
struct MultiRigFile {
    format: String,
    version: u32,
    #[serde(default)]
    units: String,
    reference: String,
    cameras: Vec<serde_json::Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    calibration: Option<serde_json::Value>,
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    rectified: bool,
}

impl MultiRig {
    /// The two cameras of a [`Rig`] as a rig of two, named `depth` and `color` (or
    /// `SENSOR.depth` / `SENSOR.color` when `sensor` is given), the depth camera the reference.
    pub fn from_pair(rig: &Rig, sensor: Option<&str>) -> MultiRig {
        let name = |role: &str| match sensor {
            Some(s) => format!("{s}.{role}"),
            None => role.to_string(),
        };
        MultiRig {
            reference: name("depth"),
            cameras: vec![
                RigCamera {
                    name: name("depth"),
                    role: CameraRole::Depth,
                    sensor: sensor.map(str::to_string),
                    model: rig.depth,
                    camera_from_reference: RigidTransform::identity(),
                    depth_correction: rig.depth_correction.clone(),
                },
                RigCamera {
                    name: name("color"),
                    role: CameraRole::Color,
                    sensor: sensor.map(str::to_string),
                    model: rig.color,
                    camera_from_reference: rig.color_from_depth,
                    depth_correction: None,
                },
            ],
            calibration: rig.calibration.clone(),
            rectified: rig.rectified,
        }
    }

    /// The camera called `name`.
    pub fn camera(&self, name: &str) -> Option<&RigCamera> {
        self.cameras.iter().find(|c| c.name == name)
    }

    /// The sensors of the rig, each once, in the order their first camera appears.
    pub fn sensors(&self) -> Vec<&str> {
        let mut out: Vec<&str> = Vec::new();
        for s in self.cameras.iter().filter_map(|c| c.sensor.as_deref()) {
            if !out.contains(&s) {
                out.push(s);
            }
        }
        out
    }

    /// `X_to = M · X_from` between two cameras of the rig.
    pub fn transform(&self, from: &RigCamera, to: &RigCamera) -> RigidTransform {
        to.camera_from_reference.compose(&from.camera_from_reference.inverse())
    }

    /// The depth + colour pair of one sensor as a two-camera [`Rig`] (its depth camera's
    /// frame the reference), with that depth camera's pose in the rig's reference frame.
    pub fn sensor_rig(&self, sensor: &str) -> Result<(Rig, RigidTransform), GeometryError> {
        let of_role = |role: CameraRole| {
            self.cameras.iter().find(|c| c.sensor.as_deref() == Some(sensor) && c.role == role)
        };
        let missing = |what: &str| {
            GeometryError::InvalidInput(format!(
                "sensor \"{sensor}\" has no {what} camera in the rig (its sensors: {})",
                self.sensors().join(", ")
            ))
        };
        let depth = of_role(CameraRole::Depth).ok_or_else(|| missing("depth"))?;
        let color = of_role(CameraRole::Color).ok_or_else(|| missing("color"))?;
        let mut rig = Rig::new(depth.model, color.model, self.transform(depth, color));
        rig.depth_correction = depth.depth_correction.clone();
        rig.rectified = self.rectified;
        Ok((rig, depth.camera_from_reference))
    }

    /// The [`Rig`] this rig is when it is exactly one depth camera (the reference) and one
    /// colour camera; `None` otherwise. Such a rig is written as a version-1 file.
    pub fn as_pair(&self) -> Option<Rig> {
        let [d, c] = self.cameras.as_slice() else { return None };
        if d.role != CameraRole::Depth || c.role != CameraRole::Color || self.reference != d.name {
            return None;
        }
        let mut rig = Rig::new(d.model, c.model, self.transform(d, c));
        rig.depth_correction = d.depth_correction.clone();
        rig.calibration = self.calibration.clone();
        rig.rectified = self.rectified;
        Some(rig)
    }

    /// Checks the structure: 1..=[`MAX_RIG_CAMERAS`] cameras with distinct, non-empty names
    /// of at most [`MAX_NAME_CHARS`] characters, a reference that is one of them with the
    /// identity pose, valid camera models, at most one depth and one colour camera per sensor,
    /// depth corrections only on depth cameras of their size.
    pub fn validate(&self) -> Result<(), GeometryError> {
        let bad = |m: String| Err(GeometryError::InvalidParameter(m));
        if self.cameras.is_empty() || self.cameras.len() > MAX_RIG_CAMERAS {
            return bad(format!(
                "a rig holds 1 to {MAX_RIG_CAMERAS} cameras, this one {}",
                self.cameras.len()
            ));
        }
        for (i, c) in self.cameras.iter().enumerate() {
            let name_ok = |n: &str| !n.trim().is_empty() && n.chars().count() <= MAX_NAME_CHARS;
            if !name_ok(&c.name) {
                return bad(format!(
                    "camera {} has an empty name or one over {MAX_NAME_CHARS} characters",
                    i + 1
                ));
            }
            if c.sensor.as_deref().is_some_and(|s| !name_ok(s)) {
                return bad(format!(
                    "camera \"{}\" has an empty sensor name or one over {MAX_NAME_CHARS} characters",
                    c.name
                ));
            }
            if self.cameras[..i].iter().any(|o| o.name == c.name) {
                return bad(format!(
                    "two cameras are called \"{}\": names must be distinct",
                    c.name
                ));
            }
            c.model.validate().map_err(|e| {
                GeometryError::InvalidParameter(format!("camera \"{}\": {e}", c.name))
            })?;
            if let Some(s) = &c.sensor
                && c.role != CameraRole::Camera
                && self.cameras[..i]
                    .iter()
                    .any(|o| o.sensor.as_ref() == Some(s) && o.role == c.role)
            {
                return bad(format!(
                    "sensor \"{s}\" has two {} cameras (\"{}\" and another): a Kinect has one of each; two sensors with the same serial number?",
                    c.role.as_str(),
                    c.name
                ));
            }
            if let Some(dc) = &c.depth_correction {
                if c.role != CameraRole::Depth {
                    return bad(format!(
                        "camera \"{}\" is not a depth camera but has a depth_correction",
                        c.name
                    ));
                }
                if (dc.width, dc.height) != (c.model.width, c.model.height) {
                    return bad(format!(
                        "camera \"{}\": depth_correction is for {}x{} images but the camera is {}x{}",
                        c.name, dc.width, dc.height, c.model.width, c.model.height
                    ));
                }
            }
            let m = c.camera_from_reference.matrix();
            if m.iter().any(|v| !v.is_finite()) {
                return bad(format!("camera \"{}\" has a pose that is not finite", c.name));
            }
        }
        let Some(reference) = self.camera(&self.reference) else {
            return bad(format!(
                "the reference \"{}\" is not a camera of the rig (its cameras: {})",
                self.reference,
                self.names().join(", ")
            ));
        };
        let off =
            (reference.camera_from_reference.matrix() - nalgebra::Matrix4::identity()).abs().max();
        if off > REFERENCE_IDENTITY_TOLERANCE {
            return bad(format!(
                "the reference camera \"{}\" must have the identity pose (its own frame), off by {off:.3e}",
                self.reference
            ));
        }
        Ok(())
    }

    /// The cameras' names in order.
    pub fn names(&self) -> Vec<&str> {
        self.cameras.iter().map(|c| c.name.as_str()).collect()
    }

    /// What makes the rig implausible for real cameras: each camera's
    /// [`camera_plausibility_problems`], a camera over [`MAX_RIG_EXTENT_M`] from the
    /// reference, and each sensor's depth ↔ colour pair judged as a two-camera rig.
    pub fn plausibility_problems(&self) -> Vec<String> {
        let mut problems: Vec<String> = Vec::new();
        for c in &self.cameras {
            problems.extend(camera_plausibility_problems(&format!("\"{}\"", c.name), &c.model));
            let distance = c.camera_from_reference.inverse().translation.norm();
            if !(distance <= MAX_RIG_EXTENT_M) {
                problems.push(format!(
                    "camera \"{}\" is {distance:.1} m from the reference, over {MAX_RIG_EXTENT_M} m: translations in millimetres?",
                    c.name
                ));
            }
        }
        for s in self.sensors() {
            if let Ok((pair, _)) = self.sensor_rig(s) {
                // The per-camera problems are listed above; keep the pair's baseline ones.
                let own: Vec<String> = camera_plausibility_problems("depth", &pair.depth)
                    .into_iter()
                    .chain(camera_plausibility_problems("colour", &pair.color))
                    .collect();
                problems.extend(
                    pair.plausibility_problems()
                        .into_iter()
                        .filter(|p| !own.contains(p))
                        .map(|p| format!("sensor \"{s}\": {p}")),
                );
            }
        }
        problems
    }

    /// The rig file's text: version 1 (exactly [`Rig::to_json`]) for a depth + colour pair,
    /// version 2 otherwise.
    pub fn to_json(&self) -> String {
        if let Some(pair) = self.as_pair() {
            return pair.to_json();
        }
        let cameras = self
            .cameras
            .iter()
            .map(|c| {
                serde_json::to_value(CameraEntry {
                    name: c.name.clone(),
                    role: c.role,
                    sensor: c.sensor.clone(),
                    model: c.model,
                    camera_from_reference: Some(c.camera_from_reference),
                    depth_correction: c.depth_correction.as_deref().map(DepthCorrection::to_file),
                })
                .unwrap_or_default()
            })
            .collect();
        let file = MultiRigFile {
            format: RIG_FORMAT.into(),
            version: MULTI_RIG_VERSION,
            units: UNITS.into(),
            reference: self.reference.clone(),
            cameras,
            calibration: self.calibration.clone(),
            rectified: self.rectified,
        };
        // Serialising plain numbers and strings cannot fail.
        serde_json::to_string_pretty(&file).unwrap_or_default()
    }

    /// Parses a rig file of either version (a version-1 file becomes a rig of two cameras,
    /// [`MultiRig::from_pair`]) and validates it; `source` names the file in errors.
    pub fn from_json(text: &str, source: &std::path::Path) -> Result<MultiRig, GeometryError> {
        let format_err =
            |message: String| GeometryError::Format { path: source.to_path_buf(), message };
        let value: serde_json::Value = serde_json::from_str(text).map_err(|e| {
            format_err(format!("not a kfuse rig file ({e}); create one with `kfuse calibrate`"))
        })?;
        if !is_multi_rig_json(&value) {
            return Rig::from_json(text, source).map(|r| MultiRig::from_pair(&r, None));
        }
        if let Some(repeated) = duplicate_key(text) {
            return Err(format_err(repeated));
        }
        if let Some(u) = unknown_keys(&value, "the rig", &MULTI_KEYS).first() {
            return Err(format_err(u.clone()));
        }
        let file: MultiRigFile = serde_json::from_value(value).map_err(|e| {
            format_err(format!("a kfuse rig file (version 2) with an error: {e}; correct it, or write it again with `kfuse calibrate`"))
        })?;
        if file.cameras.len() > MAX_RIG_CAMERAS {
            return Err(format_err(format!(
                "{} cameras, over the {MAX_RIG_CAMERAS} a rig may hold",
                file.cameras.len()
            )));
        }
        let known: Vec<&str> =
            CAMERA_KEYS.iter().chain(&CAMERA_ENTRY_EXTRA_KEYS).copied().collect();
        let mut cameras = Vec::with_capacity(file.cameras.len());
        for (i, v) in file.cameras.into_iter().enumerate() {
            let place = match v.get("name").and_then(|n| n.as_str()) {
                Some(n) => format!(
                    "camera \"{}\"",
                    n.escape_debug().take(MAX_NAME_CHARS).collect::<String>()
                ),
                None => format!("camera {}", i + 1),
            };
            if let Some(u) = unknown_keys(&v, &place, &known).first() {
                return Err(format_err(u.clone()));
            }
            let entry: CameraEntry =
                serde_json::from_value(v).map_err(|e| format_err(format!("in {place}: {e}")))?;
            let camera_from_reference = entry.camera_from_reference.ok_or_else(|| {
                format_err(format!(
                    "{place} has no camera_from_reference: every camera needs its pose in the rig's frame (calibrate the cameras together with `kfuse calibrate --camera`)"
                ))
            })?;
            let depth_correction = entry
                .depth_correction
                .map(|f| DepthCorrection::from_file(f).map(Box::new))
                .transpose()
                .map_err(|e| format_err(format!("in {place}: {e}")))?;
            cameras.push(RigCamera {
                name: entry.name,
                role: entry.role,
                sensor: entry.sensor,
                model: entry.model,
                camera_from_reference,
                depth_correction,
            });
        }
        let rig = MultiRig {
            reference: file.reference,
            cameras,
            calibration: file.calibration,
            rectified: file.rectified,
        };
        rig.validate().map_err(|e| format_err(e.to_string()))?;
        Ok(rig)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use std::path::Path;

    /// Two Kinects facing each other 2 m apart (the second turned 180° about y), the first's
    /// depth camera the reference.
    fn two_kinects() -> MultiRig {
        let pair = crate::synth::kinect_rig();
        let a = MultiRig::from_pair(&pair, Some("A"));
        let b = MultiRig::from_pair(&pair, Some("B"));
        // B's depth camera at (0, 0, 2) looking back: X_B = R·X_A + T.
        let b_from_a = RigidTransform::from_axis_angle(
            Vector3::new(0.0, std::f64::consts::PI, 0.0),
            Vector3::new(0.0, 0.0, 2.0),
        );
        let mut cameras = a.cameras.clone();
        for mut c in b.cameras {
            c.camera_from_reference = c.camera_from_reference.compose(&b_from_a);
            cameras.push(c);
        }
        MultiRig { reference: "A.depth".into(), cameras, calibration: None, rectified: false }
    }

    /// A pair writes the version-1 file byte for byte and reads back as a pair.
    #[test]
    fn a_pair_is_written_as_the_two_camera_file() {
        let pair = crate::synth::kinect_rig();
        let multi = MultiRig::from_pair(&pair, None);
        assert_eq!(multi.to_json(), pair.to_json());
        let back = MultiRig::from_json(&pair.to_json(), Path::new("r.json")).unwrap();
        let direct = Rig::from_json(&pair.to_json(), Path::new("r.json")).unwrap();
        assert_eq!(back.as_pair().unwrap(), direct);
        assert_eq!(back.names(), ["depth", "color"]);
    }

    /// Four cameras round-trip through version 2; each sensor's pair is the original pair;
    /// the relative pose of the two depth cameras is the one put in.
    #[test]
    fn four_cameras_round_trip_and_give_each_sensors_pair() {
        let rig = two_kinects();
        rig.validate().unwrap();
        assert!(rig.plausibility_problems().is_empty(), "{:?}", rig.plausibility_problems());
        let text = rig.to_json();
        assert!(text.contains("\"version\": 2") && text.contains("\"B.color\""));
        let back = MultiRig::from_json(&text, Path::new("r.json")).unwrap();
        assert_eq!(back.names(), rig.names());
        assert_eq!(back.sensors(), ["A", "B"]);
        let pair = crate::synth::kinect_rig();
        for s in ["A", "B"] {
            let (p, _) = back.sensor_rig(s).unwrap();
            assert_eq!((p.depth, p.color), (pair.depth, pair.color));
            // Through the reference and back: a few ulps of O(1) entries.
            let d = (p.color_from_depth.matrix() - pair.color_from_depth.matrix()).abs().max();
            assert!(d < 1e-12, "sensor {s}: {d}");
        }
        let (_, b_pose) = back.sensor_rig("B").unwrap();
        // B's depth camera centre in A's frame: −Rᵀ·T = (0, 0, 2) for R = rot_y(π), T = (0,0,2).
        let centre = b_pose.inverse().translation;
        assert!((centre - Vector3::new(0.0, 0.0, 2.0)).norm() < 1e-12, "{centre:?}");
        assert!(back.as_pair().is_none());
    }

    /// Each broken file gives one line naming the file and the problem.
    #[test]
    fn broken_files_name_the_problem() {
        let text = two_kinects().to_json();
        let err = |t: &str| MultiRig::from_json(t, Path::new("rig.json")).unwrap_err().to_string();
        let no_pose = {
            let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
            v["cameras"][2].as_object_mut().unwrap().remove("camera_from_reference");
            v.to_string()
        };
        let e = err(&no_pose);
        assert!(
            e.starts_with("rig.json: ")
                && e.contains("camera \"B.depth\" has no camera_from_reference"),
            "{e}"
        );
        let same_serial = text.replace("\"B\"", "\"A\"");
        let e = err(&same_serial);
        assert!(
            e.contains("sensor \"A\" has two depth cameras") && e.contains("same serial"),
            "{e}"
        );
        let e = err(&text.replace("\"reference\": \"A.depth\"", "\"reference\": \"C.depth\""));
        assert!(e.contains("the reference \"C.depth\" is not a camera of the rig"), "{e}");
        let e = err(&text.replace("\"reference\": \"A.depth\"", "\"reference\": \"B.depth\""));
        assert!(e.contains("must have the identity pose"), "{e}");
        let e = err(&text.replacen("\"role\"", "\"rloe\"", 1));
        assert!(e.contains("unknown key \"rloe\" in camera \"A.depth\""), "{e}");
        let e = err(&text.replacen("\"name\": \"A.color\"", "\"name\": \"A.depth\"", 1));
        assert!(e.contains("two cameras are called \"A.depth\""), "{e}");
        let many = {
            let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
            let one = v["cameras"][0].clone();
            v["cameras"] = serde_json::Value::Array(vec![one; MAX_RIG_CAMERAS + 1]);
            v.to_string()
        };
        assert!(err(&many).contains("over the 64 a rig may hold"), "{}", err(&many));
        // A version-1 command reading a version-2 file is told what it is.
        let e = Rig::from_json(&text, Path::new("rig.json")).unwrap_err().to_string();
        assert!(e.contains("4 cameras") && e.contains("one depth + colour pair"), "{e}");
    }

    /// A camera placed kilometres away (translations in millimetres) is implausible.
    #[test]
    fn millimetre_translations_are_implausible() {
        let mut rig = two_kinects();
        for c in &mut rig.cameras[2..] {
            c.camera_from_reference.translation *= 1000.0;
        }
        let p = rig.plausibility_problems();
        assert!(
            p.iter().any(|m| m.contains("\"B.depth\" is 2000.0 m from the reference")),
            "{p:?}"
        );
    }
}
