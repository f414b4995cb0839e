//! The error type of the `calib` crate.

use std::path::PathBuf;

/// Everything that can go wrong while detecting boards, calibrating or reading and writing
/// calibration files. Variants name the image or file, the sizes and counts involved, and say
/// how to fix the input where there is a fix.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    /// Fewer usable views than a calibration needs.
    #[error(
        "{camera}: only {usable} usable view(s) with a detected board, at least {needed} are needed{left_out}; add images that show the whole board at different tilts"
    )]
    TooFewViews {
        /// Which camera ("colour", "depth/IR", "stereo pairs").
        camera: String,
        /// Views with a usable board.
        usable: usize,
        /// Views needed.
        needed: usize,
        /// The views left out and why (" (left out: a.png (no board found), …)"), or empty.
        left_out: String,
    },
    /// The board was not found in any image.
    #[error(
        "{camera}: no {cols}x{rows} checkerboard found in any of the {images} image(s); check --board (inner corners, e.g. 7x5) and that the board is visible"
    )]
    NoBoard {
        /// Which camera.
        camera: String,
        /// Images searched.
        images: usize,
        /// Inner corners per row.
        cols: usize,
        /// Inner corners per column.
        rows: usize,
    },
    /// The views do not constrain the focal length: every board is (nearly) parallel to the
    /// image plane.
    #[error(
        "{camera}: degenerate views — the boards are all (nearly) fronto-parallel (largest tilt {max_tilt_deg:.1}°, need ≥ {min_tilt_deg:.0}°); tilt the board 20–45° in several directions"
    )]
    Degenerate {
        /// Which camera.
        camera: String,
        /// Largest board tilt among the views, degrees.
        max_tilt_deg: f64,
        /// Smallest acceptable largest tilt, degrees.
        min_tilt_deg: f64,
    },
    /// A colour/IR pair where only one image shows the board.
    #[error(
        "pair {pair}: the board is found in the {found} image '{found_image}' but not in the {missing} image '{missing_image}'; remove the pair or pass --allow-unpaired to use such images for that camera's intrinsics only"
    )]
    UnpairedView {
        /// The pair's index (0-based) or name.
        pair: String,
        /// Camera that has the board.
        found: String,
        /// Image that has the board.
        found_image: String,
        /// Camera that lacks it.
        missing: String,
        /// Image that lacks it.
        missing_image: String,
    },
    /// The optimisation did not produce finite parameters.
    #[error(
        "{camera}: the optimisation diverged ({message}); check the board size and square length"
    )]
    Diverged {
        /// Which camera.
        camera: String,
        /// What went wrong.
        message: String,
    },
    /// Invalid argument (board size, square length, flags).
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// Bad input to a calibration run (`pipeline`): what is wrong and the fix, in one line
    /// (the message `kfuse calibrate` prints).
    #[error("{0}")]
    Input(String),
    /// An error and what was being done when it happened (`pipeline`); shown as
    /// `context: cause` by whoever walks the sources (as `kfuse` prints every error).
    #[error("{context}")]
    Context {
        /// What was being done, naming the file or option.
        context: String,
        /// What went wrong.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// A file was read but its content is not what was expected.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// Depth calibration (`depth`): not enough views or distance range for a fit.
    #[error(
        "depth calibration: {views} view(s) with the board in the depth image{}; it needs at least {needed} views whose board distances span at least {span_needed:.2} m: take boards at e.g. 0.8, 1.2, 1.8 and 2.5 m, tilted 10–40°, spread over the whole image",
        match range { Some((a, b)) => format!(", at {a:.2}–{b:.2} m (span {:.2} m)", b - a), None => String::new() }
    )]
    DepthData {
        /// Usable views.
        views: usize,
        /// Views needed.
        needed: usize,
        /// Smallest and largest median board distance of the usable views, metres.
        range: Option<(f64, f64)>,
        /// Smallest distance span, metres.
        span_needed: f64,
    },
    /// Depth calibration (`depth`): the fit itself failed.
    #[error("depth calibration: {message}")]
    DepthFit {
        /// What went wrong and what to do.
        message: String,
    },
    /// Depth calibration (`depth`): a fitted scale beyond what a Kinect v2 plausibly has.
    #[error(
        "depth calibration: the fitted depth scale {:+.2} % is beyond the ±{:.0} % a Kinect v2 plausibly has (its time-of-flight scale errors are about ±1 %): the boards' distances are off, not the sensor's{moves}; check --square (the printed square's side) and that the IR intrinsics (--rig, or the images' own calibration) are those of these shots, or pass --force to write it anyway; nothing was written",
        100.0 * scale,
        100.0 * limit
    )]
    ImplausibleDepthScale {
        /// The fitted scale (fraction).
        scale: f64,
        /// The bound (`depth::MAX_PLAUSIBLE_SCALE`).
        limit: f64,
        /// What moves the scale, e.g. " (here each +1 % of the square moves it by −1.00 %, …)",
        /// or empty.
        moves: String,
    },
    /// Joint calibration (`multi`): the cameras' covisibility graph falls apart.
    #[error(
        "the cameras form separate groups that share no board view: {groups}; they need a view of the board in common (take shots in which cameras of both groups see the board at once)"
    )]
    NotConnected {
        /// The groups, e.g. "{a.ir, a.color} and {b.ir}".
        groups: String,
    },
    /// Joint calibration (`multi::input`): a camera's files do not give one view id each.
    #[error("camera {camera}: {message}")]
    ViewIds {
        /// The camera's name.
        camera: String,
        /// Which files, and the fix.
        message: String,
    },
    /// Joint calibration (`multi`): the views two cameras share disagree on their relative pose.
    #[error(
        "cameras {parent} and {camera}: only {agreeing} of their {shared} shared views agree on where {camera} is relative to {parent} (within 50 mm and 3°): one shot number does not show one board pose in both; check that the images of a shot carry the same number in every camera (and are of one session)"
    )]
    ViewsDisagree {
        /// The camera placed by the edge.
        camera: String,
        /// The camera it is placed from.
        parent: String,
        /// The views the two share.
        shared: usize,
        /// Those that agree with the most central one.
        agreeing: usize,
    },
    /// An error of the geometry core (rig file, atomic write).
    #[error(transparent)]
    Geometry(#[from] geometry::GeometryError),
}
