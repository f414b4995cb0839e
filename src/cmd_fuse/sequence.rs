//! `kfuse fuse --recording` / `--frames`: a whole recording or frame folder through the
//! streamed pipeline of `kfuse-sequence`, into one output folder that appears when the run
//! ends (Ctrl-C included: the complete frames and a valid index are kept).

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use calib::rig_io::{self, Calibration};
use clap::{Args, ValueEnum};
use fusion_gpu::Engine;
use geometry::{DepthKind, Rig};
use indicatif::{ProgressBar, ProgressStyle};
use kfuse_io::atomic::StagedDir;
use kfuse_sequence::matching::DEFAULT_MAX_SKEW_TICKS;
use kfuse_sequence::pipeline::{self, Config, Input, Kept, Report};
use kfuse_sequence::process::{self, Extras, Processor};
use kfuse_sequence::source::{FolderSource, RecordingSource, TICKS_PER_SECOND};
use kfuse_sequence::tum;
use kfuse_sequence::write::{self, FileSet, FrameWriter, Index, Layout};
use kinect_usb::recording::ReadOptions;

use super::{FuseArgs, inputs};

/// Worker threads of the pipeline: its stages form two groups (read…register, encode+write),
/// so a third thread would have nothing of its own to do.
const MAX_THREADS: usize = 2;

/// Missing or colourless frames named one by one on stderr; the rest are counted (all are in
/// index.json).
const MAX_LISTED: usize = 20;

/// Largest `--max-skew-ms`: a whole second pairs frames 30 periods apart, far beyond any use.
const MAX_SKEW_LIMIT_MS: f64 = 1000.0;

/// The sequence flags of `kfuse fuse`.
#[derive(Args, Debug, Clone, Default)]
#[command(next_help_heading = "Sequences (a recording or a frame folder)")]
pub struct SequenceArgs {
    /// A raw recording (`kfuse capture record`): every depth frame is decoded, matched with
    /// the colour frame nearest in time, registered and written. Without --rig, the rig is
    /// fitted to the sensor's factory parameters stored in the recording.
    #[arg(long, value_name = "SESSION.kfrec", conflicts_with_all = ["color", "depth", "mat", "frames"])]
    pub recording: Option<PathBuf>,
    /// A folder of `kfuse capture` shots (NAME_depth.png with NAME_color.jpg, or
    /// depth_NNNN.png with color_NNNN.jpg), or a quoted glob of their files. Without --rig,
    /// the folder's kinect_params.json.
    #[arg(long, value_name = "DIR|GLOB", conflicts_with_all = ["color", "depth", "mat"])]
    pub frames: Option<PathBuf>,
    /// Output layout: kfuse (depth/NNNNNN.png in mm, by frame number) or tum (TUM RGB-D:
    /// rgb/, depth/ at 5000 per metre, rgb.txt, depth.txt, associations.txt; recordings only).
    #[arg(long, value_enum, default_value_t = LayoutArg::Kfuse)]
    pub layout: LayoutArg,
    /// Per-frame outputs besides the registered depth, comma-separated: holes (H8 mask),
    /// color-on-depth (H6), cloud (PLY, depth camera frame), color (the sensor's JPEG).
    #[arg(long, value_enum, value_delimiter = ',', value_name = "WHAT")]
    pub write: Vec<WriteArg>,
    /// The lab's eight figures for every N-th frame (`every:N`), in figures/NNNNNN/; none by
    /// default (each costs a full single-frame fusion, ~1-3 s).
    #[arg(long, value_name = "every:N", value_parser = parse_every)]
    pub figures: Option<u64>,
    /// Worker threads: 1 (every stage on one) or 2 (read/decode/register | encode/write).
    #[arg(long, default_value_t = 2, value_name = "1|2")]
    pub threads: usize,
    /// Largest time between a depth frame and its colour partner, milliseconds (default:
    /// half the 30 Hz frame period).
    #[arg(long, value_name = "MS", default_value_t = DEFAULT_MAX_SKEW_TICKS as f64 * 1e3 / TICKS_PER_SECOND as f64, allow_negative_numbers = true)]
    pub max_skew_ms: f64,
    /// Accept a truncated recording and use its intact beginning.
    #[arg(long)]
    pub allow_truncated: bool,
    /// Leave out records of the recording whose checksum does not match.
    #[arg(long)]
    pub skip_corrupt: bool,
}

/// `--layout`.
#[derive(ValueEnum, Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LayoutArg {
    /// depth/NNNNNN.png (millimetres) by frame number, index.json.
    #[default]
    Kfuse,
    /// The TUM RGB-D benchmark's layout.
    Tum,
}

/// `--write`.
#[derive(ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum WriteArg {
    /// holes/…png: H8 disocclusion mask on the colour grid (255 = hole).
    Holes,
    /// color_on_depth/…png: H6 colour on the depth grid.
    ColorOnDepth,
    /// cloud/…ply: H1 points in the depth camera frame, coloured by H6.
    Cloud,
    /// color/…jpg: the sensor's JPEG, unchanged (always written in the TUM layout as rgb/).
    Color,
}

fn parse_every(s: &str) -> Result<u64, String> {
    s.strip_prefix("every:")
        .and_then(|n| n.parse::<u64>().ok())
        .filter(|&n| n >= 1)
        .ok_or_else(|| format!("'{s}': expected every:N with N >= 1 (e.g. every:30)"))
}

impl FuseArgs {
    /// Whether this is a sequence run (`--recording` or `--frames`).
    pub fn is_sequence(&self) -> bool {
        self.sequence.recording.is_some() || self.sequence.frames.is_some()
    }
}

/// Every name a sequence run may write into `--out`.
fn output_names() -> Vec<String> {
    [
        "index.json",
        "kinect_params.json",
        "depth",
        "rgb",
        "color",
        "holes",
        "color_on_depth",
        "cloud",
        "figures",
        "rgb.txt",
        "depth.txt",
        "associations.txt",
        "README.txt",
    ]
    .map(String::from)
    .into()
}

/// [`inputs::factory_problem`] of `rig` (read from `rig_path`) against the factory parameters
/// in `params` (`source` names where they came from): an error, or a warning with `--force`.
fn check_against_factory(
    rig: &Rig,
    rig_path: &Path,
    params: &Path,
    source: &str,
    force: bool,
) -> Result<()> {
    if let Some(problem) = inputs::factory_problem(rig, rig_path, params, source) {
        if !force {
            bail!("{problem}; pass --force if this really is meant");
        }
        eprintln!("warning: {problem} (--force)");
    }
    Ok(())
}

/// Reads a rig file: a kfuse rig, or the sensor's kinect_params.json (the rig fitted to its
/// factory parameters, as `kfuse rig import` does).
fn load_rig(path: &Path, force: bool) -> Result<Rig> {
    let imported = rig_io::import(&[path.to_path_buf()], &rig_io::ImportOptions::default())?;
    let rig = match imported.calibration {
        Calibration::Rig(rig) => rig,
        Calibration::Camera { .. } => bail!(
            "{}: this is a single-camera file; a sequence needs both cameras and color_from_depth \
             (the sensor's kinect_params.json, or a rig from `kfuse calibrate`)",
            path.display()
        ),
    };
    if force {
        for problem in rig.plausibility_problems() {
            eprintln!("warning: {}: {problem} (--force)", path.display());
        }
    } else if let Err(e) = rig.check_plausible() {
        bail!("{}: {e}; pass --force if the rig really is meant this way", path.display());
    }
    Ok(rig)
}

fn bar_for(len: u64, unit: &str) -> ProgressBar {
    let bar = ProgressBar::new(len.max(1));
    let template = format!(
        "{{spinner}} [{{elapsed_precise}}] {{bar:30}} {{percent:>3}}% {unit} {{msg}} ETA {{eta}}"
    );
    bar.set_style(
        ProgressStyle::with_template(&template).unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.enable_steady_tick(Duration::from_millis(120));
    bar
}

/// Runs `kfuse fuse` on a recording or a frame folder.
pub fn run(args: &FuseArgs) -> Result<()> {
    let command_started = std::time::Instant::now();
    let seq = &args.sequence;
    if !(1..=MAX_THREADS).contains(&seq.threads) {
        bail!("--threads must be 1 or {MAX_THREADS}, got {}", seq.threads);
    }
    if !(seq.max_skew_ms.is_finite()
        && seq.max_skew_ms > 0.0
        && seq.max_skew_ms <= MAX_SKEW_LIMIT_MS)
    {
        bail!("--max-skew-ms must be in (0, {MAX_SKEW_LIMIT_MS}], got {}", seq.max_skew_ms);
    }
    let layout = match seq.layout {
        LayoutArg::Kfuse => Layout::Kfuse,
        LayoutArg::Tum => Layout::Tum,
    };
    if layout == Layout::Tum
        && let Some(f) = &seq.frames
    {
        bail!(
            "{}: a frame folder has no sensor timestamps, which the TUM layout is named by; \
             export a recording (`kfuse capture record`) with --layout tum, or use --layout kfuse",
            f.display()
        );
    }
    let has = |w: WriteArg| seq.write.contains(&w);
    let extras = Extras {
        holes: has(WriteArg::Holes),
        color_on_depth: has(WriteArg::ColorOnDepth) || has(WriteArg::Cloud),
        cloud: has(WriteArg::Cloud),
    };
    let set = FileSet {
        holes: extras.holes,
        color_on_depth: has(WriteArg::ColorOnDepth),
        cloud: extras.cloud,
        color: has(WriteArg::Color),
    };
    let max_skew = (seq.max_skew_ms * TICKS_PER_SECOND as f64 / 1e3).round() as u64;

    let staged = StagedDir::new(&args.out)?;
    staged.refuse_foreign(&output_names())?;
    crate::interrupt::install()?;

    // The input, its rig, and the decoder for a recording.
    let (input, rig, decoder, source_name, progress) = if let Some(path) = &seq.recording {
        let options =
            ReadOptions { keep_prefix: seq.allow_truncated, skip_corrupt: seq.skip_corrupt };
        let src = RecordingSource::open(path, options)?;
        // The sensor's factory parameters, kept beside the frames (and the rig's source
        // without --rig).
        kfuse_capture::write_params_json(staged.path(), src.info())?;
        let rig = match &args.rig {
            Some(r) => {
                let rig = load_rig(r, args.force)?;
                let params = staged.join(inputs::FACTORY_PARAMS);
                check_against_factory(&rig, r, &params, &path.display().to_string(), args.force)?;
                rig
            }
            None => {
                let params = staged.join(inputs::FACTORY_PARAMS);
                let rig = load_rig(&params, args.force).with_context(|| {
                    format!("fitting a rig to the factory parameters stored in {}", path.display())
                })?;
                eprintln!(
                    "rig: fitted to the sensor's factory parameters in {} (pass --rig for a calibrated one)",
                    path.display()
                );
                rig
            }
        };
        let decoder = (process::recording_decoder(src.info())?, src.info().clone());
        let (count, len) = src.progress();
        let progress = Progress::Bytes(count, len);
        (Input::Recording(Box::new(src), max_skew), rig, Some(decoder), path.clone(), progress)
    } else if let Some(frames) = &seq.frames {
        let folder = FolderSource::open(frames)?;
        let dir = if frames.is_dir() { frames.clone() } else { glob_dir(frames) };
        let params = dir.join(inputs::FACTORY_PARAMS);
        let rig = match &args.rig {
            Some(r) => {
                let rig = load_rig(r, args.force)?;
                if params.is_file() {
                    check_against_factory(
                        &rig,
                        r,
                        &params,
                        &params.display().to_string(),
                        args.force,
                    )?;
                }
                rig
            }
            None => {
                if !params.exists() {
                    bail!(
                        "{}: no kinect_params.json beside the frames; pass --rig RIG.json",
                        frames.display()
                    );
                }
                let rig = load_rig(&params, args.force)?;
                eprintln!(
                    "rig: fitted to the sensor's factory parameters in {} (pass --rig for a calibrated one)",
                    params.display()
                );
                rig
            }
        };
        let progress = Progress::Shots(folder.shots.len() as u64);
        (Input::Folder(folder), rig, None, frames.clone(), progress)
    } else {
        bail!("give --recording SESSION.kfrec or --frames DIR");
    };

    let gpu = match args.engine() {
        Engine::Cpu => false,
        Engine::Gpu => true,
        Engine::Auto => fusion_gpu::FusionContext::new().is_ok(),
    };
    let (decoder, info) = decoder.map_or((None, None), |(d, i)| (Some(d), Some(i)));
    let mut processor = Processor::new(&rig, decoder, extras, layout.units_per_metre(), gpu)
        .with_context(|| format!("setting up registration for {}", source_name.display()))?;
    // On the GPU, a recording's depth is decoded there too (the frame never leaves the GPU)
    // unless the depth is needed on the CPU: figures, the cloud, a depth correction.
    if let (Some(info), None) = (&info, seq.figures)
        && processor.decode_on_gpu(info).context("setting up depth decoding on the GPU")?
    {
        eprintln!("depth decoding: on the GPU");
    }
    let engine = processor.adapter().unwrap_or_else(|| "cpu".into());
    if gpu {
        eprintln!("GPU adapter: {engine}");
    }
    let writer = FrameWriter::new(
        staged.path(),
        layout,
        set,
        (rig.color.width, rig.color.height),
        (rig.depth.width, rig.depth.height),
    )?;

    let bar = match &progress {
        Progress::Bytes(_, len) => bar_for(*len, "of the recording"),
        Progress::Shots(n) => bar_for(*n, "of the shots"),
    };
    let started = std::time::Instant::now();
    let mut frames = Vec::new();
    let mut missing = Vec::new();
    let mut skipped = Vec::new();
    let mut listed = 0usize;
    let mut warn = |bar: &ProgressBar, line: String| {
        listed += 1;
        if listed <= MAX_LISTED {
            bar.suspend(|| eprintln!("{line}"));
        }
    };
    let fusion_options = geometry::fusion::FusionOptions::default();
    let mut on_report = |r: Report| -> kfuse_sequence::Result<()> {
        match r {
            Report::Frame(entry, kept) => {
                if entry.color.is_none() {
                    // A folder's shots have no timestamps: a missing colour file, not a skew.
                    let why = if seq.recording.is_some() {
                        format!("no colour frame within {} ms", seq.max_skew_ms)
                    } else {
                        "no colour image of this shot".to_string()
                    };
                    warn(
                        &bar,
                        format!(
                            "frame {}: {why}; its depth is written without colour",
                            entry.name.clone().unwrap_or_else(|| entry.number.to_string()),
                        ),
                    );
                }
                if let Some(k) = kept {
                    // Figure errors are reported, not fatal: the frames matter more.
                    if let Err(e) = draw_figures(&staged, &rig, &k, &fusion_options) {
                        bar.suspend(|| eprintln!("warning: figures of frame {}: {e:#}", k.number));
                    }
                }
                frames.push(entry);
                let fps = frames.len() as f64 / started.elapsed().as_secs_f64().max(1e-9);
                bar.set_message(format!("{} frames, {fps:.1} frames/s", frames.len()));
                match &progress {
                    Progress::Bytes(count, _) => bar.set_position(count.load(Ordering::Relaxed)),
                    Progress::Shots(_) => bar.set_position((frames.len() + skipped.len()) as u64),
                }
            }
            Report::Missing(m) => {
                warn(
                    &bar,
                    format!(
                        "frame {} (depth sequence {}): {}",
                        m.number,
                        m.depth_sequence,
                        m.reason.text()
                    ),
                );
                missing.push(m);
            }
            Report::Skipped(s) => {
                warn(&bar, format!("shot {}: left out: {}", s.name, s.reason));
                skipped.push(s);
            }
        }
        Ok(())
    };
    let config = Config { threads: seq.threads, keep_every: seq.figures };
    let setup_s = command_started.elapsed().as_secs_f64();
    let outcome = pipeline::run(
        input,
        processor,
        &writer,
        config,
        &crate::interrupt::requested,
        &mut on_report,
    )
    .with_context(|| format!("processing {}", source_name.display()))?;
    bar.finish_and_clear();
    if listed > MAX_LISTED {
        eprintln!("... and {} more such lines (all are in index.json)", listed - MAX_LISTED);
    }

    if frames.is_empty() && !outcome.interrupted {
        // Nothing fused: an error, not a folder with an empty index and exit 0 (a user's
        // `--frames` of calibration shots without depth, and a recording cut before its first
        // frame).
        let why = skipped
            .first()
            .map(|s| format!("shot {}: {}", s.name, s.reason))
            .or_else(|| missing.first().map(|m| format!("frame {}: {}", m.number, m.reason.text())))
            .unwrap_or_else(|| "it holds no frame".into());
        bail!(
            "{}: no frame could be fused ({} shot(s) left out, {} depth frame(s) missing; first: {why}); nothing was written",
            source_name.display(),
            skipped.len(),
            missing.len()
        );
    }
    let source = source_name.display().to_string();
    let index = Index {
        format: "kfuse-sequence-index",
        version: 1,
        source: source.clone(),
        layout,
        depth_png: format!(
            "16-bit, registered on the colour grid (colour camera z), {} units per metre, 0 = no sample",
            layout.units_per_metre()
        ),
        depth_units_per_metre: layout.units_per_metre(),
        max_skew_ms: seq.recording.is_some().then_some(seq.max_skew_ms),
        interrupted: outcome.interrupted,
        frames,
        missing,
        skipped_shots: skipped,
        unmatched_color_frames: outcome.unmatched_colors,
        corrupt_records_skipped: outcome.read_report.skipped.len(),
        truncated_recording_used: outcome.read_report.truncated,
        threads: seq.threads,
        engine,
        setup_s,
        wall_s: outcome.wall_s,
        stage_s: outcome.stage_s,
    };
    write::write_index(staged.path(), &index)?;
    if layout == Layout::Tum {
        tum::write_lists(staged.path(), &index.frames, &source, seq.max_skew_ms)?;
    }
    let out = staged.commit()?;
    let n = index.frames.len();
    let fps = n as f64 / outcome.wall_s.max(1e-9);
    if outcome.interrupted {
        return Err(crate::interrupt::Interrupted(format!(
            ": the {n} complete frames and their index were kept in {}",
            out.display()
        ))
        .into());
    }
    println!(
        "wrote {n} frames to {} ({fps:.1} frames/s, {} thread(s), {})",
        out.display(),
        seq.threads,
        index.engine
    );
    if !index.missing.is_empty() || !index.skipped_shots.is_empty() {
        println!(
            "  {} depth frames missing, {} shots left out: listed in {}/index.json",
            index.missing.len(),
            index.skipped_shots.len(),
            out.display()
        );
    }
    let s = &index.stage_s;
    println!(
        "  stages (s, summed over frames): read {:.2}, decode {:.2}, register {:.2}, encode {:.2}, write {:.2}",
        s.read, s.decode, s.register, s.encode, s.write
    );
    if args.timings {
        // Setup and the pipeline's wall time: with two threads, read…register and
        // encode+write each sum to at most the pipeline's part.
        let wall_ms = (setup_s + outcome.wall_s) * 1e3;
        let per: &[&str] =
            &["read", "decode depth", "decode colour", "register", "encode", "write"];
        for line in s.to_timings(setup_s).summary(wall_ms, Some((n, "frame", per))) {
            eprintln!("{line}");
        }
        if seq.threads > 1 {
            eprintln!(
                "  (2 threads: read, decode and register on one, encode and write on the other; each thread's stages are within the wall time)"
            );
        }
    }
    Ok(())
}

/// How progress is measured.
enum Progress {
    /// Bytes of the recording read, of its size.
    Bytes(std::sync::Arc<std::sync::atomic::AtomicU64>, u64),
    /// Shots of a folder.
    Shots(u64),
}

/// The folder of a glob pattern: its components before the first one with a wildcard.
fn glob_dir(pattern: &Path) -> PathBuf {
    let mut dir = PathBuf::new();
    for c in pattern.components() {
        let s = c.as_os_str().to_string_lossy();
        if s.contains(['*', '?', '[']) {
            break;
        }
        dir.push(c);
    }
    if dir == pattern { pattern.parent().map(Path::to_path_buf).unwrap_or_default() } else { dir }
}

/// The lab's figures of one frame into figures/NNNNNN/ (a full single-frame fusion).
fn draw_figures(
    staged: &StagedDir,
    rig: &Rig,
    k: &Kept,
    options: &geometry::fusion::FusionOptions,
) -> Result<()> {
    let Some(jpeg) = &k.jpeg else { bail!("the frame has no colour") };
    let color = jpeg.decode(Path::new(&format!("frame {}", k.number)))?;
    let output = geometry::fusion::run(rig, &k.depth, DepthKind::Z, &color, options)?;
    let dir = staged.join(format!("figures/{:06}", k.number));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let lab = crate::figures::LabInputs {
        rig,
        color: &color,
        depth: &k.depth,
        depth_kind: DepthKind::Z,
        options,
        output: &output,
    };
    let mut files = Vec::new();
    crate::figures::save_lab_figures(|name| dir.join(name), &lab, &mut files)
}
