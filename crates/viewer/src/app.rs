//! [`ViewerApp`]: the viewer's state and its UI.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use egui::{Color32, Pos2, Rect, Sense, Stroke, TextureHandle, TextureOptions, Vec2};

use crate::ViewerError;
use crate::calib_page::CalibPage;
use crate::camera3d::OrbitCamera;
use crate::data::{self, Frame};
use crate::live::LivePage;
use crate::panes::{self, Pane, Probe};
use crate::pipeline::{self, Fused, MeshGrid, Resampling, Toggles};
use crate::render3d::{DrawParams, Geometry3d, View3dCallback};
use crate::view2d::View2d;
use fusion_gpu::Engine;

/// The viewer's pages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Page {
    /// The 2D panes (colour, depth, IR, overlays, holes, colour on depth).
    Images,
    /// The 3D view of the cloud and the mesh with the fusion switches.
    View3d,
    /// The fusion's counts and parameters.
    Summary,
    /// A `kfuse calibrate` report.
    Calibration,
    /// The sensor's live streams.
    Live,
    /// The cameras of a rig of several cameras and the merged cloud.
    Rig,
}

impl Page {
    /// The pages of a fused frame, in tab order.
    pub const ALL: [Page; 3] = [Page::Images, Page::View3d, Page::Summary];

    /// Tab label.
    pub fn label(self) -> &'static str {
        match self {
            Page::Images => "2D images",
            Page::View3d => "3D view",
            Page::Summary => "Summary",
            Page::Calibration => "Calibration",
            Page::Live => "Live",
            Page::Rig => "Rig",
        }
    }
}

/// All state of the viewer.
pub struct ViewerApp {
    /// The loaded frame, if any.
    pub frame: Option<Arc<Frame>>,
    /// The last fusion result.
    pub fused: Option<Fused>,
    /// What went wrong (shown in an error panel).
    pub error: Option<ViewerError>,
    /// Problems of a rig used with `--force` (one line each; `kfuse view` prints them).
    pub warnings: Vec<String>,
    /// Shown page.
    pub page: Page,
    /// Shown 2D pane.
    pub pane: Pane,
    /// The pipeline switches.
    pub toggles: Toggles,
    /// Zoom/pan of the 2D panes (shared by the panes on one grid).
    pub view2d: View2d,
    /// The 3D camera.
    pub camera: OrbitCamera,
    /// Draw the cloud in the 3D view.
    pub show_points: bool,
    /// Draw the textured mesh in the 3D view.
    pub show_mesh: bool,
    /// The value under the cursor (2D panes).
    pub probe: Option<Probe>,
    /// Note about the backend (e.g. why the GPU is not used).
    pub backend_note: String,
    /// The calibration page, when a calibration report is open.
    pub calib: Option<CalibPage>,
    /// The live page, when a sensor (or the simulator) is streaming.
    pub live: Option<LivePage>,
    /// The rig page, when a rig of several cameras is open.
    pub rig: Option<crate::rig_page::RigPage>,
    gpu: Option<fusion_gpu::FusionContext>,
    generation: u64,
    geometry: Option<Arc<Geometry3d>>,
    textures: HashMap<Pane, PaneTexture>,
    can_draw_3d: bool,
    home_camera: OrbitCamera,
}

/// A pane's uploaded texture: the data generation it shows, the handle, and its value range.
type PaneTexture = (u64, TextureHandle, Option<(f32, f32)>);

fn default_camera() -> OrbitCamera {
    OrbitCamera { target: [0.0, 0.0, 2.0], distance: 2.0, yaw: 0.0, pitch: 0.0 }
}

impl ViewerApp {
    fn empty(engine: Engine) -> Self {
        // Engine::Gpu falls back like Auto: the viewer can still show the frame, and the
        // title bar says why (see Engine::Gpu).
        let (gpu, backend_note) = match engine {
            Engine::Cpu => (None, "CPU fusion".to_string()),
            Engine::Gpu | Engine::Auto => match fusion_gpu::FusionContext::new() {
                Ok(ctx) => {
                    let note = format!("GPU fusion on {}", ctx.adapter_name());
                    (Some(ctx), note)
                }
                Err(e) => (None, format!("CPU fusion (no GPU: {e})")),
            },
        };
        Self {
            frame: None,
            fused: None,
            error: None,
            warnings: Vec::new(),
            page: Page::Images,
            pane: Pane::Color,
            toggles: Toggles::default(),
            view2d: View2d::default(),
            camera: default_camera(),
            show_points: false,
            show_mesh: true,
            probe: None,
            backend_note,
            calib: None,
            live: None,
            rig: None,
            gpu,
            generation: 0,
            geometry: None,
            textures: HashMap::new(),
            can_draw_3d: false,
            home_camera: default_camera(),
        }
    }

    /// True when the GPU backend was asked for but no adapter was found.
    pub fn gpu_missing(&self) -> bool {
        self.gpu.is_none() && self.backend_note.starts_with("CPU fusion (no GPU")
    }

    /// The app showing `frame`, fused with the default switches.
    pub fn with_frame(frame: Frame, engine: Engine) -> Self {
        let mut app = Self::empty(engine);
        app.frame = Some(Arc::new(frame));
        app.refuse();
        app.camera = app.fit_camera();
        app.home_camera = app.camera;
        app
    }

    /// The app on the bundled synthetic scene.
    pub fn demo(engine: Engine) -> Self {
        Self::with_frame(data::demo_frame(), engine)
    }

    /// The app on a `kfuse calibrate` output (report folder, rig file or camera file); a
    /// report that cannot be read gives an app showing the error.
    pub fn open_calibration(path: &Path) -> Self {
        let mut app = Self::empty(Engine::Cpu);
        app.page = Page::Calibration;
        match crate::calibration::open_calibration(path) {
            Ok(report) => app.calib = Some(CalibPage::new(report)),
            Err(e) => app.error = Some(e),
        }
        app
    }

    /// The app on a rig of several cameras (a version-2 rig file, or a folder with one as
    /// `rig.json` and perhaps the merged `cloud.ply`); an unreadable one gives the error.
    pub fn open_rig(path: &Path) -> Self {
        let mut app = Self::empty(Engine::Cpu);
        app.page = Page::Rig;
        match crate::rig_page::RigPage::open(path) {
            Ok(page) => app.rig = Some(page),
            Err(e) => app.error = Some(e),
        }
        app
    }

    /// The app on the live streams of `session`.
    pub fn live(page: LivePage) -> Self {
        let mut app = Self::empty(Engine::Cpu);
        app.page = Page::Live;
        app.live = Some(page);
        app
    }

    /// The pages this app can show, in tab order.
    pub fn pages(&self) -> Vec<Page> {
        let mut pages = Vec::new();
        if self.frame.is_some() {
            pages.extend(Page::ALL);
        }
        if self.calib.is_some() {
            pages.push(Page::Calibration);
        }
        if self.live.is_some() {
            pages.push(Page::Live);
        }
        if self.rig.is_some() {
            pages.push(Page::Rig);
        }
        pages
    }

    /// The app on a folder (or a calibration file): a `kfuse calibrate` output opens the
    /// calibration page, anything else is opened as a frame; a folder that cannot be opened
    /// gives an app showing the error.
    pub fn open(dir: &Path, engine: Engine) -> Self {
        Self::open_with(dir, engine, false)
    }

    /// [`ViewerApp::open`]; with `force` a frame whose rig fails the plausibility check is
    /// shown anyway, its problems in [`ViewerApp::warnings`] ([`data::open_folder_with`]).
    pub fn open_with(dir: &Path, engine: Engine, force: bool) -> Self {
        Self::open_shot(dir, engine, force, None)
    }

    /// [`ViewerApp::open_with`] on shot `shot` of a `kfuse capture` folder
    /// ([`data::open_folder_shot`]; `None`: the last one).
    pub fn open_shot(dir: &Path, engine: Engine, force: bool, shot: Option<&str>) -> Self {
        if shot.is_none() && crate::rig_page::is_multi_rig(dir) {
            return Self::open_rig(dir);
        }
        if shot.is_none() && (dir.is_file() || crate::calibration::is_calibration_folder(dir)) {
            return Self::open_calibration(dir);
        }
        match data::open_folder_shot(dir, force, shot) {
            Ok((frame, warnings)) => {
                let mut app = Self::with_frame(frame, engine);
                app.warnings = warnings;
                app
            }
            Err(e) => {
                let mut app = Self::empty(Engine::Cpu);
                app.error = Some(e);
                app
            }
        }
    }

    /// Call once the 3D renderer is installed ([`crate::render3d::install`]) for this app's
    /// egui-wgpu device.
    pub fn enable_3d(&mut self) {
        self.can_draw_3d = true;
    }

    /// Which engine produced the current result ([`Engine::Cpu`] or [`Engine::Gpu`]).
    pub fn engine(&self) -> Option<Engine> {
        self.fused.as_ref().map(|f| f.engine)
    }

    /// Changes the switches and re-runs the fusion when they differ.
    pub fn set_toggles(&mut self, toggles: Toggles) {
        if self.fused.as_ref().is_some_and(|f| f.toggles == toggles) {
            return;
        }
        self.toggles = toggles;
        self.refuse();
    }

    /// The geometry the 3D view draws (after the last fusion).
    pub fn geometry(&self) -> Option<&Arc<Geometry3d>> {
        self.geometry.as_ref()
    }

    /// Number of triangles the 3D view draws (0 when the mesh is hidden).
    pub fn drawn_triangles(&self) -> usize {
        if self.show_mesh { self.geometry.as_ref().map_or(0, |g| g.indices.len() / 3) } else { 0 }
    }

    /// Number of points the 3D view draws (0 when the cloud is hidden).
    pub fn drawn_points(&self) -> usize {
        if self.show_points { self.geometry.as_ref().map_or(0, |g| g.points.len()) } else { 0 }
    }

    fn refuse(&mut self) {
        let Some(frame) = self.frame.clone() else { return };
        match pipeline::fuse(&frame, self.toggles, self.gpu.as_mut()) {
            Ok(fused) => {
                self.generation += 1;
                let texture = Arc::new(frame.color.clone());
                self.geometry = Some(Arc::new(Geometry3d::new(
                    self.generation,
                    &fused.output.cloud,
                    &frame.rig.color_from_depth,
                    &fused.mesh,
                    texture,
                )));
                self.fused = Some(fused);
                self.error = None;
            }
            Err(e) => self.error = Some(e),
        }
    }

    fn fit_camera(&self) -> OrbitCamera {
        self.geometry
            .as_ref()
            .and_then(|g| {
                OrbitCamera::fit(
                    g.vertices.iter().map(|v| v.pos).chain(g.points.iter().map(|p| p.pos)),
                )
            })
            .unwrap_or_else(default_camera)
    }

    /// Puts the 3D camera back where it started.
    pub fn reset_camera(&mut self) {
        self.camera = self.home_camera;
    }

    /// Draws the whole viewer into `ui`.
    pub fn ui(&mut self, ui: &mut egui::Ui) {
        egui::Panel::top("kfuse-top").show(ui, |ui| {
            ui.horizontal(|ui| {
                ui.strong("kfuse view");
                ui.separator();
                for page in self.pages() {
                    ui.selectable_value(&mut self.page, page, page.label());
                }
                ui.separator();
                match (&self.frame, &self.calib, &self.live, &self.rig) {
                    (Some(f), _, _, _) => ui.label(format!("{} · {}", f.name, self.backend_note)),
                    (_, Some(c), _, _) => ui.label(c.report.source.display().to_string()),
                    (_, _, Some(l), _) => ui.label(l.title()),
                    (_, _, _, Some(r)) => ui.label(r.source.display().to_string()),
                    _ => ui.label("nothing open"),
                };
            });
        });
        if let Some(err) = &self.error {
            let msg = err.to_string();
            egui::Panel::top("kfuse-error").show(ui, |ui| {
                ui.colored_label(
                    Color32::from_rgb(230, 80, 80),
                    egui::RichText::new("Error").heading(),
                );
                ui.label(msg);
            });
        }
        if self.page == Page::Calibration
            && let Some(c) = self.calib.as_mut()
        {
            c.ui(ui);
            return;
        }
        if self.page == Page::Live
            && let Some(l) = self.live.as_mut()
        {
            l.ui(ui);
            return;
        }
        if self.page == Page::Rig
            && let Some(r) = self.rig.as_mut()
        {
            r.ui(ui);
            return;
        }
        if self.frame.is_none() || self.fused.is_none() {
            egui::CentralPanel::default().show(ui, |ui| {
                ui.label("Open a `kfuse fuse` output folder, a capture folder or a `kfuse calibrate` report: kfuse view DIR (or kfuse view --demo, kfuse view --backend sim).");
            });
            return;
        }
        match self.page {
            Page::Images => self.images_page(ui),
            Page::View3d => self.view3d_page(ui),
            Page::Summary => self.summary_page(ui),
            Page::Calibration | Page::Live | Page::Rig => {}
        }
    }

    fn images_page(&mut self, ui: &mut egui::Ui) {
        egui::Panel::left("kfuse-panes").resizable(false).show(ui, |ui| {
            ui.heading("Pane");
            for pane in Pane::ALL {
                if ui.selectable_label(self.pane == pane, pane.label()).clicked()
                    && self.pane != pane
                {
                    if pane.on_depth_grid() != self.pane.on_depth_grid() {
                        self.view2d = View2d::default();
                    }
                    self.pane = pane;
                }
            }
            ui.separator();
            if ui.button("Fit image").clicked() {
                self.view2d = View2d::default();
            }
            ui.label("Scroll: zoom · drag: pan");
        });
        egui::Panel::bottom("kfuse-probe").show(ui, |ui| {
            ui.label(match &self.probe {
                Some(p) => format!(
                    "pixel ({}, {})   depth {}   point {}",
                    p.pixel[0],
                    p.pixel[1],
                    p.depth_mm.map_or("—".to_string(), |d| format!("{d:.1} mm")),
                    p.point.map_or("—".to_string(), |q| format!(
                        "({:.3}, {:.3}, {:.3}) m",
                        q[0], q[1], q[2]
                    )),
                ),
                None => "move the cursor over the image".to_string(),
            });
        });
        egui::CentralPanel::default().show(ui, |ui| {
            let (Some(frame), Some(fused)) = (self.frame.clone(), self.fused.as_ref()) else {
                return;
            };
            if self.pane == Pane::Ir && frame.ir.is_none() {
                ui.label("This source has no IR image (a capture folder's ir.png).");
            }
            let pane = self.pane;
            let entry = self.textures.get(&pane).filter(|(g, _, _)| *g == self.generation);
            let (tex, legend) = match entry {
                Some((_, t, l)) => (t.clone(), *l),
                None => {
                    let (img, legend) = panes::render(pane, &frame, fused);
                    let bytes: Vec<u8> = img.data().iter().flatten().copied().collect();
                    let color = egui::ColorImage::from_rgb([img.width(), img.height()], &bytes);
                    let t = ui.ctx().load_texture(
                        format!("pane-{pane:?}"),
                        color,
                        TextureOptions::NEAREST,
                    );
                    self.textures.insert(pane, (self.generation, t.clone(), legend));
                    (t, legend)
                }
            };
            let size = [tex.size()[0], tex.size()[1]];
            let legend_h = if legend.is_some() { 28.0 } else { 0.0 };
            let avail = ui.available_rect_before_wrap();
            let rect =
                Rect::from_min_max(avail.min, Pos2::new(avail.max.x, avail.max.y - legend_h));
            let resp = ui.allocate_rect(rect, Sense::click_and_drag());
            self.view2d.handle_input(ui, &resp, rect, size);
            self.probe = resp.hover_pos().and_then(|pos| {
                let [x, y] = self.view2d.screen_to_pixel(rect, size, pos);
                panes::probe(pane, &frame, fused, x, y)
            });
            let painter = ui.painter_at(rect);
            painter.image(
                tex.id(),
                self.view2d.image_rect(rect, size),
                Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0)),
                Color32::WHITE,
            );
            if let Some((lo, hi)) = legend {
                let bar = Rect::from_min_max(
                    Pos2::new(rect.min.x + 70.0, rect.max.y + 6.0),
                    Pos2::new(rect.max.x - 70.0, rect.max.y + 22.0),
                );
                draw_legend(ui, bar, lo, hi);
            }
        });
    }

    fn view3d_page(&mut self, ui: &mut egui::Ui) {
        let mut t = self.toggles;
        egui::Panel::left("kfuse-3d-controls").resizable(false).show(ui, |ui| {
            ui.heading("Fusion");
            ui.label("Resampling (H3)");
            ui.radio_value(&mut t.resampling, Resampling::Nearest, "Nearest");
            ui.radio_value(&mut t.resampling, Resampling::Delaunay, "Delaunay");
            ui.label("Mesh (H4)");
            ui.radio_value(&mut t.mesh_grid, MeshGrid::Depth, "Depth grid (as fuse)");
            ui.radio_value(&mut t.mesh_grid, MeshGrid::Color, "H3 grid (handout)");
            ui.checkbox(&mut t.zbuffer, "Z-buffer (H7)");
            ui.checkbox(&mut t.remove_edges, "Remove edge faces (H5)");
            ui.add_enabled(
                t.remove_edges,
                egui::Slider::new(&mut t.stretch_ratio, 0.25..=4.0)
                    .logarithmic(true)
                    .text("edge threshold"),
            );
            ui.checkbox(&mut t.fill_holes, "Fill holes (H8)");
            depth_range_controls(ui, &mut t.depth_range);
            ui.separator();
            ui.heading("Show");
            ui.checkbox(&mut self.show_mesh, "Textured mesh");
            ui.checkbox(&mut self.show_points, "Point cloud");
            if ui.button("Reset view").clicked() {
                self.reset_camera();
            }
            ui.label("Drag: orbit · right-drag: pan · scroll: zoom");
            ui.separator();
            if let Some(f) = &self.fused {
                ui.label(format!(
                    "mesh: {} vertices, {} faces",
                    f.mesh.vertices.len(),
                    f.mesh.faces.len()
                ));
                ui.label(format!("cloud: {} points", f.output.cloud.len()));
                ui.label(format!("filled pixels: {}", f.filled_pixels));
                ui.label(format!(
                    "hole pixels: {}",
                    f.output.hole_mask.data().iter().filter(|&&m| m).count()
                ));
            }
        });
        // The slider is applied when released, so dragging it does not re-run the fusion per frame.
        let slider_busy = ui.ctx().dragged_id().is_some()
            && (t.stretch_ratio != self.toggles.stretch_ratio
                || t.depth_range != self.toggles.depth_range);
        if t != self.toggles && !slider_busy {
            self.set_toggles(t);
        } else if slider_busy {
            ui.ctx().request_repaint();
        }
        egui::CentralPanel::default().show(ui, |ui| {
            let rect = ui.available_rect_before_wrap();
            let resp = ui.allocate_rect(rect, Sense::click_and_drag());
            if resp.dragged_by(egui::PointerButton::Primary) && !ui.input(|i| i.modifiers.shift) {
                let d = resp.drag_delta();
                self.camera.orbit(d.x, d.y);
            } else if resp.dragged() {
                let d = resp.drag_delta();
                self.camera.pan(d.x, d.y, rect.height());
            }
            if resp.hovered() {
                let scroll = ui.input(|i| i.smooth_scroll_delta.y);
                if scroll != 0.0 {
                    self.camera.zoom(scroll);
                }
            }
            if resp.double_clicked() {
                self.reset_camera();
            }
            if !self.can_draw_3d {
                ui.painter().text(
                    rect.center(),
                    egui::Align2::CENTER_CENTER,
                    "the 3D view needs the wgpu renderer",
                    egui::FontId::proportional(16.0),
                    Color32::GRAY,
                );
                return;
            }
            let Some(geometry) = self.geometry.clone() else { return };
            let vp = self.camera.view_proj(rect.width() / rect.height().max(1.0));
            let params =
                DrawParams { view_proj: vp.into(), points: self.show_points, mesh: self.show_mesh };
            ui.painter().add(egui_wgpu::Callback::new_paint_callback(
                rect,
                View3dCallback { geometry, params, size_points: [rect.width(), rect.height()] },
            ));
        });
    }

    fn summary_page(&mut self, ui: &mut egui::Ui) {
        egui::CentralPanel::default().show(ui, |ui| {
            let Some(f) = &self.fused else { return };
            let s = &f.output.summary;
            ui.heading("Fusion summary");
            egui::Grid::new("kfuse-summary").striped(true).show(ui, |ui| {
                let mut row = |k: &str, v: String| {
                    ui.label(k);
                    ui.label(v);
                    ui.end_row();
                };
                row("depth image", format!("{}x{} ({:?})", s.depth_size[0], s.depth_size[1], s.depth_kind));
                row("colour image", format!("{}x{}", s.color_size[0], s.color_size[1]));
                row("valid depth pixels", s.valid_depth_pixels.to_string());
                row("cloud points (H1)", s.points.to_string());
                row("samples in colour view (H2)", s.samples_in_view.to_string());
                row("z-buffer pixels (H7)", s.zbuffer_pixels.to_string());
                row("sample spacing", format!("{:.2} px", s.sample_spacing_px));
                row("coverage radius", format!("{:.2} px", s.coverage_radius_px));
                row("nearest-filled pixels (H3)", s.nearest_pixels.to_string());
                row("hole pixels (H8)", s.hole_pixels.to_string());
                row("plane-filled pixels (H8)", f.filled_pixels.to_string());
                row("mesh vertices (H4)", f.mesh.vertices.len().to_string());
                row("faces before / after H5", format!("{} / {}", f.output.mesh.faces.len(), f.output.mesh_clean.faces.len()));
                row("colour-on-depth pixels (H6)", s.color_on_depth_pixels.to_string());
                if let Some(p) = &s.plane {
                    row(
                        "hole plane (RANSAC)",
                        format!(
                            "n = ({:.3}, {:.3}, {:.3}), offset {:.3} m, {} of {} inliers, rms {:.1} mm",
                            p.normal[0], p.normal[1], p.normal[2], p.offset, p.inliers, p.samples, p.rms_m * 1000.0
                        ),
                    );
                }
                row("backend", format!("{:?}", f.engine));
            });
        });
    }
}

/// A horizontal colour bar from `lo` to `hi` metres, labelled in millimetres.
fn draw_legend(ui: &egui::Ui, bar: Rect, lo: f32, hi: f32) {
    const STEPS: usize = 64;
    let painter = ui.painter();
    let w = bar.width() / STEPS as f32;
    for i in 0..STEPS {
        let c = panes::colormap((i as f32 + 0.5) / STEPS as f32);
        let r = Rect::from_min_size(
            Pos2::new(bar.min.x + i as f32 * w, bar.min.y),
            Vec2::new(w + 0.5, bar.height()),
        );
        painter.rect_filled(r, 0.0, Color32::from_rgb(c[0], c[1], c[2]));
    }
    painter.rect_stroke(bar, 0.0, Stroke::new(1.0, Color32::GRAY), egui::StrokeKind::Outside);
    let font = egui::FontId::proportional(12.0);
    let col = ui.visuals().text_color();
    painter.text(
        Pos2::new(bar.min.x - 6.0, bar.center().y),
        egui::Align2::RIGHT_CENTER,
        format!("{:.0} mm", lo * 1000.0),
        font.clone(),
        col,
    );
    painter.text(
        Pos2::new(bar.max.x + 6.0, bar.center().y),
        egui::Align2::LEFT_CENTER,
        format!("{:.0} mm", hi * 1000.0),
        font,
        col,
    );
}

impl eframe::App for ViewerApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        ViewerApp::ui(self, ui);
    }
}

/// The depth range sliders' span, metres: the Kinect v2 measures 0.5-4.5 m (8 m at most).
const DEPTH_SLIDER_M: std::ops::RangeInclusive<f32> = 0.0..=8.0;

/// The range a freshly switched-on clip starts with: the Kinect v2's specified 0.5-4.5 m.
const DEPTH_CLIP_START_M: (f32, f32) = (0.5, 4.5);

/// H1's depth range (`kfuse fuse --depth-range`): a switch and the near and far sliders.
fn depth_range_controls(ui: &mut egui::Ui, range: &mut geometry::fusion::DepthRange) {
    use geometry::fusion::DepthRange;
    let mut on = !range.is_all();
    ui.checkbox(&mut on, "Depth range (H1)");
    if !on {
        *range = DepthRange::ALL;
        return;
    }
    if range.is_all() {
        (range.min_m, range.max_m) = DEPTH_CLIP_START_M;
    }
    ui.add(egui::Slider::new(&mut range.min_m, DEPTH_SLIDER_M).text("near (m)"));
    ui.add(egui::Slider::new(&mut range.max_m, DEPTH_SLIDER_M).text("far (m)"));
    // The far end follows the near one past it (a range is MIN..MAX).
    range.max_m = range.max_m.max(range.min_m);
}
