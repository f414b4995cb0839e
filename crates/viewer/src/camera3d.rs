//! The 3D view's orbit camera (pure math, tested without a GPU).
//!
//! The scene is in the colour camera's frame (x right, y down, z forward, metres). The camera
//! orbits `target` at `distance`; `yaw = pitch = 0` looks along +z like the colour camera, so
//! [`OrbitCamera::fit`] starts at the colour camera's viewpoint. Clip space is wgpu's
//! (z in 0..1).

use geometry::{CameraModel, RigidTransform};
use nalgebra::{Matrix4, Point3, Vector3};

/// Vertical field of view, degrees: the Kinect v2 colour camera's (~54°).
pub const FOV_Y_DEG: f32 = 54.0;
/// Radians of orbit per point of mouse drag: a 400-point drag turns ~1.4 rad.
pub const ORBIT_RAD_PER_POINT: f32 = 0.0035;
/// Zoom factor per point of scroll: 100 points of scroll ≈ ×1.5.
pub const ZOOM_PER_POINT: f32 = 0.004;
/// Pitch limit, radians: just short of straight up/down, where the up vector degenerates.
pub const MAX_PITCH: f32 = 1.55;

/// Orbit, pan and zoom state of the 3D view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrbitCamera {
    /// The point orbited, metres (colour frame).
    pub target: [f32; 3],
    /// Eye-to-target distance, metres.
    pub distance: f32,
    /// Rotation about the frame's y axis, radians.
    pub yaw: f32,
    /// Rotation about the camera's x axis, radians.
    pub pitch: f32,
}

impl OrbitCamera {
    /// The view that looks at the centre of `points`' bounding box from the colour
    /// camera's position (the origin). `None` when there are no finite points.
    pub fn fit(points: impl Iterator<Item = [f32; 3]>) -> Option<Self> {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in points.filter(|p| p.iter().all(|c| c.is_finite())) {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        if !lo[0].is_finite() {
            return None;
        }
        let c = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
        // Look along +z at the box centre's depth, from the camera's position.
        let target = [0.0, 0.0, c[2].max(0.1)];
        Some(Self { target, distance: target[2], yaw: 0.0, pitch: 0.0 })
    }

    /// The eye position, metres.
    pub fn eye(&self) -> [f32; 3] {
        let d = self.forward();
        [0, 1, 2].map(|k| self.target[k] - self.distance * d[k])
    }

    fn forward(&self) -> [f32; 3] {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        // y is down: positive pitch looks down at the target from above (-y).
        [sy * cp, sp, cy * cp]
    }

    /// Turns by a drag of `(dx, dy)` points.
    pub fn orbit(&mut self, dx: f32, dy: f32) {
        self.yaw -= dx * ORBIT_RAD_PER_POINT;
        self.pitch = (self.pitch - dy * ORBIT_RAD_PER_POINT).clamp(-MAX_PITCH, MAX_PITCH);
    }

    /// Moves the target by a drag of `(dx, dy)` points in a view `height` points tall, so the
    /// scene under the cursor follows it.
    pub fn pan(&mut self, dx: f32, dy: f32, height: f32) {
        let f = Vector3::from(self.forward());
        let up = Vector3::new(0.0, -1.0, 0.0);
        let right = f.cross(&up).normalize();
        let cam_up = right.cross(&f).normalize();
        let metres_per_point =
            2.0 * self.distance * (FOV_Y_DEG.to_radians() * 0.5).tan() / height.max(1.0);
        let t = Vector3::from(self.target) - right * dx * metres_per_point
            + cam_up * dy * metres_per_point;
        self.target = [t.x, t.y, t.z];
    }

    /// Zooms by a scroll of `dy` points (positive = closer).
    pub fn zoom(&mut self, dy: f32) {
        self.distance = (self.distance * (-dy * ZOOM_PER_POINT).exp()).clamp(0.05, 100.0);
    }

    /// Projection × view for a viewport of `aspect` = width / height.
    pub fn view_proj(&self, aspect: f32) -> Matrix4<f32> {
        let eye = Point3::from(self.eye());
        let target = Point3::from(self.target);
        let view = Matrix4::look_at_rh(&eye, &target, &Vector3::new(0.0, -1.0, 0.0));
        let near = (self.distance * 0.01).max(0.01);
        let far = self.distance * 10.0 + 10.0;
        let f = 1.0 / (FOV_Y_DEG.to_radians() * 0.5).tan();
        #[rustfmt::skip]
        let proj = Matrix4::new(
            f / aspect.max(1e-3), 0.0, 0.0, 0.0,
            0.0, f, 0.0, 0.0,
            0.0, 0.0, far / (near - far), near * far / (near - far),
            0.0, 0.0, -1.0, 0.0,
        );
        proj * view
    }
}
/// A camera's frustum drawn as a pyramid: its optical centre and the rays through its image
/// corners cut at `depth` metres, in the frame that `frame_from_camera` maps the camera into.
/// Corners in the order top-left, top-right, bottom-right, bottom-left.
pub fn frustum(
    model: &CameraModel,
    frame_from_camera: &RigidTransform,
    depth: f64,
) -> (Vector3<f64>, [Vector3<f64>; 4]) {
    let k = model.intrinsics;
    let (w, h) = (model.width as f64 - 1.0, model.height as f64 - 1.0);
    let corner = |u: f64, v: f64| {
        frame_from_camera.apply(&(Vector3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0) * depth))
    };
    (
        frame_from_camera.apply(&Vector3::zeros()),
        [corner(0.0, 0.0), corner(w, 0.0), corner(w, h), corner(0.0, h)],
    )
}
