//! The rig calibration: both cameras and `color_from_depth`, and its versioned JSON form.
//!
//! ```json
//! {
//!   "format": "kfuse-rig", "version": 1,
//!   "units": "lengths in metres, intrinsics in pixels, rotations as row-major matrices",
//!   "depth_camera": { "width": 512, "height": 424, "fx": ..., "fy": ..., "cx": ..., "cy": ...,
//!                     "skew": 0, "k1": ..., "k2": ..., "p1": ..., "p2": ..., "k3": ... },
//!   "color_camera": { ... same fields ... },
//!   "color_from_depth": { "rotation": [[...],[...],[...]], "translation_m": [x, y, z] },
//!   "calibration": { ... optional report written by `kfuse calibrate` ... },
//!   "rectified": true   (optional, default false: the images are already undistorted),
//!   "depth_correction": { "version": 1, ... }   (optional: `crate::depth_correction`)
//! }
//! ```
//! `color_from_depth` maps depth-camera points into the colour camera: `X_c = R·X_d + T`.

use serde::{Deserialize, Serialize};

use crate::depth_correction::{DepthCorrection, DepthCorrectionFile};
use crate::num_fmt::{fixed, num};
use crate::{CameraModel, GeometryError, RigidTransform};

/// The value of the `format` field.
pub const RIG_FORMAT: &str = "kfuse-rig";
/// The newest rig file version this build writes and reads.
pub const RIG_VERSION: u32 = 1;
const RIG_UNITS: &str = "lengths in metres, intrinsics in pixels, rotations as row-major matrices";

// Plausibility limits: what a rig of real cameras can hold. Values outside are nearly always a
// unit mistake (metres or millimetres where pixels or metres belong), and they make the fusion
// loop over absurd pixel ranges or allocate absurd images, so they are refused before any work
// ([`Rig::check_plausible`]; `--force` on the command line skips the check).

/// Shortest focal length, pixels: 50. A 512-px-wide image (the Kinect's depth camera, f ≈ 365
/// px) would see 158° across at f = 50 px; a focal length in metres (0.00365) or millimetres
/// (3.65) lands far below.
pub const MIN_FOCAL_PX: f64 = 50.0;
/// Longest focal length, pixels: 20 000. A 1920-px image then sees 5.5° across (a long
/// telephoto; the Kinect's colour camera has f ≈ 1060 px); focal lengths in micrometres land
/// above.
pub const MAX_FOCAL_PX: f64 = 20_000.0;
/// Largest image side of a rig's camera, pixels: 16 384 (16K; the Kinect's largest image is
/// 1920 px wide). One 16 384² float image is 1 GiB, so a larger side is a typing mistake that
/// would allocate many gigabytes before any image is looked at.
pub const MAX_IMAGE_SIDE: usize = 16_384;
/// Longest depth → colour baseline, metres: 0.5. The Kinect v2's is 52 mm and a rig of two
/// separate sensors on one bar stays under half a metre; a `T` in millimetres reads as 52 m.
pub const MAX_BASELINE_M: f64 = 0.5;
/// Shortest depth → colour baseline, metres: 5 mm. Two camera modules cannot sit closer (the
/// Kinect v2's lenses are 52 mm apart); a `T` in metres read as millimetres gives 0.052 mm.
pub const MIN_BASELINE_M: f64 = 0.005;
/// Largest magnification of the image corners by a camera's radial distortion: 2. The real
/// lenses calibrated here stay within 0.7–1.02 (kinect-lab IR, the corpus's GoPro, Udacity
/// and robot-arm cameras, 2026-12-02).
pub const MAX_CORNER_MAGNIFICATION: f64 = 2.0;
/// Smallest fold radius of a radial distortion (where it stops being one-to-one), as a
/// fraction of the image corners' radius: 0.5. Real lenses fold at 1.0–1.25 of it or not at
/// all (the lab's Kinect IR folds just inside its corners).
pub const MIN_FOLD_FRACTION: f64 = 0.5;

/// A calibrated depth + colour camera pair.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    /// The depth (IR / time-of-flight) camera; its frame is the rig's reference.
    pub depth: CameraModel,
    /// The colour camera.
    pub color: CameraModel,
    /// `X_color = R · X_depth + T`, metres.
    pub color_from_depth: RigidTransform,
    /// The calibration report (errors, standard deviations, board, per-image RMS) as written
    /// by `kfuse calibrate`, kept verbatim; `None` for rigs from other sources.
    pub calibration: Option<serde_json::Value>,
    /// True when this rig's images are already undistorted (`kfuse undistort`, the lab's
    /// `*_rect` files): fusion then uses both cameras without their distortion. Optional in
    /// the file (absent = false, so version-1 files without it read unchanged).
    pub rectified: bool,
    /// The measured-depth correction of the depth camera (`kfuse calibrate --depth`), applied
    /// wherever depth becomes 3D; `None` (absent in the file) = the depth is taken as exact.
    /// Boxed: a rig is passed by value in enums of calibration sources, most without one.
    pub depth_correction: Option<Box<DepthCorrection>>,
}

#[derive(Serialize, Deserialize)]
struct RigFile {
    format: String,
    version: u32,
    #[serde(default)]
    units: String,
    depth_camera: CameraModel,
    color_camera: CameraModel,
    color_from_depth: RigidTransform,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    calibration: Option<serde_json::Value>,
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    rectified: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    depth_correction: Option<DepthCorrectionFile>,
}

/// The keys of a camera in rig and camera files.
pub const CAMERA_KEYS: [&str; 12] =
    ["width", "height", "fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3"];
const RIG_KEYS: [&str; 9] = [
    "format",
    "version",
    "units",
    "depth_camera",
    "color_camera",
    "color_from_depth",
    "calibration",
    "rectified",
    "depth_correction",
];
const TRANSFORM_KEYS: [&str; 2] = ["rotation", "translation_m"];
const DEPTH_CORRECTION_KEYS: [&str; 6] = ["version", "width", "height", "model", "terms", "fit"];
const DEPTH_TERM_KEYS: [&str; 3] = ["term", "value", "std"];

/// Longest part of an unknown key shown in a message, characters: 40, twice the longest key of
/// the format; a file's garbage key must not fill the terminal.
const MAX_SHOWN_KEY_CHARS: usize = 40;

/// The keys of `object` (a JSON object at `place`) that are not in `known`, one message each:
/// "unknown key \"K3\" in depth_camera (…)".
pub fn unknown_keys(object: &serde_json::Value, place: &str, known: &[&str]) -> Vec<String> {
    let Some(map) = object.as_object() else { return Vec::new() };
    map.keys()
        .filter(|k| !known.contains(&k.as_str()))
        .map(|k| {
            let close = known
                .iter()
                .find(|n| n.eq_ignore_ascii_case(k) || n.replace('_', "") == k.replace('_', ""))
                .map(|n| format!(" (\"{n}\"?)"))
                .unwrap_or_default();
            // The key as text that cannot carry control characters or run on for a page.
            let mut shown: String = k.escape_debug().take(MAX_SHOWN_KEY_CHARS).collect();
            if k.escape_debug().nth(MAX_SHOWN_KEY_CHARS).is_some() {
                shown.push('…');
            }
            format!(
                "unknown key \"{shown}\" in {place}{close}; the keys there are {}: a misspelt key would be ignored",
                known.join(", ")
            )
        })
        .collect()
}

/// The first key that appears twice in one object of JSON `text`, as a message naming it and
/// where ("key \"fx\" appears twice in depth_camera …"); `None` when every object's keys are
/// distinct, or when `text` is not JSON (the caller's parse reports that). serde_json keeps
/// the last of repeated keys without a word, so `{"fx": 365, …, "fx": 36.5}` read as 36.5;
/// a file with a key twice is refused like one with an unknown key.
pub fn duplicate_key(text: &str) -> Option<String> {
    use serde::de::DeserializeSeed;
    let mut de = serde_json::Deserializer::from_str(text);
    match (NoRepeat { place: String::new() }).deserialize(&mut de) {
        Err(e) if e.is_data() => Some(e.to_string()),
        _ => None,
    }
}

/// Walks a JSON value, failing on an object's repeated key ([`duplicate_key`]); `place` is
/// the path of the object being read (`depth_camera`, `calibration.per_image`).
struct NoRepeat {
    place: String,
}

impl<'de> serde::de::DeserializeSeed<'de> for NoRepeat {
    type Value = ();
    fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> serde::de::Visitor<'de> for NoRepeat {
    type Value = ();
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("any JSON value")
    }
    fn visit_bool<E>(self, _: bool) -> Result<(), E> {
        Ok(())
    }
    fn visit_i64<E>(self, _: i64) -> Result<(), E> {
        Ok(())
    }
    fn visit_u64<E>(self, _: u64) -> Result<(), E> {
        Ok(())
    }
    fn visit_f64<E>(self, _: f64) -> Result<(), E> {
        Ok(())
    }
    fn visit_str<E>(self, _: &str) -> Result<(), E> {
        Ok(())
    }
    fn visit_unit<E>(self) -> Result<(), E> {
        Ok(())
    }
    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
        while seq.next_element_seed(NoRepeat { place: self.place.clone() })?.is_some() {}
        Ok(())
    }
    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<(), A::Error> {
        let mut seen = std::collections::HashSet::new();
        while let Some(key) = map.next_key::<String>()? {
            let place =
                if self.place.is_empty() { key.clone() } else { format!("{}.{key}", self.place) };
            if !seen.insert(key.clone()) {
                // Shown as text that cannot carry control characters or run on for a page.
                let short = |t: &str| -> String {
                    let mut s: String = t.escape_debug().take(MAX_SHOWN_KEY_CHARS).collect();
                    if t.escape_debug().nth(MAX_SHOWN_KEY_CHARS).is_some() {
                        s.push('…');
                    }
                    s
                };
                let within = if self.place.is_empty() {
                    "the file's top level".to_string()
                } else {
                    short(&self.place)
                };
                return Err(serde::de::Error::custom(format!(
                    "key \"{}\" appears twice in {within}: only one value can be meant, keep one",
                    short(&key)
                )));
            }
            map.next_value_seed(NoRepeat { place })?;
        }
        Ok(())
    }
}

/// [`unknown_keys`] of a whole rig file: the top level, both cameras, `color_from_depth` and
/// `depth_correction` (the `calibration` report is free-form).
pub fn unknown_rig_keys(v: &serde_json::Value) -> Vec<String> {
    let mut out = unknown_keys(v, "the rig", &RIG_KEYS);
    out.extend(unknown_keys(&v["depth_camera"], "depth_camera", &CAMERA_KEYS));
    out.extend(unknown_keys(&v["color_camera"], "color_camera", &CAMERA_KEYS));
    out.extend(unknown_keys(&v["color_from_depth"], "color_from_depth", &TRANSFORM_KEYS));
    out.extend(unknown_keys(&v["depth_correction"], "depth_correction", &DEPTH_CORRECTION_KEYS));
    if let Some(terms) = v["depth_correction"]["terms"].as_array() {
        for t in terms {
            out.extend(unknown_keys(t, "a depth_correction term", &DEPTH_TERM_KEYS));
        }
    }
    out
}

/// What makes one camera implausible (focal lengths outside [`MIN_FOCAL_PX`]..[`MAX_FOCAL_PX`],
/// image sides over [`MAX_IMAGE_SIDE`], a radial distortion no lens has), each naming the
/// likely unit mistake; `name` says which
/// camera ("depth", "colour"). The per-camera half of [`Rig::plausibility_problems`], for files
/// that hold one camera.
pub fn camera_plausibility_problems(name: &str, cam: &CameraModel) -> Vec<String> {
    let mut problems = Vec::new();
    if cam.width > MAX_IMAGE_SIDE || cam.height > MAX_IMAGE_SIDE {
        problems.push(format!(
            "the {name} camera's image size {}x{} is over the {MAX_IMAGE_SIDE}-px limit per side",
            cam.width, cam.height
        ));
    }
    let k = &cam.intrinsics;
    let before = problems.len();
    for (axis, f) in [("fx", k.fx), ("fy", k.fy)] {
        if f < MIN_FOCAL_PX {
            problems.push(format!(
                "the {name} camera's {axis} = {} px is under {MIN_FOCAL_PX} px: focal lengths must be in pixels, not metres or millimetres",
                num(f)
            ));
        } else if f > MAX_FOCAL_PX {
            problems.push(format!(
                "the {name} camera's {axis} = {} px is over {MAX_FOCAL_PX} px: focal lengths must be in pixels",
                num(f)
            ));
        }
    }
    // The distortion, judged at the image's corners (meaningless with a focal length in the
    // wrong unit, which is said above).
    if problems.len() == before {
        problems.extend(distortion_problem(name, cam));
    }
    problems
}

/// What makes `cam`'s radial distortion implausible: the image corners magnified more than
/// [`MAX_CORNER_MAGNIFICATION`] times, or the model folding (no ray beyond) within
/// [`MIN_FOLD_FRACTION`] of the corners' radius. A user's `k1 = 50` passed every check and
/// shrank the fused cloud 3.5× sideways.
fn distortion_problem(name: &str, cam: &CameraModel) -> Option<String> {
    let (k, d) = (&cam.intrinsics, &cam.distortion);
    let (w, h) = ((cam.width.max(1) - 1) as f64, (cam.height.max(1) - 1) as f64);
    let corner = [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)]
        .iter()
        .map(|&(u, v)| k.from_pixel(u, v).norm())
        .fold(0.0, f64::max);
    let r2 = corner * corner;
    let factor = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3));
    let coefficients = format!("k1 {}, k2 {}, k3 {}", num(d.k1), num(d.k2), num(d.k3));
    if factor > MAX_CORNER_MAGNIFICATION {
        return Some(format!(
            "the {name} camera's radial distortion ({coefficients}) magnifies the image corners {}×, which no lens does: coefficients of another camera or model?",
            fixed(factor, 1)
        ));
    }
    match d.fold_radius() {
        Some(fold) if fold < MIN_FOLD_FRACTION * corner => Some(format!(
            "the {name} camera's radial distortion ({coefficients}) folds at {:.0} % of the image corners' radius, leaving most of the image without a valid ray: coefficients of another camera or model?",
            100.0 * fold / corner
        )),
        _ => None,
    }
}

impl Rig {
    /// A rig without a calibration report.
    pub fn new(depth: CameraModel, color: CameraModel, color_from_depth: RigidTransform) -> Self {
        Self {
            depth,
            color,
            color_from_depth,
            calibration: None,
            rectified: false,
            depth_correction: None,
        }
    }

    /// Checks both cameras.
    pub fn validate(&self) -> Result<(), GeometryError> {
        self.depth.validate()?;
        self.color.validate()
    }

    /// The rig through which already undistorted images (`kfuse undistort`, the lab's
    /// `*_rect`) are seen: the same camera matrices and pose, no distortion, `rectified` set,
    /// so nothing is undistorted twice. The one copy of that rule (`kfuse fuse`, the viewer,
    /// the Python package).
    pub fn as_rectified(&self) -> Rig {
        Rig {
            depth: self.depth.without_distortion(),
            color: self.color.without_distortion(),
            rectified: true,
            ..self.clone()
        }
    }

    /// What makes this rig implausible for real cameras (focal lengths outside
    /// [`MIN_FOCAL_PX`]..[`MAX_FOCAL_PX`], image sides over [`MAX_IMAGE_SIDE`], a radial
    /// distortion no lens has, a baseline outside [`MIN_BASELINE_M`]..[`MAX_BASELINE_M`]), each
    /// naming the likely unit mistake; empty when plausible.
    pub fn plausibility_problems(&self) -> Vec<String> {
        let mut problems = camera_plausibility_problems("depth", &self.depth);
        problems.extend(camera_plausibility_problems("colour", &self.color));
        let baseline = self.color_from_depth.translation.norm();
        if baseline < MIN_BASELINE_M {
            // Read as metres, 5-500 "mm" is a 5-500 mm baseline: the other slip.
            let hint = if (MIN_BASELINE_M / 1000.0..MIN_BASELINE_M).contains(&baseline) {
                let short = |x: f64| (x * 1e4).round() / 1e4;
                format!(
                    "; T looks like metres read as millimetres: {} mm → {} mm?",
                    short(baseline * 1000.0),
                    short(baseline * 1e6)
                )
            } else {
                String::new()
            };
            problems.push(format!(
                "the baseline |T| = {} m is under {} mm, closer than two cameras' lenses can sit{hint}",
                num(baseline),
                MIN_BASELINE_M * 1000.0
            ));
        }
        if !(baseline <= MAX_BASELINE_M) {
            // Read as millimetres, 10-500 "m" is a 1-50 cm baseline: the usual slip.
            let hint = if (10.0..=1000.0 * MAX_BASELINE_M).contains(&baseline) {
                // Rounded to 0.1 mm so the hint reads "52 → 0.052 m".
                let short = |x: f64| (x * 1e4).round() / 1e4;
                format!(
                    "; T looks like millimetres: {} → {} m?",
                    short(baseline),
                    short(baseline / 1000.0)
                )
            } else {
                String::new()
            };
            problems.push(format!(
                "the baseline |T| = {} m is over {MAX_BASELINE_M} m{hint}",
                num(baseline)
            ));
        }
        problems
    }

    /// The colour camera's optical centre in the depth camera's frame, metres (`−Rᵀ·T`). On a
    /// Kinect v2 in the images `kfuse capture` saves (the protocol's orientation) it lies at
    /// x ≈ −52 mm; a calibration of images mirrored left–right puts it at x ≈ +52 mm.
    pub fn color_centre_in_depth(&self) -> nalgebra::Vector3<f64> {
        self.color_from_depth.inverse().translation
    }

    /// The rig of the same cameras for images mirrored left–right in both cameras (column `u`
    /// → `width − 1 − u`): each camera [`CameraModel::mirrored`], and `R → M·R·M`, `T → M·T`
    /// with `M = diag(−1, 1, 1)`, so the colour camera moves to the other side. A depth
    /// correction's left–right term changes sign with it. The calibration report (image
    /// coordinates of the old orientation) is dropped.
    pub fn mirrored(&self) -> Rig {
        let m = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(-1.0, 1.0, 1.0));
        let r = m * self.color_from_depth.rotation.matrix() * m;
        let t = m * self.color_from_depth.translation;
        let color_from_depth =
            RigidTransform::new(nalgebra::Rotation3::from_matrix_unchecked(r), t);
        let depth_correction = self.depth_correction.as_ref().map(|c| {
            let mut c = c.clone();
            for term in &mut c.terms {
                if term.kind == crate::depth_correction::DepthTermKind::X {
                    term.value = -term.value;
                }
            }
            c
        });
        Rig {
            depth: self.depth.mirrored(),
            color: self.color.mirrored(),
            color_from_depth,
            calibration: None,
            rectified: self.rectified,
            depth_correction,
        }
    }

    /// Fails with every [`Rig::plausibility_problems`] in one line.
    pub fn check_plausible(&self) -> Result<(), GeometryError> {
        let problems = self.plausibility_problems();
        if problems.is_empty() {
            return Ok(());
        }
        Err(GeometryError::InvalidParameter(problems.join("; ")))
    }

    /// The rig as pretty-printed JSON (the rig file format above).
    pub fn to_json(&self) -> String {
        let file = RigFile {
            format: RIG_FORMAT.into(),
            version: RIG_VERSION,
            units: RIG_UNITS.into(),
            depth_camera: self.depth,
            color_camera: self.color,
            color_from_depth: self.color_from_depth,
            calibration: self.calibration.clone(),
            rectified: self.rectified,
            depth_correction: self.depth_correction.as_deref().map(DepthCorrection::to_file),
        };
        // Serialising plain numbers and strings cannot fail.
        serde_json::to_string_pretty(&file).unwrap_or_default()
    }

    /// Parses a rig file's text. `source` names the file in error messages. A key the format
    /// does not have is refused, naming it ([`unknown_rig_keys`]): an optional key misspelt
    /// (`"K3"`) would otherwise be read as its default, 0, without a word.
    pub fn from_json(text: &str, source: &std::path::Path) -> Result<Self, GeometryError> {
        let format_err =
            |message: String| GeometryError::Format { path: source.to_path_buf(), message };
        let value: serde_json::Value = serde_json::from_str(text).map_err(|e| {
            format_err(format!("not a kfuse rig file ({e}); create one with `kfuse calibrate`"))
        })?;
        let is_rig = value.get("format").and_then(|f| f.as_str()) == Some(RIG_FORMAT);
        if let Some(repeated) = duplicate_key(text) {
            return Err(format_err(repeated));
        }
        if crate::multi_rig::is_multi_rig_json(&value) {
            let n = value["cameras"].as_array().map_or(0, Vec::len);
            return Err(format_err(crate::multi_rig::not_a_pair_message(n)));
        }
        if is_rig && let Some(unknown) = unknown_rig_keys(&value).first() {
            return Err(format_err(unknown.clone()));
        }
        let section_error = |v: &serde_json::Value| -> Option<String> {
            let probe = |key: &str| -> Option<String> {
                let part = v.get(key).filter(|p| !p.is_null())?.clone();
                let e = match key {
                    "depth_camera" | "color_camera" => {
                        serde_json::from_value::<CameraModel>(part).err()
                    }
                    "color_from_depth" => serde_json::from_value::<RigidTransform>(part).err(),
                    _ => serde_json::from_value::<DepthCorrectionFile>(part).err(),
                }?;
                Some(format!("in {key}: {e}"))
            };
            ["depth_camera", "color_camera", "color_from_depth", "depth_correction"]
                .into_iter()
                .find_map(probe)
        };
        // The value is moved (a rig's report is up to ~600 KB); only an error reads the text
        // again to find the section.
        let file: RigFile = serde_json::from_value(value).map_err(|e| {
            format_err(if is_rig {
                // It says it is a rig: the fix is in the file, not a new calibration.
                let again = serde_json::from_str(text).unwrap_or_default();
                let what = section_error(&again).unwrap_or_else(|| e.to_string());
                format!("a kfuse rig file with an error: {what}; correct it, or write it again with `kfuse calibrate` or `kfuse rig import`")
            } else {
                format!("not a kfuse rig file ({e}); create one with `kfuse calibrate`")
            })
        })?;
        if file.format != RIG_FORMAT {
            return Err(format_err(format!(
                "format is '{}', expected '{RIG_FORMAT}'",
                file.format
            )));
        }
        if file.version > RIG_VERSION {
            return Err(format_err(format!(
                "rig file version {} is newer than this kfuse understands ({RIG_VERSION}); upgrade kfuse",
                file.version
            )));
        }
        let depth_correction = file
            .depth_correction
            .map(|f| DepthCorrection::from_file(f).map(Box::new))
            .transpose()
            .map_err(format_err)?;
        if let Some(c) = &depth_correction
            && (c.width, c.height) != (file.depth_camera.width, file.depth_camera.height)
        {
            return Err(format_err(format!(
                "depth_correction is for {}x{} depth images but the depth camera is {}x{}",
                c.width, c.height, file.depth_camera.width, file.depth_camera.height
            )));
        }
        let rig = Rig {
            depth_correction,
            depth: file.depth_camera,
            color: file.color_camera,
            color_from_depth: file.color_from_depth,
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
    use crate::{Distortion, Intrinsics};
    use nalgebra::Vector3;
    use std::path::Path;

    /// A key given twice in one object is refused naming it and where (serde_json alone kept
    /// the last, so a second `"fx"` replaced the first without a word), at the top level, in a
    /// camera and in the free-form report; the same keys in different objects are fine.
    #[test]
    fn repeated_keys_are_refused() {
        let text = crate::synth::kinect_rig().to_json();
        assert!(duplicate_key(&text).is_none(), "a written rig has distinct keys");
        let twice = text.replacen("\"fx\":", "\"fx\": 36.5, \"fx\":", 1);
        let e = Rig::from_json(&twice, Path::new("r.json")).unwrap_err().to_string();
        assert!(
            e.starts_with("r.json: ") && e.contains("key \"fx\" appears twice in depth_camera"),
            "{e}"
        );
        let top = text.replacen("\"version\":", "\"version\": 1, \"version\":", 1);
        let e = Rig::from_json(&top, Path::new("r.json")).unwrap_err().to_string();
        assert!(e.contains("key \"version\" appears twice in the file's top level"), "{e}");
        let mut rig = crate::synth::kinect_rig();
        rig.calibration = Some(serde_json::json!({"views": [{"rms": 0.1}]}));
        let report = rig.to_json().replacen("\"rms\":", "\"rms\": 9, \"rms\":", 1);
        let e = Rig::from_json(&report, Path::new("r.json")).unwrap_err().to_string();
        assert!(e.contains("key \"rms\" appears twice in calibration.views"), "{e}");
    }

    #[test]
    fn json_round_trip_keeps_every_parameter() {
        let depth = CameraModel::new(
            512,
            424,
            Intrinsics::new(365.0, 365.0, 255.5, 211.5),
            Distortion { k1: 0.098, k2: -0.22, p1: 0.004, p2: 0.0016, k3: 0.0 },
        );
        let color = CameraModel::new(
            1920,
            1080,
            Intrinsics::new(1060.0, 1060.0, 959.5, 539.5),
            Distortion::NONE,
        );
        let t = RigidTransform::from_axis_angle(
            Vector3::new(-0.001, 0.025, 0.007),
            Vector3::new(-0.052, -0.0003, 0.0006),
        );
        let mut rig = Rig::new(depth, color, t);
        rig.calibration = Some(serde_json::json!({"rms_px": 0.1}));
        let back = Rig::from_json(&rig.to_json(), Path::new("rig.json")).unwrap();
        assert_eq!(back.depth, rig.depth);
        assert_eq!(back.color, rig.color);
        // A few f64 ulps (2.2e-16) of O(1) matrix entries through the JSON text and back.
        assert!((back.color_from_depth.matrix() - t.matrix()).abs().max() < 1e-15);
        assert_eq!(back.calibration, rig.calibration);
        assert!(!back.rectified && !rig.to_json().contains("rectified"));
        rig.rectified = true;
        let back = Rig::from_json(&rig.to_json(), Path::new("rig.json")).unwrap();
        assert!(back.rectified, "the rectified flag is lost");
    }

    /// A rig written before the depth correction existed reads unchanged (no field, `None`)
    /// and writes no field; one with a correction keeps every term through the text.
    #[test]
    fn depth_correction_is_optional_and_round_trips() {
        use crate::depth_correction::{DepthCorrection, DepthTerm, DepthTermKind};
        let old = kinect().to_json();
        assert!(!old.contains("depth_correction"));
        let back = Rig::from_json(&old, Path::new("old.json")).unwrap();
        assert_eq!(back, kinect());
        let mut rig = kinect();
        let term = |kind, value, std| DepthTerm { kind, value, std };
        rig.depth_correction = Some(Box::new(DepthCorrection {
            width: 512,
            height: 424,
            terms: vec![
                term(DepthTermKind::Offset, 0.0241, 1e-4),
                term(DepthTermKind::Scale, 0.0049, 2e-5),
            ],
            fit: Some(serde_json::json!({"views_used": 14})),
        }));
        let text = rig.to_json();
        assert!(text.contains("\"depth_correction\"") && text.contains("\"version\": 1"));
        assert_eq!(Rig::from_json(&text, Path::new("new.json")).unwrap(), rig);
        // A correction for another image size is refused, naming both sizes.
        let bad = text.replace(
            "\"width\": 512,\n    \"height\": 424,\n    \"model\"",
            "\"width\": 640,\n    \"height\": 424,\n    \"model\"",
        );
        assert_ne!(bad, text);
        let err = Rig::from_json(&bad, Path::new("new.json")).unwrap_err().to_string();
        assert!(err.contains("640x424") && err.contains("512x424"), "{err}");
    }

    /// A scene point seen through the mirrored rig lands on the mirrored pixels: its depth
    /// pixel `u → w − 1 − u` and its colour pixel likewise, with distortion (skew, p1, p2, k1-k3)
    /// in both cameras; the colour camera changes side and mirroring twice gives the rig back.
    #[test]
    fn a_mirrored_rig_sees_the_mirrored_images() {
        let cam = |w, h, f, cx, cy, skew, d: [f64; 5]| {
            let mut k = Intrinsics::new(f, f * 1.003, cx, cy);
            k.skew = skew;
            CameraModel::new(w, h, k, Distortion::from_array(d))
        };
        let rig = Rig::new(
            cam(512, 424, 365.0, 261.7, 202.5, 0.3, [0.09, -0.27, 0.004, 0.0016, 0.1]),
            cam(1920, 1080, 1060.0, 951.2, 545.3, -0.2, [0.02, -0.05, -0.001, 0.0022, 0.0]),
            RigidTransform::from_axis_angle(
                Vector3::new(-0.004, 0.025, 0.007),
                Vector3::new(0.052, -0.0003, 0.0006),
            ),
        );
        let mirror = rig.mirrored();
        assert!(rig.color_centre_in_depth().x < -0.05 && mirror.color_centre_in_depth().x > 0.05);
        let flip = |p: Vector3<f64>| Vector3::new(-p.x, p.y, p.z);
        for p in [
            Vector3::new(0.3, -0.2, 1.1),
            Vector3::new(-0.6, 0.4, 2.5),
            Vector3::new(0.0, 0.1, 0.8),
        ] {
            let d = rig.depth.project(&p).unwrap();
            let c = rig.color.project(&rig.color_from_depth.apply(&p)).unwrap();
            let dm = mirror.depth.project(&flip(p)).unwrap();
            let cm = mirror.color.project(&mirror.color_from_depth.apply(&flip(p))).unwrap();
            // Exact up to rounding: 1e-9 px.
            assert!((dm.x - (511.0 - d.x)).abs() < 1e-9 && (dm.y - d.y).abs() < 1e-9, "{d} {dm}");
            assert!((cm.x - (1919.0 - c.x)).abs() < 1e-9 && (cm.y - c.y).abs() < 1e-9, "{c} {cm}");
        }
        let back = mirror.mirrored();
        assert_eq!((back.depth, back.color), (rig.depth, rig.color));
        assert!(
            (back.color_from_depth.matrix() - rig.color_from_depth.matrix()).abs().max() < 1e-15
        );
    }

    /// A misspelt optional key is refused, naming it and the key it resembles (it was read as
    /// its default, k3 = 0, without a word); a missing key names its section.
    #[test]
    fn misspelt_and_missing_keys_are_named_with_their_section() {
        let good = kinect().to_json();
        let err = |text: &str| Rig::from_json(text, Path::new("r.json")).unwrap_err().to_string();
        let e = err(&good.replacen("\"k3\"", "\"K3\"", 1));
        assert!(e.contains("unknown key \"K3\" in depth_camera (\"k3\"?)"), "{e}");
        let e = err(&good.replace("\"translation_m\"", "\"translation_mm\""));
        assert!(e.contains("unknown key \"translation_mm\" in color_from_depth"), "{e}");
        let e = err(&good.replace("\"rectified_\"", "").replacen("\"units\"", "\"unit\"", 1));
        assert!(e.contains("unknown key \"unit\" in the rig"), "{e}");
        let e = err(&good.replacen("\"fy\"", "\"fy_\"", 1).replacen("\"fy_\"", "\"fy\"", 0));
        assert!(e.contains("\"fy_\" in depth_camera (\"fy\"?)"), "{e}");
        // Missing: the section is named.
        let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
        v["color_camera"].as_object_mut().unwrap().remove("cx");
        let e = err(&v.to_string());
        assert!(
            e.contains("in color_camera: missing field `cx`") && e.contains("correct it"),
            "{e}"
        );
        assert_eq!(Rig::from_json(&good, Path::new("r.json")).unwrap(), kinect());
    }

    fn kinect() -> Rig {
        let depth = CameraModel::new(
            512,
            424,
            Intrinsics::new(365.0, 365.0, 255.5, 211.5),
            Distortion::NONE,
        );
        let color = CameraModel::new(
            1920,
            1080,
            Intrinsics::new(1060.0, 1060.0, 959.5, 539.5),
            Distortion::NONE,
        );
        Rig::new(
            depth,
            color,
            RigidTransform::from_axis_angle(Vector3::zeros(), Vector3::new(-0.052, 0.0, 0.0)),
        )
    }

    #[test]
    fn plausibility_names_each_unit_mistake() {
        assert!(kinect().check_plausible().is_ok());
        let mut mm = kinect();
        mm.color_from_depth.translation *= 1000.0;
        let err = mm.check_plausible().unwrap_err().to_string();
        assert!(err.contains("T looks like millimetres: 52 → 0.052 m?"), "{err}");
        for f in [0.00365, 3.65, 49.9] {
            let mut r = kinect();
            r.depth.intrinsics.fx = f;
            let err = r.check_plausible().unwrap_err().to_string();
            assert!(err.contains("depth camera's fx") && err.contains("in pixels"), "{err}");
        }
        let mut r = kinect();
        r.color.intrinsics.fy = 20_001.0;
        assert!(r.check_plausible().unwrap_err().to_string().contains("colour camera's fy"));
        // T in metres read as millimetres (a user's trial: 0.052 mm, fused with exit 0).
        let mut m = kinect();
        m.color_from_depth.translation /= 1000.0;
        let err = m.check_plausible().unwrap_err().to_string();
        assert!(err.contains("metres read as millimetres: 0.052 mm → 52 mm?"), "{err}");
        // Radial distortion no lens has (a user's k1 = 50 shrank the cloud 3.5×), both ways;
        // real lenses pass: the lab's Kinect IR (Bouguet's kc in Calib_Results_left.m) and
        // the corpus's GoPro (kfuse calibrate, 2026-12-02; it folds at 1.18× its corners'
        // radius).
        for (k1, what) in [(50.0, "magnifies the image corners"), (-50.0, "folds at")] {
            let mut r = kinect();
            r.depth.distortion.k1 = k1;
            let err = r.check_plausible().unwrap_err().to_string();
            assert!(
                err.contains("depth camera's radial distortion") && err.contains(what),
                "{err}"
            );
        }
        let mut lab = kinect();
        (lab.depth.distortion.k1, lab.depth.distortion.k2) = (0.0990, -0.2206);
        assert!(lab.check_plausible().is_ok(), "{:?}", lab.plausibility_problems());
        let gopro = CameraModel::new(
            1280,
            960,
            Intrinsics::new(563.7, 564.5, 651.4, 500.2),
            Distortion { k1: -0.246, k2: 0.076, k3: -0.012, ..Distortion::NONE },
        );
        assert!(gopro.distortion.fold_radius().is_some());
        assert!(camera_plausibility_problems("colour", &gopro).is_empty());
        let mut r = kinect();
        r.color.width = 30_000;
        r.color.height = 30_000;
        let err = r.check_plausible().unwrap_err().to_string();
        // 16384: MAX_IMAGE_SIDE, the rig's per-side limit; 30000 is the size set above.
        assert!(err.contains("30000x30000") && err.contains("16384"), "{err}");
        // The limits themselves are accepted.
        let mut r = kinect();
        r.depth.intrinsics.fx = MIN_FOCAL_PX;
        r.color.intrinsics.fx = MAX_FOCAL_PX;
        r.color.width = MAX_IMAGE_SIDE;
        r.color_from_depth.translation = Vector3::new(MAX_BASELINE_M, 0.0, 0.0);
        assert!(r.check_plausible().is_ok(), "{:?}", r.plausibility_problems());
    }

    #[test]
    fn wrong_format_and_future_version_are_named() {
        let err = Rig::from_json("{}", Path::new("x/rig.json")).unwrap_err().to_string();
        assert!(err.contains("x/rig.json"), "{err}");
        let depth = CameraModel::new(4, 4, Intrinsics::new(1.0, 1.0, 1.5, 1.5), Distortion::NONE);
        let text = Rig::new(depth, depth, RigidTransform::identity())
            .to_json()
            .replace("\"version\": 1", "\"version\": 99");
        let err = Rig::from_json(&text, Path::new("rig.json")).unwrap_err().to_string();
        assert!(err.contains("upgrade"), "{err}");
    }
}
