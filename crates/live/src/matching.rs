//! Matching one frame per sensor (`kfuse fuse --live`). Kinect v2s have no sync port: each runs
//! free at 30 Hz on its own clock, so frames are matched by the host time at which each
//! arrived on its PC (the header stamps; the hosts' clocks kept together by chrony or PTP).
//!
//! Per sensor, a depth frame is paired with the colour frame nearest in time, within
//! [`COLOR_PAIR_TOLERANCE_NS`] (half a frame period, the rule of `kfuse capture`'s pairs). Across
//! sensors, a set is one such pair per sensor whose depth stamps lie within the tolerance
//! ([`MATCH_TOLERANCE_NS`] by default): the newest set wins, and every frame of a set must be
//! newer than the sensor's frame in the previous set (frames only go forward).

/// The sensors' frame period: 1/30 s.
pub const FRAME_PERIOD_NS: u64 = 33_333_333;

/// Largest distance between a sensor's depth frame and the colour frame it is paired with:
/// half a frame period (16.7 ms), as `kfuse capture` pairs them.
pub const COLOR_PAIR_TOLERANCE_NS: u64 = FRAME_PERIOD_NS / 2;

/// Default largest spread (newest minus oldest depth stamp) of a matched set: 25 ms. Sensors
/// running free at 30 Hz with arbitrary phases always have one frame each within
/// (N − 1)/N of a period of each other (16.7 ms for 2, 22.2 ms for 3, 25 ms for 4 sensors), so
/// this never refuses a set of a ring of up to 4 sensors whose hosts' clocks agree; a spread
/// over it means a sensor's frames are late or its host's clock is off, and the set is
/// refused. `kfuse fuse --live --tolerance-ms` changes it.
pub const MATCH_TOLERANCE_NS: u64 = 25_000_000;

/// One sensor's frames as the matcher sees them: depth stamps and colour stamps (ns), any order.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SensorFrames {
    /// Stamps of the depth frames held.
    pub depth: Vec<u64>,
    /// Stamps of the colour frames held.
    pub color: Vec<u64>,
}

/// One sensor's part of a matched set: indices into its [`SensorFrames`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Chosen {
    /// Index of the depth frame.
    pub depth: usize,
    /// Index of the colour frame.
    pub color: usize,
    /// The depth frame's stamp.
    pub depth_ns: u64,
    /// The colour frame's stamp.
    pub color_ns: u64,
}

/// Every depth frame of `f` with its nearest colour frame within [`COLOR_PAIR_TOLERANCE_NS`].
pub fn pairs(f: &SensorFrames) -> Vec<Chosen> {
    let mut out = Vec::new();
    for (i, &d) in f.depth.iter().enumerate() {
        let best = f.color.iter().enumerate().min_by_key(|&(_, &c)| c.abs_diff(d));
        if let Some((j, &c)) = best
            && c.abs_diff(d) <= COLOR_PAIR_TOLERANCE_NS
        {
            out.push(Chosen { depth: i, color: j, depth_ns: d, color_ns: c });
        }
    }
    out
}

/// The newest set (module docs): one pair per sensor of `sensors`, each depth stamp newer than
/// the sensor's in `after`, spread within `tolerance_ns`. `None` while there is none.
pub fn newest_set(
    sensors: &[SensorFrames],
    after: &[Option<u64>],
    tolerance_ns: u64,
) -> Option<Vec<Chosen>> {
    if sensors.is_empty() {
        return None;
    }
    let candidates: Vec<Vec<Chosen>> = sensors
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let last = after.get(k).copied().flatten();
            pairs(f).into_iter().filter(|c| last.is_none_or(|t| c.depth_ns > t)).collect()
        })
        .collect();
    if candidates.iter().any(|c| c.is_empty()) {
        return None;
    }
    // Every candidate as the set's reference time, newest first; each other sensor takes its
    // pair nearest to it.
    let mut refs: Vec<u64> = candidates.iter().flatten().map(|c| c.depth_ns).collect();
    refs.sort_unstable_by(|a, b| b.cmp(a));
    refs.dedup();
    for r in refs {
        let set: Vec<Chosen> = candidates
            .iter()
            .map(|c| *c.iter().min_by_key(|p| p.depth_ns.abs_diff(r)).expect("not empty"))
            .collect();
        if spread_ns(&set) <= tolerance_ns {
            return Some(set);
        }
    }
    None
}

/// Newest minus oldest depth stamp of a set.
pub fn spread_ns(set: &[Chosen]) -> u64 {
    let max = set.iter().map(|c| c.depth_ns).max().unwrap_or(0);
    let min = set.iter().map(|c| c.depth_ns).min().unwrap_or(0);
    max - min
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn frames(phase_ms: u64, n: u64) -> SensorFrames {
        let t: Vec<u64> =
            (0..n).map(|k| 1_000 * MS + phase_ms * MS + k * FRAME_PERIOD_NS).collect();
        SensorFrames { depth: t.clone(), color: t.iter().map(|x| x + MS).collect() }
    }

    #[test]
    fn colour_is_paired_within_half_a_period() {
        let f = SensorFrames { depth: vec![100 * MS, 200 * MS], color: vec![110 * MS, 300 * MS] };
        let p = pairs(&f);
        assert_eq!(p.len(), 1);
        assert_eq!((p[0].depth, p[0].color), (0, 0));
    }

    #[test]
    fn the_newest_set_within_the_tolerance_wins() {
        // Three sensors 0, 11 and 22 ms apart: the worst phases of a ring of three.
        let s = [frames(0, 4), frames(11, 4), frames(22, 4)];
        let set = newest_set(&s, &[None, None, None], MATCH_TOLERANCE_NS).unwrap();
        assert!(spread_ns(&set) <= 22 * MS);
        assert_eq!(set[2].depth, 3, "the newest frame of the latest sensor");
        // Already used: only older or equal frames are left for sensor 0.
        let after = [Some(set[0].depth_ns), None, None];
        let again = newest_set(&s, &after, MATCH_TOLERANCE_NS);
        assert!(again.is_none_or(|g| g[0].depth_ns > set[0].depth_ns));
    }

    #[test]
    fn a_set_over_the_tolerance_is_refused() {
        let s = [frames(0, 1), frames(30, 1)];
        assert!(newest_set(&s, &[None, None], MATCH_TOLERANCE_NS).is_none());
        assert!(newest_set(&s, &[None, None], 31 * MS).is_some());
    }

    #[test]
    fn a_sensor_without_frames_gives_no_set() {
        let s = [frames(0, 3), SensorFrames::default()];
        assert!(newest_set(&s, &[None, None], MATCH_TOLERANCE_NS).is_none());
        assert!(newest_set(&[], &[], MATCH_TOLERANCE_NS).is_none());
    }
}
