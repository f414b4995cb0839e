//! PNG figures titled like the lab's ("Task 3: ..."): drawn by `kfuse_figures` (one colour
//! map, robust range and font, shared with the viewer) and written atomically through
//! `kfuse_io::images`. [`save_lab_figures`] writes the eight figures of `kfuse fuse`
//! (`kfuse_figures::lab`: axes on every panel, a colour bar in metres on every depth panel).

use std::path::PathBuf;

use anyhow::{Context, Result};
pub use kfuse_figures::lab::LabInputs;
use kfuse_io::images::write_color_png;

/// How many lab figures [`save_lab_figures`] writes (`task1.png` … `task8.png`: the handout's
/// eight tasks).
pub const LAB_FIGURES: usize = 8;

/// Draws the eight lab figures of one fusion ([`kfuse_figures::lab::lab_figures`]) and
/// saves each as `path_of(name)`, adding its name to `files`.
pub fn save_lab_figures(
    path_of: impl Fn(&str) -> PathBuf,
    inputs: &LabInputs,
    files: &mut Vec<String>,
) -> Result<()> {
    let figures = kfuse_figures::lab::lab_figures(inputs).context("drawing the lab figures")?;
    for (name, figure) in figures {
        let path = path_of(&name);
        write_color_png(&path, &figure.image)
            .with_context(|| format!("writing figure {}", path.display()))?;
        files.push(name);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use geometry::fusion::{self, FusionOptions};
    use geometry::synth;

    #[test]
    fn lab_figures_are_written_as_png_files() {
        let dir = std::env::temp_dir().join(format!("kfuse-fig-save-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let setup = synth::course_preset();
        let frame = synth::render(&setup);
        let options = FusionOptions { linear: false, ..FusionOptions::default() };
        let out = fusion::run(&setup.rig, &frame.depth, frame.depth_kind, &frame.color, &options)
            .unwrap();
        let lab = LabInputs {
            rig: &setup.rig,
            color: &frame.color,
            depth: &frame.depth,
            depth_kind: frame.depth_kind,
            options: &options,
            output: &out,
        };
        let mut files = Vec::new();
        save_lab_figures(|n| dir.join(n), &lab, &mut files).unwrap();
        assert_eq!(files, (1..=LAB_FIGURES).map(|n| format!("task{n}.png")).collect::<Vec<_>>());
        for name in &files {
            let img = image::open(dir.join(name)).unwrap().into_rgb8();
            assert!(img.width() > 640 && img.height() > 300, "{name}: {:?}", img.dimensions());
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
