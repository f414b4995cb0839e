//! The whole run of `kfuse calibrate` as library calls, for the command line and the Python
//! package alike: the images of one or two cameras (files or in memory) → detection (the
//! board's size found with `--board auto`) → the checks between the two cameras → the mono or
//! stereo fit with σ → the held-out check → the depth correction (`--depth`) → the output
//! file's text, `report.json` and where the time went.
//!
//! One module per stage: [`inputs`] (board, patterns, checks before any work), [`detect`]
//! (reading and detection of one camera), [`fit`] (the fits and their files), [`depth`] (the
//! depth correction). Nothing here prints, draws or writes: what a user is told goes to an
//! [`Observer`] as [`Event`]s in the order `kfuse calibrate` prints them, progress through
//! its `progress_*` methods; the caller writes the outputs and the figures.
//!
//! ```text
//! prepare(Request) ─▶ Prepared::inputs() (the caller checks its outputs) ─▶ Prepared::run ─▶ Outcome
//! ```

pub mod depth;
mod detect;
pub mod fit;
pub mod inputs;
pub mod joint;

use std::path::PathBuf;

use geometry::timing::Timings;
use geometry::{CameraModel, Image, Rig};

use crate::depth::DepthFit;
use crate::detect::Refinement;
use crate::files::{COLOR_RMS_LIMIT_PX, DEPTH_RMS_LIMIT_PX, opencv_yaml_camera, opencv_yaml_rig};
use crate::holdout::HoldOut;
use crate::io::ImageTiming;
use crate::{Board, CalibError, CalibFlags, MonoCalibration, StereoCalibration, ViewCorners};

pub use inputs::{expand, expand_all, parse_board, square_of_metres};

/// One camera's images, in pairing order.
#[derive(Debug, Clone, Default)]
pub struct CameraImages {
    /// The image files; for images given in memory, their names (for the tables).
    pub files: Vec<PathBuf>,
    /// Images already decoded to 8-bit grey, one per `files` entry; `None`: `files` are read
    /// as `kfuse calibrate` reads them ([`crate::io::read_gray`]).
    pub decoded: Option<Vec<Image<u8>>>,
}

impl CameraImages {
    /// Image files, read by the run.
    pub fn files(files: Vec<PathBuf>) -> Self {
        Self { files, decoded: None }
    }

    /// Images in memory with their names.
    pub fn in_memory(named: Vec<(String, Image<u8>)>) -> Self {
        let (names, images): (Vec<String>, Vec<Image<u8>>) = named.into_iter().unzip();
        Self { files: names.into_iter().map(PathBuf::from).collect(), decoded: Some(images) }
    }

    /// The number of images.
    pub fn len(&self) -> usize {
        self.files.len()
    }

    /// True without images.
    pub fn is_empty(&self) -> bool {
        self.files.is_empty()
    }
}

/// How the fits run (`kfuse calibrate`'s flags).
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Constraint flags and outlier rejection of every fit.
    pub flags: CalibFlags,
    /// Stereo: keep each camera's single-camera intrinsics (`--fix-intrinsics`).
    pub fix_intrinsics: bool,
    /// Use pairs where only one image shows the board (`--allow-unpaired`).
    pub allow_unpaired: bool,
    /// The final sub-pixel corner estimator (`--corners`).
    pub refinement: Refinement,
    /// Write an implausible depth scale with a warning (`--force`, with depth images only).
    pub force: bool,
    /// Make the held-out check (`kfuse calibrate` does with `--report`).
    pub held_out: bool,
}

impl Default for Options {
    /// `kfuse calibrate`'s defaults (the held-out check off, as without `--report`).
    fn default() -> Self {
        Self {
            flags: CalibFlags::default(),
            fix_intrinsics: false,
            allow_unpaired: false,
            refinement: Refinement::JunctionFit,
            force: false,
            held_out: false,
        }
    }
}

/// What a run is given.
#[derive(Debug, Clone)]
pub struct Request {
    /// The IR (depth) camera's images.
    pub ir: CameraImages,
    /// The colour camera's images.
    pub color: CameraImages,
    /// Depth images (16-bit, mm) of the IR shots, matched with `ir` in order: fits the depth
    /// correction.
    pub depth: Vec<PathBuf>,
    /// With `depth` and `ir` only: the rig the correction is added to (`--rig`).
    pub rig: Option<PathBuf>,
    /// The board ([`parse_board`]); its `top_left_black` is the user's (`None`: found).
    pub board: Board,
    /// Find the board's size from the images (`--board auto`).
    pub auto_board: bool,
    /// How the fits run.
    pub options: Options,
}

/// What a run tells its user, in the order `kfuse calibrate` prints it.
#[derive(Debug)]
pub enum Event<'a> {
    /// A warning about the inputs, one line (e.g. images of the other camera's size).
    Warning(&'a str),
    /// The board is about to be detected in this many readable images of `camera`.
    Detecting {
        /// "IR" or "colour".
        camera: &'a str,
        /// Readable images.
        images: usize,
    },
    /// `--board auto` chose this size.
    BoardAuto {
        /// "IR" or "colour".
        camera: &'a str,
        /// Images the board was found in with that size.
        with_board: usize,
        /// Readable images.
        images: usize,
        /// Inner corners per row.
        cols: usize,
        /// Inner corners per column.
        rows: usize,
    },
    /// An image that cannot be read is left out (the run goes on).
    Unreadable {
        /// The image.
        path: &'a std::path::Path,
        /// Why, without the path.
        why: &'a str,
    },
    /// One camera's fit.
    Mono {
        /// "IR camera" or "colour camera".
        camera: &'a str,
        /// The fit.
        fit: &'a MonoCalibration,
        /// The handout's RMS bar of that camera, px.
        limit_px: f64,
    },
    /// The stereo fit.
    Stereo {
        /// The fit.
        fit: &'a StereoCalibration,
        /// The IR views (their names name the pairs).
        ir_views: &'a [ViewCorners],
    },
    /// A problem of the stereo rig that `kfuse fuse` refuses without `--force`.
    RigWarning(&'a str),
    /// The held-out check (or why it was not made).
    HeldOut(&'a Result<HoldOut, CalibError>),
    /// A depth view without a board pose, left out of the depth fit.
    DepthNoPose {
        /// The depth image's name.
        name: &'a str,
        /// Why.
        why: &'a str,
    },
    /// An implausible depth scale written anyway (`force`): the refusal's text.
    DepthForced(&'a str),
    /// The depth fit (also just before an implausible scale is refused).
    DepthFit(&'a DepthFit),
}

/// Who follows a run: progress of its long stages and its [`Event`]s. Every method has a
/// default that ignores it. Called from the run's thread, `progress_step` also from rayon's
/// pool.
pub trait Observer: Send + Sync {
    /// A stage of `len` steps starts ("reading IR", "detecting colour").
    fn progress_start(&self, _label: &str, _len: usize) {}
    /// One step of the current stage is done.
    fn progress_step(&self) {}
    /// The current stage is done.
    fn progress_end(&self) {}
    /// Something to tell the user.
    fn event(&self, _event: Event<'_>) {}
}

/// An observer that ignores everything.
#[derive(Debug, Default, Clone, Copy)]
pub struct Quiet;

impl Observer for Quiet {}

/// A request whose inputs passed the checks made before any work.
#[derive(Debug)]
pub struct Prepared {
    req: Request,
    base_rig: Option<Rig>,
}

/// Checks `req` before any work: images given, the depth inputs against the others, `--force`
/// only with depth images, the rig of `--rig` read, the two cameras not swapped (a warning
/// goes to `obs` for one camera of the other's size), as many images of each camera.
pub fn prepare(req: Request, obs: &dyn Observer) -> Result<Prepared, CalibError> {
    if req.ir.is_empty() && req.color.is_empty() {
        return Err(CalibError::Input(inputs::NO_IMAGES.into()));
    }
    depth::check_args(req.ir.len(), req.color.len(), req.depth.len(), req.rig.as_deref())?;
    if req.options.force && req.depth.is_empty() {
        return Err(CalibError::Input(
            "--force only lets --depth write an implausible depth scale; without --depth there is nothing it applies to: leave it out".into(),
        ));
    }
    let base_rig = req.rig.as_deref().map(depth::load_base_rig).transpose()?;
    inputs::check_not_swapped(&req.ir, &req.color, obs)?;
    let (ir, color) = (req.ir.len(), req.color.len());
    if ir != 0 && color != 0 && ir != color {
        return Err(CalibError::Input(format!(
            "{color} colour images but {ir} IR images: stereo needs one image of each camera per board pose (pairs are matched in sorted order)"
        )));
    }
    Ok(Prepared { req, base_rig })
}

/// One camera's images after detection.
#[derive(Debug, Clone, Default)]
pub struct CameraRun {
    /// The files (names for images given in memory), as given.
    pub files: Vec<PathBuf>,
    /// True when the images were given in memory (`files` are names, not files).
    pub in_memory: bool,
    /// Each image as 8-bit grey, `None` where it could not be read.
    pub images: Vec<Option<Image<u8>>>,
    /// Each image's detection (a colour view aligned with its IR pair's corner order), an
    /// unreadable image a view that cannot be used, with the reason.
    pub views: Vec<ViewCorners>,
}

impl CameraRun {
    /// The readable images with their files and detections (the report's figures).
    pub fn with_images(&self) -> Vec<(&std::path::Path, &Image<u8>, &ViewCorners)> {
        self.files
            .iter()
            .zip(&self.images)
            .zip(&self.views)
            .filter_map(|((f, i), v)| Some((f.as_path(), i.as_ref()?, v)))
            .collect()
    }
}

/// Which fit a run made.
#[derive(Debug)]
pub enum Fit {
    /// IR and colour images: both cameras and their pose.
    Stereo(Box<StereoCalibration>),
    /// One camera's images.
    Mono {
        /// "IR" or "colour".
        camera: &'static str,
        /// The fit.
        fit: Box<MonoCalibration>,
    },
    /// Depth images with a given rig: only the depth correction.
    DepthOnly,
}

/// What a run gives.
#[derive(Debug)]
pub struct Outcome {
    /// The board (its size found with `--board auto`).
    pub board: Board,
    /// The fit: σ of every parameter, per-view RMS, rejected views and corners with reasons.
    pub fit: Fit,
    /// The rig (stereo, or the given rig with its new depth correction); `None` for one
    /// camera.
    pub rig: Option<Rig>,
    /// The output file's text (`--out`): the rig JSON, or the single-camera JSON.
    pub text: String,
    /// `report.json` less its `timings_ms`: the calibration section, `held_out`,
    /// `depth_correction`.
    pub report: serde_json::Value,
    /// The held-out check, where it was made.
    pub held_out: Option<Result<HoldOut, CalibError>>,
    /// The depth correction's fit, where depth images were given.
    pub depth_fit: Option<DepthFit>,
    /// The IR camera's images and views (empty without IR images).
    pub ir: CameraRun,
    /// The colour camera's images and views (empty without colour images).
    pub color: CameraRun,
    /// The run's stages (`crate::timing`), in the order they ran.
    pub timings: Timings,
    /// Every image's read and detection time.
    pub image_times: Vec<ImageTiming>,
}

impl Outcome {
    /// The OpenCV FileStorage YAML of the calibration (`--opencv-yaml`): the rig's, or the
    /// camera's; `None` when only a depth correction was fitted.
    pub fn opencv_yaml(&self) -> Option<String> {
        match (&self.fit, &self.rig) {
            (Fit::Stereo(_), Some(rig)) => Some(opencv_yaml_rig(rig)),
            (Fit::Mono { fit, .. }, _) => Some(opencv_yaml_camera(&fit.camera)),
            _ => None,
        }
    }

    /// Each calibrated camera for the report: (name, final camera, its single-camera fit with
    /// per-view data, the handout's RMS bar in px).
    pub fn cameras(&self) -> Vec<(&'static str, CameraModel, MonoCalibration, f64)> {
        match &self.fit {
            Fit::Stereo(s) => vec![
                ("IR", s.depth, s.depth_mono.clone(), DEPTH_RMS_LIMIT_PX),
                ("colour", s.color, s.color_mono.clone(), COLOR_RMS_LIMIT_PX),
            ],
            Fit::Mono { camera, fit } => {
                let limit = if *camera == "IR" { DEPTH_RMS_LIMIT_PX } else { COLOR_RMS_LIMIT_PX };
                vec![(*camera, fit.camera, (**fit).clone(), limit)]
            }
            Fit::DepthOnly => vec![],
        }
    }
}

impl Prepared {
    /// Every input file (colour, IR, depth), for checking that no output is one of them.
    pub fn inputs(&self) -> impl Iterator<Item = &PathBuf> + Clone {
        fn file(c: &CameraImages) -> &[PathBuf] {
            if c.decoded.is_some() { &[] } else { &c.files }
        }
        file(&self.req.color).iter().chain(file(&self.req.ir)).chain(&self.req.depth)
    }

    /// The run: detection in the IR images, then the colour images (with `--board auto` the
    /// IR images fix the size; one board shows both cameras the same colouring), then the
    /// fits. Writes nothing; tells `obs` what it does.
    pub fn run(self, obs: &dyn Observer) -> Result<Outcome, CalibError> {
        let Prepared { req, base_rig } = self;
        let options = req.options;
        let (mut timings, mut image_times) = (Timings::new(), Vec::new());
        let mut detect = |input: &CameraImages, board: Board, auto: bool, camera: &str| {
            if input.is_empty() {
                return Ok((CameraRun::default(), board));
            }
            let d = detect::load_and_detect(input, &board, auto, camera, options.refinement, obs)?;
            timings.extend("", &d.timings);
            image_times.extend(d.image_times);
            let run = CameraRun {
                files: input.files.clone(),
                in_memory: input.decoded.is_some(),
                images: d.images,
                views: d.views,
            };
            Ok::<_, CalibError>((run, d.board))
        };
        let (ir, board) = detect(&req.ir, req.board, req.auto_board, "IR")?;
        // With --board auto and IR images, the IR images already fixed the size. The colouring
        // (where the board's own colours decide it) is found from the colour images too and
        // compared: one board shows the same colouring to both cameras.
        let ir_colouring = board.top_left_black;
        let color_board = Board {
            top_left_black: board.top_left_black.filter(|_| req.board.top_left_black.is_some()),
            ..board
        };
        let auto_color = req.auto_board && req.ir.is_empty();
        let (mut color, color_board) = detect(&req.color, color_board, auto_color, "colour")?;
        let board = if req.color.is_empty() {
            board
        } else {
            if !ir.views.is_empty() {
                let mut colouring = detect::Colouring::default();
                colouring.agree("IR", ir_colouring, &board)?;
                colouring.agree("colour", color_board.top_left_black, &board)?;
            }
            if ir_colouring.is_some() { board } else { color_board }
        };
        let depth = (!req.depth.is_empty()).then(|| fit::DepthInput {
            files: &req.depth,
            ir: &ir,
            force: options.force,
        });
        let fitted = if !req.ir.is_empty() && !req.color.is_empty() {
            fit::stereo(&board, &ir, &mut color, depth, &options, &mut timings, obs)?
        } else if let (Some(rig), Some(depth)) = (base_rig, depth) {
            fit::depth_only(rig, &board, depth, &options, &mut timings, obs)?
        } else {
            fit::mono(&board, &ir, &color, &options, &mut timings, obs)?
        };
        Ok(Outcome {
            board,
            fit: fitted.fit,
            rig: fitted.rig,
            text: fitted.text,
            report: fitted.report,
            held_out: fitted.held_out,
            depth_fit: fitted.depth_fit,
            ir,
            color,
            timings,
            image_times,
        })
    }
}
