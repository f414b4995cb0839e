//! `kfuse.Device(backend)`: a live Kinect v2 (or the simulated one) through `kfuse-capture`,
//! what `kfuse capture` and the viewer's live page open: `Session::open` opens and starts
//! the sensor, `FramePump` decodes each depth frame with the session's decoder and keeps the
//! newest colour JPEG, `record::record` writes a `.kfrec` recording. No algorithm of its own.

use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use kfuse_capture::{
    CaptureError, DecoderOptions, FramePump, SensorSource, Session, SimOptions, SimRing, multi,
    write_params_json,
};
use kinect_usb::raw::{HEIGHT, WIDTH};
use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray2, PyArray3};
use pyo3::exceptions::{PyKeyboardInterrupt, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

/// Longest wait `Device.next_frame` accepts, seconds: a sensor that sends nothing for a minute
/// is gone, and the bound keeps `Duration::from_secs_f64` away from huge or invalid values.
const MAX_TIMEOUT_S: f64 = 60.0;

/// Most depth frames `Device.record` takes in one call: an hour at the sensor's 30 Hz (a
/// recording holds about 3 MB per frame, so this is already ~300 GB).
const MAX_RECORD_FRAMES: u64 = 30 * 3600;

/// A capture error as the exception a Python user expects: no sensor, a busy one, a sensor
/// that disappeared (unplugged) or a file that cannot be written is an OSError, a bad setting a ValueError, a failing stream a
/// RuntimeError. The message is the CLI's (`error: ` aside).
fn capture_err(e: CaptureError) -> PyErr {
    match &e {
        CaptureError::NoSensor { .. }
        | CaptureError::Busy(_)
        | CaptureError::Write { .. }
        | CaptureError::Device(kinect_usb::KinectError::Disconnected { .. }) => {
            PyOSError::new_err(e.to_string())
        }
        // A recording or parameter file that cannot be created (a missing folder, no
        // permission): Python's OSError with errno, so that `except FileNotFoundError` works.
        CaptureError::Device(kinect_usb::KinectError::File { path, source })
        | CaptureError::File(geometry::GeometryError::Io { path, source }) => PyOSError::new_err((
            source.raw_os_error().unwrap_or(0),
            source.to_string(),
            path.clone(),
        )),
        CaptureError::Config(_) | CaptureError::Setting { .. } => {
            PyValueError::new_err(e.to_string())
        }
        _ => PyRuntimeError::new_err(e.to_string()),
    }
}

/// One frame pair of a live sensor, taken by `Device.next_frame`: the newest depth frame
/// (decoded) and the newest colour frame, both received after the call began.
#[pyclass(name = "DeviceFrame", module = "kfuse", frozen)]
pub(crate) struct PyDeviceFrame {
    number: u64,
    depth_mm: Vec<f32>,
    ir: Vec<f32>,
    color_jpeg: Vec<u8>,
    depth_timestamp: Option<u32>,
    color_timestamp: Option<u32>,
}

fn image2<'py>(py: Python<'py>, data: &[f32]) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let a = Array2::from_shape_vec((HEIGHT, WIDTH), data.to_vec())
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(a.into_pyarray(py))
}

#[pymethods]
impl PyDeviceFrame {
    /// Depth frames decoded since the device opened (1 for the first).
    #[getter]
    fn number(&self) -> u64 {
        self.number
    }

    /// Depth, float32 (424, 512) millimetres, 0 = no measurement, as the scene is (the
    /// decoder's default: both filters, the Fast precision, as `kfuse capture`). Registration.register
    /// and kfuse.fuse take it as it is.
    #[getter]
    fn depth<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        image2(py, &self.depth_mm)
    }

    /// IR amplitude, float32 (424, 512), as the scene is (what `kfuse capture` writes, before
    /// its 16-bit rounding, into ir_NNNN.png).
    #[getter]
    fn ir<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        image2(py, &self.ir)
    }

    /// The colour JPEG as the sensor streamed it (mirrored left-right).
    #[getter]
    fn color_jpeg<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &self.color_jpeg)
    }

    /// The depth frame's sensor timestamp, ticks of 0.125 ms (wraps at 2^32).
    #[getter]
    fn depth_timestamp(&self) -> Option<u32> {
        self.depth_timestamp
    }

    /// The colour frame's sensor timestamp, ticks of 0.125 ms (wraps at 2^32).
    #[getter]
    fn color_timestamp(&self) -> Option<u32> {
        self.color_timestamp
    }

    /// The colour frame decoded as the scene is (unmirrored), uint8 (1080, 1920, 3) RGB.
    /// Releases the GIL.
    fn color<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<u8>>> {
        let jpeg = &self.color_jpeg;
        let img = py
            .detach(|| kfuse_io::sensor_color::decode_mirrored(jpeg))
            .map_err(|e| PyValueError::new_err(format!("colour frame {}: {e}", self.number)))?;
        let (w, h) = img.size();
        let flat: Vec<u8> = img.data().iter().flatten().copied().collect();
        let a = Array3::from_shape_vec((h, w, 3), flat)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(a.into_pyarray(py))
    }

    fn __repr__(&self) -> String {
        format!(
            "DeviceFrame(number={}, depth_timestamp={:?}, color_timestamp={:?})",
            self.number, self.depth_timestamp, self.color_timestamp
        )
    }
}

/// A Kinect v2, opened and streaming: for frame in kfuse.Device("usb"): frame.depth, ...
///
/// Device(backend="usb", serial=None, sim_sensors=1): "usb" opens the first Kinect v2 on the
/// USB bus (or the one of this serial, as `kfuse capture --device SERIAL`), "sim" the
/// simulated Kinect v2 (`--backend sim`: the synthetic scene, its own factory parameters, no
/// hardware; with sim_sensors=2..4 one sensor of the simulated ring of `--sim-sensors N`,
/// the first or the one of `serial`; kfuse.devices lists them; sim_unplug_after=N: the
/// simulated sensor disappears after N frame periods, `--sim-unplug-after N`). No sensor, or
/// one that disappears (unplugged), is an OSError with the message `kfuse capture` prints. Use it as a context manager
/// (or call close()) to release the sensor. next_frame() waits for a fresh depth + colour
/// pair; iterating yields them one after another; record(path, frames) writes a .kfrec
/// recording that kfuse.Recording and `kfuse fuse --recording` read. Waits release the GIL;
/// Ctrl-C interrupts them with KeyboardInterrupt. Usable from any thread (a
/// ThreadPoolExecutor worker), one call at a time: a call while another thread's call on the
/// same Device runs is a RuntimeError saying so. Dropped in any thread, it releases the sensor.
#[pyclass(name = "Device", module = "kfuse", frozen)]
pub(crate) struct PyDevice {
    /// The sensor, behind [`crate::one_call_at_a_time`]: a `Session` is `Send` but not `Sync`,
    /// and the lock makes the class shareable between Python threads.
    state: Mutex<DeviceState>,
}

/// What a `Device` holds: the session (None once closed) and the pump of its frames.
struct DeviceState {
    session: Option<Session>,
    pump: FramePump,
}

/// The source of `backend` (and `serial`, `sim_sensors`, `sim_unplug_after`): the CLI's
/// `--backend`, `--device SERIAL`, `--sim-sensors N` and `--sim-unplug-after N`.
fn source_of(
    backend: &str,
    serial: Option<&str>,
    sim_sensors: usize,
    sim_unplug_after: Option<u64>,
) -> PyResult<SensorSource> {
    let backend = crate::short_text("backend", backend)?;
    let serial = serial.map(|s| crate::short_text("serial", s)).transpose()?;
    if sim_unplug_after.is_some() && backend != "sim" {
        return Err(PyValueError::new_err(format!(
            "sim_unplug_after: only with backend=\"sim\", got backend={backend:?}"
        )));
    }
    let max = kinect_usb::sim::ring::MAX_SIM_SENSORS;
    if !(1..=max).contains(&sim_sensors) || (sim_sensors > 1 && backend != "sim") {
        return Err(PyValueError::new_err(format!(
            "sim_sensors: expected 1..={max} with backend=\"sim\", got {sim_sensors} with backend={backend:?}"
        )));
    }
    let ring = (sim_sensors > 1).then(|| SimRing {
        sensors: sim_sensors,
        index: 0,
        serial: kinect_usb::sim::ring::serial(0),
    });
    let base = match backend {
        "usb" => SensorSource::Usb,
        "sim" => SensorSource::Sim(SimOptions {
            ring,
            unplug_after: sim_unplug_after,
            ..SimOptions::default()
        }),
        // The CLI's hidden `--backend absent`: a bus with no Kinect, whatever is plugged in
        // (tests of what happens without a sensor).
        "absent" => SensorSource::Absent,
        other => {
            return Err(PyValueError::new_err(format!(
                "backend: expected \"usb\" or \"sim\", got {other:?}"
            )));
        }
    };
    let Some(serial) = serial else { return Ok(base) };
    let sensors = multi::connected(&base).map_err(capture_err)?;
    let found = sensors.iter().find(|c| c.serial.as_deref() == Some(serial));
    match found {
        Some(c) => Ok(c.source.clone()),
        None => {
            let have: Vec<&str> =
                sensors.iter().map(|c| c.serial.as_deref().unwrap_or("?")).collect();
            Err(PyOSError::new_err(format!(
                "no Kinect v2 with serial {serial}; connected: {}",
                have.join(", ")
            )))
        }
    }
}

/// The sensors a backend offers, as `kfuse devices` lists them: dicts of serial (None when a
/// real sensor could not be asked: busy, permissions) and line (its line in `kfuse devices`).
/// No sensor is an OSError with the CLI's message.
#[pyfunction]
#[pyo3(signature = (backend = "usb", sim_sensors = 1))]
pub(crate) fn devices<'py>(
    py: Python<'py>,
    backend: &str,
    sim_sensors: usize,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    let source = source_of(backend, None, sim_sensors, None)?;
    let sensors = py.detach(|| multi::connected(&source)).map_err(capture_err)?;
    sensors
        .into_iter()
        .map(|c| {
            let d = PyDict::new(py);
            d.set_item("serial", c.serial)?;
            d.set_item("line", c.line)?;
            Ok(d)
        })
        .collect()
}

impl DeviceState {
    fn session(&mut self) -> PyResult<&mut Session> {
        self.session.as_mut().ok_or_else(|| PyValueError::new_err("the device is closed"))
    }
}

impl PyDevice {
    /// The state for this call, or a RuntimeError while another thread's call runs.
    fn state(&self) -> PyResult<MutexGuard<'_, DeviceState>> {
        crate::one_call_at_a_time(&self.state, "Device")
    }
}

#[pymethods]
impl PyDevice {
    /// See the class documentation.
    #[new]
    #[pyo3(signature = (backend = "usb", serial = None, sim_sensors = 1, sim_unplug_after = None))]
    fn new(
        py: Python<'_>,
        backend: &str,
        serial: Option<&str>,
        sim_sensors: usize,
        sim_unplug_after: Option<u64>,
    ) -> PyResult<Self> {
        let source = source_of(backend, serial, sim_sensors, sim_unplug_after)?;
        let session = py.detach(|| Session::open(&source)).map_err(capture_err)?;
        let decoder = session.decoder(&DecoderOptions::default()).map_err(capture_err)?;
        let state = DeviceState { session: Some(session), pump: FramePump::new(decoder) };
        Ok(Self { state: Mutex::new(state) })
    }

    /// The sensor's serial number and firmware version, as it reported them.
    #[getter]
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let mut state = self.state()?;
        let i = state.session()?.info();
        let d = PyDict::new(py);
        d.set_item("serial", i.serial.clone())?;
        d.set_item("firmware", i.firmware.clone())?;
        Ok(d)
    }

    /// Waits for a depth and a colour frame both received after this call began (at most
    /// `timeout` seconds, 0 < timeout <= 60) and returns them as a DeviceFrame. Errors: the
    /// sensor disappeared (OSError), a stream that stops otherwise (RuntimeError), Ctrl-C
    /// (KeyboardInterrupt), a closed device.
    #[pyo3(signature = (timeout = 3.0))]
    fn next_frame(&self, py: Python<'_>, timeout: f64) -> PyResult<PyDeviceFrame> {
        if !(timeout > 0.0 && timeout <= MAX_TIMEOUT_S) {
            return Err(PyValueError::new_err(format!(
                "timeout: expected seconds in (0, {MAX_TIMEOUT_S}], got {timeout}"
            )));
        }
        let since = Instant::now();
        let deadline = since + Duration::from_secs_f64(timeout);
        let mut state = self.state()?;
        let DeviceState { session, pump } = &mut *state;
        let session =
            session.as_mut().ok_or_else(|| PyValueError::new_err("the device is closed"))?;
        // One frame at a time without the GIL, Ctrl-C checked between frames.
        loop {
            let fresh = py
                .detach(|| -> Result<bool, CaptureError> {
                    pump.pump(session, deadline.saturating_duration_since(Instant::now()))?;
                    Ok(pump.holds_pair_since(since))
                })
                .map_err(capture_err)?;
            py.check_signals()?;
            if fresh {
                break;
            }
            if Instant::now() >= deadline {
                return Err(PyRuntimeError::new_err(format!(
                    "no complete depth + colour pair within {timeout} s"
                )));
            }
        }
        Ok(PyDeviceFrame {
            number: pump.depth_frames(),
            depth_mm: pump.depth_mm().to_vec(),
            ir: pump.ir().to_vec(),
            color_jpeg: pump.color_jpeg().to_vec(),
            depth_timestamp: pump.depth_timestamp(),
            color_timestamp: pump.color_timestamp(),
        })
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<PyDeviceFrame> {
        self.next_frame(py, 3.0)
    }

    /// Records `frames` depth frames (1..=108000, an hour) and the colour frames between them
    /// into the .kfrec file `path`, as `kfuse capture record` does: written to a temporary
    /// file and moved into place, so `path` is a complete, replayable recording or is left
    /// as it was. An existing `path` is refused before anything is recorded (FileExistsError
    /// naming it; a folder is a ValueError) unless `overwrite`, as Rig.save and
    /// Calibration.save refuse it. Returns the frames recorded. A stream that stops early
    /// still leaves a complete file of the frames so far (`stopped_by` in the result says
    /// why; a sensor that disappeared raises OSError with `kfuse capture record`'s message,
    /// which says how many frames the file kept); Ctrl-C stops at the next frame, writes the frames so far and then raises
    /// KeyboardInterrupt (nothing is written when it comes before the first frame). Releases
    /// the GIL.
    #[pyo3(signature = (path, frames, overwrite = false))]
    fn record<'py>(
        &self,
        py: Python<'py>,
        path: PathBuf,
        frames: u64,
        overwrite: bool,
    ) -> PyResult<Bound<'py, PyDict>> {
        if !(1..=MAX_RECORD_FRAMES).contains(&frames) {
            return Err(PyValueError::new_err(format!(
                "frames: expected 1..={MAX_RECORD_FRAMES}, got {frames}"
            )));
        }
        let mut state = self.state()?;
        let session = state.session()?;
        crate::check_output_file(&path, overwrite, "session.kfrec", &[])?;
        let interrupted = std::sync::atomic::AtomicBool::new(false);
        let stop = || {
            // Signals are only seen with the GIL: take it for the check, once per frame.
            let hit = Python::attach(|py| py.check_signals().is_err());
            if hit {
                interrupted.store(true, std::sync::atomic::Ordering::SeqCst);
            }
            hit
        };
        let done = py
            .detach(|| kfuse_capture::record::record(session, &path, frames, &stop, &mut |_| {}))
            .map_err(capture_err)?;
        if interrupted.load(std::sync::atomic::Ordering::SeqCst) {
            let what = if done.written {
                format!("recording stopped: {} frames written to {}", done.frames, path.display())
            } else {
                "recording stopped before the first frame: nothing written".to_string()
            };
            return Err(PyKeyboardInterrupt::new_err(what));
        }
        if let Some(e @ kinect_usb::KinectError::Disconnected { .. }) = &done.stopped_by {
            let m = kfuse_capture::record::unplugged_message(e, done.frames, &path);
            return Err(PyOSError::new_err(m));
        }
        let d = PyDict::new(py);
        d.set_item("frames", done.frames)?;
        d.set_item("path", path)?;
        d.set_item("stopped_by", done.stopped_by.map(|e| e.to_string()))?;
        Ok(d)
    }

    /// Writes `folder/kinect_params.json`, the sensor's factory parameters of the images as
    /// the scene is (what `kfuse capture` writes beside its shots; kfuse.Rig.from_kinect_params
    /// reads it). Returns the file's path. An existing kinect_params.json (another sensor's,
    /// or any file of that name) raises FileExistsError unless `overwrite=True`, as every
    /// writer of the package.
    #[pyo3(signature = (folder, overwrite = false))]
    fn write_params(&self, folder: PathBuf, overwrite: bool) -> PyResult<PathBuf> {
        let path = folder.join("kinect_params.json");
        crate::check_output_file(&path, overwrite, "kinect_params.json", &[])?;
        let info = self.state()?.session()?.info().clone();
        write_params_json(&folder, &info).map_err(capture_err)?;
        Ok(path)
    }

    /// Stops the streams and releases the sensor (again: nothing). A RuntimeError while
    /// another thread's call on this Device runs.
    fn close(&self) -> PyResult<()> {
        if let Some(mut s) = self.state()?.session.take() {
            s.close();
        }
        Ok(())
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_args))]
    fn __exit__(&self, _args: &Bound<'_, pyo3::types::PyTuple>) -> PyResult<bool> {
        self.close()?;
        Ok(false)
    }

    fn __repr__(&self) -> String {
        let Ok(state) = self.state.try_lock() else { return "Device(in use)".into() };
        match &state.session {
            Some(s) => {
                format!("Device(serial={:?}, source={:?})", s.info().serial, s.source().name())
            }
            None => "Device(closed)".into(),
        }
    }
}
