//! `kfuse rig`: import a rig from other tools' files, export it to OpenCV and ROS, show it.
//! A thin layer over `kfuse_io::rig_io`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use kfuse_io::atomic::write_bytes_atomic;
use kfuse_io::rig_io::{self, Calibration, ImportOptions, LengthUnit, Role};

/// Arguments of `kfuse rig`.
#[derive(clap::Args, Debug)]
pub struct RigArgs {
    #[command(subcommand)]
    command: RigCommand,
}

#[derive(clap::Subcommand, Debug)]
enum RigCommand {
    /// Turn another tool's calibration into a kfuse rig (or single-camera) file.
    Import(ImportArgs),
    /// Write a rig or camera file as OpenCV FileStorage YAML, ROS camera_info or iai_kinect2's folder.
    Export(ExportArgs),
    /// Print a rig or camera file with units and sanity checks.
    Show(ShowArgs),
}

/// `kfuse rig import`.
#[derive(clap::Args, Debug)]
#[command(after_help = "SOURCES (recognised from their content):
  Calib_Results_stereo.mat [Calib_Results_left.mat Calib_Results_right.mat]
                       Bouguet stereo result; left = depth/IR, right = colour. The mono files
                       give the image sizes; by default they are read from beside the stereo file.
  Calib_Results_left.mat --camera depth
                       one Bouguet camera -> single-camera file
  KinectData.mat       the lab's file (Dparam, Cparam, R, T in mm; no distortion)
  rig.yml [extrinsics.yml]
                       OpenCV FileStorage YAML: M1 D1 M2 D2 R T (camera 1 = depth); T's unit from
                       its T_units or --t-units; image sizes from image_width_1 ... or --depth-size
  depth.yaml color.yaml
                       a ROS camera_info pair, depth camera first
  DIR | calib_color.yaml calib_ir.yaml calib_pose.yaml [calib_depth.yaml]
                       iai_kinect2's calibration (kinect2_bridge/data/SERIAL/): X_color = R·X_ir + T
                       in metres; no image sizes stored: the Kinect v2's 1920x1080 and 512x424
                       (or --color-size, --depth-size); depthShift (mm added to the depth) becomes
                       the depth correction's offset (offset = -depthShift/1000 m)
  kinect_params.json   the sensor's factory parameters (kfuse capture): the colour camera is
                       fitted to the factory registration; the fit's error is printed

EXAMPLES:
  kfuse rig import ../shared/data/kinect-lab/Calib_Results_stereo.mat --out rig.json
  kfuse rig import caps/kinect_params.json --out rig.json
  kfuse rig import old-caps/kinect_params.json --mirror --out rig.json   # version 1: mirrored images
  kfuse rig import ~/catkin_ws/src/iai_kinect2/kinect2_bridge/data/012526541941 --out rig.json
  kfuse rig import kinect.bag2/ --out rig.json      (a ROS 2 bag: its camera_infos + /tf_static)
  kfuse rig import intrinsics.yml extrinsics.yml --t-units mm --depth-size 512x424 --color-size 1920x1080 --out rig.json")]
pub struct ImportArgs {
    /// The calibration file(s), or iai_kinect2's calibration folder.
    #[arg(required = true, num_args = 1..=4)]
    sources: Vec<PathBuf>,
    /// Output: kfuse rig JSON (single-camera JSON when the source holds one camera).
    #[arg(long)]
    out: PathBuf,
    /// Replace --out when it exists (without it an existing file is refused, never replaced).
    #[arg(long)]
    overwrite: bool,
    /// Write the rig even when it fails the plausibility checks (focal lengths 50-20000 px,
    /// image sides up to 16384 px, baseline up to 0.5 m), with a warning.
    #[arg(long)]
    force: bool,
    /// Unit of T in OpenCV files that do not say (m or mm).
    #[arg(long, value_parser = ["m", "mm"])]
    t_units: Option<String>,
    /// Depth camera image size (WxH) for files that do not store it.
    #[arg(long, value_parser = parse_size)]
    depth_size: Option<(usize, usize)>,
    /// Colour camera image size (WxH) for files that do not store it.
    #[arg(long, value_parser = parse_size)]
    color_size: Option<(usize, usize)>,
    /// Which camera a single-camera source is.
    #[arg(long, value_parser = ["depth", "color"])]
    camera: Option<String>,
    /// The calibration was made on images mirrored left-right (raw libfreenect2 output, or
    /// `kfuse capture` folders older than kinect_params.json version 2: their colour camera
    /// sits at x = −52 mm of the IR camera, in images as the scene is, kfuse's rule, at
    /// +52 mm): write the rig of the unmirrored images (cx → width − 1 − cx, skew and p2
    /// negated, R → M·R·M and T → M·T with M = diag(−1, 1, 1)). Accepts a kfuse rig too.
    #[arg(long)]
    mirror: bool,
    /// A bag's depth topic, whose camera_info is the depth camera (by default the one depth
    /// Image topic, as `kfuse fuse --recording BAG` chooses it).
    #[arg(long, value_name = "TOPIC")]
    depth_topic: Option<String>,
    /// A bag's colour topic, whose camera_info is the colour camera.
    #[arg(long, value_name = "TOPIC")]
    color_topic: Option<String>,
}

/// `kfuse rig import BAG`: the rig of a ROS 2 bag's camera_infos and `/tf_static`.
fn import_bag(a: &ImportArgs) -> Result<rig_io::Imported> {
    let topics = kfuse_sequence::bag::TopicChoice {
        depth: a.depth_topic.clone(),
        color: a.color_topic.clone(),
    };
    let rig = kfuse_sequence::bag::rig_from_bag(&a.sources[0], &topics)?;
    Ok(rig_io::Imported {
        calibration: Calibration::Rig(rig),
        source: "ROS 2 bag (camera_info + /tf_static)".into(),
        notes: vec![
            "the depth and colour topics' camera_info (K, D; R and P as a pair), the pose from /tf_static (metres)".into(),
        ],
    })
}

/// `kfuse rig export`.
#[derive(clap::Args, Debug)]
#[command(after_help = "EXAMPLES:
  kfuse rig export rig.json --format opencv --out rig.yml
  kfuse rig export rig.json --format ros --out ros/   (writes ros/depth.yaml and ros/color.yaml)
  kfuse rig export ir.json --format ros --out ros/    (a single-camera file: ros/depth.yaml)
  kfuse rig export rig.json --format iai-kinect2 --out kinect2_bridge/data/012526541941/
  kfuse rig export rig3.json --format opencv --out opencv/    (a rig of several cameras: one file per camera)
  kfuse rig export rig3.json --sensor 012526541941 --format kfuse --out pair.json
                                                              (one Kinect's depth + colour pair)

OpenCV: stereoCalibrate's names (M1, D1 = depth, M2, D2 = colour, R, T with X_2 = R·X_1 + T),
T in metres (T_units: m). ROS: one camera_info per camera; the pair's R and P encode the
extrinsics (ROS convention, metres), so importing the pair gives the rig back.
iai-kinect2: the four files kinect2_bridge reads (calib_color.yaml, calib_ir.yaml, calib_pose.yaml,
calib_depth.yaml); the rig must be of the Kinect v2's image sizes and of unmirrored images as
kinect2_bridge publishes them (colour camera at about +52 mm of the IR camera); the rig is written
as it is. depthShift = -1000 x the depth correction's offset; a correction with other terms is
refused unless --depth-offset-only. kfuse: the kfuse rig file itself (with --sensor: that sensor's
pair as a two-camera rig, which every single-Kinect command reads).

A rig of several cameras (`kfuse calibrate --camera ...`, version 2): opencv writes NAME.yml per
camera into the --out folder (camera_matrix, distortion_coefficients, and R, T with
X_camera = R·X_reference + T in metres); ros writes NAME.yaml (camera_info) per camera and
transforms.yaml (each camera's pose in the reference frame for tf static_transform_publisher);
iai-kinect2 needs --sensor (it holds one Kinect). --sensor SERIAL exports that sensor's depth +
colour pair in any format.")]
pub struct ExportArgs {
    /// Rig file, or single-camera file (`kfuse calibrate --ir … --out ir.json`).
    rig: PathBuf,
    /// Output format.
    #[arg(long, value_parser = ["opencv", "ros", "iai-kinect2", "kfuse"])]
    format: String,
    /// A rig of several cameras: export only this sensor's depth + colour pair (its serial
    /// number, as `kfuse rig show` lists the sensors).
    #[arg(long)]
    sensor: Option<String>,
    /// Output file (opencv) or folder (ros, iai-kinect2).
    #[arg(long)]
    out: PathBuf,
    /// iai-kinect2: write only the offset of a depth correction that has other terms too
    /// (calib_depth.yaml's depthShift holds one offset; kinect2_bridge then corrects only it).
    #[arg(long)]
    depth_offset_only: bool,
    /// Replace the output file(s) when they exist (without it an existing file is refused,
    /// never replaced).
    #[arg(long)]
    overwrite: bool,
}

/// Refuses, before anything is written, an output file that exists when `--overwrite` was not
/// given: `rig import`/`export` once replaced a user's file of the same name without a word.
/// Writes the files of one export into `folder` (created if missing) together or not at all:
/// every file goes to its temporary sibling first and all are renamed in at the end, so a full
/// disk or any failure midway leaves none of them (and no folder this call created), never
/// one of iai_kinect2's four files beside stale others.
fn write_together<'a>(
    folder: &Path,
    files: impl Iterator<Item = (&'a PathBuf, &'a String)>,
    what: &str,
) -> Result<()> {
    let created = !folder.exists();
    std::fs::create_dir_all(folder).with_context(|| format!("creating {}", folder.display()))?;
    let mut staged = kfuse_io::atomic::StagedFiles::new();
    let mut written = Vec::new();
    let result = files
        .map(|(p, text)| {
            written.push(p.clone());
            staged.add(p, text.as_bytes())
        })
        .collect::<Result<Vec<()>, _>>()
        .and_then(|_| staged.commit());
    if let Err(e) = result {
        if created {
            // Only this call's own (now empty) folder: remove_dir refuses anything else.
            let _ = std::fs::remove_dir(folder);
        }
        return Err(e.into());
    }
    for p in written {
        println!("wrote {} ({what})", p.display());
    }
    Ok(())
}

fn check_new(path: &Path, overwrite: bool) -> Result<()> {
    if path.is_dir() {
        bail!("{}: is a folder; give a file name such as rig.json", path.display());
    }
    if path.exists() && !overwrite {
        bail!(
            "{}: exists; pass --overwrite to replace it, or give another file name",
            path.display()
        );
    }
    kfuse_io::atomic::writable_target(path)?;
    Ok(())
}

/// Refuses, even with `--overwrite`, an output that is one of the inputs or another tool's
/// calibration that an import reads (a MATLAB file: a Bouguet stereo import reads the mono
/// results beside it): `rig import … --out Calib_Results_left.mat --overwrite` replaced the
/// toolbox's file with JSON of the same name, and every later import failed.
fn check_not_input(out: &Path, inputs: &[PathBuf]) -> Result<()> {
    let same = |a: &Path, b: &Path| match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    if let Some(input) = inputs.iter().find(|i| same(i, out)) {
        bail!(
            "--out {} is one of the input files ({}); give a new file name such as rig.json",
            out.display(),
            input.display()
        );
    }
    let mut head = [0u8; 6];
    let is_mat = bounded_read::open_without_blocking(out)
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut head))
        .is_ok()
        && &head == b"MATLAB";
    if is_mat {
        bail!(
            "--out {}: is a MATLAB file (a calibration kfuse reads, not one it writes); give a new file name such as rig.json",
            out.display()
        );
    }
    Ok(())
}

/// `kfuse rig show`.
#[derive(clap::Args, Debug)]
pub struct ShowArgs {
    /// Rig file, or single-camera file.
    rig: PathBuf,
}

fn parse_size(s: &str) -> Result<(usize, usize), String> {
    let bad = || format!("'{s}' is not WIDTHxHEIGHT (e.g. 512x424)");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let w: usize = w.trim().parse().map_err(|_| bad())?;
    let h: usize = h.trim().parse().map_err(|_| bad())?;
    if w == 0 || h == 0 || w > 65_536 || h > 65_536 {
        return Err(format!("'{s}': sides must be 1..=65536"));
    }
    Ok((w, h))
}

/// Runs the command.
pub fn run(args: RigArgs) -> Result<()> {
    match args.command {
        RigCommand::Import(a) => import(a),
        RigCommand::Export(a) => export(a),
        RigCommand::Show(a) => show(&a.rig),
    }
}

fn import(a: ImportArgs) -> Result<()> {
    let opts = ImportOptions {
        t_units: a.t_units.as_deref().and_then(LengthUnit::parse),
        depth_size: a.depth_size,
        color_size: a.color_size,
        role: a.camera.as_deref().and_then(Role::parse),
    };
    check_not_input(&a.out, &a.sources)?;
    check_new(&a.out, a.overwrite)?;
    let is_bag = matches!(a.sources.as_slice(), [one] if kfuse_sequence::bag::is_bag(one));
    if !is_bag && (a.depth_topic.is_some() || a.color_topic.is_some()) {
        bail!(
            "--depth-topic / --color-topic: the source is not a bag (a rosbag2 folder or .mcap file)"
        );
    }
    let mut imported = if is_bag { import_bag(&a)? } else { rig_io::import(&a.sources, &opts)? };
    if a.mirror {
        imported.calibration = mirrored(imported.calibration, &a.sources[0]);
        imported.notes.push("mirrored left-right (--mirror)".into());
    }
    match &imported.calibration {
        Calibration::Rig(rig) => match rig_io::show::kinect_orientation(rig) {
            // --mirror of a rig that already was of images as the scene is.
            Some((true, _)) if a.mirror => imported.notes.push(format!(
                "--mirror turned a rig of images as the scene is (kfuse's orientation) into one of mirrored images (colour camera now at x = {:+.1} mm): to fuse kfuse captures, import {} without --mirror",
                rig.color_centre_in_depth().x * 1000.0,
                a.sources[0].display()
            )),
            Some((true, note)) => imported.notes.push(note),
            _ => {}
        },
        Calibration::Camera { camera, role: Some(role), .. } => {
            imported.notes.extend(rig_io::show::kinect_role_mismatch(camera, *role));
        }
        Calibration::Camera { .. } => {}
    }
    let problems = imported.calibration.plausibility_problems();
    if !problems.is_empty() {
        if !a.force {
            anyhow::bail!(
                "{}: {} (pass --force to import it anyway)",
                a.sources[0].display(),
                problems.join("; ")
            );
        }
        for p in problems {
            eprintln!("warning: {}: {p} (--force)", a.sources[0].display());
        }
    }
    let text = imported.calibration.to_json();
    write_bytes_atomic(&a.out, text.as_bytes())?;
    let what = match &imported.calibration {
        Calibration::Rig(_) => "rig".to_string(),
        Calibration::Camera { role, .. } => {
            format!("single-camera file ({})", role.map(|r| r.name()).unwrap_or("camera"))
        }
    };
    println!("imported {} → {what} {}", imported.source, a.out.display());
    for n in &imported.notes {
        println!("  note: {n}");
    }
    println!("check it with: kfuse rig show {}", a.out.display());
    Ok(())
}

/// The calibration for images mirrored left-right; the source's report (image coordinates of
/// the other orientation) is replaced by a note of where it came from.
fn mirrored(calibration: Calibration, source: &Path) -> Calibration {
    let note = serde_json::json!({
        "mirrored_from": source.display().to_string(),
        "note": "kfuse rig import --mirror: the source's calibration of images mirrored left-right, converted (its report refers to the mirrored images and is not kept)",
    });
    match calibration {
        Calibration::Rig(rig) => {
            let mut m = rig.mirrored();
            m.calibration = Some(note);
            Calibration::Rig(m)
        }
        Calibration::Camera { camera, role, .. } => {
            Calibration::Camera { camera: camera.mirrored(), role, report: Some(note) }
        }
    }
}

fn export(a: ExportArgs) -> Result<()> {
    check_not_input(&a.out, std::slice::from_ref(&a.rig))?;
    let cal = match (kfuse_io::rig::read_rig(&a.rig)?, &a.sensor) {
        (rig_io::AnyRig::Multi(multi), None) => return export_multi(&a, &multi),
        (rig_io::AnyRig::Multi(multi), Some(sensor)) => Calibration::Rig(
            multi.sensor_rig(sensor).map_err(|e| anyhow::anyhow!("{}: {e}", a.rig.display()))?.0,
        ),
        (rig_io::AnyRig::Single(_), Some(_)) => bail!(
            "{}: is not a rig of several cameras; --sensor picks one sensor's pair from one (leave it out)",
            a.rig.display()
        ),
        (rig_io::AnyRig::Single(cal), None) => *cal,
    };
    match (a.format.as_str(), &cal) {
        ("kfuse", cal) => {
            check_new(&a.out, a.overwrite)?;
            write_bytes_atomic(&a.out, cal.to_json().as_bytes())?;
            println!("wrote {} (kfuse rig file)", a.out.display());
        }
        ("opencv", Calibration::Rig(rig)) => {
            check_new(&a.out, a.overwrite)?;
            write_bytes_atomic(&a.out, kfuse_io::rig_io::opencv::opencv_yaml_rig(rig).as_bytes())?;
            println!("wrote {} (OpenCV FileStorage YAML, T in metres)", a.out.display());
        }
        ("opencv", Calibration::Camera { camera, .. }) => {
            check_new(&a.out, a.overwrite)?;
            write_bytes_atomic(
                &a.out,
                kfuse_io::rig_io::opencv::opencv_yaml_camera(camera).as_bytes(),
            )?;
            println!("wrote {} (OpenCV FileStorage YAML, one camera)", a.out.display());
        }
        ("iai-kinect2", Calibration::Camera { .. }) => bail!(
            "{}: is a single-camera file; --format iai-kinect2 writes both cameras and their pose (give a rig file)",
            a.rig.display()
        ),
        ("iai-kinect2", Calibration::Rig(rig)) => {
            if a.out.is_file() {
                bail!(
                    "{}: is a file; --format iai-kinect2 writes its four files into a folder",
                    a.out.display()
                );
            }
            let opts = rig_io::iai::ExportOptions { depth_offset_only: a.depth_offset_only };
            let files = rig_io::iai::export(rig, opts, &a.rig)?;
            let paths: Vec<PathBuf> = files.iter().map(|(name, _)| a.out.join(name)).collect();
            for p in &paths {
                check_new(p, a.overwrite)?;
            }
            write_together(&a.out, paths.iter().zip(files.iter().map(|(_, t)| t)), "iai_kinect2")?;
        }
        ("ros", cal) => {
            if a.out.is_file() {
                bail!(
                    "{}: is a file; --format ros writes one file per camera into a folder",
                    a.out.display()
                );
            }
            let files: Vec<(PathBuf, String)> = match cal {
                Calibration::Rig(rig) => {
                    let (d, c) = rig_io::ros::rig_yaml(rig);
                    vec![(a.out.join("depth.yaml"), d), (a.out.join("color.yaml"), c)]
                }
                Calibration::Camera { camera, role, .. } => {
                    let name = role.map(|r| r.name()).unwrap_or("camera");
                    let text = rig_io::ros::camera_info_yaml(
                        name,
                        camera,
                        &nalgebra::Matrix3::identity(),
                        &nalgebra::Vector3::zeros(),
                    );
                    vec![(a.out.join(format!("{name}.yaml")), text)]
                }
            };
            for (p, _) in &files {
                check_new(p, a.overwrite)?;
            }
            write_together(&a.out, files.iter().map(|(p, t)| (p, t)), "ROS camera_info")?;
        }
        (f, _) => bail!("unknown format '{f}'"),
    }
    Ok(())
}

/// A file name made of a camera's name: characters other than letters, digits, `.`, `-` and
/// `_` become `_`, so a name cannot leave the output folder.
fn file_stem(name: &str) -> String {
    name.chars()
        .map(|c| if c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_') { c } else { '_' })
        .collect::<String>()
        .trim_start_matches('.')
        .to_string()
}

/// `rig export` of a rig of several cameras (no `--sensor`): one file per camera into a folder.
fn export_multi(a: &ExportArgs, rig: &geometry::MultiRig) -> Result<()> {
    let mut files: Vec<(PathBuf, String)> = Vec::new();
    let into_folder = |files: &mut Vec<(PathBuf, String)>,
                       ext: &str,
                       text: &dyn Fn(&geometry::RigCamera) -> String|
     -> Result<()> {
        if a.out.is_file() {
            bail!(
                "{}: is a file; a rig of {} cameras is exported as one file per camera into a folder",
                a.out.display(),
                rig.cameras.len()
            );
        }
        for c in &rig.cameras {
            let path = a.out.join(format!("{}.{ext}", file_stem(&c.name)));
            if files.iter().any(|(p, _)| *p == path) {
                bail!(
                    "{}: two cameras give the file name {}; rename one in the rig",
                    a.rig.display(),
                    path.display()
                );
            }
            files.push((path, text(c)));
        }
        Ok(())
    };
    let what = match a.format.as_str() {
        "kfuse" => {
            files.push((a.out.clone(), rig.to_json()));
            "kfuse rig file"
        }
        "opencv" => {
            into_folder(&mut files, "yml", &|c| {
                kfuse_io::rig_io::opencv::opencv_yaml_rig_camera(c, &rig.reference)
            })?;
            "OpenCV FileStorage YAML, R and T from the reference camera, metres"
        }
        "ros" => {
            into_folder(&mut files, "yaml", &|c| {
                rig_io::ros::camera_info_yaml(
                    &c.name,
                    &c.model,
                    &nalgebra::Matrix3::identity(),
                    &nalgebra::Vector3::zeros(),
                )
            })?;
            files.push((a.out.join("transforms.yaml"), rig_io::ros::rig_static_transforms(rig)));
            "ROS camera_info; poses in transforms.yaml"
        }
        "iai-kinect2" => bail!(
            "{}: is a rig of {} cameras; iai_kinect2's folder holds one Kinect: pass --sensor SERIAL (its sensors: {})",
            a.rig.display(),
            rig.cameras.len(),
            rig.sensors().join(", ")
        ),
        f => bail!("unknown format '{f}'"),
    };
    for (p, _) in &files {
        check_new(p, a.overwrite)?;
    }
    if a.format != "kfuse" {
        return write_together(&a.out, files.iter().map(|(p, t)| (p, t)), what);
    }
    for (p, t) in &files {
        write_bytes_atomic(p, t.as_bytes())?;
        println!("wrote {} ({what})", p.display());
    }
    Ok(())
}

fn show(path: &Path) -> Result<()> {
    let name = path.display().to_string();
    let (text, warnings) = match kfuse_io::rig::read_rig(path)? {
        rig_io::AnyRig::Multi(multi) => rig_io::show::describe_multi(&name, &multi),
        rig_io::AnyRig::Single(cal) => rig_io::show::describe(&name, &cal),
    };
    print!("{text}");
    if warnings > 0 {
        println!(
            "{warnings} warning(s): check the values marked WARN against the source calibration"
        );
    }
    Ok(())
}
