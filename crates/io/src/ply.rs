//! Binary little-endian PLY for point clouds and meshes (MeshLab, CloudCompare, Blender and
//! Open3D read it).
//!
//! Point cloud: `element vertex` with `float x, y, z` (metres) and, when the cloud has
//! colours, `uchar red, green, blue`. Mesh: the same vertex properties plus `float s, t`
//! (texture coordinates, origin at the bottom-left of the texture as in OBJ) when the mesh has
//! them, and `element face` with `property list uchar int vertex_indices` (counter-clockwise
//! seen from the camera). A mesh with a texture names it in a `comment TextureFile <name>`
//! line, the convention MeshLab reads.

use std::io::Write;
use std::path::Path;

use crate::atomic::write_atomic;
use geometry::{GeometryError, Mesh, PointCloud};

fn header(
    out: &mut dyn Write,
    comments: &[String],
    vertices: usize,
    color: bool,
    uv: bool,
    faces: Option<usize>,
) -> std::io::Result<()> {
    writeln!(out, "ply")?;
    writeln!(out, "format binary_little_endian 1.0")?;
    for c in comments {
        writeln!(out, "comment {c}")?;
    }
    writeln!(out, "element vertex {vertices}")?;
    for axis in ["x", "y", "z"] {
        writeln!(out, "property float {axis}")?;
    }
    if color {
        for c in ["red", "green", "blue"] {
            writeln!(out, "property uchar {c}")?;
        }
    }
    if uv {
        writeln!(out, "property float s")?;
        writeln!(out, "property float t")?;
    }
    if let Some(f) = faces {
        writeln!(out, "element face {f}")?;
        writeln!(out, "property list uchar int vertex_indices")?;
    }
    writeln!(out, "end_header")
}

fn check_len(path: &Path, what: &str, got: usize, want: usize) -> Result<(), GeometryError> {
    if got != 0 && got != want {
        return Err(GeometryError::InvalidInput(format!(
            "{}: {what} has {got} entries for {want} vertices (must be 0 or equal)",
            path.display()
        )));
    }
    Ok(())
}

/// Writes a point cloud (metres; coloured when `cloud.colors` is filled) as binary PLY.
/// `frame` names the coordinate frame in a header comment (e.g. "depth camera").
pub fn write_cloud_ply(path: &Path, cloud: &PointCloud, frame: &str) -> Result<(), GeometryError> {
    check_len(path, "colors", cloud.colors.len(), cloud.points.len())?;
    let color = cloud.has_colors() && !cloud.is_empty();
    let comments = vec![
        "kfuse point cloud, units: metres".to_string(),
        format!("frame: {frame} (x right, y down, z forward)"),
    ];
    write_atomic(path, |out| {
        header(out, &comments, cloud.points.len(), color, false, None)?;
        let mut buf = Vec::with_capacity(cloud.points.len() * 15);
        for (i, p) in cloud.points.iter().enumerate() {
            for v in p {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            if color {
                buf.extend_from_slice(&cloud.colors[i]);
            }
        }
        out.write_all(&buf)
    })
}

/// Writes a mesh as binary PLY: vertices (with colours and `s, t` texture coordinates when
/// present) and triangles. `texture_file` is recorded as `comment TextureFile`.
pub fn write_mesh_ply(
    path: &Path,
    mesh: &Mesh,
    frame: &str,
    texture_file: Option<&str>,
) -> Result<(), GeometryError> {
    let n = mesh.vertices.len();
    check_len(path, "colors", mesh.colors.len(), n)?;
    check_len(path, "uvs", mesh.uvs.len(), n)?;
    if let Some(bad) = mesh.faces.iter().flatten().find(|&&i| i as usize >= n) {
        return Err(GeometryError::InvalidInput(format!(
            "{}: face index {bad} out of range for {n} vertices",
            path.display()
        )));
    }
    if n > i32::MAX as usize {
        return Err(GeometryError::InvalidInput(format!(
            "{}: {n} vertices exceed PLY's int indices",
            path.display()
        )));
    }
    let color = !mesh.colors.is_empty() && n > 0;
    let uv = !mesh.uvs.is_empty() && n > 0;
    let mut comments = vec![
        "kfuse mesh, units: metres".to_string(),
        format!("frame: {frame} (x right, y down, z forward)"),
    ];
    if let Some(t) = texture_file {
        comments.push(format!("TextureFile {t}"));
    }
    write_atomic(path, |out| {
        header(out, &comments, n, color, uv, Some(mesh.faces.len()))?;
        let mut buf = Vec::with_capacity(n * 23 + mesh.faces.len() * 13);
        for i in 0..n {
            for v in mesh.vertices[i] {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            if color {
                buf.extend_from_slice(&mesh.colors[i]);
            }
            if uv {
                for v in mesh.uvs[i] {
                    buf.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        for f in &mesh.faces {
            buf.push(3);
            for &i in f {
                buf.extend_from_slice(&(i as i32).to_le_bytes());
            }
        }
        out.write_all(&buf)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ply_rs::parser::Parser;
    use ply_rs::ply::{DefaultElement, Property};

    fn scratch(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("kfuse-ply-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn parse(path: &Path) -> ply_rs::ply::Ply<DefaultElement> {
        let mut f = std::io::BufReader::new(std::fs::File::open(path).unwrap());
        Parser::<DefaultElement>::new().read_ply(&mut f).unwrap()
    }

    fn float(e: &DefaultElement, k: &str) -> f32 {
        match e.get(k) {
            Some(Property::Float(v)) => *v,
            other => panic!("{k}: {other:?}"),
        }
    }

    fn uchar(e: &DefaultElement, k: &str) -> u8 {
        match e.get(k) {
            Some(Property::UChar(v)) => *v,
            other => panic!("{k}: {other:?}"),
        }
    }

    #[test]
    fn coloured_cloud_reads_back_with_ply_rs() {
        let dir = scratch("cloud");
        let cloud = PointCloud {
            points: vec![[0.1, -0.2, 1.5], [3.25, 0.0, 2.0], [-1.0, 1.0, 0.75]],
            colors: vec![[255, 0, 0], [1, 2, 3], [10, 200, 30]],
        };
        let path = dir.join("c.ply");
        write_cloud_ply(&path, &cloud, "depth camera").unwrap();
        let ply = parse(&path);
        let v = &ply.payload["vertex"];
        assert_eq!(v.len(), 3);
        for (e, (p, c)) in v.iter().zip(cloud.points.iter().zip(&cloud.colors)) {
            assert_eq!([float(e, "x"), float(e, "y"), float(e, "z")], *p);
            assert_eq!([uchar(e, "red"), uchar(e, "green"), uchar(e, "blue")], *c);
        }
    }

    #[test]
    fn textured_mesh_reads_back_with_ply_rs() {
        let dir = scratch("mesh");
        let mesh = Mesh {
            vertices: vec![[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [1.0, 1.0, 1.2]],
            uvs: vec![[0.0, 1.0], [1.0, 1.0], [0.0, 0.0], [1.0, 0.0]],
            colors: vec![[9, 8, 7], [6, 5, 4], [3, 2, 1], [0, 0, 0]],
            faces: vec![[0, 2, 1], [1, 2, 3]],
        };
        let path = dir.join("m.ply");
        write_mesh_ply(&path, &mesh, "depth camera", Some("m_texture.png")).unwrap();
        let ply = parse(&path);
        assert!(ply.header.comments.iter().any(|c| c == "TextureFile m_texture.png"));
        let v = &ply.payload["vertex"];
        assert_eq!(v.len(), 4);
        assert_eq!([float(&v[3], "s"), float(&v[3], "t")], [1.0, 0.0]);
        assert_eq!(uchar(&v[1], "green"), 5);
        let f = &ply.payload["face"];
        assert_eq!(f.len(), 2);
        match f[1].get("vertex_indices") {
            Some(Property::ListInt(ix)) => assert_eq!(ix, &vec![1, 2, 3]),
            other => panic!("{other:?}"),
        }
        let bad = Mesh { faces: vec![[0, 1, 9]], ..mesh };
        let err = write_mesh_ply(&dir.join("bad.ply"), &bad, "depth camera", None)
            .unwrap_err()
            .to_string();
        assert!(err.contains("bad.ply") && err.contains("face index 9"), "{err}");
        assert!(!dir.join("bad.ply").exists());
    }
}
