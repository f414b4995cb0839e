//! Locating and loading the shared Kinect v2 test vectors (used by tests, benches and the
//! CLI's simulated device). Not part of the driver proper.

use std::path::{Path, PathBuf};

use crate::error::{KinectError, Result};

/// Environment variable overriding the shared data folder.
pub const DATA_ENV: &str = "KFUSE_SHARED_DATA";

/// The vectors folder `<shared data>/kinect-v2-vectors`, if present. Uses `KFUSE_SHARED_DATA`
/// or `<workspace>/../shared/data` (from this crate's manifest directory).
pub fn vectors_dir() -> Option<PathBuf> {
    let base = match std::env::var_os(DATA_ENV) {
        Some(v) => PathBuf::from(v),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
    };
    let d = base.join("kinect-v2-vectors");
    d.is_dir().then_some(d)
}

/// Returns the vectors folder or, if absent, records a skip of `test` (`test_skip::skip`, which
/// CI counts) and returns `None` (panics instead when `KFUSE_REQUIRE_SHARED_DATA=1`).
pub fn vectors_or_skip(test: &str) -> Option<PathBuf> {
    let d = vectors_dir();
    if d.is_none() {
        if std::env::var("KFUSE_REQUIRE_SHARED_DATA").as_deref() == Ok("1") {
            panic!("{test}: shared data required but not found (set {DATA_ENV})");
        }
        test_skip::skip(test, &format!("shared data not found (set {DATA_ENV})"));
    }
    d
}

/// Largest test-vector file read: 64 MiB (the largest vector, a raw depth frame, is 3 MB).
pub const MAX_VECTOR_BYTES: u64 = 64 << 20;

/// Reads a whole test-vector file, at most [`MAX_VECTOR_BYTES`] (see `bounded_read`).
pub fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    let expected = bounded_read::Expected {
        what: "a test-vector file",
        fix: "is KFUSE_SHARED_DATA the right folder?",
    };
    bounded_read::read_bounded(path, MAX_VECTOR_BYTES, expected)
        .map_err(|source| KinectError::File { path: path.to_path_buf(), source })
}

/// Reads a little-endian f32 file.
pub fn read_f32(path: &Path) -> Result<Vec<f32>> {
    let b = read_bytes(path)?;
    if b.len() % 4 != 0 {
        return Err(KinectError::Size {
            what: path.display().to_string(),
            expected: b.len() / 4 * 4,
            got: b.len(),
        });
    }
    Ok(b.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect())
}

/// Every oracle run of the vectors' manifest (`oracle_runs`), paths relative to the vectors
/// folder: (frame, bilateral, edge_aware, xtable, ztable, depth oracle, IR oracle). Used by
/// the CPU decoder's golden tests and the GPU decoder's parity test.
pub const ORACLE_RUNS: &[(&str, bool, bool, &str, &str, &str, &str)] = &[
    (
        "frames/scene.raw",
        true,
        true,
        "tables/xtable.f32",
        "tables/ztable.f32",
        "oracle/scene_filt_depth.f32",
        "oracle/scene_ir.f32",
    ),
    (
        "frames/scene.raw",
        false,
        false,
        "tables/xtable.f32",
        "tables/ztable.f32",
        "oracle/scene_nofilt_depth.f32",
        "oracle/scene_ir.f32",
    ),
    (
        "frames/scene.raw",
        true,
        false,
        "tables/xtable.f32",
        "tables/ztable.f32",
        "oracle/scene_bilonly_depth.f32",
        "oracle/scene_ir.f32",
    ),
    (
        "frames/random.raw",
        false,
        false,
        "tables/xtable.f32",
        "tables/ztable.f32",
        "oracle/random_nofilt_depth.f32",
        "oracle/random_ir.f32",
    ),
    (
        "frames/edge_cases.raw",
        true,
        true,
        "tables/xtable.f32",
        "tables/ztable.f32",
        "oracle/edge_cases_filt_depth.f32",
        "oracle/edge_cases_ir.f32",
    ),
    (
        "frames/edge_cases.raw",
        false,
        false,
        "tables/xtable.f32",
        "tables/ztable.f32",
        "oracle/edge_cases_nofilt_depth.f32",
        "oracle/edge_cases_ir.f32",
    ),
    (
        "frames/scene_realtables.raw",
        true,
        true,
        "real/libfreenect2-history/xTable.bin",
        "real/libfreenect2-history/zTable.bin",
        "oracle/scene_realtables_filt_depth.f32",
        "oracle/scene_realtables_ir.f32",
    ),
    (
        "frames/scene_realtables.raw",
        false,
        false,
        "real/libfreenect2-history/xTable.bin",
        "real/libfreenect2-history/zTable.bin",
        "oracle/scene_realtables_nofilt_depth.f32",
        "oracle/scene_realtables_ir.f32",
    ),
];
