//! `benches/device.sh` (issue 33): a bundle made from this test build's kfuse binary, run in
//! `--quick` mode on whatever adapter wgpu finds (lavapipe in CI), gives a results file with the
//! adapter's name and the GPU sequence's figures, finite and positive. The GPU criterion benches
//! need the bench build that `device.sh --prepare` makes; this test builds nothing, so the
//! bundle has no bench executable and that part is a visible skip.

use geometry::testdata::shared_data_or_skip;
use std::path::Path;
use std::process::Command;

/// Frames of the recording in the quick run: enough for the pipeline to start two workers.
const FRAMES: &str = "4";
/// The device tool's limit on what it carries (its README): the bundle must fit.
const BUNDLE_LIMIT_BYTES: u64 = 64 << 20;

fn dir_size(p: &Path) -> u64 {
    std::fs::read_dir(p)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            let m = e.metadata().unwrap();
            if m.is_dir() { dir_size(&e.path()) } else { m.len() }
        })
        .sum()
}

#[test]
fn device_script_quick_run_on_a_bundle_of_the_test_build() {
    let Some(data) = shared_data_or_skip("device_script_quick_run_on_a_bundle_of_the_test_build")
    else {
        return;
    };
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let tmp = Path::new(env!("CARGO_TARGET_TMPDIR")).join("device-script");
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).unwrap();
    let bundle = tmp.join("bundle");
    let out = Command::new("bash")
        .arg(root.join("benches/device.sh"))
        .arg("--prepare")
        .arg(&bundle)
        .arg("--kfuse")
        .arg(env!("CARGO_BIN_EXE_kfuse"))
        .env("KFUSE_SHARED_DATA", &data)
        .output()
        .unwrap();
    assert!(out.status.success(), "prepare: {}", String::from_utf8_lossy(&out.stderr));
    let size = dir_size(&bundle);
    assert!(size <= BUNDLE_LIMIT_BYTES, "bundle of {size} bytes");
    for f in [
        "bin/kfuse",
        "device.sh",
        "render_tables.py",
        "sequence_e2e.sh",
        "data/kinect-v2-vectors/frames/scene.raw",
    ] {
        assert!(bundle.join(f).is_file(), "bundle lacks {f}");
    }
    test_skip::skip(
        "device_script_quick_run_on_a_bundle_of_the_test_build",
        "the GPU criterion benches need the bench build of device.sh --prepare; only the GPU sequence runs here",
    );
    let results = tmp.join("device-run.json");
    let out = Command::new("bash")
        .arg(bundle.join("device.sh"))
        .args(["--quick", "--frames", FRAMES, "--results"])
        .arg(&results)
        .env_remove("KFUSE_SHARED_DATA")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    if !out.status.success()
        && stderr.contains("no GPU adapter")
        && std::env::var("KFUSE_REQUIRE_GPU").as_deref() != Ok("1")
    {
        test_skip::skip("device_script_quick_run_on_a_bundle_of_the_test_build", "no GPU adapter");
        return;
    }
    assert!(out.status.success(), "run: {stderr}\n{}", String::from_utf8_lossy(&out.stdout));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&results).unwrap()).unwrap();
    let adapter = r["gpu_adapter"].as_str().unwrap();
    assert!(!adapter.is_empty());
    assert!(String::from_utf8_lossy(&out.stdout).contains(&format!("adapter: {adapter}")));
    assert_eq!(r["mode"], "quick");
    let seq = &r["steps"]["sequence_e2e"];
    assert_eq!(seq["status"], "ok", "{seq}");
    assert_eq!(seq["engine"], "gpu");
    let runs = seq["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 1, "{seq}");
    assert_eq!(runs[0]["frames"].as_u64().unwrap(), FRAMES.parse::<u64>().unwrap());
    assert_eq!(runs[0]["missing"], 0);
    for k in ["pipeline_fps", "process_fps"] {
        let v = runs[0][k].as_f64().unwrap();
        assert!(v.is_finite() && v > 0.0, "{k} = {v}");
    }
    for (stage, ms) in runs[0]["stage_ms"].as_object().unwrap() {
        let v = ms.as_f64().unwrap();
        assert!(v.is_finite() && v >= 0.0, "{stage} = {v}");
    }
    let _ = std::fs::remove_dir_all(&tmp);
}
