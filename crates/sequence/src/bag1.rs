//! A reader of ROS 1 bags (format 2.0, what `rosbag record` and iai_kinect2's users wrote),
//! streamed record by record for [`crate::bag::BagSource`]: the `#ROSBAG V2.0` line, then
//! records of `header_len: u32`, header fields (`field_len: u32`, `name=value`), `data_len:
//! u32`, data. Records by `op`: bag header (0x03), chunk (0x05: `compression`, `size`; its data
//! holds connection and message records), index data (0x04), connection (0x07: `conn`,
//! `topic`; its data the fields `type`, `md5sum`, `message_definition`), message data (0x02:
//! `conn`, `time`), chunk info (0x06).
//!
//! Chunks: **uncompressed (`none`) only**; a bz2 or lz4 chunk is refused with how to convert
//! the bag (`rosbag decompress`). Every length is checked against [`MAX_HEADER_BYTES`],
//! [`crate::bag::MAX_RECORD_BYTES`] and the bytes around it before anything is allocated; a
//! connection's `md5sum` must be its type's (the layout decoded is that type's), and the
//! message types are those of [`kfuse_ros_msgs::ros1`].

use std::collections::{HashMap, VecDeque};
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicU64;

use crate::bag::MAX_RECORD_BYTES;
use crate::source::Counting;
use crate::{Result, SequenceError};

/// The first line of a ROS 1 bag, format 2.0.
pub const MAGIC: &[u8] = b"#ROSBAG V2.0\n";

/// Largest record header read: 1 MiB. A record's header holds a few short fields (a connection
/// record's message definition is in its data, not its header).
pub const MAX_HEADER_BYTES: usize = 1 << 20;

/// Read buffer: 1 MiB, as the MCAP reader's.
const READ_BUFFER: usize = 1 << 20;

/// Record `op` codes (ROS 1 bag format 2.0).
const OP_MESSAGE: u8 = 0x02;
const OP_BAG_HEADER: u8 = 0x03;
const OP_CHUNK: u8 = 0x05;
const OP_CONNECTION: u8 = 0x07;

/// The ROS 1 message types kfuse decodes and their MD5 sums (`rosmsg md5`): a connection of one
/// of these types with another sum has another layout, and is refused.
pub const KNOWN_MD5: [(&str, &str); 4] = [
    ("sensor_msgs/Image", "060021388200f6f0f447d0fcd9c64743"),
    ("sensor_msgs/CompressedImage", "8f7a12909da2c9d3332d540a0977563f"),
    ("sensor_msgs/CameraInfo", "c9a58c1b0b154e0e6da7578cb991d214"),
    ("tf2_msgs/TFMessage", "94810edda583a504dfda3829e70d7eec"),
];

/// Whether `path` is a file that starts with [`MAGIC`].
pub fn is_ros1_bag(path: &Path) -> bool {
    if path.is_dir() {
        return false;
    }
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        // A pipe or a FIFO gives its bytes once and a sniff would steal them from the reader:
        // only the name tells.
        return path.extension().is_some_and(|e| e == "bag");
    }
    file_starts_with(path, MAGIC)
}

/// Whether the regular file `path` starts with `magic` (false for anything else: a pipe or a
/// FIFO is never opened here, its first bytes belong to the reader that follows).
pub(crate) fn file_starts_with(path: &Path, magic: &[u8]) -> bool {
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return false;
    }
    let mut head = vec![0u8; magic.len()];
    std::fs::File::open(path).and_then(|mut f| f.read_exact(&mut head)).is_ok() && head == magic
}

/// A record of the bag kfuse uses.
pub enum Ros1Rec {
    /// A connection: its id (renumbered in order of appearance), topic and type as ROS 2 names
    /// it (`pkg/msg/Type`).
    Connection {
        /// The id.
        id: u16,
        /// The topic.
        topic: String,
        /// The type.
        msg_type: String,
    },
    /// A message of connection `conn`.
    Message {
        /// The connection's id (as [`Ros1Rec::Connection`]'s).
        conn: u16,
        /// The serialised message.
        data: Vec<u8>,
    },
}

/// A ROS 1 bag read record by record.
pub struct Ros1Stream {
    path: PathBuf,
    file: BufReader<Counting>,
    /// The chunk being read and the offset of its next record.
    chunk: Option<(Vec<u8>, usize)>,
    /// The bag's connection ids to ours.
    conns: HashMap<u32, u16>,
    pending: VecDeque<Ros1Rec>,
}

/// A record's header fields.
type Fields = HashMap<String, Vec<u8>>;

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    b.get(at..at + 4).map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
}

/// The fields of a header (or a connection record's data): `len: u32` then `name=value`.
fn parse_fields(b: &[u8]) -> std::result::Result<Fields, String> {
    let mut out = Fields::new();
    let mut at = 0;
    while at < b.len() {
        let n = u32_at(b, at).ok_or("a header field's length is cut short")? as usize;
        at += 4;
        let field = b
            .get(at..at.saturating_add(n))
            .ok_or_else(|| format!("a header field claims {n} bytes, {} are left", b.len() - at))?;
        at += n;
        let eq = field.iter().position(|&c| c == b'=').ok_or("a header field without '='")?;
        let name = String::from_utf8_lossy(&field[..eq]).into_owned();
        out.insert(name, field[eq + 1..].to_vec());
    }
    Ok(out)
}

fn field_u32(f: &Fields, name: &str) -> std::result::Result<u32, String> {
    match f.get(name) {
        Some(v) if v.len() == 4 => Ok(u32::from_le_bytes([v[0], v[1], v[2], v[3]])),
        Some(v) => Err(format!("field '{name}' is {} bytes, expected 4", v.len())),
        None => Err(format!("a record without its '{name}' field")),
    }
}

fn field_text(f: &Fields, name: &str) -> std::result::Result<String, String> {
    f.get(name)
        .map(|v| String::from_utf8_lossy(v).into_owned())
        .ok_or_else(|| format!("a record without its '{name}' field"))
}

/// `pkg/Type` as ROS 2 names it: `pkg/msg/Type`.
fn ros2_type(t: &str) -> String {
    match t.split_once('/') {
        Some((pkg, name)) if !name.contains('/') => format!("{pkg}/msg/{name}"),
        _ => t.to_string(),
    }
}

impl Ros1Stream {
    /// Opens `path` and checks its first line. Returns the stream and the file's size.
    pub fn open(path: &Path, count: Arc<AtomicU64>) -> Result<(Self, u64)> {
        let io = |e: std::io::Error| SequenceError::input(path, format!("cannot read: {e}"));
        let file = bounded_read::open_without_blocking(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        let mut file = BufReader::with_capacity(READ_BUFFER, Counting { file, count });
        let mut magic = [0u8; 13];
        file.read_exact(&mut magic).map_err(io)?;
        if magic != MAGIC {
            return Err(SequenceError::input(path, "not a ROS 1 bag of format 2.0"));
        }
        let s = Self {
            path: path.to_path_buf(),
            file,
            chunk: None,
            conns: HashMap::new(),
            pending: VecDeque::new(),
        };
        Ok((s, len))
    }

    /// The bag file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn bad(&self, m: impl std::fmt::Display) -> SequenceError {
        SequenceError::input(&self.path, format!("not a readable ROS 1 bag: {m}"))
    }

    /// Reads exactly `n` bytes; `what` names them in the error of a file cut short.
    fn read_n(&mut self, n: usize, what: &str) -> Result<Vec<u8>> {
        let mut v = vec![0; n];
        self.file.read_exact(&mut v).map_err(|e| match e.kind() {
            std::io::ErrorKind::UnexpectedEof => {
                self.bad(format!("it ends inside {what} (a truncated file)"))
            }
            _ => SequenceError::input(&self.path, format!("cannot read: {e}")),
        })?;
        Ok(v)
    }

    /// The next top-level record's length field, `None` at a clean end of file.
    fn read_len(&mut self) -> Result<Option<u32>> {
        let mut b = [0u8; 4];
        let mut got = 0;
        while got < 4 {
            let n = self
                .file
                .read(&mut b[got..])
                .map_err(|e| SequenceError::input(&self.path, format!("cannot read: {e}")))?;
            if n == 0 {
                return if got == 0 {
                    Ok(None)
                } else {
                    Err(self.bad("it ends inside a record's length (a truncated file)"))
                };
            }
            got += n;
        }
        Ok(Some(u32::from_le_bytes(b)))
    }

    fn bounded(&self, n: u32, limit: usize, what: &str) -> Result<usize> {
        let n = n as usize;
        if n > limit {
            return Err(self.bad(format!("{what} claims {n} bytes, more than the {limit} read")));
        }
        Ok(n)
    }

    /// A connection record's header and data as a [`Ros1Rec::Connection`], `None` for one
    /// already seen (the index section repeats the chunks' connections).
    fn connection(&mut self, header: &Fields, data: &[u8]) -> Result<Option<Ros1Rec>> {
        let bag_id = field_u32(header, "conn").map_err(|m| self.bad(m))?;
        if self.conns.contains_key(&bag_id) {
            return Ok(None);
        }
        let topic = field_text(header, "topic").map_err(|m| self.bad(m))?;
        let fields = parse_fields(data).map_err(|m| self.bad(format!("topic {topic}: {m}")))?;
        let ty =
            field_text(&fields, "type").map_err(|m| self.bad(format!("topic {topic}: {m}")))?;
        let md5 = field_text(&fields, "md5sum").unwrap_or_default();
        if let Some((_, want)) = KNOWN_MD5.iter().find(|(t, _)| *t == ty)
            && md5 != *want
            && md5 != "*"
        {
            return Err(SequenceError::input(
                &self.path,
                format!(
                    "topic {topic}: type {ty} with md5sum {md5}, not the standard {want}: another definition of the message, which kfuse cannot decode"
                ),
            ));
        }
        let id = u16::try_from(self.conns.len())
            .map_err(|_| self.bad(format!("more than {} connections", u16::MAX)))?;
        self.conns.insert(bag_id, id);
        Ok(Some(Ros1Rec::Connection { id, topic, msg_type: ros2_type(&ty) }))
    }

    fn message(&self, header: &Fields, data: Vec<u8>) -> Result<Ros1Rec> {
        let bag_id = field_u32(header, "conn").map_err(|m| self.bad(m))?;
        let conn = *self.conns.get(&bag_id).ok_or_else(|| {
            self.bad(format!("a message of connection {bag_id}, declared nowhere before it"))
        })?;
        Ok(Ros1Rec::Message { conn, data })
    }

    /// The next record inside the current chunk, `None` when it is used up.
    fn next_in_chunk(&mut self) -> Result<Option<Ros1Rec>> {
        loop {
            let Some((buf, at)) = self.chunk.take() else { return Ok(None) };
            if at >= buf.len() {
                return Ok(None);
            }
            let cut = |what: &str| self.bad(format!("a chunk ends inside a record's {what}"));
            let hlen = u32_at(&buf, at).ok_or_else(|| cut("header length"))? as usize;
            let h = buf.get(at + 4..(at + 4).saturating_add(hlen)).ok_or_else(|| cut("header"))?;
            let header = parse_fields(h).map_err(|m| self.bad(m))?;
            let dat = at + 4 + hlen;
            let dlen = u32_at(&buf, dat).ok_or_else(|| cut("data length"))? as usize;
            let data = buf
                .get(dat + 4..(dat + 4).saturating_add(dlen))
                .ok_or_else(|| cut("data"))?
                .to_vec();
            let next = dat + 4 + dlen;
            let op = header.get("op").and_then(|v| v.first().copied());
            self.chunk = Some((buf, next));
            match op {
                Some(OP_CONNECTION) => {
                    if let Some(c) = self.connection(&header, &data)? {
                        return Ok(Some(c));
                    }
                }
                Some(OP_MESSAGE) => return Ok(Some(self.message(&header, data)?)),
                _ => {}
            }
        }
    }

    /// The next connection or message, `None` at the end of the bag.
    pub fn next_record(&mut self) -> Result<Option<Ros1Rec>> {
        loop {
            if let Some(r) = self.pending.pop_front() {
                return Ok(Some(r));
            }
            if let Some(r) = self.next_in_chunk()? {
                return Ok(Some(r));
            }
            let Some(hlen) = self.read_len()? else { return Ok(None) };
            let hlen = self.bounded(hlen, MAX_HEADER_BYTES, "a record header")?;
            let h = self.read_n(hlen, "a record header")?;
            let header = parse_fields(&h).map_err(|m| self.bad(m))?;
            let dlen = match self.read_len()? {
                Some(n) => self.bounded(n, MAX_RECORD_BYTES, "a record")?,
                None => return Err(self.bad("it ends before a record's data (a truncated file)")),
            };
            let op = header.get("op").and_then(|v| v.first().copied());
            let data = self.read_n(dlen, "a record's data")?;
            match op {
                Some(OP_CHUNK) => {
                    let compression =
                        field_text(&header, "compression").map_err(|m| self.bad(m))?;
                    if compression != "none" {
                        return Err(self.bad(format!(
                            "a chunk compressed with {compression}: only uncompressed ROS 1 bags are read; \
                             decompress it first (`rosbag decompress BAG`)"
                        )));
                    }
                    let size = field_u32(&header, "size").map_err(|m| self.bad(m))? as usize;
                    if size != data.len() {
                        return Err(self.bad(format!(
                            "an uncompressed chunk of {} bytes says its size is {size}",
                            data.len()
                        )));
                    }
                    self.chunk = Some((data, 0));
                }
                Some(OP_CONNECTION) => {
                    if let Some(c) = self.connection(&header, &data)? {
                        self.pending.push_back(c);
                    }
                }
                Some(OP_MESSAGE) => {
                    let m = self.message(&header, data)?;
                    self.pending.push_back(m);
                }
                Some(OP_BAG_HEADER) | Some(_) => {}
                None => return Err(self.bad("a record without its 'op' field")),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(fields: &[&[u8]], data: &[u8]) -> Vec<u8> {
        let mut h = Vec::new();
        for f in fields {
            h.extend_from_slice(&(f.len() as u32).to_le_bytes());
            h.extend_from_slice(f);
        }
        let mut r = (h.len() as u32).to_le_bytes().to_vec();
        r.extend_from_slice(&h);
        r.extend_from_slice(&(data.len() as u32).to_le_bytes());
        r.extend_from_slice(data);
        r
    }

    /// A bag of one uncompressed chunk: a connection of `md5` and one message.
    fn bag(compression: &str, md5: &str) -> Vec<u8> {
        let conn_data = record(
            &[
                b"topic=/k/sd/image_depth",
                b"type=sensor_msgs/Image",
                format!("md5sum={md5}").as_bytes(),
            ],
            b"",
        );
        // A connection record's data is a header of fields, without the lengths around it.
        let conn_fields = &conn_data[4..conn_data.len() - 4];
        let mut chunk =
            record(&[b"op=\x07", b"conn=\x05\0\0\0", b"topic=/k/sd/image_depth"], conn_fields);
        chunk.extend(record(&[b"op=\x02", b"conn=\x05\0\0\0", b"time=\0\0\0\0\0\0\0\0"], b"msg"));
        let mut b = MAGIC.to_vec();
        b.extend(record(&[b"op=\x03"], &[b' '; 16]));
        let mut size = b"size=".to_vec();
        size.extend_from_slice(&(chunk.len() as u32).to_le_bytes());
        let comp = format!("compression={compression}");
        b.extend(record(&[b"op=\x05", comp.as_bytes(), &size], &chunk));
        b
    }

    fn read_all(bytes: &[u8]) -> Result<Vec<Ros1Rec>> {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.bag");
        std::fs::write(&p, bytes).unwrap();
        assert!(is_ros1_bag(&p));
        let (mut s, _) = Ros1Stream::open(&p, Arc::default())?;
        let mut out = Vec::new();
        while let Some(r) = s.next_record()? {
            out.push(r);
        }
        Ok(out)
    }

    const IMAGE_MD5: &str = "060021388200f6f0f447d0fcd9c64743";

    #[test]
    fn a_chunked_bag_gives_its_connection_and_message() {
        let recs = read_all(&bag("none", IMAGE_MD5)).unwrap();
        assert_eq!(recs.len(), 2);
        match &recs[0] {
            Ros1Rec::Connection { id, topic, msg_type } => {
                assert_eq!((*id, topic.as_str()), (0, "/k/sd/image_depth"));
                assert_eq!(msg_type, "sensor_msgs/msg/Image");
            }
            Ros1Rec::Message { .. } => panic!("a connection first"),
        }
        match &recs[1] {
            Ros1Rec::Message { conn, data } => {
                assert_eq!((*conn, data.as_slice()), (0, &b"msg"[..]))
            }
            Ros1Rec::Connection { .. } => panic!("then the message"),
        }
    }

    #[test]
    fn damaged_bags_are_one_error_each() {
        let text = |b: &[u8]| read_all(b).err().map(|e| e.to_string()).unwrap_or_default();
        let good = bag("none", IMAGE_MD5);
        assert!(text(&good[..good.len() - 2]).contains("truncated"));
        assert!(text(&bag("bz2", IMAGE_MD5)).contains("rosbag decompress"));
        let e = text(&bag("none", "0123456789abcdef0123456789abcdef"));
        assert!(e.contains("/k/sd/image_depth") && e.contains("another definition"), "{e}");
        // The chunk record's data length (after magic, the bag header record and the chunk's
        // header) claims 4 GiB.
        let mut huge = good.clone();
        let bag_header = 4 + u32_at(&good, MAGIC.len()).unwrap() as usize + 4 + 16;
        let chunk_at = MAGIC.len() + bag_header;
        let hlen = u32_at(&good, chunk_at).unwrap() as usize;
        let dlen_at = chunk_at + 4 + hlen;
        huge[dlen_at..dlen_at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        let e = text(&huge);
        assert!(e.contains("claims 4294967295 bytes"), "{e}");
        // A header field longer than its header.
        let mut field = good.clone();
        field[chunk_at + 4..chunk_at + 8].copy_from_slice(&1000u32.to_le_bytes());
        assert!(text(&field).contains("claims 1000 bytes"), "{}", text(&field));
    }

    #[test]
    fn header_fields_are_bounded_and_types_renamed() {
        let mut b = Vec::new();
        for f in [&b"op=\x07"[..], b"topic=/a"] {
            b.extend_from_slice(&(f.len() as u32).to_le_bytes());
            b.extend_from_slice(f);
        }
        let f = parse_fields(&b).unwrap();
        assert_eq!(f["op"], vec![7]);
        assert_eq!(f["topic"], b"/a".to_vec());
        let mut long = b.clone();
        long.extend_from_slice(&1000u32.to_le_bytes());
        long.extend_from_slice(b"x=1");
        assert!(parse_fields(&long).unwrap_err().contains("claims 1000 bytes"));
        assert_eq!(ros2_type("sensor_msgs/Image"), "sensor_msgs/msg/Image");
        assert_eq!(ros2_type("sensor_msgs/msg/Image"), "sensor_msgs/msg/Image");
    }
}
