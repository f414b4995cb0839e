//! Joint calibration of N cameras (several Kinects' IR and colour cameras, or any cameras)
//! from views of one checkerboard in which any subset of the cameras sees the board.
//!
//! 1. Each camera alone: [`calibrate_mono`] (the same model and flags as `kfuse calibrate`),
//!    which also gives each of its views' board pose.
//! 2. The covisibility graph (cameras linked when they share a view id with a board pose
//!    in both) and its BFS spanning tree from the reference camera; each tree edge's relative
//!    pose is the medoid over the shared views of `T_b · T_a⁻¹` (the candidate with the
//!    smallest summed distance to the others, robust to one bad view). A graph that falls
//!    apart is [`CalibError::NotConnected`], naming the groups.
//! 3. One Levenberg–Marquardt (the crate's dense solver, `bundle`) over every camera's
//!    intrinsics and distortion, every camera pose (the reference fixed at the identity)
//!    and one board pose per view id in the reference frame, over every (camera, view)
//!    observation, with the crate's corner and view outlier rejection.
//! 4. σ of every parameter: `sqrt(diag((JᵀJ)⁻¹)·σ²)` with the residual variance σ², as
//!    [`crate::stereo`] does.
//!
//! The normal equations are dense: at most [`MAX_CAMERAS`] cameras and [`MAX_VIEWS`] view
//! ids (≈ 700 unknowns) are accepted.

mod graph;
pub mod input;
pub mod report;
#[cfg(test)]
mod tests;

use std::collections::{BTreeMap, BTreeSet};

use geometry::{CameraModel, CameraRole, MultiRig, RigCamera, RigidTransform};
use nalgebra::Vector3;

use crate::bundle::{CamState, Obs, Problem};
use crate::mono::{
    IntrinsicsStd, MonoCalibration, check_finite, intrinsics_std, residual_variance,
    solve_with_outliers,
};
use crate::{Board, CalibError, CalibFlags, ViewCorners, calibrate_mono};

/// Most cameras of one joint fit: 8 (four Kinects); the dense normal equations grow as the
/// square of the unknowns.
pub const MAX_CAMERAS: usize = 8;
/// Most view ids of one joint fit: 100 (6 unknowns each; 8 × 10 + 7 × 6 + 600 ≈ 720
/// unknowns, a dense Cholesky of well under a second).
pub const MAX_VIEWS: usize = 100;

/// One camera's input.
#[derive(Debug, Clone)]
pub struct CameraViews {
    /// The camera's name (`a.ir`).
    pub name: String,
    /// Its role.
    pub role: CameraRole,
    /// The sensor it belongs to (`a`), if any.
    pub sensor: Option<String>,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Its views by view id (the same id in two cameras is the same board pose).
    pub views: BTreeMap<u64, ViewCorners>,
    /// Its single-camera flags.
    pub flags: CalibFlags,
}

/// One camera of a [`MultiCalibration`].
#[derive(Debug, Clone)]
pub struct CameraReport {
    /// The camera's name.
    pub name: String,
    /// σ of its intrinsics.
    pub intrinsics_std: IntrinsicsStd,
    /// σ of the rotation of its `camera_from_reference` (small-angle components), rad
    /// (zero for the reference).
    pub rotation_std_rad: Vector3<f64>,
    /// σ of the translation of its `camera_from_reference`, metres.
    pub translation_std_m: Vector3<f64>,
    /// σ of its centre in the reference frame, metres (first order, the rotation's share
    /// included).
    pub center_std_m: Vector3<f64>,
    /// RMS of its corners after the joint fit, px.
    pub rms_px: f64,
    /// Per view id that it saw: the RMS after the joint fit, px.
    pub view_rms_px: BTreeMap<u64, f64>,
    /// Its single-camera calibration.
    pub mono: MonoCalibration,
}

/// The result of [`calibrate_multi`].
#[derive(Debug, Clone)]
pub struct MultiCalibration {
    /// The rig: every camera with its jointly refined model and pose.
    pub rig: MultiRig,
    /// Per camera, in the input order.
    pub cameras: Vec<CameraReport>,
    /// RMS over every corner of the joint fit, px.
    pub rms_px: f64,
    /// Board pose per view id in the reference frame (`reference_from_board`).
    pub board_poses: BTreeMap<u64, RigidTransform>,
    /// View ids rejected by the joint fit, with the reason.
    pub rejected_views: Vec<(u64, String)>,
    /// Corners rejected by the joint fit.
    pub rejected_corners: usize,
    /// The spanning tree: per camera (input order) its parent camera and the number of
    /// shared views of that edge (`None` for the reference).
    pub tree: Vec<Option<(String, usize)>>,
}

/// The medoid of rigid transforms: the one with the smallest summed distance (translation
/// metres + rotation angle × 1 m) to the others.
fn medoid(ts: &[RigidTransform]) -> RigidTransform {
    let dist = |a: &RigidTransform, b: &RigidTransform| {
        (a.translation - b.translation).norm()
            + geometry::pose::rotation_angle(&(a.rotation.inverse() * b.rotation))
    };
    *ts.iter()
        .min_by(|a, b| {
            let sa: f64 = ts.iter().map(|x| dist(a, x)).sum();
            let sb: f64 = ts.iter().map(|x| dist(b, x)).sum();
            sa.total_cmp(&sb)
        })
        .expect("a tree edge has at least one shared view")
}

/// A shared view agrees with its tree edge's medoid when its relative pose is within
/// 50 mm of it: a single view's board pose is off by a few mm plus its rotation error times
/// the distance (0.3° at 2 m: 10 mm), so real views stay well inside, while a view whose id
/// names another board pose in one of the cameras is off by the distance between two board
/// poses (tens of cm).
const EDGE_AGREE_M: f64 = 0.05;
/// See [`EDGE_AGREE_M`]: 3°, ten times a single view's rotation error, far below the tens of
/// degrees between two board poses.
const EDGE_AGREE_DEG: f64 = 3.0;
/// Edges with fewer shared views are not checked: with one or two views the medoid is one of
/// them, and nothing tells the good view from the bad.
const EDGE_CHECK_MIN_VIEWS: usize = 3;

/// Fails when fewer than half of a tree edge's shared views agree with its medoid
/// ([`EDGE_AGREE_M`], [`EDGE_AGREE_DEG`]): the same view id does not show the same board
/// pose in the two cameras (files numbered differently, shots of two sessions). Without it
/// the joint fit starts from a wrong pose and its outlier rounds run for minutes before
/// giving a wrong rig.
fn check_edge_agrees(
    parent: &str,
    camera: &str,
    candidates: &[RigidTransform],
    medoid: &RigidTransform,
) -> Result<(), CalibError> {
    if candidates.len() < EDGE_CHECK_MIN_VIEWS {
        return Ok(());
    }
    let agreeing = candidates
        .iter()
        .filter(|c| {
            (c.translation - medoid.translation).norm() <= EDGE_AGREE_M
                && geometry::pose::rotation_angle(&(c.rotation.inverse() * medoid.rotation))
                    .to_degrees()
                    <= EDGE_AGREE_DEG
        })
        .count();
    if 2 * agreeing < candidates.len() {
        return Err(CalibError::ViewsDisagree {
            camera: camera.to_string(),
            parent: parent.to_string(),
            shared: candidates.len(),
            agreeing,
        });
    }
    Ok(())
}

/// Calibrates the cameras jointly. `reference` names the reference camera; `None` takes the
/// first depth camera (or the first camera when there is none).
pub fn calibrate_multi(
    board: &Board,
    cameras: &[CameraViews],
    reference: Option<&str>,
) -> Result<MultiCalibration, CalibError> {
    if cameras.is_empty() || cameras.len() > MAX_CAMERAS {
        return Err(CalibError::InvalidArgument(format!(
            "{} cameras: a joint calibration takes 1 to {MAX_CAMERAS}",
            cameras.len()
        )));
    }
    let all_ids: BTreeSet<u64> = cameras.iter().flat_map(|c| c.views.keys().copied()).collect();
    if all_ids.len() > MAX_VIEWS {
        return Err(CalibError::InvalidArgument(format!(
            "{} view ids: a joint calibration takes at most {MAX_VIEWS}; leave some shots out",
            all_ids.len()
        )));
    }
    let ref_idx = match reference {
        Some(r) => cameras.iter().position(|c| c.name == r).ok_or_else(|| {
            CalibError::InvalidArgument(format!(
                "reference camera '{r}' is not among the cameras ({})",
                cameras.iter().map(|c| c.name.as_str()).collect::<Vec<_>>().join(", ")
            ))
        })?,
        None => cameras.iter().position(|c| c.role == CameraRole::Depth).unwrap_or(0),
    };
    // 1. Each camera alone.
    let mut monos = Vec::with_capacity(cameras.len());
    for c in cameras {
        if c.views.values().all(|v| v.corners.is_empty()) {
            return Err(CalibError::NoBoard {
                camera: format!("camera {}", c.name),
                images: c.views.len(),
                cols: board.cols,
                rows: board.rows,
            });
        }
        let views: Vec<ViewCorners> = c.views.values().cloned().collect();
        monos.push(calibrate_mono(&format!("camera {}", c.name), board, &views, &c.flags, None)?);
    }
    // Per camera: view id → its single-camera board pose (camera_from_board).
    let poses: Vec<BTreeMap<u64, RigidTransform>> = cameras
        .iter()
        .zip(&monos)
        .map(|(c, m)| {
            c.views
                .keys()
                .zip(&m.views)
                .filter(|(_, v)| v.rejected.is_none())
                .filter_map(|(id, v)| Some((*id, v.camera_from_board?)))
                .collect()
        })
        .collect();
    // 2. Spanning tree and initial poses.
    let names: Vec<String> = cameras.iter().map(|c| c.name.clone()).collect();
    let ids: Vec<Vec<u64>> = poses.iter().map(|p| p.keys().copied().collect()).collect();
    let order = graph::spanning_tree(&names, &ids, ref_idx)?;
    let mut cam_from_ref = vec![RigidTransform::identity(); cameras.len()];
    let mut tree = vec![None; cameras.len()];
    for (b, parent, shared) in &order {
        let Some(a) = *parent else { continue };
        let candidates: Vec<RigidTransform> = shared
            .iter()
            .map(|v| poses[*b][v].compose(&poses[a][v].inverse()).compose(&cam_from_ref[a]))
            .collect();
        let m = medoid(&candidates);
        check_edge_agrees(&names[a], &names[*b], &candidates, &m)?;
        cam_from_ref[*b] = m;
        tree[*b] = Some((names[a].clone(), shared.len()));
    }
    // Solver order: the reference first (the bundle keeps camera 0 fixed).
    let solver_order: Vec<usize> = order.iter().map(|o| o.0).collect();
    let view_ids: Vec<u64> =
        all_ids.iter().copied().filter(|v| ids.iter().any(|i| i.contains(v))).collect();
    let mut ref_from_board = Vec::with_capacity(view_ids.len());
    for v in &view_ids {
        let &c =
            solver_order.iter().find(|&&c| poses[c].contains_key(v)).expect("view id with a pose");
        ref_from_board.push(cam_from_ref[c].inverse().compose(&poses[c][v]));
    }
    // 3. The joint fit.
    let mut obs = Vec::new();
    for (si, &c) in solver_order.iter().enumerate() {
        for (vi, v) in view_ids.iter().enumerate() {
            if !poses[c].contains_key(v) {
                continue;
            }
            for k in &cameras[c].views[v].corners {
                obs.push(Obs {
                    cam: si,
                    view: vi,
                    id: k.id,
                    object: board.object_point(k.id),
                    pixel: k.px,
                    active: true,
                    weight: 1.0,
                });
            }
        }
    }
    let state = |c: usize| {
        let m = &monos[c];
        let f = cameras[c].flags;
        let mut free = f.free_mask();
        let aspect = f.fix_aspect_ratio.then(|| m.camera.intrinsics.fy / m.camera.intrinsics.fx);
        if aspect.is_some() {
            free[1] = false;
        }
        CamState { intr: m.camera.intrinsics, dist: m.camera.distortion, free, aspect }
    };
    let mut p = Problem {
        cams: solver_order.iter().map(|&c| state(c)).collect(),
        cam_from_ref: solver_order.iter().map(|&c| cam_from_ref[c]).collect(),
        extrinsics_free: true,
        view_active: vec![true; view_ids.len()],
        ref_from_board,
        obs,
    };
    let view_name =
        |si: usize, vi: usize| format!("{} view {}", names[solver_order[si]], view_ids[vi]);
    let reject = cameras.iter().all(|c| c.flags.reject_outliers);
    let (sol, rejected_corners, rejected) =
        solve_with_outliers("joint calibration", &mut p, &view_name, solver_order.len(), reject)?;
    check_finite("joint calibration", &p)?;
    let sigma2 = residual_variance(&sol);
    // 4. Reports.
    let cov = sol.covariance_unscaled();
    let mut reports: Vec<Option<CameraReport>> = vec![None; cameras.len()];
    let mut rig_cameras: Vec<Option<RigCamera>> = vec![None; cameras.len()];
    for (si, &c) in solver_order.iter().enumerate() {
        let mut rot = Vector3::zeros();
        let mut tr = Vector3::zeros();
        let mut center = Vector3::zeros();
        let pose = p.cam_from_ref[si];
        if let (Some(cov), Some(col)) = (cov, sol.layout.extr_col[si]) {
            let block = cov.fixed_view::<6, 6>(col, col).into_owned() * sigma2;
            for j in 0..3 {
                rot[j] = block[(j, j)].max(0.0).sqrt();
                tr[j] = block[(3 + j, 3 + j)].max(0.0).sqrt();
            }
            // Centre C = −Rᵀt; with R ← exp(δ)R, t ← t + τ: C ← −Rᵀ(I − [δ]×)(t + τ) =
            // C − Rᵀτ + Rᵀ(δ × t) = C − Rᵀτ − Rᵀ[t]×δ, so ∂C/∂τ = −Rᵀ, ∂C/∂δ = −Rᵀ[t]×. The
            // sign matters: δ and τ are strongly correlated (a camera turned about its centre
            // moves t), and their cross terms cancel most of the two blocks' variance (with
            // +Rᵀ[t]× they added: σ of the centres 2.5× too large, issue 52).
            let rt = pose.rotation.matrix().transpose();
            let t = pose.translation;
            let skew = nalgebra::Matrix3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0);
            let mut j = nalgebra::Matrix3x6::zeros();
            j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-(rt * skew)));
            j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-rt));
            let cc = j * block * j.transpose();
            for k in 0..3 {
                center[k] = cc[(k, k)].max(0.0).sqrt();
            }
        }
        let (mut s, mut n) = (0.0, 0usize);
        let mut per_view: BTreeMap<u64, (f64, usize)> = BTreeMap::new();
        for o in p.obs.iter().filter(|o| o.active && o.cam == si && p.view_active[o.view]) {
            let e = p.residual(o).norm_squared();
            s += e;
            n += 1;
            let pv = per_view.entry(view_ids[o.view]).or_default();
            pv.0 += e;
            pv.1 += 1;
        }
        let st = &p.cams[si];
        let cam = &cameras[c];
        rig_cameras[c] = Some(RigCamera {
            name: cam.name.clone(),
            role: cam.role,
            sensor: cam.sensor.clone(),
            model: CameraModel::new(cam.width, cam.height, st.intr, st.dist),
            camera_from_reference: pose,
            depth_correction: None,
        });
        reports[c] = Some(CameraReport {
            name: cam.name.clone(),
            intrinsics_std: intrinsics_std(&sol, si, sigma2),
            rotation_std_rad: rot,
            translation_std_m: tr,
            center_std_m: center,
            rms_px: (s / n.max(1) as f64).sqrt(),
            view_rms_px: per_view
                .into_iter()
                .map(|(k, (s, n))| (k, (s / n as f64).sqrt()))
                .collect(),
            mono: monos[c].clone(),
        });
    }
    let (s, n) = p
        .obs
        .iter()
        .filter(|o| o.active && p.view_active[o.view])
        .fold((0.0, 0usize), |(s, n), o| (s + p.residual(o).norm_squared(), n + 1));
    Ok(MultiCalibration {
        rig: MultiRig {
            reference: names[ref_idx].clone(),
            cameras: rig_cameras.into_iter().map(|c| c.expect("every camera solved")).collect(),
            calibration: None,
            rectified: false,
        },
        cameras: reports.into_iter().map(|c| c.expect("every camera solved")).collect(),
        rms_px: (s / n.max(1) as f64).sqrt(),
        board_poses: view_ids
            .iter()
            .enumerate()
            .filter(|(vi, _)| p.view_active[*vi])
            .map(|(vi, v)| (*v, p.ref_from_board[vi]))
            .collect(),
        rejected_views: rejected.into_iter().map(|(v, why)| (view_ids[v], why)).collect(),
        rejected_corners: rejected_corners.len(),
        tree,
    })
}
