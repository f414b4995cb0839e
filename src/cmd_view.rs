//! `kfuse view`: the egui viewer on a `kfuse fuse` output folder, a capture folder or the
//! bundled synthetic scene.

use std::path::PathBuf;

use anyhow::{Result, anyhow, bail};
use clap::{Args, ValueEnum};
use viewer::{BackendChoice, ViewerApp};

/// Where the fusion runs.
#[derive(ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum FusionBackendArg {
    /// GPU (wgpu/Vulkan) when an adapter exists, else CPU.
    Auto,
    /// CPU pipeline.
    Cpu,
    /// GPU pipeline (falls back to the CPU with a note in the title bar when there is no adapter).
    Gpu,
}

/// Open the viewer.
#[derive(Args, Debug, Clone)]
#[command(after_help = "\
Examples:
  kfuse view --demo              # the synthetic Kinect v2 scene, fused in-process
  kfuse view kfuse-demo/fused    # a `kfuse fuse` output folder (re-fuses its inputs)
  kfuse view kfuse-demo/input    # a capture folder: rig.json, color.png, depth.png [, ir.png]
  kfuse view DIR --fusion cpu    # keep the GPU for the display only

Pages: 2D images (colour, depth + legend, IR, blend and checkerboard overlays, hole mask,
colour on depth; scroll = zoom, drag = pan, the status bar shows pixel, depth in mm and the
3D point), 3D view (drag = orbit, right-drag = pan, scroll = zoom; switches re-run the fusion:
nearest/Delaunay, z-buffer, edge-face removal and threshold, hole filling), Summary.
A folder with missing or corrupt files opens on an error panel naming the file.")]
pub struct ViewArgs {
    /// Folder to open (a `kfuse fuse` output or a capture folder).
    #[arg(value_name = "DIR", required_unless_present = "demo", conflicts_with = "demo")]
    pub dir: Option<PathBuf>,
    /// Open the bundled synthetic Kinect v2 scene instead of a folder.
    #[arg(long)]
    pub demo: bool,
    /// Where the fusion runs.
    #[arg(long, value_enum, default_value_t = FusionBackendArg::Auto)]
    pub fusion: FusionBackendArg,
}

/// Runs `kfuse view` (blocks until the window closes).
pub fn run(args: &ViewArgs) -> Result<()> {
    let backend = match args.fusion {
        FusionBackendArg::Auto => BackendChoice::Auto,
        FusionBackendArg::Cpu => BackendChoice::Cpu,
        FusionBackendArg::Gpu => BackendChoice::Gpu,
    };
    let app = match (&args.dir, args.demo) {
        (_, true) => {
            eprintln!("rendering and fusing the synthetic Kinect v2 scene ...");
            ViewerApp::demo(backend)
        }
        (Some(dir), false) => ViewerApp::open(dir, backend),
        (None, false) => bail!("give a folder or --demo (see kfuse view --help)"),
    };
    if let Some(e) = &app.error {
        // The window shows it too; say it on the terminal for scripts.
        eprintln!("error: {e}");
    }
    let options = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default().with_inner_size([1280.0, 800.0]).with_title("kfuse view"),
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
