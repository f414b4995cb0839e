//! Depth calibration (issue 16): the time-of-flight camera's measured z against the board
//! plane its own IR image shows, and a fitted [`DepthCorrection`].
//!
//! The IR camera *is* the depth camera, so a board pose from the IR image (`camera_from_board`
//! of a calibration) gives the true z of every depth pixel on the board: along the pixel's
//! undistorted ray `(x, y, 1)`, the plane `n·X = n·t` is met at `z = n·t / n·(x, y, 1)`.
//!
//! Stages ([`fit_depth_correction`]):
//! 1. **samples** ([`board_samples`]): every valid depth pixel whose ray meets the board
//!    inside the inner corners' rectangle (the board's outline eroded by one square: no edge
//!    pixels mixing board and background) and whose IR is not saturated (glare), with its
//!    measured z and the plane's z; gross outliers (more than [`PIXEL_GATE_M`] from their
//!    view's median residual: flying pixels, multipath) are left out.
//! 2. **fit**: linear least squares of `z_measured − z_plane` on the model's terms
//!    (`geometry::depth_correction`: `offset`, `scale`·z, spatial terms), 1σ of every
//!    parameter from `(AᵀA)⁻¹·s²` and from a jackknife over views (the larger; module
//!    constants say why), per-view RMS before and after.
//! 3. **order from the data**: the spatial term groups `radial2`, `x`+`y`, `radial4` are added
//!    one at a time while the best one lowers the leave-one-view-out prediction RMS by
//!    [`MIN_CV_GAIN`].
//! 4. **views that disagree** (per-view median residual after the fit beyond [`VIEW_MAD_K`]
//!    robust σ of all views' medians) are rejected and the fit repeated.
//!
//! 5. **what it depends on** ([`fit_depth_from_corners`]): the board poses, and so the plane
//!    z, come from the IR corners through the IR intrinsics and the printed square's side; the
//!    fit is repeated with the focal length and with the square [`SENSITIVITY_STEP`] larger and
//!    smaller (poses re-solved from the same corners, same terms, same views) and the central
//!    difference reported per +1 % of each ([`DepthSensitivity`]). A scale beyond
//!    [`MAX_PLAUSIBLE_SCALE`] is refused by [`check_plausible`] (the caller's `--force` skips
//!    it): such a scale says the distances were wrong, not the sensor.
//!
//! A correction therefore belongs with the intrinsics it was fitted with: the same depth
//! images fitted with another calibration's focal length give another offset and scale (on a
//! real Kinect v2 set, +40.5 mm with kfuse's intrinsics against iai_kinect2's +25.5 mm with
//! its own); the rig file keeps the two together.
//!
//! Size (~900 lines): the four stages share the sample and design-matrix types and the
//! view-rejection loop wraps all three, so splitting them would only move private helpers
//! into `pub(crate)`; the unit tests live in `tests.rs`.

use geometry::depth_correction::{DepthCorrection, DepthTerm, DepthTermKind, ImageCoords};
use geometry::{CameraModel, Image, RigidTransform};
use nalgebra::{DMatrix, DVector, Vector3};

use crate::mono::{CalibFlags, MonoCalibration, calibrate_mono};
use crate::{Board, CalibError, ViewCorners};

/// Fewest views with board samples a fit needs: 4. Offset and scale need two distances, the
/// spatial terms boards in several parts of the image, and the rejection of a disagreeing view
/// a majority to disagree with.
pub const MIN_DEPTH_VIEWS: usize = 4;
/// Smallest spread of the views' median board distance, metres: 0.5 m. Offset and scale are
/// told apart by distance alone; over a narrower span their estimates trade off (a 1 mm error
/// at each end of 0.5 m is 0.2 % of scale).
pub const MIN_DISTANCE_SPAN_M: f64 = 0.5;
/// Fewest valid board pixels for a view to count: 200 (a 7x5 board of 40 mm squares at 3 m
/// still covers ~1 000 depth pixels; fewer means it is mostly hidden or saturated).
pub const MIN_PIXELS_PER_VIEW: usize = 200;
/// Gross-outlier gate per pixel, metres from its view's median residual: 30 mm. Within one
/// view a real depth error varies by well under that (the Kinect's corner term is ~1 cm);
/// flying pixels and multipath are off by decimetres.
pub const PIXEL_GATE_M: f64 = 0.03;
/// IR value (16-bit, decoder units) at which a pixel is glare: the decoder's
/// amplitude saturates at 65 535, where the depth is no longer trustworthy.
pub const IR_SATURATED: u16 = 65_535;
/// A spatial term group is kept when it lowers the leave-one-view-out prediction RMS (every
/// view predicted by the fit of the others) by at least this fraction: 1 %. Cross-validation
/// over views, not the fit's own RMS, because a term that only bends the fit to the pose
/// errors of a few views makes the views left out worse; 1 % is well above the few 0.1 % that
/// chance moves the cross-validated RMS of views that agree.
pub const MIN_CV_GAIN: f64 = 0.01;
/// A view is rejected when its median residual after the fit is more than this many robust σ
/// (1.4826·MAD of all views' medians) from their median: 4. Between views that agree the
/// medians scatter by the pose noise only; a moved board, a wrong IR/depth pairing or a
/// board-sized glare spot puts a view tens of σ away, and 4σ keeps a normal view with
/// probability 0.9999.
pub const VIEW_MAD_K: f64 = 4.0;
/// Floor of that robust σ at 1 m, metres: 0.5 mm, growing with z² beyond 1 m. The plane of
/// a board pose from IR corners is uncertain by about z²·σ_corner/(f·board size)/√corners
/// (0.1 px corners, f = 365 px, a 24 cm board of 35 corners: 0.2 mm at 1 m, 0.8 mm at 2 m), so
/// a far view's median legitimately sits further off than the near views' spread says; and
/// views of a noise-free simulation agree to a few µm, where 20 µm is no disagreement.
pub const VIEW_SIGMA_FLOOR_M: f64 = 5e-4;
/// Relative step of the focal length and the square size for [`DepthSensitivity`]: 1 %.
/// Large enough that the poses re-solved from the same corners move far beyond the LM's
/// convergence (1e-4 px), small enough that the fit's response is linear to well under 1 %
/// of itself (the square's effect on the scale, `(1+s)/(1+ε) − 1`, deviates from its tangent
/// by ε² = 0.01 % of z); the central difference cancels the quadratic term.
pub const SENSITIVITY_STEP: f64 = 0.01;
/// Largest |scale| a Kinect v2's depth plausibly has: 5 %. Its time-of-flight depth's scale
/// errors are about ±1 % (the sensor's own 0.5 % plus unit-to-unit spread); 5 % is 10 cm at
/// 2 m, beyond any unit described. Every 1 % error of the square or of the IR focal length
/// moves the fitted scale by about 1 % ([`DepthSensitivity`]), so 5 % passes a real sensor with
/// its fit's σ (≤ 0.5 %) and a square measured to 1 mm in 40, and catches a square off by 2 mm
/// (37–38 mm for 40 mm) or intrinsics from another calibration that far off.
pub const MAX_PLAUSIBLE_SCALE: f64 = 0.05;
/// Rejection rounds at most (each round refits; a stable set ends earlier).
const MAX_REJECTION_ROUNDS: usize = 3;

/// The spatial term groups tried beyond offset + scale, in order of preference.
const CANDIDATE_GROUPS: [&[DepthTermKind]; 3] =
    [&[DepthTermKind::Radial2], &[DepthTermKind::X, DepthTermKind::Y], &[DepthTermKind::Radial4]];

/// One view's input: the board pose from the IR image, the raw depth image (metres, 0 or NaN
/// = none) and optionally the 16-bit IR image (glare mask).
#[derive(Debug, Clone)]
pub struct DepthView {
    /// The view's name (the depth file).
    pub name: String,
    /// `X_camera = R·X_board + t` from the IR calibration.
    pub camera_from_board: RigidTransform,
    /// Depth (z), metres.
    pub depth: Image<f32>,
    /// IR, 16-bit decoder units.
    pub ir: Option<Image<u16>>,
}

/// One board pixel: raw pixel, plane z and measured z (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Pixel column.
    pub u: f32,
    /// Pixel row.
    pub v: f32,
    /// The board plane's z along the pixel's ray.
    pub z_plane: f64,
    /// The depth image's z.
    pub z_measured: f64,
}

/// Per-view result.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthViewReport {
    /// The view's name.
    pub name: String,
    /// Board pixels used.
    pub pixels: usize,
    /// Median plane z, metres.
    pub median_z_m: f64,
    /// RMS of `z_measured − z_plane` (no correction), metres.
    pub rms_before_m: f64,
    /// RMS of the residual after the model, metres.
    pub rms_after_m: f64,
    /// Median residual after the model, metres.
    pub median_after_m: f64,
    /// Why the view was left out of the fit (`None`: used).
    pub rejected: Option<String>,
}

/// One step of choosing the model's order.
#[derive(Debug, Clone, PartialEq)]
pub struct OrderStep {
    /// The terms ("offset+scale", "+radial2").
    pub terms: String,
    /// RMS of the fit's residual, metres.
    pub rms_m: f64,
    /// Leave-one-view-out prediction RMS, metres.
    pub cv_rms_m: f64,
    /// Whether the terms were kept.
    pub kept: bool,
}

/// The fit (module docs).
#[derive(Debug, Clone)]
pub struct DepthFit {
    /// The correction, with 1σ per term.
    pub correction: DepthCorrection,
    /// Every view, used or not.
    pub views: Vec<DepthViewReport>,
    /// The samples of every view (for figures), in view order.
    pub samples: Vec<Vec<Sample>>,
    /// RMS over the used views' pixels before / after, metres.
    pub rms_before_m: f64,
    /// See `rms_before_m`.
    pub rms_after_m: f64,
    /// Residual σ² of the final fit, m².
    pub residual_variance: f64,
    /// The term groups tried and what they gave.
    pub order_steps: Vec<OrderStep>,
    /// Distance range of the used views' median z, metres.
    pub distance_range_m: (f64, f64),
    /// Offset + scale alone on the used views: its residual map shows the spatial structure
    /// the order was chosen from.
    pub base: Vec<DepthTerm>,
    /// How the terms move with the IR focal length and the square size
    /// ([`fit_depth_from_corners`]; `None` from [`fit_depth_correction`], which has no corners).
    pub sensitivity: Option<DepthSensitivity>,
    /// Shots without a board pose from their IR image (name, why), left out before the fit
    /// ([`fit_depth_from_corners`]).
    pub no_pose: Vec<(String, String)>,
}

/// One term's response to the IR focal length and the square size: the change of its value
/// (its own unit: metres, unitless for the scale) per +1 % of each.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TermSensitivity {
    /// Which term.
    pub kind: DepthTermKind,
    /// Change of the value per +1 % of the IR focal length (fx and fy together).
    pub per_percent_focal: f64,
    /// Change of the value per +1 % of the board's square side.
    pub per_percent_square: f64,
}

/// The correction's dependence on what the board poses were computed with (module docs,
/// stage 5): per term the central difference of re-fits with the IR focal length and the
/// square [`SENSITIVITY_STEP`] larger and smaller.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthSensitivity {
    /// The relative step of the re-fits (fraction).
    pub step: f64,
    /// The terms in the correction's order.
    pub terms: Vec<TermSensitivity>,
}

impl DepthSensitivity {
    /// The entry of `kind`, if the correction has that term.
    pub fn of(&self, kind: DepthTermKind) -> Option<&TermSensitivity> {
        self.terms.iter().find(|t| t.kind == kind)
    }
}

/// One shot for [`fit_depth_from_corners`]: the board's corners in its IR image, the raw depth
/// image (metres, 0 or NaN = none) and optionally the 16-bit IR image (glare mask).
#[derive(Debug, Clone)]
pub struct DepthShot {
    /// The shot's name (the depth file).
    pub name: String,
    /// The board's corners detected in the IR image.
    pub corners: ViewCorners,
    /// Depth (z), metres.
    pub depth: Image<f32>,
    /// IR, 16-bit decoder units.
    pub ir: Option<Image<u16>>,
}

/// The board samples of one view (stage 1).
///
/// `rays` is `camera.ray_table()` (computed once for all views).
pub fn board_samples(
    camera: &CameraModel,
    rays: &[[f32; 2]],
    board: &Board,
    view: &DepthView,
) -> Vec<Sample> {
    samples_of(camera, rays, board, &view.camera_from_board, &view.depth, view.ir.as_ref())
}

/// [`board_samples`] of a pose, a depth and an IR image (the sensitivity's re-fits move the
/// pose only).
fn samples_of(
    camera: &CameraModel,
    rays: &[[f32; 2]],
    board: &Board,
    camera_from_board: &RigidTransform,
    depth: &Image<f32>,
    ir: Option<&Image<u16>>,
) -> Vec<Sample> {
    let (w, h) = depth.size();
    if (w, h) != (camera.width, camera.height) || rays.len() != w * h {
        return Vec::new();
    }
    let r = camera_from_board.rotation.matrix();
    let t = camera_from_board.translation;
    let n: Vector3<f64> = r.column(2).into();
    let d0 = n.dot(&t);
    let (bx_max, by_max) =
        ((board.cols - 1) as f64 * board.square_m, (board.rows - 1) as f64 * board.square_m);
    let mut out = Vec::new();
    for v in 0..h {
        for u in 0..w {
            let zm = f64::from(*depth.get(u, v));
            if !(zm > 0.0 && zm.is_finite()) {
                continue;
            }
            if ir.is_some_and(|ir| *ir.get(u, v) == IR_SATURATED) {
                continue;
            }
            let [rx, ry] = rays[v * w + u];
            if !(rx.is_finite() && ry.is_finite()) {
                continue;
            }
            let dir = Vector3::new(f64::from(rx), f64::from(ry), 1.0);
            let nd = n.dot(&dir);
            if nd.abs() < 1e-9 {
                continue;
            }
            let z = d0 / nd;
            if !(z > 0.0) {
                continue;
            }
            let q = r.transpose() * (dir * z - t);
            if !(0.0..=bx_max).contains(&q.x) || !(0.0..=by_max).contains(&q.y) {
                continue;
            }
            out.push(Sample { u: u as f32, v: v as f32, z_plane: z, z_measured: zm });
        }
    }
    // Gross outliers against the view's own median residual.
    if !out.is_empty() {
        let med = median(out.iter().map(|s| s.z_measured - s.z_plane).collect());
        out.retain(|s| (s.z_measured - s.z_plane - med).abs() <= PIXEL_GATE_M);
    }
    out
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 { v[m] } else { 0.5 * (v[m - 1] + v[m]) }
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    (s / n.max(1) as f64).sqrt()
}

/// Regressor `j` of one sample: the plane z for the scale, else the spatial term.
fn regressor(coords: &ImageCoords, kind: DepthTermKind, s: &Sample) -> f64 {
    if kind == DepthTermKind::Scale {
        s.z_plane
    } else {
        coords.term(kind, f64::from(s.u), f64::from(s.v))
    }
}

/// The model's `z_measured − z_plane` of one sample with coefficients `x`.
fn predict(coords: &ImageCoords, terms: &[DepthTermKind], x: &[f64], s: &Sample) -> f64 {
    terms.iter().zip(x).map(|(&k, x)| x * regressor(coords, k, s)).sum()
}

/// Per-view normal-equation sums of one term set (`AᵀA`, `Aᵀy`, `yᵀy`, count): every fit
/// of a subset of the views (the jackknife, the rejection rounds) is then a small solve.
struct Sums {
    ata: Vec<DMatrix<f64>>,
    atb: Vec<DVector<f64>>,
    yy: Vec<f64>,
    n: Vec<usize>,
}

fn sums(coords: &ImageCoords, terms: &[DepthTermKind], samples: &[Vec<Sample>]) -> Sums {
    use rayon::prelude::*;
    let p = terms.len();
    let per: Vec<(DMatrix<f64>, DVector<f64>, f64, usize)> = samples
        .par_iter()
        .map(|view| {
            let mut ata = DMatrix::<f64>::zeros(p, p);
            let mut atb = DVector::<f64>::zeros(p);
            let mut yy = 0.0;
            let mut a = vec![0.0; p];
            for s in view {
                for (j, &k) in terms.iter().enumerate() {
                    a[j] = regressor(coords, k, s);
                }
                let y = s.z_measured - s.z_plane;
                for i in 0..p {
                    atb[i] += a[i] * y;
                    for j in 0..p {
                        ata[(i, j)] += a[i] * a[j];
                    }
                }
                yy += y * y;
            }
            (ata, atb, yy, view.len())
        })
        .collect();
    let mut out = Sums { ata: vec![], atb: vec![], yy: vec![], n: vec![] };
    for (a, b, y, n) in per {
        out.ata.push(a);
        out.atb.push(b);
        out.yy.push(y);
        out.n.push(n);
    }
    out
}

/// Least squares on the views `views` (indices): coefficients, (AᵀA)⁻¹, the residual sum of
/// squares and the sample count. `None` when the normal matrix is singular.
fn solve(s: &Sums, views: &[usize]) -> Option<(DVector<f64>, DMatrix<f64>, f64, usize)> {
    let p = s.atb.first()?.len();
    let mut ata = DMatrix::<f64>::zeros(p, p);
    let mut atb = DVector::<f64>::zeros(p);
    let (mut yy, mut n) = (0.0, 0);
    for &i in views {
        ata += &s.ata[i];
        atb += &s.atb[i];
        yy += s.yy[i];
        n += s.n[i];
    }
    // Column scaling keeps the normal matrix well conditioned (z ~ 1 m next to ρ⁴ ~ 0.01).
    let scale: Vec<f64> = (0..p).map(|j| ata[(j, j)].sqrt().max(1e-300)).collect();
    let mut inv = ata.clone();
    for i in 0..p {
        for j in 0..p {
            inv[(i, j)] /= scale[i] * scale[j];
        }
    }
    let mut inv = inv.try_inverse()?;
    for i in 0..p {
        for j in 0..p {
            inv[(i, j)] /= scale[i] * scale[j];
        }
    }
    let x = &inv * &atb;
    // Σ(y − a·x)² = yᵀy − 2xᵀAᵀy + xᵀAᵀAx (y is centimetres at most: no cancellation worth
    // the name in f64).
    let rss = (yy - 2.0 * x.dot(&atb) + x.dot(&(&ata * &x))).max(0.0);
    x.iter().all(|v| v.is_finite()).then_some((x, inv, rss, n))
}

/// A fit with σ: coefficients, 1σ (max of covariance and jackknife), residual variance.
struct Fitted {
    x: DVector<f64>,
    std: Vec<f64>,
    variance: f64,
    rms: f64,
    /// Leave-one-view-out prediction RMS (NaN with fewer than 3 views).
    cv_rms: f64,
}

fn fit_terms(
    coords: &ImageCoords,
    terms: &[DepthTermKind],
    samples: &[Vec<Sample>],
    views: &[usize],
) -> Option<Fitted> {
    let s = sums(coords, terms, samples);
    let (x, inv, rss, n) = solve(&s, views)?;
    let p = terms.len();
    let variance = rss / (n.saturating_sub(p)).max(1) as f64;
    // Jackknife over views: the pixels of one view share that view's pose error, so the
    // covariance formula (which takes every pixel as independent) understates σ by up to the
    // square root of the pixels per view; leaving out one view at a time measures it.
    let m = views.len();
    let mut jk = vec![0.0; p];
    let mut cv_rms = f64::NAN;
    if m >= 3 {
        let subs: Vec<DVector<f64>> = (0..m)
            .filter_map(|leave| {
                let rest: Vec<usize> = views
                    .iter()
                    .enumerate()
                    .filter(|&(j, _)| j != leave)
                    .map(|(_, &v)| v)
                    .collect();
                solve(&s, &rest).map(|s| s.0)
            })
            .collect();
        if subs.len() == m {
            // The left-out view's residual sum of squares under the others' fit.
            let cv: f64 = views
                .iter()
                .zip(&subs)
                .map(|(&v, x)| {
                    (s.yy[v] - 2.0 * x.dot(&s.atb[v]) + x.dot(&(&s.ata[v] * x))).max(0.0)
                })
                .sum();
            cv_rms = (cv / n.max(1) as f64).sqrt();
            let mean: DVector<f64> = subs.iter().fold(DVector::zeros(p), |a, s| a + s) / m as f64;
            for (j, jv) in jk.iter_mut().enumerate() {
                let ss: f64 = subs.iter().map(|s| (s[j] - mean[j]).powi(2)).sum();
                *jv = ((m - 1) as f64 / m as f64 * ss).sqrt();
            }
        }
    }
    let std = (0..p).map(|j| (inv[(j, j)] * variance).max(0.0).sqrt().max(jk[j])).collect();
    Some(Fitted { x, std, variance, rms: (rss / n.max(1) as f64).sqrt(), cv_rms })
}

fn terms_name(terms: &[DepthTermKind]) -> String {
    terms.iter().map(|t| t.name()).collect::<Vec<_>>().join("+")
}

/// Model order from the data (stage 3): offset + scale, then the candidate groups.
fn choose_terms(
    coords: &ImageCoords,
    samples: &[Vec<Sample>],
    views: &[usize],
    steps: &mut Vec<OrderStep>,
) -> Result<Vec<DepthTermKind>, CalibError> {
    let mut terms = vec![DepthTermKind::Offset, DepthTermKind::Scale];
    let singular = || {
        CalibError::DepthFit {
        message: "the normal equations are singular: the views do not separate offset and scale; add views at other distances".into(),
    }
    };
    let mut current = fit_terms(coords, &terms, samples, views).ok_or_else(singular)?;
    let step = |terms: String, f: &Fitted, kept: bool| OrderStep {
        terms,
        rms_m: f.rms,
        cv_rms_m: f.cv_rms,
        kept,
    };
    steps.push(step(terms_name(&terms), &current, true));
    let mut left: Vec<&[DepthTermKind]> = CANDIDATE_GROUPS.to_vec();
    while !left.is_empty() {
        let mut best: Option<(usize, Vec<DepthTermKind>, Fitted)> = None;
        for (gi, g) in left.iter().enumerate() {
            let mut t = terms.clone();
            t.extend_from_slice(g);
            if let Some(f) = fit_terms(coords, &t, samples, views)
                && best.as_ref().is_none_or(|b| f.cv_rms < b.2.cv_rms)
            {
                best = Some((gi, t, f));
            }
        }
        let Some((gi, t, f)) = best else { break };
        let keep = f.cv_rms <= current.cv_rms * (1.0 - MIN_CV_GAIN);
        steps.push(step(format!("+{}", terms_name(&t[terms.len()..])), &f, keep));
        if !keep {
            break;
        }
        terms = t;
        current = f;
        left.remove(gi);
    }
    Ok(terms)
}

/// Fits the depth correction of `views` seen by the IR/depth `camera` (module docs).
///
/// Errors: fewer than [`MIN_DEPTH_VIEWS`] views with [`MIN_PIXELS_PER_VIEW`] board pixels, or
/// their distances spanning less than [`MIN_DISTANCE_SPAN_M`] (the message says how many
/// views and which distance range it has and needs), or a depth image of another size than
/// the camera's.
pub fn fit_depth_correction(
    camera: &CameraModel,
    board: &Board,
    views: &[DepthView],
) -> Result<DepthFit, CalibError> {
    for v in views {
        if v.depth.size() != (camera.width, camera.height) {
            let (w, h) = v.depth.size();
            return Err(CalibError::DepthFit {
                message: format!(
                    "{}: depth image is {w}x{h} but the IR camera is {}x{}; give the raw depth images of the same shots",
                    v.name, camera.width, camera.height
                ),
            });
        }
    }
    let samples: Vec<Vec<Sample>> = {
        use rayon::prelude::*;
        let rays = camera.ray_table();
        views.par_iter().map(|v| board_samples(camera, &rays, board, v)).collect()
    };
    let coords = ImageCoords::new(camera.width, camera.height);
    let median_z: Vec<f64> =
        samples.iter().map(|s| median(s.iter().map(|s| s.z_plane).collect())).collect();
    let mut rejected: Vec<Option<String>> = samples
        .iter()
        .map(|s| {
            (s.len() < MIN_PIXELS_PER_VIEW).then(|| {
                format!("{} board pixels with valid depth (need {MIN_PIXELS_PER_VIEW})", s.len())
            })
        })
        .collect();
    let used = |rej: &[Option<String>]| -> Vec<usize> {
        (0..views.len()).filter(|&i| rej[i].is_none()).collect()
    };
    let check_enough = |idx: &[usize]| -> Result<(), CalibError> {
        let zs: Vec<f64> = idx.iter().map(|&i| median_z[i]).collect();
        let (lo, hi) =
            zs.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &z| (a.min(z), b.max(z)));
        if idx.len() < MIN_DEPTH_VIEWS || !(hi - lo >= MIN_DISTANCE_SPAN_M) {
            return Err(CalibError::DepthData {
                views: idx.len(),
                needed: MIN_DEPTH_VIEWS,
                range: if idx.is_empty() { None } else { Some((lo, hi)) },
                span_needed: MIN_DISTANCE_SPAN_M,
            });
        }
        Ok(())
    };
    check_enough(&used(&rejected))?;

    let mut order_steps = Vec::new();
    let mut terms = choose_terms(&coords, &samples, &used(&rejected), &mut order_steps)?;
    let mut fitted = None;
    for _ in 0..MAX_REJECTION_ROUNDS {
        let idx = used(&rejected);
        let f = fit_terms(&coords, &terms, &samples, &idx).ok_or(CalibError::DepthFit {
            message: "the normal equations became singular after rejecting views".into(),
        })?;
        let meds: Vec<(usize, f64)> = idx
            .iter()
            .map(|&i| (i, median(residuals(&coords, &terms, &f.x, &samples[i]).collect())))
            .collect();
        let centre = median(meds.iter().map(|m| m.1).collect());
        let mad = median(meds.iter().map(|m| (m.1 - centre).abs()).collect());
        let mut changed = false;
        for &(i, m) in &meds {
            let z2 = median_z[i].max(1.0).powi(2);
            let sigma = (1.4826 * mad).max(VIEW_SIGMA_FLOOR_M * z2);
            if (m - centre).abs() > VIEW_MAD_K * sigma && idx.len() > MIN_DEPTH_VIEWS {
                rejected[i] = Some(format!(
                    "median residual {:+.2} mm is {:.1} σ ({:.2} mm) from the views' median: the view disagrees (board moved between IR and depth, glare, wrong pairing?)",
                    1e3 * (m - centre),
                    (m - centre).abs() / sigma,
                    1e3 * sigma
                ));
                changed = true;
            }
        }
        fitted = Some(f);
        if !changed {
            break;
        }
        check_enough(&used(&rejected))?;
        // The order is chosen again on the agreeing views.
        order_steps.clear();
        terms = choose_terms(&coords, &samples, &used(&rejected), &mut order_steps)?;
        fitted = None;
    }
    let idx = used(&rejected);
    let f = match fitted {
        Some(f) => f,
        None => fit_terms(&coords, &terms, &samples, &idx).ok_or(CalibError::DepthFit {
            message: "the normal equations became singular after rejecting views".into(),
        })?,
    };
    let view_reports: Vec<DepthViewReport> = views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let s = &samples[i];
            DepthViewReport {
                name: v.name.clone(),
                pixels: s.len(),
                median_z_m: median_z[i],
                rms_before_m: rms(s.iter().map(|s| s.z_measured - s.z_plane)),
                rms_after_m: rms(residuals(&coords, &terms, &f.x, s)),
                median_after_m: median(residuals(&coords, &terms, &f.x, s).collect()),
                rejected: rejected[i].clone(),
            }
        })
        .collect();
    let all_used = || idx.iter().flat_map(|&i| samples[i].iter());
    let rms_before_m = rms(all_used().map(|s| s.z_measured - s.z_plane));
    let zs: Vec<f64> = idx.iter().map(|&i| median_z[i]).collect();
    let distance_range_m =
        zs.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &z| (a.min(z), b.max(z)));
    let base_kinds = [DepthTermKind::Offset, DepthTermKind::Scale];
    let base = fit_terms(&coords, &base_kinds, &samples, &idx)
        .map(|b| {
            base_kinds
                .iter()
                .enumerate()
                .map(|(j, &kind)| DepthTerm { kind, value: b.x[j], std: b.std[j] })
                .collect()
        })
        .unwrap_or_default();
    let correction = DepthCorrection {
        width: camera.width,
        height: camera.height,
        terms: terms
            .iter()
            .enumerate()
            .map(|(j, &kind)| DepthTerm { kind, value: f.x[j], std: f.std[j] })
            .collect(),
        fit: None,
    };
    Ok(DepthFit {
        correction,
        views: view_reports,
        samples,
        rms_before_m,
        rms_after_m: f.rms,
        residual_variance: f.variance,
        order_steps,
        distance_range_m,
        base,
        sensitivity: None,
        no_pose: Vec::new(),
    })
}

/// The board poses of `corners` seen by `camera` with its intrinsics held (the depth pixels are
/// that camera's): a single-camera fit of the poses alone.
fn board_poses(
    camera: &CameraModel,
    board: &Board,
    corners: &[ViewCorners],
    reject_outliers: bool,
) -> Result<MonoCalibration, CalibError> {
    let flags = CalibFlags {
        use_intrinsic_guess: true,
        fix_intrinsics: true,
        reject_outliers,
        ..CalibFlags::default()
    };
    calibrate_mono(
        "IR camera (board poses for the depth fit)",
        board,
        corners,
        &flags,
        Some(camera),
    )
}

/// The depth calibration from the IR corners (module docs, stages 1–5): board poses from
/// `shots`' corners with `camera`'s intrinsics held, [`fit_depth_correction`] on the shots that
/// have a pose, and the fit's [`DepthSensitivity`] to the focal length and the square.
///
/// Errors: those of [`fit_depth_correction`], and a pose fit that fails (fewer than three
/// shots with a board).
pub fn fit_depth_from_corners(
    camera: &CameraModel,
    board: &Board,
    shots: &[DepthShot],
    reject_outliers: bool,
) -> Result<DepthFit, CalibError> {
    let corners: Vec<ViewCorners> = shots.iter().map(|s| s.corners.clone()).collect();
    let poses = board_poses(camera, board, &corners, reject_outliers)?;
    let mut views = Vec::new();
    let mut used_shots = Vec::new();
    let mut no_pose = Vec::new();
    for (i, (shot, report)) in shots.iter().zip(&poses.views).enumerate() {
        match (report.camera_from_board, &report.rejected) {
            (Some(pose), None) => {
                views.push(DepthView {
                    name: shot.name.clone(),
                    camera_from_board: pose,
                    depth: shot.depth.clone(),
                    ir: shot.ir.clone(),
                });
                used_shots.push(i);
            }
            (_, why) => no_pose.push((
                shot.name.clone(),
                format!(
                    "no board pose from {}: {}",
                    shot.corners.name,
                    why.as_deref().unwrap_or("the IR fit gave none")
                ),
            )),
        }
    }
    let mut fit = fit_depth_correction(camera, board, &views)?;
    // The shots the fit used, with the corners the pose fit kept (its outlier corners out).
    let used: Vec<usize> = (0..views.len()).filter(|&i| fit.views[i].rejected.is_none()).collect();
    let kept: Vec<ViewCorners> = used
        .iter()
        .map(|&i| {
            let mut c = shots[used_shots[i]].corners.clone();
            c.corners.retain(|k| {
                !poses.rejected_corners.iter().any(|r| r.view == c.name && r.id == k.id)
            });
            c
        })
        .collect();
    let used_views: Vec<&DepthView> = used.iter().map(|&i| &views[i]).collect();
    fit.sensitivity = Some(sensitivity(camera, board, &kept, &used_views, &fit)?);
    fit.no_pose = no_pose;
    Ok(fit)
}

/// The fit's terms re-fitted with the focal length and the square [`SENSITIVITY_STEP`] larger
/// and smaller (module docs, stage 5). `corners[i]` are the IR corners of `views[i]`.
fn sensitivity(
    camera: &CameraModel,
    board: &Board,
    corners: &[ViewCorners],
    views: &[&DepthView],
    fit: &DepthFit,
) -> Result<DepthSensitivity, CalibError> {
    let terms: Vec<DepthTermKind> = fit.correction.terms.iter().map(|t| t.kind).collect();
    let coords = ImageCoords::new(camera.width, camera.height);
    let refit = |focal: f64, square: f64| -> Result<DVector<f64>, CalibError> {
        let mut cam = *camera;
        cam.intrinsics.fx *= focal;
        cam.intrinsics.fy *= focal;
        let b = Board { square_m: board.square_m * square, ..*board };
        // No outlier rejection: the corners are those the nominal fit kept, and a corner
        // rejected in one re-fit but not the other would be a step, not a derivative.
        let poses = board_poses(&cam, &b, corners, false)?;
        let rays = cam.ray_table();
        let samples: Vec<Vec<Sample>> = {
            use rayon::prelude::*;
            views
                .par_iter()
                .zip(&poses.views)
                .map(|(v, p)| match p.camera_from_board {
                    Some(pose) => samples_of(&cam, &rays, &b, &pose, &v.depth, v.ir.as_ref()),
                    None => Vec::new(),
                })
                .collect()
        };
        let idx: Vec<usize> = (0..samples.len()).filter(|&i| !samples[i].is_empty()).collect();
        let s = sums(&coords, &terms, &samples);
        solve(&s, &idx).map(|r| r.0).ok_or_else(|| CalibError::DepthFit {
            message: format!(
                "the fit with the focal length x{focal} and the square x{square} is singular: the sensitivity cannot be computed; add views at other distances"
            ),
        })
    };
    let h = SENSITIVITY_STEP;
    let (fp, fm) = (refit(1.0 + h, 1.0)?, refit(1.0 - h, 1.0)?);
    let (sp, sm) = (refit(1.0, 1.0 + h)?, refit(1.0, 1.0 - h)?);
    // Central difference per unit of relative change, times 0.01: per +1 %.
    let per_percent =
        |p: &DVector<f64>, m: &DVector<f64>, j: usize| (p[j] - m[j]) / (2.0 * h) * 0.01;
    Ok(DepthSensitivity {
        step: h,
        terms: terms
            .iter()
            .enumerate()
            .map(|(j, &kind)| TermSensitivity {
                kind,
                per_percent_focal: per_percent(&fp, &fm, j),
                per_percent_square: per_percent(&sp, &sm, j),
            })
            .collect(),
    })
}

/// Refuses a fit whose scale is beyond [`MAX_PLAUSIBLE_SCALE`] (module docs, stage 5): the
/// error names the scale, the bound, what moves it (the square, the IR intrinsics, with the
/// fit's sensitivity when known) and `--force`.
pub fn check_plausible(fit: &DepthFit) -> Result<(), CalibError> {
    let scale = fit.correction.value(DepthTermKind::Scale);
    if scale.abs() <= MAX_PLAUSIBLE_SCALE {
        return Ok(());
    }
    let moves = fit
        .sensitivity
        .as_ref()
        .and_then(|s| s.of(DepthTermKind::Scale))
        .map(|s| {
            format!(
                " (here each +1 % of the square moves it by {:+.2} %, each +1 % of the IR focal length by {:+.2} %)",
                100.0 * s.per_percent_square,
                100.0 * s.per_percent_focal
            )
        })
        .unwrap_or_default();
    Err(CalibError::ImplausibleDepthScale { scale, limit: MAX_PLAUSIBLE_SCALE, moves })
}

/// Residuals `z_measured − z_plane − model` of `samples`.
fn residuals<'a>(
    coords: &'a ImageCoords,
    terms: &'a [DepthTermKind],
    x: &'a DVector<f64>,
    samples: &'a [Sample],
) -> impl Iterator<Item = f64> + 'a {
    samples.iter().map(move |s| s.z_measured - s.z_plane - predict(coords, terms, x.as_slice(), s))
}

impl DepthFit {
    /// The fit as JSON for the rig's `depth_correction.fit` and `report.json`.
    pub fn report_json(&self) -> serde_json::Value {
        serde_json::json!({
            "units": "metres",
            "views_used": self.views.iter().filter(|v| v.rejected.is_none()).count(),
            "views_total": self.views.len(),
            "pixels_used": self.views.iter().filter(|v| v.rejected.is_none()).map(|v| v.pixels).sum::<usize>(),
            "distance_range_m": [self.distance_range_m.0, self.distance_range_m.1],
            "rms_before_m": self.rms_before_m,
            "rms_after_m": self.rms_after_m,
            "residual_sigma_m": self.residual_variance.sqrt(),
            "std": "1σ: the larger of sqrt(diag((AᵀA)⁻¹)·s²) and a jackknife over views",
            "sensitivity": self.sensitivity.as_ref().map(|s| serde_json::json!({
                "what": "change of each term's value (its unit: metres, unitless for the scale) per +1 % of the IR focal length (fx and fy) and per +1 % of the board's square side; central difference of re-fits with the board poses re-solved from the same corners",
                "step_fraction": s.step,
                "terms": s.terms.iter().map(|t| serde_json::json!({
                    "term": t.kind.name(),
                    "per_percent_focal_length": t.per_percent_focal,
                    "per_percent_square_size": t.per_percent_square,
                })).collect::<Vec<_>>(),
            })),
            "max_plausible_scale": MAX_PLAUSIBLE_SCALE,
            "shots_without_board_pose": self.no_pose.iter().map(|(n, why)| serde_json::json!({"name": n, "reason": why})).collect::<Vec<_>>(),
            "order_steps": self.order_steps.iter().map(|o| serde_json::json!({"terms": o.terms, "rms_m": o.rms_m, "leave_one_view_out_rms_m": o.cv_rms_m, "kept": o.kept})).collect::<Vec<_>>(),
            "views": self.views.iter().map(|v| serde_json::json!({
                "name": v.name, "pixels": v.pixels, "median_z_m": v.median_z_m,
                "rms_before_m": v.rms_before_m, "rms_after_m": v.rms_after_m,
                "median_residual_after_m": v.median_after_m, "rejected": v.rejected,
            })).collect::<Vec<_>>(),
        })
    }
}

#[cfg(test)]
mod tests;
