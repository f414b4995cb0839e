//! The streamed pipeline: read → match → decode (worker A) and register → encode → write
//! (worker B), connected by bounded queues, so that with two threads both cores are busy at
//! once and memory stays bounded whatever the recording's length: at most
//! [`QUEUE_FRAMES`] decoded frames wait between the workers, [`REPORT_QUEUE`] results
//! wait for the caller, the matcher holds [`crate::matching::MAX_PENDING_DEPTH`] raw frames
//! and the GPU path [`GPU_BATCH`] decoded ones. With one thread, one worker runs every stage
//! in turn. The cut between the workers splits a frame's work about in half on the CPU
//! (BENCHMARKS.md, sequences: reading + decoding ~14 ms, registering + encoding + writing
//! ~12 ms); with registration on worker A, worker A was the bottleneck at ~21 ms a frame.
//!
//! Where every frame's colour JPEG is written as the scene is (the TUM and rosbag2 layouts,
//! `--write color`), the sensor's mirrored JPEG is flipped in the DCT domain per frame (about
//! 8 ms at 1920×1080, as much as registering): with two threads, worker A flips every other
//! frame's ([`SHARED_FLIP_EVERY`]) and worker B the rest, so that the flip does not all land
//! on worker B (BENCHMARKS.md, sequences, has the figures before and after).
//!
//! A stop request (Ctrl-C) is polled before each frame is read: the frames already read are
//! finished and reported, so the caller's index lists every complete frame.

use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::time::Instant;

use geometry::Image;
use kinect_usb::recording::ReadReport;

use crate::bag::BagSource;
use crate::color::ColorJpeg;
use crate::matching::{Matched, Matcher, Missing};
use crate::process::{Decoded, FrameDecoder, FrameRegistrar, GPU_BATCH, Processor};
use crate::source::{FolderSource, RecordingSource};
use crate::write::{
    ColorRef, FrameMeta, FrameWriter, IndexEntry, SkippedShot, StageSeconds, seconds_text,
};
use crate::{Result, SequenceError};

/// Decoded frames that may wait for worker B: two keep it fed while worker A is one frame
/// ahead (each holds a 0.9 MB depth image, its colour JPEG, and its decoded colour image when
/// an extra needs it).
pub const QUEUE_FRAMES: usize = 2;

/// With two threads and a layout that writes the scene's JPEG, worker A flips the colour JPEG of
/// every frame whose number is a multiple of this, worker B the others: one in two, because
/// without the flip the workers' shares of a frame are about equal (~13 ms each), so the
/// flip's ~8 ms is best split in half.
pub const SHARED_FLIP_EVERY: u64 = 2;

/// Results that may wait for the caller (progress, index, figures).
pub const REPORT_QUEUE: usize = 4;

/// Where the frames come from.
pub enum Input {
    /// A `.kfrec` recording, with the matcher's skew limit in ticks.
    Recording(Box<RecordingSource>, u64),
    /// A frame folder's shots.
    Folder(FolderSource),
    /// A ROS 2 bag, with the matcher's skew limit in ticks.
    Bag(Box<BagSource>, u64),
}

/// A frame's depth (metres) and colour JPEG, handed to the caller for figures.
pub struct Kept {
    /// The frame number.
    pub number: u64,
    /// Depth, metres, 0 = no sample.
    pub depth: Image<f32>,
    /// The colour JPEG.
    pub jpeg: Option<ColorJpeg>,
    /// H6 colour on the depth grid and where it is trusted, when the run asks for them
    /// ([`crate::SequenceOptions::kept_color`]) and the frame has colour.
    pub color_on_depth: Option<(Image<[u8; 3]>, Image<bool>)>,
}

/// What the pipeline reports, in frame order.
pub enum Report {
    /// A frame was written.
    Frame(IndexEntry, Option<Box<Kept>>),
    /// A depth frame of the recording is missing.
    Missing(Missing),
    /// A shot of a frame folder was left out.
    Skipped(SkippedShot),
}

/// How the pipeline runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Config {
    /// Worker threads: 1 (one worker runs every stage) or 2 (read…decode | register…write).
    pub threads: usize,
    /// Hand every `n`-th frame's depth and JPEG to the caller ([`Report::Frame`]'s `Kept`).
    pub keep_every: Option<u64>,
}

/// How a run ended.
#[derive(Debug, Clone, Default)]
pub struct Outcome {
    /// Stopped by the stop request.
    pub interrupted: bool,
    /// Seconds per stage, summed over frames.
    pub stage_s: StageSeconds,
    /// Wall-clock seconds.
    pub wall_s: f64,
    /// Colour frames without a depth partner.
    pub unmatched_colors: u64,
    /// The recording reader's report (skipped corrupt records, truncated prefix used).
    pub read_report: ReadReport,
}

/// One frame between worker A (read, decode) and worker B (register, encode, write).
struct Item {
    job: Job,
    decoded: Decoded,
}

/// What worker A hands to worker B, in frame order.
enum Stage2 {
    Frame(Box<Item>),
    Missing(Missing),
    Skipped(SkippedShot),
}

/// A frame read, before decoding.
struct Job {
    meta: FrameMeta,
    raw: Option<Vec<u8>>,
    depth_png: Option<std::path::PathBuf>,
    jpeg: Option<ColorJpeg>,
    /// The file the colour JPEG was read from (a frame folder's), for messages.
    color_file: Option<std::path::PathBuf>,
    /// `raw` is depth already decoded (a bag's): metres as little-endian `f32`, this size.
    predecoded: Option<(usize, usize)>,
}

/// The reading end: recording + matcher, or the folder's shots.
struct Reader {
    input: Input,
    matcher: Option<Matcher>,
    finished: bool,
    next_shot: usize,
}

impl Reader {
    fn new(input: Input) -> Self {
        let matcher = match &input {
            Input::Recording(_, skew) | Input::Bag(_, skew) => Some(Matcher::new(*skew)),
            Input::Folder(_) => None,
        };
        Self { input, matcher, finished: false, next_shot: 0 }
    }

    /// The next job or gap, `None` at the end.
    fn next(&mut self) -> Result<Option<Result<Job, Stage2>>> {
        match (&mut self.input, &mut self.matcher) {
            (Input::Recording(src, _), Some(m)) => loop {
                if let Some(r) = m.pop() {
                    return Ok(Some(paired_job(r, None, true)));
                }
                if self.finished {
                    return Ok(None);
                }
                match src.next_event()? {
                    Some(ev) => m.push(ev),
                    None => {
                        m.finish();
                        self.finished = true;
                    }
                }
            },
            (Input::Bag(src, _), Some(m)) => loop {
                if let Some(r) = m.pop() {
                    // A bag's colour is as the scene is (kfuse's rosbag2 layout writes the
                    // sensor's JPEG flipped; ROS drivers publish it unmirrored).
                    return Ok(Some(paired_job(r, src.depth_size(), false)));
                }
                if self.finished {
                    return Ok(None);
                }
                match src.next_event()? {
                    Some(ev) => m.push(ev),
                    None => {
                        m.finish();
                        self.finished = true;
                    }
                }
            },
            (Input::Folder(f), _) => {
                let Some(shot) = f.shots.get(self.next_shot).cloned() else { return Ok(None) };
                let number = self.next_shot as u64;
                self.next_shot += 1;
                let Some(depth) = shot.depth else {
                    return Ok(Some(Err(Stage2::Skipped(SkippedShot {
                        name: shot.name,
                        reason: "no depth file (only its colour JPEG is there)".into(),
                    }))));
                };
                let jpeg = match &shot.color {
                    // Bounded like every image read (a FIFO or a device named as a shot's
                    // colour file is refused, not read to the end).
                    Some(c) => Some(kfuse_io::image_header::read_image_bytes(c).map_err(|e| {
                        SequenceError::input(c, format!("cannot read the colour JPEG: {e}"))
                    })?),
                    None => None,
                };
                Ok(Some(Ok(Job {
                    meta: FrameMeta {
                        number,
                        name: Some(shot.name),
                        depth_sequence: None,
                        depth_time: None,
                        color: shot.color.is_some().then_some(ColorRef {
                            sequence: None,
                            time_s: None,
                            time_ticks: None,
                        }),
                    },
                    raw: None,
                    depth_png: Some(depth),
                    jpeg: jpeg.map(|bytes| ColorJpeg { bytes, mirrored: false }),
                    color_file: shot.color.clone(),
                    predecoded: None,
                })))
            }
            (Input::Recording(..) | Input::Bag(..), None) => Ok(None),
        }
    }

    fn finish(self) -> (u64, ReadReport) {
        let unmatched = self.matcher.as_ref().map_or(0, Matcher::unmatched_colors);
        match self.input {
            Input::Recording(src, _) => (unmatched, src.report()),
            Input::Folder(_) | Input::Bag(..) => (unmatched, ReadReport::default()),
        }
    }
}

/// The job of a matched pair (or the gap of a missing frame): `predecoded` is the size of a
/// bag's depth (already in metres), `mirrored` whether the colour is the sensor's mirrored JPEG.
fn paired_job(
    r: Matched,
    predecoded: Option<(usize, usize)>,
    mirrored: bool,
) -> Result<Job, Stage2> {
    match r {
        Matched::Missing(x) => Err(Stage2::Missing(x)),
        Matched::Frame(p) => Ok(Job {
            meta: FrameMeta {
                number: p.number,
                name: None,
                depth_sequence: Some(p.depth.sequence),
                depth_time: Some(p.depth.timestamp),
                color: p.color.as_ref().map(|c| ColorRef {
                    sequence: Some(c.sequence),
                    time_s: Some(seconds_text(c.timestamp)),
                    time_ticks: Some(c.timestamp),
                }),
            },
            raw: Some(p.depth.data),
            depth_png: None,
            jpeg: p.color.map(|c| ColorJpeg { bytes: c.jpeg, mirrored }),
            color_file: None,
            predecoded,
        }),
    }
}

fn secs(t: Instant) -> f64 {
    t.elapsed().as_secs_f64()
}

/// Worker A: reads and decodes every frame, handing each (and every gap) to `emit`.
fn produce(
    reader: &mut Reader,
    decoding: &mut FrameDecoder,
    stop: &(dyn Fn() -> bool + Sync),
    emit: &mut dyn FnMut(Stage2) -> Result<bool>,
    times: &mut StageSeconds,
    share_flip: bool,
) -> Result<bool> {
    loop {
        if stop() {
            return Ok(true);
        }
        let t = Instant::now();
        let next = reader.next()?;
        times.read += secs(t);
        let item = match next {
            None => return Ok(false),
            Some(Err(gap)) => gap,
            Some(Ok(mut job)) => {
                let t = Instant::now();
                let mut raw_for_gpu = None;
                let mut sensor = None;
                let depth = match (&job.raw, &job.depth_png, job.predecoded) {
                    (Some(metres), _, Some((w, h))) => decoding.take_decoded(metres, w, h)?,
                    (Some(_), _, None) if decoding.decodes_on_gpu() => {
                        raw_for_gpu = job.raw.take();
                        Image::filled(0, 0, 0.0)
                    }
                    (Some(raw), _, None) => {
                        let depth = decoding.decode_raw(raw)?;
                        sensor = decoding.sensor_images();
                        depth
                    }
                    (None, Some(p), _) => decoding.read_depth_png(p)?,
                    (None, None, _) => {
                        return Err(SequenceError::Pipeline("a frame without depth".into()));
                    }
                };
                // The raw frame (2.9 MB) is not needed past decoding.
                job.raw = None;
                times.decode_depth += secs(t);
                let t_color = Instant::now();
                let name = job.color_file.clone().unwrap_or_else(|| {
                    std::path::PathBuf::from(format!("frame {}", job.meta.number))
                });
                let color = match &job.jpeg {
                    Some(j) => decoding.decode_color(j, &name)?,
                    None => None,
                };
                times.decode_color += secs(t_color);
                times.decode += secs(t);
                if share_flip && job.meta.number % SHARED_FLIP_EVERY == 0 {
                    flip_here(&mut job.jpeg, &name, times)?;
                }
                let decoded = Decoded { depth, raw: raw_for_gpu, color, sensor };
                Stage2::Frame(Box::new(Item { job, decoded }))
            }
        };
        if !emit(item)? {
            return Ok(false);
        }
    }
}

/// The sensor's mirrored JPEG replaced by the scene's (flipped without loss, as worker B's
/// encoding would have written it), its time counted as encoding.
fn flip_here(
    jpeg: &mut Option<ColorJpeg>,
    name: &std::path::Path,
    times: &mut StageSeconds,
) -> Result<()> {
    if let Some(j) = jpeg.as_mut().filter(|j| j.mirrored) {
        let t = Instant::now();
        *j = ColorJpeg { bytes: j.scene_jpeg(name)?.into_owned(), mirrored: false };
        times.encode += secs(t);
    }
    Ok(())
}

/// Worker B: registers the decoded frames (one at a time on the CPU, in batches of
/// [`GPU_BATCH`] on the GPU), encodes and writes them, and passes gaps on, as reports.
struct Backend<'a> {
    registering: &'a mut FrameRegistrar,
    writer: &'a FrameWriter,
    keep_every: Option<u64>,
    batch: Vec<Item>,
    times: StageSeconds,
}

impl<'a> Backend<'a> {
    fn new(registering: &'a mut FrameRegistrar, writer: &'a FrameWriter, config: &Config) -> Self {
        Self {
            registering,
            writer,
            keep_every: config.keep_every,
            batch: Vec::new(),
            times: StageSeconds::default(),
        }
    }

    /// Takes the next item; reports go to `report` (false: the caller stopped taking them).
    fn take(&mut self, s: Stage2, report: &mut dyn FnMut(Report) -> bool) -> Result<bool> {
        match s {
            Stage2::Missing(m) => Ok(report(Report::Missing(m))),
            Stage2::Skipped(k) => Ok(report(Report::Skipped(k))),
            Stage2::Frame(item) => {
                self.batch.push(*item);
                let batch_size = if self.registering.on_gpu() { GPU_BATCH } else { 1 };
                if self.batch.len() < batch_size {
                    return Ok(true);
                }
                self.flush(report)
            }
        }
    }

    /// Registers, encodes and writes the frames waiting in the batch.
    fn flush(&mut self, report: &mut dyn FnMut(Report) -> bool) -> Result<bool> {
        if self.batch.is_empty() {
            return Ok(true);
        }
        let t = Instant::now();
        let mut decoded: Vec<Decoded> =
            self.batch.iter_mut().map(|i| take_decoded(&mut i.decoded)).collect();
        let registered = self.registering.register(&decoded)?;
        self.times.register += secs(t);
        for ((item, d), r) in self.batch.drain(..).zip(decoded.drain(..)).zip(registered) {
            let job = item.job;
            let kept = self.keep_every.filter(|&n| n > 0 && job.meta.number % n == 0).map(|_| {
                Box::new(Kept {
                    number: job.meta.number,
                    depth: d.depth,
                    jpeg: job.jpeg.clone(),
                    color_on_depth: r.color_on_depth.clone().zip(r.color_valid.clone()),
                })
            });
            let t = Instant::now();
            let encoded = self.writer.encode(job.meta, &r, job.jpeg.as_ref(), d.sensor.as_ref())?;
            drop(r);
            self.times.encode += secs(t);
            let t = Instant::now();
            let entry = self.writer.write(encoded)?;
            self.times.write += secs(t);
            if !report(Report::Frame(entry, kept)) {
                return Ok(false);
            }
        }
        Ok(true)
    }
}

fn take_decoded(d: &mut Decoded) -> Decoded {
    Decoded {
        depth: std::mem::replace(&mut d.depth, Image::filled(0, 0, 0.0)),
        raw: d.raw.take(),
        color: d.color.take(),
        sensor: d.sensor.take(),
    }
}

fn send<T>(tx: &SyncSender<T>, v: T) -> bool {
    tx.send(v).is_ok()
}

/// Runs the pipeline over `input`: every frame through `processor` and `writer`, each result
/// handed to `on_report` on the calling thread in frame order. `stop` is polled before each
/// frame is read.
///
/// Errors: the first error of any stage (the other stages stop at their next frame); a
/// worker thread that cannot start.
pub fn run(
    input: Input,
    mut processor: Processor,
    writer: &FrameWriter,
    config: Config,
    stop: &(dyn Fn() -> bool + Sync),
    on_report: &mut dyn FnMut(Report) -> Result<()>,
) -> Result<Outcome> {
    let start = Instant::now();
    let mut reader = Reader::new(input);
    let (report_tx, report_rx): (SyncSender<Report>, Receiver<Report>) = sync_channel(REPORT_QUEUE);
    let Processor { decoding, registering } = &mut processor;
    // On the GPU worker B only waits for the device; the flip then stays where it is.
    let share_flip = config.threads >= 2 && writer.writes_scene_jpeg() && !registering.on_gpu();
    let result = std::thread::scope(|s| -> Result<(bool, StageSeconds)> {
        let reader = &mut reader;
        let mut backend = Backend::new(registering, writer, &config);
        let worker_a;
        let mut worker_b = None;
        if config.threads >= 2 {
            let (tx, rx) = sync_channel::<Stage2>(QUEUE_FRAMES);
            let report_tx = report_tx.clone();
            worker_b = Some(
                std::thread::Builder::new()
                    .name("kfuse-seq-write".into())
                    .spawn_scoped(s, move || -> Result<StageSeconds> {
                        let mut report = |r: Report| send(&report_tx, r);
                        for item in rx {
                            if !backend.take(item, &mut report)? {
                                return Ok(backend.times);
                            }
                        }
                        backend.flush(&mut report)?;
                        Ok(backend.times)
                    })
                    .map_err(|e| SequenceError::Pipeline(format!("cannot start a thread: {e}")))?,
            );
            worker_a = std::thread::Builder::new()
                .name("kfuse-seq-read".into())
                .spawn_scoped(s, move || -> Result<(bool, StageSeconds)> {
                    let mut times = StageSeconds::default();
                    let mut emit = |x: Stage2| Ok(send(&tx, x));
                    let i = produce(reader, decoding, stop, &mut emit, &mut times, share_flip)?;
                    Ok((i, times))
                })
                .map_err(|e| SequenceError::Pipeline(format!("cannot start a thread: {e}")))?;
        } else {
            let report_tx = report_tx.clone();
            worker_a = std::thread::Builder::new()
                .name("kfuse-seq".into())
                .spawn_scoped(s, move || -> Result<(bool, StageSeconds)> {
                    let mut times = StageSeconds::default();
                    let mut report = |r: Report| send(&report_tx, r);
                    let mut emit = |x: Stage2| backend.take(x, &mut report);
                    let i = produce(reader, decoding, stop, &mut emit, &mut times, false)?;
                    backend.flush(&mut report)?;
                    times.add_backend(&backend.times);
                    Ok((i, times))
                })
                .map_err(|e| SequenceError::Pipeline(format!("cannot start a thread: {e}")))?;
        }
        drop(report_tx);
        let mut caller_error = None;
        for r in report_rx {
            if caller_error.is_none()
                && let Err(e) = on_report(r)
            {
                // Stop taking results: the workers see the closed queue and stop.
                caller_error = Some(e);
                break;
            }
        }
        let a: Result<(bool, StageSeconds)> = joined(worker_a);
        let b: Option<Result<StageSeconds>> = worker_b.map(joined);
        if let Some(e) = caller_error {
            return Err(e);
        }
        let (interrupted, mut times) = a?;
        if let Some(b) = b {
            times.add_backend(&b?);
        }
        Ok((interrupted, times))
    });
    let (interrupted, stage_s) = result?;
    let (unmatched_colors, read_report) = reader.finish();
    Ok(Outcome { interrupted, stage_s, wall_s: secs(start), unmatched_colors, read_report })
}

/// A worker's result; a worker's panic is passed on.
fn joined<T>(h: std::thread::ScopedJoinHandle<'_, T>) -> T {
    h.join().unwrap_or_else(|p| std::panic::resume_unwind(p))
}
