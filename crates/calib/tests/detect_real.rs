//! Detection on the real Kinect IR images of kinect-lab, checked against the corners the lab
//! extracted with Bouguet's toolbox (OpenCV's classic corners equal them to 0.001 px, and
//! OpenCV's SB corners cover ir_2 and ir_11 which the classic detector misses).

mod common;

use calib::detect::{detect, to_f32, DetectorParams};
use common::*;
use geometry::Image;
use nalgebra::Vector2;

fn load_gray(path: &std::path::Path) -> Image<u8> {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_luma8();
    Image::from_vec(img.width() as usize, img.height() as usize, img.into_raw()).unwrap()
}

/// Reference corners of an image: OpenCV classic (≡ Bouguet) when present, else SB.
fn reference(lab: &serde_json::Value, name: &str) -> Option<(Vec<Vector2<f64>>, &'static str)> {
    for kind in ["classic", "sb"] {
        if let Some(list) = lab["corners_px"][name][kind].as_array() {
            return Some((list.iter().map(|p| Vector2::new(f(&p[0]), f(&p[1]))).collect(), kind));
        }
    }
    None
}

#[test]
fn real_ir_boards_are_found_and_labelled() {
    let Some(data) = shared_data("real_ir_boards_are_found_and_labelled") else { return };
    let lab = json(data.join("kinect-lab/opencv_reference.json"));
    let board = board();
    let mut correct = 0;
    for i in 1..=11 {
        let name = format!("ir_{i}.bmp");
        let img = load_gray(&data.join("kinect-lab").join(&name));
        let det = detect(&to_f32(&img), &board, &DetectorParams::for_image(img.width(), img.height()));
        let Some(det) = det else {
            eprintln!("{name}: not found");
            continue;
        };
        let Some((refc, kind)) = reference(&lab, &name) else {
            eprintln!("{name}: {} corners, no reference", det.corners.len());
            continue;
        };
        // Match to the reference by position; the labelling is correct when one board
        // symmetry maps all our ids onto the reference's ids.
        let mut dists = Vec::new();
        let mut maps = std::collections::BTreeMap::new();
        for c in &det.corners {
            let (k, d) = refc.iter().enumerate().map(|(k, r)| (k, (r - c.px).norm())).min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
            dists.push(d);
            // Our (x, y) → reference (x', y'): either identical or rotated by 180°.
            let same = k == c.id;
            let rot = k == board.len() - 1 - c.id;
            *maps.entry((same, rot)).or_insert(0) += 1;
        }
        let mean = dists.iter().sum::<f64>() / dists.len() as f64;
        let max = dists.iter().copied().fold(0.0, f64::max);
        let consistent = maps.len() == 1 && maps.keys().all(|&(s, r)| s || r);
        eprintln!("{name}: {} corners (complete {}), vs {kind}: mean {mean:.3} max {max:.3} px, labels {maps:?}", det.corners.len(), det.complete);
        if consistent && max < 1.0 {
            correct += 1;
        }
    }
    eprintln!("correctly labelled: {correct} / 11");
    assert!(correct >= 10, "{correct}");
}
