//! `kfuse rig show|export` of a rig of several cameras (version 2, `geometry::multi_rig`),
//! through the binary. The rig is two Kinects facing each other 2 m apart, built here from
//! numbers written in this file, so every exported pose is checked against a value computed
//! independently of the exporters (a camera centre, a quaternion of a half turn).

mod common;

use std::path::Path;

use common::{kfuse, scratch};
use geometry::{MultiRig, Rig, RigidTransform};
use nalgebra::Vector3;

/// Sensor B's depth camera sits at (0, 0, 2) m in A's depth frame, turned half a turn about y
/// (facing A): X_B = R·X_A + T with R = rot_y(π) and T = (0, 0, 2) (−Rᵀ·T = (0, 0, 2)).
const B_CENTRE_M: [f64; 3] = [0.0, 0.0, 2.0];

fn two_kinects() -> MultiRig {
    let pair = geometry::synth::kinect_rig();
    let a = MultiRig::from_pair(&pair, Some("A"));
    let b_from_a = RigidTransform::from_axis_angle(
        Vector3::new(0.0, std::f64::consts::PI, 0.0),
        Vector3::new(0.0, 0.0, 2.0),
    );
    let mut cameras = a.cameras.clone();
    for mut c in MultiRig::from_pair(&pair, Some("B")).cameras {
        c.camera_from_reference = c.camera_from_reference.compose(&b_from_a);
        cameras.push(c);
    }
    MultiRig { reference: "A.depth".into(), cameras, calibration: None, rectified: false }
}

fn run(args: &[&str]) -> (bool, String, String) {
    let out = kfuse(args);
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The numbers of a YAML flow list `key: [a, b, c]` (the first such line after `after`).
fn yaml_list(text: &str, after: &str, key: &str) -> Vec<f64> {
    let start = text.find(after).unwrap_or_else(|| panic!("{after} not in\n{text}"));
    let line = text[start..]
        .lines()
        .find(|l| l.trim_start().starts_with(key))
        .unwrap_or_else(|| panic!("{key} not after {after}"));
    let inside = &line[line.find('[').unwrap() + 1..line.rfind(']').unwrap()];
    inside.split(',').map(|v| v.trim().parse().unwrap()).collect()
}

#[test]
fn show_lists_every_camera_and_its_pose() {
    let dir = scratch("rig-multi-show");
    let path = dir.join("rig4.json");
    kfuse_io::rig::write_multi_rig(&path, &two_kinects()).unwrap();
    let (ok, out, err) = run(&["rig", "show", s(&path)]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("kfuse rig of 4 cameras (2 sensor(s): A, B)"), "{out}");
    for name in ["A.depth", "A.color", "B.depth", "B.color"] {
        assert!(out.contains(&format!("camera \"{name}\"")), "{name} missing:\n{out}");
    }
    assert!(out.contains("centre at (0.000, 0.000, 2000.000) mm"), "{out}");
    assert!(!out.contains("WARN"), "a plausible rig warns:\n{out}");
}

#[test]
fn export_writes_one_file_per_camera_with_the_true_poses() {
    let dir = scratch("rig-multi-export");
    let path = dir.join("rig4.json");
    kfuse_io::rig::write_multi_rig(&path, &two_kinects()).unwrap();

    // ROS: the child B.depth's position in the parent frame is its centre, and its rotation
    // a half turn about y: the quaternion (0, ±1, 0, 0).
    let ros = dir.join("ros");
    let (ok, out, err) = run(&["rig", "export", s(&path), "--format", "ros", "--out", s(&ros)]);
    assert!(ok, "{out}\n{err}");
    for f in ["A.depth.yaml", "A.color.yaml", "B.depth.yaml", "B.color.yaml", "transforms.yaml"] {
        assert!(ros.join(f).is_file(), "{f} not written: {out}");
    }
    let tf = std::fs::read_to_string(ros.join("transforms.yaml")).unwrap();
    let t = yaml_list(&tf, "child: \"B.depth\"", "translation");
    let q = yaml_list(&tf, "child: \"B.depth\"", "rotation_xyzw");
    for k in 0..3 {
        // Two compositions of f64 rotations: well under a nanometre.
        assert!((t[k] - B_CENTRE_M[k]).abs() < 1e-12, "{t:?}");
    }
    assert!(q[0].abs() < 1e-12 && (q[1].abs() - 1.0).abs() < 1e-12 && q[2].abs() < 1e-12, "{q:?}");
    assert!(q[3].abs() < 1e-12, "{q:?}");

    // OpenCV: T of B.depth is the T put in, (0, 0, 2) m.
    let cv = dir.join("cv");
    let (ok, out, err) = run(&["rig", "export", s(&path), "--format", "opencv", "--out", s(&cv)]);
    assert!(ok, "{out}\n{err}");
    let yml = std::fs::read_to_string(cv.join("B.depth.yml")).unwrap();
    assert!(yml.contains("reference: \"A.depth\"") && yml.contains("T_units: m"), "{yml}");
    let t_block = &yml[yml.find("\nT:").unwrap()..];
    let data = t_block.lines().find(|l| l.trim_start().starts_with("data")).unwrap();
    let vals: Vec<f64> = data[data.find('[').unwrap() + 1..data.rfind(']').unwrap()]
        .split(',')
        .map(|v| v.trim().parse().unwrap())
        .collect();
    assert!((vals[2] - 2.0).abs() < 1e-12 && vals[0].abs() < 1e-12, "{vals:?}");

    // One sensor's pair as a two-camera rig: the Kinect pair it was made of.
    let pair_path = dir.join("pair.json");
    let (ok, out, err) = run(&[
        "rig",
        "export",
        s(&path),
        "--sensor",
        "B",
        "--format",
        "kfuse",
        "--out",
        s(&pair_path),
    ]);
    assert!(ok, "{out}\n{err}");
    let pair: Rig = kfuse_io::rig::read_pair(&pair_path).unwrap();
    let truth = geometry::synth::kinect_rig();
    assert_eq!((pair.depth, pair.color), (truth.depth, truth.color));
    let d = (pair.color_from_depth.matrix() - truth.color_from_depth.matrix()).abs().max();
    assert!(d < 1e-12, "B's colour_from_depth off by {d}");
}

#[test]
fn multi_rig_mistakes_are_one_line_each() {
    let dir = scratch("rig-multi-errors");
    let path = dir.join("rig4.json");
    kfuse_io::rig::write_multi_rig(&path, &two_kinects()).unwrap();
    let cases: [(&[&str], &str); 4] = [
        (&["--format", "iai-kinect2", "--out"], "pass --sensor SERIAL (its sensors: A, B)"),
        (&["--sensor", "C", "--format", "kfuse", "--out"], "sensor \"C\" has no depth camera"),
        (&["--format", "kfuse", "--out"], "exists; pass --overwrite"),
        (&["--format", "opencv", "--out"], "is a file"),
    ];
    for (args, want) in cases {
        let out_path = dir.join("out.x");
        std::fs::write(&out_path, "keep").unwrap();
        let target = if want.contains("exists") || want.contains("is a file") {
            out_path.clone()
        } else {
            dir.join("new-out")
        };
        let mut all = vec!["rig", "export", s(&path)];
        all.extend_from_slice(args);
        all.push(s(&target));
        let (ok, out, err) = run(&all);
        assert!(!ok, "{all:?} succeeded: {out}");
        assert!(err.contains(want), "{all:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{all:?}: not one line: {err}");
        assert_eq!(std::fs::read_to_string(&out_path).unwrap(), "keep", "{all:?} wrote");
        assert!(!dir.join("new-out").exists(), "{all:?} wrote new-out");
    }
    let v1 = dir.join("v1.json");
    std::fs::write(&v1, geometry::synth::kinect_rig().to_json()).unwrap();
    let (ok, _, err) =
        run(&["rig", "export", s(&v1), "--sensor", "A", "--format", "kfuse", "--out", "x.json"]);
    assert!(!ok && err.contains("is not a rig of several cameras"), "{err}");
}

/// A rig whose second sensor's translations are in millimetres (a user's unit mistake) is
/// shown with each problem once: the camera kilometres away, and the sensor's 52-m baseline.
#[test]
fn show_names_each_problem_of_a_unit_mistake_once() {
    let dir = scratch("rig-multi-mm");
    let mut rig = two_kinects();
    for c in &mut rig.cameras[2..] {
        c.camera_from_reference.translation *= 1000.0;
    }
    let path = dir.join("mm.json");
    std::fs::write(&path, rig.to_json()).unwrap();
    let (ok, out, err) = run(&["rig", "show", s(&path)]);
    assert!(ok, "{out}\n{err}");
    let warns: Vec<&str> = out.lines().filter(|l| l.contains("WARN")).collect();
    assert!(
        warns.iter().any(|w| w.contains("\"B.depth\" is 2000.0 m from the reference")),
        "{out}"
    );
    assert!(warns.iter().any(|w| w.contains("baseline")), "{out}");
    let mut distinct: Vec<String> =
        warns.iter().map(|w| w.replace("sensor \"B\"", "sensor B")).collect();
    distinct.sort();
    distinct.dedup();
    assert_eq!(distinct.len(), warns.len(), "a problem is listed twice:\n{out}");
}
