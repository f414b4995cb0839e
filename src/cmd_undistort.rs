//! `kfuse undistort`: removes lens distortion from images with a rig file's camera model.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use calib::undistort::UndistortMap;
use indicatif::{ProgressBar, ProgressStyle};
use kfuse_io::atomic::StagedDir;
use kfuse_io::image_header::image_size;
use kfuse_io::images;
use kfuse_io::raster::{Raster, RasterFormat, read_raster, write_raster_marked};
use kfuse_io::rig_io::Role;

/// Arguments of `kfuse undistort`.
#[derive(clap::Args, Debug)]
#[command(after_help = "EXAMPLES:
  kfuse undistort --rig rig.json --camera color caps/Colour.tif --out rect/
  kfuse undistort --rig rig.json --camera depth 'caps/depth_*.png' --out rect/   (quoted or not)
  kfuse fuse --rig rig.json --color rect/Colour_rect.tif --depth rect/Depth_rect.tif --rectified --out f

Writes NAME_rect.EXT per input NAME.EXT (Colour.tif -> Colour_rect.tif), in the input's format
and pixel type: TIFF stays TIFF, grey stays grey, 16-bit stays 16-bit, float TIFF stays float,
OpenEXR (float depth in metres, NaN = none) stays OpenEXR; a grey + alpha PNG becomes RGBA. Colour and 8-bit grey (IR) images are
resampled bilinearly; 16-bit (depth in millimetres, 16-bit IR) and float (depth in metres) by
nearest neighbour, so no depth is ever blended across an edge. Runs into the same --out add up
(undistort the colour, then the depth images into one folder); an output of the same name is
replaced.
Fuse the results with --rectified (they would be undistorted a second time otherwise). Each
output is marked as kfuse undistort's (PNG text, JPEG comment, TIFF/EXR software field): given
again as an input, wherever it was copied, it is refused (--force undistorts it again); in the
--out folder itself it is skipped.
Pixels whose ray falls where the distortion model folds (the lab's IR k1/k2 fold near the image
corners), or outside the input image, are masked: black, or depth 0 (no sample).")]
pub struct UndistortArgs {
    /// Rig file, or the single-camera file of `kfuse calibrate --ir … --out ir.json`.
    #[arg(long)]
    rig: PathBuf,
    /// Which camera took the images.
    #[arg(long, value_parser = ["color", "depth"])]
    camera: String,
    /// Images to undistort: files or glob patterns, quoted ('caps/*.png') or expanded by the
    /// shell.
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// Output folder (created if missing). The outputs appear all together when every image
    /// is done, or not at all.
    #[arg(long)]
    out: PathBuf,
    /// Use a rig that fails the plausibility check (see README "Limits"), or undistort an
    /// image that kfuse undistort wrote (already undistorted) again, with a warning.
    #[arg(long)]
    force: bool,
}

/// `NAME_rect.EXT` for input `NAME.EXT` (the handout's `Colour.tif` → `Colour_rect.tif`);
/// `NAME_rect.png` for a name without extension.
fn output_name(path: &Path) -> String {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "image".into());
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().into_owned())
        .unwrap_or_else(|| RasterFormat::Png.extension().into());
    format!("{stem}_rect.{ext}")
}

/// The images named on the command line: an existing file as it is, otherwise a pattern with
/// `*`, `?` or `[` expanded (sorted; the shell leaves a quoted one alone), each file once.
fn expand_images(args: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut out: Vec<PathBuf> = Vec::new();
    for arg in args {
        let text = arg.to_string_lossy();
        if arg.exists() || !text.contains(['*', '?', '[']) {
            out.push(arg.clone());
            continue;
        }
        let mut matches: Vec<PathBuf> = glob::glob(&text)
            .map_err(|e| anyhow::anyhow!("'{text}': invalid glob pattern: {e}"))?
            .filter_map(|m| m.ok())
            .filter(|p| p.is_file())
            .collect();
        if matches.is_empty() {
            bail!("'{text}': no file matches this pattern");
        }
        matches.sort();
        out.extend(matches);
    }
    let mut seen = std::collections::HashSet::new();
    out.retain(|p| seen.insert(p.clone()));
    Ok(out)
}

/// Whether `path` is an output of `kfuse undistort`: the mark it stores in each image
/// (`kfuse_io::provenance`: PNG text, JPEG comment, TIFF/EXR software field), which travels with
/// the file wherever it is copied; or, for outputs of kfuse versions before the mark (and BMP,
/// which has no place for it), a `NAME_rect.EXT` that its folder's kfuse manifest lists. Other
/// files kfuse wrote (the demo's `depth.png`) are not undistort's.
fn is_undistort_output(path: &Path) -> Result<bool> {
    if kfuse_io::provenance::written_by_undistort(path)? {
        return Ok(true);
    }
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let rect_named = path.file_stem().is_some_and(|s| s.to_string_lossy().ends_with("_rect"));
    let folder = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    Ok(rect_named && kfuse_io::atomic::written_by_kfuse(folder).contains(&name))
}

/// `images` without the outputs of an earlier `kfuse undistort` ([`is_undistort_output`]),
/// which would be undistorted a second time (`left01_rect_rect.jpg`, from a user's trial).
/// Those in `out` itself (a pattern such as `shots/*.jpg` with `--out shots` matches last
/// run's `*_rect.jpg`) are skipped with a note, and it fails when nothing else is left; one
/// elsewhere is refused with one line, unless `force` (then it is undistorted again, with a
/// warning).
fn skip_earlier_outputs(images: Vec<PathBuf>, out: &Path, force: bool) -> Result<Vec<PathBuf>> {
    let out_dir = out.canonicalize().ok();
    let mut kept = Vec::new();
    let mut skipped = Vec::new();
    for path in images {
        if !is_undistort_output(&path)? {
            kept.push(path);
            continue;
        }
        let folder =
            path.parent().map(|d| if d.as_os_str().is_empty() { Path::new(".") } else { d });
        let in_out = out_dir.is_some() && folder.and_then(|d| d.canonicalize().ok()) == out_dir;
        if in_out {
            skipped.push(path);
        } else if force {
            eprintln!(
                "warning: {}: was written by kfuse undistort; undistorting it again (--force)",
                path.display()
            );
            kept.push(path);
        } else {
            bail!(
                "{}: was written by kfuse undistort (it is already undistorted); give the original image, or pass --force to undistort it again",
                path.display()
            );
        }
    }
    if let Some(first) = skipped.first() {
        if kept.is_empty() {
            bail!(
                "every image given was written by an earlier kfuse undistort into {} (e.g. {}); give the original images",
                out.display(),
                first.display()
            );
        }
        println!(
            "note: skipped {} image(s) that an earlier kfuse undistort wrote into {} (e.g. {})",
            skipped.len(),
            out.display(),
            first.display()
        );
    }
    Ok(kept)
}

/// Undistorts one image in its own pixel type: 8-bit bilinearly, 16-bit and float (depth) by
/// nearest neighbour; masked pixels are 0 (black, no depth) or NaN (float depth).
fn remap(map: &UndistortMap, raster: &Raster) -> Raster {
    match raster {
        Raster::Gray8(i) => {
            let (r, _) = map.remap_bilinear(&i.map(|&v| [v]));
            Raster::Gray8(r.map(|v| v[0]))
        }
        Raster::Rgb8(i) => Raster::Rgb8(map.remap_bilinear(i).0),
        Raster::Rgba8(i) => Raster::Rgba8(map.remap_bilinear(i).0),
        Raster::Gray16(i) => Raster::Gray16(map.remap_nearest(i, 0)),
        Raster::GrayF32(i) => Raster::GrayF32(map.remap_nearest(i, f32::NAN)),
    }
}

/// OpenEXR's magic number (the first four bytes of every `.exr` file).
const EXR_MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];

/// True when `path` is an OpenEXR file (by its magic number, not its name).
fn is_exr(path: &Path) -> Result<bool> {
    use std::io::Read;
    let mut head = [0u8; 4];
    let mut file = bounded_read::open_without_blocking(path)
        .map_err(|e| anyhow::anyhow!("{}: cannot open: {e}", path.display()))?;
    Ok(file.read_exact(&mut head).is_ok() && head == EXR_MAGIC)
}

/// The decoded image has the camera's size (its header said so; this guards the decoder).
fn check_read_size(
    path: &Path,
    size: (usize, usize),
    camera: &str,
    cam: &geometry::CameraModel,
) -> Result<()> {
    if size != (cam.width, cam.height) {
        bail!(
            "{}: image is {}x{} but the rig's {camera} camera is {}x{}",
            path.display(),
            size.0,
            size.1,
            cam.width,
            cam.height
        );
    }
    Ok(())
}

/// The camera to undistort with: `--camera` of the rig or single-camera file, whose
/// implausibilities refuse the run (warnings with `--force`).
fn load_camera(args: &UndistortArgs) -> Result<geometry::CameraModel> {
    // A rig or the single-camera JSON that `kfuse calibrate --ir/--color --out` writes.
    let role = if args.camera == "color" { Role::Color } else { Role::Depth };
    let calibration = kfuse_io::rig::read_rig(&args.rig)?.into_calibration(&args.rig)?;
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
    Ok(cam)
}

/// The images to undistort, checked before the (large) map is built and before anything is
/// written: one output name per input, every image's size from its header.
fn checked_images(args: &UndistortArgs, cam: &geometry::CameraModel) -> Result<Vec<PathBuf>> {
    let images = skip_earlier_outputs(expand_images(&args.images)?, &args.out, args.force)?;
    let mut names: HashMap<String, &PathBuf> = HashMap::new();
    for path in &images {
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
    Ok(images)
}

/// Runs the command.
pub fn run(args: UndistortArgs) -> Result<()> {
    let cam = load_camera(&args)?;
    let images = checked_images(&args, &cam)?;
    let staged = StagedDir::new(&args.out)?;
    // Before the work: an entry of the user's carrying one of this run's output names.
    staged.refuse_foreign(&images.iter().map(|p| output_name(p)).collect::<Vec<_>>())?;
    crate::interrupt::install()?;
    let map = UndistortMap::new(&cam);
    if let Some(r) = cam.distortion.fold_radius() {
        println!(
            "note: the {} model folds at undistorted radius {r:.3}; {:.2} % of the output is masked",
            args.camera,
            100.0 * map.masked_fraction()
        );
    }
    let pb = ProgressBar::new(images.len() as u64);
    pb.set_style(
        ProgressStyle::with_template("undistorting [{bar:30}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    // Stored in every output, so that it is recognised wherever it is copied.
    let mark = format!("{} ({} camera)", kfuse_io::provenance::UNDISTORT_MARK, args.camera);
    for path in &images {
        let out = staged.join(output_name(path));
        if is_exr(path)? {
            // Float depth in metres (NaN = none), as `kfuse fuse` writes and reads it (the
            // scale applies to integer files only).
            let depth = images::read_depth(path, 1.0)?;
            check_read_size(path, depth.size(), &args.camera, &cam)?;
            images::write_depth_exr_marked(&out, &map.remap_nearest(&depth, f32::NAN), &mark)?;
        } else {
            let (raster, format) = read_raster(path)?;
            check_read_size(path, raster.size(), &args.camera, &cam)?;
            write_raster_marked(&out, &remap(&map, &raster), format, &mark)?;
        }
        pb.inc(1);
        crate::interrupt::check(": stopped; nothing was written to --out")?;
    }
    pb.finish();
    // Runs into one folder add up (the colour, then the depth images of a session).
    staged.commit_adding()?;
    println!("wrote {} image(s) to {}", images.len(), args.out.display());
    Ok(())
}
