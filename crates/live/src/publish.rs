//! One sensor's publishers (`kfuse serve`): a Zenoh publisher per topic on `rmw_zenoh`'s keys,
//! each message with `rmw_zenoh`'s attachment, and the latched messages (both `CameraInfo`s and
//! `/tf_static`) answered to queries on their keys.
//!
//! Nothing queues without bound: every publisher drops a message that the network cannot take
//! now (`CongestionControl::Drop`) instead of blocking the sensor's loop or growing a queue,
//! so a slow subscriber loses messages, counted on its side by the attachments' sequence
//! numbers.

use std::sync::{Arc, Mutex};
use std::time::{SystemTime, UNIX_EPOCH};

use kfuse_ros_msgs::{
    CameraInfo, CompressedImage, Header, Image, Message, TFMessage, Time, TransformStamped,
};
use zenoh::Wait;
use zenoh::qos::CongestionControl;

use crate::LiveError;
use crate::attachment::{Attachment, GID_BYTES};
use crate::keys::{LIVE_TOPICS, LiveTopic};

/// `sensor_msgs/Image` encoding of depth and IR (REP 118: 16-bit depth in millimetres).
pub const ENCODING_16UC1: &str = "16UC1";

/// Nanoseconds since the Unix epoch, now.
pub fn unix_now_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(0)
}

/// A header at `stamp_ns` (Unix time) in frame `frame_id`.
pub fn header(stamp_ns: u64, frame_id: &str) -> Result<Header, LiveError> {
    let stamp = Time::from_nanos(stamp_ns).map_err(|e| LiveError::Encode(e.to_string()))?;
    Ok(Header { stamp, frame_id: frame_id.to_string() })
}

/// A 16UC1 image message of `width × height` `values` (row-major).
pub fn image_16uc1(
    header: Header,
    (width, height): (usize, usize),
    values: &[u16],
) -> Result<Vec<u8>, LiveError> {
    if values.len() != width * height {
        return Err(LiveError::Encode(format!(
            "{} samples for a {width}x{height} image",
            values.len()
        )));
    }
    let dim = |v: usize| u32::try_from(v).map_err(|_| LiveError::Encode(format!("{v} pixels")));
    let msg = Image {
        header,
        height: dim(height)?,
        width: dim(width)?,
        encoding: ENCODING_16UC1.into(),
        is_bigendian: 0,
        step: dim(width * 2)?,
        data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
    };
    msg.to_cdr().map_err(|e| LiveError::Encode(e.to_string()))
}

/// A `CompressedImage` of the JPEG `jpeg` (format `jpeg`).
pub fn compressed_jpeg(header: Header, jpeg: &[u8]) -> Result<Vec<u8>, LiveError> {
    let msg = CompressedImage { header, format: "jpeg".into(), data: jpeg.to_vec() };
    msg.to_cdr().map_err(|e| LiveError::Encode(e.to_string()))
}

/// The messages answered to queries and republished: both cameras' `CameraInfo` (their
/// headers' stamps are set per frame) and the static transforms.
#[derive(Debug, Clone)]
pub struct Latched {
    /// The depth camera's `CameraInfo`.
    pub depth_info: CameraInfo,
    /// The colour camera's `CameraInfo`.
    pub color_info: CameraInfo,
    /// `/tf_static`: the sensor's transforms (colour from depth, and the depth camera in the
    /// rig's reference frame for a rig of several sensors).
    pub transforms: Vec<TransformStamped>,
}

impl Latched {
    fn cdr(&self, topic: LiveTopic) -> Option<Vec<u8>> {
        match topic {
            LiveTopic::DepthInfo => self.depth_info.to_cdr().ok(),
            LiveTopic::ColorInfo => self.color_info.to_cdr().ok(),
            LiveTopic::TfStatic => TFMessage { transforms: self.transforms.clone() }.to_cdr().ok(),
            _ => None,
        }
    }
}

/// One sensor's publishers ([module docs](self)).
pub struct SensorPublisher {
    publishers: Vec<zenoh::pubsub::Publisher<'static>>,
    sequence: [i64; LIVE_TOPICS.len()],
    gid: [u8; GID_BYTES],
    latched: Arc<Mutex<Latched>>,
    _queryables: Vec<zenoh::query::Queryable<()>>,
    bytes: u64,
}

impl std::fmt::Debug for SensorPublisher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SensorPublisher").field("bytes", &self.bytes).finish_non_exhaustive()
    }
}

impl SensorPublisher {
    /// Declares the publishers of sensor `serial` in ROS domain `domain` on `session`, and the
    /// queryables answering `latched`'s keys.
    pub fn declare(
        session: &zenoh::Session,
        domain: u32,
        serial: &str,
        latched: Latched,
    ) -> Result<Self, LiveError> {
        let zerr = |what: &str, e: zenoh::Error| LiveError::Zenoh(format!("{what}: {e}"));
        let mut publishers = Vec::new();
        for t in LIVE_TOPICS {
            let key = t.key(domain, serial);
            let p = session
                .declare_publisher(key.clone())
                .congestion_control(CongestionControl::Drop)
                .wait()
                .map_err(|e| zerr(&format!("declaring the publisher of {key}"), e))?;
            publishers.push(p);
        }
        let latched = Arc::new(Mutex::new(latched));
        let mut queryables = Vec::new();
        for t in [LiveTopic::DepthInfo, LiveTopic::ColorInfo, LiveTopic::TfStatic] {
            let key = t.key(domain, serial);
            let held = latched.clone();
            let reply_key = key.clone();
            let q = session
                .declare_queryable(key.clone())
                .callback(move |query| {
                    let bytes = held.lock().unwrap_or_else(|p| p.into_inner()).cdr(t);
                    if let Some(bytes) = bytes {
                        // A reply the querier no longer waits for is no error of ours.
                        let _ = query.reply(reply_key.clone(), bytes).wait();
                    }
                })
                .wait()
                .map_err(|e| zerr(&format!("declaring the queryable of {key}"), e))?;
            queryables.push(q);
        }
        // The GID: the session's id (16 bytes), as rmw_zenoh derives its GIDs from it.
        let zid = session.zid().to_le_bytes();
        let mut gid = [0u8; GID_BYTES];
        for (g, z) in gid.iter_mut().zip(zid.iter()) {
            *g = *z;
        }
        Ok(Self {
            publishers,
            sequence: [0; LIVE_TOPICS.len()],
            gid,
            latched,
            _queryables: queryables,
            bytes: 0,
        })
    }

    /// Publishes `cdr` on `topic` with its attachment. A message the network cannot take now
    /// is dropped by Zenoh (module docs); an error is a closed session.
    pub fn put(&mut self, topic: LiveTopic, payload: Vec<u8>) -> Result<(), LiveError> {
        let i = topic.index();
        self.sequence[i] += 1;
        let att = Attachment {
            sequence_number: self.sequence[i],
            source_timestamp: unix_now_ns() as i64,
            source_gid: self.gid,
        };
        self.bytes += payload.len() as u64;
        self.publishers[i]
            .put(payload)
            .attachment(att.encode())
            .wait()
            .map_err(|e| LiveError::Zenoh(format!("publishing {topic:?}: {e}")))
    }

    /// Publishes both `CameraInfo`s with their headers stamped `stamp` (the depth frame's
    /// header, and the colour camera's frame for the colour one); returns their bytes.
    pub fn put_camera_infos(&mut self, depth: Header, color: Header) -> Result<u64, LiveError> {
        let (d, c) = {
            let mut l = self.latched.lock().unwrap_or_else(|p| p.into_inner());
            l.depth_info.header = depth;
            l.color_info.header = color;
            let enc = |m: &CameraInfo| m.to_cdr().map_err(|e| LiveError::Encode(e.to_string()));
            (enc(&l.depth_info)?, enc(&l.color_info)?)
        };
        let n = (d.len() + c.len()) as u64;
        self.put(LiveTopic::DepthInfo, d)?;
        self.put(LiveTopic::ColorInfo, c)?;
        Ok(n)
    }

    /// Publishes `/tf_static` (at start and now and then, for ROS nodes that join late: a
    /// ROS 2 subscriber on `rmw_zenoh` does not query kfuse's queryable).
    pub fn put_tf_static(&mut self) -> Result<(), LiveError> {
        let bytes = self
            .latched
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .cdr(LiveTopic::TfStatic)
            .ok_or_else(|| LiveError::Encode("the static transforms".into()))?;
        self.put(LiveTopic::TfStatic, bytes)
    }

    /// Bytes published so far.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }
}
