//! `kfuse calibrate --camera NAME=GLOB ... | --shots DIR`: joint calibration of N cameras
//! (issue 32) over `calib::multi`: the files and view ids (`calib::multi::input`), the
//! detector of `kfuse calibrate` per camera, `calibrate_multi`, a version-2 rig
//! (`kfuse_io::rig::write_multi_rig`) and `--report DIR/report.json`
//! (`calib::multi::report`, with every camera's corners for other tools).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use calib::detect::Refinement;
use calib::multi::input::{
    CameraFiles, align_labels, camera_files, check_distinct_names, parse_camera_arg, shots_folder,
};
use calib::multi::report::{REPORT_FORMAT, report_json};
use calib::multi::{CameraViews, MultiCalibration, calibrate_multi};
use calib::{Board, ViewCorners};
use geometry::timing::Timings;
use kfuse_io::atomic::StagedDir;

use super::{CalibrateArgs, STOPPED, expand, flags, load_and_detect, on_worker, parse_board};

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
    if out.is_dir() {
        bail!("--out {} is a folder; give a file name such as rig.json", out.display());
    }
    let parent = super::parent_folder(out);
    if !parent.is_dir() {
        bail!(
            "--out {}: folder {} does not exist; create it first",
            out.display(),
            parent.display()
        );
    }
    if let Err(e) = kfuse_io::atomic::writable_target(out) {
        bail!("--out {e}");
    }
    let resolved = super::resolved_output(out);
    if let Some(f) = cameras
        .iter()
        .flat_map(|c| c.files.values())
        .find(|f| f.canonicalize().ok().as_ref() == Some(&resolved))
    {
        bail!(
            "--out {} is one of the input images ({}); give a new file name such as rig.json",
            out.display(),
            f.display()
        );
    }
    if !args.overwrite && out.exists() {
        let ours = std::fs::read_to_string(out)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
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
        if super::resolved_output(dir) == resolved {
            bail!(
                "--report {} is the same path as --out; give the report its own folder",
                dir.display()
            );
        }
    }
    Ok(())
}

/// One camera's detected views by view id, and the board (its size found by the first
/// camera with `--board auto`).
fn detect_camera(
    timings: &mut Timings,
    cam: &CameraFiles,
    board: Board,
    auto: bool,
    refinement: Refinement,
) -> Result<(BTreeMap<u64, ViewCorners>, Board)> {
    let files: Vec<PathBuf> = cam.files.values().cloned().collect();
    let name = cam.name.clone();
    let (views, _images, board, stages, _per_image) = on_worker(timings, move || {
        match load_and_detect(&files, &board, auto, &name, refinement) {
            Ok(d) => {
                let stages = d.3.clone();
                (Ok(d), stages)
            }
            Err(e) => (Err(e), Timings::new()),
        }
    })??;
    drop(stages);
    Ok((cam.files.keys().copied().zip(views).collect(), board))
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
    let (mut board, auto) = parse_board(&args.board, &args.square, args.top_left.as_deref())?;
    let cameras = cameras_of(args)?;
    check_outputs(args, &cameras)?;
    crate::interrupt::install()?;
    let flags = flags(args);
    let refinement: Refinement = args.corners.into();
    let mut timings = Timings::new();
    let mut inputs = Vec::with_capacity(cameras.len());
    let mut colouring: Option<(bool, String)> = None;
    for (i, cam) in cameras.iter().enumerate() {
        let asked = Board {
            top_left_black: board.top_left_black.filter(|_| args.top_left.is_some()),
            ..board
        };
        let (views, found) = detect_camera(&mut timings, cam, asked, auto && i == 0, refinement)?;
        (board.cols, board.rows) = (found.cols, found.rows);
        // One board shows one colouring to every camera that decides it.
        if let Some(black) = found.top_left_black {
            match &colouring {
                Some((b, first)) if *b != black && args.top_left.is_none() => {
                    let word = |b: bool| if b { "black" } else { "white" };
                    bail!(
                        "camera {first} sees a board whose top-left square is {}, camera {} one whose top-left square is {}: not the same board (images of two sessions?); give the images of one session, or --top-left black|white if the board really is the same",
                        word(*b),
                        cam.name,
                        word(black)
                    );
                }
                Some(_) => {}
                None => colouring = Some((black, cam.name.clone())),
            }
        }
        let Some(size) = views.values().find(|v| v.width > 0) else {
            bail!("camera {}: none of its {} image(s) can be read", cam.name, views.len());
        };
        let (width, height) = (size.width, size.height);
        inputs.push(CameraViews {
            name: cam.name.clone(),
            role: cam.role,
            sensor: cam.sensor.clone(),
            width,
            height,
            views,
            flags,
        });
    }
    align_labels(&board, &mut inputs);
    let reference = args.reference.clone();
    let inputs_owned = inputs.clone();
    let cal = on_worker(&mut timings, move || {
        super::timed("joint calibration", || {
            calibrate_multi(&board, &inputs_owned, reference.as_deref())
        })
    })??;
    print_table(&cal, &inputs);
    let files: Vec<BTreeMap<u64, PathBuf>> = cameras.iter().map(|c| c.files.clone()).collect();
    let report = report_json(&board, &cal, &inputs, &files);
    let mut rig = cal.rig.clone();
    // The rig keeps the report without the corners (those are in report.json).
    let mut summary = report.clone();
    if let Some(m) = summary.as_object_mut() {
        m.remove("detections");
    }
    rig.calibration = Some(summary);
    rig.validate().map_err(|e| {
        anyhow::anyhow!(
            "the calibration gives a rig that kfuse cannot use ({e}); nothing was written"
        )
    })?;
    crate::interrupt::check(STOPPED)?;
    // The report is staged first and published after the rig: a failure leaves neither.
    let staged = args.report.as_deref().map(StagedDir::new).transpose()?;
    if let Some(s) = &staged {
        calib::files::write_text(&s.join("report.json"), &serde_json::to_string_pretty(&report)?)?;
    }
    kfuse_io::rig::write_multi_rig(&args.out, &rig)?;
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
