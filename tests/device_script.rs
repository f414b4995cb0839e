//! `benches/device.sh` (issue 33): a bundle made from this test build's kfuse binary, run in
//! `--quick` mode on whatever adapter wgpu finds (lavapipe in CI), gives a results file with the
//! adapter's name and the GPU sequence's figures, finite and positive, every stage of its
//! table present. The GPU criterion benches need the bench build that `device.sh --prepare`
//! makes; this test builds nothing, so they run only when [`BENCH_EXES_ENV`] names their
//! executables (as `device.sh --bench-exe` takes them) and are then asserted to have run and
//! measured; without it, or without a GPU adapter, a visible skip that says which (a failure
//! where `KFUSE_REQUIRE_GPU_BENCHES` is `1`: `.ci/run` builds the benches and names them).

use geometry::testdata::shared_data_or_skip;
use std::path::Path;
use std::process::Command;

/// Frames of the recording in the quick run: enough for the pipeline to start two workers.
const FRAMES: &str = "4";
/// The device tool's limit on what it carries (its README): the bundle must fit.
const BUNDLE_LIMIT_BYTES: u64 = 64 << 20;

/// `device.sh`'s bundle limit for this test's bundle, MiB: the test build's kfuse (about 40
/// MiB) and its two GPU bench executables (about 11 MiB each) fit with room to spare.
const TEST_BUILD_BUNDLE_LIMIT_MIB: &str = "128";
/// The GPU criterion benches of `device.sh` (its `GPU_BENCHES`), as `PACKAGE/BENCH`.
const GPU_BENCHES: [&str; 2] = ["fusion-gpu/decode", "kfuse/fusion_gpu"];
/// Names the GPU benches' executables, `PACKAGE/BENCH=EXE` separated by spaces (what
/// `device.sh --bench-exe` takes; `cargo bench --workspace --bench decode --bench fusion_gpu
/// --no-run` prints their paths). Unset: the benches are a visible skip.
const BENCH_EXES_ENV: &str = "KFUSE_GPU_BENCH_EXES";
/// `1`: the GPU benches must run (an unset [`BENCH_EXES_ENV`] fails instead of skipping).
const REQUIRE_BENCHES_ENV: &str = "KFUSE_REQUIRE_GPU_BENCHES";
/// The stages of the sequence's table, as `sequence_e2e.sh` prints them and
/// `render_tables.py` names them: an empty or partial `stage_ms` is a failure.
const STAGES: [&str; 5] = ["read", "decode", "register", "encode", "write"];
const TEST: &str = "device_script_quick_run_on_a_bundle_of_the_test_build";

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
    let Some(data) = shared_data_or_skip(TEST) else {
        return;
    };
    let bench_exes: Vec<String> = std::env::var(BENCH_EXES_ENV)
        .map(|v| v.split_whitespace().map(str::to_string).collect())
        .unwrap_or_default();
    assert!(
        !bench_exes.is_empty() || std::env::var(REQUIRE_BENCHES_ENV).as_deref() != Ok("1"),
        "{REQUIRE_BENCHES_ENV}=1 but {BENCH_EXES_ENV} names no GPU bench executable ({})",
        GPU_BENCHES.join(", ")
    );
    for spec in &bench_exes {
        let (bench, exe) = spec
            .split_once('=')
            .unwrap_or_else(|| panic!("{BENCH_EXES_ENV}: {spec} is not PACKAGE/BENCH=EXE"));
        assert!(
            GPU_BENCHES.contains(&bench),
            "{BENCH_EXES_ENV}: {bench} is not one of {GPU_BENCHES:?}"
        );
        assert!(Path::new(exe).is_file(), "{BENCH_EXES_ENV}: {exe} is not a file");
    }
    let root = &manifest_dir();
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
        .args(bench_exes.iter().flat_map(|spec| ["--bench-exe", spec.as_str()]))
        .env("KFUSE_SHARED_DATA", &data)
        // The test profile's bench executables are larger than the bench profile's that
        // `--prepare` builds (measured: 11 MiB each, 69 MiB with the test build's kfuse): the
        // script's limit is raised for them and the 64 MiB checked below without them.
        .env("KFUSE_BUNDLE_LIMIT_MIB", TEST_BUILD_BUNDLE_LIMIT_MIB)
        .output()
        .unwrap();
    assert!(out.status.success(), "prepare: {}", String::from_utf8_lossy(&out.stderr));
    let benches_dir = bundle.join("bin/benches");
    let bench_bytes = if benches_dir.is_dir() { dir_size(&benches_dir) } else { 0 };
    let size = dir_size(&bundle) - bench_bytes;
    assert!(size <= BUNDLE_LIMIT_BYTES, "bundle of {size} bytes without the benches");
    for f in [
        "bin/kfuse",
        "device.sh",
        "render_tables.py",
        "sequence_e2e.sh",
        "data/kinect-v2-vectors/frames/scene.raw",
    ] {
        assert!(bundle.join(f).is_file(), "bundle lacks {f}");
    }
    for spec in &bench_exes {
        let bench = spec.split_once('=').unwrap().0;
        assert!(bundle.join("bin/benches").join(bench).is_file(), "bundle lacks {bench}");
    }
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
        test_skip::skip(TEST, "no GPU adapter: neither the GPU sequence nor the GPU benches ran");
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
    let stage_ms = runs[0]["stage_ms"].as_object().unwrap();
    let mut names: Vec<&str> = stage_ms.keys().map(String::as_str).collect();
    names.sort_unstable();
    let mut want = STAGES.to_vec();
    want.sort_unstable();
    assert_eq!(names, want, "the sequence's stage table: {seq}");
    for (stage, ms) in stage_ms {
        let v = ms.as_f64().unwrap();
        assert!(v.is_finite() && v >= 0.0, "{stage} = {v}");
    }
    // Four frames went through every stage: the stages' times together are not all zero.
    let total: f64 = stage_ms.values().map(|v| v.as_f64().unwrap()).sum();
    assert!(total > 0.0, "no stage took any time: {seq}");
    let benches = r["benches"].as_object().unwrap();
    if bench_exes.is_empty() {
        assert!(benches.is_empty(), "{benches:?}");
        test_skip::skip(
            TEST,
            &format!(
                "the GPU criterion benches ({}): {BENCH_EXES_ENV} does not name their executables (the bench build of device.sh --prepare); the GPU sequence ran",
                GPU_BENCHES.join(", ")
            ),
        );
    } else {
        assert_eq!(benches.len(), bench_exes.len(), "{benches:?}");
        for (bench, b) in benches {
            assert_eq!(b["status"], "ok", "{bench}: {b}");
            let results = b["results"].as_object().unwrap();
            assert!(!results.is_empty(), "{bench} measured nothing: {b}");
            println!("{bench}: {} benchmarks measured", results.len());
            for (name, x) in results {
                let ns = x["median_ns"].as_f64().unwrap();
                assert!(ns.is_finite() && ns > 0.0, "{bench} {name}: median {ns} ns");
            }
        }
    }
    let _ = std::fs::remove_dir_all(&tmp);
}

/// This package's folder from the `CARGO_MANIFEST_DIR` cargo sets when it runs the test, not
/// the path compiled in: a test binary reused from a checkout at another path (a shared target
/// directory) must read this checkout's files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map(std::path::PathBuf::from).expect("run by cargo test")
}
