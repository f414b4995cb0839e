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
    normals: bool,
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
    if normals {
        for axis in ["nx", "ny", "nz"] {
            writeln!(out, "property float {axis}")?;
        }
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
        header(out, &comments, cloud.points.len(), color, false, false, None)?;
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
    write_mesh(path, mesh, &[], frame, texture_file)
}

/// Writes a mesh with a unit normal per vertex as binary PLY (`float nx, ny, nz` after the
/// position, the names MeshLab, Open3D and Blender read), e.g. the TSDF mesh whose normals are
/// the distance field's gradient. `normals` has one entry per vertex.
pub fn write_mesh_ply_normals(
    path: &Path,
    mesh: &Mesh,
    normals: &[[f32; 3]],
    frame: &str,
) -> Result<(), GeometryError> {
    if normals.len() != mesh.vertices.len() {
        return Err(GeometryError::InvalidInput(format!(
            "{}: normals has {} entries for {} vertices (must be equal)",
            path.display(),
            normals.len(),
            mesh.vertices.len()
        )));
    }
    write_mesh(path, mesh, normals, frame, None)
}

fn write_mesh(
    path: &Path,
    mesh: &Mesh,
    normals: &[[f32; 3]],
    frame: &str,
    texture_file: Option<&str>,
) -> Result<(), GeometryError> {
    let n = mesh.vertices.len();
    check_len(path, "colors", mesh.colors.len(), n)?;
    check_len(path, "uvs", mesh.uvs.len(), n)?;
    check_len(path, "normals", normals.len(), n)?;
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
    let has_normals = !normals.is_empty() && n > 0;
    let mut comments = vec![
        "kfuse mesh, units: metres".to_string(),
        format!("frame: {frame} (x right, y down, z forward)"),
    ];
    if let Some(t) = texture_file {
        comments.push(format!("TextureFile {t}"));
    }
    write_atomic(path, |out| {
        header(out, &comments, n, color, uv, has_normals, Some(mesh.faces.len()))?;
        let mut buf = Vec::with_capacity(n * 35 + mesh.faces.len() * 13);
        for (i, p) in mesh.vertices.iter().enumerate() {
            for v in p {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            if has_normals {
                for v in normals[i] {
                    buf.extend_from_slice(&v.to_le_bytes());
                }
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

/// Longest PLY header read, bytes: 64 KiB. kfuse's headers are under 400 bytes and other
/// tools' a few KiB (comments, a dozen properties); a file without `end_header` within this
/// is not a PLY to read.
pub const MAX_PLY_HEADER_BYTES: usize = 64 * 1024;

/// The byte size of a PLY scalar type, `None` for a name the format does not have.
fn ply_type_size(t: &str) -> Option<usize> {
    Some(match t {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "int32" | "uint32" | "float" | "float32" => 4,
        "double" | "float64" => 8,
        _ => return None,
    })
}

/// Largest PLY file read into memory, bytes: 2 GiB. The largest kfuse writes, a mesh of 64
/// Kinects' full depth images (64 × 217 088 vertices of 15 bytes and twice as many faces of
/// 13 bytes), is about 0.6 GB; the rest is room for other tools' denser clouds (~140 M points
/// of x, y, z and colour).
pub const MAX_PLY_FILE_BYTES: u64 = 2 << 30;

/// The bytes of a PLY file: its first four must be `ply` and a line end (so a device such as
/// `/dev/zero` or another kind of file is refused after 4 bytes, with the first bytes alone
/// returned for the caller's error), the rest is read up to [`MAX_PLY_FILE_BYTES`] through
/// [`bounded_read`].
fn read_ply_bytes(path: &Path) -> Result<Vec<u8>, GeometryError> {
    use std::io::Read;
    let io = |source| GeometryError::Io { path: path.to_path_buf(), source };
    let expected = bounded_read::Expected { what: "a PLY file", fix: "is this the right file?" };
    let mut file = bounded_read::open_bounded(path, MAX_PLY_FILE_BYTES, expected).map_err(io)?;
    let mut head = Vec::new();
    (&mut file).take(4).read_to_end(&mut head).map_err(io)?;
    if !(head.starts_with(b"ply\n") || head.starts_with(b"ply\r")) {
        return Ok(head);
    }
    bounded_read::read_bounded_from(
        std::io::Cursor::new(head).chain(file),
        MAX_PLY_FILE_BYTES,
        expected,
    )
    .map_err(io)
}

/// Reads the vertices of a binary little-endian PLY (kfuse's clouds and meshes, and other
/// tools' files whose first element is `vertex` with scalar properties): `x, y, z` as float or
/// double, `red, green, blue` as uchar when all three are there; other properties are skipped.
/// Every count is checked against the file's size before anything is allocated. With
/// `max_points`, every k-th vertex is kept so that at most that many are returned (a viewer's
/// preview of a cloud of millions).
pub fn read_cloud_ply(path: &Path, max_points: Option<usize>) -> Result<PointCloud, GeometryError> {
    let bad = |m: String| GeometryError::Format { path: path.to_path_buf(), message: m };
    let bytes = read_ply_bytes(path)?;
    let end = bytes
        .windows(b"end_header\n".len())
        .take(MAX_PLY_HEADER_BYTES)
        .position(|w| w == b"end_header\n")
        .ok_or_else(|| {
            bad(format!(
                "not a PLY file kfuse reads: no end_header line in its first {MAX_PLY_HEADER_BYTES} bytes"
            ))
        })?;
    let body_start = end + b"end_header\n".len();
    let header = String::from_utf8_lossy(&bytes[..end]);
    let mut lines = header.lines().map(str::trim);
    if lines.next() != Some("ply") {
        return Err(bad("not a PLY file (it does not start with \"ply\")".into()));
    }
    let mut vertices: Option<usize> = None;
    // (name, offset, size, type) of each vertex property, and the stride.
    let mut props: Vec<(String, usize, &str)> = Vec::new();
    let mut stride = 0usize;
    let mut in_vertex = false;
    for line in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", f, _] if *f != "binary_little_endian" => {
                return Err(bad(format!(
                    "PLY format {f}; kfuse reads binary_little_endian (convert it in MeshLab or CloudCompare)"
                )));
            }
            ["element", name, count] => {
                if vertices.is_some() {
                    break; // The vertex element is read; later elements are not needed.
                }
                if *name != "vertex" {
                    return Err(bad(format!("its first element is \"{name}\", not vertex")));
                }
                let count: usize =
                    count.parse().map_err(|_| bad(format!("vertex count \"{count}\"")))?;
                vertices = Some(count);
                in_vertex = true;
            }
            ["property", "list", ..] if in_vertex => {
                return Err(bad("a list property in the vertex element".into()));
            }
            ["property", t, name] if in_vertex => {
                let size =
                    ply_type_size(t).ok_or_else(|| bad(format!("unknown property type {t}")))?;
                props.push((name.to_string(), stride, t));
                stride += size;
            }
            _ => {}
        }
    }
    let n = vertices.ok_or_else(|| bad("no vertex element".into()))?;
    let find = |name: &str| props.iter().find(|p| p.0 == name);
    let (Some(x), Some(y), Some(z)) = (find("x"), find("y"), find("z")) else {
        return Err(bad("the vertices have no x, y, z".into()));
    };
    let body = &bytes[body_start..];
    if stride == 0 || n.checked_mul(stride).is_none_or(|len| len > body.len()) {
        return Err(bad(format!(
            "{n} vertices of {stride} bytes do not fit in the file's {} bytes after the header (cut short?)",
            body.len()
        )));
    }
    let rgb = match (find("red"), find("green"), find("blue")) {
        (Some(r), Some(g), Some(b))
            if [r, g, b].iter().all(|p| p.2 == "uchar" || p.2 == "uint8") =>
        {
            Some([r.1, g.1, b.1])
        }
        _ => None,
    };
    let coord = |v: &[u8], p: &(String, usize, &str)| -> Result<f32, GeometryError> {
        let at = &v[p.1..];
        match p.2 {
            "float" | "float32" => Ok(f32::from_le_bytes([at[0], at[1], at[2], at[3]])),
            "double" | "float64" => {
                Ok(f64::from_le_bytes(at[..8].try_into().unwrap_or([0; 8])) as f32)
            }
            t => Err(bad(format!("coordinate {} is {t}; kfuse reads float or double", p.0))),
        }
    };
    let step = max_points.map_or(1, |m| n.div_ceil(m.max(1)).max(1));
    let mut cloud = PointCloud::default();
    for v in body.chunks_exact(stride).take(n).step_by(step) {
        cloud.points.push([coord(v, x)?, coord(v, y)?, coord(v, z)?]);
        if let Some([r, g, b]) = rgb {
            cloud.colors.push([v[r], v[g], v[b]]);
        }
    }
    Ok(cloud)
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

    /// `read_cloud_ply` gives back what the writers wrote (a cloud; a mesh's vertices past its
    /// s, t properties), keeps every k-th vertex under `max_points`, and refuses a cut file and
    /// an ASCII one with a message naming the file.
    #[test]
    fn read_cloud_ply_reads_what_kfuse_writes_and_refuses_broken_files() {
        let dir = scratch("read");
        let cloud = PointCloud {
            points: (0..10).map(|i| [i as f32, -0.5 * i as f32, 1.0 + i as f32]).collect(),
            colors: (0..10).map(|i| [i as u8, 2 * i as u8, 255 - i as u8]).collect(),
        };
        let path = dir.join("c.ply");
        write_cloud_ply(&path, &cloud, "reference").unwrap();
        assert_eq!(read_cloud_ply(&path, None).unwrap(), cloud);
        let some = read_cloud_ply(&path, Some(4)).unwrap();
        // 10 vertices, at most 4: every 3rd (0, 3, 6, 9).
        assert_eq!(some.points, [0, 3, 6, 9].map(|i| cloud.points[i]).to_vec());
        let mesh = Mesh {
            vertices: cloud.points[..3].to_vec(),
            colors: Vec::new(),
            uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
            faces: vec![[0, 1, 2]],
        };
        write_mesh_ply(&dir.join("m.ply"), &mesh, "reference", None).unwrap();
        let back = read_cloud_ply(&dir.join("m.ply"), None).unwrap();
        assert_eq!((back.points, back.colors.len()), (mesh.vertices.clone(), 0));
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(dir.join("cut.ply"), &bytes[..bytes.len() - 5]).unwrap();
        let e = read_cloud_ply(&dir.join("cut.ply"), None).unwrap_err().to_string();
        assert!(e.contains("cut.ply") && e.contains("cut short"), "{e}");
        std::fs::write(
            dir.join("a.ply"),
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n",
        )
        .unwrap();
        let e = read_cloud_ply(&dir.join("a.ply"), None).unwrap_err().to_string();
        assert!(e.contains("a.ply") && e.contains("binary_little_endian"), "{e}");
        std::fs::write(dir.join("huge.ply"), "ply\nformat binary_little_endian 1.0\nelement vertex 99999999999\nproperty float x\nproperty float y\nproperty float z\nend_header\n").unwrap();
        let e = read_cloud_ply(&dir.join("huge.ply"), None).unwrap_err().to_string();
        assert!(e.contains("do not fit"), "{e}");
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

    #[test]
    fn mesh_with_normals_reads_back_with_ply_rs() {
        let dir = scratch("normals");
        let mesh = Mesh {
            vertices: vec![[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]],
            uvs: Vec::new(),
            colors: vec![[9, 8, 7], [6, 5, 4], [3, 2, 1]],
            faces: vec![[0, 2, 1]],
        };
        let normals = [[0.0, 0.0, -1.0], [0.6, 0.0, -0.8], [0.0, 0.6, -0.8]];
        let path = dir.join("n.ply");
        write_mesh_ply_normals(&path, &mesh, &normals, "reference").unwrap();
        let ply = parse(&path);
        let v = &ply.payload["vertex"];
        for (e, (n, c)) in v.iter().zip(normals.iter().zip(&mesh.colors)) {
            assert_eq!([float(e, "nx"), float(e, "ny"), float(e, "nz")], *n);
            assert_eq!([uchar(e, "red"), uchar(e, "green"), uchar(e, "blue")], *c);
        }
        assert_eq!(read_cloud_ply(&path, None).unwrap().colors, mesh.colors);
        let e = write_mesh_ply_normals(&dir.join("bad.ply"), &mesh, &normals[..2], "reference")
            .unwrap_err()
            .to_string();
        assert!(e.contains("normals has 2 entries for 3 vertices"), "{e}");
    }
}
