//! `kinect_params.json` (the Kinect v2's factory parameters, written by `kfuse capture`) → rig.
//!
//! # What the factory parameters say (protocol spec §4.6, §4.7, §11)
//!
//! * **Depth camera**: `fx, fy, cx, cy, k1, k2, k3, p1, p2`. The registration's distortion map
//!   is OpenCV's Brown–Conrady model with integer pixel centres, i.e. exactly kfuse's
//!   [`CameraModel`]: taken as it is (values are f32 on the device; read as f32, widened).
//! * **Colour camera**: no pinhole model. Registration maps the *undistorted* depth pixel
//!   `(x, y)` at depth `z` (mm) to the colour pixel
//!   `u = (rx(x, y) + shift_m/z)·f + cx_c`, `v = ry(x, y)`, where `rx`, `ry` are cubic
//!   polynomials in `(x − cx, y − cy)` (the mapping at infinity: rotation, colour
//!   intrinsics and lens distortion folded together) and the parallax `shift_m/z` moves
//!   points along colour x only.
//!
//! # The approximation made
//!
//! A kfuse rig is a pinhole colour camera with radial distortion `k1, k2` (`p1 = p2 = k3 = 0`)
//! and a rigid `color_from_depth`. It is *fitted* to the factory mapping: 12 parameters
//! (`fx, fy, cx, cy, k1, k2`, rotation vector, translation) by Levenberg–Marquardt on the
//! colour-pixel error over undistorted depth pixels every [`FIT_STEP_PX`] px (those whose
//! distorted position is on the depth image and whose colour position is on the colour
//! image) at the depths of [`FIT_DEPTHS_MM`] (the Kinect's 0.5–4.5 m range). The two models
//! agree exactly when the polynomials are affine (a pinhole colour camera without
//! distortion, rotated only about its axis: the simulated sensor's parameters). Otherwise
//! they differ because (a) a cubic in depth-camera coordinates is not a distortion about the
//! colour principal point, (b) factory parallax is along x only and independent of the pixel,
//! while a rig's parallax follows `T` and the ray. [`FactoryFit`] reports the RMS and largest
//! error of the fit over every depth pixel at those depths.
//!
//! Measured against kinect-usb's `Registration::map_point` (the f32 reference that reproduces
//! libfreenect2's vectors), every depth pixel at 0.5–4.5 m (`tests/cli_rig.rs`):
//!
//! * the simulated sensor (affine polynomial): RMS 5e-5 px, max 2e-4 px (f32 rounding);
//! * the test vectors' factory parameters (a cubic with −0.004 x³-type terms): RMS 1.64 px,
//!   max 10.6 px in the 1920×1080 colour image (RMS 2.9 px at 0.5 m, 0.8 px at 1.2 m,
//!   1.5 px at 4.5 m; the largest errors in the image corners at 0.5 m). This is the two
//!   models' disagreement: the factory distorts the depth ray and then shifts by the
//!   parallax, so its distortion centre moves across the colour image with depth; a rig's
//!   distortion is centred on a fixed principal point.
//!
//! Pixel origin: the registration maps use integer pixel centres for the depth camera (no
//! `+0.5`), as kfuse does, so `cx`, `cy` are taken as they are; the decoder's own point cloud
//! (spec §11.4) adds `+0.5`, a half-pixel inconsistency of the reference kept there.

use geometry::GeometryError;
use geometry::{CameraModel, Distortion, Intrinsics, Rig, RigidTransform};
use nalgebra::{DMatrix, DVector, SMatrix, SVector, Vector3};
use serde_json::{Value, json};
use std::path::Path;

use super::yaml::{MAX_IMAGE_SIDE, fmt_err};

/// Depth quantum of the factory polynomial (spec §11.1 `qd`).
const QD: f64 = 0.01;
/// Colour quantum of the factory polynomial (spec §11.1 `qc`).
const QC: f64 = 0.002199;
/// Depths the rig is fitted and checked at, mm: the Kinect v2's range 0.5–4.5 m, denser
/// near, where parallax changes fastest.
pub const FIT_DEPTHS_MM: [f64; 7] = [500.0, 700.0, 1000.0, 1400.0, 2000.0, 3000.0, 4500.0];
/// Grid step of the fit's depth pixels (every 4th pixel: ~13 000 per depth, plenty for 12
/// parameters; the error is then measured on every pixel).
pub const FIT_STEP_PX: usize = 4;
/// Levenberg–Marquardt iterations allowed (the sim's exact case converges in < 10).
const LM_MAX_ITERATIONS: usize = 100;
/// Relative cost decrease below which the fit has converged.
const LM_RELATIVE_TOLERANCE: f64 = 1e-14;
/// Relative step of the numerical Jacobian (central differences; ~cube root of f64 epsilon).
const JACOBIAN_STEP: f64 = 1e-6;

/// The factory parameters read from `kinect_params.json` (f32 on the device, widened).
#[derive(Debug, Clone, PartialEq)]
pub struct FactoryParams {
    /// The depth camera (exact; see the module docs).
    pub depth: CameraModel,
    /// Colour image size.
    pub color_size: (usize, usize),
    /// Colour focal length `f` (px).
    pub f: f64,
    /// Colour principal point x (px).
    pub cx: f64,
    /// Colour principal point y (px).
    pub cy: f64,
    /// Reference depth of the x offset (mm).
    pub shift_d: f64,
    /// Parallax constant (mm): the baseline along colour x.
    pub shift_m: f64,
    /// x polynomial (x³, y³, x²y, xy², x², y², xy, x, y, 1).
    pub mx: [f64; 10],
    /// y polynomial, same monomials.
    pub my: [f64; 10],
    /// The sensor's serial number, where the file has one.
    pub serial: Option<String>,
    /// Whether the parameters (and the images beside the file) are as the scene is, kfuse's
    /// orientation rule (`"image_orientation": "scene"`, version 2), or mirrored as the sensor
    /// streams them (version 1: `kfuse capture` before the rule; `kinect_usb::orientation`).
    pub scene_orientation: bool,
}

/// The newest `kinect_params.json` version this kfuse reads (`kfuse_capture::shots::PARAMS_VERSION`).
const NEWEST_PARAMS_VERSION: u64 = 2;

/// The fit of the factory registration failed; `message` says why.
fn diverged(message: String) -> GeometryError {
    GeometryError::InvalidInput(format!(
        "Kinect factory registration: the optimisation diverged ({message})"
    ))
}

fn num(v: &Value, path: &Path, key: &str) -> Result<f64, GeometryError> {
    v.as_f64()
        // The device stores f32; reading the printed value as f32 recovers it exactly.
        .map(|x| x as f32 as f64)
        .filter(|x| x.is_finite())
        .ok_or_else(|| fmt_err(path, format!("'{key}' must be a finite number")))
}

fn side(v: &Value, path: &Path, key: &str) -> Result<usize, GeometryError> {
    v.as_u64().filter(|n| (1..=MAX_IMAGE_SIDE).contains(n)).map(|n| n as usize).ok_or_else(|| {
        fmt_err(path, format!("'{key}' must be a whole number in 1..={MAX_IMAGE_SIDE}"))
    })
}

impl FactoryParams {
    /// Reads the parsed `kinect_params.json`.
    pub fn from_json(v: &Value, path: &Path) -> Result<Self, GeometryError> {
        let version = v.get("version").and_then(Value::as_u64).unwrap_or(0);
        if version > NEWEST_PARAMS_VERSION {
            return Err(fmt_err(
                path,
                "kinect_params.json version is newer than this kfuse; upgrade kfuse",
            ));
        }
        let scene_orientation = match v.get("image_orientation") {
            None if version < 2 => false,
            Some(Value::String(o)) if o == "scene" => true,
            Some(Value::String(o)) if o == "sensor" => false,
            _ => {
                return Err(fmt_err(
                    path,
                    "'image_orientation' must be \"scene\" or \"sensor\" (version 2 files have it)",
                ));
            }
        };
        let get = |obj: &str, key: &str| -> Result<f64, GeometryError> {
            num(&v[obj][key], path, &format!("{obj}.{key}"))
        };
        let poly = |key: &str| -> Result<[f64; 10], GeometryError> {
            let arr = v["color"][key].as_array().filter(|a| a.len() == 10).ok_or_else(|| {
                fmt_err(path, format!("'color.{key}' must be a list of 10 numbers"))
            })?;
            let mut out = [0.0; 10];
            for (o, x) in out.iter_mut().zip(arr) {
                *o = num(x, path, &format!("color.{key}"))?;
            }
            Ok(out)
        };
        let depth = CameraModel::new(
            side(&v["depth"]["width"], path, "depth.width")?,
            side(&v["depth"]["height"], path, "depth.height")?,
            Intrinsics::new(
                get("depth", "fx")?,
                get("depth", "fy")?,
                get("depth", "cx")?,
                get("depth", "cy")?,
            ),
            Distortion {
                k1: get("depth", "k1")?,
                k2: get("depth", "k2")?,
                p1: get("depth", "p1")?,
                p2: get("depth", "p2")?,
                k3: get("depth", "k3")?,
            },
        );
        depth.validate().map_err(|e| fmt_err(path, format!("depth camera: {e}")))?;
        let p = FactoryParams {
            depth,
            color_size: (
                side(&v["color"]["width"], path, "color.width")?,
                side(&v["color"]["height"], path, "color.height")?,
            ),
            f: get("color", "fx")?,
            cx: get("color", "cx")?,
            cy: get("color", "cy")?,
            shift_d: get("color", "shift_d")?,
            shift_m: get("color", "shift_m")?,
            mx: poly("mx")?,
            my: poly("my")?,
            serial: v.get("serial").and_then(Value::as_str).map(str::to_owned),
            scene_orientation,
        };
        if !(p.f > 0.0) || !(p.shift_d != 0.0) {
            return Err(fmt_err(path, "'color.fx' must be positive and 'color.shift_d' non-zero"));
        }
        Ok(p)
    }

    /// The factory colour pixel of undistorted depth pixel `(x, y)` at depth `z_mm` (spec
    /// §11.1–11.2 in f64; kinect-usb's `Registration::map_point` is the f32 reference).
    pub fn map_point(&self, x: f64, y: f64, z_mm: f64) -> (f64, f64) {
        let k = &self.depth.intrinsics;
        let (mx, my) = ((x - k.cx) * QD, (y - k.cy) * QD);
        let poly = |c: &[f64; 10]| {
            c[0] * mx * mx * mx
                + c[1] * my * my * my
                + c[2] * mx * mx * my
                + c[3] * my * my * mx
                + c[4] * mx * mx
                + c[5] * my * my
                + c[6] * mx * my
                + c[7] * mx
                + c[8] * my
                + c[9]
        };
        let rx = poly(&self.mx) / (self.f * QC) - self.shift_m / self.shift_d;
        let ry = poly(&self.my) / QC + self.cy;
        ((rx + self.shift_m / z_mm) * self.f + self.cx, ry)
    }

    /// The samples `(depth point in metres, factory colour pixel)` over undistorted depth
    /// pixels every `step` px at [`FIT_DEPTHS_MM`], where the factory registration maps a
    /// depth sample (on both images).
    fn samples(&self, step: usize) -> Vec<(Vector3<f64>, [f64; 2])> {
        let d = &self.depth;
        let (cw, ch) = self.color_size;
        let color_bounds =
            CameraModel::new(cw, ch, Intrinsics::new(1.0, 1.0, 0.0, 0.0), Distortion::NONE);
        let mut out = Vec::new();
        for y in (0..d.height).step_by(step) {
            for x in (0..d.width).step_by(step) {
                let k = &d.intrinsics;
                let ray = Vector3::new((x as f64 - k.cx) / k.fx, (y as f64 - k.cy) / k.fy, 1.0);
                match d.project(&ray) {
                    Some(p) if d.contains(p.x, p.y) => {}
                    _ => continue,
                }
                for z in FIT_DEPTHS_MM {
                    let (u, v) = self.map_point(x as f64, y as f64, z);
                    if color_bounds.contains(u, v) {
                        out.push((ray * (z * 1e-3), [u, v]));
                    }
                }
            }
        }
        out
    }

    /// Fits the rig (module docs) and measures its error on every depth pixel.
    pub fn to_rig(&self) -> Result<FactoryFit, GeometryError> {
        let fit_samples = self.samples(FIT_STEP_PX);
        if fit_samples.len() < 100 {
            return Err(diverged(format!(
                "only {} depth samples map into the colour image; the colour parameters are not a Kinect's",
                fit_samples.len()
            )));
        }
        // Start: the colour camera where the depth principal ray lands at infinity, the
        // factory focal length, no rotation, the parallax as an x baseline.
        let k = &self.depth.intrinsics;
        let far = self.map_point(k.cx, k.cy, f64::INFINITY);
        let mut theta = SVector::<f64, 12>::from_column_slice(&[
            self.f,
            self.f,
            far.0,
            far.1,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            self.shift_m * 1e-3,
            0.0,
            0.0,
        ]);
        let (cw, ch) = self.color_size;
        let cost = |th: &SVector<f64, 12>| residuals(th, &fit_samples, (cw, ch)).norm_squared();
        let mut current = cost(&theta);
        let mut lambda = 1e-3;
        for _ in 0..LM_MAX_ITERATIONS {
            let r = residuals(&theta, &fit_samples, (cw, ch));
            let mut jac = DMatrix::<f64>::zeros(r.len(), 12);
            for i in 0..12 {
                let h = JACOBIAN_STEP * theta[i].abs().max(1e-3);
                let (mut a, mut b) = (theta, theta);
                a[i] += h;
                b[i] -= h;
                let col = (residuals(&a, &fit_samples, (cw, ch))
                    - residuals(&b, &fit_samples, (cw, ch)))
                    / (2.0 * h);
                jac.set_column(i, &col);
            }
            let jtj: SMatrix<f64, 12, 12> =
                (jac.transpose() * &jac).fixed_view::<12, 12>(0, 0).into();
            let jtr: SVector<f64, 12> = (jac.transpose() * &r).fixed_view::<12, 1>(0, 0).into();
            let mut improved = false;
            while lambda < 1e12 {
                let mut a = jtj;
                for i in 0..12 {
                    a[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
                }
                let Some(step) = a.cholesky().map(|c| c.solve(&jtr)) else {
                    lambda *= 10.0;
                    continue;
                };
                let next = theta - step;
                let c = cost(&next);
                if c.is_finite() && c <= current {
                    let decrease = (current - c) / current.max(f64::MIN_POSITIVE);
                    theta = next;
                    current = c;
                    lambda = (lambda / 10.0).max(1e-12);
                    improved = decrease > LM_RELATIVE_TOLERANCE;
                    break;
                }
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
        let rig = rig_of(&theta, &self.depth, (cw, ch));
        rig.validate().map_err(|e| diverged(e.to_string()))?;
        // The error on every depth pixel.
        let all = self.samples(1);
        let errs: Vec<f64> = all
            .iter()
            .map(|(p, uv)| match rig.color.project(&rig.color_from_depth.apply(p)) {
                Some(q) => ((q.x - uv[0]).powi(2) + (q.y - uv[1]).powi(2)).sqrt(),
                None => f64::INFINITY,
            })
            .collect();
        let rms_px = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt();
        let max_px = errs.iter().copied().fold(0.0, f64::max);
        let report = json!({
            "source": "Kinect v2 factory parameters (kinect_params.json)",
            "serial": self.serial,
            "approximation": "colour camera fitted to the factory registration: pinhole + radial k1, k2; the factory's cubic mapping and x-only parallax are not exactly a pinhole rig",
            "fit_depths_m": FIT_DEPTHS_MM.iter().map(|z| z * 1e-3).collect::<Vec<_>>(),
            "fit_rms_px": rms_px,
            "fit_max_px": max_px,
            "fit_samples": all.len(),
        });
        Ok(FactoryFit { rig, rms_px, max_px, samples: all.len(), report })
    }
}

/// The rig fitted to factory parameters and how well it reproduces them.
#[derive(Debug, Clone)]
pub struct FactoryFit {
    /// The rig.
    pub rig: Rig,
    /// RMS colour-pixel error against the factory mapping over every depth pixel at
    /// [`FIT_DEPTHS_MM`], px.
    pub rms_px: f64,
    /// Largest such error, px.
    pub max_px: f64,
    /// Number of (pixel, depth) samples measured.
    pub samples: usize,
    /// Provenance and the numbers above, for the rig's `calibration` field.
    pub report: Value,
}

impl FactoryFit {
    /// One line for the user.
    pub fn summary(&self) -> String {
        format!(
            "colour camera fitted to the factory registration (pinhole + k1, k2): colour-pixel error RMS {:.4} px, max {:.4} px over {} (depth pixel, depth) samples at 0.5–4.5 m",
            self.rms_px, self.max_px, self.samples
        )
    }
}

fn rig_of(th: &SVector<f64, 12>, depth: &CameraModel, (w, h): (usize, usize)) -> Rig {
    let color = CameraModel::new(
        w,
        h,
        Intrinsics::new(th[0], th[1], th[2], th[3]),
        Distortion { k1: th[4], k2: th[5], p1: 0.0, p2: 0.0, k3: 0.0 },
    );
    let cfd = RigidTransform::from_axis_angle(
        Vector3::new(th[6], th[7], th[8]),
        Vector3::new(th[9], th[10], th[11]),
    );
    Rig::new(*depth, color, cfd)
}

fn residuals(
    th: &SVector<f64, 12>,
    samples: &[(Vector3<f64>, [f64; 2])],
    size: (usize, usize),
) -> DVector<f64> {
    let rig = rig_of(
        th,
        &CameraModel::new(1, 1, Intrinsics::new(1.0, 1.0, 0.0, 0.0), Distortion::NONE),
        size,
    );
    let mut r = DVector::zeros(2 * samples.len());
    for (i, (p, uv)) in samples.iter().enumerate() {
        let q = rig.color.project(&rig.color_from_depth.apply(p));
        // A point behind the colour camera (only for absurd parameters) costs a large error.
        let (eu, ev) = q.map(|q| (q.x - uv[0], q.y - uv[1])).unwrap_or((1e6, 1e6));
        r[2 * i] = eu;
        r[2 * i + 1] = ev;
    }
    r
}
