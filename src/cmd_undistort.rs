//! `kfuse undistort`: removes lens distortion from images with a rig file's camera model.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use calib::rig_io::Role;
use calib::undistort::UndistortMap;
use indicatif::{ProgressBar, ProgressStyle};
use kfuse_io::atomic::StagedDir;
use kfuse_io::image_header::image_size;
use kfuse_io::images::{MILLIMETRES, read_color, read_depth, write_color_png, write_depth_png16};

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
    /// Output folder (created if missing). The outputs appear all together when every image
    /// is done, or not at all.
    #[arg(long)]
    out: PathBuf,
    /// Use a rig that fails the plausibility check (see README "Limits"), with a warning.
    #[arg(long)]
    force: bool,
}

/// `NAME_rect.png` for input `NAME.ext`.
fn output_name(path: &Path) -> String {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "image".into());
    format!("{stem}_rect.png")
}

/// Runs the command.
pub fn run(args: UndistortArgs) -> Result<()> {
    // A rig or the single-camera JSON that `kfuse calibrate --ir/--color --out` writes.
    let role = if args.camera == "color" { Role::Color } else { Role::Depth };
    let calibration = calib::rig_io::load(&args.rig)?;
    let cam = calibration.camera(role, &args.rig)?;
    let problems = calibration.plausibility_problems();
    if !problems.is_empty() {
        if !args.force {
            bail!(
                "{}: {} (pass --force if the rig really is meant this way)",
                args.rig.display(),
                problems.join("; ")
            );
        }
        for problem in problems {
            eprintln!("warning: {}: {problem} (--force)", args.rig.display());
        }
    }
    // Everything that can be checked is checked before the (large) map is built and before
    // anything is written: one output name per input, every image's size from its header.
    let mut names: HashMap<String, &PathBuf> = HashMap::new();
    for path in &args.images {
        let name = output_name(path);
        if let Some(first) = names.insert(name.clone(), path) {
            bail!(
                "{} and {} would both be written as {name}; undistort them into separate --out folders",
                first.display(),
                path.display()
            );
        }
        let size = image_size(path)?;
        if size != (cam.width, cam.height) {
            bail!(
                "{}: image is {}x{} but the rig's {} camera is {}x{}",
                path.display(),
                size.0,
                size.1,
                args.camera,
                cam.width,
                cam.height
            );
        }
    }
    let staged = StagedDir::new(&args.out)?;
    crate::interrupt::install()?;
    let map = UndistortMap::new(&cam);
    if let Some(r) = cam.distortion.fold_radius() {
        println!(
            "note: the {} model folds at undistorted radius {r:.3}; {:.2} % of the output is masked",
            args.camera,
            100.0 * map.masked_fraction()
        );
    }
    let pb = ProgressBar::new(args.images.len() as u64);
    pb.set_style(
        ProgressStyle::with_template("undistorting [{bar:30}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    for path in &args.images {
        let out = staged.join(output_name(path));
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
        crate::interrupt::check(": stopped; nothing was written to --out")?;
    }
    pb.finish();
    staged.commit()?;
    println!("wrote {} image(s) to {}", args.images.len(), args.out.display());
    Ok(())
}
