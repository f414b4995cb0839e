//! Marching cubes over the volume's observed voxels: one mesh with per-vertex colours and
//! normals (the TSDF's gradient), and the surface point cloud (the mesh's vertices).
//!
//! # The case table
//!
//! The 256-case table is this module's own, generated once from the cube's topology rather
//! than typed in (a transcription error in a 4 096-entry table is easy to make and hard to
//! see): on every face of the cube, each run of consecutive *inside* corners (TSDF < 0, behind
//! the surface) is cut off by one segment between the two sign-changing edges that bound the
//! run; the segments, directed so that the inside lies on their right seen from outside the
//! cube, chain into closed loops, and each loop is triangulated as a fan. On a face with two
//! diagonal inside corners (the ambiguous face of marching cubes) this separates the inside
//! corners; the rule depends on the face's four corners alone, so the two cubes that share a
//! face cut it alike and the mesh has no cracks (a test checks that a sphere's mesh is closed
//! and consistently oriented). Triangles are counter-clockwise seen from the outside (the
//! positive side, where the cameras are), so their normals agree with the TSDF's gradient.
//! Why not a crate: the maintained isosurface crates mesh dense arrays of their own layout
//! (or produce surface nets, not marching cubes); a sparse block volume would be copied into
//! a dense grid per block with its neighbours anyway, which is what [`TsdfVolume::extract_mesh`]
//! does in a dozen lines.

use std::collections::HashMap;
use std::sync::OnceLock;

use geometry::{Mesh, PointCloud};
use rayon::prelude::*;

use crate::TsdfVolume;
use crate::volume::{BLOCK_SIDE, Voxel, local_index};

/// Colour of a vertex that no frame gave a colour (`geometry::fusion::HIDDEN_VERTEX_GREY`).
pub const UNSEEN_GREY: [u8; 3] = geometry::fusion::HIDDEN_VERTEX_GREY;

/// The mesh of the surface: vertices (volume frame, metres), unit normals pointing out of the
/// surface (towards the cameras), colours (when the volume keeps them), counter-clockwise
/// triangles seen from outside.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TsdfMesh {
    /// Vertex positions.
    pub vertices: Vec<[f32; 3]>,
    /// Unit normal per vertex (the TSDF's gradient); zero where it is not defined.
    pub normals: Vec<[f32; 3]>,
    /// Colour per vertex, empty when the volume keeps no colour.
    pub colors: Vec<[u8; 3]>,
    /// Triangles.
    pub faces: Vec<[u32; 3]>,
}

impl TsdfMesh {
    /// As a `geometry` mesh (without the normals: `kfuse_io::ply::write_mesh_ply_normals`
    /// writes them next to it).
    pub fn to_mesh(&self) -> Mesh {
        Mesh {
            vertices: self.vertices.clone(),
            uvs: Vec::new(),
            colors: self.colors.clone(),
            faces: self.faces.clone(),
        }
    }

    /// The surface point cloud: the zero crossings of the TSDF on the voxel grid's edges
    /// (the mesh's vertices) with their colours.
    pub fn to_point_cloud(&self) -> PointCloud {
        PointCloud { points: self.vertices.clone(), colors: self.colors.clone() }
    }
}

/// Corner `c` of the unit cube: bit 0 is x, bit 1 y, bit 2 z.
const fn corner(c: usize) -> [usize; 3] {
    [c & 1, (c >> 1) & 1, (c >> 2) & 1]
}

/// The 12 edges: `(low corner, high corner, axis)`.
fn edges() -> [(usize, usize, usize); 12] {
    let mut out = [(0, 0, 0); 12];
    let mut n = 0;
    for axis in 0..3 {
        for c in 0..8 {
            if c & (1 << axis) == 0 {
                out[n] = (c, c | (1 << axis), axis);
                n += 1;
            }
        }
    }
    out
}

/// The case table: for each of the 256 inside-corner masks, triangles as triples of edge
/// indices into [`edges`].
fn case_table() -> &'static [Vec<[u8; 3]>; 256] {
    static TABLE: OnceLock<[Vec<[u8; 3]>; 256]> = OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(triangulate_case))
}

/// The 6 faces, each as its 4 corners counter-clockwise seen from outside the cube.
fn faces() -> [[usize; 4]; 6] {
    let mut out = [[0; 4]; 6];
    for a in 0..3 {
        let (u, v) = ((a + 1) % 3, (a + 2) % 3);
        for s in 0..2 {
            // Counter-clockwise around +e_a (e_u × e_v = e_a); reversed for the face at 0,
            // whose outward normal is −e_a.
            let mut f =
                [(0, 0), (1, 0), (1, 1), (0, 1)].map(|(cu, cv)| (s << a) | (cu << u) | (cv << v));
            if s == 0 {
                f.reverse();
            }
            out[a * 2 + s] = f;
        }
    }
    out
}

fn triangulate_case(case: usize) -> Vec<[u8; 3]> {
    let edges = edges();
    let edge = |a: usize, b: usize| {
        edges
            .iter()
            .position(|&(lo, hi, _)| (lo, hi) == (a.min(b), a.max(b)))
            .expect("cube corners of a face are joined by an edge") as u8
    };
    let inside = |c: usize| case >> c & 1 == 1;
    // Directed segments on the faces: next[e_in] = e_out.
    let mut next = [u8::MAX; 12];
    for f in faces() {
        let ins = f.map(inside);
        for k in 0..4 {
            // A run of inside corners starts at k: k inside, the corner before it outside.
            if !ins[k] || ins[(k + 3) % 4] {
                continue;
            }
            let mut j = k;
            while ins[(j + 1) % 4] {
                j = (j + 1) % 4;
            }
            let e_in = edge(f[(k + 3) % 4], f[k]);
            let e_out = edge(f[j], f[(j + 1) % 4]);
            debug_assert_eq!(next[e_in as usize], u8::MAX, "edge entered twice");
            next[e_in as usize] = e_out;
        }
    }
    let mut triangles = Vec::new();
    let mut used = [false; 12];
    for start in 0..12 {
        if next[start] == u8::MAX || used[start] {
            continue;
        }
        let mut cycle = Vec::new();
        let mut e = start;
        while !used[e] {
            used[e] = true;
            cycle.push(e as u8);
            e = next[e] as usize;
        }
        for i in 1..cycle.len().saturating_sub(1) {
            triangles.push([cycle[0], cycle[i], cycle[i + 1]]);
        }
    }
    triangles
}

/// A mesh vertex is identified by its grid edge: the global voxel coordinates of the edge's
/// low end and the edge's axis.
type EdgeKey = ([i64; 3], u8);

/// Side of the neighbourhood copied per block: the block's 8 voxels, one more for the cubes
/// that reach into the next block, and one on each side for the central differences.
const CACHE: usize = BLOCK_SIDE + 3;

#[inline]
fn cache_index(x: usize, y: usize, z: usize) -> usize {
    (z * CACHE + y) * CACHE + x
}

struct MeshVertex {
    key: EdgeKey,
    position: [f32; 3],
    normal: [f32; 3],
    color: [u8; 3],
}

struct BlockMesh {
    vertices: Vec<MeshVertex>,
    triangles: Vec<[u32; 3]>,
}

impl TsdfVolume {
    /// Marching cubes over every cube of 8 observed voxels (weight > 0): one vertex per
    /// sign-changing grid edge (linear interpolation of the TSDF between the two voxel
    /// centres), its colour interpolated likewise, its normal the normalised TSDF gradient
    /// (central differences, interpolated along the edge). Blocks are meshed in parallel and
    /// joined in block order: the output does not depend on the thread count.
    pub fn extract_mesh(&self) -> TsdfMesh {
        let crate::volume::Parts { keys, blocks, index } = self.parts();
        let mut order: Vec<usize> = (0..keys.len()).collect();
        order.sort_unstable_by_key(|&i| keys[i]);
        let voxel = self.options().voxel_size_m;
        let color = self.options().color;
        let per_block: Vec<BlockMesh> =
            order.par_iter().map(|&b| mesh_block(keys[b], blocks, index, voxel)).collect();
        let mut mesh = TsdfMesh::default();
        let mut ids: HashMap<EdgeKey, u32> = HashMap::new();
        for bm in per_block {
            let local: Vec<u32> = bm
                .vertices
                .iter()
                .map(|v| {
                    *ids.entry(v.key).or_insert_with(|| {
                        mesh.vertices.push(v.position);
                        mesh.normals.push(v.normal);
                        if color {
                            mesh.colors.push(v.color);
                        }
                        (mesh.vertices.len() - 1) as u32
                    })
                })
                .collect();
            mesh.faces.extend(bm.triangles.iter().map(|t| t.map(|i| local[i as usize])));
        }
        mesh
    }

    /// The surface point cloud ([`TsdfMesh::to_point_cloud`] of [`TsdfVolume::extract_mesh`]).
    pub fn extract_point_cloud(&self) -> PointCloud {
        self.extract_mesh().to_point_cloud()
    }
}

fn mesh_block(
    key: [i32; 3],
    blocks: &[Box<[Voxel]>],
    index: &HashMap<[i32; 3], u32>,
    voxel: f64,
) -> BlockMesh {
    // The 27 blocks around this one.
    let mut around: [Option<&[Voxel]>; 27] = [None; 27];
    for (n, slot) in around.iter_mut().enumerate() {
        let d = [n % 3, (n / 3) % 3, n / 9].map(|v| v as i32 - 1);
        let k = [key[0] + d[0], key[1] + d[1], key[2] + d[2]];
        *slot = index.get(&k).map(|&i| &*blocks[i as usize]);
    }
    // Voxels −1 … 9 of the block along each axis (unobserved: weight 0).
    let side = BLOCK_SIDE as i64;
    let mut cache = vec![Voxel::default(); CACHE * CACHE * CACHE];
    for z in 0..CACHE {
        for y in 0..CACHE {
            for x in 0..CACHE {
                let l = [x as i64 - 1, y as i64 - 1, z as i64 - 1];
                let off = l.map(|v| v.div_euclid(side));
                let n = ((off[2] + 1) * 9 + (off[1] + 1) * 3 + (off[0] + 1)) as usize;
                if let Some(b) = around[n] {
                    let m = l.map(|v| v.rem_euclid(side) as usize);
                    cache[cache_index(x, y, z)] = b[local_index(m[0], m[1], m[2])];
                }
            }
        }
    }
    let at = |p: [usize; 3]| &cache[cache_index(p[0], p[1], p[2])];
    let gradient = |p: [usize; 3]| {
        let mut g = [0f32; 3];
        for (a, ga) in g.iter_mut().enumerate() {
            let (mut lo, mut hi) = (p, p);
            lo[a] -= 1;
            hi[a] += 1;
            let (vl, vc, vh) = (at(lo), at(p), at(hi));
            *ga = match (vl.weight > 0.0, vh.weight > 0.0) {
                (true, true) => (vh.tsdf - vl.tsdf) / 2.0,
                (true, false) => vc.tsdf - vl.tsdf,
                (false, true) => vh.tsdf - vc.tsdf,
                (false, false) => 0.0,
            };
        }
        g
    };
    let table = case_table();
    let edges = edges();
    let mut out = BlockMesh { vertices: Vec::new(), triangles: Vec::new() };
    let mut local: HashMap<EdgeKey, u32> = HashMap::new();
    let base = key.map(|k| k as i64 * side);
    for z in 0..BLOCK_SIDE {
        for y in 0..BLOCK_SIDE {
            for x in 0..BLOCK_SIDE {
                // Cache coordinates of the cube's low corner (the cache starts at −1).
                let c0 = [x + 1, y + 1, z + 1];
                let corner_at = |c: usize| {
                    let d = corner(c);
                    [c0[0] + d[0], c0[1] + d[1], c0[2] + d[2]]
                };
                let mut case = 0usize;
                let mut observed = true;
                for c in 0..8 {
                    let v = at(corner_at(c));
                    observed &= v.weight > 0.0;
                    if v.tsdf < 0.0 {
                        case |= 1 << c;
                    }
                }
                if !observed || table[case].is_empty() {
                    continue;
                }
                for tri in &table[case] {
                    let ids = tri.map(|e| {
                        let (lo, hi, axis) = edges[e as usize];
                        let d = corner(lo);
                        let g = [
                            base[0] + (x + d[0]) as i64,
                            base[1] + (y + d[1]) as i64,
                            base[2] + (z + d[2]) as i64,
                        ];
                        let key = (g, axis as u8);
                        *local.entry(key).or_insert_with(|| {
                            let (pa, pb) = (corner_at(lo), corner_at(hi));
                            let (va, vb) = (at(pa), at(pb));
                            let t = va.tsdf / (va.tsdf - vb.tsdf);
                            let mut p = [0f32; 3];
                            for (a, pa) in p.iter_mut().enumerate() {
                                let shift = if a == axis { t as f64 } else { 0.0 };
                                *pa = ((g[a] as f64 + 0.5 + shift) * voxel) as f32;
                            }
                            let (ga, gb) = (gradient(pa), gradient(pb));
                            let mut n = [0f32; 3];
                            for a in 0..3 {
                                n[a] = ga[a] + (gb[a] - ga[a]) * t;
                            }
                            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                            if len > 0.0 {
                                n = n.map(|v| v / len);
                            }
                            let color = match (va.color_weight > 0.0, vb.color_weight > 0.0) {
                                (true, true) => std::array::from_fn(|k| {
                                    (va.color[k] + (vb.color[k] - va.color[k]) * t).round() as u8
                                }),
                                (true, false) => va.color.map(|c| c.round() as u8),
                                (false, true) => vb.color.map(|c| c.round() as u8),
                                (false, false) => UNSEEN_GREY,
                            };
                            out.vertices.push(MeshVertex { key, position: p, normal: n, color });
                            (out.vertices.len() - 1) as u32
                        })
                    });
                    out.triangles.push(ids);
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every case: the triangles use exactly the sign-changing edges, and every directed edge
    /// of the case's triangles on the cube's faces is matched (the loops are closed).
    #[test]
    fn table_uses_exactly_the_crossing_edges() {
        let edges = edges();
        for case in 0..256usize {
            let tris = &case_table()[case];
            let mut used = [false; 12];
            for t in tris {
                for &e in t {
                    used[e as usize] = true;
                }
            }
            for (i, &(lo, hi, _)) in edges.iter().enumerate() {
                let crossing = (case >> lo & 1) != (case >> hi & 1);
                assert_eq!(used[i], crossing, "case {case} edge {i}");
            }
            // Only the empty and the full cube have no surface.
            assert_eq!(tris.is_empty(), case == 0 || case == 255);
        }
        // Case 1 (corner 0 inside) is one triangle.
        assert_eq!(case_table()[1].len(), 1);
    }

    /// A sphere's exact signed distance on a 1 cm grid: the mesh is closed (every edge shared
    /// by two triangles), consistently oriented (every directed edge once), its vertices on
    /// the sphere, its triangles and normals pointing out.
    #[test]
    fn sphere_mesh_is_closed_oriented_and_on_the_sphere() {
        use std::collections::HashSet;
        let voxel = 0.01;
        let mu = 0.03;
        let center = [0.013, -0.021, 0.507];
        let radius = 0.1;
        let options = crate::TsdfOptions {
            voxel_size_m: voxel,
            truncation_m: mu,
            ..crate::TsdfOptions::default()
        };
        let mut volume = TsdfVolume::new(options).unwrap();
        for z in 30..80i64 {
            for y in -15..15i64 {
                for x in -15..15i64 {
                    let p = [x, y, z].map(|g| (g as f64 + 0.5) * voxel);
                    let d = ((p[0] - center[0]).powi(2)
                        + (p[1] - center[1]).powi(2)
                        + (p[2] - center[2]).powi(2))
                    .sqrt()
                        - radius;
                    if d.abs() <= mu {
                        let voxel = Voxel {
                            tsdf: (d / mu) as f32,
                            weight: 1.0,
                            color: [10.0, 20.0, 30.0],
                            color_weight: 1.0,
                        };
                        volume.set_voxel([x, y, z], voxel);
                    }
                }
            }
        }
        let mesh = volume.extract_mesh();
        assert!(mesh.faces.len() > 1000, "{}", mesh.faces.len());
        let mut directed = HashSet::new();
        for f in &mesh.faces {
            for k in 0..3 {
                assert!(directed.insert((f[k], f[(k + 1) % 3])), "directed edge twice");
            }
        }
        for &(a, b) in &directed {
            assert!(directed.contains(&(b, a)), "open edge {a}-{b}");
        }
        let c = nalgebra::Vector3::from(center);
        let v = |i: u32| nalgebra::Vector3::from(mesh.vertices[i as usize].map(|x| x as f64));
        for (i, p) in mesh.vertices.iter().enumerate() {
            let p = nalgebra::Vector3::from(p.map(|x| x as f64));
            // Linear interpolation of the distance along a 1 cm edge: < 0.3 mm on r = 10 cm.
            assert!(((p - c).norm() - radius).abs() < 3e-4, "{}", (p - c).norm());
            let n = nalgebra::Vector3::from(mesh.normals[i].map(|x| x as f64));
            assert!(n.dot(&(p - c).normalize()) > 0.99);
            assert_eq!(mesh.colors[i], [10, 20, 30]);
        }
        for f in &mesh.faces {
            let n = (v(f[1]) - v(f[0])).cross(&(v(f[2]) - v(f[0])));
            assert!(n.dot(&(v(f[0]) - c)) > 0.0, "triangle faces inwards");
        }
    }
}
