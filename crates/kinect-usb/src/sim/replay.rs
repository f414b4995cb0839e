//! The simulated device as a replay of a recording: its profile from the recording's metadata,
//! its streams the recorded events (see `frames`), and what the replay reports.

use super::{SimDevice, SimFaults, SimProfile, SimScene};
use crate::params::{ColorParams, DepthParams, P0Tables};
use crate::protocol;

impl SimDevice {
    /// A device that answers commands from a recording's metadata and streams its recorded
    /// events (the replay path: identical code from the backend up). The streams end with
    /// `Stopped { Requested }` when the recording is exhausted.
    pub fn replay(rec: crate::recording::Recording) -> crate::Result<Self> {
        Self::replay_from(&rec.meta, Box::new(rec.events.into_iter()))
    }

    /// [`SimDevice::replay`] streaming from `source` (e.g. a
    /// [`RecordingReader`](crate::recording::RecordingReader)): one recorded event is read and
    /// delivered each time the host services the device with nothing waiting (a file is
    /// replayed at the reader's pace, losing nothing), so none is held besides the reader's. A read error ends the streams with
    /// `Stopped { Stalled }` and is kept for [`SimDevice::take_replay_error`].
    pub fn replay_from(
        m: &crate::recording::RecordingMeta,
        source: Box<dyn crate::recording::ReplaySource>,
    ) -> crate::Result<Self> {
        let mut fw = [(0u16, 0u16, 0u32, 0u32); 7];
        let parts: Vec<u32> = m.firmware.split('.').filter_map(|p| p.parse().ok()).collect();
        if parts.len() >= 4 {
            fw[3] = (parts[0] as u16, parts[1] as u16, parts[2], parts[3]);
        }
        let mut hw = m.hardware_info.clone();
        hw.resize(92, 0);
        let profile = SimProfile {
            firmware: fw,
            hardware_info: hw,
            serial: m.serial.clone(),
            depth_params: DepthParams::from_response(&m.depth_params)?,
            p0: P0Tables::from_response(&m.p0)?,
            color_params: ColorParams::from_response(&m.color_params)?,
            status_words: vec![1],
            bytes_per_interval: protocol::MIN_BYTES_PER_INTERVAL,
        };
        let mut d = SimDevice::new(profile, SimScene::default(), SimFaults::default());
        d.replay = Some(source);
        Ok(d)
    }

    /// The error that ended a replay early, if any (taken: a second call returns `None`).
    pub fn take_replay_error(&mut self) -> Option<crate::KinectError> {
        self.replay_error.take()
    }

    /// What the replay source skipped or found cut so far.
    pub fn replay_report(&self) -> crate::recording::ReadReport {
        self.replay.as_ref().map(|r| r.report()).unwrap_or_default()
    }
}
