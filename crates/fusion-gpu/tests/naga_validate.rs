//! Every `.wgsl` in `shaders/` parses and validates with naga (no GPU needed) as the crate
//! compiles it (the decode shaders with their shared preamble), and the crate compiles all
//! of them.

fn validate(name: &str, source: &str) {
    let module = naga::front::wgsl::parse_str(source)
        .unwrap_or_else(|e| panic!("{name} does not parse:\n{}", e.emit_to_string(source)));
    // Default capabilities: what every WebGPU adapter has (no f64, no 64-bit atomics, ...).
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::default(),
    )
    .validate(&module)
    .unwrap_or_else(|e| panic!("{name} does not validate:\n{}", e.emit_to_string(source)));
    assert!(!module.entry_points.is_empty(), "{name} has no entry point");
    for ep in &module.entry_points {
        assert_eq!(
            ep.stage,
            naga::ShaderStage::Compute,
            "{name}: {} is not a compute entry point",
            ep.name
        );
    }
}

#[test]
fn every_shader_file_validates_with_naga() {
    let dir = manifest_dir().join("../../shaders");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "wgsl"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no .wgsl in {}", dir.display());
    // What the crate compiles: each file, with the decode shaders' shared preamble
    // (`shaders/include/`) put before them.
    for (name, source) in fusion_gpu::shaders::ALL {
        let path = dir.join(name);
        let on_disk =
            std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(source.ends_with(&on_disk), "{name}: the compiled source is not the file's");
        validate(&path.display().to_string(), source);
    }
    // Every file on disk is one the crate compiles in, and vice versa.
    let compiled: Vec<&str> = fusion_gpu::shaders::ALL.iter().map(|(n, _)| *n).collect();
    let on_disk: Vec<String> =
        files.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
    assert_eq!(on_disk, compiled, "shaders/ and fusion_gpu::shaders::ALL disagree");
}

#[test]
fn a_broken_shader_is_rejected() {
    // The validator is not a rubber stamp: an atomicMin on a non-atomic fails.
    let bad = "@group(0) @binding(0) var<storage, read_write> b: array<u32>;\n\
               @compute @workgroup_size(1) fn main() { atomicMin(&b[0], 1u); }";
    let parsed = naga::front::wgsl::parse_str(bad);
    let rejected = match parsed {
        Err(_) => true,
        Ok(m) => naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::default(),
        )
        .validate(&m)
        .is_err(),
    };
    assert!(rejected);
}

/// This package's folder from the `CARGO_MANIFEST_DIR` cargo sets when it runs the test, not
/// the path compiled in: a test binary reused from a checkout at another path (a shared target
/// directory) must read this checkout's files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map(std::path::PathBuf::from).expect("run by cargo test")
}
