//! `kfuse replay-trace FILE`: replays a USB trace (`kfuse capture record --usb-trace`) through
//! the driver's protocol code and stream parsers and prints what they found.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use kinect_usb::KinectError;
use kinect_usb::device::StreamKind;
use kinect_usb::trace::{TraceEnd, replay_trace};

/// Arguments of `kfuse replay-trace`.
#[derive(Args, Debug)]
pub struct ReplayTraceArgs {
    /// The trace (`.kftrace`).
    #[arg(value_name = "FILE.kftrace")]
    trace: PathBuf,
    /// Also list every frame assembled: stream, sequence number, sensor timestamp.
    #[arg(long)]
    frames: bool,
}

/// Runs `kfuse replay-trace`.
pub fn run(args: &ReplayTraceArgs) -> Result<()> {
    let r = replay_trace(&args.trace).map_err(|e| match e {
        // A trace that cannot be read or is damaged: the error names the file and the fix.
        e @ (KinectError::File { .. } | KinectError::Trace { .. }) => anyhow::Error::new(e),
        // What the device code answered to the recorded replies, as it did live.
        e => anyhow::anyhow!(
            "{}: the traced capture failed and its replay fails the same way: {e}",
            args.trace.display()
        ),
    })?;
    let c = &r.counters;
    let kind = if r.payload { "with payloads" } else { "headers only" };
    println!("trace {}: {kind}", args.trace.display());
    println!("sensor: serial {}, firmware {}", r.info.serial, r.info.firmware);
    println!(
        "replayed {} USB calls and {} stream events ({} left out by the size bound)",
        r.calls, r.events, r.omitted
    );
    println!(
        "depth: {} frames assembled, {} lost, {} incomplete, {} packets with an error status",
        c.depth_frames, c.depth_dropped, c.depth_incomplete, c.iso_errors
    );
    println!(
        "colour: {} frames assembled, {} packets dropped, {} with another header magic",
        c.color_frames, c.color_dropped, c.color_bad_header_magic
    );
    for w in &r.warnings {
        println!("warning: {w}");
    }
    println!(
        "end: {}",
        match &r.end {
            TraceEnd::EndOfTrace => "the trace ends with the streams running".to_string(),
            TraceEnd::Disconnected => "the sensor disappeared during the capture".to_string(),
            TraceEnd::Stopped(e) => format!("a stream stopped: {e}"),
        }
    );
    if args.frames {
        for f in &r.frames {
            let k = if f.kind == StreamKind::Depth { "depth" } else { "colour" };
            println!("{k} {} {}", f.sequence, f.timestamp);
        }
    }
    Ok(())
}
