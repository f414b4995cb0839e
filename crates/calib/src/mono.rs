//! Single-camera calibration: Zhang initialisation, LM refinement, uncertainty, and
//! automatic (always reported) corner and view outlier rejection.
//!
//! Size (~750 lines): Zhang's initialisation, the LM refinement, the uncertainty, the
//! rejection loop and the constraint flags' check against the free fit ([`FixCheck`]) all work
//! on one `Problem`/`Solution` pair and run in that order, so they read top to bottom in one
//! file.

use std::time::Instant;

use geometry::timing::{Timings, ms_since};
use geometry::{CameraModel, Distortion, Intrinsics, RigidTransform};
use nalgebra::Vector2;
use serde::{Deserialize, Serialize};

use crate::bundle::{CamState, INTR_NAMES, N_INTR, Obs, Problem, Solution};
use crate::zhang::{
    focal_with_principal_point, homography, pose_from_homography, tilt_deg, zhang_intrinsics,
};
use crate::{Board, CalibError, ViewCorners};

/// A calibration needs three views: two leave Zhang's system with no redundancy.
pub const MIN_VIEWS: usize = 3;
/// Corners a view needs to give a homography with some redundancy.
pub const MIN_CORNERS_PER_VIEW: usize = 6;
/// Largest board tilt below which the views are called fronto-parallel (focal length
/// unobservable): 3° foreshortens a 7x5 board by < 0.2 px at Kinect resolutions.
pub const MIN_MAX_TILT_DEG: f64 = 3.0;
/// A corner whose error exceeds this many robust σ is an outlier. 6σ keeps a false alarm
/// below 1e-7 per corner for Gaussian noise, while a 4 px mis-detection on 0.3 px noise is 13σ.
pub const CORNER_OUTLIER_SIGMAS: f64 = 6.0;
/// Corners closer than this are never called outliers, whatever the noise estimate: real IR
/// corners have heavy-tailed errors up to ~1.2 px (kinect-lab, OpenCV's and Bouguet's corners
/// alike), while a mis-detection is 4–7 px.
pub const CORNER_OUTLIER_MIN_PX: f64 = 1.5;
/// A view whose RMS exceeds this multiple of the median view RMS is an outlier view.
pub const VIEW_OUTLIER_FACTOR: f64 = 3.0;
/// Views below this RMS are never rejected (the handout's colour bar is 0.2 px).
pub const VIEW_OUTLIER_MIN_PX: f64 = 0.5;
/// A parameter moved by fixing another (a [`CalibFlags`] constraint) by more than this many
/// σ of the free fit is warned about ([`FixCheck`]): 5. Where the constraint is true the fixed
/// and the free fit differ by the free fit's own noise, whose spread is at most its σ (the
/// difference's variance is the free variance minus the fixed one), so 5σ is a false alarm
/// below 1e-6 per parameter; a principal point tens of pixels off the centre moves the focal
/// lengths by tens of σ (7 % on a real Kinect v2 set with σ ≈ 0.2 %).
pub const FIX_SHIFT_SIGMAS: f64 = 5.0;
/// Median of the Rayleigh distribution in units of σ: turns the median corner error into a
/// per-axis noise estimate.
const RAYLEIGH_MEDIAN: f64 = 1.177_410_022_515_474_6;

/// What to estimate (OpenCV's and Bouguet's flags).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CalibFlags {
    /// Keep `cx, cy` (at the guess, or at the image centre `((w-1)/2, (h-1)/2)`).
    pub fix_principal_point: bool,
    /// Keep `fy / fx` at the guess's ratio (1 without a guess).
    pub fix_aspect_ratio: bool,
    /// Skew fixed at zero (default; OpenCV has no skew, Bouguet's `est_alpha = 0`).
    pub zero_skew: bool,
    /// Keep `k3` (at 0 without a guess). Bouguet's default.
    pub fix_k3: bool,
    /// `p1 = p2 = 0`, not estimated.
    pub zero_tangential: bool,
    /// Start from the given camera instead of Zhang's closed form.
    pub use_intrinsic_guess: bool,
    /// Keep the intrinsics entirely (stereo with known cameras).
    pub fix_intrinsics: bool,
    /// Reject corner and view outliers (always reported). Off reproduces OpenCV, which has
    /// no rejection.
    pub reject_outliers: bool,
}

impl Default for CalibFlags {
    /// OpenCV's standard 5-coefficient model: everything but skew estimated.
    fn default() -> Self {
        Self {
            fix_principal_point: false,
            fix_aspect_ratio: false,
            zero_skew: true,
            fix_k3: false,
            zero_tangential: false,
            use_intrinsic_guess: false,
            fix_intrinsics: false,
            reject_outliers: true,
        }
    }
}

impl CalibFlags {
    /// The lab's Bouguet settings: principal point fixed at the centre, k3 = 0, no skew.
    pub fn bouguet() -> Self {
        Self { fix_principal_point: true, fix_k3: true, ..Self::default() }
    }

    pub(crate) fn free_mask(&self) -> [bool; N_INTR] {
        if self.fix_intrinsics {
            return [false; N_INTR];
        }
        [
            true,
            !self.fix_aspect_ratio,
            !self.fix_principal_point,
            !self.fix_principal_point,
            !self.zero_skew,
            true,
            true,
            !self.zero_tangential,
            !self.zero_tangential,
            !self.fix_k3,
        ]
    }
}

/// One standard deviation of every intrinsic parameter (0 for fixed ones), same units as the
/// parameter. From `(JᵀJ)⁻¹ · σ²` with `σ² = Σ|e|² / (2·N_corners − N_params)` (OpenCV's
/// `calibrateCameraExtended`).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct IntrinsicsStd {
    /// σ of fx, px.
    pub fx: f64,
    /// σ of fy, px.
    pub fy: f64,
    /// σ of cx, px.
    pub cx: f64,
    /// σ of cy, px.
    pub cy: f64,
    /// σ of skew, px.
    pub skew: f64,
    /// σ of k1.
    pub k1: f64,
    /// σ of k2.
    pub k2: f64,
    /// σ of p1.
    pub p1: f64,
    /// σ of p2.
    pub p2: f64,
    /// σ of k3.
    pub k3: f64,
}

impl IntrinsicsStd {
    /// From solver order `fx, fy, cx, cy, skew, k1, k2, p1, p2, k3`.
    pub fn from_array(a: [f64; N_INTR]) -> Self {
        Self {
            fx: a[0],
            fy: a[1],
            cx: a[2],
            cy: a[3],
            skew: a[4],
            k1: a[5],
            k2: a[6],
            p1: a[7],
            p2: a[8],
            k3: a[9],
        }
    }
    /// In solver order `fx, fy, cx, cy, skew, k1, k2, p1, p2, k3`.
    pub fn to_array(&self) -> [f64; N_INTR] {
        [self.fx, self.fy, self.cx, self.cy, self.skew, self.k1, self.k2, self.p1, self.p2, self.k3]
    }
}

/// Per-view outcome.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewReport {
    /// Image name.
    pub name: String,
    /// `camera_from_board`, metres (None for a rejected view).
    #[serde(skip)]
    pub camera_from_board: Option<RigidTransform>,
    /// RMS reprojection error over the view's used corners, px.
    pub rms_px: f64,
    /// Corners used.
    pub n_corners: usize,
    /// Board tilt, degrees.
    pub tilt_deg: f64,
    /// Why the view was left out, if it was.
    pub rejected: Option<String>,
}

/// A corner left out as an outlier.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RejectedCorner {
    /// Image name.
    pub view: String,
    /// Board index of the corner.
    pub id: usize,
    /// Its reprojection error when it was rejected, px.
    pub error_px: f64,
    /// The outlier threshold then, px.
    pub threshold_px: f64,
}

/// One parameter's move between the free fit and the fit with a parameter fixed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ParameterShift {
    /// The parameter (`fx`, `k1`, …).
    pub parameter: String,
    /// Its value in the fit with the constraint.
    pub fixed_fit: f64,
    /// Its value in the free fit.
    pub free_fit: f64,
    /// Its 1σ in the free fit.
    pub free_std: f64,
}

impl ParameterShift {
    /// The move `fixed_fit − free_fit` in σ of the free fit.
    pub fn sigmas(&self) -> f64 {
        (self.fixed_fit - self.free_fit).abs() / self.free_std.max(1e-300)
    }
}

/// What fixing one group of parameters does to the others: the fit with the flag against the
/// same views' fit without it ([`calibrate_mono`] runs one per constraint flag set).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FixCheck {
    /// The [`CalibFlags`] field (`fix_principal_point`, `fix_aspect_ratio`, `fix_k3`,
    /// `zero_tangential`).
    pub flag: String,
    /// The parameters it fixes, with the values the free fit gives them.
    pub freed: Vec<ParameterShift>,
    /// The other parameters that moved by more than [`FIX_SHIFT_SIGMAS`] σ of the free fit,
    /// largest move first (empty: the constraint agrees with the views).
    pub moved: Vec<ParameterShift>,
    /// The largest move of any other parameter, in σ of the free fit.
    pub max_sigmas: f64,
    /// Why the free fit could not be made (then no comparison).
    pub free_fit_error: Option<String>,
}

/// The result of [`calibrate_mono`].
#[derive(Debug, Clone)]
pub struct MonoCalibration {
    /// The calibrated camera.
    pub camera: CameraModel,
    /// σ of every intrinsic parameter.
    pub std: IntrinsicsStd,
    /// RMS reprojection error over all used corners, px (OpenCV's definition).
    pub rms_px: f64,
    /// Estimated per-axis corner noise σ = sqrt(Σ|e|² / (2·N_corners − N_params)), px.
    pub sigma_px: f64,
    /// Every input view in input order, with its RMS or why it was rejected.
    pub views: Vec<ViewReport>,
    /// Corners rejected as outliers.
    pub rejected_corners: Vec<RejectedCorner>,
    /// The flags used.
    pub flags: CalibFlags,
    /// LM iterations of the last run.
    pub iterations: usize,
    /// Residuals of every used corner: (view index, corner id, observed px, error px vector).
    pub residuals: Vec<(usize, usize, Vector2<f64>, Vector2<f64>)>,
    /// Per constraint flag set (principal point, aspect ratio, k3, tangential): how far it moved
    /// the other parameters against the free fit ([`FIX_SHIFT_SIGMAS`]); empty without such
    /// flags or with the intrinsics fixed.
    pub fix_checks: Vec<FixCheck>,
    /// Where the fit's time went: [`STAGE_FIT`] (Zhang, LM, outlier rounds), [`STAGE_SIGMA`]
    /// (the covariance of the final solution), [`STAGE_FIX_CHECKS`] (the free fits of the
    /// constraint checks, when any).
    pub timings: Timings,
}

/// [`MonoCalibration::timings`] stage: Zhang's initialisation, LM and the outlier rounds.
pub const STAGE_FIT: &str = "fit";
/// [`MonoCalibration::timings`] stage: σ of the parameters, (JᵀJ)⁻¹ of the final solution.
pub const STAGE_SIGMA: &str = "σ";
/// [`MonoCalibration::timings`] stage: the constraint checks' free fits.
pub const STAGE_FIX_CHECKS: &str = "constraint checks";

impl MonoCalibration {
    /// The intrinsics and distortion in solver order (`fx, fy, cx, cy, skew, k1, k2, p1, p2,
    /// k3`, as [`IntrinsicsStd::to_array`]).
    pub fn parameters(&self) -> [f64; N_INTR] {
        let (k, d) = (self.camera.intrinsics, self.camera.distortion);
        [k.fx, k.fy, k.cx, k.cy, k.skew, d.k1, d.k2, d.p1, d.p2, d.k3]
    }
}

pub(crate) fn initial_camera(
    camera: &str,
    board: &Board,
    views: &[&ViewCorners],
    flags: &CalibFlags,
    guess: Option<&CameraModel>,
    width: usize,
    height: usize,
) -> Result<(Intrinsics, Distortion, Vec<RigidTransform>), CalibError> {
    let hs: Vec<_> = views
        .iter()
        .map(|v| {
            let plane: Vec<_> = v.corners.iter().map(|c| board.object_point(c.id).xy()).collect();
            let px: Vec<_> = v.corners.iter().map(|c| c.px).collect();
            homography(&plane, &px)
        })
        .collect();
    let valid: Vec<_> = hs.iter().flatten().copied().collect();
    let centre = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    let (mut intr, dist) = match guess.filter(|_| flags.use_intrinsic_guess) {
        Some(g) => (g.intrinsics, g.distortion),
        None => {
            let zhang = (!flags.fix_principal_point)
                .then(|| zhang_intrinsics(&valid, width, height))
                .flatten();
            let k = match zhang {
                Some(k) => k,
                None => {
                    let (cx, cy) = match guess {
                        Some(g) if flags.fix_principal_point => (g.intrinsics.cx, g.intrinsics.cy),
                        _ => centre,
                    };
                    let (fx, fy) = focal_with_principal_point(&valid, cx, cy).ok_or_else(|| {
                        CalibError::Degenerate {
                            camera: camera.into(),
                            max_tilt_deg: 0.0,
                            min_tilt_deg: MIN_MAX_TILT_DEG,
                        }
                    })?;
                    Intrinsics::new(fx, fy, cx, cy)
                }
            };
            (k, Distortion::NONE)
        }
    };
    if flags.fix_aspect_ratio && !flags.use_intrinsic_guess {
        let f = 0.5 * (intr.fx + intr.fy);
        intr.fx = f;
        intr.fy = f;
    }
    let mut poses = Vec::with_capacity(views.len());
    for (v, h) in views.iter().zip(&hs) {
        let pose = h.as_ref().and_then(|h| pose_from_homography(h, &intr)).ok_or_else(|| {
            CalibError::Diverged {
                camera: camera.into(),
                message: format!("no board pose for view '{}' from its homography", v.name),
            }
        })?;
        poses.push(pose);
    }
    let max_tilt = poses.iter().map(tilt_deg).fold(0.0_f64, f64::max);
    if max_tilt < MIN_MAX_TILT_DEG || !(intr.fx.is_finite() && intr.fx > 0.0) {
        return Err(CalibError::Degenerate {
            camera: camera.into(),
            max_tilt_deg: max_tilt,
            min_tilt_deg: MIN_MAX_TILT_DEG,
        });
    }
    Ok((intr, dist, poses))
}

/// Image width and height, the usable views' indices, and per view why it was left out.
pub(crate) type UsableViews = (usize, usize, Vec<usize>, Vec<Option<String>>);

/// Picks the views a calibration can use. The camera's image size is the most common one
/// among the readable views (the first one seen on a tie); views of another size, unreadable
/// ones ([`ViewCorners::unusable`]) and those with fewer than [`MIN_CORNERS_PER_VIEW`] corners
/// are left out with their reason, and the calibration goes on while [`MIN_VIEWS`] remain.
/// Returns the image size, the usable views' indices and, per view, why it was left out.
pub(crate) fn usable_views(
    camera: &str,
    board: &Board,
    views: &[ViewCorners],
) -> Result<UsableViews, CalibError> {
    let mut sizes: Vec<((usize, usize), usize)> = Vec::new();
    for v in views.iter().filter(|v| v.unusable.is_none()) {
        match sizes.iter_mut().find(|s| s.0 == (v.width, v.height)) {
            Some(s) => s.1 += 1,
            None => sizes.push(((v.width, v.height), 1)),
        }
    }
    // Strictly more wins, so the first size seen wins a tie.
    let size = sizes.iter().fold(None, |best: Option<((usize, usize), usize)>, s| match best {
        Some(b) if b.1 >= s.1 => Some(b),
        _ => Some(*s),
    });
    let (w, h) = size.map(|s| s.0).unwrap_or((0, 0));
    let reasons: Vec<Option<String>> = views
        .iter()
        .map(|v| {
            if let Some(why) = &v.unusable {
                Some(why.clone())
            } else if (v.width, v.height) != (w, h) {
                Some(format!(
                    "image is {}x{}, the camera's other images are {w}x{h}",
                    v.width, v.height
                ))
            } else if v.corners.is_empty() {
                Some("no board found".to_string())
            } else if v.corners.len() < MIN_CORNERS_PER_VIEW {
                Some(format!("only {} corners (need {MIN_CORNERS_PER_VIEW})", v.corners.len()))
            } else {
                None
            }
        })
        .collect();
    let usable: Vec<usize> = (0..views.len()).filter(|&i| reasons[i].is_none()).collect();
    let left_out = || {
        let list: Vec<String> = views
            .iter()
            .zip(&reasons)
            .filter_map(|(v, r)| Some(format!("{} ({})", v.name, r.as_ref()?)))
            .collect();
        if list.is_empty() { String::new() } else { format!(" (left out: {})", list.join(", ")) }
    };
    let right_size = |v: &&ViewCorners| v.unusable.is_none() && (v.width, v.height) == (w, h);
    if usable.is_empty()
        && views.iter().any(|v| right_size(&v))
        && views.iter().filter(right_size).all(|v| v.corners.is_empty())
    {
        return Err(CalibError::NoBoard {
            camera: camera.into(),
            images: views.len(),
            cols: board.cols,
            rows: board.rows,
        });
    }
    if usable.len() < MIN_VIEWS {
        return Err(CalibError::TooFewViews {
            camera: camera.into(),
            usable: usable.len(),
            needed: MIN_VIEWS,
            left_out: left_out(),
        });
    }
    Ok((w, h, usable, reasons))
}

/// Robust per-axis noise σ from the median corner error.
pub(crate) fn robust_sigma(errors: &mut [f64]) -> f64 {
    if errors.is_empty() {
        return 0.0;
    }
    errors.sort_by(f64::total_cmp);
    errors[errors.len() / 2] / RAYLEIGH_MEDIAN
}

/// One round of corner outlier rejection on a solved problem: deactivates, per view, the worst
/// corner above the threshold. Returns the rejected corners.
pub(crate) fn reject_corner_outliers(
    p: &mut Problem,
    view_names: &dyn Fn(usize, usize) -> String,
) -> Vec<RejectedCorner> {
    let mut errs: Vec<f64> = p
        .obs
        .iter()
        .filter(|o| o.active && p.view_active[o.view])
        .map(|o| p.residual(o).norm())
        .collect();
    let sigma = robust_sigma(&mut errs);
    let threshold = (CORNER_OUTLIER_SIGMAS * sigma).max(CORNER_OUTLIER_MIN_PX);
    let mut worst: std::collections::BTreeMap<(usize, usize), (usize, f64)> = Default::default();
    for (i, o) in p.obs.iter().enumerate() {
        if !(o.active && p.view_active[o.view]) {
            continue;
        }
        let e = p.residual(o).norm();
        if e > threshold {
            let w = worst.entry((o.cam, o.view)).or_insert((i, e));
            if e > w.1 {
                *w = (i, e);
            }
        }
    }
    worst
        .values()
        .map(|&(i, e)| {
            p.obs[i].active = false;
            RejectedCorner {
                view: view_names(p.obs[i].cam, p.obs[i].view),
                id: p.obs[i].id,
                error_px: e,
                threshold_px: threshold,
            }
        })
        .collect()
}

/// Per-camera, per-view RMS of the active observations.
pub(crate) fn view_rms(p: &Problem, cam: usize) -> Vec<(f64, usize)> {
    let mut acc = vec![(0.0, 0usize); p.ref_from_board.len()];
    for o in p.obs.iter().filter(|o| o.active && o.cam == cam && p.view_active[o.view]) {
        acc[o.view].0 += p.residual(o).norm_squared();
        acc[o.view].1 += 1;
    }
    acc.into_iter().map(|(s, n)| (if n > 0 { (s / n as f64).sqrt() } else { 0.0 }, n)).collect()
}

/// σ of camera `c`'s intrinsics from a solution.
pub(crate) fn intrinsics_std(sol: &Solution, c: usize, sigma2: f64) -> IntrinsicsStd {
    let mut out = [0.0; N_INTR];
    if let Some(cov) = sol.covariance_unscaled() {
        for (i, col) in sol.layout.intr_col[c].iter().enumerate() {
            if let Some(col) = col {
                out[i] = (cov[(*col, *col)] * sigma2).max(0.0).sqrt();
            }
        }
    }
    IntrinsicsStd::from_array(out)
}

/// σ² = Σ|e|² / (N_residuals − N_params), OpenCV's residual variance; every corner gives two
/// residuals (x and y), so N_residuals = 2·N_corners.
pub(crate) fn residual_variance(sol: &Solution) -> f64 {
    let dof = 2.0 * sol.n_active_obs as f64 - sol.n_params as f64;
    if dof > 0.0 { sol.cost / dof } else { f64::NAN }
}

/// Calibrates one camera from labelled corners.
///
/// Views that cannot be used (another image size, unreadable, no board, fewer than
/// [`MIN_CORNERS_PER_VIEW`] corners) are reported as rejected with the reason. After the first fit, corner
/// outliers (> [`CORNER_OUTLIER_SIGMAS`] robust σ) and then view outliers (RMS >
/// [`VIEW_OUTLIER_FACTOR`] × median) are removed one round at a time and the fit repeated;
/// every removal is listed in the result.
///
/// With a constraint flag (`fix_principal_point`, `fix_aspect_ratio`, `fix_k3`,
/// `zero_tangential`; not with `fix_intrinsics`) the same views are also fitted without each
/// one, and [`MonoCalibration::fix_checks`] says which other parameters the constraint moved
/// beyond [`FIX_SHIFT_SIGMAS`] σ of that free fit.
pub fn calibrate_mono(
    camera: &str,
    board: &Board,
    views: &[ViewCorners],
    flags: &CalibFlags,
    guess: Option<&CameraModel>,
) -> Result<MonoCalibration, CalibError> {
    let mut m = calibrate_mono_unchecked(camera, board, views, flags, guess)?;
    if flags.fix_intrinsics {
        return Ok(m);
    }
    let checks_started = Instant::now();
    type Unfix = fn(&mut CalibFlags);
    let constraints: [(&str, bool, Unfix, &[usize]); 4] = [
        (
            "fix_principal_point",
            flags.fix_principal_point,
            |f| f.fix_principal_point = false,
            &[2, 3],
        ),
        ("fix_aspect_ratio", flags.fix_aspect_ratio, |f| f.fix_aspect_ratio = false, &[1]),
        ("fix_k3", flags.fix_k3, |f| f.fix_k3 = false, &[9]),
        ("zero_tangential", flags.zero_tangential, |f| f.zero_tangential = false, &[7, 8]),
    ];
    let fixed_free = flags.free_mask();
    let fixed_values = m.parameters();
    for (flag, on, unfix, fixes) in constraints {
        if !on {
            continue;
        }
        let mut free_flags = *flags;
        unfix(&mut free_flags);
        let mut check = FixCheck {
            flag: flag.into(),
            freed: vec![],
            moved: vec![],
            max_sigmas: 0.0,
            free_fit_error: None,
        };
        // The free fit starts where the fixed one did (the guess, or Zhang's closed form).
        match calibrate_mono_unchecked(camera, board, views, &free_flags, guess) {
            Err(e) => check.free_fit_error = Some(e.to_string()),
            Ok(free) => {
                let (values, std) = (free.parameters(), free.std.to_array());
                let shift = |j: usize| ParameterShift {
                    parameter: INTR_NAMES[j].into(),
                    fixed_fit: fixed_values[j],
                    free_fit: values[j],
                    free_std: std[j],
                };
                check.freed = fixes.iter().map(|&j| shift(j)).collect();
                let mut moved: Vec<ParameterShift> = (0..N_INTR)
                    .filter(|&j| fixed_free[j] && !fixes.contains(&j) && std[j] > 0.0)
                    .map(shift)
                    .collect();
                moved.sort_by(|a, b| b.sigmas().total_cmp(&a.sigmas()));
                check.max_sigmas = moved.first().map_or(0.0, ParameterShift::sigmas);
                moved.retain(|p| p.sigmas() > FIX_SHIFT_SIGMAS);
                check.moved = moved;
            }
        }
        m.fix_checks.push(check);
    }
    if !m.fix_checks.is_empty() {
        m.timings.add(STAGE_FIX_CHECKS, ms_since(checks_started));
    }
    Ok(m)
}

/// [`calibrate_mono`] without the constraint checks.
pub(crate) fn calibrate_mono_unchecked(
    camera: &str,
    board: &Board,
    views: &[ViewCorners],
    flags: &CalibFlags,
    guess: Option<&CameraModel>,
) -> Result<MonoCalibration, CalibError> {
    let started = Instant::now();
    let mut timings = Timings::new();
    let (width, height, usable, reasons) = usable_views(camera, board, views)?;
    let used: Vec<&ViewCorners> = usable.iter().map(|&i| &views[i]).collect();
    let (intr, dist, poses) = initial_camera(camera, board, &used, flags, guess, width, height)?;
    let mut free = flags.free_mask();
    let aspect = flags.fix_aspect_ratio.then(|| intr.fy / intr.fx);
    if aspect.is_some() {
        free[1] = false;
    }
    let mut obs = Vec::new();
    for (vi, v) in used.iter().enumerate() {
        for c in &v.corners {
            obs.push(Obs {
                cam: 0,
                view: vi,
                id: c.id,
                object: board.object_point(c.id),
                pixel: c.px,
                active: true,
                weight: 1.0,
            });
        }
    }
    let mut p = Problem {
        cams: vec![CamState { intr, dist, free, aspect }],
        cam_from_ref: vec![RigidTransform::identity()],
        extrinsics_free: false,
        ref_from_board: poses,
        view_active: vec![true; used.len()],
        obs,
    };
    let names: Vec<String> = used.iter().map(|v| v.name.clone()).collect();
    let (sol, rejected_corners, view_rejections) =
        solve_with_outliers(camera, &mut p, &|_, v| names[v].clone(), 1, flags.reject_outliers)?;
    let sigma2 = residual_variance(&sol);
    timings.add(STAGE_FIT, ms_since(started));
    let std = timings.time(STAGE_SIGMA, || intrinsics_std(&sol, 0, sigma2));
    let rms = view_rms(&p, 0);
    let mut views_out: Vec<ViewReport> = views
        .iter()
        .zip(&reasons)
        .map(|(v, why)| ViewReport {
            name: v.name.clone(),
            camera_from_board: None,
            rms_px: f64::NAN,
            n_corners: v.corners.len(),
            tilt_deg: f64::NAN,
            rejected: why.clone(),
        })
        .collect();
    for (vi, &orig) in usable.iter().enumerate() {
        let r = &mut views_out[orig];
        r.tilt_deg = tilt_deg(&p.ref_from_board[vi]);
        r.camera_from_board = p.view_active[vi].then_some(p.ref_from_board[vi]);
        r.rejected = view_rejections.iter().find(|(v, _)| *v == vi).map(|(_, why)| why.clone());
        // A view rejected as an outlier keeps its detected corner count and no RMS, as other
        // rejected views (its RMS when it was rejected is in the reason); the final solution
        // has no residual of it.
        if r.rejected.is_none() {
            r.rms_px = rms[vi].0;
            r.n_corners = rms[vi].1;
        }
    }
    let residuals = p
        .obs
        .iter()
        .filter(|o| o.active && p.view_active[o.view])
        .map(|o| (usable[o.view], o.id, o.pixel, p.residual(o)))
        .collect();
    let c = &p.cams[0];
    Ok(MonoCalibration {
        camera: CameraModel::new(width, height, c.intr, c.dist),
        std,
        rms_px: (sol.cost / sol.n_active_obs.max(1) as f64).sqrt(),
        sigma_px: sigma2.sqrt(),
        views: views_out,
        rejected_corners,
        flags: *flags,
        iterations: sol.iterations,
        residuals,
        fix_checks: Vec::new(),
        timings,
    })
}

/// Final solution, rejected corners, and `(view, reason)` of rejected views.
pub(crate) type Outcome = (Solution, Vec<RejectedCorner>, Vec<(usize, String)>);

/// Solve, then alternately reject corner outliers and outlier views until none remain.
/// Returns the final solution, the rejected corners and `(view, reason)` of rejected views.
pub(crate) fn solve_with_outliers(
    camera: &str,
    p: &mut Problem,
    names: &dyn Fn(usize, usize) -> String,
    n_cams: usize,
    reject_outliers: bool,
) -> Result<Outcome, CalibError> {
    let mut sol = p.solve();
    check_finite(camera, p)?;
    let mut rejected_corners = Vec::new();
    let mut rejected_views = Vec::new();
    let rounds = if reject_outliers { 50 } else { 0 };
    for _round in 0..rounds {
        let r = reject_corner_outliers(p, names);
        if !r.is_empty() {
            rejected_corners.extend(r);
            sol = p.solve();
            check_finite(camera, p)?;
            continue;
        }
        // View outliers, one per round, never below MIN_VIEWS active views.
        let active_views = p.view_active.iter().filter(|&&a| a).count();
        if active_views <= MIN_VIEWS {
            break;
        }
        let mut worst: Option<(usize, f64, f64)> = None;
        for cam in 0..n_cams {
            let rms = view_rms(p, cam);
            let mut vals: Vec<f64> = rms
                .iter()
                .enumerate()
                .filter(|(v, r)| p.view_active[*v] && r.1 > 0)
                .map(|(_, r)| r.0)
                .collect();
            if vals.is_empty() {
                continue;
            }
            vals.sort_by(f64::total_cmp);
            let median = vals[vals.len() / 2];
            for (v, r) in rms.iter().enumerate() {
                if p.view_active[v]
                    && r.1 > 0
                    && r.0 > VIEW_OUTLIER_FACTOR * median
                    && r.0 > VIEW_OUTLIER_MIN_PX
                    && worst.is_none_or(|w| r.0 / median > w.1 / w.2)
                {
                    worst = Some((v, r.0, median));
                }
            }
        }
        let Some((v, rms, median)) = worst else { break };
        p.view_active[v] = false;
        rejected_views.push((
            v,
            format!(
                "outlier view: RMS {rms:.3} px > {VIEW_OUTLIER_FACTOR} × median {median:.3} px"
            ),
        ));
        sol = p.solve();
        check_finite(camera, p)?;
    }
    Ok((sol, rejected_corners, rejected_views))
}

pub(crate) fn check_finite(camera: &str, p: &Problem) -> Result<(), CalibError> {
    for c in &p.cams {
        let k = c.intr;
        let all = [k.fx, k.fy, k.cx, k.cy, k.skew].into_iter().chain(c.dist.to_array());
        if all.into_iter().any(|v| !v.is_finite()) || k.fx <= 0.0 || k.fy <= 0.0 {
            return Err(CalibError::Diverged {
                camera: camera.into(),
                message: format!("intrinsics became {k:?}"),
            });
        }
    }
    Ok(())
}

/// Names of the intrinsic parameters in the order of [`IntrinsicsStd::to_array`].
pub fn intrinsic_names() -> [&'static str; N_INTR] {
    INTR_NAMES
}
