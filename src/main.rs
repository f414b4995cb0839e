//! `kfuse`: Kinect v2 capture, calibration and RGB-D fusion. The CLI is a thin layer of `clap`
//! structs over the library crates.

use clap::{Parser, Subcommand};

mod cmd_capture;

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
    /// List connected Kinect v2 sensors.
    Devices(cmd_capture::DevicesArgs),
    /// Capture from a Kinect v2: calibration shots, scenes, raw recordings.
    Capture(cmd_capture::CaptureArgs),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Conventions => {
            println!("pixels: 0-based, integer coordinates are pixel centres");
            println!("frames: x right, y down, z forward; the depth camera is the reference");
            println!("poses: color_from_depth maps X_depth to X_color = R X_depth + T (metres)");
        }
        Command::Devices(a) => cmd_capture::run_devices(a)?,
        Command::Capture(a) => cmd_capture::run_capture(a)?,
    }
    Ok(())
}
