//! The lab's eight figures of one fusion, laid out like the handout's: every panel with a
//! title, pixel axes, and a colour bar in metres on every depth panel ([`crate::layout`]).
//!
//! | file | panels |
//! | --- | --- |
//! | `task1.png` | colour image, depth image, the H1 cloud coloured by depth |
//! | `task2.png` | H2: the samples projected into the colour image (first per pixel) |
//! | `task3.png` | colour, H3 resampled depth, their overlay (imshowpair: green = colour, magenta = depth), H3 linear |
//! | `task4.png` | the H4 mesh |
//! | `task5.png` | the mesh after H5, and H4's mesh with H5's removed faces in red |
//! | `task6.png` | H6 colour on the depth grid, the original depth, their overlay, beside H3's overlay |
//! | `task7.png` | before / after the z-buffer: samples (red = removed by the z-buffer), H3 re-run, the Task 4 mesh redrawn |
//! | `task8.png` | red = removed by the z-buffer, green = filled by H8's plane; the filled depth |
//!
//! Colour-frame images are reduced to the panel width by blocks ([`pool_factor`]): depth keeps the
//! nearest sample of a block, masks keep a block that holds any marked pixel, so sparse
//! samples and one-pixel marks stay visible.

use geometry::fusion::{self, FusionOptions, FusionOutput, MeshSource};
use geometry::{DepthKind, Image, Mesh, PointCloud, Rig};
use plotters::prelude::*;

use crate::layout::{FigPanel, Figure, draw_figure};
use crate::{
    FONT_NAME, FigureError, PANEL_WIDTH, colormap, depth_colors, downsample_depth_min, draw_err,
    register_font, render_mesh, robust_range,
};

/// Pure red: pixels the z-buffer removed (Task 7, Task 8).
pub const REMOVED_RED: [u8; 3] = [255, 0, 0];
/// Pure green: pixels H8's plane filled (Task 8).
pub const FILLED_GREEN: [u8; 3] = [0, 255, 0];
/// Weight of the colour image under the red/green marks of Task 8: dimmed to 60 % grey so the
/// marks stand out and no image pixel can be pure red or green.
const DIM: f32 = 0.6;
/// View of the mesh renders: turned 25° about the vertical and 12° down, so depth steps and
/// the stretched faces along them are visible.
pub const MESH_VIEW_DEG: (f64, f64) = (25.0, -12.0);
/// Height of the 3D cloud plot of Task 1, pixels (width [`PANEL_WIDTH`]).
const CLOUD_PLOT_HEIGHT: usize = 520;
/// Points drawn in the cloud plot at most (more only darkens it and slows it down).
const MAX_CLOUD_POINTS: usize = 60_000;

/// Colour-frame block reduction for `width` pixels: `ceil(width / PANEL_WIDTH)` (3 for
/// 1920 px, 1 up to 640 px).
pub fn pool_factor(width: usize) -> usize {
    width.div_ceil(PANEL_WIDTH).max(1)
}

/// `mask` reduced by `factor` keeping blocks with any `true` pixel.
pub fn downsample_mask_any(mask: &Image<bool>, factor: usize) -> Image<bool> {
    let f = factor.max(1);
    let (w, h) = mask.size();
    Image::from_fn(w.div_ceil(f), h.div_ceil(f), |x, y| {
        (y * f..((y + 1) * f).min(h))
            .any(|yy| (x * f..((x + 1) * f).min(w)).any(|xx| *mask.get(xx, yy)))
    })
}

/// `color` reduced by `factor` (the top-left pixel of each block).
fn downsample_color(color: &Image<[u8; 3]>, factor: usize) -> Image<[u8; 3]> {
    let f = factor.max(1);
    let (w, h) = color.size();
    Image::from_fn(w.div_ceil(f), h.div_ceil(f), |x, y| *color.get(x * f, y * f))
}

/// The samples of H2 rasterised without a depth test (the first sample on a pixel stays,
/// [`fusion::first_write_wins`]) and the pixels whose sample the z-buffer removes: farther
/// than the visible surface (H3 nearest on the z-buffer) by more than `depth_jump`
/// ([`FusionOptions::depth_jump`]). That is both a sample the z-buffer replaced on its pixel
/// by a nearer one and a hidden sample that fell between the nearer surface's samples (H3's
/// nearest-surface test drops it).
pub fn zbuffer_removed(out: &FusionOutput, depth_jump: f32) -> (Image<f32>, Image<bool>) {
    let (w, h) = out.zbuffer.size();
    let before = fusion::first_write_wins(&out.samples, w, h);
    let removed = Image::from_fn(w, h, |x, y| {
        let (b, seen) = (*before.get(x, y), *out.nearest.get(x, y));
        b.is_finite() && seen.is_finite() && b > seen * (1.0 + depth_jump)
    });
    (before, removed)
}

/// Pixels H8's plane filled: in the hole mask and holding a depth after the fill.
pub fn filled_mask(out: &FusionOutput) -> Image<bool> {
    let (w, h) = out.hole_mask.size();
    Image::from_fn(w, h, |x, y| *out.hole_mask.get(x, y) && out.filled.get(x, y).is_finite())
}

/// `color` dimmed to grey with [`REMOVED_RED`] where `removed` and [`FILLED_GREEN`] where
/// `filled` and not `removed` (all the same size).
pub fn removed_filled_overlay(
    color: &Image<[u8; 3]>,
    removed: &Image<bool>,
    filled: &Image<bool>,
) -> Image<[u8; 3]> {
    let (w, h) = color.size();
    Image::from_fn(w, h, |x, y| {
        if *removed.get(x, y) {
            REMOVED_RED
        } else if *filled.get(x, y) {
            FILLED_GREEN
        } else {
            let c = color.get(x, y);
            let g = (DIM * (0.299 * c[0] as f32 + 0.587 * c[1] as f32 + 0.114 * c[2] as f32))
                .round() as u8;
            [g, g, g]
        }
    })
}

/// MATLAB's `imshowpair(A, B)` (false colour): the grey of `a` in green, the depth `b`
/// scaled over `range` (near = dark, far = bright) in red and blue; grey where they agree
/// in brightness, green or magenta where they differ. Pixels without depth show `a` in green
/// only.
pub fn imshowpair(a: &Image<[u8; 3]>, b: &Image<f32>, range: (f32, f32)) -> Image<[u8; 3]> {
    let (w, h) = a.size();
    let (lo, hi) = range;
    Image::from_fn(w, h, |x, y| {
        let c = a.get(x, y);
        let g = (0.299 * c[0] as f32 + 0.587 * c[1] as f32 + 0.114 * c[2] as f32).round() as u8;
        let d = *b.get(x.min(b.width() - 1), y.min(b.height() - 1));
        let m = if d.is_finite() && d > 0.0 {
            (255.0 * ((d - lo) / (hi - lo)).clamp(0.0, 1.0)).round() as u8
        } else {
            0
        };
        [m, g, m]
    })
}

/// Everything the lab figures need.
pub struct LabInputs<'a> {
    /// The rig.
    pub rig: &'a Rig,
    /// The colour image.
    pub color: &'a Image<[u8; 3]>,
    /// The depth image as read (depth camera, metres).
    pub depth: &'a Image<f32>,
    /// What `depth` measures.
    pub depth_kind: DepthKind,
    /// The options of the run.
    pub options: &'a FusionOptions,
    /// The run's output.
    pub output: &'a FusionOutput,
}

fn kind_label(kind: DepthKind) -> &'static str {
    match kind {
        DepthKind::Z => "z (m)",
        DepthKind::Range => "range (m)",
    }
}

/// The 3D scatter of `cloud` coloured by depth `z` over `range` (axes in metres, y up),
/// `PANEL_WIDTH × CLOUD_PLOT_HEIGHT`.
fn cloud_by_depth(cloud: &PointCloud, range: (f32, f32)) -> Result<Image<[u8; 3]>, FigureError> {
    register_font();
    let (w, h) = (PANEL_WIDTH as u32, CLOUD_PLOT_HEIGHT as u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let step = cloud.len().div_ceil(MAX_CLOUD_POINTS).max(1);
    let mut idx: Vec<usize> = (0..cloud.len())
        .step_by(step)
        .filter(|&i| cloud.points[i].iter().all(|v| v.is_finite()))
        .collect();
    // plotters has no depth test: draw far points first so near ones stay on top (the view
    // below looks from the camera's side).
    idx.sort_by(|&a, &b| cloud.points[b][2].total_cmp(&cloud.points[a][2]));
    let bound = |k: usize| -> (f64, f64) {
        let (lo, hi) = idx
            .iter()
            .map(|&i| cloud.points[i][k] as f64)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
        if lo.is_finite() && hi > lo { (lo, hi) } else { (0.0, 1.0) }
    };
    let (x, y, z) = (bound(0), bound(1), bound(2));
    let (lo, hi) = range;
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let mut chart = ChartBuilder::on(&root)
            .margin(10)
            // Plotted as (x, -y, -z): the camera frame turned 180° about x (y up, the camera's
            // side towards the viewer), still right-handed, so the scene is not mirrored.
            .build_cartesian_3d(x.0..x.1, -y.1..-y.0, -z.1..-z.0)
            .map_err(draw_err)?;
        chart.with_projection(|mut p| {
            p.yaw = 0.55;
            p.pitch = 0.35;
            p.scale = 0.8;
            p.into_matrix()
        });
        chart
            .configure_axes()
            .label_style((FONT_NAME, 12))
            .x_formatter(&|v| format!("x {v:.1}"))
            .y_formatter(&|v| format!("-y {v:.1}"))
            .z_formatter(&|v| format!("z {:.1} m", -v))
            .draw()
            .map_err(draw_err)?;
        chart
            .draw_series(idx.iter().map(|&i| {
                let p = cloud.points[i];
                let c = colormap((p[2] - lo) / (hi - lo));
                Circle::new(
                    (p[0] as f64, -(p[1] as f64), -(p[2] as f64)),
                    1,
                    RGBColor(c[0], c[1], c[2]).filled(),
                )
            }))
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    crate::rgb_image(buf, w as usize, h as usize)
}

/// `mesh` with its faces that `clean` lacks drawn in [`REMOVED_RED`] (their vertices are
/// copied so the red does not bleed into kept faces).
fn with_removed_faces_red(mesh: &Mesh, clean: &Mesh) -> Mesh {
    let kept: std::collections::HashSet<[u32; 3]> = clean.faces.iter().copied().collect();
    let mut out = Mesh {
        vertices: mesh.vertices.clone(),
        uvs: Vec::new(),
        colors: if mesh.colors.len() == mesh.vertices.len() {
            mesh.colors.clone()
        } else {
            vec![[180, 180, 180]; mesh.vertices.len()]
        },
        faces: Vec::with_capacity(mesh.faces.len()),
    };
    for f in &mesh.faces {
        if kept.contains(f) {
            out.faces.push(*f);
        } else {
            let base = out.vertices.len() as u32;
            for &v in f {
                out.vertices.push(mesh.vertices[v as usize]);
                out.colors.push(REMOVED_RED);
            }
            out.faces.push([base, base + 1, base + 2]);
        }
    }
    out
}

/// `mesh` with every vertex coloured by `color` where its texture coordinate points
/// (nearest pixel): what the mesh looks like without H6's occlusion test.
fn colors_from_texture(mesh: &Mesh, color: &Image<[u8; 3]>) -> Mesh {
    let (w, h) = color.size();
    let colors = mesh
        .uvs
        .iter()
        .map(|uv| {
            let x = (uv[0] * w as f32 - 0.5).round().clamp(0.0, (w - 1) as f32) as usize;
            let y = ((1.0 - uv[1]) * h as f32 - 0.5).round().clamp(0.0, (h - 1) as f32) as usize;
            *color.get(x, y)
        })
        .collect();
    Mesh { colors, ..mesh.clone() }
}

/// The eight lab figures of one fusion, named `task1.png` … `task8.png` (see the module docs).
pub fn lab_figures(inp: &LabInputs) -> Result<Vec<(String, Figure)>, FigureError> {
    let out = inp.output;
    let (cw, ch) = inp.color.size();
    let f = pool_factor(cw);
    let zlabel = "z (m)";
    let dlabel = kind_label(inp.depth_kind);
    // One range for every colour-frame depth, one for the input depth, so panels compare.
    let range = robust_range(out.nearest.data().iter().copied()).unwrap_or((0.0, 1.0));
    let drange = robust_range(inp.depth.data().iter().copied()).unwrap_or((0.0, 1.0));
    let small_color = downsample_color(inp.color, f);
    let depth_panel = |caption: String, d: &Image<f32>| {
        FigPanel::with_pixel_axes(
            caption,
            depth_colors(&downsample_depth_min(d, f), Some(range)),
            "u",
            "v",
        )
        .with_range(cw, ch)
        .bar(range, zlabel)
    };
    let color_axes = |caption: &str, img: Image<[u8; 3]>| {
        FigPanel::with_pixel_axes(caption, img, "u", "v").with_range(cw, ch)
    };
    let mut figs = Vec::new();
    let mut push = |n: usize, fig: Figure| figs.push((format!("task{n}.png"), fig));

    // Task 1.
    let cloud_range = robust_range(out.cloud.points.iter().map(|p| p[2])).unwrap_or((0.0, 1.0));
    push(
        1,
        draw_figure(
            crate::titles::TASK1,
            &[
                color_axes("colour image", small_color.clone()),
                FigPanel::with_pixel_axes(
                    "depth image (depth camera)",
                    depth_colors(inp.depth, Some(drange)),
                    "x",
                    "y",
                )
                .bar(drange, dlabel),
                FigPanel::plain(
                    format!("H1: {} points (depth camera frame), coloured by z", out.cloud.len()),
                    cloud_by_depth(&out.cloud, cloud_range)?,
                )
                .bar(cloud_range, zlabel),
            ],
            2,
        )?,
    );

    // Task 2.
    let (before, removed) = zbuffer_removed(out, inp.options.depth_jump);
    push(
        2,
        draw_figure(
            crate::titles::TASK2,
            &[depth_panel(
                format!("H2: {} samples in the colour image (first per pixel)", out.samples.len()),
                &before,
            )],
            1,
        )?,
    );

    // Task 3.
    let small_nearest = downsample_depth_min(&out.nearest, f);
    let h3_pair = imshowpair(&small_color, &small_nearest, range);
    let mut task3 = vec![
        color_axes("colour image", small_color.clone()),
        depth_panel("H3 nearest: depth resampled onto the colour grid".into(), &out.nearest),
        color_axes("overlay (imshowpair): green = colour, magenta = depth", h3_pair.clone()),
    ];
    if let Some(l) = &out.linear {
        task3.push(depth_panel("H3 Delaunay-linear".into(), l));
    }
    push(3, draw_figure(crate::titles::TASK3, &task3, 2)?);

    // Tasks 4 and 5.
    let mh = PANEL_WIDTH * ch / cw.max(1);
    let render = |m: &Mesh| render_mesh(m, PANEL_WIDTH, mh, MESH_VIEW_DEG.0, MESH_VIEW_DEG.1);
    let source = match inp.options.mesh_source {
        MeshSource::DepthGrid => "depth grid",
        MeshSource::Nearest => "H3 nearest",
        MeshSource::Linear => "H3 linear",
        MeshSource::Filled => "H3 nearest + H8 fill",
        MeshSource::LinearFilled => "H3 linear + H8 fill",
    };
    push(
        4,
        draw_figure(
            crate::titles::TASK4,
            &[FigPanel::plain(
                format!(
                    "H4 on the {source}: {} triangles, turned {}° / {}°",
                    out.mesh.faces.len(),
                    MESH_VIEW_DEG.0,
                    MESH_VIEW_DEG.1
                ),
                render(&out.mesh),
            )],
            1,
        )?,
    );
    let s = &out.summary;
    let rule = match inp.options.edge_rule {
        fusion::EdgeFaceRule::SampleScale => "sample-scale rule",
        fusion::EdgeFaceRule::Normal => "normal rule (handout)",
    };
    push(
        5,
        draw_figure(
            crate::titles::TASK5,
            &[
                FigPanel::plain(
                    format!("H5 ({rule}): {} of {} triangles kept", s.faces_after, s.faces_before),
                    render(&out.mesh_clean),
                ),
                FigPanel::plain(
                    format!(
                        "removed in red: {:.2} % of the faces",
                        100.0 * s.faces_removed_fraction
                    ),
                    render(&with_removed_faces_red(&out.mesh, &out.mesh_clean)),
                ),
            ],
            2,
        )?,
    );

    // Task 6.
    let h6_pair = imshowpair(&out.color_on_depth, inp.depth, drange);
    push(
        6,
        draw_figure(
            crate::titles::TASK6,
            &[
                FigPanel::with_pixel_axes(
                    "H6: colour resampled onto the depth grid",
                    out.color_on_depth.clone(),
                    "x",
                    "y",
                ),
                FigPanel::with_pixel_axes(
                    "original depth (depth camera)",
                    depth_colors(inp.depth, Some(drange)),
                    "x",
                    "y",
                )
                .bar(drange, dlabel),
                FigPanel::with_pixel_axes(
                    "overlay: green = H6 colour, magenta = depth",
                    h6_pair,
                    "x",
                    "y",
                ),
                color_axes("beside it H3's overlay (colour grid)", h3_pair),
            ],
            2,
        )?,
    );

    // Task 7.
    let radius = fusion::coverage_radius_px(inp.rig, inp.options);
    let h3_before = fusion::nearest_fill(&before, radius, inp.options.depth_jump);
    let n_removed = removed.data().iter().filter(|&&r| r).count();
    let small_removed = downsample_mask_any(&removed, f);
    let mut before_img = depth_colors(&downsample_depth_min(&before, f), Some(range));
    for (p, &r) in before_img.data_mut().iter_mut().zip(small_removed.data()) {
        if r {
            *p = REMOVED_RED;
        }
    }
    push(
        7,
        draw_figure(
            crate::titles::TASK7,
            &[
                color_axes(
                    &format!(
                        "before: first sample per pixel; red = hidden, removed ({n_removed} px)"
                    ),
                    before_img,
                )
                .bar(range, zlabel),
                depth_panel("after: z-buffer (nearest sample per pixel)".into(), &out.zbuffer),
                depth_panel("H3 nearest on the samples before the z-buffer".into(), &h3_before),
                depth_panel("H3 re-run on the z-buffer".into(), &out.nearest),
                FigPanel::plain(
                    "Task 4/5 mesh, colours by projection alone",
                    render(&colors_from_texture(&out.mesh_clean, inp.color)),
                ),
                FigPanel::plain(
                    "Task 4/5 mesh redrawn after the z-buffer (hidden points grey)",
                    render(&out.mesh_clean),
                ),
            ],
            2,
        )?,
    );

    // Task 8.
    let filled = filled_mask(out);
    let n_filled = filled.data().iter().zip(removed.data()).filter(|&(&g, &r)| g && !r).count();
    let overlay =
        removed_filled_overlay(&small_color, &small_removed, &downsample_mask_any(&filled, f));
    let plane = match &s.plane {
        Some(p) => format!("H8: holes filled from the plane (RMS {:.1} mm)", p.rms_m * 1e3),
        None => "H8: no plane found, holes left empty".into(),
    };
    push(
        8,
        draw_figure(
            crate::titles::TASK8,
            &[
                color_axes(
                    &format!(
                        "red = removed by the z-buffer ({n_removed} px), green = filled ({n_filled} px)"
                    ),
                    overlay,
                ),
                depth_panel(plane, &out.filled),
            ],
            2,
        )?,
    );
    Ok(figs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::Rect;
    use geometry::synth;

    /// Pixels equal to `c` inside `r` less its one-pixel border (the axes' lines).
    fn count_in(fig: &Figure, r: Rect, c: [u8; 3]) -> usize {
        (r.y + 1..r.y + r.h - 1)
            .flat_map(|y| (r.x + 1..r.x + r.w - 1).map(move |x| (x, y)))
            .filter(|&(x, y)| *fig.image.get(x, y) == c)
            .count()
    }

    /// `mask` pixels inside the image less its one-pixel border.
    fn count_mask(mask: &Image<bool>) -> usize {
        let (w, h) = mask.size();
        (1..h - 1)
            .flat_map(|y| (1..w - 1).map(move |x| (x, y)))
            .filter(|&(x, y)| *mask.get(x, y))
            .count()
    }

    #[test]
    fn lab_figures_mark_exactly_the_masks_and_bar_every_depth_panel() {
        // The course preset: 640×480 colour, so panels are not scaled and figure pixels
        // match mask pixels one to one.
        let setup = synth::course_preset();
        let frame = synth::render(&setup);
        let options = FusionOptions::default();
        let out = fusion::run(&setup.rig, &frame.depth, frame.depth_kind, &frame.color, &options)
            .unwrap();
        let inp = LabInputs {
            rig: &setup.rig,
            color: &frame.color,
            depth: &frame.depth,
            depth_kind: frame.depth_kind,
            options: &options,
            output: &out,
        };
        let figs = lab_figures(&inp).unwrap();
        let names: Vec<&str> = figs.iter().map(|f| f.0.as_str()).collect();
        assert_eq!(names, (1..=8).map(|n| format!("task{n}.png")).collect::<Vec<_>>());
        // Colour bars: on every depth panel, none elsewhere.
        let bars: Vec<usize> = figs
            .iter()
            .map(|(_, f)| f.panels.iter().filter(|p| p.colorbar.is_some()).count())
            .collect();
        assert_eq!(bars, [2, 1, 2, 0, 0, 1, 4, 1]);
        // Colour-frame bars span the robust range of H3's depth.
        let range = robust_range(out.nearest.data().iter().copied()).unwrap();
        let bar = figs[2].1.panels[1].colorbar.as_ref().unwrap();
        assert_eq!((bar.lo, bar.hi), range);

        let (_, removed) = zbuffer_removed(&out, options.depth_jump);
        let filled = filled_mask(&out);
        let n_removed = count_mask(&removed);
        let green = Image::from_fn(640, 480, |x, y| *filled.get(x, y) && !*removed.get(x, y));
        let n_green = count_mask(&green);
        eprintln!("course preset: {n_removed} px removed by the z-buffer, {n_green} px filled");
        // The course rig's 1 m baseline hides much of the background: both masks are large.
        assert!(n_removed > 1000 && n_green > 1000, "{n_removed} / {n_green}");
        // Task 8: red = removed, green = filled, pixel for pixel.
        let t8 = &figs[7].1;
        let r = t8.panels[0].image;
        assert_eq!((r.w, r.h), (640, 480));
        assert_eq!(count_in(t8, r, REMOVED_RED), n_removed);
        assert_eq!(count_in(t8, r, FILLED_GREEN), n_green);
        // Task 7: the same red on the samples before the z-buffer.
        let t7 = &figs[6].1;
        assert_eq!(count_in(t7, t7.panels[0].image, REMOVED_RED), n_removed);
    }

    #[test]
    fn overlays_put_each_input_in_its_channels() {
        let a = Image::from_fn(4, 1, |x, _| [x as u8 * 60; 3]);
        let b = Image::from_vec(4, 1, vec![1.0, 2.0, f32::NAN, 3.0]).unwrap();
        let p = imshowpair(&a, &b, (1.0, 3.0));
        assert_eq!(p.data(), &[[0, 0, 0], [128, 60, 128], [0, 120, 0], [255, 180, 255]]);
        let removed = Image::from_vec(4, 1, vec![true, false, false, true]).unwrap();
        let filled = Image::from_vec(4, 1, vec![false, true, false, true]).unwrap();
        let o = removed_filled_overlay(&a, &removed, &filled);
        assert_eq!(o.data(), &[REMOVED_RED, FILLED_GREEN, [72, 72, 72], REMOVED_RED]);
        // Pixel (4, 2) of 6 × 6 lies in block (1, 0) of 3 × 3 blocks.
        let m = downsample_mask_any(&Image::from_fn(6, 6, |x, y| x == 4 && y == 2), 3);
        assert_eq!(m.data(), &[false, true, false, false]);
    }
}
