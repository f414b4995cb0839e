//! Zoom and pan of the 2D panes (pure math, tested without a window).
//!
//! Image coordinates here are *edge-based* (`0..width`); pixel `i`'s centre is `i + 0.5`
//! (the crate's pixel-centre convention is recovered by subtracting 0.5).

use egui::{Pos2, Rect, Vec2};

/// Largest zoom (× the fitted size): 64 makes a Kinect colour pixel ~30 screen points wide.
pub const MAX_ZOOM: f32 = 64.0;
/// Zoom factor per point of scroll: 100 points ≈ ×1.5.
pub const ZOOM_PER_POINT: f32 = 0.004;

/// Zoom and pan of one image view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View2d {
    /// Magnification relative to fitting the image into the view (1 = fitted).
    pub zoom: f32,
    /// Image point (edge-based) at the view's centre; `None` = the image centre.
    pub center: Option<[f32; 2]>,
}

impl Default for View2d {
    fn default() -> Self {
        Self { zoom: 1.0, center: None }
    }
}

impl View2d {
    fn center_or(&self, size: [usize; 2]) -> Vec2 {
        self.center.map_or(Vec2::new(size[0] as f32 * 0.5, size[1] as f32 * 0.5), |c| {
            Vec2::new(c[0], c[1])
        })
    }

    /// Screen points per image pixel in `rect`.
    pub fn scale(&self, rect: Rect, size: [usize; 2]) -> f32 {
        let fit = (rect.width() / size[0].max(1) as f32).min(rect.height() / size[1].max(1) as f32);
        fit * self.zoom
    }

    /// The screen rectangle the whole image covers.
    pub fn image_rect(&self, rect: Rect, size: [usize; 2]) -> Rect {
        let s = self.scale(rect, size);
        let c = self.center_or(size);
        let min = rect.center() - c * s;
        Rect::from_min_size(min, Vec2::new(size[0] as f32, size[1] as f32) * s)
    }

    /// Screen position → image point, pixel-centre convention (pixel `i` spans `i ± 0.5`).
    pub fn screen_to_pixel(&self, rect: Rect, size: [usize; 2], pos: Pos2) -> [f32; 2] {
        let s = self.scale(rect, size);
        let p = (pos - rect.center()) / s + self.center_or(size);
        [p.x - 0.5, p.y - 0.5]
    }

    /// Zooms by `factor` keeping the image point under `pos` fixed.
    pub fn zoom_at(&mut self, rect: Rect, size: [usize; 2], pos: Pos2, factor: f32) {
        let s0 = self.scale(rect, size);
        let before = (pos - rect.center()) / s0 + self.center_or(size);
        self.zoom = (self.zoom * factor).clamp(1.0, MAX_ZOOM);
        let s1 = self.scale(rect, size);
        let c = before - (pos - rect.center()) / s1;
        self.center = Some([c.x, c.y]);
    }

    /// Applies the mouse input on `resp` (the view's area `rect`): scroll zooms about the
    /// cursor, drag pans.
    pub fn handle_input(
        &mut self,
        ui: &egui::Ui,
        resp: &egui::Response,
        rect: Rect,
        size: [usize; 2],
    ) {
        if resp.hovered() {
            let scroll = ui.input(|i| i.smooth_scroll_delta.y);
            if scroll != 0.0
                && let Some(pos) = resp.hover_pos()
            {
                self.zoom_at(rect, size, pos, (scroll * ZOOM_PER_POINT).exp());
            }
        }
        if resp.dragged() {
            self.pan(rect, size, resp.drag_delta());
        }
    }

    /// Moves the image by `delta` screen points.
    pub fn pan(&mut self, rect: Rect, size: [usize; 2], delta: Vec2) {
        let s = self.scale(rect, size);
        let c = self.center_or(size) - delta / s;
        self.center = Some([c.x, c.y]);
    }
}
