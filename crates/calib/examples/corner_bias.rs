//! Diagnostic: detected corners vs the exact projections of `synthetic-calib/ground_truth.json`
//! per camera (mean offset = bias, RMS, mean |e|), and the same statistics when every corner is
//! refined again with different windows. `cargo run -p calib --example corner_bias`.

use std::path::PathBuf;

use calib::detect::{
    detect_views, fit_junction, fit_junction_with_std, refine_corner, rotate_180, to_f32,
};
use calib::{Board, ViewCorners};
use nalgebra::Vector2;

fn main() {
    let dir = std::env::var("KFUSE_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|_| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"))
        .join("synthetic-calib");
    let gt: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("ground_truth.json")).expect("gt"))
            .expect("json");
    let board = Board::new(7, 5, 0.04).expect("board");
    // Cost of the final estimator: one image per camera, detect() with each refinement.
    for cam in ["ir", "color"] {
        let img =
            to_f32(&calib::io::read_gray(&dir.join(format!("{cam}/{cam}_01.png"))).expect("img"));
        for refinement in
            [calib::detect::Refinement::CornerSubPix, calib::detect::Refinement::JunctionFit]
        {
            let params = calib::detect::DetectorParams {
                refinement,
                ..calib::detect::DetectorParams::for_image(img.width(), img.height())
            };
            let t = std::time::Instant::now();
            for _ in 0..10 {
                std::hint::black_box(calib::detect::detect(&img, &board, &params));
            }
            println!(
                "{cam} detect with {refinement:?}: {:.1} ms",
                t.elapsed().as_secs_f64() * 100.0
            );
        }
    }
    for cam in ["ir", "color"] {
        let imgs: Vec<_> = (1..=15)
            .map(|i| {
                calib::io::read_gray(&dir.join(format!("{cam}/{cam}_{i:02}.png"))).expect("img")
            })
            .collect();
        let named: Vec<(String, &geometry::Image<u8>)> =
            imgs.iter().enumerate().map(|(i, m)| (format!("{i}"), m)).collect();
        let (views, _) = detect_views(&named, &board);
        let truth: Vec<Vec<Vector2<f64>>> = (0..15)
            .map(|i| {
                gt["views"][i][cam]["corners_px"]
                    .as_array()
                    .expect("list")
                    .iter()
                    .map(|p| Vector2::new(p[0].as_f64().expect("x"), p[1].as_f64().expect("y")))
                    .collect()
            })
            .collect();
        // Align labelling with the truth.
        let views: Vec<ViewCorners> = views
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let e = |v: &ViewCorners| {
                    v.corners.iter().map(|c| (c.px - truth[i][c.id]).norm()).sum::<f64>()
                };
                let r = rotate_180(v, &board);
                if e(v) <= e(&r) { v.clone() } else { r }
            })
            .collect();
        let stats =
            |name: &str, pts: &dyn Fn(usize, usize, Vector2<f64>) -> Option<Vector2<f64>>| {
                let (mut s, mut s2, mut sa, mut n, mut fail) = (Vector2::zeros(), 0.0, 0.0, 0, 0);
                let mut per_view = Vec::new();
                for (i, v) in views.iter().enumerate() {
                    let mut vs = Vector2::zeros();
                    for c in &v.corners {
                        let Some(p) = pts(i, c.id, c.px) else {
                            fail += 1;
                            continue;
                        };
                        let e = p - truth[i][c.id];
                        s += e;
                        vs += e;
                        s2 += e.norm_squared();
                        sa += e.norm();
                        n += 1;
                    }
                    per_view.push(format!(
                        "({:+.3},{:+.3})",
                        vs.x / v.corners.len() as f64,
                        vs.y / v.corners.len() as f64
                    ));
                }
                let nf = n as f64;
                println!(
                    "{cam} {name:28}: n {n} fail {fail} mean|e| {:.4} rms {:.4} bias ({:+.4}, {:+.4})",
                    sa / nf,
                    (s2 / nf).sqrt(),
                    s.x / nf,
                    s.y / nf
                );
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
            let a =
                if x < 6 { truth[i][k + 1] - truth[i][k] } else { truth[i][k] - truth[i][k - 1] };
            let b =
                if y < 4 { truth[i][k + 7] - truth[i][k] } else { truth[i][k] - truth[i][k - 7] };
            [a, b]
        };
        {
            let (mut se, mut ss, mut n) = (0.0, 0.0, 0.0);
            for (i, v) in views.iter().enumerate() {
                for c in &v.corners {
                    if let Some((p, sd)) =
                        fit_junction_with_std(&fimgs[i], c.px, dirs(i, c.id), 0.45 * step(i, c.id))
                    {
                        se += (p - truth[i][c.id]).norm_squared() / 2.0;
                        ss += sd * sd;
                        n += 1.0;
                    }
                }
            }
            let mut worst = Vec::new();
            for (i, v) in views.iter().enumerate() {
                for c in &v.corners {
                    if let Some((p, sd)) =
                        fit_junction_with_std(&fimgs[i], c.px, dirs(i, c.id), 0.45 * step(i, c.id))
                    {
                        let e = p - truth[i][c.id];
                        worst.push((e.norm(), i + 1, c.id, e, sd, step(i, c.id), truth[i][c.id]));
                    }
                }
            }
            // Renderer aliasing check: boards whose grid lines run within 4° of the pixel axes
            // (supersampling quantises such edges) against the others.
            let aligned = |i: usize| {
                let d = truth[i][1] - truth[i][0];
                let a = d.y.atan2(d.x).to_degrees().rem_euclid(90.0);
                a.min(90.0 - a) < 4.0
            };
            for flag in [true, false] {
                let e: Vec<f64> =
                    worst.iter().filter(|w| aligned(w.1 - 1) == flag).map(|w| w.0).collect();
                let views: Vec<usize> =
                    (0..15).filter(|&i| aligned(i) == flag).map(|i| i + 1).collect();
                println!(
                    "   grid within 4° of the pixel axes: {flag:5}, views {views:?}: mean |e| {:.4} px over {}",
                    e.iter().sum::<f64>() / e.len().max(1) as f64,
                    e.len()
                );
            }
            worst.sort_by(|a, b| b.0.total_cmp(&a.0));
            for w in worst.iter().take(12) {
                println!(
                    "   view {:2} id {:2} err {:.4} ({:+.3},{:+.3}) σ {:.4} step {:.1} at ({:.0},{:.0})",
                    w.1, w.2, w.0, w.3.x, w.3.y, w.4, w.5, w.6.x, w.6.y
                );
            }
            println!(
                "{cam} junction fit: actual per-axis rms {:.4} px, predicted (largest axis) rms {:.4} px",
                (se / n).sqrt(),
                (ss / n).sqrt()
            );
        }
        for frac in [0.2, 0.3, 0.35, 0.4, 0.45, 0.5] {
            stats(&format!("fit frac {frac}"), &|i, k, p| {
                fit_junction(&fimgs[i], p, dirs(i, k), frac * step(i, k))
            });
        }
        for hw in [3usize, 4, 5, 6, 8, 10, 12] {
            stats(&format!("fixed hw {hw}"), &|i, _, p| refine_corner(&fimgs[i], p, hw));
        }
        for frac in [0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45] {
            stats(&format!("frac {frac}"), &|i, k, p| {
                refine_corner(&fimgs[i], p, ((frac * step(i, k)).floor() as usize).clamp(2, 40))
            });
        }
    }
}
