//! PNG figures titled like the lab's ("Task 3: ..."), drawn with plotters into a memory
//! buffer and written atomically through `kfuse_io::images`.
//!
//! Text uses the bundled DejaVu Sans (`assets/fonts/`), registered with plotters' `ab_glyph`
//! backend, so figures render the same on machines without fontconfig.

use std::path::Path;
use std::sync::Once;

use anyhow::{Context, Result};
use geometry::{Image, Mesh, PointCloud};
use kfuse_io::images::write_color_png;
use nalgebra::{Matrix3, Rotation3, Vector3};
use plotters::prelude::*;

/// The lab's figure titles, one per fusion stage.
pub mod titles {
    /// H1.
    pub const TASK1: &str = "Task 1: Point cloud in global (x,y,z) space";
    /// H2.
    pub const TASK2: &str = "Task 2: Point cloud projected to the colour camera";
    /// H3.
    pub const TASK3: &str = "Task 3: Resampled depth (nearest / Delaunay-linear)";
    /// H4.
    pub const TASK4: &str = "Task 4: Textured mesh";
    /// H5.
    pub const TASK5: &str = "Task 5: Mesh after edge-face removal";
    /// H6.
    pub const TASK6: &str = "Task 6: Colour on the depth grid";
    /// H7.
    pub const TASK7: &str = "Task 7: Z-buffered depth";
    /// H8.
    pub const TASK8: &str = "Task 8: Disocclusion holes and plane filling";
}

const FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");
const FONT_NAME: &str = "sans-serif";
static REGISTER: Once = Once::new();

fn register_font() {
    REGISTER.call_once(|| {
        // The bundled file is a valid TrueType font; a failure here would only lose text.
        let _ = plotters::style::register_font(FONT_NAME, FontStyle::Normal, FONT);
    });
}

/// Width of one image panel in a panel figure, pixels (the panel is scaled to it).
pub const PANEL_WIDTH: usize = 640;
/// Height of the figure's title bar, pixels.
const TITLE_BAR: usize = 48;
/// Height of a panel's caption bar, pixels.
const CAPTION_BAR: usize = 30;
/// Gap between panels, pixels.
const GAP: usize = 12;
/// Size of the scatter-plot figures, pixels.
const PLOT_SIZE: (u32, u32) = (1000, 760);
/// Points drawn in a scatter plot at most: more only darkens the plot and slows it down.
pub const MAX_SCATTER_POINTS: usize = 60_000;

/// One image of a panel figure with its caption.
pub struct Panel {
    /// Caption above the image.
    pub caption: String,
    /// The image (any size: scaled to the panel width).
    pub image: Image<[u8; 3]>,
}

impl Panel {
    /// A panel from a caption and an image.
    pub fn new(caption: impl Into<String>, image: Image<[u8; 3]>) -> Self {
        Self { caption: caption.into(), image }
    }
}

fn save_buffer(path: &Path, buf: Vec<u8>, w: usize, h: usize) -> Result<()> {
    let pixels = buf.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let img = Image::from_vec(w, h, pixels)?;
    write_color_png(path, &img).with_context(|| format!("writing figure {}", path.display()))
}

fn draw_err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow::anyhow!("drawing a figure: {e:?}")
}

/// Colour map for depth (a perceptually ordered blue → green → yellow ramp, viridis-like):
/// `t` in 0..1.
pub fn colormap(t: f32) -> [u8; 3] {
    // Viridis anchors at t = 0, .25, .5, .75, 1.
    const STOPS: [[f32; 3]; 5] = [
        [68.0, 1.0, 84.0],
        [59.0, 82.0, 139.0],
        [33.0, 145.0, 140.0],
        [94.0, 201.0, 98.0],
        [253.0, 231.0, 37.0],
    ];
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    let x = t * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f32;
    let a = STOPS[i];
    let b = STOPS[i + 1];
    [0, 1, 2].map(|k| (a[k] + (b[k] - a[k]) * f).round() as u8)
}

/// The 2nd and 98th percentiles of the finite values (robust colour range), or `None`.
pub fn robust_range(values: impl Iterator<Item = f32>) -> Option<(f32, f32)> {
    let mut v: Vec<f32> = values.filter(|d| d.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f32::total_cmp);
    let lo = v[v.len() * 2 / 100];
    let hi = v[(v.len() * 98 / 100).min(v.len() - 1)];
    Some(if hi > lo { (lo, hi) } else { (lo, lo + 1e-3) })
}

/// Depth (metres) as colours: near = dark blue, far = yellow; `NaN` = black.
pub fn depth_colors(depth: &Image<f32>, range: Option<(f32, f32)>) -> Image<[u8; 3]> {
    let (lo, hi) =
        range.or_else(|| robust_range(depth.data().iter().copied())).unwrap_or((0.0, 1.0));
    depth.map(|&d| if d.is_finite() { colormap((d - lo) / (hi - lo)) } else { [0, 0, 0] })
}

/// Depth reduced by `factor` in each direction keeping the nearest valid sample of each
/// block: sparse depth (a z-buffer) stays visible when a figure shrinks it.
pub fn downsample_depth_min(depth: &Image<f32>, factor: usize) -> Image<f32> {
    let f = factor.max(1);
    let (w, h) = depth.size();
    Image::from_fn(w.div_ceil(f), h.div_ceil(f), |x, y| {
        let mut best = f32::NAN;
        for yy in y * f..((y + 1) * f).min(h) {
            for xx in x * f..((x + 1) * f).min(w) {
                let d = *depth.get(xx, yy);
                if d.is_finite() && (best.is_nan() || d < best) {
                    best = d;
                }
            }
        }
        best
    })
}

/// A mask as an image: `true` = red over dark grey.
pub fn mask_colors(mask: &Image<bool>) -> Image<[u8; 3]> {
    mask.map(|&m| if m { [230, 40, 40] } else { [40, 40, 40] })
}

/// Depth blended over colour (`alpha` = weight of the depth colours where depth is valid).
pub fn depth_overlay(color: &Image<[u8; 3]>, depth: &Image<f32>, alpha: f32) -> Image<[u8; 3]> {
    let dc = depth_colors(depth, None);
    let (w, h) = color.size();
    Image::from_fn(w, h, |x, y| {
        let c = color.get(x, y);
        // Depth grids may differ in size from the colour image: sample the nearest pixel.
        let dx = (x * depth.width() / w).min(depth.width().saturating_sub(1));
        let dy = (y * depth.height() / h).min(depth.height().saturating_sub(1));
        if depth.get(dx, dy).is_finite() {
            let d = dc.get(dx, dy);
            [0, 1, 2].map(|k| (c[k] as f32 * (1.0 - alpha) + d[k] as f32 * alpha).round() as u8)
        } else {
            *c
        }
    })
}

fn scaled(img: &Image<[u8; 3]>, width: usize) -> Image<[u8; 3]> {
    let (w, h) = img.size();
    if w == 0 || h == 0 {
        return Image::filled(width, 1, [255, 255, 255]);
    }
    let height = (h * width).div_ceil(w).max(1);
    // Area-free nearest sampling: exact for the integer downscales used here, and it keeps
    // depth edges crisp (no blending of foreground and background).
    Image::from_fn(width, height, |x, y| {
        *img.get((x * w / width).min(w - 1), (y * h / height).min(h - 1))
    })
}

/// Saves image panels side by side (up to `columns` per row) under a title.
pub fn save_panels(path: &Path, title: &str, panels: &[Panel], columns: usize) -> Result<()> {
    register_font();
    let columns = columns.clamp(1, panels.len().max(1));
    let scaled: Vec<Image<[u8; 3]>> =
        panels.iter().map(|p| scaled(&p.image, PANEL_WIDTH)).collect();
    let rows: Vec<&[Image<[u8; 3]>]> = scaled.chunks(columns).collect();
    let row_heights: Vec<usize> = rows
        .iter()
        .map(|r| r.iter().map(|i| i.height()).max().unwrap_or(0) + CAPTION_BAR)
        .collect();
    let w = columns * PANEL_WIDTH + (columns + 1) * GAP;
    let h = TITLE_BAR + row_heights.iter().sum::<usize>() + (rows.len() + 1) * GAP;
    let mut buf = vec![255u8; w * h * 3];
    let mut origins = Vec::new();
    let mut y0 = TITLE_BAR + GAP;
    for (r, row) in rows.iter().enumerate() {
        for (c, img) in row.iter().enumerate() {
            let x0 = GAP + c * (PANEL_WIDTH + GAP);
            origins.push((x0, y0));
            for y in 0..img.height() {
                for x in 0..img.width() {
                    let o = ((y0 + CAPTION_BAR + y) * w + x0 + x) * 3;
                    buf[o..o + 3].copy_from_slice(img.get(x, y));
                }
            }
        }
        y0 += row_heights[r] + GAP;
    }
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
        let title_style = TextStyle::from((FONT_NAME, 26).into_font()).color(&BLACK);
        root.draw_text(title, &title_style, (GAP as i32, 12)).map_err(draw_err)?;
        let caption_style = TextStyle::from((FONT_NAME, 18).into_font()).color(&BLACK);
        for (p, (x0, y0)) in panels.iter().zip(&origins) {
            root.draw_text(&p.caption, &caption_style, (*x0 as i32, *y0 as i32 + 6))
                .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }
    save_buffer(path, buf, w, h)
}

/// Every `step`-th index so that at most `max` are kept.
fn subsample(n: usize, max: usize) -> impl Iterator<Item = usize> {
    let step = n.div_ceil(max.max(1)).max(1);
    (0..n).step_by(step)
}

/// 3D scatter of a coloured point cloud (subsampled to [`MAX_SCATTER_POINTS`]), axes in
/// metres. Points are drawn with y pointing up (the camera's y is down, so −y is plotted) and
/// depth z going into the picture.
pub fn save_cloud_3d(path: &Path, title: &str, cloud: &PointCloud) -> Result<()> {
    register_font();
    let (w, h) = PLOT_SIZE;
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let idx: Vec<usize> = subsample(cloud.len(), MAX_SCATTER_POINTS)
        .filter(|&i| cloud.points[i].iter().all(|v| v.is_finite()))
        .collect();
    let bound = |k: usize| -> (f64, f64) {
        let vals = idx.iter().map(|&i| cloud.points[i][k] as f64);
        let (lo, hi) =
            vals.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
        if lo.is_finite() && hi > lo { (lo, hi) } else { (0.0, 1.0) }
    };
    let (x, y, z) = (bound(0), bound(1), bound(2));
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, (FONT_NAME, 26))
            .margin(20)
            .build_cartesian_3d(x.0..x.1, -y.1..-y.0, z.0..z.1)
            .map_err(draw_err)?;
        chart.with_projection(|mut p| {
            p.yaw = 0.55;
            p.pitch = 0.35;
            p.scale = 0.85;
            p.into_matrix()
        });
        chart
            .configure_axes()
            .label_style((FONT_NAME, 14))
            .x_formatter(&|v| format!("x {v:.2}"))
            .y_formatter(&|v| format!("-y {v:.2}"))
            .z_formatter(&|v| format!("z {v:.2} m"))
            .draw()
            .map_err(draw_err)?;
        let colored = cloud.has_colors();
        chart
            .draw_series(idx.iter().map(|&i| {
                let p = cloud.points[i];
                let c = if colored {
                    cloud.colors[i]
                } else {
                    colormap((p[2] - z.0 as f32) / (z.1 - z.0) as f32)
                };
                Circle::new(
                    (p[0] as f64, -(p[1] as f64), p[2] as f64),
                    1,
                    RGBColor(c[0], c[1], c[2]).filled(),
                )
            }))
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    save_buffer(path, buf, w as usize, h as usize)
}

/// Scatter of projected samples `(u, v, z)` over the `width × height` image frame (v down),
/// coloured by `z` (metres) with a colour-bar label.
pub fn save_projected_scatter(
    path: &Path,
    title: &str,
    samples: &[[f32; 3]],
    width: usize,
    height: usize,
) -> Result<()> {
    register_font();
    let (w, h) = PLOT_SIZE;
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let idx: Vec<usize> = subsample(samples.len(), MAX_SCATTER_POINTS).collect();
    let (lo, hi) = robust_range(idx.iter().map(|&i| samples[i][2])).unwrap_or((0.0, 1.0));
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, (FONT_NAME, 26))
            .margin(20)
            .x_label_area_size(40)
            .y_label_area_size(60)
            // v grows downwards as in the image.
            .build_cartesian_2d(-0.5f64..width as f64 - 0.5, height as f64 - 0.5..-0.5f64)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("u (px)")
            .y_desc("v (px)")
            .label_style((FONT_NAME, 14))
            .axis_desc_style((FONT_NAME, 16))
            .draw()
            .map_err(draw_err)?;
        chart
            .draw_series(idx.iter().map(|&i| {
                let s = samples[i];
                let c = colormap((s[2] - lo) / (hi - lo));
                Circle::new((s[0] as f64, s[1] as f64), 1, RGBColor(c[0], c[1], c[2]).filled())
            }))
            .map_err(draw_err)?;
        let legend = TextStyle::from((FONT_NAME, 15).into_font()).color(&BLACK);
        root.draw_text(
            &format!(
                "colour = z: dark blue {lo:.2} m → yellow {hi:.2} m ({} of {} samples shown)",
                idx.len(),
                samples.len()
            ),
            &legend,
            (80, h as i32 - 22),
        )
        .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    save_buffer(path, buf, w as usize, h as usize)
}

/// Direction of the virtual light for mesh renders (camera frame, towards the viewer, from
/// the upper left).
const LIGHT: [f64; 3] = [-0.4, -0.5, -0.77];

/// Renders a mesh (vertex colours, Lambert-shaded by face normal) seen from a virtual camera
/// that looks at the mesh's centre from the original camera's side, turned by `yaw_deg`
/// about the vertical and `pitch_deg` about the horizontal axis; z-buffered.
pub fn render_mesh(
    mesh: &Mesh,
    width: usize,
    height: usize,
    yaw_deg: f64,
    pitch_deg: f64,
) -> Image<[u8; 3]> {
    let mut img = Image::filled(width, height, [255u8, 255, 255]);
    let finite: Vec<Vector3<f64>> = mesh
        .vertices
        .iter()
        .filter(|v| v.iter().all(|c| c.is_finite()))
        .map(|v| Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64))
        .collect();
    if finite.is_empty() || mesh.faces.is_empty() {
        return img;
    }
    let centre = finite.iter().fold(Vector3::zeros(), |a, v| a + v) / finite.len() as f64;
    // Frame the bulk of the mesh (90 % of the vertices), not its farthest outlier.
    let mut dists: Vec<f64> = finite.iter().map(|v| (v - centre).norm()).collect();
    dists.sort_by(f64::total_cmp);
    let radius = dists[dists.len() * 9 / 10].max(1e-6);
    let rot: Matrix3<f64> =
        *(Rotation3::from_axis_angle(&Vector3::x_axis(), pitch_deg.to_radians())
            * Rotation3::from_axis_angle(&Vector3::y_axis(), yaw_deg.to_radians()))
        .matrix();
    // Virtual pinhole at 3 radii from the centre; the radius spans 55 % of the smaller side.
    let dist = 3.0 * radius;
    let f = 0.55 * width.min(height) as f64 * dist / radius;
    let view = |v: [f32; 3]| -> Option<(f64, f64, f64)> {
        let p = rot * (Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64) - centre)
            + Vector3::new(0.0, 0.0, dist);
        if p.z.is_nan() || p.z <= 1e-9 {
            return None;
        }
        Some((f * p.x / p.z + width as f64 / 2.0, f * p.y / p.z + height as f64 / 2.0, p.z))
    };
    let light = Vector3::from(LIGHT).normalize();
    let mut zbuf = vec![f64::INFINITY; width * height];
    for face in &mesh.faces {
        let vs = face.map(|i| mesh.vertices[i as usize]);
        let (Some(a), Some(b), Some(c)) = (view(vs[0]), view(vs[1]), view(vs[2])) else { continue };
        let pa = Vector3::new(vs[0][0] as f64, vs[0][1] as f64, vs[0][2] as f64);
        let pb = Vector3::new(vs[1][0] as f64, vs[1][1] as f64, vs[1][2] as f64);
        let pc = Vector3::new(vs[2][0] as f64, vs[2][1] as f64, vs[2][2] as f64);
        let n = rot * (pb - pa).cross(&(pc - pa));
        let shade =
            if n.norm() > 0.0 { 0.35 + 0.65 * n.normalize().dot(&light).abs() } else { 1.0 };
        let color = |k: usize| -> [f64; 3] {
            match mesh.colors.get(face[k] as usize) {
                Some(c) => [c[0] as f64, c[1] as f64, c[2] as f64],
                None => [180.0, 180.0, 180.0],
            }
        };
        let (ca, cb, cc) = (color(0), color(1), color(2));
        let plot = |img: &mut Image<[u8; 3]>,
                    zbuf: &mut [f64],
                    x: usize,
                    y: usize,
                    z: f64,
                    w: [f64; 3]| {
            let k = y * width + x;
            if z < zbuf[k] {
                zbuf[k] = z;
                *img.get_mut(x, y) = [0, 1, 2].map(|i| {
                    ((w[0] * ca[i] + w[1] * cb[i] + w[2] * cc[i]) * shade).round().clamp(0.0, 255.0)
                        as u8
                });
            }
        };
        let area = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
        if area.abs() < 1e-12 {
            continue;
        }
        let x0 = a.0.min(b.0).min(c.0).floor().max(0.0) as usize;
        let x1 = (a.0.max(b.0).max(c.0).ceil() as i64).min(width as i64 - 1);
        let y0 = a.1.min(b.1).min(c.1).floor().max(0.0) as usize;
        let y1 = (a.1.max(b.1).max(c.1).ceil() as i64).min(height as i64 - 1);
        if x1 < 0 || y1 < 0 {
            continue;
        }
        let mut covered = false;
        for y in y0..=y1 as usize {
            for x in x0..=x1 as usize {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                let w0 = ((b.0 - px) * (c.1 - py) - (b.1 - py) * (c.0 - px)) / area;
                let w1 = ((c.0 - px) * (a.1 - py) - (c.1 - py) * (a.0 - px)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                covered = true;
                let z = w0 * a.2 + w1 * b.2 + w2 * c.2;
                plot(&mut img, &mut zbuf, x, y, z, [w0, w1, w2]);
            }
        }
        // A triangle smaller than a pixel covers no pixel centre: draw it as one pixel at its
        // centroid, or a dense mesh seen from afar would vanish.
        if !covered {
            let (cx, cy) = ((a.0 + b.0 + c.0) / 3.0, (a.1 + b.1 + c.1) / 3.0);
            if cx >= 0.0 && cy >= 0.0 && (cx as usize) < width && (cy as usize) < height {
                plot(
                    &mut img,
                    &mut zbuf,
                    cx as usize,
                    cy as usize,
                    (a.2 + b.2 + c.2) / 3.0,
                    [1.0 / 3.0; 3],
                );
            }
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("kfuse-fig-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// Counts pixels of `img` within 40 (sum of channel differences) of `c`.
    fn count_near(img: &image::RgbImage, c: [u8; 3]) -> usize {
        img.pixels()
            .filter(|p| (0..3).map(|k| (p.0[k] as i32 - c[k] as i32).abs()).sum::<i32>() < 40)
            .count()
    }

    #[test]
    fn panels_place_images_and_draw_text() {
        let dir = scratch("panels");
        let red = Image::filled(320, 240, [250u8, 0, 0]);
        let blue = Image::filled(64, 48, [0u8, 0, 250]);
        let path = dir.join("p.png");
        save_panels(
            &path,
            titles::TASK3,
            &[Panel::new("nearest", red), Panel::new("linear", blue)],
            2,
        )
        .unwrap();
        let img = image::open(&path).unwrap().into_rgb8();
        // Two 640-wide panels scaled 2× and 10×: each covers 640 × 480 pixels.
        assert_eq!(img.width() as usize, 2 * PANEL_WIDTH + 3 * GAP);
        assert_eq!(count_near(&img, [250, 0, 0]), 640 * 480);
        assert_eq!(count_near(&img, [0, 0, 250]), 640 * 480);
        // Text was rendered: dark pixels exist in the title bar.
        let dark = (0..TITLE_BAR as u32)
            .flat_map(|y| (0..img.width()).map(move |x| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0[0] < 100)
            .count();
        assert!(dark > 200, "title text missing ({dark} dark pixels)");
    }

    #[test]
    fn mesh_render_draws_the_front_face_colour() {
        // A unit square at z = 2 made of two triangles, red, seen head-on.
        let mesh = Mesh {
            vertices: vec![[-0.5, -0.5, 2.0], [0.5, -0.5, 2.0], [-0.5, 0.5, 2.0], [0.5, 0.5, 2.0]],
            uvs: vec![],
            colors: vec![[200, 0, 0]; 4],
            faces: vec![[0, 2, 1], [1, 2, 3]],
        };
        let img = render_mesh(&mesh, 200, 200, 0.0, 0.0);
        // Centre pixel is the square's colour, shaded by the light (|n·l| = 0.77 → 0.85).
        let c = img.get(100, 100);
        assert!(
            c[1] == 0
                && c[2] == 0
                && (c[0] as f64
                    - 200.0 * (0.35 + 0.65 * 0.77 / (0.4f64 * 0.4 + 0.25 + 0.77 * 0.77).sqrt()))
                .abs()
                    <= 1.0,
            "{c:?}"
        );
        // Corner is background.
        assert_eq!(*img.get(2, 2), [255, 255, 255]);
    }

    #[test]
    fn scatter_figures_render() {
        let dir = scratch("scatter");
        let cloud = PointCloud {
            points: (0..500)
                .map(|i| {
                    [(i % 25) as f32 * 0.1, (i / 25) as f32 * 0.1, 2.0 + (i % 7) as f32 * 0.05]
                })
                .collect(),
            colors: (0..500).map(|i| [(i % 255) as u8, 100, 50]).collect(),
        };
        save_cloud_3d(&dir.join("c.png"), titles::TASK1, &cloud).unwrap();
        let samples: Vec<[f32; 3]> = (0..500)
            .map(|i| [(i % 25) as f32 * 20.0, (i / 25) as f32 * 20.0, 1.0 + i as f32 * 0.01])
            .collect();
        save_projected_scatter(&dir.join("s.png"), titles::TASK2, &samples, 640, 480).unwrap();
        for name in ["c.png", "s.png"] {
            let img = image::open(dir.join(name)).unwrap().into_rgb8();
            assert_eq!((img.width(), img.height()), PLOT_SIZE);
            let non_white = img.pixels().filter(|p| p.0 != [255, 255, 255]).count();
            assert!(non_white > 2000, "{name}: almost empty ({non_white})");
        }
    }
}
