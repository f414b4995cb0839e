//! `kfuse`: Kinect v2 capture, calibration and RGB-D fusion. The CLI is a thin layer of `clap`
//! structs over the library crates.

use clap::{Parser, Subcommand};

mod cmd_calibrate;
mod cmd_undistort;

/// Kinect v2 capture, calibration and RGB-D fusion.
#[derive(Parser)]
#[command(name = "kfuse", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the camera conventions kfuse uses (pixels, frames, units).
    Conventions,
    /// Calibrate the colour and/or IR camera from checkerboard images (rig file + report).
    Calibrate(cmd_calibrate::CalibrateArgs),
    /// Remove lens distortion from images with a rig file (writes *_rect images).
    Undistort(cmd_undistort::UndistortArgs),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Calibrate(args) => cmd_calibrate::run(args)?,
        Command::Undistort(args) => cmd_undistort::run(args)?,
        Command::Conventions => {
            println!("pixels: 0-based, integer coordinates are pixel centres");
            println!("frames: x right, y down, z forward; the depth camera is the reference");
            println!("poses: color_from_depth maps X_depth to X_color = R X_depth + T (metres)");
        }
    }
    Ok(())
}
