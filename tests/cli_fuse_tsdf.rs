//! `kfuse fuse --tsdf`: the simulated 3-Kinect ring (`geometry::synth::kinect_ring_preset`,
//! with the Kinect's z² noise and flying pixels) written as 16-bit PNG depth and PNG colour,
//! fused by the binary into a TSDF, and `tsdf_mesh.ply` checked against the scene's true
//! surfaces (the shapes' analytic distance, not the TSDF code) and against the merged cloud
//! of the same run; bad `--voxel-size`/`--truncation` values refused with one line and nothing
//! written.

mod common;

use std::path::Path;

use common::{kfuse, scratch};
use geometry::synth::{KinectNoise, KinectRing, Shape, kinect_ring_preset, render_ring};
use nalgebra::Vector3;

/// Voxel size of the run, metres: 10 mm, which keeps the debug-build test within seconds
/// (the 5 mm figures are in `crates/tsdf/tests/ring.rs`).
const VOXEL: &str = "0.01";
/// Bar on the median distance of the mesh's vertices to the true surfaces, mm: 1.0. The
/// library's test on the same noisy ring measures 0.39 mm at 10 mm voxels from float depth;
/// the 16-bit millimetre PNG adds a uniform ±0.5 mm step to every sample (0.29 mm rms before
/// the TSDF averages it). The run must also beat its own merged cloud's median.
const MEDIAN_BAR_MM: f64 = 1.0;

fn write_inputs(dir: &Path, ring: &KinectRing) -> Vec<String> {
    let frames = render_ring(ring, Some(&KinectNoise::default()));
    kfuse_io::rig::write_multi_rig(&dir.join("rig3.json"), &ring.rig).unwrap();
    let mut args = Vec::new();
    for (serial, f) in ring.serials.iter().zip(&frames) {
        let depth = dir.join(format!("{serial}_depth.png"));
        kfuse_io::images::write_depth_png16(&depth, &f.depth).unwrap();
        let color = dir.join(format!("{serial}_color.png"));
        kfuse_io::images::write_color_png(&color, &f.color).unwrap();
        args.push(format!("{serial}={},{}", color.display(), depth.display()));
    }
    args
}

/// Distance from `p` (world frame) to the surface of the union of the ring's solids, from the
/// shapes' signed distance functions (the ring has boxes and a sphere).
fn distance_to_truth(ring: &KinectRing, p: &Vector3<f64>) -> f64 {
    let sdf = |shape: &Shape| match shape {
        Shape::Sphere { center, radius } => (p - center).norm() - radius,
        Shape::Box { center, half_extents, rotation } => {
            let q = (rotation.inverse() * (p - center)).abs() - half_extents;
            q.map(|v| v.max(0.0)).norm() + q.x.max(q.y).max(q.z).min(0.0)
        }
        other => panic!("the ring has no {other:?}"),
    };
    ring.world.objects.iter().map(|o| sdf(&o.shape)).fold(f64::INFINITY, f64::min).abs()
}

/// Median distance to the truth of the points of a PLY in the rig's reference frame.
fn median_error_mm(ring: &KinectRing, ply: &Path) -> (f64, usize) {
    let cloud = kfuse_io::ply::read_cloud_ply(ply, None).unwrap();
    let world_from_ref = ring.depth_from_world[0].inverse();
    let mut e: Vec<f64> = cloud
        .points
        .iter()
        .map(|p| {
            let p = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            distance_to_truth(ring, &world_from_ref.apply(&p)) * 1e3
        })
        .collect();
    e.sort_by(f64::total_cmp);
    (e[e.len() / 2], e.len())
}

#[test]
fn fuse_tsdf_of_three_kinects_against_the_truth() {
    let dir = scratch("fuse-tsdf");
    let ring = kinect_ring_preset();
    let sensors = write_inputs(&dir, &ring);
    let rig = dir.join("rig3.json");
    let out = dir.join("fused");
    let mut args = vec!["fuse", "--rig", rig.to_str().unwrap()];
    for s in &sensors {
        args.extend(["--sensor", s.as_str()]);
    }
    let base = args.clone();
    args.extend(["--tsdf", "--voxel-size", VOXEL, "--out", out.to_str().unwrap()]);
    let run = kfuse(&args);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{}{stdout}", String::from_utf8_lossy(&run.stderr));
    assert!(stdout.contains("tsdf:") && stdout.contains("tsdf_mesh.ply"), "{stdout}");

    // The mesh: vertex normals and colours in the header, faces, unit normals.
    let mesh_path = out.join("tsdf_mesh.ply");
    let bytes = std::fs::read(&mesh_path).unwrap();
    let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap();
    let header = String::from_utf8_lossy(&bytes[..end]);
    for p in ["property float nx", "property uchar red", "element face"] {
        assert!(header.contains(p), "{header}");
    }
    let (tsdf_median, vertices) = median_error_mm(&ring, &mesh_path);
    let (cloud_median, points) = median_error_mm(&ring, &out.join("cloud.ply"));
    let (surface_median, surface_points) = median_error_mm(&ring, &out.join("tsdf_cloud.ply"));
    println!(
        "tsdf mesh: {vertices} vertices, median {tsdf_median:.3} mm; merged cloud: {points} points, median {cloud_median:.3} mm"
    );
    assert_eq!(surface_points, vertices);
    assert_eq!(surface_median, tsdf_median);
    assert!(tsdf_median < MEDIAN_BAR_MM, "{tsdf_median} mm");
    assert!(tsdf_median < cloud_median, "{tsdf_median} mm vs the cloud's {cloud_median} mm");
    let cloud = kfuse_io::ply::read_cloud_ply(&mesh_path, None).unwrap();
    assert_eq!(cloud.colors.len(), vertices);
    // The same mesh as OBJ, read by `tobj`: as many vertices and faces, normals and colours.
    let (models, _) = tobj::load_obj(
        out.join("tsdf_mesh.obj"),
        &tobj::LoadOptions { triangulate: true, ..Default::default() },
    )
    .unwrap();
    let m = &models[0].mesh;
    assert_eq!(m.positions.len(), 3 * vertices);
    assert_eq!(m.normals.len(), 3 * vertices);
    assert_eq!(m.vertex_color.len(), 3 * vertices);
    let ply_faces = header
        .lines()
        .find_map(|l| l.strip_prefix("element face "))
        .and_then(|n| n.trim().parse::<usize>().ok())
        .unwrap();
    assert_eq!(m.indices.len(), 3 * ply_faces);
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    let t = &summary["tsdf"];
    assert_eq!(t["voxel_size_m"], 0.01);
    assert_eq!(t["mesh_vertices"].as_u64().unwrap() as usize, vertices);
    assert_eq!(t["voxels_updated"].as_array().unwrap().len(), 3);

    // Bad values: one line naming the flag, non-zero exit, nothing written.
    let bad_out = dir.join("bad");
    let run_bad = |extra: &[&str]| {
        let mut a = base.clone();
        a.extend_from_slice(extra);
        a.extend(["--out", bad_out.to_str().unwrap()]);
        let r = kfuse(&a);
        assert!(!r.status.success(), "{extra:?}");
        assert!(!bad_out.exists(), "{} was written", bad_out.display());
        let err = String::from_utf8_lossy(&r.stderr).into_owned();
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        err
    };
    for v in ["0", "1e-9", "10", "NaN", "-0.01"] {
        let e = run_bad(&["--tsdf", "--voxel-size", v]);
        assert!(e.contains("--voxel-size") && e.contains("0.001–0.5 m"), "{v}: {e}");
    }
    for t in ["0.001", "5", "NaN"] {
        let e = run_bad(&["--tsdf", "--truncation", t]);
        assert!(e.contains("--truncation") && e.contains("truncation"), "{t}: {e}");
    }
    let e = run_bad(&["--voxel-size", "0.01"]);
    assert!(e.contains("add --tsdf"), "{e}");
    // --frames-max limits a recording's frames; several Kinects fuse one shot (it was
    // accepted and ignored).
    let e = run_bad(&["--tsdf", "--frames-max", "2"]);
    assert!(e.contains("--frames-max") && e.contains("--shot"), "{e}");
    // 1 mm voxels: the ring's band needs more blocks than the default 2 GiB bound.
    let e = run_bad(&["--tsdf", "--voxel-size", "0.001"]);
    assert!(e.contains("GiB bound") && e.contains("larger --voxel-size"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
