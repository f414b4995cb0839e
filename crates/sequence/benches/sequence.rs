//! Per-stage benchmarks of the sequence pipeline on frames of the simulated Kinect v2
//! (recorded through the same USB protocol path as `kfuse capture record --backend sim`):
//!
//! * `stage/read_frame`: reading one frame's records (CRC-32 checked) and assembling the
//!   depth frame and colour JPEG (a 10-frame recording read whole, per frame);
//! * `stage/decode`: the `Fast` depth decoder, one thread;
//! * `stage/register`: `Registration` + the 16-bit conversion of the z-buffer, one thread;
//! * `stage/write`: writing one encoded depth PNG (atomic rename) into a temporary folder;
//! * `jpeg/*`: the recording's first colour frame (the simulator's 1920×1080 JPEG, as the
//!   sensor streams it): `decode_image_crate` is `kfuse_io::images::decode_color_noting` as
//!   every colour reader decodes today (the `image` crate's JPEG decoder, zune-jpeg, plus the
//!   copy into kfuse's `Image`), `decode_turbojpeg` libjpeg-turbo's `tjDecompress` into RGB
//!   (the same pixels within JPEG's rounding), `flip_lossless`
//!   [`kfuse_io::sensor_color::flip_jpeg_lossless`] (what the TUM layout does per frame to
//!   write `rgb/`), and `copy` a plain copy of the same bytes (what the kfuse layout's
//!   `--write color` does with a frame that needs no flip) for scale;
//! * `png16/<compression>_<filter>`: the registered depth frame (1920×1080, 16 bit) encoded
//!   with each zlib level and row filter considered for [`kfuse_sequence::write::PNG_COMPRESSION`]
//!   and [`kfuse_sequence::write::PNG_FILTER`]; each variant's size is printed once.
//!
//! End to end (threads, queues, the binary): `benches/sequence_e2e.sh`.

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use kfuse_capture::{SensorSource, Session, SimOptions};
use kfuse_sequence::process::{self, Decoded, Extras, Processor};
use kfuse_sequence::source::{RecordingSource, SourceEvent};
use kfuse_sequence::write::{KFUSE_UNITS_PER_METRE, encode_png};
use kinect_usb::recording::ReadOptions;

/// Frames of the benchmark recording.
const FRAMES: u64 = 10;

fn record(dir: &Path) -> (std::path::PathBuf, geometry::Rig) {
    let path = dir.join("bench.kfrec");
    let mut session = Session::open(&SensorSource::Sim(SimOptions::default())).unwrap();
    kfuse_capture::record::record(&mut session, &path, FRAMES, &|| false, &mut |_| {}).unwrap();
    kfuse_capture::write_params_json(dir, session.info()).unwrap();
    let params = [dir.join("kinect_params.json")];
    let opts = kfuse_io::rig_io::ImportOptions::default();
    let rig = match kfuse_io::rig_io::import(&params, &opts).unwrap().calibration {
        kfuse_io::rig_io::Calibration::Rig(r) => r,
        _ => panic!("kinect_params.json is a rig"),
    };
    (path, rig)
}

/// The recording's raw depth frames and colour JPEGs, in order.
fn read_all(path: &Path) -> (Vec<Vec<u8>>, Vec<Vec<u8>>) {
    let mut src = RecordingSource::open(path, ReadOptions::default()).unwrap();
    let mut raws = Vec::new();
    let mut jpegs = Vec::new();
    while let Some(ev) = src.next_event().unwrap() {
        match ev {
            SourceEvent::Depth { frame, .. } => raws.push(frame.data),
            SourceEvent::Color(c) => jpegs.push(c.jpeg),
        }
    }
    (raws, jpegs)
}

fn benches(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let (path, rig) = record(dir.path());
    let (raws, jpegs) = read_all(&path);
    let n = raws.len() as u32;
    let src = RecordingSource::open(&path, ReadOptions::default()).unwrap();
    let decoder = process::recording_decoder(src.info()).unwrap();
    let (cpu, _) = fusion_gpu::Engine::Cpu.open().unwrap();
    let options = geometry::fusion::FusionOptions::default();
    let mut p = Processor::new(
        &rig,
        Some(decoder),
        Extras::default(),
        KFUSE_UNITS_PER_METRE,
        &options,
        cpu,
    )
    .unwrap();

    let mut g = c.benchmark_group("stage");
    g.sample_size(20);
    g.bench_function("read_frame", |b| {
        b.iter_custom(|iters| {
            let t = std::time::Instant::now();
            for _ in 0..iters.div_ceil(u64::from(n)) {
                black_box(read_all(&path));
            }
            t.elapsed() / n
        })
    });
    g.bench_function("decode", |b| b.iter(|| black_box(p.decoding.decode_raw(&raws[0]).unwrap())));
    let depth = p.decoding.decode_raw(&raws[0]).unwrap();
    let frame = [Decoded { depth, raw: None, color: None, sensor: None }];
    g.bench_function("register", |b| b.iter(|| black_box(p.registering.register(&frame).unwrap())));
    let registered = p.registering.register(&frame).unwrap().remove(0);
    let (w, h) = (rig.color.width, rig.color.height);
    let be: Vec<u8> = registered.depth_units.iter().flat_map(|v| v.to_be_bytes()).collect();
    let encode = |c, f| {
        encode_png(w, h, png::ColorType::Grayscale, png::BitDepth::Sixteen, &be, c, f).unwrap()
    };
    let chosen = encode(kfuse_sequence::write::PNG_COMPRESSION, kfuse_sequence::write::PNG_FILTER);
    let out = dir.path().join("depth.png");
    g.bench_function("write", |b| {
        b.iter(|| kfuse_io::atomic::write_bytes_atomic(&out, black_box(&chosen)).unwrap())
    });
    g.finish();

    let mut g = c.benchmark_group("jpeg");
    g.sample_size(20);
    let jpeg = &jpegs[0];
    let name = Path::new("bench colour frame");
    g.bench_function("decode_image_crate", |b| {
        b.iter(|| black_box(kfuse_io::images::decode_color_noting(name, black_box(jpeg)).unwrap()))
    });
    g.bench_function("decode_turbojpeg", |b| {
        b.iter(|| {
            black_box(turbojpeg::decompress(black_box(jpeg), turbojpeg::PixelFormat::RGB).unwrap())
        })
    });
    g.bench_function("flip_lossless", |b| {
        b.iter(|| black_box(kfuse_io::sensor_color::flip_jpeg_lossless(black_box(jpeg)).unwrap()))
    });
    g.bench_function("copy", |b| b.iter(|| black_box(black_box(jpeg).clone())));
    eprintln!("jpeg: the colour frame is {} bytes", jpeg.len());
    g.finish();

    let mut g = c.benchmark_group("png16");
    g.sample_size(10);
    use png::{Compression as C, Filter as F};
    for (cn, comp) in [("fastest", C::Fastest), ("fast", C::Fast), ("balanced", C::Balanced)] {
        for (fname, filter) in
            [("none", F::NoFilter), ("sub", F::Sub), ("up", F::Up), ("adaptive", F::Adaptive)]
        {
            let size = encode(comp, filter).len();
            eprintln!("png16/{cn}_{fname}: {size} bytes ({:.2} MB)", size as f64 / 1e6);
            g.bench_function(format!("{cn}_{fname}"), |b| {
                b.iter(|| black_box(encode(comp, filter)))
            });
        }
    }
    g.finish();
}

criterion_group!(sequence, benches);
criterion_main!(sequence);
