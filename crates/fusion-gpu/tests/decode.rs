//! The GPU depth decoder (`GpuDecoder`) against the CPU `Fast` decoder and the oracle on every
//! oracle run of the shared Kinect v2 vectors, and GPU decode + register against CPU decode +
//! GPU register (on lavapipe in CI; `KFUSE_REQUIRE_GPU=1` / `KFUSE_REQUIRE_SHARED_DATA=1` turn
//! the skips into failures).

mod common;

use std::path::Path;

use common::context_or_skip;
use fusion_gpu::{FramePlan, FusionContext, GpuDecoder, GpuError, METRES_PER_MM};
use geometry::{DepthKind, Image};
use kinect_usb::decoder::{DecoderConfig, DecoderParams, DecoderPrecision, DepthDecoder};
use kinect_usb::orientation::Orientation;
use kinect_usb::params::{P0Tables, XzTables};
use kinect_usb::raw::{HEIGHT, PIXELS, WIDTH};
use kinect_usb::testdata::{ORACLE_RUNS as RUNS, read_bytes, read_f32, vectors_or_skip};

/// Protocol §9.9's test policy: the largest depth difference (mm) of pixels valid in both.
const MAX_DEPTH_DIFF_MM: f32 = 0.01;
/// Against the oracle (libm transcendentals, true f64): protocol §9.9's "at most a handful of
/// pixels flipping", read as at most 5 of 217 088 per file, as kinect-usb's oracle test does.
const MAX_FLIPS_VS_ORACLE: usize = 5;

/// IR on a hardware adapter: relative difference allowed (about 8 f32 ulp; Vulkan allows
/// square root and division a few ulp off, and IR is a sum of three square roots).
const MAX_IR_REL_DIFF_HARDWARE: f32 = 1e-6;

/// Depth comparison of two decoded images.
#[derive(Debug, Default)]
struct DepthDiff {
    max_abs_mm: f32,
    flips: usize,
    bit_identical: usize,
    valid: usize,
}

fn depth_diff(got: &[f32], want: &[f32]) -> DepthDiff {
    let mut d = DepthDiff::default();
    for (&g, &w) in got.iter().zip(want) {
        d.bit_identical += (g.to_bits() == w.to_bits()) as usize;
        match (g != 0.0, w != 0.0) {
            (true, true) => {
                d.valid += 1;
                d.max_abs_mm = d.max_abs_mm.max((g - w).abs());
            }
            (false, false) => {}
            _ => d.flips += 1,
        }
    }
    d
}

fn p0_tables(dir: &Path) -> P0Tables {
    P0Tables::from_response(&read_bytes(&dir.join("inputs/p0_tables_response.bin")).unwrap())
        .unwrap()
}

fn xz_tables(dir: &Path, xt: &str, zt: &str) -> XzTables {
    XzTables::from_vecs(read_f32(&dir.join(xt)).unwrap(), read_f32(&dir.join(zt)).unwrap()).unwrap()
}

/// Every oracle run decoded on the GPU and by the CPU `Fast` decoder (which the shaders
/// mirror). Tolerances per file: depth within [`MAX_DEPTH_DIFF_MM`] where both are valid and
/// no pixel valid on one side only (issue 15's bar, stricter than §9.9's "a handful"). IR
/// involves neither transcendental functions nor f64 steps: bit-identical on a software
/// adapter with IEEE division and square root (lavapipe), within [`MAX_IR_REL_DIFF_HARDWARE`]
/// on hardware (Vulkan allows a few ulp there). The GPU output is also held to the oracle of
/// the independent reference decoder with protocol §9.9's policy ([`MAX_DEPTH_DIFF_MM`],
/// [`MAX_FLIPS_VS_ORACLE`]). `--nocapture` prints the measured table.
///
/// Measured on lavapipe (llvmpipe, LLVM 15.0.6; 2026-12-01): on all 8 runs the depth and IR
/// are bit-identical to the CPU `Fast` decoder (217 088 of 217 088 pixels, max |Δ| 0 mm, 0
/// flips); against the oracle max |Δ| 0.00049–0.00293 mm and 0 flips (the CPU `Fast` figures
/// of kinect-usb's oracle test). Two variants show what makes the bar reachable: WGSL's
/// built-in `atan2`/`exp`/`log` instead of fastmath's give 0.043 mm on `random_nofilt` (fails);
/// plain f32 products instead of the double-word emulation of the CPU's f64 steps give one
/// validity flip on `random_nofilt` (fails).
#[test]
fn gpu_decoder_matches_cpu_fast_decoder_on_every_oracle_run() {
    let test = "gpu_decoder_matches_cpu_fast_decoder_on_every_oracle_run";
    let Some(dir) = vectors_or_skip(test) else { return };
    let Some(ctx) = context_or_skip(test) else { return };
    let p0 = p0_tables(&dir);
    let (mut cpu_d, mut cpu_ir) = (vec![0f32; PIXELS], vec![0f32; PIXELS]);
    let (mut gpu_d, mut gpu_ir) = (vec![0f32; PIXELS], vec![0f32; PIXELS]);
    let mut failures = Vec::new();
    let mut valid_total = 0;
    eprintln!(
        "| depth oracle | GPU vs Fast max abs mm | flips | bit-identical | GPU vs oracle max abs mm | flips |"
    );
    for &(frame, bil, edge, xt, zt, dref, iref) in RUNS {
        let xz = xz_tables(&dir, xt, zt);
        let cfg = DecoderConfig {
            bilateral: bil,
            edge_aware: edge,
            parallel: true,
            orientation: Orientation::Sensor,
        };
        let raw = read_bytes(&dir.join(frame)).unwrap();
        let mut cpu = DepthDecoder::new(DecoderParams::default(), cfg, &xz, &p0)
            .unwrap()
            .with_precision(DecoderPrecision::Fast);
        cpu.decode(&raw, &mut cpu_d, &mut cpu_ir).unwrap();
        let mut gpu = GpuDecoder::new(&ctx, DecoderParams::default(), cfg, &xz, &p0).unwrap();
        gpu.decode(&raw, &mut gpu_d, &mut gpu_ir).unwrap();
        let fast = depth_diff(&gpu_d, &cpu_d);
        let oracle = depth_diff(&gpu_d, &read_f32(&dir.join(dref)).unwrap());
        valid_total += fast.valid;
        eprintln!(
            "| {dref} | {:.5} | {} | {} of {PIXELS} | {:.5} | {} |",
            fast.max_abs_mm, fast.flips, fast.bit_identical, oracle.max_abs_mm, oracle.flips
        );
        if !(fast.max_abs_mm <= MAX_DEPTH_DIFF_MM && fast.flips == 0) {
            failures.push(format!("{dref} vs CPU Fast: {fast:?}"));
        }
        if !(oracle.max_abs_mm <= MAX_DEPTH_DIFF_MM && oracle.flips <= MAX_FLIPS_VS_ORACLE) {
            failures.push(format!("{dref} vs oracle: {oracle:?}"));
        }
        let software = ctx.is_software();
        let ir_diff = gpu_ir
            .iter()
            .zip(&cpu_ir)
            .filter(|&(&g, &c)| {
                if software {
                    g.to_bits() != c.to_bits()
                } else {
                    (g - c).abs() > MAX_IR_REL_DIFF_HARDWARE * c.abs().max(1.0)
                }
            })
            .count();
        if ir_diff > 0 {
            failures.push(format!("{iref}: {ir_diff} GPU IR pixels differ from the CPU's"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // Guard, not a measurement: the scene runs alone have most of their 217 088 pixels valid,
    // so fewer than 300 000 valid pixels over the 8 runs would mean a vacuous comparison.
    assert!(valid_total > 300_000, "only {valid_total} valid pixels compared");
}

/// The depth the registration receives from the CPU path: the CPU decoder's millimetres times
/// [`METRES_PER_MM`] (the same f32 product the GPU's edge pass applies).
fn metres(depth_mm: &[f32]) -> Image<f32> {
    Image::from_vec(WIDTH, HEIGHT, depth_mm.iter().map(|d| d * METRES_PER_MM).collect()).unwrap()
}

/// GPU decode + register (raw frames in, [`FusionContext::stream_raw`] with two frames in
/// flight, and [`FusionContext::decode_and_register`]) against CPU `Fast` decode + GPU register
/// of the same frames. Tolerance: the colour z-buffer within [`MAX_DEPTH_DIFF_MM`] (as metres)
/// where both have a sample and no pixel filled on one side only; H1's points within the same
/// bar in z.
#[test]
fn gpu_decode_and_register_equals_cpu_decode_then_register() {
    let test = "gpu_decode_and_register_equals_cpu_decode_then_register";
    let Some(dir) = vectors_or_skip(test) else { return };
    let Some(mut ctx) = context_or_skip(test) else { return };
    let p0 = p0_tables(&dir);
    let xz = xz_tables(&dir, "tables/xtable.f32", "tables/ztable.f32");
    let cfg = DecoderConfig::default();
    let mut cpu = DepthDecoder::new(DecoderParams::default(), cfg, &xz, &p0).unwrap();
    let gpu = GpuDecoder::new(&ctx, DecoderParams::default(), cfg, &xz, &p0).unwrap();
    let rig = geometry::synth::kinect_rig();
    let frames: Vec<Vec<u8>> = ["frames/scene.raw", "frames/edge_cases.raw", "frames/scene.raw"]
        .iter()
        .map(|f| read_bytes(&dir.join(f)).unwrap())
        .collect();
    let plan = FramePlan { stages: None, read_intermediates: true };
    let mut streamed = Vec::new();
    let n = ctx
        .stream_raw(&gpu, &rig, frames.iter().map(|r| (&r[..], None)), plan, |k, f| {
            streamed.push((k, f))
        })
        .unwrap();
    assert_eq!(n, 3);
    let single = ctx.decode_and_register(&gpu, &frames[1], &rig, true).unwrap();
    let (mut d, mut ir) = (vec![0f32; PIXELS], vec![0f32; PIXELS]);
    let bar_m = MAX_DEPTH_DIFF_MM * METRES_PER_MM;
    let mut landed = 0;
    for (k, raw) in frames.iter().enumerate() {
        cpu.decode(raw, &mut d, &mut ir).unwrap();
        let want = ctx.register(&rig, &metres(&d), DepthKind::Z, true).unwrap();
        let mut got = vec![&streamed[k].1];
        assert_eq!(streamed[k].0, k);
        if k == 1 {
            got.push(&single);
        }
        for g in got {
            let (mut max_z, mut flips, mut filled) = (0f32, 0, 0);
            for (a, b) in g.zbuffer.data().iter().zip(want.zbuffer.data()) {
                match (a.is_nan(), b.is_nan()) {
                    (false, false) => {
                        filled += 1;
                        max_z = max_z.max((a - b).abs());
                    }
                    (true, true) => {}
                    _ => flips += 1,
                }
            }
            let (gp, wp) = (g.points.as_ref().unwrap(), want.points.as_ref().unwrap());
            let mut point_flips = 0;
            let mut max_p = 0f32;
            for (a, b) in gp.iter().zip(wp) {
                match (a[3] == 1.0, b[3] == 1.0) {
                    (true, true) => max_p = max_p.max((a[2] - b[2]).abs()),
                    (false, false) => {}
                    _ => point_flips += 1,
                }
            }
            eprintln!(
                "{test}: frame {k}: {filled} z-buffer pixels, max |dz| {max_z:e} m, {flips} flips; points max |dz| {max_p:e} m, {point_flips} flips"
            );
            assert!(max_z <= bar_m && flips == 0, "frame {k}: z-buffer {max_z:e} m, {flips} flips");
            assert!(max_p <= bar_m && point_flips == 0, "frame {k}: points {max_p:e} m");
            landed += filled;
        }
    }
    // Guard: the scene frames put tens of thousands of samples into the colour image.
    assert!(landed > 50_000, "only {landed} z-buffer pixels compared");
}

/// Bad input is refused with one line naming the fix, and the context stays usable.
#[test]
fn gpu_decoder_rejects_bad_frames_and_a_foreign_context() {
    let test = "gpu_decoder_rejects_bad_frames_and_a_foreign_context";
    let Some(dir) = vectors_or_skip(test) else { return };
    let Some(mut ctx) = context_or_skip(test) else { return };
    let p0 = p0_tables(&dir);
    let xz = xz_tables(&dir, "tables/xtable.f32", "tables/ztable.f32");
    let cfg = DecoderConfig::default();
    let mut gpu = GpuDecoder::new(&ctx, DecoderParams::default(), cfg, &xz, &p0).unwrap();
    let (mut d, mut ir) = (vec![0f32; PIXELS], vec![0f32; PIXELS]);
    let short = vec![0u8; 1000];
    let e = gpu.decode(&short, &mut d, &mut ir).unwrap_err();
    assert!(
        matches!(e, GpuError::Input(_)) && e.to_string().contains("2984960 bytes, got 1000"),
        "{e}"
    );
    let rig = geometry::synth::kinect_rig();
    let e = ctx.decode_and_register(&gpu, &short, &rig, false).unwrap_err();
    assert!(e.to_string().contains("got 1000"), "{e}");
    let mut small = rig.clone();
    small.depth = common::with_small_color(&rig, 256).color;
    let raw = read_bytes(&dir.join("frames/scene.raw")).unwrap();
    let e = ctx.decode_and_register(&gpu, &raw, &small, false).unwrap_err();
    assert!(e.to_string().contains("512x424"), "{e}");
    let other = FusionContext::new().unwrap();
    let foreign = GpuDecoder::new(&other, DecoderParams::default(), cfg, &xz, &p0).unwrap();
    let e = ctx.decode_and_register(&foreign, &raw, &rig, false).unwrap_err();
    assert!(e.to_string().contains("another FusionContext"), "{e}");
    // Still usable after the refusals.
    let ok = ctx.decode_and_register(&gpu, &raw, &rig, false).unwrap();
    assert!(ok.zbuffer.data().iter().any(|z| !z.is_nan()));
    let bad_tables = XzTables { x: vec![0.0; 10], z: xz.z.clone(), nonconverged: 0 };
    let e = GpuDecoder::new(&ctx, DecoderParams::default(), cfg, &bad_tables, &p0).unwrap_err();
    assert!(e.to_string().contains("217088 values"), "{e}");
}
