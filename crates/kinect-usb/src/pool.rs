//! What a pool of self-resubmitting transfers does when submissions fail (protocol §5.5), as
//! libfreenect2 does it (`transfer_pool.cpp:85-116,199-205`): the pool starts when at least one
//! transfer was submitted, and a transfer whose resubmission fails is retired while the others
//! go on; the stream ends only when none is left (or the device is gone). Shared by the libusb
//! pool (`transfer`) and the simulated device, so that the simulator's fault knobs drive the
//! same decisions as the real backend.

use crate::backend::{StopReason, StreamEvent};
use crate::error::UsbError;

/// A pool that started, possibly short of transfers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Submitted {
    /// Transfers in flight.
    pub(crate) in_flight: usize,
    /// The error of each transfer that could not be submitted.
    pub(crate) failures: Vec<UsbError>,
}

impl Submitted {
    /// One [`StreamEvent::Retired`] per transfer that never went in flight.
    pub(crate) fn retired_events(&self) -> Vec<StreamEvent> {
        self.failures
            .iter()
            .map(|&error| StreamEvent::Retired { error, in_flight: self.in_flight })
            .collect()
    }
}

/// Submits `count` transfers with `submit(i)`. Succeeds when at least one went in flight;
/// otherwise returns the most telling failure (device gone, then out of memory, then the
/// first).
pub(crate) fn submit_pool(
    count: usize,
    mut submit: impl FnMut(usize) -> Result<(), UsbError>,
) -> Result<Submitted, UsbError> {
    let mut s = Submitted { in_flight: 0, failures: Vec::new() };
    for i in 0..count {
        match submit(i) {
            Ok(()) => s.in_flight += 1,
            Err(e) => s.failures.push(e),
        }
    }
    if s.in_flight > 0 {
        return Ok(s);
    }
    Err([UsbError::NoDevice, UsbError::NoMem]
        .into_iter()
        .find(|e| s.failures.contains(e))
        .or(s.failures.first().copied())
        .unwrap_or(UsbError::Io))
}

/// The events of a transfer whose resubmission failed with `error`, `in_flight` transfers of
/// its pool still running: the device gone ends the stream; anything else retires this one
/// transfer, and ends the stream only when it was the last.
pub(crate) fn resubmit_failed(error: UsbError, in_flight: usize) -> Vec<StreamEvent> {
    if error == UsbError::NoDevice {
        return vec![StreamEvent::Stopped { reason: StopReason::Disconnected }];
    }
    let mut ev = vec![StreamEvent::Retired { error, in_flight }];
    if in_flight == 0 {
        ev.push(StreamEvent::Stopped { reason: StopReason::Stalled });
    }
    ev
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pool_starts_with_any_transfer_in_flight() {
        let s = submit_pool(5, |i| if i % 2 == 0 { Err(UsbError::NoMem) } else { Ok(()) }).unwrap();
        assert_eq!(s, Submitted { in_flight: 2, failures: vec![UsbError::NoMem; 3] });
        assert_eq!(
            s.retired_events(),
            vec![StreamEvent::Retired { error: UsbError::NoMem, in_flight: 2 }; 3]
        );
        assert_eq!(
            submit_pool(3, |_| Ok(())).unwrap(),
            Submitted { in_flight: 3, failures: vec![] }
        );
    }

    #[test]
    fn pool_that_submits_nothing_reports_the_telling_error() {
        let errs = [UsbError::Io, UsbError::NoMem, UsbError::Io];
        assert_eq!(submit_pool(3, |i| Err(errs[i])), Err(UsbError::NoMem));
        let errs = [UsbError::NoMem, UsbError::NoDevice];
        assert_eq!(submit_pool(2, |i| Err(errs[i])), Err(UsbError::NoDevice));
        assert_eq!(submit_pool(2, |_| Err(UsbError::Io)), Err(UsbError::Io));
        assert_eq!(submit_pool(0, |_| Ok(())), Err(UsbError::Io));
    }

    #[test]
    fn failed_resubmit_retires_until_none_remain() {
        assert_eq!(
            resubmit_failed(UsbError::Io, 59),
            [StreamEvent::Retired { error: UsbError::Io, in_flight: 59 }]
        );
        assert_eq!(
            resubmit_failed(UsbError::NoMem, 0),
            [
                StreamEvent::Retired { error: UsbError::NoMem, in_flight: 0 },
                StreamEvent::Stopped { reason: StopReason::Stalled }
            ]
        );
        assert_eq!(
            resubmit_failed(UsbError::NoDevice, 10),
            [StreamEvent::Stopped { reason: StopReason::Disconnected }]
        );
    }
}
