//! The report figures of `kfuse calibrate --depth`: residual against distance, the residual
//! map over the depth image (after offset + scale alone, whose structure chose the model's
//! order, and after the model), and per-view RMS bars.

use std::path::Path;

use anyhow::Result;
use calib::depth::{DepthFit, Sample};
use geometry::Image;
use geometry::depth_correction::{DepthCorrection, DepthTerm};
use kfuse_figures::{FONT_NAME, Panel, colormap, draw_panels, register_font};
use kfuse_io::atomic::StagedDir;
use kfuse_io::images::write_color_png;
use plotters::prelude::*;

/// The colour range of the residual maps: this percentile of |residual| (a few extreme
/// pixels must not wash the map out).
const RANGE_PERCENTILE: usize = 98;
/// Points drawn per series of the scatter plot at most (every n-th sample beyond).
const MAX_SCATTER: usize = 20_000;

/// Writes `depth_residual_vs_distance.png`, `depth_residual_map.png`, `depth_views.png`.
pub fn write(dir: &StagedDir, fit: &DepthFit) -> Result<()> {
    register_font();
    vs_distance(&dir.join("depth_residual_vs_distance.png"), fit)?;
    residual_map(&dir.join("depth_residual_map.png"), fit)?;
    view_bars(&dir.join("depth_views.png"), fit)?;
    Ok(())
}

/// The model made of `terms` (for residuals of the base fit).
fn model(fit: &DepthFit, terms: &[DepthTerm]) -> DepthCorrection {
    DepthCorrection { terms: terms.to_vec(), fit: None, ..fit.correction.clone() }
}

/// `z_measured − model(z_plane)` of one sample, metres.
fn residual(m: &DepthCorrection, s: &Sample) -> f64 {
    s.z_measured - m.distort(f64::from(s.u), f64::from(s.v), s.z_plane)
}

fn used(fit: &DepthFit) -> impl Iterator<Item = &Sample> {
    fit.views
        .iter()
        .zip(&fit.samples)
        .filter(|(v, _)| v.rejected.is_none())
        .flat_map(|(_, s)| s.iter())
}

fn save(path: &Path, buf: Vec<u8>, w: usize, h: usize) -> Result<()> {
    let img = kfuse_figures::rgb_image(buf, w, h)?;
    write_color_png(path, &img)?;
    Ok(())
}

fn vs_distance(path: &Path, fit: &DepthFit) -> Result<()> {
    let (w, h) = (900usize, 520usize);
    let none = model(fit, &[]);
    let n = used(fit).count();
    let step = n.div_ceil(MAX_SCATTER).max(1);
    let before: Vec<(f64, f64)> =
        used(fit).step_by(step).map(|s| (s.z_plane, 1e3 * residual(&none, s))).collect();
    let after: Vec<(f64, f64)> =
        used(fit).step_by(step).map(|s| (s.z_plane, 1e3 * residual(&fit.correction, s))).collect();
    let all = before.iter().chain(&after);
    let (zlo, zhi) =
        all.clone().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (rlo, rhi) = all.fold((0.0f64, 0.0f64), |(a, b), p| (a.min(p.1), b.max(p.1)));
    let mut buf = vec![255u8; w * h * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
        let mut chart = ChartBuilder::on(&root)
            .caption("Depth error against distance (red: raw, blue: corrected)", (FONT_NAME, 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d((zlo - 0.05)..(zhi + 0.05), (rlo - 2.0)..(rhi + 2.0))?;
        chart
            .configure_mesh()
            .x_desc("board z along the pixel's ray (m)")
            .y_desc("measured − true z (mm)")
            .label_style((FONT_NAME, 13))
            .draw()?;
        let red = RGBColor(220, 60, 40).mix(0.25);
        let blue = RGBColor(30, 80, 220).mix(0.35);
        chart.draw_series(before.iter().map(|&p| Circle::new(p, 1, red.filled())))?;
        chart.draw_series(after.iter().map(|&p| Circle::new(p, 1, blue.filled())))?;
        root.present()?;
    }
    save(path, buf, w, h)
}

/// Mean residual per pixel over the used views (NaN where no view has the pixel).
fn mean_map(fit: &DepthFit, m: &DepthCorrection) -> Image<f32> {
    let (w, h) = (fit.correction.width, fit.correction.height);
    let mut sum = vec![0.0f64; w * h];
    let mut count = vec![0u32; w * h];
    for s in used(fit) {
        let i = s.v as usize * w + s.u as usize;
        sum[i] += residual(m, s);
        count[i] += 1;
    }
    Image::from_fn(w, h, |x, y| {
        let i = y * w + x;
        if count[i] == 0 { f32::NAN } else { (1e3 * sum[i] / f64::from(count[i])) as f32 }
    })
}

fn colour(map: &Image<f32>, lo: f32, hi: f32) -> Image<[u8; 3]> {
    map.map(|&v| {
        if v.is_finite() {
            colormap(((v - lo) / (hi - lo).max(1e-6)).clamp(0.0, 1.0))
        } else {
            [255; 3]
        }
    })
}

fn residual_map(path: &Path, fit: &DepthFit) -> Result<()> {
    let base = mean_map(fit, &model(fit, &fit.base));
    let after = mean_map(fit, &fit.correction);
    // One symmetric range for both panels (the base map's robust extent), so that what the
    // model removed shows as colour that went away.
    let mut mags: Vec<f32> =
        base.data().iter().filter(|v| v.is_finite()).map(|v| v.abs()).collect();
    mags.sort_by(f32::total_cmp);
    let r = mags.get(mags.len() * RANGE_PERCENTILE / 100).copied().unwrap_or(1.0).max(0.1);
    let panels = [
        Panel::new(
            format!("after offset + scale only (dark {:+.1} … yellow {:+.1} mm)", -r, r),
            colour(&base, -r, r),
        ),
        Panel::new("after the fitted model (same colours)", colour(&after, -r, r)),
    ];
    let img =
        draw_panels("Depth residual over the depth image (mean over the board views)", &panels, 2)?;
    write_color_png(path, &img)?;
    Ok(())
}

fn view_bars(path: &Path, fit: &DepthFit) -> Result<()> {
    let (w, h) = (900usize, 420usize);
    let n = fit.views.len();
    let ymax = fit.views.iter().map(|v| v.rms_before_m).fold(1e-3, f64::max) * 1e3 * 1.15;
    let mut buf = vec![255u8; w * h * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "Per-view RMS depth error (red: raw, blue: corrected, grey: rejected)",
                (FONT_NAME, 18),
            )
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(55)
            .build_cartesian_2d(0f64..n.max(1) as f64, 0f64..ymax)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_desc("view index")
            .y_desc("RMS (mm)")
            .label_style((FONT_NAME, 13))
            .draw()?;
        let grey = RGBColor(160, 160, 160);
        chart.draw_series(fit.views.iter().enumerate().map(|(i, v)| {
            let c = if v.rejected.is_some() { grey } else { RGBColor(220, 60, 40) };
            Rectangle::new(
                [(i as f64 + 0.1, 0.0), (i as f64 + 0.48, 1e3 * v.rms_before_m)],
                c.filled(),
            )
        }))?;
        chart.draw_series(fit.views.iter().enumerate().map(|(i, v)| {
            let c = if v.rejected.is_some() { grey } else { RGBColor(30, 80, 220) };
            Rectangle::new(
                [(i as f64 + 0.52, 0.0), (i as f64 + 0.9, 1e3 * v.rms_after_m)],
                c.filled(),
            )
        }))?;
        root.present()?;
    }
    save(path, buf, w, h)
}
