//! Stage 4b: recordings. [`record`] writes every raw USB packet of a session and the device
//! metadata into a `.kfrec` file (`kinect_usb::recording`), published atomically: replay then
//! runs the same parsers and decoder as the live sensor.

use std::path::Path;

use kfuse_io::atomic::write_atomic;
use kinect_usb::KinectError;
use kinect_usb::backend::{StreamEvent, XferStatus};
use kinect_usb::device::StreamKind;
use kinect_usb::recording::{RecordingMeta, RecordingWriter};
use kinect_usb::stream::DepthAssembler;

use crate::pump::FRAME_TIMEOUT;
use crate::{CaptureError, Session};

/// How a recording ended.
#[derive(Debug)]
pub struct Recorded {
    /// Depth frames recorded (all of them are in the file, which is complete and replayable).
    pub frames: u64,
    /// The caller's stop request ended it before `frames` were reached.
    pub interrupted: bool,
    /// The stream error that ended it early (unplug, end of a replayed recording), if any.
    pub stopped_by: Option<KinectError>,
    /// Whether the file was written: `false` when the stop request came before the first
    /// depth frame (nothing was published; a file already at `output` is left as it was).
    pub written: bool,
}

/// The one line of a recording that the sensor's disappearance ended early: what `kfuse
/// capture record` prints and Python's `Device.record` raises (as an OSError).
pub fn unplugged_message(e: &KinectError, frames: u64, output: &Path) -> String {
    format!(
        "{e}; recording stopped: {frames} complete depth frames were saved in {} (a valid, \
         replayable file)",
        output.display()
    )
}

/// Records `frames` depth frames (and the colour frames between them) of `session` into
/// `output`. `stop` is polled between frames (a signal handler's flag); `progress` is called
/// with the count after each depth frame. A stream error or a stop request ends the
/// recording early but still writes a complete file (returned in [`Recorded`]); an I/O error
/// leaves nothing at `output`. A stop request before the first depth frame writes nothing: a
/// recording without a frame is none, and it would replace a file already at `output`
/// (`kfuse capture record --overwrite` interrupted while the sensor started).
pub fn record(
    session: &mut Session,
    output: &Path,
    frames: u64,
    stop: &dyn Fn() -> bool,
    progress: &mut dyn FnMut(u64),
) -> Result<Recorded, CaptureError> {
    let meta = RecordingMeta::from_info(session.info());
    let mut done = Recorded { frames: 0, interrupted: false, stopped_by: None, written: false };
    // Every raw event from now on, not only the newest frames (bounded: a recorder that falls
    // behind by more than `TAP_QUEUE_BYTES` loses events, counted in `tap_dropped`).
    session.device_mut().set_raw_tap(true);
    // The depth frames in the file: the written packets run through a parser of their own (a
    // frame this loop did not take in time is still in the file; one whose first packets came
    // before the tap is not).
    let mut in_file = DepthAssembler::new();
    let written = write_atomic(output, |w| {
        let mut rw = RecordingWriter::new(w, &meta)?;
        let mut io_err = None;
        while done.frames < frames {
            if stop() {
                done.interrupted = true;
                if done.frames == 0 {
                    // Abandons the temporary file; `output` stays as it is.
                    return Err(std::io::ErrorKind::Interrupted.into());
                }
                break;
            }
            let before = done.frames;
            let mut tap = |k: StreamKind, e: &StreamEvent| {
                if let Err(err) = rw.write_event(k, e) {
                    io_err.get_or_insert(err);
                }
                if let StreamEvent::IsoPacket { status: XferStatus::Completed, data } = e
                    && in_file.push(data).is_some()
                {
                    done.frames += 1;
                }
            };
            let r = session.device_mut().next_frame(FRAME_TIMEOUT, &mut tap).map(|_| ());
            if done.frames > before {
                progress(done.frames);
            }
            match r {
                Ok(()) => {}
                Err(e) => {
                    done.stopped_by = Some(e);
                    break;
                }
            }
            if let Some(e) = io_err.take() {
                return Err(e);
            }
        }
        rw.finish().map(|_| ())
    });
    session.device_mut().set_raw_tap(false);
    match written {
        Ok(()) => done.written = true,
        Err(_) if done.interrupted && done.frames == 0 => {}
        Err(e) => return Err(e.into()),
    }
    Ok(done)
}
