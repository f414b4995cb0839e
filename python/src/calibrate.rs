//! `kfuse.calibrate(...)`: checkerboard images of the IR and/or colour camera through
//! `calib::pipeline`, the run `kfuse calibrate` makes (`prepare(request)?.run(observer)?`),
//! and its `Outcome` as a `Calibration`: the rig, each camera's fit with σ, per-view errors,
//! rejected views with their reasons, report.json's content and the output file's text. This
//! module only turns Python arguments into the pipeline's `Request` (as
//! `src/cmd_calibrate.rs` turns the CLI's flags into it) and the outcome into Python values.

use std::path::PathBuf;
use std::sync::Mutex;
use std::sync::mpsc;
use std::time::Duration;

use calib::pipeline::{
    self, CameraImages, Event, Fit, Observer, Options, Outcome, Request, parse_board,
    square_of_metres,
};
use calib::{Board, IntrinsicsStd, MonoCalibration};
use geometry::{CameraModel, Image, Rig};
use numpy::ndarray::{Array1, Array2};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::{PyFileNotFoundError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyList, PyTuple};

use crate::{PyCamera, PyRig, bad_array, calib_err, describe, geometry_err};

/// `--square`'s default: the side of the board `kfuse calibrate` assumes without `--square`.
const DEFAULT_SQUARE: &str = "40mm";

/// How often a waiting `calibrate` looks for Ctrl-C (the run goes on on its own thread).
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// One camera's images from a Python argument (`what` is "ir" or "color"): `None` (no
/// images), a glob pattern or file (expanded and naturally sorted as `--ir`/`--color`
/// expand theirs), or a list of image files or of uint8 (H, W) arrays, kept in list order.
fn camera_images(obj: Option<&Bound<'_, PyAny>>, what: &str) -> PyResult<CameraImages> {
    let Some(obj) = obj else { return Ok(CameraImages::default()) };
    if !(obj.is_instance_of::<PyList>() || obj.is_instance_of::<PyTuple>()) {
        let Ok(pattern) = obj.extract::<PathBuf>() else {
            return Err(PyValueError::new_err(format!(
                "{what}: expected a list of image files or of uint8 (H, W) NumPy arrays, or a glob pattern such as 'caps/{what}_*.png'; got {}",
                describe(obj)
            )));
        };
        let files =
            pipeline::expand(&[pattern.to_string_lossy().into_owned()], what).map_err(calib_err)?;
        return Ok(CameraImages::files(files));
    }
    let mut files = Vec::new();
    let mut arrays = Vec::new();
    for (i, item) in obj.try_iter()?.enumerate() {
        let item = item?;
        let name = format!("{what}[{i}]");
        if item.hasattr("__array_interface__")? || item.hasattr("dtype")? {
            arrays.push((name.clone(), gray_image(&item, &name)?));
        } else if let Ok(path) = item.extract::<PathBuf>() {
            if !path.is_file() {
                return Err(PyFileNotFoundError::new_err(format!(
                    "{name}: {}: no such image file",
                    path.display()
                )));
            }
            files.push(path);
        } else {
            return Err(PyValueError::new_err(format!(
                "{name}: expected an image file or a uint8 (H, W) NumPy array, got {}",
                describe(&item)
            )));
        }
        if !files.is_empty() && !arrays.is_empty() {
            return Err(PyValueError::new_err(format!(
                "{what}: give all files or all arrays, not both ({name} differs from the items before it)"
            )));
        }
    }
    Ok(if arrays.is_empty() { CameraImages::files(files) } else { CameraImages::in_memory(arrays) })
}

/// A C-contiguous uint8 (H, W) array (grey) as an image, copied.
fn gray_image(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Image<u8>> {
    let expected = "uint8 (H, W)";
    let arr = obj
        .cast::<numpy::PyArray2<u8>>()
        .map_err(|_| {
            bad_array(
                name,
                expected,
                obj,
                " (8-bit grey; convert colour with e.g. PIL's .convert(\"L\"))",
            )
        })?
        .readonly();
    let (h, w) = (arr.shape()[0], arr.shape()[1]);
    let pixels = arr.as_slice().map_err(|_| {
        bad_array(
            name,
            expected,
            obj,
            " that is not C-contiguous (pass numpy.ascontiguousarray(...))",
        )
    })?;
    Image::from_vec(w, h, pixels.to_vec()).map_err(geometry_err)
}

/// The board of `board` ("COLSxROWS" inner corners or "auto"), `square` (None: 40 mm; a
/// number: metres; a string: with its unit, as `--square`) and `top_left`.
fn board_of(
    board: &str,
    square: Option<&Bound<'_, PyAny>>,
    top_left: Option<&str>,
) -> PyResult<(Board, bool)> {
    let board = crate::short_text("board", board)?;
    let top_left = top_left.map(|t| crate::short_text("top_left", t)).transpose()?;
    if let Some(t) = top_left
        && t != "black"
        && t != "white"
    {
        return Err(PyValueError::new_err(format!(
            "top_left: '{t}' is not \"black\" or \"white\" (or None: found from the images)"
        )));
    }
    let metres = match square {
        None => None,
        Some(s) if s.extract::<String>().is_ok() => None,
        Some(s) => Some(s.extract::<f64>().map_err(|_| {
            PyValueError::new_err(format!(
                "square: expected the square's side in metres (e.g. 0.04) or with a unit (\"40mm\"), got {}",
                describe(s)
            ))
        })?),
    };
    let text = match square {
        Some(s) if metres.is_none() => {
            crate::short_text("square", &s.extract::<String>()?)?.to_string()
        }
        _ => DEFAULT_SQUARE.to_string(),
    };
    let (mut b, auto) = parse_board(board, &text, top_left).map_err(calib_err)?;
    if let Some(m) = metres {
        b.square_m = square_of_metres(m).map_err(calib_err)?;
    }
    Ok((b, auto))
}

/// Collects what the run tells its user (warnings, images left out) for Python's warnings.
#[derive(Default)]
struct Collect(Mutex<Vec<String>>);

impl Observer for Collect {
    fn event(&self, event: Event<'_>) {
        let line = match event {
            Event::Warning(text) => text.to_string(),
            Event::Unreadable { path, why } => {
                format!("{}: cannot be read: {why}; left out", path.display())
            }
            Event::RigWarning(problem) => {
                format!("{problem}; `kfuse fuse` refuses such a rig without --force")
            }
            Event::DepthNoPose { name, why } => format!("{name}: {why}; left out"),
            Event::DepthForced(text) => format!("{text}; written anyway (force)"),
            _ => return,
        };
        if let Ok(mut v) = self.0.lock() {
            v.push(line);
        }
    }
}

/// σ of the intrinsics in the layouts of `K` ([[σfx, σskew, σcx], [0, σfy, σcy], [0, 0, 0]])
/// and `dist` (σ of k1, k2, p1, p2, k3).
fn k_std(s: &IntrinsicsStd) -> [[f64; 3]; 3] {
    [[s.fx, s.skew, s.cx], [0.0, s.fy, s.cy], [0.0, 0.0, 0.0]]
}

/// A finite number, or None (a NaN of "no value here").
fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// One calibrated camera of a `Calibration`: the final intrinsics and distortion (after the
/// joint fit for a stereo run) with their σ, and its single-camera fit's per-image errors
/// (the table `kfuse calibrate` prints per camera).
#[pyclass(name = "CameraFit", module = "kfuse", frozen)]
#[derive(Clone)]
pub(crate) struct PyCameraFit {
    name: &'static str,
    camera: CameraModel,
    std: IntrinsicsStd,
    rms_px: f64,
    mono: MonoCalibration,
}

#[pymethods]
impl PyCameraFit {
    /// "IR" or "colour".
    #[getter]
    fn name(&self) -> &'static str {
        self.name
    }

    /// The camera (size, `K`, `dist`), as a rig's cameras.
    #[getter]
    fn camera(&self) -> PyCamera {
        PyCamera { cam: self.camera }
    }

    /// 3x3 camera matrix, OpenCV's layout [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] (px).
    #[getter(K)]
    fn k<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        PyCamera { cam: self.camera }.k(py)
    }

    /// Distortion (k1, k2, p1, p2, k3), OpenCV's order.
    #[getter]
    fn dist<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyCamera { cam: self.camera }.dist(py)
    }

    /// 1σ of `K`, entry by entry (px; 0 where the entry is fixed): [[σfx, σskew, σcx],
    /// [0, σfy, σcy], [0, 0, 0]]. From the joint fit for a stereo run.
    #[getter(K_std)]
    fn k_std<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let m = k_std(&self.std);
        Array2::from_shape_fn((3, 3), |(r, c)| m[r][c]).into_pyarray(py)
    }

    /// 1σ of `dist` (k1, k2, p1, p2, k3); 0 for a fixed coefficient.
    #[getter]
    fn dist_std<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let s = &self.std;
        Array1::from(vec![s.k1, s.k2, s.p1, s.p2, s.k3]).into_pyarray(py)
    }

    /// This camera's RMS reprojection error, px (after the joint fit for a stereo run).
    #[getter]
    fn rms_px(&self) -> f64 {
        self.rms_px
    }

    /// The single-camera fit's per-axis corner noise σ, px.
    #[getter]
    fn sigma_px(&self) -> f64 {
        self.mono.sigma_px
    }

    /// The single-camera fit's images in input order, as its table: a dict per image with
    /// `name`, `corners` (used), `rms_px`, `tilt_deg` and `rejected` (None, or why it was left
    /// out: no board found, an outlier view, another size, ...).
    #[getter]
    fn views<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyAny>>> {
        self.mono
            .views
            .iter()
            .map(|v| {
                let d = pyo3::types::PyDict::new(py);
                d.set_item("name", &v.name)?;
                d.set_item("corners", v.n_corners)?;
                d.set_item("rms_px", finite(v.rms_px))?;
                d.set_item("tilt_deg", finite(v.tilt_deg))?;
                d.set_item("rejected", &v.rejected)?;
                Ok(d.into_any())
            })
            .collect()
    }

    /// The corners left out as outliers: dicts of `view`, `id` (board index), `error_px` and
    /// `threshold_px` (the outlier threshold then).
    #[getter]
    fn rejected_corners<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyAny>>> {
        self.mono
            .rejected_corners
            .iter()
            .map(|c| {
                let d = pyo3::types::PyDict::new(py);
                d.set_item("view", &c.view)?;
                d.set_item("id", c.id)?;
                d.set_item("error_px", c.error_px)?;
                d.set_item("threshold_px", c.threshold_px)?;
                Ok(d.into_any())
            })
            .collect()
    }

    fn __repr__(&self) -> String {
        let i = &self.camera.intrinsics;
        format!(
            "CameraFit({}, {}x{}, fx={:.3} ± {:.3}, fy={:.3} ± {:.3}, RMS {:.4} px)",
            self.name,
            self.camera.width,
            self.camera.height,
            i.fx,
            self.std.fx,
            i.fy,
            self.std.fy,
            self.rms_px
        )
    }
}

/// One pair of a stereo run: the joint fit's RMS and weight per camera.
struct Pair {
    ir: String,
    color: String,
    rms: (f64, f64),
    weight: (f64, f64),
    used: bool,
    rejected: Option<String>,
}

/// The result of `kfuse.calibrate`: what `kfuse calibrate` computes, as Python values.
///
/// .rig (stereo: a kfuse.Rig), .ir / .color (CameraFit: K, dist, their σ, per-image errors),
/// .rms_px, .pairs (stereo: per-pair RMS and weights), .rejected_views, .report (report.json's
/// content as a dict), .text (the file `kfuse calibrate --out` writes), .save(path).
#[pyclass(name = "Calibration", module = "kfuse", frozen)]
pub(crate) struct PyCalibration {
    rig: Option<Rig>,
    cameras: Vec<PyCameraFit>,
    rms_px: f64,
    pairs: Option<Vec<Pair>>,
    rejected: Vec<(String, String, String)>,
    board: Board,
    text: String,
    report: String,
    warnings: Vec<String>,
    /// The image files calibrated from (none for arrays): `save` never writes over one.
    inputs: Vec<PathBuf>,
}

impl PyCalibration {
    fn from_outcome(outcome: Outcome, warnings: Vec<String>) -> PyResult<Self> {
        let report = serde_json::to_string(&outcome.report)
            .map_err(|e| PyRuntimeError::new_err(format!("report: {e}")))?;
        let name = |views: &[calib::ViewCorners], i: usize| {
            views.get(i).map(|v| v.name.clone()).unwrap_or_default()
        };
        let mut rejected = Vec::new();
        for (camera, _, mono, _) in outcome.cameras() {
            for v in &mono.views {
                if let Some(why) = &v.rejected {
                    rejected.push((camera.to_string(), v.name.clone(), why.clone()));
                }
            }
        }
        let (cameras, rms_px, pairs) = match &outcome.fit {
            Fit::Stereo(s) => {
                let cameras = vec![
                    PyCameraFit {
                        name: "IR",
                        camera: s.depth,
                        std: s.depth_std,
                        rms_px: s.depth_rms_px,
                        mono: s.depth_mono.clone(),
                    },
                    PyCameraFit {
                        name: "colour",
                        camera: s.color,
                        std: s.color_std,
                        rms_px: s.color_rms_px,
                        mono: s.color_mono.clone(),
                    },
                ];
                for (i, why) in &s.rejected_views {
                    rejected.push(("pair".into(), name(&outcome.ir.views, *i), why.clone()));
                }
                let pairs = s
                    .view_rms_px
                    .iter()
                    .zip(&s.view_weights)
                    .enumerate()
                    .map(|(i, (rms, weight))| Pair {
                        ir: name(&outcome.ir.views, i),
                        color: name(&outcome.color.views, i),
                        rms: *rms,
                        weight: *weight,
                        used: s.pairs_used.contains(&i),
                        rejected: s
                            .rejected_views
                            .iter()
                            .find(|(j, _)| *j == i)
                            .map(|(_, why)| why.clone()),
                    })
                    .collect();
                (cameras, s.rms_px, Some(pairs))
            }
            Fit::Mono { camera, fit } => {
                let data = PyCameraFit {
                    name: camera,
                    camera: fit.camera,
                    std: fit.std,
                    rms_px: fit.rms_px,
                    mono: (**fit).clone(),
                };
                (vec![data], fit.rms_px, None)
            }
            Fit::DepthOnly => (vec![], f64::NAN, None),
        };
        let inputs = [&outcome.ir, &outcome.color]
            .into_iter()
            .filter(|run| !run.in_memory)
            .flat_map(|run| run.files.iter().cloned())
            .collect();
        Ok(Self {
            inputs,
            rig: outcome.rig,
            cameras,
            rms_px,
            pairs,
            rejected,
            board: outcome.board,
            text: outcome.text,
            report,
            warnings,
        })
    }

    fn camera(&self, name: &str) -> Option<PyCameraFit> {
        self.cameras.iter().find(|c| c.name == name).cloned()
    }
}

#[pymethods]
impl PyCalibration {
    /// The rig (kfuse.Rig) of a stereo run, None for one camera.
    #[getter]
    fn rig(&self) -> Option<PyRig> {
        self.rig.clone().map(|rig| PyRig { rig })
    }

    /// The IR camera's fit (CameraFit), None without IR images.
    #[getter]
    fn ir(&self) -> Option<PyCameraFit> {
        self.camera("IR")
    }

    /// The colour camera's fit (CameraFit), None without colour images.
    #[getter]
    fn color(&self) -> Option<PyCameraFit> {
        self.camera("colour")
    }

    /// RMS reprojection error, px: the joint fit's over both cameras' corners (stereo), or the
    /// camera's.
    #[getter]
    fn rms_px(&self) -> f64 {
        self.rms_px
    }

    /// Stereo: a dict per pair in input order: `ir`, `color` (image names), `ir_rms_px`,
    /// `color_rms_px`, `ir_weight`, `color_weight` (the joint fit's; None where that camera has
    /// no corners), `used`, `rejected` (None or why). None for one camera.
    #[getter]
    fn pairs<'py>(&self, py: Python<'py>) -> PyResult<Option<Vec<Bound<'py, PyAny>>>> {
        let Some(pairs) = &self.pairs else { return Ok(None) };
        pairs
            .iter()
            .map(|p| {
                let d = pyo3::types::PyDict::new(py);
                d.set_item("ir", &p.ir)?;
                d.set_item("color", &p.color)?;
                d.set_item("ir_rms_px", finite(p.rms.0))?;
                d.set_item("color_rms_px", finite(p.rms.1))?;
                d.set_item("ir_weight", finite(p.weight.0))?;
                d.set_item("color_weight", finite(p.weight.1))?;
                d.set_item("used", p.used)?;
                d.set_item("rejected", &p.rejected)?;
                Ok(d.into_any())
            })
            .collect::<PyResult<Vec<_>>>()
            .map(Some)
    }

    /// Every view left out, with why: (camera, image name, reason), camera "IR" or "colour"
    /// (the single-camera fit: no board found, an outlier view, ...) or "pair" (left out of
    /// the joint fit, named by its IR image).
    #[getter]
    fn rejected_views(&self) -> Vec<(String, String, String)> {
        self.rejected.clone()
    }

    /// The board: (cols, rows, square_m, top_left_black), the size found with board="auto".
    #[getter]
    fn board(&self) -> (usize, usize, f64, Option<bool>) {
        (self.board.cols, self.board.rows, self.board.square_m, self.board.top_left_black)
    }

    /// report.json's content less its timings (`kfuse calibrate --report`): the calibration,
    /// every view's corners and residuals, `held_out` (with held_out=True), as a dict.
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        py.import("json")?.call_method1("loads", (self.report.as_str(),))
    }

    /// The output file's text: what `kfuse calibrate --out FILE` writes (the rig JSON, or the
    /// single-camera JSON), byte for byte.
    #[getter]
    fn text(&self) -> &str {
        &self.text
    }

    /// What the run warned about (also issued as Python warnings): images left out, a rig
    /// `kfuse fuse` would refuse, ...
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }

    /// Writes `text` to `path` atomically (what `kfuse calibrate --out path` writes). An
    /// existing file is refused (FileExistsError) unless `overwrite`; one of the image files
    /// calibrated from (through any path to it) is refused even with `overwrite`
    /// (ValueError), as `kfuse calibrate --out` refuses it.
    #[pyo3(signature = (path, overwrite = false))]
    fn save(&self, path: PathBuf, overwrite: bool) -> PyResult<()> {
        crate::save_text(&path, &self.text, overwrite, &self.inputs)
    }

    fn __repr__(&self) -> String {
        let what = match (&self.pairs, self.cameras.first()) {
            (Some(p), _) => format!("stereo, {} pairs", p.len()),
            (None, Some(c)) => format!("{} camera", c.name),
            (None, None) => "depth correction".into(),
        };
        format!(
            "Calibration({what}, board {}x{}, RMS {:.4} px)",
            self.board.cols, self.board.rows, self.rms_px
        )
    }
}

/// Runs the pipeline on its own thread without the GIL, looking for Ctrl-C meanwhile (a
/// KeyboardInterrupt returns at once; the run's result is then dropped when it ends).
fn run_detached(py: Python<'_>, req: Request) -> PyResult<(Outcome, Vec<String>)> {
    let (tx, rx) = mpsc::channel();
    std::thread::Builder::new()
        .name("kfuse-calibrate".into())
        .spawn(move || {
            let obs = Collect::default();
            let result = pipeline::prepare(req, &obs).and_then(|p| p.run(&obs));
            let warnings = obs.0.into_inner().unwrap_or_default();
            let _ = tx.send(result.map(|o| (o, warnings)));
        })
        .map_err(|e| PyRuntimeError::new_err(format!("calibrate: cannot start its thread: {e}")))?;
    // A Receiver is not Sync; `detach` borrows it from another thread's point of view.
    let rx = Mutex::new(rx);
    let wait = || match rx.lock() {
        Ok(rx) => rx.recv_timeout(SIGNAL_POLL),
        Err(_) => Err(mpsc::RecvTimeoutError::Disconnected),
    };
    loop {
        match py.detach(wait) {
            Ok(result) => return result.map_err(calib_err),
            Err(mpsc::RecvTimeoutError::Timeout) => py.check_signals()?,
            Err(mpsc::RecvTimeoutError::Disconnected) => {
                return Err(PyRuntimeError::new_err("calibrate: the run's thread panicked"));
            }
        }
    }
}

/// calibrate(ir=None, color=None, board="auto", square=None, held_out=False, top_left=None)
///     -> Calibration
///
/// Calibrates from checkerboard images what `kfuse calibrate` calibrates, with its run
/// (`calib::pipeline`): IR and colour images give the rig (both cameras and their pose), one
/// camera's images that camera.
///
/// ir, color: the IR (depth camera) and colour camera's images: a glob pattern or file
///     ('caps/ir_*.png'; expanded and sorted as `--ir` sorts: ir_2 before ir_10), or a list
///     of image files or of uint8 (H, W) grey NumPy arrays, kept in list order. Stereo pairs
///     are matched in that order, one image of each camera per board pose.
/// board: inner corners as "COLSxROWS" ("7x5" for a board of 8x6 squares; OpenCV's sample is
///     "9x6"), or "auto": the size of the complete board most images show.
/// square: the printed square's side: metres (0.04) or a string with its unit ("40mm",
///     "4cm"); None is 40 mm, as `kfuse calibrate` without --square.
/// held_out: also make the held-out check (calibrate on every other view, predict the
///     rest; in .report["held_out"]), as `kfuse calibrate --report` does.
/// top_left: "black" or "white", the board's top-left square; None finds it from the images.
///
/// Views and corners rejected as outliers are in .rejected_views and each CameraFit. Warnings
/// of the run (images left out, a rig `kfuse fuse` would refuse) are Python warnings and
/// .warnings. Raises ValueError with the library's message (e.g. no board found, too few
/// views) and OSError for a file that cannot be read; the GIL is released during the run and
/// Ctrl-C interrupts it. Nothing is written: see Calibration.save.
#[pyfunction]
#[pyo3(signature = (ir = None, color = None, board = "auto", square = None, held_out = false, top_left = None))]
pub(crate) fn calibrate(
    py: Python<'_>,
    ir: Option<&Bound<'_, PyAny>>,
    color: Option<&Bound<'_, PyAny>>,
    board: &str,
    square: Option<&Bound<'_, PyAny>>,
    held_out: bool,
    top_left: Option<&str>,
) -> PyResult<PyCalibration> {
    let (board, auto_board) = board_of(board, square, top_left)?;
    let ir = camera_images(ir, "ir")?;
    let color = camera_images(color, "color")?;
    if ir.is_empty() && color.is_empty() {
        return Err(PyValueError::new_err(
            "calibrate: give ir and/or color images: a glob pattern such as 'caps/ir_*.png', or a list of image files or uint8 (H, W) arrays",
        ));
    }
    let options = Options { held_out, ..Options::default() };
    let req = Request { ir, color, depth: vec![], rig: None, board, auto_board, options };
    let (outcome, warnings) = run_detached(py, req)?;
    let warn = py.import("warnings")?;
    for w in &warnings {
        warn.call_method1("warn", (w.as_str(), py.get_type::<pyo3::exceptions::PyUserWarning>()))?;
    }
    PyCalibration::from_outcome(outcome, warnings)
}
