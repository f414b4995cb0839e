//! The outputs of `kfuse calibrate`: their paths checked before any work (no folder, no input
//! image, no two the same, no file kfuse did not write unless `--overwrite`), then written all
//! or nothing (the rig or camera file, the OpenCV YAML, the report folder's figures and
//! report.json), and the `--timings` lines.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Result, bail};
use calib::files::write_text;
use calib::io::ImageTiming;
use calib::pipeline::Outcome;
use geometry::timing::{Timings, ms_since};
use kfuse_io::atomic::{StagedDir, StagedFiles};

use super::{CalibrateArgs, STOPPED, depth_figures};
use crate::calibrate_report::Figures;

/// The folder of an output path (`.` for a bare file name).
pub(super) fn parent_folder(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Where an output path leads, for telling whether two outputs are one file: the path with
/// its links and `..` resolved, or (missing) its resolved folder and its name.
pub(super) fn resolved_output(path: &Path) -> PathBuf {
    path.canonicalize().unwrap_or_else(|_| {
        let folder = parent_folder(path);
        let folder = folder.canonicalize().unwrap_or_else(|_| folder.to_path_buf());
        folder.join(path.file_name().unwrap_or_default())
    })
}

/// Checks the output paths before any work: each names a file in an existing folder (a
/// missing file, a regular file or a link to one: no folder, device or pipe), none is one of
/// the input images, no two outputs are the same path, and the report folder is not a file.
/// Whether two paths name one existing file.
fn same(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

/// One output file `path` of flag `flag`, before any work: not a folder, in a folder that
/// exists, writable, and none of the `inputs` images.
pub(super) fn check_file<'a>(
    flag: &str,
    path: &Path,
    mut inputs: impl Iterator<Item = &'a PathBuf>,
) -> Result<()> {
    if path.is_dir() {
        bail!("{flag} {} is a folder; give a file name such as rig.json", path.display());
    }
    let parent = parent_folder(path);
    if !parent.is_dir() {
        bail!(
            "{flag} {}: folder {} does not exist; create it first",
            path.display(),
            parent.display()
        );
    }
    if let Err(e) = kfuse_io::atomic::writable_target(path) {
        bail!("{flag} {e}");
    }
    if let Some(input) = inputs.find(|i| same(i, path)) {
        bail!(
            "{flag} {} is one of the input images ({}); give a new file name such as rig.json",
            path.display(),
            input.display()
        );
    }
    Ok(())
}

pub(super) fn check<'a>(
    args: &CalibrateArgs,
    inputs: impl Iterator<Item = &'a PathBuf> + Clone,
) -> Result<()> {
    let mut taken: Vec<(&str, PathBuf)> = Vec::new();
    for (flag, path) in std::iter::once(("--out", &args.out))
        .chain(args.opencv_yaml.iter().map(|y| ("--opencv-yaml", y)))
    {
        check_file(flag, path, inputs.clone())?;
        let here = resolved_output(path);
        if let Some((other, _)) = taken.iter().find(|(_, p)| *p == here) {
            bail!(
                "{flag} {} is the same file as {other}; give each output its own name",
                path.display()
            );
        }
        // `--rig R --depth … --out R` adds the correction to the rig it reads: replacing it is
        // the point (its cameras and extrinsics are carried over).
        let adds_to_input_rig =
            !args.depth.is_empty() && args.rig.as_deref().is_some_and(|r| same(r, path));
        if !args.overwrite
            && !adds_to_input_rig
            && let Some(what) = foreign_output(
                path,
                flag == "--opencv-yaml",
                writes_rig(args),
                !args.depth.is_empty(),
            )
        {
            bail!(
                "{flag} {}: exists and is {what}; give another file name, or pass --overwrite to replace it",
                path.display()
            );
        }
        taken.push((flag, here));
    }
    if let Some(dir) = &args.report {
        if dir.exists() && !dir.is_dir() {
            bail!("--report {} exists and is not a folder", dir.display());
        }
        let here = resolved_output(dir);
        if let Some((other, _)) = taken.iter().find(|(_, p)| *p == here) {
            bail!(
                "--report {} is the same path as {other}; give the report its own folder",
                dir.display()
            );
        }
    }
    Ok(())
}

/// Bytes of an existing output file read to recognise it as kfuse's: a rig JSON with its
/// report is 100-400 KB (per-corner residuals of 25 pairs); an OpenCV YAML under 2 KB.
const RECOGNISE_BYTES: u64 = 16 << 20;
/// The top-level keys of the OpenCV YAML files kfuse writes (`calib::files::opencv_yaml_rig`,
/// `opencv_yaml_camera`); OpenCV's own samples add others (`calibration_time`, `nr_of_frames`).
const KFUSE_YAML_KEYS: [&[&str]; 2] = [
    &[
        "D1",
        "D2",
        "M1",
        "M2",
        "R",
        "T",
        "T_units",
        "image_height_1",
        "image_height_2",
        "image_width_1",
        "image_width_2",
    ],
    &["camera_matrix", "distortion_coefficients", "image_height", "image_width"],
];

/// What an existing output file is when kfuse calibrate did not write it (`None`: missing, or
/// one of calibrate's own: a `kfuse-rig` / `kfuse-camera` JSON whose `calibration` is
/// calibrate's report, or an OpenCV YAML with exactly the keys kfuse writes). A rerun into
/// the same `rig.json` replaces it; anything else, a rig imported from another tool, a rig
/// whose depth correction this run would drop, a user's notes or OpenCV's own calibration, is
/// kept unless `--overwrite` says otherwise. `depth_run`: this run fits a depth correction.
fn foreign_output(path: &Path, yaml: bool, rig: bool, depth_run: bool) -> Option<String> {
    use std::io::Read;
    let file = bounded_read::open_without_blocking(path).ok()?;
    if !file.metadata().is_ok_and(|m| m.is_file()) {
        return None;
    }
    let mut text = String::new();
    if file.take(RECOGNISE_BYTES).read_to_string(&mut text).is_err() {
        return Some("not a text file".into());
    }
    if yaml {
        let mut keys: Vec<&str> = text
            .lines()
            .filter(|l| l.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_'))
            .filter_map(|l| l.split_once(':').map(|(k, _)| k.trim()))
            .collect();
        keys.sort_unstable();
        let ours = text.starts_with("%YAML:1.0") && KFUSE_YAML_KEYS.contains(&keys.as_slice());
        return (!ours).then(|| "another YAML or text file".into());
    }
    let value = serde_json::from_str::<serde_json::Value>(&text).ok();
    let format =
        value.as_ref().and_then(|v| v.get("format").and_then(|f| f.as_str()).map(str::to_string));
    // Replaced by the same kind only: a single-camera run into a two-camera rig would lose
    // the other camera and the extrinsics (and the other way round a camera file).
    match (format.as_deref(), rig) {
        (Some(geometry::rig::RIG_FORMAT), true)
        | (Some(kfuse_io::rig_io::CAMERA_FORMAT), false) => {
            value.as_ref().and_then(|v| not_calibrates(v, depth_run))
        }
        (Some(geometry::rig::RIG_FORMAT), false) => {
            Some("a two-camera rig, and this run writes a single-camera file".into())
        }
        (Some(kfuse_io::rig_io::CAMERA_FORMAT), true) => {
            Some("a single-camera file, and this run writes a two-camera rig".into())
        }
        (Some(other), _) => Some(format!("a JSON file of format \"{other}\"")),
        (None, _) => Some("not a kfuse calibration file".into()),
    }
}

/// For a kfuse rig or camera file of the kind this run writes: why it is not calibrate's own
/// to replace (an import, or a depth correction this run would drop), `None` when it is.
fn not_calibrates(v: &serde_json::Value, depth_run: bool) -> Option<String> {
    /// Characters of a file's `calibration.source` shown in the message (a file name or a
    /// tool's name fits; a garbage value must not flood the terminal).
    const SOURCE_SHOWN_CHARS: usize = 80;
    // calibrate's report holds the board it was fitted on; an import names its source.
    let report = &v["calibration"];
    if report.get("board").is_none() {
        let source = match report.get("source").and_then(|s| s.as_str()) {
            Some(s) => format!(
                "imported from {}",
                s.chars().take(SOURCE_SHOWN_CHARS).collect::<String>().escape_debug()
            ),
            None => "its report names no calibration board".into(),
        };
        return Some(format!("a calibration kfuse calibrate did not make ({source})"));
    }
    if !depth_run && !v["depth_correction"].is_null() {
        return Some(
            "a rig with a depth correction (calibrate --depth), which this run would drop".into(),
        );
    }
    None
}

/// Whether this run writes a two-camera rig (IR and colour images, or `--rig` with
/// `--depth`) rather than a single-camera file.
fn writes_rig(args: &CalibrateArgs) -> bool {
    (!args.color.is_empty() && !args.ir.is_empty()) || args.rig.is_some()
}

/// Writes what `outcome` gives: the rig (or camera) file and the OpenCV YAML to temporary
/// names first, renamed only after the report folder is published, so that a failure anywhere
/// leaves neither; then prints what was written and, with `--timings`, where the time went.
pub(super) fn write(
    args: &CalibrateArgs,
    outcome: &Outcome,
    mut timings: Timings,
    started: Instant,
) -> Result<()> {
    let mut outputs: Vec<(PathBuf, String)> = vec![(args.out.clone(), outcome.text.clone())];
    if let Some(y) = &args.opencv_yaml
        && let Some(text) = outcome.opencv_yaml()
    {
        outputs.push((y.clone(), text));
    }
    crate::interrupt::check(STOPPED)?;
    let mut files = StagedFiles::new();
    timings.time(STAGE_WRITE_RIG, || {
        outputs.iter().try_for_each(|(path, text)| files.add(path, text.as_bytes()))
    })?;
    if let Some(dir) = &args.report {
        let staged = StagedDir::new(dir)?;
        let figs = Figures {
            board: Some(outcome.board),
            cameras: outcome.cameras(),
            ir_images: outcome.ir.with_images(),
            color_images: outcome.color.with_images(),
        };
        timings.time(STAGE_WRITE_FIGURES, || -> Result<()> {
            if !figs.cameras.is_empty() {
                figs.write(&staged)?;
            }
            if let Some(fit) = &outcome.depth_fit {
                depth_figures::write(&staged, fit)?;
            }
            Ok(())
        })?;
        // Last, so that its timings hold every stage before it.
        let mut report = outcome.report.clone();
        report["timings_ms"] =
            calib::timing::report_json(ms_since(started), &timings, &outcome.image_times);
        timings.time(STAGE_WRITE_REPORT, || {
            write_text(&staged.join("report.json"), &serde_json::to_string_pretty(&report)?)
                .map_err(anyhow::Error::from)
        })?;
        crate::interrupt::check(STOPPED)?;
        timings.time(STAGE_PUBLISH, || staged.commit())?;
        println!("\nreport: {}", dir.display());
    }
    timings.time(STAGE_PUBLISH, || files.commit())?;
    for (path, _) in &outputs {
        println!("wrote {}", path.display());
    }
    if args.timings {
        for line in timing_lines(ms_since(started), &timings, &outcome.image_times) {
            eprintln!("{line}");
        }
    }
    Ok(())
}

/// The `--timings` lines: the stages, with ms per image for reading and detection, then per
/// camera the median and largest image's read and detection times.
fn timing_lines(wall_ms: f64, timings: &Timings, images: &[ImageTiming]) -> Vec<String> {
    let cameras: Vec<&str> =
        ["IR", "colour"].into_iter().filter(|c| images.iter().any(|i| i.camera == *c)).collect();
    let per_image: Vec<String> = cameras
        .iter()
        .flat_map(|c| [calib::timing::read_stage(c), calib::timing::detect_stage(c)])
        .collect();
    let per_image: Vec<&str> = per_image.iter().map(String::as_str).collect();
    let n = cameras.first().map_or(0, |c| images.iter().filter(|i| i.camera == *c).count());
    let mut lines = timings.summary(wall_ms, Some((n, "image", &per_image)));
    let stats = |mut v: Vec<f64>| -> (f64, f64) {
        v.sort_by(f64::total_cmp);
        (v.get(v.len() / 2).copied().unwrap_or(0.0), v.last().copied().unwrap_or(0.0))
    };
    for c in cameras {
        let of = |f: &dyn Fn(&ImageTiming) -> Option<f64>| -> Vec<f64> {
            images.iter().filter(|i| i.camera == c).filter_map(f).collect()
        };
        let (rm, rx) = stats(of(&|i| Some(i.read_ms)));
        let (dm, dx) = stats(of(&|i| i.detect_ms));
        lines.push(format!(
            "  per {c} image (own thread): read median {rm:.2} ms (max {rx:.2}), detect median {dm:.2} ms (max {dx:.2})"
        ));
    }
    lines
}

/// Stage: the rig (or camera) file and the OpenCV YAML written to their temporary names.
const STAGE_WRITE_RIG: &str = "write rig files";
/// Stage: the report's figures (`--report`).
const STAGE_WRITE_FIGURES: &str = "write report figures";
/// Stage: report.json (`--report`; after its own `timings_ms` were taken, so only in the
/// `--timings` lines).
const STAGE_WRITE_REPORT: &str = "write report.json";
/// Stage: the outputs renamed into place (only in the `--timings` lines).
const STAGE_PUBLISH: &str = "publish outputs";
