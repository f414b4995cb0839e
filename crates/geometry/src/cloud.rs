//! Point clouds and triangle meshes produced by the fusion stages (metres, camera frames as
//! named by the producer: H1 clouds are in the depth camera's frame).

/// A set of 3D points with optional per-point colour.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    /// Points, metres.
    pub points: Vec<[f32; 3]>,
    /// Per-point RGB colour (same length as `points`) or empty.
    pub colors: Vec<[u8; 3]>,
}

impl PointCloud {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when the cloud has no point.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// True when every point has a colour.
    pub fn has_colors(&self) -> bool {
        !self.points.is_empty() && self.colors.len() == self.points.len()
    }
}

/// An indexed triangle mesh with per-vertex texture coordinates and colours.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions, metres.
    pub vertices: Vec<[f32; 3]>,
    /// Texture coordinates per vertex, `[0, 1]²`, origin at the *bottom-left* of the texture
    /// image (OBJ / OpenGL convention: `t = 1 - (v + 0.5) / height`). Empty if untextured.
    pub uvs: Vec<[f32; 2]>,
    /// RGB colour per vertex, or empty.
    pub colors: Vec<[u8; 3]>,
    /// Triangles as indices into `vertices`, counter-clockwise seen from the camera.
    pub faces: Vec<[u32; 3]>,
}
