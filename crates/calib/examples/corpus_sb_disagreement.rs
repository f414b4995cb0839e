//! Where kfuse's and OpenCV's `findChessboardCornersSB` corners disagree most on the public
//! corpus (`../shared/data/calib-corpus`), drawn so that the eye can judge which is right.
//!
//! For every set and camera it detects the boards as `tests/corpus.rs` does, compares each
//! corner with SB's corner of the same index (SB's order turned to kfuse's ordering rule, per
//! image the turn that fits) and keeps the worst corner of each image; the [`TILES_PER_CAMERA`]
//! worst images per camera become tiles: a [`CROP`]×[`CROP`] px crop of the grey image around
//! the kfuse corner, scaled ×[`SCALE`] with nearest-neighbour pixels (one image pixel = one
//! 8×8 block; pixel centres at the blocks' centres), marked with
//!
//! * kfuse: green `+`,
//! * OpenCV SB: red `×`,
//! * OpenCV classic refined with a 5x5 `cornerSubPix` window (`corners_alt`): blue square.
//!
//! Tiles are laid out in rows of [`TILES_PER_ROW`], in the order printed (set, camera, image,
//! corner id, the three distances). Writes `docs/figures/corpus_sb_disagreement.png` (or the
//! path given as the first argument):
//!
//! `cargo run --release -p calib --example corpus_sb_disagreement`

use std::path::{Path, PathBuf};

use calib::detect::detect_views;
use calib::{Board, ViewCorners};
use geometry::Image;
use nalgebra::Vector2;
use serde_json::Value;

/// Crop side, image pixels (odd: the kfuse corner's pixel in the middle).
const CROP: usize = 21;
/// Magnification of the crop.
const SCALE: usize = 8;
/// Worst images shown per camera.
const TILES_PER_CAMERA: usize = 2;
/// Tiles per row of the figure.
const TILES_PER_ROW: usize = 4;
/// Gap between tiles, px.
const GAP: usize = 4;
/// Half length of a marker's arms, px of the figure.
const ARM: i64 = 12;
/// Radius of the hole in the middle of a cross, px of the figure.
const HOLE: i64 = 3;
const GREEN: [u8; 3] = [40, 230, 40];
const RED: [u8; 3] = [255, 30, 30];
const BLUE: [u8; 3] = [40, 120, 255];

const SETS: [&str; 4] = [
    "opencv-stereo-640x480-9x6",
    "gopro-wide-1280x960-8x6",
    "udacity-camera-cal-1280x720-9x6",
    "color-1920x1080-9x6-robotarm",
];

fn points(v: &Value) -> Option<Vec<Vector2<f64>>> {
    v.as_array()?
        .iter()
        .map(|p| Some(Vector2::new(p[0].as_f64()?, p[1].as_f64()?)))
        .collect::<Option<Vec<_>>>()
}

/// One tile: the image, the corner's three positions and what to print.
struct Tile {
    img: Image<u8>,
    kfuse: Vector2<f64>,
    sb: Vector2<f64>,
    classic5: Option<Vector2<f64>>,
    label: String,
}

/// SB's (and classic's) corner index for kfuse's `id` under a turn of 0° or 180°.
fn index(id: usize, n: usize, half_turn: bool) -> usize {
    if half_turn { n - 1 - id } else { id }
}

fn worst_of(view: &ViewCorners, sb: &[Vector2<f64>], half_turn: bool) -> (f64, usize) {
    view.corners
        .iter()
        .map(|c| ((c.px - sb[index(c.id, sb.len(), half_turn)]).norm(), c.id))
        .fold((0.0, 0), |a, b| if b.0 > a.0 { b } else { a })
}

fn tiles_of_set(data: &Path, set: &str) -> Result<Vec<Tile>, String> {
    let root = data.join("calib-corpus").join(set);
    let text = std::fs::read_to_string(root.join("reference.json")).map_err(|e| e.to_string())?;
    let r: Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
    let dim = |k: &str| r["board"][k].as_u64().map(|v| v as usize).ok_or("board size");
    let board = Board::new(dim("cols")?, dim("rows")?, 1.0).map_err(|e| e.to_string())?;
    let cameras = r["cameras"].as_object().ok_or("no cameras")?;
    let mut out = Vec::new();
    for (camera, files) in cameras {
        let files: Vec<&str> =
            files.as_array().ok_or("cameras")?.iter().filter_map(|v| v.as_str()).collect();
        let images = files
            .iter()
            .map(|p| calib::io::read_gray(&root.join(p)).map_err(|e| e.to_string()))
            .collect::<Result<Vec<_>, _>>()?;
        let named: Vec<(String, &Image<u8>)> =
            files.iter().zip(&images).map(|(p, i)| (p.to_string(), i)).collect();
        let (views, _) = detect_views(&named, &board);
        let mut worst: Vec<(f64, Tile)> = Vec::new();
        for ((file, view), img) in files.iter().zip(&views).zip(&images) {
            let Some(e) =
                r["images"].as_array().and_then(|a| a.iter().find(|i| i["file"] == *file))
            else {
                continue;
            };
            if view.corners.len() != board.len() || e["sb"]["found"] != Value::Bool(true) {
                continue;
            }
            let sb = points(&e["sb"]["corners"]).ok_or("sb corners")?;
            let c5 = points(&e["classic"]["corners_alt"]).filter(|_| e["classic"]["found"] == true);
            let (a, b) = (worst_of(view, &sb, false), worst_of(view, &sb, true));
            let half_turn = b.0 < a.0;
            let (d, id) = if half_turn { b } else { a };
            let k = view.corners.iter().find(|c| c.id == id).ok_or("corner")?.px;
            let s = sb[index(id, sb.len(), half_turn)];
            // Classic's own order can be turned against SB's: its turn that fits kfuse.
            let c = c5.as_ref().map(|c| {
                let turn = worst_of(view, c, true).0 < worst_of(view, c, false).0;
                c[index(id, c.len(), turn)]
            });
            let dist = |p: Option<Vector2<f64>>, q: Vector2<f64>| {
                p.map_or("-".to_string(), |p| format!("{:.2}", (p - q).norm()))
            };
            let label = format!(
                "{set} {camera} {file} corner {id}: kfuse-SB {d:.2} px, kfuse-classic5x5 {} px, SB-classic5x5 {} px",
                dist(c, k),
                dist(c, s)
            );
            worst.push((d, Tile { img: (*img).clone(), kfuse: k, sb: s, classic5: c, label }));
        }
        worst.sort_by(|a, b| b.0.total_cmp(&a.0));
        out.extend(worst.into_iter().take(TILES_PER_CAMERA).map(|w| w.1));
    }
    Ok(out)
}

/// The tile's pixels (RGB, `CROP·SCALE` square).
fn render(t: &Tile) -> Vec<[u8; 3]> {
    let n = CROP * SCALE;
    let (x0, y0) =
        (t.kfuse.x.round() as i64 - CROP as i64 / 2, t.kfuse.y.round() as i64 - CROP as i64 / 2);
    let mut px = vec![[0u8; 3]; n * n];
    for (k, p) in px.iter_mut().enumerate() {
        let (x, y) = ((k % n) / SCALE, (k / n) / SCALE);
        let (ix, iy) = (x0 + x as i64, y0 + y as i64);
        let v = if ix >= 0
            && iy >= 0
            && (ix as usize) < t.img.width()
            && (iy as usize) < t.img.height()
        {
            *t.img.get(ix as usize, iy as usize)
        } else {
            0
        };
        *p = [v; 3];
    }
    // Image coordinate → figure coordinate (pixel centres at the blocks' centres).
    let at = |q: Vector2<f64>| {
        (
            ((q.x - x0 as f64) * SCALE as f64 + SCALE as f64 / 2.0).round() as i64,
            ((q.y - y0 as f64) * SCALE as f64 + SCALE as f64 / 2.0).round() as i64,
        )
    };
    let mut put = |x: i64, y: i64, c: [u8; 3]| {
        if x >= 0 && y >= 0 && (x as usize) < n && (y as usize) < n {
            px[y as usize * n + x as usize] = c;
        }
    };
    // Markers leave a hole of HOLE px around their point, so the pixels they mark stay visible.
    if let Some(c) = t.classic5 {
        let (cx, cy) = at(c);
        let e = ARM - 3;
        for d in -e..=e {
            for w in 0..2 {
                put(cx + d, cy - e - w, BLUE);
                put(cx + d, cy + e + w, BLUE);
                put(cx - e - w, cy + d, BLUE);
                put(cx + e + w, cy + d, BLUE);
            }
        }
    }
    let (sx, sy) = at(t.sb);
    let (kx, ky) = at(t.kfuse);
    // Lines two figure pixels wide.
    for d in (HOLE..=ARM).flat_map(|d| [d, -d]) {
        for w in 0..2 {
            put(sx + d + w, sy + d, RED);
            put(sx + d + w, sy - d, RED);
            put(kx + d, ky + w, GREEN);
            put(kx + w, ky + d, GREEN);
        }
    }
    px
}

fn main() -> Result<(), String> {
    let out = std::env::args().nth(1).map(PathBuf::from).unwrap_or_else(|| {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/figures/corpus_sb_disagreement.png")
    });
    let data = geometry::testdata::shared_data_or_skip("corpus_sb_disagreement")
        .ok_or("no shared data (set KFUSE_SHARED_DATA)")?;
    let mut tiles = Vec::new();
    for set in SETS {
        tiles.extend(tiles_of_set(&data, set)?);
    }
    let side = CROP * SCALE;
    let cols = TILES_PER_ROW.min(tiles.len()).max(1);
    let rows = tiles.len().div_ceil(cols);
    let (w, h) = (cols * side + (cols + 1) * GAP, rows * side + (rows + 1) * GAP);
    let mut fig = image::RgbImage::from_pixel(w as u32, h as u32, image::Rgb([255, 255, 255]));
    for (k, t) in tiles.iter().enumerate() {
        println!("tile {} (row {}, column {}): {}", k + 1, k / cols + 1, k % cols + 1, t.label);
        let (ox, oy) = (GAP + (k % cols) * (side + GAP), GAP + (k / cols) * (side + GAP));
        for (i, p) in render(t).into_iter().enumerate() {
            fig.put_pixel((ox + i % side) as u32, (oy + i / side) as u32, image::Rgb(p));
        }
    }
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    fig.save(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    println!("wrote {}", out.display());
    Ok(())
}
