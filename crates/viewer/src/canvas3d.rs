//! A 3D area drawn with egui's painter (lines, dots, labels) under an [`OrbitCamera`]: the
//! calibration page's board poses and the rig page's cameras and merged cloud. The mouse
//! rule of every 3D view: drag = orbit, right-drag = pan, scroll = zoom.

use egui::{Pos2, Rect, Sense};
use nalgebra::{Matrix4, Vector3, Vector4};

use crate::camera3d::OrbitCamera;

/// The rest of `ui`'s space as a 3D canvas seen through `orbit`, after applying this frame's
/// drags and scrolls to it.
pub struct Canvas3d {
    /// The area on screen.
    pub rect: Rect,
    view_proj: Matrix4<f32>,
}

impl Canvas3d {
    /// Takes the remaining space of `ui` and the mouse input over it.
    pub fn new(ui: &mut egui::Ui, orbit: &mut OrbitCamera) -> Self {
        let rect = ui.available_rect_before_wrap();
        let resp = ui.allocate_rect(rect, Sense::click_and_drag());
        if resp.dragged_by(egui::PointerButton::Primary) {
            let d = resp.drag_delta();
            orbit.orbit(d.x, d.y);
        } else if resp.dragged() {
            let d = resp.drag_delta();
            orbit.pan(d.x, d.y, rect.height());
        }
        if resp.hovered() {
            let scroll = ui.input(|i| i.smooth_scroll_delta.y);
            if scroll != 0.0 {
                orbit.zoom(scroll);
            }
        }
        Self { rect, view_proj: orbit.view_proj(rect.width() / rect.height().max(1.0)) }
    }

    /// Where a point lands on screen; `None` behind the eye.
    pub fn project(&self, p: Vector3<f64>) -> Option<Pos2> {
        let c = self.view_proj * Vector4::new(p.x as f32, p.y as f32, p.z as f32, 1.0);
        if c.w <= 1e-4 {
            return None;
        }
        let (x, y) = (c.x / c.w, c.y / c.w);
        Some(Pos2::new(
            self.rect.center().x + x * self.rect.width() * 0.5,
            self.rect.center().y - y * self.rect.height() * 0.5,
        ))
    }

    /// A line from `a` to `b` (nothing when an end is behind the eye).
    pub fn line(
        &self,
        painter: &egui::Painter,
        a: Vector3<f64>,
        b: Vector3<f64>,
        stroke: egui::Stroke,
    ) {
        if let (Some(a), Some(b)) = (self.project(a), self.project(b)) {
            painter.line_segment([a, b], stroke);
        }
    }
}
