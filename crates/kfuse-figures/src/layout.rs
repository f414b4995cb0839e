//! Panel figures with axes and colour bars, the layout of the lab figures: a title, then
//! panels in a grid, each with a caption, its image (scaled to [`PANEL_WIDTH`](crate::PANEL_WIDTH)),
//! pixel axes with ticks, and for depth panels a colour bar in metres beside it.
//!
//! The image and the colour bar's strip are copied into the figure's pixels first; plotters
//! then draws the text, axes and ticks over the margins. [`Figure::panels`] says where each
//! image and bar landed, so callers and tests can read pixels back.

use geometry::Image;
use plotters::prelude::*;

use crate::{
    FONT_NAME, FigureError, GAP, PANEL_WIDTH, TITLE_BAR, colormap, draw_err, register_font,
};

/// Height of a panel's caption bar, pixels.
pub const CAPTION_BAR: usize = 30;
/// Width of the axis area left of a panel image (tick labels and the axis name), pixels.
pub const AXIS_LEFT: usize = 64;
/// Height of the axis area below a panel image, pixels.
pub const AXIS_BOTTOM: usize = 46;
/// Width reserved right of every panel image for a colour bar and its labels, pixels.
pub const BAR_AREA: usize = 112;
/// Gap between a panel image and its colour bar, pixels.
const BAR_GAP: usize = 12;
/// Width of a colour bar's strip, pixels.
pub const BAR_WIDTH: usize = 20;
/// Length of a colour-bar tick, pixels.
const TICK: usize = 5;
/// Colour-bar ticks aimed at: 4 to 7 labels fit a bar 200 px or taller without crowding.
const BAR_TICKS: f64 = 6.0;

/// Pixel axes of a panel image: the names and the values at its left/right and top/bottom
/// edges (pixel centres at integers, so an image `w` wide spans `-0.5 .. w - 0.5`).
#[derive(Debug, Clone, PartialEq)]
pub struct Axes {
    /// Name of the horizontal axis ("u (px)").
    pub x_label: String,
    /// Name of the vertical axis ("v (px)"), growing downwards.
    pub y_label: String,
    /// Values at the left and right image edges.
    pub x_range: (f64, f64),
    /// Values at the top and bottom image edges.
    pub y_range: (f64, f64),
}

impl Axes {
    /// Pixel axes of an image `width × height` whose columns and rows are named `x`, `y`
    /// (e.g. "u", "v" for the colour camera).
    pub fn pixels(x: &str, y: &str, width: usize, height: usize) -> Self {
        Self {
            x_label: format!("{x} (px)"),
            y_label: format!("{y} (px)"),
            x_range: (-0.5, width as f64 - 0.5),
            y_range: (-0.5, height as f64 - 0.5),
        }
    }
}

/// A colour bar: the [`colormap`] from `lo` (bottom) to `hi` (top), metres.
#[derive(Debug, Clone, PartialEq)]
pub struct ColorBar {
    /// Value at the bottom, metres.
    pub lo: f32,
    /// Value at the top, metres.
    pub hi: f32,
    /// What the colours measure ("z (m)").
    pub label: String,
}

/// One panel of a figure.
pub struct FigPanel {
    /// Caption above the image.
    pub caption: String,
    /// The image (scaled to [`PANEL_WIDTH`](crate::PANEL_WIDTH) wide, nearest sampling).
    pub image: Image<[u8; 3]>,
    /// Pixel axes, or `None` for an image that carries its own (a plot).
    pub axes: Option<Axes>,
    /// The colour bar of a depth panel.
    pub colorbar: Option<ColorBar>,
}

impl FigPanel {
    /// A panel without axes or colour bar.
    pub fn plain(caption: impl Into<String>, image: Image<[u8; 3]>) -> Self {
        Self { caption: caption.into(), image, axes: None, colorbar: None }
    }

    /// A panel with pixel axes named `x`, `y` over the image's own size.
    pub fn with_pixel_axes(
        caption: impl Into<String>,
        image: Image<[u8; 3]>,
        x: &str,
        y: &str,
    ) -> Self {
        let axes = Axes::pixels(x, y, image.width(), image.height());
        Self { caption: caption.into(), image, axes: Some(axes), colorbar: None }
    }

    /// Axes spanning an image of `width × height` pixels whatever the panel image's own size
    /// (an image reduced by blocks keeps the axes of the full image).
    pub fn with_range(mut self, width: usize, height: usize) -> Self {
        if let Some(a) = &mut self.axes {
            a.x_range = (-0.5, width as f64 - 0.5);
            a.y_range = (-0.5, height as f64 - 0.5);
        }
        self
    }

    /// Adds a colour bar from `lo` to `hi` metres named `label`.
    pub fn bar(mut self, range: (f32, f32), label: impl Into<String>) -> Self {
        self.colorbar = Some(ColorBar { lo: range.0, hi: range.1, label: label.into() });
        self
    }
}

/// A rectangle of figure pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rect {
    /// Left column.
    pub x: usize,
    /// Top row.
    pub y: usize,
    /// Width.
    pub w: usize,
    /// Height.
    pub h: usize,
}

/// Where a colour bar was drawn.
#[derive(Debug, Clone, PartialEq)]
pub struct BarLayout {
    /// The colour strip (top = `hi`, bottom = `lo`).
    pub strip: Rect,
    /// Value at the bottom, metres.
    pub lo: f32,
    /// Value at the top, metres.
    pub hi: f32,
    /// The labelled ticks: value (metres) and its label.
    pub ticks: Vec<(f32, String)>,
}

impl BarLayout {
    /// The strip's row (figure pixels) that shows `value`.
    pub fn row_of(&self, value: f32) -> usize {
        let t = ((value - self.lo) / (self.hi - self.lo)).clamp(0.0, 1.0);
        let r = ((1.0 - t) * self.strip.h as f32).floor() as usize;
        self.strip.y + r.min(self.strip.h - 1)
    }
}

/// Where one panel was drawn.
#[derive(Debug, Clone, PartialEq)]
pub struct PanelLayout {
    /// The scaled image.
    pub image: Rect,
    /// Its colour bar.
    pub colorbar: Option<BarLayout>,
}

/// A drawn figure and where its panels are.
pub struct Figure {
    /// The pixels.
    pub image: Image<[u8; 3]>,
    /// One layout per panel, in order.
    pub panels: Vec<PanelLayout>,
}

/// `img` scaled to `width` columns by nearest sampling (aspect kept); exact for integer
/// factors and keeps depth edges crisp (no blending of foreground and background).
pub fn scale_to_width(img: &Image<[u8; 3]>, width: usize) -> Image<[u8; 3]> {
    let (w, h) = img.size();
    if w == 0 || h == 0 {
        return Image::filled(width, 1, [255, 255, 255]);
    }
    if w == width {
        return img.clone();
    }
    let height = (h * width).div_ceil(w).max(1);
    Image::from_fn(width, height, |x, y| {
        *img.get((x * w / width).min(w - 1), (y * h / height).min(h - 1))
    })
}

/// Round tick values in `[lo, hi]`: steps of 1, 2 or 5 × 10ⁿ giving about five ticks,
/// labelled in metres with as many decimals as the step needs.
pub fn bar_ticks(lo: f32, hi: f32) -> Vec<(f32, String)> {
    let (lo, hi) = (lo as f64, hi as f64);
    if !(hi > lo) || !lo.is_finite() || !hi.is_finite() {
        return Vec::new();
    }
    let raw = (hi - lo) / BAR_TICKS;
    let mag = 10f64.powf(raw.log10().floor());
    let step =
        [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * mag).find(|s| *s >= raw).unwrap_or(mag * 10.0);
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last)
        .map(|k| {
            let v = k as f64 * step;
            (v as f32, format!("{v:.decimals$} m"))
        })
        .collect()
}

/// Draws `panels` in a grid of up to `columns` per row under `title` (see the module docs).
pub fn draw_figure(
    title: &str,
    panels: &[FigPanel],
    columns: usize,
) -> Result<Figure, FigureError> {
    register_font();
    let columns = columns.clamp(1, panels.len().max(1));
    let scaled: Vec<Image<[u8; 3]>> =
        panels.iter().map(|p| scale_to_width(&p.image, PANEL_WIDTH)).collect();
    let cell_w = AXIS_LEFT + PANEL_WIDTH + BAR_AREA;
    let rows: Vec<usize> = (0..panels.len()).step_by(columns).collect();
    let row_h: Vec<usize> = rows
        .iter()
        .map(|&r0| {
            (r0..(r0 + columns).min(panels.len())).map(|i| scaled[i].height()).max().unwrap_or(0)
                + CAPTION_BAR
                + AXIS_BOTTOM
        })
        .collect();
    let w = columns * cell_w + (columns + 1) * GAP;
    let h = TITLE_BAR + row_h.iter().sum::<usize>() + (rows.len() + 1) * GAP;
    let mut buf = vec![255u8; w * h * 3];
    let mut layouts = Vec::with_capacity(panels.len());
    let put = |buf: &mut [u8], x: usize, y: usize, c: [u8; 3]| {
        let o = (y * w + x) * 3;
        buf[o..o + 3].copy_from_slice(&c);
    };
    let mut y0 = TITLE_BAR + GAP;
    for (r, &r0) in rows.iter().enumerate() {
        for i in r0..(r0 + columns).min(panels.len()) {
            let c = i - r0;
            let x0 = GAP + c * (cell_w + GAP);
            let img = &scaled[i];
            let rect =
                Rect { x: x0 + AXIS_LEFT, y: y0 + CAPTION_BAR, w: img.width(), h: img.height() };
            for y in 0..rect.h {
                for x in 0..rect.w {
                    put(&mut buf, rect.x + x, rect.y + y, *img.get(x, y));
                }
            }
            let colorbar = panels[i].colorbar.as_ref().map(|b| {
                let strip =
                    Rect { x: rect.x + rect.w + BAR_GAP, y: rect.y, w: BAR_WIDTH, h: rect.h };
                for y in 0..strip.h {
                    let c = colormap(1.0 - (y as f32 + 0.5) / strip.h as f32);
                    for x in 0..strip.w {
                        put(&mut buf, strip.x + x, strip.y + y, c);
                    }
                }
                BarLayout { strip, lo: b.lo, hi: b.hi, ticks: bar_ticks(b.lo, b.hi) }
            });
            layouts.push(PanelLayout { image: rect, colorbar });
        }
        y0 += row_h[r] + GAP;
    }
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
        let title_style = TextStyle::from((FONT_NAME, 26).into_font()).color(&BLACK);
        root.draw_text(title, &title_style, (GAP as i32, 12)).map_err(draw_err)?;
        let caption_style = TextStyle::from((FONT_NAME, 18).into_font()).color(&BLACK);
        let tick_style = TextStyle::from((FONT_NAME, 14).into_font()).color(&BLACK);
        for (p, l) in panels.iter().zip(&layouts) {
            let r = l.image;
            root.draw_text(
                &p.caption,
                &caption_style,
                ((r.x - AXIS_LEFT) as i32, (r.y - CAPTION_BAR) as i32 + 6),
            )
            .map_err(draw_err)?;
            if let Some(a) = &p.axes {
                let area = root.clone().shrink(
                    ((r.x - AXIS_LEFT) as u32, r.y as u32),
                    ((AXIS_LEFT + r.w) as u32, (r.h + AXIS_BOTTOM) as u32),
                );
                let mut chart = ChartBuilder::on(&area)
                    .x_label_area_size(AXIS_BOTTOM as u32)
                    .y_label_area_size(AXIS_LEFT as u32)
                    .build_cartesian_2d(a.x_range.0..a.x_range.1, a.y_range.1..a.y_range.0)
                    .map_err(draw_err)?;
                chart
                    .configure_mesh()
                    .disable_mesh()
                    .x_labels(6)
                    .y_labels(5)
                    .x_desc(a.x_label.as_str())
                    .y_desc(a.y_label.as_str())
                    .x_label_formatter(&|v| format!("{v:.0}"))
                    .y_label_formatter(&|v| format!("{v:.0}"))
                    .label_style((FONT_NAME, 13))
                    .axis_desc_style((FONT_NAME, 14))
                    .draw()
                    .map_err(draw_err)?;
            }
            if let (Some(b), Some(bl)) = (&p.colorbar, &l.colorbar) {
                let s = bl.strip;
                root.draw(&Rectangle::new(
                    [(s.x as i32 - 1, s.y as i32 - 1), ((s.x + s.w) as i32, (s.y + s.h) as i32)],
                    BLACK.stroke_width(1),
                ))
                .map_err(draw_err)?;
                let right = (s.x + s.w) as i32;
                for (v, label) in &bl.ticks {
                    let y = bl.row_of(*v) as i32;
                    root.draw(&PathElement::new(
                        vec![(right, y), (right + TICK as i32, y)],
                        BLACK.stroke_width(1),
                    ))
                    .map_err(draw_err)?;
                    root.draw_text(label, &tick_style, (right + TICK as i32 + 3, y - 7))
                        .map_err(draw_err)?;
                }
                // The bar's name under it.
                root.draw_text(&b.label, &tick_style, (s.x as i32 - 4, (s.y + s.h) as i32 + 8))
                    .map_err(draw_err)?;
            }
        }
        root.present().map_err(draw_err)?;
    }
    Ok(Figure { image: crate::rgb_image(buf, w, h)?, panels: layouts })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bar_ticks_are_round_metres_inside_the_range() {
        let t = bar_ticks(1.23, 2.87);
        let values: Vec<f32> = t.iter().map(|v| v.0).collect();
        assert_eq!(values, [1.5, 2.0, 2.5]);
        assert!(t.iter().all(|(v, _)| (1.23..=2.87).contains(v)));
        let labels: Vec<&str> = t.iter().map(|v| v.1.as_str()).collect();
        assert_eq!(labels, ["1.5 m", "2.0 m", "2.5 m"]);
        assert_eq!(
            bar_ticks(0.953, 1.013).iter().map(|v| v.1.as_str()).collect::<Vec<_>>(),
            ["0.96 m", "0.98 m", "1.00 m"]
        );
        assert!(bar_ticks(2.0, 2.0).is_empty());
    }

    #[test]
    fn depth_panel_has_a_colour_bar_matching_the_colour_map_and_axes() {
        // A 640-wide depth ramp 1 m (left) → 3 m (right) with its bar.
        let (lo, hi) = (1.0f32, 3.0f32);
        let ramp = Image::from_fn(PANEL_WIDTH, 200, |x, _| colormap(x as f32 / 639.0));
        let fig = draw_figure(
            "Task 3: test",
            &[FigPanel::with_pixel_axes("depth", ramp.clone(), "u", "v").bar((lo, hi), "z (m)")],
            1,
        )
        .unwrap();
        let l = &fig.panels[0];
        // The image is copied unscaled into its rectangle.
        assert_eq!((l.image.w, l.image.h), (PANEL_WIDTH, 200));
        for x in [0, 100, 639] {
            assert_eq!(fig.image.get(l.image.x + x, l.image.y + 50), ramp.get(x, 50));
        }
        let bar = l.colorbar.as_ref().unwrap();
        assert_eq!((bar.lo, bar.hi), (lo, hi));
        // Each tick's row of the strip shows the colour map at the tick's value (within the
        // colour change of one row, ≤ 4 levels per channel at 200 rows).
        assert_eq!(
            bar.ticks.iter().map(|t| t.1.as_str()).collect::<Vec<_>>(),
            ["1.0 m", "1.5 m", "2.0 m", "2.5 m", "3.0 m"]
        );
        let xc = bar.strip.x + bar.strip.w / 2;
        for (v, _) in &bar.ticks {
            let got = fig.image.get(xc, bar.row_of(*v));
            let want = colormap((v - lo) / (hi - lo));
            let diff = (0..3).map(|k| (got[k] as i32 - want[k] as i32).abs()).max().unwrap();
            assert!(diff <= 4, "bar at {v} m: {got:?}, colour map {want:?}");
        }
        // Labels were drawn right of the bar at the tick rows: dark pixels there.
        for (v, _) in &bar.ticks {
            let y = bar.row_of(*v);
            let dark = (bar.strip.x + bar.strip.w + 8..bar.strip.x + bar.strip.w + 60)
                .flat_map(|x| (y.saturating_sub(6)..y + 6).map(move |y| (x, y)))
                .filter(|&(x, y)| fig.image.get(x, y)[0] < 100)
                .count();
            assert!(dark > 10, "no label at {v} m");
        }
        // Axes: tick labels left of and below the image.
        let left = (l.image.x - AXIS_LEFT..l.image.x - 2)
            .flat_map(|x| (l.image.y..l.image.y + l.image.h).map(move |y| (x, y)))
            .filter(|&(x, y)| fig.image.get(x, y)[0] < 100)
            .count();
        let below = (l.image.x..l.image.x + l.image.w)
            .flat_map(|x| {
                (l.image.y + l.image.h + 2..l.image.y + l.image.h + AXIS_BOTTOM)
                    .map(move |y| (x, y))
            })
            .filter(|&(x, y)| fig.image.get(x, y)[0] < 100)
            .count();
        assert!(left > 100 && below > 100, "axes missing: {left} / {below} dark pixels");
    }

    #[test]
    fn panels_without_a_bar_have_none() {
        let fig = draw_figure("t", &[FigPanel::plain("c", Image::filled(64, 48, [9u8, 9, 9]))], 1)
            .unwrap();
        assert!(fig.panels[0].colorbar.is_none());
        // Scaled 10×: 640 × 480 pixels of the image.
        let r = fig.panels[0].image;
        assert_eq!((r.w, r.h), (640, 480));
        assert_eq!(*fig.image.get(r.x + 320, r.y + 240), [9, 9, 9]);
    }
}
