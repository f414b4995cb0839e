//! `kfuse`: Kinect v2 capture, calibration and RGB-D fusion. The CLI is a thin layer of `clap`
//! structs over the library crates.

mod cmd_demo;
mod cmd_fuse;
mod cmd_view;
mod figures;

use clap::{Parser, Subcommand};

mod cmd_calibrate;
mod cmd_capture;
mod cmd_rig;
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
    /// Fuse a depth frame with a colour frame: cloud, registered depth, meshes, holes, figures.
    Fuse(cmd_fuse::FuseArgs),
    /// Render a synthetic Kinect v2 frame, write it as input files and fuse it.
    Demo(cmd_demo::DemoArgs),
    /// Calibrate the colour and/or IR camera from checkerboard images (rig file + report).
    Calibrate(cmd_calibrate::CalibrateArgs),
    /// Import, export and show rig files (Bouguet, KinectData.mat, OpenCV, ROS, kinect_params.json).
    Rig(cmd_rig::RigArgs),
    /// Remove lens distortion from images with a rig file (writes *_rect images).
    Undistort(cmd_undistort::UndistortArgs),
    /// Open the viewer: 2D panes, 3D cloud and mesh, live fusion switches.
    View(cmd_view::ViewArgs),
    /// List connected Kinect v2 sensors.
    Devices(cmd_capture::DevicesArgs),
    /// Capture from a Kinect v2: calibration shots, scenes, raw recordings.
    Capture(cmd_capture::CaptureArgs),
}

fn main() -> std::process::ExitCode {
    match run(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // One line: the error and each cause not already spelled out by the one before.
            let mut message = e.to_string();
            for cause in e.chain().skip(1) {
                let cause = cause.to_string();
                if !message.contains(&cause) {
                    message = format!("{message}: {cause}");
                }
            }
            eprintln!("error: {message}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Calibrate(args) => cmd_calibrate::run(args)?,
        Command::Undistort(args) => cmd_undistort::run(args)?,
        Command::Rig(args) => cmd_rig::run(args)?,
        Command::Conventions => {
            println!("pixels: 0-based, integer coordinates are pixel centres");
            println!("frames: x right, y down, z forward; the depth camera is the reference");
            println!("poses: color_from_depth maps X_depth to X_color = R X_depth + T (metres)");
        }
        Command::Fuse(args) => {
            let result = cmd_fuse::run(&args)?;
            cmd_fuse::report(&result);
        }
        Command::Demo(args) => cmd_demo::run(&args)?,
        Command::View(args) => cmd_view::run(&args)?,
        Command::Devices(a) => cmd_capture::run_devices(a)?,
        Command::Capture(a) => cmd_capture::run_capture(a)?,
    }
    Ok(())
}
