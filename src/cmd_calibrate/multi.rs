//! `kfuse calibrate --camera NAME=GLOB ... | --shots DIR`: joint calibration of N cameras
//! (issue 32). The run is `calib::pipeline::joint` (detection per camera, `calibrate_multi`,
//! report.json with every camera's corners); this is its arguments, the output checks, the
//! printed table and the writing (a version-2 rig through `kfuse_io::rig::write_multi_rig`,
//! `--report DIR/report.json`).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use calib::multi::input::{
    CameraFiles, camera_files, check_distinct_names, parse_camera_arg, shots_folder,
};
use calib::multi::report::REPORT_FORMAT;
use calib::multi::{CameraViews, MultiCalibration};
use calib::pipeline::joint::{JointRequest, run_joint};
use calib::pipeline::{expand, parse_board};
use kfuse_io::atomic::StagedDir;

use super::outputs::resolved_output;
use super::{CalibrateArgs, STOPPED, flags};

/// The options of the one- and two-camera runs that a joint calibration does not take, with
/// what to do instead.
fn check_args(args: &CalibrateArgs) -> Result<()> {
    let conflicts = [
        ("--ir", !args.ir.is_empty()),
        ("--color", !args.color.is_empty()),
        ("--depth", !args.depth.is_empty()),
        ("--rig", args.rig.is_some()),
        ("--opencv-yaml", args.opencv_yaml.is_some()),
        ("--fix-intrinsics", args.fix_intrinsics),
        ("--allow-unpaired", args.allow_unpaired),
        ("--force", args.force),
    ];
    if let Some((flag, _)) = conflicts.iter().find(|c| c.1) {
        bail!(
            "{flag} is an option of the one- and two-camera calibration; with --camera/--shots give every camera as --camera NAME=GLOB (a Kinect's IR images as SERIAL.depth, its colour images as SERIAL.color)"
        );
    }
    if args.camera.is_empty() && args.shots.is_none() {
        bail!(
            "--reference names the reference camera of a joint calibration: give the cameras with --camera NAME=GLOB or --shots DIR"
        );
    }
    Ok(())
}

/// The cameras of `--shots` and `--camera`, in that order, with their files by view id.
fn cameras_of(args: &CalibrateArgs) -> Result<Vec<CameraFiles>> {
    let mut given: Vec<(String, Vec<PathBuf>)> = Vec::new();
    if let Some(dir) = &args.shots {
        if !dir.is_dir() {
            bail!(
                "--shots {}: not a folder; give the folder `kfuse capture calib --device all --out DIR` wrote",
                dir.display()
            );
        }
        given.extend(shots_folder(dir)?);
    }
    for arg in &args.camera {
        let (name, pattern) = parse_camera_arg(arg)?;
        let files = expand(std::slice::from_ref(&pattern), "camera")
            .with_context(|| format!("camera {name}"))?;
        given.push((name, files));
    }
    check_distinct_names(given.iter().map(|(n, _)| n.as_str()))?;
    if given.len() > calib::multi::MAX_CAMERAS {
        bail!(
            "{} cameras: a joint calibration takes at most {}",
            given.len(),
            calib::multi::MAX_CAMERAS
        );
    }
    if let Some(r) = &args.reference
        && !given.iter().any(|(n, _)| n == r)
    {
        bail!(
            "--reference {r}: not one of the cameras ({})",
            given.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>().join(", ")
        );
    }
    Ok(given.iter().map(|(n, f)| camera_files(n, f)).collect::<Result<_, _>>()?)
}

/// Checks `--out` and `--report` before any work: `--out` a file in an existing folder,
/// not one of the images, and (without `--overwrite`) either missing or a rig an earlier
/// joint calibration wrote; `--report` not a file.
fn check_outputs(args: &CalibrateArgs, cameras: &[CameraFiles]) -> Result<()> {
    let out = &args.out;
    super::outputs::check_file("--out", out, cameras.iter().flat_map(|c| c.files.values()))?;
    if !args.overwrite && out.exists() {
        let expected = bounded_read::Expected { what: "a rig file", fix: "" };
        let ours = bounded_read::read_bounded(out, kfuse_io::rig::MAX_RIG_FILE_BYTES, expected)
            .ok()
            .and_then(|t| serde_json::from_slice::<serde_json::Value>(&t).ok())
            .is_some_and(|v| v["calibration"]["format"] == REPORT_FORMAT);
        if !ours {
            bail!(
                "--out {}: exists and is not a rig of an earlier joint calibration; give another file name, or pass --overwrite to replace it",
                out.display()
            );
        }
    }
    if let Some(dir) = &args.report {
        if dir.exists() && !dir.is_dir() {
            bail!("--report {} exists and is not a folder", dir.display());
        }
        if resolved_output(dir) == resolved_output(out) {
            bail!(
                "--report {} is the same path as --out; give the report its own folder",
                dir.display()
            );
        }
    }
    Ok(())
}

/// The printed table: per camera its views, RMS, focal length, centre in the reference frame
/// with σ, and its spanning-tree edge; then the views left out.
fn print_table(cal: &MultiCalibration, cams: &[CameraViews]) {
    println!(
        "\njoint calibration: reference {}, RMS {:.3} px over every corner",
        cal.rig.reference, cal.rms_px
    );
    println!(
        "{:<22} {:>5} {:>7} {:>16} {:>28} {:>18}  tree edge (shared views)",
        "camera", "views", "RMS px", "fx ± σ px", "centre x, y, z mm", "σ x, y, z mm"
    );
    for (((rc, rep), input), tree) in
        cal.rig.cameras.iter().zip(&cal.cameras).zip(cams).zip(&cal.tree)
    {
        let c = rc.camera_from_reference.inverse().translation * 1e3;
        let s = rep.center_std_m * 1e3;
        let used = input.views.values().filter(|v| !v.corners.is_empty()).count();
        let edge = match tree {
            Some((parent, n)) => format!("{parent} ({n})"),
            None => "reference".into(),
        };
        println!(
            "{:<22} {used:>5} {:>7.3} {:>16} {:>28} {:>18}  {edge}",
            rc.name,
            rep.rms_px,
            format!("{:.2} ± {:.2}", rc.model.intrinsics.fx, rep.intrinsics_std.fx),
            format!("{:.1}, {:.1}, {:.1}", c.x, c.y, c.z),
            format!("{:.2}, {:.2}, {:.2}", s.x, s.y, s.z),
        );
    }
    for (v, why) in &cal.rejected_views {
        println!("  view {v} left out: {why}");
    }
    if cal.rejected_corners > 0 {
        println!("  {} corner(s) left out as outliers", cal.rejected_corners);
    }
}

/// Runs the joint calibration.
pub(super) fn run(args: &CalibrateArgs) -> Result<()> {
    check_args(args)?;
    let (board, auto_board) = parse_board(&args.board, &args.square, args.top_left.as_deref())?;
    let cameras = cameras_of(args)?;
    check_outputs(args, &cameras)?;
    crate::interrupt::install()?;
    let request = JointRequest {
        cameras,
        board,
        auto_board,
        top_left_given: args.top_left.is_some(),
        flags: flags(args),
        refinement: args.corners.into(),
        reference: args.reference.clone(),
    };
    let printer = Arc::new(super::print::Printer::default());
    let observer = printer.clone();
    let outcome =
        crate::interrupt::run_until_interrupted(STOPPED, move || run_joint(&request, &*observer))??;
    print_table(&outcome.calibration, &outcome.inputs);
    crate::interrupt::check(STOPPED)?;
    // The report is staged first and published after the rig: a failure leaves neither.
    let staged = args.report.as_deref().map(StagedDir::new).transpose()?;
    if let Some(s) = &staged {
        calib::files::write_text(
            &s.join("report.json"),
            &serde_json::to_string_pretty(&outcome.report)?,
        )?;
    }
    kfuse_io::rig::write_multi_rig(&args.out, &outcome.rig)?;
    if let (Some(s), Some(dir)) = (staged, &args.report) {
        if let Err(e) = s.commit() {
            let _ = std::fs::remove_file(&args.out);
            return Err(e.into());
        }
        println!("\nreport: {}", report_path(dir).display());
    }
    println!("wrote {}", args.out.display());
    Ok(())
}

fn report_path(dir: &Path) -> PathBuf {
    dir.join("report.json")
}
