//! Live mode: a Kinect v2 (or the simulated one) streaming on a background thread that feeds
//! the UI through a channel; `C` saves a calibration pair, `S` a scene, with the same files and
//! the same writer as `kfuse capture` (`kfuse_capture::ShotWriter`).
//!
//! The capture thread opens nothing itself: [`LiveSession::open`] opens and starts the device
//! (`kfuse_capture::Session`) on the caller's thread (so "no Kinect v2 found" is an ordinary
//! error), then moves it to the thread, whose `kfuse_capture::FramePump` decodes every depth
//! frame and keeps the newest colour JPEG; the thread sends one
//! [`LiveFrame`] per depth frame. When the UI lags, only the newest frame waits in the channel
//! (older ones are counted as not shown, never queued without bound). The thread ends when the
//! session is dropped (window closed), on unplug or on a stream error, with a message the page
//! shows. Frame rate is measured from the sensor's timestamps (0.125 ms units), not the wall
//! clock.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use egui::{Color32, Key, Pos2, Rect, TextureHandle, TextureOptions};
use geometry::Image;
use kfuse_capture::{
    CaptureError, DecoderOptions, FramePump, Pumped, SensorSource, Session, ShotKind, ShotWriter,
    shot_files, write_params_json,
};
use kinect_usb::device::{DeviceInfo, StreamCounters};
use kinect_usb::raw::{HEIGHT, WIDTH};

use crate::ViewerError;
use crate::panes;

/// How long one wait for a frame may block the capture thread, so that a closed window stops
/// it within this time.
pub const POLL: Duration = Duration::from_millis(100);
/// The simulator delivers frames as fast as they are asked for; the thread paces it to the
/// sensor's 30 Hz so the page behaves as with a real Kinect.
pub const SIM_FRAME_PERIOD: Duration = Duration::from_micros(33_333);
/// Depth colour-map range, metres: the Kinect v2's specified working range (0.5–4.5 m), fixed
/// so colours do not flicker from frame to frame.
pub const DEPTH_RANGE_M: (f32, f32) = (0.5, 4.5);
/// Frames over which the rate is measured: one second at 30 Hz.
pub const FPS_WINDOW: usize = 30;
/// Sensor timestamp units per second (0.125 ms).
const TICKS_PER_SECOND: f64 = 8000.0;

/// One depth frame with everything the page shows and saves.
#[derive(Clone)]
pub struct LiveFrame {
    /// Depth frames received since the stream started (1 for the first).
    pub number: u64,
    /// Sensor timestamp of the depth frame, 0.125 ms units.
    pub timestamp: u32,
    /// Decoded depth, millimetres, 512 × 424 upright, 0 = invalid.
    pub depth_mm: Arc<Vec<f32>>,
    /// Decoded IR amplitude, 512 × 424.
    pub ir: Arc<Vec<f32>>,
    /// The newest colour JPEG as the sensor sent it (`None` before the first colour frame).
    pub color_jpeg: Option<Arc<Vec<u8>>>,
    /// The colour image at half size for display.
    pub color_rgb: Option<Arc<Image<[u8; 3]>>>,
    /// Depth colour-mapped over [`DEPTH_RANGE_M`].
    pub depth_rgb: Arc<Image<[u8; 3]>>,
    /// IR as grey (square-root scaled over its 2nd–98th percentile).
    pub ir_rgb: Arc<Image<[u8; 3]>>,
    /// The driver's stream counters at this frame.
    pub counters: StreamCounters,
}

enum LiveEvent {
    Frame(Box<LiveFrame>),
    Stopped(String),
}

/// A streaming sensor and its capture thread. Dropping it stops the thread and closes the
/// device.
pub struct LiveSession {
    /// What the device reported when it started.
    pub info: DeviceInfo,
    /// "simulated Kinect v2" or "Kinect v2".
    pub name: String,
    rx: Option<Receiver<LiveEvent>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    repaint: Arc<Mutex<Option<egui::Context>>>,
}

impl LiveSession {
    /// Opens and starts the sensor of `source`, then streams on a background thread. The UI's
    /// context, once given to [`LiveSession::set_repaint`], is woken for every frame.
    pub fn open(source: &SensorSource) -> Result<Self, ViewerError> {
        let session = Session::open(source)?;
        let info = session.info().clone();
        let pump = FramePump::new(session.decoder(&DecoderOptions::default())?);
        let paced = source.needs_pacing();
        // Capacity 1: at most the newest frame waits for the UI.
        let (tx, rx) = mpsc::sync_channel(1);
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let repaint = Arc::new(Mutex::new(None));
        let repaint2 = repaint.clone();
        let thread = std::thread::Builder::new()
            .name("kfuse-live".into())
            .spawn(move || capture_loop(session, pump, tx, stop2, repaint2, paced))
            .map_err(|e| ViewerError::Device {
                message: format!("cannot start the capture thread: {e}"),
            })?;
        Ok(Self {
            info,
            name: source.name().to_string(),
            rx: Some(rx),
            stop,
            thread: Some(thread),
            repaint,
        })
    }

    /// The UI context to wake for every frame.
    pub fn set_repaint(&self, ctx: &egui::Context) {
        if let Ok(mut r) = self.repaint.lock()
            && r.is_none()
        {
            *r = Some(ctx.clone());
        }
    }

    /// True while the capture thread runs.
    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }
}

impl Drop for LiveSession {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        // Drop the receiver first so a thread blocked on sending wakes up with an error.
        self.rx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn half_size(rgb: &Image<[u8; 3]>) -> Image<[u8; 3]> {
    let (w, h) = (rgb.size().0 / 2, rgb.size().1 / 2);
    Image::from_fn(w, h, |x, y| {
        let mut acc = [0u32; 3];
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let p = *rgb.get(2 * x + dx, 2 * y + dy);
            for k in 0..3 {
                acc[k] += p[k] as u32;
            }
        }
        acc.map(|a| ((a + 2) / 4) as u8)
    })
}

fn ir_grey(ir: &[f32]) -> Image<[u8; 3]> {
    let (lo, hi) = panes::robust_range(ir.iter().copied()).unwrap_or((0.0, 1.0));
    let data = ir
        .iter()
        .map(|&a| {
            if a.is_finite() {
                [(((a - lo) / (hi - lo)).clamp(0.0, 1.0).sqrt() * 255.0) as u8; 3]
            } else {
                [0; 3]
            }
        })
        .collect();
    Image::from_vec(WIDTH, HEIGHT, data).unwrap_or_else(|_| Image::filled(WIDTH, HEIGHT, [0; 3]))
}

fn capture_loop(
    mut session: Session,
    mut pump: FramePump,
    tx: SyncSender<LiveEvent>,
    stop: Arc<AtomicBool>,
    repaint: Arc<Mutex<Option<egui::Context>>>,
    paced: bool,
) {
    let mut color_jpeg: Option<Arc<Vec<u8>>> = None;
    let mut color_rgb: Option<Arc<Image<[u8; 3]>>> = None;
    let mut pending: Option<LiveEvent> = None;
    let mut next_due = Instant::now();
    let wake = || {
        if let Ok(r) = repaint.lock()
            && let Some(c) = r.as_ref()
        {
            c.request_repaint();
        }
    };
    let end = loop {
        if stop.load(Ordering::Relaxed) {
            break None;
        }
        // Hand the waiting frame over if the UI took the previous one.
        if let Some(ev) = pending.take() {
            match tx.try_send(ev) {
                Ok(()) => wake(),
                Err(TrySendError::Full(ev)) => pending = Some(ev),
                Err(TrySendError::Disconnected(_)) => break None,
            }
        }
        match pump.pump(&mut session, POLL) {
            Ok(Some(Pumped::Depth { number, timestamp })) => {
                let (depth, ir) = (pump.depth_mm(), pump.ir());
                let frame = LiveFrame {
                    number,
                    timestamp,
                    depth_rgb: Arc::new(panes::depth_colors(
                        &Image::from_vec(WIDTH, HEIGHT, depth.iter().map(|&d| d * 1e-3).collect())
                            .unwrap_or_else(|_| Image::filled(WIDTH, HEIGHT, 0.0)),
                        DEPTH_RANGE_M,
                    )),
                    ir_rgb: Arc::new(ir_grey(ir)),
                    depth_mm: Arc::new(depth.to_vec()),
                    ir: Arc::new(ir.to_vec()),
                    color_jpeg: color_jpeg.clone(),
                    color_rgb: color_rgb.clone(),
                    counters: session.counters(),
                };
                // A newer frame replaces one the UI has not taken yet.
                pending = Some(LiveEvent::Frame(Box::new(frame)));
                if paced {
                    next_due += SIM_FRAME_PERIOD;
                    let now = Instant::now();
                    if next_due > now {
                        std::thread::sleep(next_due - now);
                    } else {
                        next_due = now;
                    }
                }
            }
            Ok(Some(Pumped::Color)) => {
                let jpeg = pump.color_jpeg().to_vec();
                // Shown as the scene is (the sensor streams it mirrored, kinect_usb::orientation);
                // a frame that does not decode is not shown (and a shot of it is refused).
                if let Ok(img) = kfuse_io::sensor_color::decode_mirrored(&jpeg) {
                    color_rgb = Some(Arc::new(half_size(&img)));
                }
                color_jpeg = Some(Arc::new(jpeg));
            }
            Ok(None) => {}
            Err(e) => break Some(stop_message(&e, pump.depth_frames())),
        }
    };
    session.close();
    // The last frame and the reason reach the UI unless it is gone (blocking sends: the UI
    // drains the channel, and a dropped receiver ends them with an error).
    if let Some(ev) = pending.take() {
        let _ = tx.send(ev);
    }
    if let Some(msg) = end {
        let _ = tx.send(LiveEvent::Stopped(msg));
    }
    wake();
}

/// What the page says when streaming stops after `number` depth frames.
fn stop_message(e: &CaptureError, number: u64) -> String {
    if e.is_disconnected() {
        format!(
            "the sensor was unplugged after {number} depth frames; the frames shown and the shots saved are intact. Reconnect it (USB 3 port, power) and start kfuse view again"
        )
    } else if e.is_end_of_stream() {
        format!("the stream ended after {number} depth frames")
    } else if let CaptureError::Decode(_) = e {
        e.to_string()
    } else {
        format!("streaming stopped after {number} depth frames: {e}")
    }
}

/// A save the page made, for its log.
#[derive(Debug, Clone, PartialEq)]
pub struct SavedShot {
    /// Calibration pair or scene.
    pub kind: ShotKind,
    /// The three files (colour, IR, depth).
    pub files: [PathBuf; 3],
    /// The depth frame number saved.
    pub frame: u64,
}

/// State of the live page.
pub struct LivePage {
    session: Option<LiveSession>,
    /// The device's identity.
    pub info: DeviceInfo,
    /// "simulated Kinect v2" or "Kinect v2".
    pub name: String,
    /// The newest frame received.
    pub latest: Option<LiveFrame>,
    /// Depth frames received by the capture thread (the newest frame's number).
    pub frames: u64,
    /// Frames the capture thread decoded that the UI never showed (it lagged).
    pub not_shown: u64,
    /// Why streaming stopped (unplug, error), once it has.
    pub stopped: Option<String>,
    /// Where shots go.
    pub out_dir: PathBuf,
    /// Shots saved so far.
    pub saved: Vec<SavedShot>,
    /// The last save error.
    pub save_error: Option<String>,
    writer: Option<ShotWriter>,
    timestamps: std::collections::VecDeque<u32>,
    textures: [Option<(u64, TextureHandle)>; 3],
}

impl LivePage {
    /// Opens the sensor and starts streaming; shots go to `out_dir`.
    pub fn open(source: &SensorSource, out_dir: &Path) -> Result<Self, ViewerError> {
        let session = LiveSession::open(source)?;
        Ok(Self {
            info: session.info.clone(),
            name: session.name.clone(),
            session: Some(session),
            latest: None,
            frames: 0,
            not_shown: 0,
            stopped: None,
            out_dir: out_dir.to_path_buf(),
            saved: Vec::new(),
            save_error: None,
            writer: None,
            timestamps: std::collections::VecDeque::new(),
            textures: [None, None, None],
        })
    }

    /// The title bar text.
    pub fn title(&self) -> String {
        format!("{} (serial {}, firmware {})", self.name, self.info.serial, self.info.firmware)
    }

    /// Takes what the capture thread sent; returns true when a new frame arrived.
    pub fn poll(&mut self) -> bool {
        let Some(rx) = self.session.as_ref().and_then(|s| s.rx.as_ref()) else { return false };
        let mut events = Vec::new();
        while let Ok(ev) = rx.try_recv() {
            events.push(ev);
        }
        let mut fresh = false;
        for ev in events {
            match ev {
                LiveEvent::Frame(f) => {
                    self.not_shown += f.number.saturating_sub(self.frames + 1);
                    self.frames = f.number;
                    if self.timestamps.len() == FPS_WINDOW {
                        self.timestamps.pop_front();
                    }
                    self.timestamps.push_back(f.timestamp);
                    self.latest = Some(*f);
                    fresh = true;
                }
                LiveEvent::Stopped(msg) => {
                    self.stopped = Some(msg);
                }
            }
        }
        if self.stopped.is_some() && self.session.as_ref().is_some_and(|s| !s.is_running()) {
            // The thread has ended; join it now.
            self.session = None;
        }
        fresh
    }

    /// Polls until the capture thread has stopped (unplug, end of stream) or `limit` passes (a
    /// guard against hanging, not a timing). Returns true when it stopped.
    pub fn wait_until_stopped(&mut self, limit: Duration) -> bool {
        let until = Instant::now() + limit;
        while Instant::now() < until {
            self.poll();
            if self.stopped.is_some() && self.session.is_none() {
                return true;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        false
    }

    /// True while the sensor streams.
    pub fn streaming(&self) -> bool {
        self.stopped.is_none() && self.session.is_some()
    }

    /// Frame rate from the sensor's timestamps over the last [`FPS_WINDOW`] frames.
    pub fn fps(&self) -> Option<f64> {
        let (first, last) = (self.timestamps.front()?, self.timestamps.back()?);
        let ticks = last.wrapping_sub(*first) as f64;
        (self.timestamps.len() > 1 && ticks > 0.0)
            .then(|| (self.timestamps.len() - 1) as f64 * TICKS_PER_SECOND / ticks)
    }

    fn next_name(&self, kind: ShotKind) -> String {
        // The first number whose files are all free: never overwrite earlier shots.
        (1..)
            .map(|i| match kind {
                ShotKind::Calib => format!("{i:04}"),
                ShotKind::Scene => format!("scene_{i:04}"),
            })
            .find(|n| shot_files(&self.out_dir, n, kind).iter().all(|p| !p.exists()))
            .unwrap_or_default()
    }

    /// Saves the newest frame as a calibration pair or a scene (the key presses `C` and `S`).
    pub fn save(&mut self, kind: ShotKind) -> Result<SavedShot, ViewerError> {
        let frame = self.latest.as_ref().ok_or_else(|| ViewerError::Device {
            message: "no frame yet: wait for the first depth frame".into(),
        })?;
        let jpeg = frame.color_jpeg.clone().ok_or_else(|| ViewerError::Device {
            message: "no colour frame yet: wait for the colour stream".into(),
        })?;
        let number = frame.number;
        let (ir, depth_mm) = (frame.ir.clone(), frame.depth_mm.clone());
        // The folder is created (and stale staging of killed captures removed) on first save.
        if self.writer.is_none() {
            self.writer = Some(ShotWriter::new(&self.out_dir)?);
        }
        if !self.out_dir.join("kinect_params.json").exists() {
            write_params_json(&self.out_dir, &self.info)?;
        }
        let files = shot_files(&self.out_dir, &self.next_name(kind), kind);
        if let Some(writer) = &self.writer {
            writer.write(&files, &jpeg, &ir, &depth_mm)?;
        }
        let shot = SavedShot { kind, files, frame: number };
        self.saved.push(shot.clone());
        Ok(shot)
    }

    fn texture(
        &mut self,
        ctx: &egui::Context,
        k: usize,
        img: &Image<[u8; 3]>,
        number: u64,
    ) -> TextureHandle {
        if let Some((n, t)) = &self.textures[k]
            && *n == number
        {
            return t.clone();
        }
        let bytes: Vec<u8> = img.data().iter().flatten().copied().collect();
        let color = egui::ColorImage::from_rgb([img.width(), img.height()], &bytes);
        let t = match self.textures[k].take() {
            Some((_, mut t)) => {
                t.set(color, TextureOptions::LINEAR);
                t
            }
            None => ctx.load_texture(format!("live-{k}"), color, TextureOptions::LINEAR),
        };
        self.textures[k] = Some((number, t.clone()));
        t
    }

    /// Draws the page (and handles `C` / `S`).
    pub fn ui(&mut self, ui: &mut egui::Ui) {
        if let Some(s) = &self.session {
            s.set_repaint(ui.ctx());
        }
        self.poll();
        let (c, s) = ui.input(|i| (i.key_pressed(Key::C), i.key_pressed(Key::S)));
        for (pressed, kind) in [(c, ShotKind::Calib), (s, ShotKind::Scene)] {
            if pressed {
                match self.save(kind) {
                    Ok(_) => self.save_error = None,
                    Err(e) => self.save_error = Some(e.to_string()),
                }
            }
        }
        egui::Panel::top("kfuse-live-status").show(ui, |ui| {
            ui.horizontal(|ui| {
                ui.strong(if self.streaming() { "LIVE" } else { "STOPPED" });
                ui.separator();
                ui.label(format!("frames: {}", self.frames));
                ui.separator();
                ui.label(match self.fps() {
                    Some(f) => format!("{f:.1} fps (sensor clock)"),
                    None => "— fps".to_string(),
                });
                ui.separator();
                let c = self.latest.as_ref().map(|f| f.counters).unwrap_or_default();
                ui.label(format!(
                    "dropped: depth {} (incomplete {}), colour {}, iso errors {}, not shown {}",
                    c.depth_dropped,
                    c.depth_incomplete,
                    c.color_dropped,
                    c.iso_errors,
                    self.not_shown
                ));
            });
            ui.label(format!(
                "C: save a calibration pair · S: save a scene · into {}",
                self.out_dir.display()
            ));
            if let Some(msg) = &self.stopped {
                ui.colored_label(Color32::from_rgb(230, 80, 80), msg);
            }
            if let Some(e) = &self.save_error {
                ui.colored_label(Color32::from_rgb(230, 80, 80), format!("not saved: {e}"));
            }
            if let Some(last) = self.saved.last() {
                let what = if last.kind == ShotKind::Calib { "calibration pair" } else { "scene" };
                let names: Vec<String> = last
                    .files
                    .iter()
                    .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
                    .collect();
                ui.label(format!(
                    "saved {} shot(s); last: {what} of frame {}: {}",
                    self.saved.len(),
                    last.frame,
                    names.join(", ")
                ));
            }
        });
        egui::CentralPanel::default().show(ui, |ui| {
            let Some(frame) = self.latest.clone() else {
                ui.label("waiting for the first frame ...");
                return;
            };
            let rect = ui.available_rect_before_wrap();
            // Colour on the left half; depth over IR on the right half.
            let half = rect.width() * 0.5;
            let left = Rect::from_min_max(rect.min, Pos2::new(rect.min.x + half - 4.0, rect.max.y));
            let right_top = Rect::from_min_max(
                Pos2::new(rect.min.x + half + 4.0, rect.min.y),
                Pos2::new(rect.max.x, rect.center().y - 4.0),
            );
            let right_bottom = Rect::from_min_max(
                Pos2::new(rect.min.x + half + 4.0, rect.center().y + 4.0),
                rect.max,
            );
            let panes = [
                (0, frame.color_rgb.clone(), left, "colour"),
                (1, Some(frame.depth_rgb.clone()), right_top, "depth (0.5–4.5 m)"),
                (2, Some(frame.ir_rgb.clone()), right_bottom, "IR"),
            ];
            for (k, img, area, label) in panes {
                let painter = ui.painter_at(area);
                match img {
                    Some(img) => {
                        let t = self.texture(ui.ctx(), k, &img, frame.number);
                        let fit = crate::view2d::View2d::default()
                            .image_rect(area, [img.width(), img.height()]);
                        painter.image(
                            t.id(),
                            fit,
                            Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0)),
                            Color32::WHITE,
                        );
                    }
                    None => {
                        painter.rect_filled(area, 0.0, Color32::from_gray(30));
                    }
                }
                painter.text(
                    area.min + egui::vec2(6.0, 6.0),
                    egui::Align2::LEFT_TOP,
                    label,
                    egui::FontId::proportional(14.0),
                    Color32::YELLOW,
                );
            }
        });
        if self.streaming() {
            // The capture thread wakes the UI per frame; this also catches the stop message.
            ui.ctx().request_repaint_after(Duration::from_millis(100));
        }
    }
}
