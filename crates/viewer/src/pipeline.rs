//! Re-running the fusion with the viewer's toggles.
//!
//! [`Toggles`] map onto [`FusionOptions`]; the stages `geometry::fusion::run` has no switch
//! for are recomputed here from its public stage functions:
//! * **z-buffer off**: H2's samples are scattered without a depth test, in depth-pixel order,
//!   and the first sample on a colour pixel stays ([`first_write_wins`]); H3, H8 and H6
//!   (without its occlusion test) then run on that. Where a foreground object and the
//!   background hidden behind it (seen by the depth camera, not by the colour camera) land on
//!   one colour pixel, the background can win. (Keeping the *last* sample instead would hide
//!   the effect on a Kinect: with the colour camera at −x, row-major order is
//!   occlusion-compatible and reproduces the z-buffer exactly.)
//! * **Delaunay + hole filling**: the plane fill is applied to the Delaunay-linear depth.
//! * **edge-face removal off**: the 3D view shows H4's mesh instead of H5's.

use geometry::fusion::{
    self, ColorProjection, FusionOptions, FusionOutput, MeshSource, coverage_radius_px,
    fill_holes_with_plane, hole_grow_px, mesh_from_depth, nearest_fill, remove_stretched_faces,
};
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
        }
    }
}

impl Toggles {
    /// The options `geometry::fusion::run` is called with.
    pub fn options(&self) -> FusionOptions {
        let delaunay = self.resampling == Resampling::Delaunay;
        FusionOptions {
            linear: delaunay,
            mesh_source: match (delaunay, self.fill_holes) {
                (true, _) => MeshSource::Linear,
                (false, true) => MeshSource::Filled,
                (false, false) => MeshSource::Nearest,
            },
            fill_holes: self.fill_holes,
            stretch_ratio: self.stretch_ratio,
            ..FusionOptions::default()
        }
    }
}

/// Where the per-pixel stages run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    /// `geometry::fusion::run`.
    Cpu,
    /// `fusion_gpu::FusionContext::run` (bit-identical output).
    Gpu,
}

/// One fusion result as the viewer shows it.
#[derive(Debug)]
pub struct Fused {
    /// The toggles it was computed with.
    pub toggles: Toggles,
    /// The pipeline's output (with the z-buffer-off replacements applied).
    pub output: FusionOutput,
    /// The colour-frame depth that was meshed (H3 result, plane-filled when on), metres, NaN = none.
    pub shown_depth: Image<f32>,
    /// The mesh the 3D view draws (H5's when edge removal is on, else H4's).
    pub mesh: Mesh,
    /// Colour pixels whose depth the plane fill supplied.
    pub filled_pixels: usize,
    /// Which backend ran it.
    pub backend: Backend,
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
    let (mut output, backend) = match gpu {
        Some(ctx) => (
            ctx.run(&frame.rig, &frame.depth, frame.kind, &frame.color, &options)
                .map_err(|e| err(e.to_string()))?,
            Backend::Gpu,
        ),
        None => (
            fusion::run(&frame.rig, &frame.depth, frame.kind, &frame.color, &options)
                .map_err(|e| err(e.to_string()))?,
            Backend::Cpu,
        ),
    };
    let rig = &frame.rig;
    let radius = coverage_radius_px(rig, &options);
    let mut filled_pixels = output.summary.filled_pixels;
    let mut recompute_mesh = false;
    if !toggles.zbuffer {
        let (cw, ch) = (rig.color.width, rig.color.height);
        output.zbuffer = first_write_wins(&output.samples, cw, ch);
        output.nearest = nearest_fill(&output.zbuffer, radius, options.depth_jump);
        output.hole_mask = fusion::hole_mask(&output.zbuffer, radius, hole_grow_px(rig, &options));
        let rays = fusion::depth_ray_table(&rig.depth, frame.kind);
        let proj = ColorProjection::from_rig(rig);
        let (c, v) = fusion::color_on_depth(
            &frame.depth,
            &rays,
            &proj,
            &frame.color,
            None,
            options.color_occlusion_tolerance,
        );
        output.cloud.colors = output
            .cloud_pixels
            .iter()
            .map(|&i| if v.data()[i as usize] { c.data()[i as usize] } else { [0; 3] })
            .collect();
        output.color_on_depth = c;
        output.color_on_depth_valid = v;
        recompute_mesh = true;
    }
    let base = match toggles.resampling {
        Resampling::Delaunay if toggles.zbuffer => {
            output.linear.clone().unwrap_or_else(|| output.nearest.clone())
        }
        // Delaunay on a last-write-wins buffer is not defined by the pipeline: the nearest
        // fill of that buffer is shown instead.
        _ => output.nearest.clone(),
    };
    let shown_depth = match (&output.summary.plane, toggles.fill_holes) {
        (Some(plane), true) => {
            let (d, n) = fill_holes_with_plane(&base, &output.hole_mask, &rig.color, plane);
            if toggles.resampling == Resampling::Delaunay || !toggles.zbuffer {
                recompute_mesh = true;
            }
            filled_pixels = n;
            d
        }
        _ => {
            filled_pixels = if toggles.fill_holes { filled_pixels } else { 0 };
            base
        }
    };
    if recompute_mesh {
        output.mesh = mesh_from_depth(&shown_depth, &rig.color, &frame.color, options.mesh_step);
        output.mesh_clean = remove_stretched_faces(&output.mesh, toggles.stretch_ratio);
    }
    let mesh = if toggles.remove_edges { output.mesh_clean.clone() } else { output.mesh.clone() };
    Ok(Fused { toggles, output, shown_depth, mesh, filled_pixels, backend })
}

/// H7 without the depth test: in sample order, the first sample on a colour pixel stays.
/// Empty pixels hold [`fusion::ZBUFFER_EMPTY`], like the z-buffer.
pub fn first_write_wins(
    samples: &[fusion::ColorSample],
    width: usize,
    height: usize,
) -> Image<f32> {
    let empty = fusion::ZBUFFER_EMPTY.to_bits();
    let mut img = Image::filled(width, height, fusion::ZBUFFER_EMPTY);
    for s in samples {
        if let Some(i) = fusion::zbuffer_index(s.u, s.v, width as u32, height as u32)
            && img.data()[i].to_bits() == empty
        {
            img.data_mut()[i] = s.z;
        }
    }
    img
}
