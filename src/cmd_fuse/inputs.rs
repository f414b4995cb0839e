//! The inputs of `kfuse fuse`: a rig with colour and depth files, the course's
//! `synthdata.mat`, or the lab's `KinectData.mat` (with `--color` / `--depth` replacing its
//! images); read, checked against each other and for unit mistakes before any work.

use std::path::Path;

use anyhow::{Result, bail};
use geometry::fusion::{FusionOptions, Request};
use geometry::{DepthKind, Image, Rig};
use kfuse_io::kinect_data::{self, KinectDepth};
use kfuse_io::mat::MatFile;
use kfuse_io::rig_io::{self, Calibration};
use kfuse_io::{course, image_header, images};

use super::checks::{self, DepthSource};
use super::{DepthKindArg, FuseArgs};

/// The inputs of one fusion, loaded and checked.
pub struct Inputs {
    /// The rig (without distortion when the images are rectified).
    pub rig: Rig,
    /// Depth, metres, NaN = none.
    pub depth: Image<f32>,
    /// Depth kind.
    pub kind: DepthKind,
    /// Colour.
    pub color: Image<[u8; 3]>,
    /// Description for summary.json.
    pub description: serde_json::Value,
}

fn check_size(
    what: &str,
    path: &Path,
    got: (usize, usize),
    want: (usize, usize),
    rig_path: &Path,
) -> Result<()> {
    if got != want {
        bail!(
            "{what} {} is {}x{}, but the rig {} says that camera is {}x{}; pass the {what} of that camera or the rig it was calibrated with",
            path.display(),
            got.0,
            got.1,
            rig_path.display(),
            want.0,
            want.1
        );
    }
    Ok(())
}

/// The rig plausibility check ([`Rig::check_plausible`]), or with `--force` its problems as
/// warnings.
fn check_rig(rig: &Rig, source: &Path, force: bool) -> Result<()> {
    if force {
        for problem in rig.plausibility_problems() {
            eprintln!("warning: {}: {problem} (--force)", source.display());
        }
        return Ok(());
    }
    if let Err(e) = rig.check_plausible() {
        bail!("{}: {e}; pass --force if the rig really is meant this way", source.display());
    }
    Ok(())
}

/// Reads `--rig`: a kfuse rig; a single-camera file is refused with how to get a rig.
fn load_rig_for_fuse(path: &Path, force: bool) -> Result<Rig> {
    let rig = kfuse_io::rig::read_rig(path)?.into_pair(path)?;
    check_rig(&rig, path, force)?;
    Ok(rig)
}

/// The file `kfuse capture` saves beside its images: the sensor's factory parameters.
pub const FACTORY_PARAMS: &str = "kinect_params.json";

/// The rig fitted to a sensor's factory parameters (`kinect_params.json`), as `rig import` makes.
pub fn factory_rig(params: &Path) -> Result<Rig> {
    match rig_io::import(&[params.to_path_buf()], &rig_io::ImportOptions::default())?.calibration {
        Calibration::Rig(rig) => Ok(rig),
        Calibration::Camera { .. } => {
            bail!("{}: holds one camera, not the sensor's factory parameters", params.display())
        }
    }
}

/// [`checks::check_against_factory`] of `rig` (read from `rig_path`) against the factory
/// parameters in `params` (`source` says where they came from), as a problem. The check is a
/// service: an unreadable parameter file is no reason to refuse a rig that the user gave, so it
/// only gets a warning.
pub fn factory_problem(rig: &Rig, rig_path: &Path, params: &Path, source: &str) -> Option<String> {
    let factory = match factory_rig(params) {
        Ok(f) => f,
        Err(e) => {
            eprintln!(
                "warning: the rig is not checked against the sensor's factory parameters: {e:#}"
            );
            return None;
        }
    };
    let name = rig_path.display().to_string();
    let factory_name = format!("the sensor's factory parameters in {source}");
    checks::check_against_factory(rig, &name, &factory, &factory_name).err()
}

/// Images from `kfuse capture` have the sensor's factory parameters beside them: a rig that
/// does not fit them ([`checks::check_against_factory`]) adds a problem, and so does a depth
/// file named as kfuse names IR images.
fn check_beside_capture(
    rig: &Rig,
    rig_path: &Path,
    depth_path: &Path,
    problems: &mut Vec<String>,
) -> Result<()> {
    if let Some(depth) = capture_depth_of_ir(depth_path) {
        // Named as kfuse capture names IR images, with or without the capture's folder around.
        let depth_hint = if depth.is_file() {
            format!("the depth of this shot is {}", depth.display())
        } else {
            format!("its depth would be named {}", depth.display())
        };
        problems.push(format!(
            "{}: is named as kfuse capture names the IR (brightness) image of a shot, not its depth; {depth_hint}",
            depth_path.display()
        ));
    }
    let params = depth_path.parent().unwrap_or(Path::new(".")).join(FACTORY_PARAMS);
    if params.is_file() {
        problems.extend(factory_problem(rig, rig_path, &params, &params.display().to_string()));
    } else if let Some((true, _)) = rig_io::show::kinect_orientation(rig) {
        // No factory parameters to compare with: the images may be mirrored too (raw
        // libfreenect2 output), so this is a warning, not a refusal.
        eprintln!(
            "warning: {} is a calibration of images mirrored left-right (colour camera at x = {:+.1} mm); kfuse's images, the Kinect SDK's and iai_kinect2's are as the scene is (+52 mm): if these are, convert the rig with `kfuse rig import {} --mirror --out RIG.json`",
            rig_path.display(),
            rig.color_centre_in_depth().x * 1000.0,
            rig_path.display()
        );
    }
    Ok(())
}

/// For an image that `kfuse undistort` wrote (named `NAME_rect.EXT` and listed in its folder's
/// kfuse manifest): the problem of fusing it without `--rectified`, which would undistort it a
/// second time (with the Kinect's IR lens, ~2 px at the image corners).
fn undistorted_note(path: &Path) -> Option<String> {
    let name = path.file_name()?.to_str()?;
    let stem = Path::new(name).file_stem()?.to_str()?;
    let folder = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    (stem.ends_with("_rect") && kfuse_io::atomic::written_by_kfuse(folder).iter().any(|n| n == name))
        .then(|| {
            format!(
                "{}: was written by kfuse undistort (already undistorted); pass --rectified, or it is undistorted a second time",
                path.display()
            )
        })
}

/// For a file named as `kfuse capture` names IR images (`NAME_ir.png`, `ir_NNNN.png`), the
/// depth file of the same shot (`NAME_depth.png`, `depth_NNNN.png`).
fn capture_depth_of_ir(path: &Path) -> Option<std::path::PathBuf> {
    let name = path.file_name()?.to_str()?;
    let depth = if let Some(stem) = name.strip_suffix("_ir.png") {
        format!("{stem}_depth.png")
    } else {
        let number = name.strip_prefix("ir_")?.strip_suffix(".png")?;
        number.chars().all(|c| c.is_ascii_digit()).then(|| format!("depth_{number}.png"))?
    };
    Some(path.with_file_name(depth))
}

/// Reads a colour image and checks its size against the rig (from the header first: a huge
/// or wrong image is refused before it is decoded). A file that is not a colour picture (16-bit
/// grey) adds a problem, an error unless `--force`.
fn read_color(
    path: &Path,
    rig: &Rig,
    rig_path: &Path,
    problems: &mut Vec<String>,
) -> Result<Image<[u8; 3]>> {
    let want = (rig.color.width, rig.color.height);
    check_size("colour image", path, image_header::image_size(path)?, want, rig_path)?;
    let (color, note) = images::read_color_noting(path)?;
    check_size("colour image", path, color.size(), want, rig_path)?;
    problems.extend(note);
    Ok(color)
}

/// Reads a depth image with `--depth-scale` and checks its size against the rig.
fn read_depth(
    path: &Path,
    scale: f64,
    rig: &Rig,
    rig_path: &Path,
) -> Result<(Image<f32>, DepthSource)> {
    let want = (rig.depth.width, rig.depth.height);
    check_size("depth image", path, image_header::image_size(path)?, want, rig_path)?;
    let (depth, encoding) = images::read_depth_encoded(path, scale)?;
    check_size("depth image", path, depth.size(), want, rig_path)?;
    Ok((depth, DepthSource::File { name: path.display().to_string(), encoding, scale }))
}

/// Loads and checks the inputs named by `args` (nothing is written), and the fusion
/// [`Request`] of their rig (rectified once) and `options`; the depth is prepared by it.
pub fn load_inputs(args: &FuseArgs, options: &FusionOptions) -> Result<(Inputs, Request)> {
    // Problems found while reading (an error unless --force, below).
    let mut problems = Vec::new();
    let (mut inputs, depth_source, rig_name) = match &args.mat {
        Some(mat) => load_mat(args, mat, &mut problems)?,
        None => load_files(args, &mut problems)?,
    };
    let rectified = args.rectified || inputs.rig.rectified;
    inputs.rig.rectified = rectified;
    let request = Request::new(&inputs.rig, inputs.kind, *options)?;
    inputs.rig = request.rig().clone();
    inputs.description["rectified"] = serde_json::json!(rectified);
    prepare_depth(&mut inputs, &request)?;
    // Units and emptiness (see `checks`), before any work.
    if let Some(source) = &depth_source {
        match checks::check_depth_units(&inputs.depth, source) {
            Err(e) => problems.push(e),
            Ok(()) => {
                if let Some(w) = checks::kinect_near_warning(&inputs.rig, &inputs.depth, source) {
                    eprintln!("warning: {w}");
                }
            }
        }
    }
    // The overlap test is meaningless on a depth of the wrong unit or a colour image that is
    // not one: one mistake at a time.
    if problems.is_empty()
        && let Err(e) = checks::check_overlap(&inputs.rig, &rig_name, &inputs.depth, inputs.kind)
    {
        problems.push(e);
    }
    for problem in problems {
        if !args.force {
            bail!("{problem}; pass --force if this really is meant");
        }
        eprintln!("warning: {problem} (--force)");
    }
    Ok((inputs, request))
}

/// The request's depth preparation (the rig's `depth_correction`, `kfuse calibrate --depth`,
/// applied before the depth becomes 3D), described in summary.json when it corrects.
fn prepare_depth(inputs: &mut Inputs, request: &Request) -> Result<()> {
    let n = request.prepare_depth(&mut inputs.depth)?;
    if let Some(c) = &request.rig().depth_correction {
        inputs.description["depth_correction"] =
            serde_json::json!({ "applied": true, "samples": n, "terms": c.describe() });
    }
    Ok(())
}

type Loaded = (Inputs, Option<DepthSource>, String);

fn load_files(args: &FuseArgs, problems: &mut Vec<String>) -> Result<Loaded> {
    let (Some(rig_path), Some(color_path), Some(depth_path)) =
        (&args.rig, &args.color, &args.depth)
    else {
        bail!("give --rig, --color and --depth, or --mat (see kfuse fuse --help)");
    };
    let rig = load_rig_for_fuse(rig_path, args.force)?;
    check_beside_capture(&rig, rig_path, depth_path, problems)?;
    if !args.rectified && !rig.rectified {
        problems.extend([color_path, depth_path].into_iter().filter_map(|p| undistorted_note(p)));
    }
    let color = read_color(color_path, &rig, rig_path, problems)?;
    let (depth, source) = read_depth(depth_path, args.depth_scale, &rig, rig_path)?;
    let kind = match args.depth_kind {
        DepthKindArg::Z => DepthKind::Z,
        DepthKindArg::Range => DepthKind::Range,
    };
    let inputs = Inputs {
        description: serde_json::json!({
            "rig": rig_path, "color": color_path, "depth": depth_path,
            "depth_kind": kind, "depth_scale_m_per_unit": args.depth_scale,
        }),
        rig,
        depth,
        kind,
        color,
    };
    Ok((inputs, Some(source), rig_path.display().to_string()))
}

/// `--mat`: the course's `synthdata.mat` or the lab's `KinectData.mat`; `--color` / `--depth`
/// replace the file's images (the handout's `Colour_rect.tif` / `Depth_rect.tif`).
fn load_mat(args: &FuseArgs, mat: &Path, problems: &mut Vec<String>) -> Result<Loaded> {
    let file = MatFile::read(mat)?;
    let name = mat.display().to_string();
    // The file's depth, or why it cannot be used (then --depth must replace it).
    let (rig, color, file_depth, kind, source, mut description) = if kinect_data::is_kinect_data(
        &file,
    ) {
        let kd = kinect_data::kinect_data_from_mat(&file)?;
        // A real Kinect's rig: the same plausibility check as a rig file.
        check_rig(&kd.rig, mat, args.force)?;
        let depth = match kd.depth {
            KinectDepth::Millimetres(d) => Ok(d),
            KinectDepth::Unusable(why) => Err(why),
        };
        let description = serde_json::json!({
            "mat": mat,
            "convention": "KinectData.mat: fx, fy, cx, cy 0-based; X_color = R·X_depth + T, T in mm; Depth = z (mm); no distortion (rectified images)",
        });
        let source = DepthSource::KinectMat { name: name.clone() };
        (kd.rig, kd.color, depth, DepthKind::Z, Some(source), description)
    } else {
        // No plausibility check: the course importers convert known units themselves, and
        // the lab's synthdata.mat has a 1 m baseline by design. Nor a depth-unit check:
        // the file's range is metres by definition (its background lies 18 m away).
        let data = course::course_from_mat(&file, course::CourseConvention::SYNTHDATA)?;
        let description = serde_json::json!({
            "mat": mat,
            "convention": "synthdata.mat: cx, cy 1-based; R, T = colour camera pose in the depth frame; Depth = range (m)",
        });
        (data.rig, data.color, Ok(data.depth), data.depth_kind, None, description)
    };
    let color = match &args.color {
        Some(path) => {
            description["color"] = serde_json::json!(path);
            read_color(path, &rig, mat, problems)?
        }
        None => color,
    };
    let (depth, source) = match (&args.depth, file_depth) {
        (Some(path), _) => {
            description["depth"] = serde_json::json!(path);
            description["depth_scale_m_per_unit"] = serde_json::json!(args.depth_scale);
            check_beside_capture(&rig, mat, path, problems)?;
            let (d, s) = read_depth(path, args.depth_scale, &rig, mat)?;
            (d, Some(s))
        }
        (None, Ok(d)) => (d, source),
        (None, Err(why)) => bail!(
            "{name}: {why}; it cannot be fused: pass the frame's depth image with --depth (16-bit PNG/TIFF in millimetres)"
        ),
    };
    description["depth_kind"] = serde_json::json!(kind);
    Ok((Inputs { rig, depth, kind, color, description }, source, name))
}
