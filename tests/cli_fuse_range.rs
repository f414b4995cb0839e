//! `kfuse fuse --depth-range MIN..MAX` (issue 46 item 4): depth samples outside the range are
//! not samples, for one frame and for every frame of a sequence alike. A simulated capture's
//! shot, with a range cut at its samples' 30th and 70th percentiles (ends half a millimetre
//! off the 16-bit millimetre values, so no sample sits on an end): the single frame's count
//! of samples equals the count taken here from the depth PNG, and the sequence's frame equals
//! the single frame byte for byte.

use std::path::{Path, PathBuf};

mod common;
use common::{kfuse_command as kfuse, stderr_of_success as ok};

fn read_png16(p: &Path) -> Vec<u16> {
    image::open(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())).into_luma16().into_raw()
}

fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap()
}

#[test]
fn depth_range_drops_the_same_samples_in_one_frame_and_a_sequence() {
    let dir = tempfile::tempdir().unwrap();
    let shots = dir.path().join("shots");
    ok(&kfuse()
        .args(["capture", "scene", "--backend", "sim", "--interval", "0", "--name", "a"])
        .arg("--out")
        .arg(&shots)
        .output()
        .unwrap());
    let rig = dir.path().join("rig.json");
    ok(&kfuse()
        .args(["rig", "import"])
        .arg(shots.join("kinect_params.json"))
        .arg("--out")
        .arg(&rig)
        .output()
        .unwrap());
    let mm = read_png16(&shots.join("a_depth.png"));
    let mut sorted: Vec<u16> = mm.iter().copied().filter(|&v| v > 0).collect();
    sorted.sort_unstable();
    let (lo, hi) = (sorted[sorted.len() * 3 / 10], sorted[sorted.len() * 7 / 10]);
    let range = format!("{lo}.5mm..{hi}.5mm");
    let inside = mm.iter().filter(|&&v| v > lo && v <= hi).count();
    eprintln!("--depth-range {range}: {inside} of {} samples inside", sorted.len());
    assert!(inside > sorted.len() / 3 && inside < sorted.len() * 2 / 3);

    let single = |name: &str, range: Option<&str>| -> PathBuf {
        let out = dir.path().join(name);
        let mut cmd = kfuse();
        cmd.args(["fuse", "--rig"])
            .arg(&rig)
            .arg("--color")
            .arg(shots.join("a_color.jpg"))
            .arg("--depth")
            .arg(shots.join("a_depth.png"))
            .args(["--resample", "nearest", "--no-figures"]);
        if let Some(r) = range {
            cmd.args(["--depth-range", r]);
        }
        ok(&cmd.arg("--out").arg(&out).output().unwrap());
        out
    };
    let clipped = single("single-clipped", Some(&range));
    let whole = single("single-whole", None);
    let valid = |out: &Path| summary(out)["summary"]["valid_depth_pixels"].as_u64().unwrap();
    assert_eq!(valid(&clipped), inside as u64);
    assert_eq!(valid(&whole), sorted.len() as u64);
    assert_ne!(
        read_png16(&clipped.join("depth_zbuffer.png")),
        read_png16(&whole.join("depth_zbuffer.png"))
    );

    let seq = dir.path().join("seq");
    ok(&kfuse()
        .args(["fuse", "--frames"])
        .arg(&shots)
        .args(["--depth-range", &range, "--write", "holes", "--out"])
        .arg(&seq)
        .output()
        .unwrap());
    assert!(
        read_png16(&seq.join("depth/000000.png")) == read_png16(&clipped.join("depth_zbuffer.png")),
        "the sequence's frame with --depth-range differs from kfuse fuse's of the same frame"
    );
    let gray = |p: PathBuf| image::open(&p).unwrap().into_luma8().into_raw();
    assert!(gray(seq.join("holes/000000.png")) == gray(clipped.join("hole_mask.png")));

    // A range without a unit is refused by name before any work.
    let out = dir.path().join("refused");
    let run = kfuse()
        .args(["fuse", "--frames"])
        .arg(&shots)
        .args(["--depth-range", "0.5..2", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        !run.status.success() && err.contains("--depth-range") && err.contains("no unit"),
        "{err}"
    );
    assert!(!out.exists());
}
