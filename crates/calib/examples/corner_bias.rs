//! Diagnostic: detected corners vs the exact projections of `synthetic-calib/ground_truth.json`
//! per camera (mean offset = bias, RMS, mean |e|), and the same statistics when every corner is
//! refined again with different windows. `cargo run -p calib --example corner_bias`.

use std::path::PathBuf;

use calib::detect::{detect_views, fit_junction, refine_corner, rotate_180, to_f32};
use calib::{Board, ViewCorners};
use nalgebra::Vector2;

fn main() {
    let dir = std::env::var("KFUSE_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|_| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"))
        .join("synthetic-calib");
    let gt: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("ground_truth.json")).expect("gt")).expect("json");
    let board = Board::new(7, 5, 0.04).expect("board");
    for cam in ["ir", "color"] {
        let imgs: Vec<_> = (1..=15).map(|i| calib::io::read_gray(&dir.join(format!("{cam}/{cam}_{i:02}.png"))).expect("img")).collect();
        let named: Vec<(String, &geometry::Image<u8>)> = imgs.iter().enumerate().map(|(i, m)| (format!("{i}"), m)).collect();
        let (views, _) = detect_views(&named, &board);
        let truth: Vec<Vec<Vector2<f64>>> = (0..15)
            .map(|i| {
                gt["views"][i][cam]["corners_px"].as_array().expect("list").iter().map(|p| Vector2::new(p[0].as_f64().expect("x"), p[1].as_f64().expect("y"))).collect()
            })
            .collect();
        // Align labelling with the truth.
        let views: Vec<ViewCorners> = views
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let e = |v: &ViewCorners| v.corners.iter().map(|c| (c.px - truth[i][c.id]).norm()).sum::<f64>();
                let r = rotate_180(v, &board);
                if e(v) <= e(&r) { v.clone() } else { r }
            })
            .collect();
        let stats = |name: &str, pts: &dyn Fn(usize, usize, Vector2<f64>) -> Option<Vector2<f64>>| {
            let (mut s, mut s2, mut sa, mut n, mut fail) = (Vector2::zeros(), 0.0, 0.0, 0, 0);
            let mut per_view = Vec::new();
            for (i, v) in views.iter().enumerate() {
                let mut vs = Vector2::zeros();
                for c in &v.corners {
                    let Some(p) = pts(i, c.id, c.px) else { fail += 1; continue };
                    let e = p - truth[i][c.id];
                    s += e;
                    vs += e;
                    s2 += e.norm_squared();
                    sa += e.norm();
                    n += 1;
                }
                per_view.push(format!("({:+.3},{:+.3})", vs.x / v.corners.len() as f64, vs.y / v.corners.len() as f64));
            }
            let nf = n as f64;
            println!("{cam} {name:28}: n {n} fail {fail} mean|e| {:.4} rms {:.4} bias ({:+.4}, {:+.4})", sa / nf, (s2 / nf).sqrt(), s.x / nf, s.y / nf);
            if std::env::var("PER_VIEW").is_ok() {
                println!("   per view bias {}", per_view.join(" "));
            }
        };
        stats("detected", &|_, _, p| Some(p));
        stats("truth itself (sanity)", &|i, k, _| Some(truth[i][k]));
        let fimgs: Vec<_> = imgs.iter().map(to_f32).collect();
        let step = |i: usize, k: usize| {
            let (x, y) = (k % 7, k / 7);
            let mut d = f64::INFINITY;
            for (dx, dy) in [(1i32, 0i32), (-1, 0), (0, 1), (0, -1)] {
                let (nx, ny) = (x as i32 + dx, y as i32 + dy);
                if nx >= 0 && ny >= 0 && nx < 7 && ny < 5 {
                    d = d.min((truth[i][(ny * 7 + nx) as usize] - truth[i][k]).norm());
                }
            }
            d
        };
        let dirs = |i: usize, k: usize| {
            let (x, y) = (k % 7, k / 7);
            let a = if x < 6 { truth[i][k + 1] - truth[i][k] } else { truth[i][k] - truth[i][k - 1] };
            let b = if y < 4 { truth[i][k + 7] - truth[i][k] } else { truth[i][k] - truth[i][k - 7] };
            [a, b]
        };
        for frac in [0.2, 0.3, 0.35, 0.4, 0.45, 0.5] {
            stats(&format!("fit frac {frac}"), &|i, k, p| fit_junction(&fimgs[i], p, dirs(i, k), frac * step(i, k)));
        }
        for hw in [3usize, 4, 5, 6, 8, 10, 12] {
            stats(&format!("fixed hw {hw}"), &|i, _, p| refine_corner(&fimgs[i], p, hw));
        }
        for frac in [0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45] {
            stats(&format!("frac {frac}"), &|i, k, p| refine_corner(&fimgs[i], p, ((frac * step(i, k)).floor() as usize).clamp(2, 40)));
        }
    }
}
