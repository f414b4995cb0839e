//! `kfuse demo --preset noisy` and `kfuse fuse` end to end for H4/H5 on noisy depth and the
//! lab figures: the removed fraction in summary.json, the H5 rule switch, `--no-figures`.

mod common;

use common::{kfuse, scratch};
use std::path::Path;

fn summary(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
}

fn listed_figures(s: &serde_json::Value) -> Vec<String> {
    s["files"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|f| f.as_str())
        .filter(|f| f.starts_with("task"))
        .map(String::from)
        .collect()
}

#[test]
fn noisy_demo_keeps_its_mesh_and_the_literal_rule_does_not() {
    let dir = scratch("mesh-noisy");
    let out = dir.join("demo");
    let o = kfuse(&["demo", "--preset", "noisy", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let fused = out.join("fused");
    let s = summary(&fused);
    assert_eq!(s["options"]["edge_rule"], "sample_scale");
    assert_eq!(s["options"]["mesh_source"], "depth_grid");
    let (before, after) = (
        s["summary"]["faces_before"].as_f64().unwrap(),
        s["summary"]["faces_after"].as_f64().unwrap(),
    );
    let removed = s["summary"]["faces_removed_fraction"].as_f64().unwrap();
    assert!((removed - (1.0 - after / before)).abs() < 1e-9, "{removed}");
    // The preset's depth jumps are ~1 % of the depth-grid faces (crates/geometry/tests/mesh_noisy.rs).
    assert!(removed > 0.005 && removed < 0.03, "sample-scale H5 removed {removed}");
    // Every figure drawn and listed.
    let figs = listed_figures(&s);
    assert_eq!(figs, (1..=8).map(|n| format!("task{n}.png")).collect::<Vec<_>>());
    for f in &figs {
        let img = image::open(fused.join(f)).unwrap();
        assert!(img.width() > 640, "{f}");
    }

    // The same inputs with the handout's literal rule and no figures.
    let input = out.join("input");
    let literal = dir.join("literal");
    let o = kfuse(&[
        "fuse",
        "--rig",
        input.join("rig.json").to_str().unwrap(),
        "--color",
        input.join("color.png").to_str().unwrap(),
        "--depth",
        input.join("depth.png").to_str().unwrap(),
        "--resample",
        "nearest",
        "--h5",
        "normal",
        "--no-figures",
        "--out",
        literal.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&literal);
    assert_eq!(s["options"]["edge_rule"], "normal");
    let removed_literal = s["summary"]["faces_removed_fraction"].as_f64().unwrap();
    assert!(removed_literal > 0.5, "the literal rule removed only {removed_literal}");
    assert!(listed_figures(&s).is_empty(), "--no-figures still lists figures");
    let on_disk = std::fs::read_dir(&literal)
        .unwrap()
        .filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().starts_with("task"))
        .count();
    assert_eq!(on_disk, 0);
    let _ = std::fs::remove_dir_all(&dir);
}
