//! Unit and emptiness checks of `kfuse fuse`, run on the loaded inputs before any fusion work:
//! a unit mistake (depth scale, depth in the wrong unit, T in millimetres, R, T inverted)
//! otherwise gives "0 samples", empty meshes, blank figures and exit code 0. Each check fails
//! with one line naming the file and the likely mistake; `--force` turns them into warnings.

use anyhow::{Result, bail};
use geometry::{DepthKind, Image, Rig, RigidTransform};
use kfuse_io::images::DepthEncoding;

// Plausible depth: a median outside this band is a unit mistake, not a scene (the one rule,
// `geometry::fusion::units`, that the Python package applies too).
pub use geometry::fusion::units::{MAX_MEDIAN_DEPTH_M, MIN_MEDIAN_DEPTH_M};
/// Smallest fraction of the valid depth samples that must land inside the colour image: 1 %.
/// A real rig's cameras look the same way and overlap over most of the frame (the Kinect v2's
/// over 80 %); under 1 % means the rig does not describe these images (T in millimetres, R, T
/// inverted, swapped cameras), and the fusion's output would be empty.
pub const MIN_IN_COLOR_FRACTION: f64 = 0.01;

/// Smallest `--depth-scale`, metres per unit: 1e-6 (micrometres; a 16-bit image then holds
/// at most 65 mm, finer than any depth camera).
pub const MIN_DEPTH_SCALE: f64 = 1e-6;
/// Largest `--depth-scale`, metres per unit: 1 (whole metres; larger units cannot be depth
/// images of a room, and 65 535 · 1e40 is not even a finite `f32`).
pub const MAX_DEPTH_SCALE: f64 = 1.0;

/// Coarsest depth step of a fusable 16-bit depth image, metres: 1 cm. Depth cameras resolve
/// millimetres (the Kinect v2 stores 1 mm units, noise ~1-3 mm at 1-2 m); at 1 cm a wall at
/// 2 m already shows visible terraces, and in whole metres (`--depth-scale 1` on depth saved
/// as metres and rounded) a room is three or four flat layers: the cloud, the meshes and the
/// plane fill come out as stairs with exit 0.
pub const MAX_DEPTH_STEP_M: f64 = 0.01;

/// Checks `--depth-scale` (one line naming the option and the fix).
pub fn check_depth_scale(scale: f64) -> Result<()> {
    if !(scale.is_finite() && (MIN_DEPTH_SCALE..=MAX_DEPTH_SCALE).contains(&scale)) {
        // 1e40 as written, not forty digits.
        let shown = if scale.is_finite() && scale.abs() >= 1e6 {
            format!("{scale:e}")
        } else {
            scale.to_string()
        };
        bail!(
            "--depth-scale {shown}: must be the metres per unit of 16-bit depth images, a number from {MIN_DEPTH_SCALE} to {MAX_DEPTH_SCALE} (0.001 for millimetres, the Kinect's unit)"
        );
    }
    Ok(())
}

/// Where the depth values came from, for the message naming the mistake.
#[derive(Debug, Clone)]
pub enum DepthSource {
    /// A depth image file read with `--depth-scale`.
    File {
        /// The file, as given.
        name: String,
        /// How it stores values.
        encoding: DepthEncoding,
        /// `--depth-scale`.
        scale: f64,
    },
    /// The `Depth` variable of `KinectData.mat` (uint16 millimetres).
    KinectMat {
        /// The file, as given.
        name: String,
    },
}

impl DepthSource {
    fn name(&self) -> &str {
        match self {
            DepthSource::File { name, .. } | DepthSource::KinectMat { name } => name,
        }
    }
}

/// The median of the valid samples; `None` when there is none.
pub fn median_depth(depth: &Image<f32>) -> Option<f64> {
    geometry::fusion::units::median_depth(depth, 1)
}

/// The number of distinct finite depth values (at most the 65 536 a 16-bit image holds).
fn distinct_depths(depth: &Image<f32>) -> usize {
    let mut v: Vec<u32> =
        depth.data().iter().filter(|d| d.is_finite()).map(|d| d.to_bits()).collect();
    v.sort_unstable();
    v.dedup();
    v.len()
}

/// A length for messages: "1 204" for large values (grouped thousands), 3 significant digits
/// below 100.
fn metres_text(m: f64) -> String {
    if m >= 100.0 {
        let digits = format!("{:.0}", m);
        let mut out = String::new();
        for (i, c) in digits.chars().enumerate() {
            if i > 0 && (digits.len() - i).is_multiple_of(3) {
                out.push(' ');
            }
            out.push(c);
        }
        out
    } else {
        format!("{m:.3}")
    }
}

/// Fails when the median depth lies outside [`MIN_MEDIAN_DEPTH_M`]..[`MAX_MEDIAN_DEPTH_M`],
/// naming the likely mistake.
pub fn check_depth_units(depth: &Image<f32>, source: &DepthSource) -> Result<(), String> {
    let Some(median) = median_depth(depth) else { return Ok(()) };
    if let DepthSource::File { name, encoding: DepthEncoding::Integer, scale } = source
        && *scale > MAX_DEPTH_STEP_M
        && (MIN_MEDIAN_DEPTH_M..=MAX_MEDIAN_DEPTH_M).contains(&median)
    {
        let levels = distinct_depths(depth);
        return Err(format!(
            "{name}: --depth-scale {scale} makes depth steps of {} m, coarser than {} m: this frame holds only {levels} distinct depth value(s); save depth as 16-bit millimetres (--depth-scale 0.001) or as float metres (TIFF/EXR), not rounded to {}",
            metres_text(*scale),
            MAX_DEPTH_STEP_M,
            if *scale >= 1.0 { "whole metres".to_string() } else { format!("{scale} m") },
        ));
    }
    if geometry::fusion::units::depth_unit_problem(depth, 1).is_none() {
        return Ok(());
    }
    let side = if median > MAX_MEDIAN_DEPTH_M {
        format!("over {MAX_MEDIAN_DEPTH_M} m")
    } else {
        format!("under {MIN_MEDIAN_DEPTH_M} m")
    };
    let head = format!("{}: median depth {} m is {side}", source.name(), metres_text(median));
    let hint = match source {
        DepthSource::File { encoding: DepthEncoding::Integer, scale, .. } => {
            // The scale that puts this median at the Kinect's typical 0.5-5 m, in powers of ten.
            let suggested = [1e-4, 1e-3, 1e-2, 1e-1]
                .into_iter()
                .find(|s| (0.5..=5.0).contains(&(median / scale * s)))
                .map(|s| format!(" use {s}"))
                .unwrap_or_default();
            if median > MAX_MEDIAN_DEPTH_M {
                format!(": is --depth-scale {scale} on millimetre depth?{suggested}")
            } else {
                format!(": is --depth-scale {scale} too small for this file's unit?{suggested}")
            }
        }
        DepthSource::File { encoding: DepthEncoding::FloatMetres, .. } => {
            if median > MAX_MEDIAN_DEPTH_M {
                ": float depth images must hold metres; this one looks like millimetres (divide by 1000, or save 16-bit millimetres)".into()
            } else {
                ": float depth images must hold metres; this one looks like a smaller unit or a normalised picture".into()
            }
        }
        DepthSource::KinectMat { .. } => {
            ": KinectData.mat's 'Depth' must be millimetres (uint16), as the lab's capture saves it"
                .into()
        }
    };
    Err(format!("{head}{hint}"))
}

/// Smallest offset along x (m) of the colour camera from the depth camera for which its side
/// is compared: 10 mm. The Kinect v2's cameras sit 52 mm apart along x (0.3 mm along y, 0.6 mm
/// along z in the lab's calibration); a rig whose offset is mostly along y or z has no side.
pub const MIN_SIDE_OFFSET_M: f64 = 0.01;

/// Nearest depth the Kinect v2 measures (the one rule of `geometry::fusion::units`).
pub use geometry::fusion::units::KINECT_MIN_DEPTH_M;

/// A warning when a Kinect v2 rig's 16-bit depth file has its median nearer than the sensor
/// measures ([`KINECT_MIN_DEPTH_M`]).
pub fn kinect_near_warning(rig: &Rig, depth: &Image<f32>, source: &DepthSource) -> Option<String> {
    let DepthSource::File { name, encoding: DepthEncoding::Integer, scale } = source else {
        return None;
    };
    let kinect = (rig.depth.width, rig.depth.height) == kfuse_io::rig_io::show::KINECT_DEPTH_SIZE;
    let median = median_depth(depth)?;
    (kinect && median < KINECT_MIN_DEPTH_M).then(|| {
        format!(
            "{name}: median depth {} m is nearer than the Kinect v2 measures ({KINECT_MIN_DEPTH_M} m): is the depth in centimetres (--depth-scale {})?",
            metres_text(median),
            scale * 10.0
        )
    })
}

/// Largest ratio between a rig's baseline and the sensor's factory baseline: 1.5. Kinect v2
/// units differ by a few millimetres (the lab's Bouguet 52.2 mm, the factory's 52 mm); a board
/// square given 10× too small (`--square 4mm` for 40 mm) gives a 5.2 mm baseline that passes
/// every other check and shifts the colour by ~17 px at 1 m.
pub const MAX_BASELINE_RATIO: f64 = 1.5;

/// Fails when `rig` does not fit the sensor whose factory parameters (`factory`) were saved
/// beside the images, in a way that no other check sees:
///
/// * the colour camera on the other side of the depth camera along x: the rig was calibrated
///   on images mirrored left–right (the lab's Bouguet results are: their colour camera sits at
///   x = +52 mm, kfuse's captures have it at −52 mm). Fusing with it puts the colour twice the
///   parallax off (~100 px at 1 m) while most samples still land in the image;
/// * a baseline more than [`MAX_BASELINE_RATIO`] from the factory's: a calibration with a
///   wrong `--square`.
///
/// A rig of other image sizes is left to the size checks, which name that mistake.
pub fn check_against_factory(
    rig: &Rig,
    rig_name: &str,
    factory: &Rig,
    factory_name: &str,
) -> Result<(), String> {
    let sizes = |r: &Rig| ((r.depth.width, r.depth.height), (r.color.width, r.color.height));
    if sizes(rig) != sizes(factory) {
        return Ok(());
    }
    let (x, f) = (rig.color_centre_in_depth().x, factory.color_centre_in_depth().x);
    if x.abs() >= MIN_SIDE_OFFSET_M && f.abs() >= MIN_SIDE_OFFSET_M && x.signum() != f.signum() {
        let why = if f > 0.0 {
            "the rig was calibrated on images mirrored left-right (raw libfreenect2 output, or a kfuse capture older than kinect_params.json version 2), these images are as the scene is"
        } else {
            "these images are mirrored left-right (a kfuse capture older than kinect_params.json version 2), the rig is of images as the scene is (kfuse's, the Kinect SDK's, iai_kinect2's, the lab's Bouguet results)"
        };
        return Err(format!(
            "{rig_name} puts the colour camera at x = {:+.1} mm from the depth camera, but {factory_name} at {:+.1} mm: {why}; convert the rig with `kfuse rig import {rig_name} --mirror --out RIG.json`",
            x * 1000.0,
            f * 1000.0
        ));
    }
    let (b, fb) =
        (rig.color_from_depth.translation.norm(), factory.color_from_depth.translation.norm());
    let ratio = fb / b;
    if fb > 0.0 && b > 0.0 && !(1.0 / MAX_BASELINE_RATIO..=MAX_BASELINE_RATIO).contains(&ratio) {
        return Err(format!(
            "{rig_name} has a baseline of {:.1} mm between the cameras, {factory_name} {:.1} mm: was the calibration's --square {} (its board squares {:.1}x the real ones)?",
            b * 1000.0,
            fb * 1000.0,
            if ratio > 1.0 { "too small" } else { "too large" },
            1.0 / ratio
        ));
    }
    Ok(())
}

/// Fraction of the valid depth samples whose point lands inside the colour image.
pub fn in_color_fraction(rig: &Rig, depth: &Image<f32>, kind: DepthKind) -> (f64, usize) {
    in_color_fraction_with(rig, &rig.color_from_depth, depth, kind)
}

fn in_color_fraction_with(
    rig: &Rig,
    color_from_depth: &RigidTransform,
    depth: &Image<f32>,
    kind: DepthKind,
) -> (f64, usize) {
    let (w, _) = depth.size();
    let mut valid = 0usize;
    let mut inside = 0usize;
    for (i, &d) in depth.data().iter().enumerate() {
        if !d.is_finite() {
            continue;
        }
        valid += 1;
        let (u, v) = ((i % w) as f64, (i / w) as f64);
        let Some(p) = rig.depth.backproject(u, v, d as f64, kind) else { continue };
        let q = color_from_depth.apply(&p);
        if q.z <= 0.0 {
            continue;
        }
        if let Some(uv) = rig.color.project(&q)
            && rig.color.contains(uv.x, uv.y)
        {
            inside += 1;
        }
    }
    (inside as f64 / valid.max(1) as f64, valid)
}

/// Fails when fewer than [`MIN_IN_COLOR_FRACTION`] of the depth samples land in the colour
/// image, naming the likely mistake (T in millimetres, R, T inverted) where another reading
/// of the rig would put them there.
pub fn check_overlap(
    rig: &Rig,
    rig_name: &str,
    depth: &Image<f32>,
    kind: DepthKind,
) -> Result<(), String> {
    let (fraction, valid) = in_color_fraction(rig, depth, kind);
    if fraction >= MIN_IN_COLOR_FRACTION {
        return Ok(());
    }
    let t = rig.color_from_depth.translation;
    let mut in_mm = rig.color_from_depth;
    in_mm.translation = t * 1e-3;
    let (mm_fraction, _) = in_color_fraction_with(rig, &in_mm, depth, kind);
    let (inv_fraction, _) =
        in_color_fraction_with(rig, &rig.color_from_depth.inverse(), depth, kind);
    let hint = if mm_fraction >= MIN_IN_COLOR_FRACTION && mm_fraction >= inv_fraction {
        let short = |x: f64| (x * 1e4).round() / 1e4;
        format!(
            "T looks like millimetres: {} → {} m? (read as millimetres, {:.0} % would land)",
            short(t.norm()),
            short(t.norm() * 1e-3),
            100.0 * mm_fraction
        )
    } else if inv_fraction >= MIN_IN_COLOR_FRACTION {
        format!(
            "R, T look inverted (the colour camera's pose in the depth frame, not color_from_depth; inverted, {:.0} % would land)",
            100.0 * inv_fraction
        )
    } else {
        "check that the rig belongs to these cameras, its T is in metres, and --depth-kind / --depth-scale".into()
    };
    Err(format!(
        "{rig_name}: only {:.2} % of the {valid} depth samples land in the colour image (at least {:.0} % needed): {hint}",
        100.0 * fraction,
        100.0 * MIN_IN_COLOR_FRACTION
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lengths_read_like_the_issue() {
        assert_eq!(metres_text(1204.4), "1 204");
        assert_eq!(metres_text(65535.0), "65 535");
        assert_eq!(metres_text(1.5), "1.500");
        assert_eq!(metres_text(123.0), "123");
    }

    #[test]
    fn median_and_scale_hint() {
        let d = Image::from_fn(10, 1, |x, _| if x < 3 { f32::NAN } else { 1204.0 + x as f32 });
        assert_eq!(median_depth(&d), Some(1210.0));
        let src = DepthSource::File {
            name: "d.png".into(),
            encoding: DepthEncoding::Integer,
            scale: 1.0,
        };
        let e = check_depth_units(&d, &src).unwrap_err();
        assert!(e.contains("median depth 1 210 m") && e.contains("use 0.001"), "{e}");
    }

    #[test]
    fn depth_in_whole_metres_is_refused_and_centimetres_pass() {
        // A room 1-4 m away saved as whole metres: a plausible median, four depth levels.
        let whole = Image::from_fn(8, 8, |x, _| 1.0 + (x / 2) as f32);
        let src = |scale| DepthSource::File {
            name: "d.png".into(),
            encoding: DepthEncoding::Integer,
            scale,
        };
        let e = check_depth_units(&whole, &src(1.0)).unwrap_err();
        assert!(
            e.contains("d.png") && e.contains("4 distinct") && e.contains("whole metres"),
            "{e}"
        );
        // Centimetres (the coarsest accepted unit) and millimetres pass; float metres are not
        // steps of a unit at all.
        let cm = Image::from_fn(8, 8, |x, y| 1.0 + 0.01 * (x + 8 * y) as f32);
        assert_eq!(check_depth_units(&cm, &src(0.01)), Ok(()));
        assert_eq!(check_depth_units(&cm, &src(0.001)), Ok(()));
        let float = DepthSource::File {
            name: "d.exr".into(),
            encoding: DepthEncoding::FloatMetres,
            scale: 1.0,
        };
        assert_eq!(check_depth_units(&whole, &float), Ok(()));
    }
}
