//! `kfuse fuse --rig RIG3.json --sensor SERIAL=COLOR,DEPTH ...`: the simulated 3-Kinect ring
//! (`geometry::synth::kinect_ring_preset`, with the Kinect's z² noise and flying pixels)
//! written as PNG/JPEG files, fused by the binary, and its merged cloud checked against the
//! scene's truth; bad inputs refused with one line and nothing written.

mod common;

use std::path::Path;

use common::{kfuse, scratch};
use geometry::synth::{KinectNoise, KinectRing, kinect_ring_preset, render_ring};
use nalgebra::Vector3;

/// Issue 32's consistency bar, mm.
const CONSISTENCY_BAR_MM: f64 = 2.0;
/// Bound on the merged cloud's median distance to the true surface, mm: the sensors' own
/// median error is ~1.6 mm (σ = 1.5 mm·z² at 1.3–2 m; `fusion::multi`'s tests) and the
/// 16-bit millimetre PNG adds a uniform ±0.5 mm step (0.29 mm rms).
const MEDIAN_ERROR_BOUND_MM: f64 = 2.0;

fn write_inputs(dir: &Path, ring: &KinectRing) -> Vec<String> {
    let frames = render_ring(ring, Some(&KinectNoise::default()));
    kfuse_io::rig::write_multi_rig(&dir.join("rig3.json"), &ring.rig).unwrap();
    let mut args = Vec::new();
    for (k, (serial, f)) in ring.serials.iter().zip(&frames).enumerate() {
        let depth = dir.join(format!("{serial}_depth.png"));
        kfuse_io::images::write_depth_png16(&depth, &f.depth).unwrap();
        // Sensor 1's colour as a JPEG (what a Kinect delivers), the others as PNG.
        let color = dir.join(format!("{serial}_color.{}", if k == 1 { "jpg" } else { "png" }));
        if k == 1 {
            let (w, h) = f.color.size();
            let bytes: Vec<u8> = f.color.data().iter().flatten().copied().collect();
            image::RgbImage::from_raw(w as u32, h as u32, bytes).unwrap().save(&color).unwrap();
        } else {
            kfuse_io::images::write_color_png(&color, &f.color).unwrap();
        }
        args.push(format!("{serial}={},{}", color.display(), depth.display()));
    }
    args
}

/// Distance of a world point to the scene along the rays of the sensors: the smallest
/// distance between `p` and the first hit on the ray from any sensor's centre through `p`
/// (the sensor that measured `p` sees its surface along that ray).
fn distance_to_truth(ring: &KinectRing, p: &Vector3<f64>) -> f64 {
    ring.depth_from_world
        .iter()
        .filter_map(|d| {
            let o = d.inverse().translation;
            let hit = ring.world.cast(&o, &(p - o))?;
            Some((hit.point - p).norm())
        })
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn fuse_three_kinects_into_one_cloud_against_the_truth() {
    let dir = scratch("fuse-multi");
    let ring = kinect_ring_preset();
    let sensors = write_inputs(&dir, &ring);
    let out = dir.join("fused");
    let rig = dir.join("rig3.json");
    let mut args = vec!["fuse", "--rig", rig.to_str().unwrap()];
    for s in &sensors {
        args.extend(["--sensor", s.as_str()]);
    }
    args.extend(["--out", out.to_str().unwrap()]);
    let run = kfuse(&args);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{}{stdout}", String::from_utf8_lossy(&run.stderr));
    println!("{stdout}");

    let cloud = kfuse_io::ply::read_cloud_ply(&out.join("cloud.ply"), None).unwrap();
    assert!(cloud.points.len() > 150_000, "{} points", cloud.points.len());
    assert_eq!(cloud.colors.len(), cloud.points.len());
    let world_from_ref = ring.depth_from_world[0].inverse();
    let mut errors: Vec<f64> = cloud
        .points
        .iter()
        .step_by(7)
        .map(|p| {
            let q = world_from_ref.apply(&Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64));
            distance_to_truth(&ring, &q)
        })
        .collect();
    errors.sort_by(f64::total_cmp);
    let median_mm = errors[errors.len() / 2] * 1e3;
    println!(
        "merged cloud: {} points, median distance to the true surface {median_mm:.3} mm",
        cloud.points.len()
    );
    assert!(median_mm <= MEDIAN_ERROR_BOUND_MM, "{median_mm} mm");

    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    let pairs = summary["consistency"].as_array().unwrap();
    assert_eq!(pairs.len(), 3);
    for p in pairs {
        let mm = p["tile_median_mm"].as_f64().unwrap();
        assert!(mm <= CONSISTENCY_BAR_MM && p["pixels"].as_u64().unwrap() > 2000, "{p}");
    }
    let in_cloud: u64 = summary["sensors"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["points_in_cloud"].as_u64().unwrap())
        .sum();
    assert_eq!(in_cloud as usize, cloud.points.len());
    assert_eq!(summary["view"], "RING0.color");
    // The rig written beside the cloud is the rig given.
    let back = calib::rig_io::load_multi(&out.join("rig.json")).unwrap().expect("a version-2 rig");
    assert_eq!(back.names(), ring.rig.names());
    let zbuffer = kfuse_io::images::read_depth(&out.join("depth_zbuffer.png"), 0.001).unwrap();
    assert_eq!(zbuffer.size(), (1920, 1080));

    // Bad inputs: one line, non-zero exit, nothing written.
    let bad_out = dir.join("bad");
    let bad_out_s = bad_out.to_str().unwrap().to_string();
    let run_bad = |sensor_args: &[String]| {
        let mut a = vec!["fuse".to_string(), "--rig".into(), rig.display().to_string()];
        for s in sensor_args {
            a.extend(["--sensor".into(), s.clone()]);
        }
        a.extend(["--out".into(), bad_out_s.clone()]);
        let refs: Vec<&str> = a.iter().map(String::as_str).collect();
        let r = kfuse(&refs);
        assert!(!r.status.success());
        assert!(!bad_out.exists(), "{} was written", bad_out.display());
        let err = String::from_utf8_lossy(&r.stderr).into_owned();
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        err
    };
    let mut unknown = sensors.clone();
    unknown[2] = unknown[2].replacen("RING2", "NOPE", 1);
    let e = run_bad(&unknown);
    assert!(e.contains("no sensor NOPE") && e.contains("RING0, RING1, RING2"), "{e}");
    let e = run_bad(&sensors[..2]);
    assert!(e.contains("sensor RING2") && e.contains("has no images"), "{e}");
    let mut wrong = sensors.clone();
    wrong[1] = format!(
        "RING1={},{}",
        dir.join("RING0_depth.png").display(),
        dir.join("RING1_depth.png").display()
    );
    let e = run_bad(&wrong);
    assert!(
        e.contains("colour image") && e.contains("512x424") && e.contains("RING1.color"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
