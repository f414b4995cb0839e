//! `kfuse undistort`: removes lens distortion from images with a rig file's camera model.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use calib::rig_io::Role;
use calib::undistort::UndistortMap;
use geometry::io::images::{
    MILLIMETRES, read_color, read_depth, write_color_png, write_depth_png16,
};
use indicatif::{ProgressBar, ProgressStyle};

/// Arguments of `kfuse undistort`.
#[derive(clap::Args, Debug)]
#[command(after_help = "EXAMPLES:
  kfuse undistort --rig rig.json --camera color caps/color_*.png --out rect/
  kfuse undistort --rig rig.json --camera depth caps/depth_*.png --out rect/

Writes NAME_rect.png per input. Colour and 8-bit IR images are resampled bilinearly; 16-bit
depth images (millimetres) by nearest neighbour, so no depth is ever blended across an edge.
Pixels whose ray falls where the distortion model folds (the lab's IR k1/k2 fold near the image
corners), or outside the input image, are masked: black, or depth 0 (no sample).")]
pub struct UndistortArgs {
    /// Rig file, or the single-camera file of `kfuse calibrate --ir … --out ir.json`.
    #[arg(long)]
    rig: PathBuf,
    /// Which camera took the images.
    #[arg(long, value_parser = ["color", "depth"])]
    camera: String,
    /// Images to undistort.
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// Output folder (created if missing).
    #[arg(long)]
    out: PathBuf,
}

/// Runs the command.
pub fn run(args: UndistortArgs) -> Result<()> {
    let role = if args.camera == "color" { Role::Color } else { Role::Depth };
    let cam = calib::rig_io::load(&args.rig)?.camera(role, &args.rig)?;
    let map = UndistortMap::new(&cam);
    if let Some(r) = cam.distortion.fold_radius() {
        println!(
            "note: the {} model folds at undistorted radius {r:.3}; {:.2} % of the output is masked",
            args.camera,
            100.0 * map.masked_fraction()
        );
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let pb = ProgressBar::new(args.images.len() as u64);
    pb.set_style(
        ProgressStyle::with_template("undistorting [{bar:30}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    for path in &args.images {
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "image".into());
        let out = args.out.join(format!("{stem}_rect.png"));
        let eight_bit = calib::io::is_8bit(path)?;
        if eight_bit {
            let img = read_color(path)?;
            if img.size() != (cam.width, cam.height) {
                bail!(
                    "{}: image is {}x{} but the rig's {} camera is {}x{}",
                    path.display(),
                    img.width(),
                    img.height(),
                    args.camera,
                    cam.width,
                    cam.height
                );
            }
            let (rect, _) = map.remap_bilinear(&img);
            write_color_png(&out, &rect)?;
        } else {
            let depth = read_depth(path, MILLIMETRES)?;
            if depth.size() != (cam.width, cam.height) {
                bail!(
                    "{}: image is {}x{} but the rig's {} camera is {}x{}",
                    path.display(),
                    depth.width(),
                    depth.height(),
                    args.camera,
                    cam.width,
                    cam.height
                );
            }
            let rect = map.remap_nearest(&depth, f32::NAN);
            write_depth_png16(&out, &rect)?;
        }
        pb.inc(1);
    }
    pb.finish();
    println!("wrote {} image(s) to {}", args.images.len(), args.out.display());
    Ok(())
}
