//! The fuser's side (`kfuse fuse --live`): one subscriber per sensor of the rig on its
//! namespace's keys, every message checked before it is kept.
//!
//! - **Bounded**: a payload over its topic's limit ([`LiveTopic::max_bytes`]) is refused
//!   before decoding; each sensor keeps its newest [`KEEP_FRAMES`] depth and colour frames
//!   (older ones are replaced, counted in `replaced`), whatever the senders' rate.
//! - **Garbage**: a message that does not decode (CDR, a 16UC1 image whose size, step or
//!   encoding disagree, a "JPEG" without its start marker, a status that is no status, a
//!   malformed attachment) is refused and counted per sensor with the last reason; it never
//!   stops the receiver.
//! - **Losses**: the attachments' sequence numbers count the messages a sensor published that
//!   never arrived (`lost`); a publisher's restart (another GID) starts its count again.

use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use kfuse_ros_msgs::{CameraInfo, CompressedImage, Image, Message};
use serde::Serialize;
use zenoh::Wait;

use crate::attachment::Attachment;
use crate::keys::{LIVE_TOPICS, LiveTopic, parse_sensor_key, sensor_keys};
use crate::status::Status;
use crate::{LiveError, publish::ENCODING_16UC1};

/// Depth and colour frames kept per sensor for matching: 4 (133 ms at 30 Hz, more than the
/// default matching tolerance; ~6 MB per sensor with the Kinect's JPEGs).
pub const KEEP_FRAMES: usize = 4;

/// Largest image accepted, in pixels: 1920 × 1080 (a depth image registered to the colour
/// grid; the Kinect's own depth is 512 × 424).
pub const MAX_IMAGE_PIXELS: usize = 1920 * 1080;

/// A received depth frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DepthFrame {
    /// The header's stamp: host arrival time on the sensor's PC, ns since the Unix epoch.
    pub stamp_ns: u64,
    /// The header's frame id.
    pub frame_id: String,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Depth in millimetres, row-major, 0 = none.
    pub mm: Vec<u16>,
}

/// A received colour frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ColorFrame {
    /// The header's stamp (ns since the Unix epoch).
    pub stamp_ns: u64,
    /// The JPEG as the sensor's PC sent it.
    pub jpeg: Vec<u8>,
}

fn garbage(what: &'static str, why: impl std::fmt::Display) -> LiveError {
    LiveError::Garbage { what, why: why.to_string() }
}

fn stamp_ns(t: &kfuse_ros_msgs::Time) -> Result<u64, LiveError> {
    let sec = u64::try_from(t.sec).map_err(|_| garbage("a header stamp", "negative seconds"))?;
    if t.nanosec >= 1_000_000_000 {
        return Err(garbage("a header stamp", format!("{} ns in a second", t.nanosec)));
    }
    Ok(sec * 1_000_000_000 + u64::from(t.nanosec))
}

/// Decodes a depth message: a 16UC1 little-endian `sensor_msgs/Image` whose step is
/// `2 × width` and whose data is `step × height` bytes, at most [`MAX_IMAGE_PIXELS`].
pub fn decode_depth(payload: &[u8]) -> Result<DepthFrame, LiveError> {
    let what = "a depth image (sensor_msgs/Image)";
    if payload.len() > LiveTopic::Depth.max_bytes() {
        return Err(garbage(what, format!("{} bytes, over the limit", payload.len())));
    }
    let m = Image::from_cdr(payload).map_err(|e| garbage(what, e))?;
    if m.encoding != ENCODING_16UC1 || m.is_bigendian != 0 {
        return Err(garbage(
            what,
            format!(
                "encoding {:?} (big endian {}), expected 16UC1 little endian",
                m.encoding, m.is_bigendian
            ),
        ));
    }
    let (w, h) = (m.width as usize, m.height as usize);
    if w == 0 || h == 0 || w.saturating_mul(h) > MAX_IMAGE_PIXELS {
        return Err(garbage(what, format!("{w}x{h} pixels")));
    }
    if m.step as usize != 2 * w || m.data.len() != 2 * w * h {
        return Err(garbage(
            what,
            format!("step {} and {} bytes for {w}x{h} 16-bit pixels", m.step, m.data.len()),
        ));
    }
    let mm = m.data.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
    Ok(DepthFrame {
        stamp_ns: stamp_ns(&m.header.stamp)?,
        frame_id: m.header.frame_id,
        width: w,
        height: h,
        mm,
    })
}

/// Decodes a colour message: a `sensor_msgs/CompressedImage` of format `jpeg` whose data starts
/// with the JPEG start-of-image marker (FF D8) and ends with its end marker (FF D9).
pub fn decode_color(payload: &[u8]) -> Result<ColorFrame, LiveError> {
    let what = "a colour image (sensor_msgs/CompressedImage)";
    if payload.len() > LiveTopic::Color.max_bytes() {
        return Err(garbage(what, format!("{} bytes, over the limit", payload.len())));
    }
    let m = CompressedImage::from_cdr(payload).map_err(|e| garbage(what, e))?;
    if !m.format.to_ascii_lowercase().contains("jpeg") {
        return Err(garbage(what, format!("format {:?}, expected jpeg", m.format)));
    }
    if !m.data.starts_with(&[0xFF, 0xD8]) || !m.data.ends_with(&[0xFF, 0xD9]) {
        return Err(garbage(what, "the data is no JPEG (no FF D8 … FF D9 markers)"));
    }
    Ok(ColorFrame { stamp_ns: stamp_ns(&m.header.stamp)?, jpeg: m.data })
}

/// What arrived from one sensor so far.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct SensorCounters {
    /// Depth frames kept.
    pub depth: u64,
    /// Colour frames kept.
    pub color: u64,
    /// Other messages that decoded (IR, camera infos, status).
    pub other: u64,
    /// Messages refused (over their limit or not decoding).
    pub garbage: u64,
    /// The last refused message's reason.
    pub last_garbage: Option<String>,
    /// Messages published but not received (gaps in the attachments' sequence numbers).
    pub lost: u64,
    /// Frames replaced in the receiver's hold before a set used them (newest wins).
    pub replaced: u64,
    /// Frames the sensor's publisher did not publish (newest wins there too), from its status.
    pub publisher_dropped: u64,
    /// Payload bytes received (every message kept or not, over its limit or not).
    pub bytes: u64,
}

/// One sensor's state in the receiver.
#[derive(Debug, Clone)]
pub struct SensorHold {
    /// The sensor's serial (its name in the rig).
    pub serial: String,
    /// Newest depth frames, oldest first.
    pub depth: VecDeque<Arc<DepthFrame>>,
    /// Newest colour frames, oldest first.
    pub color: VecDeque<Arc<ColorFrame>>,
    /// The newest status message.
    pub status: Option<Status>,
    /// When the newest depth frame arrived here.
    pub last_depth_at: Option<Instant>,
    /// Counters.
    pub counters: SensorCounters,
    last_sequence: [Option<(i64, [u8; 16])>; LIVE_TOPICS.len()],
}

impl SensorHold {
    fn new(serial: String) -> Self {
        Self {
            serial,
            depth: VecDeque::new(),
            color: VecDeque::new(),
            status: None,
            last_depth_at: None,
            counters: SensorCounters::default(),
            last_sequence: [None; LIVE_TOPICS.len()],
        }
    }

    fn refuse(&mut self, e: LiveError) {
        self.counters.garbage += 1;
        self.counters.last_garbage = Some(e.to_string());
    }

    fn count_sequence(&mut self, topic: LiveTopic, a: &Attachment) {
        let slot = &mut self.last_sequence[topic.index()];
        if let Some((last, gid)) = *slot
            && gid == a.source_gid
            && a.sequence_number > last + 1
        {
            self.counters.lost += (a.sequence_number - last - 1) as u64;
        }
        *slot = Some((a.sequence_number, a.source_gid));
    }

    /// Takes one message of `topic`.
    fn take(&mut self, topic: LiveTopic, payload: &[u8], attachment: Option<&[u8]>) {
        self.counters.bytes += payload.len() as u64;
        if payload.len() > topic.max_bytes() {
            let why = format!("{} bytes, over its {}-byte limit", payload.len(), topic.max_bytes());
            return self.refuse(garbage("a message", format!("{topic:?}: {why}")));
        }
        if let Some(a) = attachment {
            match Attachment::decode(a) {
                Ok(a) => self.count_sequence(topic, &a),
                Err(e) => return self.refuse(e),
            }
        }
        let r = match topic {
            LiveTopic::Depth => decode_depth(payload).map(|f| {
                if self.depth.len() == KEEP_FRAMES {
                    self.depth.pop_front();
                    self.counters.replaced += 1;
                }
                self.depth.push_back(Arc::new(f));
                self.last_depth_at = Some(Instant::now());
                self.counters.depth += 1;
            }),
            LiveTopic::Color => decode_color(payload).map(|f| {
                if self.color.len() == KEEP_FRAMES {
                    self.color.pop_front();
                }
                self.color.push_back(Arc::new(f));
                self.counters.color += 1;
            }),
            LiveTopic::Ir => Image::from_cdr(payload)
                .map(|_| self.counters.other += 1)
                .map_err(|e| garbage("an IR image (sensor_msgs/Image)", e)),
            LiveTopic::DepthInfo | LiveTopic::ColorInfo => CameraInfo::from_cdr(payload)
                .map(|_| self.counters.other += 1)
                .map_err(|e| garbage("a sensor_msgs/CameraInfo", e)),
            LiveTopic::Status => Status::decode(payload).map(|s| {
                self.counters.publisher_dropped = s.depth_dropped;
                self.status = Some(s);
                self.counters.other += 1;
            }),
            LiveTopic::TfStatic => Ok(()),
        };
        if let Err(e) = r {
            self.refuse(e);
        }
    }
}

struct Shared {
    sensors: Mutex<Vec<SensorHold>>,
    changed: Condvar,
}

/// The subscribers of a rig's sensors ([module docs](self)).
pub struct Receiver {
    shared: Arc<Shared>,
    _subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
}

impl std::fmt::Debug for Receiver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Receiver").finish_non_exhaustive()
    }
}

impl Receiver {
    /// Subscribes to the sensors `serials` in ROS domain `domain`. Error: two serials with one
    /// namespace (`kfuse_ros_msgs::names::namespace` maps other characters than
    /// `[A-Za-z0-9_]` to `_`), or a subscriber Zenoh refuses.
    pub fn subscribe(
        session: &zenoh::Session,
        domain: u32,
        serials: &[String],
    ) -> Result<Self, LiveError> {
        for (i, a) in serials.iter().enumerate() {
            for b in &serials[..i] {
                if sensor_keys(domain, a) == sensor_keys(domain, b) {
                    return Err(LiveError::Config(format!(
                        "sensors {a} and {b} have one ROS namespace ({}): rename one in the rig",
                        kfuse_ros_msgs::names::namespace(a)
                    )));
                }
            }
        }
        let shared = Arc::new(Shared {
            sensors: Mutex::new(serials.iter().map(|s| SensorHold::new(s.clone())).collect()),
            changed: Condvar::new(),
        });
        let mut subscribers = Vec::new();
        for (k, serial) in serials.iter().enumerate() {
            let keys = sensor_keys(domain, serial);
            let sh = shared.clone();
            let serial = serial.clone();
            let sub = session
                .declare_subscriber(keys.clone())
                .callback(move |sample| {
                    let key = sample.key_expr().as_str();
                    let Some(topic) = parse_sensor_key(domain, &serial, key) else {
                        return; // Another topic of the namespace: not kfuse's.
                    };
                    // Size first: a payload over the limit is never copied into one piece.
                    let payload = sample.payload();
                    let mut sensors = sh.sensors.lock().unwrap_or_else(|p| p.into_inner());
                    let hold = &mut sensors[k];
                    if payload.len() > topic.max_bytes() {
                        hold.counters.bytes += payload.len() as u64;
                        hold.refuse(garbage(
                            "a message",
                            format!(
                                "{topic:?}: {} bytes, over its {}-byte limit",
                                payload.len(),
                                topic.max_bytes()
                            ),
                        ));
                        return;
                    }
                    let bytes = payload.to_bytes();
                    let attachment = sample.attachment().map(|a| a.to_bytes());
                    if attachment.as_ref().is_some_and(|a| a.len() > 64) {
                        hold.refuse(garbage("the rmw_zenoh attachment", "over 64 bytes"));
                        return;
                    }
                    hold.take(topic, &bytes, attachment.as_deref());
                    drop(sensors);
                    sh.changed.notify_all();
                })
                .wait()
                .map_err(|e| LiveError::Zenoh(format!("subscribing to {keys}: {e}")))?;
            subscribers.push(sub);
        }
        Ok(Self { shared, _subscribers: subscribers })
    }

    /// Waits at most `timeout` for a message to arrive.
    pub fn wait(&self, timeout: Duration) {
        let g = self.shared.sensors.lock().unwrap_or_else(|p| p.into_inner());
        let _ = self.shared.changed.wait_timeout(g, timeout);
    }

    /// A copy of every sensor's hold (the frames are shared, not copied).
    pub fn snapshot(&self) -> Vec<SensorHold> {
        self.shared.sensors.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::publish::{compressed_jpeg, header, image_16uc1};

    #[test]
    fn depth_round_trips_and_bad_shapes_are_refused() {
        let h = header(1_700_000_000_123_456_789, "f").unwrap();
        let bytes = image_16uc1(h.clone(), (3, 2), &[1, 2, 3, 4, 5, 65535]).unwrap();
        let d = decode_depth(&bytes).unwrap();
        assert_eq!((d.width, d.height, d.stamp_ns), (3, 2, 1_700_000_000_123_456_789));
        assert_eq!(d.mm, vec![1, 2, 3, 4, 5, 65535]);
        // step disagreeing with the width
        let mut m = Image::from_cdr(&bytes).unwrap();
        m.step = 4;
        assert!(decode_depth(&m.to_cdr().unwrap()).is_err());
        m.step = 6;
        m.encoding = "32FC1".into();
        assert!(decode_depth(&m.to_cdr().unwrap()).is_err());
        assert!(decode_depth(&[0, 1, 0, 0, 0xff, 0xff, 0xff, 0x7f]).is_err());
        assert!(decode_depth(b"").is_err());
    }

    #[test]
    fn colour_must_be_a_jpeg() {
        let h = header(5, "c").unwrap();
        assert!(
            decode_color(&compressed_jpeg(h.clone(), &[0xFF, 0xD8, 1, 0xFF, 0xD9]).unwrap())
                .is_ok()
        );
        assert!(decode_color(&compressed_jpeg(h, b"PNG....").unwrap()).is_err());
    }

    #[test]
    fn the_hold_is_bounded_and_counts() {
        let mut s = SensorHold::new("1".into());
        for k in 0..10u64 {
            let b = image_16uc1(header(k, "f").unwrap(), (1, 1), &[7]).unwrap();
            let a = Attachment {
                sequence_number: (k * 2 + 1) as i64,
                source_timestamp: 0,
                source_gid: [1; 16],
            };
            s.take(LiveTopic::Depth, &b, Some(&a.encode()));
        }
        assert_eq!(s.depth.len(), KEEP_FRAMES);
        assert_eq!(s.counters.depth, 10);
        assert_eq!(s.counters.replaced, 10 - KEEP_FRAMES as u64);
        assert_eq!(s.counters.lost, 9, "every other sequence number never came");
        s.take(LiveTopic::Depth, &[1, 2, 3], None);
        s.take(LiveTopic::Status, b"{}", None);
        s.take(LiveTopic::Depth, &vec![0; LiveTopic::Depth.max_bytes() + 1], None);
        assert_eq!(s.counters.garbage, 3);
        assert!(s.counters.last_garbage.as_deref().unwrap().contains("limit"));
    }
}
