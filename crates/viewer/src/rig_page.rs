//! The rig page: every camera of a rig of several cameras (`kfuse calibrate --camera …`, rig
//! file version 2) as a frustum in the rig's reference frame, coloured per sensor and named,
//! and the merged cloud of `kfuse fuse` with several sensors (`cloud.ply` beside the rig)
//! when there is one, or the surface of its volumetric fusion (`tsdf_cloud.ply` of `--tsdf`,
//! the marching-cubes mesh's vertices with their colours; shown instead of the merged cloud
//! when the folder has it, a checkbox switches). Everything is in the **reference camera's
//! frame** (metres).
//!
//! Opened by `kfuse view RIG.json` on a version-2 rig file, or `kfuse view DIR` on a folder
//! whose `rig.json` is one.

use std::path::{Path, PathBuf};

use egui::{Color32, Stroke};
use geometry::MultiRig;
use nalgebra::Vector3;

use crate::camera3d::OrbitCamera;
use crate::canvas3d::Canvas3d;
use crate::error::ViewerError;

/// Most cloud points drawn, 40 000: the painter draws each as a small square, and at this
/// count a frame stays under ~10 ms on lavapipe; a merged cloud of three Kinects (~500 000
/// points) is thinned by keeping every k-th point (`kfuse_io::ply::read_cloud_ply`).
pub const MAX_DRAWN_POINTS: usize = 40_000;

/// Frustum depth as a fraction of the rig's size (the largest distance of a camera from the
/// reference), with [`MIN_FRUSTUM_DEPTH_M`] as the floor: a ring of Kinects 2 m across gets
/// 0.3 m pyramids, visible without hiding each other.
pub const FRUSTUM_FRACTION: f64 = 0.15;
/// Shortest frustum depth, metres: the calibration page's (one Kinect's pair 52 mm apart).
pub const MIN_FRUSTUM_DEPTH_M: f64 = 0.15;

/// Colours of the sensors, in the order the rig lists them (cameras of no sensor: grey).
const SENSOR_COLOURS: [Color32; 6] = [
    Color32::from_rgb(240, 200, 60),
    Color32::from_rgb(90, 200, 250),
    Color32::from_rgb(230, 120, 230),
    Color32::from_rgb(120, 220, 120),
    Color32::from_rgb(250, 140, 90),
    Color32::from_rgb(170, 150, 250),
];

/// One camera as drawn: its name, its sensor's colour, its optical centre and its image
/// corners at the frustum depth (reference frame, metres).
pub type DrawnCamera = (String, Color32, Vector3<f64>, [Vector3<f64>; 4]);

/// The state of the rig page.
pub struct RigPage {
    /// The rig shown.
    pub rig: MultiRig,
    /// The rig file.
    pub source: PathBuf,
    /// The merged cloud (thinned to [`MAX_DRAWN_POINTS`]), empty when the folder has none.
    pub cloud: geometry::PointCloud,
    /// The cloud's file, when there is one.
    pub cloud_source: Option<PathBuf>,
    /// The TSDF surface of `kfuse fuse --tsdf` (`tsdf_cloud.ply`, thinned to
    /// [`MAX_DRAWN_POINTS`]), empty when the folder has none.
    pub surface: geometry::PointCloud,
    /// The surface's file, when there is one.
    pub surface_source: Option<PathBuf>,
    /// Draw the TSDF surface instead of the merged cloud (on when the folder has one).
    pub show_surface: bool,
    orbit: OrbitCamera,
    home: OrbitCamera,
}

/// True when `path` is a version-2 rig file, or a folder whose `rig.json` is one.
pub fn is_multi_rig(path: &Path) -> bool {
    let file = if path.is_dir() { path.join("rig.json") } else { path.to_path_buf() };
    kfuse_io::rig::read_rig(&file).is_ok_and(|r| r.into_multi().is_some())
}

impl RigPage {
    /// Opens a version-2 rig file, or a folder with one as `rig.json` (and, if it is there,
    /// `cloud.ply`: the merged cloud).
    pub fn open(path: &Path) -> Result<Self, ViewerError> {
        let (file, folder) = if path.is_dir() {
            (path.join("rig.json"), Some(path.to_path_buf()))
        } else {
            (path.to_path_buf(), None)
        };
        let rig = kfuse_io::rig::read_rig(&file)
            .map_err(|e| ViewerError::Rig(e.to_string()))?
            .into_multi()
            .ok_or_else(|| {
                ViewerError::Rig(format!(
                    "{}: not a rig of several cameras (version 2); open a two-camera rig's folder or report instead",
                    file.display()
                ))
            })?;
        let read = |name: &str| -> Result<_, ViewerError> {
            let source = folder.as_ref().map(|f| f.join(name)).filter(|p| p.is_file());
            let cloud = match &source {
                Some(p) => kfuse_io::ply::read_cloud_ply(p, Some(MAX_DRAWN_POINTS))
                    .map_err(|e| ViewerError::Rig(e.to_string()))?,
                None => geometry::PointCloud::default(),
            };
            Ok((cloud, source))
        };
        let (cloud, cloud_source) = read("cloud.ply")?;
        let (surface, surface_source) = read("tsdf_cloud.ply")?;
        let show_surface = surface_source.is_some();
        let home = Self::home_orbit(&rig, if show_surface { &surface } else { &cloud });
        Ok(Self {
            rig,
            source: file,
            cloud,
            cloud_source,
            surface,
            surface_source,
            show_surface,
            orbit: home,
            home,
        })
    }

    /// The points drawn: the TSDF surface when [`RigPage::show_surface`] (and the folder has
    /// one), else the merged cloud.
    pub fn drawn_points(&self) -> &geometry::PointCloud {
        if self.show_surface && self.surface_source.is_some() { &self.surface } else { &self.cloud }
    }

    /// The rig's size: the largest distance of a camera centre from the reference, metres.
    pub fn extent_m(&self) -> f64 {
        rig_extent(&self.rig)
    }

    /// Each camera's name, sensor colour and frustum (centre, four image corners at the
    /// page's frustum depth) in the reference frame.
    pub fn frusta(&self) -> Vec<DrawnCamera> {
        let depth = (FRUSTUM_FRACTION * self.extent_m()).max(MIN_FRUSTUM_DEPTH_M);
        let sensors = self.rig.sensors();
        self.rig
            .cameras
            .iter()
            .map(|c| {
                let colour = c
                    .sensor
                    .as_deref()
                    .and_then(|s| sensors.iter().position(|x| *x == s))
                    .map_or(Color32::GRAY, |i| SENSOR_COLOURS[i % SENSOR_COLOURS.len()]);
                let (centre, corners) =
                    crate::camera3d::frustum(&c.model, &c.camera_from_reference.inverse(), depth);
                (c.name.clone(), colour, centre, corners)
            })
            .collect()
    }

    /// Seen from behind and above the reference camera, far enough back to hold every camera
    /// centre and cloud point.
    fn home_orbit(rig: &MultiRig, cloud: &geometry::PointCloud) -> OrbitCamera {
        let centres = rig.cameras.iter().map(|c| c.camera_from_reference.inverse().translation);
        let points =
            cloud.points.iter().map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64));
        let all: Vec<Vector3<f64>> = centres.chain(points).collect();
        let n = all.len().max(1) as f64;
        let mean = all.iter().fold(Vector3::zeros(), |a, p| a + p) / n;
        let radius = all.iter().map(|p| (p - mean).norm()).fold(0.0, f64::max).max(0.5);
        OrbitCamera {
            target: [mean.x as f32, mean.y as f32, mean.z as f32],
            // The field of view is 54° vertically: 2.2 radii away holds a sphere of the radius.
            distance: (2.2 * radius) as f32,
            yaw: 0.0,
            pitch: 0.5,
        }
    }

    /// Draws the page.
    pub fn ui(&mut self, ui: &mut egui::Ui) {
        egui::Panel::left("kfuse-rig-cameras").resizable(false).show(ui, |ui| {
            ui.heading("Cameras");
            ui.label(format!("reference: {}", self.rig.reference));
            for (name, colour, centre, _) in self.frusta() {
                // Rounded to mm; "-0" for a rounding residue reads as a sign error.
                let mm = |x: f64| {
                    let r = (x * 1e3).round();
                    if r == 0.0 { 0.0 } else { r }
                };
                ui.colored_label(
                    colour,
                    format!("{name}  ({}, {}, {}) mm", mm(centre.x), mm(centre.y), mm(centre.z)),
                );
            }
            ui.separator();
            match &self.cloud_source {
                Some(p) => ui.label(format!(
                    "merged cloud: {} points shown ({})",
                    self.cloud.len(),
                    p.file_name().map(|f| f.to_string_lossy()).unwrap_or_default()
                )),
                None => ui.label("no cloud.ply beside the rig"),
            };
            if let Some(p) = &self.surface_source {
                let name = p.file_name().map(|f| f.to_string_lossy()).unwrap_or_default();
                ui.checkbox(
                    &mut self.show_surface,
                    format!("TSDF surface instead: {} points ({name})", self.surface.len()),
                );
            }
        });
        egui::CentralPanel::default().show(ui, |ui| {
            ui.horizontal(|ui| {
                ui.label("The rig's cameras in the reference frame, metres. Drag: orbit · right-drag: pan · scroll: zoom");
                if ui.button("Reset view").clicked() {
                    self.orbit = self.home;
                }
            });
            let canvas = Canvas3d::new(ui, &mut self.orbit);
            let painter = ui.painter_at(canvas.rect);
            let drawn = self.drawn_points();
            for (i, p) in drawn.points.iter().enumerate() {
                let Some(at) =
                    canvas.project(Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
                else {
                    continue;
                };
                let c = drawn.colors.get(i).copied().unwrap_or([200, 200, 200]);
                painter.rect_filled(
                    egui::Rect::from_center_size(at, egui::vec2(2.0, 2.0)),
                    0.0,
                    Color32::from_rgb(c[0], c[1], c[2]),
                );
            }
            let o = Vector3::zeros();
            let axis_len = (0.1 * self.extent_m()).max(0.1);
            for (axis, c) in [
                (Vector3::x(), Color32::RED),
                (Vector3::y(), Color32::GREEN),
                (Vector3::z(), Color32::from_rgb(80, 120, 255)),
            ] {
                canvas.line(&painter, o, axis * axis_len, Stroke::new(2.0, c));
            }
            for (name, colour, centre, corners) in self.frusta() {
                for k in 0..4 {
                    canvas.line(&painter, centre, corners[k], Stroke::new(1.5, colour));
                    canvas.line(&painter, corners[k], corners[(k + 1) % 4], Stroke::new(1.5, colour));
                }
                // Depth cameras named above their top-left corner, the others below their
                // bottom-left one: a Kinect's two frusta nearly coincide.
                let (corner, align) = if name.ends_with("depth") {
                    (corners[0], egui::Align2::RIGHT_BOTTOM)
                } else {
                    (corners[3], egui::Align2::RIGHT_TOP)
                };
                if let Some(p) = canvas.project(corner) {
                    painter.text(
                        p,
                        align,
                        name,
                        egui::FontId::proportional(13.0),
                        colour,
                    );
                }
            }
        });
    }
}

/// The largest distance of a camera centre from the reference, metres.
pub fn rig_extent(rig: &MultiRig) -> f64 {
    rig.cameras
        .iter()
        .map(|c| c.camera_from_reference.inverse().translation.norm())
        .fold(0.0, f64::max)
}
