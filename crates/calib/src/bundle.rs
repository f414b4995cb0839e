//! The Levenberg–Marquardt core shared by mono and stereo calibration.
//!
//! One problem holds one or more cameras, a rigid `cam_from_ref` per camera (camera 0 is the
//! reference: identity, fixed), one `ref_from_board` pose per view, and the observed corners.
//! Residual = projected − observed pixel. Jacobians are analytic: the distortion part comes
//! from [`geometry::Distortion::distort_with_jacobian`]; rotations are updated by a left
//! perturbation `R ← exp([δ]×)·R`, so `∂(R·X)/∂δ = −[R·X]×`.
//! The normal equations are dense (≤ a few hundred unknowns for 25 views) and solved by
//! Cholesky with Marquardt's diagonal damping.

use geometry::{Distortion, Intrinsics, RigidTransform};
use nalgebra::{DMatrix, DVector, Matrix2, Matrix2x3, Matrix3, Rotation3, Vector2, Vector3};

/// Intrinsic parameter order inside the solver.
pub(crate) const N_INTR: usize = 10;
/// Names of the intrinsic parameters in solver order.
pub(crate) const INTR_NAMES: [&str; N_INTR] =
    ["fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3"];

/// Iteration cap of one LM run. A cold start from Zhang's estimate converges in 10–30.
const LM_MAX_ITERATIONS: usize = 200;
/// Stop when the cost decreases by less than this fraction (cost is Σ weight·|e|²). Below
/// 1e-12 the decrease is floating-point noise: at 1e-15 the weighted joint stereo fit ran to
/// the iteration cap on repeated views (200 iterations, 0.3 s, instead of 6); every test
/// figure (rendered-set errors, σ ratios to OpenCV, kinect-lab RMS) is unchanged.
const LM_RELATIVE_COST_TOLERANCE: f64 = 1e-12;
/// Initial damping relative to the largest diagonal entry of JᵀJ.
const LM_INITIAL_LAMBDA: f64 = 1e-4;

/// One camera's intrinsic state and which parameters move.
#[derive(Debug, Clone, Copy)]
pub(crate) struct CamState {
    pub intr: Intrinsics,
    pub dist: Distortion,
    /// Free flags in [`INTR_NAMES`] order. When `aspect` is set, `fy` is not free and follows fx.
    pub free: [bool; N_INTR],
    /// `Some(fy/fx)` when the aspect ratio is fixed.
    pub aspect: Option<f64>,
}

impl CamState {
    fn add(&mut self, i: usize, v: f64) {
        let k = &mut self.intr;
        let d = &mut self.dist;
        match i {
            0 => k.fx += v,
            1 => k.fy += v,
            2 => k.cx += v,
            3 => k.cy += v,
            4 => k.skew += v,
            5 => d.k1 += v,
            6 => d.k2 += v,
            7 => d.p1 += v,
            8 => d.p2 += v,
            _ => d.k3 += v,
        }
    }
}

/// One observed corner.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Obs {
    pub cam: usize,
    pub view: usize,
    /// Board index of the corner (for reports).
    pub id: usize,
    pub object: Vector3<f64>,
    pub pixel: Vector2<f64>,
    pub active: bool,
    /// Weight of the squared residual, 1/σ² of this corner's noise relative to the problem's
    /// unit (1 unless the caller knows the cameras' noise differs).
    pub weight: f64,
}

/// The whole least-squares problem.
#[derive(Debug, Clone)]
pub(crate) struct Problem {
    pub cams: Vec<CamState>,
    /// `cam_from_ref[0]` is the identity and never moves.
    pub cam_from_ref: Vec<RigidTransform>,
    /// Whether `cam_from_ref[c]` (c ≥ 1) is optimised.
    pub extrinsics_free: bool,
    pub ref_from_board: Vec<RigidTransform>,
    /// Views that take part (a rejected view's pose is not optimised).
    pub view_active: Vec<bool>,
    pub obs: Vec<Obs>,
}

/// Column offsets of the parameter blocks.
#[derive(Debug, Clone)]
pub(crate) struct Layout {
    /// Per camera, per intrinsic parameter: its column, if free.
    pub intr_col: Vec<[Option<usize>; N_INTR]>,
    /// Per camera: first column of its 6 extrinsic parameters (None for camera 0 / fixed).
    pub extr_col: Vec<Option<usize>>,
    /// Per view: first column of its 6 pose parameters (None when inactive).
    pub view_col: Vec<Option<usize>>,
    pub n: usize,
}

/// Solver output statistics.
#[derive(Debug, Clone)]
pub(crate) struct Solution {
    pub cost: f64,
    pub n_active_obs: usize,
    pub n_params: usize,
    pub iterations: usize,
    /// JᵀJ at the solution.
    jtj: DMatrix<f64>,
    /// (JᵀJ)⁻¹, computed once on first use ([`Solution::covariance_unscaled`]): the outlier
    /// and reweighting rounds solve several times and only the last solution's σ is reported.
    covariance: std::cell::OnceCell<Option<DMatrix<f64>>>,
    pub layout: Layout,
}

impl Solution {
    /// (JᵀJ)⁻¹ at the solution, `None` when singular (computed on the first call).
    pub fn covariance_unscaled(&self) -> Option<&DMatrix<f64>> {
        self.covariance.get_or_init(|| self.jtj.clone().cholesky().map(|c| c.inverse())).as_ref()
    }
}

fn skew3(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

impl Problem {
    pub fn layout(&self) -> Layout {
        let mut n = 0;
        let mut intr_col = Vec::new();
        for c in &self.cams {
            let mut cols = [None; N_INTR];
            for (i, col) in cols.iter_mut().enumerate() {
                if c.free[i] {
                    *col = Some(n);
                    n += 1;
                }
            }
            intr_col.push(cols);
        }
        let mut extr_col = vec![None; self.cams.len()];
        if self.extrinsics_free {
            for col in extr_col.iter_mut().skip(1) {
                *col = Some(n);
                n += 6;
            }
        }
        let mut view_col = vec![None; self.ref_from_board.len()];
        for (v, col) in view_col.iter_mut().enumerate() {
            if self.view_active[v] && self.obs.iter().any(|o| o.active && o.view == v) {
                *col = Some(n);
                n += 6;
            }
        }
        Layout { intr_col, extr_col, view_col, n }
    }

    /// Projection of one observation (no Jacobian).
    pub fn project(&self, o: &Obs) -> Option<Vector2<f64>> {
        let x_ref = self.ref_from_board[o.view].apply(&o.object);
        let p = self.cam_from_ref[o.cam].apply(&x_ref);
        if p.z <= 0.0 {
            return None;
        }
        let c = &self.cams[o.cam];
        let d = c.dist.distort(p.x / p.z, p.y / p.z);
        Some(c.intr.to_pixel(d.x, d.y))
    }

    /// Residual of one observation (projected − observed); a point behind the camera gets a
    /// large residual so the step that caused it is rejected.
    pub fn residual(&self, o: &Obs) -> Vector2<f64> {
        match self.project(o) {
            Some(p) => p - o.pixel,
            None => Vector2::new(1e6, 1e6),
        }
    }

    /// Σ weight·|residual|² over the active observations.
    pub fn cost(&self) -> f64 {
        self.obs
            .iter()
            .filter(|o| o.active && self.view_active[o.view])
            .map(|o| o.weight * self.residual(o).norm_squared())
            .sum()
    }

    /// Residual and the Jacobian entries `(column, ∂residual/∂param)` of one observation.
    fn linearise(
        &self,
        o: &Obs,
        lay: &Layout,
        out: &mut Vec<(usize, Vector2<f64>)>,
    ) -> Vector2<f64> {
        out.clear();
        let rb = &self.ref_from_board[o.view];
        let cr = &self.cam_from_ref[o.cam];
        let rot_x = rb.rotation * o.object;
        let x_ref = rot_x + rb.translation;
        let cr_rot = cr.rotation * x_ref;
        let p = cr_rot + cr.translation;
        if p.z <= 0.0 {
            return Vector2::new(1e6, 1e6);
        }
        let c = &self.cams[o.cam];
        let iz = 1.0 / p.z;
        let (x, y) = (p.x * iz, p.y * iz);
        let (d, jd) = c.dist.distort_with_jacobian(x, y);
        let k = &c.intr;
        let pix = k.to_pixel(d.x, d.y);
        let kl = Matrix2::new(k.fx, k.skew, 0.0, k.fy);
        let dxy_dp = Matrix2x3::new(iz, 0.0, -x * iz, 0.0, iz, -y * iz);
        let dpix_dp = kl * jd * dxy_dp;

        // Intrinsics.
        let cols = &lay.intr_col[o.cam];
        let r2 = x * x + y * y;
        for (i, col) in cols.iter().enumerate() {
            let Some(col) = *col else { continue };
            let g = match i {
                0 => match c.aspect {
                    Some(a) => Vector2::new(d.x, a * d.y),
                    None => Vector2::new(d.x, 0.0),
                },
                1 => Vector2::new(0.0, d.y),
                2 => Vector2::new(1.0, 0.0),
                3 => Vector2::new(0.0, 1.0),
                4 => Vector2::new(d.y, 0.0),
                5 => kl * Vector2::new(x * r2, y * r2),
                6 => kl * Vector2::new(x * r2 * r2, y * r2 * r2),
                7 => kl * Vector2::new(2.0 * x * y, r2 + 2.0 * y * y),
                8 => kl * Vector2::new(r2 + 2.0 * x * x, 2.0 * x * y),
                _ => kl * Vector2::new(x * r2 * r2 * r2, y * r2 * r2 * r2),
            };
            out.push((col, g));
        }
        // Camera extrinsics: X_cam = R_c X_ref + t_c.
        if let Some(col) = lay.extr_col[o.cam] {
            let dr = dpix_dp * (-skew3(&cr_rot));
            for j in 0..3 {
                out.push((col + j, dr.column(j).into()));
                out.push((col + 3 + j, dpix_dp.column(j).into()));
            }
        }
        // View pose: X_ref = R_v X_b + t_v.
        if let Some(col) = lay.view_col[o.view] {
            let rc = cr.rotation.matrix();
            let dt = dpix_dp * rc;
            let dr = dt * (-skew3(&rot_x));
            for j in 0..3 {
                out.push((col + j, dr.column(j).into()));
                out.push((col + 3 + j, dt.column(j).into()));
            }
        }
        pix - o.pixel
    }

    /// JᵀJ, Jᵀr and the cost at the current state.
    fn normal_equations(&self, lay: &Layout) -> (DMatrix<f64>, DVector<f64>, f64) {
        let mut jtj = DMatrix::zeros(lay.n, lay.n);
        let mut jtr = DVector::zeros(lay.n);
        let mut cost = 0.0;
        let mut entries = Vec::with_capacity(32);
        for o in self.obs.iter().filter(|o| o.active && self.view_active[o.view]) {
            let r = self.linearise(o, lay, &mut entries);
            let w = o.weight;
            cost += w * r.norm_squared();
            for &(a, ga) in &entries {
                jtr[a] += w * ga.dot(&r);
                for &(b, gb) in &entries {
                    if b >= a {
                        jtj[(a, b)] += w * ga.dot(&gb);
                    }
                }
            }
        }
        for a in 0..lay.n {
            for b in 0..a {
                jtj[(a, b)] = jtj[(b, a)];
            }
        }
        (jtj, jtr, cost)
    }

    fn apply(&mut self, lay: &Layout, delta: &DVector<f64>) {
        for (ci, cols) in lay.intr_col.iter().enumerate() {
            for (i, col) in cols.iter().enumerate() {
                if let Some(col) = col {
                    self.cams[ci].add(i, delta[*col]);
                }
            }
            if let Some(a) = self.cams[ci].aspect {
                self.cams[ci].intr.fy = a * self.cams[ci].intr.fx;
            }
        }
        let update = |t: &mut RigidTransform, col: usize| {
            let w = Vector3::new(delta[col], delta[col + 1], delta[col + 2]);
            t.rotation = Rotation3::new(w) * t.rotation;
            t.translation += Vector3::new(delta[col + 3], delta[col + 4], delta[col + 5]);
        };
        for (ci, col) in lay.extr_col.iter().enumerate() {
            if let Some(col) = col {
                update(&mut self.cam_from_ref[ci], *col);
            }
        }
        for (vi, col) in lay.view_col.iter().enumerate() {
            if let Some(col) = col {
                update(&mut self.ref_from_board[vi], *col);
            }
        }
    }

    /// Levenberg–Marquardt to convergence; returns statistics and JᵀJ for the unscaled
    /// covariance.
    pub fn solve(&mut self) -> Solution {
        let lay = self.layout();
        let mut iterations = 0;
        let (mut jtj, mut jtr, mut cost) = self.normal_equations(&lay);
        let max_diag = (0..lay.n).map(|i| jtj[(i, i)]).fold(0.0_f64, f64::max).max(1e-12);
        let mut lambda = LM_INITIAL_LAMBDA;
        let _ = max_diag;
        while iterations < LM_MAX_ITERATIONS {
            iterations += 1;
            let mut improved = false;
            for _ in 0..20 {
                let mut a = jtj.clone();
                for i in 0..lay.n {
                    a[(i, i)] += lambda * jtj[(i, i)].max(1e-9);
                }
                let Some(ch) = a.cholesky() else {
                    lambda *= 10.0;
                    continue;
                };
                let delta = -ch.solve(&jtr);
                let mut trial = self.clone();
                trial.apply(&lay, &delta);
                let new_cost = trial.cost();
                if new_cost.is_finite() && new_cost < cost {
                    let rel = (cost - new_cost) / cost.max(1e-300);
                    *self = trial;
                    lambda = (lambda / 10.0).max(1e-12);
                    improved = rel > LM_RELATIVE_COST_TOLERANCE;
                    let ne = self.normal_equations(&lay);
                    jtj = ne.0;
                    jtr = ne.1;
                    cost = ne.2;
                    break;
                }
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
        let n_active_obs = self.obs.iter().filter(|o| o.active && self.view_active[o.view]).count();
        Solution {
            cost,
            n_active_obs,
            n_params: lay.n,
            iterations,
            jtj,
            covariance: std::cell::OnceCell::new(),
            layout: lay,
        }
    }
}
