//! `kfuse view`: the egui viewer on a `kfuse fuse` output folder, a capture folder or the
//! bundled synthetic scene.

use std::path::PathBuf;

use anyhow::{Result, anyhow, bail};
use clap::Args;
use kfuse_capture::SimOptions;
use viewer::live::LivePage;
use viewer::{Engine, ViewerApp};

use crate::cmd_capture::Backend;

/// Open the viewer.
#[derive(Args, Debug, Clone)]
#[command(after_help = "\
Examples:
  kfuse view --demo              # the synthetic Kinect v2 scene, fused in-process
  kfuse view kfuse-demo/fused    # a `kfuse fuse` output folder (re-fuses its inputs)
  kfuse view kfuse-demo/input    # a capture folder: rig.json, color.png, depth.png [, ir.png]
  kfuse view shots               # a `kfuse capture` folder: its last scene shot, rig from kinect_params.json
  kfuse view data/calib --shot 0002   # a named shot of a capture folder (scene NAME or calib NNNN)
  kfuse view DIR --engine cpu    # keep the GPU for the display only
  kfuse view calib/report        # a `kfuse calibrate --report` folder (or its rig.json)
  kfuse view rig3.json           # a rig of several cameras: every camera as a frustum
  kfuse view fused3              # ... and the merged cloud of a folder with rig.json + cloud.ply
  kfuse view --backend usb --out shots   # live mode on a connected Kinect v2
  kfuse view --backend sim       # live mode on the simulated Kinect v2

Pages: 2D images (colour, depth + legend, IR, blend and checkerboard overlays, hole mask,
colour on depth; scroll = zoom, drag = pan, the status bar shows pixel, depth in mm and the
3D point), 3D view (drag = orbit, right-drag = pan, scroll = zoom; switches re-run the fusion:
nearest/Delaunay, z-buffer, edge-face removal and threshold, hole filling), Summary.
Calibration: per-image RMS bars (rejected views marked), detected corners over each image,
residual vectors (scale shown), board poses around the cameras in 3D, parameters ±3σ.
Rig (a rig of several cameras, rig file version 2): each camera as a frustum in the reference
frame, coloured per sensor and named, with its centre in mm; the merged cloud (cloud.ply
beside rig.json, thinned to 40 000 points).
Live: colour, depth and IR as they stream, frame count, fps and drops; press C to save a
calibration pair (color_NNNN.jpg, ir_NNNN.png, depth_NNNN.png) and S to save a scene
(scene_NNNN_*) into --out, the files `kfuse capture` writes.
A folder with missing or corrupt files opens on an error panel naming the file.")]
pub struct ViewArgs {
    /// Folder to open (a `kfuse fuse` output or a capture folder).
    #[arg(value_name = "DIR", required_unless_present_any = ["demo", "backend"], conflicts_with_all = ["demo", "backend"])]
    pub dir: Option<PathBuf>,
    /// Open the bundled synthetic Kinect v2 scene instead of a folder.
    #[arg(long)]
    pub demo: bool,
    /// Where the fusion's per-pixel stages run: auto (the GPU when an adapter exists, else the
    /// CPU), cpu, or gpu (as auto, but the title bar says why when it falls back to the CPU).
    /// `--fusion` is the old spelling.
    #[arg(long, alias = "fusion", value_name = "ENGINE", default_value_t = Engine::Auto, value_parser = crate::cmd_fuse::parse_engine)]
    pub engine: Engine,
    /// Live mode: stream from a sensor (usb) or the simulated one (sim).
    #[arg(long, value_enum, conflicts_with = "demo")]
    pub backend: Option<Backend>,
    /// Live mode: folder for the shots saved with C and S.
    #[arg(long, default_value = "kfuse-live", requires = "backend")]
    pub out: PathBuf,
    /// Show a folder whose rig fails the plausibility check of `kfuse fuse` (focal lengths
    /// 50-20000 px, image sides up to 16384 px, baseline up to 0.5 m; see README "Limits"),
    /// with a warning per problem.
    #[arg(long, requires = "dir")]
    pub force: bool,
    /// In a `kfuse capture` folder, the shot to show: a scene's NAME (NAME_color.jpg,
    /// NAME_depth.png) or a calibration shot's number NNNN (color_NNNN.jpg, depth_NNNN.png).
    /// Default: the last scene shot, else the last calibration shot.
    #[arg(long, value_name = "NAME", requires = "dir")]
    pub shot: Option<String>,
    /// Simulated device: unplug after this many frame periods.
    #[arg(long, hide = true)]
    pub sim_unplug_after: Option<u64>,
}

/// Runs `kfuse view` (blocks until the window closes).
pub fn run(args: &ViewArgs) -> Result<()> {
    let engine = args.engine;
    if let Some(b) = args.backend {
        let source =
            b.source(SimOptions { unplug_after: args.sim_unplug_after, ..SimOptions::default() });
        // Open the sensor before the window: no sensor is a plain CLI error.
        let page = LivePage::open(&source, &args.out).map_err(|e| anyhow!("{e}"))?;
        eprintln!(
            "{}: streaming; press C (calibration pair) or S (scene) to save into {}",
            page.title(),
            args.out.display()
        );
        return run_window(ViewerApp::live(page));
    }
    let app = match (&args.dir, args.demo) {
        (_, true) => {
            eprintln!("rendering and fusing the synthetic Kinect v2 scene ...");
            ViewerApp::demo(engine)
        }
        (Some(dir), false) => ViewerApp::open_shot(dir, engine, args.force, args.shot.as_deref()),
        (None, false) => bail!("give a folder or --demo (see kfuse view --help)"),
    };
    for warning in &app.warnings {
        eprintln!("warning: {warning}");
    }
    if let Some(e) = &app.error {
        // The window shows it too; say it on the terminal for scripts.
        eprintln!("error: {e}");
    }
    run_window(app)
}

fn run_window(app: ViewerApp) -> Result<()> {
    let options = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_inner_size([1280.0, 800.0])
            .with_title("kfuse view"),
        renderer: eframe::Renderer::Wgpu,
        ..Default::default()
    };
    eframe::run_native(
        "kfuse view",
        options,
        Box::new(move |cc| {
            let mut app = app;
            if let Some(state) = &cc.wgpu_render_state {
                viewer::render3d::install(state);
                app.enable_3d();
            }
            Ok(Box::new(app))
        }),
    )
    .map_err(|e| anyhow!("could not open the viewer window: {e} (is a display available? DISPLAY / WAYLAND_DISPLAY)"))
}
