//! Where detection spends its time: the median per stage of [`calib::detect::detect_timed`]
//! over repeated runs, per image class (the criterion bench's rendered IR and colour images,
//! and every image of each real corpus set). Release build:
//! `cargo run --release -p calib --example detect_stages` (`KFUSE_REPS=N` repetitions, default
//! 15; `KFUSE_SHARED_DATA` as in the tests). Single-threaded per image except where a stage
//! uses rayon itself.

use std::path::{Path, PathBuf};
use std::time::Duration;

use calib::Board;
use calib::detect::{DetectorParams, StageTimes, detect_timed, to_f32};

fn median(mut v: Vec<Duration>) -> f64 {
    v.sort();
    v[v.len() / 2].as_secs_f64() * 1e3
}

/// Median per stage (ms) of `reps` runs over every image, and how many boards were found.
fn measure(images: &[geometry::Image<f32>], board: &Board, reps: usize) -> ([f64; 7], usize) {
    let mut runs: Vec<StageTimes> = Vec::new();
    let mut found = 0;
    for img in images {
        let params = DetectorParams::for_image(img.width(), img.height());
        for r in 0..reps {
            let (d, t) = detect_timed(img, board, &params);
            if r == 0 && d.is_some_and(|d| d.complete) {
                found += 1;
            }
            runs.push(t);
        }
    }
    let col = |f: fn(&StageTimes) -> Duration| median(runs.iter().map(f).collect());
    (
        [
            col(|t| t.response),
            col(|t| t.peaks),
            col(|t| t.subpix),
            col(|t| t.grid),
            col(|t| t.label),
            col(|t| t.refine),
            col(|t| t.total()),
        ],
        found,
    )
}

fn load(path: &Path) -> geometry::Image<f32> {
    to_f32(&calib::io::read_gray(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())))
}

fn main() {
    let data = std::env::var("KFUSE_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|_| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    let reps: usize = std::env::var("KFUSE_REPS").ok().and_then(|v| v.parse().ok()).unwrap_or(15);
    let synth = data.join("synthetic-calib");
    let b75 = Board::new(7, 5, 0.04).expect("board");
    let mut classes: Vec<(String, Vec<geometry::Image<f32>>, Board)> = vec![
        ("rendered IR 512x424 (bench image)".into(), vec![load(&synth.join("ir/ir_01.png"))], b75),
        (
            "rendered colour 1920x1080 (bench image)".into(),
            vec![load(&synth.join("color/color_01.png"))],
            b75,
        ),
    ];
    for (set, glob_prefix, cols, rows) in [
        ("opencv-stereo-640x480-9x6", "left", 9, 6),
        ("udacity-camera-cal-1280x720-9x6", "calibration", 9, 6),
        ("gopro-wide-1280x960-8x6", "GOPR", 8, 6),
        ("color-1920x1080-9x6-robotarm", "", 9, 6),
    ] {
        let dir = data.join("calib-corpus").join(set).join("images");
        let Ok(rd) = std::fs::read_dir(&dir) else { continue };
        let mut files: Vec<PathBuf> = rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.file_name().is_some_and(|n| n.to_string_lossy().starts_with(glob_prefix)))
            .collect();
        files.sort();
        let images = files.iter().map(|p| load(p)).collect();
        classes.push((
            format!("{set} ({glob_prefix}*)"),
            images,
            Board::new(cols, rows, 1.0).expect("board"),
        ));
    }
    println!("median ms per image over {reps} runs of each image");
    println!(
        "| images | n | found | response | peaks | subpix | grid | label | final fit | total |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for (name, images, board) in &classes {
        let (m, found) = measure(images, board, reps);
        println!(
            "| {name} | {} | {found} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
            images.len(),
            m[0],
            m[1],
            m[2],
            m[3],
            m[4],
            m[5],
            m[6]
        );
    }
}
