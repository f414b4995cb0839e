//! `kfuse demo`: renders the synthetic Kinect scene, writes it as ordinary input files and
//! fuses them — the whole pipeline on data with a known answer, no device needed.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use geometry::synth;
use kfuse_io::atomic::StagedDir;
use kfuse_io::{images, rig as rigio};

use crate::cmd_fuse::{self, DepthKindArg, FuseArgs, H5Arg, MeshFromArg, ResampleArg};

/// Render a synthetic Kinect v2 frame and fuse it.
#[derive(Args, Debug, Clone)]
#[command(after_help = "\
Examples:
  kfuse demo                 # writes kfuse-demo/input/ and kfuse-demo/fused/
  kfuse demo --out /tmp/d    # somewhere else
  kfuse demo --preset noisy  # Kinect noise growing with z² and flying pixels at edges

The scene: a tilted textured wall 2.2-4.8 m away with a box, a sphere and a cone at 1-1.7 m,
seen by a Kinect v2-like rig (512x424 depth with factory distortion, 1920x1080 colour, 52 mm
baseline), with Kinect-like depth noise (1.5 mm), range limit and dropouts.
input/ holds color.png, depth.png (16-bit mm, z) and rig.json; fused/ what `kfuse fuse` writes.
Re-run the fusion yourself with:
  kfuse fuse --rig kfuse-demo/input/rig.json --color kfuse-demo/input/color.png \\
             --depth kfuse-demo/input/depth.png --out kfuse-demo/fused")]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, short, value_name = "DIR", default_value = "kfuse-demo")]
    pub out: PathBuf,
    /// Do not draw the Task 1-8 figures.
    #[arg(long)]
    pub no_figures: bool,
    /// The scene's sensor: kinect (constant 1.5 mm noise) or noisy (noise 1.5 mm at 1 m
    /// growing with z², and flying pixels at depth edges, like a real Kinect v2 frame).
    #[arg(long, value_enum, default_value_t = DemoPreset::Kinect)]
    pub preset: DemoPreset,
}

/// `kfuse demo --preset`.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum DemoPreset {
    /// `geometry::synth::kinect_preset` with its constant noise.
    Kinect,
    /// `geometry::synth::kinect_noisy_preset`: z² noise and flying pixels.
    Noisy,
}

/// Runs `kfuse demo`.
pub fn run(args: &DemoArgs) -> Result<()> {
    eprintln!("rendering the synthetic Kinect v2 scene ...");
    let (setup, frame) = match args.preset {
        DemoPreset::Kinect => {
            let setup = synth::kinect_preset(true);
            let frame = synth::render(&setup);
            (setup, frame)
        }
        DemoPreset::Noisy => {
            let (setup, noise) = synth::kinect_noisy_preset();
            let noisy = synth::render_noisy(&setup, &noise);
            (setup, noisy.frame)
        }
    };
    let input_dir = args.out.join("input");
    let staged = StagedDir::new(&input_dir)?;
    images::write_color_png(&staged.join("color.png"), &frame.color)?;
    images::write_depth_png16(&staged.join("depth.png"), &frame.depth)?;
    rigio::write_rig(&staged.join("rig.json"), &setup.rig)?;
    let input_dir = staged.commit()?;
    println!(
        "inputs written to {}/ (color.png, depth.png = 16-bit mm, rig.json)",
        input_dir.display()
    );
    let fuse = FuseArgs {
        rig: Some(input_dir.join("rig.json")),
        color: Some(input_dir.join("color.png")),
        depth: Some(input_dir.join("depth.png")),
        depth_kind: match frame.depth_kind {
            geometry::DepthKind::Z => DepthKindArg::Z,
            geometry::DepthKind::Range => DepthKindArg::Range,
        },
        depth_scale: images::MILLIMETRES,
        mat: None,
        rectified: false,
        out: args.out.join("fused"),
        resample: ResampleArg::Both,
        mesh_from: MeshFromArg::DepthGrid,
        h5: H5Arg::SampleScale,
        stretch_ratio: geometry::fusion::FusionOptions::default().stretch_ratio,
        hole_radius: geometry::fusion::FusionOptions::default().hole_radius_factor,
        depth_range: None,
        no_figures: args.no_figures,
        engine: fusion_gpu::Engine::Cpu,
        gpu: None,
        force: false,
        timings: false,
        sensor: Vec::new(),
        view: None,
        shot: None,
        virtual_view: None,
        tsdf: false,
        voxel_size: None,
        truncation: None,
        sequence: Default::default(),
        live: false,
        sets: None,
        tolerance_ms: None,
        stale_after: None,
        wait: None,
        live_match_only: false,
        net: Default::default(),
    };
    let result =
        cmd_fuse::run(&fuse).map_err(|e| match e.downcast::<crate::interrupt::Interrupted>() {
            // Said from the demo's point of view: fuse's "--out left as it was" is about
            // `OUT/fused`, while the inputs in `OUT/input` were already written.
            Ok(_) => crate::interrupt::Interrupted(format!(
                ": stopped; the inputs are in {} and {} was not written",
                input_dir.display(),
                fuse.out.display()
            ))
            .into(),
            Err(e) => e,
        })?;
    cmd_fuse::report(&result);
    Ok(())
}
