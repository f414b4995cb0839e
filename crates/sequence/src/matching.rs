//! Stage 2, match: the depth and colour streams of a recording paired by the sensor's
//! timestamps, frame numbers from the depth sequence numbers, and every depth frame that never
//! arrived listed ([`Missing`]) instead of silently shifting the ones after it.
//!
//! The Kinect v2 runs both cameras at 30 Hz without a common trigger: a depth frame's colour
//! partner is the colour frame nearest in time, if it is within [`DEFAULT_MAX_SKEW_TICKS`]
//! (or the caller's limit); each colour frame is used at most once. Matching is streamed: a
//! depth frame waits only until the first colour frame at or after its timestamp has arrived
//! (or [`MAX_PENDING_DEPTH`] newer depth frames did), so memory stays bounded whatever the
//! recording's length.

use std::collections::VecDeque;

use serde::Serialize;

use crate::source::{ColorFrame, RawDepth, SourceEvent};

/// Depth sequence numbers wrap at 2^16 (protocol §7).
pub const DEPTH_SEQUENCE_MODULUS: u32 = 1 << 16;

/// Largest forward step of the depth sequence read as frames lost: 1800, one minute at
/// 30 Hz. A longer silence of a running stream is no USB drop (a stalled stream is restarted
/// within seconds); a larger step, or one backwards in the 16-bit sequence at a later
/// timestamp, is a discontinuity (a stream restart, a reordered record), listed once as
/// [`MissingReason::Discontinuity`] instead of as up to 65 534 frames lost, which it was (a
/// 13 MB `index.json`). It also bounds the entries one gap adds to the missing list.
pub const MAX_SEQUENCE_GAP: u32 = 1800;

/// Default largest time between a depth frame and its colour partner: 133 ticks = 16.6 ms,
/// half the 33.3 ms frame period. Two free-running 30 Hz streams always have a colour frame
/// within half a period of every depth frame; one farther away belongs to a neighbouring depth
/// frame (the right partner was dropped), so pairing it would shift colour against depth.
pub const DEFAULT_MAX_SKEW_TICKS: u64 = 133;

/// Depth frames that may wait for a later colour frame: a colour stream that stalls (or ends)
/// holds at most this many raw frames (3 MB each) before they are resolved without colour.
pub const MAX_PENDING_DEPTH: usize = 3;

/// Colour frames kept as candidates: a depth stream that stalls holds at most this many JPEGs
/// (~0.3 MB each); older ones are counted as unmatched.
pub const MAX_COLOR_CANDIDATES: usize = 8;

/// Why a depth frame is missing from the output.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MissingReason {
    /// Not one packet of it was received (a gap in the sequence numbers).
    Dropped,
    /// Started but a sub-image was lost: the assembler abandoned it.
    Incomplete,
    /// Part of a gap in which some frames were dropped and others incomplete (the assembler
    /// counts incomplete frames but does not say which).
    DroppedOrIncomplete,
    /// Its sequence number repeated the previous frame's; the repeat is left out.
    Repeated,
    /// Its timestamp is not after the previous frame's (a duplicated USB block, a reordered
    /// record): left out, so that frame numbers and times only go forward.
    OutOfOrder,
    /// The sequence number jumped backwards or more than [`MAX_SEQUENCE_GAP`] ahead while
    /// time went on (a stream restart): how many frames were lost there is unknown; this one
    /// entry stands for them, and the frame after it goes on being numbered.
    Discontinuity,
}

impl MissingReason {
    /// The reason in words, for messages.
    pub fn text(self) -> &'static str {
        match self {
            MissingReason::Dropped => "dropped (no packet of it was received)",
            MissingReason::Incomplete => "incomplete (a sub-image was lost)",
            MissingReason::DroppedOrIncomplete => "dropped or incomplete",
            MissingReason::Repeated => "repeated sequence number (left out)",
            MissingReason::OutOfOrder => {
                "out of order: its timestamp is not after the previous frame's (a duplicated or reordered record; left out)"
            }
            MissingReason::Discontinuity => {
                "sequence discontinuity: the depth sequence number jumped back or too far ahead (a stream restart?); the frames lost there are unknown"
            }
        }
    }
}

/// A depth frame that is not in the output.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Missing {
    /// Its frame number (depth frame periods since the first frame of the recording).
    pub number: u64,
    /// Its depth sequence number.
    pub depth_sequence: u32,
    /// Why.
    pub reason: MissingReason,
}

/// A depth frame and its colour partner, if one was close enough in time.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Pair {
    /// Frame number: depth frame periods since the first frame (gaps where frames are missing).
    pub number: u64,
    /// The depth frame.
    pub depth: RawDepth,
    /// Its colour partner.
    pub color: Option<ColorFrame>,
}

/// What the matcher hands on, in frame order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Matched {
    /// A depth frame to process.
    Frame(Pair),
    /// A depth frame that never arrived complete.
    Missing(Missing),
}

/// The streaming matcher ([module docs](self)).
#[derive(Debug)]
pub struct Matcher {
    max_skew: u64,
    /// Sequence number and timestamp of the last depth frame taken.
    last: Option<(u32, u64)>,
    number: u64,
    pending: VecDeque<(u64, RawDepth)>,
    colors: VecDeque<ColorFrame>,
    out: VecDeque<Matched>,
    unmatched_colors: u64,
}

impl Matcher {
    /// A matcher pairing frames at most `max_skew` ticks apart.
    pub fn new(max_skew: u64) -> Self {
        Self {
            max_skew,
            last: None,
            number: 0,
            pending: VecDeque::new(),
            colors: VecDeque::new(),
            out: VecDeque::new(),
            unmatched_colors: 0,
        }
    }

    /// Colour frames left without a depth partner so far.
    pub fn unmatched_colors(&self) -> u64 {
        self.unmatched_colors
    }

    /// Takes in one event of the source.
    pub fn push(&mut self, event: SourceEvent) {
        match event {
            SourceEvent::Color(c) => {
                self.colors.push_back(c);
                while self.colors.len() > MAX_COLOR_CANDIDATES {
                    self.colors.pop_front();
                    self.unmatched_colors += 1;
                }
            }
            SourceEvent::Depth { frame, incomplete_before } => {
                self.number_depth(frame, incomplete_before);
            }
        }
        self.resolve(false);
    }

    /// Resolves every waiting depth frame with the colour frames received (end of the source).
    pub fn finish(&mut self) {
        self.resolve(true);
        self.unmatched_colors += self.colors.len() as u64;
        self.colors.clear();
    }

    /// The next result, in frame order.
    pub fn pop(&mut self) -> Option<Matched> {
        self.out.pop_front()
    }

    fn number_depth(&mut self, frame: RawDepth, incomplete_before: u64) {
        let seq = frame.sequence % DEPTH_SEQUENCE_MODULUS;
        if let Some((last, last_time)) = self.last {
            let gap = (seq + DEPTH_SEQUENCE_MODULUS - last) % DEPTH_SEQUENCE_MODULUS;
            let left_out = match gap {
                0 => Some(MissingReason::Repeated),
                _ if frame.timestamp <= last_time => Some(MissingReason::OutOfOrder),
                _ => None,
            };
            if let Some(reason) = left_out {
                // Resolve what waits first so that the list stays in frame order.
                self.resolve(true);
                self.out.push_back(Matched::Missing(Missing {
                    number: self.number,
                    depth_sequence: seq,
                    reason,
                }));
                return;
            }
            if gap > MAX_SEQUENCE_GAP {
                self.resolve(true);
                self.out.push_back(Matched::Missing(Missing {
                    number: self.number + 1,
                    depth_sequence: seq,
                    reason: MissingReason::Discontinuity,
                }));
                self.number += 2;
            } else {
                let lost = u64::from(gap - 1);
                let reason = match incomplete_before {
                    0 => MissingReason::Dropped,
                    n if n >= lost => MissingReason::Incomplete,
                    _ => MissingReason::DroppedOrIncomplete,
                };
                if lost > 0 {
                    self.resolve(true);
                }
                for k in 1..=lost {
                    self.out.push_back(Matched::Missing(Missing {
                        number: self.number + k,
                        depth_sequence: (last + k as u32) % DEPTH_SEQUENCE_MODULUS,
                        reason,
                    }));
                }
                self.number += u64::from(gap);
            }
        }
        self.last = Some((seq, frame.timestamp));
        self.pending.push_back((self.number, frame));
    }

    /// Pairs the waiting depth frames whose best colour partner is known (all with `force`).
    fn resolve(&mut self, force: bool) {
        while let Some((_, d)) = self.pending.front() {
            let t = d.timestamp;
            let later_seen = self.colors.back().is_some_and(|c| c.timestamp >= t);
            if !(force || later_seen || self.pending.len() > MAX_PENDING_DEPTH) {
                break;
            }
            let Some((number, depth)) = self.pending.pop_front() else { break };
            let best = self
                .colors
                .iter()
                .enumerate()
                .map(|(i, c)| (i, c.timestamp.abs_diff(t)))
                .min_by_key(|&(_, skew)| skew)
                .filter(|&(_, skew)| skew <= self.max_skew);
            let color = match best {
                Some((i, _)) => {
                    // Colour frames older than the partner can only be farther from every
                    // later depth frame: they stay unmatched.
                    self.unmatched_colors += i as u64;
                    self.colors.drain(..i);
                    self.colors.pop_front()
                }
                None => {
                    let stale = self
                        .colors
                        .iter()
                        .take_while(|c| c.timestamp.saturating_add(self.max_skew) < t)
                        .count();
                    self.unmatched_colors += stale as u64;
                    self.colors.drain(..stale);
                    None
                }
            };
            self.out.push_back(Matched::Frame(Pair { number, depth, color }));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn depth(sequence: u32, timestamp: u64, incomplete_before: u64) -> SourceEvent {
        SourceEvent::Depth {
            frame: RawDepth { sequence, timestamp, data: vec![] },
            incomplete_before,
        }
    }

    fn color(sequence: u32, timestamp: u64) -> SourceEvent {
        SourceEvent::Color(ColorFrame { sequence, timestamp, jpeg: vec![sequence as u8] })
    }

    fn run(events: Vec<SourceEvent>, skew: u64) -> (Vec<Matched>, u64) {
        let mut m = Matcher::new(skew);
        let mut out = Vec::new();
        for e in events {
            m.push(e);
            while let Some(r) = m.pop() {
                out.push(r);
            }
        }
        m.finish();
        while let Some(r) = m.pop() {
            out.push(r);
        }
        (out, m.unmatched_colors())
    }

    /// (number, depth sequence, colour sequence) of a frame.
    type FrameRow = (u64, u32, Option<u32>);

    /// The rows of the frames; (number, reason) of the gaps.
    fn summary(out: &[Matched]) -> (Vec<FrameRow>, Vec<(u64, MissingReason)>) {
        let mut frames = Vec::new();
        let mut missing = Vec::new();
        for r in out {
            match r {
                Matched::Frame(p) => {
                    frames.push((p.number, p.depth.sequence, p.color.as_ref().map(|c| c.sequence)))
                }
                Matched::Missing(m) => missing.push((m.number, m.reason)),
            }
        }
        (frames, missing)
    }

    #[test]
    fn nearest_colour_in_either_order_and_gaps_listed_with_their_numbers() {
        // Period 267 ticks; colour 40 ticks after depth, except frame 2 whose colour comes
        // first and 60 ticks early. Depth 3 is dropped, depth 5 incomplete; colour 6 lost.
        let events = vec![
            depth(10, 1000, 0),
            color(0, 1040),
            color(1, 1307),
            depth(11, 1267, 0),
            color(2, 1474),
            depth(12, 1534, 0),
            color(3, 1841),
            depth(14, 2068, 0),
            color(4, 2108),
            color(5, 2375),
            depth(15, 2335, 0),
            depth(17, 2869, 1),
        ];
        let (out, unmatched) = run(events, DEFAULT_MAX_SKEW_TICKS);
        let (frames, missing) = summary(&out);
        assert_eq!(
            frames,
            vec![
                (0, 10, Some(0)),
                (1, 11, Some(1)),
                (2, 12, Some(2)),
                (4, 14, Some(4)),
                (5, 15, Some(5)),
                (7, 17, None)
            ]
        );
        assert_eq!(missing, vec![(3, MissingReason::Dropped), (6, MissingReason::Incomplete)]);
        // Colour 3 (depth 13 dropped) never found a partner.
        assert_eq!(unmatched, 1);
        // Frame order is kept in the output, gaps included.
        let numbers: Vec<u64> = out
            .iter()
            .map(|r| match r {
                Matched::Frame(p) => p.number,
                Matched::Missing(m) => m.number,
            })
            .collect();
        assert_eq!(numbers, (0..8).collect::<Vec<_>>());
    }

    #[test]
    fn colour_beyond_the_skew_limit_is_not_paired_and_sequence_wrap_is_one_step() {
        let events = vec![
            depth(65535, 0, 0),
            color(0, 200),
            depth(0, 267, 0),
            color(1, 267),
            depth(2, 801, 0),
        ];
        let (out, _) = run(events, DEFAULT_MAX_SKEW_TICKS);
        let (frames, missing) = summary(&out);
        // Colour 0 is 200 ticks from the first depth frame (beyond 133): no partner. The
        // second depth frame (sequence 0 after 65535: one step) takes colour 1 (0 ticks)
        // over colour 0 (67 ticks).
        assert_eq!(frames, vec![(0, 65535, None), (1, 0, Some(1)), (3, 2, None)]);
        assert_eq!(missing, vec![(2, MissingReason::Dropped)]);
    }

    /// A duplicated block (an earlier frame again), a reordered pair, a restart of the
    /// sequence and a jump far ahead: each is one entry, never a 16-bit wrap-around of
    /// 65 000 frames lost; frame numbers and timestamps of the frames only go forward.
    #[test]
    fn backwards_and_implausible_sequence_steps_are_one_entry_each() {
        let events = vec![
            depth(100, 1000, 0),
            depth(101, 1267, 0),
            depth(100, 1000, 0), // the block of frame 100 again
            depth(102, 1534, 0),
            depth(104, 2068, 0),
            depth(103, 1801, 0), // arrives after 104
            depth(105, 2335, 0),
            depth(3, 2602, 0), // the stream restarted: sequence back to 3, time goes on
            depth(4, 2869, 0),
            depth(4 + MAX_SEQUENCE_GAP + 1, 3136, 0), // far ahead
            depth(6 + MAX_SEQUENCE_GAP, 3403, 0),
        ];
        let (out, _) = run(events, DEFAULT_MAX_SKEW_TICKS);
        let (frames, missing) = summary(&out);
        let numbers: Vec<(u64, u32)> = frames.iter().map(|f| (f.0, f.1)).collect();
        assert_eq!(
            numbers,
            vec![
                (0, 100),
                (1, 101),
                (2, 102),
                (4, 104),
                (5, 105),
                (7, 3),
                (8, 4),
                (10, 5 + MAX_SEQUENCE_GAP),
                (11, 6 + MAX_SEQUENCE_GAP)
            ]
        );
        assert_eq!(
            missing,
            vec![
                (1, MissingReason::OutOfOrder),
                (3, MissingReason::Dropped),
                (4, MissingReason::OutOfOrder),
                (6, MissingReason::Discontinuity),
                (9, MissingReason::Discontinuity),
            ]
        );
        let times: Vec<u64> = out
            .iter()
            .filter_map(|r| match r {
                Matched::Frame(p) => Some(p.depth.timestamp),
                Matched::Missing(_) => None,
            })
            .collect();
        assert!(times.windows(2).all(|w| w[0] < w[1]), "{times:?}");
        // The largest step still read as frames lost lists them all.
        let (out, _) = run(vec![depth(0, 0, 0), depth(MAX_SEQUENCE_GAP, 1, 0)], 133);
        assert_eq!(summary(&out).1.len(), (MAX_SEQUENCE_GAP - 1) as usize);
    }

    #[test]
    fn a_stalled_colour_stream_holds_a_bounded_number_of_depth_frames() {
        let mut m = Matcher::new(DEFAULT_MAX_SKEW_TICKS);
        for k in 0..10u32 {
            m.push(depth(k, 267 * u64::from(k), 0));
            assert!(m.pending.len() <= MAX_PENDING_DEPTH);
        }
        for k in 0..20u32 {
            m.push(color(k, 5000 + u64::from(k)));
            assert!(m.colors.len() <= MAX_COLOR_CANDIDATES);
        }
    }
}
