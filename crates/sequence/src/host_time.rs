//! The host clock of a recording: how the rosbag2 layout turns the sensor's timestamps (0.125 ms
//! ticks of its own clock, counted from an arbitrary origin) into Unix-epoch times, as ROS
//! stamps are.
//!
//! A `.kfrec` (format 2) stores the sensor's packets and no host clock. What it does carry is
//! its file's modification time: `kfuse capture record` (and `kfuse_capture::record::record`)
//! writes the end record right after the packets of the last depth frame it counted, then syncs
//! and renames the file, and never writes it again. That time is the host time at which the
//! last depth frame was received, to within the end record's write (microseconds, more if the
//! thread is preempted) and the kernel's file clock (coarse: up to one scheduler tick late,
//! 4 ms at 250 Hz; `tests/rosbag2_layout.rs` measured 3–5 ms). So the
//! recording's clock is anchored there: [`HostClock`] maps the last complete depth frame's
//! sensor time to the file's modification time, and every other time by the sensor's own
//! spacing (ticks × 125 µs; the two clocks drift apart by parts per million, well under a tick
//! over a recording of minutes). A copy that did not keep the modification time (`cp`
//! without `-p`, a download) moves every stamp by the same amount; the spacing stays the
//! sensor's.

use std::path::Path;
use std::time::UNIX_EPOCH;

use kinect_usb::recording::ReadOptions;

use crate::rosbag2::NANOS_PER_TICK;
use crate::source::{RecordingSource, SourceEvent};
use crate::{Result, SequenceError};

/// The map from sensor ticks to host time: `anchor_ticks` was received at `anchor_unix_ns`
/// (nanoseconds since the Unix epoch).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HostClock {
    /// A sensor time, ticks (the last complete depth frame of a recording).
    pub anchor_ticks: u64,
    /// Its host time, nanoseconds since the Unix epoch.
    pub anchor_unix_ns: u64,
}

impl HostClock {
    /// The sensor's own clock in nanoseconds (tick 0 at time 0): the map of bags that are not
    /// anchored to a host clock (tests of the message layout).
    pub const SENSOR: HostClock = HostClock { anchor_ticks: 0, anchor_unix_ns: 0 };

    /// The host time of sensor time `ticks`, nanoseconds since the Unix epoch; `None` when it
    /// falls before the epoch or beyond `u64` (a sensor time absurdly far from the anchor).
    pub fn unix_ns(&self, ticks: u64) -> Option<u64> {
        let delta =
            (i128::from(ticks) - i128::from(self.anchor_ticks)) * i128::from(NANOS_PER_TICK);
        u64::try_from(i128::from(self.anchor_unix_ns) + delta).ok()
    }
}

/// The recording's [`HostClock`] ([module docs](self)): its last complete depth frame (read
/// with `options`, as the run reads it) at the file's modification time. A recording without a
/// complete depth frame is anchored at tick 0 (it has no frame to stamp).
///
/// Errors: the file's modification time cannot be read, or is before the Unix epoch; the
/// recording's own read errors.
pub fn recording_clock(path: &Path, options: ReadOptions) -> Result<HostClock> {
    let bad = |m: String| SequenceError::input(path, m);
    // Opened first: a path that is no recording gets the reader's message.
    let mut src = RecordingSource::open(path, options)?;
    let modified = std::fs::metadata(path).and_then(|m| m.modified()).map_err(|e| {
        bad(format!(
            "cannot read the recording's modification time, which the rosbag2 layout stamps by: {e}"
        ))
    })?;
    let since = modified.duration_since(UNIX_EPOCH).map_err(|_| {
        bad("the recording's modification time is before 1970, so its host times are unknown; \
             set it to when it was recorded (touch -d) and run again"
            .into())
    })?;
    let anchor_unix_ns = u64::try_from(since.as_nanos())
        .map_err(|_| bad("the recording's modification time is beyond the year 2554".into()))?;
    let mut last = None;
    while let Some(ev) = src.next_event()? {
        if let SourceEvent::Depth { frame, .. } = ev {
            last = Some(frame.timestamp);
        }
    }
    Ok(HostClock { anchor_ticks: last.unwrap_or(0), anchor_unix_ns })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_map_by_the_sensors_spacing_around_the_anchor() {
        let c = HostClock { anchor_ticks: 1000, anchor_unix_ns: 1_765_000_000_000_000_000 };
        assert_eq!(c.unix_ns(1000), Some(1_765_000_000_000_000_000));
        assert_eq!(c.unix_ns(1267), Some(1_765_000_000_033_375_000));
        assert_eq!(c.unix_ns(733), Some(1_764_999_999_966_625_000));
        assert_eq!(HostClock::SENSOR.unix_ns(8000 * 3600 + 267), Some(3_600_033_375_000));
        let early = HostClock { anchor_ticks: 9000, anchor_unix_ns: 125_000 };
        assert_eq!(early.unix_ns(8998), None);
        assert_eq!(early.unix_ns(8999), Some(0));
    }
}
