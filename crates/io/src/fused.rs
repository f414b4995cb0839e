//! The files of `kfuse fuse`'s output folder (less the lab's figures, which the CLI draws):
//! the cloud, the colour-frame depth images, the hole mask, the colour on the depth grid, the
//! two textured meshes and `summary.json`. One writer for the CLI and the Python package
//! (`kfuse.fuse(...).save(folder)`), so both write the same bytes.

use std::path::Path;

use geometry::fusion::{FusionOptions, FusionOutput, FusionSummary};
use geometry::{GeometryError, Image};
use serde::Serialize;

use crate::atomic::{StagedDir, write_bytes_atomic};
use crate::{images, obj, ply};

/// The two meshes `fuse` writes: before and after H5.
pub const MESH_NAMES: [&str; 2] = ["mesh", "mesh_clean"];

/// The format name of `summary.json`.
pub const SUMMARY_FORMAT: &str = "kfuse-fuse-summary";

/// The kfuse version `summary.json` names (the workspace's).
pub const KFUSE_VERSION: &str = env!("CARGO_PKG_VERSION");

/// Every name [`write_data`], [`write_meshes`] and [`write_summary`] may write (a run writes a
/// subset: `depth_linear.*` only with the linear resampling). The CLI adds its figures.
pub fn output_names() -> Vec<String> {
    let mut names: Vec<String> =
        ["summary.json", "cloud.ply", "hole_mask.png", "color_on_depth.png"]
            .map(String::from)
            .into();
    for depth in ["depth_zbuffer", "depth_nearest", "depth_linear", "depth_filled"] {
        names.extend([format!("{depth}.png"), format!("{depth}.exr")]);
    }
    for mesh in MESH_NAMES {
        names.extend([".ply", ".obj", ".mtl", "_texture.png"].map(|ext| format!("{mesh}{ext}")));
    }
    names
}

fn write_depth_pair(
    staged: &StagedDir,
    name: &str,
    depth: &Image<f32>,
    files: &mut Vec<String>,
) -> Result<(), GeometryError> {
    images::write_depth_png16(&staged.join(format!("{name}.png")), depth)?;
    images::write_depth_exr(&staged.join(format!("{name}.exr")), depth)?;
    files.push(format!("{name}.png"));
    files.push(format!("{name}.exr"));
    Ok(())
}

/// `cloud.ply` (depth camera frame), `depth_{zbuffer,nearest,linear,filled}.{png,exr}`,
/// `hole_mask.png` and `color_on_depth.png` of `out` into `staged`; their names are appended
/// to `files` in the order written.
pub fn write_data(
    staged: &StagedDir,
    out: &FusionOutput,
    files: &mut Vec<String>,
) -> Result<(), GeometryError> {
    ply::write_cloud_ply(&staged.join("cloud.ply"), &out.cloud, "depth camera")?;
    files.push("cloud.ply".into());
    write_depth_pair(staged, "depth_zbuffer", &out.zbuffer, files)?;
    write_depth_pair(staged, "depth_nearest", &out.nearest, files)?;
    if let Some(linear) = &out.linear {
        write_depth_pair(staged, "depth_linear", linear, files)?;
    }
    write_depth_pair(staged, "depth_filled", &out.filled, files)?;
    images::write_mask_png(&staged.join("hole_mask.png"), &out.hole_mask)?;
    images::write_color_png(&staged.join("color_on_depth.png"), &out.color_on_depth)?;
    files.push("hole_mask.png".into());
    files.push("color_on_depth.png".into());
    Ok(())
}

/// `mesh` and `mesh_clean` of `out` as PLY and textured OBJ (+ MTL, `color` as the PNG
/// texture) into `staged`; names appended to `files`.
pub fn write_meshes(
    staged: &StagedDir,
    color: &Image<[u8; 3]>,
    out: &FusionOutput,
    files: &mut Vec<String>,
) -> Result<(), GeometryError> {
    for (name, mesh) in MESH_NAMES.into_iter().zip([&out.mesh, &out.mesh_clean]) {
        let texture = format!("{name}_texture.png");
        ply::write_mesh_ply(
            &staged.join(format!("{name}.ply")),
            mesh,
            "colour camera",
            Some(&texture),
        )?;
        obj::write_textured_obj(&staged.join(format!("{name}.obj")), mesh, Some(color))?;
        for ext in [".ply", ".obj", ".mtl", "_texture.png"] {
            files.push(format!("{name}{ext}"));
        }
    }
    Ok(())
}

#[derive(Serialize)]
struct SummaryFile<'a> {
    format: &'static str,
    kfuse_version: &'static str,
    inputs: &'a serde_json::Value,
    units: serde_json::Value,
    options: &'a FusionOptions,
    summary: &'a FusionSummary,
    files: Vec<String>,
}

/// `summary.json` into `staged`: `inputs` (where the frame came from), the options, the
/// fusion's counts (and timings when recorded) and `files` (with `summary.json` appended).
pub fn write_summary(
    staged: &StagedDir,
    inputs: &serde_json::Value,
    options: &FusionOptions,
    summary: &FusionSummary,
    mut files: Vec<String>,
) -> Result<(), GeometryError> {
    files.push("summary.json".into());
    let summary = SummaryFile {
        format: SUMMARY_FORMAT,
        kfuse_version: KFUSE_VERSION,
        inputs,
        units: serde_json::json!({
            "lengths": "metres",
            "depth_png": "16-bit millimetres, 0 = no sample",
            "depth_exr": "32-bit float metres (channel Y), NaN = no sample",
            "pixels": "0-based, integer coordinates are pixel centres",
            "frames": "cloud.ply: depth camera; meshes and depth_*: colour camera (x right, y down, z forward)",
        }),
        options,
        summary,
        files,
    };
    let path = staged.join("summary.json");
    let json = serde_json::to_string_pretty(&summary).map_err(|e| {
        GeometryError::InvalidInput(format!("{}: serialising: {e}", path.display()))
    })?;
    write_bytes_atomic(&path, json.as_bytes())
}

/// Everything but the figures in one call, into a new staged folder for `destination`,
/// committed at the end (the folder appears only when complete; same-named files in it are
/// replaced, any other kfuse output name in it is refused first). Returns the committed
/// folder. `kfuse fuse` calls the parts itself to check Ctrl-C and draw figures between them.
pub fn save(
    destination: &Path,
    inputs: &serde_json::Value,
    color: &Image<[u8; 3]>,
    options: &FusionOptions,
    out: &FusionOutput,
) -> Result<std::path::PathBuf, GeometryError> {
    let staged = StagedDir::new(destination)?;
    staged.refuse_foreign(&output_names())?;
    let mut files = Vec::new();
    write_data(&staged, out, &mut files)?;
    write_meshes(&staged, color, out, &mut files)?;
    write_summary(&staged, inputs, options, &out.summary, files)?;
    staged.commit()
}

/// The files of a volumetric fusion (`kfuse fuse --tsdf`, `kfuse.Volume.save`): the mesh with
/// vertex colours and normals as PLY (MeshLab, CloudCompare, Open3D, Blender) and as OBJ + MTL
/// (for the tools that read OBJ), and its vertices with their colours as a point cloud.
pub const TSDF_FILES: [&str; 4] =
    ["tsdf_mesh.ply", "tsdf_cloud.ply", "tsdf_mesh.obj", "tsdf_mesh.mtl"];

/// Writes [`TSDF_FILES`] into `dir`: `mesh` (vertices, colours — none when empty — and
/// triangles) with a unit normal per vertex, in the coordinate frame `frame` names. One writer
/// for the CLI (several Kinects, recordings) and the Python package.
pub fn write_tsdf_files(
    dir: &Path,
    mesh: &geometry::Mesh,
    normals: &[[f32; 3]],
    frame: &str,
) -> Result<(), GeometryError> {
    ply::write_mesh_ply_normals(&dir.join(TSDF_FILES[0]), mesh, normals, frame)?;
    let cloud = geometry::PointCloud { points: mesh.vertices.clone(), colors: mesh.colors.clone() };
    ply::write_cloud_ply(&dir.join(TSDF_FILES[1]), &cloud, frame)?;
    obj::write_obj_with_normals(&dir.join(TSDF_FILES[2]), mesh, normals)?;
    Ok(())
}
