//! `kfuse fuse --gpu` / `--gpu auto` end to end: the GPU path writes the same files as the
//! CPU path, names its adapter, and fails (or falls back) clearly without one.

use geometry::testdata::shared_data_or_skip as shared_data;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs kfuse as on a headless machine (no XDG_RUNTIME_DIR, no Wayland display), where
/// listing the Vulkan adapters used to print libwayland's "XDG_RUNTIME_DIR is invalid" line.
fn kfuse(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kfuse"))
        .args(args)
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("WAYLAND_SOCKET")
        .output()
        .expect("run kfuse")
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kfuse-gpu-e2e-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch folder");
    dir
}

fn summary_without_timings(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).expect("summary.json");
    let mut v: serde_json::Value = serde_json::from_str(&text).expect("summary.json is JSON");
    v["summary"]["timings_ms"] = serde_json::Value::Null;
    v["summary"].clone()
}

#[test]
fn gpu_flag_gives_the_cpu_results_or_a_clear_error() {
    let test = "gpu_flag_gives_the_cpu_results_or_a_clear_error";
    let Some(data) = shared_data(test) else { return };
    let mat = data.join("course/synthdata.mat");
    let mat = mat.to_str().expect("utf-8 path");
    let dir = scratch("flag");
    let (cpu, gpu, auto) = (dir.join("cpu"), dir.join("gpu"), dir.join("auto"));
    let o = kfuse(&[
        "fuse",
        "--mat",
        mat,
        "--no-figures",
        "--resample",
        "nearest",
        "--out",
        cpu.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "CPU fuse failed: {}", String::from_utf8_lossy(&o.stderr));

    // --gpu auto always succeeds, with the CPU's numbers.
    let o = kfuse(&[
        "fuse",
        "--mat",
        mat,
        "--no-figures",
        "--resample",
        "nearest",
        "--gpu",
        "auto",
        "--out",
        auto.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "--gpu auto failed: {err}");
    assert!(!err.contains("XDG_RUNTIME_DIR"), "noise on a successful run: {err}");
    assert!(
        err.contains("GPU adapter: ") || err.contains("warning: no GPU adapter found"),
        "{err}"
    );
    assert_eq!(summary_without_timings(&auto), summary_without_timings(&cpu));

    // --gpu: the adapter is named and every output file matches the CPU's byte for byte
    // (the GPU stages are bit-identical); without an adapter, a non-zero exit that says what
    // to install.
    let o = kfuse(&[
        "fuse",
        "--mat",
        mat,
        "--no-figures",
        "--resample",
        "nearest",
        "--gpu",
        "--out",
        gpu.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    if o.status.success() {
        assert!(err.contains("GPU adapter: "), "{err}");
        assert!(!err.contains("XDG_RUNTIME_DIR"), "noise on a successful run: {err}");
        assert_eq!(summary_without_timings(&gpu), summary_without_timings(&cpu));
        for f in [
            "cloud.ply",
            "depth_zbuffer.png",
            "depth_nearest.png",
            "depth_filled.png",
            "hole_mask.png",
            "color_on_depth.png",
            "mesh.ply",
        ] {
            let a = std::fs::read(cpu.join(f)).expect("CPU output");
            let b = std::fs::read(gpu.join(f)).expect("GPU output");
            assert!(a == b, "{test}: {f} differs between --gpu and the CPU path");
        }
    } else {
        assert!(err.contains("no GPU adapter found; install mesa-vulkan-drivers"), "{err}");
        assert!(
            std::env::var("KFUSE_REQUIRE_GPU").map_or(true, |v| v != "1"),
            "{test}: no adapter in CI: {err}"
        );
        assert!(!gpu.exists(), "a failed --gpu run left an output folder");
        test_skip::skip(&format!("{test} (GPU half)"), "no GPU adapter");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
