//! Wavefront OBJ + MTL + PNG texture for textured meshes (Blender, MeshLab, most viewers).
//!
//! [`write_textured_obj`] writes three files side by side: `<stem>.obj` (vertices `v x y z`,
//! extended with `r g b` in 0..1 when the mesh has vertex colours, as MeshLab and `tobj`
//! read; texture coordinates `vt s t` with the origin at the bottom-left of the texture;
//! 1-based faces `f a/a b/b c/c`), `<stem>.mtl` (one material whose `map_Kd` is the texture)
//! and `<stem>_texture.png`. Units: metres, written with 5 decimals (10 µm, far below any
//! depth sensor's noise); texture coordinates with 6 (0.002 px on a 1920-px texture).

use std::path::{Path, PathBuf};

use crate::atomic::write_atomic;
use crate::images::write_color_png;
use geometry::{GeometryError, Image, Mesh};

/// The name of the single material written to the MTL file.
pub const MATERIAL_NAME: &str = "kfuse_texture";

/// The files written by [`write_textured_obj`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ObjFiles {
    /// The `.obj` file.
    pub obj: PathBuf,
    /// The `.mtl` file.
    pub mtl: PathBuf,
    /// The texture PNG, if one was written.
    pub texture: Option<PathBuf>,
}

/// Writes `mesh` as `<obj_path>` + `<stem>.mtl` + `<stem>_texture.png` (the latter only when
/// `texture` is given; the mesh then needs texture coordinates).
pub fn write_textured_obj(
    obj_path: &Path,
    mesh: &Mesh,
    texture: Option<&Image<[u8; 3]>>,
) -> Result<ObjFiles, GeometryError> {
    write_obj(obj_path, mesh, texture, None)
}

/// Writes `mesh` with a unit normal per vertex (`vn nx ny nz`, faces `f a//a b//b c//c`; with
/// its vertex colours when it has them) as `<obj_path>` + `<stem>.mtl`: the TSDF mesh of
/// `kfuse fuse --tsdf` for the tools that read OBJ rather than PLY.
pub fn write_obj_with_normals(
    obj_path: &Path,
    mesh: &Mesh,
    normals: &[[f32; 3]],
) -> Result<ObjFiles, GeometryError> {
    write_obj(obj_path, mesh, None, Some(normals))
}

fn write_obj(
    obj_path: &Path,
    mesh: &Mesh,
    texture: Option<&Image<[u8; 3]>>,
    normals: Option<&[[f32; 3]]>,
) -> Result<ObjFiles, GeometryError> {
    let n = mesh.vertices.len();
    let invalid = |m: String| GeometryError::InvalidInput(format!("{}: {m}", obj_path.display()));
    if !mesh.uvs.is_empty() && mesh.uvs.len() != n {
        return Err(invalid(format!("{} texture coordinates for {n} vertices", mesh.uvs.len())));
    }
    if !mesh.colors.is_empty() && mesh.colors.len() != n {
        return Err(invalid(format!("{} colours for {n} vertices", mesh.colors.len())));
    }
    if let Some(normals) = normals
        && normals.len() != n
    {
        return Err(invalid(format!("{} normals for {n} vertices", normals.len())));
    }
    if texture.is_some() && mesh.uvs.is_empty() && n > 0 {
        return Err(invalid("a texture needs per-vertex texture coordinates".into()));
    }
    if let Some(bad) = mesh.faces.iter().flatten().find(|&&i| i as usize >= n) {
        return Err(invalid(format!("face index {bad} out of range for {n} vertices")));
    }
    let stem = obj_path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "mesh".into());
    let mtl = obj_path.with_file_name(format!("{stem}.mtl"));
    let tex_name = format!("{stem}_texture.png");
    let tex_path = texture.map(|_| obj_path.with_file_name(&tex_name));
    if let (Some(img), Some(p)) = (texture, &tex_path) {
        write_color_png(p, img)?;
    }
    let mtl_name = mtl.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    write_atomic(&mtl, |out| {
        writeln!(out, "# kfuse material")?;
        writeln!(out, "newmtl {MATERIAL_NAME}")?;
        writeln!(out, "Ka 1.0 1.0 1.0")?;
        writeln!(out, "Kd 1.0 1.0 1.0")?;
        writeln!(out, "Ks 0.0 0.0 0.0")?;
        writeln!(out, "d 1.0")?;
        writeln!(out, "illum 1")?;
        if texture.is_some() {
            writeln!(out, "map_Kd {tex_name}")?;
        }
        Ok(())
    })?;
    write_atomic(obj_path, |out| {
        writeln!(
            out,
            "# kfuse mesh: {} vertices, {} triangles, units: metres",
            n,
            mesh.faces.len()
        )?;
        writeln!(out, "# frame: x right, y down, z forward (camera frame)")?;
        writeln!(out, "mtllib {mtl_name}")?;
        for (i, v) in mesh.vertices.iter().enumerate() {
            if let Some(c) = mesh.colors.get(i) {
                writeln!(
                    out,
                    "v {:.5} {:.5} {:.5} {:.4} {:.4} {:.4}",
                    v[0],
                    v[1],
                    v[2],
                    c[0] as f32 / 255.0,
                    c[1] as f32 / 255.0,
                    c[2] as f32 / 255.0
                )?;
            } else {
                writeln!(out, "v {:.5} {:.5} {:.5}", v[0], v[1], v[2])?;
            }
        }
        for t in &mesh.uvs {
            writeln!(out, "vt {:.6} {:.6}", t[0], t[1])?;
        }
        // Unit normals to 5 decimals: 1e-5 rad, far below what shading shows.
        for v in normals.unwrap_or_default() {
            writeln!(out, "vn {:.5} {:.5} {:.5}", v[0], v[1], v[2])?;
        }
        writeln!(out, "usemtl {MATERIAL_NAME}")?;
        let uv = !mesh.uvs.is_empty();
        for f in &mesh.faces {
            let [a, b, c] = [f[0] + 1, f[1] + 1, f[2] + 1];
            if uv && normals.is_some() {
                writeln!(out, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}")?;
            } else if normals.is_some() {
                writeln!(out, "f {a}//{a} {b}//{b} {c}//{c}")?;
            } else if uv {
                writeln!(out, "f {a}/{a} {b}/{b} {c}/{c}")?;
            } else {
                writeln!(out, "f {a} {b} {c}")?;
            }
        }
        Ok(())
    })?;
    Ok(ObjFiles { obj: obj_path.to_path_buf(), mtl, texture: tex_path })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The TSDF mesh's OBJ: positions, colours and normals as `tobj` reads them.
    #[test]
    fn obj_with_normals_reads_back_with_tobj() {
        let dir = std::env::temp_dir().join(format!("kfuse-obj-normals-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mesh = Mesh {
            vertices: vec![[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [1.0, 1.0, 1.25]],
            uvs: vec![],
            colors: vec![[255, 0, 0], [0, 255, 0], [0, 0, 255], [51, 102, 153]],
            faces: vec![[0, 2, 1], [1, 2, 3]],
        };
        let s = 0.6f32;
        let normals = [[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, -0.8, -s], [0.8, 0.0, -s]];
        let files = write_obj_with_normals(&dir.join("tsdf.obj"), &mesh, &normals).unwrap();
        assert_eq!(files.texture, None);
        let (models, _) = tobj::load_obj(
            &files.obj,
            &tobj::LoadOptions { single_index: true, triangulate: true, ..Default::default() },
        )
        .unwrap();
        let m = &models[0].mesh;
        // `single_index` renumbers the vertices in the order the faces first use them: compare
        // each face corner's values with the vertex it was written from.
        let corners: Vec<usize> = mesh.faces.iter().flatten().map(|&i| i as usize).collect();
        assert_eq!(m.indices.len(), corners.len());
        for (&read, &written) in m.indices.iter().zip(&corners) {
            let r = read as usize;
            let at = |v: &[f32]| [v[3 * r], v[3 * r + 1], v[3 * r + 2]];
            let near = |a: [f32; 3], b: [f32; 3], tol: f32| {
                a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
            };
            // Written with 5 decimals (positions, normals) and 4 (colours in 0..1).
            assert!(near(at(&m.positions), mesh.vertices[written], 5e-6), "{written}");
            assert!(near(at(&m.normals), normals[written], 5e-6), "{written}");
            let c = mesh.colors[written].map(|c| f32::from(c) / 255.0);
            assert!(near(at(&m.vertex_color), c, 5e-5), "{written}");
        }
        let e = write_obj_with_normals(&dir.join("bad.obj"), &mesh, &normals[..3]).unwrap_err();
        assert!(e.to_string().contains("3 normals for 4 vertices"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn textured_obj_reads_back_with_tobj() {
        let dir = std::env::temp_dir().join(format!("kfuse-obj-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mesh = Mesh {
            vertices: vec![[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [1.0, 1.0, 1.25]],
            uvs: vec![[0.0, 1.0], [1.0, 1.0], [0.0, 0.0], [1.0, 0.0]],
            colors: vec![[255, 0, 0], [0, 255, 0], [0, 0, 255], [51, 102, 153]],
            faces: vec![[0, 2, 1], [1, 2, 3]],
        };
        let tex = Image::from_fn(4, 2, |x, y| [x as u8 * 50, y as u8 * 100, 0]);
        let files = write_textured_obj(&dir.join("mesh.obj"), &mesh, Some(&tex)).unwrap();
        assert_eq!(files.texture.as_deref(), Some(dir.join("mesh_texture.png").as_path()));
        let (models, materials) = tobj::load_obj(
            &files.obj,
            &tobj::LoadOptions { single_index: true, triangulate: true, ..Default::default() },
        )
        .unwrap();
        let materials = materials.unwrap();
        assert_eq!(materials.len(), 1);
        assert_eq!(materials[0].diffuse_texture.as_deref(), Some("mesh_texture.png"));
        let m = &models[0].mesh;
        // The mesh above: 4 vertices × 3 coordinates, 2 faces × 3 indices, 4 uvs × 2,
        // 4 colours × 3.
        assert_eq!(m.positions.len(), 12);
        assert_eq!(m.indices.len(), 6);
        assert_eq!(m.texcoords.len(), 8);
        assert_eq!(m.material_id, Some(0));
        // Vertex colours present (0..1 floats, printed with 4 decimals).
        assert_eq!(m.vertex_color.len(), 12);
        // Vertex 3's colour (51, 102, 153) / 255 = (0.2, 0.4, 0.6), printed with 4 decimals.
        assert!((m.vertex_color[9] - 0.2).abs() < 1e-4 && (m.vertex_color[11] - 0.6).abs() < 1e-4);
        // Triangles and positions survive (tobj may reorder vertices: compare by position).
        let tri: Vec<[f32; 3]> = m.indices[3..6]
            .iter()
            .map(|&i| {
                [
                    m.positions[3 * i as usize],
                    m.positions[3 * i as usize + 1],
                    m.positions[3 * i as usize + 2],
                ]
            })
            .collect();
        assert_eq!(tri, vec![mesh.vertices[1], mesh.vertices[2], mesh.vertices[3]]);
        assert_eq!(crate::images::read_color(files.texture.as_ref().unwrap()).unwrap(), tex);
    }
}
