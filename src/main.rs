//! `kfuse`: Kinect v2 capture, calibration and RGB-D fusion. The CLI is a thin layer of `clap`
//! structs over the library crates.

mod cmd_demo;
mod cmd_fuse;
mod cmd_view;
mod figures;

use clap::{Parser, Subcommand};

mod calibrate_report;
mod cmd_calibrate;
mod cmd_capture;
mod cmd_rig;
mod cmd_serve;
mod cmd_trace;
mod cmd_undistort;
mod interrupt;

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
    /// Fuse a depth frame with a colour frame (cloud, registered depth, meshes, holes, figures),
    /// or every frame of a recording or frame folder (registered depth, TUM RGB-D export).
    Fuse(cmd_fuse::FuseArgs),
    /// Render a synthetic Kinect v2 frame, write it as input files and fuse it.
    Demo(cmd_demo::DemoArgs),
    /// Calibrate the colour and/or IR camera from checkerboard images (rig file + report).
    Calibrate(cmd_calibrate::CalibrateArgs),
    /// Import, export and show rig files (Bouguet, KinectData.mat, OpenCV, ROS, iai_kinect2, kinect_params.json).
    Rig(cmd_rig::RigArgs),
    /// Remove lens distortion from images with a rig file (writes *_rect images).
    Undistort(cmd_undistort::UndistortArgs),
    /// Open the viewer: 2D panes, 3D cloud and mesh, live fusion switches.
    View(cmd_view::ViewArgs),
    /// List connected Kinect v2 sensors.
    Devices(cmd_capture::DevicesArgs),
    /// Capture from a Kinect v2: calibration shots, scenes, raw recordings.
    Capture(cmd_capture::CaptureArgs),
    /// Publish one Kinect v2 over Zenoh (ROS 2 topics via rmw_zenoh's keys) for `kfuse fuse --live`.
    Serve(cmd_serve::ServeArgs),
    /// Replay a USB trace (`kfuse capture record --usb-trace FILE`) through the driver's
    /// protocol code and stream parsers and print what they found.
    #[command(after_help = "Examples:\n  \
        kfuse capture record --out bug.kfrec --frames 30 --usb-trace bug.kftrace\n  \
        kfuse replay-trace bug.kftrace            # sensor, calls, frames, counters, how it ended\n  \
        kfuse replay-trace bug.kftrace --frames   # plus one line per frame: stream sequence timestamp\n\n\
        The replay answers kfuse's own start sequence from the trace (a trace of another kfuse version\n\
        whose commands differ is refused, naming the first call that differs) and feeds the recorded\n\
        transfers to the same frame parsers as a live sensor: `lost`, `incomplete` and the error\n\
        counts are what the capture's parsers saw. A start that failed replays to the same error\n\
        (exit status 1); a damaged or unfinished trace is refused with one line.")]
    ReplayTrace(cmd_trace::ReplayTraceArgs),
}

/// Exit status when standard output is closed before kfuse is done writing to it (`kfuse
/// calibrate … | head`): 128 + SIGPIPE (13), what a shell reports for a program that the
/// broken pipe stopped, as it stops `cat` or `grep`.
const BROKEN_PIPE_EXIT: i32 = 141;

/// Rust ignores SIGPIPE, so `println!` to a closed pipe panics with a stack trace; a reader
/// that stopped reading is no error of kfuse's: stop quietly with [`BROKEN_PIPE_EXIT`] instead.
/// Every other panic keeps the default report.
fn stop_quietly_on_broken_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let text = info.to_string();
        if text.contains("failed printing to stdout") && text.contains("Broken pipe") {
            std::process::exit(BROKEN_PIPE_EXIT);
        }
        default(info);
    }));
}

fn main() -> std::process::ExitCode {
    stop_quietly_on_broken_pipe();
    match run(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            let code = if e.downcast_ref::<interrupt::Interrupted>().is_some() {
                std::process::ExitCode::from(interrupt::INTERRUPTED_EXIT_CODE)
            } else {
                std::process::ExitCode::FAILURE
            };
            // One line: the error and each cause not already spelled out by the one before.
            let mut message = e.to_string();
            for cause in e.chain().skip(1) {
                let cause = cause.to_string();
                if !message.contains(&cause) {
                    message = format!("{message}: {cause}");
                }
            }
            eprintln!("error: {message}");
            code
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
        Command::Fuse(args) if args.live => cmd_fuse::live::run(&args)?,
        Command::Fuse(args) if cmd_fuse::multi::is_multi(&args) => {
            cmd_fuse::multi::run(&args)?;
        }
        Command::Fuse(args) if args.is_sequence() => cmd_fuse::sequence::run(&args)?,
        Command::Fuse(args) => {
            let result = cmd_fuse::run(&args)?;
            cmd_fuse::report(&result);
        }
        Command::Demo(args) => cmd_demo::run(&args)?,
        Command::View(args) => cmd_view::run(&args)?,
        Command::Devices(a) => cmd_capture::run_devices(a)?,
        Command::Capture(a) => cmd_capture::run_capture(a)?,
        Command::Serve(a) => cmd_serve::run(a)?,
        Command::ReplayTrace(a) => cmd_trace::run(&a)?,
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusion_gpu::Engine;

    fn parse(args: &[&str]) -> Result<Cli, clap::Error> {
        Cli::try_parse_from(std::iter::once("kfuse").chain(args.iter().copied()))
    }

    fn fuse_engine(extra: &[&str]) -> Result<Engine, clap::Error> {
        let mut args = vec!["fuse", "--mat", "in.mat", "--out", "o"];
        args.extend_from_slice(extra);
        match parse(&args)?.command {
            Command::Fuse(a) => Ok(a.engine()),
            _ => unreachable!("parsed as fuse"),
        }
    }

    fn view_engine(extra: &[&str]) -> Result<Engine, clap::Error> {
        let mut args = vec!["view", "--demo"];
        args.extend_from_slice(extra);
        match parse(&args)?.command {
            Command::View(a) => Ok(a.engine),
            _ => unreachable!("parsed as view"),
        }
    }

    #[test]
    fn engine_flag_and_its_old_spellings_select_the_same_engines() {
        // --engine on both commands, with each command's default.
        assert_eq!(fuse_engine(&[]).unwrap(), Engine::Cpu);
        assert_eq!(view_engine(&[]).unwrap(), Engine::Auto);
        for e in Engine::ALL {
            assert_eq!(fuse_engine(&["--engine", e.name()]).unwrap(), e);
            assert_eq!(view_engine(&["--engine", e.name()]).unwrap(), e);
            // view --fusion is the old spelling of --engine.
            assert_eq!(view_engine(&["--fusion", e.name()]).unwrap(), e);
        }
        // fuse --gpu / --gpu auto are the old spellings of --engine gpu / auto.
        assert_eq!(fuse_engine(&["--gpu"]).unwrap(), Engine::Gpu);
        assert_eq!(fuse_engine(&["--gpu", "auto"]).unwrap(), Engine::Auto);
        // Contradictions and unknown names are refused with the accepted values.
        assert!(fuse_engine(&["--engine", "cpu", "--gpu"]).is_err());
        let e = fuse_engine(&["--engine", "tpu"]).unwrap_err().to_string();
        assert!(e.contains("cpu, gpu or auto"), "{e}");
        assert!(fuse_engine(&["--gpu", "cpu"]).is_err());
    }
}
