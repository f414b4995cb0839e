//! PNG figures titled like the lab's ("Task 3: ..."): drawn by `kfuse_figures` (one colour
//! map, robust range and font, shared with the viewer) and written atomically through
//! `kfuse_io::images`.

use std::path::Path;

use anyhow::{Context, Result};
use geometry::{Image, PointCloud};
pub use kfuse_figures::{
    PANEL_WIDTH, Panel, depth_colors, depth_overlay, downsample_depth_min, mask_colors,
    render_mesh, robust_range, titles,
};
use kfuse_io::images::write_color_png;

fn save(path: &Path, img: Result<Image<[u8; 3]>, kfuse_figures::FigureError>) -> Result<()> {
    let img = img.with_context(|| format!("drawing figure {}", path.display()))?;
    write_color_png(path, &img).with_context(|| format!("writing figure {}", path.display()))
}

/// Saves image panels side by side (up to `columns` per row) under a title
/// ([`kfuse_figures::draw_panels`]).
pub fn save_panels(path: &Path, title: &str, panels: &[Panel], columns: usize) -> Result<()> {
    save(path, kfuse_figures::draw_panels(title, panels, columns))
}

/// Saves a 3D scatter of a coloured point cloud ([`kfuse_figures::draw_cloud_3d`]).
pub fn save_cloud_3d(path: &Path, title: &str, cloud: &PointCloud) -> Result<()> {
    save(path, kfuse_figures::draw_cloud_3d(title, cloud))
}

/// Saves a scatter of projected samples `(u, v, z)` over the `width × height` image frame
/// ([`kfuse_figures::draw_projected_scatter`]).
pub fn save_projected_scatter(
    path: &Path,
    title: &str,
    samples: &[[f32; 3]],
    width: usize,
    height: usize,
) -> Result<()> {
    save(path, kfuse_figures::draw_projected_scatter(title, samples, width, height))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figures_are_written_as_png_files() {
        let dir = std::env::temp_dir().join(format!("kfuse-fig-save-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let red = Image::filled(320, 240, [250u8, 0, 0]);
        let path = dir.join("p.png");
        save_panels(&path, titles::TASK3, &[Panel::new("nearest", red)], 1).unwrap();
        let img = image::open(&path).unwrap().into_rgb8();
        assert_eq!(img.width() as usize, PANEL_WIDTH + 2 * kfuse_figures::GAP);
        // The panel's own colour (PNG is lossless); (100, 200) lies inside the scaled panel.
        assert_eq!(img.get_pixel(100, 200).0, [250, 0, 0]);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
