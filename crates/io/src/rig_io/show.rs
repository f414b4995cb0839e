//! A rig or camera in words, with units, and its sanity checks (`kfuse rig show`).
//!
//! The checks here are about plausibility of the *geometry* (square pixels, principal point
//! near the centre, distortion that does not fold inside the image, near-parallel cameras);
//! each returns a [`Finding`] and none changes the rig.

use std::fmt::Write as _;

use geometry::num_fmt::fixed;
use geometry::{CameraModel, CameraRole, MultiRig, Rig};

use super::{Calibration, Role};

/// Largest |fy/fx − 1| of a camera with square pixels (Kinect v2: < 0.3 %; 5 % means the
/// image was resized in one direction or fx, fy were swapped).
pub const MAX_ASPECT_DEVIATION: f64 = 0.05;
/// Largest distance of the principal point from the image centre, as a fraction of the
/// image side (real lenses: < 5 %; 15 % suggests a 1-based/0-based mix-up on a crop or a
/// principal point of another image size).
pub const MAX_PRINCIPAL_OFFSET: f64 = 0.15;
/// Largest |skew| / fx (modern sensors have none; Bouguet's `alpha_c` is ~0).
pub const MAX_SKEW_RATIO: f64 = 0.01;
/// Largest angle between the two cameras of an RGB-D rig, degrees (Kinect v2: ~0.5°; a
/// larger angle usually means R belongs to another pair or is inverted twice).
pub const MAX_RIG_ANGLE_DEG: f64 = 10.0;
/// Image sizes of the Kinect v2's cameras.
pub const KINECT_DEPTH_SIZE: (usize, usize) = (512, 424);
/// See [`KINECT_DEPTH_SIZE`].
pub const KINECT_COLOR_SIZE: (usize, usize) = (1920, 1080);

/// Where the Kinect v2's colour camera sits along x in the depth frame in images as the scene
/// is (kfuse's orientation rule, `kinect_usb::orientation`; the Kinect SDK's, iai_kinect2's and
/// the lab's Bouguet results agree: +52.2 mm), metres. The sensor's raw stream (libfreenect2's
/// output, `kfuse capture` before the rule) is mirrored: there the colour camera is at −52 mm.
pub const KINECT_COLOR_CENTRE_X_M: f64 = 0.052;

/// For a Kinect v2 rig: which image orientation it was calibrated in, from the side of the
/// colour camera (`None` for other rigs, or a colour camera within 10 mm of the depth
/// camera's x). `(true, text)` when it is a calibration of mirrored images (raw
/// libfreenect2 output, or `kfuse capture` before it wrote images as the scene is).
pub fn kinect_orientation(rig: &Rig) -> Option<(bool, String)> {
    let kinect = (rig.depth.width, rig.depth.height) == KINECT_DEPTH_SIZE
        && (rig.color.width, rig.color.height) == KINECT_COLOR_SIZE;
    let x = rig.color_centre_in_depth().x;
    if !kinect || x.abs() < 0.01 {
        return None;
    }
    let mirrored = x.signum() != KINECT_COLOR_CENTRE_X_M.signum();
    let text = if mirrored {
        format!(
            "orientation: the colour camera sits at x = {:+.1} mm of the depth camera, a calibration of images mirrored left-right (raw libfreenect2 output, or kfuse captures older than kinect_params.json version 2); kfuse's images are as the scene is (about {:+.0} mm): convert it with `kfuse rig import FILE --mirror` (fuse refuses it beside a new capture's kinect_params.json)",
            x * 1000.0,
            KINECT_COLOR_CENTRE_X_M * 1000.0
        )
    } else {
        format!(
            "orientation: the colour camera sits at x = {:+.1} mm of the depth camera: images as the scene is, as kfuse, the Kinect SDK and iai_kinect2 write them",
            x * 1000.0
        )
    };
    Some((mirrored, text))
}

/// One result of a check.
#[derive(Debug, Clone, PartialEq)]
pub struct Finding {
    /// True when the value is outside its plausible range.
    pub warning: bool,
    /// What was checked and what was found (units included).
    pub text: String,
}

fn finding(warning: bool, text: String) -> Finding {
    Finding { warning, text }
}

/// `x` with an explicit sign and `decimals` decimals ([`fixed`] otherwise).
fn signed(x: f64, decimals: usize) -> String {
    let text = fixed(x, decimals);
    if text.starts_with('-') { text } else { format!("+{text}") }
}

fn fov_deg(c: &CameraModel) -> (f64, f64) {
    let k = &c.intrinsics;
    let h = ((c.width as f64 - 0.5 - k.cx) / k.fx).atan() + ((k.cx + 0.5) / k.fx).atan();
    let v = ((c.height as f64 - 0.5 - k.cy) / k.fy).atan() + ((k.cy + 0.5) / k.fy).atan();
    (h.to_degrees(), v.to_degrees())
}

/// For a single camera given a role: a note when its image size is the other Kinect v2
/// camera's (a 512x424 camera as the colour camera), `None` otherwise.
pub fn kinect_role_mismatch(c: &CameraModel, role: Role) -> Option<String> {
    let (other, this) = match role {
        Role::Color => (KINECT_DEPTH_SIZE, "colour"),
        Role::Depth => (KINECT_COLOR_SIZE, "depth"),
    };
    ((c.width, c.height) == other).then(|| {
        let that = if this == "colour" { "depth/IR" } else { "colour" };
        format!(
            "a {}x{} camera as the {this} camera: that is the Kinect v2's {that} camera's size (--camera the other way?)",
            c.width, c.height
        )
    })
}

/// The checks of one camera.
pub fn camera_checks(c: &CameraModel, role: Option<Role>) -> Vec<Finding> {
    let k = &c.intrinsics;
    let name = role.map(|r| r.name()).unwrap_or("camera");
    let mut out = Vec::new();
    if let Some(note) = role.and_then(|r| kinect_role_mismatch(c, r)) {
        out.push(finding(true, note));
    }
    let aspect = k.fy / k.fx;
    out.push(finding(
        (aspect - 1.0).abs() > MAX_ASPECT_DEVIATION,
        format!(
            "{name}: fy/fx = {} (square pixels: within {MAX_ASPECT_DEVIATION} of 1)",
            fixed(aspect, 4)
        ),
    ));
    let (ox, oy) = (k.cx - (c.width as f64 - 1.0) / 2.0, k.cy - (c.height as f64 - 1.0) / 2.0);
    let off = (ox / c.width as f64).abs().max((oy / c.height as f64).abs());
    out.push(finding(
        off > MAX_PRINCIPAL_OFFSET,
        format!(
            "{name}: principal point {}, {} px from the image centre ({} % of the image, limit {:.0} %)",
            signed(ox, 1),
            signed(oy, 1),
            fixed(100.0 * off, 1),
            100.0 * MAX_PRINCIPAL_OFFSET
        ),
    ));
    if k.skew.abs() > MAX_SKEW_RATIO * k.fx {
        out.push(finding(
            true,
            format!("{name}: skew {} px is more than {MAX_SKEW_RATIO} of fx", fixed(k.skew, 3)),
        ));
    }
    if let Some(r) = c.distortion.fold_radius() {
        let corner = [
            (0.0, 0.0),
            (c.width as f64 - 1.0, 0.0),
            (0.0, c.height as f64 - 1.0),
            (c.width as f64 - 1.0, c.height as f64 - 1.0),
        ]
        .iter()
        .map(|&(u, v)| {
            let d = k.from_pixel(u, v);
            d.norm()
        })
        .fold(0.0, f64::max);
        // Distorted corner radius vs the distorted radius at the fold.
        let fold_d = r
            * (1.0
                + r * r * (c.distortion.k1 + r * r * (c.distortion.k2 + r * r * c.distortion.k3)));
        out.push(finding(
            fold_d < corner,
            format!(
                "{name}: distortion folds {:.1}° off-axis{}",
                r.atan().to_degrees(),
                if fold_d < corner {
                    " — inside the image: undistort masks the corners"
                } else {
                    ", outside the image"
                }
            ),
        ));
    }
    out
}

/// The checks of a rig: both cameras, sizes, the angle between the cameras.
pub fn rig_checks(rig: &Rig) -> Vec<Finding> {
    // The limits every command enforces (focal lengths in pixels, image sides, baseline).
    let mut out: Vec<Finding> =
        rig.plausibility_problems().into_iter().map(|p| finding(true, p)).collect();
    out.extend(camera_checks(&rig.depth, Some(Role::Depth)));
    out.extend(camera_checks(&rig.color, Some(Role::Color)));
    let angle = rig.color_from_depth.angle_deg();
    out.push(finding(
        // A NaN angle is not "ok" (it was, printed as "rotation NaN°").
        !(angle <= MAX_RIG_ANGLE_DEG),
        format!(
            "rotation between the cameras {angle:.3}° (RGB-D rigs: below {MAX_RIG_ANGLE_DEG}°)"
        ),
    ));
    if let Some((mirrored, text)) = kinect_orientation(rig) {
        out.push(finding(mirrored, text));
    }
    let sizes = ((rig.depth.width, rig.depth.height), (rig.color.width, rig.color.height));
    if sizes == (KINECT_COLOR_SIZE, KINECT_DEPTH_SIZE) {
        out.push(finding(
            true,
            "the depth camera is 1920x1080 and the colour camera 512x424: the Kinect v2's two cameras exchanged (--ir and --color swapped when it was calibrated?)".into(),
        ));
    } else if sizes != (KINECT_DEPTH_SIZE, KINECT_COLOR_SIZE) {
        out.push(finding(
            false,
            format!(
                "image sizes {}x{} (depth) and {}x{} (colour) are not the Kinect v2's 512x424 and 1920x1080",
                sizes.0.0, sizes.0.1, sizes.1.0, sizes.1.1
            ),
        ));
    }
    out
}

fn camera_text(s: &mut String, title: &str, c: &CameraModel) {
    let k = &c.intrinsics;
    let d = &c.distortion;
    let (h, v) = fov_deg(c);
    let _ = writeln!(s, "{title}: {} x {} px", c.width, c.height);
    let _ = writeln!(s, "  focal length     fx {} px, fy {} px", fixed(k.fx, 3), fixed(k.fy, 3));
    let _ = writeln!(
        s,
        "  principal point  cx {} px, cy {} px (0-based, pixel centres at integers)",
        fixed(k.cx, 3),
        fixed(k.cy, 3)
    );
    if k.skew != 0.0 {
        let _ = writeln!(s, "  skew             {} px", fixed(k.skew, 4));
    }
    let _ = writeln!(s, "  field of view    {h:.1}° x {v:.1}° (horizontal x vertical)");
    if d.is_zero() {
        let _ = writeln!(s, "  distortion       none");
    } else {
        let _ = writeln!(
            s,
            "  distortion       k1 {}, k2 {}, p1 {}, p2 {}, k3 {} (OpenCV order, unitless)",
            fixed(d.k1, 6),
            fixed(d.k2, 6),
            fixed(d.p1, 6),
            fixed(d.p2, 6),
            fixed(d.k3, 6)
        );
    }
}

/// The text of `kfuse rig show`: every parameter with its unit, then the checks
/// (`WARN` for implausible values, `ok` otherwise). Returns `(text, number of warnings)`.
pub fn describe(name: &str, c: &Calibration) -> (String, usize) {
    let mut s = String::new();
    let findings = match c {
        Calibration::Rig(rig) => {
            let _ = writeln!(s, "{name}: kfuse rig (depth camera = reference frame)");
            camera_text(&mut s, "depth camera", &rig.depth);
            camera_text(&mut s, "colour camera", &rig.color);
            let t = rig.color_from_depth.translation * 1e3;
            let axis = rig.color_from_depth.rotation.axis().map(|a| a.into_inner());
            let centre =
                -(rig.color_from_depth.rotation.inverse() * rig.color_from_depth.translation) * 1e3;
            let _ = writeln!(s, "color_from_depth: X_color = R·X_depth + T");
            match axis {
                Some(a) => {
                    let _ = writeln!(
                        s,
                        "  rotation         {:.4}° about ({:+.3}, {:+.3}, {:+.3})",
                        rig.color_from_depth.angle_deg(),
                        a.x,
                        a.y,
                        a.z
                    );
                }
                None => {
                    let _ = writeln!(s, "  rotation         none");
                }
            }
            let mm = |x: f64| fixed(x, 3);
            let _ = writeln!(s, "  translation T    ({}, {}, {}) mm", mm(t.x), mm(t.y), mm(t.z));
            let _ = writeln!(
                s,
                "  baseline         {} mm (colour camera centre at ({}, {}, {}) mm in the depth frame)",
                mm(t.norm()),
                mm(centre.x),
                mm(centre.y),
                mm(centre.z)
            );
            match &rig.depth_correction {
                None => {
                    let _ = writeln!(s, "depth correction: none (the depth is taken as exact)");
                }
                Some(c) => {
                    let _ = writeln!(
                        s,
                        "depth correction: z_measured = (1 + scale)·z_true + Σ terms ({}x{} raw depth pixels; ρ = 1 at the corners)",
                        c.width, c.height
                    );
                    for line in c.describe() {
                        let _ = writeln!(s, "  {line}");
                    }
                }
            }
            rig_checks(rig)
        }
        Calibration::Camera { camera, role, .. } => {
            let what = role.map(|r| format!("{} camera", r.name())).unwrap_or("camera".into());
            let _ = writeln!(s, "{name}: kfuse single-camera file");
            camera_text(&mut s, &what, camera);
            camera_checks(camera, *role)
        }
    };
    checks_text(s, &findings)
}

/// The text of `kfuse rig show` for a rig of several cameras: every camera with its role,
/// sensor, parameters and pose (its centre in the reference frame, mm, and its rotation from
/// the reference), then the checks: the rig's own ([`MultiRig::plausibility_problems`]), each
/// camera's ([`camera_checks`]) and each sensor's depth + colour pair ([`rig_checks`]).
pub fn describe_multi(name: &str, rig: &MultiRig) -> (String, usize) {
    let mut s = String::new();
    let sensors = rig.sensors();
    let _ = writeln!(
        s,
        "{name}: kfuse rig of {} cameras ({} sensor(s){}); reference frame = camera \"{}\"",
        rig.cameras.len(),
        sensors.len(),
        if sensors.is_empty() { String::new() } else { format!(": {}", sensors.join(", ")) },
        rig.reference
    );
    let mut findings: Vec<Finding> =
        rig.plausibility_problems().into_iter().map(|p| finding(true, p)).collect();
    for c in &rig.cameras {
        let sensor = c.sensor.as_deref().map(|s| format!(", sensor {s}")).unwrap_or_default();
        camera_text(
            &mut s,
            &format!("camera \"{}\" ({}{sensor})", c.name, c.role.as_str()),
            &c.model,
        );
        // Rounding noise of the pose product shows as "-0.000" otherwise.
        let centre = (c.camera_from_reference.inverse().translation * 1e3)
            .map(|x| if x.abs() < 5e-4 { 0.0 } else { x });
        let _ = writeln!(
            s,
            "  pose             centre at ({}, {}, {}) mm in the reference frame, rotated {:.4}° from it (camera_from_reference: X_cam = R·X_ref + T)",
            fixed(centre.x, 3),
            fixed(centre.y, 3),
            fixed(centre.z, 3),
            c.camera_from_reference.angle_deg()
        );
        if let Some(dc) = &c.depth_correction {
            let _ = writeln!(s, "  depth correction {}x{} raw depth pixels:", dc.width, dc.height);
            for line in dc.describe() {
                let _ = writeln!(s, "    {line}");
            }
        }
        let role = match c.role {
            CameraRole::Depth => Some(Role::Depth),
            CameraRole::Color => Some(Role::Color),
            CameraRole::Camera => None,
        };
        findings.extend(
            camera_checks(&c.model, role)
                .into_iter()
                .map(|f| Finding { text: format!("\"{}\": {}", c.name, f.text), ..f }),
        );
    }
    for sensor in &sensors {
        if let Ok((pair, _)) = rig.sensor_rig(sensor) {
            // The cameras were checked one by one above and the pair's plausibility (its
            // baseline) is in the rig's own problems: keep only the pair's other checks.
            let own: Vec<String> = camera_checks(&pair.depth, Some(Role::Depth))
                .into_iter()
                .chain(camera_checks(&pair.color, Some(Role::Color)))
                .map(|f| f.text)
                .chain(pair.plausibility_problems())
                .collect();
            findings.extend(
                rig_checks(&pair)
                    .into_iter()
                    .filter(|f| !own.contains(&f.text))
                    .map(|f| Finding { text: format!("sensor {sensor}: {}", f.text), ..f }),
            );
        }
    }
    checks_text(s, &findings)
}

/// `text` followed by the checks (`WARN` or `ok`, one a line), and the number of warnings.
fn checks_text(mut text: String, findings: &[Finding]) -> (String, usize) {
    let _ = writeln!(text, "checks:");
    let mut warnings = 0;
    for f in findings {
        warnings += f.warning as usize;
        let _ = writeln!(text, "  {}  {}", if f.warning { "WARN" } else { "ok  " }, f.text);
    }
    (text, warnings)
}

#[cfg(test)]
mod tests {
    use super::*;
    use geometry::{Distortion, Intrinsics, RigidTransform};
    use nalgebra::Vector3;

    #[test]
    fn implausible_values_are_flagged_and_plausible_ones_pass() {
        let good = geometry::synth::kinect_rig();
        assert!(rig_checks(&good).iter().all(|f| !f.warning), "{:?}", rig_checks(&good));
        let mut bad = good.clone();
        bad.color.intrinsics.fy *= 1.2;
        bad.depth.intrinsics.cx = 10.0;
        bad.color_from_depth = RigidTransform::from_axis_angle(
            Vector3::new(0.0, 0.5, 0.0),
            Vector3::new(-0.05, 0.0, 0.0),
        );
        let w: Vec<String> =
            rig_checks(&bad).into_iter().filter(|f| f.warning).map(|f| f.text).collect();
        // Three faults were planted above: fy/fx = 1.2, cx = 10 px, a 0.5 rad (28.6°) rotation.
        assert_eq!(w.len(), 3, "{w:?}");
        assert!(
            w[0].contains("principal point")
                && w[1].contains("fy/fx = 1.1")
                && w[2].contains("28.6"),
            "{w:?}"
        );
        // The lab's IR k1/k2 fold inside the image.
        let lab = CameraModel::new(
            512,
            424,
            Intrinsics::new(364.1, 364.1, 255.5, 211.5),
            Distortion { k1: 0.0905, k2: -0.2695, p1: 0.0, p2: 0.0, k3: 0.0 },
        );
        let f = camera_checks(&lab, Some(Role::Depth));
        assert!(f.iter().any(|f| f.warning && f.text.contains("inside the image")), "{f:?}");
    }

    /// The Kinect's cameras exchanged (a rig calibrated with --ir and --color swapped, a mono
    /// file imported as the other camera) are warnings, not "ok"; the right way round is not.
    #[test]
    fn kinect_cameras_exchanged_are_warned_about() {
        let good = geometry::synth::kinect_rig();
        let mut swapped = good.clone();
        std::mem::swap(&mut swapped.depth, &mut swapped.color);
        let w: Vec<String> =
            rig_checks(&swapped).into_iter().filter(|f| f.warning).map(|f| f.text).collect();
        assert!(w.iter().any(|t| t.contains("two cameras exchanged")), "{w:?}");
        assert!(kinect_role_mismatch(&good.depth, Role::Color).is_some());
        assert!(kinect_role_mismatch(&good.color, Role::Depth).is_some());
        assert!(kinect_role_mismatch(&good.depth, Role::Depth).is_none());
        assert!(kinect_role_mismatch(&good.color, Role::Color).is_none());
        // `geometry::synth`'s rig, modelled on the lab's Bouguet result, has its colour camera
        // at +51.9 mm (images as the scene is, kfuse's rule); mirrored, at −51.9 mm.
        assert!(matches!(kinect_orientation(&good), Some((false, _))));
        assert!(matches!(kinect_orientation(&good.mirrored()), Some((true, _))));
    }
}
