//! Golden tests: the CPU decoder against every oracle run of the vectors' manifest.

use kinect_usb::decoder::{DecoderConfig, DecoderParams, DepthDecoder};
use kinect_usb::params::{P0Tables, XzTables};
use kinect_usb::raw::PIXELS;
use kinect_usb::testdata::{read_bytes, read_f32, vectors_or_skip};

/// (frame, bilateral, edge_aware, xtable, ztable, depth oracle, ir oracle) — the manifest's
/// `oracle_runs`.
const RUNS: &[(&str, bool, bool, &str, &str, &str, &str)] = &[
    ("frames/scene.raw", true, true, "tables/xtable.f32", "tables/ztable.f32", "oracle/scene_filt_depth.f32", "oracle/scene_ir.f32"),
    ("frames/scene.raw", false, false, "tables/xtable.f32", "tables/ztable.f32", "oracle/scene_nofilt_depth.f32", "oracle/scene_ir.f32"),
    ("frames/scene.raw", true, false, "tables/xtable.f32", "tables/ztable.f32", "oracle/scene_bilonly_depth.f32", "oracle/scene_ir.f32"),
    ("frames/random.raw", false, false, "tables/xtable.f32", "tables/ztable.f32", "oracle/random_nofilt_depth.f32", "oracle/random_ir.f32"),
    ("frames/edge_cases.raw", true, true, "tables/xtable.f32", "tables/ztable.f32", "oracle/edge_cases_filt_depth.f32", "oracle/edge_cases_ir.f32"),
    ("frames/edge_cases.raw", false, false, "tables/xtable.f32", "tables/ztable.f32", "oracle/edge_cases_nofilt_depth.f32", "oracle/edge_cases_ir.f32"),
    ("frames/scene_realtables.raw", true, true, "real/libfreenect2-history/xTable.bin", "real/libfreenect2-history/zTable.bin", "oracle/scene_realtables_filt_depth.f32", "oracle/scene_realtables_ir.f32"),
    ("frames/scene_realtables.raw", false, false, "real/libfreenect2-history/xTable.bin", "real/libfreenect2-history/zTable.bin", "oracle/scene_realtables_nofilt_depth.f32", "oracle/scene_realtables_ir.f32"),
];

fn mismatches(got: &[f32], want: &[f32]) -> (usize, usize) {
    let first = got.iter().zip(want).position(|(a, b)| a.to_bits() != b.to_bits()).unwrap_or(usize::MAX);
    (got.iter().zip(want).filter(|(a, b)| a.to_bits() != b.to_bits()).count(), first)
}

/// Tolerance: none. Every oracle file (depth and IR, all runs, including −0.0 pixels) must be
/// reproduced bit for bit (spec §9.9: the reference used the same f32 operation order and
/// glibc libm, which Rust's f32 functions call on Linux).
#[test]
fn decoder_matches_every_oracle_run_bit_for_bit() {
    let Some(dir) = vectors_or_skip("decoder_matches_every_oracle_run_bit_for_bit") else { return };
    let p0 = P0Tables::from_response(&read_bytes(&dir.join("inputs/p0_tables_response.bin")).unwrap()).unwrap();
    let mut depth = vec![0f32; PIXELS];
    let mut ir = vec![0f32; PIXELS];
    let mut failures = Vec::new();
    let mut checked = 0;
    for &(frame, bil, edge, xt, zt, dref, iref) in RUNS {
        let xz = XzTables::from_vecs(read_f32(&dir.join(xt)).unwrap(), read_f32(&dir.join(zt)).unwrap()).unwrap();
        let cfg = DecoderConfig { bilateral: bil, edge_aware: edge, parallel: true };
        let mut dec = DepthDecoder::new(DecoderParams::default(), cfg, &xz, &p0).unwrap();
        let raw = read_bytes(&dir.join(frame)).unwrap();
        dec.decode(&raw, &mut depth, &mut ir).unwrap();
        for (name, got, path) in [("depth", &depth, dref), ("ir", &ir, iref)] {
            let want = read_f32(&dir.join(path)).unwrap();
            let (n, first) = mismatches(got, &want);
            checked += 1;
            if n > 0 {
                failures.push(format!(
                    "{path} ({name}, bilateral={bil}, edge={edge}): {n} pixels differ, first at {first}: got {} want {}",
                    got[first], want[first]
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert_eq!(checked, 16);
}
