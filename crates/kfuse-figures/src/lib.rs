//! kfuse's figures: one colour map, one robust range and one font for the lab figures of
//! `kfuse fuse` and the viewer's panes. Everything draws into an [`Image`] in memory (plotters'
//! bitmap backend with the bundled font, so figures render the same on machines without
//! fontconfig); writing files is the caller's.
//!
//! | module | what |
//! | --- | --- |
//! | [`colors`] | [`colormap`] (viridis), [`robust_range`], depth and mask images |
//! | [`layout`] | figures of panels with pixel axes and colour bars in metres |
//! | [`lab`] | the eight lab figures (Task 1–8) of one fusion |
//! | this file | the font, panel figures, 3D and projected scatter plots, mesh renders |
#![deny(missing_docs)]

pub mod colors;
pub mod lab;
pub mod layout;

use std::sync::Once;

use geometry::{GeometryError, Image, Mesh, PointCloud};
use nalgebra::{Matrix3, Rotation3, Vector3};
use plotters::prelude::*;

pub use colors::{
    colormap, depth_colors, depth_overlay, downsample_depth_min, mask_colors, robust_range,
};

/// What can go wrong drawing a figure.
#[derive(Debug, thiserror::Error)]
pub enum FigureError {
    /// plotters failed (the message is its error).
    #[error("drawing a figure: {0}")]
    Draw(String),
    /// An image did not match its size.
    #[error(transparent)]
    Geometry(#[from] GeometryError),
}

/// The lab's figure titles, one per fusion stage.
pub mod titles {
    /// H1.
    pub const TASK1: &str = "Task 1: Colour and depth images, point cloud in global (x,y,z) space";
    /// H2.
    pub const TASK2: &str = "Task 2: Point cloud projected to the colour camera";
    /// H3.
    pub const TASK3: &str = "Task 3: Depth resampled onto the colour image";
    /// H4.
    pub const TASK4: &str = "Task 4: Textured mesh";
    /// H5.
    pub const TASK5: &str = "Task 5: Mesh after edge-face removal";
    /// H6.
    pub const TASK6: &str = "Task 6: Colour resampled onto the depth image";
    /// H7.
    pub const TASK7: &str = "Task 7: Z-buffering, before and after";
    /// H8.
    pub const TASK8: &str = "Task 8: Removed by the z-buffer, filled from the plane";
}

/// DejaVu Sans (`assets/fonts/`, 742 KiB), the one copy of the font in the binary.
pub const FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");
/// The family name [`register_font`] registers [`FONT`] under, for plotters' text styles.
pub const FONT_NAME: &str = "sans-serif";
static REGISTER: Once = Once::new();

/// Registers [`FONT`] with plotters' `ab_glyph` backend as [`FONT_NAME`] (once per process);
/// every drawing function here calls it, other plotters users must call it first.
pub fn register_font() {
    REGISTER.call_once(|| {
        // The bundled file is a valid TrueType font; a failure here would only lose text.
        let _ = plotters::style::register_font(FONT_NAME, FontStyle::Normal, FONT);
    });
}

/// Width of one image panel in a panel figure, pixels (the panel is scaled to it).
pub const PANEL_WIDTH: usize = 640;
/// Height of the figure's title bar, pixels.
pub const TITLE_BAR: usize = 48;
/// Height of a panel's caption bar, pixels.
const CAPTION_BAR: usize = 30;
/// Gap between panels, pixels.
pub const GAP: usize = 12;
/// Size of the scatter-plot figures, pixels.
pub const PLOT_SIZE: (u32, u32) = (1000, 760);
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

/// An RGB byte buffer as an image.
pub fn rgb_image(buf: Vec<u8>, w: usize, h: usize) -> Result<Image<[u8; 3]>, FigureError> {
    let pixels = buf.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    Ok(Image::from_vec(w, h, pixels)?)
}

/// plotters' error as a [`FigureError::Draw`].
pub fn draw_err<E: std::fmt::Debug>(e: E) -> FigureError {
    FigureError::Draw(format!("{e:?}"))
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

/// Image panels side by side (up to `columns` per row) under a title.
pub fn draw_panels(
    title: &str,
    panels: &[Panel],
    columns: usize,
) -> Result<Image<[u8; 3]>, FigureError> {
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
    rgb_image(buf, w, h)
}

/// Every `step`-th index so that at most `max` are kept.
fn subsample(n: usize, max: usize) -> impl Iterator<Item = usize> {
    let step = n.div_ceil(max.max(1)).max(1);
    (0..n).step_by(step)
}

/// 3D scatter of a coloured point cloud (subsampled to [`MAX_SCATTER_POINTS`]), axes in
/// metres. Points are drawn with y pointing up (the camera's y is down, so −y is plotted) and
/// depth z going into the picture.
pub fn draw_cloud_3d(title: &str, cloud: &PointCloud) -> Result<Image<[u8; 3]>, FigureError> {
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
    rgb_image(buf, w as usize, h as usize)
}

/// Scatter of projected samples `(u, v, z)` over the `width × height` image frame (v down),
/// coloured by `z` (metres) with a colour-bar label.
pub fn draw_projected_scatter(
    title: &str,
    samples: &[[f32; 3]],
    width: usize,
    height: usize,
) -> Result<Image<[u8; 3]>, FigureError> {
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
    rgb_image(buf, w as usize, h as usize)
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

    /// Counts pixels of `img` within 40 (sum of channel differences) of `c`.
    fn count_near(img: &Image<[u8; 3]>, c: [u8; 3]) -> usize {
        img.data()
            .iter()
            .filter(|p| (0..3).map(|k| (p[k] as i32 - c[k] as i32).abs()).sum::<i32>() < 40)
            .count()
    }

    #[test]
    fn panels_place_images_and_draw_text() {
        let red = Image::filled(320, 240, [250u8, 0, 0]);
        let blue = Image::filled(64, 48, [0u8, 0, 250]);
        let img = draw_panels(
            titles::TASK3,
            &[Panel::new("nearest", red), Panel::new("linear", blue)],
            2,
        )
        .unwrap();
        // Two 640-wide panels scaled 2× and 10×: each covers 640 × 480 pixels.
        assert_eq!(img.width(), 2 * PANEL_WIDTH + 3 * GAP);
        // Exact count: panels are scaled by whole factors, so every pixel of a panel keeps its
        // colour; 40 in count_near only separates them from white background and dark text.
        assert_eq!(count_near(&img, [250, 0, 0]), 640 * 480);
        assert_eq!(count_near(&img, [0, 0, 250]), 640 * 480);
        // Text was rendered: dark pixels exist in the title bar.
        let dark = (0..TITLE_BAR)
            .flat_map(|y| (0..img.width()).map(move |x| (x, y)))
            .filter(|&(x, y)| img.get(x, y)[0] < 100)
            .count();
        // Guard, not a measurement: a rendered title line has thousands of dark glyph pixels; 200
        // fails only when no text was drawn.
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
                    // 1: the u8 rounding of the shaded channel.
                    <= 1.0,
            "{c:?}"
        );
        // Corner is background.
        assert_eq!(*img.get(2, 2), [255, 255, 255]);
    }

    #[test]
    fn scatter_figures_render() {
        let cloud = PointCloud {
            points: (0..500)
                .map(|i| {
                    [(i % 25) as f32 * 0.1, (i / 25) as f32 * 0.1, 2.0 + (i % 7) as f32 * 0.05]
                })
                .collect(),
            colors: (0..500).map(|i| [(i % 255) as u8, 100, 50]).collect(),
        };
        let c = draw_cloud_3d(titles::TASK1, &cloud).unwrap();
        let samples: Vec<[f32; 3]> = (0..500)
            .map(|i| [(i % 25) as f32 * 20.0, (i / 25) as f32 * 20.0, 1.0 + i as f32 * 0.01])
            .collect();
        let s = draw_projected_scatter(titles::TASK2, &samples, 640, 480).unwrap();
        for (name, img) in [("cloud", c), ("scatter", s)] {
            assert_eq!((img.width() as u32, img.height() as u32), PLOT_SIZE);
            let non_white = img.data().iter().filter(|p| **p != [255, 255, 255]).count();
            // Guard, not a measurement: 500 points are drawn; 2000 non-white pixels fails for
            // an (almost) empty plot.
            assert!(non_white > 2000, "{name}: almost empty ({non_white})");
        }
    }
}
