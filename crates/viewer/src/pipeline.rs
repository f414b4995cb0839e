//! Re-running the fusion with the viewer's toggles: [`Toggles`] map onto [`FusionOptions`]
//! and [`fuse`] is one call of the library's pipeline (`geometry::fusion::run_on`, on the CPU
//! or the GPU):
//! * **z-buffer off**: [`FusionOptions::zbuffer`] (first write wins, H6 without its occlusion
//!   test; always on the CPU, see `geometry::fusion::first_write_wins`). Delaunay on such a
//!   buffer is not defined: the nearest fill is shown instead.
//! * **mesh grid**: [`MeshGrid::Depth`] (default) meshes the depth samples on the depth pixel
//!   grid ([`MeshSource::DepthGrid`], what `kfuse fuse` writes by default), so the 3D view
//!   shows exactly the mesh of `fuse`; [`MeshGrid::Color`] meshes the colour-frame depth the
//!   H3/H8 switches produce on the colour pixel grid (the handout's H3-grid mesh, below).
//! * **Delaunay + hole filling** with the H3-grid mesh: [`MeshSource::LinearFilled`].
//! * **edge-face removal off**: the 3D view shows H4's mesh instead of H5's.
//!
//! The 2D panes show the colour-frame depth the H3/H8 switches produce ([`Fused::shown_depth`])
//! whichever grid is meshed. With the depth-grid mesh the pipeline fills only the nearest
//! depth (it fills the Delaunay depth only to mesh it), so Delaunay + hole filling shows the
//! unfilled Delaunay depth there.

use fusion_gpu::Engine;
use geometry::fusion::{self, DepthRange, FusionOptions, FusionOutput, MeshSource};
use geometry::{Image, Mesh};

use crate::ViewerError;
use crate::data::Frame;

/// How colour pixels between depth samples are filled (H3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Resampling {
    /// Nearest sample within the coverage radius.
    Nearest,
    /// Linear interpolation on the Delaunay triangulation of the samples.
    Delaunay,
}

/// Which grid H4 meshes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshGrid {
    /// The depth samples on the depth pixel grid ([`MeshSource::DepthGrid`]): `kfuse fuse`'s
    /// default mesh, every vertex a measurement, disocclusion holes left open.
    Depth,
    /// The colour-frame depth of H3 (with H8's fill when on) on the colour pixel grid: the
    /// handout's H3-grid mesh.
    Color,
}

/// The switches of the 3D page.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Toggles {
    /// H3 resampling.
    pub resampling: Resampling,
    /// H7 z-buffer (nearest surface per colour pixel) or last-write-wins.
    pub zbuffer: bool,
    /// H5 edge-face removal.
    pub remove_edges: bool,
    /// H5 threshold, `|n_xy| / |n_z|` (1 = 45°).
    pub stretch_ratio: f32,
    /// H8 plane fill of disocclusion holes.
    pub fill_holes: bool,
    /// H4's grid.
    pub mesh_grid: MeshGrid,
    /// H1's depth range (`kfuse fuse --depth-range`): depth outside is not a sample.
    pub depth_range: DepthRange,
}

impl Default for Toggles {
    fn default() -> Self {
        let d = FusionOptions::default();
        Self {
            resampling: Resampling::Nearest,
            zbuffer: true,
            remove_edges: true,
            stretch_ratio: d.stretch_ratio,
            fill_holes: true,
            mesh_grid: MeshGrid::Depth,
            depth_range: DepthRange::ALL,
        }
    }
}

impl Toggles {
    /// The options the pipeline is called with.
    pub fn options(&self) -> FusionOptions {
        FusionOptions {
            linear: self.resampling == Resampling::Delaunay,
            mesh_source: match self.mesh_grid {
                MeshGrid::Depth => MeshSource::DepthGrid,
                MeshGrid::Color => self.color_depth_source(),
            },
            fill_holes: self.fill_holes,
            stretch_ratio: self.stretch_ratio,
            zbuffer: self.zbuffer,
            depth_range: self.depth_range,
            ..FusionOptions::default()
        }
    }

    /// The colour-frame depth the H3/H8 switches pick (what the H3-grid mesh meshes and the
    /// 2D panes show).
    pub fn color_depth_source(&self) -> MeshSource {
        // Delaunay on a first-write-wins buffer is computed (the Summary shows its counts) but
        // not meshed: the nearest fill is shown instead (see the module docs).
        let delaunay = self.resampling == Resampling::Delaunay && self.zbuffer;
        match (delaunay, self.fill_holes) {
            (true, true) => MeshSource::LinearFilled,
            (true, false) => MeshSource::Linear,
            (false, true) => MeshSource::Filled,
            (false, false) => MeshSource::Nearest,
        }
    }
}

/// One fusion result as the viewer shows it.
#[derive(Debug)]
pub struct Fused {
    /// The toggles it was computed with.
    pub toggles: Toggles,
    /// The pipeline's output (with the z-buffer-off replacements applied).
    pub output: FusionOutput,
    /// The colour-frame depth of the H3/H8 switches (H3 result, plane-filled when on; the
    /// depth the H3-grid mesh meshes), metres, NaN = none.
    pub shown_depth: Image<f32>,
    /// The mesh the 3D view draws (H5's when edge removal is on, else H4's).
    pub mesh: Mesh,
    /// Pixels of `shown_depth` the plane fill supplied.
    pub filled_pixels: usize,
    /// Which engine ran it ([`Engine::Cpu`] or [`Engine::Gpu`]).
    pub engine: Engine,
}

/// Runs the pipeline on `frame` with `toggles` (see the module docs). `gpu`: the GPU
/// context to use, or `None` for the CPU.
pub fn fuse(
    frame: &Frame,
    toggles: Toggles,
    gpu: Option<&mut fusion_gpu::FusionContext>,
) -> Result<Fused, ViewerError> {
    let options = toggles.options();
    let err = |message: String| ViewerError::Fusion { source_name: frame.name.clone(), message };
    let (rig, depth, kind, color) = (&frame.rig, &frame.depth, frame.kind, &frame.color);
    // With the z-buffer off the per-pixel stages run on the CPU whatever the engine.
    let (output, engine) = match gpu {
        Some(ctx) if options.zbuffer => (
            ctx.run(rig, depth, kind, color, &options).map_err(|e| err(e.to_string()))?,
            Engine::Gpu,
        ),
        _ => (
            fusion::run(rig, depth, kind, color, &options).map_err(|e| err(e.to_string()))?,
            Engine::Cpu,
        ),
    };
    let source = toggles.color_depth_source();
    let shown_depth = output.meshed_depth(source).clone();
    let filled_pixels = match (toggles.mesh_grid, source) {
        (MeshGrid::Color, _) => output.mesh_filled_pixels,
        // The depth-grid run fills the nearest depth only (see the module docs).
        (MeshGrid::Depth, MeshSource::Filled) => output.summary.filled_pixels,
        (MeshGrid::Depth, _) => 0,
    };
    let mesh = if toggles.remove_edges { output.mesh_clean.clone() } else { output.mesh.clone() };
    Ok(Fused { toggles, output, shown_depth, mesh, filled_pixels, engine })
}
