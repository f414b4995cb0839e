//! The calibration page: per-image RMS bars, detected corners over each image, residual
//! vectors, board poses around the cameras in 3D (a wireframe painted with egui's painter)
//! and the parameter table with ±3σ. The numbers come from [`crate::calibration`].
//!
//! Size (~690 lines, one file): the five views (errors, corners, residuals, poses,
//! parameters) are methods of one [`CalibPage`] that share its state (selected camera and
//! image, orbit camera, texture cache, drawn counts the tests read); split, that private
//! state would become crate-visible for one page.

use std::collections::HashMap;

use egui::{Color32, Pos2, Rect, Sense, Stroke, TextureHandle, TextureOptions, Vec2};
use geometry::{CameraModel, RigidTransform};
use nalgebra::Vector3;

use crate::calibration::{CalibCamera, CalibReport, residual_gain};
use crate::camera3d::OrbitCamera;
use crate::view2d::View2d;

/// Depth of the drawn camera frusta, metres: a third of the closest board distances the lab
/// uses (0.45–0.9 m), so the pyramids are visible without hiding the boards.
pub const FRUSTUM_DEPTH_M: f64 = 0.15;

/// Sub-views of the calibration page.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CalibView {
    /// Per-image RMS bars.
    Errors,
    /// Detected corners over the selected image.
    Corners,
    /// Residual vectors of the selected camera.
    Residuals,
    /// Board poses around the cameras, 3D.
    Poses,
    /// Parameters with ±3σ.
    Parameters,
}

impl CalibView {
    /// All sub-views in menu order.
    pub const ALL: [CalibView; 5] = [
        CalibView::Errors,
        CalibView::Corners,
        CalibView::Residuals,
        CalibView::Poses,
        CalibView::Parameters,
    ];

    /// Button label.
    pub fn label(self) -> &'static str {
        match self {
            CalibView::Errors => "Per-image error",
            CalibView::Corners => "Detected corners",
            CalibView::Residuals => "Residual vectors",
            CalibView::Poses => "Board poses (3D)",
            CalibView::Parameters => "Parameters ±3σ",
        }
    }
}

/// One bar of the error chart.
#[derive(Debug, Clone, PartialEq)]
pub struct ErrorBar {
    /// Image name.
    pub name: String,
    /// RMS, px, as in the report (`None` = no usable board).
    pub rms_px: Option<f64>,
    /// Rejected view (drawn grey with a cross).
    pub rejected: bool,
}

/// State of the calibration page.
pub struct CalibPage {
    /// The report shown.
    pub report: CalibReport,
    /// Shown sub-view.
    pub view: CalibView,
    /// Selected camera (index into `report.cameras`).
    pub camera: usize,
    /// Selected image of that camera.
    pub image: usize,
    /// Zoom/pan of the corner image.
    pub view2d: View2d,
    /// The 3D camera of the pose view.
    pub orbit: OrbitCamera,
    /// Corner markers painted in the last frame of the corner view.
    pub markers_drawn: usize,
    /// Residual arrows painted in the last frame of the residual view.
    pub arrows_drawn: usize,
    /// The residual view shows the stereo joint fit's residuals (when the report has them;
    /// the default) rather than the single-camera fit's.
    pub joint_residuals: bool,
    /// Board outlines painted in the last frame of the pose view.
    pub boards_drawn: usize,
    home: OrbitCamera,
    textures: HashMap<(usize, usize), Result<TextureHandle, String>>,
}

/// Hue-spread colours for boards (egui has no palette; 10 distinguishable hues).
fn palette(i: usize) -> Color32 {
    const P: [[u8; 3]; 10] = [
        [31, 119, 180],
        [255, 127, 14],
        [44, 160, 44],
        [214, 39, 40],
        [148, 103, 189],
        [140, 86, 75],
        [227, 119, 194],
        [127, 127, 127],
        [188, 189, 34],
        [23, 190, 207],
    ];
    let c = P[i % P.len()];
    Color32::from_rgb(c[0], c[1], c[2])
}

impl CalibPage {
    /// The page on `report`, showing the error bars.
    pub fn new(report: CalibReport) -> Self {
        let home = Self::home_orbit(&report);
        Self {
            report,
            view: CalibView::Errors,
            camera: 0,
            image: 0,
            view2d: View2d::default(),
            orbit: home,
            markers_drawn: 0,
            arrows_drawn: 0,
            joint_residuals: true,
            boards_drawn: 0,
            home,
            textures: HashMap::new(),
        }
    }

    /// The error chart's bars per camera: exactly the report's per-image RMS values.
    pub fn error_bars(&self) -> Vec<(&'static str, Vec<ErrorBar>)> {
        self.report
            .cameras
            .iter()
            .map(|c| {
                (
                    c.label,
                    c.images
                        .iter()
                        .map(|i| ErrorBar {
                            name: i.name.clone(),
                            rms_px: i.rms_px,
                            rejected: i.rejected.is_some(),
                        })
                        .collect(),
                )
            })
            .collect()
    }

    /// Board poses in the 3D view's frame (the depth camera for a stereo report, else the
    /// camera's own), with the image index they belong to.
    pub fn board_poses(&self) -> Vec<(usize, RigidTransform)> {
        if self.report.stereo.is_some() && !self.report.depth_from_board.is_empty() {
            return self
                .report
                .depth_from_board
                .iter()
                .enumerate()
                .filter_map(|(i, p)| p.map(|p| (i, p)))
                .collect();
        }
        self.report.cameras.first().map_or(Vec::new(), |c| {
            c.images
                .iter()
                .enumerate()
                .filter_map(|(i, im)| im.camera_from_board.map(|p| (i, p)))
                .collect()
        })
    }

    /// The cameras in the 3D view's frame: (label, model, frame_from_camera).
    pub fn camera_poses(&self) -> Vec<(&'static str, CameraModel, RigidTransform)> {
        let mut out = Vec::new();
        for (i, c) in self.report.cameras.iter().enumerate() {
            let pose = match (&self.report.stereo, i) {
                (Some(s), 1) => s.color_from_depth.inverse(),
                _ => RigidTransform::identity(),
            };
            out.push((c.label, c.model, pose));
        }
        out
    }

    fn home_orbit(report: &CalibReport) -> OrbitCamera {
        let page_poses: Vec<Vector3<f64>> = if report.stereo.is_some() {
            report.depth_from_board.iter().flatten().map(|p| p.translation).collect()
        } else {
            report.cameras.first().map_or(Vec::new(), |c| {
                c.images.iter().filter_map(|i| i.camera_from_board.map(|p| p.translation)).collect()
            })
        };
        let n = page_poses.len().max(1) as f64;
        let c = page_poses.iter().fold(Vector3::zeros(), |a, p| a + p) / n;
        // Half-way between the cameras (origin) and the boards, seen from above and aside.
        let target = [(c.x * 0.5) as f32, (c.y * 0.5) as f32, (c.z * 0.5) as f32];
        let distance = (c.norm() * 1.6).max(0.5) as f32;
        OrbitCamera { target, distance, yaw: 0.9, pitch: 0.45 }
    }

    fn selected_camera(&self) -> Option<&CalibCamera> {
        self.report.cameras.get(self.camera)
    }

    /// Draws the page.
    pub fn ui(&mut self, ui: &mut egui::Ui) {
        egui::Panel::left("kfuse-calib-nav").resizable(false).show(ui, |ui| {
            ui.heading("Calibration");
            for v in CalibView::ALL {
                ui.selectable_value(&mut self.view, v, v.label());
            }
            ui.separator();
            if self.report.cameras.len() > 1 {
                ui.horizontal(|ui| {
                    for (i, c) in self.report.cameras.iter().enumerate() {
                        if ui.selectable_label(self.camera == i, format!("{} camera", c.label)).clicked() && self.camera != i {
                            self.camera = i;
                            self.image = self.image.min(c.images.len().saturating_sub(1));
                            self.view2d = View2d::default();
                        }
                    }
                });
            }
            let Some(cam) = self.report.cameras.get(self.camera) else { return };
            ui.label(format!("{} images, RMS {:.4} px (bar {} px)", cam.images.len(), cam.rms_px, cam.limit_px));
            let mut pick = None;
            egui::ScrollArea::vertical().show(ui, |ui| {
                for (i, im) in cam.images.iter().enumerate() {
                    let rms = im.rms_px.map_or("—".to_string(), |r| format!("{r:.4}"));
                    // A view the stereo joint fit down-weighted shows its weight.
                    let weight = im.joint_weight.filter(|w| *w < 1.0).map_or(String::new(), |w| format!("  w {w:.2}"));
                    let text = match &im.rejected {
                        Some(_) => egui::RichText::new(format!("X {}  {rms}", im.name)).color(Color32::from_rgb(220, 90, 90)),
                        None => egui::RichText::new(format!("{}  {rms}{weight}", im.name)),
                    };
                    let r = ui.selectable_label(self.image == i, text);
                    let r = match (&im.rejected, im.joint_weight) {
                        (Some(why), _) => r.on_hover_text(format!("rejected: {why}")),
                        (None, Some(w)) => r.on_hover_text(format!(
                            "weight {w:.2} in the stereo joint fit (1 = this camera's own noise level; a noisier view counts less)"
                        )),
                        (None, None) => r,
                    };
                    if r.clicked() {
                        pick = Some(i);
                    }
                }
            });
            if let Some(i) = pick {
                self.image = i;
            }
        });
        egui::Panel::bottom("kfuse-calib-source").show(ui, |ui| {
            ui.label(format!("report: {}", self.report.source.display()));
        });
        egui::CentralPanel::default().show(ui, |ui| match self.view {
            CalibView::Errors => self.errors_ui(ui),
            CalibView::Corners => self.corners_ui(ui),
            CalibView::Residuals => self.residuals_ui(ui),
            CalibView::Poses => self.poses_ui(ui),
            CalibView::Parameters => self.parameters_ui(ui),
        });
    }

    fn errors_ui(&mut self, ui: &mut egui::Ui) {
        let bars = self.error_bars();
        let rect = ui.available_rect_before_wrap();
        let resp = ui.allocate_rect(rect, Sense::click());
        let painter = ui.painter_at(rect);
        let text = ui.visuals().text_color();
        let font = egui::FontId::proportional(12.0);
        let rows = bars.len().max(1);
        let row_h = rect.height() / rows as f32;
        let mut clicked = None;
        for (ci, (label, list)) in bars.iter().enumerate() {
            let limit = self.report.cameras[ci].limit_px;
            let area = Rect::from_min_size(
                Pos2::new(rect.min.x + 50.0, rect.min.y + ci as f32 * row_h + 24.0),
                Vec2::new(rect.width() - 60.0, row_h - 48.0),
            );
            let ymax = list.iter().filter_map(|b| b.rms_px).fold(limit, f64::max) * 1.15;
            let y_of = |v: f64| area.max.y - (v / ymax) as f32 * area.height();
            painter.text(Pos2::new(area.min.x, area.min.y - 20.0), egui::Align2::LEFT_TOP,
                format!("{label} camera: RMS per image, px (red line: handout bar {limit} px; grey X: rejected)"), egui::FontId::proportional(14.0), text);
            painter.line_segment(
                [area.left_bottom(), area.right_bottom()],
                Stroke::new(1.0, Color32::GRAY),
            );
            painter.line_segment(
                [area.left_bottom(), area.left_top()],
                Stroke::new(1.0, Color32::GRAY),
            );
            for k in 0..=4 {
                let v = ymax * k as f64 / 4.0;
                painter.text(
                    Pos2::new(area.min.x - 4.0, y_of(v)),
                    egui::Align2::RIGHT_CENTER,
                    format!("{v:.2}"),
                    font.clone(),
                    text,
                );
            }
            let n = list.len().max(1);
            let w = area.width() / n as f32;
            for (i, b) in list.iter().enumerate() {
                let x0 = area.min.x + i as f32 * w;
                let slot =
                    Rect::from_min_max(Pos2::new(x0, area.min.y), Pos2::new(x0 + w, area.max.y));
                let colour = if b.rejected {
                    Color32::from_gray(150)
                } else if b.rms_px.is_some_and(|r| r > limit) {
                    Color32::from_rgb(214, 39, 40)
                } else {
                    Color32::from_rgb(31, 119, 180)
                };
                if let Some(r) = b.rms_px {
                    let bar = Rect::from_min_max(
                        Pos2::new(x0 + 0.15 * w, y_of(r)),
                        Pos2::new(x0 + 0.85 * w, area.max.y),
                    );
                    painter.rect_filled(bar, 0.0, colour);
                }
                if b.rejected {
                    painter.text(
                        Pos2::new(slot.center().x, area.max.y - 10.0),
                        egui::Align2::CENTER_CENTER,
                        "X",
                        egui::FontId::proportional(16.0),
                        Color32::from_rgb(220, 60, 60),
                    );
                }
                if self.camera == ci && self.image == i {
                    painter.rect_stroke(
                        slot,
                        0.0,
                        Stroke::new(1.5, Color32::YELLOW),
                        egui::StrokeKind::Inside,
                    );
                }
                painter.text(
                    Pos2::new(slot.center().x, area.max.y + 2.0),
                    egui::Align2::CENTER_TOP,
                    format!("{}", i + 1),
                    font.clone(),
                    text,
                );
                if resp.hover_pos().is_some_and(|p| slot.contains(p)) {
                    let rms = b.rms_px.map_or("no board".to_string(), |r| format!("{r:.4} px"));
                    let why = self.report.cameras[ci].images[i]
                        .rejected
                        .as_deref()
                        .map_or(String::new(), |w| format!(" — rejected: {w}"));
                    painter.text(
                        Pos2::new(area.max.x, area.min.y - 20.0),
                        egui::Align2::RIGHT_TOP,
                        format!("{}: {rms}{why}", b.name),
                        font.clone(),
                        Color32::YELLOW,
                    );
                    if resp.clicked() {
                        clicked = Some((ci, i));
                    }
                }
            }
            painter.line_segment(
                [Pos2::new(area.min.x, y_of(limit)), Pos2::new(area.max.x, y_of(limit))],
                Stroke::new(1.5, Color32::from_rgb(214, 39, 40)),
            );
        }
        if let Some((c, i)) = clicked {
            self.camera = c;
            self.image = i;
        }
    }

    fn texture(&mut self, ctx: &egui::Context) -> Option<Result<TextureHandle, String>> {
        let key = (self.camera, self.image);
        if !self.textures.contains_key(&key) {
            let im = self.report.cameras.get(self.camera)?.images.get(self.image)?;
            let tex = match &im.image {
                None => {
                    Err("the report names no image file (re-run `kfuse calibrate`)".to_string())
                }
                Some(path) => match kfuse_io::images::read_color(path) {
                    Ok(img) => {
                        let bytes: Vec<u8> = img.data().iter().flatten().copied().collect();
                        let color = egui::ColorImage::from_rgb([img.width(), img.height()], &bytes);
                        Ok(ctx.load_texture(
                            format!("calib-{}-{}", self.camera, self.image),
                            color,
                            TextureOptions::LINEAR,
                        ))
                    }
                    Err(e) => Err(e.to_string()),
                },
            };
            self.textures.insert(key, tex);
        }
        self.textures.get(&key).cloned()
    }

    fn corners_ui(&mut self, ui: &mut egui::Ui) {
        let Some(cam) = self.selected_camera().cloned() else { return };
        let Some(im) = cam.images.get(self.image).cloned() else { return };
        let tex = self.texture(ui.ctx());
        let size = [cam.model.width, cam.model.height];
        ui.label(format!(
            "{}: {} corners detected (red: corner 0 -> x axis){}",
            im.name,
            im.detected.len(),
            im.rejected.as_deref().map_or(String::new(), |w| format!(" — view rejected: {w}"))
        ));
        if let Some(Err(e)) = &tex {
            ui.colored_label(Color32::from_rgb(230, 150, 80), format!("image not shown: {e}"));
        }
        let rect = ui.available_rect_before_wrap();
        let resp = ui.allocate_rect(rect, Sense::click_and_drag());
        self.view2d.handle_input(ui, &resp, rect, size);
        let painter = ui.painter_at(rect);
        let img_rect = self.view2d.image_rect(rect, size);
        match &tex {
            Some(Ok(t)) => {
                painter.image(
                    t.id(),
                    img_rect,
                    Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0)),
                    Color32::WHITE,
                );
            }
            _ => {
                painter.rect_filled(img_rect, 0.0, Color32::from_gray(40));
            }
        }
        let s = self.view2d.scale(rect, size);
        // Pixel centres at integers: pixel x spans x ± 0.5, so its centre is at edge x + 0.5.
        let to_screen =
            |x: f64, y: f64| img_rect.min + Vec2::new((x as f32 + 0.5) * s, (y as f32 + 0.5) * s);
        let r = (s * size[0].max(size[1]) as f32 / 160.0).max(3.0);
        let mut drawn = 0;
        for c in &im.detected {
            let colour = if c[0] == 0.0 { Color32::RED } else { Color32::from_rgb(40, 220, 40) };
            painter.circle_stroke(to_screen(c[1], c[2]), r, Stroke::new(1.5, colour));
            drawn += 1;
        }
        let find = |id: f64| im.detected.iter().find(|c| c[0] == id);
        if let (Some(a), Some(b)) = (find(0.0), find(1.0)) {
            painter.line_segment(
                [to_screen(a[1], a[2]), to_screen(b[1], b[2])],
                Stroke::new(2.0, Color32::RED),
            );
        }
        self.markers_drawn = drawn;
    }

    fn residuals_ui(&mut self, ui: &mut egui::Ui) {
        let Some(cam) = self.selected_camera().cloned() else { return };
        let joint = self.joint_residuals && cam.has_joint_residuals();
        if cam.has_joint_residuals() {
            ui.horizontal(|ui| {
                ui.selectable_value(&mut self.joint_residuals, true, "stereo joint fit");
                ui.selectable_value(&mut self.joint_residuals, false, "single-camera fit");
            });
        }
        let gain = residual_gain(&cam, joint);
        let largest = cam
            .images
            .iter()
            .flat_map(|i| i.residual_rows(joint))
            .map(|r| r[3].hypot(r[4]))
            .fold(0.0, f64::max);
        let fit = if joint {
            "stereo joint fit"
        } else if self.report.stereo.is_some() {
            "single-camera fit"
        } else {
            "fit"
        };
        ui.label(format!(
            "{} camera, {fit}: residual vectors (observed - projected) of every used corner, magnified ×{gain:.0}; largest {largest:.3} px; selected image highlighted",
            cam.label
        ));
        let rect = ui.available_rect_before_wrap().shrink(8.0);
        ui.allocate_rect(rect, Sense::hover());
        let size = [cam.model.width, cam.model.height];
        let frame = View2d::default().image_rect(
            Rect::from_min_max(rect.min, Pos2::new(rect.max.x, rect.max.y - 30.0)),
            size,
        );
        let painter = ui.painter_at(rect);
        painter.rect_stroke(frame, 0.0, Stroke::new(1.0, Color32::GRAY), egui::StrokeKind::Inside);
        let s = frame.width() / size[0] as f32;
        let at = |x: f64, y: f64| frame.min + Vec2::new((x as f32 + 0.5) * s, (y as f32 + 0.5) * s);
        let mut drawn = 0;
        for (i, im) in cam.images.iter().enumerate() {
            let selected = i == self.image;
            let colour = if selected { Color32::YELLOW } else { Color32::from_rgb(90, 160, 230) };
            for r in im.residual_rows(joint) {
                let p = at(r[1], r[2]);
                let v = Vec2::new((r[3] * gain) as f32 * s, (r[4] * gain) as f32 * s);
                painter.arrow(p, v, Stroke::new(if selected { 1.6 } else { 1.0 }, colour));
                drawn += 1;
            }
        }
        self.arrows_drawn = drawn;
        // Scale bar: the largest "nice" length (1, 2, 5 × 10^k px) not above the largest residual.
        if largest > 0.0 {
            let k = largest.log10().floor();
            let base = 10f64.powf(k);
            let nice =
                [5.0, 2.0, 1.0].iter().map(|m| m * base).find(|&v| v <= largest).unwrap_or(base);
            let len = (nice * gain) as f32 * s;
            let y = frame.max.y + 18.0;
            let x = frame.min.x;
            painter.line_segment(
                [Pos2::new(x, y), Pos2::new(x + len, y)],
                Stroke::new(3.0, Color32::YELLOW),
            );
            painter.text(
                Pos2::new(x + len + 8.0, y),
                egui::Align2::LEFT_CENTER,
                format!("scale: {nice} px residual (×{gain:.0})"),
                egui::FontId::proportional(13.0),
                ui.visuals().text_color(),
            );
        }
    }

    fn poses_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            let frame = if self.report.stereo.is_some() {
                "depth (IR) camera frame"
            } else {
                "camera frame"
            };
            ui.label(format!(
                "Board poses in the {frame}, metres. Drag: orbit · right-drag: pan · scroll: zoom"
            ));
            if ui.button("Reset view").clicked() {
                self.orbit = self.home;
            }
        });
        let canvas = crate::canvas3d::Canvas3d::new(ui, &mut self.orbit);
        let project = |p: Vector3<f64>| canvas.project(p);
        let painter = ui.painter_at(canvas.rect);
        let line =
            |a: Vector3<f64>, b: Vector3<f64>, stroke: Stroke| canvas.line(&painter, a, b, stroke);
        // Axes of the reference frame: x red, y green, z blue, 0.1 m.
        let o = Vector3::zeros();
        for (axis, c) in [
            (Vector3::x(), Color32::RED),
            (Vector3::y(), Color32::GREEN),
            (Vector3::z(), Color32::from_rgb(80, 120, 255)),
        ] {
            line(o, axis * 0.1, Stroke::new(2.0, c));
        }
        for (label, model, pose) in self.camera_poses() {
            let (c, corners) = crate::camera3d::frustum(&model, &pose, FRUSTUM_DEPTH_M);
            let colour = if label == "IR" {
                Color32::from_rgb(230, 120, 230)
            } else {
                Color32::from_rgb(240, 200, 60)
            };
            for i in 0..4 {
                line(c, corners[i], Stroke::new(1.5, colour));
                line(corners[i], corners[(i + 1) % 4], Stroke::new(1.5, colour));
            }
            if let Some(p) = project(corners[0]) {
                painter.text(
                    p,
                    egui::Align2::RIGHT_BOTTOM,
                    format!("{label} camera"),
                    egui::FontId::proportional(13.0),
                    colour,
                );
            }
        }
        let (bw, bh) = self.report.board_size_m();
        let outline = [(0.0, 0.0), (bw, 0.0), (bw, bh), (0.0, bh)];
        let mut drawn = 0;
        for (i, pose) in self.board_poses() {
            let pts: Vec<Vector3<f64>> =
                outline.iter().map(|&(x, y)| pose.apply(&Vector3::new(x, y, 0.0))).collect();
            let colour = palette(i);
            let width = if i == self.image { 3.0 } else { 1.5 };
            for k in 0..4 {
                line(pts[k], pts[(k + 1) % 4], Stroke::new(width, colour));
            }
            // Corner 0 -> x axis, as in the corner view.
            line(
                pts[0],
                pose.apply(&Vector3::new(bw * 0.25, 0.0, 0.0)),
                Stroke::new(width + 1.0, Color32::RED),
            );
            if let Some(p) = project(pose.apply(&Vector3::new(bw * 0.5, bh * 0.5, 0.0))) {
                painter.text(
                    p,
                    egui::Align2::CENTER_CENTER,
                    format!("{}", i + 1),
                    egui::FontId::proportional(12.0),
                    colour,
                );
            }
            drawn += 1;
        }
        self.boards_drawn = drawn;
    }

    fn parameters_ui(&mut self, ui: &mut egui::Ui) {
        fn table(ui: &mut egui::Ui, id: usize, title: &str, rows: &[crate::calibration::ParamRow]) {
            ui.strong(title);
            egui::Grid::new(format!("kfuse-calib-params-{id}")).striped(true).num_columns(3).show(
                ui,
                |ui| {
                    for (name, v, e, unit) in rows {
                        ui.label(name);
                        ui.monospace(format!("{v:>14.6}"));
                        ui.monospace(match e {
                            Some(e) => format!("± {e:.6} {unit}"),
                            None => format!("fixed {unit}"),
                        });
                        ui.end_row();
                    }
                },
            );
        }
        egui::ScrollArea::vertical().show(ui, |ui| {
            ui.label("Intervals are ±3σ (3 × the report's 1σ, comparable with Bouguet's *_error); fixed parameters show none.");
            let groups = self.report.parameter_rows();
            let cams = self.report.cameras.len().min(groups.len());
            // The cameras side by side, the stereo extrinsics below.
            ui.columns(cams.max(1), |cols| {
                for (i, (title, rows)) in groups.iter().take(cams).enumerate() {
                    table(&mut cols[i], i, title, rows);
                }
            });
            for (i, (title, rows)) in groups.iter().enumerate().skip(cams) {
                ui.add_space(8.0);
                table(ui, i, title, rows);
            }
        });
    }
}
