//! Speed of detection and calibration. Data: `../shared/data/synthetic-calib` (skips with a
//! message when absent). Goal (issue 3): a 25-view 1920x1080 colour + IR stereo calibration end
//! to end in under 3 s.

use std::path::PathBuf;

use calib::detect::{DetectorParams, detect, detect_views, to_f32};
use calib::{Board, CalibFlags, StereoOptions, ViewCorners, calibrate_mono, calibrate_stereo};
use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};
use geometry::Image;

fn data() -> Option<PathBuf> {
    let dir = std::env::var("KFUSE_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|_| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    if dir.join("synthetic-calib").exists() {
        Some(dir)
    } else {
        eprintln!("SKIP calib benches: shared data not found at {}", dir.display());
        None
    }
}

fn load(dir: &std::path::Path, cam: &str, i: usize) -> Image<u8> {
    calib::io::read_gray(&dir.join(format!("synthetic-calib/{cam}/{cam}_{:02}.png", i % 15 + 1)))
        .expect("readable test image")
}

fn benches(c: &mut Criterion) {
    let Some(dir) = data() else { return };
    let board = Board::new(7, 5, 0.04).expect("valid board");
    let ir = load(&dir, "ir", 0);
    let color = load(&dir, "color", 0);
    let (irf, colorf) = (to_f32(&ir), to_f32(&color));
    c.bench_function("detect 512x424 (rendered IR)", |b| {
        b.iter(|| detect(&irf, &board, &DetectorParams::for_image(512, 424)))
    });
    c.bench_function("detect 1920x1080 (rendered colour)", |b| {
        b.iter(|| detect(&colorf, &board, &DetectorParams::for_image(1920, 1080)))
    });
    // 25 pairs (the 15 rendered poses, cycled).
    let irs: Vec<Image<u8>> = (0..25).map(|i| load(&dir, "ir", i)).collect();
    let colors: Vec<Image<u8>> = (0..25).map(|i| load(&dir, "color", i)).collect();
    let irn: Vec<(String, &Image<u8>)> =
        irs.iter().enumerate().map(|(i, im)| (format!("ir{i}"), im)).collect();
    let coln: Vec<(String, &Image<u8>)> =
        colors.iter().enumerate().map(|(i, im)| (format!("c{i}"), im)).collect();
    let (dv, _) = detect_views(&irn, &board);
    let (cv, _) = detect_views(&coln, &board);
    let cv: Vec<ViewCorners> =
        dv.iter().zip(&cv).map(|(d, c)| calib::detect::align_pair(d, c, &board)).collect();
    let mut g = c.benchmark_group("calibration");
    g.sample_size(10);
    // Flat: every sample runs the same number of iterations (10 calls of ~0.1–1 s here, not
    // the 55 of linear sampling), so `benches/run_all.sh` stays minutes long.
    g.sampling_mode(SamplingMode::Flat);
    g.bench_function("mono 25 views (IR corners)", |b| {
        b.iter(|| {
            calibrate_mono("ir", &board, &dv, &CalibFlags::default(), None).expect("calibrates")
        })
    });
    g.bench_function("stereo 25 pairs from corners", |b| {
        b.iter(|| {
            calibrate_stereo(&board, &dv, &cv, &StereoOptions::default(), None, None)
                .expect("calibrates")
        })
    });
    g.bench_function("end to end: detect 25 IR + 25 colour 1080p, stereo", |b| {
        b.iter(|| {
            let (d, _) = detect_views(&irn, &board);
            let (c, _) = detect_views(&coln, &board);
            let c: Vec<ViewCorners> =
                d.iter().zip(&c).map(|(d, c)| calib::detect::align_pair(d, c, &board)).collect();
            calibrate_stereo(&board, &d, &c, &StereoOptions::default(), None, None)
                .expect("calibrates")
        })
    });
    g.finish();
}

criterion_group!(calib_benches, benches);
criterion_main!(calib_benches);
