//! `kfuse.Recording(path)`: the frames of a `.kfrec` recording, read, matched and decoded by
//! `kfuse-sequence` (`source::RecordingSource`, `matching::Matcher`,
//! `process::recording_decoder`), the stages `kfuse fuse --recording` runs; or of a ROS bag
//! (`bag::BagSource`: rosbag2/MCAP or ROS 1, depth already decoded), as `fuse` reads one.

use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

use kfuse_sequence::SequenceError;
use kfuse_sequence::bag::{BagSource, TopicChoice};
use kfuse_sequence::color::ColorJpeg;
use kfuse_sequence::matching::{DEFAULT_MAX_SKEW_TICKS, Matched, Matcher, Missing, Pair};
use kfuse_sequence::process::recording_decoder;
use kfuse_sequence::source::{RecordingSource, TICKS_PER_SECOND};
use kinect_usb::decoder::DepthDecoder;
use kinect_usb::raw::{self, PIXELS};
use kinect_usb::recording::ReadOptions;
use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray2, PyArray3};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

fn sequence_err(e: SequenceError) -> PyErr {
    match &e {
        SequenceError::Recording(kinect_usb::KinectError::File { .. }) => {
            PyOSError::new_err(e.to_string())
        }
        _ => PyValueError::new_err(e.to_string()),
    }
}

/// One depth frame of a recording and its colour partner (the colour frame nearest in time,
/// within half a frame period), as `kfuse fuse --recording` pairs them.
#[pyclass(name = "RecordingFrame", module = "kfuse", frozen)]
pub(crate) struct PyRecordingFrame {
    pair: Pair,
    depth_mm: Vec<f32>,
    path: PathBuf,
    /// The depth frame's size (columns, rows).
    size: (usize, usize),
    /// From a bag: no raw frame, colour as the scene is.
    from_bag: bool,
}

#[pymethods]
impl PyRecordingFrame {
    /// Frame number: depth frame periods since the recording's first frame (a lost frame
    /// leaves a gap), as in index.json and the output names (depth/NNNNNN.png).
    #[getter]
    fn number(&self) -> u64 {
        self.pair.number
    }

    /// The sensor's depth sequence number.
    #[getter]
    fn depth_sequence(&self) -> u32 {
        self.pair.depth.sequence
    }

    /// The depth frame's sensor time in ticks of 0.125 ms (8000 per second), unwrapped.
    #[getter]
    fn depth_time_ticks(&self) -> u64 {
        self.pair.depth.timestamp
    }

    /// The depth frame's sensor time in seconds.
    #[getter]
    fn depth_time(&self) -> f64 {
        self.pair.depth.timestamp as f64 / TICKS_PER_SECOND as f64
    }

    /// Depth decoded as fuse decodes a recording (both filters, the Fast precision): float32
    /// (424, 512) millimetres, 0 = no measurement, as the scene is. Registration.register
    /// and kfuse.fuse take it as it is.
    #[getter]
    fn depth<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let a = Array2::from_shape_vec((self.size.1, self.size.0), self.depth_mm.clone())
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(a.into_pyarray(py))
    }

    /// The raw depth frame as the sensor sent it (2 984 960 bytes; kfuse.Decoder's input).
    /// A bag holds decoded depth only: ValueError.
    #[getter]
    fn raw_depth<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        if self.from_bag {
            return Err(PyValueError::new_err(format!(
                "{}: a bag holds decoded depth, no raw frame (use .depth)",
                self.path.display()
            )));
        }
        Ok(PyBytes::new(py, &self.pair.depth.data))
    }

    /// The colour partner's JPEG as the sensor streamed it (mirrored left-right), or None
    /// when no colour frame was close enough in time. From a bag: its picture as the bag
    /// holds it (as the scene is; an rgb8/bgr8 Image as a PNG).
    #[getter]
    fn color_jpeg<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyBytes>> {
        self.pair.color.as_ref().map(|c| PyBytes::new(py, &c.jpeg))
    }

    /// The colour partner's sensor time in ticks, or None.
    #[getter]
    fn color_time_ticks(&self) -> Option<u64> {
        self.pair.color.as_ref().map(|c| c.timestamp)
    }

    /// The colour partner's sensor time in seconds, or None.
    #[getter]
    fn color_time(&self) -> Option<f64> {
        self.pair.color.as_ref().map(|c| c.timestamp as f64 / TICKS_PER_SECOND as f64)
    }

    /// The colour partner decoded as the scene is (unmirrored), uint8 (1080, 1920, 3) RGB,
    /// as fuse decodes it; None without a partner. Releases the GIL.
    fn color<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray3<u8>>>> {
        let Some(c) = &self.pair.color else { return Ok(None) };
        let jpeg = ColorJpeg { bytes: c.jpeg.clone(), mirrored: !self.from_bag };
        let name = self.path.join(format!("colour of frame {}", self.pair.number));
        let img = py.detach(|| jpeg.decode(&name)).map_err(sequence_err)?;
        let (w, h) = img.size();
        let flat: Vec<u8> = img.data().iter().flatten().copied().collect();
        let a = Array3::from_shape_vec((h, w, 3), flat)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(Some(a.into_pyarray(py)))
    }

    fn __repr__(&self) -> String {
        format!(
            "RecordingFrame(number={}, depth_sequence={}, depth_time={:.6} s, color={})",
            self.pair.number,
            self.pair.depth.sequence,
            self.depth_time(),
            if self.pair.color.is_some() { "True" } else { "None" }
        )
    }
}

/// A lost frame as a dict: number, depth_sequence, reason (index.json's "missing" entry).
fn missing_dict<'py>(py: Python<'py>, m: &Missing) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("number", m.number)?;
    d.set_item("depth_sequence", m.depth_sequence)?;
    let reason = serde_json::to_value(m.reason)
        .ok()
        .and_then(|v| v.as_str().map(String::from))
        .unwrap_or_default();
    d.set_item("reason", reason)?;
    Ok(d)
}

/// The frames of a `.kfrec` recording (`kfuse capture record`), streamed: for frame in
/// kfuse.Recording(path): frame.depth, frame.color_jpeg, frame.depth_time, ...
///
/// Recording(path, allow_truncated=False, skip_corrupt=False) reads, pairs and decodes as
/// `kfuse fuse --recording` does (--allow-truncated, --skip-corrupt).
/// A ROS bag (a rosbag2 folder, an .mcap file, a ROS 1 .bag with uncompressed chunks) is read
/// as `kfuse fuse --recording BAG` reads it: its depth topic (in millimetres here) paired with
/// its colour topic by header stamp; `info` then names the topics. The depth frames that
/// never arrived complete are in `lost` (complete once the iteration ends). Ctrl-C between
/// frames raises KeyboardInterrupt. Usable from any thread (a ThreadPoolExecutor worker), one
/// call at a time: a call while another thread's call on the same Recording runs is a
/// RuntimeError saying so. Dropped in any thread, it closes the file.
#[pyclass(name = "Recording", module = "kfuse", frozen)]
pub(crate) struct PyRecording {
    path: PathBuf,
    /// The reader, behind [`crate::one_call_at_a_time`]: the lock makes the class shareable
    /// between Python threads.
    state: Mutex<RecordingState>,
}

/// Where a `Recording`'s frames come from.
enum Source {
    /// A `.kfrec` and its depth decoder.
    Kfrec(Box<RecordingSource>, Box<DepthDecoder>),
    /// A bag (depth decoded already).
    Bag(Box<BagSource>),
}

/// What a `Recording` reads with: the file, the matcher and the decoder, and the frames so far.
struct RecordingState {
    source: Source,
    matcher: Matcher,
    lost: Vec<Missing>,
    ended: bool,
    /// A frame decoded when Ctrl-C came: returned by the next `__next__`, so that the
    /// KeyboardInterrupt loses no frame.
    pending: Option<PyRecordingFrame>,
}

impl PyRecording {
    /// The state for this call, or a RuntimeError while another thread's call runs.
    fn state(&self) -> PyResult<MutexGuard<'_, RecordingState>> {
        crate::one_call_at_a_time(&self.state, "Recording")
    }
}

impl RecordingState {
    /// The next matched item: from the matcher, else after feeding it the source's events.
    fn next_matched(&mut self, py: Python<'_>) -> PyResult<Option<Matched>> {
        loop {
            if let Some(m) = self.matcher.pop() {
                return Ok(Some(m));
            }
            if self.ended {
                return Ok(None);
            }
            // Between packets' frames: Ctrl-C is a KeyboardInterrupt here.
            py.check_signals()?;
            let (source, matcher) = (&mut self.source, &mut self.matcher);
            let ended = py
                .detach(|| -> Result<bool, SequenceError> {
                    let next = match source {
                        Source::Kfrec(s, _) => s.next_event()?,
                        Source::Bag(b) => b.next_event()?,
                    };
                    match next {
                        Some(ev) => {
                            matcher.push(ev);
                            Ok(false)
                        }
                        None => {
                            matcher.finish();
                            Ok(true)
                        }
                    }
                })
                .map_err(sequence_err)?;
            self.ended = ended;
        }
    }
}

#[pymethods]
impl PyRecording {
    /// See the class documentation.
    #[new]
    #[pyo3(signature = (path, allow_truncated = false, skip_corrupt = false))]
    fn new(path: PathBuf, allow_truncated: bool, skip_corrupt: bool) -> PyResult<Self> {
        let source = if kfuse_sequence::bag::is_bag(&path) {
            let bag = BagSource::open(&path, &TopicChoice::default()).map_err(sequence_err)?;
            Source::Bag(Box::new(bag))
        } else {
            let options = ReadOptions { keep_prefix: allow_truncated, skip_corrupt };
            let source = RecordingSource::open(&path, options).map_err(sequence_err)?;
            let decoder = recording_decoder(source.info()).map_err(sequence_err)?;
            Source::Kfrec(Box::new(source), Box::new(decoder))
        };
        let state = RecordingState {
            source,
            matcher: Matcher::new(DEFAULT_MAX_SKEW_TICKS),
            lost: Vec::new(),
            ended: false,
            pending: None,
        };
        Ok(Self { path, state: Mutex::new(state) })
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<Option<PyRecordingFrame>> {
        let mut state = self.state()?;
        if let Some(frame) = state.pending.take() {
            return Ok(Some(frame));
        }
        while let Some(m) = state.next_matched(py)? {
            match m {
                Matched::Missing(missing) => state.lost.push(missing),
                Matched::Frame(pair) => {
                    let frame = match &mut state.source {
                        Source::Kfrec(_, decoder) => {
                            let depth_mm = py
                                .detach(|| {
                                    let mut depth = vec![0f32; PIXELS];
                                    let mut ir = vec![0f32; PIXELS];
                                    decoder
                                        .decode(&pair.depth.data, &mut depth, &mut ir)
                                        .map(|()| depth)
                                })
                                .map_err(|e| {
                                    PyValueError::new_err(format!(
                                        "{}: frame {}: {e}",
                                        self.path.display(),
                                        pair.number
                                    ))
                                })?;
                            let size = (raw::WIDTH, raw::HEIGHT);
                            PyRecordingFrame {
                                pair,
                                depth_mm,
                                path: self.path.clone(),
                                size,
                                from_bag: false,
                            }
                        }
                        Source::Bag(b) => {
                            let size = b.depth_size().unwrap_or((0, 0));
                            // The bag's metres (little-endian f32) in millimetres.
                            let depth_mm = pair
                                .depth
                                .data
                                .chunks_exact(4)
                                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]) * 1000.0)
                                .collect();
                            PyRecordingFrame {
                                pair,
                                depth_mm,
                                path: self.path.clone(),
                                size,
                                from_bag: true,
                            }
                        }
                    };
                    // Ctrl-C during the decode: raised here, the frame kept for the next call.
                    if let Err(e) = py.check_signals() {
                        state.pending = Some(frame);
                        return Err(e);
                    }
                    return Ok(Some(frame));
                }
            }
        }
        Ok(None)
    }

    /// The depth frames that never arrived complete, so far (all of them once the iteration
    /// has ended): dicts of number, depth_sequence and reason ("dropped", "incomplete",
    /// "dropped_or_incomplete", "repeated", "out_of_order", "discontinuity"), in frame order.
    #[getter]
    fn lost<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.state()?.lost.iter().map(|m| missing_dict(py, m)).collect()
    }

    /// The sensor's serial number and firmware, as recorded.
    #[getter]
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let state = self.state()?;
        let d = PyDict::new(py);
        match &state.source {
            Source::Kfrec(s, _) => {
                let i = s.info();
                d.set_item("serial", i.serial.clone())?;
                d.set_item("firmware", i.firmware.clone())?;
            }
            Source::Bag(b) => {
                // A bag names no sensor; its topics instead.
                d.set_item("serial", None::<String>)?;
                d.set_item("firmware", None::<String>)?;
                d.set_item("depth_topic", b.meta().depth_topic.clone())?;
                d.set_item("color_topic", b.meta().color_topic.clone())?;
            }
        }
        Ok(d)
    }

    /// The recording file.
    #[getter]
    fn path(&self) -> &Path {
        &self.path
    }
}
