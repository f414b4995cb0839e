//! The Python module `kfuse`: rig files and the exact z-buffered registration of
//! `geometry::fusion` (`register_on`, on the CPU or the GPU), NumPy in and out. A thin layer: every algorithm and
//! every file format is the workspace's (`kfuse_io::rig_io`, `geometry::fusion`); this crate only
//! checks arrays, converts them and maps errors (`ValueError` for bad content, `OSError`
//! for a file that cannot be read or written).
#![deny(missing_docs)]

use std::path::{Path, PathBuf};

mod calibrate;
mod device;
mod fuse;
mod recording;
mod volume;

use calib::CalibError;
use fusion_gpu::{Engine, EngineUsed, GpuError, PixelEngine};
use geometry::fusion::{self, ColorProjection};
use geometry::{CameraModel, DepthKind, GeometryError, Image, Rig};
use kfuse_io::rig_io::{self, Calibration, ImportOptions};
use kinect_usb::decoder::{DecoderConfig, DecoderParams, DecoderPrecision, DepthDecoder};
use kinect_usb::orientation::Orientation;
use kinect_usb::params::{P0Tables, XzTables};
use kinect_usb::raw::{self, PIXELS};
use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyFileExistsError, PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyTuple;

/// Millimetres to metres, as `kfuse fuse` reads a 16-bit depth PNG
/// (`kfuse_io::images::MILLIMETRES`).
const METRES_PER_MM: f64 = kfuse_io::images::MILLIMETRES;

fn calib_err(e: CalibError) -> PyErr {
    match e {
        CalibError::Io { .. } => PyOSError::new_err(e.to_string()),
        CalibError::Geometry(g) => geometry_err(g),
        other => PyValueError::new_err(other.to_string()),
    }
}

/// The one overwrite rule of the package's file writers (`Rig.save`, `Calibration.save`,
/// `Device.record`; `FusedFrame.save` has the same for its folder), checked before anything is
/// written: a folder is a ValueError (`example` is a file name to suggest, e.g. rig.json), one
/// of the `inputs` the object was made from a ValueError even with `overwrite` (as `kfuse
/// calibrate --out` refuses an input image), and an existing file (or link) a FileExistsError
/// naming it unless `overwrite`.
pub(crate) fn check_output_file(
    path: &Path,
    overwrite: bool,
    example: &str,
    inputs: &[PathBuf],
) -> PyResult<()> {
    if path.is_dir() {
        return Err(PyValueError::new_err(format!(
            "{}: is a folder; give a file name such as {example}",
            path.display()
        )));
    }
    if let Some(input) = inputs.iter().find(|i| same_file(i, path)) {
        return Err(PyValueError::new_err(format!(
            "{}: is one of the input images ({}); overwrite=True does not replace an input: give a new file name such as {example}",
            path.display(),
            input.display()
        )));
    }
    // `symlink_metadata`: a link whose target is missing is a file of the user's too.
    if path.symlink_metadata().is_ok() && !overwrite {
        return Err(PyFileExistsError::new_err(format!(
            "{}: exists; pass overwrite=True to replace it, or give another file name",
            path.display()
        )));
    }
    Ok(())
}

/// Whether `a` and `b` name one existing file (links and `..` resolved), the CLI's test of an
/// output against its inputs (`src/cmd_calibrate/outputs.rs`).
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

/// Writes `text` to the file `path` atomically, as the CLI's `--out`, after
/// [`check_output_file`] (`inputs`: the files `text` was computed from).
fn save_text(path: &Path, text: &str, overwrite: bool, inputs: &[PathBuf]) -> PyResult<()> {
    check_output_file(path, overwrite, "rig.json", inputs)?;
    kfuse_io::atomic::write_bytes_atomic(path, text.as_bytes()).map_err(geometry_err)
}

/// The state of a class that holds a file or a device (`Device`, `Recording`) for one call:
/// such a class is usable from any thread, and dropping it in any thread closes what it
/// holds, but two threads cannot use one object at once. The lock is taken without waiting
/// (a call waiting here with the GIL could deadlock with the call it waits for, which takes
/// the GIL back to check for Ctrl-C); a second caller gets a RuntimeError naming the rule.
pub(crate) fn one_call_at_a_time<'a, T>(
    state: &'a std::sync::Mutex<T>,
    class: &str,
) -> PyResult<std::sync::MutexGuard<'a, T>> {
    state.try_lock().map_err(|e| match e {
        std::sync::TryLockError::WouldBlock => pyo3::exceptions::PyRuntimeError::new_err(format!(
            "kfuse.{class}: another thread's call on this {class} is running (one call at a time, from any thread); wait for that call to return, or give each thread its own {class}"
        )),
        std::sync::TryLockError::Poisoned(_) => pyo3::exceptions::PyRuntimeError::new_err(format!(
            "kfuse.{class}: an earlier call failed inside kfuse and left it unusable; open a new {class}"
        )),
    })
}

pub(crate) fn geometry_err(e: GeometryError) -> PyErr {
    match e {
        GeometryError::Io { .. } => PyOSError::new_err(e.to_string()),
        other => PyValueError::new_err(other.to_string()),
    }
}

/// The error of an allocation a call's sizes make too large for this process: MemoryError
/// naming what and how much (Rust aborts the interpreter on a failed allocation; the
/// allocations sized by the caller's arrays and cameras are made fallibly here instead).
fn no_memory(what: &str, bytes: usize) -> PyErr {
    pyo3::exceptions::PyMemoryError::new_err(format!(
        "{what}: needs {} MiB more than this process can allocate; use smaller images or free memory",
        bytes >> 20
    ))
}

/// `values` copied into a new Vec, or MemoryError: the copies handed to NumPy are the largest
/// allocations at the boundary (a 50 Mpx camera's z-buffer is 200 MB).
pub(crate) fn try_copy<T: Clone>(values: &[T], what: &str) -> PyResult<Vec<T>> {
    let mut v = Vec::new();
    v.try_reserve_exact(values.len())
        .map_err(|_| no_memory(what, std::mem::size_of_val(values)))?;
    v.extend_from_slice(values);
    Ok(v)
}

/// Longest text a name-like argument (an engine, a board, a backend, a serial...) may have:
/// 256 characters, far above any valid one ("0.5m..2.5m", "11x8", a 12-digit serial); longer
/// text is refused here without being echoed, so a message stays one readable line.
const MAX_NAME_CHARS: usize = 256;

/// `text` for an argument `name` that takes a short name: a ValueError (without the text)
/// when it is longer than [`MAX_NAME_CHARS`].
pub(crate) fn short_text<'a>(name: &str, text: &'a str) -> PyResult<&'a str> {
    let n = text.chars().count();
    if n > MAX_NAME_CHARS {
        return Err(PyValueError::new_err(format!(
            "{name}: {n} characters of text, longer than any valid value ({MAX_NAME_CHARS} at most); see help(kfuse) for the values it takes"
        )));
    }
    Ok(text)
}

/// MemoryError, before any work, when this process cannot get `bytes` more memory: the peak a
/// library call on the caller's sizes allocates inside (where its growing buffers cannot
/// fail softly), reserved fallibly and released.
fn ensure_memory(what: &str, bytes: usize) -> PyResult<()> {
    let mut probe: Vec<u8> = Vec::new();
    probe.try_reserve_exact(bytes).map_err(|_| no_memory(what, bytes))
}

/// `dtype` and `shape` of any object, for messages ("uint8 (1080, 1920)"; "list" for a
/// non-array).
fn describe(obj: &Bound<'_, PyAny>) -> String {
    let dtype = obj.getattr("dtype").and_then(|d| d.str()).map(|s| s.to_string());
    let shape = obj.getattr("shape").and_then(|s| s.str()).map(|s| s.to_string());
    match (dtype, shape) {
        (Ok(d), Ok(s)) => format!("{d} array of shape {s}"),
        _ => obj.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "object".into()),
    }
}

/// The error for an argument that is not the array expected.
fn bad_array(name: &str, expected: &str, obj: &Bound<'_, PyAny>, why: &str) -> PyErr {
    PyValueError::new_err(format!(
        "{name}: expected a C-contiguous {expected} NumPy array, got {}{why}",
        describe(obj)
    ))
}

/// `out=`: a C-contiguous 2-D array of `T` of exactly `rows x cols` (whether it is writable is
/// checked by [`writable`] when it is borrowed).
fn out_array2<'py, T: numpy::Element>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    dtype: &str,
    rows: usize,
    cols: usize,
) -> PyResult<Bound<'py, PyArray2<T>>> {
    let expected = format!("writable {dtype} ({rows}, {cols})");
    let arr = obj.cast::<PyArray2<T>>().map_err(|_| bad_array(name, &expected, obj, ""))?;
    if arr.shape() != [rows, cols] {
        return Err(bad_array(name, &expected, obj, ""));
    }
    if !arr.is_c_contiguous() {
        return Err(bad_array(name, &expected, obj, " that is not C-contiguous"));
    }
    Ok(arr.clone())
}

/// `out`'s write borrow: a ValueError when it is read-only or borrowed elsewhere (an input of
/// the same call).
fn writable<'py, T: numpy::Element>(
    array: &Bound<'py, PyArray2<T>>,
    obj: &Bound<'py, PyAny>,
    expected: &str,
) -> PyResult<numpy::PyReadwriteArray2<'py, T>> {
    array.try_readwrite().map_err(|_| {
        bad_array("out", expected, obj, " that is read-only or also an input of this call")
    })
}

/// A C-contiguous 2-D array of `T` of exactly `rows x cols`, without a copy.
pub(crate) fn array2<'py, T: numpy::Element>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    dtype: &str,
    rows: usize,
    cols: usize,
) -> PyResult<PyReadonlyArray2<'py, T>> {
    let expected = format!("{dtype} ({rows}, {cols})");
    let arr =
        obj.cast::<PyArray2<T>>().map_err(|_| bad_array(name, &expected, obj, ""))?.readonly();
    if arr.shape() != [rows, cols] {
        return Err(bad_array(name, &expected, obj, ""));
    }
    if !arr.is_c_contiguous() {
        return Err(bad_array(
            name,
            &expected,
            obj,
            " that is not C-contiguous (pass numpy.ascontiguousarray(...))",
        ));
    }
    Ok(arr)
}

/// One camera of a rig: OpenCV's camera matrix and distortion vector, image size.
#[pyclass(name = "Camera", module = "kfuse", frozen)]
struct PyCamera {
    cam: CameraModel,
}

#[pymethods]
impl PyCamera {
    /// Image width in pixels.
    #[getter]
    fn width(&self) -> usize {
        self.cam.width
    }

    /// Image height in pixels.
    #[getter]
    fn height(&self) -> usize {
        self.cam.height
    }

    /// The 3x3 camera matrix in OpenCV's layout: [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]
    /// (pixels; 0-based, pixel centres at integers, as OpenCV).
    #[getter(K)]
    fn k<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let i = &self.cam.intrinsics;
        let m = [[i.fx, i.skew, i.cx], [0.0, i.fy, i.cy], [0.0, 0.0, 1.0]];
        Array2::from_shape_fn((3, 3), |(r, c)| m[r][c]).into_pyarray(py)
    }

    /// The distortion vector in OpenCV's order: (k1, k2, p1, p2, k3).
    #[getter]
    fn dist<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let d = &self.cam.distortion;
        Array1::from(vec![d.k1, d.k2, d.p1, d.p2, d.k3]).into_pyarray(py)
    }

    fn __repr__(&self) -> String {
        let i = &self.cam.intrinsics;
        format!(
            "Camera({}x{}, fx={}, fy={}, cx={}, cy={})",
            self.cam.width, self.cam.height, i.fx, i.fy, i.cx, i.cy
        )
    }
}

/// A calibrated depth + colour camera pair: X_color = R · X_depth + T (metres).
///
/// Rig.load(path, *more, force=False) reads every format `kfuse rig import` reads (kfuse rig
/// JSON, Bouguet .mat, KinectData.mat, OpenCV YAML, a ROS camera_info pair, iai_kinect2's
/// folder, kinect_params.json) with the same checks and messages.
#[pyclass(name = "Rig", module = "kfuse", frozen)]
struct PyRig {
    rig: Rig,
}

#[pymethods]
impl PyRig {
    /// Reads a rig from `path` (and the further files some formats need, as `kfuse rig
    /// import`). A file that fails the plausibility checks is refused unless `force`.
    /// Raises OSError when a file cannot be read, ValueError for its content.
    #[staticmethod]
    #[pyo3(signature = (path, *more, force = false))]
    fn load(
        py: Python<'_>,
        path: PathBuf,
        more: &Bound<'_, PyTuple>,
        force: bool,
    ) -> PyResult<Self> {
        let mut sources = vec![path];
        for m in more.iter() {
            sources.push(m.extract::<PathBuf>()?);
        }
        let imported = rig_io::import(&sources, &ImportOptions::default()).map_err(geometry_err)?;
        let Calibration::Rig(rig) = imported.calibration else {
            return Err(PyValueError::new_err(format!(
                "{}: holds one camera, not a rig; a Registration needs both cameras and their pose (give a rig file, e.g. from `kfuse calibrate --ir ... --color ...`)",
                sources[0].display()
            )));
        };
        let problems = rig.plausibility_problems();
        if !problems.is_empty() && !force {
            return Err(PyValueError::new_err(format!(
                "{}: {} (pass force=True to load it anyway)",
                sources[0].display(),
                problems.join("; ")
            )));
        }
        // A rig of mirrored images fits only images mirrored the same way; said as `rig
        // import` and `rig show` say it (issue 51: Python gave no notice): a version-1
        // kinect_params.json (`kfuse capture` before it wrote images as the scene is), or a
        // Kinect rig whose colour camera sits on the mirrored side (raw libfreenect2 output).
        let mut notices = Vec::new();
        if sources.len() == 1
            && let Ok(text) = rig_io::yaml::read_text(&sources[0])
            && let Ok(v) = serde_json::from_str::<serde_json::Value>(&text)
            && v.get("format").and_then(|f| f.as_str()) == Some(rig_io::KINECT_PARAMS_FORMAT)
            && let Ok(params) = rig_io::kinect::FactoryParams::from_json(&v, &sources[0])
            && !params.scene_orientation
        {
            notices.push(
                "the parameters of mirrored images (kinect_params.json version 1: `kfuse capture` before it wrote images as the scene is), and so is this rig: it fits that capture's images; `kfuse rig import FILE --mirror` gives the rig of images as the scene is".to_string(),
            );
        }
        if let Some((true, text)) = rig_io::show::kinect_orientation(&rig) {
            notices.push(text);
        }
        for text in notices {
            let message = std::ffi::CString::new(format!("{}: {text}", sources[0].display()))
                .map_err(|e| PyValueError::new_err(e.to_string()))?;
            PyErr::warn(py, &py.get_type::<pyo3::exceptions::PyUserWarning>(), &message, 1)?;
        }
        Ok(Self { rig })
    }

    /// Reads a Kinect v2's `kinect_params.json` (the factory parameters `kfuse capture`
    /// saves beside a capture) as a rig, through the import `kfuse rig import
    /// kinect_params.json` makes: the same as `Rig.load(path)`, but any other format is
    /// refused (ValueError naming the format found and saying to use Rig.load). Raises OSError
    /// when the file cannot be read, ValueError for its content.
    #[staticmethod]
    #[pyo3(signature = (path, force = false))]
    fn from_kinect_params(py: Python<'_>, path: PathBuf, force: bool) -> PyResult<Self> {
        // Bounded as every rig file is read (a /dev/zero or a FIFO given here was read to
        // the end: the interpreter aborted at the address-space limit).
        let text = rig_io::yaml::read_text(&path).map_err(geometry_err)?;
        let format = serde_json::from_str::<serde_json::Value>(&text)
            .ok()
            .map(|v| v.get("format").and_then(|f| f.as_str()).map(str::to_string));
        if format != Some(Some(rig_io::KINECT_PARAMS_FORMAT.to_string())) {
            let found = match format {
                None => "not JSON".to_string(),
                Some(None) => "JSON without a \"format\" field".to_string(),
                Some(Some(f)) => format!("JSON of format \"{f}\""),
            };
            return Err(PyValueError::new_err(format!(
                "{}: is {found}, not a kinect_params.json (format \"{}\", written by `kfuse capture`); Rig.load reads every rig format",
                path.display(),
                rig_io::KINECT_PARAMS_FORMAT
            )));
        }
        Self::load(py, path, &PyTuple::empty(py), force)
    }

    /// Writes the rig as kfuse rig JSON (what `kfuse rig import --out` writes), atomically.
    /// An existing file is refused (FileExistsError) unless `overwrite`.
    #[pyo3(signature = (path, overwrite = false))]
    fn save(&self, path: PathBuf, overwrite: bool) -> PyResult<()> {
        save_text(&path, &self.rig.to_json(), overwrite, &[])
    }

    /// The depth (IR) camera, the rig's reference frame.
    #[getter]
    fn depth(&self) -> PyCamera {
        PyCamera { cam: self.rig.depth }
    }

    /// The colour camera.
    #[getter]
    fn color(&self) -> PyCamera {
        PyCamera { cam: self.rig.color }
    }

    /// Rotation R (3x3) of X_color = R · X_depth + T (OpenCV stereoCalibrate's R).
    #[getter(R)]
    fn r<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let m = self.rig.color_from_depth.rotation.matrix();
        Array2::from_shape_fn((3, 3), |(r, c)| m[(r, c)]).into_pyarray(py)
    }

    /// Translation T (3,), metres.
    #[getter(T)]
    fn t<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let t = &self.rig.color_from_depth.translation;
        Array1::from(vec![t.x, t.y, t.z]).into_pyarray(py)
    }

    /// True when the rig's images are already undistorted (`kfuse undistort`).
    #[getter]
    fn rectified(&self) -> bool {
        self.rig.rectified
    }

    fn __repr__(&self) -> String {
        let t = &self.rig.color_from_depth.translation;
        format!(
            "Rig(depth {}x{}, color {}x{}, T=({:.4}, {:.4}, {:.4}) m)",
            self.rig.depth.width,
            self.rig.depth.height,
            self.rig.color.width,
            self.rig.color.height,
            t.x,
            t.y,
            t.z
        )
    }
}

/// `color_on_depth`'s result: RGB on the depth grid and where it is valid.
type ColorOnDepth<'py> = (Bound<'py, PyArray3<u8>>, Bound<'py, PyArray2<bool>>);

/// Exact z-buffered registration (H1 + H2 + H7) and the H8 hole mask, frame after frame, on
/// the CPU or the GPU: `kfuse fuse`'s request (its default options, `depth_range`, z depth)
/// through `geometry::fusion::register_on`, one frame of `stream_on` written straight into
/// the caller's arrays.
///
/// reg = kfuse.Registration(rig, engine="cpu", force=False, depth_range=None)
/// z = reg.register(depth_mm)  # (H, W) float32 metres, NaN = none
#[pyclass(name = "Registration", module = "kfuse")]
struct PyRegistration {
    /// The fusion request (the rig as fused, the options; its depth preparation is every
    /// frame's).
    request: fusion::Request,
    /// Where the stages run.
    engine: PixelEngine,
    used: EngineUsed,
    /// H1's ray per depth pixel and H2's projection, for `color_on_depth` (fixed by the rig).
    rays: Vec<[f32; 3]>,
    projection: ColorProjection,
    /// Depth in a unit the fusion does not read is accepted (`force=True`).
    force: bool,
    /// The frame being read (metres, prepared), reused; it becomes `depth` once registered.
    incoming: Image<f32>,
    /// The last registered frame's depth (metres, prepared, not clipped to the range).
    depth: Image<f32>,
    registered: bool,
    /// The GPU's hole mask of the last frame (the GPU computes it with the z-buffer; the CPU
    /// keeps the occupancy bits it is made from instead). Empty on the CPU.
    gpu_mask: Vec<bool>,
    /// A z-buffer of the registration's own, for `color_on_depth` and `cloud` (empty until
    /// one of them needs it).
    zbuffer: Image<f32>,
    /// Whether `zbuffer` holds the last frame's registration (H6's occlusion test reads H3's
    /// nearest fill of it, at the pixels the samples land on: `fusion::NearestFill`).
    own_zbuffer_current: bool,
}

/// A `depth` argument, borrowed: uint16 millimetres (a 16-bit PNG's) or float32 millimetres
/// (the decoder's and `Recording`'s).
enum DepthArg<'py> {
    Units(PyReadonlyArray2<'py, u16>),
    Millimetres(PyReadonlyArray2<'py, f32>),
}

impl<'py> DepthArg<'py> {
    /// `depth` checked against the rig's depth size (ValueError naming `depth`).
    fn new(rig: &Rig, depth: &Bound<'py, PyAny>) -> PyResult<Self> {
        let (dw, dh) = (rig.depth.width, rig.depth.height);
        Ok(if depth.cast::<PyArray2<f32>>().is_ok() {
            let arr = array2::<f32>(depth, "depth", "float32", dh, dw)?;
            arr.as_slice().map_err(|_| bad_array("depth", "float32", depth, ""))?;
            DepthArg::Millimetres(arr)
        } else {
            let arr = array2::<u16>(depth, "depth", "uint16", dh, dw)?;
            arr.as_slice().map_err(|_| bad_array("depth", "uint16", depth, ""))?;
            DepthArg::Units(arr)
        })
    }

    /// The borrowed values, to read without the GIL.
    fn values(&self) -> PyResult<DepthValues<'_>> {
        let bad = |e: numpy::AsSliceError| PyValueError::new_err(format!("depth: {e}"));
        Ok(match self {
            DepthArg::Units(a) => DepthValues::Units(a.as_slice().map_err(bad)?),
            DepthArg::Millimetres(a) => DepthValues::Millimetres(a.as_slice().map_err(bad)?),
        })
    }
}

/// A [`DepthArg`]'s values.
#[derive(Clone, Copy)]
enum DepthValues<'a> {
    Units(&'a [u16]),
    Millimetres(&'a [f32]),
}

impl DepthValues<'_> {
    /// The depth in metres into `out` (the rig's depth size) with the request's depth
    /// preparation, as fuse reads and prepares it: uint16 as `kfuse_io::images::read_depth`
    /// reads a 16-bit PNG, float32 as `kfuse fuse --recording` converts the decoder's.
    fn metres_into(
        self,
        request: &fusion::Request,
        out: &mut Image<f32>,
    ) -> Result<(), GeometryError> {
        match self {
            DepthValues::Units(v) => {
                kfuse_io::images::depth_from_units_into(v, METRES_PER_MM, out.data_mut())?
            }
            DepthValues::Millimetres(v) => kfuse_sequence::process::depth_in_metres_into(v, out)
                .map_err(|e| GeometryError::InvalidInput(e.to_string()))?,
        }
        request.prepare_depth(out)?;
        Ok(())
    }
}

impl PyRegistration {
    fn has_frame(&self, what: &str) -> PyResult<()> {
        if self.registered {
            return Ok(());
        }
        Err(PyValueError::new_err(format!(
            "{what}: no frame registered yet; call register(depth) first"
        )))
    }

    /// Registers `incoming` (read, prepared and unit-checked) on the engine into `zbuffer`
    /// (the GPU's hole mask into `gpu_mask`); it becomes the last frame.
    fn register_incoming(&mut self, zbuffer: &mut [f32]) -> Result<(), GpuError> {
        let Self { engine, request, incoming, gpu_mask, .. } = self;
        let mask = matches!(engine, PixelEngine::Gpu(_)).then_some(&mut gpu_mask[..]);
        fusion::register_on(engine, request, incoming, zbuffer, mask)?;
        std::mem::swap(&mut self.incoming, &mut self.depth);
        self.registered = true;
        self.own_zbuffer_current = false;
        Ok(())
    }

    /// Reads `depth` into `incoming` and, unless it needs the unit check's words (a median
    /// outside the band: raise, or warn and go on), registers it into `zbuffer`, all without
    /// the GIL. A frame refused here leaves the last frame as it was.
    fn read_and_register(
        &mut self,
        py: Python<'_>,
        depth: DepthValues<'_>,
        zbuffer: &mut [f32],
    ) -> PyResult<()> {
        let rig = self.request.rig();
        let (dw, dh) = (rig.depth.width, rig.depth.height);
        if self.incoming.size() != (dw, dh) {
            // The two depth frames (being read, last registered), made on the first frame.
            ensure_memory("register", (dw * dh).saturating_mul(2 * 4))?;
            self.incoming = Image::filled(dw, dh, f32::NAN);
            self.depth = Image::filled(dw, dh, f32::NAN);
        }
        let registered = py
            .detach(|| -> Result<bool, GpuError> {
                depth.metres_into(&self.request, &mut self.incoming)?;
                if !self.force && unit_needs_words(self.request.rig(), &self.incoming) {
                    return Ok(false);
                }
                self.register_incoming(zbuffer)?;
                Ok(true)
            })
            .map_err(fuse::gpu_err)?;
        if !registered {
            check_depth_unit(py, self.request.rig(), &self.incoming)?;
            py.detach(|| self.register_incoming(zbuffer)).map_err(fuse::gpu_err)?;
        }
        Ok(())
    }

    /// H6 of the last registered frame (which must exist): fuse's colour on the depth grid
    /// (the depth range applied, as H1 applies it) with its occlusion test against H3's
    /// nearest fill of the frame's z-buffer (registered again into the registration's own
    /// z-buffer on first use).
    fn color_of_frame(
        &mut self,
        color: &Image<[u8; 3]>,
    ) -> Result<(Image<[u8; 3]>, Image<bool>), GpuError> {
        if !self.registered {
            return Err(GeometryError::InvalidInput("no frame registered yet".into()).into());
        }
        let params = self.request.params();
        if !self.own_zbuffer_current {
            let rig = self.request.rig();
            if self.zbuffer.size() != (rig.color.width, rig.color.height) {
                self.zbuffer = Image::filled(rig.color.width, rig.color.height, f32::NAN);
            }
            let Self { engine, request, depth, gpu_mask, zbuffer, .. } = self;
            let mask = matches!(engine, PixelEngine::Gpu(_)).then_some(&mut gpu_mask[..]);
            fusion::register_on(engine, request, depth, zbuffer.data_mut(), mask)?;
            self.own_zbuffer_current = true;
        }
        let nearest = fusion::NearestFill::new(&self.zbuffer, params.radius_px, params.depth_jump);
        let depth = params.depth_range.clip(&self.depth);
        let tol = params.occlusion_tolerance.unwrap_or(0.0);
        Ok(fusion::color_on_depth(&depth, &self.rays, &self.projection, color, Some(&nearest), tol))
    }
}

#[pymethods]
impl PyRegistration {
    /// Buffers and per-pixel constants for `rig`, with `kfuse fuse`'s request: its default
    /// options (z depth, its hole radii) and the keywords of `kfuse.fuse` that apply to
    /// registration:
    ///
    /// * `engine`: where the stages run, a kfuse.Engine or "cpu" (the default), "gpu" (wgpu,
    ///   Vulkan; no adapter is a RuntimeError) or "auto" (the GPU if there is one, else the
    ///   CPU with a RuntimeWarning); the `engine` attribute says which. Results are
    ///   bit-identical on every engine.
    /// * `force`: every frame's depth unit is checked as fuse checks it (a median depth
    ///   outside 0.2-15 m raises ValueError); `force=True` registers such frames anyway.
    /// * `depth_range`: fuse's `--depth-range`, "0.5m..2.5m" or a (min, max) pair in metres;
    ///   samples outside are not samples. None keeps every sample.
    ///
    /// (`linear`, fuse's H3 resampling, has no part in registration.)
    #[new]
    #[pyo3(signature = (rig, engine = None, force = false, depth_range = None))]
    fn new(
        py: Python<'_>,
        rig: &PyRig,
        engine: Option<&Bound<'_, PyAny>>,
        force: bool,
        depth_range: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let engine = engine.map(fuse::engine_arg).transpose()?.unwrap_or(Engine::Cpu);
        let options = fuse::cli_options(true, fuse::depth_range_arg(depth_range)?);
        let request =
            fusion::Request::new(&rig.rig, DepthKind::Z, options).map_err(geometry_err)?;
        let fused = request.rig();
        fused.validate().map_err(geometry_err)?;
        fusion::checked_coverage_radius_px(fused, &options).map_err(geometry_err)?;
        let (engine, used) = py.detach(|| engine.open()).map_err(fuse::gpu_err)?;
        fuse::warn_fallback(py, &used, "registering")?;
        let (cw, ch) = (fused.color.width, fused.color.height);
        let gpu_mask = match engine {
            PixelEngine::Gpu(_) => vec![false; cw * ch],
            PixelEngine::Cpu(_) => Vec::new(),
        };
        Ok(Self {
            rays: fusion::depth_ray_table(&fused.depth, DepthKind::Z),
            projection: ColorProjection::from_rig(fused),
            incoming: Image::filled(0, 0, f32::NAN),
            depth: Image::filled(0, 0, f32::NAN),
            registered: false,
            gpu_mask,
            zbuffer: Image::filled(0, 0, f32::NAN),
            own_zbuffer_current: false,
            force,
            engine,
            used,
            request,
        })
    }

    /// Where the stages run: "cpu" or "gpu" (engine="auto" says which it picked).
    #[getter]
    fn engine(&self) -> &'static str {
        match self.engine {
            PixelEngine::Cpu(_) => "cpu",
            PixelEngine::Gpu(_) => "gpu",
        }
    }

    /// As FusedFrame.engine_used: "cpu", "gpu: ADAPTER" or "cpu (fallback: REASON)".
    #[getter]
    fn engine_used(&self) -> String {
        fuse::engine_used_text(&self.used)
    }

    /// Registers one depth frame: `depth` is a C-contiguous uint16 (H, W) array of z in
    /// millimetres (0 = no sample), or float32 millimetres as kfuse.Decoder gives them, the
    /// depth camera's size. Returns the colour camera's z in metres on the colour grid,
    /// float32 (colour H, colour W), NaN where no sample landed: the z-buffer `kfuse fuse`
    /// writes as depth_zbuffer.exr, bit for bit, on every engine. The rig's depth correction
    /// is applied first and the depth range by H1, as fuse does. Releases the GIL.
    ///
    /// `out`: a writable C-contiguous float32 (colour H, colour W) array to register into and
    /// return instead of a new one (whatever it holds is overwritten). On the CPU the
    /// z-buffer is written straight into it, with no copy; a stream of frames then allocates
    /// nothing per frame.
    #[pyo3(signature = (depth, out = None))]
    fn register<'py>(
        &mut self,
        py: Python<'py>,
        depth: &Bound<'py, PyAny>,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let depth = DepthArg::new(self.request.rig(), depth)?;
        let (cw, ch) = (self.request.rig().color.width, self.request.rig().color.height);
        let (array, obj) = match out {
            Some(out) => (out_array2::<f32>(out, "out", "float32", ch, cw)?, out.clone()),
            None => {
                ensure_memory("register", cw * ch * 4)?;
                let a = PyArray2::<f32>::zeros(py, [ch, cw], false);
                let obj = a.as_any().clone();
                (a, obj)
            }
        };
        {
            let mut dst = writable(&array, &obj, "float32 (colour H, colour W)")?;
            let dst = dst.as_slice_mut().map_err(|_| bad_array("out", "float32", &obj, ""))?;
            self.read_and_register(py, depth.values()?, dst)?;
        }
        Ok(array)
    }

    /// H8's disocclusion hole mask of the last registered frame: bool (colour H, colour W),
    /// True where the colour camera sees a surface the depth camera did not (fuse's
    /// hole_mask.png), the same on every engine.
    ///
    /// `out`: a writable C-contiguous bool (colour H, colour W) array to fill and return
    /// instead of a new one (on the CPU written straight from the registration's bits).
    #[pyo3(signature = (out = None))]
    fn hole_mask<'py>(
        &mut self,
        py: Python<'py>,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray2<bool>>> {
        self.has_frame("hole_mask")?;
        let (cw, ch) = (self.request.rig().color.width, self.request.rig().color.height);
        let (array, obj) = match out {
            Some(out) => (out_array2::<bool>(out, "out", "bool", ch, cw)?, out.clone()),
            None => {
                ensure_memory("hole_mask", cw * ch)?;
                let a = PyArray2::<bool>::zeros(py, [ch, cw], false);
                let obj = a.as_any().clone();
                (a, obj)
            }
        };
        {
            let mut dst = writable(&array, &obj, "bool (colour H, colour W)")?;
            let dst = dst.as_slice_mut().map_err(|_| bad_array("out", "bool", &obj, ""))?;
            let (engine, gpu_mask) = (&mut self.engine, &self.gpu_mask);
            py.detach(|| match engine {
                PixelEngine::Cpu(c) => c.last_hole_mask(dst).map(|_| ()),
                PixelEngine::Gpu(_) => {
                    dst.copy_from_slice(gpu_mask);
                    Some(())
                }
            })
            .ok_or_else(|| PyValueError::new_err("hole_mask: the engine kept no frame"))?;
        }
        Ok(array)
    }

    /// H6: the colour seen by every depth pixel of the last registered frame, bilinear from
    /// `color` (C-contiguous uint8 (colour H, colour W, 3), RGB), with fuse's occlusion test
    /// against H3's nearest fill. Returns (rgb uint8 (H, W, 3), valid bool (H, W)) on the
    /// depth grid; invalid pixels are black. Releases the GIL.
    fn color_on_depth<'py>(
        &mut self,
        py: Python<'py>,
        color: &Bound<'py, PyAny>,
    ) -> PyResult<ColorOnDepth<'py>> {
        let color_img = color_image(py, self.request.rig(), color)?;
        self.has_frame("color_on_depth")?;
        let (rgb, valid) = py.detach(|| self.color_of_frame(&color_img)).map_err(fuse::gpu_err)?;
        let rig = self.request.rig();
        let (dw, dh) = (rig.depth.width, rig.depth.height);
        let rgb = Array3::from_shape_vec((dh, dw, 3), try_flat(rgb.data(), "color_on_depth")?)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        let valid = Array2::from_shape_vec((dh, dw), try_copy(valid.data(), "color_on_depth")?)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok((rgb.into_pyarray(py), valid.into_pyarray(py)))
    }

    /// H1 (and H6): the point cloud `kfuse fuse` writes as cloud.ply. `depth` is as for
    /// `register` (uint16 (H, W) mm, the rig's depth correction applied, samples outside the
    /// depth range left out); returns (points float32 (N, 3) metres in the depth camera's
    /// frame, x right, y down, z forward, one per valid depth pixel in row-major order; colors
    /// uint8 (N, 3) or None). With `color` (uint8 (colour H, colour W, 3), RGB) the frame is
    /// registered as by `register` (it becomes the last frame) and every point gets H6's
    /// colour, black where fuse does not trust it (occluded or outside the colour image), as
    /// in cloud.ply. Without it nothing is registered. Releases the GIL.
    #[pyo3(signature = (depth, color = None))]
    fn cloud<'py>(
        &mut self,
        py: Python<'py>,
        depth: &Bound<'py, PyAny>,
        color: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<CloudArrays<'py>> {
        let color_img = color.map(|c| color_image(py, self.request.rig(), c)).transpose()?;
        let image = depth_metres(py, &self.request, depth, self.force)?;
        // H1's cloud grows to one point (12 bytes) and one pixel index (4) per depth pixel,
        // its buffers up to twice that while they grow; then the (N, 3) arrays.
        let (w, h) = image.size();
        ensure_memory("cloud", (w * h).saturating_mul(2 * 16 + 12 + 6))?;
        let range = self.request.params().depth_range;
        let (points, pixels) =
            py.detach(|| fusion::backproject_cloud(&range.clip(&image), &self.rays));
        let colors = match color_img {
            None => None,
            Some(color_img) => {
                let rig = self.request.rig();
                let (cw, ch) = (rig.color.width, rig.color.height);
                ensure_memory("cloud", cw * ch * 4)?;
                let (rgb, valid) = py
                    .detach(|| -> Result<_, GpuError> {
                        self.incoming = image;
                        if self.zbuffer.size() != (cw, ch) {
                            self.zbuffer = Image::filled(cw, ch, f32::NAN);
                        }
                        let mut zbuffer =
                            std::mem::replace(&mut self.zbuffer, Image::filled(0, 0, f32::NAN));
                        let registered = self.register_incoming(zbuffer.data_mut());
                        self.zbuffer = zbuffer;
                        registered?;
                        self.own_zbuffer_current = true;
                        self.color_of_frame(&color_img)
                    })
                    .map_err(fuse::gpu_err)?;
                Some(rows(py, &fusion::cloud_colors(&pixels, &rgb, &valid))?)
            }
        };
        Ok((rows(py, &points.points)?, colors))
    }

    fn __repr__(&self) -> String {
        let rig = self.request.rig();
        format!(
            "Registration(depth {}x{} -> colour {}x{}, engine {:?})",
            rig.depth.width,
            rig.depth.height,
            rig.color.width,
            rig.color.height,
            self.engine()
        )
    }
}

/// `cloud`'s result: points (N, 3) float32 metres and colours (N, 3) uint8 or None.
type CloudArrays<'py> = (Bound<'py, PyArray2<f32>>, Option<Bound<'py, PyArray2<u8>>>);

/// `depth` in metres, NaN or 0 = no sample, with the rig's depth correction applied as fuse
/// applies it: a uint16 (H, W) array of millimetres as `kfuse_io::images::read_depth` reads
/// a 16-bit PNG, or a float32 (H, W) array of millimetres (the decoder's and `Recording`'s
/// output) as `kfuse fuse --recording` converts it (`kfuse_sequence::process::depth_in_metres`);
/// (H, W) is the rig's depth camera's size. Depth in another unit is refused (or warned
/// about) as fuse refuses it, unless `force`.
fn depth_metres(
    py: Python<'_>,
    request: &fusion::Request,
    depth: &Bound<'_, PyAny>,
    force: bool,
) -> PyResult<Image<f32>> {
    let rig = request.rig();
    let arg = DepthArg::new(rig, depth)?;
    let values = arg.values()?;
    let mut image = Image::filled(rig.depth.width, rig.depth.height, f32::NAN);
    py.detach(|| values.metres_into(request, &mut image)).map_err(geometry_err)?;
    if !force {
        check_depth_unit(py, rig, &image)?;
    }
    Ok(image)
}

/// Whether `image`'s unit check has something to say ([`check_depth_unit`]: a median outside
/// 0.2-15 m, or under the Kinect's 0.5 m for a Kinect-size frame), found by counting
/// (`median_outside`, a few microseconds) instead of sorting.
fn unit_needs_words(rig: &Rig, image: &Image<f32>) -> bool {
    use geometry::fusion::units::{
        KINECT_MIN_DEPTH_M, MAX_MEDIAN_DEPTH_M, MIN_MEDIAN_DEPTH_M, median_outside,
    };
    let under = if is_kinect_depth(rig) { KINECT_MIN_DEPTH_M } else { MIN_MEDIAN_DEPTH_M };
    median_outside(image, UNIT_CHECK_STRIDE, under, MAX_MEDIAN_DEPTH_M)
        .is_some_and(|(below, above)| below || above)
}

/// A Kinect v2's depth camera (512 x 424), for fuse's warning of a median under 0.5 m.
fn is_kinect_depth(rig: &Rig) -> bool {
    (rig.depth.width, rig.depth.height) == (512, 424)
}

/// The stride of the depth-unit check's median: every 7th pixel (about 31 000 of a Kinect
/// frame, ~0.2 ms), so a stream of frames pays little; the median of a sample that size is
/// within a few millimetres of the whole frame's, and the band it is compared with is
/// 0.2-15 m.
const UNIT_CHECK_STRIDE: usize = 7;

/// `kfuse fuse`'s depth-unit rule (`geometry::fusion::units`): a frame whose median depth is
/// outside 0.2-15 m is in another unit (metres, 0.1 mm, a 65 535 fill): ValueError naming
/// `depth`, the median and the fix.
fn check_depth_unit(py: Python<'_>, rig: &Rig, image: &Image<f32>) -> PyResult<()> {
    use geometry::fusion::units::{
        DepthUnitProblem, KINECT_MIN_DEPTH_M, median_depth, unit_problem_of_median,
    };
    let Some(median) = py.detach(|| median_depth(image, UNIT_CHECK_STRIDE)) else {
        return Ok(());
    };
    const READ_AS: &str =
        "depth is read as millimetres (uint16, or float32 as kfuse.Decoder gives it)";
    let Some(problem) = unit_problem_of_median(median) else {
        // fuse's warning for a Kinect (512 x 424 depth camera) nearer than it measures.
        if is_kinect_depth(rig) && median < KINECT_MIN_DEPTH_M {
            let message = std::ffi::CString::new(format!(
                "depth: median depth {} m is nearer than the Kinect v2 measures ({KINECT_MIN_DEPTH_M} m): centimetres? {READ_AS}",
                median as f32
            ))
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
            PyErr::warn(py, &py.get_type::<pyo3::exceptions::PyUserWarning>(), &message, 1)?;
        }
        return Ok(());
    };
    let hint = match problem {
        DepthUnitProblem::TooNear(_) => "metres? pass depth * 1000",
        DepthUnitProblem::TooFar(_) => "0.1 mm units, or a 65535 fill? convert to millimetres",
    };
    Err(PyValueError::new_err(format!(
        "depth: {problem}, no scene a depth camera sees: {READ_AS}; {hint} (force=True fuses it anyway)"
    )))
}

/// `color` (C-contiguous uint8 (colour H, colour W, 3), RGB) as an image.
fn color_image(py: Python<'_>, rig: &Rig, color: &Bound<'_, PyAny>) -> PyResult<Image<[u8; 3]>> {
    let (cw, ch) = (rig.color.width, rig.color.height);
    let expected = format!("uint8 ({ch}, {cw}, 3)");
    let arr: PyReadonlyArray3<u8> = color
        .cast::<PyArray3<u8>>()
        .map_err(|_| bad_array("color", &expected, color, ""))?
        .readonly();
    if arr.shape() != [ch, cw, 3] {
        return Err(bad_array("color", &expected, color, ""));
    }
    let pixels = arr.as_slice().map_err(|_| {
        bad_array(
            "color",
            &expected,
            color,
            " that is not C-contiguous (pass numpy.ascontiguousarray(...))",
        )
    })?;
    py.detach(|| {
        Image::from_vec(cw, ch, pixels.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
    })
    .map_err(geometry_err)
}

/// The `open3d` module, or an ImportError that says kfuse does not depend on it and how to
/// install it.
fn open3d(py: Python<'_>) -> PyResult<Bound<'_, PyModule>> {
    py.import("open3d").map_err(|e| {
        pyo3::exceptions::PyImportError::new_err(format!(
            "to_open3d needs Open3D, which kfuse does not depend on: pip install open3d-cpu (or open3d) ({e})"
        ))
    })
}

/// `points` (N, 3) metres and optional uint8 `colors` (N, 3) as an `open3d.geometry.PointCloud`.
fn open3d_cloud<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    colors: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let o3d = open3d(py)?;
    let v3 = o3d.getattr("utility")?.getattr("Vector3dVector")?;
    let pcd = o3d.getattr("geometry")?.getattr("PointCloud")?.call0()?;
    pcd.setattr("points", v3.call1((points.call_method1("astype", ("float64",))?,))?)?;
    if let Some(c) = colors {
        let c = c.call_method1("astype", ("float64",))?.call_method1("__truediv__", (255.0,))?;
        pcd.setattr("colors", v3.call1((c,))?)?;
    }
    Ok(pcd)
}

/// to_open3d(points, colors=None) -> open3d.geometry.PointCloud: `Registration.cloud`'s
/// result (points float (N, 3) metres, colours uint8 (N, 3)) as an Open3D cloud (colours in
/// [0, 1]). Open3D is not a dependency of kfuse: without it, ImportError saying how to
/// install it.
#[pyfunction]
#[pyo3(signature = (points, colors = None))]
fn to_open3d<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    colors: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    open3d_cloud(py, points, colors)
}

/// `v`'s values in order, one Vec, or MemoryError (`what` names the call).
pub(crate) fn try_flat<T: Copy, const N: usize>(v: &[[T; N]], what: &str) -> PyResult<Vec<T>> {
    let mut flat = Vec::new();
    flat.try_reserve_exact(v.len() * N).map_err(|_| no_memory(what, std::mem::size_of_val(v)))?;
    flat.extend(v.iter().flatten().copied());
    Ok(flat)
}

/// Rows of `N` values as an (len, N) array.
pub(crate) fn rows<'py, T: numpy::Element + Copy, const N: usize>(
    py: Python<'py>,
    v: &[[T; N]],
) -> PyResult<Bound<'py, PyArray2<T>>> {
    let a = Array2::from_shape_vec((v.len(), N), try_flat(v, "rows")?)
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(a.into_pyarray(py))
}

/// Reads a depth image file as `kfuse fuse --depth` does (16-bit PNG/TIFF in millimetres,
/// float TIFF/EXR in metres) into float32 metres (H, W), NaN = no sample.
fn read_depth_file<'py>(py: Python<'py>, path: &Path) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let img = kfuse_io::images::read_depth(path, METRES_PER_MM).map_err(geometry_err)?;
    let (w, h) = img.size();
    let a = Array2::from_shape_vec((h, w), try_copy(img.data(), "read_depth")?)
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(a.into_pyarray(py))
}

/// read_depth(path) -> float32 (H, W) metres, NaN = no sample: a depth file read exactly as
/// `kfuse fuse --depth` reads it (16-bit PNG/TIFF in mm, float TIFF or OpenEXR in metres, such
/// as fuse's own depth_zbuffer.exr).
#[pyfunction]
fn read_depth<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyArray2<f32>>> {
    read_depth_file(py, &path)
}

/// Kinect v2 depth decoder on the CPU (`kinect_usb::decoder::DepthDecoder`, as `kfuse
/// capture` decodes): raw 2 984 960-byte depth frames into depth (mm) and IR.
///
/// Decoder(p0_tables, x_table, z_table, bilateral=True, edge_aware=True,
///         orientation="scene", precision="fast")
///
/// `p0_tables` is the sensor's P0-table response (bytes); `x_table`, `z_table` are float32
/// arrays of 424 x 512 values (the protocol's x/z tables). `orientation` "scene" (kfuse's
/// rule) or "sensor" (mirrored, as libfreenect2 and the test vectors); `precision` "fast" or
/// "exact" (bit-identical to libfreenect2's CPU decoder).
#[pyclass(name = "Decoder", module = "kfuse")]
struct PyDecoder {
    dec: DepthDecoder,
}

/// A float32 table of [`PIXELS`] values, 1-D or (424, 512), C-contiguous.
fn table(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<f32>> {
    let expected = format!("float32 ({}, {}) or ({PIXELS},)", raw::HEIGHT, raw::WIDTH);
    let bad = |why: &str| bad_array(name, &expected, obj, why);
    let arr = obj.cast::<numpy::PyArrayDyn<f32>>().map_err(|_| bad(""))?.readonly();
    if arr.len() != PIXELS || !(arr.ndim() == 1 || arr.shape() == [raw::HEIGHT, raw::WIDTH]) {
        return Err(bad(""));
    }
    let v = arr
        .as_slice()
        .map_err(|_| bad(" that is not C-contiguous (pass numpy.ascontiguousarray(...))"))?;
    Ok(v.to_vec())
}

#[pymethods]
impl PyDecoder {
    /// See the class documentation.
    #[new]
    #[pyo3(signature = (p0_tables, x_table, z_table, bilateral = true, edge_aware = true, orientation = "scene", precision = "fast"))]
    fn new(
        p0_tables: &[u8],
        x_table: &Bound<'_, PyAny>,
        z_table: &Bound<'_, PyAny>,
        bilateral: bool,
        edge_aware: bool,
        orientation: &str,
        precision: &str,
    ) -> PyResult<Self> {
        let orientation = match short_text("orientation", orientation)? {
            "scene" => Orientation::Scene,
            "sensor" => Orientation::Sensor,
            o => {
                return Err(PyValueError::new_err(format!(
                    "orientation: '{o}' is not \"scene\" or \"sensor\""
                )));
            }
        };
        let precision = match short_text("precision", precision)? {
            "fast" => DecoderPrecision::Fast,
            "exact" => DecoderPrecision::Exact,
            p => {
                return Err(PyValueError::new_err(format!(
                    "precision: '{p}' is not \"fast\" or \"exact\""
                )));
            }
        };
        let usb = |e: kinect_usb::KinectError| PyValueError::new_err(e.to_string());
        let p0 = P0Tables::from_response(p0_tables).map_err(usb)?;
        let xz = XzTables::from_vecs(table(x_table, "x_table")?, table(z_table, "z_table")?)
            .map_err(usb)?;
        let config = DecoderConfig { bilateral, edge_aware, parallel: true, orientation };
        let dec = DepthDecoder::new(DecoderParams::default(), config, &xz, &p0)
            .map_err(usb)?
            .with_precision(precision);
        Ok(Self { dec })
    }

    /// Decodes one raw depth frame (bytes of 2 984 960) into (depth, ir): float32 (424, 512)
    /// each, depth in millimetres (0 = no measurement), IR in the decoder's amplitude units.
    /// Releases the GIL.
    fn decode<'py>(&mut self, py: Python<'py>, raw: &[u8]) -> PyResult<DecodedFrame<'py>> {
        let dec = &mut self.dec;
        let (depth, ir) = py
            .detach(|| {
                let mut depth = vec![0f32; PIXELS];
                let mut ir = vec![0f32; PIXELS];
                dec.decode(raw, &mut depth, &mut ir).map(|()| (depth, ir))
            })
            .map_err(|e| PyValueError::new_err(format!("raw: {e}")))?;
        let shape = (raw::HEIGHT, raw::WIDTH);
        let to = |v: Vec<f32>| {
            Array2::from_shape_vec(shape, v).map_err(|e| PyValueError::new_err(e.to_string()))
        };
        Ok((to(depth)?.into_pyarray(py), to(ir)?.into_pyarray(py)))
    }
}

/// decode(raw, p0_tables, x_table, z_table, bilateral=True, edge_aware=True,
///        orientation="scene", precision="fast") -> (depth, ir)
///
/// One raw depth frame decoded in one call: `kfuse.Decoder(p0_tables, x_table, z_table,
/// ...).decode(raw)`, with the same arguments, results and errors. Depth in millimetres and IR,
/// float32 (424, 512) each. For a stream, build one `Decoder` and call its `decode` per frame:
/// this builds the decoder's tables (a few milliseconds) on every call. Releases the GIL.
#[pyfunction]
#[pyo3(signature = (raw, p0_tables, x_table, z_table, bilateral = true, edge_aware = true, orientation = "scene", precision = "fast"))]
#[allow(clippy::too_many_arguments)] // Decoder's own signature, plus the frame
fn decode<'py>(
    py: Python<'py>,
    raw: &[u8],
    p0_tables: &[u8],
    x_table: &Bound<'py, PyAny>,
    z_table: &Bound<'py, PyAny>,
    bilateral: bool,
    edge_aware: bool,
    orientation: &str,
    precision: &str,
) -> PyResult<DecodedFrame<'py>> {
    PyDecoder::new(p0_tables, x_table, z_table, bilateral, edge_aware, orientation, precision)?
        .decode(py, raw)
}

/// `Decoder.decode`'s result: depth (mm) and IR, float32 (424, 512) each.
type DecodedFrame<'py> = (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<f32>>);

/// kfuse from Python: calibration (`calibrate`), rig files and the exact z-buffered
/// depth-to-colour registration.
#[pymodule]
fn kfuse(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyCamera>()?;
    m.add_class::<PyRig>()?;
    m.add_class::<PyRegistration>()?;
    m.add_class::<PyDecoder>()?;
    m.add_function(wrap_pyfunction!(decode, m)?)?;
    m.add_function(wrap_pyfunction!(read_depth, m)?)?;
    m.add_class::<fuse::PyFusedFrame>()?;
    m.add_class::<volume::PyVolume>()?;
    m.add_function(wrap_pyfunction!(fuse::fuse, m)?)?;
    m.add_class::<fuse::PyEngine>()?;
    m.add_function(wrap_pyfunction!(to_open3d, m)?)?;
    m.add_class::<recording::PyRecording>()?;
    m.add_class::<recording::PyRecordingFrame>()?;
    m.add_class::<calibrate::PyCalibration>()?;
    m.add_class::<calibrate::PyCameraFit>()?;
    m.add_function(wrap_pyfunction!(calibrate::calibrate, m)?)?;
    m.add_class::<device::PyDevice>()?;
    m.add_class::<device::PyDeviceFrame>()?;
    m.add_function(wrap_pyfunction!(device::devices, m)?)?;
    Ok(())
}
