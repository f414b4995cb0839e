//! `kfuse capture record --format rosbag2`: a recording written straight into a rosbag2 folder
//! with the topics of `kfuse fuse --recording … --layout rosbag2` (README "ROS 2 bags").
//!
//! Design: the sensor is recorded into a staged `.kfrec` (the same `record` as
//! `--format kfrec`, in a hidden staging folder beside `--out`), which is then converted by
//! `kfuse fuse --recording STAGED --layout rosbag2` itself, and removed. One writer makes
//! every bag, so the two commands' bags cannot drift apart: the decoder's depth and IR, the
//! registered depth, the JPEG as the scene is, camera_info of the rig fitted to the sensor's
//! factory parameters, `/tf_static`, `--points`, the host-time stamps (the staged file's
//! modification time is the host time of its last frame, `kfuse_sequence::host_time`), the
//! staged output folder committed only when whole. Encoding while recording would compete
//! with the USB stream for the cores (the raw stream must never wait for a decoder or zstd:
//! a late recorder loses packets); the price is the recording's disk space and the
//! conversion's time after the last frame (BENCHMARKS.md, "rosbag2"). When the
//! conversion fails or is interrupted, the raw recording is kept beside `--out` (`OUT.kfrec`)
//! and the message says how to convert it.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use clap::Parser;
use kfuse_io::atomic::StagedDir;

use super::CommonArgs;
use crate::cmd_fuse::FuseArgs;

/// `kfuse fuse`'s flags, parsed from the conversion's command line.
#[derive(Parser)]
struct Fuse {
    #[command(flatten)]
    args: FuseArgs,
}

/// Records `frames` depth frames of the sensor of `common` into the rosbag2 folder `output`
/// (module docs), with `sd/points` when `points`, and the USB trace `trace` asks for.
pub(super) fn record(
    output: &Path,
    frames: u64,
    overwrite: bool,
    points: bool,
    common: &CommonArgs,
    trace: super::usb_trace::TraceRequest,
) -> Result<()> {
    if output.is_file() {
        bail!(
            "--out {}: is a file; --format rosbag2 writes a folder (metadata.yaml + an .mcap file): give a folder name such as bag",
            output.display()
        );
    }
    if output.exists() && !overwrite {
        bail!("{} already exists; pass --overwrite to replace it", output.display());
    }
    let name = output
        .file_name()
        .and_then(|n| n.to_str())
        .filter(|n| kfuse_io::atomic::is_plain_name(n))
        .ok_or_else(|| {
            anyhow::anyhow!(
                "--out {}: give the bag folder a plain name (letters, digits, . _ -), which names its .mcap file",
                output.display()
            )
        })?;
    let parent = output.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).map_err(|e| {
        anyhow::anyhow!("--out {}: creating {}: {e}", output.display(), parent.display())
    })?;
    // The raw recording's own staging folder: removed when dropped (and by the next run after a
    // kill), so a finished bag leaves nothing else beside it.
    let raw = StagedDir::new(&parent.join(format!("{name}.raw")))?;
    let kfrec = raw.join(format!("{name}.kfrec"));
    let recorded = super::record(&kfrec, frames, true, common, trace);
    if !kfrec.is_file() {
        // Nothing recorded (no sensor, stopped before the first frame): record's own error.
        return recorded;
    }
    let kept = parent.join(format!("{name}.kfrec"));
    if let Err(e) = recorded {
        bail!("{e}{}", keep(&kfrec, &kept, output));
    }
    let mut argv: Vec<std::ffi::OsString> =
        ["fuse", "--layout", "rosbag2", "--recording"].into_iter().map(Into::into).collect();
    argv.push(kfrec.clone().into());
    argv.push("--out".into());
    argv.push(output.into());
    if points {
        argv.push("--points".into());
    }
    let fuse = Fuse::try_parse_from(argv)?;
    match crate::cmd_fuse::sequence::run(&fuse.args) {
        Ok(()) if crate::interrupt::requested() => {
            bail!("interrupted while writing the bag{}", keep(&kfrec, &kept, output))
        }
        Ok(()) => {
            eprintln!("rosbag2: {} (ros2 bag play {})", output.display(), output.display());
            Ok(())
        }
        Err(e) => bail!("{e}{}", keep(&kfrec, &kept, output)),
    }
}

/// Moves the staged recording to `kept` (unless a file is there) and says how to convert it.
fn keep(kfrec: &Path, kept: &Path, output: &Path) -> String {
    let at: PathBuf = if !kept.exists() && std::fs::rename(kfrec, kept).is_ok() {
        kept.to_path_buf()
    } else {
        return format!(
            "\nthe raw recording could not be kept ({} exists); nothing was written to {}",
            kept.display(),
            output.display()
        );
    };
    format!(
        "\nthe raw recording is kept in {}: convert it with kfuse fuse --recording {} --layout rosbag2 --out {}",
        at.display(),
        at.display(),
        output.display()
    )
}
